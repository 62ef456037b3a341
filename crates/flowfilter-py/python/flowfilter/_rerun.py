"""``Estimate.log_to_rerun``: an estimate (and optionally its two frames) logged with rerun-sdk.

The entity paths and the ``pair`` timeline are the Rust recorder's (``docs/rerun.md``), so a
recording made here opens like one made by ``flowfilter estimate --rerun``.
"""

from __future__ import annotations

import json

import numpy as np

from ._flowfilter import InputError

#: The stages whose times are logged as ``timings/<stage>_ms``.
STAGES = ["depth_model", "depth_target", "flow", "correspondences", "registration", "judge", "align", "total"]

#: rerun-sdk's version the recordings are written for (the Rust SDK's: ``rerun = "=0.36.3"``).
RERUN_VERSION = "0.36.3"


def _rerun():
    try:
        import rerun as rr
    except ImportError as e:
        raise ImportError(
            f"Estimate.log_to_rerun needs rerun-sdk (pip install rerun-sdk=={RERUN_VERSION})"
        ) from e
    return rr


def _frame(rr, rec, prefix: str, frame) -> None:
    """Colour, depth (metres where the unit is known) and mask of a flowfilter.Frame."""
    rr.log(f"{prefix}/color", rr.Image(np.asarray(frame.color)), recording=rec)
    depth = np.asarray(frame.depth)
    if depth.dtype == np.uint16 and frame.depth_unit:
        rr.log(f"{prefix}/depth", rr.DepthImage(depth, meter=1.0 / frame.depth_unit), recording=rec)
    elif depth.dtype == np.uint16:
        rr.log(f"{prefix}/depth", rr.DepthImage(depth), recording=rec)
    else:
        rr.log(f"{prefix}/depth", rr.DepthImage(depth.astype(np.float32), meter=1.0), recording=rec)
    if frame.mask is not None:
        mask = np.asarray(frame.mask).astype(np.uint8)
        rr.log(f"{prefix}/mask", rr.SegmentationImage(mask, opacity=0.4), recording=rec)


def log_estimate(estimate, model=None, target=None, recording=None, step: int = 0) -> None:
    """Log ``estimate`` at step ``step`` of the ``pair`` timeline of ``recording`` (a
    ``rerun.RecordingStream``; None: the current one, e.g. after ``rerun.init`` and
    ``rerun.save``/``rerun.spawn``). ``model``/``target``: the estimate's ``flowfilter.Frame``s,
    to log their images too."""
    rr = _rerun()
    for name, frame in [("model", model), ("target", target)]:
        if frame is not None and type(frame).__name__ != "Frame":
            raise InputError(f"{name}: expected a flowfilter.Frame or None, found {type(frame).__name__}")
    rec = recording
    d = estimate.to_dict()
    rr.set_time("pair", sequence=int(step), recording=rec)
    if model is not None:
        _frame(rr, rec, "model", model)
    if target is not None:
        _frame(rr, rec, "target", target)
    t = np.asarray(d["transform"], dtype=np.float64)
    rr.log("pose/estimate", rr.Transform3D(translation=t[:3, 3], mat3x3=t[:3, :3]), recording=rec)
    bounds = d["registration"].get("uncertainty")
    if bounds:
        rr.log("pose/bound/rotation_deg", rr.Scalars(bounds["rotation_deg"]), recording=rec)
        rr.log("pose/bound/translation_m", rr.Scalars(bounds["translation_m"]), recording=rec)
    truth = d.get("ground_truth")
    if truth:
        g = np.asarray(truth["transform"], dtype=np.float64)
        rr.log("pose/truth", rr.Transform3D(translation=g[:3, 3], mat3x3=g[:3, :3]), recording=rec)
        rr.log("pose/error/rotation_deg", rr.Scalars(truth["errors"]["geodesic_error_deg"]), recording=rec)
        rr.log("pose/error/translation_m", rr.Scalars(truth["errors"]["translation_error_m"]), recording=rec)
    judge = d.get("judge")
    if judge:
        rr.log("judge/score/answer", rr.Scalars(judge["answer_score"]), recording=rec)
        if judge.get("best_score") is not None:
            rr.log("judge/score/best", rr.Scalars(judge["best_score"]), recording=rec)
    for stage in STAGES:
        rr.log(f"timings/{stage}_ms", rr.Scalars(float(d["stage_ms"][stage])), recording=rec)
    for w in d["warnings"]:
        rr.log("warnings", rr.TextLog(f"{w['code']}: {w['message']}", level="WARN"), recording=rec)
    converged = "converged" if d["registration"]["converged"] else "not converged"
    text = f"# {d['model']} -> {d['target']}\n\n{converged}\n\n```json\n{json.dumps(d, indent=2)}\n```\n"
    rr.log("summary", rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), recording=rec)
