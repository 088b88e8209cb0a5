//! Ghost and stray light in acquisitions (`render --ghosts K [--mechanics] [--coating SPEC]`, issue 23).
//!
//! The sequential render ([`super::engine`]) stays the main image, untouched. This pass adds what it
//! cannot see: for every plane, every open scene pixel with a non-zero coded value and each of its
//! `rays_per_pixel` samples (the render's own samples when the counts are equal: same sampler, seed and
//! ray generation, [`super::transport::PlaneContext`]), the ray's non-sequential tree
//! ([`crate::tracer::nonseq::walk_tree`]) is walked to ghost order K through a [`NextHit`] kernel
//! (brute force or Embree, with the mechanics as extra geometry if asked). Of its detector arrivals only
//! those with at least one Fresnel reflection (**ghosts**) or one scatter off a mount (**stray light**) are
//! kept: the order-0 path is the main image already and is never splatted twice. Each kept arrival
//! deposits `value · power / rays_per_pixel` bilinearly at its landing point (the main image's splat:
//! detector pixel centres at integer coordinates, taps off the detector lost); each plane is blurred by
//! the same Airy kernel as the main image's plane and weighted by B/K, as the main image is.
//!
//! **Mechanics in the beam.** The sequential main image has no mechanics: a mechanical part across the
//! beam (a user mesh, a baffle) would not dim it. So a tree whose order-0 path meets the extra geometry
//! ([`RayTree::main_blocked`](crate::tracer::nonseq::RayTree)) also traces its ray sequentially, and where
//! the main image counted it, the **blocked** image takes the same deposit (`value / rays_per_pixel` at the
//! sequential landing, the same splat, blur and plane weight); the acquisition is main − blocked + ghost +
//! stray. The blocked rays are always every rendered ray's, so they leave exactly (to the rounding of the
//! render's f32 footprints): with a ghost subsample (`rays_per_pixel` < the render's N) a second pass walks
//! the order-0 path alone (`order` 0) of each of the render's N rays (a subsample's estimate, clamped at 0 per
//! pixel, brightened what it should dim).
//!
//! **Units.** The main image counts an arrived ray with weight 1 (the sequential model has no Fresnel
//! loss); ghost and stray arrivals carry their power relative to the launched ray (1), so the ghost share
//! of the acquisition is the physical ghost power over the (lossless) main image's. The tree's own
//! order-0 power — the main image's Fresnel transmission, which the sequential render leaves out — is
//! reported beside (`main_path_share`).
//!
//! **Estimator.** With `rays_per_pixel` = the render's N every rendered ray runs its tree; fewer rays per
//! pixel is an unbiased subsample (the stratified samples of an N′-ray sampler, weight 1/N′ each). Russian
//! roulette below `threshold` is unbiased ([`crate::tracer::nonseq::tree`]). Ray i's roulette and
//! scattering streams are keyed by (seed, plane, pixel, sample) only, and each plane's image is summed in
//! a fixed order, so the result does not depend on the thread count.
//!
//! **Energy** per tree: main + ghost + stray + absorbed + escaped + truncated + rouletted = launched
//! ([`TreeEnergy`]; `truncated`: reflections beyond K and bounce limits, `rouletted`: expectation 0).
//!
//! ```
//! use diffcassi::prelude::*;
//! use diffcassi::render::{ghosts::{render_ghosts, GhostConfig}, Mask, RenderConfig, Renderer, SpectralSampling};
//! use diffcassi::scene::SpectralCube;
//! use diffcassi::tracer::nonseq::{BruteForce, SolidsOptions};
//! let system = SequentialSystem::build(&presets::spec("sp")?)?;
//! let mut cfg = RenderConfig::paper(4);
//! cfg.spectral = SpectralSampling::new(vec![520.0], 1)?;
//! cfg.rays_per_pixel = 4;
//! let tracer = AnalyticTracer::default();
//! let r = Renderer::new(&system, &tracer, cfg, Mask::open(4, 4))?;
//! let scene = SpectralCube::uniform(4, 4, vec![500.0, 540.0], 1.0);
//! let kernel = BruteForce::new(&system, &SolidsOptions::default())?;
//! let g = render_ghosts(&r, &kernel, &scene, &GhostConfig::new(2, &system, 4), false)?;
//! assert!(g.report.energy.ghost > 0.0 && g.report.energy.imbalance().abs() < 1e-9);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::engine::Renderer;
use super::sampling::{RaySampler, SampleRow};
use super::transport::PlaneContext;
use crate::error::{Error, Result};
use crate::scene::SpectralCube;
use crate::spec::Coating;
use crate::system::SequentialSystem;
use crate::tracer::nonseq::{walk_tree, FresnelModel, NextHit, RayTree, TreeOptions, MAX_GHOST_ORDER};
use rayon::prelude::*;
use std::time::Instant;

/// Settings of the ghost pass.
#[derive(Clone, Debug, PartialEq)]
pub struct GhostConfig {
    /// Ghost order K (1 ..= [`MAX_GHOST_ORDER`]).
    pub order: u32,
    pub model: FresnelModel,
    /// Relative power below which Russian roulette plays.
    pub threshold: f64,
    /// Seed of the roulette and scattering streams.
    pub seed: u64,
    /// Rays per scene pixel per plane whose trees are walked (the render's N: every rendered ray).
    pub rays_per_pixel: usize,
    /// Coating of each sequential surface (the spec's, or overridden).
    pub coatings: Vec<Option<Coating>>,
}

impl GhostConfig {
    /// Order `order`, polarised Fresnel, roulette below 1e-7, seed 0, `rays_per_pixel` rays, the spec's
    /// coatings.
    pub fn new(order: u32, system: &SequentialSystem, rays_per_pixel: usize) -> Self {
        GhostConfig { order, model: FresnelModel::Polarized, threshold: 1e-7, seed: 0, rays_per_pixel, coatings: system.spec.surfaces.iter().map(|s| s.coating.clone()).collect() }
    }

    /// Errors name the setting and its value.
    pub fn validate(&self, system: &SequentialSystem) -> Result<()> {
        refuse_mask_surface(system, "the ghost and stray-light render")?;
        if !(1..=MAX_GHOST_ORDER).contains(&self.order) {
            return Err(Error::invalid(format!("ghost order {}: must be in 1..={MAX_GHOST_ORDER} (trees grow as interfaces^order)", self.order)));
        }
        if self.model == FresnelModel::Off {
            return Err(Error::invalid("ghosts need Fresnel weighting (model scalar or polarized, not off)"));
        }
        if self.rays_per_pixel == 0 {
            return Err(Error::invalid("ghost rays per pixel must be ≥ 1"));
        }
        if self.coatings.len() != system.spec.surfaces.len() {
            return Err(Error::invalid(format!("{} coatings for {} surfaces", self.coatings.len(), system.spec.surfaces.len())));
        }
        check_coating_sites(system, &self.coatings)?;
        self.tree_options().validate()
    }

    fn tree_options(&self) -> TreeOptions {
        TreeOptions { order: self.order, model: self.model, threshold: self.threshold, seed: self.seed, ..TreeOptions::default() }
    }
}

/// Where a tree's launched power went, split for the acquisition: order-0 arrivals (`main`), arrivals
/// after ≥ 1 Fresnel reflection and no scatter (`ghost`), arrivals after ≥ 1 scatter off a mount
/// (`stray`), and the ledger's other terms. Summed over trees, it is the pass's energy budget.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct TreeEnergy {
    pub launched: f64,
    pub main: f64,
    pub ghost: f64,
    pub stray: f64,
    pub absorbed: f64,
    pub escaped: f64,
    pub truncated: f64,
    pub rouletted: f64,
}

impl TreeEnergy {
    /// The split of one tree.
    pub fn of(tree: &RayTree) -> Self {
        let l = &tree.ledger;
        let mut e = TreeEnergy { launched: l.launched, absorbed: l.absorbed, escaped: l.escaped, truncated: l.truncated, rouletted: l.rouletted, ..Default::default() };
        for a in &tree.arrivals {
            match (a.scatters > 0, a.path.is_empty()) {
                (true, _) => e.stray += a.power,
                (false, true) => e.main += a.power,
                (false, false) => e.ghost += a.power,
            }
        }
        e
    }

    pub fn add(&mut self, o: &TreeEnergy) {
        self.launched += o.launched;
        self.main += o.main;
        self.ghost += o.ghost;
        self.stray += o.stray;
        self.absorbed += o.absorbed;
        self.escaped += o.escaped;
        self.truncated += o.truncated;
        self.rouletted += o.rouletted;
    }

    /// main + ghost + stray + absorbed + escaped + truncated + rouletted − launched (0 to rounding).
    pub fn imbalance(&self) -> f64 {
        self.main + self.ghost + self.stray + self.absorbed + self.escaped + self.truncated + self.rouletted - self.launched
    }

    /// `x` as a share of the launched power (0 when nothing was launched).
    pub fn share(&self, x: f64) -> f64 {
        if self.launched > 0.0 {
            x / self.launched
        } else {
            0.0
        }
    }
}

/// What the pass did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct GhostReport {
    /// Trees walked (one per ray).
    pub rays_traced: u64,
    /// Power budget over all trees (each launched with power 1, not weighted by the scene).
    pub energy: TreeEnergy,
    /// Ghost and stray energy added to the acquisition (acquisition units, after blur and plane weights).
    pub ghost_total: f64,
    pub stray_total: f64,
    /// The main image's energy the mechanics block (acquisition units, after blur and plane weights; subtract it).
    pub blocked_total: f64,
    /// Trees whose order-0 path the mechanics stopped and that the main image counted.
    pub blocked_rays: u64,
    /// Ghost/stray splat weight (acquisition units: with the plane weights, before the blur) that fell off the detector.
    pub off_detector: f64,
    /// Arrivals at a non-finite or implausible position (not splatted).
    pub out_of_range: u64,
    pub wall_seconds: f64,
}

/// The ghost and stray images (detector-sized, row-major; add them to the acquisition) and the report.
#[derive(Clone, Debug)]
pub struct GhostImages {
    pub ghost: Vec<f64>,
    pub stray: Vec<f64>,
    /// The main image's light the mechanics block (subtract it; zero without mechanics in the beam).
    pub blocked: Vec<f64>,
    /// Per band ghost + stray − blocked images, when asked.
    pub bands: Option<Vec<Vec<f64>>>,
    pub report: GhostReport,
}

/// One plane's blurred, weighted images and its budget.
struct PlaneResult {
    ghost: Vec<f64>,
    stray: Vec<f64>,
    blocked: Vec<f64>,
    blocked_rays: u64,
    energy: TreeEnergy,
    rays: u64,
    off: f64,
    out_of_range: u64,
}

/// Planes traced at once (bounded memory; the result does not depend on it or on the thread count).
const PLANE_CHUNK: usize = 8;

/// Walk the trees of the rays of `renderer`'s acquisition of `scene` through `kernel` and splat the ghost
/// and stray arrivals (see the [module docs](self)).
pub fn render_ghosts<H: NextHit>(renderer: &Renderer, kernel: &H, scene: &SpectralCube, cfg: &GhostConfig, keep_bands: bool) -> Result<GhostImages> {
    let t0 = Instant::now();
    let system = renderer.system;
    cfg.validate(system)?;
    let c = &renderer.config;
    if scene.height != c.scene_height || scene.width != c.scene_width {
        return Err(Error::invalid(format!("the scene is {}×{} but the render expects {}×{}", scene.height, scene.width, c.scene_height, c.scene_width)));
    }
    let sp = &c.spectral;
    let det = renderer.detector;
    let npix = det.pixels();
    let sampler = RaySampler::new(cfg.rays_per_pixel, c.sampling);
    let ctx = PlaneContext {
        system,
        tracer: renderer.tracer,
        direct_kernel: false,
        simd: None,
        precision: c.precision,
        detector: &renderer.detector,
        scene_height: c.scene_height,
        scene_width: c.scene_width,
        scene_pitch_mm: c.scene_pitch_mm,
        mask: &renderer.mask.values,
        surface_mask: None,
        sampler: &sampler,
        seed: c.seed,
        cancel: renderer.cancel(),
    };
    let opts = cfg.tree_options();
    // The blocked rays come from the trees when they are the render's own rays, else from a pass over those.
    let full = cfg.rays_per_pixel == c.rays_per_pixel;
    // Only a kernel with mechanics (extra geometry, [`NextHit::has_extra`]) stops order-0 paths.
    let mechanics = kernel.has_extra();
    let trees = Pass { arrivals: true, blocked: mechanics && full };
    let mut out = GhostImages { ghost: vec![0.0; npix], stray: vec![0.0; npix], blocked: vec![0.0; npix], bands: keep_bands.then(|| vec![vec![0.0; npix]; sp.bands_nm.len()]), report: GhostReport::default() };
    let planes: Vec<usize> = (0..sp.planes()).collect();
    // One pass over every plane's rays (of `ctx`'s sampler), its images and budget added to `out`.
    let mut run = |ctx: &PlaneContext, opts: &TreeOptions, pass: Pass| -> Result<()> {
        for chunk in planes.chunks(PLANE_CHUNK) {
            let results: Vec<Result<PlaneResult>> = chunk.par_iter().map(|&p| plane(ctx, renderer, kernel, scene, cfg, opts, p, pass)).collect();
            for (&p, r) in chunk.iter().zip(results) {
                let r = r?;
                for (image, add) in [(&mut out.ghost, &r.ghost), (&mut out.stray, &r.stray), (&mut out.blocked, &r.blocked)] {
                    for (a, b) in image.iter_mut().zip(add) {
                        *a += b;
                    }
                }
                if let Some(bands) = &mut out.bands {
                    for (((a, g), s), b) in bands[sp.plane_band[p]].iter_mut().zip(&r.ghost).zip(&r.stray).zip(&r.blocked) {
                        *a += g + s - b;
                    }
                }
                out.report.blocked_rays += r.blocked_rays;
                out.report.energy.add(&r.energy);
                // Trees walked; the order-0 pass's walks are not trees of the ghost pass.
                if pass.arrivals {
                    out.report.rays_traced += r.rays;
                }
                out.report.off_detector += r.off;
                out.report.out_of_range += r.out_of_range;
            }
        }
        Ok(())
    };
    run(&ctx, &opts, trees)?;
    if mechanics && !full {
        // The render's N rays, their order-0 paths only: which of them the mechanics stop.
        let sampler_n = RaySampler::new(c.rays_per_pixel, c.sampling);
        run(&PlaneContext { sampler: &sampler_n, ..ctx.clone() }, &TreeOptions { order: 0, ..opts }, Pass { arrivals: false, blocked: true })?;
    }
    out.report.ghost_total = out.ghost.iter().sum();
    out.report.stray_total = out.stray.iter().sum();
    out.report.blocked_total = out.blocked.iter().sum();
    out.report.wall_seconds = t0.elapsed().as_secs_f64();
    Ok(out)
}

/// What a pass over a plane's rays keeps.
#[derive(Clone, Copy)]
struct Pass {
    /// The ghost and stray arrivals and the trees' energy.
    arrivals: bool,
    /// The deposits of the rays whose order-0 path the mechanics stop.
    blocked: bool,
}

/// One plane: trees of every ray of `ctx`'s sampler, splats, blur, plane weight.
#[allow(clippy::too_many_arguments)]
fn plane<H: NextHit>(ctx: &PlaneContext, renderer: &Renderer, kernel: &H, scene: &SpectralCube, cfg: &GhostConfig, opts: &TreeOptions, p: usize, pass: Pass) -> Result<PlaneResult> {
    let c = &renderer.config;
    let det = renderer.detector;
    let wavelength_nm = c.spectral.planes_nm[p];
    let n = ctx.system.indices(wavelength_nm)?;
    let (h, w) = (c.scene_height, c.scene_width);
    let values: Vec<f32> = scene.plane(wavelength_nm).iter().zip(&renderer.mask.values).map(|(v, m)| v * m).collect();
    let nr = ctx.sampler.rays;
    let weight = 1.0 / nr as f64;
    // Ghost, stray and blocked (the main image's light the mechanics stop) images.
    let mut img = [vec![0.0f64; det.pixels()], vec![0.0f64; det.pixels()], vec![0.0f64; det.pixels()]];
    let mut res = PlaneResult { ghost: Vec::new(), stray: Vec::new(), blocked: Vec::new(), blocked_rays: 0, energy: TreeEnergy::default(), rays: 0, off: 0.0, out_of_range: 0 };
    let mut samples = SampleRow::default();
    for row in 0..h {
        // Open pixels of the row with light on them (a zero coded value adds nothing).
        let cols: Vec<usize> = (0..w).filter(|&col| renderer.mask.values[row * w + col] > 0.0 && values[row * w + col] != 0.0).collect();
        if cols.is_empty() {
            continue;
        }
        let pixels: Vec<u64> = cols.iter().map(|&col| (row * w + col) as u64).collect();
        ctx.sampler.fill_pixels(ctx.seed, p as u64, &pixels, &mut samples);
        for (k, &col) in cols.iter().enumerate() {
            let pixel = row * w + col;
            let v = values[pixel] as f64 * weight;
            for s in 0..nr {
                let (o, d) = ctx.ray(&n, row, col, &samples.get(k * nr + s))?;
                // The ray's key: (plane, pixel, sample), unique in the render.
                let index = ((p as u64 * (h * w) as u64) + pixel as u64) * nr as u64 + s as u64;
                let tree = walk_tree(kernel, &n, &cfg.coatings, wavelength_nm, o, d, index, opts);
                res.rays += 1;
                if pass.arrivals {
                    res.energy.add(&TreeEnergy::of(&tree));
                }
                if pass.blocked && tree.main_blocked {
                    // Where the sequential main image put this ray (if it did), the blocked image takes its deposit.
                    let mut landed = None;
                    super::transport::trace_interleaved(&ctx.system.path, &n, &[(o, d)], |r| landed = r.ok());
                    if let Some((q, _)) = landed.filter(|(q, dq)| q.is_finite() && dq.is_finite() && q.abs().max_element() <= crate::limits::MAX_IMAGE_COORD_MM) {
                        let (u, vv) = det.to_pixel(q.x, q.y);
                        splat(&mut img[2], det.width, det.height, u, vv, v);
                        res.blocked_rays += 1;
                    }
                }
                for a in tree.arrivals.iter().filter(|a| pass.arrivals && (a.scatters > 0 || !a.path.is_empty())) {
                    if !(a.point.is_finite() && a.point.abs().max_element() <= crate::limits::MAX_IMAGE_COORD_MM) {
                        res.out_of_range += 1;
                        continue;
                    }
                    let (u, vv) = det.to_pixel(a.point.x, a.point.y);
                    res.off += splat(&mut img[(a.scatters > 0) as usize], det.width, det.height, u, vv, v * a.power);
                }
            }
        }
    }
    let pw = c.spectral.plane_weight;
    // The off-detector weight in the images' units: the plane weight (bands per plane) scales both alike
    // (it was left out, so `off_detector` read B/K times too small against `ghost_total`; round 19).
    res.off *= pw;
    let [ghost, stray, blocked] = img.map(|im| {
        let im32: Vec<f32> = im.iter().map(|&x| x as f32).collect();
        let blurred = match &renderer.kernels[p] {
            Some(k) => k.convolve(&im32, det.width, det.height),
            None => im32,
        };
        blurred.iter().map(|&x| pw * x as f64).collect::<Vec<f64>>()
    });
    res.ghost = ghost;
    res.stray = stray;
    res.blocked = blocked;
    Ok(res)
}

/// Bilinear splat of weight `w` at continuous pixel coordinates (u, v) (centres at integers); returns the
/// weight that fell off the detector.
fn splat(img: &mut [f64], width: usize, height: usize, u: f64, v: f64, w: f64) -> f64 {
    let (j, i) = (u.floor(), v.floor());
    let (fu, fv) = (u - j, v - i);
    let mut lost = 0.0;
    for (di, wi) in [(0.0, 1.0 - fv), (1.0, fv)] {
        for (dj, wj) in [(0.0, 1.0 - fu), (1.0, fu)] {
            let (r, c) = (i + di, j + dj);
            let tap = w * wi * wj;
            if r >= 0.0 && c >= 0.0 && r < height as f64 && c < width as f64 {
                img[r as usize * width + c as usize] += tap;
            } else {
                lost += tap;
            }
        }
    }
    lost
}

/// Each coating is valid and on a surface where it acts ([`crate::tracer::nonseq::solids::coating_sites`]):
/// a coating the trees never read (a plane in air, a face merged into the coincident one before it) is
/// refused, naming the surface and why, rather than recorded as applied.
pub fn check_coating_sites(system: &SequentialSystem, coatings: &[Option<Coating>]) -> Result<()> {
    if coatings.iter().all(Option::is_none) {
        return Ok(());
    }
    let sites = crate::tracer::nonseq::solids::coating_sites(system)?;
    for (k, c) in coatings.iter().enumerate() {
        if let Some(c) = c {
            c.validate().map_err(|e| Error::invalid(format!("coating of surface {k}: {e}")))?;
            if let Some(what) = sites.get(k).cloned().flatten() {
                return Err(Error::invalid(format!("coating of surface {k}: surface {k} is {what}: a coating there would do nothing")));
            }
        }
    }
    Ok(())
}

/// The non-sequential ghost and stray-light paths (`render --ghosts`, the `ghosts` analysis) do not model a
/// coded-mask surface inside the system (dual-disperser CASSI): such a system is refused, naming `what`, rather
/// than analysed as if the mask were air (the `ghosts` command did, a held-out battery, round 6).
pub fn refuse_mask_surface(system: &SequentialSystem, what: &str) -> Result<()> {
    match system.coded_mask {
        Some(m) => Err(Error::invalid(format!(
            "system `{}` holds its coded mask on surface {} (dual-disperser CASSI): {what} does not model a mask surface yet",
            system.name(),
            m.surface
        ))),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splat_conserves_inside_and_counts_losses() {
        let mut img = vec![0.0; 12];
        assert_eq!(splat(&mut img, 4, 3, 1.25, 0.5, 2.0), 0.0);
        assert!((img.iter().sum::<f64>() - 2.0).abs() < 1e-15);
        assert!((img[1] - 2.0 * 0.75 * 0.5).abs() < 1e-15 && (img[6] - 2.0 * 0.25 * 0.5).abs() < 1e-15);
        let mut img = vec![0.0; 12];
        let lost = splat(&mut img, 4, 3, 3.5, -0.5, 1.0);
        assert!((lost - 0.75).abs() < 1e-15 && (img.iter().sum::<f64>() - 0.25).abs() < 1e-15);
    }
}
