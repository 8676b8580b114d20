/* preview.c - see preview.h. */
#include "preview.h"

#include <stdint.h>
#include <stdlib.h>
#include <string.h>

void preview_fit(int sw, int sh, int max_w, int max_h, int *w, int *h)
{
    if (sw <= max_w && sh <= max_h) {
        *w = sw; /* never scaled up */
        *h = sh;
    } else if ((int64_t)max_w * sh <= (int64_t)max_h * sw) {
        /* the width limits: the height follows, rounded, within max_h since
         * sh * max_w / sw <= max_h */
        *w = max_w;
        *h = (int)(((int64_t)sh * max_w + sw / 2) / sw);
    } else {
        *h = max_h;
        *w = (int)(((int64_t)sw * max_h + sh / 2) / sh);
    }
    if (*w < 1)
        *w = 1;
    if (*h < 1)
        *h = 1;
}

/* Adds pixels x0..x1-1 of source row y to acc: R, G, B (mean radiance) and
 * samples, each summed over the pixels. */
typedef void (*box_row_fn)(const void *src, int y, int x0, int x1, double acc[4]);

/* The first source index of output box o of n over s source pixels: the
 * smallest x with floor(x * n / s) >= o. */
static int box_start(int o, int s, int n)
{
    return (int)(((int64_t)o * s + n - 1) / n);
}

/* The box filter over a sw x sh source, one output row at a time (the
 * source rows arrive in order, so only one output row is open). */
static int box_filter(const void *src, box_row_fn add, int sw, int sh, int w, int h, float *rgb,
                      float *spp)
{
    if (w < 1 || h < 1 || w > sw || h > sh)
        return -1;
    double *acc = malloc((size_t)w * 4 * sizeof *acc);
    int *col = malloc(((size_t)w + 1) * sizeof *col);
    if (!acc || !col) {
        free(acc);
        free(col);
        return -1;
    }
    for (int ox = 0; ox <= w; ox++)
        col[ox] = box_start(ox, sw, w);
    for (int oy = 0, y = 0; oy < h; oy++) {
        int y0 = y, y1 = box_start(oy + 1, sh, h);
        memset(acc, 0, (size_t)w * 4 * sizeof *acc);
        for (; y < y1; y++)
            for (int ox = 0; ox < w; ox++)
                add(src, y, col[ox], col[ox + 1], acc + 4 * ox);
        for (int ox = 0; ox < w; ox++) {
            double area = (double)(y1 - y0) * (col[ox + 1] - col[ox]);
            size_t o = (size_t)oy * w + ox;
            for (int c = 0; c < 3; c++)
                rgb[3 * o + c] = (float)(acc[4 * ox + c] / area);
            spp[o] = (float)(acc[4 * ox + 3] / area);
        }
    }
    free(acc);
    free(col);
    return 0;
}

static void film_row(const void *src, int y, int x0, int x1, double acc[4])
{
    const film_t *f = src;
    const film_pixel_t *row = f->pixels + (size_t)y * f->width;
    for (int x = x0; x < x1; x++) {
        const film_pixel_t *p = &row[x];
        if (!p->count)
            continue; /* black, as film_mean says */
        /* film_mean's arithmetic, inline: this loop is the whole cost of a
         * preview (about 9 ms at 1920x1080, bound by reading the film's
         * 88-byte pixels, not by the divisions) */
        double n = (double)p->count;
        for (int c = 0; c < 3; c++)
            acc[c] += (p->sum[c] + p->comp[c]) / n;
        acc[3] += n;
    }
}

int preview_from_film(const film_t *f, int w, int h, float *rgb, float *spp)
{
    return box_filter(f, film_row, f->width, f->height, w, h, rgb, spp);
}

/* An image's planes, for image_row. */
typedef struct image_planes {
    int width;
    const float *c[4]; /* R, G, B, samples (NULL: none) */
} image_planes_t;

static void image_row(const void *src, int y, int x0, int x1, double acc[4])
{
    const image_planes_t *p = src;
    size_t at = (size_t)y * p->width;
    for (int x = x0; x < x1; x++)
        for (int c = 0; c < 4; c++)
            acc[c] += p->c[c] ? p->c[c][at + x] : 0.0;
}

int preview_from_image(const image_t *img, int w, int h, float *rgb, float *spp)
{
    image_planes_t p = {img->width,
                        {image_channel(img, "R"), image_channel(img, "G"), image_channel(img, "B"),
                         image_channel(img, "samples")}};
    if (!p.c[0] || !p.c[1] || !p.c[2])
        return -1;
    return box_filter(&p, image_row, img->width, img->height, w, h, rgb, spp);
}

float preview_max(const float *v, size_t n)
{
    float top = 0;
    for (size_t i = 0; i < n; i++)
        if (v[i] > top)
            top = v[i];
    return top;
}
