"""Arrays in and out: round trips of every accepted dtype and layout, and bad arrays raising
InputError with a message that names the argument and says what was expected."""

import numpy as np
import pytest

import flowfilter

GOOD = np.random.default_rng(0).uniform(-0.1, 0.1, (200, 3))


@pytest.mark.parametrize(
    "bad,words",
    [
        (GOOD[:, :2], ["source", "shape (N, 3)", "(200, 2)"]),
        (GOOD.reshape(-1), ["source", "shape (N, 3)", "(600,)"]),
        (GOOD.reshape(200, 3, 1), ["source", "(200, 3, 1)"]),
        (np.zeros((0, 3)), ["source", "empty"]),
        (GOOD.astype(np.int64), ["source", "float32 or float64", "int64"]),
        (GOOD.astype(np.complex128), ["source", "complex128"]),
        (GOOD.astype(object), ["source", "object"]),
        (GOOD.tolist(), ["source", "NumPy array", "list"]),
        ("points.ply", ["source", "NumPy array", "str"]),
    ],
)
def test_bad_source_arrays(bad, words):
    with pytest.raises(flowfilter.InputError) as e:
        flowfilter.register(bad, GOOD)
    for w in words:
        assert w in str(e.value), (w, str(e.value))


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_points(value):
    bad = GOOD.copy()
    bad[17, 1] = value
    with pytest.raises(flowfilter.InputError, match=r"target: row 17 is not finite"):
        flowfilter.register(GOOD, bad)
    with pytest.raises(flowfilter.InputError, match=r"target_normals: row 17 is not finite"):
        flowfilter.register(GOOD, GOOD, method="icp-pt2pl", target_normals=bad)
    with pytest.raises(flowfilter.InputError, match=r"points: row 17"):
        flowfilter.estimate_normals(bad)


def test_other_bad_arguments():
    normals = flowfilter.estimate_normals(GOOD)
    with pytest.raises(flowfilter.InputError, match=r"target_normals: 199 rows, but target has 200"):
        flowfilter.register(GOOD, GOOD, method="icp-pt2pl", target_normals=normals[:-1])
    with pytest.raises(flowfilter.InputError, match=r"needs normals on the target cloud.*estimate_normals"):
        flowfilter.register(GOOD, GOOD, method="filterreg-pt2pl")
    with pytest.raises(flowfilter.InputError, match=r"init: expected shape \(4, 4\), found \(3, 3\)"):
        flowfilter.register(GOOD, GOOD, init=np.eye(3))
    with pytest.raises(flowfilter.InputError, match=r"init: .*rigid|init: .*rotation"):
        flowfilter.register(GOOD, GOOD, init=np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(flowfilter.InputError, match=r"init: the matrix has a non-finite value"):
        flowfilter.register(GOOD, GOOD, init=np.full((4, 4), np.nan))
    with pytest.raises(flowfilter.InputError, match=r"correspondences: 200 source points but 199 target points"):
        flowfilter.register(GOOD, GOOD, method="flowfilter", correspondences=(GOOD, GOOD[1:]))
    with pytest.raises(flowfilter.InputError, match=r"correspondences\[2\]: element 3 is -1"):
        w = np.ones(200)
        w[3] = -1
        flowfilter.register(GOOD, GOOD, method="flowfilter", correspondences=(GOOD, GOOD, w))
    with pytest.raises(flowfilter.InputError, match=r"k must be >= 3"):
        flowfilter.estimate_normals(GOOD, k=2)
    # Nested lists are accepted where a matrix is small and commonly written by hand.
    r = flowfilter.register(GOOD, GOOD, method="icp-pt2pt", init=np.eye(4).tolist())
    assert np.allclose(r.transformation, np.eye(4), atol=1e-9)


def test_config_errors():
    with pytest.raises(flowfilter.ConfigError, match=r"unknown method 'ndt'.*icp-pt2pt"):
        flowfilter.register(GOOD, GOOD, method="ndt")
    with pytest.raises(flowfilter.ConfigError, match=r"unknown field `max_iteration`.*max_iterations"):
        flowfilter.register(GOOD, GOOD, method="icp-pt2pt", max_iteration=30)
    with pytest.raises(flowfilter.ConfigError, match=r"max_iterations"):
        flowfilter.register(GOOD, GOOD, method="icp-pt2pt", max_iterations=-1)
    with pytest.raises(flowfilter.ConfigError, match=r"variant: set by the method name"):
        flowfilter.register(GOOD, GOOD, method="icp-pt2pt", variant="point_to_plane")
    with pytest.raises(flowfilter.ConfigError, match=r"must be finite"):
        flowfilter.register(GOOD, GOOD, method="filterreg-pt2pt", tolerance=float("nan"))
    with pytest.raises(flowfilter.ConfigError, match=r"unknown method"):
        flowfilter.default_params("ndt")
    assert issubclass(flowfilter.InputError, flowfilter.Error) and issubclass(flowfilter.ConfigError, flowfilter.Error)
    # NumPy scalars are numbers.
    r = flowfilter.register(GOOD, GOOD + 0.001, method="icp-pt2pt", max_iterations=np.int64(5),
                            max_correspondence_distance=np.float32(0.05))
    assert r.iterations <= 5


def test_defaults_are_the_config_defaults():
    for method in flowfilter.METHODS:
        params = flowfilter.default_params(method)
        assert "variant" not in params and "mode" not in params
        r = flowfilter.register(GOOD, GOOD + 0.002, method=method.replace("pt2pl", "pt2pt"), **{})
        explicit = flowfilter.register(GOOD, GOOD + 0.002, method=method.replace("pt2pl", "pt2pt"),
                                       **flowfilter.default_params(method.replace("pt2pl", "pt2pt")))
        assert np.array_equal(r.transformation, explicit.transformation), method
    config = flowfilter.default_config()
    assert config["method"] == "flowfilter" and config["depth"]["cloud"]["knn"] == flowfilter.DEFAULT_KNN
    assert config["registration"]["icp"]["max_iterations"] == flowfilter.default_params("icp-pt2pt")["max_iterations"]


def frame_arrays(h=48, w=64):
    rng = np.random.default_rng(3)
    color = rng.integers(0, 255, (h, w, 3), dtype=np.uint8)
    depth = np.full((h, w), 8000, dtype=np.uint16)
    mask = np.zeros((h, w), dtype=bool)
    mask[10:30, 20:40] = True
    return color, depth, mask


def test_frame_round_trips():
    color, depth, mask = frame_arrays()
    f = flowfilter.Frame(color, depth, mask, depth_scale=10000.0, name="a")
    assert np.array_equal(f.color, color) and f.color.dtype == np.uint8
    assert np.array_equal(f.depth, depth) and f.depth.dtype == np.uint16
    assert np.array_equal(f.mask, mask) and f.mask.dtype == np.bool_
    assert f.name == "a" and f.depth_unit == pytest.approx(1e-4) and f.K is None
    metres = depth.astype(np.float32) / 10000
    g = flowfilter.Frame(np.asfortranarray(color), metres[:, ::-1][:, ::-1], mask.T.T)
    assert np.array_equal(g.depth, metres) and g.depth.dtype == np.float32
    assert np.array_equal(g.color, color) and g.depth_unit is None
    h = flowfilter.Frame(color, metres.astype(np.float64))
    assert h.depth.dtype == np.float32 and h.mask is None


@pytest.mark.parametrize(
    "change,words",
    [
        (lambda c, d, m: (c[..., 0], d, m), ["color", "shape (H, W, 3)"]),
        (lambda c, d, m: (c.astype(np.float32), d, m), ["color", "uint8", "float32"]),
        (lambda c, d, m: (c, d.astype(np.int32), m), ["depth", "uint16", "float32", "int32"]),
        (lambda c, d, m: (c, d[None], m), ["depth", "shape (H, W)"]),
        (lambda c, d, m: (c, -d.astype(np.float32), m), ["depth", "negative depth"]),
        (lambda c, d, m: (c, d, m.astype(np.uint8)), ["mask", "bool", "uint8"]),
        (lambda c, d, m: (c[:0], d, m), ["color", "empty"]),
    ],
)
def test_bad_frames(change, words):
    with pytest.raises(flowfilter.InputError) as e:
        flowfilter.Frame(*change(*frame_arrays()))
    for w in words:
        assert w in str(e.value), (w, str(e.value))


def test_frames_that_do_not_fit_their_camera():
    color, depth, mask = frame_arrays()
    camera = flowfilter.Camera(K=[[500, 0, 31.5], [0, 500, 23.5], [0, 0, 1]], depth_unit=1e-4)
    small = flowfilter.Frame(color, depth[:, :32], mask)
    with pytest.raises(flowfilter.InputError, match=r"frame 'frame': depth: the depth image is 32x48 but the colour image is 64x48"):
        flowfilter.estimate(small, small, camera)
    with pytest.raises(flowfilter.InputError, match=r"mask: the mask is 32x48"):
        f = flowfilter.Frame(color, depth, mask[:, :32])
        flowfilter.estimate(f, f, camera)
    with pytest.raises(flowfilter.InputError, match=r"mask is empty"):
        f = flowfilter.Frame(color, depth, np.zeros_like(mask))
        flowfilter.estimate(f, f, camera)
    with pytest.raises(flowfilter.InputError, match=r"no camera"):
        f = flowfilter.Frame(color, depth, mask)
        flowfilter.estimate(f, f)
    with pytest.raises(flowfilter.InputError, match=r"depth_scale is raw units per metre"):
        f = flowfilter.Frame(color, depth, mask, depth_scale=0.0001)
        flowfilter.estimate(f, f, camera)
    with pytest.raises(flowfilter.InputError, match=r"depth_unit_m"):
        f = flowfilter.Frame(color, depth, mask)
        flowfilter.estimate(f, f, flowfilter.Camera(K=np.array([[500, 0, 31.5], [0, 500, 23.5], [0, 0, 1]])))
    with pytest.raises(flowfilter.InputError, match=r"beyond any RGB-D sensor's range"):
        f = flowfilter.Frame(color, depth.astype(np.float32), mask)
        flowfilter.estimate(f, f, camera)
    with pytest.raises(flowfilter.InputError, match=r"expected a flowfilter.Frame"):
        flowfilter.estimate(color, depth, camera)


def test_camera():
    k = np.array([[500.0, 0, 31.5], [0, 510.0, 23.5], [0, 0, 1]])
    c = flowfilter.Camera(K=k, width=64, height=48, depth_unit=0.001, distortion=[0.1, 0, 0, 0, 0])
    assert np.array_equal(c.K, k) and (c.width, c.height, c.depth_unit, c.is_registered) == (64, 48, 0.001, True)
    bop = flowfilter.Camera.from_dict({"cam_K": k.reshape(-1).tolist(), "depth_scale": 0.1})
    assert bop.depth_unit == pytest.approx(1e-4) and np.array_equal(bop.K, k)
    o3d = flowfilter.Camera.from_dict({"width": 64, "height": 48, "intrinsic_matrix": k.T.reshape(-1).tolist()})
    assert np.array_equal(o3d.K, k) and o3d.depth_unit is None
    with pytest.raises(flowfilter.InputError, match=r"not a camera file"):
        flowfilter.Camera.from_dict({"focal": 500})
    with pytest.raises(flowfilter.InputError, match=r"cannot read"):
        flowfilter.read_camera("/nonexistent/camera.json")
