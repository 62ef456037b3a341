//! NumPy arrays in and out: shape, dtype and value checks with messages that name the argument,
//! and copies into the library's types (any memory layout; the one copy is into the library's
//! own buffers).

use crate::errors::input;
use flowfilter_pipeline::geometry::{Grid, rigid_from_matrix};
use flowfilter_pipeline::{Mask, Point3, Pose, RawDepth};
use image::RgbImage;
use nalgebra::{Matrix4, Vector3};
use numpy::ndarray::{Array2, Array3, ArrayView2, ArrayView3};
use numpy::prelude::*;
use numpy::{Element, PyArray2, PyArray3, PyUntypedArray};
use pyo3::prelude::*;

/// `(480, 640, 3)`.
fn shape_text(shape: &[usize]) -> String {
    match shape {
        [n] => format!("({n},)"),
        _ => format!("({})", shape.iter().map(usize::to_string).collect::<Vec<_>>().join(", ")),
    }
}

/// `obj` as a NumPy array, or an error saying what `name` must be.
fn untyped<'py>(obj: &Bound<'py, PyAny>, name: &str, expected: &str) -> PyResult<Bound<'py, PyUntypedArray>> {
    obj.cast::<PyUntypedArray>().cloned().map_err(|_| {
        let found = obj.get_type().name().map_or_else(|_| "?".into(), |n| n.to_string());
        input(format!("{name}: expected a NumPy array {expected}, found {found}"))
    })
}

fn dtype_name(a: &Bound<'_, PyUntypedArray>) -> String {
    a.dtype().getattr("name").and_then(|n| n.extract::<String>()).unwrap_or_else(|_| "?".into())
}

/// The array with `shape` checked by `ok`; `expected` describes it for the message.
fn shaped<'py>(
    obj: &Bound<'py, PyAny>,
    name: &str,
    expected: &str,
    ok: impl Fn(&[usize]) -> bool,
) -> PyResult<Bound<'py, PyUntypedArray>> {
    let a = untyped(obj, name, &format!("of shape {expected}"))?;
    if !ok(a.shape()) {
        return Err(input(format!("{name}: expected shape {expected}, found {}", shape_text(a.shape()))));
    }
    if a.shape().contains(&0) {
        return Err(input(format!("{name}: empty array of shape {}", shape_text(a.shape()))));
    }
    Ok(a)
}

/// The array as `T` in native byte order: the array itself when it already is, else a copy
/// (`astype`) for an array of the same kind in another byte order.
fn typed<'py, T: Element, D: numpy::ndarray::Dimension>(
    a: &Bound<'py, PyUntypedArray>,
) -> Option<Bound<'py, numpy::PyArray<T, D>>> {
    if let Ok(t) = a.cast::<numpy::PyArray<T, D>>() {
        return Some(t.clone());
    }
    let wanted = numpy::dtype::<T>(a.py());
    let same_kind = a.dtype().kind() == wanted.kind() && a.dtype().itemsize() == wanted.itemsize();
    if !same_kind {
        return None;
    }
    a.call_method1("astype", (wanted,)).ok()?.cast_into::<numpy::PyArray<T, D>>().ok()
}

/// Rows of an (N, 3) float32/float64 array as points, every value finite.
pub fn points(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<Point3>> {
    rows3(obj, name).map(|rows| rows.into_iter().map(Point3::from).collect())
}

/// Rows of an (N, 3) float32/float64 array as vectors (normals), every value finite.
pub fn vectors(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<Vector3<f64>>> {
    rows3(obj, name)
}

fn rows3(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<Vector3<f64>>> {
    let a = shaped(obj, name, "(N, 3)", |s| s.len() == 2 && s[1] == 3)?;
    let rows: Vec<Vector3<f64>> = if let Some(t) = typed::<f64, numpy::Ix2>(&a) {
        collect_rows(t.readonly().as_array(), |v| v)
    } else if let Some(t) = typed::<f32, numpy::Ix2>(&a) {
        collect_rows(t.readonly().as_array(), f64::from)
    } else {
        return Err(input(format!("{name}: expected dtype float32 or float64, found {}", dtype_name(&a))));
    };
    if let Some((i, r)) = rows.iter().enumerate().find(|(_, r)| !r.iter().all(|v| v.is_finite())) {
        return Err(input(format!("{name}: row {i} is not finite: [{}, {}, {}]", r.x, r.y, r.z)));
    }
    Ok(rows)
}

fn collect_rows<T: Copy>(view: ArrayView2<'_, T>, f: impl Fn(T) -> f64) -> Vec<Vector3<f64>> {
    view.rows().into_iter().map(|r| Vector3::new(f(r[0]), f(r[1]), f(r[2]))).collect()
}

/// A 1-D float array of `n` finite, non-negative values.
pub fn weights(obj: &Bound<'_, PyAny>, name: &str, n: usize) -> PyResult<Vec<f64>> {
    let a = shaped(obj, name, &format!("({n},)"), |s| s == [n])?;
    let values: Vec<f64> = if let Some(t) = typed::<f64, numpy::Ix1>(&a) {
        t.readonly().as_array().iter().copied().collect()
    } else if let Some(t) = typed::<f32, numpy::Ix1>(&a) {
        t.readonly().as_array().iter().map(|v| f64::from(*v)).collect()
    } else {
        return Err(input(format!("{name}: expected dtype float32 or float64, found {}", dtype_name(&a))));
    };
    if let Some((i, v)) = values.iter().enumerate().find(|(_, v)| !(v.is_finite() && **v >= 0.0)) {
        return Err(input(format!("{name}: element {i} is {v}; weights must be finite and >= 0")));
    }
    Ok(values)
}

/// An (H, W, 3) uint8 colour image.
pub fn color(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<RgbImage> {
    let a = shaped(obj, name, "(H, W, 3)", |s| s.len() == 3 && s[2] == 3)?;
    let Ok(t) = a.cast::<PyArray3<u8>>() else {
        return Err(input(format!("{name}: expected dtype uint8 (RGB), found {}", dtype_name(&a))));
    };
    let readonly = t.readonly();
    let view: ArrayView3<'_, u8> = readonly.as_array();
    let (h, w) = (view.shape()[0], view.shape()[1]);
    let raw: Vec<u8> = view.iter().copied().collect();
    RgbImage::from_raw(w as u32, h as u32, raw).ok_or_else(|| input(format!("{name}: cannot make an image")))
}

/// A grey image for flow: (H, W, 3) uint8 colour, (H, W) uint8, or (H, W) float32 in [0, 1].
pub fn gray(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<flowfilter_pipeline::Gray> {
    let a = shaped(obj, name, "(H, W, 3) or (H, W)", |s| s.len() == 2 || (s.len() == 3 && s[2] == 3))?;
    if a.ndim() == 3 {
        return Ok(flowfilter_pipeline::flow::lk::to_gray(&color(obj, name)?));
    }
    if let Ok(t) = a.cast::<PyArray2<u8>>() {
        let v = t.readonly();
        let v = v.as_array();
        return Ok(Grid::from_fn(v.shape()[1], v.shape()[0], |x, y| f32::from(v[[y, x]]) / 255.0));
    }
    if let Some(t) = typed::<f32, numpy::Ix2>(&a) {
        let v = t.readonly();
        let v = v.as_array();
        if let Some(bad) = v.iter().find(|g| !g.is_finite()) {
            return Err(input(format!("{name}: grey values must be finite, found {bad}")));
        }
        return Ok(Grid::from_fn(v.shape()[1], v.shape()[0], |x, y| v[[y, x]]));
    }
    Err(input(format!("{name}: expected dtype uint8 (or float32 grey in [0, 1]), found {}", dtype_name(&a))))
}

/// Depth as given: raw sensor units, or metres.
#[derive(Debug, Clone)]
pub enum DepthArray {
    /// uint16 raw units (0 = no reading); metres = value / depth_scale.
    Raw(RawDepth),
    /// Metres (0 = no reading).
    Metres(Grid<f32>),
}

/// An (H, W) depth image: uint16 raw units, or float32/float64 metres (NaN, inf and 0 = no
/// reading; a negative value is an error).
pub fn depth(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<DepthArray> {
    let a = shaped(obj, name, "(H, W)", |s| s.len() == 2)?;
    if let Ok(t) = a.cast::<PyArray2<u16>>() {
        let v = t.readonly();
        let v = v.as_array();
        return Ok(DepthArray::Raw(Grid::from_fn(v.shape()[1], v.shape()[0], |x, y| v[[y, x]])));
    }
    let metres: Array2<f32> = if let Some(t) = typed::<f32, numpy::Ix2>(&a) {
        t.readonly().as_array().to_owned()
    } else if let Some(t) = typed::<f64, numpy::Ix2>(&a) {
        t.readonly().as_array().mapv(|v| v as f32)
    } else {
        return Err(input(format!(
            "{name}: expected dtype uint16 (raw units, with depth_scale) or float32 (metres), found {}",
            dtype_name(&a)
        )));
    };
    if let Some(((y, x), v)) = metres.indexed_iter().find(|(_, v)| **v < 0.0) {
        return Err(input(format!("{name}: negative depth {v} m at pixel (x {x}, y {y})")));
    }
    let (h, w) = metres.dim();
    Ok(DepthArray::Metres(Grid::from_fn(w, h, |x, y| {
        let v = metres[[y, x]];
        if v.is_finite() { v } else { 0.0 }
    })))
}

/// An (H, W) bool mask.
pub fn mask(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Mask> {
    let a = shaped(obj, name, "(H, W)", |s| s.len() == 2)?;
    let Ok(t) = a.cast::<PyArray2<bool>>() else {
        return Err(input(format!("{name}: expected dtype bool (e.g. labels == object_id), found {}", dtype_name(&a))));
    };
    let v = t.readonly();
    let v = v.as_array();
    Ok(Grid::from_fn(v.shape()[1], v.shape()[0], |x, y| v[[y, x]]))
}

/// A 4x4 rigid transform (float array or nested lists).
pub fn pose(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Pose> {
    let rows: [[f64; 4]; 4] = match untyped(obj, name, "of shape (4, 4)") {
        Ok(a) => {
            let a = shaped(a.as_any(), name, "(4, 4)", |s| s == [4, 4])?;
            let t = typed::<f64, numpy::Ix2>(&a)
                .or_else(|| {
                    a.call_method1("astype", ("float64",)).ok().and_then(|c| c.cast_into::<PyArray2<f64>>().ok())
                })
                .ok_or_else(|| input(format!("{name}: expected a float array, found {}", dtype_name(&a))))?;
            let v = t.readonly();
            let v = v.as_array();
            std::array::from_fn(|r| std::array::from_fn(|c| v[[r, c]]))
        }
        Err(e) => obj.extract::<[[f64; 4]; 4]>().map_err(|_| e)?,
    };
    let m = Matrix4::from_fn(|r, c| rows[r][c]);
    if !m.iter().all(|v| v.is_finite()) {
        return Err(input(format!("{name}: the matrix has a non-finite value")));
    }
    rigid_from_matrix(&m).map_err(|e| input(format!("{name}: {e}")))
}

/// A 4x4 float64 array.
pub fn matrix<'py>(py: Python<'py>, rows: &[[f64; 4]; 4]) -> Bound<'py, PyArray2<f64>> {
    Array2::from_shape_fn((4, 4), |(r, c)| rows[r][c]).into_pyarray(py)
}

/// The 3x3 float64 intrinsic matrix.
pub fn intrinsic_matrix<'py>(
    py: Python<'py>,
    i: &flowfilter_pipeline::camera::Intrinsics,
) -> Bound<'py, PyArray2<f64>> {
    let rows = [[i.fx, 0.0, i.cx], [0.0, i.fy, i.cy], [0.0, 0.0, 1.0]];
    Array2::from_shape_fn((3, 3), |(r, c)| rows[r][c]).into_pyarray(py)
}

/// An (N, 3) float64 array of points or vectors.
pub fn rows_array<'py, V: std::ops::Index<usize, Output = f64>>(
    py: Python<'py>,
    rows: &[V],
) -> Bound<'py, PyArray2<f64>> {
    Array2::from_shape_fn((rows.len(), 3), |(i, c)| rows[i][c]).into_pyarray(py)
}

/// An (H, W, 3) uint8 array of an image.
pub fn color_array<'py>(py: Python<'py>, img: &RgbImage) -> Bound<'py, PyArray3<u8>> {
    let (w, h) = img.dimensions();
    Array3::from_shape_fn((h as usize, w as usize, 3), |(y, x, c)| img.get_pixel(x as u32, y as u32).0[c])
        .into_pyarray(py)
}

/// An (H, W) array of a grid.
pub fn grid_array<'py, T: Element + Copy>(py: Python<'py>, g: &Grid<T>) -> Bound<'py, PyArray2<T>> {
    let (w, h) = g.dims();
    Array2::from_shape_fn((h, w), |(y, x)| *g.at(x, y)).into_pyarray(py)
}

/// A serialisable value as the Python object `json.loads` makes of its JSON.
pub fn json_object<'py>(py: Python<'py>, value: &impl serde::Serialize) -> PyResult<Bound<'py, PyAny>> {
    let text = serde_json::to_string(value).map_err(|e| crate::errors::Error::new_err(e.to_string()))?;
    py.import("json")?.call_method1("loads", (text,))
}
