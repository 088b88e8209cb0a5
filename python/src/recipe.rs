//! Pickling of the native objects built from a system and settings (`Transport`, `Operator`, `DiffRenderer`):
//! each keeps its [`Recipe`] — the public factory of the `diffcassi` package that built it, its arguments and
//! keywords (copied at construction, so a later change to the caller's mask array or settings dict does not
//! reach it) — and its `__reduce__` hands the recipe to pickle, which rebuilds the object by calling the factory
//! again (`diffcassi._rebuild`). The rebuild traces again with the same seeds, so the copy's numbers equal the
//! original's bit for bit (the renderer's determinism); it costs the trace the original cost. What this serves:
//! DataLoader workers started by spawn or forkserver, `torch.save` of a model holding an operator or a
//! `CassiRenderer`, `copy.deepcopy` for EMA snapshots and best checkpoints.
//!
//! ```text
//! op = diffcassi.exact(system, 64, 64, rays=4, seed=3)
//! op2 = pickle.loads(pickle.dumps(op))   # diffcassi._rebuild("exact", (system, 64, 64, None), {"rays": 4, "seed": 3})
//! ```
use crate::system::PySystem;
use diffcassi::render::Mask;
use numpy::{IntoPyArray, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};
use std::sync::Arc;

/// How a native object was built: `diffcassi._rebuild(factory, args, kwargs, values)` builds it again.
pub struct Recipe {
    /// The factory's name in `diffcassi._rebuild`'s table (`exact`, `mapping_operator`, `shift_operator`,
    /// `Transport`, `DiffRenderer`).
    factory: &'static str,
    args: Py<PyTuple>,
    kwargs: Py<PyDict>,
    /// `DiffRenderer.with_values(values)` after the factory (a renderer moved to other parameter values).
    values: Option<Vec<f64>>,
}

impl Recipe {
    /// The recipe of `factory(system, height, width, mask, **settings)` (the render-settings factories): the
    /// system shared (it is immutable), the mask as the float32 array the object was built with (`None`: the
    /// settings' random mask), the settings deep-copied.
    pub fn render_settings(py: Python<'_>, factory: &'static str, system: &PySystem, height: usize, width: usize, mask: Option<&Mask>, settings: Option<&Bound<'_, PyDict>>) -> PyResult<Arc<Recipe>> {
        let system = Py::new(py, system.share())?.into_any();
        let mask: PyObject = match mask {
            Some(m) => m.values.clone().into_pyarray(py).reshape([m.height, m.width])?.into_any().unbind(),
            None => py.None(),
        };
        let args = PyTuple::new(py, [system, height.into_pyobject(py)?.into_any().unbind(), width.into_pyobject(py)?.into_any().unbind(), mask])?;
        Ok(Arc::new(Recipe { factory, args: args.unbind(), kwargs: deep_copy(py, settings)?, values: None }))
    }

    /// A recipe from arguments already owned (e.g. `DiffRenderer`'s), keywords deep-copied.
    pub fn new(py: Python<'_>, factory: &'static str, args: Bound<'_, PyTuple>, kwargs: Option<&Bound<'_, PyDict>>) -> PyResult<Arc<Recipe>> {
        Ok(Arc::new(Recipe { factory, args: args.unbind(), kwargs: deep_copy(py, kwargs)?, values: None }))
    }

    /// The same arguments for another factory (`Transport(...).operator` is `exact(...)` with them).
    pub fn with_factory(&self, py: Python<'_>, factory: &'static str) -> Arc<Recipe> {
        Arc::new(Recipe { factory, args: self.args.clone_ref(py), kwargs: self.kwargs.clone_ref(py), values: self.values.clone() })
    }

    /// The system the object was built from (its factory's first argument), when it is one.
    pub fn system<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyAny>> {
        let first = self.args.bind(py).get_item(0).ok()?;
        first.downcast::<PySystem>().is_ok().then_some(first)
    }

    /// The same recipe followed by `with_values(values)`.
    pub fn with_values(&self, py: Python<'_>, values: Vec<f64>) -> Arc<Recipe> {
        Arc::new(Recipe { factory: self.factory, args: self.args.clone_ref(py), kwargs: self.kwargs.clone_ref(py), values: Some(values) })
    }

    /// `__reduce__`'s value: `(diffcassi._rebuild, (factory, args, kwargs, values))`.
    pub fn reduce<'py>(&self, py: Python<'py>) -> PyResult<(Bound<'py, PyAny>, (&'static str, Py<PyTuple>, Py<PyDict>, Option<Vec<f64>>))> {
        let rebuild = py.import("diffcassi")?.getattr("_rebuild")?;
        Ok((rebuild, (self.factory, self.args.clone_ref(py), self.kwargs.clone_ref(py), self.values.clone())))
    }
}

fn deep_copy(py: Python<'_>, d: Option<&Bound<'_, PyDict>>) -> PyResult<Py<PyDict>> {
    match d {
        Some(d) => Ok(py.import("copy")?.call_method1("deepcopy", (d,))?.downcast_into::<PyDict>()?.unbind()),
        None => Ok(PyDict::new(py).unbind()),
    }
}
