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
 * <math.h>): correctly rounded sqrt, and exact fabs, copysign, isfinite (f64; the f32 twins below). Under
 * NVRTC sqrtf and division are IEEE (--prec-sqrt=true --prec-div=true) and subnormals kept (--ftz=false). */
#define DC_SQRT(x) sqrt(x)
#define DC_FABS(x) fabs(x)
#define DC_COPYSIGN(x, y) copysign(x, y)
#define DC_ISFINITE(x) isfinite(x)
/* tan, the one transcendental function of the library's that the kernels call (the field angles of an object at
 * infinity, rays::PupilAim::parallel_ray). The host twin calls the platform's libm, as Rust's f64::tan does, so
 * the twin has the CPU renderer's bits; CUDA's double tan (libdevice __nv_tan) is not correctly rounded — its
 * documented bound is 2 ulp (CUDA C++ Programming Guide, "Mathematical Functions", double precision) — so on
 * the device a ray at infinity may start a few ulp away from the CPU's: docs/gpu.md, scripts/gpu/render_check.py. */
#define DC_TAN(x) tan(x)

#define DC_EPSILON 2.220446049250313080847263336181640625e-16 /* f64::EPSILON */
#define DC_EPSILON_F32 1.1920928955078125e-7f                 /* f32::EPSILON */

/* ---- One source for two precisions -------------------------------------------------------------------
 *
 * The vector arithmetic (dc_vec_tmpl.h) and the sequential trace (dc_trace_tmpl.h) are written once over a
 * real type and included twice: with the tag DC_P = f64 (names unchanged: dc_v3, dc_trace_step, ...) and
 * DC_P = f32 (names suffixed _f32: dc_v3_f32, dc_trace_step_f32, ...). A template names its type DC_REAL,
 * its functions DC_T(name), rounds every system constant with DC_R (computed in f64 first, then rounded
 * once, as tracer::simd::block does with `Lanes::of`; the identity in f64) and takes the precision's math
 * and tolerances from the tables below (DC_RSQRT, DC_BRANCH_TOL, ...). */
#define DC_CAT2(a, b) a##b
#define DC_CAT(a, b) DC_CAT2(a, b)
typedef double dc_real_f64;
typedef float dc_real_f32;
#define DC_REAL DC_CAT(dc_real_, DC_P)
#define DC_T(name) DC_CAT(name, DC_SFX)
#define DC_V3 DC_T(dc_v3)
#define DC_R(x) ((DC_REAL)(x))
#define DC_RSQRT DC_CAT(DC_SQRT_, DC_P)
#define DC_RFABS DC_CAT(DC_FABS_, DC_P)
#define DC_RCOPYSIGN DC_CAT(DC_COPYSIGN_, DC_P)
#define DC_RNAN DC_CAT(DC_NAN_, DC_P)
#define DC_BRANCH_TOL DC_CAT(DC_BRANCH_TOL_, DC_P)
#define DC_NEWTON_WIDTH DC_CAT(DC_NEWTON_WIDTH_, DC_P)
#define DC_NEWTON_STEP_TOL DC_CAT(DC_NEWTON_STEP_TOL_, DC_P)
#define DC_NEWTON_RESIDUAL_TOL DC_CAT(DC_NEWTON_RESIDUAL_TOL_, DC_P)
#define DC_NEWTON_FINAL_TOL DC_CAT(DC_NEWTON_FINAL_TOL_, DC_P)

#define DC_SQRT_f64(x) sqrt(x)
#define DC_SQRT_f32(x) sqrtf(x)
#define DC_FABS_f64(x) fabs(x)
#define DC_FABS_f32(x) fabsf(x)
#define DC_COPYSIGN_f64(x, y) copysign(x, y)
#define DC_COPYSIGN_f32(x, y) copysignf(x, y)
#define DC_NAN_f64 DC_NAN
#define DC_NAN_f32 ((float)DC_NAN)
/* The trace's tolerances, f64 (the scalar kernel's) and f32 (tracer::simd::lanes, `impl Real for f32`:
 * scaled to f32's rounding, docs/performance.md "f32 mode"), each in the Rust operation order:
 * the conic vertex-branch test |z − sag| ≤ tol at a hit of local height z reached at parameter t, */
#define DC_BRANCH_TOL_f64(z, t) (1e-9 * (1.0 + fabs(z)))
#define DC_BRANCH_TOL_f32(z, t) (1e-5f * ((1.0f + fabsf(z)) + fabsf(t)))
/* the even-asphere Newton's bracket width (× (1 + |t|)), step test |t′ − t| ≤ tol, residual test |f| < tol
 * after a small step, and the residual test once the 100 iterations are spent. */
#define DC_NEWTON_WIDTH_f64 (4.0 * DC_EPSILON)
#define DC_NEWTON_WIDTH_f32 (4.0f * DC_EPSILON_F32)
#define DC_NEWTON_STEP_TOL_f64(t) (1e-15 * (1.0 + fabs(t)))
#define DC_NEWTON_STEP_TOL_f32(t) ((8.0f * DC_EPSILON_F32) * (1.0f + fabsf(t)))
#define DC_NEWTON_RESIDUAL_TOL_f64(t) 1e-9
#define DC_NEWTON_RESIDUAL_TOL_f32(t) (1e-5f * (1.0f + fabsf(t)))
#define DC_NEWTON_FINAL_TOL_f64(t) 1e-12
#define DC_NEWTON_FINAL_TOL_f32(t) (1e-6f * (1.0f + fabsf(t)))

/* Rust's f64::max: the other operand when one is NaN. */
DC_FN double dc_max(double a, double b) { return (a != a) ? b : ((b != b) ? a : (a > b ? a : b)); }

/* A 3×3 matrix stored by columns, as glam's DMat3; M·v = x_axis·v.x + y_axis·v.y + z_axis·v.z. */
typedef struct {
    double c[9]; /* c[0..3] = x_axis, c[3..6] = y_axis, c[6..9] = z_axis */
} dc_m3;

/* The vector arithmetic in f64 (dc_v3, dc_add, ...) and in f32 (dc_v3_f32, dc_add_f32, ...). */
#define DC_P f64
#define DC_SFX
#include "dc_vec_tmpl.h"
#undef DC_P
#undef DC_SFX
#define DC_P f32
#define DC_SFX _f32
#include "dc_vec_tmpl.h"
#undef DC_P
#undef DC_SFX

#endif /* DC_COMMON_H */
