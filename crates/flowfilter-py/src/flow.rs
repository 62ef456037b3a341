//! `flowfilter.flow` and `flowfilter.estimate_normals`: dense optical flow between two images,
//! and k-NN normals of a cloud.

use crate::arrays;
use crate::errors::{flow as flow_error, input};
use crate::threads;
use flowfilter_pipeline::depth::cloud::knn_normals;
use flowfilter_pipeline::{DepthConfig, Point3};
use numpy::ndarray::Array3;
use numpy::{IntoPyArray, PyArray2, PyArray3};
use pyo3::prelude::*;

/// Dense optical flow from `image1` to `image2`: an (H, W, 2) float32 array of displacements
/// `(u, v)` in pixels, NaN where there is none (outside `mask`, or where the estimator gives
/// none).
///
/// Images: (H, W, 3) uint8 colour, (H, W) uint8 grey, or (H, W) float32 grey in [0, 1], both of
/// one size. `method`: dis (DIS, OpenCV's medium preset), dis-fast, dis-ultrafast, lk
/// (pyramidal Lucas-Kanade on a grid, interpolated), and in builds with the `onnx` feature net
/// or onnx:MODEL.onnx. `mask`: (H, W) bool; only pixels inside it are estimated.
///
/// Raises InputError for images that cannot be used, ConfigError for an unknown method.
#[pyfunction]
#[pyo3(signature = (image1, image2, method = "dis", mask = None))]
pub fn flow<'py>(
    py: Python<'py>,
    image1: &Bound<'py, PyAny>,
    image2: &Bound<'py, PyAny>,
    method: &str,
    mask: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let estimator = flowfilter_pipeline::flow::flow_estimator_with_presets(method).map_err(|e| flow_error(&e))?;
    let (a, b) = (arrays::gray(image1, "image1")?, arrays::gray(image2, "image2")?);
    let mask = mask.filter(|m| !m.is_none()).map(|m| arrays::mask(m, "mask")).transpose()?;
    let field = threads::run(py, || estimator.dense(&a, &b, mask.as_ref()))?.map_err(|e| flow_error(&e))?;
    let (w, h) = field.flow.dims();
    let out = Array3::from_shape_fn(
        (h, w, 2),
        |(y, x, c)| {
            if *field.valid.at(x, y) { field.flow.at(x, y)[c] } else { f32::NAN }
        },
    );
    Ok(out.into_pyarray(py))
}

/// Unit normals of a cloud by PCA over each point's `k` nearest neighbours (like Open3D's
/// `estimate_normals` with `KDTreeSearchParamKNN(k)`), each turned to face `viewpoint` (the
/// camera's centre: the origin of camera-frame clouds). Returns (N, 3) float64.
///
/// `k` defaults to the depth stage's `knn` (`[depth.cloud] knn`).
///
/// Raises InputError for points that cannot be used or k < 3.
#[pyfunction]
#[pyo3(signature = (points, k = 20, viewpoint = (0.0, 0.0, 0.0)))]
#[pyo3(text_signature = "(points, k=20, viewpoint=(0.0, 0.0, 0.0))")]
pub fn estimate_normals<'py>(
    py: Python<'py>,
    points: &Bound<'py, PyAny>,
    k: usize,
    viewpoint: (f64, f64, f64),
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    if k < 3 {
        return Err(input(format!("k must be >= 3 (a plane needs three neighbours), found {k}")));
    }
    let points = arrays::points(points, "points")?;
    if points.len() < 3 {
        return Err(input(format!("points: {} point(s); normals need at least 3", points.len())));
    }
    let view = Point3::new(viewpoint.0, viewpoint.1, viewpoint.2);
    let normals = threads::run(py, || knn_normals(&points, k, &view))?;
    Ok(arrays::rows_array(py, &normals))
}

/// The default of `estimate_normals`'s `k`, from the depth stage's configuration.
pub fn default_knn() -> usize {
    DepthConfig::default().cloud.knn
}
