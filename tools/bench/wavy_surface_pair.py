"""A Kinect-sized registration pair with a known motion, for timing CPD on full clouds.

Writes SOURCE.ply (60k points of a wavy 1.2 x 0.9 m surface 1.5 m away, 2 mm noise), TARGET.ply
(55k points of the same surface moved by 4 deg about x, 2 deg about y and a few centimetres,
resampled, 2 mm noise) and TRUTH.txt (the 4x4 source-to-target transform, row-major) into DIR.
Seeded: the same files on every run.

    python3 tools/bench/wavy_surface_pair.py DIR
    flowfilter register --source DIR/source.ply --target DIR/target.ply \
        --config configs/cpd-full-cloud.toml --json
Needs numpy and scipy.
"""

import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation


def write_ply(path, points):
    with open(path, "w") as f:
        f.write(
            f"ply\nformat ascii 1.0\nelement vertex {len(points)}\n"
            "property float x\nproperty float y\nproperty float z\nend_header\n"
        )
        np.savetxt(f, points, fmt="%.6f")


def main():
    out = Path(sys.argv[1])
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(7)
    n = 60000
    u, v = rng.uniform(-0.6, 0.6, n), rng.uniform(-0.45, 0.45, n)
    z = 1.5 + 0.05 * np.sin(6 * u) * np.cos(5 * v) + 0.03 * np.sin(11 * v)
    source = np.stack([u, v, z], 1)
    rotation = Rotation.from_euler("xyz", [4, 2, 0], degrees=True)
    shift = np.array([0.02, -0.01, 0.015])
    centre = source.mean(0)
    target = rotation.apply(source - centre) + centre + shift + rng.normal(0, 0.002, source.shape)
    source = source + rng.normal(0, 0.002, source.shape)
    target = target[rng.choice(n, 55000, replace=False)]
    write_ply(out / "source.ply", source)
    write_ply(out / "target.ply", target)
    truth = np.eye(4)
    truth[:3, :3] = rotation.as_matrix()
    truth[:3, 3] = shift + centre - rotation.apply(centre)
    np.savetxt(out / "truth.txt", truth)


if __name__ == "__main__":
    main()
