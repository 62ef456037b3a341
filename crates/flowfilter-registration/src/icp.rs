//! Iterative closest point: point-to-point (Besl & McKay 1992) and point-to-plane
//! (Chen & Medioni 1992), with robust kernels and Open3D's convergence criteria.

use crate::error::RegistrationError;
use crate::evaluate::{RobustKernel, point_to_plane_step_by};
use crate::problem::{IterationRecord, Registrar, Registration, RegistrationProblem, in_pool, validate_problem};
use crate::warning::RegistrationWarning;
use flowfilter_geometry::{
    KnnIndex, Neighbour, Neighbourhoods, Point3, Pose, RadiusGrid, spatial_order, weighted_kabsch_by,
};
use flowfilter_geometry::{ParamError, params};
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
    ///
    /// # Errors
    /// [`RegistrationError::Param`] for a value out of range ([`IcpConfig::validate`]).
    pub fn new(config: IcpConfig) -> Result<Self, RegistrationError> {
        config.validate().map_err(|e| e.within("icp"))?;
        Ok(Self { config })
    }
}

impl IcpConfig {
    /// Check every value: finite and in range.
    ///
    /// # Errors
    /// The first key at fault (keys relative to the `[icp]` table).
    pub fn validate(&self) -> Result<(), ParamError> {
        params::positive("max_correspondence_distance", self.max_correspondence_distance)?;
        params::count_positive("max_iterations", self.max_iterations)?;
        params::non_negative("relative_fitness", self.relative_fitness)?;
        params::non_negative("relative_rmse", self.relative_rmse)?;
        params::non_negative("min_update", self.min_update)?;
        match self.kernel {
            RobustKernel::None => Ok(()),
            RobustKernel::Huber { k } | RobustKernel::Tukey { k } => params::positive("kernel.k", k),
        }
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
        let mut matcher = Matcher::new(&p.target.points, cfg.max_correspondence_distance);
        let normals = p.target.normals.as_deref().unwrap_or(&[]);
        let mut t = p.init;
        // Source points in a spatially coherent order: consecutive queries share tree branches.
        let source: Vec<Point3> =
            spatial_order(&p.source.points).iter().map(|&i| p.source.points[i as usize]).collect();
        let mut tracks = vec![Track::UNKNOWN; source.len()];
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
        let mut corr = matcher.pairs(&source, &mut tracks, &t, None);
        let (mut fitness, mut rmse) = stats(&corr);
        let mut history = vec![];
        let mut warnings = vec![];
        let mut converged = false;
        let mut iterations = 0;
        for it in 0..cfg.max_iterations {
            if corr.len() < 3 {
                warnings.push(RegistrationWarning::TooFewPairs {
                    found: corr.len(),
                    max_distance_m: cfg.max_correspondence_distance,
                });
                break;
            }
            let delta = if pt2pl {
                point_to_plane_step_by(corr.len(), |i| {
                    let (x, j, d) = corr[i];
                    (x, p.target.points[j], normals[j], cfg.kernel.weight(d))
                })
            } else {
                weighted_kabsch_by(corr.len(), |i| {
                    let (x, j, d) = corr[i];
                    (x, p.target.points[j], cfg.kernel.weight(d))
                })
                .ok()
            };
            let Some(delta) = delta else {
                warnings.push(RegistrationWarning::DegenerateUpdate);
                break;
            };
            let searched_at = t;
            t = delta * t;
            iterations = it + 1;
            matcher.prepare(&corr);
            corr = matcher.pairs(&source, &mut tracks, &t, Some(&searched_at));
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
            correspondence_set: None,
            uncertainty: None,
            overruled_flow: None,
        })
    }
}

/// What the last pass learnt of a source point's nearest target point.
#[derive(Debug, Clone, Copy)]
struct Track {
    /// Its partner within the gate (`u32::MAX`: none).
    partner: u32,
    /// Without one: a lower bound on its distance to the nearest target point, beyond the gate
    /// (0: unknown).
    far: f64,
}

impl Track {
    /// Nothing known yet.
    const UNKNOWN: Self = Self { partner: u32::MAX, far: 0.0 };
}

/// Source points searched in turn, each from the answer of the one before (see
/// [`Matcher::pairs`]); runs are searched in parallel.
const SEEDED_RUN: usize = 256;

/// Relative margin a skipped point's distance bound keeps beyond the gate (rounding of the
/// bound's arithmetic).
const FAR_MARGIN: f64 = 1e-9;

/// Target points sampled to estimate the cloud's spacing.
const SPACING_SAMPLES: usize = 64;

/// The neighbourhoods' radius, in multiples of the 90th percentile of the current pair
/// distances: once the pose settles, a point moves little between passes and the distance to
/// its last partner is about its pair distance, so twice that (the certificate's need) plus a
/// margin answers nine searches in ten from the lists.
const LIST_RADIUS_PER_PAIR_DISTANCE: f64 = 2.2;

/// The largest neighbourhood radius built, in target spacings: wider lists cost more to build
/// and scan than the k-d tree searches they replace.
const MAX_LIST_RADIUS_IN_SPACINGS: f64 = 4.0;

/// Cell edge of the grid that answers searches from a partner up to a few cells away, in
/// target spacings.
const GRID_CELL_IN_SPACINGS: f64 = 4.0;

/// ICP's correspondence search: each moved source point's nearest target point within the
/// gate. A k-d tree answers from scratch. A point whose last partner lies within a few grid
/// cells is answered from the grid cells around it instead (the nearest point is no farther
/// than the partner: [`RadiusGrid::nearest_within`]); once the pairs are close (in target
/// spacings) the target's neighbourhoods are built and most searches are answered from the list
/// of the point's last partner (exact: see [`Neighbourhoods::nearest_from`]). Every path gives
/// the tree's answer.
struct Matcher<'a> {
    target: &'a [Point3],
    index: KnnIndex,
    /// Median distance between neighbouring target points.
    spacing: f64,
    lists: Option<Neighbourhoods>,
    /// The target in cells of [`GRID_CELL_IN_SPACINGS`] spacings, for searches from a partner
    /// a few spacings away (before the lists exist, or beyond their reach).
    grid: Option<RadiusGrid>,
    max_d2: f64,
}

impl<'a> Matcher<'a> {
    fn new(target: &'a [Point3], max_correspondence_distance: f64) -> Self {
        let index = KnnIndex::new(target);
        let spacing = index.median_neighbour_distance(target, 2, SPACING_SAMPLES).unwrap_or(0.0);
        let grid = RadiusGrid::new(target, GRID_CELL_IN_SPACINGS * spacing);
        Self { target, index, spacing, lists: None, grid, max_d2: max_correspondence_distance.powi(2) }
    }

    /// The pairs of `t * source` (moved source point, target index, distance), in source order,
    /// for the points with a target point within the gate; `tracks` holds what the last pass
    /// (at pose `searched_at`) learnt of each point and is updated. A point without a partner
    /// (every point of the first pass) is searched from the nearest target point of the point
    /// before it: the source is in spatial order, so that point is about as near as its own
    /// nearest, and the grid cells within that distance hold the answer (the k-d tree answers
    /// the first point of each run of [`SEEDED_RUN`] and where the cells would be too many).
    /// A point whose nearest target point lay beyond the gate by more than it has moved since is
    /// not searched: it still has none within the gate (a whole frame's edges and background,
    /// searched from scratch on every pass otherwise). The pairs are those of a search of every
    /// point.
    fn pairs(
        &self,
        source: &[Point3],
        tracks: &mut [Track],
        t: &Pose,
        searched_at: Option<&Pose>,
    ) -> Vec<(Point3, usize, f64)> {
        let gate = self.max_d2.sqrt();
        source
            .par_chunks(SEEDED_RUN)
            .zip(tracks.par_chunks_mut(SEEDED_RUN))
            .flat_map_iter(|(source, tracks)| {
                let mut seed = u32::MAX;
                source.iter().zip(tracks).filter_map(move |(s, last)| {
                    let x = t * s;
                    if let Some(before) = searched_at.filter(|_| last.far > 0.0) {
                        let bound = last.far - (x - before * s).norm();
                        if bound > gate * (1.0 + FAR_MARGIN) {
                            last.far = bound;
                            return None;
                        }
                    }
                    let n = self.nearest(&x, if last.partner == u32::MAX { seed } else { last.partner });
                    seed = n.map_or(u32::MAX, |n| n.index as u32);
                    *last = match n {
                        Some(n) if n.dist2 <= self.max_d2 => Track { partner: n.index as u32, far: 0.0 },
                        Some(n) => Track { partner: u32::MAX, far: n.dist2.sqrt() },
                        None => Track::UNKNOWN,
                    };
                    n.filter(|n| n.dist2 <= self.max_d2).map(|n| (x, n.index, n.dist2.sqrt()))
                })
            })
            .collect()
    }

    /// The target point nearest to `x`, searched from target point `from` when there is one
    /// (`u32::MAX`: none): the neighbour lists, then the grid, then the k-d tree. Every path
    /// gives the nearest point.
    fn nearest(&self, x: &Point3, from: u32) -> Option<Neighbour> {
        let listed = match from {
            u32::MAX => None,
            j => {
                let d2 = (x - self.target[j as usize]).norm_squared();
                let lists = self.lists.as_ref().and_then(|l| l.nearest_from(self.target, x, j as usize, d2));
                lists.or_else(|| self.grid.as_ref()?.nearest_within(x, j as usize, d2))
            }
        };
        listed.or_else(|| self.index.nearest(x))
    }

    /// Builds the neighbourhoods once the pairs `corr` are close enough, in target spacings, for
    /// short lists to answer most of the next searches.
    fn prepare(&mut self, corr: &[(Point3, usize, f64)]) {
        if self.lists.is_some() || corr.is_empty() || self.spacing <= 0.0 {
            return;
        }
        let mut d: Vec<f64> = corr.iter().map(|c| c.2).collect();
        let at = (d.len() - 1) * 9 / 10;
        let radius = LIST_RADIUS_PER_PAIR_DISTANCE * *d.select_nth_unstable_by(at, f64::total_cmp).1;
        if radius <= MAX_LIST_RADIUS_IN_SPACINGS * self.spacing {
            self.lists = Neighbourhoods::new(self.target, radius.max(self.spacing));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    /// A bumpy 10 cm patch, sampled on a jittered grid (`phase` moves the samples).
    fn patch(n: usize, phase: f64) -> Vec<Point3> {
        let side = (n as f64).sqrt() as usize;
        (0..side * side)
            .map(|i| {
                let jitter = |k: f64| ((i as f64 + phase) * k).sin() * 0.3;
                let u = ((i % side) as f64 + jitter(12.9898)) / side as f64;
                let v = ((i / side) as f64 + jitter(78.233)) / side as f64;
                Point3::new(0.1 * u, 0.1 * v, 0.015 * (9.0 * u).sin() * (7.0 * v).cos())
            })
            .collect()
    }

    /// The motion between the tests' source and target patches.
    fn patch_motion() -> Pose {
        Pose::from_parts(
            Translation3::new(0.01, -0.02, 0.005),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.1, -0.25, 0.2)),
        )
    }

    #[test]
    fn neighbourhood_answers_are_the_tree_answers() {
        let target = patch(4000, 0.0);
        let truth = patch_motion();
        let source: Vec<Point3> = patch(3000, 0.5).iter().map(|p| truth.inverse() * p).collect();
        let mut with_lists = Matcher::new(&target, 0.25);
        let mut tree_only = Matcher::new(&target, 0.25);
        tree_only.grid = None;
        let mut tracks = vec![Track::UNKNOWN; source.len()];
        // Poses approaching the truth, as ICP's estimates do, then settling around it.
        let mut listed_passes = 0;
        let mut before = None;
        for (k, t) in approaching(&truth).into_iter().enumerate() {
            let a = with_lists.pairs(&source, &mut tracks, &t, before.as_ref());
            let b = tree_only.pairs(&source, &mut vec![Track::UNKNOWN; source.len()], &t, None);
            assert_eq!(a, b, "pass {k}");
            listed_passes += usize::from(with_lists.lists.is_some());
            with_lists.prepare(&a);
            before = Some(t);
        }
        assert!(listed_passes >= 5, "the neighbourhoods answered {listed_passes} passes");
        assert!(tree_only.lists.is_none());
    }

    /// Poses approaching `truth` from the identity, as ICP's estimates do, then settling around it.
    fn approaching(truth: &Pose) -> Vec<Pose> {
        (0..=16)
            .map(|k| {
                let f = (k as f64 / 10.0).min(1.0);
                let wobble = if k > 10 { 1e-4 * (k as f64).sin() } else { 0.0 };
                Pose::identity().lerp_slerp(truth, f) * Translation3::new(wobble, -wobble, 0.0)
            })
            .collect()
    }

    /// A source reaching far past the target (a whole frame's background) under a 1 cm gate: the
    /// points beyond it are skipped on later passes, and the pairs are still a full search's.
    #[test]
    fn points_far_beyond_the_gate_are_skipped_with_the_same_pairs() {
        let target = patch(4000, 0.0);
        let truth = patch_motion();
        // Three times the target's extent: most of the source has nothing within the gate.
        let wide: Vec<Point3> =
            patch(3000, 0.5).iter().map(|p| Point3::new(3.0 * p.x - 0.1, 3.0 * p.y - 0.1, p.z)).collect();
        let source: Vec<Point3> = wide.iter().map(|p| truth.inverse() * p).collect();
        let matcher = Matcher::new(&target, 0.01);
        let mut tracks = vec![Track::UNKNOWN; source.len()];
        let mut before = None;
        for (k, t) in approaching(&truth).into_iter().enumerate() {
            let a = matcher.pairs(&source, &mut tracks, &t, before.as_ref());
            let b = matcher.pairs(&source, &mut vec![Track::UNKNOWN; source.len()], &t, None);
            assert_eq!(a, b, "pass {k}");
            before = Some(t);
        }
        let far = tracks.iter().filter(|t| t.far > 0.01).count();
        assert!(far > source.len() / 2, "{far} of {} points known to be far", source.len());
    }
}
