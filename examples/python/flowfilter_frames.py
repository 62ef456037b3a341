"""Flow Filter on two RGB-D frames: the object's motion from colour, depth and a mask.

    python examples/python/flowfilter_frames.py [DIR]

DIR is a BOP scene folder (scene_camera.json, rgb/, depth/, mask_visib/) or a folder of
YCB-Video frames (NNNNNN-color.png, -depth.png, -label.png, -gt.json). Default: the real
YCB-Video sample in ../shared/data when it is there, else the repository's tiny BOP fixture.
"""

import json
import pathlib
import sys

import numpy as np

import flowfilter

ROOT = pathlib.Path(__file__).resolve().parents[2]
REAL = ROOT.parent / "shared" / "data" / "ycb-video" / "0001"


def geodesic_deg(a, b):
    d = a[:3, :3] @ b[:3, :3].T
    return float(np.degrees(np.arccos(np.clip((np.trace(d) - 1) / 2, -1, 1))))


def bop_pair(scene):
    """The first object annotated in the scene's first and last images."""
    images = flowfilter.bop_objects(scene)
    (first, objects), (last, _) = images[0], images[-1]
    obj = objects[0]
    frames = flowfilter.read_bop_frame(scene, first, obj), flowfilter.read_bop_frame(scene, last, obj)
    return frames, flowfilter.bop_motion(scene, first, last, obj), f"object {obj}, image {first} -> {last}"


def ycb_video_pair(folder, class_id=2, a=1, b=3):
    """Object `class_id` (the cracker box) in frames a and b; the truth from the gt.json poses."""

    def frame(i):
        stem = folder / f"{i:06d}"
        camera = f"{stem}-gt.json"
        f = flowfilter.read_frame(f"{stem}-color.png", f"{stem}-depth.png", camera, mask=f"{stem}-label.png", label=class_id)
        gt = json.loads(pathlib.Path(camera).read_text())
        pose = next(np.array(o["T_camera_from_object"]) for o in gt["objects"] if o["class_id"] == class_id)
        return f, pose

    (fa, pa), (fb, pb) = frame(a), frame(b)
    return (fa, fb), pb @ np.linalg.inv(pa), f"class {class_id}, frame {a} -> {b}"


def main():
    folder = pathlib.Path(sys.argv[1]) if len(sys.argv) > 1 else (REAL if REAL.is_dir() else ROOT / "fixtures" / "bop" / "000001")
    pair = bop_pair if (folder / "scene_camera.json").is_file() else ycb_video_pair
    (model, target), truth, what = pair(folder)
    print(f"{folder}: {what}")
    for method in ["flowfilter", "filterreg-pt2pl", "icp-pt2pl"]:
        e = flowfilter.estimate(model, target, method=method, gt=truth)
        err = e.ground_truth["errors"]
        bounds = e.registration.get("uncertainty")
        print(f"{method:>16}: {e.rotation_angle_deg:.3f} deg moved (true {geodesic_deg(truth, np.eye(4)):.3f}), "
              f"geodesic error {err['geodesic_error_deg']:.3f} deg, translation error {err['translation_error_m'] * 1e3:.2f} mm"
              + (f", bounds {bounds['rotation_deg']:.3f} deg" if bounds else ""))
        for w in e.warnings:
            print(f"{'':>18}warning ({w['code']})")


if __name__ == "__main__":
    main()
