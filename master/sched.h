/* sched.h - variance-balanced scheduling of one job (thesis, Procedure 2),
 * as a pure module: no sockets, no clock, no threads.
 *
 * The image is cut into fixed ranges of pixels; a task is (layer, range):
 * G samples for the range's pixels that take part in that layer. Three
 * rules make the result a pure function of the settings, whatever the
 * number of workers or the order results arrive in:
 *
 *  1. Task (l, r) becomes ready only when (l-1, r) is complete. So every
 *     pixel merges its layers in order, and a task's "so far" sums (eq. 4.1)
 *     are always exactly the pixel's previous layers.
 *  2. The pixels of layer l are chosen when layer l-2 is complete, from the
 *     statistics of layers <= l-2 only (a snapshot; later results do not leak
 *     in). Layer l-1 is then still being traced, so the queue never drains
 *     at a layer boundary.
 *  3. A layer takes part in the skip rule only when its flag is set (the
 *     flag sequence): by default the first half of the layers are uniform.
 *     Layers 0 and 1 never skip: nothing is known yet when they are chosen.
 *
 * Skip rule (adaptive thesis): pixel p skips layer l if flag[l] and
 * variance[p] < threshold, where variance[p] is the eq. 4.1 statistic of
 * the last layer p took part in and threshold is its mean over all pixels
 * (eq. 4.3), both as of layer l-2.
 */
#ifndef VB_SCHED_H
#define VB_SCHED_H

#include <stddef.h>
#include <stdint.h>

#include "film.h"
#include "tracer.h"

typedef enum { SCHED_ADAPTIVE_NONE = 0, SCHED_ADAPTIVE_THESIS = 1 } sched_adaptive_t;

typedef struct sched_config {
    uint32_t width, height;
    uint32_t spp;            /* most samples per pixel */
    uint32_t granularity;    /* G, samples per pixel per layer */
    sched_adaptive_t adaptive;
    uint32_t uniform_layers; /* flag sequence: layers below this never skip;
                                UINT32_MAX: the default, half of the layers */
    uint32_t range_pixels;   /* pixels per task range; 0: chosen from G */
    const char *flags;       /* the thesis's flag sequence, one '0' or '1' per
                                layer ('1': the skip rule applies), or NULL:
                                uniform_layers decides. Copied by sched_new. */
} sched_config_t;

typedef struct sched sched_t;

/* A task handed out: owned by the scheduler until completed or requeued. */
typedef struct sched_task {
    uint64_t id;            /* 1 + layer * range_count + range: stable across runs */
    uint32_t layer;
    uint32_t range;
    uint32_t count;         /* pixels in records */
    const tracer_task_t *records; /* with first_sample, sample_count and prior sums */
} sched_task_t;

/* NULL with a message for a bad config (zero sizes, G > TRACER_MAX_TASK_SAMPLES,
 * adaptive with G < 2: eq. 4.1 is always 0 then). */
sched_t *sched_new(const sched_config_t *cfg, char *err, size_t errlen);
void sched_destroy(sched_t **s);

uint32_t sched_layer_count(const sched_t *s);
uint32_t sched_uniform_layers(const sched_t *s);
uint32_t sched_range_count(const sched_t *s);

/* The next ready task (requeued ones first, then in (layer, range) order).
 * Returns 1 and fills *out, 0 when none is ready now, -1 when every task
 * has been handed out or completed. */
int sched_next(sched_t *s, sched_task_t *out);

/* Puts a handed-out task back (its worker died or its lease ran out). */
int sched_requeue(sched_t *s, uint64_t task_id);

/* Completes a handed-out task with its results (records in the task's pixel
 * order). Checks count, pixels and sample counts against the task; -1 with
 * a message and nothing merged if they do not match; -2 if the task is not
 * outstanding (already completed, or never issued). */
int sched_complete(sched_t *s, uint64_t task_id, const tracer_result_t *results, uint32_t count,
                   char *err, size_t errlen);

int sched_done(const sched_t *s);

/* Progress: layers fully complete, tasks outstanding, samples merged. */
uint32_t sched_layers_complete(const sched_t *s);
uint64_t sched_samples_done(const sched_t *s);
/* Pixel-layers scheduled so far (issued or decided), and skipped. */
uint64_t sched_pixel_layers(const sched_t *s);
uint64_t sched_pixel_layers_skipped(const sched_t *s);

/* The film: per-pixel sums merged so far. */
const film_t *sched_film(const sched_t *s);

/* Whether pixel p takes part in layer l (decided layers only: l <= the
 * last decided layer), and the threshold used for layer l (0 for uniform
 * layers). For tests and the heat map. */
int sched_pixel_in_layer(const sched_t *s, uint32_t layer, uint32_t pixel);
double sched_threshold(const sched_t *s, uint32_t layer);

#endif
