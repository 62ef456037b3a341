#!/usr/bin/env bash
# One shard of a sharded run, for any scheduler. The shard comes from, in this order:
#   FLOWFILTER_SHARD=K/N                      (set by hand, or by the Ray driver)
#   SLURM_ARRAY_TASK_ID (1..N) and SHARDS=N   (a Slurm job array; SHARDS also when re-running one task)
#   JOB_COMPLETION_INDEX (0..N-1) and SHARDS=N (a Kubernetes Indexed Job)
#
# Usage: deploy/run-shard.sh OUT COMMAND [options...]
#   COMMAND bench-bigbird | bench-bop: `cargo xtask COMMAND --out OUT --shard K/N [options]`
#           (writes OUT/shard-K-of-N/; merge with `cargo xtask bench-merge OUT`)
#   COMMAND estimate-batch: `flowfilter estimate-batch --out OUT/shard-K-of-N.jsonl --shard K/N [options]`
# Binaries: $FLOWFILTER_XTASK and $FLOWFILTER_CLI, default target/release/{xtask,flowfilter}
# (built with cargo when absent). Threads: RAYON_NUM_THREADS, default SLURM_CPUS_PER_TASK.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ $# -lt 2 ]; then
    echo "usage: deploy/run-shard.sh OUT bench-bigbird|bench-bop|estimate-batch [options...]" >&2
    exit 64
fi
out=$1 command=$2
shift 2
if [ -n "${FLOWFILTER_SHARD:-}" ]; then
    shard=$FLOWFILTER_SHARD
elif [ -n "${SLURM_ARRAY_TASK_ID:-}" ]; then
    shard="$SLURM_ARRAY_TASK_ID/${SHARDS:-${SLURM_ARRAY_TASK_COUNT:?set SHARDS=N (the number of shards)}}"
elif [ -n "${JOB_COMPLETION_INDEX:-}" ]; then
    shard="$((JOB_COMPLETION_INDEX + 1))/${SHARDS:?set SHARDS=N (the number of completions)}"
else
    echo "run-shard.sh: no shard: set FLOWFILTER_SHARD=K/N, or run as a Slurm array task or a Kubernetes Indexed Job" >&2
    exit 64
fi
if [ -z "${RAYON_NUM_THREADS:-}" ] && [ -n "${SLURM_CPUS_PER_TASK:-}" ]; then
    export RAYON_NUM_THREADS=$SLURM_CPUS_PER_TASK
fi
binary() { # binary NAME PACKAGE: the prebuilt binary, or build it
    local path=$1
    if [ ! -x "$path" ]; then
        cargo build --release -p "$2" >&2
    fi
    echo "$path"
}
echo "run-shard.sh: shard $shard of $command -> $out" >&2
case $command in
    bench-bigbird | bench-bop)
        exec "$(binary "${FLOWFILTER_XTASK:-target/release/xtask}" xtask)" "$command" --out "$out" --shard "$shard" "$@"
        ;;
    estimate-batch)
        mkdir -p "$out"
        exec "$(binary "${FLOWFILTER_CLI:-target/release/flowfilter}" flowfilter)" estimate-batch \
            --out "$out/shard-${shard%/*}-of-${shard#*/}.jsonl" --shard "$shard" "$@"
        ;;
    *)
        echo "run-shard.sh: unknown command '$command' (bench-bigbird, bench-bop, estimate-batch)" >&2
        exit 64
        ;;
esac
