//! Atomic file replacement: write everything to a temporary file in the destination's directory,
//! flush it to disk, then rename it over the destination.
//!
//! A reader therefore sees either the old file or the complete new one, never a half-written file,
//! and a failed write (error returned by the closure, full disk, ...) leaves the old file untouched
//! and removes the temporary file. Missing parent directories are created.
//!
//! The temporary file is named `.<file name>.stage-<host>-<pid>-<start>-<n>[.<ext>]` and lives next to the
//! destination (a rename is only atomic within one file system); the ones a killed run left for the same
//! destination are removed first ([`super::stale`]).
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

use super::policy::{check_out_folder, check_own_file, output_target, FolderRule, FolderState};
use super::{stale, IoError};

/// Atomically replace (or create) `path` with `bytes`.
pub fn write_atomic(path: impl AsRef<Path>, bytes: &[u8]) -> Result<(), IoError> {
    write_atomic_with(path, |w: &mut dyn Write| w.write_all(bytes))
}

/// Atomically replace (or create) `path` with whatever `write` produces.
///
/// `write` receives a buffered writer on a temporary file; returning an error aborts the whole
/// operation (the destination is not touched, the temporary file is deleted) and the error is
/// reported with the destination path. A destination that is a named pipe, a device or a socket is refused
/// before anything is written; a symbolic link is replaced, never followed ([`super::policy::check_own_file`]:
/// the user's own output paths are checked by the commands, `policy::check_out_file`, which refuses links).
pub fn write_atomic_with<F>(path: impl AsRef<Path>, write: F) -> Result<(), IoError>
where
    F: FnOnce(&mut dyn Write) -> std::io::Result<()>,
{
    let path = path.as_ref();
    if !path.is_dir() {
        check_own_file("the output", path)?;
    }
    path.file_name().ok_or_else(|| {
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

    // Housekeeping only: a temporary that cannot be removed does not stop the write.
    let _ = stale::remove_stale(path);
    let (tmp_path, file) = create_temp(path).map_err(|e| IoError::io(path, "cannot create temporary file", e))?;
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

fn create_temp(dest: &Path) -> std::io::Result<(PathBuf, File)> {
    let mut last_err = None;
    for _ in 0..100 {
        let tmp = stale::temp_path(dest);
        match OpenOptions::new().write(true).create_new(true).open(&tmp) {
            Ok(f) => return Ok((tmp, f)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => last_err = Some(e),
            Err(e) => return Err(e),
        }
    }
    Err(last_err.unwrap_or_else(|| std::io::Error::other("no free temporary file name")))
}

/// Environment variable of the tests only: `DIFFCASSI_TEST_PAUSE_AT=commit` (every file of an output set
/// staged, nothing moved yet) or `=swap` (inside the swap of an output folder: after the exchange, before the
/// old set is removed; in the two-rename fallback, between the renames) makes the process stop itself
/// (SIGSTOP) there, so a test can SIGKILL it at that exact point (tests/output_policy.rs). Not for users.
pub const TEST_PAUSE_ENV: &str = "DIFFCASSI_TEST_PAUSE_AT";

/// Stop the process (SIGSTOP) when [`TEST_PAUSE_ENV`] names `point` (a test hook; see there).
pub fn test_pause(point: &str) {
    if std::env::var(TEST_PAUSE_ENV).is_ok_and(|v| v == point) {
        eprintln!("{TEST_PAUSE_ENV}={point}: stopping for a test");
        // SAFETY: raise() only sends a signal to this process; SIGSTOP cannot be caught.
        unsafe {
            libc::raise(libc::SIGSTOP);
        }
    }
}

/// Exchange two paths atomically (`renameat2(RENAME_EXCHANGE)`, Linux ≥ 3.15 on ext4, xfs, btrfs, tmpfs, …).
/// `Ok(false)`: the file system or kernel does not support it (EINVAL, ENOSYS, ENOTSUP), nothing changed.
fn exchange(a: &Path, b: &Path) -> std::io::Result<bool> {
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::ffi::OsStrExt;
        let c = |p: &Path| std::ffi::CString::new(p.as_os_str().as_bytes()).map_err(|_| std::io::Error::new(std::io::ErrorKind::InvalidInput, "path holds a NUL byte"));
        let (ca, cb) = (c(a)?, c(b)?);
        // SAFETY: two valid NUL-terminated paths relative to the working directory.
        let r = unsafe { libc::renameat2(libc::AT_FDCWD, ca.as_ptr(), libc::AT_FDCWD, cb.as_ptr(), libc::RENAME_EXCHANGE) };
        if r == 0 {
            return Ok(true);
        }
        let e = std::io::Error::last_os_error();
        match e.raw_os_error() {
            Some(libc::EINVAL) | Some(libc::ENOSYS) | Some(libc::ENOTSUP) => Ok(false),
            _ => Err(e),
        }
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = (a, b);
        Ok(false)
    }
}

fn remove_any(p: &Path) -> std::io::Result<()> {
    match fs::symlink_metadata(p) {
        Ok(m) if m.is_dir() => fs::remove_dir_all(p),
        Ok(_) => fs::remove_file(p),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(e),
    }
}

/// Put the complete folder `stage` in place of `dest` (absent, or a previous set, replaced whole) so that
/// `dest` names the old set or the new one at every instant: a rename when `dest` is absent, else
/// `renameat2(RENAME_EXCHANGE)` and the old set (now under the stage's name) removed. Where the file system
/// refuses the exchange, two renames (`dest` → `stage.old`, `stage` → `dest`): between them, for the
/// microseconds of one rename, `dest` is absent (the old set is complete under `stage.old`, the new under
/// `stage`; a rerun removes both once their writer is gone).
pub fn swap_into_place(stage: &Path, dest: &Path) -> Result<(), IoError> {
    // The staged entries must be on disk before a rename makes them visible.
    if let Ok(f) = File::open(stage) {
        let _ = f.sync_all();
    }
    let exists = fs::symlink_metadata(dest).is_ok();
    if !exists {
        fs::rename(stage, dest).map_err(|e| IoError::io(dest, "cannot move the new output set into place", e))?;
    } else if exchange(stage, dest).map_err(|e| IoError::io(dest, "cannot exchange the new output set with the previous one", e))? {
        test_pause("swap");
        remove_any(stage).map_err(|e| IoError::io(stage, "cannot remove the previous output set (the new one is in place)", e))?;
    } else {
        let mut old = stage.as_os_str().to_os_string();
        old.push(".old");
        let old = PathBuf::from(old);
        fs::rename(dest, &old).map_err(|e| IoError::io(dest, "cannot move the previous output set aside", e))?;
        test_pause("swap");
        if let Err(e) = fs::rename(stage, dest) {
            let _ = fs::rename(&old, dest);
            return Err(IoError::io(dest, "cannot move the new output set into place", e));
        }
        remove_any(&old).map_err(|e| IoError::io(&old, "cannot remove the previous output set (the new one is in place)", e))?;
    }
    if let Some(parent) = dest.parent().filter(|p| !p.as_os_str().is_empty()) {
        if let Ok(f) = File::open(parent) {
            let _ = f.sync_all();
        }
    }
    Ok(())
}

/// All-or-nothing output of a command: every file is first written to a staging place and the whole set is
/// moved into place by [`OutputSet::commit`] once everything succeeded. Dropping an uncommitted set removes
/// what was staged, so a command that fails half-way leaves the previous outputs exactly as they were.
///
/// Two forms:
/// * [`OutputSet::files`]: loose files anywhere (`spot --csv a.csv --json b.json --png c.png`, `make-scene`);
///   each is staged beside its destination as `.NAME.stage-HOST-PID-START-N.EXT` (same file system, so the
///   final renames are atomic; the extension is kept for writers that choose the format by it) and renamed at
///   commit.
/// * [`OutputSet::folder`]: a command's output folder (`report --out`, `render --out`, `reconstruct --out`),
///   checked against the output policy ([`super::policy`]) when the set is created, before any work: new,
///   empty, a previous output of the command (it holds the command's marker file), or with `--force` a folder
///   of other files. Files are written into a sibling folder `.NAME.stage-HOST-PID-START-N`; at commit the
///   staging folder replaces the destination whole ([`swap_into_place`]: the old or the new set is under the
///   name at every instant); into a `--force`d folder of other files the outputs are moved one by one, the
///   marker last, and nothing else there is touched.
///
/// Creating a set removes the temporaries that killed runs left for the same destination ([`super::stale`]).
///
/// ```
/// use diffcassi::io::{policy::FolderRule, OutputSet};
/// let dir = tempfile::tempdir().unwrap();
/// let out = dir.path().join("report");
/// let rule = FolderRule { option: "--out", command: "report", marker: "report.json", force: false };
/// let set = OutputSet::folder(&out, &rule, &[]).unwrap();
/// std::fs::write(set.stage_dir().unwrap().join("a.csv"), "x\n").unwrap();
/// std::fs::write(set.stage_dir().unwrap().join("report.json"), "{}").unwrap();
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
    option: String,
    command: String,
    force: bool,
}

impl OutputSet {
    /// A set of loose files; register each with [`OutputSet::stage`].
    pub fn files() -> Self {
        OutputSet { staged: Vec::new(), folder: None, committed: false }
    }

    /// A set replacing the folder `dest`, checked against the output policy and the command's `inputs`
    /// (option, path) first ([`super::policy::check_out_folder`]); write into [`OutputSet::stage_dir`].
    pub fn folder(dest: impl AsRef<Path>, rule: &FolderRule, inputs: &[(&str, &Path)]) -> Result<Self, IoError> {
        // A link is written through: the set replaces its target, the link stays (a dangling one is refused by
        // the policy check, on the path as given).
        check_out_folder(dest.as_ref(), rule, inputs)?;
        let dest = output_target(rule.option, dest.as_ref())?;
        let parent = dest.parent().map(Path::to_path_buf).unwrap_or_default();
        if !parent.as_os_str().is_empty() {
            fs::create_dir_all(&parent).map_err(|e| IoError::io(&parent, "cannot create directory", e))?;
        }
        stale::remove_stale(&dest)?;
        let stage = stale::temp_path(&dest);
        fs::create_dir(&stage).map_err(|e| IoError::io(&stage, "cannot create staging folder", e))?;
        let folder = FolderStage { stage, dest, marker: rule.marker.to_string(), option: rule.option.to_string(), command: rule.command.to_string(), force: rule.force };
        Ok(OutputSet { staged: Vec::new(), folder: Some(folder), committed: false })
    }

    /// The staging folder of a [`OutputSet::folder`] set.
    pub fn stage_dir(&self) -> Option<&Path> {
        self.folder.as_ref().map(|f| f.stage.as_path())
    }

    /// Where to write the file that will end up at `dest` (a loose file of a [`OutputSet::files`] set).
    pub fn stage(&mut self, dest: impl AsRef<Path>) -> PathBuf {
        let dest = dest.as_ref().to_path_buf();
        // Housekeeping: a killed run's staged copies of this destination.
        let _ = stale::remove_stale(&dest);
        let tmp = stale::temp_path(&dest);
        self.staged.push((tmp.clone(), dest));
        tmp
    }

    /// Move everything into place.
    pub fn commit(mut self) -> Result<(), IoError> {
        test_pause("commit");
        // Every destination checked before any is replaced: a named pipe or a device is never renamed over, and
        // a set is moved into place whole or not at all.
        for (tmp, dest) in &self.staged {
            if tmp.exists() {
                check_own_file("the output", dest)?;
            }
        }
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

/// The hidden files listing the entries of a folder output set (one name a line), written with the set: a later
/// run replaces the folder whole only when it holds nothing else, so files a user put beside the outputs
/// (or the files of a `--force`d folder) are never deleted. One list per command, named after its marker
/// (`.diffcassi-set.render.json`), so that a `--force`d write of another command (a reconstruction into a
/// render's folder) does not take over the first command's list, which a later plain run of the first
/// command would then read as its own and delete the other's outputs by (a held-out battery, round 7).
/// Earlier versions wrote one list named `.diffcassi-set`: read as the set of the command whose marker it
/// lists, and replaced by that command's own list when it next commits there.
pub const SET_LIST: &str = ".diffcassi-set";

/// The set list of the command whose marker file is `marker`.
pub fn set_list_name(marker: &str) -> String {
    format!("{SET_LIST}.{marker}")
}

/// Whether `name` is a set list (the legacy one or a command's).
fn is_set_list(name: &str) -> bool {
    name == SET_LIST || name.strip_prefix(SET_LIST).is_some_and(|r| r.starts_with('.'))
}

fn entry_names(dir: &Path) -> Result<Vec<String>, IoError> {
    let mut v = Vec::new();
    for e in fs::read_dir(dir).map_err(|e| IoError::io(dir, "cannot read the folder", e))? {
        v.push(e.map_err(|e| IoError::io(dir, "cannot read the folder", e))?.file_name().to_string_lossy().into_owned());
    }
    v.sort();
    Ok(v)
}

fn commit_folder(f: &FolderStage) -> Result<(), IoError> {
    let list_name = set_list_name(&f.marker);
    let new_names: Vec<String> = entry_names(&f.stage)?.into_iter().filter(|n| !is_set_list(n)).collect();
    write_atomic(f.stage.join(&list_name), new_names.iter().map(|n| format!("{n}\n")).collect::<String>().as_bytes())?;
    // Checked again: the folder may have changed while the command ran.
    let rule = FolderRule { option: &f.option, command: &f.command, marker: &f.marker, force: f.force };
    let state = check_out_folder(&f.dest, &rule, &[])?;
    // What of the destination is an earlier set's (its list; without one, an earlier version's set: all of it).
    let read_list = |name: &str| fs::read_to_string(f.dest.join(name)).ok().map(|t| t.lines().map(str::to_string).collect::<Vec<_>>());
    // The legacy single list is ours when it lists our marker; another command's legacy list leaves us only
    // our marker as certainly ours (the rest is kept, never deleted).
    let mut legacy_is_ours = false;
    let old_list: Option<Vec<String>> = match state {
        FolderState::Previous => read_list(&list_name).or_else(|| {
            read_list(SET_LIST).map(|l| {
                legacy_is_ours = l.contains(&f.marker);
                if legacy_is_ours {
                    l
                } else {
                    vec![f.marker.clone()]
                }
            })
        }),
        _ => None,
    };
    let foreign: Vec<String> = match (state, &old_list) {
        (FolderState::Foreign, _) => entry_names(&f.dest)?,
        (FolderState::Previous, Some(list)) => entry_names(&f.dest)?.into_iter().filter(|n| !is_set_list(n) && !list.contains(n) && !stale::is_temporary(n)).collect(),
        _ => Vec::new(),
    };
    if foreign.is_empty() && state != FolderState::Foreign {
        return swap_into_place(&f.stage, &f.dest);
    }
    // Other files in the folder (--force, or files put beside an earlier set): move the outputs in, the marker
    // and the list last; remove only the earlier set's own entries the new set lacks; a folder of an output's
    // name that is not the earlier set's is never removed (refused before anything moves).
    let ours = |n: &String| old_list.as_ref().is_some_and(|l| l.contains(n));
    for n in &new_names {
        let to = f.dest.join(n);
        if !ours(n) && fs::symlink_metadata(&to).is_ok_and(|m| m.is_dir()) {
            return Err(IoError::Refused { path: to, reason: "a folder of this output's name is in the output folder and is not an earlier output's; nothing was moved (it is not removed): remove or rename it".into() });
        }
    }
    let mut order = new_names.clone();
    order.sort_by_key(|n| (*n == f.marker, n.clone()));
    order.push(list_name.clone());
    for n in &order {
        let to = f.dest.join(n);
        if ours(n) && fs::symlink_metadata(&to).is_ok_and(|m| m.is_dir()) {
            remove_any(&to).map_err(|e| IoError::io(&to, "cannot replace an earlier output", e))?;
        }
        fs::rename(f.stage.join(n), &to).map_err(|e| IoError::io(&to, "cannot move the output into place", e))?;
    }
    for n in old_list.iter().flatten().filter(|n| !new_names.contains(n) && !is_set_list(n)) {
        let p = f.dest.join(n);
        remove_any(&p).map_err(|e| IoError::io(&p, "cannot remove an earlier output the new set does not have", e))?;
    }
    if legacy_is_ours {
        // Our own list replaces the legacy one.
        let _ = fs::remove_file(f.dest.join(SET_LIST));
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
    use crate::io::policy::FolderRule;

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
        let list = set_list_name("render.json");
        let out = tmp.path().join("out");
        fs::create_dir(&out).unwrap();
        fs::write(out.join("render.json"), "old").unwrap();
        fs::write(out.join("cube.exr"), "old cube").unwrap();
        let rule = FolderRule { option: "--out", command: "render", marker: "render.json", force: false };
        // A failed run leaves the old set untouched and no staging folder.
        {
            let set = OutputSet::folder(&out, &rule, &[]).unwrap();
            fs::write(set.stage_dir().unwrap().join("acquisition.exr"), "half").unwrap();
        }
        assert_eq!(entries(&out), vec!["cube.exr", "render.json"]);
        assert_eq!(entries(tmp.path()), vec!["out"]);
        // A successful one replaces the whole set (the old cube.exr is not part of it).
        let set = OutputSet::folder(&out, &rule, &[]).unwrap();
        fs::write(set.stage_dir().unwrap().join("acquisition.exr"), "new").unwrap();
        fs::write(set.stage_dir().unwrap().join("render.json"), "new").unwrap();
        set.commit().unwrap();
        assert_eq!(entries(&out), vec![list.as_str(), "acquisition.exr", "render.json"]);
        assert_eq!(entries(tmp.path()), vec!["out"]);
        // A file the user put beside the set survives the next run; the old set's files the new one lacks go.
        fs::write(out.join("notes.txt"), "keep").unwrap();
        let set = OutputSet::folder(&out, &rule, &[]).unwrap();
        fs::write(set.stage_dir().unwrap().join("render.json"), "newer").unwrap();
        set.commit().unwrap();
        assert_eq!(entries(&out), vec![list.as_str(), "notes.txt", "render.json"]);
        // An unrelated folder is refused, untouched; with --force it keeps its other files.
        let other = tmp.path().join("mine");
        fs::create_dir(&other).unwrap();
        fs::write(other.join("notes.txt"), "keep").unwrap();
        fs::create_dir(other.join("sub")).unwrap();
        let err = OutputSet::folder(&other, &rule, &[]).unwrap_err().to_string();
        assert!(err.contains("--force") && err.contains("render.json"), "{err}");
        assert_eq!(entries(tmp.path()), vec!["mine", "out"]);
        let forced = FolderRule { force: true, ..rule };
        let set = OutputSet::folder(&other, &forced, &[]).unwrap();
        fs::write(set.stage_dir().unwrap().join("render.json"), "new").unwrap();
        set.commit().unwrap();
        assert_eq!(entries(&other), vec![list.as_str(), "notes.txt", "render.json", "sub"]);
        // Rerun without --force (the folder now holds render.json): the user's files still survive.
        let set = OutputSet::folder(&other, &rule, &[]).unwrap();
        fs::write(set.stage_dir().unwrap().join("render.json"), "again").unwrap();
        fs::write(set.stage_dir().unwrap().join("extra.csv"), "x").unwrap();
        set.commit().unwrap();
        assert_eq!(entries(&other), vec![list.as_str(), "extra.csv", "notes.txt", "render.json", "sub"]);
        assert_eq!(fs::read_to_string(other.join("notes.txt")).unwrap(), "keep");
        // A folder of an output's name that is not an earlier output's is never removed.
        let set = OutputSet::folder(&other, &forced, &[]).unwrap();
        fs::write(set.stage_dir().unwrap().join("sub"), "file").unwrap();
        assert!(set.commit().unwrap_err().to_string().contains("sub"));
        assert_eq!(entries(&other), vec![list.as_str(), "extra.csv", "notes.txt", "render.json", "sub"]);
        assert_eq!(entries(tmp.path()), vec!["mine", "out"]);
    }

    #[test]
    fn a_forced_set_of_another_command_keeps_both_lists() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("both");
        let render = FolderRule { option: "--out", command: "render", marker: "render.json", force: false };
        let recon = FolderRule { option: "--out", command: "reconstruct", marker: "reconstruct.json", force: true };
        let write = |rule: &FolderRule, names: &[&str]| {
            let set = OutputSet::folder(&out, rule, &[]).unwrap();
            for n in names {
                fs::write(set.stage_dir().unwrap().join(n), "x").unwrap();
            }
            set.commit().unwrap();
        };
        write(&render, &["render.json", "acquisition.exr", "preview.png"]);
        write(&recon, &["reconstruct.json", "cube.npy"]);
        // A plain render again (its marker is there): it replaces its own set and nothing of the other's.
        write(&render, &["render.json", "acquisition.exr"]);
        let (lr, lc) = (set_list_name("render.json"), set_list_name("reconstruct.json"));
        assert_eq!(entries(&out), vec![lc.as_str(), lr.as_str(), "acquisition.exr", "cube.npy", "reconstruct.json", "render.json"]);
        // A legacy single list written by the other command: only our marker is certainly ours.
        let legacy = tmp.path().join("legacy");
        fs::create_dir(&legacy).unwrap();
        for n in ["render.json", "acquisition.exr", "reconstruct.json", "cube.npy"] {
            fs::write(legacy.join(n), "old").unwrap();
        }
        fs::write(legacy.join(SET_LIST), "reconstruct.json\ncube.npy\n").unwrap();
        let set = OutputSet::folder(&legacy, &render, &[]).unwrap();
        fs::write(set.stage_dir().unwrap().join("render.json"), "new").unwrap();
        set.commit().unwrap();
        assert_eq!(entries(&legacy), vec![SET_LIST, lr.as_str(), "acquisition.exr", "cube.npy", "reconstruct.json", "render.json"]);
        // A legacy list of our own is read as ours, and replaced by our list.
        fs::remove_file(legacy.join(&lr)).unwrap();
        fs::write(legacy.join(SET_LIST), "render.json\nacquisition.exr\n").unwrap();
        let set = OutputSet::folder(&legacy, &render, &[]).unwrap();
        fs::write(set.stage_dir().unwrap().join("render.json"), "newer").unwrap();
        set.commit().unwrap();
        assert_eq!(entries(&legacy), vec![lr.as_str(), "cube.npy", "reconstruct.json", "render.json"]);
    }

    #[test]
    fn swap_exchanges_and_stale_stages_are_removed() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("out");
        let rule = FolderRule { option: "--out", command: "render", marker: "render.json", force: false };
        // A stage of a killed writer (PID 0, this host) and one of a live writer (this process).
        let dead = tmp.path().join(format!(".out.stage-{}-0-1-7", stale::host_name()));
        fs::create_dir(&dead).unwrap();
        let live = stale::temp_path(&out);
        fs::create_dir(&live).unwrap();
        let set = OutputSet::folder(&out, &rule, &[]).unwrap();
        assert!(!dead.exists() && live.exists());
        fs::write(set.stage_dir().unwrap().join("render.json"), "1").unwrap();
        set.commit().unwrap();
        fs::remove_dir(&live).unwrap();
        for v in ["2", "3"] {
            let set = OutputSet::folder(&out, &rule, &[]).unwrap();
            fs::write(set.stage_dir().unwrap().join("render.json"), v).unwrap();
            set.commit().unwrap();
            assert_eq!(fs::read_to_string(out.join("render.json")).unwrap(), v);
            assert_eq!(entries(tmp.path()), vec!["out"]);
        }
        // The exchange itself (ext4, tmpfs, xfs, btrfs support it).
        let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
        fs::write(&a, "A").unwrap();
        fs::write(&b, "B").unwrap();
        if exchange(&a, &b).unwrap() {
            assert_eq!((fs::read_to_string(&a).unwrap(), fs::read_to_string(&b).unwrap()), ("B".into(), "A".into()));
        }
    }
}
