//! The recording's layout: timelines and entity paths. They are part of the public interface
//! (documented in the repository's `docs/rerun.md`) and stay the same across releases; new
//! entities may be added.

/// Sequence timeline of a pair: 0 for `estimate`, the failing pair's number in a benchmark's
/// recording.
pub const TIMELINE_PAIR: &str = "pair";

/// Model frame: colour image (RGB).
pub const MODEL_COLOR: &str = "model/color";
/// Model frame: depth on the colour grid (metres).
pub const MODEL_DEPTH: &str = "model/depth";
/// Model frame: the object mask (segmentation: 1 = object).
pub const MODEL_MASK: &str = "model/mask";

/// Target frame: colour image.
pub const TARGET_COLOR: &str = "target/color";
/// Target frame: depth on the colour grid (metres).
pub const TARGET_DEPTH: &str = "target/depth";
/// Target frame: the object mask used (propagated from the model's when the target had none).
pub const TARGET_MASK: &str = "target/mask";
/// Flow pairs drawn on the target image: arrows from each model pixel to where the flow put it;
/// green when the pair agrees with the estimate, red when not, grey for pairs of sets the
/// registration did not keep.
pub const TARGET_FLOW: &str = "target/flow";

/// The model cloud as prepared (model camera frame), before alignment.
pub const CLOUD_MODEL: &str = "world/model";
/// The target cloud (target camera frame: the world of the 3-D view).
pub const CLOUD_TARGET: &str = "world/target";
/// The model cloud moved by the estimate.
pub const CLOUD_ALIGNED: &str = "world/aligned";
/// The model cloud moved by the true motion, when it is known.
pub const CLOUD_TRUTH: &str = "world/truth";
/// The kept set's flow pairs in 3-D: segments from each model point moved by the estimate to
/// its target point, coloured as [`TARGET_FLOW`].
pub const WORLD_PAIRS: &str = "world/pairs";
/// The model cloud moved by the judge's best candidate, when the judge weighed any.
pub const CLOUD_BEST_CANDIDATE: &str = "world/judge_best";

/// The estimate as a transform (`target ~ T * model`).
pub const POSE_ESTIMATE: &str = "pose/estimate";
/// The true motion, when known.
pub const POSE_TRUTH: &str = "pose/truth";
/// The estimate's rotation bound (degrees), when the method gives bounds.
pub const BOUND_ROTATION: &str = "pose/bound/rotation_deg";
/// The estimate's translation bound (metres).
pub const BOUND_TRANSLATION: &str = "pose/bound/translation_m";
/// Geodesic rotation error against the truth (degrees), when known.
pub const ERROR_ROTATION: &str = "pose/error/rotation_deg";
/// Translation error against the truth (metres), when known.
pub const ERROR_TRANSLATION: &str = "pose/error/translation_m";

/// The judge's candidates as a table (axis, turn, score): a Markdown document.
pub const JUDGE_CANDIDATES: &str = "judge/candidates";
/// The judge's score of the registration's answer (lower agrees better with the image).
pub const JUDGE_ANSWER_SCORE: &str = "judge/score/answer";
/// The best candidate's score.
pub const JUDGE_BEST_SCORE: &str = "judge/score/best";

/// The warnings, one log line each.
pub const WARNINGS: &str = "warnings";
/// The estimate as `flowfilter estimate --json` prints it (a Markdown document).
pub const SUMMARY: &str = "summary";

/// Per-stage time in milliseconds: `timings/<stage>_ms` for the stages of
/// [`STAGES`].
pub fn timing(stage: &str) -> String {
    format!("timings/{stage}_ms")
}

/// The stages whose times are recorded (the fields of `stage_ms` in `estimate --json`).
pub const STAGES: [&str; 8] =
    ["depth_model", "depth_target", "flow", "correspondences", "registration", "judge", "align", "total"];
