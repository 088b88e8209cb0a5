//! `diffcassi._native`: the compiled half of the `diffcassi` Python package (PyO3 + rust-numpy). Every
//! function is a thin layer on the library crate: it checks the NumPy arguments (dtype, shape,
//! C-contiguity, finiteness; a clear `ValueError` naming the argument otherwise), releases the GIL, runs the
//! Rust API in the pool `set_num_threads` chose, and hands the Rust-owned result to NumPy without a copy.
//! The pure-Python half (`diffcassi/__init__.py`, `diffcassi/torch.py`) adds docstrings, defaults and
//! PyTorch helpers.
//!
//! ```text
//! import diffcassi, numpy as np
//! sp = diffcassi.System.preset("sp")
//! acq, info = diffcassi.render(sp, np.ones((32, 32, 28), np.float32), np.linspace(450, 650, 28))
//! ```
use pyo3::prelude::*;

mod arrays;
mod codesign;
mod errors;
mod limits;
mod pool;
mod recipe;
mod recon;
mod render;
mod settings;
mod study;
mod system;

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    pool::init();
    // The library's messages name settings as Python's keywords (diffcassi::frontend).
    diffcassi::frontend::set(diffcassi::frontend::Frontend::Python);
    limits::init()?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("EMBREE", cfg!(feature = "embree"))?;
    // The ray status codes of `trace` and their names, from the library's enum (every code it can return).
    let status = pyo3::types::PyDict::new(m.py());
    for s in diffcassi::tracer::RayStatus::ALL {
        status.set_item(s as u8, s.words())?;
    }
    m.add("STATUS", status)?;
    m.add_function(wrap_pyfunction!(pool::_check_rayon_env, m)?)?;
    m.add_function(wrap_pyfunction!(pool::set_num_threads, m)?)?;
    m.add_function(wrap_pyfunction!(pool::get_num_threads, m)?)?;
    m.add_function(wrap_pyfunction!(limits::set_limits, m)?)?;
    m.add_function(wrap_pyfunction!(limits::get_limits, m)?)?;
    system::register(m)?;
    render::register(m)?;
    recon::register(m)?;
    codesign::register(m)?;
    study::register(m)?;
    Ok(())
}
