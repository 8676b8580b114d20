/* sched_rules.c - the adaptive rules: which pixels take the next layer.
 *
 * One table holds the modes (sched_adaptive_t), each with the one function
 * that gives a pixel's statistic as of its last merge; relerr and relmse
 * then judge a pixel by its neighbours' statistic and its own layer count
 * (their second function). The thesis's rule (eq. 4.3: skip a layer when
 * the metric is below its mean over pixels), the dilation, and target-error
 * stopping (sched_target.c) then choose the layer's pixels.
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
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "rng.h"
#include "sched_priv.h"

/* ---- the rules ------------------------------------------------------------ */

/* none: every pixel takes every layer (no statistic). */
static void own_none(const sched_t *s, uint32_t p0, uint32_t n, double *out)
{
    (void)s;
    (void)p0;
    memset(out, 0, n * sizeof(double));
}

/* thesis: eq. 4.1 of the pixel's last merged layer. */
static void own_thesis(const sched_t *s, uint32_t p0, uint32_t n, double *out)
{
    memcpy(out, s->pvar_cur + p0, n * sizeof(double));
}

/* variance: the sample variance of the pixel's mean. */
static void own_variance(const sched_t *s, uint32_t p0, uint32_t n, double *out)
{
    for (uint32_t i = 0; i < n; i++)
        out[i] =
            s->film->pixels[p0 + i].count >= 2 ? film_variance_of_mean(s->film, p0 + i) : INFINITY;
}

/* relerr and relmse: the relative variance of one layer's mean, over the
 * uniform layers; metric_row turns its neighbours' into the metric. */
static void own_layer_rvar(const sched_t *s, uint32_t p0, uint32_t n, double *out)
{
    for (uint32_t i = 0; i < n; i++) {
        const uint32_t p = p0 + i, nu = s->ubatches[p];
        double scale = fabs(s->umean[p]) + SCHED_RELERR_EPS;
        out[i] = nu >= 2 ? s->um2[p] / (nu - 1) / (scale * scale) : INFINITY;
    }
}

/* relerr: a Student-t half-width of the mean of nb layer means. */
static double pooled_relerr(sched_t *s, double rv, uint32_t nb, double cost)
{
    (void)cost;
    return sched_t_factor(s, &s->t_table, SCHED_RELERR_CONFIDENCE, nb - 1) * sqrt(rv / nb);
}

/* relmse: the relMSE one more layer takes off, per ray it costs. */
static double pooled_relmse(sched_t *s, double rv, uint32_t nb, double cost)
{
    (void)s;
    return rv / ((double)nb * nb) / cost;
}

typedef struct sched_rule {
    const char *name;
    /* the statistic of pixels p0 .. p0 + n - 1 as of their last merge */
    void (*own)(const sched_t *s, uint32_t p0, uint32_t n, double *out);
    /* NULL: a pixel's own statistic is its metric. Else the metric from rv,
     * the mean of its neighbours' statistics, nb, its own layers (>= 2),
     * and cost, its neighbours' rays per sample (1 unless weighs_cost) */
    double (*pooled)(sched_t *s, double rv, uint32_t nb, double cost);
    int weighs_cost; /* relmse weighs a layer's gain against its rays (sched.h) */
} sched_rule_t;

static const sched_rule_t rules[] = {
    [SCHED_ADAPTIVE_NONE] = {"none", own_none, NULL, 0},
    [SCHED_ADAPTIVE_THESIS] = {"thesis", own_thesis, NULL, 0},
    [SCHED_ADAPTIVE_VARIANCE] = {"variance", own_variance, NULL, 0},
    [SCHED_ADAPTIVE_RELERR] = {"relerr", own_layer_rvar, pooled_relerr, 0},
    [SCHED_ADAPTIVE_RELMSE] = {"relmse", own_layer_rvar, pooled_relmse, 1},
};
#define RULES (int)(sizeof rules / sizeof rules[0])

static const sched_rule_t *rule_of(const sched_t *s)
{
    return &rules[s->cfg.adaptive];
}

int sched_adaptive_from_name(const char *name)
{
    for (int i = 0; i < RULES; i++)
        if (strcmp(name, rules[i].name) == 0)
            return i;
    return -1;
}

const char *sched_adaptive_name(sched_adaptive_t a)
{
    return (unsigned)a < RULES ? rules[a].name : "?";
}

/* relerr and relmse decide from the pixel's neighbours (metric_row). */
int sched_pools_neighbours(const sched_t *s)
{
    return rule_of(s)->pooled != NULL;
}

/* Layer-mean counts per pixel, and the statistics of the layer means its
 * neighbours judge it by (its uniform layers; with a target error, its
 * first SCHED_TARGET_MIN_LAYERS): kept for the target error and for the
 * modes that pool their neighbours. */
int sched_keeps_counts(const sched_t *s)
{
    return s->cfg.target_error > 0 || sched_pools_neighbours(s);
}

int sched_weighs_cost(const sched_t *s)
{
    return rule_of(s)->weighs_cost;
}

/* ---- the statistics a decision reads ------------------------------------- */

/* Whether layer's pixels are chosen by the skip rule (rule 3). With a
 * target error no decision applies it (sched_decide_layer): these layers
 * then only keep a threshold, zero. */
int sched_applies_skip_rule(const sched_t *s, uint32_t layer)
{
    /* relerr and relmse learn only from uniform layers (pool_neighbours):
     * without a flag sequence, every SCHED_UNIFORM_EVERY-th layer stays
     * uniform so their statistics keep growing (not with a target error,
     * whose statistics stop growing after SCHED_TARGET_MIN_LAYERS) */
    int refresh =
        sched_pools_neighbours(s) && s->cfg.target_error <= 0 && layer % SCHED_UNIFORM_EVERY == 0;
    int flag = s->flags ? s->flags[layer] == '1' : layer >= s->uniform && !refresh;
    return flag && layer >= 2 && s->cfg.adaptive != SCHED_ADAPTIVE_NONE;
}

static float cur_cost(const sched_t *s, uint32_t p)
{
    return s->usamples[p] ? (float)((double)s->urays[p] / (double)s->usamples[p]) : 0.0f;
}

/* Before pixel p merges the later layer in flight: keep what it replaces. */
void sched_keep_prev(sched_t *s, uint32_t p)
{
    if (s->prev_metric)
        rule_of(s)->own(s, p, 1, &s->prev_metric[p]);
    if (s->prev_rvar)
        s->prev_rvar[p] = sched_target_rvar(s, p);
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
snap_row_t *sched_snap_row(sched_t *s, int y)
{
    snap_row_t *r = &s->ring[y % SCHED_RING];
    if (r->y == y)
        return r;
    r->y = y;
    uint32_t w = s->cfg.width;
    const uint32_t ahead = s->complete, rp = s->range_pixels;
    const int any_ahead = ahead < s->decided_n;
    const int target = s->cfg.target_error > 0, counts = sched_keeps_counts(s),
              cost = sched_weighs_cost(s);
    if (s->complete == 0) { /* layers 0 and 1: nothing merged yet */
        memset(r->metric, 0, w * sizeof(double));
        memset(r->rvar, 0, w * sizeof(double));
        memset(r->nb, 0, w * sizeof(uint32_t));
        memset(r->cost, 0, w * sizeof(float));
        w = 0;
    }
    /* every pixel's current values, the rule's a row at once (a call a
     * pixel costs more than the arithmetic), then the pixels that merged
     * ahead */
    const uint32_t p0 = (uint32_t)y * s->cfg.width;
    if (w)
        rule_of(s)->own(s, p0, w, r->metric);
    for (uint32_t x = 0; x < w; x++) {
        r->rvar[x] = target ? sched_target_rvar(s, p0 + x) : 0;
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
    if (target && !s->crv) /* the calibrated rule reads no maxima */
        sched_target_row_max(s, r);
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

/* The sums the skip rule's spread test reads (SCHED_ALIKE_SPREAD): over the
 * pixels whose own and neighbours' statistics are both known, each
 * pixel's own per-ray statistic o and its neighbours' mean q. */
typedef struct spread_sums {
    double n, o, q, oq;
} spread_sums_t;

/* Whether the pixels' statistics differ by more than their noise: the
 * covariance of o and q over pixels (a pixel's noise and its neighbours'
 * are independent, so only what they share in truth remains), over the
 * squared mean. */
static int pixels_differ(const spread_sums_t *t)
{
    if (t->n < 2)
        return 1; /* nothing to tell them apart by: the rule as it is */
    const double mo = t->o / t->n, mq = t->q / t->n;
    return t->oq / t->n - mo * mq > SCHED_ALIKE_SPREAD * mo * mq;
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
 * variance: the pixel's own. With spread, each pixel's own statistic and
 * its neighbours' mean, both per ray, go into its sums (pixels_differ).
 * Not the replicates' calibrated error (sched_error.c), though the layer
 * means' spread overstates a pixel's error by a factor that varies from
 * pixel to pixel: frozen after the uniform layers, as it must be here,
 * it has R - 1 degrees of freedom a pixel and learns nothing more, and
 * every way of reading it measured lost some of relmse's gain on the
 * Cornell box and glass (docs/ADAPTIVE.md). */
static void metric_row(sched_t *s, int y, double *out, spread_sums_t *spread)
{
    const sched_rule_t *rule = rule_of(s);
    const int w = (int)s->cfg.width, h = (int)s->cfg.height;
    const snap_row_t *self = sched_snap_row(s, y);
    if (!rule->pooled) {
        memcpy(out, self->metric, (size_t)w * sizeof(double));
        return;
    }
    const snap_row_t *up = y > 0 ? sched_snap_row(s, y - 1) : NULL,
                     *down = y + 1 < h ? sched_snap_row(s, y + 1) : NULL;
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
        if (nb < 2 || !isfinite(rv)) {
            out[x] = INFINITY; /* sampled until it and its neighbours have two */
            continue;
        }
        const double cost = rule->weighs_cost ? neighbour_cost(c, x, w) : 1.0;
        out[x] = rule->pooled(s, rv, nb, cost);
        if (spread && isfinite(self->metric[x])) {
            const double own_cost = rule->weighs_cost && self->cost[x] > 1 ? self->cost[x] : 1.0,
                         o = self->metric[x] / own_cost, q = rv / cost;
            spread->n++;
            spread->o += o;
            spread->q += q;
            spread->oq += o * q;
        }
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
            metric_row(s, y, s->row_metric, NULL);
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

/* Chooses the pixels of layer s->decided_n from the snapshot. */
void sched_decide_layer(sched_t *s, uint32_t layer)
{
    if (layer >= s->layers || layer != s->decided_n)
        return;
    const int w = (int)s->cfg.width, h = (int)s->cfg.height;
    const int target = s->cfg.target_error > 0;
    /* With a target error the target alone decides which pixels take a
     * layer: every pixel short of it takes every layer until it meets it
     * or reaches --spp. The skip rule spreads a fixed number of layers,
     * and on top of the target it left pixels that had neither met the
     * target nor reached --spp when the job's last layer was done: at E =
     * 0.02 relmse gave 941 of the glass scene's 1024 pixels (32 x 32)
     * fewer samples than --adaptive none, a median of 0.56 of them, and
     * 0.89 of its pixels within E where none holds 0.96 (the rule reads
     * the layer means, which rank pixels otherwise than the calibrated
     * error the target reads). Before, it starved pixels short of the
     * target behind those that had met it (relmse: 22 % of the Cornell
     * box's at E = 0.05 with under a quarter of their samples). A layer
     * still records its threshold's place: layers a skip rule would judge
     * keep a (zero) threshold, as a checkpoint's window expects. */
    int skip_rule = sched_applies_skip_rule(s, layer) && !target;
    spread_sums_t spread = {0, 0, 0, 0};
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
                metric_row(s, y, row, &spread);
            for (int x = 0; x < w; x++) {
                const size_t p = (size_t)y * (size_t)w + (size_t)x;
                int c = 0;
                if (target) {
                    c = sched_meets_target(s, x, y);
                    if (conv_of)
                        conv_of[p] = (uint8_t)c;
                    conv += (uint64_t)c;
                }
                if (skip_rule) {
                    double m = row[x];
                    if (isfinite(m)) {
                        threshold += m;
                        n++;
                    }
                }
            }
        }
    threshold = n ? threshold / (double)n : 0.0;
    /* pixels all alike: the layer stays uniform (SCHED_ALIKE_SPREAD) */
    if (skip_rule && sched_pools_neighbours(s) && !pixels_differ(&spread))
        skip_rule = 0;
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
        sched_decided(s, layer);
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
            int in = chosen && !stop_all &&
                     !(target && (conv_of ? conv_of[p] : sched_meets_target(s, x, y)));
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
    sched_decided(s, layer);
}
