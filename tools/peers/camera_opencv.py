#!/usr/bin/env python3
"""Record OpenCV's projectPoints / undistortPoints on a few points as a fixture.

Output: fixtures/peers/camera_opencv.json, read by crates/flowfilter-camera/tests/opencv_reference.rs.
"""
import json
import pathlib

import cv2
import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]
OUT = ROOT / "fixtures" / "peers" / "camera_opencv.json"

# A BigBIRD-like colour camera (focal ~1081 px, principal point ~(621, 481)) with realistic distortion.
K = np.array([[1081.37, 0.0, 621.25], [0.0, 1080.91, 481.63], [0.0, 0.0, 1.0]])
D = np.array([0.0421, -0.1137, 0.00091, -0.00063, 0.0512])

rng = np.random.default_rng(7)
points = np.column_stack([
    rng.uniform(-0.35, 0.35, 12),
    rng.uniform(-0.3, 0.3, 12),
    rng.uniform(0.5, 1.5, 12),
])
proj, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), K, D)
proj = proj.reshape(-1, 2)

pixels = np.column_stack([rng.uniform(0, 1279, 12), rng.uniform(0, 1023, 12)])
und = cv2.undistortPoints(pixels.reshape(-1, 1, 2), K, D, P=K,
                          criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)).reshape(-1, 2)

OUT.parent.mkdir(parents=True, exist_ok=True)
OUT.write_text(json.dumps({
    "generator": f"tools/peers/camera_opencv.py with OpenCV {cv2.__version__}",
    "K": K.tolist(),
    "dist": D.tolist(),
    "points": points.tolist(),
    "projected": proj.tolist(),
    "pixels": pixels.tolist(),
    "undistorted": und.tolist(),
}, indent=1) + "\n")
print(f"wrote {OUT}")
