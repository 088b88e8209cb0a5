/* Small C++ shim over the INSTALLED Embree 4 headers, compiled by build.rs with the same headers as the
   bindings:
   - Embree's rtcInit* helpers are `static inline` (no symbol in libembree4): exported here so the Rust
     side runs exactly the installed headers' initialisation;
   - user-geometry callbacks receive ray packets of runtime width N (RTCRayHitN), whose accessors
     (RTCRayN_org_x, RTCHitN_instID, ...) exist only as C++ inline functions: the two functions below use
     them, so the Rust callback never hard-codes the packet layout. */
#include <embree4/rtcore.h>

extern "C" {

void diffcassi_rtcInitRayQueryContext(RTCRayQueryContext* context) { rtcInitRayQueryContext(context); }
void diffcassi_rtcInitIntersectArguments(RTCIntersectArguments* args) { rtcInitIntersectArguments(args); }

/* Lane i of the callback's packet: out = {org_x, org_y, org_z, dir_x, dir_y, dir_z, tnear, tfar}, *id = the
   ray's ID (which the tracer sets to the lane of its own packet); returns the ray's mask. */
unsigned int diffcassi_user_ray(const RTCIntersectFunctionNArguments* args, unsigned int i, float* out, unsigned int* id) {
    RTCRayN* ray = RTCRayHitN_RayN(args->rayhit, args->N);
    const unsigned int N = args->N;
    out[0] = RTCRayN_org_x(ray, N, i);
    out[1] = RTCRayN_org_y(ray, N, i);
    out[2] = RTCRayN_org_z(ray, N, i);
    out[3] = RTCRayN_dir_x(ray, N, i);
    out[4] = RTCRayN_dir_y(ray, N, i);
    out[5] = RTCRayN_dir_z(ray, N, i);
    out[6] = RTCRayN_tnear(ray, N, i);
    out[7] = RTCRayN_tfar(ray, N, i);
    *id = RTCRayN_id(ray, N, i);
    return RTCRayN_mask(ray, N, i);
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

}
