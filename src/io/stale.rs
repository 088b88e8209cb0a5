//! Temporary names that carry their writer, and the removal of the stale ones a killed run left.
//!
//! Every temporary file or folder diffcassi writes beside an output `NAME` (the atomic write of a file, the
//! staging folder of an output set, a loose staged file) is called
//!
//! ```text
//! .NAME.stage-HOST-PID-START-N[.EXT]
//! ```
//!
//! `HOST` is the short host name, `PID` the writer's process id, `START` its start time (clock ticks since
//! boot, field 22 of `/proc/PID/stat`), `N` a per-process counter, `.EXT` the destination's extension (kept
//! for writers that choose the format by it). A process killed by SIGKILL or a power loss cannot remove its
//! temporaries, so a rerun writing the same output removes them ([`remove_stale`]) — only those of `NAME`,
//! and only those whose writer is gone:
//!
//! * same host, and no process `PID` is running, or the one running started at another time than `START`
//!   (the PID was reused by an unrelated process): gone, removed;
//! * same host and the process `PID` with start time `START` runs: a live concurrent writer, kept;
//! * another host (a shared file system, a Slurm cluster): kept — diffcassi cannot see that host's
//!   processes. (`render-dataset` is the exception: the shard owning a scene removes that scene's
//!   temporaries from any host, [`crate::render::dataset`].)
//!
//! The names of earlier diffcassi versions, which carried a PID only (`.NAME.stage-PID-N`, `.NAME.tmp-PID`,
//! `.NAME.old-PID`, `.NAME.PID.N.tmp`), are removed when no process `PID` runs on this host (a running
//! one may be a reused PID: kept, the safe side).
//!
//! ```
//! use diffcassi::io::stale::{remove_stale, temp_path};
//! let dir = tempfile::tempdir().unwrap();
//! let dest = dir.path().join("cube.npy");
//! let tmp = temp_path(&dest);
//! assert!(tmp.file_name().unwrap().to_string_lossy().starts_with(".cube.npy.stage-"));
//! std::fs::write(&tmp, b"half").unwrap();
//! // This process is alive: its temporary is not stale.
//! assert_eq!(remove_stale(&dest).unwrap(), 0);
//! // A killed writer's (PID 0 never names a user process; start time 1).
//! let host = diffcassi::io::stale::host_name();
//! std::fs::write(dir.path().join(format!(".cube.npy.stage-{host}-0-1-0.npy")), b"x").unwrap();
//! assert_eq!(remove_stale(&dest).unwrap(), 1);
//! assert!(tmp.exists());
//! ```
use std::fs;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::OnceLock;

use super::IoError;

/// The short host name (before any dot), as temporary names record it: `host` when it cannot be read.
pub fn host_name() -> &'static str {
    static HOST: OnceLock<String> = OnceLock::new();
    HOST.get_or_init(|| {
        let name = fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default();
        let short = name.trim().split('.').next().unwrap_or("").to_string();
        if short.is_empty() || short.contains(['/', '\\']) || short.starts_with('-') {
            "host".into()
        } else {
            short
        }
    })
}

/// Start time of process `pid` (clock ticks since boot, field 22 of `/proc/PID/stat`); `None` when it cannot
/// be read (no such process, or no `/proc`).
fn start_time(pid: u32) -> std::io::Result<Option<u64>> {
    Ok(proc_stat(pid)?.1)
}

/// `/proc/PID/stat`'s state letter (`R`, `S`, `Z`, …) and start time (clock ticks after boot).
fn proc_stat(pid: u32) -> std::io::Result<(Option<char>, Option<u64>)> {
    let stat = fs::read_to_string(format!("/proc/{pid}/stat"))?;
    // The command name (field 2) is in parentheses and may hold spaces: count fields after the last ')'.
    let after = stat.rsplit_once(')').map(|(_, r)| r).unwrap_or("");
    let mut fields = after.split_whitespace();
    let state = fields.next().and_then(|s| s.chars().next());
    // Start time is field 22 of the line, the 20th after the state.
    Ok((state, fields.nth(18).and_then(|s| s.parse().ok())))
}

/// This process's identity in temporary names: `HOST-PID-START`.
pub fn writer_tag() -> &'static str {
    static TAG: OnceLock<String> = OnceLock::new();
    TAG.get_or_init(|| {
        let pid = std::process::id();
        let start = start_time(pid).ok().flatten().unwrap_or(0);
        format!("{}-{pid}-{start}", host_name())
    })
}

/// A fresh number for a temporary name (one counter for the whole process, so two temporaries of one
/// destination never share a name).
pub fn next_counter() -> u64 {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    COUNTER.fetch_add(1, Ordering::Relaxed)
}

/// A new temporary path beside `dest`: `.NAME.stage-HOST-PID-START-N[.EXT]` (a bare file name stays
/// relative to the working directory). Nothing is created.
pub fn temp_path(dest: &Path) -> PathBuf {
    let name = dest
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    let ext = dest
        .extension()
        .map(|e| format!(".{}", e.to_string_lossy()))
        .unwrap_or_default();
    let dir = dest.parent().map(Path::to_path_buf).unwrap_or_default();
    dir.join(format!(
        ".{name}.stage-{}-{}{ext}",
        writer_tag(),
        next_counter()
    ))
}

/// Who wrote a temporary: host (`None`: not recorded, an earlier version's name), PID, start time.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Writer {
    pub host: Option<String>,
    pub pid: u32,
    pub start: Option<u64>,
}

impl Writer {
    /// Whether that process is certainly gone. Only a writer of this host can be judged; an unreadable
    /// `/proc` entry other than "no such process" counts as alive (the safe side).
    pub fn is_gone(&self) -> bool {
        if self.host.as_deref().is_some_and(|h| h != host_name()) {
            return false;
        }
        if !Path::new("/proc/self/stat").exists() {
            return !pid_exists(self.pid);
        }
        match proc_stat(self.pid) {
            Err(e) => e.kind() == std::io::ErrorKind::NotFound,
            // A zombie (killed, not yet reaped by its parent, e.g. under `timeout` or a Slurm step) writes
            // nothing more: its temporaries are stale (a held-out battery, round 7).
            Ok((Some('Z' | 'X'), _)) => true,
            Ok((_, now)) => match self.start {
                // Another process now holds the PID: ours is gone.
                Some(s) => now.is_some_and(|t| t != s),
                None => false,
            },
        }
    }
}

/// `kill(pid, 0)`: the process exists (EPERM: it exists but is another user's).
fn pid_exists(pid: u32) -> bool {
    let Ok(p) = libc::pid_t::try_from(pid) else {
        return false;
    };
    if p <= 0 {
        return false;
    }
    // SAFETY: signal 0 only checks for existence and permission; it sends nothing.
    let r = unsafe { libc::kill(p, 0) };
    r == 0 || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM)
}

/// `HOST-PID-START` (the host may hold '-') or an earlier version's bare `PID`.
pub fn parse_tag(tag: &str) -> Option<Writer> {
    if let Ok(pid) = tag.parse::<u32>() {
        return Some(Writer {
            host: None,
            pid,
            start: None,
        });
    }
    let mut it = tag.rsplitn(3, '-');
    let start = it.next()?.parse::<u64>().ok()?;
    let pid = it.next()?.parse::<u32>().ok()?;
    let host = it.next().filter(|h| !h.is_empty())?;
    Some(Writer {
        host: Some(host.to_string()),
        pid,
        start: Some(start),
    })
}

/// If `entry` (a file name in the destination's folder) is a temporary of destination `name`, its writer.
/// A temporary of a temporary (an atomic write of a staged file, `..NAME.stage-…-1.EXT.stage-…-2.EXT`) is one
/// of `NAME` too.
pub fn temporary_of(entry: &str, name: &str) -> Option<Writer> {
    if let Some(w) = direct_temporary_of(entry, name) {
        return Some(w);
    }
    let k = entry
        .rfind(".stage-")
        .filter(|&k| k > 1 && entry.starts_with('.'))?;
    let inner = &entry[1..k];
    let w = direct_temporary_of(entry, inner)?;
    temporary_of(inner, name).map(|_| w)
}

/// Whether `entry` is a diffcassi temporary of any destination (`.NAME.stage-HOST-PID-START-N…`).
pub fn is_temporary(entry: &str) -> bool {
    entry
        .rfind(".stage-")
        .filter(|&k| k > 1 && entry.starts_with('.'))
        .is_some_and(|k| direct_temporary_of(entry, &entry[1..k]).is_some())
}

fn direct_temporary_of(entry: &str, name: &str) -> Option<Writer> {
    let rest = entry.strip_prefix('.')?.strip_prefix(name)?;
    if let Some(r) = rest.strip_prefix(".stage-") {
        // HOST-PID-START-N, then an optional .EXT and an optional .old (the aside name of a swap).
        let r = r.strip_suffix(".old").unwrap_or(r);
        let r = match Path::new(name).extension() {
            Some(e) => r
                .strip_suffix(&format!(".{}", e.to_string_lossy()))
                .unwrap_or(r),
            None => r,
        };
        let (tag, n) = r.rsplit_once('-')?;
        n.parse::<u64>().ok()?;
        return parse_tag(tag);
    }
    // Earlier versions: `.NAME.tmp-PID` / `.NAME.old-PID` (reconstruct), `.NAME.PID.N.tmp` (atomic writes).
    for p in [".tmp-", ".old-"] {
        if let Some(pid) = rest.strip_prefix(p).and_then(|s| s.parse::<u32>().ok()) {
            return Some(Writer {
                host: None,
                pid,
                start: None,
            });
        }
    }
    let mid = rest.strip_prefix('.')?.strip_suffix(".tmp")?;
    let (pid, n) = mid.split_once('.')?;
    n.parse::<u64>().ok()?;
    Some(Writer {
        host: None,
        pid: pid.parse().ok()?,
        start: None,
    })
}

/// Remove the temporaries of destination `dest` (files or folders beside it, named as above) whose writer
/// is gone; returns how many were removed. Nothing else is touched.
pub fn remove_stale(dest: &Path) -> Result<usize, IoError> {
    let Some(name) = dest.file_name().map(|n| n.to_string_lossy().into_owned()) else {
        return Ok(0);
    };
    let dir = match dest.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let Ok(rd) = fs::read_dir(&dir) else {
        return Ok(0);
    };
    let mut n = 0;
    for e in rd.flatten() {
        let entry = e.file_name().to_string_lossy().into_owned();
        if temporary_of(&entry, &name).is_some_and(|w| w.is_gone()) {
            let p = e.path();
            let r = match fs::symlink_metadata(&p) {
                Ok(m) if m.is_dir() => fs::remove_dir_all(&p),
                Ok(_) => fs::remove_file(&p),
                Err(_) => continue,
            };
            match r {
                Ok(()) => n += 1,
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(e) => return Err(IoError::io(&p, "cannot remove a killed run's temporary", e)),
            }
        }
    }
    Ok(n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_back() {
        let dest = Path::new("dir/cube.npy");
        let t = temp_path(dest);
        let entry = t.file_name().unwrap().to_string_lossy().into_owned();
        let w = temporary_of(&entry, "cube.npy").unwrap();
        assert_eq!(w.pid, std::process::id());
        assert_eq!(w.host.as_deref(), Some(host_name()));
        assert!(!w.is_gone(), "this process is alive");
        assert!(
            temporary_of(&entry, "cube.np").is_none() && temporary_of(&entry, "cube").is_none()
        );
        assert!(temporary_of(&format!("{entry}.old"), "cube.npy").is_some());
        let nested = temp_path(&Path::new("dir").join(&entry))
            .file_name()
            .unwrap()
            .to_string_lossy()
            .into_owned();
        assert_eq!(
            temporary_of(&nested, "cube.npy").map(|w| w.pid),
            Some(std::process::id())
        );
        assert!(temporary_of(&nested, "cube").is_none());
        assert!(
            is_temporary(&entry) && is_temporary(&nested) && is_temporary(".out.stage-h-1-2-3")
        );
        assert!(
            !is_temporary("out.stage-h-1-2-3")
                && !is_temporary(".out.stage-x")
                && !is_temporary(".stage-h-1-2-3")
        );
        // Host names with dashes; earlier versions' names.
        assert_eq!(
            parse_tag("node-7-123-456"),
            Some(Writer {
                host: Some("node-7".into()),
                pid: 123,
                start: Some(456)
            })
        );
        assert_eq!(
            temporary_of(".out.stage-4242-0", "out").map(|w| w.pid),
            Some(4242)
        );
        assert_eq!(temporary_of(".rec.tmp-77", "rec").map(|w| w.pid), Some(77));
        assert_eq!(
            temporary_of(".a.csv.77.3.tmp", "a.csv").map(|w| w.pid),
            Some(77)
        );
        for not in [
            ".out.stage-x-0",
            "out.stage-1-2-3-4",
            ".out.stage-",
            ".outx.stage-h-1-2-3",
            ".out.tmp-",
            ".out.partial-h-1",
        ] {
            assert!(temporary_of(not, "out").is_none(), "{not}");
        }
    }

    #[test]
    fn a_zombie_writer_is_gone() {
        if !Path::new("/proc/self/stat").exists() {
            return;
        }
        // A child that exited and is not reaped yet: a zombie, as a `reconstruct` killed under `timeout`.
        let mut child = std::process::Command::new("true").spawn().expect("spawn true");
        let pid = child.id();
        let start = start_time(pid).ok().flatten();
        let mut zombie = false;
        for _ in 0..200 {
            if proc_stat(pid).is_ok_and(|(s, _)| s == Some('Z')) {
                zombie = true;
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        assert!(zombie, "the child never became a zombie");
        assert!(Writer { host: Some(host_name().into()), pid, start }.is_gone(), "a zombie writes nothing more");
        child.wait().unwrap();
    }

    #[test]
    fn liveness() {
        let me = Writer {
            host: Some(host_name().into()),
            pid: std::process::id(),
            start: start_time(std::process::id()).unwrap(),
        };
        assert!(!me.is_gone());
        // Our PID with another start time: a reused PID, so the recorded writer is gone.
        assert!(Writer {
            start: me.start.map(|s| s + 1),
            ..me.clone()
        }
        .is_gone());
        // Another host's writer is never judged.
        assert!(!Writer {
            host: Some("elsewhere-node".into()),
            pid: 0,
            start: Some(1)
        }
        .is_gone());
        // PID 0 / a huge PID never name a live user process here.
        assert!(Writer {
            host: None,
            pid: 0,
            start: None
        }
        .is_gone());
        assert!(Writer {
            host: None,
            pid: 4_000_000_000,
            start: None
        }
        .is_gone());
    }

    #[test]
    fn removes_only_gone_writers_of_that_destination() {
        let tmp = tempfile::tempdir().unwrap();
        let dest = tmp.path().join("out");
        let h = host_name();
        let dead = format!(".out.stage-{h}-0-1-3");
        let live = temp_path(&dest)
            .file_name()
            .unwrap()
            .to_string_lossy()
            .into_owned();
        let other_host = ".out.stage-elsewhere-0-1-3".to_string();
        let other_dest = format!(".outer.stage-{h}-0-1-3");
        for d in [&dead, &live, &other_host, &other_dest] {
            fs::create_dir(tmp.path().join(d)).unwrap();
            fs::write(tmp.path().join(d).join("f"), b"x").unwrap();
        }
        fs::write(tmp.path().join(".out.0.0.tmp"), b"x").unwrap(); // an earlier version's, PID 0
        fs::write(tmp.path().join("notes.txt"), b"x").unwrap();
        assert_eq!(remove_stale(&dest).unwrap(), 2);
        let mut left: Vec<String> = fs::read_dir(tmp.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        left.sort();
        let mut want = vec![live, other_host, other_dest, "notes.txt".to_string()];
        want.sort();
        assert_eq!(left, want);
    }
}
