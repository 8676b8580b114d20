/* test_image.c - Check suite for common/image.c: the channel/attribute
 * tables, EXR round trips (bit-exact floats, attributes, channel order),
 * reading HALF/UINT and tiled files written here with the OpenEXR C API,
 * clean failures on bad input, and the sRGB / heat-map PNG previews read
 * back with libpng. */
#include "image.h"
#include "testutil.h"

#include <check.h>
#include <dirent.h>
#include <math.h>
#include <png.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <openexr.h>

/* ------------------------------------------------------------------ */
/* helpers                                                             */

static uint32_t bits_of(float f)
{
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    return u;
}

static float float_of(uint32_t u)
{
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}

static long file_size(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0 ? (long)st.st_size : -1;
}

/* Number of entries in the scratch folder that start with prefix and
 * contain ".tmp." (leftover temporaries of an atomic write). */
static int count_tmp_files(const char *prefix)
{
    char dir[1024];
    tu_tmp_path(dir, sizeof dir, "");
    DIR *d = opendir(dir);
    if (!d)
        return -1;
    int n = 0;
    struct dirent *e;
    while ((e = readdir(d)) != NULL)
        if (strncmp(e->d_name, prefix, strlen(prefix)) == 0 && strstr(e->d_name, ".tmp."))
            n++;
    closedir(d);
    return n;
}

/* The sRGB OETF, written out independently of image.c. */
static int srgb_byte(double lin)
{
    if (!(lin > 0))
        lin = 0;
    if (lin > 1)
        lin = 1;
    double v = lin <= 0.0031308 ? 12.92 * lin : 1.055 * pow(lin, 1 / 2.4) - 0.055;
    return (int)floor(v * 255 + 0.5);
}

/* Reads a PNG back as packed RGB8 with libpng's simplified API; the
 * caller frees *rgb. */
static int read_png_rgb(const char *path, int *w, int *h, unsigned char **rgb)
{
    png_image im;
    memset(&im, 0, sizeof im);
    im.version = PNG_IMAGE_VERSION;
    if (!png_image_begin_read_from_file(&im, path))
        return -1;
    im.format = PNG_FORMAT_RGB;
    *rgb = malloc(PNG_IMAGE_SIZE(im));
    if (!*rgb) {
        png_image_free(&im);
        return -1;
    }
    if (!png_image_finish_read(&im, NULL, *rgb, 0, NULL)) {
        free(*rgb);
        *rgb = NULL;
        png_image_free(&im);
        return -1;
    }
    *w = (int)im.width;
    *h = (int)im.height;
    return 0;
}

static void quiet_exr_errors(exr_const_context_t c, exr_result_t code, const char *msg)
{
    (void)c;
    (void)code;
    (void)msg;
}

/* A channel for write_custom_exr: data is a plane in the channel's own
 * type (uint16_t half bits, uint32_t or float). */
typedef struct {
    const char *name;
    exr_pixel_type_t type;
    const void *data;
} raw_chan_t;

/* Writes an EXR with the C API directly, so the reader can be tested on
 * files image_write_exr never produces (HALF, UINT, tiled, float attrs).
 * Returns 0 or an exr_result_t. */
static int write_custom_exr(const char *path, int tiled, int w, int h, exr_compression_t comp,
                            const raw_chan_t *chs, int n, float float_attr)
{
    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    init.error_handler_fn = quiet_exr_errors;
    exr_context_t ctx = NULL;
    exr_result_t rv = exr_start_write(&ctx, path, EXR_WRITE_FILE_DIRECTLY, &init);
    if (rv)
        return rv;
    int part = 0;
    const int tile = 8;
    rv = exr_add_part(ctx, NULL, tiled ? EXR_STORAGE_TILED : EXR_STORAGE_SCANLINE, &part);
    if (!rv)
        rv = exr_initialize_required_attr_simple(ctx, part, w, h, comp);
    if (!rv && tiled)
        rv =
            exr_set_tile_descriptor(ctx, part, tile, tile, EXR_TILE_ONE_LEVEL, EXR_TILE_ROUND_DOWN);
    for (int c = 0; !rv && c < n; c++)
        rv = exr_add_channel(ctx, part, chs[c].name, chs[c].type, EXR_PERCEPTUALLY_LOGARITHMIC, 1,
                             1);
    if (!rv)
        rv = exr_attr_set_float(ctx, part, "fattr", float_attr);
    if (!rv)
        rv = exr_write_header(ctx);
    int32_t lines = 1;
    if (!rv && !tiled)
        rv = exr_get_scanlines_per_chunk(ctx, part, &lines);
    exr_encode_pipeline_t enc = EXR_ENCODE_PIPELINE_INITIALIZER;
    int inited = 0;
    int step_y = tiled ? tile : lines, step_x = tiled ? tile : w;
    for (int y = 0; !rv && y < h; y += step_y) {
        for (int x = 0; !rv && x < w; x += step_x) {
            exr_chunk_info_t ci;
            rv = tiled ? exr_write_tile_chunk_info(ctx, part, x / tile, y / tile, 0, 0, &ci)
                       : exr_write_scanline_chunk_info(ctx, part, y, &ci);
            if (rv)
                break;
            rv = inited ? exr_encoding_update(ctx, part, &ci, &enc)
                        : exr_encoding_initialize(ctx, part, &ci, &enc);
            if (rv)
                break;
            inited = 1;
            for (int c = 0; c < enc.channel_count; c++) {
                exr_coding_channel_info_t *ch = &enc.channels[c];
                const raw_chan_t *src = NULL;
                for (int k = 0; k < n; k++)
                    if (strcmp(chs[k].name, ch->channel_name) == 0)
                        src = &chs[k];
                ck_assert_ptr_nonnull(src);
                int bpe = src->type == EXR_PIXEL_HALF ? 2 : 4;
                ch->encode_from_ptr =
                    (const uint8_t *)src->data + ((size_t)y * (size_t)w + (size_t)x) * (size_t)bpe;
                ch->user_pixel_stride = bpe;
                ch->user_line_stride = w * bpe;
                ch->user_bytes_per_element = (int16_t)bpe;
                ch->user_data_type = (uint16_t)src->type;
            }
            rv = exr_encoding_choose_default_routines(ctx, part, &enc);
            if (!rv)
                rv = exr_encoding_run(ctx, part, &enc);
        }
    }
    if (inited)
        exr_encoding_destroy(ctx, &enc);
    exr_result_t frv = exr_finish(&ctx);
    return rv ? rv : frv;
}

/* ------------------------------------------------------------------ */
/* image table                                                         */

START_TEST(test_new_sizes)
{
    ck_assert_ptr_null(image_new(0, 10));
    ck_assert_ptr_null(image_new(10, 0));
    ck_assert_ptr_null(image_new(-1, 10));
    ck_assert_ptr_null(image_new(10, -5));
    ck_assert_ptr_null(image_new(65537, 1));
    ck_assert_ptr_null(image_new(1, 65537));
    ck_assert_ptr_null(image_new(65536, 65536)); /* 2^32 pixels */
    ck_assert_ptr_null(image_new(16385, 16384)); /* just over 2^28 */
    image_t *img = image_new(65536, 1);
    ck_assert_ptr_nonnull(img);
    image_destroy(&img);
    ck_assert_ptr_null(img);
    img = image_new(3, 2);
    ck_assert_ptr_nonnull(img);
    ck_assert_int_eq(img->width, 3);
    ck_assert_int_eq(img->height, 2);
    ck_assert_int_eq(img->channel_count, 0);
    ck_assert_int_eq(img->attr_count, 0);
    image_destroy(&img);
    image_destroy(&img); /* already NULL */
    image_destroy(NULL);
}
END_TEST

START_TEST(test_add_channel)
{
    image_t *img = image_new(4, 3);
    float *r = image_add_channel(img, "R");
    ck_assert_ptr_nonnull(r);
    for (int i = 0; i < 12; i++)
        ck_assert_uint_eq(bits_of(r[i]), 0);
    ck_assert_ptr_eq(image_channel(img, "R"), r);
    ck_assert_ptr_null(image_channel(img, "G"));
    ck_assert_ptr_null(image_add_channel(img, "R")); /* duplicate */
    ck_assert_ptr_null(image_add_channel(img, ""));  /* empty */
    ck_assert_ptr_null(image_add_channel(img, NULL));
    char name[IMAGE_NAME_LEN + 1];
    memset(name, 'x', IMAGE_NAME_LEN);
    name[IMAGE_NAME_LEN] = '\0';
    ck_assert_ptr_null(image_add_channel(img, name)); /* too long */
    name[IMAGE_NAME_LEN - 1] = '\0';
    ck_assert_ptr_nonnull(image_add_channel(img, name)); /* longest allowed */
    ck_assert_int_eq(img->channel_count, 2);
    for (int c = 2; c < IMAGE_MAX_CHANNELS; c++) {
        char n[16];
        snprintf(n, sizeof n, "c%d", c);
        ck_assert_ptr_nonnull(image_add_channel(img, n));
    }
    ck_assert_ptr_null(image_add_channel(img, "onemore")); /* table full */
    ck_assert_int_eq(img->channel_count, IMAGE_MAX_CHANNELS);
    image_destroy(&img);
}
END_TEST

START_TEST(test_attrs)
{
    image_t *img = image_new(1, 1);
    ck_assert_int_eq(image_set_string(img, "s", "hello"), 0);
    ck_assert_int_eq(image_set_int(img, "i", 42), 0);
    ck_assert_int_eq(image_set_double(img, "d", 0.25), 0);
    ck_assert_int_eq(img->attr_count, 3);
    const image_attr_t *a = image_attr(img, "s");
    ck_assert_ptr_nonnull(a);
    ck_assert_int_eq(a->type, IMAGE_ATTR_STRING);
    ck_assert_str_eq(a->s, "hello");
    /* replacing keeps one entry, and may change the type */
    ck_assert_int_eq(image_set_int(img, "s", 7), 0);
    ck_assert_int_eq(img->attr_count, 3);
    a = image_attr(img, "s");
    ck_assert_int_eq(a->type, IMAGE_ATTR_INT);
    ck_assert_int_eq(a->i, 7);
    ck_assert_ptr_null(image_attr(img, "nope"));
    /* too long name / value, empty name */
    char big[IMAGE_STRING_LEN + 1];
    memset(big, 'v', IMAGE_STRING_LEN);
    big[IMAGE_STRING_LEN] = '\0';
    ck_assert_int_eq(image_set_string(img, "big", big), -1);
    big[IMAGE_STRING_LEN - 1] = '\0';
    ck_assert_int_eq(image_set_string(img, "big", big), 0);
    big[IMAGE_NAME_LEN] = '\0';
    ck_assert_int_eq(image_set_int(img, big, 1), -1);
    ck_assert_int_eq(image_set_int(img, "", 1), -1);
    ck_assert_int_eq(image_set_string(img, "x", NULL), -1);
    /* table full */
    while (img->attr_count < IMAGE_MAX_ATTRS) {
        char n[16];
        snprintf(n, sizeof n, "a%d", img->attr_count);
        ck_assert_int_eq(image_set_int(img, n, img->attr_count), 0);
    }
    ck_assert_int_eq(image_set_double(img, "overflow", 1.0), -1);
    ck_assert_int_eq(image_set_double(img, "d", 2.0), 0); /* replacing still works */
    ck_assert(image_attr(img, "d")->d == 2.0);
    image_destroy(&img);
}
END_TEST

/* ------------------------------------------------------------------ */
/* EXR                                                                 */

START_TEST(test_exr_roundtrip)
{
    const int w = 37, h = 23;
    static const char *const names[5] = {"R", "G", "B", "samples", "variance"};
    const float special[] = {
        0.0f,
        -0.0f,
        1.0f,
        -1.0f,
        1e-30f,
        -1e-30f,
        3e38f,
        -3e38f,
        1e-40f /* denormal */,
        0.1f,
        1.0f / 3.0f,
        65504.0f,
        65520.0f /* beyond half */,
        1.0009765625f + 1e-7f,
        3.14159265f,
        1e10f,
        123456.789f,
        float_of(0x3f800001) /* 1 + 1ulp */,
        INFINITY,
        -INFINITY,
    };
    const int nspecial = (int)(sizeof special / sizeof special[0]);
    image_t *img = image_new(w, h);
    for (int c = 0; c < 5; c++) {
        float *p = image_add_channel(img, names[c]);
        ck_assert_ptr_nonnull(p);
        for (int i = 0; i < w * h; i++) {
            int k = i + 7 * c;
            /* mostly non-half-representable values, with the specials sprinkled in */
            p[i] = (k % 5 == 0) ? special[(k / 5) % nspecial]
                                : (float)(c + 1) * 0.001234567f * (float)(i - 300);
        }
    }
    ck_assert_int_eq(image_set_string(img, "vb.scene", "scenes/cornell-box.json"), 0);
    ck_assert_int_eq(image_set_int(img, "vb.seed", -123456789), 0);
    ck_assert_int_eq(image_set_double(img, "vb.time", 1234.5678901234), 0);
    char path[1024], err[512] = "";
    tu_tmp_path(path, sizeof path, "img_rt.exr");
    ck_assert_msg(image_write_exr(img, path, err, sizeof err) == 0, "%s", err);
    ck_assert_int_eq(count_tmp_files("img_rt.exr"), 0);

    image_t *back = NULL;
    ck_assert_msg(image_read_exr(path, &back, err, sizeof err) == 0, "%s", err);
    ck_assert_ptr_nonnull(back);
    ck_assert_int_eq(back->width, w);
    ck_assert_int_eq(back->height, h);
    ck_assert_int_eq(back->channel_count, 5);
    for (int c = 0; c < 5; c++) {
        const float *a = image_channel(img, names[c]);
        const float *b = image_channel(back, names[c]);
        ck_assert_msg(b != NULL, "channel %s missing", names[c]);
        for (int i = 0; i < w * h; i++)
            ck_assert_msg(bits_of(a[i]) == bits_of(b[i]), "%s[%d]: %08x != %08x", names[c], i,
                          (unsigned)bits_of(a[i]), (unsigned)bits_of(b[i]));
    }
    ck_assert_int_eq(back->attr_count, 3);
    const image_attr_t *at = image_attr(back, "vb.scene");
    ck_assert_ptr_nonnull(at);
    ck_assert_int_eq(at->type, IMAGE_ATTR_STRING);
    ck_assert_str_eq(at->s, "scenes/cornell-box.json");
    at = image_attr(back, "vb.seed");
    ck_assert_ptr_nonnull(at);
    ck_assert_int_eq(at->type, IMAGE_ATTR_INT);
    ck_assert_int_eq(at->i, -123456789);
    at = image_attr(back, "vb.time");
    ck_assert_ptr_nonnull(at);
    ck_assert_int_eq(at->type, IMAGE_ATTR_DOUBLE);
    double want = 1234.5678901234;
    ck_assert(memcmp(&at->d, &want, sizeof want) == 0);
    image_destroy(&back);
    image_destroy(&img);
}
END_TEST

START_TEST(test_exr_channel_order)
{
    /* Not alphabetical, mixed case: the file stores them sorted. */
    static const char *const names[] = {"zeta", "R", "alpha", "B", "a", "G", "Z.depth"};
    const int n = (int)(sizeof names / sizeof names[0]);
    const int w = 5, h = 33; /* more than two 16-line ZIP chunks, last one short */
    image_t *img = image_new(w, h);
    for (int c = 0; c < n; c++) {
        float *p = image_add_channel(img, names[c]);
        for (int i = 0; i < w * h; i++)
            p[i] = (float)(c * 1000 + i);
    }
    char path[1024], err[512] = "";
    tu_tmp_path(path, sizeof path, "img_order.exr");
    ck_assert_msg(image_write_exr(img, path, err, sizeof err) == 0, "%s", err);
    image_t *back = NULL;
    ck_assert_msg(image_read_exr(path, &back, err, sizeof err) == 0, "%s", err);
    ck_assert_int_eq(back->channel_count, n);
    for (int c = 0; c < n; c++) {
        const float *p = image_channel(back, names[c]);
        ck_assert_msg(p != NULL, "channel %s missing", names[c]);
        for (int i = 0; i < w * h; i++)
            ck_assert_msg(p[i] == (float)(c * 1000 + i), "%s[%d] = %g", names[c], i, (double)p[i]);
    }
    image_destroy(&back);
    image_destroy(&img);
}
END_TEST

START_TEST(test_exr_long_names)
{
    /* Names over 31 characters need the EXR long-name flag. */
    const char *ch = "a.channel.name.longer.than.thirty.one.chars";
    const char *an = "an.attribute.name.longer.than.thirty.one";
    image_t *img = image_new(2, 2);
    float *p = image_add_channel(img, ch);
    p[3] = 5.5f;
    ck_assert_int_eq(image_set_int(img, an, 9), 0);
    char path[1024], err[512] = "";
    tu_tmp_path(path, sizeof path, "img_long.exr");
    ck_assert_msg(image_write_exr(img, path, err, sizeof err) == 0, "%s", err);
    image_t *back = NULL;
    ck_assert_msg(image_read_exr(path, &back, err, sizeof err) == 0, "%s", err);
    ck_assert_ptr_nonnull(image_channel(back, ch));
    ck_assert(image_channel(back, ch)[3] == 5.5f);
    ck_assert_ptr_nonnull(image_attr(back, an));
    ck_assert_int_eq(image_attr(back, an)->i, 9);
    image_destroy(&back);
    image_destroy(&img);
}
END_TEST

/* OpenEXRCore 3.1.5 mislabels chunks whose zlib form is exactly as long as
 * the raw data (e.g. 2x2 floats -> 16 bytes); image.c works around it.
 * Sweep small sizes and contents so that case is certainly hit. */
START_TEST(test_exr_tiny)
{
    char path[1024], err[512] = "";
    tu_tmp_path(path, sizeof path, "img_tiny.exr");
    for (int w = 1; w <= 6; w++) {
        for (int h = 1; h <= 6; h++) {
            for (int fill = 0; fill < 3; fill++) {
                image_t *img = image_new(w, h);
                float *p = image_add_channel(img, "R");
                float *q = image_add_channel(img, "G");
                for (int i = 0; i < w * h; i++) {
                    p[i] = fill == 0 ? 0.0f : fill == 1 ? (float)i : (float)(i * 7919 % 13) - 5.5f;
                    q[i] = (float)(w * h - i) * 0.1f;
                }
                p[w * h - 1] = 5.5f;
                ck_assert_msg(image_write_exr(img, path, err, sizeof err) == 0, "%s", err);
                image_t *back = NULL;
                ck_assert_msg(image_read_exr(path, &back, err, sizeof err) == 0, "%s", err);
                for (int c = 0; c < 2; c++) {
                    const float *a = img->channels[c];
                    const float *b = image_channel(back, img->channel_names[c]);
                    ck_assert_ptr_nonnull(b);
                    for (int i = 0; i < w * h; i++)
                        ck_assert_msg(bits_of(a[i]) == bits_of(b[i]),
                                      "%dx%d fill %d %s[%d]: %g != %g", w, h, fill,
                                      img->channel_names[c], i, (double)a[i], (double)b[i]);
                }
                image_destroy(&back);
                image_destroy(&img);
            }
        }
    }
}
END_TEST

START_TEST(test_exr_overwrite)
{
    char path[1024], err[512] = "";
    tu_tmp_path(path, sizeof path, "img_over.exr");
    for (int round = 1; round <= 2; round++) {
        image_t *img = image_new(3 * round, 2);
        image_add_channel(img, "Y")[0] = (float)round;
        ck_assert_msg(image_write_exr(img, path, err, sizeof err) == 0, "%s", err);
        image_destroy(&img);
    }
    image_t *back = NULL;
    ck_assert_msg(image_read_exr(path, &back, err, sizeof err) == 0, "%s", err);
    ck_assert_int_eq(back->width, 6);
    ck_assert(image_channel(back, "Y")[0] == 2.0f);
    image_destroy(&back);
    ck_assert_int_eq(count_tmp_files("img_over.exr"), 0);
}
END_TEST

START_TEST(test_exr_half_uint)
{
    const int w = 7, h = 19;
    /* half bit patterns and their exact float values */
    static const uint16_t hbits[] = {0x0000, 0x3c00, 0xc000, 0x3800, 0x7bff, 0x0001, 0x3555};
    static const float hvals[] = {
        0.0f, 1.0f, -2.0f, 0.5f, 65504.0f, 5.9604644775390625e-8f, 0.333251953125f};
    uint16_t *hp = malloc(sizeof *hp * (size_t)(w * h));
    uint32_t *up = malloc(sizeof *up * (size_t)(w * h));
    float *fp = malloc(sizeof *fp * (size_t)(w * h));
    for (int i = 0; i < w * h; i++) {
        hp[i] = hbits[i % 7];
        up[i] = i == 5 ? 4000000000u : (uint32_t)(i * 3);
        fp[i] = -0.1f * (float)i;
    }
    raw_chan_t chs[3] = {
        {"H", EXR_PIXEL_HALF, hp}, {"U", EXR_PIXEL_UINT, up}, {"F", EXR_PIXEL_FLOAT, fp}};
    char path[1024], err[512] = "";
    tu_tmp_path(path, sizeof path, "img_types.exr");
    ck_assert_int_eq(write_custom_exr(path, 0, w, h, EXR_COMPRESSION_ZIP, chs, 3, 0.75f), 0);
    image_t *back = NULL;
    ck_assert_msg(image_read_exr(path, &back, err, sizeof err) == 0, "%s", err);
    const float *H = image_channel(back, "H"), *U = image_channel(back, "U"),
                *F = image_channel(back, "F");
    ck_assert(H && U && F);
    for (int i = 0; i < w * h; i++) {
        ck_assert_msg(H[i] == hvals[i % 7], "H[%d] = %g", i, (double)H[i]);
        ck_assert_msg(U[i] == (float)up[i], "U[%d] = %g", i, (double)U[i]);
        ck_assert_uint_eq(bits_of(F[i]), bits_of(fp[i]));
    }
    const image_attr_t *a = image_attr(back, "fattr");
    ck_assert_ptr_nonnull(a);
    ck_assert_int_eq(a->type, IMAGE_ATTR_DOUBLE);
    ck_assert(a->d == 0.75);
    image_destroy(&back);
    free(hp);
    free(up);
    free(fp);
}
END_TEST

START_TEST(test_exr_tiled)
{
    const int w = 19, h = 13; /* partial tiles at the right and bottom */
    float *fp = malloc(sizeof *fp * (size_t)(w * h));
    uint16_t *hp = malloc(sizeof *hp * (size_t)(w * h));
    for (int i = 0; i < w * h; i++) {
        fp[i] = (float)i + 0.25f;
        hp[i] = (uint16_t)(0x3c00 + (i % 1024)); /* 1 + k/1024 */
    }
    raw_chan_t chs[2] = {{"Y", EXR_PIXEL_FLOAT, fp}, {"A", EXR_PIXEL_HALF, hp}};
    char path[1024], err[512] = "";
    tu_tmp_path(path, sizeof path, "img_tiled.exr");
    for (int comp = 0; comp < 2; comp++) {
        ck_assert_int_eq(write_custom_exr(path, 1, w, h,
                                          comp ? EXR_COMPRESSION_ZIP : EXR_COMPRESSION_NONE, chs, 2,
                                          1.0f),
                         0);
        image_t *back = NULL;
        ck_assert_msg(image_read_exr(path, &back, err, sizeof err) == 0, "%s", err);
        ck_assert_int_eq(back->width, w);
        ck_assert_int_eq(back->height, h);
        const float *Y = image_channel(back, "Y"), *A = image_channel(back, "A");
        ck_assert(Y && A);
        for (int i = 0; i < w * h; i++) {
            ck_assert_msg(Y[i] == fp[i], "Y[%d] = %g", i, (double)Y[i]);
            ck_assert_msg(A[i] == 1.0f + (float)(i % 1024) / 1024.0f, "A[%d] = %g", i,
                          (double)A[i]);
        }
        image_destroy(&back);
    }
    free(fp);
    free(hp);
}
END_TEST

START_TEST(test_exr_read_errors)
{
    char path[1024], err[512];
    image_t *img = NULL;

    tu_write_tmp(path, sizeof path, "img_text.exr", "this is not an image\n");
    err[0] = '\0';
    ck_assert_int_eq(image_read_exr(path, &img, err, sizeof err), -1);
    ck_assert_ptr_null(img);
    ck_assert_msg(strstr(err, path) && strstr(err, "not an OpenEXR file"), "%s", err);

    tu_write_tmp(path, sizeof path, "img_empty.exr", "");
    err[0] = '\0';
    ck_assert_int_eq(image_read_exr(path, &img, err, sizeof err), -1);
    ck_assert_msg(strstr(err, path) != NULL, "%s", err);

    /* right magic, garbage header */
    tu_write_tmp(path, sizeof path, "img_badhdr.exr", "v/1\001\002\000\000\000garbage");
    err[0] = '\0';
    ck_assert_int_eq(image_read_exr(path, &img, err, sizeof err), -1);
    ck_assert_ptr_null(img);
    ck_assert_msg(strstr(err, path) != NULL, "%s", err);

    tu_tmp_path(path, sizeof path, "img_does_not_exist.exr");
    unlink(path);
    err[0] = '\0';
    ck_assert_int_eq(image_read_exr(path, &img, err, sizeof err), -1);
    ck_assert_ptr_null(img);
    ck_assert_msg(strstr(err, path) && strstr(err, "No such file"), "%s", err);

    /* a directory */
    tu_tmp_path(path, sizeof path, "");
    err[0] = '\0';
    ck_assert_int_eq(image_read_exr(path, &img, err, sizeof err), -1);
    ck_assert_ptr_null(img);
    ck_assert_msg(strstr(err, path) && strstr(err, "directory"), "%s", err);
}
END_TEST

START_TEST(test_exr_truncated)
{
    const int w = 64, h = 64;
    image_t *img = image_new(w, h);
    float *p = image_add_channel(img, "R");
    for (int i = 0; i < w * h; i++)
        p[i] = (float)sin(i * 0.37) * 1000.0f; /* keeps ZIP from shrinking it to nothing */
    char path[1024], err[512] = "";
    tu_tmp_path(path, sizeof path, "img_trunc.exr");
    ck_assert_msg(image_write_exr(img, path, err, sizeof err) == 0, "%s", err);
    image_destroy(&img);
    long size = file_size(path);
    ck_assert_int_gt(size, 1000);
    /* cut at several points: inside the data, just after the header, in
     * the header */
    const long cuts[] = {size / 2, size - 1, size / 8, 40, 8};
    for (size_t k = 0; k < sizeof cuts / sizeof cuts[0]; k++) {
        ck_assert_int_eq(truncate(path, cuts[k]), 0);
        image_t *back = NULL;
        err[0] = '\0';
        ck_assert_msg(image_read_exr(path, &back, err, sizeof err) == -1, "cut at %ld read fine",
                      cuts[k]);
        ck_assert_ptr_null(back);
        ck_assert_msg(strstr(err, path) != NULL, "cut %ld: %s", cuts[k], err);
    }
}
END_TEST

START_TEST(test_exr_write_errors)
{
    char err[512] = "";
    image_t *img = image_new(4, 4);
    image_add_channel(img, "R");
    const char *bad = "/nonexistent-dir-vbrender/out.exr";
    ck_assert_int_eq(image_write_exr(img, bad, err, sizeof err), -1);
    ck_assert_msg(strstr(err, bad) && strstr(err, "cannot open for writing") &&
                      strstr(err, "No such file"),
                  "%s", err);

    /* an image without channels */
    image_t *empty = image_new(4, 4);
    char path[1024];
    tu_tmp_path(path, sizeof path, "img_nochan.exr");
    err[0] = '\0';
    ck_assert_int_eq(image_write_exr(empty, path, err, sizeof err), -1);
    ck_assert_msg(strstr(err, path) != NULL, "%s", err);
    ck_assert_int_eq(count_tmp_files("img_nochan.exr"), 0);
    image_destroy(&empty);

    /* an attribute whose name clashes with a standard one of another type:
     * the library refuses it, the temporary goes away */
    tu_tmp_path(path, sizeof path, "img_clash.exr");
    unlink(path);
    ck_assert_int_eq(image_set_string(img, "dataWindow", "oops"), 0);
    err[0] = '\0';
    ck_assert_int_eq(image_write_exr(img, path, err, sizeof err), -1);
    ck_assert_msg(strstr(err, path) && strstr(err, "dataWindow"), "%s", err);
    ck_assert_int_eq(file_size(path), -1);
    ck_assert_int_eq(count_tmp_files("img_clash.exr"), 0);
    image_destroy(&img);
}
END_TEST

/* ------------------------------------------------------------------ */
/* PNG                                                                 */

START_TEST(test_png_srgb)
{
    const int w = 4, h = 2;
    static const float R[8] = {0.0f, 1.0f, 0.5f, 2.0f, 0.0031308f, 0.2f, -1.0f, 0.04f};
    static const float G[8] = {0.2f, 0.0f, 1.0f, 0.5f, 0.001f, 0.9f, 0.0031308f, 1e-6f};
    static const float B[8] = {0.5f, 0.2f, 0.0f, 1.0f, 3.0f, NAN, 0.75f, 0.018f};
    image_t *img = image_new(w, h);
    memcpy(image_add_channel(img, "R"), R, sizeof R);
    memcpy(image_add_channel(img, "G"), G, sizeof G);
    memcpy(image_add_channel(img, "B"), B, sizeof B);
    char path[1024], err[512] = "";
    tu_tmp_path(path, sizeof path, "img_srgb.png");
    for (int pass = 0; pass < 2; pass++) {
        const float exposure = pass ? 0.5f : 1.0f;
        ck_assert_msg(image_write_png(img, path, exposure, err, sizeof err) == 0, "%s", err);
        int rw = 0, rh = 0;
        unsigned char *rgb = NULL;
        ck_assert_int_eq(read_png_rgb(path, &rw, &rh, &rgb), 0);
        ck_assert_int_eq(rw, w);
        ck_assert_int_eq(rh, h);
        for (int i = 0; i < w * h; i++) {
            const float *planes[3] = {R, G, B};
            for (int k = 0; k < 3; k++) {
                double lin = (double)planes[k][i] * exposure;
                ck_assert_msg(rgb[i * 3 + k] == srgb_byte(lin), "pass %d px %d ch %d: %d != %d",
                              pass, i, k, rgb[i * 3 + k], srgb_byte(lin));
            }
        }
        if (pass == 0) {
            /* hand-checked anchors of the curve */
            ck_assert_int_eq(rgb[0 * 3], 0);     /* 0 */
            ck_assert_int_eq(rgb[1 * 3], 255);   /* 1 */
            ck_assert_int_eq(rgb[2 * 3], 188);   /* 0.5 -> 0.7354 */
            ck_assert_int_eq(rgb[3 * 3], 255);   /* 2.0 clamps */
            ck_assert_int_eq(rgb[4 * 3], 10);    /* 0.0031308 -> 0.04045 */
            ck_assert_int_eq(rgb[5 * 3], 124);   /* 0.2 -> 0.4845 */
            ck_assert_int_eq(rgb[6 * 3], 0);     /* negative clamps */
            ck_assert_int_eq(rgb[5 * 3 + 2], 0); /* NaN -> 0 */
        }
        free(rgb);
    }
    ck_assert_int_eq(count_tmp_files("img_srgb.png"), 0);
    image_destroy(&img);
}
END_TEST

START_TEST(test_png_errors)
{
    image_t *img = image_new(2, 2);
    image_add_channel(img, "G");
    image_add_channel(img, "B");
    char path[1024], err[512] = "";
    tu_tmp_path(path, sizeof path, "img_norgb.png");
    unlink(path);
    ck_assert_int_eq(image_write_png(img, path, 1.0f, err, sizeof err), -1);
    ck_assert_msg(strstr(err, path) && strstr(err, "no channel R"), "%s", err);
    ck_assert_int_eq(file_size(path), -1);
    image_add_channel(img, "R");
    const char *bad = "/nonexistent-dir-vbrender/out.png";
    err[0] = '\0';
    ck_assert_int_eq(image_write_png(img, bad, 1.0f, err, sizeof err), -1);
    ck_assert_msg(strstr(err, bad) && strstr(err, "cannot open for writing"), "%s", err);
    err[0] = '\0';
    ck_assert_int_eq(image_write_heatmap_png(img, "samples", 0, 1, path, err, sizeof err), -1);
    ck_assert_msg(strstr(err, path) && strstr(err, "no channel samples"), "%s", err);
    ck_assert_int_eq(count_tmp_files("img_norgb.png"), 0);
    image_destroy(&img);
}
END_TEST

START_TEST(test_png_heatmap)
{
    const int w = 7, h = 1;
    /* lo = 10, hi = 50: t = -?, 0, 0.25, 0.5, 0.75, 1, >1 */
    static const float v[7] = {-5.0f, 10.0f, 20.0f, 30.0f, 40.0f, 50.0f, 1000.0f};
    static const unsigned char want[7][3] = {
        {0, 0, 0},     {0, 0, 0},       {0, 0, 255},     {255, 0, 0},
        {255, 255, 0}, {255, 255, 255}, {255, 255, 255},
    };
    image_t *img = image_new(w, h);
    memcpy(image_add_channel(img, "samples"), v, sizeof v);
    char path[1024], err[512] = "";
    tu_tmp_path(path, sizeof path, "img_heat.png");
    ck_assert_msg(image_write_heatmap_png(img, "samples", 10.0f, 50.0f, path, err, sizeof err) == 0,
                  "%s", err);
    int rw, rh;
    unsigned char *rgb = NULL;
    ck_assert_int_eq(read_png_rgb(path, &rw, &rh, &rgb), 0);
    ck_assert_int_eq(rw, w);
    ck_assert_int_eq(rh, h);
    for (int i = 0; i < w; i++)
        for (int k = 0; k < 3; k++)
            ck_assert_msg(rgb[i * 3 + k] == want[i][k], "px %d ch %d: %d", i, k, rgb[i * 3 + k]);
    free(rgb);

    /* halfway between blue (t=.25) and red (t=.5): t = .375 */
    float *p = image_channel(img, "samples");
    p[0] = 25.0f;
    ck_assert_int_eq(image_write_heatmap_png(img, "samples", 10.0f, 50.0f, path, err, sizeof err),
                     0);
    ck_assert_int_eq(read_png_rgb(path, &rw, &rh, &rgb), 0);
    ck_assert_int_eq(rgb[0], 128);
    ck_assert_int_eq(rgb[1], 0);
    ck_assert_int_eq(rgb[2], 128);
    free(rgb);

    /* hi <= lo: everything black */
    ck_assert_int_eq(image_write_heatmap_png(img, "samples", 5.0f, 5.0f, path, err, sizeof err), 0);
    ck_assert_int_eq(read_png_rgb(path, &rw, &rh, &rgb), 0);
    for (int i = 0; i < w * 3; i++)
        ck_assert_int_eq(rgb[i], 0);
    free(rgb);
    ck_assert_int_eq(count_tmp_files("img_heat.png"), 0);
    image_destroy(&img);
}
END_TEST

static Suite *image_suite(void)
{
    Suite *s = suite_create("image");
    TCase *t = tcase_create("table");
    tcase_add_test(t, test_new_sizes);
    tcase_add_test(t, test_add_channel);
    tcase_add_test(t, test_attrs);
    suite_add_tcase(s, t);

    t = tcase_create("exr");
    tcase_set_timeout(t, 30);
    tcase_add_test(t, test_exr_roundtrip);
    tcase_add_test(t, test_exr_channel_order);
    tcase_add_test(t, test_exr_long_names);
    tcase_add_test(t, test_exr_tiny);
    tcase_add_test(t, test_exr_overwrite);
    tcase_add_test(t, test_exr_half_uint);
    tcase_add_test(t, test_exr_tiled);
    tcase_add_test(t, test_exr_read_errors);
    tcase_add_test(t, test_exr_truncated);
    tcase_add_test(t, test_exr_write_errors);
    suite_add_tcase(s, t);

    t = tcase_create("png");
    tcase_set_timeout(t, 30);
    tcase_add_test(t, test_png_srgb);
    tcase_add_test(t, test_png_errors);
    tcase_add_test(t, test_png_heatmap);
    suite_add_tcase(s, t);
    return s;
}

int main(void)
{
    SRunner *sr = srunner_create(image_suite());
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed == 0 ? EXIT_SUCCESS : EXIT_FAILURE;
}
