/* tracer.c - ray casting (trilist.h for a small scene; above, our
 * traversal of a BVH Embree builds, bvh.h, or Embree's own for a scene
 * with smooth glass),
 * the two integrators and the per-pixel statistics.
 *
 * `path`: unidirectional path tracing with next-event estimation on the
 * emissive triangles, combined with BSDF sampling by multiple importance
 * sampling (power heuristic), and Russian roulette after TRACER_RR_DEPTH
 * bounces on the throughput with glass's radiance compression undone (as
 * Mitsuba 3's path.cpp): unbiased, no depth clamp unless max_depth is set.
 * `naive`: the thesis's Procedure 1, radiance only when a path hits a light.
 * Both estimate the same integral, so they converge to the same image.
 * Picking a point on a light is lights.h's; where a path goes at a surface
 * is its material's (material_sample, material_eval in material.h).
 *
 * Robustness: hit points come from barycentrics kept off the triangle's
 * edges (tracer_inset_from_edges), new rays leave from a point offset by the
 * Wachter-Binder method along the geometric normal, so there is no
 * scene-scale epsilon; shading normals never let light through the
 * geometric surface; a NaN/Inf sample is counted and left out.
 */
#include "tracer.h"

#include <embree3/rtcore.h>
#include <math.h>
#include <pmmintrin.h> /* _MM_DENORMALS_ZERO_ON */
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <xmmintrin.h> /* _mm_getcsr, _MM_FLUSH_ZERO_ON */

#include "tracer_priv.h"
#include "wave.h"

struct tracer_device {
    RTCDevice device;
    char isa[16];
    pthread_mutex_t lock; /* guards error: builds may run on several threads */
    char error[256];      /* last Embree error, written by the callback */
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

/* The diffuse kernel's build (wave.h): AVX-512 at 16 lanes only beside
 * the triangle list's AVX-512 kernel, where it gained 6.5 % on the Cornell
 * box. Beside code that keeps to 256 bits it lost: 6.5 % on the Buddha
 * (our BVH's traversal) and glass (Embree), 9 % on the Cornell box with
 * the list's AVX2 kernel (Intel Xeon, bench_core, one thread), the lower
 * clock these cores take for 512-bit code, which the list's AVX-512
 * kernel pays anyway. Else AVX2 at 8 lanes where the host has it. */
static int shading_lanes_for(const tracer_t *t)
{
    if (t->small && strcmp(trilist_kernel(t->small), "avx512") == 0 &&
        __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl"))
        return WAVE_LANES_AVX512;
    return __builtin_cpu_supports("avx2") ? WAVE_LANES_AVX2 : WAVE_LANES;
}

int tracer_new(tracer_device_t *dev, const scene_t *scene, tracer_t **out, char *err, size_t errlen)
{
    return tracer_new_accel(dev, scene, TRACER_ACCEL_AUTO, out, err, errlen);
}

tracer_accel_t tracer_accel_for(const scene_t *scene)
{
    if (scene->triangle_count <= TRILIST_MAX_TRIANGLES)
        return TRACER_ACCEL_TRILIST;
    return tracer_own_traversal(scene) ? TRACER_ACCEL_BVH : TRACER_ACCEL_EMBREE;
}

/* Our traversal where the host runs it: the ISA is in the build id, so
 * hosts of either kind never share a job. Not in a scene with smooth
 * glass: paths through it stay coherent, and Embree's packets cast
 * cornell-glass's recorded path rays 1.04x as fast as ours, where ours
 * cast the Buddha's 1.2x as fast as packets (bench_core; in the renderer,
 * cornell-glass ran 6 % slower with ours). */
int tracer_own_traversal(const scene_t *s)
{
    if (!bvh_supported())
        return 0;
    for (size_t i = 0; i < s->triangle_count; i++)
        if (s->materials[s->tri_material[i]].type == MATERIAL_DIELECTRIC)
            return 0;
    return 1;
}

int tracer_new_accel(tracer_device_t *dev, const scene_t *scene, tracer_accel_t accel,
                     tracer_t **out, char *err, size_t errlen)
{
    *out = NULL;
    if (scene->checked_only) {
        snprintf(err, errlen, "the scene was loaded to be checked (scene_check*), not traced");
        return -1;
    }
    tracer_t *t = calloc(1, sizeof *t);
    if (!t) {
        snprintf(err, errlen, "out of memory");
        return -1;
    }
    t->dev = dev;
    t->scene = scene;
    __builtin_cpu_init();
    t->shading_lanes = shading_lanes_for(t);
    if (accel == TRACER_ACCEL_AUTO)
        accel = tracer_accel_for(scene);
    if (accel == TRACER_ACCEL_TRILIST) {
        t->small = trilist_new(scene->positions, scene->indices, scene->triangle_count);
        if (!t->small) {
            snprintf(err, errlen, "out of memory");
            tracer_destroy(&t);
            return -1;
        }
        t->shading_lanes = shading_lanes_for(t);
        *out = t;
        return 0;
    }
    char old[256];
    take_error(dev, old, sizeof old); /* start clean */
    if (accel == TRACER_ACCEL_BVH) {
        if (!bvh_supported()) {
            snprintf(err, errlen, "our BVH traversal needs AVX2, which this host lacks");
            tracer_destroy(&t);
            return -1;
        }
        char e[256];
        t->bvh = bvh_new(dev->device, scene->positions, scene->indices, scene->triangle_count, e,
                         sizeof e);
        if (!t->bvh) {
            snprintf(err, errlen, "cannot build the BVH: %s", e);
            tracer_destroy(&t);
            return -1;
        }
        *out = t;
        return 0;
    }
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
    bvh_destroy(&t->bvh);
    trilist_destroy(&t->small);
    free(t);
    *tp = NULL;
}

const char *tracer_isa(const tracer_t *t)
{
    return t->dev->isa;
}

int tracer_shading_lanes(const tracer_t *t)
{
    return t->shading_lanes;
}

int tracer_use_isa(tracer_t *t, const char *isa)
{
    __builtin_cpu_init();
    if (strcmp(isa, "sse2") == 0) {
        /* our traversal has no kernel for the baseline */
        if (t->bvh || (t->small && trilist_use_kernel(t->small, isa) < 0))
            return -1;
        t->shading_lanes = WAVE_LANES;
        return 0;
    }
    if (strcmp(isa, "avx512") != 0 && strcmp(isa, "avx2") != 0)
        return -1;
    if (strcmp(isa, "avx512") == 0 ? !__builtin_cpu_supports("avx512vl")
                                   : !__builtin_cpu_supports("avx2"))
        return -1;
    /* (both kernels' names are the ISA's) */
    if ((t->small && trilist_use_kernel(t->small, isa) < 0) ||
        (t->bvh && bvh_use_kernel(t->bvh, isa) < 0))
        return -1;
    t->shading_lanes = shading_lanes_for(t);
    return 0;
}

/* ---- the integrators ---------------------------------------------------- */

/* One path of a sample, as it is traced. */
typedef struct path {
    rng_stream_t rng; /* the sample's random numbers, drawn in order */
    vec3_t o, d;      /* the ray being traced; d unit length */
    vec3_t L;         /* radiance gathered so far */
    vec3_t beta;      /* throughput */
    float eta_scale;  /* product of eta^2 of the transmissions taken: undoes
                         the 1/eta^2 compression in beta for the roulette */
    float prev_pdf;   /* solid-angle pdf of the BSDF sample that made d */
    int specular;     /* camera rays and specular bounces see lights fully */
    uint32_t rays;
} path_t;

/* The camera ray through a random point of the pixel (two numbers). The
 * sample's numbers: under sobol, point sample_index of the pixel's
 * scrambled Sobol sequence (rng.h). */
static void path_start(path_t *path, const camera_t *cam, const tracer_settings_t *st,
                       uint32_t pixel, uint64_t sample_index)
{
    path->rng = st->sampler == RNG_SAMPLER_SOBOL ? rng_stream_sobol(st->seed, pixel, sample_index)
                                                 : rng_stream(st->seed, pixel, sample_index);
    uint32_t px = pixel % (uint32_t)cam->width, py = pixel / (uint32_t)cam->width;
    tracer_camera_ray(cam, &path->rng, px, py, &path->o, &path->d);
    path->L = vec3_make(0, 0, 0);
    path->beta = vec3_make(1, 1, 1);
    path->eta_scale = 1.0f;
    path->prev_pdf = 0.0f;
    path->specular = 1;
    path->rays = 0;
}

/* Radiance of an emitter the path hit from its front (cos_o > 0), weighted
 * by MIS against light sampling when that could have found this point. */
static void add_emission(path_t *path, const scene_t *s, const material_t *m, const tracer_hit_t *h,
                         float cos_o, int nee)
{
    float w = 1.0f;
    if (nee && !path->specular) {
        /* d is unit length, so h->t is the distance */
        float light_pdf = lights_hit_pdf(s, h->tri, path->o, h->t, cos_o);
        w = tracer_power_heuristic(path->prev_pdf, light_pdf);
    }
    path->L = vec3_add(path->L, vec3_mul(path->beta, vec3_scale(m->radiance, w)));
}

/* Next-event estimation at p on diffuse m: a light and a point on it (two
 * numbers, lights_sample), a shadow ray, and its share MIS-weighted
 * against BSDF sampling. */
static void sample_direct(const tracer_t *tr, path_t *path, const material_t *m, vec3_t p,
                          const material_hit_t *mh)
{
    const scene_t *s = tr->scene;
    double ul = rng_next_double(&path->rng);
    float u2 = rng_next_float(&path->rng);
    size_t which;
    float pick;
    int env = lights_pick_env(s, &ul);
    if (env || lights_pick_delta(s, &ul, &which, &pick)) {
        vec3_t from = {0, 0, 0}, seg = from, gain = from;
        if (env ? !tracer_env_direct(s, m, m->albedo, path->beta, p, mh, ul, u2, &from, &seg, &gain)
                : !tracer_delta_direct(s, m, m->albedo, path->beta, p, mh, which, pick, &from, &seg,
                                       &gain))
            return;
        path->rays++;
        if (tracer_unoccluded(tr, from, seg))
            path->L = vec3_add(path->L, gain);
        return;
    }
    vec3_t q, nl, target;
    float area_pdf;
    uint32_t lt;
    if (!lights_sample_from(s, p, ul, u2, &q, &nl, &area_pdf, &lt, &target))
        return;
    vec3_t to = vec3_sub(q, p);
    float dist2 = vec3_dot(to, to);
    if (!(dist2 > 0.0f))
        return;
    vec3_t wl = vec3_scale(to, 1.0f / sqrtf(dist2));
    float cos_l = -vec3_dot(nl, wl), cos_s, bsdf_pdf;
    if (!(cos_l > 0.0f) || !material_eval(m, mh, wl, &cos_s, &bsdf_pdf))
        return;
    vec3_t from = vec3_offset_ray_origin(p, mh->ngf);
    path->rays++;
    if (!tracer_unoccluded(tr, from, vec3_sub(target, from)))
        return;
    const material_t *lm = &s->materials[s->tri_material[lt]];
    float light_pdf = area_pdf * dist2 / cos_l;
    float w = tracer_power_heuristic(light_pdf, bsdf_pdf);
    float k = w * cos_s * VMATH_INV_PI / light_pdf;
    path->L =
        vec3_add(path->L, vec3_mul(vec3_mul(path->beta, m->albedo), vec3_scale(lm->radiance, k)));
}

float tracer_roulette_probability(const scene_t *s, vec3_t beta, float eta_scale)
{
    return fminf(s->rr_cap, vec3_max_comp(beta) * eta_scale / s->rr_threshold);
}

/* Russian roulette (one number): 0 ends the path; a survivor's throughput
 * is divided by its survival probability. A path inside glass is judged as
 * if it were outside (tracer_roulette_probability): on beta alone, 1/1.5^2
 * of compression made it 2.25x likelier to die, then 2.25x brighter when it
 * survived and left the glass, which only added variance. */
static int survives_roulette(const scene_t *s, path_t *path)
{
    float q = tracer_roulette_probability(s, path->beta, path->eta_scale);
    if (!(rng_next_float(&path->rng) < q))
        return 0;
    path->beta = vec3_scale(path->beta, 1.0f / q);
    return 1;
}

/* One sample of a pixel: its radiance in *out; returns the rays traced.
 * Random numbers are drawn in a fixed order per bounce (light sample,
 * BSDF sample, roulette), so a sample's path depends on its coordinates
 * alone. */
static uint32_t trace_sample(const tracer_t *tr, const tracer_settings_t *st, uint32_t pixel,
                             uint64_t sample_index, vec3_t *out)
{
    const scene_t *s = tr->scene;
    const int nee = st->integrator == SCENE_INTEGRATOR_PATH &&
                    (s->light_count > 0 || s->has_env || s->delta_count > 0);
    path_t path;
    path_start(&path, &s->camera, st, pixel, sample_index);
    for (uint32_t depth = 0;; depth++) {
        tracer_hit_t h;
        path.rays++;
        if (s->hide_emitters && depth == 0
                ? !tracer_intersect_camera(tr, path.o, path.d, &h, &path.rays)
                : !tracer_intersect(tr, path.o, path.d, &h)) {
            if (s->has_env && !(depth == 0 && s->hide_emitters))
                path.L = tracer_env_miss(s, path.L, path.beta, path.d, path.specular, path.prev_pdf,
                                         nee);
            break;
        }
        const material_t *m = &s->materials[s->tri_material[h.tri]];
        tracer_inset_from_edges(&h);
        vec3_t p = scene_point(s, h.tri, h.u, h.v);
        vec3_t wo = vec3_neg(path.d);
        float cos_o = vec3_dot(s->tri_normal[h.tri], wo);
        if (m->type == MATERIAL_EMITTER) {
            if (cos_o > 0.0f)
                add_emission(&path, s, m, &h, cos_o, nee);
            if (vec3_is_zero(m->albedo))
                break; /* a black emitter absorbs everything */
        }
        if (m->one_sided && !(cos_o > 0.0f))
            break; /* a one-sided surface is black from behind */
        /* segments so far: depth + 1; a bounce or a light sample adds one */
        if (st->max_depth && depth + 2 > st->max_depth)
            break;
        material_hit_t mh = tracer_orient_normals(s, &h, wo, cos_o);
        material_t textured;
        m = tracer_textured(s, m, &h, &textured);
        material_sample_t bs;
        if (material_is_glossy(m)) {
            int shadow;
            vec3_t from = {0, 0, 0}, seg = from, gain = from;
            int goes_on = tracer_shade_glossy(s, m, &path.rng, depth, nee, path.beta, p, &mh,
                                              &shadow, &from, &seg, &gain, &bs);
            if (shadow) {
                path.rays++;
                if (tracer_unoccluded(tr, from, seg))
                    path.L = vec3_add(path.L, gain);
            }
            if (!goes_on)
                break;
        } else {
            rng_seek(&path.rng, tracer_bounce_dim(depth) + 2);
            if (nee && material_is_diffuse(m))
                sample_direct(tr, &path, m, p, &mh);
            rng_seek(&path.rng, tracer_bounce_dim(depth) + 4);
            if (!material_sample(m, &mh, &path.rng, &bs))
                break;
        }
        path.beta = vec3_mul(path.beta, bs.weight);
        if (bs.transmits)
            path.eta_scale *= bs.eta * bs.eta;
        path.prev_pdf = bs.pdf;
        path.specular = bs.specular;
        path.o = vec3_offset_ray_origin(p, bs.transmits ? vec3_neg(mh.ngf) : mh.ngf);
        rng_seek(&path.rng, tracer_bounce_dim(depth));
        if (depth + 1 >= s->rr_depth && !survives_roulette(s, &path))
            break;
        path.d = vec3_normalize(bs.wi);
    }
    *out = path.L;
    return path.rays;
}

/* ---- the direct integrator ---------------------------------------------- */

/* m's BSDF toward wi, for any material: f cos and the density with which
 * its sampling would choose wi. 0 when m gives wi nothing. */
static int direct_eval(const material_t *m, const material_hit_t *mh, vec3_t wi, vec3_t *f_cos,
                       float *pdf)
{
    if (material_is_glossy(m))
        return material_glossy_eval(m, mh, wi, f_cos, pdf);
    float cos_s;
    if (!material_eval(m, mh, wi, &cos_s, pdf))
        return 0;
    *f_cos = vec3_scale(m->albedo, cos_s * VMATH_INV_PI);
    return 1;
}

/* Mitsuba's power heuristic with each strategy's share of the samples. */
static float direct_mis(float pdf_a, float pdf_b)
{
    float a2 = pdf_a * pdf_a, b2 = pdf_b * pdf_b, w = a2 / (a2 + b2);
    return isfinite(w) ? w : 0.0f;
}

/* One sample of a pixel under the direct integrator (Mitsuba's `direct`):
 * what the camera ray sees emitting, then at its hit E light samples and
 * B BSDF samples (scene_t.direct_*), each MIS-weighted against the other
 * strategy by the power heuristic, with the strategies' shares E / (E + B)
 * and B / (E + B) in the densities, as Mitsuba weighs them. Numbers: the
 * camera's pair, then light sample i at [2 + 2i, 3 + 2i], BSDF sample j's
 * lobe at 2 + 2E + 3j and its pair after it. Both engines run it (it has
 * no wavefront kernel: a path of one bounce has no stages to batch), but
 * for one light and one BSDF sample, traced as a path (as_traced). */
static uint32_t trace_direct(const tracer_t *tr, const tracer_settings_t *st, uint32_t pixel,
                             uint64_t sample_index, vec3_t *out)
{
    const scene_t *s = tr->scene;
    path_t path;
    path_start(&path, &s->camera, st, pixel, sample_index);
    *out = vec3_make(0, 0, 0);
    tracer_hit_t h;
    path.rays++;
    if (!tracer_intersect_camera(tr, path.o, path.d, &h, &path.rays)) {
        if (s->has_env && !s->hide_emitters)
            *out = lights_env_radiance(s, path.d);
        return path.rays;
    }
    const material_t *m = &s->materials[s->tri_material[h.tri]];
    tracer_inset_from_edges(&h);
    vec3_t p = scene_point(s, h.tri, h.u, h.v);
    vec3_t wo = vec3_neg(path.d), L = vec3_make(0, 0, 0);
    float cos_o = vec3_dot(s->tri_normal[h.tri], wo);
    if (m->type == MATERIAL_EMITTER && cos_o > 0.0f)
        L = m->radiance;
    if ((m->type == MATERIAL_EMITTER && vec3_is_zero(m->albedo)) ||
        (m->one_sided && !(cos_o > 0.0f))) {
        *out = L;
        return path.rays;
    }
    material_hit_t mh = tracer_orient_normals(s, &h, wo, cos_o);
    material_t textured;
    m = tracer_textured(s, m, &h, &textured);
    const uint32_t E = s->direct_emitter_samples, B = s->direct_bsdf_samples;
    const float frac_lum = (float)E / (float)(E + B), frac_bsdf = (float)B / (float)(E + B);
    int has_lobe = material_is_glossy(m) ? material_glossy_has_lobe(m) : material_is_diffuse(m);
    for (uint32_t i = 0;
         has_lobe && (s->light_count > 0 || s->has_env || s->delta_count > 0) && i < E; i++) {
        rng_seek(&path.rng, 2 + 2 * (uint64_t)i);
        double ul = rng_next_double(&path.rng);
        float u2 = rng_next_float(&path.rng), light_pdf, bsdf_pdf;
        vec3_t wl, radiance, from, seg, f_cos;
        int delta;
        if (!tracer_sample_light(s, p, mh.ngf, ul, u2, &wl, &light_pdf, &radiance, &from, &seg,
                                 &delta) ||
            !direct_eval(m, &mh, wl, &f_cos, &bsdf_pdf))
            continue;
        path.rays++;
        if (!tracer_unoccluded(tr, from, seg))
            continue;
        /* (a light with no area: BSDF samples cannot find it; Mitsuba
         * weighs it 1 whatever emitter_samples is, we 1 / E: unbiased) */
        float w =
            (delta ? 1.0f : direct_mis(light_pdf * frac_lum, bsdf_pdf * frac_bsdf)) / (float)E;
        L = vec3_add(L, vec3_mul(f_cos, vec3_scale(radiance, w / light_pdf)));
    }
    for (uint32_t j = 0; j < B; j++) {
        uint64_t dim = 2 + 2 * (uint64_t)E + 3 * (uint64_t)j;
        material_sample_t bs;
        rng_seek(&path.rng, dim);
        float u_lobe = rng_next_float(&path.rng);
        int ok;
        if (material_is_glossy(m)) {
            float u1 = rng_next_float(&path.rng), u2 = rng_next_float(&path.rng);
            ok = material_glossy_sample(m, &mh, u_lobe, u1, u2, &bs);
        } else {
            rng_seek(&path.rng, dim + 1);
            bs.eta = 1.0f;
            ok = material_sample(m, &mh, &path.rng, &bs);
        }
        if (!ok || vec3_is_zero(bs.weight))
            continue;
        vec3_t o = vec3_offset_ray_origin(p, bs.transmits ? vec3_neg(mh.ngf) : mh.ngf);
        vec3_t d = vec3_normalize(bs.wi);
        tracer_hit_t lh;
        path.rays++;
        vec3_t radiance;
        float emitter_pdf;
        if (!tracer_intersect(tr, o, d, &lh)) {
            if (!s->has_env)
                continue;
            radiance = lights_env_eval(s, d, &emitter_pdf);
        } else {
            const material_t *lm = &s->materials[s->tri_material[lh.tri]];
            float cos_l = -vec3_dot(s->tri_normal[lh.tri], d);
            if (lm->type != MATERIAL_EMITTER || !(cos_l > 0.0f))
                continue;
            radiance = lm->radiance;
            emitter_pdf = lights_hit_pdf(s, lh.tri, o, lh.t, cos_l);
        }
        if (bs.specular)
            emitter_pdf = 0.0f;
        float w = direct_mis(bs.pdf * frac_bsdf, emitter_pdf * frac_lum) / (float)B;
        if (bs.specular)
            w = 1.0f / (float)B;
        L = vec3_add(L, vec3_mul(bs.weight, vec3_scale(radiance, w)));
    }
    *out = L;
    return path.rays;
}

/* Mitsuba's direct integrator with one light sample and one BSDF sample
 * is the path integrator cut after its bounce, term for term: what the
 * camera ray sees emitting, next-event estimation at the hit, and the
 * BSDF sample's emitter, each MIS-weighted by the power heuristic (the
 * strategies' equal shares cancel in it), no roulette before the second
 * segment. Traced as that, the wavefront engine runs it (veach-mis.xml
 * 1.15x the samples/s of trace_direct, the same relMSE); other counts
 * stay trace_direct's. *buf holds the settings when they change. */
static const tracer_settings_t *as_traced(const scene_t *s, const tracer_settings_t *st,
                                          tracer_settings_t *buf)
{
    if (st->integrator != SCENE_INTEGRATOR_DIRECT || s->direct_emitter_samples != 1 ||
        s->direct_bsdf_samples != 1 || s->rr_depth < 2)
        return st;
    *buf = *st;
    buf->integrator = SCENE_INTEGRATOR_PATH;
    buf->max_depth = 2;
    return buf;
}

uint32_t tracer_sample(const tracer_t *t, const tracer_settings_t *settings, uint32_t pixel,
                       uint64_t sample_index, float rgb[3])
{
    tracer_settings_t buf;
    settings = as_traced(t->scene, settings, &buf);
    vec3_t L;
    uint32_t rays = settings->integrator == SCENE_INTEGRATOR_DIRECT
                        ? trace_direct(t, settings, pixel, sample_index, &L)
                        : trace_sample(t, settings, pixel, sample_index, &L);
    rgb[0] = L.x;
    rgb[1] = L.y;
    rgb[2] = L.z;
    return rays;
}

/* Refuses a task list with a pixel outside the image or a sample count
 * outside 1..TRACER_MAX_TASK_SAMPLES, before any work is done. */
static int check_tasks(const camera_t *cam, const tracer_task_t *tasks, size_t count, char *err,
                       size_t errlen)
{
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
    return 0;
}

/* One task's result from its samples' radiance L[0..sample_count) and
 * rays, taken in sample order. Returns the rays traced. */
static uint64_t task_result(const tracer_task_t *task, const vec3_t *Ls, const uint32_t *rays_of,
                            tracer_result_t *r)
{
    uint64_t rays = 0;
    double running[TRACER_MAX_TASK_SAMPLES];
    memset(r, 0, sizeof *r);
    r->pixel = task->pixel;
    /* eq. 4.1: P_i is the running estimate (all samples so far) after
     * the i-th sample of this task; Welford gives the task's own M2. */
    double prior_lum = vmath_luminance(task->prior_sum[0], task->prior_sum[1], task->prior_sum[2]);
    double lum_sum = 0, mean = 0, m2 = 0;
    uint32_t n = 0;
    for (uint32_t i = 0; i < task->sample_count; i++) {
        vec3_t L = Ls[i];
        rays += rays_of[i];
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
    r->samples = n;
    r->lum_m2 = m2;
    double pvar = 0;
    for (uint32_t i = 0; i + 1 < n; i++) {
        double dv = running[i] - running[n - 1];
        pvar += dv * dv;
    }
    r->pvar = pvar;
    r->rays = rays < UINT32_MAX ? (uint32_t)rays : UINT32_MAX;
    return rays;
}

/* The samples' radiance and rays, for every task of the list. */
typedef struct trace_buffers {
    vec3_t L[WAVE_MAX_SAMPLES];
    uint32_t rays[WAVE_MAX_SAMPLES];
    wave_state_t wave;
} trace_buffers_t;

int tracer_trace(const tracer_t *t, const tracer_settings_t *st, const tracer_task_t *tasks,
                 size_t count, tracer_result_t *results, tracer_stats_t *stats, char *err,
                 size_t errlen)
{
    if (check_tasks(&t->scene->camera, tasks, count, err, errlen) < 0)
        return -1;
    trace_buffers_t buf;
    const scene_t *s = t->scene;
    tracer_settings_t traced;
    st = as_traced(s, st, &traced);
    const wave_ctx_t ctx = {
        .tracer = t,
        .scene = s,
        .settings = st,
        .nee = st->integrator == SCENE_INTEGRATOR_PATH &&
               (s->light_count > 0 || s->has_env || s->delta_count > 0),
        .env = s->has_env,
        .hide_camera = s->hide_emitters,
        .shading_lanes = t->shading_lanes,
    };
    uint64_t rays = 0, samples = 0;
    /* runs of whole tasks of at most WAVE_MAX_SAMPLES samples */
    for (size_t first = 0; first < count;) {
        size_t end = first, total = 0;
        while (end < count && total + tasks[end].sample_count <= WAVE_MAX_SAMPLES)
            total += tasks[end++].sample_count;
        /* Denormals flushed to zero, in and out, while paths are traced,
         * as Embree asks of every thread that calls it (a denormal can
         * cost a hundred cycles an operation); the caller's mode comes
         * back before the task statistics. Both engines trace under it. */
        const unsigned int csr = _mm_getcsr();
        _mm_setcsr(csr | _MM_FLUSH_ZERO_ON | _MM_DENORMALS_ZERO_ON);
        if (t->engine == TRACER_ENGINE_WAVEFRONT && st->integrator != SCENE_INTEGRATOR_DIRECT) {
            wave_trace(&ctx, &buf.wave, tasks + first, end - first, buf.L, buf.rays);
        } else {
            size_t at = 0;
            for (size_t k = first; k < end; k++)
                for (uint32_t i = 0; i < tasks[k].sample_count; i++, at++)
                    buf.rays[at] = st->integrator == SCENE_INTEGRATOR_DIRECT
                                       ? trace_direct(t, st, tasks[k].pixel,
                                                      tasks[k].first_sample + i, &buf.L[at])
                                       : trace_sample(t, st, tasks[k].pixel,
                                                      tasks[k].first_sample + i, &buf.L[at]);
        }
        _mm_setcsr(csr);
        size_t at = 0;
        for (size_t k = first; k < end; k++) {
            rays += task_result(&tasks[k], buf.L + at, buf.rays + at, &results[k]);
            samples += tasks[k].sample_count;
            at += tasks[k].sample_count;
        }
        first = end;
    }
    if (stats) {
        stats->rays += rays;
        stats->samples += samples;
    }
    return 0;
}

void tracer_use_engine(tracer_t *t, tracer_engine_t engine)
{
    t->engine = engine;
}

int tracer_sampler_from_name(const char *name)
{
    if (name && strcmp(name, "sobol") == 0)
        return RNG_SAMPLER_SOBOL;
    if (name && strcmp(name, "independent") == 0)
        return RNG_SAMPLER_INDEPENDENT;
    return -1;
}

const char *tracer_sampler_name(rng_sampler_t sampler)
{
    return sampler == RNG_SAMPLER_SOBOL ? "sobol" : "independent";
}
