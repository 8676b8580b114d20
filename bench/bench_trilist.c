/* bench_trilist.c - where the triangle list (trilist.h: every triangle
 * tested, no BVH) stops beating Embree, which sets TRILIST_MAX_TRIANGLES.
 *
 * For closed meshes of growing size (cubes of 12 to 300 triangles, the
 * Cornell box, icospheres of 20 to 1280 triangles) it times closest-hit rays from random points
 * inside in random directions, and shadow rays between two such points (the any-hit query; on a
 * convex mesh none is blocked, its worst case), on the triangle list (its widest kernel) and on
 * Embree's BVH built as the tracer builds it (ROBUST, high quality, the same ISA). One thread, best
 * of 5.
 *
 * Then why the BVH stays ROBUST: an icosphere of 81,920 triangles (every edge shared exactly) built
 * with Embree's default flags (what Mitsuba 3 uses) and with ROBUST, the same --leak-rays rays
 * (default 10^7) from random points inside it in random directions cast on both: each ray that
 * misses went through a crack between two triangles. Printed with both rates.
 *
 * usage: bench_trilist [--rays N] [--leak-rays N] [--json OUT.json]
 */
#include <cJSON.h>
#include <embree3/rtcore.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "bvh.h"
#include "rng.h"
#include "scene.h"
#include "trilist.h"

#include "../tests/closedmesh.h"
#include "benchray.h"

typedef struct mesh {
    const char *name;
    closedmesh_t g;
    float lo[3], hi[3]; /* where ray origins are drawn */
    int sphere;         /* origins inside the unit sphere (else the box lo..hi) */
} mesh_t;

static double now_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void *xrealloc(void *p, size_t n)
{
    void *q = realloc(p, n);
    if (!q) {
        fprintf(stderr, "bench_trilist: out of memory\n");
        exit(1);
    }
    return q;
}

/* The cube [-1, 1]^3, each face an n x n grid of quads: 12 n^2 triangles
 * (shared lattice points, so it is closed). */
static mesh_t cube_grid(int n)
{
    static char names[8][32];
    mesh_t m = {.lo = {-0.9f, -0.9f, -0.9f}, .hi = {0.9f, 0.9f, 0.9f}};
    for (int axis = 0; axis < 3; axis++) {
        for (int side = 0; side < 2; side++) {
            int a1 = (axis + 1) % 3, a2 = (axis + 2) % 3;
            for (int i = 0; i < n; i++) {
                for (int j = 0; j < n; j++) {
                    uint32_t q[4];
                    static const int di[4] = {0, 1, 1, 0}, dj[4] = {0, 0, 1, 1};
                    for (int c = 0; c < 4; c++) {
                        float p[3];
                        p[axis] = side ? 1.0f : -1.0f;
                        p[a1] = -1.0f + 2.0f * (float)(i + di[c]) / (float)n;
                        p[a2] = -1.0f + 2.0f * (float)(j + dj[c]) / (float)n;
                        q[c] = closedmesh_vertex(&m.g, p[0], p[1], p[2]);
                    }
                    closedmesh_tri(&m.g, q[0], q[1], q[2]);
                    closedmesh_tri(&m.g, q[0], q[2], q[3]);
                }
            }
        }
    }
    snprintf(names[n % 8], sizeof names[n % 8], n == 1 ? "cube" : "cube-grid-%d", n);
    m.name = names[n % 8];
    return m;
}

static mesh_t icosphere(int levels)
{
    static char names[8][32];
    mesh_t m = {.sphere = 1, .g = closedmesh_icosphere(levels)};
    snprintf(names[levels], sizeof names[levels], "icosphere-%zu", m.g.nt);
    m.name = names[levels];
    return m;
}

static mesh_t cornell(void)
{
    mesh_t m = {.name = "cornell-box", .lo = {20, 1, 20}, .hi = {530, 546, 540}};
    scene_t *s = NULL;
    char err[512];
    if (scene_load("scenes/cornell-box.json", &s, err, sizeof err) < 0) {
        fprintf(stderr, "bench_trilist: %s\n", err);
        exit(1);
    }
    m.g.nv = s->vertex_count;
    m.g.nt = s->triangle_count;
    m.g.pos = xrealloc(NULL, 3 * m.g.nv * sizeof(float));
    m.g.idx = xrealloc(NULL, 3 * m.g.nt * sizeof(uint32_t));
    memcpy(m.g.pos, s->positions, 3 * m.g.nv * sizeof(float));
    memcpy(m.g.idx, s->indices, 3 * m.g.nt * sizeof(uint32_t));
    scene_destroy(&s);
    return m;
}

static vec3_t inside_point(const mesh_t *m, rng_stream_t *rng)
{
    if (m->sphere) {
        for (;;) {
            vec3_t p = vec3_make(2 * rng_next_float(rng) - 1, 2 * rng_next_float(rng) - 1,
                                 2 * rng_next_float(rng) - 1);
            if (vec3_dot(p, p) < 0.81f)
                return p;
        }
    }
    return vec3_make(m->lo[0] + (m->hi[0] - m->lo[0]) * rng_next_float(rng),
                     m->lo[1] + (m->hi[1] - m->lo[1]) * rng_next_float(rng),
                     m->lo[2] + (m->hi[2] - m->lo[2]) * rng_next_float(rng));
}

typedef struct rays {
    vec3_t *o, *d, *so, *sd; /* closest-hit rays; shadow segments */
    size_t n;
} rays_t;

static rays_t make_rays(const mesh_t *m, size_t n)
{
    rays_t r = {.n = n};
    r.o = xrealloc(NULL, n * sizeof(vec3_t));
    r.d = xrealloc(NULL, n * sizeof(vec3_t));
    r.so = xrealloc(NULL, n * sizeof(vec3_t));
    r.sd = xrealloc(NULL, n * sizeof(vec3_t));
    rng_stream_t rng = rng_stream(11, 0, 0);
    for (size_t i = 0; i < n; i++) {
        r.o[i] = inside_point(m, &rng);
        float z = 1.0f - 2.0f * rng_next_float(&rng), phi = 6.2831853f * rng_next_float(&rng);
        float rr = sqrtf(fmaxf(0.0f, 1.0f - z * z));
        r.d[i] = vec3_make(rr * cosf(phi), rr * sinf(phi), z);
        r.so[i] = inside_point(m, &rng);
        r.sd[i] = vec3_sub(inside_point(m, &rng), r.so[i]);
    }
    return r;
}

static void free_rays(rays_t *r)
{
    free(r->o);
    free(r->d);
    free(r->so);
    free(r->sd);
}

typedef struct rates {
    double ext, shadow; /* M rays/s */
    size_t hits;
} rates_t;

#define RUNS 5

/* The list l, or when b is set our traversal of Embree's BVH (bvh.h). */
static rates_t time_trilist(const trilist_t *l, const bvh_t *b, const rays_t *r)
{
    rates_t out = {0};
    double best_e = INFINITY, best_s = INFINITY;
    for (int run = 0; run < RUNS; run++) {
        size_t hits = 0;
        double t0 = now_seconds();
        for (size_t i = 0; i < r->n; i++) {
            uint32_t tri;
            float t, u, v;
            hits +=
                (size_t)(b ? bvh_intersect(b, r->o[i], r->d[i], INFINITY, &tri, &t, &u, &v)
                           : trilist_intersect(l, r->o[i], r->d[i], INFINITY, &tri, &t, &u, &v));
        }
        double t1 = now_seconds();
        for (size_t i = 0; i < r->n; i++)
            hits += (size_t)(b ? bvh_occluded(b, r->so[i], r->sd[i], 0.99999f)
                               : trilist_occluded(l, r->so[i], r->sd[i], 0.99999f));
        double t2 = now_seconds();
        best_e = fmin(best_e, t1 - t0);
        best_s = fmin(best_s, t2 - t1);
        out.hits = hits;
    }
    out.ext = (double)r->n / best_e / 1e6;
    out.shadow = (double)r->n / best_s / 1e6;
    return out;
}

/* 1 if the ray o + t d, t > 0, hits the scene (rtcIntersect1). */
static int embree_hits(RTCScene sc, vec3_t o, vec3_t d)
{
    struct RTCRayHit rh;
    return benchray_intersect(sc, o, d, &rh);
}

/* m's BVH, high quality, ROBUST (as the tracer builds it) or with the
 * default flags. */
static RTCScene embree_scene(RTCDevice dev, const mesh_t *m, int robust)
{
    RTCScene sc = rtcNewScene(dev);
    rtcSetSceneFlags(sc, robust ? RTC_SCENE_FLAG_ROBUST : RTC_SCENE_FLAG_NONE);
    rtcSetSceneBuildQuality(sc, RTC_BUILD_QUALITY_HIGH);
    RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, m->g.pos, 0,
                               3 * sizeof(float), m->g.nv);
    rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, m->g.idx, 0,
                               3 * sizeof(uint32_t), m->g.nt);
    rtcCommitGeometry(g);
    rtcAttachGeometry(sc, g);
    rtcReleaseGeometry(g);
    rtcCommitScene(sc);
    return sc;
}

static rates_t time_embree(RTCScene sc, const rays_t *r)
{
    rates_t out = {0};
    double best_e = INFINITY, best_s = INFINITY;
    for (int run = 0; run < RUNS; run++) {
        size_t hits = 0;
        double t0 = now_seconds();
        for (size_t i = 0; i < r->n; i++) {
            hits += (size_t)embree_hits(sc, r->o[i], r->d[i]);
        }
        double t1 = now_seconds();
        for (size_t i = 0; i < r->n; i++) {
            struct RTCIntersectContext ctx;
            rtcInitIntersectContext(&ctx);
            struct RTCRay ray;
            memset(&ray, 0, sizeof ray);
            ray.org_x = r->so[i].x;
            ray.org_y = r->so[i].y;
            ray.org_z = r->so[i].z;
            ray.dir_x = r->sd[i].x;
            ray.dir_y = r->sd[i].y;
            ray.dir_z = r->sd[i].z;
            ray.tfar = 0.99999f;
            ray.mask = 0xffffffffu;
            rtcOccluded1(sc, &ctx, &ray);
            hits += ray.tfar < 0.0f;
        }
        double t2 = now_seconds();
        best_e = fmin(best_e, t1 - t0);
        best_s = fmin(best_s, t2 - t1);
        out.hits = hits;
    }
    out.ext = (double)r->n / best_e / 1e6;
    out.shadow = (double)r->n / best_s / 1e6;
    return out;
}

/* Rays of r (closest hit) that miss a closed mesh, and the rate: a miss is
 * a ray through a crack, since every ray starts inside. */
typedef struct leaks {
    size_t misses;
    double mrays; /* M rays/s, one pass */
} leaks_t;

static leaks_t count_leaks(RTCDevice dev, const mesh_t *m, const rays_t *r, int robust)
{
    RTCScene sc = embree_scene(dev, m, robust);
    leaks_t out = {0};
    double t0 = now_seconds();
    for (size_t i = 0; i < r->n; i++)
        out.misses += !embree_hits(sc, r->o[i], r->d[i]);
    out.mrays = (double)r->n / (now_seconds() - t0) / 1e6;
    rtcReleaseScene(sc);
    return out;
}

/* The same kind of rays, n of them made and cast a chunk at a time (10^8
 * would not fit in memory), on our traversal of a BVH Embree builds
 * (bvh.h, what the tracer uses for closest hits): each ray a closest hit,
 * and a shadow segment to twice as far, which the sphere must block. The
 * rate is the closest hits' alone, making the rays not timed. */
typedef struct bvh_leaks {
    size_t misses, unblocked;
    double mrays;
    const char *kernel;
} bvh_leaks_t;

static int count_leaks_bvh(RTCDevice dev, const mesh_t *m, size_t n, bvh_leaks_t *out)
{
    char err[256];
    bvh_t *b = bvh_new(dev, m->g.pos, m->g.idx, m->g.nt, err, sizeof err);
    if (!b) {
        fprintf(stderr, "bench_trilist: %s\n", err);
        return -1;
    }
    memset(out, 0, sizeof *out);
    out->kernel = bvh_kernel(b);
    enum { CHUNK = 1 << 20 };
    vec3_t *o = xrealloc(NULL, CHUNK * sizeof *o), *d = xrealloc(NULL, CHUNK * sizeof *d);
    rng_stream_t rng = rng_stream(13, 0, 0);
    double seconds = 0;
    for (size_t done = 0; done < n;) {
        size_t k = n - done < CHUNK ? n - done : CHUNK;
        for (size_t i = 0; i < k; i++) {
            o[i] = inside_point(m, &rng);
            float z = 1.0f - 2.0f * rng_next_float(&rng), phi = 6.2831853f * rng_next_float(&rng);
            float rr = sqrtf(fmaxf(0.0f, 1.0f - z * z));
            d[i] = vec3_make(rr * cosf(phi), rr * sinf(phi), z);
        }
        double t0 = now_seconds();
        for (size_t i = 0; i < k; i++) {
            uint32_t tri;
            float t, u, v;
            out->misses += !bvh_intersect(b, o[i], d[i], INFINITY, &tri, &t, &u, &v);
        }
        seconds += now_seconds() - t0;
        for (size_t i = 0; i < k; i++)
            out->unblocked += !bvh_occluded(b, o[i], vec3_scale(d[i], 4.0f), 1.0f);
        done += k;
    }
    out->mrays = (double)n / seconds / 1e6;
    free(o);
    free(d);
    bvh_destroy(&b);
    return 0;
}

int main(int argc, char **argv)
{
    size_t nrays = 500000, leak_rays = 10000000, bvh_leak_rays = 100000000;
    const char *json_path = NULL;
    for (int i = 1; i < argc; i++) {
        if ((strcmp(argv[i], "--rays") == 0 || strcmp(argv[i], "--leak-rays") == 0 ||
             strcmp(argv[i], "--bvh-leak-rays") == 0) &&
            i + 1 < argc) {
            const char *opt = argv[i];
            char *end;
            unsigned long long v = strtoull(argv[++i], &end, 10);
            if (*end || v == 0 || v > 100000000ull) {
                fprintf(stderr, "bench_trilist: %s: want 1..1e8, got '%s'\n", opt, argv[i]);
                return 2;
            }
            *(strcmp(opt, "--rays") == 0        ? &nrays
              : strcmp(opt, "--leak-rays") == 0 ? &leak_rays
                                                : &bvh_leak_rays) = (size_t)v;
        } else if (strcmp(argv[i], "--json") == 0 && i + 1 < argc) {
            json_path = argv[++i];
        } else {
            fprintf(stderr, "usage: bench_trilist [--rays N] [--leak-rays N] [--bvh-leak-rays N] "
                            "[--json OUT.json]\n");
            return 2;
        }
    }
    __builtin_cpu_init();
    const char *isa = __builtin_cpu_supports("avx2") ? "avx2" : "sse4.2";
    char config[64];
    snprintf(config, sizeof config, "isa=%s,verbose=0", isa);
    RTCDevice dev = rtcNewDevice(config);
    if (!dev) {
        fprintf(stderr, "bench_trilist: cannot create the Embree device\n");
        return 1;
    }
    mesh_t meshes[] = {cube_grid(1), icosphere(0), cornell(),    cube_grid(2), icosphere(1),
                       cube_grid(3), cube_grid(4), cube_grid(5), icosphere(2), icosphere(3)};
    const size_t count = sizeof meshes / sizeof meshes[0];
    cJSON *root = cJSON_CreateObject(), *rows = cJSON_AddArrayToObject(root, "meshes");
    cJSON_AddStringToObject(root, "benchmark", "trilist");
    cJSON_AddNumberToObject(root, "rays", (double)nrays);
    cJSON_AddNumberToObject(root, "max_triangles", TRILIST_MAX_TRIANGLES);
    const char *kernel = "";
    printf("| Mesh | Triangles | List ext M rays/s | Embree ext | List / Embree | List shadow | "
           "Embree shadow | List / Embree | Our BVH ext | Our BVH shadow |\n"
           "|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|\n");
    for (size_t k = 0; k < count; k++) {
        mesh_t *m = &meshes[k];
        trilist_t *l = trilist_new(m->g.pos, m->g.idx, m->g.nt);
        if (!l) {
            fprintf(stderr, "bench_trilist: out of memory\n");
            return 1;
        }
        kernel = trilist_kernel(l);
        RTCScene sc = embree_scene(dev, m, 1);
        rays_t r = make_rays(m, nrays);
        rates_t a = time_trilist(l, NULL, &r), b = time_embree(sc, &r), c = {0};
        char err[256];
        bvh_t *own =
            bvh_supported() ? bvh_new(dev, m->g.pos, m->g.idx, m->g.nt, err, sizeof err) : NULL;
        if (own) {
            c = time_trilist(NULL, own, &r);
            if (c.hits != a.hits)
                fprintf(stderr, "bench_trilist: %s: %zu hits on the list, %zu on our BVH\n",
                        m->name, a.hits, c.hits);
            bvh_destroy(&own);
        }
        if (a.hits != b.hits)
            fprintf(stderr, "bench_trilist: %s: %zu hits on the list, %zu on Embree\n", m->name,
                    a.hits, b.hits);
        printf("| %s | %zu | %.2f | %.2f | %.2f | %.2f | %.2f | %.2f | %.2f | %.2f |\n", m->name,
               m->g.nt, a.ext, b.ext, a.ext / b.ext, a.shadow, b.shadow, a.shadow / b.shadow, c.ext,
               c.shadow);
        fflush(stdout);
        cJSON *row = cJSON_CreateObject();
        cJSON_AddStringToObject(row, "mesh", m->name);
        cJSON_AddNumberToObject(row, "triangles", (double)m->g.nt);
        cJSON_AddNumberToObject(row, "list_ext_mrays", a.ext);
        cJSON_AddNumberToObject(row, "embree_ext_mrays", b.ext);
        cJSON_AddNumberToObject(row, "list_shadow_mrays", a.shadow);
        cJSON_AddNumberToObject(row, "embree_shadow_mrays", b.shadow);
        if (c.ext > 0) {
            cJSON_AddNumberToObject(row, "own_bvh_ext_mrays", c.ext);
            cJSON_AddNumberToObject(row, "own_bvh_shadow_mrays", c.shadow);
        }
        cJSON_AddItemToArray(rows, row);
        free_rays(&r);
        rtcReleaseScene(sc);
        trilist_destroy(&l);
        closedmesh_free(&m->g);
    }
    cJSON_AddStringToObject(root, "kernel", kernel);
    cJSON_AddStringToObject(root, "embree_isa", isa);

    mesh_t sphere = icosphere(6);
    rays_t r = make_rays(&sphere, leak_rays);
    printf("\n| Embree BVH (%zu-triangle icosphere, %zu rays from inside) | Rays through a crack | "
           "M rays/s |\n|---|--:|--:|\n",
           sphere.g.nt, leak_rays);
    cJSON *lk = cJSON_AddObjectToObject(root, "leaks");
    cJSON_AddNumberToObject(lk, "triangles", (double)sphere.g.nt);
    cJSON_AddNumberToObject(lk, "rays", (double)leak_rays);
    for (int robust = 0; robust < 2; robust++) {
        leaks_t k = count_leaks(dev, &sphere, &r, robust);
        const char *name = robust ? "robust" : "default";
        printf("| %s | %zu | %.2f |\n",
               robust ? "RTC_SCENE_FLAG_ROBUST" : "default flags (Mitsuba 3's)", k.misses, k.mrays);
        cJSON *e = cJSON_AddObjectToObject(lk, name);
        cJSON_AddNumberToObject(e, "misses", (double)k.misses);
        cJSON_AddNumberToObject(e, "mrays", k.mrays);
    }
    free_rays(&r);
    if (bvh_supported()) {
        bvh_leaks_t k;
        if (count_leaks_bvh(dev, &sphere, bvh_leak_rays, &k) < 0)
            return 1;
        printf("| our traversal of Embree's BVH (bvh.h, %s), %zu rays | %zu (shadow segments "
               "not blocked: %zu) | %.2f |\n",
               k.kernel, bvh_leak_rays, k.misses, k.unblocked, k.mrays);
        cJSON *e = cJSON_AddObjectToObject(lk, "own_bvh");
        cJSON_AddNumberToObject(e, "rays", (double)bvh_leak_rays);
        cJSON_AddNumberToObject(e, "misses", (double)k.misses);
        cJSON_AddNumberToObject(e, "shadow_unblocked", (double)k.unblocked);
        cJSON_AddNumberToObject(e, "mrays", k.mrays);
        cJSON_AddStringToObject(e, "kernel", k.kernel);
    }
    closedmesh_free(&sphere.g);
    rtcReleaseDevice(dev);
    int rc = 0;
    if (json_path) {
        char *text = cJSON_Print(root);
        FILE *f = fopen(json_path, "w");
        if (!f || fputs(text, f) < 0 || fclose(f) != 0) {
            fprintf(stderr, "bench_trilist: cannot write %s\n", json_path);
            rc = 1;
        }
        cJSON_free(text);
    }
    cJSON_Delete(root);
    return rc;
}
