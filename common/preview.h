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
 * Made in one pass over the source with a buffer of one source row: a
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

/* The largest of n values (0 for none): the top of the samples map. */
float preview_max(const float *v, size_t n);

#endif
