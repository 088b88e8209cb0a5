//! The calibration cache of `--tolerance-um`: one small JSON file per (kind, key), where the key is a
//! 64-bit FNV-1a hash of the crate version, the calibration kind, the resolved system spec (JSON) and the
//! wavelengths (and any kind-specific settings). A missing, unreadable, corrupt or mismatching entry is
//! recomputed, never trusted; writes are atomic (temporary file + rename), and a new entry is stored
//! first-writer-wins ([`store_first`]): processes that calibrate one key at the same time on a fresh cache
//! all end with the first one's entry, so one cache gives one choice (a held-out battery, round 20: three
//! `render-dataset` shards started together on a fresh cache timed the f32 lanes on either side of the
//! margin and refused each other's scenes).
//!
//! Directory: `--calibration-cache DIR`, else `$DIFFCASSI_CACHE_DIR`, else `$XDG_CACHE_HOME/diffcassi`,
//! else `$HOME/.cache/diffcassi`; with none of them, nothing is cached.
//!
//! ```
//! use diffcassi::fidelity::cache::{fnv1a64, CacheKey};
//! assert_eq!(fnv1a64(b""), 0xcbf29ce484222325);
//! let k = CacheKey::new("rays", &["spec text", "450,650"]);
//! assert_eq!(k, CacheKey::new("rays", &["spec text", "450,650"]));
//! assert_ne!(k, CacheKey::new("rays", &["spec text", "450,651"]));
//! ```
use crate::error::{Error, Result};
use serde::{de::DeserializeOwned, Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// FNV-1a, 64 bit (Fowler–Noll–Vo): a stable hash (unlike std's `DefaultHasher`, the same in every build).
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in bytes {
        h ^= *b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// Kind + hash of everything a calibration depends on.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CacheKey {
    pub kind: String,
    pub hash: u64,
}

impl CacheKey {
    /// Key of `parts` (the crate version is always included).
    pub fn new(kind: &str, parts: &[&str]) -> Self {
        let mut text = format!("diffcassi {}\u{1}{kind}", env!("CARGO_PKG_VERSION"));
        for p in parts {
            text.push('\u{1}');
            text.push_str(p);
        }
        CacheKey { kind: kind.to_string(), hash: fnv1a64(text.as_bytes()) }
    }
    pub fn file_name(&self) -> String {
        format!("calibration-{}-{:016x}.json", self.kind, self.hash)
    }
}

/// The cache directory from an explicit choice or the environment (see the module docs).
pub fn cache_dir(explicit: Option<&Path>) -> Option<PathBuf> {
    if let Some(p) = explicit {
        return Some(p.to_path_buf());
    }
    let env = |k: &str| std::env::var_os(k).filter(|v| !v.is_empty()).map(PathBuf::from);
    env("DIFFCASSI_CACHE_DIR").or_else(|| env("XDG_CACHE_HOME").map(|p| p.join("diffcassi"))).or_else(|| env("HOME").map(|p| p.join(".cache").join("diffcassi")))
}

#[derive(Serialize, Deserialize)]
struct Entry<T> {
    version: String,
    kind: String,
    key: String,
    payload: T,
}

/// What a lookup found.
pub enum Lookup<T> {
    Hit(T),
    Miss,
    /// The file exists but cannot be trusted (why).
    Corrupt(String),
}

/// The largest calibration entry read (a few kB in practice: a handful of numbers per wavelength).
pub const MAX_ENTRY_BYTES: u64 = 16 << 20;

/// Read the entry of `key` from `dir`. `valid` checks the payload (finite numbers, expected sizes…).
pub fn load<T: DeserializeOwned>(dir: &Path, key: &CacheKey, valid: impl Fn(&T) -> bool) -> Lookup<T> {
    let path = dir.join(key.file_name());
    match std::fs::metadata(&path) {
        // No entry: no file (or a dangling link), or a directory that is not there (a path through a file:
        // `--calibration-cache afile/sub`, whose store then fails, said as such).
        Err(e) if matches!(e.kind(), std::io::ErrorKind::NotFound | std::io::ErrorKind::NotADirectory) => return Lookup::Miss,
        _ => {}
    }
    // Through the one input reader (docs/robustness.md): a regular file of bounded size, opened without
    // blocking. A FIFO in its place hung the render, a link to /dev/zero was read until memory ran out (a
    // held-out battery, round 17); either is a corrupt entry, recomputed at once.
    let text = match crate::io::input::read_input_text(&path, MAX_ENTRY_BYTES) {
        Ok(t) => t,
        Err(e) => return Lookup::Corrupt(format!("cannot read: {e}")),
    };
    let entry: Entry<T> = match serde_json::from_str(&text) {
        Ok(e) => e,
        Err(e) => return Lookup::Corrupt(format!("{}: not a calibration entry: {e}", path.display())),
    };
    if entry.version != env!("CARGO_PKG_VERSION") || entry.kind != key.kind || entry.key != format!("{:016x}", key.hash) {
        return Lookup::Corrupt(format!("{}: entry is for another key or version", path.display()));
    }
    if !valid(&entry.payload) {
        return Lookup::Corrupt(format!("{}: implausible values", path.display()));
    }
    Lookup::Hit(entry.payload)
}

/// Write the entry of `key` into `dir` (created if needed), atomically. Returns the file's path.
pub fn store<T: Serialize>(dir: &Path, key: &CacheKey, payload: &T) -> Result<PathBuf> {
    std::fs::create_dir_all(dir).map_err(|e| Error::File { path: dir.display().to_string(), message: format!("cannot create the calibration cache directory: {e}") })?;
    let entry = Entry { version: env!("CARGO_PKG_VERSION").to_string(), kind: key.kind.clone(), key: format!("{:016x}", key.hash), payload };
    let text = serde_json::to_string_pretty(&entry).map_err(|e| Error::invalid(format!("calibration JSON encoding failed: {e}")))?;
    let path = dir.join(key.file_name());
    crate::io::write_atomic(&path, text.as_bytes())?;
    Ok(path)
}

/// What [`store_first`] did.
#[derive(Debug)]
pub enum Stored<T> {
    /// This payload is the entry now (the key had none, or a corrupt one, which was replaced).
    Mine(PathBuf),
    /// Another process stored a valid entry for the key first: that entry (the caller uses it, not its own).
    Theirs(T, PathBuf),
}

/// Store `payload` as the entry of `key` in `dir` (created if needed) unless a valid entry (`valid`) is
/// already there: first writer wins. The complete entry is written to a temporary file beside it and
/// hard-linked into place, which fails when the name exists (atomic on POSIX file systems, NFS included),
/// so two processes racing on a fresh cache cannot both install theirs: the loser reads the winner's entry
/// and returns it ([`Stored::Theirs`]). A corrupt entry in the way is removed and the link tried again. On a
/// file system without hard links the entry is renamed into place (last writer wins, as before) and read
/// back, so the caller still takes what the cache holds.
pub fn store_first<T: Serialize + DeserializeOwned>(dir: &Path, key: &CacheKey, payload: &T, valid: impl Fn(&T) -> bool) -> Result<Stored<T>> {
    std::fs::create_dir_all(dir).map_err(|e| Error::File { path: dir.display().to_string(), message: format!("cannot create the calibration cache directory: {e}") })?;
    let entry = Entry { version: env!("CARGO_PKG_VERSION").to_string(), kind: key.kind.clone(), key: format!("{:016x}", key.hash), payload };
    let text = serde_json::to_string_pretty(&entry).map_err(|e| Error::invalid(format!("calibration JSON encoding failed: {e}")))?;
    let path = dir.join(key.file_name());
    // The temporary is a `stale` one of this entry (`.NAME.stage-HOST-PID-START-N.json`): a killed writer's
    // is removed by the next write of the same entry.
    let _ = crate::io::stale::remove_stale(&path);
    let tmp = crate::io::stale::temp_path(&path);
    let written = (|| -> std::io::Result<()> {
        use std::io::Write;
        let mut f = std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp)?;
        f.write_all(text.as_bytes())?;
        f.sync_all()
    })();
    if let Err(e) = written {
        let _ = std::fs::remove_file(&tmp);
        return Err(Error::File { path: path.display().to_string(), message: format!("cannot write the calibration entry: {e}") });
    }
    let result = (|| {
        for _ in 0..3 {
            match std::fs::hard_link(&tmp, &path) {
                Ok(()) => return Ok(Stored::Mine(path.clone())),
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => match load::<T>(dir, key, &valid) {
                    Lookup::Hit(t) => return Ok(Stored::Theirs(t, path.clone())),
                    // Gone meanwhile: link again.
                    Lookup::Miss => {}
                    // A corrupt entry (found before this calibration, or written by an older build): out of the
                    // way, then link again (a racer that links first in between wins, and this one reads it).
                    Lookup::Corrupt(_) => {
                        let _ = std::fs::remove_file(&path);
                    }
                },
                // No hard links here (some FUSE or SMB mounts): rename into place and take what is there.
                Err(_) => {
                    std::fs::rename(&tmp, &path).map_err(|e| Error::File { path: path.display().to_string(), message: format!("cannot store the calibration entry: {e}") })?;
                    return Ok(match load::<T>(dir, key, &valid) {
                        Lookup::Hit(t) => Stored::Theirs(t, path.clone()),
                        _ => Stored::Mine(path.clone()),
                    });
                }
            }
        }
        Err(Error::File { path: path.display().to_string(), message: "cannot store the calibration entry: another process keeps replacing it".into() })
    })();
    let _ = std::fs::remove_file(&tmp);
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corrupt_entries_are_not_trusted() {
        let dir = tempfile::tempdir().unwrap();
        let key = CacheKey::new("test", &["a"]);
        assert!(matches!(load::<Vec<f64>>(dir.path(), &key, |_| true), Lookup::Miss));
        store(dir.path(), &key, &vec![1.0, 2.0]).unwrap();
        assert!(matches!(load::<Vec<f64>>(dir.path(), &key, |v| v.len() == 2), Lookup::Hit(v) if v == vec![1.0, 2.0]));
        // The validator rejects it.
        assert!(matches!(load::<Vec<f64>>(dir.path(), &key, |v| v.len() == 3), Lookup::Corrupt(_)));
        // Truncated file.
        let p = dir.path().join(key.file_name());
        let text = std::fs::read_to_string(&p).unwrap();
        std::fs::write(&p, &text[..text.len() / 2]).unwrap();
        assert!(matches!(load::<Vec<f64>>(dir.path(), &key, |_| true), Lookup::Corrupt(_)));
        // Another key's entry under this name.
        store(dir.path(), &CacheKey::new("test", &["b"]), &vec![3.0]).unwrap();
        let other = dir.path().join(CacheKey::new("test", &["b"]).file_name());
        std::fs::copy(&other, &p).unwrap();
        assert!(matches!(load::<Vec<f64>>(dir.path(), &key, |_| true), Lookup::Corrupt(_)));
    }

    /// First writer wins: a second store of one key keeps the first entry and hands it back; a corrupt entry
    /// in the way is replaced.
    #[test]
    fn the_first_stored_entry_wins() {
        let dir = tempfile::tempdir().unwrap();
        let key = CacheKey::new("test", &["race"]);
        assert!(matches!(store_first(dir.path(), &key, &vec![1.0], |_: &Vec<f64>| true).unwrap(), Stored::Mine(_)));
        assert!(matches!(store_first(dir.path(), &key, &vec![2.0], |_: &Vec<f64>| true).unwrap(), Stored::Theirs(v, _) if v == vec![1.0]));
        assert!(matches!(load::<Vec<f64>>(dir.path(), &key, |_| true), Lookup::Hit(v) if v == vec![1.0]));
        std::fs::write(dir.path().join(key.file_name()), "{ not json").unwrap();
        assert!(matches!(store_first(dir.path(), &key, &vec![3.0], |_: &Vec<f64>| true).unwrap(), Stored::Mine(_)));
        assert!(matches!(load::<Vec<f64>>(dir.path(), &key, |_| true), Lookup::Hit(v) if v == vec![3.0]));
        // No temporary is left behind.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }
}
