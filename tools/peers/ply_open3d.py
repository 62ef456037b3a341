#!/usr/bin/env python3
"""PLY interoperability with Open3D.

1. Reads fixtures/ply/ours_{ascii,binary}.ply (written by our writer:
   `cargo run -p flowfilter-depth --example write_ply_fixture`) with Open3D and records what
   Open3D sees in fixtures/peers/open3d_read_ours.json.
2. Writes a cloud with Open3D to fixtures/ply/open3d_{ascii,binary}.ply and records the cloud
   in fixtures/peers/open3d_written.json.
crates/flowfilter-depth/tests/ply_open3d.rs asserts both directions.
"""
import json
import pathlib

import numpy as np
import open3d as o3d

ROOT = pathlib.Path(__file__).resolve().parents[2]
PLY = ROOT / "fixtures" / "ply"
PEERS = ROOT / "fixtures" / "peers"


def describe(pcd):
    return {
        "points": np.asarray(pcd.points).tolist(),
        "normals": np.asarray(pcd.normals).tolist(),
        "colors_u8": np.round(np.asarray(pcd.colors) * 255).astype(int).tolist(),
    }


read = {}
for fmt in ["ascii", "binary"]:
    read[fmt] = describe(o3d.io.read_point_cloud(str(PLY / f"ours_{fmt}.ply")))

rng = np.random.default_rng(3)
pcd = o3d.geometry.PointCloud()
pcd.points = o3d.utility.Vector3dVector(rng.normal(size=(150, 3)) * [0.05, 0.05, 0.02] + [0, 0, 0.8])
normals = rng.normal(size=(150, 3))
pcd.normals = o3d.utility.Vector3dVector(normals / np.linalg.norm(normals, axis=1, keepdims=True))
pcd.colors = o3d.utility.Vector3dVector(rng.integers(0, 256, size=(150, 3)) / 255.0)
o3d.io.write_point_cloud(str(PLY / "open3d_ascii.ply"), pcd, write_ascii=True)
o3d.io.write_point_cloud(str(PLY / "open3d_binary.ply"), pcd, write_ascii=False)

PEERS.mkdir(parents=True, exist_ok=True)
meta = {"generator": f"tools/peers/ply_open3d.py with Open3D {o3d.__version__}"}
(PEERS / "open3d_read_ours.json").write_text(json.dumps({**meta, **read}) + "\n")
(PEERS / "open3d_written.json").write_text(json.dumps({**meta, **describe(pcd)}) + "\n")
print("wrote", PEERS / "open3d_read_ours.json", PEERS / "open3d_written.json")
