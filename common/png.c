/* png.c - image_write_png and image_write_heatmap_png (see image.h): 8-bit
 * sRGB and heat-map previews through libpng, written through atomicfile.c.
 * (No png.h of ours: it would hide libpng's, as common/ is on the include
 * path; the declarations are in image.h.)
 */
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <png.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "atomicfile.h"
#include "image.h"
#include "image_priv.h"

/* libpng reports errors through a callback that must not return; we
 * keep its message and jump back to the setjmp in png_encode. */
typedef struct png_msg {
    char text[256];
} png_msg_t;

static void png_error_cb(png_structp png, png_const_charp msg)
{
    png_msg_t *m = png_get_error_ptr(png);
    if (m)
        snprintf(m->text, sizeof m->text, "%s", msg ? msg : "libpng error");
    png_longjmp(png, 1);
}

static void png_warning_cb(png_structp png, png_const_charp msg)
{
    (void)png; /* warnings are not errors; keep them off stderr */
    (void)msg;
}

/* Encodes w x h packed RGB8 pixels to f. Everything allocated here is
 * created before setjmp and not reassigned afterwards, so its value is
 * well defined after a longjmp; `volatile` keeps that true if this
 * function is ever changed. */
static int png_encode(FILE *f, int w, int h, const unsigned char *rgb, png_msg_t *m)
{
    png_structp volatile png =
        png_create_write_struct(PNG_LIBPNG_VER_STRING, m, png_error_cb, png_warning_cb);
    if (!png) {
        snprintf(m->text, sizeof m->text, "out of memory");
        return -1;
    }
    png_infop volatile info = png_create_info_struct(png);
    if (!info) {
        png_structp p = png;
        png_destroy_write_struct(&p, NULL);
        snprintf(m->text, sizeof m->text, "out of memory");
        return -1;
    }
    if (setjmp(png_jmpbuf(png))) {
        png_structp p = png;
        png_infop i = info;
        png_destroy_write_struct(&p, &i);
        return -1;
    }
    png_init_io(png, f);
    png_set_IHDR(png, info, (png_uint_32)w, (png_uint_32)h, 8, PNG_COLOR_TYPE_RGB,
                 PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    png_set_sRGB(png, info, PNG_sRGB_INTENT_PERCEPTUAL);
    png_write_info(png, info);
    for (int y = 0; y < h; y++)
        png_write_row(png, rgb + (size_t)y * (size_t)w * 3);
    png_write_end(png, info);
    png_structp p = png;
    png_infop i = info;
    png_destroy_write_struct(&p, &i);
    return 0;
}

/* Writes packed RGB8 pixels to path through a temporary file. */
static int png_write_file(const char *path, int w, int h, const unsigned char *rgb, char *err,
                          size_t errlen)
{
    char tmp[PATH_MAX];
    int fd = atomicfile_open(path, tmp, sizeof tmp, err, errlen);
    if (fd < 0)
        return -1;
    /* A separate descriptor for stdio, so fclose flushes without closing
     * the one we still need for fsync. */
    int fd2 = dup(fd);
    FILE *f = fd2 >= 0 ? fdopen(fd2, "wb") : NULL;
    if (!f) {
        image_set_err(err, errlen, "%s: cannot open for writing: %s", path, strerror(errno));
        if (fd2 >= 0)
            close(fd2);
        atomicfile_abandon(fd, tmp);
        return -1;
    }
    png_msg_t m;
    memset(&m, 0, sizeof m);
    int rc = png_encode(f, w, h, rgb, &m);
    if (rc != 0) {
        image_set_err(err, errlen, "%s: cannot write PNG: %s", path, m.text);
        fclose(f);
        atomicfile_abandon(fd, tmp);
        return -1;
    }
    if (fclose(f) != 0) {
        image_set_err(err, errlen, "%s: cannot write PNG: %s", path, strerror(errno));
        atomicfile_abandon(fd, tmp);
        return -1;
    }
    return atomicfile_commit(fd, tmp, path, err, errlen);
}

/* The sRGB OETF (IEC 61966-2-1), with the linear toe near black. */
static double srgb_encode(double v)
{
    return v <= 0.0031308 ? 12.92 * v : 1.055 * pow(v, 1.0 / 2.4) - 0.055;
}

static unsigned char to_byte(double v)
{
    if (!(v > 0.0)) /* also maps NaN to 0 */
        return 0;
    if (v >= 1.0)
        return 255;
    return (unsigned char)(v * 255.0 + 0.5);
}

unsigned char image_srgb_byte(double v)
{
    /* Clamp before the curve: pow() of a negative is NaN, and the curve
     * maps [0,1] onto [0,1], so this equals clamping after. */
    if (!(v > 0.0))
        v = 0.0;
    else if (v > 1.0)
        v = 1.0;
    return to_byte(srgb_encode(v));
}

/* Packed RGB8 buffer for the image, or NULL (with err set). */
static unsigned char *rgb_alloc(const image_t *img, const char *path, char *err, size_t errlen)
{
    unsigned char *rgb = malloc((size_t)img->width * (size_t)img->height * 3);
    if (!rgb)
        image_set_err(err, errlen, "%s: out of memory", path);
    return rgb;
}

int image_write_png(const image_t *img, const char *path, float exposure, char *err, size_t errlen)
{
    if (!img || !path || !path[0]) {
        image_set_err(err, errlen, "%s: cannot write PNG: bad arguments", path ? path : "(null)");
        return -1;
    }
    static const char *const names[3] = {"R", "G", "B"};
    const float *planes[3];
    for (int k = 0; k < 3; k++) {
        planes[k] = image_channel(img, names[k]);
        if (!planes[k]) {
            image_set_err(err, errlen, "%s: no channel %s", path, names[k]);
            return -1;
        }
    }
    unsigned char *rgb = rgb_alloc(img, path, err, errlen);
    if (!rgb)
        return -1;
    const size_t n = (size_t)img->width * (size_t)img->height;
    for (size_t p = 0; p < n; p++) {
        for (int k = 0; k < 3; k++) {
            double v = (double)planes[k][p] * (double)exposure;
            rgb[p * 3 + (size_t)k] = image_srgb_byte(v);
        }
    }
    int rc = png_write_file(path, img->width, img->height, rgb, err, errlen);
    free(rgb);
    return rc;
}

/* Black - blue - red - yellow - white at t = 0, 1/4, 1/2, 3/4, 1. */
static void heat_ramp(double t, double out[3])
{
    static const double stops[5][3] = {
        {0, 0, 0}, {0, 0, 1}, {1, 0, 0}, {1, 1, 0}, {1, 1, 1},
    };
    double s = t * 4.0;
    int i = (int)s;
    if (i >= 4) {
        i = 3;
    }
    double f = s - i;
    for (int k = 0; k < 3; k++)
        out[k] = stops[i][k] + (stops[i + 1][k] - stops[i][k]) * f;
}

void image_heat_rgb(double t, unsigned char rgb[3])
{
    if (!(t > 0.0)) /* also NaN */
        t = 0.0;
    else if (t > 1.0)
        t = 1.0;
    double c[3];
    heat_ramp(t, c);
    for (int k = 0; k < 3; k++)
        rgb[k] = to_byte(c[k]);
}

int image_write_heatmap_png(const image_t *img, const char *channel, float lo, float hi,
                            const char *path, char *err, size_t errlen)
{
    if (!img || !channel || !path || !path[0]) {
        image_set_err(err, errlen, "%s: cannot write PNG: bad arguments", path ? path : "(null)");
        return -1;
    }
    const float *plane = image_channel(img, channel);
    if (!plane) {
        image_set_err(err, errlen, "%s: no channel %s", path, channel);
        return -1;
    }
    unsigned char *rgb = rgb_alloc(img, path, err, errlen);
    if (!rgb)
        return -1;
    const double dlo = lo, range = (double)hi - (double)lo;
    const int usable = range > 0.0 && isfinite(range);
    const size_t n = (size_t)img->width * (size_t)img->height;
    for (size_t p = 0; p < n; p++) {
        double t = usable ? ((double)plane[p] - dlo) / range : 0.0;
        image_heat_rgb(t, rgb + p * 3);
    }
    int rc = png_write_file(path, img->width, img->height, rgb, err, errlen);
    free(rgb);
    return rc;
}
