"""Rerun recordings read back with rerun-sdk: `flowfilter estimate --rerun` on real frames,
a benchmark's failing pairs (`--rerun`), and `Estimate.log_to_rerun`.

Skipped without rerun-sdk (pip install rerun-sdk==0.36.3), and the CLI cases without a CLI built
with `--features rerun` (CI builds one); the real-frame cases need ../shared."""

import json
import os
import pathlib
import subprocess

import numpy as np
import pytest

import flowfilter
from conftest import ROOT, SHARED, find_cli

rr = pytest.importorskip("rerun", reason="rerun-sdk is not installed (pip install rerun-sdk==0.36.3)")
import rerun.experimental as rx  # noqa: E402

TOTE = SHARED / "realsense-shelf" / "tote"

# Every entity a recorded pair holds (docs/rerun.md); the truth's when the truth is known.
PAIR_ENTITIES = {
    "model/color", "model/depth", "model/mask", "target/color", "target/depth", "target/mask", "target/flow",
    "world/model", "world/target", "world/aligned", "world/pairs", "pose/estimate", "summary",
} | {f"timings/{s}_ms" for s in ["depth_model", "depth_target", "flow", "correspondences", "registration", "judge", "align", "total"]}
TRUTH_ENTITIES = {"world/truth", "pose/truth", "pose/error/rotation_deg", "pose/error/translation_m"}
# When the method gives error bounds.
BOUND_ENTITIES = {"pose/bound/rotation_deg", "pose/bound/translation_m"}


def entities(path):
    """Entity paths of a recording (without the leading '/'), and its `pair` timeline's presence."""
    schema = rx.RrdReader(str(path)).store().schema()
    paths = {c.entity_path.lstrip("/") for c in schema.component_columns()}
    return paths, "pair" in str(schema)


def recording_cli():
    """The CLI when it was built with the `rerun` feature, else skip."""
    path = find_cli()
    if path is None:
        pytest.skip("no flowfilter CLI build (cargo build -p flowfilter --features rerun)")
    probe = subprocess.run([str(path), "estimate", "--help"], capture_output=True, text=True, timeout=60)
    return path, probe


def run_cli(path, *args):
    done = subprocess.run([str(path), *map(str, args)], capture_output=True, text=True, timeout=600)
    if done.returncode not in (0, 3) and "features rerun" in done.stderr:
        pytest.skip("the flowfilter CLI was built without the rerun feature (cargo build -p flowfilter --features rerun)")
    assert done.returncode in (0, 3), done.stderr
    return done


def tote_truth(a, b):
    poses = json.loads((TOTE / "poses.json").read_text())["camera_to_world_calibrated"]
    ca, cb = np.array(poses[str(a)]), np.array(poses[str(b)])
    return np.linalg.inv(cb) @ ca


@pytest.fixture
def tote():
    if not TOTE.is_dir():
        pytest.skip(f"{TOTE} is absent: the real-frame tests need ../shared beside the repository")
    return TOTE


def test_estimate_records_a_failing_real_pair(tmp_path, tote):
    """Whole tote frames 54 deg apart (2 -> 3), which Flow Filter gets 62 deg wrong (`cargo xtask
    bench-real`): the recording holds every documented entity, the truth's, and the pair's warnings."""
    cli, _ = recording_cli()
    truth = tmp_path / "truth.json"
    truth.write_text(json.dumps({"transform": tote_truth(2, 3).tolist()}))
    rrd = tmp_path / "pair.rrd"
    f = lambda i, kind: tote / f"frame-{i:06d}.{kind}.png"  # noqa: E731
    done = run_cli(cli, "estimate", "--camera", tote / "camera.json", "--model-color", f(2, "color"),
                   "--model-depth", f(2, "depth"), "--target-color", f(3, "color"), "--target-depth", f(3, "depth"),
                   "--gt", truth, "--json", "--rerun", rrd)
    estimate = json.loads(done.stdout)
    assert not estimate["ground_truth"]["errors"]["success"], "this pair was meant to fail"
    found, has_pair_timeline = entities(rrd)
    assert has_pair_timeline
    missing = (PAIR_ENTITIES | TRUTH_ENTITIES) - found
    assert not missing, f"missing entities: {sorted(missing)}"
    if estimate["warnings"]:
        assert "warnings" in found
    if estimate["registration"].get("uncertainty"):
        assert BOUND_ENTITIES <= found
    if estimate.get("judge"):
        assert {"judge/candidates", "judge/score/answer"} <= found


def test_a_benchmarks_failing_pairs_are_recorded(tmp_path, tote):
    """`bench-real --rerun` (an xtask built with `--features rerun`, $FLOWFILTER_XTASK or
    target/*/xtask): ICP on the tote's region pairs fails some, and each is in the recording."""
    xtask = os.environ.get("FLOWFILTER_XTASK")
    candidates = [pathlib.Path(xtask)] if xtask else [ROOT / "target" / p / "xtask" for p in ("debug", "release")]
    xtask = next((p for p in candidates if p.is_file()), None)
    if xtask is None:
        pytest.skip("no xtask build (cargo build -p xtask --features rerun, or set FLOWFILTER_XTASK)")
    rrd = tmp_path / "failures.rrd"
    done = subprocess.run(
        [str(xtask), "bench-real", "--data", str(tote.parent), "--sequences", "tote", "--quick", "--no-whole",
         "--methods", "icp-pt2pl", "--out", str(tmp_path / "results"), "--rerun", str(rrd)],
        capture_output=True, text=True, timeout=900, cwd=ROOT,
    )
    if done.returncode != 0 and "features rerun" in done.stderr:
        pytest.skip("the xtask was built without the rerun feature (cargo build -p xtask --features rerun)")
    assert done.returncode == 0, done.stderr
    results = json.loads(next((tmp_path / "results").rglob("results.json")).read_text())
    failed = [p for p in results["pairs"] if p["method"] == "icp-pt2pl" and not p["errors"]["success"]]
    assert failed, "no pair failed: the test needs one"
    assert f"rerun: {len(failed)} failing pair(s) recorded" in done.stdout, done.stdout
    found, has_pair_timeline = entities(rrd)
    assert has_pair_timeline
    missing = (PAIR_ENTITIES | TRUTH_ENTITIES) - found
    assert not missing, f"missing entities: {sorted(missing)}"


def test_log_to_rerun_writes_the_documented_entities(tmp_path, bop_scene):
    a, b = (flowfilter.read_bop_frame(bop_scene, im, 1) for im in (0, 1))
    e = flowfilter.estimate(a, b, gt=flowfilter.bop_motion(bop_scene, 0, 1, 1))
    rrd = tmp_path / "estimate.rrd"
    rec = rr.RecordingStream("flowfilter-test")
    rec.save(str(rrd))
    e.log_to_rerun(a, b, recording=rec)
    rec.disconnect()  # closes the file (its footer written)
    found, has_pair_timeline = entities(rrd)
    assert has_pair_timeline
    expected = {"model/color", "model/depth", "model/mask", "target/color", "target/depth", "target/mask",
                "pose/estimate", "pose/truth", "pose/error/rotation_deg", "summary"}
    expected |= {f"timings/{s}_ms" for s in ["flow", "registration", "total"]}
    assert not expected - found, sorted(expected - found)
    with pytest.raises(flowfilter.InputError, match="model: expected a flowfilter.Frame"):
        e.log_to_rerun(np.zeros((2, 2)), b, recording=rec)


def test_track_records_each_frame(tmp_path):
    """`flowfilter track --rerun` on three frames of a real shelf: each frame's estimate against its
    reference, with the truth's entities (the calibrated poses)."""
    shelf = SHARED / "realsense-shelf" / "shelf-D"
    if not shelf.is_dir():
        pytest.skip(f"{shelf} is absent: the real-frame tests need ../shared beside the repository")
    cli, _ = recording_cli()
    rrd = tmp_path / "track.rrd"
    run_cli(cli, "track", "--frames", shelf, "--camera", shelf / "camera.json", "--gt", shelf / "poses.json",
            "--max-frames", "3", "--rerun", rrd)
    found, has_pair_timeline = entities(rrd)
    assert has_pair_timeline
    missing = (PAIR_ENTITIES | TRUTH_ENTITIES) - found
    assert not missing, f"missing entities: {sorted(missing)}"
