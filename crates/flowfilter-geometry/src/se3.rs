//! The exponential and logarithm maps of SE(3), for Gauss-Newton updates on a twist.
//!
//! A twist is `xi = (rho, phi)` (translation part first, rotation part second), following the
//! convention of Barfoot, "State Estimation for Robotics" (2017), section 7.1.

use crate::Pose;
use nalgebra::{Matrix3, Translation3, UnitQuaternion, Vector3, Vector6};

fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// The left Jacobian `J(phi)` of SO(3), relating the twist's translation part to the pose's.
pub fn so3_left_jacobian(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta = phi.norm();
    let k = skew(phi);
    if theta < 1e-8 {
        return Matrix3::identity() + 0.5 * k + k * k / 6.0;
    }
    let t2 = theta * theta;
    Matrix3::identity() + (1.0 - theta.cos()) / t2 * k + (theta - theta.sin()) / (t2 * theta) * k * k
}

/// Exponential map: twist `(rho, phi)` to a pose.
pub fn exp(xi: &Vector6<f64>) -> Pose {
    let rho = Vector3::new(xi[0], xi[1], xi[2]);
    let phi = Vector3::new(xi[3], xi[4], xi[5]);
    let rot = UnitQuaternion::from_scaled_axis(phi);
    let t = so3_left_jacobian(&phi) * rho;
    Pose::from_parts(Translation3::from(t), rot)
}

/// Logarithm map: pose to twist `(rho, phi)`, the inverse of [`exp`] for rotation angles below pi.
pub fn log(pose: &Pose) -> Vector6<f64> {
    let phi = pose.rotation.scaled_axis();
    let j = so3_left_jacobian(&phi);
    let rho = j.try_inverse().unwrap_or_else(Matrix3::identity) * pose.translation.vector;
    Vector6::new(rho.x, rho.y, rho.z, phi.x, phi.y, phi.z)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn exp_log_round_trip(r in prop::array::uniform3(-0.5f64..0.5), p in prop::array::uniform3(-1.5f64..1.5)) {
            let xi = Vector6::new(r[0], r[1], r[2], p[0], p[1], p[2]);
            let back = log(&exp(&xi));
            prop_assert!((back - xi).abs().max() < 1e-9);
        }
    }

    #[test]
    fn small_twist_matches_first_order() {
        let xi = Vector6::new(1e-9, 2e-9, -1e-9, 3e-9, 0.0, -2e-9);
        let pose = exp(&xi);
        assert!((pose.translation.vector - Vector3::new(1e-9, 2e-9, -1e-9)).norm() < 1e-15);
    }
}
