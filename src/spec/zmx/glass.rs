//! The glass catalogues a `.zmx` file names (`GCAT SCHOTT OHARA …`) and the check that every `GLAS` of
//! the file is found in them.
//!
//! A catalogue `NAME` is looked up as `NAME.AGF` (any case) in the caller's folders, the `.zmx` file's
//! folder and the folders of the `DIFFCASSI_GLASS_DIR` environment variable (separated like `PATH`); every
//! catalogue found is recorded in the spec's `glass_catalogs`. The built-in SCHOTT subset (N-BK7, N-SK2,
//! N-SF10, N-BAF10, SF10, SK10) is always there. A glass found in neither is looked up in the built-in
//! vendor catalogues ([`crate::materials::builtin_catalogs`]: SCHOTT, OHARA, HOYA, CDGM, SUMITA, HIKARI)
//! that stand in for the `GCAT` names not found as files (`SUMITA_AUG2011` → SUMITA, said in a note), the
//! first in `GCAT` order that holds it; the catalogues so used are recorded as `builtin:NAME` entries, before
//! the files (a user's file wins over a built-in copy), so the built system resolves every glass the way it
//! was resolved here (checked). A glass in none of these either — an obsolete glass of an old file, SCHOTT's
//! `BK7` of Edmund's achromats — is taken, as the last resort and said in a note naming its line, from the
//! legacy catalogues ([`builtin_catalogs`]'s "Legacy catalogues": `SCHOTT1980`), recorded first of all.
//! A glass found nowhere is an error naming its line, surface and name, and which catalogues were missing.
use crate::materials::{builtin_catalogs, Glass, GlassCatalog};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// The temperature of every imported system (°C): OpticStudio's default `ENVD 20 1`, the only one accepted.
const SYSTEM_TEMPERATURE_C: f64 = 20.0;

/// Find `NAME.AGF` (case-insensitive file name) in the folders.
pub(super) fn find_catalog(name: &str, dirs: &[PathBuf]) -> Option<PathBuf> {
    let want = format!("{name}.agf").to_ascii_lowercase();
    for d in dirs {
        let Ok(entries) = std::fs::read_dir(d) else { continue };
        let mut hits: Vec<PathBuf> =
            entries.flatten().map(|e| e.path()).filter(|p| p.file_name().and_then(|f| f.to_str()).is_some_and(|f| f.to_ascii_lowercase() == want)).collect();
        hits.sort();
        if let Some(p) = hits.into_iter().next() {
            // Recorded as an absolute path: the imported spec may be saved (and read again) elsewhere.
            return Some(std::path::absolute(&p).unwrap_or(p));
        }
    }
    None
}

/// The folders searched for the catalogues of the file at `source`. Each folder of `DIFFCASSI_GLASS_DIR` must
/// exist and be a folder, as `--glass-dir` must (a missing one was listed as searched, a file ignored); empty
/// entries (`a::b`, an empty variable) are no folder and are skipped.
pub(super) fn search_dirs(source: Option<&Path>, extra: &[PathBuf]) -> Result<Vec<PathBuf>, String> {
    let mut dirs: Vec<PathBuf> = extra.to_vec();
    if let Some(dir) = source.and_then(Path::parent) {
        dirs.push(if dir.as_os_str().is_empty() { PathBuf::from(".") } else { dir.to_path_buf() });
    }
    if let Some(v) = std::env::var_os("DIFFCASSI_GLASS_DIR") {
        for d in std::env::split_paths(&v).filter(|d| !d.as_os_str().is_empty()) {
            match std::fs::metadata(&d) {
                Ok(m) if m.is_dir() => dirs.push(d),
                Ok(_) => return Err(format!("DIFFCASSI_GLASS_DIR: {} is a file, not a folder (give the folders holding the .AGF catalogues)", d.display())),
                Err(e) => return Err(format!("DIFFCASSI_GLASS_DIR: {}: no such folder ({e})", d.display())),
            }
        }
    }
    Ok(dirs)
}

/// Where one glass of a file (or spec) comes from.
#[derive(Clone, Debug, PartialEq)]
pub struct GlassOrigin {
    /// Line of the `GLAS` record (0 when not from a `.zmx` file).
    pub line: usize,
    /// Surface number.
    pub surface: usize,
    /// The glass name as written.
    pub name: String,
    /// The catalogue the glass belongs to (`OHARA`).
    pub catalog: String,
    /// The `glass_catalogs` entry it was taken from (`builtin:OHARA`, a file path), or `built-in SCHOTT subset`.
    pub entry: String,
    /// Its dispersion formula (`Schott (AGF 1)`, `tabulated (8 points, monotone cubic (PCHIP) in λ)`).
    pub formula: String,
    /// The catalogue's n_d.
    pub nd: f64,
    /// For a built-in vendor glass: the database page and vendor catalogue it was converted from, and the
    /// database commit; for a file: the file.
    pub source: String,
}

/// The label of glasses that come from [`GlassCatalog::builtin`].
pub const SUBSET: &str = "built-in SCHOTT subset";

/// The catalogue name an entry stands for: `builtin:OHARA` → OHARA, `/x/ohara.agf` → OHARA.
fn entry_catalog_name(entry: &str) -> String {
    match builtin_catalogs::entry_name(entry) {
        Some(n) => n.to_ascii_uppercase(),
        None => Path::new(entry).file_stem().and_then(|s| s.to_str()).unwrap_or("").to_ascii_uppercase(),
    }
}

/// Loaded entries, each once.
#[derive(Default)]
pub(super) struct Loaded(HashMap<String, GlassCatalog>);

impl Loaded {
    fn get(&mut self, entry: &str) -> Result<&GlassCatalog, String> {
        if !self.0.contains_key(entry) {
            let c = GlassCatalog::from_entry(entry).map_err(|e| format!("glass catalogue {entry}: {e}"))?;
            self.0.insert(entry.to_string(), c);
        }
        Ok(&self.0[entry])
    }

    /// The built-in subset plus the entries, merged as the system build merges them (later wins).
    fn merged(&mut self, entries: &[String]) -> Result<GlassCatalog, String> {
        let mut c = GlassCatalog::builtin();
        for e in entries {
            c.merge(self.get(e)?.clone());
        }
        Ok(c)
    }
}

/// The origin of glass `name` in the catalogue built from `entries` (the last entry holding the same glass).
pub fn origin(entries: &[String], name: &str, line: usize, surface: usize) -> Result<Option<GlassOrigin>, String> {
    let mut loaded = Loaded::default();
    origin_in(&mut loaded, entries, name, line, surface)
}

fn origin_in(loaded: &mut Loaded, entries: &[String], name: &str, line: usize, surface: usize) -> Result<Option<GlassOrigin>, String> {
    let merged = loaded.merged(entries)?;
    let Some(g) = merged.find(name).cloned() else { return Ok(None) };
    let mut entry = SUBSET.to_string();
    for e in entries.iter().rev() {
        if loaded.get(e)?.find(name).is_some_and(|h| **h == *g) {
            entry = e.clone();
            break;
        }
    }
    let source = if let Some(b) = builtin_catalogs::entry_name(&entry).filter(|_| !g.info.comment.is_empty()) {
        format!("{} ({})", g.info.comment, builtin_catalogs::source(b))
    } else if entry == SUBSET {
        "typed in from SCHOTT.AGF (December 2024)".to_string()
    } else {
        entry.clone()
    };
    Ok(Some(GlassOrigin { line, surface, name: name.to_string(), catalog: g.catalog.clone(), entry, formula: formula_label(&g), nd: g.nd, source }))
}

fn formula_label(g: &Glass) -> String {
    g.formula.label()
}

/// The catalogues of a file and where each of its glasses comes from.
pub(super) struct Resolution {
    /// The spec's `glass_catalogs`.
    pub entries: Vec<String>,
    pub glasses: Vec<GlassOrigin>,
    pub notes: Vec<String>,
}

/// Resolve the glasses `uses` = (line, surface, name) of a file with `GCAT` names `gcat` (and its line),
/// diffcassi's own `DCGC` entries and the user's catalogues `user` (`--glass-catalog`: after the file's, so a
/// glass in both is the user's, as for a TOML spec); errors name the line, surface and glass, and every
/// catalogue searched.
pub(super) fn resolve(
    gcat: Option<&(usize, Vec<String>)>,
    dcgc: &[String],
    user: &[String],
    uses: &[(usize, usize, String)],
    dirs: &[PathBuf],
) -> Result<Resolution, String> {
    let mut loaded = Loaded::default();
    let mut files: Vec<String> = dcgc.to_vec();
    let mut missing: Vec<String> = Vec::new();
    // (GCAT name, built-in catalogue) for the names found as no file, in GCAT order.
    let mut stand_ins: Vec<(String, &'static str)> = Vec::new();
    // The files found for GCAT names, in GCAT order; put in the list last first, so that, as the list
    // merges (a later catalogue wins), a glass several of them hold is the first's — OpticStudio looks a glass
    // up in its catalogues in GCAT order (as rayoptics reads it), and `GCAT SCHOTT MYCAT` took MYCAT's N-BK7.
    let mut gcat_files: Vec<String> = Vec::new();
    // A file diffcassi exported holds the spec's catalogues verbatim as `DCGC` lines, and writes `GCAT` for
    // OpticStudio only (SCHOTT added for the built-in subset): its `GCAT` names are not looked up again, else a
    // SCHOTT.AGF beside the export took over the `DCGC` catalogue's glass (a held-out battery, round 15).
    let gcat_names: &[String] = if dcgc.is_empty() { gcat.map(|g| g.1.as_slice()).unwrap_or(&[]) } else { &[] };
    for n in gcat_names {
        if files.iter().chain(&gcat_files).chain(user).any(|p| entry_catalog_name(p).eq_ignore_ascii_case(n)) {
            continue;
        }
        match find_catalog(n, dirs) {
            Some(p) => gcat_files.push(p.display().to_string()),
            None => match builtin_catalogs::standing_in_for(n) {
                Some(b) => stand_ins.push((n.clone(), b)),
                None => missing.push(n.clone()),
            },
        }
    }
    files.extend(gcat_files.into_iter().rev());
    for u in user {
        if !files.contains(u) {
            files.push(u.clone());
        }
    }
    let subset = GlassCatalog::builtin();
    // Each glass as OpticStudio finds it: in the file's catalogues (the files found, then the built-in
    // stand-ins, the first in GCAT order that holds it) — HIKARI's SF10 for `GCAT HIKARI`, not the subset's
    // SCHOTT SF10 (a held-out battery, round 7) — else the built-in SCHOTT subset (said in a note when the
    // file names catalogues), else, the last resort (said in a note), the first legacy catalogue holding it.
    // `wanted[i]`: the glass of `uses[i]` when no file holds it (a file's glass is the files' merge, `want` below).
    let mut wanted: Vec<Option<Glass>> = vec![None; uses.len()];
    let mut used: Vec<usize> = Vec::new();
    let mut legacy_used: Vec<&'static str> = Vec::new();
    let mut notes = Vec::new();
    for (i, (line, surface, name)) in uses.iter().enumerate() {
        let in_a_file = {
            let mut hit = false;
            for f in &files {
                hit |= loaded.get(f)?.contains(name);
            }
            hit
        };
        if in_a_file {
            continue;
        }
        let mut found = false;
        for (k, (_, b)) in stand_ins.iter().enumerate() {
            if let Some(g) = loaded.get(&format!("{}{b}", builtin_catalogs::ENTRY_PREFIX))?.find(name).map(|g| (**g).clone()) {
                // The built-in SCHOTT standing in for `GCAT SCHOTT` holds the subset's own data: no entry needed.
                if subset.find(name).is_none_or(|s| **s != g) && !used.contains(&k) {
                    used.push(k);
                }
                wanted[i] = Some(g);
                found = true;
                break;
            }
        }
        if !found {
            if let Some(g) = subset.find(name) {
                if let Some((gl, names)) = gcat.filter(|g| !g.1.is_empty() && dcgc.is_empty()) {
                    notes.push(format!(
                        "line {line} `GLAS`: glass `{name}` of surface {surface} is in none of the file's catalogues (`GCAT {}`, line {gl}); taken from the {SUBSET}",
                        names.join(" ")
                    ));
                }
                wanted[i] = Some((**g).clone());
                found = true;
            }
        }
        if !found {
            for l in builtin_catalogs::legacy_names() {
                if let Some(g) = loaded.get(&format!("{}{l}", builtin_catalogs::ENTRY_PREFIX))?.find(name) {
                    let (lo, hi) = g.valid_range_nm();
                    notes.push(format!(
                        "line {line} `GLAS`: glass `{name}` of surface {surface} is in none of the catalogues the file names (nor their built-in stand-ins); taken from the built-in legacy catalogue {l} ({}, valid {lo}–{hi} nm; {})",
                        g.formula.label(),
                        builtin_catalogs::source(l)
                    ));
                    if !legacy_used.contains(&l) {
                        legacy_used.push(l);
                    }
                    wanted[i] = Some((**g).clone());
                    found = true;
                    break;
                }
            }
        }
        if !found {
            let gl = gcat.map(|g| format!(" (`GCAT` line {})", g.0)).unwrap_or_default();
            let loaded_list: String = files.iter().map(|p| format!(", {p}")).collect();
            let builtins: Vec<String> =
                stand_ins.iter().map(|s| s.1).chain(builtin_catalogs::legacy_names()).map(|b| format!("built-in {b}")).collect();
            let looked = if builtins.is_empty() { String::new() } else { format!(", {}", builtins.join(", ")) };
            let why = if missing.is_empty() {
                "no catalogue searched holds it".to_string()
            } else {
                format!(
                    "the file's catalogue(s) {} were not found{gl} and are not built in (built in: {}): put {} in {} or set DIFFCASSI_GLASS_DIR",
                    missing.join(", "),
                    builtin_catalogs::vendor_names().collect::<Vec<_>>().join(", "),
                    missing.iter().map(|m| format!("{m}.AGF")).collect::<Vec<_>>().join(", "),
                    dirs.iter().map(|d| d.display().to_string()).collect::<Vec<_>>().join(", ")
                )
            };
            return Err(format!(
                "line {line} `GLAS`: glass `{name}` of surface {surface} is in none of the loaded catalogues ({SUBSET}{loaded_list}{looked}): {why}"
            ));
        }
    }
    used.sort_unstable();
    // Built-ins first — the legacy ones first of all (they hold only what nothing else does), then the
    // stand-ins (the first in GCAT order last, so it wins among them) — then the files.
    let mut builtin_entries: Vec<String> = legacy_used
        .iter()
        .map(|l| format!("{}{l}", builtin_catalogs::ENTRY_PREFIX))
        .chain(used.iter().rev().map(|&k| format!("{}{}", builtin_catalogs::ENTRY_PREFIX, stand_ins[k].1)))
        .collect();
    let chosen = |loaded: &mut Loaded, entries: &[String]| -> Result<Vec<Option<Glass>>, String> {
        let m = loaded.merged(entries)?;
        Ok(uses.iter().map(|u| m.find(&u.2).map(|g| (**g).clone())).collect())
    };
    let want: Vec<Option<Glass>> = {
        // A file's glass as the files merge (a later file wins); the others as chosen above.
        let w = chosen(&mut loaded, &files)?;
        w.into_iter().zip(wanted).map(|(a, b)| b.or(a)).collect()
    };
    let mut entries: Vec<String> = builtin_entries.iter().cloned().chain(files.iter().cloned()).collect();
    if !builtin_entries.is_empty() && chosen(&mut loaded, &entries)? != want {
        // A built-in shadows a glass of the subset (HIKARI's SF10 over SCHOTT's): the built-in SCHOTT (the
        // subset over the converted SCHOTT glasses) on top of the built-ins puts it back.
        builtin_entries.retain(|e| !entry_catalog_name(e).eq_ignore_ascii_case("SCHOTT"));
        builtin_entries.push(format!("{}SCHOTT", builtin_catalogs::ENTRY_PREFIX));
        entries = builtin_entries.iter().cloned().chain(files.iter().cloned()).collect();
    }
    let got = chosen(&mut loaded, &entries)?;
    if got != want {
        let k = got.iter().zip(&want).position(|(a, b)| a != b).unwrap_or(0);
        return Err(format!(
            "line {} `GLAS`: glass `{}` of surface {} is in more than one of the file's catalogues with different data ({}), and the spec's catalogue list cannot keep OpticStudio's choice: give it in one catalogue file only",
            uses[k].0, uses[k].2, uses[k].1, entries.join(", ")
        ));
    }
    // The system is at 20 °C (`ENVD` is refused otherwise): a glass whose data are referenced to another
    // temperature (its `TD` record) would need the thermal index change, which is not modelled.
    for ((line, surface, name), g) in uses.iter().zip(&got) {
        if let Some(t) = g.as_ref().and_then(|g| g.thermal).filter(|t| t.reference_temperature_c != SYSTEM_TEMPERATURE_C) {
            return Err(format!(
                "line {line} `GLAS`: glass `{name}` of surface {surface} is referenced to {} °C (its catalogue's `TD` record) and the system is at {SYSTEM_TEMPERATURE_C} °C: the thermal change of its index (dn/dT) is not modelled; use the glass's data at {SYSTEM_TEMPERATURE_C} °C",
                crate::limits::fmt_num(t.reference_temperature_c)
            ));
        }
    }
    for &k in &used {
        let (n, b) = &stand_ins[k];
        if !n.eq_ignore_ascii_case(b) {
            notes.push(format!("`GCAT {n}`: no {n}.AGF found; the built-in {b} catalogue stands in for it"));
        }
    }
    let mut glasses = Vec::new();
    for (line, surface, name) in uses {
        if let Some(o) = origin_in(&mut loaded, &entries, name, *line, *surface)? {
            glasses.push(o);
        }
    }
    Ok(Resolution { entries, glasses, notes })
}
