/* bench_core.c - the core benchmark ("Path-tracing core", section 6) for one
 * scene at one thread count:
 *
 *   1. our renderer: render_run with the path integrator, best of --runs,
 *      giving samples/s and rays/s (total and per core) and rays per sample;
 *      the split of those rays into extension (camera + bounce) and shadow
 *      rays comes from a short render with the naive integrator, which
 *      traces exactly the extension rays of the same path-length
 *      distribution (same materials, same Russian roulette) and no shadow
 *      rays;
 *   2. raw ray casting: the tracer's calls (tracer_intersect_packet,
 *      tracer_unoccluded_packet: our traversal of a BVH Embree builds,
 *      bvh.h, where the tracer uses it, or rtcIntersect8 / rtcOccluded8
 *      over TRACER_PACKET consecutive rays; JSON "path_embree_packets":
 *      Embree's packets, "path_own_bvh": bvh.h) over a precomputed batch of extension
 *      rays and a batch of shadow rays, on a scene built exactly as
 *      common/tracer.c builds its scene, timed separately on --threads
 *      pthreads (and, for reference, one ray a call: rtcIntersect1 /
 *      rtcOccluded1, JSON "path_one_by_one"), for two ray distributions:
 *        "path": the rays of real random walks from the camera (diffuse
 *                bounces, and through glass)
 *                (what our tracer traces, replayed without any shading);
 *        "area": origins uniform by area on the non-black-emitter
 *                triangles, cosine directions about the winding normal,
 *                shadow rays to uniform points on the lights (the
 *                issue's recipe; on the Happy Buddha the 100 m^2 floor is
 *                almost all of the area, so these rays mostly miss and the
 *                rate says little: the table uses "path");
 *      and the ratio of our rays/s to the raw rate of our own mix of the
 *      two kinds (time-weighted: a mix rate is 1 / sum(fraction / rate));
 *      for reference, the "path" rays also on a BVH built without
 *      RTC_SCENE_FLAG_ROBUST (what that flag costs; JSON only);
 *      and on the triangle list (trilist.h), which the tracer uses instead
 *      of Embree for a scene of up to TRILIST_MAX_TRIANGLES triangles
 *      ("accel" in the JSON says which the renders used), in the tracer's
 *      packets as the renders cast them (two rays a call);
 *      and, on a scene traced through Embree, the two other ways it could
 *      be kept watertight (issue 9; JSON "path_sorted" and
 *      "path_watertight_user"): the same rays sorted by direction octant
 *      and the Morton code of their origin (what a wavefront tracer that
 *      sorts its rays could at best gain: the sort is not timed), and an
 *      Embree BVH over clusters of 16 triangles tested by trilist's
 *      watertight kernel (user geometry) instead of ROBUST;
 *   3. peak memory (ru_maxrss) right after the renders, before the ray
 *      batches exist, and at the end.
 *
 * Each timing also records the process's CPU utilization (CPU time / wall
 * time x threads): on a shared machine another process shows up there. A
 * measurement whose best run was disturbed gets a few extra runs and is
 * flagged "disturbed" if none was clean.
 *
 * usage: bench_core --scene FILE.json [--threads T] [--spp N] [--runs R]
 *                   [--rays N] [--json OUT.json]
 */
#include <cJSON.h>
#include <embree3/rtcore.h>
#include <errno.h>
#include <inttypes.h>
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>

#include "bvh.h"
#include "film.h"
#include "lights.h"
#include "material.h"
#include "mitsuba.h"
#include "render.h"
#include "rng.h"
#include "scene.h"
#include "tracer.h"
#include "tracer_priv.h"
#include "trilist.h"
#include "vberr.h"
#include "vmath.h"

#include "benchray.h"

static const char usage_text[] =
    "usage: bench_core --scene FILE.json [options]\n"
    "\n"
    "Measures our renderer (render_run, path integrator) against raw Embree\n"
    "on the same scene and prints a summary; --json writes every number.\n"
    "\n"
    "options:\n"
    "  --scene FILE.json   scene to measure (required)\n"
    "  --threads T         render and Embree threads, 1..256 (default 1)\n"
    "  --spp N             samples per pixel of each timed render (default 64)\n"
    "  --runs R            timed repetitions, best is kept (default 3)\n"
    "  --rays N            rays per raw Embree batch (default 2000000)\n"
    "  --engine E          wavefront (default) or scalar (tracer.h)\n"
    "  --sampler S         independent (default: the fastest, as Mitsuba's peer\n"
    "                      runs) or sobol (what a job takes by default)\n"
    "  --roulette R        mitsuba (default: a path survives with probability its\n"
    "                      throughput, at most 0.95, as Mitsuba's peer runs, so\n"
    "                      both trace the same paths) or ours (the scene's\n"
    "                      rr_threshold and rr_cap, what a job takes: longer\n"
    "                      paths, fewer samples/s)\n"
    "  --isa I             our own SIMD kernels (triangle list, BVH traversal) for\n"
    "                      avx512 or avx2 (default: the widest the host runs); avx2\n"
    "                      on an AVX-512 host measures what an AVX2-only host runs\n"
    "  --json FILE         write the results as JSON\n"
    "  -h, --help          this text\n";

/* ---- small helpers ------------------------------------------------------ */

static double now_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* CPU time of the whole process: divided by wall time x threads it says
 * whether our threads had their cores to themselves (another process on
 * this 2-core machine shows as utilization well under 1). */
static double cpu_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* A measurement whose best run had less than this share of its cores gets
 * extra runs, and is flagged if it still has. Clean runs measure 0.97-1.0
 * (render_run's threads wait briefly at each layer's barrier); a run at
 * 0.92 was seen to be 6% slow. */
#define UNDISTURBED 0.95
#define EXTRA_RUNS 3
#define MAX_RUNS 100
/* A raw pass takes 0.1-0.3 s, so more of them cost little and make a clean
 * one likelier. */
#define RAW_MIN_RUNS 5

static long peak_rss_kb(void)
{
    struct rusage ru;
    if (getrusage(RUSAGE_SELF, &ru) < 0)
        return -1;
    return ru.ru_maxrss; /* kilobytes on Linux */
}

static int parse_u64(const char *s, uint64_t lo, uint64_t hi, uint64_t *out)
{
    if (!s || !*s || *s == '-' || *s == '+')
        return -1;
    errno = 0;
    char *end;
    unsigned long long v = strtoull(s, &end, 10);
    if (errno || *end || v < lo || v > hi)
        return -1;
    *out = v;
    return 0;
}

static int usage_error(const char *what, const char *arg)
{
    fprintf(stderr, "bench_core: %s%s%s\n\n%s", what, arg ? " " : "", arg ? arg : "", usage_text);
    return 2;
}

/* Index of the first cdf entry > u (cdf ascending, last entry 1). */
static size_t cdf_pick(const double *cdf, size_t n, double u)
{
    size_t lo = 0, hi = n - 1;
    while (lo < hi) {
        size_t mid = (lo + hi) / 2;
        if (cdf[mid] > u)
            hi = mid;
        else
            lo = mid + 1;
    }
    return lo;
}

/* A light point picked as the tracer picks it (sample_direct in tracer.c):
 * the triangle by power and the point on it from one pair. */
static uint32_t light_point(const scene_t *s, rng_stream_t *rng, vec3_t *q)
{
    double ul = rng_next_double(rng);
    float u2 = rng_next_float(rng);
    return lights_sample(s, ul, u2, q);
}

/* ---- raw Embree ---------------------------------------------------------- */

/* A ray of a batch: the 24 bytes the tracer knows before it calls Embree.
 * The timed loop fills Embree's struct from it exactly as tracer.c does, so
 * the raw rate includes that (tiny) cost and nothing else. */
typedef struct bray {
    float o[3], d[3];
} bray_t;

typedef struct batch {
    bray_t *rays;
    size_t count, cap;
} batch_t;

static int batch_init(batch_t *b, size_t cap)
{
    b->rays = malloc(cap * sizeof *b->rays);
    b->count = 0;
    b->cap = cap;
    return b->rays ? 0 : -1;
}

static void batch_free(batch_t *b)
{
    free(b->rays);
    b->rays = NULL;
    b->count = b->cap = 0;
}

static void batch_push(batch_t *b, vec3_t o, vec3_t d)
{
    if (b->count == b->cap)
        return;
    bray_t *r = &b->rays[b->count++];
    r->o[0] = o.x;
    r->o[1] = o.y;
    r->o[2] = o.z;
    r->d[0] = d.x;
    r->d[1] = d.y;
    r->d[2] = d.z;
}

typedef struct embree {
    RTCDevice device;
    RTCScene scene;
    char isa[16];
    trilist_t *list;         /* if set, rays go to the triangle list instead */
    bvh_t *tracer_bvh;       /* if set, rays go to our traversal (bvh.h), as TRACER_ACCEL_BVH */
    int one_by_one;          /* rtcIntersect1 / rtcOccluded1, not the tracer's packets */
    const char *kernels_isa; /* --isa: every list and BVH of ours runs it; NULL: the widest */
} embree_t;

/* Puts a list or BVH of ours (either may be NULL) on the --isa kernels, as
 * tracer_use_isa does the tracer's; -1, said, if the host cannot run them. */
static int use_kernels_isa(const char *isa, trilist_t *l, bvh_t *b)
{
    if (!isa)
        return 0;
    if ((l && trilist_use_kernel(l, isa) < 0) || (b && bvh_use_kernel(b, isa) < 0)) {
        fprintf(stderr, "bench_core: this host cannot run the %s kernels\n", isa);
        return -1;
    }
    return 0;
}

/* e->device configured as tracer_device_new configures it (the ISA pinned). */
static int embree_device_new(embree_t *e)
{
    __builtin_cpu_init();
    snprintf(e->isa, sizeof e->isa, "%s", __builtin_cpu_supports("avx2") ? "avx2" : "sse4.2");
    char config[64];
    snprintf(config, sizeof config, "isa=%s,verbose=0", e->isa);
    e->device = rtcNewDevice(config);
    return e->device ? 0 : -1;
}

/* The same device configuration, scene flags and build quality as
 * tracer_new, so the BVH and kernels are the ones our tracer uses (robust
 * 0 leaves out RTC_SCENE_FLAG_ROBUST, for the reference figure only). */
static int embree_build(const scene_t *s, embree_t *e, int robust)
{
    if (embree_device_new(e) < 0)
        return -1;
    e->scene = rtcNewScene(e->device);
    rtcSetSceneFlags(e->scene, robust ? RTC_SCENE_FLAG_ROBUST : RTC_SCENE_FLAG_NONE);
    rtcSetSceneBuildQuality(e->scene, RTC_BUILD_QUALITY_HIGH);
    RTCGeometry g = rtcNewGeometry(e->device, RTC_GEOMETRY_TYPE_TRIANGLE);
    float *vb = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                        3 * sizeof(float), s->vertex_count);
    uint32_t *ib = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                           3 * sizeof(uint32_t), s->triangle_count);
    if (!vb || !ib) {
        rtcReleaseGeometry(g);
        return -1;
    }
    memcpy(vb, s->positions, s->vertex_count * 3 * sizeof(float));
    memcpy(ib, s->indices, s->triangle_count * 3 * sizeof(uint32_t));
    rtcCommitGeometry(g);
    rtcAttachGeometry(e->scene, g);
    rtcReleaseGeometry(g);
    rtcCommitScene(e->scene);
    return rtcGetDeviceError(e->device) == RTC_ERROR_NONE ? 0 : -1;
}

static void embree_free(embree_t *e)
{
    if (e->scene)
        rtcReleaseScene(e->scene);
    if (e->device)
        rtcReleaseDevice(e->device);
}

/* Untimed closest hit, for building the path batch. */
static int closest_hit(const embree_t *e, vec3_t o, vec3_t d, uint32_t *tri, float *u, float *v)
{
    struct RTCRayHit rh;
    if (!benchray_intersect(e->scene, o, d, &rh))
        return 0;
    *tri = rh.hit.primID;
    *u = rh.hit.u;
    *v = rh.hit.v;
    return 1;
}

typedef struct raw_job {
    RTCScene scene;
    const trilist_t *list;
    const bvh_t *tracer_bvh;
    int one_by_one;
    const bray_t *rays;
    size_t begin, end;
    int shadow;
    size_t hits; /* hits or occlusions, to report what the batch does */
} raw_job_t;

/* One thread's share of a timed pass, through the calls the tracer makes
 * (tracer_priv.h). */
static void *raw_worker(void *argp)
{
    raw_job_t *j = argp;
    size_t hits = 0;
    if (j->list || !j->one_by_one) {
        /* packets of consecutive rays, through the tracer's own calls */
        const tracer_t tr = {
            .rtc = j->scene, .bvh = (bvh_t *)j->tracer_bvh, .small = (trilist_t *)j->list};
        for (size_t i = j->begin; i < j->end; i += TRACER_PACKET) {
            size_t m = j->end - i < TRACER_PACKET ? j->end - i : TRACER_PACKET;
            tracer_packet_t pk;
            for (size_t q = 0; q < m; q++) {
                const bray_t *b = &j->rays[i + q];
                pk.o[q] = vec3_make(b->o[0], b->o[1], b->o[2]);
                pk.d[q] = vec3_make(b->d[0], b->d[1], b->d[2]);
            }
            int got[TRACER_PACKET];
            if (j->shadow) {
                tracer_unoccluded_packet(&tr, &pk, m, got);
                for (size_t q = 0; q < m; q++)
                    hits += !got[q];
            } else {
                tracer_hit_t h[TRACER_PACKET];
                tracer_intersect_packet(&tr, &pk, m, got, h);
                for (size_t q = 0; q < m; q++)
                    hits += (size_t)got[q];
            }
        }
    } else {
        for (size_t i = j->begin; i < j->end; i++) {
            const bray_t *b = &j->rays[i];
            vec3_t o = vec3_make(b->o[0], b->o[1], b->o[2]),
                   d = vec3_make(b->d[0], b->d[1], b->d[2]);
            tracer_hit_t h;
            hits += j->shadow ? !tracer_embree_unoccluded(j->scene, o, d)
                              : tracer_embree_intersect(j->scene, o, d, &h);
        }
    }
    j->hits = hits;
    return NULL;
}

typedef struct raw_result {
    size_t rays;
    double seconds_best;
    double utilization; /* of the best pass: CPU time / (wall time x threads) */
    double hit_fraction;
    double rays_per_second;
} raw_result_t;

/* Best of `runs` passes over the batch, split into `threads` contiguous
 * chunks. Thread start-up (tens of microseconds) is inside the timing; a
 * pass takes a fraction of a second, so it does not matter. */
static int raw_time(const embree_t *e, const batch_t *b, int shadow, int threads, int runs,
                    raw_result_t *out)
{
    memset(out, 0, sizeof *out);
    out->rays = b->count;
    if (b->count == 0)
        return 0;
    raw_job_t jobs[RENDER_MAX_THREADS];
    pthread_t tid[RENDER_MAX_THREADS];
    double best = INFINITY, best_util = 0;
    size_t hits = 0;
    for (int run = 0; run < runs || (best_util < UNDISTURBED && run < runs + EXTRA_RUNS); run++) {
        double t0 = now_seconds(), c0 = cpu_seconds();
        for (int k = 0; k < threads; k++) {
            jobs[k].scene = e->scene;
            jobs[k].list = e->list;
            jobs[k].tracer_bvh = e->tracer_bvh;
            jobs[k].one_by_one = e->one_by_one;
            jobs[k].rays = b->rays;
            jobs[k].begin = b->count * (size_t)k / (size_t)threads;
            jobs[k].end = b->count * (size_t)(k + 1) / (size_t)threads;
            jobs[k].shadow = shadow;
            jobs[k].hits = 0;
            if (pthread_create(&tid[k], NULL, raw_worker, &jobs[k]) != 0) {
                for (int m = 0; m < k; m++)
                    pthread_join(tid[m], NULL);
                return -1;
            }
        }
        hits = 0;
        for (int k = 0; k < threads; k++) {
            pthread_join(tid[k], NULL);
            hits += jobs[k].hits;
        }
        double dt = now_seconds() - t0, util = (cpu_seconds() - c0) / (dt * threads);
        if (dt < best) {
            best = dt;
            best_util = util;
        }
    }
    out->seconds_best = best;
    out->utilization = best_util;
    out->hit_fraction = (double)hits / (double)b->count;
    out->rays_per_second = (double)b->count / best;
    return 0;
}

/* ---- ray batches ---------------------------------------------------------- */

/* The tracer ends a path at an emitter without albedo, so no ray leaves one. */
static int tri_reflects(const scene_t *s, uint32_t tri)
{
    const material_t *m = &s->materials[s->tri_material[tri]];
    return !(m->type == MATERIAL_EMITTER && vec3_is_zero(m->albedo));
}

/* Shadow ray as the tracer builds it, if the tracer would trace it: from p
 * (face-forward normal ngf, shading normal ns) to a light point. */
static void push_shadow(const scene_t *s, batch_t *sh, vec3_t p, vec3_t ngf, vec3_t ns,
                        rng_stream_t *rng)
{
    vec3_t q;
    uint32_t lt = light_point(s, rng, &q);
    vec3_t to = vec3_sub(q, p);
    float dist2 = vec3_dot(to, to);
    if (!(dist2 > 0.0f))
        return;
    vec3_t wl = vec3_scale(to, 1.0f / sqrtf(dist2));
    vec3_t nl = s->tri_normal[lt];
    if (-vec3_dot(nl, wl) > 0.0f && vec3_dot(ns, wl) > 0.0f && vec3_dot(ngf, wl) > 0.0f) {
        vec3_t from = vec3_offset_ray_origin(p, ngf);
        vec3_t target = vec3_offset_ray_origin(q, nl);
        batch_push(sh, from, vec3_sub(target, from));
    }
}

/* "path": the rays of random walks from the camera, built like the
 * path integrator's (camera ray, next-event shadow ray at each diffuse
 * vertex, cosine bounce about the shading normal, Russian roulette after
 * TRACER_RR_DEPTH bounces on the throughput, tracer_roulette_probability).
 * Pixels in scanline order, one sample per pixel per pass, until the
 * extension batch is full. Walks go on through glass and off mirrors as
 * the path integrator does (material_sample, no shadow ray there), so
 * cornell-glass's batch holds the rays inside its glass object; they stop
 * at the glossy materials, which no core scene has. */
static void build_path_batch(const scene_t *s, const embree_t *e, uint64_t seed, batch_t *ext,
                             batch_t *sh)
{
    const camera_t *cam = &s->camera;
    const uint32_t npix = (uint32_t)cam->width * (uint32_t)cam->height;
    for (uint64_t sample = 0; ext->count < ext->cap; sample++) {
        for (uint32_t pixel = 0; pixel < npix && ext->count < ext->cap; pixel++) {
            rng_stream_t rng = rng_stream(seed, pixel, sample);
            float fu = rng_next_float(&rng), fv = rng_next_float(&rng);
            vec3_t o = cam->position;
            vec3_t d = vec3_normalize(camera_ray_dir(cam, pixel % (uint32_t)cam->width,
                                                     pixel / (uint32_t)cam->width, fu, fv));
            vec3_t beta = vec3_make(1, 1, 1);
            float eta_scale = 1.0f;
            for (uint32_t depth = 0; ext->count < ext->cap; depth++) {
                batch_push(ext, o, d);
                uint32_t tri;
                float hu, hv;
                if (!closest_hit(e, o, d, &tri, &hu, &hv))
                    break;
                const uint32_t *vi = s->indices + 3 * tri;
                const material_t *m = &s->materials[s->tri_material[tri]];
                if (!tri_reflects(s, tri))
                    break;
                if (s->max_depth && depth + 2 > s->max_depth)
                    break;
                if (m->type != MATERIAL_DIFFUSE && m->type != MATERIAL_EMITTER &&
                    m->type != MATERIAL_MIRROR && m->type != MATERIAL_DIELECTRIC)
                    break; /* (the glossy materials: no core scene has one) */
                vec3_t p = scene_point(s, tri, hu, hv);
                vec3_t ng = s->tri_normal[tri];
                vec3_t wo = vec3_neg(d);
                vec3_t ngf = vec3_dot(ng, wo) < 0.0f ? vec3_neg(ng) : ng;
                vec3_t ns = ngf;
                if (s->tri_smooth[tri]) {
                    vec3_t n = vec3_normalize(vec3_barycentric(
                        scene_vertex_normal(s, vi[0]), scene_vertex_normal(s, vi[1]),
                        scene_vertex_normal(s, vi[2]), hu, hv));
                    if (vec3_dot(n, ngf) < 0.0f)
                        n = vec3_neg(n);
                    if (vec3_is_finite(n) && vec3_dot(n, wo) > 0.0f)
                        ns = n;
                }
                vec3_t wi;
                if (m->type == MATERIAL_MIRROR || m->type == MATERIAL_DIELECTRIC) {
                    /* through glass and off mirrors as the path integrator
                     * goes (no shadow ray from a specular surface) */
                    material_hit_t mh = {
                        .wo = wo, .ngf = ngf, .ns = ns, .front = vec3_dot(ng, wo) > 0.0f};
                    material_sample_t bs;
                    if (!material_sample(m, &mh, &rng, &bs))
                        break;
                    wi = bs.wi;
                    beta = vec3_mul(beta, bs.weight);
                    if (bs.transmits)
                        eta_scale *= bs.eta * bs.eta;
                    o = vec3_offset_ray_origin(p, bs.transmits ? vec3_neg(ngf) : ngf);
                } else {
                    if (s->light_count > 0)
                        push_shadow(s, sh, p, ngf, ns, &rng);
                    float u1 = rng_next_float(&rng), u2 = rng_next_float(&rng);
                    wi = material_sample_cosine(ns, u1, u2);
                    if (vec3_dot(ngf, wi) <= 0.0f || vec3_dot(ns, wi) <= 0.0f)
                        break;
                    beta = vec3_mul(beta, m->albedo);
                    o = vec3_offset_ray_origin(p, ngf);
                }
                if (depth + 1 >= TRACER_RR_DEPTH) {
                    float q = tracer_roulette_probability(s, beta, eta_scale);
                    if (!(rng_next_float(&rng) < q))
                        break;
                    beta = vec3_scale(beta, 1.0f / q);
                }
                d = vec3_normalize(wi);
            }
        }
    }
}

/* "area": origins uniform by area over the triangles a path can leave from,
 * offset along the winding normal, cosine directions about it. The winding
 * normal is the side a path tracer leaves from in both benchmark scenes
 * (Cornell walls face into the room, boxes, statue and floor face out); a
 * random side would start half the rays inside closed objects. Shadow rays
 * go from a fresh such point to a light point, redrawn until the tracer
 * would trace them (each side faces the other). */
static int build_area_batch(const scene_t *s, uint64_t seed, batch_t *ext, batch_t *sh)
{
    double *cdf = malloc(s->triangle_count * sizeof *cdf);
    uint32_t *ids = malloc(s->triangle_count * sizeof *ids);
    if (!cdf || !ids) {
        free(cdf);
        free(ids);
        return -1;
    }
    size_t n = 0;
    double total = 0;
    for (uint32_t t = 0; t < s->triangle_count; t++) {
        if (!tri_reflects(s, t))
            continue;
        const uint32_t *v = s->indices + 3 * t;
        vec3_t a = scene_vertex(s, v[0]);
        total += 0.5 * (double)vec3_length(vec3_cross(vec3_sub(scene_vertex(s, v[1]), a),
                                                      vec3_sub(scene_vertex(s, v[2]), a)));
        cdf[n] = total;
        ids[n++] = t;
    }
    if (n == 0 || !(total > 0)) {
        free(cdf);
        free(ids);
        return 0;
    }
    for (size_t i = 0; i < n; i++)
        cdf[i] /= total;
    cdf[n - 1] = 1.0;
    for (uint64_t i = 0; ext->count < ext->cap; i++) {
        rng_stream_t rng = rng_stream(seed, 1, i);
        uint32_t t = ids[cdf_pick(cdf, n, rng_next_double(&rng))];
        float u1 = rng_next_float(&rng), u2 = rng_next_float(&rng);
        vec3_t p = scene_sample_point(s, t, u1, u2), ng = s->tri_normal[t];
        u1 = rng_next_float(&rng);
        u2 = rng_next_float(&rng);
        batch_push(ext, vec3_offset_ray_origin(p, ng), material_sample_cosine(ng, u1, u2));
    }
    /* Bounded: a scene whose lights face no surface yields no shadow rays. */
    for (uint64_t i = 0; s->light_count > 0 && sh->count < sh->cap && i < 50 * (uint64_t)sh->cap;
         i++) {
        rng_stream_t rng = rng_stream(seed, 2, i);
        uint32_t t = ids[cdf_pick(cdf, n, rng_next_double(&rng))];
        float u1 = rng_next_float(&rng), u2 = rng_next_float(&rng);
        vec3_t p = scene_sample_point(s, t, u1, u2), ng = s->tri_normal[t];
        push_shadow(s, sh, p, ng, ng, &rng);
    }
    free(cdf);
    free(ids);
    return 0;
}

/* ---- other ways to stay watertight on Embree (issue 9) --------------------- */

/* An empty box [lo, hi], and the box grown to take in p. */
static void bounds_empty(float lo[3], float hi[3])
{
    for (int k = 0; k < 3; k++) {
        lo[k] = INFINITY;
        hi[k] = -INFINITY;
    }
}

static void bounds_grow(float lo[3], float hi[3], const float p[3])
{
    for (int k = 0; k < 3; k++) {
        lo[k] = fminf(lo[k], p[k]);
        hi[k] = fmaxf(hi[k], p[k]);
    }
}

/* 10 bits of x spread to every third bit (a 30-bit Morton code's share). */
static uint32_t morton_spread(uint32_t x)
{
    x &= 0x3ffu;
    x = (x | x << 16) & 0x030000ffu;
    x = (x | x << 8) & 0x0300f00fu;
    x = (x | x << 4) & 0x030c30c3u;
    return (x | x << 2) & 0x09249249u;
}

/* The Morton code of p in the box [lo, hi]. */
static uint32_t morton_code(const float p[3], const float lo[3], const float hi[3])
{
    uint32_t code = 0;
    for (int k = 0; k < 3; k++) {
        float f = hi[k] > lo[k] ? (p[k] - lo[k]) / (hi[k] - lo[k]) : 0.0f;
        f = f < 0.0f ? 0.0f : f > 1.0f ? 1.0f : f;
        code |= morton_spread((uint32_t)(f * 1023.0f)) << k;
    }
    return code;
}

typedef struct sort_key {
    uint64_t key;
    uint32_t index;
} sort_key_t;

static int sort_key_cmp(const void *a, const void *b)
{
    const sort_key_t *x = a, *y = b;
    if (x->key != y->key)
        return x->key < y->key ? -1 : 1;
    return x->index < y->index ? -1 : x->index > y->index;
}

/* A copy of b sorted by direction octant, then the origin's Morton code
 * in the batch's bounds: rays that start close together and go the same
 * way become neighbours. */
static int batch_sorted(const batch_t *b, batch_t *out)
{
    if (batch_init(out, b->count ? b->count : 1) < 0)
        return -1;
    sort_key_t *keys = malloc((b->count ? b->count : 1) * sizeof *keys);
    if (!keys) {
        batch_free(out);
        return -1;
    }
    float lo[3], hi[3];
    bounds_empty(lo, hi);
    for (size_t i = 0; i < b->count; i++)
        bounds_grow(lo, hi, b->rays[i].o);
    for (size_t i = 0; i < b->count; i++) {
        const bray_t *r = &b->rays[i];
        uint64_t octant = (uint64_t)((r->d[0] < 0) | (r->d[1] < 0) << 1 | (r->d[2] < 0) << 2);
        keys[i].key = octant << 32 | morton_code(r->o, lo, hi);
        keys[i].index = (uint32_t)i;
    }
    qsort(keys, b->count, sizeof *keys, sort_key_cmp);
    for (size_t i = 0; i < b->count; i++)
        out->rays[i] = b->rays[keys[i].index];
    out->count = b->count;
    free(keys);
    return 0;
}

/* Triangles in clusters of TRILIST_BLOCK-sized lists, each one Embree user
 * primitive: Embree's BVH finds the clusters a ray may hit, trilist's
 * watertight kernel tests their triangles. */
#define CLUSTER_TRIANGLES 16

typedef struct clusters {
    trilist_t **lists;
    uint32_t *tri; /* the scene's triangle of each clustered one, cluster by cluster */
    float *bounds; /* 6 per cluster, padded outwards: Embree's non-robust
                    * traversal must not skip a cluster a ray grazes */
    size_t count;
} clusters_t;

static void clusters_free(clusters_t *c)
{
    for (size_t i = 0; c->lists && i < c->count; i++)
        trilist_destroy(&c->lists[i]);
    free(c->lists);
    free(c->tri);
    free(c->bounds);
    memset(c, 0, sizeof *c);
}

static void cluster_bounds_fn(const struct RTCBoundsFunctionArguments *args)
{
    const clusters_t *c = args->geometryUserPtr;
    const float *b = c->bounds + 6 * (size_t)args->primID;
    args->bounds_o->lower_x = b[0];
    args->bounds_o->lower_y = b[1];
    args->bounds_o->lower_z = b[2];
    args->bounds_o->upper_x = b[3];
    args->bounds_o->upper_y = b[4];
    args->bounds_o->upper_z = b[5];
}

static void cluster_intersect_fn(const struct RTCIntersectFunctionNArguments *args)
{
    if (args->N != 1 || !args->valid[0])
        return;
    const clusters_t *c = args->geometryUserPtr;
    struct RTCRayHit *rh = (struct RTCRayHit *)args->rayhit;
    vec3_t o = vec3_make(rh->ray.org_x, rh->ray.org_y, rh->ray.org_z);
    vec3_t d = vec3_make(rh->ray.dir_x, rh->ray.dir_y, rh->ray.dir_z);
    uint32_t k;
    float t, u, v;
    if (!trilist_intersect(c->lists[args->primID], o, d, rh->ray.tfar, &k, &t, &u, &v))
        return;
    rh->ray.tfar = t;
    rh->hit.u = u;
    rh->hit.v = v;
    rh->hit.primID = c->tri[(size_t)args->primID * CLUSTER_TRIANGLES + k];
    rh->hit.geomID = args->geomID;
    rh->hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
}

static void cluster_occluded_fn(const struct RTCOccludedFunctionNArguments *args)
{
    if (args->N != 1 || !args->valid[0])
        return;
    const clusters_t *c = args->geometryUserPtr;
    struct RTCRay *r = (struct RTCRay *)args->ray;
    if (trilist_occluded(c->lists[args->primID], vec3_make(r->org_x, r->org_y, r->org_z),
                         vec3_make(r->dir_x, r->dir_y, r->dir_z), r->tfar))
        r->tfar = -INFINITY;
}

/* e: the device and a BVH (high quality, default flags) over s's triangles
 * in Morton order of their centroids, CLUSTER_TRIANGLES to a cluster. */
static int clusters_build(const scene_t *s, embree_t *e, clusters_t *c)
{
    memset(c, 0, sizeof *c);
    size_t n = s->triangle_count;
    c->count = (n + CLUSTER_TRIANGLES - 1) / CLUSTER_TRIANGLES;
    sort_key_t *keys = malloc((n ? n : 1) * sizeof *keys);
    uint32_t *idx = malloc((n ? 3 * n : 1) * sizeof *idx);
    c->lists = calloc(c->count ? c->count : 1, sizeof *c->lists);
    c->tri = calloc(c->count * CLUSTER_TRIANGLES + 1, sizeof *c->tri);
    c->bounds = malloc((c->count ? 6 * c->count : 1) * sizeof *c->bounds);
    if (!keys || !idx || !c->lists || !c->tri || !c->bounds) {
        free(keys);
        free(idx);
        clusters_free(c);
        return -1;
    }
    float lo[3], hi[3];
    bounds_empty(lo, hi);
    for (size_t i = 0; i < s->vertex_count; i++)
        bounds_grow(lo, hi, s->positions + 3 * i);
    for (size_t t = 0; t < n; t++) {
        float centroid[3] = {0, 0, 0};
        for (int j = 0; j < 3; j++)
            for (int k = 0; k < 3; k++)
                centroid[k] += s->positions[3 * s->indices[3 * t + j] + k] / 3.0f;
        keys[t].key = morton_code(centroid, lo, hi);
        keys[t].index = (uint32_t)t;
    }
    qsort(keys, n, sizeof *keys, sort_key_cmp);
    for (size_t t = 0; t < n; t++)
        for (int j = 0; j < 3; j++)
            idx[3 * t + j] = s->indices[3 * keys[t].index + j];
    int rc = 0;
    for (size_t i = 0; i < c->count && rc == 0; i++) {
        size_t first = i * CLUSTER_TRIANGLES, m = n - first;
        if (m > CLUSTER_TRIANGLES)
            m = CLUSTER_TRIANGLES;
        c->lists[i] = trilist_new(s->positions, idx + 3 * first, m);
        if (!c->lists[i] || use_kernels_isa(e->kernels_isa, c->lists[i], NULL) < 0)
            rc = -1;
        float *b = c->bounds + 6 * i;
        bounds_empty(b, b + 3);
        for (size_t t = first; t < first + m; t++) {
            c->tri[t] = keys[t].index;
            for (int j = 0; j < 3; j++)
                bounds_grow(b, b + 3, s->positions + 3 * idx[3 * t + j]);
        }
        for (int k = 0; k < 3; k++) {
            float pad = 1e-5f * (fabsf(b[k]) + fabsf(b[3 + k])) + 1e-30f;
            b[k] -= pad;
            b[3 + k] += pad;
        }
    }
    free(keys);
    free(idx);
    if (rc < 0) {
        clusters_free(c);
        return -1;
    }
    if (embree_device_new(e) < 0) {
        clusters_free(c);
        return -1;
    }
    e->scene = rtcNewScene(e->device);
    rtcSetSceneBuildQuality(e->scene, RTC_BUILD_QUALITY_HIGH);
    RTCGeometry g = rtcNewGeometry(e->device, RTC_GEOMETRY_TYPE_USER);
    rtcSetGeometryUserPrimitiveCount(g, (unsigned)c->count);
    rtcSetGeometryUserData(g, c);
    rtcSetGeometryBoundsFunction(g, cluster_bounds_fn, c);
    rtcSetGeometryIntersectFunction(g, cluster_intersect_fn);
    rtcSetGeometryOccludedFunction(g, cluster_occluded_fn);
    rtcCommitGeometry(g);
    rtcAttachGeometry(e->scene, g);
    rtcReleaseGeometry(g);
    rtcCommitScene(e->scene);
    return rtcGetDeviceError(e->device) == RTC_ERROR_NONE ? 0 : -1;
}

/* ---- reporting ------------------------------------------------------------ */

/* Rate of a mix of two kinds of rays: the time per ray is the weighted
 * mean of the per-kind times. */
static double mix_rate(double f_ext, double r_ext, double r_sh)
{
    if (!(r_ext > 0))
        return 0;
    if (!(r_sh > 0) || f_ext >= 1.0)
        return r_ext;
    return 1.0 / (f_ext / r_ext + (1.0 - f_ext) / r_sh);
}

static cJSON *raw_json(const raw_result_t *r, int threads)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddNumberToObject(o, "rays", (double)r->rays);
    cJSON_AddNumberToObject(o, "seconds_best", r->seconds_best);
    cJSON_AddNumberToObject(o, "rays_per_second", r->rays_per_second);
    cJSON_AddNumberToObject(o, "rays_per_second_per_core", r->rays_per_second / threads);
    cJSON_AddNumberToObject(o, "hit_fraction", r->hit_fraction);
    cJSON_AddNumberToObject(o, "cpu_utilization", r->utilization);
    return o;
}

typedef struct dist_result {
    raw_result_t ext, sh;
    double mix, mix_5050;
} dist_result_t;

static cJSON *dist_json(const dist_result_t *d, int threads, const char *how)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "distribution", how);
    cJSON_AddItemToObject(o, "extension", raw_json(&d->ext, threads));
    cJSON_AddItemToObject(o, "shadow", raw_json(&d->sh, threads));
    cJSON_AddNumberToObject(o, "mix_rays_per_second", d->mix);
    cJSON_AddNumberToObject(o, "mix_rays_per_second_per_core", d->mix / threads);
    cJSON_AddNumberToObject(o, "mix_5050_rays_per_second", d->mix_5050);
    return o;
}

static const char *base_name(const char *path, char *buf, size_t len)
{
    const char *b = strrchr(path, '/');
    snprintf(buf, len, "%s", b ? b + 1 : path);
    char *dot = strrchr(buf, '.');
    if (dot)
        *dot = '\0';
    return buf;
}

/* ---- main ------------------------------------------------------------------ */

typedef struct args {
    const char *scene, *json;
    const char *isa; /* our kernels' ISA (tracer_use_isa), NULL: the widest */
    uint64_t threads, spp, runs, rays;
    tracer_engine_t engine;
    rng_sampler_t sampler;
    int our_roulette; /* the scene's rr_threshold and rr_cap, else Mitsuba's */
} args_t;

static int parse_args(int argc, char **argv, args_t *a)
{
    memset(a, 0, sizeof *a);
    a->threads = 1;
    a->spp = 64;
    a->runs = 3;
    a->rays = 2000000;
    for (int i = 1; i < argc; i++) {
        const char *o = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(o, "-h") == 0 || strcmp(o, "--help") == 0) {
            fputs(usage_text, stdout);
            return 1;
        } else if (strcmp(o, "--scene") == 0) {
            if (!v)
                return usage_error("--scene needs a file", NULL);
            a->scene = v;
        } else if (strcmp(o, "--engine") == 0) {
            if (v && strcmp(v, "wavefront") == 0)
                a->engine = TRACER_ENGINE_WAVEFRONT;
            else if (v && strcmp(v, "scalar") == 0)
                a->engine = TRACER_ENGINE_SCALAR;
            else
                return usage_error("--engine needs wavefront or scalar, got", v ? v : "nothing");
        } else if (strcmp(o, "--sampler") == 0) {
            int smp = v ? tracer_sampler_from_name(v) : -1;
            if (smp < 0)
                return usage_error("--sampler needs independent or sobol, got", v ? v : "nothing");
            a->sampler = (rng_sampler_t)smp;
        } else if (strcmp(o, "--roulette") == 0) {
            if (v && strcmp(v, "mitsuba") == 0)
                a->our_roulette = 0;
            else if (v && strcmp(v, "ours") == 0)
                a->our_roulette = 1;
            else
                return usage_error("--roulette needs mitsuba or ours, got", v ? v : "nothing");
        } else if (strcmp(o, "--isa") == 0) {
            if (!v || (strcmp(v, "avx512") != 0 && strcmp(v, "avx2") != 0))
                return usage_error("--isa needs avx512 or avx2, got", v ? v : "nothing");
            a->isa = v;
        } else if (strcmp(o, "--json") == 0) {
            if (!v)
                return usage_error("--json needs a file", NULL);
            a->json = v;
        } else if (strcmp(o, "--threads") == 0) {
            if (parse_u64(v, 1, RENDER_MAX_THREADS, &a->threads) < 0)
                return usage_error("--threads needs an integer from 1 to 256, got",
                                   v ? v : "nothing");
        } else if (strcmp(o, "--spp") == 0) {
            if (parse_u64(v, 1, 1u << 20, &a->spp) < 0)
                return usage_error("--spp needs an integer from 1 to 1048576, got",
                                   v ? v : "nothing");
        } else if (strcmp(o, "--runs") == 0) {
            if (parse_u64(v, 1, MAX_RUNS - EXTRA_RUNS, &a->runs) < 0)
                return usage_error("--runs needs an integer from 1 to 97, got", v ? v : "nothing");
        } else if (strcmp(o, "--rays") == 0) {
            if (parse_u64(v, 1000, 100000000, &a->rays) < 0)
                return usage_error("--rays needs an integer from 1000 to 100000000, got",
                                   v ? v : "nothing");
        } else {
            return usage_error("unknown argument", o);
        }
        i++;
    }
    if (!a->scene)
        return usage_error("--scene is required", NULL);
    return 0;
}

/* One render_run on a fresh film; returns seconds or -1, and the CPU
 * utilization in *util. */
static double render_once(const tracer_t *tr, const scene_t *s, scene_integrator_t integ,
                          rng_sampler_t sampler, uint32_t spp, int threads, render_summary_t *sum,
                          double *util)
{
    film_t *film = film_new(s->camera.width, s->camera.height);
    if (!film)
        return -1;
    render_settings_t rs;
    memset(&rs, 0, sizeof rs);
    rs.tracer.seed = s->seed;
    rs.tracer.integrator = integ;
    rs.tracer.sampler = sampler;
    rs.tracer.max_depth = s->max_depth;
    rs.spp = spp;
    rs.granularity = RENDER_DEFAULT_GRANULARITY;
    rs.threads = threads;
    rs.progress = PROGRESS_NONE;
    rs.progress_out = NULL;
    char err[VB_ERR_LEN];
    double c0 = cpu_seconds();
    int rc = render_run(tr, film, &rs, sum, err, sizeof err);
    double cpu = cpu_seconds() - c0;
    *util = sum->seconds > 0 ? cpu / (sum->seconds * threads) : 0;
    film_destroy(&film);
    if (rc < 0) {
        fprintf(stderr, "bench_core: render failed: %s\n", err);
        return -1;
    }
    return sum->seconds;
}

/* Our renderer's figures: best of the timed renders, and the ray mix. */
typedef struct ours {
    double times[MAX_RUNS], utils[MAX_RUNS], best, best_util;
    int nruns;
    uint64_t samples, rays, nonfinite;
    double sps, rps, rays_per_sample, ext_per_sample, f_ext;
    long rss_render;
} ours_t;

/* Renders until `runs` runs, and up to EXTRA_RUNS more while none ran
 * undisturbed; then a small naive render for the extension-ray fraction:
 * the naive integrator traces the same extension rays (same path-length
 * distribution) and no shadow rays, so 8 spp give the fraction to 3 digits. */
static int measure_ours(const tracer_t *tr, const scene_t *s, const args_t *a, ours_t *o)
{
    const int threads = (int)a->threads, runs = (int)a->runs;
    memset(o, 0, sizeof *o);
    o->best = INFINITY;
    render_summary_t sum;
    while (o->nruns < runs || (o->best_util < UNDISTURBED && o->nruns < runs + EXTRA_RUNS)) {
        double util;
        double t = render_once(tr, s, SCENE_INTEGRATOR_PATH, a->sampler, (uint32_t)a->spp, threads,
                               &sum, &util);
        if (t < 0)
            return -1;
        o->times[o->nruns] = t;
        o->utils[o->nruns] = util;
        if (t < o->best) {
            o->best = t;
            o->best_util = util;
        }
        o->samples = sum.samples;
        o->rays = sum.rays;
        o->nonfinite = sum.nonfinite;
        fprintf(stderr, "  render %d: %.3f s, CPU %.0f%% of %d core(s)%s\n", o->nruns, t,
                100 * util, threads,
                util < UNDISTURBED ? " (disturbed: another process had the CPU)" : "");
        o->nruns++;
    }
    render_summary_t nsum;
    double nutil;
    if (render_once(tr, s, SCENE_INTEGRATOR_NAIVE, a->sampler, 8, threads, &nsum, &nutil) < 0)
        return -1;
    o->rss_render = peak_rss_kb();
    o->sps = (double)o->samples / o->best;
    o->rps = (double)o->rays / o->best;
    o->rays_per_sample = (double)o->rays / (double)o->samples;
    o->ext_per_sample = (double)nsum.rays / (double)nsum.samples;
    if (o->ext_per_sample > o->rays_per_sample)
        o->ext_per_sample = o->rays_per_sample;
    o->f_ext = o->ext_per_sample / o->rays_per_sample;
    fprintf(
        stderr,
        "  ours: %.3f s best, %.3f M samples/s, %.3f M rays/s, %.3f rays/sample (%.3f extension)\n",
        o->best, o->sps / 1e6, o->rps / 1e6, o->rays_per_sample, o->ext_per_sample);
    return 0;
}

/* Raw Embree on two ray distributions; dist[0] ("path") also on a BVH
 * without ROBUST (into *fast). */
typedef struct raw {
    dist_result_t dist[2], fast, list, sorted, user, one_by_one, own, packets;
    int runs;
    long rss_total;
} raw_t;

static void print_dist(const char *name, double tgen, const dist_result_t *d)
{
    fprintf(stderr,
            "  raw %s (%.1f s to build): extension %.3f M rays/s (%.0f%% hit), shadow %.3f M "
            "rays/s (%zu rays, %.0f%% occluded), our mix %.3f M rays/s; CPU %.0f%% / %.0f%%%s\n",
            name, tgen, d->ext.rays_per_second / 1e6, 100 * d->ext.hit_fraction,
            d->sh.rays_per_second / 1e6, d->sh.rays, 100 * d->sh.hit_fraction, d->mix / 1e6,
            100 * d->ext.utilization, 100 * d->sh.utilization,
            d->ext.utilization < UNDISTURBED || d->sh.utilization < UNDISTURBED ? " (disturbed)"
                                                                                : "");
}

/* One more way of casting the path rays, after print_dist's line. */
static void print_way(const char *way, const dist_result_t *d)
{
    fprintf(
        stderr,
        "  raw path, %s: extension %.3f M rays/s, shadow %.3f M rays/s, our mix %.3f M rays/s\n",
        way, d->ext.rays_per_second / 1e6, d->sh.rays_per_second / 1e6, d->mix / 1e6);
}

static void set_mix(dist_result_t *d, double f_ext)
{
    d->mix = mix_rate(f_ext, d->ext.rays_per_second, d->sh.rays_per_second);
    d->mix_5050 = mix_rate(0.5, d->ext.rays_per_second, d->sh.rays_per_second);
}

/* The path rays sorted on the ROBUST BVH, and on clusters tested by the
 * watertight list kernel (r->sorted, r->user). */
static int measure_other_ways(const scene_t *s, const embree_t *e, const batch_t *ext,
                              const batch_t *sh, int threads, double f_ext, raw_t *r)
{
    batch_t sext, ssh;
    if (batch_sorted(ext, &sext) < 0)
        return -1;
    if (batch_sorted(sh, &ssh) < 0) {
        batch_free(&sext);
        return -1;
    }
    embree_t robust = *e; /* Embree's packets, whatever the tracer uses */
    robust.tracer_bvh = NULL;
    int rc = raw_time(&robust, &sext, 0, threads, r->runs, &r->sorted.ext) < 0 ||
                     raw_time(&robust, &ssh, 1, threads, r->runs, &r->sorted.sh) < 0
                 ? -1
                 : 0;
    batch_free(&sext);
    batch_free(&ssh);
    if (rc < 0)
        return -1;
    if (!e->tracer_bvh) {
        /* (where the tracer uses it, dist[0] already is this way) */
        embree_t eo = *e;
        char err[256];
        double tb = now_seconds();
        eo.tracer_bvh =
            bvh_new(e->device, s->positions, s->indices, s->triangle_count, err, sizeof err);
        tb = now_seconds() - tb;
        if (!eo.tracer_bvh) {
            fprintf(stderr, "bench_core: %s\n", err);
            return -1;
        }
        if (use_kernels_isa(e->kernels_isa, NULL, eo.tracer_bvh) < 0) {
            bvh_destroy(&eo.tracer_bvh);
            return -1;
        }
        if (raw_time(&eo, ext, 0, threads, r->runs, &r->own.ext) < 0 ||
            raw_time(&eo, sh, 1, threads, r->runs, &r->own.sh) < 0)
            rc = -1;
        set_mix(&r->own, f_ext);
        fprintf(stderr,
                "  raw path, our watertight traversal of Embree's BVH (%.2f s to build, %.1f MB): "
                "extension %.3f, shadow %.3f, our mix %.3f M rays/s (%.4f%% hit, Embree "
                "%.4f%%; %.4f%% occluded, Embree %.4f%%)\n",
                tb, bvh_bytes(eo.tracer_bvh) / 1e6, r->own.ext.rays_per_second / 1e6,
                r->own.sh.rays_per_second / 1e6, r->own.mix / 1e6, 100 * r->own.ext.hit_fraction,
                100 * r->dist[0].ext.hit_fraction, 100 * r->own.sh.hit_fraction,
                100 * r->dist[0].sh.hit_fraction);
        bvh_destroy(&eo.tracer_bvh);
    } else {
        r->own = r->dist[0];
    }
    embree_t eu;
    clusters_t c;
    memset(&eu, 0, sizeof eu);
    eu.one_by_one = 1; /* the callbacks take one ray */
    eu.kernels_isa = e->kernels_isa;
    if (clusters_build(s, &eu, &c) < 0) {
        fprintf(stderr, "bench_core: cannot build the clustered scene\n");
        embree_free(&eu);
        return -1;
    }
    if (raw_time(&eu, ext, 0, threads, r->runs, &r->user.ext) < 0 ||
        raw_time(&eu, sh, 1, threads, r->runs, &r->user.sh) < 0)
        rc = -1;
    embree_free(&eu);
    clusters_free(&c);
    if (rc == 0) {
        set_mix(&r->sorted, f_ext);
        set_mix(&r->user, f_ext);
        fprintf(stderr,
                "  raw path, ROBUST, rays sorted (sort not timed): extension %.3f, shadow %.3f, "
                "our mix %.3f M rays/s\n"
                "  raw path, watertight clusters of %d (user geometry): extension %.3f, shadow "
                "%.3f, our mix %.3f M rays/s (%zu of %zu hits as ROBUST)\n",
                r->sorted.ext.rays_per_second / 1e6, r->sorted.sh.rays_per_second / 1e6,
                r->sorted.mix / 1e6, CLUSTER_TRIANGLES, r->user.ext.rays_per_second / 1e6,
                r->user.sh.rays_per_second / 1e6, r->user.mix / 1e6,
                (size_t)(r->user.ext.hit_fraction * (double)ext->count + 0.5),
                (size_t)(r->dist[0].ext.hit_fraction * (double)ext->count + 0.5));
    }
    return rc < 0 ? -1 : 0;
}

/* One distribution (k = 0 path rays, 1 area rays) on the ROBUST BVH, and
 * for k = 0 also on the fast one. */
static int measure_dist(const scene_t *s, const args_t *a, int k, const embree_t *e,
                        const embree_t *efast, const embree_t *elist, double f_ext, raw_t *r)
{
    const int threads = (int)a->threads;
    batch_t ext, sh;
    if (batch_init(&ext, a->rays) < 0 || batch_init(&sh, a->rays) < 0) {
        fprintf(stderr, "bench_core: out of memory for %" PRIu64 " rays\n", a->rays);
        return -1;
    }
    double t0 = now_seconds();
    if (k == 0)
        build_path_batch(s, e, s->seed + 1000, &ext, &sh);
    else if (build_area_batch(s, s->seed + 2000, &ext, &sh) < 0) {
        fprintf(stderr, "bench_core: out of memory\n");
        return -1;
    }
    double tgen = now_seconds() - t0;
    dist_result_t *d = &r->dist[k];
    if (raw_time(e, &ext, 0, threads, r->runs, &d->ext) < 0 ||
        raw_time(e, &sh, 1, threads, r->runs, &d->sh) < 0 ||
        (k == 0 && (raw_time(efast, &ext, 0, threads, r->runs, &r->fast.ext) < 0 ||
                    raw_time(efast, &sh, 1, threads, r->runs, &r->fast.sh) < 0)) ||
        (k == 0 && elist->list &&
         (raw_time(elist, &ext, 0, threads, r->runs, &r->list.ext) < 0 ||
          raw_time(elist, &sh, 1, threads, r->runs, &r->list.sh) < 0))) {
        fprintf(stderr, "bench_core: cannot start threads\n");
        return -1;
    }
    set_mix(d, f_ext);
    print_dist(k == 0 ? "path" : "area", tgen, d);
    if (k == 0) {
        set_mix(&r->fast, f_ext);
        print_way("BVH without ROBUST", &r->fast);
    }
    if (k == 0 && !elist->list && e->tracer_bvh) {
        embree_t packets = *e;
        packets.tracer_bvh = NULL;
        if (raw_time(&packets, &ext, 0, threads, r->runs, &r->packets.ext) < 0 ||
            raw_time(&packets, &sh, 1, threads, r->runs, &r->packets.sh) < 0) {
            fprintf(stderr, "bench_core: cannot start threads\n");
            batch_free(&ext);
            batch_free(&sh);
            return -1;
        }
        set_mix(&r->packets, f_ext);
        print_way("ROBUST, Embree's packets for both kinds (the tracer before bvh.h)", &r->packets);
    }
    if (k == 0 && !elist->list) {
        embree_t single = *e;
        single.tracer_bvh = NULL;
        single.one_by_one = 1;
        if (raw_time(&single, &ext, 0, threads, r->runs, &r->one_by_one.ext) < 0 ||
            raw_time(&single, &sh, 1, threads, r->runs, &r->one_by_one.sh) < 0) {
            fprintf(stderr, "bench_core: cannot start threads\n");
            batch_free(&ext);
            batch_free(&sh);
            return -1;
        }
        set_mix(&r->one_by_one, f_ext);
        print_way("one ray a call (rtcIntersect1/rtcOccluded1)", &r->one_by_one);
    }
    if (k == 0 && !elist->list && measure_other_ways(s, e, &ext, &sh, threads, f_ext, r) < 0) {
        batch_free(&ext);
        batch_free(&sh);
        return -1;
    }
    if (k == 0 && elist->list) {
        set_mix(&r->list, f_ext);
        fprintf(stderr,
                "  raw path, triangle list (%s kernel, no BVH): extension %.3f M rays/s, shadow "
                "%.3f M rays/s, our mix %.3f M rays/s\n",
                trilist_kernel(elist->list), r->list.ext.rays_per_second / 1e6,
                r->list.sh.rays_per_second / 1e6, r->list.mix / 1e6);
    }
    batch_free(&ext);
    batch_free(&sh);
    return 0;
}

/* Raw Embree, after the renders so the batches do not count in the
 * renderer's peak memory. */
static int measure_raw(const scene_t *s, const args_t *a, double f_ext, raw_t *r)
{
    memset(r, 0, sizeof *r);
    r->runs = (int)a->runs > RAW_MIN_RUNS ? (int)a->runs : RAW_MIN_RUNS;
    embree_t e, efast, elist;
    memset(&e, 0, sizeof e);
    memset(&efast, 0, sizeof efast);
    memset(&elist, 0, sizeof elist);
    int rc = 0;
    e.kernels_isa = a->isa;
    if (embree_build(s, &e, 1) < 0 || embree_build(s, &efast, 0) < 0) {
        fprintf(stderr, "bench_core: cannot build the Embree scene\n");
        rc = -1;
    }
    char err[256];
    if (rc == 0 && tracer_accel_for(s) == TRACER_ACCEL_BVH) {
        e.tracer_bvh =
            bvh_new(e.device, s->positions, s->indices, s->triangle_count, err, sizeof err);
        if (!e.tracer_bvh) {
            fprintf(stderr, "bench_core: %s\n", err);
            rc = -1;
        } else if (use_kernels_isa(a->isa, NULL, e.tracer_bvh) < 0) {
            rc = -1;
        }
    }
    /* the list only where the tracer uses it: on a big scene it is 100x
     * slower than the BVH and would take minutes for nothing */
    if (tracer_accel_for(s) == TRACER_ACCEL_TRILIST) {
        elist.list = trilist_new(s->positions, s->indices, s->triangle_count);
        if (!elist.list) {
            fprintf(stderr, "bench_core: out of memory\n");
            rc = -1;
        } else if (use_kernels_isa(a->isa, elist.list, NULL) < 0) {
            rc = -1;
        }
    }
    for (int k = 0; k < 2 && rc == 0; k++)
        rc = measure_dist(s, a, k, &e, &efast, &elist, f_ext, r);
    r->rss_total = peak_rss_kb();
    bvh_destroy(&e.tracer_bvh);
    embree_free(&e);
    embree_free(&efast);
    trilist_destroy(&elist.list);
    return rc;
}

static cJSON *ours_json(const ours_t *o, const args_t *a, const scene_t *s, int threads)
{
    cJSON *j = cJSON_CreateObject();
    cJSON_AddStringToObject(j, "integrator", "path");
    cJSON_AddNumberToObject(j, "spp", (double)a->spp);
    cJSON_AddNumberToObject(j, "granularity", RENDER_DEFAULT_GRANULARITY);
    cJSON_AddNumberToObject(j, "seed", (double)s->seed);
    cJSON_AddItemToObject(j, "seconds_all", cJSON_CreateDoubleArray(o->times, o->nruns));
    cJSON_AddItemToObject(j, "cpu_utilization_all", cJSON_CreateDoubleArray(o->utils, o->nruns));
    cJSON_AddNumberToObject(j, "seconds_best", o->best);
    cJSON_AddNumberToObject(j, "cpu_utilization", o->best_util);
    cJSON_AddNumberToObject(j, "samples", (double)o->samples);
    cJSON_AddNumberToObject(j, "rays", (double)o->rays);
    cJSON_AddNumberToObject(j, "nonfinite", (double)o->nonfinite);
    cJSON_AddNumberToObject(j, "samples_per_second", o->sps);
    cJSON_AddNumberToObject(j, "samples_per_second_per_core", o->sps / threads);
    cJSON_AddNumberToObject(j, "rays_per_second", o->rps);
    cJSON_AddNumberToObject(j, "rays_per_second_per_core", o->rps / threads);
    cJSON_AddNumberToObject(j, "rays_per_sample", o->rays_per_sample);
    cJSON_AddNumberToObject(j, "extension_rays_per_sample", o->ext_per_sample);
    cJSON_AddNumberToObject(j, "shadow_rays_per_sample", o->rays_per_sample - o->ext_per_sample);
    cJSON_AddNumberToObject(j, "extension_fraction", o->f_ext);
    cJSON_AddStringToObject(j, "mix_method",
                            "extension rays/sample from a naive-integrator render "
                            "at 8 spp; shadow = path - naive");
    return j;
}

/* d under key, if that measurement was made on this scene. */
static void add_dist_if_run(cJSON *j, const char *key, const dist_result_t *d, int threads,
                            const char *how)
{
    if (d->ext.rays)
        cJSON_AddItemToObject(j, key, dist_json(d, threads, how));
}

static cJSON *raw_embree_json(const raw_t *r, const args_t *a, int threads)
{
    cJSON *j = cJSON_CreateObject();
    cJSON_AddNumberToObject(j, "rays_per_batch", (double)a->rays);
    cJSON_AddNumberToObject(j, "runs", r->runs);
    cJSON_AddItemToObject(
        j, "path",
        dist_json(&r->dist[0], threads,
                  "rays of random walks from the camera (diffuse bounces, through glass), as the "
                  "path integrator "
                  "traces them (camera, bounce and next-event shadow rays), cast as the tracer "
                  "casts them: on a scene the tracer casts through our watertight traversal of a "
                  "BVH Embree builds (accel \"bvh\"), that; otherwise Embree packets of "
                  "consecutive rays (TRACER_PACKET)"));
    add_dist_if_run(j, "path_embree_packets", &r->packets, threads,
                    "the path rays on the ROBUST BVH in Embree packets of 8, as the tracer casts "
                    "them on a scene with smooth glass (and cast them all before bvh.h)");
    add_dist_if_run(j, "path_own_bvh", &r->own, threads,
                    "the path rays, both kinds, by our watertight traversal of a BVH Embree "
                    "builds (bvh.h), one ray a call");
    add_dist_if_run(j, "path_one_by_one", &r->one_by_one, threads,
                    "the path rays on the ROBUST BVH one ray a call (rtcIntersect1 / "
                    "rtcOccluded1), as the tracer cast them before packets");
    cJSON_AddItemToObject(j, "area",
                          dist_json(&r->dist[1], threads,
                                    "origins uniform by area on non-black-emitter triangles, "
                                    "cosine directions about the winding normal; shadow rays to "
                                    "uniform light points where both sides face each other"));
    cJSON_AddItemToObject(j, "path_not_robust",
                          dist_json(&r->fast, threads,
                                    "the path rays on a BVH built without RTC_SCENE_FLAG_ROBUST "
                                    "(reference: what the flag costs)"));
    add_dist_if_run(j, "path_sorted", &r->sorted, threads,
                    "the path rays on the ROBUST BVH, sorted by direction octant and origin "
                    "Morton code (sort not timed)");
    add_dist_if_run(j, "path_watertight_user", &r->user, threads,
                    "the path rays on a BVH (default flags) over user geometry: clusters of 16 "
                    "triangles in Morton order, each tested by the watertight trilist kernel");
    add_dist_if_run(j, "path_triangle_list", &r->list, threads,
                    "the path rays on every triangle without a BVH (trilist.h, what the tracer "
                    "uses up to TRILIST_MAX_TRIANGLES)");
    return j;
}

static int write_json(const char *path, const args_t *a, const char *name, const scene_t *s,
                      const tracer_t *tr, const ours_t *o, const raw_t *r, int disturbed)
{
    const int threads = (int)a->threads;
    const double rps = o->rps;
    cJSON *root = cJSON_CreateObject();
    cJSON_AddStringToObject(root, "scene", a->scene);
    cJSON_AddStringToObject(root, "scene_name", name);
    cJSON_AddNumberToObject(root, "triangles", (double)s->triangle_count);
    cJSON_AddNumberToObject(root, "lights", (double)s->light_count);
    cJSON_AddNumberToObject(root, "width", s->camera.width);
    cJSON_AddNumberToObject(root, "height", s->camera.height);
    cJSON_AddNumberToObject(root, "threads", threads);
    cJSON_AddStringToObject(root, "isa", tracer_isa(tr));
    /* the kernel our own code casts with (the list's or our traversal's),
     * none where Embree casts every ray */
    cJSON_AddStringToObject(root, "kernels_isa",
                            tr->small ? trilist_kernel(tr->small)
                            : tr->bvh ? bvh_kernel(tr->bvh)
                                      : "none");
    /* the paths the diffuse shading takes at once (its build: 16, 8, 4) */
    cJSON_AddNumberToObject(root, "shading_lanes", tracer_shading_lanes(tr));
    cJSON_AddStringToObject(root, "accel",
                            tracer_accel_for(s) == TRACER_ACCEL_TRILIST ? "trilist"
                            : tracer_accel_for(s) == TRACER_ACCEL_BVH   ? "bvh"
                                                                        : "embree");
    cJSON_AddStringToObject(root, "engine",
                            a->engine == TRACER_ENGINE_SCALAR ? "scalar" : "wavefront");
    cJSON_AddStringToObject(root, "sampler", tracer_sampler_name(a->sampler));
    cJSON_AddNumberToObject(root, "rr_threshold", s->rr_threshold);
    cJSON_AddNumberToObject(root, "rr_cap", s->rr_cap);
    cJSON_AddStringToObject(root, "embree_version", RTC_VERSION_STRING);
    cJSON_AddBoolToObject(root, "disturbed", disturbed);
    cJSON_AddItemToObject(root, "ours", ours_json(o, a, s, threads));
    cJSON_AddItemToObject(root, "raw_embree", raw_embree_json(r, a, threads));
    /* against what the tracer casts rays with: the list, or the BVH */
    const dist_result_t *own = r->list.ext.rays ? &r->list : &r->dist[0];
    cJSON_AddNumberToObject(root, "ratio_ours_over_raw", own->mix > 0 ? rps / own->mix : 0.0);
    cJSON_AddNumberToObject(root, "ratio_ours_over_raw_area",
                            r->dist[1].mix > 0 ? rps / r->dist[1].mix : 0.0);
    cJSON_AddNumberToObject(root, "ratio_ours_over_raw_5050",
                            r->dist[0].mix_5050 > 0 ? rps / r->dist[0].mix_5050 : 0.0);
    cJSON_AddNumberToObject(root, "peak_rss_kb_render", (double)o->rss_render);
    cJSON_AddNumberToObject(root, "peak_rss_kb_total", (double)r->rss_total);
    cJSON_AddNumberToObject(root, "pixels", (double)s->camera.width * (double)s->camera.height);

    char *text = cJSON_Print(root);
    FILE *f = fopen(path, "w");
    int bad = !text || !f || fputs(text, f) < 0 || fputc('\n', f) == EOF;
    if (f && fclose(f) != 0)
        bad = 1;
    cJSON_free(text);
    cJSON_Delete(root);
    if (bad) {
        fprintf(stderr, "bench_core: cannot write %s: %s\n", path, strerror(errno));
        return -1;
    }
    return 0;
}

static int run(const args_t *a, const char *name, const scene_t *s, const tracer_t *tr)
{
    const int threads = (int)a->threads;
    ours_t o;
    raw_t r;
    if (measure_ours(tr, s, a, &o) < 0 || measure_raw(s, a, o.f_ext, &r) < 0)
        return 1;
    const dist_result_t *d = r.list.ext.rays ? &r.list : &r.dist[0];
    const int disturbed = o.best_util < UNDISTURBED || d->ext.utilization < UNDISTURBED ||
                          d->sh.utilization < UNDISTURBED;
    printf("%-12s T=%d  ours %.3f M samples/s/core, %.3f M rays/s/core | raw %s (path rays) "
           "ext %.3f / shadow %.3f M rays/s/core, mix %.3f | ours/raw %.3f | peak %.1f MiB%s\n",
           name, threads, o.sps / threads / 1e6, o.rps / threads / 1e6,
           r.list.ext.rays ? "triangle list" : "Embree", d->ext.rays_per_second / threads / 1e6,
           d->sh.rays_per_second / threads / 1e6, d->mix / threads / 1e6,
           d->mix > 0 ? o.rps / d->mix : 0.0, (double)o.rss_render / 1024.0,
           disturbed ? " | DISTURBED" : "");
    if (a->json && write_json(a->json, a, name, s, tr, &o, &r, disturbed) < 0)
        return 1;
    return 0;
}

int main(int argc, char **argv)
{
    args_t a;
    int rc = parse_args(argc, argv, &a);
    if (rc)
        return rc == 1 ? 0 : rc;
    char err[VB_ERR_LEN], name[256];
    base_name(a.scene, name, sizeof name);
    scene_t *s = NULL;
    if (mitsuba_scene_load(a.scene, &s, err, sizeof err) < 0) {
        fprintf(stderr, "bench_core: %s\n", err);
        return 1;
    }
    /* the peer's roulette unless asked: samples/s compare like with like
     * only where both renderers trace the same paths */
    if (!a.our_roulette) {
        s->rr_threshold = 1.0f;
        s->rr_cap = 0.95f;
    }
    tracer_t *tr = NULL;
    tracer_device_t *dev = NULL;
    if (tracer_device_new(&dev, err, sizeof err) < 0 ||
        tracer_new(dev, s, &tr, err, sizeof err) < 0) {
        fprintf(stderr, "bench_core: %s\n", err);
        tracer_device_destroy(&dev);
        scene_destroy(&s);
        return 1;
    }
    tracer_use_engine(tr, a.engine);
    if (a.isa && tracer_use_isa(tr, a.isa) < 0) {
        fprintf(stderr, "bench_core: this host cannot run the %s kernels\n", a.isa);
        tracer_destroy(&tr);
        tracer_device_destroy(&dev);
        scene_destroy(&s);
        return 1;
    }
    fprintf(stderr,
            "bench_core: %s: %zu triangles, %zu lights, %dx%d, %d thread(s), %s%s%s, shading %d "
            "lanes, roulette threshold %g cap %g (%s)\n",
            name, s->triangle_count, s->light_count, s->camera.width, s->camera.height,
            (int)a.threads, tracer_isa(tr), a.isa ? ", our kernels " : "", a.isa ? a.isa : "",
            tracer_shading_lanes(tr), (double)s->rr_threshold, (double)s->rr_cap,
            a.our_roulette ? "ours" : "Mitsuba's");
    rc = run(&a, name, s, tr);
    tracer_destroy(&tr);
    tracer_device_destroy(&dev);
    scene_destroy(&s);
    return rc;
}
