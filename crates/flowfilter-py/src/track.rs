//! `flowfilter.Tracker`: an RGB-D stream, one frame at a time, the object's motion from the
//! first frame out (`flowfilter track`).

use crate::estimate::Estimate;
use crate::frame::{camera_arg, frame_arg};
use crate::{arrays, params, threads};
use flowfilter_pipeline::{Pipeline, RgbdFrame};
use flowfilter_track::boxed::{BoxError, PixelBox, first_mask};
use flowfilter_track::{TrackState, TrackedFrame, TrackerConfig};
use pyo3::prelude::*;
use serde::Serialize;
use std::sync::Mutex;

/// The tracker's report on one frame.
#[derive(Debug, Clone, Serialize)]
pub struct TrackInfo {
    pub index: usize,
    pub state: &'static str,
    pub reason: Option<String>,
    pub reference: Option<usize>,
    pub keyframe: bool,
    pub mask_px: usize,
    pub aligned_only: bool,
    pub prepared_region: Option<(usize, usize, usize, usize)>,
}

fn state_name(s: TrackState) -> &'static str {
    match s {
        TrackState::Tracking => "tracking",
        TrackState::Uncertain => "uncertain",
        TrackState::Lost => "lost",
        TrackState::Recovered => "recovered",
    }
}

/// Tracks an object through a stream of RGB-D frames of one camera from its mask in the first
/// frame (without a mask, the whole scene): `Tracker(camera, frame, mask=None, config=None)`,
/// then `update(frame)` for each later frame (no mask needed), which returns an `Estimate` of
/// the object's motion from the first frame with the track's `state`, `reason`, `reference`,
/// `keyframe` and `frame_index`. Frames are `Frame`s or `open3d.geometry.RGBDImage`s; calls
/// release the GIL.
#[pyclass(module = "flowfilter")]
pub struct Tracker {
    inner: Mutex<flowfilter_track::Tracker>,
    camera: Option<flowfilter_pipeline::CameraFile>,
    first: String,
    method: String,
}

impl Tracker {
    /// The tracker, or an error when an earlier call panicked while holding it.
    fn locked(&self) -> PyResult<std::sync::MutexGuard<'_, flowfilter_track::Tracker>> {
        self.inner.lock().map_err(|_| crate::errors::input("the tracker failed in an earlier call"))
    }

    fn rgbd(&self, frame: &Bound<'_, PyAny>, name: &str) -> PyResult<RgbdFrame> {
        frame_arg(frame, name)?.rgbd(self.camera.as_ref())
    }
}

#[pymethods]
impl Tracker {
    /// Start on `frame` (a `Frame`): `mask` ((H, W) bool, or the frame's own) is the object's;
    /// or `bbox = (x, y, w, h)` (pixels: left, top, width, height), a box around it: the
    /// object is the box's pixels within 5 cm of the depth of the box's central half. Without
    /// either the whole scene is tracked. `camera`: as `estimate`'s (None for frames read from a
    /// dataset). `config`: a pipeline configuration (TOML path or dict). `settings`: the
    /// tracker's own (a dict of `flowfilter_track::TrackerConfig`'s keys, e.g.
    /// `{"aligned_path": True}`; the defaults otherwise).
    ///
    /// Raises InputError for a frame that cannot be used (no depth in the mask), a box outside
    /// the image or given with a mask, ConfigError for a bad configuration or setting.
    #[new]
    #[pyo3(signature = (camera, frame, mask = None, config = None, bbox = None, settings = None))]
    fn new(
        py: Python<'_>,
        camera: Option<&Bound<'_, PyAny>>,
        frame: &Bound<'_, PyAny>,
        mask: Option<&Bound<'_, PyAny>>,
        config: Option<&Bound<'_, PyAny>>,
        bbox: Option<(usize, usize, usize, usize)>,
        settings: Option<&Bound<'_, pyo3::types::PyDict>>,
    ) -> PyResult<Self> {
        let config = params::pipeline_config(config)?;
        let settings = tracker_settings(settings)?;
        let method = config.method.clone();
        let pipeline = Pipeline::from_config(config).map_err(|e| crate::errors::pipeline(&e))?;
        let camera = camera.filter(|c| !c.is_none()).map(camera_arg).transpose()?;
        let mut first = frame_arg(frame, "frame")?.rgbd(camera.as_ref())?;
        if let Some(m) = mask.filter(|m| !m.is_none()) {
            let m = arrays::mask(&crate::open3d::image(m, "mask")?, "mask")?;
            if m.dims() != first.mask.dims() {
                let ((w, h), (fw, fh)) = (m.dims(), first.mask.dims());
                return Err(crate::errors::input(format!("mask: {w}x{h}, but the frame is {fw}x{fh}")));
            }
            first.mask = m;
        }
        if let Some((x, y, width, height)) = bbox {
            if mask.is_some_and(|m| !m.is_none()) {
                return Err(crate::errors::input("give a mask or a bbox, not both"));
            }
            let rect = PixelBox { x, y, width, height };
            first.mask = threads::run(py, || first_mask(&pipeline, &first, rect))?.map_err(|e| match e {
                BoxError::Frame(e) => crate::errors::pipeline(&e),
                unusable => crate::errors::input(format!("bbox: {unusable}")),
            })?;
        }
        let label = first.label.clone();
        let tracker = threads::run(py, || flowfilter_track::Tracker::new(pipeline, settings, &first))?
            .map_err(|e| crate::errors::input(crate::errors::message(&e)))?;
        Ok(Self { inner: Mutex::new(tracker), camera, first: label, method })
    }

    /// The next frame of the stream: the object's motion from the first frame, as an
    /// `Estimate` with the track's state. A frame that cannot be used (another size, no depth)
    /// is `lost` with the reason, not an exception.
    fn update(&self, py: Python<'_>, frame: &Bound<'_, PyAny>) -> PyResult<Estimate> {
        let rgbd = self.rgbd(frame, "frame").map_err(|e| e.to_string());
        let mut inner = self.locked()?;
        let tracker: &mut flowfilter_track::Tracker = &mut inner;
        let tracked: TrackedFrame = threads::run(py, || tracker.update(rgbd))?;
        Ok(estimate_of(&tracked, &self.first, &self.method))
    }

    /// Stream indices of the keyframes held now.
    fn keyframes(&self) -> PyResult<Vec<usize>> {
        let inner = self.locked()?;
        Ok(inner.keyframes())
    }

    /// The object's mask in the last frame as the tracker carried it there ((H, W) bool: what
    /// the next frame's mask is predicted from; with the `reveal` setting, grown onto the faces
    /// turning into view); None when tracking the whole scene or after a lost frame.
    fn object_mask<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        let inner = self.locked()?;
        Ok(inner.object_mask().map(|m| arrays::grid_array(py, m).into_any()))
    }

    fn __repr__(&self) -> String {
        format!("Tracker(first='{}', method='{}')", self.first, self.method)
    }
}

/// The tracker's settings from a dict of their keys (the defaults for the others).
fn tracker_settings(settings: Option<&Bound<'_, pyo3::types::PyDict>>) -> PyResult<TrackerConfig> {
    let Some(d) = settings else { return Ok(TrackerConfig::default()) };
    let value = serde_json::Value::Object(params::dict_to_json(d, "settings")?);
    serde_json::from_value(value).map_err(|e| crate::errors::config(format!("settings: {e}")))
}

fn estimate_of(t: &TrackedFrame, first: &str, method: &str) -> Estimate {
    Estimate {
        estimate: t.from_first(first, method),
        track: Some(TrackInfo {
            index: t.index,
            state: state_name(t.state),
            reason: t.reason.clone(),
            reference: t.reference,
            keyframe: t.keyframe,
            mask_px: t.mask_px,
            aligned_only: t.aligned_only,
            prepared_region: t.prepared_region.map(|r| (r.x, r.y, r.width, r.height)),
        }),
    }
}
