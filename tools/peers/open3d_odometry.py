"""Open3D's RGB-D odometry against `flowfilter track` on whole frames of posed sequences.

For each sequence folder (frame-NNNNNN.color.png, frame-NNNNNN.depth.png, camera.json with the
depth camera's own intrinsics and `color_from_depth`, poses.json with calibrated camera poses):

- Open3D 0.20's `compute_rgbd_odometry` (hybrid photometric + geometric term, its default
  options) between consecutive frames, chained into the scene's motion from the first frame
  `T_0k` (P_k = T_0k P_0). Open3D needs depth on the colour grid: the raw depth is registered
  onto the colour camera here (each depth pixel back-projected with the depth camera, moved by
  `color_from_depth`, projected into the colour camera, the nearest kept), as our depth stage
  does it;
- `flowfilter track` (whole frames, no mask) on the same frames, its `--tum` output;
- both scored the same way against the truth `T_0k = inv(C_k) C_0`: ATE (position RMSE after
  the rigid alignment of the positions, as `evo_ape --align`), RPE over one frame (rotation,
  degrees) and the last frame's rotation error.

    python3 tools/peers/open3d_odometry.py ../shared/data/realsense-shelf/shelf-A [more ...] \
        [--flowfilter target/release/flowfilter] [--max-frames N]

Needs numpy and open3d (tools/peers/requirements.txt; the open3d wheel needs Debian's
libusb-1.0-0). Prints one table row per sequence and method.
"""

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import open3d as o3d


def register_depth(depth_mm, camera):
    """Raw depth (uint16 mm, depth camera grid) -> metres on the colour grid (0 = none)."""
    kd = np.array(camera["depth"]["K"], dtype=float)
    kc = np.array(camera["K"], dtype=float)
    c_from_d = np.array(camera["color_from_depth"], dtype=float)
    unit = camera.get("depth_unit_m", 0.001)
    h, w = depth_mm.shape
    v, u = np.nonzero(depth_mm)
    z = depth_mm[v, u].astype(float) * unit
    pts = np.stack([(u - kd[0, 2]) / kd[0, 0] * z, (v - kd[1, 2]) / kd[1, 1] * z, z], axis=1)
    pts = pts @ c_from_d[:3, :3].T + c_from_d[:3, 3]
    front = pts[:, 2] > 0
    pts = pts[front]
    uc = np.round(kc[0, 0] * pts[:, 0] / pts[:, 2] + kc[0, 2]).astype(int)
    vc = np.round(kc[1, 1] * pts[:, 1] / pts[:, 2] + kc[1, 2]).astype(int)
    inside = (uc >= 0) & (uc < camera["width"]) & (vc >= 0) & (vc < camera["height"])
    uc, vc, zc = uc[inside], vc[inside], pts[inside, 2]
    out = np.full((camera["height"], camera["width"]), np.inf)
    np.minimum.at(out, (vc, uc), zc)
    out[np.isinf(out)] = 0.0
    return out.astype(np.float32)


def rgbd(folder, n, camera):
    color = o3d.io.read_image(str(folder / f"frame-{n:06d}.color.png"))
    depth_mm = np.asarray(o3d.io.read_image(str(folder / f"frame-{n:06d}.depth.png")))
    depth = o3d.geometry.Image(register_depth(depth_mm, camera))
    return o3d.geometry.RGBDImage.create_from_color_and_depth(
        color, depth, depth_scale=1.0, depth_trunc=3.0, convert_rgb_to_intensity=True
    )


def open3d_track(folder, numbers, camera):
    """T_0k per frame by chained consecutive odometry, and the seconds per pair."""
    kc = np.array(camera["K"], dtype=float)
    intrinsic = o3d.camera.PinholeCameraIntrinsic(
        camera["width"], camera["height"], kc[0, 0], kc[1, 1], kc[0, 2], kc[1, 2]
    )
    poses, seconds = [np.eye(4)], []
    previous = rgbd(folder, numbers[0], camera)
    for n in numbers[1:]:
        current = rgbd(folder, n, camera)
        start = time.perf_counter()
        ok, step, _ = o3d.pipelines.odometry.compute_rgbd_odometry(
            previous,
            current,
            intrinsic,
            np.eye(4),
            o3d.pipelines.odometry.RGBDOdometryJacobianFromHybridTerm(),
            o3d.pipelines.odometry.OdometryOption(),
        )
        seconds.append(time.perf_counter() - start)
        # A failed pair keeps the pose (what a tracker reporting "lost" does).
        poses.append(step @ poses[-1] if ok else poses[-1])
        previous = current
    return poses, seconds


def read_tum(path):
    poses = []
    for line in Path(path).read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        t, x, y, z, qx, qy, qz, qw = map(float, line.split())
        r = quaternion_matrix(qx, qy, qz, qw)
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = r, [x, y, z]
        poses.append(m)
    return poses


def quaternion_matrix(x, y, z, w):
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def flowfilter_track(binary, folder, n_frames):
    with tempfile.TemporaryDirectory() as tmp:
        tum = Path(tmp) / "track.tum"
        start = time.perf_counter()
        subprocess.run(
            [binary, "track", "--frames", str(folder), "--camera", str(folder / "camera.json"),
             "--max-frames", str(n_frames), "--tum", str(tum)],
            check=True, capture_output=True,
        )
        elapsed = time.perf_counter() - start
        return read_tum(tum), elapsed


def rotation_deg(r):
    return np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1)))


def scores(poses, truth):
    """ATE (m, positions rigidly aligned, as evo_ape --align), RPE over one frame (deg), last (deg)."""
    est = np.array([p[:3, 3] for p in poses])
    ref = np.array([t[:3, 3] for t in truth])
    me, mr = est.mean(0), ref.mean(0)
    u, _, vt = np.linalg.svd((ref - mr).T @ (est - me))
    d = np.diag([1, 1, np.sign(np.linalg.det(u @ vt))])
    r = u @ d @ vt
    aligned = (est - me) @ r.T + mr
    ate = float(np.sqrt(((aligned - ref) ** 2).sum(1).mean()))
    rpe = [
        rotation_deg((np.linalg.inv(poses[k - 1]) @ poses[k])[:3, :3].T @ (np.linalg.inv(truth[k - 1]) @ truth[k])[:3, :3])
        for k in range(1, len(poses))
    ]
    last = rotation_deg(poses[-1][:3, :3].T @ truth[-1][:3, :3])
    return ate, float(np.sqrt(np.mean(np.square(rpe)))), float(last)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sequences", nargs="+", type=Path)
    ap.add_argument("--flowfilter", default="target/release/flowfilter")
    ap.add_argument("--max-frames", type=int, default=0)
    args = ap.parse_args()
    print(f"open3d {o3d.__version__}")
    print("| sequence | frames | method | ATE (m) | RPE rot (deg, RMS) | last frame rot (deg) | s per frame |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for folder in args.sequences:
        camera = json.loads((folder / "camera.json").read_text())
        calibrated = json.loads((folder / "poses.json").read_text())["camera_to_world_calibrated"]
        numbers = sorted(int(k) for k in calibrated)
        if args.max_frames:
            numbers = numbers[: args.max_frames]
        c = {int(k): np.array(v, dtype=float) for k, v in calibrated.items()}
        truth = [np.linalg.inv(c[n]) @ c[numbers[0]] for n in numbers]
        o3d_poses, o3d_seconds = open3d_track(folder, numbers, camera)
        ours, ours_seconds = flowfilter_track(args.flowfilter, folder, len(numbers))
        rows = [
            ("Open3D RGB-D odometry (hybrid)", o3d_poses, sum(o3d_seconds) / max(len(o3d_seconds), 1)),
            ("flowfilter track (whole frames)", ours, ours_seconds / max(len(numbers) - 1, 1)),
        ]
        for name, poses, secs in rows:
            ate, rpe, last = scores(poses, truth)
            print(f"| {folder.name} | {len(numbers)} | {name} | {ate:.4f} | {rpe:.2f} | {last:.2f} | {secs:.2f} |")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
