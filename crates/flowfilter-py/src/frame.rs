//! `flowfilter.Camera` and `flowfilter.Frame`: a camera (any of the camera-file layouts) and one
//! RGB-D view as arrays, turned into the pipeline's frame.

use crate::arrays::{self, DepthArray, color_array, grid_array};
use crate::errors::{input, pipeline};
use crate::params::to_json;
use flowfilter_pipeline::{CameraFile, ImagesError, Mask, RawDepth, RgbdFrame};
use image::RgbImage;
use numpy::PyArray2;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use serde_json::json;
use std::path::PathBuf;

/// A camera: intrinsics, optional image size and distortion, the depth unit, and optionally a
/// separate depth camera (in a camera file).
#[pyclass(module = "flowfilter", frozen)]
#[derive(Clone)]
pub struct Camera {
    pub file: CameraFile,
}

fn camera_error(e: &flowfilter_pipeline::camera::CameraFileError) -> PyErr {
    input(crate::errors::message(e))
}

#[pymethods]
impl Camera {
    /// A camera from its 3x3 intrinsic matrix `K` (pixels), optional `width` and `height`
    /// (else the images' size), `depth_unit` (metres per raw depth unit, e.g. 0.001 for
    /// millimetres) and `distortion` (`k1, k2, p1, p2, k3`, OpenCV's order).
    #[new]
    #[pyo3(signature = (K, width = None, height = None, depth_unit = None, distortion = None))]
    #[allow(non_snake_case)]
    fn new(
        K: &Bound<'_, PyAny>,
        width: Option<u32>,
        height: Option<u32>,
        depth_unit: Option<f64>,
        distortion: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let mut v = json!({ "K": to_json(K, "K").map_err(|e| input(e.to_string()))? });
        if let Some(w) = width {
            v["width"] = json!(w);
        }
        if let Some(h) = height {
            v["height"] = json!(h);
        }
        if let Some(u) = depth_unit {
            v["depth_unit_m"] = json!(u);
        }
        if let Some(d) = distortion {
            v["distortion"] = to_json(d, "distortion").map_err(|e| input(e.to_string()))?;
        }
        CameraFile::from_json_value(&v, "Camera(...)").map(|file| Self { file }).map_err(|e| camera_error(&e))
    }

    /// A camera file: this project's JSON, a BOP `scene_camera.json` entry or `camera.json`, or
    /// Open3D's `PinholeCameraIntrinsic` JSON.
    #[staticmethod]
    pub fn from_file(path: PathBuf) -> PyResult<Self> {
        CameraFile::from_file(&path).map(|file| Self { file }).map_err(|e| camera_error(&e))
    }

    /// A camera from a dict in any of the camera-file layouts.
    #[staticmethod]
    pub fn from_dict(d: &Bound<'_, PyDict>) -> PyResult<Self> {
        let v = to_json(d.as_any(), "camera").map_err(|e| input(e.to_string()))?;
        CameraFile::from_json_value(&v, "<dict>").map(|file| Self { file }).map_err(|e| camera_error(&e))
    }

    /// The 3x3 intrinsic matrix (float64).
    #[getter]
    #[allow(non_snake_case)]
    fn K<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        arrays::intrinsic_matrix(py, &self.file.intrinsics)
    }
    /// Image width, when the camera gives it.
    #[getter]
    fn width(&self) -> Option<u32> {
        self.file.size.map(|s| s.width)
    }
    /// Image height, when the camera gives it.
    #[getter]
    fn height(&self) -> Option<u32> {
        self.file.size.map(|s| s.height)
    }
    /// Metres per raw depth unit, when the camera gives it.
    #[getter]
    fn depth_unit(&self) -> Option<f64> {
        self.file.metres_per_unit
    }
    /// Whether depth is registered to colour (no separate depth camera).
    #[getter]
    fn is_registered(&self) -> bool {
        self.file.is_registered()
    }
    fn __repr__(&self) -> String {
        let i = self.file.intrinsics;
        format!(
            "Camera(fx={}, fy={}, cx={}, cy={}, size={}, depth_unit={})",
            i.fx,
            i.fy,
            i.cx,
            i.cy,
            self.file.size.map_or("None".into(), |s| format!("{}x{}", s.width, s.height)),
            self.file.metres_per_unit.map_or("None".into(), |u| u.to_string())
        )
    }
}

/// A camera argument: a `Camera`, an `open3d.camera.PinholeCameraIntrinsic`, a path to a camera
/// file, or a dict.
pub fn camera_arg(obj: &Bound<'_, PyAny>) -> PyResult<CameraFile> {
    if let Ok(c) = obj.cast::<Camera>() {
        return Ok(c.get().file.clone());
    }
    if let Some(d) = crate::open3d::pinhole_intrinsic(obj)? {
        return Camera::from_dict(&d).map(|c| c.file);
    }
    if let Ok(d) = obj.cast::<PyDict>() {
        return Camera::from_dict(d).map(|c| c.file);
    }
    let path: PathBuf = obj
        .extract()
        .map_err(|_| input("camera: expected a flowfilter.Camera, an open3d.camera.PinholeCameraIntrinsic, a path to a camera file (JSON) or a dict"))?;
    Camera::from_file(path).map(|c| c.file)
}

/// What a frame holds: arrays given by the caller (the camera comes with `estimate`), or a
/// frame read from a dataset with its own calibration.
#[derive(Clone)]
enum Content {
    Arrays { color: RgbImage, depth: DepthArray, mask: Option<Mask>, depth_scale: Option<f64> },
    Read(Box<RgbdFrame>),
}

/// One RGB-D view: colour (H, W, 3) uint8, depth (H, W) uint16 raw units (with `depth_scale`)
/// or float32 metres, and an optional object mask (H, W) bool.
#[pyclass(module = "flowfilter", frozen)]
#[derive(Clone)]
pub struct Frame {
    name: String,
    content: Content,
}

/// Depths above this many metres are refused (beyond every RGB-D sensor's range).
const MAX_DEPTH_M: f32 = 65.0;

#[pymethods]
impl Frame {
    /// A frame from arrays. `depth_scale`: raw units per metre for uint16 depth (Open3D's
    /// convention: 1000.0 for millimetres, 10000.0 for YCB-Video's 0.1 mm); without it the
    /// camera's depth unit applies. `name` labels the frame in results and messages.
    #[new]
    #[pyo3(signature = (color, depth, mask = None, depth_scale = None, name = "frame"))]
    fn new(
        color: &Bound<'_, PyAny>,
        depth: &Bound<'_, PyAny>,
        mask: Option<&Bound<'_, PyAny>>,
        depth_scale: Option<f64>,
        name: &str,
    ) -> PyResult<Self> {
        let color = arrays::color(&crate::open3d::color(color, "color")?, "color")?;
        let depth = arrays::depth(&crate::open3d::image(depth, "depth")?, "depth")?;
        let mask = mask
            .filter(|m| !m.is_none())
            .map(|m| crate::open3d::image(m, "mask").and_then(|m| arrays::mask(&m, "mask")))
            .transpose()?;
        if let Some(s) = depth_scale
            && !(s.is_finite() && s > 0.0)
        {
            return Err(input(format!("depth_scale must be a positive number (raw units per metre), found {s}")));
        }
        if depth_scale.is_some() && matches!(depth, DepthArray::Metres(_)) {
            return Err(input("depth_scale is for uint16 depth; float depth is already in metres"));
        }
        Ok(Self { name: name.into(), content: Content::Arrays { color, depth, mask, depth_scale } })
    }

    /// The frame's name.
    #[getter]
    fn name(&self) -> &str {
        &self.name
    }
    /// Colour image, (H, W, 3) uint8.
    #[getter]
    fn color<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        match &self.content {
            Content::Arrays { color, .. } => color_array(py, color).into_any(),
            Content::Read(f) => color_array(py, &f.color).into_any(),
        }
    }
    /// Depth as given: (H, W) uint16 raw units or float32 metres.
    #[getter]
    fn depth<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        match &self.content {
            Content::Arrays { depth: DepthArray::Raw(d), .. } => grid_array(py, d).into_any(),
            Content::Arrays { depth: DepthArray::Metres(d), .. } => grid_array(py, d).into_any(),
            Content::Read(f) => grid_array(py, &f.depth).into_any(),
        }
    }
    /// Object mask (H, W) bool, or None when not given.
    #[getter]
    fn mask<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyAny>> {
        match &self.content {
            Content::Arrays { mask, .. } => mask.as_ref().map(|m| grid_array(py, m).into_any()),
            Content::Read(f) => Some(grid_array(py, &f.mask).into_any()),
        }
    }
    /// Metres per raw depth unit of a frame read from a dataset; None for frames made from
    /// arrays (the camera or `depth_scale` gives it).
    #[getter]
    fn depth_unit(&self) -> Option<f64> {
        match &self.content {
            Content::Read(f) => Some(f.sensor.metres_per_unit),
            Content::Arrays { depth_scale, .. } => depth_scale.map(|s| 1.0 / s),
        }
    }
    /// The colour camera's 3x3 intrinsic matrix of a frame read from a dataset, else None.
    #[getter]
    #[allow(non_snake_case)]
    fn K<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray2<f64>>> {
        let Content::Read(f) = &self.content else { return None };
        Some(arrays::intrinsic_matrix(py, &f.sensor.color.intrinsics))
    }
    fn __repr__(&self) -> String {
        let (w, h) = match &self.content {
            Content::Arrays { color, .. } => color.dimensions(),
            Content::Read(f) => f.color.dimensions(),
        };
        format!("Frame(name='{}', {w}x{h})", self.name)
    }
}

impl Frame {
    /// A frame read from a dataset (its calibration included).
    pub fn read(frame: RgbdFrame) -> Self {
        Self { name: frame.label.clone(), content: Content::Read(Box::new(frame)) }
    }

    /// The pipeline's frame, with `camera` (required for frames made from arrays; for frames
    /// read from a dataset it replaces their calibration). A camera's `depth_bias` corrects
    /// depth once: arrays here, files when they are read (a frame read with a corrected camera
    /// is not corrected again).
    pub fn rgbd(&self, camera: Option<&CameraFile>) -> PyResult<RgbdFrame> {
        match (&self.content, camera) {
            (Content::Read(f), None) => Ok((**f).clone()),
            (Content::Read(f), Some(camera)) => {
                let mut camera = camera.clone();
                camera.metres_per_unit = camera.metres_per_unit.or(Some(f.sensor.metres_per_unit));
                camera.depth_bias = None;
                self.build(f.color.clone(), f.depth.clone(), Some(f.mask.clone()), &camera)
            }
            (Content::Arrays { .. }, None) => Err(input(format!(
                "frame '{}': no camera: pass camera=... (a flowfilter.Camera, a camera file or a dict)",
                self.name
            ))),
            (Content::Arrays { color, depth, mask, depth_scale }, Some(camera)) => {
                let mut camera = camera.clone();
                let raw = match depth {
                    DepthArray::Raw(d) => {
                        if let Some(s) = depth_scale {
                            camera.metres_per_unit = Some(1.0 / s);
                        }
                        d.clone()
                    }
                    DepthArray::Metres(m) => {
                        let (raw, unit) = quantised(m, &self.name)?;
                        camera.metres_per_unit = Some(unit);
                        raw
                    }
                };
                check_depth_unit(&raw, &camera, &self.name)?;
                self.build(color.clone(), raw, mask.clone(), &camera)
            }
        }
    }

    fn build(&self, color: RgbImage, depth: RawDepth, mask: Option<Mask>, camera: &CameraFile) -> PyResult<RgbdFrame> {
        RgbdFrame::from_images(&self.name, color, depth, mask, camera).map_err(|e| match e {
            ImagesError::Depth(m) => input(format!("frame '{}': depth: {m}", self.name)),
            ImagesError::Mask(m) => input(format!("frame '{}': mask: {m}", self.name)),
            ImagesError::Camera(e) => pipeline(&flowfilter_pipeline::PipelineError::Camera(e)),
        })
    }
}

/// Metric depth as raw units: 0.1 mm units up to 6.5 m, else millimetres (the quantisation,
/// at most half a unit, is far below any sensor's noise).
fn quantised(m: &flowfilter_pipeline::geometry::Grid<f32>, name: &str) -> PyResult<(RawDepth, f64)> {
    let max = m.as_slice().iter().copied().fold(0.0f32, f32::max);
    if max > MAX_DEPTH_M {
        return Err(input(format!(
            "frame '{name}': depth: {max} m is beyond any RGB-D sensor's range (at most {MAX_DEPTH_M} m); is it in millimetres?"
        )));
    }
    let unit = if max < 6.5 { 1e-4 } else { 1e-3 };
    Ok((m.map(|v| (f64::from(*v) / unit).round() as u16), unit))
}

/// Refuse a depth unit that puts the frame's median depth outside 1 cm - 100 m: a scale given
/// in the wrong convention.
fn check_depth_unit(raw: &RawDepth, camera: &CameraFile, name: &str) -> PyResult<()> {
    let Some(unit) = camera.metres_per_unit else { return Ok(()) };
    let mut values: Vec<u16> = raw.as_slice().iter().copied().filter(|v| *v > 0).collect();
    if values.is_empty() {
        return Ok(());
    }
    let mid = values.len() / 2;
    let median = f64::from(*values.select_nth_unstable(mid).1) * unit;
    if !(0.01..=100.0).contains(&median) {
        return Err(input(format!(
            "frame '{name}': depth: with {unit} m per unit the median depth is {median} m; depth_scale is raw units per \
             metre (Open3D's convention: 1000.0 for millimetres)"
        )));
    }
    Ok(())
}

/// A frame argument: a `Frame`.
pub fn frame_arg(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Frame> {
    if let Some((color, depth)) = crate::open3d::rgbd_parts(obj, name)? {
        return Frame::new(&color, &depth, None, None, name);
    }
    obj.cast::<Frame>().map(|f| f.get().clone()).map_err(|_| {
        let found = crate::open3d::class_name(obj)
            .map_or_else(|| obj.get_type().name().map_or("?".into(), |n| n.to_string()), |c| format!("open3d.{c}"));
        input(format!(
            "{name}: expected a flowfilter.Frame (Frame(color, depth, mask=None, depth_scale=None)) or an \
             open3d.geometry.RGBDImage, found {found}"
        ))
    })
}
