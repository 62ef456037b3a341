"""Open3D's objects taken as they are, and `flowfilter.open3d`: Open3D's `registration_icp` API.

Open3D itself is used where it is installed (tools/peers/requirements.txt; its wheel needs
Debian's libusb-1.0-0); everywhere else the same paths run on stand-ins that carry Open3D's class
names, modules and attributes, and the poses are Open3D's recorded ones (fixtures/peers)."""

import time

import numpy as np
import pytest

import flowfilter
from flowfilter import open3d as ffo3d
from conftest import PEERS, peer_cases

GEOMETRY = "open3d.cpu.pybind.geometry"
CAMERA = "open3d.cpu.pybind.camera"


def stand_in(module, name, **attrs):
    """An object whose type is named and placed as Open3D's pybind classes are."""
    cls = type(name, (), {"__module__": module})
    obj = cls()
    for k, v in attrs.items():
        setattr(obj, k, v)
    return obj


def cloud(points, normals=None):
    pcd = stand_in(GEOMETRY, "PointCloud", points=np.asarray(points), normals=np.zeros((0, 3)))
    if normals is not None:
        pcd.normals = np.asarray(normals)
    pcd.has_normals = lambda: normals is not None
    return pcd


class Image:
    """Open3D's `geometry.Image`: a buffer NumPy views."""

    __module__ = GEOMETRY

    def __init__(self, array):
        self._a = np.ascontiguousarray(array)

    def __array__(self, dtype=None, copy=None):
        return self._a if dtype is None else self._a.astype(dtype)


def load(name):
    source, _ = flowfilter.read_ply(PEERS / f"{name}_source.ply")
    target, _ = flowfilter.read_ply(PEERS / f"{name}_target.ply")
    return source, target


# The script a user has, written against Open3D; only its import line changes.
OPEN3D_SCRIPT = """
import numpy as np
{import_line}

def align(source, target):
    criteria = reg.ICPConvergenceCriteria(relative_fitness=1e-6, relative_rmse=1e-6, max_iteration=200)
    point_to_plane = reg.registration_icp(source, target, 0.25, np.identity(4),
                                          reg.TransformationEstimationPointToPlane(), criteria)
    point_to_point = reg.registration_icp(source, target, 0.25, np.identity(4),
                                          reg.TransformationEstimationPointToPoint(), criteria)
    check = reg.evaluate_registration(source, target, 0.25, point_to_plane.transformation)
    return point_to_plane, point_to_point, check
"""


def script(import_line):
    namespace = {}
    exec(OPEN3D_SCRIPT.format(import_line=import_line), namespace)
    return namespace["align"]


def test_the_open3d_script_gives_open3ds_recorded_poses():
    """The script with `from flowfilter import open3d as reg`, on Open3D-typed clouds (stand-ins
    here), returns Open3D 0.20's recorded poses on every peer fixture."""
    align = script("from flowfilter import open3d as reg")
    for case in peer_cases():
        source, target = load(case["name"])
        normals = flowfilter.estimate_normals(target, k=12)
        pl, pt, check = align(cloud(source), cloud(target, normals))
        for result, method in [(pl, "icp-pt2pl"), (pt, "icp-pt2pt")]:
            peer = np.array(case["peers"][method]["transform"])
            assert isinstance(result, ffo3d.RegistrationResult)
            assert result.transformation.shape == (4, 4)
            assert np.abs(result.transformation - peer).max() < 1e-9, f"{case['name']} {method}"
            assert 0.0 < result.fitness <= 1.0 and result.inlier_rmse > 0.0
            assert result.correspondence_set.shape == (round(result.fitness * len(source)), 2)
        assert np.array_equal(check.correspondence_set, pl.correspondence_set)
        assert check.fitness == pl.fitness


def test_correspondence_set_is_the_pairs_within_the_distance():
    rng = np.random.default_rng(4)
    target = rng.uniform(-1, 1, (300, 3))
    source = target[:100] + np.array([0.0, 0.0, 0.001])
    source[:10] += 5.0  # far from every target point
    r = ffo3d.evaluate_registration(source, target, 0.01)
    assert r.correspondence_set.dtype == np.int64
    assert np.array_equal(r.correspondence_set, np.stack([np.arange(10, 100), np.arange(10, 100)], axis=1))
    assert r.fitness == pytest.approx(0.9) and r.inlier_rmse == pytest.approx(0.001)
    moved = ffo3d.evaluate_registration(source, target, 0.01, np.diag([1.0, 1.0, 1.0, 1.0]))
    assert np.array_equal(moved.correspondence_set, r.correspondence_set)


def test_what_our_icp_does_not_do_is_refused():
    source, target = load("case_0")
    with pytest.raises(flowfilter.ConfigError, match="with_scaling"):
        ffo3d.TransformationEstimationPointToPoint(with_scaling=True)
    with pytest.raises(flowfilter.ConfigError, match="kernel"):
        ffo3d.TransformationEstimationPointToPlane(kernel=object())
    with pytest.raises(flowfilter.ConfigError, match="estimation_method"):
        ffo3d.registration_icp(source, target, 0.1, np.eye(4), object())
    with pytest.raises(flowfilter.InputError, match="normals"):
        ffo3d.registration_icp(cloud(source), cloud(target), 0.1, np.eye(4), ffo3d.TransformationEstimationPointToPlane())
    with pytest.raises(flowfilter.InputError, match="max_correspondence_distance"):
        ffo3d.registration_icp(source, target, -1.0)
    with pytest.raises(flowfilter.ConfigError, match="criteria"):
        ffo3d.registration_icp(source, target, 0.1, np.eye(4), ffo3d.TransformationEstimationPointToPoint(), criteria=3)


def test_register_takes_point_clouds_with_their_normals():
    source, target = load("case_1")
    normals = flowfilter.estimate_normals(target, k=12)
    from_arrays = flowfilter.register(source, target, method="icp-pt2pl", target_normals=normals)
    from_clouds = flowfilter.register(cloud(source), cloud(target, normals), method="icp-pt2pl")
    assert np.array_equal(from_arrays.transformation, from_clouds.transformation)
    # Given normals win over the cloud's own.
    flipped = flowfilter.register(cloud(source), cloud(target, -normals), method="icp-pt2pl", target_normals=normals)
    assert np.array_equal(flipped.transformation, from_arrays.transformation)


@pytest.mark.parametrize("where", ["source", "target"])
def test_open3d_objects_of_the_wrong_kind_raise_input_error(where):
    source, target = load("case_1")
    mesh = stand_in(GEOMETRY, "TriangleMesh")
    args = {"source": source, "target": target, where: mesh}
    with pytest.raises(flowfilter.InputError, match=rf"{where}: expected .*open3d.geometry.PointCloud, found open3d.TriangleMesh"):
        flowfilter.register(args["source"], args["target"])


def frames_of(scene):
    """A synthesised BOP scene's two frames as arrays, with its camera."""
    a = flowfilter.read_bop_frame(scene, 0, 1)
    b = flowfilter.read_bop_frame(scene, 1, 1)
    return a, b


def rgbd(frame, intensity=False):
    """Open3D's `RGBDImage.create_from_color_and_depth` of a frame: float depth in metres, and the
    colour either as given or as float intensity (`convert_rgb_to_intensity=True`)."""
    depth = np.asarray(frame.depth).astype(np.float32) * np.float32(frame.depth_unit)
    color = np.asarray(frame.color)
    if intensity:
        color = (color.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)) / 255.0
    return stand_in(GEOMETRY, "RGBDImage", color=Image(color), depth=Image(depth))


def pinhole(frame):
    k = np.asarray(frame.K)
    h, w = np.asarray(frame.depth).shape
    return stand_in(CAMERA, "PinholeCameraIntrinsic", intrinsic_matrix=k, width=w, height=h)


def test_estimate_takes_rgbd_images_and_pinhole_intrinsics(bop_scene):
    a, b = frames_of(bop_scene)
    # The same frames as arrays (float depth in metres), whole frames, the camera as a dict.
    plain = [
        flowfilter.Frame(np.asarray(f.color), np.asarray(f.depth).astype(np.float32) * np.float32(f.depth_unit), name=n)
        for f, n in [(a, "model"), (b, "target")]
    ]
    k = np.asarray(a.K)
    camera = flowfilter.Camera(k, width=np.asarray(a.depth).shape[1], height=np.asarray(a.depth).shape[0])
    expected = flowfilter.estimate(plain[0], plain[1], camera)
    got = flowfilter.estimate(rgbd(a), rgbd(b), pinhole(a))
    assert np.array_equal(got.transform, expected.transform)
    # Open3D's default RGB-D image (intensity in [0, 1]) works too, on the same grey levels.
    grey = flowfilter.estimate(rgbd(a, intensity=True), rgbd(b, intensity=True), pinhole(a))
    assert np.abs(grey.transform - expected.transform).max() < 5e-3


def test_frame_takes_open3d_images(bop_scene):
    a, _ = frames_of(bop_scene)
    color, depth, mask = np.asarray(a.color), np.asarray(a.depth), np.asarray(a.mask)
    f = flowfilter.Frame(Image(color), Image(depth), mask=Image(mask), depth_scale=1.0 / a.depth_unit)
    assert np.array_equal(np.asarray(f.color), color) and np.array_equal(np.asarray(f.depth), depth)
    assert np.array_equal(np.asarray(f.mask), mask)


def test_wrong_open3d_types_in_estimate_raise_input_error(bop_scene):
    a, b = frames_of(bop_scene)
    pcd = cloud(np.zeros((3, 3)))
    with pytest.raises(flowfilter.InputError, match="model: expected a flowfilter.Frame .* found open3d.PointCloud"):
        flowfilter.estimate(pcd, rgbd(b), pinhole(a))
    with pytest.raises(flowfilter.InputError, match="camera: expected"):
        flowfilter.estimate(rgbd(a), rgbd(b), stand_in(CAMERA, "PinholeCameraParameters"))
    with pytest.raises(flowfilter.InputError, match="color: expected an array or an open3d.geometry.Image, found open3d.PointCloud"):
        flowfilter.Frame(pcd, np.zeros((4, 4), np.float32))


# --- Open3D itself, where it is installed -------------------------------------------------


def test_the_open3d_script_runs_unchanged_on_open3d_clouds_with_open3ds_poses():
    """The same script, once on Open3D and once on flowfilter.open3d, on Open3D's own clouds:
    the same poses, fitness, RMSE and correspondences; the ratio of times is printed."""
    o3d = pytest.importorskip("open3d", reason="open3d is not installed (tools/peers/requirements.txt)")
    theirs_align = script("from open3d.pipelines import registration as reg")
    ours_align = script("from flowfilter import open3d as reg")
    spent = {"open3d": 0.0, "flowfilter": 0.0}
    for case in peer_cases():
        source, target = load(case["name"])
        pcd_s = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(source))
        pcd_t = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(target))
        pcd_t.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=12))
        pcd_t.orient_normals_towards_camera_location(np.zeros(3))
        t0 = time.perf_counter()
        theirs = theirs_align(pcd_s, pcd_t)
        t1 = time.perf_counter()
        ours = ours_align(pcd_s, pcd_t)
        t2 = time.perf_counter()
        spent["open3d"] += t1 - t0
        spent["flowfilter"] += t2 - t1
        for a, b in zip(theirs, ours):
            assert np.abs(np.asarray(a.transformation) - b.transformation).max() < 1e-9, case["name"]
            assert abs(a.fitness - b.fitness) < 1e-12 and abs(a.inlier_rmse - b.inlier_rmse) < 1e-9
            assert np.array_equal(np.asarray(a.correspondence_set), b.correspondence_set), case["name"]
    print(f"\nOpen3D script, 9 fixtures x 3 calls: open3d {spent['open3d']:.3f} s, flowfilter.open3d {spent['flowfilter']:.3f} s")


def test_real_open3d_objects_everywhere(bop_scene):
    o3d = pytest.importorskip("open3d", reason="open3d is not installed (tools/peers/requirements.txt)")
    source, target = load("case_2")
    pcd_t = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(target))
    pcd_t.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=12))
    pcd_t.orient_normals_towards_camera_location(np.zeros(3))
    pcd_s = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(source))
    r = flowfilter.register(pcd_s, pcd_t, method="icp-pt2pl")
    expected = flowfilter.register(source, target, method="icp-pt2pl", target_normals=np.asarray(pcd_t.normals))
    assert np.array_equal(r.transformation, expected.transformation)
    with pytest.raises(flowfilter.InputError, match="found open3d.TriangleMesh"):
        flowfilter.register(o3d.geometry.TriangleMesh(), pcd_t)

    a, b = frames_of(bop_scene)
    h, w = np.asarray(a.depth).shape
    k = np.asarray(a.K)
    intrinsic = o3d.camera.PinholeCameraIntrinsic(w, h, k[0, 0], k[1, 1], k[0, 2], k[1, 2])
    made = []
    for f in (a, b):
        color = o3d.geometry.Image(np.ascontiguousarray(np.asarray(f.color)))
        depth = o3d.geometry.Image(np.ascontiguousarray(np.asarray(f.depth)))
        made.append(o3d.geometry.RGBDImage.create_from_color_and_depth(
            color, depth, depth_scale=1.0 / f.depth_unit, depth_trunc=10.0, convert_rgb_to_intensity=False))
    e = flowfilter.estimate(made[0], made[1], intrinsic)
    plain = [flowfilter.Frame(np.asarray(f.color), np.asarray(f.depth).astype(np.float32) * np.float32(f.depth_unit))
             for f in (a, b)]
    expected = flowfilter.estimate(plain[0], plain[1], flowfilter.Camera(k, width=w, height=h))
    assert np.abs(e.transform - expected.transform).max() < 1e-6
    frame = flowfilter.Frame(o3d.geometry.Image(np.ascontiguousarray(np.asarray(a.color))),
                             o3d.geometry.Image(np.ascontiguousarray(np.asarray(a.depth))), depth_scale=1.0 / a.depth_unit)
    assert np.array_equal(np.asarray(frame.depth), np.asarray(a.depth))
    with pytest.raises(flowfilter.InputError, match="found open3d.PointCloud"):
        flowfilter.estimate(pcd_s, made[1], intrinsic)
