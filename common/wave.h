/* wave.h - the wavefront engine: a task list's samples traced as a stream
 * of paths, stage by stage.
 *
 * Up to WAVE_PATHS paths are in flight, their states in arrays (one entry
 * per slot). A bounce runs the stages over every live path in turn:
 * closest hit; the hit's own work (a miss ends the path, an emitter adds
 * its MIS-weighted radiance, max_depth ends it); shading, one kernel per
 * material type over the paths that hit it (next-event estimation's
 * shadow ray and the BSDF sample); the shadow rays; Russian roulette and
 * the next ray. Paths start in chunks of one task's samples, whose rays
 * are cast in packets (WAVE_CHUNK); a chunk starts when there are free
 * slots for all of it. Each path does the very operations tracer.c's scalar engine does,
 * in its order, so a sample's radiance and ray count are the same bits in
 * both engines (test_tracer compares them sample by sample): which slot or
 * lane a path takes, and when, cannot change its value.
 *
 * A material's kernel is one file, wave_<material>.c, and one line in
 * wave.c's table: it reads the hit and the path and writes where the path
 * goes on, what its throughput becomes, and the shadow ray, if any, with
 * what the light gives when that ray is free. Not a public interface:
 * tracer.c calls wave_trace. */
#ifndef VB_WAVE_H
#define VB_WAVE_H

#include <stddef.h>
#include <stdint.h>

#include "tracer_priv.h"

/* Paths in flight: enough for whole blocks of WAVE_LANES in each kernel,
 * few enough that a hit's triangle data is still cached when its kernel
 * runs. 64 measured best over 32, 128 and 256 on cornell-buddha (100k
 * triangles: 0.94x the scalar engine at 256) and no worse on the others;
 * with chunks and packets, 128 and 256 measured the same as 64 within 3 %
 * (cornell-buddha, cornell-glass), and 64 with chunks of 16 4 % slower. */
#define WAVE_PATHS 64
/* The most samples of one task started together as a chunk. A chunk's
 * paths are at the same bounce at every step, and its rays are cast in
 * packets of TRACER_PACKET in sample order: which rays share a packet
 * depends on the task alone, never on the other tasks in the list, so a
 * worker's image does not depend on how tasks were dealt to workers. */
#define WAVE_CHUNK 32
/* The SIMD kernels' width: 4 floats, one SSE register. The kernels are
 * built for the baseline target: 8 floats there were lowered through the
 * stack. The diffuse kernel, the commonest, is built a second time for
 * AVX2 at 8 lanes (wave_diffuse_avx2.c; wave_ctx_t.shading_lanes picks it
 * where the host has AVX2): the same bits, 1 % faster on the Cornell box;
 * and a third time for AVX-512 at 16 lanes (wave_diffuse_avx512.c), picked
 * only beside the triangle list's AVX-512 kernel (tracer.c,
 * shading_lanes_for): 6.5 % faster on the Cornell box there, 6.5-9 % slower
 * beside casting that keeps to 256 bits (the clock Intel's cores lower for
 * 512-bit code). An AVX2 clone of every kernel, calling into code built without AVX,
 * had paid more for the transitions than it gained; the diffuse kernel
 * inlines all it calls on its common path. */
#define WAVE_LANES 4
#define WAVE_LANES_AVX2 8
#define WAVE_LANES_AVX512 16
/* The most samples one wave_trace call takes (the caller splits a task
 * list into runs of whole tasks no larger). */
#define WAVE_MAX_SAMPLES TRACER_MAX_TASK_SAMPLES

/* What every kernel reads. */
typedef struct wave_ctx {
    const tracer_t *tracer;
    const scene_t *scene;
    const tracer_settings_t *settings;
    int nee;           /* next-event estimation: the path integrator, with lights */
    int env;           /* the scene has an environment (scene_t.has_env) */
    int hide_camera;   /* scene_t.hide_emitters: camera rays pass emitters */
    int shading_lanes; /* the diffuse kernel's build: WAVE_LANES, _AVX2 or _AVX512 */
} wave_ctx_t;

/* A chunk's paths still going, their slots in sample order. */
typedef struct wave_chunk {
    uint16_t live[WAVE_CHUNK];
    uint16_t n;
} wave_chunk_t;

/* The paths in flight, one entry per slot. */
typedef struct wave_state {
    wave_chunk_t chunks[WAVE_PATHS]; /* the chunks in flight (one path each at least) */
    /* the path */
    rng_stream_t rng[WAVE_PATHS];
    vec3_t o[WAVE_PATHS], d[WAVE_PATHS]; /* the ray being traced; d unit length */
    vec3_t L[WAVE_PATHS], beta[WAVE_PATHS];
    float eta_scale[WAVE_PATHS]; /* product of eta^2 of the transmissions taken */
    float prev_pdf[WAVE_PATHS];  /* solid-angle pdf of the BSDF sample that made d */
    uint8_t specular[WAVE_PATHS];
    uint32_t depth[WAVE_PATHS];
    uint32_t rays[WAVE_PATHS];
    uint32_t sample[WAVE_PATHS]; /* its place in the call's sample list */
    /* the hit, as the hit stage leaves it for the kernels */
    uint32_t tri[WAVE_PATHS];
    float u[WAVE_PATHS], v[WAVE_PATHS]; /* kept off the edges (tracer_inset_from_edges) */
    float cos_o[WAVE_PATHS];            /* geometric normal . wo */
    /* a kernel's answer */
    uint8_t alive[WAVE_PATHS];  /* 0: the path ends at this hit */
    vec3_t next_d[WAVE_PATHS];  /* the new direction, normalised (vec3_normalize) */
    uint8_t shadow[WAVE_PATHS]; /* a shadow ray to test: */
    vec3_t shadow_o[WAVE_PATHS], shadow_d[WAVE_PATHS]; /* its segment (t in [0, 1)) */
    vec3_t shadow_L[WAVE_PATHS];                       /* added to L when it is free */
    /* the diffuse kernel's, with emitting spheres: the shadow ray's end
     * lights_sample_from gave (kept here, not beside the kernel's
     * vectors: there it cost the Cornell box, which has no spheres, 1-2 %) */
    vec3_t shadow_to[WAVE_PATHS];
} wave_state_t;

/* The surface slot s hit, as tracer.c's trace_sample sees it: its
 * material, the point and the normals oriented to the ray's side. */
static inline const material_t *wave_surface(const wave_ctx_t *c, const wave_state_t *w, uint16_t s,
                                             vec3_t *p, material_hit_t *mh)
{
    const scene_t *sc = c->scene;
    tracer_hit_t h = {.tri = w->tri[s], .u = w->u[s], .v = w->v[s]};
    *p = scene_point(sc, h.tri, h.u, h.v);
    *mh = tracer_orient_normals(sc, &h, vec3_neg(w->d[s]), w->cos_o[s]);
    return &sc->materials[sc->tri_material[h.tri]];
}

/* Slot s goes on along the direction bs sampled from the surface at p:
 * tracer.c's trace_sample after material_sample, for kernels that sample
 * path by path. */
static inline void wave_follow(wave_state_t *w, uint16_t s, vec3_t p, const material_hit_t *mh,
                               const material_sample_t *bs)
{
    w->beta[s] = vec3_mul(w->beta[s], bs->weight);
    if (bs->transmits)
        w->eta_scale[s] *= bs->eta * bs->eta;
    w->prev_pdf[s] = bs->pdf;
    w->specular[s] = (uint8_t)bs->specular;
    w->o[s] = vec3_offset_ray_origin(p, bs->transmits ? vec3_neg(mh->ngf) : mh->ngf);
    w->next_d[s] = vec3_normalize(bs->wi);
}

/* A material's kernel: shades the n paths in slots[0..n), which all hit
 * surfaces of its material type, and sets alive, and for the living
 * beta, eta_scale, prev_pdf, specular, o (the new origin), next_d
 * and the rng's dimension; shadow, and the shadow ray, for each. */
typedef void (*wave_kernel_t)(const wave_ctx_t *c, wave_state_t *w, const uint16_t *slots,
                              size_t n);

/* Under the sobol sampler, computes ahead, for all n paths in slots[] at
 * once (rng_sobol_fill), the pairs a kernel that samples a light and a
 * BSDF draws at their bounce: the light pair and the BSDF pair, or the
 * BSDF pair alone without next-event estimation; paths past the
 * quasi-random bounces are left out. Such a kernel calls it first: a pair
 * one path at a time costs about a hundred integer operations. Sixteen
 * streams a vector where the diffuse kernel runs 16 lanes (512-bit code is
 * then paid for anyway), eight elsewhere. */
void wave_sobol_ahead(const wave_ctx_t *c, wave_state_t *w, const uint16_t *slots, size_t n);

void wave_kernel_diffuse(const wave_ctx_t *c, wave_state_t *w, const uint16_t *slots, size_t n);
/* (its AVX2 and AVX-512 builds, which wave_kernel_diffuse calls as
 * c->shading_lanes says) */
void wave_kernel_diffuse_avx2(const wave_ctx_t *c, wave_state_t *w, const uint16_t *slots,
                              size_t n);
void wave_kernel_diffuse_avx512(const wave_ctx_t *c, wave_state_t *w, const uint16_t *slots,
                                size_t n);
void wave_kernel_mirror(const wave_ctx_t *c, wave_state_t *w, const uint16_t *slots, size_t n);
void wave_kernel_dielectric(const wave_ctx_t *c, wave_state_t *w, const uint16_t *slots, size_t n);
void wave_kernel_glossy(const wave_ctx_t *c, wave_state_t *w, const uint16_t *slots, size_t n);

/* Traces every sample of tasks[0..count) (at most WAVE_MAX_SAMPLES in
 * all; checked by the caller): sample i of task k lands at index
 * (samples of tasks before k) + i of L and rays. w is scratch. */
void wave_trace(const wave_ctx_t *c, wave_state_t *w, const tracer_task_t *tasks, size_t count,
                vec3_t *L, uint32_t *rays);

#endif
