"""`flowfilter.Tracker`: a stream from one mask, the motion from the first frame with a state per
frame, lost frames as states (not exceptions), and the same poses as `flowfilter track`."""

import json

import numpy as np
import pytest

import flowfilter
from conftest import SHARED

SHELF = SHARED / "realsense-shelf" / "shelf-D"


def bop_stream(bop_scene, ims):
    """The scene's frames `ims` of object 1, their camera, and the same frames as plain arrays of
    colour and depth (later frames come without a mask)."""
    frames = [flowfilter.read_bop_frame(bop_scene, im, 1) for im in ims]
    k = np.asarray(frames[0].K)
    h, w = np.asarray(frames[0].depth).shape
    camera = flowfilter.Camera(k, width=w, height=h, depth_unit=frames[0].depth_unit)
    plain = [flowfilter.Frame(np.asarray(f.color), np.asarray(f.depth), name=f"im{i}") for i, f in enumerate(frames)]
    return frames, camera, plain


def rotation_deg(a, b):
    d = a[:3, :3] @ b[:3, :3].T
    return float(np.degrees(np.arccos(np.clip((np.trace(d) - 1) / 2, -1, 1))))


def test_an_object_is_tracked_from_its_first_mask(bop_scene):
    frames, camera, plain = bop_stream(bop_scene, (0, 1, 2))
    tracker = flowfilter.Tracker(camera, plain[0], mask=np.asarray(frames[0].mask))
    for im in (1, 2):
        e = tracker.update(plain[im])
        assert isinstance(e, flowfilter.Estimate)
        assert e.state == "tracking", e.reason
        assert e.frame_index == im and e.reference is not None and e.model == "im0"
        # The first motion has nothing to be predicted from: the full estimate.
        assert im > 1 or e.aligned_only is False
        # Prepared on the object's predicted region, or whole: inside the image either way.
        region = e.prepared_region
        assert region is None or (region[0] + region[2] <= camera.width and region[1] + region[3] <= camera.height)
        truth = flowfilter.bop_motion(bop_scene, 0, im, 1)
        assert rotation_deg(e.transform, truth) < 1.0, im
        assert e.to_dict()["track"]["state"] == "tracking"
        # The carried mask: the frame's size, its pixels the reported count, mostly the object's.
        carried = tracker.object_mask()
        assert carried.shape == (camera.height, camera.width) and carried.dtype == np.bool_
        assert int(carried.sum()) == e.to_dict()["track"]["mask_px"]
        true_mask = np.asarray(frames[im].mask)
        assert (carried & true_mask).sum() > 0.8 * carried.sum()
    assert tracker.keyframes()[0] == 0
    # The whole scene has no object mask.
    assert flowfilter.Tracker(camera, plain[0]).object_mask() is None
    # A pairwise estimate has no track.
    assert flowfilter.estimate(frames[0], frames[1]).state is None


def test_the_trackers_settings_from_a_dict(bop_scene):
    frames, camera, plain = bop_stream(bop_scene, (0, 1, 2))
    mask = np.asarray(frames[0].mask)
    # Every frame a keyframe: the settings are the tracker's.
    tracker = flowfilter.Tracker(camera, plain[0], mask=mask, settings={"aligned_path": True, "keyframe_deg": 1e-6})
    for im in (1, 2):
        e = tracker.update(plain[im])
        assert e.state == "tracking", e.reason
        assert rotation_deg(e.transform, flowfilter.bop_motion(bop_scene, 0, im, 1)) < 1.0, im
    assert tracker.keyframes() == [0, 1, 2]
    default = flowfilter.Tracker(camera, plain[0], mask=mask)
    default.update(plain[1])
    assert default.keyframes() == [0]
    with pytest.raises(flowfilter.ConfigError, match="aligned_paths"):
        flowfilter.Tracker(camera, plain[0], mask=mask, settings={"aligned_paths": True})


def test_a_box_around_the_object_instead_of_a_mask(bop_scene):
    frames, camera, plain = bop_stream(bop_scene, (0, 1))
    ys, xs = np.nonzero(np.asarray(frames[0].mask))
    box = (int(xs.min()) - 4, int(ys.min()) - 4, int(xs.max() - xs.min()) + 9, int(ys.max() - ys.min()) + 9)
    tracker = flowfilter.Tracker(camera, plain[0], bbox=box)
    e = tracker.update(plain[1])
    assert e.state == "tracking", e.reason
    assert rotation_deg(e.transform, flowfilter.bop_motion(bop_scene, 0, 1, 1)) < 1.0
    w = np.asarray(frames[0].depth).shape[1]
    with pytest.raises(flowfilter.InputError, match="inside"):
        flowfilter.Tracker(camera, plain[0], bbox=(w - 10, 0, 50, 50))
    with pytest.raises(flowfilter.InputError, match="not both"):
        flowfilter.Tracker(camera, plain[0], mask=np.asarray(frames[0].mask), bbox=box)


def test_a_frame_of_another_size_is_lost_not_an_exception(bop_scene):
    a = flowfilter.read_bop_frame(bop_scene, 0, 1)
    tracker = flowfilter.Tracker(None, a)
    small = flowfilter.Frame(np.asarray(a.color)[:100, :100].copy(), np.asarray(a.depth)[:100, :100].copy())
    k = np.asarray(a.K)
    tracker_cam = flowfilter.Tracker(flowfilter.Camera(k, depth_unit=a.depth_unit), a)
    e = tracker_cam.update(small)
    assert e.state == "lost" and not e.registration["converged"], e.reason
    assert "another size" in e.reason or "size" in e.reason
    assert np.array_equal(e.transform, np.eye(4))
    with pytest.raises(flowfilter.InputError, match="mask"):
        flowfilter.Tracker(None, a, mask=np.ones((3, 3), bool))
    assert tracker is not None


def test_the_same_poses_as_the_cli(cli, tmp_path):
    if not SHELF.is_dir():
        pytest.skip(f"{SHELF} is absent: the real-frame tests need ../shared beside the repository")
    json_path = tmp_path / "t.jsonl"
    cli("track", "--frames", SHELF, "--camera", SHELF / "camera.json", "--max-frames", "3", "--json", json_path)
    rows = [json.loads(l) for l in json_path.read_text().splitlines()]
    frames = [flowfilter.read_frame(SHELF / f"frame-{i:06d}.color.png", SHELF / f"frame-{i:06d}.depth.png",
                                    SHELF / "camera.json") for i in range(3)]
    tracker = flowfilter.Tracker(None, frames[0])
    for i in (1, 2):
        e = tracker.update(frames[i])
        assert e.state == rows[i]["state"]
        assert np.abs(e.transform - np.array(rows[i]["pose_from_first"])).max() < 1e-9
        # The estimate from the first frame carries the bounds of that motion, as the CLI's
        # `bound_from_first`.
        assert e.registration.get("uncertainty") == rows[i]["bound_from_first"]
