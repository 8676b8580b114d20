/* sched_target.c - target-error stopping: a pixel stops once the
 * Student-t half-width of its mean, at the job's confidence, is within the
 * target relative error; the job stops once target_share of its pixels
 * have (sched.h). The decision that applies it is sched_decide_layer's.
 *
 * With replicates (the default) the variance is the calibrated one, as the
 * EXR's variance channel (sched_error.c): the spread of a pixel's
 * replicate means over its first SCHED_TARGET_CALIBRATED_LAYERS layers,
 * a layer's share of it taken as 1/n of the whole (the safe side: a Sobol
 * sequence's error falls faster than 1/n), and its mean over the pixel's
 * 24 neighbours plus a standard error of that mean, t with their degrees
 * of freedom. Without them, a layer mean's spread over the first
 * SCHED_TARGET_MIN_LAYERS layers, the neighbours' largest: under the
 * sobol sampler the layers of one sequence are not independent, and their
 * spread overstates the error of the mean (bench/error/coverage.py
 * measured how much the calibrated rule saves, and what it still holds). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sched_priv.h"
#include "stats.h"

/* The two-sided t factor at `confidence` for k degrees of freedom, cached in
 * *table (grown on demand: k is at most the layers merged so far). 0 means
 * not computed yet: a quantile is never 0 for k >= 1 (and if one ever
 * underflowed it would merely be computed again). */
double sched_t_factor(sched_t *s, double **table, double confidence, uint32_t k)
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

/* The target error's: a layer mean's relative variance, over its first
 * layers (infinite before them); with replicates the calibrated one where
 * they gave one (sched_target_freeze), else the layer means' spread. */
double sched_target_rvar(const sched_t *s, uint32_t p)
{
    const uint32_t nu = s->ubatches[p];
    if (nu < sched_target_layers(s))
        return INFINITY;
    if (s->crv && s->crv[p] >= 0)
        return s->crv[p];
    double scale = fabs(s->umean[p]) + SCHED_TARGET_EPS;
    return s->um2[p] / (nu - 1) / (scale * scale);
}

void sched_target_freeze(sched_t *s, uint32_t p)
{
    const double v = sched_replicate_variance(s, p);
    const film_pixel_t *fp = &s->film->pixels[p];
    /* the variance of the mean of n samples, as n / G layers' worth */
    const double layers = (double)((uint64_t)fp->count + fp->nonfinite) / s->cfg.granularity;
    const double scale = fabs(s->umean[p]) + SCHED_TARGET_EPS;
    s->crv[p] = v >= 0 ? v * layers / (scale * scale) : -1;
}

/* The row's rvar maxima over each pixel's (2 SCHED_TARGET_POOL_RADIUS + 1)
 * pixels of it, the pixel itself in (window_max's first pass). */
void sched_target_row_max(const sched_t *s, snap_row_t *r)
{
    const int w = (int)s->cfg.width, rad = SCHED_TARGET_POOL_RADIUS;
    for (int x = 0; x < w; x++) {
        double m = 0;
        for (int xx = x - rad; xx <= x + rad; xx++)
            if (xx >= 0 && xx < w && r->rvar[xx] > m)
                m = r->rvar[xx];
        r->rvmax[x] = m;
    }
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
        if (yy >= 0 && yy < h && sched_snap_row(s, yy)->rvmax[x] > m)
            m = sched_snap_row(s, yy)->rvmax[x];
    if (w * h == 1 || sched_snap_row(s, y)->rvar[x] < m)
        return m; /* a neighbour holds the maximum */
    m = 0;
    for (int yy = y - r; yy <= y + r; yy++) {
        if (yy < 0 || yy >= h)
            continue;
        const double *v = sched_snap_row(s, yy)->rvar;
        for (int xx = x - r; xx <= x + r; xx++)
            if (xx >= 0 && xx < w && (yy != y || xx != x) && v[xx] > m)
                m = v[xx];
    }
    return m;
}

/* Calls fn(ctx, v) for the relative variance v of each of (x, y)'s
 * neighbours in its window, the pixel left out; returns how many. */
static uint32_t each_neighbour(sched_t *s, int x, int y, void (*fn)(double *ctx, double v),
                               double *ctx)
{
    const int w = (int)s->cfg.width, h = (int)s->cfg.height, r = SCHED_TARGET_POOL_RADIUS;
    uint32_t count = 0;
    for (int yy = y - r; yy <= y + r; yy++) {
        if (yy < 0 || yy >= h)
            continue;
        const double *v = sched_snap_row(s, yy)->rvar;
        for (int xx = x - r; xx <= x + r; xx++)
            if (xx >= 0 && xx < w && (yy != y || xx != x)) {
                fn(ctx, v[xx]);
                count++;
            }
    }
    return count;
}
static void add_value(double *ctx, double v)
{
    ctx[0] += v;
}
static void add_square_from_mean(double *ctx, double v)
{
    ctx[1] += (v - ctx[0]) * (v - ctx[0]);
}

/* With replicates: the mean relative variance of (x, y)'s neighbours in
 * its window, the pixel left out (infinite while any has not taken its
 * first layers), plus SCHED_TARGET_UCB standard errors of that mean (their
 * spread over the root of their count), and the t factor for the R - 1
 * degrees of freedom each gives, at confidence
 * 1 - (1 - C) / SCHED_TARGET_ALPHA_DIVISOR.
 *
 * A mean, not the largest: each neighbour's estimate has R - 1 degrees of
 * freedom, and the largest of 24 would overstate the error several times
 * over; their mean is what the EXR's channel calibrates. But a mean over
 * few samples misses what is rare: light through the glass sphere
 * reaching the floor shows in one neighbour's replicates, not in the
 * others', and the mean of 24 dilutes it. Over the first 8 layers, at C
 * itself, the glass scene ended with 0.76 to 0.88 of its pixels within E
 * for C = 0.9 and 0.95, the Cornell box at 0.92 to 0.95 (its pixels differ
 * from a typical neighbour: darker, or at an edge). Frozen after 16
 * layers, with the standard error added (what one bright neighbour
 * raises) and half the alpha, both hold on every E (bench/error/
 * coverage.py; docs/ADAPTIVE.md has the candidates measured). */
static int meets_calibrated(sched_t *s, int x, int y, uint32_t nb)
{
    double acc[2] = {0, 0};
    uint32_t count = each_neighbour(s, x, y, add_value, acc);
    double v;
    if (count == 0) { /* a 1 x 1 image: the pixel's own */
        v = sched_snap_row(s, y)->rvar[x];
        count = 1;
    } else {
        acc[0] /= count;
        if (count > 1 && isfinite(acc[0]))
            each_neighbour(s, x, y, add_square_from_mean, acc);
        v = acc[0] + SCHED_TARGET_UCB * sqrt(acc[1] / (count - (count > 1)) / count);
    }
    const double t =
        sched_t_factor(s, &s->t_target, 1 - (1 - s->cfg.confidence) / SCHED_TARGET_ALPHA_DIVISOR,
                       count * (sched_replicates(s) - 1));
    return t * sqrt(v / nb) <= s->cfg.target_error;
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
int sched_meets_target(sched_t *s, int x, int y)
{
    uint32_t nb = sched_snap_row(s, y)->nb[x];
    if (nb < sched_target_layers(s))
        return 0;
    if (s->crv)
        return meets_calibrated(s, x, y, nb);
    return sched_t_factor(s, &s->t_target, s->cfg.confidence, nb - 1) *
               sqrt(window_max(s, x, y) / nb) <=
           s->cfg.target_error;
}
