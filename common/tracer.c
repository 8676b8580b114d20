/* tracer.c - Embree BVH, the two integrators and the per-pixel statistics.
 *
 * `path`: unidirectional path tracing with next-event estimation on the
 * emissive triangles, combined with BSDF sampling by multiple importance
 * sampling (power heuristic), and Russian roulette after TRACER_RR_DEPTH
 * bounces: unbiased, no depth clamp unless max_depth is set.
 * `naive`: the thesis's Procedure 1, radiance only when a path hits a light.
 * Both estimate the same integral, so they converge to the same image.
 *
 * Robustness: hit points come from barycentrics, new rays leave from a point
 * offset by the Wachter-Binder method along the geometric normal, so there is
 * no scene-scale epsilon; shading normals never let light through the
 * geometric surface; a NaN/Inf sample is counted and left out.
 */
#include "tracer.h"

#include <embree3/rtcore.h>
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "rng.h"

struct tracer_device {
    RTCDevice device;
    char isa[16];
    pthread_mutex_t lock; /* guards error: builds may run on several threads */
    char error[256];      /* last Embree error, written by the callback */
};

struct tracer {
    tracer_device_t *dev;
    RTCScene rtc;
    const scene_t *scene;
};

static void embree_error(void *user, enum RTCError code, const char *str)
{
    tracer_device_t *d = user;
    pthread_mutex_lock(&d->lock);
    snprintf(d->error, sizeof d->error, "Embree error %d: %s", (int)code, str ? str : "");
    pthread_mutex_unlock(&d->lock);
}

/* Takes (and clears) the device's last error; 1 if there was one. */
static int take_error(tracer_device_t *d, char *out, size_t len)
{
    pthread_mutex_lock(&d->lock);
    int had = d->error[0] != '\0';
    snprintf(out, len, "%s", had ? d->error : "unknown Embree failure");
    d->error[0] = '\0';
    pthread_mutex_unlock(&d->lock);
    return had;
}

int tracer_device_new(tracer_device_t **out, char *err, size_t errlen)
{
    *out = NULL;
    tracer_device_t *d = calloc(1, sizeof *d);
    if (!d) {
        snprintf(err, errlen, "out of memory");
        return -1;
    }
    pthread_mutex_init(&d->lock, NULL);
    /* Pin the ISA: Embree would otherwise pick the widest the CPU has, and
     * AVX-512 and AVX2 kernels may round a hit differently. Every x86-64
     * server since 2013 has AVX2; older hosts use SSE4.2, and the ISA is in
     * the build id a worker's HELLO carries, so a cluster refuses to mix. */
    __builtin_cpu_init();
    snprintf(d->isa, sizeof d->isa, "%s", __builtin_cpu_supports("avx2") ? "avx2" : "sse4.2");
    char config[64];
    snprintf(config, sizeof config, "isa=%s,verbose=0", d->isa);
    d->device = rtcNewDevice(config);
    if (!d->device) {
        snprintf(err, errlen, "cannot create the Embree device (%s): error %d", config,
                 (int)rtcGetDeviceError(NULL));
        pthread_mutex_destroy(&d->lock);
        free(d);
        return -1;
    }
    rtcSetDeviceErrorFunction(d->device, embree_error, d);
    *out = d;
    return 0;
}

void tracer_device_destroy(tracer_device_t **dp)
{
    if (!dp || !*dp)
        return;
    rtcReleaseDevice((*dp)->device);
    pthread_mutex_destroy(&(*dp)->lock);
    free(*dp);
    *dp = NULL;
}

const char *tracer_device_isa(const tracer_device_t *d)
{
    return d->isa;
}

int tracer_new(tracer_device_t *dev, const scene_t *scene, tracer_t **out, char *err, size_t errlen)
{
    *out = NULL;
    tracer_t *t = calloc(1, sizeof *t);
    if (!t) {
        snprintf(err, errlen, "out of memory");
        return -1;
    }
    t->dev = dev;
    t->scene = scene;
    char old[256];
    take_error(dev, old, sizeof old); /* start clean */
    t->rtc = rtcNewScene(dev->device);
    rtcSetSceneFlags(t->rtc, RTC_SCENE_FLAG_ROBUST);
    rtcSetSceneBuildQuality(t->rtc, RTC_BUILD_QUALITY_HIGH);
    RTCGeometry g = rtcNewGeometry(dev->device, RTC_GEOMETRY_TYPE_TRIANGLE);
    float *vb = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                        3 * sizeof(float), scene->vertex_count);
    uint32_t *ib = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                           3 * sizeof(uint32_t), scene->triangle_count);
    if (!vb || !ib) {
        char e[256];
        take_error(dev, e, sizeof e);
        snprintf(err, errlen, "cannot allocate Embree buffers: %s", e);
        rtcReleaseGeometry(g);
        tracer_destroy(&t);
        return -1;
    }
    memcpy(vb, scene->positions, scene->vertex_count * 3 * sizeof(float));
    memcpy(ib, scene->indices, scene->triangle_count * 3 * sizeof(uint32_t));
    rtcCommitGeometry(g);
    rtcAttachGeometry(t->rtc, g);
    rtcReleaseGeometry(g);
    rtcCommitScene(t->rtc);
    char e[256];
    if (take_error(dev, e, sizeof e)) {
        snprintf(err, errlen, "cannot build the BVH: %s", e);
        tracer_destroy(&t);
        return -1;
    }
    *out = t;
    return 0;
}

void tracer_destroy(tracer_t **tp)
{
    if (!tp || !*tp)
        return;
    tracer_t *t = *tp;
    if (t->rtc)
        rtcReleaseScene(t->rtc);
    free(t);
    *tp = NULL;
}

const char *tracer_isa(const tracer_t *t)
{
    return t->dev->isa;
}

/* ---- ray casting -------------------------------------------------------- */

typedef struct hit {
    uint32_t tri;
    float t, u, v;
} hit_t;

static inline int intersect(const tracer_t *tr, vec3_t o, vec3_t d, hit_t *h)
{
    struct RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    struct RTCRayHit rh;
    rh.ray.org_x = o.x;
    rh.ray.org_y = o.y;
    rh.ray.org_z = o.z;
    rh.ray.tnear = 0.0f;
    rh.ray.dir_x = d.x;
    rh.ray.dir_y = d.y;
    rh.ray.dir_z = d.z;
    rh.ray.time = 0.0f;
    rh.ray.tfar = INFINITY;
    rh.ray.mask = 0xffffffffu;
    rh.ray.id = 0;
    rh.ray.flags = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(tr->rtc, &ctx, &rh);
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID)
        return 0;
    h->tri = rh.hit.primID;
    h->t = rh.ray.tfar;
    h->u = rh.hit.u;
    h->v = rh.hit.v;
    return 1;
}

/* 1 if the segment o -> o + d (d unnormalised, t in [0, 1)) is free. */
static inline int unoccluded(const tracer_t *tr, vec3_t o, vec3_t d)
{
    struct RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    struct RTCRay r;
    r.org_x = o.x;
    r.org_y = o.y;
    r.org_z = o.z;
    r.tnear = 0.0f;
    r.dir_x = d.x;
    r.dir_y = d.y;
    r.dir_z = d.z;
    r.time = 0.0f;
    r.tfar = 0.99999f;
    r.mask = 0xffffffffu;
    r.id = 0;
    r.flags = 0;
    rtcOccluded1(tr->rtc, &ctx, &r);
    return r.tfar >= 0.0f;
}

static inline vec3_t vertex(const scene_t *s, uint32_t i)
{
    const float *p = s->positions + 3 * i;
    return vec3_make(p[0], p[1], p[2]);
}

static inline vec3_t vertex_normal(const scene_t *s, uint32_t i)
{
    const float *p = s->normals + 3 * i;
    return vec3_make(p[0], p[1], p[2]);
}

static inline vec3_t lerp3(vec3_t a, vec3_t b, vec3_t c, float u, float v)
{
    float w = 1.0f - u - v;
    return vec3_make(w * a.x + u * b.x + v * c.x, w * a.y + u * b.y + v * c.y,
                     w * a.z + u * b.z + v * c.z);
}

/* Picks an emissive triangle by power and a uniform point on it. */
static inline uint32_t sample_light(const scene_t *s, double u, float u1, float u2, vec3_t *q)
{
    size_t lo = 0, hi = s->light_count - 1;
    while (lo < hi) {
        size_t mid = (lo + hi) / 2;
        if (s->light_cdf[mid] > u)
            hi = mid;
        else
            lo = mid + 1;
    }
    uint32_t tri = s->light_tris[lo];
    const uint32_t *v = s->indices + 3 * tri;
    float su = sqrtf(u1);
    *q = lerp3(vertex(s, v[0]), vertex(s, v[1]), vertex(s, v[2]), su * u2, 1.0f - su);
    return tri;
}

static inline float power_heuristic(float a, float b)
{
    float a2 = a * a, b2 = b * b;
    return a2 / (a2 + b2);
}

/* ---- the integrators ---------------------------------------------------- */

static uint32_t trace_sample(const tracer_t *tr, const tracer_settings_t *st, uint32_t pixel,
                             uint64_t sample_index, vec3_t *out)
{
    const scene_t *s = tr->scene;
    const camera_t *cam = &s->camera;
    const int nee = st->integrator == SCENE_INTEGRATOR_PATH && s->light_count > 0;
    const uint32_t max_depth = st->max_depth;
    rng_stream_t rng = rng_stream(st->seed, pixel, sample_index);
    uint32_t px = pixel % (uint32_t)cam->width, py = pixel / (uint32_t)cam->width;
    float fu = rng_next_float(&rng), fv = rng_next_float(&rng);
    vec3_t o = cam->position;
    vec3_t d = vec3_normalize(camera_ray_dir(cam, px, py, fu, fv));
    vec3_t L = vec3_make(0, 0, 0), beta = vec3_make(1, 1, 1);
    float prev_pdf = 0.0f; /* solid-angle pdf of the BSDF sample that made d */
    int specular = 1;      /* camera rays and specular bounces see lights fully */
    uint32_t rays = 0;

    for (uint32_t depth = 0;; depth++) {
        hit_t h;
        rays++;
        if (!intersect(tr, o, d, &h))
            break;
        const uint32_t *vi = s->indices + 3 * h.tri;
        const material_t *m = &s->materials[s->tri_material[h.tri]];
        vec3_t p = lerp3(vertex(s, vi[0]), vertex(s, vi[1]), vertex(s, vi[2]), h.u, h.v);
        vec3_t ng = s->tri_normal[h.tri];
        vec3_t wo = vec3_neg(d);
        float cos_o = vec3_dot(ng, wo);

        if (m->type == MATERIAL_EMITTER) {
            if (cos_o > 0.0f) {
                float w = 1.0f;
                if (nee && !specular) {
                    /* d is unit length, so h.t is the distance */
                    float light_pdf = s->tri_light_pdf[h.tri] * h.t * h.t / cos_o;
                    w = power_heuristic(prev_pdf, light_pdf);
                }
                L = vec3_add(L, vec3_mul(beta, vec3_scale(m->radiance, w)));
            }
            if (vec3_is_zero(m->albedo))
                break; /* a black emitter absorbs everything */
        }
        /* segments so far: depth + 1; a bounce or a light sample adds one */
        if (max_depth && depth + 2 > max_depth)
            break;

        /* Orient the normals to the side the ray came from. */
        vec3_t ngf = cos_o < 0.0f ? vec3_neg(ng) : ng;
        vec3_t ns = ngf;
        if (s->tri_smooth[h.tri]) {
            vec3_t n = vec3_normalize(lerp3(vertex_normal(s, vi[0]), vertex_normal(s, vi[1]),
                                            vertex_normal(s, vi[2]), h.u, h.v));
            if (vec3_dot(n, ngf) < 0.0f)
                n = vec3_neg(n);
            /* A shading normal that hides wo would make the BSDF take light
             * from behind the surface: fall back to the geometric one. */
            if (vec3_is_finite(n) && vec3_dot(n, wo) > 0.0f)
                ns = n;
        }
        vec3_t wi;
        if (m->type == MATERIAL_DIFFUSE || m->type == MATERIAL_EMITTER) {
            if (nee) {
                double ul = rng_next_double(&rng);
                float u1 = rng_next_float(&rng), u2 = rng_next_float(&rng);
                vec3_t q;
                uint32_t lt = sample_light(s, ul, u1, u2, &q);
                vec3_t to = vec3_sub(q, p);
                float dist2 = vec3_dot(to, to);
                vec3_t nl = s->tri_normal[lt];
                if (dist2 > 0.0f) {
                    float dist = sqrtf(dist2);
                    vec3_t wl = vec3_scale(to, 1.0f / dist);
                    float cos_l = -vec3_dot(nl, wl), cos_s = vec3_dot(ns, wl);
                    if (cos_l > 0.0f && cos_s > 0.0f && vec3_dot(ngf, wl) > 0.0f) {
                        vec3_t from = vec3_offset_ray_origin(p, ngf);
                        vec3_t target = vec3_offset_ray_origin(q, nl);
                        rays++;
                        if (unoccluded(tr, from, vec3_sub(target, from))) {
                            const material_t *lm = &s->materials[s->tri_material[lt]];
                            float light_pdf = s->tri_light_pdf[lt] * dist2 / cos_l;
                            float bsdf_pdf = cos_s * VMATH_INV_PI;
                            float w = power_heuristic(light_pdf, bsdf_pdf);
                            float k = w * cos_s * VMATH_INV_PI / light_pdf;
                            L = vec3_add(L, vec3_mul(vec3_mul(beta, m->albedo),
                                                     vec3_scale(lm->radiance, k)));
                        }
                    }
                }
            }
            float u1 = rng_next_float(&rng), u2 = rng_next_float(&rng);
            wi = material_sample_cosine(ns, u1, u2);
            float cos_i = vec3_dot(ns, wi);
            if (vec3_dot(ngf, wi) <= 0.0f || cos_i <= 0.0f)
                break;
            prev_pdf = cos_i * VMATH_INV_PI;
            specular = 0;
            beta = vec3_mul(beta, m->albedo);
            o = vec3_offset_ray_origin(p, ngf);
        } else if (m->type == MATERIAL_MIRROR) {
            wi = material_reflect(wo, ns);
            if (vec3_dot(ngf, wi) <= 0.0f)
                break;
            specular = 1;
            beta = vec3_mul(beta, m->albedo);
            o = vec3_offset_ray_origin(p, ngf);
        } else { /* dielectric */
            float eta = cos_o > 0.0f ? m->ior : 1.0f / m->ior;
            float cos_i = vec3_dot(ns, wo), cos_t;
            float F = material_fresnel(cos_i, eta, &cos_t);
            if (rng_next_float(&rng) < F) {
                wi = material_reflect(wo, ns);
                if (vec3_dot(ngf, wi) <= 0.0f)
                    break;
                o = vec3_offset_ray_origin(p, ngf);
            } else {
                wi = vec3_add(vec3_scale(wo, -1.0f / eta), vec3_scale(ns, cos_i / eta - cos_t));
                if (vec3_dot(ngf, wi) >= 0.0f)
                    break;
                /* radiance is compressed into the denser medium (pbrt's 1/eta^2) */
                beta = vec3_scale(beta, 1.0f / (eta * eta));
                o = vec3_offset_ray_origin(p, vec3_neg(ngf));
            }
            specular = 1;
        }
        if (depth + 1 >= TRACER_RR_DEPTH) {
            float q = fminf(0.95f, vec3_max_comp(beta));
            if (!(rng_next_float(&rng) < q))
                break;
            beta = vec3_scale(beta, 1.0f / q);
        }
        d = vec3_normalize(wi);
    }
    *out = L;
    return rays;
}

uint32_t tracer_sample(const tracer_t *t, const tracer_settings_t *settings, uint32_t pixel,
                       uint64_t sample_index, float rgb[3])
{
    vec3_t L;
    uint32_t rays = trace_sample(t, settings, pixel, sample_index, &L);
    rgb[0] = L.x;
    rgb[1] = L.y;
    rgb[2] = L.z;
    return rays;
}

int tracer_trace(const tracer_t *t, const tracer_settings_t *st, const tracer_task_t *tasks,
                 size_t count, tracer_result_t *results, tracer_stats_t *stats, char *err,
                 size_t errlen)
{
    const camera_t *cam = &t->scene->camera;
    const uint64_t npix = (uint64_t)cam->width * (uint64_t)cam->height;
    for (size_t k = 0; k < count; k++) {
        if (tasks[k].pixel >= npix) {
            snprintf(err, errlen, "task %zu: pixel %u outside the %dx%d image", k, tasks[k].pixel,
                     cam->width, cam->height);
            return -1;
        }
        if (tasks[k].sample_count == 0 || tasks[k].sample_count > TRACER_MAX_TASK_SAMPLES) {
            snprintf(err, errlen, "task %zu: sample count %u outside 1..%d", k,
                     tasks[k].sample_count, TRACER_MAX_TASK_SAMPLES);
            return -1;
        }
    }
    uint64_t rays = 0, samples = 0;
    double running[TRACER_MAX_TASK_SAMPLES];
    for (size_t k = 0; k < count; k++) {
        const tracer_task_t *task = &tasks[k];
        tracer_result_t *r = &results[k];
        memset(r, 0, sizeof *r);
        r->pixel = task->pixel;
        /* eq. 4.1: P_i is the running estimate (all samples so far) after
         * the i-th sample of this task; Welford gives the task's own M2. */
        double prior_lum =
            vmath_luminance(task->prior_sum[0], task->prior_sum[1], task->prior_sum[2]);
        double lum_sum = 0, mean = 0, m2 = 0;
        uint32_t n = 0;
        for (uint32_t i = 0; i < task->sample_count; i++) {
            vec3_t L;
            rays += trace_sample(t, st, task->pixel, task->first_sample + i, &L);
            if (!vec3_is_finite(L)) {
                r->nonfinite++;
                continue;
            }
            r->sum[0] += L.x;
            r->sum[1] += L.y;
            r->sum[2] += L.z;
            double lum = vmath_luminance(L.x, L.y, L.z);
            n++;
            double delta = lum - mean;
            mean += delta / n;
            m2 += delta * (lum - mean);
            lum_sum += lum;
            running[n - 1] = (prior_lum + lum_sum) / (double)(task->prior_count + n);
        }
        samples += task->sample_count;
        r->samples = n;
        r->lum_m2 = m2;
        double pvar = 0;
        for (uint32_t i = 0; i + 1 < n; i++) {
            double dv = running[i] - running[n - 1];
            pvar += dv * dv;
        }
        r->pvar = pvar;
    }
    if (stats) {
        stats->rays += rays;
        stats->samples += samples;
    }
    return 0;
}
