/* test_bitmap.c - Check suite for bitmap textures: bitmap.c's decoders
 * (PNG, JPEG, OpenEXR, Radiance HDR; sRGB to linear; refusals of bad
 * files), the
 * lookups of texture.h (nearest and bilinear, repeat, mirror and clamp)
 * against values worked out by hand, and the scene loader's "bitmap"
 * albedo, from a file beside the scene and from a bundle. */
#include <check.h>
#include <math.h>
#include <png.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <jpeglib.h>
#include <zlib.h>

#include "bitmap.h"
#include "image.h"
#include "lights.h"
#include "scene.h"
#include "testutil.h"
#include "texture.h"

/* ---- files made here ----------------------------------------------------------- */

/* w x h RGB8 pixels as a PNG in memory (*size bytes, malloc'd). */
static unsigned char *png_bytes(const unsigned char *px, int w, int h, size_t *size)
{
    png_image img;
    memset(&img, 0, sizeof img);
    img.version = PNG_IMAGE_VERSION;
    img.width = (png_uint_32)w;
    img.height = (png_uint_32)h;
    img.format = PNG_FORMAT_RGB;
    png_alloc_size_t n = 0;
    ck_assert(png_image_write_to_memory(&img, NULL, &n, 0, px, 0, NULL));
    unsigned char *buf = malloc(n);
    ck_assert(png_image_write_to_memory(&img, buf, &n, 0, px, 0, NULL));
    *size = n;
    return buf;
}

/* w x h pixels of one grey level as a baseline JPEG in memory. */
static unsigned char *jpeg_bytes(int w, int h, unsigned char grey, size_t *size)
{
    struct jpeg_compress_struct c;
    struct jpeg_error_mgr e;
    c.err = jpeg_std_error(&e);
    jpeg_create_compress(&c);
    unsigned char *buf = NULL;
    unsigned long n = 0;
    jpeg_mem_dest(&c, &buf, &n);
    c.image_width = (JDIMENSION)w;
    c.image_height = (JDIMENSION)h;
    c.input_components = 3;
    c.in_color_space = JCS_RGB;
    jpeg_set_defaults(&c);
    jpeg_set_quality(&c, 100, TRUE);
    jpeg_start_compress(&c, TRUE);
    unsigned char *row = malloc((size_t)w * 3);
    memset(row, grey, (size_t)w * 3);
    while (c.next_scanline < c.image_height) {
        JSAMPROW r = row;
        jpeg_write_scanlines(&c, &r, 1);
    }
    jpeg_finish_compress(&c);
    jpeg_destroy_compress(&c);
    free(row);
    *size = n;
    return buf;
}

/* ---- decoding ------------------------------------------------------------------ */

START_TEST(srgb_curve)
{
    ck_assert(bitmap_srgb_to_linear(0.0f) == 0.0f);
    ck_assert(fabsf(bitmap_srgb_to_linear(1.0f) - 1.0f) < 1e-6f);
    /* the linear segment, and the power segment at 0.5: ((0.555 / 1.055)^2.4 */
    ck_assert(fabsf(bitmap_srgb_to_linear(0.04f) - 0.04f / 12.92f) < 1e-9f);
    ck_assert(fabsf(bitmap_srgb_to_linear(0.5f) - 0.2140411f) < 1e-6f);
}
END_TEST

START_TEST(png_decoded)
{
    /* 2x2: red, green / blue, grey 128 */
    const unsigned char px[12] = {255, 0, 0, 0, 255, 0, 0, 0, 255, 128, 128, 128};
    size_t n;
    unsigned char *png = png_bytes(px, 2, 2, &n);
    bitmap_t b;
    char err[256];
    ck_assert_msg(bitmap_decode("t.png", png, n, 0, BITMAP_MAX_TEXELS, &b, err, sizeof err) == 0,
                  "%s", err);
    ck_assert(b.width == 2 && b.height == 2);
    ck_assert(b.rgb[0] == 1.0f && b.rgb[1] == 0.0f && b.rgb[4] == 1.0f && b.rgb[8] == 1.0f);
    /* row 1, column 1: sRGB 128 in linear */
    ck_assert(fabsf(b.rgb[9] - bitmap_srgb_to_linear(128.0f / 255.0f)) < 1e-7f);
    bitmap_free(&b);
    /* raw: the stored values */
    ck_assert(bitmap_decode("t.png", png, n, 1, BITMAP_MAX_TEXELS, &b, err, sizeof err) == 0);
    ck_assert(fabsf(b.rgb[9] - 128.0f / 255.0f) < 1e-7f);
    bitmap_free(&b);
    /* cut short: refused with the name */
    ck_assert(bitmap_decode("cut.png", png, n / 2, 0, BITMAP_MAX_TEXELS, &b, err, sizeof err) ==
              -1);
    ck_assert_msg(strstr(err, "cut.png") && strstr(err, "not a readable PNG"), "%s", err);
    ck_assert_ptr_null(b.rgb);
    /* a chunk that claims far more than the file holds (fuzz_bitmap: libpng
     * allocated the 1.9 GB it claimed): refused before libpng sees it */
    unsigned char lying[33 + 16];
    memcpy(lying, png, 33); /* the signature and IHDR */
    const unsigned char text[16] = {0x70, 0x00, 0x00, 0x25, 't', 'E', 'X', 't',
                                    'a',  'b',  'c',  'd',  0,   0,   0,   0};
    memcpy(lying + 33, text, sizeof text);
    ck_assert(bitmap_decode("lying.png", lying, sizeof lying, 0, BITMAP_MAX_TEXELS, &b, err,
                            sizeof err) == -1);
    ck_assert_msg(strstr(err, "lying.png") &&
                      strstr(err, "chunk tEXt at byte 33 claims 1879048229"),
                  "%s", err);
    ck_assert_ptr_null(b.rgb);
    free(png);
}
END_TEST

START_TEST(jpeg_decoded)
{
    size_t n;
    unsigned char *jpg = jpeg_bytes(5, 3, 200, &n);
    bitmap_t b;
    char err[256];
    ck_assert_msg(bitmap_decode("t.jpg", jpg, n, 0, BITMAP_MAX_TEXELS, &b, err, sizeof err) == 0,
                  "%s", err);
    ck_assert(b.width == 5 && b.height == 3);
    /* a flat grey survives JPEG to within a level */
    for (int i = 0; i < 15 * 3; i++)
        ck_assert_msg(fabsf(b.rgb[i] - bitmap_srgb_to_linear(200.0f / 255.0f)) < 0.01f, "%d: %g", i,
                      b.rgb[i]);
    bitmap_free(&b);
    /* a truncated stream: libjpeg's error, not a crash or an exit */
    ck_assert(bitmap_decode("cut.jpg", jpg, 40, 0, BITMAP_MAX_TEXELS, &b, err, sizeof err) == -1);
    ck_assert_msg(strstr(err, "cut.jpg") && strstr(err, "not a readable JPEG"), "%s", err);
    free(jpg);
    /* neither: named */
    const unsigned char junk[16] = "GIF89a.........";
    ck_assert(
        bitmap_decode("x.gif", junk, sizeof junk, 0, BITMAP_MAX_TEXELS, &b, err, sizeof err) == -1);
    ck_assert_msg(strstr(err, "x.gif: not a PNG, JPEG, OpenEXR or Radiance HDR image"), "%s", err);
}
END_TEST

START_TEST(exr_decoded_and_size_capped)
{
    image_t *img = image_new(3, 2);
    float *r = image_add_channel(img, "R"), *g = image_add_channel(img, "G"),
          *bl = image_add_channel(img, "B");
    for (int i = 0; i < 6; i++) {
        r[i] = 0.25f * (float)i;
        g[i] = 2.0f;
        bl[i] = 0.0f;
    }
    char path[1024], err[256];
    tu_tmp_path(path, sizeof path, "bitmap.exr");
    ck_assert_msg(image_write_exr(img, path, err, sizeof err) == 0, "%s", err);
    image_destroy(&img);
    FILE *f = fopen(path, "rb");
    ck_assert_ptr_nonnull(f);
    unsigned char buf[4096];
    size_t n = fread(buf, 1, sizeof buf, f);
    fclose(f);
    bitmap_t b;
    ck_assert_msg(bitmap_decode("t.exr", buf, n, 0, BITMAP_MAX_TEXELS, &b, err, sizeof err) == 0,
                  "%s", err);
    /* linear as stored (half floats hold these exactly), row 0 on top */
    ck_assert(b.width == 3 && b.height == 2 && b.rgb[3 * 4] == 1.0f && b.rgb[1] == 2.0f);
    bitmap_free(&b);
    /* a header claiming 5000x5000: refused before any texel is decoded
     * (a 1x1 PNG with its IHDR's size and CRC rewritten) */
    const unsigned char one[3] = {1, 2, 3};
    unsigned char *png = png_bytes(one, 1, 1, &n);
    unsigned char *ihdr = png + 8 + 4; /* after the signature and the chunk length */
    ck_assert(memcmp(ihdr, "IHDR", 4) == 0);
    const unsigned char side[4] = {0, 0, 0x13, 0x88}; /* 5000, big-endian */
    memcpy(ihdr + 4, side, 4);
    memcpy(ihdr + 8, side, 4);
    uLong crc = crc32(0, ihdr, 17);
    unsigned char be[4] = {(unsigned char)(crc >> 24), (unsigned char)(crc >> 16),
                           (unsigned char)(crc >> 8), (unsigned char)crc};
    memcpy(ihdr + 17, be, 4);
    ck_assert(bitmap_decode("big.png", png, n, 0, BITMAP_MAX_TEXELS, &b, err, sizeof err) == -1);
    ck_assert_msg(strstr(err, "big.png: a 5000x5000 image"), "%s", err);
    free(png);
}
END_TEST

/* A Radiance HDR file of w x h texels from its RGBE bytes as they are
 * stored (flat, or run-length scanlines as the caller wrote them), in
 * memory (*size bytes, malloc'd). */
static unsigned char *hdr_bytes(int w, int h, const unsigned char *pixels, size_t npixels,
                                size_t *size)
{
    char head[128];
    int n =
        snprintf(head, sizeof head, "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y %d +X %d\n", h, w);
    unsigned char *buf = malloc((size_t)n + npixels);
    ck_assert_ptr_nonnull(buf);
    memcpy(buf, head, (size_t)n);
    memcpy(buf + n, pixels, npixels);
    *size = (size_t)n + npixels;
    return buf;
}

/* RGBE texels decode to mantissa x 2^(exponent - 136), as Greg Ward's
 * reader (and Mitsuba's) decodes them: flat texels, and a run-length
 * encoded scanline; row 0 on top. A truncated file and a header claiming
 * 5000x5000 texels are refused with the file's name. */
START_TEST(hdr_decoded)
{
    /* 3x2, flat: exponent 129 is 2^-7, 0 is black */
    const unsigned char flat[6 * 4] = {128, 64, 255, 129, 1,   2, 3, 136, 0, 0, 0, 0,
                                       10,  20, 30,  140, 255, 0, 0, 128, 7, 7, 7, 120};
    size_t n;
    unsigned char *file = hdr_bytes(3, 2, flat, sizeof flat, &n);
    bitmap_t b;
    char err[256];
    ck_assert(bitmap_is_hdr(file, n));
    ck_assert_msg(bitmap_decode("t.hdr", file, n, 0, BITMAP_MAX_TEXELS, &b, err, sizeof err) == 0,
                  "%s", err);
    ck_assert(b.width == 3 && b.height == 2);
    for (int i = 0; i < 6; i++)
        for (int c = 0; c < 3; c++) {
            const unsigned char *px = flat + 4 * i;
            float want = px[3] ? ldexpf((float)px[c], px[3] - 136) : 0.0f;
            ck_assert_msg(b.rgb[3 * i + c] == want, "texel %d channel %d: %a, want %a", i, c,
                          b.rgb[3 * i + c], want);
        }
    ck_assert(b.rgb[0] == 1.0f && b.rgb[1] == 0.5f && b.rgb[3] == 1.0f);
    bitmap_free(&b);
    /* truncated: half the texels missing */
    ck_assert(bitmap_decode("cut.hdr", file, n - 12, 0, BITMAP_MAX_TEXELS, &b, err, sizeof err) ==
              -1);
    ck_assert_msg(strstr(err, "cut.hdr"), "%s", err);
    free(file);
    /* 8x1, run-length encoded: the scanline's 2 2 0 8 marker, then each
     * channel in turn: a run of 8 (128 + 8, then the value) or 8 literals */
    const unsigned char rle[] = {2, 2, 0, 8, 128 + 8, 200, 128 + 8, 100,     8,  1,
                                 2, 3, 4, 5, 6,       7,   255,     128 + 8, 130};
    file = hdr_bytes(8, 1, rle, sizeof rle, &n);
    ck_assert_msg(bitmap_decode("rle.hdr", file, n, 0, BITMAP_MAX_TEXELS, &b, err, sizeof err) == 0,
                  "%s", err);
    ck_assert(b.width == 8 && b.height == 1);
    for (int i = 0; i < 8; i++) {
        float blue = (float)(i < 7 ? i + 1 : 255) / 64.0f;
        ck_assert_msg(b.rgb[3 * i] == 3.125f && b.rgb[3 * i + 1] == 1.5625f &&
                          b.rgb[3 * i + 2] == blue,
                      "texel %d: %g %g %g", i, b.rgb[3 * i], b.rgb[3 * i + 1], b.rgb[3 * i + 2]);
    }
    bitmap_free(&b);
    /* the same with its last run cut short */
    ck_assert(bitmap_decode("cut.hdr", file, n - 1, 0, BITMAP_MAX_TEXELS, &b, err, sizeof err) ==
              -1);
    ck_assert_msg(strstr(err, "cut.hdr: the Radiance HDR image is truncated"), "%s", err);
    free(file);
    /* a header claiming 5000x5000: refused before any texel is decoded */
    file = hdr_bytes(5000, 5000, flat, sizeof flat, &n);
    ck_assert(bitmap_decode("big.hdr", file, n, 0, BITMAP_MAX_TEXELS, &b, err, sizeof err) == -1);
    ck_assert_msg(strstr(err, "big.hdr: a 5000x5000 image"), "%s", err);
    free(file);
}
END_TEST

/* An environment map read from a Radiance HDR file gives the very
 * radiance of the same map read from OpenEXR (texels RGBE holds exactly:
 * red 1 + column + 10 row, green and blue 1, all at exponent 2^-3), in
 * every direction looked up. */
START_TEST(hdr_environment_as_exr)
{
    enum { W = 4, H = 3 };
    image_t *img = image_new(W, H);
    float *r = image_add_channel(img, "R"), *g = image_add_channel(img, "G"),
          *bl = image_add_channel(img, "B");
    unsigned char rgbe[W * H * 4];
    for (int j = 0; j < H; j++)
        for (int i = 0; i < W; i++) {
            int k = j * W + i;
            r[k] = (float)(1 + i + 10 * j);
            g[k] = bl[k] = 1.0f;
            rgbe[4 * k] = (unsigned char)(8 * (1 + i + 10 * j));
            rgbe[4 * k + 1] = rgbe[4 * k + 2] = 8;
            rgbe[4 * k + 3] = 133;
        }
    char exr[1024], hdr[1024], dir[1024], err[512], json[1024];
    tu_tmp_path(exr, sizeof exr, "env43.exr");
    ck_assert_msg(image_write_exr(img, exr, err, sizeof err) == 0, "%s", err);
    image_destroy(&img);
    size_t n;
    unsigned char *file = hdr_bytes(W, H, rgbe, sizeof rgbe, &n);
    tu_tmp_path(hdr, sizeof hdr, "env43.hdr");
    FILE *f = fopen(hdr, "wb");
    ck_assert(f && fwrite(file, 1, n, f) == n);
    fclose(f);
    free(file);
    snprintf(dir, sizeof dir, "%s", hdr);
    *strrchr(dir, '/') = '\0';
    scene_t *s[2] = {NULL, NULL};
    const char *names[2] = {"env43.exr", "env43.hdr"};
    for (int k = 0; k < 2; k++) {
        snprintf(json, sizeof json,
                 "{\"camera\": {\"position\": [0, 0, 5], \"look_at\": [0, 0, 0], \"fov\": 30, "
                 "\"width\": 4, \"height\": 4}, \"environment\": {\"map\": \"%s\", \"scale\": 0.5},"
                 " \"materials\": {\"m\": {\"type\": \"diffuse\", \"albedo\": [0.5, 0.5, 0.5]}},"
                 " \"shapes\": [{\"type\": \"quad\", \"material\": \"m\", \"vertices\": [[0, 0, "
                 "0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]}]}",
                 names[k]);
        ck_assert_msg(
            scene_load_string(json, strlen(json), "env.json", dir, &s[k], err, sizeof err) == 0,
            "%s: %s", names[k], err);
        ck_assert(s[k]->has_env && s[k]->env_map);
    }
    for (int t = 0; t < 40; t++)
        for (int q = 0; q < 80; q++) {
            double th = (t + 0.5) / 40 * M_PI, ph = (q + 0.5) / 80 * 2 * M_PI;
            vec3_t d =
                vec3_make((float)(sin(th) * cos(ph)), (float)cos(th), (float)(sin(th) * sin(ph)));
            vec3_t a = lights_env_radiance(s[0], d), b = lights_env_radiance(s[1], d);
            ck_assert_msg(a.x == b.x && a.y == b.y && a.z == b.z && a.x > 0,
                          "direction (%d, %d): EXR %g %g %g, HDR %g %g %g", t, q, a.x, a.y, a.z,
                          b.x, b.y, b.z);
        }
    scene_destroy(&s[0]);
    scene_destroy(&s[1]);
}
END_TEST

/* ---- lookups, by hand ---------------------------------------------------------- */

/* 2x2 texels: (0, 0) 0.1, (1, 0) 0.3 on the top row; (0, 1) 0.5, (1, 1)
 * 0.9 below (red channel; green 0, blue 1). */
static float texels[12] = {0.1f, 0, 1, 0.3f, 0, 1, 0.5f, 0, 1, 0.9f, 0, 1};

static texture_t two_by_two(int nearest, texture_wrap_t wrap)
{
    texture_t t = {.kind = TEXTURE_BITMAP,
                   .width = 2,
                   .height = 2,
                   .rgb = texels,
                   .nearest = (uint8_t)nearest,
                   .wrap = wrap};
    return t;
}

START_TEST(lookups_by_hand)
{
    texture_t t = two_by_two(1, TEXTURE_WRAP_REPEAT);
    /* nearest: the texel the point falls in */
    ck_assert(texture_bitmap(&t, 0.2f, 0.2f).x == 0.1f);
    ck_assert(texture_bitmap(&t, 0.7f, 0.2f).x == 0.3f);
    ck_assert(texture_bitmap(&t, 0.2f, 0.7f).x == 0.5f);
    ck_assert(texture_bitmap(&t, 0.7f, 0.7f).z == 1.0f);
    /* repeat: u 1.2 is u 0.2; u -0.2 is 0.8 */
    ck_assert(texture_bitmap(&t, 1.2f, 0.2f).x == 0.1f);
    ck_assert(texture_bitmap(&t, -0.2f, 0.2f).x == 0.3f);
    /* bilinear: texel centres at 0.25 and 0.75 give the texels; halfway
     * between all four, their mean 0.45; a quarter of the way from (0, 0)
     * toward (1, 0): 0.1 + 0.25 * 0.2 = 0.15 */
    t = two_by_two(0, TEXTURE_WRAP_REPEAT);
    ck_assert(fabsf(texture_bitmap(&t, 0.25f, 0.25f).x - 0.1f) < 1e-6f);
    ck_assert(fabsf(texture_bitmap(&t, 0.75f, 0.75f).x - 0.9f) < 1e-6f);
    ck_assert(fabsf(texture_bitmap(&t, 0.5f, 0.5f).x - 0.45f) < 1e-6f);
    ck_assert(fabsf(texture_bitmap(&t, 0.375f, 0.25f).x - 0.15f) < 1e-6f);
    /* at u 0 (between texel 1 of the previous period and texel 0):
     * repeat blends 0.3 and 0.1; clamp holds 0.1; mirror reflects 0.1 */
    ck_assert(fabsf(texture_bitmap(&t, 0.0f, 0.25f).x - 0.2f) < 1e-6f);
    t = two_by_two(0, TEXTURE_WRAP_CLAMP);
    ck_assert(fabsf(texture_bitmap(&t, 0.0f, 0.25f).x - 0.1f) < 1e-6f);
    ck_assert(fabsf(texture_bitmap(&t, 7.0f, 9.0f).x - 0.9f) < 1e-6f);
    t = two_by_two(0, TEXTURE_WRAP_MIRROR);
    ck_assert(fabsf(texture_bitmap(&t, 0.0f, 0.25f).x - 0.1f) < 1e-6f);
    /* mirror: u 1.25 is texel column 2, which mirrors to column 1 */
    t = two_by_two(1, TEXTURE_WRAP_MIRROR);
    ck_assert(texture_bitmap(&t, 1.25f, 0.25f).x == 0.3f);
    ck_assert(texture_bitmap(&t, 1.75f, 0.25f).x == 0.1f);
    ck_assert(texture_bitmap(&t, -0.25f, 0.25f).x == 0.1f);
    /* far outside, NaN: a texel, not undefined behaviour */
    ck_assert(isfinite(texture_bitmap(&t, 1e30f, -1e30f).x));
    ck_assert(isfinite(texture_bitmap(&t, NAN, 0.5f).x));
    /* wrap rules alone */
    ck_assert_int_eq(texture_wrap(-1, 4, TEXTURE_WRAP_REPEAT), 3);
    ck_assert_int_eq(texture_wrap(-1, 4, TEXTURE_WRAP_MIRROR), 0);
    ck_assert_int_eq(texture_wrap(4, 4, TEXTURE_WRAP_MIRROR), 3);
    ck_assert_int_eq(texture_wrap(9, 4, TEXTURE_WRAP_MIRROR), 1);
    ck_assert_int_eq(texture_wrap(-5, 4, TEXTURE_WRAP_CLAMP), 0);
}
END_TEST

/* ---- the scene loader ---------------------------------------------------------- */

static const char scene_fmt[] =
    "{\"camera\": {\"position\": [0, 0, 5], \"look_at\": [0, 0, 0], \"fov\": 30, \"width\": 4, "
    "\"height\": 4},"
    " \"materials\": {\"t\": {\"type\": \"diffuse\", \"albedo\": {\"type\": \"bitmap\", "
    "\"file\": \"%s\", \"filter\": \"nearest\"%s}}},"
    " \"shapes\": [{\"type\": \"triangles\", \"material\": \"t\","
    " \"vertices\": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], \"uvs\": [[0, 0], [1, 0], [0, 1]],"
    " \"indices\": [[0, 1, 2]]}]}";

START_TEST(scene_bitmap)
{
    const unsigned char px[12] = {255, 0, 0, 0, 255, 0, 0, 0, 255, 255, 255, 255};
    size_t n;
    unsigned char *png = png_bytes(px, 2, 2, &n);
    char path[1024], dir[1024], json[2048], err[512];
    tu_tmp_path(path, sizeof path, "quad.png");
    FILE *f = fopen(path, "wb");
    ck_assert(f && fwrite(png, 1, n, f) == n);
    fclose(f);
    snprintf(dir, sizeof dir, "%s", path);
    *strrchr(dir, '/') = '\0';
    snprintf(json, sizeof json, scene_fmt, "quad.png", "");
    scene_t *s = NULL;
    ck_assert_msg(scene_load_string(json, strlen(json), "t.json", dir, &s, err, sizeof err) == 0,
                  "%s", err);
    const material_t *m = &s->materials[0];
    /* (u, v) barycentric = texture coordinates: near (0, 0) red, near
     * (1, 0) green, near (0, 1) blue */
    ck_assert(texture_albedo(s, m, 0, 0.1f, 0.1f).x == 1.0f);
    ck_assert(texture_albedo(s, m, 0, 0.8f, 0.1f).y == 1.0f);
    ck_assert(texture_albedo(s, m, 0, 0.1f, 0.8f).z == 1.0f);
    scene_destroy(&s);
    /* from a bundle: found by name, never on disk */
    scene_blob_t blob = {"quad.png", png, n};
    ck_assert_msg(scene_load_bundle(json, strlen(json), "t.json", &blob, 1, &s, err, sizeof err) ==
                      0,
                  "%s", err);
    ck_assert(texture_albedo(s, &s->materials[0], 0, 0.8f, 0.1f).y == 1.0f);
    scene_destroy(&s);
    ck_assert(scene_load_bundle(json, strlen(json), "t.json", NULL, 0, &s, err, sizeof err) == -1);
    ck_assert_msg(strstr(err, "\"quad.png\" is not in the scene bundle"), "%s", err);
    /* the faults, named with the JSON path */
    static const struct {
        const char *file, *extra, *says;
    } bad[] = {
        {"nowhere.png", "", "cannot open"},
        {"quad.png", ", \"wrap\": \"spiral\"", "wrap: expected"},
        {"quad.png", ", \"raw\": 1", "raw: expected true or false"},
        {"t.json", "", "not a PNG, JPEG, OpenEXR or Radiance HDR image"},
    };
    tu_write_tmp(path, sizeof path, "t.json", "{}");
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        snprintf(json, sizeof json, scene_fmt, bad[i].file, bad[i].extra);
        ck_assert(scene_load_string(json, strlen(json), "t.json", dir, &s, err, sizeof err) == -1);
        ck_assert_msg(strstr(err, "materials.t.albedo") && strstr(err, bad[i].says), "case %zu: %s",
                      i, err);
    }
    free(png);
}
END_TEST

static Suite *bitmap_suite(void)
{
    Suite *s = suite_create("bitmap");
    TCase *tc = tcase_create("bitmap");
    tcase_set_timeout(tc, 60);
    tcase_add_test(tc, srgb_curve);
    tcase_add_test(tc, png_decoded);
    tcase_add_test(tc, jpeg_decoded);
    tcase_add_test(tc, exr_decoded_and_size_capped);
    tcase_add_test(tc, hdr_decoded);
    tcase_add_test(tc, hdr_environment_as_exr);
    tcase_add_test(tc, lookups_by_hand);
    tcase_add_test(tc, scene_bitmap);
    suite_add_tcase(s, tc);
    return s;
}

int main(void)
{
    SRunner *sr = srunner_create(bitmap_suite());
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed ? EXIT_FAILURE : EXIT_SUCCESS;
}
