/* diffcassi GPU kernels, device build: the CUDA entry points over the same headers as host.c.
 *
 * Compiled to PTX by scripts/gpu/build_ptx.py with NVRTC (--fmad=false: no contraction, the same bits as
 * the host twin) and assembled by ptxas for sm_90 in the test command; the PTX is committed beside this
 * file (trace.ptx) and embedded in the library. One thread a ray.
 */
#include "dc_accum.h"

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
    if (t < b.n_pixels * (dc_u64)b.sampler.rays) dc_landing_ray(&b, t, t, 0, 0);
}

/* The renderer's --precision f32 landings (render::transport::trace_row_lanes_f32). */
extern "C" __global__ void dc_landing_f32_kernel(dc_landing_batch b) {
    dc_u64 t = (dc_u64)blockIdx.x * (dc_u64)blockDim.x + (dc_u64)threadIdx.x;
    if (t < b.n_pixels * (dc_u64)b.sampler.rays) dc_landing_ray(&b, t, t, 1, 0);
}

/* The same with ray aiming (dc_aimed_ray: OpticStudio's RAIM, rays::aimed_ray), launched when the system aims:
 * separate builds, so that the unaimed kernels keep their registers. */
extern "C" __global__ void dc_landing_aimed_kernel(dc_landing_batch b) {
    dc_u64 t = (dc_u64)blockIdx.x * (dc_u64)blockDim.x + (dc_u64)threadIdx.x;
    if (t < b.n_pixels * (dc_u64)b.sampler.rays) dc_landing_ray(&b, t, t, 0, 1);
}

extern "C" __global__ void dc_landing_aimed_f32_kernel(dc_landing_batch b) {
    dc_u64 t = (dc_u64)blockIdx.x * (dc_u64)blockDim.x + (dc_u64)threadIdx.x;
    if (t < b.n_pixels * (dc_u64)b.sampler.rays) dc_landing_ray(&b, t, t, 1, 1);
}

/* `w`: each ray's coded-mask transmission (dc_landing_batch::w), or null without a mask surface. */
extern "C" __global__ void dc_footprint_size_kernel(const double *u, const double *v, const double *w, dc_u32 n, dc_i64 det_w, dc_i64 det_h, dc_window *wins, dc_u64 n_pixels) {
    dc_u64 q = (dc_u64)blockIdx.x * (dc_u64)blockDim.x + (dc_u64)threadIdx.x;
    if (q < n_pixels) dc_footprint_size(u + q * n, v + q * n, w ? w + q * n : 0, n, det_w, det_h, &wins[q]);
}

extern "C" __global__ void dc_footprint_fill_kernel(const double *u, const double *v, const double *w, dc_u32 n, dc_window *wins, const dc_u64 *offsets, double *scratch, float *weights, dc_u64 n_pixels) {
    dc_u64 q = (dc_u64)blockIdx.x * (dc_u64)blockDim.x + (dc_u64)threadIdx.x;
    if (q < n_pixels && wins[q].w > 0) dc_footprint_fill(u + q * n, v + q * n, w ? w + q * n : 0, n, &wins[q], scratch + offsets[q], weights + offsets[q]);
}

/* One thread a ray of the plane: its taps added to the plane image (fixed-point atomics, dc_accum.h); its
 * status and off-detector weight counted per block in shared memory, then once per block into counts[0..11]
 * (statuses, 10: DC_MASKED) and counts[11] (weight off the detector): integers, so the totals do not depend on
 * the order. A ray whose aim failed (ray aiming on) lowers counts[12] to its key (atomicMin: the first such ray,
 * any order). */
static __device__ __forceinline__ void dc_deposit_body(const dc_deposit_batch &b, dc_u64 n_rays, dc_u64 *counts, int aimed) {
    __shared__ unsigned long long block_counts[DC_STATUS_SLOTS + 1];
    if (threadIdx.x <= DC_STATUS_SLOTS) block_counts[threadIdx.x] = 0;
    __syncthreads();
    dc_u64 t = (dc_u64)blockIdx.x * (dc_u64)blockDim.x + (dc_u64)threadIdx.x;
    if (t < n_rays) {
        dc_u64 lost;
        dc_u32 st = dc_deposit_ray(&b, t, &lost, aimed);
        if (st == DC_AIM_FAILED) {
            atomicMin((unsigned long long *)&counts[DC_AIM_FAILURE_SLOT], (unsigned long long)dc_aim_failure_key(b.land.plane, t));
        } else {
            atomicAdd(&block_counts[st < DC_STATUS_SLOTS ? st : 5u], 1ull);
            if (lost) atomicAdd(&block_counts[DC_STATUS_SLOTS], (unsigned long long)lost);
        }
    }
    __syncthreads();
    if (threadIdx.x <= DC_STATUS_SLOTS && block_counts[threadIdx.x]) atomicAdd((unsigned long long *)&counts[threadIdx.x], block_counts[threadIdx.x]);
}

extern "C" __global__ void dc_deposit_kernel(dc_deposit_batch b, dc_u64 n_rays, dc_u64 *counts) { dc_deposit_body(b, n_rays, counts, 0); }

/* The deposit with ray aiming, launched when the system aims (as dc_landing_aimed_kernel). */
extern "C" __global__ void dc_deposit_aimed_kernel(dc_deposit_batch b, dc_u64 n_rays, dc_u64 *counts) { dc_deposit_body(b, n_rays, counts, 1); }

/* One thread a detector pixel: the plane's Airy gather added to its band. */
extern "C" __global__ void dc_airy_kernel(dc_airy_batch b, dc_u64 npix) {
    dc_u64 pix = (dc_u64)blockIdx.x * (dc_u64)blockDim.x + (dc_u64)threadIdx.x;
    if (pix < npix) dc_airy_pixel(&b, pix);
}

/* One thread a detector pixel: the bands rounded to f32 and summed in band order. */
extern "C" __global__ void dc_finish_kernel(const double *band, dc_u32 n_bands, dc_u64 npix, double *image, float *bands_f32) {
    dc_u64 pix = (dc_u64)blockIdx.x * (dc_u64)blockDim.x + (dc_u64)threadIdx.x;
    if (pix < npix) dc_finish_pixel(band, n_bands, npix, image, bands_f32, pix);
}
