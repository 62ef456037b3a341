//! Shared pieces: inlier evaluation, robust kernels, the point-to-plane Gauss-Newton step.

use flowfilter_geometry::{KnnIndex, Point3, Pose, Vector3, se3};
use nalgebra::{Matrix6, Translation3, UnitQuaternion, Vector6};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Points per chunk of the order-fixed parallel sums.
const DETERMINISTIC_CHUNK: usize = 512;

/// Fitness (fraction of source points with a target point within `max_distance`) and the RMSE of
/// those pairs, for the source moved by `transform` (as Open3D's `evaluate_registration`).
pub fn evaluate(source: &[Point3], target: &KnnIndex, transform: &Pose, max_distance: f64) -> (f64, f64) {
    evaluate_by(source, transform, max_distance, |_, q| target.nearest(q).map(|n| n.dist2))
}

/// The pairs `(source index, target index)` of [`evaluate`]: each source point moved by
/// `transform` with its nearest target point, where that is within `max_distance` (Open3D's
/// `RegistrationResult.correspondence_set`). In source order, the same for any thread count.
///
/// ```
/// use flowfilter_geometry::{KnnIndex, Point3, Pose};
/// use flowfilter_registration::correspondence_set;
///
/// let target = [Point3::new(0.0, 0.0, 1.0), Point3::new(0.1, 0.0, 1.0)];
/// let source = [Point3::new(0.1, 0.0, 1.0), Point3::new(5.0, 0.0, 1.0)];
/// let pairs = correspondence_set(&source, &KnnIndex::new(&target), &Pose::identity(), 0.01);
/// assert_eq!(pairs, vec![(0, 1)]);
/// ```
pub fn correspondence_set(
    source: &[Point3],
    target: &KnnIndex,
    transform: &Pose,
    max_distance: f64,
) -> Vec<(usize, usize)> {
    let limit2 = max_distance * max_distance;
    source
        .par_iter()
        .enumerate()
        .filter_map(|(i, p)| target.nearest(&(transform * p)).filter(|n| n.dist2 <= limit2).map(|n| (i, n.index)))
        .collect()
}

/// [`evaluate`] with the squared distance from moved source point `i` (at `q`) to its nearest
/// target point given by `nearest2(i, q)` (`None`: no target point).
pub(crate) fn evaluate_by(
    source: &[Point3],
    transform: &Pose,
    max_distance: f64,
    nearest2: impl Fn(usize, &Point3) -> Option<f64> + Sync,
) -> (f64, f64) {
    // Fixed chunks summed in order: the same bits whatever the thread count or scheduling.
    let (count, sum) = source
        .par_chunks(DETERMINISTIC_CHUNK)
        .enumerate()
        .map(|(c, chunk)| {
            chunk
                .iter()
                .enumerate()
                .filter_map(|(k, p)| {
                    nearest2(c * DETERMINISTIC_CHUNK + k, &(transform * p))
                        .filter(|d2| *d2 <= max_distance * max_distance)
                })
                .fold((0usize, 0.0f64), |a, d2| (a.0 + 1, a.1 + d2))
        })
        .collect::<Vec<_>>()
        .into_iter()
        .fold((0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    if count == 0 { (0.0, 0.0) } else { (count as f64 / source.len() as f64, (sum / count as f64).sqrt()) }
}

/// Mean over the moved source points of `min(distance to the nearest target point, tau)`: a
/// robust geometric misfit (0 for a perfect overlap, `tau` where nothing overlaps). The
/// searches run side by side; the sum is taken in the points' order, so the same input always
/// gives the same bits.
pub fn truncated_residual(source: &[Point3], target: &KnnIndex, transform: &Pose, tau: f64) -> f64 {
    if source.is_empty() {
        return tau;
    }
    let misfits: Vec<f64> =
        source.par_iter().map(|p| target.nearest(&(transform * p)).map_or(tau, |n| n.dist2.sqrt().min(tau))).collect();
    misfits.iter().sum::<f64>() / source.len() as f64
}

/// The truncated residual (`truncated_residual`: the mean of each moved point's distance to its
/// nearest target point, at most `tau`) over the source points that the move leaves facing the
/// camera (the clouds are in the camera frame, camera at the origin): the cosine between the
/// moved normal and the direction to the camera must exceed `min_cos`. A correct pose on a
/// partial view turns some points out of view, which then have no partner and must not count
/// against it. Without normals every point counts.
pub fn visible_residual(
    source: &[Point3],
    normals: Option<&[Vector3]>,
    target: &KnnIndex,
    transform: &Pose,
    tau: f64,
    min_cos: f64,
) -> f64 {
    let Some(normals) = normals else { return truncated_residual(source, target, transform, tau) };
    // The visible points' misfits searched side by side, summed in the points' order.
    let misfits: Vec<Option<f64>> = source
        .par_iter()
        .zip(normals)
        .map(|(p, nrm)| {
            let q = transform * p;
            let m = transform.rotation * nrm;
            let to_camera = -q.coords / q.coords.norm().max(1e-12);
            // Normals may point either way: the surface faces the camera if |cos| is large.
            (m.dot(&to_camera).abs() >= min_cos).then(|| target.nearest(&q).map_or(tau, |nb| nb.dist2.sqrt().min(tau)))
        })
        .collect();
    let (mut sum, mut n) = (0.0, 0usize);
    for misfit in misfits.into_iter().flatten() {
        sum += misfit;
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

/// One Gauss-Newton step of weighted point-to-plane alignment over `len` pairs given by
/// `pair(i) = (x_i, y_i, n_i, w_i)` (read where they are stored, no gathered copies): the
/// solution `(t, a)` of the linearised problem `min sum w_i (n_i . (x_i + a x x_i + t - y_i))^2`,
/// composed as Open3D's point-to-plane ICP composes it: rotation `Rz(a_z) Ry(a_y) Rx(a_x)`,
/// translation `t`. The first-order solution is the same for any composition, but the iterates
/// are not: with the exponential map they differ at second order in the step and, on noisy
/// clouds with a wide gate, can settle elsewhere than Open3D's. `None` when the normal
/// equations are singular (e.g. all normals parallel).
pub fn point_to_plane_step_by(
    len: usize,
    pair: impl Fn(usize) -> (Point3, Point3, Vector3, f64) + Sync,
) -> Option<Pose> {
    let xi = normal_equations_solution(len, |i, h, g| {
        let (x, y, n, w) = pair(i);
        plane_term(&x, &y, &n, w, h, g)
    })?;
    let rotation = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), xi[5])
        * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), xi[4])
        * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), xi[3]);
    Some(Pose::from_parts(Translation3::new(xi[0], xi[1], xi[2]), rotation))
}

/// Adds one weighted point-to-plane residual `n . (x - y)` to the normal equations.
#[inline]
fn plane_term(x: &Point3, y: &Point3, n: &Vector3, w: f64, h: &mut Matrix6<f64>, g: &mut Vector6<f64>) {
    let r = n.dot(&(x - y));
    let c = x.coords.cross(n);
    let j = Vector6::new(n.x, n.y, n.z, c.x, c.y, c.z);
    h.syger(w, &j, &j, 1.0);
    g.axpy(w * r, &j, 1.0);
}

/// Solves the normal equations accumulated by `term(i, h, g)` over `0..len` (in fixed chunks
/// summed in order: the same bits whatever the thread count) for the left twist.
fn gauss_newton_step(len: usize, term: impl Fn(usize, &mut Matrix6<f64>, &mut Vector6<f64>) + Sync) -> Option<Pose> {
    normal_equations_solution(len, term).map(|xi| se3::exp(&xi))
}

/// The solution `xi` (translation, then rotation) of the normal equations accumulated by
/// `term(i, h, g)` over `0..len`, or `None` when they are singular or the solution is not finite.
fn normal_equations_solution(
    len: usize,
    term: impl Fn(usize, &mut Matrix6<f64>, &mut Vector6<f64>) + Sync,
) -> Option<Vector6<f64>> {
    let chunks = len.div_ceil(DETERMINISTIC_CHUNK);
    let (h, g) = (0..chunks)
        .into_par_iter()
        .map(|c| {
            let (mut h, mut g) = (Matrix6::zeros(), Vector6::zeros());
            for i in c * DETERMINISTIC_CHUNK..((c + 1) * DETERMINISTIC_CHUNK).min(len) {
                term(i, &mut h, &mut g);
            }
            (h, g)
        })
        .collect::<Vec<_>>()
        .into_iter()
        .fold((Matrix6::zeros(), Vector6::zeros()), |a, b| (a.0 + b.0, a.1 + b.1));
    // Only the lower triangle was accumulated.
    let h = Matrix6::from_fn(|r, c| if r >= c { h[(r, c)] } else { h[(c, r)] });
    let xi = h.cholesky()?.solve(&(-g));
    xi.iter().all(|v| v.is_finite()).then_some(xi)
}

/// [`point_to_plane_step_by`] where a pair without a normal (`None`) contributes its full
/// point-to-point residual `|x - y|^2` (the sum of its point-to-plane residuals along the axes),
/// and the source points are first moved by `pre` (the Gauss-Newton steps taken so far).
pub fn plane_or_point_step(x: &[Point3], y: &[Point3], n: &[Option<Vector3>], w: &[f64], pre: &Pose) -> Option<Pose> {
    gauss_newton_step(x.len(), |i, h, g| {
        let xi = pre * x[i];
        match &n[i] {
            Some(n) => plane_term(&xi, &y[i], n, w[i], h, g),
            None => {
                for axis in [Vector3::x(), Vector3::y(), Vector3::z()] {
                    plane_term(&xi, &y[i], &axis, w[i], h, g);
                }
            }
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    /// A pair without a normal weighs as its three axis-aligned point-to-plane residuals, and
    /// `pre` moves the source first.
    #[test]
    fn plane_or_point_step_equals_the_expanded_point_to_plane_step() {
        let x: Vec<Point3> =
            (0..40).map(|i| Point3::new((i as f64 * 0.37).sin(), (i as f64 * 0.71).cos(), 0.1 * i as f64)).collect();
        let pre = Pose::from_parts(
            Translation3::new(0.01, -0.02, 0.005),
            UnitQuaternion::from_euler_angles(0.02, -0.01, 0.03),
        );
        let y: Vec<Point3> =
            x.iter().enumerate().map(|(i, p)| p + Vector3::new(0.01 * (i % 3) as f64, -0.004, 0.002)).collect();
        let n: Vec<Option<Vector3>> =
            (0..40).map(|i| (i % 4 != 0).then(|| Vector3::new(1.0, (i as f64).sin(), 0.5).normalize())).collect();
        let w: Vec<f64> = (0..40).map(|i| 0.5 + (i % 5) as f64 * 0.1).collect();
        let (mut ex, mut ey, mut en, mut ew) = (vec![], vec![], vec![], vec![]);
        for i in 0..40 {
            let axes = match n[i] {
                Some(v) => vec![v],
                None => vec![Vector3::x(), Vector3::y(), Vector3::z()],
            };
            for a in axes {
                ex.push(pre * x[i]);
                ey.push(y[i]);
                en.push(a);
                ew.push(w[i]);
            }
        }
        let want = gauss_newton_step(ex.len(), |i, h, g| plane_term(&ex[i], &ey[i], &en[i], ew[i], h, g)).unwrap();
        let got = plane_or_point_step(&x, &y, &n, &w, &pre).unwrap();
        assert!((want.to_homogeneous() - got.to_homogeneous()).abs().max() < 1e-12);
    }

    #[test]
    fn point_to_plane_step_composes_its_solution_as_open3d() {
        let x: Vec<Point3> =
            (0..60).map(|i| Point3::new((i as f64 * 0.37).sin(), (i as f64 * 0.71).cos(), 0.1 * i as f64)).collect();
        let truth =
            Pose::from_parts(Translation3::new(0.03, -0.02, 0.01), UnitQuaternion::from_euler_angles(0.2, -0.1, 0.3));
        let n: Vec<Vector3> =
            (0..60).map(|i| Vector3::new((i as f64).cos(), (i as f64 * 1.3).sin(), 0.7).normalize()).collect();
        let y: Vec<Point3> = x.iter().map(|p| truth * p).collect();
        let step = point_to_plane_step_by(x.len(), |i| (x[i], y[i], n[i], 1.0)).unwrap();
        let xi = normal_equations_solution(x.len(), |i, h, g| plane_term(&x[i], &y[i], &n[i], 1.0, h, g)).unwrap();
        // Open3D's TransformVector6dToMatrix4d: R = Rz(c) Ry(b) Rx(a), t as solved.
        let (a, b, c) = (xi[3], xi[4], xi[5]);
        let rx = nalgebra::Matrix3::new(1.0, 0.0, 0.0, 0.0, a.cos(), -a.sin(), 0.0, a.sin(), a.cos());
        let ry = nalgebra::Matrix3::new(b.cos(), 0.0, b.sin(), 0.0, 1.0, 0.0, -b.sin(), 0.0, b.cos());
        let rz = nalgebra::Matrix3::new(c.cos(), -c.sin(), 0.0, c.sin(), c.cos(), 0.0, 0.0, 0.0, 1.0);
        let r = rz * ry * rx;
        assert!((step.rotation.to_rotation_matrix().matrix() - r).abs().max() < 1e-14);
        assert!((step.translation.vector - Vector3::new(xi[0], xi[1], xi[2])).abs().max() < 1e-15);
        // One step of a large motion is first-order: it moves towards the truth, not onto it.
        assert!((step.rotation.angle() - truth.rotation.angle()).abs() < 0.2);
    }
}
