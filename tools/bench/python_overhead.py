#!/usr/bin/env python3
"""The Python binding's per-call overhead: `flowfilter.register` timed from Python against the
time spent inside the backend (`RegistrationResult.seconds`), on clouds of 50k points.

    pip install .            # the package, release build
    python tools/bench/python_overhead.py [--points 50000] [--repeat 5] [--threads 1,2]

The overhead is everything the call does besides registering: checking and copying the arrays
(float64 C order, float32, Fortran order), the parameters, the result. Prints a Markdown table
(the figures in docs/python.md) with the median of `--repeat` calls per row.
"""

import argparse
import pathlib
import statistics
import sys
import time

import numpy as np

import flowfilter

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "peers"))
from shapes import bumpy_shape, rotation  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--points", type=int, default=50000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--threads", default="1,2")
    a = ap.parse_args()
    rng = np.random.default_rng(5)
    shape = bumpy_shape(a.points, rng)
    rot = rotation(np.array([0.3, -0.5, 0.8]), 10.0)
    source = shape + rng.normal(scale=0.001, size=shape.shape)
    target = shape @ rot.T + np.array([0.01, -0.005, 0.008]) + rng.normal(scale=0.001, size=shape.shape)
    normals = flowfilter.estimate_normals(target)
    layouts = {
        "float64": lambda x: x,
        "float32": lambda x: x.astype(np.float32),
        "fortran": np.asfortranarray,
    }
    methods = {
        "icp-pt2pl": dict(max_correspondence_distance=0.05, max_iterations=30, min_update=0.0),
        "filterreg-pt2pt": {},
        "filterreg-pt2pl": {},
    }
    print(f"{a.points} points, median of {a.repeat} calls per row (flowfilter {flowfilter.__version__})\n")
    print("| method | threads | input | call (ms) | in the backend (ms) | overhead (ms) | overhead share |")
    print("|---|---|---|---|---|---|---|")
    for threads in [int(t) for t in a.threads.split(",")]:
        flowfilter.set_num_threads(threads)
        for method, params in methods.items():
            for layout, convert in layouts.items():
                s, t, n = convert(source), convert(target), convert(normals)
                calls, inside = [], []
                for _ in range(a.repeat):
                    t0 = time.perf_counter()
                    r = flowfilter.register(s, t, method=method, target_normals=n, **params)
                    calls.append(time.perf_counter() - t0)
                    inside.append(r.seconds)
                call, backend = statistics.median(calls), statistics.median(inside)
                overhead = statistics.median(c - i for c, i in zip(calls, inside))
                print(f"| {method} | {threads} | {layout} | {call * 1e3:.1f} | {backend * 1e3:.1f} | {overhead * 1e3:.2f} | "
                      f"{overhead / call * 100:.2f}% |")
    flowfilter.set_num_threads(0)


if __name__ == "__main__":
    main()
