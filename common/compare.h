/* compare.h - error of an image against a reference, over channels R, G, B.
 *
 *   relMSE = mean over pixels and channels of (a - r)^2 / (r^2 + 1e-2)
 *   RMSE   = sqrt(mean over pixels and channels of (a - r)^2)
 *   MARE   = mean over pixels and channels of |a - r| / (|r| + 1e-2)
 *   max    = largest |a - r|
 *   above  = share of pixels whose largest channel relative error
 *            |a - r| / (|r| + 1e-2) exceeds a threshold
 * The same definitions serve `vbrender compare`, the master's error tracking
 * against --reference, and the benchmarks.
 */
#ifndef VB_COMPARE_H
#define VB_COMPARE_H

#include <stddef.h>

#include "image.h"

#define COMPARE_EPS 1e-2

typedef struct compare_result {
    double relmse, rmse, mare, max_abs;
    double above; /* share of pixels over the threshold */
    double threshold;
    size_t pixels;
} compare_result_t;

/* Planes a and r (R, G, B each, width*height floats, row-major). Pixels
 * where mask is non-NULL and 0 are left out. */
void compare_planes(const float *const a[3], const float *const r[3], size_t pixels,
                    const unsigned char *mask, double threshold, compare_result_t *out);

/* Two images: -1 with a message when either lacks R, G or B or their sizes
 * differ. */
int compare_images(const image_t *a, const image_t *ref, double threshold, compare_result_t *out,
                   char *err, size_t errlen);

/* Per-pixel relative error (largest channel) as an image with one channel
 * "error", for an error-map PNG. NULL when out of memory. */
image_t *compare_error_image(const image_t *a, const image_t *ref);

#endif
