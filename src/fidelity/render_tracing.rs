//! A render's tracer, rays per pixel and precision: as the settings give them, or chosen for an error
//! tolerance — one step every front end takes before it builds its [`crate::render::Renderer`].
//!
//! The CLI's `render` and `render-dataset` (`--tolerance-um`), Python's `diffcassi.render(...,
//! tolerance_um=)` and C++'s `System::render` (`RenderOptions::tolerance_um`) resolve the same
//! [`TracerSource`] here, with the same checks and the same choice
//! ([`super::choose_render_for`]): a tolerance chooses the rays per pixel and the precision itself, so it
//! refuses rays or a precision given beside it, and the scalar kernel (f64 only, which cannot run the f32
//! lanes it may choose). The chosen rays are checked against the ray budget before anything is traced.
//!
//! ```
//! use diffcassi::prelude::*;
//! use diffcassi::fidelity::{CacheOptions, RenderTracing, TracerSource};
//! use diffcassi::render::RenderSettings;
//! let sys = SequentialSystem::build(&presets::spec("sp")?)?;
//! let settings = RenderSettings { scene_size: 8, planes: 4, ..RenderSettings::default() };
//! let (mut cfg, mask) = settings.config()?;
//! let source = TracerSource::Tolerance { tolerance_um: 5.0, cache: CacheOptions::none() };
//! let t = RenderTracing::resolve(source, &sys, &settings, &mut cfg, &mask)?;
//! assert_eq!(cfg.rays_per_pixel, t.rays_per_pixel);
//! assert!(t.predicted_error_um.unwrap() <= 5.0);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::select::{choose_render_for, CacheOptions};
use crate::error::{Error, Result};
use crate::render::settings::{check_render_budget, check_render_rays};
use crate::render::{Mask, RenderConfig, RenderSettings};
use crate::system::SequentialSystem;
use crate::tracer::{Kernel, Precision, Tracer};

/// Where a render's tracer comes from.
pub enum TracerSource {
    /// A tracer the caller built (a backend by name); the rays per pixel and the precision are the
    /// settings' (default [`crate::render::settings::DEFAULT_RAYS`] and f64).
    Given(Box<dyn Tracer>),
    /// The cheapest backend, rays per pixel and precision whose predicted error of where a scene pixel's
    /// energy lands is within `tolerance_um` (µm, image plane), calibrated on this system over the
    /// render's planes and field ([`super::choose_render_for`]); calibrations cached in `cache`.
    Tolerance { tolerance_um: f64, cache: CacheOptions },
    /// A tolerance's choice made before and recorded, taken as it is without calibrating again: a dataset's
    /// shards and a resumed array render with the choice its `dataset.json` records for the same tolerance
    /// (`crate::render::dataset::run_with_source`), not with one of their own timings (a held-out battery,
    /// round 20: shards on fresh caches chose f32 or f64 by the machine's timing noise and refused each
    /// other). `backend` is the choice's `--backend` text (`analytic`, `analytic-f32`, `embree-user:f64`…);
    /// `origin` names the record for the explanation.
    Recorded { tolerance_um: f64, backend: String, rays_per_pixel: usize, predicted_error_um: f64, origin: String },
}

impl TracerSource {
    /// The tolerance (µm) of a [`TracerSource::Tolerance`] or [`TracerSource::Recorded`] source.
    pub fn tolerance_um(&self) -> Option<f64> {
        match self {
            TracerSource::Given(_) => None,
            TracerSource::Tolerance { tolerance_um, .. } | TracerSource::Recorded { tolerance_um, .. } => Some(*tolerance_um),
        }
    }
}

/// A resolved [`TracerSource`].
pub struct RenderTracing {
    pub tracer: Box<dyn Tracer>,
    pub rays_per_pixel: usize,
    pub precision: Precision,
    /// The tolerance that chose them (µm), `None` when given.
    pub tolerance_um: Option<f64>,
    /// The error the choice predicts (µm: trace error + σ/√N), `None` when given.
    pub predicted_error_um: Option<f64>,
    /// The choice's `--backend` text (`analytic-f32` for the f32 lanes), `None` when given: what a dataset
    /// records so that its other shards take the same choice ([`TracerSource::Recorded`]).
    pub backend: Option<String>,
    /// The choice, its candidates and where the calibrations came from, for a front end to show; `None`
    /// when given.
    pub explanation: Option<String>,
}

impl RenderTracing {
    /// Resolve `source` for a render of `system` with `settings`, whose configuration and mask are `cfg`
    /// and `mask` ([`RenderSettings::config`] or `config_hw`): sets `cfg.rays_per_pixel` and
    /// `cfg.precision` to the result's. A tolerance is refused beside rays, a precision or `--kernel
    /// scalar` in `settings`; on a device other than the CPU it chooses among the analytic f64 tracer's
    /// rays per pixel only (the GPU kernels are the analytic tracer's; the other candidates' throughputs and
    /// f32 errors are the CPU's, not the device's).
    pub fn resolve(source: TracerSource, system: &SequentialSystem, settings: &RenderSettings, cfg: &mut RenderConfig, mask: &Mask) -> Result<RenderTracing> {
        let (tolerance_um, cache) = match source {
            TracerSource::Given(tracer) => {
                let (rays_per_pixel, precision) = (settings.rays_or_default(), settings.precision.unwrap_or_default());
                cfg.rays_per_pixel = rays_per_pixel;
                cfg.precision = precision;
                return Ok(RenderTracing { tracer, rays_per_pixel, precision, tolerance_um: None, predicted_error_um: None, backend: None, explanation: None });
            }
            TracerSource::Tolerance { tolerance_um, cache } => (tolerance_um, Ok(cache)),
            TracerSource::Recorded { tolerance_um, backend, rays_per_pixel, predicted_error_um, origin } => (tolerance_um, Err((backend, rays_per_pixel, predicted_error_um, origin))),
        };
        let t = crate::limits::fmt_num(tolerance_um);
        if let Some(n) = settings.rays {
            return Err(Error::invalid(format!("--tolerance-um {t} chooses the rays per pixel itself; it cannot be combined with --rays {n}")));
        }
        if let Some(p) = settings.precision {
            return Err(Error::invalid(format!("--tolerance-um {t} chooses the precision itself; it cannot be combined with --precision {p}")));
        }
        if cfg.kernel == Kernel::Scalar {
            // Before the calibration (seconds): its choice may be the f32 lanes, which the scalar kernel lacks.
            return Err(Error::invalid(format!("--tolerance-um {t} chooses among the SIMD kernel's f64 and f32 lanes; --kernel scalar (f64 only, the reference) cannot take its choice: drop one of them")));
        }
        let (h, w) = (cfg.scene_height, cfg.scene_width);
        let (choice, provenance) = match cache {
            Ok(cache) => {
                // The calibration's memory beside the render's, before it runs: its Embree meshes and ray set
                // stay in the allocator's pages while the render runs (round 19: left out, the estimate was
                // 0.47× the peak at 256²). Counted whether or not the cache will serve it.
                let half = super::workload::scene_half_width(h, w, crate::render::scene_pitch_for(system, cfg)?);
                let set = super::workload::RaySetSpec::calibration().covering(system, half).build(system, &cfg.spectral.planes_nm)?.len();
                let calibration = crate::limits::bytes_calibration(system.spec.surfaces.len(), set as f64);
                let render = settings.memory_bytes(h, w);
                crate::limits::check_memory(&format!("--tolerance-um {t}'s calibration ({} surfaces, {set} rays) beside the {h}×{w} render", system.spec.surfaces.len()), calibration + render)?;
                // Traced pixels: the open ones, or every pixel when the mask is a surface inside the system.
                let open = if system.coded_mask.is_some() { mask.values.len() } else { mask.values.iter().filter(|&&v| v > 0.0).count() };
                choose_render_for(system, cfg, settings.device, tolerance_um, open, &cache)?
            }
            Err((backend, n, predicted, origin)) => {
                // Nothing is calibrated: the choice is taken as recorded, where this render can run it (the f32
                // lanes and the Embree backends on the CPU, a coded-mask system on the analytic f64 path).
                let config: crate::tracer::BackendConfig = backend.parse().map_err(|e| Error::invalid(format!("{origin}: the recorded choice of --tolerance-um {t}: backend `{backend}`: {e}")))?;
                let only_f64 = system.coded_mask.is_some() || settings.device != crate::render::Device::Cpu;
                if (only_f64 && config.backend != crate::tracer::Backend::Analytic) || n == 0 || !(predicted.is_finite() && predicted > 0.0 && predicted <= tolerance_um) {
                    return Err(Error::invalid(format!("{origin}: the recorded choice of --tolerance-um {t} (--backend {backend} --rays {n}, predicted error {predicted} µm) cannot be taken by this render")));
                }
                let explanation = format!("fidelity: tolerance {t} µm → --backend {backend} --rays {n} (error {predicted:.2e} µm), the choice {origin} records: taken as it is, not chosen again on this run's timings");
                (super::select::RenderChoice { config, rays_per_pixel: n, error_um: predicted, explanation }, "no calibration".to_string())
            }
        };
        if h == w {
            check_render_rays(h, cfg.spectral.planes(), choice.rays_per_pixel)?;
        } else {
            check_render_budget(h, w, cfg, choice.rays_per_pixel)?;
        }
        let precision = choice.precision();
        cfg.rays_per_pixel = choice.rays_per_pixel;
        cfg.precision = precision;
        Ok(RenderTracing {
            tracer: choice.tracer()?,
            rays_per_pixel: choice.rays_per_pixel,
            precision,
            tolerance_um: Some(tolerance_um),
            predicted_error_um: Some(choice.error_um),
            backend: Some(super::measure::backend_text(&choice.config)),
            explanation: Some(format!("{} [{provenance}]", choice.explanation)),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::Device;

    fn sp() -> SequentialSystem {
        SequentialSystem::build(&crate::presets::spec("sp").unwrap()).unwrap()
    }

    fn small() -> RenderSettings {
        RenderSettings { scene_size: 8, planes: 4, ..RenderSettings::default() }
    }

    fn tol(um: f64) -> TracerSource {
        TracerSource::Tolerance { tolerance_um: um, cache: CacheOptions::none() }
    }

    /// Rays, a precision or the scalar kernel beside a tolerance are refused, naming both, before any
    /// calibration; a given tracer keeps the settings' rays and precision.
    #[test]
    fn a_tolerance_refuses_what_it_would_choose() {
        let sys = sp();
        for (s, want) in [
            (RenderSettings { rays: Some(7), ..small() }, "cannot be combined with --rays 7"),
            (RenderSettings { precision: Some(Precision::F32), ..small() }, "cannot be combined with --precision f32"),
            (RenderSettings { kernel: Kernel::Scalar, ..small() }, "--kernel scalar"),
        ] {
            let (mut cfg, mask) = s.config().unwrap();
            let e = RenderTracing::resolve(tol(2.0), &sys, &s, &mut cfg, &mask).err().expect(want).to_string();
            assert!(e.contains(want) && e.contains("--tolerance-um 2"), "{e}");
        }
        let s = RenderSettings { rays: Some(7), precision: Some(Precision::F32), ..small() };
        let (mut cfg, mask) = s.config().unwrap();
        let t = RenderTracing::resolve(TracerSource::Given(Box::new(crate::tracer::AnalyticTracer::default())), &sys, &s, &mut cfg, &mask).unwrap();
        assert_eq!((t.rays_per_pixel, t.precision, cfg.rays_per_pixel, cfg.precision), (7, Precision::F32, 7, Precision::F32));
        assert!(t.predicted_error_um.is_none() && t.explanation.is_none());
    }

    /// On a device the choice is the analytic f64 tracer's rays per pixel (the tolerance that lets the CPU
    /// take the f32 lanes, as `a_tolerance_refuses_what_it_would_choose`'s system does at 5 µm, stays f64
    /// on the GPU kernels' twin), with the same N the f64 candidate needs on the CPU.
    #[test]
    fn on_a_device_a_tolerance_chooses_f64_rays_only() {
        let sys = sp();
        let cpu = small();
        let (mut c_cfg, mask) = cpu.config().unwrap();
        let on_cpu = RenderTracing::resolve(tol(5.0), &sys, &cpu, &mut c_cfg, &mask).unwrap();
        let twin = RenderSettings { device: Device::CpuTwin, ..small() };
        let (mut t_cfg, mask) = twin.config().unwrap();
        let on_twin = RenderTracing::resolve(tol(5.0), &sys, &twin, &mut t_cfg, &mask).unwrap();
        let text = on_twin.explanation.clone().unwrap();
        assert_eq!((on_twin.tracer.name().as_str(), on_twin.precision), ("analytic-f64", Precision::F64), "{text}");
        assert!(text.contains("--device cpu-twin"), "{text}");
        assert!(on_twin.predicted_error_um.unwrap() <= 5.0);
        // The f64 candidate's N on the CPU's list equals the device's choice.
        let cpu_text = on_cpu.explanation.unwrap();
        let n = format!("analytic N={} ", on_twin.rays_per_pixel);
        assert!(cpu_text.contains(&n), "{n} not in {cpu_text}");
    }
}
