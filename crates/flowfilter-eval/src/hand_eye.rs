//! A camera's mount on a robot arm, fitted from two records of the same camera motions (the
//! hand-eye problem `A X = X B`): the arm's kinematics with a nominal mount, and a reference
//! such as a calibration's camera poses.
//!
//! Benchmarks on arm-held cameras use it to build a second truth that does not depend on the
//! reference's per-frame errors: the arm's motion `A` (camera frame, nominal mount) corrected by
//! the fitted mount `X` gives the camera's motion `X^-1 A X`. The fit is robust (Huber weights),
//! so a few badly calibrated frames in the reference do not move it.

use flowfilter_geometry::{Pose, Vector3};
use nalgebra::{Matrix6, Vector6};

/// One motion of the camera between two frames, as two records give it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionPair {
    /// The motion by the arm's kinematics and its nominal mount, `inv(A_j) * A_i` (the scene's
    /// motion in the camera frame from frame `i` to frame `j`).
    pub arm: Pose,
    /// The same motion by the reference, `inv(C_j) * C_i`.
    pub reference: Pose,
}

/// The fitted mount correction and how well the two records agree through it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MountFit {
    /// `X`: the reference's camera motion is `X^-1 * arm * X`.
    pub mount: Pose,
    /// Motions used.
    pub pairs: usize,
    /// Median rotation disagreement after the fit, degrees.
    pub median_rotation_deg: f64,
    /// Median translation disagreement after the fit, metres.
    pub median_translation_m: f64,
}

impl MountFit {
    /// The camera's motion from the arm's: `X^-1 * arm * X`.
    pub fn corrected(&self, arm: &Pose) -> Pose {
        self.mount.inverse() * arm * self.mount
    }
}

/// Why no mount can be fitted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MountFitError {
    /// Fewer than two motions were given.
    #[error("a mount needs at least 2 camera motions, found {found}")]
    TooFewMotions {
        /// Motions given.
        found: usize,
    },
    /// The motions turn about one axis only (or not at all): the mount's turn about that axis
    /// and its offset along it are not determined.
    #[error("the camera motions turn about a single axis: the mount is not determined (condition {condition:.1e})")]
    Degenerate {
        /// Smallest over largest eigenvalue of the fit's normal matrix.
        condition: f64,
    },
    /// A motion holds a non-finite number.
    #[error("camera motion {index} is not finite")]
    NotFinite {
        /// Its index.
        index: usize,
    },
}

/// Rotation disagreement that counts fully in the fit (Huber scale), radians (0.5 deg).
const ROTATION_SCALE_RAD: f64 = 0.5 * std::f64::consts::PI / 180.0;
/// Translation disagreement that counts fully in the fit (Huber scale), metres.
const TRANSLATION_SCALE_M: f64 = 0.005;
/// Gauss-Newton iterations at most.
const MAX_ITERATIONS: usize = 100;
/// Smallest over largest eigenvalue of the normal matrix below which the fit is degenerate.
const MIN_CONDITION: f64 = 1e-8;

/// Fit the mount `X` so that `X^-1 * arm * X` matches `reference` over `motions`: iteratively
/// reweighted Gauss-Newton on `X`'s twist from the identity, each motion's residual (rotation over
/// 0.5 deg, translation over 5 mm) weighted by Huber's rule.
///
/// # Errors
/// [`MountFitError`] for fewer than two motions, a non-finite one, or motions about one axis.
///
/// ```
/// use flowfilter_eval::hand_eye::{MotionPair, fit_mount};
/// use flowfilter_geometry::{Pose, Vector3};
///
/// let mount = Pose::new(Vector3::new(0.01, 0.0, -0.02), Vector3::new(0.0, 0.05, 0.02));
/// let motions: Vec<MotionPair> = [Vector3::new(0.2, 0.0, 0.0), Vector3::new(0.0, 0.25, 0.05), Vector3::new(0.1, -0.1, 0.2)]
///     .iter()
///     .map(|turn| {
///         let arm = Pose::new(Vector3::new(0.05, -0.02, 0.01), *turn);
///         MotionPair { arm, reference: mount.inverse() * arm * mount }
///     })
///     .collect();
/// let fit = fit_mount(&motions)?;
/// assert!((fit.mount.inverse() * mount).rotation.angle() < 1e-6);
/// assert!((fit.mount.translation.vector - mount.translation.vector).norm() < 1e-6);
/// # Ok::<(), flowfilter_eval::hand_eye::MountFitError>(())
/// ```
pub fn fit_mount(motions: &[MotionPair]) -> Result<MountFit, MountFitError> {
    if motions.len() < 2 {
        return Err(MountFitError::TooFewMotions { found: motions.len() });
    }
    if let Some(index) = motions.iter().position(|m| !finite(&m.arm) || !finite(&m.reference)) {
        return Err(MountFitError::NotFinite { index });
    }
    let mut mount = Pose::identity();
    for _ in 0..MAX_ITERATIONS {
        let (normal, gradient) = normal_equations(motions, &mount);
        check_conditioned(&normal)?;
        let Some(step) = normal.cholesky().map(|c| c.solve(&gradient)) else {
            return Err(MountFitError::Degenerate { condition: 0.0 });
        };
        mount *= twist(&step);
        if step.norm() < 1e-12 {
            break;
        }
    }
    let (rotations, translations): (Vec<f64>, Vec<f64>) = motions
        .iter()
        .map(|m| {
            let e = disagreement(m, &mount);
            (e.rotation.angle().to_degrees(), e.translation.vector.norm())
        })
        .unzip();
    let median = |v: &[f64]| crate::mean_median(v).map_or(0.0, |(_, m)| m);
    Ok(MountFit {
        mount,
        pairs: motions.len(),
        median_rotation_deg: median(&rotations),
        median_translation_m: median(&translations),
    })
}

/// Whether every entry of a pose is finite.
fn finite(p: &Pose) -> bool {
    p.translation.vector.iter().all(|v| v.is_finite()) && p.rotation.coords.iter().all(|v| v.is_finite())
}

/// The reference's motion undone from the corrected arm's: `inv(reference) * X^-1 * arm * X`.
fn disagreement(m: &MotionPair, mount: &Pose) -> Pose {
    m.reference.inverse() * mount.inverse() * m.arm * mount
}

/// A motion's residual, scaled: rotation vector over [`ROTATION_SCALE_RAD`], translation over
/// [`TRANSLATION_SCALE_M`].
fn residual(m: &MotionPair, mount: &Pose) -> Vector6<f64> {
    let e = disagreement(m, mount);
    let (r, t) = (e.rotation.scaled_axis() / ROTATION_SCALE_RAD, e.translation.vector / TRANSLATION_SCALE_M);
    Vector6::new(r.x, r.y, r.z, t.x, t.y, t.z)
}

/// A pose from a twist `(rotation vector, translation)` (first order is all the steps need).
fn twist(step: &Vector6<f64>) -> Pose {
    Pose::new(Vector3::new(step[3], step[4], step[5]), Vector3::new(step[0], step[1], step[2]))
}

/// The Huber-weighted normal matrix and the descent direction at `mount`, with central
/// differences for the Jacobian (six parameters, a few hundred motions: cost is no concern).
fn normal_equations(motions: &[MotionPair], mount: &Pose) -> (Matrix6<f64>, Vector6<f64>) {
    const H: f64 = 1e-6;
    let mut normal = Matrix6::zeros();
    let mut gradient = Vector6::zeros();
    for m in motions {
        let r = residual(m, mount);
        let mut jacobian = Matrix6::zeros();
        for k in 0..6 {
            let mut d = Vector6::zeros();
            d[k] = H;
            let column = (residual(m, &(mount * twist(&d))) - residual(m, &(mount * twist(&-d)))) / (2.0 * H);
            jacobian.set_column(k, &column);
        }
        let weight = if r.norm() <= 1.0 { 1.0 } else { 1.0 / r.norm() };
        normal += weight * jacobian.transpose() * jacobian;
        gradient -= weight * jacobian.transpose() * r;
    }
    (normal, gradient)
}

/// [`MountFitError::Degenerate`] when the normal matrix is (nearly) singular.
fn check_conditioned(normal: &Matrix6<f64>) -> Result<(), MountFitError> {
    let eigen = normal.symmetric_eigenvalues();
    let (lo, hi) = (eigen.min(), eigen.max());
    let condition = if hi > 0.0 { lo / hi } else { 0.0 };
    if condition < MIN_CONDITION { Err(MountFitError::Degenerate { condition }) } else { Ok(()) }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Arm motions of 10-20 deg about spread axes, 3-8 cm, drawn from a fixed sequence.
    fn arm_motions(n: usize) -> Vec<Pose> {
        (0..n)
            .map(|i| {
                let a = i as f64 * 2.399_963;
                let axis = Vector3::new(a.cos(), a.sin(), 0.4 * (1.7 * a).sin()).normalize();
                let angle = (10.0 + 10.0 * ((i * 7 % 11) as f64 / 10.0)).to_radians();
                let shift = Vector3::new(0.05 * (1.3 * a).cos(), 0.03 * a.sin(), 0.02 * (0.7 * a).cos());
                Pose::new(shift, axis * angle)
            })
            .collect()
    }

    /// A known mount (3 deg, 2 cm) is recovered from reference motions with 0.1-deg noise and
    /// five motions off by 3-5 deg (a calibration's bad frames), which the fit discounts.
    #[test]
    fn the_mount_is_recovered_despite_bad_reference_frames() {
        let mount = Pose::new(Vector3::new(0.012, -0.004, -0.015), Vector3::new(0.03, -0.04, 0.02));
        let motions: Vec<MotionPair> = arm_motions(40)
            .into_iter()
            .enumerate()
            .map(|(i, arm)| {
                let a = i as f64;
                let noise = if i % 8 == 3 { 3.0 + (i % 3) as f64 } else { 0.1 };
                let wobble = Vector3::new(a.sin(), (2.0 * a).cos(), (3.0 * a).sin()).normalize() * noise.to_radians();
                let reference =
                    Pose::new(Vector3::new(0.0005 * a.cos(), 0.0, 0.0), wobble) * mount.inverse() * arm * mount;
                MotionPair { arm, reference }
            })
            .collect();
        let fit = fit_mount(&motions).unwrap();
        let off = fit.mount.inverse() * mount;
        assert!(off.rotation.angle().to_degrees() < 0.15, "{} deg", off.rotation.angle().to_degrees());
        assert!(off.translation.vector.norm() < 0.003, "{} m", off.translation.vector.norm());
        assert_eq!(fit.pairs, 40);
        assert!(fit.median_rotation_deg < 0.2, "{}", fit.median_rotation_deg);
        // The raw arm motions disagree with the reference by about the mount's turn.
        let raw = crate::mean_median(
            &motions
                .iter()
                .map(|m| disagreement(m, &Pose::identity()).rotation.angle().to_degrees())
                .collect::<Vec<_>>(),
        )
        .unwrap()
        .1;
        assert!(raw > 0.5, "{raw}");
        let corrected = fit.corrected(&motions[0].arm);
        assert!((corrected.inverse() * motions[0].reference).rotation.angle().to_degrees() < 0.2);
    }

    /// Turns about one axis leave the mount undetermined; too few or non-finite motions are
    /// named.
    #[test]
    fn undetermined_mounts_are_errors() {
        let about_z: Vec<MotionPair> = (1..10)
            .map(|i| {
                let arm = Pose::new(Vector3::new(0.0, 0.0, 0.0), Vector3::new(0.0, 0.0, 0.1 * i as f64));
                MotionPair { arm, reference: arm }
            })
            .collect();
        assert!(matches!(fit_mount(&about_z), Err(MountFitError::Degenerate { .. })));
        assert_eq!(fit_mount(&about_z[..1]), Err(MountFitError::TooFewMotions { found: 1 }));
        let mut bad = about_z.clone();
        bad[2].arm.translation.vector.x = f64::NAN;
        assert_eq!(fit_mount(&bad), Err(MountFitError::NotFinite { index: 2 }));
    }
}
