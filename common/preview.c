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

/* The box filter over a sw x sh source into output rows oy0..oy1-1 of a w x
 * h preview, one output row at a time (each is the mean of its own source
 * rows, so any range of them can be redone alone). */
static int box_filter(const void *src, box_row_fn add, int sw, int sh, int w, int h, int oy0,
                      int oy1, float *rgb, float *spp)
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
    for (int oy = oy0; oy < oy1; oy++) {
        int y0 = box_start(oy, sh, h), y1 = box_start(oy + 1, sh, h);
        memset(acc, 0, (size_t)w * 4 * sizeof *acc);
        for (int y = y0; y < y1; y++)
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
         * preview (about 10 ms for all of a 1920x1080 film, bound by
         * reading its 88-byte pixels, not by the divisions) */
        double n = (double)p->count;
        for (int c = 0; c < 3; c++)
            acc[c] += (p->sum[c] + p->comp[c]) / n;
        acc[3] += n;
    }
}

int preview_from_film(const film_t *f, int w, int h, float *rgb, float *spp)
{
    return box_filter(f, film_row, f->width, f->height, w, h, 0, h, rgb, spp);
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
    return box_filter(&p, image_row, img->width, img->height, w, h, 0, h, rgb, spp);
}

float preview_max(const float *v, size_t n)
{
    float top = 0;
    for (size_t i = 0; i < n; i++)
        if (v[i] > top)
            top = v[i];
    return top;
}

/* ---- a preview kept up to date ------------------------------------------------------- */

struct preview {
    int width, height;
    float *rgb, *spp;
    const film_t *film; /* the film it was last brought up to date with */
    uint64_t seen;      /* that film's stamp then */
};

preview_t *preview_new(int width, int height)
{
    if (width < 1 || height < 1)
        return NULL;
    preview_t *p = calloc(1, sizeof *p);
    if (!p)
        return NULL;
    p->width = width;
    p->height = height;
    p->rgb = malloc((size_t)width * height * 3 * sizeof *p->rgb);
    p->spp = malloc((size_t)width * height * sizeof *p->spp);
    if (!p->rgb || !p->spp)
        preview_destroy(&p);
    return p;
}

void preview_destroy(preview_t **pp)
{
    if (!pp || !*pp)
        return;
    free((*pp)->rgb);
    free((*pp)->spp);
    free(*pp);
    *pp = NULL;
}

/* Whether a source row of output row oy was merged into after seen. */
static int rows_changed(const film_t *f, int h, int oy, uint64_t seen)
{
    for (int y = box_start(oy, f->height, h), y1 = box_start(oy + 1, f->height, h); y < y1; y++)
        if (f->rows->row_stamp[y] > seen)
            return 1;
    return 0;
}

int preview_update(preview_t *p, const film_t *f)
{
    int fresh = p->film != f || !f->rows->row_stamp;
    if (film_track_rows(f) < 0)
        return -1;
    int redone = 0;
    for (int oy = 0; oy < p->height;) {
        if (!fresh && !rows_changed(f, p->height, oy, p->seen)) {
            oy++;
            continue;
        }
        int end = oy + 1; /* a run of changed rows at once: one set of buffers */
        while (end < p->height && (fresh || rows_changed(f, p->height, end, p->seen)))
            end++;
        if (box_filter(f, film_row, f->width, f->height, p->width, p->height, oy, end, p->rgb,
                       p->spp) < 0) {
            p->film = NULL; /* all again next time */
            return -1;
        }
        redone += end - oy;
        oy = end;
    }
    p->film = f;
    p->seen = f->rows->stamp;
    return redone;
}

int preview_fill_image(preview_t *p, const image_t *img)
{
    p->film = NULL; /* an update from a film redoes it all */
    return preview_from_image(img, p->width, p->height, p->rgb, p->spp);
}

void preview_planes(const preview_t *p, int *width, int *height, const float **rgb,
                    const float **spp)
{
    *width = p->width;
    *height = p->height;
    *rgb = p->rgb;
    *spp = p->spp;
}
