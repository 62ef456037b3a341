#!/usr/bin/env python3
"""Export trained ffnet parameters (`ffnet_params.npz` from train.py) to ONNX with its TOML
contract, and check onnxruntime against JAX on a pair of the held-out data.

    python3 tools/train-flow/export.py --params fixtures/models/ffnet_params.npz \
        --heldout /tmp/fds_heldout --out fixtures/models
"""
import argparse
from pathlib import Path

import numpy as np
import jax
import jax.numpy as jnp

import model as M

MEAN, STD = 0.45, 0.25
W, H = 640, 512


def unflatten(leaves):
    template = M.init_params(0)
    treedef = jax.tree_util.tree_structure(template)
    return jax.tree_util.tree_unflatten(treedef, [jnp.asarray(x) for x in leaves])


def export(params, out, heldout_from, heldout_to):
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    M.export_onnx(params, out / "ffnet.onnx", W, H, MEAN, STD)
    (out / "ffnet.toml").write_text(
        "# Contract of ffnet.onnx (tools/train-flow/): two grey inputs at the network's working size\n"
        "# (half of BigBIRD's 1280x1024 colour frames; other sizes are resized and the flow rescaled).\n"
        "[input]\nnames = [\"from\", \"to\"]\nchannels = 1\nscale = 1.0\n"
        f"mean = [{MEAN}]\nstd = [{STD}]\nfixed_size = [{W}, {H}]\n\n"
        "[output]\nname = \"flow\"\nscale = 1.0\ndownsample = 1\n")
    import onnxruntime as ort
    sess = ort.InferenceSession(str(out / "ffnet.onnx"))
    x = np.zeros((1, 1, H, W), np.float32); y = x.copy()
    x[0, 0, :160, :160] = (heldout_from / 255 - MEAN) / STD
    y[0, 0, :160, :160] = (heldout_to / 255 - MEAN) / STD
    ref = np.asarray(M.forward(params, jnp.asarray(x), jnp.asarray(y))[-1])
    got = sess.run(None, {"from": x, "to": y})[0]
    diff = float(np.abs(ref - got).max())
    print(f"onnxruntime vs JAX: max |diff| {diff:.2e}")
    assert diff < 1e-3, diff
    return diff


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--params", required=True)
    ap.add_argument("--heldout", required=True)
    ap.add_argument("--out", default="fixtures/models")
    a = ap.parse_args()
    z = np.load(a.params)
    params = unflatten([z[f"arr_{i}"] for i in range(len(z.files))])
    d = Path(a.heldout)
    export(params, a.out, np.load(d / "from.npy")[0], np.load(d / "to.npy")[0])


if __name__ == "__main__":
    main()
