//! Refinement of a pose by the reprojection error of its correspondences, both ways.
//!
//! A flow pair is a pixel tracked from one image to the other, each end lifted to 3-D by its own
//! depth. Depth noise (millimetres on consumer sensors) enters a 3-D pair residual directly; the
//! pixel positions are known to a tenth of a pixel. Here each source point moved by the pose is
//! compared with the *ray* of its target point (normalised image coordinates `x/z, y/z` in the
//! camera frame, where the clouds live), and each target point moved back with the ray of its
//! source point: each depth only ever places points on its own side, and on a small motion a
//! depth error barely moves the reprojection. A weak range term (the difference of distances to
//! the camera, weighted by the ratio of pixel to depth precision) keeps the motion along the
//! rays tied to depth.
//!
//! Consumer colour cameras expose their rows one after the other (a rolling shutter): when the
//! image motion changes speed between the two exposures, the target image is sheared, each row
//! shifted in proportion to its height. No rigid motion explains that shift, and a rigid fit on an
//! object's patch takes its antisymmetric part for an in-plane rotation (on the real YCB-Video
//! sample, a shift of 0.003-0.009 px per row turned the objects by 0.1-0.3 deg).
//! [`Shutter::Rolling`] estimates the shear with the pose: two more unknowns, the target rays'
//! shift per unit of (normalised) row.

use flowfilter_geometry::{Correspondences, Point3, Pose, se3};
use nalgebra::{Matrix3, Matrix6, SMatrix, SVector, Vector2, Vector3};
use statrs::distribution::{ContinuousCDF, FisherSnedecor};
use std::collections::BTreeMap;

/// Fewest usable pairs the refinement works with.
const MIN_PAIRS: usize = 8;

/// Weight of a pair's range residual (relative to its range) against its ray residual: the ratio
/// of a tracked pixel's precision (about 0.3 px at 1000 px focal length, 3e-4) to a consumer depth
/// sensor's relative range precision (about 2.5e-3 at 0.8 m). The range term keeps the motion
/// along the rays, which rays alone hardly see, tied to depth.
const RANGE_WEIGHT: f64 = 0.12;

/// The ray of a point: `(x/z, y/z)`; `None` behind or on the camera plane.
fn ray(p: &Point3) -> Option<Vector2<f64>> {
    (p.z > 1e-6).then(|| Vector2::new(p.x / p.z, p.y / p.z))
}

/// `d ray / d X` at `X`.
fn ray_jacobian(x: &Point3) -> SMatrix<f64, 2, 3> {
    let iz = 1.0 / x.z;
    SMatrix::<f64, 2, 3>::new(iz, 0.0, -x.x * iz * iz, 0.0, iz, -x.y * iz * iz)
}

/// How the target image was exposed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shutter {
    /// All rows at once: the pose alone explains the pairs.
    Global,
    /// Row after row: the pose and a shift of the target rays proportional to their row (see
    /// the module documentation), with a zero-mean Gaussian prior on the shear.
    Rolling {
        /// The prior's standard deviation (rays' shift per unit of normalised row: pixels per
        /// pixel row). On an object much taller than wide the shear trades against a turn about
        /// the long axis; the prior keeps it to what a shutter does.
        shear_sd: f64,
    },
}

/// One residual (ray difference, then weighted relative range difference) and its Jacobian with
/// respect to the state: a left twist `T <- exp(xi) T` (6 columns), then the row shear (2).
type Term = (Vector3<f64>, SMatrix<f64, 3, 8>);

/// The residual of point `x` against the observed point `o`: ray difference, then the range
/// difference relative to the observed range, weighted.
fn residual(x: &Point3, o: &Point3) -> Option<Vector3<f64>> {
    let r2 = ray(x)? - ray(o)?;
    let (range, observed) = (x.coords.norm(), o.coords.norm());
    Some(Vector3::new(r2.x, r2.y, RANGE_WEIGHT * (range / observed - 1.0)))
}

/// `d residual / d x` of [`residual`].
fn residual_by_point(x: &Point3, o: &Point3) -> Matrix3<f64> {
    let mut j = Matrix3::zeros();
    j.fixed_view_mut::<2, 3>(0, 0).copy_from(&ray_jacobian(x));
    let k = RANGE_WEIGHT / (o.coords.norm() * x.coords.norm());
    j.fixed_view_mut::<1, 3>(2, 0).copy_from(&(k * x.coords.transpose()));
    j
}

/// `d residual / d o` of [`residual`].
fn residual_by_observed(x: &Point3, o: &Point3) -> Matrix3<f64> {
    let mut j = Matrix3::zeros();
    j.fixed_view_mut::<2, 3>(0, 0).copy_from(&(-ray_jacobian(o)));
    let on = o.coords.norm();
    let k = -RANGE_WEIGHT * x.coords.norm() / (on * on * on);
    j.fixed_view_mut::<1, 3>(2, 0).copy_from(&(k * o.coords.transpose()));
    j
}

/// `d X / d xi` for `X <- exp(xi) X` at `x`.
fn twist_jacobian(x: &Point3) -> SMatrix<f64, 3, 6> {
    let mut d = SMatrix::<f64, 3, 6>::zeros();
    d.fixed_view_mut::<3, 3>(0, 0).copy_from(&Matrix3::identity());
    d.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-x.coords.cross_matrix()));
    d
}

/// What is being refined: the pose, and the shift of the target rays per unit of row away from
/// `row0` (the pairs' mean target row).
#[derive(Debug, Clone, Copy)]
struct State {
    pose: Pose,
    shear: Vector2<f64>,
    row0: f64,
}

impl State {
    /// The target point as all rows exposed at once would have placed it (its ray shifted back
    /// by the shear at its row, at its own depth), and `d q' / d shear`.
    fn unsheared(&self, q: &Point3) -> (Point3, SMatrix<f64, 3, 2>) {
        let s = q.y / q.z - self.row0;
        let shifted = Point3::new(q.x - q.z * s * self.shear.x, q.y - q.z * s * self.shear.y, q.z);
        (shifted, SMatrix::<f64, 3, 2>::new(-q.z * s, 0.0, 0.0, -q.z * s, 0.0, 0.0))
    }

    /// Source point moved by the pose against the target's ray.
    fn forward(&self, p: &Point3, q: &Point3) -> Option<Term> {
        let (q, dq) = self.unsheared(q);
        let x = self.pose * p;
        let r = residual(&x, &q)?;
        let mut j = SMatrix::<f64, 3, 8>::zeros();
        j.fixed_view_mut::<3, 6>(0, 0).copy_from(&(residual_by_point(&x, &q) * twist_jacobian(&x)));
        j.fixed_view_mut::<3, 2>(0, 6).copy_from(&(residual_by_observed(&x, &q) * dq));
        Some((r, j))
    }

    /// Target point moved back by the pose's inverse against the source's ray
    /// (`T^-1 <- T^-1 exp(-xi)`).
    fn backward(&self, p: &Point3, q: &Point3) -> Option<Term> {
        let (q, dq) = self.unsheared(q);
        let inv = self.pose.inverse();
        let y = inv * q;
        let r = residual(&y, p)?;
        let back = residual_by_point(&y, p) * inv.rotation.to_rotation_matrix().matrix();
        let mut j = SMatrix::<f64, 3, 8>::zeros();
        j.fixed_view_mut::<3, 6>(0, 0).copy_from(&(-back * twist_jacobian(&q)));
        j.fixed_view_mut::<3, 2>(0, 6).copy_from(&(back * dq));
        Some((r, j))
    }

    /// Both of a pair's terms.
    fn terms(&self, p: &Point3, q: &Point3) -> impl Iterator<Item = Term> {
        [self.forward(p, q), self.backward(p, q)].into_iter().flatten()
    }
}

/// Median of the residual norms of the `usable` pairs at `st` (both ways).
fn median_norm(c: &Correspondences, usable: &[usize], st: &State) -> Option<f64> {
    let mut n: Vec<f64> =
        usable.iter().flat_map(|&i| st.terms(&c.source[i], &c.target[i])).map(|(r, _)| r.norm()).collect();
    if n.is_empty() {
        return None;
    }
    n.sort_by(f64::total_cmp);
    Some(n[n.len() / 2])
}

/// A refined pose, the covariance of its left twist `(rho, phi)` and the target image's row
/// shear. The covariance is cluster-robust: `H^-1 M H^-1` at the solution (`H` the Gauss-Newton
/// matrix, `M` the spread of the gradients of blocks of neighbouring pairs, the shear
/// marginalised out), so that errors the pairs of one region share count once per region, not
/// once per pair; with too few blocks, `s^2 H^-1` (`s^2` the weighted residual variance).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Refinement {
    /// The pose.
    pub pose: Pose,
    /// Covariance of `(rho, phi)` (metres, radians).
    pub covariance: Matrix6<f64>,
    /// How many blocks of pairs the covariance came from (0: from the pairs as independent).
    pub blocks: usize,
    /// Shift of the target image's rays per unit of normalised row (`x/z, y/z` per `y/z`; times
    /// the focal length: pixels per row), zero with [`Shutter::Global`].
    pub row_shear: Vector2<f64>,
}

impl Refinement {
    /// Bounds of the rotation (degrees) and translation (metres) error, meant to hold together on
    /// 90% of estimates: each is the 95% radius (Bonferroni: two bounds at 95% hold together at
    /// 90% or more) of a 3-D error with the worst axis's standard deviation on every axis. For a
    /// known covariance that is 2.8 standard deviations (the chi-square quantile); a covariance
    /// estimated from `B` blocks is itself uncertain, and the radius is Hotelling's,
    /// `sqrt(3 (B - 1) / (B - 3) F(3, B - 3))` standard deviations at the 95% quantile (3.4 for 16
    /// blocks, 4.1 for 10).
    pub fn bounds(&self) -> (f64, f64) {
        let worst = |block: Matrix3<f64>| block.symmetric_eigenvalues().max().max(0.0).sqrt();
        let rot = worst(self.covariance.fixed_view::<3, 3>(3, 3).into_owned());
        let trans = worst(self.covariance.fixed_view::<3, 3>(0, 0).into_owned());
        let k = radius_quantile(self.blocks);
        (k * rot.to_degrees(), k * trans)
    }
}

/// The 95% quantile of the radius (in standard deviations) of a 3-D Gaussian error whose
/// covariance was estimated from `blocks` blocks (0: known; see [`Refinement::bounds`]).
fn radius_quantile(blocks: usize) -> f64 {
    /// `sqrt` of the chi-square (3 degrees of freedom) 95% quantile, 7.815.
    const KNOWN: f64 = 2.7955;
    if blocks <= 4 {
        return KNOWN;
    }
    let b = blocks as f64;
    FisherSnedecor::new(3.0, b - 3.0)
        .map(|f| (3.0 * (b - 1.0) / (b - 3.0) * f.inverse_cdf(0.95)).sqrt())
        .ok()
        .filter(|k| k.is_finite())
        .map_or(KNOWN, |k| k.max(KNOWN))
}

/// The Gauss-Newton system, its weighted squared residual sum and residual count.
struct Normal {
    h: SMatrix<f64, 8, 8>,
    g: SVector<f64, 8>,
    sum: f64,
    count: usize,
}

/// Side of the grid of blocks that [`Blocks`] groups the pairs into: blocks a quarter of the
/// object across hold what neighbouring pairs share, and up to sixteen of them are enough for
/// eight unknowns.
const BLOCKS_PER_SIDE: f64 = 4.0;

/// The pairs' gradients `w J^T r` summed per block: the cells of a 4 x 4 grid over the source
/// rays' extent (see [`Blocks::covariance`]).
struct Blocks {
    lo: Vector2<f64>,
    cell: f64,
    sums: BTreeMap<(i64, i64), SVector<f64, 8>>,
}

impl Blocks {
    /// An empty grid over the `usable` pairs' source rays.
    fn new(c: &Correspondences, usable: &[usize]) -> Self {
        let rays: Vec<Vector2<f64>> = usable.iter().filter_map(|&i| ray(&c.source[i])).collect();
        let lo = rays.iter().fold(Vector2::repeat(f64::INFINITY), |a, r| a.inf(r));
        let hi = rays.iter().fold(Vector2::repeat(f64::NEG_INFINITY), |a, r| a.sup(r));
        Self { lo, cell: ((hi - lo).max() / BLOCKS_PER_SIDE).max(1e-12), sums: BTreeMap::new() }
    }

    /// The block gradient of the pair whose source point is `p` (`None` behind the camera).
    fn at(&mut self, p: &Point3) -> Option<&mut SVector<f64, 8>> {
        let r = ray(p)?;
        let key = (((r.x - self.lo.x) / self.cell) as i64, ((r.y - self.lo.y) / self.cell) as i64);
        Some(self.sums.entry(key).or_default())
    }

    /// The state's covariance from the blocks (cluster-robust): `H^-1 (sum_b g_b g_b^T) H^-1`
    /// times `B / (B - 1)`. An error that neighbouring pairs share (a texture tracked with a
    /// bias, a depth edge, a shutter's shear not quite linear) adds up within a block instead of
    /// averaging out as independent noise would. With the number of blocks; `None` with no more
    /// blocks than unknowns.
    fn covariance(mut self, h_inv: &SMatrix<f64, 8, 8>, unknowns: usize) -> Option<(SMatrix<f64, 8, 8>, usize)> {
        if self.sums.len() <= unknowns {
            return None;
        }
        let mut meat = SMatrix::<f64, 8, 8>::zeros();
        for g in self.sums.values_mut() {
            // A fixed shear has no gradient.
            g.rows_mut(unknowns, 8 - unknowns).fill(0.0);
            meat += *g * g.transpose();
        }
        let b = self.sums.len() as f64;
        Some((h_inv * meat * h_inv * (b / (b - 1.0)), self.sums.len()))
    }
}

/// The Huber weight of a term of residual norm `norm` from a pair of weight `w`.
fn robust_weight(w: f64, norm: f64, delta: f64) -> f64 {
    w * if norm <= delta { 1.0 } else { delta / norm }
}

/// What the Gauss-Newton system is built from besides the pairs.
struct Model {
    shutter: Shutter,
    /// Huber threshold of a residual's norm.
    delta: f64,
}

impl Model {
    /// Unknowns estimated: the twist, and the shear with a rolling shutter.
    fn unknowns(&self) -> usize {
        match self.shutter {
            Shutter::Global => 6,
            Shutter::Rolling { .. } => 8,
        }
    }
}

/// The Gauss-Newton system at `st` over the `usable` pairs. With [`Shutter::Rolling`] the
/// shear's prior (zero, `shear_sd`) is one more term, weighted against the pairs by their
/// residual variance at `st`; with [`Shutter::Global`] the shear's rows
/// and columns are those of a fixed unknown (identity, zero gradient). With `blocks`, each
/// pair's gradient is also added to its block's.
fn normal_equations(
    c: &Correspondences,
    usable: &[usize],
    st: &State,
    model: &Model,
    mut blocks: Option<&mut Blocks>,
) -> Normal {
    let mut n = Normal { h: SMatrix::zeros(), g: SVector::zeros(), sum: 0.0, count: 0 };
    for &i in usable {
        let mut block = blocks.as_deref_mut().and_then(|b| b.at(&c.source[i]));
        for (r, j) in st.terms(&c.source[i], &c.target[i]) {
            let w = robust_weight(c.weights[i], r.norm(), model.delta);
            let gradient = w * j.transpose() * r;
            n.h += w * j.transpose() * j;
            n.g += gradient;
            n.sum += w * r.norm_squared();
            n.count += 3;
            if let Some(b) = block.as_deref_mut() {
                *b += gradient;
            }
        }
    }
    match model.shutter {
        Shutter::Rolling { shear_sd } => {
            let noise_var = n.sum / n.count.max(1) as f64;
            let prior = noise_var / (shear_sd * shear_sd).max(1e-300);
            for k in 6..8 {
                n.h[(k, k)] += prior;
                n.g[k] += prior * st.shear[k - 6];
            }
        }
        Shutter::Global => {
            for k in 6..8 {
                n.h.row_mut(k).fill(0.0);
                n.h.column_mut(k).fill(0.0);
                n.h[(k, k)] = 1.0;
                n.g[k] = 0.0;
            }
        }
    }
    n
}

/// [`refine_by_reprojection_with`] for a global shutter (the pose alone).
pub fn refine_by_reprojection(
    c: &Correspondences,
    use_pair: &[bool],
    init: Pose,
    iterations: usize,
) -> Option<Refinement> {
    refine_by_reprojection_with(c, use_pair, init, iterations, Shutter::Global)
}

/// Refine `init` by Gauss-Newton on the two-way reprojection error of the pairs flagged in
/// `use_pair` (weighted by the pairs' weights, Huber-weighted at 1.345 robust sigmas), with the
/// covariance of the result (from blocks of pairs, see [`Refinement`]); with [`Shutter::Rolling`]
/// the target image's row shear is estimated with the pose. `None` with fewer than eight usable
/// pairs or a singular system.
pub fn refine_by_reprojection_with(
    c: &Correspondences,
    use_pair: &[bool],
    init: Pose,
    iterations: usize,
    shutter: Shutter,
) -> Option<Refinement> {
    let usable: Vec<usize> = (0..c.len()).filter(|&i| use_pair[i] && c.weights[i] > 0.0).collect();
    if usable.len() < MIN_PAIRS {
        return None;
    }
    let row0 = usable.iter().map(|&i| c.target[i].y / c.target[i].z).sum::<f64>() / usable.len() as f64;
    let mut st = State { pose: init, shear: Vector2::zeros(), row0 };
    let sigma = 1.4826 * median_norm(c, &usable, &st)?;
    let delta = (1.345 * sigma).max(1e-9);
    let model = Model { shutter, delta };
    for _ in 0..iterations {
        let n = normal_equations(c, &usable, &st, &model, None);
        let step = -n.h.cholesky()?.solve(&n.g);
        if !step.iter().all(|v| v.is_finite()) {
            return None;
        }
        st.pose = se3::exp(&step.fixed_rows::<6>(0).into_owned()) * st.pose;
        st.shear += step.fixed_rows::<2>(6);
        if step.norm() < 1e-12 {
            break;
        }
    }
    let mut blocks = Blocks::new(c, &usable);
    let n = normal_equations(c, &usable, &st, &model, Some(&mut blocks));
    let h_inv = n.h.cholesky()?.inverse();
    let unknowns = model.unknowns();
    let (full, blocks) = blocks.covariance(&h_inv, unknowns).unwrap_or_else(|| {
        let s2 = n.sum / (n.count.saturating_sub(unknowns).max(1)) as f64;
        (h_inv * s2, 0)
    });
    let covariance: Matrix6<f64> = full.fixed_view::<6, 6>(0, 0).into_owned();
    let finite = covariance.iter().chain(st.shear.iter()).all(|v| v.is_finite());
    finite.then_some(Refinement { pose: st.pose, covariance, blocks, row_shear: st.shear })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points on a 10 cm object 0.8 m away, moved by a small motion; every target point's depth
    /// scaled by a few millimetres' noise along its ray (the pixel stays): the 3-D pairs are off by
    /// millimetres, the rays are exact, and the refinement recovers the motion from identity.
    #[test]
    fn depth_noise_along_the_rays_does_not_move_the_answer() {
        let truth = Pose::new(Vector3::new(0.002, -0.001, 0.0015), Vector3::new(0.002, 0.004, -0.001));
        let mut source = vec![];
        let mut target = vec![];
        for i in 0..200 {
            let (u, v) = ((i % 20) as f64 / 19.0 - 0.5, (i / 20) as f64 / 9.0 - 0.5);
            let p = Point3::new(0.1 * u, 0.06 * v, 0.8 + 0.03 * (3.0 * u).sin() + 0.02 * v * v);
            let q = truth * p;
            let noise = 1.0 + 0.004 * ((i * 7919 % 101) as f64 / 50.0 - 1.0);
            source.push(p);
            target.push(Point3::from(q.coords * noise));
        }
        let c = Correspondences { weights: vec![1.0; source.len()], source, target };
        let all = vec![true; c.len()];
        let r = refine_by_reprojection(&c, &all, Pose::identity(), 20).unwrap();
        let rot_err = (r.pose.rotation * truth.rotation.inverse()).angle().to_degrees();
        assert!(rot_err < 0.01, "rotation error {rot_err} deg");
        // The bounds cover the error and are of its order (the range term carries the noise).
        let (rot_bound, trans_bound) = r.bounds();
        let trans_err = (r.pose.translation.vector - truth.translation.vector).norm();
        assert!(rot_err <= rot_bound && rot_bound < 0.5, "{rot_err} vs bound {rot_bound}");
        assert!(trans_err <= trans_bound && trans_bound < 0.01, "{trans_err} vs bound {trans_bound}");
        // Too few pairs: no answer.
        let few: Vec<bool> = (0..c.len()).map(|i| i < 5).collect();
        assert!(refine_by_reprojection(&c, &few, Pose::identity(), 20).is_none());
    }

    /// The bounds' radius (95% quantiles, scipy's values): 2.80 standard deviations for a known
    /// covariance, Hotelling's for one estimated from few blocks (wider the fewer there are),
    /// approaching 2.80 with many.
    #[test]
    fn the_bound_radius_widens_for_a_covariance_from_few_blocks() {
        assert!((radius_quantile(0) - 2.7955).abs() < 1e-4);
        assert!((radius_quantile(16) - 3.4359).abs() < 1e-3, "{}", radius_quantile(16));
        assert!((radius_quantile(10) - 4.0947).abs() < 1e-3, "{}", radius_quantile(10));
        assert!(radius_quantile(9) > radius_quantile(10) && radius_quantile(10_000) < 2.7965);
    }

    /// Pairs on a 10 cm object 0.8 m away after a small motion, the target image sheared as a
    /// rolling shutter shears it (each target ray shifted by 0.008 per unit of row: about 0.008 px
    /// per pixel row, 0.4 px across the object), plus a tenth of a pixel of tracking noise.
    fn sheared_pairs(shear: Vector2<f64>) -> (Correspondences, Pose) {
        let truth = Pose::new(Vector3::new(0.002, -0.001, 0.0015), Vector3::new(0.001, 0.002, -0.002));
        let (mut source, mut target) = (vec![], vec![]);
        for i in 0..400 {
            let (u, v) = ((i % 20) as f64 / 19.0 - 0.5, (i / 20) as f64 / 19.0 - 0.5);
            let p = Point3::new(0.1 * u, 0.1 * v, 0.8 + 0.03 * (3.0 * u).sin() + 0.02 * v * v);
            let q = truth * p;
            let noise =
                1e-4 * Vector2::new(((i * 7919) % 97) as f64 / 48.0 - 1.0, ((i * 104729) % 89) as f64 / 44.0 - 1.0);
            let r = Vector2::new(q.x / q.z, q.y / q.z) + q.y / q.z * shear + noise;
            source.push(p);
            target.push(Point3::new(r.x * q.z, r.y * q.z, q.z));
        }
        (Correspondences { weights: vec![1.0; source.len()], source, target }, truth)
    }

    fn rotation_error_deg(r: &Refinement, truth: &Pose) -> f64 {
        (r.pose.rotation * truth.rotation.inverse()).angle().to_degrees()
    }

    /// A rolling shutter's shear: the rigid fit turns the object (in-plane) to explain it, the
    /// rolling-shutter fit recovers the motion and the shear; on an unsheared image both agree.
    #[test]
    fn the_rolling_shutter_model_removes_the_shear_a_rigid_fit_takes_for_rotation() {
        let shear = Vector2::new(0.008, -0.004);
        let (c, truth) = sheared_pairs(shear);
        let all = vec![true; c.len()];
        let rigid = refine_by_reprojection(&c, &all, Pose::identity(), 20).unwrap();
        let rolling =
            refine_by_reprojection_with(&c, &all, Pose::identity(), 20, Shutter::Rolling { shear_sd: 0.01 }).unwrap();
        let (rigid_err, rolling_err) = (rotation_error_deg(&rigid, &truth), rotation_error_deg(&rolling, &truth));
        assert!(rigid_err > 0.15, "the rigid fit absorbs the shear: {rigid_err} deg");
        assert!(rolling_err < 0.02, "rolling-shutter fit: {rolling_err} deg");
        assert!((rolling.row_shear - shear).norm() < 5e-4, "shear {:?}", rolling.row_shear);
        assert_eq!(rigid.row_shear, Vector2::zeros());
        assert!(rolling_err <= rolling.bounds().0, "{rolling_err} vs bound {}", rolling.bounds().0);

        let (c, truth) = sheared_pairs(Vector2::zeros());
        let rigid = refine_by_reprojection(&c, &all, Pose::identity(), 20).unwrap();
        let rolling =
            refine_by_reprojection_with(&c, &all, Pose::identity(), 20, Shutter::Rolling { shear_sd: 0.01 }).unwrap();
        assert!(rotation_error_deg(&rigid, &truth) < 0.02 && rotation_error_deg(&rolling, &truth) < 0.02);
        assert!(rolling.row_shear.norm() < 5e-4, "no shear to find: {:?}", rolling.row_shear);
        // The shear's two unknowns are what the rotation bound pays (about 3.4x wider here).
        let (rolling_bound, rigid_bound) = (rolling.bounds().0, rigid.bounds().0);
        assert!(rotation_error_deg(&rolling, &truth) <= rolling_bound, "{rolling_bound}");
        assert!(rigid_bound < rolling_bound && rolling_bound < 5.0 * rigid_bound, "{rolling_bound} vs {rigid_bound}");
    }
}
