//! A calibrated camera: intrinsics, distortion and image size.

use crate::{CameraError, Distortion, Intrinsics, Pixel};
use flowfilter_geometry::{Point3, Vector3};
use serde::{Deserialize, Serialize};

/// Image size in pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct ImageSize {
    /// Width (columns).
    pub width: u32,
    /// Height (rows).
    pub height: u32,
}

impl ImageSize {
    /// Validated constructor: both dimensions non-zero.
    pub fn new(width: u32, height: u32) -> Result<Self, CameraError> {
        if width == 0 || height == 0 {
            return Err(CameraError::EmptyImage { width, height });
        }
        Ok(Self { width, height })
    }

    /// Number of pixels.
    pub fn area(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Whether a continuous pixel position lies inside the image (pixel centres at integers,
    /// so the valid range is `[-0.5, width - 0.5)`).
    pub fn contains(&self, p: &Pixel) -> bool {
        p.x >= -0.5 && p.y >= -0.5 && p.x < self.width as f64 - 0.5 && p.y < self.height as f64 - 0.5
    }
}

impl std::fmt::Display for ImageSize {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}x{}", self.width, self.height)
    }
}

/// A calibrated pinhole camera with Brown-Conrady distortion.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CameraModel {
    /// Pinhole intrinsics.
    pub intrinsics: Intrinsics,
    /// Lens distortion.
    pub distortion: Distortion,
    /// Image size.
    pub size: ImageSize,
}

impl CameraModel {
    /// A camera model.
    pub fn new(intrinsics: Intrinsics, distortion: Distortion, size: ImageSize) -> Self {
        Self { intrinsics, distortion, size }
    }

    /// Project a point in the camera frame to a (distorted) pixel. `None` for points at or
    /// behind the camera centre. The pixel may lie outside the image; check with
    /// [`ImageSize::contains`].
    pub fn project(&self, p: &Point3) -> Option<Pixel> {
        if p.z <= 0.0 || !p.z.is_finite() {
            return None;
        }
        let (xd, yd) = self.distortion.distort(p.x / p.z, p.y / p.z);
        let k = &self.intrinsics;
        Some(Pixel::new(k.fx * xd + k.cx, k.fy * yd + k.cy))
    }

    /// [`CameraModel::project`] and its Jacobian, d(pixel)/d(point) as a 2x3 matrix (rows x and
    /// y), analytic through the distortion. `None` where the point does not project.
    pub fn project_with_jacobian(&self, p: &Point3) -> Option<(Pixel, nalgebra::Matrix2x3<f64>)> {
        let pixel = self.project(p)?;
        let (x, y) = (p.x / p.z, p.y / p.z);
        let d = self.distortion.jacobian(x, y);
        let k = &self.intrinsics;
        // d(x, y)/d(point) = [[1/z, 0, -x/z], [0, 1/z, -y/z]]; then the distortion; then K.
        let iz = 1.0 / p.z;
        let row = |scale: f64, [a, b]: [f64; 2]| [scale * a * iz, scale * b * iz, -scale * (a * x + b * y) * iz];
        let (rx, ry) = (row(k.fx, d[0]), row(k.fy, d[1]));
        Some((pixel, nalgebra::Matrix2x3::new(rx[0], rx[1], rx[2], ry[0], ry[1], ry[2])))
    }

    /// Project ignoring distortion (ideal pinhole).
    pub fn project_undistorted(&self, p: &Point3) -> Option<Pixel> {
        if p.z <= 0.0 || !p.z.is_finite() {
            return None;
        }
        let k = &self.intrinsics;
        Some(Pixel::new(k.fx * p.x / p.z + k.cx, k.fy * p.y / p.z + k.cy))
    }

    /// The undistorted normalised coordinates `(x, y)` (the ray `(x, y, 1)`) of a pixel.
    /// `None` where the distortion model cannot be inverted.
    pub fn normalized_ray(&self, pixel: &Pixel) -> Option<Vector3> {
        let k = &self.intrinsics;
        let (x, y) = self.distortion.undistort((pixel.x - k.cx) / k.fx, (pixel.y - k.cy) / k.fy)?;
        Some(Vector3::new(x, y, 1.0))
    }

    /// Back-project a pixel with depth `z` (metres along the optical axis) to a 3-D point.
    pub fn backproject(&self, pixel: &Pixel, z: f64) -> Option<Point3> {
        self.normalized_ray(pixel).map(|r| Point3::from(r * z))
    }

    /// Undistort a pixel: the pixel where an ideal pinhole camera with the same intrinsics
    /// would see the same ray (what OpenCV's `undistortPoints(..., P=K)` returns).
    pub fn undistort_pixel(&self, pixel: &Pixel) -> Option<Pixel> {
        let r = self.normalized_ray(pixel)?;
        let k = &self.intrinsics;
        Some(Pixel::new(k.fx * r.x + k.cx, k.fy * r.y + k.cy))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn camera() -> CameraModel {
        CameraModel::new(
            Intrinsics::new(1081.4, 1080.9, 621.3, 481.6).unwrap(),
            Distortion { k1: 0.042, k2: -0.11, p1: 0.0009, p2: -0.0006, k3: 0.05 },
            ImageSize::new(1280, 1024).unwrap(),
        )
    }

    proptest! {
        #[test]
        fn project_backproject_round_trip(u in 0.0f64..1279.0, v in 0.0f64..1023.0, z in 0.2f64..3.0) {
            let cam = camera();
            let p = cam.backproject(&Pixel::new(u, v), z).unwrap();
            prop_assert!((p.z - z).abs() < 1e-12);
            let q = cam.project(&p).unwrap();
            prop_assert!((q - Pixel::new(u, v)).norm() < 1e-6);
        }

        #[test]
        fn undistort_inverts_distort(u in 0.0f64..1279.0, v in 0.0f64..1023.0) {
            // Distort an ideal pixel anywhere in the image, then undistort it back.
            let cam = camera();
            let k = cam.intrinsics;
            let (x, y) = ((u - k.cx) / k.fx, (v - k.cy) / k.fy);
            let distorted = cam.project(&Point3::new(x, y, 1.0)).unwrap();
            let ideal = cam.undistort_pixel(&distorted).unwrap();
            prop_assert!((ideal - Pixel::new(u, v)).norm() < 1e-6);
        }
    }

    proptest! {
        #[test]
        fn the_projection_jacobian_matches_central_differences(
            x in -0.6f64..0.6, y in -0.5f64..0.5, z in 0.2f64..3.0,
        ) {
            let cam = camera();
            let p = Point3::new(x * z, y * z, z);
            let (pixel, j) = cam.project_with_jacobian(&p).unwrap();
            prop_assert_eq!(pixel, cam.project(&p).unwrap());
            let h = 1e-6;
            for k in 0..3 {
                let mut e = Vector3::zeros();
                e[k] = h;
                let d = (cam.project(&(p + e)).unwrap() - cam.project(&(p - e)).unwrap()) / (2.0 * h);
                prop_assert!((j[(0, k)] - d.x).abs() < 1e-4 * (1.0 + d.x.abs()), "x/{}: {} vs {}", k, j[(0, k)], d.x);
                prop_assert!((j[(1, k)] - d.y).abs() < 1e-4 * (1.0 + d.y.abs()), "y/{}: {} vs {}", k, j[(1, k)], d.y);
            }
        }
    }

    #[test]
    fn behind_camera_does_not_project() {
        assert!(camera().project(&Point3::new(0.0, 0.0, -1.0)).is_none());
        assert!(camera().project(&Point3::new(0.0, 0.0, 0.0)).is_none());
    }

    #[test]
    fn image_contains_uses_pixel_centres() {
        let s = ImageSize::new(4, 3).unwrap();
        assert!(s.contains(&Pixel::new(-0.5, -0.5)));
        assert!(s.contains(&Pixel::new(3.49, 2.49)));
        assert!(!s.contains(&Pixel::new(3.5, 0.0)));
        assert!(ImageSize::new(0, 3).is_err());
    }
}
