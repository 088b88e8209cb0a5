//! The crate's error type. Every message names what was wrong: the file, the line or field, the value.
use crate::materials::MaterialError;

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A spec (TOML/JSON/YAML/CSV prescription) could not be read or is invalid.
    #[error("{source_name}: {message}")]
    Spec { source_name: String, message: String },
    /// A built system is inconsistent (message names surface and field).
    #[error("system `{system}`: surface {surface} ({field}): {message}")]
    System { system: String, surface: usize, field: String, message: String },
    #[error(transparent)]
    Material(#[from] MaterialError),
    #[error("{path}: {message}")]
    File { path: String, message: String },
    #[error("{0}")]
    Invalid(String),
    #[error(transparent)]
    Io(#[from] crate::io::IoError),
    #[error(transparent)]
    Plot(#[from] crate::plot::PlotError),
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    pub fn spec(source_name: impl Into<String>, message: impl Into<String>) -> Self {
        Error::Spec { source_name: source_name.into(), message: message.into() }
    }
    pub fn invalid(message: impl Into<String>) -> Self {
        Error::Invalid(message.into())
    }
}
