//! The output policy: what a command's `--out` (or any other output path) may be, checked before any work.
//!
//! * An output **folder** (`render`, `report`, `reconstruct`, `study`, `render-dataset`) may be new, an empty
//!   folder, or a previous output of the *same command* — recognised by its marker file (`render.json`,
//!   `report.json`, `reconstruct.json`, `study.json`, `dataset.json`). Anything else — a file, a folder holding
//!   other files — is refused with an error naming it, and nothing is touched, unless `--force`: then the
//!   outputs are moved in *beside* the folder's files ([`FolderState::Foreign`]); a file of the same name as an
//!   output is replaced, a folder of the same name as an output is refused, nothing else there is touched or
//!   deleted.
//! * An output is never an input of the same command, nor (for folders) inside one or containing one:
//!   `reconstruct --out` equal to, inside or containing `--from` is refused, `--force` or not. Paths are
//!   compared after resolving symbolic links and `..` (the part of the path that does not exist yet is
//!   compared as written).
//! * An output **file** may be new or an existing regular file (it is replaced atomically); never a folder, a
//!   named pipe, a device or a socket (`--json /dev/null` as root would have replaced the system's
//!   `/dev/null` with a regular file), never an input file.
//! * An output **folder** named by a symbolic link is written at the link's target, the link kept
//!   ([`output_target`]); an output **file** named by a symbolic link is refused (written in its place it would
//!   replace the link; written through, two outputs of one command could land on one file, and the files
//!   written beside it — `NAME_wavelengths_nm.npy` — would land beside the link). A link to nothing is refused.
//!   Files a command writes inside its own folder replace a link there, never follow it (a planted link would
//!   make a resume write outside the folder, onto an input).
//! * A `.npy` input's wavelength list beside it (`NAME_wavelengths_nm.npy`) is an input too.
//!
//! ```
//! use diffcassi::io::policy::{check_out_folder, FolderRule, FolderState};
//! let dir = tempfile::tempdir().unwrap();
//! let from = dir.path().join("render");
//! std::fs::create_dir(&from).unwrap();
//! std::fs::write(from.join("render.json"), "{}").unwrap();
//! let rule = FolderRule { option: "--out", command: "reconstruct", marker: "reconstruct.json", force: false };
//! let inputs = [("--from", from.as_path())];
//! assert_eq!(check_out_folder(&dir.path().join("rec"), &rule, &inputs).unwrap(), FolderState::New);
//! // The input folder itself, or a folder inside it, is refused.
//! assert!(check_out_folder(&from, &rule, &inputs).unwrap_err().to_string().contains("--from"));
//! assert!(check_out_folder(&from.join("rec"), &rule, &inputs).is_err());
//! // A folder holding someone else's files is refused without --force.
//! let mine = dir.path().join("mine");
//! std::fs::create_dir(&mine).unwrap();
//! std::fs::write(mine.join("notes.txt"), "keep").unwrap();
//! assert!(check_out_folder(&mine, &rule, &[]).unwrap_err().to_string().contains("--force"));
//! let forced = FolderRule { force: true, ..rule };
//! assert_eq!(check_out_folder(&mine, &forced, &[]).unwrap(), FolderState::Foreign);
//! ```
use std::fs;
use std::path::{Component, Path, PathBuf};

use super::IoError;

/// How a command's output folder is recognised and whether `--force` was given.
#[derive(Clone, Copy, Debug)]
pub struct FolderRule<'a> {
    /// The option that named the folder (`--out`).
    pub option: &'a str,
    /// The command (`reconstruct`).
    pub command: &'a str,
    /// The file every output of the command holds (`reconstruct.json`).
    pub marker: &'a str,
    /// `--force`: a non-empty folder that is not an output of the command is accepted (outputs moved in beside
    /// its files).
    pub force: bool,
}

/// What the output folder is, when the policy accepts it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FolderState {
    /// Does not exist yet.
    New,
    /// An empty folder.
    Empty,
    /// A previous output of the same command (holds the marker): replaced whole.
    Previous,
    /// A non-empty folder of other files, accepted by `--force`: the outputs are moved in beside them.
    Foreign,
}

fn refused(path: &Path, reason: String) -> IoError {
    IoError::Refused {
        path: path.to_path_buf(),
        reason,
    }
}

/// `p` made absolute with symbolic links and `..` resolved: the longest existing ancestor is canonicalised,
/// the rest appended as written (lexically normalised).
pub fn resolved(p: &Path) -> PathBuf {
    let abs = if p.is_absolute() {
        p.to_path_buf()
    } else {
        std::env::current_dir().unwrap_or_default().join(p)
    };
    let mut lexical = PathBuf::new();
    for c in abs.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                lexical.pop();
            }
            other => lexical.push(other),
        }
    }
    let mut rest = Vec::new();
    let mut base = lexical.as_path();
    loop {
        if let Ok(c) = fs::canonicalize(base) {
            let mut out = c;
            for r in rest.iter().rev() {
                out.push(r);
            }
            return out;
        }
        match (base.parent(), base.file_name()) {
            (Some(parent), Some(name)) => {
                rest.push(name.to_os_string());
                base = parent;
            }
            _ => return lexical,
        }
    }
}

/// Refuse `out` when it is one of `inputs` (option, path), lies inside one, or (`folder`) contains one.
pub fn check_not_input(
    option: &str,
    out: &Path,
    inputs: &[(&str, &Path)],
    folder: bool,
) -> Result<(), IoError> {
    let o = resolved(out);
    // A cube's wavelength list, read beside it, is as much an input as the cube (`evaluate --json
    // t_wavelengths_nm.npy` replaced the truth's list: a held-out battery).
    let sidecars: Vec<(String, PathBuf)> = inputs
        .iter()
        .filter(|(_, p)| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("npy")))
        .filter_map(|(opt, p)| p.file_stem().map(|s| (format!("{opt} (its wavelength list)"), p.with_file_name(format!("{}_wavelengths_nm.npy", s.to_string_lossy())))))
        .collect();
    let all = inputs.iter().map(|(o, p)| (o.to_string(), p.to_path_buf())).chain(sidecars);
    for (opt, input) in all {
        let i = resolved(&input);
        let relation = if o == i {
            "is"
        } else if o.starts_with(&i) {
            "is inside"
        } else if folder && i.starts_with(&o) {
            "contains"
        } else {
            continue;
        };
        return Err(refused(
            out,
            format!(
                "{option} {relation} the input {opt} {}: writing there would destroy the input; nothing was written, choose another {option}",
                input.display()
            ),
        ));
    }
    Ok(())
}

/// Check an output folder against the policy (see the module docs) before any work. A folder holding only
/// diffcassi temporaries (what a run killed before writing anything else left) counts as empty.
pub fn check_out_folder(
    out: &Path,
    rule: &FolderRule,
    inputs: &[(&str, &Path)],
) -> Result<FolderState, IoError> {
    check_out_folder_owned(out, rule, inputs, &|_| false)
}

/// [`check_out_folder`] for a command that resumes into its folder and may be killed before its marker is
/// written (`render-dataset`: shards start together, `dataset.json` is written after the mask): a folder
/// whose every entry is one the command writes (`owned(file name)`) or a temporary is a previous output too.
pub fn check_out_folder_owned(
    out: &Path,
    rule: &FolderRule,
    inputs: &[(&str, &Path)],
    owned: &dyn Fn(&str) -> bool,
) -> Result<FolderState, IoError> {
    if out.file_name().is_none() {
        return Err(refused(
            out,
            format!(
                "{} must name a folder (a path ending in a name, not `..` or `/`)",
                rule.option
            ),
        ));
    }
    check_not_input(rule.option, out, inputs, true)?;
    let meta = match fs::metadata(out) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            // A dangling symbolic link is someone's: not ours to replace.
            if fs::symlink_metadata(out).is_ok() {
                return Err(refused(
                    out,
                    format!(
                        "{} is a symbolic link to nothing; nothing was written, choose another {}",
                        rule.option, rule.option
                    ),
                ));
            }
            return Ok(FolderState::New);
        }
        Err(e) => return Err(IoError::io(out, "cannot read the output folder", e)),
        Ok(m) => m,
    };
    if !meta.is_dir() {
        return Err(refused(out, format!("{} is a file, not a folder; nothing was written (a file is never replaced by an output folder, --force or not): remove it or choose another {}", rule.option, rule.option)));
    }
    let names: Vec<String> = fs::read_dir(out)
        .map_err(|e| IoError::io(out, "cannot read the output folder", e))?
        .map(|e| e.map(|e| e.file_name().to_string_lossy().into_owned()))
        .collect::<Result<_, _>>()
        .map_err(|e| IoError::io(out, "cannot read the output folder", e))?;
    let kept: Vec<&String> = names
        .iter()
        .filter(|n| !super::stale::is_temporary(n))
        .collect();
    if kept.is_empty() {
        return Ok(FolderState::Empty);
    }
    if out.join(rule.marker).is_file() || kept.iter().all(|n| owned(n)) {
        return Ok(FolderState::Previous);
    }
    if rule.force {
        return Ok(FolderState::Foreign);
    }
    Err(refused(
        out,
        format!(
            "{} is a folder holding files that are not a previous `{}` output (it has no {}); nothing was written. Choose a new or empty folder, or pass --force to write the outputs beside those files (they are kept; a file of an output's name is replaced)",
            rule.option, rule.command, rule.marker
        ),
    ))
}

/// Where an output folder named `out` is written: `out` itself, or — a symbolic link — its final target (the
/// link is kept and the folder it points at is the output). A link whose target cannot be reached (to nothing,
/// a cycle) is refused: not ours to replace, and no target to write.
pub fn output_target(option: &str, out: &Path) -> Result<PathBuf, IoError> {
    match fs::symlink_metadata(out) {
        Ok(m) if m.file_type().is_symlink() => fs::canonicalize(out).map_err(|e| {
            let why = if e.raw_os_error() == Some(libc::ELOOP) { "a cycle of symbolic links".to_string() } else { format!("a symbolic link whose target cannot be reached ({e})") };
            refused(out, format!("{option} is {why}; nothing was written"))
        }),
        _ => Ok(out.to_path_buf()),
    }
}

/// An output file may be absent or a regular file: a symbolic link (named by the user), a folder, a named
/// pipe, a device or a socket is refused, naming it — an output is a regular file renamed into place, which
/// would replace the node itself (`--json /dev/null` as root replaced the system's `/dev/null`).
pub fn check_replaceable_file(option: &str, out: &Path) -> Result<(), IoError> {
    match fs::symlink_metadata(out) {
        Ok(m) if m.file_type().is_symlink() => Err(refused(
            out,
            format!("{option} is a symbolic link (to {}); an output file is written in its place, which would replace the link: give the link's target instead; nothing was written", fs::read_link(out).map(|t| t.display().to_string()).unwrap_or_else(|_| "?".into())),
        )),
        Ok(m) if !m.is_file() => Err(not_a_regular_file(option, out, m.file_type())),
        _ => Ok(()),
    }
}

/// The refusal of an output path that is a folder, a named pipe, a device or a socket.
fn not_a_regular_file(option: &str, out: &Path, t: fs::FileType) -> IoError {
    refused(out, format!("{option} is {}, not a regular file; an output never replaces one: nothing was written", super::input::kind(t)))
}

/// A file a command writes inside its own folder (or any output it names itself) may be absent, a regular file
/// or a symbolic link — a link is *replaced*, never followed: a link planted in a dataset's folder would make a
/// resume write onto its target (an input, another file). A named pipe, a device, a socket or a folder is
/// refused as by [`check_replaceable_file`].
pub fn check_own_file(option: &str, out: &Path) -> Result<(), IoError> {
    match fs::symlink_metadata(out) {
        Ok(m) if m.file_type().is_symlink() || m.is_file() => Ok(()),
        Ok(m) => Err(not_a_regular_file(option, out, m.file_type())),
        Err(_) => Ok(()),
    }
}

/// Check an output file: not a folder, not one of the `inputs`, and its folder can be written: the nearest
/// existing ancestor is a folder (not a file: `ro/g.json` where `ro` is a file) that this process may write
/// into (missing folders below it are created at the commit). A multi-file output set checks every file
/// this way before any work, so a set is never half announced and then refused.
pub fn check_out_file(option: &str, out: &Path, inputs: &[(&str, &Path)]) -> Result<(), IoError> {
    if out.is_dir() {
        return Err(refused(
            out,
            format!("{option} is a folder, not a file; nothing was written"),
        ));
    }
    check_replaceable_file(option, out)?;
    check_not_input(option, out, inputs, false)?;
    check_writable_parent(option, out)
}

/// A file `out` written with companions `<stem><suffix>` (`suffixes`: a cube's wavelength list, a mask of valid
/// entries, a preview) must not share them with another file: refused when a regular file beside it has the
/// same stem and one of `exts` (any case) without being `out` (`x.NPY` beside `x.npy`: x's list was replaced),
/// or when `out` is itself such a file's companion (`--npy q_valid.npy` beside `q.npy`). Held-out batteries,
/// round 6 (`make-scene`, `mapping`).
pub fn check_companions(option: &str, out: &Path, exts: &[&str], suffixes: &[&str]) -> Result<(), IoError> {
    let (Some(stem), Some(name)) = (out.file_stem().map(|s| s.to_string_lossy().into_owned()), out.file_name()) else {
        return Ok(());
    };
    let parent = out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let is_owner = |p: &Path, stem: &str| p.is_file() && p.file_stem().is_some_and(|s| s.to_string_lossy() == stem) && p.extension().and_then(|e| e.to_str()).is_some_and(|e| exts.iter().any(|x| e.eq_ignore_ascii_case(x)));
    let entries: Vec<PathBuf> = fs::read_dir(parent).into_iter().flatten().flatten().map(|e| e.path()).collect();
    if let Some(other) = entries.iter().find(|p| p.file_name() != Some(name) && is_owner(p, &stem)) {
        let names: Vec<String> = suffixes.iter().map(|s| format!("{stem}{s}")).collect();
        return Err(refused(out, format!("{option}: {} beside it has the same stem, so this output's {} would replace its own; choose another name or remove it", other.display(), names.join(" / "))));
    }
    let file = name.to_string_lossy();
    for suffix in suffixes {
        if let Some(owner_stem) = file.strip_suffix(suffix).filter(|s| !s.is_empty()) {
            if let Some(owner) = entries.iter().find(|p| is_owner(p, owner_stem)) {
                return Err(refused(out, format!("{option}: {file} is the companion ({suffix}) of {} beside it, which it would replace; choose another name", owner.display())));
            }
        }
    }
    Ok(())
}

/// The nearest existing ancestor of `out` must be a folder this process may create entries in.
fn check_writable_parent(option: &str, out: &Path) -> Result<(), IoError> {
    use std::os::unix::ffi::OsStrExt;
    let mut dir = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    loop {
        match fs::metadata(&dir) {
            Ok(m) if m.is_dir() => break,
            Ok(_) => {
                return Err(refused(
                    out,
                    format!("{option}: {} is a file, not a folder, so the output cannot be written there; nothing was written", dir.display()),
                ))
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => match dir.parent() {
                Some(p) if !p.as_os_str().is_empty() => dir = p.to_path_buf(),
                _ => {
                    dir = PathBuf::from(".");
                    break;
                }
            },
            Err(e) => return Err(IoError::io(&dir, "cannot reach the output's folder", e)),
        }
    }
    let c = std::ffi::CString::new(dir.as_os_str().as_bytes()).map_err(|_| refused(out, format!("{option}: the path holds a NUL byte")))?;
    // SAFETY: `c` is a valid NUL-terminated path; access(2) only reads it.
    if unsafe { libc::access(c.as_ptr(), libc::W_OK | libc::X_OK) } != 0 {
        let e = std::io::Error::last_os_error();
        return Err(refused(
            out,
            format!("{option}: the folder {} cannot be written ({e}); nothing was written, choose another {option}", dir.display()),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn states_and_refusals() {
        let tmp = tempfile::tempdir().unwrap();
        let rule = FolderRule {
            option: "--out",
            command: "render",
            marker: "render.json",
            force: false,
        };
        let p = |s: &str| tmp.path().join(s);
        assert_eq!(
            check_out_folder(&p("new/deeper"), &rule, &[]).unwrap(),
            FolderState::New
        );
        fs::create_dir(p("empty")).unwrap();
        assert_eq!(
            check_out_folder(&p("empty"), &rule, &[]).unwrap(),
            FolderState::Empty
        );
        fs::write(
            p(&format!(
                "empty/.render.json.stage-{}-0-1-2",
                super::super::stale::host_name()
            )),
            "killed",
        )
        .unwrap();
        assert_eq!(
            check_out_folder(&p("empty"), &rule, &[]).unwrap(),
            FolderState::Empty,
            "only a temporary"
        );
        fs::write(p("empty/mask.png"), "m").unwrap();
        assert!(check_out_folder(&p("empty"), &rule, &[]).is_err());
        assert_eq!(
            check_out_folder_owned(&p("empty"), &rule, &[], &|n| n == "mask.png").unwrap(),
            FolderState::Previous
        );
        fs::create_dir(p("prev")).unwrap();
        fs::write(p("prev/render.json"), "{}").unwrap();
        assert_eq!(
            check_out_folder(&p("prev"), &rule, &[]).unwrap(),
            FolderState::Previous
        );
        fs::write(p("file"), "x").unwrap();
        let e = check_out_folder(
            &p("file"),
            &FolderRule {
                force: true,
                ..rule
            },
            &[],
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("is a file") && e.contains("file"), "{e}");
        // Overlaps, through `..` and a symbolic link.
        let e = check_out_folder(
            &p("prev/../prev"),
            &rule,
            &[("--scene", &p("prev/scene.npy"))],
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("contains the input --scene"), "{e}");
        std::os::unix::fs::symlink(p("prev"), p("link")).unwrap();
        let e = check_out_folder(&p("link/x"), &rule, &[("--from", &p("prev"))])
            .unwrap_err()
            .to_string();
        assert!(e.contains("is inside the input --from"), "{e}");
        std::os::unix::fs::symlink(p("nowhere"), p("dangling")).unwrap();
        assert!(check_out_folder(&p("dangling"), &rule, &[]).is_err());
        assert!(check_out_folder(Path::new("/"), &rule, &[]).is_err());
        assert!(check_out_file("--json", &p("prev"), &[]).is_err());
        assert!(check_out_file(
            "--json",
            &p("prev/x.json"),
            &[("--truth", &p("prev/x.json"))]
        )
        .is_err());
        check_out_file(
            "--json",
            &p("prev/y.json"),
            &[("--truth", &p("prev/x.json"))],
        )
        .unwrap();
    }
}
