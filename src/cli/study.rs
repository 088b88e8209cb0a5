//! `study`: the reference paper's four-system experiment, end to end. Every scene is rendered through every
//! system with one mask, reconstructed with every operator and solver, and evaluated against the scene:
//!
//! ```text
//! diffcassi study --presets ap,sp,map,msp --operators exact,mapping,shift --scenes data/scenes --scene-size 128 --out out/study
//! diffcassi study --synthetic 2 --scene-size 24 --presets ap,sp --planes 28 --rays 4 --iterations 5 --out out/tiny
//! diffcassi study --synthetic 2 --presets sp --systems my_cassi.toml,lens.zmx --scene-fov-deg 6 --out out/mine
//! ```
//!
//! The pipeline — systems, scenes, the folder layout, what a resumed study reuses, the tables — is the
//! library's [`crate::study`] (its module docs); this module parses the options into its
//! [`StudySettings`](crate::study::StudySettings) and draws the progress bars.
use super::bars::{bar, BarSlot};
use super::reconstruct::SolverTuning;
use crate::error::Result;
use crate::recon::pipeline::NoiseModel;
use crate::study::{StudyProgress, StudySettings};
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug, Clone)]
pub struct StudyArgs {
    /// Systems (presets), comma-separated [default: ap,sp,map,msp, unless --systems is given].
    #[arg(long)]
    pub presets: Option<String>,
    /// System files, comma-separated (or repeated): .toml/.json (our spec), .yml/.yaml, .csv or .zmx, read as
    /// `--system` elsewhere; each row is labelled by its file stem (`lens.zmx` → `lens`), unique among the systems.
    #[arg(long, value_delimiter = ',')]
    pub systems: Vec<PathBuf>,
    /// Extra AGF glass catalogue(s) for the `--systems` files, comma-separated (or repeated), loaded after each
    /// file's own catalogues as `--glass-catalog` elsewhere (recorded in each file's resolved spec).
    #[arg(long = "glass-catalog", value_delimiter = ',')]
    pub glass_catalogs: Vec<PathBuf>,
    /// For the systems whose object is at infinity: the scenes' full angular extent across their width (degrees,
    /// in (0, 180)), as `render --scene-fov-deg`; refused when no system of the study has its object at infinity.
    #[arg(long = "scene-fov-deg", allow_hyphen_values = true)]
    pub scene_fov_deg: Option<f64>,
    /// Operators, comma-separated: exact, mapping (bilinear), mapping-nearest, shift.
    #[arg(long, default_value = "exact,mapping,shift")]
    pub operators: String,
    /// Solvers, comma-separated: gap-tv, admm-tv, pnp-gap, pnp-admm, unrolled (the unrolled network: the
    /// committed weights of each system, sp and msp, or --weights for one system).
    #[arg(long, default_value = "gap-tv")]
    pub solvers: String,
    /// Folder of scenes: RGB .png photographs (uplifted to spectra), .npy/.exr cubes, CAVE-style PNG folders.
    #[arg(long, conflicts_with = "synthetic")]
    pub scenes: Option<PathBuf>,
    /// Use N synthetic scenes (seeds 0..N) instead of --scenes.
    #[arg(long)]
    pub synthetic: Option<usize>,
    /// Wavelengths (nm) of the scene files' bands (list or first:last:count), overriding what the files say
    /// (e.g. KAIST EXRs whose channel names carry no wavelength); for RGB photographs, the wavelengths they are
    /// uplifted at, as `render --scene-wavelengths` [default for them: the render bands].
    #[arg(long = "scene-wavelengths")]
    pub scene_wavelengths: Option<String>,
    /// Scene side (pixels of 10 µm on a finite object plane; at infinity --scene-fov-deg / S each); scenes are
    /// brought to S×S by --fit.
    #[arg(long = "scene-size", default_value_t = 128)]
    pub scene_size: usize,
    /// crop (centre) or resize (area average, then centre crop).
    #[arg(long, default_value = "resize", conflicts_with = "synthetic")]
    pub fit: String,
    /// Bands: list or first:last:count (nm).
    #[arg(long, default_value = "450:650:28")]
    pub bands: String,
    /// Spectral planes of the render (112 = 28 × 4, the paper's).
    #[arg(long, default_value_t = 112)]
    pub planes: usize,
    /// Rays per scene pixel per plane.
    #[arg(long, default_value_t = 20)]
    pub rays: usize,
    /// Acquisition ray seed (the exact operator uses seed + 1).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Mask file ((H, W) NPY or PNG, e.g. ../shared/reference/paper_mask_512.npy), centre-cropped to the scene size;
    /// default a random binary mask of --opening.
    #[arg(long, conflicts_with_all = ["opening", "mask_seed"])]
    pub mask: Option<PathBuf>,
    #[arg(long, default_value_t = 0.5)]
    pub opening: f64,
    #[arg(long = "mask-seed", default_value_t = 0)]
    pub mask_seed: u64,
    /// Airy disk diameter (pixels) at 520 nm.
    #[arg(long = "airy-diameter-px", default_value_t = 2.5)]
    pub airy_diameter_px: f64,
    #[command(flatten)]
    pub tuning: SolverTuning,
    /// Light-transport memory budget (GB) for the renders and the exact operator.
    #[arg(long = "transport-memory-gb", default_value_t = 4.0)]
    pub transport_memory_gb: f64,
    /// Output folder: new, empty, or a previous study (it holds study.json; resumed); never an input (--scenes, --mask,
    /// --denoiser), inside one or containing one.
    #[arg(long)]
    pub out: PathBuf,
    /// Accept an --out folder that holds other files (not a previous study): the study's files are written
    /// beside them, nothing else there is touched (docs/robustness.md, "Output policy").
    #[arg(long)]
    pub force: bool,
}

impl StudyArgs {
    /// The library's settings these options describe.
    pub fn settings(&self) -> Result<StudySettings> {
        let mut tuning = self.tuning.settings("", self.tuning.accelerated);
        tuning.noise_model = None;
        Ok(StudySettings {
            presets: self.presets.clone(),
            systems: self.systems.clone(),
            glass_catalogs: self.glass_catalogs.clone(),
            scene_fov_deg: self.scene_fov_deg,
            operators: self.operators.clone(),
            solvers: self.solvers.clone(),
            scenes: self.scenes.clone(),
            synthetic: self.synthetic,
            scene_wavelengths: self.scene_wavelengths.clone(),
            scene_size: self.scene_size,
            fit: self.fit.clone(),
            bands: self.bands.clone(),
            planes: self.planes,
            rays: self.rays,
            seed: self.seed,
            mask: self.mask.clone(),
            opening: self.opening,
            mask_seed: self.mask_seed,
            airy_diameter_px: self.airy_diameter_px,
            tuning,
            noise_estimate: self.tuning.noise_estimate.as_deref().map(|n| NoiseModel::parse("--noise-estimate", n)).transpose()?,
            transport_memory_gb: self.transport_memory_gb,
            out: self.out.clone(),
            force: self.force,
        })
    }
}

/// The study's progress as bars on the terminal (one at a time), its lines printed above them.
struct Bars(BarSlot);

impl StudyProgress for Bars {
    fn line(&self, text: &str) {
        println!("{text}");
    }
    fn warning(&self, text: &str) {
        eprintln!("warning: {text}");
    }
    fn transport_started(&self, what: &str, rays: u64) {
        self.0.show(bar(rays, "{msg} [{elapsed_precise}] {wide_bar} {human_pos}/{human_len} rays, ETA {eta}", what));
    }
    fn rays(&self, n: u64) {
        self.0.with(|pb| pb.inc(n));
    }
    fn transport_done(&self) {
        self.0.clear();
    }
    fn cells_started(&self, what: &str, cells: u64) {
        self.0.show(bar(cells, "{msg} [{elapsed_precise}] {wide_bar} {pos}/{len} cells, ETA {eta}", what));
    }
    fn cell_done(&self, line: &str) {
        let shown = self.0.with(|pb| {
            pb.println(line);
            pb.inc(1);
        });
        if shown.is_none() {
            println!("{line}");
        }
    }
    fn cells_done(&self) {
        self.0.clear();
    }
}

pub fn study(a: StudyArgs) -> Result<()> {
    let done = crate::study::run(&a.settings()?, &Bars(BarSlot::default()))?;
    println!("study: {} cells computed, {} already done; {:.1} s → {}", done.computed, done.skipped, done.seconds, done.table.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        study: StudyArgs,
    }

    /// The command line's defaults are the library's (one place for them: `StudySettings::new`).
    #[test]
    fn defaults_are_the_librarys() {
        let a = Cli::try_parse_from(["study", "--out", "x"]).unwrap().study;
        let (s, d) = (a.settings().unwrap(), StudySettings::new("x"));
        assert_eq!(format!("{s:?}"), format!("{d:?}"));
        let a = Cli::try_parse_from(["study", "--out", "x", "--noise-estimate", "model", "--accelerated", "--no-equivariant"]).unwrap().study;
        let s = a.settings().unwrap();
        assert_eq!((s.noise_estimate, s.tuning.accelerated, s.tuning.equivariant), (Some(NoiseModel::Model), true, Some(false)));
    }
}
