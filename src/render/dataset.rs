//! Dataset mode: find the scenes of a folder, render each into its own sub-folder, skip those already
//! complete, and trace the system's light transport once for all of them (the acquisition is linear in the
//! scene). The transport lives in memory only while it fits a budget; otherwise every scene is traced
//! afresh. Either way each scene's result is bit-identical to rendering it alone with the same seed
//! (same footprints, applied in the same order).
use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// A scene found in a dataset folder.
#[derive(Clone, Debug, PartialEq)]
pub struct DatasetScene {
    /// Output sub-folder name (file stem or folder name).
    pub name: String,
    pub path: PathBuf,
}

/// Scenes of `dir`, sorted by name: `.exr` files, `.npy` cubes (not their `*_wavelengths_nm.npy` lists), RGB
/// `.png` photographs (uplifted to spectra) and sub-folders holding `.png` files (one per band, CAVE-style).
pub fn find_scenes(dir: &Path) -> Result<Vec<DatasetScene>> {
    let entries = std::fs::read_dir(dir).map_err(|e| Error::File { path: dir.display().to_string(), message: format!("cannot list the scenes folder: {e}") })?;
    let mut out = Vec::new();
    for e in entries.flatten() {
        let p = e.path();
        let stem = p.file_stem().unwrap_or_default().to_string_lossy().into_owned();
        let ext = p.extension().and_then(|x| x.to_str()).map(|x| x.to_ascii_lowercase());
        let is_scene = if p.is_dir() {
            std::fs::read_dir(&p).map(|r| r.flatten().any(|f| f.path().extension().and_then(|x| x.to_str()).map(|x| x.eq_ignore_ascii_case("png")).unwrap_or(false))).unwrap_or(false)
        } else {
            match ext.as_deref() {
                Some("exr") => true,
                Some("npy") => !stem.ends_with("_wavelengths_nm") && !stem.ends_with("_wavelengths"),
                // An RGB photograph, uplifted to spectra (crate::scene::natural) — but not the sRGB preview
                // `<stem>_rgb.png` that `make-scene` writes beside a `<stem>.npy`/`.exr` cube.
                Some("png") => !stem.strip_suffix("_rgb").is_some_and(|c| ["npy", "exr"].iter().any(|x| p.with_file_name(format!("{c}.{x}")).is_file())),
                _ => false,
            }
        };
        if is_scene {
            let name = if p.is_dir() { p.file_name().unwrap_or_default().to_string_lossy().into_owned() } else { stem };
            out.push(DatasetScene { name, path: p });
        }
    }
    out.sort_by(|a, b| a.name.cmp(&b.name).then(a.path.cmp(&b.path)));
    for w in out.windows(2) {
        if w[0].name == w[1].name {
            return Err(Error::File { path: dir.display().to_string(), message: format!("two scenes would share the output folder `{}`: {} and {}", w[0].name, w[0].path.display(), w[1].path.display()) });
        }
    }
    Ok(out)
}
