#!/usr/bin/env python3
"""Measured optical flow against the flow the true motion predicts, on real YCB-Video frames.

For frames A and B of a YCB-Video frame folder (`NNNNNN-color.png`, `-depth.png`, `-label.png`,
`-gt.json`: a static scene seen by a moving camera, so every object moves with the camera), each
pixel of A with depth is lifted to 3-D, moved by the true motion (from `-gt.json`) and projected
into B: the predicted flow. The measured flow is a `.flo` file written by

    flowfilter flow --from A-color.png --to B-color.png --method dis --out A_B.flo

Per object (label) and for the background, the script prints the mean residual (measured minus
predicted, pixels) and the residual's affine part: its gradient (`dux/dy` is the sideways shift
per row) and its antisymmetric part as a turn in the image plane. A residual shift proportional
to the row that no rigid motion explains, the same on every object and the background, is a
rolling shutter's signature (docs/bop.md, real frames). Needs numpy and Pillow.

    python3 tools/bench/flow_against_truth.py ../shared/data/ycb-video/0001 1 3 A_B.flo
"""
import argparse
import json
import math
from pathlib import Path

import numpy as np
from PIL import Image


def frame(folder, i, kind):
    return folder / f"{i:06d}-{kind}"


def true_motion(gt_a, gt_b):
    """P_B = T P_A for the first object both frames annotate (the scene is static)."""
    b = {o["name"]: o for o in gt_b["objects"]}
    o = next(o for o in gt_a["objects"] if o["name"] in b)
    ta = np.array(o["T_camera_from_object"])
    tb = np.array(b[o["name"]]["T_camera_from_object"])
    return tb @ np.linalg.inv(ta)


def read_flo(path, shape):
    data = np.fromfile(path, np.float32)
    if data[0] != 202021.25:
        raise SystemExit(f"{path}: not a .flo file (bad magic number)")
    w, h = data[1:3].view(np.int32)
    if (h, w) != shape:
        raise SystemExit(f"{path}: flow is {w}x{h}, the frames are {shape[1]}x{shape[0]}")
    return data[3:].reshape(h, w, 2)


def affine_report(name, region, u, v, residual):
    """Fit residual = c + G (x - mean) over the region's pixels and print it."""
    if region.sum() < 100:
        return
    x, y, r = u[region], v[region], residual[region]
    ok = np.isfinite(r).all(axis=1) & (np.abs(r) < 50).all(axis=1)
    x, y, r = x[ok], y[ok], r[ok]
    a = np.stack([np.ones_like(x), x - x.mean(), y - y.mean()], axis=1).astype(float)
    cx = np.linalg.lstsq(a, r[:, 0], rcond=None)[0]
    cy = np.linalg.lstsq(a, r[:, 1], rcond=None)[0]
    turn = math.degrees((cy[1] - cx[2]) / 2)
    print(
        f"{name:22s} {len(x):7d} px  mean residual ({r[:, 0].mean():+.2f}, {r[:, 1].mean():+.2f}) px  "
        f"dux/dx {cx[1]:+.4f} dux/dy {cx[2]:+.4f} duy/dx {cy[1]:+.4f} duy/dy {cy[2]:+.4f}  "
        f"turn {turn:+.3f} deg"
    )


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folder", type=Path)
    p.add_argument("a", type=int)
    p.add_argument("b", type=int)
    p.add_argument("flo", type=Path)
    args = p.parse_args()
    gt_a = json.loads(frame(args.folder, args.a, "gt.json").read_text())
    gt_b = json.loads(frame(args.folder, args.b, "gt.json").read_text())
    k = np.array(gt_a["K"])
    depth = np.asarray(Image.open(frame(args.folder, args.a, "depth.png")), dtype=float)
    depth /= gt_a["depth_png_units_per_metre"]
    label = np.asarray(Image.open(frame(args.folder, args.a, "label.png")))
    flow = read_flo(args.flo, depth.shape)
    t = true_motion(gt_a, gt_b)
    v, u = np.mgrid[0 : depth.shape[0], 0 : depth.shape[1]].astype(float)
    z = np.where(depth > 0, depth, np.nan)
    pts = np.stack([(u - k[0, 2]) / k[0, 0] * z, (v - k[1, 2]) / k[1, 1] * z, z])
    moved = np.tensordot(t[:3, :3], pts, axes=1) + t[:3, 3, None, None]
    predicted = np.stack(
        [k[0, 0] * moved[0] / moved[2] + k[0, 2] - u, k[1, 1] * moved[1] / moved[2] + k[1, 2] - v], axis=-1
    )
    residual = flow - predicted
    valid = depth > 0
    print(f"frames {args.a} -> {args.b}: true turn {math.degrees(np.arccos(np.clip((np.trace(t[:3, :3]) - 1) / 2, -1, 1))):.3f} deg")
    for o in gt_a["objects"]:
        affine_report(o["name"], valid & (label == o["class_id"]), u, v, residual)
    affine_report("background", valid & (label == 0), u, v, residual)


if __name__ == "__main__":
    main()
