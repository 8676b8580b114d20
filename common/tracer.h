/* tracer.h - the rendering core: "trace these samples for these pixels".
 *
 * A tracer holds the scene's ray-casting structure, built once and then
 * only read, so any number of threads may call tracer_trace at once: for a
 * scene of up to TRILIST_MAX_TRIANGLES triangles the whole triangle list,
 * tested 8 or 16 at a time (trilist.h), else Embree's BVH. A call
 * takes a list of pixel tasks (the thesis's message, table 4.3: pixel,
 * samples to take, first sample index, samples and RGB sums so far) and
 * fills one result per task with exactly what a worker sends back: RGB
 * sums, samples taken, the eq. 4.1 statistic, the luminance sum of squared
 * deviations, and the count of NaN/Inf samples left out. It allocates
 * nothing; every random number comes from (seed, pixel, sample index,
 * dimension), so the answer does not depend on which thread, worker or
 * attempt computes it.
 */
#ifndef VB_TRACER_H
#define VB_TRACER_H

#include <stddef.h>
#include <stdint.h>

#include "rng.h"
#include "scene.h"

/* The most samples one pixel task may take: the eq. 4.1 statistic keeps each
 * running estimate of the task on the stack. A layer is G samples, G <= this. */
#define TRACER_MAX_TASK_SAMPLES 4096
/* The tracer's version: raised whenever the same (scene, settings, seed,
 * pixel, sample) would give another value (a sampler or estimator change).
 * It is part of the build id (proto_build_id), so a master refuses a worker
 * built from a commit that traces different bits, as it refuses another
 * ISA: 2 since the light and the point on it come from one pair of
 * numbers (lights_sample) and new rays leave 16 ulps off the surface
 * (vmath_offset_coord); 3 since a material may be one-sided (a build
 * without that would draw such a scene two-sided; our own scenes' bits
 * are unchanged); 4 since the glossy materials and the direct integrator
 * (a build without them cannot trace such a scene or task); 5 since a light
 * sample picks its emitter as Mitsuba does, the environment, each light
 * with no area and each emitting material alike (scene.c
 * finish_delta_lights, build_light_cdf: scenes with more than one draw
 * other numbers; our own scenes, one emitter each, keep their bits); 6
 * since the wavefront engine casts Embree rays in packets of 8 (tracer_priv.h
 * TRACER_PACKET: the same bits as one ray a call on every ray we tested,
 * but Embree does not promise it, so a worker of each kind stays apart); 7
 * since paths are traced with denormals flushed to zero (tracer_trace: a
 * value that would have been denormal is 0; our scenes keep their bits); 8
 * since the cosine bounce takes its sin and cos from a polynomial
 * (vmath_sincos_turn), not libm's calls: our scenes' bits change; 9 since
 * a scene of more than TRILIST_MAX_TRIANGLES finds its closest hits by our
 * traversal of a BVH Embree builds (bvh.h: trilist's triangle test, not
 * Embree's), on AVX2 hosts, unless it has smooth glass; 10 since such a
 * scene's shadow rays go through it too (Embree builds no scene of its
 * own for it); 11 since that BVH's spatial splits bound a vertex on the
 * plane on both sides (bvh.c: a part could miss the corner there, so a
 * hierarchy may differ where one did); 12 since a light sample of an
 * environment map reads the cell it picked (lights_env_sample) instead of
 * going back from its direction, and takes vmath_sincos_turn's sines,
 * and the direct integrator with one light and one BSDF sample is traced
 * as the path integrator cut after the bounce (its numbers the path's);
 * 13 since, under the sobol sampler, the first bounce's light pair shares
 * the camera pair's index and the second bounce's BSDF pair the first's
 * (rng.h, rng_sobol_partner); 14 since Russian roulette spares a path
 * until its throughput falls below the scene's rr_threshold
 * (SCENE_RR_THRESHOLD, 1/4), where it had played on the throughput itself,
 * and caps survival at its rr_cap (SCENE_RR_CAP, 0.99, was 0.95); 15
 * since the watertight triangle test shears a vertex with one rounding
 * (a fused multiply-add: trilist_kernel.inc, bvh_kernel.inc). */
#define TRACER_VERSION 15
/* Russian roulette starts after this many bounces unless the scene says
 * otherwise (scene_t.rr_depth; as Mitsuba 3's default rr_depth). */
#define TRACER_RR_DEPTH SCENE_RR_DEPTH

typedef struct tracer tracer_t;

/* 1 when a scene too big for the triangle list is traced by our traversal
 * (bvh.h): the host runs it (AVX2) and no triangle is smooth glass
 * (tracer.c says why); 0 when Embree's packets cast its rays. */
int tracer_own_traversal(const scene_t *s);

/* The Embree device: one per process, shared by every tracer in it (a
 * worker's cached scenes, the embedded render's workers). Its ISA is pinned
 * so that every process running this binary on a host with that ISA traces
 * the same bits; its error callback reports into the device, not stderr.
 * Thread-safe once created. */
typedef struct tracer_device tracer_device_t;

int tracer_device_new(tracer_device_t **out, char *err, size_t errlen);
void tracer_device_destroy(tracer_device_t **d);
/* The ISA the device runs ("avx2" or "sse4.2"). */
const char *tracer_device_isa(const tracer_device_t *d);

/* Per-job settings of a trace call. */
typedef struct tracer_settings {
    uint64_t seed;
    scene_integrator_t integrator;
    uint32_t max_depth;    /* 0: unlimited; else the most path segments */
    rng_sampler_t sampler; /* where a sample's numbers come from (rng.h); under
                            * sobol a pixel's samples are one scrambled Sobol
                            * sequence, each a function of its index alone */
} tracer_settings_t;

/* The sampler named "sobol" or "independent", or -1. */
int tracer_sampler_from_name(const char *name);
/* The name of a sampler ("sobol", "independent"). */
const char *tracer_sampler_name(rng_sampler_t sampler);

/* One pixel of a task (the thesis's master -> slave message). */
typedef struct tracer_task {
    uint32_t pixel;        /* y * width + x */
    uint32_t sample_count; /* samples to take, 1..TRACER_MAX_TASK_SAMPLES */
    uint64_t first_sample; /* index of the first sample: the pixel's samples so far */
    uint64_t prior_count;  /* finite samples merged so far */
    double prior_sum[3];   /* their RGB sums, for eq. 4.1's running estimates */
} tracer_task_t;

/* One pixel's answer (slave -> master). */
typedef struct tracer_result {
    uint32_t pixel;
    uint32_t samples;   /* finite samples in the sums */
    uint32_t nonfinite; /* NaN/Inf samples counted and left out */
    uint32_t rays;      /* rays traced for these samples (camera, extension, shadow; at
                         * least one a sample), saturated at UINT32_MAX: what a
                         * pixel's samples cost, for relmse's allocation (sched.h) */
    double sum[3];      /* RGB sums of this task's finite samples */
    double lum_m2;      /* sum of squared deviations of luminance from this task's mean */
    double pvar;        /* eq. 4.1: sum over i < G of (P_i - P_G)^2 */
} tracer_result_t;

typedef struct tracer_stats {
    uint64_t rays;    /* camera, extension and shadow rays traced */
    uint64_t samples; /* samples taken, finite or not */
} tracer_stats_t;

/* How rays find the scene's surfaces. */
typedef enum tracer_accel {
    TRACER_ACCEL_AUTO,    /* tracer_accel_for(scene) */
    TRACER_ACCEL_EMBREE,  /* Embree's BVH */
    TRACER_ACCEL_TRILIST, /* every triangle tested, SIMD (trilist.h) */
    TRACER_ACCEL_BVH,     /* our traversal of a BVH Embree builds (bvh.h; AVX2) */
} tracer_accel_t;

/* What tracer_new uses for a scene: the triangle list up to
 * TRILIST_MAX_TRIANGLES triangles; above, our traversal (bvh.h) where
 * tracer_own_traversal says so, Embree's otherwise. A function of the
 * scene (and the host's ISA, which the build id carries) alone, so every
 * worker of a job traces the same bits. */
tracer_accel_t tracer_accel_for(const scene_t *scene);

/* Builds the BVH for a scene on a device. Both are borrowed and must
 * outlive the tracer. Returns 0, or -1 with a message (Embree's own, from
 * the device's error callback, when it refuses). */
int tracer_new(tracer_device_t *device, const scene_t *scene, tracer_t **out, char *err,
               size_t errlen);
/* tracer_new with the acceleration chosen (tests and benchmarks compare
 * the two on one scene). */
int tracer_new_accel(tracer_device_t *device, const scene_t *scene, tracer_accel_t accel,
                     tracer_t **out, char *err, size_t errlen);
void tracer_destroy(tracer_t **t);

/* The Embree ISA this tracer runs ("avx2" or "sse4.2"). */
const char *tracer_isa(const tracer_t *t);

/* The paths the wavefront's diffuse shading takes at once: 16 (its
 * AVX-512 build, beside the triangle list's AVX-512 kernel), 8 (AVX2) or
 * 4 (the baseline); the same bits in all. */
int tracer_shading_lanes(const tracer_t *t);

/* Runs our own SIMD kernels (the triangle list's, our traversal's and the
 * wavefront's diffuse shading, the only code built for more than the
 * baseline ISA besides Embree, which is pinned to AVX2) for "avx512",
 * "avx2" or "sse2" (the baseline: not with our traversal, which needs
 * AVX2): the same bits whichever, at the speed a host with only that ISA
 * would see (bench_core --isa). Returns -1, changing nothing, if the host
 * cannot run it, the tracer has no such kernels, or the name is unknown. */
int tracer_use_isa(tracer_t *t, const char *isa);

/* Traces count tasks into results[0..count). Thread-safe; no allocation.
 * stats, if not NULL, is added to (not reset). Returns 0, or -1 with a
 * message when a task is out of range (pixel outside the image, sample
 * count 0 or too large); then no result is valid. */
int tracer_trace(const tracer_t *t, const tracer_settings_t *settings, const tracer_task_t *tasks,
                 size_t count, tracer_result_t *results, tracer_stats_t *stats, char *err,
                 size_t errlen);

/* How a tracer runs its samples. Both give the same bits for every sample
 * (test_tracer compares them sample list by sample list). The wavefront
 * engine (wave.h) is the default: 1.03x the scalar engine's samples/s on
 * the Cornell box, cornell-glass and cornell-buddha alike, one thread, best
 * of alternating rounds (parity within this host's noise at two threads);
 * the scalar one stays as the reference the wavefront is checked against. */
typedef enum tracer_engine {
    TRACER_ENGINE_WAVEFRONT, /* paths in flight, stage by stage (wave.h) */
    TRACER_ENGINE_SCALAR,    /* one sample at a time, bounce by bounce */
} tracer_engine_t;

/* Chooses the engine; not while another thread traces with t. */
void tracer_use_engine(tracer_t *t, tracer_engine_t engine);

/* Russian roulette's survival probability in scene s for a path of
 * throughput beta that has crossed dielectric interfaces whose eta^2
 * multiply to eta_scale (1 outside glass). beta carries their 1/eta^2
 * radiance compression, which says nothing about how much the path will
 * still carry: the decision is made on beta * eta_scale, as pbrt-v4 and
 * Mitsuba 3 do, over the scene's rr_threshold, capped at its rr_cap. */
float tracer_roulette_probability(const scene_t *s, vec3_t beta, float eta_scale);

/* Radiance of sample `sample_index` of a pixel (no statistics); for tests
 * and tools. Returns the rays traced. */
uint32_t tracer_sample(const tracer_t *t, const tracer_settings_t *settings, uint32_t pixel,
                       uint64_t sample_index, float rgb[3]);

#endif
