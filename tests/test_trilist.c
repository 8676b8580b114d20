/* test_trilist.c - the triangle list (no BVH) against Embree, against
 * itself at every SIMD width, and on closed meshes it must never let a ray
 * through (rays aimed exactly at shared edges and vertices). */
#include <check.h>
#include <embree3/rtcore.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "closedmesh.h"
#include "rng.h"
#include "scene.h"
#include "testutil.h"
#include "trilist.h"

static const char *kernels[] = {"avx512", "avx2", "sse2"};

/* ---- meshes ----------------------------------------------------------- */

/* The cube [-1, 1]^3 as 12 triangles, diagonals alternating. */
static closedmesh_t cube_mesh(void)
{
    closedmesh_t m = {0};
    for (int v = 0; v < 8; v++)
        closedmesh_vertex(&m, v & 1 ? 1.0f : -1.0f, v & 2 ? 1.0f : -1.0f, v & 4 ? 1.0f : -1.0f);
    static const uint32_t faces[6][4] = {{0, 1, 3, 2}, {4, 6, 7, 5}, {0, 4, 5, 1},
                                         {2, 3, 7, 6}, {0, 2, 6, 4}, {1, 5, 7, 3}};
    for (int f = 0; f < 6; f++) {
        const uint32_t *q = faces[f];
        if (f % 2) {
            closedmesh_tri(&m, q[0], q[1], q[2]);
            closedmesh_tri(&m, q[0], q[2], q[3]);
        } else {
            closedmesh_tri(&m, q[0], q[1], q[3]);
            closedmesh_tri(&m, q[1], q[2], q[3]);
        }
    }
    return m;
}

static vec3_t vtx(const closedmesh_t *m, uint32_t i)
{
    return vec3_make(m->pos[3 * i], m->pos[3 * i + 1], m->pos[3 * i + 2]);
}

/* ---- watertightness ----------------------------------------------------- */

/* From interior points, rays aimed exactly at every vertex, at points along
 * every edge (including its midpoint) and in random directions: each must
 * hit the closed mesh and be occluded by it. Returns the rays cast. */
static uint64_t assert_no_leak(const closedmesh_t *m, const char *kernel, uint64_t random_rays)
{
    trilist_t *l = trilist_new(m->pos, m->idx, m->nt);
    ck_assert(l != NULL);
    if (trilist_use_kernel(l, kernel) < 0) {
        trilist_destroy(&l);
        return 0;
    }
    const vec3_t origins[] = {vec3_make(0, 0, 0), vec3_make(0.3f, -0.2f, 0.1f),
                              vec3_make(-0.61f, 0.47f, -0.33f), vec3_make(1e-4f, 2e-4f, -3e-4f)};
    static const float fractions[] = {0.5f, 1.0f / 3.0f, 1.0f / 7.0f, 0.999f, 1e-3f};
    uint64_t rays = 0, leaks = 0;
    rng_stream_t rng = rng_stream(42, 0, 0);
    for (size_t oi = 0; oi < sizeof origins / sizeof origins[0]; oi++) {
        vec3_t o = origins[oi];
        for (size_t t = 0; t < m->nt; t++) {
            for (int e = 0; e < 3; e++) {
                vec3_t a = vtx(m, m->idx[3 * t + e]), b = vtx(m, m->idx[3 * t + (e + 1) % 3]);
                for (size_t f = 0; f < sizeof fractions / sizeof fractions[0]; f++) {
                    vec3_t target = vec3_add(a, vec3_scale(vec3_sub(b, a), fractions[f]));
                    vec3_t d = vec3_sub(target, o);
                    uint32_t tri;
                    float th, u, v;
                    rays += 2;
                    leaks += !trilist_intersect(l, o, d, INFINITY, &tri, &th, &u, &v);
                    leaks += !trilist_occluded(l, o, vec3_scale(d, 4.0f), 1.0f);
                }
                vec3_t d = vec3_sub(a, o); /* exactly through a vertex */
                uint32_t tri;
                float th, u, v;
                rays++;
                leaks += !trilist_intersect(l, o, d, INFINITY, &tri, &th, &u, &v);
            }
        }
        for (uint64_t i = 0; i < random_rays; i++) {
            float z = 1.0f - 2.0f * rng_next_float(&rng), phi = 6.2831853f * rng_next_float(&rng);
            float r = sqrtf(fmaxf(0.0f, 1.0f - z * z));
            vec3_t d = vec3_make(r * cosf(phi), r * sinf(phi), z);
            uint32_t tri;
            float th, u, v;
            rays++;
            leaks += !trilist_intersect(l, o, d, INFINITY, &tri, &th, &u, &v);
        }
    }
    ck_assert_msg(leaks == 0, "%s kernel: %llu of %llu rays left the closed mesh of %zu triangles",
                  kernel, (unsigned long long)leaks, (unsigned long long)rays, m->nt);
    trilist_destroy(&l);
    return rays;
}

START_TEST(test_watertight_cube)
{
    closedmesh_t m = cube_mesh();
    ck_assert_uint_eq(m.nt, 12);
    uint64_t rays = 0;
    for (size_t k = 0; k < 3; k++)
        rays += assert_no_leak(&m, kernels[k], 200000);
    ck_assert_uint_gt(rays, 0);
    closedmesh_free(&m);
}
END_TEST

START_TEST(test_watertight_icosphere)
{
    closedmesh_t m = closedmesh_icosphere(3);
    ck_assert_uint_eq(m.nt, 1280);
    ck_assert_uint_eq(m.nv, 642); /* every edge shared: V - E + F = 2 */
    for (size_t k = 0; k < 3; k++)
        assert_no_leak(&m, kernels[k], 20000);
    closedmesh_free(&m);
}
END_TEST

/* ---- against Embree and across kernels ---------------------------------- */

typedef struct ray {
    vec3_t o, d;
} ray_t;

/* Rays from random points inside the Cornell box in random directions. */
static ray_t *cornell_rays(size_t n)
{
    ray_t *r = malloc(n * sizeof *r);
    ck_assert(r != NULL);
    rng_stream_t rng = rng_stream(7, 1, 2);
    for (size_t i = 0; i < n; i++) {
        r[i].o = vec3_make(20 + 510 * rng_next_float(&rng), 1 + 545 * rng_next_float(&rng),
                           20 + 520 * rng_next_float(&rng));
        float z = 1.0f - 2.0f * rng_next_float(&rng), phi = 6.2831853f * rng_next_float(&rng);
        float rr = sqrtf(fmaxf(0.0f, 1.0f - z * z));
        r[i].d = vec3_make(rr * cosf(phi), rr * sinf(phi), z);
    }
    return r;
}

static scene_t *cornell(void)
{
    char path[1024], err[512];
    scene_t *s = NULL;
    ck_assert_msg(scene_load(tu_root_path(path, sizeof path, "scenes/cornell-box.json"), &s, err,
                             sizeof err) == 0,
                  "%s", err);
    return s;
}

START_TEST(test_agrees_with_embree)
{
    scene_t *s = cornell();
    trilist_t *l = trilist_new(s->positions, s->indices, s->triangle_count);
    RTCDevice dev = rtcNewDevice("isa=avx2,verbose=0");
    if (!dev)
        dev = rtcNewDevice(NULL);
    ck_assert(dev != NULL);
    RTCScene sc = rtcNewScene(dev);
    rtcSetSceneFlags(sc, RTC_SCENE_FLAG_ROBUST);
    RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, s->positions, 0,
                               3 * sizeof(float), s->vertex_count);
    rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, s->indices, 0,
                               3 * sizeof(uint32_t), s->triangle_count);
    rtcCommitGeometry(g);
    rtcAttachGeometry(sc, g);
    rtcReleaseGeometry(g);
    rtcCommitScene(sc);
    const size_t n = 200000;
    ray_t *rays = cornell_rays(n);
    size_t differ = 0, both = 0;
    for (size_t i = 0; i < n; i++) {
        struct RTCIntersectContext ctx;
        rtcInitIntersectContext(&ctx);
        struct RTCRayHit rh;
        memset(&rh, 0, sizeof rh);
        rh.ray.org_x = rays[i].o.x;
        rh.ray.org_y = rays[i].o.y;
        rh.ray.org_z = rays[i].o.z;
        rh.ray.dir_x = rays[i].d.x;
        rh.ray.dir_y = rays[i].d.y;
        rh.ray.dir_z = rays[i].d.z;
        rh.ray.tfar = INFINITY;
        rh.ray.mask = 0xffffffffu;
        rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
        rtcIntersect1(sc, &ctx, &rh);
        uint32_t tri;
        float t, u, v;
        int hit = trilist_intersect(l, rays[i].o, rays[i].d, INFINITY, &tri, &t, &u, &v);
        int ehit = rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
        if (hit != ehit || (hit && tri != rh.hit.primID)) {
            differ++;
            continue;
        }
        if (!hit)
            continue;
        both++;
        /* rounding scales with the coordinates (up to 560), not with t */
        ck_assert_msg(fabsf(t - rh.ray.tfar) <= 1e-6f * (rh.ray.tfar + 560.0f),
                      "ray %zu: t %.9g vs %.9g", i, t, rh.ray.tfar);
        ck_assert_msg(fabsf(u - rh.hit.u) <= 1e-4f && fabsf(v - rh.hit.v) <= 1e-4f,
                      "ray %zu: (u, v) (%.7f, %.7f) vs (%.7f, %.7f)", i, u, v, rh.hit.u, rh.hit.v);
        /* and a shadow ray to just before that hit is free, past it blocked */
        ck_assert(!trilist_occluded(l, rays[i].o, rays[i].d, t * 0.999f));
        ck_assert(trilist_occluded(l, rays[i].o, rays[i].d, t * 1.001f));
    }
    /* most rays hit (the box is open at the front); they may differ only
     * where two triangles meet within rounding (an edge, a box's foot) */
    ck_assert_msg(both > n * 3 / 4, "%zu of %zu rays hit", both, n);
    ck_assert_msg(differ <= n / 10000, "%zu of %zu rays hit another triangle than Embree's", differ,
                  n);
    free(rays);
    rtcReleaseScene(sc);
    rtcReleaseDevice(dev);
    trilist_destroy(&l);
    scene_destroy(&s);
}
END_TEST

/* Each kernel the host runs gives the same bits on the Cornell box and on
 * an icosphere of 5 blocks plus a partial one. */
START_TEST(test_kernels_same_bits)
{
    scene_t *s = cornell();
    closedmesh_t ico = closedmesh_icosphere(2); /* 320 triangles: 20 blocks */
    for (int which = 0; which < 2; which++) {
        const float *pos = which ? ico.pos : s->positions;
        const uint32_t *idx = which ? ico.idx : s->indices;
        size_t nt = which ? ico.nt - 3 : s->triangle_count; /* 317: a partial block */
        trilist_t *l = trilist_new(pos, idx, nt);
        ck_assert(l != NULL);
        const size_t n = 50000;
        ray_t *rays = cornell_rays(n);
        if (which)
            for (size_t i = 0; i < n; i++) /* origins inside the sphere */
                rays[i].o = vec3_scale(vec3_sub(rays[i].o, vec3_make(278, 274, 280)), 1.0f / 600);
        typedef struct {
            uint32_t tri;
            float t, u, v;
            int hit, occ;
        } res_t;
        res_t *ref = calloc(n, sizeof *ref), *got = calloc(n, sizeof *got);
        ck_assert(ref && got);
        int tested = 0;
        for (size_t k = 0; k < 3; k++) {
            if (trilist_use_kernel(l, kernels[k]) < 0)
                continue;
            res_t *r = tested ? got : ref;
            for (size_t i = 0; i < n; i++) {
                r[i].hit = trilist_intersect(l, rays[i].o, rays[i].d, INFINITY, &r[i].tri, &r[i].t,
                                             &r[i].u, &r[i].v);
                r[i].occ = trilist_occluded(l, rays[i].o, rays[i].d, 100.0f);
            }
            if (tested)
                for (size_t i = 0; i < n; i++)
                    ck_assert_msg(memcmp(&ref[i], &got[i], sizeof ref[i]) == 0,
                                  "%s kernel differs from the widest on ray %zu", kernels[k], i);
            tested++;
            /* two rays at once give each ray's own result: neighbours in
             * the list, and each ray with one far from it in the list (a
             * shadow ray blocked early beside one that is not) */
            for (size_t i = 0; i + 1 < n; i++) {
                const size_t j = i % 2 ? (i * 7919) % n : i + 1;
                const vec3_t o[2] = {rays[i].o, rays[j].o}, d[2] = {rays[i].d, rays[j].d};
                int hit[2], occ[2];
                uint32_t tri[2];
                float t[2], u[2], v[2];
                trilist_intersect_pair(l, o, d, hit, tri, t, u, v);
                trilist_occluded_pair(l, o, d, 100.0f, occ);
                const size_t which_ray[2] = {i, j};
                for (int q = 0; q < 2; q++) {
                    const res_t *e = &r[which_ray[q]];
                    ck_assert_msg(hit[q] == e->hit && occ[q] == e->occ,
                                  "%s kernel, rays %zu and %zu: ray %d's pair result differs",
                                  kernels[k], i, j, q);
                    if (hit[q])
                        ck_assert_msg(tri[q] == e->tri && memcmp(&t[q], &e->t, sizeof t[q]) == 0 &&
                                          memcmp(&u[q], &e->u, sizeof u[q]) == 0 &&
                                          memcmp(&v[q], &e->v, sizeof v[q]) == 0,
                                      "%s kernel, rays %zu and %zu: ray %d's hit differs",
                                      kernels[k], i, j, q);
                }
            }
        }
        ck_assert_int_ge(tested, 1); /* sse2 runs on every x86-64 host */
        size_t hits = 0;
        for (size_t i = 0; i < n; i++)
            hits += (size_t)ref[i].hit;
        ck_assert_uint_gt(hits, n * 3 / 4);
        free(ref);
        free(got);
        free(rays);
        trilist_destroy(&l);
    }
    closedmesh_free(&ico);
    scene_destroy(&s);
}
END_TEST

/* The nearest triangle wins wherever it sits in the list; two at the same
 * distance go to the lower index; tfar and bad rays are respected. */
START_TEST(test_nearest_and_ties)
{
    /* 40 parallel squares-worth of triangles at z = 40 - i, then a copy of
     * triangle 5 at the end: the ray from z = -1 along +z hits z = 1 first */
    float pos[3 * 3 * 41];
    uint32_t idx[3 * 41];
    for (int i = 0; i < 41; i++) {
        float z = i < 40 ? 40.0f - (float)i : 35.0f;
        const float v[9] = {-1, -1, z, 3, -1, z, -1, 3, z};
        memcpy(pos + 9 * i, v, sizeof v);
        for (int k = 0; k < 3; k++)
            idx[3 * i + k] = (uint32_t)(3 * i + k);
    }
    trilist_t *l = trilist_new(pos, idx, 41);
    for (size_t k = 0; k < 3; k++) {
        if (trilist_use_kernel(l, kernels[k]) < 0)
            continue;
        uint32_t tri;
        float t, u, v;
        ck_assert(trilist_intersect(l, vec3_make(0.1f, 0.2f, -1), vec3_make(0, 0, 1), INFINITY,
                                    &tri, &t, &u, &v));
        ck_assert_uint_eq(tri, 39); /* z = 1 */
        ck_assert_float_eq(t, 2.0f);
        ck_assert(fabsf(u - 0.275f) < 1e-6f && fabsf(v - 0.3f) < 1e-6f);
        /* from z = 35.5 towards -z: triangle 5 (z = 35) and its copy 40 tie */
        ck_assert(trilist_intersect(l, vec3_make(0.1f, 0.2f, 35.5f), vec3_make(0, 0, -1), INFINITY,
                                    &tri, &t, &u, &v));
        ck_assert_uint_eq(tri, 5);
        ck_assert(!trilist_intersect(l, vec3_make(0.1f, 0.2f, 35.5f), vec3_make(0, 0, -1), 0.4f,
                                     &tri, &t, &u, &v));
        ck_assert(!trilist_occluded(l, vec3_make(0.1f, 0.2f, 35.5f), vec3_make(0, 0, -1), 0.4f));
        ck_assert(trilist_occluded(l, vec3_make(0.1f, 0.2f, 35.5f), vec3_make(0, 0, -1), 0.6f));
        /* outside every triangle, a zero direction, a NaN origin: no hit */
        ck_assert(!trilist_intersect(l, vec3_make(5, 5, -1), vec3_make(0, 0, 1), INFINITY, &tri, &t,
                                     &u, &v));
        ck_assert(!trilist_intersect(l, vec3_make(0, 0, -1), vec3_make(0, 0, 0), INFINITY, &tri, &t,
                                     &u, &v));
        ck_assert(!trilist_occluded(l, vec3_make(NAN, 0, -1), vec3_make(0, 0, 1), INFINITY));
        /* the same in pairs: a hit beside a miss, either way round */
        const vec3_t po[2] = {vec3_make(0.1f, 0.2f, -1), vec3_make(5, 5, -1)};
        const vec3_t pd[2] = {vec3_make(0, 0, 1), vec3_make(0, 0, 1)};
        const vec3_t qo[2] = {po[1], po[0]}, qd[2] = {pd[1], pd[0]};
        int hit[2];
        uint32_t tris[2];
        float ts[2], us[2], vs[2];
        trilist_intersect_pair(l, po, pd, hit, tris, ts, us, vs);
        ck_assert(hit[0] && !hit[1] && tris[0] == 39 && ts[0] == 2.0f);
        trilist_intersect_pair(l, qo, qd, hit, tris, ts, us, vs);
        ck_assert(!hit[0] && hit[1] && tris[1] == 39 && ts[1] == 2.0f);
        trilist_occluded_pair(l, po, pd, INFINITY, hit);
        ck_assert(hit[0] && !hit[1]);
        trilist_occluded_pair(l, qo, qd, INFINITY, hit);
        ck_assert(!hit[0] && hit[1]);
    }
    ck_assert_int_eq(trilist_use_kernel(l, "avx1024"), -1);
    trilist_destroy(&l);
    /* an empty list hits nothing */
    l = trilist_new(pos, idx, 0);
    ck_assert(l != NULL);
    uint32_t tri;
    float t, u, v;
    ck_assert(
        !trilist_intersect(l, vec3_make(0, 0, -1), vec3_make(0, 0, 1), INFINITY, &tri, &t, &u, &v));
    const vec3_t eo[2] = {vec3_make(0, 0, -1), vec3_make(0, 0, -1)};
    const vec3_t ed[2] = {vec3_make(0, 0, 1), vec3_make(0, 1, 0)};
    int ehit[2] = {-1, -1};
    uint32_t etri[2];
    float et[2], eu[2], ev[2];
    trilist_intersect_pair(l, eo, ed, ehit, etri, et, eu, ev);
    ck_assert(!ehit[0] && !ehit[1]);
    trilist_occluded_pair(l, eo, ed, INFINITY, ehit);
    ck_assert(!ehit[0] && !ehit[1]);
    trilist_destroy(&l);
}
END_TEST

static Suite *trilist_suite(void)
{
    Suite *s = suite_create("trilist");
    TCase *tc = tcase_create("core");
    tcase_set_timeout(tc, 300);
    tcase_add_test(tc, test_watertight_cube);
    tcase_add_test(tc, test_watertight_icosphere);
    tcase_add_test(tc, test_agrees_with_embree);
    tcase_add_test(tc, test_kernels_same_bits);
    tcase_add_test(tc, test_nearest_and_ties);
    suite_add_tcase(s, tc);
    return s;
}

int main(void)
{
    SRunner *sr = srunner_create(trilist_suite());
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed ? EXIT_FAILURE : EXIT_SUCCESS;
}
