/* film.h - per-pixel accumulation of tracer results.
 *
 * Each pixel keeps its sample count, RGB sums (double, Neumaier-compensated
 * so a million samples keep the mean exact to 1e-12), luminance M2 merged
 * with Chan's formula and its NaN/Inf count. Samples taken (count plus
 * nonfinite) are also where the pixel's next layer starts in its sample
 * sequence: every layer but the last takes G.
 * Merging is per pixel, so a render is deterministic as long as each pixel
 * receives its tasks' results in layer order, whatever the thread or worker
 * that produced them.
 */
#ifndef VB_FILM_H
#define VB_FILM_H

#include <stddef.h>
#include <stdint.h>

#include "image.h"
#include "tracer.h"

/* 64 bytes: a 4K film is 530 MB, and the master keeps one per running job
 * (counts fit 32 bits: a pixel takes at most spp samples, a uint32). */
typedef struct film_pixel {
    double sum[3];
    double comp[3];     /* Neumaier compensation of sum */
    double lum_m2;      /* sum of squared deviations of luminance from the mean */
    uint32_t count;     /* finite samples */
    uint32_t nonfinite; /* NaN/Inf samples left out */
} film_pixel_t;

/* Which rows merges touched (film_track_rows): off until asked for. */
typedef struct film_rows {
    uint64_t stamp;      /* merges counted since tracking began */
    uint64_t *row_stamp; /* per row: the stamp of its last merge (NULL: off) */
} film_rows_t;

typedef struct film {
    int width, height;
    film_pixel_t *pixels;
    film_rows_t *rows; /* never NULL; not pixels: may change through a const film */
} film_t;

film_t *film_new(int width, int height);
void film_destroy(film_t **f);

/* Merges one result into its pixel (the caller keeps layer order per
 * pixel). Returns -1 if the pixel is outside the film. */
int film_merge(film_t *f, const tracer_result_t *r);

/* Whether merging r keeps the pixel finite: 0, or -1 when a sum or M2
 * would overflow (a result that must be refused, not merged). */
int film_merge_check(const film_t *f, const tracer_result_t *r);

/* From now on each film_merge stamps its pixel's row with a count that
 * only grows (f->rows), so a viewer can redo just the rows merged into
 * since it last looked (preview_update). Changes no pixel, hence const;
 * only for a film merged on one thread (the master's, not render.c's,
 * whose threads merge into one row at once), and called on that thread.
 * Rows start at stamp 0. 0, or -1 when out of memory. */
int film_track_rows(const film_t *f);

/* Fills a task's "so far" fields (prior_count, prior_sum) for a pixel. */
void film_prior(const film_t *f, tracer_task_t *task);

/* Per-pixel mean RGB, and the variance of the mean of luminance
 * (M2 / (n (n-1)); 0 below two samples). */
void film_mean(const film_t *f, uint32_t pixel, double rgb[3]);
double film_variance_of_mean(const film_t *f, uint32_t pixel);

/* Totals over the image. */
uint64_t film_total_samples(const film_t *f);
uint64_t film_total_nonfinite(const film_t *f);

/* An image with channels R, G, B (mean), samples and variance. NULL when
 * out of memory. */
image_t *film_to_image(const film_t *f);

#endif
