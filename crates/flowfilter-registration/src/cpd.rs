//! Rigid Coherent Point Drift (Myronenko & Song, "Point Set Registration: Coherent Point
//! Drift", PAMI 2010): the source is a Gaussian mixture whose centroids move rigidly (with
//! optional scale) to explain the target; sigma^2 is updated in closed form.

use crate::error::RegistrationError;
use crate::evaluate::evaluate;
use crate::gmm::{mean_pair_distance2, outlier_term};
use crate::lattice::Lattice;
use crate::problem::{IterationRecord, Registrar, Registration, RegistrationProblem, in_pool, validate_problem};
use crate::warning::RegistrationWarning;
use flowfilter_geometry::{KnnIndex, Point3, PointCloud, Pose, Vector3, nearest_rotation, spatial_order};
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
    /// Stop when sigma^2 changes by less than this fraction.
    pub tolerance: f64,
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
}

impl Default for CpdConfig {
    fn default() -> Self {
        Self {
            w: 0.0,
            max_iterations: 150,
            tolerance: 1e-5,
            estimate_scale: false,
            e_step: CpdEStep::Auto { max_pairs: 4_000_000 },
            init_sigma2: None,
            evaluation_distance: 0.01,
            max_points: DEFAULT_MAX_POINTS,
        }
    }
}

/// [`CpdConfig::max_points`]'s default: above every cloud of the benchmarks (at most about 6k
/// points after their voxel grid), at about 0.5 s per iteration on 2 cores.
pub const DEFAULT_MAX_POINTS: usize = 10_000;

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

/// One E-step of the given kind.
fn e_step(ty: &[Point3], x: &[Point3], sigma2: f64, c: f64, kind: EStepKind) -> EStep {
    match kind {
        EStepKind::Exact => summed_e_step(ty, x, sigma2, c, None),
        EStepKind::Truncated(r) => summed_e_step(ty, x, sigma2, c, Some(r * sigma2.sqrt())),
        EStepKind::Lattice => lattice_e_step(ty, x, sigma2, c),
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

/// The E-step by direct sums over every pair, or over the components within `radius` (k-d tree).
fn summed_e_step(ty: &[Point3], x: &[Point3], sigma2: f64, c: f64, radius: Option<f64>) -> EStep {
    let m = ty.len();
    let index = radius.map(|_| KnnIndex::new(ty));
    let inv = -0.5 / sigma2;
    // Fixed chunks of observations, each summed sequentially, the partial sums then added in
    // chunk order: the same bits whatever the thread count or scheduling (rayon's adaptive
    // fold/reduce would group the additions differently from run to run).
    let partials: Vec<(Vec<f64>, Vec<Vector3>, Vec<f64>)> = x
        .par_chunks(E_STEP_CHUNK)
        .map(|chunk| {
            let (mut p1, mut px, mut pt1) = (vec![0.0; m], vec![Vector3::zeros(); m], Vec::with_capacity(chunk.len()));
            for xn in chunk {
                // Log-domain posteriors: stable when sigma is far below the point spacing.
                let terms: Vec<(usize, f64)> = match (&index, radius) {
                    // Relative to the largest term: keep every component whose term is within
                    // exp(-r^2 / 2 sigma^2) of it, so the posterior's normalisation is kept even
                    // for observations far from every component.
                    (Some(idx), Some(r)) => {
                        let near = idx.nearest(xn).map_or(0.0, |nb| nb.dist2);
                        idx.within(xn, (near + r * r).sqrt()).into_iter().map(|nb| (nb.index, nb.dist2 * inv)).collect()
                    }
                    _ => ty.iter().enumerate().map(|(k, y)| (k, (xn - y).norm_squared() * inv)).collect(),
                };
                let log_c = if c > 0.0 { c.ln() } else { f64::NEG_INFINITY };
                let top = terms.iter().map(|t| t.1).fold(log_c, f64::max);
                let mut row = 0.0;
                if top.is_finite() {
                    let log_den =
                        top + (terms.iter().map(|t| (t.1 - top).exp()).sum::<f64>() + (log_c - top).exp()).ln();
                    for (k, e) in terms {
                        let pk = (e - log_den).exp();
                        p1[k] += pk;
                        px[k] += pk * xn.coords;
                        row += pk;
                    }
                }
                pt1.push(row);
            }
            (p1, px, pt1)
        })
        .collect();
    let mut partials = partials.into_iter();
    let (mut p1, mut px, mut pt1) =
        partials.next().unwrap_or_else(|| (vec![0.0; m], vec![Vector3::zeros(); m], vec![]));
    for (b1, bx, bt) in partials {
        p1.iter_mut().zip(&b1).for_each(|(a, b)| *a += b);
        px.iter_mut().zip(&bx).for_each(|(a, b)| *a += b);
        pt1.extend(bt);
    }
    EStep { p1, pt1, px, observed: None }
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

impl Cpd {
    /// [`Registrar::register`]'s body, run on a pool thread.
    fn solve(&self, p: &RegistrationProblem) -> Result<Registration, RegistrationError> {
        validate_problem(p, None)?;
        let cfg = &self.config;
        let y = &p.source.points;
        let x = &p.target.points;
        let (m, n) = (y.len(), x.len());
        let mut rot = p.init.rotation;
        let mut trans = p.init.translation.vector;
        let mut scale = 1.0;
        let moved = |rot: &UnitQuaternion<f64>, t: &Vector3, s: f64| -> Vec<Point3> {
            y.iter().map(|q| Point3::from(s * (rot * q.coords) + t)).collect()
        };
        let mut ty = moved(&rot, &trans, scale);
        let mut sigma2 = cfg.init_sigma2.unwrap_or_else(|| mean_pair_distance2(&ty, x) / 3.0);
        let (mut history, mut converged, mut iterations, mut warnings) = (vec![], false, 0, vec![]);
        for it in 0..cfg.max_iterations {
            // The paper's outlier term, in the data's own (metric) units, as the reference
            // implementations evaluate it.
            let c = outlier_term(sigma2, cfg.w, m, n);
            let e = e_step(&ty, x, sigma2, c, cfg.e_step.kind(&ty, x, sigma2));
            let np: f64 = e.p1.iter().sum();
            if np < 1e-9 {
                warnings.push(RegistrationWarning::NothingExplained);
                break;
            }
            let (sx, sxx) = e.observed.unwrap_or_else(|| {
                x.iter().zip(&e.pt1).fold((Vector3::zeros(), 0.0), |(a, b), (p, w)| {
                    (a + *w * p.coords, b + w * p.coords.norm_squared())
                })
            });
            let mu_x = sx / np;
            let mu_y = y.iter().zip(&e.p1).fold(Vector3::zeros(), |a, (p, w)| a + *w * p.coords) / np;
            let a = y.iter().zip(&e.px).fold(Matrix3::zeros(), |acc, (q, pxm)| acc + pxm * q.coords.transpose())
                - np * mu_x * mu_y.transpose();
            let r = nearest_rotation(&a);
            let tr_ar = (a.transpose() * r.matrix()).trace();
            if cfg.estimate_scale {
                let yy = y.iter().zip(&e.p1).map(|(q, w)| w * q.coords.norm_squared()).sum::<f64>()
                    - np * mu_y.norm_squared();
                scale = tr_ar / yy;
            }
            rot = UnitQuaternion::from_rotation_matrix(&r);
            trans = mu_x - scale * (rot * mu_y);
            let xx = sxx - np * mu_x.norm_squared();
            let new_sigma2 = ((xx - scale * tr_ar) / (np * 3.0)).max(SIGMA2_FLOOR);
            ty = moved(&rot, &trans, scale);
            let step = history.last().map_or(f64::INFINITY, |h: &IterationRecord| {
                let now = Pose::from_parts(Translation3::from(trans), rot);
                let d = now * h.transform.inverse();
                d.rotation.angle() + d.translation.vector.norm()
            });
            iterations = it + 1;
            history.push(IterationRecord {
                iteration: it,
                transform: Pose::from_parts(Translation3::from(trans), rot),
                objective: new_sigma2,
            });
            let change = (sigma2 - new_sigma2).abs() / sigma2;
            sigma2 = new_sigma2;
            // Converged when sigma^2 has settled and the pose no longer moves.
            if change < cfg.tolerance && step < 1e-9 {
                converged = true;
                break;
            }
        }
        let transform = Pose::from_parts(Translation3::from(trans), rot);
        let (fitness, inlier_rmse) = evaluate(y, &KnnIndex::new(x), &transform, cfg.evaluation_distance);
        Ok(Registration {
            transform,
            iterations,
            converged,
            fitness,
            inlier_rmse,
            sigma2: Some(sigma2),
            scale: cfg.estimate_scale.then_some(scale),
            history,
            warnings,
            correspondence_set: None,
            uncertainty: None,
        })
    }
}
