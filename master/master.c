/* master.c - see master.h.
 *
 * Work is fenced by (job, task, attempt): a result counts only if its job
 * is running, its task is outstanding with that worker, and its attempt is
 * the task's current one; anything else is late or a duplicate and is
 * dropped. A worker that goes silent, says BYE or fails to take a message
 * loses its tasks, which go back to the scheduler and out again with the
 * next attempt number. Bad messages are logged, counted and dropped: the
 * master never exits on input.
 */
#include "master.h"

#include <cJSON.h>
#include <errno.h>
#include <inttypes.h>
#include <math.h>
#include <sodium.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <zmq.h>

#include "compare.h"
#include "film.h"
#include "proto.h"
#include "vblog.h"
#include "scene.h"
#include "sched.h"

#define MAX_WORKERS 4096
#define MAX_IDENTITY 255
#define MAX_TASK_FAILURES 8
#define CONTROL_MAX_BYTES ((int64_t)PROTO_MAX_BUNDLE + (1 << 20))

typedef enum { JOB_QUEUED, JOB_RUNNING, JOB_DONE, JOB_FAILED, JOB_CANCELLED } job_state_t;
static const char *const job_state_names[] = {"queued", "running", "done", "failed", "cancelled"};

typedef struct worker {
    uint8_t id[MAX_IDENTITY];
    size_t id_len;
    char host[64];
    char build[PROTO_BUILD_SIZE + 1];
    uint32_t threads;
    uint32_t credit;
    uint32_t outstanding;
    double joined, last_seen, last_sent;
    uint64_t rays, tasks_done, busy_us, samples;
    int alive;
} remote_t;

typedef struct job {
    uint64_t id;
    job_state_t state;
    char error[512];
    char name[128];
    /* the bundle, shipped to workers by hash */
    uint8_t hash[PROTO_HASH_SIZE];
    char *json;
    size_t json_size;
    uint32_t mesh_count;
    char (*mesh_names)[PROTO_MAX_NAME + 1];
    uint8_t **mesh_data;
    uint32_t *mesh_sizes;
    /* settings */
    uint32_t width, height, spp, granularity;
    sched_adaptive_t adaptive;
    tracer_settings_t tracer;
    double time_limit, target_error;
    /* progress */
    sched_t *sched;
    uint32_t *attempt;  /* per task id - 1 */
    int32_t *holder;    /* per task id - 1: worker slot, -1 none */
    double *deadline;   /* per task id - 1 */
    uint32_t outstanding, reissued, failures;
    double submitted, started, finished;
    uint64_t rays, busy_us, late_results;
    int stopped_issuing; /* time limit reached: no new tasks */
    /* error against a reference (--reference), over time and samples */
    float *ref[3], *cur[3];
    double *series; /* 4 per point: seconds, samples, relMSE, RMSE */
    size_t series_n, series_cap;
    double last_eval;
    uint32_t last_eval_layers;
    struct job *next;
} job_t;

struct master {
    master_config_t cfg;
    void *workers_sock, *control_sock;
    remote_t *workers;
    uint32_t worker_count;
    job_t *jobs, *jobs_tail;
    uint64_t next_job;
    uint32_t rr; /* round-robin start for dispatch */
    char build[PROTO_BUILD_SIZE + 1];
    uint8_t *payload;  /* encode buffer */
    size_t payload_cap;
    tracer_result_t *results; /* decode buffer */
    tracer_task_t *task_records;
    uint64_t malformed, dropped_late;
    double last_heartbeat_check;
    int shutdown;
};

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void logf_(master_t *m, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void logf_(master_t *m, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vblog_write(m->cfg.log, "master", fmt, ap);
    va_end(ap);
}

/* ---- jobs ---------------------------------------------------------------- */

static void job_free(job_t *j)
{
    if (!j)
        return;
    sched_destroy(&j->sched);
    free(j->json);
    for (uint32_t i = 0; i < j->mesh_count; i++)
        if (j->mesh_data)
            free(j->mesh_data[i]);
    free(j->mesh_names);
    free(j->mesh_data);
    free(j->mesh_sizes);
    free(j->attempt);
    free(j->holder);
    free(j->deadline);
    for (int c = 0; c < 3; c++) {
        free(j->ref[c]);
        free(j->cur[c]);
    }
    free(j->series);
    free(j);
}

/* Appends the current error against the reference to the job's series. */
static void job_eval_error(job_t *j, double now)
{
    if (!j->ref[0] || !j->started)
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
    compare_planes((const float *const *)j->cur, (const float *const *)j->ref, n, NULL, 0.05, &r);
    if (j->series_n == j->series_cap) {
        size_t cap = j->series_cap ? 2 * j->series_cap : 64;
        double *ns = realloc(j->series, cap * 4 * sizeof(double));
        if (!ns)
            return;
        j->series = ns;
        j->series_cap = cap;
    }
    double *pt = j->series + 4 * j->series_n++;
    pt[0] = (j->finished ? j->finished : now) - j->started;
    pt[1] = (double)sched_samples_done(j->sched);
    pt[2] = r.relmse;
    pt[3] = r.rmse;
    j->last_eval = now;
    j->last_eval_layers = sched_layers_complete(j->sched);
}

static job_t *find_job(master_t *m, uint64_t id)
{
    for (job_t *j = m->jobs; j; j = j->next)
        if (j->id == id)
            return j;
    return NULL;
}

static job_t *find_job_by_hash(master_t *m, const uint8_t *hash)
{
    for (job_t *j = m->jobs; j; j = j->next)
        if (j->json && memcmp(j->hash, hash, PROTO_HASH_SIZE) == 0)
            return j;
    return NULL;
}

/* Drops the job's outstanding tasks (cancel, failure): their results will be
 * ignored as late. */
static void job_release_all(master_t *m, job_t *j)
{
    if (!j->holder)
        return;
    size_t cells = (size_t)sched_layer_count(j->sched) * sched_range_count(j->sched);
    for (size_t c = 0; c < cells; c++)
        if (j->holder[c] >= 0) {
            remote_t *w = &m->workers[j->holder[c]];
            if (w->outstanding)
                w->outstanding--;
            j->holder[c] = -1;
        }
    j->outstanding = 0;
}

static void job_finish(master_t *m, job_t *j, job_state_t st, const char *why)
{
    if (j->state == JOB_DONE || j->state == JOB_FAILED || j->state == JOB_CANCELLED)
        return;
    job_release_all(m, j);
    j->state = st;
    j->finished = now_s();
    job_eval_error(j, j->finished);
    if (why)
        snprintf(j->error, sizeof j->error, "%s", why);
    logf_(m, "job %" PRIu64 " %s after %.2f s: %" PRIu64 " samples, %" PRIu64 " rays%s%s",
          j->id, job_state_names[st], j->started ? j->finished - j->started : 0.0,
          sched_samples_done(j->sched), j->rays, why ? ": " : "", why ? why : "");
}

/* ---- sending -------------------------------------------------------------- */

static int ensure_payload(master_t *m, size_t need)
{
    if (need <= m->payload_cap)
        return 0;
    uint8_t *p = realloc(m->payload, need);
    if (!p)
        return -1;
    m->payload = p;
    m->payload_cap = need;
    return 0;
}

/* Sends msg to worker w; -1 if the worker is unreachable (it is then dead). */
static int send_to_worker(master_t *m, remote_t *w, proto_msg_t *msg)
{
    size_t need = proto_payload_size(msg);
    if (ensure_payload(m, need ? need : 1) < 0)
        return -1;
    uint8_t header[PROTO_HEADER_SIZE];
    char err[256];
    long n = proto_encode(msg, header, m->payload, m->payload_cap, err, sizeof err);
    if (n < 0) {
        logf_(m, "cannot encode %s: %s", proto_type_name(msg->h.type), err);
        return -1;
    }
    if (zmq_send(m->workers_sock, w->id, w->id_len, ZMQ_SNDMORE | ZMQ_DONTWAIT) < 0 ||
        zmq_send(m->workers_sock, header, PROTO_HEADER_SIZE, ZMQ_SNDMORE | ZMQ_DONTWAIT) < 0 ||
        zmq_send(m->workers_sock, m->payload, (size_t)n, ZMQ_DONTWAIT) < 0)
        return -1;
    w->last_sent = now_s();
    return 0;
}

static void send_raw_to(master_t *m, const uint8_t *id, size_t id_len, proto_msg_t *msg)
{
    remote_t tmp;
    memset(&tmp, 0, sizeof tmp);
    memcpy(tmp.id, id, id_len);
    tmp.id_len = id_len;
    send_to_worker(m, &tmp, msg);
}

/* ---- workers --------------------------------------------------------------- */

static remote_t *find_remote(master_t *m, const uint8_t *id, size_t len)
{
    for (uint32_t i = 0; i < m->worker_count; i++)
        if (m->workers[i].alive && m->workers[i].id_len == len && memcmp(m->workers[i].id, id, len) == 0)
            return &m->workers[i];
    return NULL;
}

/* Gives back every task the worker holds. */
static void remote_lost(master_t *m, remote_t *w, const char *why)
{
    int slot = (int)(w - m->workers);
    uint32_t back = 0;
    for (job_t *j = m->jobs; j; j = j->next) {
        if (j->state != JOB_RUNNING || !j->holder)
            continue;
        size_t cells = (size_t)sched_layer_count(j->sched) * sched_range_count(j->sched);
        for (size_t c = 0; c < cells; c++)
            if (j->holder[c] == slot) {
                j->holder[c] = -1;
                j->outstanding--;
                j->reissued++;
                sched_requeue(j->sched, (uint64_t)c + 1);
                back++;
            }
    }
    logf_(m, "worker %s (%u threads) gone: %s; %u task%s issued again", w->host, w->threads, why,
          back, back == 1 ? "" : "s");
    w->alive = 0;
    w->credit = 0;
    w->outstanding = 0;
}

/* ---- dispatch --------------------------------------------------------------- */

/* The oldest running job's next ready task, starting queued jobs as it goes. */
static job_t *next_task(master_t *m, sched_task_t *t, double now)
{
    for (job_t *j = m->jobs; j; j = j->next) {
        if (j->state == JOB_QUEUED) {
            j->state = JOB_RUNNING;
            j->started = now;
            logf_(m, "job %" PRIu64 " started: %s %ux%u, %u spp, G %u, adaptive %s", j->id, j->name, j->width,
                  j->height, j->spp, j->granularity, sched_adaptive_name(j->adaptive));
        }
        if (j->state != JOB_RUNNING || j->stopped_issuing)
            continue;
        if (sched_next(j->sched, t) == 1)
            return j;
    }
    return NULL;
}

/* Hands ready tasks to workers with credit, one task per worker in turn
 * (round robin from the worker after the last one served), so a trickle of
 * ready tasks spreads over all workers instead of filling the first. */
static void dispatch(master_t *m)
{
    double now = now_s();
    for (;;) {
        remote_t *w = NULL;
        uint32_t i = 0;
        for (uint32_t k = 0; k < m->worker_count && !w; k++) {
            i = (m->rr + k) % m->worker_count;
            if (m->workers[i].alive && m->workers[i].credit > 0)
                w = &m->workers[i];
        }
        if (!w)
            return;
        sched_task_t t;
        job_t *j = next_task(m, &t, now);
        if (!j)
            return;
        size_t c = (size_t)(t.id - 1);
        proto_msg_t *msg = calloc(1, sizeof *msg);
        if (!msg) {
            sched_requeue(j->sched, t.id);
            return;
        }
        msg->h.type = PROTO_TASK;
        msg->h.job = j->id;
        msg->h.task = t.id;
        msg->h.attempt = ++j->attempt[c];
        memcpy(msg->u.task.scene_hash, j->hash, PROTO_HASH_SIZE);
        msg->u.task.settings = j->tracer;
        msg->u.task.layer = t.layer;
        msg->u.task.count = t.count;
        msg->u.task.records = (tracer_task_t *)t.records;
        int rc = send_to_worker(m, w, msg);
        free(msg);
        m->rr = i + 1;
        if (rc < 0) {
            sched_requeue(j->sched, t.id);
            remote_lost(m, w, "unreachable");
            continue;
        }
        j->holder[c] = (int32_t)i;
        j->deadline[c] = now + m->cfg.lease_ms / 1000.0;
        j->outstanding++;
        w->outstanding++;
        w->credit--;
    }
}

/* ---- worker messages --------------------------------------------------------- */

static void on_result(master_t *m, remote_t *w, proto_msg_t *msg)
{
    job_t *j = find_job(m, msg->h.job);
    w->credit++; /* a result returns the task's credit */
    if (!j || j->state != JOB_RUNNING) {
        m->dropped_late++;
        return;
    }
    uint64_t id = msg->h.task;
    size_t cells = (size_t)sched_layer_count(j->sched) * sched_range_count(j->sched);
    int slot = (int)(w - m->workers);
    if (id == 0 || id > cells || j->holder[id - 1] != slot || j->attempt[id - 1] != msg->h.attempt) {
        j->late_results++;
        m->dropped_late++;
        return;
    }
    size_t c = (size_t)(id - 1);
    if (msg->h.type == PROTO_TASK_FAILED) {
        j->holder[c] = -1;
        j->outstanding--;
        w->outstanding--;
        j->failures++;
        logf_(m, "job %" PRIu64 " task %" PRIu64 " failed on %s: %s", j->id, id, w->host, msg->u.text.text);
        if (j->failures >= MAX_TASK_FAILURES) {
            char why[sizeof j->error];
            snprintf(why, sizeof why, "workers failed %u tasks; last: %.400s", j->failures, msg->u.text.text);
            job_finish(m, j, JOB_FAILED, why);
        } else {
            j->reissued++;
            sched_requeue(j->sched, id);
        }
        return;
    }
    char err[256];
    int rc = sched_complete(j->sched, id, msg->u.result.records, msg->u.result.count, err, sizeof err);
    j->holder[c] = -1;
    j->outstanding--;
    w->outstanding--;
    if (rc < 0) {
        /* a result that does not fit its task: drop it, issue the task again */
        m->malformed++;
        logf_(m, "job %" PRIu64 " task %" PRIu64 ": bad result from %s: %s", j->id, id, w->host, err);
        j->reissued++;
        sched_requeue(j->sched, id);
        return;
    }
    j->rays += msg->u.result.rays;
    j->busy_us += msg->u.result.busy_us;
    w->rays += msg->u.result.rays;
    w->busy_us += msg->u.result.busy_us;
    w->tasks_done++;
    for (uint32_t i = 0; i < msg->u.result.count; i++)
        w->samples += msg->u.result.records[i].samples + msg->u.result.records[i].nonfinite;
    if (sched_done(j->sched))
        job_finish(m, j, JOB_DONE, sched_stopped_on_target(j->sched) ? "target error reached" : NULL);
    else if (j->ref[0] && sched_layers_complete(j->sched) != j->last_eval_layers)
        job_eval_error(j, now_s()); /* a point per finished layer, however fast */
}

static void on_hello(master_t *m, const uint8_t *id, size_t id_len, const char *host, proto_msg_t *msg)
{
    proto_msg_t reply;
    memset(&reply, 0, sizeof reply);
    if (strcmp(msg->u.hello.build, m->build) != 0) {
        reply.h.type = PROTO_REFUSE;
        snprintf(reply.u.text.text, sizeof reply.u.text.text,
                 "build mismatch: master is %s, worker is %s (they could trace different bits)",
                 m->build, msg->u.hello.build);
        logf_(m, "refused worker %s: %s", host, reply.u.text.text);
        send_raw_to(m, id, id_len, &reply);
        return;
    }
    remote_t *w = find_remote(m, id, id_len);
    if (w) /* a reconnect with the same identity: forget its old tasks */
        remote_lost(m, w, "said hello again");
    uint32_t slot = m->worker_count;
    for (uint32_t i = 0; i < m->worker_count; i++)
        if (!m->workers[i].alive && m->workers[i].outstanding == 0) {
            slot = i;
            break;
        }
    if (slot == m->worker_count) {
        if (m->worker_count == MAX_WORKERS) {
            reply.h.type = PROTO_REFUSE;
            snprintf(reply.u.text.text, sizeof reply.u.text.text, "too many workers (%d)", MAX_WORKERS);
            send_raw_to(m, id, id_len, &reply);
            return;
        }
        m->worker_count++;
    }
    w = &m->workers[slot];
    memset(w, 0, sizeof *w);
    memcpy(w->id, id, id_len);
    w->id_len = id_len;
    snprintf(w->host, sizeof w->host, "%s", host);
    snprintf(w->build, sizeof w->build, "%s", msg->u.hello.build);
    w->threads = msg->u.hello.threads;
    w->joined = w->last_seen = now_s();
    w->alive = 1;
    reply.h.type = PROTO_WELCOME;
    reply.u.welcome.heartbeat_ms = m->cfg.heartbeat_ms;
    reply.u.welcome.lease_ms = m->cfg.lease_ms;
    logf_(m, "worker %s joined: %u threads, %s", w->host, w->threads, w->build);
    if (send_to_worker(m, w, &reply) < 0)
        remote_lost(m, w, "unreachable");
}

static void on_scene_request(master_t *m, remote_t *w, proto_msg_t *msg)
{
    job_t *j = find_job_by_hash(m, msg->u.scene_hash);
    if (!j) {
        logf_(m, "worker %s asked for an unknown scene", w->host);
        return;
    }
    proto_msg_t *b = calloc(1, sizeof *b);
    if (!b)
        return;
    b->h.type = PROTO_SCENE_BUNDLE;
    b->h.job = j->id;
    memcpy(b->u.bundle.hash, j->hash, PROTO_HASH_SIZE);
    b->u.bundle.json = j->json;
    b->u.bundle.json_size = (uint32_t)j->json_size;
    b->u.bundle.mesh_count = j->mesh_count;
    for (uint32_t i = 0; i < j->mesh_count; i++) {
        memcpy(b->u.bundle.meshes[i].name, j->mesh_names[i], sizeof b->u.bundle.meshes[i].name);
        b->u.bundle.meshes[i].data = j->mesh_data[i];
        b->u.bundle.meshes[i].size = j->mesh_sizes[i];
    }
    if (send_to_worker(m, w, b) < 0)
        remote_lost(m, w, "unreachable");
    free(b);
}

static void handle_worker_message(master_t *m)
{
    zmq_msg_t frames[3];
    int n = 0, more = 1;
    char host[64] = "?";
    while (more) {
        zmq_msg_t f;
        zmq_msg_init(&f);
        if (zmq_msg_recv(&f, m->workers_sock, ZMQ_DONTWAIT) < 0) {
            zmq_msg_close(&f);
            break;
        }
        more = zmq_msg_more(&f);
        if (n < 3) {
            if (n == 1) {
                const char *peer = zmq_msg_gets(&f, "Peer-Address");
                snprintf(host, sizeof host, "%s", peer ? peer : "local");
            }
            frames[n++] = f;
        } else {
            zmq_msg_close(&f);
            n = 4; /* too many frames */
        }
    }
    if (n != 3) {
        m->malformed++;
        logf_(m, "dropped a worker message with %s frames", n > 3 ? "too many" : "too few");
        for (int i = 0; i < (n < 3 ? n : 3); i++)
            zmq_msg_close(&frames[i]);
        return;
    }
    const uint8_t *id = zmq_msg_data(&frames[0]);
    size_t id_len = zmq_msg_size(&frames[0]);
    proto_msg_t *msg = calloc(1, sizeof *msg);
    if (!msg)
        goto out;
    msg->capacity = PROTO_MAX_TASK_PIXELS;
    msg->u.result.records = m->results;
    char err[256];
    int rc = proto_decode(zmq_msg_data(&frames[1]), zmq_msg_size(&frames[1]), zmq_msg_data(&frames[2]),
                          zmq_msg_size(&frames[2]), msg, err, sizeof err);
    if (rc == -2) {
        proto_msg_t reply;
        memset(&reply, 0, sizeof reply);
        reply.h.type = PROTO_REFUSE;
        snprintf(reply.u.text.text, sizeof reply.u.text.text, "master refuses: %s", err);
        logf_(m, "refused a peer: %s", err);
        send_raw_to(m, id, id_len, &reply);
        goto out;
    }
    if (rc < 0) {
        m->malformed++;
        logf_(m, "dropped a malformed worker message (%" PRIu64 " so far): %s", m->malformed, err);
        goto out;
    }
    if (msg->h.type == PROTO_HELLO) {
        on_hello(m, id, id_len, host, msg);
        goto out;
    }
    remote_t *w = find_remote(m, id, id_len);
    if (!w) {
        /* e.g. the master restarted: tell the worker to start over */
        proto_msg_t bye;
        memset(&bye, 0, sizeof bye);
        bye.h.type = PROTO_BYE;
        snprintf(bye.u.text.text, sizeof bye.u.text.text, "unknown worker: say HELLO first");
        send_raw_to(m, id, id_len, &bye);
        goto out;
    }
    w->last_seen = now_s();
    switch (msg->h.type) {
    case PROTO_CREDIT:
        w->credit = w->credit + msg->u.credit > PROTO_MAX_CREDIT ? PROTO_MAX_CREDIT : w->credit + msg->u.credit;
        break;
    case PROTO_SCENE_REQUEST:
        on_scene_request(m, w, msg);
        break;
    case PROTO_RESULT:
    case PROTO_TASK_FAILED:
        on_result(m, w, msg);
        break;
    case PROTO_HEARTBEAT:
        break;
    case PROTO_BYE:
        remote_lost(m, w, "said bye");
        break;
    default:
        m->malformed++;
        logf_(m, "dropped an out-of-protocol %s from worker %s", proto_type_name(msg->h.type), w->host);
        break;
    }
out:
    free(msg);
    for (int i = 0; i < 3; i++)
        zmq_msg_close(&frames[i]);
}

/* ---- control (JSON) ---------------------------------------------------------- */

static void reply_json(master_t *m, zmq_msg_t *id, cJSON *body, int more)
{
    char *text = cJSON_PrintUnformatted(body);
    zmq_send(m->control_sock, zmq_msg_data(id), zmq_msg_size(id), ZMQ_SNDMORE | ZMQ_DONTWAIT);
    zmq_send(m->control_sock, "", 0, ZMQ_SNDMORE | ZMQ_DONTWAIT);
    zmq_send(m->control_sock, text ? text : "{}", text ? strlen(text) : 2, (more ? ZMQ_SNDMORE : 0) | ZMQ_DONTWAIT);
    cJSON_free(text);
}

static cJSON *error_body(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
static cJSON *error_body(const char *fmt, ...)
{
    char msg[1024];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    cJSON *b = cJSON_CreateObject();
    cJSON_AddBoolToObject(b, "ok", 0);
    cJSON_AddStringToObject(b, "error", msg);
    return b;
}

static cJSON *job_json(master_t *m, job_t *j, int with_series)
{
    cJSON *o = cJSON_CreateObject();
    double now = now_s();
    double el = j->started ? (j->finished ? j->finished : now) - j->started : 0;
    uint64_t samples = sched_samples_done(j->sched);
    uint64_t max_samples = (uint64_t)j->spp * j->width * j->height;
    cJSON_AddNumberToObject(o, "id", (double)j->id);
    cJSON_AddStringToObject(o, "state", job_state_names[j->state]);
    cJSON_AddStringToObject(o, "scene", j->name);
    cJSON_AddNumberToObject(o, "width", j->width);
    cJSON_AddNumberToObject(o, "height", j->height);
    cJSON_AddNumberToObject(o, "spp", j->spp);
    cJSON_AddNumberToObject(o, "granularity", j->granularity);
    cJSON_AddStringToObject(o, "adaptive", sched_adaptive_name(j->adaptive));
    char seed[32];
    snprintf(seed, sizeof seed, "%" PRIu64, j->tracer.seed);
    cJSON_AddStringToObject(o, "seed", seed);
    cJSON_AddStringToObject(o, "integrator", scene_integrator_name(j->tracer.integrator));
    cJSON_AddNumberToObject(o, "layers", sched_layer_count(j->sched));
    cJSON_AddNumberToObject(o, "uniform_layers", sched_uniform_layers(j->sched));
    cJSON_AddNumberToObject(o, "layers_done", sched_layers_complete(j->sched));
    cJSON_AddNumberToObject(o, "samples", (double)samples);
    cJSON_AddNumberToObject(o, "max_samples", (double)max_samples);
    cJSON_AddNumberToObject(o, "pixel_layers_skipped", (double)sched_pixel_layers_skipped(j->sched));
    cJSON_AddNumberToObject(o, "rays", (double)j->rays);
    cJSON_AddNumberToObject(o, "seconds", el);
    cJSON_AddNumberToObject(o, "rays_per_second", el > 0 ? j->rays / el : 0);
    cJSON_AddNumberToObject(o, "samples_per_second", el > 0 ? samples / el : 0);
    cJSON_AddNumberToObject(o, "busy_seconds", j->busy_us / 1e6);
    cJSON_AddNumberToObject(o, "tasks_reissued", j->reissued);
    cJSON_AddNumberToObject(o, "late_results", (double)j->late_results);
    cJSON_AddNumberToObject(o, "nonfinite", (double)sched_nonfinite(j->sched));
    cJSON_AddNumberToObject(o, "time_limit", j->time_limit);
    if (j->target_error > 0) {
        cJSON_AddNumberToObject(o, "target_error", j->target_error);
        cJSON_AddNumberToObject(o, "converged_pixels", (double)sched_converged(j->sched));
        cJSON_AddBoolToObject(o, "stopped_on_target", sched_stopped_on_target(j->sched));
    }
    if (j->series_n > 0) {
        const double *last = j->series + 4 * (j->series_n - 1);
        cJSON_AddNumberToObject(o, "relmse", last[2]);
        cJSON_AddNumberToObject(o, "rmse", last[3]);
    }
    if (with_series && j->series_n > 0) {
        cJSON *arr = cJSON_AddArrayToObject(o, "error_series");
        for (size_t i = 0; i < j->series_n; i++)
            cJSON_AddItemToArray(arr, cJSON_CreateDoubleArray(j->series + 4 * i, 4));
    }
    if (j->error[0])
        cJSON_AddStringToObject(o, "error", j->error);
    (void)m;
    return o;
}

static job_t *job_from_request(master_t *m, const cJSON *req, zmq_msg_t *frames, int nframes, char *err,
                               size_t errlen);

static void control_submit(master_t *m, zmq_msg_t *id, const cJSON *req, zmq_msg_t *extra, int nextra)
{
    char err[1024];
    job_t *j = job_from_request(m, req, extra, nextra, err, sizeof err);
    cJSON *b;
    if (!j) {
        b = error_body("%s", err);
        logf_(m, "refused a submission: %s", err);
    } else {
        j->id = ++m->next_job;
        j->submitted = now_s();
        if (m->jobs_tail)
            m->jobs_tail->next = j;
        else
            m->jobs = j;
        m->jobs_tail = j;
        logf_(m, "job %" PRIu64 " queued: %s", j->id, j->name);
        b = cJSON_CreateObject();
        cJSON_AddBoolToObject(b, "ok", 1);
        cJSON_AddNumberToObject(b, "job", (double)j->id);
    }
    reply_json(m, id, b, 0);
    cJSON_Delete(b);
}

static void control_fetch(master_t *m, zmq_msg_t *id, job_t *j)
{
    const film_t *f = sched_film(j->sched);
    image_t *img = film_to_image(f);
    if (!img) {
        cJSON *b = error_body("out of memory");
        reply_json(m, id, b, 0);
        cJSON_Delete(b);
        return;
    }
    cJSON *b = cJSON_CreateObject();
    cJSON_AddBoolToObject(b, "ok", 1);
    cJSON_AddItemToObject(b, "job", job_json(m, j, 1));
    cJSON *ch = cJSON_AddArrayToObject(b, "channels");
    for (int c = 0; c < img->channel_count; c++)
        cJSON_AddItemToArray(ch, cJSON_CreateString(img->channel_names[c]));
    reply_json(m, id, b, 1);
    cJSON_Delete(b);
    size_t plane = (size_t)img->width * img->height * sizeof(float);
    for (int c = 0; c < img->channel_count; c++)
        zmq_send(m->control_sock, img->channels[c], plane, (c + 1 < img->channel_count ? ZMQ_SNDMORE : 0) | ZMQ_DONTWAIT);
    image_destroy(&img);
}

static void handle_control_message(master_t *m)
{
    zmq_msg_t frames[PROTO_MAX_MESHES + 4];
    int n = 0, more = 1, overflow = 0;
    while (more) {
        zmq_msg_t f;
        zmq_msg_init(&f);
        if (zmq_msg_recv(&f, m->control_sock, ZMQ_DONTWAIT) < 0) {
            zmq_msg_close(&f);
            break;
        }
        more = zmq_msg_more(&f);
        if (n < (int)(sizeof frames / sizeof frames[0]))
            frames[n++] = f;
        else {
            zmq_msg_close(&f);
            overflow = 1;
        }
    }
    /* [identity][empty][json][binary...] as a REQ socket sends them */
    if (n < 3 || zmq_msg_size(&frames[1]) != 0) {
        m->malformed++;
        logf_(m, "dropped a malformed control message");
        for (int i = 0; i < n; i++)
            zmq_msg_close(&frames[i]);
        return;
    }
    zmq_msg_t *id = &frames[0];
    cJSON *req = cJSON_ParseWithLength(zmq_msg_data(&frames[2]), zmq_msg_size(&frames[2]));
    const cJSON *cmd = req ? cJSON_GetObjectItemCaseSensitive(req, "cmd") : NULL;
    cJSON *b = NULL;
    if (overflow) {
        b = error_body("too many frames (at most %d mesh files)", PROTO_MAX_MESHES);
    } else if (!req || !cJSON_IsObject(req)) {
        b = error_body("request is not a JSON object");
    } else if (!cJSON_IsString(cmd)) {
        b = error_body("request has no \"cmd\"");
    } else if (strcmp(cmd->valuestring, "submit") == 0) {
        control_submit(m, id, req, frames + 3, n - 3);
    } else if (n != 3) {
        b = error_body("%s takes no binary frames", cmd->valuestring);
    } else if (strcmp(cmd->valuestring, "jobs") == 0) {
        b = cJSON_CreateObject();
        cJSON_AddBoolToObject(b, "ok", 1);
        cJSON *arr = cJSON_AddArrayToObject(b, "jobs");
        for (job_t *j = m->jobs; j; j = j->next)
            cJSON_AddItemToArray(arr, job_json(m, j, 0));
    } else if (strcmp(cmd->valuestring, "workers") == 0) {
        b = cJSON_CreateObject();
        cJSON_AddBoolToObject(b, "ok", 1);
        cJSON *arr = cJSON_AddArrayToObject(b, "workers");
        double now = now_s();
        for (uint32_t i = 0; i < m->worker_count; i++) {
            remote_t *w = &m->workers[i];
            if (!w->alive)
                continue;
            cJSON *o = cJSON_CreateObject();
            cJSON_AddStringToObject(o, "host", w->host);
            cJSON_AddNumberToObject(o, "threads", w->threads);
            cJSON_AddNumberToObject(o, "tasks_done", (double)w->tasks_done);
            cJSON_AddNumberToObject(o, "tasks_outstanding", w->outstanding);
            cJSON_AddNumberToObject(o, "rays", (double)w->rays);
            cJSON_AddNumberToObject(o, "samples", (double)w->samples);
            cJSON_AddNumberToObject(o, "busy_seconds", w->busy_us / 1e6);
            double up = now - w->joined;
            cJSON_AddNumberToObject(o, "seconds", up);
            cJSON_AddNumberToObject(o, "rays_per_second", w->busy_us ? w->rays / (w->busy_us / 1e6) * w->threads : 0);
            cJSON_AddStringToObject(o, "build", w->build);
            cJSON_AddItemToArray(arr, o);
        }
    } else if (strcmp(cmd->valuestring, "shutdown") == 0) {
        if (m->cfg.allow_shutdown) {
            m->shutdown = 1;
            b = cJSON_CreateObject();
            cJSON_AddBoolToObject(b, "ok", 1);
        } else {
            b = error_body("this master does not take shutdown requests (send it SIGTERM)");
        }
    } else {
        const cJSON *jid = cJSON_GetObjectItemCaseSensitive(req, "job");
        job_t *j = cJSON_IsNumber(jid) ? find_job(m, (uint64_t)jid->valuedouble) : NULL;
        if (strcmp(cmd->valuestring, "status") != 0 && strcmp(cmd->valuestring, "cancel") != 0 &&
            strcmp(cmd->valuestring, "fetch") != 0) {
            b = error_body("unknown command \"%s\" (submit, status, jobs, workers, cancel, fetch)",
                           cmd->valuestring);
        } else if (!j) {
            b = error_body("%s: no such job%s", cmd->valuestring, cJSON_IsNumber(jid) ? "" : " (give \"job\": N)");
        } else if (strcmp(cmd->valuestring, "status") == 0) {
            b = cJSON_CreateObject();
            cJSON_AddBoolToObject(b, "ok", 1);
            cJSON_AddItemToObject(b, "job", job_json(m, j, 0));
        } else if (strcmp(cmd->valuestring, "cancel") == 0) {
            if (j->state == JOB_QUEUED || j->state == JOB_RUNNING)
                job_finish(m, j, JOB_CANCELLED, "cancelled by a client");
            b = cJSON_CreateObject();
            cJSON_AddBoolToObject(b, "ok", 1);
            cJSON_AddItemToObject(b, "job", job_json(m, j, 0));
        } else {
            control_fetch(m, id, j);
        }
    }
    if (b) {
        reply_json(m, id, b, 0);
        cJSON_Delete(b);
    }
    cJSON_Delete(req);
    for (int i = 0; i < n; i++)
        zmq_msg_close(&frames[i]);
}

/* Builds a job from a submit request: validates the whole scene (loaded
 * from the bundle exactly as a worker will load it) and every setting, so a
 * bad submission fails here, at the client, and never reaches a worker. */
static job_t *job_from_request(master_t *m, const cJSON *req, zmq_msg_t *frames, int nframes, char *err,
                               size_t errlen)
{
    (void)m;
    if (nframes < 1) {
        snprintf(err, errlen, "submit needs the scene JSON as its second frame");
        return NULL;
    }
    const cJSON *meshes = cJSON_GetObjectItemCaseSensitive(req, "meshes");
    int mesh_count = meshes ? cJSON_GetArraySize(meshes) : 0;
    if (meshes && !cJSON_IsArray(meshes)) {
        snprintf(err, errlen, "\"meshes\" must be an array of names");
        return NULL;
    }
    const cJSON *refspec = cJSON_GetObjectItemCaseSensitive(req, "reference");
    int ref_frames = refspec ? 3 : 0;
    if (mesh_count != nframes - 1 - ref_frames || mesh_count > PROTO_MAX_MESHES) {
        snprintf(err, errlen, "%d mesh names%s but %d frames after the scene", mesh_count,
                 ref_frames ? " and a reference (3 frames)" : "", nframes - 1);
        return NULL;
    }
    job_t *j = calloc(1, sizeof *j);
    if (!j) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    const cJSON *name = cJSON_GetObjectItemCaseSensitive(req, "name");
    snprintf(j->name, sizeof j->name, "%s", cJSON_IsString(name) ? name->valuestring : "scene.json");
    j->json_size = zmq_msg_size(&frames[0]);
    if (j->json_size > PROTO_MAX_SCENE_JSON) {
        snprintf(err, errlen, "scene JSON too large (%zu bytes)", j->json_size);
        goto fail;
    }
    j->json = malloc(j->json_size + 1);
    j->mesh_count = (uint32_t)mesh_count;
    j->mesh_names = calloc((size_t)mesh_count + 1, sizeof *j->mesh_names);
    j->mesh_data = calloc((size_t)mesh_count + 1, sizeof *j->mesh_data);
    j->mesh_sizes = calloc((size_t)mesh_count + 1, sizeof *j->mesh_sizes);
    scene_blob_t blobs[PROTO_MAX_MESHES];
    if (!j->json || !j->mesh_names || !j->mesh_data || !j->mesh_sizes) {
        snprintf(err, errlen, "out of memory");
        goto fail;
    }
    memcpy(j->json, zmq_msg_data(&frames[0]), j->json_size);
    j->json[j->json_size] = '\0';
    int i = 0;
    for (const cJSON *it = meshes ? meshes->child : NULL; it; it = it->next, i++) {
        if (!cJSON_IsString(it) || strlen(it->valuestring) == 0 || strlen(it->valuestring) > PROTO_MAX_NAME ||
            strchr(it->valuestring, '/') || strchr(it->valuestring, '\\')) {
            snprintf(err, errlen, "meshes[%d]: a name of 1 to %d characters without '/'", i, PROTO_MAX_NAME);
            goto fail;
        }
        size_t sz = zmq_msg_size(&frames[1 + i]);
        if (sz > PROTO_MAX_MESH_BYTES) {
            snprintf(err, errlen, "meshes[%d]: %zu bytes is over the limit", i, sz);
            goto fail;
        }
        snprintf(j->mesh_names[i], sizeof j->mesh_names[i], "%s", it->valuestring);
        for (int k = 0; k < i; k++)
            if (strcmp(j->mesh_names[k], j->mesh_names[i]) == 0) {
                snprintf(err, errlen, "meshes[%d]: \"%s\" given twice", i, j->mesh_names[i]);
                goto fail;
            }
        j->mesh_data[i] = malloc(sz ? sz : 1);
        if (!j->mesh_data[i]) {
            snprintf(err, errlen, "out of memory");
            goto fail;
        }
        memcpy(j->mesh_data[i], zmq_msg_data(&frames[1 + i]), sz);
        j->mesh_sizes[i] = (uint32_t)sz;
        blobs[i].name = j->mesh_names[i];
        blobs[i].data = j->mesh_data[i];
        blobs[i].size = sz;
    }
    scene_t *scene = NULL;
    char serr[900];
    if (scene_load_bundle(j->json, j->json_size, j->name, blobs, (size_t)mesh_count, &scene, serr, sizeof serr) < 0) {
        snprintf(err, errlen, "bad scene: %s", serr);
        goto fail;
    }
    j->width = (uint32_t)scene->camera.width;
    j->height = (uint32_t)scene->camera.height;
    j->spp = scene->spp;
    j->tracer.seed = scene->seed;
    j->tracer.integrator = scene->integrator;
    j->tracer.max_depth = scene->max_depth;
    scene_destroy(&scene);

    /* settings: each optional, checked */
    double v;
    const cJSON *it;
    j->granularity = 32;
    j->adaptive = SCHED_ADAPTIVE_THESIS;
    uint32_t uniform = UINT32_MAX;
    double confidence = 0.95, share = 1.0;
    int random_selection = 0, dilate = 0;
#define NUM_FIELD(key, lo, hi, dst)                                                               \
    if ((it = cJSON_GetObjectItemCaseSensitive(req, key)) != NULL) {                               \
        v = cJSON_IsNumber(it) ? it->valuedouble : NAN;                                            \
        if (!(v >= (lo) && v <= (hi)) || v != floor(v)) {                                          \
            snprintf(err, errlen, "%s must be an integer from %.0f to %.0f", key, (double)(lo),    \
                     (double)(hi));                                                                \
            goto fail;                                                                             \
        }                                                                                          \
        dst = v;                                                                                   \
    }
    NUM_FIELD("spp", 1, 4294967295.0, j->spp)
    NUM_FIELD("granularity", 1, TRACER_MAX_TASK_SAMPLES, j->granularity)
    NUM_FIELD("seed", 0, 9007199254740992.0, j->tracer.seed)
    NUM_FIELD("max_depth", 0, 1000000, j->tracer.max_depth)
    NUM_FIELD("uniform_layers", 0, 4294967294.0, uniform)
#undef NUM_FIELD
    if ((it = cJSON_GetObjectItemCaseSensitive(req, "time_limit")) != NULL) {
        if (!cJSON_IsNumber(it) || !(it->valuedouble >= 0) || !isfinite(it->valuedouble)) {
            snprintf(err, errlen, "time_limit must be a number of seconds >= 0");
            goto fail;
        }
        j->time_limit = it->valuedouble;
    }
    if ((it = cJSON_GetObjectItemCaseSensitive(req, "adaptive")) != NULL) {
        int a = cJSON_IsString(it) ? sched_adaptive_from_name(it->valuestring) : -1;
        if (a < 0) {
            snprintf(err, errlen, "adaptive must be \"thesis\", \"variance\", \"relerr\" or \"none\"");
            goto fail;
        }
        j->adaptive = (sched_adaptive_t)a;
    }
#define RANGE_FIELD(key, lo, hi, lo_open, dst)                                                       \
    if ((it = cJSON_GetObjectItemCaseSensitive(req, key)) != NULL) {                                \
        v = cJSON_IsNumber(it) ? it->valuedouble : NAN;                                             \
        if (!(v >= (lo) && v <= (hi)) || ((lo_open) && v == (lo))) {                                \
            snprintf(err, errlen, "%s must be in %s%g, %g]", key, (lo_open) ? "(" : "[", (double)(lo), \
                     (double)(hi));                                                                 \
            goto fail;                                                                              \
        }                                                                                           \
        dst = v;                                                                                    \
    }
    RANGE_FIELD("target_error", 0, 1e6, 1, j->target_error)
    RANGE_FIELD("confidence", 0, 0.999999, 1, confidence)
    RANGE_FIELD("target_share", 0, 1, 1, share)
#undef RANGE_FIELD
    if ((it = cJSON_GetObjectItemCaseSensitive(req, "random_selection")) != NULL)
        random_selection = cJSON_IsTrue(it);
    if ((it = cJSON_GetObjectItemCaseSensitive(req, "dilate")) != NULL)
        dilate = cJSON_IsTrue(it);
    if ((it = cJSON_GetObjectItemCaseSensitive(req, "integrator")) != NULL) {
        int in = cJSON_IsString(it) ? scene_integrator_from_name(it->valuestring) : -1;
        if (in < 0) {
            snprintf(err, errlen, "integrator must be \"path\" or \"naive\"");
            goto fail;
        }
        j->tracer.integrator = (scene_integrator_t)in;
    }
    const char *flags = NULL;
    if ((it = cJSON_GetObjectItemCaseSensitive(req, "flags")) != NULL) {
        if (!cJSON_IsString(it)) {
            snprintf(err, errlen, "flags must be a string of 0 and 1, one per layer");
            goto fail;
        }
        flags = it->valuestring;
    }
    sched_config_t sc = {.width = j->width, .height = j->height, .spp = j->spp, .granularity = j->granularity,
                         .adaptive = j->adaptive, .uniform_layers = uniform, .flags = flags,
                         .random_selection = random_selection, .dilate = dilate, .seed = j->tracer.seed,
                         .target_error = j->target_error, .confidence = confidence, .target_share = share};
    char schederr[256];
    j->sched = sched_new(&sc, schederr, sizeof schederr);
    if (!j->sched) {
        snprintf(err, errlen, "bad settings: %s", schederr);
        goto fail;
    }
    size_t cells = (size_t)sched_layer_count(j->sched) * sched_range_count(j->sched);
    j->attempt = calloc(cells, sizeof *j->attempt);
    j->holder = malloc(cells * sizeof *j->holder);
    j->deadline = calloc(cells, sizeof *j->deadline);
    if (!j->attempt || !j->holder || !j->deadline) {
        snprintf(err, errlen, "out of memory");
        goto fail;
    }
    for (size_t c = 0; c < cells; c++)
        j->holder[c] = -1;
    if (refspec) {
        /* the reference: three float32 planes R, G, B of the image's size */
        size_t plane = (size_t)j->width * j->height * sizeof(float);
        for (int c = 0; c < 3; c++) {
            zmq_msg_t *f = &frames[1 + mesh_count + c];
            if (zmq_msg_size(f) != plane) {
                snprintf(err, errlen, "reference: channel %d has %zu bytes, a %ux%u image needs %zu (another size?)",
                         c, zmq_msg_size(f), j->width, j->height, plane);
                goto fail;
            }
            j->ref[c] = malloc(plane);
            j->cur[c] = malloc(plane);
            if (!j->ref[c] || !j->cur[c]) {
                snprintf(err, errlen, "out of memory");
                goto fail;
            }
            memcpy(j->ref[c], zmq_msg_data(f), plane);
        }
    }
    /* content hash of the bundle: what workers cache scenes by */
    proto_bundle_t *view = calloc(1, sizeof *view);
    if (!view) {
        snprintf(err, errlen, "out of memory");
        goto fail;
    }
    view->json = j->json;
    view->json_size = (uint32_t)j->json_size;
    view->mesh_count = j->mesh_count;
    for (uint32_t k = 0; k < j->mesh_count; k++) {
        memcpy(view->meshes[k].name, j->mesh_names[k], sizeof view->meshes[k].name);
        view->meshes[k].data = j->mesh_data[k];
        view->meshes[k].size = j->mesh_sizes[k];
    }
    proto_bundle_hash(view, j->hash);
    free(view);
    j->state = JOB_QUEUED;
    return j;
fail:
    job_free(j);
    return NULL;
}

/* ---- timers -------------------------------------------------------------------- */

static void timers(master_t *m)
{
    double now = now_s();
    /* heartbeats out, silent workers dropped */
    for (uint32_t i = 0; i < m->worker_count; i++) {
        remote_t *w = &m->workers[i];
        if (!w->alive)
            continue;
        if (now - w->last_seen > m->cfg.worker_timeout_ms / 1000.0) {
            remote_lost(m, w, "silent");
            continue;
        }
        if (now - w->last_sent >= m->cfg.heartbeat_ms / 1000.0) {
            proto_msg_t hb;
            memset(&hb, 0, sizeof hb);
            hb.h.type = PROTO_HEARTBEAT;
            if (send_to_worker(m, w, &hb) < 0)
                remote_lost(m, w, "unreachable");
        }
    }
    /* leases and time limits */
    for (job_t *j = m->jobs; j; j = j->next) {
        if (j->state != JOB_RUNNING)
            continue;
        if (j->time_limit > 0 && !j->stopped_issuing && now - j->started >= j->time_limit) {
            j->stopped_issuing = 1;
            logf_(m, "job %" PRIu64 ": time limit %.1f s reached; finishing the tasks out", j->id, j->time_limit);
        }
        if (j->stopped_issuing && j->outstanding == 0) {
            job_finish(m, j, JOB_DONE, "time limit reached");
            continue;
        }
        if (j->ref[0] && (now - j->last_eval >= 0.25 || sched_layers_complete(j->sched) != j->last_eval_layers))
            job_eval_error(j, now);
        if (j->outstanding == 0)
            continue;
        size_t cells = (size_t)sched_layer_count(j->sched) * sched_range_count(j->sched);
        for (size_t c = 0; c < cells; c++)
            if (j->holder[c] >= 0 && now > j->deadline[c]) {
                remote_t *w = &m->workers[j->holder[c]];
                logf_(m, "job %" PRIu64 " task %zu: lease ran out on %s; issuing it again", j->id, c + 1, w->host);
                if (w->outstanding)
                    w->outstanding--;
                /* No credit back here: the slow worker still holds the task,
                 * and its late result (ignored) returns the credit then. */
                j->holder[c] = -1;
                j->outstanding--;
                j->reissued++;
                sched_requeue(j->sched, (uint64_t)c + 1);
            }
    }
}

/* ---- lifecycle ------------------------------------------------------------------- */

master_t *master_new(const master_config_t *cfg, char *err, size_t errlen)
{
    if (sodium_init() < 0) {
        snprintf(err, errlen, "libsodium failed to initialise");
        return NULL;
    }
    master_t *m = calloc(1, sizeof *m);
    if (!m) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    m->cfg = *cfg;
    if (!m->cfg.heartbeat_ms)
        m->cfg.heartbeat_ms = 1000;
    if (!m->cfg.lease_ms)
        m->cfg.lease_ms = 60000;
    if (!m->cfg.worker_timeout_ms)
        m->cfg.worker_timeout_ms = 5 * m->cfg.heartbeat_ms;
    m->workers = calloc(MAX_WORKERS, sizeof *m->workers);
    m->results = malloc(PROTO_MAX_TASK_PIXELS * sizeof *m->results);
    if (!m->workers || !m->results) {
        snprintf(err, errlen, "out of memory");
        master_destroy(&m);
        return NULL;
    }
    /* The build id pins the ISA: a worker on another ISA could trace other bits. */
    __builtin_cpu_init();
    proto_build_id(__builtin_cpu_supports("avx2") ? "avx2" : "sse4.2", m->build);
    m->workers_sock = zmq_socket(cfg->zmq_ctx, ZMQ_ROUTER);
    m->control_sock = zmq_socket(cfg->zmq_ctx, ZMQ_ROUTER);
    int zero = 0, one = 1;
    int64_t max_worker_msg = (int64_t)PROTO_HEADER_SIZE + 24 + (int64_t)PROTO_RESULT_RECORD_SIZE * PROTO_MAX_TASK_PIXELS + 4096;
    int64_t max_control = CONTROL_MAX_BYTES;
    if (!m->workers_sock || !m->control_sock) {
        snprintf(err, errlen, "cannot create sockets: %s", zmq_strerror(errno));
        master_destroy(&m);
        return NULL;
    }
    zmq_setsockopt(m->workers_sock, ZMQ_LINGER, &zero, sizeof zero);
    zmq_setsockopt(m->control_sock, ZMQ_LINGER, &zero, sizeof zero);
    zmq_setsockopt(m->workers_sock, ZMQ_ROUTER_MANDATORY, &one, sizeof one);
    zmq_setsockopt(m->workers_sock, ZMQ_MAXMSGSIZE, &max_worker_msg, sizeof max_worker_msg);
    zmq_setsockopt(m->control_sock, ZMQ_MAXMSGSIZE, &max_control, sizeof max_control);
    if (zmq_bind(m->workers_sock, cfg->worker_endpoint) < 0) {
        snprintf(err, errlen, "cannot bind the worker socket to %s: %s", cfg->worker_endpoint, zmq_strerror(errno));
        master_destroy(&m);
        return NULL;
    }
    if (zmq_bind(m->control_sock, cfg->control_endpoint) < 0) {
        snprintf(err, errlen, "cannot bind the control socket to %s: %s", cfg->control_endpoint, zmq_strerror(errno));
        master_destroy(&m);
        return NULL;
    }
    logf_(m, "listening: workers %s, control %s, build %s", cfg->worker_endpoint, cfg->control_endpoint, m->build);
    return m;
}

int master_run(master_t *m, const atomic_int *stop)
{
    zmq_pollitem_t items[2] = {{m->workers_sock, 0, ZMQ_POLLIN, 0}, {m->control_sock, 0, ZMQ_POLLIN, 0}};
    while (!(stop && atomic_load(stop)) && !m->shutdown) {
        int rc = zmq_poll(items, 2, 50);
        if (rc < 0 && errno != EINTR)
            break;
        /* bounded batches so neither socket starves the other */
        for (int k = 0; k < 4096 && (items[0].revents & ZMQ_POLLIN); k++) {
            handle_worker_message(m);
            int ev = 0;
            size_t sz = sizeof ev;
            zmq_getsockopt(m->workers_sock, ZMQ_EVENTS, &ev, &sz);
            if (!(ev & ZMQ_POLLIN))
                break;
        }
        if (items[1].revents & ZMQ_POLLIN)
            handle_control_message(m);
        double now = now_s();
        if (now - m->last_heartbeat_check >= 0.1) {
            timers(m);
            m->last_heartbeat_check = now;
        }
        dispatch(m);
    }
    /* tell workers we are going so they reconnect rather than wait out a timeout */
    for (uint32_t i = 0; i < m->worker_count; i++)
        if (m->workers[i].alive) {
            proto_msg_t bye;
            memset(&bye, 0, sizeof bye);
            bye.h.type = PROTO_BYE;
            snprintf(bye.u.text.text, sizeof bye.u.text.text, "master stopping");
            send_to_worker(m, &m->workers[i], &bye);
        }
    logf_(m, "stopped");
    return 0;
}

void master_destroy(master_t **mp)
{
    if (!mp || !*mp)
        return;
    master_t *m = *mp;
    if (m->workers_sock)
        zmq_close(m->workers_sock);
    if (m->control_sock)
        zmq_close(m->control_sock);
    job_t *j = m->jobs;
    while (j) {
        job_t *next = j->next;
        job_free(j);
        j = next;
    }
    free(m->workers);
    free(m->results);
    free(m->payload);
    free(m->task_records);
    free(m);
    *mp = NULL;
}
