//! Direct image alignment: the final pose refined on the two images themselves.
//!
//! Flow pairs fix the pose to what the tracker resolves (about a degree on a turntable pair);
//! the geometry cannot fix the turn about an axis of symmetry at all. The alignment moves the
//! model frame's object pixels (back-projected with their depth) by the pose, projects them into
//! the target frame and minimises, by Gauss-Newton on the pose, two residuals per pixel (the
//! formulation of dense RGB-D odometry, Kerl et al. 2013, and Open3D's hybrid RGB-D odometry):
//! - the target's texture under the pixel ([`crate::judge::high_pass`] grey values) less the
//!   model's times a gain (the ratio of the two textures' contrasts, so that a change of exposure
//!   does not count);
//! - the target's depth under the pixel less the pixel's own depth.
//!
//! Each residual is scaled by a robust estimate of its noise (the median absolute deviation)
//! and truncated: pixels hidden in one frame, off the object or on a highlight stop counting.
//! The aligned pose is kept only when it lowers that truncated cost and stays within a stated
//! distance of the pose it started from.

use crate::judge::Texture;
use crate::stages::PreparedFrame;
use flowfilter_geometry::{ParamError, Point3, Pose, Vector3, params, se3};
use nalgebra::{Matrix6, Vector6};
use serde::{Deserialize, Serialize};

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
    /// [`crate::judge::high_pass`]).
    pub texture_radius_px: usize,
    /// A residual beyond this many robust standard deviations stops counting (the pixel is
    /// taken for hidden, off the object or a highlight).
    pub truncation: f64,
    /// The depth residual's noise is taken as at least this (metres): keeps a smooth synthetic
    /// surface from outweighing the texture.
    pub min_depth_noise_m: f64,
    /// The aligned pose may turn at most this far from the pose it started from (degrees)...
    pub max_turn_deg: f64,
    /// ... and move its model pixels at most this far (metres); beyond either, the start is
    /// kept.
    pub max_shift_m: f64,
}

impl Default for AlignConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            iterations: 10,
            smoothing_px: vec![2],
            stride: 2,
            max_pixels: 3000,
            min_pixels: 200,
            texture_radius_px: 4,
            truncation: 3.0,
            min_depth_noise_m: 0.001,
            max_turn_deg: 3.0,
            max_shift_m: 0.02,
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
        params::positive("max_turn_deg", self.max_turn_deg)?;
        params::positive("max_shift_m", self.max_shift_m)
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
    /// Whether the aligned pose replaced the start.
    pub accepted: bool,
}

/// A model pixel: its point (model camera frame) and texture.
struct Sample {
    point: Point3,
    texture: f64,
}

/// The target as the residuals read it.
struct TargetView<'a> {
    frame: &'a PreparedFrame,
    texture: Texture,
}

/// One pixel's residuals and their Jacobians with respect to a left twist `(rho, phi)`.
struct Residuals {
    texture: f64,
    texture_jacobian: Vector6<f64>,
    depth: Option<(f64, Vector6<f64>)>,
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
    samples: Vec<Sample>,
    view: TargetView<'a>,
    cfg: &'a AlignConfig,
}

/// Where a descent ended.
struct Descent {
    pose: Pose,
    iterations: usize,
}

impl<'a> Aligner<'a> {
    /// The frames with their textures smoothed by a box of half-width `smoothing_px` (0: as
    /// they are); `None` when the model has fewer than `cfg.min_pixels` object pixels with
    /// depth.
    pub fn new(
        model: &PreparedFrame,
        target: &'a PreparedFrame,
        cfg: &'a AlignConfig,
        smoothing_px: usize,
    ) -> Option<Self> {
        let samples = samples(model, cfg, smoothing_px);
        let texture = Texture::new(&target.gray, &target.mask, cfg.texture_radius_px).smoothed(smoothing_px);
        (samples.len() >= cfg.min_pixels).then_some(Self { samples, view: TargetView { frame: target, texture }, cfg })
    }

    /// The residuals' noise scales at `pose`; `None` when too few pixels are visible in both
    /// frames or the texture is flat there.
    pub fn scales(&self, pose: &Pose) -> Option<Scales> {
        scales(&self.samples, &self.view, pose, self.cfg)
    }

    /// The truncated cost per pixel of `pose` with the scales `sc`.
    pub fn cost(&self, pose: &Pose, sc: Scales) -> f64 {
        cost(&self.samples, &self.view, pose, sc, self.cfg) / self.samples.len() as f64
    }

    /// Damped Gauss-Newton from `start` with the scales `sc`, while it lowers the cost.
    fn descend(&self, start: &Pose, sc: Scales) -> Descent {
        let cfg = self.cfg;
        let (mut pose, mut current, mut lambda, mut iterations) = (*start, self.cost(start, sc), 1e-4, 0);
        while iterations < cfg.iterations {
            iterations += 1;
            let Some(step) = gauss_newton_step(&self.samples, &self.view, &pose, sc, cfg, lambda) else { break };
            let trial = se3::exp(&step) * pose;
            let c = self.cost(&trial, sc);
            if c < current {
                (pose, current, lambda) = (trial, c, (lambda * 0.3).max(1e-6));
                if step.norm() < 1e-7 {
                    break;
                }
            } else {
                lambda *= 10.0;
                if lambda > 1e3 {
                    break;
                }
            }
        }
        Descent { pose, iterations }
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
/// use flowfilter_bigbird::SensorId;
/// use flowfilter_pipeline::align::{AlignConfig, align};
/// use flowfilter_pipeline::{Pipeline, PipelineConfig, Pose, RgbdFrame};
/// use flowfilter_synth::{Rig, Scene, procedural, render_frame, world_from_table};
///
/// let (rig, sensor) = (Rig::bigbird_like(), SensorId::new(3).unwrap());
/// let scene = Scene::new(procedural("box", 1)?.placed_on_table(0.01, -0.005), 1);
/// let pipeline = Pipeline::from_config(PipelineConfig::default())?;
/// let frame = |angle| {
///     let f = render_frame(&scene, &rig, sensor, angle, None, 7);
///     let frame = RgbdFrame { label: format!("{angle}"), color: f.color, depth: f.raw_depth, mask: f.mask, sensor: rig.sensors[&sensor].rgbd };
///     pipeline.prepare(&frame)
/// };
/// let (model, target) = (frame(0)?, frame(6)?);
/// let h = |angle: f64| rig.sensors[&sensor].h_color_from_world * world_from_table(angle);
/// let truth = h(6.0) * h(0.0).inverse();
/// // Half a degree off about the camera's x axis.
/// let start = Pose::rotation(nalgebra::Vector3::x() * 0.5f64.to_radians()) * truth;
/// let (pose, report) = align(&model, &target, &start, &AlignConfig::default()).expect("textured");
/// assert!(report.accepted && (pose.inverse() * truth).rotation.angle().to_degrees() < 0.1);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn align(
    model: &PreparedFrame,
    target: &PreparedFrame,
    start: &Pose,
    cfg: &AlignConfig,
) -> Option<(Pose, AlignReport)> {
    Alignment::new(model, target, cfg)?.run(start)
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
    pub fn new(model: &PreparedFrame, target: &'a PreparedFrame, cfg: &'a AlignConfig) -> Option<Self> {
        let fine = Aligner::new(model, target, cfg, 0)?;
        let coarse =
            cfg.smoothing_px.iter().filter(|s| **s > 0).filter_map(|&s| Aligner::new(model, target, cfg, s)).collect();
        Some(Self { coarse, fine, cfg })
    }

    /// [`align`] from `start`.
    pub fn run(&self, start: &Pose) -> Option<(Pose, AlignReport)> {
        let (fine, cfg) = (&self.fine, self.cfg);
        let judged_by = fine.scales(start)?;
        let (mut pose, mut iterations) = (*start, 0);
        for coarse in &self.coarse {
            let Some(sc) = coarse.scales(&pose) else { continue };
            let d = coarse.descend(&pose, sc);
            (pose, iterations) = (d.pose, iterations + d.iterations);
        }
        let d = fine.descend(&pose, fine.scales(&pose).unwrap_or(judged_by));
        (pose, iterations) = (d.pose, iterations + d.iterations);
        let (cost_before, cost_after) = (fine.cost(start, judged_by), fine.cost(&pose, judged_by));
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
            accepted,
        };
        Some((pose, report))
    }
}

/// The model's object pixels with depth (every `stride`-th, thinned to `max_pixels`), with
/// their texture smoothed by a box of half-width `smoothing_px`.
fn samples(model: &PreparedFrame, cfg: &AlignConfig, smoothing_px: usize) -> Vec<Sample> {
    let texture = Texture::new(&model.gray, &model.mask, cfg.texture_radius_px).smoothed(smoothing_px);
    let samples = crate::judge::object_samples(model, &texture, cfg.stride, cfg.max_pixels);
    samples.into_iter().map(|(point, texture)| Sample { point, texture }).collect()
}

impl TargetView<'_> {
    /// The residuals of one model pixel moved by `pose`; `None` where it leaves the target's
    /// texture.
    fn residuals(&self, s: &Sample, pose: &Pose, gain: f64) -> Option<Residuals> {
        let camera = &self.frame.sensor.color;
        let q = pose * s.point;
        let px = camera.project(&q)?;
        let (b, gx, gy) = self.texture.bilinear_gradient(px.x, px.y)?;
        let jp = projection_jacobian(camera, &q)?;
        let dq = point_twist_jacobian(&q);
        let image = jp * dq; // 2x6: the pixel's motion per twist
        let texture_jacobian = (image.row(0) * gx + image.row(1) * gy).transpose();
        let depth = self.depth_at(px.x, px.y).map(|(z, dzx, dzy)| {
            let j = image.row(0) * dzx + image.row(1) * dzy - dq.row(2);
            (z - q.z, j.transpose())
        });
        Some(Residuals { texture: b - gain * s.texture, texture_jacobian, depth })
    }

    /// The residuals of [`TargetView::residuals`] without their Jacobians (what the cost reads:
    /// a sixth of the projections).
    fn values(&self, s: &Sample, pose: &Pose, gain: f64) -> Option<(f64, Option<f64>)> {
        let q = pose * s.point;
        let px = self.frame.sensor.color.project(&q)?;
        let (b, _, _) = self.texture.bilinear_gradient(px.x, px.y)?;
        Some((b - gain * s.texture, self.depth_at(px.x, px.y).map(|(z, _, _)| z - q.z)))
    }

    /// The target's depth at `(x, y)` (bilinear) and its gradient, where the four pixels
    /// around have depth on one surface (no jump larger than 1 cm between them).
    fn depth_at(&self, x: f64, y: f64) -> Option<(f64, f64, f64)> {
        let d = &self.frame.depth;
        let (w, h) = d.dims();
        if x < 0.0 || y < 0.0 {
            return None;
        }
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
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

/// d(pixel)/d(point) of the (distorted) projection, by central differences.
fn projection_jacobian(camera: &flowfilter_camera::CameraModel, q: &Point3) -> Option<nalgebra::Matrix2x3<f64>> {
    const H: f64 = 1e-5;
    let mut j = nalgebra::Matrix2x3::zeros();
    for k in 0..3 {
        let mut e = Vector3::zeros();
        e[k] = H;
        let (a, b) = (camera.project(&(q + e))?, camera.project(&(q - e))?);
        j[(0, k)] = (a.x - b.x) / (2.0 * H);
        j[(1, k)] = (a.y - b.y) / (2.0 * H);
    }
    Some(j)
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
fn scales(samples: &[Sample], view: &TargetView<'_>, pose: &Pose, cfg: &AlignConfig) -> Option<Scales> {
    // (target texture, model texture, depth residual) of the pixels visible in both: the
    // target's depth agrees within the depth of field of a turntable object (a hidden pixel
    // lies behind the target's surface by more).
    let visible: Vec<(f64, f64, f64)> = samples
        .iter()
        .filter_map(|s| {
            let (b, d) = view.values(s, pose, 0.0)?;
            d.filter(|d| d.abs() < 0.01).map(|d| (b, s.texture, d))
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
    let depth = mad(visible.iter().map(|(_, _, d)| *d).collect()).max(cfg.min_depth_noise_m);
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

/// The truncated cost of `pose`: each residual squared in units of its scale, at most
/// `truncation^2`; a pixel that leaves the target counts the cap for both.
fn cost(samples: &[Sample], view: &TargetView<'_>, pose: &Pose, sc: Scales, cfg: &AlignConfig) -> f64 {
    let cap = cfg.truncation * cfg.truncation;
    samples
        .iter()
        .map(|s| match view.values(s, pose, sc.gain) {
            None => 2.0 * cap,
            Some((texture, depth)) => {
                let t = (texture / sc.texture).powi(2).min(cap);
                let d = depth.map_or(cap, |d| (d / sc.depth).powi(2).min(cap));
                t + d
            }
        })
        .sum()
}

/// One damped Gauss-Newton step on the residuals within the truncation; `None` when the
/// normal equations are singular.
fn gauss_newton_step(
    samples: &[Sample],
    view: &TargetView<'_>,
    pose: &Pose,
    sc: Scales,
    cfg: &AlignConfig,
    lambda: f64,
) -> Option<Vector6<f64>> {
    let (mut h, mut g) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros());
    for r in samples.iter().filter_map(|s| view.residuals(s, pose, sc.gain)) {
        let mut add = |res: f64, jac: &Vector6<f64>, scale: f64| {
            if (res / scale).abs() <= cfg.truncation {
                let w = 1.0 / (scale * scale);
                h += jac * jac.transpose() * w;
                g += jac * (res * w);
            }
        };
        if let Some((d, jd)) = &r.depth {
            if (d / sc.depth).abs() > cfg.truncation {
                continue; // hidden in one of the frames: its texture is another surface's
            }
            add(*d, jd, sc.depth);
        } else {
            continue;
        }
        add(r.texture, &r.texture_jacobian, sc.texture);
    }
    let damped = h + Matrix6::from_diagonal(&h.diagonal()) * lambda;
    damped.cholesky().map(|c| -c.solve(&g))
}
