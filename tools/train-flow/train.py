#!/usr/bin/env python3
"""Train ffnet (model.py) on the project's own data and export it to ONNX with its contract.

Data: synthesised turntable pairs with exact flow, written by
`cargo run --release -p flowfilter-flow --example flow_dataset -- DIR PAIRS SEED OBJECTS`
(half resolution, 160x160 crops), plus FlyingChairs-like pairs made here: random textured layers
moved by random affine motions (analytic flow). Reproducible from --seed and --steps.

    pip install "jax[cpu]" onnx onnxruntime numpy scipy
    python3 tools/train-flow/train.py --data /tmp/fds_train --heldout /tmp/fds_heldout \
        --steps 6000 --seed 1 --out fixtures/models
"""
import argparse, json, time
from pathlib import Path

import numpy as np
import jax
import jax.numpy as jnp
from scipy.ndimage import map_coordinates, gaussian_filter

import model as M
from export import export

MEAN, STD = 0.45, 0.25
CROP = 128


def load(dirpath):
    d = Path(dirpath)
    return (np.load(d / "from.npy"), np.load(d / "to.npy"), np.load(d / "flow.npy"), np.load(d / "valid.npy"))


def texture(rng, s):
    """A random texture in [0, 1]: blurred noise at a few scales plus random sinusoids and blobs."""
    t = np.zeros((s, s))
    for sigma in (1.0, 3.0, 8.0):
        t += gaussian_filter(rng.normal(0, 1, (s, s)), sigma) * sigma * rng.uniform(0.2, 1.0)
    y, x = np.mgrid[0:s, 0:s]
    for _ in range(3):
        f = rng.uniform(0.02, 0.3, 2)
        t += 0.3 * np.sin(x * f[0] + y * f[1] + rng.uniform(0, 6.3))
    t = (t - t.min()) / (np.ptp(t) + 1e-9)
    return np.clip(t * rng.uniform(0.5, 1.0) + rng.uniform(0, 0.3), 0, 1)


def affine(rng, max_t, max_r, max_s):
    a, s = rng.uniform(-max_r, max_r), np.exp(rng.uniform(-max_s, max_s))
    return np.array([[s * np.cos(a), -s * np.sin(a)], [s * np.sin(a), s * np.cos(a)]]), rng.uniform(-max_t, max_t, 2)


def chairs(rng, s=160):
    """A FlyingChairs-like pair: background and 1-3 textured ellipse/polygon layers, each under
    its own affine motion; exact forward flow of every pixel of the first image."""
    c = s / 2
    y, x = np.mgrid[0:s, 0:s].astype(np.float64)
    pts = np.stack([x - c, y - c], -1)
    layers = [(np.ones((s, s), bool), texture(rng, s), affine(rng, 6, 0.05, 0.05))]
    for _ in range(rng.integers(1, 4)):
        cx, cy = rng.uniform(20, s - 20, 2)
        rx, ry = rng.uniform(10, 45, 2)
        th = rng.uniform(0, np.pi)
        u = ((x - cx) * np.cos(th) + (y - cy) * np.sin(th)) / rx
        v = (-(x - cx) * np.sin(th) + (y - cy) * np.cos(th)) / ry
        k = rng.uniform(1.5, 4)  # superellipse exponent: round to boxy shapes
        layers.append((np.abs(u) ** k + np.abs(v) ** k < 1, texture(rng, s), affine(rng, 12, 0.15, 0.1)))
    im1 = np.zeros((s, s)); im2 = np.zeros((s, s)); flow = np.zeros((2, s, s))
    # First image: layers painted back to front; the flow is that of the top layer at each pixel.
    for mask, tex, (A, t) in layers:
        im1[mask] = tex[mask]
        moved = pts @ A.T + t
        flow[0][mask] = (moved[..., 0] - pts[..., 0])[mask]
        flow[1][mask] = (moved[..., 1] - pts[..., 1])[mask]
    # Second image: each layer's texture and mask moved (inverse mapping), back to front.
    for mask, tex, (A, t) in layers:
        Ainv = np.linalg.inv(A)
        src = (pts - t) @ Ainv.T
        coords = [src[..., 1] + c, src[..., 0] + c]
        m2 = map_coordinates(mask.astype(float), coords, order=1, mode="constant") > 0.5
        t2 = map_coordinates(tex, coords, order=1, mode="reflect")
        im2[m2] = t2[m2]
    q = lambda im: np.clip(np.round(im * 255), 0, 255).astype(np.uint8)
    return q(im1), q(im2), flow.astype(np.float32), np.ones((s, s), np.uint8)


def augment(rng, a, b, f, v):
    n = a.shape[0]
    out = []
    for i in range(n):
        y0, x0 = rng.integers(0, a.shape[1] - CROP + 1, 2)
        sl = (slice(y0, y0 + CROP), slice(x0, x0 + CROP))
        ai, bi = a[i][sl].astype(np.float32) / 255, b[i][sl].astype(np.float32) / 255
        fi, vi = f[i][:, sl[0], sl[1]].copy(), v[i][sl].astype(np.float32)
        if rng.random() < 0.5:
            ai, bi, fi, vi = ai[:, ::-1], bi[:, ::-1], fi[:, :, ::-1] * np.array([-1, 1], np.float32)[:, None, None], vi[:, ::-1]
        if rng.random() < 0.5:
            ai, bi, fi, vi = ai[::-1], bi[::-1], fi[:, ::-1] * np.array([1, -1], np.float32)[:, None, None], vi[::-1]
        gain, bias = rng.uniform(0.7, 1.3), rng.uniform(-0.1, 0.1)
        noise = rng.uniform(0, 0.02)
        ai = np.clip(ai * gain + bias + rng.normal(0, noise, ai.shape), 0, 1)
        bi = np.clip(bi * gain * rng.uniform(0.95, 1.05) + bias + rng.normal(0, noise, bi.shape), 0, 1)
        out.append(((ai - MEAN) / STD, (bi - MEAN) / STD, fi, vi))
    return [np.ascontiguousarray(np.stack(x)) for x in zip(*out)]


def loss_fn(params, im1, im2, flow, valid):
    flows = M.forward(params, im1[:, None], im2[:, None])
    total, gt, v = 0.0, flow, valid[:, None]
    for l in range(M.LEVELS - 1, -1, -1):
        err = jnp.sqrt(jnp.sum((flows[l] - gt) ** 2, axis=1, keepdims=True) + 1e-6)
        epe = jnp.sum(err * v) / (jnp.sum(v) + 1e-6)
        total = total + epe * (0.5 ** (M.LEVELS - 1 - l))
        if l == M.LEVELS - 1:
            fine = epe
        # Next coarser level: averaged flow (halved), valid where all four were.
        gt = M.avgpool2(gt * v) / jnp.maximum(M.avgpool2(v), 1e-6) / 2.0
        v = (M.avgpool2(v) > 0.999).astype(v.dtype)
    return total, fine


def evaluate(params, data, batch=8):
    """Mean EPE over the valid pixels of full 160x160 crops (no augmentation)."""
    a, b, f, v = data
    fwd = jax.jit(lambda p, x, y: M.forward(p, x, y)[-1])
    num = den = 0.0
    for i in range(0, a.shape[0], batch):
        x = ((a[i:i + batch].astype(np.float32) / 255 - MEAN) / STD)[:, None]
        y = ((b[i:i + batch].astype(np.float32) / 255 - MEAN) / STD)[:, None]
        out = np.asarray(fwd(params, x, y))
        err = np.sqrt(((out - f[i:i + batch]) ** 2).sum(1))
        num += (err * v[i:i + batch]).sum(); den += v[i:i + batch].sum()
    return num / max(den, 1)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", required=True)
    ap.add_argument("--heldout", required=True)
    ap.add_argument("--steps", type=int, default=6000)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--chairs", type=int, default=800, help="FlyingChairs-like pairs generated")
    ap.add_argument("--chairs-fraction", type=float, default=0.3)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--out", default="fixtures/models")
    ap.add_argument("--init", help="start from these parameters (an ffnet_params.npz) instead of --seed's")
    a = ap.parse_args()
    rng = np.random.default_rng(a.seed)
    t0 = time.time()
    train, held = load(a.data), load(a.heldout)
    ch = [chairs(rng) for _ in range(a.chairs)]
    chairs_data = [np.stack(x) for x in zip(*ch)]
    print(f"data: {train[0].shape[0]} turntable pairs, {a.chairs} chairs pairs, {held[0].shape[0]} held out ({time.time() - t0:.0f} s)", flush=True)
    params = M.init_params(a.seed)
    if a.init:
        # Fine-tuning: the saved leaves, in the order of jax.tree_util.tree_leaves.
        saved = np.load(a.init)
        leaves = [jnp.asarray(saved[f"arr_{i}"]) for i in range(len(saved.files))]
        params = jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(params), leaves)
    m = jax.tree_util.tree_map(jnp.zeros_like, params)
    s = jax.tree_util.tree_map(jnp.zeros_like, params)

    @jax.jit
    def step(params, m, s, t, lr, im1, im2, flow, valid):
        (loss, fine), g = jax.value_and_grad(loss_fn, has_aux=True)(params, im1, im2, flow, valid)
        b1, b2 = 0.9, 0.999
        m = jax.tree_util.tree_map(lambda m, g: b1 * m + (1 - b1) * g, m, g)
        s = jax.tree_util.tree_map(lambda s, g: b2 * s + (1 - b2) * g * g, s, g)
        mh = jax.tree_util.tree_map(lambda m: m / (1 - b1 ** t), m)
        sh = jax.tree_util.tree_map(lambda s: s / (1 - b2 ** t), s)
        params = jax.tree_util.tree_map(lambda p, m, s: p - lr * m / (jnp.sqrt(s) + 1e-8), params, mh, sh)
        return params, m, s, loss, fine

    log = []
    for it in range(1, a.steps + 1):
        lr = a.lr * 0.5 * (1 + np.cos(np.pi * it / a.steps)) + 1e-5
        nc = int(round(a.batch * a.chairs_fraction))
        ti = rng.integers(0, train[0].shape[0], a.batch - nc)
        ci = rng.integers(0, a.chairs, nc)
        parts = [augment(rng, *(x[ti] for x in train)), augment(rng, *(x[ci] for x in chairs_data))]
        batch = [np.concatenate([p[k] for p in parts]) for k in range(4)]
        params, m, s, loss, fine = step(params, m, s, it, lr, *batch)
        if it % 200 == 0 or it == a.steps:
            entry = {"step": it, "loss": float(loss), "train_epe": float(fine), "seconds": round(time.time() - t0)}
            if it % 1000 == 0 or it == a.steps:
                entry["heldout_epe"] = float(evaluate(params, held))
            log.append(entry)
            print(json.dumps(entry), flush=True)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    np.savez(out / "ffnet_params.npz", *[np.asarray(x) for x in jax.tree_util.tree_leaves(params)])
    diff = export(params, out, held[0][0], held[1][0])
    (out / "ffnet_training.json").write_text(json.dumps({
        "seed": a.seed, "steps": a.steps, "batch": a.batch, "chairs": a.chairs, "chairs_fraction": a.chairs_fraction,
        "lr": a.lr, "init": a.init, "seconds": round(time.time() - t0), "onnx_vs_jax_max_abs": diff, "log": log,
        "jax": jax.__version__}, indent=1) + "\n")


if __name__ == "__main__":
    main()
