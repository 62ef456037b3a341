#!/usr/bin/env bash
# Submit a sharded benchmark as a Slurm job array and its merge as a dependent job.
#
#   deploy/slurm/submit.sh N OUT bench-bigbird|bench-bop [options]
set -euo pipefail
cd "$(dirname "$0")/../.."
n=$1 out=$2
shift 2
cargo build --release -p xtask -p flowfilter
array=$(sbatch --parsable --export=ALL,SHARDS="$n" --array=1-"$n" deploy/slurm/bench.sbatch "$out" "$@")
merge=$(sbatch --parsable --dependency=afterok:"$array" deploy/slurm/merge.sbatch "$out")
echo "array job $array ($n shards), merge job $merge; results in $out/merged"
