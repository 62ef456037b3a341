#!/usr/bin/env python3
"""Flow Filter's error on the real YCB-Video sample against its synthetic twin's, per object.

The twin (`cargo xtask twin`) renders each annotated object's scan where the real frames'
annotation puts it, through the real camera, with the noise profile and the per-frame effects
fitted to the sample (`--noise xtion-sample --effects sample`, the defaults). Its noise and
effects are random draws, so one twin is one draw: the twin's predicted error is the mean over
several seeds. The script runs

    xtask bench-bop --data DATA --gaps 1,2,3,4 --methods flowfilter --out OUT/real
    xtask twin --data DATA --out OUT/twin-SEED --seed SEED          (for every seed)
    xtask bench-bop --data OUT/twin-SEED --gaps 1,2,3,4 --methods flowfilter --out OUT/results-SEED

and prints, per object, the real frames' mean geodesic error, the twin's (mean over the seeds,
and the range of the seeds' means) and their ratio. Needs only the standard library and the
xtask binary (`cargo build --release -p xtask`).

    python3 tools/bench/twin_against_real.py ../shared/data/ycb-video/0001 \
        --xtask target/release/xtask --out target/twin-against-real
"""
import argparse
import csv
import subprocess
from collections import defaultdict
from pathlib import Path


def bench(xtask, data, out):
    """Run bench-bop on `data` and return its pairs.csv path."""
    cmd = [xtask, "bench-bop", "--data", str(data), "--gaps", "1,2,3,4", "--methods", "flowfilter", "--out", str(out)]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    found = sorted(Path(out).glob("*/pairs.csv"))
    if not found:
        raise SystemExit(f"no pairs.csv under {out}")
    return found[-1]


def per_object(pairs_csv):
    """Mean geodesic error of Flow Filter per object."""
    errors = defaultdict(list)
    with open(pairs_csv, newline="") as f:
        for row in csv.DictReader(f):
            if row["method"] == "flowfilter" and row["geodesic_error_deg"]:
                errors[row["object"]].append(float(row["geodesic_error_deg"]))
    return {k: sum(v) / len(v) for k, v in errors.items()}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data", help="a folder of YCB-Video frames (../shared/data/ycb-video/0001)")
    ap.add_argument("--xtask", default="target/release/xtask", help="the xtask binary")
    ap.add_argument("--seeds", default="7,8,9,10", help="the twins' seeds, comma separated")
    ap.add_argument("--out", default="target/twin-against-real", help="output folder")
    args = ap.parse_args()
    out = Path(args.out)
    real = per_object(bench(args.xtask, args.data, out / "real"))
    twins = []
    for seed in [int(s) for s in args.seeds.split(",")]:
        frames = out / f"twin-{seed}"
        subprocess.run(
            [args.xtask, "twin", "--data", args.data, "--out", str(frames), "--seed", str(seed)],
            check=True,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        twins.append(per_object(bench(args.xtask, frames, out / f"results-{seed}")))
    print("| object | real | twin, mean over seeds | twin seeds' range | twin / real |")
    print("| --- | --- | --- | --- | --- |")
    rows = []
    for name in sorted(real):
        draws = [t[name] for t in twins if name in t]
        twin = sum(draws) / len(draws)
        rows.append((real[name], twin))
        print(f"| {name} | {real[name]:.3f} | {twin:.3f} | {min(draws):.3f}-{max(draws):.3f} | {twin / real[name]:.2f} |")
    r, t = (sum(x) / len(rows) for x in zip(*rows))
    print(f"| all | {r:.3f} | {t:.3f} | | {t / r:.2f} |")


if __name__ == "__main__":
    main()
