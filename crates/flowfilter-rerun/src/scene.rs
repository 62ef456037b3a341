//! [`PairScene`]: what a recording of one pair shows, computed from the pipeline's outputs
//! alone (no Rerun needed), so that what is drawn is tested without the viewer.

use flowfilter_geometry::{DepthMap, Mask, Point3, Pose};
use flowfilter_pipeline::{Estimate, PairTrace, PipelineWarning, PreparedFrame, TracedCandidate};
use image::RgbImage;

/// Colour of a flow pair that agrees with the estimate (green).
pub const INLIER_COLOR: [u8; 3] = [40, 200, 60];
/// Colour of a pair of the kept set that does not agree (red).
pub const OUTLIER_COLOR: [u8; 3] = [220, 40, 40];
/// Colour of a pair of a set the registration did not keep (grey).
pub const UNUSED_COLOR: [u8; 3] = [150, 150, 150];

/// One frame's images as the pipeline used them.
#[derive(Debug, Clone)]
pub struct FrameLayer {
    /// The colour image.
    pub color: RgbImage,
    /// Depth on the colour grid, metres (0: none).
    pub depth_m: DepthMap,
    /// The object mask used.
    pub mask: Mask,
}

/// One flow pair, on the images and in 3-D.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlowPair {
    /// Index of its set in [`PairTrace::sets`].
    pub set: usize,
    /// The model point's pixel in the model image.
    pub model_px: [f32; 2],
    /// The target point's pixel in the target image.
    pub target_px: [f32; 2],
    /// The model point moved by the estimate (target camera frame).
    pub aligned: [f32; 3],
    /// The target point.
    pub target: [f32; 3],
    /// Whether it belongs to the set the registration kept.
    pub kept: bool,
    /// Whether it agrees with the estimate (within the inlier distance).
    pub inlier: bool,
}

impl FlowPair {
    /// Its colour: [`INLIER_COLOR`], [`OUTLIER_COLOR`] or [`UNUSED_COLOR`].
    pub fn color(&self) -> [u8; 3] {
        match (self.kept, self.inlier) {
            (false, _) => UNUSED_COLOR,
            (true, true) => INLIER_COLOR,
            (true, false) => OUTLIER_COLOR,
        }
    }
}

/// Everything a recording of one pair shows (the entities of [`crate::paths`]).
#[derive(Debug, Clone)]
pub struct PairScene {
    /// `model -> target`, as the estimate names the frames.
    pub label: String,
    /// The model frame.
    pub model: FrameLayer,
    /// The target frame (its mask is the propagated one when the pipeline propagated it).
    pub target: FrameLayer,
    /// The model cloud (model camera frame).
    pub model_cloud: Vec<[f32; 3]>,
    /// The target cloud.
    pub target_cloud: Vec<[f32; 3]>,
    /// The model cloud moved by the estimate.
    pub aligned_cloud: Vec<[f32; 3]>,
    /// The model cloud moved by the truth, when known.
    pub truth_cloud: Option<Vec<[f32; 3]>>,
    /// The model cloud moved by the judge's best-scored candidate, when it scored any.
    pub best_candidate_cloud: Option<Vec<[f32; 3]>>,
    /// Every flow pair of every candidate set.
    pub flow: Vec<FlowPair>,
    /// The estimate.
    pub pose: Pose,
    /// The true motion, when known.
    pub truth: Option<Pose>,
    /// Rotation (degrees) and translation (metres) bounds, when the method gives them.
    pub bounds: Option<(f64, f64)>,
    /// Geodesic rotation error (degrees) and translation error (metres), when the truth is known.
    pub errors: Option<(f64, f64)>,
    /// The judge's candidates.
    pub candidates: Vec<TracedCandidate>,
    /// The judge's score of the registration's answer.
    pub answer_score: Option<f64>,
    /// Stage times, milliseconds, in the order of [`crate::paths::STAGES`].
    pub timings_ms: Vec<(&'static str, f64)>,
    /// The warnings, as the CLI prints them.
    pub warnings: Vec<String>,
    /// Whether the estimate is reported as converged.
    pub converged: bool,
    /// The estimate as `estimate --json` prints it.
    pub summary_json: String,
}

/// One frame of a pair: its colour image and the pipeline's preparation of it.
#[derive(Clone, Copy)]
pub struct FrameInput<'a> {
    /// The colour image.
    pub color: &'a RgbImage,
    /// The frame as the pipeline prepared it.
    pub prepared: &'a PreparedFrame,
}

impl PairScene {
    /// The scene of one estimated pair: the frames, the estimate, what the pipeline traced
    /// ([`flowfilter_pipeline::Pipeline::estimate_traced`]) and the truth when known.
    ///
    /// ```
    /// use flowfilter_bigbird::SensorId;
    /// use flowfilter_pipeline::{Pipeline, PipelineConfig, RgbdFrame};
    /// use flowfilter_rerun::{FrameInput, PairScene};
    /// use flowfilter_synth::{Rig, Scene, procedural, render_frame};
    ///
    /// let (rig, sensor) = (Rig::bigbird_like(), SensorId::new(3).unwrap());
    /// let scene = Scene::new(procedural("box", 1)?.placed_on_table(0.01, -0.005), 1);
    /// let frame = |angle| {
    ///     let f = render_frame(&scene, &rig, sensor, angle, None, 7);
    ///     let sensor = rig.sensors[&sensor].rgbd;
    ///     RgbdFrame { label: format!("NP3_{angle}"), color: f.color, depth: f.raw_depth, mask: f.mask, sensor }
    /// };
    /// let pipeline = Pipeline::from_config(PipelineConfig::default())?;
    /// let (fa, fb) = (frame(0), frame(6));
    /// let (a, b) = (pipeline.prepare(&fa)?, pipeline.prepare(&fb)?);
    /// let (estimate, trace) = pipeline.estimate_traced(&a, &b)?;
    /// let model = FrameInput { color: &fa.color, prepared: &a };
    /// let target = FrameInput { color: &fb.color, prepared: &b };
    /// let scene = PairScene::new(model, target, &estimate, &trace, None);
    /// assert_eq!(scene.aligned_cloud.len(), a.cloud.len());
    /// assert!(scene.flow.iter().filter(|p| p.inlier).count() >= 12);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn new(
        model: FrameInput<'_>,
        target: FrameInput<'_>,
        estimate: &Estimate,
        trace: &PairTrace,
        truth: Option<&Pose>,
    ) -> Self {
        let pose = estimate.pose;
        let model_points = &model.prepared.cloud.points;
        let best =
            trace.candidates.iter().filter_map(|c| c.score.map(|s| (s, c.pose))).min_by(|a, b| a.0.total_cmp(&b.0));
        let target_mask = trace.propagated_mask.clone().unwrap_or_else(|| target.prepared.mask.clone());
        Self {
            label: format!("{} -> {}", estimate.model, estimate.target),
            model: layer(model, model.prepared.mask.clone()),
            target: layer(target, target_mask),
            model_cloud: points_f32(model_points, &Pose::identity()),
            target_cloud: points_f32(&target.prepared.cloud.points, &Pose::identity()),
            aligned_cloud: points_f32(model_points, &pose),
            truth_cloud: truth.map(|t| points_f32(model_points, t)),
            best_candidate_cloud: best.map(|(_, p)| points_f32(model_points, &p)),
            flow: flow_pairs(model.prepared, target.prepared, trace, &pose),
            pose,
            truth: truth.copied(),
            bounds: estimate.registration.uncertainty.map(|u| (u.rotation_deg, u.translation_m)),
            errors: estimate.ground_truth.as_ref().map(|g| (g.errors.geodesic_error_deg, g.errors.translation_error_m)),
            candidates: trace.candidates.clone(),
            answer_score: trace.answer_score,
            timings_ms: stage_times(estimate),
            warnings: estimate.warnings.iter().map(PipelineWarning::to_string).collect(),
            converged: estimate.registration.converged,
            summary_json: serde_json::to_string_pretty(estimate).unwrap_or_default(),
        }
    }

    /// The pairs of the set the registration kept that agree with the estimate, and all of
    /// that set's pairs.
    pub fn kept_inliers(&self) -> (usize, usize) {
        let kept = self.flow.iter().filter(|p| p.kept);
        let (n, inliers) = kept.fold((0, 0), |(n, i), p| (n + 1, i + usize::from(p.inlier)));
        (inliers, n)
    }

    /// The judge's candidates as a Markdown table (axis, turn, score), best first.
    pub fn candidates_table(&self) -> String {
        let mut rows: Vec<&TracedCandidate> = self.candidates.iter().collect();
        rows.sort_by(|a, b| a.score.unwrap_or(f64::INFINITY).total_cmp(&b.score.unwrap_or(f64::INFINITY)));
        let answer = self.answer_score.map_or("-".into(), |s| format!("{s:.5}"));
        let mut text =
            format!("Answer's score: {answer} (lower agrees better)\n\n| axis | turn (deg) | score |\n|---|---|---|\n");
        for c in rows {
            let [x, y, z] = c.axis;
            let score = c.score.map_or("-".into(), |s| format!("{s:.5}"));
            text.push_str(&format!("| ({x:.3}, {y:.3}, {z:.3}) | {:.1} | {score} |\n", c.turn_deg));
        }
        text
    }
}

fn layer(frame: FrameInput<'_>, mask: Mask) -> FrameLayer {
    FrameLayer { color: frame.color.clone(), depth_m: frame.prepared.depth.clone(), mask }
}

fn points_f32(points: &[Point3], pose: &Pose) -> Vec<[f32; 3]> {
    points.iter().map(|p| to_f32(&(pose * p))).collect()
}

fn to_f32(p: &Point3) -> [f32; 3] {
    [p.x as f32, p.y as f32, p.z as f32]
}

/// Every pair of every traced set, placed on both images (pairs whose points fall outside an
/// image are left out) and classified against `pose`.
fn flow_pairs(model: &PreparedFrame, target: &PreparedFrame, trace: &PairTrace, pose: &Pose) -> Vec<FlowPair> {
    let mut out = vec![];
    for (k, set) in trace.sets.iter().enumerate() {
        let pairs = &set.pairs;
        for i in 0..pairs.len() {
            let (Some(a), Some(b)) =
                (model.sensor.color.project(&pairs.source[i]), target.sensor.color.project(&pairs.target[i]))
            else {
                continue;
            };
            out.push(FlowPair {
                set: k,
                model_px: [a.x as f32, a.y as f32],
                target_px: [b.x as f32, b.y as f32],
                aligned: to_f32(&(pose * pairs.source[i])),
                target: to_f32(&pairs.target[i]),
                kept: trace.kept_set == Some(k),
                inlier: trace.is_inlier(pairs, i, pose),
            });
        }
    }
    out
}

fn stage_times(e: &Estimate) -> Vec<(&'static str, f64)> {
    let t = &e.stage_ms;
    let values = [t.depth_model, t.depth_target, t.flow, t.correspondences, t.registration, t.judge, t.align, t.total];
    crate::paths::STAGES.into_iter().zip(values).collect()
}
