//! The CPU twin of the device trace kernel: `dc_trace_batch_ray` of `src/gpu/kernels/dc_trace.h`, compiled
//! for the host by `build.rs` and run over rayon chunks, as a [`Tracer`]. It exists so that the code the GPU
//! runs is tested where there is no GPU: it must equal the Rust scalar kernel (`Kernel::Scalar`) ray for ray
//! — landing points, directions and statuses (tests below and `tests/gpu_twin.rs`).
use super::ffi::{dc_trace_batch_host, layouts_match, status_of};
use super::pack::{self, Batch};
use crate::error::Result;
use crate::rays::RayBatch;
use crate::system::SequentialSystem;
use crate::tracer::{RaySlices, TracedBatch, Tracer};
use rayon::prelude::*;


/// The device trace kernel run on the host (f64). `chunk_size` rays per rayon task.
#[derive(Clone, Debug)]
pub struct TwinTracer {
    pub chunk_size: usize,
}

impl Default for TwinTracer {
    fn default() -> Self {
        TwinTracer { chunk_size: 4096 }
    }
}

impl Tracer for TwinTracer {
    fn name(&self) -> String {
        "gpu-twin-f64".into()
    }

    fn trace(&self, system: &SequentialSystem, rays: &RayBatch) -> Result<TracedBatch> {
        self.trace_slices(system, rays.as_slices()?)
    }

    fn trace_slices(&self, system: &SequentialSystem, rays: RaySlices<'_>) -> Result<TracedBatch> {
        if !layouts_match() {
            return Err(crate::error::Error::invalid("internal: the GPU kernels' C structs and their Rust twins differ in size (src/gpu/pack.rs)"));
        }
        let steps = pack::steps(system)?;
        let tables = pack::index_tables(system, rays.wavelength_nm())?;
        let n = rays.len();
        let mut out = TracedBatch::zeroed(n);
        let mut status = vec![0u8; n];
        let chunk = self.chunk_size.max(1);
        out.x
            .par_chunks_mut(chunk)
            .zip(out.y.par_chunks_mut(chunk))
            .zip(out.z.par_chunks_mut(chunk))
            .zip(out.dir_x.par_chunks_mut(chunk))
            .zip(out.dir_y.par_chunks_mut(chunk))
            .zip(out.dir_z.par_chunks_mut(chunk))
            .zip(status.par_chunks_mut(chunk))
            .zip(out.surface.par_chunks_mut(chunk))
            .enumerate()
            .for_each(|(c, (((((((x, y), z), ux), uy), uz), st), sf))| {
                let r = c * chunk..c * chunk + x.len();
                let batch = Batch {
                    path: steps.as_ptr(),
                    tables: tables.tables.as_ptr(),
                    table_of_ray: tables.table_of_ray[r.clone()].as_ptr(),
                    ox: rays.origin_x[r.clone()].as_ptr(),
                    oy: rays.origin_y[r.clone()].as_ptr(),
                    oz: rays.origin_z[r.clone()].as_ptr(),
                    dx: rays.dir_x[r.clone()].as_ptr(),
                    dy: rays.dir_y[r.clone()].as_ptr(),
                    dz: rays.dir_z[r.clone()].as_ptr(),
                    x: x.as_mut_ptr(),
                    y: y.as_mut_ptr(),
                    z: z.as_mut_ptr(),
                    ux: ux.as_mut_ptr(),
                    uy: uy.as_mut_ptr(),
                    uz: uz.as_mut_ptr(),
                    status: st.as_mut_ptr(),
                    surface: sf.as_mut_ptr(),
                    n_rays: x.len() as u64,
                    n_steps: steps.len() as u32,
                    n_surfaces: tables.n_surfaces as u32,
                };
                // SAFETY: every pointer covers `n_rays` elements of this chunk (inputs) or is this chunk's
                // own output slice; `path` has `n_steps` steps, `tables` a row of `n_surfaces` per table
                // index; the layouts were checked above; the C code only reads and writes within these.
                unsafe { dc_trace_batch_host(&batch, 0, batch.n_rays) };
            });
        out.status = status.into_iter().map(status_of).collect();
        out.classify_out_of_range(system.surfaces.len().saturating_sub(1) as u32);
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tracer::{AnalyticTracer, Kernel};
    use crate::gpu::pack::Step;

    #[test]
    fn layouts_match_the_c_compiler() {
        assert!(layouts_match(), "Step {} / Batch {} bytes", std::mem::size_of::<Step>(), std::mem::size_of::<Batch>());
    }

    #[test]
    fn twin_equals_the_scalar_kernel_on_the_presets() {
        for name in ["sp", "ap", "msp", "map"] {
            let sys = SequentialSystem::build(&crate::presets::spec(name).unwrap()).unwrap();
            let fields: Vec<[f64; 2]> = (0..9).flat_map(|i| (0..9).map(move |j| [-2.5 + 0.625 * i as f64, -2.5 + 0.625 * j as f64])).collect();
            for w in [450.0, 520.0, 650.0] {
                let rays = RayBatch::chief_rays(&sys, &fields, w).unwrap();
                let a = TwinTracer::default().trace(&sys, &rays).unwrap();
                let b = AnalyticTracer::with_kernel(Kernel::Scalar).trace(&sys, &rays).unwrap();
                assert_eq!(a.status, b.status, "{name} {w} nm");
                assert_eq!(a.surface, b.surface, "{name} {w} nm");
                for (u, v) in [(&a.x, &b.x), (&a.y, &b.y), (&a.z, &b.z), (&a.dir_x, &b.dir_x), (&a.dir_y, &b.dir_y), (&a.dir_z, &b.dir_z)] {
                    assert_eq!(u, v, "{name} {w} nm: bit-identical");
                }
            }
        }
    }
}
