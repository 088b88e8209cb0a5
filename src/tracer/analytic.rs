use super::kernel::{trace_steps, unit_direction};
use super::simd::{self, Kernel, LaneBlock, Real, SimdLevel, LANES, LANES_F32};
use super::{RaySlices, RayStatus, TracedBatch, Tracer};
use crate::error::Result;
use crate::rays::RayBatch;
use crate::system::SequentialSystem;
use glam::DVec3;
use rayon::prelude::*;
use std::collections::HashMap;

/// The exact sequential tracer: f64 throughout, exact intersections (closed form for planes and conics,
/// guarded Newton for even aspheres), vector Snell refraction. Parallel over rays with rayon; every ray is
/// independent, so results do not depend on the thread count. The default kernel is the lane-parallel one
/// ([`super::simd`], the same numbers as the scalar kernel); `Kernel::Scalar` keeps the reference.
#[derive(Clone, Debug)]
pub struct AnalyticTracer {
    /// Rays per rayon task.
    pub chunk_size: usize,
    /// Scalar or SIMD f64 kernel (same results).
    pub kernel: Kernel,
}

impl Default for AnalyticTracer {
    fn default() -> Self {
        AnalyticTracer { chunk_size: 4096, kernel: Kernel::Simd(None) }
    }
}

impl AnalyticTracer {
    /// The default tracer with the given kernel.
    pub const fn with_kernel(kernel: Kernel) -> Self {
        AnalyticTracer { chunk_size: 4096, kernel }
    }
}

/// Refractive indices after each surface for each distinct wavelength of a batch.
pub(crate) fn index_table(system: &SequentialSystem, wavelengths: &[f64]) -> Result<HashMap<u64, Vec<f64>>> {
    let mut table: HashMap<u64, Vec<f64>> = HashMap::new();
    for &w in wavelengths {
        if let std::collections::hash_map::Entry::Vacant(e) = table.entry(w.to_bits()) {
            e.insert(system.indices(w)?);
        }
    }
    Ok(table)
}

impl Tracer for AnalyticTracer {
    fn name(&self) -> String {
        "analytic-f64".into()
    }

    fn trace(&self, system: &SequentialSystem, rays: &RayBatch) -> Result<TracedBatch> {
        self.trace_slices(system, rays.as_slices()?)
    }

    fn as_analytic(&self) -> Option<&AnalyticTracer> {
        Some(self)
    }

    /// The one implementation: reads the borrowed columns in place.
    fn trace_slices(&self, system: &SequentialSystem, rays: RaySlices<'_>) -> Result<TracedBatch> {
        let table = index_table(system, rays.wavelength_nm())?;
        // Either kernel, then one classification of absurd landings (`out_of_range`) for both.
        let mut out = match self.kernel.resolve()? {
            Some(level) => trace_lanes::<f64, LANES>(self.chunk_size, system, rays, &table, level),
            None => self.trace_scalar(system, rays, &table),
        };
        out.classify_out_of_range(system.surfaces.len().saturating_sub(1) as u32);
        Ok(out)
    }
}

impl AnalyticTracer {
    /// [`Tracer::trace_slices`] with the scalar reference kernel, one ray at a time per chunk.
    fn trace_scalar(&self, system: &SequentialSystem, rays: RaySlices<'_>, table: &HashMap<u64, Vec<f64>>) -> TracedBatch {
        let n = rays.len();
        let mut out = TracedBatch::zeroed(n);
        let chunk = self.chunk_size.max(1);
        let path = &system.path;
        out.x
            .par_chunks_mut(chunk)
            .zip(out.y.par_chunks_mut(chunk))
            .zip(out.z.par_chunks_mut(chunk))
            .zip(out.dir_x.par_chunks_mut(chunk))
            .zip(out.dir_y.par_chunks_mut(chunk))
            .zip(out.dir_z.par_chunks_mut(chunk))
            .zip(out.status.par_chunks_mut(chunk))
            .zip(out.surface.par_chunks_mut(chunk))
            .enumerate()
            .for_each(|(c, (((((((x, y), z), dx), dy), dz), st), sf))| {
                let base = c * chunk;
                let mut cached: (u64, Option<&Vec<f64>>) = (u64::MAX, None);
                for k in 0..x.len() {
                    let i = base + k;
                    let w = rays.wavelength_nm[i].to_bits();
                    if cached.0 != w || cached.1.is_none() {
                        cached = (w, table.get(&w));
                    }
                    let idx = cached.1.expect("every batch wavelength is in the table");
                    let o = rays.origin(i);
                    let Some(d) = unit_direction(rays.direction(i)).filter(|_| o.is_finite()) else {
                        st[k] = RayStatus::InvalidInput;
                        sf[k] = 0;
                        continue;
                    };
                    match trace_steps(path, idx, o, d) {
                        Ok((p, dir)) => {
                            x[k] = p.x;
                            y[k] = p.y;
                            z[k] = p.z;
                            dx[k] = dir.x;
                            dy[k] = dir.y;
                            dz[k] = dir.z;
                        }
                        Err((status, surface)) => {
                            st[k] = status;
                            sf[k] = surface as u32;
                        }
                    }
                }
            });
        out
    }
}

/// [`Tracer::trace_slices`] with the lane kernel of float type `T`: blocks of `N` rays, each lane with
/// its own wavelength's index table; the same input checks and outputs as the scalar loop (f32 lanes also
/// refuse origins beyond [`Real::MAX_INPUT_MM`] as invalid input).
fn trace_lanes<T: Real, const N: usize>(chunk_size: usize, system: &SequentialSystem, rays: RaySlices<'_>, table: &HashMap<u64, Vec<f64>>, level: SimdLevel) -> TracedBatch {
    let n = rays.len();
    let mut out = TracedBatch::zeroed(n);
    let chunk = chunk_size.max(1);
    let path = &system.path;
    out.x
        .par_chunks_mut(chunk)
        .zip(out.y.par_chunks_mut(chunk))
        .zip(out.z.par_chunks_mut(chunk))
        .zip(out.dir_x.par_chunks_mut(chunk))
        .zip(out.dir_y.par_chunks_mut(chunk))
        .zip(out.dir_z.par_chunks_mut(chunk))
        .zip(out.status.par_chunks_mut(chunk))
        .zip(out.surface.par_chunks_mut(chunk))
        .enumerate()
        .for_each(|(c, (((((((x, y), z), dx), dy), dz), st), sf))| {
            let base = c * chunk;
            let mut cached: (u64, Option<&Vec<f64>>) = (u64::MAX, None);
            let first: &[f64] = table.values().next().map(|v| v.as_slice()).unwrap_or(&[]);
            let mut start = 0;
            while start < x.len() {
                let len = N.min(x.len() - start);
                let mut b = LaneBlock::<T, N>::default();
                let mut tables: [&[f64]; N] = [first; N];
                for k in 0..len {
                    let i = base + start + k;
                    let w = rays.wavelength_nm[i].to_bits();
                    if cached.0 != w || cached.1.is_none() {
                        cached = (w, table.get(&w));
                    }
                    let idx = cached.1.expect("every batch wavelength is in the table");
                    tables[k] = idx;
                    let o = rays.origin(i);
                    match unit_direction(rays.direction(i)).filter(|_| o.is_finite()) {
                        Some(d) => b.set_checked(k, o, d),
                        None => b.set_invalid(k),
                    }
                }
                // Padding lanes share lane 0's table so that a one-wavelength block stays uniform.
                for k in len..N {
                    tables[k] = tables[0];
                }
                simd::trace_block(level, path, &tables, &mut b);
                for k in 0..len {
                    let j = start + k;
                    match b.result(k) {
                        Ok((p, dir)) => {
                            x[j] = p.x;
                            y[j] = p.y;
                            z[j] = p.z;
                            dx[j] = dir.x;
                            dy[j] = dir.y;
                            dz[j] = dir.z;
                        }
                        Err((status, surface)) => {
                            st[j] = status;
                            sf[j] = surface as u32;
                        }
                    }
                }
                start += len;
            }
        });
    out
}


/// The analytic tracer in f32 ([`crate::tracer::Precision::F32`]): the SIMD lane kernel with
/// [`LANES_F32`] lanes of f32 (the same code as the f64 lanes, see [`simd::block`]); results are reported
/// in f64 and classified like the f64 tracer's. For rendering and the mapping cube only: its error against
/// f64 is measured by `bench tradeoff` (`docs/performance.md`, "f32 mode"); never for analyses compared to
/// Zemax.
#[derive(Clone, Debug)]
pub struct AnalyticF32Tracer {
    /// Rays per rayon task.
    pub chunk_size: usize,
    /// The instruction set (checked by [`AnalyticF32Tracer::new`] callers through `Kernel::resolve`).
    pub level: SimdLevel,
}

impl AnalyticF32Tracer {
    pub const fn new(level: SimdLevel) -> Self {
        AnalyticF32Tracer { chunk_size: 4096, level }
    }
}

impl Tracer for AnalyticF32Tracer {
    fn name(&self) -> String {
        "analytic-f32".into()
    }

    fn trace(&self, system: &SequentialSystem, rays: &RayBatch) -> Result<TracedBatch> {
        self.trace_slices(system, rays.as_slices()?)
    }

    fn as_analytic_f32(&self) -> Option<&AnalyticF32Tracer> {
        Some(self)
    }

    fn trace_slices(&self, system: &SequentialSystem, rays: RaySlices<'_>) -> Result<TracedBatch> {
        let table = index_table(system, rays.wavelength_nm())?;
        let mut out = trace_lanes::<f32, LANES_F32>(self.chunk_size, system, rays, &table, self.level.check()?);
        out.classify_out_of_range(system.surfaces.len().saturating_sub(1) as u32);
        Ok(out)
    }
}

/// Trace one ray (object frame) at one wavelength: the image-frame position and direction, or the status.
pub fn trace_single(system: &SequentialSystem, origin: DVec3, direction: DVec3, wavelength_nm: f64) -> Result<std::result::Result<(DVec3, DVec3), (RayStatus, usize)>> {
    let n = system.indices(wavelength_nm)?;
    match unit_direction(direction).filter(|_| origin.is_finite()) {
        Some(d) => Ok(trace_steps(&system.path, &n, origin, d)),
        None => Ok(Err((RayStatus::InvalidInput, 0))),
    }
}
