/* diffcassi GPU kernels: where the renderer's rays land, one ray per call.
 *
 * Ray t of a plane launch is ray k = t mod N of open scene pixel pixels[t div N]: its sample
 * (dc_sample.h), its object ray, the sequential trace (dc_trace.h), and its landing on the detector in
 * continuous pixel coordinates — the numbers render::transport computes before its bilinear splat. A ray
 * that stops, or arrives non-finite or beyond max_coord_mm (limits::MAX_IMAGE_COORD_MM: `out_of_range`),
 * lands nowhere (u = v = NaN) and carries its status. In a dual-disperser system (the coded mask on a surface
 * inside it) each ray also carries the mask's transmission where it crossed that surface, its weight.
 */
#ifndef DC_RENDER_H
#define DC_RENDER_H
#include "dc_sample.h"
#include "dc_trace.h"

/* tracer::RayStatus::OutOfRange. */
#define DC_OUT_OF_RANGE 8u
/* Not a RayStatus: ray aiming found no ray through the aim point (rays::aimed_ray's error). The CPU renderer
 * stops the render there (PlaneContext::ray's Err), so the host turns the first such ray into the same error. */
#define DC_AIM_FAILED 11u

/* The coded mask on a surface inside the system (dual-disperser CASSI, system::MaskSurface): its pattern and
 * where it lies on the path. Its pixels are laid out as the scene's: an H×W grid of pitch p centred on the
 * surface's vertex, column c covering x ∈ [(c − W/2)·p, (c + 1 − W/2)·p), row r covering
 * y ∈ ((H/2 − r − 1)·p, (H/2 − r)·p] (row 0 at +y). */
typedef struct {
    const float *values; /* height × width, row-major; null: no mask surface (the object-plane mask weights rays) */
    double pitch_mm;
    dc_u32 height, width;
    dc_u32 step;         /* its step on the traced path (MaskSurface::step) */
    dc_u32 bilinear;     /* MaskSampling: 0 nearest, 1 bilinear */
} dc_surface_mask;

/* Mask pixel (r, c) (integral, finite), 0 outside the mask (its opaque frame): MaskSurface::transmission's `at`,
 * its integer bounds compared in f64 (the same answer for every finite integral r, c). */
DC_FN double dc_mask_at(const dc_surface_mask *m, double r, double c) {
    if (!(r >= 0.0 && c >= 0.0 && r < (double)m->height && c < (double)m->width)) return 0.0;
    return (double)m->values[(dc_u64)r * m->width + (dc_u64)c];
}

/* The mask's transmission at local (x, y) mm on its surface (MaskSurface::transmission, operation for operation):
 * continuous pixel coordinates u = x/p + W/2 along the columns, v = H/2 − y/p along the rows; 0 for a non-finite
 * point; nearest reads the containing pixel, bilinear interpolates between the four pixel centres around it. */
DC_FN double dc_mask_transmission(const dc_surface_mask *m, double x, double y) {
    double u = x / m->pitch_mm + (double)m->width * 0.5;
    double v = (double)m->height * 0.5 - y / m->pitch_mm;
    if (!(DC_ISFINITE(u) && DC_ISFINITE(v))) return 0.0;
    if (!m->bilinear) return dc_mask_at(m, floor(v), floor(u));
    double uc = u - 0.5, vc = v - 0.5;
    double c0 = floor(uc), r0 = floor(vc);
    double fu = uc - c0, fv = vc - r0;
    return (1.0 - fv) * ((1.0 - fu) * dc_mask_at(m, r0, c0) + fu * dc_mask_at(m, r0, c0 + 1.0)) + fv * ((1.0 - fu) * dc_mask_at(m, r0 + 1.0, c0) + fu * dc_mask_at(m, r0 + 1.0, c0 + 1.0));
}

typedef struct {
    const dc_step *path;
    const double *n;         /* the plane's indices after each surface */
    const dc_u32 *pixels;    /* open scene pixels, row-major index */
    const dc_step *aim_path; /* ray aiming: aim.aim_steps steps before the stop (apertures open), then the stop's probe */
    double *u, *v;           /* landing, detector pixels (NaN: none) */
    unsigned char *status;   /* tracer::RayStatus code */
    double *w;               /* the coded-mask surface's transmission where the ray crossed it (null: not written) */
    dc_surface_mask surface_mask;
    dc_sampler sampler;
    dc_aim aim;
    dc_scene scene;
    dc_u64 plane;
    dc_u64 n_pixels;
    double max_coord_mm;
    dc_u32 n_steps;
    dc_u32 pad;
} dc_landing_batch;

/* rays::aim::stop_crossing: where the ray (o, d) (object frame, unit d) crosses the stop surface, in the stop's
 * local (x, y) mm — traced through the steps before the stop with their apertures open, then intersected with
 * the stop's figure (intersection only). 0 when it does not get there. */
DC_FN int dc_stop_crossing(const dc_step *aim_path, dc_u32 n_before, const double *n, dc_v3 o, dc_v3 d, double *x, double *y) {
    dc_u32 surface;
    if (dc_trace_path(aim_path, n_before, n, &o, &d, &surface, 0) != DC_OK) return 0;
    const dc_step *s = &aim_path[n_before];
    dc_v3 off = dc_v3_make(s->offset[0], s->offset[1], s->offset[2]);
    dc_v3 lp = dc_m3_mul(&s->rotation, dc_sub(o, off));
    dc_v3 ld = dc_m3_mul(&s->rotation, d);
    dc_v3 q, normal;
    if (dc_intersect(s, lp, ld, &q, &normal) != DC_OK) return 0;
    *x = q.x;
    *y = q.y;
    return 1;
}

/* The object ray through entrance-pupil plane point (u, v) (mm; telecentric: normalised) of field (fx, fy): from
 * the object point (fx, fy, 0), or at infinity parallel with the field's (tan θx, tan θy) = (tx, ty). */
DC_FN void dc_pupil_ray(const dc_aim *aim, double fx, double fy, double tx, double ty, double u, double v, dc_v3 *o, dc_v3 *d) {
    if (aim->at_infinity) {
        dc_parallel_ray_tan(aim, tx, ty, u, v, o, d);
        return;
    }
    *o = dc_v3_make(fx, fy, 0.0);
    *d = dc_aim_through(aim, fx, fy, u, v);
}

/* OpticStudio's ray aiming (RAIM 0 1 paraxial, 0 2 real), rays::aimed_ray operation for operation: the
 * entrance-pupil plane point (u, v), started at (px, py)·r_ep, is moved by Newton's method with a
 * finite-difference Jacobian (step h = 1e-7·max(r_ep, 1)) until the ray crosses the stop at
 * (px, py)·stop_radius_mm (|error| < 1e-13·(1 + r_stop) on both axes, or a step below 1e-14·(1 + r_ep)), at most
 * 30 steps. The three evaluations of a step share one call site (one inlined trace, not three). DC_OK with the
 * aimed ray, or DC_AIM_FAILED (a ray that does not reach the stop, a singular Jacobian, no convergence). */
DC_FN dc_u32 dc_aimed_ray(const dc_aim *aim, const dc_step *aim_path, const double *n, double fx, double fy, double px, double py, dc_v3 *o, dc_v3 *d) {
    double tnx = 0.0, tny = 0.0;
    if (aim->at_infinity) {
        tnx = DC_TAN(fx);
        tny = DC_TAN(fy);
    }
    double r_ep = aim->scale;
    double u = px * r_ep, v = py * r_ep;
    double r_stop = aim->stop_radius_mm;
    double tx = px * r_stop, ty = py * r_stop;
    double h = 1e-7 * dc_max(r_ep, 1.0);
    for (int it = 0; it < 30; ++it) {
        double xs[3], ys[3], ex = 0.0, ey = 0.0;
        for (int j = 0; j < 3; ++j) {
            double uj = j == 1 ? u + h : u, vj = j == 2 ? v + h : v;
            dc_v3 oj, dj;
            dc_pupil_ray(aim, fx, fy, tnx, tny, uj, vj, &oj, &dj);
            if (!dc_stop_crossing(aim_path, aim->aim_steps, n, oj, dj, &xs[j], &ys[j])) return DC_AIM_FAILED;
            if (j == 0) {
                ex = xs[0] - tx;
                ey = ys[0] - ty;
                if (DC_FABS(ex) < 1e-13 * (1.0 + r_stop) && DC_FABS(ey) < 1e-13 * (1.0 + r_stop)) {
                    dc_pupil_ray(aim, fx, fy, tnx, tny, u, v, o, d);
                    return DC_OK;
                }
            }
        }
        double a = (xs[1] - xs[0]) / h, c = (ys[1] - ys[0]) / h;
        double b = (xs[2] - xs[0]) / h, dd = (ys[2] - ys[0]) / h;
        double det = a * dd - b * c;
        if (!(DC_FABS(det) > 0.0) || !DC_ISFINITE(det)) return DC_AIM_FAILED;
        double du = (dd * ex - b * ey) / det;
        double dv = (-c * ex + a * ey) / det;
        u -= du;
        v -= dv;
        if (DC_FABS(du) < 1e-14 * (1.0 + r_ep) && DC_FABS(dv) < 1e-14 * (1.0 + r_ep)) {
            dc_pupil_ray(aim, fx, fy, tnx, tny, u, v, o, d);
            return DC_OK;
        }
    }
    return DC_AIM_FAILED;
}

/* Ray t of the launch: its status, where it lands (*u, *v; NaN when it does not arrive) and its weight *w — with a
 * coded-mask surface its transmission where the ray crossed that surface (0 for a ray that stopped before it:
 * render::transport::trace_through_mask; an arrived ray of weight 0 is `masked`), 1 without one. `f32`: the
 * renderer's f32 trace (dc_trace_ray_raw_f32, as render::transport::trace_row_lanes_f32), its results widened
 * to f64 and landed like the f64 ones. `aimed`: this build aims rays (b->aim.aiming: the host twin passes it;
 * the device has an aimed kernel of each kind, chosen at launch, because the aim's trace to the stop costs
 * ~70 registers a thread that the unaimed kernels should not pay). A launch with aiming on through a kernel
 * built without it fails every ray (DC_AIM_FAILED; the host then reports the disagreement). */
DC_FN dc_u32 dc_land(const dc_landing_batch *b, dc_u64 t, double *u_out, double *v_out, double *w_out, int f32, int aimed) {
    dc_u64 q = t / b->sampler.rays;
    dc_u32 k = (dc_u32)(t % b->sampler.rays);
    dc_u32 pixel = b->pixels[q];
    dc_u32 row = pixel / b->scene.scene_width, col = pixel % b->scene.scene_width;
    double s[4];
    dc_v3 o, d;
    dc_u32 surface;
    dc_sample_ray(&b->sampler, b->plane, pixel, k, s);
    *w_out = 0.0;
    if (!aimed && b->aim.aiming) {
        *u_out = DC_NAN;
        *v_out = DC_NAN;
        return DC_AIM_FAILED;
    }
    if (aimed) {
        /* PlaneContext::ray with ray aiming on: the field point jittered in the pixel, aimed in f64 (the f32
         * renderer aims in f64 too, then rounds the aimed ray as any other: dc_trace_ray_raw_f32). */
        double fx, fy;
        dc_field_point(&b->scene, row, col, s, &fx, &fy);
        if (dc_aimed_ray(&b->aim, b->aim_path, b->n, fx, fy, s[0], s[1], &o, &d) != DC_OK) {
            *u_out = DC_NAN;
            *v_out = DC_NAN;
            return DC_AIM_FAILED;
        }
    } else {
        dc_object_ray(&b->scene, &b->aim, row, col, s, &o, &d);
    }
    /* The coded-mask surface: where the ray crosses its step (one trace, probed there; without a mask surface at
     * no step — always a probe of this frame, so that it stays in registers). */
    int has_mask = b->surface_mask.values != 0;
    dc_probe probe = {has_mask ? b->surface_mask.step : DC_NO_STEP, 0, 0.0, 0.0};
    dc_u32 st = f32 ? dc_trace_ray_raw_f32(b->path, b->n_steps, b->n, &o, &d, &surface, &probe) : dc_trace_ray(b->path, b->n_steps, b->n, &o, &d, &surface, &probe);
    *w_out = !has_mask ? 1.0 : probe.crossed ? dc_mask_transmission(&b->surface_mask, probe.x, probe.y) : 0.0;
    double u = DC_NAN, v = DC_NAN;
    if (st == DC_OK) {
        double m = dc_max(DC_FABS(o.x), dc_max(DC_FABS(o.y), DC_FABS(o.z)));
        if (dc_v3_finite(o) && dc_v3_finite(d) && m <= b->max_coord_mm)
            dc_to_pixel(&b->scene, o.x, o.y, &u, &v);
        else
            st = DC_OUT_OF_RANGE;
    }
    *u_out = u;
    *v_out = v;
    return st;
}

/* Ray t of the launch, its outputs written at index `slot` of u, v, status and w (when not null; the device:
 * slot = t; the host twin: t − the first ray of its chunk, so that each chunk writes its own arrays); `f32`,
 * `aimed` as dc_land's. */
DC_FN void dc_landing_ray(const dc_landing_batch *b, dc_u64 t, dc_u64 slot, int f32, int aimed) {
    double u, v, w;
    dc_u32 st = dc_land(b, t, &u, &v, &w, f32, aimed);
    b->u[slot] = u;
    b->v[slot] = v;
    b->status[slot] = (unsigned char)st;
    if (b->w) b->w[slot] = w;
}

/* ---- Footprints: one open pixel's bilinear splat (render::transport::PlaneContext::footprint) ----------------
 *
 * Pass 1 (dc_footprint_size): from the pixel's N landings, the window (the bounding box of its bilinear cells,
 * clipped to the detector) and whether it is empty. Pass 2 (dc_footprint_fill), after the caller's prefix sum
 * of the window sizes: the window's taps summed in ray order in f64 into `scratch` (zeroed), the weight lost off
 * the detector, and the window scaled by 1/N into f32 `weights` — the CPU's numbers, operation for operation.
 * `w` (null: every ray weighs 1) holds each ray's coded-mask transmission (dc_land): a ray of weight 0 is
 * `masked` and deposits nothing, the others' taps are weighted by it (x·1 = x: without a mask surface the
 * numbers are the same).
 */
typedef struct {
    dc_i64 x0, y0;  /* the window's corner (detector column, row) */
    dc_u32 w, h;    /* its size; 0 × 0: no footprint */
    double off_detector; /* splat weight (in rays) that fell off the detector */
} dc_window;

/* floor as an integer, as `f64::floor(..) as i64` gives it for the coordinates the tracer lets through. */
DC_FN dc_i64 dc_floor_i64(double x) { return (dc_i64)floor(x); }

/* Ray t's weight in a footprint: 0 when it did not arrive (u NaN) or the coded mask blocked it, else its
 * transmission (1 without a mask surface). */
DC_FN double dc_ray_weight(const double *u, const double *w, dc_u32 t) {
    if (u[t] != u[t]) return 0.0;
    return w ? w[t] : 1.0;
}

DC_FN void dc_footprint_size(const double *u, const double *v, const double *w, dc_u32 n, dc_i64 det_w, dc_i64 det_h, dc_window *out) {
    dc_i64 x0 = 0x7FFFFFFFFFFFFFFFll, x1 = -0x7FFFFFFFFFFFFFFFll - 1, y0 = x0, y1 = x1;
    double arrived = 0.0; /* the arrived rays' weight (their count without a mask surface) */
    for (dc_u32 t = 0; t < n; ++t) {
        double wt = dc_ray_weight(u, w, t);
        if (wt == 0.0) continue; /* did not arrive, or masked */
        dc_i64 j = dc_floor_i64(u[t]), i = dc_floor_i64(v[t]);
        arrived += wt;
        x0 = j < x0 ? j : x0;
        x1 = j + 1 > x1 ? j + 1 : x1;
        y0 = i < y0 ? i : y0;
        y1 = i + 1 > y1 ? i + 1 : y1;
    }
    out->w = 0;
    out->h = 0;
    out->off_detector = 0.0;
    out->x0 = 0;
    out->y0 = 0;
    if (x0 > x1) return;
    dc_i64 cx0 = x0 > 0 ? x0 : 0, cx1 = x1 < det_w - 1 ? x1 : det_w - 1;
    dc_i64 cy0 = y0 > 0 ? y0 : 0, cy1 = y1 < det_h - 1 ? y1 : det_h - 1;
    if (cx0 > cx1 || cy0 > cy1) {
        out->off_detector = arrived;
        return;
    }
    out->x0 = cx0;
    out->y0 = cy0;
    out->w = (dc_u32)(cx1 - cx0 + 1);
    out->h = (dc_u32)(cy1 - cy0 + 1);
}

/* `scratch` and `weights` point at this window's w·h cells; `scratch` is zero on entry. */
DC_FN void dc_footprint_fill(const double *u, const double *v, const double *w, dc_u32 n, dc_window *win, double *scratch, float *weights) {
    dc_i64 ww = win->w, wh = win->h;
    double lost = 0.0;
    for (dc_u32 t = 0; t < n; ++t) {
        double wt = dc_ray_weight(u, w, t);
        if (wt == 0.0) continue;
        double fj = floor(u[t]), fi = floor(v[t]);
        dc_i64 j = (dc_i64)fj, i = (dc_i64)fi;
        double fu = u[t] - fj, fv = v[t] - fi;
        double wi[2] = {1.0 - fv, fv}, wj[2] = {1.0 - fu, fu};
        for (int di = 0; di < 2; ++di) {
            for (int dj = 0; dj < 2; ++dj) {
                dc_i64 r = i + di - win->y0, c = j + dj - win->x0;
                double tap = wi[di] * wj[dj] * wt;
                if (r < 0 || r >= wh || c < 0 || c >= ww)
                    lost += tap;
                else
                    scratch[r * ww + c] += tap;
            }
        }
    }
    win->off_detector = lost;
    double weight = 1.0 / (double)n;
    for (dc_i64 k = 0; k < ww * wh; ++k) weights[k] = (float)(scratch[k] * weight);
}

#endif /* DC_RENDER_H */
