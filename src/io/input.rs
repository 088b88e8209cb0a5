//! Reading an input file whole: only a **regular file** of **bounded size**, through a bounded reader.
//!
//! A named pipe (FIFO) given as a spec would block forever, `/dev/zero` would be read until memory runs out,
//! and a folder would be reported as "no such file". [`read_input`] opens the path without blocking
//! (`O_NONBLOCK`: opening a FIFO for reading returns at once), checks the *opened* file's metadata (a regular
//! file, not a FIFO, device, socket or folder; its size within the limit) before reading a byte, then reads at
//! most `max_bytes + 1` bytes, so a file that grows while it is read is still refused at the limit.
//!
//! ```
//! use diffcassi::io::input::{read_input, read_input_text};
//! let dir = tempfile::tempdir().unwrap();
//! let p = dir.path().join("spec.toml");
//! std::fs::write(&p, "name = 'x'\n").unwrap();
//! assert_eq!(read_input_text(&p, 1 << 20).unwrap(), "name = 'x'\n");
//! // Over the limit, a folder, a device: refused before reading, naming the path.
//! assert!(read_input(&p, 4).unwrap_err().to_string().contains("limit"));
//! assert!(read_input(dir.path(), 1 << 20).unwrap_err().to_string().contains("folder"));
//! assert!(read_input(std::path::Path::new("/dev/zero"), 1 << 20).unwrap_err().to_string().contains("character device"));
//! ```
use std::fs::{File, OpenOptions};
use std::io::Read;
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::path::Path;

use super::IoError;

fn refused(path: &Path, reason: String) -> IoError {
    IoError::Input { path: path.to_path_buf(), reason }
}

/// What a non-regular file is, for messages (inputs here, outputs in [`super::policy`]).
pub(crate) fn kind(t: std::fs::FileType) -> &'static str {
    if t.is_dir() {
        "a folder"
    } else if t.is_fifo() {
        "a named pipe (FIFO)"
    } else if t.is_char_device() {
        "a character device"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_socket() {
        "a socket"
    } else {
        "not a regular file"
    }
}

/// Open `path` for reading as an input: a regular file (after following symbolic links) of at most
/// `max_bytes`; returns the file and its size. Never blocks (a FIFO is refused, not opened for waiting).
pub fn open_input(path: &Path, max_bytes: u64) -> Result<(File, u64), IoError> {
    let file = OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)
        .map_err(|e| IoError::io(path, "cannot read", e))?;
    let meta = file.metadata().map_err(|e| IoError::io(path, "cannot read", e))?;
    if !meta.is_file() {
        return Err(refused(path, format!("is {}, not a regular file: inputs must be regular files", kind(meta.file_type()))));
    }
    if meta.len() > max_bytes {
        return Err(refused(path, format!("{} bytes: larger than the {max_bytes}-byte limit of this input (docs/robustness.md)", meta.len())));
    }
    Ok((file, meta.len()))
}

/// Read a whole input file of at most `max_bytes` (see the module documentation).
pub fn read_input(path: &Path, max_bytes: u64) -> Result<Vec<u8>, IoError> {
    let (file, len) = open_input(path, max_bytes)?;
    let mut bytes = Vec::with_capacity(usize::try_from(len).unwrap_or(0));
    file.take(max_bytes.saturating_add(1)).read_to_end(&mut bytes).map_err(|e| IoError::io(path, "cannot read", e))?;
    if bytes.len() as u64 > max_bytes {
        return Err(refused(path, format!("grew past the {max_bytes}-byte limit of this input while it was read")));
    }
    Ok(bytes)
}

/// [`read_input`] as UTF-8 text.
pub fn read_input_text(path: &Path, max_bytes: u64) -> Result<String, IoError> {
    String::from_utf8(read_input(path, max_bytes)?).map_err(|e| refused(path, format!("not UTF-8 text (byte {} is invalid)", e.utf8_error().valid_up_to())))
}

/// A JSON sidecar the program wrote (`render.json`, `dataset.json`, a study cell), read as [`read_input_text`]
/// within [`MAX_TEXT_FILE_BYTES`](crate::limits::MAX_TEXT_FILE_BYTES); the error names the file by its name
/// and says whether it was unreadable or damaged (a resume treats either as an output to redo).
pub fn read_sidecar_json(path: &Path) -> Result<serde_json::Value, String> {
    let name = path.file_name().unwrap_or_default().to_string_lossy().into_owned();
    let text = read_input_text(path, crate::limits::MAX_TEXT_FILE_BYTES).map_err(|e| format!("{name}: unreadable ({e})"))?;
    serde_json::from_str(&text).map_err(|e| format!("{name}: not valid JSON ({e}): truncated or damaged"))
}

/// The size and CRC-32 (IEEE, 8 hex digits) of a regular file's bytes, read in blocks (any size).
pub fn file_crc32(path: &Path) -> std::io::Result<(u64, String)> {
    // A regular file only (a FIFO in place of an output would block the open): [`open_input`]'s check, after
    // the plain lookup that reports a missing file as such.
    std::fs::metadata(path)?;
    let (mut f, _) = open_input(path, u64::MAX).map_err(|e| std::io::Error::other(e.to_string()))?;
    let mut h = crc32fast::Hasher::new();
    let mut buf = vec![0u8; 1 << 16];
    let mut n = 0u64;
    loop {
        let k = f.read(&mut buf)?;
        if k == 0 {
            break;
        }
        h.update(&buf[..k]);
        n += k as u64;
    }
    Ok((n, format!("{:08x}", h.finalize())))
}

/// A file named by its content, `NAME (N bytes, crc32 X)` (its file name, size and [`file_crc32`]): the
/// identity records keep of an input that is not part of the program (a dataset's glass catalogues, a
/// copied `System`'s), so that equal identities mean equal bytes wherever the file lies.
pub fn content_identity(path: &Path) -> std::io::Result<String> {
    let (bytes, crc) = file_crc32(path)?;
    let name = path.file_name().map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned());
    Ok(format!("{name} ({bytes} bytes, crc32 {crc})"))
}

/// The limit of a binary input decoded into memory (NPY, EXR, PNG): the memory budget
/// ([`crate::limits::budget`], `--max-memory-gb`).
pub fn binary_limit() -> u64 {
    let b = crate::limits::budget().memory_bytes;
    if b >= u64::MAX as f64 {
        u64::MAX
    } else {
        b as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::{Duration, Instant};

    #[test]
    fn fifo_is_refused_without_blocking() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("pipe.zmx");
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        // SAFETY: a valid NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let t = Instant::now();
        let e = read_input(&fifo, 1 << 20).unwrap_err().to_string();
        assert!(t.elapsed() < Duration::from_secs(5));
        assert!(e.contains("named pipe") && e.contains("pipe.zmx"), "{e}");
    }

    #[test]
    fn limits_and_text() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.txt");
        std::fs::write(&p, b"12345").unwrap();
        assert_eq!(read_input(&p, 5).unwrap(), b"12345");
        let e = read_input(&p, 4).unwrap_err().to_string();
        assert!(e.contains("5 bytes") && e.contains("4-byte limit"), "{e}");
        std::fs::write(&p, [0xff, 0xfe, 0x41]).unwrap();
        assert!(read_input_text(&p, 10).unwrap_err().to_string().contains("UTF-8"));
        let e = read_input(&dir.path().join("missing"), 10).unwrap_err().to_string();
        assert!(e.contains("missing") && e.contains("No such file"), "{e}");
    }
}
