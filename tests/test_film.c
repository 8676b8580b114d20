/* test_film.c - merging results: Chan's M2 equals a one-pass variance of
 * all samples, whatever the batch boundaries; sums stay exact; the image
 * channels say what the film holds. */
#include <check.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "film.h"
#include "preview.h"
#include "rng.h"
#include "vmath.h"

/* A result built from a batch of samples the test knows. */
static tracer_result_t batch_result(uint32_t pixel, const double (*x)[3], uint32_t n)
{
    tracer_result_t r;
    memset(&r, 0, sizeof r);
    r.pixel = pixel;
    r.samples = n;
    double mean = 0, m2 = 0;
    for (uint32_t i = 0; i < n; i++) {
        for (int c = 0; c < 3; c++)
            r.sum[c] += x[i][c];
        double l = vmath_luminance(x[i][0], x[i][1], x[i][2]);
        double d = l - mean;
        mean += d / (i + 1);
        m2 += d * (l - mean);
    }
    r.lum_m2 = m2;
    return r;
}

START_TEST(test_chan_merge_matches_two_pass)
{
    enum { N = 1000 };
    static double x[N][3];
    rng_stream_t s = rng_stream(1, 0, 0);
    for (int i = 0; i < N; i++)
        for (int c = 0; c < 3; c++)
            x[i][c] = 1e3 + rng_next_double(&s) *
                                (c + 1); /* large offset: naive sums of squares would cancel */
    /* exact two-pass reference */
    double mean = 0;
    for (int i = 0; i < N; i++)
        mean += vmath_luminance(x[i][0], x[i][1], x[i][2]);
    mean /= N;
    double m2 = 0;
    for (int i = 0; i < N; i++) {
        double d = vmath_luminance(x[i][0], x[i][1], x[i][2]) - mean;
        m2 += d * d;
    }
    /* batch boundaries: uneven, including batches of 1 */
    const uint32_t cuts[] = {1, 31, 32, 1, 200, 7, 500, 228};
    film_t *f = film_new(2, 1);
    uint32_t at = 0;
    for (size_t k = 0; k < sizeof cuts / sizeof cuts[0]; k++) {
        tracer_result_t r = batch_result(1, x + at, cuts[k]);
        ck_assert(film_merge(f, &r) == 0);
        at += cuts[k];
    }
    ck_assert_uint_eq(at, N);
    ck_assert_uint_eq(f->pixels[1].count, N);
    ck_assert_uint_eq(f->pixels[1].nonfinite, 0);
    ck_assert_msg(fabs(f->pixels[1].lum_m2 - m2) <= 1e-9 * m2, "M2 %.15g vs %.15g",
                  f->pixels[1].lum_m2, m2);
    double expect_var = m2 / ((double)N * (N - 1));
    ck_assert(fabs(film_variance_of_mean(f, 1) - expect_var) <= 1e-9 * expect_var);
    /* untouched pixel stays empty */
    ck_assert_uint_eq(f->pixels[0].count, 0);
    ck_assert(film_variance_of_mean(f, 0) == 0.0);
    /* a result for a pixel outside the film is refused */
    tracer_result_t bad = batch_result(2, x, 1);
    ck_assert(film_merge(f, &bad) == -1);
    film_destroy(&f);
    ck_assert(f == NULL);
    film_destroy(&f); /* NULL is fine */
}
END_TEST

START_TEST(test_prior_and_nonfinite)
{
    film_t *f = film_new(1, 1);
    double x[2][3] = {{1, 2, 3}, {3, 2, 1}};
    tracer_result_t r = batch_result(0, (const double(*)[3])x, 2);
    r.nonfinite = 3;
    film_merge(f, &r);
    tracer_task_t t = {.pixel = 0};
    film_prior(f, &t);
    ck_assert_uint_eq(t.prior_count, 2);
    ck_assert(t.prior_sum[0] == 4 && t.prior_sum[1] == 4 && t.prior_sum[2] == 4);
    ck_assert_uint_eq(film_total_nonfinite(f), 3);
    ck_assert_uint_eq(film_total_samples(f), 5);
    double rgb[3];
    film_mean(f, 0, rgb);
    ck_assert(rgb[0] == 2 && rgb[1] == 2 && rgb[2] == 2);
    film_destroy(&f);
}
END_TEST

START_TEST(test_compensated_sum)
{
    /* 1e6 results of 0.1 (not representable): plain double summation drifts
     * by about 1e-11 relative; the compensated sum stays within 1e-15. */
    film_t *f = film_new(1, 1);
    tracer_result_t r;
    memset(&r, 0, sizeof r);
    r.samples = 1;
    r.sum[0] = r.sum[1] = r.sum[2] = 0.1;
    double plain = 0;
    for (int i = 0; i < 1000000; i++) {
        film_merge(f, &r);
        plain += 0.1;
    }
    double rgb[3];
    film_mean(f, 0, rgb);
    ck_assert_msg(fabs(rgb[0] - 0.1) <= 1e-15, "compensated mean off by %g", fabs(rgb[0] - 0.1));
    ck_assert_msg(fabs(plain / 1e6 - 0.1) > 1e-13, "plain summation should drift (%g)",
                  fabs(plain / 1e6 - 0.1));
    film_destroy(&f);
}
END_TEST

START_TEST(test_to_image)
{
    film_t *f = film_new(3, 2);
    double x[4][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, 1, 1}};
    tracer_result_t r = batch_result(4, (const double(*)[3])x, 4);
    film_merge(f, &r);
    image_t *img = film_to_image(f);
    ck_assert(img != NULL);
    const char *names[] = {"R", "G", "B", "samples", "variance"};
    for (int i = 0; i < 5; i++)
        ck_assert_msg(image_channel(img, names[i]) != NULL, "missing %s", names[i]);
    ck_assert(image_channel(img, "R")[4] == 0.5f);
    ck_assert(image_channel(img, "samples")[4] == 4.0f);
    ck_assert(image_channel(img, "samples")[0] == 0.0f);
    ck_assert(image_channel(img, "variance")[4] == (float)film_variance_of_mean(f, 4));
    ck_assert(image_channel(img, "variance")[4] > 0);
    image_destroy(&img);
    film_destroy(&f);
}
END_TEST

/* A film whose pixel i holds count samples of mean (r, g, b) = value(i). */
static void put(film_t *f, uint32_t pixel, double r, double g, double b, uint32_t count)
{
    tracer_result_t res;
    memset(&res, 0, sizeof res);
    res.pixel = pixel;
    res.samples = count;
    res.sum[0] = r * count;
    res.sum[1] = g * count;
    res.sum[2] = b * count;
    ck_assert(film_merge(f, &res) == 0);
}

/* 4x4 into 2x2: each output pixel is the mean of a 2x2 block of pixel
 * means (an unsampled pixel counts as black) and of their sample counts. */
START_TEST(test_preview_even)
{
    film_t *f = film_new(4, 4);
    for (uint32_t i = 0; i < 15; i++) /* pixel 15 stays unsampled */
        put(f, i, i, 2.0 * i, 1, 1 + i % 2);
    float rgb[2 * 2 * 3], spp[2 * 2];
    ck_assert(preview_from_film(f, 2, 2, rgb, spp) == 0);
    /* blocks: {0,1,4,5} {2,3,6,7} {8,9,12,13} {10,11,14,15} */
    const float r[4] = {2.5f, 4.5f, 10.5f, 8.75f}, n[4] = {1.5f, 1.5f, 1.5f, 1.0f};
    const float b[4] = {1, 1, 1, 0.75f};
    for (int o = 0; o < 4; o++) {
        ck_assert_float_eq(rgb[3 * o], r[o]);
        ck_assert_float_eq(rgb[3 * o + 1], 2 * r[o]);
        ck_assert_float_eq(rgb[3 * o + 2], b[o]);
        ck_assert_float_eq(spp[o], n[o]);
    }
    ck_assert_float_eq(preview_max(spp, 4), 1.5f);
    /* the same size: a copy of the film's means */
    float full[16 * 3], fspp[16];
    ck_assert(preview_from_film(f, 4, 4, full, fspp) == 0);
    ck_assert_float_eq(full[3 * 6], 6.0f);
    ck_assert_float_eq(fspp[7], 2.0f);
    ck_assert_float_eq(fspp[15], 0.0f);
    film_destroy(&f);
}
END_TEST

/* 5x3 into 2x2: columns {0,1,2} {3,4}, rows {0,1} {2}: boxes of unequal
 * size, each averaged over its own area. */
START_TEST(test_preview_uneven)
{
    film_t *f = film_new(5, 3);
    for (uint32_t y = 0; y < 3; y++)
        for (uint32_t x = 0; x < 5; x++)
            put(f, y * 5 + x, x + 10.0 * y, 0, 1, 1 + y);
    float rgb[2 * 2 * 3], spp[2 * 2];
    ck_assert(preview_from_film(f, 2, 2, rgb, spp) == 0);
    const float r[4] = {6.0f, 8.5f, 21.0f, 23.5f}, n[4] = {1.5f, 1.5f, 3.0f, 3.0f};
    for (int o = 0; o < 4; o++) {
        ck_assert_float_eq(rgb[3 * o], r[o]);
        ck_assert_float_eq(rgb[3 * o + 1], 0.0f);
        ck_assert_float_eq(rgb[3 * o + 2], 1.0f);
        ck_assert_float_eq(spp[o], n[o]);
    }
    /* the stored image of the same film gives the same preview */
    image_t *img = film_to_image(f);
    float irgb[2 * 2 * 3], ispp[2 * 2];
    ck_assert(preview_from_image(img, 2, 2, irgb, ispp) == 0);
    ck_assert(memcmp(irgb, rgb, sizeof rgb) == 0 && memcmp(ispp, spp, sizeof spp) == 0);
    /* an image without a samples channel: zeros */
    image_t *plain = image_new(5, 3);
    const char *names[] = {"R", "G", "B"};
    for (int c = 0; c < 3; c++)
        memcpy(image_add_channel(plain, names[c]), image_channel(img, names[c]),
               15 * sizeof(float));
    ck_assert(preview_from_image(plain, 2, 2, irgb, ispp) == 0);
    ck_assert(memcmp(irgb, rgb, sizeof rgb) == 0);
    for (int o = 0; o < 4; o++)
        ck_assert_float_eq(ispp[o], 0.0f);
    /* sizes outside 1..source are refused, never scaled up */
    ck_assert(preview_from_film(f, 6, 2, rgb, spp) == -1);
    ck_assert(preview_from_film(f, 2, 0, rgb, spp) == -1);
    image_destroy(&plain);
    ck_assert(preview_from_image(img, 2, 4, irgb, ispp) == -1);
    image_destroy(&img);
    film_destroy(&f);
}
END_TEST

START_TEST(test_preview_fit)
{
    const int cases[][6] = {
        /* source, limit, expected */
        {1920, 1080, 256, 256, 256, 144}, /* the width limits */
        {1080, 1920, 256, 256, 144, 256}, /* the height limits */
        {100, 50, 256, 256, 100, 50},     /* never scaled up */
        {4, 4, 2, 2, 2, 2},
        {5, 3, 2, 2, 2, 1},       /* 1.2 rounds to 1 */
        {1000, 1, 10, 10, 10, 1}, /* at least one row */
        {300, 200, 300, 100, 150, 100},
        {300, 200, 1, 4096, 1, 1}, /* 0.67 rounds to 1 */
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        const int *c = cases[i];
        int w = 0, h = 0;
        preview_fit(c[0], c[1], c[2], c[3], &w, &h);
        ck_assert_msg(w == c[4] && h == c[5], "%dx%d in %dx%d: %dx%d, expected %dx%d", c[0], c[1],
                      c[2], c[3], w, h, c[4], c[5]);
    }
}
END_TEST

/* A kept preview redoes only the output rows merged into since the last
 * update, and always equals a preview made afresh. */
START_TEST(test_preview_update)
{
    film_t *f = film_new(5, 6);
    for (uint32_t i = 0; i < 30; i++)
        put(f, i, i, 1, 2, 1);
    preview_t *p = preview_new(2, 3); /* output rows: source rows {0,1} {2,3} {4,5} */
    ck_assert_ptr_nonnull(p);
    ck_assert_int_eq(preview_update(p, f), 3); /* the first time: all */
    ck_assert_int_eq(preview_update(p, f), 0); /* nothing merged since */
    put(f, 2 * 5 + 4, 7, 7, 7, 3);             /* row 2: output row 1 */
    ck_assert_int_eq(preview_update(p, f), 1);
    put(f, 0, 1, 1, 1, 1);
    put(f, 29, 1, 1, 1, 1); /* rows 0 and 5: output rows 0 and 2 */
    ck_assert_int_eq(preview_update(p, f), 2);
    float rgb[2 * 3 * 3], spp[2 * 3];
    ck_assert(preview_from_film(f, 2, 3, rgb, spp) == 0);
    int w, h;
    const float *prgb, *pspp;
    preview_planes(p, &w, &h, &prgb, &pspp);
    ck_assert(w == 2 && h == 3);
    ck_assert(memcmp(prgb, rgb, sizeof rgb) == 0);
    ck_assert(memcmp(pspp, spp, sizeof spp) == 0);
    /* filled from the film's image: the same; then a film update redoes all */
    image_t *img = film_to_image(f);
    ck_assert_int_eq(preview_fill_image(p, img), 0);
    preview_planes(p, &w, &h, &prgb, &pspp);
    ck_assert(memcmp(prgb, rgb, sizeof rgb) == 0 && memcmp(pspp, spp, sizeof spp) == 0);
    ck_assert_int_eq(preview_update(p, f), 3);
    image_destroy(&img);
    /* another film: all again; larger than the film: refused */
    film_t *g = film_new(5, 6);
    ck_assert_int_eq(preview_update(p, g), 3);
    preview_planes(p, &w, &h, &prgb, &pspp);
    ck_assert_float_eq(pspp[0], 0.0f);
    preview_t *big = preview_new(6, 3);
    ck_assert_int_eq(preview_update(big, f), -1);
    preview_destroy(&big);
    preview_destroy(&p);
    ck_assert_ptr_null(p);
    film_destroy(&g);
    film_destroy(&f);
}
END_TEST

int main(void)
{
    Suite *s = suite_create("film");
    TCase *tc = tcase_create("merge");
    tcase_add_test(tc, test_chan_merge_matches_two_pass);
    tcase_add_test(tc, test_prior_and_nonfinite);
    tcase_add_test(tc, test_compensated_sum);
    tcase_add_test(tc, test_to_image);
    tcase_add_test(tc, test_preview_even);
    tcase_add_test(tc, test_preview_uneven);
    tcase_add_test(tc, test_preview_fit);
    tcase_add_test(tc, test_preview_update);
    suite_add_tcase(s, tc);
    SRunner *sr = srunner_create(s);
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed ? 1 : 0;
}
