//! `--tolerance-um` on the tracing commands, and `bench tradeoff`.
//!
//! ```text
//! diffcassi spot --preset sp --tolerance-um 0.1          # prints the configuration it chose and why
//! diffcassi mapping --preset sp --npy m.npy --tolerance-um 0.01
//! diffcassi render --preset sp --tolerance-um 2          # chooses the rays per pixel too
//! diffcassi bench tradeoff --csv tradeoff.csv --png tradeoff.png [--quick]
//! ```
use super::args::{BackendArgs, BenchArgs};
use super::commands::{bench_counts, check_extension, commit, say_written};
use super::shared::make_tracer;
use crate::error::{Error, Result};
use crate::fidelity::{self, CacheOptions};
use crate::system::SequentialSystem;
use crate::tracer::Tracer;

fn cache_options(a: &BackendArgs) -> Result<CacheOptions> {
    CacheOptions::checked(a.calibration_cache.as_deref())
}

/// The tolerance, after checking it does not fight explicit backend flags.
fn tolerance(a: &BackendArgs) -> Result<Option<f64>> {
    let Some(t) = a.tolerance_um else {
        if a.calibration_cache.is_some() {
            return Err(Error::invalid("--calibration-cache applies to --tolerance-um only"));
        }
        return Ok(None);
    };
    let mut given = Vec::new();
    if a.backend.is_some() {
        given.push("--backend");
    }
    if a.refine.is_some() {
        given.push("--refine");
    }
    if a.mesh_max_sag_um.is_some() {
        given.push("--mesh-max-sag-um");
    }
    if a.mesh_segments.is_some() {
        given.push("--mesh-segments");
    }
    if !given.is_empty() {
        return Err(Error::invalid(format!(
            "--tolerance-um {t} chooses the backend and its precision itself; it cannot be combined with {} (drop one or the other)",
            given.join(", ")
        )));
    }
    if !(t.is_finite() && t > 0.0) {
        return Err(Error::invalid(format!("--tolerance-um {t}: must be finite and > 0")));
    }
    Ok(Some(t))
}

/// The tracer for a job of `job_rays` rays at `wavelengths_nm`: the named one, or the one the tolerance
/// chooses (printed with its reason).
pub(super) fn tracer_for(a: &BackendArgs, system: &SequentialSystem, wavelengths_nm: &[f64], job_rays: u64) -> Result<Box<dyn Tracer>> {
    let Some(t) = tolerance(a)? else { return make_tracer(a) };
    let (cal, prov) = fidelity::calibrate_backends(system, wavelengths_nm, &cache_options(a)?)?;
    let choice = fidelity::choose_backend(&cal, t, job_rays)?;
    println!("{} [{prov}]", choice.explanation);
    choice.config.build()
}

/// The mapping model: tracer and interpolation stride (1 = exact).
pub(super) fn mapping_for(a: &BackendArgs, system: &SequentialSystem, height: usize, width: usize, pitch_mm: f64, wavelengths_nm: &[f64]) -> Result<(Box<dyn Tracer>, usize)> {
    let Some(t) = tolerance(a)? else { return Ok((make_tracer(a)?, 1)) };
    let cache = cache_options(a)?;
    // Over the cube's field, not only the system's fields.
    let half = fidelity::workload::scene_half_width(height, width, pitch_mm);
    let (cal, prov) = fidelity::calibrate_backends_over(system, wavelengths_nm, Some(half), &cache)?;
    let (map, prov2) = fidelity::calibrate_mapping(system, height, width, pitch_mm, wavelengths_nm, &cache)?;
    let choice = fidelity::choose_mapping(&cal, &map, t, wavelengths_nm.len())?;
    println!("{} [backends: {prov}; interpolation: {prov2}]", choice.explanation);
    Ok((choice.config.build()?, choice.stride))
}

/// Where the render's tracer comes from: the backend the flags name, or `--tolerance-um` (refused beside the
/// backend flags), which [`fidelity::RenderTracing::resolve`] turns into a tracer, rays and precision.
pub(super) fn render_source(a: &BackendArgs) -> Result<fidelity::TracerSource> {
    Ok(match tolerance(a)? {
        None => fidelity::TracerSource::Given(make_tracer(a)?),
        Some(tolerance_um) => fidelity::TracerSource::Tolerance { tolerance_um, cache: cache_options(a)? },
    })
}

/// `diffcassi bench tradeoff`.
pub(super) fn bench_tradeoff(a: &BenchArgs) -> Result<()> {
    // Outputs first (a file of its format, never a folder), then the counts and the budgets, before any work.
    check_extension("--csv", &a.csv, &["csv"], &[])?;
    check_extension("--png", &a.png, &["png"], &[])?;
    let mut opts = fidelity::TradeoffOptions::new(a.quick);
    let (repeat, _, wavelengths) = bench_counts(a, opts.repeat, 1, opts.wavelengths)?;
    opts.repeat = repeat;
    opts.wavelengths = wavelengths;
    // The preset first (milliseconds): the estimate counts its Embree mesh scenes.
    let system = SequentialSystem::build(&crate::presets::spec(&a.preset)?)?;
    let (bytes, rays) = opts.estimate(&system)?;
    let what = format!("bench tradeoff{} × --wavelengths {wavelengths} × --repeat {repeat}", if a.quick { " --quick" } else { "" });
    let mesh_note = if a.quick { "" } else { " (with the Embree mesh scene at max-sag=0.01um, which --quick leaves out)" };
    crate::limits::check_memory(&format!("{what}{mesh_note}"), bytes)?;
    crate::limits::check_rays(&what, rays)?;
    let t0 = std::time::Instant::now();
    println!(
        "bench tradeoff: {}, {} wavelengths 450–650 nm, {} mode, {} threads, best of {}",
        system.name(),
        opts.wavelengths,
        if a.quick { "quick" } else { "full" },
        rayon::current_num_threads(),
        opts.repeat
    );
    let rows = fidelity::run_tradeoff(&system, &opts, &mut |r| {
        eprintln!("  {:8} {:12} {:42} max {:.2e} µm, {:.3} M items/s", r.workload, r.backend, r.options, r.error.max_um, r.items_per_s / 1e6)
    })?;
    print!("{}", fidelity::tradeoff::markdown(&rows));
    // One staged set: both files are written beside their destinations, then moved in together.
    let mut set = crate::io::OutputSet::files();
    if let Some(p) = &a.csv {
        let staged = set.stage(p);
        fidelity::tradeoff::write_csv(&staged, &system, &opts, &rows)?;
        say_written(&staged);
    }
    if let Some(p) = &a.png {
        let staged = set.stage(p);
        fidelity::tradeoff::plot(&staged, &system, &rows)?;
        say_written(&staged);
    }
    commit(set)?;
    println!("bench tradeoff finished in {:.1} s", t0.elapsed().as_secs_f64());
    Ok(())
}
