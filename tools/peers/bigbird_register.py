#!/usr/bin/env python3
"""numpy reference of the public BigBIRD tools' depth registration, on the h5py fixture.

For each frame of fixtures/bigbird/latest/tiny_spheres: discontinuity filter on raw depth (7x7,
reject when the window's max or min differs from the centre by more than 1000 raw units; only
valid readings take part), scale to metres, back-project with the depth intrinsics, move into
the colour camera (H_rgb_from_ir = H_NPc_from_NP5 inv(H_NPc_ir_from_NP5)), project with the
colour intrinsics and distortion (cv2.projectPoints), round to the nearest pixel, nearest depth
wins. Output: fixtures/peers/bigbird_registered/NP{c}_{angle}.h5, dataset `depth` (uint16,
colour-grid depth in units of 0.1 mm, 0 = none), read by crates/flowfilter-depth/tests/bigbird_reference.rs.
"""
import pathlib

import cv2
import h5py
import numpy as np
from scipy.ndimage import maximum_filter, minimum_filter

ROOT = pathlib.Path(__file__).resolve().parents[2]
OBJ = ROOT / "fixtures" / "bigbird" / "latest" / "tiny_spheres"
OUT = ROOT / "fixtures" / "peers" / "bigbird_registered"


def register(raw, cal, c, colour_shape):
    valid = raw > 0
    r = raw.astype(np.int64)
    mx = maximum_filter(np.where(valid, r, -1), size=7, mode="constant", cval=-1)
    mn = minimum_filter(np.where(valid, r, 1 << 40), size=7, mode="constant", cval=1 << 40)
    keep = valid & (mx - r <= 1000) & (r - mn <= 1000)
    scale = float(np.ravel(cal[f"NP{c}_ir_depth_scale"][()])[0])
    k_ir = cal[f"NP{c}_ir_K"][()] if f"NP{c}_ir_K" in cal else cal[f"NP{c}_depth_K"][()]
    v, u = np.nonzero(keep)
    z = raw[v, u] * scale * 1e-4
    pts = np.column_stack([(u - k_ir[0, 2]) / k_ir[0, 0] * z, (v - k_ir[1, 2]) / k_ir[1, 1] * z, z])
    h = cal[f"H_NP{c}_from_NP5"][()] @ np.linalg.inv(cal[f"H_NP{c}_ir_from_NP5"][()])
    pc = pts @ h[:3, :3].T + h[:3, 3]
    proj, _ = cv2.projectPoints(pc, np.zeros(3), np.zeros(3), cal[f"NP{c}_rgb_K"][()], np.ravel(cal[f"NP{c}_rgb_d"][()]))
    proj = np.rint(proj.reshape(-1, 2)).astype(np.int64)
    hgt, wid = colour_shape
    inside = (proj[:, 0] >= 0) & (proj[:, 1] >= 0) & (proj[:, 0] < wid) & (proj[:, 1] < hgt) & (pc[:, 2] > 0)
    out = np.full(hgt * wid, np.inf)
    np.minimum.at(out, proj[inside, 1] * wid + proj[inside, 0], pc[inside, 2])
    out = out.reshape(hgt, wid)
    return np.where(np.isfinite(out), np.round(out * 1e4), 0).astype(np.uint16)


OUT.mkdir(parents=True, exist_ok=True)
with h5py.File(OBJ / "calibration.h5", "r") as cal:
    for depth_file in sorted(OBJ.glob("NP*_*.h5")):
        stem = depth_file.stem
        c = int(stem[2])
        colour = cv2.imread(str(OBJ / f"{stem}.jpg"))
        with h5py.File(depth_file, "r") as f:
            raw = f["depth"][()]
        reg = register(raw, cal, c, colour.shape[:2])
        with h5py.File(OUT / f"{stem}.h5", "w") as f:
            f.create_dataset("depth", data=reg, compression="gzip", compression_opts=9)
        print(stem, int((reg > 0).sum()), "registered pixels")
