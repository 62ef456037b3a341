"""Test shapes shared by the peers harness and the benchmarks (numpy only)."""

import numpy as np


def bumpy_shape(n, rng):
    """n points on a closed bumpy surface about 14 x 10 x 12 cm."""
    z = rng.uniform(-1, 1, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    theta = np.arccos(z)
    r = 1.0 + 0.25 * np.sin(3 * theta) * np.cos(2 * phi) + 0.15 * np.sin(phi + 0.5)
    s = np.sqrt(1 - z * z)
    return np.column_stack([0.07 * r * s * np.cos(phi), 0.05 * r * s * np.sin(phi), 0.06 * r * z + 0.01 * np.cos(phi)])


def rotation(axis, deg):
    """The rotation by `deg` degrees about `axis` (Rodrigues)."""
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = np.deg2rad(deg)
    return np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * k @ k
