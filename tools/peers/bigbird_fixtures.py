#!/usr/bin/env python3
"""Write tiny BigBIRD-layout object directories with h5py, in both HDF5 file formats.

Output: fixtures/bigbird/{earliest,latest}/tiny_spheres/ (about 100 KB each). The scene is two
spheres standing off-centre on a turntable disc, ray-cast analytically here (independently of
the Rust code) with the frame conventions of shared/docs/bigbird-format.md:

  H_NP{c}_from_table(a) = H_NP{c}_from_NP5 * inv(H_table_from_reference_camera(a))

The Rust tests read these files with `hdf5-reader`, which proves we read what libhdf5 writes in
the oldest (superblock 0, v1 object headers, contiguous) and newest (superblock 3, v2 headers,
chunked + gzip) formats, and check the ground-truth motion direction against the masks.
"""
import pathlib
import shutil

import cv2
import h5py
import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]
OUT = ROOT / "fixtures" / "bigbird"
CAMERAS = [1, 5]
ANGLES = [0, 3, 30]
COLOR_SIZE = (160, 128)  # width, height (BigBIRD: 1280x1024, scaled by 1/8)
DEPTH_SIZE = (80, 60)  # width, height (BigBIRD: 640x480, scaled by 1/8)
K_RGB = np.array([[135.17, 0.0, 79.62], [0.0, 135.11, 63.45], [0.0, 0.0, 1.0]])
D_RGB = np.array([0.0421, -0.1137, 0.00091, -0.00063, 0.0512])
K_IR = np.array([[72.4, 0.0, 39.5], [0.0, 72.3, 29.5], [0.0, 0.0, 1.0]])
DEPTH_SCALE = 1.0125  # raw * scale * 1e-4 = metres
IR_OFFSET = 0.025  # the IR camera sits 2.5 cm along the colour camera's -x axis
SPHERES = [((0.09, 0.0, 0.06), 0.06), ((-0.06, 0.07, 0.035), 0.035)]  # table frame, metres
DISC_RADIUS = 0.25


def rot_z(deg):
    a = np.deg2rad(deg)
    m = np.eye(4)
    m[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    return m


def look_at(position, target):
    """H_cam_from_world for an OpenCV camera (x right, y down, z forward) at `position`."""
    z = target - position
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    h = np.eye(4)
    h[:3, :3] = np.stack([x, y, z])  # rows: camera axes in world coordinates
    h[:3, 3] = -h[:3, :3] @ position
    return h


def camera_from_world(c):
    """Camera c of the rig: elevation from ~10 deg (NP1) to ~80 deg (NP5), 0.7-0.8 m away."""
    elevation = np.deg2rad([10.0, 28.0, 45.0, 62.0, 80.0][c - 1])
    dist = 0.8 - 0.02 * c
    pos = np.array([0.01 * c, -dist * np.cos(elevation), 0.05 + dist * np.sin(elevation)])
    return look_at(pos, np.array([0.0, 0.0, 0.05]))


def ray_cast(dirs_cam, h_table_from_cam):
    """Nearest hit of rays (N,3 with z=1) from the camera centre; returns depth z and hit points (table frame), id."""
    r = h_table_from_cam[:3, :3]
    o = h_table_from_cam[:3, 3]
    d = dirs_cam @ r.T
    n = d.shape[0]
    best = np.full(n, np.inf)
    ident = np.full(n, -1)
    for k, (c, rad) in enumerate(SPHERES):
        oc = o - np.array(c)
        b = d @ oc
        a = np.einsum("ij,ij->i", d, d)
        disc = b * b - a * (oc @ oc - rad * rad)
        t = (-b - np.sqrt(np.maximum(disc, 0.0))) / a
        hit = (disc > 0) & (t > 0) & (t < best)
        best[hit] = t[hit]
        ident[hit] = k
    t = -o[2] / d[:, 2]
    p = o + t[:, None] * d
    hit = (t > 0) & (t < best) & (np.hypot(p[:, 0], p[:, 1]) < DISC_RADIUS)
    best[hit] = t[hit]
    ident[hit] = 99
    points = o + best[:, None] * d
    return best, points, ident


def pixel_grid(width, height):
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    return np.column_stack([u.ravel(), v.ravel()])


def write_pbm(path, mask):
    """Binary PBM (P4): bit 1 = black = object, rows padded to whole bytes."""
    h, w = mask.shape
    packed = np.packbits(mask.astype(np.uint8), axis=1)
    path.write_bytes(f"P4\n{w} {h}\n".encode() + packed.tobytes())


def write_object(root, libver):
    obj = root / "tiny_spheres"
    if obj.exists():
        shutil.rmtree(obj)
    (obj / "masks").mkdir(parents=True)
    (obj / "poses").mkdir()
    h_world_from = {c: np.linalg.inv(camera_from_world(c)) for c in range(1, 6)}
    h_from_np5 = {c: camera_from_world(c) @ h_world_from[5] for c in range(1, 6)}
    h_ir_from_rgb = np.eye(4)
    h_ir_from_rgb[0, 3] = IR_OFFSET
    chunked = dict(chunks=(30, 40), compression="gzip", compression_opts=4) if libver == "latest" else {}

    with h5py.File(obj / "calibration.h5", "w", libver=libver) as f:
        for c in range(1, 6):
            f[f"NP{c}_rgb_K"] = K_RGB
            f[f"NP{c}_rgb_d"] = D_RGB
            # Older captures name the depth intrinsics `_depth_K`; both names are accepted.
            f[f"NP{c}_{'ir' if c % 2 else 'depth'}_K"] = K_IR
            f[f"NP{c}_ir_depth_scale"] = np.array([DEPTH_SCALE])
            f[f"NP{c}_ir_depth_bias"] = np.array([0.0])
            f[f"H_NP{c}_from_NP5"] = h_from_np5[c]
            f[f"H_NP{c}_ir_from_NP5"] = h_ir_from_rgb @ h_from_np5[c]
    with h5py.File(obj / "poses" / "turntable.h5", "w", libver=libver) as f:
        h_np5_from_world = camera_from_world(5)
        f["center"] = h_np5_from_world[:3, 3]
        f["normal"] = h_np5_from_world[:3, 2]

    colour_pixels = pixel_grid(*COLOR_SIZE)
    normalized = cv2.undistortPoints(colour_pixels.reshape(-1, 1, 2), K_RGB, D_RGB).reshape(-1, 2)
    colour_rays = np.column_stack([normalized, np.ones(len(normalized))])
    depth_pixels = pixel_grid(*DEPTH_SIZE)
    depth_rays = np.column_stack([(depth_pixels - K_IR[:2, 2]) / np.diag(K_IR)[:2], np.ones(len(depth_pixels))])

    for a in ANGLES:
        h_table_from_np5 = rot_z(-a) @ h_world_from[5]
        with h5py.File(obj / "poses" / f"NP5_{a}_pose.h5", "w", libver=libver) as f:
            f["H_table_from_reference_camera"] = h_table_from_np5
            f["board_frame_offset"] = np.array([0.0, 0.0, 0.0])
        for c in CAMERAS:
            h_cam_from_table = h_from_np5[c] @ np.linalg.inv(h_table_from_np5)
            # Colour image and mask on the colour grid.
            _, pts, ident = ray_cast(colour_rays, np.linalg.inv(h_cam_from_table))
            w, h = COLOR_SIZE
            with np.errstate(invalid="ignore"):
                checker = ((np.floor(pts[:, 0] / 0.03) + np.floor(pts[:, 1] / 0.03) + np.floor(pts[:, 2] / 0.03)) % 2)
            bgr = np.full((len(ident), 3), 235.0)
            bgr[ident == 99] = 150.0
            obj_hit = (ident >= 0) & (ident < 99)
            bgr[obj_hit] = np.where(checker[obj_hit, None] > 0, [30.0, 40.0, 210.0], [40.0, 150.0, 230.0])
            cv2.imwrite(str(obj / f"NP{c}_{a}.jpg"), bgr.reshape(h, w, 3).astype(np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 90])
            write_pbm(obj / "masks" / f"NP{c}_{a}_mask.pbm", obj_hit.reshape(h, w))
            # Raw depth from the IR camera.
            h_ir_from_table = h_ir_from_rgb @ h_cam_from_table
            z, _, ident = ray_cast(depth_rays, np.linalg.inv(h_ir_from_table))
            raw = np.where(np.isfinite(z), np.round(z / (DEPTH_SCALE * 1e-4)), 0).astype(np.uint16)
            w, h = DEPTH_SIZE
            with h5py.File(obj / f"NP{c}_{a}.h5", "w", libver=libver) as f:
                f.create_dataset("depth", data=raw.reshape(h, w), **chunked)
    print(f"wrote {obj}")


if __name__ == "__main__":
    for libver in ["earliest", "latest"]:
        write_object(OUT / libver, libver)
