//! Ghost analysis: every ghost path of a system (its reflection sequence, e.g. `5R 3R`), from the ray
//! trees of [`crate::tracer::nonseq`] walked through the brute-force f64 kernel.
//!
//! For each source — a point source at each of the system's fields, and a uniform extended source (an
//! N×N grid of field points over the field box, equal power each) — and each wavelength (the system's,
//! plus 520 nm, the reference at which every system's table is read: [`reference_wavelength`]), rays through a hexapolar pupil are split up to ghost order K. A field point is an object
//! height (mm, source `point x,y`) for a finite object and a pair of field angles for an object at infinity
//! (radians inside, degrees in the source's name: `point 0,2 deg`; its rays are the field's parallel beam,
//! started in front of every solid, [`crate::tracer::nonseq::launch`]). Per path:
//! * `energy_fraction`: detector power of the path / detector power of the main image (no reflection);
//! * `x_mm`, `y_mm`: power-weighted centroid on the detector (image surface frame); `rms_radius_mm`;
//! * `defocus_mm`: where the path's bundle is smallest along the detector normal (least-squares: the
//!   shift δ minimising Σ|x̃ᵢ + δ·ũᵢ|², x̃, ũ centroid-relative positions and direction tangents) minus the
//!   same for the main image;
//! * `peak_ratio`: the path's mean irradiance over its RMS disc, E/(π r²) with r ≥ [`MIN_RADIUS_MM`],
//!   over the main image's — what a user compares with a sensor's dynamic range.
//! "Averaged" rows average the energy fraction over the wavelengths (equal weight).
//!
//! ```
//! use diffcassi::prelude::*;
//! use diffcassi::analysis::ghosts::{ghost_analysis, GhostOptions};
//! let sys = SequentialSystem::build(&presets::spec("sp")?)?;
//! let r = ghost_analysis(&sys, &GhostOptions { rings: 2, extended_grid: 2, ..Default::default() })?;
//! assert!(r.on_axis_520().iter().all(|p| p.energy_fraction > 0.0 && p.energy_fraction < 0.1));
//! # Ok::<(), diffcassi::Error>(())
//! ```
use crate::error::{Error, Result};
use crate::rays::{PupilPattern, RayBatch};
use crate::system::SequentialSystem;
use crate::tracer::nonseq::{path_label, trace_trees, BruteForce, FresnelModel, Ledger, RayTree, SolidsOptions, TreeOptions};
use glam::DVec3;
use serde::Serialize;
use std::collections::BTreeMap;

/// Smallest radius of the disc over which a path's irradiance is averaged (mm): about a pixel.
pub const MIN_RADIUS_MM: f64 = 0.005;

/// Ghost analysis options.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GhostOptions {
    pub order: u32,
    pub model: FresnelModel,
    pub threshold: f64,
    pub seed: u64,
    /// Hexapolar pupil rings per field point.
    pub rings: usize,
    /// The extended source's field grid is N × N.
    pub extended_grid: usize,
}

impl Default for GhostOptions {
    fn default() -> Self {
        GhostOptions { order: 2, model: FresnelModel::Polarized, threshold: 1e-7, seed: 0, rings: 6, extended_grid: 5 }
    }
}

/// One ghost path of one source at one wavelength (`wavelength_nm` None: averaged over wavelengths).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GhostPath {
    pub source: String,
    pub wavelength_nm: Option<f64>,
    pub path: String,
    pub order: usize,
    pub energy_fraction: f64,
    pub x_mm: f64,
    pub y_mm: f64,
    pub rms_radius_mm: f64,
    pub defocus_mm: f64,
    pub peak_ratio: f64,
}

/// A detector power map (row-major, `n`×`n`, over [x0, x0 + n·pixel] × [y0, …]).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GhostMap {
    pub n: usize,
    pub x0_mm: f64,
    pub y0_mm: f64,
    pub pixel_mm: f64,
    pub power: Vec<f64>,
}

/// Everything `ghosts` reports.
#[derive(Clone, Debug, Serialize)]
pub struct GhostReport {
    pub system: String,
    pub order: u32,
    pub model: FresnelModel,
    /// The name of the on-axis point source (`point 0,0`, or `point 0,0 deg` for an object at infinity).
    pub on_axis_source: String,
    pub rays_traced: usize,
    /// Every (source, wavelength) row, main image excluded, ranked by peak ratio within each.
    pub paths: Vec<GhostPath>,
    /// On-axis point source at the reference wavelength (520 nm): energy fractions of the scalar model, per path (same order as
    /// [`GhostReport::on_axis_520`]), and the largest relative error of the scalar against the polarised.
    pub scalar_energy_fraction: Vec<f64>,
    pub scalar_max_relative_error: f64,
    /// The ledger summed over every tree.
    pub ledger: Ledger,
    pub map_point: GhostMap,
    pub map_uniform: GhostMap,
    /// The wavelength of the CSV rows, the PNG maps and the scalar-model comparison (nm): 520 nm, or the
    /// system's primary wavelength when a glass of the system does not cover 520 nm
    /// ([`reference_wavelength`]; then `reference_note` says why).
    pub reference_wavelength_nm: f64,
    /// Why the reference wavelength is not 520 nm; absent from the JSON when it is.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reference_note: Option<String>,
    /// What the solids' design-beam check changed ([`crate::tracer::nonseq::Solids::design_beam_note`]: a
    /// detector margin shrunk in a folded system); absent from the JSON when nothing was.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub design_beam_note: Option<String>,
}

impl GhostReport {
    /// The rows of the on-axis point source at the reference wavelength (the CSV's rows): 520 nm unless a
    /// glass of the system does not cover it ([`GhostReport::reference_wavelength_nm`]).
    pub fn on_axis_520(&self) -> Vec<&GhostPath> {
        self.paths.iter().filter(|p| p.source == self.on_axis_source && p.wavelength_nm == Some(self.reference_wavelength_nm)).collect()
    }
}

/// The name of the point source at field point `field` of `system`: `point x,y` (object height, mm) for a
/// finite object, `point θx,θy deg` (field angles, degrees) for an object at infinity.
pub fn point_source_name(system: &SequentialSystem, field: [f64; 2]) -> String {
    match system.field_display(field) {
        // Degrees from radians do not round-trip (3° → 3.0000000000000004): named to 1e-9°.
        (f, "deg") => {
            let deg = |v: f64| {
                let t = format!("{v:.9}");
                let t = t.trim_end_matches('0').trim_end_matches('.');
                if t == "-0" { "0".to_string() } else { t.to_string() }
            };
            format!("point {},{} deg", deg(f[0]), deg(f[1]))
        }
        (f, _) => format!("point {},{}", f[0], f[1]),
    }
}

/// A path's bundle: power-weighted sums of its landing points x and direction tangents u, taken about the
/// first arrival's (x₀, u₀) (the shifted data of a stable variance: a collimated bundle's u − u₀ is rounding
/// only, so its var(u) is ~1e-34, not the ~1e-18 that E[u²] − E[u]² leaves at a 5° field).
#[derive(Default)]
struct Acc {
    power: f64,
    /// The first arrival's landing point and direction tangents (the shift).
    origin: Option<([f64; 2], [f64; 2])>,
    /// Σw·x, Σw·x², Σw·u (direction tangents), Σw·x·u, Σw·u² (2-D, summed over x and y), of the shifted data.
    sx: [f64; 2],
    sxx: f64,
    su: [f64; 2],
    sxu: f64,
    suu: f64,
}

impl Acc {
    fn add(&mut self, p: DVec3, d: DVec3, w: f64) {
        let u = [d.x / d.z, d.y / d.z];
        let (x0, u0) = *self.origin.get_or_insert(([p.x, p.y], u));
        let (x, u) = ([p.x - x0[0], p.y - x0[1]], [u[0] - u0[0], u[1] - u0[1]]);
        self.power += w;
        self.sx[0] += w * x[0];
        self.sx[1] += w * x[1];
        self.sxx += w * (x[0] * x[0] + x[1] * x[1]);
        self.su[0] += w * u[0];
        self.su[1] += w * u[1];
        self.sxu += w * (x[0] * u[0] + x[1] * u[1]);
        self.suu += w * (u[0] * u[0] + u[1] * u[1]);
    }
    /// The shifted data's centroid (about x₀).
    fn shifted_centroid(&self) -> [f64; 2] {
        [self.sx[0] / self.power, self.sx[1] / self.power]
    }
    fn centroid(&self) -> [f64; 2] {
        let x0 = self.origin.map_or([0.0; 2], |o| o.0);
        let c = self.shifted_centroid();
        [x0[0] + c[0], x0[1] + c[1]]
    }
    fn rms(&self) -> f64 {
        let c = self.shifted_centroid();
        (self.sxx / self.power - c[0] * c[0] - c[1] * c[1]).max(0.0).sqrt()
    }
    /// δ minimising the RMS of x + δ·u (centred): −cov(x, u)/var(u).
    /// A collimated bundle (var(u) ≤ 1e-30: every ray parallel to rounding) has no focus: 0.
    fn focus_shift(&self) -> f64 {
        let (c, m) = (self.shifted_centroid(), [self.su[0] / self.power, self.su[1] / self.power]);
        let cov = self.sxu / self.power - c[0] * m[0] - c[1] * m[1];
        let var = self.suu / self.power - m[0] * m[0] - m[1] * m[1];
        if var > 1e-30 {
            -cov / var
        } else {
            0.0
        }
    }
}

/// Group the arrivals of `trees` by path.
fn accumulate(trees: &[RayTree]) -> BTreeMap<Vec<u32>, Acc> {
    let mut m: BTreeMap<Vec<u32>, Acc> = BTreeMap::new();
    for t in trees {
        for a in &t.arrivals {
            if a.direction.z.abs() > 0.0 {
                m.entry(a.path.clone()).or_default().add(a.point, a.direction, a.power);
            }
        }
    }
    m
}

/// Ghost rows of one (source, wavelength), ranked by peak ratio (main image excluded).
fn rows(source: &str, wavelength_nm: Option<f64>, groups: &BTreeMap<Vec<u32>, Acc>) -> Result<Vec<GhostPath>> {
    let main = groups.get(&Vec::new()).filter(|m| m.power > 0.0).ok_or_else(|| Error::invalid(format!("ghosts: no main-image ray of source {source} reached the detector")))?;
    let irr = |a: &Acc| a.power / (std::f64::consts::PI * a.rms().max(MIN_RADIUS_MM).powi(2));
    let mut v: Vec<GhostPath> = groups
        .iter()
        .filter(|(p, a)| !p.is_empty() && a.power > 0.0)
        .map(|(p, a)| {
            let c = a.centroid();
            GhostPath {
                source: source.to_string(),
                wavelength_nm,
                path: path_label(p),
                order: p.len(),
                energy_fraction: a.power / main.power,
                x_mm: c[0],
                y_mm: c[1],
                rms_radius_mm: a.rms(),
                defocus_mm: a.focus_shift() - main.focus_shift(),
                peak_ratio: irr(a) / irr(main),
            }
        })
        .collect();
    v.sort_by(|a, b| b.peak_ratio.total_cmp(&a.peak_ratio).then_with(|| a.path.cmp(&b.path)));
    Ok(v)
}

fn ghost_map(trees: &[RayTree], n: usize) -> GhostMap {
    let pts: Vec<(DVec3, f64)> = trees.iter().flat_map(|t| t.arrivals.iter().map(|a| (a.point, a.power))).collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for (p, _) in &pts {
        lo = [lo[0].min(p.x), lo[1].min(p.y)];
        hi = [hi[0].max(p.x), hi[1].max(p.y)];
    }
    let side = ((hi[0] - lo[0]).max(hi[1] - lo[1]) * 1.05).max(0.1);
    let (cx, cy) = (0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]));
    let pixel = side / n as f64;
    let (x0, y0) = (cx - 0.5 * side, cy - 0.5 * side);
    let mut power = vec![0.0; n * n];
    for (p, w) in pts {
        let i = (((p.x - x0) / pixel) as usize).min(n - 1);
        let j = (((p.y - y0) / pixel) as usize).min(n - 1);
        power[j * n + i] += w;
    }
    GhostMap { n, x0_mm: x0, y0_mm: y0, pixel_mm: pixel, power }
}

/// Bytes of one detector arrival slot of a ray tree (`Arrival`: its reflection list's header, point,
/// direction, power, scatters), counted over the arrivals `Vec`'s capacity (it grows by doubling: at order 4
/// on a Cooke triplet 144 arrivals sit in 216 slots on average).
pub const BYTES_PER_ARRIVAL: f64 = 88.0;
/// Bytes of a ghost arrival's heap path label (`Vec<u32>` of ≤ 4 surfaces: the allocator's smallest chunk,
/// 32 B); the main image's empty label allocates nothing.
pub const BYTES_PER_LABEL: f64 = 32.0;
/// Bytes per arrival of the ghost map's copy (point, power) of the reference wavelength's sources.
pub const BYTES_PER_MAP_POINT: f64 = 32.0;
/// The process before the analysis (binary, system, solids): 16.8 MB resident measured on a Cooke triplet.
pub const BYTES_BASE: f64 = 17e6;
/// Bytes one ray tree of the source being traced holds besides its arrivals: the source's ray (56 B), the tree
/// and its ledger (80 B), allocator and grouping overhead. Measured: AP, order 4, 2.0 paths per tree, rings 16 and
/// 32 with an extended grid of 16 (2.1·10⁵ and 8.1·10⁵ trees in the largest source) peaked at 147 MB and 506 MB
/// resident, 600–620 B per tree.
pub const BYTES_PER_TREE: f64 = 300.0;

/// What [`ghost_analysis`] will trace and hold, estimated before the analysis runs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GhostEstimate {
    /// Ray trees walked: wavelengths × (point sources + N² extended-grid points) × pupil rays, plus the
    /// on-axis source twice more (the scalar-model comparison).
    pub trees: f64,
    /// Trees of the largest source (the extended one), held at once.
    pub largest_source: f64,
    /// Detector paths per tree, measured on a pilot (see [`ghost_estimate`]).
    pub paths_per_tree: f64,
    /// Rays traced: every tree's walk and each of its detector paths, trees × (1 + paths per tree).
    pub rays: f64,
    /// Peak memory: the process ([`BYTES_BASE`]) and the largest source's rays, trees and detector paths
    /// ([`BYTES_PER_TREE`]; per arrival slot [`BYTES_PER_ARRIVAL`], per ghost label [`BYTES_PER_LABEL`], per
    /// map point [`BYTES_PER_MAP_POINT`], each counted on the pilot's own trees).
    pub bytes: f64,
}

/// Refuse a coating that transmits nothing (`reflectance = 1`). The main image of a sequential system crosses
/// every coated surface (a coating on a mirror, a Coordinate Break or the image is refused by
/// [`crate::render::ghosts::check_coating_sites`]), so such a coating stops every order-0 ray and the ghosts
/// have no main image to be normalised by; named here rather than as "no main-image ray reached the
/// detector" after the trace (round 21).
fn refuse_opaque_coatings(coatings: &[Option<crate::spec::Coating>]) -> Result<()> {
    let opaque: Vec<String> = coatings
        .iter()
        .enumerate()
        .filter(|(_, c)| matches!(c, Some(crate::spec::Coating::Reflectance(r)) if *r >= 1.0))
        .map(|(k, _)| k.to_string())
        .collect();
    if opaque.is_empty() {
        return Ok(());
    }
    let (which, verb) = if opaque.len() == 1 { (format!("surface {}'s coating", opaque[0]), "transmits") } else { (format!("the coatings of surfaces {}", opaque.join(", ")), "transmit") };
    Err(Error::invalid(format!(
        "ghosts: {which} (reflectance 1) {verb} nothing: every main-image ray stops there, so there is no main image to normalise the ghosts by; give a reflectance below 1"
    )))
}

/// The wavelength at which ghost tables of different systems compare (nm): the presets' primary, the middle
/// of the visible band.
pub const REFERENCE_WAVELENGTH_NM: f64 = 520.0;

/// The wavelength of the CSV rows and the PNG maps (nm), and why it is not [`REFERENCE_WAVELENGTH_NM`] when it
/// is not. 520 nm is traced beside the system's wavelengths so that every system's ghost table is read at one
/// wavelength; a glass whose data do not reach 520 nm (germanium, ZnSe in an LWIR lens: valid 2–14 µm) has no
/// index there (its formula, extrapolated far below its range, may give n² < 0), so such a system is read at
/// its primary wavelength instead, and 520 nm is not traced at all.
pub fn reference_wavelength(system: &SequentialSystem) -> (f64, Option<String>) {
    let w = REFERENCE_WAVELENGTH_NM;
    let outside = system.surfaces.iter().filter_map(|s| s.medium_after.glass()).find(|g| !g.in_range(w));
    match outside {
        None => (w, None),
        Some(g) => {
            let (lo, hi) = g.valid_range_nm();
            let p = system.primary_wavelength_nm();
            let f = crate::limits::fmt_num;
            (
                p,
                Some(format!(
                    "the ghosts' reference wavelength {} nm is outside the valid range [{}, {}] nm of glass {}: the on-axis rows (CSV, table), the ghost maps (PNG) and the scalar-model comparison are at the system's primary wavelength {} nm instead, and {} nm is not traced",
                    f(w),
                    f(lo),
                    f(hi),
                    g.name,
                    f(p),
                    f(w)
                )),
            )
        }
    }
}

/// The wavelengths a ghost analysis traces: the system's, plus the reference ([`reference_wavelength`]).
fn analysis_wavelengths(system: &SequentialSystem, reference: f64) -> Vec<f64> {
    let mut w = system.spec.wavelengths_nm.clone();
    if !w.contains(&reference) {
        w.push(reference);
    }
    w
}

/// Estimate a ghost analysis before running it (the CLI checks it against `--max-rays`/`--max-memory-gb`).
/// The trees are counted from the options; the paths a tree keeps depend on the system, the order and the
/// roulette threshold (from 1 to thousands), so they are measured on a pilot: the extended source itself, made
/// small (up to 4×4 of its own field points, each weighted by the grid points nearest to it, through up to 6
/// hexapolar rings: the same weighting of pupil zones), at the reference wavelength, walked with the analysis' own options
/// (0.1 s at order 2, 1 s at order 4 on 2 cores). The old pilot (2 rings, the on-axis field and the box's 4 corners, whose vignetted rays
/// keep fewest paths) counted 118 paths per tree where the Cooke triplet's extended source kept 144 at order 4.
/// Memory is counted from the pilot trees' own allocations (arrival slots, labels): on that triplet at orders
/// 2, 3 and 4 (rings 6–32, grids 8–16) the estimate is 1.03–1.08 of the measured peak resident memory.
pub fn ghost_estimate(system: &SequentialSystem, options: &GhostOptions) -> Result<GhostEstimate> {
    crate::render::ghosts::refuse_mask_surface(system, "the ghost analysis")?;
    let coatings: Vec<Option<crate::spec::Coating>> = system.spec.surfaces.iter().map(|s| s.coating.clone()).collect();
    crate::render::ghosts::check_coating_sites(system, &coatings)?;
    refuse_opaque_coatings(&coatings)?;
    let tree_opts = TreeOptions { order: options.order, model: options.model, threshold: options.threshold, seed: options.seed, ..Default::default() };
    tree_opts.validate()?;
    let r = options.rings as f64;
    let pupil = 1.0 + 3.0 * r * (r + 1.0);
    let (reference, _) = reference_wavelength(system);
    let wavelengths = analysis_wavelengths(system, reference).len();
    let fields = system.fields.len() + usize::from(!system.fields.contains(&[0.0, 0.0]));
    let grid = (options.extended_grid as f64).powi(2);
    let largest_source = grid.max(1.0) * pupil;
    let trees = wavelengths as f64 * (fields as f64 + grid) * pupil + 2.0 * pupil;
    // The pilot.
    let kernel = BruteForce::new(system, &SolidsOptions::default())?;
    let (fx, fy) = system.fields.iter().fold((0.0f64, 0.0f64), |(a, b), f| (a.max(f[0].abs()), b.max(f[1].abs())));
    let sample = PupilPattern::Hexapolar { rings: options.rings.clamp(1, 6) }.points();
    // Up to 4 of the grid's own indices per axis, each weighted by the grid points nearest to it (a stratified
    // sample: the box's edges, vignetted, keep fewer paths than its inside).
    let g = options.extended_grid.max(1);
    let n = g.min(4);
    let picks: Vec<usize> = (0..n).map(|j| if n == 1 { g / 2 } else { (j * (g - 1) + (n - 1) / 2) / (n - 1) }).collect();
    let mut weight = vec![0.0f64; n];
    for i in 0..g {
        let j = (0..n).min_by_key(|&j| picks[j].abs_diff(i)).unwrap_or(0);
        weight[j] += 1.0;
    }
    let s = |i: usize| if g == 1 { 0.0 } else { -1.0 + 2.0 * i as f64 / (g - 1) as f64 };
    let mut rays = RayBatch::default();
    let mut ray_weight: Vec<f64> = Vec::new();
    for (a, b) in (0..n * n).map(|k| (k % n, k / n)) {
        if let Ok(batch) = RayBatch::for_field(system, [fx * s(picks[a]), fy * s(picks[b])], &sample, reference) {
            ray_weight.extend(std::iter::repeat_n(weight[a] * weight[b], batch.len()));
            rays.extend(&batch);
        }
    }
    let pilot = trace_trees(&kernel, system, &rays, &tree_opts)?;
    let total: f64 = ray_weight.iter().sum::<f64>().max(1e-300);
    let per_tree = |f: &dyn Fn(&RayTree) -> usize| pilot.iter().zip(&ray_weight).map(|(t, w)| f(t) as f64 * w).sum::<f64>() / total;
    let paths_per_tree = per_tree(&|t| t.arrivals.len());
    let slots = per_tree(&|t| t.arrivals.capacity());
    let labels = per_tree(&|t| t.arrivals.iter().filter(|a| a.path.capacity() > 0).count());
    let rays = trees * (1.0 + paths_per_tree);
    let bytes = BYTES_BASE + largest_source * (BYTES_PER_TREE + slots * BYTES_PER_ARRIVAL + labels * BYTES_PER_LABEL + paths_per_tree * BYTES_PER_MAP_POINT);
    Ok(GhostEstimate { trees, largest_source, paths_per_tree, rays, bytes })
}

/// Run the analysis (brute-force kernel). Errors: invalid options (ghost order above the maximum …), a
/// source whose main image misses the detector.
pub fn ghost_analysis(system: &SequentialSystem, options: &GhostOptions) -> Result<GhostReport> {
    crate::render::ghosts::refuse_mask_surface(system, "the ghost analysis")?;
    let coatings: Vec<Option<crate::spec::Coating>> = system.spec.surfaces.iter().map(|s| s.coating.clone()).collect();
    crate::render::ghosts::check_coating_sites(system, &coatings)?;
    refuse_opaque_coatings(&coatings)?;
    let tree_opts = TreeOptions { order: options.order, model: options.model, threshold: options.threshold, seed: options.seed, ..Default::default() };
    tree_opts.validate()?;
    if options.model == FresnelModel::Off {
        return Err(Error::invalid("ghosts: the Fresnel model must be scalar or polarized"));
    }
    if options.rings == 0 || options.rings > 64 || options.extended_grid == 0 || options.extended_grid > 64 {
        return Err(Error::invalid(format!("ghosts: rings {} and extended grid {} must be in 1..=64", options.rings, options.extended_grid)));
    }
    let kernel = BruteForce::new(system, &SolidsOptions::default())?;
    let pupil = PupilPattern::Hexapolar { rings: options.rings }.points();
    let (reference, reference_note) = reference_wavelength(system);
    let wavelengths = analysis_wavelengths(system, reference);
    let mut fields = system.fields.clone();
    if !fields.contains(&[0.0, 0.0]) {
        fields.insert(0, [0.0, 0.0]);
    }
    let mut ledger = Ledger::default();
    let mut paths = Vec::new();
    let mut rays_traced = 0usize;
    let mut averaged: BTreeMap<(String, String), (f64, usize, GhostPath)> = BTreeMap::new();
    let mut map_point = None;
    let mut map_uniform = None;
    let mut on_axis_trees: Option<RayBatch> = None;
    let on_axis = point_source_name(system, [0.0, 0.0]);
    // Extended source: N×N field points over the box of the fields' magnitudes.
    let (fx, fy) = fields.iter().fold((0.0f64, 0.0f64), |(a, b), f| (a.max(f[0].abs()), b.max(f[1].abs())));
    let g = options.extended_grid;
    let grid: Vec<[f64; 2]> = (0..g * g)
        .map(|k| {
            let s = |i: usize| if g == 1 { 0.0 } else { -1.0 + 2.0 * i as f64 / (g - 1) as f64 };
            [fx * s(k % g), fy * s(k / g)]
        })
        .collect();
    for &w in &wavelengths {
        let mut sources: Vec<(String, RayBatch)> = Vec::new();
        for f in &fields {
            sources.push((point_source_name(system, *f), RayBatch::for_field(system, *f, &pupil, w)?));
        }
        let mut ext = RayBatch::default();
        for f in &grid {
            ext.extend(&RayBatch::for_field(system, *f, &pupil, w)?);
        }
        sources.push(("uniform".to_string(), ext));
        for (name, rays) in sources {
            let trees = trace_trees(&kernel, system, &rays, &tree_opts)?;
            rays_traced += rays.len();
            for t in &trees {
                ledger.add(&t.ledger);
            }
            let groups = accumulate(&trees);
            let r = rows(&name, Some(w), &groups)?;
            for p in &r {
                let e = averaged.entry((name.clone(), p.path.clone())).or_insert((0.0, 0, GhostPath { wavelength_nm: None, ..p.clone() }));
                e.0 += p.energy_fraction;
                e.1 += 1;
            }
            if w == reference {
                if name == on_axis {
                    map_point = Some(ghost_map(&trees, 256));
                    on_axis_trees = Some(rays.clone());
                } else if name == "uniform" {
                    map_uniform = Some(ghost_map(&trees, 256));
                }
            }
            paths.extend(r);
        }
    }
    let nw = wavelengths.len() as f64;
    for ((_, _), (sum, _, mut p)) in averaged {
        p.energy_fraction = sum / nw;
        paths.push(p);
    }
    // The scalar model on the on-axis source at the reference wavelength, against the polarised one.
    let mut report = GhostReport {
        system: system.name().to_string(),
        order: options.order,
        model: options.model,
        rays_traced,
        paths,
        scalar_energy_fraction: Vec::new(),
        scalar_max_relative_error: 0.0,
        ledger,
        map_point: map_point.ok_or_else(|| Error::invalid("ghosts: the system has no on-axis field (0, 0)"))?,
        on_axis_source: on_axis.clone(),
        map_uniform: map_uniform.expect("the uniform source is traced at the reference wavelength"),
        reference_wavelength_nm: reference,
        reference_note,
        design_beam_note: kernel.solids.design_beam_note.clone(),
    };
    if let Some(rays) = on_axis_trees {
        let scalar = TreeOptions { model: FresnelModel::Scalar, ..tree_opts };
        let polar = TreeOptions { model: FresnelModel::Polarized, ..tree_opts };
        let s = rows(&on_axis, Some(reference), &accumulate(&trace_trees(&kernel, system, &rays, &scalar)?))?;
        let p = rows(&on_axis, Some(reference), &accumulate(&trace_trees(&kernel, system, &rays, &polar)?))?;
        report.scalar_energy_fraction = report.on_axis_520().iter().map(|g| s.iter().find(|x| x.path == g.path).map(|x| x.energy_fraction).unwrap_or(0.0)).collect();
        report.scalar_max_relative_error = p
            .iter()
            .map(|g| {
                let sv = s.iter().find(|x| x.path == g.path).map(|x| x.energy_fraction).unwrap_or(0.0);
                (sv - g.energy_fraction).abs() / g.energy_fraction
            })
            .fold(0.0, f64::max);
    }
    Ok(report)
}
