/* test_cli.c - Check suite for the vbrender command line (client/vbrender.c),
 * run as a separate process: usage and exit codes (0 done, 1 the work
 * failed, 2 bad usage), a message naming every bad flag, scene and output
 * errors, and one tiny real render whose EXR is read back. */
#include <check.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "image.h"
#include "testutil.h"

#define PATHLEN 1024
#define OUTLEN 16384
#define CMDLEN 4096

/* ---- helpers ------------------------------------------------------------ */

/* Runs "BIN ARGS" and returns the exit status; out gets stdout + stderr. */
static int run(char *out, size_t outlen, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

static int run(char *out, size_t outlen, const char *fmt, ...)
{
    char args[CMDLEN], cmd[CMDLEN + PATHLEN];
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(args, sizeof args, fmt, ap);
    va_end(ap);
    ck_assert_int_gt(n, -1);
    ck_assert_uint_lt((size_t)n, sizeof args);
    n = snprintf(cmd, sizeof cmd, "'%s' %s", tu_bin(), args);
    ck_assert_uint_lt((size_t)n, sizeof cmd);
    int rc = tu_run(cmd, out, outlen);
    ck_assert_msg(rc >= 0, "could not run %s", cmd);
    return rc;
}

static void expect_usage_error(const char *args, const char *frag)
{
    char out[OUTLEN];
    int rc = run(out, sizeof out, "%s", args);
    ck_assert_msg(rc == 2, "'%s': exit %d, want 2; output:\n%s", args, rc, out);
    ck_assert_msg(strstr(out, frag) != NULL, "'%s': output lacks \"%s\":\n%s", args, frag, out);
}

static const char *cornell_path(char *buf, size_t len)
{
    return tu_root_path(buf, len, "scenes/cornell-box.json");
}

/* Replaces the first `from` in text (of capacity cap) with `to`. */
static void replace_once(char *text, size_t cap, const char *from, const char *to)
{
    char *at = strstr(text, from);
    ck_assert_msg(at != NULL, "\"%s\" not found", from);
    size_t fl = strlen(from), tl = strlen(to), rest = strlen(at + fl);
    ck_assert_uint_lt((size_t)(at - text) + tl + rest, cap);
    memmove(at + tl, at + fl, rest + 1);
    memcpy(at, to, tl);
}

/* The Cornell box at 16x16 (without its light when no_light) in a scratch
 * file. */
static const char *tiny_scene(char *path, size_t len, const char *name, int no_light)
{
    char src[PATHLEN];
    FILE *f = fopen(cornell_path(src, sizeof src), "rb");
    ck_assert_msg(f != NULL, "cannot open %s", src);
    static char text[65536];
    size_t n = fread(text, 1, sizeof text / 2, f);
    fclose(f);
    text[n] = '\0';
    replace_once(text, sizeof text, "\"width\": 256, \"height\": 256", "\"width\": 16, \"height\": 16");
    if (no_light)
        replace_once(text, sizeof text, "{\"type\": \"emitter\", \"radiance\": [17.0, 12.0, 4.0]}",
                     "{\"type\": \"diffuse\", \"albedo\": [0.5, 0.5, 0.5]}");
    ck_assert_ptr_nonnull(tu_write_tmp(path, len, name, text));
    return path;
}

static int file_exists(const char *path)
{
    return access(path, F_OK) == 0;
}

/* ---- usage -------------------------------------------------------------- */

START_TEST(help)
{
    char out[OUTLEN];
    ck_assert_int_eq(run(out, sizeof out, "--help"), 0);
    ck_assert_ptr_nonnull(strstr(out, "usage"));
    ck_assert_ptr_nonnull(strstr(out, "--spp"));
    ck_assert_int_eq(run(out, sizeof out, "-h"), 0);
    ck_assert_ptr_nonnull(strstr(out, "usage"));
    ck_assert_int_eq(run(out, sizeof out, "render --help"), 0);
    ck_assert_ptr_nonnull(strstr(out, "usage"));
}
END_TEST

START_TEST(no_args)
{
    char out[OUTLEN];
    ck_assert_int_eq(run(out, sizeof out, "%s", ""), 2);
    ck_assert_ptr_nonnull(strstr(out, "usage"));
}
END_TEST

START_TEST(unknown_command)
{
    expect_usage_error("frobnicate", "frobnicate");
}
END_TEST

START_TEST(render_without_scene)
{
    expect_usage_error("render", "scene");
    expect_usage_error("render --spp 4", "scene");
}
END_TEST

START_TEST(unknown_option)
{
    char scene[PATHLEN], args[CMDLEN];
    snprintf(args, sizeof args, "render '%s' --bogus", cornell_path(scene, sizeof scene));
    expect_usage_error(args, "--bogus");
    snprintf(args, sizeof args, "render '%s' '%s'", scene, scene);
    expect_usage_error(args, "unexpected argument");
}
END_TEST

START_TEST(bad_flag_values)
{
    static const char *const cases[][2] = {
        {"--spp 0", "--spp"},          {"--spp -3", "--spp"},
        {"--spp abc", "--spp"},        {"--spp 4294967296", "--spp"},
        {"--spp", "--spp"},            {"--threads 0", "--threads"},
        {"--threads 999", "--threads"}, {"--threads 2x", "--threads"},
        {"--integrator foo", "--integrator"}, {"--granularity 0", "--granularity"},
        {"--granularity 4097", "--granularity"}, {"--seed x", "--seed"},
        {"--seed -1", "--seed"},       {"--max-depth -1", "--max-depth"},
        {"--progress loud", "--progress"}, {"-o", "-o"},
    };
    char scene[PATHLEN], args[CMDLEN];
    cornell_path(scene, sizeof scene);
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        snprintf(args, sizeof args, "render '%s' %s", scene, cases[i][0]);
        expect_usage_error(args, cases[i][1]);
    }
}
END_TEST

/* ---- scene and output errors -------------------------------------------- */

START_TEST(missing_scene)
{
    char path[PATHLEN], out[OUTLEN];
    tu_tmp_path(path, sizeof path, "cli-no-such-scene.json");
    unlink(path);
    int rc = run(out, sizeof out, "render '%s' --progress none", path);
    ck_assert_msg(rc == 1, "exit %d:\n%s", rc, out);
    ck_assert_msg(strstr(out, path) != NULL, "output lacks the path:\n%s", out);
}
END_TEST

START_TEST(bad_scene)
{
    char path[PATHLEN], out[OUTLEN], want[PATHLEN + 16];
    tu_write_tmp(path, sizeof path, "cli-bad.json", "{\n  \"camera\": ,\n}\n");
    int rc = run(out, sizeof out, "render '%s' --progress none", path);
    ck_assert_msg(rc == 1, "exit %d:\n%s", rc, out);
    snprintf(want, sizeof want, "%s:2:", path);
    ck_assert_msg(strstr(out, want) != NULL, "output lacks %s:\n%s", want, out);
    int line = 0, col = 0;
    const char *at = strstr(out, want);
    ck_assert_int_eq(sscanf(at + strlen(path), ":%d:%d:", &line, &col), 2);
    ck_assert_int_eq(line, 2);
    ck_assert_int_gt(col, 0);
}
END_TEST

START_TEST(unwritable_output)
{
    char scene[PATHLEN], out[OUTLEN];
    tiny_scene(scene, sizeof scene, "cli-unwritable.json", 0);
    int rc = run(out, sizeof out,
                 "render '%s' -o /nonexistent-dir/x.exr --spp 1 --threads 2 --progress none", scene);
    ck_assert_msg(rc == 1, "exit %d:\n%s", rc, out);
    ck_assert_msg(strstr(out, "/nonexistent-dir/x.exr") != NULL, "output lacks the path:\n%s", out);
    ck_assert_msg(strstr(out, "No such file or directory") != NULL, "output lacks why:\n%s", out);
    /* refused before rendering: no render summary was printed */
    ck_assert_msg(strstr(out, "samples/s") == NULL, "rendered before checking the output:\n%s", out);
    /* an option where the file name belongs is a usage error, not a file name */
    rc = run(out, sizeof out, "render '%s' -o --spp 4", scene);
    ck_assert_msg(rc == 2 && strstr(out, "-o needs a file name") != NULL, "exit %d:\n%s", rc, out);
}
END_TEST

/* Determinism end to end: 1 thread, 2 threads and a second 2-thread run of
 * the binary give the same EXR in every channel, bit for bit; only the
 * timing attribute may differ. */
START_TEST(deterministic_exr)
{
    char scene[PATHLEN], exr[3][PATHLEN], out[OUTLEN];
    tiny_scene(scene, sizeof scene, "cli-determinism.json", 0);
    const int threads[3] = {1, 2, 2};
    image_t *img[3];
    for (int i = 0; i < 3; i++) {
        char name[64];
        snprintf(name, sizeof name, "cli-det-%d.exr", i);
        tu_tmp_path(exr[i], sizeof exr[i], name);
        int rc = run(out, sizeof out, "render '%s' -o '%s' --spp 40 --granularity 16 --threads %d --seed 9 --progress none",
                     scene, exr[i], threads[i]);
        ck_assert_msg(rc == 0, "exit %d:\n%s", rc, out);
        char err[512];
        ck_assert_msg(image_read_exr(exr[i], &img[i], err, sizeof err) == 0, "%s", err);
    }
    for (int i = 1; i < 3; i++) {
        ck_assert_int_eq(img[i]->channel_count, img[0]->channel_count);
        for (int c = 0; c < img[0]->channel_count; c++) {
            const float *a = image_channel(img[0], img[0]->channel_names[c]);
            const float *b = image_channel(img[i], img[0]->channel_names[c]);
            ck_assert_ptr_nonnull(b);
            ck_assert_msg(memcmp(a, b, 16 * 16 * sizeof(float)) == 0, "run %d: channel %s differs", i,
                          img[0]->channel_names[c]);
        }
        ck_assert_str_eq(image_attr(img[i], "vb.seed")->s, "9");
        ck_assert(image_attr(img[i], "vb.total_samples")->d == image_attr(img[0], "vb.total_samples")->d);
    }
    for (int i = 0; i < 3; i++)
        image_destroy(&img[i]);
}
END_TEST

START_TEST(warning_printed)
{
    char scene[PATHLEN], exr[PATHLEN], png[PATHLEN], out[OUTLEN];
    tiny_scene(scene, sizeof scene, "cli-dark.json", 1);
    tu_tmp_path(exr, sizeof exr, "cli-dark.exr");
    tu_tmp_path(png, sizeof png, "cli-dark.png");
    int rc = run(out, sizeof out, "render '%s' -o '%s' --spp 1 --threads 1 --progress none", scene, exr);
    ck_assert_msg(rc == 0, "exit %d:\n%s", rc, out);
    ck_assert_msg(strstr(out, "warning") && strstr(out, "no light"), "no warning:\n%s", out);
    unlink(exr);
    unlink(png);
}
END_TEST

/* ---- a real render ------------------------------------------------------ */

START_TEST(tiny_render)
{
    char scene[PATHLEN], exr[PATHLEN], png[PATHLEN], err[1024];
    static char out[OUTLEN];
    tiny_scene(scene, sizeof scene, "cli-tiny.json", 0);
    tu_tmp_path(exr, sizeof exr, "cli-tiny-out.exr");
    tu_tmp_path(png, sizeof png, "cli-tiny-out.png");
    unlink(exr);
    unlink(png);
    int rc = run(out, sizeof out, "render '%s' -o '%s' --spp 4 --threads 2 --progress lines", scene, exr);
    ck_assert_msg(rc == 0, "exit %d:\n%s", rc, out);
    ck_assert_msg(file_exists(exr), "%s missing", exr);
    ck_assert_msg(file_exists(png), "%s missing", png);
    ck_assert_msg(strstr(out, "samples/s") && strstr(out, "rays/s") && strstr(out, "NaN/Inf"),
                  "summary incomplete:\n%s", out);
    ck_assert_msg(strstr(out, "16x16") && strstr(out, "4 spp"), "summary lacks size/spp:\n%s", out);
    /* progress lines: whole lines with a percentage, ending at 100 % */
    int lines = 0;
    for (const char *p = out; *p;) {
        const char *e = strchr(p, '\n');
        size_t len = e ? (size_t)(e - p) : strlen(p);
        if (memchr(p, '%', len) && !memchr(p, '\r', len))
            lines++;
        p += len + (e ? 1 : 0);
    }
    ck_assert_msg(lines >= 1, "no progress lines:\n%s", out);
    ck_assert_msg(strstr(out, "100.0%") != NULL, "no 100%% line:\n%s", out);
    /* stdout names both outputs */
    ck_assert_msg(strstr(out, exr) && strstr(out, png), "outputs not named:\n%s", out);

    image_t *img = NULL;
    ck_assert_msg(image_read_exr(exr, &img, err, sizeof err) == 0, "%s", err);
    ck_assert_int_eq(img->width, 16);
    ck_assert_int_eq(img->height, 16);
    static const char *const chans[] = {"R", "G", "B", "samples", "variance"};
    for (int i = 0; i < 5; i++)
        ck_assert_msg(image_channel(img, chans[i]) != NULL, "channel %s missing", chans[i]);
    const float *samples = image_channel(img, "samples");
    const float *r = image_channel(img, "R");
    double sum = 0;
    for (int i = 0; i < 16 * 16; i++) {
        ck_assert_msg(samples[i] == 4.0f, "pixel %d has %g samples", i, samples[i]);
        ck_assert_msg(isfinite(r[i]) && r[i] >= 0, "pixel %d R = %g", i, r[i]);
        sum += r[i];
    }
    ck_assert_msg(sum > 0, "the image is black");
    const image_attr_t *a = image_attr(img, "vb.seed");
    ck_assert_ptr_nonnull(a);
    ck_assert_int_eq(a->type, IMAGE_ATTR_STRING);
    ck_assert_str_eq(a->s, "1");
    a = image_attr(img, "vb.integrator");
    ck_assert_ptr_nonnull(a);
    ck_assert_int_eq(a->type, IMAGE_ATTR_STRING);
    ck_assert_str_eq(a->s, "path");
    a = image_attr(img, "vb.total_samples");
    ck_assert_ptr_nonnull(a);
    ck_assert_int_eq(a->type, IMAGE_ATTR_DOUBLE);
    ck_assert_double_eq(a->d, 16.0 * 16.0 * 4.0);
    a = image_attr(img, "vb.render_seconds");
    ck_assert_ptr_nonnull(a);
    ck_assert_msg(a->d >= 0 && isfinite(a->d), "render_seconds %g", a->d);
    a = image_attr(img, "vb.spp");
    ck_assert_ptr_nonnull(a);
    ck_assert_int_eq(a->i, 4);
    image_destroy(&img);
    unlink(exr);
    unlink(png);
}
END_TEST

/* Without -o the output is the scene's base name + .exr in the current
 * folder; --seed and --integrator reach the file. */
START_TEST(default_output_and_flags)
{
    char scene[PATHLEN], dir[PATHLEN], exr[PATHLEN], png[PATHLEN], err[1024];
    static char out[OUTLEN];
    tiny_scene(scene, sizeof scene, "cli-default.json", 0);
    tu_tmp_path(dir, sizeof dir, "");
    tu_tmp_path(exr, sizeof exr, "cli-default.exr");
    tu_tmp_path(png, sizeof png, "cli-default.png");
    unlink(exr);
    unlink(png);
    char cmd[CMDLEN];
    snprintf(cmd, sizeof cmd,
             "cd '%s' && '%s' render '%s' --spp 1 --seed 77 --integrator naive --threads 1 "
             "--progress none",
             dir, tu_bin(), scene);
    int rc = tu_run(cmd, out, sizeof out);
    ck_assert_msg(rc == 0, "exit %d:\n%s", rc, out);
    ck_assert_msg(file_exists(exr) && file_exists(png), "default outputs missing:\n%s", out);
    ck_assert_msg(strchr(out, '%') == NULL, "--progress none printed progress:\n%s", out);
    image_t *img = NULL;
    ck_assert_msg(image_read_exr(exr, &img, err, sizeof err) == 0, "%s", err);
    ck_assert_str_eq(image_attr(img, "vb.seed")->s, "77");
    ck_assert_str_eq(image_attr(img, "vb.integrator")->s, "naive");
    ck_assert_double_eq(image_attr(img, "vb.total_samples")->d, 256.0);
    image_destroy(&img);
    unlink(exr);
    unlink(png);
}
END_TEST

/* ---- suite -------------------------------------------------------------- */

static Suite *cli_suite(void)
{
    Suite *su = suite_create("cli");
    TCase *tc = tcase_create("usage");
    tcase_set_timeout(tc, 30);
    tcase_add_test(tc, help);
    tcase_add_test(tc, no_args);
    tcase_add_test(tc, unknown_command);
    tcase_add_test(tc, render_without_scene);
    tcase_add_test(tc, unknown_option);
    tcase_add_test(tc, bad_flag_values);
    suite_add_tcase(su, tc);

    tc = tcase_create("errors");
    tcase_set_timeout(tc, 60);
    tcase_add_test(tc, missing_scene);
    tcase_add_test(tc, bad_scene);
    tcase_add_test(tc, unwritable_output);
    tcase_add_test(tc, warning_printed);
    suite_add_tcase(su, tc);

    tc = tcase_create("render");
    tcase_set_timeout(tc, 120);
    tcase_add_test(tc, tiny_render);
    tcase_add_test(tc, default_output_and_flags);
    tcase_add_test(tc, deterministic_exr);
    suite_add_tcase(su, tc);
    return su;
}

int main(void)
{
    SRunner *sr = srunner_create(cli_suite());
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed == 0 ? EXIT_SUCCESS : EXIT_FAILURE;
}
