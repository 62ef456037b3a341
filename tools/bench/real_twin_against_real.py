#!/usr/bin/env python3
"""Flow Filter on the real RealSense shelf pairs against the same pairs' synthetic twins.

`cargo xtask bench-real --twin` renders each pair from its model frame's own surface (the real
texture, geometry and depth holes; the SR300 shelf profile's noise and effects; the exact
truth). The script runs

    xtask bench-real --methods flowfilter --seed SEED --out OUT/real-SEED [ARGS]
    xtask bench-real --methods flowfilter --twin --seed SEED --out OUT/twin-SEED [ARGS]

for every seed (the seed draws the regions and their masks' defects; or reads one seed's
pairs.csv files given with --real-csv and --twin-csv) and prints, per seed and kind of pair
(region or whole frame, shelf or tote, gap), the real pairs' success / within 2 deg / median
geodesic error against their twins', the ratio of the medians, and how many of the real pairs
over 2 deg off are over 2 deg off in their twin too. Needs only the standard library and the
xtask binary (`cargo build --release -p xtask`).

    python3 tools/bench/real_twin_against_real.py --xtask target/release/xtask \
        --out target/real-twin --seeds 0,1
"""
import argparse
import csv
import statistics
import subprocess
from collections import defaultdict
from pathlib import Path


def bench(xtask, out, extra):
    """Run bench-real with `extra` arguments into `out` and return its pairs.csv path."""
    cmd = [xtask, "bench-real", "--methods", "flowfilter", "--out", str(out), *extra]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    found = sorted(Path(out).glob("*/pairs.csv"))
    if not found:
        raise SystemExit(f"no pairs.csv under {out}")
    return found[-1]


def rows(pairs_csv):
    """Flow Filter's rows of a pairs.csv, keyed by (object, sequence, from, to, index)."""
    out = {}
    seen = defaultdict(int)
    with open(pairs_csv, newline="") as f:
        for r in csv.DictReader(f):
            if r["method"] != "flowfilter" or not r["geodesic_error_deg"]:
                continue
            base = (r["object"], r["camera"], int(r["from"]), int(r["to"]))
            out[(*base, seen[base])] = r
            seen[base] += 1
    return out


def kind(key, row):
    """The table row a pair belongs to."""
    place = "tote" if key[1] == "tote" else "shelf"
    return f"{key[0]}, {place}, gap {row['step']}"


def cell(group):
    """success / within 2 deg / median geodesic error of a list of rows."""
    errors = [float(r["geodesic_error_deg"]) for r in group]
    ok = sum(r["success"] == "true" for r in group)
    within = sum(e < 2.0 for e in errors)
    n = len(group)
    return f"{100 * ok / n:.0f}% / {100 * within / n:.0f}% / {statistics.median(errors):.2f}", statistics.median(errors)


def compare(real, twin):
    """Print the table and the pair-by-pair counts of one seed's runs."""
    groups = defaultdict(lambda: ([], []))
    for key, r in real.items():
        groups[kind(key, r)][0].append(r)
    for key, r in twin.items():
        groups[kind(key, r)][1].append(r)
    print("| pairs | n | real | twin | twin / real (median) |")
    print("|---|---|---|---|---|")
    for name in sorted(groups):
        rg, tg = groups[name]
        if not rg or not tg:
            continue
        (rc, rm), (tc, tm) = cell(rg), cell(tg)
        print(f"| {name} | {len(rg)} | {rc} | {tc} | {tm / rm:.2f} |")
    wrong = [k for k, r in real.items() if float(r["geodesic_error_deg"]) >= 2.0 and k in twin]
    both = [k for k in wrong if float(twin[k]["geodesic_error_deg"]) >= 2.0]
    right = [k for k, r in real.items() if float(r["geodesic_error_deg"]) < 2.0 and k in twin]
    twin_wrong = [k for k in right if float(twin[k]["geodesic_error_deg"]) >= 2.0]
    print(f"\nReal pairs over 2 deg off: {len(wrong)}; their twins over 2 deg off: {len(both)}.")
    print(f"Real pairs within 2 deg: {len(right)}; their twins over 2 deg off: {len(twin_wrong)}.\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--xtask", default="target/release/xtask")
    ap.add_argument("--out", default="target/real-twin")
    ap.add_argument("--seeds", default="0", help="seeds, comma separated")
    ap.add_argument("--real-csv", help="one seed's real pairs.csv instead of running it")
    ap.add_argument("--twin-csv", help="the same seed's twin pairs.csv instead of running it")
    ap.add_argument("args", nargs="*", help="more bench-real arguments for both runs (after --)")
    a = ap.parse_args()
    if a.real_csv or a.twin_csv:
        if not (a.real_csv and a.twin_csv):
            raise SystemExit("give both --real-csv and --twin-csv")
        compare(rows(a.real_csv), rows(a.twin_csv))
        return
    for seed in a.seeds.split(","):
        print(f"Seed {seed}:\n")
        real = bench(a.xtask, Path(a.out) / f"real-{seed}", ["--seed", seed, *a.args])
        twin = bench(a.xtask, Path(a.out) / f"twin-{seed}", ["--twin", "--seed", seed, *a.args])
        compare(rows(real), rows(twin))


if __name__ == "__main__":
    main()
