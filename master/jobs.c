/* jobs.c - the job store in memory (master_priv.h). */
#include <inttypes.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "compare.h"
#include "film.h"
#include "journal.h"
#include "master_priv.h"
#include "preview.h"
#include "scene.h"

const char *const job_state_names[] = {"queued", "running", "done", "failed", "cancelled"};

job_t *job_find(master_t *m, uint64_t id)
{
    for (job_t *j = m->jobs; j; j = j->next)
        if (j->id == id)
            return j;
    return NULL;
}

job_t *job_find_by_hash(master_t *m, const uint8_t *hash)
{
    for (job_t *j = m->jobs; j; j = j->next)
        if (j->json && memcmp(j->hash, hash, PROTO_HASH_SIZE) == 0)
            return j;
    return NULL;
}

job_t *job_find_by_request(master_t *m, const char *request_id)
{
    for (job_t *j = m->jobs; j; j = j->next)
        if (j->request_id[0] && strcmp(j->request_id, request_id) == 0)
            return j;
    return NULL;
}

void job_append(master_t *m, job_t *j)
{
    j->next = NULL;
    if (m->jobs_tail)
        m->jobs_tail->next = j;
    else
        m->jobs = j;
    m->jobs_tail = j;
}

static void free_bundle(job_t *j)
{
    free(j->json);
    j->json = NULL;
    for (uint32_t i = 0; i < j->mesh_count; i++)
        if (j->mesh_data)
            free(j->mesh_data[i]);
    free(j->mesh_names);
    free(j->mesh_data);
    free(j->mesh_sizes);
    j->mesh_names = NULL;
    j->mesh_data = NULL;
    j->mesh_sizes = NULL;
    j->mesh_count = 0;
}

void job_shed(job_t *j)
{
    if (!j->summary) {
        cJSON *o = job_json(j, 1);
        j->summary = o ? cJSON_PrintUnformatted(o) : NULL;
        cJSON_Delete(o);
    }
    if (!j->summary)
        return; /* out of memory: keep the job whole */
    free_bundle(j);
    verify_free(j);
    preview_destroy(&j->preview); /* of the film freed here */
    sched_destroy(&j->sched);
    free(j->attempt);
    free(j->holder);
    free(j->sent_ms);
    lease_queue_destroy(&j->leases);
    j->attempt = NULL;
    j->holder = NULL;
    j->sent_ms = NULL;
    for (int c = 0; c < 3; c++) {
        free(j->ref[c]);
        free(j->cur[c]);
        j->ref[c] = j->cur[c] = NULL;
    }
    free(j->series);
    j->series = NULL;
    j->series_n = j->series_cap = 0;
}

void job_free(job_t *j)
{
    if (!j)
        return;
    free_bundle(j);
    verify_free(j);
    preview_destroy(&j->preview);
    sched_destroy(&j->sched);
    free(j->flags);
    free(j->quarantined);
    free(j->attempt);
    free(j->holder);
    free(j->sent_ms);
    lease_queue_destroy(&j->leases);
    for (int c = 0; c < 3; c++) {
        free(j->ref[c]);
        free(j->cur[c]);
    }
    free(j->series);
    journal_destroy(&j->journal);
    cJSON_free(j->summary);
    free(j);
}

int job_ended(const job_t *j)
{
    return j->state == JOB_DONE || j->state == JOB_FAILED || j->state == JOB_CANCELLED;
}

double job_seconds(const job_t *j, double now)
{
    if (!j->started)
        return j->run_before;
    return j->run_before + (j->finished ? j->finished : now) - j->started;
}

/* compare_planes' threshold for its "above" share, which the series does
 * not keep (only relMSE and RMSE): any value gives the same series. */
#define JOB_EVAL_THRESHOLD 0.05

/* Appends the current error against the reference to the job's series. */
void job_eval_error(job_t *j, double now)
{
    if (!j->ref[0] || !j->started || !j->sched)
        return;
    const film_t *f = sched_film(j->sched);
    size_t n = (size_t)j->width * j->height;
    for (size_t i = 0; i < n; i++) {
        double rgb[3];
        film_mean(f, (uint32_t)i, rgb);
        for (int c = 0; c < 3; c++)
            j->cur[c][i] = (float)rgb[c];
    }
    compare_result_t r;
    compare_planes((const float *const *)j->cur, (const float *const *)j->ref, n, NULL,
                   JOB_EVAL_THRESHOLD, &r);
    if (j->series_n == j->series_cap) {
        size_t cap = j->series_cap ? 2 * j->series_cap : 64;
        double *ns = realloc(j->series, cap * JOB_SERIES_COLUMNS * sizeof(double));
        if (!ns)
            return;
        j->series = ns;
        j->series_cap = cap;
    }
    double *pt = j->series + JOB_SERIES_COLUMNS * j->series_n++;
    pt[0] = job_seconds(j, now);
    pt[1] = (double)sched_samples_done(j->sched);
    pt[2] = r.relmse;
    pt[3] = r.rmse;
    pt[4] = (double)j->rays;
    j->last_eval = now;
    j->last_eval_layers = sched_layers_complete(j->sched);
}

/* Drops the job's outstanding tasks (cancel, failure): their results will be
 * ignored as late. */
void job_release_all(master_t *m, job_t *j)
{
    if (!j->holder || !j->sched)
        return;
    verify_release_all(m, j); /* its cells are free after this */
    size_t cells = (size_t)sched_layer_count(j->sched) * sched_range_count(j->sched);
    for (size_t c = 0; c < cells; c++)
        if (j->holder[c]) {
            peer_t *w = &m->workers[j->holder[c] - 1];
            if (w->outstanding)
                w->outstanding--;
            w->owed++;
            j->holder[c] = 0;
        }
    j->outstanding = 0;
}

void job_reissue(master_t *m, job_t *j, size_t cell)
{
    peer_t *w = &m->workers[j->holder[cell] - 1];
    if (w->outstanding)
        w->outstanding--;
    w->tasks_reissued++;
    j->holder[cell] = 0;
    j->outstanding--;
    j->reissued++;
    job_requeue(m, j, (uint64_t)cell + 1);
}

/* ---- task times and leases -------------------------------------------------------- */

double job_task_seconds(const job_t *j)
{
    return lease_times_quantile(&j->times, MASTER_TASK_QUANTILE);
}

double job_lease_seconds(const master_t *m, const job_t *j)
{
    double ceiling = m->cfg.lease_ms / 1000.0;
    double floor = MASTER_LEASE_FLOOR_S < ceiling ? MASTER_LEASE_FLOOR_S : ceiling;
    return lease_length(job_task_seconds(j), MASTER_LEASE_FACTOR, floor, ceiling);
}

void job_lease(master_t *m, job_t *j, uint64_t task, uint32_t attempt, uint32_t slot, double now)
{
    lease_t l = {.task = task, .attempt = attempt, .slot = slot, .sent = now};
    if (lease_push(j->leases, &l) < 0)
        master_log(m, "job %" PRIu64 " task %" PRIu64 ": out of memory for its lease", j->id, task);
}

uint32_t job_ms(const job_t *j, double now)
{
    double ms = (now - j->epoch) * 1000.0;
    return ms <= 0 ? 0 : ms >= 4294967295.0 ? UINT32_MAX : (uint32_t)ms;
}

void job_requeue(master_t *m, job_t *j, uint64_t task)
{
    sched_status_t rc = sched_requeue(j->sched, task);
    if (rc == SCHED_OK)
        return;
    /* The scheduler holds the task as handed out until it takes it back: a
     * refusal leaves it out with no holder and no lease, so it is never
     * issued again and the job cannot finish. The job fails at the next
     * tick (job_clocks) with its image so far kept, rather than hang; not
     * here, since callers still hold the job. */
    m->requeue_refused++;
    j->requeue_refused = 1;
    master_log(
        m, "job %" PRIu64 " task %" PRIu64 ": the scheduler refused it back: %s", j->id, task,
        rc == SCHED_NO_MEMORY ? "out of memory" : "it was not outstanding (a bookkeeping bug)");
}

void job_merged(master_t *m, job_t *j)
{
    if (sched_done(j->sched))
        job_finish(m, j, JOB_DONE,
                   sched_stopped_on_target(j->sched) ? "target error reached" : NULL);
    else if (j->ref[0] && sched_layers_complete(j->sched) != j->last_eval_layers)
        job_eval_error(j, master_now()); /* a point per finished layer, however fast */
}

void job_finish(master_t *m, job_t *j, job_state_t st, const char *why)
{
    if (job_ended(j))
        return;
    job_release_all(m, j);
    j->state = st;
    j->finished = master_now();
    if (!j->started)
        j->started = j->finished;
    job_eval_error(j, j->finished);
    if (why)
        snprintf(j->error, sizeof j->error, "%s", why);
    master_log(m, "job %" PRIu64 " %s after %.2f s: %" PRIu64 " samples, %" PRIu64 " rays%s%s",
               j->id, job_state_names[st], job_seconds(j, j->finished),
               j->sched ? sched_samples_done(j->sched) : 0, j->rays, why ? ": " : "",
               why ? why : "");
}

/* How far the job is, 0 to 1: its share of max_samples, or of its time
 * limit if that is further; 1 once done (an adaptive job may end short of
 * max_samples). */
static double job_progress(const job_t *j, double el, uint64_t samples, uint64_t max_samples)
{
    if (j->state == JOB_DONE)
        return 1;
    double p = max_samples ? (double)samples / (double)max_samples : 0;
    if (j->time_limit > 0 && el / j->time_limit > p)
        p = el / j->time_limit;
    return p < 1 ? p : 1;
}

/* Seconds left at the job's rate so far, to max_samples or to its time
 * limit, whichever comes first; 0 once ended; -1 while not known (queued,
 * or no sample merged yet). An adaptive job may end sooner. */
static double job_eta(const job_t *j, double el, uint64_t samples, uint64_t max_samples)
{
    if (job_ended(j))
        return 0;
    if (j->state != JOB_RUNNING)
        return -1;
    double left = -1;
    if (samples > 0 && el > 0)
        left = (double)(max_samples > samples ? max_samples - samples : 0) / (samples / el);
    if (j->time_limit > 0) {
        double t = j->time_limit > el ? j->time_limit - el : 0;
        if (left < 0 || t < left)
            left = t;
    }
    return left;
}

static void add_str(cJSON *o, const char *k, const char *v)
{
    cJSON_AddStringToObject(o, k, v);
}

/* An ended job whose film is on disk: its status as of the end, with what
 * may have changed since. */
static cJSON *summary_json(const job_t *j, int with_series)
{
    cJSON *o = cJSON_Parse(j->summary);
    if (o && !with_series)
        cJSON_DeleteItemFromObjectCaseSensitive(o, "error_series");
    if (o && j->storage_error[0]) {
        cJSON_DeleteItemFromObjectCaseSensitive(o, "storage_error");
        cJSON_AddStringToObject(o, "storage_error", j->storage_error);
    }
    return o;
}

/* What the job was asked for. */
static void settings_json(const job_t *j, cJSON *o)
{
    cJSON_AddNumberToObject(o, "id", (double)j->id);
    add_str(o, "state", job_state_names[j->state]);
    add_str(o, "scene", j->name);
    cJSON_AddNumberToObject(o, "width", j->width);
    cJSON_AddNumberToObject(o, "height", j->height);
    cJSON_AddNumberToObject(o, "spp", j->spp);
    cJSON_AddNumberToObject(o, "granularity", j->granularity);
    add_str(o, "adaptive", sched_adaptive_name(j->adaptive));
    char seed[32];
    snprintf(seed, sizeof seed, "%" PRIu64, j->tracer.seed);
    add_str(o, "seed", seed);
    add_str(o, "integrator", scene_integrator_name(j->tracer.integrator));
    add_str(o, "sampler", tracer_sampler_name(j->tracer.sampler));
    cJSON_AddNumberToObject(o, "replicates",
                            j->sched_cfg.replicates > 1 ? (double)j->sched_cfg.replicates : 1.0);
    cJSON_AddNumberToObject(o, "layers", sched_layer_count(j->sched));
    cJSON_AddNumberToObject(o, "uniform_layers", sched_uniform_layers(j->sched));
}

/* How far it got, and how fast. */
static void progress_json(const job_t *j, cJSON *o)
{
    double el = job_seconds(j, master_now());
    uint64_t samples = sched_samples_done(j->sched);
    uint64_t max_samples = (uint64_t)j->spp * j->width * j->height;
    cJSON_AddNumberToObject(o, "layers_done", sched_layers_complete(j->sched));
    cJSON_AddNumberToObject(o, "samples", (double)samples);
    cJSON_AddNumberToObject(o, "max_samples", (double)max_samples);
    cJSON_AddNumberToObject(o, "pixel_layers_skipped",
                            (double)sched_pixel_layers_skipped(j->sched));
    cJSON_AddNumberToObject(o, "rays", (double)j->rays);
    cJSON_AddNumberToObject(o, "seconds", el);
    cJSON_AddNumberToObject(o, "rays_per_second", el > 0 ? j->rays / el : 0);
    cJSON_AddNumberToObject(o, "samples_per_second", el > 0 ? samples / el : 0);
    cJSON_AddNumberToObject(o, "busy_seconds", j->busy_us / 1e6);
    cJSON_AddNumberToObject(o, "tasks_reissued", j->reissued);
    cJSON_AddNumberToObject(o, "tasks_outstanding", j->outstanding);
    /* backup copies of stragglers' tasks, and how many answered first */
    cJSON_AddNumberToObject(o, "backups", (double)j->backups);
    cJSON_AddNumberToObject(o, "backups_won", (double)j->backups_won);
    cJSON_AddNumberToObject(o, "task_seconds", job_task_seconds(j));
    cJSON_AddNumberToObject(o, "mean_spp",
                            j->width && j->height ? (double)samples / ((double)j->width * j->height)
                                                  : 0);
    cJSON_AddNumberToObject(o, "progress", job_progress(j, el, samples, max_samples));
    double eta = job_eta(j, el, samples, max_samples);
    if (eta >= 0)
        cJSON_AddNumberToObject(o, "eta_seconds", eta);
    else
        cJSON_AddNullToObject(o, "eta_seconds");
    cJSON_AddNumberToObject(o, "late_results", (double)j->late_results);
    cJSON_AddNumberToObject(o, "nonfinite", (double)sched_nonfinite(j->sched));
}

/* Stopping rules and the error against a reference. */
static void error_json(const job_t *j, cJSON *o, int with_series)
{
    cJSON_AddNumberToObject(o, "time_limit", j->time_limit);
    if (j->target_error > 0) {
        cJSON_AddNumberToObject(o, "target_error", j->target_error);
        cJSON_AddNumberToObject(o, "converged_pixels", (double)sched_converged(j->sched));
        cJSON_AddBoolToObject(o, "stopped_on_target", sched_stopped_on_target(j->sched));
        cJSON_AddNumberToObject(o, "pixels_at_cap", (double)sched_pixels_at_cap(j->sched));
    }
    if (j->series_n > 0) {
        const double *last = j->series + JOB_SERIES_COLUMNS * (j->series_n - 1);
        cJSON_AddNumberToObject(o, "relmse", last[2]);
        cJSON_AddNumberToObject(o, "rmse", last[3]);
    }
    if (with_series && j->series_n > 0) {
        cJSON *arr = cJSON_AddArrayToObject(o, "error_series");
        for (size_t i = 0; i < j->series_n; i++)
            cJSON_AddItemToArray(arr, cJSON_CreateDoubleArray(j->series + JOB_SERIES_COLUMNS * i,
                                                              JOB_SERIES_COLUMNS));
    }
}

cJSON *job_json(const job_t *j, int with_series)
{
    if (j->summary && !j->sched)
        return summary_json(j, with_series);
    cJSON *o = cJSON_CreateObject();
    if (!o)
        return NULL;
    settings_json(j, o);
    progress_json(j, o);
    verify_json(j, o);
    error_json(j, o, with_series);
    if (j->error[0])
        add_str(o, "error", j->error);
    if (j->storage_error[0])
        add_str(o, "storage_error", j->storage_error);
    if (j->recovered[0])
        add_str(o, "recovered", j->recovered);
    if (j->journal) {
        /* the checkpoint on disk: samples it holds, and the snapshot's and
         * journal's bytes */
        cJSON_AddNumberToObject(o, "durable_samples", (double)j->ckpt_samples);
        cJSON_AddNumberToObject(o, "state_bytes",
                                (double)((j->snap_gen ? j->snap_bytes : 0) + j->journal_bytes));
        /* what a snapshot of the job takes: the state directory's unit */
        if (j->sched)
            cJSON_AddNumberToObject(o, "snapshot_bytes", (double)sched_save_bytes(j->sched));
    }
    if (j->owner[0])
        add_str(o, "owner", j->owner);
    if (j->request_id[0])
        add_str(o, "request_id", j->request_id);
    return o;
}

void job_delete(master_t *m, job_t *j)
{
    if (!job_ended(j))
        job_finish(m, j, JOB_CANCELLED, "deleted by a client");
    job_t **pp = &m->jobs, *prev = NULL;
    while (*pp && *pp != j) {
        prev = *pp;
        pp = &(*pp)->next;
    }
    if (*pp) {
        *pp = j->next;
        if (m->jobs_tail == j)
            m->jobs_tail = prev;
    }
    m->reissued_deleted_jobs += j->reissued; /* the master's total stays monotonic */
    if (m->store) {
        /* removed when no background write can be touching its files */
        if (m->doomed_n == m->doomed_cap) {
            size_t cap = m->doomed_cap ? 2 * m->doomed_cap : 16;
            uint64_t *d = realloc(m->doomed, cap * sizeof *d);
            if (d) {
                m->doomed = d;
                m->doomed_cap = cap;
            }
        }
        if (m->doomed_n < m->doomed_cap)
            m->doomed[m->doomed_n++] = j->id;
        else
            master_log(m, "job %" PRIu64 ": out of memory; its files stay in the state directory",
                       j->id);
    }
    job_free(j);
}

void job_retention(master_t *m)
{
    uint32_t ended = 0;
    for (job_t *j = m->jobs; j; j = j->next)
        ended += job_ended(j) && (j->final_durable || !m->store);
    while (ended > m->cfg.keep_finished) {
        job_t *oldest = NULL;
        for (job_t *j = m->jobs; j; j = j->next)
            if (job_ended(j) && (j->final_durable || !m->store) && !j->in_write &&
                (!oldest || j->finished < oldest->finished ||
                 (j->finished == oldest->finished && j->id < oldest->id)))
                oldest = j;
        if (!oldest)
            return;
        master_log(m, "job %" PRIu64 " removed: more than %u ended jobs are kept (--keep-finished)",
                   oldest->id, m->cfg.keep_finished);
        job_delete(m, oldest);
        ended--;
    }
}
