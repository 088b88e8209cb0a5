//! `diffcassi import-zmx`: a Zemax OpticStudio `.zmx` lens file → our spec format (TOML or JSON).
//!
//! ```text
//! diffcassi import-zmx design.zmx --out design.toml
//! diffcassi import-zmx design.zmx --out design.toml --ignore-unsupported   # lists what it skipped
//! diffcassi import-zmx design.zmx --glass-catalog vendor.agf --out design.toml  # glasses the file's GCAT lacks
//! ```
//! Without `--ignore-unsupported` anything the file holds that diffcassi does not model is refused (exit 1,
//! nothing written) with every such item listed by line and keyword (`docs/zemax-files.md`).
use crate::error::{Error, Result};
use crate::spec::zmx::{import_zmx_file, ZmxOptions};
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct ImportZmxArgs {
    /// The .zmx file (UTF-16 with byte-order mark, UTF-8 with or without BOM, ASCII or ANSI Windows-1252).
    pub input: PathBuf,
    /// Output spec: .toml or .json (or .zmx, rewritten by diffcassi).
    #[arg(long)]
    pub out: PathBuf,
    /// Skip what diffcassi does not model (vignetting factors, tolerance data, unknown keywords…) and list
    /// every skipped item on stderr, instead of refusing the file.
    #[arg(long = "ignore-unsupported")]
    pub ignore_unsupported: bool,
    /// Folder(s) searched first for the AGF catalogues the file names (`GCAT`); then the file's folder and
    /// DIFFCASSI_GLASS_DIR.
    #[arg(long = "glass-dir")]
    pub glass_dirs: Vec<PathBuf>,
    /// Extra AGF glass catalogue(s) (or `builtin:NAME`), searched for the file's glasses after its own
    /// catalogues, as `--glass-catalog` of `info`, `render` and the other commands reading a `.zmx`; recorded in
    /// the written spec's `glass_catalogs` (absolute paths), so it reads the same glasses again.
    #[arg(long = "glass-catalog")]
    pub glass_catalogs: Vec<PathBuf>,
}

pub fn import_zmx(a: ImportZmxArgs) -> Result<()> {
    // The output policy (docs/robustness.md): a file, never a folder, never the .zmx it reads (a spec written
    // beside the catalogues of a --glass-dir is fine: they are only read).
    let mut inputs = vec![("(the .zmx file)", a.input.as_path())];
    inputs.extend(a.glass_catalogs.iter().map(|p| ("--glass-catalog", p.as_path())));
    crate::io::policy::check_out_file("--out", &a.out, &inputs)?;
    // A --glass-dir that is missing or a file would be searched in vain (and the GCAT catalogues reported
    // missing, or found elsewhere): refused, naming it.
    for d in &a.glass_dirs {
        match std::fs::metadata(d) {
            Ok(m) if m.is_dir() => {}
            Ok(_) => return Err(Error::invalid(format!("--glass-dir {}: is a file, not a folder (give the folder holding the .AGF catalogues)", d.display()))),
            Err(e) => return Err(Error::invalid(format!("--glass-dir {}: no such folder ({e})", d.display()))),
        }
    }
    let glass_catalogs = a.glass_catalogs.iter().map(crate::spec::catalog_entry).collect();
    let options = ZmxOptions { ignore_unsupported: a.ignore_unsupported, glass_dirs: a.glass_dirs.clone(), glass_catalogs };
    let imported = import_zmx_file(&a.input, &options)?;
    // Build it before writing: a file that imports but does not make a traceable system writes nothing.
    let system = crate::system::SequentialSystem::build_from(&imported.spec, crate::system::SystemOrigin::Zmx)?;
    for w in system.warnings() {
        eprintln!("warning: {w}");
    }
    crate::spec::save_spec_file(&imported.spec, &a.out)?;
    if !imported.ignored.is_empty() {
        eprintln!("warning: {}: {} item(s) ignored (--ignore-unsupported):", a.input.display(), imported.ignored.len());
        for u in &imported.ignored {
            eprintln!("  {u}");
        }
    }
    for n in &imported.notes {
        println!("note: {n}");
    }
    for o in &imported.glasses {
        println!("glass `{}` (line {}, surface {}): {} {}, n_d {}, from {}", o.name, o.line, o.surface, o.catalog, o.formula, o.nd, o.entry);
    }
    if !imported.skipped.is_empty() {
        println!("{}", super::commands::skipped_list(&imported.skipped));
    }
    println!(
        "imported {} ({} surfaces, {} fields, {} wavelengths) → {}",
        a.input.display(),
        imported.spec.surfaces.len(),
        // Heights or angles (at infinity): "0 fields" was printed for every file of angles.
        imported.spec.fields_mm.len() + imported.spec.fields_deg.len(),
        imported.spec.wavelengths_nm.len(),
        a.out.display()
    );
    Ok(())
}
