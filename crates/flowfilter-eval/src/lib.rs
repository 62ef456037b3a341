//! Pose-error metrics.
//!
//! - [`angle_error_deg`]: the paper's metric, the absolute difference of the rotation angles
//!   (axis-angle magnitudes) of the estimate and the truth.
//! - [`geodesic_error_deg`]: the angle of `R_est R_true^T` (axis errors count too).
//! - [`translation_error_m`]: `|t_est - t_true|`.
//! - [`add_s`]: mean distance from each model point moved by the estimate to the nearest model
//!   point moved by the truth (symmetric objects are not penalised).
//! - [`PoseErrors`]: all of them for one estimate, with the success test (< 2 deg and < 1 cm).
//! - [`trajectory::trajectory_errors`]: ATE and RPE of a sequence of poses, as the TUM RGB-D
//!   benchmark defines them.
//! - [`hand_eye::fit_mount`]: a camera's mount on an arm from the arm's and a reference's
//!   records of the same motions, for a truth that does not carry the reference's per-frame
//!   errors.

#![warn(missing_docs)]

pub mod hand_eye;
pub mod trajectory;

use flowfilter_geometry::{KnnIndex, Point3, Pose};
use serde::{Deserialize, Serialize};

/// The paper's metric: `| angle(R_est) - angle(R_true) |`, degrees.
pub fn angle_error_deg(est: &Pose, truth: &Pose) -> f64 {
    (est.rotation.angle() - truth.rotation.angle()).abs().to_degrees()
}

/// Geodesic rotation error `angle(R_est R_true^-1)`, degrees.
pub fn geodesic_error_deg(est: &Pose, truth: &Pose) -> f64 {
    (est.rotation * truth.rotation.inverse()).angle().to_degrees()
}

/// Translation error `|t_est - t_true|`, metres.
pub fn translation_error_m(est: &Pose, truth: &Pose) -> f64 {
    (est.translation.vector - truth.translation.vector).norm()
}

/// ADD-S: mean over model points of the distance from the estimate-moved point to the nearest
/// truth-moved point, metres. `None` for an empty model.
pub fn add_s(est: &Pose, truth: &Pose, model: &[Point3]) -> Option<f64> {
    if model.is_empty() {
        return None;
    }
    let moved_truth: Vec<Point3> = model.iter().map(|p| truth * p).collect();
    let index = KnnIndex::new(&moved_truth);
    let sum: f64 = model.iter().map(|p| index.nearest(&(est * p)).map_or(0.0, |n| n.dist2.sqrt())).sum();
    Some(sum / model.len() as f64)
}

/// Rotation threshold of a success, degrees.
pub const SUCCESS_DEG: f64 = 2.0;
/// Translation threshold of a success, metres.
pub const SUCCESS_M: f64 = 0.01;

/// Every metric of one estimate.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PoseErrors {
    /// Paper's rotation-angle error, degrees.
    pub angle_error_deg: f64,
    /// Geodesic rotation error, degrees.
    pub geodesic_error_deg: f64,
    /// Translation error, metres.
    pub translation_error_m: f64,
    /// ADD-S, metres (when model points were given).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub add_s_m: Option<f64>,
    /// Geodesic error < 2 deg and translation error < 1 cm.
    pub success: bool,
}

impl PoseErrors {
    /// Compute all metrics.
    pub fn new(est: &Pose, truth: &Pose, model: Option<&[Point3]>) -> Self {
        let g = geodesic_error_deg(est, truth);
        let t = translation_error_m(est, truth);
        Self {
            angle_error_deg: angle_error_deg(est, truth),
            geodesic_error_deg: g,
            translation_error_m: t,
            add_s_m: model.and_then(|m| add_s(est, truth, m)),
            success: g < SUCCESS_DEG && t < SUCCESS_M,
        }
    }
}

/// Mean and median of a sample (`None` when empty).
pub fn mean_median(values: &[f64]) -> Option<(f64, f64)> {
    if values.is_empty() {
        return None;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    let median = if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) };
    Some((v.iter().sum::<f64>() / n as f64, median))
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowfilter_geometry::Vector3;

    #[test]
    fn metrics_of_known_errors() {
        let truth = Pose::new(Vector3::new(0.1, 0.0, 0.0), Vector3::new(0.0, 0.0, 20f64.to_radians()));
        // Same angle about another axis: the paper's metric is 0, the geodesic one is not.
        let tilted = Pose::new(Vector3::new(0.1, 0.0, 0.0), Vector3::new(0.0, 20f64.to_radians(), 0.0));
        assert!(angle_error_deg(&tilted, &truth) < 1e-9);
        assert!((geodesic_error_deg(&tilted, &truth) - 28.0).abs() < 0.3);
        let est = Pose::new(Vector3::new(0.1, 0.005, 0.0), Vector3::new(0.0, 0.0, 21f64.to_radians()));
        let e = PoseErrors::new(&est, &truth, None);
        assert!((e.angle_error_deg - 1.0).abs() < 1e-9 && (e.geodesic_error_deg - 1.0).abs() < 1e-9);
        assert!((e.translation_error_m - 0.005).abs() < 1e-12);
        assert!(e.success);
        assert!(!PoseErrors::new(&tilted, &truth, None).success);
    }

    #[test]
    fn add_s_ignores_symmetry() {
        // A ring is symmetric about z: a rotation about z costs nothing in ADD-S.
        let ring: Vec<Point3> = (0..360)
            .map(|i| {
                let a = (i as f64).to_radians();
                Point3::new(0.05 * a.cos(), 0.05 * a.sin(), 0.0)
            })
            .collect();
        let truth = Pose::identity();
        let spun = Pose::new(Vector3::zeros(), Vector3::new(0.0, 0.0, 0.3));
        assert!(add_s(&spun, &truth, &ring).unwrap() < 1e-3);
        let shifted = Pose::translation(0.0, 0.0, 0.01);
        assert!((add_s(&shifted, &truth, &ring).unwrap() - 0.01).abs() < 1e-9);
        assert_eq!(mean_median(&[3.0, 1.0, 2.0, 10.0]), Some((4.0, 2.5)));
    }
}

/// The README's examples, compiled and run as doctests.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
