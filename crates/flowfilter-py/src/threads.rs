//! The thread pool every computation runs in: sized by `flowfilter.set_num_threads`, entered
//! with the GIL released.

use pyo3::{PyResult, Python};
use rayon::ThreadPool;
use std::sync::{Arc, Mutex};

/// The pool and the size asked for (0: rayon's default, `RAYON_NUM_THREADS` or one per core).
static POOL: Mutex<Option<(usize, Arc<ThreadPool>)>> = Mutex::new(None);

fn build(threads: usize) -> PyResult<Arc<ThreadPool>> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .thread_name(|i| format!("flowfilter-{i}"))
        .build()
        .map(Arc::new)
        .map_err(|e| crate::errors::Error::new_err(format!("cannot start {threads} threads: {e}")))
}

fn pool() -> PyResult<Arc<ThreadPool>> {
    let mut guard = POOL.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    if let Some((_, pool)) = guard.as_ref() {
        return Ok(Arc::clone(pool));
    }
    let pool = build(0)?;
    *guard = Some((0, Arc::clone(&pool)));
    Ok(pool)
}

/// Size the pool: `threads` workers, or 0 for the default. Results do not depend on it.
pub fn set(threads: usize) -> PyResult<()> {
    let pool = build(threads)?;
    *POOL.lock().unwrap_or_else(std::sync::PoisonError::into_inner) = Some((threads, pool));
    Ok(())
}

/// Workers of the pool.
pub fn count() -> PyResult<usize> {
    Ok(pool()?.current_num_threads())
}

/// Run `work` in the pool with the GIL released (other Python threads run meanwhile).
pub fn run<T: Send>(py: Python<'_>, work: impl FnOnce() -> T + Send) -> PyResult<T> {
    let pool = pool()?;
    Ok(py.detach(|| pool.install(work)))
}
