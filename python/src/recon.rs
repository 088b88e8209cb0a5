//! Reconstruction operators, solvers and metrics (issue 13), wrapped once the library has them.
use pyo3::prelude::*;

pub fn register(_m: &Bound<'_, PyModule>) -> PyResult<()> {
    Ok(())
}
