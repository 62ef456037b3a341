//! Rigid Coherent Point Drift (Myronenko & Song, "Point Set Registration: Coherent Point
//! Drift", PAMI 2010): the source is a Gaussian mixture whose centroids move rigidly (with
//! optional scale) to explain the target; sigma^2 is updated in closed form.

mod component_lists;

use crate::anderson::PoseMixing;
use crate::error::RegistrationError;
use crate::evaluate::evaluate;
use crate::gmm::{mean_pair_distance2, outlier_term};
use crate::lattice::Lattice;
use crate::problem::{IterationRecord, Registrar, Registration, RegistrationProblem, in_pool, validate_problem};
use crate::warning::RegistrationWarning;
use component_lists::{ComponentLists, LIST_MARGIN};
use flowfilter_geometry::{KnnIndex, Point3, PointCloud, Pose, Vector3, fastmath, nearest_rotation, spatial_order};
use flowfilter_geometry::{ParamError, params};
use nalgebra::{Matrix3, Translation3, UnitQuaternion};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// How the E-step sums over the mixture.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum CpdEStep {
    /// Every pair (rayon-parallel over target points): exact, O(M N).
    Exact,
    /// Only components within `radius_sigmas * sigma` (k-d tree): the neglected terms are below
    /// `exp(-radius_sigmas^2 / 2)` each.
    Truncated {
        /// Cut-off radius in units of sigma.
        radius_sigmas: f64,
    },
    /// Exact below `max_pairs` pairs, truncated at 4 sigma above.
    Auto {
        /// Pair-count threshold.
        max_pairs: usize,
    },
    /// For clouds of sensor size: exact below `max_pairs` pairs; above, the Gaussian sums on a
    /// permutohedral lattice (the role of the fast Gauss transform in the CPD paper: O(M + N)
    /// per iteration) while a truncated E-step would still visit more than `max_neighbours`
    /// components per observation (sigma large against the point spacing, where the lattice's
    /// few percent of error do not move the pose), then truncated at 4 sigma (exact where it
    /// matters, near the optimum).
    Fast {
        /// Pair-count threshold of the exact E-step.
        max_pairs: usize,
        /// Mean components within 4 sigma of an observation above which the lattice is used; at
        /// least [`MIN_LATTICE_NEIGHBOURS`].
        max_neighbours: usize,
    },
}

/// How one iteration's E-step runs (see [`CpdEStep`]).
#[derive(Debug, Clone, Copy)]
enum EStepKind {
    Exact,
    Truncated(f64),
    Lattice,
}

/// Smallest `max_neighbours` of [`CpdEStep::Fast`]: below, the lattice runs at a sigma near the
/// point spacing, where its error moves the pose (64 turned a 60k-point pair 160 deg away).
pub const MIN_LATTICE_NEIGHBOURS: usize = 100;

/// Observations sampled to estimate how many components lie within the truncation radius.
const NEIGHBOUR_SAMPLE: usize = 32;

/// Anderson mixing starts once an EM step changes sigma^2 by less than this fraction.
const MIXING_SIGMA_CHANGE: f64 = 0.05;

/// Log-posteriors are clamped at this (`e^-700`: far below a double's precision against the
/// largest term, and above the subnormals whose arithmetic is slow).
const NEGLIGIBLE_LOG: f64 = -700.0;

/// Floor of sigma^2 (m^2): 10 micrometres, far below any sensor's noise.
const SIGMA2_FLOOR: f64 = 1e-10;

/// Observations per chunk of the E-step's order-fixed parallel sums.
const E_STEP_CHUNK: usize = 1024;

/// CPD parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CpdConfig {
    /// Weight of the uniform outlier component, in [0, 1).
    pub w: f64,
    /// Iteration limit.
    pub max_iterations: usize,
    /// Stop when sigma^2 changes by less than this fraction ...
    pub tolerance: f64,
    /// ... and an iteration turns the pose by less than this (radians plus metres moved).
    pub pose_tolerance: f64,
    /// Estimate a scale too.
    pub estimate_scale: bool,
    /// E-step evaluation.
    pub e_step: CpdEStep,
    /// Initial sigma^2 (m^2); `None`: the mean squared pair distance / 3 (the paper's).
    pub init_sigma2: Option<f64>,
    /// Inlier distance for the reported fitness / RMSE, metres.
    pub evaluation_distance: f64,
    /// Work limit: a cloud with more points is registered on an even subset of this many (every
    /// k-th point in spatial order), with a warning; 0 = no limit. While sigma is large the
    /// E-step visits every pair, so an iteration costs about `M N` kernel evaluations (0.5 s at
    /// 10k x 10k points on 2 cores, 12.6 s at 50k x 50k).
    pub max_points: usize,
    /// Anderson acceleration of the EM iteration (pose and sigma^2) over the last this many
    /// steps, from the first step that changes sigma^2 by less than 5%; 0 runs plain EM (the
    /// reference implementations' iteration). A mixed step whose fixed-point residual grew is
    /// replaced by the plain step. Same fixed points, several times fewer iterations where EM
    /// crawls (points sliding along a smooth surface). Ignored with `estimate_scale`.
    pub anderson_depth: usize,
    /// Coarse-to-fine settling: clouds with at least twice this many points are first
    /// registered on even subsets (every k-th point in spatial order) of a quarter, a sixteenth,
    /// ... of the larger cloud's size, down to no fewer than this many points, smallest first,
    /// each level until its iteration settles; then on every point. The wide-kernel iterations,
    /// where a subset describes the mixture as well as the whole cloud, cost a fraction, and
    /// each level starts near its own optimum. 0 iterates on every point throughout. The final
    /// iterations, which decide the pose, always use every point.
    pub settling_points: usize,
}

impl Default for CpdConfig {
    fn default() -> Self {
        Self {
            w: 0.0,
            max_iterations: 150,
            tolerance: 1e-5,
            pose_tolerance: 1e-8,
            estimate_scale: false,
            e_step: CpdEStep::Fast { max_pairs: 4_000_000, max_neighbours: 256 },
            init_sigma2: None,
            evaluation_distance: 0.01,
            max_points: DEFAULT_MAX_POINTS,
            anderson_depth: 5,
            settling_points: 2000,
        }
    }
}

/// [`CpdConfig::max_points`]'s default: twice a full 640x480 sensor cloud's valid points (about
/// 50-60k), so that a sensor's cloud is registered whole. With the default fast E-step an
/// iteration costs O(M + N) (1 s for a 60k-point pair on 2 cores, docs/benchmarks.md); the limit
/// bounds a merged or scanned cloud's cost.
pub const DEFAULT_MAX_POINTS: usize = 120_000;

/// Rigid CPD as a [`Registrar`].
#[derive(Debug, Clone)]
pub struct Cpd {
    /// Parameters.
    pub config: CpdConfig,
}

impl Cpd {
    /// CPD with the given parameters.
    ///
    /// # Errors
    /// [`RegistrationError::Param`] for a value out of range ([`CpdConfig::validate`]).
    pub fn new(config: CpdConfig) -> Result<Self, RegistrationError> {
        config.validate().map_err(|e| e.within("cpd"))?;
        Ok(Self { config })
    }
}

impl CpdConfig {
    /// Check every value: finite and in range.
    ///
    /// # Errors
    /// The first key at fault (keys relative to the `[cpd]` table).
    pub fn validate(&self) -> Result<(), ParamError> {
        params::in_half_open("w", self.w, 0.0, 1.0)?;
        params::count_positive("max_iterations", self.max_iterations)?;
        params::positive("tolerance", self.tolerance)?;
        params::positive("pose_tolerance", self.pose_tolerance)?;
        if let Some(s2) = self.init_sigma2 {
            params::positive("init_sigma2", s2)?;
        }
        params::positive("evaluation_distance", self.evaluation_distance)?;
        if self.max_points != 0 {
            params::require(self.max_points >= 3, "max_points", "0 (no limit) or at least 3", self.max_points)?;
        }
        match self.e_step {
            CpdEStep::Truncated { radius_sigmas } => params::positive("e_step.radius_sigmas", radius_sigmas)?,
            CpdEStep::Auto { max_pairs } => params::count_positive("e_step.max_pairs", max_pairs)?,
            CpdEStep::Fast { max_pairs, max_neighbours } => {
                params::count_positive("e_step.max_pairs", max_pairs)?;
                params::require(
                    max_neighbours >= MIN_LATTICE_NEIGHBOURS,
                    "e_step.max_neighbours",
                    "at least 100 (the lattice is not accurate when sigma nears the point spacing)",
                    max_neighbours,
                )?;
            }
            CpdEStep::Exact => {}
        }
        Ok(())
    }
}

/// Posterior sums of one E-step.
struct EStep {
    /// `P 1` per component (source point).
    p1: Vec<f64>,
    /// `P^T 1` per observation (target point).
    pt1: Vec<f64>,
    /// `P X` per component.
    px: Vec<Vector3>,
    /// `(sum_mn P_mn x_n, sum_mn P_mn |x_n|^2)` summed over the components, when the sums per
    /// observation come from another approximation than `px` (the lattice: the M-step's
    /// variance is a difference of these sums, and they must come from one pass).
    observed: Option<(Vector3, f64)>,
}

impl CpdEStep {
    /// The E-step for this iteration: `ty` the moved source (components), `x` the target.
    fn kind(&self, ty: &[Point3], x: &[Point3], sigma2: f64) -> EStepKind {
        let pairs = ty.len() * x.len();
        match *self {
            CpdEStep::Exact => EStepKind::Exact,
            CpdEStep::Truncated { radius_sigmas } => EStepKind::Truncated(radius_sigmas),
            CpdEStep::Auto { max_pairs } if pairs > max_pairs => EStepKind::Truncated(4.0),
            CpdEStep::Auto { .. } => EStepKind::Exact,
            CpdEStep::Fast { max_pairs, .. } if pairs <= max_pairs => EStepKind::Exact,
            CpdEStep::Fast { max_neighbours, .. } => {
                if mean_neighbours(ty, x, 4.0 * sigma2.sqrt()) > max_neighbours as f64 {
                    EStepKind::Lattice
                } else {
                    EStepKind::Truncated(4.0)
                }
            }
        }
    }
}

/// Mean count of components within `radius` of an evenly spread sample of the observations
/// (counted directly: at most `NEIGHBOUR_SAMPLE x M` distances).
fn mean_neighbours(ty: &[Point3], x: &[Point3], radius: f64) -> f64 {
    let step = x.len().div_ceil(NEIGHBOUR_SAMPLE).max(1);
    let r2 = radius * radius;
    let sample: Vec<&Point3> = x.iter().step_by(step).collect();
    let total: usize = sample.iter().map(|xn| ty.iter().filter(|y| (*xn - *y).norm_squared() <= r2).count()).sum();
    total as f64 / sample.len().max(1) as f64
}

/// The two clouds of one registration and what the truncated E-step builds from them once:
/// a k-d tree over the unmoved source and the observations' spatial order.
struct Mixture<'a> {
    /// The target (observations).
    x: &'a [Point3],
    /// The source (components), unmoved.
    y: &'a [Point3],
    truncated: std::sync::OnceLock<ComponentSearch<'a>>,
}

impl<'a> Mixture<'a> {
    fn new(y: &'a [Point3], x: &'a [Point3]) -> Self {
        Self { x, y, truncated: std::sync::OnceLock::new() }
    }

    /// One E-step of the given kind, the components moved by `motion` to `ty`.
    fn e_step(&self, motion: &Motion, ty: &[Point3], sigma2: f64, c: f64, kind: EStepKind) -> EStep {
        match kind {
            EStepKind::Exact => exact_e_step(ty, self.x, sigma2, c),
            EStepKind::Truncated(r) => {
                let hoods = self.truncated.get_or_init(|| ComponentSearch {
                    y: self.y,
                    tree: KnnIndex::new(self.y),
                    x_order: spatial_order(self.x),
                    lists: std::sync::Mutex::new(None),
                });
                let radius = r * sigma2.sqrt();
                truncated_e_step(hoods, motion, self.x, sigma2, c, radius, mean_neighbours(ty, self.x, radius))
            }
            EStepKind::Lattice => lattice_e_step(ty, self.x, sigma2, c),
        }
    }
}

/// Coordinates divided by `s`, flattened (the lattice's positions).
fn scaled(points: &[Point3], s: f64) -> Vec<f64> {
    points.iter().flat_map(|p| [p.x / s, p.y / s, p.z / s]).collect()
}

/// The E-step's sums on two permutohedral lattices: the components splatted with weight 1 and
/// sliced at the observations give each observation's normaliser `sum_m K(x_n, y_m)`; the
/// observations splatted with `(1, x_n) / (normaliser + c)` and sliced at the components give
/// `P 1` and `P X`. The lattice's blur is the Gaussian up to a constant factor; the factor is
/// measured on a sample of observations against the exact sums (it matters only beside the
/// outlier term `c`).
fn lattice_e_step(ty: &[Point3], x: &[Point3], sigma2: f64, c: f64) -> EStep {
    let s = sigma2.sqrt();
    let (pos_y, pos_x) = (scaled(ty, s), scaled(x, s));
    let mut raw = vec![0.0; x.len()];
    Lattice::new(3, &pos_y, 1, &vec![1.0; ty.len()]).slice(&pos_x, &mut raw);
    let scale = lattice_scale(ty, x, sigma2, &raw);
    let den: Vec<f64> = raw.iter().map(|r| r / scale + c).collect();
    // An observation no component reaches in the first pass has all its posterior on the
    // outlier term: it must not reach the components in the second either (the two lattices
    // hold different vertices, and its weight 1 / c would spread from its own).
    let values: Vec<f64> = x
        .iter()
        .zip(raw.iter().zip(&den))
        .flat_map(|(xn, (r, d))| {
            let w = if *r > 0.0 && *d > 0.0 && d.is_finite() { 1.0 / d } else { 0.0 };
            [w, w * xn.x, w * xn.y, w * xn.z, w * xn.coords.norm_squared()]
        })
        .collect();
    let mut sums = vec![0.0; 5 * ty.len()];
    Lattice::new(3, &pos_x, 5, &values).slice(&pos_y, &mut sums);
    let pt1: Vec<f64> = raw.iter().zip(&den).map(|(r, d)| if *d > 0.0 { (r / scale) / d } else { 0.0 }).collect();
    // Both passes sum the same posteriors, once per observation and once per component; the
    // lattice's error makes the totals differ by a few percent, and the M-step's variance is a
    // difference of sums taken each way: the component sums are rescaled to the observations'.
    let total: f64 = pt1.iter().sum();
    let lattice_total: f64 = sums.chunks_exact(5).map(|v| v[0].max(0.0)).sum();
    let k = if lattice_total > 0.0 { total / lattice_total } else { 0.0 };
    let (p1, px): (Vec<f64>, Vec<Vector3>) =
        sums.chunks_exact(5).map(|v| (k * v[0].max(0.0), k * Vector3::new(v[1], v[2], v[3]))).unzip();
    let sx: Vector3 = px.iter().sum();
    let sxx = k * sums.chunks_exact(5).map(|v| v[4].max(0.0)).sum::<f64>();
    EStep { p1, pt1, px, observed: Some((sx, sxx)) }
}

/// The lattice's response relative to the exact Gaussian sums: `sum raw / sum exact` over an
/// evenly spread sample of observations (1 where the sample sees no mass).
fn lattice_scale(ty: &[Point3], x: &[Point3], sigma2: f64, raw: &[f64]) -> f64 {
    let step = x.len().div_ceil(NEIGHBOUR_SAMPLE).max(1);
    let inv = -0.5 / sigma2;
    let (mut lattice, mut exact) = (0.0, 0.0);
    for n in (0..x.len()).step_by(step) {
        lattice += raw[n];
        exact += ty.iter().map(|y| ((x[n] - y).norm_squared() * inv).exp()).sum::<f64>();
    }
    if exact > 0.0 && lattice > 0.0 { lattice / exact } else { 1.0 }
}

/// The E-step by direct sums over every pair.
fn exact_e_step(ty: &[Point3], x: &[Point3], sigma2: f64, c: f64) -> EStep {
    let inv = -0.5 / sigma2;
    let order: Vec<u32> = (0..x.len() as u32).collect();
    summed_e_step(x, &order, ty.len(), c, Accumulate::Dense, |n, terms| {
        let xn = &x[n];
        terms.extend(ty.iter().enumerate().map(|(k, y)| (k as u32, (xn - y).norm_squared() * inv)));
    })
}

/// How an E-step adds up each observation's posteriors per component.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Accumulate {
    /// Into a full-length array per chunk of observations, the arrays then added in order:
    /// cheaper where an observation reaches more than about `M / E_STEP_CHUNK` components.
    Dense,
    /// As (component, posterior) entries per chunk, then added one by one in order: cheaper
    /// where each observation reaches few components.
    Sparse,
}

/// The E-step's sums from each observation's log-kernel terms (`terms_of(n, terms)` appends
/// observation `n`'s `(component, -d^2 / 2 sigma^2)`), visiting the observations in `order`.
/// Fixed chunks of observations are summed sequentially, a batch of chunks in parallel, and
/// the chunks' sums are then added in chunk order: the same bits whatever the thread count or
/// scheduling (rayon's adaptive fold/reduce would group the additions differently from run to
/// run), with memory bounded by the batch.
fn summed_e_step(
    x: &[Point3],
    order: &[u32],
    m: usize,
    c: f64,
    accumulate: Accumulate,
    terms_of: impl Fn(usize, &mut Vec<(u32, f64)>) + Sync,
) -> EStep {
    let (mut p1, mut px, mut pt1) = (vec![0.0; m], vec![Vector3::zeros(); m], vec![0.0; x.len()]);
    for batch in order.chunks(E_STEP_BATCH) {
        let chunks: Vec<ChunkSums> = batch
            .par_chunks(E_STEP_CHUNK)
            .map(|chunk| {
                let mut sums = ChunkSums::new(accumulate, m, chunk.len());
                let mut terms = Vec::new();
                for &n in chunk {
                    let start = if accumulate == Accumulate::Dense { 0 } else { terms.len() };
                    if accumulate == Accumulate::Dense {
                        terms.clear();
                    }
                    terms_of(n as usize, &mut terms);
                    let row = posteriors(&mut terms[start..], c);
                    sums.observation(n, row, &terms[start..], &x[n as usize]);
                }
                if accumulate == Accumulate::Sparse {
                    sums.entries = terms;
                }
                sums
            })
            .collect();
        for sums in chunks {
            sums.add_to(x, &mut p1, &mut px, &mut pt1);
        }
    }
    EStep { p1, pt1, px, observed: None }
}

/// Observations of one parallel batch of an E-step.
const E_STEP_BATCH: usize = 8 * E_STEP_CHUNK;

/// One chunk of observations' share of the E-step's sums.
struct ChunkSums {
    /// Dense: `P 1` and `P X` per component; empty when sparse.
    p1: Vec<f64>,
    px: Vec<Vector3>,
    /// Sparse: every observation's (component, posterior), in order.
    entries: Vec<(u32, f64)>,
    /// Per observation: its index, `P^T 1`, and (sparse) the end of its entries.
    rows: Vec<(u32, f64, u32)>,
}

impl ChunkSums {
    fn new(accumulate: Accumulate, m: usize, observations: usize) -> Self {
        let dense = accumulate == Accumulate::Dense;
        Self {
            p1: if dense { vec![0.0; m] } else { vec![] },
            px: if dense { vec![Vector3::zeros(); m] } else { vec![] },
            entries: vec![],
            rows: Vec::with_capacity(observations),
        }
    }

    /// Record observation `n`'s posteriors (all of its entries, `P^T 1` = `row`).
    fn observation(&mut self, n: u32, row: f64, posteriors: &[(u32, f64)], xn: &Point3) {
        if self.p1.is_empty() {
            let end = self.rows.last().map_or(0, |r| r.2) + posteriors.len() as u32;
            self.rows.push((n, row, end));
            return;
        }
        for &(k, pk) in posteriors {
            self.p1[k as usize] += pk;
            self.px[k as usize] += pk * xn.coords;
        }
        self.rows.push((n, row, 0));
    }

    /// Add this chunk's sums to the totals.
    fn add_to(self, x: &[Point3], p1: &mut [f64], px: &mut [Vector3], pt1: &mut [f64]) {
        if self.p1.is_empty() {
            let mut start = 0;
            for &(n, row, end) in &self.rows {
                let xn = x[n as usize].coords;
                for &(k, pk) in &self.entries[start..end as usize] {
                    p1[k as usize] += pk;
                    px[k as usize] += pk * xn;
                }
                pt1[n as usize] = row;
                start = end as usize;
            }
            return;
        }
        p1.iter_mut().zip(&self.p1).for_each(|(a, b)| *a += b);
        px.iter_mut().zip(&self.px).for_each(|(a, b)| *a += b);
        for &(n, row, _) in &self.rows {
            pt1[n as usize] = row;
        }
    }
}

/// Turn one observation's log-kernel terms `(component, -d^2 / 2 sigma^2)` into its posteriors
/// in place (log-domain: stable when sigma is far below the point spacing); returns their sum
/// (`P^T 1` of the observation). No terms, or none above the outlier term's reach: all zero.
fn posteriors(terms: &mut [(u32, f64)], c: f64) -> f64 {
    let log_c = if c > 0.0 { c.ln() } else { f64::NEG_INFINITY };
    let top = terms.iter().map(|t| t.1).fold(log_c, f64::max);
    if !top.is_finite() {
        terms.iter_mut().for_each(|t| t.1 = 0.0);
        return 0.0;
    }
    // Clamped at e^-700 (branch-free, so the loops vectorise): subnormal results cost a hundred
    // times more, and a term that small is nothing against the largest.
    // One exponential per term: each term relative to the largest, then divided by their sum
    // (with the outlier term's share), which is at least 1.
    let mut den = (log_c - top).exp();
    for t in terms.iter_mut() {
        t.1 = fastmath::exp((t.1 - top).max(NEGLIGIBLE_LOG));
        den += t.1;
    }
    let inv_den = 1.0 / den;
    let mut row = 0.0;
    for t in terms.iter_mut() {
        t.1 *= inv_den;
        row += t.1;
    }
    row
}

/// The rigid (scaled) motion of the components: `ty_m = s R y_m + t`.
#[derive(Debug, Clone, Copy)]
struct Motion {
    rot: UnitQuaternion<f64>,
    trans: Vector3,
    scale: f64,
}

impl Motion {
    /// An observation taken into the components' unmoved frame: distances there are the moved
    /// ones divided by the scale.
    fn unmove(&self, x: &Point3) -> Point3 {
        Point3::from(self.rot.inverse() * (x.coords - self.trans) / self.scale)
    }
}

/// The truncated E-step's lists answer for this multiple of the truncation radius: every
/// observation whose nearest component lies within half the radius (all but outliers and the
/// unmatched part of a partial view) finds its whole neighbourhood in its list; the others go
/// to the k-d tree.
const LIST_REACH: f64 = std::f64::consts::SQRT_2;

/// Where the truncated E-step finds each observation's components: lists of candidates kept
/// across iterations ([`ComponentLists`]), and the unmoved source in a k-d tree (built once per
/// registration) for the observations the lists cannot answer. Observations are taken into the
/// source's frame ([`Motion::unmove`]) and visited in spatial order.
struct ComponentSearch<'a> {
    y: &'a [Point3],
    tree: KnnIndex,
    x_order: Vec<u32>,
    /// The observations' candidate lists, kept from one truncated E-step to the next.
    lists: std::sync::Mutex<Option<ComponentLists>>,
}

impl ComponentSearch<'_> {
    /// Appends to `terms` the log-kernel terms of observation `q` (in the source's frame) found
    /// by the k-d tree: every component within `sqrt(d_near^2 + radius^2)` (moved units), so
    /// that each kept term is within `exp(-radius^2 / 2 sigma^2)` of the largest even for an
    /// observation far from every component. (The lists answer most observations first.)
    fn terms(&self, q: &Point3, motion: &Motion, (radius, inv): (f64, f64), terms: &mut Vec<(u32, f64)>) {
        let s2 = motion.scale * motion.scale;
        if let Some(near) = self.tree.nearest(q) {
            let reach = (near.dist2 * s2 + radius * radius).sqrt() / motion.scale;
            terms.extend(self.tree.within(q, reach).into_iter().map(|nb| (nb.index as u32, nb.dist2 * s2 * inv)));
        }
    }
}

/// The truncated E-step: each observation sums over the components within its truncation
/// radius (see [`ComponentSearch::terms`]), dense or sparse by the components an observation
/// reaches on average (`neighbours`).
fn truncated_e_step(
    hoods: &ComponentSearch,
    motion: &Motion,
    x: &[Point3],
    sigma2: f64,
    c: f64,
    radius: f64,
    neighbours: f64,
) -> EStep {
    let m = hoods.y.len();
    let (inv, s2) = (-0.5 / sigma2, motion.scale * motion.scale);
    // The radius (unmoved units) within which most observations find every term they need.
    let need = LIST_REACH * radius / motion.scale;
    let unmoved: Vec<Point3> = x.par_iter().map(|p| motion.unmove(p)).collect();
    let mut held = hoods.lists.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    if !held.as_ref().is_some_and(|l| l.serve(&unmoved, need)) {
        *held = ComponentLists::gather(hoods.y, unmoved.clone(), LIST_MARGIN * need);
    }
    let lists = held.as_ref();
    let accumulate = if neighbours * E_STEP_CHUNK as f64 > m as f64 { Accumulate::Dense } else { Accumulate::Sparse };
    summed_e_step(x, &hoods.x_order, m, c, accumulate, |n, terms| {
        let q = &unmoved[n];
        if !lists.is_some_and(|l| l.terms(n, q, hoods.y, s2, radius, inv, terms)) {
            hoods.terms(q, motion, (radius, inv), terms);
        }
    })
}

/// The subset sizes of the settling levels (see [`CpdConfig::settling_points`]), smallest
/// first: a quarter of `points` (the larger cloud's size; half the point spacing on a surface
/// from one level to the next), a sixteenth, ... down to no fewer than `smallest`; none when
/// `smallest` is 0 or the clouds have fewer than twice as many points.
fn settling_levels(smallest: usize, points: usize) -> Vec<usize> {
    if smallest == 0 || points < 2 * smallest {
        return vec![];
    }
    let mut levels: Vec<usize> =
        std::iter::successors(Some(points / 4), |&s| Some(s / 4)).take_while(|&s| s >= smallest).collect();
    if levels.is_empty() {
        levels.push(smallest);
    }
    levels.reverse();
    levels
}

/// One M-step's estimate.
struct MStep {
    rot: UnitQuaternion<f64>,
    trans: Vector3,
    sigma2: f64,
}

/// The M-step: the weighted Procrustes fit of the components to the posterior means (with the
/// scale, when estimated, written to `scale`) and sigma^2 in closed form.
fn m_step(cfg: &CpdConfig, y: &[Point3], x: &[Point3], e: &EStep, np: f64, scale: &mut f64) -> MStep {
    let (sx, sxx) = e.observed.unwrap_or_else(|| {
        x.iter()
            .zip(&e.pt1)
            .fold((Vector3::zeros(), 0.0), |(a, b), (p, w)| (a + *w * p.coords, b + w * p.coords.norm_squared()))
    });
    let mu_x = sx / np;
    let mu_y = y.iter().zip(&e.p1).fold(Vector3::zeros(), |a, (p, w)| a + *w * p.coords) / np;
    let a = y.iter().zip(&e.px).fold(Matrix3::zeros(), |acc, (q, pxm)| acc + pxm * q.coords.transpose())
        - np * mu_x * mu_y.transpose();
    let r = nearest_rotation(&a);
    let tr_ar = (a.transpose() * r.matrix()).trace();
    if cfg.estimate_scale {
        let yy = y.iter().zip(&e.p1).map(|(q, w)| w * q.coords.norm_squared()).sum::<f64>() - np * mu_y.norm_squared();
        *scale = tr_ar / yy;
    }
    let rot = UnitQuaternion::from_rotation_matrix(&r);
    let trans = mu_x - *scale * (rot * mu_y);
    let xx = sxx - np * mu_x.norm_squared();
    let sigma2 = ((xx - *scale * tr_ar) / (np * 3.0)).max(SIGMA2_FLOOR);
    MStep { rot, trans, sigma2 }
}

/// A cloud's centroid and RMS distance from it (at least 1 mm: the mixing's length unit).
fn centre_and_radius(points: &[Point3]) -> (Point3, f64) {
    let n = points.len().max(1) as f64;
    let centre = Point3::from(points.iter().map(|p| p.coords).sum::<Vector3>() / n);
    let radius = (points.iter().map(|p| (p - centre).norm_squared()).sum::<f64>() / n).sqrt();
    (centre, radius.max(1e-3))
}

impl Registrar for Cpd {
    fn name(&self) -> &str {
        "cpd"
    }

    fn register(&self, p: &RegistrationProblem) -> Result<Registration, RegistrationError> {
        in_pool(|| {
            validate_problem(p, None)?;
            let limit = self.config.max_points;
            let (source, target) = (&p.source, &p.target);
            if limit == 0 || (source.len() <= limit && target.len() <= limit) {
                return self.solve(p);
            }
            let mut warnings = vec![];
            let mut limited = |cloud: &PointCloud, which: &'static str| {
                if cloud.len() <= limit {
                    return PointCloud::from_points(cloud.points.clone());
                }
                let subset = even_subset(&cloud.points, limit);
                warnings.push(RegistrationWarning::Subsampled {
                    which,
                    points: cloud.len(),
                    kept: subset.len(),
                    limit,
                });
                PointCloud::from_points(subset)
            };
            let small =
                RegistrationProblem::new(limited(source, "source"), limited(target, "target")).with_init(p.init);
            let mut r = self.solve(&small)?;
            r.warnings.splice(0..0, warnings);
            Ok(r)
        })
    }
}

/// At most `limit` points spread evenly over the cloud: every k-th point in spatial order.
fn even_subset(points: &[Point3], limit: usize) -> Vec<Point3> {
    let step = points.len().div_ceil(limit.max(1));
    spatial_order(points).iter().step_by(step).map(|&i| points[i as usize]).collect()
}

/// The EM iteration's state, carried from the settling subset to the full clouds.
struct Iterate {
    /// The current iterate (mixed or plain).
    rot: UnitQuaternion<f64>,
    trans: Vector3,
    scale: f64,
    sigma2: f64,
    /// The last plain EM step's pose: the result.
    result: Pose,
    iterations: usize,
    history: Vec<IterationRecord>,
    mixing: Option<PoseMixing>,
    mixing_started: bool,
}

/// How one phase of the iteration ended.
#[derive(Debug, Clone, Copy, PartialEq)]
enum PhaseEnd {
    /// Sigma^2 settled and the pose stopped moving.
    Converged,
    /// A settling level's iteration settled (see [`SUBSET_SETTLED_SIGMA2`]).
    Settled,
    /// The iteration limit.
    Exhausted,
    /// No observation explained.
    NothingExplained,
}

/// A settling level's iterations have settled once a step changes sigma^2 by less than this
/// fraction ...
const SUBSET_SETTLED_SIGMA2: f64 = 0.01;

/// ... and moves the source by less than this fraction of sigma (the translation plus the
/// rotation's sweep at the cloud's RMS radius): the next level starts near its own optimum,
/// and its iterations, not the subset's, decide the pose.
const SUBSET_SETTLED_MOVE: f64 = 0.1;

impl Iterate {
    fn pose(&self) -> Pose {
        Pose::from_parts(Translation3::from(self.trans), self.rot)
    }

    /// EM iterations of the components `y` against the observations `x` until convergence,
    /// the iteration limit or, with `settle = Some(radius)` (the cloud's RMS radius), until the
    /// subset's iteration settles.
    fn run(&mut self, cfg: &CpdConfig, y: &[Point3], x: &[Point3], settle: Option<f64>) -> PhaseEnd {
        let (m, n) = (y.len(), x.len());
        let mixture = Mixture::new(y, x);
        let moved = |it: &Self| -> Vec<Point3> {
            y.iter().map(|q| Point3::from(it.scale * (it.rot * q.coords) + it.trans)).collect()
        };
        let mut ty = moved(self);
        while self.iterations < cfg.max_iterations {
            // The paper's outlier term, in the data's own (metric) units, as the reference
            // implementations evaluate it.
            let c = outlier_term(self.sigma2, cfg.w, m, n);
            let motion = Motion { rot: self.rot, trans: self.trans, scale: self.scale };
            let e = mixture.e_step(&motion, &ty, self.sigma2, c, cfg.e_step.kind(&ty, x, self.sigma2));
            let np: f64 = e.p1.iter().sum();
            if np < 1e-9 {
                return PhaseEnd::NothingExplained;
            }
            let step = m_step(cfg, y, x, &e, np, &mut self.scale);
            let plain = Pose::from_parts(Translation3::from(step.trans), step.rot);
            let d = plain * self.pose().inverse();
            let (angle, shift) = (d.rotation.angle(), d.translation.vector.norm());
            self.history.push(IterationRecord { iteration: self.iterations, transform: plain, objective: step.sigma2 });
            self.iterations += 1;
            self.result = plain;
            let change = (self.sigma2 - step.sigma2).abs() / self.sigma2;
            // Converged when sigma^2 has settled and the pose no longer moves.
            if settle.is_none() && change < cfg.tolerance && angle + shift < cfg.pose_tolerance {
                self.sigma2 = step.sigma2;
                return PhaseEnd::Converged;
            }
            if let Some(radius) = settle {
                let sigma = self.sigma2.sqrt();
                if change < SUBSET_SETTLED_SIGMA2 && angle * radius + shift < SUBSET_SETTLED_MOVE * sigma {
                    (self.rot, self.trans, self.sigma2) = (step.rot, step.trans, step.sigma2);
                    return PhaseEnd::Settled;
                }
            }
            self.mixing_started |= change <= MIXING_SIGMA_CHANGE;
            let (now, started) = (self.pose(), self.mixing_started);
            let next = match self.mixing.as_mut().filter(|_| started) {
                Some(mixing) => mixing.step(now, self.sigma2, plain, step.sigma2, SIGMA2_FLOOR),
                None => (plain, step.sigma2),
            };
            (self.rot, self.trans, self.sigma2) = (next.0.rotation, next.0.translation.vector, next.1);
            ty = moved(self);
        }
        PhaseEnd::Exhausted
    }
}

impl Cpd {
    /// [`Registrar::register`]'s body, run on a pool thread.
    fn solve(&self, p: &RegistrationProblem) -> Result<Registration, RegistrationError> {
        validate_problem(p, None)?;
        let cfg = &self.config;
        let (y, x) = (&p.source.points, &p.target.points);
        let (centre, radius) = centre_and_radius(y);
        let mut it = Iterate {
            rot: p.init.rotation,
            trans: p.init.translation.vector,
            scale: 1.0,
            sigma2: 0.0,
            result: p.init,
            iterations: 0,
            history: vec![],
            mixing: (cfg.anderson_depth > 0 && !cfg.estimate_scale)
                .then(|| PoseMixing::new(cfg.anderson_depth, p.init, centre, radius, true)),
            mixing_started: false,
        };
        // Each settled level hands its iterate to the next, with a fresh mixing history; the
        // last level is every point.
        let levels = settling_levels(cfg.settling_points, y.len().max(x.len()));
        let mut end = PhaseEnd::Settled;
        for level in levels.into_iter().map(Some).chain([None]) {
            if end != PhaseEnd::Settled {
                break;
            }
            let subsets = level.map(|size| (even_subset(y, size), even_subset(x, size)));
            let (ys, xs) = subsets.as_ref().map_or((y.as_slice(), x.as_slice()), |(a, b)| (a.as_slice(), b.as_slice()));
            if it.iterations == 0 {
                let moved: Vec<Point3> = ys.iter().map(|q| p.init * q).collect();
                it.sigma2 = cfg.init_sigma2.unwrap_or_else(|| mean_pair_distance2(&moved, xs) / 3.0);
            } else if let Some(mixing) = it.mixing.as_mut() {
                mixing.restart();
                it.mixing_started = false;
            }
            end = it.run(cfg, ys, xs, level.map(|_| radius));
        }
        let warnings =
            if end == PhaseEnd::NothingExplained { vec![RegistrationWarning::NothingExplained] } else { vec![] };
        let transform = it.result;
        let (fitness, inlier_rmse) = evaluate(y, &KnnIndex::new(x), &transform, cfg.evaluation_distance);
        Ok(Registration {
            transform,
            iterations: it.iterations,
            converged: end == PhaseEnd::Converged,
            fitness,
            inlier_rmse,
            sigma2: Some(it.sigma2),
            scale: cfg.estimate_scale.then_some(it.scale),
            history: it.history,
            warnings,
            correspondence_set: None,
            uncertainty: None,
            overruled_flow: None,
        })
    }
}
