/* sched_error.c - the per-pixel error a job reports: the variance of each
 * pixel's mean luminance, calibrated by the replicates (sched.h,
 * sched_variance_of_mean), and the image that carries it.
 *
 * Why calibrated: under the sobol sampler a pixel's samples are one
 * stratified sequence, and their own variance over n (the film's) is not
 * the error of their mean: on the Cornell box at 256 spp it is 28x the
 * actual squared error (bench/error/calibrate.py). R independently
 * scrambled replicates give an unbiased estimate, sum w_r^2 (m_r - m)^2 /
 * (1 - sum w_r^2) with w_r a replicate's share of the samples (R / (R - 1)
 * times the spread of equal ones), but from R - 1 degrees of freedom: far
 * too noisy alone for a pixel (with two, 72 % of the pixels lie within 1.96
 * of its sigma, not 95 %). So a pixel's error is the mean of that estimate
 * over the 5 x 5 pixels around it: 24 more degrees of freedom, and a pixel
 * that has not met a rare bright path yet is judged by neighbours that
 * have. On the shipped scenes at 256 and 1,024 spp this predicts the
 * actual squared error within 0.91 to 1.01x (the caustic apart: 1.5-1.6x,
 * a few pixels' rare paths), with 93.7 to 95.4 % of the pixels within 1.96
 * sigma; the film's variance scaled by the replicates' gain over the
 * window (a per-pixel shape) left 43 to 94 % of them (docs/ADAPTIVE.md). */
#include <math.h>
#include <stdlib.h>

#include "sched_priv.h"
#include "vmath.h"

#define ERROR_POOL_RADIUS 2 /* the 5 x 5 window */

double sched_replicate_variance(const sched_t *s, uint32_t p)
{
    const film_pixel_t *fp = &s->film->pixels[p];
    const uint32_t R = sched_replicates(s), G = s->cfg.granularity;
    const uint64_t taken = (uint64_t)fp->count + fp->nonfinite;
    const uint64_t layers = (taken + G - 1) / G;
    if (layers < 2 || fp->count == 0)
        return -1;
    double sum_r[RNG_MAX_REPLICATES], n_r[RNG_MAX_REPLICATES];
    const double total = vmath_luminance(fp->sum[0] + fp->comp[0], fp->sum[1] + fp->comp[1],
                                         fp->sum[2] + fp->comp[2]);
    sum_r[0] = total; /* replicate 0's: the pixel's less the others' */
    for (uint32_t r = 0; r < R; r++) {
        /* replicate r has the pixel's layers k = r, r + R, ...; the last
         * layer may be short of G */
        const uint64_t lr = layers / R + (r < layers % R);
        n_r[r] = (double)(lr * G);
        if (lr > 0 && (layers - 1) % R == r)
            n_r[r] -= (double)(layers * G - taken);
        if (r > 0) {
            sum_r[r] = s->rep_lum[(size_t)p * (R - 1) + r - 1];
            sum_r[0] -= sum_r[r];
        }
    }
    double n = (double)taken, w2 = 0, v = 0;
    const double mean = total / n;
    for (uint32_t r = 0; r < R; r++) {
        if (n_r[r] <= 0)
            continue;
        const double w = n_r[r] / n, d = sum_r[r] / n_r[r] - mean;
        w2 += w * w;
        v += w * w * d * d;
    }
    return w2 < 1 ? v / (1 - w2) : -1;
}

/* out = in summed over the 2 ERROR_POOL_RADIUS + 1 pixels around each one
 * along rows (dx 1) or columns, clipped at the image's edge. */
static void box_pass(const double *in, double *out, uint32_t w, uint32_t h, int along_rows)
{
    const int rad = ERROR_POOL_RADIUS;
    for (uint32_t y = 0; y < h; y++)
        for (uint32_t x = 0; x < w; x++) {
            double a = 0;
            for (int d = -rad; d <= rad; d++) {
                const int64_t xx = (int64_t)x + (along_rows ? d : 0),
                              yy = (int64_t)y + (along_rows ? 0 : d);
                if (xx >= 0 && xx < (int64_t)w && yy >= 0 && yy < (int64_t)h)
                    a += in[(size_t)yy * w + (size_t)xx];
            }
            out[(size_t)y * w + x] = a;
        }
}

int sched_variance_of_mean(const sched_t *s, float *out)
{
    const uint32_t w = s->cfg.width, h = s->cfg.height;
    const size_t n = s->npix;
    for (uint32_t p = 0; p < s->npix; p++)
        out[p] = (float)film_variance_of_mean(s->film, p);
    if (sched_replicates(s) < 2)
        return 0;
    /* per pixel its replicate estimate (0, and not counted, where it has
     * none), then their sums and counts over each window, rows first */
    double *buf = malloc(4 * n * sizeof(double));
    if (!buf)
        return -1;
    double *rep = buf, *has = buf + n, *rep_sum = buf + 2 * n, *has_sum = buf + 3 * n;
    for (uint32_t p = 0; p < s->npix; p++) {
        const double v = sched_replicate_variance(s, p);
        has[p] = v >= 0;
        rep[p] = v >= 0 ? v : 0;
    }
    box_pass(rep, rep_sum, w, h, 1);
    box_pass(has, has_sum, w, h, 1);
    box_pass(rep_sum, rep, w, h, 0);
    box_pass(has_sum, has, w, h, 0);
    /* a window with no replicates yet (every pixel a single layer) keeps
     * the film's variance */
    for (size_t p = 0; p < n; p++)
        if (has[p] > 0)
            out[p] = (float)(rep[p] / has[p]);
    free(buf);
    return 0;
}

image_t *sched_image(const sched_t *s)
{
    image_t *img = film_to_image(s->film);
    if (img && sched_variance_of_mean(s, image_channel(img, "variance")) < 0)
        image_destroy(&img);
    return img;
}
