/* bitmap.c - bitmap_decode (bitmap.h): PNG through libpng's simplified
 * reader, JPEG through libjpeg, OpenEXR through image_read_exr_buffer,
 * Radiance HDR (RGBE) through stb_image (Debian's libstb). */
#include "bitmap.h"

#include <ctype.h>
#include <math.h>
#include <png.h>
#include <setjmp.h>
#include <stdint.h>
#include <stdio.h> /* before jpeglib.h, which uses FILE */
#include <stdlib.h>
#include <string.h>

#include <jpeglib.h>
#include <stb/stb_image.h>

#include "image.h"

float bitmap_srgb_to_linear(float v)
{
    return v <= 0.04045f ? v / 12.92f : powf((v + 0.055f) / 1.055f, 2.4f);
}

void bitmap_free(bitmap_t *b)
{
    if (!b)
        return;
    free(b->rgb);
    b->rgb = NULL;
    b->width = b->height = 0;
}

static int too_large(const char *name, unsigned w, unsigned h, size_t max, char *err, size_t errlen)
{
    if (w == 0 || h == 0 || (uint64_t)w * h > max) {
        snprintf(err, errlen, "%s: a %ux%u image (1 to %zu texels)", name, w, h, max);
        return 1;
    }
    return 0;
}

/* 8-bit RGB rows into linear floats (sRGB-decoded unless raw): a table,
 * since there are 256 values. */
static float *from_bytes(const unsigned char *px, size_t texels, int raw)
{
    float table[256];
    for (int i = 0; i < 256; i++)
        table[i] = raw ? (float)i / 255.0f : bitmap_srgb_to_linear((float)i / 255.0f);
    float *rgb = malloc(texels * 3 * sizeof *rgb);
    if (rgb)
        for (size_t i = 0; i < texels * 3; i++)
            rgb[i] = table[px[i]];
    return rgb;
}

/* Every chunk's declared length within the file. libpng allocates a
 * chunk's buffer by its length before it reads it, and its simplified API
 * sets no limit on that (png_set_chunk_malloc_max needs the full API): a
 * 200-byte file whose chunk claims 1.9 GB made it allocate 1.9 GB
 * (fuzz_bitmap). Only the chunk frames are read here, 12 bytes each; libpng
 * does all the decoding. */
static int png_chunks_fit(const char *name, const unsigned char *data, size_t size, char *err,
                          size_t errlen)
{
    size_t at = 8; /* past the signature */
    while (at + 8 <= size) {
        const uint32_t len = (uint32_t)data[at] << 24 | (uint32_t)data[at + 1] << 16 |
                             (uint32_t)data[at + 2] << 8 | data[at + 3];
        const unsigned char *type = data + at + 4;
        if (len > size - at - 8 || size - at - 8 - len < 4) { /* data, then a 4-byte CRC */
            const int named =
                isalpha(type[0]) && isalpha(type[1]) && isalpha(type[2]) && isalpha(type[3]);
            snprintf(err, errlen,
                     "%s: not a readable PNG (chunk %.4s at byte %zu claims %u bytes, the file "
                     "has %zu after it)",
                     name, named ? (const char *)type : "????", at, len, size - at - 8);
            return -1;
        }
        if (memcmp(type, "IEND", 4) == 0)
            return 0;
        at += 12 + (size_t)len;
    }
    return 0; /* truncated before IEND: libpng says so */
}

static int decode_png(const char *name, const unsigned char *data, size_t size, int raw, size_t max,
                      bitmap_t *out, char *err, size_t errlen)
{
    if (png_chunks_fit(name, data, size, err, errlen) < 0)
        return -1;
    png_image img;
    memset(&img, 0, sizeof img);
    img.version = PNG_IMAGE_VERSION;
    if (!png_image_begin_read_from_memory(&img, data, size)) {
        snprintf(err, errlen, "%s: not a readable PNG (%s)", name, img.message);
        png_image_free(&img);
        return -1;
    }
    if (too_large(name, img.width, img.height, max, err, errlen)) {
        png_image_free(&img);
        return -1;
    }
    img.format = PNG_FORMAT_RGB;
    size_t texels = (size_t)img.width * img.height;
    unsigned char *px = malloc(texels * 3);
    if (!px) {
        png_image_free(&img);
        snprintf(err, errlen, "%s: out of memory", name);
        return -1;
    }
    if (!png_image_finish_read(&img, NULL, px, 0, NULL)) {
        snprintf(err, errlen, "%s: not a readable PNG (%s)", name, img.message);
        png_image_free(&img); /* (a no-op when libpng freed it already) */
        free(px);
        return -1;
    }
    out->rgb = from_bytes(px, texels, raw);
    free(px);
    if (!out->rgb) {
        snprintf(err, errlen, "%s: out of memory", name);
        return -1;
    }
    out->width = (int)img.width;
    out->height = (int)img.height;
    return 0;
}

/* libjpeg's errors end in a longjmp back to decode_jpeg, with the message. */
typedef struct jpeg_fail {
    struct jpeg_error_mgr mgr;
    jmp_buf back;
    char text[JMSG_LENGTH_MAX];
} jpeg_fail_t;

static void jpeg_error_exit(j_common_ptr cinfo)
{
    jpeg_fail_t *f = (jpeg_fail_t *)cinfo->err;
    cinfo->err->format_message(cinfo, f->text);
    longjmp(f->back, 1);
}

static void jpeg_quiet(j_common_ptr cinfo, int level)
{
    (void)cinfo; /* warnings (a corrupt but readable file) stay off stderr */
    (void)level;
}

static int decode_jpeg(const char *name, const unsigned char *data, size_t size, int raw,
                       size_t max, bitmap_t *out, char *err, size_t errlen)
{
    struct jpeg_decompress_struct cinfo;
    jpeg_fail_t fail;
    /* volatile: assigned after setjmp and read after a longjmp */
    unsigned char *volatile px = NULL;
    memset(&cinfo, 0, sizeof cinfo);
    cinfo.err = jpeg_std_error(&fail.mgr);
    fail.mgr.error_exit = jpeg_error_exit;
    fail.mgr.emit_message = jpeg_quiet;
    fail.text[0] = '\0';
    jpeg_create_decompress(&cinfo);
    if (setjmp(fail.back)) {
        snprintf(err, errlen, "%s: not a readable JPEG (%s)", name, fail.text);
        jpeg_destroy_decompress(&cinfo);
        free(px);
        return -1;
    }
    jpeg_mem_src(&cinfo, data, (unsigned long)size);
    jpeg_read_header(&cinfo, TRUE);
    if (too_large(name, cinfo.image_width, cinfo.image_height, max, err, errlen)) {
        jpeg_destroy_decompress(&cinfo);
        return -1;
    }
    cinfo.out_color_space = JCS_RGB;
    jpeg_start_decompress(&cinfo);
    if (cinfo.output_components != 3) {
        snprintf(err, errlen, "%s: a JPEG of %d components (RGB or grey expected)", name,
                 cinfo.output_components);
        jpeg_destroy_decompress(&cinfo);
        return -1;
    }
    size_t w = cinfo.output_width, h = cinfo.output_height;
    px = malloc(w * h * 3);
    if (!px) {
        snprintf(err, errlen, "%s: out of memory", name);
        jpeg_destroy_decompress(&cinfo);
        return -1;
    }
    while (cinfo.output_scanline < cinfo.output_height) {
        JSAMPROW row = px + (size_t)cinfo.output_scanline * w * 3;
        jpeg_read_scanlines(&cinfo, &row, 1);
    }
    jpeg_finish_decompress(&cinfo);
    jpeg_destroy_decompress(&cinfo);
    out->rgb = from_bytes(px, w * h, raw);
    free(px);
    if (!out->rgb) {
        snprintf(err, errlen, "%s: out of memory", name);
        return -1;
    }
    out->width = (int)w;
    out->height = (int)h;
    return 0;
}

static int decode_exr(const char *name, const unsigned char *data, size_t size, size_t max,
                      bitmap_t *out, char *err, size_t errlen)
{
    image_t *img = NULL;
    if (image_read_exr_buffer_capped(name, data, size, (long long)max, &img, err, errlen) < 0)
        return -1;
    const float *ch[3] = {image_channel(img, "R"), image_channel(img, "G"),
                          image_channel(img, "B")};
    const float *y = image_channel(img, "Y");
    if (!(ch[0] && ch[1] && ch[2]) && !y) {
        snprintf(err, errlen, "%s: the image has neither R, G and B nor Y channels", name);
        image_destroy(&img);
        return -1;
    }
    if (too_large(name, (unsigned)img->width, (unsigned)img->height, max, err, errlen)) {
        image_destroy(&img);
        return -1;
    }
    size_t texels = (size_t)img->width * img->height;
    out->rgb = malloc(texels * 3 * sizeof *out->rgb);
    if (!out->rgb) {
        snprintf(err, errlen, "%s: out of memory", name);
        image_destroy(&img);
        return -1;
    }
    for (size_t i = 0; i < texels; i++)
        for (int c = 0; c < 3; c++)
            out->rgb[3 * i + c] = ch[0] && ch[1] && ch[2] ? ch[c][i] : y[i];
    out->width = img->width;
    out->height = img->height;
    image_destroy(&img);
    return 0;
}

/* Whether an RGBE file of w x h texels holds all of its texels. stb_image
 * reads a flat file past its end without a word (the missing texels are
 * whatever its stack held) and a run-length one as zeros, so the payload
 * is walked first, as stb's decoder will walk it: after the header (its
 * lines up to the first empty one) and the resolution line, scanlines of
 * runs (2, 2, width) for a width in [8, 32768), else w x h flat texels. */
static int hdr_complete(const unsigned char *data, size_t size, int w, int h)
{
    const unsigned char *end = data + size, *p = NULL;
    for (const unsigned char *q = data; q + 1 < end; q++)
        if (q[0] == '\n' && q[1] == '\n') {
            p = q + 2;
            break;
        }
    while (p && p < end && *p != '\n')
        p++;
    if (!p || p >= end)
        return 0;
    p++;
    int runs = w >= 8 && w < 32768 && end - p >= 4 && p[0] == 2 && p[1] == 2 && !(p[2] & 0x80);
    if (!runs)
        return (size_t)(end - p) / 4 >= (size_t)w * (size_t)h;
    for (int y = 0; y < h; y++) {
        if (end - p < 4 || p[0] != 2 || p[1] != 2 || ((p[2] << 8) | p[3]) != w)
            return 0;
        p += 4;
        for (int k = 0; k < 4; k++)
            for (int x = 0; x < w;) {
                if (p >= end)
                    return 0;
                int count = *p++;
                if (count > 128) {
                    count -= 128;
                    p++; /* the run's value */
                } else {
                    p += count; /* literals */
                }
                if (count == 0 || count > w - x || p > end)
                    return 0;
                x += count;
            }
    }
    return 1;
}

/* A Radiance RGBE file: each texel's mantissas times 2^(exponent - 136),
 * as Greg Ward's and Mitsuba's readers decode it. Its size and its
 * completeness are checked before anything is decoded. */
static int decode_hdr(const char *name, const unsigned char *data, size_t size, size_t max,
                      bitmap_t *out, char *err, size_t errlen)
{
    int w = 0, h = 0, comp = 0;
    if (size > INT32_MAX) {
        snprintf(err, errlen, "%s: a Radiance HDR file over 2 GB", name);
        return -1;
    }
    if (!stbi_info_from_memory(data, (int)size, &w, &h, &comp)) {
        snprintf(err, errlen, "%s: not a readable Radiance HDR image (%s)", name,
                 stbi_failure_reason());
        return -1;
    }
    if (too_large(name, (unsigned)w, (unsigned)h, max, err, errlen))
        return -1;
    if (!hdr_complete(data, size, w, h)) {
        snprintf(err, errlen, "%s: the Radiance HDR image is truncated or its runs are corrupt",
                 name);
        return -1;
    }
    float *rgb = stbi_loadf_from_memory(data, (int)size, &w, &h, &comp, 3);
    if (!rgb) {
        snprintf(err, errlen, "%s: the Radiance HDR image cannot be decoded (%s)", name,
                 stbi_failure_reason());
        return -1;
    }
    size_t texels = (size_t)w * (size_t)h;
    out->rgb = malloc(texels * 3 * sizeof *out->rgb);
    if (!out->rgb) {
        snprintf(err, errlen, "%s: out of memory", name);
        stbi_image_free(rgb);
        return -1;
    }
    memcpy(out->rgb, rgb, texels * 3 * sizeof *out->rgb);
    stbi_image_free(rgb);
    out->width = w;
    out->height = h;
    return 0;
}

int bitmap_is_hdr(const unsigned char *data, size_t size)
{
    return (size >= 10 && memcmp(data, "#?RADIANCE", 10) == 0) ||
           (size >= 6 && memcmp(data, "#?RGBE", 6) == 0);
}

int bitmap_decode(const char *name, const unsigned char *data, size_t size, int raw,
                  size_t max_texels, bitmap_t *out, char *err, size_t errlen)
{
    memset(out, 0, sizeof *out);
    static const unsigned char png_sig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
    static const unsigned char exr_sig[4] = {0x76, 0x2f, 0x31, 0x01};
    if (size >= 8 && memcmp(data, png_sig, 8) == 0)
        return decode_png(name, data, size, raw, max_texels, out, err, errlen);
    if (size >= 3 && data[0] == 0xff && data[1] == 0xd8 && data[2] == 0xff)
        return decode_jpeg(name, data, size, raw, max_texels, out, err, errlen);
    if (size >= 4 && memcmp(data, exr_sig, 4) == 0)
        return decode_exr(name, data, size, max_texels, out, err, errlen);
    if (bitmap_is_hdr(data, size))
        return decode_hdr(name, data, size, max_texels, out, err, errlen);
    snprintf(err, errlen, "%s: not a PNG, JPEG, OpenEXR or Radiance HDR image", name);
    return -1;
}
