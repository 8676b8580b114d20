/* preview.h - a small box-filtered copy of a film or of an image, for a
 * live view of a render (the master's `preview` control command).
 *
 * The source (sw x sh) is cut into w x h boxes: source column x belongs to
 * output column floor(x * w / sw), and rows likewise, so with w <= sw and
 * h <= sh every box holds at least one pixel and the boxes differ in size
 * by at most one pixel per axis. An output pixel is the plain mean over its
 * box of the per-pixel mean radiance (what fetch's R, G, B hold; a pixel
 * with no sample counts as black) and of the per-pixel sample counts.
 *
 * Made in one pass over the source with a buffer of one output row: a
 * preview of a running 1920x1080 film allocates no full-size image.
 */
#ifndef VB_PREVIEW_H
#define VB_PREVIEW_H

#include "film.h"
#include "image.h"

/* The size of a preview of a sw x sh source that fits within max_w x
 * max_h, keeping the aspect ratio and never larger than the source: w <=
 * min(sw, max_w), h <= min(sh, max_h), each at least 1. Sizes must be >= 1. */
void preview_fit(int sw, int sh, int max_w, int max_h, int *w, int *h);

/* Fills rgb (w*h*3 floats, RGB interleaved, row 0 at the top) and spp (w*h
 * floats: the mean sample count of each box) from the film. w and h must
 * be 1..film size. Returns 0, or -1 on bad sizes or out of memory. */
int preview_from_film(const film_t *f, int w, int h, float *rgb, float *spp);

/* The same from an image with channels R, G, B and, if it has one,
 * "samples" (else spp is all zeros). -1 when R, G or B is missing, on bad
 * sizes or out of memory. */
int preview_from_image(const image_t *img, int w, int h, float *rgb, float *spp);

/* A preview of a film kept from one look to the next: an update redoes
 * only the output rows with a source row merged into since the last one
 * (film_track_rows), so a viewer polling a large running film pays for
 * what changed, not for the whole film each time. */
typedef struct preview preview_t;

/* A width x height preview, made by its first update. NULL on a bad size
 * or out of memory. */
preview_t *preview_new(int width, int height);
void preview_destroy(preview_t **p);

/* Brings p up to date with f (what preview_from_film would give now): all
 * of it the first time or for another film, else the changed rows. Turns
 * on f's row tracking (so the same thread rules apply). The number of
 * output rows redone, or -1 when p is larger than f or out of memory. */
int preview_update(preview_t *p, const film_t *f);
/* Fills p from an image, as preview_from_image does (0, or -1 when R, G or
 * B is missing or p is larger than img). */
int preview_fill_image(preview_t *p, const image_t *img);

/* Its size and planes, as preview_from_film fills them (owned by p). */
void preview_planes(const preview_t *p, int *width, int *height, const float **rgb,
                    const float **spp);

/* The largest of n values (0 for none): the top of the samples map. */
float preview_max(const float *v, size_t n);

#endif
