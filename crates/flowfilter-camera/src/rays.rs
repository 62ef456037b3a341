//! Precomputed undistorted rays of every pixel of a camera, for fast back-projection.

use crate::{CameraModel, Pixel};
use flowfilter_geometry::Point3;
use rayon::prelude::*;

/// The normalised ray `(x, y, 1)` of every pixel centre of a camera (NaN where the distortion
/// model cannot be inverted). Back-projecting a pixel is then one multiply.
#[derive(Debug, Clone)]
pub struct RayTable {
    camera: CameraModel,
    rays: Vec<[f32; 2]>,
}

impl RayTable {
    /// Compute the table (rayon-parallel over rows).
    pub fn new(camera: &CameraModel) -> Self {
        let (w, h) = (camera.size.width as usize, camera.size.height as usize);
        let mut rays = vec![[f32::NAN; 2]; w * h];
        rays.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (x, r) in row.iter_mut().enumerate() {
                if let Some(v) = camera.normalized_ray(&Pixel::new(x as f64, y as f64)) {
                    *r = [v.x as f32, v.y as f32];
                }
            }
        });
        Self { camera: *camera, rays }
    }

    /// The camera this table was computed for.
    pub fn camera(&self) -> &CameraModel {
        &self.camera
    }

    /// The ray of pixel `(x, y)` as `(x/z, y/z)`; `None` outside the image or where undefined.
    pub fn ray(&self, x: usize, y: usize) -> Option<[f32; 2]> {
        let w = self.camera.size.width as usize;
        if x >= w || y >= self.camera.size.height as usize {
            return None;
        }
        let r = self.rays[y * w + x];
        r[0].is_finite().then_some(r)
    }

    /// Back-project pixel `(x, y)` at depth `z`.
    pub fn backproject(&self, x: usize, y: usize, z: f64) -> Option<Point3> {
        self.ray(x, y).map(|[rx, ry]| Point3::new(f64::from(rx) * z, f64::from(ry) * z, z))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Distortion, ImageSize, Intrinsics};

    #[test]
    fn table_matches_direct_backprojection() {
        let cam = CameraModel::new(
            Intrinsics::new(300.0, 301.0, 79.5, 59.5).unwrap(),
            Distortion { k1: 0.05, k2: -0.1, p1: 0.001, p2: -0.001, k3: 0.02 },
            ImageSize::new(160, 120).unwrap(),
        );
        let table = RayTable::new(&cam);
        for (x, y) in [(0, 0), (159, 119), (80, 60), (13, 101)] {
            let a = table.backproject(x, y, 0.8).unwrap();
            let b = cam.backproject(&Pixel::new(x as f64, y as f64), 0.8).unwrap();
            assert!((a - b).norm() < 1e-6, "{x},{y}");
        }
        assert!(table.ray(160, 0).is_none());
    }
}
