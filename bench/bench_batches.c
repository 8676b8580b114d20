/* bench_batches.c - every layer's per-pixel luminance mean, for studying
 * stopping rules offline (bench/error/target.py).
 *
 *   bench_batches SCENE.json OUT.f64 --layers L [--granularity G] [--seed S]
 *                 [--sampler sobol|independent] [--replicates R] [--threads T]
 *                 [--counts COUNTS.u32] [--summary]
 *
 * Traces layers 0..L-1 of every pixel exactly as a uniform job's tasks do
 * (layer l's first sample as rng_replicate_first_sample places it for the
 * job's replicates, G samples, the job's seed and sampler), so the
 * numbers are the batch means the master's --target-error rule sees, bit for
 * bit. OUT is L x pixels little-endian doubles, layer-major: luminance of the
 * layer's finite samples' mean (0 when none was finite), NaN past a pixel's
 * count. --counts gives each pixel its own number of layers (one uint32 per
 * pixel, at most L; 0 leaves the pixel out). --summary writes, instead of the
 * layers, 3 doubles per pixel: layers traced, mean and sum of squared
 * deviations of the layer means (Welford), for references too deep to keep.
 * Simulating a rule on these costs milliseconds where a render per candidate
 * costs minutes.
 */
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mitsuba.h"
#include "rng.h"
#include "scene.h"
#include "tracer.h"
#include "vmath.h"

typedef struct {
    const tracer_t *tracer;
    tracer_settings_t settings;
    uint32_t npix, layers, granularity, threads, index;
    uint32_t replicates;    /* the job's (default 1: a study passes the master's,
                               JOB_DEFAULT_REPLICATES, to mirror its jobs) */
    const uint32_t *counts; /* per pixel, or NULL: layers for all */
    int summary;
    double *out; /* layers x npix, or 3 x npix with summary */
    int failed;
    char err[256];
} job_t;

static uint32_t pixel_layers(const job_t *j, uint32_t p)
{
    return j->counts ? j->counts[p] : j->layers;
}

static void store(job_t *j, uint32_t layer, const tracer_result_t *r)
{
    double m = r->samples ? vmath_luminance(r->sum[0], r->sum[1], r->sum[2]) / r->samples : 0.0;
    if (!j->summary) {
        j->out[(size_t)layer * j->npix + r->pixel] = m;
        return;
    }
    double *w = j->out + 3 * (size_t)r->pixel; /* Welford: n, mean, M2 */
    double d = m - w[1];
    w[0] += 1;
    w[1] += d / w[0];
    w[2] += d * (m - w[1]);
}

/* Thread `index` takes every threads-th chunk of pixels, each through all
 * its layers: which thread traces a pixel changes no bit of it. */
static void *trace_rows(void *arg)
{
    job_t *j = arg;
    enum { CHUNK = 64 };
    tracer_task_t tasks[CHUNK];
    tracer_result_t results[CHUNK];
    for (uint32_t p0 = j->index * CHUNK; p0 < j->npix; p0 += j->threads * CHUNK) {
        uint32_t end = j->npix - p0 < CHUNK ? j->npix : p0 + CHUNK;
        for (uint32_t layer = 0; layer < j->layers; layer++) {
            uint32_t n = 0;
            memset(tasks, 0, sizeof tasks);
            for (uint32_t p = p0; p < end; p++)
                if (layer < pixel_layers(j, p)) {
                    tasks[n].pixel = p;
                    tasks[n].sample_count = j->granularity;
                    tasks[n].first_sample = rng_replicate_first_sample(
                        (uint64_t)layer * j->granularity, j->granularity, j->replicates);
                    n++;
                }
            if (n == 0)
                break;
            if (tracer_trace(j->tracer, &j->settings, tasks, n, results, NULL, j->err,
                             sizeof j->err) < 0) {
                j->failed = 1;
                return NULL;
            }
            for (uint32_t i = 0; i < n; i++)
                store(j, layer, &results[i]);
        }
    }
    return NULL;
}

static int usage(void)
{
    fprintf(
        stderr,
        "usage: bench_batches SCENE.json OUT.f64 --layers L [--granularity G] "
        "[--seed S] [--sampler sobol|independent] [--replicates R] [--threads T] [--counts FILE] "
        "[--summary]\n");
    return 2;
}

static int parse(int argc, char **argv, job_t *base, const char **scene, const char **out,
                 const char **counts)
{
    if (argc < 3)
        return -1;
    *scene = argv[1];
    *out = argv[2];
    for (int i = 3; i < argc; i += 2) {
        const char *k = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(k, "--summary") == 0) {
            base->summary = 1;
            i--;
            continue;
        }
        if (!v)
            return -1;
        if (strcmp(k, "--counts") == 0)
            *counts = v;
        else if (strcmp(k, "--layers") == 0)
            base->layers = (uint32_t)strtoul(v, NULL, 10);
        else if (strcmp(k, "--replicates") == 0)
            base->replicates = (uint32_t)strtoul(v, NULL, 10);
        else if (strcmp(k, "--granularity") == 0)
            base->granularity = (uint32_t)strtoul(v, NULL, 10);
        else if (strcmp(k, "--seed") == 0)
            base->settings.seed = strtoull(v, NULL, 10);
        else if (strcmp(k, "--threads") == 0)
            base->threads = (uint32_t)strtoul(v, NULL, 10);
        else if (strcmp(k, "--sampler") == 0 && tracer_sampler_from_name(v) >= 0)
            base->settings.sampler = (rng_sampler_t)tracer_sampler_from_name(v);
        else
            return -1;
    }
    if (base->layers == 0 || base->granularity == 0 ||
        base->granularity > TRACER_MAX_TASK_SAMPLES || base->threads == 0 || base->threads > 256 ||
        base->replicates == 0 || base->replicates > RNG_MAX_REPLICATES)
        return -1;
    if (base->settings.sampler == RNG_SAMPLER_INDEPENDENT)
        base->replicates = 1; /* as the master: independent samples need none */
    return 0;
}

/* The per-pixel layer counts, each at most layers; NULL on error. */
static uint32_t *read_counts(const char *path, uint32_t npix, uint32_t layers)
{
    uint32_t *c = malloc((size_t)npix * sizeof *c);
    FILE *f = fopen(path, "rb");
    int ok = c && f && fread(c, sizeof *c, npix, f) == npix && fgetc(f) == EOF;
    for (uint32_t p = 0; ok && p < npix; p++)
        ok = c[p] <= layers;
    if (f)
        fclose(f);
    if (!ok) {
        fprintf(stderr, "bench_batches: %s: expected %u uint32 counts, each <= %u\n", path, npix,
                layers);
        free(c);
        return NULL;
    }
    return c;
}

static int trace_all(const tracer_t *tr, const job_t *base, double *out)
{
    pthread_t th[256];
    job_t jobs[256];
    for (uint32_t t = 0; t < base->threads; t++) {
        jobs[t] = *base;
        jobs[t].tracer = tr;
        jobs[t].index = t;
        jobs[t].out = out;
        pthread_create(&th[t], NULL, trace_rows, &jobs[t]);
    }
    int failed = 0;
    for (uint32_t t = 0; t < base->threads; t++) {
        pthread_join(th[t], NULL);
        if (jobs[t].failed) {
            fprintf(stderr, "bench_batches: %s\n", jobs[t].err);
            failed = 1;
        }
    }
    return failed ? -1 : 0;
}

int main(int argc, char **argv)
{
    job_t base = {.layers = 0, .granularity = 32, .threads = 2, .replicates = 1};
    base.settings.seed = 1;
    base.settings.sampler = RNG_SAMPLER_SOBOL;
    base.settings.integrator = SCENE_INTEGRATOR_PATH;
    const char *scene_path, *out_path, *counts_path = NULL;
    if (parse(argc, argv, &base, &scene_path, &out_path, &counts_path) < 0)
        return usage();
    char err[256];
    scene_t *s = NULL;
    tracer_device_t *dev = NULL;
    tracer_t *tr = NULL;
    if (mitsuba_scene_load(scene_path, &s, err, sizeof err) < 0 ||
        tracer_device_new(&dev, err, sizeof err) < 0 ||
        tracer_new(dev, s, &tr, err, sizeof err) < 0) {
        fprintf(stderr, "bench_batches: %s\n", err);
        tracer_device_destroy(&dev);
        scene_destroy(&s);
        return 1;
    }
    base.settings.integrator = s->integrator;
    base.settings.max_depth = s->max_depth;
    base.npix = s->camera.width * s->camera.height;
    uint32_t *counts = counts_path ? read_counts(counts_path, base.npix, base.layers) : NULL;
    base.counts = counts;
    size_t n = (size_t)(base.summary ? 3 : base.layers) * base.npix;
    double *out = malloc(n * sizeof(double));
    for (size_t i = 0; out && i < n; i++)
        out[i] = base.summary ? 0.0 : NAN;
    int rc = out && (counts || !counts_path) && trace_all(tr, &base, out) == 0 ? 0 : 1;
    FILE *f = rc == 0 ? fopen(out_path, "wb") : NULL;
    if (rc == 0 && (!f || fwrite(out, sizeof(double), n, f) != n)) {
        fprintf(stderr, "bench_batches: cannot write %s\n", out_path);
        rc = 1;
    }
    if (f && fclose(f) != 0)
        rc = 1;
    free(out);
    free(counts);
    tracer_destroy(&tr);
    tracer_device_destroy(&dev);
    scene_destroy(&s);
    return rc;
}
