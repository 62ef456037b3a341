//! Trajectory metrics as the TUM RGB-D benchmark defines them (Sturm et al. 2012; `evo`'s
//! `evo_ape` / `evo_rpe` with `--align` and `--delta 1 --delta_unit f`), for poses given frame by
//! frame (the same frames in the estimate and the truth, no time association needed).

use flowfilter_geometry::{Point3, Pose, weighted_kabsch};
use serde::{Deserialize, Serialize};

/// Absolute and relative errors of a trajectory against the truth.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TrajectoryErrors {
    /// Frames compared.
    pub frames: usize,
    /// Absolute trajectory error: RMSE of the positions after the rigid alignment that
    /// minimises it (Horn), metres.
    pub ate_rmse_m: f64,
    /// Relative pose error over one frame: RMSE of the translational error, metres.
    pub rpe_rmse_m: f64,
    /// ... and the mean rotational error, degrees.
    pub rpe_mean_deg: f64,
    /// Rotation error of the last frame (geodesic, no alignment), degrees: a loop's closure
    /// error when the sequence ends where it started.
    pub final_rotation_deg: f64,
    /// Translation error of the last frame (`|t_est - t_true|`), metres.
    pub final_translation_m: f64,
}

/// The errors of `estimate` against `truth` (the same length, at least 2 frames; `None`
/// otherwise).
///
/// ```
/// use flowfilter_eval::trajectory::trajectory_errors;
/// use flowfilter_geometry::{Pose, Vector3};
///
/// // A camera on a curve, turning as it goes.
/// let truth: Vec<Pose> = (0..10)
///     .map(|k| {
///         let k = k as f64;
///         Pose::new(Vector3::new(0.01 * k, 0.05 * (0.5 * k).sin(), 0.02 * (0.3 * k).cos()), Vector3::new(0.0, 0.02 * k, 0.0))
///     })
///     .collect();
/// let shifted: Vec<Pose> = truth.iter().map(|p| Pose::translation(0.0, 0.0, 0.05) * p).collect();
/// let e = trajectory_errors(&shifted, &truth).unwrap();
/// assert!(e.ate_rmse_m < 1e-9 && e.rpe_rmse_m < 1e-9, "{e:?}"); // a rigid offset aligns away
/// assert!((e.final_translation_m - 0.05).abs() < 1e-9);        // the last frame's error does not
/// ```
pub fn trajectory_errors(estimate: &[Pose], truth: &[Pose]) -> Option<TrajectoryErrors> {
    if estimate.len() != truth.len() || estimate.len() < 2 {
        return None;
    }
    let n = estimate.len();
    let positions =
        |poses: &[Pose]| -> Vec<Point3> { poses.iter().map(|p| Point3::from(p.translation.vector)).collect() };
    let (est, gt) = (positions(estimate), positions(truth));
    let align = weighted_kabsch(&est, &gt, None).unwrap_or_else(|_| Pose::identity());
    let ate = (est.iter().zip(&gt).map(|(e, g)| (align * e - g).norm_squared()).sum::<f64>() / n as f64).sqrt();
    let relative = |poses: &[Pose], k: usize| poses[k].inverse() * poses[k + 1];
    let (mut sum_t2, mut sum_r) = (0.0, 0.0);
    for k in 0..n - 1 {
        let e = relative(truth, k).inverse() * relative(estimate, k);
        sum_t2 += e.translation.vector.norm_squared();
        sum_r += e.rotation.angle().to_degrees();
    }
    Some(TrajectoryErrors {
        frames: n,
        ate_rmse_m: ate,
        rpe_rmse_m: (sum_t2 / (n - 1) as f64).sqrt(),
        rpe_mean_deg: sum_r / (n - 1) as f64,
        final_rotation_deg: crate::geodesic_error_deg(&estimate[n - 1], &truth[n - 1]),
        final_translation_m: crate::translation_error_m(&estimate[n - 1], &truth[n - 1]),
    })
}
