"""Align two point clouds with every backend, as an Open3D or probreg user would.

    python examples/python/align_clouds.py [SOURCE.ply TARGET.ply]

Without arguments: a recorded peer case (a noisy bumpy shape with 20% outliers) and its true
motion. Prints each method's rotation error (when the truth is known), fitness and time.
"""

import json
import pathlib
import sys

import numpy as np

import flowfilter

ROOT = pathlib.Path(__file__).resolve().parents[2]
CASES = ROOT / "fixtures" / "peers" / "registration"


def rotation_error_deg(a, b):
    d = a[:3, :3] @ b[:3, :3].T
    return float(np.degrees(np.arccos(np.clip((np.trace(d) - 1) / 2, -1, 1))))


def main():
    if len(sys.argv) == 3:
        source_path, target_path, truth = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2]), None
    else:
        case = json.loads((CASES / "results.json").read_text())["cases"][4]
        source_path, target_path = CASES / f"{case['name']}_source.ply", CASES / f"{case['name']}_target.ply"
        truth = np.array(case["truth"])
        print(f"{case['name']}: {case['description']}")
    source, _ = flowfilter.read_ply(source_path)
    target, _ = flowfilter.read_ply(target_path)
    normals = flowfilter.estimate_normals(target, k=12)  # Open3D: KDTreeSearchParamKNN(12), towards the camera
    runs = {
        # Open3D's registration_icp(source, target, 0.25, np.eye(4), PointToPlane, ICPConvergenceCriteria(1e-6, 1e-6, 200))
        "icp-pt2pl": dict(max_correspondence_distance=0.25, max_iterations=200, min_update=0.0),
        # probreg's registration_filterreg(source, target, w=0.2) and registration_cpd(..., w=0.2)
        "filterreg-pt2pt": dict(w=0.2),
        "filterreg-pt2pl": dict(w=0.2),
        "cpd": dict(w=0.2),
    }
    print(f"{len(source)} -> {len(target)} points")
    for method, params in runs.items():
        r = flowfilter.register(source, target, method=method, init=np.eye(4), target_normals=normals, **params)
        error = f"{rotation_error_deg(r.transformation, truth):7.3f} deg" if truth is not None else "-"
        print(f"{method:>16}: rotation error {error}, fitness {r.fitness:.3f}, {r.iterations:3d} iterations, "
              f"{r.seconds * 1e3:7.1f} ms")


if __name__ == "__main__":
    main()
