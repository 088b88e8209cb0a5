//! Rust errors → Python exceptions. The classes live in `diffcassi/_errors.py` (so they can derive from
//! both `DiffcassiError` and `ValueError`/`OSError`): file problems → `DiffcassiFileError` (an `OSError`),
//! everything else → `DiffcassiValueError` (a `ValueError`); the message is the Rust one.
use pyo3::prelude::*;
use pyo3::types::PyType;

/// `message` with each command-line option that has a Python keyword (`--read-noise-e`) written as that
/// keyword (`read_noise_e`): the library's table of the front ends' spellings
/// ([`diffcassi::frontend::spell`]); other options (`--scene`, which Python takes as an argument) are left as
/// written. Library errors are spelled so already (the module declares itself the Python front end); this
/// spells the binding's own messages and the library's warnings.
pub fn pythonic(message: &str) -> String {
    diffcassi::frontend::spell(message, diffcassi::frontend::Frontend::Python).into_owned()
}

fn raise(kind: &str, message: String) -> PyErr {
    let message = pythonic(&message);
    Python::with_gil(|py| {
        let cls = py.import("diffcassi._errors").and_then(|m| m.getattr(kind)).and_then(|c| c.downcast_into::<PyType>().map_err(PyErr::from));
        match cls {
            Ok(cls) => PyErr::from_type(cls, message),
            // The package is not importable (the extension loaded on its own): plain built-ins.
            Err(_) if kind == "DiffcassiFileError" => pyo3::exceptions::PyOSError::new_err(message),
            Err(_) => pyo3::exceptions::PyValueError::new_err(message),
        }
    })
}

/// A `ValueError` (bad value, shape, dtype) with `message`.
pub fn value_error(message: impl Into<String>) -> PyErr {
    raise("DiffcassiValueError", message.into())
}

/// An `OSError` (missing or unreadable file) with `message`.
pub fn file_error(message: impl Into<String>) -> PyErr {
    raise("DiffcassiFileError", message.into())
}

/// The Python exception of a library error.
pub fn to_py(e: diffcassi::Error) -> PyErr {
    use diffcassi::Error as E;
    match &e {
        E::File { .. } | E::Io(_) => file_error(e.to_string()),
        _ => value_error(e.to_string()),
    }
}

/// `Result` conversion: `.py()?` in the bindings.
pub trait IntoPy<T> {
    fn py(self) -> PyResult<T>;
}

impl<T> IntoPy<T> for diffcassi::Result<T> {
    fn py(self) -> PyResult<T> {
        self.map_err(to_py)
    }
}
