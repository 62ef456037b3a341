//! The photometric judge: when the object may have turned further than the flow followed.
//!
//! Flow and geometry both fail towards "no motion" on an object whose silhouette and shading
//! stay put while it turns (cans, bottles, mugs at 20-30 degree steps). The surface's texture
//! does turn with it. After the registration, the judge takes the
//! poses the clouds allow ([`TurnHypotheses`]: the answer turned about the model's normal-scatter
//! axes, kept where the clouds still fit) and scores each by photometric consistency: the model
//! frame's object pixels, back-projected with their depth, moved by the pose and projected into
//! the target frame, compared with the target's grey values where the target's depth agrees
//! (pixels visible in both). The score is one minus the normalised cross-correlation, so a
//! change of exposure (gain and offset) does not count. When a candidate agrees clearly better
//! than the answer, the flow is tracked again from it and the registration re-run; the result
//! replaces the answer if its own photometric score is the better one.

use crate::gate::JudgeGate;
use crate::texture::{ObjectSample, Texture, object_samples};
use crate::turns::{TurnCandidate, TurnHypotheses, TurnSweepConfig};
use crate::view::ImageView;
use flowfilter_geometry::{ParamError, Pose, params};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// The judge's parameters (`[judge]` in the pipeline configuration).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct JudgeConfig {
    /// Run the judge after methods that use flow correspondences.
    pub enabled: bool,
    /// When the judge is skipped: the flow settled on a small answer ([`crate::gate`]).
    pub gate: JudgeGate,
    /// The candidate sweep.
    pub sweep: TurnSweepConfig,
    /// The fine sweep around the best coarse candidate: step (degrees).
    pub fine_step_deg: f64,
    /// ... and reach on either side (degrees).
    pub fine_reach_deg: f64,
    /// A candidate is tried when its score is below this fraction of the answer's. Lower
    /// keeps more answers the flow found (and more of its failures); higher re-tracks more
    /// pairs (each costs a guided flow pass and a registration).
    pub ratio: f64,
    /// Every `stride`-th model pixel in each direction is compared...
    pub stride: usize,
    /// ... and at most this many of them (evenly thinned on large objects).
    pub max_pixels: usize,
    /// A moved model pixel counts as visible in the target when the target's depth there is
    /// within this of its own (metres).
    pub depth_agreement_m: f64,
    /// Fewer compared pixels than this give no score.
    pub min_pixels: usize,
    /// Another pose is as good as the estimate when its score exceeds the estimate's by at most
    /// this (scores are 1 - correlation): the pipeline's `ambiguous_pose` warning then
    /// names it. Larger warns on objects whose texture tells the poses apart only weakly;
    /// smaller misses a plain object, whose turned candidates, a little off its axis, match its
    /// edges a little worse than the estimate.
    pub ambiguity_tolerance: f64,
    /// ... and when it is turned at least this far from the estimate (degrees).
    pub ambiguity_min_turn_deg: f64,
    /// Half-width of the box whose mean is taken from the grey values before comparing
    /// (pixels; see [`crate::high_pass`]).
    pub texture_radius_px: usize,
    /// Align every coarse candidate and the answer on the images ([`crate::align()`]) before
    /// comparing them: a candidate a few degrees off the true turn scores like any wrong pose
    /// (the score's basin is 3-6 degrees wide), aligned it scores like the truth.
    pub align_candidates: bool,
    /// The candidates' alignment uses at most this many model pixels...
    pub candidate_pixels: usize,
    /// ... and at most this many Gauss-Newton steps per level (the rest of `[align]` as
    /// configured).
    pub candidate_iterations: usize,
    /// Where a geometric check overruled the flow's result (the clouds alone fit as well from
    /// the initial pose), weigh the two on the images, each aligned as the candidates are, and
    /// keep the flow's when it matches clearly better (its score below [`JudgeConfig::ratio`]
    /// times the other's). A surface whose shape fits several poses (a tote's walls, a poster's
    /// plane and its bin) lets the clouds move anywhere; its texture does not.
    pub weigh_overruled_flow: bool,
    /// ... and only when the flow's aligned score is at most this: the images confirm it, as
    /// they must a scene's geometric answer (`[geometry_first] max_score`), not merely prefer
    /// it to a worse one.
    pub restore_max_score: f64,
}

impl Default for JudgeConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            gate: JudgeGate::default(),
            sweep: TurnSweepConfig::default(),
            fine_step_deg: 1.0,
            fine_reach_deg: 4.0,
            ratio: 0.8,
            stride: 2,
            max_pixels: 4000,
            depth_agreement_m: 0.01,
            min_pixels: 100,
            texture_radius_px: 4,
            ambiguity_tolerance: 0.05,
            ambiguity_min_turn_deg: 12.0,
            align_candidates: true,
            candidate_pixels: 400,
            candidate_iterations: 5,
            weigh_overruled_flow: true,
            restore_max_score: 0.5,
        }
    }
}

impl JudgeConfig {
    /// Ranges serde cannot check.
    ///
    /// # Errors
    /// [`ParamError`] naming the key.
    pub fn validate(&self) -> Result<(), ParamError> {
        params::positive("fine_step_deg", self.fine_step_deg)?;
        params::non_negative("fine_reach_deg", self.fine_reach_deg)?;
        params::require(self.ratio > 0.0 && self.ratio <= 1.0, "ratio", "in (0, 1]", self.ratio)?;
        params::count_positive("stride", self.stride)?;
        params::count_positive("min_pixels", self.min_pixels)?;
        params::require(self.max_pixels >= self.min_pixels, "max_pixels", "at least min_pixels", self.max_pixels)?;
        params::positive("depth_agreement_m", self.depth_agreement_m)?;
        params::non_negative("ambiguity_tolerance", self.ambiguity_tolerance)?;
        params::non_negative("ambiguity_min_turn_deg", self.ambiguity_min_turn_deg)?;
        params::count_positive("candidate_pixels", self.candidate_pixels)?;
        params::count_positive("candidate_iterations", self.candidate_iterations)?;
        params::positive("restore_max_score", self.restore_max_score)?;
        self.gate.validate().map_err(|e| e.within("gate"))?;
        self.sweep.validate().map_err(|e| e.within("sweep"))
    }
}

/// What the judge saw on one pair (reported in the estimate).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JudgeReport {
    /// The answer's photometric score (1 - normalised cross-correlation; lower agrees better).
    pub answer_score: f64,
    /// Candidates that fit the clouds well enough.
    pub candidates: usize,
    /// The best candidate's score and turn (degrees about axis `best_axis` of [`TurnHypotheses::axes`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub best_score: Option<f64>,
    /// See `best_score`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub best_turn_deg: Option<f64>,
    /// See `best_score`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub best_axis: Option<usize>,
    /// The re-tracked result's score, when a candidate was tried.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub retracked_score: Option<f64>,
    /// Whether the re-tracked result replaced the answer.
    pub replaced: bool,
    /// The registration's answer before the judge (4x4 row-major, as `transform`).
    pub answer_transform: [[f64; 4]; 4],
    /// The answer's score after the candidates' alignment (`align_candidates`), what aligned
    /// candidates are compared with.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub aligned_answer_score: Option<f64>,
    /// Whether the replacement is an aligned candidate (`align_candidates`) rather than a
    /// re-tracked result; `retracked_score` and `retracked_transform` are then its own.
    #[serde(default)]
    pub aligned_candidate: bool,
    /// The re-tracked result, when a candidate was tried (whether or not it replaced the
    /// answer).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub retracked_transform: Option<[[f64; 4]; 4]>,
}

/// What the scores compare, prepared once per judgement: the model's object pixels (every
/// `stride`-th, with depth) back-projected with their texture, and the target's texture.
pub struct Textures<'a> {
    target: ImageView<'a>,
    samples: Vec<ObjectSample>,
    target_texture: std::sync::Arc<Texture>,
}

impl<'a> Textures<'a> {
    /// The samples of `model` and the texture of `target` ([`crate::high_pass`] with `cfg`'s radius).
    pub fn new(model: &ImageView<'_>, target: &ImageView<'a>, cfg: &JudgeConfig) -> Self {
        let r = cfg.texture_radius_px;
        let (samples, _) = object_samples(model, &model.texture(r, 0), cfg.stride, cfg.max_pixels);
        Self { target: *target, samples, target_texture: target.texture(r, 0) }
    }
}

/// One minus the normalised cross-correlation of the model's object pixels moved by `pose` and
/// the target's texture under them, over the pixels visible in both (the target's depth there
/// agrees with the moved pixel's); `None` with fewer than `cfg.min_pixels` of those or a flat
/// patch.
pub fn photometric_score(images: &Textures<'_>, pose: &Pose, cfg: &JudgeConfig) -> Option<f64> {
    agreement(images, pose, cfg).score
}

/// How the target agrees with the model moved by a pose: what confirms a pose found on the
/// images alone ([`agreement`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Agreement {
    /// Model pixels compared (every `stride`-th object pixel with depth, thinned to
    /// `max_pixels`).
    pub samples: usize,
    /// Of those, the pixels visible in the target: inside the image, where the target's depth
    /// agrees with the moved pixel's within `depth_agreement_m`.
    pub visible: usize,
    /// [`photometric_score`] over the visible pixels.
    pub score: Option<f64>,
}

impl Agreement {
    /// The fraction of the compared pixels visible in the target (0 without any).
    pub fn visible_fraction(&self) -> f64 {
        if self.samples == 0 { 0.0 } else { self.visible as f64 / self.samples as f64 }
    }
}

/// The model's object pixels moved by `pose` against the target: how many land where the
/// target's depth agrees, and how their texture correlates with the target's there
/// ([`photometric_score`]).
pub fn agreement(images: &Textures<'_>, pose: &Pose, cfg: &JudgeConfig) -> Agreement {
    let target = &images.target;
    let (w, h) = target.depth.dims();
    let camera = target.camera;
    let (mut n, mut sa, mut sb, mut saa, mut sbb, mut sab) = (0usize, 0.0, 0.0, 0.0, 0.0, 0.0);
    for &ObjectSample { point, value: a, .. } in &images.samples {
        let q = pose * point;
        let Some(px) = camera.project(&q) else { continue };
        let (u, v) = (px.x.round(), px.y.round());
        if u < 0.0 || v < 0.0 || u >= w as f64 || v >= h as f64 {
            continue;
        }
        let zt = f64::from(*target.depth.at(u as usize, v as usize));
        if zt <= 0.0 || (zt - q.z).abs() > cfg.depth_agreement_m {
            continue;
        }
        let Some(b) = images.target_texture.bilinear(px.x, px.y) else { continue };
        n += 1;
        (sa, sb, saa, sbb, sab) = (sa + a, sb + b, saa + a * a, sbb + b * b, sab + a * b);
    }
    let nf = n as f64;
    let (va, vb) = (saa - sa * sa / nf, sbb - sb * sb / nf);
    let score =
        (n >= cfg.min_pixels && va > 1e-12 && vb > 1e-12).then(|| 1.0 - (sab - sa * sb / nf) / (va * vb).sqrt());
    Agreement { samples: images.samples.len(), visible: n, score }
}

/// The candidates of one judgement: the coarse sweep's, each with its score, and the best of
/// them after the fine sweep.
pub struct Sweep {
    /// The coarse candidates (those that fit the clouds) and their scores.
    pub coarse: Vec<(TurnCandidate, Option<f64>)>,
    /// The best candidate and its score; `None` when no candidate can be scored.
    pub best: Option<(f64, TurnCandidate)>,
}

/// The candidates the clouds allow, scored: the coarse sweep, then the fine sweep around its
/// best.
pub fn sweep(hypotheses: &TurnHypotheses, images: &Textures<'_>, cfg: &JudgeConfig) -> Sweep {
    let score = |c: &TurnCandidate| photometric_score(images, &c.pose, cfg);
    // Scored side by side, collected in order.
    let coarse: Vec<(TurnCandidate, Option<f64>)> =
        hypotheses.coarse(&cfg.sweep).into_par_iter().map(|c| (c, score(&c))).collect();
    let mut best = coarse.iter().filter_map(|(c, s)| s.map(|s| (s, *c))).min_by(|a, b| a.0.total_cmp(&b.0));
    if let Some((_, around)) = best {
        let steps = (cfg.fine_reach_deg / cfg.fine_step_deg).round() as i32;
        // The fine steps fitted and scored side by side, then taken in order.
        let fine: Vec<(f64, TurnCandidate)> = (-steps..=steps)
            .into_par_iter()
            .filter(|s| *s != 0)
            .filter_map(|s| {
                let c = hypotheses.candidate(around.axis, around.deg + f64::from(s) * cfg.fine_step_deg)?;
                Some((score(&c)?, c))
            })
            .collect();
        for (score, c) in fine {
            if best.as_ref().is_none_or(|b| score < b.0) {
                best = Some((score, c));
            }
        }
    }
    Sweep { coarse, best }
}

/// Other poses the clouds and the images allow as well as the estimate: coarse candidates at
/// least `cfg.ambiguity_min_turn_deg` from the estimate's turn `at_deg` on axis `at_axis` (the
/// estimate is the answer itself when `at_axis` is `None`), whose score is within
/// `cfg.ambiguity_tolerance` of the estimate's `score` (or that cannot be scored, like the
/// estimate, when the texture is flat). The axis with the most of them and their turns
/// relative to the estimate; `None` when there are none.
pub fn ambiguity(
    sweep: &Sweep,
    score: Option<f64>,
    at: Option<(usize, f64)>,
    cfg: &JudgeConfig,
) -> Option<(usize, Vec<f64>)> {
    let admitted = |s: Option<f64>| match (s, score) {
        (Some(s), Some(best)) => s <= best + cfg.ambiguity_tolerance,
        (None, None) => true,
        _ => false,
    };
    let mut per_axis: [Vec<f64>; 3] = Default::default();
    for (c, s) in &sweep.coarse {
        let relative = match at {
            None => c.deg,
            Some((axis, deg)) if axis == c.axis => c.deg - deg,
            Some(_) => continue,
        };
        if relative.abs() >= cfg.ambiguity_min_turn_deg && admitted(*s) {
            per_axis[c.axis].push(relative);
        }
    }
    let (axis, turns) = per_axis.into_iter().enumerate().max_by_key(|(_, t)| t.len())?;
    (!turns.is_empty()).then_some((axis, turns))
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowfilter_camera::{CameraModel, Distortion, ImageSize, Intrinsics, RayTable};
    use flowfilter_geometry::Grid;
    use nalgebra::{Translation3, UnitQuaternion};

    /// A textured wall 0.6 m in front of the camera, and the same wall 3 mm to the right under
    /// another exposure (or 5 cm farther): at the true motion the wall's pixels are all visible and their
    /// texture correlates; a few pixels off it correlates less, half its waves off not at all;
    /// behind another surface nothing is visible.
    #[test]
    fn the_agreement_confirms_the_true_motion_only() {
        let camera = CameraModel::new(
            Intrinsics::new(525.0, 525.0, 160.0, 120.0).unwrap(),
            Distortion::from_slice(&[0.0; 5]).unwrap(),
            ImageSize::new(320, 240).unwrap(),
        );
        let rays = RayTable::new(&camera);
        let wall = |x: f64, y: f64| {
            (0.5 + 0.2 * (x * 0.23).sin() * (y * 0.19).cos() + 0.1 * (x * 0.07 + y * 0.05).sin()) as f32
        };
        let shift_px = 525.0 * 0.003 / 0.6;
        let model_gray = Grid::from_fn(320, 240, |x, y| wall(x as f64, y as f64));
        let target_gray = Grid::from_fn(320, 240, |x, y| 1.3 * wall(x as f64 - shift_px, y as f64) + 0.1);
        let depth = Grid::filled(320, 240, 0.6f32);
        let far_depth = Grid::filled(320, 240, 0.65f32);
        let mask = Grid::from_fn(320, 240, |x, y| (60..260).contains(&x) && (40..200).contains(&y));
        let view = |gray, depth| ImageView { gray, depth, mask: &mask, rays: &rays, camera: &camera, textures: None };
        let cfg = JudgeConfig::default();
        let images = Textures::new(&view(&model_gray, &depth), &view(&target_gray, &depth), &cfg);
        let moved = |dx: f64| Pose::from_parts(Translation3::new(dx, 0.0, 0.0), UnitQuaternion::identity());
        let truth = agreement(&images, &moved(0.003), &cfg);
        assert!(truth.visible_fraction() > 0.95, "{truth:?}");
        assert!(truth.score.unwrap() < 0.02, "{truth:?}");
        let near = agreement(&images, &Pose::identity(), &cfg);
        assert!(near.score.unwrap() > truth.score.unwrap() + 0.1, "{near:?} against {truth:?}");
        let wrong = agreement(&images, &moved(0.0155), &cfg);
        assert!(wrong.score.unwrap() > 0.6, "{wrong:?}");
        let hidden = Textures::new(&view(&model_gray, &depth), &view(&target_gray, &far_depth), &cfg);
        let behind = agreement(&hidden, &moved(0.003), &cfg);
        assert_eq!((behind.visible, behind.score), (0, None), "{behind:?}");
    }
}
