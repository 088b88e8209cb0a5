/* diffcassi GPU kernels: the sequential ray trace in f64 and in f32, one ray per call.
 *
 * The per-ray physics of src/tracer/kernel.rs and src/surfaces/intersect.rs, expression for expression:
 * frame change p' = M(p − o), d' = M d; the exact intersection with a plane, a conic (the vertex-branch
 * root, Numerical Recipes §5.6) or an even asphere (guarded Newton from the conic's root, then the vertex
 * plane's); the clear aperture or a circular obscuration; vector Snell's law, the ideal (Paraxial) lens or a
 * mirror's reflection (OpticStudio's sequential convention, as the CPU kernel); OpticStudio's Toroidal surface
 * (guarded Newton on its sag, src/surfaces/toroidal.rs) and the diffraction grating's vector grating equation
 * (src/surfaces/grating.rs), both in f64 (the f32 instance widens the ray, as the f32 lane kernel does). A ray
 * that stops is classified (missed, vignetted, TIR, no convergence, invalid input, evanescent order) with the
 * surface where it stopped;
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
/* A grating order that does not propagate (RayStatus::Evanescent, the grating equation's "TIR"). */
#define DC_EVANESCENT 9u
/* `TracedBatch::surface` of a ray that arrived (u32::MAX). */
#define DC_NO_SURFACE 0xFFFFFFFFu

#define DC_SHAPE_PLANE 0u
#define DC_SHAPE_CONIC 1u
#define DC_SHAPE_ASPHERE 2u
#define DC_SHAPE_PARAXIAL 3u
/* OpticStudio's Toroidal surface (SurfaceShape::Toroidal): the YZ curve (curvature, conic, coef[] of y², y⁴, …)
 * rotated about an axis parallel to y at the radius 1/rotation_curvature (0: a cylinder). */
#define DC_SHAPE_TOROIDAL 4u

#define DC_APERTURE_NONE 0u
#define DC_APERTURE_CIRCULAR 1u
#define DC_APERTURE_RECTANGULAR 2u
/* OpticStudio's Circular Obscuration (surfaces::Aperture::CircularObscuration): the closed annulus
 * rmin ≤ r ≤ rmax blocks, everything else passes. */
#define DC_APERTURE_OBSCURATION 3u

/* What a step does to a ray after the aperture (system::Interaction): refract (vector Snell, or the
 * Paraxial lens), reflect (a mirror, `GLAS MIRROR`), or diffract into one order of a grating (`DGRATING`),
 * transmissive or reflective (a grating that is also a mirror). */
#define DC_INTERACTION_REFRACT 0u
#define DC_INTERACTION_REFLECT 1u
#define DC_INTERACTION_GRATING 2u
#define DC_INTERACTION_GRATING_REFLECT 3u
/* tracer::kernel::GRAZING_COS: a mirror hit with |d·n̂| at or below it is grazing, and the ray `missed`. */
#define DC_GRAZING_COS 1e-12

/* At most 8 even-asphere (r² … r¹⁶) or toroid (y² … y¹⁶) terms: every term spec::system_spec allows
 * (limits::MAX_ASPHERE_TERMS, OpticStudio's PARM 1–8; gpu::pack::MAX_COEF). */
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
    double coef[DC_MAX_COEF]; /* even-asphere coefficients of r², r⁴, … (toroid: of y², y⁴, …) */
    double rotation_curvature; /* toroid: 1/(radius of rotation), 1/mm; 0 for a cylinder */
    double grating_lines_per_um; /* grating: T, lines per µm */
    double grating_order;        /* grating: the diffraction order m */
    dc_u32 shape;       /* DC_SHAPE_* */
    dc_u32 aperture_kind; /* DC_APERTURE_* */
    dc_u32 surface;     /* the surface's index in the system */
    dc_u32 n_coef;      /* how many of coef are used */
    dc_u32 interaction; /* DC_INTERACTION_* */
    dc_u32 wavelength_slot; /* grating: where the index row holds the wavelength, nm (SequentialSystem::indices) */
} dc_step;

/* Where a ray crosses one step of the path (the coded-mask surface of a dual-disperser system, system::MaskSurface):
 * dc_trace_path writes the ray's position after path[step] — in that surface's local frame, widened to f64 by the
 * f32 instance — once the ray is past it, as render::transport::trace_through_mask reads it after the first arm
 * path[..=step]. `crossed` stays 0 for a ray that stops before. */
typedef struct {
    dc_u32 step;
    int crossed;
    double x, y; /* mm */
} dc_probe;
/* A probe's step that no path has (the loop index stays below n_steps ≤ 2³² − 1). */
#define DC_NO_STEP 0xFFFFFFFFu

/* ---- The f64 pieces the f32 instance also calls (on a ray widened to f64) ------------------------------ */

/* The toroid's YZ curve at y (surfaces::toroidal::yz_curve, same operations in the same order): z_y and z_y′;
 * NaN outside the conic's domain. (Its z_y″, used by the Jacobians only, is not needed to trace.) */
DC_FN void dc_toroid_yz(const dc_step *s, double y, double *zy, double *zy1) {
    double c = s->curvature, k = s->conic;
    double y2 = y * y;
    double disc = 1.0 - (1.0 + k) * c * c * y2;
    if (disc < 0.0) {
        *zy = DC_NAN;
        *zy1 = DC_NAN;
        return;
    }
    double sq = DC_SQRT(disc);
    double z = c * y2 / (1.0 + sq);
    /* f(y²) with f′ = c/(2s) and z_y′ = 2y f′ */
    double f1 = c != 0.0 ? c / (2.0 * sq) : 0.0;
    double pw = 1.0; /* y2^j */
    for (dc_u32 j = 0; j < s->n_coef; ++j) {
        double i = (double)(j + 1);
        double a = s->coef[j];
        z += a * pw * y2;
        f1 += i * a * pw;
        pw *= y2;
    }
    *zy = z;
    *zy1 = 2.0 * y * f1;
}

/* The toroid at (x, y) (surfaces::toroidal::toroid_local): z = z_y + c_u x²/(1 + w), c_u = c_R/(1 − c_R z_y),
 * w = √(1 − c_u² x²), and its gradient (c_u x/w, z_y′/w); NaN outside its domain. */
DC_FN void dc_toroid_local(const dc_step *s, double x, double y, double *sag, double *gx, double *gy) {
    double zy, zy1;
    dc_toroid_yz(s, y, &zy, &zy1);
    double cr = s->rotation_curvature;
    double cu = cr / (1.0 - cr * zy);
    double x2 = x * x;
    double w2 = 1.0 - cu * cu * x2;
    if (!(w2 >= 0.0) || !DC_ISFINITE(zy)) {
        *sag = DC_NAN;
        *gx = DC_NAN;
        *gy = DC_NAN;
        return;
    }
    double w = DC_SQRT(w2);
    *sag = zy + cu * x2 / (1.0 + w);
    *gx = cu * x / w;
    *gy = zy1 / w;
}

/* The vector grating equation (surfaces::grating::diffract): unit d at unit normal n̂ (any orientation), from
 * index n1 into n2, kick g = mλT; K = normalise(ŷ − (ŷ·n̂)n̂) across the lines, v = n₁d − s g K (s = −1 for a
 * reflective grating), n₂d′ = v_t ± √(n₂² − |v_t|²) n̂ along the incoming side. 0 when the order is evanescent
 * (or the kick is NaN). */
DC_FN int dc_diffract(dc_v3 d, dc_v3 normal, double n1, double n2, double kick, int reflect, dc_v3 *out) {
    double cos_i = dc_dot(d, normal);
    dc_v3 nrm = cos_i < 0.0 ? dc_neg(normal) : normal;
    /* glam: DVec3::Y − n̂·n̂_y, component-wise (0 − …, 1 − …, 0 − …: the signs of zeros as Rust's) */
    dc_v3 k = dc_sub(dc_v3_make(0.0, 1.0, 0.0), dc_scale(normal, normal.y));
    double inv = 1.0 / DC_SQRT(dc_dot(k, k));
    k = dc_scale(k, inv);
    double sg = reflect ? -1.0 : 1.0;
    dc_v3 v = dc_sub(dc_scale(d, n1), dc_scale(k, sg * kick));
    double vn = dc_dot(v, nrm);
    dc_v3 vt = dc_sub(v, dc_scale(nrm, vn));
    double q = n2 * n2 - dc_dot(vt, vt);
    if (!(q >= 0.0)) return 0;
    double along = reflect ? -DC_SQRT(q) : DC_SQRT(q);
    *out = dc_div(dc_add(vt, dc_scale(nrm, along)), n2);
    return 1;
}

/* The trace in f64 (dc_intersect, dc_trace_step, dc_trace_path, ...) and in f32 (the same names + _f32). */
#define DC_P f64
#define DC_SFX
#define DC_F64_PASS 1
#include "dc_trace_tmpl.h"
#undef DC_P
#undef DC_SFX
#undef DC_F64_PASS
#define DC_P f32
#define DC_SFX _f32
#define DC_F64_PASS 0
#include "dc_trace_tmpl.h"
#undef DC_P
#undef DC_SFX
#undef DC_F64_PASS

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
 * stopped (0 for invalid input). `probe` as dc_trace_path's (null: none). */
DC_FN dc_u32 dc_trace_ray(const dc_step *path, dc_u32 n_steps, const double *n, dc_v3 *p, dc_v3 *d, dc_u32 *surface, dc_probe *probe) {
    dc_v3 u;
    if (!dc_unit_direction(*d, &u) || !dc_v3_finite(*p)) {
        *surface = 0;
        return DC_INVALID_INPUT;
    }
    *d = u;
    return dc_trace_path(path, n_steps, n, p, d, surface, probe);
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
    dc_u32 st = dc_trace_path_f32(path, n_steps, n, &pf, &df, surface, 0);
    *p = dc_v3_make(pf.x, pf.y, pf.z);
    *d = dc_v3_make(df.x, df.y, df.z);
    return st;
}

/* The f32 renderer's rule (render::transport::trace_row_lanes_f32: LaneBlock::set_raw, then normalize_inputs):
 * a direction whose largest component lies outside [1e-15, 1e15] is first divided by it (in f64), the origin
 * is checked and both are rounded to f32 (set_checked), then the ray is checked (finite p and d, |d| > 0) and
 * d divided by its length, in f32. `probe` as dc_trace_path's. */
DC_FN dc_u32 dc_trace_ray_raw_f32(const dc_step *path, dc_u32 n_steps, const double *n, dc_v3 *p, dc_v3 *d, dc_u32 *surface, dc_probe *probe) {
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
    dc_u32 st = dc_trace_path_f32(path, n_steps, n, &pf, &df, surface, probe);
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
    case DC_TRACE_F32_RAW: return dc_trace_ray_raw_f32(path, n_steps, n, p, d, surface, 0);
    default: return dc_trace_ray(path, n_steps, n, p, d, surface, 0);
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
