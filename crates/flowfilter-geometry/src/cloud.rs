//! Point clouds with optional per-point attributes.

use crate::{Point3, Pose, Vector3};
use serde::{Deserialize, Serialize};

/// A point cloud in metres, with optional per-point normals, RGB colours and the (sub)pixel
/// of the image each point was back-projected from (for organised clouds).
///
/// Every present attribute vector has exactly `points.len()` entries; [`PointCloud::validate`]
/// checks that and the finiteness of the coordinates.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PointCloud {
    /// Point coordinates.
    pub points: Vec<Point3>,
    /// Unit normals, if estimated.
    pub normals: Option<Vec<Vector3>>,
    /// 8-bit RGB colours, if known.
    pub colors: Option<Vec<[u8; 3]>>,
    /// Pixel `(u, v)` each point came from, if the cloud is organised on an image.
    pub pixels: Option<Vec<[f32; 2]>>,
}

/// A structural problem with a [`PointCloud`].
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CloudError {
    /// An attribute array does not have one entry per point.
    #[error("attribute '{attribute}' has {found} entries, expected one per point ({expected})")]
    AttributeLength {
        /// Attribute name.
        attribute: &'static str,
        /// Number of points.
        expected: usize,
        /// Entries found.
        found: usize,
    },
    /// A coordinate is NaN or infinite.
    #[error("point {index} has a non-finite coordinate")]
    NonFinite {
        /// Index of the first bad point.
        index: usize,
    },
}

impl PointCloud {
    /// A cloud of bare points.
    pub fn from_points(points: Vec<Point3>) -> Self {
        Self { points, ..Self::default() }
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether the cloud has no points.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Check attribute lengths and coordinate finiteness.
    pub fn validate(&self) -> Result<(), CloudError> {
        let n = self.points.len();
        let check = |attribute, found| {
            if found == n { Ok(()) } else { Err(CloudError::AttributeLength { attribute, expected: n, found }) }
        };
        if let Some(v) = &self.normals {
            check("normals", v.len())?;
        }
        if let Some(v) = &self.colors {
            check("colors", v.len())?;
        }
        if let Some(v) = &self.pixels {
            check("pixels", v.len())?;
        }
        match self.points.iter().position(|p| !p.coords.iter().all(|c| c.is_finite())) {
            Some(index) => Err(CloudError::NonFinite { index }),
            None => Ok(()),
        }
    }

    /// Centroid of the points (`None` for an empty cloud).
    pub fn centroid(&self) -> Option<Point3> {
        if self.points.is_empty() {
            return None;
        }
        let sum = self.points.iter().fold(Vector3::zeros(), |acc, p| acc + p.coords);
        Some(Point3::from(sum / self.points.len() as f64))
    }

    /// Apply a rigid transform to points and normals, in place.
    pub fn transform(&mut self, pose: &Pose) {
        for p in &mut self.points {
            *p = pose * *p;
        }
        if let Some(normals) = &mut self.normals {
            for n in normals {
                *n = pose.rotation * *n;
            }
        }
    }

    /// A transformed copy.
    pub fn transformed(&self, pose: &Pose) -> Self {
        let mut out = self.clone();
        out.transform(pose);
        out
    }

    /// The sub-cloud of the given indices, attributes included.
    pub fn select(&self, indices: &[usize]) -> Self {
        Self {
            points: indices.iter().map(|&i| self.points[i]).collect(),
            normals: self.normals.as_ref().map(|v| indices.iter().map(|&i| v[i]).collect()),
            colors: self.colors.as_ref().map(|v| indices.iter().map(|&i| v[i]).collect()),
            pixels: self.pixels.as_ref().map(|v| indices.iter().map(|&i| v[i]).collect()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn validate_catches_bad_attributes_and_nan() {
        let mut c = PointCloud::from_points(vec![Point3::origin(), Point3::new(1.0, 0.0, 0.0)]);
        assert!(c.validate().is_ok());
        c.colors = Some(vec![[0, 0, 0]]);
        assert_eq!(c.validate(), Err(CloudError::AttributeLength { attribute: "colors", expected: 2, found: 1 }));
        c.colors = None;
        c.points[1].y = f64::INFINITY;
        assert_eq!(c.validate(), Err(CloudError::NonFinite { index: 1 }));
    }

    #[test]
    fn transform_moves_points_and_rotates_normals() {
        let mut c = PointCloud::from_points(vec![Point3::new(1.0, 0.0, 0.0)]);
        c.normals = Some(vec![Vector3::x()]);
        let pose = Pose::new(Vector3::new(0.0, 0.0, 1.0), Vector3::new(0.0, 0.0, std::f64::consts::FRAC_PI_2));
        c.transform(&pose);
        assert!((c.points[0] - Point3::new(0.0, 1.0, 1.0)).norm() < 1e-12);
        assert!((c.normals.as_ref().unwrap()[0] - Vector3::y()).norm() < 1e-12);
        assert_eq!(c.centroid().unwrap(), c.points[0]);
        assert_eq!(c.select(&[0]).len(), 1);
    }
}
