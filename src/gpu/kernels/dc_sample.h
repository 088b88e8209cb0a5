/* diffcassi GPU kernels: the renderer's ray generation, one ray per call.
 *
 * The counter-based sampler of src/render/sampling.rs ported bit for bit: ray k of scene pixel q at plane p
 * (seed s) draws its four uniforms from the SplitMix64 finaliser chain keyed by (s, p, q, k); stratified
 * sampling takes pupil cell k and pixel-area cell π(k) of a Fisher–Yates permutation drawn from the pixel's
 * own stream (here replayed backwards for one position, without the array: the same π). The pupil point is
 * the concentric (Shirley–Chiu) disk map with the renderer's branch-free sin/cos (src/render/trig.rs, the
 * fdlibm kernels), and the object ray is PupilAim::direction's (src/rays/aim.rs) through the paraxial
 * entrance pupil (ray aiming off) — for an object at infinity PupilAim::parallel_ray's, the scene sampled in
 * field angle. Landing: Detector::to_pixel's continuous pixel coordinates.
 */
#ifndef DC_SAMPLE_H
#define DC_SAMPLE_H
#include "dc_common.h"

/* SplitMix64's finaliser (render::sampling::mix64). */
DC_FN dc_u64 dc_mix64(dc_u64 z) {
    z = z + 0x9E3779B97F4A7C15ull;
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

DC_FN dc_u64 dc_pixel_key(dc_u64 seed, dc_u64 plane, dc_u64 pixel) { return dc_mix64(dc_mix64(dc_mix64(seed) ^ plane) ^ pixel); }

/* The top 53 bits as a double in [0, 1). */
DC_FN double dc_unit(dc_u64 h) { return (double)(h >> 11) * (1.0 / 9007199254740992.0); }

/* render::trig::sin_cos: fdlibm's __kernel_sin/__kernel_cos after a one-step reduction by π/2, |x| ≤ 3π/4. */
DC_FN void dc_sin_cos(double x, double *s_out, double *c_out) {
    const double FRAC_PI_2 = 1.5707963267948966, FRAC_PI_4 = 0.7853981633974483, PIO2_TAIL = 6.123233995736766e-17;
    const double S1 = -1.66666666666666324348e-01, S2 = 8.33333333332248946124e-03, S3 = -1.98412698298579493134e-04;
    const double S4 = 2.75573137070700676789e-06, S5 = -2.50507602534068634195e-08, S6 = 1.58969099521155010221e-10;
    const double C1 = 4.16666666666666019037e-02, C2 = -1.38888888888741095749e-03, C3 = 2.48015872894767294178e-05;
    const double C4 = -2.75573143513906633035e-07, C5 = 2.08757232129817482790e-09, C6 = -1.13596475577881948265e-11;
    const double TINY = 1.4901161193847656e-8;
    double n = x > FRAC_PI_4 ? 1.0 : (x < -FRAC_PI_4 ? -1.0 : 0.0);
    double hi = x - n * FRAC_PI_2;
    double lo = n * PIO2_TAIL;
    double y0 = hi - lo;
    double y1 = (hi - y0) - lo;
    double z = y0 * y0;
    double w = z * z;
    double r = S2 + z * (S3 + z * S4) + z * w * (S5 + z * S6);
    double v = z * y0;
    double sin_no_tail = y0 + v * (S1 + z * r);
    double sin_tail = y0 - ((z * (0.5 * y1 - v * r) - y1) - v * S1);
    double rc = z * (C1 + z * (C2 + z * C3)) + w * w * (C4 + z * (C5 + z * C6));
    double hz = 0.5 * z;
    double wc = 1.0 - hz;
    double cos_y = wc + (((1.0 - wc) - hz) + (z * rc - y0 * y1));
    double sin_small = DC_FABS(y0) < TINY ? y0 : sin_no_tail;
    *s_out = n == 0.0 ? sin_small : (n > 0.0 ? cos_y : -cos_y);
    *c_out = n == 0.0 ? cos_y : (n > 0.0 ? -sin_tail : sin_tail);
}

/* The concentric map of [0,1)² onto the unit disk (render::sampling::concentric_disk). */
DC_FN void dc_concentric_disk(double u, double v, double *x, double *y) {
    const double FRAC_PI_2 = 1.5707963267948966, FRAC_PI_4 = 0.7853981633974483;
    double a = 2.0 * u - 1.0, b = 2.0 * v - 1.0;
    int first = DC_FABS(a) > DC_FABS(b);
    double r = first ? a : b, num = first ? b : a, den = first ? a : b;
    double t = FRAC_PI_4 * (num / den);
    double phi = first ? t : FRAC_PI_2 - t;
    double s, c;
    dc_sin_cos(phi, &s, &c);
    int centre = a == 0.0 && b == 0.0;
    *x = centre ? 0.0 : r * c;
    *y = centre ? 0.0 : r * s;
}

#define DC_SAMPLING_STRATIFIED 0u
#define DC_SAMPLING_INDEPENDENT 1u

/* The sampler's constants: N rays per pixel-plane on an a × b strata grid (RaySampler::new). */
typedef struct {
    dc_u64 seed;
    dc_u32 rays;
    dc_u32 mode;   /* DC_SAMPLING_* */
    dc_u32 grid_a; /* a: the largest divisor of N not above √N */
    dc_u32 grid_b; /* N / a */
} dc_sampler;

/* The pixel-area cell π(k) of stratified ray k: position k of the Fisher–Yates shuffle of 0..N−1 that
 * RaySampler::prepare applies (for k = N−1 down to 1: swap(k, j_k), j_k = mix64(base ^ k) mod (k+1)),
 * found by following position k back through the swaps, last swap first. */
DC_FN dc_u32 dc_area_cell(dc_u64 pk, dc_u32 n, dc_u32 k) {
    dc_u64 base = dc_mix64(pk ^ 0xFFFFFFFFFFFFFFFFull);
    dc_u32 pos = k;
    for (dc_u32 s = 1; s < n; ++s) {
        dc_u32 j = (dc_u32)(dc_mix64(base ^ (dc_u64)s) % ((dc_u64)s + 1));
        if (pos == s)
            pos = j;
        else if (pos == j)
            pos = s;
    }
    return pos;
}

/* Ray k's sample of (plane, pixel): out = [px, py] in the unit disk, [sx, sy] in the pixel, [0, 1)². */
DC_FN void dc_sample_ray(const dc_sampler *sm, dc_u64 plane, dc_u64 pixel, dc_u32 k, double out[4]) {
    dc_u64 pk = dc_pixel_key(sm->seed, plane, pixel);
    dc_u64 h1, h2, h3, h4;
    double pi = 0.0, pj = 0.0, ai = 0.0, aj = 0.0, na = 1.0, nb = 1.0;
    if (sm->mode == DC_SAMPLING_INDEPENDENT) {
        dc_u64 key = pk ^ (2ull * (dc_u64)k);
        h1 = dc_mix64(key);
        h2 = dc_mix64(h1);
        h3 = dc_mix64(key ^ 1ull);
    } else {
        dc_u64 key = pk ^ (dc_u64)k;
        dc_u32 a = sm->grid_a;
        dc_u32 cell = dc_area_cell(pk, sm->rays, k);
        h1 = dc_mix64(key);
        h2 = dc_mix64(h1);
        h3 = dc_mix64(h2);
        pi = (double)(k % a);
        pj = (double)(k / a);
        ai = (double)(cell % a);
        aj = (double)(cell / a);
        na = (double)a;
        nb = (double)sm->grid_b;
    }
    h4 = dc_mix64(h3);
    dc_concentric_disk((pi + dc_unit(h1)) / na, (pj + dc_unit(h2)) / nb, &out[0], &out[1]);
    out[2] = (ai + dc_unit(h3)) / na;
    out[3] = (aj + dc_unit(h4)) / nb;
}

/* The paraxial entrance-pupil aim of rays::PupilAim (ray aiming off). */
typedef struct {
    double scale;       /* pupil radius (or 1 when telecentric), mm per normalised pupil unit */
    double sin_marginal;
    double magnification_sign;
    double distance_mm; /* object plane → entrance pupil */
    dc_u32 telecentric;
    dc_u32 at_infinity; /* the object is at infinity: fields are angles (rad), the rays of a field parallel */
    /* Ray aiming (OpticStudio's RAIM; rays::aimed_ray): 0 off (the paraxial entrance pupil), 1 on — paraxial or
     * real, which differ only in stop_radius_mm (SequentialSystem::aim_stop_radius_mm: the paraxial stop radius,
     * or the real marginal ray's height at the stop). aim_steps: the path steps before the stop, their
     * apertures opened (StopProbe::open_path), followed in the launch's aim_path by the stop's probe. */
    double stop_radius_mm;
    dc_u32 aiming;
    dc_u32 aim_steps;
} dc_aim;

/* PupilAim::through: the unit direction from object point (x, y, 0) through the entrance-pupil plane point (u, v)
 * (telecentric: direction sines (u, v)·sin θ). */
DC_FN dc_v3 dc_aim_through(const dc_aim *aim, double x, double y, double u, double v) {
    if (aim->telecentric) {
        double s = aim->sin_marginal;
        double sx = u * s, sy = v * s;
        double zz = 1.0 - sx * sx - sy * sy;
        return dc_v3_make(sx, sy, DC_SQRT(dc_max(zz, 0.0)));
    }
    double m = aim->magnification_sign;
    double wx = m * u - x, wy = m * v - y, wz = aim->distance_mm - 0.0;
    if (aim->distance_mm < 0.0) {
        wx = -wx;
        wy = -wy;
        wz = -wz;
    }
    double inv = 1.0 / DC_SQRT(wx * wx + wy * wy + wz * wz);
    return dc_v3_make(wx * inv, wy * inv, wz * inv);
}

/* PupilAim::direction: the unit direction from object point (x, y, 0) through normalised pupil (px, py). */
DC_FN dc_v3 dc_aim_direction(const dc_aim *aim, double x, double y, double px, double py) {
    return dc_aim_through(aim, x, y, px * aim->scale, py * aim->scale);
}

/* PupilAim::parallel_ray after its two tan: the ray of direction ∝ (tx, ty, 1) through the entrance-pupil plane
 * point (u, v) mm (ray aiming moves (u, v) and keeps the field's tan θ, computed once: tan is a function, so the
 * bits are those of parallel_ray's own call). */
DC_FN void dc_parallel_ray_tan(const dc_aim *aim, double tx, double ty, double u, double v, dc_v3 *o, dc_v3 *d) {
    double m = aim->magnification_sign;
    double z = aim->distance_mm;
    *o = dc_v3_make(m * u - tx * z, m * v - ty * z, 0.0);
    double inv = 1.0 / DC_SQRT(tx * tx + ty * ty + 1.0);
    *d = dc_v3_make(tx * inv, ty * inv, inv);
}

/* PupilAim::parallel_ray (object at infinity): the ray of field angles (θx, θy) rad through the entrance-pupil
 * point (u, v) = (px, py)·scale, direction ∝ (tan θx, tan θy, 1), starting where it crosses the object frame's
 * z = 0 plane (surface 1's vertex). tan: DC_TAN (dc_common.h: the platform's libm on the host, bit for bit the
 * CPU's; CUDA's within 2 ulp on the device). */
DC_FN void dc_parallel_ray(const dc_aim *aim, double theta_x, double theta_y, double px, double py, dc_v3 *o, dc_v3 *d) {
    double r = aim->scale;
    double u = px * r, v = py * r;
    double tx = DC_TAN(theta_x), ty = DC_TAN(theta_y);
    dc_parallel_ray_tan(aim, tx, ty, u, v, o, d);
}

/* The scene geometry and the detector of a render (for an object at infinity the scene pitch is an angle,
 * rad: render::engine::scene_pitch_for). */
typedef struct {
    double scene_pitch_mm;
    double detector_x_left_mm, detector_y_top_mm, detector_pitch_mm;
    dc_u32 scene_height, scene_width;
} dc_scene;

/* MappingCube::scene_xy: the centre of scene pixel (row, col), mm (x right, y up, origin at the centre). */
DC_FN void dc_scene_xy(const dc_scene *sc, dc_u32 row, dc_u32 col, double *x, double *y) {
    *x = ((double)col + 0.5 - (double)sc->scene_width / 2.0) * sc->scene_pitch_mm;
    *y = ((double)sc->scene_height / 2.0 - (double)row - 0.5) * sc->scene_pitch_mm;
}

/* PlaneContext::ray's field point of sample s of scene pixel (row, col): the pixel centre jittered by s[2], s[3]. */
DC_FN void dc_field_point(const dc_scene *sc, dc_u32 row, dc_u32 col, const double s[4], double *fx, double *fy) {
    double cx, cy;
    dc_scene_xy(sc, row, col, &cx, &cy);
    *fx = cx + (s[2] - 0.5) * sc->scene_pitch_mm;
    *fy = cy - (s[3] - 0.5) * sc->scene_pitch_mm;
}

/* The object ray of sample s of scene pixel (row, col) (PlaneContext::ray, then the trace's own
 * normalisation): the field point (fx, fy) jittered in the pixel; on a finite object plane the origin
 * (fx, fy, 0) and the unit aim direction (render::sampling::object_rays); at infinity (fx, fy) are field angles
 * (rad) and the ray is dc_parallel_ray's (rays::object_ray). */
DC_FN void dc_object_ray(const dc_scene *sc, const dc_aim *aim, dc_u32 row, dc_u32 col, const double s[4], dc_v3 *o, dc_v3 *d) {
    double fx, fy;
    dc_field_point(sc, row, col, s, &fx, &fy);
    if (aim->at_infinity) {
        dc_parallel_ray(aim, fx, fy, s[0], s[1], o, d);
        return;
    }
    *o = dc_v3_make(fx, fy, 0.0);
    *d = dc_aim_direction(aim, fx, fy, s[0], s[1]);
}

/* Detector::to_pixel: continuous (column, row) of image point (x, y) mm; pixel (i, j)'s centre is (j, i). */
DC_FN void dc_to_pixel(const dc_scene *sc, double x, double y, double *u, double *v) {
    *u = (x - sc->detector_x_left_mm) / sc->detector_pitch_mm - 0.5;
    *v = (sc->detector_y_top_mm - y) / sc->detector_pitch_mm - 0.5;
}

#endif /* DC_SAMPLE_H */
