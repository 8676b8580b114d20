/* sched_target.c - target-error stopping: a pixel stops once the
 * Student-t half-width of its mean, at the job's confidence, is within the
 * target relative error; the job stops once target_share of its pixels
 * have (sched.h). The decision that applies it is sched_decide_layer's. */
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

/* The target error's: a layer mean's relative variance, over its first layers. */
double sched_target_rvar(const sched_t *s, uint32_t p)
{
    const uint32_t nu = s->ubatches[p];
    double scale = fabs(s->umean[p]) + SCHED_TARGET_EPS;
    return nu >= SCHED_TARGET_MIN_LAYERS ? s->um2[p] / (nu - 1) / (scale * scale) : INFINITY;
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
    return nb >= SCHED_TARGET_MIN_LAYERS &&
           sched_t_factor(s, &s->t_target, s->cfg.confidence, nb - 1) *
                   sqrt(window_max(s, x, y) / nb) <=
               s->cfg.target_error;
}
