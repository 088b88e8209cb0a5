/* diffcassi GPU kernels: the sequential ray trace in f64 and in f32, one ray per call.
 *
 * The per-ray physics of src/tracer/kernel.rs and src/surfaces/intersect.rs, expression for expression:
 * frame change p' = M(p − o), d' = M d; the exact intersection with a plane, a conic (the vertex-branch
 * root, Numerical Recipes §5.6) or an even asphere (guarded Newton from the conic's root, then the vertex
 * plane's); the clear aperture or a circular obscuration; vector Snell's law, the ideal (Paraxial) lens or a
 * mirror's reflection (OpticStudio's sequential convention, as the CPU kernel). A ray that stops is
 * classified (missed, vignetted, TIR, no convergence, invalid input) with the surface where it stopped;
 * nothing here returns a NaN position. The status codes are those of `tracer::RayStatus`. The trace itself is
 * written once, in dc_trace_tmpl.h, and instantiated here in f64 (dc_trace_path: the scalar kernel's bits) and
 * in f32 (dc_trace_path_f32: the f32 lane kernel's bits, tracer::simd::block); each precision has its own
 * input rule (below).
 *
 * Host build: src/gpu/kernels/host.c (the CPU twin). Device build: src/gpu/kernels/device.cu (PTX).
 */
#ifndef DC_TRACE_H
#define DC_TRACE_H
#include "dc_common.h"

#define DC_OK 0u
#define DC_MISSED 1u
#define DC_VIGNETTED 2u
#define DC_TIR 3u
#define DC_NO_CONVERGENCE 4u
#define DC_INVALID_INPUT 5u
/* `TracedBatch::surface` of a ray that arrived (u32::MAX). */
#define DC_NO_SURFACE 0xFFFFFFFFu

#define DC_SHAPE_PLANE 0u
#define DC_SHAPE_CONIC 1u
#define DC_SHAPE_ASPHERE 2u
#define DC_SHAPE_PARAXIAL 3u

#define DC_APERTURE_NONE 0u
#define DC_APERTURE_CIRCULAR 1u
#define DC_APERTURE_RECTANGULAR 2u
/* OpticStudio's Circular Obscuration (surfaces::Aperture::CircularObscuration): the closed annulus
 * rmin ≤ r ≤ rmax blocks, everything else passes. */
#define DC_APERTURE_OBSCURATION 3u

/* What a step does to a ray after the aperture (system::Interaction): refract (vector Snell, or the
 * Paraxial lens) or reflect (a mirror, `GLAS MIRROR`). Gratings are refused by gpu::pack. */
#define DC_INTERACTION_REFRACT 0u
#define DC_INTERACTION_REFLECT 1u
/* tracer::kernel::GRAZING_COS: a mirror hit with |d·n̂| at or below it is grazing, and the ray `missed`. */
#define DC_GRAZING_COS 1e-12

/* At most 8 even-asphere terms (r² … r¹⁶), as spec::system_spec allows. */
#define DC_MAX_COEF 8

/* One surface of the traced path (`system::PathStep`), laid out as `gpu::pack::Step` (repr(C)). */
typedef struct {
    dc_m3 rotation;     /* into the surface's local frame */
    double offset[3];   /* the local frame's origin in the previous frame, mm */
    double curvature;   /* 1/mm (conic, asphere) */
    double conic;       /* conic constant k */
    double focal_length; /* mm (paraxial) */
    double aperture[4]; /* circular: semi-diameter, min radius, decenter x, y; rectangular: half x, half y, decenter x, y;
                           obscuration: min radius, max radius, decenter x, y (mm) */
    double coef[DC_MAX_COEF]; /* even-asphere coefficients of r², r⁴, … */
    dc_u32 shape;       /* DC_SHAPE_* */
    dc_u32 aperture_kind; /* DC_APERTURE_* */
    dc_u32 surface;     /* the surface's index in the system */
    dc_u32 n_coef;      /* how many of coef are used */
    dc_u32 interaction; /* DC_INTERACTION_* */
    dc_u32 pad;
} dc_step;

/* The trace in f64 (dc_intersect, dc_trace_step, dc_trace_path, ...) and in f32 (the same names + _f32). */
#define DC_P f64
#define DC_SFX
#include "dc_trace_tmpl.h"
#undef DC_P
#undef DC_SFX
#define DC_P f32
#define DC_SFX _f32
#include "dc_trace_tmpl.h"
#undef DC_P
#undef DC_SFX

/* The unit vector along a finite, non-zero direction (tracer::kernel::unit_direction); 0 if invalid. */
DC_FN int dc_unit_direction(dc_v3 d, dc_v3 *out) {
    if (!dc_v3_finite(d)) return 0;
    double len2 = dc_dot(d, d);
    if (DC_ISFINITE(len2) && len2 > 1e-300) {
        *out = dc_div(d, DC_SQRT(len2));
        return 1;
    }
    double m = dc_max(DC_FABS(d.x), dc_max(DC_FABS(d.y), DC_FABS(d.z)));
    if (!(m > 0.0)) return 0;
    dc_v3 s = dc_div(d, m);
    *out = dc_div(s, DC_SQRT(dc_dot(s, s)));
    return 1;
}

/* A whole ray in f64: validate the input (finite origin, unit_direction), then every step. On DC_OK, (p, d)
 * are on the last surface in its frame and *surface is DC_NO_SURFACE; otherwise *surface is where the ray
 * stopped (0 for invalid input). */
DC_FN dc_u32 dc_trace_ray(const dc_step *path, dc_u32 n_steps, const double *n, dc_v3 *p, dc_v3 *d, dc_u32 *surface) {
    dc_v3 u;
    if (!dc_unit_direction(*d, &u) || !dc_v3_finite(*p)) {
        *surface = 0;
        return DC_INVALID_INPUT;
    }
    *d = u;
    return dc_trace_path(path, n_steps, n, p, d, surface);
}

/* ---- f32 inputs: the two rules of the Rust f32 paths (tracer::simd::block::LaneBlock) -------------------- */

/* The largest origin coordinate an f32 ray accepts (`Real::MAX_INPUT_MM` for f32, 1 m: the origin rounds
 * by ≤ 3e-5 mm); beyond it, or NaN-free but unbounded, the ray is an invalid input. */
#define DC_F32_MAX_INPUT_MM 1e3

/* LaneBlock::set_checked: p and a unit d (f64) rounded to f32, or 0 (invalid) when max|p| > 1 mm·1e3 (glam's
 * max_element, NaN-ignoring as Rust's max). */
DC_FN int dc_set_checked_f32(dc_v3 p, dc_v3 d, dc_v3_f32 *pf, dc_v3_f32 *df) {
    if (!(dc_max(DC_FABS(p.x), dc_max(DC_FABS(p.y), DC_FABS(p.z))) <= DC_F32_MAX_INPUT_MM)) return 0;
    *pf = dc_v3_make_f32((float)p.x, (float)p.y, (float)p.z);
    *df = dc_v3_make_f32((float)d.x, (float)d.y, (float)d.z);
    return 1;
}

/* The f32 tracer's rule (tracer::AnalyticF32Tracer): the f64 check and unit_direction, then set_checked, then
 * the f32 trace. Outputs are the f32 results widened to f64. */
DC_FN dc_u32 dc_trace_ray_f32(const dc_step *path, dc_u32 n_steps, const double *n, dc_v3 *p, dc_v3 *d, dc_u32 *surface) {
    dc_v3 u;
    dc_v3_f32 pf, df;
    if (!dc_unit_direction(*d, &u) || !dc_v3_finite(*p) || !dc_set_checked_f32(*p, u, &pf, &df)) {
        *surface = 0;
        return DC_INVALID_INPUT;
    }
    dc_u32 st = dc_trace_path_f32(path, n_steps, n, &pf, &df, surface);
    *p = dc_v3_make(pf.x, pf.y, pf.z);
    *d = dc_v3_make(df.x, df.y, df.z);
    return st;
}

/* The f32 renderer's rule (render::transport::trace_row_lanes_f32: LaneBlock::set_raw, then normalize_inputs):
 * a direction whose largest component lies outside [1e-15, 1e15] is first divided by it (in f64), the origin
 * is checked and both are rounded to f32 (set_checked), then the ray is checked (finite p and d, |d| > 0) and
 * d divided by its length, in f32. */
DC_FN dc_u32 dc_trace_ray_raw_f32(const dc_step *path, dc_u32 n_steps, const double *n, dc_v3 *p, dc_v3 *d, dc_u32 *surface) {
    dc_v3 dd = *d;
    dc_v3_f32 pf, df;
    double m = dc_max(DC_FABS(dd.x), dc_max(DC_FABS(dd.y), DC_FABS(dd.z)));
    if (!(m >= 1e-15 && m <= 1e15)) dd = dc_div(dd, m);
    int ok = dc_set_checked_f32(*p, dd, &pf, &df);
    if (ok) {
        float len = sqrtf(dc_dot_f32(df, df));
        ok = dc_v3_finite_f32(pf) && dc_v3_finite_f32(df) && len > 0.0f;
        df = dc_div_f32(df, len);
    }
    if (!ok) {
        *surface = 0;
        return DC_INVALID_INPUT;
    }
    dc_u32 st = dc_trace_path_f32(path, n_steps, n, &pf, &df, surface);
    *p = dc_v3_make(pf.x, pf.y, pf.z);
    *d = dc_v3_make(df.x, df.y, df.z);
    return st;
}

/* A batch of rays in structure-of-arrays form, the layout of `gpu::pack::Batch` (repr(C)). Ray i uses the
 * index table tables[table_of_ray[i] · n_surfaces ...]. Outputs are zero for rays that stop. */
typedef struct {
    const dc_step *path;
    const double *tables;
    const dc_u32 *table_of_ray;
    const double *ox, *oy, *oz, *dx, *dy, *dz;
    double *x, *y, *z, *ux, *uy, *uz;
    unsigned char *status;
    dc_u32 *surface;
    dc_u64 n_rays;
    dc_u32 n_steps;
    dc_u32 n_surfaces;
} dc_batch;

/* Which trace a launch runs: f64 (the scalar kernel), f32 with the f32 tracer's input rule, or f32 with the
 * renderer's (dc_trace_ray, dc_trace_ray_f32, dc_trace_ray_raw_f32). */
#define DC_TRACE_F64 0u
#define DC_TRACE_F32 1u
#define DC_TRACE_F32_RAW 2u

DC_FN dc_u32 dc_trace_ray_as(dc_u32 mode, const dc_step *path, dc_u32 n_steps, const double *n, dc_v3 *p, dc_v3 *d, dc_u32 *surface) {
    switch (mode) {
    case DC_TRACE_F32: return dc_trace_ray_f32(path, n_steps, n, p, d, surface);
    case DC_TRACE_F32_RAW: return dc_trace_ray_raw_f32(path, n_steps, n, p, d, surface);
    default: return dc_trace_ray(path, n_steps, n, p, d, surface);
    }
}

DC_FN void dc_trace_batch_ray(const dc_batch *b, dc_u64 i, dc_u32 mode) {
    dc_v3 p = dc_v3_make(b->ox[i], b->oy[i], b->oz[i]);
    dc_v3 d = dc_v3_make(b->dx[i], b->dy[i], b->dz[i]);
    dc_u32 surface = 0;
    const double *n = b->tables + (dc_u64)b->table_of_ray[i] * b->n_surfaces;
    dc_u32 st = dc_trace_ray_as(mode, b->path, b->n_steps, n, &p, &d, &surface);
    if (st != DC_OK) {
        p = dc_v3_make(0.0, 0.0, 0.0);
        d = p;
    }
    b->x[i] = p.x;
    b->y[i] = p.y;
    b->z[i] = p.z;
    b->ux[i] = d.x;
    b->uy[i] = d.y;
    b->uz[i] = d.z;
    b->status[i] = (unsigned char)st;
    b->surface[i] = surface;
}

#endif /* DC_TRACE_H */
