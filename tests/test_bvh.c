/* test_bvh.c - our traversal of a BVH Embree builds (bvh.h): on closed
 * meshes it never lets a ray through (rays aimed exactly at shared edges
 * and vertices, and random ones), it finds the very hit the whole
 * triangle list finds (trilist.h: same test, nearest, ties to the lowest
 * index), and its two compiled traversals give the same bits; the build's
 * spatial splits bound what they cut, with the bits of scalar code. */
#include <check.h>
#include <embree3/rtcore.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bvh.h"
#include "closedmesh.h"
#include "rng.h"
#include "scene.h"
#include "testutil.h"
#include "trilist.h"

static const char *kernels[] = {"avx512", "avx2"};

static RTCDevice device(void)
{
    RTCDevice dev = rtcNewDevice("isa=avx2,verbose=0");
    ck_assert(dev != NULL);
    return dev;
}

static vec3_t vtx(const float *pos, uint32_t i)
{
    return vec3_make(pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]);
}

static vec3_t random_dir(rng_stream_t *rng)
{
    float z = 1.0f - 2.0f * rng_next_float(rng), phi = 6.2831853f * rng_next_float(rng);
    float r = sqrtf(fmaxf(0.0f, 1.0f - z * z));
    return vec3_make(r * cosf(phi), r * sinf(phi), z);
}

/* From interior points, rays aimed exactly at every vertex, at points
 * along every edge and in random directions: each must hit the closed
 * mesh, and a segment through it must be blocked. */
static void assert_no_leak(RTCDevice dev, const closedmesh_t *m, const char *kernel,
                           uint64_t random_rays)
{
    char err[256];
    bvh_t *b = bvh_new(dev, m->pos, m->idx, m->nt, err, sizeof err);
    ck_assert_msg(b != NULL, "%s", err);
    if (bvh_use_kernel(b, kernel) < 0) {
        bvh_destroy(&b);
        return;
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
                vec3_t a = vtx(m->pos, m->idx[3 * t + e]);
                vec3_t c = vtx(m->pos, m->idx[3 * t + (e + 1) % 3]);
                for (size_t f = 0; f < sizeof fractions / sizeof fractions[0]; f++) {
                    vec3_t d = vec3_sub(vec3_add(a, vec3_scale(vec3_sub(c, a), fractions[f])), o);
                    uint32_t tri;
                    float th, u, v;
                    rays += 2;
                    leaks += !bvh_intersect(b, o, d, INFINITY, &tri, &th, &u, &v);
                    leaks += !bvh_occluded(b, o, vec3_scale(d, 4.0f), 1.0f);
                }
                uint32_t tri;
                float th, u, v;
                rays++;
                leaks += !bvh_intersect(b, o, vec3_sub(a, o), INFINITY, &tri, &th, &u, &v);
            }
        }
        for (uint64_t i = 0; i < random_rays; i++) {
            vec3_t d = random_dir(&rng);
            uint32_t tri;
            float th, u, v;
            rays += 2;
            leaks += !bvh_intersect(b, o, d, INFINITY, &tri, &th, &u, &v);
            leaks += !bvh_occluded(b, o, vec3_scale(d, 4.0f), 1.0f);
        }
    }
    ck_assert_msg(leaks == 0,
                  "%s traversal: %llu of %llu rays left the closed mesh of %zu triangles", kernel,
                  (unsigned long long)leaks, (unsigned long long)rays, m->nt);
    bvh_destroy(&b);
}

START_TEST(test_watertight_icosphere)
{
    RTCDevice dev = device();
    closedmesh_t m = closedmesh_icosphere(3);
    ck_assert_uint_eq(m.nt, 1280);
    for (size_t k = 0; k < 2; k++)
        assert_no_leak(dev, &m, kernels[k], 20000);
    closedmesh_free(&m);
    /* 20480 triangles: a hierarchy five levels deep */
    m = closedmesh_icosphere(5);
    assert_no_leak(dev, &m, kernels[0], 100000);
    closedmesh_free(&m);
    rtcReleaseDevice(dev);
}
END_TEST

static scene_t *load(const char *rel)
{
    char path[1024], err[512];
    scene_t *s = NULL;
    ck_assert_msg(scene_load(tu_root_path(path, sizeof path, rel), &s, err, sizeof err) == 0, "%s",
                  err);
    return s;
}

/* Rays from random points inside the Cornell box in random directions,
 * and shadow segments between two such points. */
static void box_ray(rng_stream_t *rng, vec3_t *o, vec3_t *d)
{
    *o = vec3_make(20 + 510 * rng_next_float(rng), 1 + 545 * rng_next_float(rng),
                   20 + 520 * rng_next_float(rng));
    *d = random_dir(rng);
}

/* On the Buddha in the Cornell box (100k triangles) every ray finds the
 * very triangle, t, u and v bits that testing every triangle finds, every
 * shadow segment the same answer; each traversal the host runs. */
START_TEST(test_matches_the_whole_list)
{
    scene_t *s = load("scenes/cornell-buddha.json");
    ck_assert_uint_gt(s->triangle_count, 50000);
    RTCDevice dev = device();
    char err[256];
    bvh_t *b = bvh_new(dev, s->positions, s->indices, s->triangle_count, err, sizeof err);
    ck_assert_msg(b != NULL, "%s", err);
    trilist_t *l = trilist_new(s->positions, s->indices, s->triangle_count);
    ck_assert(l != NULL);
    for (size_t k = 0; k < 2; k++) {
        if (bvh_use_kernel(b, kernels[k]) < 0)
            continue;
        rng_stream_t rng = rng_stream(5, k, 0);
        size_t hits = 0, blocked = 0;
        const size_t n = 3000; /* the list tests 100k triangles a ray */
        for (size_t i = 0; i < n; i++) {
            vec3_t o, d;
            box_ray(&rng, &o, &d);
            uint32_t ta = 0, tb = 0;
            float t1 = 0, u1 = 0, v1 = 0, t2 = 0, u2 = 0, v2 = 0;
            int ha = bvh_intersect(b, o, d, INFINITY, &ta, &t1, &u1, &v1);
            int hb = trilist_intersect(l, o, d, INFINITY, &tb, &t2, &u2, &v2);
            ck_assert_int_eq(ha, hb);
            if (ha) {
                hits++;
                ck_assert_msg(ta == tb && memcmp(&t1, &t2, 4) == 0 && memcmp(&u1, &u2, 4) == 0 &&
                                  memcmp(&v1, &v2, 4) == 0,
                              "%s ray %zu: triangle %u t %.9g against %u %.9g", kernels[k], i, ta,
                              t1, tb, t2);
            }
            vec3_t q, dq;
            box_ray(&rng, &q, &dq);
            vec3_t seg = vec3_sub(q, o);
            int oa = bvh_occluded(b, o, seg, 0.99999f), ob = trilist_occluded(l, o, seg, 0.99999f);
            ck_assert_int_eq(oa, ob);
            blocked += (size_t)oa;
        }
        /* most rays hit something (the box is open at the front only) and
         * some segments are blocked by the Buddha: both answers tested */
        ck_assert_uint_gt(hits, n / 2);
        ck_assert_uint_gt(blocked, 0);
        ck_assert_uint_lt(blocked, n);
    }
    trilist_destroy(&l);
    bvh_destroy(&b);
    rtcReleaseDevice(dev);
    scene_destroy(&s);
}
END_TEST

/* The two traversals give the same bits on 200k rays of the Buddha. */
START_TEST(test_kernels_same_bits)
{
    scene_t *s = load("scenes/cornell-buddha.json");
    RTCDevice dev = device();
    char err[256];
    bvh_t *b = bvh_new(dev, s->positions, s->indices, s->triangle_count, err, sizeof err);
    ck_assert_msg(b != NULL, "%s", err);
    if (bvh_use_kernel(b, "avx512") == 0) {
        rng_stream_t rng = rng_stream(6, 0, 0);
        for (size_t i = 0; i < 200000; i++) {
            vec3_t o, d;
            box_ray(&rng, &o, &d);
            uint32_t h[2][4] = {{0}};
            int hit[2], occ[2];
            for (int k = 0; k < 2; k++) {
                ck_assert_int_eq(bvh_use_kernel(b, kernels[k]), 0);
                float t = 0, u = 0, v = 0;
                hit[k] = bvh_intersect(b, o, d, INFINITY, &h[k][0], &t, &u, &v);
                memcpy(&h[k][1], &t, 4);
                memcpy(&h[k][2], &u, 4);
                memcpy(&h[k][3], &v, 4);
                occ[k] = bvh_occluded(b, o, vec3_scale(d, 300.0f), 1.0f);
            }
            ck_assert_int_eq(hit[0], hit[1]);
            ck_assert_int_eq(occ[0], occ[1]);
            ck_assert_msg(memcmp(h[0], h[1], sizeof h[0]) == 0, "ray %zu differs", i);
        }
    }
    bvh_destroy(&b);
    rtcReleaseDevice(dev);
    scene_destroy(&s);
}
END_TEST

/* A grid of squares in the plane z = 1, laid twice (triangles n .. 2n-1
 * repeat 0 .. n-1): every hit is a tie, and the lowest index wins, in
 * whichever leaf the copies land. The segment test stops short of tfar. */
START_TEST(test_ties_and_tfar)
{
    enum { G = 40 };
    closedmesh_t m = {0};
    for (int y = 0; y <= G; y++)
        for (int x = 0; x <= G; x++)
            closedmesh_vertex(&m, (float)x / G * 2 - 1, (float)y / G * 2 - 1, 1.0f);
    for (int copy = 0; copy < 2; copy++)
        for (int y = 0; y < G; y++)
            for (int x = 0; x < G; x++) {
                uint32_t a = (uint32_t)(y * (G + 1) + x), c = a + G + 1;
                closedmesh_tri(&m, a, a + 1, c + 1);
                closedmesh_tri(&m, a, c + 1, c);
            }
    size_t n = m.nt / 2;
    RTCDevice dev = device();
    char err[256];
    bvh_t *b = bvh_new(dev, m.pos, m.idx, m.nt, err, sizeof err);
    ck_assert_msg(b != NULL, "%s", err);
    rng_stream_t rng = rng_stream(8, 0, 0);
    for (int i = 0; i < 20000; i++) {
        vec3_t o = vec3_make(1.4f * rng_next_float(&rng) - 0.7f, 1.4f * rng_next_float(&rng) - 0.7f,
                             -1.0f);
        vec3_t d = vec3_normalize(
            vec3_make(0.2f * rng_next_float(&rng) - 0.1f, 0.2f * rng_next_float(&rng) - 0.1f, 1));
        uint32_t tri;
        float t, u, v;
        ck_assert(bvh_intersect(b, o, d, INFINITY, &tri, &t, &u, &v));
        ck_assert_msg(tri < n, "ray %d hit copy %u, not the lower index %u", i, tri,
                      (unsigned)(tri - n));
        /* o + t d lies on z = 1 */
        ck_assert_float_eq_tol(o.z + t * d.z, 1.0f, 1e-5f);
        vec3_t to_hit = vec3_scale(d, t);
        ck_assert(!bvh_occluded(b, o, to_hit, 0.999f));
        ck_assert(bvh_occluded(b, o, to_hit, 1.001f));
        ck_assert(!bvh_intersect(b, o, d, t, &tri, &t, &u, &v)); /* 0 < t < tfar */
        ck_assert(!bvh_occluded(b, o, vec3_neg(d), INFINITY));
    }
    bvh_destroy(&b);
    closedmesh_free(&m);
    /* no triangles: nothing is ever hit */
    b = bvh_new(dev, NULL, NULL, 0, err, sizeof err);
    ck_assert_msg(b != NULL, "%s", err);
    uint32_t tri;
    float t, u, v;
    ck_assert(
        !bvh_intersect(b, vec3_make(0, 0, 0), vec3_make(0, 0, 1), INFINITY, &tri, &t, &u, &v));
    ck_assert(!bvh_occluded(b, vec3_make(0, 0, 0), vec3_make(0, 0, 1), 1.0f));
    bvh_destroy(&b);
    rtcReleaseDevice(dev);
}
END_TEST

/* bvh_split_bounds in scalar code, one coordinate at a time, with Embree's
 * own splitter's rule (a vertex on the plane bounds both parts; ours gave
 * it to the left part alone, so a part right of the plane could miss the
 * corner at that vertex: the conservative check below caught it). The
 * vector version must match it bit for bit: Embree's hierarchy, and so
 * every traversal's order, follows these bounds. */
static void split_scalar(const float *p[3], const struct RTCBounds *box, unsigned dim,
                         float position, struct RTCBounds *left, struct RTCBounds *right)
{
    float lo[2][3], hi[2][3];
    for (int s = 0; s < 2; s++)
        for (int k = 0; k < 3; k++) {
            lo[s][k] = INFINITY;
            hi[s][k] = -INFINITY;
        }
    for (int e = 0; e < 3; e++) {
        const float *a = p[e], *b = p[(e + 1) % 3];
        float pa = a[dim], pb = b[dim];
        for (int s = 0; s < 2; s++) {
            if (s == 0 ? !(pa <= position) : !(pa >= position))
                continue;
            for (int k = 0; k < 3; k++) {
                lo[s][k] = a[k] < lo[s][k] ? a[k] : lo[s][k];
                hi[s][k] = a[k] > hi[s][k] ? a[k] : hi[s][k];
            }
        }
        if ((pa < position && pb > position) || (pa > position && pb < position)) {
            float f = (position - pa) / (pb - pa);
            for (int k = 0; k < 3; k++) {
                float x = (unsigned)k == dim ? position : a[k] + f * (b[k] - a[k]);
                for (int q = 0; q < 2; q++) {
                    lo[q][k] = x < lo[q][k] ? x : lo[q][k];
                    hi[q][k] = x > hi[q][k] ? x : hi[q][k];
                }
            }
        }
    }
    const float plo[3] = {box->lower_x, box->lower_y, box->lower_z};
    const float phi[3] = {box->upper_x, box->upper_y, box->upper_z};
    struct RTCBounds *out[2] = {left, right};
    for (int s = 0; s < 2; s++) {
        float l[3], h[3];
        for (int k = 0; k < 3; k++) {
            l[k] = lo[s][k] > plo[k] ? lo[s][k] : plo[k];
            h[k] = hi[s][k] < phi[k] ? hi[s][k] : phi[k];
        }
        if (s == 0)
            h[dim] = h[dim] < position ? h[dim] : position;
        else
            l[dim] = l[dim] > position ? l[dim] : position;
        *out[s] = (struct RTCBounds){.lower_x = l[0],
                                     .lower_y = l[1],
                                     .lower_z = l[2],
                                     .upper_x = h[0],
                                     .upper_y = h[1],
                                     .upper_z = h[2]};
    }
}

/* Does box b hold point x (on the split axis, a side's own half)? */
static int holds(const struct RTCBounds *b, const float x[3])
{
    return x[0] >= b->lower_x && x[0] <= b->upper_x && x[1] >= b->lower_y && x[1] <= b->upper_y &&
           x[2] >= b->lower_z && x[2] <= b->upper_z;
}

/* The spatial split's bounds: the scalar code's bits on random triangles,
 * planes through their vertices, vertices on a coarse grid (edges in the
 * plane, triangles flat along it) and references already clipped by an
 * earlier split; and every point of the triangle inside the box lies in
 * its side's bounds (to the rounding of the crossing points). */
START_TEST(test_split_bounds)
{
    rng_stream_t rng = rng_stream(12, 0, 0);
    size_t crossed = 0, on_plane = 0;
    for (int i = 0; i < 200000; i++) {
        float v[3][3];
        int grid = i % 3 == 0;
        for (int j = 0; j < 3; j++)
            for (int k = 0; k < 3; k++)
                v[j][k] = grid ? (float)(int)(4.0f * rng_next_float(&rng)) - 2.0f
                               : 4.0f * rng_next_float(&rng) - 2.0f;
        const float *p[3] = {v[0], v[1], v[2]};
        struct RTCBounds box = {INFINITY,  INFINITY,  INFINITY,  0,
                                -INFINITY, -INFINITY, -INFINITY, 0};
        for (int j = 0; j < 3; j++) {
            box.lower_x = fminf(box.lower_x, v[j][0]);
            box.lower_y = fminf(box.lower_y, v[j][1]);
            box.lower_z = fminf(box.lower_z, v[j][2]);
            box.upper_x = fmaxf(box.upper_x, v[j][0]);
            box.upper_y = fmaxf(box.upper_y, v[j][1]);
            box.upper_z = fmaxf(box.upper_z, v[j][2]);
        }
        if (i % 5 == 1) { /* a reference an earlier split clipped */
            box.lower_x += 0.25f * (box.upper_x - box.lower_x);
            box.upper_y -= 0.25f * (box.upper_y - box.lower_y);
        }
        unsigned dim = (unsigned)(i % 3);
        float position = i % 4 == 0 ? v[i % 3][dim] : 4.0f * rng_next_float(&rng) - 2.0f;
        struct RTCBounds got[2], want[2];
        memset(got, 0x5a, sizeof got);
        memset(want, 0x5a, sizeof want);
        bvh_split_bounds(v[0], v[1], v[2], &box, dim, position, &got[0], &got[1]);
        split_scalar(p, &box, dim, position, &want[0], &want[1]);
        for (int side = 0; side < 2; side++) {
            const float g[6] = {got[side].lower_x, got[side].lower_y, got[side].lower_z,
                                got[side].upper_x, got[side].upper_y, got[side].upper_z};
            const float w[6] = {want[side].lower_x, want[side].lower_y, want[side].lower_z,
                                want[side].upper_x, want[side].upper_y, want[side].upper_z};
            ck_assert_msg(memcmp(g, w, sizeof g) == 0,
                          "case %d side %d: (%g %g %g)-(%g %g %g), the scalar code's "
                          "(%g %g %g)-(%g %g %g)",
                          i, side, g[0], g[1], g[2], g[3], g[4], g[5], w[0], w[1], w[2], w[3], w[4],
                          w[5]);
        }
        /* conservative: points of the triangle (a barycentric grid), within
         * the box, in their side's bounds, grown by the crossings' rounding */
        int straddles = 0;
        for (int j = 0; j < 3; j++) {
            straddles |= v[j][dim] < position ? 1 : v[j][dim] > position ? 2 : 4;
        }
        crossed += (straddles & 3) == 3;
        on_plane += (straddles & 4) != 0;
        for (int a = 0; a <= 8; a++)
            for (int b = 0; a + b <= 8; b++) {
                float wa = (float)a / 8, wb = (float)b / 8, wc = 1.0f - wa - wb, x[3];
                for (int k = 0; k < 3; k++)
                    x[k] = wa * v[0][k] + wb * v[1][k] + wc * v[2][k];
                if (!holds(&box, x))
                    continue;
                int side = x[dim] <= position ? 0 : 1;
                struct RTCBounds grown = got[side];
                float eps = 1e-5f;
                grown.lower_x -= eps;
                grown.lower_y -= eps;
                grown.lower_z -= eps;
                grown.upper_x += eps;
                grown.upper_y += eps;
                grown.upper_z += eps;
                ck_assert_msg(holds(&grown, x), "case %d: a point of the triangle outside side %d",
                              i, side);
            }
    }
    /* the cases the branches tell apart all came up */
    ck_assert_uint_gt(crossed, 10000);
    ck_assert_uint_gt(on_plane, 10000);
}
END_TEST

static Suite *bvh_suite(void)
{
    Suite *s = suite_create("bvh");
    TCase *tc = tcase_create("core");
    tcase_set_timeout(tc, 300);
    if (bvh_supported()) {
        tcase_add_test(tc, test_watertight_icosphere);
        tcase_add_test(tc, test_matches_the_whole_list);
        tcase_add_test(tc, test_kernels_same_bits);
        tcase_add_test(tc, test_ties_and_tfar);
        tcase_add_test(tc, test_split_bounds);
    } else {
        printf("SKIPPED: bvh: this host has no AVX2, the tracer uses Embree's traversal\n");
    }
    suite_add_tcase(s, tc);
    return s;
}

int main(void)
{
    SRunner *sr = srunner_create(bvh_suite());
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed ? EXIT_FAILURE : EXIT_SUCCESS;
}
