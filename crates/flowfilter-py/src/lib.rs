//! The compiled module of the Python package `flowfilter` (`flowfilter._flowfilter`): NumPy
//! arrays in, the library's types, results out. A thin layer: no algorithm lives here; each
//! function converts and checks its arguments, runs the library with the GIL released in the
//! package's thread pool, and converts the result. Errors become `flowfilter.InputError` or
//! `flowfilter.ConfigError` (both `flowfilter.Error`) with the library's message.

/// mimalloc keeps freed pages for the next frame's images (the workspace manifest says more).
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

mod arrays;
mod errors;
mod estimate;
mod flow;
mod frame;
mod open3d;
mod params;
mod readers;
mod register;
mod threads;
mod track;

use pyo3::prelude::*;

/// Set the number of worker threads of every later call (0: one per core, or
/// `RAYON_NUM_THREADS`). Results do not depend on it.
#[pyfunction]
fn set_num_threads(n: usize) -> PyResult<()> {
    threads::set(n)
}

/// The number of worker threads calls run on.
#[pyfunction]
fn get_num_threads() -> PyResult<usize> {
    threads::count()
}

/// The defaults of a registration method's parameters: the keys `register(**params)` takes
/// (the method's TOML table).
///
/// Raises ConfigError for an unknown method.
#[pyfunction]
fn default_params<'py>(py: Python<'py>, method: &str) -> PyResult<Bound<'py, PyAny>> {
    arrays::json_object(py, &params::default_params(method)?)
}

/// The default pipeline configuration as a dict of its tables (`configs/flowfilter.toml`'s
/// keys), for `estimate(..., config=...)`.
#[pyfunction]
fn default_config(py: Python<'_>) -> PyResult<Bound<'_, PyAny>> {
    arrays::json_object(py, &flowfilter_pipeline::PipelineConfig::default())
}

/// Freed pages go back to the kernel after a second, not 10 ms (the workspace manifest says
/// why), unless `MIMALLOC_PURGE_DELAY` says otherwise.
fn keep_freed_pages() {
    /// `mi_option_purge_delay` (the same slot in mimalloc v2 and v3; libmimalloc-sys does not
    /// name it).
    const PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;
    if std::env::var_os("MIMALLOC_PURGE_DELAY").is_none() {
        // SAFETY: sets one of mimalloc's integer options; it is read on the allocator's next purge.
        unsafe { libmimalloc_sys::mi_option_set(PURGE_DELAY, 1000) };
    }
}

/// Relative 6-DoF pose of partially seen rigid objects from RGB-D: Flow Filter and the
/// registration baselines (ICP, CPD, FilterReg), with NumPy arrays in and out.
#[pymodule]
fn _flowfilter(m: &Bound<'_, PyModule>) -> PyResult<()> {
    keep_freed_pages();
    let py = m.py();
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("METHODS", flowfilter_pipeline::registration::METHOD_NAMES.to_vec())?;
    m.add("DEFAULT_KNN", flow::default_knn())?;
    m.add("Error", py.get_type::<errors::Error>())?;
    m.add("InputError", py.get_type::<errors::InputError>())?;
    m.add("ConfigError", py.get_type::<errors::ConfigError>())?;
    m.add_class::<register::RegistrationResult>()?;
    m.add_class::<estimate::Estimate>()?;
    m.add_class::<estimate::Correspondences>()?;
    m.add_class::<frame::Camera>()?;
    m.add_class::<frame::Frame>()?;
    m.add_class::<track::Tracker>()?;
    m.add_function(wrap_pyfunction!(register::register, m)?)?;
    m.add_function(wrap_pyfunction!(register::evaluate_registration, m)?)?;
    m.add_function(wrap_pyfunction!(register::global_registration, m)?)?;
    m.add_function(wrap_pyfunction!(estimate::estimate, m)?)?;
    m.add_function(wrap_pyfunction!(estimate::correspondences, m)?)?;
    m.add_function(wrap_pyfunction!(flow::flow, m)?)?;
    m.add_function(wrap_pyfunction!(flow::estimate_normals, m)?)?;
    m.add_function(wrap_pyfunction!(readers::read_ply, m)?)?;
    m.add_function(wrap_pyfunction!(readers::write_ply, m)?)?;
    m.add_function(wrap_pyfunction!(readers::read_camera, m)?)?;
    m.add_function(wrap_pyfunction!(readers::read_frame, m)?)?;
    m.add_function(wrap_pyfunction!(readers::read_bigbird_frame, m)?)?;
    m.add_function(wrap_pyfunction!(readers::bigbird_motion, m)?)?;
    m.add_function(wrap_pyfunction!(readers::read_bop_frame, m)?)?;
    m.add_function(wrap_pyfunction!(readers::bop_motion, m)?)?;
    m.add_function(wrap_pyfunction!(readers::bop_objects, m)?)?;
    m.add_function(wrap_pyfunction!(set_num_threads, m)?)?;
    m.add_function(wrap_pyfunction!(get_num_threads, m)?)?;
    m.add_function(wrap_pyfunction!(default_params, m)?)?;
    m.add_function(wrap_pyfunction!(default_config, m)?)?;
    Ok(())
}
