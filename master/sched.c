/* sched.c - see sched.h for the rules that make scheduling deterministic.
 *
 * State per (layer, range): not ready, ready (queued), outstanding, or
 * complete. Only two layers are ever in flight, the first incomplete one
 * and the next (rule 1: a layer's pixels are decided when the layer two
 * before it completes), so the scheduler keeps cell states and membership
 * for those two only, in a window of two slots (layer l in slot l & 1):
 * every earlier layer is complete, every later one undecided. What a
 * complete layer leaves behind lives in the film (the samples a pixel has
 * taken, which is also where its next layer starts) and in the per-pixel
 * statistics. So the master's memory grows with the pixels, not with
 * pixels x layers.
 *
 * A decision reads each pixel's statistics as of the layer just completed
 * (the snapshot). Pixels of the later layer in flight may have merged it
 * already; those are the only pixels whose statistics have moved past the
 * snapshot, by exactly one layer, so each merge into that later layer
 * keeps the value it replaces (the prev_* arrays), and a decision reads a
 * pixel's current statistics or, where it merged ahead, that kept value.
 * The rows a decision reads around a pixel (its 3 x 3 or 5 x 5
 * neighbourhood) are computed into a ring of a few rows, not whole images.
 */
#include "sched.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "defaults.h"
#include "rng.h"
#include "stats.h"
#include "vmath.h"

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
    snap_row_t ring[SCHED_RING];
    double *row_metric; /* one row of the skip rule's statistic */
    sel_row_t sel_ring[3];
    double *t_table;  /* t factors by batches - 1, for relerr (0.95) and the target, */
    double *t_target; /* 0 until first needed (t_factor), grown on demand */
    size_t t_cap;
    uint64_t converged;
    int stopped_on_target;
    uint64_t *queue; /* ready task ids, FIFO (entries sched_take took are skipped) */
    size_t q_head, q_tail, q_cap;
    uint64_t *requeued; /* handed back, issued first (LIFO) */
    size_t rq_len, rq_cap;
    uint64_t samples_done, pixel_layers, skipped, nonfinite;
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
static uint8_t cell_state(const sched_t *s, uint32_t layer, uint32_t range)
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

static size_t member_bytes(const sched_t *s)
{
    return ((size_t)s->npix + 7) / 8;
}

/* Where pixel p's samples of its next layer start: after the samples it has
 * taken, so that a pixel's samples are always the first ones of its sample
 * sequence, whichever layers the adaptive rule skipped (under the sobol
 * sampler the first 2^m samples of a pixel form a net, an arbitrary set of
 * layers does not: rng.h). Every layer but the last takes G, and a task is
 * made only once its range's earlier layers are merged (rule 1): the film's
 * count of samples taken is exactly the samples of the layers before. */
static uint64_t first_sample_of(const sched_t *s, uint32_t p)
{
    const film_pixel_t *fp = &s->film->pixels[p];
    return (uint64_t)fp->count + fp->nonfinite;
}

/* Samples a pixel takes in layer l: G, or what is left of spp in the last. */
static uint32_t layer_samples(const sched_t *s, uint32_t layer)
{
    uint64_t first = (uint64_t)layer * s->cfg.granularity;
    return (uint32_t)(s->cfg.spp - first < s->cfg.granularity ? s->cfg.spp - first
                                                              : s->cfg.granularity);
}

static uint32_t range_members(const sched_t *s, uint32_t layer, uint32_t range)
{
    uint32_t p0 = range * s->range_pixels, p1 = p0 + s->range_pixels, n = 0;
    if (p1 > s->npix)
        p1 = s->npix;
    for (uint32_t p = p0; p < p1; p++)
        n += (uint32_t)is_member(s, layer, p);
    return n;
}

/* The config's own consistency, before anything is derived from it. */
static int check_config(const sched_config_t *cfg, char *err, size_t errlen)
{
    if (cfg->width == 0 || cfg->height == 0 || cfg->spp == 0) {
        snprintf(err, errlen, "image size and spp must be positive");
        return -1;
    }
    if (cfg->granularity == 0 || cfg->granularity > TRACER_MAX_TASK_SAMPLES) {
        snprintf(err, errlen, "granularity must be 1..%d", TRACER_MAX_TASK_SAMPLES);
        return -1;
    }
    if (cfg->target_error < 0 || !isfinite(cfg->target_error) || cfg->confidence < 0 ||
        cfg->confidence >= 1 || cfg->target_share < 0 || cfg->target_share > 1) {
        snprintf(err, errlen,
                 "target error must be >= 0, confidence in (0, 1), target share in (0, 1]");
        return -1;
    }
    if (cfg->adaptive == SCHED_ADAPTIVE_THESIS && cfg->granularity < 2) {
        snprintf(err, errlen, "adaptive sampling needs granularity >= 2 (eq. 4.1 is 0 for G = 1)");
        return -1;
    }
    if ((uint64_t)cfg->width * cfg->height > SCHED_MAX_PIXELS) {
        snprintf(err, errlen, "image too large (%llu pixels, at most %u)",
                 (unsigned long long)cfg->width * cfg->height, SCHED_MAX_PIXELS);
        return -1;
    }
    return 0;
}

/* Pixels, layers, the range partition and the uniform layers, from s->cfg. */
static void derive_sizes(sched_t *s)
{
    const sched_config_t *cfg = &s->cfg;
    s->npix = cfg->width * cfg->height;
    s->layers = (uint32_t)(((uint64_t)cfg->spp + cfg->granularity - 1) / cfg->granularity);
    /* About SCHED_TASK_SAMPLES a task: tens of milliseconds on one core; but
     * at least SCHED_MIN_RANGES ranges, so a small image still spreads over
     * many workers. The partition does not change a pixel's result: each
     * pixel merges its layers in order whatever range it sits in. */
    uint32_t rp = cfg->range_pixels;
    if (!rp) {
        rp = SCHED_TASK_SAMPLES / cfg->granularity;
        uint32_t spread = (s->npix + SCHED_MIN_RANGES - 1) / SCHED_MIN_RANGES;
        rp = rp < spread ? rp : spread;
    }
    s->range_pixels = rp < 1 ? 1 : rp;
    s->ranges = (s->npix + s->range_pixels - 1) / s->range_pixels;
    s->uniform = cfg->uniform_layers != UINT32_MAX
                     ? cfg->uniform_layers
                     : sched_default_uniform_layers(cfg->adaptive, s->layers);
}

uint32_t sched_default_uniform_layers(sched_adaptive_t adaptive, uint32_t layers)
{
    if (adaptive == SCHED_ADAPTIVE_NONE)
        return layers;
    /* The thesis (section 5.3.2) runs half the layers uniformly. The other
     * modes start skipping after a fixed few, so a job bounded by time or
     * by a target error (whose --spp is only a cap, often huge) adapts too;
     * half a small job's layers stays the bound, as in the thesis. */
    uint32_t half = layers / 2;
    if (adaptive == SCHED_ADAPTIVE_THESIS || half < SCHED_DEFAULT_UNIFORM_LAYERS)
        return half;
    return SCHED_DEFAULT_UNIFORM_LAYERS;
}

/* Checks and copies the flag sequence, if any (s->cfg.flags then points at
 * the copy). */
static int copy_flags(sched_t *s, char *err, size_t errlen)
{
    const char *flags = s->cfg.flags;
    if (!flags)
        return 0;
    size_t n = strlen(flags);
    if (n != s->layers || strspn(flags, "01") != n) {
        snprintf(err, errlen,
                 "flag sequence must be %u characters of 0 and 1 (one per layer), got %zu",
                 s->layers, n);
        return -1;
    }
    if (s->cfg.adaptive == SCHED_ADAPTIVE_NONE) {
        snprintf(err, errlen, "a flag sequence needs adaptive sampling");
        return -1;
    }
    s->flags = malloc(n + 1);
    if (!s->flags) {
        snprintf(err, errlen, "out of memory");
        return -1;
    }
    memcpy(s->flags, flags, n + 1);
    s->cfg.flags = s->flags;
    /* uniform_layers reports the leading run of zeros */
    s->uniform = (uint32_t)strspn(flags, "0");
    return 0;
}

/* One more batch mean x into a Welford accumulator (count, mean, sum of
 * squared deviations). */
static void welford_add(uint32_t *n, double *mean, double *m2, double x)
{
    uint32_t k = ++*n;
    double d = x - *mean;
    *mean += d / k;
    *m2 += d * (x - *mean);
}

/* relerr and relmse decide from the pixel's neighbours (decide_layer). */
static int pools_neighbours(const sched_t *s)
{
    return s->cfg.adaptive == SCHED_ADAPTIVE_RELERR || s->cfg.adaptive == SCHED_ADAPTIVE_RELMSE;
}

/* Layer-mean counts per pixel, and the statistics of the layer means its
 * neighbours judge it by (its uniform layers; with a target error, its
 * first SCHED_TARGET_MIN_LAYERS): kept for the target error and for the
 * modes that pool their neighbours. */
static int keeps_counts(const sched_t *s)
{
    return s->cfg.target_error > 0 || pools_neighbours(s);
}

/* relmse weighs a layer's gain against what its samples cost (sched.h). */
static int weighs_cost(const sched_t *s)
{
    return s->cfg.adaptive == SCHED_ADAPTIVE_RELMSE;
}

/* Each per-pixel array and whether this job keeps it (by what its mode
 * reads): one table for allocation, freeing, sched_memory and checkpoints. */
typedef struct pixel_array {
    const char *name; /* the checkpoint section's tag (8 characters at most) */
    size_t offset;    /* of the pointer in sched_t */
    size_t size;      /* of an element */
    int (*kept)(const sched_t *s);
} pixel_array_t;

static int kept_thesis(const sched_t *s)
{
    return s->cfg.adaptive == SCHED_ADAPTIVE_THESIS;
}
static int kept_adaptive(const sched_t *s)
{
    return s->cfg.adaptive != SCHED_ADAPTIVE_NONE;
}
static int kept_target(const sched_t *s)
{
    return s->cfg.target_error > 0;
}

#define PIXEL_ARRAY(tag, field, elem, kept)                                                        \
    {                                                                                              \
        tag, offsetof(sched_t, field), sizeof(elem), kept                                          \
    }
static const pixel_array_t pixel_arrays[] = {
    PIXEL_ARRAY("batches", batches, uint32_t, keeps_counts),
    PIXEL_ARRAY("ubat", ubatches, uint32_t, keeps_counts),
    PIXEL_ARRAY("umean", umean, double, keeps_counts),
    PIXEL_ARRAY("um2", um2, double, keeps_counts),
    PIXEL_ARRAY("urays", urays, uint64_t, weighs_cost),
    PIXEL_ARRAY("usamp", usamples, uint32_t, weighs_cost),
    PIXEL_ARRAY("pvarcur", pvar_cur, double, kept_thesis),
    PIXEL_ARRAY("pmetric", prev_metric, double, kept_adaptive),
    PIXEL_ARRAY("prvar", prev_rvar, double, kept_target),
    PIXEL_ARRAY("pnb", prev_nb, uint32_t, keeps_counts),
    PIXEL_ARRAY("pcost", prev_cost, float, weighs_cost),
};
#define PIXEL_ARRAYS (sizeof pixel_arrays / sizeof pixel_arrays[0])

static void **array_slot(sched_t *s, const pixel_array_t *a)
{
    return (void **)((char *)s + a->offset);
}
static const void *array_of(const sched_t *s, const pixel_array_t *a)
{
    return *(void *const *)((const char *)s + a->offset);
}
/* Bytes of array a in this job (0 when not kept). */
static size_t array_bytes(const sched_t *s, const pixel_array_t *a)
{
    return a->kept(s) ? (size_t)s->npix * a->size : 0;
}

/* The snapshot rows' buffers (a few image rows each). */
static int alloc_ring(sched_t *s)
{
    const size_t w = s->cfg.width;
    if (!(s->row_metric = malloc(w * sizeof(double))))
        return -1;
    for (int k = 0; k < SCHED_RING; k++) {
        snap_row_t *r = &s->ring[k];
        r->y = -1;
        r->metric = malloc(w * sizeof(double));
        r->rvar = malloc(w * sizeof(double));
        r->rvmax = malloc(w * sizeof(double));
        r->nb = malloc(w * sizeof(uint32_t));
        r->cost = malloc(w * sizeof(float));
        if (!r->metric || !r->rvar || !r->rvmax || !r->nb || !r->cost)
            return -1;
    }
    for (int k = 0; k < 3; k++) {
        s->sel_ring[k].y = -1;
        if (!(s->sel_ring[k].sel = malloc(w)))
            return -1;
    }
    return 0;
}

/* Every table, zeroed; -1 if any is missing (sched_destroy frees the rest). */
static int alloc_tables(sched_t *s)
{
    int failed = 0;
    s->film = film_new((int)s->cfg.width, (int)s->cfg.height);
    for (int k = 0; k < 2; k++) {
        s->member[k] = calloc(member_bytes(s), 1);
        s->state[k] = calloc(s->ranges, 1);
        s->out[k] = calloc(s->ranges, sizeof(tracer_task_t *));
        s->out_count[k] = calloc(s->ranges, sizeof(uint32_t));
        failed |= !s->member[k] || !s->state[k] || !s->out[k] || !s->out_count[k];
    }
    for (size_t i = 0; i < PIXEL_ARRAYS; i++)
        if (pixel_arrays[i].kept(s)) {
            void **slot = array_slot(s, &pixel_arrays[i]);
            *slot = calloc(s->npix, pixel_arrays[i].size);
            failed |= !*slot;
        }
    failed |= alloc_ring(s) < 0;
    /* ready cells are in the window: at most two layers of ranges */
    s->q_cap = 2 * (size_t)s->ranges + 1;
    s->queue = malloc(s->q_cap * sizeof(uint64_t));
    s->rq_cap = SCHED_REQUEUE_CAP0;
    s->requeued = malloc(s->rq_cap * sizeof(uint64_t));
    return failed || !s->film || !s->queue || !s->requeued ? -1 : 0;
}

sched_t *sched_new(const sched_config_t *cfg, char *err, size_t errlen)
{
    if (check_config(cfg, err, errlen) < 0)
        return NULL;
    sched_t *s = calloc(1, sizeof *s);
    if (!s) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    s->cfg = *cfg;
    derive_sizes(s);
    if (copy_flags(s, err, errlen) < 0) {
        free(s);
        return NULL;
    }
    if (s->cfg.confidence <= 0)
        s->cfg.confidence = JOB_DEFAULT_CONFIDENCE;
    if (s->cfg.target_share <= 0)
        s->cfg.target_share = JOB_DEFAULT_TARGET_SHARE;
    if (alloc_tables(s) < 0) {
        snprintf(err, errlen, "out of memory");
        sched_destroy(&s);
        return NULL;
    }
    return s;
}

void sched_destroy(sched_t **sp)
{
    if (!sp || !*sp)
        return;
    sched_t *s = *sp;
    for (int k = 0; k < 2; k++) {
        if (s->out[k])
            for (uint32_t r = 0; r < s->ranges; r++)
                free(s->out[k][r]);
        free(s->out[k]);
        free(s->out_count[k]);
        free(s->member[k]);
        free(s->state[k]);
    }
    for (size_t i = 0; i < PIXEL_ARRAYS; i++)
        free(*array_slot(s, &pixel_arrays[i]));
    for (int k = 0; k < SCHED_RING; k++) {
        snap_row_t *r = &s->ring[k];
        free(r->metric);
        free(r->rvar);
        free(r->rvmax);
        free(r->nb);
        free(r->cost);
    }
    for (int k = 0; k < 3; k++)
        free(s->sel_ring[k].sel);
    free(s->row_metric);
    film_destroy(&s->film);
    free(s->flags);
    free(s->t_table);
    free(s->t_target);
    free(s->queue);
    free(s->requeued);
    free(s);
    *sp = NULL;
}

size_t sched_memory(const sched_t *s, sched_memory_fn fn, void *ctx)
{
    const size_t n = s->npix;
    size_t total = 0, records = 0, bytes;
#define REPORT(name, b)                                                                            \
    do {                                                                                           \
        bytes = (b);                                                                               \
        total += bytes;                                                                            \
        if (fn && bytes)                                                                           \
            fn(ctx, name, bytes);                                                                  \
    } while (0)
    REPORT("film", n * sizeof(film_pixel_t));
    for (size_t i = 0; i < PIXEL_ARRAYS; i++)
        REPORT(pixel_arrays[i].name, array_bytes(s, &pixel_arrays[i]));
    REPORT("window (membership, cells)",
           2 * (member_bytes(s) + s->ranges * (1 + sizeof(tracer_task_t *) + sizeof(uint32_t))) +
               s->q_cap * sizeof(uint64_t) + s->rq_cap * sizeof(uint64_t));
    REPORT("decision rows",
           s->cfg.width *
               ((size_t)SCHED_RING * (3 * sizeof(double) + sizeof(uint32_t) + sizeof(float)) +
                sizeof(double) + 3));
    REPORT("t tables", 2 * s->t_cap * sizeof(double));
    for (int k = 0; k < 2; k++)
        for (uint32_t r = 0; r < s->ranges; r++)
            records += s->out[k][r] ? s->out_count[k][r] * sizeof(tracer_task_t) : 0;
    REPORT("records of tasks in flight", records);
#undef REPORT
    return total;
}

uint32_t sched_layer_count(const sched_t *s)
{
    return s->layers;
}
uint32_t sched_uniform_layers(const sched_t *s)
{
    return s->uniform;
}
uint32_t sched_range_count(const sched_t *s)
{
    return s->ranges;
}
uint32_t sched_layers_complete(const sched_t *s)
{
    return s->complete;
}
uint64_t sched_samples_done(const sched_t *s)
{
    return s->samples_done;
}
uint64_t sched_nonfinite(const sched_t *s)
{
    return s->nonfinite;
}
uint64_t sched_pixel_layers(const sched_t *s)
{
    return s->pixel_layers;
}
uint64_t sched_pixel_layers_skipped(const sched_t *s)
{
    return s->skipped;
}
const film_t *sched_film(const sched_t *s)
{
    return s->film;
}
int sched_done(const sched_t *s)
{
    return s->complete == s->layers;
}
uint64_t sched_converged(const sched_t *s)
{
    return s->converged;
}
int sched_stopped_on_target(const sched_t *s)
{
    return s->stopped_on_target;
}

static const char *const adaptive_names[] = {"none", "thesis", "variance", "relerr", "relmse"};
#define ADAPTIVE_MODES (int)(sizeof adaptive_names / sizeof adaptive_names[0])

int sched_adaptive_from_name(const char *name)
{
    for (int i = 0; i < ADAPTIVE_MODES; i++)
        if (strcmp(name, adaptive_names[i]) == 0)
            return i;
    return -1;
}

const char *sched_adaptive_name(sched_adaptive_t a)
{
    return (unsigned)a < ADAPTIVE_MODES ? adaptive_names[a] : "?";
}

int sched_pixel_in_layer(const sched_t *s, uint32_t layer, uint32_t pixel)
{
    if (layer >= s->layers || pixel >= s->npix || !in_window(s, layer))
        return -1;
    return is_member(s, layer, pixel);
}

double sched_threshold(const sched_t *s, uint32_t layer)
{
    if (layer >= s->layers)
        return 0.0;
    return in_window(s, layer) ? s->threshold[layer & 1] : NAN;
}

/* The two-sided t factor at `confidence` for k degrees of freedom, cached in
 * *table (grown on demand: k is at most the layers merged so far). 0 means
 * not computed yet: a quantile is never 0 for k >= 1 (and if one ever
 * underflowed it would merely be computed again). */
static double t_factor(sched_t *s, double **table, double confidence, uint32_t k)
{
    if (k >= s->t_cap) {
        size_t cap = s->t_cap ? s->t_cap : 64;
        while (cap <= k)
            cap *= 2;
        double *a = realloc(s->t_table, cap * sizeof(double));
        if (a)
            s->t_table = a;
        double *b = a ? realloc(s->t_target, cap * sizeof(double)) : NULL;
        if (b)
            s->t_target = b;
        if (!a || !b) /* out of memory: correct, only slower */
            return stats_t_two_sided(confidence, k);
        memset(a + s->t_cap, 0, (cap - s->t_cap) * sizeof(double));
        memset(b + s->t_cap, 0, (cap - s->t_cap) * sizeof(double));
        s->t_cap = cap;
    }
    if ((*table)[k] == 0)
        (*table)[k] = stats_t_two_sided(confidence, k);
    return (*table)[k];
}

static void complete_range(sched_t *s, uint32_t layer, uint32_t range);

/* Appends a ready id; when the ring is full, first drops the ids sched_take
 * handed out already (at most the window's cells are ready at once). */
static void push_ready(sched_t *s, uint64_t id)
{
    if ((s->q_tail + 1) % s->q_cap == s->q_head) {
        size_t n = 0;
        for (size_t i = s->q_head; i != s->q_tail; i = (i + 1) % s->q_cap) {
            uint64_t q = s->queue[i];
            if (cell_state(s, (uint32_t)((q - 1) / s->ranges), (uint32_t)((q - 1) % s->ranges)) ==
                ST_READY)
                s->queue[(s->q_head + n++) % s->q_cap] = q;
        }
        s->q_tail = (s->q_head + n) % s->q_cap;
    }
    s->queue[s->q_tail] = id;
    s->q_tail = (s->q_tail + 1) % s->q_cap;
}

/* (layer, range) can run: queue it, or complete it at once when the layer
 * has none of the range's pixels. */
static void make_ready(sched_t *s, uint32_t layer, uint32_t range)
{
    if (cell_state(s, layer, range) != ST_WAITING)
        return;
    if (range_members(s, layer, range) == 0) {
        set_state(s, layer, range, ST_OUT);
        complete_range(s, layer, range);
        return;
    }
    set_state(s, layer, range, ST_READY);
    push_ready(s, task_id(s, layer, range));
}

/* Whether layer's pixels are chosen by the skip rule (rule 3). */
static int applies_skip_rule(const sched_t *s, uint32_t layer)
{
    /* relerr and relmse learn only from uniform layers (pool_neighbours):
     * without a flag sequence, every SCHED_UNIFORM_EVERY-th layer stays
     * uniform so their statistics keep growing (not with a target error,
     * whose statistics stop growing after SCHED_TARGET_MIN_LAYERS) */
    int refresh =
        pools_neighbours(s) && s->cfg.target_error <= 0 && layer % SCHED_UNIFORM_EVERY == 0;
    int flag = s->flags ? s->flags[layer] == '1' : layer >= s->uniform && !refresh;
    return flag && layer >= 2 && s->cfg.adaptive != SCHED_ADAPTIVE_NONE;
}

/* ---- the statistics a decision reads ------------------------------------- */

/* Pixel p's statistics as of its last merge (what sched_complete keeps). */
static double cur_metric(const sched_t *s, uint32_t p)
{
    switch (s->cfg.adaptive) {
    case SCHED_ADAPTIVE_VARIANCE:
        return s->film->pixels[p].count >= 2 ? film_variance_of_mean(s->film, p) : INFINITY;
    case SCHED_ADAPTIVE_RELERR:
    case SCHED_ADAPTIVE_RELMSE: {
        /* the relative variance of one layer's mean, over the uniform
         * layers; decide_layer turns its neighbours' into the metric */
        const uint32_t nu = s->ubatches[p];
        double scale = fabs(s->umean[p]) + SCHED_RELERR_EPS;
        return nu >= 2 ? s->um2[p] / (nu - 1) / (scale * scale) : INFINITY;
    }
    case SCHED_ADAPTIVE_THESIS:
        return s->pvar_cur[p];
    default:
        return 0.0;
    }
}

/* The target error's: a layer mean's relative variance, over its first layers. */
static double cur_rvar(const sched_t *s, uint32_t p)
{
    const uint32_t nu = s->ubatches[p];
    double scale = fabs(s->umean[p]) + SCHED_TARGET_EPS;
    return nu >= SCHED_TARGET_MIN_LAYERS ? s->um2[p] / (nu - 1) / (scale * scale) : INFINITY;
}

static float cur_cost(const sched_t *s, uint32_t p)
{
    return s->usamples[p] ? (float)((double)s->urays[p] / (double)s->usamples[p]) : 0.0f;
}

/* Before pixel p merges the later layer in flight: keep what it replaces. */
static void keep_prev(sched_t *s, uint32_t p)
{
    if (s->prev_metric)
        s->prev_metric[p] = cur_metric(s, p);
    if (s->prev_rvar)
        s->prev_rvar[p] = cur_rvar(s, p);
    if (s->prev_nb)
        s->prev_nb[p] = s->batches[p];
    if (s->prev_cost)
        s->prev_cost[p] = cur_cost(s, p);
}

/* Row y of the snapshot a decision reads (as of layer complete - 1), in the
 * ring; computed on first use. Pixels that have merged the layer `complete`
 * already read their prev_* values; pixels that have merged nothing read 0
 * (what a pixel's statistics were before it took part in a complete
 * layer: only decisions of layers 0 and 1, which no statistic changes). */
static snap_row_t *snap_row(sched_t *s, int y)
{
    snap_row_t *r = &s->ring[y % SCHED_RING];
    if (r->y == y)
        return r;
    r->y = y;
    uint32_t w = s->cfg.width;
    const uint32_t ahead = s->complete, rp = s->range_pixels;
    const int any_ahead = ahead < s->decided_n;
    const int target = s->cfg.target_error > 0, counts = keeps_counts(s), cost = weighs_cost(s);
    if (s->complete == 0) { /* layers 0 and 1: nothing merged yet */
        memset(r->metric, 0, w * sizeof(double));
        memset(r->rvar, 0, w * sizeof(double));
        memset(r->nb, 0, w * sizeof(uint32_t));
        memset(r->cost, 0, w * sizeof(float));
        w = 0;
    }
    /* every pixel's current values, mode by mode (a switch a pixel costs
     * more than the arithmetic), then the pixels that merged ahead */
    const uint32_t p0 = (uint32_t)y * s->cfg.width;
    switch (w ? s->cfg.adaptive : SCHED_ADAPTIVE_NONE) {
    case SCHED_ADAPTIVE_THESIS:
        memcpy(r->metric, s->pvar_cur + p0, w * sizeof(double));
        break;
    case SCHED_ADAPTIVE_NONE:
        memset(r->metric, 0, w * sizeof(double));
        break;
    default:
        for (uint32_t x = 0; x < w; x++)
            r->metric[x] = cur_metric(s, p0 + x);
        break;
    }
    for (uint32_t x = 0; x < w; x++) {
        r->rvar[x] = target ? cur_rvar(s, p0 + x) : 0;
        r->cost[x] = cost ? cur_cost(s, p0 + x) : 0;
    }
    if (counts && w)
        memcpy(r->nb, s->batches + p0, w * sizeof(uint32_t));
    else
        memset(r->nb, 0, w * sizeof(uint32_t));
    for (uint32_t range = p0 / rp; any_ahead && w && range * rp < p0 + w; range++) {
        if (s->state[ahead & 1][range] != ST_DONE)
            continue;
        const uint32_t a = range * rp > p0 ? range * rp : p0,
                       b = (range + 1) * rp < p0 + w ? (range + 1) * rp : p0 + w;
        for (uint32_t p = a; p < b; p++) {
            if (!is_member(s, ahead, p))
                continue;
            const uint32_t x = p - p0;
            r->metric[x] = s->prev_metric ? s->prev_metric[p] : 0;
            r->rvar[x] = target ? s->prev_rvar[p] : 0;
            r->nb[x] = counts ? s->prev_nb[p] : 0;
            r->cost[x] = cost ? s->prev_cost[p] : 0;
        }
    }
    w = s->cfg.width;
    if (target) {
        const int rad = SCHED_TARGET_POOL_RADIUS;
        for (int x = 0; x < (int)w; x++) {
            double m = 0;
            for (int xx = x - rad; xx <= x + rad; xx++)
                if (xx >= 0 && xx < (int)w && r->rvar[xx] > m)
                    m = r->rvar[xx];
            r->rvmax[x] = m;
        }
    }
    return r;
}

/* Starts a decision: no row of an earlier one is valid any more. */
static void ring_reset(sched_t *s)
{
    for (int k = 0; k < SCHED_RING; k++)
        s->ring[k].y = -1;
    for (int k = 0; k < 3; k++)
        s->sel_ring[k].y = -1;
}

/* The largest relative variance in the (2 SCHED_TARGET_POOL_RADIUS + 1)^2
 * window around (x, y), the pixel itself left out (the rows' maxima, then
 * the columns', with the pixel in; then, only where the pixel is its
 * window's maximum, again without it). A pixel with no neighbour at all (a
 * 1 x 1 image) keeps its own value. Needs rows y - 2 .. y + 2 in the ring. */
static double window_max(sched_t *s, int x, int y)
{
    const int w = (int)s->cfg.width, h = (int)s->cfg.height, r = SCHED_TARGET_POOL_RADIUS;
    double m = 0;
    for (int yy = y - r; yy <= y + r; yy++)
        if (yy >= 0 && yy < h && snap_row(s, yy)->rvmax[x] > m)
            m = snap_row(s, yy)->rvmax[x];
    if (w * h == 1 || snap_row(s, y)->rvar[x] < m)
        return m; /* a neighbour holds the maximum */
    m = 0;
    for (int yy = y - r; yy <= y + r; yy++) {
        if (yy < 0 || yy >= h)
            continue;
        const double *v = snap_row(s, yy)->rvar;
        for (int xx = x - r; xx <= x + r; xx++)
            if (xx >= 0 && xx < w && (yy != y || xx != x) && v[xx] > m)
                m = v[xx];
    }
    return m;
}

/* Whether pixel (x, y) meets the target error, from the snapshot. A pixel's
 * own layer means can look steady long before it meets a rare bright path
 * (a caustic seen through glass) that its neighbours have met: its
 * relative variance is taken as the largest in its window (sched.h,
 * bench/error/target.py). The pixel itself is left out: a pixel that
 * stopped because its own layers looked steady would stop exactly when it
 * had not met the bright path yet, and its mean would be low
 * (test_target_unbiased); only its layer count is its own. Nor may a
 * neighbour's statistics grow with the layers it took, since how many it
 * took depends on this pixel's values through the neighbour's own window:
 * they come from every pixel's first SCHED_TARGET_MIN_LAYERS layers,
 * frozen from then on (sched.h). */
static int meets_target(sched_t *s, int x, int y)
{
    uint32_t nb = snap_row(s, y)->nb[x];
    return nb >= SCHED_TARGET_MIN_LAYERS &&
           t_factor(s, &s->t_target, s->cfg.confidence, nb - 1) * sqrt(window_max(s, x, y) / nb) <=
               s->cfg.target_error;
}

/* relmse: the rays a sample of pixel x of the middle row takes (rows: the
 * cost of the rows above, at and below it; NULL past the image), as the mean over
 * its 3x3 neighbours of their uniform layers' rays per sample, the pixel
 * itself left out for the same reason as its variance (its own uniform
 * rays count with its radiance: the paths that enter glass are both the
 * long and the bright ones). At least 1 (every sample traces its camera
 * ray); 1 while no neighbour has any (a 1 x 1 image: all pixels alike). */
static double neighbour_cost(const float *const rows[3], int x, int w)
{
    double sum = 0;
    int k = 0;
    for (int dy = 0; dy < 3; dy++) {
        const float *c = rows[dy];
        if (!c)
            continue;
        for (int xx = x - 1; xx <= x + 1; xx++)
            if (xx >= 0 && xx < w && (dy != 1 || xx != x) && c[xx] > 0) {
                sum += c[xx];
                k++;
            }
    }
    return k && sum > k ? sum / k : 1.0;
}

/* The skip rule's statistic for the pixels of row y, into out. relerr and relmse: the
 * relative variance of a layer mean, measured over the uniform layers only,
 * is the mean over the pixel's 3x3 neighbours, the pixel itself left out;
 * its own layer count scales it. Why: a pixel given more layers when its
 * own layers look noisy, and fewer when they look steady, keeps a low
 * estimate longer than a high one (a pixel that has not met a rare bright
 * path looks steady and stops), so its mean comes out low: -3 to -4 % on
 * the glass scene. Its neighbours' variance says about as much about how
 * noisy it is. Uniform layers only, since a neighbour's other layers were
 * chosen by statistics this pixel's samples took part in (its spike would
 * send the neighbours on sampling, find their spikes, and come back as more
 * layers for it: still -2 to -3 % in test_sched). So nothing that decides
 * how many layers a pixel gets depends on its own samples, and its mean
 * stays unbiased (but for its 1/npix share in the threshold). thesis and
 * variance: the pixel's own. */
static void metric_row(sched_t *s, int y, double *out)
{
    const int w = (int)s->cfg.width, h = (int)s->cfg.height;
    const snap_row_t *self = snap_row(s, y);
    if (!pools_neighbours(s)) {
        memcpy(out, self->metric, (size_t)w * sizeof(double));
        return;
    }
    const snap_row_t *up = y > 0 ? snap_row(s, y - 1) : NULL,
                     *down = y + 1 < h ? snap_row(s, y + 1) : NULL;
    const double *const v[3] = {up ? up->metric : NULL, self->metric, down ? down->metric : NULL};
    const float *const c[3] = {up ? up->cost : NULL, self->cost, down ? down->cost : NULL};
    for (int x = 0; x < w; x++) {
        double sum = 0;
        int k = 0;
        for (int dy = 0; dy < 3; dy++) {
            if (!v[dy])
                continue;
            for (int xx = x - 1; xx <= x + 1; xx++)
                if (xx >= 0 && xx < w && (dy != 1 || xx != x)) {
                    sum += v[dy][xx];
                    k++;
                }
        }
        const double rv = k ? sum / k : self->metric[x]; /* a 1 x 1 image has only itself */
        const uint32_t nb = self->nb[x];
        if (nb < 2 || !isfinite(rv))
            out[x] = INFINITY; /* sampled until it and its neighbours have two */
        else if (s->cfg.adaptive == SCHED_ADAPTIVE_RELMSE)
            out[x] = rv / ((double)nb * nb) / neighbour_cost(c, x, w);
        else
            out[x] = t_factor(s, &s->t_table, SCHED_RELERR_CONFIDENCE, nb - 1) * sqrt(rv / nb);
    }
}

/* Row y's choice by the skip rule alone (before dilation), in its ring row. */
static const uint8_t *select_row(sched_t *s, int y, uint32_t layer, int skip_rule, double threshold,
                                 const double *metric_of)
{
    sel_row_t *r = &s->sel_ring[y % 3];
    if (r->y == y)
        return r->sel;
    const uint32_t w = s->cfg.width;
    const double *m = NULL;
    if (skip_rule) {
        if (metric_of) {
            m = metric_of + (size_t)y * w;
        } else {
            metric_row(s, y, s->row_metric);
            m = s->row_metric;
        }
    }
    for (uint32_t x = 0; x < w; x++) {
        int in = 1;
        if (skip_rule) {
            in = !(m[x] < threshold);
            if (!in && s->cfg.random_selection && threshold > 0) {
                /* near the threshold a pixel is likely kept, far below rarely:
                 * avoids trapping pixels in a "local solution" (thesis 6) */
                const uint32_t p = (uint32_t)y * w + x;
                rng_stream_t rs = rng_stream(s->cfg.seed ^ 0x5eed5e1ec7ULL, p, layer);
                in = rng_next_double(&rs) < m[x] / threshold;
            }
        }
        r->sel[x] = (uint8_t)in;
    }
    r->y = y;
    return r->sel;
}

/* Layer is decided: the ranges whose previous layer is done can run. */
static void decided(sched_t *s, uint32_t layer)
{
    s->decided_n = layer + 1;
    for (uint32_t r = 0; r < s->ranges; r++)
        if (layer == 0 || cell_state(s, layer - 1, r) == ST_DONE)
            make_ready(s, layer, r);
}

/* Chooses the pixels of layer s->decided_n from the snapshot. */
static void decide_layer(sched_t *s, uint32_t layer)
{
    if (layer >= s->layers || layer != s->decided_n)
        return;
    const int w = (int)s->cfg.width, h = (int)s->cfg.height;
    const int skip_rule = applies_skip_rule(s, layer), target = s->cfg.target_error > 0;
    ring_reset(s);
    /* the mean over pixels (eq. 4.3); pixels without a value yet (inf)
     * are sampled anyway and left out of the mean. One pass for it and the
     * pixels that meet the target, one to choose. */
    double threshold = 0;
    size_t n = 0;
    uint64_t conv = 0;
    /* What the first pass finds for each pixel, for the second (only while
     * deciding: 9 bytes a pixel at most; without them the second pass
     * computes them again) */
    double *metric_of = skip_rule ? malloc((size_t)s->npix * sizeof(double)) : NULL;
    uint8_t *conv_of = target ? malloc(s->npix) : NULL;
    if (skip_rule || target)
        for (int y = 0; y < h; y++) {
            double *row = metric_of ? metric_of + (size_t)y * (size_t)w : s->row_metric;
            if (skip_rule)
                metric_row(s, y, row);
            for (int x = 0; x < w; x++) {
                const size_t p = (size_t)y * (size_t)w + (size_t)x;
                if (skip_rule) {
                    double m = row[x];
                    if (isfinite(m)) {
                        threshold += m;
                        n++;
                    }
                }
                if (target) {
                    int c = meets_target(s, x, y);
                    if (conv_of)
                        conv_of[p] = (uint8_t)c;
                    conv += (uint64_t)c;
                }
            }
        }
    threshold = n ? threshold / (double)n : 0.0;
    s->converged = conv;
    int stop_all = target && (double)conv >= s->cfg.target_share * s->npix;
    if (stop_all && !s->stopped_on_target)
        s->stopped_on_target = 1;
    /* the slot of layer - 2, complete */
    const int slot = (int)(layer & 1);
    memset(s->member[slot], 0, member_bytes(s));
    memset(s->state[slot], ST_WAITING, s->ranges);
    s->range_done[slot] = 0;
    s->threshold[slot] = skip_rule ? threshold : 0.0;
    if (!skip_rule && !target) { /* a uniform layer: every pixel, nothing to read */
        memset(s->member[slot], 0xff, s->npix / 8);
        for (uint32_t p = s->npix & ~7u; p < s->npix; p++)
            set_member(s, layer, p);
        s->pixel_layers += s->npix;
        free(metric_of);
        free(conv_of);
        decided(s, layer);
        return;
    }
    const int dilate = skip_rule && s->cfg.dilate;
    for (int y = 0; y < h; y++) {
        const uint8_t *sel = select_row(s, y, layer, skip_rule, threshold, metric_of);
        const uint8_t *up =
            dilate && y > 0 ? select_row(s, y - 1, layer, skip_rule, threshold, metric_of) : NULL;
        const uint8_t *down = dilate && y + 1 < h
                                  ? select_row(s, y + 1, layer, skip_rule, threshold, metric_of)
                                  : NULL;
        for (int x = 0; x < w; x++) {
            const uint32_t p = (uint32_t)(y * w + x);
            int chosen = sel[x];
            /* grow the selection by one pixel: noise is seen across pixels, and
             * a lone skipped pixel or a hard edge of skipped ones shows as a seam */
            if (dilate && !chosen)
                for (int dx = -1; dx <= 1 && !chosen; dx++)
                    if (x + dx >= 0 && x + dx < w)
                        chosen = (up && up[x + dx]) || sel[x + dx] || (down && down[x + dx]);
            int in =
                chosen && !stop_all && !(target && (conv_of ? conv_of[p] : meets_target(s, x, y)));
            if (in) {
                set_member(s, layer, p);
                s->pixel_layers++;
            } else {
                s->skipped++;
            }
        }
    }
    free(metric_of);
    free(conv_of);
    decided(s, layer);
}

static void complete_range(sched_t *s, uint32_t layer, uint32_t range)
{
    /* An explicit stack instead of recursion: completing (l, r) can make
     * (l+1, r) ready, which may be empty and complete at once, and so on. */
    for (;;) {
        set_state(s, layer, range, ST_DONE);
        if (++s->range_done[layer & 1] == s->ranges) {
            /* Layers complete in order (rule 1), so this is s->complete. */
            s->complete = layer + 1;
            decide_layer(s, layer + 2);
        }
        uint32_t next = layer + 1;
        if (next >= s->layers || !in_window(s, next))
            return;
        if (cell_state(s, next, range) != ST_WAITING)
            return;
        if (range_members(s, next, range) == 0) {
            set_state(s, next, range, ST_OUT);
            layer = next;
            continue;
        }
        make_ready(s, next, range);
        return;
    }
}

static void start(sched_t *s)
{
    if (s->layers > 0 && s->decided_n == 0) {
        decide_layer(s, 0);
        decide_layer(s, 1);
    }
}

/* Hands out the ready task `id`: builds its records (from the film, which
 * holds exactly its pixels' earlier layers) unless it has them from an
 * earlier issue. SCHED_OK, or SCHED_NO_MEMORY (nothing changed). */
static sched_status_t issue(sched_t *s, uint64_t id, sched_task_t *out)
{
    uint32_t layer = (uint32_t)((id - 1) / s->ranges), range = (uint32_t)((id - 1) % s->ranges);
    const int slot = (int)(layer & 1);
    if (!s->out[slot][range]) {
        uint32_t p0 = range * s->range_pixels, p1 = p0 + s->range_pixels;
        if (p1 > s->npix)
            p1 = s->npix;
        uint32_t n = range_members(s, layer, range);
        tracer_task_t *rec = calloc(n, sizeof *rec);
        if (!rec)
            return SCHED_NO_MEMORY;
        uint32_t take = layer_samples(s, layer);
        uint32_t k = 0;
        for (uint32_t p = p0; p < p1; p++) {
            if (!is_member(s, layer, p))
                continue;
            rec[k].pixel = p;
            rec[k].sample_count = take;
            rec[k].first_sample = first_sample_of(s, p);
            film_prior(s->film, &rec[k]);
            k++;
        }
        s->out[slot][range] = rec;
        s->out_count[slot][range] = n;
    }
    set_state(s, layer, range, ST_OUT);
    out->id = id;
    out->layer = layer;
    out->range = range;
    out->count = s->out_count[slot][range];
    out->records = s->out[slot][range];
    return SCHED_OK;
}

/* Whether id names a task of this job, and its cell. */
static int split_id(const sched_t *s, uint64_t id, uint32_t *layer, uint32_t *range)
{
    if (id == 0 || id > (uint64_t)s->layers * s->ranges)
        return 0;
    *layer = (uint32_t)((id - 1) / s->ranges);
    *range = (uint32_t)((id - 1) % s->ranges);
    return 1;
}

int sched_next(sched_t *s, sched_task_t *out)
{
    start(s);
    for (;;) {
        uint64_t id;
        const int from_requeued = s->rq_len > 0;
        if (from_requeued) {
            id = s->requeued[--s->rq_len];
        } else if (s->q_head != s->q_tail) {
            id = s->queue[s->q_head];
            s->q_head = (s->q_head + 1) % s->q_cap;
        } else {
            return s->complete == s->layers ? SCHED_NEXT_ALL_ISSUED : SCHED_NEXT_NONE_READY;
        }
        uint32_t layer, range;
        if (!split_id(s, id, &layer, &range) || cell_state(s, layer, range) != ST_READY)
            continue; /* sched_take handed it out already */
        if (issue(s, id, out) != SCHED_OK) {
            /* Put it back where it came from: the caller retries later. */
            if (from_requeued)
                s->rq_len++;
            else
                s->q_head = (s->q_head + s->q_cap - 1) % s->q_cap;
            return SCHED_NEXT_NONE_READY;
        }
        return SCHED_NEXT_TASK;
    }
}

int sched_take(sched_t *s, uint64_t task_id, sched_task_t *out)
{
    start(s);
    uint32_t layer, range;
    if (!split_id(s, task_id, &layer, &range) || cell_state(s, layer, range) != ST_READY)
        return SCHED_NOT_OUTSTANDING;
    return issue(s, task_id, out);
}

/* SCHED_OK and the task's layer and range if it is handed out, else
 * SCHED_NOT_OUTSTANDING. */
static sched_status_t lookup(const sched_t *s, uint64_t id, uint32_t *layer, uint32_t *range)
{
    if (!split_id(s, id, layer, range) || !in_window(s, *layer))
        return SCHED_NOT_OUTSTANDING;
    return cell_state(s, *layer, *range) == ST_OUT && s->out[*layer & 1][*range]
               ? SCHED_OK
               : SCHED_NOT_OUTSTANDING;
}

int sched_requeue(sched_t *s, uint64_t task_id)
{
    uint32_t layer, range;
    if (lookup(s, task_id, &layer, &range) != SCHED_OK)
        return SCHED_NOT_OUTSTANDING;
    if (s->rq_len == s->rq_cap) {
        uint64_t *n = realloc(s->requeued, 2 * s->rq_cap * sizeof(uint64_t));
        if (!n)
            return SCHED_NO_MEMORY;
        s->requeued = n;
        s->rq_cap *= 2;
    }
    set_state(s, layer, range, ST_READY);
    s->requeued[s->rq_len++] = task_id;
    return SCHED_OK;
}

int sched_outstanding(const sched_t *s, uint64_t task_id, sched_task_t *out)
{
    uint32_t layer, range;
    if (lookup(s, task_id, &layer, &range) != SCHED_OK)
        return SCHED_NOT_OUTSTANDING;
    out->id = task_id;
    out->layer = layer;
    out->range = range;
    out->count = s->out_count[layer & 1][range];
    out->records = s->out[layer & 1][range];
    return SCHED_OK;
}

int sched_check(const sched_t *s, uint64_t task_id, const tracer_result_t *results, uint32_t count,
                char *err, size_t errlen)
{
    uint32_t layer, range;
    if (lookup(s, task_id, &layer, &range) != SCHED_OK) {
        snprintf(err, errlen, "task %llu is not outstanding", (unsigned long long)task_id);
        return SCHED_NOT_OUTSTANDING;
    }
    const tracer_task_t *rec = s->out[layer & 1][range];
    const uint32_t want = s->out_count[layer & 1][range];
    if (count != want) {
        snprintf(err, errlen, "task %llu: %u results for %u pixels", (unsigned long long)task_id,
                 count, want);
        return SCHED_BAD_RESULT;
    }
    /* Check everything before merging anything: a bad result changes nothing,
     * and no merge may make the film non-finite. */
    uint64_t nonfinite = 0, taken = 0;
    for (uint32_t i = 0; i < count; i++) {
        const tracer_result_t *r = &results[i];
        if (r->pixel != rec[i].pixel ||
            (uint64_t)r->samples + r->nonfinite != rec[i].sample_count) {
            snprintf(err, errlen,
                     "task %llu: result %u is for pixel %u with %u+%u samples, "
                     "expected pixel %u with %u",
                     (unsigned long long)task_id, i, r->pixel, r->samples, r->nonfinite,
                     rec[i].pixel, rec[i].sample_count);
            return SCHED_BAD_RESULT;
        }
        if (r->rays < rec[i].sample_count) { /* each traces at least its camera ray */
            snprintf(err, errlen, "task %llu: result %u (pixel %u): %u rays for %u samples",
                     (unsigned long long)task_id, i, r->pixel, r->rays, rec[i].sample_count);
            return SCHED_BAD_RESULT;
        }
        /* radiance is never negative; sums of no samples are zero */
        const double n = r->samples, cap = SCHED_MAX_RADIANCE;
        int bad = !(r->lum_m2 >= 0 && r->lum_m2 <= n * cap * cap) ||
                  !(r->pvar >= 0 && r->pvar <= (double)rec[i].sample_count * cap * cap);
        for (int c = 0; c < 3; c++)
            bad |= !(r->sum[c] >= 0 && r->sum[c] <= n * cap);
        if (bad || film_merge_check(s->film, r) < 0) {
            snprintf(err, errlen,
                     "task %llu: result %u (pixel %u) is out of range: sums %g %g %g, M2 %g, "
                     "eq. 4.1 %g%s",
                     (unsigned long long)task_id, i, r->pixel, r->sum[0], r->sum[1], r->sum[2],
                     r->lum_m2, r->pvar, bad ? "" : " (the merge would overflow the film)");
            return SCHED_BAD_RESULT;
        }
        nonfinite += r->nonfinite;
        taken += rec[i].sample_count;
    }
    /* A tracer leaves out a NaN/Inf sample now and then; a task where most
     * are is a broken or lying worker, not light. */
    if (taken > 0 && 2 * nonfinite > taken) {
        snprintf(err, errlen, "task %llu: %llu of %llu samples NaN/Inf: implausible",
                 (unsigned long long)task_id, (unsigned long long)nonfinite,
                 (unsigned long long)taken);
        return SCHED_BAD_RESULT;
    }
    return SCHED_OK;
}

int sched_complete(sched_t *s, uint64_t task_id, const tracer_result_t *results, uint32_t count,
                   char *err, size_t errlen)
{
    sched_status_t rc = sched_check(s, task_id, results, count, err, errlen);
    if (rc != SCHED_OK)
        return rc;
    const uint32_t layer = (uint32_t)((task_id - 1) / s->ranges),
                   range = (uint32_t)((task_id - 1) % s->ranges);
    const int slot = (int)(layer & 1);
    const tracer_task_t *rec = s->out[slot][range];
    /* the later layer in flight: a decision may still read its pixels'
     * statistics as they were before it (see the top of this file) */
    const int ahead = layer > s->complete;
    /* batch statistics only where something reads them: this loop runs for
     * every pixel-layer result, millions a second on one master core */
    const int batches = keeps_counts(s);
    /* a uniform layer: every pixel takes it, whatever any pixel's values */
    const int adaptive_layer = applies_skip_rule(s, layer);
    for (uint32_t i = 0; i < count; i++) {
        uint32_t p = results[i].pixel;
        if (ahead)
            keep_prev(s, p);
        film_merge(s->film, &results[i]);
        s->samples_done += rec[i].sample_count;
        s->nonfinite += results[i].nonfinite;
        if (s->pvar_cur)
            s->pvar_cur[p] = results[i].pvar;
        if (!batches)
            continue;
        /* with a target error, a pixel's first SCHED_TARGET_MIN_LAYERS
         * layers whatever they are (meets_target); else its uniform layers */
        const int judged =
            s->cfg.target_error > 0 ? s->ubatches[p] < SCHED_TARGET_MIN_LAYERS : !adaptive_layer;
        /* the layer's mean is one batch; Welford over batches */
        if (results[i].samples > 0) {
            s->batches[p]++;
            if (judged) {
                double bm =
                    vmath_luminance(results[i].sum[0], results[i].sum[1], results[i].sum[2]) /
                    results[i].samples;
                welford_add(&s->ubatches[p], &s->umean[p], &s->um2[p], bm);
            }
        }
        if (s->urays && judged) {
            s->urays[p] += results[i].rays;
            s->usamples[p] += rec[i].sample_count;
        }
    }
    free(s->out[slot][range]);
    s->out[slot][range] = NULL;
    s->out_count[slot][range] = 0;
    complete_range(s, layer, range);
    return SCHED_OK;
}

/* ---- checkpoints ---------------------------------------------------------- */

/* write and read calls carry at most this much: the pipe or socket behind
 * them need not take a gigabyte film in one call. */
#define SAVE_CHUNK ((size_t)1 << 20)

static const uint8_t save_magic[8] = {'V', 'B', 'S', 'C', 'H', 'E', 'D', '\n'};

/* The oldest stream this build still reads (sched_load_v5 below). */
#define SCHED_SAVE_VERSION_V5 5
/* Version 5's film pixel: 64-bit counts, the last eq. 4.1 value, layers. */
typedef struct film_pixel_v5 {
    uint64_t count, nonfinite;
    double sum[3], comp[3], lum_m2, pvar;
    uint32_t layers;
} film_pixel_v5_t;

/* The fingerprint: what a restored scheduler must share with the saved one
 * (settings first, so a mismatch names the setting, not what it derives). */
enum {
    FP_WIDTH,
    FP_HEIGHT,
    FP_SPP,
    FP_GRANULARITY,
    FP_ADAPTIVE,
    FP_UNIFORM,
    FP_HAS_FLAGS,
    FP_FLAGS,
    FP_RANGE_PIXELS,
    FP_RANDOM_SELECTION,
    FP_DILATE,
    FP_SEED,
    FP_TARGET_ERROR,
    FP_CONFIDENCE,
    FP_TARGET_SHARE,
    FP_PIXELS,
    FP_LAYERS,
    FP_RANGES,
    FP_PIXEL_BYTES,
    FP_COUNT
};
static const char *const fp_names[FP_COUNT] = {"width",
                                               "height",
                                               "spp",
                                               "granularity",
                                               "adaptive",
                                               "uniform layers",
                                               "flag sequence (present)",
                                               "flag sequence",
                                               "range_pixels",
                                               "random_selection",
                                               "dilate",
                                               "seed",
                                               "target_error",
                                               "confidence",
                                               "target_share",
                                               "pixels",
                                               "layers",
                                               "ranges",
                                               "film pixel size"};

static uint64_t f64_bits(double x)
{
    uint64_t u;
    memcpy(&u, &x, sizeof u);
    return u;
}

static void fingerprint(const sched_t *s, uint64_t fp[FP_COUNT], size_t pixel_bytes)
{
    uint64_t h = 0xcbf29ce484222325ULL; /* FNV-1a of the flag sequence */
    for (uint32_t l = 0; s->flags && l < s->layers; l++)
        h = (h ^ (uint8_t)s->flags[l]) * 0x100000001b3ULL;
    fp[FP_WIDTH] = s->cfg.width;
    fp[FP_HEIGHT] = s->cfg.height;
    fp[FP_SPP] = s->cfg.spp;
    fp[FP_GRANULARITY] = s->cfg.granularity;
    fp[FP_ADAPTIVE] = (uint64_t)s->cfg.adaptive;
    fp[FP_UNIFORM] = s->uniform;
    fp[FP_HAS_FLAGS] = s->flags != NULL;
    fp[FP_FLAGS] = s->flags ? h : 0;
    fp[FP_RANGE_PIXELS] = s->range_pixels;
    fp[FP_RANDOM_SELECTION] = (uint64_t)(int64_t)s->cfg.random_selection;
    fp[FP_DILATE] = (uint64_t)(int64_t)s->cfg.dilate;
    fp[FP_SEED] = s->cfg.seed;
    fp[FP_TARGET_ERROR] = f64_bits(s->cfg.target_error);
    fp[FP_CONFIDENCE] = f64_bits(s->cfg.confidence); /* as normalised by sched_new */
    fp[FP_TARGET_SHARE] = f64_bits(s->cfg.target_share);
    fp[FP_PIXELS] = s->npix;
    fp[FP_LAYERS] = s->layers;
    fp[FP_RANGES] = s->ranges;
    fp[FP_PIXEL_BYTES] = pixel_bytes;
}

/* A checksum of the stream, the same however it is cut into calls: words
 * of 8 bytes (a partial one kept back), each folded in by a bijection, so
 * one changed word always changes the sum. Not cryptographic: it catches
 * corruption that the consistency checks cannot see (a finite film value
 * with a flipped bit). */
typedef struct cksum {
    uint64_t h, total;
    uint8_t pend[8];
    unsigned npend;
} cksum_t;

static void ck_word(cksum_t *c, uint64_t w)
{
    uint64_t h = (c->h ^ w) * 0x9e3779b97f4a7c15ULL;
    c->h = h ^ (h >> 29);
}

static void ck_update(cksum_t *c, const void *data, size_t len)
{
    const uint8_t *p = data;
    uint64_t w;
    c->total += len;
    while (len > 0 && c->npend > 0) {
        c->pend[c->npend++] = *p++;
        len--;
        if (c->npend == 8) {
            memcpy(&w, c->pend, 8);
            ck_word(c, w);
            c->npend = 0;
        }
    }
    for (; len >= 8; p += 8, len -= 8) {
        memcpy(&w, p, 8);
        ck_word(c, w);
    }
    while (len > 0) { /* here npend == 0 and len < 8 */
        c->pend[c->npend++] = *p++;
        len--;
    }
}

static uint64_t ck_final(const cksum_t *c0)
{
    cksum_t c = *c0;
    uint64_t w = 0;
    memcpy(&w, c.pend, c.npend);
    ck_word(&c, w);
    ck_word(&c, c.total);
    return rng_mix64(c.h);
}

static void tag_bytes(const char *tag, uint8_t out[8])
{
    size_t n = strlen(tag);
    memset(out, 0, 8);
    memcpy(out, tag, n < 8 ? n : 8);
}

typedef struct saver {
    sched_write_fn write;
    void *ctx;
    cksum_t ck;
    int rc;
} saver_t;

static int put(saver_t *w, const void *data, size_t len)
{
    const uint8_t *p = data;
    while (len > 0 && w->rc == 0) {
        size_t n = len < SAVE_CHUNK ? len : SAVE_CHUNK;
        ck_update(&w->ck, p, n);
        w->rc = w->write(w->ctx, p, n);
        p += n;
        len -= n;
    }
    return w->rc;
}

static int put_head(saver_t *w, const char *tag, uint64_t bytes)
{
    uint8_t h[16];
    tag_bytes(tag, h);
    memcpy(h + 8, &bytes, 8);
    return put(w, h, sizeof h);
}

static int put_section(saver_t *w, const char *tag, const void *data, size_t bytes)
{
    if (put_head(w, tag, bytes))
        return w->rc;
    return put(w, data, bytes);
}

/* Zeros, as a section's body (a window slot that holds no layer). */
static int put_zeros(saver_t *w, size_t bytes)
{
    static const uint8_t zero[4096];
    while (bytes > 0 && w->rc == 0) {
        size_t n = bytes < sizeof zero ? bytes : sizeof zero;
        put(w, zero, n);
        bytes -= n;
    }
    return w->rc;
}

/* Counters, in this order in the "counters" section. */
enum {
    CT_COMPLETE,
    CT_CONVERGED,
    CT_STOPPED,
    CT_SAMPLES,
    CT_PIXEL_LAYERS,
    CT_SKIPPED,
    CT_NONFINITE,
    CT_DECIDED, /* version 6 */
    CT_COUNT
};
#define CT_COUNT_V5 CT_DECIDED

/* The window's layers per slot: layer, or UINT32_MAX for an empty slot. */
static void window_layers(const sched_t *s, uint32_t layer_of[2])
{
    layer_of[0] = layer_of[1] = UINT32_MAX;
    for (uint32_t l = s->complete; l < s->decided_n; l++)
        layer_of[l & 1] = l;
}

int sched_save(const sched_t *s, sched_write_fn write, void *ctx)
{
    /* Everything here lives on the stack or in *s: this runs in a forked
     * child, where malloc may be locked by a thread that no longer exists. */
    saver_t w = {write, ctx, {0, 0, {0}, 0}, 0};
    const size_t n = s->npix, mb = member_bytes(s);
    uint32_t vc[2] = {SCHED_SAVE_VERSION, FP_COUNT}, layer_of[2];
    uint64_t fp[FP_COUNT];
    fingerprint(s, fp, sizeof(film_pixel_t));
    window_layers(s, layer_of);
    const uint64_t ct[CT_COUNT] = {s->complete,     s->converged,    (uint64_t)s->stopped_on_target,
                                   s->samples_done, s->pixel_layers, s->skipped,
                                   s->nonfinite,    s->decided_n};
    if (put(&w, save_magic, sizeof save_magic) || put(&w, vc, sizeof vc) ||
        put(&w, fp, sizeof fp) || put_section(&w, "counters", ct, sizeof ct) ||
        put_section(&w, "film", s->film->pixels, n * sizeof(film_pixel_t)))
        return w.rc;
    /* The window, slot by slot; a slot with no layer in it is all zeros.
     * Outstanding tasks go out as ready: their records are not saved, and
     * sched_next rebuilds them from the film (layer l of a range is merged
     * only when it completes, so the film holds exactly its priors). */
    if (put_head(&w, "member", 2 * mb))
        return w.rc;
    for (int k = 0; k < 2; k++)
        if (layer_of[k] == UINT32_MAX ? put_zeros(&w, mb) : put(&w, s->member[k], mb))
            return w.rc;
    if (put_head(&w, "state", 2 * (size_t)s->ranges))
        return w.rc;
    uint8_t buf[4096];
    for (int k = 0; k < 2; k++)
        for (size_t c0 = 0; c0 < s->ranges; c0 += sizeof buf) {
            size_t m = s->ranges - c0 < sizeof buf ? s->ranges - c0 : sizeof buf;
            for (size_t i = 0; i < m; i++) {
                uint8_t st = layer_of[k] == UINT32_MAX ? ST_WAITING : s->state[k][c0 + i];
                buf[i] = st == ST_OUT ? ST_READY : st;
            }
            if (put(&w, buf, m))
                return w.rc;
        }
    uint8_t slots[2 * (sizeof(uint32_t) + sizeof(double))] = {0};
    for (int k = 0; k < 2; k++)
        if (layer_of[k] != UINT32_MAX) {
            memcpy(slots + 4 * k, &s->range_done[k], 4);
            memcpy(slots + 8 + 8 * k, &s->threshold[k], 8);
        }
    if (put_section(&w, "slots", slots, sizeof slots))
        return w.rc;
    for (size_t i = 0; i < PIXEL_ARRAYS; i++)
        if (put_section(&w, pixel_arrays[i].name, array_of(s, &pixel_arrays[i]),
                        array_bytes(s, &pixel_arrays[i])))
            return w.rc;
    if (put_head(&w, "end", sizeof(uint64_t)))
        return w.rc;
    uint64_t sum = ck_final(&w.ck);
    return put(&w, &sum, sizeof sum);
}

size_t sched_save_bytes(const sched_t *s)
{
    const size_t head = 16; /* a section's tag and length */
    size_t n = sizeof save_magic + 2 * sizeof(uint32_t) + FP_COUNT * sizeof(uint64_t);
    n += head + CT_COUNT * sizeof(uint64_t);
    n += head + (size_t)s->npix * sizeof(film_pixel_t);
    n += head + 2 * member_bytes(s) + head + 2 * (size_t)s->ranges;
    n += head + 2 * (sizeof(uint32_t) + sizeof(double));
    for (size_t i = 0; i < PIXEL_ARRAYS; i++)
        n += head + array_bytes(s, &pixel_arrays[i]);
    return n + head + sizeof(uint64_t);
}

typedef struct loader {
    sched_read_fn read;
    void *ctx;
    cksum_t ck;
} loader_t;

static int get(loader_t *r, void *data, size_t len, const char *what, char *err, size_t errlen)
{
    uint8_t *p = data;
    while (len > 0) {
        size_t n = len < SAVE_CHUNK ? len : SAVE_CHUNK;
        if (r->read(r->ctx, p, n) != 0) {
            snprintf(err, errlen, "checkpoint: truncated or unreadable (reading %s)", what);
            return -1;
        }
        ck_update(&r->ck, p, n);
        p += n;
        len -= n;
    }
    return 0;
}

/* A section's head: its tag and its size, both fixed by the config. */
static int get_head(loader_t *r, const char *tag, size_t bytes, char *err, size_t errlen)
{
    uint8_t h[16], want[8];
    uint64_t n;
    if (get(r, h, sizeof h, tag, err, errlen))
        return -1;
    tag_bytes(tag, want);
    if (memcmp(h, want, 8) != 0) {
        snprintf(err, errlen, "checkpoint: section \"%s\" expected, another tag in its place", tag);
        return -1;
    }
    memcpy(&n, h + 8, 8);
    if (n != bytes) {
        snprintf(err, errlen, "checkpoint: section \"%s\" holds %llu bytes, this config needs %zu",
                 tag, (unsigned long long)n, bytes);
        return -1;
    }
    return 0;
}

static int get_section(loader_t *r, const char *tag, void *data, size_t bytes, char *err,
                       size_t errlen)
{
    if (get_head(r, tag, bytes, err, errlen))
        return -1;
    return get(r, data, bytes, tag, err, errlen);
}

/* The header: magic, version (into *version: 5 or 6), fingerprint. */
static int load_header(const sched_t *s, loader_t *r, uint32_t *version, char *err, size_t errlen)
{
    uint8_t magic[8];
    uint32_t vc[2];
    uint64_t fp[FP_COUNT], want[FP_COUNT];
    if (get(r, magic, sizeof magic, "header", err, errlen))
        return -1;
    if (memcmp(magic, save_magic, sizeof magic) != 0) {
        snprintf(err, errlen, "checkpoint: not a scheduler checkpoint (bad magic)");
        return -1;
    }
    if (get(r, vc, sizeof vc, "header", err, errlen))
        return -1;
    if (vc[0] != SCHED_SAVE_VERSION && vc[0] != SCHED_SAVE_VERSION_V5) {
        snprintf(err, errlen,
                 "checkpoint: format version %u, this build reads versions %u and %u (a newer "
                 "master wrote it?)",
                 vc[0], SCHED_SAVE_VERSION_V5, SCHED_SAVE_VERSION);
        return -1;
    }
    *version = vc[0];
    if (vc[1] != FP_COUNT) {
        snprintf(err, errlen, "checkpoint: %u config fingerprint fields, format version %u has %u",
                 vc[1], vc[0], FP_COUNT);
        return -1;
    }
    if (get(r, fp, sizeof fp, "header", err, errlen))
        return -1;
    fingerprint(s, want,
                vc[0] == SCHED_SAVE_VERSION_V5 ? sizeof(film_pixel_v5_t) : sizeof(film_pixel_t));
    for (int i = 0; i < FP_COUNT; i++) {
        if (fp[i] == want[i])
            continue;
        if (i == FP_TARGET_ERROR || i == FP_CONFIDENCE || i == FP_TARGET_SHARE) {
            double a, b;
            memcpy(&a, &fp[i], sizeof a);
            memcpy(&b, &want[i], sizeof b);
            snprintf(
                err, errlen,
                "checkpoint: the saved job's config differs in %s (saved %.17g, this config %.17g)",
                fp_names[i], a, b);
        } else {
            snprintf(
                err, errlen,
                "checkpoint: the saved job's config differs in %s (saved %llu, this config %llu)",
                fp_names[i], (unsigned long long)fp[i], (unsigned long long)want[i]);
        }
        return -1;
    }
    return 0;
}

/* The counters every version has, into s; checked against the config. */
static int apply_counters(sched_t *s, const uint64_t *ct, char *err, size_t errlen)
{
    if (ct[CT_COMPLETE] > s->layers || ct[CT_STOPPED] > 1 || ct[CT_CONVERGED] > s->npix) {
        snprintf(err, errlen,
                 "checkpoint: counters out of range (%llu layers complete of %u, stopped %llu, "
                 "converged %llu of %u pixels)",
                 (unsigned long long)ct[CT_COMPLETE], s->layers, (unsigned long long)ct[CT_STOPPED],
                 (unsigned long long)ct[CT_CONVERGED], s->npix);
        return -1;
    }
    s->complete = (uint32_t)ct[CT_COMPLETE];
    s->converged = ct[CT_CONVERGED];
    s->stopped_on_target = (int)ct[CT_STOPPED];
    s->samples_done = ct[CT_SAMPLES];
    s->pixel_layers = ct[CT_PIXEL_LAYERS];
    s->skipped = ct[CT_SKIPPED];
    s->nonfinite = ct[CT_NONFINITE];
    return 0;
}

/* Version 6 (sched_save): reads the stream into s (made by sched_new for
 * the caller's config, so every size comes from the config, none from the
 * stream). */
static int load_v6(sched_t *s, loader_t *r, char *err, size_t errlen)
{
    const size_t n = s->npix, mb = member_bytes(s);
    uint64_t ct[CT_COUNT];
    uint8_t slots[2 * (sizeof(uint32_t) + sizeof(double))];
    if (get_section(r, "counters", ct, sizeof ct, err, errlen) ||
        apply_counters(s, ct, err, errlen))
        return -1;
    uint64_t want_d = ct[CT_DECIDED] == 0                     ? 0
                      : (uint64_t)s->complete + 2 < s->layers ? (uint64_t)s->complete + 2
                                                              : s->layers;
    if (ct[CT_DECIDED] != want_d) {
        snprintf(err, errlen, "checkpoint: %llu layers decided, expected %llu with %u complete",
                 (unsigned long long)ct[CT_DECIDED], (unsigned long long)want_d, s->complete);
        return -1;
    }
    s->decided_n = (uint32_t)ct[CT_DECIDED];
    if (get_section(r, "film", s->film->pixels, n * sizeof(film_pixel_t), err, errlen) ||
        get_head(r, "member", 2 * mb, err, errlen) ||
        get(r, s->member[0], mb, "member", err, errlen) ||
        get(r, s->member[1], mb, "member", err, errlen) ||
        get_head(r, "state", 2 * (size_t)s->ranges, err, errlen) ||
        get(r, s->state[0], s->ranges, "state", err, errlen) ||
        get(r, s->state[1], s->ranges, "state", err, errlen) ||
        get_section(r, "slots", slots, sizeof slots, err, errlen))
        return -1;
    for (int k = 0; k < 2; k++) {
        memcpy(&s->range_done[k], slots + 4 * k, 4);
        memcpy(&s->threshold[k], slots + 8 + 8 * k, 8);
    }
    for (size_t i = 0; i < PIXEL_ARRAYS; i++)
        if (get_section(r, pixel_arrays[i].name, *array_slot(s, &pixel_arrays[i]),
                        array_bytes(s, &pixel_arrays[i]), err, errlen))
            return -1;
    return get_head(r, "end", sizeof(uint64_t), err, errlen);
}

/* Reads n bytes of a section in chunks into buf (at most SAVE_CHUNK), each
 * passed to fn with its offset in the section. */
typedef void (*chunk_fn)(sched_t *s, const uint8_t *data, size_t offset, size_t len, void *ctx);
static int get_chunked(loader_t *r, sched_t *s, const char *tag, size_t bytes, uint8_t *buf,
                       chunk_fn fn, void *ctx, char *err, size_t errlen)
{
    if (get_head(r, tag, bytes, err, errlen))
        return -1;
    for (size_t off = 0; off < bytes; off += SAVE_CHUNK) {
        size_t k = bytes - off < SAVE_CHUNK ? bytes - off : SAVE_CHUNK;
        if (get(r, buf, k, tag, err, errlen))
            return -1;
        if (fn)
            fn(s, buf, off, k, ctx);
    }
    return 0;
}

/* Version 5 kept every layer: its member bits (layer l at bit l * npix + p),
 * cell states (l * ranges + r), decided flags, thresholds and range counts
 * per layer. Only the window's layers are kept from them. */
static void v5_member(sched_t *s, const uint8_t *d, size_t off, size_t len, void *ctx)
{
    (void)ctx;
    const size_t lo = off * 8, hi = (off + len) * 8; /* the chunk's bits */
    for (uint32_t l = s->complete; l < s->decided_n; l++) {
        const size_t b0 = (size_t)l * s->npix, b1 = b0 + s->npix; /* the layer's bits */
        for (size_t bit = b0 > lo ? b0 : lo; bit < (b1 < hi ? b1 : hi); bit++)
            if ((d[(bit >> 3) - off] >> (bit & 7)) & 1)
                set_member(s, l, (uint32_t)(bit - b0));
    }
}
static void v5_state(sched_t *s, const uint8_t *d, size_t off, size_t len, void *ctx)
{
    (void)ctx;
    for (uint32_t l = s->complete; l < s->decided_n; l++) {
        const size_t c0 = (size_t)l * s->ranges, c1 = c0 + s->ranges;
        for (size_t c = c0 > off ? c0 : off; c < (c1 < off + len ? c1 : off + len); c++)
            s->state[l & 1][c - c0] = d[c - off];
    }
}
/* A section that must be all zeros (version 5's batch counts in a mode
 * that keeps none). */
static void v5_zeros(sched_t *s, const uint8_t *d, size_t off, size_t len, void *ctx)
{
    (void)s;
    (void)off;
    for (size_t i = 0; i < len; i++)
        *(int *)ctx |= d[i] != 0;
}
/* Per-layer arrays: the window's layers' elements, in slot order. */
typedef struct v5_layer_ctx {
    size_t elem;
    uint8_t *out; /* 2 elements */
} v5_layer_ctx_t;
static void v5_per_layer(sched_t *s, const uint8_t *d, size_t off, size_t len, void *ctx)
{
    v5_layer_ctx_t *c = ctx;
    for (uint32_t l = s->complete; l < s->decided_n; l++)
        for (size_t b = 0; b < c->elem; b++) {
            size_t at = (size_t)l * c->elem + b;
            if (at >= off && at < off + len)
                c->out[(l & 1) * c->elem + b] = d[at - off];
        }
}
/* The decided flags: how many, as a prefix (checked for being one). */
typedef struct v5_decided_ctx {
    uint32_t prefix;
    int gap; /* a decided layer after an undecided one, or a flag not 0/1 */
} v5_decided_ctx_t;
static void v5_decided(sched_t *s, const uint8_t *d, size_t off, size_t len, void *ctx)
{
    (void)s;
    v5_decided_ctx_t *c = ctx;
    for (size_t i = 0; i < len; i++) {
        if (d[i] > 1 || (d[i] == 1 && c->prefix != off + i))
            c->gap = 1;
        else if (d[i] == 1)
            c->prefix++;
    }
}

/* Version 5 into this version's state. The snapshot and the statistics
 * after each layer in flight (by parity) become the prev_* values: a pixel
 * that merged the layer `complete` by then read the snapshot as of layer
 * complete - 1 in version 5; here it reads prev_*, which must then hold
 * that, which is the value after the layer complete - 1... as it left the
 * pixel: its flight value if it took part, the older snapshot if not. */
static int load_v5(sched_t *s, loader_t *r, char *err, size_t errlen)
{
    const size_t n = s->npix, L = s->layers, R = s->ranges;
    const int target = s->cfg.target_error > 0, counts = keeps_counts(s), cost = weighs_cost(s);
    const size_t tn = target ? n : 0, cn = counts ? n : 0, kn = cost ? n : 0;
    uint64_t ct[CT_COUNT_V5];
    int rc = -1;
    uint8_t *buf = malloc(SAVE_CHUNK);
    film_pixel_v5_t *old = malloc(SAVE_CHUNK);
    double *dv[3] = {calloc(n, sizeof(double)), calloc(n, sizeof(double)),
                     calloc(n, sizeof(double))};
    double *rv[3] = {calloc(tn + 1, sizeof(double)), calloc(tn + 1, sizeof(double)),
                     calloc(tn + 1, sizeof(double))};
    uint32_t *nv[3] = {calloc(cn + 1, sizeof(uint32_t)), calloc(cn + 1, sizeof(uint32_t)),
                       calloc(cn + 1, sizeof(uint32_t))};
    float *cv[3] = {calloc(kn + 1, sizeof(float)), calloc(kn + 1, sizeof(float)),
                    calloc(kn + 1, sizeof(float))};
    uint64_t *usamp = calloc(kn + 1, sizeof(uint64_t));
    uint32_t rdone[2] = {0, 0};
    v5_decided_ctx_t dc = {0, 0};
    v5_layer_ctx_t thc = {sizeof(double), (uint8_t *)s->threshold},
                   rdc = {sizeof(uint32_t), (uint8_t *)rdone};
    if (!buf || !old || !dv[0] || !dv[1] || !dv[2] || !rv[0] || !rv[1] || !rv[2] || !nv[0] ||
        !nv[1] || !nv[2] || !cv[0] || !cv[1] || !cv[2] || !usamp) {
        snprintf(err, errlen, "out of memory");
        goto out;
    }
    if (get_section(r, "counters", ct, sizeof ct, err, errlen) ||
        apply_counters(s, ct, err, errlen) || get_head(r, "film", n * sizeof *old, err, errlen))
        goto out;
    const size_t per = SAVE_CHUNK / sizeof *old;
    for (size_t p0 = 0; p0 < n; p0 += per) {
        size_t k = n - p0 < per ? n - p0 : per;
        if (get(r, old, k * sizeof *old, "film", err, errlen))
            goto out;
        for (size_t i = 0; i < k; i++) {
            film_pixel_t *fp = &s->film->pixels[p0 + i];
            if (old[i].count > s->cfg.spp || old[i].nonfinite > s->cfg.spp) {
                snprintf(err, errlen, "checkpoint: film pixel %zu: %llu + %llu samples", p0 + i,
                         (unsigned long long)old[i].count, (unsigned long long)old[i].nonfinite);
                goto out;
            }
            memcpy(fp->sum, old[i].sum, sizeof fp->sum);
            memcpy(fp->comp, old[i].comp, sizeof fp->comp);
            fp->lum_m2 = old[i].lum_m2;
            fp->count = (uint32_t)old[i].count;
            fp->nonfinite = (uint32_t)old[i].nonfinite;
            if (s->pvar_cur)
                s->pvar_cur[p0 + i] = old[i].pvar;
        }
    }
    /* Version 5's sections come member, decided, ...: the window must be
     * known before the member bits. It is: decided = complete + 2 (at most
     * all layers), or none before the first task (checked below). */
    const size_t member_total = (L * n + 7) / 8;
    s->decided_n = (uint32_t)(s->complete + 2 < L ? s->complete + 2 : L);
    if (get_chunked(r, s, "member", member_total, buf, v5_member, NULL, err, errlen) ||
        get_chunked(r, s, "decided", L, buf, v5_decided, &dc, err, errlen))
        goto out;
    if (dc.gap || (dc.prefix != s->decided_n && !(dc.prefix == 0 && s->complete == 0))) {
        snprintf(err, errlen, "checkpoint: %u layers decided, expected %u with %u complete",
                 dc.prefix, s->decided_n, s->complete);
        goto out;
    }
    if (dc.prefix == 0) { /* saved before its first task: nothing decided */
        s->decided_n = 0;
        memset(s->member[0], 0, member_bytes(s));
        memset(s->member[1], 0, member_bytes(s));
    }
    if (get_chunked(r, s, "thresh", L * sizeof(double), buf, v5_per_layer, &thc, err, errlen) ||
        get_chunked(r, s, "state", L * R, buf, v5_state, NULL, err, errlen) ||
        get_chunked(r, s, "rdone", L * sizeof(uint32_t), buf, v5_per_layer, &rdc, err, errlen))
        goto out;
    s->range_done[0] = rdone[0];
    s->range_done[1] = rdone[1];
    if (get_section(r, "var", dv[0], n * sizeof(double), err, errlen) ||
        get_section(r, "pvar0", dv[1], n * sizeof(double), err, errlen) ||
        get_section(r, "pvar1", dv[2], n * sizeof(double), err, errlen) ||
        get_section(r, "rvar", rv[0], tn * sizeof(double), err, errlen) ||
        get_section(r, "rvar0", rv[1], tn * sizeof(double), err, errlen) ||
        get_section(r, "rvar1", rv[2], tn * sizeof(double), err, errlen) ||
        get_section(r, "nbat", nv[0], cn * sizeof(uint32_t), err, errlen) ||
        get_section(r, "nbat0", nv[1], cn * sizeof(uint32_t), err, errlen) ||
        get_section(r, "nbat1", nv[2], cn * sizeof(uint32_t), err, errlen))
        goto out;
    /* batches, then its mean and M2, which nothing read (dropped) */
    int stray_batches = 0;
    if (s->batches ? get_section(r, "batches", s->batches, n * sizeof(uint32_t), err, errlen)
                   : get_chunked(r, s, "batches", n * sizeof(uint32_t), buf, v5_zeros,
                                 &stray_batches, err, errlen))
        goto out;
    if (stray_batches) {
        snprintf(err, errlen, "checkpoint: batch counts in a mode that keeps none");
        goto out;
    }
    if (get_chunked(r, s, "bmean", n * sizeof(double), buf, NULL, NULL, err, errlen) ||
        get_chunked(r, s, "bm2", n * sizeof(double), buf, NULL, NULL, err, errlen) ||
        get_section(r, "ubat", s->ubatches, cn * sizeof(uint32_t), err, errlen) ||
        get_section(r, "umean", s->umean, cn * sizeof(double), err, errlen) ||
        get_section(r, "um2", s->um2, cn * sizeof(double), err, errlen) ||
        get_section(r, "urays", s->urays, kn * sizeof(uint64_t), err, errlen) ||
        get_section(r, "usamp", usamp, kn * sizeof(uint64_t), err, errlen) ||
        get_section(r, "cost", cv[0], kn * sizeof(float), err, errlen) ||
        get_section(r, "cost0", cv[1], kn * sizeof(float), err, errlen) ||
        get_section(r, "cost1", cv[2], kn * sizeof(float), err, errlen) ||
        get_head(r, "end", sizeof(uint64_t), err, errlen))
        goto out;
    for (size_t p = 0; p < kn; p++) {
        if (usamp[p] > s->cfg.spp) {
            snprintf(err, errlen, "checkpoint: pixel %zu: %llu uniform-layer samples", p,
                     (unsigned long long)usamp[p]);
            goto out;
        }
        s->usamples[p] = (uint32_t)usamp[p];
    }
    /* prev_*: the statistics as of layer complete - 1 where it merged it */
    const uint32_t c = s->complete;
    for (uint32_t p = 0; p < n && s->decided_n > c; p++) {
        const int k = is_member(s, c, p) && s->state[c & 1][p / s->range_pixels] == ST_DONE
                          ? 1 + (int)(c & 1)
                          : 0;
        if (s->prev_metric)
            s->prev_metric[p] = dv[k][p];
        if (s->prev_rvar)
            s->prev_rvar[p] = rv[k][p];
        if (s->prev_nb)
            s->prev_nb[p] = nv[k][p];
        if (s->prev_cost)
            s->prev_cost[p] = cv[k][p];
    }
    rc = 0;
out:
    free(buf);
    free(old);
    for (int k = 0; k < 3; k++) {
        free(dv[k]);
        free(rv[k]);
        free(nv[k]);
        free(cv[k]);
    }
    free(usamp);
    return rc;
}

static const char *state_name(uint8_t st)
{
    static const char *const names[] = {"waiting", "ready", "outstanding", "done"};
    return st <= ST_DONE ? names[st] : "?";
}

static unsigned popcount8(uint8_t b)
{
    unsigned n = 0;
    for (; b; b &= (uint8_t)(b - 1))
        n++;
    return n;
}

/* The window: each slot's cells, counts, members and threshold must be what
 * the scheduler's own transitions leave, and a slot with no layer empty. */
static int check_window(const sched_t *s, char *err, size_t errlen)
{
    const uint32_t R = s->ranges;
    const size_t mb = member_bytes(s);
    uint32_t layer_of[2];
    window_layers(s, layer_of);
    for (int k = 0; k < 2; k++) {
        const uint32_t l = layer_of[k];
        if (l == UINT32_MAX) {
            int stray = s->range_done[k] != 0 || f64_bits(s->threshold[k]) != 0; /* -0 too */
            for (size_t i = 0; i < mb && !stray; i++)
                stray = s->member[k][i] != 0;
            for (uint32_t r = 0; r < R && !stray; r++)
                stray = s->state[k][r] != ST_WAITING;
            if (stray) {
                snprintf(err, errlen,
                         "checkpoint: window slot %d holds no layer, yet member bits, cell states "
                         "or counts are set",
                         k);
                return -1;
            }
            continue;
        }
        if (s->npix % 8 && (s->member[k][mb - 1] >> (s->npix % 8)) != 0) {
            snprintf(err, errlen, "checkpoint: member bits past the last pixel (layer %u)", l);
            return -1;
        }
        double t = s->threshold[k];
        if (applies_skip_rule(s, l) ? isnan(t) : t != 0) {
            snprintf(err, errlen, "checkpoint: threshold %g of layer %u", t, l);
            return -1;
        }
        uint32_t done = 0;
        for (uint32_t r = 0; r < R; r++) {
            uint8_t st = s->state[k][r];
            if (st != ST_WAITING && st != ST_READY && st != ST_DONE) {
                snprintf(err, errlen,
                         "checkpoint: cell state %u at layer %u, range %u is not waiting, ready or "
                         "done",
                         st, l, r);
                return -1;
            }
            /* rule 1: a cell runs once its range's previous layer is done;
             * then at once (done) if the layer has none of its pixels */
            int may = l == 0 || cell_state(s, l - 1, r) == ST_DONE;
            if ((st != ST_WAITING) != may) {
                snprintf(err, errlen,
                         "checkpoint: cell state %s at layer %u, range %u contradicts rule 1 "
                         "(previous layer's cell %s)",
                         state_name(st), l, r, l ? state_name(cell_state(s, l - 1, r)) : "none");
                return -1;
            }
            if (st == ST_READY && range_members(s, l, r) == 0) {
                snprintf(err, errlen,
                         "checkpoint: cell state ready at layer %u, range %u, which has no pixels",
                         l, r);
                return -1;
            }
            done += st == ST_DONE;
        }
        if (done != s->range_done[k] || done == R) {
            snprintf(err, errlen,
                     "checkpoint: layer %u has range_done %u and %u cells done of %u, yet is not "
                     "complete",
                     l, s->range_done[k], done, R);
            return -1;
        }
    }
    uint64_t window_members = 0;
    for (int k = 0; k < 2; k++)
        for (size_t i = 0; layer_of[k] != UINT32_MAX && i < mb; i++)
            window_members += popcount8(s->member[k][i]);
    if (s->pixel_layers + s->skipped != (uint64_t)s->decided_n * s->npix ||
        s->pixel_layers < window_members) {
        snprintf(
            err, errlen,
            "checkpoint: pixel_layers %llu and skipped %llu for %u decided layers of %u pixels",
            (unsigned long long)s->pixel_layers, (unsigned long long)s->skipped, s->decided_n,
            s->npix);
        return -1;
    }
    if (s->cfg.target_error == 0 && (s->converged || s->stopped_on_target)) {
        snprintf(err, errlen, "checkpoint: converged %llu / stopped %d without a target error",
                 (unsigned long long)s->converged, s->stopped_on_target);
        return -1;
    }
    return 0;
}

/* What Welford over at most `most` layer means in range can make. */
static int welford_plausible(uint32_t n, double mean, double m2, uint32_t most)
{
    return n <= most && mean >= 0 && mean <= 2 * SCHED_MAX_RADIANCE && m2 >= 0 && isfinite(m2) &&
           (n > 0 || mean == 0) && (n > 1 || m2 == 0);
}

/* Pixel p: finite film values, samples a whole number of layers (only the
 * last may be short), statistics that results in range can make. */
static int check_pixel(const sched_t *s, uint32_t p, char *err, size_t errlen)
{
    const film_pixel_t *fp = &s->film->pixels[p];
    const uint32_t G = s->cfg.granularity;
    /* at most the complete layers and those of the window it merged */
    uint64_t merged = s->complete;
    for (uint32_t l = s->complete; l < s->decided_n; l++)
        merged += is_member(s, l, p) && s->state[l & 1][p / s->range_pixels] == ST_DONE;
    const uint64_t taken = (uint64_t)fp->count + fp->nonfinite,
                   most = merged * G < s->cfg.spp ? merged * G : s->cfg.spp;
    static const char *const names[7] = {"sum[0]",  "sum[1]",  "sum[2]", "comp[0]",
                                         "comp[1]", "comp[2]", "lum_m2"};
    const double v[7] = {fp->sum[0],  fp->sum[1],  fp->sum[2], fp->comp[0],
                         fp->comp[1], fp->comp[2], fp->lum_m2};
    for (int k = 0; k < 7; k++)
        if (!isfinite(v[k])) {
            snprintf(err, errlen, "checkpoint: film pixel %u: %s is not finite (%g)", p, names[k],
                     v[k]);
            return -1;
        }
    if (taken > most || (taken % G != 0 && taken % G != s->cfg.spp % G)) {
        snprintf(err, errlen,
                 "checkpoint: film pixel %u holds %u + %u nonfinite samples: not whole layers of "
                 "%u, or more than the %llu layers it can have merged take",
                 p, fp->count, fp->nonfinite, G, (unsigned long long)merged);
        return -1;
    }
    const uint32_t layers = (uint32_t)((taken + G - 1) / G);
    if (s->pvar_cur && !(s->pvar_cur[p] >= 0 &&
                         s->pvar_cur[p] <= (double)G * SCHED_MAX_RADIANCE * SCHED_MAX_RADIANCE)) {
        snprintf(err, errlen, "checkpoint: pixel %u: eq. 4.1 %g", p, s->pvar_cur[p]);
        return -1;
    }
    if (s->prev_metric) {
        double m = s->prev_metric[p];
        if (isnan(m) || m == -INFINITY || (pools_neighbours(s) && m < 0)) {
            snprintf(err, errlen, "checkpoint: pixel %u: adaptive metric %g", p, m);
            return -1;
        }
    }
    if (s->prev_rvar && !(s->prev_rvar[p] >= 0)) {
        snprintf(err, errlen, "checkpoint: pixel %u: relative variance %g", p, s->prev_rvar[p]);
        return -1;
    }
    if (s->batches) {
        /* what results in range can make: a mean of layer luminances in
         * [0, SCHED_MAX_RADIANCE] (2x: rounding), a sum of squares >= 0,
         * both 0 before the first batch and the sum still 0 after it.
         * Anything else can turn the metrics NaN or infinite on the next
         * merge (Welford's update assumes them) */
        const uint32_t nb = s->batches[p];
        if (nb > layers || s->prev_nb[p] > nb ||
            !welford_plausible(s->ubatches[p], s->umean[p], s->um2[p], nb)) {
            snprintf(err, errlen,
                     "checkpoint: pixel %u: batch statistics (%u batches of %u layers, %u before "
                     "the last; %u uniform, mean %g, m2 %g)",
                     p, nb, layers, s->prev_nb[p], s->ubatches[p], s->umean[p], s->um2[p]);
            return -1;
        }
    }
    if (s->urays) {
        const uint64_t rays = s->urays[p], n = s->usamples[p];
        if (n > taken || rays < n || (n == 0) != (rays == 0)) {
            snprintf(err, errlen,
                     "checkpoint: pixel %u: %llu rays for %llu uniform-layer samples of %llu taken",
                     p, (unsigned long long)rays, (unsigned long long)n, (unsigned long long)taken);
            return -1;
        }
        const float c = s->prev_cost[p];
        if (!(c == 0 || (c >= 1 && isfinite(c)))) {
            snprintf(err, errlen, "checkpoint: pixel %u: %g rays per sample", p, (double)c);
            return -1;
        }
    }
    return 0;
}

static int check_pixels(const sched_t *s, char *err, size_t errlen)
{
    uint64_t total = 0, nonfinite = 0;
    for (uint32_t p = 0; p < s->npix; p++) {
        if (check_pixel(s, p, err, errlen) < 0)
            return -1;
        total += (uint64_t)s->film->pixels[p].count + s->film->pixels[p].nonfinite;
        nonfinite += s->film->pixels[p].nonfinite;
    }
    if (total != s->samples_done || nonfinite != s->nonfinite) {
        snprintf(
            err, errlen,
            "checkpoint: samples_done %llu and nonfinite %llu, but the film holds %llu and %llu",
            (unsigned long long)s->samples_done, (unsigned long long)s->nonfinite,
            (unsigned long long)total, (unsigned long long)nonfinite);
        return -1;
    }
    return 0;
}

sched_t *sched_load(const sched_config_t *cfg, sched_read_fn read, void *ctx, char *err,
                    size_t errlen)
{
    sched_t *s = sched_new(cfg, err, errlen);
    if (!s)
        return NULL;
    loader_t r = {read, ctx, {0, 0, {0}, 0}};
    uint64_t sum_read = 0, sum = 0;
    uint32_t version = 0;
    if (load_header(s, &r, &version, err, errlen) ||
        (version == SCHED_SAVE_VERSION ? load_v6(s, &r, err, errlen)
                                       : load_v5(s, &r, err, errlen))) {
        sched_destroy(&s);
        return NULL;
    }
    /* The checksum is compared after the consistency checks: they name a
     * problem better. */
    sum = ck_final(&r.ck);
    if (get(&r, &sum_read, sizeof sum_read, "checksum", err, errlen) ||
        check_window(s, err, errlen) || check_pixels(s, err, errlen)) {
        sched_destroy(&s);
        return NULL;
    }
    if (sum_read != sum) {
        snprintf(err, errlen, "checkpoint: checksum mismatch (the stream is corrupt)");
        sched_destroy(&s);
        return NULL;
    }
    /* The ready queue in id order: results merge per pixel in layer order
     * and decisions read snapshots only, so the order tasks are issued in
     * changes nothing. */
    s->q_head = s->q_tail = 0;
    for (uint32_t l = s->complete; l < s->decided_n; l++)
        for (uint32_t rr = 0; rr < s->ranges; rr++)
            if (s->state[l & 1][rr] == ST_READY)
                s->queue[s->q_tail++] = task_id(s, l, rr);
    return s;
}
