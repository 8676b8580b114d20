/* ctl.c - the control commands (JSON over the control ROUTER socket,
 * proto/PROTOCOL.md), as a table of name, handler and what they take. */
#include <inttypes.h>
#include <math.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>

#include "film.h"
#include "frames.h"
#include "master_priv.h"
#include "preview.h"

/* A request being answered. */
typedef struct ctl_req {
    master_t *m;
    zmq_msg_t *id;         /* the client's identity frame */
    const cJSON *body;     /* the parsed JSON request */
    zmq_msg_t *json_frame; /* the request as received (stored with a submission) */
    zmq_msg_t *extra;      /* binary frames after the JSON */
    int nextra;
    job_t *job; /* for commands on one job */
    /* who asks: with CURVE keys a client owns the jobs it submitted and
     * acts on those only, unless it is an admin; without keys there is no
     * identity to own by (loopback or --insecure), so every client may act
     * on every job */
    char client[128];
    int keyed, admin;
} ctl_req_t;

/* Whether r's client may see and act on j. */
static int may_act(const ctl_req_t *r, const job_t *j)
{
    return !r->keyed || r->admin || strcmp(j->owner, r->client) == 0;
}

/* The client a request comes from: its CURVE key (the ZAP handler's
 * User-Id), or without keys its address. */
static void client_of(zmq_msg_t *frame, char *out, size_t len)
{
    const char *key = zmq_msg_gets(frame, "User-Id");
    if (key && *key) {
        snprintf(out, len, "%s", key);
        return;
    }
    const char *addr = zmq_msg_gets(frame, "Peer-Address");
    snprintf(out, len, "%s", addr && *addr ? addr : "local");
}

/* A token bucket per connection (routing identity): max_requests_per_s
 * refill, twice that as a burst. A fixed table; a new connection takes the
 * slot least recently used. */
typedef struct ctl_bucket {
    uint8_t id[64];
    size_t id_len;
    double tokens, last;
} ctl_bucket_t;

static int rate_ok(master_t *m, zmq_msg_t *id, double now)
{
    if (!m->buckets && !(m->buckets = calloc(MASTER_RATE_BUCKETS, sizeof *m->buckets)))
        return 1;
    size_t len =
        zmq_msg_size(id) < sizeof m->buckets[0].id ? zmq_msg_size(id) : sizeof m->buckets[0].id;
    ctl_bucket_t *b = NULL, *oldest = &m->buckets[0];
    for (size_t i = 0; i < MASTER_RATE_BUCKETS && !b; i++) {
        ctl_bucket_t *c = &m->buckets[i];
        if (c->id_len == len && memcmp(c->id, zmq_msg_data(id), len) == 0)
            b = c;
        else if (c->last < oldest->last)
            oldest = c;
    }
    double rate = m->cfg.max_requests_per_s, burst = 2 * rate;
    if (!b) {
        b = oldest;
        memcpy(b->id, zmq_msg_data(id), len);
        b->id_len = len;
        b->tokens = burst;
        b->last = now;
    }
    b->tokens += (now - b->last) * rate;
    if (b->tokens > burst)
        b->tokens = burst;
    b->last = now;
    if (b->tokens < 1)
        return 0;
    b->tokens -= 1;
    return 1;
}

/* A handler returns the reply body (sent and freed by the caller), or NULL
 * when it sent its reply itself. */
typedef cJSON *(*ctl_handler_fn)(ctl_req_t *r);

typedef struct ctl_command {
    const char *name;
    ctl_handler_fn handler;
    int takes_frames; /* binary frames after the JSON */
    int needs_job;    /* a "job": N that names an existing job the client may act on */
    int admin_only;   /* with keys, admins only */
} ctl_command_t;

/* The most binary parts a reply carries after its JSON (fetch: one per
 * image channel). */
#define CTL_MAX_REPLY_PARTS IMAGE_MAX_CHANNELS

/* One reply as one message: [client id][""][JSON][binary parts...]. */
static void reply_parts(master_t *m, zmq_msg_t *id, cJSON *body, const void *const *extra,
                        const size_t *extra_sizes, size_t n_extra)
{
    char *text = cJSON_PrintUnformatted(body);
    const void *parts[3 + CTL_MAX_REPLY_PARTS] = {zmq_msg_data(id), "", text ? text : "{}"};
    size_t sizes[3 + CTL_MAX_REPLY_PARTS] = {zmq_msg_size(id), 0, text ? strlen(text) : 2};
    for (size_t i = 0; i < n_extra && i < CTL_MAX_REPLY_PARTS; i++) {
        parts[3 + i] = extra[i];
        sizes[3 + i] = extra_sizes[i];
    }
    /* DONTWAIT: a client that does not read its replies has them dropped at
     * the high-water mark rather than stalling the master; a dropped reply
     * is the client's loss only, so the result is not checked */
    (void)proto_send(m->control_sock, parts, sizes, 3 + n_extra, ZMQ_DONTWAIT);
    cJSON_free(text);
}

static void reply_json(master_t *m, zmq_msg_t *id, cJSON *body)
{
    reply_parts(m, id, body, NULL, NULL, 0);
}

static cJSON *error_body(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
static cJSON *error_body(const char *fmt, ...)
{
    char msg[VB_ERR_LEN];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    cJSON *b = cJSON_CreateObject();
    cJSON_AddBoolToObject(b, "ok", 0);
    cJSON_AddStringToObject(b, "error", msg);
    return b;
}

static cJSON *ok_body(void)
{
    cJSON *b = cJSON_CreateObject();
    cJSON_AddBoolToObject(b, "ok", 1);
    return b;
}

static cJSON *ok_with_job(const job_t *j)
{
    cJSON *b = ok_body();
    cJSON_AddItemToObject(b, "job", job_json(j, 0));
    return b;
}

static int inflight_find(const master_t *m, const char *rid)
{
    for (size_t i = 0; i < m->inflight_n; i++)
        if (strcmp(m->inflight[i], rid) == 0)
            return (int)i;
    return -1;
}

static void inflight_add(master_t *m, const char *rid)
{
    if (m->inflight_n == m->inflight_cap) {
        size_t cap = m->inflight_cap ? 2 * m->inflight_cap : 16;
        char(*n)[MASTER_MAX_REQUEST_ID + 1] = realloc(m->inflight, cap * sizeof *n);
        if (!n)
            return; /* a duplicate may then make a second job: rare and harmless */
        m->inflight = n;
        m->inflight_cap = cap;
    }
    snprintf(m->inflight[m->inflight_n++], sizeof m->inflight[0], "%s", rid);
}

static void inflight_remove(master_t *m, const char *rid)
{
    int i = inflight_find(m, rid);
    if (i >= 0)
        memmove(&m->inflight[i], &m->inflight[i + 1],
                (m->inflight_n - (size_t)i - 1) * sizeof m->inflight[0]);
    if (i >= 0)
        m->inflight_n--;
}

static cJSON *duplicate_body(const job_t *j)
{
    /* the client retried after a lost reply: the job exists already */
    cJSON *b = ok_body();
    cJSON_AddNumberToObject(b, "job", (double)j->id);
    cJSON_AddBoolToObject(b, "duplicate", 1);
    return b;
}

static const char *request_id_of(const cJSON *req)
{
    const cJSON *rid = cJSON_GetObjectItemCaseSensitive(req, "request_id");
    return cJSON_IsString(rid) && strlen(rid->valuestring) <= MASTER_MAX_REQUEST_ID
               ? rid->valuestring
               : NULL;
}

/* The request goes to the offload thread (scene loading, storing); the
 * reply follows when it is done (ctl_offload_done). */
static cJSON *ctl_submit(ctl_req_t *r)
{
    master_t *m = r->m;
    const char *rid = request_id_of(r->body);
    job_t *dup = rid ? job_find_by_request(m, rid) : NULL;
    if (dup)
        return duplicate_body(dup);
    const char *client = r->client;
    uint32_t queued = 0;
    for (job_t *j = m->jobs; j; j = j->next)
        queued += !job_ended(j) && strcmp(j->owner, client) == 0;
    if (queued >= m->cfg.max_queued_per_client)
        return error_body("this client has %u jobs queued or running; the master takes at most %u "
                          "(--max-queued-per-client)",
                          queued, m->cfg.max_queued_per_client);
    offload_item_t *it = offload_item_new(OFFLOAD_SUBMIT);
    if (!it || !(it->req = cJSON_Duplicate(r->body, 1))) {
        offload_item_free(it);
        return error_body("out of memory");
    }
    zmq_msg_copy(&it->client, r->id);
    snprintf(it->owner, sizeof it->owner, "%s", client);
    zmq_msg_move(&it->frames[0], r->json_frame);
    for (int i = 0; i < r->nextra; i++)
        zmq_msg_move(&it->frames[1 + i], &r->extra[i]);
    it->nframes = 1 + r->nextra;
    if (rid && inflight_find(m, rid) >= 0)
        it->kind = OFFLOAD_SUBMIT_DUPLICATE; /* answered once the first is in */
    else if (rid)
        inflight_add(m, rid);
    offload_push(m->offload, it);
    return NULL;
}

/* A submission the offload thread has checked (and stored). */
static void submit_done(master_t *m, offload_item_t *it)
{
    const char *rid = request_id_of(it->req);
    job_t *dup = rid ? job_find_by_request(m, rid) : NULL;
    cJSON *b;
    if (it->kind == OFFLOAD_SUBMIT_DUPLICATE && dup) {
        b = duplicate_body(dup);
    } else if (it->kind == OFFLOAD_SUBMIT_DUPLICATE) {
        b = error_body("the first try of this request failed; submit again");
    } else if (!it->job) {
        master_log_limited(m, "refused-submission", "refused a submission: %s", it->err);
        b = error_body("%s", it->err);
    } else {
        job_t *j = it->job;
        it->job = NULL;
        if (!m->store)
            j->id = ++m->next_job;
        j->submitted = master_now();
        job_append(m, j);
        master_log(m, "job %" PRIu64 " queued: %s", j->id, j->name);
        b = ok_body();
        cJSON_AddNumberToObject(b, "job", (double)j->id);
    }
    if (rid && it->kind == OFFLOAD_SUBMIT)
        inflight_remove(m, rid);
    reply_json(m, &it->client, b);
    cJSON_Delete(b);
}

static cJSON *ctl_jobs(ctl_req_t *r)
{
    cJSON *b = ok_body();
    cJSON *arr = cJSON_AddArrayToObject(b, "jobs");
    for (job_t *j = r->m->jobs; j; j = j->next)
        if (may_act(r, j))
            cJSON_AddItemToArray(arr, job_json(j, 0));
    return b;
}

/* The master's queue and task counters, into the workers reply's "master"
 * object: every job in memory counts, whoever owns it (numbers only). */
static void master_queue_json(const master_t *m, cJSON *st)
{
    uint64_t queued = 0, running = 0, outstanding = 0, reissued = m->reissued_deleted_jobs;
    for (const job_t *j = m->jobs; j; j = j->next) {
        queued += j->state == JOB_QUEUED;
        running += j->state == JOB_RUNNING;
        outstanding += j->state == JOB_RUNNING ? j->outstanding : 0;
        reissued += j->reissued;
    }
    cJSON_AddNumberToObject(st, "jobs_queued", (double)queued);
    cJSON_AddNumberToObject(st, "jobs_running", (double)running);
    cJSON_AddNumberToObject(st, "tasks_outstanding", (double)outstanding);
    cJSON_AddNumberToObject(st, "tasks_issued", (double)m->tasks_issued);
    cJSON_AddNumberToObject(st, "tasks_reissued", (double)reissued);
}

static cJSON *ctl_workers(ctl_req_t *r)
{
    master_t *m = r->m;
    cJSON *b = ok_body();
    cJSON *arr = cJSON_AddArrayToObject(b, "workers");
    double now = master_now();
    for (uint32_t i = 0; i < m->worker_count; i++) {
        peer_t *w = &m->workers[i];
        if (!w->alive)
            continue;
        cJSON *o = cJSON_CreateObject();
        cJSON_AddStringToObject(o, "host", w->host);
        cJSON_AddNumberToObject(o, "threads", w->threads);
        cJSON_AddNumberToObject(o, "tasks_done", (double)w->tasks_done);
        cJSON_AddNumberToObject(o, "tasks_outstanding", w->outstanding);
        cJSON_AddNumberToObject(o, "tasks_reissued", (double)w->tasks_reissued);
        cJSON_AddNumberToObject(o, "backups", (double)w->backups);
        cJSON_AddNumberToObject(o, "bad_results", w->bad_results);
        /* breaker: its leases kept running out, it gets no task until it answers */
        cJSON_AddStringToObject(o, "state", peer_breaker_open(w) ? "breaker" : "ok");
        cJSON_AddNumberToObject(o, "last_seen_seconds", now - w->last_seen);
        cJSON_AddNumberToObject(o, "rays", (double)w->rays);
        cJSON_AddNumberToObject(o, "samples", (double)w->samples);
        cJSON_AddNumberToObject(o, "busy_seconds", w->busy_us / 1e6);
        cJSON_AddNumberToObject(o, "seconds", now - w->joined);
        cJSON_AddNumberToObject(o, "rays_per_second",
                                w->busy_us ? w->rays / (w->busy_us / 1e6) * w->threads : 0);
        cJSON_AddStringToObject(o, "build", w->build);
        cJSON_AddItemToArray(arr, o);
    }
    /* what the master dropped: bad input is counted, and logged only at a
     * bounded rate */
    cJSON *st = cJSON_AddObjectToObject(b, "master");
    cJSON_AddNumberToObject(st, "malformed_messages", (double)m->malformed);
    cJSON_AddNumberToObject(st, "late_results", (double)m->dropped_late);
    cJSON_AddNumberToObject(st, "requeue_refused", (double)m->requeue_refused);
    cJSON_AddNumberToObject(st, "rate_limited_requests", (double)m->rate_limited);
    cJSON_AddNumberToObject(st, "backups", (double)m->backups);
    cJSON_AddNumberToObject(st, "workers_banned", (double)m->banned);
    peer_bans_json(m, cJSON_AddArrayToObject(st, "bans"), now);
    master_queue_json(m, st);
    if (m->store) {
        /* the last background write of checkpoints and images: what it costs */
        store_bg_stats_t bg = store_bg_last(m->store);
        cJSON_AddNumberToObject(st, "state_writes", (double)bg.runs);
        cJSON_AddNumberToObject(st, "state_write_seconds", bg.wall_s);
        cJSON_AddNumberToObject(st, "state_write_cpu_seconds", bg.cpu_s);
        cJSON_AddNumberToObject(st, "state_fork_ms", bg.fork_ms);
        cJSON_AddNumberToObject(st, "checkpoint_writes", (double)m->ckpt_runs);
        cJSON_AddNumberToObject(st, "checkpoint_cpu_seconds", m->ckpt_cpu_s);
        cJSON_AddNumberToObject(st, "checkpoint_wall_seconds", m->ckpt_wall_s);
        cJSON_AddNumberToObject(st, "checkpoint_fork_ms_max", m->ckpt_fork_ms_max);
        /* checkpoints as snapshots and journal commits: what they write
         * against the results they hold (the wire size of the records) */
        cJSON_AddNumberToObject(st, "journal_commits", (double)m->journal_commits);
        cJSON_AddNumberToObject(st, "journal_bytes_written", (double)m->journal_bytes_written);
        cJSON_AddNumberToObject(st, "snapshots_written", (double)m->snapshots_written);
        cJSON_AddNumberToObject(st, "snapshot_bytes_written", (double)m->snapshot_bytes_written);
        cJSON_AddNumberToObject(st, "results_bytes_merged", (double)m->results_bytes_merged);
    }
    return b;
}

static cJSON *ctl_shutdown(ctl_req_t *r)
{
    if (!r->m->cfg.allow_shutdown)
        return error_body("this master does not take shutdown requests (send it SIGTERM)");
    r->m->shutdown = 1;
    return ok_body();
}

static cJSON *ctl_status(ctl_req_t *r)
{
    return ok_with_job(r->job);
}

static cJSON *ctl_cancel(ctl_req_t *r)
{
    if (r->job->state == JOB_QUEUED || r->job->state == JOB_RUNNING)
        job_finish(r->m, r->job, JOB_CANCELLED, "cancelled by a client");
    return ok_with_job(r->job);
}

static cJSON *ctl_delete(ctl_req_t *r)
{
    uint64_t id = r->job->id;
    job_delete(r->m, r->job);
    r->job = NULL;
    master_log(r->m, "job %" PRIu64 " deleted by a client", id);
    cJSON *b = ok_body();
    cJSON_AddNumberToObject(b, "deleted", (double)id);
    return b;
}

/* The reply to fetch: the job's status, its channel names, then one frame
 * per channel. */
static void send_image(master_t *m, zmq_msg_t *client, const job_t *j, const image_t *img)
{
    cJSON *b = ok_body();
    cJSON_AddItemToObject(b, "job", job_json(j, 1));
    cJSON *ch = cJSON_AddArrayToObject(b, "channels");
    for (int c = 0; c < img->channel_count; c++)
        cJSON_AddItemToArray(ch, cJSON_CreateString(img->channel_names[c]));
    size_t plane = (size_t)img->width * img->height * sizeof(float);
    const void *planes[IMAGE_MAX_CHANNELS];
    size_t sizes[IMAGE_MAX_CHANNELS];
    for (int c = 0; c < img->channel_count; c++) {
        planes[c] = img->channels[c];
        sizes[c] = plane;
    }
    reply_parts(m, client, b, planes, sizes, (size_t)img->channel_count);
    cJSON_Delete(b);
}

/* An ended job's image is on disk: the offload thread reads it, off the
 * loop, and the reply follows (ctl_offload_done). A preview's read carries
 * its size limits in req; a fetch's has none. */
static cJSON *read_stored_image(ctl_req_t *r, cJSON *preview_req)
{
    offload_item_t *it = offload_item_new(OFFLOAD_FETCH);
    if (!it) {
        cJSON_Delete(preview_req);
        return error_body("out of memory");
    }
    zmq_msg_copy(&it->client, r->id);
    it->job_id = r->job->id;
    it->req = preview_req;
    persist_image_path(r->m, r->job, it->path, sizeof it->path);
    offload_push(r->m->offload, it);
    return NULL;
}

static cJSON *ctl_fetch(ctl_req_t *r)
{
    master_t *m = r->m;
    job_t *j = r->job;
    if (!j->sched)
        return read_stored_image(r, NULL);
    image_t *img = sched_image(j->sched);
    if (!img)
        return error_body("fetch: out of memory");
    send_image(m, r->id, j, img);
    image_destroy(&img);
    return NULL;
}

/* The job a stored image was read for, or NULL once the client has been
 * told why not. */
static job_t *read_for_job(master_t *m, offload_item_t *it, const char *cmd)
{
    job_t *j = job_find(m, it->job_id);
    cJSON *b = NULL;
    if (!j)
        b = error_body("%s: no such job %" PRIu64 " (deleted meanwhile)", cmd, it->job_id);
    else if (!it->image)
        b = error_body("%s: %s", cmd, it->err);
    if (b) {
        reply_json(m, &it->client, b);
        cJSON_Delete(b);
        return NULL;
    }
    return j;
}

static void fetch_done(master_t *m, offload_item_t *it)
{
    job_t *j = read_for_job(m, it, "fetch");
    if (j)
        send_image(m, &it->client, j, it->image);
}

/* ---- preview ------------------------------------------------------------------------- */

#define CTL_PREVIEW_DEFAULT 256
#define CTL_PREVIEW_MAX 4096

/* "max_width" or "max_height" of a preview request into *out: absent, the
 * default; -1 if present and not an integer 1..CTL_PREVIEW_MAX. */
static int preview_limit(const cJSON *req, const char *field, int *out)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(req, field);
    if (!v) {
        *out = CTL_PREVIEW_DEFAULT;
        return 0;
    }
    if (!cJSON_IsNumber(v) || !(v->valuedouble >= 1 && v->valuedouble <= CTL_PREVIEW_MAX) ||
        v->valuedouble != floor(v->valuedouble))
        return -1;
    *out = (int)v->valuedouble;
    return 0;
}

/* The reply to preview: the job's status and the preview's size, then a
 * frame of RGB (3 floats a pixel) and one of mean samples per pixel. */
static void send_preview(master_t *m, zmq_msg_t *client, const job_t *j, int w, int h,
                         const float *rgb, const float *spp)
{
    size_t n = (size_t)w * h;
    cJSON *b = ok_with_job(j);
    cJSON_AddNumberToObject(b, "width", w);
    cJSON_AddNumberToObject(b, "height", h);
    cJSON_AddNumberToObject(b, "spp_max", preview_max(spp, n));
    const void *planes[2] = {rgb, spp};
    size_t sizes[2] = {n * 3 * sizeof *rgb, n * sizeof *spp};
    reply_parts(m, client, b, planes, sizes, 2);
    cJSON_Delete(b);
}

/* The preview of a job whose film is in memory. The job keeps it (one
 * size, the last asked for), so polling it again redoes only the rows
 * merged into since: a dashboard's 0.25 s refresh of a running 1920x1080
 * film costs a few rows, not a pass over 180 MB of pixels. */
static cJSON *reply_film_preview(ctl_req_t *r, int max_w, int max_h)
{
    job_t *j = r->job;
    const film_t *f = sched_film(j->sched);
    int w, h, pw = 0, ph = 0;
    const float *rgb, *spp;
    preview_fit(f->width, f->height, max_w, max_h, &w, &h);
    if (j->preview)
        preview_planes(j->preview, &pw, &ph, &rgb, &spp);
    if (pw != w || ph != h)
        preview_destroy(&j->preview);
    if (!j->preview)
        j->preview = preview_new(w, h);
    if (!j->preview || preview_update(j->preview, f) < 0) {
        preview_destroy(&j->preview);
        return error_body("preview: out of memory");
    }
    preview_planes(j->preview, &w, &h, &rgb, &spp);
    send_preview(r->m, r->id, j, w, h, rgb, spp);
    return NULL;
}

static cJSON *ctl_preview(ctl_req_t *r)
{
    int max_w, max_h;
    if (preview_limit(r->body, "max_width", &max_w) < 0)
        return error_body("preview: \"max_width\" must be an integer from 1 to %d",
                          CTL_PREVIEW_MAX);
    if (preview_limit(r->body, "max_height", &max_h) < 0)
        return error_body("preview: \"max_height\" must be an integer from 1 to %d",
                          CTL_PREVIEW_MAX);
    job_t *j = r->job;
    if (j->sched)
        return reply_film_preview(r, max_w, max_h);
    int w, h, pw = 0, ph = 0;
    const float *rgb, *spp;
    preview_fit((int)j->width, (int)j->height, max_w, max_h, &w, &h);
    if (j->preview)
        preview_planes(j->preview, &pw, &ph, &rgb, &spp);
    if (pw == w && ph == h) { /* made from its stored image before (preview_done) */
        send_preview(r->m, r->id, j, w, h, rgb, spp);
        return NULL;
    }
    cJSON *limits = cJSON_CreateObject();
    if (!limits || !cJSON_AddNumberToObject(limits, "max_width", max_w) ||
        !cJSON_AddNumberToObject(limits, "max_height", max_h)) {
        cJSON_Delete(limits);
        return error_body("out of memory");
    }
    return read_stored_image(r, limits);
}

/* The preview of an ended job, from its stored image. The job keeps it,
 * so a dashboard that goes on polling a finished job does not have the
 * image read and decoded again each time; one such job at a time, since
 * ended jobs can be many. */
static void preview_done(master_t *m, offload_item_t *it)
{
    job_t *j = read_for_job(m, it, "preview");
    if (!j)
        return;
    int max_w = CTL_PREVIEW_DEFAULT, max_h = CTL_PREVIEW_DEFAULT, w, h;
    (void)preview_limit(it->req, "max_width", &max_w); /* checked by ctl_preview */
    (void)preview_limit(it->req, "max_height", &max_h);
    preview_fit(it->image->width, it->image->height, max_w, max_h, &w, &h);
    preview_t *p = preview_new(w, h);
    if (!p || preview_fill_image(p, it->image) < 0) {
        cJSON *b = error_body(!p ? "preview: out of memory"
                                 : "preview: the stored image has no R, G and B channels");
        reply_json(m, &it->client, b);
        cJSON_Delete(b);
        preview_destroy(&p);
        return;
    }
    const float *rgb, *spp;
    preview_planes(p, &w, &h, &rgb, &spp);
    send_preview(m, &it->client, j, w, h, rgb, spp);
    for (job_t *o = m->jobs; o; o = o->next)
        if (!o->sched)
            preview_destroy(&o->preview);
    j->preview = p;
}

void ctl_offload_done(master_t *m)
{
    offload_item_t *it = offload_take_done(m->offload);
    while (it) {
        offload_item_t *next = it->next;
        if (it->kind == OFFLOAD_FETCH && it->req)
            preview_done(m, it);
        else if (it->kind == OFFLOAD_FETCH)
            fetch_done(m, it);
        else
            submit_done(m, it);
        offload_item_free(it);
        it = next;
    }
}

static cJSON *ctl_readmit(ctl_req_t *r)
{
    const cJSON *who = cJSON_GetObjectItemCaseSensitive(r->body, "worker");
    if (!cJSON_IsString(who))
        return error_body("readmit: give \"worker\": its key, or its address without keys");
    if (peer_readmit(r->m, who->valuestring) < 0)
        return error_body("readmit: %.200s is not quarantined", who->valuestring);
    return ok_body();
}

static const ctl_command_t ctl_commands[] = {
    {"submit", ctl_submit, 1, 0, 0},   {"status", ctl_status, 0, 1, 0},
    {"jobs", ctl_jobs, 0, 0, 0},       {"workers", ctl_workers, 0, 0, 0},
    {"cancel", ctl_cancel, 0, 1, 0},   {"fetch", ctl_fetch, 0, 1, 0},
    {"delete", ctl_delete, 0, 1, 0},   {"shutdown", ctl_shutdown, 0, 0, 0},
    {"readmit", ctl_readmit, 0, 0, 1}, {"preview", ctl_preview, 0, 1, 0},
};

static const ctl_command_t *find_command(const char *name)
{
    for (size_t i = 0; i < sizeof ctl_commands / sizeof ctl_commands[0]; i++)
        if (strcmp(ctl_commands[i].name, name) == 0)
            return &ctl_commands[i];
    return NULL;
}

int ctl_job_id(const cJSON *req, uint64_t *id)
{
    const cJSON *jid = cJSON_GetObjectItemCaseSensitive(req, "job");
    if (!cJSON_IsNumber(jid))
        return -1;
    double v = jid->valuedouble;
    if (!(v >= 1 && v <= 9007199254740992.0) || v != floor(v))
        return -1;
    *id = (uint64_t)v;
    return 0;
}

static cJSON *answer(ctl_req_t *r, int overflow)
{
    const cJSON *cmd = r->body ? cJSON_GetObjectItemCaseSensitive(r->body, "cmd") : NULL;
    if (overflow)
        return error_body("too many frames (at most %d mesh files)", PROTO_MAX_MESHES);
    const ctl_command_t *c = cJSON_IsString(cmd) ? find_command(cmd->valuestring) : NULL;
    if (!c)
        r->m->malformed++; /* counted with the worker port's: both are bad input */
    if (!r->body || !cJSON_IsObject(r->body))
        return error_body("request is not a JSON object");
    if (!cJSON_IsString(cmd))
        return error_body("request has no \"cmd\"");
    if (!c)
        return error_body(
            "unknown command \"%.64s\" (submit, status, jobs, workers, cancel, fetch, delete)",
            cmd->valuestring);
    if (!c->takes_frames && r->nextra > 0)
        return error_body("%s takes no binary frames", c->name);
    if (c->needs_job) {
        uint64_t id;
        if (ctl_job_id(r->body, &id) < 0)
            return error_body("%s: give \"job\": N, a job id", c->name);
        if (!(r->job = job_find(r->m, id)))
            return error_body("%s: no such job %" PRIu64, c->name, id);
        if (!may_act(r, r->job))
            return error_body("%s: job %" PRIu64
                              " belongs to another client (an admin key may act on it)",
                              c->name, id);
    }
    if (c->admin_only && r->keyed && !r->admin)
        return error_body("%s: only an admin key may do this", c->name);
    return c->handler(r);
}

void ctl_handle_message(master_t *m)
{
    /* each part is bounded by the socket's ZMQ_MAXMSGSIZE and their number
     * here; submit checks the bundle's total itself */
    proto_frames_t fr;
    int overflow = proto_recv(m->control_sock, &fr, PROTO_FRAMES_MAX, SIZE_MAX, ZMQ_DONTWAIT) ==
                   PROTO_RECV_TOO_MANY;
    zmq_msg_t *frames = fr.part;
    int n = fr.count;
    /* [identity][empty][json][binary...] as a REQ socket sends them */
    if (n < 3 || zmq_msg_size(&frames[1]) != 0) {
        m->malformed++;
        master_log_limited(m, "control-malformed", "dropped a malformed control message");
        proto_frames_close(&fr);
        return;
    }
    if (!master_peer_allowed(m, AUTH_DOMAIN_CONTROL, &frames[2])) {
        /* its key left the allow-lists (SIGHUP) while it was connected */
        master_log_limited(m, "client-key-revoked",
                           "refused a request: client key %s no longer allowed",
                           master_peer_key(&frames[2]));
        cJSON *b = error_body("this client's key is no longer allowed by the master");
        reply_json(m, &frames[0], b);
        cJSON_Delete(b);
        proto_frames_close(&fr);
        return;
    }
    cJSON *req = cJSON_ParseWithLength(zmq_msg_data(&frames[2]), zmq_msg_size(&frames[2]));
    ctl_req_t r = {.m = m,
                   .id = &frames[0],
                   .body = req,
                   .json_frame = &frames[2],
                   .extra = frames + 3,
                   .nextra = n - 3};
    client_of(&frames[2], r.client, sizeof r.client);
    const char *key = zmq_msg_gets(&frames[2], "User-Id");
    r.keyed = key && *key;
    r.admin = r.keyed && master_is_admin(m, key);
    cJSON *b;
    if (!rate_ok(m, &frames[0], master_now())) {
        m->rate_limited++;
        b = error_body("too many requests: this master answers at most %u a second per connection",
                       m->cfg.max_requests_per_s);
    } else {
        b = answer(&r, overflow);
    }
    if (b) {
        reply_json(m, &frames[0], b);
        cJSON_Delete(b);
    }
    cJSON_Delete(req);
    proto_frames_close(&fr);
}
