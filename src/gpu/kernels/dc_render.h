/* diffcassi GPU kernels: where the renderer's rays land, one ray per call.
 *
 * Ray t of a plane launch is ray k = t mod N of open scene pixel pixels[t div N]: its sample
 * (dc_sample.h), its object ray, the sequential trace (dc_trace.h), and its landing on the detector in
 * continuous pixel coordinates — the numbers render::transport computes before its bilinear splat. A ray
 * that stops, or arrives non-finite or beyond max_coord_mm (limits::MAX_IMAGE_COORD_MM: `out_of_range`),
 * lands nowhere (u = v = NaN) and carries its status.
 */
#ifndef DC_RENDER_H
#define DC_RENDER_H
#include "dc_sample.h"
#include "dc_trace.h"

/* tracer::RayStatus::OutOfRange. */
#define DC_OUT_OF_RANGE 8u

typedef struct {
    const dc_step *path;
    const double *n;         /* the plane's indices after each surface */
    const dc_u32 *pixels;    /* open scene pixels, row-major index */
    double *u, *v;           /* landing, detector pixels (NaN: none) */
    unsigned char *status;   /* tracer::RayStatus code */
    dc_sampler sampler;
    dc_aim aim;
    dc_scene scene;
    dc_u64 plane;
    dc_u64 n_pixels;
    double max_coord_mm;
    dc_u32 n_steps;
    dc_u32 pad;
} dc_landing_batch;

/* Ray t of the launch: its status, and where it lands (*u, *v; NaN when it does not arrive). `f32`: the
 * renderer's f32 trace (dc_trace_ray_raw_f32, as render::transport::trace_row_lanes_f32), its results widened
 * to f64 and landed like the f64 ones. */
DC_FN dc_u32 dc_land(const dc_landing_batch *b, dc_u64 t, double *u_out, double *v_out, int f32) {
    dc_u64 q = t / b->sampler.rays;
    dc_u32 k = (dc_u32)(t % b->sampler.rays);
    dc_u32 pixel = b->pixels[q];
    dc_u32 row = pixel / b->scene.scene_width, col = pixel % b->scene.scene_width;
    double s[4];
    dc_v3 o, d;
    dc_u32 surface;
    dc_sample_ray(&b->sampler, b->plane, pixel, k, s);
    dc_object_ray(&b->scene, &b->aim, row, col, s, &o, &d);
    dc_u32 st = f32 ? dc_trace_ray_raw_f32(b->path, b->n_steps, b->n, &o, &d, &surface) : dc_trace_ray(b->path, b->n_steps, b->n, &o, &d, &surface);
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

/* Ray t of the launch, its outputs written at index `slot` of u, v and status (the device: slot = t; the host
 * twin: t − the first ray of its chunk, so that each chunk writes its own arrays); `f32` as dc_land's. */
DC_FN void dc_landing_ray(const dc_landing_batch *b, dc_u64 t, dc_u64 slot, int f32) {
    double u, v;
    dc_u32 st = dc_land(b, t, &u, &v, f32);
    b->u[slot] = u;
    b->v[slot] = v;
    b->status[slot] = (unsigned char)st;
}

/* ---- Footprints: one open pixel's bilinear splat (render::transport::PlaneContext::footprint) ----------------
 *
 * Pass 1 (dc_footprint_size): from the pixel's N landings, the window (the bounding box of its bilinear cells,
 * clipped to the detector) and whether it is empty. Pass 2 (dc_footprint_fill), after the caller's prefix sum
 * of the window sizes: the window's taps summed in ray order in f64 into `scratch` (zeroed), the weight lost off
 * the detector, and the window scaled by 1/N into f32 `weights` — the CPU's numbers, operation for operation.
 */
typedef struct {
    dc_i64 x0, y0;  /* the window's corner (detector column, row) */
    dc_u32 w, h;    /* its size; 0 × 0: no footprint */
    double off_detector; /* splat weight (in rays) that fell off the detector */
} dc_window;

/* floor as an integer, as `f64::floor(..) as i64` gives it for the coordinates the tracer lets through. */
DC_FN dc_i64 dc_floor_i64(double x) { return (dc_i64)floor(x); }

DC_FN void dc_footprint_size(const double *u, const double *v, dc_u32 n, dc_i64 det_w, dc_i64 det_h, dc_window *out) {
    dc_i64 x0 = 0x7FFFFFFFFFFFFFFFll, x1 = -0x7FFFFFFFFFFFFFFFll - 1, y0 = x0, y1 = x1;
    dc_u32 arrived = 0;
    for (dc_u32 t = 0; t < n; ++t) {
        if (u[t] != u[t]) continue; /* NaN: did not arrive */
        dc_i64 j = dc_floor_i64(u[t]), i = dc_floor_i64(v[t]);
        arrived += 1;
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
        out->off_detector = (double)arrived;
        return;
    }
    out->x0 = cx0;
    out->y0 = cy0;
    out->w = (dc_u32)(cx1 - cx0 + 1);
    out->h = (dc_u32)(cy1 - cy0 + 1);
}

/* `scratch` and `weights` point at this window's w·h cells; `scratch` is zero on entry. */
DC_FN void dc_footprint_fill(const double *u, const double *v, dc_u32 n, dc_window *win, double *scratch, float *weights) {
    dc_i64 ww = win->w, wh = win->h;
    double lost = 0.0;
    for (dc_u32 t = 0; t < n; ++t) {
        if (u[t] != u[t]) continue;
        double fj = floor(u[t]), fi = floor(v[t]);
        dc_i64 j = (dc_i64)fj, i = (dc_i64)fi;
        double fu = u[t] - fj, fv = v[t] - fi;
        double wi[2] = {1.0 - fv, fv}, wj[2] = {1.0 - fu, fu};
        for (int di = 0; di < 2; ++di) {
            for (int dj = 0; dj < 2; ++dj) {
                dc_i64 r = i + di - win->y0, c = j + dj - win->x0;
                double tap = wi[di] * wj[dj];
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
