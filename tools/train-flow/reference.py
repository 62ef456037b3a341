#!/usr/bin/env python3
"""The fixture pair and reference output of the shipped ffnet (test
`crates/flowfilter-flow/tests/onnx.rs::shipped_network_matches_its_reference`).

Input: a `flowfilter truth-flow` directory of a held-out object (full-resolution from.png,
to.png, flow.flo). Writes to --out: ffnet_pair_a.png / ffnet_pair_b.png (grey, half resolution:
the network's 640x512 working size, so no resizing happens in the test), and
ffnet_reference.json with onnxruntime's output and the exact flow (half-resolution pixels) at
every 8th pixel and every other object pixel.

    cargo run --release -p flowfilter -- truth-flow --mesh ../shared/data/ycb/004_sugar_box/textured.obj \
        --camera NP3 --from 0 --to 6 --out /tmp/ffnet_fixture
    python3 tools/train-flow/reference.py --pair /tmp/ffnet_fixture --out fixtures/models
"""
import argparse, json
from pathlib import Path

import numpy as np
import onnxruntime as ort
from PIL import Image

STEP = 8


def grey_half(path):
    rgb = np.asarray(Image.open(path).convert("RGB")).astype(np.float32)
    g = (0.299 * rgb[..., 0] + 0.587 * rgb[..., 1] + 0.114 * rgb[..., 2]) / 255.0
    h = (g[0::2, 0::2] + g[1::2, 0::2] + g[0::2, 1::2] + g[1::2, 1::2]) / 4
    return np.clip(np.round(h * 255), 0, 255).astype(np.uint8)


def read_flo(path):
    b = Path(path).read_bytes()
    w, h = np.frombuffer(b[4:12], "<i4")
    return np.frombuffer(b[12:], "<f4").reshape(h, w, 2)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--pair", required=True)
    ap.add_argument("--out", default="fixtures/models")
    a = ap.parse_args()
    pair, out = Path(a.pair), Path(a.out)
    ga, gb = grey_half(pair / "from.png"), grey_half(pair / "to.png")
    Image.fromarray(ga).save(out / "ffnet_pair_a.png")
    Image.fromarray(gb).save(out / "ffnet_pair_b.png")
    flo = read_flo(pair / "flow.flo")
    known = np.abs(flo).max(-1) < 1e9
    # Half-resolution truth: the mean of the four full-resolution flows, halved, where all four are known.
    q = [(0, 0), (1, 0), (0, 1), (1, 1)]
    ok = np.all([known[dy::2, dx::2] for dx, dy in q], 0)
    gt = sum(np.where(known[dy::2, dx::2, None], flo[dy::2, dx::2], 0) for dx, dy in q) / 8.0
    contract = (out / "ffnet.toml").read_text()
    mean, std = 0.45, 0.25
    assert f"mean = [{mean}]" in contract and f"std = [{std}]" in contract, "contract changed: update reference.py"
    x = ((ga.astype(np.float32) / np.float32(255.0) - np.float32(mean)) / np.float32(std))[None, None]
    y = ((gb.astype(np.float32) / np.float32(255.0) - np.float32(mean)) / np.float32(std))[None, None]
    sess = ort.InferenceSession(str(out / "ffnet.onnx"))
    flow = sess.run(None, {"from": x, "to": y})[0][0]
    # Every STEP-th pixel (the network's output everywhere) and every other pixel of the object
    # where the exact flow is known (the accuracy check).
    ys, xs = np.mgrid[0:ga.shape[0]:STEP, 0:ga.shape[1]:STEP]
    pts = {(int(px), int(py)) for px, py in zip(xs.ravel(), ys.ravel())}
    oy, ox = np.nonzero(ok)
    pts |= {(int(px), int(py)) for px, py in zip(ox, oy) if px % 2 == 0 and py % 2 == 0}
    pts = sorted(pts, key=lambda p: (p[1], p[0]))
    ref = {
        "tool": f"onnxruntime {ort.__version__}",
        "step": STEP,
        "points": [[px, py] for px, py in pts],
        "network": [[float(flow[0, py, px]), float(flow[1, py, px])] for px, py in pts],
        "truth": [[float(gt[py, px, 0]), float(gt[py, px, 1])] if ok[py, px] else None for px, py in pts],
    }
    err = [np.hypot(*(np.array(n) - np.array(t))) for n, t in zip(ref["network"], ref["truth"]) if t is not None]
    ref["epe_at_points"] = float(np.mean(err))
    (out / "ffnet_reference.json").write_text(json.dumps(ref) + "\n")
    print(f"{len(pts)} points, {len(err)} with truth, network EPE {ref['epe_at_points']:.3f} (half-resolution px)")


if __name__ == "__main__":
    main()
