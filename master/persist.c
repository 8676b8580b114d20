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
#include <float.h>
#include <inttypes.h>
#ifdef __GLIBC__
#include <malloc.h>
#endif
#include <signal.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "film.h"
#include "image.h"
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

/* ---- the background writer (runs in the forked child) ------------------------------ */

typedef struct bg_ctx {
    master_t *m;
    double now;
} bg_ctx_t;

/* The scheduler and the job's counters: PATH.tmp, then renamed into place
 * keeping the last one as checkpoint.prev. */
static int write_checkpoint(master_t *m, const job_t *j, double now, char *err, size_t errlen)
{
    char path[4096];
    store_job_path(m->store, j->id, "checkpoint", path, sizeof path);
    char *extras = extras_json(j, now);
    store_rec_writer_t *w = malloc(sizeof *w);
    if (!extras || !w) {
        snprintf(err, errlen, "out of memory");
        free(w);
        cJSON_free(extras);
        return -1;
    }
    int rc = store_rec_begin(w, path, STORE_KIND_CHECKPOINT);
    rc = rc < 0 ? rc : store_rec_write_block(w, extras, strlen(extras));
    rc = rc < 0 ? rc : sched_save(j->sched, store_rec_write, w);
    cJSON_free(extras);
    rc = rc < 0 ? rc : store_rec_finish(w);
#ifdef VB_FAULT_INJECTION
    /* Test builds only: the master dies between writing a checkpoint and
     * renaming it into place. */
    if (rc == 0 && getenv("VB_FAULT_CRASH_BEFORE_RENAME")) {
        kill(getppid(), SIGKILL);
        _exit(3);
    }
#endif
    rc = rc < 0 ? rc : store_rec_install(w, 1);
    if (rc < 0)
        snprintf(err, errlen, "checkpoint: %.900s", w->err[0] ? w->err : "sched_save failed");
    free(w);
    return rc;
}

/* The image and the closing status; then the checkpoints are no longer
 * needed. The image first: a final record means the image is there. */
static int write_final(master_t *m, const job_t *j, char *err, size_t errlen)
{
    char path[4096];
    store_job_path(m->store, j->id, "image.exr", path, sizeof path);
    image_t *img = film_to_image(sched_film(j->sched));
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
    store_job_path(m->store, j->id, "checkpoint", path, sizeof path);
    (void)unlink(path);
    store_job_path(m->store, j->id, "checkpoint.prev", path, sizeof path);
    (void)unlink(path);
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
                                              : write_checkpoint(c->m, j, c->now, err, sizeof err);
        store_bg_report(report_fd, j->id, rc < 0 ? err : NULL);
        failed |= rc < 0;
    }
    return failed;
}

/* ---- in the master ------------------------------------------------------------------ */

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
        return;
    }
    j->storage_error[0] = '\0';
    if (what == PERSIST_FINAL) {
        j->final_durable = 1;
        job_shed(j);
#ifdef __GLIBC__
        /* give the film's pages back: freed by this thread but allocated by
         * the offload thread, they would stay in its arena otherwise */
        malloc_trim(0);
#endif
    } else {
        j->ckpt_samples = j->ckpt_writing;
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

void persist_tick(master_t *m, double now, int force)
{
    collect(m);
    if (store_bg_running(m->store))
        return;
    remove_doomed(m);
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
            want = j->state == JOB_RUNNING && sched_samples_done(j->sched) != j->ckpt_samples &&
                   (force || now - j->last_ckpt >=
                                 (wait > m->cfg.checkpoint_s ? wait : m->cfg.checkpoint_s));
        if (!want)
            continue;
        /* what the child writes is decided now: a job that ends while its
         * checkpoint is being written gets its final record next time */
        j->in_write = job_ended(j) ? PERSIST_FINAL : PERSIST_CHECKPOINT;
        m->bg_final |= j->in_write == PERSIST_FINAL;
        j->ckpt_writing = sched_samples_done(j->sched);
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
    persist_tick(m, master_now(), 1);
    store_bg_wait(m->store, on_report, m);
    collect(m);
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
    }
out:
    cJSON_Delete(req);
    store_rec_free(&rec);
    return j;
}

/* Restores the scheduler from checkpoint, or checkpoint.prev; says which in
 * j->recovered. */
static void recover_progress(master_t *m, job_t *j)
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
                     "%s at %u of %u layers (%" PRIu64 " samples)%s%.400s", names[k],
                     sched_layers_complete(s), sched_layer_count(s), sched_samples_done(s),
                     k ? "; the newer one was unusable: " : "", k ? why[0] : "");
        }
        cJSON_Delete(extras);
        store_rec_free(&rec);
        if (s)
            return;
    }
    if (present)
        snprintf(j->recovered, sizeof j->recovered,
                 "no usable checkpoint (%.400s%s%.400s): started over", why[0],
                 why[0][0] && why[1][0] ? "; " : "", why[1]);
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
