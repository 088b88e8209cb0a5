//! Rendering a coded acquisition into a caller-visible buffer, no files: the scene cube (H×W×B f32,
//! C order [row][col][band], at the given band wavelengths) and the mask (H×W transmissions, or a random
//! binary mask from (opening, seed)) are read in place; the detector image (f64, row-major, the sizes
//! [`System::render_detector`] reports) is written into the caller's buffer.
//!
//! The options map onto `diffcassi::render::RenderConfig::paper(H)` with: scene H×W at
//! `scene_pitch_mm`, bands = the scene's wavelengths, `SpectralSampling::with_planes(bands, planes)`
//! (`planes` 0: 4 per band, the paper's), `rays_per_pixel`, stratified sampling, `seed`, detector pitch
//! `detector_pitch_mm`, Airy blur of `airy_diameter_px` at 520 nm when `airy`; for an object at infinity,
//! `scene_fov_deg` (the scene's angular extent across its width; 0 for a finite object). The image is
//! `Renderer::render(..).image` of the Rust API, bit for bit.
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
use crate::ffi::{RenderInfo, RenderOptions};
use crate::system::System;
use diffcassi::error::{Error, Result};
use diffcassi::render::{AiryConfig, Mask, RenderConfig, Renderer, Sampling, SpectralSampling};
use diffcassi::scene::SpectralCube;

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
    }
}

/// The Rust render settings the options describe.
pub fn render_config(height: usize, width: usize, wavelengths_nm: &[f64], o: &RenderOptions) -> Result<RenderConfig> {
    crate::system::checked_size("scene (height, width, bands)", &[height, width, wavelengths_nm.len()])?;
    if wavelengths_nm.is_empty() {
        return Err(Error::invalid("render: no scene wavelengths"));
    }
    let planes = if o.planes == 0 { 4 * wavelengths_nm.len() } else { o.planes };
    if o.rays_per_pixel == 0 {
        return Err(Error::invalid("render: rays per pixel must be ≥ 1"));
    }
    for (what, v) in [("scene pitch", o.scene_pitch_mm), ("detector pitch", o.detector_pitch_mm)] {
        if !(v.is_finite() && v > 0.0) {
            return Err(Error::invalid(format!("render: {what} {v} mm must be finite and > 0")));
        }
    }
    let max_airy = diffcassi::limits::MAX_AIRY_DIAMETER_PX;
    if o.airy && !(o.airy_diameter_px.is_finite() && o.airy_diameter_px > 0.0 && o.airy_diameter_px <= max_airy) {
        return Err(Error::invalid(format!("render: Airy diameter {} px must be finite and in (0, {max_airy}]", diffcassi::limits::fmt_num(o.airy_diameter_px))));
    }
    let mut cfg = RenderConfig::paper(height);
    cfg.scene_height = height;
    cfg.scene_width = width;
    cfg.scene_pitch_mm = o.scene_pitch_mm;
    cfg.detector_pitch_mm = o.detector_pitch_mm;
    cfg.spectral = SpectralSampling::with_planes(wavelengths_nm.to_vec(), planes)?;
    cfg.rays_per_pixel = o.rays_per_pixel;
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
    diffcassi::render::settings::check_render_budget(height, width, &cfg, o.rays_per_pixel)?;
    Ok(cfg)
}

/// The mask: the caller's transmissions (H×W, each in [0, 1]) or, when `values` is empty, the random
/// binary mask of the options.
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
    Ok(Mask { height, width, values: values.to_vec(), description: "caller-provided".into() })
}

fn info(r: &Renderer<'_>, traced: u64, arrived: u64) -> RenderInfo {
    RenderInfo {
        detector_height: r.detector.height,
        detector_width: r.detector.width,
        detector_pitch_mm: r.detector.pitch_mm,
        x_left_mm: r.detector.x_left_mm,
        y_top_mm: r.detector.y_top_mm,
        planes: r.config.spectral.planes(),
        rays_traced: traced,
        rays_arrived: arrived,
    }
}

impl System {
    /// The detector a render with these settings produces (size the output buffer with it). Cheap
    /// relative to the render (chief rays of the scene's corners and edges only), deterministic.
    pub fn render_detector(&self, backend: &str, height: usize, width: usize, wavelengths_nm: &[f64], options: &RenderOptions) -> Result<RenderInfo> {
        let cfg = render_config(height, width, wavelengths_nm, options)?;
        let tracer = self.backends.get(self.system(), backend)?;
        let r = Renderer::new(self.system(), tracer.as_ref(), cfg, Mask::open(height, width))?;
        Ok(info(&r, 0, 0))
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
        let cfg = render_config(height, width, wavelengths_nm, options)?;
        let mask = render_mask(height, width, mask, options)?;
        let cube = SpectralCube::new(height, width, wavelengths_nm.to_vec(), scene.to_vec(), "render scene")?;
        // The radiance range the CLI and Python take (3.4e38 rendered inf, negative values negative pixels).
        diffcassi::render::settings::check_scene_values(&cube).map_err(|e| Error::invalid(format!("render: {e}")))?;
        let tracer = self.backends.get(self.system(), backend)?;
        let r = Renderer::new(self.system(), tracer.as_ref(), cfg, mask)?;
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
        Ok(info(&r, acq.stats.traced, acq.stats.arrived))
    }
}

#[cfg(test)]
mod tests {
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
        assert!(e.contains("Airy diameter 1e9 px must be finite and in (0, 100]"), "{e}");
    }
}
