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

/* Starts the path of the cursor's sample in slot s (tracer.c's
 * path_start, field by field), all but its camera ray (start_camera_ray,
 * once the chunk's first pairs are computed). */
static void start_path(const wave_ctx_t *c, wave_state_t *w, uint16_t s, const tracer_task_t *task,
                       const rng_pixel_t *pixel, uint32_t index, uint32_t flat)
{
    uint64_t sample_index = task->first_sample + index;
    w->rng[s] = c->settings->sampler == RNG_SAMPLER_SOBOL ? rng_stream_sobol_at(pixel, sample_index)
                                                          : rng_stream_at(pixel, sample_index);
    w->L[s] = vec3_make(0, 0, 0);
    w->beta[s] = vec3_make(1, 1, 1);
    w->eta_scale[s] = 1.0f;
    w->prev_pdf[s] = 0.0f;
    w->specular[s] = 1;
    w->depth[s] = 0;
    w->rays[s] = 0;
    w->sample[s] = flat;
}

/* The camera rays of a chunk's paths, all of pixel `pixel`
 * (tracer_camera_ray). A pinhole camera's directions are normalised four
 * at a time after the loop, the same operations in each lane (vec3_normalize:
 * the square root and the division were a chain of latencies a path). */
typedef float wave_v4f __attribute__((vector_size(16)));
static void start_camera_rays(const wave_ctx_t *c, wave_state_t *w, const wave_chunk_t *ch,
                              uint32_t pixel)
{
    const camera_t *cam = &c->scene->camera;
    uint32_t px = pixel % (uint32_t)cam->width, py = pixel / (uint32_t)cam->width;
    if (cam->ortho || cam->aperture > 0.0f) {
        for (size_t i = 0; i < ch->n; i++) {
            uint16_t s = ch->live[i];
            tracer_camera_ray(cam, &w->rng[s], px, py, &w->o[s], &w->d[s]);
        }
        return;
    }
    wave_v4f dx[WAVE_CHUNK / 4], dy[WAVE_CHUNK / 4], dz[WAVE_CHUNK / 4];
    for (size_t i = 0; i < ch->n; i++) {
        uint16_t s = ch->live[i];
        float fu = rng_next_float(&w->rng[s]), fv = rng_next_float(&w->rng[s]);
        vec3_t dir = camera_ray_dir(cam, px, py, fu, fv);
        dx[i / 4][i % 4] = dir.x;
        dy[i / 4][i % 4] = dir.y;
        dz[i / 4][i % 4] = dir.z;
        w->o[s] = cam->position;
    }
    for (size_t i = ch->n; i % 4; i++) /* the last vector's unused lanes */
        dx[i / 4][i % 4] = dy[i / 4][i % 4] = dz[i / 4][i % 4] = 1.0f;
    for (size_t k = 0; k < ((size_t)ch->n + 3) / 4; k++) {
        wave_v4f len2 = dx[k] * dx[k] + dy[k] * dy[k] + dz[k] * dz[k], len;
        for (int j = 0; j < 4; j++)
            len[j] = sqrtf(len2[j]);
        wave_v4f inv = 1.0f / len;
        for (int j = 0; j < 4 && 4 * k + (size_t)j < ch->n; j++)
            w->d[ch->live[4 * k + (size_t)j]] =
                vec3_make(dx[k][j] * inv[j], dy[k][j] * inv[j], dz[k][j] * inv[j]);
    }
}

void wave_sobol_ahead(const wave_ctx_t *c, wave_state_t *w, const uint16_t *slots, size_t n)
{
    if (c->settings->sampler != RNG_SAMPLER_SOBOL)
        return;
    rng_stream_t *streams[WAVE_PATHS];
    uint32_t first[WAVE_PATHS];
    size_t m = 0;
    for (size_t i = 0; i < n; i++) {
        uint16_t s = slots[i];
        if (w->depth[s] >= RNG_SOBOL_BOUNCES)
            continue;
        /* tracer_bounce_dim's layout: [2, 3] the light pair, [4, 5] BSDF */
        uint64_t dim = tracer_bounce_dim(w->depth[s]) + (c->nee ? 2 : 4);
        streams[m] = &w->rng[s];
        first[m++] = (uint32_t)(dim >> 1);
    }
    rng_sobol_fill(streams, m, first, c->nee ? 2 : 1, c->shading_lanes == WAVE_LANES_AVX512);
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
    /* the kernels read the triangle's corners (and vertex normals) after
     * every chunk's hits: on a large mesh (the glass sphere, the Buddha)
     * those loads missed the caches, half of the dielectric kernel's time */
    const uint32_t *vi = sc->indices + 3 * (size_t)h->tri;
    for (int k = 0; k < 3; k++) {
        __builtin_prefetch(sc->positions + 3 * (size_t)vi[k]);
        if (sc->normals)
            __builtin_prefetch(sc->normals + 3 * (size_t)vi[k]);
    }
    w->u[s] = h->u;
    w->v[s] = h->v;
    w->cos_o[s] = cos_o;
    *type = m->type;
    return 1;
}

/* Ends slot s's path: its radiance and rays to the sample list, the slot
 * to the free list. */
static void finish_path(wave_state_t *w, uint16_t s, vec3_t *L, uint32_t *rays,
                        uint16_t *free_slots, size_t *nfree)
{
    L[w->sample[s]] = w->L[s];
    rays[w->sample[s]] = w->rays[s];
    free_slots[(*nfree)++] = s;
}

/* The closest-hit stage of one chunk: its rays cast in packets, in sample
 * order; the paths that go on are queued for their material's kernel and
 * stay in the chunk, the others end. */
static void chunk_hits(const wave_ctx_t *c, wave_state_t *w, wave_chunk_t *ch,
                       uint16_t (*queue)[WAVE_PATHS], size_t *queued, vec3_t *L, uint32_t *rays,
                       uint16_t *free_slots, size_t *nfree)
{
    size_t kept = 0;
    /* a chunk's paths are all at the same bounce */
    int camera_hides = c->hide_camera && w->depth[ch->live[0]] == 0;
    for (size_t j0 = 0; j0 < ch->n; j0 += TRACER_PACKET) {
        size_t m = ch->n - j0 < TRACER_PACKET ? ch->n - j0 : TRACER_PACKET;
        tracer_hit_t h[TRACER_PACKET];
        int hit[TRACER_PACKET];
        if (camera_hides) {
            for (size_t i = 0; i < m; i++) {
                uint16_t s = ch->live[j0 + i];
                w->rays[s]++;
                hit[i] = tracer_intersect_camera(c->tracer, w->o[s], w->d[s], &h[i], &w->rays[s]);
            }
        } else {
            tracer_packet_t pk;
            for (size_t i = 0; i < m; i++) {
                uint16_t s = ch->live[j0 + i];
                w->rays[s]++;
                pk.o[i] = w->o[s];
                pk.d[i] = w->d[s];
            }
            tracer_intersect_packet(c->tracer, &pk, m, hit, h);
        }
        for (size_t i = 0; i < m; i++) {
            uint16_t s = ch->live[j0 + i];
            material_type_t type;
            if (hit[i]) {
                if (hit_stage(c, w, s, &h[i], &type)) {
                    queue[type][queued[type]++] = s;
                    ch->live[kept++] = s;
                    continue;
                }
            } else if (c->env && !camera_hides) {
                w->L[s] = tracer_env_miss(c->scene, w->L[s], w->beta[s], w->d[s], w->specular[s],
                                          w->prev_pdf[s], c->nee);
            }
            finish_path(w, s, L, rays, free_slots, nfree);
        }
    }
    ch->n = (uint16_t)kept;
}

/* After shading, for one chunk: its shadow rays cast in packets, in
 * sample order; then Russian roulette and the next ray, or the path's end. */
static void chunk_continue(const wave_ctx_t *c, wave_state_t *w, wave_chunk_t *ch, vec3_t *L,
                           uint32_t *rays, uint16_t *free_slots, size_t *nfree)
{
    tracer_packet_t pk;
    uint16_t in_packet[TRACER_PACKET];
    size_t m = 0;
    for (size_t j = 0; j <= ch->n; j++) {
        if (j < ch->n && w->shadow[ch->live[j]]) {
            uint16_t s = ch->live[j];
            w->rays[s]++;
            pk.o[m] = w->shadow_o[s];
            pk.d[m] = w->shadow_d[s];
            in_packet[m++] = s;
        }
        if (m == TRACER_PACKET || (j == ch->n && m > 0)) {
            int clear[TRACER_PACKET];
            tracer_unoccluded_packet(c->tracer, &pk, m, clear);
            for (size_t i = 0; i < m; i++)
                if (clear[i])
                    w->L[in_packet[i]] = vec3_add(w->L[in_packet[i]], w->shadow_L[in_packet[i]]);
            m = 0;
        }
    }
    size_t kept = 0;
    for (size_t j = 0; j < ch->n; j++) {
        uint16_t s = ch->live[j];
        int goes_on = w->alive[s];
        if (goes_on) {
            rng_seek(&w->rng[s], tracer_bounce_dim(w->depth[s]));
            if (w->depth[s] + 1 >= c->scene->rr_depth) {
                float q = tracer_roulette_probability(c->scene, w->beta[s], w->eta_scale[s]);
                if (!(rng_next_float(&w->rng[s]) < q))
                    goes_on = 0;
                else
                    w->beta[s] = vec3_scale(w->beta[s], 1.0f / q);
            }
        }
        if (!goes_on) {
            finish_path(w, s, L, rays, free_slots, nfree);
            continue;
        }
        w->d[s] = w->next_d[s];
        w->depth[s]++;
        ch->live[kept++] = s;
    }
    ch->n = (uint16_t)kept;
}

void wave_trace(const wave_ctx_t *c, wave_state_t *w, const tracer_task_t *tasks, size_t count,
                vec3_t *L, uint32_t *rays)
{
    uint16_t free_slots[WAVE_PATHS];
    uint16_t queue[WAVE_KERNELS][WAVE_PATHS];
    size_t queued[WAVE_KERNELS];
    size_t nfree = WAVE_PATHS, nchunks = 0;
    wave_chunk_t *chunks = w->chunks;
    for (size_t i = 0; i < WAVE_PATHS; i++)
        free_slots[i] = (uint16_t)(WAVE_PATHS - 1 - i);
    wave_cursor_t cur = {0, 0, 0}; /* (tracer_trace refuses tasks of no samples) */
    for (;;) {
        /* start the next chunks (the next samples of one task, at most
         * WAVE_CHUNK) while there are slots for them */
        while (cur.task < count) {
            uint32_t left = tasks[cur.task].sample_count - cur.index;
            size_t size = left < WAVE_CHUNK ? left : WAVE_CHUNK;
            if (nfree < size)
                break;
            wave_chunk_t *ch = &chunks[nchunks++];
            ch->n = 0;
            rng_pixel_t pixel = rng_pixel(c->settings->seed, tasks[cur.task].pixel);
            for (size_t i = 0; i < size; i++) {
                uint16_t s = free_slots[--nfree];
                start_path(c, w, s, &tasks[cur.task], &pixel, cur.index, cur.flat);
                ch->live[ch->n++] = s;
                cur.flat++;
                cur.index++;
            }
            if (c->settings->sampler == RNG_SAMPLER_SOBOL) {
                /* the film point's pair, for the whole chunk at once */
                rng_stream_t *streams[WAVE_CHUNK];
                uint32_t first[WAVE_CHUNK] = {0};
                for (size_t i = 0; i < ch->n; i++)
                    streams[i] = &w->rng[ch->live[i]];
                rng_sobol_fill(streams, ch->n, first, 1, c->shading_lanes == WAVE_LANES_AVX512);
            }
            start_camera_rays(c, w, ch, tasks[cur.task].pixel);
            if (cur.index == tasks[cur.task].sample_count) {
                cur.index = 0;
                cur.task++;
            }
        }
        if (nchunks == 0)
            break;
        for (size_t k = 0; k < WAVE_KERNELS; k++)
            queued[k] = 0;
        /* closest hit, and the hit's own work */
        for (size_t k = 0; k < nchunks; k++)
            chunk_hits(c, w, &chunks[k], queue, queued, L, rays, free_slots, &nfree);
        /* shading, one kernel per material type present */
        for (size_t k = 0; k < WAVE_KERNELS; k++)
            if (queued[k])
                wave_kernels[k](c, w, queue[k], queued[k]);
        /* shadow rays, Russian roulette, the next ray; chunks whose paths
         * have all ended leave */
        size_t kept = 0;
        for (size_t k = 0; k < nchunks; k++) {
            chunk_continue(c, w, &chunks[k], L, rays, free_slots, &nfree);
            if (chunks[k].n > 0)
                chunks[kept++] = chunks[k];
        }
        nchunks = kept;
    }
}
