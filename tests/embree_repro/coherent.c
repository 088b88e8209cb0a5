/* Minimal check of RTC_RAY_QUERY_FLAG_COHERENT on rtcIntersect16 against rtcIntersect1 (Embree 4.3).
   Scene: two large parallel quads (2 triangles each), geometry 0 in z = 0 (mask 1), geometry 1 in z = 5
   (mask 2). A 16-lane packet starts at z = -1 heading +z (slightly spread). Variants:
     A: every ray mask = all bits            -> every lane hits geometry 0 at t ~ 1
     B: every ray mask excludes geometry 0   -> every lane hits geometry 1 at t ~ 6
     C: lanes alternate A/B masks            -> even lanes geometry 0, odd lanes geometry 1
     D: like C, half the lanes invalid
   For each variant the packet is traced incoherent and coherent, and each lane compared with
   rtcIntersect1 of the same ray (then E, F, G, H on curved meshes, below). Prints mismatches; exit status 1 if any.
   H reproduces the tracer's lost hits: one lane whose direction has a component of -8.7e-19 makes coherent
   rtcIntersect16 miss on 14 of the 16 lanes (Embree 4.3.3, AVX-512); the same packet with -0.0 there, or
   traced incoherent, loses none. So this program exits 1 on Embree 4.3.3 (see README.md).
   FTZ_DAZ=1 in the environment sets MXCSR flush-to-zero and denormals-are-zero first, as the tracer does. */
#include <embree4/rtcore.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <math.h>
#include <xmmintrin.h>

static unsigned quad(RTCDevice d, RTCScene s, float z, unsigned mask) {
    RTCGeometry g = rtcNewGeometry(d, RTC_GEOMETRY_TYPE_TRIANGLE);
    float* v = (float*)rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), 4);
    unsigned* i = (unsigned*)rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), 2);
    float vv[12] = {-50, -50, z, 50, -50, z, 50, 50, z, -50, 50, z};
    unsigned ii[6] = {0, 1, 2, 0, 2, 3};
    memcpy(v, vv, sizeof vv);
    memcpy(i, ii, sizeof ii);
    rtcSetGeometryMask(g, mask);
    rtcCommitGeometry(g);
    unsigned id = rtcAttachGeometry(s, g);
    rtcReleaseGeometry(g);
    return id;
}

static void setup(struct RTCRayHit16* rh, int* valid, int variant, int lane_count) {
    memset(rh, 0, sizeof *rh);
    for (int k = 0; k < 16; k++) {
        rh->ray.org_x[k] = -3.0f + 0.4f * k;
        rh->ray.org_y[k] = 1.0f - 0.1f * k;
        rh->ray.org_z[k] = -1.0f;
        rh->ray.dir_x[k] = 0.01f * (k - 8);
        rh->ray.dir_y[k] = 0.005f * k;
        rh->ray.dir_z[k] = 1.0f;
        rh->ray.tnear[k] = 0.0f;
        rh->ray.tfar[k] = INFINITY;
        unsigned all = 0xffffffffu, skip0 = ~1u;
        rh->ray.mask[k] = variant == 0 ? all : variant == 1 ? skip0 : (k % 2 ? skip0 : all);
        rh->hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
        rh->hit.primID[k] = RTC_INVALID_GEOMETRY_ID;
        rh->hit.instID[0][k] = RTC_INVALID_GEOMETRY_ID;
        valid[k] = (variant == 3 && k % 4 >= 2) ? 0 : -1;
        if (!valid[k]) rh->ray.tfar[k] = -1.0f;
        (void)lane_count;
    }
}

/* A spherical cap z = z0 + sag(r), radius of curvature R, clear radius a, as a polar triangle mesh. */
static void cap(RTCDevice d, RTCScene s, float z0, float R, float a, unsigned mask) {
    enum { NR = 24, NA = 64 };
    RTCGeometry g = rtcNewGeometry(d, RTC_GEOMETRY_TYPE_TRIANGLE);
    float* v = (float*)rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), 1 + NR * NA);
    unsigned* t = (unsigned*)rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), NA + 2 * NA * (NR - 1));
    v[0] = 0; v[1] = 0; v[2] = z0;
    for (int i = 0; i < NR; i++)
        for (int j = 0; j < NA; j++) {
            float r = a * (i + 1) / NR, phi = 6.2831853f * j / NA;
            float sag = R - copysignf(sqrtf(R * R - r * r), R);
            float* p = v + 3 * (1 + i * NA + j);
            p[0] = r * cosf(phi); p[1] = r * sinf(phi); p[2] = z0 + sag;
        }
    int n = 0;
    for (int j = 0; j < NA; j++) { t[n++] = 0; t[n++] = 1 + j; t[n++] = 1 + (j + 1) % NA; }
    for (int i = 0; i + 1 < NR; i++)
        for (int j = 0; j < NA; j++) {
            unsigned a0 = 1 + i * NA + j, a1 = 1 + i * NA + (j + 1) % NA, b0 = a0 + NA, b1 = a1 + NA;
            t[n++] = a0; t[n++] = b0; t[n++] = b1;
            t[n++] = a0; t[n++] = b1; t[n++] = a1;
        }
    rtcSetGeometryMask(g, mask);
    rtcCommitGeometry(g);
    rtcAttachGeometry(s, g);
    rtcReleaseGeometry(g);
}

/* Variant E/F: a diverging on-axis bundle (all direction octants) from the origin to two caps; F starts
   every ray on cap 1 (where E's rays met it) with cap 1 masked out, as a non-sequential tracer does after a
   refraction. */
static int bundle(RTCScene s, int start_on_cap, int coherent) {
    struct RTCRayHit16 rh __attribute__((aligned(64)));
    int valid[16] __attribute__((aligned(64)));
    memset(&rh, 0, sizeof rh);
    for (int k = 0; k < 16; k++) {
        float th = k == 0 ? 0.0f : 0.3f, phi = 6.2831853f * k / 15.0f;
        rh.ray.dir_x[k] = sinf(th) * cosf(phi); rh.ray.dir_y[k] = sinf(th) * sinf(phi); rh.ray.dir_z[k] = cosf(th);
        rh.ray.tfar[k] = INFINITY;
        rh.ray.mask[k] = 0xffffffffu;
        rh.hit.geomID[k] = rh.hit.primID[k] = rh.hit.instID[0][k] = RTC_INVALID_GEOMETRY_ID;
        valid[k] = -1;
    }
    if (start_on_cap) {
        struct RTCRayHit16 first = rh;
        struct RTCIntersectArguments a0;
        rtcInitIntersectArguments(&a0);
        rtcIntersect16(valid, s, &first, &a0);
        for (int k = 0; k < 16; k++) {
            rh.ray.org_x[k] = first.ray.tfar[k] * rh.ray.dir_x[k];
            rh.ray.org_y[k] = first.ray.tfar[k] * rh.ray.dir_y[k];
            rh.ray.org_z[k] = first.ray.tfar[k] * rh.ray.dir_z[k];
            rh.ray.mask[k] = ~1u;
        }
    }
    struct RTCRayHit16 in = rh;
    struct RTCIntersectArguments args;
    rtcInitIntersectArguments(&args);
    args.flags = coherent ? RTC_RAY_QUERY_FLAG_COHERENT : RTC_RAY_QUERY_FLAG_INCOHERENT;
    rtcIntersect16(valid, s, &rh, &args);
    int miss = 0;
    for (int k = 0; k < 16; k++) {
        struct RTCRayHit r1;
        memset(&r1, 0, sizeof r1);
        r1.ray.org_x = in.ray.org_x[k]; r1.ray.org_y = in.ray.org_y[k]; r1.ray.org_z = in.ray.org_z[k];
        r1.ray.dir_x = in.ray.dir_x[k]; r1.ray.dir_y = in.ray.dir_y[k]; r1.ray.dir_z = in.ray.dir_z[k];
        r1.ray.tnear = 0.0f; r1.ray.tfar = INFINITY; r1.ray.mask = in.ray.mask[k];
        r1.hit.geomID = r1.hit.primID = r1.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
        rtcIntersect1(s, &r1, NULL);
        if (r1.hit.geomID != rh.hit.geomID[k] || fabsf(r1.ray.tfar - rh.ray.tfar[k]) > 1e-4f) {
            miss++;
            printf("  %s, %s: lane %d rtcIntersect16 geom %d t %g, rtcIntersect1 geom %d t %g\n", start_on_cap ? "F" : "E",
                   coherent ? "coherent" : "incoherent", k, (int)rh.hit.geomID[k], rh.ray.tfar[k], (int)r1.hit.geomID, r1.ray.tfar);
        }
    }
    printf("%-28s %-10s: %d lane(s) differ from rtcIntersect1\n", start_on_cap ? "F bundle from cap 1" : "E diverging bundle", coherent ? "coherent" : "incoherent", miss);
    return miss;
}

/* Variant G: one direction octant (all components > 0), but origins spread along the axis (some lanes in
   front of cap 1, some between the caps, as a packet holds rays at different stages of a walk) and the
   x/y direction components spread over two orders of magnitude. */
static int spread(RTCScene s, int coherent) {
    struct RTCRayHit16 rh __attribute__((aligned(64)));
    int valid[16] __attribute__((aligned(64)));
    memset(&rh, 0, sizeof rh);
    for (int k = 0; k < 16; k++) {
        float sx = (k % 4 == 0) ? 0.002f : 0.05f * (k % 4), sy = (k % 3 == 0) ? 0.001f : 0.04f * (k % 3);
        float n = sqrtf(sx * sx + sy * sy + 1.0f);
        rh.ray.dir_x[k] = sx / n; rh.ray.dir_y[k] = sy / n; rh.ray.dir_z[k] = 1.0f / n;
        rh.ray.org_x[k] = -4.0f + 0.5f * k; rh.ray.org_y[k] = -3.0f + 0.3f * k;
        rh.ray.org_z[k] = (k % 2) ? 13.0f : -1.0f;  /* odd lanes start between the caps */
        rh.ray.tfar[k] = INFINITY;
        rh.ray.mask[k] = (k % 2) ? ~1u : 0xffffffffu;
        rh.hit.geomID[k] = rh.hit.primID[k] = rh.hit.instID[0][k] = RTC_INVALID_GEOMETRY_ID;
        valid[k] = -1;
    }
    struct RTCRayHit16 in = rh;
    struct RTCIntersectArguments args;
    rtcInitIntersectArguments(&args);
    args.flags = coherent ? RTC_RAY_QUERY_FLAG_COHERENT : RTC_RAY_QUERY_FLAG_INCOHERENT;
    rtcIntersect16(valid, s, &rh, &args);
    int miss = 0;
    for (int k = 0; k < 16; k++) {
        struct RTCRayHit r1;
        memset(&r1, 0, sizeof r1);
        r1.ray.org_x = in.ray.org_x[k]; r1.ray.org_y = in.ray.org_y[k]; r1.ray.org_z = in.ray.org_z[k];
        r1.ray.dir_x = in.ray.dir_x[k]; r1.ray.dir_y = in.ray.dir_y[k]; r1.ray.dir_z = in.ray.dir_z[k];
        r1.ray.tnear = 0.0f; r1.ray.tfar = INFINITY; r1.ray.mask = in.ray.mask[k];
        r1.hit.geomID = r1.hit.primID = r1.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
        rtcIntersect1(s, &r1, NULL);
        if (r1.hit.geomID != rh.hit.geomID[k] || fabsf(r1.ray.tfar - rh.ray.tfar[k]) > 1e-4f) {
            miss++;
            printf("  G, %s: lane %d rtcIntersect16 geom %d t %g, rtcIntersect1 geom %d t %g\n", coherent ? "coherent" : "incoherent", k,
                   (int)rh.hit.geomID[k], rh.ray.tfar[k], (int)r1.hit.geomID, r1.ray.tfar);
        }
    }
    printf("%-28s %-10s: %d lane(s) differ from rtcIntersect1\n", "G spread origins, 1 octant", coherent ? "coherent" : "incoherent", miss);
    return miss;
}

/* H: one direction octant (x, y < 0), origins spread across the caps' aperture at z = -1, all masks set;
   lane 0's y direction is `tiny` (-8.7e-19: the f64 rounding residue of a ray in a symmetry plane, as the
   tracer's restarted rays carry; or exactly -0.0 as a control). Every lane is compared with rtcIntersect1. */
static int tiny_lane(RTCScene s, int coherent, float tiny) {
    struct RTCRayHit16 rh __attribute__((aligned(64)));
    int valid[16] __attribute__((aligned(64)));
    memset(&rh, 0, sizeof rh);
    for (int k = 0; k < 16; k++) {
        float sx = -0.01f - 0.003f * k, sy = k == 0 ? tiny : -0.01f - 0.002f * (k % 5);
        float n = sqrtf(sx * sx + sy * sy + 1.0f);
        rh.ray.dir_x[k] = sx / n; rh.ray.dir_y[k] = k == 0 ? tiny : sy / n; rh.ray.dir_z[k] = 1.0f / n;
        rh.ray.org_x[k] = 6.0f - 0.7f * k; rh.ray.org_y[k] = 5.0f - 0.6f * k; rh.ray.org_z[k] = -1.0f;
        rh.ray.tfar[k] = INFINITY;
        rh.ray.mask[k] = 0xffffffffu;
        rh.hit.geomID[k] = rh.hit.primID[k] = rh.hit.instID[0][k] = RTC_INVALID_GEOMETRY_ID;
        valid[k] = -1;
    }
    struct RTCRayHit16 in = rh;
    struct RTCIntersectArguments args;
    rtcInitIntersectArguments(&args);
    args.flags = coherent ? RTC_RAY_QUERY_FLAG_COHERENT : RTC_RAY_QUERY_FLAG_INCOHERENT;
    rtcIntersect16(valid, s, &rh, &args);
    int miss = 0;
    for (int k = 0; k < 16; k++) {
        struct RTCRayHit r1;
        memset(&r1, 0, sizeof r1);
        r1.ray.org_x = in.ray.org_x[k]; r1.ray.org_y = in.ray.org_y[k]; r1.ray.org_z = in.ray.org_z[k];
        r1.ray.dir_x = in.ray.dir_x[k]; r1.ray.dir_y = in.ray.dir_y[k]; r1.ray.dir_z = in.ray.dir_z[k];
        r1.ray.tnear = 0.0f; r1.ray.tfar = INFINITY; r1.ray.mask = in.ray.mask[k];
        r1.hit.geomID = r1.hit.primID = r1.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
        rtcIntersect1(s, &r1, NULL);
        if (r1.hit.geomID != rh.hit.geomID[k] || fabsf(r1.ray.tfar - rh.ray.tfar[k]) > 1e-4f) {
            miss++;
            printf("  H, %s, dy0 = %g: lane %d rtcIntersect16 geom %d t %g, rtcIntersect1 geom %d t %g\n", coherent ? "coherent" : "incoherent", tiny, k,
                   (int)rh.hit.geomID[k], rh.ray.tfar[k], (int)r1.hit.geomID, r1.ray.tfar);
        }
    }
    printf("%-28s %-10s: %d lane(s) differ from rtcIntersect1\n", tiny == 0.0f ? "H control: lane 0 dy = -0" : "H lane 0 dy = -8.7e-19", coherent ? "coherent" : "incoherent", miss);
    return miss;
}

int main(void) {
    if (getenv("FTZ_DAZ")) _mm_setcsr(_mm_getcsr() | 0x8040); /* as the tracer runs (FTZ + DAZ) */
    RTCDevice d = rtcNewDevice(NULL);
    RTCScene s = rtcNewScene(d);
    quad(d, s, 0.0f, 1u);
    quad(d, s, 5.0f, 2u);
    rtcCommitScene(s);
    printf("Embree %d.%d.%d\n", RTC_VERSION_MAJOR, RTC_VERSION_MINOR, RTC_VERSION_PATCH);
    int bad = 0;
    const char* names[4] = {"A all masks", "B skip geometry 0", "C alternating masks", "D alternating, half invalid"};
    for (int variant = 0; variant < 4; variant++) {
        for (int coherent = 0; coherent < 2; coherent++) {
            struct RTCRayHit16 rh __attribute__((aligned(64)));
            int valid[16] __attribute__((aligned(64)));
            setup(&rh, valid, variant, 16);
            struct RTCRayHit16 in = rh;
            struct RTCIntersectArguments args;
            rtcInitIntersectArguments(&args);
            args.flags = coherent ? RTC_RAY_QUERY_FLAG_COHERENT : RTC_RAY_QUERY_FLAG_INCOHERENT;
            rtcIntersect16(valid, s, &rh, &args);
            int miss = 0;
            for (int k = 0; k < 16; k++) {
                if (!valid[k]) continue;
                struct RTCRayHit r1;
                memset(&r1, 0, sizeof r1);
                r1.ray.org_x = in.ray.org_x[k]; r1.ray.org_y = in.ray.org_y[k]; r1.ray.org_z = in.ray.org_z[k];
                r1.ray.dir_x = in.ray.dir_x[k]; r1.ray.dir_y = in.ray.dir_y[k]; r1.ray.dir_z = in.ray.dir_z[k];
                r1.ray.tnear = in.ray.tnear[k]; r1.ray.tfar = in.ray.tfar[k]; r1.ray.mask = in.ray.mask[k];
                r1.hit.geomID = r1.hit.primID = r1.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
                rtcIntersect1(s, &r1, NULL);
                if (r1.hit.geomID != rh.hit.geomID[k] || fabsf(r1.ray.tfar - rh.ray.tfar[k]) > 1e-5f) {
                    miss++;
                    printf("  %s, %s: lane %d rtcIntersect16 geom %d t %g, rtcIntersect1 geom %d t %g\n", names[variant],
                           coherent ? "coherent" : "incoherent", k, (int)rh.hit.geomID[k], rh.ray.tfar[k], (int)r1.hit.geomID, r1.ray.tfar);
                }
            }
            printf("%-28s %-10s: %d lane(s) differ from rtcIntersect1\n", names[variant], coherent ? "coherent" : "incoherent", miss);
            bad += miss;
        }
    }
    rtcReleaseScene(s);
    /* Curved caps: a convex one at z = 10 (R = 33.34, mask 1) and a concave one at z = 19 (R = -22.28, mask 2). */
    RTCScene c = rtcNewScene(d);
    rtcSetSceneFlags(c, RTC_SCENE_FLAG_ROBUST);
    cap(d, c, 10.0f, 33.34f, 12.7f, 1u);
    cap(d, c, 19.0f, -22.28f, 12.7f, 2u);
    rtcCommitScene(c);
    for (int start = 0; start < 2; start++)
        for (int coherent = 0; coherent < 2; coherent++) bad += bundle(c, start, coherent);
    for (int coherent = 0; coherent < 2; coherent++) bad += spread(c, coherent);
    for (int coherent = 0; coherent < 2; coherent++) {
        bad += tiny_lane(c, coherent, -0.0f);
        bad += tiny_lane(c, coherent, -8.7e-19f);
    }
    rtcReleaseScene(c);
    rtcReleaseDevice(d);
    return bad ? 1 : 0;
}
