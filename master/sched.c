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

#include "rng.h"
#include "stats.h"
#include "vmath.h"

enum { ST_WAITING = 0, ST_READY, ST_OUT, ST_DONE };

struct sched {
    sched_config_t cfg;
    char *flags;            /* copy of cfg.flags, or NULL */
    uint32_t npix, layers, ranges, range_pixels, uniform;
    film_t *film;
    uint8_t *member;        /* layers x npix bits: pixel takes part in layer */
    uint8_t *decided;       /* per layer */
    double *threshold;      /* per layer */
    uint8_t *state;         /* layers x ranges */
    uint32_t *range_done;   /* per layer: ranges complete */
    uint32_t complete;      /* layers fully complete (the next incomplete layer) */
    double *var_snapshot;   /* per pixel: the metric as of layer complete-1 */
    double *pvar_flight[2]; /* per pixel: the metric after a layer in flight, by parity */
    uint8_t *conv_snapshot; /* per pixel: met the target error, as of layer complete-1 */
    uint8_t *conv_flight[2];
    uint32_t *batches;      /* per pixel: layers merged (batch means) */
    double *bmean, *bm2;    /* per pixel: Welford over the layers' luminance means */
    double *t_table;        /* t factors by batches - 1, for relerr (0.95) and the target, */
    double *t_target;       /* 0 until first needed (t_factor): ~50 us each, and a submit must
                               not compute one per layer up front (1M layers: a minute) */
    uint64_t converged;
    int stopped_on_target;
    uint8_t *scratch;       /* npix: dilation */
    tracer_task_t **out;    /* layers x ranges: records of outstanding tasks */
    uint32_t *out_count;
    uint64_t *queue;        /* ready task ids, FIFO */
    size_t q_head, q_tail, q_cap;
    uint64_t *requeued;     /* handed back, issued first (LIFO) */
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

static uint32_t range_members(const sched_t *s, uint32_t layer, uint32_t range)
{
    uint32_t p0 = range * s->range_pixels, p1 = p0 + s->range_pixels, n = 0;
    if (p1 > s->npix)
        p1 = s->npix;
    for (uint32_t p = p0; p < p1; p++)
        n += (uint32_t)is_member(s, layer, p);
    return n;
}

sched_t *sched_new(const sched_config_t *cfg, char *err, size_t errlen)
{
    if (cfg->width == 0 || cfg->height == 0 || cfg->spp == 0) {
        snprintf(err, errlen, "image size and spp must be positive");
        return NULL;
    }
    if (cfg->granularity == 0 || cfg->granularity > TRACER_MAX_TASK_SAMPLES) {
        snprintf(err, errlen, "granularity must be 1..%d", TRACER_MAX_TASK_SAMPLES);
        return NULL;
    }
    if (cfg->target_error < 0 || !isfinite(cfg->target_error) || cfg->confidence < 0 || cfg->confidence >= 1 ||
        cfg->target_share < 0 || cfg->target_share > 1) {
        snprintf(err, errlen, "target error must be >= 0, confidence in (0, 1), target share in (0, 1]");
        return NULL;
    }
    if (cfg->adaptive == SCHED_ADAPTIVE_THESIS && cfg->granularity < 2) {
        snprintf(err, errlen, "adaptive sampling needs granularity >= 2 (eq. 4.1 is 0 for G = 1)");
        return NULL;
    }
    if ((uint64_t)cfg->width * cfg->height > (1u << 28)) {
        snprintf(err, errlen, "image too large");
        return NULL;
    }
    sched_t *s = calloc(1, sizeof *s);
    if (!s) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    s->cfg = *cfg;
    s->npix = cfg->width * cfg->height;
    s->layers = (uint32_t)(((uint64_t)cfg->spp + cfg->granularity - 1) / cfg->granularity);
    /* About 32k samples a task: tens of milliseconds on one core; but at
     * least 64 ranges, so a small image still spreads over many workers.
     * The partition does not change a pixel's result: each pixel merges its
     * layers in order whatever range it sits in. */
    uint32_t rp = cfg->range_pixels;
    if (!rp) {
        rp = 32768 / cfg->granularity;
        uint32_t spread = (s->npix + 63) / 64;
        rp = rp < spread ? rp : spread;
    }
    s->range_pixels = rp < 1 ? 1 : rp;
    s->ranges = (s->npix + s->range_pixels - 1) / s->range_pixels;
    s->uniform = cfg->adaptive == SCHED_ADAPTIVE_NONE ? s->layers
                 : cfg->uniform_layers == UINT32_MAX ? s->layers / 2
                                                     : cfg->uniform_layers;
    if (cfg->flags) {
        size_t n = strlen(cfg->flags);
        if (n != s->layers || strspn(cfg->flags, "01") != n) {
            snprintf(err, errlen, "flag sequence must be %u characters of 0 and 1 (one per layer), got %zu",
                     s->layers, n);
            free(s);
            return NULL;
        }
        if (cfg->adaptive == SCHED_ADAPTIVE_NONE) {
            snprintf(err, errlen, "a flag sequence needs adaptive sampling");
            free(s);
            return NULL;
        }
        s->flags = malloc(n + 1);
        if (!s->flags) {
            snprintf(err, errlen, "out of memory");
            free(s);
            return NULL;
        }
        memcpy(s->flags, cfg->flags, n + 1);
        s->cfg.flags = s->flags;
        /* uniform_layers reports the leading run of zeros */
        s->uniform = (uint32_t)strspn(cfg->flags, "0");
    }
    size_t cells = (size_t)s->layers * s->ranges;
    size_t member_bytes = ((size_t)s->layers * s->npix + 7) / 8;
    if (member_bytes > ((size_t)1 << 30) || cells > ((size_t)1 << 26)) {
        snprintf(err, errlen, "too many layers x pixels (%u layers of %u pixels)", s->layers, s->npix);
        free(s);
        return NULL;
    }
    s->film = film_new((int)cfg->width, (int)cfg->height);
    s->member = calloc(member_bytes, 1);
    s->decided = calloc(s->layers, 1);
    s->threshold = calloc(s->layers, sizeof(double));
    s->state = calloc(cells, 1);
    s->range_done = calloc(s->layers, sizeof(uint32_t));
    s->var_snapshot = calloc(s->npix, sizeof(double));
    s->pvar_flight[0] = calloc(s->npix, sizeof(double));
    s->pvar_flight[1] = calloc(s->npix, sizeof(double));
    s->conv_snapshot = calloc(s->npix, 1);
    s->conv_flight[0] = calloc(s->npix, 1);
    s->conv_flight[1] = calloc(s->npix, 1);
    s->batches = calloc(s->npix, sizeof(uint32_t));
    s->bmean = calloc(s->npix, sizeof(double));
    s->bm2 = calloc(s->npix, sizeof(double));
    s->scratch = calloc(s->npix, 1);
    s->t_table = calloc((size_t)s->layers + 1, sizeof(double));
    s->t_target = calloc((size_t)s->layers + 1, sizeof(double));
    if (s->cfg.confidence <= 0)
        s->cfg.confidence = 0.95;
    if (s->cfg.target_share <= 0)
        s->cfg.target_share = 1.0;
    s->out = calloc(cells, sizeof(tracer_task_t *));
    s->out_count = calloc(cells, sizeof(uint32_t));
    s->q_cap = cells + 1;
    s->queue = malloc(s->q_cap * sizeof(uint64_t));
    s->rq_cap = 64;
    s->requeued = malloc(s->rq_cap * sizeof(uint64_t));
    if (!s->film || !s->member || !s->decided || !s->threshold || !s->state || !s->range_done ||
        !s->var_snapshot || !s->pvar_flight[0] || !s->pvar_flight[1] || !s->out || !s->out_count ||
        !s->conv_snapshot || !s->conv_flight[0] || !s->conv_flight[1] || !s->batches || !s->bmean ||
        !s->bm2 || !s->scratch || !s->t_table || !s->t_target ||
        !s->queue || !s->requeued) {
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
    free(s->decided);
    free(s->threshold);
    free(s->state);
    free(s->range_done);
    free(s->var_snapshot);
    free(s->pvar_flight[0]);
    free(s->pvar_flight[1]);
    free(s->conv_snapshot);
    free(s->conv_flight[0]);
    free(s->conv_flight[1]);
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

uint32_t sched_layer_count(const sched_t *s) { return s->layers; }
uint32_t sched_uniform_layers(const sched_t *s) { return s->uniform; }
uint32_t sched_range_count(const sched_t *s) { return s->ranges; }
uint32_t sched_layers_complete(const sched_t *s) { return s->complete; }
uint64_t sched_samples_done(const sched_t *s) { return s->samples_done; }
uint64_t sched_nonfinite(const sched_t *s) { return s->nonfinite; }
uint64_t sched_pixel_layers(const sched_t *s) { return s->pixel_layers; }
uint64_t sched_pixel_layers_skipped(const sched_t *s) { return s->skipped; }
const film_t *sched_film(const sched_t *s) { return s->film; }
int sched_done(const sched_t *s) { return s->complete == s->layers; }
uint64_t sched_converged(const sched_t *s) { return s->converged; }
int sched_stopped_on_target(const sched_t *s) { return s->stopped_on_target; }

static const char *const adaptive_names[] = {"none", "thesis", "variance", "relerr"};

int sched_adaptive_from_name(const char *name)
{
    for (int i = 0; i < 4; i++)
        if (strcmp(name, adaptive_names[i]) == 0)
            return i;
    return -1;
}

const char *sched_adaptive_name(sched_adaptive_t a)
{
    return (unsigned)a < 4 ? adaptive_names[a] : "?";
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

/* Chooses the pixels of a layer from the snapshot (layers < s->complete). */
static void decide_layer(sched_t *s, uint32_t layer)
{
    if (layer >= s->layers || s->decided[layer])
        return;
    int flag = s->flags ? s->flags[layer] == '1' : layer >= s->uniform;
    int skip_rule = flag && layer >= 2 && s->cfg.adaptive != SCHED_ADAPTIVE_NONE;
    double threshold = 0;
    if (skip_rule) {
        /* the mean over pixels (eq. 4.3); pixels without a value yet (inf)
         * are sampled anyway and left out of the mean */
        size_t n = 0;
        for (uint32_t p = 0; p < s->npix; p++)
            if (isfinite(s->var_snapshot[p])) {
                threshold += s->var_snapshot[p];
                n++;
            }
        threshold = n ? threshold / (double)n : 0.0;
    }
    s->threshold[layer] = threshold;
    uint64_t conv = 0;
    if (s->cfg.target_error > 0)
        for (uint32_t p = 0; p < s->npix; p++)
            conv += s->conv_snapshot[p];
    s->converged = conv;
    int stop_all = s->cfg.target_error > 0 && (double)conv >= s->cfg.target_share * s->npix;
    if (stop_all && !s->stopped_on_target)
        s->stopped_on_target = 1;
    uint8_t *sel = s->scratch;
    for (uint32_t p = 0; p < s->npix; p++) {
        double m = s->var_snapshot[p];
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
            double *pv = s->pvar_flight[layer & 1];
            uint8_t *cv = s->conv_flight[layer & 1];
            for (uint32_t p = 0; p < s->npix; p++)
                if (is_member(s, layer, p)) {
                    s->var_snapshot[p] = pv[p];
                    s->conv_snapshot[p] = cv[p];
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

static int start(sched_t *s)
{
    if (s->layers > 0 && !s->decided[0]) {
        decide_layer(s, 0);
        decide_layer(s, 1);
    }
    return 0;
}

int sched_next(sched_t *s, sched_task_t *out)
{
    start(s);
    uint64_t id;
    if (s->rq_len > 0) {
        id = s->requeued[--s->rq_len];
    } else if (s->q_head != s->q_tail) {
        id = s->queue[s->q_head];
        s->q_head = (s->q_head + 1) % s->q_cap;
    } else {
        return s->complete == s->layers ? -1 : 0;
    }
    uint32_t layer = (uint32_t)((id - 1) / s->ranges), range = (uint32_t)((id - 1) % s->ranges);
    size_t cell = (size_t)layer * s->ranges + range;
    if (!s->out[cell]) {
        uint32_t p0 = range * s->range_pixels, p1 = p0 + s->range_pixels;
        if (p1 > s->npix)
            p1 = s->npix;
        uint32_t n = range_members(s, layer, range);
        tracer_task_t *rec = calloc(n, sizeof *rec);
        if (!rec) {
            /* Put it back: the caller retries later. */
            s->requeued[s->rq_len++] = id;
            return 0;
        }
        uint64_t first = (uint64_t)layer * s->cfg.granularity;
        uint32_t take = (uint32_t)(s->cfg.spp - first < s->cfg.granularity ? s->cfg.spp - first
                                                                           : s->cfg.granularity);
        uint32_t k = 0;
        for (uint32_t p = p0; p < p1; p++) {
            if (!is_member(s, layer, p))
                continue;
            rec[k].pixel = p;
            rec[k].sample_count = take;
            rec[k].first_sample = first;
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
    return 1;
}

static int lookup(const sched_t *s, uint64_t id, size_t *cell)
{
    if (id == 0 || id > (uint64_t)s->layers * s->ranges)
        return -1;
    *cell = (size_t)(id - 1);
    return s->state[*cell] == ST_OUT && s->out[*cell] ? 0 : -1;
}

int sched_requeue(sched_t *s, uint64_t task_id)
{
    size_t cell;
    if (lookup(s, task_id, &cell) < 0)
        return -1;
    if (s->rq_len == s->rq_cap) {
        uint64_t *n = realloc(s->requeued, 2 * s->rq_cap * sizeof(uint64_t));
        if (!n)
            return -1;
        s->requeued = n;
        s->rq_cap *= 2;
    }
    s->state[cell] = ST_READY;
    s->requeued[s->rq_len++] = task_id;
    return 0;
}

int sched_complete(sched_t *s, uint64_t task_id, const tracer_result_t *results, uint32_t count,
                   char *err, size_t errlen)
{
    size_t cell;
    if (lookup(s, task_id, &cell) < 0) {
        snprintf(err, errlen, "task %llu is not outstanding", (unsigned long long)task_id);
        return -2;
    }
    const tracer_task_t *rec = s->out[cell];
    if (count != s->out_count[cell]) {
        snprintf(err, errlen, "task %llu: %u results for %u pixels", (unsigned long long)task_id,
                 count, s->out_count[cell]);
        return -1;
    }
    /* Check everything before merging anything: a bad result changes nothing. */
    for (uint32_t i = 0; i < count; i++) {
        if (results[i].pixel != rec[i].pixel ||
            (uint64_t)results[i].samples + results[i].nonfinite != rec[i].sample_count) {
            snprintf(err, errlen, "task %llu: result %u is for pixel %u with %u+%u samples, "
                     "expected pixel %u with %u", (unsigned long long)task_id, i, results[i].pixel,
                     results[i].samples, results[i].nonfinite, rec[i].pixel, rec[i].sample_count);
            return -1;
        }
    }
    uint32_t layer = (uint32_t)((task_id - 1) / s->ranges), range = (uint32_t)((task_id - 1) % s->ranges);
    double *pv = s->pvar_flight[layer & 1];
    uint8_t *cv = s->conv_flight[layer & 1];
    /* batch statistics only where something reads them: this loop runs for
     * every pixel-layer result, millions a second on one master core */
    const int batches = s->cfg.adaptive == SCHED_ADAPTIVE_RELERR || s->cfg.target_error > 0;
    for (uint32_t i = 0; i < count; i++) {
        uint32_t p = results[i].pixel;
        film_merge(s->film, &results[i]);
        s->samples_done += rec[i].sample_count;
        s->nonfinite += results[i].nonfinite;
        if (!batches) {
            pv[p] = s->cfg.adaptive == SCHED_ADAPTIVE_VARIANCE
                        ? (s->film->pixels[p].count >= 2 ? film_variance_of_mean(s->film, p) : INFINITY)
                        : results[i].pvar;
            continue;
        }
        /* the layer's mean is one batch; Welford over batches */
        if (results[i].samples > 0) {
            double bm = vmath_luminance(results[i].sum[0], results[i].sum[1], results[i].sum[2]) / results[i].samples;
            uint32_t nb = ++s->batches[p];
            double d = bm - s->bmean[p];
            s->bmean[p] += d / nb;
            s->bm2[p] += d * (bm - s->bmean[p]);
        }
        uint32_t nb = s->batches[p];
        double se = nb >= 2 ? sqrt(s->bm2[p] / ((double)(nb - 1) * nb)) : INFINITY;
        switch (s->cfg.adaptive) {
        case SCHED_ADAPTIVE_VARIANCE:
            pv[p] = s->film->pixels[p].count >= 2 ? film_variance_of_mean(s->film, p) : INFINITY;
            break;
        case SCHED_ADAPTIVE_RELERR:
            pv[p] = nb >= 2 ? t_factor(s->t_table, 0.95, nb - 1) * se / (fabs(s->bmean[p]) + SCHED_RELERR_EPS) : INFINITY;
            break;
        default:
            pv[p] = results[i].pvar;
            break;
        }
        cv[p] = (uint8_t)(s->cfg.target_error > 0 && nb >= SCHED_TARGET_MIN_LAYERS &&
                          t_factor(s->t_target, s->cfg.confidence, nb - 1) * se <= s->cfg.target_error * (fabs(s->bmean[p]) + SCHED_TARGET_EPS));
    }
    free(s->out[cell]);
    s->out[cell] = NULL;
    s->out_count[cell] = 0;
    complete_range(s, layer, range);
    return 0;
}
