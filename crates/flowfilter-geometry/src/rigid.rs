//! Validation of 4x4 homogeneous matrices as rigid transforms, and conversions.

use crate::Pose;
use nalgebra::{Matrix3, Matrix4, Rotation3, Translation3, UnitQuaternion};

/// Why a 4x4 matrix is not a rigid transform.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RigidTransformError {
    /// An entry is NaN or infinite.
    #[error("matrix entry ({row}, {col}) is not finite (found {value})")]
    NonFinite {
        /// Row of the offending entry.
        row: usize,
        /// Column of the offending entry.
        col: usize,
        /// The value found.
        value: f64,
    },
    /// The last row is not `[0 0 0 1]`.
    #[error("last row must be [0 0 0 1], found {found:?}")]
    BadLastRow {
        /// The last row as found.
        found: [f64; 4],
    },
    /// `R^T R` differs from the identity by more than the tolerance.
    #[error("rotation block is not orthonormal: max |R^T R - I| = {deviation:.3e} (tolerance {tolerance:.1e})")]
    NotOrthonormal {
        /// Largest absolute deviation of `R^T R` from the identity.
        deviation: f64,
        /// Tolerance used.
        tolerance: f64,
    },
    /// The translation is longer than [`crate::MAX_COORDINATE_M`] (a unit or file error).
    #[error("translation is {norm:e} m long, beyond the {limit:e} m any scene spans (wrong unit or a damaged file?)")]
    TranslationTooLarge {
        /// Length of the translation found.
        norm: f64,
        /// The limit.
        limit: f64,
    },
    /// The determinant of the rotation block is not +1 (a reflection, or scaling).
    #[error("rotation block has determinant {det:.6}, expected +1")]
    BadDeterminant {
        /// Determinant found.
        det: f64,
    },
}

/// Tolerance on `|R^T R - I|` accepted by [`rigid_from_matrix`]; calibration files store
/// float64 rotations that are orthonormal to about 1e-9, files written in float32 to about 1e-6.
pub const ORTHONORMAL_TOLERANCE: f64 = 1e-4;

/// Validate a 4x4 homogeneous matrix and convert it into a [`Pose`].
///
/// The rotation block is re-orthonormalised (nearest rotation) after validation, so tiny
/// round-off in stored matrices does not accumulate through chains of transforms.
pub fn rigid_from_matrix(m: &Matrix4<f64>) -> Result<Pose, RigidTransformError> {
    for row in 0..4 {
        for col in 0..4 {
            let value = m[(row, col)];
            if !value.is_finite() {
                return Err(RigidTransformError::NonFinite { row, col, value });
            }
        }
    }
    let last = [m[(3, 0)], m[(3, 1)], m[(3, 2)], m[(3, 3)]];
    if last[0].abs() > 1e-9 || last[1].abs() > 1e-9 || last[2].abs() > 1e-9 || (last[3] - 1.0).abs() > 1e-9 {
        return Err(RigidTransformError::BadLastRow { found: last });
    }
    let r: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into_owned();
    let deviation = (r.transpose() * r - Matrix3::identity()).abs().max();
    if deviation > ORTHONORMAL_TOLERANCE {
        return Err(RigidTransformError::NotOrthonormal { deviation, tolerance: ORTHONORMAL_TOLERANCE });
    }
    let det = r.determinant();
    if (det - 1.0).abs() > 1e-3 {
        return Err(RigidTransformError::BadDeterminant { det });
    }
    let t = Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]);
    let norm = t.vector.norm();
    if norm > crate::MAX_COORDINATE_M {
        return Err(RigidTransformError::TranslationTooLarge { norm, limit: crate::MAX_COORDINATE_M });
    }
    Ok(Pose::from_parts(t, UnitQuaternion::from_rotation_matrix(&nearest_rotation(&r))))
}

/// The rotation nearest (in Frobenius norm) to a 3x3 matrix with positive determinant.
pub fn nearest_rotation(r: &Matrix3<f64>) -> Rotation3<f64> {
    let svd = r.svd(true, true);
    let (u, v_t) = (svd.u.expect("requested U"), svd.v_t.expect("requested V^T"));
    let mut d = Matrix3::identity();
    if (u * v_t).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    Rotation3::from_matrix_unchecked(u * d * v_t)
}

/// The 4x4 homogeneous matrix of a pose.
pub fn matrix_from_pose(pose: &Pose) -> Matrix4<f64> {
    pose.to_homogeneous()
}

/// Rotation angle of a pose (axis-angle magnitude), in degrees, in `[0, 180]`.
pub fn rotation_angle_deg(pose: &Pose) -> f64 {
    pose.rotation.angle().to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn accepts_rigid_and_round_trips() {
        let pose = Pose::new(Vector3::new(0.1, -0.2, 0.9), Vector3::new(0.3, -0.1, 0.2));
        let back = rigid_from_matrix(&matrix_from_pose(&pose)).unwrap();
        assert!((back.to_homogeneous() - pose.to_homogeneous()).abs().max() < 1e-12);
    }

    #[test]
    fn rejects_nan() {
        let mut m = Matrix4::identity();
        m[(1, 2)] = f64::NAN;
        assert!(matches!(rigid_from_matrix(&m), Err(RigidTransformError::NonFinite { row: 1, col: 2, .. })));
    }

    #[test]
    fn rejects_scaled_and_reflected() {
        let mut m = Matrix4::identity();
        m[(0, 0)] = 1.1;
        assert!(matches!(rigid_from_matrix(&m), Err(RigidTransformError::NotOrthonormal { .. })));
        let mut m = Matrix4::identity();
        m[(2, 2)] = -1.0;
        assert!(matches!(rigid_from_matrix(&m), Err(RigidTransformError::BadDeterminant { .. })));
    }

    #[test]
    fn rejects_projective_last_row() {
        let mut m = Matrix4::identity();
        m[(3, 0)] = 0.5;
        let err = rigid_from_matrix(&m).unwrap_err();
        assert!(err.to_string().contains("last row"), "{err}");
    }

    #[test]
    fn angle_of_known_rotation() {
        let pose = Pose::new(Vector3::zeros(), Vector3::new(0.0, 0.0, 30f64.to_radians()));
        assert!((rotation_angle_deg(&pose) - 30.0).abs() < 1e-10);
    }
}
