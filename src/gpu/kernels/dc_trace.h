/* diffcassi GPU kernels: the sequential f64 ray trace, one ray per call.
 *
 * The per-ray physics of src/tracer/kernel.rs and src/surfaces/intersect.rs, expression for expression:
 * frame change p' = M(p − o), d' = M d; the exact intersection with a plane, a conic (the vertex-branch
 * root, Numerical Recipes §5.6) or an even asphere (guarded Newton from the conic's root, then the vertex
 * plane's); the clear aperture; vector Snell's law or the ideal (Paraxial) lens. A ray that stops is
 * classified (missed, vignetted, TIR, no convergence, invalid input) with the surface where it stopped;
 * nothing here returns a NaN position. The status codes are those of `tracer::RayStatus`.
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

/* At most 8 even-asphere terms (r² … r¹⁶), as spec::system_spec allows. */
#define DC_MAX_COEF 8

/* One surface of the traced path (`system::PathStep`), laid out as `gpu::pack::Step` (repr(C)). */
typedef struct {
    dc_m3 rotation;     /* into the surface's local frame */
    double offset[3];   /* the local frame's origin in the previous frame, mm */
    double curvature;   /* 1/mm (conic, asphere) */
    double conic;       /* conic constant k */
    double focal_length; /* mm (paraxial) */
    double aperture[4]; /* circular: semi-diameter, min radius, decenter x, y; rectangular: half x, half y, decenter x, y (mm) */
    double coef[DC_MAX_COEF]; /* even-asphere coefficients of r², r⁴, … */
    dc_u32 shape;       /* DC_SHAPE_* */
    dc_u32 aperture_kind; /* DC_APERTURE_* */
    dc_u32 surface;     /* the surface's index in the system */
    dc_u32 n_coef;      /* how many of coef are used */
} dc_step;

/* The vertex plane z = 0: t = −p_z/d_z. Returns 0 on success. */
DC_FN int dc_intersect_plane(dc_v3 p, dc_v3 d, double *t_out, dc_v3 *point) {
    if (d.z == 0.0) return 0;
    double t = -p.z / d.z;
    dc_v3 q = dc_v3_make(p.x + t * d.x, p.y + t * d.y, 0.0);
    if (!dc_v3_finite(q)) return 0;
    *t_out = t;
    *point = q;
    return 1;
}

/* Whether `q` lies on the vertex branch of c(x²+y²+kk·z²) − 2z = 0 (where the sag formula holds). */
DC_FN int dc_on_conic_vertex_branch(dc_v3 q, double c, double kk) {
    double r2 = q.x * q.x + q.y * q.y;
    double domain = 1.0 - kk * c * c * r2;
    if (domain < 0.0) return 0;
    double sag = c * r2 / (1.0 + DC_SQRT(domain));
    return DC_FABS(q.z - sag) <= 1e-9 * (1.0 + DC_FABS(q.z));
}

DC_FN int dc_on_branch_at(dc_v3 p, dc_v3 d, double t, double c, double kk) {
    return DC_ISFINITE(t) && dc_on_conic_vertex_branch(dc_add(p, dc_scale(d, t)), c, kk);
}

/* Vertex-branch root of the conic along p + t d (the cancellation-free pair t₁ = C/q, t₂ = q/A). */
DC_FN int dc_conic_root(double c, double k, dc_v3 p, dc_v3 d, double *t_out) {
    double kk = 1.0 + k;
    double a = c * (d.x * d.x + d.y * d.y + kk * d.z * d.z);
    double b = c * (p.x * d.x + p.y * d.y + kk * p.z * d.z) - d.z;
    double cc = c * (p.x * p.x + p.y * p.y + kk * p.z * p.z) - 2.0 * p.z;
    double disc = b * b - a * cc;
    if (!(disc >= 0.0)) return 0;
    /* Rust's signum: ±1 by the sign bit (b is not NaN here: disc would be NaN). */
    double q = -(b + DC_COPYSIGN(1.0, b) * DC_SQRT(disc));
    if (q == 0.0) return 0;
    double t1 = cc / q;
    if (dc_on_branch_at(p, d, t1, c, kk)) {
        *t_out = t1;
        return 1;
    }
    double t2 = q / a;
    if (a != 0.0 && dc_on_branch_at(p, d, t2, c, kk)) {
        *t_out = t2;
        return 1;
    }
    return 0;
}

/* The conic sag c r² / (1 + √(1 − (1+k) c² r²)); NaN outside the domain (as surfaces::conic_sag). */
DC_FN double dc_conic_sag(double c, double k, double r2) {
    double disc = 1.0 - (1.0 + k) * c * c * r2;
    if (disc < 0.0) return DC_NAN;
    return c * r2 / (1.0 + DC_SQRT(disc));
}

DC_FN double dc_conic_dsag_dr2(double c, double k, double r2) {
    double disc = 1.0 - (1.0 + k) * c * c * r2;
    if (disc <= 0.0) return DC_NAN;
    return c / (2.0 * DC_SQRT(disc));
}

/* Σ aᵢ r^{2i} and its derivative with respect to r², by Horner from the highest term. */
DC_FN void dc_asphere_poly(const dc_step *s, double r2, double *value, double *deriv) {
    double v = 0.0, dv = 0.0;
    for (int i = (int)s->n_coef - 1; i >= 0; --i) {
        double power = (double)(i + 1);
        double a = s->coef[i];
        v = (v + a) * r2;
        dv = dv * r2 + power * a;
    }
    *value = v;
    *deriv = dv;
}

DC_FN double dc_sag(const dc_step *s, double x, double y) {
    double r2 = x * x + y * y;
    double v, dv;
    switch (s->shape) {
    case DC_SHAPE_CONIC: return dc_conic_sag(s->curvature, s->conic, r2);
    case DC_SHAPE_ASPHERE:
        dc_asphere_poly(s, r2, &v, &dv);
        return dc_conic_sag(s->curvature, s->conic, r2) + v;
    default: return 0.0;
    }
}

DC_FN void dc_sag_gradient(const dc_step *s, double x, double y, double *gx, double *gy) {
    double r2 = x * x + y * y;
    double dz_dr2 = 0.0, v, dv;
    switch (s->shape) {
    case DC_SHAPE_CONIC: dz_dr2 = dc_conic_dsag_dr2(s->curvature, s->conic, r2); break;
    case DC_SHAPE_ASPHERE:
        dc_asphere_poly(s, r2, &v, &dv);
        dz_dr2 = dc_conic_dsag_dr2(s->curvature, s->conic, r2) + dv;
        break;
    default: break;
    }
    *gx = 2.0 * x * dz_dr2;
    *gy = 2.0 * y * dz_dr2;
}

DC_FN dc_v3 dc_normal(const dc_step *s, dc_v3 q) {
    double c = s->curvature, k = s->conic, gx, gy;
    switch (s->shape) {
    case DC_SHAPE_CONIC: return dc_normalize(dc_v3_make(-c * q.x, -c * q.y, 1.0 - c * (1.0 + k) * q.z));
    case DC_SHAPE_ASPHERE:
        dc_sag_gradient(s, q.x, q.y, &gx, &gy);
        return dc_normalize(dc_v3_make(-gx, -gy, 1.0));
    default: return dc_v3_make(0.0, 0.0, 1.0);
    }
}

/* f(t) = z(t) − sag(x(t), y(t)) and f′(t). */
DC_FN void dc_asphere_eval(const dc_step *s, dc_v3 p, dc_v3 d, double t, double *f, double *fp) {
    dc_v3 q = dc_add(p, dc_scale(d, t));
    double gx, gy;
    *f = q.z - dc_sag(s, q.x, q.y);
    dc_sag_gradient(s, q.x, q.y, &gx, &gy);
    *fp = d.z - gx * d.x - gy * d.y;
}

/* Newton on f(t), guarded by a bracket once a sign change is seen (surfaces::intersect::asphere_newton).
 * Returns DC_OK with *t_out, DC_MISSED or DC_NO_CONVERGENCE. */
DC_FN dc_u32 dc_asphere_newton(const dc_step *s, dc_v3 p, dc_v3 d, double t0, double *t_out) {
    double t = t0, lo = 0.0, hi = 0.0, f, fp;
    int has_lo = 0, has_hi = 0;
    for (int it = 0; it < 100; ++it) {
        dc_asphere_eval(s, p, d, t, &f, &fp);
        if (!DC_ISFINITE(f)) {
            if (has_lo && has_hi) {
                t = 0.5 * (lo + hi);
                continue;
            }
            return DC_MISSED;
        }
        if (f == 0.0) {
            *t_out = t;
            return DC_OK;
        }
        if (f < 0.0) {
            lo = t;
            has_lo = 1;
        } else {
            hi = t;
            has_hi = 1;
        }
        double next = t - f / fp;
        if (has_lo && has_hi) {
            double mn = lo < hi ? lo : hi, mx = lo < hi ? hi : lo;
            if (!(next > mn && next < mx)) next = 0.5 * (lo + hi);
            if ((mx - mn) <= 4.0 * DC_EPSILON * (1.0 + DC_FABS(t))) {
                *t_out = next;
                return DC_OK;
            }
        } else if (!DC_ISFINITE(next)) {
            return DC_NO_CONVERGENCE;
        }
        if (DC_FABS(next - t) <= 1e-15 * (1.0 + DC_FABS(t))) {
            double fn, fpn;
            dc_asphere_eval(s, p, d, next, &fn, &fpn);
            if (DC_ISFINITE(fn) && DC_FABS(fn) < 1e-9) {
                *t_out = next;
                return DC_OK;
            }
            return DC_NO_CONVERGENCE;
        }
        t = next;
    }
    dc_asphere_eval(s, p, d, t, &f, &fp);
    if (DC_ISFINITE(f) && DC_FABS(f) < 1e-12) {
        *t_out = t;
        return DC_OK;
    }
    return DC_NO_CONVERGENCE;
}

/* The surface's intersection: DC_OK with the hit point and unit normal (toward local +z), or a failure. */
DC_FN dc_u32 dc_intersect(const dc_step *s, dc_v3 p, dc_v3 d, dc_v3 *point, dc_v3 *normal) {
    double t;
    switch (s->shape) {
    case DC_SHAPE_CONIC:
        if (s->curvature != 0.0) {
            if (!dc_conic_root(s->curvature, s->conic, p, d, &t)) return DC_MISSED;
            *point = dc_add(p, dc_scale(d, t));
            *normal = dc_normal(s, *point);
            return DC_OK;
        }
        /* fallthrough - a flat conic is the plane */
    case DC_SHAPE_PLANE:
    case DC_SHAPE_PARAXIAL:
        if (!dc_intersect_plane(p, d, &t, point)) return DC_MISSED;
        *normal = dc_v3_make(0.0, 0.0, 1.0);
        return DC_OK;
    case DC_SHAPE_ASPHERE: {
        /* Starts: the base conic's root, then the vertex plane's (see intersect.rs). */
        double starts[2];
        int ok[2];
        dc_v3 q;
        ok[0] = s->curvature != 0.0 && dc_conic_root(s->curvature, s->conic, p, d, &starts[0]);
        ok[1] = dc_intersect_plane(p, d, &starts[1], &q);
        dc_u32 result = DC_MISSED;
        for (int k = 0; k < 2; ++k) {
            if (!ok[k]) continue;
            result = dc_asphere_newton(s, p, d, starts[k], &t);
            if (result == DC_OK) break;
        }
        if (result != DC_OK) return result;
        *point = dc_add(p, dc_scale(d, t));
        *normal = dc_normal(s, *point);
        if (!dc_v3_finite(*normal)) return DC_MISSED;
        return DC_OK;
    }
    default: return DC_MISSED;
    }
}

DC_FN int dc_aperture_contains(const dc_step *s, double x, double y) {
    const double *a = s->aperture;
    switch (s->aperture_kind) {
    case DC_APERTURE_CIRCULAR: {
        double u = x - a[2], v = y - a[3];
        double r2 = u * u + v * v;
        return r2 <= a[0] * a[0] && r2 >= a[1] * a[1];
    }
    case DC_APERTURE_RECTANGULAR: return DC_FABS(x - a[2]) <= a[0] && DC_FABS(y - a[3]) <= a[1];
    default: return 1;
    }
}

/* Vector Snell's law (tracer::kernel::refract); 0 on total internal reflection. */
DC_FN int dc_refract(dc_v3 d, dc_v3 normal, double n1, double n2, dc_v3 *out) {
    dc_v3 nrm = normal;
    double cos_i = dc_dot(d, nrm);
    if (cos_i < 0.0) {
        nrm = dc_neg(nrm);
        cos_i = -cos_i;
    }
    double mu = n1 / n2;
    double k = 1.0 - mu * mu * (1.0 - cos_i * cos_i);
    if (k < 0.0) return 0;
    *out = dc_add(dc_scale(d, mu), dc_scale(nrm, DC_SQRT(k) - mu * cos_i));
    return 1;
}

/* Zemax's Paraxial surface: tan′ = (n₁/n₂)·tan − h/f (tracer::kernel::paraxial_deflect). */
DC_FN dc_v3 dc_paraxial_deflect(dc_v3 p, dc_v3 d, double f, double n1, double n2) {
    double mu = n1 / n2;
    double tx = mu * d.x / d.z - p.x / f;
    double ty = mu * d.y / d.z - p.y / f;
    dc_v3 v = dc_normalize(dc_v3_make(tx, ty, 1.0));
    return d.z < 0.0 ? dc_neg(v) : v;
}

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

/* One step (tracer::kernel::trace_step): into the frame, intersect, clip, refract. `n` holds the index
 * after each surface. Returns DC_OK or the status at which the ray stopped. */
DC_FN dc_u32 dc_trace_step(const dc_step *s, const double *n, dc_v3 *p, dc_v3 *d) {
    dc_v3 off = dc_v3_make(s->offset[0], s->offset[1], s->offset[2]);
    dc_v3 lp = dc_m3_mul(&s->rotation, dc_sub(*p, off));
    dc_v3 ld = dc_m3_mul(&s->rotation, *d);
    dc_v3 q, normal;
    dc_u32 st = dc_intersect(s, lp, ld, &q, &normal);
    if (st != DC_OK) return st;
    if (!dc_aperture_contains(s, q.x, q.y)) return DC_VIGNETTED;
    double n1 = n[s->surface - 1], n2 = n[s->surface];
    if (s->shape == DC_SHAPE_PARAXIAL) {
        ld = dc_paraxial_deflect(q, ld, s->focal_length, n1, n2);
    } else if (n1 != n2) {
        dc_v3 r;
        if (!dc_refract(ld, normal, n1, n2, &r)) return DC_TIR;
        ld = r;
    }
    *p = q;
    *d = ld;
    return DC_OK;
}

/* A whole ray: validate the input, then every step. On DC_OK, (p, d) are on the last surface in its
 * frame and *surface is DC_NO_SURFACE; otherwise *surface is where the ray stopped (0 for invalid input). */
DC_FN dc_u32 dc_trace_ray(const dc_step *path, dc_u32 n_steps, const double *n, dc_v3 *p, dc_v3 *d, dc_u32 *surface) {
    dc_v3 u;
    if (!dc_unit_direction(*d, &u) || !dc_v3_finite(*p)) {
        *surface = 0;
        return DC_INVALID_INPUT;
    }
    *d = u;
    for (dc_u32 i = 0; i < n_steps; ++i) {
        dc_u32 st = dc_trace_step(&path[i], n, p, d);
        if (st != DC_OK) {
            *surface = path[i].surface;
            return st;
        }
    }
    *surface = DC_NO_SURFACE;
    return DC_OK;
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

DC_FN void dc_trace_batch_ray(const dc_batch *b, dc_u64 i) {
    dc_v3 p = dc_v3_make(b->ox[i], b->oy[i], b->oz[i]);
    dc_v3 d = dc_v3_make(b->dx[i], b->dy[i], b->dz[i]);
    dc_u32 surface = 0;
    const double *n = b->tables + (dc_u64)b->table_of_ray[i] * b->n_surfaces;
    dc_u32 st = dc_trace_ray(b->path, b->n_steps, n, &p, &d, &surface);
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
