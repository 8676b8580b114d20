/* sched.c - task states, the window of layers in flight, dispatch order,
 * and merging results; see sched.h for the rules that make scheduling
 * deterministic, and sched_priv.h for the scheduler's other files (the
 * adaptive rules, target-error stopping, checkpoints).
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
 * pixels x layers. A merge into the later layer in flight keeps the
 * statistics it replaces (sched_keep_prev): decisions read the layer just
 * completed (sched_rules.c). Ready tasks go out the earlier layer's first
 * (a queue per slot): the next decision waits on the last of that layer,
 * so none of it may sit queued behind the later layer's tasks while the
 * workers run out of work. The order changes no result.
 */
#include "sched.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "defaults.h"
#include "rng.h"
#include "sched_priv.h"
#include "vmath.h"

/* Where pixel p's samples of its next layer start: after the samples it has
 * taken, so that a pixel's samples are always the first ones of its sample
 * sequence, whichever layers the adaptive rule skipped (under the sobol
 * sampler the first 2^m samples of a pixel form a net, an arbitrary set of
 * layers does not: rng.h). Every layer but the last takes G, and a task is
 * made only once its range's earlier layers are merged (rule 1): the film's
 * count of samples taken is exactly the samples of the layers before.
 * With replicates, that many samples are spread over the replicates' own
 * sequences (rng_replicate_first_sample). */
static uint64_t taken_of(const sched_t *s, uint32_t p)
{
    const film_pixel_t *fp = &s->film->pixels[p];
    return (uint64_t)fp->count + fp->nonfinite;
}
static uint64_t first_sample_of(const sched_t *s, uint32_t p)
{
    return rng_replicate_first_sample(taken_of(s, p), s->cfg.granularity, sched_replicates(s));
}

/* Samples a pixel takes in layer l: G, or what is left of spp in the last. */
static uint32_t layer_samples(const sched_t *s, uint32_t layer)
{
    uint64_t first = (uint64_t)layer * s->cfg.granularity;
    return (uint32_t)(s->cfg.spp - first < s->cfg.granularity ? s->cfg.spp - first
                                                              : s->cfg.granularity);
}

/* The config's own consistency, before anything is derived from it. */
static int check_config(const sched_config_t *cfg, char *err, size_t errlen)
{
    if (cfg->width == 0 || cfg->height == 0 || cfg->spp == 0) {
        snprintf(err, errlen, "image size and spp must be positive");
        return -1;
    }
    if (cfg->replicates > RNG_MAX_REPLICATES) {
        snprintf(err, errlen, "replicates must be 1..%d", RNG_MAX_REPLICATES);
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
static int kept_replicates(const sched_t *s)
{
    return sched_replicates(s) > 1;
}
static int kept_calibrated_target(const sched_t *s)
{
    return kept_target(s) && kept_replicates(s);
}
static uint32_t replicates_but_one(const sched_t *s)
{
    return sched_replicates(s) - 1;
}

#define PIXEL_ARRAY(tag, field, elem, kept)                                                        \
    {                                                                                              \
        tag, offsetof(sched_t, field), sizeof(elem), kept, NULL, 0                                 \
    }
const pixel_array_t sched_pixel_arrays[] = {
    PIXEL_ARRAY("batches", batches, uint32_t, sched_keeps_counts),
    PIXEL_ARRAY("ubat", ubatches, uint32_t, sched_keeps_counts),
    PIXEL_ARRAY("umean", umean, double, sched_keeps_counts),
    PIXEL_ARRAY("um2", um2, double, sched_keeps_counts),
    PIXEL_ARRAY("urays", urays, uint64_t, sched_weighs_cost),
    PIXEL_ARRAY("usamp", usamples, uint32_t, sched_weighs_cost),
    PIXEL_ARRAY("pvarcur", pvar_cur, double, kept_thesis),
    PIXEL_ARRAY("pmetric", prev_metric, double, kept_adaptive),
    PIXEL_ARRAY("prvar", prev_rvar, double, kept_target),
    PIXEL_ARRAY("pnb", prev_nb, uint32_t, sched_keeps_counts),
    PIXEL_ARRAY("pcost", prev_cost, float, sched_weighs_cost),
    {"rep", offsetof(sched_t, rep_lum), sizeof(double), kept_replicates, replicates_but_one, 1},
    /* in streams of version SCHED_SAVE_VERSION_CALIBRATED only */
    {"crv", offsetof(sched_t, crv), sizeof(double), kept_calibrated_target, NULL, 1},
};
const size_t sched_pixel_array_count = sizeof sched_pixel_arrays / sizeof sched_pixel_arrays[0];

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
    for (size_t i = 0; i < sched_pixel_array_count; i++)
        if (sched_pixel_arrays[i].kept(s)) {
            void **slot = sched_array_slot(s, &sched_pixel_arrays[i]);
            *slot = calloc(1, sched_array_bytes(s, &sched_pixel_arrays[i]));
            failed |= !*slot;
        }
    if (s->crv) /* none frozen yet */
        for (size_t p = 0; p < s->npix; p++)
            s->crv[p] = -1;
    failed |= alloc_ring(s) < 0;
    /* ready cells are in the window: at most a layer of ranges a slot */
    s->q_cap = (size_t)s->ranges + 1;
    for (int k = 0; k < 2; k++) {
        s->ready[k].ids = malloc(s->q_cap * sizeof(uint64_t));
        failed |= !s->ready[k].ids;
    }
    s->rq_cap = SCHED_REQUEUE_CAP0;
    s->requeued = malloc(s->rq_cap * sizeof(uint64_t));
    return failed || !s->film || !s->requeued ? -1 : 0;
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
    for (size_t i = 0; i < sched_pixel_array_count; i++)
        free(*sched_array_slot(s, &sched_pixel_arrays[i]));
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
    for (int k = 0; k < 2; k++)
        free(s->ready[k].ids);
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
    for (size_t i = 0; i < sched_pixel_array_count; i++)
        REPORT(sched_pixel_arrays[i].name, sched_array_bytes(s, &sched_pixel_arrays[i]));
    REPORT("window (membership, cells)",
           2 * (member_bytes(s) + s->ranges * (1 + sizeof(tracer_task_t *) + sizeof(uint32_t))) +
               2 * s->q_cap * sizeof(uint64_t) + s->rq_cap * sizeof(uint64_t));
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
uint64_t sched_pixels_at_cap(const sched_t *s)
{
    return s->at_cap;
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

static void complete_range(sched_t *s, uint32_t layer, uint32_t range);

/* Appends a ready id to its layer's ring; when the ring is full, first
 * drops the ids sched_take handed out already (at most a layer's ranges
 * are ready in one slot at once). */
void sched_push_ready(sched_t *s, uint64_t id)
{
    struct ready_ring *q = &s->ready[((id - 1) / s->ranges) & 1];
    if ((q->tail + 1) % s->q_cap == q->head) {
        size_t n = 0;
        for (size_t i = q->head; i != q->tail; i = (i + 1) % s->q_cap) {
            uint64_t x = q->ids[i];
            if (cell_state(s, (uint32_t)((x - 1) / s->ranges), (uint32_t)((x - 1) % s->ranges)) ==
                ST_READY)
                q->ids[(q->head + n++) % s->q_cap] = x;
        }
        q->tail = (q->head + n) % s->q_cap;
    }
    q->ids[q->tail] = id;
    q->tail = (q->tail + 1) % s->q_cap;
}

/* The next queued id, the earliest layer's first: 1 and *slot its ring,
 * or 0 when both are empty. */
static int pop_ready(sched_t *s, uint64_t *id, int *slot)
{
    for (uint32_t k = 0; k < 2; k++) {
        struct ready_ring *q = &s->ready[(s->complete + k) & 1];
        if (q->head == q->tail)
            continue;
        *id = q->ids[q->head];
        q->head = (q->head + 1) % s->q_cap;
        *slot = (int)((s->complete + k) & 1);
        return 1;
    }
    return 0;
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
    sched_push_ready(s, task_id(s, layer, range));
}

/* (sched_priv.h) */
void sched_decided(sched_t *s, uint32_t layer)
{
    s->decided_n = layer + 1;
    for (uint32_t r = 0; r < s->ranges; r++)
        if (layer == 0 || cell_state(s, layer - 1, r) == ST_DONE)
            make_ready(s, layer, r);
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
            sched_decide_layer(s, layer + 2);
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
        sched_decide_layer(s, 0);
        sched_decide_layer(s, 1);
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
        int slot = 0;
        const int from_requeued = s->rq_len > 0;
        if (from_requeued) {
            id = s->requeued[--s->rq_len];
        } else if (!pop_ready(s, &id, &slot)) {
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
                s->ready[slot].head = (s->ready[slot].head + s->q_cap - 1) % s->q_cap;
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
    const int batches = sched_keeps_counts(s);
    /* a uniform layer: every pixel takes it, whatever any pixel's values */
    const int adaptive_layer = sched_applies_skip_rule(s, layer);
    for (uint32_t i = 0; i < count; i++) {
        uint32_t p = results[i].pixel;
        if (ahead)
            sched_keep_prev(s, p);
        film_merge(s->film, &results[i]);
        s->samples_done += rec[i].sample_count;
        s->at_cap += taken_of(s, p) == s->cfg.spp;
        const uint32_t rep = rng_replicate_of(rec[i].first_sample);
        if (rep > 0) /* replicate 0's sum is the film's less the others' */
            s->rep_lum[(size_t)p * (sched_replicates(s) - 1) + rep - 1] +=
                vmath_luminance(results[i].sum[0], results[i].sum[1], results[i].sum[2]);
        s->nonfinite += results[i].nonfinite;
        if (s->pvar_cur)
            s->pvar_cur[p] = results[i].pvar;
        if (!batches)
            continue;
        /* with a target error, a pixel's first sched_target_layers()
         * layers whatever they are (meets_target); else its uniform layers */
        const int judged =
            s->cfg.target_error > 0 ? s->ubatches[p] < sched_target_layers(s) : !adaptive_layer;
        /* the layer's mean is one batch; Welford over batches */
        if (results[i].samples > 0) {
            s->batches[p]++;
            if (judged) {
                double bm =
                    vmath_luminance(results[i].sum[0], results[i].sum[1], results[i].sum[2]) /
                    results[i].samples;
                sched_welford_add(&s->ubatches[p], &s->umean[p], &s->um2[p], bm);
                /* a pixel's layers merge in order (rule 1): the film and
                 * the replicate sums hold exactly its first layers now */
                if (s->crv && s->ubatches[p] == SCHED_TARGET_CALIBRATED_LAYERS)
                    sched_target_freeze(s, p);
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
