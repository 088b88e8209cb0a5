//! Rendering a coded acquisition into a caller-visible buffer, no files: the scene cube (H×W×B f32,
//! C order [row][col][band], at the given band wavelengths) and the mask (H×W transmissions, or a random
//! binary mask from (opening, seed)) are read in place; the detector image (f64, row-major, the sizes
//! [`System::render_detector`] reports) is written into the caller's buffer.
//!
//! The options map onto `diffcassi::render::RenderConfig::paper(H)` with: scene H×W at
//! `scene_pitch_mm`, bands = the scene's wavelengths, `SpectralSampling::with_planes(bands, planes)`
//! (`planes` 0: 4 per band, the paper's), `rays_per_pixel`, stratified sampling, `seed`, detector pitch
//! `detector_pitch_mm`, Airy blur of `airy_diameter_px` at 520 nm when `airy`; for an object at infinity,
//! `scene_fov_deg` (the scene's angular extent across its width; 0 for a finite object), the kernel's
//! `precision` (`Auto`: f64). The image is `Renderer::render(..).image` of the Rust API, bit for bit.
//!
//! **A tolerance** (`tolerance_um` > 0, the CLI's `--tolerance-um`) chooses the backend, the rays per pixel
//! and the precision instead, as the CLI and Python do (`diffcassi::fidelity::RenderTracing`: the same
//! choice, calibrated on this system over the render's planes and field, cached in the folder of
//! [`set_calibration_cache`], by default where the CLI caches: `$DIFFCASSI_CACHE_DIR`, else
//! `$XDG_CACHE_HOME/diffcassi`, else `~/.cache/diffcassi`). What it chose is
//! in the returned [`RenderInfo`] (`tracer`, `rays_per_pixel`, `precision`, `predicted_error_um`). It needs
//! what it chooses left open: `rays_per_pixel` 0, `precision` `Auto`, the backend argument empty (the C++
//! wrappers' default; without a tolerance an empty backend is `analytic`).
//!
//! ```
//! let sys = diffcassi_cpp::load_preset("ap")?;
//! let mut o = diffcassi_cpp::default_render_options();
//! (o.planes, o.rays_per_pixel) = (3, 2);
//! let wl = [500.0, 520.0, 540.0];
//! let info = sys.render_detector("analytic", 4, 4, &wl, &o)?;
//! let mut image = vec![0.0; info.detector_height * info.detector_width];
//! let scene = vec![1.0f32; 4 * 4 * 3];
//! let done = sys.render("analytic", 4, 4, &wl, &scene, &[], &o, &mut image)?;
//! assert_eq!(done.rays_traced, done.rays_arrived);
//! assert!(image.iter().sum::<f64>() > 0.0);
//! let e = sys.render("analytic", 4, 4, &wl, &scene, &[], &o, &mut image[1..]).err().unwrap();
//! assert!(e.to_string().contains("output buffer"), "{e}");
//! # Ok::<(), diffcassi::Error>(())
//! ```
use crate::ffi::{RenderInfo, RenderOptions, RenderPrecision};
use crate::system::System;
use diffcassi::error::{Error, Result};
use diffcassi::fidelity::{CacheOptions, RenderTracing, TracerSource};
use diffcassi::render::{AiryConfig, Mask, RenderConfig, RenderSettings, Renderer, Sampling, SpectralSampling};
use diffcassi::scene::SpectralCube;
use diffcassi::tracer::{Precision, Tracer};

/// The paper's settings: 4 planes per band, 20 rays per pixel, seed 0, 10 µm scene and detector pixels,
/// Airy disk 2.5 px at 520 nm, random mask of opening 0.5 with seed 0.
pub fn default_render_options() -> RenderOptions {
    RenderOptions {
        planes: 0,
        rays_per_pixel: 20,
        seed: 0,
        scene_pitch_mm: 0.01,
        detector_pitch_mm: 0.01,
        airy: true,
        airy_diameter_px: 2.5,
        mask_opening: 0.5,
        mask_seed: 0,
        scene_fov_deg: 0.0,
        precision: RenderPrecision::Auto,
        tolerance_um: 0.0,
    }
}

/// The options' precision: `None` for `Auto`. Another value of the enum (a C++ caller can cast any
/// integer into it) is refused.
fn given_precision(o: &RenderOptions) -> Result<Option<Precision>> {
    match o.precision {
        RenderPrecision::Auto => Ok(None),
        RenderPrecision::F64 => Ok(Some(Precision::F64)),
        RenderPrecision::F32 => Ok(Some(Precision::F32)),
        other => Err(Error::invalid(format!("render: RenderOptions::precision {}: not Auto, F64 or F32", other.repr))),
    }
}

fn precision_of(p: Precision) -> RenderPrecision {
    match p {
        Precision::F64 => RenderPrecision::F64,
        Precision::F32 => RenderPrecision::F32,
    }
}

/// The calibration cache's folder set by [`set_calibration_cache`]; `None`: the default.
static CALIBRATION_CACHE: std::sync::Mutex<Option<std::path::PathBuf>> = std::sync::Mutex::new(None);

/// Set the folder of the tolerance's calibration cache for every following render (empty: the default
/// folder); refused when the path exists and is not a folder ([`CacheOptions::checked`]).
pub fn set_calibration_cache(dir: &str) -> Result<()> {
    crate::results::name_budgets();
    crate::system::no_nul("calibration cache", dir)?;
    let dir = (!dir.is_empty()).then(|| std::path::PathBuf::from(dir));
    CacheOptions::checked(dir.as_deref())?;
    *CALIBRATION_CACHE.lock().unwrap_or_else(|p| p.into_inner()) = dir;
    Ok(())
}

fn calibration_cache() -> Result<CacheOptions> {
    let dir = CALIBRATION_CACHE.lock().unwrap_or_else(|p| p.into_inner()).clone();
    CacheOptions::checked(dir.as_deref())
}

/// The tolerance of the options: `None` for 0; else finite and > 0 (as `--tolerance-um`).
fn tolerance(o: &RenderOptions) -> Result<Option<f64>> {
    let t = o.tolerance_um;
    if t == 0.0 {
        return Ok(None);
    }
    if !(t.is_finite() && t > 0.0) {
        return Err(Error::invalid(format!("render: RenderOptions::tolerance_um {}: must be finite and > 0 (0 for none)", diffcassi::limits::fmt_num(t))));
    }
    Ok(Some(t))
}

/// The Rust render settings the options describe.
pub fn render_config(height: usize, width: usize, wavelengths_nm: &[f64], o: &RenderOptions) -> Result<RenderConfig> {
    crate::system::checked_size("scene (height, width, bands)", &[height, width, wavelengths_nm.len()])?;
    // Every setting checked here, named as C++ sets it (the library's own refusals, `100001 spectral planes`,
    // `mask opening ratio NaN`, named none; round 15); the scene's wavelengths in the range the CLI and
    // Python take (1e9 nm was refused only by a glass's range).
    let fmt = diffcassi::limits::fmt_num;
    diffcassi::render::settings::check_wavelengths("--bands", wavelengths_nm)?;
    let max_planes = diffcassi::limits::MAX_PLANES;
    if o.planes > max_planes {
        return Err(Error::invalid(format!("render: RenderOptions::planes {}: must be at most {max_planes} (0: 4 per band)", o.planes)));
    }
    let planes = if o.planes == 0 { 4 * wavelengths_nm.len() } else { o.planes };
    let tolerance_um = tolerance(o)?;
    if o.rays_per_pixel == 0 && tolerance_um.is_none() {
        return Err(Error::invalid("render: RenderOptions::rays_per_pixel 0: must be ≥ 1 (0 only with RenderOptions::tolerance_um, which chooses the rays per pixel)"));
    }
    for (what, v) in [("RenderOptions::scene_pitch_mm", o.scene_pitch_mm), ("RenderOptions::detector_pitch_mm", o.detector_pitch_mm)] {
        if !(v.is_finite() && v > 0.0) {
            return Err(Error::invalid(format!("render: {what} {}: must be finite and > 0 (mm)", fmt(v))));
        }
    }
    let max_airy = diffcassi::limits::MAX_AIRY_DIAMETER_PX;
    if o.airy && !(o.airy_diameter_px.is_finite() && o.airy_diameter_px > 0.0 && o.airy_diameter_px <= max_airy) {
        return Err(Error::invalid(format!("render: RenderOptions::airy_diameter_px {}: the Airy diameter must be finite and in (0, {max_airy}] px", fmt(o.airy_diameter_px))));
    }
    if !(o.mask_opening.is_finite() && (0.0..=1.0).contains(&o.mask_opening)) {
        return Err(Error::invalid(format!("render: RenderOptions::mask_opening {}: the mask's opening ratio must be in [0, 1]", fmt(o.mask_opening))));
    }
    let mut cfg = RenderConfig::paper(height);
    cfg.scene_height = height;
    cfg.scene_width = width;
    cfg.scene_pitch_mm = o.scene_pitch_mm;
    cfg.detector_pitch_mm = o.detector_pitch_mm;
    cfg.spectral = SpectralSampling::with_planes(wavelengths_nm.to_vec(), planes)?;
    // A tolerance's rays are set and checked against the budget when it has chosen them.
    cfg.rays_per_pixel = o.rays_per_pixel.max(1);
    cfg.precision = given_precision(o)?.unwrap_or_default();
    if cfg.precision == Precision::F32 {
        cfg.precision.level(cfg.kernel)?; // the f32 lanes of the SIMD kernel (there is no scalar f32)
    }
    cfg.sampling = Sampling::Stratified;
    cfg.seed = o.seed;
    cfg.airy = o.airy.then_some(AiryConfig { diameter_px: o.airy_diameter_px, ..AiryConfig::default() });
    // 0 = a finite object; any other value (NaN included) is the angular extent, which the renderer checks
    // against the system (`render::scene_pitch_for`: in (0, 180) degrees, and only for an object at infinity).
    if o.scene_fov_deg != 0.0 {
        diffcassi::render::check_scene_fov_deg(o.scene_fov_deg)?;
        cfg.scene_fov_deg = Some(o.scene_fov_deg);
    }
    // The memory and ray budgets the CLI and Python check (1e5×1e5 scenes and 2⁴⁰ rays per pixel aborted the
    // process on allocation; a held-out battery, round 9).
    diffcassi::render::settings::check_render_budget(height, width, &cfg, cfg.rays_per_pixel)?;
    Ok(cfg)
}

/// The mask: the caller's transmissions (H×W, each in [0, 1]; at the 16-bit steps of `mask.png`, as every
/// front end takes a mask: [`Mask::at_png_steps`]) or, when `values` is empty, the random binary mask of the
/// options.
pub fn render_mask(height: usize, width: usize, values: &[f32], o: &RenderOptions) -> Result<Mask> {
    if values.is_empty() {
        return Mask::random(height, width, o.mask_opening, o.mask_seed);
    }
    if values.len() != height * width {
        return Err(Error::invalid(format!("render: the mask has {} values but the scene is {height}×{width}", values.len())));
    }
    if let Some(i) = values.iter().position(|v| !(0.0..=1.0).contains(v)) {
        return Err(Error::invalid(format!("render: mask value at row {}, col {} is {} (must be in [0, 1])", i / width, i % width, values[i])));
    }
    // At the 16-bit steps of mask.png, as the CLI reads a mask file and Python takes an array: the same
    // render from every front end (a greyscale mask rendered 3140 other pixels from C++; round 15).
    Ok(Mask { height, width, values: values.to_vec(), description: "caller-provided".into() }.at_png_steps())
}

fn info(r: &Renderer<'_>, tracing: &Tracing, traced: u64, arrived: u64) -> RenderInfo {
    RenderInfo {
        detector_height: r.detector.height,
        detector_width: r.detector.width,
        detector_pitch_mm: r.detector.pitch_mm,
        x_left_mm: r.detector.x_left_mm,
        y_top_mm: r.detector.y_top_mm,
        planes: r.config.spectral.planes(),
        rays_traced: traced,
        rays_arrived: arrived,
        tracer: r.tracer_name(),
        rays_per_pixel: r.config.rays_per_pixel,
        precision: precision_of(r.config.precision),
        predicted_error_um: tracing.predicted_error_um(),
        warnings: Vec::new(),
    }
}

/// A render's tracer: the backend named (from the system's cache of backends), or a tolerance's choice.
enum Tracing {
    Named(std::sync::Arc<dyn Tracer>),
    Chosen(RenderTracing),
}

impl Tracing {
    fn tracer(&self) -> &dyn Tracer {
        match self {
            Tracing::Named(t) => t.as_ref(),
            Tracing::Chosen(c) => c.tracer.as_ref(),
        }
    }

    fn predicted_error_um(&self) -> f64 {
        match self {
            Tracing::Named(_) => 0.0,
            Tracing::Chosen(c) => c.predicted_error_um.unwrap_or(0.0),
        }
    }
}

impl System {
    /// The tracer of a render with `options`, `cfg` its configuration: the backend named (an empty name is
    /// `analytic`), or, with a tolerance, the library's choice ([`RenderTracing::resolve`], which sets
    /// `cfg`'s rays per pixel and precision; it refuses rays or a precision given beside the tolerance).
    fn render_tracing(&self, backend: &str, options: &RenderOptions, cfg: &mut RenderConfig, mask: &Mask) -> Result<Tracing> {
        let Some(tolerance_um) = tolerance(options)? else {
            let name = if backend.is_empty() { "analytic" } else { backend };
            return Ok(Tracing::Named(self.backends.get(self.system(), name)?));
        };
        if !backend.is_empty() {
            return Err(Error::invalid(format!(
                "render: RenderOptions::tolerance_um {} chooses the backend itself; it cannot be combined with the backend `{backend}` (pass an empty backend)",
                diffcassi::limits::fmt_num(tolerance_um)
            )));
        }
        // What the tolerance chooses, as given (the checks of `resolve`); the rest of the settings are `cfg`'s.
        let settings = RenderSettings { rays: (options.rays_per_pixel != 0).then_some(options.rays_per_pixel), precision: given_precision(options)?, mapping: false, ..RenderSettings::default() };
        let source = TracerSource::Tolerance { tolerance_um, cache: calibration_cache()? };
        Ok(Tracing::Chosen(RenderTracing::resolve(source, self.system(), &settings, cfg, mask)?))
    }

    /// The detector a render with these settings produces (size the output buffer with it). Cheap
    /// relative to the render (chief rays of the scene's corners and edges only), deterministic; with a
    /// tolerance, the choice is made first (a calibration the first time, cached: see the module's docs).
    pub fn render_detector(&self, backend: &str, height: usize, width: usize, wavelengths_nm: &[f64], options: &RenderOptions) -> Result<RenderInfo> {
        // In this process's pool: a fresh one in a fork() child (diffcassi::pool).
        diffcassi::pool::install(|| {
            let mut cfg = render_config(height, width, wavelengths_nm, options)?;
            // A tolerance's choice weighs the rays the open pixels cost: those of the options' random mask (a
            // caller's mask may tip it to another backend, whose detector is the same but for Embree's f32 hits).
            let mask = if options.tolerance_um != 0.0 { render_mask(height, width, &[], options)? } else { Mask::open(height, width) };
            let tracing = self.render_tracing(backend, options, &mut cfg, &mask)?;
            let r = Renderer::new(self.system(), tracing.tracer(), cfg, mask)?;
            Ok(info(&r, &tracing, 0, 0))
        })
    }

    /// Render the coded acquisition of `scene` into `out` (detector height × width, row-major).
    #[allow(clippy::too_many_arguments)]
    pub fn render(
        &self,
        backend: &str,
        height: usize,
        width: usize,
        wavelengths_nm: &[f64],
        scene: &[f32],
        mask: &[f32],
        options: &RenderOptions,
        out: &mut [f64],
    ) -> Result<RenderInfo> {
        // In this process's pool: a fresh one in a fork() child (diffcassi::pool).
        diffcassi::pool::install(|| {
            let mut cfg = render_config(height, width, wavelengths_nm, options)?;
            let mask = render_mask(height, width, mask, options)?;
            let cube = SpectralCube::new(height, width, wavelengths_nm.to_vec(), scene.to_vec(), "render scene")?;
            // The radiance range the CLI and Python take (3.4e38 rendered inf, negative values negative pixels).
            diffcassi::render::settings::check_scene_values(&cube).map_err(|e| Error::invalid(format!("render: {e}")))?;
            let tracing = self.render_tracing(backend, options, &mut cfg, &mask)?;
            let r = Renderer::new(self.system(), tracing.tracer(), cfg, mask)?;
            let pixels = r.detector.pixels();
            if out.len() != pixels {
                return Err(Error::invalid(format!(
                    "render: the output buffer has {} values but the detector is {}×{} = {pixels} pixels (size it with render_detector)",
                    out.len(),
                    r.detector.height,
                    r.detector.width
                )));
            }
            let acq = r.render(&cube, false, &|_| {})?;
            out.copy_from_slice(&acq.image);
            let mut done = info(&r, &tracing, acq.stats.traced, acq.stats.arrived);
            // The CLI's warnings on this render (`render::folder`), spelled as C++ sets the settings: a zero
            // acquisition was returned in silence (round 15).
            let (notes, _) = diffcassi::render::folder::render_notes(&r, &cube, None)?;
            let zero = diffcassi::render::folder::zero_warning(&acq, &serde_json::Value::Null);
            done.warnings = zero.into_iter().chain(notes).map(|w| diffcassi::frontend::spell(&w, diffcassi::frontend::Frontend::Cpp).into_owned()).collect();
            Ok(done)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The library's refusals name the C++ settings (`RenderOptions::scene_fov_deg`), not the command line's
    /// options (`--scene-fov-deg`): the bridge declares itself the C++ front end (`diffcassi::frontend`) on its
    /// first call. An Airy diameter beyond the CLI's limit is named as such (it was a memory refusal).
    #[test]
    fn refusals_name_the_render_options() {
        let sys = crate::load_preset("sp").unwrap();
        let wl = [500.0, 520.0, 540.0];
        let (scene, mut image) = (vec![1.0f32; 4 * 4 * 3], vec![0.0; 1 << 12]);
        let mut refused = |f: &dyn Fn(&mut crate::ffi::RenderOptions)| {
            let mut o = crate::default_render_options();
            f(&mut o);
            sys.render("analytic", 4, 4, &wl, &scene, &[], &o, &mut image).err().unwrap().to_string()
        };
        let e = refused(&|o| o.scene_fov_deg = 1.0);
        assert!(e.contains("RenderOptions::scene_fov_deg 1: system `sp` has a finite object") && !e.contains("--"), "{e}");
        let e = refused(&|o| o.rays_per_pixel = 1 << 40);
        assert!(e.contains("raise max_rays (diffcassi::set_limits)") && !e.contains("--"), "{e}");
        let e = refused(&|o| o.airy_diameter_px = 1e9);
        assert!(e.contains("RenderOptions::airy_diameter_px 1e9: the Airy diameter must be finite and in (0, 100] px"), "{e}");
    }

    /// A tolerance renders what the library's choice renders (`RenderTracing::resolve`, the CLI's and
    /// Python's step), bit for bit, and the render's info says what it chose; the choice's calibration is
    /// cached in the folder set; an f32 precision is the f32 lanes' render.
    #[test]
    fn a_tolerance_renders_the_librarys_choice_and_says_what_it_chose() {
        use diffcassi::fidelity::{CacheOptions, RenderTracing, TracerSource};
        let dir = std::env::temp_dir().join(format!("diffcassi-cpp-cache-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        crate::set_calibration_cache(dir.to_str().unwrap()).unwrap();
        let sys = crate::load_preset("sp").unwrap();
        let (h, w, wl) = (6usize, 5usize, [500.0, 520.0, 540.0]);
        let scene: Vec<f32> = (0..h * w * 3).map(|q| 0.2 + (q % 7) as f32 * 0.1).collect();
        let mut o = crate::default_render_options();
        (o.planes, o.rays_per_pixel, o.tolerance_um) = (3, 0, 5.0);
        let d = sys.render_detector("", h, w, &wl, &o).unwrap();
        let mut image = vec![0.0; d.detector_height * d.detector_width];
        let got = sys.render("", h, w, &wl, &scene, &[], &o, &mut image).unwrap();
        assert!(std::fs::read_dir(&dir).unwrap().count() > 0, "no calibration cached in {}", dir.display());
        // The library's own step, on the same cache.
        let mut cfg = render_config(h, w, &wl, &o).unwrap();
        let mask = render_mask(h, w, &[], &o).unwrap();
        let source = TracerSource::Tolerance { tolerance_um: 5.0, cache: CacheOptions::checked(Some(&dir)).unwrap() };
        let settings = RenderSettings { rays: None, precision: None, mapping: false, ..RenderSettings::default() };
        let t = RenderTracing::resolve(source, sys.system(), &settings, &mut cfg, &mask).unwrap();
        let r = Renderer::new(sys.system(), t.tracer.as_ref(), cfg, mask).unwrap();
        let cube = SpectralCube::new(h, w, wl.to_vec(), scene.clone(), "s").unwrap();
        assert_eq!(image, r.render(&cube, false, &|_| {}).unwrap().image);
        assert_eq!((got.rays_per_pixel, got.precision, got.tracer.as_str()), (t.rays_per_pixel, precision_of(t.precision), r.tracer_name().as_str()));
        assert!(got.predicted_error_um > 0.0 && got.predicted_error_um <= 5.0, "{}", got.predicted_error_um);
        assert_eq!((d.detector_height, d.detector_width), (got.detector_height, got.detector_width));
        // Without a tolerance an empty backend is the analytic tracer; F32 its f32 lanes, recorded as such.
        (o.rays_per_pixel, o.tolerance_um, o.precision) = (2, 0.0, RenderPrecision::F32);
        let f32_info = sys.render("", h, w, &wl, &scene, &[], &o, &mut image).unwrap();
        assert_eq!((f32_info.tracer.as_str(), f32_info.precision, f32_info.rays_per_pixel, f32_info.predicted_error_um), ("analytic-f32", RenderPrecision::F32, 2, 0.0));
        // A file as the cache is refused, and the folder set stays.
        let file = dir.join("not-a-folder");
        std::fs::write(&file, b"x").unwrap();
        let e = crate::set_calibration_cache(file.to_str().unwrap()).err().unwrap().to_string();
        assert!(e.contains("not a directory"), "{e}");
        crate::set_calibration_cache("").unwrap();
        let _ = std::fs::remove_dir_all(&dir);
    }
}
