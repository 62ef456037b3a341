//! Direct image alignment: the final pose refined on the two images themselves.
//!
//! Flow pairs fix the pose to what the tracker resolves (about a degree on a turntable pair);
//! the geometry cannot fix the turn about an axis of symmetry at all. The alignment moves the
//! model frame's object pixels (back-projected with their depth) by the pose, projects them into
//! the target frame and minimises, by Gauss-Newton on the pose, two residuals per pixel (the
//! formulation of dense RGB-D odometry, Kerl et al. 2013, and Open3D's hybrid RGB-D odometry):
//! - the target's texture under the pixel ([`crate::high_pass`] grey values) less the
//!   model's times a gain (the ratio of the two textures' contrasts, so that a change of exposure
//!   does not count);
//! - the target's depth under the pixel less the pixel's own depth.
//!
//! Each residual is scaled by a robust estimate of its noise (the median absolute deviation; the
//! depth's at least the sensor's depth step there) and truncated: pixels hidden in one frame,
//! off the object or on a highlight stop counting.
//!
//! Consumer colour cameras expose their rows one after another: when the image motion changes
//! speed between two frames, the target image is sheared (each row shifted in proportion to its
//! height), and a rigid fit on an object's patch takes the shear for a turn. Once the rigid
//! alignment has converged, the shear (sideways and down, pixels per row) is estimated with the
//! pose and kept where a likelihood-ratio test says the frames show it. With
//! [`AlignConfig::symmetric`] the target's pixels are aligned into the model as well and the
//! pose is the midpoint of the two results. The aligned pose is kept only when it lowers the
//! truncated cost and stays within a stated distance of the pose it started from.

use crate::texture::{GradientTexture, ObjectSample, Texture, TextureCache, object_samples, revalued};
use crate::view::ImageView;
use flowfilter_geometry::{ParamError, Point3, Pose, params, se3};
use nalgebra::{SMatrix, SVector, Vector2};
use serde::{Deserialize, Serialize};
use statrs::distribution::{ChiSquared, ContinuousCDF};

/// The alignment's parameters (`[align]` in the pipeline configuration).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AlignConfig {
    /// Align the pose of methods that use flow correspondences.
    pub enabled: bool,
    /// Gauss-Newton iterations at most, per level.
    pub iterations: usize,
    /// The coarse levels: the textures smoothed by a box of each of these half-widths
    /// (pixels) in turn before the textures as they are. Widens the reach of the first steps
    /// beyond a pixel on fine textures.
    pub smoothing_px: Vec<usize>,
    /// Every `stride`-th model pixel in each direction is aligned...
    pub stride: usize,
    /// ... and at most this many of them (evenly thinned on large objects).
    pub max_pixels: usize,
    /// Fewer aligned pixels than this leave the pose as it is.
    pub min_pixels: usize,
    /// Half-width of the box whose mean is taken from the grey values (pixels; see
    /// [`crate::high_pass`]).
    pub texture_radius_px: usize,
    /// A residual beyond this many robust standard deviations stops counting (the pixel is
    /// taken for hidden, off the object or a highlight).
    pub truncation: f64,
    /// The depth residual's noise is taken as at least this (metres): keeps a smooth synthetic
    /// surface from outweighing the texture.
    pub min_depth_noise_m: f64,
    /// ... and at least the depth sensor's resolution at the pixel's depth: one step of its
    /// disparity, this many metres at 1 m, growing with the square of the depth (structured
    /// light and stereo alike). A difference of two quantised depths can be off by a step, and
    /// where most differences fall on the same step their spread (the robust scale) says less.
    pub depth_step_at_1m_m: f64,
    /// ... and at least this many metres per degree the pose turns (0: off): one surface's
    /// depth, read from two views, differs more the further the view turned.
    pub depth_noise_per_deg_m: f64,
    /// The aligned pose may turn at most this far from the pose it started from (degrees): the
    /// judge's candidates are 6 degrees apart, and aligned, the one nearest the true turn must
    /// reach it (3 degrees, half the spacing, left real regions at 25-30 degrees and turntable
    /// pairs short of where their images agree best)...
    pub max_turn_deg: f64,
    /// ... and move its model pixels at most this far (metres); beyond either, the start is
    /// kept.
    pub max_shift_m: f64,
    /// The target colour image's rolling-shutter row shear (pixels of shift per pixel row, both
    /// directions) is estimated with the pose, under a zero-mean Gaussian prior of this standard
    /// deviation; 0 aligns a rigid motion alone. See the module documentation.
    pub row_shear_sd: f64,
    /// Align both ways: the model's pixels into the target and the target's pixels into the
    /// model (from the inverse start); the pose is the two results' midpoint. Each frame's
    /// pixels and noise then count alike.
    pub symmetric: bool,
}

impl Default for AlignConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            iterations: 10,
            smoothing_px: vec![2],
            stride: 1,
            max_pixels: 3000,
            min_pixels: 200,
            texture_radius_px: 4,
            truncation: 3.0,
            min_depth_noise_m: 0.001,
            depth_step_at_1m_m: 0.0029,
            depth_noise_per_deg_m: 0.0,
            max_turn_deg: 6.0,
            max_shift_m: 0.02,
            row_shear_sd: 0.01,
            symmetric: true,
        }
    }
}

impl AlignConfig {
    /// Ranges serde cannot check.
    ///
    /// # Errors
    /// [`ParamError`] naming the key.
    pub fn validate(&self) -> Result<(), ParamError> {
        params::count_positive("iterations", self.iterations)?;
        params::count_positive("stride", self.stride)?;
        params::count_positive("min_pixels", self.min_pixels)?;
        params::require(self.max_pixels >= self.min_pixels, "max_pixels", "at least min_pixels", self.max_pixels)?;
        params::positive("truncation", self.truncation)?;
        params::positive("min_depth_noise_m", self.min_depth_noise_m)?;
        params::non_negative("depth_step_at_1m_m", self.depth_step_at_1m_m)?;
        params::non_negative("depth_noise_per_deg_m", self.depth_noise_per_deg_m)?;
        params::positive("max_turn_deg", self.max_turn_deg)?;
        params::positive("max_shift_m", self.max_shift_m)?;
        params::non_negative("row_shear_sd", self.row_shear_sd)
    }
}

/// What the alignment did on one pair (reported in the estimate).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AlignReport {
    /// Model pixels aligned.
    pub pixels: usize,
    /// Gauss-Newton iterations run.
    pub iterations: usize,
    /// The truncated cost per pixel at the start and at the aligned pose.
    pub cost_before: f64,
    /// See `cost_before`.
    pub cost_after: f64,
    /// How far the alignment turned the pose (degrees; 0 when the start was kept)...
    pub turn_deg: f64,
    /// ... and changed its translation (metres).
    pub shift_m: f64,
    /// The target colour image's row shear estimated with the pose (pixels per pixel row, x
    /// and y; 0 when the start was kept or `row_shear_sd` is 0).
    pub row_shear_px_per_row: [f64; 2],
    /// Whether the aligned pose replaced the start.
    pub accepted: bool,
}

/// The target as the residuals read it.
struct TargetView<'a> {
    frame: ImageView<'a>,
    texture: GradientTexture,
    /// The row the shear turns about: the model object's mean row.
    row0: f64,
    /// How many samples share one texture box (its area over the samples' spacing squared, at
    /// least 1): their residuals are counted once per box where independence matters (the
    /// shear's prior and its test).
    shared: f64,
}

/// The 95% quantile of a chi-square with `dof` degrees of freedom: what the shear's evidence
/// must exceed (2 degrees of freedom one way, 4 both ways).
fn chi_square_95(dof: f64) -> f64 {
    ChiSquared::new(dof).map_or(f64::INFINITY, |c| c.inverse_cdf(0.95))
}

/// A descent ends after a step smaller than this (twist in radians and metres, shear in pixels
/// per row): 0.006 degrees, 0.1 mm, 0.02 px over 200 rows. Below it the truncated cost's steps
/// dither (accepted and refused in turn) without moving the pose: on a whole shelf frame the
/// descents ran to their 10 iterations each at 1e-5; the default protocol's mean error moved
/// by 0.0003 deg.
const CONVERGED_STEP: f64 = 1e-4;

/// The unknowns' count: a left twist `(rho, phi)` of the pose, then the row shear.
const DOF: usize = 8;

/// A step or Jacobian row over the unknowns.
type Step = SVector<f64, DOF>;

/// What the alignment moves: the pose, and the target colour image's row shear (pixels of
/// shift per pixel row, x and y, about the model object's mean row).
#[derive(Debug, Clone, Copy)]
struct State {
    pose: Pose,
    shear: Vector2<f64>,
    /// Whether the shear is an unknown (else it stays at 0).
    free_shear: bool,
}

impl State {
    /// `pose` with no shear, and the shear held at 0.
    fn rigid(pose: Pose) -> Self {
        Self { pose, shear: Vector2::zeros(), free_shear: false }
    }

    /// `pose` with no shear yet, the shear free.
    fn sheared(pose: Pose) -> Self {
        Self { free_shear: true, ..Self::rigid(pose) }
    }

    /// The state moved by `step`.
    fn stepped(&self, step: &Step) -> Self {
        let twist = step.fixed_rows::<6>(0).into_owned();
        Self { pose: se3::exp(&twist) * self.pose, shear: self.shear + step.fixed_rows::<2>(6), ..*self }
    }
}

/// One pixel's residuals and their Jacobians with respect to the state (a left twist
/// `(rho, phi)`, then the shear).
struct Residuals {
    texture: f64,
    texture_jacobian: Step,
    depth: Option<(f64, Step)>,
    /// The moved point's depth (what the depth noise grows with).
    z: f64,
}

/// Robust noise scales of the two residuals and the texture's gain (see [`Aligner::scales`]).
#[derive(Debug, Clone, Copy)]
pub struct Scales {
    texture: f64,
    depth: f64,
    gain: f64,
}

/// The two frames prepared for direct alignment at one smoothing of their textures: the
/// model's samples and the target's texture.
pub struct Aligner<'a> {
    samples: Vec<ObjectSample>,
    view: TargetView<'a>,
    cfg: &'a AlignConfig,
}

/// Where a descent ended.
struct Descent {
    state: State,
    iterations: usize,
}

/// The rigid descent and, when the shear is estimated, the sheared one after it with its
/// evidence ([`Aligner::shear_evidence`]).
struct Descents {
    rigid: Descent,
    sheared: Option<(Descent, f64)>,
}

impl Descents {
    /// The sheared descent's evidence for its shear (0 without one).
    fn shear_evidence(&self) -> f64 {
        self.sheared.as_ref().map_or(0.0, |(_, z2)| *z2)
    }

    /// The sheared descent when `keep_shear` (and there is one), else the rigid one; its
    /// iterations count both.
    fn chosen(self, keep_shear: bool) -> Descent {
        let spent = self.rigid.iterations + self.sheared.as_ref().map_or(0, |(d, _)| d.iterations);
        let d = match self.sheared {
            Some((d, _)) if keep_shear => d,
            _ => self.rigid,
        };
        Descent { iterations: spent, ..d }
    }
}

impl<'a> Aligner<'a> {
    /// The frames with their textures smoothed by a box of half-width `smoothing_px` (0: as
    /// they are); `None` when the model has fewer than `cfg.min_pixels` object pixels with
    /// depth.
    pub fn new(
        model: &ImageView<'_>,
        target: &ImageView<'a>,
        cfg: &'a AlignConfig,
        smoothing_px: usize,
    ) -> Option<Self> {
        let r = cfg.texture_radius_px;
        let samples = samples(model, &model.texture(r, smoothing_px), cfg);
        Self::with_samples(samples, target, target.gradient_texture(r, smoothing_px), cfg)
    }

    /// [`Aligner::new`] with the model's samples (and their spacing, pixels) and the target's
    /// texture at its level already computed.
    fn with_samples(
        (samples, spacing): (Vec<ObjectSample>, f64),
        target: &ImageView<'a>,
        texture: GradientTexture,
        cfg: &'a AlignConfig,
    ) -> Option<Self> {
        let shared = ((2 * cfg.texture_radius_px + 1) as f64 / spacing).powi(2).max(1.0);
        let row0 = samples.iter().map(|s| s.row as f64).sum::<f64>() / samples.len().max(1) as f64;
        (samples.len() >= cfg.min_pixels).then_some(Self {
            samples,
            view: TargetView { frame: *target, texture, row0, shared },
            cfg,
        })
    }

    /// The residuals' noise scales at `pose`; `None` when too few pixels are visible in both
    /// frames or the texture is flat there.
    pub fn scales(&self, pose: &Pose) -> Option<Scales> {
        scales(&self.samples, &self.view, &State::rigid(*pose), self.cfg)
    }

    /// The residuals' robust noise at `pose`: texture (high-passed grey values, after the gain)
    /// and depth (metres); `None` as [`Aligner::scales`].
    pub fn noise(&self, pose: &Pose) -> Option<(f64, f64)> {
        self.scales(pose).map(|s| (s.texture, s.depth))
    }

    /// The truncated cost per pixel of `pose` (the target image taken as unsheared) with the
    /// scales `sc`.
    pub fn cost(&self, pose: &Pose, sc: Scales) -> f64 {
        self.state_cost(&State::rigid(*pose), sc)
    }

    /// The truncated cost per pixel of `state`, its shear's prior included.
    fn state_cost(&self, state: &State, sc: Scales) -> f64 {
        cost(&self.samples, &self.view, state, sc, self.cfg) / self.samples.len() as f64
    }

    /// Damped Gauss-Newton from `start` with the scales `sc`, while it lowers the cost.
    fn descend(&self, start: &State, sc: Scales) -> Descent {
        let cfg = self.cfg;
        let (mut state, mut current, mut lambda, mut iterations) = (*start, self.state_cost(start, sc), 1e-4, 0);
        // The normal equations change only with the state: a refused step re-solves them with
        // more damping.
        let mut normal = normal_equations(&self.samples, &self.view, &state, sc, cfg);
        while iterations < cfg.iterations {
            iterations += 1;
            let Some(step) = damped_step(&normal, lambda) else { break };
            let trial = state.stepped(&step);
            let c = self.state_cost(&trial, sc);
            if c < current {
                (state, current, lambda) = (trial, c, (lambda * 0.3).max(1e-6));
                if step.norm() < CONVERGED_STEP {
                    break;
                }
                normal = normal_equations(&self.samples, &self.view, &state, sc, cfg);
            } else {
                lambda *= 10.0;
                if lambda > 1e3 || step.norm() < CONVERGED_STEP {
                    break;
                }
            }
        }
        Descent { state, iterations }
    }

    /// The likelihood ratio of a sheared state against a rigid one: the drop of the truncated
    /// cost (in units of the residuals' noise), the residuals counted once per texture box (as
    /// in the prior). Twice the log-likelihood ratio of nested models: a chi-square with as many
    /// degrees of freedom as the shear adds where the frames show no shear.
    fn shear_evidence(&self, rigid: &State, sheared: &State, sc: Scales) -> f64 {
        let drop = self.state_cost(rigid, sc) - self.state_cost(sheared, sc);
        drop * self.samples.len() as f64 / self.view.shared
    }

    /// Pixels aligned.
    pub fn pixels(&self) -> usize {
        self.samples.len()
    }
}

/// Align `start` (model to target, colour camera frame) by direct alignment, coarse to fine
/// (the textures smoothed by each of `cfg.smoothing_px` in turn, then as they are); the
/// aligned pose (or `start` when it is not kept: a higher cost at the finest level, with the
/// scales of the start, or a move beyond `max_turn_deg` / `max_shift_m`) and the report. `None`
/// when too few pixels can be aligned or the texture is flat.
///
/// ```
/// use flowfilter_camera::{CameraModel, Distortion, ImageSize, Intrinsics, RayTable};
/// use flowfilter_geometry::{Grid, Pose};
/// use flowfilter_photometric::{AlignConfig, ImageView, align};
///
/// let camera = CameraModel::new(Intrinsics::new(525.0, 525.0, 160.0, 120.0)?, Distortion::from_slice(&[0.0; 5])?, ImageSize::new(320, 240)?);
/// let rays = RayTable::new(&camera);
/// // A textured wall 0.6 m in front of the camera, then the same wall 3 mm to the right.
/// let wall = |x: f64, y: f64| (0.5 + 0.2 * (x * 0.23).sin() * (y * 0.19).cos() + 0.1 * (x * 0.07 + y * 0.05).sin()) as f32;
/// let shift_px = 525.0 * 0.003 / 0.6;
/// let model_gray = Grid::from_fn(320, 240, |x, y| wall(x as f64, y as f64));
/// let target_gray = Grid::from_fn(320, 240, |x, y| wall(x as f64 - shift_px, y as f64));
/// let depth = Grid::filled(320, 240, 0.6f32);
/// let mask = Grid::from_fn(320, 240, |x, y| (60..260).contains(&x) && (40..200).contains(&y));
/// let view = |gray| ImageView { gray, depth: &depth, mask: &mask, rays: &rays, camera: &camera, textures: None };
/// let (pose, report) = align(&view(&model_gray), &view(&target_gray), &Pose::identity(), &AlignConfig::default()).expect("textured");
/// assert!(report.accepted);
/// assert!((pose.translation.vector - nalgebra::Vector3::new(0.003, 0.0, 0.0)).norm() < 3e-4);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn align(
    model: &ImageView<'_>,
    target: &ImageView<'_>,
    start: &Pose,
    cfg: &AlignConfig,
) -> Option<(Pose, AlignReport)> {
    if !cfg.symmetric {
        return Alignment::new(model, target, cfg)?.run(start);
    }
    // Each frame's textures serve both ways (from its cache, or one made for this call),
    // computed side by side first; the two ways run side by side (each step of either is the
    // same whatever the thread count).
    let (model_cache, target_cache) = (TextureCache::new(), TextureCache::new());
    let (model, target) = (&model.or_cache(&model_cache), &target.or_cache(&target_cache));
    rayon::join(|| prepare_textures(model, cfg), || prepare_textures(target, cfg));
    let (forward, backward) = rayon::join(|| Alignment::new(model, target, cfg), || Alignment::new(target, model, cfg));
    let forward = forward?;
    let Some(backward) = backward else {
        return forward.run(start);
    };
    let back_start = start.inverse();
    let (Some(fwd_scales), Some(bwd_scales)) = (forward.fine.scales(start), backward.fine.scales(&back_start)) else {
        return forward.run(start);
    };
    // The shear is kept both ways or neither, on the evidence of both.
    let (fd, bd) = rayon::join(|| forward.descents(start, fwd_scales), || backward.descents(&back_start, bwd_scales));
    let keep = fd.shear_evidence() + bd.shear_evidence() > chi_square_95(4.0);
    let ((forward_pose, report), (back_pose, back_report)) = rayon::join(
        || forward.finish(start, fwd_scales, fd.chosen(keep)),
        || backward.finish(&back_start, bwd_scales, bd.chosen(keep)),
    );
    let back = back_report.accepted.then(|| back_pose.inverse());
    let pose = match back {
        Some(back) if report.accepted => midpoint(&forward_pose, &back),
        Some(back) => back,
        None => forward_pose,
    };
    let shear = Vector2::from(report.row_shear_px_per_row);
    let cost_after = forward.fine.state_cost(&State { pose, shear, free_shear: shear != Vector2::zeros() }, fwd_scales);
    Some((pose, summarised(report, start, &pose, cost_after)))
}

/// The geodesic midpoint of two poses.
fn midpoint(a: &Pose, b: &Pose) -> Pose {
    se3::exp(&(se3::log(&(b * a.inverse())) * 0.5)) * a
}

/// The forward alignment's report for the pose `pose` both ways came to: its move from `start`,
/// the forward cost there (`cost_after`), accepted when either way was.
fn summarised(forward: AlignReport, start: &Pose, pose: &Pose, cost_after: f64) -> AlignReport {
    let moved = pose != start;
    AlignReport {
        turn_deg: (pose * start.inverse()).rotation.angle().to_degrees(),
        shift_m: (pose.translation.vector - start.translation.vector).norm(),
        cost_after: if moved { cost_after } else { forward.cost_before },
        accepted: forward.accepted || moved,
        ..forward
    }
}

/// The two frames prepared for [`align`] at every level, to align several starts.
pub struct Alignment<'a> {
    coarse: Vec<Aligner<'a>>,
    fine: Aligner<'a>,
    cfg: &'a AlignConfig,
}

impl<'a> Alignment<'a> {
    /// The levels of `cfg`; `None` when the model has fewer than `cfg.min_pixels` object
    /// pixels with depth.
    ///
    /// The frames' textures come from their caches ([`ImageView::textures`]); a frame without
    /// one gets one for this call, so each of its textures is computed once here.
    pub fn new(model: &ImageView<'_>, target: &ImageView<'a>, cfg: &'a AlignConfig) -> Option<Self> {
        let (model_cache, target_cache) = (TextureCache::new(), TextureCache::new());
        let (m, t) = (model.or_cache(&model_cache), target.or_cache(&target_cache));
        let r = cfg.texture_radius_px;
        // The model's pixels are the same at every level, their values each level's.
        let (fine_samples, spacing) = samples(&m, &m.texture(r, 0), cfg);
        let level = |s: usize| {
            let at_level = if s == 0 { fine_samples.clone() } else { revalued(&fine_samples, &m.texture(r, s)) };
            Aligner::with_samples((at_level, spacing), target, t.gradient_texture(r, s), cfg)
        };
        let fine = level(0)?;
        let coarse = cfg.smoothing_px.iter().filter(|s| **s > 0).filter_map(|&s| level(s)).collect();
        Some(Self { coarse, fine, cfg })
    }

    /// Every level's descent in turn from `start`.
    fn descend_levels(&self, start: State, judged_by: Scales) -> Descent {
        let (fine, cfg) = (&self.fine, self.cfg);
        let (mut state, mut iterations) = (start, 0);
        for coarse in &self.coarse {
            let Some(sc) = scales(&coarse.samples, &coarse.view, &state, cfg) else { continue };
            let d = coarse.descend(&state, sc);
            (state, iterations) = (d.state, iterations + d.iterations);
        }
        let sc = scales(&fine.samples, &fine.view, &state, cfg).unwrap_or(judged_by);
        let d = fine.descend(&state, sc);
        Descent { state: d.state, iterations: iterations + d.iterations }
    }

    /// [`align`] from `start`, one way: the shear is kept when the frames show it
    /// (the shear evidence beyond the 95% quantile of a chi-square with 2 degrees of
    /// freedom), else the rigid alignment is.
    pub fn run(&self, start: &Pose) -> Option<(Pose, AlignReport)> {
        let judged_by = self.fine.scales(start)?;
        let d = self.descents(start, judged_by);
        let keep = d.shear_evidence() > chi_square_95(2.0);
        Some(self.finish(start, judged_by, d.chosen(keep)))
    }

    /// The rigid descent through every level from `start`, then (when `row_shear_sd` is not 0)
    /// every level again from its pose with the shear free (the finest level alone lands up to
    /// 0.015 deg further from the truth on the real sample). The shear is freed only once
    /// the pose is aligned: from a pose still off, a stretch of the rows would take up part of
    /// a tilt.
    fn descents(&self, start: &Pose, judged_by: Scales) -> Descents {
        let rigid = self.descend_levels(State::rigid(*start), judged_by);
        let sheared = (self.cfg.row_shear_sd > 0.0).then(|| {
            let d = self.descend_levels(State::sheared(rigid.state.pose), judged_by);
            let evidence = self.fine.shear_evidence(&rigid.state, &d.state, judged_by);
            (d, evidence)
        });
        Descents { rigid, sheared }
    }

    /// The aligned pose and report from `descent`: kept when it lowers the cost and stays
    /// within the stated move.
    fn finish(&self, start: &Pose, judged_by: Scales, descent: Descent) -> (Pose, AlignReport) {
        let (fine, cfg) = (&self.fine, self.cfg);
        let (state, iterations) = (descent.state, descent.iterations);
        let pose = state.pose;
        let (cost_before, cost_after) = (fine.cost(start, judged_by), fine.state_cost(&state, judged_by));
        let turn_deg = (pose * start.inverse()).rotation.angle().to_degrees();
        let shift = fine.samples.iter().map(|s| (pose * s.point - start * s.point).norm()).fold(0.0, f64::max);
        let accepted = cost_after < cost_before && turn_deg <= cfg.max_turn_deg && shift <= cfg.max_shift_m;
        let pose = if accepted { pose } else { *start };
        let report = AlignReport {
            pixels: fine.pixels(),
            iterations,
            cost_before,
            cost_after: if accepted { cost_after } else { cost_before },
            turn_deg: if accepted { turn_deg } else { 0.0 },
            shift_m: (pose.translation.vector - start.translation.vector).norm(),
            row_shear_px_per_row: if accepted { [state.shear.x, state.shear.y] } else { [0.0; 2] },
            accepted,
        };
        (pose, report)
    }
}

/// Compute into `frame`'s [`crate::TextureCache`] the textures an alignment with `cfg` reads:
/// at every level (as they are, then smoothed by each non-zero `cfg.smoothing_px` in turn), with
/// their gradients. A caller with time to spare on one thread (beside a registration) spends it
/// here; the alignment then finds them built. Without a cache the work is lost.
pub fn prepare_textures(frame: &ImageView<'_>, cfg: &AlignConfig) {
    let levels = std::iter::once(0).chain(cfg.smoothing_px.iter().copied().filter(|s| *s > 0));
    for s in levels {
        frame.gradient_texture(cfg.texture_radius_px, s);
    }
}

/// The model's object pixels with depth (every `stride`-th, thinned to `max_pixels`), with
/// their value in `texture`, and the samples' spacing (pixels).
fn samples(model: &ImageView<'_>, texture: &Texture, cfg: &AlignConfig) -> (Vec<ObjectSample>, f64) {
    let (samples, every) = object_samples(model, texture, cfg.stride, cfg.max_pixels);
    (samples, cfg.stride as f64 * (every as f64).sqrt())
}

impl TargetView<'_> {
    /// The residuals of one model pixel moved by `pose`; `None` where it leaves the target's
    /// texture.
    fn residuals(&self, s: &ObjectSample, state: &State, gain: f64) -> Option<Residuals> {
        let camera = &self.frame.camera;
        let q = state.pose * s.point;
        let (px, jp) = camera.project_with_jacobian(&q)?;
        let lean = px.y - self.row0;
        let (sx, sy) = (px.x + state.shear.x * lean, px.y + state.shear.y * lean);
        let (b, gx, gy) = self.texture.bilinear_gradient(sx, sy)?;
        let dq = point_twist_jacobian(&q);
        let image = jp * dq; // 2x6: the pixel's motion per twist
        // The sheared pixel's motion: its row moves its shift too.
        let (gx_pose, gy_pose) = (gx, gx * state.shear.x + gy * (1.0 + state.shear.y));
        let mut texture_jacobian = Step::zeros();
        texture_jacobian
            .fixed_rows_mut::<6>(0)
            .copy_from(&(image.row(0) * gx_pose + image.row(1) * gy_pose).transpose());
        if state.free_shear {
            texture_jacobian[6] = gx * lean;
            texture_jacobian[7] = gy * lean;
        }
        let depth = self.depth_at(px.x, px.y).map(|(z, dzx, dzy)| {
            let mut j = Step::zeros();
            j.fixed_rows_mut::<6>(0).copy_from(&(image.row(0) * dzx + image.row(1) * dzy - dq.row(2)).transpose());
            (z - q.z, j)
        });
        Some(Residuals { texture: b - gain * s.value, texture_jacobian, depth, z: q.z })
    }

    /// The residuals of [`TargetView::residuals`] without their Jacobians (what the cost reads:
    /// a sixth of the projections): texture, depth, and the moved point's depth.
    fn values(&self, s: &ObjectSample, state: &State, gain: f64) -> Option<(f64, Option<f64>, f64)> {
        let q = state.pose * s.point;
        let px = self.frame.camera.project(&q)?;
        let lean = px.y - self.row0;
        let b =
            self.texture.bilinear_with_gradient_support(px.x + state.shear.x * lean, px.y + state.shear.y * lean)?;
        Some((b - gain * s.value, self.depth_at(px.x, px.y).map(|(z, _, _)| z - q.z), q.z))
    }

    /// The target's depth at `(x, y)` (bilinear) and its gradient, where the four pixels
    /// around have depth on one surface (no jump larger than 1 cm between them).
    fn depth_at(&self, x: f64, y: f64) -> Option<(f64, f64, f64)> {
        let d = &self.frame.depth;
        let (w, h) = d.dims();
        if x < 0.0 || y < 0.0 {
            return None;
        }
        // Not negative: the truncation is the floor (without a libm call on baseline x86-64).
        let (x0, y0) = (x as usize, y as usize);
        if x0 + 1 >= w || y0 + 1 >= h {
            return None;
        }
        let z = |xx: usize, yy: usize| f64::from(*d.at(xx, yy));
        let (z00, z10, z01, z11) = (z(x0, y0), z(x0 + 1, y0), z(x0, y0 + 1), z(x0 + 1, y0 + 1));
        let (lo, hi) = (z00.min(z10).min(z01).min(z11), z00.max(z10).max(z01).max(z11));
        if lo <= 0.0 || hi - lo > 0.01 {
            return None;
        }
        let (fx, fy) = (x - x0 as f64, y - y0 as f64);
        let top = z00 + (z10 - z00) * fx;
        let bottom = z01 + (z11 - z01) * fx;
        let value = top + (bottom - top) * fy;
        let dzx = (z10 - z00) * (1.0 - fy) + (z11 - z01) * fy;
        let dzy = bottom - top;
        Some((value, dzx, dzy))
    }
}

/// d(exp(xi) q)/d(xi) at xi = 0 for a twist `(rho, phi)`: `[I | -[q]x]`.
fn point_twist_jacobian(q: &Point3) -> nalgebra::Matrix3x6<f64> {
    let mut j = nalgebra::Matrix3x6::zeros();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&nalgebra::Matrix3::identity());
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-q.coords.cross_matrix()));
    j
}

/// The residuals' robust noise scales and the texture gain at `pose`; `None` when too few
/// pixels land on the target or its texture is flat there.
fn scales(samples: &[ObjectSample], view: &TargetView<'_>, state: &State, cfg: &AlignConfig) -> Option<Scales> {
    // (target texture, model texture, depth residual) of the pixels visible in both: the
    // target's depth agrees within the depth of field of a turntable object (a hidden pixel
    // lies behind the target's surface by more).
    let visible: Vec<(f64, f64, f64)> = samples
        .iter()
        .filter_map(|s| {
            let (b, d, _) = view.values(s, state, 0.0)?;
            d.filter(|d| d.abs() < 0.01).map(|d| (b, s.value, d))
        })
        .collect();
    if visible.len() < cfg.min_pixels {
        return None;
    }
    // The exposure's gain as the ratio of the textures' contrasts (not their regression, which
    // falls to zero when the start is a pixel or two off and the textures do not yet overlap).
    let (sbb, saa) = visible.iter().fold((0.0, 0.0), |(bb, aa), (b, a, _)| (bb + b * b, aa + a * a));
    if saa <= 1e-12 || sbb <= 1e-12 {
        return None;
    }
    let gain = (sbb / saa).sqrt();
    let texture = mad(visible.iter().map(|(b, a, _)| b - gain * a).collect());
    let turned = cfg.depth_noise_per_deg_m * state.pose.rotation.angle().to_degrees();
    let depth = mad(visible.iter().map(|(_, _, d)| *d).collect()).max(cfg.min_depth_noise_m).max(turned);
    (texture > 1e-9).then_some(Scales { texture, depth, gain })
}

/// 1.4826 times the median absolute deviation from the median.
fn mad(mut v: Vec<f64>) -> f64 {
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    if v.is_empty() {
        return 0.0;
    }
    let m = median(&mut v);
    let mut dev: Vec<f64> = v.iter().map(|x| (x - m).abs()).collect();
    1.4826 * median(&mut dev)
}

/// The truncated cost of `state`: each residual squared in units of its scale, at most
/// `truncation^2` (a pixel that leaves the target counts the cap for both), and the shear's
/// prior.
fn cost(samples: &[ObjectSample], view: &TargetView<'_>, state: &State, sc: Scales, cfg: &AlignConfig) -> f64 {
    let cap = cfg.truncation * cfg.truncation;
    shear_prior(state, cfg, view.shared).0
        + samples
            .iter()
            .map(|s| match view.values(s, state, sc.gain) {
                None => 2.0 * cap,
                Some((texture, depth, z)) => {
                    let t = (texture / sc.texture).powi(2).min(cap);
                    let d = depth.map_or(cap, |d| (d / depth_scale(sc, cfg, z)).powi(2).min(cap));
                    t + d
                }
            })
            .sum::<f64>()
}

/// The Levenberg-Marquardt step of the normal equations `(h, g)` with damping `lambda`; `None`
/// when they are singular.
fn damped_step((h, g): &(SMatrix<f64, DOF, DOF>, Step), lambda: f64) -> Option<Step> {
    let damped = h + SMatrix::<f64, DOF, DOF>::from_diagonal(&h.diagonal()) * lambda;
    damped.cholesky().map(|c| -c.solve(g))
}

/// The Gauss-Newton normal equations `(J^T W J, J^T W r)` at `state`, over the residuals within
/// the truncation and the shear's prior.
fn normal_equations(
    samples: &[ObjectSample],
    view: &TargetView<'_>,
    state: &State,
    sc: Scales,
    cfg: &AlignConfig,
) -> (SMatrix<f64, DOF, DOF>, Step) {
    let (mut h, mut g) = (SMatrix::<f64, DOF, DOF>::zeros(), Step::zeros());
    for r in samples.iter().filter_map(|s| view.residuals(s, state, sc.gain)) {
        let mut add = |res: f64, jac: &Step, scale: f64| {
            if (res / scale).abs() <= cfg.truncation {
                let w = 1.0 / (scale * scale);
                // The lower triangle in place (the upper is filled once, below).
                h.syger(w, jac, jac, 1.0);
                g.axpy(res * w, jac, 1.0);
            }
        };
        // Without depth under it the pixel is off the target's surface.
        let Some((d, jd)) = &r.depth else { continue };
        let scale = depth_scale(sc, cfg, r.z);
        if (d / scale).abs() > cfg.truncation {
            continue; // hidden in one of the frames: its texture is another surface's
        }
        add(*d, jd, scale);
        add(r.texture, &r.texture_jacobian, sc.texture);
    }
    h.fill_upper_triangle_with_lower_triangle();
    match shear_prior(state, cfg, view.shared).1 {
        Some(w) => {
            for k in 6..DOF {
                h[(k, k)] += w;
                g[k] += w * state.shear[k - 6];
            }
        }
        None => {
            // A rigid alignment: the shear is not an unknown (its Jacobian columns are 0 and it
            // stays at 0).
            h[(6, 6)] = 1.0;
            h[(7, 7)] = 1.0;
        }
    }
    (h, g)
}

/// The depth residual's noise at depth `z`: the robust scale, at least the sensor's resolution
/// there.
fn depth_scale(sc: Scales, cfg: &AlignConfig, z: f64) -> f64 {
    sc.depth.max(cfg.depth_step_at_1m_m * z * z)
}

/// The shear's prior: its cost, and its weight (`None` when the shear is not estimated).
fn shear_prior(state: &State, cfg: &AlignConfig, shared: f64) -> (f64, Option<f64>) {
    if !state.free_shear || cfg.row_shear_sd <= 0.0 {
        return (0.0, None);
    }
    // The residuals of neighbouring pixels share their texture's box mean: about one in
    // (2r + 1)^2 / stride^2 says something of its own, and the prior weighs as much against
    // them.
    let w = shared / (cfg.row_shear_sd * cfg.row_shear_sd);
    (state.shear.norm_squared() * w, Some(w))
}
