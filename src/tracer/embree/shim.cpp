/* Small C++ shim over the INSTALLED Embree 4 headers, compiled by build.rs with the same headers as the
   bindings:
   - Embree's rtcInit* helpers are `static inline` (no symbol in libembree4): exported here so the Rust
     side runs exactly the installed headers' initialisation;
   - user-geometry callbacks receive ray packets of runtime width N (RTCRayHitN), whose accessors
     (RTCRayN_org_x, RTCHitN_instID, ...) exist only as C++ inline functions: the two functions below use
     them (one call reads all the lanes a callback concerns, one commits a hit), so the Rust callback never
     hard-codes the packet layout;
   - the floor benchmark's oracle callback (end of file), which reports recorded hits and solves nothing. */
#include <embree4/rtcore.h>

extern "C" {

void diffcassi_rtcInitRayQueryContext(RTCRayQueryContext* context) { rtcInitRayQueryContext(context); }
void diffcassi_rtcInitIntersectArguments(RTCIntersectArguments* args) { rtcInitIntersectArguments(args); }

/* The lanes [start, start + 16) ∩ [0, N) of the callback's packet that are valid and whose ray mask shares a
   bit with geom_mask, compacted (one call per callback instead of one per lane): lane[k] = the packet lane,
   org/dir[3k..3k+3], tnear/tfar[k], id[k] = the ray ID (the tracer's own lane). Returns the count. */
unsigned int diffcassi_user_rays16(const RTCIntersectFunctionNArguments* args, unsigned int start, unsigned int geom_mask,
                                   unsigned int* lane, float* org, float* dir, float* tnear, float* tfar, unsigned int* id) {
    RTCRayN* ray = RTCRayHitN_RayN(args->rayhit, args->N);
    const unsigned int N = args->N;
    const unsigned int end = N < start + 16 ? N : start + 16;
    unsigned int k = 0;
    for (unsigned int i = start; i < end; i++) {
        if (args->valid[i] == 0 || (RTCRayN_mask(ray, N, i) & geom_mask) == 0) continue;
        lane[k] = i;
        org[3 * k] = RTCRayN_org_x(ray, N, i);
        org[3 * k + 1] = RTCRayN_org_y(ray, N, i);
        org[3 * k + 2] = RTCRayN_org_z(ray, N, i);
        dir[3 * k] = RTCRayN_dir_x(ray, N, i);
        dir[3 * k + 1] = RTCRayN_dir_y(ray, N, i);
        dir[3 * k + 2] = RTCRayN_dir_z(ray, N, i);
        tnear[k] = RTCRayN_tnear(ray, N, i);
        tfar[k] = RTCRayN_tfar(ray, N, i);
        id[k] = RTCRayN_id(ray, N, i);
        k++;
    }
    return k;
}

/* Record a hit at distance t on lane i (no filter functions are used, so the hit is committed directly):
   tfar, geometric normal, u = v = 0, prim/geom IDs, and the instance IDs of the query context. */
void diffcassi_user_report_hit(const RTCIntersectFunctionNArguments* args, unsigned int i, float t, float ng_x, float ng_y, float ng_z) {
    const unsigned int N = args->N;
    RTCRayN* ray = RTCRayHitN_RayN(args->rayhit, N);
    RTCHitN* hit = RTCRayHitN_HitN(args->rayhit, N);
    RTCRayN_tfar(ray, N, i) = t;
    RTCHitN_Ng_x(hit, N, i) = ng_x;
    RTCHitN_Ng_y(hit, N, i) = ng_y;
    RTCHitN_Ng_z(hit, N, i) = ng_z;
    RTCHitN_u(hit, N, i) = 0.0f;
    RTCHitN_v(hit, N, i) = 0.0f;
    RTCHitN_primID(hit, N, i) = args->primID;
    RTCHitN_geomID(hit, N, i) = args->geomID;
    for (unsigned int l = 0; l < RTC_MAX_INSTANCE_LEVEL_COUNT; l++) {
        RTCHitN_instID(hit, N, i, l) = args->context->instID[l];
#if defined(RTC_GEOMETRY_INSTANCE_ARRAY)
        RTCHitN_instPrimID(hit, N, i, l) = args->context->instPrimID[l];
#endif
    }
}

/* The oracle of the floor benchmark (docs/nonsequential.md, "Fourth pass"): Embree's query context extended
   with, per ray ID (the caller's lane), the geometry the lane is to hit and its distance, as the tracer's
   walk recorded them (OracleContext in wrapper.rs, same layout). The callback solves nothing: on every
   valid lane whose answer is this geometry, within [tnear, tfar], it commits that hit. The ray masks need no
   test: a lane's recorded geometry is never the one its mask excludes. */
struct DiffcassiOracleContext {
    RTCRayQueryContext base;
    const unsigned int* geom_id;
    const float* t;
};

void diffcassi_oracle_intersect(const RTCIntersectFunctionNArguments* args) {
    const DiffcassiOracleContext* ctx = (const DiffcassiOracleContext*)args->context;
    if (ctx->geom_id == 0 || ctx->t == 0) return;
    const unsigned int N = args->N;
    RTCRayN* ray = RTCRayHitN_RayN(args->rayhit, N);
    for (unsigned int i = 0; i < N; i++) {
        if (args->valid[i] == 0) continue;
        const unsigned int id = RTCRayN_id(ray, N, i);
        if (id >= 16 || ctx->geom_id[id] != args->geomID) continue;
        const float t = ctx->t[id];
        if (t < RTCRayN_tnear(ray, N, i) || t > RTCRayN_tfar(ray, N, i)) continue;
        diffcassi_user_report_hit(args, i, t, 0.0f, 0.0f, 0.0f);
    }
}

}
