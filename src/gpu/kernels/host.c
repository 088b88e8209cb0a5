/* diffcassi GPU kernels, host build: the CPU twin of device.cu, from the same headers.
 *
 * Compiled by build.rs with the `cc` crate (C99, -O2, -ffp-contract=off) into the library, and called from
 * src/gpu/twin.rs over ranges of rays (rayon chunks). The tests compare it with the Rust kernels; what
 * passes here is what the device runs.
 */
#include "dc_accum.h"

/* Trace rays [begin, end) of the batch: the body of the device kernels dc_trace_kernel (mode DC_TRACE_F64) and
 * dc_trace_f32_kernel (DC_TRACE_F32), one ray a turn; DC_TRACE_F32_RAW is the landing kernel's f32 input rule,
 * here so that the tests can give it constructed rays. */
void dc_trace_batch_host(const dc_batch *b, dc_u64 begin, dc_u64 end, dc_u32 mode) {
    for (dc_u64 i = begin; i < end && i < b->n_rays; ++i) dc_trace_batch_ray(b, i, mode);
}

/* Landings of rays [begin, end) of a plane launch: the body of dc_landing_kernel (f32 = 0) and
 * dc_landing_f32_kernel (f32 = 1), or of their aimed builds (dc_landing_aimed*_kernel) when the launch aims. Here b->u, b->v and b->status point at the chunk's own outputs: ray t is
 * written at t − begin. */
void dc_landing_host(const dc_landing_batch *b, dc_u64 begin, dc_u64 end, int f32) {
    dc_u64 n = b->n_pixels * (dc_u64)b->sampler.rays;
    int aimed = b->aim.aiming != 0;
    for (dc_u64 t = begin; t < end && t < n; ++t) dc_landing_ray(b, t, t - begin, f32, aimed);
}

/* sizeof of the shared structs, so that the Rust side can check its repr(C) layouts. */
dc_u64 dc_sizeof_step(void) { return (dc_u64)sizeof(dc_step); }
dc_u64 dc_sizeof_batch(void) { return (dc_u64)sizeof(dc_batch); }
dc_u64 dc_sizeof_landing_batch(void) { return (dc_u64)sizeof(dc_landing_batch); }

/* Footprint windows of open pixels [begin, end): pass 1 of dc_footprint_*_kernel. Pixel q's rays are
 * u/v[q·n .. q·n + n]. */
void dc_footprint_size_host(const double *u, const double *v, const double *w, dc_u32 n, dc_i64 det_w, dc_i64 det_h, dc_window *wins, dc_u64 begin, dc_u64 end) {
    for (dc_u64 q = begin; q < end; ++q) dc_footprint_size(u + q * n, v + q * n, w ? w + q * n : 0, n, det_w, det_h, &wins[q]);
}

/* Pass 2: the windows' taps; offsets[q] is where pixel q's cells start in scratch and weights. `w`: each ray's
 * coded-mask transmission, or null (dc_footprint_size's too). */
void dc_footprint_fill_host(const double *u, const double *v, const double *w, dc_u32 n, dc_window *wins, const dc_u64 *offsets, double *scratch, float *weights, dc_u64 begin, dc_u64 end) {
    for (dc_u64 q = begin; q < end; ++q)
        if (wins[q].w > 0) dc_footprint_fill(u + q * n, v + q * n, w ? w + q * n : 0, n, &wins[q], scratch + offsets[q], weights + offsets[q]);
}

dc_u64 dc_sizeof_window(void) { return (dc_u64)sizeof(dc_window); }

/* Rays [begin, end) of a plane: the body of dc_deposit_kernel (dc_deposit_aimed_kernel when the launch aims), into this worker's own plane image; counts[0..11]
 * by status (10: DC_MASKED), counts[11] the fixed-point weight off the detector, counts[12] the first failed aim's key (min). */
void dc_deposit_host(const dc_deposit_batch *b, dc_u64 begin, dc_u64 end, dc_u64 *counts) {
    for (dc_u64 t = begin; t < end; ++t) {
        dc_u64 lost;
        dc_u32 st = dc_deposit_ray(b, t, &lost, b->land.aim.aiming != 0);
        if (st == DC_AIM_FAILED) {
            dc_u64 key = dc_aim_failure_key(b->land.plane, t);
            if (key < counts[DC_AIM_FAILURE_SLOT]) counts[DC_AIM_FAILURE_SLOT] = key;
            continue;
        }
        counts[st < DC_STATUS_SLOTS ? st : 5u] += 1;
        counts[DC_STATUS_SLOTS] += lost;
    }
}

/* Detector pixels [begin, end): the body of dc_airy_kernel. */
void dc_airy_host(const dc_airy_batch *b, dc_u64 begin, dc_u64 end) {
    for (dc_u64 pix = begin; pix < end; ++pix) dc_airy_pixel(b, pix);
}

/* Detector pixels [begin, end): the body of dc_finish_kernel. */
void dc_finish_host(const double *band, dc_u32 n_bands, dc_u64 npix, double *image, float *bands_f32, dc_u64 begin, dc_u64 end) {
    for (dc_u64 pix = begin; pix < end; ++pix) dc_finish_pixel(band, n_bands, npix, image, bands_f32, pix);
}

dc_u64 dc_sizeof_deposit_batch(void) { return (dc_u64)sizeof(dc_deposit_batch); }
dc_u64 dc_sizeof_airy_batch(void) { return (dc_u64)sizeof(dc_airy_batch); }
