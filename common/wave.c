/* wave.c - the wavefront engine's stages (wave.h). */
#include "wave.h"

/* The kernel of each material type (material_type_t order). An emitter
 * with an albedo reflects as a diffuse surface does. */
static const wave_kernel_t wave_kernels[] = {
    [MATERIAL_DIFFUSE] = wave_kernel_diffuse,
    [MATERIAL_EMITTER] = wave_kernel_diffuse,
    [MATERIAL_MIRROR] = wave_kernel_mirror,
    [MATERIAL_DIELECTRIC] = wave_kernel_dielectric,
    [MATERIAL_CONDUCTOR] = wave_kernel_glossy,
    [MATERIAL_PLASTIC] = wave_kernel_glossy,
    [MATERIAL_THIN_DIELECTRIC] = wave_kernel_glossy,
    [MATERIAL_ROUGH_DIELECTRIC] = wave_kernel_glossy,
};
#define WAVE_KERNELS (sizeof wave_kernels / sizeof wave_kernels[0])

/* Where the next path comes from: sample `index` of task `task`. */
typedef struct wave_cursor {
    size_t task;
    uint32_t index;
    uint32_t flat; /* its place in the sample list */
} wave_cursor_t;

/* Starts the camera ray of the cursor's sample in slot s (tracer.c's
 * path_start, field by field). */
static void start_path(const wave_ctx_t *c, wave_state_t *w, uint16_t s, const tracer_task_t *task,
                       uint32_t index, uint32_t flat)
{
    const tracer_settings_t *st = c->settings;
    const camera_t *cam = &c->scene->camera;
    uint64_t sample_index = task->first_sample + index;
    w->rng[s] = st->sampler == RNG_SAMPLER_SOBOL
                    ? rng_stream_sobol(st->seed, task->pixel, sample_index)
                    : rng_stream(st->seed, task->pixel, sample_index);
    uint32_t px = task->pixel % (uint32_t)cam->width, py = task->pixel / (uint32_t)cam->width;
    tracer_camera_ray(cam, &w->rng[s], px, py, &w->o[s], &w->d[s]);
    w->L[s] = vec3_make(0, 0, 0);
    w->beta[s] = vec3_make(1, 1, 1);
    w->eta_scale[s] = 1.0f;
    w->prev_pdf[s] = 0.0f;
    w->specular[s] = 1;
    w->depth[s] = 0;
    w->rays[s] = 0;
    w->sample[s] = flat;
}

/* The hit stage for slot s: 1 when the path goes on to its material's
 * kernel, 0 when it ends here (tracer.c's trace_sample up to shading). */
static int hit_stage(const wave_ctx_t *c, wave_state_t *w, uint16_t s, tracer_hit_t *h,
                     material_type_t *type)
{
    const scene_t *sc = c->scene;
    const material_t *m = &sc->materials[sc->tri_material[h->tri]];
    tracer_inset_from_edges(h);
    vec3_t wo = vec3_neg(w->d[s]);
    float cos_o = vec3_dot(sc->tri_normal[h->tri], wo);
    if (m->type == MATERIAL_EMITTER) {
        if (cos_o > 0.0f) {
            float mis = 1.0f;
            if (c->nee && !w->specular[s]) {
                float light_pdf = lights_hit_pdf(sc, h->tri, w->o[s], h->t, cos_o);
                mis = tracer_power_heuristic(w->prev_pdf[s], light_pdf);
            }
            w->L[s] = vec3_add(w->L[s], vec3_mul(w->beta[s], vec3_scale(m->radiance, mis)));
        }
        if (vec3_is_zero(m->albedo))
            return 0;
    }
    if (m->one_sided && !(cos_o > 0.0f))
        return 0; /* a one-sided surface is black from behind */
    if (c->settings->max_depth && w->depth[s] + 2 > c->settings->max_depth)
        return 0;
    w->tri[s] = h->tri;
    w->u[s] = h->u;
    w->v[s] = h->v;
    w->cos_o[s] = cos_o;
    *type = m->type;
    return 1;
}

void wave_trace(const wave_ctx_t *c, wave_state_t *w, const tracer_task_t *tasks, size_t count,
                vec3_t *L, uint32_t *rays)
{
    uint16_t live[WAVE_PATHS], next_live[WAVE_PATHS], free_slots[WAVE_PATHS];
    uint16_t queue[WAVE_KERNELS][WAVE_PATHS];
    size_t queued[WAVE_KERNELS];
    size_t nlive = 0, nfree = WAVE_PATHS;
    for (size_t i = 0; i < WAVE_PATHS; i++)
        free_slots[i] = (uint16_t)(WAVE_PATHS - 1 - i);
    wave_cursor_t cur = {0, 0, 0}; /* (tracer_trace refuses tasks of no samples) */
    for (;;) {
        /* fill the free slots with the next samples */
        while (nfree > 0 && cur.task < count) {
            uint16_t s = free_slots[--nfree];
            start_path(c, w, s, &tasks[cur.task], cur.index, cur.flat);
            live[nlive++] = s;
            cur.flat++;
            if (++cur.index == tasks[cur.task].sample_count) {
                cur.index = 0;
                cur.task++;
            }
        }
        if (nlive == 0)
            break;
        for (size_t k = 0; k < WAVE_KERNELS; k++)
            queued[k] = 0;
        /* closest hit, and the hit's own work */
        for (size_t j = 0; j < nlive; j++) {
            uint16_t s = live[j];
            tracer_hit_t h;
            material_type_t type;
            w->rays[s]++;
            if (c->hide_camera && w->depth[s] == 0
                    ? tracer_intersect_camera(c->tracer, w->o[s], w->d[s], &h, &w->rays[s])
                    : tracer_intersect(c->tracer, w->o[s], w->d[s], &h)) {
                if (hit_stage(c, w, s, &h, &type)) {
                    queue[type][queued[type]++] = s;
                    continue;
                }
            } else if (c->env && !(c->hide_camera && w->depth[s] == 0)) {
                w->L[s] = tracer_env_miss(c->scene, w->L[s], w->beta[s], w->d[s], w->specular[s],
                                          w->prev_pdf[s], c->nee);
            }
            L[w->sample[s]] = w->L[s];
            rays[w->sample[s]] = w->rays[s];
            free_slots[nfree++] = s;
        }
        /* shading, one kernel per material type present */
        for (size_t k = 0; k < WAVE_KERNELS; k++)
            if (queued[k])
                wave_kernels[k](c, w, queue[k], queued[k]);
        /* shadow rays, Russian roulette, the next ray */
        nlive = 0;
        for (size_t k = 0; k < WAVE_KERNELS; k++) {
            for (size_t j = 0; j < queued[k]; j++) {
                uint16_t s = queue[k][j];
                if (w->shadow[s]) {
                    w->rays[s]++;
                    if (tracer_unoccluded(c->tracer, w->shadow_o[s], w->shadow_d[s]))
                        w->L[s] = vec3_add(w->L[s], w->shadow_L[s]);
                }
                int goes_on = w->alive[s];
                if (goes_on) {
                    rng_seek(&w->rng[s], tracer_bounce_dim(w->depth[s]));
                    if (w->depth[s] + 1 >= c->scene->rr_depth) {
                        float q = tracer_roulette_probability(w->beta[s], w->eta_scale[s]);
                        if (!(rng_next_float(&w->rng[s]) < q))
                            goes_on = 0;
                        else
                            w->beta[s] = vec3_scale(w->beta[s], 1.0f / q);
                    }
                }
                if (!goes_on) {
                    L[w->sample[s]] = w->L[s];
                    rays[w->sample[s]] = w->rays[s];
                    free_slots[nfree++] = s;
                    continue;
                }
                w->d[s] = w->next_d[s];
                w->depth[s]++;
                next_live[nlive++] = s;
            }
        }
        for (size_t j = 0; j < nlive; j++)
            live[j] = next_live[j];
    }
}
