#!/usr/bin/env python3
"""Flow Filter in the BOP layout against the BigBIRD layout, on the pairs both runs share.

The embedded BOP dataset's coarse scenes (ids below 100) show camera NP3 with image i at
turntable angle 3i degrees; `configs/bench/bop_pairs.toml` runs the same camera, objects and
angles in the BigBIRD layout. This script matches the rows of the two runs' pairs.csv by
(object, model angle, target angle) and prints the mean rotation-angle error of a method in
each layout, per object and overall. Standard library only.

    python3 tools/bench/compare_layouts.py BOP_RUN/pairs.csv BIGBIRD_RUN/pairs.csv [--method flowfilter]
"""
import argparse
import csv
from collections import defaultdict


def rows(path, method):
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            if r["method"] == method and r["angle_error_deg"] != "-":
                yield r


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bop_pairs")
    ap.add_argument("bigbird_pairs")
    ap.add_argument("--method", default="flowfilter")
    ap.add_argument("--deg-per-image", type=float, default=3.0)
    args = ap.parse_args()
    bop = {}
    for r in rows(args.bop_pairs, args.method):
        if int(r["camera"]) >= 100:  # the fine scenes have no BigBIRD twin
            continue
        key = (r["object"], round(int(r["from"]) * args.deg_per_image), round(int(r["to"]) * args.deg_per_image))
        bop[key] = float(r["angle_error_deg"])
    bigbird = {}
    for r in rows(args.bigbird_pairs, args.method):
        bigbird[(r["object"], int(r["from"]), int(r["to"]))] = float(r["angle_error_deg"])
    shared = sorted(set(bop) & set(bigbird))
    if not shared:
        raise SystemExit("no pair in common: are these the embedded BOP run and the bop_pairs.toml run?")
    per_object = defaultdict(lambda: [0.0, 0.0, 0])
    for k in shared:
        acc = per_object[k[0]]
        acc[0] += bop[k]
        acc[1] += bigbird[k]
        acc[2] += 1
    print(f"| object | pairs | {args.method} BOP layout | BigBIRD layout | ratio |")
    print("| --- | --- | --- | --- | --- |")
    for o, (a, b, n) in sorted(per_object.items()):
        print(f"| {o} | {n} | {a / n:.2f} | {b / n:.2f} | {a / b if b else float('nan'):.2f} |")
    a = sum(bop[k] for k in shared) / len(shared)
    b = sum(bigbird[k] for k in shared) / len(shared)
    print(f"| ALL | {len(shared)} | {a:.2f} | {b:.2f} | {a / b:.2f} |")


if __name__ == "__main__":
    main()
