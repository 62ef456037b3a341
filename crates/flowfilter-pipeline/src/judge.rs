//! The photometric judge: when the object may have turned further than the flow followed.
//!
//! Flow and geometry both fail towards "no motion" on an object whose silhouette and shading
//! stay put while it turns (cans, bottles, mugs at 20-30 degree steps). The surface's texture
//! does turn with it. After the registration, the judge asks the registration crate for the
//! poses the clouds allow ([`TurnHypotheses`]: the answer turned about the model's normal-scatter
//! axes, kept where the clouds still fit) and scores each by photometric consistency: the model
//! frame's object pixels, back-projected with their depth, moved by the pose and projected into
//! the target frame, compared with the target's grey values where the target's depth agrees
//! (pixels visible in both). The score is one minus the normalised cross-correlation, so a
//! change of exposure (gain and offset) does not count. When a candidate agrees clearly better
//! than the answer, the flow is tracked again from it and the registration re-run; the result
//! replaces the answer if its own photometric score is the better one.

use crate::stages::PreparedFrame;
use flowfilter_flow::lk::Gray;
use flowfilter_geometry::{Mask, ParamError, Point3, Pose, mask_bbox, params};
use flowfilter_registration::judge::{TurnCandidate, TurnHypotheses, TurnSweepConfig};
use serde::{Deserialize, Serialize};

/// The judge's parameters (`[judge]` in the pipeline configuration).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct JudgeConfig {
    /// Run the judge after methods that use flow correspondences.
    pub enabled: bool,
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
    /// this (scores are 1 - correlation): an [`crate::PipelineWarning::AmbiguousPose`] then
    /// names it. Larger warns on objects whose texture tells the poses apart only weakly;
    /// smaller misses a plain object, whose turned candidates, a little off its axis, match its
    /// edges a little worse than the estimate.
    pub ambiguity_tolerance: f64,
    /// ... and when it is turned at least this far from the estimate (degrees).
    pub ambiguity_min_turn_deg: f64,
    /// Half-width of the box whose mean is taken from the grey values before comparing
    /// (pixels; see [`high_pass`]).
    pub texture_radius_px: usize,
    /// Align every coarse candidate and the answer on the images ([`crate::align`]) before
    /// comparing them: a candidate a few degrees off the true turn scores like any wrong pose
    /// (the score's basin is 3-6 degrees wide), aligned it scores like the truth.
    pub align_candidates: bool,
    /// The candidates' alignment uses at most this many model pixels...
    pub candidate_pixels: usize,
    /// ... and at most this many Gauss-Newton steps per level (the rest of `[align]` as
    /// configured).
    pub candidate_iterations: usize,
}

impl Default for JudgeConfig {
    fn default() -> Self {
        Self {
            enabled: true,
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

/// The grey image less its local mean over a `(2r+1)^2` box (a high-pass): what stays is the
/// texture, not the shading or the contrast between large regions (a can's white lid against
/// its dark label), which do not turn with the surface.
pub fn high_pass(img: &Gray, r: usize) -> Gray {
    let (w, h) = img.dims();
    // Integral image, one row and column of zeros in front.
    let mut sum = vec![0.0f64; (w + 1) * (h + 1)];
    for y in 0..h {
        let mut row = 0.0;
        for x in 0..w {
            row += f64::from(*img.at(x, y));
            sum[(y + 1) * (w + 1) + x + 1] = sum[y * (w + 1) + x + 1] + row;
        }
    }
    Gray::from_fn(w, h, |x, y| {
        let (x0, y0, x1, y1) = (x.saturating_sub(r), y.saturating_sub(r), (x + r + 1).min(w), (y + r + 1).min(h));
        let s = sum[y1 * (w + 1) + x1] - sum[y0 * (w + 1) + x1] - sum[y1 * (w + 1) + x0] + sum[y0 * (w + 1) + x0];
        let mean = s / ((x1 - x0) * (y1 - y0)) as f64;
        (f64::from(*img.at(x, y)) - mean) as f32
    })
}

/// A frame's texture ([`high_pass`]) on the rectangle where it is needed.
#[derive(Clone)]
pub struct Texture {
    x0: usize,
    y0: usize,
    grid: Gray,
}

impl Texture {
    /// The texture of `img` on the bounding box of the object's `mask` (its depth lies within
    /// it), exact there (the box is widened by `r` for the local means and clamped to the
    /// image). Empty with an empty mask.
    pub fn new(img: &Gray, mask: &Mask, r: usize) -> Self {
        let (w, h) = img.dims();
        let Some((bx0, by0, bx1, by1)) = mask_bbox(mask) else {
            return Self { x0: 0, y0: 0, grid: Gray::filled(0, 0, 0.0) };
        };
        let (x0, y0) = (bx0.saturating_sub(r), by0.saturating_sub(r));
        let (x1, y1) = ((bx1 + r + 1).min(w), (by1 + r + 1).min(h));
        Self { x0, y0, grid: high_pass(&img.crop(x0, y0, x1 - x0, y1 - y0), r) }
    }

    /// The texture smoothed by a box of half-width `r` (unchanged for 0).
    pub(crate) fn smoothed(self, r: usize) -> Self {
        if r == 0 {
            return self;
        }
        let detail = high_pass(&self.grid, r);
        let grid = Gray::from_fn(self.grid.dims().0, self.grid.dims().1, |x, y| self.grid.at(x, y) - detail.at(x, y));
        Self { grid, ..self }
    }

    /// The rectangle `((x0, y0), (x1, y1))` (exclusive ends) the texture covers.
    pub(crate) fn bounds(&self) -> ((usize, usize), (usize, usize)) {
        let (w, h) = self.grid.dims();
        ((self.x0, self.y0), (self.x0 + w, self.y0 + h))
    }

    /// The texture at pixel `(x, y)` of the full image; `None` outside the rectangle.
    pub(crate) fn at(&self, x: usize, y: usize) -> Option<f64> {
        let (gx, gy) = (x.checked_sub(self.x0)?, y.checked_sub(self.y0)?);
        self.grid.get(gx, gy).map(|v| f64::from(*v))
    }

    /// Bilinear texture at `(x, y)` of the full image; `None` outside the rectangle.
    fn bilinear(&self, x: f64, y: f64) -> Option<f64> {
        let (gx, gy) = (x - self.x0 as f64, y - self.y0 as f64);
        let (w, h) = self.grid.dims();
        let inside = w > 0 && h > 0 && gx >= 0.0 && gy >= 0.0 && gx <= (w - 1) as f64 && gy <= (h - 1) as f64;
        inside.then(|| f64::from(flowfilter_flow::lk::bilinear(&self.grid, gx as f32, gy as f32)))
    }
}

/// A [`Texture`] with its central differences, `(T(x+1) - T(x-1)) / 2` and alike in y (clamped at
/// the grid's edges, which [`GradientTexture::bilinear_gradient`] never weighs): what the
/// alignment reads in the frame it aligns into.
#[derive(Clone)]
pub(crate) struct GradientTexture {
    texture: Texture,
    gradients: (Gray, Gray),
}

impl GradientTexture {
    /// `texture` and its central differences.
    pub(crate) fn new(texture: Texture) -> Self {
        let (w, h) = texture.grid.dims();
        let gradients = if w == 0 || h == 0 {
            (Gray::filled(0, 0, 0.0), Gray::filled(0, 0, 0.0))
        } else {
            flowfilter_flow::lk::central_gradients(&texture.grid)
        };
        Self { texture, gradients }
    }

    /// Bilinear texture at `(x, y)` and its gradient: the bilinear texture's central differences
    /// one pixel either side, `(B(x+1, y) - B(x-1, y)) / 2` and alike in y, read as the bilinear
    /// interpolation of the grid's central differences (the same values: interpolation commutes
    /// with whole-pixel shifts) with the value's weights. `None` where any of the five samples
    /// would leave the rectangle.
    pub(crate) fn bilinear_gradient(&self, x: f64, y: f64) -> Option<(f64, f64, f64)> {
        let (gx, gy) = self.gradient_support(x, y)?;
        let [v, dx, dy] =
            flowfilter_flow::lk::bilinear_many([&self.texture.grid, &self.gradients.0, &self.gradients.1], gx, gy);
        Some((f64::from(v), f64::from(dx), f64::from(dy)))
    }

    /// The bilinear texture at `(x, y)` where [`GradientTexture::bilinear_gradient`] has a value (the
    /// same domain, without the gradient).
    pub(crate) fn bilinear_with_gradient_support(&self, x: f64, y: f64) -> Option<f64> {
        let (gx, gy) = self.gradient_support(x, y)?;
        Some(f64::from(flowfilter_flow::lk::bilinear(&self.texture.grid, gx, gy)))
    }

    /// `(x, y)` on the grid when it lies at least a pixel inside every edge.
    fn gradient_support(&self, x: f64, y: f64) -> Option<(f32, f32)> {
        let (gx, gy) = (x - self.texture.x0 as f64, y - self.texture.y0 as f64);
        let (w, h) = self.texture.grid.dims();
        let inside = w > 2 && h > 2 && gx >= 1.0 && gy >= 1.0 && gx <= (w - 2) as f64 && gy <= (h - 2) as f64;
        inside.then_some((gx as f32, gy as f32))
    }
}

/// What the scores compare, prepared once per judgement: the model's object pixels (every
/// `stride`-th, with depth) back-projected with their texture, and the target's texture.
pub struct Textures<'a> {
    target: &'a PreparedFrame,
    samples: Vec<ObjectSample>,
    target_texture: Texture,
}

impl<'a> Textures<'a> {
    /// The samples of `model` and the texture of `target` ([`high_pass`] with `cfg`'s radius).
    pub fn new(model: &PreparedFrame, target: &'a PreparedFrame, cfg: &JudgeConfig) -> Self {
        let r = cfg.texture_radius_px;
        let samples = object_samples(model, &Texture::new(&model.gray, &model.mask, r), cfg.stride, cfg.max_pixels);
        Self { target, samples, target_texture: Texture::new(&target.gray, &target.mask, r) }
    }
}

/// An object pixel of a frame with depth: back-projected, with its value in a texture and its
/// image row.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ObjectSample {
    pub(crate) point: Point3,
    pub(crate) value: f64,
    pub(crate) row: usize,
}

/// The object pixels of `model` with depth (every `stride`-th in each direction, evenly thinned
/// to at most `max_pixels` on a large object), back-projected, with their value in `texture`.
pub(crate) fn object_samples(
    model: &PreparedFrame,
    texture: &Texture,
    stride: usize,
    max_pixels: usize,
) -> Vec<ObjectSample> {
    let ((x0, y0), (x1, y1)) = texture.bounds();
    let mut samples = Vec::new();
    for y in (y0.next_multiple_of(stride)..y1).step_by(stride) {
        for x in (x0.next_multiple_of(stride)..x1).step_by(stride) {
            let z = f64::from(*model.depth.at(x, y));
            if !*model.mask.at(x, y) || z <= 0.0 {
                continue;
            }
            if let (Some(point), Some(value)) = (model.rays.backproject(x, y, z), texture.at(x, y)) {
                samples.push(ObjectSample { point, value, row: y });
            }
        }
    }
    let every = samples.len().div_ceil(max_pixels.max(1)).max(1);
    samples.into_iter().step_by(every).collect()
}

/// One minus the normalised cross-correlation of the model's object pixels moved by `pose` and
/// the target's texture under them, over the pixels visible in both (the target's depth there
/// agrees with the moved pixel's); `None` with fewer than `cfg.min_pixels` of those or a flat
/// patch.
pub fn photometric_score(images: &Textures<'_>, pose: &Pose, cfg: &JudgeConfig) -> Option<f64> {
    let target = images.target;
    let (w, h) = target.depth.dims();
    let camera = &target.sensor.color;
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
    if n < cfg.min_pixels {
        return None;
    }
    let nf = n as f64;
    let (va, vb) = (saa - sa * sa / nf, sbb - sb * sb / nf);
    if va <= 1e-12 || vb <= 1e-12 {
        return None;
    }
    Some(1.0 - (sab - sa * sb / nf) / (va * vb).sqrt())
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
    let coarse: Vec<(TurnCandidate, Option<f64>)> =
        hypotheses.coarse(&cfg.sweep).into_iter().map(|c| (c, score(&c))).collect();
    let mut best = coarse.iter().filter_map(|(c, s)| s.map(|s| (s, *c))).min_by(|a, b| a.0.total_cmp(&b.0));
    if let Some((_, around)) = best {
        let steps = (cfg.fine_reach_deg / cfg.fine_step_deg).round() as i32;
        for s in (-steps..=steps).filter(|s| *s != 0) {
            let deg = around.deg + f64::from(s) * cfg.fine_step_deg;
            if let Some(c) = hypotheses.candidate(around.axis, deg)
                && let Some(score) = score(&c)
                && best.as_ref().is_none_or(|b| score < b.0)
            {
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
