//! Rigid Coherent Point Drift (Myronenko & Song, "Point Set Registration: Coherent Point
//! Drift", PAMI 2010): the source is a Gaussian mixture whose centroids move rigidly (with
//! optional scale) to explain the target; sigma^2 is updated in closed form.

use crate::error::RegistrationError;
use crate::evaluate::evaluate;
use crate::gmm::{mean_pair_distance2, outlier_term};
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
}

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
}

fn e_step(ty: &[Point3], x: &[Point3], sigma2: f64, c: f64, radius: Option<f64>) -> EStep {
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
    EStep { p1, pt1, px }
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
        let radius_sigmas = match cfg.e_step {
            CpdEStep::Exact => None,
            CpdEStep::Truncated { radius_sigmas } => Some(radius_sigmas),
            CpdEStep::Auto { max_pairs } => (m * n > max_pairs).then_some(4.0),
        };
        let (mut history, mut converged, mut iterations, mut warnings) = (vec![], false, 0, vec![]);
        for it in 0..cfg.max_iterations {
            // The paper's outlier term, in the data's own (metric) units, as the reference
            // implementations evaluate it.
            let c = outlier_term(sigma2, cfg.w, m, n);
            let e = e_step(&ty, x, sigma2, c, radius_sigmas.map(|r| r * sigma2.sqrt()));
            let np: f64 = e.p1.iter().sum();
            if np < 1e-9 {
                warnings.push(RegistrationWarning::NothingExplained);
                break;
            }
            let mu_x = x.iter().zip(&e.pt1).fold(Vector3::zeros(), |a, (p, w)| a + *w * p.coords) / np;
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
            let xx =
                x.iter().zip(&e.pt1).map(|(q, w)| w * q.coords.norm_squared()).sum::<f64>() - np * mu_x.norm_squared();
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
