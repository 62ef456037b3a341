//! The pipeline's result and its JSON schema (`flowfilter estimate --json`).
//!
//! Schema `flowfilter estimate v3` (all lengths in metres, angles in degrees, times in ms):
//! - `schema`: the string `"flowfilter estimate v3"`;
//! - `method`, `flow_estimator` (absent when the method uses no flow), `model`, `target` (frame labels);
//! - `transform`: the 4x4 row-major matrix `T` with `target ~ T * model` (colour camera frame);
//! - `rotation_angle_deg`, `rotation_axis` (unit, `[0,0,0]` for no rotation), `translation_m`;
//! - `registration`: `iterations`, `converged`, `fitness`, `inlier_rmse_m`, `sigma2` (absent for methods without a kernel width),
//!   `model_points`, `target_points`;
//! - `correspondences` (absent without flow): `tracked`, `consistent`, `inliers`, `guided`;
//! - `stage_ms`: `depth_model`, `depth_target`, `flow`, `correspondences`, `registration`, `total`;
//! - `warnings`: objects `{code, message}` (a fallback taken, flow that failed; the codes are
//!   those of [`crate::PipelineWarning::code`]);
//! - `ground_truth` (absent when unknown): `transform` and `errors` (`angle_error_deg`,
//!   `geodesic_error_deg`, `translation_error_m`, `add_s_m`, `success`).

use crate::warning::PipelineWarning;
use flowfilter_eval::PoseErrors;
use flowfilter_geometry::{Point3, Pose};
use flowfilter_registration::{Registration, Uncertainty};
use serde::{Deserialize, Serialize};

/// The schema tag of [`Estimate`]'s JSON.
pub const ESTIMATE_SCHEMA: &str = "flowfilter estimate v3";

/// What the registration backend reported.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RegistrationSummary {
    /// Iterations run.
    pub iterations: usize,
    /// Whether the backend's convergence criterion was met.
    pub converged: bool,
    /// Fraction of model points with a target neighbour within the inlier distance.
    pub fitness: f64,
    /// RMSE of those pairs, metres.
    pub inlier_rmse_m: f64,
    /// Final sigma^2 of GMM backends.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sigma2: Option<f64>,
    /// Points of the model cloud given to the backend.
    pub model_points: usize,
    /// Points of the target cloud.
    pub target_points: usize,
    /// The backend's error bounds, when it gives them (Flow Filter; see `Uncertainty`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub uncertainty: Option<Uncertainty>,
}

impl RegistrationSummary {
    /// The summary of `r`, a registration of clouds of `model_points` and `target_points`.
    pub fn new(r: &Registration, model_points: usize, target_points: usize) -> Self {
        Self {
            iterations: r.iterations,
            converged: r.converged,
            fitness: r.fitness,
            inlier_rmse_m: r.inlier_rmse,
            sigma2: r.sigma2,
            model_points,
            target_points,
            uncertainty: r.uncertainty,
        }
    }
}

/// How many flow correspondences survived each check.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct CorrespondenceSummary {
    /// Model pixels tracked.
    pub tracked: usize,
    /// Pairs that passed the consistency, mask and depth checks.
    pub consistent: usize,
    /// Pairs kept by the depth-change fit (weight > 0).
    pub inliers: usize,
    /// Whether the pairs come from tracking guided by the geometric prediction.
    pub guided: bool,
}

/// Wall time per stage, milliseconds.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct StageTimes {
    /// Depth stage and cloud of the model frame.
    pub depth_model: f64,
    /// Depth stage and cloud of the target frame.
    pub depth_target: f64,
    /// Optical flow (forward and backward).
    pub flow: f64,
    /// Correspondence geometry and checks.
    pub correspondences: f64,
    /// Registration.
    pub registration: f64,
    /// The photometric judge, with any re-tracking and re-registration it ran.
    #[serde(default)]
    pub judge: f64,
    /// The direct alignment.
    #[serde(default)]
    pub align: f64,
    /// Everything.
    pub total: f64,
}

/// The ground truth and the estimate's errors against it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GroundTruth {
    /// The true transform, row-major 4x4.
    pub transform: [[f64; 4]; 4],
    /// Errors of the estimate.
    pub errors: PoseErrors,
}

/// The pipeline's estimate of the relative pose between two frames.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Estimate {
    /// Always [`ESTIMATE_SCHEMA`].
    pub schema: &'static str,
    /// Registration method.
    pub method: String,
    /// Flow estimator (methods that use flow).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub flow_estimator: Option<String>,
    /// Model frame label.
    pub model: String,
    /// Target frame label.
    pub target: String,
    /// `T` with `target ~ T * model`, row-major.
    pub transform: [[f64; 4]; 4],
    /// Rotation angle of `T`.
    pub rotation_angle_deg: f64,
    /// Rotation axis of `T`.
    pub rotation_axis: [f64; 3],
    /// Translation of `T`.
    pub translation_m: [f64; 3],
    /// Backend report.
    pub registration: RegistrationSummary,
    /// Flow correspondences.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub correspondences: Option<CorrespondenceSummary>,
    /// Time per stage.
    pub stage_ms: StageTimes,
    /// What the photometric judge saw (methods that use flow correspondences).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub judge: Option<crate::judge::JudgeReport>,
    /// What the direct alignment did (methods that use flow correspondences).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub align: Option<crate::align::AlignReport>,
    /// A scene's geometry-first try (`[geometry_first]`): whether its geometric registration was
    /// kept without flow, and what the images said of it; absent where it did not run.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geometry_first: Option<crate::geometry_first::GeometryFirstReport>,
    /// Conditions the caller should know about.
    pub warnings: Vec<PipelineWarning>,
    /// Ground truth, when known.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ground_truth: Option<GroundTruth>,
    /// The estimate as a pose.
    #[serde(skip)]
    pub pose: Pose,
}

/// Row-major 4x4 of a pose.
pub fn matrix_rows(p: &Pose) -> [[f64; 4]; 4] {
    let m = p.to_homogeneous();
    std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)]))
}

impl Estimate {
    /// The estimate with another pose (its transform, angle, axis and translation with it): a
    /// tracker reports the motion from the first frame this way.
    pub fn with_pose(mut self, pose: Pose) -> Self {
        let (axis, angle) = pose.rotation.axis_angle().map_or(([0.0; 3], 0.0), |(a, t)| ([a.x, a.y, a.z], t));
        let t = pose.translation.vector;
        self.transform = matrix_rows(&pose);
        self.rotation_angle_deg = angle.to_degrees();
        self.rotation_axis = axis;
        self.translation_m = [t.x, t.y, t.z];
        self.pose = pose;
        self
    }

    /// Attach the ground truth; `model_points` (the model cloud) gives ADD-S.
    pub fn with_ground_truth(mut self, truth: &Pose, model_points: Option<&[Point3]>) -> Self {
        self.ground_truth = Some(GroundTruth {
            transform: matrix_rows(truth),
            errors: PoseErrors::new(&self.pose, truth, model_points),
        });
        self
    }
}

/// The schema tag of [`RegisterReport`]'s JSON (`flowfilter register --json`).
pub const REGISTER_SCHEMA: &str = "flowfilter register v1";

/// Wall time of a registration alone, milliseconds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RegisterTimes {
    /// The backend's `register` call.
    pub registration: f64,
    /// The same (no other stage runs).
    pub total: f64,
}

/// One registration of two clouds, as `flowfilter register --json` and the Python package's
/// `RegistrationResult.to_dict()` report it (the names of [`Estimate`] for the same quantities).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RegisterReport {
    /// Always [`REGISTER_SCHEMA`].
    pub schema: &'static str,
    /// The backend's name.
    pub method: String,
    /// `T` with `target ~ T * source`, row-major.
    pub transform: [[f64; 4]; 4],
    /// Rotation angle of `T`.
    pub rotation_angle_deg: f64,
    /// Rotation axis of `T` (`[0, 0, 0]` for no rotation).
    pub rotation_axis: [f64; 3],
    /// Translation of `T`.
    pub translation_m: [f64; 3],
    /// Backend report.
    pub registration: RegistrationSummary,
    /// Time taken.
    pub stage_ms: RegisterTimes,
    /// Conditions the caller should know about.
    pub warnings: Vec<flowfilter_registration::RegistrationWarning>,
}

impl RegisterReport {
    /// The report of `r`, made by backend `method` from clouds of `source_points` and
    /// `target_points` in `ms` milliseconds.
    pub fn new(method: &str, r: &Registration, source_points: usize, target_points: usize, ms: f64) -> Self {
        let (axis, angle) = r.transform.rotation.axis_angle().map_or(([0.0; 3], 0.0), |(a, t)| ([a.x, a.y, a.z], t));
        let t = r.transform.translation.vector;
        Self {
            schema: REGISTER_SCHEMA,
            method: method.into(),
            transform: matrix_rows(&r.transform),
            rotation_angle_deg: angle.to_degrees(),
            rotation_axis: axis,
            translation_m: [t.x, t.y, t.z],
            registration: RegistrationSummary::new(r, source_points, target_points),
            stage_ms: RegisterTimes { registration: ms, total: ms },
            warnings: r.warnings.clone(),
        }
    }
}
