#!/usr/bin/env python3
"""How far the whole frame's motion is from the annotated motion, on real YCB-Video frames.

The scene of a YCB-Video frame folder is static and the camera moves, so the whole frame (every
pixel with depth, no mask) moves with the annotated relative motion of any object. Registering
whole frames uses every pixel: what is left between that estimate and the annotation is the
agreement between the frames and the annotation, the floor any per-object estimate is measured
against. For every pair of frames (gaps 1..4) the script runs

    flowfilter estimate --camera A-gt.json --model-color A-color.png --model-depth A-depth.png
        --target-color B-color.png --target-depth B-depth.png --gt truth.json --method M --json

without masks, for Flow Filter (colour flow and depth) and point-to-plane ICP (depth alone), and
prints each pair's geodesic error and the mean per gap beside the "no motion" answer's (the true
rotation). Needs only the standard library and the `flowfilter` binary.

    python3 tools/bench/whole_frame_against_truth.py ../shared/data/ycb-video/0001 \
        --flowfilter target/release/flowfilter
"""
import argparse
import json
import math
import subprocess
import tempfile
from pathlib import Path

METHODS = ("flowfilter", "icp-pt2pl")


def matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(4)) for j in range(4)] for i in range(4)]


def rigid_inverse(t):
    r = [[t[j][i] for j in range(3)] for i in range(3)]
    p = [-sum(r[i][k] * t[k][3] for k in range(3)) for i in range(3)]
    return [r[0] + [p[0]], r[1] + [p[1]], r[2] + [p[2]], [0.0, 0.0, 0.0, 1.0]]


def rotation_deg(t):
    """The rotation's angle; from its antisymmetric part as well, which stays exact where the
    trace's arccosine loses a small angle to rounding."""
    s = math.hypot(t[2][1] - t[1][2], t[0][2] - t[2][0], t[1][0] - t[0][1]) / 2.0
    return math.degrees(math.atan2(s, (t[0][0] + t[1][1] + t[2][2] - 1.0) / 2.0))


def true_motion(folder, a, b):
    """P_b = T P_a for the first object both frames annotate (the scene is static)."""
    gt = [json.loads((folder / f"{i:06d}-gt.json").read_text()) for i in (a, b)]
    later = {o["name"]: o for o in gt[1]["objects"]}
    o = next(o for o in gt[0]["objects"] if o["name"] in later)
    return matmul(later[o["name"]]["T_camera_from_object"], rigid_inverse(o["T_camera_from_object"]))


def estimate(cli, folder, a, b, method, truth_file):
    f = lambda i, kind: str(folder / f"{i:06d}-{kind}.png")
    cmd = [cli, "estimate", "--camera", str(folder / f"{a:06d}-gt.json"),
           "--model-color", f(a, "color"), "--model-depth", f(a, "depth"),
           "--target-color", f(b, "color"), "--target-depth", f(b, "depth"),
           "--gt", str(truth_file), "--method", method, "--json"]
    out = subprocess.run(cmd, capture_output=True, text=True)
    # Exit code 3: the estimate carries a warning; its JSON is complete.
    if out.returncode not in (0, 3):
        raise SystemExit(f"{' '.join(cmd)} failed ({out.returncode}): {out.stderr.strip()}")
    return json.loads(out.stdout)["ground_truth"]["errors"]["geodesic_error_deg"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path, help="a YCB-Video frame folder (NNNNNN-color.png, -depth.png, -gt.json)")
    ap.add_argument("--flowfilter", default="flowfilter", help="the flowfilter binary")
    ap.add_argument("--gaps", default="1,2,3,4", help="frame gaps, comma separated")
    args = ap.parse_args()
    frames = sorted(int(p.name[:6]) for p in args.folder.glob("*-gt.json"))
    gaps = [int(g) for g in args.gaps.split(",")]
    per_gap = {g: {m: [] for m in ("no-motion",) + METHODS} for g in gaps}
    with tempfile.TemporaryDirectory() as tmp:
        truth_file = Path(tmp) / "truth.json"
        for g in gaps:
            for a, b in ((a, a + g) for a in frames if a + g in frames):
                truth = true_motion(args.folder, a, b)
                truth_file.write_text(json.dumps({"transform": truth}))
                row = {"no-motion": rotation_deg(truth)}
                for m in METHODS:
                    row[m] = estimate(args.flowfilter, args.folder, a, b, m, truth_file)
                for k, v in row.items():
                    per_gap[g][k].append(v)
                print(f"{a} -> {b}: " + ", ".join(f"{k} {v:.3f}" for k, v in row.items()), flush=True)
    print("\n| frame gap | " + " | ".join(("no motion",) + METHODS) + " |")
    print("| --- |" + " --- |" * (1 + len(METHODS)))
    for g in gaps:
        cols = per_gap[g]
        n = len(cols["no-motion"])
        if n:
            means = [sum(cols[k]) / n for k in ("no-motion",) + METHODS]
            print(f"| {g} ({n} pairs) | " + " | ".join(f"{v:.2f}" for v in means) + " |")


if __name__ == "__main__":
    main()
