#!/usr/bin/env python3
"""Time Open3D doing the depth stage's steps on one synthesised frame, for docs/benchmarks.md.

Input: an object directory written by `flowfilter synth` (default: /tmp/depthbench/box, made by
`flowfilter synth --procedural box --cameras NP3 --angles 30 --out /tmp/depthbench/box --seed 1`).
Steps, as close to ours as Open3D allows (Open3D has no lens distortion model and no
Gaussian-window filter): raw depth -> cloud in the depth camera (create_from_depth_image) ->
colour camera frame -> z-buffered projection onto the 1280x1024 colour grid
(t.geometry.PointCloud.project_to_depth_image) -> masked organised cloud on the colour grid
(create_from_depth_image with the colour intrinsics) -> normals (k-NN 20).
Prints the median over 20 runs.
"""
import pathlib
import statistics
import sys
import time

import cv2
import h5py
import numpy as np
import open3d as o3d

obj = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else "/tmp/depthbench/box")
frame = "NP3_30"
with h5py.File(obj / "calibration.h5", "r") as cal:
    k_ir, k_rgb = cal["NP3_ir_K"][()], cal["NP3_rgb_K"][()]
    scale = float(np.ravel(cal["NP3_ir_depth_scale"][()])[0])
    h_rgb_from_ir = cal["H_NP3_from_NP5"][()] @ np.linalg.inv(cal["H_NP3_ir_from_NP5"][()])
with h5py.File(obj / f"{frame}.h5", "r") as f:
    raw = f["depth"][()]
mask = cv2.imread(str(obj / "masks" / f"{frame}_mask.pbm"), cv2.IMREAD_GRAYSCALE) == 0
o3d_depth_scale = 1.0 / (scale * 1e-4)
ir = o3d.camera.PinholeCameraIntrinsic(640, 480, k_ir[0, 0], k_ir[1, 1], k_ir[0, 2], k_ir[1, 2])
rgb = o3d.camera.PinholeCameraIntrinsic(1280, 1024, k_rgb[0, 0], k_rgb[1, 1], k_rgb[0, 2], k_rgb[1, 2])
rgb_t = o3d.core.Tensor(k_rgb, o3d.core.float64)


def run():
    pcd = o3d.geometry.PointCloud.create_from_depth_image(o3d.geometry.Image(raw), ir, depth_scale=o3d_depth_scale, depth_trunc=5.0)
    pcd.transform(h_rgb_from_ir)
    tp = o3d.t.geometry.PointCloud.from_legacy(pcd)
    depth = tp.project_to_depth_image(1280, 1024, rgb_t, o3d.core.Tensor(np.eye(4)), depth_scale=1000.0, depth_max=5.0)
    d = np.asarray(depth.to_legacy()) * np.float32(1.0)
    d[~mask] = 0
    cloud = o3d.geometry.PointCloud.create_from_depth_image(o3d.geometry.Image(d.astype(np.float32)), rgb, depth_scale=1000.0, depth_trunc=5.0)
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=20))
    return len(cloud.points)


run()
times = []
for _ in range(20):
    t0 = time.perf_counter()
    n = run()
    times.append(time.perf_counter() - t0)
print(f"Open3D {o3d.__version__}: {n} points, median {statistics.median(times) * 1e3:.1f} ms over 20 runs (threads: Open3D default)")
