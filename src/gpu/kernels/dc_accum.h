/* diffcassi GPU kernels: the acquisition accumulated on the device, deterministically.
 *
 * The CPU renderer (render::engine) forms, plane by plane, Σ_q value_p(q) · F_{p,q} (each open scene pixel's
 * bilinear footprint, its N rays' taps × 1/N), blurs it with the plane's Airy kernel A_p and adds w_p · A_p ∗ ·
 * to the band image of the plane. On the device the rays of a plane run in parallel and their order is the
 * scheduler's, so sums in floating point would depend on it. Here each ray adds its four bilinear taps
 * (value · tap, f64) to the plane image as **64-bit fixed-point integers** (round(value · tap · 2^S)):
 * integer addition is associative, so the plane image — hence everything after it — has the same bits
 * whatever the order (the device's atomics, the host twin's loop, any thread count). 2^S is chosen by the
 * host so that no pixel can overflow: |Σ| ≤ max|value| · (rays of the plane) · 2^S < 2^62 (docs/gpu.md);
 * the error of a deposit is ≤ 2^−(S+1), i.e. ≤ 2^−63 · (rays of the plane) · max|value| ≈ 3·10⁻¹³ of the
 * peak value at paper scale (2.6 M rays a plane), against 6·10⁻⁸ for the CPU's f32 weights.
 *
 * Then, one thread a detector pixel, the plane's Airy blur is a gather in f64 (out(y, x) = Σ_{ki,kj}
 * A[ki][kj] · img(y − (ki − h), x − (kj − h)), zero outside: AiryKernel::convolve's taps, in f64) added
 * × w_p to the band's f64 image; planes run in ascending order, so each band's sum has one order. Finally
 * the acquisition is the f64 sum of the bands in band order (render::engine sums the bands' f32 roundings;
 * here they stay f64, and are rounded to f32 only for the band images a caller keeps).
 *
 * Ray counts by status and the weight that fell off the detector (fixed point, 2^24 a ray) are integers too.
 */
#ifndef DC_ACCUM_H
#define DC_ACCUM_H
#include "dc_render.h"

/* The adds of a deposit: atomic on the device; on the host twin each worker owns its image. */
#if DC_DEVICE
#define DC_ADD_U64(p, v) atomicAdd((unsigned long long *)(p), (unsigned long long)(v))
#else
#define DC_ADD_U64(p, v) (*(p) += (dc_u64)(v))
#endif

/* Status slots counted per plane: tracer::RayStatus codes 0 … 9 (9: a grating's evanescent order), then
 * DC_MASKED. */
#define DC_STATUS_SLOTS 11u
/* Not a RayStatus: the ray arrived, but the coded-mask surface's transmission is 0 where it crossed it
 * (RayStats::masked; dual-disperser systems only). It deposits nothing. */
#define DC_MASKED 10u
/* counts[DC_STATUS_SLOTS + 1]: the first ray whose aim failed (DC_AIM_FAILED), as dc_aim_failure_key — the
 * minimum over the launch (order-free: an atomicMin on the device), ~0 when none. Such a ray is not counted by
 * status: the CPU renderer stops with an error there, and so does the host after the run. */
#define DC_AIM_FAILURE_SLOT (DC_STATUS_SLOTS + 1u)
DC_FN dc_u64 dc_aim_failure_key(dc_u64 plane, dc_u64 t) { return (plane << 40) | t; }
/* Fixed-point units of one ray's weight in the off-detector count. */
#define DC_LOST_ONE 16777216.0

typedef struct {
    dc_landing_batch land; /* the plane launch (its u, v, status are not used) */
    const float *cube;     /* the scene, [pixel][band], f32 */
    const float *mask;     /* per scene pixel */
    dc_u64 *image;         /* the plane image, det_w × det_h, fixed point (two's complement) */
    double fixed_scale;    /* 2^S */
    dc_i64 det_w, det_h;
    dc_u32 bands;          /* the cube's bands */
    dc_u32 k0, k1;         /* the two bands the plane interpolates (SpectralCube::interpolation) */
    float tw;              /* weight of k1 */
    dc_u32 f32;            /* 1: the renderer's f32 trace (dc_land), 0: f64 */
} dc_deposit_batch;

/* round(x) to the nearest integer, halves up: the same bits on both builds. */
DC_FN dc_i64 dc_round_i64(double x) { return (dc_i64)floor(x + 0.5); }

/* The plane's value at open pixel `pixel`: ((1 − t)·a + t·b)·mask in f32 (render::engine, operation for
 * operation). */
DC_FN float dc_plane_value(const dc_deposit_batch *b, dc_u32 pixel) {
    float a = b->cube[(dc_u64)pixel * b->bands + b->k0], c = b->cube[(dc_u64)pixel * b->bands + b->k1];
    return ((1.0f - b->tw) * a + b->tw * c) * b->mask[pixel];
}

/* Ray t of the plane: trace it (`aimed` as dc_land's) and add its taps, each weighted by the ray's coded-mask
 * transmission (1 without a mask surface). Returns its status (DC_MASKED for a ray the mask blocks); *lost gets
 * the fixed-point weight of its taps that fall off the detector (0 when it does not arrive). */
DC_FN dc_u32 dc_deposit_ray(const dc_deposit_batch *b, dc_u64 t, dc_u64 *lost, int aimed) {
    double u, v, w;
    dc_u32 st = dc_land(&b->land, t, &u, &v, &w, (int)b->f32, aimed);
    *lost = 0;
    if (st != DC_OK) return st;
    if (w == 0.0) return DC_MASKED;
    float value = dc_plane_value(b, b->land.pixels[t / b->land.sampler.rays]);
    double fj = floor(u), fi = floor(v);
    dc_i64 j = (dc_i64)fj, i = (dc_i64)fi;
    double fu = u - fj, fv = v - fi;
    double wi[2] = {1.0 - fv, fv}, wj[2] = {1.0 - fu, fu};
    for (int di = 0; di < 2; ++di) {
        for (int dj = 0; dj < 2; ++dj) {
            dc_i64 r = i + di, c = j + dj;
            double tap = wi[di] * wj[dj] * w;
            if (r < 0 || r >= b->det_h || c < 0 || c >= b->det_w)
                *lost += (dc_u64)dc_round_i64(tap * DC_LOST_ONE);
            else if (value != 0.0f)
                DC_ADD_U64(&b->image[r * b->det_w + c], dc_round_i64((double)value * tap * b->fixed_scale));
        }
    }
    return st;
}

typedef struct {
    const dc_u64 *image; /* the plane image, fixed point */
    double *band;        /* the band's image, f64 */
    const float *taps;   /* the Airy kernel, (2·half + 1)², row-major (a single 1: no blur) */
    dc_i64 det_w, det_h, half;
    double unit;         /* the value of one fixed-point unit: 2^−S · (1/N) */
    double weight;       /* the plane weight w_p */
} dc_airy_batch;

/* Detector pixel `pix`: band += w · Σ A · img (the gather form of AiryKernel::convolve, in f64). */
DC_FN void dc_airy_pixel(const dc_airy_batch *b, dc_u64 pix) {
    dc_i64 y = (dc_i64)(pix / (dc_u64)b->det_w), x = (dc_i64)(pix % (dc_u64)b->det_w);
    dc_i64 n = 2 * b->half + 1;
    double acc = 0.0;
    for (dc_i64 ki = 0; ki < n; ++ki) {
        dc_i64 sy = y - (ki - b->half);
        if (sy < 0 || sy >= b->det_h) continue;
        for (dc_i64 kj = 0; kj < n; ++kj) {
            dc_i64 sx = x - (kj - b->half);
            float w = b->taps[ki * n + kj];
            if (w == 0.0f || sx < 0 || sx >= b->det_w) continue;
            acc += (double)w * ((double)(dc_i64)b->image[sy * b->det_w + sx] * b->unit);
        }
    }
    b->band[pix] += b->weight * acc;
}

/* Detector pixel `pix` of the acquisition: the f64 sum of the bands in band order (each band also rounded to
 * f32 into bands_f32 when not null). `band` is band-major: band b's pixel at b · npix + pix. */
DC_FN void dc_finish_pixel(const double *band, dc_u32 n_bands, dc_u64 npix, double *image, float *bands_f32, dc_u64 pix) {
    double s = 0.0;
    for (dc_u32 k = 0; k < n_bands; ++k) {
        double v = band[(dc_u64)k * npix + pix];
        if (bands_f32) bands_f32[(dc_u64)k * npix + pix] = (float)v;
        s += v;
    }
    image[pix] = s;
}

#endif /* DC_ACCUM_H */
