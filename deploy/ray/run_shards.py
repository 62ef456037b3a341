#!/usr/bin/env python3
"""Run a sharded benchmark as Ray tasks, then merge the shards.

    pip install "ray[default]"                      # deploy/ray/requirements.txt
    cargo build --release -p xtask -p flowfilter    # once, on a filesystem every node sees
    python deploy/ray/run_shards.py --shards 3 --out results/ray -- bench-bigbird --quick --check

Each shard is one Ray task that runs `deploy/run-shard.sh OUT COMMAND --shard K/N ...` as a
plain process (Ray schedules it, one task per `--cpus-per-shard` CPUs). A task whose process
dies is retried alone (`--retries`); a shard that still fails is named and nothing is merged.
Then `cargo xtask bench-merge OUT` writes the merged outputs to OUT/merged.

Without `--address` the driver starts a local Ray instance with `--num-cpus` CPUs (the check in
docs/cluster.md); with `--address auto` (or ray://...) it joins a running cluster.
`--kill-shard K` kills shard K's process a few seconds into its first attempt, to show that the
re-run shard gives the same result (`--compare DIR`: a single-process run's results directory).
"""

import argparse
import os
import pathlib
import signal
import subprocess
import sys
import time

import ray

ROOT = pathlib.Path(__file__).resolve().parents[2]


@ray.remote
def run_shard(shard, out, command, options, kill_after, env):
    """One shard as a process; raises (so Ray retries) when the process fails."""
    env = {**os.environ, **env, "FLOWFILTER_SHARD": shard}
    marker = pathlib.Path(out) / f".killed-{shard.replace('/', '-of-')}"
    proc = subprocess.Popen([str(ROOT / "deploy" / "run-shard.sh"), out, command, *options], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if kill_after is not None and not marker.exists():
        try:
            proc.wait(timeout=kill_after)
        except subprocess.TimeoutExpired:
            marker.parent.mkdir(parents=True, exist_ok=True)
            marker.write_text("killed once by --kill-shard\n")
            proc.send_signal(signal.SIGKILL)
    log, _ = proc.communicate()
    if proc.returncode != 0:
        raise RuntimeError(f"shard {shard} exited with {proc.returncode}:\n{log[-2000:]}")
    return shard, log.strip().splitlines()[-1] if log.strip() else ""


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shards", type=int, required=True)
    ap.add_argument("--out", required=True, help="results root shared by every node")
    ap.add_argument("--address", help="a running Ray cluster (auto, ray://host:10001); default: start a local one")
    ap.add_argument("--num-cpus", type=int, default=2, help="CPUs of the local Ray instance")
    ap.add_argument("--cpus-per-shard", type=float, default=1.0)
    ap.add_argument("--retries", type=int, default=2, help="re-runs of a shard whose process fails")
    ap.add_argument("--kill-shard", type=int, help="kill this shard's first attempt after --kill-after seconds")
    ap.add_argument("--kill-after", type=float, default=5.0)
    ap.add_argument("--compare", help="a single-process results directory the merge must equal (times aside)")
    ap.add_argument("command", nargs=argparse.REMAINDER, help="-- bench-bigbird|bench-bop [options]")
    a = ap.parse_args()
    command = [c for c in a.command if c != "--"]
    if not command or command[0] not in ("bench-bigbird", "bench-bop"):
        ap.error("give the benchmark after --: -- bench-bigbird [options] or -- bench-bop [options]")
    out = str(pathlib.Path(a.out).resolve())
    if a.address:
        ray.init(address=a.address)
    else:
        ray.init(num_cpus=a.num_cpus, include_dashboard=False)
    threads = {"RAYON_NUM_THREADS": str(max(1, int(a.cpus_per_shard)))}
    task = run_shard.options(num_cpus=a.cpus_per_shard, max_retries=a.retries, retry_exceptions=True)
    started = time.perf_counter()
    refs = {
        k: task.remote(f"{k}/{a.shards}", out, command[0], command[1:], a.kill_after if k == a.kill_shard else None, threads)
        for k in range(1, a.shards + 1)
    }
    failed = []
    for k, ref in refs.items():
        try:
            shard, last = ray.get(ref)
            print(f"shard {shard}: done ({last})")
        except Exception as e:  # the task failed after its retries
            failed.append(k)
            print(f"shard {k}/{a.shards}: FAILED: {e}", file=sys.stderr)
    print(f"{a.shards} shards in {time.perf_counter() - started:.1f} s")
    if failed:
        print(f"not merged: shard(s) {', '.join(f'{k}/{a.shards}' for k in failed)} failed; re-run with FLOWFILTER_SHARD=K/N "
              f"deploy/run-shard.sh {out} {command[0]} ..., then cargo xtask bench-merge {out}", file=sys.stderr)
        return 1
    xtask = os.environ.get("FLOWFILTER_XTASK", str(ROOT / "target" / "release" / "xtask"))
    merge = [xtask, "bench-merge", out, "--out", str(pathlib.Path(out) / "merged")]
    if a.compare:
        merge += ["--compare", a.compare]
    return subprocess.run(merge, cwd=ROOT).returncode


if __name__ == "__main__":
    sys.exit(main())
