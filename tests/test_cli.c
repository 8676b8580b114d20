/* test_cli.c - Check suite for the vbrender command line (client/vbrender.c),
 * run as a separate process: usage and exit codes (0 done, 1 the work
 * failed, 2 bad usage), a message naming every bad flag, scene and output
 * errors, one tiny real render whose EXR is read back, Ctrl-C on a render
 * (the image so far, marked partial; exit 130), --version and --log-level
 * of every binary, and the commands for a running master against a
 * scripted fake one (lost replies, restarts). */
#include <cJSON.h>
#include <check.h>
#include <ctype.h>
#include <fcntl.h>
#include <math.h>
#include <pthread.h>
#include <signal.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>
#include <zmq.h>

#include "defaults.h"
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
    replace_once(text, sizeof text, "\"width\": 256, \"height\": 256",
                 "\"width\": 16, \"height\": 16");
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
        {"--spp 0", "--spp"},
        {"--spp -3", "--spp"},
        {"--spp abc", "--spp"},
        {"--spp 4294967296", "--spp"},
        {"--spp", "--spp"},
        {"--threads 0", "--threads"},
        {"--threads 999", "--threads"},
        {"--threads 2x", "--threads"},
        {"--integrator foo", "--integrator"},
        {"--granularity 0", "--granularity"},
        {"--granularity 4097", "--granularity"},
        {"--seed x", "--seed"},
        {"--seed -1", "--seed"},
        {"--max-depth -1", "--max-depth"},
        {"--progress loud", "--progress"},
        {"-o", "-o"},
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
    int rc =
        run(out, sizeof out,
            "render '%s' -o /nonexistent-dir/x.exr --spp 1 --threads 2 --progress none", scene);
    ck_assert_msg(rc == 1, "exit %d:\n%s", rc, out);
    ck_assert_msg(strstr(out, "/nonexistent-dir/x.exr") != NULL, "output lacks the path:\n%s", out);
    ck_assert_msg(strstr(out, "No such file or directory") != NULL, "output lacks why:\n%s", out);
    /* refused before rendering: no render summary was printed */
    ck_assert_msg(strstr(out, "samples/s") == NULL, "rendered before checking the output:\n%s",
                  out);
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
        int rc = run(
            out, sizeof out,
            "render '%s' -o '%s' --spp 40 --granularity 16 --threads %d --seed 9 --progress none",
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
            ck_assert_msg(memcmp(a, b, 16 * 16 * sizeof(float)) == 0, "run %d: channel %s differs",
                          i, img[0]->channel_names[c]);
        }
        ck_assert_str_eq(image_attr(img[i], "vb.seed")->s, "9");
        ck_assert(image_attr(img[i], "vb.total_samples")->d ==
                  image_attr(img[0], "vb.total_samples")->d);
    }
    for (int i = 0; i < 3; i++)
        image_destroy(&img[i]);
}
END_TEST

/* Occurrences of needle in text. */
static int count_in(const char *text, const char *needle)
{
    int n = 0;
    for (const char *at = strstr(text, needle); at; at = strstr(at + 1, needle))
        n++;
    return n;
}

/* The embedded render's workers load a scene once between them: one
 * loads it, the others wait and share it (their log lines say which), and
 * the image is the one worker's, bit for bit. */
START_TEST(embedded_workers_share_scene)
{
    char scene[PATHLEN], exr[2][PATHLEN];
    static char out[OUTLEN];
    tiny_scene(scene, sizeof scene, "cli-share.json", 0);
    const int workers[2] = {1, 3};
    image_t *img[2];
    for (int i = 0; i < 2; i++) {
        char name[64];
        snprintf(name, sizeof name, "cli-share-%d.exr", i);
        tu_tmp_path(exr[i], sizeof exr[i], name);
        int rc = run(out, sizeof out,
                     "render '%s' -o '%s' --spp 40 --granularity 16 --workers %d --threads %d "
                     "--seed 9 --progress none --log-level info",
                     scene, exr[i], workers[i], workers[i]);
        ck_assert_msg(rc == 0, "exit %d:\n%s", rc, out);
        ck_assert_msg(count_in(out, "scene loaded in") == 1, "%d workers, not one load:\n%s",
                      workers[i], out);
        ck_assert_msg(count_in(out, "scene shared with another worker") == workers[i] - 1,
                      "%d workers, not %d shared:\n%s", workers[i], workers[i] - 1, out);
        char err[512];
        ck_assert_msg(image_read_exr(exr[i], &img[i], err, sizeof err) == 0, "%s", err);
    }
    const float *a = image_channel(img[0], "R"), *b = image_channel(img[1], "R");
    ck_assert_ptr_nonnull(a);
    ck_assert_ptr_nonnull(b);
    ck_assert_msg(memcmp(a, b, 16 * 16 * sizeof(float)) == 0, "3 workers' image differs");
    for (int i = 0; i < 2; i++) {
        image_destroy(&img[i]);
        unlink(exr[i]);
    }
}
END_TEST

START_TEST(warning_printed)
{
    char scene[PATHLEN], exr[PATHLEN], png[PATHLEN], out[OUTLEN];
    tiny_scene(scene, sizeof scene, "cli-dark.json", 1);
    tu_tmp_path(exr, sizeof exr, "cli-dark.exr");
    tu_tmp_path(png, sizeof png, "cli-dark.png");
    int rc =
        run(out, sizeof out, "render '%s' -o '%s' --spp 1 --threads 1 --progress none", scene, exr);
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
    int rc = run(out, sizeof out, "render '%s' -o '%s' --spp 4 --threads 2 --progress lines", scene,
                 exr);
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
    a = image_attr(img, "vb.replicates"); /* the default: the variance channel is calibrated */
    ck_assert_ptr_nonnull(a);
    ck_assert_int_eq(a->i, JOB_DEFAULT_REPLICATES);
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

/* ---- a fake master ------------------------------------------------------ */

/* A ROUTER socket on a loopback port, in a thread, answering the client as
 * a script says: the requests it got are kept for the test to check. */
#define FAKE_MAX 64

typedef struct fake_master fake_master_t;
/* Returns the reply (JSON text) to request n (0-based, its JSON text), or
 * NULL to drop it unanswered, as a master that died would; t: seconds
 * since the first request. */
typedef const char *(*fake_script_fn)(fake_master_t *f, int n, const char *json, double t);

struct fake_master {
    void *ctx, *sock;
    char endpoint[64];
    pthread_t thread;
    atomic_int stop;
    fake_script_fn script;
    double first;   /* time of the first request */
    double dropped; /* a script's mark: when it first dropped a request (-1: not yet) */
    pthread_mutex_t lock;
    int count; /* requests received */
    char *json[FAKE_MAX];
    int frames[FAKE_MAX];              /* frames after the JSON */
    unsigned long long hash[FAKE_MAX]; /* FNV-1a over those frames */
};

static double mono_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void *fake_thread(void *arg)
{
    fake_master_t *f = arg;
    while (!atomic_load(&f->stop)) {
        zmq_pollitem_t item = {f->sock, 0, ZMQ_POLLIN, 0};
        if (zmq_poll(&item, 1, 20) <= 0)
            continue;
        /* [identity][empty][json][frames...] */
        zmq_msg_t parts[8];
        int n = 0, more = 1, extra = 0;
        unsigned long long h = 1469598103934665603ULL;
        while (more) {
            zmq_msg_t m;
            zmq_msg_init(&m);
            if (zmq_msg_recv(&m, f->sock, 0) < 0) {
                zmq_msg_close(&m);
                break;
            }
            more = zmq_msg_more(&m);
            if (n >= 3) {
                const unsigned char *d = zmq_msg_data(&m);
                for (size_t k = 0; k < zmq_msg_size(&m); k++)
                    h = (h ^ d[k]) * 1099511628211ULL;
                h = (h ^ 0xff) * 1099511628211ULL; /* frame boundary */
                extra++;
            }
            if (n < 8)
                parts[n++] = m;
            else
                zmq_msg_close(&m);
        }
        if (n < 3) {
            for (int k = 0; k < n; k++)
                zmq_msg_close(&parts[k]);
            continue;
        }
        char *json = strndup(zmq_msg_data(&parts[2]), zmq_msg_size(&parts[2]));
        double t = mono_now();
        pthread_mutex_lock(&f->lock);
        int idx = f->count++;
        if (idx == 0)
            f->first = t;
        t -= f->first;
        if (idx < FAKE_MAX) {
            f->json[idx] = json;
            f->frames[idx] = extra;
            f->hash[idx] = h;
        }
        pthread_mutex_unlock(&f->lock);
        const char *reply = f->script(f, idx, json, t);
        if (idx >= FAKE_MAX)
            free(json);
        if (reply) {
            zmq_send(f->sock, zmq_msg_data(&parts[0]), zmq_msg_size(&parts[0]), ZMQ_SNDMORE);
            zmq_send(f->sock, "", 0, ZMQ_SNDMORE);
            zmq_send(f->sock, reply, strlen(reply), 0);
        }
        for (int k = 0; k < n; k++)
            zmq_msg_close(&parts[k]);
    }
    return NULL;
}

static void fake_start(fake_master_t *f, fake_script_fn script)
{
    memset(f, 0, sizeof *f);
    f->script = script;
    f->dropped = -1;
    pthread_mutex_init(&f->lock, NULL);
    f->ctx = zmq_ctx_new();
    f->sock = zmq_socket(f->ctx, ZMQ_ROUTER);
    ck_assert_ptr_nonnull(f->sock);
    int zero = 0;
    zmq_setsockopt(f->sock, ZMQ_LINGER, &zero, sizeof zero);
    ck_assert_int_eq(zmq_bind(f->sock, "tcp://127.0.0.1:*"), 0);
    size_t len = sizeof f->endpoint;
    ck_assert_int_eq(zmq_getsockopt(f->sock, ZMQ_LAST_ENDPOINT, f->endpoint, &len), 0);
    ck_assert_int_eq(pthread_create(&f->thread, NULL, fake_thread, f), 0);
}

/* Stops the thread; what it received stays for the test until fake_free. */
static void fake_stop(fake_master_t *f)
{
    atomic_store(&f->stop, 1);
    pthread_join(f->thread, NULL);
    zmq_close(f->sock);
    zmq_ctx_term(f->ctx);
    pthread_mutex_destroy(&f->lock);
}

static void fake_free(fake_master_t *f)
{
    for (int i = 0; i < f->count && i < FAKE_MAX; i++)
        free(f->json[i]);
    f->count = 0;
}

/* A loopback endpoint nobody listens on: bound, read back, closed. */
static void dead_endpoint(char *buf, size_t len)
{
    void *ctx = zmq_ctx_new();
    void *s = zmq_socket(ctx, ZMQ_ROUTER);
    ck_assert_int_eq(zmq_bind(s, "tcp://127.0.0.1:*"), 0);
    ck_assert_int_eq(zmq_getsockopt(s, ZMQ_LAST_ENDPOINT, buf, &len), 0);
    zmq_close(s);
    zmq_ctx_term(ctx);
}

static int count_of(const char *text, const char *frag)
{
    int n = 0;
    for (const char *p = strstr(text, frag); p; p = strstr(p + 1, frag))
        n++;
    return n;
}

static const char *running_job = "{\"ok\": true, \"job\": {\"id\": 7, \"state\": \"running\", "
                                 "\"layers\": 4, \"layers_done\": 1, "
                                 "\"samples\": 10, \"max_samples\": 40, \"seconds\": 0.5}}";

/* drops the first request (a reply lost in a restart), answers the rest */
static const char *script_submit(fake_master_t *f, int n, const char *json, double t)
{
    (void)f, (void)json, (void)t;
    return n == 0 ? NULL : "{\"ok\": true, \"job\": 4242, \"duplicate\": true}";
}

/* running for two requests, then silent for 1.5 s from the first request
 * it drops (restarting), then done: counted in requests, not in seconds
 * since the start, so that a slow client sees the same story */
static const char *script_restart(fake_master_t *f, int n, const char *json, double t)
{
    (void)json;
    if (n < 2)
        return running_job;
    if (f->dropped < 0)
        f->dropped = t;
    if (t - f->dropped < 1.5)
        return NULL;
    return "{\"ok\": true, \"job\": {\"id\": 7, \"state\": \"done\", \"layers\": 4, "
           "\"layers_done\": 4, "
           "\"samples\": 40, \"max_samples\": 40, \"seconds\": 2.5, "
           "\"recovered\": \"checkpoint at 1 layers\"}}";
}

static const char *script_cancelled(fake_master_t *f, int n, const char *json, double t)
{
    (void)f, (void)json, (void)t;
    return n < 2 ? running_job
                 : "{\"ok\": true, \"job\": {\"id\": 7, \"state\": \"cancelled\", \"layers\": 4, "
                   "\"layers_done\": 2, \"seconds\": 1, \"error\": \"cancelled by a client\"}}";
}

static const char *script_no_such_job(fake_master_t *f, int n, const char *json, double t)
{
    (void)f, (void)n, (void)json, (void)t;
    return "{\"ok\": false, \"error\": \"status: no such job\"}";
}

static const char *script_delete(fake_master_t *f, int n, const char *json, double t)
{
    (void)f, (void)n, (void)json, (void)t;
    return "{\"ok\": true, \"deleted\": 5}";
}

/* a durable master's notes on a job: status JOB or jobs */
static const char *script_notes(fake_master_t *f, int n, const char *json, double t)
{
    (void)f, (void)n, (void)t;
#define NOTED_JOB                                                                                  \
    "{\"id\": 7, \"state\": \"running\", \"storage_error\": \"state/7.ckpt: No space left on "     \
    "device\", "                                                                                   \
    "\"recovered\": \"checkpoint at 42 layers\"}"
    if (strstr(json, "\"jobs\""))
        return "{\"ok\": true, \"jobs\": [" NOTED_JOB ", {\"id\": 8, \"state\": \"queued\"}]}";
    return "{\"ok\": true, \"job\": " NOTED_JOB "}";
#undef NOTED_JOB
}

START_TEST(timeout_flag_checked)
{
    expect_usage_error("wait 1 --timeout 0", "--timeout");
    expect_usage_error("wait 1 --timeout -3", "--timeout");
    expect_usage_error("wait 1 --timeout abc", "--timeout");
    expect_usage_error("wait 1 --timeout", "--timeout");
    expect_usage_error("submit x.json --timeout nan", "--timeout");
    /* only the commands that retry take it */
    expect_usage_error("status 1 --timeout 5", "--timeout");
}
END_TEST

START_TEST(delete_needs_job)
{
    expect_usage_error("delete", "delete needs a job id");
    expect_usage_error("delete x", "delete needs a job id");
}
END_TEST

/* Nothing listens: wait gives up after --timeout, saying so once per
 * outage, and not as a job failure. */
START_TEST(wait_unreachable)
{
    char ep[64], out[OUTLEN];
    dead_endpoint(ep, sizeof ep);
    double t0 = mono_now();
    int rc = run(out, sizeof out, "wait 3 --master %s --timeout 2 --progress none", ep);
    double took = mono_now() - t0;
    ck_assert_msg(rc == 1, "exit %d:\n%s", rc, out);
    ck_assert_msg(strstr(out, "unreachable for 2 s; job 3 may still be running"),
                  "no timeout message:\n%s", out);
    ck_assert_msg(count_of(out, "not answering; retrying (up to 2 s)") == 1,
                  "want one outage line:\n%s", out);
    ck_assert_msg(!strstr(out, "cancelled") && !strstr(out, "failed"),
                  "reads as a job failure:\n%s", out);
    ck_assert_msg(took >= 1.5, "gave up after %.2f s, before --timeout", took);
}
END_TEST

/* The first submit's reply is lost; the retry carries the same request id
 * and frames, and the job id the master answers is printed. */
START_TEST(submit_retries_same_request)
{
    char scene[PATHLEN], out[OUTLEN];
    tiny_scene(scene, sizeof scene, "cli-fake-submit.json", 0);
    fake_master_t f;
    fake_start(&f, script_submit);
    int rc = run(out, sizeof out, "submit '%s' --spp 8 --master %s --timeout 5", scene, f.endpoint);
    fake_stop(&f);
    ck_assert_msg(rc == 0, "exit %d:\n%s", rc, out);
    ck_assert_msg(strstr(out, "4242\n") != NULL, "job id not printed:\n%s", out);
    ck_assert_msg(strstr(out, "not answering; retrying") != NULL, "outage not reported:\n%s", out);
    ck_assert_int_eq(f.count, 2);
    char ids[2][80];
    for (int i = 0; i < 2; i++) {
        cJSON *req = cJSON_Parse(f.json[i]);
        ck_assert_ptr_nonnull(req);
        ck_assert_str_eq(cJSON_GetObjectItemCaseSensitive(req, "cmd")->valuestring, "submit");
        const cJSON *id = cJSON_GetObjectItemCaseSensitive(req, "request_id");
        ck_assert_msg(cJSON_IsString(id), "request %d has no request_id: %s", i, f.json[i]);
        snprintf(ids[i], sizeof ids[i], "%s", id->valuestring);
        cJSON_Delete(req);
        ck_assert_uint_eq(strlen(ids[i]), 32);
        for (int k = 0; k < 32; k++)
            ck_assert_msg(isxdigit((unsigned char)ids[i][k]), "request_id %s is not hex", ids[i]);
    }
    ck_assert_str_eq(ids[0], ids[1]);
    ck_assert_str_eq(f.json[0], f.json[1]);
    ck_assert_int_eq(f.frames[0], 1); /* the scene JSON, no meshes */
    ck_assert_int_eq(f.frames[1], f.frames[0]);
    ck_assert(f.hash[0] == f.hash[1]);
    fake_free(&f);
    /* a second submit is another request */
    fake_start(&f, script_submit);
    rc = run(out, sizeof out, "submit '%s' --master %s --timeout 5", scene, f.endpoint);
    fake_stop(&f);
    ck_assert_msg(rc == 0, "exit %d:\n%s", rc, out);
    ck_assert_int_eq(f.count, 2);
    ck_assert_msg(strstr(f.json[0], ids[0]) == NULL, "two submits share request id %s", ids[0]);
    fake_free(&f);
}
END_TEST

/* The master goes quiet for 1.5 s (a restart) and comes back: wait carries
 * on and ends with the job done, exit 0. */
START_TEST(wait_outlasts_restart)
{
    char out[OUTLEN];
    fake_master_t f;
    fake_start(&f, script_restart);
    int rc = run(out, sizeof out, "wait 7 --master %s --timeout 10 --progress lines", f.endpoint);
    fake_stop(&f);
    ck_assert_msg(rc == 0, "exit %d:\n%s", rc, out);
    ck_assert_msg(count_of(out, "not answering; retrying (up to 10 s)") == 1,
                  "want one outage line:\n%s", out);
    ck_assert_msg(strstr(out, "done in") != NULL, "no end of progress:\n%s", out);
    ck_assert_msg(strstr(out, "job 7: recovered from checkpoint at 1 layers") != NULL,
                  "recovery not shown:\n%s", out);
    for (int i = 0; i < f.count && i < FAKE_MAX; i++)
        ck_assert_msg(strstr(f.json[i], "\"cmd\":\"status\"") && strstr(f.json[i], "\"job\":7"),
                      "request %s", f.json[i]);
    ck_assert_msg(f.count >= 4, "only %d requests", f.count);
    fake_free(&f);
}
END_TEST

START_TEST(wait_cancelled_fails)
{
    char out[OUTLEN];
    fake_master_t f;
    fake_start(&f, script_cancelled);
    int rc = run(out, sizeof out, "wait 7 --master %s --progress none", f.endpoint);
    fake_stop(&f);
    ck_assert_msg(rc == 1, "exit %d:\n%s", rc, out);
    ck_assert_msg(strstr(out, "job 7 cancelled: cancelled by a client") != NULL, "no reason:\n%s",
                  out);
    ck_assert_msg(strstr(out, "unreachable") == NULL, "reads as an outage:\n%s", out);
    fake_free(&f);
}
END_TEST

/* A master that restarted without the job: a real error, no retries. */
START_TEST(wait_no_such_job)
{
    char out[OUTLEN];
    fake_master_t f;
    fake_start(&f, script_no_such_job);
    int rc = run(out, sizeof out, "wait 7 --master %s --progress none", f.endpoint);
    fake_stop(&f);
    ck_assert_msg(rc == 1, "exit %d:\n%s", rc, out);
    ck_assert_msg(strstr(out, "job 7: status: no such job") != NULL, "no message:\n%s", out);
    ck_assert_int_eq(f.count, 1);
    fake_free(&f);
}
END_TEST

START_TEST(status_shows_notes)
{
    char out[OUTLEN];
    fake_master_t f;
    fake_start(&f, script_notes);
    char cmd[CMDLEN];
    snprintf(cmd, sizeof cmd, "{ '%s' status 7 --master %s 2>/dev/null; }", tu_bin(), f.endpoint);
    int rc = tu_run(cmd, out, sizeof out);
    ck_assert_msg(rc == 0, "exit %d:\n%s", rc, out);
    cJSON *st = cJSON_Parse(out); /* stdout stays JSON */
    ck_assert_msg(st != NULL, "stdout is not JSON:\n%s", out);
    cJSON_Delete(st);
    rc = run(out, sizeof out, "status 7 --master %s", f.endpoint);
    ck_assert_msg(rc == 0, "exit %d:\n%s", rc, out);
    ck_assert_msg(strstr(out, "job 7: storage error: state/7.ckpt: No space left on device") &&
                      strstr(out, "job 7: recovered from checkpoint at 42 layers"),
                  "notes not shown:\n%s", out);
    rc = run(out, sizeof out, "jobs --master %s", f.endpoint);
    fake_stop(&f);
    ck_assert_msg(rc == 0, "exit %d:\n%s", rc, out);
    ck_assert_msg(count_of(out, "storage error: ") == 1 && count_of(out, "recovered from ") == 1,
                  "jobs does not mark the job once:\n%s", out);
    fake_free(&f);
}
END_TEST

START_TEST(delete_sends_request)
{
    char out[OUTLEN];
    fake_master_t f;
    fake_start(&f, script_delete);
    int rc = run(out, sizeof out, "delete 5 --master %s", f.endpoint);
    fake_stop(&f);
    ck_assert_msg(rc == 0, "exit %d:\n%s", rc, out);
    ck_assert_msg(strstr(out, "deleted job 5") != NULL, "result not printed:\n%s", out);
    ck_assert_int_eq(f.count, 1);
    cJSON *req = cJSON_Parse(f.json[0]);
    ck_assert_ptr_nonnull(req);
    ck_assert_int_eq(cJSON_GetArraySize(req), 2);
    ck_assert_str_eq(cJSON_GetObjectItemCaseSensitive(req, "cmd")->valuestring, "delete");
    ck_assert_double_eq(cJSON_GetObjectItemCaseSensitive(req, "job")->valuedouble, 5);
    cJSON_Delete(req);
    ck_assert_int_eq(f.frames[0], 0);
    fake_free(&f);
}
END_TEST

/* ---- suite -------------------------------------------------------------- */

/* ---- interrupts, --version, --log-level ----------------------------------- */

static const char *bin_path(char *buf, size_t len, const char *name)
{
    const char *dir = getenv("VB_BINDIR");
    snprintf(buf, len, "%s/%s", dir && *dir ? dir : "bin", name);
    return buf;
}

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void sleep_ms(long ms)
{
    struct timespec ts = {ms / 1000, (ms % 1000) * 1000000L};
    nanosleep(&ts, NULL);
}

/* Starts vbrender with argv (argv[0] included) and its stdout and stderr in
 * the file log, with SIGINT and SIGTERM at their defaults and unblocked,
 * as a shell would start it in the foreground. */
static pid_t spawn_logged(const char *log, char *const argv[])
{
    /* emptied here, not in the child: the caller reads it next, and must
     * not find the last run's lines there */
    int fd = open(log, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    ck_assert_msg(fd >= 0, "cannot create %s", log);
    pid_t pid = fork();
    ck_assert_int_ge(pid, 0);
    if (pid == 0) {
        dup2(fd, STDOUT_FILENO);
        dup2(fd, STDERR_FILENO);
        close(fd);
        signal(SIGINT, SIG_DFL);
        signal(SIGTERM, SIG_DFL);
        sigset_t none;
        sigemptyset(&none);
        sigprocmask(SIG_SETMASK, &none, NULL);
        execv(tu_bin(), argv);
        _exit(127);
    }
    close(fd);
    return pid;
}

/* The file's text (up to len - 1 bytes) into buf. */
static const char *read_text(const char *path, char *buf, size_t len)
{
    buf[0] = '\0';
    FILE *f = fopen(path, "rb");
    if (f) {
        size_t n = fread(buf, 1, len - 1, f);
        buf[n] = '\0';
        fclose(f);
    }
    return buf;
}

/* pid's exit status (128 + the signal when one ended it), or -1 when it
 * was still running after timeout_s (then it is killed). */
static int wait_exit(pid_t pid, double timeout_s)
{
    int st;
    for (double end = now_s() + timeout_s; now_s() < end; sleep_ms(10)) {
        pid_t r = waitpid(pid, &st, WNOHANG);
        ck_assert_int_ge(r, 0);
        if (r == pid)
            return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
    }
    kill(pid, SIGKILL);
    waitpid(pid, &st, 0);
    return -1;
}

/* A render of 8000 layers (256000 spp, uniform), interrupted once its
 * progress bar (redrawn at every look at the job) shows the first layer
 * done: the test waits for that event, not for a time, and the render has
 * 7999 layers to go. */
#define LONG_RENDER_SPP 256000
static pid_t start_long_render(const char *scene, const char *exr, const char *log)
{
    char spp[16];
    snprintf(spp, sizeof spp, "%d", LONG_RENDER_SPP);
    char *const argv[] = {"vbrender",   "render", (char *)scene, "-o", (char *)exr,  "--spp", spp,
                          "--adaptive", "none",   "--threads",   "2",  "--progress", "bar",   NULL};
    return spawn_logged(log, argv);
}

/* Whether the render's progress (in the file) came to show a layer done
 * within timeout_s: "layer N/M" with N > 0. */
static int wait_for_layer(const char *path, double timeout_s)
{
    static char buf[OUTLEN];
    for (double end = now_s() + timeout_s; now_s() < end; sleep_ms(5)) {
        read_text(path, buf, sizeof buf);
        for (const char *p = strstr(buf, "layer "); p; p = strstr(p + 1, "layer "))
            if (atoi(p + 6) > 0)
                return 1;
    }
    return 0;
}

/* Whether sig is pending for pid (sent, not yet taken by the process). */
static int signal_pending(pid_t pid, int sig)
{
    char path[64], line[256];
    snprintf(path, sizeof path, "/proc/%ld/status", (long)pid);
    FILE *f = fopen(path, "r");
    int pending = 0;
    while (f && fgets(line, sizeof line, f)) {
        unsigned long long mask;
        if ((sscanf(line, "ShdPnd: %llx", &mask) == 1 ||
             sscanf(line, "SigPnd: %llx", &mask) == 1) &&
            (mask >> (sig - 1) & 1))
            pending = 1;
    }
    if (f)
        fclose(f);
    return pending;
}

START_TEST(interrupt_writes_partial)
{
    char scene[PATHLEN], exr[PATHLEN], log[PATHLEN], err[1024];
    static char out[OUTLEN];
    tiny_scene(scene, sizeof scene, "cli-interrupt.json", 0);
    tu_tmp_path(exr, sizeof exr, "cli-interrupt.exr");
    tu_tmp_path(log, sizeof log, "cli-interrupt.log");
    unlink(exr);
    pid_t pid = start_long_render(scene, exr, log);
    int progressed = wait_for_layer(log, 60);
    kill(pid, SIGINT);
    int rc = wait_exit(pid, 60);
    read_text(log, out, sizeof out);
    ck_assert_msg(progressed, "no layer done within 60 s:\n%s", out);
    ck_assert_msg(rc == 130, "exit %d, want 130:\n%s", rc, out);
    ck_assert_msg(strstr(out, "interrupted: wrote partial image") && strstr(out, exr),
                  "no partial-image line:\n%s", out);
    image_t *img = NULL;
    ck_assert_msg(image_read_exr(exr, &img, err, sizeof err) == 0, "%s", err);
    const image_attr_t *a = image_attr(img, "vb.partial");
    ck_assert_msg(a && a->type == IMAGE_ATTR_INT && a->i == 1, "vb.partial missing or not 1");
    const image_attr_t *done = image_attr(img, "vb.layers_done"),
                       *all = image_attr(img, "vb.layers");
    ck_assert_ptr_nonnull(done);
    ck_assert_ptr_nonnull(all);
    ck_assert_int_eq(all->i, LONG_RENDER_SPP / 32);
    ck_assert_msg(done->i >= 1 && done->i < all->i, "%d of %d layers", done->i, all->i);
    double total = image_attr(img, "vb.total_samples")->d, sum = 0;
    ck_assert_msg(total > 0 && total < (double)LONG_RENDER_SPP * 16 * 16, "vb.total_samples %g",
                  total);
    const float *samples = image_channel(img, "samples");
    for (int i = 0; i < 16 * 16; i++)
        sum += samples[i];
    ck_assert_msg(sum == total, "samples channel sums to %g, header says %g", sum, total);
    image_destroy(&img);
    unlink(exr);
}
END_TEST

/* The second interrupt exits at once (saying so), without the image the
 * first one asked for. It is sent once the first has been taken (no longer
 * pending: two pending at once would be one); if the render had written
 * its image and was on its way out by then, the try proves nothing and is
 * made again. */
START_TEST(second_interrupt_exits_at_once)
{
    char scene[PATHLEN], exr[PATHLEN], log[PATHLEN];
    static char out[OUTLEN];
    tiny_scene(scene, sizeof scene, "cli-interrupt2.json", 0);
    tu_tmp_path(exr, sizeof exr, "cli-interrupt2.exr");
    tu_tmp_path(log, sizeof log, "cli-interrupt2.log");
    for (int tries = 0;; tries++) {
        ck_assert_msg(tries < 5, "the second interrupt came after the image every time:\n%s", out);
        pid_t pid = start_long_render(scene, exr, log);
        int progressed = wait_for_layer(log, 60);
        kill(pid, SIGINT);
        for (double end = now_s() + 60; signal_pending(pid, SIGINT) && now_s() < end;)
            sleep_ms(1);
        kill(pid, SIGINT);
        int rc = wait_exit(pid, 60);
        read_text(log, out, sizeof out);
        ck_assert_msg(progressed, "no layer done within 60 s:\n%s", out);
        ck_assert_msg(rc == 130, "exit %d, want 130:\n%s", rc, out);
        if (strstr(out, "interrupted again: exiting at once"))
            break;
        ck_assert_msg(strstr(out, "interrupted: wrote partial image"),
                      "neither exited at once nor wrote the image:\n%s", out);
    }
    unlink(exr);
}
END_TEST

/* Every binary prints the same build id as "PROGRAM BUILD". */
START_TEST(version_everywhere)
{
    static const char *const names[] = {"vbrender", "vbrender-master", "vbrender-worker"};
    char build[3][256];
    for (int i = 0; i < 3; i++) {
        char path[PATHLEN], cmd[CMDLEN], out[OUTLEN];
        snprintf(cmd, sizeof cmd, "'%s' --version", bin_path(path, sizeof path, names[i]));
        int rc = tu_run(cmd, out, sizeof out);
        ck_assert_msg(rc == 0, "%s: exit %d:\n%s", cmd, rc, out);
        size_t n = strlen(names[i]);
        ck_assert_msg(strncmp(out, names[i], n) == 0 && out[n] == ' ', "%s printed:\n%s", cmd, out);
        ck_assert_msg(sscanf(out + n + 1, "%255s", build[i]) == 1, "%s printed:\n%s", cmd, out);
        ck_assert_msg(strncmp(build[i], "vbrender-p", 10) == 0, "build id '%s'", build[i]);
        ck_assert_str_eq(build[i], build[0]);
    }
}
END_TEST

/* --log-level: a bad level is a usage error naming the flag, for every
 * binary; render's embedded daemons log per task at debug only. */
START_TEST(log_level_flag)
{
    static const char *const names[] = {"vbrender-master", "vbrender-worker"};
    char path[PATHLEN], cmd[CMDLEN], scene[PATHLEN], exr[PATHLEN];
    static char out[OUTLEN];
    for (int i = 0; i < 2; i++) {
        snprintf(cmd, sizeof cmd, "'%s' --log-level loud --master tcp://127.0.0.1:1",
                 bin_path(path, sizeof path, names[i]));
        int rc = tu_run(cmd, out, sizeof out);
        ck_assert_msg(rc == 2, "%s: exit %d, want 2:\n%s", cmd, rc, out);
        ck_assert_msg(strstr(out, "--log-level") && strstr(out, "loud"), "%s:\n%s", cmd, out);
    }
    tiny_scene(scene, sizeof scene, "cli-loglevel.json", 0);
    tu_tmp_path(exr, sizeof exr, "cli-loglevel.exr");
    char args[CMDLEN];
    snprintf(args, sizeof args, "render '%s' -o '%s' --log-level loud", scene, exr);
    expect_usage_error(args, "--log-level");
    int rc = run(out, sizeof out, "render '%s' -o '%s' --spp 4 --progress none --log-level debug",
                 scene, exr);
    ck_assert_msg(rc == 0, "exit %d:\n%s", rc, out);
    ck_assert_msg(strstr(out, "issued to") && strstr(out, "master: stopped"), "no debug lines:\n%s",
                  out);
    rc = run(out, sizeof out, "render '%s' -o '%s' --spp 4 --progress none --log-level info", scene,
             exr);
    ck_assert_msg(rc == 0, "exit %d:\n%s", rc, out);
    ck_assert_msg(!strstr(out, "issued to") && strstr(out, "master: stopped"),
                  "info shows debug lines, or none:\n%s", out);
    rc = run(out, sizeof out, "render '%s' -o '%s' --spp 4 --progress none --log-level error",
             scene, exr);
    ck_assert_msg(rc == 0 && !strstr(out, "master:"), "exit %d, lines at error:\n%s", rc, out);
    unlink(exr);
}
END_TEST

/* ---- Mitsuba scene files ------------------------------------------------ */

/* render takes a Mitsuba file and its -D parameters */
START_TEST(mitsuba_render)
{
    char scene[PATHLEN], exr[PATHLEN];
    static char out[OUTLEN];
    tu_root_path(scene, sizeof scene, "scenes/mitsuba/cornell-box.xml");
    tu_tmp_path(exr, sizeof exr, "cli-mitsuba.exr");
    unlink(exr);
    int rc = run(out, sizeof out,
                 "render '%s' -D res=12 -Dspp=8 -o '%s' --threads 2 --progress none", scene, exr);
    ck_assert_msg(rc == 0, "exit %d:\n%s", rc, out);
    ck_assert_msg(strstr(out, "12x12") && strstr(out, "8 spp"), "summary lacks size/spp:\n%s", out);
    ck_assert_msg(file_exists(exr), "%s missing", exr);
    /* -D belongs to Mitsuba files; a bad one is a usage error */
    rc = run(out, sizeof out, "render '%s' -D nothing --progress none", scene);
    ck_assert_msg(rc == 2 && strstr(out, "-D needs name=value"), "exit %d:\n%s", rc, out);
    char json[PATHLEN];
    tu_root_path(json, sizeof json, "scenes/cornell-box.json");
    rc = run(out, sizeof out, "render '%s' -D spp=4 --progress none", json);
    ck_assert_msg(rc == 2 && strstr(out, "not of"), "exit %d:\n%s", rc, out);
    unlink(exr);
}
END_TEST

/* a plugin we do not render: exit 1, the file, the line, the plugin */
START_TEST(mitsuba_refused)
{
    char path[PATHLEN], out[OUTLEN], want[PATHLEN + 64];
    tu_write_tmp(path, sizeof path, "cli-hair.xml",
                 "<scene version=\"3.0.0\">\n"
                 "  <sensor type=\"perspective\"><float name=\"fov\" value=\"40\"/>"
                 "<film type=\"hdrfilm\"><rfilter type=\"box\"/></film></sensor>\n"
                 "  <shape type=\"cube\"><bsdf type=\"hair\"/></shape>\n"
                 "</scene>\n");
    int rc = run(out, sizeof out, "render '%s' --progress none", path);
    ck_assert_msg(rc == 1, "exit %d:\n%s", rc, out);
    snprintf(want, sizeof want, "%s:3: bsdf type \"hair\" is not supported (supported: ", path);
    ck_assert_msg(strstr(out, want) != NULL, "output lacks %s:\n%s", want, out);
}
END_TEST

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
    tcase_add_test(tc, mitsuba_refused);
    suite_add_tcase(su, tc);

    tc = tcase_create("render");
    tcase_set_timeout(tc, 120);
    tcase_add_test(tc, tiny_render);
    tcase_add_test(tc, mitsuba_render);
    tcase_add_test(tc, default_output_and_flags);
    tcase_add_test(tc, deterministic_exr);
    tcase_add_test(tc, version_everywhere);
    tcase_add_test(tc, log_level_flag);
    tcase_add_test(tc, embedded_workers_share_scene);
    suite_add_tcase(su, tc);

    tc = tcase_create("interrupt");
    tcase_set_timeout(tc, 150);
    tcase_add_test(tc, interrupt_writes_partial);
    tcase_add_test(tc, second_interrupt_exits_at_once);
    suite_add_tcase(su, tc);

    tc = tcase_create("master");
    tcase_set_timeout(tc, 30);
    tcase_add_test(tc, timeout_flag_checked);
    tcase_add_test(tc, delete_needs_job);
    tcase_add_test(tc, wait_unreachable);
    tcase_add_test(tc, submit_retries_same_request);
    tcase_add_test(tc, wait_outlasts_restart);
    tcase_add_test(tc, wait_cancelled_fails);
    tcase_add_test(tc, wait_no_such_job);
    tcase_add_test(tc, status_shows_notes);
    tcase_add_test(tc, delete_sends_request);
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
