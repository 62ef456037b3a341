//! Shared pieces: inlier evaluation, robust kernels, the point-to-plane Gauss-Newton step.

use flowfilter_geometry::{KnnIndex, Point3, Pose, Vector3, se3};
use nalgebra::{Matrix6, Vector6};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Points per chunk of the order-fixed parallel sums.
const DETERMINISTIC_CHUNK: usize = 512;

/// Fitness (fraction of source points with a target point within `max_distance`) and the RMSE of
/// those pairs, for the source moved by `transform` (as Open3D's `evaluate_registration`).
pub fn evaluate(source: &[Point3], target: &KnnIndex, transform: &Pose, max_distance: f64) -> (f64, f64) {
    // Fixed chunks summed in order: the same bits whatever the thread count or scheduling.
    let (count, sum) = source
        .par_chunks(DETERMINISTIC_CHUNK)
        .map(|chunk| {
            chunk
                .iter()
                .filter_map(|p| target.nearest(&(transform * p)).filter(|n| n.dist2 <= max_distance * max_distance))
                .fold((0usize, 0.0f64), |a, n| (a.0 + 1, a.1 + n.dist2))
        })
        .collect::<Vec<_>>()
        .into_iter()
        .fold((0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    if count == 0 { (0.0, 0.0) } else { (count as f64 / source.len() as f64, (sum / count as f64).sqrt()) }
}

/// Mean over the moved source points of `min(distance to the nearest target point, tau)`: a
/// robust geometric misfit (0 for a perfect overlap, `tau` where nothing overlaps). Sequential,
/// so the same input always gives the same bits.
pub fn truncated_residual(source: &[Point3], target: &KnnIndex, transform: &Pose, tau: f64) -> f64 {
    if source.is_empty() {
        return tau;
    }
    let sum: f64 =
        source.iter().map(|p| target.nearest(&(transform * p)).map_or(tau, |n| n.dist2.sqrt().min(tau))).sum();
    sum / source.len() as f64
}

/// [`truncated_residual`] over the source points that the move leaves facing the camera (the
/// clouds are in the camera frame, camera at the origin): the cosine between the moved normal
/// and the direction to the camera must exceed `min_cos`. A correct pose on a partial view
/// turns some points out of view, which then have no partner and must not count against it.
/// Without normals every point counts.
pub fn visible_residual(
    source: &[Point3],
    normals: Option<&[Vector3]>,
    target: &KnnIndex,
    transform: &Pose,
    tau: f64,
    min_cos: f64,
) -> f64 {
    let Some(normals) = normals else { return truncated_residual(source, target, transform, tau) };
    let (mut sum, mut n) = (0.0, 0usize);
    for (p, nrm) in source.iter().zip(normals) {
        let q = transform * p;
        let m = transform.rotation * nrm;
        let to_camera = -q.coords / q.coords.norm().max(1e-12);
        // Normals may point either way: the surface faces the camera if |cos| is large.
        if m.dot(&to_camera).abs() < min_cos {
            continue;
        }
        sum += target.nearest(&q).map_or(tau, |nb| nb.dist2.sqrt().min(tau));
        n += 1;
    }
    if n * 5 < source.len() { tau } else { sum / n as f64 }
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
    let indices: Vec<usize> = (0..x.len()).collect();
    let (h, g) = indices
        .par_chunks(DETERMINISTIC_CHUNK)
        .map(|chunk| {
            chunk.iter().fold((Matrix6::zeros(), Vector6::zeros()), |(h, g), &i| {
                let r = n[i].dot(&(x[i] - y[i]));
                let c = x[i].coords.cross(&n[i]);
                let j = Vector6::new(n[i].x, n[i].y, n[i].z, c.x, c.y, c.z);
                (h + w[i] * j * j.transpose(), g + w[i] * r * j)
            })
        })
        .collect::<Vec<_>>()
        .into_iter()
        .fold((Matrix6::zeros(), Vector6::zeros()), |a, b| (a.0 + b.0, a.1 + b.1));
    let xi = h.cholesky()?.solve(&(-g));
    xi.iter().all(|v| v.is_finite()).then(|| se3::exp(&xi))
}
