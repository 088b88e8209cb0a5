use super::kernel::{trace_steps, unit_direction};
use super::{RaySlices, RayStatus, TracedBatch, Tracer};
use crate::error::Result;
use crate::rays::RayBatch;
use crate::system::SequentialSystem;
use glam::DVec3;
use rayon::prelude::*;
use std::collections::HashMap;

/// The exact sequential tracer: f64 throughout, exact intersections (closed form for planes and conics,
/// guarded Newton for even aspheres), vector Snell refraction. Parallel over rays with rayon; every ray is
/// independent, so results do not depend on the thread count.
#[derive(Clone, Debug)]
pub struct AnalyticTracer {
    /// Rays per rayon task.
    pub chunk_size: usize,
}

impl Default for AnalyticTracer {
    fn default() -> Self {
        AnalyticTracer { chunk_size: 4096 }
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

    /// The one implementation: reads the borrowed columns in place.
    fn trace_slices(&self, system: &SequentialSystem, rays: RaySlices<'_>) -> Result<TracedBatch> {
        let table = index_table(system, rays.wavelength_nm())?;
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
