//! File input/output helpers: atomic writes, NumPy `.npy` arrays and small numeric CSV tables.
//!
//! Every fallible function returns [`IoError`], whose message always names the file involved and,
//! where it applies, the line, column and field that caused the problem, so an error can be printed
//! to the user as is.
//!
//! * [`atomic`]: [`write_atomic`] / [`write_atomic_with`] (temporary file in the same directory,
//!   then rename; parent directories are created).
//! * [`policy`]: what an output path may be (new, a previous output of the same command, never an input;
//!   `--force`), checked before any work; [`stale`]: temporary names carrying their writer, and the removal
//!   of those killed runs left; [`OutputSet`] stages multi-file outputs and swaps them in; [`lock`]: an
//!   exclusive advisory lock on an output folder (concurrent runs into one folder).
//! * [`npy`]: [`write_npy_f64`], [`write_npy_f32`], [`write_npy_u8`], [`write_npy_u16`] and
//!   [`read_npy_f64`] (NPY format, little-endian, C order).
//! * [`csv`]: [`read_columns`] (pick numeric columns by header name) and [`CsvWriter`].
//! * [`input`]: [`input::read_input`], every input file read whole: a regular file (never a FIFO, device or
//!   folder) of bounded size, through a bounded reader.
//!
//! # Example
//!
//! ```
//! use diffcassi::io::{read_columns, read_npy_f64, write_npy_f64, CsvWriter};
//!
//! # fn main() -> Result<(), diffcassi::io::IoError> {
//! let dir = std::env::temp_dir().join(format!("diffcassi_io_doc_{}", std::process::id()));
//! let npy = dir.join("cube.npy");
//! write_npy_f64(&npy, &[2, 3], &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0])?;
//! let (shape, data) = read_npy_f64(&npy)?;
//! assert_eq!(shape, vec![2, 3]);
//! assert_eq!(data[5], 6.0);
//!
//! let csv = dir.join("spots.csv");
//! let mut w = CsvWriter::new(&csv, &["px", "py"])?;
//! w.row_f64(&[0.5, -0.25])?;
//! w.finish()?;
//! let cols = read_columns(&csv, &["py"])?;
//! assert_eq!(cols, vec![vec![-0.25]]);
//! # std::fs::remove_dir_all(&dir).ok();
//! # Ok(())
//! # }
//! ```

pub mod atomic;
pub mod csv;
pub mod exr;
pub mod input;
pub mod lock;
pub mod npy;
pub mod png16;
pub mod policy;
pub mod sha256;
pub mod stale;

use std::path::{Path, PathBuf};

pub use atomic::{swap_into_place, write_atomic, write_atomic_with, OutputSet};
pub use csv::{parse_columns, read_columns, CsvValue, CsvWriter};
pub use npy::{
    read_npy_f32, read_npy_f64, write_npy, write_npy_f32, write_npy_f64, write_npy_u16, write_npy_u8, NpyElement,
};

/// Errors of the [`io`](self) module. Every variant carries the path of the file concerned.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum IoError {
    /// An operating-system level error (open, read, write, rename, create directory...).
    #[error("{}: {action}: {source}", path.display())]
    Io {
        path: PathBuf,
        /// What was being attempted, e.g. "cannot create directory".
        action: &'static str,
        #[source]
        source: std::io::Error,
    },

    /// `shape.iter().product()` does not match the number of elements supplied.
    #[error(
        "{}: array shape {shape:?} holds {expected} elements but {actual} values were given",
        path.display()
    )]
    ShapeMismatch {
        path: PathBuf,
        shape: Vec<usize>,
        expected: usize,
        actual: usize,
    },

    /// A malformed or unsupported `.npy` file.
    #[error("{}: not a supported .npy file: {reason}", path.display())]
    Npy { path: PathBuf, reason: String },

    /// A well-formed `.npy` file whose content cannot be taken: a value beyond the float32 range the cubes
    /// are held in, or an array beyond the memory budget.
    #[error("{}: {reason}", path.display())]
    NpyContent { path: PathBuf, reason: String },

    /// A malformed, truncated or unsupported OpenEXR file (see [`exr`]).
    #[error("{}: {reason}", path.display())]
    Exr { path: PathBuf, reason: String },

    /// A malformed, truncated or unsupported PNG file (see [`png16`]).
    #[error("{}: {reason}", path.display())]
    Png { path: PathBuf, reason: String },

    /// An input that is not a regular file of bounded size ([`input`]): nothing was read.
    #[error("{}: {reason}", path.display())]
    Input { path: PathBuf, reason: String },

    /// The output policy refused an output path ([`policy`]): nothing was written.
    #[error("{}: {reason}", path.display())]
    Refused { path: PathBuf, reason: String },

    /// The CSV file has no header line (it is empty or holds only comments and blank lines).
    #[error("{}: no header line (the file is empty or holds only '#' comments and blank lines)", path.display())]
    CsvNoHeader { path: PathBuf },

    /// A requested column is not in the header.
    #[error(
        "{}:{line}: no column named '{column}' in the header; available columns: {}",
        path.display(),
        available.join(", ")
    )]
    CsvMissingColumn {
        path: PathBuf,
        /// 1-based line number of the header.
        line: usize,
        column: String,
        available: Vec<String>,
    },

    /// A requested column name occurs more than once in the header.
    #[error(
        "{}:{line}: column '{column}' appears more than once in the header (fields {first} and {second})",
        path.display()
    )]
    CsvDuplicateColumn {
        path: PathBuf,
        line: usize,
        column: String,
        /// 1-based field numbers of the first two occurrences.
        first: usize,
        second: usize,
    },

    /// A data row has no value (missing or empty field) for a requested column.
    #[error(
        "{}:{line}: missing value for column '{column}' (field {field}; the row has {fields_in_row} fields)",
        path.display()
    )]
    CsvMissingValue {
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        column: String,
        /// 1-based field number of the column.
        field: usize,
        fields_in_row: usize,
    },

    /// A value of a requested column is not a number.
    #[error(
        "{}:{line}: column '{column}' (field {field}): cannot parse '{value}' as a number",
        path.display()
    )]
    CsvParse {
        path: PathBuf,
        line: usize,
        column: String,
        field: usize,
        value: String,
    },

    /// A syntax error such as an unterminated quoted field.
    #[error("{}:{line}: {reason}", path.display())]
    CsvSyntax {
        path: PathBuf,
        line: usize,
        reason: String,
    },

    /// [`CsvWriter`]: a row does not have as many fields as the header.
    #[error(
        "{}: row {row} has {actual} fields but the header has {expected} columns",
        path.display()
    )]
    CsvRowLength {
        path: PathBuf,
        /// 1-based data row number.
        row: usize,
        expected: usize,
        actual: usize,
    },

    /// [`CsvWriter`]: a value that cannot be represented (e.g. a string with a line break).
    #[error("{}: row {row}: {reason}", path.display())]
    CsvValue {
        path: PathBuf,
        /// 1-based data row number (0 = header).
        row: usize,
        reason: String,
    },
}

impl IoError {
    /// Wrap an [`std::io::Error`] with the file path and what was being done.
    pub fn io(path: impl AsRef<Path>, action: &'static str, source: std::io::Error) -> Self {
        IoError::Io {
            path: path.as_ref().to_path_buf(),
            action,
            source,
        }
    }

    /// The file this error is about.
    pub fn path(&self) -> &Path {
        match self {
            IoError::Io { path, .. }
            | IoError::ShapeMismatch { path, .. }
            | IoError::Npy { path, .. }
            | IoError::NpyContent { path, .. }
            | IoError::Exr { path, .. }
            | IoError::Png { path, .. }
            | IoError::Refused { path, .. }
            | IoError::Input { path, .. }
            | IoError::CsvNoHeader { path }
            | IoError::CsvMissingColumn { path, .. }
            | IoError::CsvDuplicateColumn { path, .. }
            | IoError::CsvMissingValue { path, .. }
            | IoError::CsvParse { path, .. }
            | IoError::CsvSyntax { path, .. }
            | IoError::CsvRowLength { path, .. }
            | IoError::CsvValue { path, .. } => path,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_name_the_path() {
        let e = IoError::io("/a/b.npy", "cannot open", std::io::Error::other("boom"));
        assert_eq!(e.to_string(), "/a/b.npy: cannot open: boom");
        assert_eq!(e.path(), Path::new("/a/b.npy"));
        let e = IoError::CsvParse {
            path: "x.csv".into(),
            line: 7,
            column: "py".into(),
            field: 2,
            value: "abc".into(),
        };
        assert_eq!(
            e.to_string(),
            "x.csv:7: column 'py' (field 2): cannot parse 'abc' as a number"
        );
        let e = IoError::CsvMissingColumn {
            path: "x.csv".into(),
            line: 3,
            column: "pz".into(),
            available: vec!["px".into(), "py".into()],
        };
        assert_eq!(
            e.to_string(),
            "x.csv:3: no column named 'pz' in the header; available columns: px, py"
        );
    }
}
