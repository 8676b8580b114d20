/* persist.c - the master's durable state (master_priv.h, store.h):
 * submissions, checkpoints, final images, and recovery at startup.
 *
 * A submission is written (fsync'd) before its id is answered. Progress is
 * checkpointed every --checkpoint-s by a forked child, which sees the jobs
 * as they were at the fork; when it reports back, the jobs it wrote are
 * marked durable up to that point. An ended job's image and closing status
 * are written the same way, and then its film and bundle leave memory:
 * fetch reads the image from disk.
 *
 * Recovery rebuilds each job from its stored submission through the same
 * steps a client's submission takes, then restores its scheduler from the
 * newest good checkpoint. The scheduler is a pure function of its settings
 * and the results merged in layer order, so the resumed job ends with the
 * image an uninterrupted run gives, bit for bit.
 */
#include <errno.h>
#include <fcntl.h>
#include <float.h>
#include <inttypes.h>
#ifdef __GLIBC__
#include <malloc.h>
#endif
#include <pthread.h>
#include <signal.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "film.h"
#include "image.h"
#include "journal.h"
#include "master_priv.h"

/* ---- fault injection (test builds only) -------------------------------------------- */

/* The fault build fails every state write while the file named by
 * VB_FAULT_FAIL_WRITES_IF exists, as a full disk would. */
static int injected_write_failure(char *err, size_t errlen)
{
#ifdef VB_FAULT_INJECTION
    const char *flag = getenv("VB_FAULT_FAIL_WRITES_IF");
    if (flag && access(flag, F_OK) == 0) {
        snprintf(err, errlen, "No space left on device (injected fault)");
        return -1;
    }
#else
    (void)err;
    (void)errlen;
#endif
    return 0;
}

/* ---- submissions ----------------------------------------------------------------- */

int persist_submission(store_t *store, job_t *j, const void *req, size_t req_size,
                       const submit_frame_t *frames, int nframes, char *err, size_t errlen)
{
    if (injected_write_failure(err, errlen) < 0)
        return -1;
    uint64_t id = store_take_job_id(store, err, errlen);
    if (!id || store_job_dir(store, id, err, errlen) < 0)
        return -1;
    char path[4096];
    store_job_path(store, id, "submit", path, sizeof path);
    store_rec_writer_t *w = malloc(sizeof *w);
    if (!w) {
        snprintf(err, errlen, "out of memory");
        return -1;
    }
    uint32_t n = (uint32_t)nframes;
    int rc = store_rec_begin(w, path, STORE_KIND_SUBMIT);
    rc = rc < 0 ? rc : store_rec_write_block(w, req, req_size);
    rc = rc < 0 ? rc : store_rec_write(w, &n, sizeof n);
    for (int i = 0; rc == 0 && i < nframes; i++)
        rc = store_rec_write_block(w, frames[i].data, frames[i].size);
    rc = rc < 0 ? rc : store_rec_write_block(w, j->owner, strlen(j->owner));
    rc = rc < 0 ? rc : store_rec_commit(w, 0);
    if (rc < 0) {
        snprintf(err, errlen, "%s", w->err);
        store_rec_abort(w);
        /* Unchecked: the failure is already the answer. A directory left
         * has no valid submit record and shows after a restart as an
         * unrecoverable job, which a client may delete. */
        (void)store_job_remove(store, id, NULL, 0);
    }
    free(w);
    if (rc < 0)
        return -1;
    j->id = id;
    return 0;
}

/* ---- what a checkpoint holds beside the scheduler -------------------------------- */

static char *extras_json(const job_t *j, double now)
{
    cJSON *o = cJSON_CreateObject();
    if (!o)
        return NULL;
    cJSON_AddNumberToObject(o, "seconds", job_seconds(j, now));
    cJSON_AddNumberToObject(o, "rays", (double)j->rays);
    cJSON_AddNumberToObject(o, "busy_us", (double)j->busy_us);
    cJSON_AddNumberToObject(o, "reissued", j->reissued);
    cJSON_AddNumberToObject(o, "late_results", (double)j->late_results);
    cJSON_AddNumberToObject(o, "failures", j->failures);
    cJSON_AddNumberToObject(o, "tasks_verified", (double)j->tasks_verified);
    cJSON_AddNumberToObject(o, "verify_mismatches", (double)j->verify_mismatches);
    cJSON_AddNumberToObject(o, "tasks_unverified", (double)j->tasks_unverified);
    if (j->quarantined_n) {
        cJSON *q = cJSON_AddArrayToObject(o, "quarantined");
        for (size_t i = 0; q && i < j->quarantined_n; i++)
            cJSON_AddItemToArray(q, cJSON_CreateString(j->quarantined[i]));
    }
    if (j->series_n) {
        cJSON *arr = cJSON_AddArrayToObject(o, "series");
        for (size_t i = 0; i < j->series_n; i++)
            cJSON_AddItemToArray(arr, cJSON_CreateDoubleArray(j->series + JOB_SERIES_COLUMNS * i,
                                                              JOB_SERIES_COLUMNS));
    }
    char *text = cJSON_PrintUnformatted(o);
    cJSON_Delete(o);
    return text;
}

/* The largest double below 2^64: every double up to it converts to uint64_t. */
#define MAX_U64_DOUBLE 18446744073709549568.0

/* A counter in [0, max], else 0: converting a double beyond its integer
 * type's range is undefined behaviour (found by tests/fuzz_ckpt.c). */
static double num(const cJSON *o, const char *key, double max)
{
    const cJSON *it = cJSON_GetObjectItemCaseSensitive(o, key);
    return cJSON_IsNumber(it) && it->valuedouble >= 0 && it->valuedouble <= max ? it->valuedouble
                                                                                : 0;
}

void persist_apply_extras(job_t *j, const cJSON *o)
{
    j->run_before = num(o, "seconds", DBL_MAX);
    j->rays = (uint64_t)num(o, "rays", MAX_U64_DOUBLE);
    j->busy_us = (uint64_t)num(o, "busy_us", MAX_U64_DOUBLE);
    j->reissued = (uint32_t)num(o, "reissued", UINT32_MAX);
    j->late_results = (uint64_t)num(o, "late_results", MAX_U64_DOUBLE);
    j->failures = (uint32_t)num(o, "failures", UINT32_MAX);
    j->tasks_verified = (uint64_t)num(o, "tasks_verified", MAX_U64_DOUBLE);
    j->verify_mismatches = (uint64_t)num(o, "verify_mismatches", MAX_U64_DOUBLE);
    j->tasks_unverified = (uint64_t)num(o, "tasks_unverified", MAX_U64_DOUBLE);
    const cJSON *who;
    cJSON_ArrayForEach(who, cJSON_GetObjectItemCaseSensitive(o, "quarantined"))
    {
        if (cJSON_IsString(who))
            verify_note_quarantined(j, who->valuestring);
    }
    const cJSON *series = cJSON_GetObjectItemCaseSensitive(o, "series");
    int n = cJSON_IsArray(series) ? cJSON_GetArraySize(series) : 0;
    if (n > 0 && (j->series = calloc((size_t)n * JOB_SERIES_COLUMNS, sizeof(double))) != NULL) {
        j->series_cap = (size_t)n;
        for (const cJSON *pt = series->child; pt; pt = pt->next) {
            if (cJSON_GetArraySize(pt) != JOB_SERIES_COLUMNS)
                continue;
            for (int k = 0; k < JOB_SERIES_COLUMNS; k++) {
                const cJSON *v = cJSON_GetArrayItem(pt, k);
                j->series[JOB_SERIES_COLUMNS * j->series_n + (size_t)k] =
                    cJSON_IsNumber(v) ? v->valuedouble : 0;
            }
            j->series_n++;
        }
    }
}

/* ---- the journal writer thread ------------------------------------------------------ */

/* The event loop seals each job's merged tasks into a commit every
 * --checkpoint-s and hands the framed bytes to this thread, which appends
 * them to the job's journal and fdatasyncs it; the loop collects the
 * outcome at a later tick. The loop never waits on the disk: the mutex is
 * held only to hand a batch over and to see it done. */
typedef struct jw_item {
    uint64_t job;
    char path[4096];
    uint64_t offset; /* the journal's durable size: the write goes there */
    int create;      /* no file yet (a job's first commit): made with this header */
    journal_header_t header;
    uint8_t *data;
    size_t len;
    int failed;
    char err[VB_ERR_LEN];
} jw_item_t;

typedef struct persist_writer {
    pthread_t thread;
    pthread_mutex_t mu;
    pthread_cond_t cv;
    jw_item_t *items;
    size_t n, cap;
    int busy; /* a batch is with the thread or not yet collected */
    int done; /* the thread has finished the batch */
    int stop;
    double cpu_s, wall_s; /* of the last batch */
    uint8_t *bounce;      /* STORE_WRITE_BUF bytes, aligned: O_DIRECT appends */
} persist_writer_t;

static double thread_cpu_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* Appends one job's commits at item->offset: whatever a failed write left
 * past it is cut off first, so the file never holds a torn record before a
 * good one. */
static void jw_write(jw_item_t *it, uint8_t *bounce)
{
    if (injected_write_failure(it->err, sizeof it->err) < 0) {
        it->failed = 1;
        return;
    }
    if (it->create) {
#ifdef VB_FAULT_INJECTION
        /* Test builds only: the master dies before its first state file of
         * the job is renamed into place. */
        if (getenv("VB_FAULT_CRASH_BEFORE_RENAME"))
            kill(getpid(), SIGKILL);
#endif
        if (journal_create(it->path, &it->header, it->err, sizeof it->err) < 0) {
            it->failed = 1;
            return;
        }
        it->offset = JOURNAL_HEADER_SIZE;
    }
    char err[VB_ERR_LEN];
    it->failed = store_append(it->path, it->offset, it->data, it->len, bounce, err, sizeof err) < 0;
    if (it->failed)
        snprintf(it->err, sizeof it->err, "journal: %.900s", err);
}

static void *jw_main(void *arg)
{
    persist_writer_t *w = arg;
    pthread_mutex_lock(&w->mu);
    for (;;) {
        while (!w->stop && !(w->busy && !w->done))
            pthread_cond_wait(&w->cv, &w->mu);
        if (w->busy && !w->done) {
            pthread_mutex_unlock(&w->mu);
            double c0 = thread_cpu_s(), t0 = master_now();
            for (size_t i = 0; i < w->n; i++)
                jw_write(&w->items[i], w->bounce);
            double cpu = thread_cpu_s() - c0, wall = master_now() - t0;
            pthread_mutex_lock(&w->mu);
            w->cpu_s = cpu;
            w->wall_s = wall;
            w->done = 1;
            pthread_cond_broadcast(&w->cv);
            continue;
        }
        if (w->stop)
            break;
    }
    pthread_mutex_unlock(&w->mu);
    return NULL;
}

static persist_writer_t *jw_get(master_t *m)
{
    if (m->writer)
        return m->writer;
    persist_writer_t *w = calloc(1, sizeof *w);
    if (!w)
        return NULL;
    void *bounce = NULL;
    if (posix_memalign(&bounce, STORE_ALIGN, STORE_WRITE_BUF) == 0)
        w->bounce = bounce; /* else the page cache's way */
    pthread_mutex_init(&w->mu, NULL);
    pthread_cond_init(&w->cv, NULL);
    if (pthread_create(&w->thread, NULL, jw_main, w) != 0) {
        free(w->bounce);
        pthread_mutex_destroy(&w->mu);
        pthread_cond_destroy(&w->cv);
        free(w);
        return NULL;
    }
    m->writer = w;
    return w;
}

/* Whether the batch handed over is finished (or none is out). */
static int jw_idle(persist_writer_t *w, int block)
{
    if (!w)
        return 1;
    pthread_mutex_lock(&w->mu);
    while (block && w->busy && !w->done)
        pthread_cond_wait(&w->cv, &w->mu);
    int idle = !w->busy || w->done;
    pthread_mutex_unlock(&w->mu);
    return idle;
}

/* Takes in a finished batch: a written commit is durable; a failed one is
 * given back to its journal, to be written again first. */
static void jw_collect(master_t *m, int block)
{
    persist_writer_t *w = m->writer;
    if (!w || !w->busy || !jw_idle(w, block))
        return;
    m->ckpt_cpu_s += w->cpu_s;
    m->ckpt_wall_s += w->wall_s;
    for (size_t i = 0; i < w->n; i++) {
        jw_item_t *it = &w->items[i];
        job_t *j = job_find(m, it->job);
        if (!j || !j->journal_writing || !j->journal) {
            free(it->data); /* the job was deleted or has ended meanwhile */
            continue;
        }
        j->journal_writing = 0;
        if (it->failed) {
            journal_give_back(j->journal, it->data, it->len);
            snprintf(j->storage_error, sizeof j->storage_error, "%s", it->err);
            master_log_at(m, VBLOG_ERROR,
                          "job %" PRIu64 ": cannot write its state (it keeps running): %s", j->id,
                          it->err);
            continue;
        }
        free(it->data);
        j->storage_error[0] = '\0';
        j->journal_bytes = (it->create ? JOURNAL_HEADER_SIZE : it->offset) + it->len;
        if (it->create)
            m->journal_bytes_written += JOURNAL_HEADER_SIZE;
        j->ckpt_samples = j->journal_samples;
        m->journal_bytes_written += it->len;
        m->journal_commits++;
        m->ckpt_runs++;
    }
    w->n = 0;
    pthread_mutex_lock(&w->mu);
    w->busy = 0;
    w->done = 0;
    pthread_mutex_unlock(&w->mu);
}

/* Seals each running job's merged tasks into a commit (with its counters
 * now) and hands the unwritten commits to the writer thread. */
static void jw_start(master_t *m, double now, int force)
{
    persist_writer_t *w = jw_get(m);
    if (!w || w->busy)
        return;
    for (job_t *j = m->jobs; j; j = j->next) {
        /* a journal as large as its snapshot waits for the compaction
         * (persist_tick): it never exceeds the snapshot by more than one
         * commit */
        if (!j->journal || j->state != JOB_RUNNING || j->need_snapshot || j->in_write ||
            j->journal_writing || j->journal_bytes >= j->snap_bytes)
            continue;
        if (!force && now - j->last_ckpt < m->cfg.checkpoint_s)
            continue;
        if (journal_pending(j->journal) > 0) {
            char *extras = extras_json(j, now);
            if (!extras || journal_seal(j->journal, extras, strlen(extras)) < 0) {
                /* out of memory: a snapshot holds everything */
                j->need_snapshot = 1;
                cJSON_free(extras);
                continue;
            }
            cJSON_free(extras);
        }
        if (journal_unwritten(j->journal) == 0)
            continue;
        if (w->n == w->cap) {
            size_t cap = w->cap ? 2 * w->cap : 8;
            jw_item_t *ni = realloc(w->items, cap * sizeof *ni);
            if (!ni)
                break;
            w->items = ni;
            w->cap = cap;
        }
        jw_item_t *it = &w->items[w->n++];
        memset(it, 0, offsetof(jw_item_t, path));
        it->job = j->id;
        store_job_path(m->store, j->id, "journal", it->path, sizeof it->path);
        it->offset = j->journal_bytes;
        /* generation 0 (no snapshot yet): the file comes with the first commit */
        it->create = j->journal_bytes == 0;
        it->header = (journal_header_t){.version = JOURNAL_VERSION,
                                        .flags = journal_flags(j->journal),
                                        .generation = journal_generation(j->journal),
                                        .job = j->id};
        journal_take_unwritten(j->journal, &it->data, &it->len);
        it->failed = 0;
        it->err[0] = '\0';
        j->journal_writing = 1;
        j->journal_samples = sched_samples_done(j->sched);
        j->last_ckpt = now;
    }
    if (w->n == 0)
        return;
    pthread_mutex_lock(&w->mu);
    w->busy = 1;
    w->done = 0;
    pthread_cond_broadcast(&w->cv);
    pthread_mutex_unlock(&w->mu);
}

void persist_destroy(master_t *m)
{
    persist_writer_t *w = m->writer;
    if (!w)
        return;
    pthread_mutex_lock(&w->mu);
    w->stop = 1;
    pthread_cond_broadcast(&w->cv);
    pthread_mutex_unlock(&w->mu);
    pthread_join(w->thread, NULL);
    for (size_t i = 0; i < w->n; i++)
        free(w->items[i].data);
    free(w->items);
    free(w->bounce);
    pthread_mutex_destroy(&w->mu);
    pthread_cond_destroy(&w->cv);
    free(w);
    m->writer = NULL;
}

/* Generation 0 is the job as sched_new makes it, from its submission: no
 * file. Its journal is compacted, like any, once it holds as many bytes as
 * a snapshot would (sched_save_bytes, and the record's framing). */
static uint64_t generation0_bytes(const job_t *j)
{
    return (uint64_t)sched_save_bytes(j->sched) + 4096;
}

/* Records carry what the job's mode reads (journal.h): pvar for thesis's
 * skip rule, rays for relmse's cost (sched.c, sched_complete); the film
 * and the other statistics need neither. */
static uint32_t persist_journal_flags(const job_t *j)
{
    return (j->adaptive == SCHED_ADAPTIVE_THESIS ? JOURNAL_PVAR : 0) |
           (j->adaptive == SCHED_ADAPTIVE_RELMSE ? JOURNAL_RAYS : 0) |
           (j->sched_cfg.granularity <= 255 ? JOURNAL_NF8 : 0);
}

void persist_note(master_t *m, job_t *j, uint64_t task_id, const tracer_result_t *results,
                  uint32_t count)
{
    m->results_bytes_merged += (uint64_t)count * PROTO_RESULT_RECORD_SIZE;
    if (!j->journal && m->store && !j->snap_gen && !j->need_snapshot) {
        /* the job's first merge: its journal (generation 0) starts here,
         * or a merge before the next tick would be in no checkpoint */
        j->journal = journal_new(j->id, 0, persist_journal_flags(j));
        j->snap_bytes = generation0_bytes(j);
        if (!j->journal)
            j->need_snapshot = 1; /* out of memory: a snapshot holds everything */
    }
    if (j->journal && !journal_failed(j->journal) &&
        journal_note(j->journal, task_id, results, count) < 0)
        j->need_snapshot = 1; /* out of memory: a snapshot holds everything */
}

/* ---- the background writer (runs in the forked child) ------------------------------ */

typedef struct bg_ctx {
    master_t *m;
    double now;
} bg_ctx_t;

/* Test builds only: the child kills the master at a named point of a
 * compaction (VB_FAULT_CRASH_IN_COMPACTION=before_rename|after_rename:
 * every snapshot is one, generation 0 being the job as submitted), or
 * before the rename of any snapshot (VB_FAULT_CRASH_BEFORE_RENAME; the
 * journal writer does the same before a job's first journal file). */
static void fault_point(const char *where, uint64_t generation)
{
#ifdef VB_FAULT_INJECTION
    const char *at = getenv("VB_FAULT_CRASH_IN_COMPACTION");
    int hit = generation >= 1 && at && strcmp(at, where) == 0;
    hit |= strcmp(where, "before_rename") == 0 && getenv("VB_FAULT_CRASH_BEFORE_RENAME");
    if (hit) {
        kill(getppid(), SIGKILL);
        _exit(3);
    }
#else
    (void)where;
    (void)generation;
#endif
}

/* A snapshot of generation g: the job's counters, g and the scheduler, to
 * snapshot.tmp, fsync, renamed over snapshot; then a fresh journal of
 * generation g that follows it (journal.tmp, renamed over the old one, which
 * recovery ignores from the rename of the snapshot on: its generation is
 * older). The old checkpoint files of a job taken over from a master of
 * format 1 go last. */
static int write_snapshot(master_t *m, const job_t *j, double now, char *err, size_t errlen)
{
    const uint64_t gen = j->snap_gen + 1;
    char path[4096];
    store_job_path(m->store, j->id, "snapshot", path, sizeof path);
    char *extras = extras_json(j, now);
    store_rec_writer_t *w = malloc(sizeof *w);
    if (!extras || !w) {
        snprintf(err, errlen, "out of memory");
        free(w);
        cJSON_free(extras);
        return -1;
    }
    uint8_t g[8];
    for (int i = 0; i < 8; i++)
        g[i] = (uint8_t)(gen >> (8 * i));
    int rc = store_rec_begin(w, path, STORE_KIND_SNAPSHOT);
    rc = rc < 0 ? rc : store_rec_write_block(w, extras, strlen(extras));
    rc = rc < 0 ? rc : store_rec_write(w, g, sizeof g);
    rc = rc < 0 ? rc : sched_save(j->sched, store_rec_write, w);
    cJSON_free(extras);
    rc = rc < 0 ? rc : store_rec_finish(w);
    if (rc == 0)
        fault_point("before_rename", gen);
    rc = rc < 0 ? rc : store_rec_install(w, 0);
    if (rc < 0) {
        snprintf(err, errlen, "snapshot: %.900s", w->err[0] ? w->err : "sched_save failed");
        free(w);
        return -1;
    }
    free(w);
    fault_point("after_rename", gen);
    journal_header_t h = {.version = JOURNAL_VERSION,
                          .flags = journal_flags(j->journal),
                          .generation = gen,
                          .job = j->id};
    store_job_path(m->store, j->id, "journal", path, sizeof path);
    if (journal_create(path, &h, err, errlen) < 0)
        return -1;
    /* Unchecked: recovery reads the snapshot first; old files only take
     * space until the job ends. */
    store_job_path(m->store, j->id, "checkpoint", path, sizeof path);
    (void)unlink(path);
    store_job_path(m->store, j->id, "checkpoint.prev", path, sizeof path);
    (void)unlink(path);
    return 0;
}

/* The image and the closing status; then the checkpoints are no longer
 * needed. The image first: a final record means the image is there. */
static int write_final(master_t *m, const job_t *j, char *err, size_t errlen)
{
    char path[4096];
    store_job_path(m->store, j->id, "image.exr", path, sizeof path);
    image_t *img = sched_image(j->sched);
    if (!img) {
        snprintf(err, errlen, "out of memory for the image");
        return -1;
    }
    int rc = image_write_exr(img, path, err, errlen);
    image_destroy(&img);
    if (rc < 0)
        return -1;
    cJSON *st = job_json(j, 1);
    char *text = st ? cJSON_PrintUnformatted(st) : NULL;
    cJSON_Delete(st);
    store_rec_writer_t *w = malloc(sizeof *w);
    if (!text || !w) {
        snprintf(err, errlen, "out of memory");
        free(w);
        cJSON_free(text);
        return -1;
    }
    store_job_path(m->store, j->id, "final", path, sizeof path);
    rc = store_rec_begin(w, path, STORE_KIND_FINAL);
    rc = rc < 0 ? rc : store_rec_write_block(w, text, strlen(text));
    rc = rc < 0 ? rc : store_rec_commit(w, 0);
    cJSON_free(text);
    if (rc < 0) {
        snprintf(err, errlen, "final status: %.900s", w->err);
        free(w);
        return -1;
    }
    free(w);
    /* Unchecked: with the final record there, recovery never reads a
     * checkpoint; one left behind only takes space until the job is deleted. */
    static const char *const done_with[] = {"snapshot", "journal", "checkpoint", "checkpoint.prev"};
    for (size_t k = 0; k < sizeof done_with / sizeof done_with[0]; k++) {
        store_job_path(m->store, j->id, done_with[k], path, sizeof path);
        (void)unlink(path);
    }
    return 0;
}

static int bg_write(void *ctx, int report_fd)
{
    bg_ctx_t *c = ctx;
    int failed = 0;
    for (job_t *j = c->m->jobs; j; j = j->next) {
        if (!j->in_write)
            continue;
        char err[VB_ERR_LEN] = "";
        if (injected_write_failure(err, sizeof err) < 0) {
            store_bg_report(report_fd, j->id, err);
            failed = 1;
            continue;
        }
        int rc = j->in_write == PERSIST_FINAL ? write_final(c->m, j, err, sizeof err)
                                              : write_snapshot(c->m, j, c->now, err, sizeof err);
        store_bg_report(report_fd, j->id, rc < 0 ? err : NULL);
        failed |= rc < 0;
    }
    return failed;
}

/* ---- in the master ------------------------------------------------------------------ */

static uint64_t file_size(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0 ? (uint64_t)st.st_size : 0;
}

static void on_report(void *ctx, uint64_t id, const char *error)
{
    master_t *m = ctx;
    job_t *j = job_find(m, id);
    if (!j || !j->in_write)
        return;
    int what = j->in_write;
    j->in_write = 0;
    if (error) {
        snprintf(j->storage_error, sizeof j->storage_error, "%s", error);
        master_log_at(m, VBLOG_ERROR,
                      "job %" PRIu64 ": cannot write its state (it keeps running): %s", id, error);
        /* The snapshot may have been renamed into place before the failure,
         * which makes the old journal stale: nothing more goes into it, the
         * next snapshot holds everything. */
        if (what == PERSIST_SNAPSHOT)
            j->need_snapshot = 1;
        return;
    }
    j->storage_error[0] = '\0';
    if (what == PERSIST_FINAL) {
        j->final_durable = 1;
        journal_destroy(&j->journal);
        job_shed(j);
#ifdef __GLIBC__
        /* give the film's pages back: freed by this thread but allocated by
         * the offload thread, they would stay in its arena otherwise */
        malloc_trim(0);
#endif
    } else {
        char path[4096];
        store_job_path(m->store, j->id, "snapshot", path, sizeof path);
        j->snap_gen++;
        j->snap_bytes = file_size(path);
        j->journal_bytes = JOURNAL_HEADER_SIZE;
        j->need_snapshot = 0;
        if (j->journal)
            journal_restart(j->journal, j->snap_gen, j->snap_keep_from);
        j->ckpt_samples = j->ckpt_writing;
        m->snapshots_written++;
        m->snapshot_bytes_written += j->snap_bytes;
        m->journal_bytes_written += JOURNAL_HEADER_SIZE;
    }
}

static void collect(master_t *m)
{
    int status = 0;
    if (!store_bg_poll(m->store, on_report, m, &status))
        return;
    if (!m->bg_final) {
        store_bg_stats_t bg = store_bg_last(m->store);
        m->ckpt_runs++;
        m->ckpt_cpu_s += bg.cpu_s;
        m->ckpt_wall_s += bg.wall_s;
        if (bg.fork_ms > m->ckpt_fork_ms_max)
            m->ckpt_fork_ms_max = bg.fork_ms;
    }
    for (job_t *j = m->jobs; j; j = j->next)
        if (j->in_write) {
            /* the child died before it reported this job */
            if (j->in_write == PERSIST_SNAPSHOT)
                j->need_snapshot = 1;
            j->in_write = 0;
            snprintf(j->storage_error, sizeof j->storage_error,
                     "the state writer died (status %d) before this job", status);
            master_log_at(m, VBLOG_ERROR, "job %" PRIu64 ": %s", j->id, j->storage_error);
        }
}

static void remove_doomed(master_t *m)
{
    for (size_t i = 0; i < m->doomed_n; i++) {
        char err[VB_ERR_LEN];
        if (store_job_remove(m->store, m->doomed[i], err, sizeof err) < 0)
            master_log(m, "job %" PRIu64 ": %s", m->doomed[i], err);
    }
    m->doomed_n = 0;
}

/* Whether a running job wants a snapshot now: one the journal cannot go
 * on without, or a compaction (the journal has grown to the snapshot's
 * size; for generation 0, to what a snapshot would take). */
static int wants_snapshot(const master_t *m, const job_t *j, double now, int force)
{
    if (j->state != JOB_RUNNING || !j->journal || j->journal_writing)
        return 0;
    if (j->need_snapshot) /* at once, unless the last write failed */
        return force || !j->storage_error[0] || now - j->last_ckpt >= m->cfg.checkpoint_s;
    return j->journal_bytes >= j->snap_bytes;
}

void persist_tick(master_t *m, double now, int force)
{
    collect(m);
    jw_collect(m, 0);
    if (!store_bg_running(m->store) && !(m->writer && m->writer->busy))
        remove_doomed(m);
    for (job_t *j = m->jobs; j; j = j->next)
        if (!j->journal && j->state == JOB_RUNNING && !j->snap_gen && !j->need_snapshot) {
            j->journal = journal_new(j->id, 0, persist_journal_flags(j));
            j->snap_bytes = generation0_bytes(j);
        }
    jw_start(m, now, force);
    if (store_bg_running(m->store))
        return;
    job_retention(m);
    int any = 0;
    m->bg_final = 0;
    for (job_t *j = m->jobs; j; j = j->next) {
        /* a failed write is retried after a checkpoint interval, not at once */
        double wait = j->storage_error[0] ? m->cfg.checkpoint_s : 0;
        int want;
        if (job_ended(j))
            want = !j->final_durable && j->sched && (force || now - j->last_ckpt >= wait);
        else
            want = wants_snapshot(m, j, now, force);
        if (!want)
            continue;
        /* what the child writes is decided now: a job that ends while its
         * snapshot is being written gets its final record next time */
        j->in_write = job_ended(j) ? PERSIST_FINAL : PERSIST_SNAPSHOT;
        m->bg_final |= j->in_write == PERSIST_FINAL;
        j->ckpt_writing = sched_samples_done(j->sched);
        j->snap_keep_from = j->journal ? journal_pending(j->journal) : 0;
        j->last_ckpt = now;
        any = 1;
    }
    if (!any)
        return;
    bg_ctx_t ctx = {.m = m, .now = now};
    char err[VB_ERR_LEN];
    if (store_bg_start(m->store, bg_write, &ctx, err, sizeof err) < 0) {
        master_log_at(m, VBLOG_ERROR, "cannot start the state writer: %s", err);
        for (job_t *j = m->jobs; j; j = j->next)
            if (j->in_write) {
                j->in_write = 0;
                snprintf(j->storage_error, sizeof j->storage_error, "%s", err);
            }
    }
}

void persist_finish(master_t *m)
{
    store_bg_wait(m->store, on_report, m);
    collect(m);
    jw_collect(m, 1);
    persist_tick(m, master_now(), 1);
    store_bg_wait(m->store, on_report, m);
    collect(m);
    jw_collect(m, 1);
    /* a commit sealed only now, or a snapshot's first commit */
    jw_start(m, master_now(), 1);
    jw_collect(m, 1);
}

void persist_image_path(master_t *m, const job_t *j, char *out, size_t outlen)
{
    if (m->store)
        store_job_path(m->store, j->id, "image.exr", out, outlen);
    else if (outlen)
        out[0] = '\0';
}

/* ---- recovery ------------------------------------------------------------------------ */

/* A job that cannot be rebuilt keeps its id, as a failed job saying why. */
static job_t *unrecoverable(uint64_t id, const char *why)
{
    job_t *j = calloc(1, sizeof *j);
    if (!j)
        return NULL;
    j->id = id;
    j->state = JOB_FAILED;
    j->final_durable = 1;
    snprintf(j->error, sizeof j->error, "cannot recover the job: %.900s", why);
    cJSON *o = cJSON_CreateObject();
    cJSON_AddNumberToObject(o, "id", (double)id);
    cJSON_AddStringToObject(o, "state", "failed");
    cJSON_AddStringToObject(o, "scene", "?");
    cJSON_AddStringToObject(o, "error", j->error);
    j->summary = cJSON_PrintUnformatted(o);
    cJSON_Delete(o);
    return j;
}

static job_t *recover_ended(uint64_t id, store_rec_t *rec)
{
    const uint8_t *text;
    size_t len;
    if (store_rec_read_block(rec, &text, &len) < 0)
        return NULL;
    cJSON *st = cJSON_ParseWithLength((const char *)text, len);
    const cJSON *state = cJSON_GetObjectItemCaseSensitive(st, "state");
    int k = -1;
    for (int i = JOB_DONE; cJSON_IsString(state) && i <= JOB_CANCELLED; i++)
        if (strcmp(state->valuestring, job_state_names[i]) == 0)
            k = i;
    job_t *j = k >= 0 ? calloc(1, sizeof *j) : NULL;
    if (!j) {
        cJSON_Delete(st);
        return NULL;
    }
    j->id = id;
    j->state = (job_state_t)k;
    j->final_durable = 1;
    const cJSON *name = cJSON_GetObjectItemCaseSensitive(st, "scene");
    snprintf(j->name, sizeof j->name, "%s", cJSON_IsString(name) ? name->valuestring : "?");
    const cJSON *owner = cJSON_GetObjectItemCaseSensitive(st, "owner");
    if (cJSON_IsString(owner))
        snprintf(j->owner, sizeof j->owner, "%s", owner->valuestring);
    const cJSON *rid = cJSON_GetObjectItemCaseSensitive(st, "request_id");
    if (cJSON_IsString(rid))
        snprintf(j->request_id, sizeof j->request_id, "%s", rid->valuestring);
    j->summary = cJSON_PrintUnformatted(st);
    cJSON_Delete(st);
    return j;
}

static job_t *recover_submitted(master_t *m, uint64_t id, char *err, size_t errlen)
{
    char path[4096];
    store_job_path(m->store, id, "submit", path, sizeof path);
    store_rec_t rec;
    if (store_rec_load(path, STORE_KIND_SUBMIT, &rec, err, errlen) < 0)
        return NULL;
    const uint8_t *text;
    size_t len;
    uint32_t n = 0;
    submit_frame_t frames[PROTO_MAX_MESHES + 4];
    job_t *j = NULL;
    cJSON *req = NULL;
    if (store_rec_read_block(&rec, &text, &len) < 0 || store_rec_read(&rec, &n, sizeof n) < 0 ||
        n > PROTO_MAX_MESHES + 4) {
        snprintf(err, errlen, "%.900s: malformed", path);
        goto out;
    }
    for (uint32_t i = 0; i < n; i++) {
        const uint8_t *d;
        if (store_rec_read_block(&rec, &d, &frames[i].size) < 0) {
            snprintf(err, errlen, "%.900s: malformed", path);
            goto out;
        }
        frames[i].data = d;
    }
    req = cJSON_ParseWithLength((const char *)text, len);
    if (!req) {
        snprintf(err, errlen, "%.900s: the request is not JSON", path);
        goto out;
    }
    /* no limits: the job was accepted once, under the limits of its day */
    j = submit_parse(req, frames, (int)n, NULL, err, errlen);
    if (j) {
        j->id = id;
        const uint8_t *owner;
        size_t olen;
        if (store_rec_read_block(&rec, &owner, &olen) == 0 && olen < sizeof j->owner) {
            memcpy(j->owner, owner, olen);
            j->owner[olen] = '\0';
        }
        /* taken over from a master of format 1, which must not start it
         * over if it runs on this directory again: it refuses format 2 */
        char werr[VB_ERR_LEN];
        if (rec.version < STORE_FORMAT_VERSION &&
            store_rec_save(path, STORE_KIND_SUBMIT, rec.data, rec.size, werr, sizeof werr) < 0)
            master_log_at(m, VBLOG_WARN, "job %" PRIu64 ": %s", id, werr);
    }
out:
    cJSON_Delete(req);
    store_rec_free(&rec);
    return j;
}

/* The old checkpoint of a job taken over from a master of format 1:
 * checkpoint, or checkpoint.prev; says which in j->recovered. 1 if one
 * was loaded (a snapshot is then written at once), 0 if none was there,
 * -1 if none was usable. */
static int recover_old_checkpoint(master_t *m, job_t *j)
{
    const char *names[2] = {"checkpoint", "checkpoint.prev"};
    char why[2][VB_ERR_LEN] = {"", ""};
    int present = 0;
    for (int k = 0; k < 2; k++) {
        char path[4096];
        store_job_path(m->store, j->id, names[k], path, sizeof path);
        if (access(path, F_OK) != 0)
            continue;
        present++;
        store_rec_t rec;
        if (store_rec_load(path, STORE_KIND_CHECKPOINT, &rec, why[k], sizeof why[k]) < 0)
            continue;
        const uint8_t *text;
        size_t len;
        cJSON *extras = NULL;
        sched_t *s = NULL;
        if (store_rec_read_block(&rec, &text, &len) < 0 ||
            !(extras = cJSON_ParseWithLength((const char *)text, len)))
            snprintf(why[k], sizeof why[k], "%.900s: malformed counters", path);
        else
            s = sched_load(&j->sched_cfg, store_rec_read, &rec, why[k], sizeof why[k]);
        if (s) {
            sched_destroy(&j->sched);
            j->sched = s;
            persist_apply_extras(j, extras);
            j->ckpt_samples = sched_samples_done(s);
            snprintf(j->recovered, sizeof j->recovered,
                     "old %s (state format 1) at %u of %u layers (%" PRIu64 " samples)%s%.400s",
                     names[k], sched_layers_complete(s), sched_layer_count(s),
                     sched_samples_done(s), k ? "; the newer one was unusable: " : "",
                     k ? why[0] : "");
        }
        cJSON_Delete(extras);
        store_rec_free(&rec);
        if (s)
            return 1;
    }
    if (present)
        snprintf(j->recovered, sizeof j->recovered,
                 "no usable checkpoint (%.400s%s%.400s): started over", why[0],
                 why[0][0] && why[1][0] ? "; " : "", why[1]);
    return present ? -1 : 0;
}

/* Reads a whole file; NULL with a message (missing: errno ENOENT). */
static uint8_t *read_file(const char *path, size_t *size, char *err, size_t errlen)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        snprintf(err, errlen, "%.600s: %s", path, strerror(errno));
        return NULL;
    }
    uint8_t *data = NULL;
    size_t n = 0, cap = 0;
    for (;;) {
        if (cap - n < 65536) {
            cap = cap ? 2 * cap : 1 << 20;
            uint8_t *nd = realloc(data, cap);
            if (!nd) {
                snprintf(err, errlen, "%.600s: out of memory", path);
                free(data);
                fclose(f);
                return NULL;
            }
            data = nd;
        }
        size_t got = fread(data + n, 1, cap - n, f);
        n += got;
        if (got == 0)
            break;
    }
    int bad = ferror(f);
    fclose(f);
    if (bad) {
        snprintf(err, errlen, "%.600s: read error", path);
        free(data);
        return NULL;
    }
    *size = n;
    return data;
}

/* A commit's counters over the job's: the series is replaced, not added to. */
static void apply_commit_extras(job_t *j, const char *text, size_t len)
{
    cJSON *o = cJSON_ParseWithLength(text, len);
    if (!o)
        return;
    free(j->series);
    j->series = NULL;
    j->series_n = j->series_cap = 0;
    persist_apply_extras(j, o);
    cJSON_Delete(o);
}

/* Replays one commit's tasks in merge order: each is taken from the
 * scheduler (it must be ready, as it was when merged) and completed with
 * its results. 0, or -1 with a message (the tasks before it stay merged). */
static int replay_commit(job_t *j, const journal_commit_t *c, uint32_t flags,
                         tracer_result_t **scratch, size_t *scratch_n, char *err, size_t errlen)
{
    journal_tasks_t it;
    journal_tasks_init(&it, c, flags);
    uint64_t task;
    uint32_t count;
    const uint8_t *records;
    int r;
    while ((r = journal_task_next(&it, &task, &count, &records)) == 1) {
        sched_task_t t;
        if (sched_take(j->sched, task, &t) != SCHED_OK) {
            snprintf(err, errlen, "task %" PRIu64 " is not ready to take", task);
            return -1;
        }
        if (t.count != count) {
            snprintf(err, errlen, "task %" PRIu64 ": %u results for %u pixels", task, count,
                     t.count);
            (void)sched_requeue(j->sched, task); /* it goes out again */
            return -1;
        }
        if (count > *scratch_n) {
            tracer_result_t *ns = realloc(*scratch, count * sizeof *ns);
            if (!ns) {
                snprintf(err, errlen, "out of memory");
                (void)sched_requeue(j->sched, task);
                return -1;
            }
            *scratch = ns;
            *scratch_n = count;
        }
        for (uint32_t i = 0; i < count; i++)
            if (journal_result(records, i, flags, &t.records[i], &(*scratch)[i]) < 0) {
                snprintf(err, errlen, "task %" PRIu64 ": result %u is malformed", task, i);
                (void)sched_requeue(j->sched, task);
                return -1;
            }
        char why[VB_ERR_LEN];
        if (sched_complete(j->sched, task, *scratch, count, why, sizeof why) != SCHED_OK) {
            snprintf(err, errlen, "%.900s", why);
            (void)sched_requeue(j->sched, task);
            return -1;
        }
    }
    if (r < 0) {
        snprintf(err, errlen, "malformed tasks");
        return -1;
    }
    return 0;
}

/* Truncates the journal at its last good commit (before anything is
 * appended to it again). */
static void truncate_journal(master_t *m, job_t *j, const char *path, uint64_t at)
{
    int fd = open(path, O_WRONLY | O_CLOEXEC);
    if (fd < 0 || ftruncate(fd, (off_t)at) != 0 || fdatasync(fd) != 0) {
        master_log_at(m, VBLOG_ERROR,
                      "job %" PRIu64 ": cannot truncate %s at %" PRIu64
                      ": %s; a snapshot replaces it",
                      j->id, path, at, strerror(errno));
        j->need_snapshot = 1;
    }
    if (fd >= 0)
        (void)close(fd); /* nothing more to learn about the data */
}

/* Replays DIR/jobs/<id>/journal over the snapshot of generation gen just
 * loaded; sets up the job's journal to append to. Returns the commits
 * replayed. */
static uint64_t replay_journal(master_t *m, job_t *j, uint64_t gen)
{
    char path[4096], err[VB_ERR_LEN];
    store_job_path(m->store, j->id, "journal", path, sizeof path);
    size_t size = 0;
    uint8_t *data = read_file(path, &size, err, sizeof err);
    journal_reader_t r;
    memset(&r, 0, sizeof r);
    int usable = 0;
    if (!data) {
        if (errno != ENOENT)
            master_log(m, "job %" PRIu64 ": %s: a fresh journal replaces it", j->id, err);
    } else if (journal_reader_init(&r, data, size, err, sizeof err) < 0) {
        master_log(m, "job %" PRIu64 ": journal %s: %s: a fresh journal replaces it", j->id, path,
                   err);
    } else if (r.header.generation != gen || r.header.job != j->id) {
        /* a crash between a compaction's new snapshot and its new journal */
        master_log(m,
                   "job %" PRIu64 ": journal %s is stale (generation %" PRIu64
                   ", the snapshot's %" PRIu64 "): ignored",
                   j->id, path, r.header.generation, gen);
    } else {
        usable = 1;
    }
    uint32_t flags = usable ? r.header.flags : persist_journal_flags(j);
    j->journal = journal_new(j->id, gen, flags);
    uint64_t commits = 0;
    if (!usable) {
        free(data);
        journal_header_t h = {
            .version = JOURNAL_VERSION, .flags = flags, .generation = gen, .job = j->id};
        if (journal_create(path, &h, err, sizeof err) < 0) {
            master_log_at(m, VBLOG_ERROR, "job %" PRIu64 ": %s", j->id, err);
            j->need_snapshot = 1;
        }
        j->journal_bytes = JOURNAL_HEADER_SIZE;
        return 0;
    }
    tracer_result_t *scratch = NULL;
    size_t scratch_n = 0;
    journal_commit_t c;
    int rc;
    size_t at = r.pos;
    while ((rc = journal_next(&r, &c, err, sizeof err)) == 1) {
        char why[VB_ERR_LEN];
        if (replay_commit(j, &c, flags, &scratch, &scratch_n, why, sizeof why) < 0) {
            master_log(m,
                       "job %" PRIu64 ": journal %s: commit %" PRIu64 " at offset %zu does not "
                       "replay (%s): the job continues from commit %" PRIu64
                       ", and a snapshot replaces the journal",
                       j->id, path, c.seq, at, why, c.seq - 1);
            /* part of it may be merged: only a snapshot holds that */
            j->need_snapshot = 1;
            r.pos = at;
            r.seq = c.seq - 1;
            rc = 0;
            break;
        }
        apply_commit_extras(j, c.extras, c.extras_len);
        commits++;
        at = r.pos;
    }
    if (rc < 0)
        master_log(m,
                   "job %" PRIu64 ": journal %s: the record at offset %zu is refused (%s): "
                   "replayed the %" PRIu64 " commits before it, and the journal is cut there",
                   j->id, path, r.pos, err, commits);
    free(scratch);
    if (r.pos < size)
        truncate_journal(m, j, path, r.pos);
    journal_set_next_seq(j->journal, r.seq + 1);
    j->journal_bytes = r.pos;
    free(data);
    return commits;
}

/* Restores the scheduler from the snapshot and the journal after it (or, in
 * a state directory of format 1, from the old checkpoint); says what in
 * j->recovered. */
static void recover_progress(master_t *m, job_t *j)
{
    char path[4096], why[VB_ERR_LEN] = "";
    store_job_path(m->store, j->id, "snapshot", path, sizeof path);
    if (access(path, F_OK) != 0) {
        int old = recover_old_checkpoint(m, j);
        store_job_path(m->store, j->id, "journal", path, sizeof path);
        if (old == 0 && access(path, F_OK) == 0) {
            /* generation 0: the journal alone, over the job as submitted */
            j->snap_gen = 0;
            j->snap_bytes = generation0_bytes(j);
            uint64_t commits = replay_journal(m, j, 0);
            j->ckpt_samples = sched_samples_done(j->sched);
            snprintf(j->recovered, sizeof j->recovered,
                     "the journal alone (no snapshot yet): %" PRIu64
                     " commit%s at %u of %u layers (%" PRIu64 " samples)",
                     commits, commits == 1 ? "" : "s", sched_layers_complete(j->sched),
                     sched_layer_count(j->sched), sched_samples_done(j->sched));
            return;
        }
        if (old != 0) {
            /* a snapshot in the new format at once; the old files go then */
            j->journal = journal_new(j->id, 0, persist_journal_flags(j));
            j->need_snapshot = j->journal != NULL;
            if (j->recovered[0] && strncmp(j->recovered, "old ", 4) == 0)
                master_log(m,
                           "job %" PRIu64
                           ": recovered from the old checkpoint (state format 1); writing a "
                           "snapshot and journal in its place",
                           j->id);
        }
        return;
    }
    store_rec_t rec;
    sched_t *s = NULL;
    cJSON *extras = NULL;
    uint64_t gen = 0;
    if (store_rec_load(path, STORE_KIND_SNAPSHOT, &rec, why, sizeof why) == 0) {
        const uint8_t *text;
        size_t len;
        uint8_t g[8];
        if (store_rec_read_block(&rec, &text, &len) < 0 ||
            !(extras = cJSON_ParseWithLength((const char *)text, len)) ||
            store_rec_read(&rec, g, sizeof g) < 0)
            snprintf(why, sizeof why, "%.900s: malformed counters", path);
        else {
            for (int i = 7; i >= 0; i--)
                gen = gen << 8 | g[i];
            s = gen ? sched_load(&j->sched_cfg, store_rec_read, &rec, why, sizeof why) : NULL;
            if (!gen)
                snprintf(why, sizeof why, "%.900s: generation 0", path);
        }
        store_rec_free(&rec);
    }
    if (!s) {
        cJSON_Delete(extras);
        snprintf(j->recovered, sizeof j->recovered, "no usable snapshot (%.900s): started over",
                 why);
        master_log(m, "job %" PRIu64 ": %s", j->id, j->recovered);
        /* its journal follows a snapshot that is gone */
        store_job_path(m->store, j->id, "journal", path, sizeof path);
        (void)unlink(path); /* unchecked: a stale journal is ignored (generation) */
        return;
    }
    sched_destroy(&j->sched);
    j->sched = s;
    persist_apply_extras(j, extras);
    cJSON_Delete(extras);
    j->snap_gen = gen;
    j->snap_bytes = file_size(path);
    uint64_t commits = replay_journal(m, j, gen);
    j->ckpt_samples = sched_samples_done(s);
    snprintf(j->recovered, sizeof j->recovered,
             "snapshot %" PRIu64 " and %" PRIu64 " journal commit%s at %u of %u layers (%" PRIu64
             " samples)",
             gen, commits, commits == 1 ? "" : "s", sched_layers_complete(s), sched_layer_count(s),
             sched_samples_done(s));
}

void persist_recover(master_t *m)
{
    uint64_t *ids;
    size_t n;
    char err[VB_ERR_LEN];
    if (store_job_ids(m->store, &ids, &n, err, sizeof err) < 0) {
        master_log_at(m, VBLOG_ERROR, "state: %s", err);
        return;
    }
    uint32_t resumed = 0, ended = 0, lost = 0;
    for (size_t i = 0; i < n; i++) {
        char path[4096];
        store_job_clean(m->store, ids[i]);
        store_job_path(m->store, ids[i], "final", path, sizeof path);
        store_rec_t rec;
        job_t *j = NULL;
        if (store_rec_load(path, STORE_KIND_FINAL, &rec, err, sizeof err) == 0) {
            j = recover_ended(ids[i], &rec);
            store_rec_free(&rec);
            if (j) {
                ended++;
                job_append(m, j);
                continue;
            }
        }
        j = recover_submitted(m, ids[i], err, sizeof err);
        if (!j) {
            master_log(m, "job %" PRIu64 " cannot be recovered: %s", ids[i], err);
            if ((j = unrecoverable(ids[i], err)) != NULL)
                job_append(m, j);
            lost++;
            continue;
        }
        recover_progress(m, j);
        job_append(m, j);
        resumed++;
        master_log(m, "job %" PRIu64 " recovered: %s", j->id,
                   j->recovered[0] ? j->recovered : "from its submission");
        if (sched_done(j->sched)) /* it had finished; its image was not yet written */
            job_finish(m, j, JOB_DONE, NULL);
    }
    free(ids);
    master_log(m, "state %s: %u job%s to resume, %u ended, %u unrecoverable", store_dir(m->store),
               resumed, resumed == 1 ? "" : "s", ended, lost);
}
