#!/usr/bin/env python3
"""Run the reference registration implementations on shared clouds and record their results.

Peers: probreg CPD (rigid), probreg FilterReg (pt2pt, pt2pl), Open3D ICP (pt2pt, pt2pl).

Fixture mode (default): writes fixtures/peers/registration/case_{k}_{source,target}.ply and
fixtures/peers/registration/results.json (truth, each peer's transform, rotation/translation
error and time). Cases: a procedural bumpy shape with random transforms up to 45 degrees,
noise-free and with noise + 20% outliers in both clouds, and partial-view pairs from the
synthesiser (`cargo run --release -p flowfilter-registration --example partial_view_cases`
writes fixtures/peers/registration/partial_*.ply first). The Rust test
crates/flowfilter-registration/tests/peers.rs runs our backends on the same files.

Bench mode (`--bench DIR`): writes 5k/10k/20k-point clouds to DIR with the peers' timings
(1 and 2 threads are set through the environment of the caller) in DIR/peers.json, for
`cargo run --release -p flowfilter-registration --example bench_peers -- DIR`.
"""
import argparse
import json
import pathlib
import time

import numpy as np
import open3d as o3d
from probreg import cpd, filterreg
from shapes import bumpy_shape, rotation

ROOT = pathlib.Path(__file__).resolve().parents[2]
OUT = ROOT / "fixtures" / "peers" / "registration"


def corrupt(points, rng, sigma, outliers):
    p = points + rng.normal(scale=sigma, size=points.shape) if sigma > 0 else points.copy()
    m = int(outliers * len(points))
    if m:
        lo, hi = p.min(0) - 0.05, p.max(0) + 0.05
        p = np.vstack([p, rng.uniform(lo, hi, size=(m, 3))])
    return p


def with_normals(points):
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=12))
    pcd.orient_normals_towards_camera_location(np.zeros(3))
    return pcd


def errors(t, truth):
    d = t[:3, :3] @ truth[:3, :3].T
    ang = np.degrees(np.arccos(np.clip((np.trace(d) - 1) / 2, -1, 1)))
    return float(ang), float(np.linalg.norm(t[:3, 3] - truth[:3, 3]))


def to_matrix(rot, t, scale=1.0):
    m = np.eye(4)
    m[:3, :3] = rot
    m[:3, 3] = t
    return m


def run_peers(src, tgt, with_cpd=True):
    """Each peer on o3d clouds src, tgt (tgt with normals): {name: (matrix, seconds)}."""
    out = {}
    s_np, t_np, t_n = np.asarray(src.points), np.asarray(tgt.points), np.asarray(tgt.normals)
    if with_cpd:
        t0 = time.perf_counter()
        res = cpd.registration_cpd(s_np, t_np, tf_type_name="rigid", w=0.2, maxiter=100, tol=1e-6)
        out["cpd"] = (to_matrix(res.transformation.rot, res.transformation.t), time.perf_counter() - t0)
    for obj in ["pt2pt", "pt2pl"]:
        t0 = time.perf_counter()
        kw = dict(target_normals=t_n) if obj == "pt2pl" else {}
        res = filterreg.registration_filterreg(s_np, t_np, objective_type=obj, update_sigma2=True, w=0.2, maxiter=100, tol=1e-6, **kw)
        tf = res.transformation if hasattr(res, "transformation") else res[0]
        out[f"filterreg-{obj}"] = (to_matrix(tf.rot, tf.t), time.perf_counter() - t0)
    reg = o3d.pipelines.registration
    for name, est in [("icp-pt2pt", reg.TransformationEstimationPointToPoint()), ("icp-pt2pl", reg.TransformationEstimationPointToPlane())]:
        t0 = time.perf_counter()
        r = reg.registration_icp(src, tgt, 0.25, np.eye(4), est, reg.ICPConvergenceCriteria(1e-6, 1e-6, 200))
        out[name] = (np.asarray(r.transformation), time.perf_counter() - t0)
    return out


def write_ply(path, points, normals=None):
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    if normals is not None:
        pcd.normals = o3d.utility.Vector3dVector(normals)
    o3d.io.write_point_cloud(str(path), pcd, write_ascii=False)


def fixtures():
    rng = np.random.default_rng(2024)
    cases = []
    shape = bumpy_shape(1000, rng)
    for k in range(6):
        truth = to_matrix(rotation(rng.normal(size=3), rng.uniform(15, 45)), rng.uniform(-0.05, 0.05, 3))
        noisy = k >= 3
        src = corrupt(shape, rng, 0.002 if noisy else 0.0, 0.2 if noisy else 0.0)
        tgt = corrupt(shape @ truth[:3, :3].T + truth[:3, 3], rng, 0.002 if noisy else 0.0, 0.2 if noisy else 0.0)
        cases.append((f"case_{k}", src, tgt, truth, "bumpy shape" + (", 2 mm noise, 20% outliers in both" if noisy else ", noise-free")))
    for path in sorted(OUT.glob("partial_*_source.ply")):
        stem = path.name[: -len("_source.ply")]
        meta = json.loads((OUT / f"{stem}.json").read_text())
        src = np.asarray(o3d.io.read_point_cloud(str(path)).points)
        tgt = np.asarray(o3d.io.read_point_cloud(str(OUT / f"{stem}_target.ply")).points)
        cases.append((stem, src, tgt, np.array(meta["truth"]), meta["description"]))
    results = []
    for name, src, tgt, truth, desc in cases:
        s = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(src))
        t = with_normals(tgt)
        if not name.startswith("partial_"):
            write_ply(OUT / f"{name}_source.ply", src)
            write_ply(OUT / f"{name}_target.ply", tgt, np.asarray(t.normals))
        peers = run_peers(s, t)
        entry = {"name": name, "description": desc, "truth": truth.tolist(), "peers": {}}
        for peer, (m, secs) in peers.items():
            deg, metres = errors(m, truth)
            entry["peers"][peer] = {"transform": m.tolist(), "rotation_error_deg": deg, "translation_error_m": metres, "seconds": secs}
            print(f"{name:>24} {peer:>16}: {deg:8.4f} deg {metres * 1e3:8.3f} mm {secs * 1e3:9.1f} ms")
        results.append(entry)
    meta = {"generator": f"tools/peers/registration_peers.py, probreg, Open3D {o3d.__version__}"}
    (OUT / "results.json").write_text(json.dumps({**meta, "cases": results}, indent=1) + "\n")


def bench(directory, sizes, cpd_max, repeat=1):
    directory = pathlib.Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(5)
    table = []
    for n in sizes:
        shape = bumpy_shape(n, rng)
        truth = to_matrix(rotation(np.array([0.3, -0.5, 0.8]), 25.0), np.array([0.02, -0.01, 0.015]))
        src = corrupt(shape, rng, 0.001, 0.0)
        tgt = corrupt(shape @ truth[:3, :3].T + truth[:3, 3], rng, 0.001, 0.0)
        t = with_normals(tgt)
        write_ply(directory / f"n{n}_source.ply", src)
        write_ply(directory / f"n{n}_target.ply", tgt, np.asarray(t.normals))
        # probreg's CPD is O(N^2) in time and memory per iteration: skipped above cpd_max.
        # Each peer's fastest of `repeat` runs (same pose every run): a shared machine's
        # stalls only ever add time, so the minimum is the repeatable number.
        s = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(src))
        runs = [run_peers(s, t, with_cpd=n <= cpd_max) for _ in range(repeat)]
        peers = {name: (runs[0][name][0], min(r[name][1] for r in runs)) for name in runs[0]}
        row = {"n": n, "truth": truth.tolist(), "repeat": repeat, "peers": {}}
        for peer, (m, secs) in peers.items():
            deg, metres = errors(m, truth)
            row["peers"][peer] = {"rotation_error_deg": deg, "translation_error_m": metres, "seconds": secs}
            print(f"n={n:6} {peer:>16}: {deg:8.4f} deg {metres * 1e3:8.3f} mm {secs:8.3f} s")
        table.append(row)
    (directory / "peers.json").write_text(json.dumps(table, indent=1) + "\n")


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--bench")
    ap.add_argument("--sizes", default="5000,10000,20000")
    ap.add_argument("--cpd-max", type=int, default=10000)
    ap.add_argument("--repeat", type=int, default=1, help="--bench: time each peer this many times, keep the fastest")
    a = ap.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    if a.bench:
        bench(a.bench, [int(v) for v in a.sizes.split(",")], a.cpd_max, a.repeat)
    else:
        fixtures()
