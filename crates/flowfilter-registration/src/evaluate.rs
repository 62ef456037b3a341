//! Shared pieces: inlier evaluation, robust kernels, the point-to-plane Gauss-Newton step.

use flowfilter_geometry::{KnnIndex, Point3, Pose, Vector3, se3};
use nalgebra::{Matrix6, Vector6};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Fitness (fraction of source points with a target point within `max_distance`) and the RMSE of
/// those pairs, for the source moved by `transform` (as Open3D's `evaluate_registration`).
pub fn evaluate(source: &[Point3], target: &KnnIndex, transform: &Pose, max_distance: f64) -> (f64, f64) {
    let (count, sum) = source
        .par_iter()
        .filter_map(|p| target.nearest(&(transform * p)).filter(|n| n.dist2 <= max_distance * max_distance))
        .map(|n| (1usize, n.dist2))
        .reduce(|| (0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    if count == 0 { (0.0, 0.0) } else { (count as f64 / source.len() as f64, (sum / count as f64).sqrt()) }
}

/// Robust kernels on residual magnitudes (IRLS weights).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum RobustKernel {
    /// Least squares.
    #[default]
    None,
    /// Huber with threshold `k` (metres).
    Huber {
        /// Threshold.
        k: f64,
    },
    /// Tukey biweight with threshold `k` (metres).
    Tukey {
        /// Threshold.
        k: f64,
    },
}

impl RobustKernel {
    /// IRLS weight of a residual of magnitude `r`.
    pub fn weight(&self, r: f64) -> f64 {
        match *self {
            Self::None => 1.0,
            Self::Huber { k } => {
                if r <= k {
                    1.0
                } else {
                    k / r
                }
            }
            Self::Tukey { k } => {
                if r <= k {
                    (1.0 - (r / k).powi(2)).powi(2)
                } else {
                    0.0
                }
            }
        }
    }
}

/// One Gauss-Newton step of weighted point-to-plane alignment: the twist `xi` (left
/// perturbation) minimising `sum w_i (n_i . (exp(xi) x_i - y_i))^2` to first order. `None` when
/// the normal equations are singular (e.g. all normals parallel).
pub fn point_to_plane_step(x: &[Point3], y: &[Point3], n: &[Vector3], w: &[f64]) -> Option<Pose> {
    let (h, g) = (0..x.len())
        .into_par_iter()
        .map(|i| {
            let r = n[i].dot(&(x[i] - y[i]));
            let c = x[i].coords.cross(&n[i]);
            let j = Vector6::new(n[i].x, n[i].y, n[i].z, c.x, c.y, c.z);
            (w[i] * j * j.transpose(), w[i] * r * j)
        })
        .reduce(|| (Matrix6::zeros(), Vector6::zeros()), |a, b| (a.0 + b.0, a.1 + b.1));
    let xi = h.cholesky()?.solve(&(-g));
    xi.iter().all(|v| v.is_finite()).then(|| se3::exp(&xi))
}
