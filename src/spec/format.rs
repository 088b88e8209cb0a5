use super::SystemSpec;
use crate::error::{Error, Result};
use std::path::Path;

/// Parse a TOML spec; errors carry `source_name` and TOML's line/column and field path.
pub fn from_toml(text: &str, source_name: &str) -> Result<SystemSpec> {
    // The surface count before the parse: TOML's document tree costs ~2 kB per `[[surfaces]]` table (round 19:
    // 0.92 GB for the 4·10⁵ surfaces of a 20 MB spec), held before the spec's own count is known.
    let mut tables = 0usize;
    for (i, line) in text.lines().enumerate() {
        let header: String = line.chars().filter(|c| !c.is_whitespace()).take(13).collect();
        if header.starts_with("[[surfaces]]") {
            tables += 1;
            if let Err(m) = crate::limits::check_surface_count(tables) {
                return Err(Error::spec(source_name, format!("line {}: `[[surfaces]]` table {tables}: {m}", i + 1)));
            }
        }
    }
    let spec: SystemSpec = toml::from_str(text.strip_prefix('\u{feff}').unwrap_or(text)).map_err(|e| Error::spec(source_name, format!("invalid TOML spec: {e}")))?;
    spec.validate().map_err(|m| Error::spec(source_name, m))?;
    Ok(spec)
}

/// Parse a JSON spec; errors carry `source_name`, line and column.
pub fn from_json(text: &str, source_name: &str) -> Result<SystemSpec> {
    let spec: SystemSpec = serde_json::from_str(text.strip_prefix('\u{feff}').unwrap_or(text)).map_err(|e| Error::spec(source_name, format!("invalid JSON spec: {e}")))?;
    spec.validate().map_err(|m| Error::spec(source_name, m))?;
    Ok(spec)
}

/// Parse a spec held in memory in `format`: `toml`, `json`, or `auto`/empty (case-insensitive): JSON when the
/// first non-blank character after an optional UTF-8 byte-order mark is `{`, TOML otherwise. The mark is
/// skipped before sniffing, as [`load_spec_file`] does (round 21: a JSON spec string with a BOM was sniffed as
/// TOML, and its error was TOML's "invalid key" at line 1).
///
/// ```
/// let json = format!("\u{feff}{}", diffcassi::spec::to_json(&diffcassi::presets::spec("sp")?)?);
/// assert_eq!(diffcassi::spec::from_text(&json, "auto", "sp.json")?.name, "sp");
/// # Ok::<(), diffcassi::Error>(())
/// ```
pub fn from_text(text: &str, format: &str, source_name: &str) -> Result<SystemSpec> {
    match format.to_ascii_lowercase().as_str() {
        "toml" => from_toml(text, source_name),
        "json" => from_json(text, source_name),
        "auto" | "" => {
            if text.strip_prefix('\u{feff}').unwrap_or(text).trim_start().starts_with('{') {
                from_json(text, source_name)
            } else {
                from_toml(text, source_name)
            }
        }
        other => Err(Error::spec(source_name, format!("unknown spec format `{other}` (use toml, json or auto)"))),
    }
}

pub fn to_toml(spec: &SystemSpec) -> Result<String> {
    toml::to_string_pretty(spec).map_err(|e| Error::invalid(format!("cannot write spec `{}` as TOML: {e}", spec.name)))
}

pub fn to_json(spec: &SystemSpec) -> Result<String> {
    serde_json::to_string_pretty(spec).map_err(|e| Error::invalid(format!("cannot write spec `{}` as JSON: {e}", spec.name)))
}

/// Load a spec by extension: `.toml`, `.json`, `.yml`/`.yaml` (the reference paper's format, imported),
/// `.csv` (a Zemax prescription transcription, see [`super::zemax_csv`]), `.zmx` (a Zemax lens file, see
/// [`super::zmx`]; anything it holds that diffcassi does not model is refused).
pub fn load_spec_file(path: impl AsRef<Path>) -> Result<SystemSpec> {
    let path = path.as_ref();
    let name = path.display().to_string();
    if path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("zmx")) {
        return super::zmx::import_zmx_file(path, &super::zmx::ZmxOptions::default()).map(|i| i.spec);
    }
    let text = crate::io::input::read_input_text(path, crate::limits::MAX_TEXT_FILE_BYTES)?;
    // A UTF-8 byte-order mark (Windows editors write one) is skipped, as the CSV, `.zmx` and AGF readers do:
    // JSON called it "expected value at line 1 column 1" and YAML glued it to the first key's name.
    let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
    // A spec file's glass catalogues are relative to the spec file (`glass_catalogs`' documentation).
    let base = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
        Some("toml") => from_toml(text, &name).map(|s| with_catalogs_from(s, base)),
        Some("json") => from_json(text, &name).map(|s| with_catalogs_from(s, base)),
        Some("yml") | Some("yaml") => super::yaml::import_yaml(text, &name),
        Some("csv") => super::zemax_csv::import_prescription(text, &name, &super::zemax_csv::SystemData::paper_defaults()),
        other => Err(Error::spec(&name, format!("unknown spec extension {:?}: use .toml, .json, .yml, .csv or .zmx", other.unwrap_or("")))),
    }
}

/// [`load_spec_file`] with the user's catalogues `extra` (`--glass-catalog`, as [`catalog_entry`] writes them)
/// appended to the spec's `glass_catalogs` (after the spec's own: a later catalogue wins). A `.zmx` file's
/// glasses are looked up in them too (after the file's `GCAT` catalogues), so a glass only they hold is found.
pub fn load_spec_file_with_catalogs(path: impl AsRef<Path>, extra: &[String]) -> Result<SystemSpec> {
    let path = path.as_ref();
    if path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("zmx")) {
        let options = super::zmx::ZmxOptions { glass_catalogs: extra.to_vec(), ..Default::default() };
        return super::zmx::import_zmx_file(path, &options).map(|i| i.spec);
    }
    let mut spec = load_spec_file(path)?;
    spec.glass_catalogs.extend(extra.iter().cloned());
    Ok(spec)
}

/// The `glass_catalogs` entry of a catalogue named on the command line or found in a folder: `builtin:NAME`
/// as it is, a file path made absolute (against the working directory), so that the entry reads the same
/// file wherever the spec that records it is read again (a render's `render.json`, a saved spec).
pub fn catalog_entry(entry: impl AsRef<Path>) -> String {
    let p = entry.as_ref();
    if p.to_str().and_then(crate::materials::builtin_catalogs::entry_name).is_some() {
        return p.display().to_string();
    }
    std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf()).display().to_string()
}

/// `spec` with each relative catalogue file of its `glass_catalogs` and each relative mesh file of its
/// `[mechanics]` taken relative to `base` (the spec file's folder) as an absolute path, so that a spec saved
/// elsewhere (`export-spec`, a render's record) reads the same files; absolute paths, `builtin:NAME` entries
/// and an empty mesh path (refused by the spec's checks) are kept as written.
fn with_catalogs_from(mut spec: SystemSpec, base: &Path) -> SystemSpec {
    for e in &mut spec.glass_catalogs {
        if crate::materials::builtin_catalogs::entry_name(e).is_none() && Path::new(e.as_str()).is_relative() {
            *e = catalog_entry(base.join(e.as_str()));
        }
    }
    for m in spec.mechanics.iter_mut().flat_map(|m| m.meshes.iter_mut()) {
        if !m.path.is_empty() && Path::new(&m.path).is_relative() {
            let p = base.join(&m.path);
            m.path = std::path::absolute(&p).unwrap_or(p).display().to_string();
        }
    }
    spec
}

/// Write a spec as TOML, JSON or a Zemax `.zmx` lens file, atomically; the format follows the extension
/// (`.toml`, `.json` or `.zmx`, any case)
/// and any other extension is an error (nothing is written): a `.yaml`/`.csv` name would otherwise hold TOML.
pub fn save_spec_file(spec: &SystemSpec, path: impl AsRef<Path>) -> Result<()> {
    let path = path.as_ref();
    let text = match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
        Some("json") => to_json(spec)?,
        Some("toml") => to_toml(spec)?,
        Some("zmx") => super::zmx::to_zmx(spec)?,
        other => {
            return Err(Error::File {
                path: path.display().to_string(),
                message: format!(
                    "cannot write a spec as {}: the format follows the extension, use .toml or .json (or .zmx, a Zemax lens file; the paper's .yml and Zemax .csv are import-only)",
                    other.map(|e| format!(".{e}")).unwrap_or_else(|| "a file without extension".into())
                ),
            })
        }
    };
    crate::io::write_atomic(path, text.as_bytes())?;
    Ok(())
}
