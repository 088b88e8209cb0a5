//! `render --ghosts K [--mechanics] [--coating SPEC]`: ghost and stray light added to an acquisition
//! ([`crate::render::ghosts`]; docs/ghosts.md, "Ghosts in acquisitions"). Off by default. The options are
//! checked by clap (a ghost order outside 1..=4 or a coating reflectance outside [0, 1] is a usage error,
//! exit 2), the mechanics meshes are loaded and checked (exit 1) before anything is written.
//!
//! ```text
//! diffcassi render --preset sp --ghosts 2 --out out/sp-ghosts
//! diffcassi render --system sp-mounts.toml --ghosts 2 --mechanics --coating all=mgf2@550 --ghost-rays 4
//! ```
use super::args::SystemArgs;
use crate::error::{Error, Result};
use crate::render::ghosts::{render_ghosts, GhostConfig, GhostImages};
use crate::render::{Acquisition, Renderer};
use crate::scene::SpectralCube;
use crate::system::SequentialSystem;
use crate::tracer::nonseq::coating::CoatingOverride;
use crate::tracer::nonseq::{BruteForce, ExtraGeometry, NextHit, SolidsOptions, MAX_GHOST_ORDER};
use clap::Args;
use std::sync::Arc;
use std::time::Instant;

/// The ghost options of `render`.
#[derive(Args, Debug, Clone, Default)]
pub struct GhostArgs {
    /// Add ghost images up to this order K (Fresnel reflections per path, 1..=4) to the acquisition.
    #[arg(long, value_parser = ghost_order)]
    pub ghosts: Option<u32>,
    /// With --ghosts: the mechanics (the spec's [mechanics] section, or the generated absorbing mounts)
    /// absorb or Lambertian-scatter the rays that hit them; scattered light reaching the detector is stray light.
    #[arg(long, requires = "ghosts")]
    pub mechanics: bool,
    /// With --ghosts: override the spec's coatings, a comma list of TARGET=VALUE (TARGET `all` or a surface
    /// index; VALUE `bare`, `R<reflectance>` e.g. R0.01, or `mgf2@<nm>` e.g. mgf2@550), applied in order.
    #[arg(long, requires = "ghosts", allow_hyphen_values = true, value_parser = <CoatingOverride as std::str::FromStr>::from_str)]
    pub coating: Option<CoatingOverride>,
    /// With --ghosts: rays per scene pixel per plane whose ray trees are walked, at most the render's (an
    /// unbiased, stratified subsample, weight 1/R each) [default: the render's rays per pixel: every rendered ray].
    #[arg(long = "ghost-rays", requires = "ghosts", value_parser = clap::value_parser!(u32).range(1..))]
    pub ghost_rays: Option<u32>,
    /// With --ghosts: the non-sequential kernel: brute (every object in f64), embree-user or embree-mesh
    /// (Embree finds the object, f64 decides; mechanics as Embree triangle meshes) [default: embree-user,
    /// brute without Embree].
    #[arg(long = "ghost-backend", requires = "ghosts", value_parser = ["brute", "embree-user", "embree-mesh"])]
    pub ghost_backend: Option<String>,
}

fn ghost_order(s: &str) -> std::result::Result<u32, String> {
    ghost_order_from(s, 1)
}

/// A ghost order in `lowest..=MAX_GHOST_ORDER`, parsed by clap (a usage error, exit 2): `render --ghosts K`
/// from 1, `ghosts --order K` from 0 (the main image alone).
pub(super) fn ghost_order_from(s: &str, lowest: u32) -> std::result::Result<u32, String> {
    let k: u32 = s.trim().parse().map_err(|_| format!("`{s}` is not a ghost order (an integer in {lowest}..={MAX_GHOST_ORDER})"))?;
    if (lowest..=MAX_GHOST_ORDER).contains(&k) {
        Ok(k)
    } else {
        Err(format!("ghost order {k}: must be in {lowest}..={MAX_GHOST_ORDER}, at most {MAX_GHOST_ORDER} (trees grow as interfaces^order)"))
    }
}

/// The non-sequential kernel of the pass.
enum Kernel {
    Brute(BruteForce),
    #[cfg(feature = "embree")]
    Embree(crate::tracer::embree::EmbreeNextHit),
}

/// A prepared ghost pass: settings, kernel, and what to record.
pub struct GhostPass {
    config: GhostConfig,
    kernel: Kernel,
    backend: String,
    coating: String,
    mechanics: Option<(String, usize)>,
    setup_seconds: f64,
    /// What the solids' design-beam check changed (`Solids::design_beam_note`), for render.json.
    design_beam_note: Option<String>,
}

impl GhostPass {
    /// The pass the options ask for (`None` without --ghosts): coatings overridden, mechanics built (mesh
    /// files loaded and checked), kernel built. `rays_per_pixel`, `seed`: the render's.
    pub fn prepare(a: &GhostArgs, sys_args: &SystemArgs, system: &SequentialSystem, rays_per_pixel: usize, seed: u64) -> Result<Option<Self>> {
        if system.spec.mechanics.is_some() && !a.mechanics {
            // The section is read and checked with the spec, but only `--ghosts K --mechanics` traces it.
            eprintln!("note: the spec's [mechanics] section is not used: only `render --ghosts K --mechanics` traces the mechanics (the main image is sequential)");
        }
        let Some(order) = a.ghosts else { return Ok(None) };
        if let Some(n) = super::shared::zmx_coating_note(sys_args, "`render --ghosts` (unless --coating gives a surface's)") {
            eprintln!("note: {n}");
        }
        let t0 = Instant::now();
        if let Some(r) = a.ghost_rays.filter(|&r| r as usize > rays_per_pixel) {
            return Err(Error::invalid(format!("--ghost-rays {r}: at most the render's {rays_per_pixel} rays per pixel (a subsample of the rendered rays)")));
        }
        let mut config = GhostConfig::new(order, system, a.ghost_rays.map_or(rays_per_pixel, |r| r as usize));
        config.seed = seed;
        if let Some(o) = &a.coating {
            let sites = crate::tracer::nonseq::solids::coating_sites(system)?;
            config.coatings = o.apply(&config.coatings, &|k| sites.get(k).cloned().flatten())?;
        }
        config.validate(system)?;
        let extra: Option<(Arc<dyn ExtraGeometry>, String, usize)> = if a.mechanics { Some(mechanics(sys_args, system, a.ghost_backend.as_deref())?) } else { None };
        let default = if cfg!(feature = "embree") { "embree-user" } else { "brute" };
        let backend = a.ghost_backend.clone().unwrap_or_else(|| default.to_string());
        let kernel = match backend.as_str() {
            "brute" => {
                let k = BruteForce::new(system, &SolidsOptions::default())?;
                Kernel::Brute(match &extra {
                    Some((e, ..)) => k.with_extra(e.clone()),
                    None => k,
                })
            }
            #[cfg(feature = "embree")]
            b @ ("embree-user" | "embree-mesh") => {
                use crate::tracer::embree::{EmbreeNextHit, SceneOptions, SurfaceRepresentation};
                let mut o = SceneOptions::default();
                if b == "embree-mesh" {
                    o.representation = SurfaceRepresentation::Mesh(crate::surfaces::MeshResolution::MaxSagErrorUm(1.0));
                }
                let k = EmbreeNextHit::new(system, &o)?;
                Kernel::Embree(match &extra {
                    Some((e, ..)) => k.with_extra(e.clone()),
                    None => k,
                })
            }
            b => return Err(Error::invalid(format!("--ghost-backend {b}: this build has no Embree (use brute)"))),
        };
        // What the solids' design-beam check changed (a detector margin shrunk in a folded system).
        let note = match &kernel {
            Kernel::Brute(k) => k.solids().design_beam_note.clone(),
            #[cfg(feature = "embree")]
            Kernel::Embree(k) => k.solids().design_beam_note.clone(),
        };
        if let Some(n) = &note {
            eprintln!("note: {n}");
        }
        let coating = a.coating.as_ref().map_or_else(|| "spec".to_string(), |c| c.text.clone());
        let backend = match &extra {
            Some((e, ..)) => format!("{backend}+{}", e.name()),
            None => backend,
        };
        Ok(Some(GhostPass { config, kernel, backend, coating, mechanics: extra.map(|(_, name, tri)| (name, tri)), setup_seconds: t0.elapsed().as_secs_f64(), design_beam_note: note }))
    }

    fn images(&self, renderer: &Renderer, scene: &SpectralCube, keep_bands: bool) -> Result<GhostImages> {
        match &self.kernel {
            Kernel::Brute(k) => render_ghosts(renderer, k, scene, &self.config, keep_bands),
            #[cfg(feature = "embree")]
            Kernel::Embree(k) => render_ghosts(renderer, k, scene, &self.config, keep_bands),
        }
    }

    /// Run the pass, add its images to `acq` and return the `"ghosts"` object of render.json (printed too).
    pub fn run(&self, renderer: &Renderer, scene: &SpectralCube, acq: &mut Acquisition) -> Result<serde_json::Value> {
        let g = self.images(renderer, scene, acq.bands.is_some())?;
        let main_total = acq.total();
        // main − blocked + ghost + stray; a pixel the mechanics block entirely is 0 up to the rounding of the
        // render's f32 footprints, held at 0 (never a negative irradiance).
        for (((a, x), y), b) in acq.image.iter_mut().zip(&g.ghost).zip(&g.stray).zip(&g.blocked) {
            *a = (*a - b + x + y).max(0.0);
        }
        if let (Some(bands), Some(extra)) = (&mut acq.bands, &g.bands) {
            for (b, e) in bands.iter_mut().zip(extra) {
                for (x, y) in b.iter_mut().zip(e) {
                    *x = (*x + *y as f32).max(0.0);
                }
            }
        }
        let r = &g.report;
        let e = &r.energy;
        let total = main_total - r.blocked_total + r.ghost_total + r.stray_total;
        let share = |x: f64| if total > 0.0 { x / total } else { 0.0 };
        let plain = acq.timings.wall_seconds;
        let ratio = if plain > 0.0 { r.wall_seconds / plain } else { 0.0 };
        println!(
            "ghosts: order {}, coating {}, mechanics {}, {} kernel: {} ray trees in {:.2} s ({:.1}× the plain render's {:.2} s); ghost share {:.3e}, stray share {:.3e} of the acquisition; per launched ray: main path {:.4}, absorbed {:.4}, escaped {:.4}{}",
            self.config.order,
            self.coating,
            self.mechanics.as_ref().map_or("off".to_string(), |(n, t)| format!("on ({n}, {t} triangles)")),
            self.backend,
            r.rays_traced,
            r.wall_seconds,
            ratio,
            plain,
            share(r.ghost_total),
            share(r.stray_total),
            e.share(e.main),
            e.share(e.absorbed),
            e.share(e.escaped),
            if r.blocked_rays > 0 { format!("; the mechanics block {:.3e} of the main image ({} rays)", r.blocked_total / main_total.max(f64::MIN_POSITIVE), r.blocked_rays) } else { String::new() },
        );
        let mut record = serde_json::json!({
            "order": self.config.order,
            "model": self.config.model.label(),
            "coating": self.coating,
            "coatings": self.config.coatings,
            "mechanics": self.mechanics.is_some(),
            "mechanics_parts": self.mechanics.as_ref().map(|m| &m.0),
            "mechanics_triangles": self.mechanics.as_ref().map_or(0, |m| m.1),
            "backend": self.backend,
            "rays_per_pixel": self.config.rays_per_pixel,
            "roulette_threshold": self.config.threshold,
            "seed": self.config.seed,
            "rays_traced": r.rays_traced,
            "seconds_setup": self.setup_seconds,
            "seconds": r.wall_seconds,
            "seconds_plain_render": plain,
            "cost_ratio": ratio,
            "acquisition_main": main_total,
            "acquisition_ghost": r.ghost_total,
            "acquisition_stray": r.stray_total,
            "acquisition_blocked": r.blocked_total,
            "blocked_rays": r.blocked_rays,
            "main_blocked_share": if main_total > 0.0 { r.blocked_total / main_total } else { 0.0 },
            "ghost_share": share(r.ghost_total),
            "stray_share": share(r.stray_total),
            "main_path_share": e.share(e.main),
            "ghost_per_launched": e.share(e.ghost),
            "stray_per_launched": e.share(e.stray),
            "absorbed_share": e.share(e.absorbed),
            "escaped_share": e.share(e.escaped),
            "truncated_share": e.share(e.truncated),
            "rouletted_share": e.share(e.rouletted),
            "energy_imbalance": e.imbalance(),
            "off_detector": r.off_detector,
            "out_of_range": r.out_of_range,
            "energy": e,
            "notes": "the acquisition is main − blocked (the main image's rays the mechanics stop) + ghost + stray; ghost_share and stray_share: of its energy; the other shares: of the power launched by the ray trees (per ray 1, not weighted by the scene). The main image is the sequential render (no Fresnel loss); reconstruct uses the ghost-free operator.",
        });
        // As `ghosts`' JSON: present only when the design-beam check changed something.
        if let (Some(n), Some(obj)) = (&self.design_beam_note, record.as_object_mut()) {
            obj.insert("design_beam_note".into(), n.clone().into());
        }
        Ok(record)
    }
}

/// The mechanics of the spec (or the generated absorbing mounts) as the kernel's extra geometry: (geometry,
/// description, triangles). Mesh paths are relative to the spec file.
impl crate::render::folder::AcquisitionPass for GhostPass {
    fn run(&self, renderer: &Renderer, scene: &SpectralCube, acq: &mut Acquisition) -> Result<serde_json::Value> {
        GhostPass::run(self, renderer, scene, acq)
    }
}

fn mechanics(sys_args: &SystemArgs, system: &SequentialSystem, backend: Option<&str>) -> Result<(Arc<dyn ExtraGeometry>, String, usize)> {
    let base = sys_args.system.as_ref().and_then(|p| p.parent().map(|d| d.to_path_buf())).unwrap_or_default();
    let spec = system.spec.mechanics.clone().unwrap_or_default();
    let m = crate::mechanics::Mechanics::build(system, &spec, &base)?;
    if m.parts.is_empty() {
        return Err(Error::invalid("--mechanics: the spec's [mechanics] section has no parts (generate = false and no meshes)"));
    }
    let names: Vec<&str> = m.parts.iter().map(|p| p.name.as_str()).collect();
    let desc = names.join(", ");
    let tri = m.triangle_count();
    #[cfg(feature = "embree")]
    if backend != Some("brute") {
        return Ok((Arc::new(crate::mechanics::MechanicsScene::new(&m)?), desc, tri));
    }
    let _ = backend;
    Ok((Arc::new(m), desc, tri))
}
