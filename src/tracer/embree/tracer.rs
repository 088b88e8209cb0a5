//! [`EmbreeTracer`]: the non-sequential Embree backend of the [`Tracer`] trait.
//!
//! Each ray is followed through the [`OpticalScene`]: Embree finds the next geometry (f32, the cheap
//! preliminary hit), then the surface interaction is computed in f64 — exactly re-solved on the
//! identified surface with [`Refinement::F64`], or taken from Embree's f32 distance with
//! [`Refinement::None`] (mesh normals interpolated from the exact vertex normals, user-geometry normals
//! from the callback). Refraction is vector Snell's law with the media on the two sides of the
//! interface; a mirror face reflects specularly (d′ = d − 2(d·n̂)n̂ at the exact normal, the ray's weight
//! unchanged: reflectivity 1, nothing transmitted; a grazing hit, |d·n̂| ≤ [`GRAZING_COS`], is `missed` as in
//! the sequential kernel); total internal reflection is *followed* (the ray reflects and goes on) until the detector,
//! an absorber (side wall → [`RayStatus::Absorbed`], aperture blade → [`RayStatus::Vignetted`]), a miss,
//! or [`EmbreeOptions::max_bounces`] interactions ([`RayStatus::BounceLimit`]).
//!
//! The surface a ray just left is excluded from its next query with Embree's ray masks (one bit per
//! interface), so a ray never re-hits its own surface at t ≈ 0 (the classic self-intersection problem);
//! consequently a ray cannot meet the *same* surface twice in a row, which for these systems (planes and
//! lens surfaces convex toward the ray) never happens physically.
//!
//! Where precision is lost: Embree works in f32 on global coordinates (up to ~300 mm here, ulp ≈ 3e-5 mm),
//! so unrefined hit points carry ~1e-5 mm errors, and mesh facets add their chord-sag error to positions
//! and their interpolated normals an O(h²) direction error. With [`Refinement::F64`] the f32 result only
//! *identifies* the surface, and the answers equal the analytic tracer's.
//!
//! ```no_run
//! use diffcassi::prelude::*;
//! use diffcassi::tracer::embree::{EmbreeOptions, EmbreeTracer};
//! let sys = SequentialSystem::build(&presets::spec("sp")?)?;
//! let rays = RayBatch::chief_rays(&sys, &[[0.0, 0.0], [2.5, 2.5]], 520.0)?;
//! let out = EmbreeTracer::new(EmbreeOptions::default()).trace(&sys, &rays)?;
//! let exact = AnalyticTracer::default().trace(&sys, &rays)?;
//! assert!((out.x[1] - exact.x[1]).abs() < 1e-6);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::floor::{QueryLog, QueryStep};
use super::scene::{OpticalScene, Role, SceneObject, SceneOptions, SurfaceRepresentation};
use super::wrapper::{with_flush_denormals, ExactRay, ExactRays, Hit, Ray};
use crate::error::{Error, Result};
use crate::rays::RayBatch;
use crate::surfaces::{MeshResolution, SurfacePatch};
use crate::system::SequentialSystem;
use crate::tracer::analytic::index_table;
use crate::tracer::hits::{HitKind, HitLog, HitRecord};
use crate::tracer::kernel::{paraxial_deflect, reflect, refract, unit_direction, GRAZING_COS};
use crate::tracer::{RayStatus, TracedBatch, Tracer};
use glam::DVec3;
use rayon::prelude::*;
use std::sync::{Arc, Mutex};

/// How an Embree hit becomes a surface interaction.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refinement {
    /// Use Embree's f32 distance (and the mesh's interpolated or the callback's normal).
    None,
    /// Re-solve the hit exactly in f64 on the surface Embree identified.
    F64,
}

/// Embree backend options.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EmbreeOptions {
    pub scene: SceneOptions,
    pub refine: Refinement,
    /// Trace bundles of 16 consecutive rays with `rtcIntersect16` instead of one by one (`rtcIntersect1`).
    pub packets: bool,
    /// With `packets`, pass `RTC_RAY_QUERY_FLAG_COHERENT` (Embree's frustum traversal for bundles of similar
    /// rays). Off by default. Embree 4.3.3 loses the hits of a coherent packet's lanes when another lane's
    /// direction has a component 0 < |c| < 1e-12 (tests/embree_repro/coherent.c, variant H); the wrapper
    /// sets such components to 0 in coherent queries, and coherent packets then equal single rays bit for
    /// bit on SP and AP (tests/embree_speed.rs; docs/nonsequential.md, "Embree's coherent flag").
    pub coherent: bool,
    /// Most surface interactions (refractions + reflections) per ray.
    pub max_bounces: u32,
    /// Rays per rayon task.
    pub chunk_size: usize,
}

impl Default for EmbreeOptions {
    fn default() -> Self {
        EmbreeOptions { scene: SceneOptions::default(), refine: Refinement::F64, packets: true, coherent: false, max_bounces: 64, chunk_size: 1024 }
    }
}

impl EmbreeOptions {
    /// Analytic user geometry.
    pub fn user(refine: Refinement) -> Self {
        EmbreeOptions { refine, ..Default::default() }
    }
    /// Tessellated surfaces.
    pub fn mesh(resolution: MeshResolution, refine: Refinement) -> Self {
        EmbreeOptions { scene: SceneOptions { representation: SurfaceRepresentation::Mesh(resolution), ..Default::default() }, refine, ..Default::default() }
    }
}

/// Per-ray diagnostics of a non-sequential trace.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TraceDetails {
    /// Total internal reflections followed.
    pub reflections: Vec<u16>,
    /// Surface interactions (refractions, reflections, ideal-lens deflections).
    pub interactions: Vec<u16>,
    /// Largest |z − sag(x, y)| of the ray's hit points on their exact surfaces (mm): the geometric error
    /// of the hit (0 with f64 refinement up to rounding; the chord-sag error for meshes).
    pub max_hit_deviation_mm: Vec<f64>,
    /// Sequential index of the surface where the ray was first totally internally reflected, `u32::MAX`
    /// if it never was: where the sequential tracer would have stopped it with
    /// [`RayStatus::TotalInternalReflection`] (the classification the two backends share).
    pub first_reflection_surface: Vec<u32>,
}

/// The Embree backend. The scene of a system is built on first use and cached (keyed by the resolved
/// spec), so repeated batches on one system pay for it once.
pub struct EmbreeTracer {
    pub options: EmbreeOptions,
    cache: Mutex<Option<(String, Arc<OpticalScene>)>>,
}

impl std::fmt::Debug for EmbreeTracer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("EmbreeTracer").field("options", &self.options).finish()
    }
}

/// One ray's state during the non-sequential walk (global frame).
#[derive(Clone, Copy)]
struct Walk {
    p: DVec3,
    d: DVec3,
    /// Start of the next query's interval (mm along `d`), 0 except right after passing an aperture edge.
    tnear: f32,
    exclude: u32,
    interactions: u16,
    reflections: u16,
    max_dev: f64,
    /// Whether `max_dev` is measured (a sag evaluation per hit): only when the details are returned.
    measure_dev: bool,
    first_reflection: u32,
    last_surface: u32,
    done: bool,
    status: RayStatus,
    out_p: DVec3,
    out_d: DVec3,
    /// The roots the analytic user geometry of Embree's hit (its geometry ID) solved on this ray's exact
    /// ray during the last query, reused by the f64 refinement instead of solving the surface again.
    solved: Option<(u32, [Option<f64>; 2])>,
}

impl Walk {
    fn new(o: DVec3, d: DVec3, measure_dev: bool) -> Self {
        let unit = unit_direction(d).filter(|_| o.is_finite());
        let valid = unit.is_some();
        Walk {
            p: o,
            d: unit.unwrap_or(DVec3::Z),
            tnear: 0.0,
            exclude: 0,
            interactions: 0,
            reflections: 0,
            max_dev: 0.0,
            measure_dev,
            first_reflection: u32::MAX,
            last_surface: 0,
            done: !valid,
            status: if valid { RayStatus::Ok } else { RayStatus::InvalidInput },
            out_p: DVec3::ZERO,
            out_d: DVec3::ZERO,
            solved: None,
        }
    }
    fn exact(&self) -> ExactRay {
        ExactRay { org: self.p, dir: self.d }
    }
    fn ray(&self) -> Ray {
        let mut r = Ray::new(self.p.as_vec3().to_array(), self.d.as_vec3().to_array());
        r.mask = !self.exclude;
        r.tnear = self.tnear;
        r
    }
    fn finish(&mut self, status: RayStatus, surface: usize) {
        self.done = true;
        self.status = status;
        self.last_surface = surface as u32;
    }
}

impl EmbreeTracer {
    pub fn new(options: EmbreeOptions) -> Self {
        EmbreeTracer { options, cache: Mutex::new(None) }
    }

    /// The scene of `system` (built, or taken from the cache).
    pub fn scene_for(&self, system: &SequentialSystem) -> Result<Arc<OpticalScene>> {
        let key = format!("{:?}", system.spec);
        let mut cache = self.cache.lock().map_err(|_| Error::invalid("Embree scene cache poisoned by an earlier panic"))?;
        if let Some((k, s)) = cache.as_ref() {
            if *k == key {
                return Ok(s.clone());
            }
        }
        let scene = Arc::new(OpticalScene::build(system, &self.options.scene)?);
        *cache = Some((key, scene.clone()));
        Ok(scene)
    }

    /// Trace with per-ray diagnostics.
    pub fn trace_detailed(&self, system: &SequentialSystem, rays: &RayBatch) -> Result<(TracedBatch, TraceDetails)> {
        self.trace_inner(system, rays, false, true, false).map(|(out, details, _, _)| (out, details))
    }

    /// Trace with per-ray diagnostics and the [`HitLog`] of every interaction: the interface hit (its
    /// merged sequential surfaces), the hit point in its frame (f64-refined with [`Refinement::F64`]), the
    /// incoming direction, the media, and whether the ray refracted, was deflected by an ideal lens or
    /// totally reflected; the detector hit last. Recording is only done here: [`Self::trace_detailed`] and
    /// [`Tracer::trace`] record nothing. The traced values are the same bits either way.
    pub fn trace_with_hits(&self, system: &SequentialSystem, rays: &RayBatch) -> Result<(TracedBatch, TraceDetails, HitLog)> {
        self.trace_inner(system, rays, true, true, false).map(|(out, details, log, _)| (out, details, log.unwrap_or_default()))
    }

    /// Trace and record every packet query of the walk, per ray: the ray as queried (exact ray, tnear,
    /// mask) and Embree's answer (geometry, f32 distance) — what the floor benchmark replays
    /// ([`super::floor`]). Packets only (the default); the traced values are the same bits as
    /// [`Tracer::trace`]'s.
    pub fn record_queries(&self, system: &SequentialSystem, rays: &RayBatch) -> Result<(TracedBatch, QueryLog)> {
        if !self.options.packets {
            return Err(Error::invalid("recording the walk's queries needs packets (EmbreeOptions::packets)"));
        }
        let (out, _, _, steps) = self.trace_inner(system, rays, false, false, true)?;
        Ok((out, QueryLog { steps: steps.unwrap_or_default(), chunk_size: self.options.chunk_size.max(16) }))
    }

    /// With `details`, the per-ray hit deviation is measured (otherwise left 0: [`Tracer::trace`] drops
    /// the details); the traced values are the same bits either way. With `queries`, every packet query
    /// of each ray is returned too ([`Self::record_queries`]).
    #[allow(clippy::type_complexity)]
    fn trace_inner(&self, system: &SequentialSystem, rays: &RayBatch, record: bool, details: bool, queries: bool) -> Result<(TracedBatch, TraceDetails, Option<HitLog>, Option<Vec<Vec<QueryStep>>>)> {
        if !rays.is_consistent() {
            return Err(Error::invalid("ray batch columns have different lengths"));
        }
        if self.options.max_bounces == 0 || self.options.max_bounces > u16::MAX as u32 {
            return Err(Error::invalid(format!("max_bounces = {}: must be in 1..=65535", self.options.max_bounces)));
        }
        let table = index_table(system, &rays.wavelength_nm)?;
        let scene = self.scene_for(system)?;
        let n = rays.len();
        let chunk = self.options.chunk_size.max(16);
        let parts: Vec<(Vec<Walk>, Vec<Vec<HitRecord>>, Vec<Vec<QueryStep>>)> = (0..n.div_ceil(chunk))
            .into_par_iter()
            .map(|c| {
                let range = c * chunk..((c + 1) * chunk).min(n);
                with_flush_denormals(|| self.trace_range(&scene, &table, rays, range, record, details, queries))
            })
            .collect();
        let mut walks: Vec<Walk> = Vec::with_capacity(n);
        let mut logs: Vec<Vec<HitRecord>> = Vec::with_capacity(if record { n } else { 0 });
        let mut steps: Vec<Vec<QueryStep>> = Vec::with_capacity(if queries { n } else { 0 });
        for (w, l, q) in parts {
            walks.extend(w);
            logs.extend(l);
            steps.extend(q);
        }
        let mut out = TracedBatch::zeroed(n);
        let mut details = TraceDetails { reflections: vec![0; n], interactions: vec![0; n], max_hit_deviation_mm: vec![0.0; n], first_reflection_surface: vec![u32::MAX; n] };
        for (i, w) in walks.iter().enumerate() {
            out.status[i] = w.status;
            details.reflections[i] = w.reflections;
            details.interactions[i] = w.interactions;
            details.max_hit_deviation_mm[i] = w.max_dev;
            details.first_reflection_surface[i] = w.first_reflection;
            if w.status == RayStatus::Ok {
                (out.x[i], out.y[i], out.z[i]) = (w.out_p.x, w.out_p.y, w.out_p.z);
                (out.dir_x[i], out.dir_y[i], out.dir_z[i]) = (w.out_d.x, w.out_d.y, w.out_d.z);
            } else {
                out.surface[i] = w.last_surface;
            }
        }
        out.classify_out_of_range(system.surfaces.len().saturating_sub(1) as u32);
        Ok((out, details, record.then(|| HitLog::from_rays(logs)), queries.then_some(steps)))
    }

    /// Walk the rays of `range`; with `record`, also one hit list per ray, with `queries` (packets
    /// only) one list of its queries per ray (empty vectors otherwise).
    #[allow(clippy::too_many_arguments)]
    fn trace_range(
        &self,
        scene: &OpticalScene,
        table: &std::collections::HashMap<u64, Vec<f64>>,
        rays: &RayBatch,
        range: std::ops::Range<usize>,
        record: bool,
        details: bool,
        queries: bool,
    ) -> (Vec<Walk>, Vec<Vec<HitRecord>>, Vec<Vec<QueryStep>>) {
        // An object at infinity: each ray starts in front of every solid, on its own line (`nonseq::launch`).
        let start = |i: usize| crate::tracer::nonseq::launch::launch_origin(scene.start_plane.as_ref(), rays.origin(i), rays.direction(i));
        let mut walks: Vec<Walk> = range.clone().map(|i| Walk::new(start(i), rays.direction(i), details)).collect();
        let mut logs: Vec<Vec<HitRecord>> = if record { vec![Vec::new(); walks.len()] } else { Vec::new() };
        let mut steps: Vec<Vec<QueryStep>> = if queries && self.options.packets { vec![Vec::new(); walks.len()] } else { Vec::new() };
        let idx: Vec<&Vec<f64>> = range.map(|i| table.get(&rays.wavelength_nm[i].to_bits()).expect("every batch wavelength is in the table")).collect();
        // With f64 refinement over analytic user geometry, the callbacks solve on the exact rays and the
        // refinement reuses their roots (one surface solve per interaction).
        let exact = self.options.refine == Refinement::F64 && self.options.scene.representation == SurfaceRepresentation::User;
        if self.options.packets {
            // Packets of 16 consecutive rays (similar rays: Embree's packet traversal shares their nodes),
            // walked until all are done; finished lanes are left out of the queries. (Refilling packets with
            // the next rays as lanes finish measured slower on SP: docs/nonsequential.md, profile section.)
            let mut lanes = ExactRays::<16>::default();
            for (p, (ws, ns)) in walks.chunks_mut(16).zip(idx.chunks(16)).enumerate() {
                loop {
                    let mut packet = [Ray::new([0.0; 3], [0.0, 0.0, 1.0]); 16];
                    let mut valid = [false; 16];
                    for (k, w) in ws.iter().enumerate() {
                        if !w.done {
                            packet[k] = w.ray();
                            valid[k] = true;
                            if exact {
                                lanes.rays[k] = w.exact();
                            }
                        }
                    }
                    if !valid.iter().any(|v| *v) {
                        break;
                    }
                    // Incoherent unless asked (see `EmbreeOptions::coherent`).
                    let hits = scene.scene.intersect16_exact(&packet, &valid, self.options.coherent, exact.then_some(&lanes));
                    if queries {
                        for (k, w) in ws.iter().enumerate().filter(|(k, _)| valid[*k]) {
                            steps[p * 16 + k].push(QueryStep { exact: w.exact(), tnear: packet[k].tnear, mask: packet[k].mask, geom_id: hits[k].geom_id, t: hits[k].t });
                        }
                    }
                    for (k, w) in ws.iter_mut().enumerate() {
                        if valid[k] {
                            if exact {
                                w.solved = lanes.roots_for(k, hits[k].geom_id).map(|r| (hits[k].geom_id, r));
                            }
                            // Not recording: `logs` is empty and `get_mut` gives None.
                            self.interact(scene, ns[k], w, &hits[k], logs.get_mut(p * 16 + k));
                        }
                    }
                }
            }
        } else {
            let mut lane = ExactRays::<1>::default();
            for (i, (w, n)) in walks.iter_mut().zip(&idx).enumerate() {
                while !w.done {
                    lane.rays[0] = w.exact();
                    let hit = scene.scene.intersect1_exact(&w.ray(), exact.then_some(&lane));
                    w.solved = lane.roots_for(0, hit.geom_id).map(|r| (hit.geom_id, r));
                    self.interact(scene, n, w, &hit, logs.get_mut(i));
                }
            }
        }
        (walks, logs, steps)
    }

    /// Apply what the geometry Embree found does to the ray.
    /// With `log`, the interaction is appended to it as a [`HitRecord`].
    fn interact(&self, scene: &OpticalScene, n: &[f64], w: &mut Walk, hit: &Hit, log: Option<&mut Vec<HitRecord>>) {
        let retried = w.tnear > 0.0;
        w.tnear = 0.0;
        if !hit.is_hit() {
            let s = w.last_surface as usize;
            w.finish(RayStatus::Missed, s);
            return;
        }
        let obj = &scene.objects[hit.geom_id as usize];
        // A mesh covers its clear aperture with a margin (`scene::covering_mesh`): with f64 refinement, a
        // hit whose exact point lies outside the aperture is not a hit of the surface (the user geometry
        // never reports one); query again just past it. The root found is left for `locate`.
        if let (Refinement::F64, Some(_), Some(patch), Role::Interface { .. } | Role::Mirror { .. } | Role::Detector { .. }) = (self.options.refine, &obj.mesh, obj.patch.as_ref(), &obj.role) {
            let (p0, d) = (obj.frame.point_to_local(w.p), obj.frame.dir_to_local(w.d));
            if let Some(t) = patch.nearest_root(p0, d, hit.t as f64) {
                let x = p0 + d * t;
                if !patch.aperture.contains(x.x, x.y) {
                    w.tnear = hit.t.next_up();
                    return;
                }
                w.solved = Some((hit.geom_id, [Some(t), None]));
            }
        }
        match &obj.role {
            Role::Wall { surface, ends } => {
                // A ray refracted exactly at the rim of a solid's face starts on the side wall, which
                // shares that rim: a wall hit within a few f32 ulps of the ray's start is that shared edge
                // (a self-intersection, like re-hitting the surface just left), not an exit through the
                // side. Query again past it; a genuine wall hit further on still absorbs.
                let eps = 16.0 * f32::EPSILON * (w.p.abs().max_element().max(1.0) as f32);
                if w.interactions > 0 && hit.t < eps && !retried {
                    w.tnear = eps;
                    return;
                }
                // A ray entering a face at its rim meets the wall's edge and the face at the same f32
                // distance, and Embree may report either. With f64 refinement, if the ray meets one of the
                // faces the wall joins (inside its clear aperture, decided in f64) no later than the wall
                // (up to f32 rounding), it reaches that face: the interaction is with the face.
                if self.options.refine == Refinement::F64 {
                    let tie = 64.0 * f64::from(f32::EPSILON) * w.p.abs().max_element().max(1.0);
                    for &k in ends {
                        let face = &scene.objects[k];
                        if face.mask == w.exclude {
                            continue;
                        }
                        let Some(patch) = face.patch.as_ref() else { continue };
                        let (p, d) = (face.frame.point_to_local(w.p), face.frame.dir_to_local(w.d));
                        let Some(t) = patch.nearest_root(p, d, hit.t as f64).filter(|t| *t >= -tie && *t <= hit.t as f64 + tie) else { continue };
                        let q = p + d * t;
                        // Outside an explicit aperture: the blade, which starts at the same rim, stops it.
                        if let Some((s, _)) = face.apertures.iter().find(|(_, ap)| !ap.contains(q.x, q.y)) {
                            return w.finish(RayStatus::Vignetted, *s);
                        }
                        if patch.aperture.contains(q.x, q.y) {
                            return self.interact(scene, n, w, &Hit { t: t as f32, geom_id: k as u32, ..*hit }, log);
                        }
                    }
                }
                w.finish(RayStatus::Absorbed, *surface)
            }
            Role::Blade { surface, interface } => {
                // Aperture edges are decided in f64 when refining (closed apertures, as in the sequential
                // tracer). Embree's f32 blade may catch a ray that passes the aperture: its inner edge is
                // an inscribed polygon (inside a circular edge by r(1 − cos(π/N))) and f32 rounds the ray
                // origin by up to 2⁻²⁴ of the coordinates. Re-solve the hit on the exact figure and test
                // the apertures on that point.
                if self.options.refine == Refinement::F64 {
                    if let Some(p) = self.exact_point(obj, w, hit) {
                        if obj.apertures.iter().all(|(_, ap)| ap.contains(p.x, p.y)) {
                            match interface {
                                // The ray meets the refracting surface inside its aperture (unless it
                                // has just been refracted there and only touches the blade's edge).
                                Some(k) if scene.objects[*k].mask != w.exclude => self.refract_at(scene, &scene.objects[*k], n, w, hit, log),
                                // A virtual surface (a stop in air): the ray passes unchanged. The next
                                // query starts a few f32 ulps further, past this blade.
                                _ => {
                                    w.p = obj.frame.point_to_global(p);
                                    let scale = w.p.abs().max_element().max(1.0) as f32;
                                    w.tnear = 16.0 * f32::EPSILON * scale;
                                }
                            }
                            return;
                        }
                    }
                }
                w.finish(RayStatus::Vignetted, *surface)
            }
            Role::Detector { surface, front_medium, back_medium } => match self.locate(scene, obj, w, hit) {
                Some((p, normal, d)) => {
                    // The sequential tracer refracts at the image surface too (glass before it, air after).
                    let (n1, n2) = (n[*front_medium], n[*back_medium]);
                    let out = if n1 != n2 { refract(d, normal, n1, n2) } else { Some(d) };
                    match out {
                        Some(out_d) => {
                            if let Some(log) = log {
                                // The incoming direction, as for every record.
                                let s = *surface as u32;
                                log.push(HitRecord { first_surface: s, last_surface: s, point: p, direction: d, medium_in: *front_medium as u32, medium_out: *back_medium as u32, kind: HitKind::Detector });
                            }
                            w.out_p = p;
                            w.out_d = out_d;
                            w.finish(RayStatus::Ok, *surface);
                            w.last_surface = u32::MAX;
                        }
                        None => w.finish(RayStatus::TotalInternalReflection, *surface),
                    }
                }
                None => w.finish(RayStatus::NoConvergence, *surface),
            },
            Role::Interface { .. } | Role::Mirror { .. } => self.refract_at(scene, obj, n, w, hit, log),
        }
    }

    /// The ray meets mirror `obj` (sequential surface `surface`, in medium `medium`): specular reflection
    /// d′ = d − 2(d·n̂)n̂ at the exact normal, the weight unchanged (a perfect reflector: no Fresnel split, no
    /// transmitted ray; mirror reflections are not counted in [`TraceDetails::reflections`], which counts the
    /// total internal reflections the sequential tracer would stop at). Logged as [`HitKind::Mirror`] with
    /// the media the sequential log gives a mirror step (before: `medium`, after: `surface`, the same medium).
    #[allow(clippy::too_many_arguments)]
    fn reflect_at(&self, scene: &OpticalScene, obj: &SceneObject, surface: usize, medium: usize, w: &mut Walk, hit: &Hit, log: Option<&mut Vec<HitRecord>>) {
        let Some((p, normal, d)) = self.locate_within(scene, obj, w, hit, surface) else { return };
        // Grazing incidence: the ray touches the mirror without a defined reflection (the sequential
        // kernel's classification, `missed`), never a NaN direction.
        if d.dot(normal).abs().is_nan() || d.dot(normal).abs() <= GRAZING_COS {
            w.finish(RayStatus::Missed, surface);
            return;
        }
        let new_d = reflect(d, normal);
        if let Some(log) = log {
            let s = surface as u32;
            log.push(HitRecord { first_surface: s, last_surface: s, point: p, direction: d, medium_in: medium as u32, medium_out: s, kind: HitKind::Mirror });
        }
        self.leave(obj, w, p, new_d, surface);
    }

    /// The ray meets interface `obj` (located from `hit`): refract, deflect (ideal lens) or reflect (TIR);
    /// a mirror face reflects ([`Self::reflect_at`]). With `log`, the interaction is appended to it as a
    /// [`HitRecord`].
    fn refract_at(&self, scene: &OpticalScene, obj: &SceneObject, n: &[f64], w: &mut Walk, hit: &Hit, log: Option<&mut Vec<HitRecord>>) {
        if let Role::Mirror { surface, medium } = &obj.role {
            return self.reflect_at(scene, obj, *surface, *medium, w, hit, log);
        }
        let Role::Interface { surfaces, front_medium, back_medium, paraxial_focal_mm, .. } = &obj.role else {
            return w.finish(RayStatus::NoConvergence, w.last_surface as usize);
        };
        let surface = *surfaces.last().expect("an interface has surfaces");
        let Some((p, normal, d)) = self.locate_within(scene, obj, w, hit, surface) else { return };
        // The normal points to the back side (+z): a ray with d·n > 0 goes front → back.
        let forward = d.dot(normal) > 0.0;
        let (m1, m2) = if forward { (*front_medium, *back_medium) } else { (*back_medium, *front_medium) };
        let (n1, n2) = (n[m1], n[m2]);
        let mut kind = HitKind::Refraction;
        let new_d = match paraxial_focal_mm {
            Some(f) => {
                kind = HitKind::Deflection;
                paraxial_deflect(p, d, *f, n1, n2)
            }
            None => match refract(d, normal, n1, n2) {
                Some(r) => r,
                None => {
                    // Total internal reflection: followed, not dropped.
                    w.reflections = w.reflections.saturating_add(1);
                    if w.first_reflection == u32::MAX {
                        w.first_reflection = surface as u32;
                    }
                    kind = HitKind::Reflection;
                    d - 2.0 * d.dot(normal) * normal
                }
            },
        };
        if let Some(log) = log {
            let (medium_in, medium_out) = if kind == HitKind::Reflection { (m1, m1) } else { (m1, m2) };
            log.push(HitRecord { first_surface: surfaces[0] as u32, last_surface: surface as u32, point: p, direction: d, medium_in: medium_in as u32, medium_out: medium_out as u32, kind });
        }
        self.leave(obj, w, p, new_d, surface);
    }

    /// The exact (f64) point where the ray meets `obj`'s figure near Embree's distance, local frame.
    fn exact_point(&self, obj: &SceneObject, w: &Walk, hit: &Hit) -> Option<DVec3> {
        let patch = obj.patch.as_ref()?;
        let p0 = obj.frame.point_to_local(w.p);
        let d = obj.frame.dir_to_local(w.d);
        let t = patch.nearest_root(p0, d, hit.t as f64)?;
        let mut p = p0 + d * t;
        if matches!(patch.shape, crate::surfaces::SurfaceShape::Plane | crate::surfaces::SurfaceShape::Paraxial { .. }) {
            p.z = 0.0;
        }
        p.is_finite().then_some(p)
    }

    /// The hit point, the unit normal (oriented toward local +z) and the ray's direction, in the object's
    /// local frame.
    /// The walk leaves `obj` from the local hit point `p` in the local direction `new_d` after an interaction
    /// at `surface` (a reflection, refraction or deflection): back to the global frame, `obj` excluded from
    /// the next hit, and stopped at the bounce limit.
    fn leave(&self, obj: &SceneObject, w: &mut Walk, p: DVec3, new_d: DVec3, surface: usize) {
        w.p = obj.frame.point_to_global(p);
        w.d = obj.frame.dir_to_global(new_d).normalize();
        w.exclude = obj.mask;
        w.last_surface = surface as u32;
        w.interactions = w.interactions.saturating_add(1);
        if w.interactions as u32 >= self.options.max_bounces {
            w.finish(RayStatus::BounceLimit, surface);
        }
    }

    /// [`Self::locate`], finishing the walk where it fails (`surface`: no convergence) and, with f64
    /// refinement, where the exact hit point is outside one of the object's explicit apertures (decided on
    /// the exact point, closed sets, as in the sequential tracer: f32 rounding may have let a ray one ulp
    /// outside reach the surface). `None` when the walk finished.
    fn locate_within(&self, scene: &OpticalScene, obj: &SceneObject, w: &mut Walk, hit: &Hit, surface: usize) -> Option<(DVec3, DVec3, DVec3)> {
        let Some((p, normal, d)) = self.locate(scene, obj, w, hit) else {
            w.finish(RayStatus::NoConvergence, surface);
            return None;
        };
        if self.options.refine == Refinement::F64 {
            if let Some((s, _)) = obj.apertures.iter().find(|(_, ap)| !ap.contains(p.x, p.y)) {
                w.finish(RayStatus::Vignetted, *s);
                return None;
            }
        }
        Some((p, normal, d))
    }

    fn locate(&self, scene: &OpticalScene, obj: &SceneObject, w: &mut Walk, hit: &Hit) -> Option<(DVec3, DVec3, DVec3)> {
        let patch = obj.patch.as_ref()?;
        let p0 = obj.frame.point_to_local(w.p);
        let d = obj.frame.dir_to_local(w.d);
        // Embree's t is measured from the f32-rounded origin along the f32 direction (|d₃₂| ≈ 1).
        let t_embree = hit.t as f64;
        // The roots the user geometry already solved on this exact ray in this frame, if `obj` is it.
        let solved = w.solved.take().filter(|(g, _)| scene.objects.get(*g as usize).is_some_and(|o| std::ptr::eq(o, obj))).map(|(_, r)| r);
        let (p, normal) = match self.options.refine {
            Refinement::F64 => {
                let t = match solved {
                    Some(roots) => SurfacePatch::nearest_of(roots, t_embree)?,
                    None => patch.nearest_root(p0, d, t_embree)?,
                };
                let mut p = p0 + d * t;
                if matches!(patch.shape, crate::surfaces::SurfaceShape::Plane | crate::surfaces::SurfaceShape::Paraxial { .. }) {
                    p.z = 0.0; // exactly on the plane, as the sequential tracer puts it
                }
                (p, patch.shape.normal(p))
            }
            Refinement::None => {
                let p = p0 + d * t_embree;
                let n_global = match &obj.mesh {
                    Some(mesh) => {
                        let tri = mesh.triangles.get(hit.prim_id as usize)?;
                        let (u, v) = (hit.u as f64, hit.v as f64);
                        (1.0 - u - v) * mesh.normals[tri[0] as usize] + u * mesh.normals[tri[1] as usize] + v * mesh.normals[tri[2] as usize]
                    }
                    None => DVec3::new(hit.ng[0] as f64, hit.ng[1] as f64, hit.ng[2] as f64),
                };
                let mut nl = obj.frame.dir_to_local(n_global).normalize();
                if nl.z < 0.0 {
                    nl = -nl;
                }
                (p, nl)
            }
        };
        if !(p.is_finite() && normal.is_finite()) {
            return None;
        }
        if w.measure_dev {
            let sag = patch.shape.sag(p.x, p.y);
            if sag.is_finite() {
                w.max_dev = w.max_dev.max((p.z - sag).abs());
            }
        }
        Some((p, normal, d))
    }
}

impl Tracer for EmbreeTracer {
    fn name(&self) -> String {
        let geometry = match self.options.scene.representation {
            SurfaceRepresentation::User => "embree-user".to_string(),
            SurfaceRepresentation::Mesh(MeshResolution::Segments(n)) => format!("embree-mesh(segments={n})"),
            SurfaceRepresentation::Mesh(MeshResolution::MaxSagErrorUm(e)) => format!("embree-mesh(max-sag={e}um)"),
        };
        let refine = match self.options.refine {
            Refinement::F64 => "refine=f64",
            Refinement::None => "refine=none",
        };
        format!("{geometry},{refine}{}", if self.options.packets { "" } else { ",single" })
    }

    fn trace(&self, system: &SequentialSystem, rays: &RayBatch) -> Result<TracedBatch> {
        self.trace_inner(system, rays, false, false, false).map(|(out, _, _, _)| out)
    }
}
