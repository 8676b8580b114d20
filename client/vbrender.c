/* vbrender.c - the command-line front end.
 *
 *   vbrender render SCENE.json [-o OUT.exr] [--spp N] [--seed S]
 *                  [--threads T] [--integrator path|naive] [--granularity G]
 *                  [--max-depth D] [--progress auto|bar|lines|none]
 *
 * Exit status: 0 done, 1 the work failed (bad scene, I/O), 2 bad usage.
 */
#include <errno.h>
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "film.h"
#include "image.h"
#include "render.h"
#include "scene.h"
#include "tracer.h"

static const char usage_text[] =
    "usage: vbrender render SCENE.json [options]\n"
    "\n"
    "Renders a scene on this machine and writes OUT.exr (channels R, G, B,\n"
    "samples, variance) and a PNG preview beside it (OUT.png).\n"
    "\n"
    "options:\n"
    "  -o, --output FILE.exr     output image (default: SCENE name + .exr)\n"
    "  --spp N                   samples per pixel (default: the scene's)\n"
    "  --seed S                  random seed (default: the scene's)\n"
    "  --threads T               render threads (default: all cores)\n"
    "  --integrator path|naive   path: NEE + MIS; naive: light only when hit\n"
    "  --granularity G           samples per pixel per layer (default 32)\n"
    "  --max-depth D             most path segments (default 0: unlimited)\n"
    "  --progress MODE           auto, bar, lines or none (default auto)\n"
    "  -h, --help                this text\n";

static int usage_error(const char *fmt, const char *arg)
{
    fprintf(stderr, "vbrender: ");
    fprintf(stderr, fmt, arg);
    fprintf(stderr, "\n(run 'vbrender --help' for usage)\n");
    return 2;
}

/* Parses a whole decimal unsigned integer in [lo, hi]. */
static int parse_u64(const char *s, uint64_t lo, uint64_t hi, uint64_t *out)
{
    if (!s || !*s || *s == '-' || *s == '+')
        return -1;
    errno = 0;
    char *end;
    unsigned long long v = strtoull(s, &end, 10);
    if (errno || *end || v < lo || v > hi)
        return -1;
    *out = v;
    return 0;
}

static void replace_extension(const char *path, const char *ext, char *out, size_t len)
{
    snprintf(out, len, "%s", path);
    char *dot = strrchr(out, '.'), *slash = strrchr(out, '/');
    if (dot && (!slash || dot > slash))
        *dot = '\0';
    size_t n = strlen(out);
    snprintf(out + n, len - n, "%s", ext);
}

typedef struct render_args {
    const char *scene;
    const char *output;
    int have_spp, have_seed, have_integrator, have_depth;
    uint64_t spp, seed, threads, granularity, max_depth;
    int integrator;
    progress_mode_t progress;
} render_args_t;

static int parse_render_args(int argc, char **argv, render_args_t *a)
{
    memset(a, 0, sizeof *a);
    long cores = sysconf(_SC_NPROCESSORS_ONLN);
    a->threads = cores > 0 ? (uint64_t)cores : 1;
    if (a->threads > RENDER_MAX_THREADS)
        a->threads = RENDER_MAX_THREADS;
    a->granularity = RENDER_DEFAULT_GRANULARITY;
    a->progress = PROGRESS_AUTO;
    for (int i = 0; i < argc; i++) {
        const char *o = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        int takes = 1;
        if (strcmp(o, "-o") == 0 || strcmp(o, "--output") == 0) {
            if (!v || v[0] == '-')
                return usage_error("%s needs a file name", o);
            a->output = v;
        } else if (strcmp(o, "--spp") == 0) {
            if (parse_u64(v, 1, UINT32_MAX, &a->spp) < 0)
                return usage_error("--spp needs an integer from 1 to 4294967295 (got '%s')", v ? v : "");
            a->have_spp = 1;
        } else if (strcmp(o, "--seed") == 0) {
            if (parse_u64(v, 0, UINT64_MAX, &a->seed) < 0)
                return usage_error("--seed needs a non-negative integer (got '%s')", v ? v : "");
            a->have_seed = 1;
        } else if (strcmp(o, "--threads") == 0) {
            if (parse_u64(v, 1, RENDER_MAX_THREADS, &a->threads) < 0)
                return usage_error("--threads needs an integer from 1 to 256 (got '%s')", v ? v : "");
        } else if (strcmp(o, "--granularity") == 0) {
            if (parse_u64(v, 1, TRACER_MAX_TASK_SAMPLES, &a->granularity) < 0)
                return usage_error("--granularity needs an integer from 1 to 4096 (got '%s')", v ? v : "");
        } else if (strcmp(o, "--max-depth") == 0) {
            if (parse_u64(v, 0, 1000000, &a->max_depth) < 0)
                return usage_error("--max-depth needs an integer from 0 to 1000000 (got '%s')", v ? v : "");
            a->have_depth = 1;
        } else if (strcmp(o, "--integrator") == 0) {
            a->integrator = v ? scene_integrator_from_name(v) : -1;
            if (a->integrator < 0)
                return usage_error("--integrator must be path or naive (got '%s')", v ? v : "");
            a->have_integrator = 1;
        } else if (strcmp(o, "--progress") == 0) {
            if (v && strcmp(v, "auto") == 0)
                a->progress = PROGRESS_AUTO;
            else if (v && strcmp(v, "bar") == 0)
                a->progress = PROGRESS_BAR;
            else if (v && strcmp(v, "lines") == 0)
                a->progress = PROGRESS_LINES;
            else if (v && strcmp(v, "none") == 0)
                a->progress = PROGRESS_NONE;
            else
                return usage_error("--progress must be auto, bar, lines or none (got '%s')", v ? v : "");
        } else if (o[0] == '-' && o[1] != '\0') {
            return usage_error("unknown option '%s'", o);
        } else {
            takes = 0;
            if (a->scene)
                return usage_error("unexpected argument '%s' (one scene file per render)", o);
            a->scene = o;
        }
        i += takes;
    }
    if (!a->scene)
        return usage_error("%s", "render needs a scene file: vbrender render SCENE.json");
    return 0;
}

static int cmd_render(int argc, char **argv)
{
    render_args_t a;
    int rc = parse_render_args(argc, argv, &a);
    if (rc)
        return rc;
    char err[1024], out_exr[4096], out_png[4096];
    if (a.output) {
        snprintf(out_exr, sizeof out_exr, "%s", a.output);
    } else {
        const char *base = strrchr(a.scene, '/');
        replace_extension(base ? base + 1 : a.scene, ".exr", out_exr, sizeof out_exr);
    }
    replace_extension(out_exr, ".png", out_png, sizeof out_png);

    /* Refuse an output we could not write before rendering, not after. */
    char dir[4096];
    snprintf(dir, sizeof dir, "%s", out_exr);
    char *slash = strrchr(dir, '/');
    if (slash)
        *(slash == dir ? slash + 1 : slash) = '\0';
    else
        snprintf(dir, sizeof dir, ".");
    if (access(dir, W_OK) != 0) {
        fprintf(stderr, "vbrender: cannot write %s: folder %s: %s\n", out_exr, dir, strerror(errno));
        return 1;
    }

    scene_t *scene = NULL;
    if (scene_load(a.scene, &scene, err, sizeof err) < 0) {
        fprintf(stderr, "vbrender: %s\n", err);
        return 1;
    }
    for (int i = 0; i < scene->warning_count; i++)
        fprintf(stderr, "vbrender: warning: %s\n", scene->warnings[i]);

    render_settings_t s;
    memset(&s, 0, sizeof s);
    s.spp = a.have_spp ? (uint32_t)a.spp : scene->spp;
    s.tracer.seed = a.have_seed ? a.seed : scene->seed;
    s.tracer.integrator = a.have_integrator ? (scene_integrator_t)a.integrator : scene->integrator;
    s.tracer.max_depth = a.have_depth ? (uint32_t)a.max_depth : scene->max_depth;
    s.granularity = (uint32_t)a.granularity;
    s.threads = (int)a.threads;
    s.progress = a.progress;
    s.progress_out = stderr;

    tracer_t *tracer = NULL;
    film_t *film = NULL;
    image_t *img = NULL;
    rc = 1;
    if (tracer_new(scene, &tracer, err, sizeof err) < 0) {
        fprintf(stderr, "vbrender: %s\n", err);
        goto done;
    }
    film = film_new(scene->camera.width, scene->camera.height);
    if (!film) {
        fprintf(stderr, "vbrender: out of memory for a %dx%d film\n", scene->camera.width,
                scene->camera.height);
        goto done;
    }
    render_summary_t sum;
    if (render_run(tracer, film, &s, &sum, err, sizeof err) < 0) {
        fprintf(stderr, "vbrender: render failed: %s\n", err);
        goto done;
    }
    img = film_to_image(film);
    if (!img) {
        fprintf(stderr, "vbrender: out of memory for the image\n");
        goto done;
    }
    char seed[32];
    snprintf(seed, sizeof seed, "%" PRIu64, s.tracer.seed);
    image_set_string(img, "vb.seed", seed);
    image_set_string(img, "vb.integrator", scene_integrator_name(s.tracer.integrator));
    image_set_double(img, "vb.total_samples", (double)sum.samples);
    image_set_double(img, "vb.render_seconds", sum.seconds);
    image_set_int(img, "vb.spp", (int32_t)(s.spp > INT32_MAX ? INT32_MAX : s.spp));
    image_set_int(img, "vb.granularity", (int32_t)s.granularity);
    image_set_int(img, "vb.max_depth", (int32_t)s.tracer.max_depth);
    image_set_double(img, "vb.nonfinite_samples", (double)sum.nonfinite);
    if (image_write_exr(img, out_exr, err, sizeof err) < 0 ||
        image_write_png(img, out_png, 1.0f, err, sizeof err) < 0) {
        fprintf(stderr, "vbrender: %s\n", err);
        goto done;
    }
    char a1[32], a2[32], a3[32], a4[32];
    double secs = sum.seconds > 0 ? sum.seconds : 1e-9;
    fprintf(stderr,
            "vbrender: %dx%d, %u spp, %s, seed %s, %d threads (%s): %.2f s, %s samples "
            "(%s samples/s), %s rays (%s rays/s), %" PRIu64 " NaN/Inf samples left out\n",
            scene->camera.width, scene->camera.height, s.spp,
            scene_integrator_name(s.tracer.integrator), seed, s.threads, tracer_isa(tracer),
            sum.seconds, render_si((double)sum.samples, a1, sizeof a1),
            render_si((double)sum.samples / secs, a2, sizeof a2),
            render_si((double)sum.rays, a3, sizeof a3), render_si((double)sum.rays / secs, a4, sizeof a4),
            sum.nonfinite);
    printf("%s\n%s\n", out_exr, out_png);
    rc = 0;
done:
    image_destroy(&img);
    film_destroy(&film);
    tracer_destroy(&tracer);
    scene_destroy(&scene);
    return rc;
}

int main(int argc, char **argv)
{
    if (argc < 2) {
        fputs(usage_text, stderr);
        return 2;
    }
    if (strcmp(argv[1], "-h") == 0 || strcmp(argv[1], "--help") == 0 || strcmp(argv[1], "help") == 0) {
        fputs(usage_text, stdout);
        return 0;
    }
    if (strcmp(argv[1], "render") == 0) {
        for (int i = 2; i < argc; i++)
            if (strcmp(argv[i], "-h") == 0 || strcmp(argv[i], "--help") == 0) {
                fputs(usage_text, stdout);
                return 0;
            }
        return cmd_render(argc - 2, argv + 2);
    }
    fprintf(stderr, "vbrender: unknown command '%s' (run 'vbrender --help')\n", argv[1]);
    return 2;
}
