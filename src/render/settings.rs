//! Render settings in one place: what a render, a dataset render or a traced operator takes (scene size,
//! bands, planes, rays, sampling, mask, Airy blur, scene fit, kernel, precision, device, sensor noise), its
//! defaults (the paper's), its limits and its validation. Front ends fill a [`RenderSettings`] (starting
//! from [`RenderSettings::default`]) and call [`RenderSettings::config`]: the command line converts its
//! options into it (`render`, `render-dataset`), the Python bindings their keywords. Messages name each
//! setting by its command-line spelling (`--planes 0: …`); the Python keywords have the same names.
//!
//! ```
//! use diffcassi::render::settings::{Device, RenderSettings};
//! let mut s = RenderSettings { scene_size: 16, planes: 8, rays: Some(2), ..RenderSettings::default() };
//! let (cfg, mask) = s.config()?;
//! assert_eq!((cfg.scene_height, cfg.spectral.planes(), mask.width), (16, 8, 16));
//! s.device = Device::Cuda(0);
//! assert!(s.config().unwrap_err().to_string().contains("--device cuda: ")); // no launcher (or driver) here
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::{AiryConfig, Mask, NoiseConfig, RenderConfig, Sampling, SpectralSampling};
use crate::error::{Error, Result};
use crate::scene::{Fit, SpectralCube};
use crate::tracer::{Kernel, Precision};
use std::path::PathBuf;

/// Rays per scene pixel per plane when none are given (and no fidelity tolerance chooses them).
pub const DEFAULT_RAYS: usize = 20;

/// Where a render runs, chosen in one place for every front end. `Cuda(N)` is the GPU backend (docs/gpu.md):
/// the kernels tested through their CPU twin, launched on CUDA device N ([`super::device::render_for`]),
/// spelt as torch spells it — `cuda` (device 0) or `cuda:N`, N counting the devices the driver shows after
/// `CUDA_VISIBLE_DEVICES`; [`Device::check`] refuses it, before anything is written, with what is missing
/// (the driver, that device, or kernels the driver could load: [`crate::gpu::require_cuda`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Device {
    #[default]
    Cpu,
    /// CUDA device N.
    Cuda(usize),
    /// The GPU kernels run on the CPU (their host twin): the device's arithmetic and bits, slowly — to check
    /// a GPU's results where there is none.
    CpuTwin,
}

impl Device {
    /// Why this build cannot render on the device (`None`: it can): for `Cuda`, what is missing — the NVIDIA
    /// driver, the device, or kernels it can load ([`crate::gpu::require_cuda`]).
    pub fn unavailable(self) -> Option<String> {
        match self {
            Device::Cpu | Device::CpuTwin => None,
            Device::Cuda(n) => crate::gpu::require_cuda(n).err().map(|e| e.to_string()),
        }
    }

    /// `Ok` for a device this build can render on; otherwise an error naming `--device` and what is missing.
    pub fn check(self) -> Result<()> {
        match self.unavailable() {
            None => Ok(()),
            Some(why) => Err(Error::invalid(format!("--device {self}: {why}; use --device cpu"))),
        }
    }

    /// The tracer of a command's own batches of rays (the chief-ray cube of `mapping`) on this device, in
    /// `precision`: the analytic tracer on the CPU, the GPU kernels' host twin on `CpuTwin`, and on `Cuda`
    /// the same kernels launched on the device ([`crate::gpu::CudaTracer`]; an error naming what is missing,
    /// via [`Device::check`], where there is none).
    pub fn tracer(self, precision: Precision) -> Result<Box<dyn crate::tracer::Tracer>> {
        match self {
            Device::Cpu => precision.tracer(Kernel::default()),
            Device::CpuTwin => Ok(Box::new(crate::gpu::TwinTracer { precision, ..Default::default() })),
            Device::Cuda(ordinal) => {
                self.check()?;
                Ok(Box::new(crate::gpu::CudaTracer { precision, ordinal }))
            }
        }
    }

    /// The kind of device: `cpu`, `cuda` (any ordinal) or `cpu-twin`; [`Device`]'s `Display` adds the ordinal.
    pub fn kind(self) -> &'static str {
        match self {
            Device::Cpu => "cpu",
            Device::Cuda(_) => "cuda",
            Device::CpuTwin => "cpu-twin",
        }
    }

    /// A GPU device (`cuda`, `cuda:N`).
    pub fn is_cuda(self) -> bool {
        matches!(self, Device::Cuda(_))
    }
}

impl std::str::FromStr for Device {
    type Err = Error;
    /// `cpu`, `cuda` (device 0), `cuda:N` (N a decimal ordinal < [`crate::gpu::device::MAX_DEVICES`]) or
    /// `cpu-twin`.
    fn from_str(s: &str) -> Result<Self> {
        Device::parse_value(s).map_err(|why| Error::invalid(format!("--device `{s}`: {why}")))
    }
}

impl Device {
    /// [`FromStr`](std::str::FromStr)'s parse, its error the reason alone (the command line's parser, whose
    /// message clap prefixes with the option and the value).
    pub fn parse_value(s: &str) -> std::result::Result<Self, String> {
        let max = crate::gpu::device::MAX_DEVICES;
        // As torch reads device strings, and as Python's render refused them: `" cpu"` was taken by the CLI and
        // `mapping`, refused by `render` (round 15).
        if s.trim() != s {
            return Err("no spaces around it: use cpu, cuda or cuda:N (or cpu-twin)".into());
        }
        match s {
            "cpu" => Ok(Device::Cpu),
            "cuda" => Ok(Device::Cuda(0)),
            "cpu-twin" => Ok(Device::CpuTwin),
            t if t.starts_with("cuda:") => match t["cuda:".len()..].parse::<usize>() {
                // Decimal digits without a leading zero, as torch reads device strings (`cuda:01` is refused there too).
                Ok(n) if n < max && t["cuda:".len()..].bytes().all(|b| b.is_ascii_digit()) && !(t.len() > "cuda:".len() + 1 && t.as_bytes()["cuda:".len()] == b'0') => Ok(Device::Cuda(n)),
                Ok(n) if n >= max => Err(format!("device ordinal {n}: at most {max} CUDA devices (cuda:0 … cuda:{}) are supported", max - 1)),
                _ => Err("after `cuda:` give a device ordinal (0, 1, …, no leading zero), e.g. cuda:1".into()),
            },
            _ => Err("use cpu, cuda or cuda:N (or cpu-twin: the GPU kernels on the CPU)".into()),
        }
    }
}

impl std::fmt::Display for Device {
    /// `cpu`, `cuda` (device 0), `cuda:N` or `cpu-twin`: what [`FromStr`](std::str::FromStr) reads back.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Device::Cuda(n) if *n > 0 => write!(f, "cuda:{n}"),
            d => f.write_str(d.kind()),
        }
    }
}

/// The mask of a render: a random binary mask or a file (greyscale PNG or (H, W) NPY). One or the other,
/// so a front end cannot give both a file and a random mask's opening.
#[derive(Clone, Debug, PartialEq)]
pub enum MaskSource {
    /// Binary, each pixel open with probability `opening` ∈ [0, 1], from the stream seeded with `seed`.
    Random { opening: f64, seed: u64 },
    File(PathBuf),
}

/// Everything a render takes besides the system, the tracer and the scene. See the module docs.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderSettings {
    /// Scene side N (pixels of 10 µm on the object plane); scenes are brought to N×N by [`Self::fit`].
    pub scene_size: usize,
    /// Render bands (nm).
    pub bands_nm: Vec<f64>,
    /// Spectral planes over the bands' range (112 = 28 bands × 4, the paper's).
    pub planes: usize,
    /// Rays per scene pixel per plane; `None`: [`DEFAULT_RAYS`] (or chosen by a fidelity tolerance).
    pub rays: Option<usize>,
    /// Seed of the rays' random numbers.
    pub seed: u64,
    pub sampling: Sampling,
    pub mask: MaskSource,
    /// Airy disk diameter (pixels) at 520 nm, ∝ λ; `None`: no diffraction blur.
    pub airy_diameter_px: Option<f64>,
    /// Wavelengths (nm) of a scene file's bands, overriding what the file says.
    pub scene_wavelengths_nm: Option<Vec<f64>>,
    /// How scene files are brought to N×N.
    pub fit: Fit,
    /// Also keep the detector image of each band.
    pub cube: bool,
    /// f64 ray kernel of the analytic backend.
    pub kernel: Kernel,
    /// Float precision of the ray kernel; `None`: f64 (or chosen by a fidelity tolerance).
    pub precision: Option<Precision>,
    pub device: Device,
    /// An object at infinity: the scene's full angular extent across its width (degrees, `--scene-fov-deg`);
    /// `None` for a finite object. The renderer checks it against the system ([`super::scene_pitch_for`]).
    pub scene_fov_deg: Option<f64>,
    /// Write the chief-ray mapping cube beside the render (`mapping.npy`; `--no-mapping`: false): its term of
    /// the memory estimate ([`crate::limits::bytes_render_mapping`]) counts only when it is written.
    pub mapping: bool,
    /// A fidelity tolerance (`--tolerance-um`) chooses the rays per pixel: without `rays` given, [`Self::config`]
    /// checks the ray budget at the fewest it may choose (1 per pixel and plane) rather than the default it
    /// replaces, and [`crate::fidelity::RenderTracing::resolve`] checks its choice, and the calibration's memory.
    pub tolerance_chooses_rays: bool,
}

impl Default for RenderSettings {
    /// The paper's render: 512², 28 bands 450–650 nm, 112 planes, 20 rays, seed 0, stratified, a random
    /// mask of opening 0.5 (seed 0), Airy disk 2.5 px, centre crop, SIMD kernel, f64, on the CPU.
    fn default() -> Self {
        RenderSettings {
            scene_size: 512,
            bands_nm: crate::analysis::linspace(450.0, 650.0, 28),
            planes: 112,
            rays: None,
            seed: 0,
            sampling: Sampling::Stratified,
            mask: MaskSource::Random { opening: 0.5, seed: 0 },
            airy_diameter_px: Some(2.5),
            scene_wavelengths_nm: None,
            fit: Fit::Crop,
            cube: false,
            kernel: Kernel::default(),
            precision: None,
            device: Device::Cpu,
            scene_fov_deg: None,
            mapping: true,
            tolerance_chooses_rays: false,
        }
    }
}

impl RenderSettings {
    /// The render configuration and mask of an N×N render (N = [`Self::scene_size`]), every setting and
    /// the memory and ray budgets ([`crate::limits`]) checked before anything scene-sized is allocated.
    pub fn config(&self) -> Result<(RenderConfig, Mask)> {
        let n = self.scene_size;
        let cfg = self.checked(n)?;
        let mask = self.make_mask(n, n)?;
        Ok((cfg, mask))
    }

    /// [`Self::config`] for a `height × width` scene ([`Self::scene_size`] is not used): the checks of an
    /// N×N render with N the shorter side, then the rectangle's own memory and ray budgets.
    pub fn config_hw(&self, height: usize, width: usize) -> Result<(RenderConfig, Mask)> {
        if height == 0 || width == 0 {
            return Err(Error::invalid(format!("scene size {height}×{width}: must be ≥ 1")));
        }
        let mut cfg = self.checked(height.min(width))?;
        if width != height {
            check_render_budget(height, width, &cfg, self.rays_to_check())?;
        }
        cfg.scene_height = height;
        cfg.scene_width = width;
        let mask = self.make_mask(height, width)?;
        Ok((cfg, mask))
    }

    /// The memory estimate of a `height × width` render of these settings ([`crate::limits::bytes_render_hw`]
    /// with [`Self::scene_bands`]; the mapping cube's term only when it is written, [`Self::mapping`]).
    pub fn memory_bytes(&self, height: usize, width: usize) -> f64 {
        let bands = self.bands_nm.len();
        let all = crate::limits::bytes_render_hw(height, width, self.scene_bands(), bands, self.planes, self.cube, self.airy_diameter_px);
        if self.mapping {
            all
        } else {
            all - crate::limits::bytes_render_mapping(height as f64 * width as f64, bands)
        }
    }

    /// The scene bands the memory estimate counts: the scene file's (`--scene-wavelengths`), else at least 31
    /// (the synthetic scene's).
    pub fn scene_bands(&self) -> usize {
        self.scene_wavelengths_nm.as_ref().map_or(self.bands_nm.len().max(31), Vec::len)
    }

    /// The rays per pixel given, or the default.
    pub fn rays_or_default(&self) -> usize {
        self.rays.unwrap_or(DEFAULT_RAYS)
    }

    /// The rays per pixel and plane the ray budget is checked at before the render: the given or default
    /// rays, or 1 — the fewest a tolerance may choose — when [`Self::tolerance_chooses_rays`] and none were
    /// given (its choice is checked again once made).
    pub fn rays_to_check(&self) -> usize {
        match self.rays {
            None if self.tolerance_chooses_rays => 1,
            _ => self.rays_or_default(),
        }
    }

    /// Every check and the configuration of an `n × n` render (no mask).
    fn checked(&self, n: usize) -> Result<RenderConfig> {
        self.device.check()?;
        // `--kernel` picks the CPU's ray kernel; the GPU kernels (and their twin) are their own, so another
        // kernel there was ignored and still recorded in render.json (a held-out battery).
        if self.device != Device::Cpu && self.kernel != Kernel::default() {
            return Err(Error::invalid(format!("--kernel {} with --device {}: the kernel chooses the CPU's ray kernel; the GPU kernels are their own (leave --kernel out)", self.kernel.name(), self.device)));
        }
        if n == 0 {
            return Err(Error::invalid("--scene-size must be ≥ 1"));
        }
        check_wavelengths("--bands", &self.bands_nm)?;
        if self.planes == 0 || self.planes > crate::limits::MAX_PLANES {
            return Err(Error::invalid(format!("--planes {}: must be in 1..={}", self.planes, crate::limits::MAX_PLANES)));
        }
        if let Some(d) = self.airy_diameter_px {
            if !(d.is_finite() && d > 0.0 && d <= crate::limits::MAX_AIRY_DIAMETER_PX) {
                return Err(Error::invalid(format!("--airy-diameter-px {d}: must be in (0, {}] pixels", crate::limits::MAX_AIRY_DIAMETER_PX)));
            }
        }
        if self.rays == Some(0) {
            return Err(Error::invalid("--rays must be ≥ 1"));
        }
        if let MaskSource::Random { opening, .. } = self.mask {
            if !(opening.is_finite() && (0.0..=1.0).contains(&opening)) {
                return Err(Error::invalid(format!("--opening {opening}: the mask's opening ratio must be in [0, 1]")));
            }
        }
        let bands = self.bands_nm.len();
        if let Some(ws) = &self.scene_wavelengths_nm {
            check_wavelengths("--scene-wavelengths", ws)?;
        }
        let what = if self.mapping { format!("--scene-size {n} × --planes {} (× {bands} bands, with the mapping cube, which --no-mapping leaves out)", self.planes) } else { format!("--scene-size {n} × --planes {} (× {bands} bands)", self.planes) };
        crate::limits::check_memory(&what, self.memory_bytes(n, n))?;
        // The ray budget with the given (or default) rays per pixel; a tolerance's choice is checked again
        // (`RenderTracing::resolve`), and before it the fewest rays it may choose, not the default it replaces.
        check_render_rays(n, self.planes, self.rays_to_check())?;
        let spectral = SpectralSampling::with_planes(self.bands_nm.clone(), self.planes).map_err(|e| Error::invalid(format!("the bands (--bands) and planes: {e}")))?;
        let mut cfg = RenderConfig::paper(n);
        cfg.spectral = spectral;
        cfg.rays_per_pixel = self.rays_or_default();
        cfg.seed = self.seed;
        cfg.sampling = self.sampling;
        cfg.kernel = self.kernel;
        cfg.kernel.resolve()?;
        cfg.precision = self.precision.unwrap_or_default();
        if cfg.precision == Precision::F32 {
            cfg.precision.level(cfg.kernel)?; // f32 has no scalar kernel
        }
        cfg.airy = self.airy_diameter_px.map(|d| AiryConfig { diameter_px: d, ..AiryConfig::default() });
        if let Some(f) = self.scene_fov_deg {
            super::check_scene_fov_deg(f)?;
        }
        cfg.scene_fov_deg = self.scene_fov_deg;
        Ok(cfg)
    }

    fn make_mask(&self, height: usize, width: usize) -> Result<Mask> {
        match &self.mask {
            MaskSource::Random { opening, seed } => Mask::random(height, width, *opening, *seed),
            MaskSource::File(p) => {
                let m = Mask::load(p)?;
                if m.height != height || m.width != width {
                    let want = if height == width { format!("--scene-size is {height}") } else { format!("the scene is {height}×{width}") };
                    return Err(Error::File { path: p.display().to_string(), message: format!("the mask is {}×{} but {want}", m.height, m.width) });
                }
                Ok(m)
            }
        }
    }
}

/// `520`, `450,520,650` or `450:650:28` (first:last:count) → wavelengths in nm, each within
/// [`crate::limits::WAVELENGTH_RANGE_NM`]; errors name `option` (the setting as the command line spells it) and
/// the text. The clients' one parser of wavelength lists.
pub fn parse_wavelengths(option: &str, text: &str) -> Result<Vec<f64>> {
    let bad = |why: &str| Error::invalid(format!("{option} `{text}`: {why} (use 520, 450,520,650 or 450:650:28)"));
    let num = |s: &str| -> Result<f64> {
        let v: f64 = s.trim().parse().map_err(|_| bad(&format!("`{s}` is not a number")))?;
        let (lo, hi) = crate::limits::WAVELENGTH_RANGE_NM;
        if !(v.is_finite() && (lo..=hi).contains(&v)) {
            return Err(bad(&format!("{v} nm is outside {lo}–{hi} nm")));
        }
        Ok(v)
    };
    if text.contains(':') {
        let parts: Vec<&str> = text.split(':').collect();
        if parts.len() != 3 {
            return Err(bad("a range needs first:last:count"));
        }
        let count: usize = parts[2].trim().parse().map_err(|_| bad("count is not a whole number"))?;
        if count == 0 || count > crate::limits::MAX_WAVELENGTHS {
            return Err(bad(&format!("count {count} must be in 1..={}", crate::limits::MAX_WAVELENGTHS)));
        }
        return Ok(crate::analysis::linspace(num(parts[0])?, num(parts[1])?, count));
    }
    if text.split(',').count() > crate::limits::MAX_WAVELENGTHS {
        return Err(bad(&format!("more than {} wavelengths", crate::limits::MAX_WAVELENGTHS)));
    }
    text.split(',').map(num).collect()
}

/// Wavelengths of a setting (`option`): 1..=[`crate::limits::MAX_WAVELENGTHS`] values, each finite and in
/// [`crate::limits::WAVELENGTH_RANGE_NM`].
pub fn check_wavelengths(option: &str, ws: &[f64]) -> Result<()> {
    if ws.is_empty() || ws.len() > crate::limits::MAX_WAVELENGTHS {
        return Err(Error::invalid(format!("{option}: {} wavelengths; give 1..={}", ws.len(), crate::limits::MAX_WAVELENGTHS)));
    }
    let (lo, hi) = crate::limits::WAVELENGTH_RANGE_NM;
    if let Some(w) = ws.iter().find(|w| !(w.is_finite() && (lo..=hi).contains(*w))) {
        return Err(Error::invalid(format!("{option}: {} nm is outside {lo}–{hi} nm", crate::limits::fmt_num(*w))));
    }
    Ok(())
}

/// The memory and ray budgets of a `height × width` render of `cfg`'s planes with `rays` per pixel per plane
/// (the estimate of [`crate::limits::bytes_render_hw`]), naming the height and width: for front ends that take
/// rectangles (Python, C++).
pub fn check_render_budget(height: usize, width: usize, cfg: &RenderConfig, rays: usize) -> Result<()> {
    use crate::limits;
    let bands = cfg.spectral.bands_nm.len();
    let planes = cfg.spectral.planes();
    let airy = cfg.airy.as_ref().map(|a| a.diameter_px);
    let what = format!("height × width {height}×{width} × planes {planes} (× {bands} bands)");
    limits::check_memory(&what, limits::bytes_render_hw(height, width, bands.max(31), bands, planes, false, airy))?;
    limits::check_rays(&format!("height × width {height}×{width} × planes {planes} × rays {rays}"), height as f64 * width as f64 * planes as f64 * rays as f64)
}

/// Rays of a render: N² pixels × planes × rays per pixel, within the ray budget.
pub fn check_render_rays(n: usize, planes: usize, rays: usize) -> Result<()> {
    crate::limits::check_rays(&format!("--scene-size {n} × --planes {planes} × --rays {rays}"), (n as f64).powi(2) * planes as f64 * rays as f64)
}

/// Scene radiances must be finite, ≥ 0 and below [`crate::limits::MAX_SCENE_VALUE`] (so that sums over
/// planes, rays and the Airy kernel cannot overflow the f32 images). `Err` holds the reason, naming the
/// pixel and band.
pub fn check_scene_values(cube: &SpectralCube) -> std::result::Result<(), String> {
    for (i, &v32) in cube.data.iter().enumerate() {
        let v = v32 as f64;
        if !v.is_finite() || v < 0.0 || v > crate::limits::MAX_SCENE_VALUE {
            let (b, px) = (i % cube.wavelengths_nm.len().max(1), i / cube.wavelengths_nm.len().max(1));
            // The f32 value as stored (its shortest form: -0.001, not the widened -0.0010000000474974513).
            return Err(format!(
                "scene value {v32} at pixel ({}, {}), band {b}: radiances must be finite, ≥ 0 and ≤ {:.3e} (f32 range / 10⁹, so the acquisition cannot overflow)",
                px / cube.width.max(1),
                px % cube.width.max(1),
                crate::limits::MAX_SCENE_VALUE
            ));
        }
    }
    // A scene so dim that its acquisition's values fall among f32's subnormals renders wrong numbers (a scene
    // of 1e-45 summed 5× too low, 1e-300 to zeros; a held-out battery, round 9): its brightest value must be 0
    // (a black scene) or ≥ MIN_SCENE_PEAK.
    let peak = cube.data.iter().fold(0.0f32, |m, &v| m.max(v)) as f64;
    if peak > 0.0 && peak < crate::limits::MIN_SCENE_PEAK {
        return Err(format!(
            "the scene's brightest value is {}: below {:e} its acquisition falls among f32's subnormal numbers and loses its precision; scale the scene's radiance up",
            crate::limits::fmt_num(peak),
            crate::limits::MIN_SCENE_PEAK
        ));
    }
    Ok(())
}

/// Sensor noise settings (all `None`: off); see `docs/noise.md`. [`NoiseSettings::config`] turns them into
/// a [`NoiseConfig`], refusing the options of a source that is not selected.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NoiseSettings {
    /// Sources, a comma list of shot, read, adc; `none` or `None`: no noise.
    pub noise: Option<String>,
    /// Full-well capacity (electrons) [default 20000].
    pub full_well_e: Option<f64>,
    /// Photo-electrons per acquisition unit (instead of mapping the peak to the full well).
    pub electrons_per_unit: Option<f64>,
    /// Read noise σ (electrons) [default with `read`: 2].
    pub read_noise_e: Option<f64>,
    /// ADC bit depth [default with `adc`: 12].
    pub adc_bits: Option<u32>,
    /// Seed of the noise's random numbers [default 0].
    pub noise_seed: Option<u64>,
}

impl NoiseSettings {
    /// The noise the settings describe (`None`: off). Options of a source that is not selected are errors.
    pub fn config(&self) -> Result<Option<NoiseConfig>> {
        let list = self.noise.as_deref().unwrap_or("none").trim();
        let mut cfg = NoiseConfig::default();
        let (mut read, mut adc) = (false, false);
        if list != "none" {
            let mut seen: Vec<&str> = Vec::new();
            for item in list.split(',').map(str::trim) {
                if item.is_empty() {
                    return Err(Error::invalid(format!("--noise `{list}`: an empty item (a stray comma?); use a comma list of shot, read, adc (or none)")));
                }
                if seen.contains(&item) {
                    return Err(Error::invalid(format!("--noise `{list}`: `{item}` is listed twice")));
                }
                seen.push(item);
                match item {
                    "shot" => cfg.shot = true,
                    "read" => read = true,
                    "adc" => adc = true,
                    "none" => return Err(Error::invalid(format!("--noise `{list}`: `none` means no noise and stands alone; use a comma list of shot, read, adc, or none"))),
                    _ => return Err(Error::invalid(format!("--noise `{item}`: use a comma list of shot, read, adc (or none)"))),
                }
            }
        }
        let on = cfg.shot || read || adc;
        let given = [
            ("--full-well-e", self.full_well_e.is_some()),
            ("--electrons-per-unit", self.electrons_per_unit.is_some()),
            ("--noise-seed", self.noise_seed.is_some()),
        ];
        if let Some((name, _)) = given.iter().find(|g| g.1 && !on) {
            return Err(Error::invalid(format!("{name} needs --noise (shot, read and/or adc)")));
        }
        if self.read_noise_e.is_some() && !read {
            return Err(Error::invalid("--read-noise-e needs `read` in --noise"));
        }
        if self.adc_bits.is_some() && !adc {
            return Err(Error::invalid("--adc-bits needs `adc` in --noise"));
        }
        if let (Some(f), Some(_), false) = (self.full_well_e, self.electrons_per_unit, adc) {
            // The full well is the ADC's full scale and, without --electrons-per-unit, the exposure: with neither
            // it changed nothing, yet render.json recorded it (a held-out battery, round 6).
            return Err(Error::invalid(format!(
                "--full-well-e {}: sets the ADC's full scale (`adc` in --noise) and, without --electrons-per-unit, the exposure; with --electrons-per-unit and no `adc` it has no effect",
                crate::limits::fmt_num(f)
            )));
        }
        if !on {
            return Ok(None);
        }
        if let Some(f) = self.full_well_e {
            cfg.full_well_e = f;
        }
        cfg.electrons_per_unit = self.electrons_per_unit;
        if read {
            cfg.read_noise_e = self.read_noise_e.unwrap_or(2.0);
            if cfg.read_noise_e == 0.0 {
                return Err(Error::invalid("--read-noise-e 0 with `read` in --noise: drop `read` instead"));
            }
        }
        if adc {
            cfg.adc_bits = Some(self.adc_bits.unwrap_or(12));
        }
        cfg.seed = self.noise_seed.unwrap_or(0);
        cfg.validate().map_err(|e| Error::invalid(format!("--noise: {e}")))?;
        Ok(Some(cfg))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_the_papers() {
        let s = RenderSettings::default();
        assert_eq!((s.scene_size, s.bands_nm.len(), s.planes, s.rays_or_default()), (512, 28, 112, 20));
        assert_eq!(s.airy_diameter_px, Some(2.5));
        assert_eq!(s.mask, MaskSource::Random { opening: 0.5, seed: 0 });
    }

    #[test]
    fn device_cuda_without_a_driver_is_refused_and_unknown_names_are_errors() {
        let s = RenderSettings { scene_size: 4, planes: 2, device: Device::Cuda(0), ..RenderSettings::default() };
        if crate::gpu::probe(0).is_err() {
            // No driver here (CI): refused with what is missing.
            let e = s.config().unwrap_err().to_string();
            assert!(e.starts_with("--device cuda: ") && e.ends_with("use --device cpu"), "{e}");
            assert!(e.contains("no NVIDIA driver") || e.contains("no CUDA device") || e.contains("NVIDIA driver is installed but"), "{e}");
        }
        assert_eq!("cpu".parse::<Device>().unwrap(), Device::Cpu);
        assert!("tpu".parse::<Device>().unwrap_err().to_string().contains("--device `tpu`"));
    }

    #[test]
    fn cuda_devices_are_spelt_as_torch_spells_them() {
        for (text, device, shown) in [("cuda", Device::Cuda(0), "cuda"), ("cuda:0", Device::Cuda(0), "cuda"), ("cuda:3", Device::Cuda(3), "cuda:3"), ("cuda:63", Device::Cuda(63), "cuda:63"), ("cpu-twin", Device::CpuTwin, "cpu-twin")] {
            let d: Device = text.parse().unwrap();
            assert_eq!((d, d.to_string().as_str()), (device, shown), "{text}");
            assert_eq!(d.to_string().parse::<Device>().unwrap(), d);
        }
        // Spaces around it are refused, as torch refuses them (they were trimmed: round 15).
        for bad in [" cuda:63 ", " cpu", "cuda "] {
            assert!(bad.parse::<Device>().unwrap_err().to_string().contains("no spaces around it"), "{bad:?}");
        }
        for bad in ["cuda:", "cuda:-1", "cuda:+1", "cuda:1.0", "cuda: 1", "cuda:x", "cuda:1:2", "cuda:01", "cuda:00"] {
            let e = bad.parse::<Device>().unwrap_err().to_string();
            assert!(e.contains(&format!("--device `{bad}`")) && e.contains("give a device ordinal"), "{bad}: {e}");
        }
        let e = "cuda:64".parse::<Device>().unwrap_err().to_string();
        assert!(e.contains("at most 64 CUDA devices (cuda:0 … cuda:63)"), "{e}");
        assert!("cuda:99999999999999999999999".parse::<Device>().unwrap_err().to_string().contains("give a device ordinal"));
    }

    #[test]
    fn bad_values_name_the_setting() {
        let base = RenderSettings { scene_size: 4, planes: 2, ..RenderSettings::default() };
        let err = |s: RenderSettings| s.config().unwrap_err().to_string();
        assert!(err(RenderSettings { planes: 0, ..base.clone() }).contains("--planes 0"));
        assert!(err(RenderSettings { rays: Some(0), ..base.clone() }).contains("--rays"));
        assert!(err(RenderSettings { airy_diameter_px: Some(-1.0), ..base.clone() }).contains("--airy-diameter-px -1"));
        assert!(err(RenderSettings { bands_nm: vec![500.0, 1e9], ..base.clone() }).contains("--bands: 1e9 nm is outside"));
        assert!(err(RenderSettings { mask: MaskSource::Random { opening: 2.0, seed: 0 }, ..base.clone() }).contains("--opening 2"));
        assert!(base.config_hw(0, 3).unwrap_err().to_string().contains("scene size 0×3"));
        let (cfg, m) = base.config_hw(3, 5).unwrap();
        assert_eq!((cfg.scene_height, cfg.scene_width, m.height, m.width), (3, 5, 3, 5));
    }

    #[test]
    fn noise_options_need_their_source() {
        let n = NoiseSettings { adc_bits: Some(10), ..NoiseSettings::default() };
        assert!(n.config().unwrap_err().to_string().contains("--adc-bits needs `adc`"));
        assert_eq!(NoiseSettings::default().config().unwrap(), None);
        let n = NoiseSettings { noise: Some("shot,read".into()), ..NoiseSettings::default() };
        assert_eq!(n.config().unwrap().unwrap().read_noise_e, 2.0);
    }
}
