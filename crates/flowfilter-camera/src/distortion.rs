//! Brown-Conrady lens distortion (OpenCV's 5-coefficient model).

use crate::error::{CameraError, finite};
use serde::{Deserialize, Serialize};

/// Radial-tangential distortion of normalised image coordinates, OpenCV order `k1 k2 p1 p2 k3`:
///
/// `x_d = x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2)`
/// `y_d = y (1 + k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 y^2) + 2 p2 x y`
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Distortion {
    /// Radial coefficient of r^2.
    pub k1: f64,
    /// Radial coefficient of r^4.
    pub k2: f64,
    /// Tangential coefficient 1.
    pub p1: f64,
    /// Tangential coefficient 2.
    pub p2: f64,
    /// Radial coefficient of r^6.
    pub k3: f64,
}

/// Undistortion stops when the distorted position is reproduced to this (normalised units);
/// at focal lengths of ~1000 px this is far below 1e-6 px.
const UNDISTORT_TOLERANCE: f64 = 1e-13;
const UNDISTORT_MAX_ITERATIONS: usize = 50;

impl Distortion {
    /// No distortion.
    pub const NONE: Self = Self { k1: 0.0, k2: 0.0, p1: 0.0, p2: 0.0, k3: 0.0 };

    /// From the 5 coefficients in OpenCV order, validated finite.
    pub fn from_slice(d: &[f64]) -> Result<Self, CameraError> {
        if d.len() != 5 {
            return Err(CameraError::DistortionLength { found: d.len() });
        }
        Ok(Self {
            k1: finite("k1", d[0])?,
            k2: finite("k2", d[1])?,
            p1: finite("p1", d[2])?,
            p2: finite("p2", d[3])?,
            k3: finite("k3", d[4])?,
        })
    }

    /// The coefficients in OpenCV order.
    pub fn to_array(&self) -> [f64; 5] {
        [self.k1, self.k2, self.p1, self.p2, self.k3]
    }

    /// Whether all coefficients are zero.
    pub fn is_none(&self) -> bool {
        self.to_array().iter().all(|c| *c == 0.0)
    }

    /// Distort normalised coordinates.
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
        (xd, yd)
    }

    /// Jacobian of [`Distortion::distort`] at `(x, y)`, row-major `[[dxd/dx, dxd/dy], [dyd/dx, dyd/dy]]`.
    pub(crate) fn jacobian(&self, x: f64, y: f64) -> [[f64; 2]; 2] {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let dradial_dr2 = self.k1 + r2 * (2.0 * self.k2 + 3.0 * r2 * self.k3);
        let (drx, dry) = (2.0 * x * dradial_dr2, 2.0 * y * dradial_dr2);
        [
            [radial + x * drx + 2.0 * self.p1 * y + 6.0 * self.p2 * x, x * dry + 2.0 * self.p1 * x + 2.0 * self.p2 * y],
            [y * drx + 2.0 * self.p1 * x + 2.0 * self.p2 * y, radial + y * dry + 6.0 * self.p1 * y + 2.0 * self.p2 * x],
        ]
    }

    /// Undistort normalised coordinates by Newton iterations on [`Distortion::distort`], starting
    /// from the distorted point. Returns `None` if it does not converge (far outside the region
    /// where the polynomial model is invertible).
    pub fn undistort(&self, xd: f64, yd: f64) -> Option<(f64, f64)> {
        if self.is_none() {
            return Some((xd, yd));
        }
        let (mut x, mut y) = (xd, yd);
        for _ in 0..UNDISTORT_MAX_ITERATIONS {
            let (fx, fy) = self.distort(x, y);
            let (ex, ey) = (fx - xd, fy - yd);
            if ex.abs() < UNDISTORT_TOLERANCE && ey.abs() < UNDISTORT_TOLERANCE {
                return Some((x, y));
            }
            let j = self.jacobian(x, y);
            let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
            if !det.is_finite() || det.abs() < 1e-12 {
                return None;
            }
            x -= (j[1][1] * ex - j[0][1] * ey) / det;
            y -= (-j[1][0] * ex + j[0][0] * ey) / det;
        }
        let (fx, fy) = self.distort(x, y);
        ((fx - xd).abs() < 1e-10 && (fy - yd).abs() < 1e-10).then_some((x, y))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jacobian_matches_finite_differences() {
        let d = Distortion { k1: 0.12, k2: -0.25, p1: 0.001, p2: -0.0015, k3: 0.08 };
        let (x, y, h) = (0.31, -0.22, 1e-7);
        let j = d.jacobian(x, y);
        let (ax, ay) = d.distort(x + h, y);
        let (bx, by) = d.distort(x - h, y);
        assert!(((ax - bx) / (2.0 * h) - j[0][0]).abs() < 1e-6);
        assert!(((ay - by) / (2.0 * h) - j[1][0]).abs() < 1e-6);
        let (ax, ay) = d.distort(x, y + h);
        let (bx, by) = d.distort(x, y - h);
        assert!(((ax - bx) / (2.0 * h) - j[0][1]).abs() < 1e-6);
        assert!(((ay - by) / (2.0 * h) - j[1][1]).abs() < 1e-6);
    }

    #[test]
    fn wrong_length_is_rejected() {
        assert_eq!(Distortion::from_slice(&[0.0; 4]), Err(CameraError::DistortionLength { found: 4 }));
    }
}
