#!/usr/bin/env python3
"""The peers' side of `cargo xtask bench-speed`: time probreg, Open3D and OpenCV on the inputs
the xtask wrote, with the thread count the xtask sets in the environment.

    python3 tools/peers/speed_peers.py DIR/manifest.json OUT.json

`manifest.json` (written by the xtask) names the registration pairs (PLY files, the target with
normals), the parameters every method runs with, and optionally Sintel image pairs for the flow
row. Each peer is timed `repeat` times, then again while its runs took under `min_seconds` in
all (at most `max_runs`), and its fastest run kept (a shared machine's stalls only ever add
time); a run over 5 s is not repeated. OUT.json holds, per row, the seconds, the transform or the flow's EPE, and the
library versions. A missing library ends the script with exit code 3 and a message naming it;
the xtask then reports the peers as skipped.
"""
import json
import os
import sys
import time
from pathlib import Path


def need(name):
    try:
        return __import__(name)
    except ImportError as e:
        print(f"speed_peers.py: {name} is not installed ({e}); pip install -r tools/peers/requirements.txt",
              file=sys.stderr)
        sys.exit(3)


np = need("numpy")
o3d = need("open3d")
probreg = need("probreg")
cv2 = need("cv2")
from probreg import cpd, filterreg  # noqa: E402
from flow_opencv import read_flo  # noqa: E402  (the harness's .flo reader)


# A run longer than this is not repeated: the host's stalls are small beside it, and probreg's
# FilterReg on 60k points takes 10-30 s a run.
LONG_RUN_S = 5.0


def fastest(fn, repeat, min_seconds, max_runs):
    """The last result and the fastest of the runs of `fn`: `repeat` runs (fewer when one takes
    over LONG_RUN_S), then more while the runs so far took under `min_seconds` in all, up to
    `max_runs`; the xtask times its own side by the same rule."""
    best, out, runs, spent = float("inf"), None, 0, 0.0
    while runs < max(repeat, 1) or (runs < max_runs and spent < min_seconds):
        t0 = time.perf_counter()
        out = fn()
        secs = time.perf_counter() - t0
        best, runs, spent = min(best, secs), runs + 1, spent + secs
        if best > LONG_RUN_S:
            break
    return out, best


def to_matrix(tf):
    m = np.eye(4)
    m[:3, :3] = tf.rot
    m[:3, 3] = tf.t
    return m


def read_cloud(path):
    pcd = o3d.io.read_point_cloud(str(path))
    if len(pcd.points) == 0:
        raise SystemExit(f"speed_peers.py: {path}: no points")
    return pcd


def registration_rows(pair, params, runs):
    """`runs`: the keyword arguments of `fastest` (repeat, min_seconds, max_runs)."""
    src, tgt = read_cloud(pair["source"]), read_cloud(pair["target"])
    s, t = np.asarray(src.points), np.asarray(tgt.points)
    if not tgt.has_normals():
        raise SystemExit(f"speed_peers.py: {pair['target']}: the target needs normals")
    tn = np.asarray(tgt.normals)
    rows = []
    fr = params["filterreg"]
    for obj in ["pt2pt", "pt2pl"]:
        kw = dict(target_normals=tn) if obj == "pt2pl" else {}
        res, secs = fastest(lambda: filterreg.registration_filterreg(
            s, t, objective_type=obj, update_sigma2=True, w=fr["w"], maxiter=fr["max_iterations"],
            tol=fr["tolerance"], **kw), **runs)
        tf = res.transformation if hasattr(res, "transformation") else res[0]
        rows.append({"method": f"filterreg-{obj}", "peer": f"probreg {probreg.__version__}",
                     "points": [len(s), len(t)], "seconds": secs, "transform": to_matrix(tf).tolist()})
    icp = params["icp"]
    reg = o3d.pipelines.registration
    criteria = reg.ICPConvergenceCriteria(icp["relative_fitness"], icp["relative_rmse"], icp["max_iterations"])
    for name, est in [("icp-pt2pt", reg.TransformationEstimationPointToPoint()),
                      ("icp-pt2pl", reg.TransformationEstimationPointToPlane())]:
        res, secs = fastest(lambda: reg.registration_icp(
            src, tgt, icp["max_correspondence_distance"], np.eye(4), est, criteria), **runs)
        rows.append({"method": name, "peer": f"Open3D {o3d.__version__}", "points": [len(s), len(t)],
                     "seconds": secs, "transform": np.asarray(res.transformation).tolist()})
    c = params["cpd"]
    if c["peer_subsample"] > 0:
        rng = np.random.default_rng(c["seed"])
        ss = s[rng.choice(len(s), min(len(s), c["peer_subsample"]), replace=False)]
        ts = t[rng.choice(len(t), min(len(t), c["peer_subsample"]), replace=False)]
        res, secs = fastest(lambda: cpd.registration_cpd(
            ss, ts, tf_type_name="rigid", w=c["w"], maxiter=c["max_iterations"], tol=c["tolerance"]), **runs)
        rows.append({"method": "cpd", "peer": f"probreg {probreg.__version__} ({len(ss)}-point subsets)",
                     "points": [len(ss), len(ts)], "seconds": secs,
                     "transform": to_matrix(res.transformation).tolist()})
    return rows


def flow_rows(pairs, runs):
    rows = []
    for p in pairs:
        a = cv2.imread(p["from"], cv2.IMREAD_GRAYSCALE)
        b = cv2.imread(p["to"], cv2.IMREAD_GRAYSCALE)
        if a is None or b is None:
            raise SystemExit(f"speed_peers.py: cannot read {p['from']} or {p['to']}")
        dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
        dis.calc(a, b, None)  # warm-up
        flow, secs = fastest(lambda: dis.calc(a, b, None), **runs)
        gt = read_flo(p["gt"])
        epe = float(np.mean(np.linalg.norm(flow - gt, axis=2)))
        rows.append({"method": "dis-medium", "case": p["case"], "peer": f"OpenCV {cv2.__version__}",
                     "seconds": secs, "epe": epe})
    return rows


def main():
    if len(sys.argv) != 3:
        raise SystemExit("usage: speed_peers.py MANIFEST.json OUT.json")
    manifest = json.loads(Path(sys.argv[1]).read_text())
    threads = int(os.environ.get("OMP_NUM_THREADS", "0")) or None
    if threads:
        cv2.setNumThreads(threads)
    runs = {k: manifest[k] for k in ("repeat", "min_seconds", "max_runs")}
    rows = []
    for pair in manifest["pairs"]:
        for row in registration_rows(pair, manifest["params"], runs):
            rows.append({"pair": pair["name"], **row})
    rows += flow_rows(manifest.get("flow", []), runs)
    Path(sys.argv[2]).write_text(json.dumps({"threads": threads, "rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
