//! Pinhole intrinsics.

use crate::error::{CameraError, finite};
use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

/// The largest focal length or principal-point coordinate accepted, pixels: 10^6 (a 600 mm lens
/// on 4 micrometre pixels is 1.5 x 10^5); a larger value is a unit or file error.
pub const MAX_PIXELS: f64 = 1e6;

/// Pinhole intrinsics in pixels (no skew), OpenCV convention: `u = fx * x + cx`, `v = fy * y + cy`
/// for normalised coordinates `(x, y) = (X/Z, Y/Z)`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Focal length along u, pixels.
    pub fx: f64,
    /// Focal length along v, pixels.
    pub fy: f64,
    /// Principal point u, pixels.
    pub cx: f64,
    /// Principal point v, pixels.
    pub cy: f64,
}

impl Intrinsics {
    /// Validated constructor: all finite, focal lengths positive.
    pub fn new(fx: f64, fy: f64, cx: f64, cy: f64) -> Result<Self, CameraError> {
        let k = Self { fx: finite("fx", fx)?, fy: finite("fy", fy)?, cx: finite("cx", cx)?, cy: finite("cy", cy)? };
        if fx <= 0.0 {
            return Err(CameraError::NonPositiveFocal { name: "fx", value: fx });
        }
        if fy <= 0.0 {
            return Err(CameraError::NonPositiveFocal { name: "fy", value: fy });
        }
        for (name, value) in [("fx", fx), ("fy", fy), ("cx", cx), ("cy", cy)] {
            if value.abs() > MAX_PIXELS {
                return Err(CameraError::OutOfRange { name, value, limit: MAX_PIXELS });
            }
        }
        Ok(k)
    }

    /// From a 3x3 matrix `[fx 0 cx; 0 fy cy; 0 0 1]`; skew and the last row are checked.
    pub fn from_matrix(k: &Matrix3<f64>) -> Result<Self, CameraError> {
        for (row, col, expected) in [(0, 1, 0.0), (1, 0, 0.0), (2, 0, 0.0), (2, 1, 0.0), (2, 2, 1.0)] {
            let found = k[(row, col)];
            if !found.is_finite() {
                return Err(CameraError::NonFinite { name: "K", value: found });
            }
            if (found - expected).abs() > 1e-9 {
                return Err(CameraError::NotPinhole { row, col, expected, found });
            }
        }
        Self::new(k[(0, 0)], k[(1, 1)], k[(0, 2)], k[(1, 2)])
    }

    /// The 3x3 camera matrix.
    pub fn matrix(&self) -> Matrix3<f64> {
        Matrix3::new(self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }

    /// Intrinsics of the same camera at an image scaled by `s` (e.g. 0.5 for half resolution),
    /// with pixel centres kept consistent (`c' = (c + 0.5) * s - 0.5`).
    pub fn scaled(&self, s: f64) -> Self {
        Self { fx: self.fx * s, fy: self.fy * s, cx: (self.cx + 0.5) * s - 0.5, cy: (self.cy + 0.5) * s - 0.5 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matrix_round_trip_and_validation() {
        let k = Intrinsics::new(1081.0, 1080.5, 621.2, 481.7).unwrap();
        assert_eq!(Intrinsics::from_matrix(&k.matrix()).unwrap(), k);
        let mut m = k.matrix();
        m[(0, 1)] = 2.0;
        assert!(matches!(Intrinsics::from_matrix(&m), Err(CameraError::NotPinhole { row: 0, col: 1, .. })));
        assert!(matches!(Intrinsics::new(-1.0, 1.0, 0.0, 0.0), Err(CameraError::NonPositiveFocal { name: "fx", .. })));
        assert!(matches!(Intrinsics::new(1.0, 1.0, f64::NAN, 0.0), Err(CameraError::NonFinite { name: "cx", .. })));
        assert!(matches!(Intrinsics::new(1e300, 1.0, 0.0, 0.0), Err(CameraError::OutOfRange { name: "fx", .. })));
    }

    #[test]
    fn scaling_keeps_pixel_centres() {
        let k = Intrinsics::new(100.0, 100.0, 49.5, 29.5).unwrap().scaled(2.0);
        assert_eq!((k.fx, k.cx, k.cy), (200.0, 99.5, 59.5));
    }
}
