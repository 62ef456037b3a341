//! `flowfilter.estimate` and `flowfilter.correspondences`: two RGB-D frames through the
//! pipeline (`flowfilter estimate`).

use crate::arrays::{self, json_object, matrix, rows_array};
use crate::errors::pipeline;
use crate::frame::{camera_arg, frame_arg};
use crate::{params, threads};
use flowfilter_pipeline::{
    CorrespondenceFinder, DepthPreparer, FlowCorrespondenceFinder, FramePreparer, Pipeline, PipelineError, Pose,
    RgbdFrame,
};
use numpy::{PyArray1, PyArray2};
use pyo3::prelude::*;

/// The pipeline's estimate: the fields of `flowfilter estimate --json` (schema
/// "flowfilter estimate v3").
#[pyclass(module = "flowfilter", frozen)]
pub struct Estimate {
    pub(crate) estimate: flowfilter_pipeline::Estimate,
    /// The tracker's report, for an estimate made by `Tracker.update`.
    pub(crate) track: Option<crate::track::TrackInfo>,
}

#[pymethods]
impl Estimate {
    /// The 4x4 float64 transform `T` with `target ~ T @ model` (colour camera frame).
    #[getter]
    fn transform<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        matrix(py, &self.estimate.transform)
    }
    /// The same as `transform` (Open3D's name).
    #[getter]
    fn transformation<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        matrix(py, &self.estimate.transform)
    }
    /// Log the estimate to Rerun (needs `rerun-sdk`): the pose, its bounds and its error when
    /// known, the judge's scores, the stage times, the warnings and the summary, at the entity
    /// paths of `flowfilter estimate --rerun` (docs/rerun.md), at step `step` of the `pair`
    /// timeline. `model`/`target`: the two `Frame`s, to log their colour, depth and masks too.
    /// `recording`: a `rerun.RecordingStream` (None: the current one).
    ///
    /// Raises ImportError without rerun-sdk, InputError for frames that are not `Frame`s.
    #[pyo3(signature = (model = None, target = None, recording = None, step = 0))]
    fn log_to_rerun(
        slf: &Bound<'_, Self>,
        model: Option<&Bound<'_, PyAny>>,
        target: Option<&Bound<'_, PyAny>>,
        recording: Option<&Bound<'_, PyAny>>,
        step: i64,
    ) -> PyResult<()> {
        let log = PyModule::import(slf.py(), "flowfilter._rerun")?.getattr("log_estimate")?;
        log.call1((slf, model, target, recording, step))?;
        Ok(())
    }
    /// Registration method.
    #[getter]
    fn method(&self) -> &str {
        &self.estimate.method
    }
    /// Flow estimator, for methods that use flow; else None.
    #[getter]
    fn flow_estimator(&self) -> Option<&str> {
        self.estimate.flow_estimator.as_deref()
    }
    /// Model frame's name.
    #[getter]
    fn model(&self) -> &str {
        &self.estimate.model
    }
    /// Target frame's name.
    #[getter]
    fn target(&self) -> &str {
        &self.estimate.target
    }
    /// Rotation angle of `T`, degrees.
    #[getter]
    fn rotation_angle_deg(&self) -> f64 {
        self.estimate.rotation_angle_deg
    }
    /// Unit rotation axis of `T` (`[0, 0, 0]` without rotation).
    #[getter]
    fn rotation_axis(&self) -> [f64; 3] {
        self.estimate.rotation_axis
    }
    /// Translation of `T`, metres.
    #[getter]
    fn translation_m(&self) -> [f64; 3] {
        self.estimate.translation_m
    }
    /// The backend's report: iterations, converged, fitness, inlier_rmse_m, sigma2,
    /// model_points, target_points and, for Flow Filter, uncertainty.
    #[getter]
    fn registration<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_object(py, &self.estimate.registration)
    }
    /// Flow correspondences (tracked, consistent, inliers, guided), or None without flow.
    #[getter]
    fn correspondences<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_object(py, &self.estimate.correspondences)
    }
    /// Milliseconds per stage.
    #[getter]
    fn stage_ms<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_object(py, &self.estimate.stage_ms)
    }
    /// Conditions to know about, as dicts `{"code", "message"}`.
    #[getter]
    fn warnings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_object(py, &self.estimate.warnings)
    }
    /// What the photometric judge saw (answer_score, candidates, best_score, best_turn_deg,
    /// best_axis, retracked_score, replaced, answer_transform, retracked_transform,
    /// aligned_answer_score, aligned_candidate), or None for methods without flow and where the
    /// texture is flat.
    #[getter]
    fn judge<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_object(py, &self.estimate.judge)
    }
    /// What the direct alignment did (pixels, iterations, cost_before, cost_after, turn_deg,
    /// shift_m, row_shear_px_per_row, accepted), or None for methods without flow and where the
    /// images cannot be aligned.
    #[getter]
    fn align<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_object(py, &self.estimate.align)
    }
    /// A scene's geometry-first try (confirmed, registration_converged, score,
    /// visible_fraction): whether its geometric registration was kept without flow; None where
    /// no try ran (not a scene, not a Flow Filter method).
    #[getter]
    fn geometry_first<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_object(py, &self.estimate.geometry_first)
    }
    /// The true transform and the errors against it, when `gt` was given; else None.
    #[getter]
    fn ground_truth<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_object(py, &self.estimate.ground_truth)
    }
    /// The estimate as `flowfilter estimate --json` prints it.
    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let d = json_object(py, &self.estimate)?;
        if let Some(t) = &self.track {
            d.set_item("track", json_object(py, t)?)?;
        }
        Ok(d)
    }
    /// For `Tracker.update`'s estimates: the track's state at this frame (`tracking`,
    /// `uncertain`, `lost`, `recovered`); None for a pairwise estimate.
    #[getter]
    fn state(&self) -> Option<&'static str> {
        self.track.as_ref().map(|t| t.state)
    }
    /// For `Tracker.update`'s estimates: why the state is not `tracking` (or what the estimate
    /// warned of); else None.
    #[getter]
    fn reason(&self) -> Option<&str> {
        self.track.as_ref().and_then(|t| t.reason.as_deref())
    }
    /// For `Tracker.update`'s estimates: the stream index of the frame measured against (None
    /// when lost).
    #[getter]
    fn reference(&self) -> Option<usize> {
        self.track.as_ref().and_then(|t| t.reference)
    }
    /// For `Tracker.update`'s estimates: whether this frame became a keyframe.
    #[getter]
    fn keyframe(&self) -> Option<bool> {
        self.track.as_ref().map(|t| t.keyframe)
    }
    /// For `Tracker.update`'s estimates: whether the pose came from direct alignment alone from
    /// the motion's prediction, confirmed on the images (no flow, registration or judge).
    #[getter]
    fn aligned_only(&self) -> Option<bool> {
        self.track.as_ref().map(|t| t.aligned_only)
    }
    /// For `Tracker.update`'s estimates: the part of the image the frame was prepared on,
    /// `(x, y, width, height)` in pixels (the object's predicted region); `None` for the whole
    /// image (and for pair estimates).
    #[getter]
    fn prepared_region(&self) -> Option<(usize, usize, usize, usize)> {
        self.track.as_ref().and_then(|t| t.prepared_region)
    }
    /// For `Tracker.update`'s estimates: the frame's index in the stream (0: the first).
    #[getter]
    fn frame_index(&self) -> Option<usize> {
        self.track.as_ref().map(|t| t.index)
    }
    fn __repr__(&self) -> String {
        let e = &self.estimate;
        format!(
            "Estimate(method='{}', model='{}', target='{}', rotation_angle_deg={:.4}, converged={})",
            e.method,
            e.model,
            e.target,
            e.rotation_angle_deg,
            if e.registration.converged { "True" } else { "False" }
        )
    }
}

/// Both frames as the pipeline's, with the camera argument when given.
pub(crate) fn frames(
    model: &Bound<'_, PyAny>,
    target: &Bound<'_, PyAny>,
    camera: Option<&Bound<'_, PyAny>>,
) -> PyResult<(RgbdFrame, RgbdFrame)> {
    let camera = camera.filter(|c| !c.is_none()).map(camera_arg).transpose()?;
    let (a, b) = (frame_arg(model, "model")?, frame_arg(target, "target")?);
    Ok((a.rgbd(camera.as_ref())?, b.rgbd(camera.as_ref())?))
}

/// The relative pose of the object between two RGB-D frames of one camera: `T` with
/// `target ~ T @ model`.
///
/// `model`, `target`: `Frame`s (arrays, or read by `read_bop_frame` / `read_bigbird_frame` /
/// `read_frame`). `camera`: a `Camera`, a camera-file path or a dict (required for frames made
/// from arrays). `method`: the registration method (it replaces the configuration's; None
/// keeps the configuration's). `config`: a pipeline configuration, as a TOML file path or a
/// dict of the same tables (`configs/flowfilter.toml`). `gt`: the true 4x4 motion, for the
/// errors in `ground_truth`.
///
/// Raises InputError for frames that cannot be used, ConfigError for a bad configuration.
#[pyfunction]
#[pyo3(signature = (model, target, camera = None, method = Some("flowfilter"), config = None, *, gt = None))]
#[pyo3(text_signature = "(model, target, camera=None, method='flowfilter', config=None, *, gt=None)")]
pub fn estimate(
    py: Python<'_>,
    model: &Bound<'_, PyAny>,
    target: &Bound<'_, PyAny>,
    camera: Option<&Bound<'_, PyAny>>,
    method: Option<&str>,
    config: Option<&Bound<'_, PyAny>>,
    gt: Option<&Bound<'_, PyAny>>,
) -> PyResult<Estimate> {
    let mut config = params::pipeline_config(config)?;
    if let Some(m) = method {
        config.method = m.into();
    }
    let pipeline = Pipeline::from_config(config).map_err(|e| crate::errors::pipeline(&e))?;
    let (fa, fb) = frames(model, target, camera)?;
    let truth: Option<Pose> = gt.filter(|g| !g.is_none()).map(|g| arrays::pose(g, "gt")).transpose()?;
    let result = threads::run(py, || pipeline.estimate_against(&fa, &fb, truth.as_ref()))?;
    result.map(|(estimate, _, _)| Estimate { estimate, track: None }).map_err(|e| crate::errors::pipeline(&e))
}

/// Flow correspondences between two frames: model points (colour camera frame) and where the
/// flow puts them in the target frame.
#[pyclass(module = "flowfilter", frozen)]
pub struct Correspondences {
    pairs: flowfilter_pipeline::Correspondences,
    tracked: usize,
}

#[pymethods]
impl Correspondences {
    /// Model-frame points, (K, 3) float64, metres.
    #[getter]
    fn source<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        rows_array(py, &self.pairs.source)
    }
    /// Target-frame points, (K, 3) float64.
    #[getter]
    fn target<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        rows_array(py, &self.pairs.target)
    }
    /// Weights in [0, 1], (K,) float64 (0: rejected by the depth-change fit).
    #[getter]
    fn weights<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.pairs.weights)
    }
    /// Model pixels tracked before any check.
    #[getter]
    fn tracked(&self) -> usize {
        self.tracked
    }
    fn __len__(&self) -> usize {
        self.pairs.len()
    }
    fn __repr__(&self) -> String {
        format!("Correspondences({} pairs, {} usable, {} tracked)", self.pairs.len(), self.pairs.usable(), self.tracked)
    }
}

/// The pipeline's flow correspondences between two frames (its depth stage, flow estimator
/// and checks, from `config`); with `init` (a 4x4 predicted motion) tracking is guided by it.
/// Pass the result to `register(..., method="flowfilter", correspondences=(c.source, c.target,
/// c.weights))`.
///
/// Raises InputError for frames that cannot be used, ConfigError for a bad configuration.
#[pyfunction]
#[pyo3(signature = (model, target, camera = None, config = None, init = None))]
pub fn correspondences(
    py: Python<'_>,
    model: &Bound<'_, PyAny>,
    target: &Bound<'_, PyAny>,
    camera: Option<&Bound<'_, PyAny>>,
    config: Option<&Bound<'_, PyAny>>,
    init: Option<&Bound<'_, PyAny>>,
) -> PyResult<Correspondences> {
    let config = params::pipeline_config(config)?;
    let preparer = DepthPreparer::new(config.depth.clone(), config.cloud.clone()).map_err(|e| pipeline(&e))?;
    let estimator = config.flow.estimator().map_err(|e| crate::errors::flow(&e))?;
    let finder = FlowCorrespondenceFinder::new(estimator, config.flow.correspondences.clone());
    let (fa, fb) = frames(model, target, camera)?;
    let init: Option<Pose> = init.filter(|i| !i.is_none()).map(|i| arrays::pose(i, "init")).transpose()?;
    let found = threads::run(py, || -> Result<_, PipelineError> {
        let (a, b) = (preparer.prepare(&fa)?, preparer.prepare(&fb)?);
        match init {
            Some(pose) => finder.find_guided(&a, &b, &pose),
            None => finder.find(&a, &b),
        }
    })?
    .map_err(|e| pipeline(&e))?;
    Ok(Correspondences { pairs: found.pairs, tracked: found.tracked })
}
