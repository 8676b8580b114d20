/* sched.c - see sched.h for the rules that make scheduling deterministic.
 *
 * State per (layer, range): not ready, ready (queued), outstanding, or
 * complete. Layer membership is a bitmap per layer, decided two layers
 * ahead. The eq. 4.1 statistics of the (at most two) layers in flight are
 * kept apart from the snapshot the skip decisions read, and folded into it
 * only when their layer is complete.
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

#define SCHED_TASK_SAMPLES 32768                 /* samples a task aims at (range_pixels 0) */
#define SCHED_MIN_RANGES 64                      /* ... but at least this many ranges */
#define SCHED_MAX_PIXELS (1u << 28)              /* width x height */
#define SCHED_MAX_MEMBER_BYTES ((size_t)1 << 30) /* the membership bitmap, layers x pixels */
#define SCHED_MAX_CELLS ((size_t)1 << 26)        /* layers x ranges */
#define SCHED_REQUEUE_CAP0 64                    /* requeued ids before the stack grows */
#define SCHED_RELERR_CONFIDENCE 0.95             /* relerr's half-width (sched.h) */

struct sched {
    sched_config_t cfg;
    char *flags; /* copy of cfg.flags, or NULL */
    uint32_t npix, layers, ranges, range_pixels, uniform;
    film_t *film;
    uint8_t *member;        /* layers x npix bits: pixel takes part in layer */
    uint32_t *taken;        /* per pixel: decided layers it takes part in */
    uint8_t *decided;       /* per layer */
    double *threshold;      /* per layer */
    uint8_t *state;         /* layers x ranges */
    uint32_t *range_done;   /* per layer: ranges complete */
    uint32_t complete;      /* layers fully complete (the next incomplete layer) */
    double *var_snapshot;   /* per pixel: the metric as of layer complete-1 (relerr and
                               relmse: the relative variance of a layer mean, which the
                               decision pools over the pixel's neighbours) */
    double *pvar_flight[2]; /* per pixel: the same after a layer in flight, by parity */
    double *pooled;         /* npix: relerr and relmse's metric from the neighbours */
    /* The target error (sched.h): per pixel, the relative variance of its
     * layer means and how many it has (the counts also for relerr and
     * relmse), as of layer complete-1 and after a layer in flight; from the
     * snapshot, which pixels meet the target. */
    double *rvar_snapshot, *rvar_flight[2];
    uint32_t *nb_snapshot, *nb_flight[2];
    uint8_t *conv_snapshot;
    double *pool_row, *pool_max; /* npix each: the window's row maxima, then maxima */
    uint32_t *batches;           /* per pixel: layers merged (batch means) */
    double *bmean, *bm2;         /* per pixel: Welford over the layers' luminance means */
    uint32_t *ubatches;          /* relerr, relmse: the same over the uniform layers only */
    double *umean, *um2;
    /* relmse: what a sample of the pixel costs, in rays, over the same
     * layers as ubatches (their rays and samples, NaN/Inf ones too); the
     * rays per sample as of layer complete-1 and after a layer in flight
     * (0: none yet), which decide_layer reads from the neighbours */
    uint64_t *urays, *usamples;
    float *cost_snapshot, *cost_flight[2];
    double *t_table;  /* t factors by batches - 1, for relerr (0.95) and the target, */
    double *t_target; /* 0 until first needed (t_factor): ~50 us each, and a submit must
                         not compute one per layer up front (1M layers: a minute) */
    uint64_t converged;
    int stopped_on_target;
    uint8_t *scratch;    /* npix: dilation */
    tracer_task_t **out; /* layers x ranges: records of outstanding tasks */
    uint32_t *out_count;
    uint64_t *queue; /* ready task ids, FIFO */
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
    size_t bit = (size_t)layer * s->npix + pixel;
    return (s->member[bit >> 3] >> (bit & 7)) & 1;
}

static inline void set_member(sched_t *s, uint32_t layer, uint32_t pixel)
{
    size_t bit = (size_t)layer * s->npix + pixel;
    s->member[bit >> 3] |= (uint8_t)(1u << (bit & 7));
}

/* Where pixel p's samples of layer l start: after the samples of the
 * earlier layers it took part in, so that a pixel's samples are always the
 * first ones of its sample sequence, whichever layers the adaptive rule
 * skipped (under the sobol sampler the first 2^m samples of a pixel form a
 * net, an arbitrary set of layers does not: rng.h). Only the last layer may
 * be short, so every earlier one counts G. Layers are decided in order and
 * at most two beyond the last complete one, and a layer's records are made
 * before it completes: taken[p] less the decided layers from l on is the
 * count before l, a pure function of the decisions. */
static uint64_t first_sample_of(const sched_t *s, uint32_t layer, uint32_t p)
{
    uint32_t before = s->taken[p];
    for (uint32_t l = layer; l < s->layers && s->decided[l]; l++)
        before -= (uint32_t)is_member(s, l, p);
    return (uint64_t)before * s->cfg.granularity;
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
        snprintf(err, errlen, "image too large");
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

/* The target error's tables (36 bytes a pixel), only for a job that has
 * one; -1 if any is missing. */
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

static int alloc_target_tables(sched_t *s)
{
    const size_t n = s->npix;
    if (keeps_counts(s)) {
        s->nb_snapshot = calloc(n, sizeof(uint32_t));
        s->nb_flight[0] = calloc(n, sizeof(uint32_t));
        s->nb_flight[1] = calloc(n, sizeof(uint32_t));
        if (!s->nb_snapshot || !s->nb_flight[0] || !s->nb_flight[1])
            return -1;
    }
    if (pools_neighbours(s) && !(s->pooled = calloc(n, sizeof(double))))
        return -1;
    if (keeps_counts(s)) {
        s->ubatches = calloc(n, sizeof(uint32_t));
        s->umean = calloc(n, sizeof(double));
        s->um2 = calloc(n, sizeof(double));
        if (!s->ubatches || !s->umean || !s->um2)
            return -1;
    }
    if (weighs_cost(s)) {
        s->urays = calloc(n, sizeof(uint64_t));
        s->usamples = calloc(n, sizeof(uint64_t));
        s->cost_snapshot = calloc(n, sizeof(float));
        s->cost_flight[0] = calloc(n, sizeof(float));
        s->cost_flight[1] = calloc(n, sizeof(float));
        if (!s->urays || !s->usamples || !s->cost_snapshot || !s->cost_flight[0] ||
            !s->cost_flight[1])
            return -1;
    }
    if (s->cfg.target_error <= 0)
        return 0;
    s->conv_snapshot = calloc(n, 1);
    s->pool_row = calloc(n, sizeof(double));
    s->pool_max = calloc(n, sizeof(double));
    s->rvar_snapshot = calloc(n, sizeof(double));
    for (int k = 0; k < 2; k++)
        s->rvar_flight[k] = calloc(n, sizeof(double));
    return !s->conv_snapshot || !s->pool_row || !s->pool_max || !s->rvar_snapshot ||
                   !s->rvar_flight[0] || !s->rvar_flight[1]
               ? -1
               : 0;
}

/* Every per-layer, per-cell and per-pixel table, zeroed; -1 if any is
 * missing (sched_destroy frees the rest). */
static int alloc_tables(sched_t *s, size_t cells, size_t member_bytes)
{
    s->film = film_new((int)s->cfg.width, (int)s->cfg.height);
    s->member = calloc(member_bytes, 1);
    s->taken = calloc(s->npix, sizeof(uint32_t));
    s->decided = calloc(s->layers, 1);
    s->threshold = calloc(s->layers, sizeof(double));
    s->state = calloc(cells, 1);
    s->range_done = calloc(s->layers, sizeof(uint32_t));
    s->var_snapshot = calloc(s->npix, sizeof(double));
    s->pvar_flight[0] = calloc(s->npix, sizeof(double));
    s->pvar_flight[1] = calloc(s->npix, sizeof(double));
    int target_failed = alloc_target_tables(s);
    s->batches = calloc(s->npix, sizeof(uint32_t));
    s->bmean = calloc(s->npix, sizeof(double));
    s->bm2 = calloc(s->npix, sizeof(double));
    s->scratch = calloc(s->npix, 1);
    s->t_table = calloc((size_t)s->layers + 1, sizeof(double));
    s->t_target = calloc((size_t)s->layers + 1, sizeof(double));
    s->out = calloc(cells, sizeof(tracer_task_t *));
    s->out_count = calloc(cells, sizeof(uint32_t));
    s->q_cap = cells + 1;
    s->queue = malloc(s->q_cap * sizeof(uint64_t));
    s->rq_cap = SCHED_REQUEUE_CAP0;
    s->requeued = malloc(s->rq_cap * sizeof(uint64_t));
    return !s->film || !s->member || !s->taken || !s->decided || !s->threshold || !s->state ||
                   !s->range_done || !s->var_snapshot || !s->pvar_flight[0] || !s->pvar_flight[1] ||
                   !s->out || !s->out_count || target_failed || !s->batches || !s->bmean ||
                   !s->bm2 || !s->scratch || !s->t_table || !s->t_target || !s->queue ||
                   !s->requeued
               ? -1
               : 0;
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
    size_t cells = (size_t)s->layers * s->ranges;
    size_t member_bytes = ((size_t)s->layers * s->npix + 7) / 8;
    if (member_bytes > SCHED_MAX_MEMBER_BYTES || cells > SCHED_MAX_CELLS) {
        snprintf(err, errlen, "too many layers x pixels (%u layers of %u pixels)", s->layers,
                 s->npix);
        free(s->flags);
        free(s);
        return NULL;
    }
    if (s->cfg.confidence <= 0)
        s->cfg.confidence = JOB_DEFAULT_CONFIDENCE;
    if (s->cfg.target_share <= 0)
        s->cfg.target_share = JOB_DEFAULT_TARGET_SHARE;
    if (alloc_tables(s, cells, member_bytes) < 0) {
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
    if (s->out)
        for (size_t i = 0; i < (size_t)s->layers * s->ranges; i++)
            free(s->out[i]);
    film_destroy(&s->film);
    free(s->flags);
    free(s->member);
    free(s->taken);
    free(s->decided);
    free(s->threshold);
    free(s->state);
    free(s->range_done);
    free(s->var_snapshot);
    free(s->pvar_flight[0]);
    free(s->pvar_flight[1]);
    free(s->pooled);
    free(s->ubatches);
    free(s->umean);
    free(s->um2);
    free(s->urays);
    free(s->usamples);
    free(s->cost_snapshot);
    free(s->cost_flight[0]);
    free(s->cost_flight[1]);
    free(s->conv_snapshot);
    free(s->pool_row);
    free(s->pool_max);
    for (int k = 0; k < 2; k++) {
        free(s->rvar_flight[k]);
        free(s->nb_flight[k]);
    }
    free(s->rvar_snapshot);
    free(s->nb_snapshot);
    free(s->batches);
    free(s->bmean);
    free(s->bm2);
    free(s->scratch);
    free(s->t_table);
    free(s->t_target);
    free(s->out);
    free(s->out_count);
    free(s->queue);
    free(s->requeued);
    free(s);
    *sp = NULL;
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
    if (layer >= s->layers || pixel >= s->npix || !s->decided[layer])
        return -1;
    return is_member(s, layer, pixel);
}

double sched_threshold(const sched_t *s, uint32_t layer)
{
    return layer < s->layers ? s->threshold[layer] : 0.0;
}

/* The two-sided t factor at `confidence` for k degrees of freedom, cached in
 * table[k]. 0 means not computed yet: a quantile is never 0 for k >= 1 (and
 * if one ever underflowed it would merely be computed again). */
static double t_factor(double *table, double confidence, uint32_t k)
{
    if (table[k] == 0)
        table[k] = stats_t_two_sided(confidence, k);
    return table[k];
}

static void complete_range(sched_t *s, uint32_t layer, uint32_t range);

/* (layer, range) can run: queue it, or complete it at once when the layer
 * has none of the range's pixels. */
static void make_ready(sched_t *s, uint32_t layer, uint32_t range)
{
    size_t cell = (size_t)layer * s->ranges + range;
    if (s->state[cell] != ST_WAITING)
        return;
    if (range_members(s, layer, range) == 0) {
        s->state[cell] = ST_OUT;
        complete_range(s, layer, range);
        return;
    }
    s->state[cell] = ST_READY;
    s->queue[s->q_tail] = task_id(s, layer, range);
    s->q_tail = (s->q_tail + 1) % s->q_cap;
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

/* The largest of v over the (2 SCHED_TARGET_POOL_RADIUS + 1)^2 window around
 * each pixel, the pixel itself left out, into out: separable (rows into
 * s->pool_row, then columns) with the pixel in, then the few pixels that
 * are their window's maximum done again without themselves. A pixel with
 * no neighbour at all (a 1 x 1 image) keeps its own value. */
static void window_max_excluding_self(sched_t *s, const double *v, double *out)
{
    const int w = (int)s->cfg.width, h = (int)s->cfg.height, r = SCHED_TARGET_POOL_RADIUS;
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            double m = 0;
            for (int xx = x - r; xx <= x + r; xx++)
                if (xx >= 0 && xx < w && v[y * w + xx] > m)
                    m = v[y * w + xx];
            s->pool_row[y * w + x] = m;
        }
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            double m = 0;
            for (int yy = y - r; yy <= y + r; yy++)
                if (yy >= 0 && yy < h && s->pool_row[yy * w + x] > m)
                    m = s->pool_row[yy * w + x];
            out[y * w + x] = m;
        }
    if (w * h == 1)
        return;
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            if (v[y * w + x] < out[y * w + x])
                continue; /* a neighbour holds the maximum */
            double m = 0;
            for (int yy = y - r; yy <= y + r; yy++)
                for (int xx = x - r; xx <= x + r; xx++)
                    if (yy >= 0 && yy < h && xx >= 0 && xx < w && (yy != y || xx != x) &&
                        v[yy * w + xx] > m)
                        m = v[yy * w + xx];
            out[y * w + x] = m;
        }
}

/* Which pixels meet the target error, from the snapshot, into
 * s->conv_snapshot; returns how many. A pixel's own layer means can look
 * steady long before it meets a rare bright path (a caustic seen through
 * glass) that its neighbours have met: its relative variance is taken as
 * the largest in its window (sched.h, bench/error/target.py). The pixel
 * itself is left out: a pixel that stopped because its own layers looked
 * steady would stop exactly when it had not met the bright path yet, and
 * its mean would be low (test_target_unbiased); only its layer count is
 * its own. Nor may
 * a neighbour's statistics grow with the layers it took, since how many
 * it took depends on this pixel's values through the neighbour's own
 * window: they come from every pixel's first SCHED_TARGET_MIN_LAYERS
 * layers, frozen from then on (sched.h). */
static uint64_t mark_converged(sched_t *s)
{
    uint64_t conv = 0;
    window_max_excluding_self(s, s->rvar_snapshot, s->pool_max);
    for (uint32_t p = 0; p < s->npix; p++) {
        uint32_t nb = s->nb_snapshot[p];
        int c = nb >= SCHED_TARGET_MIN_LAYERS &&
                t_factor(s->t_target, s->cfg.confidence, nb - 1) * sqrt(s->pool_max[p] / nb) <=
                    s->cfg.target_error;
        s->conv_snapshot[p] = (uint8_t)c;
        conv += (uint64_t)c;
    }
    return conv;
}

/* relmse: the rays a sample of the pixel at (x, y) takes, as the mean over
 * its 3x3 neighbours of their uniform layers' rays per sample, the pixel
 * itself left out for the same reason as its variance (its own uniform
 * rays count with its radiance: the paths that enter glass are both the
 * long and the bright ones). At least 1 (every sample traces its camera
 * ray); 1 while no neighbour has any (a 1 x 1 image: all pixels alike). */
static double neighbour_cost(const sched_t *s, int x, int y)
{
    const int w = (int)s->cfg.width, h = (int)s->cfg.height;
    double sum = 0;
    int k = 0;
    for (int yy = y - 1; yy <= y + 1; yy++)
        for (int xx = x - 1; xx <= x + 1; xx++)
            if (yy >= 0 && yy < h && xx >= 0 && xx < w && (yy != y || xx != x) &&
                s->cost_snapshot[yy * w + xx] > 0) {
                sum += s->cost_snapshot[yy * w + xx];
                k++;
            }
    return k && sum > k ? sum / k : 1.0;
}

/* relerr and relmse's metric for each pixel, into s->pooled, from the
 * snapshot: the relative variance of a layer mean, measured over the uniform
 * layers only, is the mean over the pixel's 3x3 neighbours, the pixel itself
 * left out; its own layer count scales it. Why: a pixel given more layers
 * when its own layers look noisy, and fewer when they look steady, keeps a
 * low estimate longer than a high one (a pixel that has not met a rare
 * bright path looks steady and stops), so its mean comes out low: -3 to -4 %
 * on the glass scene. Its neighbours' variance says about as much about how
 * noisy it is. Uniform layers only, since a neighbour's other layers were
 * chosen by statistics this pixel's samples took part in (its spike would
 * send the neighbours on sampling, find their spikes, and come back as more
 * layers for it: still -2 to -3 % in test_sched). So nothing that decides
 * how many layers a pixel gets depends on its own samples, and its mean
 * stays unbiased (but for its 1/npix share in the threshold). */
static void pool_neighbours(sched_t *s)
{
    const int w = (int)s->cfg.width, h = (int)s->cfg.height;
    const double *v = s->var_snapshot;
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            const uint32_t p = (uint32_t)(y * w + x);
            double sum = 0;
            int k = 0;
            for (int yy = y - 1; yy <= y + 1; yy++)
                for (int xx = x - 1; xx <= x + 1; xx++)
                    if (yy >= 0 && yy < h && xx >= 0 && xx < w && (yy != y || xx != x)) {
                        sum += v[yy * w + xx];
                        k++;
                    }
            const double rv = k ? sum / k : v[p]; /* a 1 x 1 image has only itself */
            const uint32_t nb = s->nb_snapshot[p];
            if (nb < 2 || !isfinite(rv))
                s->pooled[p] = INFINITY; /* sampled until it and its neighbours have two */
            else if (s->cfg.adaptive == SCHED_ADAPTIVE_RELMSE)
                s->pooled[p] = rv / ((double)nb * nb) / neighbour_cost(s, x, y);
            else
                s->pooled[p] =
                    t_factor(s->t_table, SCHED_RELERR_CONFIDENCE, nb - 1) * sqrt(rv / nb);
        }
}

/* Chooses the pixels of a layer from the snapshot (layers < s->complete). */
static void decide_layer(sched_t *s, uint32_t layer)
{
    if (layer >= s->layers || s->decided[layer])
        return;
    int skip_rule = applies_skip_rule(s, layer);
    double threshold = 0;
    const double *metric = s->var_snapshot;
    if (skip_rule && pools_neighbours(s)) {
        pool_neighbours(s);
        metric = s->pooled;
    }
    if (skip_rule) {
        /* the mean over pixels (eq. 4.3); pixels without a value yet (inf)
         * are sampled anyway and left out of the mean */
        size_t n = 0;
        for (uint32_t p = 0; p < s->npix; p++)
            if (isfinite(metric[p])) {
                threshold += metric[p];
                n++;
            }
        threshold = n ? threshold / (double)n : 0.0;
    }
    s->threshold[layer] = threshold;
    uint64_t conv = s->cfg.target_error > 0 ? mark_converged(s) : 0;
    s->converged = conv;
    int stop_all = s->cfg.target_error > 0 && (double)conv >= s->cfg.target_share * s->npix;
    if (stop_all && !s->stopped_on_target)
        s->stopped_on_target = 1;
    uint8_t *sel = s->scratch;
    for (uint32_t p = 0; p < s->npix; p++) {
        double m = metric[p];
        int in = !skip_rule || !(m < threshold);
        if (!in && s->cfg.random_selection && threshold > 0) {
            /* near the threshold a pixel is likely kept, far below rarely:
             * avoids trapping pixels in a "local solution" (thesis 6) */
            rng_stream_t r = rng_stream(s->cfg.seed ^ 0x5eed5e1ec7ULL, p, layer);
            in = rng_next_double(&r) < m / threshold;
        }
        sel[p] = (uint8_t)in;
    }
    if (skip_rule && s->cfg.dilate) {
        /* grow the selection by one pixel: noise is seen across pixels, and a
         * lone skipped pixel or a hard edge of skipped ones shows as a seam */
        uint32_t w = s->cfg.width, h = s->cfg.height;
        for (uint32_t y = 0; y < h; y++)
            for (uint32_t x = 0; x < w; x++) {
                uint32_t p = y * w + x;
                if (sel[p] & 1)
                    continue;
                int near = 0;
                for (int dy = -1; dy <= 1 && !near; dy++)
                    for (int dx = -1; dx <= 1 && !near; dx++) {
                        int yy = (int)y + dy, xx = (int)x + dx;
                        if (yy >= 0 && yy < (int)h && xx >= 0 && xx < (int)w)
                            near = sel[(uint32_t)yy * w + (uint32_t)xx] & 1;
                    }
                if (near)
                    sel[p] |= 2;
            }
    }
    for (uint32_t p = 0; p < s->npix; p++) {
        int in = sel[p] != 0 && !stop_all && !(s->cfg.target_error > 0 && s->conv_snapshot[p]);
        if (in) {
            set_member(s, layer, p);
            s->taken[p]++;
            s->pixel_layers++;
        } else {
            s->skipped++;
        }
    }
    s->decided[layer] = 1;
    for (uint32_t r = 0; r < s->ranges; r++)
        if (layer == 0 || s->state[(size_t)(layer - 1) * s->ranges + r] == ST_DONE)
            make_ready(s, layer, r);
}

static void complete_range(sched_t *s, uint32_t layer, uint32_t range)
{
    /* An explicit stack instead of recursion: completing (l, r) can make
     * (l+1, r) ready, which may be empty and complete at once, and so on. */
    for (;;) {
        size_t cell = (size_t)layer * s->ranges + range;
        s->state[cell] = ST_DONE;
        if (++s->range_done[layer] == s->ranges) {
            /* Layers complete in order (rule 1), so this is s->complete. */
            const double *pv = s->pvar_flight[layer & 1], *rv = s->rvar_flight[layer & 1];
            const uint32_t *nf = s->nb_flight[layer & 1];
            const float *cf = s->cost_flight[layer & 1];
            for (uint32_t p = 0; p < s->npix; p++)
                if (is_member(s, layer, p)) {
                    s->var_snapshot[p] = pv[p];
                    if (rv)
                        s->rvar_snapshot[p] = rv[p];
                    if (nf)
                        s->nb_snapshot[p] = nf[p];
                    if (cf)
                        s->cost_snapshot[p] = cf[p];
                }
            s->complete = layer + 1;
            decide_layer(s, layer + 2);
        }
        uint32_t next = layer + 1;
        if (next >= s->layers || !s->decided[next])
            return;
        size_t ncell = (size_t)next * s->ranges + range;
        if (s->state[ncell] != ST_WAITING)
            return;
        if (range_members(s, next, range) == 0) {
            s->state[ncell] = ST_OUT;
            layer = next;
            continue;
        }
        make_ready(s, next, range);
        return;
    }
}

static void start(sched_t *s)
{
    if (s->layers > 0 && !s->decided[0]) {
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
    size_t cell = (size_t)layer * s->ranges + range;
    if (!s->out[cell]) {
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
            rec[k].first_sample = first_sample_of(s, layer, p);
            film_prior(s->film, &rec[k]);
            k++;
        }
        s->out[cell] = rec;
        s->out_count[cell] = n;
    }
    s->state[cell] = ST_OUT;
    out->id = id;
    out->layer = layer;
    out->range = range;
    out->count = s->out_count[cell];
    out->records = s->out[cell];
    return SCHED_OK;
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
        if (s->state[id - 1] != ST_READY)
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
    if (task_id == 0 || task_id > (uint64_t)s->layers * s->ranges ||
        s->state[task_id - 1] != ST_READY)
        return SCHED_NOT_OUTSTANDING;
    return issue(s, task_id, out);
}

/* SCHED_OK and the task's cell if it is handed out, else SCHED_NOT_OUTSTANDING. */
static sched_status_t lookup(const sched_t *s, uint64_t id, size_t *cell)
{
    if (id == 0 || id > (uint64_t)s->layers * s->ranges)
        return SCHED_NOT_OUTSTANDING;
    *cell = (size_t)(id - 1);
    return s->state[*cell] == ST_OUT && s->out[*cell] ? SCHED_OK : SCHED_NOT_OUTSTANDING;
}

int sched_requeue(sched_t *s, uint64_t task_id)
{
    size_t cell;
    if (lookup(s, task_id, &cell) != SCHED_OK)
        return SCHED_NOT_OUTSTANDING;
    if (s->rq_len == s->rq_cap) {
        uint64_t *n = realloc(s->requeued, 2 * s->rq_cap * sizeof(uint64_t));
        if (!n)
            return SCHED_NO_MEMORY;
        s->requeued = n;
        s->rq_cap *= 2;
    }
    s->state[cell] = ST_READY;
    s->requeued[s->rq_len++] = task_id;
    return SCHED_OK;
}

int sched_outstanding(const sched_t *s, uint64_t task_id, sched_task_t *out)
{
    size_t cell;
    if (lookup(s, task_id, &cell) != SCHED_OK)
        return SCHED_NOT_OUTSTANDING;
    out->id = task_id;
    out->layer = (uint32_t)(cell / s->ranges);
    out->range = (uint32_t)(cell % s->ranges);
    out->count = s->out_count[cell];
    out->records = s->out[cell];
    return SCHED_OK;
}

int sched_check(const sched_t *s, uint64_t task_id, const tracer_result_t *results, uint32_t count,
                char *err, size_t errlen)
{
    size_t cell;
    if (lookup(s, task_id, &cell) != SCHED_OK) {
        snprintf(err, errlen, "task %llu is not outstanding", (unsigned long long)task_id);
        return SCHED_NOT_OUTSTANDING;
    }
    const tracer_task_t *rec = s->out[cell];
    if (count != s->out_count[cell]) {
        snprintf(err, errlen, "task %llu: %u results for %u pixels", (unsigned long long)task_id,
                 count, s->out_count[cell]);
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
    const size_t cell = (size_t)(task_id - 1);
    const tracer_task_t *rec = s->out[cell];
    uint32_t layer = (uint32_t)((task_id - 1) / s->ranges),
             range = (uint32_t)((task_id - 1) % s->ranges);
    double *pv = s->pvar_flight[layer & 1], *rv = s->rvar_flight[layer & 1];
    uint32_t *nf = s->nb_flight[layer & 1];
    float *cf = s->cost_flight[layer & 1];
    /* batch statistics only where something reads them: this loop runs for
     * every pixel-layer result, millions a second on one master core */
    const int batches = s->cfg.adaptive == SCHED_ADAPTIVE_RELERR ||
                        s->cfg.adaptive == SCHED_ADAPTIVE_RELMSE || s->cfg.target_error > 0;
    /* a uniform layer: every pixel takes it, whatever any pixel's values */
    const int adaptive_layer = applies_skip_rule(s, layer);
    for (uint32_t i = 0; i < count; i++) {
        uint32_t p = results[i].pixel;
        film_merge(s->film, &results[i]);
        s->samples_done += rec[i].sample_count;
        s->nonfinite += results[i].nonfinite;
        if (!batches) {
            pv[p] =
                s->cfg.adaptive == SCHED_ADAPTIVE_VARIANCE
                    ? (s->film->pixels[p].count >= 2 ? film_variance_of_mean(s->film, p) : INFINITY)
                    : results[i].pvar;
            continue;
        }
        /* with a target error, a pixel's first SCHED_TARGET_MIN_LAYERS
         * layers whatever they are (mark_converged); else its uniform layers */
        const int judged =
            s->ubatches &&
            (s->cfg.target_error > 0 ? s->ubatches[p] < SCHED_TARGET_MIN_LAYERS : !adaptive_layer);
        /* the layer's mean is one batch; Welford over batches */
        if (results[i].samples > 0) {
            double bm = vmath_luminance(results[i].sum[0], results[i].sum[1], results[i].sum[2]) /
                        results[i].samples;
            welford_add(&s->batches[p], &s->bmean[p], &s->bm2[p], bm);
            if (judged)
                welford_add(&s->ubatches[p], &s->umean[p], &s->um2[p], bm);
        }
        if (cf) {
            if (judged) {
                s->urays[p] += results[i].rays;
                s->usamples[p] += rec[i].sample_count;
            }
            cf[p] = s->usamples[p] ? (float)((double)s->urays[p] / (double)s->usamples[p]) : 0.0f;
        }
        uint32_t nb = s->batches[p];
        switch (s->cfg.adaptive) {
        case SCHED_ADAPTIVE_VARIANCE:
            pv[p] = s->film->pixels[p].count >= 2 ? film_variance_of_mean(s->film, p) : INFINITY;
            break;
        case SCHED_ADAPTIVE_RELERR:
        case SCHED_ADAPTIVE_RELMSE: {
            /* the relative variance of one layer's mean, over the uniform
             * layers; decide_layer turns its neighbours' into the metric */
            const uint32_t nu = s->ubatches[p];
            double scale = fabs(s->umean[p]) + SCHED_RELERR_EPS;
            pv[p] = nu >= 2 ? s->um2[p] / (nu - 1) / (scale * scale) : INFINITY;
            break;
        }
        default:
            pv[p] = results[i].pvar;
            break;
        }
        if (s->cfg.target_error > 0) {
            /* a layer mean's relative variance, over its first layers */
            const uint32_t nu = s->ubatches[p];
            double scale = fabs(s->umean[p]) + SCHED_TARGET_EPS;
            rv[p] =
                nu >= SCHED_TARGET_MIN_LAYERS ? s->um2[p] / (nu - 1) / (scale * scale) : INFINITY;
        }
        if (nf)
            nf[p] = nb;
    }
    free(s->out[cell]);
    s->out[cell] = NULL;
    s->out_count[cell] = 0;
    complete_range(s, layer, range);
    return SCHED_OK;
}

/* ---- checkpoints ---------------------------------------------------------- */

/* write and read calls carry at most this much: the pipe or socket behind
 * them need not take a gigabyte bitmap in one call. */
#define SAVE_CHUNK ((size_t)1 << 20)

static const uint8_t save_magic[8] = {'V', 'B', 'S', 'C', 'H', 'E', 'D', '\n'};

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

static void fingerprint(const sched_t *s, uint64_t fp[FP_COUNT])
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
    fp[FP_PIXEL_BYTES] = sizeof(film_pixel_t);
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

static size_t member_bytes(const sched_t *s)
{
    return ((size_t)s->layers * s->npix + 7) / 8;
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

/* Counters, in this order in the "counters" section. */
enum {
    CT_COMPLETE,
    CT_CONVERGED,
    CT_STOPPED,
    CT_SAMPLES,
    CT_PIXEL_LAYERS,
    CT_SKIPPED,
    CT_NONFINITE,
    CT_COUNT
};

int sched_save(const sched_t *s, sched_write_fn write, void *ctx)
{
    /* Everything here lives on the stack or in *s: this runs in a forked
     * child, where malloc may be locked by a thread that no longer exists. */
    saver_t w = {write, ctx, {0, 0, {0}, 0}, 0};
    const size_t cells = (size_t)s->layers * s->ranges, n = s->npix;
    const size_t tn = s->cfg.target_error > 0 ? n : 0; /* the target error's tables */
    const size_t cn = keeps_counts(s) ? n : 0;         /* layer-mean counts */
    const size_t un = keeps_counts(s) ? n : 0;         /* uniform layers' statistics */
    const size_t kn = weighs_cost(s) ? n : 0;          /* their cost */
    uint32_t vc[2] = {SCHED_SAVE_VERSION, FP_COUNT};
    uint64_t fp[FP_COUNT];
    fingerprint(s, fp);
    const uint64_t ct[CT_COUNT] = {s->complete,     s->converged,    (uint64_t)s->stopped_on_target,
                                   s->samples_done, s->pixel_layers, s->skipped,
                                   s->nonfinite};
    if (put(&w, save_magic, sizeof save_magic) || put(&w, vc, sizeof vc) ||
        put(&w, fp, sizeof fp) || put_section(&w, "counters", ct, sizeof ct) ||
        put_section(&w, "film", s->film->pixels, n * sizeof(film_pixel_t)) ||
        put_section(&w, "member", s->member, member_bytes(s)) ||
        put_section(&w, "decided", s->decided, s->layers) ||
        put_section(&w, "thresh", s->threshold, s->layers * sizeof(double)))
        return w.rc;
    /* Outstanding tasks go out as ready: their records are not saved, and
     * sched_next rebuilds them from the film (layer l of a range is merged
     * only when it completes, so the film holds exactly its priors). */
    if (put_head(&w, "state", cells))
        return w.rc;
    uint8_t buf[4096];
    for (size_t c0 = 0; c0 < cells; c0 += sizeof buf) {
        size_t k = cells - c0 < sizeof buf ? cells - c0 : sizeof buf;
        for (size_t i = 0; i < k; i++)
            buf[i] = s->state[c0 + i] == ST_OUT ? ST_READY : s->state[c0 + i];
        if (put(&w, buf, k))
            return w.rc;
    }
    if (put_section(&w, "rdone", s->range_done, s->layers * sizeof(uint32_t)) ||
        put_section(&w, "var", s->var_snapshot, n * sizeof(double)) ||
        put_section(&w, "pvar0", s->pvar_flight[0], n * sizeof(double)) ||
        put_section(&w, "pvar1", s->pvar_flight[1], n * sizeof(double)) ||
        put_section(&w, "rvar", s->rvar_snapshot, tn * sizeof(double)) ||
        put_section(&w, "rvar0", s->rvar_flight[0], tn * sizeof(double)) ||
        put_section(&w, "rvar1", s->rvar_flight[1], tn * sizeof(double)) ||
        put_section(&w, "nbat", s->nb_snapshot, cn * sizeof(uint32_t)) ||
        put_section(&w, "nbat0", s->nb_flight[0], cn * sizeof(uint32_t)) ||
        put_section(&w, "nbat1", s->nb_flight[1], cn * sizeof(uint32_t)) ||
        put_section(&w, "batches", s->batches, n * sizeof(uint32_t)) ||
        put_section(&w, "bmean", s->bmean, n * sizeof(double)) ||
        put_section(&w, "bm2", s->bm2, n * sizeof(double)) ||
        put_section(&w, "ubat", s->ubatches, un * sizeof(uint32_t)) ||
        put_section(&w, "umean", s->umean, un * sizeof(double)) ||
        put_section(&w, "um2", s->um2, un * sizeof(double)) ||
        put_section(&w, "urays", s->urays, kn * sizeof(uint64_t)) ||
        put_section(&w, "usamp", s->usamples, kn * sizeof(uint64_t)) ||
        put_section(&w, "cost", s->cost_snapshot, kn * sizeof(float)) ||
        put_section(&w, "cost0", s->cost_flight[0], kn * sizeof(float)) ||
        put_section(&w, "cost1", s->cost_flight[1], kn * sizeof(float)) ||
        put_head(&w, "end", sizeof(uint64_t)))
        return w.rc;
    uint64_t sum = ck_final(&w.ck);
    return put(&w, &sum, sizeof sum);
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

/* Reads the stream into s (made by sched_new for the caller's config, so
 * every size comes from the config, none from the stream). The checksum is
 * returned, not compared: the consistency checks name a problem better. */
static int load_stream(sched_t *s, loader_t *r, uint64_t *sum_read, uint64_t *sum_computed,
                       char *err, size_t errlen)
{
    const size_t cells = (size_t)s->layers * s->ranges, n = s->npix;
    const size_t tn = s->cfg.target_error > 0 ? n : 0, cn = keeps_counts(s) ? n : 0,
                 un = keeps_counts(s) ? n : 0, kn = weighs_cost(s) ? n : 0;
    uint8_t magic[8];
    uint32_t vc[2];
    uint64_t fp[FP_COUNT], want[FP_COUNT], ct[CT_COUNT];
    if (get(r, magic, sizeof magic, "header", err, errlen))
        return -1;
    if (memcmp(magic, save_magic, sizeof magic) != 0) {
        snprintf(err, errlen, "checkpoint: not a scheduler checkpoint (bad magic)");
        return -1;
    }
    if (get(r, vc, sizeof vc, "header", err, errlen))
        return -1;
    if (vc[0] != SCHED_SAVE_VERSION) {
        snprintf(err, errlen, "checkpoint: format version %u, this build reads version %u only",
                 vc[0], SCHED_SAVE_VERSION);
        return -1;
    }
    if (vc[1] != FP_COUNT) {
        snprintf(err, errlen, "checkpoint: %u config fingerprint fields, format version %u has %u",
                 vc[1], SCHED_SAVE_VERSION, FP_COUNT);
        return -1;
    }
    if (get(r, fp, sizeof fp, "header", err, errlen))
        return -1;
    fingerprint(s, want);
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
    if (get_section(r, "counters", ct, sizeof ct, err, errlen))
        return -1;
    if (ct[CT_COMPLETE] > s->layers || ct[CT_STOPPED] > 1) {
        snprintf(err, errlen,
                 "checkpoint: counters out of range (%llu layers complete of %u, stopped %llu)",
                 (unsigned long long)ct[CT_COMPLETE], s->layers,
                 (unsigned long long)ct[CT_STOPPED]);
        return -1;
    }
    s->complete = (uint32_t)ct[CT_COMPLETE];
    s->converged = ct[CT_CONVERGED];
    s->stopped_on_target = (int)ct[CT_STOPPED];
    s->samples_done = ct[CT_SAMPLES];
    s->pixel_layers = ct[CT_PIXEL_LAYERS];
    s->skipped = ct[CT_SKIPPED];
    s->nonfinite = ct[CT_NONFINITE];
    if (get_section(r, "film", s->film->pixels, n * sizeof(film_pixel_t), err, errlen) ||
        get_section(r, "member", s->member, member_bytes(s), err, errlen) ||
        get_section(r, "decided", s->decided, s->layers, err, errlen) ||
        get_section(r, "thresh", s->threshold, s->layers * sizeof(double), err, errlen) ||
        get_section(r, "state", s->state, cells, err, errlen) ||
        get_section(r, "rdone", s->range_done, s->layers * sizeof(uint32_t), err, errlen) ||
        get_section(r, "var", s->var_snapshot, n * sizeof(double), err, errlen) ||
        get_section(r, "pvar0", s->pvar_flight[0], n * sizeof(double), err, errlen) ||
        get_section(r, "pvar1", s->pvar_flight[1], n * sizeof(double), err, errlen) ||
        get_section(r, "rvar", s->rvar_snapshot, tn * sizeof(double), err, errlen) ||
        get_section(r, "rvar0", s->rvar_flight[0], tn * sizeof(double), err, errlen) ||
        get_section(r, "rvar1", s->rvar_flight[1], tn * sizeof(double), err, errlen) ||
        get_section(r, "nbat", s->nb_snapshot, cn * sizeof(uint32_t), err, errlen) ||
        get_section(r, "nbat0", s->nb_flight[0], cn * sizeof(uint32_t), err, errlen) ||
        get_section(r, "nbat1", s->nb_flight[1], cn * sizeof(uint32_t), err, errlen) ||
        get_section(r, "batches", s->batches, n * sizeof(uint32_t), err, errlen) ||
        get_section(r, "bmean", s->bmean, n * sizeof(double), err, errlen) ||
        get_section(r, "bm2", s->bm2, n * sizeof(double), err, errlen) ||
        get_section(r, "ubat", s->ubatches, un * sizeof(uint32_t), err, errlen) ||
        get_section(r, "umean", s->umean, un * sizeof(double), err, errlen) ||
        get_section(r, "um2", s->um2, un * sizeof(double), err, errlen) ||
        get_section(r, "urays", s->urays, kn * sizeof(uint64_t), err, errlen) ||
        get_section(r, "usamp", s->usamples, kn * sizeof(uint64_t), err, errlen) ||
        get_section(r, "cost", s->cost_snapshot, kn * sizeof(float), err, errlen) ||
        get_section(r, "cost0", s->cost_flight[0], kn * sizeof(float), err, errlen) ||
        get_section(r, "cost1", s->cost_flight[1], kn * sizeof(float), err, errlen) ||
        get_head(r, "end", sizeof(uint64_t), err, errlen))
        return -1;
    *sum_computed = ck_final(&r->ck);
    return get(r, sum_read, sizeof *sum_read, "checksum", err, errlen);
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

/* Cell states, decided layers and their counts: each must follow from the
 * others exactly as the scheduler's own transitions leave them. */
static int check_cells(const sched_t *s, uint32_t *decided_out, char *err, size_t errlen)
{
    const uint32_t L = s->layers, R = s->ranges;
    const size_t cells = (size_t)L * R;
    /* saved outstanding tasks come back ready, so never ST_OUT */
    for (size_t c = 0; c < cells; c++)
        if (s->state[c] != ST_WAITING && s->state[c] != ST_READY && s->state[c] != ST_DONE) {
            snprintf(
                err, errlen,
                "checkpoint: cell state %u at layer %zu, range %zu is not waiting, ready or done",
                s->state[c], c / R, c % R);
            return -1;
        }
    /* decided layers are a prefix: the first two, then two past the complete ones */
    uint32_t D = 0;
    while (D < L && s->decided[D] == 1)
        D++;
    for (uint32_t l = D; l < L; l++)
        if (s->decided[l] != 0) {
            snprintf(err, errlen,
                     "checkpoint: decided flag %u at layer %u after undecided layer %u",
                     s->decided[l], l, D);
            return -1;
        }
    uint32_t complete = L;
    for (uint32_t l = 0; l < L; l++) {
        uint32_t done = 0;
        for (uint32_t r = 0; r < R; r++)
            done += s->state[(size_t)l * R + r] == ST_DONE;
        if (done != s->range_done[l]) {
            snprintf(err, errlen,
                     "checkpoint: layer %u has range_done %u but %u cells in state done", l,
                     s->range_done[l], done);
            return -1;
        }
        if (done < R && complete == L)
            complete = l;
    }
    if (s->complete != complete) {
        snprintf(err, errlen, "checkpoint: %u layers complete, but the cell states say %u",
                 s->complete, complete);
        return -1;
    }
    uint64_t want_d = D == 0 ? 0 : (uint64_t)complete + 2 < L ? (uint64_t)complete + 2 : L;
    if (D != want_d) {
        snprintf(err, errlen, "checkpoint: %u layers decided, expected %llu with %u complete", D,
                 (unsigned long long)want_d, complete);
        return -1;
    }
    /* rule 1: a cell runs once its layer is decided and its range's previous
     * layer is done; then at once (done) if the layer has none of its pixels */
    for (uint32_t l = 0; l < L; l++)
        for (uint32_t r = 0; r < R; r++) {
            uint8_t st = s->state[(size_t)l * R + r];
            int may = s->decided[l] && (l == 0 || s->state[(size_t)(l - 1) * R + r] == ST_DONE);
            if ((st != ST_WAITING) != may) {
                snprintf(err, errlen,
                         "checkpoint: cell state %s at layer %u, range %u contradicts rule 1 "
                         "(layer %s, previous layer's cell %s)",
                         state_name(st), l, r, s->decided[l] ? "decided" : "undecided",
                         l ? state_name(s->state[(size_t)(l - 1) * R + r]) : "none");
                return -1;
            }
            if (st == ST_READY && range_members(s, l, r) == 0) {
                snprintf(err, errlen,
                         "checkpoint: cell state ready at layer %u, range %u, which has no pixels",
                         l, r);
                return -1;
            }
        }
    *decided_out = D;
    return 0;
}

/* Layer membership, thresholds and the counters that count them. */
static int check_layers(const sched_t *s, uint32_t D, char *err, size_t errlen)
{
    for (uint32_t l = 0; l < s->layers; l++) {
        double t = s->threshold[l];
        if (l < D && applies_skip_rule(s, l) ? isnan(t) : t != 0) {
            snprintf(err, errlen, "checkpoint: threshold %g of layer %u (%s)", t, l,
                     l < D ? "decided" : "not decided yet");
            return -1;
        }
    }
    /* the member bits of decided layers, and none beyond */
    const size_t used = (size_t)D * s->npix, bytes = member_bytes(s), full = used / 8;
    uint64_t pop = 0;
    int stray = 0;
    for (size_t i = 0; i < full; i++)
        pop += popcount8(s->member[i]);
    if (full < bytes) {
        uint8_t low = (uint8_t)((1u << (used & 7)) - 1);
        pop += popcount8(s->member[full] & low);
        stray = (s->member[full] & (uint8_t)~low) != 0;
        for (size_t i = full + 1; i < bytes && !stray; i++)
            stray = s->member[i] != 0;
    }
    if (stray) {
        snprintf(err, errlen, "checkpoint: member bits set in layers not decided yet");
        return -1;
    }
    if (s->pixel_layers != pop || s->skipped != used - pop) {
        snprintf(err, errlen,
                 "checkpoint: pixel_layers %llu and skipped %llu, but the member bitmap holds %llu "
                 "of %zu",
                 (unsigned long long)s->pixel_layers, (unsigned long long)s->skipped,
                 (unsigned long long)pop, used);
        return -1;
    }
    if (s->converged > s->npix ||
        (s->cfg.target_error == 0 && (s->converged || s->stopped_on_target))) {
        snprintf(
            err, errlen, "checkpoint: converged %llu / stopped %d (of %u pixels, target error %g)",
            (unsigned long long)s->converged, s->stopped_on_target, s->npix, s->cfg.target_error);
        return -1;
    }
    return 0;
}

/* What the done cells of layers < D merged: per pixel, the layers it took
 * part in and their samples. */
static void count_merged(const sched_t *s, uint32_t D, uint32_t *layers, uint64_t *samples)
{
    const uint32_t N = s->npix, R = s->ranges;
    for (uint32_t l = 0; l < D; l++) {
        uint32_t take = layer_samples(s, l);
        for (uint32_t r = 0; r < R; r++) {
            if (s->state[(size_t)l * R + r] != ST_DONE)
                continue;
            uint32_t p0 = r * s->range_pixels,
                     p1 = p0 + s->range_pixels < N ? p0 + s->range_pixels : N;
            for (uint32_t p = p0; p < p1; p++)
                if (is_member(s, l, p)) {
                    layers[p]++;
                    samples[p] += take;
                }
        }
    }
}

/* Film pixel p: finite sums, and the layers and samples its cells merged. */
static int check_film_pixel(const sched_t *s, uint32_t p, uint32_t layers, uint64_t samples,
                            char *err, size_t errlen)
{
    const film_pixel_t *fp = &s->film->pixels[p];
    static const char *const names[8] = {"sum[0]",  "sum[1]",  "sum[2]", "comp[0]",
                                         "comp[1]", "comp[2]", "lum_m2", "pvar"};
    const double v[8] = {fp->sum[0],  fp->sum[1],  fp->sum[2], fp->comp[0],
                         fp->comp[1], fp->comp[2], fp->lum_m2, fp->pvar};
    for (int k = 0; k < 8; k++)
        if (!isfinite(v[k])) {
            snprintf(err, errlen, "checkpoint: film pixel %u: %s is not finite (%g)", p, names[k],
                     v[k]);
            return -1;
        }
    if (fp->layers != layers) {
        snprintf(err, errlen, "checkpoint: film pixel %u merged %u layers, the cell states say %u",
                 p, fp->layers, layers);
        return -1;
    }
    if (fp->count > samples || fp->nonfinite != samples - fp->count) {
        snprintf(err, errlen,
                 "checkpoint: film pixel %u holds %llu + %llu nonfinite samples, its layers %llu",
                 p, (unsigned long long)fp->count, (unsigned long long)fp->nonfinite,
                 (unsigned long long)samples);
        return -1;
    }
    return 0;
}

/* Pixel p's adaptive metrics, converged flags and batch statistics. */
/* What Welford over at most `most` layer means in range can make. */
static int welford_plausible(uint32_t n, double mean, double m2, uint32_t most)
{
    return n <= most && mean >= 0 && mean <= 2 * SCHED_MAX_RADIANCE && m2 >= 0 && isfinite(m2) &&
           (n > 0 || mean == 0) && (n > 1 || m2 == 0);
}

static int check_pixel_stats(const sched_t *s, uint32_t p, uint32_t layers, char *err,
                             size_t errlen)
{
    const double m[3] = {s->var_snapshot[p], s->pvar_flight[0][p], s->pvar_flight[1][p]};
    for (int k = 0; k < 3; k++)
        if (isnan(m[k]) || m[k] == -INFINITY || (pools_neighbours(s) && m[k] < 0)) {
            snprintf(err, errlen, "checkpoint: pixel %u: adaptive metric %g", p, m[k]);
            return -1;
        }
    if (keeps_counts(s)) {
        /* a pixel has no more layer means than layers it took; a relative
         * variance is >= 0 (infinite before a second layer; the target's,
         * before SCHED_TARGET_MIN_LAYERS) */
        const uint32_t finite_from = s->cfg.target_error > 0 ? SCHED_TARGET_MIN_LAYERS : 2;
        const double *rvs[3] = {s->rvar_snapshot, s->rvar_flight[0], s->rvar_flight[1]};
        const uint32_t nb[3] = {s->nb_snapshot[p], s->nb_flight[0][p], s->nb_flight[1][p]};
        for (int k = 0; k < 3; k++) {
            const double rv = rvs[k] ? rvs[k][p] : 0.0; /* without a target: none kept */
            if (!(rv >= 0) || nb[k] > layers || (nb[k] >= finite_from && !isfinite(rv))) {
                snprintf(err, errlen,
                         "checkpoint: pixel %u: layer-mean statistics (relative variance %g of "
                         "%u layer means, %u layers taken)",
                         p, rv, nb[k], layers);
                return -1;
            }
        }
    }
    /* what results in range can make: a mean of layer luminances in
     * [0, SCHED_MAX_RADIANCE] (2x: rounding), a sum of squares >= 0,
     * both 0 before the first batch and the sum still 0 after it.
     * Anything else can turn the metrics NaN or infinite on the next
     * merge (Welford's update assumes them) */
    const int batch = s->cfg.adaptive == SCHED_ADAPTIVE_RELERR ||
                      s->cfg.adaptive == SCHED_ADAPTIVE_RELMSE || s->cfg.target_error > 0;
    const uint32_t nb = s->batches[p];
    if (batch ? !welford_plausible(nb, s->bmean[p], s->bm2[p], layers)
              : nb != 0 || s->bmean[p] != 0 || s->bm2[p] != 0) {
        snprintf(err, errlen,
                 "checkpoint: pixel %u: batch statistics (%u batches of %u layers, mean %g, m2 %g)",
                 p, s->batches[p], layers, s->bmean[p], s->bm2[p]);
        return -1;
    }
    if (s->ubatches && !welford_plausible(s->ubatches[p], s->umean[p], s->um2[p], nb)) {
        snprintf(err, errlen,
                 "checkpoint: pixel %u: uniform-layer statistics (%u batches of %u, mean %g, m2 "
                 "%g)",
                 p, s->ubatches[p], nb, s->umean[p], s->um2[p]);
        return -1;
    }
    return 0;
}

/* relmse's cost of pixel p: rays of at most the samples merged, at least
 * one a sample, and rays per sample of 0 (none yet) or at least 1. */
static int check_pixel_cost(const sched_t *s, uint32_t p, uint64_t samples, char *err,
                            size_t errlen)
{
    if (!s->urays)
        return 0;
    const uint64_t rays = s->urays[p], taken = s->usamples[p];
    if (taken > samples || rays < taken || (taken == 0) != (rays == 0)) {
        snprintf(err, errlen,
                 "checkpoint: pixel %u: %llu rays for %llu uniform-layer samples of %llu merged", p,
                 (unsigned long long)rays, (unsigned long long)taken, (unsigned long long)samples);
        return -1;
    }
    const float c[3] = {s->cost_snapshot[p], s->cost_flight[0][p], s->cost_flight[1][p]};
    for (int k = 0; k < 3; k++)
        if (!(c[k] == 0 || (c[k] >= 1 && isfinite(c[k])))) {
            snprintf(err, errlen, "checkpoint: pixel %u: %g rays per sample", p, (double)c[k]);
            return -1;
        }
    return 0;
}

/* The film against the cells that were merged into it, and the per-pixel
 * statistics. */
static int check_pixels(const sched_t *s, uint32_t D, char *err, size_t errlen)
{
    const uint32_t N = s->npix;
    uint32_t *layers = calloc(N, sizeof *layers);
    uint64_t *samples = calloc(N, sizeof *samples);
    int rc = -1;
    if (!layers || !samples) {
        snprintf(err, errlen, "out of memory");
        goto out;
    }
    count_merged(s, D, layers, samples);
    uint64_t total = 0, nonfinite = 0;
    for (uint32_t p = 0; p < N; p++) {
        if (check_film_pixel(s, p, layers[p], samples[p], err, errlen) < 0 ||
            check_pixel_stats(s, p, layers[p], err, errlen) < 0 ||
            check_pixel_cost(s, p, samples[p], err, errlen) < 0)
            goto out;
        total += samples[p];
        nonfinite += s->film->pixels[p].nonfinite;
    }
    if (total != s->samples_done || nonfinite != s->nonfinite) {
        snprintf(
            err, errlen,
            "checkpoint: samples_done %llu and nonfinite %llu, but the film holds %llu and %llu",
            (unsigned long long)s->samples_done, (unsigned long long)s->nonfinite,
            (unsigned long long)total, (unsigned long long)nonfinite);
        goto out;
    }
    rc = 0;
out:
    free(layers);
    free(samples);
    return rc;
}

sched_t *sched_load(const sched_config_t *cfg, sched_read_fn read, void *ctx, char *err,
                    size_t errlen)
{
    sched_t *s = sched_new(cfg, err, errlen);
    if (!s)
        return NULL;
    loader_t r = {read, ctx, {0, 0, {0}, 0}};
    uint64_t sum_read = 0, sum = 0;
    uint32_t decided = 0;
    if (load_stream(s, &r, &sum_read, &sum, err, errlen) || check_cells(s, &decided, err, errlen) ||
        check_layers(s, decided, err, errlen) || check_pixels(s, decided, err, errlen)) {
        sched_destroy(&s);
        return NULL;
    }
    if (sum_read != sum) {
        snprintf(err, errlen, "checkpoint: checksum mismatch (the stream is corrupt)");
        sched_destroy(&s);
        return NULL;
    }
    /* Each pixel's count of decided layers it takes part in: derived, not
     * saved (first_sample_of). */
    for (uint32_t l = 0; l < s->layers && s->decided[l]; l++)
        for (uint32_t p = 0; p < s->npix; p++)
            s->taken[p] += (uint32_t)is_member(s, l, p);
    /* The ready queue in id order: results merge per pixel in layer order
     * and decisions read snapshots only, so the order tasks are issued in
     * changes nothing. */
    size_t cells = (size_t)s->layers * s->ranges;
    s->q_head = s->q_tail = 0;
    for (size_t c = 0; c < cells; c++)
        if (s->state[c] == ST_READY)
            s->queue[s->q_tail++] = (uint64_t)c + 1;
    return s;
}
