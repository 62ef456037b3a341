//! `flowfilter.register`: two clouds in, the rigid transform out (`flowfilter register`).

use crate::arrays::{self, json_object, matrix};
use crate::errors::{input, registration};
use crate::{params, threads};
use flowfilter_pipeline::registration::{correspondence_set, evaluate, registrar_by_name};
use flowfilter_pipeline::{Correspondences, PointCloud, RegisterReport, RegistrationProblem};
use numpy::PyArray2;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};
use std::time::Instant;

/// The result of `register`: Open3D's `RegistrationResult` fields (`transformation`, `fitness`,
/// `inlier_rmse`) and the backend's report.
#[pyclass(module = "flowfilter", frozen)]
pub struct RegistrationResult {
    report: RegisterReport,
    sigma2: Option<f64>,
    scale: Option<f64>,
    seconds: f64,
}

#[pymethods]
impl RegistrationResult {
    /// The 4x4 float64 transform `T` with `target ~ T @ source` (homogeneous coordinates).
    #[getter]
    fn transformation<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        matrix(py, &self.report.transform)
    }
    /// Fraction of source points with a target neighbour within the inlier distance.
    #[getter]
    fn fitness(&self) -> f64 {
        self.report.registration.fitness
    }
    /// RMSE of those inlier pairs, metres.
    #[getter]
    fn inlier_rmse(&self) -> f64 {
        self.report.registration.inlier_rmse_m
    }
    /// Iterations run.
    #[getter]
    fn iterations(&self) -> usize {
        self.report.registration.iterations
    }
    /// Whether the backend's convergence criterion was met.
    #[getter]
    fn converged(&self) -> bool {
        self.report.registration.converged
    }
    /// Final sigma^2 (m^2) of the GMM backends (CPD, FilterReg, Flow Filter); None for ICP.
    #[getter]
    fn sigma2(&self) -> Option<f64> {
        self.sigma2
    }
    /// CPD's scale when scale estimation is on, else None.
    #[getter]
    fn scale(&self) -> Option<f64> {
        self.scale
    }
    /// The backend's name (`icp-pt2pl`, ...).
    #[getter]
    fn method(&self) -> &str {
        &self.report.method
    }
    /// Seconds spent inside the backend (the rest of the call is the binding's).
    #[getter]
    fn seconds(&self) -> f64 {
        self.seconds
    }
    /// Conditions to know about, as dicts `{"code", "message"}` (`register --json`'s).
    #[getter]
    fn warnings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_object(py, &self.report.warnings)
    }
    /// Error bounds `{"rotation_deg", "translation_m"}` when the backend gives them, else None.
    #[getter]
    fn uncertainty<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_object(py, &self.report.registration.uncertainty)
    }
    /// The result as `flowfilter register --json` prints it (schema "flowfilter register v1").
    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_object(py, &self.report)
    }
    fn __repr__(&self) -> String {
        let r = &self.report.registration;
        format!(
            "RegistrationResult(method='{}', fitness={:.6}, inlier_rmse={:.6e}, iterations={}, converged={})",
            self.report.method,
            r.fitness,
            r.inlier_rmse_m,
            r.iterations,
            if r.converged { "True" } else { "False" }
        )
    }
}

/// A cloud from its points and optional normals (same number of rows). `points` may be an
/// `open3d.geometry.PointCloud`: its normals are used unless `normals` are given.
pub fn cloud(points: &Bound<'_, PyAny>, normals: Option<&Bound<'_, PyAny>>, name: &str) -> PyResult<PointCloud> {
    let (points, own_normals) = crate::open3d::points_and_normals(points, name)?;
    let mut cloud = PointCloud::from_points(arrays::points(&points, name)?);
    if let Some(n) = normals.filter(|n| !n.is_none()).or(own_normals.as_ref()) {
        let normals = arrays::vectors(n, &format!("{name}_normals"))?;
        if normals.len() != cloud.len() {
            return Err(input(format!("{name}_normals: {} rows, but {name} has {}", normals.len(), cloud.len())));
        }
        cloud.normals = Some(normals);
    }
    Ok(cloud)
}

/// `(source_points, target_points)` or `(source_points, target_points, weights)`.
fn correspondences(obj: &Bound<'_, PyAny>) -> PyResult<Correspondences> {
    let parts = obj.cast::<PyTuple>().map_err(|_| {
        input("correspondences: expected a tuple (source_points, target_points[, weights]) of (K, 3) arrays")
    })?;
    if !(2..=3).contains(&parts.len()) {
        return Err(input(format!("correspondences: expected 2 or 3 arrays, found {}", parts.len())));
    }
    let source = arrays::points(&parts.get_item(0)?, "correspondences[0]")?;
    let target = arrays::points(&parts.get_item(1)?, "correspondences[1]")?;
    if source.len() != target.len() {
        return Err(input(format!(
            "correspondences: {} source points but {} target points",
            source.len(),
            target.len()
        )));
    }
    let weights = match parts.get_item(2) {
        Ok(w) => arrays::weights(&w, "correspondences[2]", source.len())?,
        Err(_) => vec![1.0; source.len()],
    };
    let c = Correspondences { source, target, weights };
    c.validate().map_err(|e| input(format!("correspondences: {e}")))?;
    Ok(c)
}

/// Align `source` to `target`: the rigid `T` with `target ~ T @ source`.
///
/// `source`, `target`: (N, 3) float32 or float64 arrays (any memory layout), or
/// `open3d.geometry.PointCloud`s (their normals used when they have them). `method`: one of
/// icp-pt2pt, icp-pt2pl, cpd, filterreg-pt2pt, filterreg-pt2pl, flowfilter (with
/// `correspondences`; without them Flow Filter falls back to FilterReg with a warning).
/// `init`: a 4x4 initial transform. `target_normals` (and `source_normals`): (N, 3) unit
/// normals, needed by the point-to-plane methods (see `estimate_normals`). `correspondences`:
/// `(source_points, target_points[, weights])` for the Flow Filter methods. `**params`: the
/// backend's parameters, with the names and defaults of its TOML table (`[icp]`, `[cpd]`,
/// `[filterreg]`, `[flowfilter]`; see `default_params(method)`).
///
/// Raises InputError for arrays that cannot be used, ConfigError for an unknown method or
/// parameter or a value out of range.
#[pyfunction]
#[pyo3(signature = (source, target, method = "filterreg-pt2pt", init = None, target_normals = None, *, source_normals = None, correspondences = None, **params))]
#[allow(clippy::too_many_arguments)]
pub fn register(
    py: Python<'_>,
    source: &Bound<'_, PyAny>,
    target: &Bound<'_, PyAny>,
    method: &str,
    init: Option<&Bound<'_, PyAny>>,
    target_normals: Option<&Bound<'_, PyAny>>,
    source_normals: Option<&Bound<'_, PyAny>>,
    correspondences: Option<&Bound<'_, PyAny>>,
    params: Option<&Bound<'_, PyDict>>,
) -> PyResult<RegistrationResult> {
    let config = params::registration_config(method, params)?;
    let registrar = registrar_by_name(method, &config).map_err(|e| registration(&e))?;
    let mut problem =
        RegistrationProblem::new(cloud(source, source_normals, "source")?, cloud(target, target_normals, "target")?);
    if let Some(init) = init.filter(|i| !i.is_none()) {
        problem = problem.with_init(arrays::pose(init, "init")?);
    }
    if let Some(c) = correspondences.filter(|c| !c.is_none()) {
        problem = problem.with_correspondences(self::correspondences(c)?);
    }
    let (points_s, points_t) = (problem.source.len(), problem.target.len());
    let (result, seconds) = threads::run(py, || {
        let start = Instant::now();
        let r = registrar.register_checked(&problem);
        (r, start.elapsed().as_secs_f64())
    })?;
    let r = result.map_err(|e| registration(&e))?;
    Ok(RegistrationResult {
        report: RegisterReport::new(registrar.name(), &r, points_s, points_t, seconds * 1e3),
        sigma2: r.sigma2,
        scale: r.scale,
        seconds,
    })
}

/// How well `transformation` aligns `source` to `target` (Open3D's `evaluate_registration`):
/// `(fitness, inlier_rmse, correspondence_set)`, with fitness the fraction of moved source
/// points whose nearest target point lies within `max_correspondence_distance`, the RMSE of
/// those pairs (metres), and the pairs as a (K, 2) int64 array of `(source index, target
/// index)`. `source`, `target`: (N, 3) arrays or `open3d.geometry.PointCloud`s;
/// `transformation`: 4x4 (default identity).
///
/// Raises InputError for arrays that cannot be used or a distance that is not positive.
#[pyfunction]
#[pyo3(signature = (source, target, max_correspondence_distance, transformation = None))]
pub fn evaluate_registration<'py>(
    py: Python<'py>,
    source: &Bound<'py, PyAny>,
    target: &Bound<'py, PyAny>,
    max_correspondence_distance: f64,
    transformation: Option<&Bound<'py, PyAny>>,
) -> PyResult<(f64, f64, Bound<'py, PyArray2<i64>>)> {
    if !(max_correspondence_distance.is_finite() && max_correspondence_distance > 0.0) {
        return Err(input(format!(
            "max_correspondence_distance: expected a positive distance (metres), found {max_correspondence_distance}"
        )));
    }
    let source = cloud(source, None, "source")?;
    let target = cloud(target, None, "target")?;
    let transform = match transformation.filter(|t| !t.is_none()) {
        Some(t) => arrays::pose(t, "transformation")?,
        None => flowfilter_pipeline::Pose::identity(),
    };
    let (fitness, rmse, pairs) = threads::run(py, || {
        let index = flowfilter_pipeline::geometry::KnnIndex::new(&target.points);
        let (fitness, rmse) = evaluate(&source.points, &index, &transform, max_correspondence_distance);
        (fitness, rmse, correspondence_set(&source.points, &index, &transform, max_correspondence_distance))
    })?;
    let rows: Vec<Vec<i64>> = pairs.into_iter().map(|(s, t)| vec![s as i64, t as i64]).collect();
    let array = if rows.is_empty() {
        numpy::PyArray2::zeros(py, [0, 2], false)
    } else {
        numpy::PyArray2::from_vec2(py, &rows).map_err(|e| input(e.to_string()))?
    };
    Ok((fitness, rmse, array))
}

/// `(transformation, inliers, matches)` of [`global_registration`].
type GlobalStartTuple<'py> = (Bound<'py, PyArray2<f64>>, usize, usize);

/// A start for `register` from nowhere (Open3D's global registration, then point-to-plane ICP;
/// `flowfilter register --global`): both clouds thinned to at most 2500 points from
/// `voxel_size` (metres) up, FPFH descriptors matched both ways, a RANSAC over three matches.
/// Returns `(transformation, inliers, matches)`: the 4x4 float64 transform with `target ~ T @
/// source`, and how many of the mutual descriptor matches agree with it; `None` when no motion
/// gathers 12 of them. `source`, `target`: (N, 3) arrays or `open3d.geometry.PointCloud`s.
///
/// Raises InputError for arrays that cannot be used or a voxel size that is not positive.
#[pyfunction]
#[pyo3(signature = (source, target, voxel_size = 0.005))]
pub fn global_registration<'py>(
    py: Python<'py>,
    source: &Bound<'py, PyAny>,
    target: &Bound<'py, PyAny>,
    voxel_size: f64,
) -> PyResult<Option<GlobalStartTuple<'py>>> {
    if !(voxel_size.is_finite() && voxel_size > 0.0) {
        return Err(input(format!("voxel_size: expected a positive length (metres), found {voxel_size}")));
    }
    let (source, target) = (cloud(source, None, "source")?, cloud(target, None, "target")?);
    let cfg = flowfilter_pipeline::GeometryGuideConfig { min_voxel_m: voxel_size, ..Default::default() };
    let found = threads::run(py, || flowfilter_pipeline::global_start(&source, &target, &cfg))?;
    Ok(found.map(|f| (matrix(py, &flowfilter_pipeline::matrix_rows(&f.pose)), f.inliers, f.matches)))
}
