//! Option groups shared by several commands ([`SystemArgs`], [`BackendArgs`]) and the arguments of the
//! analysis commands of [`super::commands`]. The command tree itself ([`super::Command`]) lives in the
//! parent module, so this file imports no command module.
use clap::Args;
use std::path::PathBuf;

/// Which system to use.
#[derive(Args, Debug, Clone)]
pub struct SystemArgs {
    /// A preset: sp, ap, msp, map (the paper's four systems), gsp (SP with a plane transmission grating), ddsp, mddsp (dual-disperser CASSI: SP's arm onto a coded mask, then mirrored onto the detector).
    #[arg(long, conflicts_with = "system")]
    pub preset: Option<String>,
    /// A spec file: .toml, .json, .yml/.yaml (paper format), .csv (Zemax prescription) or .zmx (Zemax lens file).
    #[arg(long)]
    pub system: Option<PathBuf>,
    /// Extra AGF glass catalogue(s) to load beside the built-in glasses.
    #[arg(long = "glass-catalog")]
    pub glass_catalogs: Vec<PathBuf>,
}

/// Which tracer backend and its precision, or a tolerance that chooses them.
#[derive(Args, Debug, Clone)]
pub struct BackendArgs {
    /// Tracer: analytic (exact f64, sequential), embree-user (Embree, analytic user geometry) or
    /// embree-mesh (Embree, tessellated surfaces); the Embree ones trace non-sequentially [default: analytic].
    #[arg(long)]
    pub backend: Option<String>,
    /// Embree hit refinement: f64 (re-solve each hit exactly: equals the analytic tracer) or none (f32 hits)
    /// [default: f64].
    #[arg(long)]
    pub refine: Option<String>,
    /// embree-mesh: tessellate to this maximum chord-sag error (µm) [default 1].
    #[arg(long = "mesh-max-sag-um", conflicts_with = "mesh_segments")]
    pub mesh_max_sag_um: Option<f64>,
    /// embree-mesh: tessellate with this many segments (rings; 6× around circular apertures).
    #[arg(long = "mesh-segments")]
    pub mesh_segments: Option<usize>,
    /// Choose the cheapest configuration (backend, tessellation, refinement; for renders also rays per
    /// pixel, for the mapping cube an interpolation stride) whose error measured on this system and these
    /// wavelengths is within this many µm of the analytic f64 result; prints the choice. Excludes
    /// --backend/--refine/--mesh-*.
    #[arg(long = "tolerance-um", allow_negative_numbers = true)]
    pub tolerance_um: Option<f64>,
    /// Directory of the --tolerance-um calibration cache [default: $DIFFCASSI_CACHE_DIR, else
    /// $XDG_CACHE_HOME/diffcassi, else ~/.cache/diffcassi].
    #[arg(long = "calibration-cache")]
    pub calibration_cache: Option<PathBuf>,
}

#[derive(Args, Debug)]
pub struct InfoArgs {
    #[command(flatten)]
    pub system: SystemArgs,
    /// Print the resolved spec as JSON instead of the table.
    #[arg(long)]
    pub json: bool,
}

#[derive(Args, Debug)]
pub struct SpotArgs {
    #[command(flatten)]
    pub system: SystemArgs,
    #[command(flatten)]
    pub backend: BackendArgs,
    /// Wavelength(s) in nm: `520`, `450,520,650`, or `450:650:28` (first:last:count). Default: the system's.
    #[arg(long = "wavelength-nm", alias = "wavelengths-nm")]
    pub wavelength_nm: Option<String>,
    /// Field point(s) as object height `X,Y` mm (finite objects); repeat for several. Default: the system's fields.
    #[arg(long = "field-mm", allow_hyphen_values = true)]
    pub field_mm: Vec<String>,
    /// Field point(s) as field angles `X,Y` in degrees (objects at infinity; chief-ray direction
    /// (tan X, tan Y, 1)); repeat for several.
    #[arg(long = "field-deg", allow_hyphen_values = true, conflicts_with = "field_mm")]
    pub field_deg: Vec<String>,
    /// Pupil sampling: chief, marginal, hexapolar:RINGS, grid:N, grid-step:STEP, random:N:SEED.
    #[arg(long, default_value = "hexapolar:12", conflicts_with = "pupil_csv")]
    pub pupil: String,
    /// Read normalised pupil coordinates from the `px,py` columns of a CSV (other columns and `#` lines ignored).
    #[arg(long = "pupil-csv")]
    pub pupil_csv: Option<PathBuf>,
    /// Trace the whole pupil of every field: ignore the system's vignetting factors (by default a defined
    /// field's pupil points are mapped by its factors, OpticStudio's VDX, VDY, VCX, VCY).
    #[arg(long = "full-pupil")]
    pub full_pupil: bool,
    /// Per-ray CSV: px,py,x_mm,y_mm,status (plus field and wavelength columns when several).
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// Statistics (and, for `trace`, rays) as JSON.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Spot diagram PNG.
    #[arg(long)]
    pub png: Option<PathBuf>,
}

#[derive(Args, Debug)]
pub struct DistortionArgs {
    #[command(flatten)]
    pub system: SystemArgs,
    #[command(flatten)]
    pub backend: BackendArgs,
    /// Wavelength (nm). Default: the primary wavelength.
    #[arg(long = "wavelength-nm")]
    pub wavelength_nm: Option<f64>,
    /// Grid points per side (odd numbers include the axis, like Zemax).
    #[arg(long, default_value_t = 13)]
    pub grid: usize,
    /// Half width of the square object field (mm; finite objects).
    #[arg(long = "half-width-mm", default_value_t = 2.5)]
    pub half_width_mm: f64,
    /// Half width of the square field in degrees, for an object at infinity (the grid is uniform in tan θ,
    /// a flat distant object). Default: the system's largest field angle.
    #[arg(long = "half-width-deg")]
    pub half_width_deg: Option<f64>,
    #[arg(long)]
    pub csv: Option<PathBuf>,
    #[arg(long)]
    pub json: Option<PathBuf>,
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Arrow magnification in the PNG.
    #[arg(long = "arrow-scale", default_value_t = 10.0, requires = "png")]
    pub arrow_scale: f64,
}

#[derive(Args, Debug)]
pub struct DispersionArgs {
    #[command(flatten)]
    pub system: SystemArgs,
    #[command(flatten)]
    pub backend: BackendArgs,
    /// Field point `X,Y` mm (default: the axis).
    #[arg(long = "field-mm", allow_hyphen_values = true)]
    pub field_mm: Option<String>,
    /// Field angles `X,Y` in degrees, for an object at infinity (default: the axis).
    #[arg(long = "field-deg", allow_hyphen_values = true, conflicts_with = "field_mm")]
    pub field_deg: Option<String>,
    /// Wavelengths: list or first:last:count (default: the paper's 28 bands, 450:650:28).
    #[arg(long = "wavelengths-nm", alias = "wavelength-nm", default_value = "450:650:28")]
    pub wavelengths_nm: String,
    #[arg(long)]
    pub csv: Option<PathBuf>,
    #[arg(long)]
    pub png: Option<PathBuf>,
}

#[derive(Args, Debug)]
pub struct MappingArgs {
    #[command(flatten)]
    pub system: SystemArgs,
    #[command(flatten)]
    pub backend: BackendArgs,
    #[arg(long, default_value_t = 512)]
    pub height: usize,
    #[arg(long, default_value_t = 512)]
    pub width: usize,
    /// Scene pixel pitch on the object plane (mm).
    #[arg(long = "pitch-mm", default_value_t = 0.01)]
    pub pitch_mm: f64,
    /// For an object at infinity: the scene's full angular extent across its width (degrees, (0, 180));
    /// pixels are uniform in field angle.
    #[arg(long = "scene-fov-deg", allow_hyphen_values = true)]
    pub scene_fov_deg: Option<f64>,
    /// Wavelengths: list or first:last:count.
    #[arg(long = "wavelengths-nm", default_value = "450:650:28")]
    pub wavelengths_nm: String,
    /// Output NPY, shape (H, W, Nλ, 2), detector (x, y) mm; a companion `<stem>_valid.npy` (u8, H×W×Nλ)
    /// flags rays that arrived.
    #[arg(long)]
    pub npy: PathBuf,
    /// Write float64 instead of float32.
    #[arg(long)]
    pub f64: bool,
    /// Float precision of the chief-ray trace: f64 (exact, the default) or f32 (the SIMD lanes in f32;
    /// error against f64 measured by `bench tradeoff`, see docs/performance.md).
    #[arg(long, value_name = "f64|f32", value_parser = <crate::tracer::Precision as std::str::FromStr>::from_str)]
    pub precision: Option<crate::tracer::Precision>,
    /// Where the chief rays are traced: cpu (the default), cuda / cuda:N (the GPU trace kernels on CUDA device
    /// 0 / N, in --precision; docs/gpu.md) or cpu-twin (the same kernels on the CPU: the device's numbers,
    /// slowly, where there is no GPU).
    #[arg(long, default_value = "cpu", value_name = "cpu|cuda[:N]|cpu-twin", value_parser = super::render::device_arg)]
    pub device: crate::render::Device,
}

#[derive(Args, Debug)]
pub struct ReportArgs {
    #[command(flatten)]
    pub system: SystemArgs,
    #[command(flatten)]
    pub backend: BackendArgs,
    /// Output folder (default out/report-<system>): new, empty, or a previous report (replaced whole).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Accept an --out folder that holds other files (not a previous output of this command): the outputs
    /// are moved in beside them, nothing else there is touched (docs/robustness.md, "Output policy").
    #[arg(long)]
    pub force: bool,
}

#[derive(Args, Debug)]
pub struct BenchArgs {
    /// `tradeoff`: the speed/accuracy frontier of every backend and model (CSV, table, PNG) instead of the
    /// rays/s table. `nonsequential`: sequential backends, mechanics queries brute force vs Embree, and the
    /// crossover triangle count (docs/nonsequential.md).
    #[arg(value_parser = ["tradeoff", "nonsequential"])]
    pub mode: Option<String>,
    #[arg(long, default_value = "sp")]
    pub preset: String,
    /// `nonsequential`: a spec file instead of --preset (its `[mechanics]` meshes are added to every row (c)).
    #[arg(long)]
    pub system: Option<PathBuf>,
    /// Backends to compare, comma-separated: analytic, embree-user[:f64|:none],
    /// embree-mesh[:SAG_UM][:f64|:none] (defaults f64 refinement, 1 µm) [default: analytic]. (Plain `bench`
    /// only: `tradeoff` and `nonsequential` run every backend and refuse it.)
    #[arg(long)]
    pub backends: Option<String>,
    /// Rays per wavelength [default: 100000]; `nonsequential`: row (a)'s rays per wavelength (not with
    /// --quick, which sets its own sizes); not with `tradeoff`.
    #[arg(long)]
    pub rays: Option<usize>,
    /// Number of wavelengths (450–650 nm), 1..=100000 [default: 28; `nonsequential`: 4].
    #[arg(long)]
    pub wavelengths: Option<usize>,
    /// Repetitions (the best is reported), 1..=1000 [default: 3; `tradeoff`: 3, 2 with --quick;
    /// `nonsequential`: 3, 1 with --quick].
    #[arg(long)]
    pub repeat: Option<usize>,
    /// `tradeoff`, `nonsequential`: write the rows as CSV.
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// `tradeoff`: write the frontier plot (PNG).
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// `tradeoff`, `nonsequential`: small workloads (under a minute on 2 cores); without it, the README's sizes.
    #[arg(long)]
    pub quick: bool,
    /// `nonsequential`: row (a), then the floor of Embree as the sequential tracer (the walk's own packet
    /// queries replayed with oracle or real callbacks, docs/nonsequential.md "Fourth pass") instead of
    /// rows (b), (c) and the crossover.
    #[arg(long)]
    pub floor: bool,
}

#[derive(Args, Debug)]
pub struct ExportArgs {
    #[command(flatten)]
    pub system: SystemArgs,
    /// Output .toml, .json or .zmx (the format follows the extension).
    #[arg(long)]
    pub out: PathBuf,
    /// The output format (toml, json, zmx); it must agree with --out's extension [default: the extension's].
    #[arg(long, value_parser = ["toml", "json", "zmx"])]
    pub format: Option<String>,
}
