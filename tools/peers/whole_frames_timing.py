"""Whole 640x480 RGB-D frames: Open3D's coloured ICP against `flowfilter estimate`, same pairs, same minutes.

For each sequence folder (frame-NNNNNN.color.png, frame-NNNNNN.depth.png, camera.json with the
depth camera's own intrinsics and `color_from_depth`, poses.json with calibrated camera poses),
every pair of frames `gap` apart (`--gaps`, default 1,2) is registered whole (no mask) by:

- Open3D 0.20's multi-scale coloured ICP as its tutorial runs it (voxels of 4, 2 and 1 cm; 50,
  30 and 14 iterations; normals from 30 neighbours within twice the voxel; relative fitness and
  RMSE 1e-6), from the identity. Timed from the two RGB-D images to the answer: both clouds,
  their downsampling and normals, the three scales. The raw depth is registered onto the colour
  grid beforehand, untimed (by `open3d_odometry.register_depth`); ours does that inside its
  timing;
- Flow Filter (defaults) and FilterReg point-to-plane (`--method filterreg-pt2pl`), two ways:
  - in this process, as Open3D runs: the Python package's `flowfilter.estimate` on the two
    frames (`flowfilter.read_frame`, untimed, as Open3D's reading), timed around the call (both
    frames' depth stage included), with `flowfilter.set_num_threads`. Needs the package
    (`pip install .` from the repository root); without it these rows are left out;
  - `flowfilter estimate`, a fresh process per pair: the `stage_ms.total` the CLI reports (file
    reading not included). A fresh process also pays for the first touch of every page it
    allocates (about 130 MB on a whole-frame pair);
  - Flow Filter also from the very input Open3D gets ("registered depth" rows): the colour image
    and the depth Open3D reads (registered onto the colour grid by the same function, untimed),
    as `flowfilter.Frame` arrays with the colour camera alone, so that neither side's time holds
    the registration of depth onto colour.

The two sides alternate pair by pair, under one thread count at a time (`--threads`, default
1,2: `RAYON_NUM_THREADS` for ours, `OMP_NUM_THREADS` for Open3D, set before it is imported).
Errors are against the calibrated poses, `T = inv(C_b) C_a`; success is under 2 deg and 1 cm.

    python3 tools/peers/whole_frames_timing.py ../shared/data/realsense-shelf/shelf-A [more ...] \
        [--flowfilter target/release/flowfilter] [--gaps 1,2] [--threads 1,2] [--json OUT]

Needs numpy and open3d (tools/peers/requirements.txt; the open3d wheel needs Debian's
libusb-1.0-0). Prints one Markdown row per thread count and method, and per-pair rows with
`--pairs`.
"""

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def open3d_pair(o3d, folder, a, b, camera):
    """Open3D's multi-scale coloured ICP of frame a onto frame b: (T, seconds)."""
    from open3d_odometry import register_depth  # the same registration of depth onto colour

    kc = np.array(camera["K"], dtype=float)
    intrinsic = o3d.camera.PinholeCameraIntrinsic(camera["width"], camera["height"], kc[0, 0], kc[1, 1], kc[0, 2], kc[1, 2])

    def rgbd(n):
        color = o3d.io.read_image(str(folder / f"frame-{n:06d}.color.png"))
        depth = np.asarray(o3d.io.read_image(str(folder / f"frame-{n:06d}.depth.png")))
        return o3d.geometry.RGBDImage.create_from_color_and_depth(
            color, o3d.geometry.Image(register_depth(depth, camera)), depth_scale=1.0, depth_trunc=3.0,
            convert_rgb_to_intensity=False,
        )

    images = rgbd(a), rgbd(b)
    start = time.perf_counter()
    source, target = (o3d.geometry.PointCloud.create_from_rgbd_image(i, intrinsic) for i in images)
    transform = np.eye(4)
    for radius, iterations in zip([0.04, 0.02, 0.01], [50, 30, 14]):
        s, t = source.voxel_down_sample(radius), target.voxel_down_sample(radius)
        for c in (s, t):
            c.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius * 2, max_nn=30))
        result = o3d.pipelines.registration.registration_colored_icp(
            s, t, radius, transform,
            o3d.pipelines.registration.TransformationEstimationForColoredICP(),
            o3d.pipelines.registration.ICPConvergenceCriteria(
                relative_fitness=1e-6, relative_rmse=1e-6, max_iteration=iterations
            ),
        )
        transform = result.transformation
    return np.asarray(transform), time.perf_counter() - start


def ours_pair(binary, folder, a, b, method):
    """`flowfilter estimate` on the whole frames: (T, seconds as stage_ms.total, converged)."""
    f = lambda n, kind: str(folder / f"frame-{n:06d}.{kind}.png")
    cmd = [binary, "estimate", "--camera", str(folder / "camera.json"), "--model-color", f(a, "color"),
           "--model-depth", f(a, "depth"), "--target-color", f(b, "color"), "--target-depth", f(b, "depth"), "--json"]
    if method:
        cmd += ["--method", method]
    out = subprocess.run(cmd, check=False, capture_output=True, text=True)
    if not out.stdout.strip():
        raise RuntimeError(f"{' '.join(cmd)}: {out.stderr.strip()}")
    e = json.loads(out.stdout)
    return np.array(e["transform"], dtype=float), e["stage_ms"]["total"] / 1e3, e["registration"]["converged"]


def library_pair(flowfilter, folder, a, b, method, camera):
    """`flowfilter.estimate` in this process on the whole frames: (T, seconds around the call)."""
    f = lambda n, kind: str(folder / f"frame-{n:06d}.{kind}.png")
    model, target = (flowfilter.read_frame(f(n, "color"), f(n, "depth"), camera) for n in (a, b))
    start = time.perf_counter()
    e = flowfilter.estimate(model, target, camera, method=method or "flowfilter")
    return np.asarray(e.transform, dtype=float), time.perf_counter() - start


def registered_pair(o3d, flowfilter, folder, a, b, method, camera):
    """`flowfilter.estimate` from the colour image and the registered depth Open3D reads:
    (T, seconds around the call)."""
    from open3d_odometry import register_depth

    colour_camera = flowfilter.Camera(camera["K"], width=camera["width"], height=camera["height"])

    def frame(n):
        color = np.ascontiguousarray(np.asarray(o3d.io.read_image(str(folder / f"frame-{n:06d}.color.png")))[:, :, :3])
        depth = np.asarray(o3d.io.read_image(str(folder / f"frame-{n:06d}.depth.png")))
        return flowfilter.Frame(color, register_depth(depth, camera), name=f"{n}")

    model, target = frame(a), frame(b)
    start = time.perf_counter()
    e = flowfilter.estimate(model, target, colour_camera, method=method or "flowfilter")
    return np.asarray(e.transform, dtype=float), time.perf_counter() - start


def errors(t, truth):
    from open3d_odometry import rotation_deg

    angle = rotation_deg(t[:3, :3].T @ truth[:3, :3])
    return float(angle), float(np.linalg.norm(t[:3, 3] - truth[:3, 3]))


METHODS = [("Open3D coloured ICP", None, None), ("Flow Filter", "", "library"),
           ("FilterReg point-to-plane", "filterreg-pt2pl", "library"),
           ("Flow Filter (CLI)", "", "cli"), ("FilterReg point-to-plane (CLI)", "filterreg-pt2pl", "cli"),
           ("Flow Filter, registered depth", "", "registered")]


def worker(args):
    """One thread count: every pair by every method, alternating; JSON lines on stdout."""
    import open3d as o3d

    try:
        import flowfilter

        flowfilter.set_num_threads(args.worker)
    except ImportError:
        flowfilter = None
    for folder in args.sequences:
        camera = json.loads((folder / "camera.json").read_text())
        ff_camera = flowfilter.read_camera(folder / "camera.json") if flowfilter else None
        poses = json.loads((folder / "poses.json").read_text())["camera_to_world_calibrated"]
        c = {int(k): np.array(v, dtype=float) for k, v in poses.items()}
        numbers = sorted(c)
        for gap in args.gaps:
            for a, b in zip(numbers, numbers[gap:]):
                truth = np.linalg.inv(c[b]) @ c[a]
                for name, method, way in METHODS:
                    if way is None:
                        t, secs = open3d_pair(o3d, folder, a, b, camera)
                    elif way == "library":
                        if flowfilter is None:
                            continue
                        t, secs = library_pair(flowfilter, folder, a, b, method, ff_camera)
                    elif way == "registered":
                        if flowfilter is None:
                            continue
                        t, secs = registered_pair(o3d, flowfilter, folder, a, b, method, camera)
                    else:
                        t, secs, _ = ours_pair(args.flowfilter, folder, a, b, method)
                    rot, trans = errors(t, truth)
                    row = dict(sequence=folder.name, a=a, b=b, gap=gap, method=name, seconds=secs,
                               rotation_error_deg=rot, translation_error_m=trans)
                    print(json.dumps(row), flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sequences", nargs="+", type=Path)
    ap.add_argument("--flowfilter", default="target/release/flowfilter")
    ap.add_argument("--gaps", default="1,2")
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--json", type=Path, help="write every pair's row here (JSON lines)")
    ap.add_argument("--pairs", action="store_true", help="also print one row per pair")
    ap.add_argument("--worker", type=int, default=0, help=argparse.SUPPRESS)
    args = ap.parse_args()
    args.gaps = [int(g) for g in args.gaps.split(",")]
    if args.worker:
        worker(args)
        return
    rows = []
    for threads in [int(t) for t in args.threads.split(",")]:
        env = dict(os.environ, RAYON_NUM_THREADS=str(threads), OMP_NUM_THREADS=str(threads))
        cmd = [sys.executable, __file__, *map(str, args.sequences), "--flowfilter", args.flowfilter,
               "--gaps", ",".join(map(str, args.gaps)), "--worker", str(threads)]
        out = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True).stdout
        rows += [dict(json.loads(line), threads=threads) for line in out.splitlines() if line.strip()]
    if args.json:
        args.json.write_text("".join(json.dumps(r) + "\n" for r in rows))
    print("| threads | method | pairs | median s | mean s | max s | median / Open3D's | success | median error (deg) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for threads in sorted({r["threads"] for r in rows}):
        of = lambda name: [r for r in rows if r["threads"] == threads and r["method"] == name]
        peer = np.median([r["seconds"] for r in of(METHODS[0][0])])
        for name, _, _ in METHODS:
            rs = of(name)
            if not rs:
                continue
            secs = np.array([r["seconds"] for r in rs])
            ok = sum(r["rotation_error_deg"] < 2.0 and r["translation_error_m"] < 0.01 for r in rs)
            err = np.median([r["rotation_error_deg"] for r in rs])
            print(f"| {threads} | {name} | {len(rs)} | {np.median(secs):.3f} | {secs.mean():.3f} | {secs.max():.3f} | "
                  f"{np.median(secs) / peer:.2f}x | {ok}/{len(rs)} | {err:.2f} |")
    if args.pairs:
        for r in rows:
            print(f"{r['threads']} {r['sequence']} {r['a']}->{r['b']} {r['method']}: {r['seconds']:.3f} s, "
                  f"{r['rotation_error_deg']:.2f} deg, {r['translation_error_m'] * 1000:.1f} mm")


if __name__ == "__main__":
    main()
