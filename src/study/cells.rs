//! A study's records on disk: a finished cell's result file (`cells/…/<operator>-<solver>.json`), read back
//! as a [`Cell`], and the configuration comparison that decides whether a render or a cell is reused.
use crate::error::{Error, Result};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::Path;

/// Whether a stored configuration equals this one: every number compared by value, bit-exactly (the records
/// are written and read back exactly, serde_json's `float_roundtrip`).
pub(super) fn same_config(stored: Option<&Value>, config: &Value) -> bool {
    stored.is_some_and(|s| crate::render::dataset::configuration_differences(s, config).is_empty())
}

/// A cell's or render's JSON record; `None` when missing, unreadable or not JSON (the cell is computed again).
/// Through `io::input`: a FIFO planted as a record is not waited on (it blocked `study`: a held-out battery).
pub(super) fn read_json(path: &Path) -> Option<Value> {
    crate::io::input::read_sidecar_json(path).ok()
}

pub(super) fn write_json(path: &Path, v: &Value) -> Result<()> {
    let text = serde_json::to_string_pretty(v).map_err(|e| Error::invalid(format!("JSON encoding failed: {e}")))?;
    crate::io::write_atomic(path, text.as_bytes())?;
    Ok(())
}

/// One finished cell, read back from its result file.
#[derive(Clone, Debug)]
pub(super) struct Cell {
    /// The system's label (a preset's display name, a file's stem) and the preset it is (`None` for a file).
    pub(super) system: String,
    pub(super) preset: Option<String>,
    pub(super) scene: String,
    pub(super) operator: String,
    pub(super) solver: String,
    pub(super) metrics: BTreeMap<String, f64>,
    pub(super) seconds_solve: f64,
    pub(super) seconds_operator: f64,
    pub(super) iterations: usize,
    pub(super) residual: f64,
}

const METRIC_KEYS: [&str; 6] = ["psnr_db", "psnr_band_db", "ssim", "sam_deg", "sam_rad", "rmse"];

pub(super) fn cell_from_json(v: &Value) -> Option<Cell> {
    let s = |k: &str| v.get(k).and_then(Value::as_str).map(str::to_string);
    let m = v.get("metrics")?;
    let metrics = METRIC_KEYS.iter().map(|k| Some((k.to_string(), m.get(*k)?.as_f64()?))).collect::<Option<BTreeMap<_, _>>>()?;
    Some(Cell {
        system: s("system")?,
        preset: s("preset"),
        scene: s("scene")?,
        operator: s("operator")?,
        solver: s("solver")?,
        metrics,
        seconds_solve: v.get("seconds_solve")?.as_f64()?,
        seconds_operator: v.get("seconds_operator")?.as_f64()?,
        iterations: v.get("iterations")?.as_u64()? as usize,
        residual: v.get("final_residual").and_then(Value::as_f64).unwrap_or(f64::NAN),
    })
}


/// SHA-256 of a file's bytes (`None` when it cannot be read).
pub(super) fn file_sha256(path: &Path) -> Option<String> {
    std::fs::read(path).ok().map(|b| crate::io::sha256::sha256_hex(&b))
}

/// Whether a cell's reconstruction folder (`reconstruction`, relative to the study folder `out`) holds the
/// `cube.npy` the cell recorded (`cube_npy_sha256`); a cell without the digest (written before it existed) is
/// not trusted.
pub(super) fn reconstruction_intact(out: &Path, cell: &Value) -> bool {
    let (Some(rel), Some(recorded)) = (cell.get("reconstruction").and_then(Value::as_str), cell.get("cube_npy_sha256").and_then(Value::as_str)) else { return false };
    file_sha256(&out.join(rel).join("cube.npy")).as_deref() == Some(recorded)
}
