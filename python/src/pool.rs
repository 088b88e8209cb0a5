//! The thread pool heavy calls run in, and the GIL release around them.
//!
//! `set_num_threads(n)` builds a rayon pool of `n` threads (0: back to rayon's global pool, sized by
//! `RAYON_NUM_THREADS` or the core count). Results never depend on the thread count (the library's rule).
use pyo3::prelude::*;
use std::sync::{Arc, RwLock};

static POOL: RwLock<Option<Arc<rayon::ThreadPool>>> = RwLock::new(None);

fn current() -> Option<Arc<rayon::ThreadPool>> {
    POOL.read().unwrap_or_else(|p| p.into_inner()).clone()
}

/// Run `f` without the GIL, inside the chosen pool.
pub fn run<T: Send>(py: Python<'_>, f: impl FnOnce() -> T + Send) -> T {
    let pool = current();
    py.allow_threads(move || match pool {
        Some(p) => p.install(f),
        None => f(),
    })
}

/// Use `n` threads for every following heavy call (0: rayon's default, all cores or `RAYON_NUM_THREADS`).
#[pyfunction]
pub fn set_num_threads(n: i64) -> PyResult<()> {
    if n < 0 {
        return Err(pyo3::exceptions::PyValueError::new_err(format!("set_num_threads: n = {n} must be ≥ 0 (0: all cores)")));
    }
    let pool = if n == 0 {
        None
    } else {
        let p = rayon::ThreadPoolBuilder::new()
            .num_threads(n as usize)
            .build()
            .map_err(|e| pyo3::exceptions::PyRuntimeError::new_err(format!("set_num_threads({n}): {e}")))?;
        Some(Arc::new(p))
    };
    *POOL.write().unwrap_or_else(|p| p.into_inner()) = pool;
    Ok(())
}

/// Threads the heavy calls use.
#[pyfunction]
pub fn get_num_threads() -> usize {
    match current() {
        Some(p) => p.current_num_threads(),
        None => rayon::current_num_threads(),
    }
}
