//! Rust errors → Python exceptions. The classes live in `diffcassi/_errors.py` (so they can derive from
//! both `DiffcassiError` and `ValueError`/`OSError`): file problems → `DiffcassiFileError` (an `OSError`),
//! everything else → `DiffcassiValueError` (a `ValueError`); the message is the Rust one.
use pyo3::prelude::*;
use pyo3::types::PyType;

/// The keywords of the Python calls that stand for a command-line option of the same name in kebab case
/// (`electrons_per_unit` for `--electrons-per-unit`): the render and noise keywords, `reconstruct`'s and
/// `study`'s. The library's messages name the command line's options; [`pythonic`] names these keywords
/// instead, so a Python user reads what to change in the call they made.
const OPTION_KEYWORDS: &[&str] = &[
    // render (`crate::settings::RENDER_KEYS`) and its noise keywords
    "bands_nm", "planes", "rays", "seed", "sampling", "opening", "mask_seed", "airy_diameter_px", "airy", "backend", "device",
    "precision", "scene_fov_deg", "noise", "full_well_e", "electrons_per_unit", "read_noise_e", "adc_bits", "noise_seed",
    // reconstruct
    "solver", "iterations", "step", "tv_weight", "tv_iterations", "tv_coupling", "accelerated", "admm_eta", "sigma_max",
    "sigma_min", "tolerance", "denoiser", "tv_warmup", "discrepancy", "noise_norm", "sigma_auto", "noise_twin", "noise_factor",
    "equivariant", "equivariant_seed",
    // study (its keywords are the command line's options in snake case; `--bands` is `render`'s `bands_nm` and
    // `study`'s `bands`: written as both, [`pythonic`])
    "bands", "presets", "systems", "glass_catalogs", "operators", "solvers", "scenes", "synthetic", "scene_wavelengths", "scene_size",
    "fit", "mask", "transport_memory_gb", "force", "noise_estimate", "plain", "weights",
];

/// `message` with each command-line option that has a Python keyword (`--read-noise-e`) written as that
/// keyword (`read_noise_e`); other options (`--scene`, which Python takes as an argument) are left as written.
pub fn pythonic(message: &str) -> String {
    let mut out = String::with_capacity(message.len());
    let mut rest = message;
    while let Some(at) = rest.find("--") {
        let (before, from) = rest.split_at(at);
        out.push_str(before);
        let name_len = from[2..].find(|c: char| !(c.is_ascii_lowercase() || c.is_ascii_digit() || c == '-')).unwrap_or(from.len() - 2);
        let name = from[2..2 + name_len].trim_end_matches('-');
        // An option stands alone: after a space, a bracket or a quote and before a space or punctuation (not in
        // a path such as `runs/--seed/x.npy`).
        let before = out.chars().last().map_or(true, |c| c.is_whitespace() || "([`'\"".contains(c));
        let next = &from[2 + name.len()..];
        let after = match next.chars().next() {
            None => true,
            // A full stop, not a file name's extension (`--seed.npy`).
            Some('.') => next[1..].chars().next().map_or(true, char::is_whitespace),
            Some(c) => c.is_whitespace() || ",;:)]`'\"".contains(c),
        };
        let snake = name.replace('-', "_");
        if before && after && name.starts_with(|c: char| c.is_ascii_lowercase()) && OPTION_KEYWORDS.contains(&snake.as_str()) {
            out.push_str(if snake == "bands" { "bands_nm (study: bands)" } else { &snake });
            rest = &from[2 + name.len()..];
        } else {
            out.push_str("--");
            rest = &from[2..];
        }
    }
    out.push_str(rest);
    out
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
