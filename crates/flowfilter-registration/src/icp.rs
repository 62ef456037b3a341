//! Iterative closest point: point-to-point (Besl & McKay 1992) and point-to-plane
//! (Chen & Medioni 1992), with robust kernels and Open3D's convergence criteria.

use crate::error::RegistrationError;
use crate::evaluate::{RobustKernel, point_to_plane_step_by};
use crate::problem::{IterationRecord, Registrar, Registration, RegistrationProblem, in_pool, validate_problem};
use flowfilter_geometry::{KnnIndex, Point3, spatial_order, weighted_kabsch};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Which ICP error.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum IcpVariant {
    /// Point-to-point (closed-form weighted Kabsch per iteration).
    PointToPoint,
    /// Point-to-plane (one Gauss-Newton step on a twist per iteration; needs target normals).
    PointToPlane,
}

/// ICP parameters (defaults as Open3D's `ICPConvergenceCriteria`, distances for tabletop objects).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IcpConfig {
    /// Point-to-point or point-to-plane.
    pub variant: IcpVariant,
    /// Pairs farther apart than this are not correspondences, metres.
    pub max_correspondence_distance: f64,
    /// Iteration limit.
    pub max_iterations: usize,
    /// Stop when fitness changes by less than this.
    pub relative_fitness: f64,
    /// Stop when the inlier RMSE changes by less than this.
    pub relative_rmse: f64,
    /// IRLS kernel on residuals.
    pub kernel: RobustKernel,
    /// Also require the last update's rotation (rad) and translation (m) to be below this
    /// before stopping: on smooth or planar parts the pose can keep sliding while fitness and
    /// RMSE no longer change (more iterations, a better pose). 0 stops on Open3D's two criteria
    /// alone (its iterations and result).
    pub min_update: f64,
}

impl Default for IcpConfig {
    fn default() -> Self {
        Self {
            variant: IcpVariant::PointToPoint,
            max_correspondence_distance: 0.02,
            max_iterations: 50,
            relative_fitness: 1e-6,
            relative_rmse: 1e-6,
            kernel: RobustKernel::None,
            min_update: 1e-7,
        }
    }
}

/// ICP as a [`Registrar`].
#[derive(Debug, Clone)]
pub struct Icp {
    /// Parameters.
    pub config: IcpConfig,
}

impl Icp {
    /// ICP with the given parameters.
    pub fn new(config: IcpConfig) -> Result<Self, RegistrationError> {
        if config.max_correspondence_distance.is_nan()
            || config.max_correspondence_distance <= 0.0
            || config.max_iterations == 0
        {
            return Err(RegistrationError::Config(
                "icp needs max_correspondence_distance > 0 and max_iterations > 0".into(),
            ));
        }
        Ok(Self { config })
    }
}

impl Registrar for Icp {
    fn name(&self) -> &str {
        match self.config.variant {
            IcpVariant::PointToPoint => "icp-pt2pt",
            IcpVariant::PointToPlane => "icp-pt2pl",
        }
    }

    fn register(&self, p: &RegistrationProblem) -> Result<Registration, RegistrationError> {
        in_pool(|| self.solve(p))
    }
}

impl Icp {
    /// [`Registrar::register`]'s body, run on a pool thread.
    fn solve(&self, p: &RegistrationProblem) -> Result<Registration, RegistrationError> {
        let cfg = &self.config;
        let pt2pl = cfg.variant == IcpVariant::PointToPlane;
        validate_problem(p, pt2pl.then_some("icp-pt2pl"))?;
        let target = KnnIndex::new(&p.target.points);
        let normals = p.target.normals.as_deref().unwrap_or(&[]);
        let max_d2 = cfg.max_correspondence_distance.powi(2);
        let mut t = p.init;
        // Source points in a spatially coherent order: consecutive queries share tree branches.
        let source: Vec<Point3> =
            spatial_order(&p.source.points).iter().map(|&i| p.source.points[i as usize]).collect();
        // Correspondences of the current estimate: (moved source, target index, distance). The
        // search is bounded by the correspondence gate and by the distance to the point's last
        // partner (the nearest point is at most that far): the same answer, with less of the
        // tree visited.
        let mut partner = vec![u32::MAX; source.len()];
        let mut correspond = |t: &flowfilter_geometry::Pose| -> Vec<(Point3, usize, f64)> {
            source
                .par_iter()
                .zip(partner.par_iter_mut())
                .filter_map(|(s, last)| {
                    let x = t * s;
                    let n = match *last {
                        u32::MAX => target.nearest(&x).filter(|n| n.dist2 <= max_d2),
                        j => target.nearest_within(&x, (x - p.target.points[j as usize]).norm_squared().min(max_d2)),
                    };
                    *last = n.map_or(u32::MAX, |n| n.index as u32);
                    n.map(|n| (x, n.index, n.dist2.sqrt()))
                })
                .collect()
        };
        let stats = |c: &[(Point3, usize, f64)]| {
            if c.is_empty() {
                (0.0, 0.0)
            } else {
                (
                    c.len() as f64 / p.source.len() as f64,
                    (c.iter().map(|x| x.2 * x.2).sum::<f64>() / c.len() as f64).sqrt(),
                )
            }
        };
        let mut corr = correspond(&t);
        let (mut fitness, mut rmse) = stats(&corr);
        let mut history = vec![];
        let mut warnings = vec![];
        let mut converged = false;
        let mut iterations = 0;
        for it in 0..cfg.max_iterations {
            if corr.len() < 3 {
                warnings.push(format!(
                    "only {} correspondences within {} m: ICP cannot continue",
                    corr.len(),
                    cfg.max_correspondence_distance
                ));
                break;
            }
            let delta = if pt2pl {
                point_to_plane_step_by(corr.len(), |i| {
                    let (x, j, d) = corr[i];
                    (x, p.target.points[j], normals[j], cfg.kernel.weight(d))
                })
            } else {
                let x: Vec<Point3> = corr.iter().map(|c| c.0).collect();
                let y: Vec<Point3> = corr.iter().map(|c| p.target.points[c.1]).collect();
                let w: Vec<f64> = corr.iter().map(|c| cfg.kernel.weight(c.2)).collect();
                weighted_kabsch(&x, &y, Some(&w)).ok()
            };
            let Some(delta) = delta else {
                warnings.push("the update is not determined (degenerate correspondences)".into());
                break;
            };
            t = delta * t;
            iterations = it + 1;
            corr = correspond(&t);
            let (f, r) = stats(&corr);
            history.push(IterationRecord { iteration: it, transform: t, objective: r });
            // Open3D's criteria, plus a vanishing update: on planar parts the pose can keep
            // sliding while fitness and RMSE no longer change.
            let still = cfg.min_update <= 0.0
                || (delta.rotation.angle() < cfg.min_update && delta.translation.vector.norm() < cfg.min_update);
            let done = (f - fitness).abs() < cfg.relative_fitness && (r - rmse).abs() < cfg.relative_rmse && still;
            fitness = f;
            rmse = r;
            if done {
                converged = true;
                break;
            }
        }
        if fitness == 0.0 {
            converged = false;
        }
        Ok(Registration {
            transform: t,
            iterations,
            converged,
            fitness,
            inlier_rmse: rmse,
            sigma2: None,
            scale: None,
            history,
            warnings,
        })
    }
}
