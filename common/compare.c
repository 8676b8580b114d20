/* compare.c - see compare.h. */
#include "compare.h"

#include <math.h>
#include <stdio.h>

void compare_planes(const float *const a[3], const float *const r[3], size_t pixels,
                    const unsigned char *mask, double threshold, compare_result_t *out)
{
    double se = 0, rel = 0, are = 0, mx = 0;
    size_t n = 0, above = 0;
    for (size_t i = 0; i < pixels; i++) {
        if (mask && !mask[i])
            continue;
        double worst = 0;
        for (int c = 0; c < 3; c++) {
            double d = (double)a[c][i] - (double)r[c][i], rr = r[c][i];
            se += d * d;
            rel += d * d / (rr * rr + COMPARE_EPS);
            double re = fabs(d) / (fabs(rr) + COMPARE_EPS);
            are += re;
            worst = re > worst ? re : worst;
            mx = fabs(d) > mx ? fabs(d) : mx;
        }
        above += worst > threshold;
        n++;
    }
    double k = n ? 1.0 / (3.0 * (double)n) : 0.0;
    out->relmse = rel * k;
    out->rmse = sqrt(se * k);
    out->mare = are * k;
    out->max_abs = mx;
    out->above = n ? (double)above / (double)n : 0.0;
    out->threshold = threshold;
    out->pixels = n;
}

static int rgb(const image_t *img, const float *p[3])
{
    p[0] = image_channel(img, "R");
    p[1] = image_channel(img, "G");
    p[2] = image_channel(img, "B");
    return p[0] && p[1] && p[2] ? 0 : -1;
}

int compare_images(const image_t *a, const image_t *ref, double threshold, compare_result_t *out,
                   char *err, size_t errlen)
{
    const float *pa[3], *pr[3];
    if (rgb(a, pa) < 0 || rgb(ref, pr) < 0) {
        snprintf(err, errlen, "%s has no R, G and B channels",
                 rgb(a, pa) < 0 ? "the image" : "the reference");
        return -1;
    }
    if (a->width != ref->width || a->height != ref->height) {
        snprintf(err, errlen, "sizes differ: %dx%d against a %dx%d reference", a->width, a->height,
                 ref->width, ref->height);
        return -1;
    }
    compare_planes(pa, pr, (size_t)a->width * a->height, NULL, threshold, out);
    return 0;
}

image_t *compare_error_image(const image_t *a, const image_t *ref)
{
    const float *pa[3], *pr[3];
    if (rgb(a, pa) < 0 || rgb(ref, pr) < 0 || a->width != ref->width || a->height != ref->height)
        return NULL;
    image_t *e = image_new(a->width, a->height);
    float *out = e ? image_add_channel(e, "error") : NULL;
    if (!out) {
        image_destroy(&e);
        return NULL;
    }
    for (size_t i = 0; i < (size_t)a->width * a->height; i++) {
        double worst = 0;
        for (int c = 0; c < 3; c++) {
            double re = fabs((double)pa[c][i] - pr[c][i]) / (fabs((double)pr[c][i]) + COMPARE_EPS);
            worst = re > worst ? re : worst;
        }
        out[i] = (float)worst;
    }
    return e;
}
