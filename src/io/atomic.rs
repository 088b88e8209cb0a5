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

/// All-or-nothing output of a command: every file is first written to a staging place and the whole set is
/// moved into place by [`OutputSet::commit`] once everything succeeded. Dropping an uncommitted set removes
/// what was staged, so a command that fails half-way leaves the previous outputs exactly as they were.
///
/// Two forms:
/// * [`OutputSet::files`]: loose files anywhere (`spot --csv a.csv --json b.json --png c.png`); each is staged
///   beside its destination as `.diffcassi-stage-<pid>-<n>-<name>` (same file system, so the final renames are
///   atomic; the extension is kept for writers that choose the format by it) and renamed at commit.
/// * [`OutputSet::folder`]: a command's output folder (`report --out`, `render --out`): files are written into a
///   sibling folder `.<name>.stage-<pid>-<n>`; at commit the staging folder replaces the destination with two
///   renames when the destination is new, empty, or a previous output set of the command (it holds the
///   command's `marker` file): a reader sees the old set or the new one, never a mix. A destination holding
///   anything else (an unrelated folder such as `.`) is not swapped: the files are moved in one by one,
///   `marker` last, and nothing else there is touched.
///
/// ```
/// use diffcassi::io::OutputSet;
/// let dir = tempfile::tempdir().unwrap();
/// let out = dir.path().join("report");
/// let set = OutputSet::folder(&out, "report.json").unwrap();
/// std::fs::write(set.stage_dir().unwrap().join("a.csv"), "x\n").unwrap();
/// assert!(!out.exists()); // nothing visible before the commit
/// set.commit().unwrap();
/// assert!(out.join("a.csv").is_file());
/// ```
#[derive(Debug)]
pub struct OutputSet {
    /// (staged path, destination) of loose files.
    staged: Vec<(PathBuf, PathBuf)>,
    folder: Option<FolderStage>,
    committed: bool,
}

#[derive(Debug)]
struct FolderStage {
    stage: PathBuf,
    dest: PathBuf,
    marker: String,
}

fn stage_counter() -> u64 {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    COUNTER.fetch_add(1, Ordering::Relaxed)
}

impl OutputSet {
    /// A set of loose files; register each with [`OutputSet::stage`].
    pub fn files() -> Self {
        OutputSet { staged: Vec::new(), folder: None, committed: false }
    }

    /// A set replacing the folder `dest`; write into [`OutputSet::stage_dir`]. `marker` names the file every
    /// output set of this command contains (e.g. `render.json`); it is moved last.
    pub fn folder(dest: impl AsRef<Path>, marker: &str) -> Result<Self, IoError> {
        let dest = dest.as_ref().to_path_buf();
        let name = dest.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "out".into());
        let parent = dest.parent().map(Path::to_path_buf).unwrap_or_default();
        if dest.exists() && !dest.is_dir() {
            return Err(IoError::io(&dest, "cannot write an output folder", std::io::Error::new(std::io::ErrorKind::AlreadyExists, "a file of that name exists")));
        }
        if !parent.as_os_str().is_empty() {
            fs::create_dir_all(&parent).map_err(|e| IoError::io(&parent, "cannot create directory", e))?;
        }
        let stage = parent.join(format!(".{name}.stage-{}-{}", std::process::id(), stage_counter()));
        fs::create_dir(&stage).map_err(|e| IoError::io(&stage, "cannot create staging folder", e))?;
        Ok(OutputSet { staged: Vec::new(), folder: Some(FolderStage { stage, dest, marker: marker.to_string() }), committed: false })
    }

    /// The staging folder of a [`OutputSet::folder`] set.
    pub fn stage_dir(&self) -> Option<&Path> {
        self.folder.as_ref().map(|f| f.stage.as_path())
    }

    /// Where to write the file that will end up at `dest` (a loose file of a [`OutputSet::files`] set).
    pub fn stage(&mut self, dest: impl AsRef<Path>) -> PathBuf {
        let dest = dest.as_ref().to_path_buf();
        let name = dest.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        // Beside the destination (a bare file name stays relative to the working directory).
        let dir = dest.parent().map(Path::to_path_buf).unwrap_or_default();
        let tmp = dir.join(format!(".diffcassi-stage-{}-{}-{name}", std::process::id(), stage_counter()));
        self.staged.push((tmp.clone(), dest));
        tmp
    }

    /// Move everything into place.
    pub fn commit(mut self) -> Result<(), IoError> {
        for (tmp, dest) in &self.staged {
            if tmp.exists() {
                fs::rename(tmp, dest).map_err(|e| IoError::io(dest, "cannot move the output into place", e))?;
            }
        }
        if let Some(f) = &self.folder {
            commit_folder(f)?;
        }
        self.committed = true;
        Ok(())
    }
}

fn commit_folder(f: &FolderStage) -> Result<(), IoError> {
    let swappable = match fs::read_dir(&f.dest) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => true,
        Err(e) => return Err(IoError::io(&f.dest, "cannot read the output folder", e)),
        Ok(mut entries) => entries.next().is_none() || f.dest.join(&f.marker).is_file(),
    };
    if swappable {
        let old = f.stage.with_file_name(format!("{}.old", f.stage.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()));
        let had_old = f.dest.exists();
        if had_old {
            fs::rename(&f.dest, &old).map_err(|e| IoError::io(&f.dest, "cannot move the previous output set aside", e))?;
        }
        if let Err(e) = fs::rename(&f.stage, &f.dest) {
            if had_old {
                let _ = fs::rename(&old, &f.dest);
            }
            return Err(IoError::io(&f.dest, "cannot move the new output set into place", e));
        }
        if had_old {
            let _ = fs::remove_dir_all(&old);
        }
        return Ok(());
    }
    // An unrelated, non-empty folder: move the files in, the marker last.
    let mut names: Vec<std::ffi::OsString> = fs::read_dir(&f.stage).map_err(|e| IoError::io(&f.stage, "cannot read the staging folder", e))?.filter_map(|e| e.ok().map(|e| e.file_name())).collect();
    names.sort_by_key(|n| (n.to_string_lossy() == f.marker, n.clone()));
    for n in names {
        let to = f.dest.join(&n);
        if to.is_dir() {
            let _ = fs::remove_dir_all(&to);
        }
        fs::rename(f.stage.join(&n), &to).map_err(|e| IoError::io(&to, "cannot move the output into place", e))?;
    }
    let _ = fs::remove_dir_all(&f.stage);
    Ok(())
}

impl Drop for OutputSet {
    fn drop(&mut self) {
        if self.committed {
            return;
        }
        for (tmp, _) in &self.staged {
            let _ = fs::remove_file(tmp);
        }
        if let Some(f) = &self.folder {
            let _ = fs::remove_dir_all(&f.stage);
        }
    }
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

    #[test]
    fn output_set_files_all_or_nothing() {
        let tmp = tempfile::tempdir().unwrap();
        let (a, b) = (tmp.path().join("a.csv"), tmp.path().join("b.json"));
        fs::write(&a, "old a").unwrap();
        fs::write(&b, "old b").unwrap();
        {
            let mut set = OutputSet::files();
            write_atomic(set.stage(&a), b"new a").unwrap();
            let _ = set.stage(&b); // the command fails before writing b
        }
        assert_eq!(fs::read(&a).unwrap(), b"old a");
        assert_eq!(entries(tmp.path()), vec!["a.csv", "b.json"]);
        let mut set = OutputSet::files();
        write_atomic(set.stage(&a), b"new a").unwrap();
        write_atomic(set.stage(&b), b"new b").unwrap();
        assert_eq!(fs::read(&b).unwrap(), b"old b");
        set.commit().unwrap();
        assert_eq!((fs::read(&a).unwrap(), fs::read(&b).unwrap()), (b"new a".to_vec(), b"new b".to_vec()));
        assert_eq!(entries(tmp.path()), vec!["a.csv", "b.json"]);
    }

    #[test]
    fn output_set_folder_replaces_a_previous_set_whole() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("out");
        fs::create_dir(&out).unwrap();
        fs::write(out.join("render.json"), "old").unwrap();
        fs::write(out.join("cube.exr"), "old cube").unwrap();
        // A failed run leaves the old set untouched and no staging folder.
        {
            let set = OutputSet::folder(&out, "render.json").unwrap();
            fs::write(set.stage_dir().unwrap().join("acquisition.exr"), "half").unwrap();
        }
        assert_eq!(entries(&out), vec!["cube.exr", "render.json"]);
        assert_eq!(entries(tmp.path()), vec!["out"]);
        // A successful one replaces the whole set (the old cube.exr is not part of it).
        let set = OutputSet::folder(&out, "render.json").unwrap();
        fs::write(set.stage_dir().unwrap().join("acquisition.exr"), "new").unwrap();
        fs::write(set.stage_dir().unwrap().join("render.json"), "new").unwrap();
        set.commit().unwrap();
        assert_eq!(entries(&out), vec!["acquisition.exr", "render.json"]);
        assert_eq!(entries(tmp.path()), vec!["out"]);
        // An unrelated folder keeps its other files.
        let other = tmp.path().join("mine");
        fs::create_dir(&other).unwrap();
        fs::write(other.join("notes.txt"), "keep").unwrap();
        let set = OutputSet::folder(&other, "render.json").unwrap();
        fs::write(set.stage_dir().unwrap().join("render.json"), "new").unwrap();
        set.commit().unwrap();
        assert_eq!(entries(&other), vec!["notes.txt", "render.json"]);
        assert_eq!(entries(tmp.path()), vec!["mine", "out"]);
    }
}
