//! Open3D's objects taken as they are: `open3d.geometry.PointCloud` (points, normals),
//! `open3d.geometry.Image`, `open3d.geometry.RGBDImage` and
//! `open3d.camera.PinholeCameraIntrinsic`, recognised by their class (Open3D need not be
//! installed for anything else) and read through NumPy's buffer view of them.

use crate::errors::input;
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// The Open3D class name of `obj` (`PointCloud`, `Image`, ...) when its type comes from Open3D.
pub fn class_name(obj: &Bound<'_, PyAny>) -> Option<String> {
    let ty = obj.get_type();
    let module: String = ty.getattr("__module__").ok()?.extract().ok()?;
    if module != "open3d" && !module.starts_with("open3d.") {
        return None;
    }
    ty.getattr("__name__").ok()?.extract().ok()
}

/// `numpy.asarray(value)`.
fn as_array<'py>(value: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    PyModule::import(value.py(), "numpy")?.getattr("asarray")?.call1((value,))
}

/// An argument that must be an array, with Open3D's objects named in the refusal.
fn refuse(name: &str, class: &str, expected: &str) -> PyErr {
    input(format!("{name}: expected {expected}, found open3d.{class}"))
}

/// A point argument: an (N, 3) array as given, or an `open3d.geometry.PointCloud`'s points
/// with its normals when it has them. Other Open3D objects are refused with their class.
///
/// # Errors
/// `InputError` for an Open3D object that is not a point cloud.
pub fn points_and_normals<'py>(
    obj: &Bound<'py, PyAny>,
    name: &str,
) -> PyResult<(Bound<'py, PyAny>, Option<Bound<'py, PyAny>>)> {
    match class_name(obj).as_deref() {
        None => Ok((obj.clone(), None)),
        Some("PointCloud") => {
            let points = as_array(&obj.getattr("points")?)?;
            let has_normals: bool = obj.call_method0("has_normals")?.extract()?;
            let normals = if has_normals { Some(as_array(&obj.getattr("normals")?)?) } else { None };
            Ok((points, normals))
        }
        Some(other) => Err(refuse(name, other, "an (N, 3) array or an open3d.geometry.PointCloud")),
    }
}

/// An image argument: an array as given, or an `open3d.geometry.Image`'s pixels.
///
/// # Errors
/// `InputError` for another Open3D object.
pub fn image<'py>(obj: &Bound<'py, PyAny>, name: &str) -> PyResult<Bound<'py, PyAny>> {
    match class_name(obj).as_deref() {
        None => Ok(obj.clone()),
        Some("Image") => as_array(obj),
        Some(other) => Err(refuse(name, other, "an array or an open3d.geometry.Image")),
    }
}

/// A colour argument: (H, W, 3) uint8 as given; Open3D's (H, W) float intensity in [0, 1]
/// (an `RGBDImage` made with `convert_rgb_to_intensity=True`) or (H, W) uint8 grey become grey
/// RGB. Other arrays pass through, for the array checks to name what is wrong with them.
pub fn color<'py>(obj: &Bound<'py, PyAny>, name: &str) -> PyResult<Bound<'py, PyAny>> {
    let from_open3d = class_name(obj).is_some();
    let array = image(obj, name)?;
    if !from_open3d {
        return Ok(array);
    }
    let ndim: usize = array.getattr("ndim")?.extract()?;
    if ndim != 2 {
        return Ok(array);
    }
    let kind: String = array.getattr("dtype")?.getattr("kind")?.extract()?;
    let np = PyModule::import(obj.py(), "numpy")?;
    let grey = if kind == "f" {
        let scaled = array.call_method1("__mul__", (255.0,))?;
        let clipped = np.getattr("clip")?.call1((scaled, 0.0, 255.0))?;
        np.getattr("rint")?.call1((clipped,))?.call_method1("astype", ("uint8",))?
    } else {
        array
    };
    let stacked = np.getattr("stack")?.call((vec![grey.clone(), grey.clone(), grey],), Some(&axis_last(obj.py())?))?;
    Ok(stacked)
}

fn axis_last(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let kwargs = PyDict::new(py);
    kwargs.set_item("axis", -1)?;
    Ok(kwargs)
}

/// The colour and depth arrays of an `open3d.geometry.RGBDImage`, `None` for any other object.
/// Open3D's depth in an `RGBDImage` is float metres (its `depth_scale` applied), which is what
/// float depth means here.
pub fn rgbd_parts<'py>(
    obj: &Bound<'py, PyAny>,
    name: &str,
) -> PyResult<Option<(Bound<'py, PyAny>, Bound<'py, PyAny>)>> {
    if class_name(obj).as_deref() != Some("RGBDImage") {
        return Ok(None);
    }
    let color = color(&obj.getattr("color")?, &format!("{name}.color"))?;
    let depth = image(&obj.getattr("depth")?, &format!("{name}.depth"))?;
    Ok(Some((color, depth)))
}

/// An `open3d.camera.PinholeCameraIntrinsic` as a dict in Open3D's own JSON layout
/// (`width`, `height`, column-major `intrinsic_matrix`), which the camera files read; `None`
/// for any other object.
pub fn pinhole_intrinsic<'py>(obj: &Bound<'py, PyAny>) -> PyResult<Option<Bound<'py, PyDict>>> {
    if class_name(obj).as_deref() != Some("PinholeCameraIntrinsic") {
        return Ok(None);
    }
    let py = obj.py();
    let k = as_array(&obj.getattr("intrinsic_matrix")?)?;
    let column_major = k.getattr("T")?.call_method0("flatten")?.call_method0("tolist")?;
    let d = PyDict::new(py);
    d.set_item("width", obj.getattr("width")?)?;
    d.set_item("height", obj.getattr("height")?)?;
    d.set_item("intrinsic_matrix", column_major)?;
    Ok(Some(d))
}
