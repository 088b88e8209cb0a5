//! A reconstruction folder on disk: its output policy ([`reconstruction_rule`]) and its all-or-nothing writer
//! ([`write_reconstruction`]: `cube.npy` + `cube_wavelengths_nm.npy`, optionally `cube.exr`, `rgb.png` and
//! `reconstruct.json`, staged and swapped in). `reconstruct` and `study` write their folders through it.
//!
//! ```no_run
//! use diffcassi::recon::pipeline::output::{reconstruction_rule, write_reconstruction};
//! # let cube = diffcassi::scene::SpectralCube::new(1, 1, vec![520.0], vec![0.5], "x")?;
//! let out = std::path::Path::new("out/recon");
//! let set = diffcassi::io::OutputSet::folder(out, &reconstruction_rule(false), &[])?; // before the work
//! write_reconstruction(set, &cube, &serde_json::json!({"solver": "gap-tv"}), true)?;
//! # Ok::<(), diffcassi::Error>(())
//! ```
use crate::error::{Error, Result};
use crate::scene::{colorimetry, save_exr, save_npy, SpectralCube};
use serde_json::Value;

/// The output policy of a reconstruction folder: new, empty, a previous reconstruction (it holds
/// `reconstruct.json`) or, with `force`, a folder of other files ([`crate::io::policy`]).
pub fn reconstruction_rule(force: bool) -> crate::io::policy::FolderRule<'static> {
    crate::io::policy::FolderRule { option: "--out", command: "reconstruct", marker: "reconstruct.json", force }
}

/// Write a reconstruction folder all or nothing through `set` (an [`OutputSet::folder`](crate::io::OutputSet)
/// made with [`reconstruction_rule`] before the work): everything goes into its staging folder, which replaces
/// `out` when complete. `exr`: also write `cube.exr`.
pub fn write_reconstruction(set: crate::io::OutputSet, cube: &SpectralCube, json: &Value, exr: bool) -> Result<()> {
    let tmp = set.stage_dir().ok_or_else(|| Error::invalid("write_reconstruction needs a folder output set"))?.to_path_buf();
    save_npy(cube, &tmp.join("cube.npy"))?;
    if exr {
        save_exr(cube, &tmp.join("cube.exr"))?;
    }
    colorimetry::save_srgb_png(cube, 1.0, &tmp.join("rgb.png"))?;
    let text = serde_json::to_string_pretty(json).map_err(|e| Error::invalid(format!("JSON encoding failed: {e}")))?;
    crate::io::write_atomic(tmp.join("reconstruct.json"), text.as_bytes())?;
    set.commit()?;
    Ok(())
}
