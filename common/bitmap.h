/* bitmap.h - the images a bitmap texture or an environment map reads (PNG,
 * JPEG, OpenEXR, Radiance HDR), decoded by libpng, libjpeg, OpenEXR and
 * stb_image into linear RGB floats.
 *
 * 8-bit images are sRGB-encoded: each texel is turned to linear on load
 * (Mitsuba's bitmap does the same per texel before it interpolates)
 * unless `raw` asks for the stored values as they are. An OpenEXR image is
 * linear already, and so is a Radiance HDR (RGBE) one. Grey images become three equal channels;
 * alpha is dropped. Row 0 is the image's top row. */
#ifndef VB_BITMAP_H
#define VB_BITMAP_H

#include <stddef.h>

/* The most texels a bitmap may have (a 4096x4096 image): 192 MB of
 * floats; a larger file is refused rather than exhaust a worker. */
#define BITMAP_MAX_TEXELS (4096u * 4096u)

typedef struct bitmap {
    int width, height;
    float *rgb; /* 3 floats per texel, rows from the top */
} bitmap_t;

/* Decodes the file `name` held in data[0..size) by its signature (PNG,
 * JPEG, OpenEXR or Radiance HDR) into *out, refusing an image of more than max_texels
 * texels (BITMAP_MAX_TEXELS for a scene; the fuzz target passes less, to
 * stay within its memory limit) before decoding it. Returns 0, or -1 with
 * a message naming the file and what is wrong. */
int bitmap_decode(const char *name, const unsigned char *data, size_t size, int raw,
                  size_t max_texels, bitmap_t *out, char *err, size_t errlen);

/* 1 if data[0..size) starts as a Radiance HDR file does ("#?RADIANCE" or
 * "#?RGBE"). */
int bitmap_is_hdr(const unsigned char *data, size_t size);

/* Frees the texels; accepts a zeroed bitmap. */
void bitmap_free(bitmap_t *b);

/* The sRGB transfer function's inverse (the exact piecewise curve). */
float bitmap_srgb_to_linear(float v);

#endif
