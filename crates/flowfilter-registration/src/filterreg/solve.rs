//! FilterReg's EM iteration, step by step: set-up (spatial order, target values, index,
//! pyramids), the E-step choice and the points it visits, the M-step, the sigma update, the
//! Anderson-mixed step, and the final evaluation.

use super::{
    AUTO_NEIGHBOURS, ExactEStep, FilterReg, FilterRegConfig, FilterRegEStep, FilterRegVariant, MERGED_MIN_POINTS,
    MIXING_SIGMA_CHANGE, Reach, SUBSET_SETTLED, SURFACE_SIGMA_SETTLED, SigmaSchedule, Sums, lattice_sums, m_step,
    permuted, target_values,
};
use crate::aggregate::Pyramid;
use crate::anderson::PoseMixing;
use crate::error::RegistrationError;
use crate::evaluate::{evaluate, evaluate_by};
use crate::gmm::mean_pair_distance2;
use crate::problem::{IterationRecord, Registration, RegistrationProblem, validate_problem};
use crate::warning::RegistrationWarning;
use flowfilter_geometry::{KnnIndex, Point3, Pose, Vector3, spatial_order};

/// The exact E-step's cost per point relative to the lattice's beyond which a registration in
/// its exact phase goes back to the lattice (sigma twice the switch's: four times the
/// neighbours; see `use_lattice`).
const EXACT_EXIT_COST: f64 = 4.0;

/// Iterations over which a result that moved less than the tolerance per iteration on average
/// has converged. Near its fixed point, Anderson mixing (and the exact E-step's neighbour lists,
/// rebuilt as points move) makes single steps wander by a few tolerances around a pose that no
/// longer moves: on whole RealSense frames (`cargo xtask bench-real --methods filterreg-pt2pl`),
/// 16 of the 141 registrations ran to the 300-iteration limit about such a pose and were
/// reported as not converged; they now converge within 0.004 deg of where the limit left them.
const STALL_WINDOW: usize = 10;

/// Whether the last [`STALL_WINDOW`] iterations of `history` moved the result by less than
/// `tolerance` per iteration, in rotation (rad) and translation (m).
fn stalled(history: &[IterationRecord], tolerance: f64) -> bool {
    let n = history.len();
    n > STALL_WINDOW && {
        let d = history[n - 1].transform * history[n - 1 - STALL_WINDOW].transform.inverse();
        let limit = STALL_WINDOW as f64 * tolerance;
        d.rotation.angle() < limit && d.translation.vector.norm() < limit
    }
}

/// Whether the next iteration's E-step is exact, given whether this one's was and the exact
/// sums' cost per point relative to the lattice's (`None`: no exact phase): entered below 1,
/// left above [`EXACT_EXIT_COST`].
fn exact_next(exact: bool, cost: Option<f64>) -> bool {
    match (exact, cost) {
        (_, None) => false,
        (true, Some(c)) => c <= EXACT_EXIT_COST,
        (false, Some(c)) => c < 1.0,
    }
}

/// The clouds in a spatially coherent order (the neighbours of a point, and the points queried
/// one after the other, then sit close together in memory), with what every iteration reads.
struct Prepared {
    source: Vec<Point3>,
    target: Vec<Point3>,
    /// Values per target point (5, or 8 with normals) and their rows.
    vd: usize,
    values: Vec<f64>,
    index: KnnIndex,
    /// The support radius below which exact sums are cheaper than the lattice (Auto).
    exact_below: Option<f64>,
    /// Merged source (no values) and target for the wide-kernel lattice iterations.
    pyramids: Option<(Pyramid, Pyramid)>,
    /// The source's centroid and RMS radius (how far an update moves it; Anderson coordinates).
    centre: Point3,
    radius: f64,
}

impl Prepared {
    fn new(cfg: &FilterRegConfig, p: &RegistrationProblem, pt2pl: bool) -> Self {
        // (Independent set-up steps run side by side.)
        let (source_order, target_order) =
            rayon::join(|| spatial_order(&p.source.points), || spatial_order(&p.target.points));
        let source = permuted(&p.source.points, &source_order);
        let target = permuted(&p.target.points, &target_order);
        let normals: Option<Vec<Vector3>> =
            p.target.normals.as_deref().filter(|_| pt2pl).map(|n| permuted(n, &target_order));
        let (vd, values) = target_values(&target, normals.as_deref());
        let index = KnnIndex::new(&target);
        // The median distance from (a strided sample of) target points to their
        // AUTO_NEIGHBOURS-th neighbour: the support radius below which exact sums are cheaper
        // than the lattice (Auto), and a quarter of it the point spacing (merging).
        let merging = cfg.merge_fraction > 0.0 && cfg.e_step == FilterRegEStep::Auto;
        let support = (cfg.e_step == FilterRegEStep::Auto || merging)
            .then(|| index.median_neighbour_distance(&target, AUTO_NEIGHBOURS, 64).unwrap_or(f64::INFINITY));
        let exact_below = support.filter(|_| cfg.e_step == FilterRegEStep::Auto);
        let pyramids = support.filter(|r| merging && r.is_finite() && *r > 0.0).map(|r| {
            let finest = r / 4.0;
            rayon::join(
                || Pyramid::new(&source, &[], 0, finest, MERGED_MIN_POINTS),
                || Pyramid::new(&target, &values, vd, finest, MERGED_MIN_POINTS),
            )
        });
        let (centre, radius) = centre_and_radius(&source);
        Self { source, target, vd, values, index, exact_below, pyramids, centre, radius }
    }
}

/// The centroid of `points` and their RMS distance to it (at least 1e-9).
fn centre_and_radius(points: &[Point3]) -> (Point3, f64) {
    let n = points.len() as f64;
    let centre = Point3::from(points.iter().fold(Vector3::zeros(), |a, s| a + s.coords) / n);
    (centre, (points.iter().map(|s| (s - centre).norm_squared()).sum::<f64>() / n).sqrt().max(1e-9))
}

/// The points one iteration visits: source points (each standing for `counts` points spread by
/// `spreads` when merged) and target points with their values.
struct Visit<'a> {
    src: &'a [Point3],
    counts: Option<&'a [f64]>,
    spreads: Option<&'a [f64]>,
    tgt: &'a [Point3],
    tgt_values: &'a [f64],
}

impl<'a> Visit<'a> {
    /// The settling subset where it has fewer points than the merged level, else the merged
    /// level (wide kernels on the lattice; voxels up to a fraction of sigma), else every point.
    fn select(
        cfg: &FilterRegConfig,
        prep: &'a Prepared,
        subset: Option<&'a (Vec<Point3>, Vec<f64>)>,
        use_lattice: bool,
        sigma: f64,
    ) -> Self {
        let levels = prep
            .pyramids
            .as_ref()
            .filter(|_| use_lattice)
            .map(|(ps, pt)| (ps.level_for(cfg.merge_fraction * sigma), pt.level_for(cfg.merge_fraction * sigma)));
        let (src, counts, spreads) = match (levels.and_then(|l| l.0), subset) {
            (Some(l), Some((pts, n))) if pts.len() < l.points.len() => (&pts[..], Some(&n[..]), None),
            (Some(l), _) => (&l.points[..], Some(&l.counts[..]), Some(&l.spreads[..])),
            (None, Some((pts, n))) => (&pts[..], Some(&n[..]), None),
            (None, None) => (&prep.source[..], None, None),
        };
        let (tgt, tgt_values) = match levels.and_then(|l| l.1) {
            Some(l) => (&l.points[..], &l.values[..]),
            None => (&prep.target[..], &prep.values[..]),
        };
        Self { src, counts, spreads, tgt, tgt_values }
    }

    /// The EM update's numerator and denominator of sigma^2 with the new pose `g` and this
    /// E-step's posteriors. A merged point stands for `n` points spread by `s` around it:
    /// `sum_j |x_j|^2 = n |x|^2 + s`.
    fn sigma_sums(&self, sums: &Sums, g: &Pose, c: f64) -> (f64, f64) {
        (0..self.src.len())
            .filter(|&i| sums.m0[i] > 1e-12)
            .map(|i| {
                let (m0, xg) = (sums.m0[i], g * self.src[i]);
                let (n, s) = (self.counts.map_or(1.0, |n| n[i]), self.spreads.map_or(0.0, |s| s[i]));
                let q = m0 * (n * xg.coords.norm_squared() + s) - 2.0 * n * xg.coords.dot(&sums.m1[i]) + n * sums.m2[i];
                (q / (m0 + c), n * m0 / (m0 + c))
            })
            .fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1))
    }
}

/// The EM iteration's state from one iteration to the next.
struct EmState {
    /// The current iterate (mixed or plain) and sigma^2.
    t: Pose,
    sigma2: f64,
    /// The last plain EM step's pose: the result.
    result: Pose,
    iterations: usize,
    converged: bool,
    history: Vec<IterationRecord>,
    warnings: Vec<RegistrationWarning>,
    /// Whether Auto has switched to the exact E-step.
    exact_phase: bool,
    /// How often Auto's E-step has switched between the lattice and the exact sums from one
    /// iteration to the next.
    switches: usize,
    /// The evenly spread subset of the source visited while the pose settles (every k-th
    /// point in spatial order, each standing for its share of the cloud); `None` once the
    /// iterations visit every point.
    subset: Option<(Vec<Point3>, Vec<f64>)>,
    /// Anderson mixing of the EM map (pose, sigma^2) -> (pose', sigma'^2).
    mixing: Option<PoseMixing>,
    /// Whether mixing has started.
    started: bool,
}

impl EmState {
    fn new(cfg: &FilterRegConfig, p: &RegistrationProblem, prep: &Prepared) -> Self {
        let t = p.init;
        let sigma2 = cfg.init_sigma2.unwrap_or_else(|| {
            let x: Vec<Point3> = prep.source.iter().map(|s| t * s).collect();
            mean_pair_distance2(&x, &prep.target) / 3.0
        });
        let mixing = (cfg.anderson_depth > 0).then(|| {
            let with_sigma = matches!(cfg.sigma, SigmaSchedule::Update { .. });
            PoseMixing::new(cfg.anderson_depth, t, prep.centre, prep.radius, with_sigma)
        });
        let source = &prep.source;
        let subset = (cfg.settling_points > 0 && source.len() > 2 * cfg.settling_points).then(|| {
            let pts: Vec<Point3> = source.iter().step_by(source.len().div_ceil(cfg.settling_points)).copied().collect();
            let counts = vec![source.len() as f64 / pts.len() as f64; pts.len()];
            (pts, counts)
        });
        Self {
            t,
            sigma2,
            result: t,
            iterations: 0,
            converged: false,
            history: vec![],
            warnings: vec![],
            exact_phase: false,
            switches: 0,
            subset,
            mixing,
            started: false,
        }
    }

    /// Whether this iteration's E-step runs on the lattice.
    fn use_lattice(&mut self, cfg: &FilterRegConfig, prep: &Prepared, sigma: f64) -> bool {
        match cfg.e_step {
            FilterRegEStep::Lattice => true,
            FilterRegEStep::Exact => false,
            FilterRegEStep::Auto => {
                // The exact sums cost the kernel's neighbour count, (4 sigma / r)^2 *
                // AUTO_NEIGHBOURS on a surface, per source point visited; the lattice costs
                // about as much per point of both clouds: the source points visited and the
                // target (taken as large as the whole source). With every point visited the
                // switch comes at (4 sigma / r)^2 = 1; visiting a share s of the source moves it
                // to (4 sigma / r)^2 = (s + 1) / (2 s), wider kernels. Once exact, stay exact
                // (no flip-flopping) unless sigma grows back far past the switch
                // (`EXACT_EXIT_COST` times its cost per point): a registration that lost the
                // overlap (a scene 30-80 deg away) widens its kernel to centimetres, where every
                // point has thousands of neighbours (280 ms per iteration on 17k points).
                let share = self.subset.as_ref().map_or(1.0, |(pts, _)| pts.len() as f64 / prep.source.len() as f64);
                let cost = prep.exact_below.map(|r| (4.0 * sigma / r).powi(2) * share / (0.5 * (share + 1.0)));
                let exact = exact_next(self.exact_phase, cost);
                // The first iteration's choice is no switch.
                if self.iterations > 0 && exact != self.exact_phase {
                    self.switches += 1;
                }
                self.exact_phase = exact;
                !exact
            }
        }
    }

    /// Whether a point-to-plane registration's E-step has switched `max_e_step_switches` times
    /// (its kernel cycles between the two E-steps' sums).
    fn cycling(&self, cfg: &FilterRegConfig) -> bool {
        let limit = cfg.max_e_step_switches.unwrap_or(super::DEFAULT_MAX_E_STEP_SWITCHES);
        cfg.variant == FilterRegVariant::PointToPlane && limit > 0 && self.switches >= limit
    }

    /// After the plain step to `(g, new_sigma2)` (the update `delta`, moving the source by
    /// `moved`): the next iterate. True once converged.
    fn advance(
        &mut self,
        cfg: &FilterRegConfig,
        delta: &Pose,
        g: Pose,
        new_sigma2: f64,
        moved: f64,
        min_sigma: f64,
    ) -> bool {
        let (sigma2, sigma) = (self.sigma2, self.sigma2.sqrt());
        let small = delta.rotation.angle() < cfg.tolerance && delta.translation.vector.norm() < cfg.tolerance;
        let sigma_settled = (new_sigma2 - sigma2).abs() <= 1e-3 * sigma2;
        // The subset's iteration has settled: from here on every point, with a fresh history.
        if self.subset.is_some()
            && moved < SUBSET_SETTLED * sigma
            && (new_sigma2 - sigma2).abs() <= SUBSET_SETTLED * sigma2
        {
            self.subset = None;
            if let Some(mixing) = self.mixing.as_mut() {
                mixing.restart();
            }
            (self.t, self.sigma2) = (g, new_sigma2);
            return false;
        }
        // (On the subset, a pose that stops moving settles the subset above instead.)
        if sigma_settled && (small || (self.subset.is_none() && stalled(&self.history, cfg.tolerance))) {
            self.sigma2 = new_sigma2;
            self.converged = true;
            return true;
        }
        // Mixing starts once sigma has (nearly) settled: while it shrinks fast the EM map
        // changes from step to step and extrapolating it can leave the basin.
        self.started |= (new_sigma2 - sigma2).abs() <= MIXING_SIGMA_CHANGE * sigma2;
        if self.mixing.is_none() || !self.started {
            (self.t, self.sigma2) = (g, new_sigma2);
            return false;
        }
        let mixing = self.mixing.as_mut().expect("mixing is on");
        (self.t, self.sigma2) = mixing.step(self.t, self.sigma2, g, new_sigma2, min_sigma * min_sigma);
        false
    }
}

/// The sigma^2 that follows `sigma2` given the EM estimate's sums `(num, den)`.
fn next_sigma2(cfg: &FilterRegConfig, sigma2: f64, (num, den): (f64, f64), surface_settled: bool) -> f64 {
    let min_sigma = cfg.min_sigma();
    match cfg.sigma {
        // The EM estimate, shrinking by at most half per iteration: an EM step that
        // collapses sigma freezes the posteriors before the pose has converged.
        SigmaSchedule::Update { .. } => {
            let em = num / (3.0 * den);
            let estimate = if surface_settled { 3.0 * em - 2.0 * sigma2 } else { em };
            estimate.max(0.5 * sigma2).max(min_sigma * min_sigma)
        }
        SigmaSchedule::Anneal { factor, .. } => (sigma2 * factor * factor).max(min_sigma * min_sigma),
    }
}

impl FilterRegConfig {
    /// The sigma schedule's floor.
    fn min_sigma(&self) -> f64 {
        match self.sigma {
            SigmaSchedule::Update { min_sigma } | SigmaSchedule::Anneal { min_sigma, .. } => min_sigma,
        }
    }
}

impl FilterReg {
    /// [`crate::Registrar::register`]'s body, run on a pool thread.
    pub(super) fn solve(&self, p: &RegistrationProblem) -> Result<Registration, RegistrationError> {
        let cfg = &self.config;
        let pt2pl = cfg.variant == FilterRegVariant::PointToPlane;
        validate_problem(p, pt2pl.then_some("filterreg-pt2pl"))?;
        let prep = Prepared::new(cfg, p, pt2pl);
        let mut exact = (cfg.e_step != FilterRegEStep::Lattice).then(|| ExactEStep {
            index: &prep.index,
            target: &prep.target,
            cache: None,
        });
        let mut em = EmState::new(cfg, p, &prep);
        let corr = p.correspondences.as_ref().filter(|c| !c.is_empty());
        let surface_sigma = cfg.surface_sigma && pt2pl;
        // Outlier level relative to the unnormalised kernel sums (as FilterReg's reference
        // implementation does): c = w / (1 - w) * N / M, independent of sigma.
        let c =
            if cfg.w > 0.0 { cfg.w / (1.0 - cfg.w) * prep.target.len() as f64 / prep.source.len() as f64 } else { 0.0 };
        for it in 0..cfg.max_iterations {
            let sigma = em.sigma2.sqrt();
            let use_lattice = em.use_lattice(cfg, &prep, sigma);
            if em.cycling(cfg) {
                em.warnings.push(RegistrationWarning::KernelCycling { iterations: it, switches: em.switches });
                break;
            }
            let visit = Visit::select(cfg, &prep, em.subset.as_ref(), use_lattice, sigma);
            let x: Vec<Point3> = visit.src.iter().map(|s| em.t * s).collect();
            let sums = match (&mut exact, use_lattice) {
                (Some(e), false) => e.sums(&x, &prep.values, prep.vd, sigma),
                _ => lattice_sums(visit.tgt, visit.tgt_values, prep.vd, &x, sigma),
            };
            let reach = Reach { centre: em.t * prep.centre, radius: prep.radius, sigma };
            let Some(delta) = m_step(cfg, &x, visit.counts, &sums, c, corr.map(|k| (k, &em.t)), &reach) else {
                em.warnings.push(RegistrationWarning::NothingNear { sigma_m: sigma });
                break;
            };
            let g = delta * em.t;
            em.result = g;
            em.iterations = it + 1;
            let sigma_sums = visit.sigma_sums(&sums, &g, c);
            let moved = reach.moved_by(&delta);
            let surface_settled = surface_sigma && moved < SURFACE_SIGMA_SETTLED * sigma;
            let new_sigma2 = next_sigma2(cfg, em.sigma2, sigma_sums, surface_settled);
            em.history.push(IterationRecord { iteration: it, transform: g, objective: new_sigma2 });
            if em.advance(cfg, &delta, g, new_sigma2, moved, cfg.min_sigma()) {
                break;
            }
        }
        let cache = exact.and_then(|e| e.cache);
        Ok(finish(cfg, p, &prep, cache, em))
    }
}

/// The result: the last plain step's pose, evaluated (the initial pose with a warning when the
/// iterations diverged).
fn finish(
    cfg: &FilterRegConfig,
    p: &RegistrationProblem,
    prep: &Prepared,
    cache: Option<super::NeighbourCache>,
    em: EmState,
) -> Registration {
    let t = em.result;
    if !t.to_homogeneous().iter().all(|v| v.is_finite()) {
        return Registration {
            transform: p.init,
            iterations: em.iterations,
            converged: false,
            fitness: 0.0,
            inlier_rmse: 0.0,
            sigma2: Some(em.sigma2),
            scale: None,
            history: em.history,
            warnings: vec![RegistrationWarning::Diverged { method: "FilterReg" }],
            correspondence_set: None,
            uncertainty: None,
            overruled_flow: None,
        };
    }
    // The last exact iteration's lists (when they were gathered for every point) answer
    // most of the evaluation's nearest-neighbour searches.
    let (source, target, index) = (&prep.source, &prep.target, &prep.index);
    let lists = cache.filter(|c| c.built_at.len() == source.len());
    let (fitness, inlier_rmse) = match &lists {
        Some(c) => evaluate_by(source, &t, cfg.evaluation_distance, |i, q| {
            c.nearest2(i, q, target).or_else(|| index.nearest(q).map(|n| n.dist2))
        }),
        None => evaluate(source, index, &t, cfg.evaluation_distance),
    };
    Registration {
        transform: t,
        iterations: em.iterations,
        converged: em.converged,
        fitness,
        inlier_rmse,
        sigma2: Some(em.sigma2),
        scale: None,
        history: em.history,
        warnings: em.warnings,
        correspondence_set: None,
        uncertainty: None,
        overruled_flow: None,
    }
}

#[cfg(test)]
mod tests {
    use super::{STALL_WINDOW, exact_next, stalled};
    use crate::problem::IterationRecord;
    use flowfilter_geometry::{Pose, Vector3};

    /// Records whose poses turn by `step(k)` rad about z at iteration k.
    fn records(n: usize, step: impl Fn(usize) -> f64) -> Vec<IterationRecord> {
        let mut angle = 0.0;
        (0..n)
            .map(|k| {
                angle += step(k);
                let transform = Pose::new(Vector3::zeros(), Vector3::z() * angle);
                IterationRecord { iteration: k, transform, objective: 1e-6 }
            })
            .collect()
    }

    #[test]
    fn a_result_that_wanders_about_one_pose_has_stalled_and_a_crawl_has_not() {
        let tol = 1e-6;
        // Steps of three tolerances back and forth: each step too large, the result still.
        assert!(stalled(&records(40, |k| if k % 2 == 0 { 3e-6 } else { -3e-6 }), tol));
        // A steady crawl of 1.5 tolerances per step is still moving.
        assert!(!stalled(&records(40, |_| 1.5e-6), tol));
        // Too short a history to tell.
        assert!(!stalled(&records(STALL_WINDOW, |_| 0.0), tol));
    }

    /// The phases over a run of costs, starting on the lattice.
    fn phases(costs: &[f64]) -> Vec<bool> {
        let mut exact = false;
        costs
            .iter()
            .map(|c| {
                exact = exact_next(exact, Some(*c));
                exact
            })
            .collect()
    }

    #[test]
    fn the_exact_phase_is_entered_below_the_switch_and_left_far_above_it() {
        // Sigma shrinking: lattice, then exact at the switch.
        assert_eq!(phases(&[9.0, 3.0, 1.5, 0.9, 0.5, 0.3]), [false, false, false, true, true, true]);
        // Sigma growing back: exact up to four times the switch's cost, then the lattice, and
        // exact again only below the switch (no flip-flopping in between).
        assert_eq!(phases(&[0.5, 2.0, 3.9, 4.5, 3.0, 1.2, 0.8]), [true, true, true, false, false, false, true]);
        assert!(!exact_next(true, None));
    }
}
