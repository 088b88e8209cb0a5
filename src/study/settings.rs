//! What a study runs: [`StudySettings`] (every option of `diffcassi study`, with the library's defaults) and
//! the checks and per-cell settings derived from it.
//!
//! ```
//! use diffcassi::study::StudySettings;
//! let s = StudySettings { synthetic: Some(2), scene_size: 24, presets: Some("ap,sp".into()), planes: 28, rays: 4, ..StudySettings::new("out/tiny") };
//! assert_eq!(s.operators, "exact,mapping,shift"); // the paper's three forward models
//! assert_eq!(s.bands, "450:650:28");
//! ```
use crate::error::{Error, Result};
use crate::recon::pipeline::{is_unrolled, NoiseModel, SolveSettings};
use crate::render::{AiryConfig, Mask, RenderConfig, SpectralSampling};
use crate::scene::{synthetic_wavelengths, Fit};
use std::path::PathBuf;

/// The systems of a study given neither presets nor files: the paper's four.
pub const DEFAULT_PRESETS: &str = "ap,sp,map,msp";

/// Every setting of a study. Lists are comma lists as the command line takes them (`"exact,shift"`), so the
/// errors quote what was given; [`StudySettings::new`] holds the defaults (those of `diffcassi study`).
#[derive(Clone, Debug)]
pub struct StudySettings {
    /// Systems (presets), comma-separated [default: ap,sp,map,msp, unless `systems` is given].
    pub presets: Option<String>,
    /// System files (.toml/.json, .yml/.yaml, .csv, .zmx); each row is labelled by its file stem.
    pub systems: Vec<PathBuf>,
    /// Extra AGF glass catalogues for the `systems` files, loaded after each file's own catalogues.
    pub glass_catalogs: Vec<PathBuf>,
    /// For systems whose object is at infinity: the scenes' full angular extent across their width (degrees).
    pub scene_fov_deg: Option<f64>,
    /// Operators, comma-separated: exact, mapping (bilinear), mapping-nearest, shift.
    pub operators: String,
    /// Solvers, comma-separated: gap-tv, admm-tv, pnp-gap, pnp-admm, unrolled.
    pub solvers: String,
    /// Folder of scenes (RGB photographs, .npy/.exr cubes, CAVE-style PNG folders); or `synthetic`.
    pub scenes: Option<PathBuf>,
    /// N synthetic scenes (seeds 0..N) instead of `scenes`.
    pub synthetic: Option<usize>,
    /// Wavelengths (nm) of the scene files' bands (list or first:last:count), overriding what the files say.
    pub scene_wavelengths: Option<String>,
    /// Scene side (pixels of 10 µm on a finite object plane; at infinity scene_fov_deg / S each).
    pub scene_size: usize,
    /// How scene files are brought to the scene size: crop (centre) or resize (area average, then crop).
    pub fit: String,
    /// Bands: list or first:last:count (nm).
    pub bands: String,
    /// Spectral planes of the render (112 = 28 × 4, the paper's).
    pub planes: usize,
    /// Rays per scene pixel per plane.
    pub rays: usize,
    /// Acquisition ray seed (the exact operator uses seed + 1).
    pub seed: u64,
    /// Mask file ((H, W) NPY or PNG), centre-cropped to the scene size; default a random binary mask of
    /// `opening` drawn with `mask_seed`.
    pub mask: Option<PathBuf>,
    pub opening: f64,
    pub mask_seed: u64,
    /// Airy disk diameter (pixels) at 520 nm.
    pub airy_diameter_px: f64,
    /// The solvers' settings (`solver`, `noise`, `noise_model` and `unrolled` are set per cell; `accelerated`
    /// and `plain` apply to gap-tv, the PnP options to the PnP solvers, `weights` to unrolled).
    pub tuning: SolveSettings,
    /// How the exact operator's Monte-Carlo term of δ is estimated (`None`: spread, the default).
    pub noise_estimate: Option<NoiseModel>,
    /// Light-transport memory budget (GB) for the renders and the exact operator.
    pub transport_memory_gb: f64,
    /// Output folder: new, empty, or a previous study (resumed); never an input.
    pub out: PathBuf,
    /// Accept an `out` folder that holds other files (not a previous study).
    pub force: bool,
}

impl StudySettings {
    /// The defaults (the paper's study: SP/AP/mSP/mAP, exact/mapping/shift, GAP-TV, 128², 28 bands × 4
    /// planes, 20 rays, a random mask of opening 0.5) writing to `out`; give `scenes` or `synthetic`.
    pub fn new(out: impl Into<PathBuf>) -> Self {
        StudySettings {
            presets: None,
            systems: Vec::new(),
            glass_catalogs: Vec::new(),
            scene_fov_deg: None,
            operators: "exact,mapping,shift".into(),
            solvers: "gap-tv".into(),
            scenes: None,
            synthetic: None,
            scene_wavelengths: None,
            scene_size: 128,
            fit: "resize".into(),
            bands: "450:650:28".into(),
            planes: 112,
            rays: 20,
            seed: 0,
            mask: None,
            opening: 0.5,
            mask_seed: 0,
            airy_diameter_px: 2.5,
            tuning: SolveSettings::new(""),
            noise_estimate: None,
            transport_memory_gb: crate::recon::pipeline::TRANSPORT_MEMORY_GB,
            out: out.into(),
            force: false,
        }
    }
}

/// A comma list of `--{what}`: no empty entry (a stray comma), no entry twice.
pub fn split_list(s: &str, what: &str) -> Result<Vec<String>> {
    let v: Vec<String> = s.split(',').map(|x| x.trim().to_string()).collect();
    if v.iter().all(String::is_empty) {
        return Err(Error::invalid(format!("--{what} is empty")));
    }
    // An empty entry (`gap-tv,`, `a,,b`) is a typo: refused rather than skipped.
    if v.iter().any(String::is_empty) {
        return Err(Error::invalid(format!("--{what} `{s}` has an empty entry (a stray comma)")));
    }
    let mut seen = v.clone();
    seen.sort();
    seen.dedup();
    if seen.len() != v.len() {
        return Err(Error::invalid(format!("--{what} `{s}` lists an entry twice")));
    }
    Ok(v)
}

/// The mask every render of the study uses: `mask` centre-cropped to the scene size, or a random binary one.
pub(super) fn study_mask(a: &StudySettings) -> Result<Mask> {
    let n = a.scene_size;
    match &a.mask {
        None => Mask::random(n, n, a.opening, a.mask_seed),
        Some(p) => {
            let m = Mask::load(p)?;
            if m.height < n || m.width < n {
                return Err(Error::File { path: p.display().to_string(), message: format!("the mask is {}×{}, smaller than the {n}×{n} scenes", m.height, m.width) });
            }
            let (r0, c0) = ((m.height - n) / 2, (m.width - n) / 2);
            let values = (0..n).flat_map(|r| m.values[(r0 + r) * m.width + c0..(r0 + r) * m.width + c0 + n].to_vec()).collect();
            Ok(Mask { height: n, width: n, values, description: format!("{} (centre {n}×{n} of {}×{})", m.description, m.height, m.width) })
        }
    }
}

/// The limits `render` applies (same messages), checked before any scene is loaded or generated: planes,
/// Airy diameter, opening, the memory of the renders and of the study's scenes held together, and the ray
/// budget of each render; `--fit`, `--transport-memory-gb` and `--accelerated` validated so none is ignored.
pub(super) fn check_limits(a: &StudySettings, bands: &[f64], solvers: &[String]) -> Result<()> {
    let n = a.scene_size;
    Fit::parse(&a.fit)?;
    if a.planes == 0 || a.planes > crate::limits::MAX_PLANES {
        return Err(Error::invalid(format!("--planes {}: must be in 1..={}", a.planes, crate::limits::MAX_PLANES)));
    }
    if !(a.airy_diameter_px.is_finite() && a.airy_diameter_px > 0.0 && a.airy_diameter_px <= crate::limits::MAX_AIRY_DIAMETER_PX) {
        return Err(Error::invalid(format!("--airy-diameter-px {}: must be in (0, {}] pixels", a.airy_diameter_px, crate::limits::MAX_AIRY_DIAMETER_PX)));
    }
    if !(a.opening.is_finite() && (0.0..=1.0).contains(&a.opening)) {
        return Err(Error::invalid(format!("--opening {}: the mask's opening ratio must be in [0, 1]", a.opening)));
    }
    if a.opening == 0.0 && a.mask.is_none() {
        // A closed mask lets no light through: every acquisition is black, every reconstruction fails (it did so
        // after the renders).
        return Err(Error::invalid("--opening 0: a closed mask lets no light through, so there is nothing to reconstruct; give an opening in (0, 1]"));
    }
    if !(a.transport_memory_gb.is_finite() && a.transport_memory_gb >= 0.0) {
        return Err(Error::invalid(format!("--transport-memory-gb {}: must be finite and ≥ 0 (0: never keep the transport)", a.transport_memory_gb)));
    }
    if a.tuning.plain && !solvers.iter().any(|s| s == "gap-tv") {
        return Err(Error::invalid(format!("--plain applies to gap-tv only, and --solvers `{}` has no gap-tv", a.solvers)));
    }
    if a.tuning.accelerated && !solvers.iter().any(|s| s == "gap-tv") {
        return Err(Error::invalid(format!("--accelerated applies to gap-tv only, and --solvers `{}` has no gap-tv", a.solvers)));
    }
    if a.rays == 0 {
        return Err(Error::invalid("--rays must be ≥ 1"));
    }
    if a.synthetic.is_some() && a.scene_wavelengths.is_some() {
        return Err(Error::invalid("--scene-wavelengths applies to the files of --scenes, not to --synthetic scenes"));
    }
    if let Some(k) = a.synthetic {
        if k > crate::limits::MAX_SCENES {
            return Err(Error::invalid(format!("--synthetic {k}: must be in 1..={}", crate::limits::MAX_SCENES)));
        }
    }
    // Every scene's fitted cube is held for the whole study (its truth), beside one render.
    let scene_bands = synthetic_wavelengths().len().max(bands.len());
    let scenes = a.synthetic.unwrap_or(1);
    let what = format!("--scene-size {n} × --planes {} (× {} bands, {scenes} scenes)", a.planes, bands.len());
    crate::limits::check_memory(&what, crate::limits::bytes_render(n, scene_bands, bands.len(), a.planes, false, Some(a.airy_diameter_px)) + scenes as f64 * crate::limits::bytes_cube(n, n, scene_bands))?;
    crate::render::settings::check_render_rays(n, a.planes, a.rays)
}

/// The render configuration of the study.
pub(super) fn render_config(a: &StudySettings, bands: &[f64]) -> Result<RenderConfig> {
    let mut cfg = RenderConfig::paper(a.scene_size);
    cfg.spectral = SpectralSampling::with_planes(bands.to_vec(), a.planes)?;
    cfg.rays_per_pixel = a.rays;
    cfg.seed = a.seed;
    cfg.airy = Some(AiryConfig { diameter_px: a.airy_diameter_px, ..AiryConfig::default() });
    Ok(cfg)
}

/// The settings of one solver of the study: `--accelerated` applies to gap-tv only, the PnP options
/// (`--denoiser`, `--sigma-max`, `--sigma-min`) to the PnP solvers only.
pub(super) fn cell_settings(a: &StudySettings, solver: &str) -> SolveSettings {
    let mut s = a.tuning.clone();
    s.solver = solver.to_string();
    (s.accelerated, s.plain) = (a.tuning.accelerated && solver == "gap-tv", a.tuning.plain && solver == "gap-tv");
    (s.noise, s.unrolled) = (None, None);
    // Given or not, as the study's option (the unrolled network takes none: it has no δ).
    s.noise_model = if is_unrolled(solver) { None } else { a.noise_estimate };
    if !solver.parse::<crate::recon::SolverKind>().is_ok_and(|k| k.is_pnp()) {
        (s.denoiser, s.sigma_max, s.sigma_min, s.tv_warmup, s.sigma_auto, s.equivariant, s.equivariant_seed) = (None, None, None, None, false, None, None);
    }
    if is_unrolled(solver) {
        // The iterative solvers' options apply to them only.
        (s.iterations, s.tv_weight, s.tolerance, s.discrepancy, s.accelerated, s.plain) = (None, None, None, None, false, false);
    } else {
        s.weights = None;
    }
    s
}

/// An option that no solver of `--solvers` takes is refused: each cell drops the options of other solvers
/// ([`cell_settings`]), so with none of its solvers listed it would be ignored by every cell (e.g.
/// `--iterations` with `--solvers unrolled`, whose stages are fixed).
pub(super) fn check_options_apply(a: &StudySettings, solvers: &[String]) -> Result<()> {
    use crate::recon::solver::SettingScope;
    // --accelerated and --plain are checked against gap-tv in `check_limits` (the study applies them to it only).
    let mut given = a.tuning.clone();
    (given.accelerated, given.plain) = (false, false);
    for (key, flag) in given.given() {
        let scope = SettingScope::of(key);
        if !solvers.iter().any(|s| s.parse::<crate::recon::SolverKind>().is_ok_and(|k| scope.contains(k))) {
            let takes = if scope == SettingScope::Every { "the iterative solvers (gap-tv, admm-tv, pnp-gap, pnp-admm; unrolled has a fixed number of stages)" } else { scope.solvers() };
            return Err(Error::invalid(format!("{flag}: applies to {takes}, and --solvers `{}` has none of them", a.solvers)));
        }
    }
    Ok(())
}

