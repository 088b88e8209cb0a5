/* diffcassi GPU kernels: the portability layer shared by the host (C99) and device (CUDA, NVRTC) builds.
 *
 * Every kernel header of src/gpu/kernels is written in the C subset that both a host C compiler and CUDA
 * accept: no C++ library, no standard headers under NVRTC, fixed-width integers from this file, and the
 * qualifier DC_FN on every function so that one source is compiled as host code (the CPU twin, built by
 * build.rs with the `cc` crate and tested against the Rust kernels) and as device code (PTX, built by
 * scripts/gpu/build_ptx.py with NVRTC). Floating point follows IEEE 754 without contraction on both sides
 * (host: -ffp-contract=off; device: --fmad=false), so the twin and the device compute the same bits for
 * the same operations; the Rust reference kernel evaluates the same expressions in the same order.
 */
#ifndef DC_COMMON_H
#define DC_COMMON_H

#if defined(__CUDACC__) || defined(__CUDACC_RTC__)
#define DC_DEVICE 1
#define DC_FN static __host__ __device__ __forceinline__
typedef unsigned int dc_u32;
typedef unsigned long long dc_u64;
typedef long long dc_i64;
#define DC_NAN __longlong_as_double(0x7ff8000000000000LL)
#else
#include <math.h>
#include <stdint.h>
#define DC_DEVICE 0
#define DC_FN static inline
typedef uint32_t dc_u32;
typedef uint64_t dc_u64;
typedef int64_t dc_i64;
#define DC_NAN ((double)NAN)
#endif

/* The math both builds take from their own library under the same names (CUDA's device functions, C99's
 * <math.h>): correctly rounded sqrt, and exact fabs, copysign, isfinite. */
#define DC_SQRT(x) sqrt(x)
#define DC_FABS(x) fabs(x)
#define DC_COPYSIGN(x, y) copysign(x, y)
#define DC_ISFINITE(x) isfinite(x)

#define DC_EPSILON 2.220446049250313080847263336181640625e-16 /* f64::EPSILON */

/* Three-vectors in f64, with the arithmetic of glam's DVec3 (component-wise, left to right). */
typedef struct {
    double x, y, z;
} dc_v3;

DC_FN dc_v3 dc_v3_make(double x, double y, double z) {
    dc_v3 r;
    r.x = x;
    r.y = y;
    r.z = z;
    return r;
}
DC_FN dc_v3 dc_add(dc_v3 a, dc_v3 b) { return dc_v3_make(a.x + b.x, a.y + b.y, a.z + b.z); }
DC_FN dc_v3 dc_sub(dc_v3 a, dc_v3 b) { return dc_v3_make(a.x - b.x, a.y - b.y, a.z - b.z); }
DC_FN dc_v3 dc_scale(dc_v3 a, double s) { return dc_v3_make(a.x * s, a.y * s, a.z * s); }
DC_FN dc_v3 dc_neg(dc_v3 a) { return dc_v3_make(-a.x, -a.y, -a.z); }
DC_FN dc_v3 dc_div(dc_v3 a, double s) { return dc_v3_make(a.x / s, a.y / s, a.z / s); }
/* glam: (x·x) + (y·y) + (z·z), left to right. */
DC_FN double dc_dot(dc_v3 a, dc_v3 b) { return (a.x * b.x) + (a.y * b.y) + (a.z * b.z); }
DC_FN int dc_v3_finite(dc_v3 a) { return DC_ISFINITE(a.x) && DC_ISFINITE(a.y) && DC_ISFINITE(a.z); }
/* glam's normalize: v · (1 / √(v·v)). */
DC_FN dc_v3 dc_normalize(dc_v3 a) { return dc_scale(a, 1.0 / DC_SQRT(dc_dot(a, a))); }
/* Rust's f64::max: the other operand when one is NaN. */
DC_FN double dc_max(double a, double b) { return (a != a) ? b : ((b != b) ? a : (a > b ? a : b)); }

/* A 3×3 matrix stored by columns, as glam's DMat3; M·v = x_axis·v.x + y_axis·v.y + z_axis·v.z. */
typedef struct {
    double c[9]; /* c[0..3] = x_axis, c[3..6] = y_axis, c[6..9] = z_axis */
} dc_m3;

DC_FN dc_v3 dc_m3_mul(const dc_m3 *m, dc_v3 v) {
    dc_v3 r = dc_v3_make(m->c[0] * v.x, m->c[1] * v.x, m->c[2] * v.x);
    r = dc_add(r, dc_v3_make(m->c[3] * v.y, m->c[4] * v.y, m->c[5] * v.y));
    r = dc_add(r, dc_v3_make(m->c[6] * v.z, m->c[7] * v.z, m->c[8] * v.z));
    return r;
}

#endif /* DC_COMMON_H */
