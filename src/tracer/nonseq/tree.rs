//! Ray trees: each launched ray is split at every optical interface into a reflected and a transmitted
//! child, up to a ghost order K (the number of partial — Fresnel — reflections on a path; at most
//! [`MAX_GHOST_ORDER`]), walked through any [`NextHit`] kernel.
//!
//! * Interfaces weight the children by [`super::coating::interface_coefficients`] with the
//!   [`FresnelModel`]: `Polarized` carries two incoherent flux-normalised field states per ray through
//!   Chipman's polarisation ray-tracing matrices; `Scalar` multiplies the intensity by ½(R_s + R_p) or its
//!   complement; `Off` transmits everything (K must then be 0) — the walk is then today's Embree
//!   non-sequential trace with f64 refinement, bit for bit.
//! * Total internal reflection is followed as a whole (it is not a ghost and does not count toward K).
//!   Ideal (paraxial) lenses and the detector do not reflect; the detector absorbs what reaches it.
//! * A **mirror** face ([`Role::Mirror`], `GLAS MIRROR`) does not split: it is a perfect conductor
//!   (reflectivity 1 on either side) and the ray goes on as one reflected ray, d′ = d − 2(d·n̂)n̂, with its
//!   whole power; it is not a ghost (the path label and the order K are unchanged). In the polarised model
//!   the field is reflected with r_s = −1, r_p = +1 — the n₂ → ∞ limit of the Fresnel amplitudes in
//!   [`super::fresnel`]'s convention (r_p = −r_s at normal incidence), so that at normal incidence E′ = −E,
//!   the tangential field of a perfect conductor vanishing at its surface. Coatings on a mirror are refused
//!   by the spec ([`crate::spec::SystemSpec::not_an_interface`]) and skipped by `--coating all=…`; none is
//!   read here. A grazing hit (|d·n̂| ≤ [`GRAZING_COS`]) ends the path as `missed` (its power escapes), as
//!   in the sequential kernel.
//! * A reflected child beyond order K is not followed: its power is booked as `truncated`.
//! * **Russian roulette** (unbiased): a child whose power w is below `threshold`·w₀ (w₀ the launched
//!   power) survives with probability q = w/(threshold·w₀) and is then given power w/q (its fields scaled
//!   by 1/√q); otherwise it is dropped. E[w′] = q·w/q = w, so every expected detector power is unchanged.
//!   The random numbers come from a ChaCha8 stream seeded from (seed, ray index) only, so a tree does not
//!   depend on the thread that walks it.
//! * **Ledger** per tree: detector + absorbed + escaped + truncated + rouletted = launched (to rounding),
//!   where `rouletted` = Σ dropped w − Σ (w/q − w) over survivors (its expectation is 0).
//!
//! ```
//! use diffcassi::prelude::*;
//! use diffcassi::tracer::nonseq::{BruteForce, SolidsOptions, TreeOptions, FresnelModel, trace_trees};
//! let sys = SequentialSystem::build(&presets::spec("sp")?)?;
//! let brute = BruteForce::new(&sys, &SolidsOptions::default())?;
//! let rays = RayBatch::chief_rays(&sys, &[[0.0, 0.0]], 520.0)?;
//! let trees = trace_trees(&brute, &sys, &rays, &TreeOptions { order: 2, ..Default::default() })?;
//! assert!(trees[0].arrivals.iter().any(|a| a.path.len() == 2)); // second-order ghosts reach the detector
//! assert!(trees[0].ledger.imbalance().abs() < 1e-12);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::coating::interface_coefficients;
use super::fresnel::{apply_prt, sp_basis, unpolarized, CVec3, FresnelModel};
use super::next_hit::{f32_ulps, Event, NextHit, Query};
use super::solids::Role;
use crate::error::{Error, Result};
use crate::rays::RayBatch;
use crate::spec::Coating;
use crate::system::SequentialSystem;
use crate::tracer::kernel::{paraxial_deflect, reflect, refract, unit_direction, GRAZING_COS};
use crate::tracer::RayStatus;
use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// The highest ghost order the tree follows (trees grow as (interfaces)^K).
pub const MAX_GHOST_ORDER: u32 = 4;

/// Ray-tree options.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TreeOptions {
    /// Ghost order K: most partial reflections on a path (0 ..= [`MAX_GHOST_ORDER`]).
    pub order: u32,
    pub model: FresnelModel,
    /// Relative power below which Russian roulette plays (0: never).
    pub threshold: f64,
    /// Seed of the roulette streams.
    pub seed: u64,
    /// Most interactions per path.
    pub max_bounces: u32,
}

impl Default for TreeOptions {
    fn default() -> Self {
        TreeOptions { order: 2, model: FresnelModel::Polarized, threshold: 1e-7, seed: 0, max_bounces: 64 }
    }
}

impl TreeOptions {
    /// Errors name the option and the value.
    pub fn validate(&self) -> Result<()> {
        if self.order > MAX_GHOST_ORDER {
            return Err(Error::invalid(format!("ghost order {}: at most {MAX_GHOST_ORDER} (trees grow as interfaces^order)", self.order)));
        }
        if self.model == FresnelModel::Off && self.order > 0 {
            return Err(Error::invalid(format!("ghost order {} needs Fresnel weighting (model scalar or polarized, not off)", self.order)));
        }
        if !(self.threshold.is_finite() && (0.0..1.0).contains(&self.threshold)) {
            return Err(Error::invalid(format!("roulette threshold {}: must be in [0, 1)", self.threshold)));
        }
        if self.max_bounces == 0 {
            return Err(Error::invalid("max_bounces 0: must be ≥ 1"));
        }
        Ok(())
    }
}

/// Where a tree's power went.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Ledger {
    pub launched: f64,
    pub detector: f64,
    /// Walls, blades, vignetting apertures, extra geometry.
    pub absorbed: f64,
    /// Left the system (no further hit).
    pub escaped: f64,
    /// Reflections beyond order K, bounce limit, unsolvable hits.
    pub truncated: f64,
    /// Russian roulette: dropped power minus the boost of survivors (expectation 0).
    pub rouletted: f64,
}

impl Ledger {
    /// detector + absorbed + escaped + truncated + rouletted − launched.
    pub fn imbalance(&self) -> f64 {
        self.detector + self.absorbed + self.escaped + self.truncated + self.rouletted - self.launched
    }
    pub fn add(&mut self, o: &Ledger) {
        self.launched += o.launched;
        self.detector += o.detector;
        self.absorbed += o.absorbed;
        self.escaped += o.escaped;
        self.truncated += o.truncated;
        self.rouletted += o.rouletted;
    }
}

/// One path reaching the detector.
#[derive(Clone, Debug, PartialEq)]
pub struct Arrival {
    /// Sequential surface (first of its merged interface) of each partial reflection, in order; empty for
    /// the main image.
    pub path: Vec<u32>,
    /// Hit point (image surface's local frame, mm) and the direction after it (as the tracers report).
    pub point: DVec3,
    pub direction: DVec3,
    /// Power (the launched ray has 1).
    pub power: f64,
    /// Lambertian scatters off extra (mechanical) geometry on the path: > 0 is stray light.
    pub scatters: u32,
}

/// The walked tree of one ray.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RayTree {
    pub arrivals: Vec<Arrival>,
    pub ledger: Ledger,
    /// How the order-0 path (all transmissions) ended, and where ([`RayStatus`] as the tracers classify).
    pub main_status: Option<RayStatus>,
    pub main_surface: u32,
    /// The order-0 path met the kernel's extra geometry (a mechanical part) before the detector: the
    /// sequential main image, which has no mechanics, counts a ray the mechanics stopped.
    pub main_blocked: bool,
}

/// The label of a path: "5R 3R" (surfaces of its reflections), "main" for none.
pub fn path_label(path: &[u32]) -> String {
    if path.is_empty() {
        "main".to_string()
    } else {
        path.iter().map(|s| format!("{s}R")).collect::<Vec<_>>().join(" ")
    }
}

#[derive(Clone)]
struct Node {
    p: DVec3,
    d: DVec3,
    /// Scalar power (Off, Scalar).
    w: f64,
    /// Field states (Polarized).
    e: [CVec3; 2],
    path: Vec<u32>,
    exclude: Option<usize>,
    tnear: f64,
    interactions: u32,
    scatters: u32,
}

impl Node {
    fn power(&self, model: FresnelModel) -> f64 {
        match model {
            FresnelModel::Polarized => self.e[0].norm_sqr() + self.e[1].norm_sqr(),
            _ => self.w,
        }
    }
}

/// The roulette seed of ray `index` (SplitMix64 of the seed and the index).
fn stream_seed(seed: u64, index: u64) -> u64 {
    let mut z = seed ^ index.wrapping_mul(0x9E37_79B9_7F4A_7C15).wrapping_add(0xD1B5_4A32_D192_ED03);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Walk the ray trees of every ray of `rays` (object space, as the tracers take them), in parallel; the
/// result is independent of the thread count. Ray i's roulette stream is seeded from (seed, i).
pub fn trace_trees<H: NextHit>(kernel: &H, system: &SequentialSystem, rays: &RayBatch, options: &TreeOptions) -> Result<Vec<RayTree>> {
    options.validate()?;
    if !rays.is_consistent() {
        return Err(Error::invalid("ray batch columns have different lengths"));
    }
    let table = crate::tracer::analytic::index_table(system, &rays.wavelength_nm)?;
    let coatings: Vec<Option<Coating>> = system.spec.surfaces.iter().map(|s| s.coating.clone()).collect();
    Ok((0..rays.len())
        .into_par_iter()
        .map(|i| {
            let n = &table[&rays.wavelength_nm[i].to_bits()];
            walk_tree(kernel, n, &coatings, rays.wavelength_nm[i], rays.origin(i), rays.direction(i), i as u64, options)
        })
        .collect())
}

/// Walk one ray's tree (`n`: indices of the media after each surface at its wavelength).
#[allow(clippy::too_many_arguments)]
pub fn walk_tree<H: NextHit>(kernel: &H, n: &[f64], coatings: &[Option<Coating>], wavelength_nm: f64, origin: DVec3, direction: DVec3, index: u64, options: &TreeOptions) -> RayTree {
    let model = options.model;
    let mut tree = RayTree::default();
    let Some(d0) = unit_direction(direction).filter(|_| origin.is_finite()) else {
        tree.main_status = Some(RayStatus::InvalidInput);
        return tree;
    };
    let mut rng = ChaCha8Rng::seed_from_u64(stream_seed(options.seed, index));
    tree.ledger.launched = 1.0;
    // An object at infinity: the ray starts in front of every solid, on its own line (`launch`).
    let origin = kernel.solids().launch_origin(origin, d0);
    let root = Node { p: origin, d: d0, w: 1.0, e: unpolarized(d0, 1.0), path: Vec::new(), exclude: None, tnear: 0.0, interactions: 0, scatters: 0 };
    let objects = &kernel.solids().objects;
    let mut scatter_count = 0u32;
    let mut stack = vec![root];
    while let Some(mut node) = stack.pop() {
        let main = node.path.is_empty();
        let mut passes = 0u32;
        // Walk this node until it ends; reflected children are pushed on the stack.
        let (status, surface) = loop {
            let q = Query { p: node.p, d: node.d, exclude: node.exclude, tnear: node.tnear, after_interaction: node.interactions > 0 && node.tnear == 0.0 };
            let event = kernel.next_hit(&q);
            node.tnear = 0.0;
            let last = node.exclude.map(|k| surface_of(&objects[k].role)).unwrap_or(0);
            let power = node.power(model);
            match event {
                Event::Miss => {
                    tree.ledger.escaped += power;
                    break (RayStatus::Missed, last);
                }
                Event::Extra(hit) => {
                    // Mechanics: the kernel's extra geometry scatters a fraction (a Lambertian lobe, keyed by
                    // (seed, ray index, scatter count of the tree): thread-independent), the rest is absorbed.
                    let p = node.p + node.d * hit.t;
                    if main && node.scatters == 0 {
                        // The order-0 path ends here as far as the main image is concerned.
                        tree.main_status = Some(RayStatus::Absorbed);
                        tree.main_surface = last;
                        tree.main_blocked = true;
                    }
                    let scattered = kernel.scatter(&hit, node.d, options.seed, index, u64::from(scatter_count));
                    scatter_count += 1;
                    let Some((d, rho)) = scattered.filter(|_| p.is_finite() && node.interactions + 1 < options.max_bounces) else {
                        tree.ledger.absorbed += power;
                        break (RayStatus::Absorbed, last);
                    };
                    tree.ledger.absorbed += (1.0 - rho) * power;
                    match model {
                        // Scattered light is unpolarised (depolarising diffuse surface).
                        FresnelModel::Polarized => node.e = unpolarized(d, rho * power),
                        _ => node.w = rho * power,
                    }
                    (node.p, node.d, node.exclude) = (p, d, None);
                    node.tnear = f32_ulps(p, 16.0);
                    node.interactions += 1;
                    node.scatters += 1;
                    let w = node.power(model);
                    if !roulette(&mut node, w, options.threshold, model, &mut rng, &mut tree.ledger) {
                        break (RayStatus::Absorbed, last);
                    }
                    continue;
                }
                Event::Absorber { object } => {
                    tree.ledger.absorbed += power;
                    match objects[object].role {
                        Role::Blade { surface, .. } => break (RayStatus::Vignetted, surface as u32),
                        Role::Wall { surface, .. } => break (RayStatus::Absorbed, surface as u32),
                        _ => break (RayStatus::Absorbed, last),
                    }
                }
                Event::Pass { point } => {
                    node.p = point;
                    node.tnear = f32_ulps(point, 16.0);
                    // Passes count toward the bounce limit too: a walk always ends.
                    passes += 1;
                    if passes >= options.max_bounces {
                        tree.ledger.truncated += power;
                        break (RayStatus::BounceLimit, last);
                    }
                    continue;
                }
                Event::Optical { object, t } => {
                    let obj = &objects[object];
                    let patch = obj.patch.as_ref().expect("optical solids have patches");
                    let surface = surface_of(&obj.role);
                    let p0 = obj.frame.point_to_local(node.p);
                    let dl = obj.frame.dir_to_local(node.d);
                    let Some(te) = patch.nearest_root(p0, dl, t) else {
                        tree.ledger.truncated += power;
                        break (RayStatus::NoConvergence, surface);
                    };
                    let mut p = p0 + dl * te;
                    if matches!(patch.shape, crate::surfaces::SurfaceShape::Plane | crate::surfaces::SurfaceShape::Paraxial { .. }) {
                        p.z = 0.0;
                    }
                    let normal = patch.shape.normal(p);
                    if !(p.is_finite() && normal.is_finite()) {
                        tree.ledger.truncated += power;
                        break (RayStatus::NoConvergence, surface);
                    }
                    if let Some((s, _)) = obj.apertures.iter().find(|(_, ap)| !ap.contains(p.x, p.y)) {
                        tree.ledger.absorbed += power;
                        break (RayStatus::Vignetted, *s as u32);
                    }
                    match &obj.role {
                        Role::Detector { front_medium, back_medium, .. } => {
                            let (n1, n2) = (n[*front_medium], n[*back_medium]);
                            match if n1 != n2 { refract(dl, normal, n1, n2) } else { Some(dl) } {
                                Some(out_d) => {
                                    tree.ledger.detector += power;
                                    tree.arrivals.push(Arrival { path: node.path.clone(), point: p, direction: out_d, power, scatters: node.scatters });
                                    break (RayStatus::Ok, u32::MAX);
                                }
                                None => {
                                    tree.ledger.truncated += power;
                                    break (RayStatus::TotalInternalReflection, surface);
                                }
                            }
                        }
                        Role::Interface { surfaces, front_medium, back_medium, paraxial_focal_mm, side_surfaces } => {
                            let forward = dl.dot(normal) > 0.0;
                            let (m1, m2) = if forward { (*front_medium, *back_medium) } else { (*back_medium, *front_medium) };
                            let (n1, n2) = (n[m1], n[m2]);
                            let reflect_d = dl - 2.0 * dl.dot(normal) * normal;
                            let new_d = match paraxial_focal_mm {
                                Some(f) => paraxial_deflect(p, dl, *f, n1, n2),
                                None => match refract(dl, normal, n1, n2) {
                                    None => {
                                        // TIR: the whole ray reflects (with the TIR phase in the polarised model).
                                        if model == FresnelModel::Polarized {
                                            let c = interface_coefficients(coatings[surfaces[0]].as_ref(), n1, n2, dl.dot(normal), wavelength_nm);
                                            let (k, nrm, kr) = (node.d, obj.frame.dir_to_global(normal), obj.frame.dir_to_global(reflect_d).normalize());
                                            let basis = sp_basis(k, nrm, kr);
                                            node.e = node.e.map(|e| apply_prt(&e, basis, c.rs, c.rp));
                                        }
                                        reflect_d
                                    }
                                    Some(td) => {
                                        if model != FresnelModel::Off {
                                            let c = interface_coefficients(coatings[surfaces[0]].as_ref(), n1, n2, dl.dot(normal), wavelength_nm);
                                            let k = node.d;
                                            let nrm = obj.frame.dir_to_global(normal);
                                            let kr = obj.frame.dir_to_global(reflect_d).normalize();
                                            let kt = obj.frame.dir_to_global(td).normalize();
                                            let mut child = node.clone();
                                            match model {
                                                FresnelModel::Polarized => {
                                                    let (br, bt) = (sp_basis(k, nrm, kr), sp_basis(k, nrm, kt));
                                                    child.e = node.e.map(|e| apply_prt(&e, br, c.rs, c.rp));
                                                    node.e = node.e.map(|e| apply_prt(&e, bt, c.ts, c.tp));
                                                }
                                                _ => {
                                                    let r = c.reflectance();
                                                    child.w = node.w * r;
                                                    node.w *= 1.0 - r;
                                                }
                                            }
                                            let cp = child.power(model);
                                            if (node.path.len() as u32) < options.order {
                                                child.p = obj.frame.point_to_global(p);
                                                child.d = kr;
                                                child.exclude = Some(object);
                                                child.interactions = node.interactions + 1;
                                                // Labelled by the sequential surface the face is from the side the ray
                                                // meets it (a face crossed twice: 2R from the air, 4R from the glass).
                                                child.path.push(side_surfaces[usize::from(!forward)] as u32);
                                                if roulette(&mut child, cp, options.threshold, model, &mut rng, &mut tree.ledger) {
                                                    stack.push(child);
                                                }
                                            } else {
                                                tree.ledger.truncated += cp;
                                            }
                                            let tp = node.power(model);
                                            if !roulette(&mut node, tp, options.threshold, model, &mut rng, &mut tree.ledger) {
                                                break (RayStatus::Absorbed, surface);
                                            }
                                        }
                                        td
                                    }
                                },
                            };
                            node.p = obj.frame.point_to_global(p);
                            let k_in = node.d;
                            node.d = obj.frame.dir_to_global(new_d).normalize();
                            if paraxial_focal_mm.is_some() && model == FresnelModel::Polarized {
                                // An ideal lens bends the ray without loss: the field turns with it (unit
                                // s and p amplitudes in the plane of k and k′), staying transverse.
                                let basis = sp_basis(k_in, node.d, node.d);
                                let one = num_complex::Complex64::new(1.0, 0.0);
                                node.e = node.e.map(|e| apply_prt(&e, basis, one, one));
                            }
                            node.exclude = Some(object);
                            node.interactions += 1;
                            if node.interactions >= options.max_bounces {
                                tree.ledger.truncated += node.power(model);
                                break (RayStatus::BounceLimit, surface);
                            }
                        }
                        Role::Mirror { .. } => {
                            // A perfect reflector: one reflected ray with the whole power (no Fresnel
                            // split, no transmitted child, not a ghost); grazing → missed, never NaN.
                            if dl.dot(normal).abs().is_nan() || dl.dot(normal).abs() <= GRAZING_COS {
                                tree.ledger.escaped += power;
                                break (RayStatus::Missed, surface);
                            }
                            let k_in = node.d;
                            node.p = obj.frame.point_to_global(p);
                            node.d = obj.frame.dir_to_global(reflect(dl, normal)).normalize();
                            if model == FresnelModel::Polarized {
                                // Perfect conductor: r_s = −1, r_p = +1 (|r| = 1: the power is kept).
                                let basis = sp_basis(k_in, obj.frame.dir_to_global(normal), node.d);
                                let (rs, rp) = (num_complex::Complex64::new(-1.0, 0.0), num_complex::Complex64::new(1.0, 0.0));
                                node.e = node.e.map(|e| apply_prt(&e, basis, rs, rp));
                            }
                            node.exclude = Some(object);
                            node.interactions += 1;
                            if node.interactions >= options.max_bounces {
                                tree.ledger.truncated += node.power(model);
                                break (RayStatus::BounceLimit, surface);
                            }
                        }
                        _ => unreachable!("optical solids are interfaces, mirrors or the detector"),
                    }
                }
            }
        };
        if main && tree.main_status.is_none() {
            tree.main_status = Some(status);
            tree.main_surface = surface;
        }
    }
    tree
}

/// Russian roulette on a node of power `w` (launched power 1): true if it goes on (boosted if it was
/// below the threshold), false if dropped. Books the ledger's `rouletted` term.
fn roulette(node: &mut Node, w: f64, threshold: f64, model: FresnelModel, rng: &mut ChaCha8Rng, ledger: &mut Ledger) -> bool {
    if w >= threshold {
        return true;
    }
    if w <= 0.0 {
        ledger.rouletted += w;
        return false;
    }
    let q = w / threshold;
    if rng.gen::<f64>() < q {
        match model {
            FresnelModel::Polarized => node.e = node.e.map(|e| e.scale((1.0 / q).sqrt())),
            _ => node.w = w / q,
        }
        ledger.rouletted -= node.power(model) - w;
        true
    } else {
        ledger.rouletted += w;
        false
    }
}

/// The sequential surface an object stands for (an interface: its last merged surface, as the Embree
/// tracer reports it).
fn surface_of(role: &Role) -> u32 {
    match role {
        Role::Interface { surfaces, .. } => *surfaces.last().expect("an interface has surfaces") as u32,
        Role::Mirror { surface, .. } | Role::Detector { surface, .. } | Role::Blade { surface, .. } | Role::Wall { surface, .. } => *surface as u32,
    }
}
