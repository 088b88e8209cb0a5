/* diffcassi GPU kernels: the sequential trace over one real type, a template included twice by dc_trace.h (no
 * include guard). DC_P = f64 (names unchanged) is src/tracer/kernel.rs and src/surfaces/intersect.rs,
 * expression for expression; DC_P = f32 (names suffixed _f32) is one lane of tracer::simd::block in f32 — the
 * same algorithm, with each system constant computed in f64 and rounded once (DC_R), the refractive index
 * tables kept in f64 (the index change decided on them, n₁/n₂ divided in f64 and rounded), and the f32
 * tolerances of dc_common.h. Every operation is an IEEE operation of DC_REAL in the Rust order, without
 * contraction, so each instance computes its Rust kernel's bits. Where the f32 lane kernel itself works in
 * f64 — a mirror, a grating, a Toroidal surface's intersection (tracer::simd::block: the ray widened, the
 * scalar f64 functions, the result rounded once) — the f32 instance does the same with the f64 functions;
 * DC_F64_PASS is 1 in the f64 instance, which alone defines those f64-only pieces (the toroid's solve).
 */

/* The vertex plane z = 0: t = −p_z/d_z. Returns 0 on success. */
DC_FN int DC_T(dc_intersect_plane)(DC_V3 p, DC_V3 d, DC_REAL *t_out, DC_V3 *point) {
    if (d.z == DC_R(0.0)) return 0;
    DC_REAL t = -p.z / d.z;
    DC_V3 q = DC_T(dc_v3_make)(p.x + t * d.x, p.y + t * d.y, DC_R(0.0));
    if (!DC_T(dc_v3_finite)(q)) return 0;
    *t_out = t;
    *point = q;
    return 1;
}

/* Whether `q`, reached at distance t from the solve's start, lies on the vertex branch of c(x²+y²+kk·z²) − 2z = 0
 * (where the sag formula holds; the f32 tolerance grows with t). */
DC_FN int DC_T(dc_on_conic_vertex_branch)(DC_V3 q, DC_REAL t, double c, double kk) {
    DC_REAL r2 = q.x * q.x + q.y * q.y;
    DC_REAL domain = DC_R(1.0) - DC_R(kk * c * c) * r2;
    (void)t; /* the f64 tolerance does not use it */
    if (domain < DC_R(0.0)) return 0;
    DC_REAL sag = DC_R(c) * r2 / (DC_R(1.0) + DC_RSQRT(domain));
    return DC_RFABS(q.z - sag) <= DC_BRANCH_TOL(q.z, t);
}

/* Vertex-branch root of the conic along p + t d, solved from the line's point nearest the vertex
 * p0 = p + t0·d, t0 = −p·d (a start far in front otherwise loses the discriminant's digits), in the
 * cancellation-free pair s₁ = C/q, s₂ = q/A; the root nearest the ray's start (|t0 + s| smallest) is tested
 * first: surfaces::intersect::conic_root. Gives t = t0 + s and the point p0 + s·d. */
DC_FN int DC_T(dc_conic_root)(double c, double k, DC_V3 p, DC_V3 d, DC_REAL *t_out, DC_V3 *point_out) {
    double kk = 1.0 + k;
    DC_REAL cl = DC_R(c), kl = DC_R(kk);
    DC_REAL t0 = -DC_T(dc_dot)(p, d);
    DC_V3 p0 = DC_T(dc_add)(p, DC_T(dc_scale)(d, t0));
    DC_REAL a = cl * (d.x * d.x + d.y * d.y + kl * d.z * d.z);
    DC_REAL b = cl * (p0.x * d.x + p0.y * d.y + kl * p0.z * d.z) - d.z;
    DC_REAL cc = cl * (p0.x * p0.x + p0.y * p0.y + kl * p0.z * p0.z) - DC_R(2.0) * p0.z;
    DC_REAL disc = b * b - a * cc;
    if (!(disc >= DC_R(0.0))) return 0;
    /* Rust's signum: ±1 by the sign bit (b is not NaN here: disc would be NaN). */
    DC_REAL q = -(b + DC_RCOPYSIGN(DC_R(1.0), b) * DC_RSQRT(disc));
    if (q == DC_R(0.0)) return 0;
    DC_REAL s[2], r[2];
    s[0] = cc / q;
    s[1] = q / a; /* ±inf or NaN when a = 0: never finite, never swapped */
    r[0] = t0 + s[0];
    r[1] = t0 + s[1];
    int first = DC_RFABS(r[1]) < DC_RFABS(r[0]) ? 1 : 0;
    for (int i = 0; i < 2; ++i) {
        int j = i == 0 ? first : 1 - first;
        DC_V3 q_pt = DC_T(dc_add)(p0, DC_T(dc_scale)(d, s[j]));
        if (isfinite(s[j]) && isfinite(r[j]) && DC_T(dc_on_conic_vertex_branch)(q_pt, s[j], c, kk)) {
            *t_out = r[j];
            *point_out = q_pt;
            return 1;
        }
    }
    return 0;
}

/* The conic sag c r² / (1 + √(1 − (1+k) c² r²)); NaN outside the domain (as surfaces::conic_sag). */
DC_FN DC_REAL DC_T(dc_conic_sag)(double c, double k, DC_REAL r2) {
    DC_REAL disc = DC_R(1.0) - DC_R((1.0 + k) * c * c) * r2;
    if (disc < DC_R(0.0)) return DC_RNAN;
    return DC_R(c) * r2 / (DC_R(1.0) + DC_RSQRT(disc));
}

DC_FN DC_REAL DC_T(dc_conic_dsag_dr2)(double c, double k, DC_REAL r2) {
    DC_REAL disc = DC_R(1.0) - DC_R((1.0 + k) * c * c) * r2;
    if (disc <= DC_R(0.0)) return DC_RNAN;
    return DC_R(c) / (DC_R(2.0) * DC_RSQRT(disc));
}

/* Σ aᵢ r^{2i} and its derivative with respect to r², by Horner from the highest term. */
DC_FN void DC_T(dc_asphere_poly)(const dc_step *s, DC_REAL r2, DC_REAL *value, DC_REAL *deriv) {
    DC_REAL v = DC_R(0.0), dv = DC_R(0.0);
    for (int i = (int)s->n_coef - 1; i >= 0; --i) {
        double power = (double)(i + 1);
        double a = s->coef[i];
        v = (v + DC_R(a)) * r2;
        dv = dv * r2 + DC_R(power * a);
    }
    *value = v;
    *deriv = dv;
}

DC_FN DC_REAL DC_T(dc_sag)(const dc_step *s, DC_REAL x, DC_REAL y) {
    DC_REAL r2 = x * x + y * y;
    DC_REAL v, dv;
#if DC_F64_PASS
    if (s->shape == DC_SHAPE_TOROIDAL) {
        double gx, gy;
        dc_toroid_local(s, x, y, &v, &gx, &gy);
        return v;
    }
#endif
    switch (s->shape) {
    case DC_SHAPE_CONIC: return DC_T(dc_conic_sag)(s->curvature, s->conic, r2);
    case DC_SHAPE_ASPHERE:
        DC_T(dc_asphere_poly)(s, r2, &v, &dv);
        return DC_T(dc_conic_sag)(s->curvature, s->conic, r2) + v;
    default: return DC_R(0.0);
    }
}

DC_FN void DC_T(dc_sag_gradient)(const dc_step *s, DC_REAL x, DC_REAL y, DC_REAL *gx, DC_REAL *gy) {
    DC_REAL r2 = x * x + y * y;
    DC_REAL dz_dr2 = DC_R(0.0), v, dv;
#if DC_F64_PASS
    if (s->shape == DC_SHAPE_TOROIDAL) {
        /* SurfaceShape::sag_gradient: the toroid's own (z_x, z_y) */
        dc_toroid_local(s, x, y, &v, gx, gy);
        return;
    }
#endif
    switch (s->shape) {
    case DC_SHAPE_CONIC: dz_dr2 = DC_T(dc_conic_dsag_dr2)(s->curvature, s->conic, r2); break;
    case DC_SHAPE_ASPHERE:
        DC_T(dc_asphere_poly)(s, r2, &v, &dv);
        dz_dr2 = DC_T(dc_conic_dsag_dr2)(s->curvature, s->conic, r2) + dv;
        break;
    default: break;
    }
    *gx = DC_R(2.0) * x * dz_dr2;
    *gy = DC_R(2.0) * y * dz_dr2;
}

DC_FN DC_V3 DC_T(dc_normal)(const dc_step *s, DC_V3 q) {
    double c = s->curvature, k = s->conic;
    DC_REAL gx, gy;
    switch (s->shape) {
    case DC_SHAPE_CONIC: return DC_T(dc_normalize)(DC_T(dc_v3_make)(DC_R(-c) * q.x, DC_R(-c) * q.y, DC_R(1.0) - DC_R(c * (1.0 + k)) * q.z));
    case DC_SHAPE_ASPHERE:
    case DC_SHAPE_TOROIDAL:
        DC_T(dc_sag_gradient)(s, q.x, q.y, &gx, &gy);
        return DC_T(dc_normalize)(DC_T(dc_v3_make)(-gx, -gy, DC_R(1.0)));
    default: return DC_T(dc_v3_make)(DC_R(0.0), DC_R(0.0), DC_R(1.0));
    }
}

/* f(t) = z(t) − sag(x(t), y(t)) and f′(t). */
DC_FN void DC_T(dc_asphere_eval)(const dc_step *s, DC_V3 p, DC_V3 d, DC_REAL t, DC_REAL *f, DC_REAL *fp) {
    DC_V3 q = DC_T(dc_add)(p, DC_T(dc_scale)(d, t));
    DC_REAL gx, gy;
    *f = q.z - DC_T(dc_sag)(s, q.x, q.y);
    DC_T(dc_sag_gradient)(s, q.x, q.y, &gx, &gy);
    *fp = d.z - gx * d.x - gy * d.y;
}

/* Newton on f(t), guarded by a bracket once a sign change is seen (surfaces::intersect::asphere_newton; the
 * lane kernel's `asphere_newton` is the same rule per lane). Returns DC_OK with *t_out, DC_MISSED or
 * DC_NO_CONVERGENCE. */
DC_FN dc_u32 DC_T(dc_asphere_newton)(const dc_step *s, DC_V3 p, DC_V3 d, DC_REAL t0, DC_REAL *t_out) {
    DC_REAL t = t0, lo = DC_R(0.0), hi = DC_R(0.0), f, fp;
    int has_lo = 0, has_hi = 0;
    for (int it = 0; it < 100; ++it) {
        DC_T(dc_asphere_eval)(s, p, d, t, &f, &fp);
        if (!isfinite(f)) {
            if (has_lo && has_hi) {
                t = DC_R(0.5) * (lo + hi);
                continue;
            }
            return DC_MISSED;
        }
        if (f == DC_R(0.0)) {
            *t_out = t;
            return DC_OK;
        }
        if (f < DC_R(0.0)) {
            lo = t;
            has_lo = 1;
        } else {
            hi = t;
            has_hi = 1;
        }
        DC_REAL next = t - f / fp;
        if (has_lo && has_hi) {
            DC_REAL mn = lo < hi ? lo : hi, mx = lo < hi ? hi : lo;
            if (!(next > mn && next < mx)) next = DC_R(0.5) * (lo + hi);
            if ((mx - mn) <= DC_NEWTON_WIDTH * (DC_R(1.0) + DC_RFABS(t))) {
                *t_out = next;
                return DC_OK;
            }
        } else if (!isfinite(next)) {
            return DC_NO_CONVERGENCE;
        }
        if (DC_RFABS(next - t) <= DC_NEWTON_STEP_TOL(t)) {
            DC_REAL fn, fpn;
            DC_T(dc_asphere_eval)(s, p, d, next, &fn, &fpn);
            if (isfinite(fn) && DC_RFABS(fn) < DC_NEWTON_RESIDUAL_TOL(next)) {
                *t_out = next;
                return DC_OK;
            }
            return DC_NO_CONVERGENCE;
        }
        t = next;
    }
    DC_T(dc_asphere_eval)(s, p, d, t, &f, &fp);
    if (isfinite(f) && DC_RFABS(f) < DC_NEWTON_FINAL_TOL(t)) {
        *t_out = t;
        return DC_OK;
    }
    return DC_NO_CONVERGENCE;
}

/* The guarded Newton solve of an even asphere or a toroid from the first of two starts that converges, the
 * vertex plane's root and the base conic's (a failed start is skipped), then the hit and its normal (missed
 * where the normal is not finite): surfaces::intersect::newton_hit. The even asphere tries the conic's root
 * first, the toroid the plane's (`plane_first`), as intersect.rs orders them. */
DC_FN dc_u32 DC_T(dc_newton_hit)(const dc_step *s, DC_V3 p, DC_V3 d, int plane_first, DC_V3 *point, DC_V3 *normal) {
    DC_REAL starts[2], t;
    int ok[2];
    DC_V3 q, q_conic; /* the starts' points, unused: the solve keeps t */
    int ic = plane_first ? 1 : 0, ip = 1 - ic;
    ok[ic] = s->curvature != 0.0 && DC_T(dc_conic_root)(s->curvature, s->conic, p, d, &starts[ic], &q_conic);
    ok[ip] = DC_T(dc_intersect_plane)(p, d, &starts[ip], &q);
    dc_u32 result = DC_MISSED;
    for (int k = 0; k < 2; ++k) {
        if (!ok[k]) continue;
        result = DC_T(dc_asphere_newton)(s, p, d, starts[k], &t);
        if (result == DC_OK) break;
    }
    if (result != DC_OK) return result;
    *point = DC_T(dc_add)(p, DC_T(dc_scale)(d, t));
    *normal = DC_T(dc_normal)(s, *point);
    if (!DC_T(dc_v3_finite)(*normal)) return DC_MISSED;
    return DC_OK;
}

/* The surface's intersection: DC_OK with the hit point and unit normal (toward local +z), or a failure. */
DC_FN dc_u32 DC_T(dc_intersect)(const dc_step *s, DC_V3 p, DC_V3 d, DC_V3 *point, DC_V3 *normal) {
    DC_REAL t;
    switch (s->shape) {
    case DC_SHAPE_CONIC:
        if (s->curvature != 0.0) {
            if (!DC_T(dc_conic_root)(s->curvature, s->conic, p, d, &t, point)) return DC_MISSED;
            *normal = DC_T(dc_normal)(s, *point);
            return DC_OK;
        }
        /* fallthrough - a flat conic is the plane */
    case DC_SHAPE_PLANE:
    case DC_SHAPE_PARAXIAL:
        if (!DC_T(dc_intersect_plane)(p, d, &t, point)) return DC_MISSED;
        *normal = DC_T(dc_v3_make)(DC_R(0.0), DC_R(0.0), DC_R(1.0));
        return DC_OK;
#if DC_F64_PASS
    /* One Newton for both (dc_sag and dc_sag_gradient switch on the shape): the toroid starts from the plane. */
    case DC_SHAPE_ASPHERE:
    case DC_SHAPE_TOROIDAL: return dc_newton_hit(s, p, d, s->shape == DC_SHAPE_TOROIDAL, point, normal);
#else
    case DC_SHAPE_ASPHERE: return DC_T(dc_newton_hit)(s, p, d, 0, point, normal);
    case DC_SHAPE_TOROIDAL: {
        /* In f64 (tracer::simd::block's Toroidal arm: the scalar intersection on the widened ray, its point and
         * normal rounded once). */
        dc_v3 qk, nk;
        dc_u32 st = dc_newton_hit(s, dc_v3_make((double)p.x, (double)p.y, (double)p.z), dc_v3_make((double)d.x, (double)d.y, (double)d.z), 1, &qk, &nk);
        if (st != DC_OK) return st;
        *point = DC_T(dc_v3_make)((DC_REAL)qk.x, (DC_REAL)qk.y, (DC_REAL)qk.z);
        *normal = DC_T(dc_v3_make)((DC_REAL)nk.x, (DC_REAL)nk.y, (DC_REAL)nk.z);
        return DC_OK;
    }
#endif
    default: return DC_MISSED;
    }
}

DC_FN int DC_T(dc_aperture_contains)(const dc_step *s, DC_REAL x, DC_REAL y) {
    const double *a = s->aperture;
    switch (s->aperture_kind) {
    case DC_APERTURE_CIRCULAR: {
        DC_REAL u = x - DC_R(a[2]), v = y - DC_R(a[3]);
        DC_REAL r2 = u * u + v * v;
        return r2 <= DC_R(a[0] * a[0]) && r2 >= DC_R(a[1] * a[1]);
    }
    case DC_APERTURE_RECTANGULAR: return DC_RFABS(x - DC_R(a[2])) <= DC_R(a[0]) && DC_RFABS(y - DC_R(a[3])) <= DC_R(a[1]);
    case DC_APERTURE_OBSCURATION: {
        /* Aperture::contains: the blocked annulus is closed (its edges block), r² < rmin² or r² > rmax²
         * passes, and a NaN point passes neither. */
        DC_REAL u = x - DC_R(a[2]), v = y - DC_R(a[3]);
        DC_REAL r2 = u * u + v * v;
        return r2 < DC_R(a[0] * a[0]) || r2 > DC_R(a[1] * a[1]);
    }
    default: return 1;
    }
}

/* Vector Snell's law (tracer::kernel::refract) with mu = n₁/n₂; 0 on total internal reflection. */
DC_FN int DC_T(dc_refract)(DC_V3 d, DC_V3 normal, DC_REAL mu, DC_V3 *out) {
    DC_V3 nrm = normal;
    DC_REAL cos_i = DC_T(dc_dot)(d, nrm);
    if (cos_i < DC_R(0.0)) {
        nrm = DC_T(dc_neg)(nrm);
        cos_i = -cos_i;
    }
    DC_REAL k = DC_R(1.0) - mu * mu * (DC_R(1.0) - cos_i * cos_i);
    if (k < DC_R(0.0)) return 0;
    *out = DC_T(dc_add)(DC_T(dc_scale)(d, mu), DC_T(dc_scale)(nrm, DC_RSQRT(k) - mu * cos_i));
    return 1;
}

/* A mirror's specular reflection d′ = d − 2(d·n̂)n̂ (tracer::kernel::reflect), evaluated in f64 as the CPU
 * does: the f32 lane kernel widens d and n̂ to f64, reflects and rounds the result once
 * (tracer::simd::block::special_interaction), so the f32 instance does the same and the f64 one is the scalar
 * kernel's expression. 0 at grazing incidence, |d·n̂| ≤ DC_GRAZING_COS (the ray is `missed`). The frame is
 * not flipped (OpticStudio's sequential convention): the ray leaves toward local −z and the next offset is a
 * negative thickness, so nothing else changes here. */
DC_FN int DC_T(dc_reflect)(DC_V3 d, DC_V3 normal, DC_V3 *out) {
    dc_v3 dk = dc_v3_make((double)d.x, (double)d.y, (double)d.z);
    dc_v3 nk = dc_v3_make((double)normal.x, (double)normal.y, (double)normal.z);
    if (DC_FABS(dc_dot(dk, nk)) <= DC_GRAZING_COS) return 0;
    dc_v3 r = dc_sub(dk, dc_scale(nk, 2.0 * dc_dot(dk, nk)));
    *out = DC_T(dc_v3_make)((DC_REAL)r.x, (DC_REAL)r.y, (DC_REAL)r.z);
    return 1;
}

/* A grating's diffraction into its order (tracer::kernel::trace_step's Interaction::Grating): a reflective
 * grating at grazing incidence, |d·n̂| ≤ DC_GRAZING_COS, is missed; the kick mλT takes λ (nm) from the index
 * row's wavelength slot (Grating::kick); an evanescent order stops the ray (DC_EVANESCENT). In f64 as the CPU
 * does (the f32 lane kernel's special_interaction widens d and n̂, diffracts in f64 and rounds once). */
DC_FN dc_u32 DC_T(dc_grating_step)(const dc_step *s, const double *n, DC_V3 d, DC_V3 normal, DC_V3 *out) {
    dc_v3 dk = dc_v3_make((double)d.x, (double)d.y, (double)d.z);
    dc_v3 nk = dc_v3_make((double)normal.x, (double)normal.y, (double)normal.z);
    int reflective = s->interaction == DC_INTERACTION_GRATING_REFLECT;
    if (reflective && DC_FABS(dc_dot(dk, nk)) <= DC_GRAZING_COS) return DC_MISSED;
    double kick = s->grating_order * (n[s->wavelength_slot] * 1e-3) * s->grating_lines_per_um;
    dc_v3 r;
    if (!dc_diffract(dk, nk, n[s->surface - 1], n[s->surface], kick, reflective, &r)) return DC_EVANESCENT;
    *out = DC_T(dc_v3_make)((DC_REAL)r.x, (DC_REAL)r.y, (DC_REAL)r.z);
    return DC_OK;
}

/* Zemax's Paraxial surface: tan′ = (n₁/n₂)·tan − h/f (tracer::kernel::paraxial_deflect), mu = n₁/n₂. */
DC_FN DC_V3 DC_T(dc_paraxial_deflect)(DC_V3 p, DC_V3 d, double f_mm, DC_REAL mu) {
    DC_REAL f = DC_R(f_mm);
    DC_REAL tx = mu * d.x / d.z - p.x / f;
    DC_REAL ty = mu * d.y / d.z - p.y / f;
    DC_V3 v = DC_T(dc_normalize)(DC_T(dc_v3_make)(tx, ty, DC_R(1.0)));
    return d.z < DC_R(0.0) ? DC_T(dc_neg)(v) : v;
}

/* One step (tracer::kernel::trace_step): into the frame, intersect, clip, then reflect (a mirror), diffract (a
 * grating) or refract.
 * `n` holds the index (f64) after each surface. Returns DC_OK or the status at which the ray stopped. */
DC_FN dc_u32 DC_T(dc_trace_step)(const dc_step *s, const double *n, DC_V3 *p, DC_V3 *d) {
    DC_V3 off = DC_T(dc_v3_make)(DC_R(s->offset[0]), DC_R(s->offset[1]), DC_R(s->offset[2]));
    DC_V3 lp = DC_T(dc_m3_mul)(&s->rotation, DC_T(dc_sub)(*p, off));
    DC_V3 ld = DC_T(dc_m3_mul)(&s->rotation, *d);
    DC_V3 q, normal;
    dc_u32 st = DC_T(dc_intersect)(s, lp, ld, &q, &normal);
    if (st != DC_OK) return st;
    if (!DC_T(dc_aperture_contains)(s, q.x, q.y)) return DC_VIGNETTED;
    double n1 = n[s->surface - 1], n2 = n[s->surface];
    DC_REAL mu = DC_R(n1 / n2);
    if (s->interaction == DC_INTERACTION_REFLECT) {
        /* Interaction::Reflect, before the Paraxial and Snell branches as in trace_step. */
        if (!DC_T(dc_reflect)(ld, normal, &ld)) return DC_MISSED;
    } else if (s->interaction == DC_INTERACTION_GRATING || s->interaction == DC_INTERACTION_GRATING_REFLECT) {
        dc_u32 gs = DC_T(dc_grating_step)(s, n, ld, normal, &ld);
        if (gs != DC_OK) return gs;
    } else if (s->shape == DC_SHAPE_PARAXIAL) {
        ld = DC_T(dc_paraxial_deflect)(q, ld, s->focal_length, mu);
    } else if (n1 != n2) {
        DC_V3 r;
        if (!DC_T(dc_refract)(ld, normal, mu, &r)) return DC_TIR;
        ld = r;
    }
    *p = q;
    *d = ld;
    return DC_OK;
}

/* Every step of the path for a checked ray (p finite, d a unit vector). On DC_OK, (p, d) are on the last
 * surface in its frame and *surface is DC_NO_SURFACE; otherwise *surface is where the ray stopped. `probe`
 * (null: none) gets the ray's local (x, y) on step probe->step once it is past it (dc_probe). */
DC_FN dc_u32 DC_T(dc_trace_path)(const dc_step *path, dc_u32 n_steps, const double *n, DC_V3 *p, DC_V3 *d, dc_u32 *surface, dc_probe *probe) {
    for (dc_u32 i = 0; i < n_steps; ++i) {
        dc_u32 st = DC_T(dc_trace_step)(&path[i], n, p, d);
        if (st != DC_OK) {
            *surface = path[i].surface;
            return st;
        }
        if (probe && i == probe->step) {
            probe->x = (double)p->x;
            probe->y = (double)p->y;
            probe->crossed = 1;
        }
    }
    *surface = DC_NO_SURFACE;
    return DC_OK;
}
