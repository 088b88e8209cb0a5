//! Jacobians from hits found by another backend: the hit points come from a [`HitLog`] (the Embree
//! tracer's f64-refined hits, or [`crate::tracer::hits::sequential_hits`]), and the derivatives are
//! obtained by implicit differentiation at those hits — the intersections are never re-solved.
//!
//! Per ray, the sequential path is replayed step by step with the tangents (δp_k, δd_k) of every free
//! parameter: the frame change of each step ([`super::kernel::enter_frame`]: exact for any point on the
//! ray, so no hit on intermediate surfaces is needed), then at a surface the backend hit, the recorded
//! point q and incoming direction d give t = (q − p)·d from the previous point p, the hit tangent
//! δt = −(∂F/∂θ + ∇F·(δp + t δd))/(∇F·d) of F(q; θ) = z − sag = 0 ([`super::hit`]) and the tangent of
//! vector Snell's law or of the ideal lens ([`super::kernel`]). Coincident planes a backend merged into one
//! interface are differentiated as the separate surfaces they are in the sequential model (same point,
//! t = 0: a parameter may separate them). Surfaces a backend did not need to hit (Embree's *virtual*
//! interfaces: a dummy between equal media, or coincident planes with the same medium on both outer
//! sides) are accepted when the run of them leaves the medium unchanged; each is still differentiated as
//! the sequential model has it, at its crossing with the ray (the only place a position is computed here
//! rather than taken from the backend, since the backend has none).
//!
//! A ray's Jacobian is **unavailable, with a reason**, when its recorded path is not the sequential one:
//! it did not arrive, it was totally reflected (a non-sequential backend follows the reflection), it
//! skipped a refracting surface, crossed one backward, passed outside an explicit aperture, or its hit
//! is not on the exact surface (an unrefined f32/mesh hit). Such a ray's row is zero and
//! [`JacobianBatch::usable`] is false.
//!
//! ```
//! use diffcassi::diff::{Param, ParamSet};
//! use diffcassi::materials::GlassCatalog;
//! use diffcassi::prelude::*;
//! use diffcassi::tracer::hits::sequential_hits;
//! let set = ParamSet::new(presets::spec("sp")?, GlassCatalog::builtin(), vec![Param::parse("s4.tilt_x_deg")?])?;
//! let ds = set.build()?;
//! let rays = RayBatch::chief_rays(&ds.system, &[[0.0, 0.0], [2.5, 2.5]], 520.0)?;
//! let (traced, log) = sequential_hits(&ds.system, &rays)?;
//! let from_hits = ds.jacobian_from_hits(&rays, &traced, &log)?;
//! let direct = ds.trace(&rays)?;
//! assert!(from_hits.unavailable.iter().all(|r| r.is_none()));
//! assert!((from_hits.batch.d_position(1, 0) - direct.d_position(1, 0)).length() < 1e-12);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::hit::SurfaceLocal;
use super::jacobian::JacobianBatch;
use super::kernel::{enter_frame, interact_tangents};
use super::param::Param;
use super::DiffSystem;
use crate::error::{Error, Result};
use crate::rays::RayBatch;
use crate::surfaces::{intersect, Aperture, SurfaceShape};
use crate::tracer::hits::{HitKind, HitLog, HitRecord};
use crate::tracer::{RayStatus, TracedBatch};
use glam::DVec3;
use rayon::prelude::*;
use std::collections::HashMap;

/// Largest distance of a recorded hit from the exact surface (mm) for it to count as refined.
pub const HIT_ON_SURFACE_TOLERANCE_MM: f64 = 1e-9;
/// Largest difference between a recorded incoming direction and the sequential replay's.
const DIRECTION_TOLERANCE: f64 = 1e-9;
/// Largest distance of a recorded hit from the replayed ray line (mm).
const LINE_TOLERANCE_MM: f64 = 1e-8;

/// Jacobians from a backend's hits, with the reason a ray's Jacobian is unavailable.
#[derive(Clone, Debug)]
pub struct HitJacobianBatch {
    /// Values: the backend's traced batch (unchanged). Rows of unavailable rays are zero and
    /// `batch.finite[i]` is false for them, so `batch.usable(i)` is false.
    pub batch: JacobianBatch,
    /// `None`: the Jacobian of ray `i` is available. Otherwise why not (did not arrive, path differs
    /// from the sequential one, hit not refined, derivatives not finite).
    pub unavailable: Vec<Option<String>>,
}

impl HitJacobianBatch {
    /// Rays whose Jacobian is available.
    pub fn available_count(&self) -> usize {
        self.unavailable.iter().filter(|r| r.is_none()).count()
    }
}

/// Rays per rayon task.
const CHUNK: usize = 512;

impl DiffSystem {
    /// Jacobians of `rays` at the hits recorded in `log` (one list per ray, as the backend met them) for
    /// the backend's result `traced`. Errors: no free parameters, batch/log lengths differ, a wavelength
    /// outside a glass's range. Per-ray problems are reported in [`HitJacobianBatch::unavailable`].
    pub fn jacobian_from_hits(&self, rays: &RayBatch, traced: &TracedBatch, log: &HitLog) -> Result<HitJacobianBatch> {
        let kk = self.k();
        if kk == 0 {
            return Err(Error::invalid("Jacobian requested with no free parameters"));
        }
        if !rays.is_consistent() {
            return Err(Error::invalid("ray batch columns have different lengths"));
        }
        if traced.len() != rays.len() || log.len() != rays.len() {
            return Err(Error::invalid(format!(
                "Jacobian from hits: {} rays, {} traced results and hit records for {} rays (must be equal)",
                rays.len(),
                traced.len(),
                log.len()
            )));
        }
        let mut table: HashMap<u64, (Vec<f64>, Vec<f64>)> = HashMap::new();
        for &w in &rays.wavelength_nm {
            if let std::collections::hash_map::Entry::Vacant(e) = table.entry(w.to_bits()) {
                e.insert(self.index_tangents(w)?);
            }
        }
        let n = rays.len();
        let parts: Vec<(Vec<f64>, Vec<Option<String>>)> = (0..n.div_ceil(CHUNK))
            .into_par_iter()
            .map(|c| {
                let (lo, hi) = (c * CHUNK, ((c + 1) * CHUNK).min(n));
                let mut jac = vec![0.0; (hi - lo) * 6 * kk];
                let mut why = vec![None; hi - lo];
                let mut dp = vec![DVec3::ZERO; kk];
                let mut dd = vec![DVec3::ZERO; kk];
                for i in lo..hi {
                    let j = i - lo;
                    if traced.status[i] != RayStatus::Ok {
                        why[j] = Some(format!("ray did not arrive ({} at surface {})", traced.status[i].label(), traced.surface[i]));
                        continue;
                    }
                    let (idx, didx) = &table[&rays.wavelength_nm[i].to_bits()];
                    match self.ray_from_hits(rays.origin(i), rays.direction(i), log.ray(i), idx, didx, &mut dp, &mut dd) {
                        Err(reason) => why[j] = Some(reason),
                        Ok(()) if !dp.iter().chain(dd.iter()).all(|v| v.is_finite()) => {
                            why[j] = Some("derivatives not finite (grazing incidence or a kink)".into());
                        }
                        Ok(()) => {
                            let row = &mut jac[j * 6 * kk..(j + 1) * 6 * kk];
                            for k in 0..kk {
                                for c in 0..3 {
                                    row[c * kk + k] = dp[k][c];
                                    row[(c + 3) * kk + k] = dd[k][c];
                                }
                            }
                        }
                    }
                }
                (jac, why)
            })
            .collect();
        let mut jac = Vec::with_capacity(n * 6 * kk);
        let mut unavailable = Vec::with_capacity(n);
        for (j, w) in parts {
            jac.extend(j);
            unavailable.extend(w);
        }
        let finite = unavailable.iter().map(|r| r.is_none()).collect();
        let batch = JacobianBatch { traced: traced.clone(), params: self.params.iter().map(|p| p.name()).collect(), jac, finite };
        Ok(HitJacobianBatch { batch, unavailable })
    }

    /// Trace `rays` with the Embree backend (hits recorded, f64-refined) and differentiate at its hits.
    /// The tracer must refine its hits ([`crate::tracer::embree::Refinement::F64`]): an f32 or mesh-facet
    /// hit is not on the surface whose implicit equation is differentiated.
    #[cfg(feature = "embree")]
    pub fn trace_embree(&self, tracer: &crate::tracer::embree::EmbreeTracer, rays: &RayBatch) -> Result<HitJacobianBatch> {
        if tracer.options.refine != crate::tracer::embree::Refinement::F64 {
            return Err(Error::invalid(
                "Jacobians from Embree hits need f64-refined hits (refine f64): an unrefined hit is not on the exact surface",
            ));
        }
        if self.k() == 0 {
            return Err(Error::invalid("Jacobian requested with no free parameters"));
        }
        let (traced, _details, log) = tracer.trace_with_hits(&self.system, rays)?;
        self.jacobian_from_hits(rays, &traced, &log)
    }

    /// Jacobians with the backend `config` names: the analytic sequential trace ([`DiffSystem::trace`]) or,
    /// for the Embree backends, [`DiffSystem::trace_embree`] (f64 refinement required). Every ray whose
    /// Jacobian is not usable gets its reason, for either backend.
    pub fn trace_with_backend(&self, config: &crate::tracer::BackendConfig, rays: &RayBatch) -> Result<HitJacobianBatch> {
        match config.backend {
            crate::tracer::Backend::Analytic => {
                let batch = self.trace(rays)?;
                let unavailable = (0..batch.len())
                    .map(|i| match batch.traced.status[i] {
                        RayStatus::Ok if batch.finite[i] => None,
                        RayStatus::Ok => Some("derivatives not finite (grazing incidence or a kink)".to_string()),
                        s => Some(format!("ray did not arrive ({} at surface {})", s.label(), batch.traced.surface[i])),
                    })
                    .collect();
                Ok(HitJacobianBatch { batch, unavailable })
            }
            crate::tracer::Backend::AnalyticF32 => Err(Error::invalid("Jacobians are f64 only: the f32 kernel (analytic-f32) is for rendering")),
            #[cfg(feature = "embree")]
            crate::tracer::Backend::EmbreeUser | crate::tracer::Backend::EmbreeMesh => {
                use crate::tracer::embree::{EmbreeOptions, EmbreeTracer, Refinement};
                if config.refine != crate::tracer::Refine::F64 {
                    return Err(Error::invalid(
                        "Jacobians from Embree hits need f64-refined hits (refine f64): an unrefined hit is not on the exact surface",
                    ));
                }
                let options =
                    if config.backend == crate::tracer::Backend::EmbreeUser { EmbreeOptions::user(Refinement::F64) } else { EmbreeOptions::mesh(config.mesh, Refinement::F64) };
                self.trace_embree(&EmbreeTracer::new(options), rays)
            }
            #[cfg(not(feature = "embree"))]
            crate::tracer::Backend::EmbreeUser | crate::tracer::Backend::EmbreeMesh => {
                Err(crate::tracer::embree_missing(config.backend, crate::frontend::current()))
            }
        }
    }

    /// One ray: seed the tangents, replay the path at the recorded hits. `Err` names why the recorded
    /// path is not the sequential one.
    #[allow(clippy::too_many_arguments)]
    fn ray_from_hits(&self, o: DVec3, d0: DVec3, hits: &[HitRecord], n: &[f64], dn: &[f64], dp: &mut [DVec3], dd: &mut [DVec3]) -> std::result::Result<(), String> {
        let kk = dp.len();
        let len = d0.length();
        if !(o.is_finite() && d0.is_finite() && len > 0.0) {
            return Err("invalid input ray".into());
        }
        let u = d0 / len;
        for k in 0..kk {
            dp[k] = DVec3::ZERO;
            dd[k] = DVec3::ZERO;
            match self.params[k] {
                Param::RayOrigin(a) => dp[k][a] = 1.0,
                Param::RayDirection(a) => {
                    // ∂(d/|d|)/∂d_a = (e_a − u u_a)/|d|
                    let mut e = DVec3::ZERO;
                    e[a] = 1.0;
                    dd[k] = (e - u * u[a]) / len;
                }
                _ => {}
            }
        }
        let path = &self.system.path;
        let last = path.len() - 1;
        let (mut p, mut d) = (o, u);
        let mut h = 0;
        let mut k = 0;
        while k < path.len() {
            let (step, tan) = (&path[k], &self.steps[k]);
            (p, d) = enter_frame(step, tan, p, d, dp, dd);
            let s = step.surface;
            let Some(rec) = hits.get(h).filter(|r| r.first_surface as usize == s) else {
                // Surfaces the backend did not hit: a run of path steps up to the next recorded one. Fine
                // only when the run as a whole does nothing to the ray — the same medium before and after
                // it and no ideal lens (a dummy surface, or Embree's *virtual* merged coincident planes
                // such as the double Amici's zero-thickness split). Inside the run each surface is still
                // differentiated as the sequential model has it (a parameter may open a gap between
                // coincident planes), at its crossing with the ray.
                let next = hits.get(h).map(|r| r.first_surface as usize);
                let mut r = k;
                while r < last && Some(path[r + 1].surface) != next {
                    r += 1;
                }
                let same = |a: usize, b: usize| n[a] == n[b] && dn[a * kk..(a + 1) * kk] == dn[b * kk..(b + 1) * kk];
                let lens = path[k..=r].iter().any(|st| matches!(st.shape, SurfaceShape::Paraxial { .. }));
                if r == last || lens || !same(s - 1, path[r].surface) {
                    let met = next.map_or("nothing more".to_string(), |f| format!("surface {f}"));
                    return Err(format!("path differs from the sequential one: surface {s} was not hit (the backend met {met} next)"));
                }
                for j in k..=r {
                    let (st, tj) = (&path[j], &self.steps[j]);
                    if j > k {
                        (p, d) = enter_frame(st, tj, p, d, dp, dd);
                    }
                    let sj = st.surface;
                    let passive = same(sj - 1, sj);
                    if passive && st.aperture == Aperture::None {
                        continue; // neither the ray nor its tangents change
                    }
                    let Ok(hit) = intersect(&st.shape, p, d) else {
                        return Err(format!("path differs from the sequential one: the ray misses surface {sj}"));
                    };
                    if !st.aperture.contains(hit.point.x, hit.point.y) {
                        return Err(format!("path differs from the sequential one: outside the aperture of surface {sj}"));
                    }
                    if !passive {
                        let local = SurfaceLocal::at(&st.shape, hit.point);
                        d = interact_tangents(st, tj, &local, hit.point, hit.normal, hit.t, d, n, dn, dp, dd)
                            .map_err(|_| format!("total internal reflection at surface {sj} in the sequential model (the backend passed it)"))?;
                        p = hit.point;
                    }
                }
                k = r + 1;
                continue;
            };
            match rec.kind {
                HitKind::Reflection => {
                    return Err(format!("path differs from the sequential one: total internal reflection at surface {s}, followed by the backend"))
                }
                HitKind::Detector if k != last => return Err(format!("path differs from the sequential one: stopped on surface {s} before the image")),
                _ if k == last && rec.kind != HitKind::Detector => return Err(format!("path differs from the sequential one: surface {s} is the image but was not recorded as the detector")),
                _ => {}
            }
            // The steps of the (possibly merged) interface.
            let mut k_end = k;
            while k_end < last && (path[k_end + 1].surface as u32) <= rec.last_surface {
                k_end += 1;
            }
            if path[k_end].surface as u32 != rec.last_surface {
                return Err(format!("hit record for surfaces {}..={} does not match the sequential path", rec.first_surface, rec.last_surface));
            }
            if rec.kind != HitKind::Detector && (rec.medium_in as usize != s - 1 || rec.medium_out as usize != path[k_end].surface) {
                return Err(format!("path differs from the sequential one: surface {s} crossed backward"));
            }
            let q = rec.point;
            let din = rec.direction;
            if !(q.is_finite() && din.is_finite()) {
                return Err(format!("non-finite hit record at surface {s}"));
            }
            let sag = step.shape.sag(q.x, q.y);
            let off = if matches!(step.shape, SurfaceShape::Paraxial { .. }) { q.z.abs() } else { (q.z - sag).abs() };
            if !(off <= HIT_ON_SURFACE_TOLERANCE_MM) {
                return Err(format!("hit on surface {s} is {off:.1e} mm off the exact surface (not refined)"));
            }
            if (din - d).length() > DIRECTION_TOLERANCE {
                return Err(format!("path differs from the sequential one: incoming direction at surface {s} differs by {:.1e}", (din - d).length()));
            }
            let t = (q - p).dot(din);
            if (q - (p + din * t)).length() > LINE_TOLERANCE_MM * (1.0 + t.abs()) {
                return Err(format!("path differs from the sequential one: hit on surface {s} is off the ray"));
            }
            if !step.aperture.contains(q.x, q.y) {
                return Err(format!("path differs from the sequential one: outside the aperture of surface {s}"));
            }
            let local = SurfaceLocal::at(&step.shape, q);
            d = interact_tangents(step, tan, &local, q, local.normal, t, din, n, dn, dp, dd)
                .map_err(|_| format!("total internal reflection at surface {s} in the sequential model"))?;
            p = q;
            // Coincident planes merged by the backend: the same point, t = 0, each surface's own media.
            for j in k + 1..=k_end {
                let (st, tj) = (&path[j], &self.steps[j]);
                (p, d) = enter_frame(st, tj, p, d, dp, dd);
                if !st.aperture.contains(p.x, p.y) {
                    return Err(format!("path differs from the sequential one: outside the aperture of surface {}", st.surface));
                }
                let local = SurfaceLocal::at(&st.shape, p);
                d = interact_tangents(st, tj, &local, p, local.normal, 0.0, d, n, dn, dp, dd)
                    .map_err(|_| format!("total internal reflection at surface {} in the sequential model", st.surface))?;
            }
            h += 1;
            k = k_end + 1;
        }
        if h != hits.len() {
            return Err(format!("path differs from the sequential one: {} interactions recorded after the image", hits.len() - h));
        }
        Ok(())
    }
}
