"""One Open3D ICP script, timed on Open3D and on `flowfilter.open3d` (the import line swapped).

Usage: python3 tools/peers/open3d_script_timing.py [--repeat 7]

Needs open3d (tools/peers/requirements.txt) and the flowfilter package (pip install .). Each of
the nine peer fixtures (fixtures/peers/registration) as Open3D point clouds, target normals by
Open3D (k = 12, turned to the camera); the script runs point-to-plane and point-to-point ICP
(25 cm gate, Open3D's criteria, 200 iterations) and `evaluate_registration`. Prints, per
estimation method, the median over repeats of the summed time of the nine fixtures, the ratio,
and the largest pose difference between the two.
"""

import argparse
import pathlib
import statistics
import time

import numpy as np
import open3d as o3d
from open3d.pipelines import registration as o3d_reg

import flowfilter
from flowfilter import open3d as ff_reg

ROOT = pathlib.Path(__file__).resolve().parents[2]
PEERS = ROOT / "fixtures" / "peers" / "registration"


def clouds():
    for src in sorted(PEERS.glob("*_source.ply")):
        name = src.name[: -len("_source.ply")]
        source, _ = flowfilter.read_ply(src)
        target, _ = flowfilter.read_ply(PEERS / f"{name}_target.ply")
        pcd_s = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(source))
        pcd_t = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(target))
        pcd_t.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=12))
        pcd_t.orient_normals_towards_camera_location(np.zeros(3))
        yield name, pcd_s, pcd_t


def run(reg, method, pairs):
    """The script's call, with `reg` the module it imported; (seconds, poses)."""
    criteria = reg.ICPConvergenceCriteria(relative_fitness=1e-6, relative_rmse=1e-6, max_iteration=200)
    estimation = reg.TransformationEstimationPointToPlane() if method == "pt2pl" else reg.TransformationEstimationPointToPoint()
    poses = []
    t0 = time.perf_counter()
    for _, s, t in pairs:
        r = reg.registration_icp(s, t, 0.25, np.identity(4), estimation, criteria)
        poses.append(np.asarray(r.transformation))
    return time.perf_counter() - t0, poses


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--repeat", type=int, default=7)
    args = p.parse_args()
    pairs = list(clouds())
    print(f"open3d {o3d.__version__}, flowfilter {flowfilter.__version__}, {len(pairs)} fixtures, "
          f"{flowfilter.get_num_threads()} threads")
    print("| method | Open3D (ms) | flowfilter.open3d (ms) | time ratio (ours / Open3D) | max pose difference |")
    print("| --- | --- | --- | --- | --- |")
    for method in ["pt2pl", "pt2pt"]:
        theirs, ours = [], []
        for _ in range(args.repeat):
            ts, their_poses = run(o3d_reg, method, pairs)
            to, our_poses = run(ff_reg, method, pairs)
            theirs.append(ts)
            ours.append(to)
        diff = max(np.abs(a - b).max() for a, b in zip(their_poses, our_poses))
        t, o = statistics.median(theirs) * 1e3, statistics.median(ours) * 1e3
        print(f"| {method} | {t:.1f} | {o:.1f} | {o / t:.2f} | {diff:.1e} |")


if __name__ == "__main__":
    main()
