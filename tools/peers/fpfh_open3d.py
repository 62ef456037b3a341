#!/usr/bin/env python3
"""FPFH descriptors and their mutual matches, by Open3D.

Records in fixtures/peers/fpfh_open3d.json a wavy patch of 400 points with normals, the same
patch moved by a known motion with every point jittered, Open3D's FPFH descriptors of both
(`compute_fpfh_feature`, radius 0.03 m, at most 100 neighbours) and its mutual matches
(`correspondences_from_features(..., mutual_filter=True)`).
crates/flowfilter-registration/tests/fpfh_open3d.rs asserts ours against them.
"""
import json
import pathlib

import numpy as np
import open3d as o3d

ROOT = pathlib.Path(__file__).resolve().parents[2]
OUT = ROOT / "fixtures" / "peers" / "fpfh_open3d.json"
RADIUS, MAX_NN = 0.03, 100

rng = np.random.default_rng(11)
xy = rng.uniform(0.0, 0.12, size=(400, 2))
x, y = xy[:, 0], xy[:, 1]
z = 0.6 + 0.012 * np.sin(x * 50.0) * np.cos(y * 35.0) + 0.3 * (x - 0.06) ** 2
dzdx = 0.012 * 50.0 * np.cos(x * 50.0) * np.cos(y * 35.0) + 0.6 * (x - 0.06)
dzdy = -0.012 * 35.0 * np.sin(x * 50.0) * np.sin(y * 35.0)
points = np.stack([x, y, z], 1)
normals = np.stack([dzdx, dzdy, -np.ones_like(x)], 1)
normals /= np.linalg.norm(normals, axis=1, keepdims=True)

angle = np.radians(35.0)
axis = np.array([0.2, 1.0, 0.3]) / np.linalg.norm([0.2, 1.0, 0.3])
rotation = o3d.geometry.get_rotation_matrix_from_axis_angle(axis * angle)
translation = np.array([0.04, -0.02, 0.05])
moved = points @ rotation.T + translation + rng.normal(scale=0.0004, size=points.shape)
moved_normals = normals @ rotation.T


def cloud(p, n):
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
    pcd.normals = o3d.utility.Vector3dVector(n)
    return pcd


param = o3d.geometry.KDTreeSearchParamHybrid(radius=RADIUS, max_nn=MAX_NN)
a, b = cloud(points, normals), cloud(moved, moved_normals)
fa = o3d.pipelines.registration.compute_fpfh_feature(a, param)
fb = o3d.pipelines.registration.compute_fpfh_feature(b, param)
matches = o3d.pipelines.registration.correspondences_from_features(fa, fb, mutual_filter=True)
OUT.write_text(
    json.dumps(
        {
            "open3d": o3d.__version__,
            "radius": RADIUS,
            "max_nn": MAX_NN,
            "points": points.tolist(),
            "normals": normals.tolist(),
            "moved_points": moved.tolist(),
            "moved_normals": moved_normals.tolist(),
            "rotation": rotation.tolist(),
            "translation": translation.tolist(),
            "features": np.round(np.asarray(fa.data).T, 4).tolist(),
            "moved_features": np.round(np.asarray(fb.data).T, 4).tolist(),
            "mutual_matches": np.asarray(matches).tolist(),
        }
    )
)
print(f"wrote {OUT}: {len(points)} points, {len(np.asarray(matches))} mutual matches")
