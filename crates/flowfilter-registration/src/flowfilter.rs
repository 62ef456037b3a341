//! Flow Filter: FilterReg plus optical-flow correspondences (stage 6 of the method).
//!
//! The problem's weighted correspondences (from optical flow) give (a) a robust initial pose by
//! RANSAC over minimal sets of three pairs with weighted Kabsch, refined on the inliers, and (b) a
//! correspondence term `lambda * sum_j w_j |T a_j - b_j|^2` added to FilterReg's M-step. Each part
//! can be switched off for ablation ([`FlowFilterMode`]). Without enough correspondences it
//! degrades to plain FilterReg and says so in the result's warnings.

use crate::error::RegistrationError;
use crate::evaluate::visible_residual;
use crate::filterreg::{FilterReg, FilterRegConfig, FilterRegVariant};
use crate::icp::{Icp, IcpConfig, IcpVariant};
use crate::problem::Uncertainty;
use crate::problem::{Correspondences, Registrar, Registration, RegistrationProblem, in_pool, validate_problem};
use crate::reprojection::{Refinement, Shutter, refine_by_reprojection_with};
use crate::warning::RegistrationWarning;
use flowfilter_geometry::{KnnIndex, Point3, Pose, weighted_kabsch};
use flowfilter_geometry::{ParamError, params};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Which parts of Flow Filter run (for the ablation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FlowFilterMode {
    /// The RANSAC + Kabsch pose from the correspondences alone.
    FlowOnly,
    /// FilterReg started from that pose, without the correspondence term.
    InitOnly,
    /// FilterReg started from that pose, with the correspondence term (the method).
    Joint,
}

/// Flow Filter parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FlowFilterConfig {
    /// Ablation switch.
    pub mode: FlowFilterMode,
    /// RANSAC hypotheses.
    pub ransac_iterations: usize,
    /// A pair is an inlier of a hypothesis within this distance, metres.
    pub inlier_threshold_m: f64,
    /// Minimum inlier pairs for the flow pose to be trusted.
    pub min_inliers: usize,
    /// Minimum fraction of the usable pairs that must agree with the flow pose for it to be
    /// trusted (views without a common surface give a few pairs that agree by chance).
    pub min_inlier_fraction: f64,
    /// Weight `lambda` of the correspondence term relative to the FilterReg term.
    pub correspondence_weight: f64,
    /// Seed of the RANSAC sampling.
    pub seed: u64,
    /// Geometric verification: also run FilterReg from the flow pose without the flow term and
    /// from the problem's initial pose, and keep the result whose clouds fit best (truncated
    /// mean residual); the flow result wins ties within `geometric_margin_m`. Flow then decides
    /// where the geometry is ambiguous (symmetric shapes) and cannot override it where it is not.
    pub geometric_check: bool,
    /// The geometric check is skipped where the flow settles the answer: the first
    /// correspondence set (the plain flow's) is the one chosen, at least this many of its pairs
    /// agree on the RANSAC pose... (0 = always check). Every flow-free alternative the check
    /// weighs would contradict that many pairs; what it guards against (flow stuck on shading
    /// that does not turn with the surface) shows as fewer agreeing pairs or a larger turn.
    pub settled_min_pairs: usize,
    /// ...at least this fraction of its usable pairs agree...
    pub settled_fraction: f64,
    /// ...and the RANSAC pose turns less than this (degrees)...
    pub settled_max_turn_deg: f64,
    /// ...and at least this (degrees): flow locked on shading that stays put while the surface
    /// turns says "no motion", consistently, on many pairs; an answer that barely turns is
    /// always checked.
    pub settled_min_turn_deg: f64,
    /// Residual difference (metres) below which the geometry counts as ambiguous.
    pub geometric_margin_m: f64,
    /// ...and residual ratio below which it does: a correct pose on a partial view leaves the
    /// points that turned out of view unmatched, so it may fit slightly worse than a slid one;
    /// a wrong flow pose fits far worse (measured: 1.1-1.5x vs 1.4-2x).
    pub geometric_ratio: f64,
    /// Truncation of the residual (metres).
    pub geometric_tau_m: f64,
    /// Motion check (part of the geometric check): a geometric registration from the initial
    /// pose (FilterReg, and point-to-plane ICP) wins when it fits the clouds better than the
    /// flow result *and* moves further than the flow pose by more than this many degrees (or
    /// fits nearly as well, `motion_fit_tolerance`, and moves more than twice as far plus this). Both cues fail towards "no motion": flow where the
    /// visible pattern does not move with the surface (shading on a turning surface of
    /// revolution seen from above: consistent, wrong, near-static tracks), geometry where the
    /// shape is symmetric (a registration from the initial pose stays there). A geometric
    /// registration that leaves the initial pose for more motion than the flow found, and fits
    /// better, was pulled there by unambiguous geometry. Negative switches the check off.
    pub motion_margin_deg: f64,
    /// How much worse (relative mean residual) than the flow result a candidate of the motion
    /// check may fit and still win, when it moved more than twice as far as the flow pose: the
    /// visible-point residual of partial views separates poses only by a few percent (measured:
    /// a mug turned 30 degrees, the right pose 10% worse than the flow result that barely moved;
    /// a box turned 30 degrees, a flipped pose that moved 58 degrees 4% worse than the right flow
    /// pose). Among the candidates that qualify, the one that moved furthest wins (both cues err
    /// towards no motion).
    pub motion_fit_tolerance: f64,
    /// Correspondence gate (metres) of the point-to-plane ICP from the initial pose that the
    /// motion check also considers (0 = FilterReg only; needs target normals).
    pub motion_icp_distance_m: f64,
    /// Final point-to-plane ICP polish with this correspondence gate (metres; 0 = off): the GMM
    /// estimate is biased by its own smoothing on partial views, a short point-to-plane ICP from
    /// it is not (and cannot slide far: the gate is a few millimetres).
    pub polish_distance_m: f64,
    /// The polish is undone when it moves the flow pairs' median residual up by more than half
    /// of itself and more than this (metres): a polish that slides along a symmetry, or that
    /// follows a partial view's geometric bias away from accurate flow, disagrees with the flow.
    pub polish_flow_slack_m: f64,
    /// Last step: refine the pose by the two-way reprojection error of the flow pairs that agree
    /// with it (within `inlier_threshold_m`): pixels are known to a tenth of a pixel, depth only
    /// to millimetres, and a reprojection barely feels depth error (see
    /// [`crate::refine_by_reprojection`]).
    pub reprojection_refine: bool,
    /// The refinement is not taken when it turns the pose by more than this (degrees): it then
    /// left the basin the registration found. Smaller refuses corrections the flow supports: on
    /// the real YCB-Video sample the registration before it is up to 2.5 deg off and the
    /// refinement lands within 0.8.
    pub reprojection_max_change_deg: f64,
    /// The refinement also estimates a rolling shutter's row shear of the target image, with a
    /// zero-mean prior of this standard deviation (pixels per pixel row; 0 = a global shutter,
    /// [`Shutter`]): consumer colour cameras expose row after row, and a change of image speed
    /// between the exposures shifts each row in proportion to its height, which a rigid fit on
    /// an object's patch takes for a turn. Larger lets the shear trade against a turn about the
    /// long axis of tall, narrow objects; smaller leaves more of a real shear in the pose.
    pub reprojection_row_shear_sd: f64,
    /// The FilterReg part (its runs stop a cycling kernel after
    /// [`SCENE_MAX_E_STEP_SWITCHES`] unless `max_e_step_switches` is set).
    pub filterreg: FilterRegConfig,
    /// A model cloud with more points than this is a scene (a whole frame, a large object), not
    /// a small object: every FilterReg run (the joint one, the fallback and the geometric checks)
    /// then uses the point-to-plane objective when the target has normals, whatever
    /// `filterreg.variant` says. Point-to-point EM crawls on a scene (a 13k-point shelf frame:
    /// 300 iterations, 64 s on 2 cores), point-to-plane converges in tens of iterations (0.1-0.2
    /// s); on the small objects of the default protocol (at most about 2.6k points) point-to-point
    /// is the more accurate (0.25 deg against 0.37 with point-to-plane everywhere). The count is
    /// [`RegistrationProblem::source_size`]: a cloud thinned by the pipeline's budget counts as
    /// the points it stands for, counted at a 4 mm voxel (the pipeline scales a cloud at another
    /// voxel by the surface it covers). 0 = never.
    pub scene_points: usize,
}

impl Default for FlowFilterConfig {
    fn default() -> Self {
        Self {
            mode: FlowFilterMode::Joint,
            ransac_iterations: 300,
            inlier_threshold_m: 0.005,
            min_inliers: 12,
            min_inlier_fraction: 0.3,
            correspondence_weight: 1.0,
            seed: 0,
            geometric_check: true,
            settled_min_pairs: 200,
            settled_fraction: 0.7,
            settled_max_turn_deg: 10.0,
            settled_min_turn_deg: 1.0,
            geometric_margin_m: 0.001,
            geometric_ratio: 1.8,
            geometric_tau_m: 0.01,
            motion_margin_deg: 2.0,
            motion_fit_tolerance: 0.15,
            motion_icp_distance_m: 0.02,
            polish_distance_m: 0.005,
            polish_flow_slack_m: 0.0005,
            reprojection_refine: true,
            reprojection_max_change_deg: 3.0,
            reprojection_row_shear_sd: 0.002,
            filterreg: FilterRegConfig::default(),
            scene_points: 8000,
        }
    }
}

/// Flow Filter as a [`Registrar`].
#[derive(Debug, Clone)]
pub struct FlowFilter {
    /// Parameters.
    pub config: FlowFilterConfig,
}

/// RANSAC over minimal sets, then weighted Kabsch on the best hypothesis' inliers: the pose and
/// the inlier flags. `None` without enough usable pairs.
pub fn ransac_kabsch(
    c: &Correspondences,
    iterations: usize,
    threshold: f64,
    min_inliers: usize,
    seed: u64,
) -> Option<(Pose, Vec<bool>)> {
    let usable: Vec<usize> = (0..c.len()).filter(|&i| c.weights[i] > 0.0).collect();
    if usable.len() < min_inliers.max(3) {
        return None;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let inliers_of = |t: &Pose| -> Vec<bool> {
        (0..c.len()).map(|i| c.weights[i] > 0.0 && (t * c.source[i] - c.target[i]).norm() < threshold).collect()
    };
    let mut best: Option<(usize, Vec<bool>)> = None;
    for _ in 0..iterations {
        let idx: Vec<usize> = (0..3).map(|_| usable[rng.random_range(0..usable.len())]).collect();
        let (s, t): (Vec<Point3>, Vec<Point3>) = idx.iter().map(|&i| (c.source[i], c.target[i])).unzip();
        let Ok(h) = weighted_kabsch(&s, &t, None) else { continue };
        let inl = inliers_of(&h);
        let n = inl.iter().filter(|b| **b).count();
        if best.as_ref().is_none_or(|b| n > b.0) {
            best = Some((n, inl));
        }
    }
    let (n, mut inl) = best?;
    if n < min_inliers {
        return None;
    }
    // Refine: Kabsch on the inliers, re-collect inliers, twice.
    let mut pose = Pose::identity();
    for _ in 0..2 {
        let w: Vec<f64> = (0..c.len()).map(|i| if inl[i] { c.weights[i] } else { 0.0 }).collect();
        pose = weighted_kabsch(&c.source, &c.target, Some(&w)).ok()?;
        inl = inliers_of(&pose);
    }
    Some((pose, inl))
}

impl FlowFilterConfig {
    /// Whether `p`'s model cloud is a scene ([`FlowFilterConfig::scene_points`]): more points
    /// than that, counted as [`RegistrationProblem::source_size`].
    pub fn is_scene(&self, p: &RegistrationProblem) -> bool {
        self.scene_points > 0 && p.source_size() > self.scene_points
    }

    /// Whether the flow settles the answer and the geometric check is skipped (see
    /// [`FlowFilterConfig::settled_min_pairs`]): correspondence set `set` chosen, `agreeing` of
    /// its `usable` pairs agreeing on `pose`.
    pub fn settles(&self, set: usize, agreeing: usize, usable: usize, pose: &Pose) -> bool {
        self.settled_min_pairs > 0
            && set == 0
            && agreeing >= self.settled_min_pairs
            && agreeing as f64 >= self.settled_fraction * usable as f64
            && (self.settled_min_turn_deg..self.settled_max_turn_deg).contains(&pose.rotation.angle().to_degrees())
    }

    /// The polish's guard: whether a polish that moves the flow pairs' median residual from
    /// `before` to `after` (metres) is kept (see [`FlowFilterConfig::polish_flow_slack_m`]).
    pub fn polish_agrees_with_flow(&self, before: f64, after: f64) -> bool {
        after <= before + (0.5 * before).max(self.polish_flow_slack_m)
    }

    /// The motion check's rule: whether a geometric registration from the initial pose with
    /// mean visible residual `s` that moved `moved` degrees replaces the flow result
    /// `(s_flow, flow_moved)` (see [`FlowFilterConfig::motion_margin_deg`]).
    pub fn motion_wins(&self, (s, moved): (f64, f64), (s_flow, flow_moved): (f64, f64)) -> bool {
        let further = moved > flow_moved + self.motion_margin_deg;
        let much_further = moved > 2.0 * flow_moved + self.motion_margin_deg;
        self.motion_margin_deg >= 0.0
            && ((further && s < s_flow) || (much_further && s <= s_flow * (1.0 + self.motion_fit_tolerance)))
    }
}

impl FlowFilter {
    /// Flow Filter with the given parameters.
    ///
    /// # Errors
    /// [`RegistrationError::Param`] for a value out of range ([`FlowFilterConfig::validate`]).
    pub fn new(config: FlowFilterConfig) -> Result<Self, RegistrationError> {
        config.validate().map_err(|e| e.within("flowfilter"))?;
        Ok(Self { config })
    }
}

impl FlowFilterConfig {
    /// Check every value: finite and in range (the inner `[filterreg]` table too).
    ///
    /// # Errors
    /// The first key at fault (keys relative to the `[flowfilter]` table).
    pub fn validate(&self) -> Result<(), ParamError> {
        self.filterreg.validate().map_err(|e| e.within("filterreg"))?;
        params::count_positive("ransac_iterations", self.ransac_iterations)?;
        params::positive("inlier_threshold_m", self.inlier_threshold_m)?;
        params::in_closed("min_inlier_fraction", self.min_inlier_fraction, 0.0, 1.0)?;
        params::non_negative("correspondence_weight", self.correspondence_weight)?;
        params::in_closed("settled_fraction", self.settled_fraction, 0.0, 1.0)?;
        params::non_negative("settled_max_turn_deg", self.settled_max_turn_deg)?;
        params::non_negative("settled_min_turn_deg", self.settled_min_turn_deg)?;
        params::non_negative("geometric_margin_m", self.geometric_margin_m)?;
        params::at_least("geometric_ratio", self.geometric_ratio, 1.0)?;
        params::positive("geometric_tau_m", self.geometric_tau_m)?;
        // Negative turns the motion check off: any finite number.
        params::finite("motion_margin_deg", self.motion_margin_deg)?;
        params::non_negative("motion_fit_tolerance", self.motion_fit_tolerance)?;
        params::non_negative("motion_icp_distance_m", self.motion_icp_distance_m)?;
        params::non_negative("polish_distance_m", self.polish_distance_m)?;
        params::non_negative("polish_flow_slack_m", self.polish_flow_slack_m)?;
        params::non_negative("reprojection_max_change_deg", self.reprojection_max_change_deg)?;
        params::non_negative("reprojection_row_shear_sd", self.reprojection_row_shear_sd)
    }
}

impl Registrar for FlowFilter {
    fn name(&self) -> &str {
        match self.config.mode {
            FlowFilterMode::FlowOnly => "flowfilter-flow-only",
            FlowFilterMode::InitOnly => "flowfilter-init-only",
            FlowFilterMode::Joint => "flowfilter",
        }
    }

    fn register(&self, p: &RegistrationProblem) -> Result<Registration, RegistrationError> {
        in_pool(|| self.solve_and_polish(p))
    }

    fn uses_correspondences(&self) -> bool {
        true
    }

    /// FilterReg from the initial pose without the flow term: the motion that guided tracking
    /// starts from, and one of the geometric check's alternatives (reused when handed back).
    fn prior(&self, p: &RegistrationProblem) -> Result<Option<Registration>, RegistrationError> {
        validate_problem(p, None)?;
        FilterReg::new(self.geometric_config(p))?.register(&p.geometry_only()).map(Some)
    }
}

/// Flow Filter's answer before the polish.
struct Solved {
    registration: Registration,
    /// Whether trusted flow was used (the polish and the refinement follow only then).
    flow_used: bool,
    /// The flow result when a geometric check replaced it.
    overruled: Option<Registration>,
}

impl Solved {
    /// The flow result, kept.
    fn by_flow(registration: Registration) -> Self {
        Self { registration, flow_used: true, overruled: None }
    }
}

/// The candidate set of correspondences Flow Filter uses, with its RANSAC consensus.
struct FlowConsensus<'a> {
    /// Which set (see `RegistrationProblem::alternative_correspondences`).
    index: usize,
    /// The pairs.
    pairs: &'a Correspondences,
    /// RANSAC's pose and inlier flags (`None`: no hypothesis with enough inliers).
    ransac: Option<(Pose, Vec<bool>)>,
}

impl FlowConsensus<'_> {
    /// Pairs that agree with the RANSAC pose.
    fn agreeing(&self) -> usize {
        self.ransac.as_ref().map_or(0, |(_, inliers)| inliers.iter().filter(|b| **b).count())
    }
}

impl FlowFilter {
    /// [`Registrar::register`]'s body, run on a pool thread: choose the correspondences, solve,
    /// polish.
    fn solve_and_polish(&self, p: &RegistrationProblem) -> Result<Registration, RegistrationError> {
        validate_problem(p, None)?;
        let chosen = self.consensus(p);
        let Solved { registration: mut r, flow_used, overruled } = self.solve(p, chosen.as_ref())?;
        // Without trusted flow the result is plain FilterReg, as documented: no polish.
        if flow_used {
            let pairs = chosen.as_ref().map(|c| c.pairs);
            r = self.polish(p, pairs, r)?;
            // The overruled flow result, polished and refined as the answer is: each one's bounds
            // reach the other.
            let overruled = overruled.map(|f| self.polish(p, pairs, f)).transpose()?;
            if let Some(c) = &chosen {
                self.refine(c.pairs, overruled.as_ref().map(|f| &f.transform), &mut r);
            }
            r.overruled_flow = overruled.map(|mut f| {
                if let Some(c) = &chosen {
                    self.refine(c.pairs, Some(&r.transform), &mut f);
                }
                f.correspondence_set = chosen.as_ref().map(|c| c.index);
                Box::new(f)
            });
        }
        r.correspondence_set = chosen.map(|c| c.index);
        Ok(r)
    }

    /// The candidate set whose largest rigid consensus (RANSAC inliers) is biggest; the first
    /// on ties. `None` without correspondences.
    fn consensus<'a>(&self, p: &'a RegistrationProblem) -> Option<FlowConsensus<'a>> {
        let cfg = &self.config;
        let mut best: Option<FlowConsensus<'a>> = None;
        for (index, pairs) in p.correspondence_sets().into_iter().enumerate() {
            let ransac = ransac_kabsch(pairs, cfg.ransac_iterations, cfg.inlier_threshold_m, cfg.min_inliers, cfg.seed);
            let candidate = FlowConsensus { index, pairs, ransac };
            if best.as_ref().is_none_or(|b| candidate.agreeing() > b.agreeing()) {
                best = Some(candidate);
            }
        }
        best
    }

    /// The FilterReg configuration without the correspondence term.
    fn geometric_config(&self, p: &RegistrationProblem) -> FilterRegConfig {
        FilterRegConfig { correspondence_weight: 0.0, ..self.filterreg_config(p) }
    }

    /// The FilterReg configuration for `p`: point-to-plane on a scene
    /// ([`FlowFilterConfig::scene_points`]), else as configured.
    fn filterreg_config(&self, p: &RegistrationProblem) -> FilterRegConfig {
        let mut cfg = self.config.filterreg.clone();
        cfg.max_e_step_switches.get_or_insert(SCENE_MAX_E_STEP_SWITCHES);
        if self.config.is_scene(p) && p.target.normals.is_some() {
            cfg.variant = FilterRegVariant::PointToPlane;
        }
        cfg
    }

    /// Point-to-plane ICP from `r` with a short gate (see `polish_distance_m`); warnings kept.
    fn polish(
        &self,
        p: &RegistrationProblem,
        pairs: Option<&Correspondences>,
        r: Registration,
    ) -> Result<Registration, RegistrationError> {
        let d = self.config.polish_distance_m;
        if d <= 0.0 || self.config.mode == FlowFilterMode::FlowOnly || p.target.normals.is_none() {
            return Ok(r);
        }
        let icp = Icp::new(IcpConfig {
            variant: IcpVariant::PointToPlane,
            max_correspondence_distance: d,
            max_iterations: 30,
            ..IcpConfig::default()
        })?;
        let q = icp.register(&p.geometry_only().with_init(r.transform))?;
        // The polish must not undo what the flow decided (a slide along a symmetry): the flow
        // pairs' median residual may not grow by more than half of itself and the slack.
        if let Some(c) = pairs.filter(|c| c.weights.iter().any(|w| *w > 0.0)) {
            let (before, after) = (median_residual(c, &r.transform), median_residual(c, &q.transform));
            if !self.config.polish_agrees_with_flow(before, after) {
                return Ok(r);
            }
        }
        Ok(Registration { transform: q.transform, fitness: q.fitness, inlier_rmse: q.inlier_rmse, ..r })
    }

    /// [`FlowFilterConfig::reprojection_refine`] from `r` on the pairs that agree with it (`r`
    /// keeps its pose when off, with too few pairs, or when the refinement turns too far). The
    /// refinement's bounds, widened by how far it moved the pose ([`bounds_after_refinement`]),
    /// become `r.uncertainty`, and a motion within them is reported
    /// ([`RegistrationWarning::BelowResolution`]). When a geometric check `overruled` the flow's
    /// pose, the bounds reach that pose too: it is the other answer the frames support.
    fn refine(&self, pairs: &Correspondences, overruled: Option<&Pose>, r: &mut Registration) {
        if !self.config.reprojection_refine {
            return;
        }
        let t = r.transform;
        let gate2 = self.config.inlier_threshold_m.powi(2);
        let agree: Vec<bool> = (0..pairs.len())
            .map(|i| pairs.weights[i] > 0.0 && (t * pairs.source[i] - pairs.target[i]).norm_squared() <= gate2)
            .collect();
        let shear_sd = self.config.reprojection_row_shear_sd;
        let shutter = if shear_sd > 0.0 { Shutter::Rolling { shear_sd } } else { Shutter::Global };
        let Some(q) = refine_by_reprojection_with(pairs, &agree, t, 20, shutter) else { return };
        let taken = pose_distance(&q.pose, &t).0 <= self.config.reprojection_max_change_deg;
        if taken {
            r.transform = q.pose;
        }
        let mut bounds = bounds_after_refinement(&q, &t, taken);
        if let Some(other) = overruled {
            let (turned_deg, shifted_m) = pose_distance(&r.transform, other);
            bounds.rotation_deg = bounds.rotation_deg.max(turned_deg);
            bounds.translation_m = bounds.translation_m.max(shifted_m);
        }
        r.uncertainty = Some(bounds);
        let moved_deg = r.transform.rotation.angle().to_degrees();
        let moved_m = r.transform.translation.vector.norm();
        let Uncertainty { rotation_deg, translation_m } = bounds;
        if moved_deg <= rotation_deg && moved_m <= translation_m {
            r.warnings.push(RegistrationWarning::BelowResolution { moved_deg, rotation_deg, moved_m, translation_m });
        }
    }

    /// Flow Filter before the polish.
    fn solve(&self, p: &RegistrationProblem, chosen: Option<&FlowConsensus<'_>>) -> Result<Solved, RegistrationError> {
        let cfg = &self.config;
        let usable = chosen.map_or(0, |c| c.pairs.usable());
        let agreeing = chosen.map_or(0, FlowConsensus::agreeing);
        let trusted = agreeing as f64 >= cfg.min_inlier_fraction * usable as f64;
        let flow = chosen.and_then(|c| c.ransac.as_ref().map(|(pose, inliers)| (c.pairs, *pose, inliers)));
        let Some((pairs, pose, inliers)) = flow.filter(|_| trusted) else {
            let registration = self.fallback(p, chosen.map(|c| c.pairs), agreeing, usable)?;
            return Ok(Solved { registration, flow_used: false, overruled: None });
        };
        if cfg.mode == FlowFilterMode::FlowOnly {
            return Ok(Solved::by_flow(flow_only(pose, agreeing, pairs.len())));
        }
        let settled = chosen.is_some_and(|c| self.config.settles(c.index, agreeing, usable, &pose));
        if !cfg.geometric_check || settled {
            return Ok(Solved::by_flow(self.filterreg_from_flow(p, pairs, pose, inliers)?));
        }
        // The flow result and the flow-free registrations the checks weigh it against do not
        // depend on one another: they run side by side.
        let plain = p.geometry_only();
        // A flow pose this near the initial pose starts FilterReg where the run from the initial
        // pose starts: the clouds alone from there would repeat that run.
        let (turn_deg, shift_m) = pose_distance(&pose, &p.init);
        let repeats_init = turn_deg < cfg.settled_min_turn_deg && shift_m < LOCAL_START_SIGMA_M;
        let ((flow_result, local), (from_init, icp)) = rayon::join(
            || {
                rayon::join(
                    || self.filterreg_from_flow(p, pairs, pose, inliers),
                    || if repeats_init { Ok(None) } else { self.local(p, pose) },
                )
            },
            || rayon::join(|| self.geometry_from_init(&plain, p), || self.motion_icp(&plain)),
        );
        let alternatives = FlowFree { from_init: from_init?, icp: icp?, local: local? };
        self.verify(p, &plain, flow_result?, alternatives)
    }

    /// The clouds alone registered from the initial pose (the prior, when the problem has one).
    fn geometry_from_init(
        &self,
        plain: &RegistrationProblem,
        p: &RegistrationProblem,
    ) -> Result<Registration, RegistrationError> {
        match &p.prior {
            Some(prior) => Ok(prior.clone()),
            None => FilterReg::new(self.geometric_config(p))?.register(plain),
        }
    }

    /// Point-to-plane ICP from the initial pose for the motion check (none when the check is
    /// off, has no ICP gate or the target has no normals).
    fn motion_icp(&self, plain: &RegistrationProblem) -> Result<Option<Registration>, RegistrationError> {
        let cfg = &self.config;
        if cfg.motion_margin_deg < 0.0 || cfg.motion_icp_distance_m <= 0.0 || plain.target.normals.is_none() {
            return Ok(None);
        }
        let icp = Icp::new(IcpConfig {
            variant: IcpVariant::PointToPlane,
            max_correspondence_distance: cfg.motion_icp_distance_m,
            max_iterations: 50,
            ..IcpConfig::default()
        })?;
        icp.register(plain).map(Some)
    }

    /// FilterReg from the flow pose without the flow term, for the fit check (joint mode only).
    fn local(&self, p: &RegistrationProblem, pose: Pose) -> Result<Option<Registration>, RegistrationError> {
        if self.config.mode != FlowFilterMode::Joint {
            return Ok(None);
        }
        let mut local_cfg = self.geometric_config(p);
        local_cfg.init_sigma2.get_or_insert(LOCAL_START_SIGMA_M * LOCAL_START_SIGMA_M);
        FilterReg::new(local_cfg)?.register(&p.geometry_only().with_init(pose)).map(Some)
    }

    /// No trusted flow: plain FilterReg on the problem, flagged.
    fn fallback(
        &self,
        p: &RegistrationProblem,
        pairs: Option<&Correspondences>,
        agreeing: usize,
        usable: usize,
    ) -> Result<Registration, RegistrationError> {
        let mut problem = p.geometry_only();
        problem.correspondences = pairs.cloned();
        let mut r = FilterReg::new(self.filterreg_config(p))?.register(&problem)?;
        r.warnings.push(RegistrationWarning::FlowFallback {
            agreeing,
            usable,
            min_inliers: self.config.min_inliers,
            min_fraction: self.config.min_inlier_fraction,
        });
        Ok(r)
    }

    /// FilterReg started from the flow pose, with the correspondence term on the RANSAC inliers
    /// (joint mode) or without it (init-only mode).
    fn filterreg_from_flow(
        &self,
        p: &RegistrationProblem,
        pairs: &Correspondences,
        pose: Pose,
        inliers: &[bool],
    ) -> Result<Registration, RegistrationError> {
        let cfg = &self.config;
        let mut fr_cfg = self.filterreg_config(p);
        let mut problem = p.geometry_only().with_init(pose);
        if cfg.mode == FlowFilterMode::Joint {
            fr_cfg.correspondence_weight = cfg.correspondence_weight;
            problem.correspondences = Some(Correspondences {
                source: pairs.source.clone(),
                target: pairs.target.clone(),
                weights: (0..pairs.len()).map(|i| if inliers[i] { pairs.weights[i] } else { 0.0 }).collect(),
            });
        }
        // Start sigma at the scale of the flow pose's residual mismatch rather than the
        // all-pairs spread: the initial pose is already close.
        fr_cfg.init_sigma2.get_or_insert(LOCAL_START_SIGMA_M * LOCAL_START_SIGMA_M);
        FilterReg::new(fr_cfg)?.register(&problem)
    }

    /// Geometric verification of the flow result against the flow-free registrations: the
    /// motion check first, then the fit check.
    fn verify(
        &self,
        p: &RegistrationProblem,
        plain: &RegistrationProblem,
        flow_result: Registration,
        flow_free: FlowFree,
    ) -> Result<Solved, RegistrationError> {
        let cfg = &self.config;
        let index = KnnIndex::new(&p.target.points);
        let normals = p.source.normals.as_deref();
        let score = |r: &Registration| {
            visible_residual(&p.source.points, normals, &index, &r.transform, cfg.geometric_tau_m, 0.3)
        };
        let FlowFree { from_init, icp, local } = flow_free;
        let s_flow = score(&flow_result);
        if cfg.motion_margin_deg >= 0.0
            && let Some(r) = self.motion_check(plain, &from_init, icp, &flow_result, s_flow, &score)
        {
            return Ok(Solved { registration: r, flow_used: true, overruled: Some(flow_result) });
        }
        let mut alternatives = vec![("FilterReg from the initial pose", from_init)];
        if let Some(local) = local {
            alternatives.push(("FilterReg from the flow pose without the flow term", local));
        }
        Ok(match self.fit_check(alternatives, s_flow, &score) {
            Some(registration) => Solved { registration, flow_used: true, overruled: Some(flow_result) },
            None => Solved::by_flow(flow_result),
        })
    }

    /// The motion check (see [`FlowFilterConfig::motion_margin_deg`]) on the clouds alone
    /// (`plain`): the geometric registration from the initial pose (FilterReg, and point-to-plane
    /// ICP where it ran) that qualifies and moved furthest, if any.
    fn motion_check(
        &self,
        plain: &RegistrationProblem,
        from_init: &Registration,
        icp: Option<Registration>,
        flow_result: &Registration,
        s_flow: f64,
        score: &dyn Fn(&Registration) -> f64,
    ) -> Option<Registration> {
        let cfg = &self.config;
        let angle = |r: &Registration| (plain.init.inverse() * r.transform).rotation.angle().to_degrees();
        // Point-to-plane ICP's hard gate holds on to small asymmetric features, such as a mug's
        // handle, that the GMM's wide kernels average away.
        let mut candidates = vec![("FilterReg from the initial pose", from_init.clone())];
        candidates.extend(icp.map(|r| ("point-to-plane ICP from the initial pose", r)));
        let flow_moved = angle(flow_result);
        let winner = candidates
            .into_iter()
            .map(|(name, r)| (score(&r), angle(&r), name, r))
            .filter(|(s, moved, _, _)| cfg.motion_wins((*s, *moved), (s_flow, flow_moved)))
            .max_by(|a, b| a.1.total_cmp(&b.1));
        winner.map(|(s, moved, kept, mut r)| {
            r.warnings.push(RegistrationWarning::MotionCheck {
                kept,
                moved_deg: moved,
                residual_m: s,
                flow_moved_deg: flow_moved,
                flow_residual_m: s_flow,
            });
            r
        })
    }

    /// The fit check: the best-fitting alternative, which replaces the flow result (whose
    /// residual is `s_flow`) only when it fits clearly better (by the margin and the ratio);
    /// `None` when none does.
    fn fit_check(
        &self,
        alternatives: Vec<(&'static str, Registration)>,
        s_flow: f64,
        score: &dyn Fn(&Registration) -> f64,
    ) -> Option<Registration> {
        let cfg = &self.config;
        let best = alternatives
            .into_iter()
            .map(|(name, r)| (score(&r), name, r))
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .expect("at least one alternative");
        if best.0 + cfg.geometric_margin_m < s_flow && best.0 * cfg.geometric_ratio < s_flow {
            let (s, kept, mut r) = best;
            r.warnings.push(RegistrationWarning::GeometricCheck { kept, residual_m: s, flow_residual_m: s_flow });
            return Some(r);
        }
        None
    }
}

/// The kernel width FilterReg starts with from the flow pose (metres): the pose is already close.
const LOCAL_START_SIGMA_M: f64 = 0.01;

/// Flow Filter's limit of FilterReg's E-step switches where its configuration sets none
/// ([`FilterRegConfig::max_e_step_switches`]; FilterReg alone stops at 9): a scene's
/// geometry-first try that converged after 11 switches (shelf-G 7 -> 9) was seen here, and
/// stopping the tries at 9 lost a real whole frame (shelf-G 1 -> 3, 0.6 -> 60 deg off).
pub const SCENE_MAX_E_STEP_SWITCHES: usize = 12;

/// The flow-free registrations the checks weigh the flow result against.
struct FlowFree {
    /// The clouds alone from the initial pose.
    from_init: Registration,
    /// Point-to-plane ICP from the initial pose (the motion check's), where it ran.
    icp: Option<Registration>,
    /// FilterReg from the flow pose without the flow term (joint mode).
    local: Option<Registration>,
}

/// How far apart two poses are: the angle of the rotation between them (degrees) and the distance
/// between their translations (metres), the two quantities the bounds are on.
fn pose_distance(a: &Pose, b: &Pose) -> (f64, f64) {
    ((a.rotation * b.rotation.inverse()).angle().to_degrees(), (a.translation.vector - b.translation.vector).norm())
}

/// Error bounds of the pose Flow Filter reports, from its reprojection refinement `q` that
/// started at `start` (the pose flow and geometry agreed on) and was `taken` or not.
///
/// The refinement's covariance sees the flow pairs' scatter, but not an error that all of them
/// share (a shear the prior held back, a texture tracked with a bias) nor the geometry's pull.
/// How far the refinement moved the pose measures the two together: flow alone against flow and
/// geometry. When taken, that distance is added to the covariance's bound as an independent
/// error (in quadrature); when not taken, the reported pose is `start`, that far from the refined
/// pose, and the bounds add it outright (the triangle inequality).
fn bounds_after_refinement(q: &Refinement, start: &Pose, taken: bool) -> Uncertainty {
    let (rotation_deg, translation_m) = q.bounds();
    let (turned_deg, shifted_m) = pose_distance(&q.pose, start);
    if taken {
        Uncertainty { rotation_deg: rotation_deg.hypot(turned_deg), translation_m: translation_m.hypot(shifted_m) }
    } else {
        Uncertainty { rotation_deg: rotation_deg + turned_deg, translation_m: translation_m + shifted_m }
    }
}

/// The flow-only mode's result: the RANSAC pose itself.
fn flow_only(pose: Pose, agreeing: usize, pairs: usize) -> Registration {
    Registration {
        iterations: 1,
        converged: true,
        fitness: agreeing as f64 / pairs as f64,
        ..Registration::with_transform(pose)
    }
}

/// Median distance `|T a_j - b_j|` over the pairs with a positive weight.
fn median_residual(c: &Correspondences, t: &Pose) -> f64 {
    let mut d: Vec<f64> =
        (0..c.len()).filter(|&i| c.weights[i] > 0.0).map(|i| (t * c.source[i] - c.target[i]).norm()).collect();
    d.sort_by(f64::total_cmp);
    d[d.len() / 2]
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix6, Vector2, Vector3};

    /// A refinement at `pose` whose covariance puts 0.1 deg (rotation) and 1 mm (translation)
    /// standard deviations on every axis, from the pairs as independent (2.8 sd bounds).
    fn refinement(pose: Pose) -> Refinement {
        let (rot, trans) = (0.1f64.to_radians(), 0.001f64);
        let diag = Vector3::repeat(trans * trans).push(rot * rot).push(rot * rot).push(rot * rot);
        let covariance = Matrix6::from_diagonal(&nalgebra::Vector6::from_iterator(diag.iter().copied()));
        Refinement { pose, covariance, blocks: 0, row_shear: Vector2::zeros() }
    }

    /// Flow Filter's FilterReg runs stop a cycling kernel after [`SCENE_MAX_E_STEP_SWITCHES`]
    /// where the configuration sets no limit (FilterReg alone: 9), and after the configured
    /// number where it does.
    #[test]
    fn flow_filters_filterreg_runs_take_its_own_switch_limit_unless_one_is_set() {
        let cloud = flowfilter_geometry::PointCloud::from_points(
            (0..10).map(|i| Point3::new(f64::from(i) * 0.01, 0.0, 1.0)).collect(),
        );
        let p = RegistrationProblem::new(cloud.clone(), cloud);
        let limit = |set: Option<usize>| {
            let mut cfg = FlowFilterConfig::default();
            cfg.filterreg.max_e_step_switches = set;
            FlowFilter { config: cfg }.filterreg_config(&p).max_e_step_switches
        };
        assert_eq!(FilterRegConfig::default().max_e_step_switches, None);
        assert_eq!(limit(None), Some(SCENE_MAX_E_STEP_SWITCHES));
        assert_eq!(limit(Some(9)), Some(9));
        assert_eq!(limit(Some(0)), Some(0));
    }

    /// The geometric check is skipped only where the plain flow's many pairs agree on a small
    /// motion that is not "no motion".
    #[test]
    fn the_check_is_skipped_only_where_the_flow_settles_a_small_turn() {
        let cfg = FlowFilterConfig::default();
        let turned = |deg: f64| Pose::new(Vector3::new(0.01, 0.0, 0.0), Vector3::new(0.0, deg.to_radians(), 0.0));
        assert!(cfg.settles(0, 400, 500, &turned(3.0)));
        assert!(!cfg.settles(1, 400, 500, &turned(3.0)), "a guided or searched set is always checked");
        assert!(!cfg.settles(0, 150, 160, &turned(3.0)), "too few pairs");
        assert!(!cfg.settles(0, 300, 500, &turned(3.0)), "too small a share");
        assert!(!cfg.settles(0, 400, 500, &turned(12.0)), "a large turn");
        assert!(!cfg.settles(0, 400, 500, &turned(0.3)), "flow that says no motion (shading locked)");
        assert!(
            !FlowFilterConfig { settled_min_pairs: 0, ..cfg }.settles(0, 400, 500, &turned(3.0)),
            "0: always checked"
        );
    }

    /// Taken, the refinement's move adds to its bounds in quadrature; not taken (the pose
    /// reported is the start), outright.
    #[test]
    fn the_bounds_widen_by_how_far_the_refinement_moved() {
        let start = Pose::new(Vector3::new(0.0, 0.0, 0.5), Vector3::zeros());
        let moved = Pose::new(Vector3::new(0.003, 0.0, 0.5), Vector3::new(0.0, 0.0, 1f64.to_radians()));
        let q = refinement(moved);
        let (rot, trans) = q.bounds();
        assert!((rot - 0.27955).abs() < 1e-4 && (trans - 0.0027955).abs() < 1e-7, "{rot} {trans}");
        let (turned, shifted) = pose_distance(&moved, &start);
        assert!((turned - 1.0).abs() < 1e-9 && (shifted - 0.003).abs() < 1e-12, "{turned} {shifted}");
        let taken = bounds_after_refinement(&q, &start, true);
        assert!((taken.rotation_deg - rot.hypot(1.0)).abs() < 1e-9, "{taken:?}");
        assert!((taken.translation_m - trans.hypot(0.003)).abs() < 1e-12, "{taken:?}");
        let kept = bounds_after_refinement(&q, &start, false);
        assert!((kept.rotation_deg - (rot + 1.0)).abs() < 1e-9, "{kept:?}");
        assert!((kept.translation_m - (trans + 0.003)).abs() < 1e-12, "{kept:?}");
        // A refinement that stays put keeps the covariance's bounds.
        let still = bounds_after_refinement(&refinement(start), &start, true);
        assert!((still.rotation_deg - rot).abs() < 1e-12 && (still.translation_m - trans).abs() < 1e-12);
    }
}
