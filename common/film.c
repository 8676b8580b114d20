/* film.c - see film.h. */
#include "film.h"

#include <math.h>
#include <stdlib.h>

#include "vmath.h"

film_t *film_new(int width, int height)
{
    if (width <= 0 || height <= 0)
        return NULL;
    film_t *f = calloc(1, sizeof *f);
    if (!f)
        return NULL;
    f->width = width;
    f->height = height;
    f->pixels = calloc((size_t)width * (size_t)height, sizeof(film_pixel_t));
    f->rows = calloc(1, sizeof *f->rows);
    if (!f->pixels || !f->rows) {
        free(f->pixels);
        free(f->rows);
        free(f);
        return NULL;
    }
    return f;
}

void film_destroy(film_t **fp)
{
    if (!fp || !*fp)
        return;
    free((*fp)->pixels);
    if ((*fp)->rows)
        free((*fp)->rows->row_stamp);
    free((*fp)->rows);
    free(*fp);
    *fp = NULL;
}

/* Neumaier's compensated addition: the error of each add is kept in *c. */
static inline void neumaier_add(double *sum, double *c, double x)
{
    double t = *sum + x;
    if (fabs(*sum) >= fabs(x))
        *c += (*sum - t) + x;
    else
        *c += (x - t) + *sum;
    *sum = t;
}

/* The pixel's M2 after merging r (Chan et al.: M2 = M2a + M2b + delta^2
 * na nb / n, means from the sums). */
static double merged_m2(const film_pixel_t *p, const tracer_result_t *r)
{
    if (p->count == 0)
        return r->lum_m2;
    double na = (double)p->count, nb = (double)r->samples;
    double sa[3] = {p->sum[0] + p->comp[0], p->sum[1] + p->comp[1], p->sum[2] + p->comp[2]};
    double mean_a = vmath_luminance(sa[0], sa[1], sa[2]) / na;
    double mean_b = vmath_luminance(r->sum[0], r->sum[1], r->sum[2]) / nb;
    double delta = mean_b - mean_a;
    return p->lum_m2 + r->lum_m2 + delta * delta * na * nb / (na + nb);
}

int film_merge_check(const film_t *f, const tracer_result_t *r)
{
    if ((uint64_t)r->pixel >= (uint64_t)f->width * (uint64_t)f->height)
        return -1;
    const film_pixel_t *p = &f->pixels[r->pixel];
    if (r->samples == 0)
        return 0;
    for (int c = 0; c < 3; c++)
        if (!isfinite(p->sum[c] + p->comp[c] + r->sum[c]) || !isfinite(p->sum[c] + r->sum[c]))
            return -1;
    return isfinite(merged_m2(p, r)) ? 0 : -1;
}

int film_merge(film_t *f, const tracer_result_t *r)
{
    if ((uint64_t)r->pixel >= (uint64_t)f->width * (uint64_t)f->height)
        return -1;
    film_pixel_t *p = &f->pixels[r->pixel];
    if (f->rows->row_stamp)
        f->rows->row_stamp[r->pixel / (uint32_t)f->width] = ++f->rows->stamp;
    p->nonfinite += r->nonfinite;
    if (r->samples == 0)
        return 0;
    p->lum_m2 = merged_m2(p, r);
    for (int c = 0; c < 3; c++)
        neumaier_add(&p->sum[c], &p->comp[c], r->sum[c]);
    p->count += r->samples;
    return 0;
}

int film_track_rows(const film_t *f)
{
    if (!f->rows->row_stamp)
        f->rows->row_stamp = calloc((size_t)f->height, sizeof *f->rows->row_stamp);
    return f->rows->row_stamp ? 0 : -1;
}

void film_prior(const film_t *f, tracer_task_t *task)
{
    const film_pixel_t *p = &f->pixels[task->pixel];
    task->prior_count = p->count;
    for (int c = 0; c < 3; c++)
        task->prior_sum[c] = p->sum[c] + p->comp[c];
}

void film_mean(const film_t *f, uint32_t pixel, double rgb[3])
{
    const film_pixel_t *p = &f->pixels[pixel];
    for (int c = 0; c < 3; c++)
        rgb[c] = p->count ? (p->sum[c] + p->comp[c]) / (double)p->count : 0.0;
}

double film_variance_of_mean(const film_t *f, uint32_t pixel)
{
    const film_pixel_t *p = &f->pixels[pixel];
    if (p->count < 2)
        return 0.0;
    double n = (double)p->count;
    return p->lum_m2 / (n * (n - 1.0));
}

uint64_t film_total_samples(const film_t *f)
{
    uint64_t n = 0;
    for (size_t i = 0; i < (size_t)f->width * (size_t)f->height; i++)
        n += (uint64_t)f->pixels[i].count + f->pixels[i].nonfinite;
    return n;
}

uint64_t film_total_nonfinite(const film_t *f)
{
    uint64_t n = 0;
    for (size_t i = 0; i < (size_t)f->width * (size_t)f->height; i++)
        n += f->pixels[i].nonfinite;
    return n;
}

image_t *film_to_image(const film_t *f)
{
    image_t *img = image_new(f->width, f->height);
    if (!img)
        return NULL;
    float *r = image_add_channel(img, "R"), *g = image_add_channel(img, "G");
    float *b = image_add_channel(img, "B"), *n = image_add_channel(img, "samples");
    float *v = image_add_channel(img, "variance");
    if (!r || !g || !b || !n || !v) {
        image_destroy(&img);
        return NULL;
    }
    size_t count = (size_t)f->width * (size_t)f->height;
    for (size_t i = 0; i < count; i++) {
        double rgb[3];
        film_mean(f, (uint32_t)i, rgb);
        r[i] = (float)rgb[0];
        g[i] = (float)rgb[1];
        b[i] = (float)rgb[2];
        n[i] = (float)f->pixels[i].count;
        v[i] = (float)film_variance_of_mean(f, (uint32_t)i);
    }
    return img;
}
