//! Exclusive advisory locks on output folders (a held-out battery, round 16: two `render-dataset` runs with
//! different settings both found no `dataset.json`, both wrote, and both exited 0 over a mixed folder; two
//! `study` runs mixed their cells in one `study.csv`).
//!
//! The lock is `flock(2)` on the folder's own file descriptor: no lock file is left in the folder (so the
//! output policy and `dataset-status` see nothing new), and the kernel releases it when the process ends,
//! killed or not, so a crashed run never leaves a stale lock. `flock` locks belong to an open file
//! description: two locks on one folder conflict even within one process.
//!
//! Some shared file systems cannot lock a folder (NFS emulates `flock` with write locks, which a folder opened
//! read-only cannot take; Lustre without `-o flock`): [`lock_folder`] then reports
//! [`LockAttempt::Unsupported`] and the caller goes on unguarded (warning), as before.
//!
//! ```
//! use diffcassi::io::lock::{lock_folder, LockAttempt};
//! let d = std::env::temp_dir().join(format!("diffcassi_lock_doc_{}", std::process::id()));
//! std::fs::create_dir_all(&d).unwrap();
//! let held = lock_folder(&d, false).unwrap();
//! assert!(matches!(held, LockAttempt::Held(_)));
//! // A second lock on the same folder is busy while the first is held …
//! assert!(matches!(lock_folder(&d, false).unwrap(), LockAttempt::Busy));
//! drop(held);
//! // … and free once it is dropped.
//! assert!(matches!(lock_folder(&d, false).unwrap(), LockAttempt::Held(_)));
//! std::fs::remove_dir_all(&d).ok();
//! ```
use std::fs::File;
use std::os::fd::AsRawFd;
use std::path::Path;

/// An exclusive lock on a folder, released when dropped (or when the process ends).
#[derive(Debug)]
pub struct FolderLock {
    _file: File,
}

/// What [`lock_folder`] got.
#[derive(Debug)]
pub enum LockAttempt {
    /// The lock is held until the [`FolderLock`] is dropped.
    Held(FolderLock),
    /// Another process (or another open of the folder) holds it; only without `wait`.
    Busy,
    /// The file system cannot lock this folder (the error): go on unguarded.
    Unsupported(std::io::Error),
}

/// Take an exclusive lock on the existing folder `dir`: waiting for it with `wait`, else [`LockAttempt::Busy`]
/// at once when another holds it. An error only when the folder cannot be opened.
pub fn lock_folder(dir: &Path, wait: bool) -> std::io::Result<LockAttempt> {
    let file = File::open(dir)?;
    let op = if wait { libc::LOCK_EX } else { libc::LOCK_EX | libc::LOCK_NB };
    loop {
        // SAFETY: flock on a descriptor this function owns.
        if unsafe { libc::flock(file.as_raw_fd(), op) } == 0 {
            return Ok(LockAttempt::Held(FolderLock { _file: file }));
        }
        let e = std::io::Error::last_os_error();
        match e.raw_os_error() {
            Some(libc::EINTR) => continue,
            Some(libc::EWOULDBLOCK) => return Ok(LockAttempt::Busy),
            _ => return Ok(LockAttempt::Unsupported(e)),
        }
    }
}
