//! The `diffcassi` command line: one subcommand per analysis, each writing CSV/JSON/NPY/PNG outputs.
//!
//! ```text
//! diffcassi info --preset sp
//! diffcassi distortion --preset sp --wavelength-nm 450 --grid 13 --half-width-mm 2.5 --csv grid.csv --png grid.png
//! diffcassi spot --preset ap --wavelength-nm 520 --field-mm 2.5,0 --pupil-csv rays.csv --csv spot.csv
//! diffcassi mapping --preset msp --npy mapping.npy
//! diffcassi report --preset sp --out out/sp
//! diffcassi render --preset sp                  # the main job: out/render-sp
//! diffcassi make-scene --rgb data/scenes/coffee.png --out out/coffee.npy
//! diffcassi reconstruct --from out/render-sp --operator exact --out out/recon-sp
//! diffcassi study --presets ap,sp,map,msp --operators exact,mapping,shift --scenes data/scenes --scene-size 128 --out out/study
//! diffcassi evaluate --truth scene.npy --estimate cube.npy --json metrics.json
//! diffcassi render-dataset --scenes scenes/ --preset sp --out out/ds --shard 0/4
//! diffcassi dataset-status out/ds --scenes scenes/
//! diffcassi ghosts --preset sp --order 2 --csv ghosts.csv --png ghosts.png
//! ```
mod args;
mod bars;
mod commands;
mod shared;
mod dataset;
pub mod render;
mod render_ghosts;
mod design;
pub mod evaluate;
mod fidelity;
mod ghosts;
mod import_zmx;
mod make_scene;
#[cfg(feature = "embree")]
mod nonsequential;
pub mod reconstruct;
pub mod study;

pub use args::*;
/// Text forms of the command line (the bindings parse pupil patterns with the library's
/// [`crate::rays::PupilPattern::parse_for`], which `parse_pupil` calls).
pub use shared::{parse_pupil, parse_wavelengths};
use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

/// diffcassi — exact ray tracing of coded-aperture snapshot spectral imagers (CASSI), matching Zemax.
///
/// Systems come from a preset (sp, ap, msp, map: the reference paper's four systems, built from their
/// Zemax prescriptions; gsp: SP with its prism replaced by a grating, docs/study.md "gsp"; ddsp, mddsp: dual-disperser
/// CASSI, the coded mask a surface inside the system, docs/study.md "Dual-disperser CASSI") or a spec file (.toml, .json, the paper's .yml, a Zemax prescription .csv or a Zemax .zmx).
/// Lengths are millimetres, wavelengths nanometres, angles degrees.
#[derive(Parser, Debug)]
#[command(name = "diffcassi", version, about, long_about = None, propagate_version = true)]
pub struct Cli {
    /// Worker threads (default: all cores). Results do not depend on it.
    #[arg(long, global = true)]
    pub threads: Option<usize>,
    /// Memory budget (GB) checked before any large allocation; a command whose estimate exceeds it is
    /// refused with the estimate [default: half of the physical memory, else 16 GB].
    #[arg(long = "max-memory-gb", global = true)]
    pub max_memory_gb: Option<f64>,
    /// Most rays a command may trace (checked before tracing) [default: 2e10].
    #[arg(long = "max-rays", global = true)]
    pub max_rays: Option<f64>,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Print the resolved system: surfaces (pickups and solves evaluated), pupil, media.
    Info(InfoArgs),
    /// Trace rays of one field and wavelength; write per-ray image positions and outcomes.
    Trace(SpotArgs),
    /// Spot diagrams (centroid, RMS and GEO radius) for fields × wavelengths; CSV/JSON/PNG.
    Spot(SpotArgs),
    /// Grid distortion like Zemax's listing: N×N chief rays, real vs predicted; CSV/JSON/PNG.
    Distortion(DistortionArgs),
    /// Spatio-spectral spreading: chief-ray position vs wavelength for one field; CSV/PNG.
    Dispersion(DispersionArgs),
    /// The scene→detector mapping cube f(x_s, y_s, λ) → (x_d, y_d) as NPY.
    Mapping(MappingArgs),
    /// Analyse a preset end to end (spots, distortion, dispersion) and write every table and plot to a folder.
    Report(ReportArgs),
    /// Throughput of the analytic tracer (rays/s) on SP-like workloads, printed as a table.
    Bench(BenchArgs),
    /// Write a system (preset or file) as a TOML or JSON spec.
    ExportSpec(ExportArgs),
    /// Render a coded acquisition of a hyperspectral scene (default: the synthetic demo scene).
    Render(render::RenderArgs),
    /// Render every scene of a folder (or one shard of it), tracing the system's light transport once.
    RenderDataset(dataset::RenderDatasetArgs),
    /// Which scenes of a render-dataset output are done, missing or corrupt (exit 1 unless all done).
    DatasetStatus(dataset::DatasetStatusArgs),
    /// Reconstruct the cube from a render folder's acquisition (operators exact/mapping/mapping-nearest/shift; solvers GAP-TV, ADMM-TV, PnP, unrolled).
    Reconstruct(reconstruct::ReconstructArgs),
    /// The paper's four-system study: render scenes through every system, reconstruct with every operator, evaluate.
    Study(study::StudyArgs),
    /// Write a test scene (RGB photograph uplifted to spectra, ColorChecker chart, synthetic) as NPY/EXR + sRGB preview.
    MakeScene(make_scene::MakeSceneArgs),
    /// Time the paper-scale acquisition and dataset mode, printed as a table.
    BenchRender(render::BenchRenderArgs),
    /// Quality metrics of an estimated cube against the truth: RMSE, PSNR (paper and MST), SSIM, SAM.
    Evaluate(evaluate::EvaluateArgs),
    /// Optical design by exact derivatives (`design amici`: the paper's double-Amici prism).
    Design(design::DesignArgs),
    /// Recover a misalignment (e.g. the prism tilt) from another system's spot centroids.
    Calibrate(design::CalibrateArgs),
    /// Ghost images from Fresnel reflections: every ghost path, its energy, landing point, spot and defocus; CSV/JSON/PNG.
    Ghosts(ghosts::GhostsArgs),
    /// Convert a Zemax OpticStudio .zmx lens file to a spec (.toml/.json), refusing what is not modelled.
    ImportZmx(import_zmx::ImportZmxArgs),
}

/// The command tree, with negative numbers accepted as option values everywhere (`--tilt -5`,
/// `--tolerance-um -1` reach the option's own check, which names it, instead of clap's "unexpected argument").
pub fn command() -> clap::Command {
    fn relax(c: clap::Command) -> clap::Command {
        c.allow_negative_numbers(true).mut_subcommands(relax)
    }
    relax(Cli::command())
}

/// Entry point of the binary: parse, run, print errors; returns the process exit code
/// (0 success, 1 runtime error, 2 usage error).
pub fn main() -> i32 {
    let cli = match command().try_get_matches().and_then(|m| Cli::from_arg_matches(&m)) {
        Ok(c) => c,
        Err(e) => {
            let code = if e.use_stderr() { 2 } else { 0 };
            let _ = e.print();
            return code;
        }
    };
    if let Err(e) = crate::limits::set_budget(cli.max_memory_gb, cli.max_rays) {
        eprintln!("error: {e}");
        return 2;
    }
    if cli.threads.is_none() {
        if let Err(e) = crate::limits::check_rayon_env() {
            eprintln!("error: {e}");
            return 2;
        }
    }
    if let Some(n) = cli.threads {
        if let Err(e) = crate::limits::check_threads(n) {
            eprintln!("error: {e}");
            return 2;
        }
        if let Err(e) = rayon::ThreadPoolBuilder::new().num_threads(n).build_global() {
            eprintln!("error: cannot set {n} threads: {e}");
            return 1;
        }
    }
    match run(cli.command) {
        Ok(()) => 0,
        Err(e) => {
            eprintln!("error: {e:#}");
            1
        }
    }
}

/// One function per subcommand. The dispatch lives here, in the parent, so that the command modules
/// (`commands`, `render`, `dataset`, `design`) need not import one another to be reached.
fn run(command: Command) -> crate::error::Result<()> {
    use commands::*;
    match command {
        Command::Info(a) => info(a),
        Command::Trace(a) => trace(a),
        Command::Spot(a) => spot(a),
        Command::Distortion(a) => distortion(a),
        Command::Dispersion(a) => dispersion(a),
        Command::Mapping(a) => mapping(a),
        Command::Report(a) => report(a),
        Command::Bench(a) => bench(a),
        Command::ExportSpec(a) => export_spec(a),
        Command::Render(a) => render::render(a),
        Command::RenderDataset(a) => dataset::render_dataset(a),
        Command::DatasetStatus(a) => dataset::dataset_status(a),
        Command::BenchRender(a) => render::bench_render(a),
        Command::MakeScene(a) => make_scene::make_scene(a),
        Command::Reconstruct(a) => reconstruct::reconstruct(a),
        Command::Study(a) => study::study(a),
        Command::Evaluate(a) => evaluate::evaluate(a),
        Command::Design(a) => design::design_cmd(a),
        Command::Calibrate(a) => design::calibrate_cmd(a),
        Command::ImportZmx(a) => import_zmx::import_zmx(a),
        Command::Ghosts(a) => ghosts::ghosts(a),
    }
}
