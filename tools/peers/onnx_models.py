#!/usr/bin/env python3
"""Tiny ONNX flow graphs for testing the `OnnxFlow` loader (feature `onnx`), and onnxruntime's
output on a fixture pair as the reference.

The graphs use the operators of SPyNet/RAFT-class networks (Conv, Relu, Resize, GridSample,
Concat, Transpose, Add, Sub, Mul) with fixed random weights (seed 7); they are not trained: the
test is that tract computes what onnxruntime computes.

    pip install onnx onnxruntime numpy pillow
    python3 tools/peers/onnx_models.py [--out fixtures/models]

Writes, each with its TOML contract beside it:
- tiny_warp.onnx: inputs from/to [1,1,48,64] (fixed size), a half-resolution conv flow,
  Resize x2, GridSample of `to`, a residual conv: output flow [1,2,48,64];
- tiny_concat.onnx: one input [1,6,H,W] (two RGB images concatenated, any H, W multiple of 4),
  strided conv, Resize x4: output flow [1,2,H/2,W/2] (a half-resolution output);
- pair_a.png, pair_b.png (64x48 grey) and reference.json (onnxruntime's outputs on them).
"""
import argparse, json
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper
import onnxruntime as ort
from PIL import Image

W, H = 64, 48
rng = np.random.default_rng(7)


def init(name, arr):
    return numpy_helper.from_array(np.asarray(arr, dtype=np.float32), name)


def tiny_warp():
    w1 = rng.normal(0, 0.3, (4, 2, 3, 3)); b1 = rng.normal(0, 0.1, 4)
    w2 = rng.normal(0, 0.3, (2, 4, 3, 3)); b2 = rng.normal(0, 0.1, 2)
    w3 = rng.normal(0, 0.2, (2, 3, 3, 3)); b3 = np.zeros(2)
    # Base sampling grid in GridSample's normalised coordinates (align_corners=1).
    xs = np.linspace(-1, 1, W); ys = np.linspace(-1, 1, H)
    gx, gy = np.meshgrid(xs, ys)
    grid = np.stack([gx, gy], -1)[None]  # [1,H,W,2]
    to_norm = np.array([2.0 / (W - 1), 2.0 / (H - 1)]).reshape(1, 1, 1, 2)
    nodes = [
        helper.make_node("Concat", ["from", "to"], ["x"], axis=1),
        helper.make_node("Conv", ["x", "w1", "b1"], ["c1"], pads=[1, 1, 1, 1], strides=[2, 2]),
        helper.make_node("Relu", ["c1"], ["r1"]),
        helper.make_node("Conv", ["r1", "w2", "b2"], ["c2"], pads=[1, 1, 1, 1]),
        helper.make_node("Resize", ["c2", "", "scales"], ["up"], mode="linear", coordinate_transformation_mode="half_pixel"),
        helper.make_node("Transpose", ["up"], ["up_t"], perm=[0, 2, 3, 1]),
        helper.make_node("Mul", ["up_t", "to_norm"], ["offset"]),
        helper.make_node("Add", ["grid", "offset"], ["g"]),
        helper.make_node("GridSample", ["to", "g"], ["warped"], align_corners=1, mode="bilinear", padding_mode="border"),
        helper.make_node("Sub", ["warped", "from"], ["diff"]),
        helper.make_node("Concat", ["up", "diff"], ["y"], axis=1),
        helper.make_node("Conv", ["y", "w3", "b3"], ["c3"], pads=[1, 1, 1, 1]),
        helper.make_node("Add", ["up", "c3"], ["flow"]),
    ]
    graph = helper.make_graph(
        nodes, "tiny_warp",
        [helper.make_tensor_value_info("from", TensorProto.FLOAT, [1, 1, H, W]),
         helper.make_tensor_value_info("to", TensorProto.FLOAT, [1, 1, H, W])],
        [helper.make_tensor_value_info("flow", TensorProto.FLOAT, [1, 2, H, W])],
        [init("w1", w1), init("b1", b1), init("w2", w2), init("b2", b2), init("w3", w3), init("b3", b3),
         init("scales", [1, 1, 2, 2]), init("grid", grid), init("to_norm", to_norm)],
    )
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 16)])


def tiny_concat():
    w1 = rng.normal(0, 0.2, (8, 6, 3, 3)); b1 = rng.normal(0, 0.1, 8)
    w2 = rng.normal(0, 0.2, (2, 8, 3, 3)); b2 = rng.normal(0, 0.1, 2)
    nodes = [
        helper.make_node("Conv", ["images", "w1", "b1"], ["c1"], pads=[1, 1, 1, 1], strides=[4, 4]),
        helper.make_node("Relu", ["c1"], ["r1"]),
        helper.make_node("Conv", ["r1", "w2", "b2"], ["c2"], pads=[1, 1, 1, 1]),
        helper.make_node("Resize", ["c2", "", "scales"], ["flow"], mode="linear", coordinate_transformation_mode="half_pixel"),
    ]
    graph = helper.make_graph(
        nodes, "tiny_concat",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 6, "H", "W"])],
        [helper.make_tensor_value_info("flow", TensorProto.FLOAT, [1, 2, "h", "w"])],
        [init("w1", w1), init("b1", b1), init("w2", w2), init("b2", b2), init("scales", [1, 1, 2, 2])],
    )
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 16)])


def pattern(shift):
    y, x = np.mgrid[0:H, 0:W].astype(np.float32)
    u, v = x - shift[0], y - shift[1]
    s = 0.5 + 0.2 * np.sin(u * 0.31) * np.cos(v * 0.27) + 0.15 * np.sin((u + 2 * v) * 0.13)
    return np.clip(np.round(s * 255), 0, 255).astype(np.uint8)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="fixtures/models")
    out = Path(ap.parse_args().out)
    out.mkdir(parents=True, exist_ok=True)
    a, b = pattern((0, 0)), pattern((1.5, -0.5))
    Image.fromarray(a).save(out / "pair_a.png")
    Image.fromarray(b).save(out / "pair_b.png")
    ref = {"tool": f"onnxruntime {ort.__version__}, onnx {onnx.__version__}"}
    # tiny_warp: grey inputs scaled to [0, 1].
    m = tiny_warp(); onnx.checker.check_model(m); onnx.save(m, out / "tiny_warp.onnx")
    sess = ort.InferenceSession(str(out / "tiny_warp.onnx"))
    fa, fb = (a / 255.0).astype(np.float32)[None, None], (b / 255.0).astype(np.float32)[None, None]
    ref["tiny_warp"] = sess.run(None, {"from": fa, "to": fb})[0].ravel().tolist()
    # tiny_concat: the grey image replicated to RGB, ImageNet-style normalisation.
    m = tiny_concat(); onnx.checker.check_model(m); onnx.save(m, out / "tiny_concat.onnx")
    sess = ort.InferenceSession(str(out / "tiny_concat.onnx"))
    mean = np.array([0.485, 0.456, 0.406], np.float32).reshape(1, 3, 1, 1)
    std = np.array([0.229, 0.224, 0.225], np.float32).reshape(1, 3, 1, 1)
    rgb = lambda g: ((np.repeat((g / 255.0).astype(np.float32)[None, None], 3, 1)) - mean) / std
    x = np.concatenate([rgb(a), rgb(b)], 1).astype(np.float32)
    ref["tiny_concat"] = sess.run(None, {"images": x})[0].ravel().tolist()
    (out / "reference.json").write_text(json.dumps(ref) + "\n")
    print({k: (len(v) if isinstance(v, list) else v) for k, v in ref.items()})


if __name__ == "__main__":
    main()
