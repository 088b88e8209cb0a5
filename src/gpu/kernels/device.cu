/* diffcassi GPU kernels, device build: the CUDA entry points over the same headers as host.c.
 *
 * Compiled to PTX by scripts/gpu/build_ptx.py with NVRTC (--fmad=false: no contraction, the same bits as
 * the host twin) and assembled by ptxas for sm_90 in the test command; the PTX is committed beside this
 * file (trace.ptx) and embedded in the library. One thread a ray.
 */
#include "dc_render.h"

extern "C" __global__ void dc_trace_kernel(dc_batch b) {
    dc_u64 i = (dc_u64)blockIdx.x * (dc_u64)blockDim.x + (dc_u64)threadIdx.x;
    if (i < b.n_rays) dc_trace_batch_ray(&b, i, DC_TRACE_F64);
}

/* The f32 trace (tracer::AnalyticF32Tracer's numbers), f64 in and out. */
extern "C" __global__ void dc_trace_f32_kernel(dc_batch b) {
    dc_u64 i = (dc_u64)blockIdx.x * (dc_u64)blockDim.x + (dc_u64)threadIdx.x;
    if (i < b.n_rays) dc_trace_batch_ray(&b, i, DC_TRACE_F32);
}

extern "C" __global__ void dc_landing_kernel(dc_landing_batch b) {
    dc_u64 t = (dc_u64)blockIdx.x * (dc_u64)blockDim.x + (dc_u64)threadIdx.x;
    if (t < b.n_pixels * (dc_u64)b.sampler.rays) dc_landing_ray(&b, t, t, 0);
}

/* The renderer's --precision f32 landings (render::transport::trace_row_lanes_f32). */
extern "C" __global__ void dc_landing_f32_kernel(dc_landing_batch b) {
    dc_u64 t = (dc_u64)blockIdx.x * (dc_u64)blockDim.x + (dc_u64)threadIdx.x;
    if (t < b.n_pixels * (dc_u64)b.sampler.rays) dc_landing_ray(&b, t, t, 1);
}

extern "C" __global__ void dc_footprint_size_kernel(const double *u, const double *v, dc_u32 n, dc_i64 det_w, dc_i64 det_h, dc_window *wins, dc_u64 n_pixels) {
    dc_u64 q = (dc_u64)blockIdx.x * (dc_u64)blockDim.x + (dc_u64)threadIdx.x;
    if (q < n_pixels) dc_footprint_size(u + q * n, v + q * n, n, det_w, det_h, &wins[q]);
}

extern "C" __global__ void dc_footprint_fill_kernel(const double *u, const double *v, dc_u32 n, dc_window *wins, const dc_u64 *offsets, double *scratch, float *weights, dc_u64 n_pixels) {
    dc_u64 q = (dc_u64)blockIdx.x * (dc_u64)blockDim.x + (dc_u64)threadIdx.x;
    if (q < n_pixels && wins[q].w > 0) dc_footprint_fill(u + q * n, v + q * n, n, &wins[q], scratch + offsets[q], weights + offsets[q]);
}
