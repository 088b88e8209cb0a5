//! `diffcassi ghosts`: the ghost paths of a system (see [`crate::analysis::ghosts`] and docs/ghosts.md).
//!
//! ```text
//! diffcassi ghosts --preset sp --order 2 --csv ghosts.csv --json ghosts.json --png ghosts.png
//! ```
use super::args::SystemArgs;
use super::commands::{check_extension, commit, say_written, write_json};
use super::shared::{load_system, system_inputs};
use crate::analysis::ghosts::{ghost_analysis, ghost_estimate, GhostMap, GhostOptions, GhostReport};
use crate::error::{Error, Result};
use crate::io::{CsvValue, CsvWriter};
use crate::tracer::nonseq::FresnelModel;
use clap::Args;
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct GhostsArgs {
    #[command(flatten)]
    pub system: SystemArgs,
    /// Ghost order K: most Fresnel reflections on a path (0 ..= 4).
    #[arg(long, default_value_t = 2, value_parser = |s: &str| super::render_ghosts::ghost_order_from(s, 0))]
    pub order: u32,
    /// Interface model: polarized (two incoherent states, polarisation ray tracing) or scalar (s/p-averaged reflectance).
    #[arg(long, default_value = "polarized", value_parser = ["polarized", "scalar"])]
    pub model: String,
    /// Relative power below which Russian roulette plays, in [0, 1).
    #[arg(long, default_value_t = 1e-7, allow_hyphen_values = true)]
    pub threshold: f64,
    /// Seed of the roulette streams.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Hexapolar pupil rings per field point (1..=64).
    #[arg(long, default_value_t = 6)]
    pub rings: usize,
    /// The uniform extended source is an N×N grid of field points (1..=64).
    #[arg(long = "extended-grid", default_value_t = 5)]
    pub extended_grid: usize,
    /// Ghost paths of the on-axis point source at 520 nm, or the primary wavelength when a glass does not cover 520 nm (path, energy_fraction, x_mm, y_mm, …).
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// Every source and wavelength, the averages, the ledger and the scalar-model error.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Ghost maps (log scale): on-axis point source | uniform field, 520 nm (or the primary wavelength, as the CSV).
    #[arg(long)]
    pub png: Option<PathBuf>,
}

pub(super) fn ghosts(a: GhostsArgs) -> Result<()> {
    let inputs = system_inputs(&a.system);
    check_extension("--csv", &a.csv, &["csv"], &inputs)?;
    check_extension("--json", &a.json, &["json"], &inputs)?;
    check_extension("--png", &a.png, &["png"], &inputs)?;
    if !(a.threshold.is_finite() && (0.0..1.0).contains(&a.threshold)) {
        return Err(Error::invalid(format!("--threshold {}: the roulette threshold must be in [0, 1)", crate::limits::fmt_num(a.threshold))));
    }
    for (option, v) in [("--rings", a.rings), ("--extended-grid", a.extended_grid)] {
        crate::limits::check_count(option, v, 64)?;
    }
    let system = load_system(&a.system)?;
    if system.spec.mechanics.is_some() {
        eprintln!("note: the spec's [mechanics] section is not used by `ghosts` (the Fresnel ghost paths of the optics alone); `render --ghosts K --mechanics` traces the mechanics");
    }
    let model = if a.model == "scalar" { FresnelModel::Scalar } else { FresnelModel::Polarized };
    let options = GhostOptions { order: a.order, model, threshold: a.threshold, seed: a.seed, rings: a.rings, extended_grid: a.extended_grid };
    // The budgets before the analysis: trees from the options, paths per tree from a pilot.
    let e = ghost_estimate(&system, &options)?;
    let what = format!(
        "--order {} × --rings {} × --extended-grid {} ({:.3e} ray trees, {:.1} detector paths each)",
        a.order, a.rings, a.extended_grid, e.trees, e.paths_per_tree
    );
    let reduce = "--order, --rings or --extended-grid";
    crate::limits::check_rays_reducing(&what, reduce, e.rays)?;
    crate::limits::check_memory_reducing(&what, reduce, e.bytes)?;
    if let Some(n) = super::shared::zmx_coating_note(&a.system, "`ghosts`") {
        eprintln!("note: {n}");
    }
    let t0 = std::time::Instant::now();
    let report = ghost_analysis(&system, &options)?;
    if let Some(n) = &report.design_beam_note {
        eprintln!("note: {n}");
    }
    if let Some(n) = &report.reference_note {
        eprintln!("note: {n}");
    }
    let reference = crate::limits::fmt_num(report.reference_wavelength_nm);
    let rows = report.on_axis_520();
    println!("ghosts of {} (order {}, {} model, brute-force f64 kernel): on-axis point source, {reference} nm, ranked by peak irradiance / main image", report.system, report.order, model.label());
    println!("{:>14} {:>13} {:>10} {:>10} {:>10} {:>11} {:>11}", "path", "energy/main", "x_mm", "y_mm", "rms_mm", "defocus_mm", "peak/main");
    for p in &rows {
        println!("{:>14} {:>13.4e} {:>10.4} {:>10.4} {:>10.4} {:>11.3} {:>11.3e}", p.path, p.energy_fraction, p.x_mm, p.y_mm, p.rms_radius_mm, p.defocus_mm, p.peak_ratio);
    }
    // `+ 0.0`: an empty or all-zero sum of f64 is −0.0, printed "-0.0000e0".
    let total: f64 = rows.iter().map(|p| p.energy_fraction).sum::<f64>() + 0.0;
    println!("total ghost energy / main: {total:.4e}; scalar model vs polarised: largest relative error {:.3e} over the paths", report.scalar_max_relative_error);
    let l = &report.ledger;
    println!(
        "ledger over {} rays: detector {:.6}, absorbed {:.6}, escaped {:.6}, truncated {:.3e}, rouletted {:.3e} (imbalance {:.1e}); {:.1} s",
        report.rays_traced,
        l.detector,
        l.absorbed,
        l.escaped,
        l.truncated,
        l.rouletted,
        l.imbalance(),
        t0.elapsed().as_secs_f64()
    );
    let mut set = crate::io::OutputSet::files();
    if let Some(path) = &a.csv {
        write_csv(&set.stage(path), &report)?;
    }
    if let Some(path) = &a.json {
        write_json(&set.stage(path), &report)?;
    }
    if let Some(path) = &a.png {
        write_png(&set.stage(path), &report)?;
    }
    commit(set)?;
    Ok(())
}

fn write_csv(path: &Path, r: &GhostReport) -> Result<()> {
    let mut w = CsvWriter::new(path, &["path", "order", "energy_fraction", "x_mm", "y_mm", "rms_radius_mm", "defocus_mm", "peak_ratio", "energy_fraction_scalar"])?;
    w.comment(&format!("system {}; ghost order {}; model {}; on-axis point source at {} nm{}; energies relative to the main image; positions in the image surface's frame (mm)", r.system, r.order, r.model.label(), crate::limits::fmt_num(r.reference_wavelength_nm), if r.reference_note.is_some() { " (the system's primary: a glass does not cover 520 nm)" } else { "" }));
    for (k, p) in r.on_axis_520().iter().enumerate() {
        w.row(&[
            CsvValue::Str(&p.path),
            CsvValue::Int(p.order as i64),
            CsvValue::F64(p.energy_fraction),
            CsvValue::F64(p.x_mm),
            CsvValue::F64(p.y_mm),
            CsvValue::F64(p.rms_radius_mm),
            CsvValue::F64(p.defocus_mm),
            CsvValue::F64(p.peak_ratio),
            CsvValue::F64(r.scalar_energy_fraction.get(k).copied().unwrap_or(0.0)),
        ])?;
    }
    w.finish()?;
    say_written(path);
    Ok(())
}

/// Two panels side by side (point source | uniform field), log₁₀ of the power per pixel relative to the
/// panel's brightest pixel over 8 decades, viridis.
fn write_png(path: &Path, r: &GhostReport) -> Result<()> {
    let n = r.map_point.n;
    let mut img = image::RgbImage::new(2 * n as u32 + 8, n as u32);
    for (panel, map) in [&r.map_point, &r.map_uniform].into_iter().enumerate() {
        draw(&mut img, map, panel as u32 * (n as u32 + 8));
    }
    img.save_with_format(path, image::ImageFormat::Png).map_err(|e| Error::invalid(format!("{}: cannot write PNG: {e}", path.display())))?;
    say_written(path);
    Ok(())
}

fn draw(img: &mut image::RgbImage, map: &GhostMap, x_off: u32) {
    let peak = map.power.iter().cloned().fold(0.0, f64::max).max(1e-300);
    for j in 0..map.n {
        for i in 0..map.n {
            let v = map.power[j * map.n + i] / peak;
            let t = if v > 0.0 { ((v.log10() + 8.0) / 8.0).clamp(0.0, 1.0) } else { 0.0 };
            let c = if v > 0.0 { crate::plot::colors::viridis(t) } else { plotters::style::RGBColor(0, 0, 0) };
            // Image rows go down; detector y goes up.
            img.put_pixel(x_off + i as u32, (map.n - 1 - j) as u32, image::Rgb([c.0, c.1, c.2]));
        }
    }
}
