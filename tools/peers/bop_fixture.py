#!/usr/bin/env python3
"""Write a tiny BOP-layout scene for the reader's tests, independently of the Rust code.

    python3 tools/peers/bop_fixture.py fixtures/bop

Writes `fixtures/bop/000001/` as the BOP toolkit's scene-wise format has it
(docs/bop_datasets_format.md of bop_toolkit): `scene_camera.json` (cam_K row-wise, depth_scale:
depth PNG x depth_scale = millimetres), `scene_gt.json` (cam_R_m2c row-wise, cam_t_m2c in
millimetres, obj_id), `scene_gt_info.json` (visib_fract and pixel counts), `rgb/{im:06d}.png`,
`depth/{im:06d}.png` (16-bit), `mask_visib/{im:06d}_{gt:06d}.png`. Two objects: a textured
square plate (obj_id 7) seen in three images while the camera moves around it, and a small box
(obj_id 3) that is in images 0 and 1 only. `truth.json` records, per image pair, the object's
relative motion T_ab = T_cam_b_from_obj * inv(T_cam_a_from_obj) computed here with numpy-free
matrix code, for the tests to compare against. Only the Python standard library is used (PNG
written with zlib).
"""

import json
import math
import struct
import sys
import zlib
from pathlib import Path

W, H = 64, 48
FX, FY, CX, CY = 60.0, 61.0, 31.5, 23.5
DEPTH_SCALE = 0.1  # depth PNG units are 0.1 mm


def png(path, rows, bit_depth, channels):
    """Write a PNG (colour type 0 grey or 2 RGB) from rows of integer samples."""
    colour_type = {1: 0, 3: 2}[channels]
    raw = b""
    for row in rows:
        raw += b"\x00"
        if bit_depth == 16:
            raw += b"".join(struct.pack(">H", v) for v in row)
        else:
            raw += bytes(row)
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
    header = struct.pack(">IIBBBBB", W, H, bit_depth, colour_type, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(len(b))) for j in range(len(b[0]))] for i in range(len(a))]


def rot_y(deg):
    t = math.radians(deg)
    return [[math.cos(t), 0, math.sin(t)], [0, 1, 0], [-math.sin(t), 0, math.cos(t)]]


def rot_x(deg):
    t = math.radians(deg)
    return [[1, 0, 0], [0, math.cos(t), -math.sin(t)], [0, math.sin(t), math.cos(t)]]


def pose(r, t_mm):
    return [r[0] + [t_mm[0]], r[1] + [t_mm[1]], r[2] + [t_mm[2]], [0, 0, 0, 1]]


def inverse(m):
    r = [[m[j][i] for j in range(3)] for i in range(3)]
    t = [-sum(r[i][k] * m[k][3] for k in range(3)) for i in range(3)]
    return pose(r, t)


def main():
    out = Path(sys.argv[1] if len(sys.argv) > 1 else "fixtures/bop") / "000001"
    for d in ["rgb", "depth", "mask_visib"]:
        (out / d).mkdir(parents=True, exist_ok=True)
    # The plate: a 200 mm square in its own x-y plane, 400 mm in front of the camera, turned a
    # little more in every image; the box: a 30 mm square nearer the camera, partly in front
    # of the plate.
    plate_poses = [pose(matmul(rot_y(a), rot_x(5)), [0, 0, 400]) for a in (0, 4, 9)]
    box_poses = [pose(rot_y(a), [-60, 40, 380]) for a in (0, 4)]
    camera, gt, info = {}, {}, {}
    for im, plate in enumerate(plate_poses):
        depth = [[0] * W for _ in range(H)]
        rgb = [[0] * (3 * W) for _ in range(H)]
        label = [[0] * W for _ in range(H)]
        seen_all = {}
        objects = [(7, plate, 100.0)] + ([(3, box_poses[im], 15.0)] if im < len(box_poses) else [])
        for v in range(H):
            for u in range(W):
                ray = [(u - CX) / FX, (v - CY) / FY, 1.0]
                best = None
                for k, (obj_id, m, half) in enumerate(objects):
                    # Intersect the ray with the object's z = 0 plane (a square of side 2 half).
                    n = [m[0][2], m[1][2], m[2][2]]
                    p0 = [m[0][3], m[1][3], m[2][3]]
                    den = sum(n[i] * ray[i] for i in range(3))
                    if abs(den) < 1e-9:
                        continue
                    s = sum(n[i] * p0[i] for i in range(3)) / den
                    x = [ray[i] * s - p0[i] for i in range(3)]
                    local = [sum(m[j][i] * x[j] for j in range(3)) for i in range(3)]
                    if abs(local[0]) <= half and abs(local[1]) <= half:
                        seen_all[k] = seen_all.get(k, 0) + 1
                        if best is None or s < best[0]:
                            best = (s, k, local)
                if best is None:
                    continue
                s, k, local = best
                depth[v][u] = int(round(s / DEPTH_SCALE))
                label[v][u] = k + 1
                checker = (int((local[0] + 200) // 25) + int((local[1] + 200) // 25)) % 2
                base = (200, 60, 40) if objects[k][0] == 7 else (40, 90, 210)
                shade = 1.0 if checker else 0.55
                rgb[v][3 * u:3 * u + 3] = [int(c * shade) for c in base]
        png(out / "rgb" / f"{im:06d}.png", rgb, 8, 3)
        png(out / "depth" / f"{im:06d}.png", depth, 16, 1)
        camera[str(im)] = {"cam_K": [FX, 0.0, CX, 0.0, FY, CY, 0.0, 0.0, 1.0], "depth_scale": DEPTH_SCALE}
        gt[str(im)], info[str(im)] = [], []
        for gt_id, (obj_id, m, _) in enumerate(objects):
            mask = [[255 if label[v][u] == gt_id + 1 else 0 for u in range(W)] for v in range(H)]
            png(out / "mask_visib" / f"{im:06d}_{gt_id:06d}.png", mask, 8, 1)
            count = sum(1 for row in mask for x in row if x)
            gt[str(im)].append({
                "cam_R_m2c": [m[i][j] for i in range(3) for j in range(3)],
                "cam_t_m2c": [m[i][3] for i in range(3)],
                "obj_id": obj_id,
            })
            total = seen_all.get(gt_id, 0)
            info[str(im)].append({"px_count_all": total, "px_count_visib": count, "visib_fract": count / total if total else 0.0})
    (out / "scene_camera.json").write_text(json.dumps(camera, indent=2))
    (out / "scene_gt.json").write_text(json.dumps(gt, indent=2))
    (out / "scene_gt_info.json").write_text(json.dumps(info, indent=2))
    truth = {}
    for a in range(3):
        for b in range(3):
            rel = matmul(plate_poses[b], inverse(plate_poses[a]))
            truth[f"{a}->{b}"] = [[v / 1000.0 if j == 3 and i < 3 else v for j, v in enumerate(row)] for i, row in enumerate(rel)]
    (out / "truth.json").write_text(json.dumps({"obj_id": 7, "relative_motion_m": truth}, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
