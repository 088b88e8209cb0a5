//! The CPU twin of the device trace kernels: `dc_trace_batch_ray` of `src/gpu/kernels/dc_trace.h`, compiled
//! for the host by `build.rs` and run over rayon chunks, as a [`Tracer`]. It exists so that the code the GPU
//! runs is tested where there is no GPU: in f64 (`dc_trace_kernel`) it must equal the Rust scalar kernel
//! (`Kernel::Scalar`) ray for ray, in f32 (`dc_trace_f32_kernel`, [`TwinTracer::f32`]) the f32 lane kernel
//! ([`crate::tracer::AnalyticF32Tracer`]) — landing points, directions and statuses, bit for bit (tests below
//! and `tests/gpu_twin.rs`).
use super::ffi::{dc_trace_batch_host, layouts_match, status_of, TRACE_F32, TRACE_F64};
use super::pack::{self, Batch};
use crate::error::Result;
use crate::rays::RayBatch;
use crate::system::SequentialSystem;
use crate::tracer::{Precision, RaySlices, TracedBatch, Tracer};
use rayon::prelude::*;

/// The device trace kernel run on the host, in f64 (the default) or f32. `chunk_size` rays per rayon task.
#[derive(Clone, Debug)]
pub struct TwinTracer {
    pub chunk_size: usize,
    /// f64: `dc_trace_kernel`, the scalar kernel's numbers; f32: `dc_trace_f32_kernel`, the f32 lane kernel's.
    pub precision: Precision,
}

impl Default for TwinTracer {
    fn default() -> Self {
        TwinTracer { chunk_size: 4096, precision: Precision::F64 }
    }
}

impl TwinTracer {
    /// The f32 trace kernel's twin: [`crate::tracer::AnalyticF32Tracer`]'s numbers.
    pub fn f32() -> Self {
        TwinTracer { precision: Precision::F32, ..Self::default() }
    }

    /// Trace with `dc_trace_batch_host` in `mode` (`DC_TRACE_*`).
    pub(crate) fn trace_mode(&self, system: &SequentialSystem, rays: RaySlices<'_>, mode: u32) -> Result<TracedBatch> {
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
                unsafe { dc_trace_batch_host(&batch, 0, batch.n_rays, mode) };
            });
        out.status = status.into_iter().map(status_of).collect();
        out.classify_out_of_range(system.surfaces.len().saturating_sub(1) as u32);
        Ok(out)
    }
}

impl Tracer for TwinTracer {
    fn name(&self) -> String {
        format!("gpu-twin-{}", self.precision.name())
    }

    fn trace(&self, system: &SequentialSystem, rays: &RayBatch) -> Result<TracedBatch> {
        self.trace_slices(system, rays.as_slices()?)
    }

    fn trace_slices(&self, system: &SequentialSystem, rays: RaySlices<'_>) -> Result<TracedBatch> {
        self.trace_mode(system, rays, if self.precision == Precision::F32 { TRACE_F32 } else { TRACE_F64 })
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

    /// The landing kernel's f32 input rule (`dc_trace_ray_raw_f32`) equals the renderer's (`LaneBlock::set_raw`,
    /// then `trace_block_raw`: rescaling of extreme directions in f64, the 1 m origin check, normalisation in
    /// f32) on constructed rays — unreliable inputs among the presets' chief and marginal rays, each block of
    /// lanes traced at every SIMD level — statuses, surfaces and bits.
    #[test]
    fn raw_f32_rule_equals_the_renderers_f32_lanes() {
        use crate::tracer::simd::{trace_block_raw, BlockF32, LANES_F32};
        use crate::tracer::SimdLevel;
        use glam::DVec3;
        let (nan, inf) = (f64::NAN, f64::INFINITY);
        let odd = [
            (DVec3::new(nan, 0.0, 0.0), DVec3::Z),
            (DVec3::ZERO, DVec3::new(0.0, inf, 1.0)),
            (DVec3::ZERO, DVec3::ZERO),
            (DVec3::ZERO, DVec3::new(0.0, 0.0, 1e-310)),
            (DVec3::ZERO, DVec3::new(1e-3, 0.0, 1e300)),
            (DVec3::ZERO, DVec3::new(2e-16, 1e-17, 3e-16)),
            (DVec3::ZERO, DVec3::new(1e-40, 1e-41, 1e-39)),
            (DVec3::ZERO, DVec3::new(0.0, 2e15, 3e15)),
            (DVec3::ZERO, DVec3::new(0.0, 1e-30, 1e30)),
            (DVec3::new(1e300, 0.0, 0.0), DVec3::Z),
            (DVec3::new(0.0, -1000.0, 0.0), DVec3::Z),
            (DVec3::new(0.0, -1000.0001, 0.0), DVec3::Z),
            (DVec3::new(0.0, 0.0, nan), DVec3::Z),
            (DVec3::new(0.1, 0.2, 0.0), DVec3::new(1e-8, -2e-8, 3.0)),
            (DVec3::ZERO, DVec3::X),
            (DVec3::ZERO, -DVec3::Z),
        ];
        for name in ["sp", "ap", "msp", "map"] {
            let sys = SequentialSystem::build(&crate::presets::spec(name).unwrap()).unwrap();
            let fields: Vec<[f64; 2]> = (0..9).flat_map(|i| (0..9).map(move |j| [-3.0 + 0.75 * i as f64, -3.0 + 0.75 * j as f64])).collect();
            let mut rays = RayBatch::with_capacity(0);
            for f in &fields {
                for (px, py) in [(0.0, 0.0), (1.0, 0.0), (0.0, -1.0), (0.7, 0.7), (1.2, 0.0)] {
                    let (o, d) = crate::rays::object_ray(&sys, *f, px, py);
                    rays.push(o, d * 2.5, 520.0); // not unit: the rule normalises
                }
            }
            for &(o, d) in &odd {
                rays.push(o, d, 520.0);
            }
            let twin = TwinTracer::f32().trace_mode(&sys, rays.as_slices().unwrap(), crate::gpu::ffi::TRACE_F32_RAW).unwrap();
            let n = sys.indices(520.0).unwrap();
            let tables = [n.as_slice(); LANES_F32];
            for level in SimdLevel::available() {
                for start in (0..rays.len()).step_by(LANES_F32) {
                    let m = (rays.len() - start).min(LANES_F32);
                    let mut b = BlockF32::default();
                    for k in 0..m {
                        b.set_raw(k, rays.origin(start + k), rays.direction(start + k));
                    }
                    trace_block_raw(level, &sys.path, &tables, &mut b);
                    for k in 0..m {
                        let i = start + k;
                        match b.result(k) {
                            Ok((p, d)) => {
                                assert_eq!(twin.status[i], crate::tracer::RayStatus::Ok, "{name} {} ray {i}", level.name());
                                for (a, w) in [(twin.x[i], p.x), (twin.y[i], p.y), (twin.z[i], p.z), (twin.dir_x[i], d.x), (twin.dir_y[i], d.y), (twin.dir_z[i], d.z)] {
                                    assert_eq!(a.to_bits(), w.to_bits(), "{name} {} ray {i}: {a} vs {w}", level.name());
                                }
                            }
                            Err((st, surface)) => {
                                assert_eq!((twin.status[i], twin.surface[i]), (st, surface as u32), "{name} {} ray {i}", level.name());
                            }
                        }
                    }
                }
            }
            let invalid = twin.status.iter().filter(|&&s| s == crate::tracer::RayStatus::InvalidInput).count();
            assert!(invalid >= 6, "{name}: {invalid} invalid inputs");
            assert!(twin.status.iter().filter(|&&s| s == crate::tracer::RayStatus::Ok).count() > fields.len(), "{name}: rays must arrive");
        }
    }
}
