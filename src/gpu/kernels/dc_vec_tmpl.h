/* diffcassi GPU kernels: three-vectors of one real type, a template included twice by dc_common.h (no include
 * guard): DC_P = f64 gives dc_v3, dc_add, ... (glam's DVec3), DC_P = f32 gives dc_v3_f32, dc_add_f32, ... (the
 * f32 lanes' V3 of tracer::simd::lanes). The arithmetic is glam's, component-wise and left to right, in both.
 */
typedef struct {
    DC_REAL x, y, z;
} DC_V3;

DC_FN DC_V3 DC_T(dc_v3_make)(DC_REAL x, DC_REAL y, DC_REAL z) {
    DC_V3 r;
    r.x = x;
    r.y = y;
    r.z = z;
    return r;
}
DC_FN DC_V3 DC_T(dc_add)(DC_V3 a, DC_V3 b) { return DC_T(dc_v3_make)(a.x + b.x, a.y + b.y, a.z + b.z); }
DC_FN DC_V3 DC_T(dc_sub)(DC_V3 a, DC_V3 b) { return DC_T(dc_v3_make)(a.x - b.x, a.y - b.y, a.z - b.z); }
DC_FN DC_V3 DC_T(dc_scale)(DC_V3 a, DC_REAL s) { return DC_T(dc_v3_make)(a.x * s, a.y * s, a.z * s); }
DC_FN DC_V3 DC_T(dc_neg)(DC_V3 a) { return DC_T(dc_v3_make)(-a.x, -a.y, -a.z); }
DC_FN DC_V3 DC_T(dc_div)(DC_V3 a, DC_REAL s) { return DC_T(dc_v3_make)(a.x / s, a.y / s, a.z / s); }
/* glam: (x·x) + (y·y) + (z·z), left to right. */
DC_FN DC_REAL DC_T(dc_dot)(DC_V3 a, DC_V3 b) { return (a.x * b.x) + (a.y * b.y) + (a.z * b.z); }
DC_FN int DC_T(dc_v3_finite)(DC_V3 a) { return isfinite(a.x) && isfinite(a.y) && isfinite(a.z); }
/* glam's normalize: v · (1 / √(v·v)). */
DC_FN DC_V3 DC_T(dc_normalize)(DC_V3 a) { return DC_T(dc_scale)(a, DC_R(1.0) / DC_RSQRT(DC_T(dc_dot)(a, a))); }
/* M·v = x_axis·v.x + y_axis·v.y + z_axis·v.z with M's f64 entries rounded to DC_REAL (tracer::simd::block::rotate). */
DC_FN DC_V3 DC_T(dc_m3_mul)(const dc_m3 *m, DC_V3 v) {
    DC_V3 r = DC_T(dc_v3_make)(DC_R(m->c[0]) * v.x, DC_R(m->c[1]) * v.x, DC_R(m->c[2]) * v.x);
    r = DC_T(dc_add)(r, DC_T(dc_v3_make)(DC_R(m->c[3]) * v.y, DC_R(m->c[4]) * v.y, DC_R(m->c[5]) * v.y));
    r = DC_T(dc_add)(r, DC_T(dc_v3_make)(DC_R(m->c[6]) * v.z, DC_R(m->c[7]) * v.z, DC_R(m->c[8]) * v.z));
    return r;
}
