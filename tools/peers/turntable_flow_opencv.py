#!/usr/bin/env python3
"""OpenCV's DIS beside ours and our network on synthesised turntable pairs (issue #9's held-out
comparison), on exactly the same images.

Each pair directory is a `flowfilter truth-flow` output (from.png, to.png, flow.flo,
occlusion.png, object.png) holding the estimates of our methods as `<name>.flo` (written by
`flowfilter flow --method <name> --out <name>.flo`). Scores the non-occluded object pixels, as
`turntable_flow` does; prints per-object and overall means of the per-pair EPE.

    for o in 004_sugar_box 005_tomato_soup_can 006_mustard_bottle; do for c in NP1 NP3 NP5; do
      for s in 3 9 15; do d=/tmp/heldout_pairs/${o}_${c}_$s
        flowfilter truth-flow --mesh ../shared/data/ycb/$o/textured.obj --camera $c --from 0 --to $s \
            --noise carmine --seed 1 --out $d
        for m in dis net; do flowfilter flow --from $d/from.png --to $d/to.png --method $m --out $d/$m.flo; done
      done; done; done
    python3 tools/peers/turntable_flow_opencv.py /tmp/heldout_pairs dis net
"""
import sys
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from flow_opencv import read_flo  # noqa: E402


def main():
    root, ours = Path(sys.argv[1]), sys.argv[2:]
    cv2.setNumThreads(2)
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    per_object = defaultdict(lambda: defaultdict(list))
    for d in sorted(p for p in root.iterdir() if (p / "flow.flo").is_file()):
        obj = d.name.rsplit("_", 2)[0]
        a = cv2.imread(str(d / "from.png"), cv2.IMREAD_GRAYSCALE)
        b = cv2.imread(str(d / "to.png"), cv2.IMREAD_GRAYSCALE)
        truth = read_flo(d / "flow.flo")
        keep = (cv2.imread(str(d / "object.png"), cv2.IMREAD_GRAYSCALE) > 0) & (
            cv2.imread(str(d / "occlusion.png"), cv2.IMREAD_GRAYSCALE) == 0) & np.isfinite(truth).all(axis=2) & (
            np.abs(truth).max(axis=2) < 1e9)
        estimates = {"opencv-dis-medium": dis.calc(a, b, None)}
        for name in ours:
            estimates[name] = read_flo(d / f"{name}.flo")
        for name, f in estimates.items():
            err = np.sqrt(((f - truth) ** 2).sum(axis=2))[keep]
            per_object[obj][name].append(float(err.mean()))
    names = ["opencv-dis-medium"] + ours
    print("| object | pairs | " + " | ".join(names) + " |")
    print("| --- | --- | " + " | ".join("---" for _ in names) + " |")
    everything = defaultdict(list)
    for obj, scores in sorted(per_object.items()):
        print(f"| {obj} | {len(scores[names[0]])} | " + " | ".join(f"{np.mean(scores[n]):.3f}" for n in names) + " |")
        for n in names:
            everything[n] += scores[n]
    print(f"| all | {len(everything[names[0]])} | " + " | ".join(f"{np.mean(everything[n]):.3f}" for n in names) + " |")


if __name__ == "__main__":
    main()
