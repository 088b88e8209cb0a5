//! The glass catalogues a `.zmx` file names (`GCAT SCHOTT OHARA …`) and the check that every `GLAS` of
//! the file is found in them.
//!
//! A catalogue `NAME` is looked up as `NAME.AGF` (any case) in the `.zmx` file's folder and in the folders
//! of the `DIFFCASSI_GLASS_DIR` environment variable (separated like `PATH`) or of the caller's list;
//! every catalogue found is recorded in the spec's `glass_catalogs`. The built-in SCHOTT subset (N-BK7,
//! N-SK2, N-SF10, N-BAF10, SF10, SK10) is always there. A glass found nowhere is an error naming its line,
//! and which catalogues were missing.
use crate::materials::GlassCatalog;
use std::path::{Path, PathBuf};

/// Find `NAME.AGF` (case-insensitive file name) in the folders.
pub(super) fn find_catalog(name: &str, dirs: &[PathBuf]) -> Option<PathBuf> {
    let want = format!("{name}.agf").to_ascii_lowercase();
    for d in dirs {
        let Ok(entries) = std::fs::read_dir(d) else { continue };
        let mut hits: Vec<PathBuf> =
            entries.flatten().map(|e| e.path()).filter(|p| p.file_name().and_then(|f| f.to_str()).is_some_and(|f| f.to_ascii_lowercase() == want)).collect();
        hits.sort();
        if let Some(p) = hits.into_iter().next() {
            return Some(p);
        }
    }
    None
}

/// The folders searched for the catalogues of the file at `source`.
pub(super) fn search_dirs(source: Option<&Path>, extra: &[PathBuf]) -> Vec<PathBuf> {
    let mut dirs: Vec<PathBuf> = extra.to_vec();
    if let Some(dir) = source.and_then(Path::parent) {
        dirs.push(if dir.as_os_str().is_empty() { PathBuf::from(".") } else { dir.to_path_buf() });
    }
    if let Some(v) = std::env::var_os("DIFFCASSI_GLASS_DIR") {
        dirs.extend(std::env::split_paths(&v));
    }
    dirs
}

/// Load the built-ins plus the catalogue files.
pub(super) fn load(paths: &[String]) -> Result<GlassCatalog, String> {
    let mut catalog = GlassCatalog::builtin();
    for p in paths {
        catalog.merge(GlassCatalog::from_agf_file(p).map_err(|e| format!("glass catalogue {p}: {e}"))?);
    }
    Ok(catalog)
}
