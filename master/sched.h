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
 *     flag sequence): by default the first layers are uniform
 *     (sched_default_uniform_layers), and for relerr and relmse every
 *     SCHED_UNIFORM_EVERY-th layer after them too. Layers 0 and 1 never
 *     skip: nothing is known yet when they are chosen.
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

/* What the skip rule compares with its threshold (the mean over pixels):
 *  thesis:   eq. 4.1, exactly as published;
 *  variance: the sample variance of the pixel mean (luminance, Welford/Chan);
 *  relerr:   a Student-t half-width (confidence 0.95) of the mean of the
 *            layers' means, each layer an independent batch, divided by
 *            (mean + SCHED_RELERR_EPS). Pixels with fewer than two layers
 *            have no bound yet and are always sampled.
 *  relmse:   the relMSE one more layer would take off the pixel per ray it
 *            costs: the relative variance of its mean (the same batches and
 *            scale as relerr) divided by its layers and by the rays a
 *            sample takes, v / (n^2 c) for a pixel of relative variance v
 *            per layer after n layers whose samples trace c rays each.
 *            Balancing it gives each pixel layers in proportion to
 *            sqrt(v / c), which minimises the image's relMSE for the rays
 *            (the time) spent; balancing relerr gives layers in proportion
 *            to v, which ties uniform sampling on that measure
 *            (docs/ADAPTIVE.md).
 *  relerr and relmse keep a skip-rule layer uniform while the pixels'
 *  statistics differ no more than their noise (SCHED_ALIKE_SPREAD).
 *  relerr and relmse take the relative variance of a layer mean (and relmse
 *  the rays per sample) from the pixel's 3x3 neighbours, the pixel itself
 *  left out, over their uniform layers, and the layer count from the
 *  pixel: a pixel's own samples then do not decide how many it gets, which
 *  keeps its mean unbiased (judged on its own variance, a pixel that has
 *  not yet met a rare bright path stops early and low; its own rays count
 *  with its radiance, as the long paths through glass are the bright
 *  ones). thesis and variance judge the pixel by itself, as published. */
typedef enum {
    SCHED_ADAPTIVE_NONE = 0,
    SCHED_ADAPTIVE_THESIS = 1,
    SCHED_ADAPTIVE_VARIANCE = 2,
    SCHED_ADAPTIVE_RELERR = 3,
    SCHED_ADAPTIVE_RELMSE = 4
} sched_adaptive_t;

/* Uniform layers, when the job does not say, for the variance and relerr
 * modes: enough layers for a first variance estimate of every pixel (the
 * study's options table: 2 starve dim pixels on dark-bright, 8 do not). */
#define SCHED_DEFAULT_UNIFORM_LAYERS 8
/* relerr and relmse, without a flag sequence: after the uniform layers,
 * every 4th layer (layer % 4 == 0) is uniform too, since they learn a
 * pixel's variance from its neighbours' uniform layers only (on the glass
 * scene, relMSE at equal samples against uniform sampling: 1.29x with only
 * the first 8 uniform, 0.88x with every 4th, 0.91x with every 2nd). */
#define SCHED_UNIFORM_EVERY 4

/* relerr and relmse: a skip-rule layer stays uniform when the pixels'
 * per-ray relative variances do not differ (their spread, measured as the
 * covariance over pixels of each pixel's own value with its neighbours'
 * mean, relative to the squared mean: the pixels' noise, independent from
 * pixel to pixel, leaves it out) by more than this squared coefficient of
 * variation. Balancing pixels whose variances spread that little takes at
 * most about a quarter of it (2.5 %) off the image's relMSE, and under the
 * sobol sampler each layer a pixel skips breaks its replicates' nets: on
 * the white furnace, where every pixel is alike, relmse read 29x uniform
 * sampling's relMSE at equal samples. The other shipped scenes read 0.73
 * (the Cornell box) to 15 (the caustic) at their lowest over a job; the
 * furnace reads 0.000 +- 0.001. */
#define SCHED_ALIKE_SPREAD 0.1

/* relerr's epsilon: the same scale as relMSE's (r^2 + 1e-2), so the metric
 * the sampler balances is the one the error is measured in. */
#define SCHED_RELERR_EPS 0.1
/* The target-error rule (sched_config_t.target_error): its epsilon
 * (half-width <= E (mean + eps)); the layers whose means give each pixel's
 * relative variance (its first ones, frozen after them), which is also the
 * fewest a pixel takes; and the radius of the window whose relative
 * variances (their mean with replicates, else their largest) a pixel's
 * half-width uses, the pixel itself left out. The window
 * is what makes the target hold: a pixel's own layer means look steady
 * until it meets a rare bright path its neighbours have already met
 * (bench/error/target.py measured the candidates: on the glass scene the
 * pixel's own variance left 43 % of the pixels within E = 0.05, a 5 x 5
 * window 98 %). Leaving the pixel out, and freezing every pixel's
 * statistics after the same number of layers, is what keeps the image
 * unbiased: whether a pixel stops then depends on its neighbours' first
 * layers alone, never on its own values (test_target_unbiased). */
#define SCHED_TARGET_EPS 1e-3
#define SCHED_TARGET_MIN_LAYERS 8
#define SCHED_TARGET_POOL_RADIUS 2
/* With replicates, the rule's alpha (1 - C) is divided by this: the
 * calibrated error of a pixel's neighbours is not quite its own
 * (sched_target.c; bench/error/coverage.py measured 1, 2 and 4). */
#define SCHED_TARGET_ALPHA_DIVISOR 2
/* With replicates, the layers whose replicate means give each pixel's
 * calibrated statistic (its first ones, frozen after them: more than the
 * layer means' 8, since a rare bright path must show in two replicates,
 * not in one of 8 layers), also the fewest a pixel takes; and the standard
 * errors of the neighbours' mean added to it (sched_target.c). */
#define SCHED_TARGET_CALIBRATED_LAYERS 16
#define SCHED_TARGET_UCB 1.0
/* The largest mean radiance a result may report per sample. No scene comes
 * near it (the brightest test light is 1e7), and squares and sums of it
 * stay far from overflow in every statistic the master computes: a result
 * past it is a broken or lying worker, refused before it reaches the film. */
#define SCHED_MAX_RADIANCE 1e30

/* "thesis", "variance", "relerr", "relmse", "none"; -1 for anything else. */
int sched_adaptive_from_name(const char *name);
const char *sched_adaptive_name(sched_adaptive_t a);

typedef struct sched_config {
    uint32_t width, height;
    uint32_t spp;         /* most samples per pixel */
    uint32_t granularity; /* G, samples per pixel per layer */
    sched_adaptive_t adaptive;
    uint32_t uniform_layers; /* flag sequence: layers below this never skip;
                                UINT32_MAX: the default, half of the layers */
    uint32_t range_pixels;   /* pixels per task range; 0: chosen from G */
    const char *flags;       /* the thesis's flag sequence, one '0' or '1' per
                                layer ('1': the skip rule applies), or NULL:
                                uniform_layers decides. Copied by sched_new. */
    /* Options the thesis left open. */
    int random_selection; /* a pixel below the threshold still takes part
                             with probability metric / threshold */
    int dilate;           /* grow each layer's pixels by one (3 x 3) */
    uint64_t seed;        /* for random selection */
    /* Stopping on a confidence bound: a pixel stops once the t half-width
     * of its mean at `confidence` is <= target_error (mean + eps). Its
     * relative variance per layer is its neighbours' over their first
     * layers (SCHED_TARGET_POOL_RADIUS): with replicates the mean of the
     * calibrated one their replicates give over SCHED_TARGET_CALIBRATED_LAYERS,
     * plus SCHED_TARGET_UCB standard errors of it; without them the largest
     * of their layer means' over SCHED_TARGET_MIN_LAYERS (sched_target.c).
     * The target alone then decides which pixels take a layer: every pixel
     * short of it takes every layer, whatever the adaptive mode (its skip
     * rule left pixels short of the target and of the cap at the job's
     * end). The job stops when target_share of the pixels have. 0: off. */
    double target_error;
    double confidence;   /* 0: JOB_DEFAULT_CONFIDENCE (0.95) */
    double target_share; /* 0: 1.0 */
    /* Independent replicates per pixel (rng_replicate_first_sample): layer
     * k of a pixel is replicate k mod R's. 0 or 1: one sequence. With two
     * or more the scheduler keeps each replicate's luminance sum, and
     * sched_image's variance channel is the calibrated error they give. */
    uint32_t replicates;
} sched_config_t;

typedef struct sched sched_t;

/* What sched_requeue, sched_outstanding, sched_check and sched_complete
 * return: 0, or one of these (negative, so `< 0` still means "failed"). */
typedef enum {
    SCHED_OK = 0,
    SCHED_BAD_RESULT = -1,      /* a result that fails the checks; nothing merged */
    SCHED_NOT_OUTSTANDING = -2, /* the task is not handed out: never issued,
                                   requeued, or already completed */
    SCHED_NO_MEMORY = -3        /* the task is still handed out, unchanged */
} sched_status_t;

/* What sched_next returns. */
typedef enum {
    SCHED_NEXT_TASK = 1,        /* *out is a task now handed out */
    SCHED_NEXT_NONE_READY = 0,  /* none ready now (waiting on results), or out of memory */
    SCHED_NEXT_ALL_ISSUED = -1, /* every task has been handed out or completed */
} sched_next_t;

/* A task handed out: owned by the scheduler until completed or requeued. */
typedef struct sched_task {
    uint64_t id; /* 1 + layer * range_count + range: stable across runs */
    uint32_t layer;
    uint32_t range;
    uint32_t count;               /* pixels in records */
    const tracer_task_t *records; /* with first_sample, sample_count and prior sums */
} sched_task_t;

/* NULL with a message for a bad config (zero sizes, G > TRACER_MAX_TASK_SAMPLES,
 * adaptive with G < 2: eq. 4.1 is always 0 then). */
sched_t *sched_new(const sched_config_t *cfg, char *err, size_t errlen);
void sched_destroy(sched_t **s);

uint32_t sched_layer_count(const sched_t *s);
uint32_t sched_uniform_layers(const sched_t *s);
/* The uniform layers a job of `layers` layers runs when it gives none:
 * all of them for none, half for thesis (section 5.3.2), else
 * SCHED_DEFAULT_UNIFORM_LAYERS or half, whichever is fewer. */
uint32_t sched_default_uniform_layers(sched_adaptive_t adaptive, uint32_t layers);
uint32_t sched_range_count(const sched_t *s);

/* The next ready task (requeued ones first, then in (layer, range) order).
 * Returns SCHED_NEXT_TASK and fills *out, SCHED_NEXT_NONE_READY when none
 * is ready now, SCHED_NEXT_ALL_ISSUED when every task has been handed out
 * or completed. */
int sched_next(sched_t *s, sched_task_t *out);

/* Hands out one particular ready task, as sched_next would when its turn
 * came: for replaying results merged before a restart (a journal), in the
 * order they were merged, which is an order in which each was ready.
 * SCHED_OK and *out; SCHED_NOT_OUTSTANDING when the task is not ready now
 * (never made ready, handed out, or complete); SCHED_NO_MEMORY. */
int sched_take(sched_t *s, uint64_t task_id, sched_task_t *out);

/* Puts a handed-out task back (its worker died or its lease ran out):
 * SCHED_OK, SCHED_NOT_OUTSTANDING, or SCHED_NO_MEMORY (the task stays
 * handed out: a caller that drops it then stalls the job). */
int sched_requeue(sched_t *s, uint64_t task_id);

/* Completes a handed-out task with its results (records in the task's pixel
 * order). Checks count, pixels and sample counts against the task, and
 * every value's range (finite, non-negative, at most SCHED_MAX_RADIANCE per
 * sample, zero sums for no samples, at most half the samples NaN/Inf, and
 * no merge that would make the film non-finite); SCHED_BAD_RESULT with a
 * message and nothing merged if anything is off; SCHED_NOT_OUTSTANDING
 * (with a message) if the task is not outstanding (already completed, or
 * never issued). SCHED_OK when merged. */
int sched_complete(sched_t *s, uint64_t task_id, const tracer_result_t *results, uint32_t count,
                   char *err, size_t errlen);

/* sched_complete's checks without the merge (the same codes and messages):
 * a result can be judged when it arrives and merged later, once another
 * worker's copy agrees (verification by replication, master/verify.c).
 * The checks hold until the merge: the pixels a task reads are changed
 * only by that task while it is outstanding. */
int sched_check(const sched_t *s, uint64_t task_id, const tracer_result_t *results, uint32_t count,
                char *err, size_t errlen);

/* A handed-out task, as sched_next gave it (records included), to send the
 * same task to another worker: SCHED_OK and *out, or SCHED_NOT_OUTSTANDING
 * (never issued, requeued, or completed). The records stay
 * valid until it is completed or requeued. */
int sched_outstanding(const sched_t *s, uint64_t task_id, sched_task_t *out);

int sched_done(const sched_t *s);

/* Progress: layers fully complete, tasks outstanding, samples merged. */
uint32_t sched_layers_complete(const sched_t *s);
uint64_t sched_samples_done(const sched_t *s);
/* NaN/Inf samples left out so far (a running count: status is cheap). */
uint64_t sched_nonfinite(const sched_t *s);
/* Pixel-layers scheduled so far (issued or decided), and skipped. */
uint64_t sched_pixel_layers(const sched_t *s);
uint64_t sched_pixel_layers_skipped(const sched_t *s);

/* Pixels that met the target error (as of the last decided layer), and
 * whether the job stopped on the target rather than at spp. */
uint64_t sched_converged(const sched_t *s);
int sched_stopped_on_target(const sched_t *s);
/* The image so far: the film's channels (film_to_image), its variance
 * channel calibrated when the job has replicates (sched_variance_of_mean).
 * NULL when out of memory. */
image_t *sched_image(const sched_t *s);

/* The variance of each pixel's mean luminance, into out[width x height].
 * With replicates (sched_config_t): calibrated, the variance their spread
 * gives, averaged over the 5 x 5 pixels around it (sched_error.c says
 * why); where no pixel of the window has two layers yet, and without
 * replicates, the film's own (film_variance_of_mean), which under sobol
 * overstates the error 10-50x. -1 when out of memory. */
int sched_variance_of_mean(const sched_t *s, float *out);

/* Pixels that have taken every sample spp allows. With a target error, the
 * pixels its rule has not stopped (a pixel whose light no path has found
 * yet looks converged and stops early, so this is a lower bound on the
 * pixels the rule could not judge). */
uint64_t sched_pixels_at_cap(const sched_t *s);

/* The film: per-pixel sums merged so far. */
const film_t *sched_film(const sched_t *s);

/* Whether pixel p takes part in layer l, and the threshold used for layer
 * l (0 for uniform layers): for the two layers in flight only (the first
 * incomplete layer and the next, once decided), -1 and NaN for the others,
 * which the scheduler no longer keeps (complete) or has not decided yet.
 * For tests. */
int sched_pixel_in_layer(const sched_t *s, uint32_t layer, uint32_t pixel);
double sched_threshold(const sched_t *s, uint32_t layer);

/* The scheduler's heap, array by array: fn(ctx, name, bytes) for each one
 * this job keeps (film, per-pixel statistics, the window of layers in
 * flight and their task records...); fn may be NULL. Returns the total. */
typedef void (*sched_memory_fn)(void *ctx, const char *name, size_t bytes);
size_t sched_memory(const sched_t *s, sched_memory_fn fn, void *ctx);

/* Checkpoints. sched_save streams the scheduler's whole state (the film
 * included) through write(ctx, data, len). It allocates nothing and touches
 * no globals: it runs in a forked child of the master. Tasks handed out but
 * not completed are saved as ready: a restored scheduler issues them again.
 * Returns 0, or the first non-zero value write returned.
 *
 * The stream (same-host byte order and layout; film pixels as film_pixel_t):
 * an 8-byte magic, a uint32 format version, a uint32 count n, n uint64
 * fingerprint fields; then sections, each an 8-byte ASCII tag (NUL padded),
 * a uint64 byte count and the bytes; last the section "end" holding a
 * uint64 checksum of everything before it. */
/* 2: target-error window statistics; 3: layer-mean counts for relerr and
 * relmse, whose saved metric is then a layer mean's relative variance;
 * 4: the target error's too, and its variances from uniform layers;
 * 5: relmse's rays and samples of the uniform layers, and rays per sample;
 * 6: only the two layers in flight (membership, cells), a 64-byte film
 * pixel, and each pixel's statistics before its merge into the later layer
 * in flight in place of version 5's snapshot and per-layer copies;
 * 7: version 6 and the replicates' luminance sums ("rep"), written for a job
 * with replicates (an older master refuses it by its version) and 6 for
 * one without (the same bytes as before);
 * 8: version 7 and each pixel's calibrated relative variance ("crv"),
 * written for a job with replicates and a target error, whose stopping
 * reads it (an older master refuses it by its version). This build reads
 * 5 too (sched_load converts it), and 7 for such a job: its pixels then
 * keep the statistic of before (the layer means' spread; sched_target.c). */
#define SCHED_SAVE_VERSION 6
#define SCHED_SAVE_VERSION_REPLICATES 7
#define SCHED_SAVE_VERSION_CALIBRATED 8
typedef int (*sched_write_fn)(void *ctx, const void *data, size_t len);
/* Reads exactly len bytes; returns 0, or non-zero on a short read / error. */
typedef int (*sched_read_fn)(void *ctx, void *data, size_t len);
int sched_save(const sched_t *s, sched_write_fn write, void *ctx);
/* The bytes sched_save writes for s (the same at every point of the job:
 * every size comes from the config). */
size_t sched_save_bytes(const sched_t *s);
/* A scheduler for cfg restored from what sched_save wrote. cfg must be the
 * job's config (the same one the saved scheduler was made with): a saved
 * fingerprint of the derived sizes and settings (pixels, layers, ranges,
 * range_pixels, spp, G, adaptive, uniform layers, flags, target settings,
 * seed...) must match, or it fails. Everything read is checked before it is
 * trusted: cell states in range, counts consistent with states (range_done
 * vs DONE cells, complete layers, decided flags consistent), film values
 * finite, counts that add up (samples_done equals the film's total, ...).
 * Garbage is never merged: NULL with a message naming what is wrong. */
sched_t *sched_load(const sched_config_t *cfg, sched_read_fn read, void *ctx, char *err,
                    size_t errlen);

#endif
