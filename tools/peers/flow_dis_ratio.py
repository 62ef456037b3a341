#!/usr/bin/env python3
"""Our DIS-medium against OpenCV's, timed in the same minutes.

The host's speed drifts by 20-30% over minutes, so timings taken in separate runs are not
comparable. This script alternates the two estimators on each Sintel pair: per round, OpenCV's
DIS-medium (2 threads, median of --runs calls after a warm-up) and then our `dis_timing` example
(a fresh process: its first call is dropped as the warm-up, median of the rest), and reports per
pair the median over rounds of each time and of the per-round ratio.

    cargo build --release -p flowfilter-flow --example dis_timing
    python3 tools/peers/flow_dis_ratio.py [--rounds 5] [--runs 7] [--gradients opencv_sobel|central]
"""
import argparse, os, statistics, subprocess, time
from pathlib import Path

import cv2


def median_ms(fn, runs):
    fn()  # warm-up
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        times.append(1000 * (time.perf_counter() - t))
    return statistics.median(times)


def ours_ms(binary, case, runs, gradients):
    env = dict(os.environ, N=str(runs + 1), GRADIENTS=gradients)
    out = subprocess.run([binary, case], env=env, capture_output=True, text=True, check=True).stdout
    times = [float(line.split()[0]) for line in out.splitlines() if line.endswith(" ms")]
    if len(times) != runs + 1:
        raise SystemExit(f"{binary} {case}: expected {runs + 1} timings, found {out!r}")
    return statistics.median(times[1:])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sintel", default="../shared/data/sintel")
    ap.add_argument("--binary", default="target/release/examples/dis_timing")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--gradients", default="opencv_sobel")
    args = ap.parse_args()
    if not Path(args.binary).exists():
        raise SystemExit(f"{args.binary} is missing: cargo build --release -p flowfilter-flow --example dis_timing")
    cv2.setNumThreads(2)
    print(f"DIS-medium, ours (search gradients {args.gradients}) vs OpenCV {cv2.__version__}, "
          f"{args.rounds} alternating rounds of {args.runs} runs")
    print("| pass/scene | ours ms | OpenCV ms | ratio (median of rounds) | ratio range |")
    print("| --- | --- | --- | --- | --- |")
    for pas in ["clean", "final"]:
        for scene in ["easy", "medium"]:
            d = Path(args.sintel) / pas / scene
            a = cv2.imread(str(d / "frame_0002.png"), cv2.IMREAD_GRAYSCALE)
            b = cv2.imread(str(d / "frame_0003.png"), cv2.IMREAD_GRAYSCALE)
            dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
            cv_times, our_times, ratios = [], [], []
            for _ in range(args.rounds):
                cv = median_ms(lambda: dis.calc(a, b, None), args.runs)
                ours = ours_ms(args.binary, f"{pas}/{scene}", args.runs, args.gradients)
                cv_times.append(cv)
                our_times.append(ours)
                ratios.append(ours / cv)
            print(f"| {pas}/{scene} | {statistics.median(our_times):.1f} | {statistics.median(cv_times):.1f} | "
                  f"{statistics.median(ratios):.2f}x | {min(ratios):.2f}-{max(ratios):.2f}x |", flush=True)


if __name__ == "__main__":
    main()
