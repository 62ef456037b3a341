//! Readers and writers: PLY clouds, camera files, RGB-D frames from files, BigBIRD-layout
//! objects and BOP scenes.

use crate::arrays::{matrix, rows_array};
use crate::errors::{input, pipeline};
use crate::frame::{Camera, Frame, camera_arg};
use crate::register::cloud;
use flowfilter_pipeline::bigbird::{BigBirdObject, FrameId, SensorId};
use flowfilter_pipeline::bop::BopScene;
use flowfilter_pipeline::depth::ply::{PlyFormat, read_ply as read_ply_file, write_ply as write_ply_file};
use flowfilter_pipeline::{FrameFiles, MaskSource, PipelineError, load_bigbird_frame, matrix_rows};
use numpy::PyArray2;
use pyo3::prelude::*;
use std::path::{Path, PathBuf};

/// An (N, 3) float64 array.
type Rows<'py> = Bound<'py, PyArray2<f64>>;

/// A PLY point cloud (ASCII or binary): `(points, normals)`, (N, 3) float64 arrays, normals
/// None when the file has none.
///
/// Raises InputError for a file that cannot be read or parsed.
#[pyfunction]
pub fn read_ply(py: Python<'_>, path: PathBuf) -> PyResult<(Rows<'_>, Option<Rows<'_>>)> {
    let cloud = read_ply_file(&path).map_err(|e| input(crate::errors::message(&e)))?;
    let normals = cloud.normals.as_ref().map(|n| rows_array(py, n));
    Ok((rows_array(py, &cloud.points), normals))
}

/// Write points (and optional normals) as a PLY file, binary little-endian unless
/// `binary=False`.
///
/// Raises InputError for arrays that cannot be used or a file that cannot be written.
#[pyfunction]
#[pyo3(signature = (path, points, normals = None, binary = true))]
pub fn write_ply(
    path: PathBuf,
    points: &Bound<'_, PyAny>,
    normals: Option<&Bound<'_, PyAny>>,
    binary: bool,
) -> PyResult<()> {
    let c = cloud(points, normals, "points")?;
    let format = if binary { PlyFormat::BinaryLittleEndian } else { PlyFormat::Ascii };
    write_ply_file(&c, &path, format).map_err(|e| input(crate::errors::message(&e)))
}

/// A camera file (this project's JSON, a BOP `scene_camera.json` entry or `camera.json`, or
/// Open3D's `PinholeCameraIntrinsic`).
///
/// Raises InputError naming the file and field.
#[pyfunction]
pub fn read_camera(path: PathBuf) -> PyResult<Camera> {
    Camera::from_file(path)
}

/// One RGB-D frame from files, for any camera: a colour PNG/JPEG, a 16-bit depth PNG
/// (metres = value x the camera's depth unit), and a mask (binary PNG, or a label image with
/// `label`). `camera`: a `Camera`, a camera-file path or a dict.
///
/// Raises InputError naming the file at fault.
#[pyfunction]
#[pyo3(signature = (color, depth, camera, mask = None, label = None, name = None))]
pub fn read_frame(
    color: PathBuf,
    depth: PathBuf,
    camera: &Bound<'_, PyAny>,
    mask: Option<PathBuf>,
    label: Option<u16>,
    name: Option<String>,
) -> PyResult<Frame> {
    let camera = camera_arg(camera)?;
    let mask = match (mask, label) {
        (None, None) => MaskSource::None,
        (None, Some(_)) => return Err(input("label needs mask= (the label image)")),
        (Some(path), None) => MaskSource::Binary(path),
        (Some(path), Some(id)) => MaskSource::Label { path, id },
    };
    let name = name.unwrap_or_else(|| stem(&color));
    let files = FrameFiles { color, depth, mask };
    files.load(&camera, &name).map(Frame::read).map_err(|e| pipeline(&e))
}

fn stem(p: &Path) -> String {
    p.file_stem().map_or_else(|| p.display().to_string(), |s| s.to_string_lossy().into_owned())
}

fn sensor_id(camera: &str) -> PyResult<SensorId> {
    camera.parse().map_err(|e| input(format!("camera '{camera}': {e} (NP1..NP5)")))
}

fn bigbird(dir: &Path) -> PyResult<BigBirdObject> {
    BigBirdObject::open(dir).map_err(|e| pipeline(&PipelineError::Dataset(e)))
}

/// One frame of a BigBIRD-layout object directory (real or synthesised): camera NP1..NP5 at
/// turntable `angle` (degrees), with its calibration (a separate depth camera).
///
/// Raises InputError naming the file at fault.
#[pyfunction]
pub fn read_bigbird_frame(object_dir: PathBuf, camera: &str, angle: u32) -> PyResult<Frame> {
    let object = bigbird(&object_dir)?;
    let id = FrameId { sensor: sensor_id(camera)?, angle };
    if !object.has_frame(id) {
        return Err(input(format!("{}: no frame {id} (camera {camera}, angle {angle})", object_dir.display())));
    }
    load_bigbird_frame(&object, id).map(Frame::read).map_err(|e| pipeline(&PipelineError::Dataset(e)))
}

/// The true motion of a BigBIRD-layout object between turntable angles `from_angle` and
/// `to_angle`, in camera `camera`'s colour frame: a 4x4 float64 `T` with
/// `P_to = T @ P_from`.
#[pyfunction]
pub fn bigbird_motion<'py>(
    py: Python<'py>,
    object_dir: PathBuf,
    camera: &str,
    from_angle: u32,
    to_angle: u32,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let object = bigbird(&object_dir)?;
    let pose = object
        .relative_motion(sensor_id(camera)?, from_angle, to_angle)
        .map_err(|e| pipeline(&PipelineError::Dataset(e)))?;
    Ok(matrix(py, &matrix_rows(&pose)))
}

fn bop(dir: &Path) -> PyResult<BopScene> {
    BopScene::open(dir).map_err(|e| pipeline(&e))
}

/// One object in one image of a BOP scene folder (`scene_camera.json`, `scene_gt.json`,
/// `rgb/`, `depth/`, `mask_visib/`): the frame with the object's visible mask.
///
/// Raises InputError naming the file at fault.
#[pyfunction]
pub fn read_bop_frame(scene_dir: PathBuf, im_id: u32, obj_id: u32) -> PyResult<Frame> {
    bop(&scene_dir)?.frame(im_id, obj_id).map(Frame::read).map_err(|e| pipeline(&e))
}

/// The true motion of object `obj_id` from image `im_a` to image `im_b` of a BOP scene, in the
/// camera frame: `T = T_b @ inv(T_a)` (4x4 float64, metres).
#[pyfunction]
pub fn bop_motion<'py>(
    py: Python<'py>,
    scene_dir: PathBuf,
    im_a: u32,
    im_b: u32,
    obj_id: u32,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let pose = bop(&scene_dir)?.relative_motion(im_a, im_b, obj_id).map_err(|e| pipeline(&e))?;
    Ok(matrix(py, &matrix_rows(&pose)))
}

/// The image ids of a BOP scene and, per image, the ids of the objects annotated in it.
#[pyfunction]
pub fn bop_objects(scene_dir: PathBuf) -> PyResult<Vec<(u32, Vec<u32>)>> {
    let scene = bop(&scene_dir)?;
    Ok(scene.image_ids().into_iter().map(|im| (im, scene.instances(im).iter().map(|i| i.obj_id).collect())).collect())
}
