//! [`Pipeline`]: the stages composed, timed, and every degradation reported.

use crate::config::PipelineConfig;
use crate::error::PipelineError;
use crate::estimate::{CorrespondenceSummary, ESTIMATE_SCHEMA, Estimate, RegistrationSummary, StageTimes, matrix_rows};
use crate::frame::RgbdFrame;
use crate::geometry_first::GeometryFirstReport;
use crate::stages::{CorrespondenceFinder, DepthPreparer, FlowCorrespondenceFinder, FramePreparer, PreparedFrame};
use crate::trace::{PairTrace, TracedCandidate, TracedSet};
use crate::warning::PipelineWarning;
use crate::wide::CoarseView;
use flowfilter_flow::correspondences::FlowPairs;
use flowfilter_geometry::Pose;
use flowfilter_photometric::align::{self, AlignConfig, AlignReport, Alignment};
use flowfilter_photometric::gate::evidence_settled;
use flowfilter_photometric::judge::{self, JudgeReport};
use flowfilter_photometric::{TurnCandidate, TurnHypotheses};
use flowfilter_registration::{Registrar, Registration, RegistrationProblem, RegistrationWarning, registrar_by_name};
use rayon::prelude::*;
use std::time::Instant;

/// Two RGB-D frames in, a relative pose out.
///
/// ```
/// use flowfilter_pipeline::{Pipeline, PipelineConfig};
/// let pipeline = Pipeline::from_config(PipelineConfig::default())?;
/// assert_eq!(pipeline.method(), "flowfilter");
/// # Ok::<(), flowfilter_pipeline::PipelineError>(())
/// ```
pub struct Pipeline {
    config: PipelineConfig,
    preparer: Box<dyn FramePreparer>,
    finder: Option<Box<dyn CorrespondenceFinder>>,
    registrar: Box<dyn Registrar>,
}

/// The geometry-first try of a scene ([`crate::geometry_first`]): the registrar's prior (handed
/// back to it when the full pipeline follows), the aligned answer, what the images said of it,
/// and the time it took.
struct FirstTry {
    prior: Registration,
    reg: Registration,
    aligned: Option<AlignReport>,
    report: GeometryFirstReport,
    registration_ms: f64,
    align_ms: f64,
}

/// The correspondence stage's candidate sets, in the order handed to the registrar.
struct FoundSets {
    /// Per set: where it came from (`plain`, `wide`, `guided`).
    sources: Vec<&'static str>,
    /// Per set: pixels tracked, pairs found, pairs with a positive weight.
    counts: Vec<SearchCounts>,
    /// Seconds spent in flow estimation.
    flow_seconds: f64,
}

impl Pipeline {
    /// The default stages, configured: the correspondence stage only for a registrar that
    /// uses correspondences. Each stage is built once.
    ///
    /// # Errors
    /// [`PipelineError::Config`] for a value out of range or an unknown name,
    /// [`PipelineError::Flow`] when the flow estimator cannot be made (an ONNX model that does
    /// not load).
    pub fn from_config(config: PipelineConfig) -> Result<Self, PipelineError> {
        let invalid = |message| PipelineError::Config { path: "<configuration>".into(), message };
        config.validate_stages().map_err(invalid)?;
        flowfilter_flow::check_estimator_name(&config.flow.estimator)
            .map_err(|e| invalid(format!("key 'flow.estimator': {e}")))?;
        let registrar = registrar_by_name(&config.method, &config.registration)
            .map_err(|e| invalid(format!("key 'method': {e}")))?;
        let preparer = Box::new(DepthPreparer::new(config.depth.clone(), config.cloud.clone())?);
        let finder: Option<Box<dyn CorrespondenceFinder>> = if registrar.uses_correspondences() {
            Some(Box::new(FlowCorrespondenceFinder::new(config.flow.estimator()?, config.flow.correspondences.clone())))
        } else {
            None
        };
        Ok(Self { config, preparer, finder, registrar })
    }

    /// A pipeline from custom stages. The configuration is kept for reference and for the
    /// policy it sets (`flow.guided`); the stages' own parameters are theirs. Without a
    /// `finder` the registrar gets no correspondences.
    ///
    /// ```
    /// use flowfilter_pipeline::{DepthPreparer, Pipeline, PipelineConfig};
    /// use flowfilter_pipeline::registration::{RegistrationConfig, registrar_by_name};
    /// let config = PipelineConfig::default();
    /// let preparer = DepthPreparer::new(config.depth.clone(), config.cloud.clone())?;
    /// let icp = registrar_by_name("icp-pt2pl", &RegistrationConfig::default())?;
    /// let pipeline = Pipeline::with_stages(config, Box::new(preparer), None, icp);
    /// assert_eq!(pipeline.method(), "icp-pt2pl");
    /// # Ok::<(), flowfilter_pipeline::PipelineError>(())
    /// ```
    pub fn with_stages(
        config: PipelineConfig,
        preparer: Box<dyn FramePreparer>,
        finder: Option<Box<dyn CorrespondenceFinder>>,
        registrar: Box<dyn Registrar>,
    ) -> Self {
        Self { config, preparer, finder, registrar }
    }

    /// The correspondence stage, when the registrar reads correspondences.
    fn finder(&self) -> Option<&dyn CorrespondenceFinder> {
        self.finder.as_deref().filter(|_| self.registrar.uses_correspondences())
    }

    /// The configuration.
    pub fn config(&self) -> &PipelineConfig {
        &self.config
    }

    /// The registration backend's name.
    pub fn method(&self) -> &str {
        self.registrar.name()
    }

    /// Run the frame stage on one frame (reusable across many pairs).
    ///
    /// # Errors
    /// As the preparer's [`FramePreparer::prepare`].
    pub fn prepare(&self, frame: &RgbdFrame) -> Result<PreparedFrame, PipelineError> {
        self.preparer.prepare(frame)
    }

    /// Estimate `T` with `target ~ T * model` from two frames.
    ///
    /// # Errors
    /// [`PipelineError::Depth`] when a frame cannot be prepared (sizes that disagree, no depth
    /// inside the mask), [`PipelineError::Registration`] when the clouds cannot be registered.
    /// A failed flow stage is not an error: the estimate carries a
    /// [`PipelineWarning::FlowFailed`] and comes from the clouds alone.
    ///
    /// ```
    /// use flowfilter_bigbird::SensorId;
    /// use flowfilter_pipeline::{Pipeline, PipelineConfig, RgbdFrame};
    /// use flowfilter_synth::{Rig, Scene, procedural, render_frame};
    ///
    /// // A synthesised box on a turntable, seen by one camera before and after a 10-degree turn.
    /// let (rig, sensor) = (Rig::bigbird_like(), SensorId::new(3).unwrap());
    /// let scene = Scene::new(procedural("box", 1)?.placed_on_table(0.01, -0.005), 1);
    /// let frame = |angle| {
    ///     let f = render_frame(&scene, &rig, sensor, angle, None, 7);
    ///     let sensor = rig.sensors[&sensor].rgbd;
    ///     RgbdFrame { label: format!("NP3_{angle}"), color: f.color, depth: f.raw_depth, mask: f.mask, sensor }
    /// };
    /// let pipeline = Pipeline::from_config(PipelineConfig::default())?;
    /// let estimate = pipeline.estimate(&frame(0), &frame(10))?;
    /// assert!((estimate.rotation_angle_deg - 10.0).abs() < 1.0, "{}", estimate.rotation_angle_deg);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn estimate(&self, model: &RgbdFrame, target: &RgbdFrame) -> Result<Estimate, PipelineError> {
        self.estimate_against(model, target, None).map(|(e, _, _)| e)
    }

    /// [`Pipeline::estimate`], scored against the true motion when it is known (ADD-S on the
    /// model cloud), with both prepared frames (to write or draw their clouds).
    ///
    /// # Errors
    /// As [`Pipeline::estimate`].
    pub fn estimate_against(
        &self,
        model: &RgbdFrame,
        target: &RgbdFrame,
        truth: Option<&Pose>,
    ) -> Result<(Estimate, PreparedFrame, PreparedFrame), PipelineError> {
        self.against(model, target, truth, None)
    }

    /// [`Pipeline::estimate_against`] with the pair's [`PairTrace`] (as
    /// [`Pipeline::estimate_traced`]): what a recording of the pair shows.
    ///
    /// # Errors
    /// As [`Pipeline::estimate`].
    pub fn estimate_against_traced(
        &self,
        model: &RgbdFrame,
        target: &RgbdFrame,
        truth: Option<&Pose>,
    ) -> Result<(Estimate, PreparedFrame, PreparedFrame, PairTrace), PipelineError> {
        let mut trace = self.empty_trace();
        let (e, a, b) = self.against(model, target, truth, Some(&mut trace))?;
        Ok((e, a, b, trace))
    }

    fn against(
        &self,
        model: &RgbdFrame,
        target: &RgbdFrame,
        truth: Option<&Pose>,
        trace: Option<&mut PairTrace>,
    ) -> Result<(Estimate, PreparedFrame, PreparedFrame), PipelineError> {
        let t0 = Instant::now();
        // The two frames side by side: a frame's depth stage keeps one core busy for much of
        // its time (a whole 640x480 frame: 55-65 ms on one thread or two). Each frame's result
        // is the same whatever runs beside it; the model's error is reported first.
        let (a, b) = rayon::join(|| self.prepare(model), || self.prepare(target));
        let (a, b) = (a?, b?);
        let mut e = self.estimate_inner(&a, &b, trace)?;
        e.stage_ms.total = t0.elapsed().as_secs_f64() * 1e3;
        if let Some(truth) = truth {
            e = e.with_ground_truth(truth, Some(&a.cloud.points));
        }
        Ok((e, a, b))
    }

    /// A trace with nothing recorded yet but the configuration's inlier distance.
    fn empty_trace(&self) -> PairTrace {
        PairTrace { inlier_distance_m: self.config.registration.flowfilter.inlier_threshold_m, ..PairTrace::default() }
    }

    /// Estimate from frames already prepared (their preparation times are reported).
    ///
    /// # Errors
    /// [`PipelineError::Registration`] when the clouds cannot be registered.
    pub fn estimate_prepared(&self, model: &PreparedFrame, target: &PreparedFrame) -> Result<Estimate, PipelineError> {
        self.estimate_inner(model, target, None)
    }

    /// [`Pipeline::estimate_prepared`] with what it weighed on the way: the candidate sets of
    /// flow correspondences, the set kept, the judge's candidates and scores, a propagated
    /// mask ([`PairTrace`]). The estimate is the same as without the trace.
    ///
    /// # Errors
    /// As [`Pipeline::estimate_prepared`].
    ///
    /// ```
    /// use flowfilter_bigbird::SensorId;
    /// use flowfilter_pipeline::{Pipeline, PipelineConfig, RgbdFrame};
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
    /// let (a, b) = (pipeline.prepare(&frame(0))?, pipeline.prepare(&frame(6))?);
    /// let (estimate, trace) = pipeline.estimate_traced(&a, &b)?;
    /// let kept = &trace.sets[trace.kept_set.unwrap_or(0)].pairs;
    /// let inliers = (0..kept.len()).filter(|&i| trace.is_inlier(kept, i, &estimate.pose)).count();
    /// assert!(inliers >= 12, "{inliers} of {} pairs agree", kept.len());
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn estimate_traced(
        &self,
        model: &PreparedFrame,
        target: &PreparedFrame,
    ) -> Result<(Estimate, PairTrace), PipelineError> {
        let mut trace = self.empty_trace();
        let estimate = self.estimate_inner(model, target, Some(&mut trace))?;
        Ok((estimate, trace))
    }

    /// The pair through the stages, filling `trace` when given; the frames' image pyramids,
    /// which the pair's tracking passes shared, are let go at the end (a frame a tracker keeps
    /// as a keyframe would hold them for nothing: its next pair cuts another crop).
    fn estimate_inner(
        &self,
        model: &PreparedFrame,
        target: &PreparedFrame,
        trace: Option<&mut PairTrace>,
    ) -> Result<Estimate, PipelineError> {
        let estimate = self.estimate_pair(model, target, trace);
        model.pyramids.clear();
        target.pyramids.clear();
        estimate
    }

    /// [`Pipeline::estimate_inner`]'s stages.
    fn estimate_pair(
        &self,
        model: &PreparedFrame,
        target: &PreparedFrame,
        mut trace: Option<&mut PairTrace>,
    ) -> Result<Estimate, PipelineError> {
        let t0 = Instant::now();
        let mut times =
            StageTimes { depth_model: model.seconds * 1e3, depth_target: target.seconds * 1e3, ..Default::default() };
        let mut warnings: Vec<PipelineWarning> = vec![];
        // A target without a mask, for a model with one: the model's mask is propagated.
        let propagate = target.unmasked && !model.unmasked;
        let wide = &self.config.flow.wide;
        // The coarse search runs here when the mask must be propagated; else only when the
        // correspondence stage finds the pyramid's own flow split (`flow.wide.settled_*`).
        let coarse = propagate.then(|| CoarseView::new(model, target, wide));
        let propagated = coarse.as_ref().map(|view| {
            let (frame, placed) = crate::propagate::with_propagated_mask(model, target, view.found.as_ref());
            warnings.push(PipelineWarning::MaskPropagated { frame: target.label.clone(), placed });
            frame
        });
        if let (Some(t), Some(p)) = (trace.as_deref_mut(), propagated.as_ref()) {
            t.propagated_mask = Some(p.mask.clone());
        }
        let target = propagated.as_ref().unwrap_or(target);
        warnings.extend([model, target].into_iter().filter_map(crate::frame_checks::mask_coverage));
        let (source, target_cloud) = crate::stages::registration_clouds(model, target);
        let mut problem = RegistrationProblem::new(source, target_cloud);
        // The model's own size before any thinning past the configured voxel (the budget's, or
        // the other frame's density), as the points its surface holds at the scene rule's voxel.
        let at_voxel = model.thinning.finer.as_ref().map_or(model.cloud.len(), |f| f.len());
        problem.source_points = Some(model.thinning.scene_rule_points(at_voxel));
        let first = if propagate { None } else { self.geometry_first(model, target, &problem) };
        if let Some(f) = &first {
            times.registration += f.registration_ms;
            times.align += f.align_ms;
        }
        let first_report = match first {
            Some(f) if f.report.confirmed => {
                times.total = times.depth_model + times.depth_target + t0.elapsed().as_secs_f64() * 1e3;
                return Ok(self.kept_on_geometry((model, target), &problem, f, times, warnings));
            }
            Some(f) => {
                // Computed once: the guided pass and the geometric check read it back.
                problem.prior = Some(f.prior);
                Some(f.report)
            }
            None => None,
        };
        let found = self.finder().and_then(|finder| {
            let tf = Instant::now();
            let found =
                self.correspondence_stage(finder, (model, target), coarse.as_ref(), &mut problem, &mut warnings);
            if let Some(f) = &found {
                times.flow = f.flow_seconds * 1e3;
                times.correspondences = (tf.elapsed().as_secs_f64() - f.flow_seconds).max(0.0) * 1e3;
            }
            found
        });
        if let (Some(t), Some(f)) = (trace.as_deref_mut(), found.as_ref()) {
            let sets = problem.correspondences.iter().chain(&problem.alternative_correspondences);
            t.sets = sets.zip(&f.sources).map(|(pairs, &source)| TracedSet { source, pairs: pairs.clone() }).collect();
        }
        let tr = Instant::now();
        let reg = self.registrar.register_checked(&problem)?;
        if let Some(t) = trace.as_deref_mut() {
            t.kept_set = reg.correspondence_set.or(found.as_ref().map(|_| 0));
        }
        times.registration = tr.elapsed().as_secs_f64() * 1e3;
        let tj = Instant::now();
        let (reg, restored) = self.weigh_overruled_flow(model, target, reg);
        warnings.extend(restored);
        let (reg, judge) = if found.is_some() { self.judge(model, target, &problem, reg)? } else { (reg, None) };
        times.judge = tj.elapsed().as_secs_f64() * 1e3;
        let tp = Instant::now();
        let (reg, aligned) = if found.is_some() { self.aligned(model, target, reg) } else { (reg, None) };
        times.align = tp.elapsed().as_secs_f64() * 1e3;
        times.total = times.depth_model + times.depth_target + t0.elapsed().as_secs_f64() * 1e3;
        let summary = match judge.as_ref().and_then(|j| j.retracked) {
            Some(counts) => Some(summary(counts, true)),
            None => found.map(|f| correspondence_summary(&f, &reg)),
        };
        warnings.extend(reg.warnings.iter().cloned().map(PipelineWarning::from));
        if let (Some(t), Some(j)) = (trace, judge.as_ref()) {
            t.candidates.clone_from(&j.candidates);
            t.answer_score = j.report.as_ref().map(|r| r.answer_score);
        }
        let (report, ambiguity) = judge.map_or((None, None), |j| (j.report, j.warning));
        warnings.extend(ambiguity);
        let mut estimate = self.reported((model, target), &problem, reg, summary, times, warnings);
        estimate.judge = report;
        estimate.align = aligned;
        estimate.geometry_first = first_report;
        Ok(estimate)
    }

    /// A scene's geometry-first try (`[geometry_first]`): the registrar's registration of the
    /// clouds alone ([`Registrar::prior`]; Flow Filter: point-to-plane FilterReg from the initial
    /// pose), then (when it converged) the direct alignment and the images' agreement at the
    /// aligned pose. `None` where it does not apply: off, no flow stage, a registrar without
    /// such a step, not a scene, or the registration refused the clouds (the full pipeline then
    /// reports why).
    fn geometry_first(
        &self,
        model: &PreparedFrame,
        target: &PreparedFrame,
        problem: &RegistrationProblem,
    ) -> Option<FirstTry> {
        let scene = self.config.registration.flowfilter.is_scene(problem);
        if !self.config.geometry_first.enabled || self.finder().is_none() || !scene {
            return None;
        }
        let tr = Instant::now();
        // The registration leaves a thread idle much of its time: the frames' alignment
        // textures, which the alignment below (or the full pipeline's) reads, are built there.
        let (prior, ()) = rayon::join(|| self.registrar.prior(problem), || self.prepare_textures(model, target));
        let prior = prior.ok()??;
        let mut reg = prior.clone();
        flowfilter_registration::assess(problem, &mut reg);
        let registration_ms = tr.elapsed().as_secs_f64() * 1e3;
        let ta = Instant::now();
        let converged = reg.converged;
        let (reg, aligned, agreement) = if converged {
            let (reg, aligned) = self.aligned(model, target, reg);
            let agreement = self.agreement_at(model, target, &reg.transform);
            (reg, aligned, Some(agreement))
        } else {
            (reg, None, None)
        };
        let report = GeometryFirstReport {
            confirmed: agreement.as_ref().is_some_and(|a| self.config.geometry_first.confirms(a)),
            registration_converged: converged,
            score: agreement.as_ref().and_then(|a| a.score),
            visible_fraction: agreement.as_ref().map(judge::Agreement::visible_fraction),
        };
        Some(FirstTry { prior, reg, aligned, report, registration_ms, align_ms: ta.elapsed().as_secs_f64() * 1e3 })
    }

    /// Both frames' textures of the direct alignment, into their caches (when it runs).
    fn prepare_textures(&self, model: &PreparedFrame, target: &PreparedFrame) {
        let cfg = &self.config.align;
        if cfg.enabled {
            rayon::join(
                || align::prepare_textures(&model.image_view(), cfg),
                || align::prepare_textures(&target.image_view(), cfg),
            );
        }
    }

    /// The estimate of a scene whose geometric answer the images confirmed (no flow ran).
    fn kept_on_geometry(
        &self,
        frames: (&PreparedFrame, &PreparedFrame),
        problem: &RegistrationProblem,
        first: FirstTry,
        times: StageTimes,
        mut warnings: Vec<PipelineWarning>,
    ) -> Estimate {
        warnings.extend(first.reg.warnings.iter().cloned().map(PipelineWarning::from));
        let mut estimate = self.reported(frames, problem, first.reg, None, times, warnings);
        estimate.align = first.aligned;
        estimate.geometry_first = Some(first.report);
        estimate
    }

    /// The estimate as reported, whichever path gave `reg`: a bound wider than `[report]
    /// max_bound_deg` warns, and an estimate the evidence does not single out (a doubtful
    /// warning) is not converged: never confidently wrong.
    fn reported(
        &self,
        frames: (&PreparedFrame, &PreparedFrame),
        problem: &RegistrationProblem,
        reg: Registration,
        summary: Option<CorrespondenceSummary>,
        times: StageTimes,
        mut warnings: Vec<PipelineWarning>,
    ) -> Estimate {
        let limit_deg = self.config.report.max_bound_deg;
        if let Some(u) = reg.uncertainty.filter(|u| limit_deg > 0.0 && u.rotation_deg > limit_deg) {
            warnings.push(PipelineWarning::WideBounds { rotation_deg: u.rotation_deg, limit_deg });
        }
        let doubtful = warnings.iter().any(PipelineWarning::is_doubtful);
        let points = (problem.source.len(), problem.target.len());
        let mut estimate = self.assemble(frames, points, reg, summary, times, warnings);
        estimate.registration.converged &= !doubtful;
        estimate
    }

    /// How the target agrees with the model moved by `pose` ([`judge::agreement`], on the
    /// judge's pixels).
    fn agreement_at(&self, model: &PreparedFrame, target: &PreparedFrame, pose: &Pose) -> judge::Agreement {
        let images = judge::Textures::new(&model.image_view(), &target.image_view(), &self.config.judge);
        judge::agreement(&images, pose, &self.config.judge)
    }

    /// The motion from `model` to `target` near a predicted one, on the images alone: the
    /// direct alignment ([`flowfilter_photometric::align()`], `[align]`) from `predicted`, and how
    /// the target agrees with the model at the aligned pose ([`judge::agreement`], on the
    /// judge's pixels). No flow, registration or judge runs: the cheap path of a tracker whose
    /// prediction is good, which must confirm the answer by the agreement before trusting it.
    /// The estimate is converged when the alignment kept its pose; `None` when the images
    /// cannot be aligned (too few object pixels with depth, a flat texture).
    ///
    /// ```
    /// use flowfilter_bigbird::SensorId;
    /// use flowfilter_pipeline::{Pipeline, PipelineConfig, Pose, RgbdFrame};
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
    /// let (a, b) = (pipeline.prepare(&frame(0))?, pipeline.prepare(&frame(2))?);
    /// let truth = pipeline.estimate_prepared(&a, &b)?.pose;
    /// // A prediction half a degree off.
    /// let predicted = flowfilter_geometry::se3::exp(&nalgebra::Vector6::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.5f64.to_radians())) * truth;
    /// let (estimate, agreement) = pipeline.estimate_near(&a, &b, &predicted).expect("textured");
    /// assert!((estimate.pose.inverse() * truth).rotation.angle().to_degrees() < 0.2);
    /// assert!(agreement.visible_fraction() > 0.8);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn estimate_near(
        &self,
        model: &PreparedFrame,
        target: &PreparedFrame,
        predicted: &Pose,
    ) -> Option<(Estimate, judge::Agreement)> {
        let t0 = Instant::now();
        let (pose, report) = align::align(&model.image_view(), &target.image_view(), predicted, &self.config.align)?;
        let align_ms = t0.elapsed().as_secs_f64() * 1e3;
        let agreement = self.agreement_at(model, target, &pose);
        let mut reg = Registration::with_transform(pose);
        reg.iterations = report.iterations;
        reg.converged = report.accepted;
        reg.fitness = agreement.visible_fraction();
        let spent_ms = t0.elapsed().as_secs_f64() * 1e3;
        let times = StageTimes {
            depth_model: model.seconds * 1e3,
            depth_target: target.seconds * 1e3,
            align: align_ms,
            judge: spent_ms - align_ms,
            total: (model.seconds + target.seconds) * 1e3 + spent_ms,
            ..StageTimes::default()
        };
        let mut estimate = self.assemble((model, target), (0, 0), reg, None, times, vec![]);
        estimate.align = Some(report);
        Some((estimate, agreement))
    }

    /// The correspondence stage, its failures turned into warnings: `None` when it did not run.
    fn correspondence_stage(
        &self,
        finder: &dyn CorrespondenceFinder,
        (model, target): (&PreparedFrame, &PreparedFrame),
        coarse: Option<&CoarseView>,
        problem: &mut RegistrationProblem,
        warnings: &mut Vec<PipelineWarning>,
    ) -> Option<FoundSets> {
        if model.sensor.color != target.sensor.color || model.gray.dims() != target.gray.dims() {
            warnings.push(PipelineWarning::FlowSkipped { model: model.label.clone(), target: target.label.clone() });
            return None;
        }
        match self.find_correspondences(finder, (model, target), coarse, problem) {
            Ok(found) => Some(found),
            Err(e) => {
                (problem.correspondences, problem.alternative_correspondences, problem.prior) = (None, vec![], None);
                warnings.push(PipelineWarning::FlowFailed { message: e.to_string() });
                None
            }
        }
    }

    /// The candidate sets of correspondences, put into `problem`: the plain search and, when
    /// `flow.guided` is set and the registrar offers a [`Registrar::prior`], the search guided
    /// by it (the prior is handed back to the registrar, which picks the set).
    fn find_correspondences(
        &self,
        finder: &dyn CorrespondenceFinder,
        (model, target): (&PreparedFrame, &PreparedFrame),
        coarse: Option<&CoarseView>,
        problem: &mut RegistrationProblem,
    ) -> Result<FoundSets, PipelineError> {
        let mut sets = vec![finder.find(model, target)?];
        let mut sources = vec!["plain"];
        // The region tracked again from where a coarse search finds it, when it moved beyond
        // the pyramid's reach (its flow split): one more candidate set for the registration's
        // RANSAC.
        let wide = &self.config.flow.wide;
        // Whether the plain pairs already agree: read by the search, the geometric guide and the
        // guided pass alone.
        let plain = (wide.enabled || self.config.flow.guided).then(|| crate::wide::consensus(&sets[0].pairs, wide));
        let settled = plain.and_then(|c| crate::wide::settled_by(c, &sets[0].pairs, wide));
        let searched;
        let view = match coarse {
            _ if !wide.enabled || settled.is_some() => None,
            Some(view) => Some(view),
            None => {
                searched = CoarseView::new(model, target, wide);
                Some(&searched)
            }
        };
        // Tracked again from a wide-baseline guide: each window's brightness matched when so set.
        let from_wide_guide = |guide: &Pose| match wide.match_brightness {
            true => finder.find_guided_matched(model, target, guide),
            false => finder.find_guided(model, target, guide),
        };
        if let Some(guide) = view.and_then(|view| crate::wide::wide_guide(model, view, wide)) {
            sets.push(from_wide_guide(&guide)?);
            sources.push("wide");
        }
        // The clouds' shapes where the search runs and no set of tracks so far found a motion
        // (no rigid consensus of `settled_min_pairs`, whatever its share): the region tracked
        // again from where a global registration of the two clouds puts it.
        if view.is_some()
            && wide.geometry.enabled
            && plain.flatten().is_none()
            && !sets[1..].iter().any(|set| crate::wide::consensus(&set.pairs, wide).is_some())
            && let Some(guide) = crate::wide::geometric_guide(model, target, wide)
        {
            sets.push(from_wide_guide(&guide)?);
            sources.push("geometry");
        }
        // Feature matches where the search runs: their own set, and the region tracked again
        // from the motion they agree on.
        if view.is_some() && wide.features.enabled {
            let k_sigma = self.config.flow.correspondences.depth_k_sigma;
            let (matched, guide) = crate::wide::feature_guide(model, target, wide, k_sigma);
            sets.push(matched);
            sources.push("features");
            if let Some(guide) = guide {
                sets.push(from_wide_guide(&guide)?);
                sources.push("features-guided");
            }
        }
        if self.config.flow.guided
            && !followed_small_motion(&sets[0], settled.as_ref(), self.config.flow.unguided_below_deg)
            && let Some(prior) = match problem.prior.take() {
                Some(prior) => Some(prior),
                None => self.registrar.prior(problem)?,
            }
        {
            sets.push(finder.find_guided(model, target, &prior.transform)?);
            sources.push("guided");
            problem.prior = Some(prior);
        }
        let found = FoundSets {
            sources,
            counts: sets.iter().map(search_counts).collect(),
            flow_seconds: sets.iter().map(|s| s.flow_seconds).sum(),
        };
        let mut pairs = sets.into_iter().map(|s| s.pairs);
        problem.correspondences = pairs.next();
        problem.alternative_correspondences = pairs.collect();
        Ok(found)
    }

    /// The photometric judge ([`flowfilter_photometric::judge`]) on the registration's answer:
    /// when a turned candidate agrees clearly better with the target image, the flow is tracked
    /// again from it and the registration re-run; that result replaces the answer when it
    /// agrees better.
    fn judge(
        &self,
        model: &PreparedFrame,
        target: &PreparedFrame,
        problem: &RegistrationProblem,
        reg: Registration,
    ) -> Result<(Registration, Option<Judged>), PipelineError> {
        let cfg = &self.config.judge;
        let Some(finder) = self.finder().filter(|_| cfg.enabled) else { return Ok((reg, None)) };
        // Skipped when the flow settled on a small answer: every candidate would contradict it.
        let settled =
            problem.correspondences.as_ref().is_some_and(|plain| evidence_settled(plain, &reg.transform, &cfg.gate));
        if settled {
            return Ok((reg, None));
        }
        let Some(hypotheses) = TurnHypotheses::new(problem, reg.transform, &cfg.sweep) else { return Ok((reg, None)) };
        let images = judge::Textures::new(&model.image_view(), &target.image_view(), cfg);
        let answer_score = judge::photometric_score(&images, &reg.transform, cfg);
        let sweep = judge::sweep(&hypotheses, &images, cfg);
        let candidates: Vec<TracedCandidate> = sweep
            .coarse
            .iter()
            .map(|(c, score)| {
                let a = hypotheses.axes[c.axis].direction;
                TracedCandidate { axis: [a.x, a.y, a.z], turn_deg: c.deg, pose: c.pose, score: *score }
            })
            .collect();
        let Some(answer_score) = answer_score else {
            // No texture to compare: the judge can only say what else the clouds allow.
            let warning = self.ambiguity(&hypotheses, &sweep, None, None);
            return Ok((reg, Some(Judged { report: None, candidates, retracked: None, warning })));
        };
        let best = sweep.best;
        let mut report = JudgeReport {
            answer_score,
            candidates: sweep.coarse.len(),
            best_score: best.map(|b| b.0),
            best_turn_deg: best.map(|b| b.1.deg),
            best_axis: best.map(|b| b.1.axis),
            retracked_score: None,
            replaced: false,
            answer_transform: matrix_rows(&reg.transform),
            retracked_transform: None,
            aligned_answer_score: None,
            aligned_candidate: false,
        };
        // The candidates and the answer aligned on the images (`judge.align_candidates`).
        let quick = self.candidate_alignment();
        let target_view = target.image_view();
        let alignment = (cfg.align_candidates && !sweep.coarse.is_empty())
            .then(|| Alignment::new(&model.image_view(), &target_view, &quick))
            .flatten();
        let aligned_score = |pose: &Pose| alignment.as_ref().and_then(|a| scored_aligned(&images, Some(a), pose, cfg));
        let aligned_answer = aligned_score(&reg.transform).map(|(s, _)| s);
        report.aligned_answer_score = aligned_answer;
        // The distinct candidates aligned and scored: what aligned candidates are judged by, and
        // what the ambiguity is then read from.
        let aligned: Vec<(TurnCandidate, Option<f64>, Pose)> = match aligned_answer {
            // Each candidate aligned on its own (a few hundred pixels: too few to split), side by
            // side; collected in order, so the same answer with any thread count.
            Some(_) => distinct_candidates(&sweep, DISTINCT_TURN_DEG)
                .into_par_iter()
                .map(|c| match aligned_score(&c.pose) {
                    Some((s, p)) => (c, Some(s), p),
                    None => (c, None, c.pose),
                })
                .collect(),
            None => vec![],
        };
        let aligned_sweep = judge::Sweep { coarse: aligned.iter().map(|(c, s, _)| (*c, *s)).collect(), best: None };
        let aligned_best = aligned_answer.and_then(|answer| {
            let scored = aligned.iter().filter_map(|(c, s, p)| s.map(|s| (s, *p, *c)));
            scored.min_by(|a, b| a.0.total_cmp(&b.0)).filter(|(s, _, _)| *s < cfg.ratio * answer)
        });
        // The flow re-tracked from the best candidate as scored without alignment.
        let retracked = match best.filter(|(s, _)| *s < cfg.ratio * answer_score) {
            Some((_, candidate)) => self
                .retracked(finder, model, target, problem, &candidate.pose)?
                .map(|(r, counts)| (r, counts, candidate)),
            None => None,
        };
        if let Some((again, _, _)) = &retracked {
            report.retracked_score = judge::photometric_score(&images, &again.transform, cfg);
            report.retracked_transform = Some(matrix_rows(&again.transform));
        }
        let kept = |report: JudgeReport| {
            let warning = match aligned_answer {
                Some(a) => self.ambiguity(&hypotheses, &aligned_sweep, Some(a), None),
                None => self.ambiguity(&hypotheses, &sweep, Some(answer_score), None),
            };
            Judged { report: Some(report), candidates: candidates.clone(), retracked: None, warning }
        };
        // The re-tracked result is taken when it matches the image better than the answer (and,
        // with an aligned candidate in play, when aligned alike it matches at least as well as
        // that candidate); else a clearly better aligned candidate is taken.
        let retracked_wins = retracked.as_ref().is_some_and(|(again, _, _)| match &aligned_best {
            Some((s, _, _)) => aligned_score(&again.transform).is_some_and(|(r, _)| r <= *s),
            None => report.retracked_score.is_some_and(|r| r < answer_score),
        });
        if let Some((again, counts, candidate)) = retracked.filter(|_| retracked_wins) {
            report.replaced = true;
            let score = report.retracked_score.unwrap_or(answer_score);
            let warning = self.ambiguity(&hypotheses, &sweep, Some(score), Some((candidate.axis, candidate.deg)));
            return Ok((again, Some(Judged { report: Some(report), candidates, retracked: Some(counts), warning })));
        }
        let Some((score, pose, candidate)) = aligned_best else { return Ok((reg, Some(kept(report)))) };
        report.replaced = true;
        report.aligned_candidate = true;
        report.retracked_score = Some(score);
        report.retracked_transform = Some(matrix_rows(&pose));
        let warning = self.ambiguity(&hypotheses, &aligned_sweep, Some(score), Some((candidate.axis, candidate.deg)));
        Ok((moved_to(reg, pose), Some(Judged { report: Some(report), candidates, retracked: None, warning })))
    }

    /// The flow's result where a geometric check overruled it and the images match it clearly
    /// better ([`judge::JudgeConfig::weigh_overruled_flow`]): each pose aligned as the judge's
    /// candidates are, then scored on the judge's grid; the flow's is kept when its score is
    /// below `ratio` times the check's and at most `restore_max_score`. Else the registration as
    /// it came (without the overruled result).
    fn weigh_overruled_flow(
        &self,
        model: &PreparedFrame,
        target: &PreparedFrame,
        mut reg: Registration,
    ) -> (Registration, Option<PipelineWarning>) {
        let cfg = &self.config.judge;
        let Some(flow) = reg.overruled_flow.take() else { return (reg, None) };
        if !cfg.enabled || !cfg.weigh_overruled_flow {
            return (reg, None);
        }
        let images = judge::Textures::new(&model.image_view(), &target.image_view(), cfg);
        let quick = self.candidate_alignment();
        let target_view = target.image_view();
        let alignment =
            cfg.align_candidates.then(|| Alignment::new(&model.image_view(), &target_view, &quick)).flatten();
        let score = |pose: &Pose| scored_aligned(&images, alignment.as_ref(), pose, cfg).map(|(s, _)| s);
        let (Some(check_score), Some(flow_score)) = (score(&reg.transform), score(&flow.transform)) else {
            return (reg, None);
        };
        if flow_score >= cfg.ratio * check_score || flow_score > cfg.restore_max_score {
            return (reg, None);
        }
        let check =
            reg.warnings
                .iter()
                .find_map(|w| match w {
                    RegistrationWarning::MotionCheck { kept, .. }
                    | RegistrationWarning::GeometricCheck { kept, .. } => Some(*kept),
                    _ => None,
                })
                .unwrap_or("a geometric registration");
        (*flow, Some(PipelineWarning::FlowRestored { check, flow_score, check_score }))
    }

    /// The alignment the judge runs on its candidates: `[align]` with `judge.candidate_pixels`
    /// and `judge.candidate_iterations`.
    fn candidate_alignment(&self) -> AlignConfig {
        let cfg = &self.config.judge;
        AlignConfig {
            max_pixels: cfg.candidate_pixels,
            // The judge's own grid: its candidates are compared on those pixels.
            stride: cfg.stride,
            min_pixels: self.config.align.min_pixels.min(cfg.candidate_pixels),
            iterations: cfg.candidate_iterations,
            symmetric: false,
            row_shear_sd: 0.0,
            depth_step_at_1m_m: 0.0,
            ..self.config.align.clone()
        }
    }

    /// The registration's pose refined by the direct alignment
    /// ([`flowfilter_photometric::align()`]), when it is enabled and the images can be aligned;
    /// its error bounds widened by the alignment's move.
    fn aligned(
        &self,
        model: &PreparedFrame,
        target: &PreparedFrame,
        reg: Registration,
    ) -> (Registration, Option<AlignReport>) {
        let cfg = &self.config.align;
        if !cfg.enabled {
            return (reg, None);
        }
        let Some((pose, report)) = align::align(&model.image_view(), &target.image_view(), &reg.transform, cfg) else {
            return (reg, None);
        };
        // The registration's bounds hold for its own pose: widened by the alignment's move, they
        // hold for the aligned one.
        (moved_to(reg, pose), Some(report))
    }

    /// The registration with the flow tracked again from `guide` (where the flow follows the
    /// texture), and that search's counts (tracked, consistent, inliers); `None` when the
    /// search fails.
    fn retracked(
        &self,
        finder: &dyn CorrespondenceFinder,
        model: &PreparedFrame,
        target: &PreparedFrame,
        problem: &RegistrationProblem,
        guide: &Pose,
    ) -> Result<Option<(Registration, SearchCounts)>, PipelineError> {
        let Ok(found) = finder.find_guided(model, target, guide) else { return Ok(None) };
        let counts = search_counts(&found);
        // From the original start: the guide is only where the flow was tracked from (a
        // registration started there slides back along the symmetry, which the motion check
        // would then take for the geometry's own answer).
        let mut retry = problem.geometry_only().with_correspondences(found.pairs);
        retry.prior.clone_from(&problem.prior);
        Ok(Some((self.registrar.register_checked(&retry)?, counts)))
    }

    /// [`judge::ambiguity`] as a warning (the axis in the model frame).
    fn ambiguity(
        &self,
        hypotheses: &TurnHypotheses,
        sweep: &judge::Sweep,
        score: Option<f64>,
        at: Option<(usize, f64)>,
    ) -> Option<PipelineWarning> {
        let (axis, turns_deg) = judge::ambiguity(sweep, score, at, &self.config.judge)?;
        let a = hypotheses.axes[axis];
        Some(PipelineWarning::AmbiguousPose {
            axis: [a.direction.x, a.direction.y, a.direction.z],
            pivot_m: [a.pivot.x, a.pivot.y, a.pivot.z],
            turns_deg,
        })
    }

    /// The estimate from the registration (of clouds of `points`, model and target) and what
    /// the stages reported.
    fn assemble(
        &self,
        (model, target): (&PreparedFrame, &PreparedFrame),
        points: (usize, usize),
        reg: Registration,
        correspondences: Option<CorrespondenceSummary>,
        stage_ms: StageTimes,
        warnings: Vec<PipelineWarning>,
    ) -> Estimate {
        let (axis, angle) = reg.transform.rotation.axis_angle().map_or(([0.0; 3], 0.0), |(a, t)| ([a.x, a.y, a.z], t));
        let t = reg.transform.translation.vector;
        Estimate {
            schema: ESTIMATE_SCHEMA,
            method: self.registrar.name().to_string(),
            flow_estimator: self.finder().map(|f| f.name().to_string()),
            model: model.label.clone(),
            target: target.label.clone(),
            transform: matrix_rows(&reg.transform),
            rotation_angle_deg: angle.to_degrees(),
            rotation_axis: axis,
            translation_m: [t.x, t.y, t.z],
            registration: RegistrationSummary::new(&reg, points.0, points.1),
            correspondences,
            stage_ms,
            judge: None,
            align: None,
            geometry_first: None,
            warnings,
            ground_truth: None,
            pose: reg.transform,
        }
    }
}

/// A correspondence search's counts: pixels tracked, pairs found (consistent), pairs with a
/// positive weight (inliers).
type SearchCounts = (usize, usize, usize);

/// The judge's report (none when the texture is flat) and, when its re-tracked result replaced
/// the answer, that search's counts (tracked, consistent, inliers).
struct Judged {
    report: Option<JudgeReport>,
    /// The candidates weighed, with their scores (for [`PairTrace`]).
    candidates: Vec<TracedCandidate>,
    retracked: Option<SearchCounts>,
    /// Other poses that the clouds and the images allow as well.
    warning: Option<PipelineWarning>,
}

/// Candidates whose poses turn less than this from each other (degrees) are aligned once.
const DISTINCT_TURN_DEG: f64 = 0.5;

/// `pose` aligned on the images by `alignment` (as it is where there is none, or the alignment
/// cannot run), and its texture score there: the score and the aligned pose.
fn scored_aligned(
    images: &judge::Textures<'_>,
    alignment: Option<&Alignment<'_>>,
    pose: &Pose,
    cfg: &judge::JudgeConfig,
) -> Option<(f64, Pose)> {
    let aligned = alignment.and_then(|a| a.run(pose)).map_or(*pose, |(p, _)| p);
    judge::photometric_score(images, &aligned, cfg).map(|s| (s, aligned))
}

/// The sweep's coarse candidates without those whose pose turns less than `within_deg` from
/// one already kept (about a can's axis two of the three axes give nearly the same turns).
fn distinct_candidates(sweep: &judge::Sweep, within_deg: f64) -> Vec<TurnCandidate> {
    let mut kept: Vec<TurnCandidate> = Vec::new();
    for (c, _) in &sweep.coarse {
        if kept.iter().all(|k| (c.pose * k.pose.inverse()).rotation.angle().to_degrees() >= within_deg) {
            kept.push(*c);
        }
    }
    kept
}

/// `reg` moved to `pose`: its error bounds (which held for its own pose) widened by the move.
fn moved_to(mut reg: Registration, pose: Pose) -> Registration {
    if let Some(u) = reg.uncertainty.as_mut() {
        u.rotation_deg += (pose * reg.transform.inverse()).rotation.angle().to_degrees();
        u.translation_m += (pose.translation.vector - reg.transform.translation.vector).norm();
    }
    reg.transform = pose;
    reg
}

/// Whether the plain pass followed a small motion: its pairs settled on one rigid motion turning
/// less than `below_deg`, and at least [`FOLLOWED_FRACTION`] of the pixels it tracked survived
/// its consistency checks (a pyramid that lost most of them can agree on a wrong motion: a
/// whole shelf frame turned 25 degrees kept 207 of 4491, on a turn under 10).
fn followed_small_motion(plain: &FlowPairs, settled: Option<&Pose>, below_deg: f64) -> bool {
    let kept = plain.pairs.len() as f64 >= FOLLOWED_FRACTION * plain.tracked as f64;
    kept && settled.is_some_and(|motion| motion.rotation.angle().to_degrees() < below_deg)
}

/// See [`followed_small_motion`].
const FOLLOWED_FRACTION: f64 = 0.5;

/// A search's counts.
fn search_counts(s: &FlowPairs) -> SearchCounts {
    (s.tracked, s.pairs.len(), s.pairs.usable())
}

/// The summary of a search with these counts.
fn summary((tracked, consistent, inliers): SearchCounts, guided: bool) -> CorrespondenceSummary {
    CorrespondenceSummary { tracked, consistent, inliers, guided }
}

/// The counts of the set the registrar used (the first when it does not say).
fn correspondence_summary(found: &FoundSets, reg: &Registration) -> CorrespondenceSummary {
    let set = reg.correspondence_set.filter(|&k| k < found.counts.len()).unwrap_or(0);
    summary(found.counts[set], set > 0)
}
