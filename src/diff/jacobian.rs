//! Batch Jacobians: trace a [`RayBatch`] and, per ray, ∂(image position, image direction)/∂θ for every
//! free parameter. Parallel over fixed chunks of rays with rayon; each ray is independent, so the result
//! does not depend on the thread count. The plain [`crate::tracer::AnalyticTracer`] is untouched: the
//! derivatives cost nothing unless asked for.
use super::kernel::trace_tangents;
use super::param::Param;
use super::DiffSystem;
use crate::error::{Error, Result};
use crate::rays::RayBatch;
use crate::tracer::{RayStatus, TracedBatch};
use glam::DVec3;
use rayon::prelude::*;
use std::collections::HashMap;

/// Rays at the image with their Jacobians.
#[derive(Clone, Debug)]
pub struct JacobianBatch {
    /// Positions and directions, bit-identical to [`crate::tracer::AnalyticTracer`]'s.
    pub traced: TracedBatch,
    /// The free parameters' names, in column order.
    pub params: Vec<String>,
    /// `jac[(ray * 6 + c) * K + k]` = ∂(component c of x, y, z, dir_x, dir_y, dir_z) / ∂θ_k in the image frame
    /// (mm or direction units per parameter unit). Zero for rays whose status is not `Ok`.
    pub jac: Vec<f64>,
    /// False for an `Ok` ray whose derivatives are not finite (grazing incidence, a kink); its row is zeroed.
    pub finite: Vec<bool>,
}

impl JacobianBatch {
    pub fn len(&self) -> usize {
        self.traced.len()
    }
    pub fn is_empty(&self) -> bool {
        self.traced.is_empty()
    }
    pub fn k(&self) -> usize {
        self.params.len()
    }
    /// ∂(x, y, z)/∂θ_k of ray `i`.
    pub fn d_position(&self, i: usize, k: usize) -> DVec3 {
        let kk = self.k();
        DVec3::new(self.jac[(i * 6) * kk + k], self.jac[(i * 6 + 1) * kk + k], self.jac[(i * 6 + 2) * kk + k])
    }
    /// ∂(dir_x, dir_y, dir_z)/∂θ_k of ray `i`.
    pub fn d_direction(&self, i: usize, k: usize) -> DVec3 {
        let kk = self.k();
        DVec3::new(self.jac[(i * 6 + 3) * kk + k], self.jac[(i * 6 + 4) * kk + k], self.jac[(i * 6 + 5) * kk + k])
    }
    /// The K derivatives of component `c` (0..6: x, y, z, dir_x, dir_y, dir_z) of ray `i`.
    pub fn row(&self, i: usize, c: usize) -> &[f64] {
        let kk = self.k();
        &self.jac[(i * 6 + c) * kk..(i * 6 + c + 1) * kk]
    }
    /// Whether ray `i` arrived with finite derivatives.
    pub fn usable(&self, i: usize) -> bool {
        self.traced.status[i] == RayStatus::Ok && self.finite[i]
    }
}

/// Rays per rayon task.
const CHUNK: usize = 512;

impl DiffSystem {
    /// Trace `rays` (object frame) with their Jacobians. Errors: no free parameters, inconsistent batch,
    /// a wavelength outside a glass's range.
    pub fn trace(&self, rays: &RayBatch) -> Result<JacobianBatch> {
        let kk = self.k();
        if kk == 0 {
            return Err(Error::invalid("Jacobian requested with no free parameters"));
        }
        if !rays.is_consistent() {
            return Err(Error::invalid("ray batch columns have different lengths"));
        }
        let mut table: HashMap<u64, (Vec<f64>, Vec<f64>)> = HashMap::new();
        for &w in &rays.wavelength_nm {
            if let std::collections::hash_map::Entry::Vacant(e) = table.entry(w.to_bits()) {
                e.insert(self.index_tangents(w)?);
            }
        }
        let seeds: Vec<(Option<usize>, Option<usize>)> = self
            .params
            .iter()
            .map(|p| match p {
                Param::RayOrigin(a) => (Some(*a), None),
                Param::RayDirection(a) => (None, Some(*a)),
                _ => (None, None),
            })
            .collect();
        let n = rays.len();
        // The Jacobian (48·K B per ray, the batch's bulk) is allocated once at its full size and each chunk
        // writes its rows in place; only the traced columns (53 B per ray) are gathered from the chunks. A
        // per-chunk Jacobian concatenated afterwards held it twice at the peak (round 21: 10⁶ rays × 24
        // parameters peaked at 1.43 GB for a 1.15 GB Jacobian); [`crate::limits::bytes_jacobian_trace`]
        // models this layout.
        let mut jac = vec![0.0; n * 6 * kk];
        let mut finite = vec![true; n];
        let chunks: Vec<TracedBatch> = jac
            .par_chunks_mut(CHUNK * 6 * kk)
            .zip(finite.par_chunks_mut(CHUNK))
            .enumerate()
            .map(|(c, (jac_rows, finite))| {
                let lo = c * CHUNK;
                let m = finite.len();
                let mut traced = TracedBatch::zeroed(m);
                let mut dp = vec![DVec3::ZERO; kk];
                let mut dd = vec![DVec3::ZERO; kk];
                for j in 0..m {
                    let i = lo + j;
                    let (idx, didx) = &table[&rays.wavelength_nm[i].to_bits()];
                    let o = rays.origin(i);
                    let d = rays.direction(i);
                    let len = d.length();
                    if !(o.is_finite() && d.is_finite()) || !(len > 0.0) {
                        traced.status[j] = RayStatus::InvalidInput;
                        traced.surface[j] = 0;
                        continue;
                    }
                    let u = d / len;
                    for k in 0..kk {
                        dp[k] = DVec3::ZERO;
                        dd[k] = DVec3::ZERO;
                        if let Some(a) = seeds[k].0 {
                            dp[k][a] = 1.0;
                        }
                        if let Some(a) = seeds[k].1 {
                            // ∂(d/|d|)/∂d_a = (e_a − u u_a)/|d|
                            let mut e = DVec3::ZERO;
                            e[a] = 1.0;
                            dd[k] = (e - u * u[a]) / len;
                        }
                    }
                    match trace_tangents(&self.system.path, &self.steps, idx, didx, o, u, &mut dp, &mut dd) {
                        Ok((p, dir)) => {
                            traced.x[j] = p.x;
                            traced.y[j] = p.y;
                            traced.z[j] = p.z;
                            traced.dir_x[j] = dir.x;
                            traced.dir_y[j] = dir.y;
                            traced.dir_z[j] = dir.z;
                            let ok = dp.iter().chain(dd.iter()).all(|v| v.is_finite());
                            finite[j] = ok;
                            if ok {
                                let row = &mut jac_rows[j * 6 * kk..(j + 1) * 6 * kk];
                                for k in 0..kk {
                                    for c in 0..3 {
                                        row[c * kk + k] = dp[k][c];
                                        row[(c + 3) * kk + k] = dd[k][c];
                                    }
                                }
                            }
                        }
                        Err((status, surface)) => {
                            traced.status[j] = status;
                            traced.surface[j] = surface as u32;
                        }
                    }
                }
                traced
            })
            .collect();
        let mut traced = TracedBatch {
            x: Vec::with_capacity(n),
            y: Vec::with_capacity(n),
            z: Vec::with_capacity(n),
            dir_x: Vec::with_capacity(n),
            dir_y: Vec::with_capacity(n),
            dir_z: Vec::with_capacity(n),
            status: Vec::with_capacity(n),
            surface: Vec::with_capacity(n),
        };
        for c in chunks {
            traced.x.extend(c.x);
            traced.y.extend(c.y);
            traced.z.extend(c.z);
            traced.dir_x.extend(c.dir_x);
            traced.dir_y.extend(c.dir_y);
            traced.dir_z.extend(c.dir_z);
            traced.status.extend(c.status);
            traced.surface.extend(c.surface);
        }
        Ok(JacobianBatch { traced, params: self.params.iter().map(|p| p.name()).collect(), jac, finite })
    }
}

/// The incidence of a ray on one path step, with derivatives: the data of a total-internal-reflection
/// margin.
#[derive(Clone, Debug, PartialEq)]
pub struct Incidence {
    /// Surface index of the step.
    pub surface: usize,
    /// cos θᵢ (normal oriented along the ray) and ∂/∂θ_k.
    pub cos_i: f64,
    pub d_cos_i: Vec<f64>,
    /// Indices before and after, and their derivatives.
    pub n1: f64,
    pub n2: f64,
    pub dn1: Vec<f64>,
    pub dn2: Vec<f64>,
}

impl DiffSystem {
    /// Surface index of each path step.
    pub fn step_surfaces(&self) -> Vec<usize> {
        self.system.path.iter().map(|s| s.surface).collect()
    }

    /// For each ray, its incidence on path step `step` (`None` if it does not get there).
    pub fn incidence(&self, rays: &RayBatch, step: usize) -> Result<Vec<Option<Incidence>>> {
        let kk = self.k();
        let path = &self.system.path;
        if step >= path.len() {
            return Err(Error::invalid(format!("incidence: step {step} of a {}-step path", path.len())));
        }
        let mut out = Vec::with_capacity(rays.len());
        for i in 0..rays.len() {
            let (n, dn) = self.index_tangents(rays.wavelength_nm[i])?;
            let o = rays.origin(i);
            let d0 = rays.direction(i);
            let len = d0.length();
            let (mut dp, mut dd) = (vec![DVec3::ZERO; kk], vec![DVec3::ZERO; kk]);
            if !(len > 0.0) {
                out.push(None);
                continue;
            }
            let Ok((p, d)) = trace_tangents(&path[..step], &self.steps[..step], &n, &dn, o, d0 / len, &mut dp, &mut dd) else {
                out.push(None);
                continue;
            };
            let (st, tan) = (&path[step], &self.steps[step]);
            let (p1, d1) = super::kernel::enter_frame(st, tan, p, d, &mut dp, &mut dd);
            let Ok(hit) = crate::surfaces::intersect(&st.shape, p1, d1) else {
                out.push(None);
                continue;
            };
            let local = super::hit::SurfaceLocal::at(&st.shape, hit.point);
            let sgn = if d1.dot(hit.normal) < 0.0 { -1.0 } else { 1.0 };
            let nrm = hit.normal * sgn;
            let d_cos_i = (0..kk)
                .map(|k| {
                    let ht = local.tangent(d1, dp[k] + dd[k] * hit.t, &tan.shape[k]);
                    dd[k].dot(nrm) + d1.dot(ht.normal * sgn)
                })
                .collect();
            let s = st.surface;
            out.push(Some(Incidence {
                surface: s,
                cos_i: d1.dot(nrm),
                d_cos_i,
                n1: n[s - 1],
                n2: n[s],
                dn1: dn[(s - 1) * kk..s * kk].to_vec(),
                dn2: dn[s * kk..(s + 1) * kk].to_vec(),
            }));
        }
        Ok(out)
    }
}
