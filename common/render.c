/* render.c - see render.h. */
#include "render.h"
#include "vberr.h"

#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

/* A batch of pixels one thread takes at a time: about RENDER_BATCH_SAMPLES
 * samples, clamped to a pixel count range. */
#define RENDER_BATCH_SAMPLES 4096
#define RENDER_BATCH_MIN_PIXELS 16
#define RENDER_BATCH_MAX_PIXELS 1024
#define RENDER_PROGRESS_MS 100 /* how often the progress line is redrawn */

typedef struct job {
    const tracer_t *tracer;
    film_t *film;
    const render_settings_t *s;
    uint32_t layers;
    size_t npix;
    size_t batch_pixels;
    size_t batch_count;
    pthread_barrier_t barrier;
    atomic_size_t next_batch;     /* of the current layer */
    atomic_uint_fast64_t samples; /* progress, read by the monitor */
    atomic_uint_fast64_t rays;
    atomic_int running; /* worker threads not finished */
    atomic_int failed;
    pthread_mutex_t gate_lock; /* workers wait here until the barrier */
    pthread_cond_t gate;       /* is sized to the threads that started */
    int gate_open;
    pthread_cond_t finished; /* the last worker wakes the monitor */
    char err[VB_ERR_LEN];    /* written once by the first failing thread */
    pthread_mutex_t err_lock;
} job_t;

typedef struct worker_arg {
    job_t *job;
    int index;
} worker_arg_t;

static double now_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

const char *render_si(double v, char *buf, size_t len)
{
    if (v >= 1e9)
        snprintf(buf, len, "%.2fG", v / 1e9);
    else if (v >= 1e6)
        snprintf(buf, len, "%.2fM", v / 1e6);
    else if (v >= 1e3)
        snprintf(buf, len, "%.1fk", v / 1e3);
    else
        snprintf(buf, len, "%.0f", v);
    return buf;
}

static void *worker_main(void *argp)
{
    worker_arg_t *arg = argp;
    job_t *job = arg->job;
    const render_settings_t *s = job->s;
    tracer_task_t *tasks = malloc(job->batch_pixels * sizeof *tasks);
    tracer_result_t *results = malloc(job->batch_pixels * sizeof *results);
    if (!tasks || !results)
        atomic_store(&job->failed, 1);
    pthread_mutex_lock(&job->gate_lock);
    while (!job->gate_open)
        pthread_cond_wait(&job->gate, &job->gate_lock);
    pthread_mutex_unlock(&job->gate_lock);
    for (uint32_t layer = 0; layer < job->layers; layer++) {
        uint64_t first = (uint64_t)layer * s->granularity;
        uint32_t take =
            (uint32_t)((uint64_t)s->spp - first < s->granularity ? (uint64_t)s->spp - first
                                                                 : s->granularity);
        for (;;) {
            if (atomic_load(&job->failed))
                break;
            size_t b = atomic_fetch_add(&job->next_batch, 1);
            if (b >= job->batch_count)
                break;
            size_t p0 = b * job->batch_pixels;
            size_t n = job->npix - p0 < job->batch_pixels ? job->npix - p0 : job->batch_pixels;
            for (size_t i = 0; i < n; i++) {
                tasks[i].pixel = (uint32_t)(p0 + i);
                tasks[i].sample_count = take;
                tasks[i].first_sample = first;
                film_prior(job->film, &tasks[i]);
            }
            tracer_stats_t st = {0, 0};
            char err[VB_ERR_LEN];
            if (tracer_trace(job->tracer, &s->tracer, tasks, n, results, &st, err, sizeof err) <
                0) {
                pthread_mutex_lock(&job->err_lock);
                if (!atomic_load(&job->failed))
                    snprintf(job->err, sizeof job->err, "%s", err);
                atomic_store(&job->failed, 1);
                pthread_mutex_unlock(&job->err_lock);
                break;
            }
            for (size_t i = 0; i < n; i++)
                film_merge(job->film, &results[i]);
            atomic_fetch_add(&job->samples, st.samples);
            atomic_fetch_add(&job->rays, st.rays);
        }
        /* The layer is complete when every thread has passed here; one of
         * them resets the batch counter, and a second wait keeps the others
         * from taking batches of the next layer before the reset. */
        if (pthread_barrier_wait(&job->barrier) == PTHREAD_BARRIER_SERIAL_THREAD)
            atomic_store(&job->next_batch, 0);
        pthread_barrier_wait(&job->barrier);
    }
    free(tasks);
    free(results);
    pthread_mutex_lock(&job->gate_lock);
    if (atomic_fetch_sub(&job->running, 1) == 1)
        pthread_cond_signal(&job->finished);
    pthread_mutex_unlock(&job->gate_lock);
    return NULL;
}

static int check_settings(const render_settings_t *s, char *err, size_t errlen)
{
    if (s->spp == 0) {
        snprintf(err, errlen, "spp must be at least 1");
        return -1;
    }
    if (s->granularity < 1 || s->granularity > TRACER_MAX_TASK_SAMPLES) {
        snprintf(err, errlen, "granularity must be 1..%d", TRACER_MAX_TASK_SAMPLES);
        return -1;
    }
    if (s->threads < 1 || s->threads > RENDER_MAX_THREADS) {
        snprintf(err, errlen, "threads must be 1..%d", RENDER_MAX_THREADS);
        return -1;
    }
    return 0;
}

static void job_init(job_t *job, const tracer_t *tracer, film_t *film, const render_settings_t *s)
{
    memset(job, 0, sizeof *job);
    job->tracer = tracer;
    job->film = film;
    job->s = s;
    job->layers = (uint32_t)(((uint64_t)s->spp + s->granularity - 1) / s->granularity);
    job->npix = (size_t)film->width * (size_t)film->height;
    /* A batch of about 4096 samples: a few milliseconds of work, small
     * enough that the layer's tail is short, large enough to amortise. */
    size_t bp = RENDER_BATCH_SAMPLES / (s->granularity < s->spp ? s->granularity : s->spp);
    job->batch_pixels = bp < RENDER_BATCH_MIN_PIXELS   ? RENDER_BATCH_MIN_PIXELS
                        : bp > RENDER_BATCH_MAX_PIXELS ? RENDER_BATCH_MAX_PIXELS
                                                       : bp;
    job->batch_count = (job->npix + job->batch_pixels - 1) / job->batch_pixels;
    atomic_init(&job->next_batch, 0);
    atomic_init(&job->samples, 0);
    atomic_init(&job->rays, 0);
    atomic_init(&job->running, s->threads);
    atomic_init(&job->failed, 0);
    pthread_mutex_init(&job->err_lock, NULL);
    pthread_mutex_init(&job->gate_lock, NULL);
    pthread_cond_init(&job->gate, NULL);
    pthread_cond_init(&job->finished, NULL);
}

static void job_cleanup(job_t *job)
{
    pthread_barrier_destroy(&job->barrier);
    pthread_mutex_destroy(&job->err_lock);
    pthread_mutex_destroy(&job->gate_lock);
    pthread_cond_destroy(&job->gate);
    pthread_cond_destroy(&job->finished);
}

/* Starts the threads, then opens the gate once the barrier is sized to the
 * threads that did start. Returns how many started. */
static int start_threads(job_t *job, pthread_t *threads, worker_arg_t *args)
{
    int started = 0;
    for (int i = 0; i < job->s->threads; i++) {
        args[i].job = job;
        args[i].index = i;
        if (pthread_create(&threads[i], NULL, worker_main, &args[i]) != 0)
            break;
        started++;
    }
    /* Fewer threads than asked (resource limits) still render correctly. */
    atomic_store(&job->running, started);
    pthread_barrier_init(&job->barrier, NULL, (unsigned)(started ? started : 1));
    pthread_mutex_lock(&job->gate_lock);
    job->gate_open = 1;
    pthread_cond_broadcast(&job->gate);
    pthread_mutex_unlock(&job->gate_lock);
    if (started == 0) {
        atomic_store(&job->failed, 1);
        snprintf(job->err, sizeof job->err, "cannot start any render thread");
    }
    return started;
}

/* Shows progress until the last thread ends: wakes every
 * RENDER_PROGRESS_MS, or at once when the last worker signals. */
static void monitor(job_t *job, progress_t *prog, double t0)
{
    const double total = (double)job->s->spp * (double)job->npix;
    for (;;) {
        struct timespec until;
        clock_gettime(CLOCK_REALTIME, &until);
        until.tv_nsec += RENDER_PROGRESS_MS * 1000L * 1000L;
        if (until.tv_nsec >= 1000000000L) {
            until.tv_sec++;
            until.tv_nsec -= 1000000000L;
        }
        pthread_mutex_lock(&job->gate_lock);
        if (atomic_load(&job->running) > 0)
            pthread_cond_timedwait(&job->finished, &job->gate_lock, &until);
        int left = atomic_load(&job->running);
        pthread_mutex_unlock(&job->gate_lock);
        if (left == 0)
            return;
        double done = (double)atomic_load(&job->samples), el = now_seconds() - t0;
        char detail[160], a[32], b[32];
        double rate = el > 0 ? done / el : 0;
        double eta = rate > 0 ? (total - done) / rate : 0;
        snprintf(detail, sizeof detail, "%s samples/s, %s rays/s, ETA %.0fs",
                 render_si(rate, a, sizeof a),
                 render_si((double)atomic_load(&job->rays) / (el > 0 ? el : 1), b, sizeof b), eta);
        progress_update(prog, done / total, detail);
    }
}

int render_run(const tracer_t *tracer, film_t *film, const render_settings_t *s,
               render_summary_t *summary, char *err, size_t errlen)
{
    memset(summary, 0, sizeof *summary);
    if (check_settings(s, err, errlen) < 0)
        return -1;
    job_t job;
    job_init(&job, tracer, film, s);
    pthread_t threads[RENDER_MAX_THREADS];
    worker_arg_t args[RENDER_MAX_THREADS];
    double t0 = now_seconds();
    int started = start_threads(&job, threads, args);
    progress_t *prog =
        s->progress_out ? progress_new(s->progress_out, s->progress, "render") : NULL;
    monitor(&job, prog, t0);
    for (int i = 0; i < started; i++)
        pthread_join(threads[i], NULL);
    double elapsed = now_seconds() - t0;
    job_cleanup(&job);

    summary->seconds = elapsed;
    summary->samples = atomic_load(&job.samples);
    summary->rays = atomic_load(&job.rays);
    summary->nonfinite = film_total_nonfinite(film);
    summary->layers = job.layers;
    if (atomic_load(&job.failed)) {
        progress_destroy(&prog);
        snprintf(err, errlen, "%s", job.err[0] ? job.err : "out of memory");
        return -1;
    }
    char detail[64];
    snprintf(detail, sizeof detail, "%.2fs", elapsed);
    progress_finish(prog, detail);
    progress_destroy(&prog);
    return 0;
}
