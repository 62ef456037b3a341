//! FilterReg (Gao & Tedrake, "FilterReg: Robust and Efficient Probabilistic Point-Set
//! Registration using Gaussian Filter and Twist Parameterization", CVPR 2019).
//!
//! The target is a Gaussian mixture with one isotropic component per point. For each moved
//! source point `x_i` the E-step needs `M0_i = sum_k N(x_i; y_k)`, `M1_i = sum_k N(x_i; y_k) y_k`,
//! `M2_i = sum_k N(x_i; y_k) |y_k|^2` and, for point-to-plane, `Mn_i = sum_k N(x_i; y_k) n_k`.
//! They come from a permutohedral-lattice Gaussian filter (linear in the number of points) or,
//! for checking, from exact sums over the k-d-tree neighbours within 4 sigma. The M-step
//! minimises `sum_i M0_i / (M0_i + c) |T x_i - M1_i / M0_i|^2` (point-to-point, closed form)
//! or its projection on the filtered normal (point-to-plane, Gauss-Newton on a twist); sigma^2
//! follows the EM update or an annealing schedule. Optional weighted correspondences add
//! `lambda * sum_j w_j |T a_j - b_j|^2` to the objective (used by Flow Filter). Once sigma has
//! settled, the EM iteration is Anderson-accelerated (see [`FilterRegConfig::anderson_depth`]).

mod solve;

use crate::error::RegistrationError;
use crate::evaluate::plane_or_point_step;
use crate::lattice::Lattice;
use crate::problem::{Correspondences, Registrar, Registration, RegistrationProblem, in_pool};
use flowfilter_geometry::{KnnIndex, Point3, Pose, RadiusGrid, Vector3, fastmath, weighted_kabsch};
use flowfilter_geometry::{ParamError, params};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::OnceLock;

/// Point-to-point or point-to-plane objective.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FilterRegVariant {
    /// `|T x_i - ybar_i|^2`.
    PointToPoint,
    /// `(nbar_i . (T x_i - ybar_i))^2`; needs target normals.
    PointToPlane,
}

/// How sigma evolves.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum SigmaSchedule {
    /// The EM update of sigma^2 after every M-step (floored at `min_sigma`).
    Update {
        /// Floor on sigma, metres.
        min_sigma: f64,
    },
    /// Multiply sigma by `factor` after every iteration, down to `min_sigma`.
    Anneal {
        /// Factor in (0, 1).
        factor: f64,
        /// Floor on sigma, metres.
        min_sigma: f64,
    },
}

/// How the E-step sums are computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FilterRegEStep {
    /// Permutohedral lattice (linear time; the method's).
    Lattice,
    /// Exact sums over target points within 4 sigma (k-d tree).
    Exact,
    /// The lattice while the 4-sigma support holds many target points (where the lattice's
    /// linear cost matters and its few-percent kernel error does not), exact sums once it holds
    /// fewer than about 48 (where the final accuracy is decided; neighbour lists are reused
    /// across iterations while the points move less than their margin).
    Auto,
}

/// FilterReg parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FilterRegConfig {
    /// Objective.
    pub variant: FilterRegVariant,
    /// Weight of the uniform outlier component, in [0, 1).
    pub w: f64,
    /// Iteration limit.
    pub max_iterations: usize,
    /// Stop when the update's rotation (rad) and translation (m) are both below this, or when
    /// the result moved by less than this per iteration over the last 10 (sigma settled in
    /// both cases).
    pub tolerance: f64,
    /// Sigma schedule.
    pub sigma: SigmaSchedule,
    /// Initial sigma^2 (m^2); `None`: the mean squared pair distance / 3 (computed in O(M+N)).
    pub init_sigma2: Option<f64>,
    /// E-step evaluation.
    pub e_step: FilterRegEStep,
    /// Gauss-Newton steps per M-step (point-to-plane).
    pub gauss_newton_steps: usize,
    /// Weight `lambda` of the correspondence term (when the problem has correspondences).
    pub correspondence_weight: f64,
    /// Inlier distance for the reported fitness / RMSE, metres.
    pub evaluation_distance: f64,
    /// Anderson acceleration of the EM iteration (pose and, with [`SigmaSchedule::Update`],
    /// sigma^2) mixing the last this many steps; 0 runs plain EM. A mixed step that makes the
    /// fixed-point residual grow is replaced by the plain EM step. Same fixed points, several
    /// times fewer iterations where EM crawls (points sliding along a smooth surface).
    pub anderson_depth: usize,
    /// With the [`FilterRegEStep::Auto`] E-step, the lattice iterations (wide kernel) merge
    /// source and target points into voxels of edge up to this fraction of sigma (centroids
    /// carrying their counts, spreads and summed values; the kernel sums change by about
    /// `fraction^2 / 4`), so they visit hundreds of points instead of thousands. The exact
    /// iterations that decide the final pose always use every point; the other E-steps never
    /// merge (with the lattice alone, the last iterations decide the pose). 0 disables merging.
    pub merge_fraction: f64,
    /// Point-to-plane with [`SigmaSchedule::Update`]: once an iteration moves the source by less
    /// than a tenth of sigma, estimate sigma^2 as the EM estimate less the kernel's two tangential
    /// variances. On surfaces the isotropic EM estimate is about `(2 sigma^2 + r^2) / 3` (the
    /// posterior spreads by sigma^2 along each tangent axis, by the residual `r^2` along the
    /// normal), so it shrinks by only a third per step towards `r^2`; `3 em - 2 sigma^2` goes
    /// there directly (still at most halving sigma^2 per step). The fixed point is the same.
    /// Ignored by point-to-point, whose tangential sliding needs the wider kernel.
    pub surface_sigma: bool,
    /// While the pose settles, iterate on an evenly spread subset of about this many source
    /// points (every k-th point in spatial order, each standing for k; it replaces the merged
    /// level where it is smaller); once an update moves the subset by less than 1% of sigma and
    /// changes sigma^2 by less than 1%, iterate on every point, with a fresh Anderson history,
    /// to convergence. The subset changes the route (the slow EM crawl of the middle iterations
    /// costs a fraction), not the fixed point. Clouds of at most twice this many points, and 0,
    /// use every point throughout.
    pub settling_points: usize,
    /// With the [`FilterRegEStep::Auto`] E-step and the point-to-plane objective, a registration
    /// whose E-step has switched between the lattice and the exact sums this many times stops
    /// there, not converged ([`crate::RegistrationWarning::KernelCycling`]): its kernel cycles
    /// (the lattice's sums narrow it, the exact ones widen it again) and it would run to
    /// `max_iterations` without settling. `None`: the runner's own limit, FilterReg alone
    /// [`DEFAULT_MAX_E_STEP_SWITCHES`], Flow Filter's runs
    /// [`crate::SCENE_MAX_E_STEP_SWITCHES`]. Point-to-point registrations switch
    /// often on their way to a pose and are not stopped (stopping them lost 4 of the 282 real
    /// region pairs). 0 = no limit.
    pub max_e_step_switches: Option<usize>,
}

/// FilterReg's own limit of E-step switches ([`FilterRegConfig::max_e_step_switches`]): on the
/// 141 whole RealSense frames every point-to-plane registration that converged switched at most
/// 7 times, every one that cycled switched on to the limit (with none, 19-46 times).
pub const DEFAULT_MAX_E_STEP_SWITCHES: usize = 9;

impl Default for FilterRegConfig {
    fn default() -> Self {
        Self {
            variant: FilterRegVariant::PointToPoint,
            w: 0.1,
            max_iterations: 300,
            tolerance: 1e-6,
            sigma: SigmaSchedule::Update { min_sigma: 1e-4 },
            init_sigma2: None,
            e_step: FilterRegEStep::Auto,
            gauss_newton_steps: 1,
            correspondence_weight: 0.0,
            evaluation_distance: 0.01,
            anderson_depth: 5,
            merge_fraction: 0.5,
            max_e_step_switches: None,
            surface_sigma: true,
            settling_points: 1000,
        }
    }
}

/// Minimum agreement `|sum_k K_ik n_k| / sum_k K_ik` of the normals under the kernel for a
/// point-to-plane residual; below it the point contributes its full point-to-point residual.
const NORMAL_COHERENCE: f64 = 0.8;

/// FilterReg as a [`Registrar`].
#[derive(Debug, Clone)]
pub struct FilterReg {
    /// Parameters.
    pub config: FilterRegConfig,
}

/// Per-source-point filtered sums.
struct Sums {
    m0: Vec<f64>,
    m1: Vec<Vector3>,
    m2: Vec<f64>,
    mn: Vec<Vector3>,
}

/// The lattice's kernel scale in 3-D, computed once per process.
fn lattice_scale() -> f64 {
    static SCALE: OnceLock<f64> = OnceLock::new();
    computed_once(&SCALE, || Lattice::kernel_scale(3))
}

/// The value in `cell`, computed by `compute` and stored if the cell is empty.
///
/// Unlike `OnceLock::get_or_init`, no lock is held while computing: the lattice's computation
/// runs rayon jobs, and while it waits for them its worker may steal another registration that
/// asks for the same value, re-entering the initialisation on the same thread (a deadlock).
/// `compute` must be deterministic: threads that race here compute the same value, and the
/// first one stored is kept.
fn computed_once(cell: &OnceLock<f64>, compute: impl Fn() -> f64) -> f64 {
    if let Some(value) = cell.get() {
        return *value;
    }
    let value = compute();
    *cell.get_or_init(|| value)
}

/// Target values per point: `[1, y, |y|^2]` and, with normals, `n`.
fn target_values(target: &[Point3], normals: Option<&[Vector3]>) -> (usize, Vec<f64>) {
    let vd = if normals.is_some() { 8 } else { 5 };
    let mut v = Vec::with_capacity(target.len() * vd);
    for (i, y) in target.iter().enumerate() {
        v.extend_from_slice(&[1.0, y.x, y.y, y.z, y.coords.norm_squared()]);
        if let Some(n) = normals {
            v.extend_from_slice(&[n[i].x, n[i].y, n[i].z]);
        }
    }
    (vd, v)
}

fn unpack(out: &[f64], vd: usize) -> Sums {
    let n = out.len() / vd;
    let mut s = Sums {
        m0: Vec::with_capacity(n),
        m1: Vec::with_capacity(n),
        m2: Vec::with_capacity(n),
        mn: Vec::with_capacity(n),
    };
    for o in out.chunks_exact(vd) {
        s.m0.push(o[0].max(0.0));
        s.m1.push(Vector3::new(o[1], o[2], o[3]));
        s.m2.push(o[4]);
        s.mn.push(if vd == 8 { Vector3::new(o[5], o[6], o[7]) } else { Vector3::zeros() });
    }
    s
}

fn lattice_sums(target: &[Point3], values: &[f64], vd: usize, queries: &[Point3], sigma: f64) -> Sums {
    let scaled =
        |v: &[Point3]| -> Vec<f64> { v.iter().flat_map(|p| [p.x / sigma, p.y / sigma, p.z / sigma]).collect() };
    let lattice = Lattice::new(3, &scaled(target), vd, values);
    let q = scaled(queries);
    let mut out = vec![0.0; queries.len() * vd];
    out.par_chunks_mut(vd * 256).zip(q.par_chunks(3 * 256)).for_each(|(o, qq)| lattice.slice(qq, o));
    let scale = lattice_scale();
    out.iter_mut().for_each(|v| *v /= scale);
    unpack(&out, vd)
}

/// [`FilterRegEStep::Auto`] switches to exact sums when the kernel support holds fewer target
/// points than this (typically).
const AUTO_NEIGHBOURS: usize = 48;

/// Merging stops at levels with fewer points than this.
const MERGED_MIN_POINTS: usize = 64;

/// Candidate target neighbours of every (moved) source point, gathered within `radius` of where
/// the points were (`built_at`). While the points have moved less than `radius - r` since, every
/// target point within `r` of a point is among its candidates, so the exact sums can be
/// evaluated from the lists without new k-d tree searches (most of the exact E-step's time).
struct NeighbourCache {
    radius: f64,
    built_at: Vec<Point3>,
    /// The lists of [`CACHE_CHUNK`] consecutive points per chunk: gathered, cut and read chunk by
    /// chunk in parallel, with no per-point allocation and no serial concatenation.
    chunks: Vec<ListChunk>,
}

/// The candidate lists of consecutive points: point `i`'s list is
/// `indices[offsets[i]..offsets[i + 1]]`, ascending.
struct ListChunk {
    offsets: Vec<u32>,
    indices: Vec<u32>,
}

impl ListChunk {
    fn with_capacity(points: usize, candidates: usize) -> Self {
        let mut offsets = Vec::with_capacity(points + 1);
        offsets.push(0);
        Self { offsets, indices: Vec::with_capacity(candidates) }
    }

    fn list(&self, i: usize) -> &[u32] {
        &self.indices[self.offsets[i] as usize..self.offsets[i + 1] as usize]
    }

    /// Ends the list of the next point (the indices pushed since the previous one).
    fn close(&mut self) {
        self.offsets.push(self.indices.len() as u32);
    }
}

/// Points per [`ListChunk`].
const CACHE_CHUNK: usize = 256;

/// Candidate lists are gathered this much wider than the kernel's 4-sigma support. Tight lists
/// win: every candidate costs a distance evaluation in every iteration, and cutting or
/// re-gathering the lists is cheap next to that (1.05 / 1.2 measured 10-20% faster than
/// 1.25 / 1.6 on the peers' clouds, same poses).
const CACHE_MARGIN: f64 = 1.05;
/// Lists wider than this many times the current support are cut down (sigma has shrunk).
const CACHE_MAX_WIDTH: f64 = 1.2;

impl NeighbourCache {
    fn build(index: &KnnIndex, target: &[Point3], queries: &[Point3], radius: f64) -> Self {
        // A uniform grid where the box allows one (the usual case), else the k-d tree.
        let grid = RadiusGrid::new(target, radius);
        let chunks = queries
            .par_chunks(CACHE_CHUNK)
            .map(|qs| {
                let mut c = ListChunk::with_capacity(qs.len(), 0);
                let mut seen = vec![];
                for q in qs {
                    let start = c.indices.len();
                    match &grid {
                        Some(g) => g.within(q, &mut c.indices),
                        None => c.indices.extend(index.within(q, radius).iter().map(|n| n.index as u32)),
                    }
                    // Ascending indices: the sums then walk the target arrays forwards.
                    sort_distinct(&mut c.indices[start..], target.len(), &mut seen);
                    c.close();
                }
                c
            })
            .collect();
        Self { radius, built_at: queries.to_vec(), chunks }
    }

    /// The largest squared distance a point of `queries` (the same points, moved) has moved since
    /// the lists were gathered; `None` for other points.
    fn moved2(&self, queries: &[Point3]) -> Option<f64> {
        (queries.len() == self.built_at.len())
            .then(|| queries.iter().zip(&self.built_at).map(|(q, b)| (q - b).norm_squared()).fold(0.0, f64::max))
    }

    /// The squared distance from `q`, point `i` of the queries moved, to its nearest target
    /// point, where `i`'s list certifies it: every target point within the list's radius less
    /// the distance moved since the gathering is on the list, so a nearest candidate that close
    /// is the nearest point. `None` otherwise (search the tree).
    fn nearest2(&self, i: usize, q: &Point3, target: &[Point3]) -> Option<f64> {
        let slack = self.radius - (q - self.built_at[i]).norm();
        if slack <= 0.0 {
            return None;
        }
        let list = self.chunks[i / CACHE_CHUNK].list(i % CACHE_CHUNK);
        let best = list.iter().map(|&k| (target[k as usize] - q).norm_squared()).fold(f64::INFINITY, f64::min);
        (best <= slack * slack).then_some(best)
    }

    /// Whether the lists still cover radius `r` around every point, the points having moved by at
    /// most `sqrt(moved2)`, without being much wider than needed (each candidate costs a distance
    /// evaluation).
    fn covers(&self, moved2: f64, r: f64) -> bool {
        self.radius <= CACHE_MAX_WIDTH * r && within_slack(moved2, self.radius - r)
    }

    /// Lists of radius `radius` around `queries` cut from these wider ones, when they still hold
    /// every target point within `radius` of every query (the points moved less than the
    /// difference of the radii since the lists were gathered). No k-d tree search: sigma shrinks
    /// a few percent per iteration, and re-gathering was most of the exact E-step's time.
    fn shrunk(&self, queries: &[Point3], moved2: f64, values: &[f64], vd: usize, radius: f64) -> Option<Self> {
        if !within_slack(moved2, self.radius - radius) {
            return None;
        }
        let r2 = radius * radius;
        let chunks = self
            .chunks
            .par_iter()
            .zip(queries.par_chunks(CACHE_CHUNK))
            .map(|(c, qs)| {
                let mut out = ListChunk::with_capacity(qs.len(), c.indices.len());
                for (i, q) in qs.iter().enumerate() {
                    // Branch-free compaction: every candidate is written, the kept ones advance.
                    let (list, start) = (c.list(i), out.indices.len());
                    out.indices.resize(start + list.len(), 0);
                    let mut kept = start;
                    for &k in list {
                        out.indices[kept] = k;
                        kept += usize::from(dist2(&values[k as usize * vd..], q) <= r2);
                    }
                    out.indices.truncate(kept);
                    out.close();
                }
                out
            })
            .collect();
        Some(Self { radius, built_at: queries.to_vec(), chunks })
    }
}

/// Whether a move of `sqrt(moved2)` stays below `slack` (> 0).
fn within_slack(moved2: f64, slack: f64) -> bool {
    slack > 0.0 && moved2 < slack * slack
}

/// Sorts `list`, distinct indices below `n`, ascending: by comparisons when it is short, else by
/// marking the indices in the bit set `seen` and reading them back in order (linear time; the
/// lists of wide kernels hold hundreds to thousands of candidates). Either way the same order.
fn sort_distinct(list: &mut [u32], n: usize, seen: &mut Vec<u64>) {
    let words = n.div_ceil(64);
    if list.len() < 64 || words > 4 * list.len() {
        list.sort_unstable();
        return;
    }
    seen.clear();
    seen.resize(words, 0);
    for &k in list.iter() {
        seen[k as usize / 64] |= 1 << (k % 64);
    }
    let mut out = 0;
    for (w, &word) in seen.iter().enumerate() {
        let mut bits = word;
        while bits != 0 {
            list[out] = (w * 64) as u32 + bits.trailing_zeros();
            out += 1;
            bits &= bits - 1;
        }
    }
    debug_assert_eq!(out, list.len(), "indices were not distinct");
}

/// Squared distance from `q` to the target point of a values row `[1, y, |y|^2, ...]` (the
/// coordinates come from the same cache lines as the values summed).
#[inline]
fn dist2(v: &[f64], q: &Point3) -> f64 {
    (v[1] - q.x).powi(2) + (v[2] - q.y).powi(2) + (v[3] - q.z).powi(2)
}

/// The exact E-step: a k-d tree over the target and the current neighbour lists.
struct ExactEStep<'a> {
    index: &'a KnnIndex,
    target: &'a [Point3],
    cache: Option<NeighbourCache>,
}

impl ExactEStep<'_> {
    /// Exact sums within 4 sigma of `queries` (the moved source points).
    fn sums(&mut self, queries: &[Point3], values: &[f64], vd: usize, sigma: f64) -> Sums {
        let (index, target, cache) = (self.index, self.target, &mut self.cache);
        let r = 4.0 * sigma;
        // How far the points moved since the lists were gathered: measured once, for both tests.
        let held = cache.as_ref().and_then(|c| Some((c, c.moved2(queries)?)));
        if !held.is_some_and(|(c, moved2)| c.covers(moved2, r)) {
            let shrunk = held.and_then(|(c, moved2)| c.shrunk(queries, moved2, values, vd, CACHE_MARGIN * r));
            *cache = Some(shrunk.unwrap_or_else(|| NeighbourCache::build(index, target, queries, CACHE_MARGIN * r)));
        }
        let cache = cache.as_ref().expect("built above");
        let (inv, r2) = (-0.5 / (sigma * sigma), r * r);
        let mut out = vec![0.0; queries.len() * vd];
        out.par_chunks_mut(vd * CACHE_CHUNK)
            .zip(cache.chunks.par_iter())
            .zip(queries.par_chunks(CACHE_CHUNK))
            .for_each(|((out, c), qs)| match vd {
                5 => kernel_sums::<5>(c, qs, values, inv, r2, out),
                8 => kernel_sums::<8>(c, qs, values, inv, r2, out),
                _ => unreachable!("target values rows hold 5 or 8 entries"),
            });
        unpack(&out, vd)
    }
}

/// The exact sums of one chunk of points: `out` row `i` (`VD` entries) receives
/// `sum_k exp(inv d2_ik) v_k` over the candidates `k` of point `i` within `sqrt(r2)` of
/// `qs[i]`. The weights of a point's candidates are computed first, in one branch-free pass
/// (the exponentials vectorise; a candidate beyond the support weighs exactly 0), then summed.
fn kernel_sums<const VD: usize>(c: &ListChunk, qs: &[Point3], values: &[f64], inv: f64, r2: f64, out: &mut [f64]) {
    let mut weights = Vec::new();
    for ((i, q), acc) in qs.iter().enumerate().zip(out.chunks_exact_mut(VD)) {
        let list = c.list(i);
        weights.clear();
        weights.extend(list.iter().map(|&k| dist2(&values[k as usize * VD..], q)));
        for w in weights.iter_mut() {
            let e = fastmath::exp(*w * inv);
            *w = if *w <= r2 { e } else { 0.0 };
        }
        let mut sum = [0.0; VD];
        for (&k, &w) in list.iter().zip(&weights) {
            let v: &[f64; VD] = values[k as usize * VD..(k as usize + 1) * VD].try_into().expect("VD entries");
            for (s, vc) in sum.iter_mut().zip(v) {
                *s += w * vc;
            }
        }
        acc.copy_from_slice(&sum);
    }
}

impl FilterReg {
    /// FilterReg with the given parameters.
    ///
    /// # Errors
    /// [`RegistrationError::Param`] for a value out of range ([`FilterRegConfig::validate`]).
    pub fn new(config: FilterRegConfig) -> Result<Self, RegistrationError> {
        config.validate().map_err(|e| e.within("filterreg"))?;
        Ok(Self { config })
    }
}

impl FilterRegConfig {
    /// Check every value: finite and in range.
    ///
    /// # Errors
    /// The first key at fault (keys relative to the `[filterreg]` table).
    pub fn validate(&self) -> Result<(), ParamError> {
        params::in_half_open("w", self.w, 0.0, 1.0)?;
        params::count_positive("max_iterations", self.max_iterations)?;
        params::non_negative("tolerance", self.tolerance)?;
        match self.sigma {
            SigmaSchedule::Update { min_sigma } => params::positive("sigma.min_sigma", min_sigma)?,
            SigmaSchedule::Anneal { factor, min_sigma } => {
                params::in_open("sigma.factor", factor, 0.0, 1.0)?;
                params::positive("sigma.min_sigma", min_sigma)?;
            }
        }
        if let Some(s2) = self.init_sigma2 {
            params::positive("init_sigma2", s2)?;
        }
        params::count_positive("gauss_newton_steps", self.gauss_newton_steps)?;
        params::non_negative("correspondence_weight", self.correspondence_weight)?;
        params::positive("evaluation_distance", self.evaluation_distance)?;
        params::in_closed("merge_fraction", self.merge_fraction, 0.0, 1.0)
    }
}

/// One M-step: the update `delta` (applied on the left) from the filtered targets, plus the
/// correspondence term. Point-to-point is solved in closed form by a weighted Kabsch over the
/// union of both point sets (the correspondence term has the same form). `counts`: how many
/// source points each of `x` stands for (merged points), `None` for one each.
///
/// A point-to-plane update that would move the source (`reach`) by more than the kernel's
/// width is replaced by the point-to-point update: the posteriors only hold within about a
/// kernel of where they were computed, and while the kernel is wide the filtered normals of a
/// smooth sheet agree well enough to pass the coherence test yet leave the sliding directions
/// unconstrained (a 1.2 m wavy surface 4.5 deg off took a 62 deg first step and diverged).
fn m_step(
    cfg: &FilterRegConfig,
    x: &[Point3],
    counts: Option<&[f64]>,
    sums: &Sums,
    c: f64,
    corr: Option<(&Correspondences, &Pose)>,
    reach: &Reach,
) -> Option<Pose> {
    let mut src = Vec::with_capacity(x.len());
    let mut dst = Vec::with_capacity(x.len());
    let mut w = Vec::with_capacity(x.len());
    let mut nrm = Vec::with_capacity(x.len());
    for (i, xi) in x.iter().enumerate() {
        let m0 = sums.m0[i];
        if m0 <= 1e-12 {
            continue;
        }
        src.push(*xi);
        dst.push(Point3::from(sums.m1[i] / m0));
        w.push(counts.map_or(1.0, |n| n[i]) * m0 / (m0 + c));
        // The filtered normal is only meaningful where the normals under the kernel agree
        // (|sum n| close to sum 1); elsewhere (large sigma, edges) use the full residual.
        let coherence = sums.mn[i].norm() / m0;
        nrm.push(if coherence >= NORMAL_COHERENCE { sums.mn[i].try_normalize(1e-12) } else { None });
    }
    let total_gmm: f64 = w.iter().sum();
    if let Some((k, t)) = corr {
        let wsum: f64 = k.weights.iter().sum();
        if wsum > 0.0 && cfg.correspondence_weight > 0.0 {
            // lambda scales the correspondence term relative to the (normalised) GMM term.
            let scale = cfg.correspondence_weight * total_gmm.max(1.0) / wsum;
            for j in 0..k.len() {
                src.push(t * k.source[j]);
                dst.push(k.target[j]);
                w.push(scale * k.weights[j]);
                nrm.push(None);
            }
        }
    }
    if src.len() < 3 {
        return None;
    }
    match cfg.variant {
        FilterRegVariant::PointToPoint => weighted_kabsch(&src, &dst, Some(&w)).ok(),
        FilterRegVariant::PointToPlane => {
            // Pairs without a coherent normal (and correspondence pairs) contribute their
            // point-to-point error, the sum of three point-to-plane errors along the axes.
            let mut delta = Pose::identity();
            for _ in 0..cfg.gauss_newton_steps.max(1) {
                delta = plane_or_point_step(&src, &dst, &nrm, &w, &delta)? * delta;
            }
            if reach.moved_by(&delta) <= reach.sigma { Some(delta) } else { weighted_kabsch(&src, &dst, Some(&w)).ok() }
        }
    }
}

/// The moved source's extent and the kernel's width, against which an update is measured.
struct Reach {
    /// The source's centroid, moved by the current pose.
    centre: Point3,
    /// The source's RMS distance from its centroid.
    radius: f64,
    sigma: f64,
}

impl Reach {
    /// How far the update `delta` (applied on the left) moves the source: its centroid's
    /// displacement plus the rotation's sweep at its RMS radius.
    fn moved_by(&self, delta: &Pose) -> f64 {
        (delta * self.centre - self.centre).norm() + delta.rotation.angle() * self.radius
    }
}

/// [`FilterRegConfig::surface_sigma`] applies once an iteration moves the source (its centroid,
/// plus the rotation's sweep at its RMS radius) by less than this fraction of sigma.
const SURFACE_SIGMA_SETTLED: f64 = 0.1;

/// The iterations on [`FilterRegConfig::settling_points`] have settled once an update moves the
/// source by less than this fraction of sigma and changes sigma^2 by less than this fraction.
const SUBSET_SETTLED: f64 = 0.01;

/// Mixing starts once an EM step changes sigma^2 by less than this fraction.
const MIXING_SIGMA_CHANGE: f64 = 0.05;

impl Registrar for FilterReg {
    fn name(&self) -> &str {
        match self.config.variant {
            FilterRegVariant::PointToPoint => "filterreg-pt2pt",
            FilterRegVariant::PointToPlane => "filterreg-pt2pl",
        }
    }

    fn register(&self, p: &RegistrationProblem) -> Result<Registration, RegistrationError> {
        in_pool(|| self.solve(p))
    }
}

/// `values` in the order `order` (indices into `values`).
fn permuted<T: Copy>(values: &[T], order: &[u32]) -> Vec<T> {
    order.iter().map(|&i| values[i as usize]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    /// A rayon worker computing the kernel scale may steal a job that asks for it again, on the
    /// same thread. That nested request must compute the value rather than wait on the outer one
    /// (with `OnceLock::get_or_init` it deadlocks).
    #[test]
    fn the_kernel_scale_may_be_requested_while_it_is_being_computed() {
        let (done, finished) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let cell = OnceLock::new();
            let outer = computed_once(&cell, || computed_once(&cell, || 2.0) + 0.0);
            done.send((outer, cell.get().copied())).unwrap();
        });
        let (outer, stored) = finished
            .recv_timeout(std::time::Duration::from_secs(10))
            .expect("a nested request for the value blocked on the outer one");
        assert_eq!((outer, stored), (2.0, Some(2.0)));
        assert_eq!(lattice_scale(), Lattice::kernel_scale(3));
    }

    fn cloud(n: usize, seed: u64) -> Vec<Point3> {
        crate::test_clouds::uniform_box(n, seed, (0.1, 0.1, 0.02))
    }

    /// Long lists sorted through the bit set come out as a comparison sort's.
    #[test]
    fn bit_set_sorting_is_the_comparison_sort() {
        let mut seed = 5u64;
        let mut seen = vec![];
        for (len, n) in [(10usize, 100usize), (64, 200), (300, 1000), (2000, 20000), (5000, 5000)] {
            // Distinct indices below n in a scrambled order (a permutation's prefix).
            let mut all: Vec<u32> = (0..n as u32).collect();
            for i in (1..n).rev() {
                seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                all.swap(i, (seed >> 33) as usize % (i + 1));
            }
            let mut list = all[..len].to_vec();
            let mut want = list.clone();
            want.sort_unstable();
            sort_distinct(&mut list, n, &mut seen);
            assert_eq!(list, want, "{len} of {n}");
        }
    }

    /// The exact E-step's sums are the brute-force Gaussian sums over every target point within
    /// 4 sigma (libm's exp), with and without normals, to a few ulp.
    #[test]
    fn exact_sums_are_the_brute_force_sums() {
        let (source, target) = (cloud(300, 3), cloud(900, 4));
        let normals: Vec<Vector3> =
            target.iter().map(|p| Vector3::new(p.x.sin(), p.y.cos(), 1.0 + p.z).normalize()).collect();
        let sigma = 0.006;
        let index = KnnIndex::new(&target);
        for with_normals in [false, true] {
            let (vd, values) = target_values(&target, with_normals.then_some(&normals[..]));
            let mut e = ExactEStep { index: &index, target: &target, cache: None };
            let got = e.sums(&source, &values, vd, sigma);
            for (i, q) in source.iter().enumerate() {
                let mut want = vec![0.0; vd];
                for (k, y) in target.iter().enumerate() {
                    let d2 = (y - q).norm_squared();
                    if d2 <= 16.0 * sigma * sigma {
                        let w = (-d2 / (2.0 * sigma * sigma)).exp();
                        want.iter_mut().zip(&values[k * vd..(k + 1) * vd]).for_each(|(a, v)| *a += w * v);
                    }
                }
                let scale = want[0].max(1e-300);
                assert!((got.m0[i] - want[0]).abs() <= 1e-13 * scale, "m0[{i}]");
                assert!((got.m1[i] - Vector3::new(want[1], want[2], want[3])).norm() <= 1e-13 * scale, "m1[{i}]");
                assert!((got.m2[i] - want[4]).abs() <= 1e-13 * scale, "m2[{i}]");
                if with_normals {
                    assert!((got.mn[i] - Vector3::new(want[5], want[6], want[7])).norm() <= 1e-13 * scale, "mn[{i}]");
                }
            }
            assert!(got.m0.iter().filter(|&&m| m > 0.0).count() > 200, "most points have neighbours");
        }
    }

    /// Sums from reused neighbour lists equal sums from a fresh k-d tree search, and lists are
    /// gathered again once the points have moved beyond their margin or sigma has shrunk.
    #[test]
    fn reused_neighbour_lists_give_the_sums_of_a_fresh_search() {
        let (source, target) = (cloud(800, 1), cloud(1200, 2));
        let (vd, values) = target_values(&target, None);
        let sigma = 0.004;
        let fresh = |pose: &Pose, sigma: f64| {
            let x: Vec<Point3> = source.iter().map(|s| pose * s).collect();
            let index = KnnIndex::new(&target);
            let mut e = ExactEStep { index: &index, target: &target, cache: None };
            (e.sums(&x, &values, vd, sigma), x)
        };
        let index = KnnIndex::new(&target);
        let mut e = ExactEStep { index: &index, target: &target, cache: None };
        let p0 = Pose::identity();
        let x0: Vec<Point3> = source.iter().map(|s| p0 * s).collect();
        e.sums(&x0, &values, vd, sigma);
        // Small move (well inside the margin): the lists are reused.
        let p1 = Pose::from_parts(
            Translation3::new(0.0006, -0.0003, 0.0002),
            UnitQuaternion::from_euler_angles(0.004, 0.0, 0.003),
        );
        let (want, x1) = fresh(&p1, sigma);
        let got = e.sums(&x1, &values, vd, sigma);
        assert_eq!(e.cache.as_ref().unwrap().built_at, x0, "lists were gathered again for a small move");
        for i in 0..source.len() {
            assert!((got.m0[i] - want.m0[i]).abs() <= 1e-12 * want.m0[i].max(1.0), "m0[{i}]");
            assert!((got.m1[i] - want.m1[i]).norm() <= 1e-12 * want.m0[i].max(1.0), "m1[{i}]");
        }
        // A move beyond the margin (6 mm: lists of 1.05 x 16 mm for a 16 mm support) and a halved sigma each trigger a new search.
        let p2 = Pose::from_parts(Translation3::new(0.006, 0.0, 0.0), UnitQuaternion::identity());
        let (want, x2) = fresh(&p2, sigma);
        let got = e.sums(&x2, &values, vd, sigma);
        assert_eq!(e.cache.as_ref().unwrap().built_at, x2);
        assert!(got.m0.iter().zip(&want.m0).all(|(a, b)| (a - b).abs() <= 1e-12 * b.max(1.0)));
        // A halved sigma: the lists are cut from the wider ones (no new search) and give the
        // sums of a fresh search.
        let got = e.sums(&x2, &values, vd, sigma / 2.0);
        assert!(e.cache.as_ref().unwrap().radius < CACHE_MARGIN * 4.0 * sigma);
        let (want, _) = fresh(&p2, sigma / 2.0);
        for i in 0..source.len() {
            assert!((got.m0[i] - want.m0[i]).abs() <= 1e-12 * want.m0[i].max(1.0), "shrunk m0[{i}]");
            assert!((got.m1[i] - want.m1[i]).norm() <= 1e-12 * want.m0[i].max(1.0), "shrunk m1[{i}]");
        }
    }
}
