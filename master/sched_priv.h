/* sched_priv.h - what the scheduler's files share (not an interface: the
 * interface is sched.h).
 *
 * The scheduler is five files, one concept each:
 * - sched.c: task states, the window of two layers, dispatch order, and
 *   merging results;
 * - sched_rules.c: the adaptive rules (one table, one function per rule),
 *   the statistics a decision reads, and the decision itself;
 * - sched_target.c: target-error stopping;
 * - sched_save.c: checkpoints (save, load, and the checks a loaded state
 *   passes);
 * - sched_error.c: the per-pixel error the image carries (the replicates').
 */
#ifndef VB_SCHED_PRIV_H
#define VB_SCHED_PRIV_H

#include <stddef.h>
#include <stdint.h>

#include "sched.h"

enum { ST_WAITING = 0, ST_READY, ST_OUT, ST_DONE };

#define SCHED_TASK_SAMPLES 32768     /* samples a task aims at (range_pixels 0) */
#define SCHED_MIN_RANGES 64          /* ... but at least this many ranges */
#define SCHED_MAX_PIXELS (1u << 28)  /* width x height */
#define SCHED_REQUEUE_CAP0 64        /* requeued ids before the stack grows */
#define SCHED_RELERR_CONFIDENCE 0.95 /* relerr's half-width (sched.h) */
#define SCHED_RING 5                 /* rows a decision keeps: 2 SCHED_TARGET_POOL_RADIUS + 1 */

/* One row of the snapshot a decision reads (decide_layer). */
typedef struct snap_row {
    int y;          /* the image row held, -1: none */
    double *metric; /* the skip rule's statistic (sched.h) */
    double *rvar;   /* the target error's relative variance */
    double *rvmax;  /* rvar's maximum over the row's 5-pixel window, itself in */
    uint32_t *nb;   /* layer means */
    float *cost;    /* relmse: rays per sample */
} snap_row_t;

/* One row of the skip rule's choice before dilation (decide_layer). */
typedef struct sel_row {
    int y; /* -1: none */
    uint8_t *sel;
} sel_row_t;

struct sched {
    sched_config_t cfg;
    char *flags; /* copy of cfg.flags, or NULL */
    uint32_t npix, layers, ranges, range_pixels, uniform;
    film_t *film;
    uint32_t complete;  /* layers fully complete (the next incomplete layer) */
    uint32_t decided_n; /* layers decided: 0 before the first sched_next, then
                           complete + 2 (at most all of them) */
    /* The window: layer l in [complete, decided_n) in slot l & 1. */
    uint8_t *member[2];     /* npix bits: pixel takes part in the layer */
    uint8_t *state[2];      /* per range */
    uint32_t range_done[2]; /* ranges complete */
    double threshold[2];    /* the skip rule's threshold (0: uniform layer) */
    tracer_task_t **out[2]; /* per range: records of an issued task */
    uint32_t *out_count[2];
    /* Per pixel: what decisions read (sched.h), current as of the pixel's
     * last merge; what it was before a merge into the later layer in
     * flight (prev_*); see the top of this file. */
    double *pvar_cur;    /* thesis: eq. 4.1 of the last merged layer */
    double *prev_metric; /* any adaptive mode */
    double *prev_rvar;   /* with a target error */
    uint32_t *prev_nb;   /* relerr, relmse, target error */
    float *prev_cost;    /* relmse */
    uint32_t *batches;   /* relerr, relmse, target: layers merged with samples */
    uint32_t *ubatches;  /* the same, over the layers its neighbours judge it by */
    double *umean, *um2; /* Welford over those layers' luminance means */
    /* relmse: what a sample of the pixel costs, in rays, over the same
     * layers as ubatches (their rays and samples, NaN/Inf ones too) */
    uint64_t *urays;
    uint32_t *usamples;
    /* with replicates: per pixel, the luminance sums of replicates 1 .. R - 1
     * (replicate 0's is the film's sum less these) */
    double *rep_lum;
    /* with replicates and a target error: per pixel, the relative variance
     * of a layer mean its replicates give over its first
     * SCHED_TARGET_CALIBRATED_LAYERS layers (sched_target.c), frozen then; -1
     * before, or where they give none */
    double *crv;
    snap_row_t ring[SCHED_RING];
    double *row_metric; /* one row of the skip rule's statistic */
    sel_row_t sel_ring[3];
    double *t_table;  /* t factors by batches - 1, for relerr (0.95) and the target, */
    double *t_target; /* 0 until first needed (t_factor), grown on demand */
    size_t t_cap;
    uint64_t converged;
    int stopped_on_target;
    /* Ready task ids, one FIFO ring per window slot (layer & 1), entries
     * sched_take took skipped: the earlier layer's are issued first, so the
     * layer whose completion decides the next one is never left waiting
     * behind the later one's tasks (sched_next). */
    struct ready_ring {
        uint64_t *ids;
        size_t head, tail;
    } ready[2];
    size_t q_cap;       /* each ring's */
    uint64_t *requeued; /* handed back, issued first (LIFO) */
    size_t rq_len, rq_cap;
    uint64_t samples_done, pixel_layers, skipped, nonfinite;
    uint64_t at_cap; /* pixels whose samples taken reached spp (not saved: from the film) */
};

static inline uint64_t task_id(const sched_t *s, uint32_t layer, uint32_t range)
{
    return 1 + (uint64_t)layer * s->ranges + range;
}

static inline int is_member(const sched_t *s, uint32_t layer, uint32_t pixel)
{
    return (s->member[layer & 1][pixel >> 3] >> (pixel & 7)) & 1;
}

static inline void set_member(sched_t *s, uint32_t layer, uint32_t pixel)
{
    s->member[layer & 1][pixel >> 3] |= (uint8_t)(1u << (pixel & 7));
}

static inline int in_window(const sched_t *s, uint32_t layer)
{
    return layer >= s->complete && layer < s->decided_n;
}

/* Any cell's state: complete below the window, waiting above it. */
static inline uint8_t cell_state(const sched_t *s, uint32_t layer, uint32_t range)
{
    if (layer < s->complete)
        return ST_DONE;
    if (layer >= s->decided_n)
        return ST_WAITING;
    return s->state[layer & 1][range];
}

static inline void set_state(sched_t *s, uint32_t layer, uint32_t range, uint8_t st)
{
    s->state[layer & 1][range] = st;
}

static inline size_t member_bytes(const sched_t *s)
{
    return ((size_t)s->npix + 7) / 8;
}

static inline uint32_t range_members(const sched_t *s, uint32_t layer, uint32_t range)
{
    uint32_t p0 = range * s->range_pixels, p1 = p0 + s->range_pixels, n = 0;
    if (p1 > s->npix)
        p1 = s->npix;
    for (uint32_t p = p0; p < p1; p++)
        n += (uint32_t)is_member(s, layer, p);
    return n;
}

/* Each per-pixel array and whether this job keeps it (by what its mode
 * reads): one table for allocation, freeing, sched_memory and checkpoints. */
typedef struct pixel_array {
    const char *name; /* the checkpoint section's tag (8 characters at most) */
    size_t offset;    /* of the pointer in sched_t */
    size_t size;      /* of an element */
    int (*kept)(const sched_t *s);
    /* elements per pixel (NULL: one) */
    uint32_t (*per_pixel)(const sched_t *s);
    /* 1: a checkpoint has the section only where the job keeps it (a newer
     * array: streams of before it, and of jobs without it, stay as they were) */
    int only_if_kept;
} pixel_array_t;

/* The per-pixel arrays (sched.c): allocation, freeing, sched_memory and
 * checkpoints walk this one table. */
extern const pixel_array_t sched_pixel_arrays[];
extern const size_t sched_pixel_array_count;

static inline void **sched_array_slot(sched_t *s, const pixel_array_t *a)
{
    return (void **)((char *)s + a->offset);
}
static inline const void *sched_array_of(const sched_t *s, const pixel_array_t *a)
{
    return *(void *const *)((const char *)s + a->offset);
}
/* Bytes of array a in this job (0 when not kept). */
static inline size_t sched_array_bytes(const sched_t *s, const pixel_array_t *a)
{
    return a->kept(s) ? (size_t)s->npix * a->size * (a->per_pixel ? a->per_pixel(s) : 1) : 0;
}

/* One more batch mean x into a Welford accumulator (count, mean, sum of
 * squared deviations). */
static inline void sched_welford_add(uint32_t *n, double *mean, double *m2, double x)
{
    uint32_t k = ++*n;
    double d = x - *mean;
    *mean += d / k;
    *m2 += d * (x - *mean);
}

/* ---- sched.c ---- */

/* Layer is decided: the ranges whose previous layer is done can run. */
void sched_decided(sched_t *s, uint32_t layer);

/* The layers a pixel's target-error statistics are frozen after (and the
 * fewest it takes): SCHED_TARGET_CALIBRATED_LAYERS with replicates. */
static inline uint32_t sched_target_layers(const sched_t *s)
{
    return s->crv ? SCHED_TARGET_CALIBRATED_LAYERS : SCHED_TARGET_MIN_LAYERS;
}

/* Replicates of the job (rng_replicate_first_sample): 1 for none. */
static inline uint32_t sched_replicates(const sched_t *s)
{
    return s->cfg.replicates > 1 ? s->cfg.replicates : 1;
}

/* ---- sched_rules.c ---- */

/* What the job's mode keeps and reads (sched_rules.c has the why). */
int sched_pools_neighbours(const sched_t *s);
int sched_keeps_counts(const sched_t *s);
int sched_weighs_cost(const sched_t *s);
/* Whether layer's pixels are chosen by the skip rule (rule 3). */
int sched_applies_skip_rule(const sched_t *s, uint32_t layer);
/* Before pixel p merges the later layer in flight: keep what it replaces. */
void sched_keep_prev(sched_t *s, uint32_t p);
/* (sched.c) Queues ready task id on its layer's ring. */
void sched_push_ready(sched_t *s, uint64_t id);
/* Row y of the snapshot a decision reads, computed on first use. */
snap_row_t *sched_snap_row(sched_t *s, int y);
/* Chooses the pixels of layer s->decided_n from the snapshot. */
void sched_decide_layer(sched_t *s, uint32_t layer);

/* ---- sched_target.c ---- */

/* The two-sided t factor at `confidence` for k degrees of freedom, cached
 * in *table (s->t_table or s->t_target). */
double sched_t_factor(sched_t *s, double **table, double confidence, uint32_t k);
/* Pixel p's relative variance of a layer mean, as the target reads it. */
double sched_target_rvar(const sched_t *s, uint32_t p);
/* With replicates, once pixel p has merged its sched_target_layers()-th
 * layer (and nothing after it): freezes s->crv[p]. */
void sched_target_freeze(sched_t *s, uint32_t p);
/* Row r's rvmax from its rvar (a snapshot row being filled). */
void sched_target_row_max(const sched_t *s, snap_row_t *r);
/* Whether pixel (x, y) meets the target error, from the snapshot. */
int sched_meets_target(sched_t *s, int x, int y);

/* ---- sched_error.c ---- */

/* Pixel p's replicate estimate of the variance of its mean luminance, from
 * the film and s->rep_lum; -1 when fewer than two replicates have samples. */
double sched_replicate_variance(const sched_t *s, uint32_t p);

#endif
