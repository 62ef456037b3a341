#!/usr/bin/env python3
"""OpenCV optical-flow reference on the shared Sintel pairs.

Runs DIS (presets fast and medium) and pyramidal LK (calcOpticalFlowPyrLK, 21x21 window, 3 levels,
on a 16-px grid) with 2 threads, and records EPE (all pixels, non-occluded; LK at grid points, in
all and per point) and median time into fixtures/peers/flow_opencv.json. The Rust tests compare
against it.

    python3 tools/peers/flow_opencv.py [--sintel ../shared/data/sintel] [--out fixtures/peers/flow_opencv.json]
"""
import argparse, json, platform, time
from pathlib import Path

import cv2
import numpy as np


def read_flo(path):
    with open(path, "rb") as f:
        tag = np.frombuffer(f.read(4), np.float32)[0]
        assert abs(tag - 202021.25) < 1e-3, f"{path}: bad tag"
        w, h = np.frombuffer(f.read(8), np.int32)
        return np.frombuffer(f.read(), np.float32).reshape(h, w, 2)


def timed(fn, repeats):
    out, times = None, []
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return out, 1000 * float(np.median(times))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sintel", default="../shared/data/sintel")
    ap.add_argument("--out", default="fixtures/peers/flow_opencv.json")
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    cv2.setNumThreads(2)
    root = Path(args.sintel)
    cases = []
    for pas in ["clean", "final"]:
        for scene in ["easy", "medium"]:
            d = root / pas / scene
            a = cv2.imread(str(d / "frame_0002.png"), cv2.IMREAD_GRAYSCALE)
            b = cv2.imread(str(d / "frame_0003.png"), cv2.IMREAD_GRAYSCALE)
            gt = read_flo(d / "gt" / "frame_0002.flo")
            occ = cv2.imread(str(d / "gt" / "occlusions_0002.png"), 0)
            inv = cv2.imread(str(d / "gt" / "invalid_0002.png"), 0)
            noc = (occ < 128) & (inv < 128)
            case = {"pass": pas, "scene": scene}
            for preset, name in [(cv2.DISOPTICAL_FLOW_PRESET_FAST, "dis_fast"), (cv2.DISOPTICAL_FLOW_PRESET_MEDIUM, "dis_medium")]:
                dis = cv2.DISOpticalFlow_create(preset)
                dis.calc(a, b, None)  # warm-up
                f, ms = timed(lambda: dis.calc(a, b, None), args.repeats)
                e = np.linalg.norm(f - gt, axis=2)
                case[name] = {"epe_all": float(e.mean()), "epe_noc": float(e[noc].mean()), "ms": ms}
            h, w = a.shape
            ys, xs = np.mgrid[8:h - 8:16, 8:w - 8:16]
            pts = np.stack([xs.ravel(), ys.ravel()], 1).astype(np.float32).reshape(-1, 1, 2)
            lk = lambda: cv2.calcOpticalFlowPyrLK(
                a, b, pts, None, winSize=(21, 21), maxLevel=3,
                criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01))
            (nxt, st, _), ms = timed(lk, args.repeats)
            ok = st.ravel() == 1
            p = pts.reshape(-1, 2)
            est = (nxt.reshape(-1, 2) - p)
            truth = gt[p[:, 1].astype(int), p[:, 0].astype(int)]
            err = np.linalg.norm(est - truth, axis=1)
            # Per grid point (row-major): the endpoint error, or null where the tracker lost it;
            # comparisons are then made over the points both trackers keep.
            errors = [round(float(e), 4) if k else None for e, k in zip(err, ok)]
            case["lk"] = {"epe_points": float(err[ok].mean()), "tracked": int(ok.sum()), "points": int(len(ok)), "ms": ms,
                          "grid": {"step": 16, "offset": 8}, "errors": errors}
            cases.append(case)
            print(pas, scene, {k: v for k, v in case.items() if k not in ("pass", "scene")})
    out = {
        "tool": f"opencv-python {cv2.__version__}",
        "machine": f"{platform.machine()}, {platform.processor() or 'cpu'}, cv2.setNumThreads(2)",
        "cases": cases,
    }
    Path(args.out).write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
