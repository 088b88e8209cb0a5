//! Atomic file replacement: write everything to a temporary file in the destination's directory,
//! flush it to disk, then rename it over the destination.
//!
//! A reader therefore sees either the old file or the complete new one, never a half-written file,
//! and a failed write (error returned by the closure, full disk, ...) leaves the old file untouched
//! and removes the temporary file. Missing parent directories are created.
//!
//! The temporary file is named `.<file name>.<pid>.<n>.tmp` and lives next to the destination
//! (a rename is only atomic within one file system).
//!
//! # Example
//!
//! ```
//! use std::io::Write;
//! use diffcassi::io::{write_atomic, write_atomic_with};
//!
//! # fn main() -> Result<(), diffcassi::io::IoError> {
//! let dir = std::env::temp_dir().join(format!("diffcassi_atomic_doc_{}", std::process::id()));
//! let path = dir.join("nested/out.txt");
//! write_atomic(&path, b"hello\n")?;
//! write_atomic_with(&path, |w: &mut dyn Write| {
//!     for i in 0..3 {
//!         writeln!(w, "line {i}")?;
//!     }
//!     Ok(())
//! })?;
//! assert_eq!(std::fs::read_to_string(&path).unwrap(), "line 0\nline 1\nline 2\n");
//! # std::fs::remove_dir_all(&dir).ok();
//! # Ok(())
//! # }
//! ```

use std::fs::{self, File, OpenOptions};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use super::IoError;

/// Atomically replace (or create) `path` with `bytes`.
pub fn write_atomic(path: impl AsRef<Path>, bytes: &[u8]) -> Result<(), IoError> {
    write_atomic_with(path, |w: &mut dyn Write| w.write_all(bytes))
}

/// Atomically replace (or create) `path` with whatever `write` produces.
///
/// `write` receives a buffered writer on a temporary file; returning an error aborts the whole
/// operation (the destination is not touched, the temporary file is deleted) and the error is
/// reported with the destination path.
pub fn write_atomic_with<F>(path: impl AsRef<Path>, write: F) -> Result<(), IoError>
where
    F: FnOnce(&mut dyn Write) -> std::io::Result<()>,
{
    let path = path.as_ref();
    let file_name = path.file_name().ok_or_else(|| {
        IoError::io(
            path,
            "cannot write",
            std::io::Error::new(std::io::ErrorKind::InvalidInput, "path has no file name"),
        )
    })?;
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    fs::create_dir_all(&dir).map_err(|e| IoError::io(&dir, "cannot create directory", e))?;

    let (tmp_path, file) = create_temp(&dir, &file_name.to_string_lossy())
        .map_err(|e| IoError::io(path, "cannot create temporary file", e))?;
    // From here on, remove the temporary file on any failure.
    let result = (|| -> Result<(), IoError> {
        let mut w = BufWriter::with_capacity(1 << 16, file);
        write(&mut w).map_err(|e| IoError::io(path, "cannot write", e))?;
        let file = w
            .into_inner()
            .map_err(|e| IoError::io(path, "cannot write", e.into_error()))?;
        file.sync_all()
            .map_err(|e| IoError::io(path, "cannot flush to disk", e))?;
        drop(file);
        fs::rename(&tmp_path, path).map_err(|e| IoError::io(path, "cannot replace file", e))
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp_path);
    }
    result
}

fn create_temp(dir: &Path, file_name: &str) -> std::io::Result<(PathBuf, File)> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let pid = std::process::id();
    let mut last_err = None;
    for _ in 0..100 {
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let tmp = dir.join(format!(".{file_name}.{pid}.{n}.tmp"));
        match OpenOptions::new().write(true).create_new(true).open(&tmp) {
            Ok(f) => return Ok((tmp, f)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => last_err = Some(e),
            Err(e) => return Err(e),
        }
    }
    Err(last_err.unwrap_or_else(|| std::io::Error::other("no free temporary file name")))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entries(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn creates_parents_and_replaces() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("a/b/c.bin");
        write_atomic(&p, b"first").unwrap();
        assert_eq!(fs::read(&p).unwrap(), b"first");
        write_atomic(&p, b"second, longer").unwrap();
        assert_eq!(fs::read(&p).unwrap(), b"second, longer");
        write_atomic(&p, b"").unwrap();
        assert_eq!(fs::read(&p).unwrap(), b"");
        assert_eq!(entries(&tmp.path().join("a/b")), vec!["c.bin"]);
    }

    #[test]
    fn closure_error_keeps_old_file_and_cleans_up() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("keep.txt");
        write_atomic(&p, b"old").unwrap();
        let err = write_atomic_with(&p, |w: &mut dyn Write| {
            w.write_all(b"partial")?;
            Err(std::io::Error::other("simulated failure"))
        })
        .unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.contains("keep.txt") && msg.contains("simulated failure"),
            "{msg}"
        );
        assert_eq!(fs::read(&p).unwrap(), b"old");
        assert_eq!(entries(tmp.path()), vec!["keep.txt"]);
    }

    #[test]
    fn path_without_file_name_is_an_error() {
        assert!(write_atomic(Path::new(""), b"x").is_err());
        assert!(write_atomic(Path::new("/"), b"x").is_err());
    }

    #[test]
    fn destination_is_a_directory() {
        let tmp = tempfile::tempdir().unwrap();
        let d = tmp.path().join("dir");
        fs::create_dir(&d).unwrap();
        fs::write(d.join("inside"), b"1").unwrap();
        let err = write_atomic(&d, b"x").unwrap_err();
        assert!(err.to_string().contains("dir"), "{err}");
        assert_eq!(entries(tmp.path()), vec!["dir"]);
    }

    #[test]
    fn concurrent_writers_never_expose_partial_files() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("shared.txt");
        std::thread::scope(|s| {
            for t in 0..4u8 {
                let p = &p;
                s.spawn(move || {
                    for _ in 0..20 {
                        write_atomic(p, &vec![b'a' + t; 10_000]).unwrap();
                        let got = fs::read(p).unwrap();
                        assert_eq!(got.len(), 10_000);
                        assert!(got.iter().all(|&b| b == got[0]));
                    }
                });
            }
        });
        assert_eq!(entries(tmp.path()), vec!["shared.txt"]);
    }
}
