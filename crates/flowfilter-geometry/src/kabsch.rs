//! Weighted Kabsch / Umeyama: the rigid transform minimising `sum w_i |R x_i + t - y_i|^2`.

use crate::{Point3, Pose, nearest_rotation};
use nalgebra::{Matrix3, Translation3, UnitQuaternion, Vector3};

/// Why a weighted Kabsch problem has no unique solution.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum KabschError {
    /// Source and target slices have different lengths, or the weights another length.
    #[error("correspondence arrays differ in length: {sources} sources, {targets} targets, {weights} weights")]
    LengthMismatch {
        /// Number of source points.
        sources: usize,
        /// Number of target points.
        targets: usize,
        /// Number of weights.
        weights: usize,
    },
    /// Fewer than three correspondences with positive weight.
    #[error("need at least 3 correspondences with positive weight, found {found}")]
    TooFew {
        /// Number of usable correspondences.
        found: usize,
    },
    /// A coordinate or weight is NaN/inf, or a weight is negative.
    #[error("correspondence {index} has a non-finite coordinate or a negative/non-finite weight")]
    InvalidInput {
        /// Index of the first bad correspondence.
        index: usize,
    },
    /// The points are (nearly) collinear or coincident, so the rotation is not determined.
    #[error(
        "points are collinear or coincident: second singular value {sigma2:.3e} of the cross-covariance is too small"
    )]
    Degenerate {
        /// Second-largest singular value of the weighted cross-covariance.
        sigma2: f64,
    },
}

/// Solve for the rigid transform `T` minimising `sum_i w_i |T x_i - y_i|^2`.
///
/// `weights = None` weights every pair equally. Reflections are excluded (the solution is in
/// SO(3)), following Umeyama (1991).
pub fn weighted_kabsch(sources: &[Point3], targets: &[Point3], weights: Option<&[f64]>) -> Result<Pose, KabschError> {
    let n = sources.len();
    let wlen = weights.map_or(n, <[f64]>::len);
    if targets.len() != n || wlen != n {
        return Err(KabschError::LengthMismatch { sources: n, targets: targets.len(), weights: wlen });
    }
    weighted_kabsch_by(n, |i| (sources[i], targets[i], weights.map_or(1.0, |w| w[i])))
}

/// [`weighted_kabsch`] over `n` pairs read through `pair(i) = (x_i, y_i, w_i)`: the pairs need
/// not be gathered into slices first (the same sums in the same order, so the same result).
/// `pair` is called twice per index.
pub fn weighted_kabsch_by(n: usize, pair: impl Fn(usize) -> (Point3, Point3, f64)) -> Result<Pose, KabschError> {
    let mut wsum = 0.0;
    let mut cs = Vector3::zeros();
    let mut ct = Vector3::zeros();
    let mut used = 0usize;
    for i in 0..n {
        let (x, y, wi) = pair(i);
        let finite = x.coords.iter().chain(y.coords.iter()).all(|v| v.is_finite());
        if !finite || !wi.is_finite() || wi < 0.0 {
            return Err(KabschError::InvalidInput { index: i });
        }
        if wi > 0.0 {
            used += 1;
            wsum += wi;
            cs += wi * x.coords;
            ct += wi * y.coords;
        }
    }
    if used < 3 {
        return Err(KabschError::TooFew { found: used });
    }
    cs /= wsum;
    ct /= wsum;
    let mut h = Matrix3::zeros();
    let mut spread = 0.0;
    for i in 0..n {
        let (x, y, wi) = pair(i);
        if wi > 0.0 {
            let a = x.coords - cs;
            let b = y.coords - ct;
            h += wi * b * a.transpose();
            spread += wi * a.norm_squared();
        }
    }
    let mut sv = h.singular_values();
    // Sort descending to read the second singular value robustly.
    sv.as_mut_slice().sort_by(|a, b| b.total_cmp(a));
    let scale = spread.max(f64::MIN_POSITIVE);
    if sv[1] / scale < 1e-10 {
        return Err(KabschError::Degenerate { sigma2: sv[1] });
    }
    let rot = UnitQuaternion::from_rotation_matrix(&nearest_rotation(&h));
    let t = ct - rot * cs;
    Ok(Pose::from_parts(Translation3::from(t), rot))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud() -> Vec<Point3> {
        (0..50)
            .map(|i| {
                let f = i as f64;
                Point3::new((f * 0.37).sin(), (f * 0.71).cos() * 0.5, (f * 0.13).sin() * 0.3)
            })
            .collect()
    }

    #[test]
    fn recovers_exact_transform() {
        let truth = Pose::new(Vector3::new(0.1, 0.02, -0.3), Vector3::new(0.2, -0.4, 0.1));
        let src = cloud();
        let dst: Vec<_> = src.iter().map(|p| truth * p).collect();
        let est = weighted_kabsch(&src, &dst, None).unwrap();
        assert!((est.to_homogeneous() - truth.to_homogeneous()).abs().max() < 1e-10);
    }

    #[test]
    fn zero_weight_ignores_outliers() {
        let truth = Pose::new(Vector3::new(0.0, 0.1, 0.0), Vector3::new(0.0, 0.3, 0.0));
        let src = cloud();
        let mut dst: Vec<_> = src.iter().map(|p| truth * p).collect();
        let mut w = vec![1.0; src.len()];
        dst[3] = Point3::new(10.0, 10.0, 10.0);
        w[3] = 0.0;
        let est = weighted_kabsch(&src, &dst, Some(&w)).unwrap();
        assert!((est.to_homogeneous() - truth.to_homogeneous()).abs().max() < 1e-10);
    }

    #[test]
    fn accessor_form_is_the_slice_form() {
        let truth = Pose::new(Vector3::new(0.05, -0.02, 0.1), Vector3::new(-0.3, 0.2, 0.4));
        let src = cloud();
        // Noisy targets and uneven weights: a non-trivial least-squares problem.
        let dst: Vec<Point3> =
            src.iter().enumerate().map(|(i, p)| truth * p + Vector3::repeat(0.01 * (i as f64 * 1.7).sin())).collect();
        let w: Vec<f64> = (0..src.len()).map(|i| 0.5 + (i % 7) as f64).collect();
        let sliced = weighted_kabsch(&src, &dst, Some(&w)).unwrap();
        let by = weighted_kabsch_by(src.len(), |i| (src[i], dst[i], w[i])).unwrap();
        assert_eq!(sliced.to_homogeneous(), by.to_homogeneous());
        assert!((sliced * truth.inverse()).rotation.angle() < 0.05);
        assert!(matches!(weighted_kabsch_by(2, |i| (src[i], dst[i], 1.0)), Err(KabschError::TooFew { found: 2 })));
    }

    #[test]
    fn rejects_degenerate_inputs() {
        let line: Vec<_> = (0..10).map(|i| Point3::new(i as f64, 0.0, 0.0)).collect();
        assert!(matches!(weighted_kabsch(&line, &line, None), Err(KabschError::Degenerate { .. })));
        let two = &line[..2];
        assert!(matches!(weighted_kabsch(two, two, None), Err(KabschError::TooFew { found: 2 })));
        let mut bad = cloud();
        bad[4].x = f64::NAN;
        assert!(matches!(weighted_kabsch(&bad, &cloud(), None), Err(KabschError::InvalidInput { index: 4 })));
        assert!(matches!(weighted_kabsch(&cloud(), &line, None), Err(KabschError::LengthMismatch { .. })));
    }
}
