//! `set_limits` / `get_limits`: the memory and ray budgets of every following call (the CLI's
//! `--max-memory-gb` / `--max-rays`, [`diffcassi::limits`]). The budgets are process-wide; messages of a
//! refused call name these keywords (`raise max_memory_gb (diffcassi.set_limits)`), set at import.
//!
//! ```text
//! diffcassi.set_limits(max_memory_gb=64, max_rays=1e11)   # None: the default (half the RAM, 2e10 rays)
//! diffcassi.get_limits()  # {'max_memory_gb': 64.0, 'max_rays': 1e11, 'memory_source': 'max_memory_gb=64'}
//! ```
use crate::errors::{value_error, IntoPy};
use diffcassi::limits::{self, BudgetNames};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// The budgets' names in messages: the keywords of `diffcassi.set_limits`.
fn names() -> BudgetNames {
    BudgetNames { memory: "max_memory_gb".into(), rays: "max_rays".into(), separator: "=".into(), setter: "diffcassi.set_limits".into() }
}

/// The defaults, named by the Python keywords (at import).
pub fn init() -> PyResult<()> {
    limits::set_budget_named(None, None, names()).py()
}

/// A budget keyword: `None` or a real number (not a bool, not a string).
fn number(name: &str, v: Option<&Bound<'_, PyAny>>) -> PyResult<Option<f64>> {
    let Some(v) = v.filter(|v| !v.is_none()) else { return Ok(None) };
    if v.is_instance_of::<pyo3::types::PyBool>() {
        return Err(value_error(format!("{name}: expected a number or None, got bool {v}")));
    }
    v.extract::<f64>().map(Some).map_err(|_| {
        let ty = v.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "?".into());
        value_error(format!("{name}: expected a number or None, got {ty} {}", v.repr().map(|r| r.to_string()).unwrap_or_default()))
    })
}

/// Set the memory budget (GB, > 0) and the ray budget (rays, ≥ 1) of every following call; `None`: the
/// default (half of the physical memory; 2·10¹⁰ rays). Both are replaced at each call.
#[pyfunction]
#[pyo3(signature = (max_memory_gb = None, max_rays = None))]
pub fn set_limits(max_memory_gb: Option<&Bound<'_, PyAny>>, max_rays: Option<&Bound<'_, PyAny>>) -> PyResult<()> {
    let (gb, rays) = (number("max_memory_gb", max_memory_gb)?, number("max_rays", max_rays)?);
    limits::set_budget_named(gb, rays, names()).py()
}

/// The budgets now: {max_memory_gb, max_rays, memory_source}.
#[pyfunction]
pub fn get_limits(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let b = limits::budget();
    let d = PyDict::new(py);
    d.set_item("max_memory_gb", b.memory_bytes / 1e9)?;
    d.set_item("max_rays", b.rays)?;
    d.set_item("memory_source", b.memory_source)?;
    Ok(d)
}
