/* test_adaptive.c - speed against error, end to end through the binary:
 * error tracking against a reference, stopping on a target error, and the
 * adaptive modes and options staying deterministic across worker counts. */
#include <cJSON.h>
#include <check.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "image.h"
#include "sched.h"
#include "testutil.h"

#define OUTLEN 16384

/* The Cornell box at 24x24 in the scratch folder. */
static const char *small_cornell(char *path, size_t len)
{
    char src[1024];
    FILE *f = fopen(tu_root_path(src, sizeof src, "scenes/cornell-box.json"), "rb");
    ck_assert(f != NULL);
    static char text[65536];
    size_t n = fread(text, 1, sizeof text - 1, f);
    fclose(f);
    text[n] = '\0';
    char *at = strstr(text, "\"width\": 256, \"height\": 256");
    ck_assert(at != NULL);
    memcpy(at, "\"width\":  24, \"height\":  24", strlen("\"width\": 256, \"height\": 256"));
    return tu_write_tmp(path, len, "adaptive-cornell.json", text);
}

static void render(const char *args, char *out)
{
    char cmd[4096];
    snprintf(cmd, sizeof cmd, "'%s' render %s --progress none", tu_bin(), args);
    int rc = tu_run(cmd, out, OUTLEN);
    ck_assert_msg(rc == 0, "exit %d: %s\n%s", rc, cmd, out);
}

static cJSON *read_json(const char *path)
{
    FILE *f = fopen(path, "rb");
    ck_assert_msg(f != NULL, "no %s", path);
    static char buf[1 << 20];
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    fclose(f);
    buf[n] = '\0';
    cJSON *j = cJSON_Parse(buf);
    ck_assert(j != NULL);
    return j;
}

START_TEST(test_reference_series)
{
    char scene[1024], ref[1024], img[1024], ejson[1024], out[OUTLEN], args[4096];
    small_cornell(scene, sizeof scene);
    tu_tmp_path(ref, sizeof ref, "adaptive-ref.exr");
    tu_tmp_path(img, sizeof img, "adaptive-img.exr");
    tu_tmp_path(ejson, sizeof ejson, "adaptive-img.error.json");
    unlink(ejson);
    snprintf(args, sizeof args, "'%s' -o '%s' --spp 1024 --adaptive none --seed 99", scene, ref);
    render(args, out);
    snprintf(args, sizeof args,
             "'%s' -o '%s' --spp 128 --granularity 8 --adaptive relerr --reference '%s'", scene,
             img, ref);
    render(args, out);
    cJSON *doc = read_json(ejson);
    const cJSON *series = cJSON_GetObjectItem(doc, "series");
    int n = cJSON_GetArraySize(series);
    ck_assert_msg(n >= 2, "series has %d points", n);
    const cJSON *first = cJSON_GetArrayItem(series, 0), *last = cJSON_GetArrayItem(series, n - 1);
    double rel0 = cJSON_GetArrayItem(first, 2)->valuedouble,
           rel1 = cJSON_GetArrayItem(last, 2)->valuedouble;
    ck_assert_msg(rel1 < rel0, "relMSE did not fall: %g -> %g", rel0, rel1);
    ck_assert_str_eq(cJSON_GetObjectItem(doc, "columns")->valuestring,
                     "seconds samples relmse rmse rays");
    /* samples, seconds and rays never go backwards; every sample traces a
     * ray at least */
    for (int i = 0; i < n; i++) {
        const cJSON *b = cJSON_GetArrayItem(series, i);
        ck_assert_int_eq(cJSON_GetArraySize(b), 5);
        ck_assert(cJSON_GetArrayItem(b, 4)->valuedouble >= cJSON_GetArrayItem(b, 1)->valuedouble);
        if (i == 0)
            continue;
        const cJSON *a = cJSON_GetArrayItem(series, i - 1);
        for (int k = 0; k < 5; k += k == 1 ? 3 : 1) /* seconds, samples, rays */
            ck_assert(cJSON_GetArrayItem(b, k)->valuedouble >=
                      cJSON_GetArrayItem(a, k)->valuedouble);
    }
    /* the last point's rays are the job's */
    ck_assert_double_eq(cJSON_GetArrayItem(last, 4)->valuedouble,
                        cJSON_GetObjectItem(cJSON_GetObjectItem(doc, "job"), "rays")->valuedouble);
    /* the last point is the final image's error, as `compare` measures it */
    char cmd[4096];
    snprintf(cmd, sizeof cmd, "'%s' compare '%s' '%s'", tu_bin(), img, ref);
    ck_assert_int_eq(tu_run(cmd, out, OUTLEN), 0);
    double relmse = -1;
    const char *p = strstr(out, "relMSE ");
    ck_assert(p && sscanf(p, "relMSE %lf", &relmse) == 1);
    ck_assert_msg(fabs(relmse - rel1) <= 1e-6 * rel1, "compare says %g, the series %g", relmse,
                  rel1);
    cJSON_Delete(doc);
    /* a reference of another size is refused by the master, with a reason */
    char other[1024];
    tu_tmp_path(other, sizeof other, "adaptive-other.exr");
    image_t *o = image_new(8, 8);
    image_add_channel(o, "R");
    image_add_channel(o, "G");
    image_add_channel(o, "B");
    char err[256];
    ck_assert(image_write_exr(o, other, err, sizeof err) == 0);
    image_destroy(&o);
    snprintf(cmd, sizeof cmd, "'%s' render '%s' -o '%s' --spp 8 --reference '%s' --progress none",
             tu_bin(), scene, img, other);
    ck_assert_int_eq(tu_run(cmd, out, OUTLEN), 1);
    ck_assert_msg(strstr(out, "reference") != NULL, "%s", out);
}
END_TEST

START_TEST(test_target_error_stops_early)
{
    char scene[1024], img[1024], out[OUTLEN], args[4096];
    small_cornell(scene, sizeof scene);
    tu_tmp_path(img, sizeof img, "adaptive-target.exr");
    snprintf(args, sizeof args,
             "'%s' -o '%s' --spp 4096 --granularity 16 --adaptive none --target-error 0.3 "
             "--confidence 0.9",
             scene, img);
    render(args, out);
    image_t *im = NULL;
    char err[256];
    ck_assert(image_read_exr(img, &im, err, sizeof err) == 0);
    const float *n = image_channel(im, "samples");
    double total = 0, lo = 1e30, hi = 0;
    int at_cap = 0;
    for (int i = 0; i < 24 * 24; i++) {
        total += n[i];
        at_cap += n[i] == 4096;
        lo = n[i] < lo ? n[i] : lo;
        hi = n[i] > hi ? n[i] : hi;
    }
    /* stopped well before 4096 spp everywhere, and not uniformly */
    ck_assert_msg(total < 0.5 * 4096 * 24 * 24, "took %g samples", total);
    /* (the default: 2 replicates) */
    ck_assert_msg(lo >= 16 * SCHED_TARGET_CALIBRATED_LAYERS,
                  "a pixel stopped after %g samples (before %d layers)", lo,
                  SCHED_TARGET_CALIBRATED_LAYERS);
    ck_assert_msg(hi > lo, "every pixel took %g samples", lo);
    /* the summary says which pixels the rule stopped and which ran to the cap */
    char want[160];
    snprintf(want, sizeof want, "target error 0.3: %d of %d pixels stopped below the cap",
             24 * 24 - at_cap, 24 * 24);
    ck_assert_msg(strstr(out, want) != NULL, "no \"%s\" in: %s", want, out);
    snprintf(want, sizeof want, "%d ran to the cap of 4096 spp", at_cap);
    ck_assert_msg(strstr(out, want) != NULL, "no \"%s\" in: %s", want, out);
    image_destroy(&im);
}
END_TEST

/* sum (a - b)^2 over sum (var_a + var_b), over the pixels of PAIRS pairs of
 * renders of one scene under distinct seeds: 1 when the variance channel
 * is the error of each mean. (A sum, not a per-pixel statistic: the
 * film's own variance is wrong most where it is largest, at the light's
 * edges, where stratification takes out nearly all of it.) */
#define PAIRS 3
static double error_over_predicted(const char *scene, const char *extra)
{
    double d2 = 0, pred = 0;
    for (int pair = 0; pair < PAIRS; pair++) {
        image_t *im[2];
        for (int k = 0; k < 2; k++) {
            char img[1024], out[OUTLEN], args[4096], err[256];
            tu_tmp_path(img, sizeof img, k ? "calibrated-b.exr" : "calibrated-a.exr");
            snprintf(args, sizeof args, "'%s' -o '%s' --spp 128 --adaptive none --seed %d %s",
                     scene, img, 11 + 2 * pair + k, extra);
            render(args, out);
            im[k] = NULL;
            ck_assert_msg(image_read_exr(img, &im[k], err, sizeof err) == 0, "%s", err);
        }
        for (int i = 0; i < 24 * 24; i++) {
            double l[2];
            for (int k = 0; k < 2; k++) {
                l[k] = 0.3 * image_channel(im[k], "R")[i] + 0.59 * image_channel(im[k], "G")[i] +
                       0.11 * image_channel(im[k], "B")[i];
                pred += image_channel(im[k], "variance")[i];
            }
            d2 += (l[0] - l[1]) * (l[0] - l[1]);
        }
        image_destroy(&im[0]);
        image_destroy(&im[1]);
    }
    return d2 / pred;
}

/* The EXR's variance channel is the error of the pixel's mean: renders
 * under distinct seeds differ by what their channels predict (by default,
 * with the replicates' calibration; bench/error/calibrate.py measures it
 * per pixel); with one sequence (--replicates 1) the channel, the
 * samples' own variance, overstates it about 20x (0.04 to 0.07 here). */
START_TEST(test_variance_channel_calibrated)
{
    char scene[1024];
    small_cornell(scene, sizeof scene);
    const double calibrated = error_over_predicted(scene, "");
    ck_assert_msg(calibrated > 0.4 && calibrated < 2.5, "error / predicted %g, want 1", calibrated);
    const double one_sequence = error_over_predicted(scene, "--replicates 1");
    ck_assert_msg(one_sequence < 0.2, "one sequence: error / predicted %g", one_sequence);
}
END_TEST

static image_t *render_read(const char *scene, const char *name, const char *extra)
{
    char img[1024], out[OUTLEN], args[4096], err[256];
    tu_tmp_path(img, sizeof img, name);
    snprintf(args, sizeof args, "'%s' -o '%s' --spp 96 --granularity 8 --uniform-layers 3 %s",
             scene, img, extra);
    render(args, out);
    image_t *im = NULL;
    ck_assert_msg(image_read_exr(img, &im, err, sizeof err) == 0, "%s", err);
    return im;
}

START_TEST(test_modes_deterministic)
{
    char scene[1024];
    small_cornell(scene, sizeof scene);
    const char *modes[] = {"--adaptive variance", "--adaptive relerr --dilate",
                           "--adaptive thesis --random-selection --seed 5"};
    for (size_t m = 0; m < sizeof modes / sizeof modes[0]; m++) {
        char extra[256];
        snprintf(extra, sizeof extra, "%s --workers 1 --threads 1", modes[m]);
        image_t *a = render_read(scene, "adaptive-det-a.exr", extra);
        snprintf(extra, sizeof extra, "%s --workers 3 --threads 3", modes[m]);
        image_t *b = render_read(scene, "adaptive-det-b.exr", extra);
        for (int c = 0; c < a->channel_count; c++)
            ck_assert_msg(
                memcmp(image_channel(a, a->channel_names[c]), image_channel(b, a->channel_names[c]),
                       24 * 24 * sizeof(float)) == 0,
                "%s: channel %s differs between 1 and 3 workers", modes[m], a->channel_names[c]);
        /* and the mode really adapted: sample counts vary */
        const float *n = image_channel(a, "samples");
        int varies = 0;
        for (int i = 1; i < 24 * 24; i++)
            varies |= n[i] != n[0];
        ck_assert_msg(varies, "%s: every pixel got the same samples", modes[m]);
        image_destroy(&a);
        image_destroy(&b);
    }
}
END_TEST

int main(void)
{
    Suite *s = suite_create("adaptive");
    TCase *tc = tcase_create("end to end");
    tcase_set_timeout(tc, 300);
    tcase_add_test(tc, test_reference_series);
    tcase_add_test(tc, test_target_error_stops_early);
    tcase_add_test(tc, test_variance_channel_calibrated);
    tcase_add_test(tc, test_modes_deterministic);
    suite_add_tcase(s, tc);
    SRunner *sr = srunner_create(s);
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed ? 1 : 0;
}
