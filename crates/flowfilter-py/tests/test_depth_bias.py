"""A camera file's `depth_bias` (as `flowfilter calibrate-depth` writes it) corrects depth once:
frames read from files with the camera, and frames made from arrays when the camera is given."""

import json

import numpy as np

import flowfilter


def test_a_camera_with_a_depth_bias_corrects_depth_once(bop_scene, tmp_path):
    color, depth = bop_scene / "rgb" / "000000.png", bop_scene / "depth" / "000000.png"
    plain = flowfilter.read_frame(color, depth, flowfilter.read_camera(bop_scene / "scene_camera.json"))
    h, w = plain.depth.shape
    camera = {
        "K": plain.K.tolist(),
        "width": w,
        "height": h,
        "depth_unit_m": plain.depth_unit,
        # 5 mm too far everywhere: 50 raw units of 0.1 mm.
        "depth_bias": {"cols": 2, "rows": 2, "width": w, "height": h, "metres": [0.005] * 4},
    }
    path = tmp_path / "camera.json"
    path.write_text(json.dumps(camera))
    corrected = flowfilter.read_frame(color, depth, path)
    valid = plain.depth > 0
    assert valid.sum() > 1000
    assert np.array_equal(corrected.depth[valid], plain.depth[valid] - 50)
    assert np.array_equal(corrected.depth[~valid], plain.depth[~valid])
    # Frames made from the raw arrays with the camera are corrected once; frames read with it
    # are not corrected again when the camera is given: the same estimate.
    scene_camera = flowfilter.read_camera(bop_scene / "scene_camera.json")
    files = [(bop_scene / "rgb" / f"{im:06d}.png", bop_scene / "depth" / f"{im:06d}.png") for im in (0, 1)]
    raw = [flowfilter.read_frame(c, d, scene_camera) for c, d in files]
    arrays = [flowfilter.Frame(f.color, f.depth, depth_scale=1.0 / f.depth_unit) for f in raw]
    read = [flowfilter.read_frame(c, d, path) for c, d in files]
    assert np.array_equal(flowfilter.estimate(*arrays, path).transform, flowfilter.estimate(*read, path).transform)
    # A bias over another image size is refused by name.
    camera["depth_bias"]["width"] = w // 2
    path.write_text(json.dumps(camera))
    try:
        flowfilter.read_frame(color, depth, path)
    except Exception as e:  # noqa: BLE001 - the package's error type
        assert "depth_bias" in str(e) and f"{w // 2}x{h}" in str(e), str(e)
    else:
        raise AssertionError("a depth_bias of another size was accepted")
