/* test_compare.c - the error metrics against values worked by hand, and the
 * `vbrender compare` command (output lines, refusals, error map). */
#include <check.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "compare.h"
#include "image.h"
#include "testutil.h"

static image_t *make(int w, int h, const float *rgb3)
{
    image_t *img = image_new(w, h);
    float *p[3] = {image_add_channel(img, "R"), image_add_channel(img, "G"),
                   image_add_channel(img, "B")};
    for (int i = 0; i < w * h; i++)
        for (int c = 0; c < 3; c++)
            p[c][i] = rgb3[3 * i + c];
    return img;
}

/* Two pixels. Reference (1,1,1) and (0,0,0); image (1.1,1,1) and (0,0,0.1).
 * squared errors: 0.01 and 0.01, others 0 -> RMSE = sqrt(0.02 / 6)
 * relMSE = (0.01/(1+0.01) + 0.01/(0+0.01)) / 6
 * MARE = (0.1/1.01 + 0.1/0.01) / 6; max = 0.1
 * per-pixel worst relative error: 0.099 and 10 -> above 0.5: 1/2 */
START_TEST(test_by_hand)
{
    const float ref[] = {1, 1, 1, 0, 0, 0}, img[] = {1.1f, 1, 1, 0, 0, 0.1f};
    image_t *r = make(2, 1, ref), *a = make(2, 1, img);
    compare_result_t res;
    char err[256];
    ck_assert(compare_images(a, r, 0.5, &res, err, sizeof err) == 0);
    double d0 = (double)1.1f - 1.0, d1 = (double)0.1f;
    ck_assert(fabs(res.rmse - sqrt((d0 * d0 + d1 * d1) / 6)) < 1e-12);
    ck_assert(fabs(res.relmse - (d0 * d0 / 1.01 + d1 * d1 / 0.01) / 6) < 1e-12);
    ck_assert(fabs(res.mare - (d0 / 1.01 + d1 / 0.01) / 6) < 1e-12);
    ck_assert(fabs(res.max_abs - d1) < 1e-12 || fabs(res.max_abs - d0) < 1e-12);
    ck_assert(fabs(res.above - 0.5) < 1e-15);
    ck_assert_uint_eq(res.pixels, 2);
    /* an image against itself: all zero */
    ck_assert(compare_images(r, r, 0.0, &res, err, sizeof err) == 0);
    ck_assert(res.relmse == 0 && res.rmse == 0 && res.above == 0);
    image_t *e = compare_error_image(a, r);
    ck_assert(e != NULL);
    ck_assert(fabs(image_channel(e, "error")[1] - d1 / 0.01) < 1e-5);
    image_destroy(&e);
    image_destroy(&a);
    image_destroy(&r);
}
END_TEST

START_TEST(test_refusals)
{
    const float px[12] = {0};
    image_t *a = make(2, 2, px), *b = make(4, 1, px);
    compare_result_t res;
    char err[256];
    ck_assert(compare_images(a, b, 0.1, &res, err, sizeof err) == -1);
    ck_assert_msg(strstr(err, "sizes differ") != NULL, "%s", err);
    image_t *c = image_new(2, 2);
    image_add_channel(c, "R");
    ck_assert(compare_images(c, a, 0.1, &res, err, sizeof err) == -1);
    ck_assert_msg(strstr(err, "R, G and B") != NULL, "%s", err);
    image_destroy(&a);
    image_destroy(&b);
    image_destroy(&c);
}
END_TEST

START_TEST(test_cli_compare)
{
    const float ref[] = {1, 1, 1, 0, 0, 0}, img[] = {1.1f, 1, 1, 0, 0, 0.1f};
    image_t *r = make(2, 1, ref), *a = make(2, 1, img), *small = make(1, 1, ref);
    char pa[1024], pr[1024], ps[1024], pm[1024], err[256], cmd[4096], out[4096];
    tu_tmp_path(pa, sizeof pa, "cmp-a.exr");
    tu_tmp_path(pr, sizeof pr, "cmp-ref.exr");
    tu_tmp_path(ps, sizeof ps, "cmp-small.exr");
    tu_tmp_path(pm, sizeof pm, "cmp-map.png");
    ck_assert(image_write_exr(a, pa, err, sizeof err) == 0);
    ck_assert(image_write_exr(r, pr, err, sizeof err) == 0);
    ck_assert(image_write_exr(small, ps, err, sizeof err) == 0);
    unlink(pm);
    snprintf(cmd, sizeof cmd, "'%s' compare '%s' '%s' --threshold 0.5 --error-map '%s'", tu_bin(),
             pa, pr, pm);
    ck_assert_int_eq(tu_run(cmd, out, sizeof out), 0);
    double relmse = -1, rmse = -1;
    const char *p = strstr(out, "relMSE ");
    ck_assert_msg(p && sscanf(p, "relMSE %lf", &relmse) == 1, "%s", out);
    p = strstr(out, "RMSE ");
    ck_assert_msg(p && sscanf(p, "RMSE %lf", &rmse) == 1, "%s", out);
    double d0 = (double)1.1f - 1.0, d1 = (double)0.1f;
    ck_assert(fabs(relmse - (d0 * d0 / 1.01 + d1 * d1 / 0.01) / 6) < 1e-8);
    ck_assert(fabs(rmse - sqrt((d0 * d0 + d1 * d1) / 6)) < 1e-8);
    ck_assert_msg(strstr(out, "above 0.5 0.5") != NULL, "%s", out);
    ck_assert(access(pm, F_OK) == 0);
    /* another size: refused, exit 1, saying why */
    snprintf(cmd, sizeof cmd, "'%s' compare '%s' '%s'", tu_bin(), pa, ps);
    ck_assert_int_eq(tu_run(cmd, out, sizeof out), 1);
    ck_assert_msg(strstr(out, "sizes differ") != NULL, "%s", out);
    snprintf(cmd, sizeof cmd, "'%s' compare '%s'", tu_bin(), pa);
    ck_assert_int_eq(tu_run(cmd, out, sizeof out), 2);
    image_destroy(&a);
    image_destroy(&r);
    image_destroy(&small);
}
END_TEST

int main(void)
{
    Suite *s = suite_create("compare");
    TCase *tc = tcase_create("metrics");
    tcase_add_test(tc, test_by_hand);
    tcase_add_test(tc, test_refusals);
    tcase_add_test(tc, test_cli_compare);
    suite_add_tcase(s, tc);
    SRunner *sr = srunner_create(s);
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed ? 1 : 0;
}
