"""The network of `train.py` in JAX, and its ONNX export (built node by node with onnx.helper, so
the exported graph computes exactly what was trained, with operators tract supports).

Architecture ("ffnet", SPyNet-class): grey images at a fixed working size (640x512 for
BigBIRD's 1280x1024 colour frames), an average-pooled pyramid of LEVELS levels, and per level,
coarse to fine: the flow from the level below upsampled x2 (bilinear, half-pixel) and doubled,
the second image warped by it (bilinear GridSample, border padding), and a small conv stack on
[first image, warped second image, flow / FLOW_SCALE] that predicts a residual flow.
"""
import numpy as np
import jax
import jax.numpy as jnp
from jax import lax

LEVELS = 4
CHANNELS = [4, 32, 32, 32, 16, 2]
FLOW_SCALE = 8.0


def init_params(seed):
    key = jax.random.PRNGKey(seed)
    params = []
    for _ in range(LEVELS):
        level = []
        for i in range(len(CHANNELS) - 1):
            key, k = jax.random.split(key)
            fan_in = CHANNELS[i] * 9
            w = jax.random.normal(k, (CHANNELS[i + 1], CHANNELS[i], 3, 3)) * np.sqrt(2.0 / fan_in)
            if i == len(CHANNELS) - 2:
                w = w * 0.1
            level.append((w, jnp.zeros(CHANNELS[i + 1])))
        params.append(level)
    return params


def conv(x, w, b):
    return lax.conv_general_dilated(x, w, (1, 1), ((1, 1), (1, 1)), dimension_numbers=("NCHW", "OIHW", "NCHW")) + b[None, :, None, None]


def avgpool2(x):
    n, c, h, w = x.shape
    return x.reshape(n, c, h // 2, 2, w // 2, 2).mean(axis=(3, 5))


def upsample2(x):
    """ONNX Resize x2, mode linear, half_pixel, edge-clamped: out[i] samples in[i/2 - 0.25]."""
    def along(x, axis):
        n = x.shape[axis]
        prev = jnp.concatenate([lax.slice_in_dim(x, 0, 1, axis=axis), lax.slice_in_dim(x, 0, n - 1, axis=axis)], axis)
        nxt = jnp.concatenate([lax.slice_in_dim(x, 1, n, axis=axis), lax.slice_in_dim(x, n - 1, n, axis=axis)], axis)
        even = 0.75 * x + 0.25 * prev
        odd = 0.75 * x + 0.25 * nxt
        out = jnp.stack([even, odd], axis + 1)
        shape = list(x.shape)
        shape[axis] = 2 * n
        return out.reshape(shape)
    return along(along(x, 2), 3)


def warp(img, flow):
    """Bilinear sample of img [N,1,H,W] at (x + u, y + v), coordinates clamped to the image."""
    n, _, h, w = img.shape
    ys, xs = jnp.meshgrid(jnp.arange(h, dtype=img.dtype), jnp.arange(w, dtype=img.dtype), indexing="ij")
    x = jnp.clip(xs[None] + flow[:, 0], 0, w - 1)
    y = jnp.clip(ys[None] + flow[:, 1], 0, h - 1)
    x0 = jnp.clip(jnp.floor(x), 0, w - 2)
    y0 = jnp.clip(jnp.floor(y), 0, h - 2)
    fx, fy = x - x0, y - y0
    x0i, y0i = x0.astype(jnp.int32), y0.astype(jnp.int32)
    flat = img[:, 0].reshape(n, -1)
    def at(yy, xx):
        return jnp.take_along_axis(flat, (yy * w + xx).reshape(n, -1), axis=1).reshape(n, h, w)
    a, b = at(y0i, x0i), at(y0i, x0i + 1)
    c, d = at(y0i + 1, x0i), at(y0i + 1, x0i + 1)
    top = a * (1 - fx) + b * fx
    bot = c * (1 - fx) + d * fx
    return (top * (1 - fy) + bot * fy)[:, None]


def forward(params, im1, im2):
    """im1, im2: [N,1,H,W] normalised. Returns the flows of every level, coarse to fine."""
    p1, p2 = [im1], [im2]
    for _ in range(LEVELS - 1):
        p1.insert(0, avgpool2(p1[0]))
        p2.insert(0, avgpool2(p2[0]))
    flows = []
    flow = jnp.zeros((im1.shape[0], 2) + p1[0].shape[2:], im1.dtype)
    for l in range(LEVELS):
        if l > 0:
            flow = upsample2(flow) * 2.0
        x = jnp.concatenate([p1[l], warp(p2[l], flow), flow / FLOW_SCALE], axis=1)
        for i, (w, b) in enumerate(params[l]):
            x = conv(x, w, b)
            if i < len(params[l]) - 1:
                x = jax.nn.relu(x)
        flow = flow + x
        flows.append(flow)
    return flows


def export_onnx(params, path, width, height, mean, std):
    """The trained network as ONNX: inputs `from`, `to` [1,1,height,width] (already normalised by
    the contract), output `flow` [1,2,height,width] in pixels of that size."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    inits, nodes = [], []
    def init(name, arr):
        inits.append(numpy_helper.from_array(np.asarray(arr, dtype=np.float32), name))
        return name
    sizes = [(height >> (LEVELS - 1 - l), width >> (LEVELS - 1 - l)) for l in range(LEVELS)]
    names1, names2 = {LEVELS - 1: "from"}, {LEVELS - 1: "to"}
    for l in range(LEVELS - 2, -1, -1):
        for names, src in ((names1, "p1"), (names2, "p2")):
            out = f"{src}_{l}"
            nodes.append(helper.make_node("AveragePool", [names[l + 1]], [out], kernel_shape=[2, 2], strides=[2, 2]))
            names[l] = out
    init("scales2", [1, 1, 2, 2])
    init("two", [2.0])
    init("inv_flow_scale", [1.0 / FLOW_SCALE])
    flow = None
    for l in range(LEVELS):
        h, w = sizes[l]
        if flow is None:
            flow = init(f"zero_flow_{l}", np.zeros((1, 2, h, w)))
        else:
            nodes.append(helper.make_node("Resize", [flow, "", "scales2"], [f"up_{l}"], mode="linear", coordinate_transformation_mode="half_pixel"))
            nodes.append(helper.make_node("Mul", [f"up_{l}", "two"], [f"flow_in_{l}"]))
            flow = f"flow_in_{l}"
        # GridSample grid (align_corners=1): normalised (x + u, y + v).
        # The base grid as the broadcast sum of a row of (x, 0) and a column of (0, y): small
        # constants instead of an H x W x 2 table.
        gx = np.zeros((1, 1, w, 2)); gx[0, 0, :, 0] = np.linspace(-1, 1, w)
        gy = np.zeros((1, h, 1, 2)); gy[0, :, 0, 1] = np.linspace(-1, 1, h)
        init(f"grid_x_{l}", gx)
        init(f"grid_y_{l}", gy)
        init(f"to_norm_{l}", np.array([2.0 / (w - 1), 2.0 / (h - 1)]).reshape(1, 1, 1, 2))
        nodes += [
            helper.make_node("Transpose", [flow], [f"flow_t_{l}"], perm=[0, 2, 3, 1]),
            helper.make_node("Mul", [f"flow_t_{l}", f"to_norm_{l}"], [f"offset_{l}"]),
            helper.make_node("Add", [f"grid_x_{l}", f"offset_{l}"], [f"gxo_{l}"]),
            helper.make_node("Add", [f"grid_y_{l}", f"gxo_{l}"], [f"g_{l}"]),
            helper.make_node("GridSample", [names2[l], f"g_{l}"], [f"warped_{l}"], align_corners=1, mode="bilinear", padding_mode="border"),
            helper.make_node("Mul", [flow, "inv_flow_scale"], [f"flow_s_{l}"]),
            helper.make_node("Concat", [names1[l], f"warped_{l}", f"flow_s_{l}"], [f"x_{l}_0"], axis=1),
        ]
        x = f"x_{l}_0"
        for i, (wt, b) in enumerate(params[l]):
            wn, bn = init(f"w_{l}_{i}", np.asarray(wt)), init(f"b_{l}_{i}", np.asarray(b))
            nodes.append(helper.make_node("Conv", [x, wn, bn], [f"c_{l}_{i}"], pads=[1, 1, 1, 1]))
            x = f"c_{l}_{i}"
            if i < len(params[l]) - 1:
                nodes.append(helper.make_node("Relu", [x], [f"r_{l}_{i}"]))
                x = f"r_{l}_{i}"
        out = "flow" if l == LEVELS - 1 else f"flow_{l}"
        nodes.append(helper.make_node("Add", [flow, x], [out]))
        flow = out
    graph = helper.make_graph(
        nodes, "ffnet",
        [helper.make_tensor_value_info("from", TensorProto.FLOAT, [1, 1, height, width]),
         helper.make_tensor_value_info("to", TensorProto.FLOAT, [1, 1, height, width])],
        [helper.make_tensor_value_info("flow", TensorProto.FLOAT, [1, 2, height, width])],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 16)])
    model.doc_string = f"ffnet: input normalisation mean {mean}, std {std} (see the TOML contract)"
    onnx.checker.check_model(model)
    onnx.save(model, path)
    return model
