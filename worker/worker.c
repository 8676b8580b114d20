/* worker.c - see worker.h.
 *
 * The main thread owns the socket to the master and the scene cache; render
 * threads take tasks from a queue, trace them with the core and hand the
 * results back, waking the main thread through an inproc socket each (ZeroMQ
 * sockets are not shared between threads). Tasks from an earlier connection
 * are traced but not reported: the master has already issued them again.
 */
#include "worker.h"

#include <errno.h>
#include <inttypes.h>
#include <pthread.h>
#include <sodium.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <zmq.h>

#include "frames.h"
#include "handshake.h"
#include "proto.h"
#include "scene.h"
#include "tracer.h"
#include "vberr.h"
#include "vblog.h"

/* A scene in a worker_scenes_t: loaded by one worker, read by all. */
typedef struct shared_scene {
    uint8_t hash[PROTO_HASH_SIZE];
    scene_t *scene;
    tracer_t *tracer;
    int loading; /* a worker is loading it: the others wait */
    int users;   /* workers' cache entries holding it */
    struct shared_scene *next;
} shared_scene_t;

struct worker_scenes {
    pthread_mutex_t lock;
    pthread_cond_t loaded; /* a load ended (or failed) */
    shared_scene_t *list;
};

worker_scenes_t *worker_scenes_new(void)
{
    worker_scenes_t *s = calloc(1, sizeof *s);
    if (!s)
        return NULL;
    pthread_mutex_init(&s->lock, NULL);
    pthread_cond_init(&s->loaded, NULL);
    return s;
}

void worker_scenes_destroy(worker_scenes_t **sp)
{
    if (!sp || !*sp)
        return;
    worker_scenes_t *s = *sp;
    /* every worker has let go of its scenes (worker_destroy) by now */
    while (s->list) {
        shared_scene_t *next = s->list->next;
        tracer_destroy(&s->list->tracer);
        scene_destroy(&s->list->scene);
        free(s->list);
        s->list = next;
    }
    pthread_mutex_destroy(&s->lock);
    pthread_cond_destroy(&s->loaded);
    free(s);
    *sp = NULL;
}

typedef struct scene_entry {
    uint8_t hash[PROTO_HASH_SIZE];
    scene_t *scene;
    tracer_t *tracer;
    shared_scene_t *shared; /* where scene and tracer belong when shared */
    int requested;          /* bundle asked for, not yet here */
    int refs;               /* tasks queued or being traced */
    double last_used;
    struct scene_entry *next;
} scene_entry_t;

typedef struct wtask {
    uint64_t job, task;
    uint32_t attempt;
    uint32_t generation; /* connection it came on */
    tracer_settings_t settings;
    uint32_t count;
    tracer_task_t *records;
    tracer_result_t *results;
    scene_entry_t *scene;
    uint64_t rays, busy_us;
    int failed;
    char error[VB_ERR_LEN];
    struct wtask *next;
} wtask_t;

typedef struct wthread {
    worker_t *w;
    pthread_t thread;
    int started;
} wthread_t;

struct worker {
    worker_config_t cfg;
    char name[64];
    void *sock;
    void *wake; /* PULL: render threads say "done" */
    char wake_endpoint[64];
    wthread_t *threads;
    pthread_mutex_t lock;
    pthread_cond_t cond;
    wtask_t *todo, *todo_tail; /* ready to trace */
    wtask_t *done, *done_tail; /* traced, to report */
    wtask_t *waiting;          /* waiting for their scene bundle */
    int busy;                  /* tasks being traced */
    int quit;
    scene_entry_t *cache;
    uint32_t generation;
    int welcomed;
    uint32_t heartbeat_ms;
    double last_from_master, last_sent, last_hello, hello_backoff;
    char build[PROTO_BUILD_SIZE + 1];
    uint8_t *payload;
    size_t payload_cap;
    tracer_task_t *decode_records;    /* decode buffers: a TASK's records, */
    proto_mesh_file_t *decode_meshes; /* a SCENE_BUNDLE's files */
    int refused;
    int curve;                /* keys given: the socket is a CURVE client */
    handshake_monitor_t *mon; /* sock's handshakes and disconnections */
    int connected;            /* sock's handshake succeeded and it has not been lost since */
    double reopen_at;         /* sock closed after a failed handshake: open it then */
    double handshake_backoff; /* seconds before the next try: 1 doubling to 30 */
    char keys[3][64];         /* copies of the CURVE keys cfg points to */
    tracer_device_t *device;
    int own_device;
#ifdef VB_FAULT_INJECTION
    unsigned long lie_every; /* VB_FAULT_LIE_EVERY: perturb one result in this many */
    unsigned long lie_bit;   /* VB_FAULT_LIE_BIT: the bit flipped (default 0) */
    unsigned long results_sent;
    double slow;   /* VB_FAULT_SLOW=F: each task takes F times its trace time */
    double delay;  /* VB_FAULT_DELAY_MS=N: and N ms more */
    int hoard;     /* VB_FAULT_HOARD=1: takes tasks, never answers (heartbeats go on) */
    int malformed; /* VB_FAULT_MALFORMED=1: every RESULT has a record of 0 rays */
#endif
};

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* A line at info level; log_at at another (vblog.h). */
static void logf_(worker_t *w, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void logf_(worker_t *w, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vblog_write(vblog_filter(w->cfg.log, w->cfg.log_level, VBLOG_INFO), w->name, fmt, ap);
    va_end(ap);
}

static void log_at(worker_t *w, vblog_level_t level, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
static void log_at(worker_t *w, vblog_level_t level, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vblog_write(vblog_filter(w->cfg.log, w->cfg.log_level, level), w->name, fmt, ap);
    va_end(ap);
}

static void task_free(wtask_t *t)
{
    if (!t)
        return;
    free(t->records);
    free(t->results);
    free(t);
}

/* ---- render threads --------------------------------------------------------- */

static void *render_main(void *arg)
{
    wthread_t *self = arg;
    worker_t *w = self->w;
    void *push = zmq_socket(w->cfg.zmq_ctx, ZMQ_PUSH);
    int zero = 0;
    zmq_setsockopt(push, ZMQ_LINGER, &zero, sizeof zero);
    zmq_connect(push, w->wake_endpoint);
    for (;;) {
        pthread_mutex_lock(&w->lock);
        while (!w->quit && !w->todo)
            pthread_cond_wait(&w->cond, &w->lock);
        if (!w->todo) {
            pthread_mutex_unlock(&w->lock);
            break;
        }
        wtask_t *t = w->todo;
        w->todo = t->next;
        if (!w->todo)
            w->todo_tail = NULL;
        w->busy++;
        pthread_mutex_unlock(&w->lock);

        double t0 = now_s();
        tracer_stats_t st = {0, 0};
        if (tracer_trace(t->scene->tracer, &t->settings, t->records, t->count, t->results, &st,
                         t->error, sizeof t->error) < 0)
            t->failed = 1;
        t->rays = st.rays;
#ifdef VB_FAULT_INJECTION
        if (w->slow > 1 || w->delay > 0) { /* a slower host: the thread stays busy */
            double extra = (w->slow > 1 ? (w->slow - 1) * (now_s() - t0) : 0) + w->delay;
            struct timespec ts = {(time_t)extra, (long)((extra - (double)(time_t)extra) * 1e9)};
            nanosleep(&ts, NULL);
        }
#endif
        t->busy_us = (uint64_t)((now_s() - t0) * 1e6);

        pthread_mutex_lock(&w->lock);
        t->next = NULL;
        if (w->done_tail)
            w->done_tail->next = t;
        else
            w->done = t;
        w->done_tail = t;
        w->busy--;
        pthread_mutex_unlock(&w->lock);
        zmq_send(push, "", 0, ZMQ_DONTWAIT);
    }
    zmq_close(push);
    return NULL;
}

/* ---- sending ------------------------------------------------------------------- */

static int send_msg(worker_t *w, proto_msg_t *msg)
{
    if (!w->sock)
        return -1; /* waiting to try the handshake again */
    size_t need = proto_payload_size(msg);
    if (need > w->payload_cap) {
        uint8_t *p = realloc(w->payload, need);
        if (!p)
            return -1;
        w->payload = p;
        w->payload_cap = need;
    }
    uint8_t header[PROTO_HEADER_SIZE];
    char err[VB_ERR_LEN];
    long n = proto_encode(msg, header, w->payload, w->payload_cap, err, sizeof err);
    if (n < 0) {
        logf_(w, "cannot encode %s: %s", proto_type_name(msg->h.type), err);
        return -1;
    }
#ifdef VB_FAULT_INJECTION
    /* the first record's rays (the payload's head is 24 bytes, rays sit at
     * 12 in a record) zeroed after encoding, which would refuse it */
    if (w->malformed && msg->h.type == PROTO_RESULT && n >= 24 + PROTO_RESULT_RECORD_SIZE)
        memset(w->payload + 24 + 12, 0, 4);
#endif
    const void *parts[2] = {header, w->payload};
    const size_t sizes[2] = {PROTO_HEADER_SIZE, (size_t)n};
    if (proto_send(w->sock, parts, sizes, 2, ZMQ_DONTWAIT) < 0)
        return -1;
    w->last_sent = now_s();
    return 0;
}

static void send_simple(worker_t *w, proto_type_t type, const char *text)
{
    char cut[PROTO_TEXT_MAX + 1]; /* a longer text is cut, not refused */
    snprintf(cut, sizeof cut, "%s", text ? text : "");
    proto_msg_t msg = {.h.type = (uint16_t)type, .u.text.text = cut};
    send_msg(w, &msg);
}

static void send_hello(worker_t *w)
{
    proto_msg_t msg = {.h.type = PROTO_HELLO};
    msg.u.hello.threads = (uint32_t)w->cfg.threads;
    memcpy(msg.u.hello.build, w->build, sizeof msg.u.hello.build);
    send_msg(w, &msg);
    w->last_hello = now_s();
}

/* Test builds only (VB_FAULT_INJECTION): one result in VB_FAULT_LIE_EVERY
 * has the lowest bit (or bit VB_FAULT_LIE_BIT, so two liars can lie
 * differently) of the first record's red sum flipped: still a plausible
 * value, which only another worker's copy can expose. */
static void maybe_lie(worker_t *w, wtask_t *t)
{
#ifdef VB_FAULT_INJECTION
    if (!w->lie_every || t->count == 0 || ++w->results_sent % w->lie_every != 0)
        return;
    uint64_t bits;
    memcpy(&bits, &t->results[0].sum[0], sizeof bits);
    bits ^= (uint64_t)1 << (w->lie_bit & 31);
    memcpy(&t->results[0].sum[0], &bits, sizeof bits);
    logf_(w, "fault injection: lying about job %" PRIu64 " task %" PRIu64 " attempt %u", t->job,
          t->task, t->attempt);
#else
    (void)w;
    (void)t;
#endif
}

static void report(worker_t *w, wtask_t *t)
{
    if (t->generation != w->generation || !w->welcomed)
        return; /* from an earlier connection: the master has moved on */
    proto_msg_t msg = {.h = {.job = t->job, .task = t->task, .attempt = t->attempt}};
    char text[PROTO_TEXT_MAX + 1];
    if (t->failed) {
        msg.h.type = PROTO_TASK_FAILED;
        snprintf(text, sizeof text, "%s: %.900s", w->name, t->error); /* cut to fit the wire text */
        msg.u.text.text = text;
    } else {
#ifdef VB_FAULT_INJECTION
        if (w->hoard)
            return; /* as if it kept tracing forever */
#endif
        maybe_lie(w, t);
        msg.h.type = PROTO_RESULT;
        msg.u.result.rays = t->rays;
        msg.u.result.busy_us = t->busy_us;
        msg.u.result.count = t->count;
        msg.u.result.records = t->results;
    }
    send_msg(w, &msg);
}

static void drain_done(worker_t *w)
{
    pthread_mutex_lock(&w->lock);
    wtask_t *list = w->done;
    w->done = w->done_tail = NULL;
    pthread_mutex_unlock(&w->lock);
    while (list) {
        wtask_t *next = list->next;
        report(w, list);
        list->scene->refs--;
        list->scene->last_used = now_s();
        task_free(list);
        list = next;
    }
}

/* ---- scenes --------------------------------------------------------------------- */

static scene_entry_t *find_scene(worker_t *w, const uint8_t *hash)
{
    for (scene_entry_t *e = w->cache; e; e = e->next)
        if (memcmp(e->hash, hash, PROTO_HASH_SIZE) == 0)
            return e;
    return NULL;
}

/* Lets go of a cache entry's scene: the last of the process's workers to
 * hold a shared one frees it. */
static void drop_scene(worker_t *w, scene_entry_t *e)
{
    shared_scene_t *sh = e->shared;
    if (!sh) {
        tracer_destroy(&e->tracer);
        scene_destroy(&e->scene);
        return;
    }
    worker_scenes_t *st = w->cfg.scenes;
    pthread_mutex_lock(&st->lock);
    if (--sh->users == 0) {
        for (shared_scene_t **l = &st->list; *l; l = &(*l)->next)
            if (*l == sh) {
                *l = sh->next;
                break;
            }
        tracer_destroy(&sh->tracer);
        scene_destroy(&sh->scene);
        free(sh);
    }
    pthread_mutex_unlock(&st->lock);
    e->shared = NULL;
    e->scene = NULL;
    e->tracer = NULL;
}

/* The bundle's scene and its tracer into e: loaded here, or, with a
 * process's shared store, taken from the worker that loaded it (waiting
 * while one loads it). 0, or -1 with a message. */
static int load_scene(worker_t *w, scene_entry_t *e, const proto_bundle_t *b, char *err,
                      size_t errlen, int *shared)
{
    scene_blob_t blobs[PROTO_MAX_MESHES];
    for (uint32_t i = 0; i < b->mesh_count; i++) {
        blobs[i].name = b->meshes[i].name;
        blobs[i].data = b->meshes[i].data;
        blobs[i].size = b->meshes[i].size;
    }
    worker_scenes_t *st = w->cfg.scenes;
    shared_scene_t *sh = NULL;
    *shared = 0;
    if (st) {
        pthread_mutex_lock(&st->lock);
        for (;;) {
            for (sh = st->list; sh && memcmp(sh->hash, b->hash, PROTO_HASH_SIZE) != 0;)
                sh = sh->next;
            if (!sh || !sh->loading)
                break;
            pthread_cond_wait(&st->loaded, &st->lock);
        }
        if (sh) {
            sh->users++;
            pthread_mutex_unlock(&st->lock);
            e->shared = sh;
            e->scene = sh->scene;
            e->tracer = sh->tracer;
            *shared = 1;
            return 0;
        }
        /* this worker loads it; the others wait for it */
        sh = calloc(1, sizeof *sh);
        if (sh) {
            memcpy(sh->hash, b->hash, PROTO_HASH_SIZE);
            sh->loading = 1;
            sh->users = 1;
            sh->next = st->list;
            st->list = sh;
        }
        pthread_mutex_unlock(&st->lock);
    }
    int rc = scene_load_bundle(b->json, b->json_size, "scene", blobs, b->mesh_count, &e->scene, err,
                               errlen);
    if (rc == 0 && tracer_new(w->device, e->scene, &e->tracer, err, errlen) < 0) {
        scene_destroy(&e->scene);
        rc = -1;
    }
    if (sh) {
        pthread_mutex_lock(&st->lock);
        sh->loading = 0;
        if (rc == 0) {
            sh->scene = e->scene;
            sh->tracer = e->tracer;
            e->shared = sh;
        } else {
            /* gone: a waiting worker loads it itself, and says why it fails */
            for (shared_scene_t **l = &st->list; *l; l = &(*l)->next)
                if (*l == sh) {
                    *l = sh->next;
                    break;
                }
            free(sh);
        }
        pthread_cond_broadcast(&st->loaded);
        pthread_mutex_unlock(&st->lock);
    }
    return rc;
}

static void evict(worker_t *w)
{
    int limit = w->cfg.cache_scenes > 0 ? w->cfg.cache_scenes : 4;
    for (;;) {
        int n = 0;
        scene_entry_t *oldest = NULL, **oldest_link = NULL;
        for (scene_entry_t **link = &w->cache; *link; link = &(*link)->next) {
            scene_entry_t *e = *link;
            if (!e->scene)
                continue;
            n++;
            if (e->refs == 0 && (!oldest || e->last_used < oldest->last_used)) {
                oldest = e;
                oldest_link = link;
            }
        }
        if (n <= limit || !oldest)
            return;
        logf_(w, "dropping a cached scene (%d loaded, limit %d)", n, limit);
        *oldest_link = oldest->next;
        drop_scene(w, oldest);
        free(oldest);
    }
}

static void enqueue(worker_t *w, wtask_t *t)
{
    pthread_mutex_lock(&w->lock);
    t->next = NULL;
    if (w->todo_tail)
        w->todo_tail->next = t;
    else
        w->todo = t;
    w->todo_tail = t;
    pthread_cond_signal(&w->cond);
    pthread_mutex_unlock(&w->lock);
}

static void on_bundle(worker_t *w, const proto_msg_t *msg)
{
    const proto_bundle_t *b = &msg->u.bundle;
    scene_entry_t *e = find_scene(w, b->hash);
    if (!e || e->scene)
        return; /* not asked for, or already here */
    char err[VB_ERR_LEN] = "";
    uint8_t check[PROTO_HASH_SIZE];
    proto_bundle_hash(b, check);
    int ok = memcmp(check, b->hash, PROTO_HASH_SIZE) == 0;
    if (!ok)
        snprintf(err, sizeof err, "scene bundle does not match its hash");
    double t0 = now_s();
    int shared = 0;
    if (ok && load_scene(w, e, b, err, sizeof err, &shared) < 0)
        ok = 0;
    e->requested = 0;
    if (ok)
        logf_(w, "scene %s in %.2f s: %zu triangles (%s)",
              shared ? "shared with another worker" : "loaded", now_s() - t0,
              e->scene->triangle_count, tracer_isa(e->tracer));
    else
        logf_(w, "scene failed to load: %s", err);
    /* release the tasks that waited for it */
    wtask_t **link = &w->waiting;
    while (*link) {
        wtask_t *t = *link;
        if (t->scene != e) {
            link = &t->next;
            continue;
        }
        *link = t->next;
        if (ok) {
            enqueue(w, t);
        } else {
            t->failed = 1;
            snprintf(t->error, sizeof t->error, "%.480s", err);
            report(w, t);
            e->refs--;
            task_free(t);
        }
    }
    if (!ok) {
        /* forget it: a later task may ask again */
        for (scene_entry_t **l = &w->cache; *l; l = &(*l)->next)
            if (*l == e && e->refs == 0) {
                *l = e->next;
                free(e);
                break;
            }
    }
    evict(w);
}

static void on_task(worker_t *w, const proto_msg_t *msg)
{
    wtask_t *t = calloc(1, sizeof *t);
    uint32_t n = msg->u.task.count;
    if (t) {
        t->records = malloc(n * sizeof *t->records);
        t->results = malloc(n * sizeof *t->results);
    }
    if (!t || !t->records || !t->results) {
        if (t) {
            task_free(t);
        }
        char text[PROTO_TEXT_MAX + 1];
        snprintf(text, sizeof text, "%s: out of memory", w->name);
        proto_msg_t f = {.h = msg->h, .u.text.text = text};
        f.h.type = PROTO_TASK_FAILED;
        send_msg(w, &f);
        return;
    }
    memcpy(t->records, msg->u.task.records, n * sizeof *t->records);
    t->job = msg->h.job;
    t->task = msg->h.task;
    t->attempt = msg->h.attempt;
    t->generation = w->generation;
    t->settings = msg->u.task.settings;
    t->count = n;
    scene_entry_t *e = find_scene(w, msg->u.task.scene_hash);
    if (!e) {
        e = calloc(1, sizeof *e);
        if (!e) {
            task_free(t);
            return;
        }
        memcpy(e->hash, msg->u.task.scene_hash, PROTO_HASH_SIZE);
        e->next = w->cache;
        w->cache = e;
    }
    t->scene = e;
    e->refs++;
    e->last_used = now_s();
    if (e->scene) {
        enqueue(w, t);
        return;
    }
    t->next = w->waiting;
    w->waiting = t;
    if (!e->requested) {
        proto_msg_t req = {.h.type = PROTO_SCENE_REQUEST, .h.job = msg->h.job};
        memcpy(req.u.scene_hash, e->hash, PROTO_HASH_SIZE);
        send_msg(w, &req);
        e->requested = 1;
        logf_(w, "fetching the scene of job %" PRIu64, msg->h.job);
    }
}

/* Drops queued and waiting tasks: the master issues them again. */
static void release_queued(worker_t *w)
{
    pthread_mutex_lock(&w->lock);
    wtask_t *list = w->todo;
    w->todo = w->todo_tail = NULL;
    pthread_mutex_unlock(&w->lock);
    while (list) {
        wtask_t *next = list->next;
        list->scene->refs--;
        task_free(list);
        list = next;
    }
    while (w->waiting) {
        wtask_t *next = w->waiting->next;
        w->waiting->scene->refs--;
        task_free(w->waiting);
        w->waiting = next;
    }
    for (scene_entry_t *e = w->cache; e; e = e->next)
        e->requested = 0;
}

static void start_over(worker_t *w, const char *why)
{
    logf_(w, "starting over with the master: %s", why);
    release_queued(w);
    w->generation++;
    w->welcomed = 0;
    w->hello_backoff = 0.1;
    send_hello(w);
}

static void on_welcome(worker_t *w, const proto_msg_t *msg)
{
    if (w->welcomed)
        return;
    w->welcomed = 1;
    w->heartbeat_ms = msg->u.welcome.heartbeat_ms;
    uint32_t want = (uint32_t)(PROTO_CREDIT_PER_THREAD * w->cfg.threads);
    proto_msg_t c = {.h.type = PROTO_CREDIT,
                     .u.credit = want > PROTO_MAX_CREDIT ? PROTO_MAX_CREDIT : want};
    send_msg(w, &c);
    logf_(w, "connected to %s with %d threads", w->cfg.master_endpoint, w->cfg.threads);
}

/* A message from the master, decoded. */
static void on_message(worker_t *w, const proto_msg_t *msg)
{
    w->last_from_master = now_s();
    switch (msg->h.type) {
    case PROTO_WELCOME:
        on_welcome(w, msg);
        break;
    case PROTO_REFUSE:
        log_at(w, VBLOG_ERROR, "refused by the master: %s", msg->u.text.text);
        w->refused = 1;
        break;
    case PROTO_TASK:
        log_at(w, VBLOG_DEBUG, "job %" PRIu64 " task %" PRIu64 " (attempt %u): %u pixels",
               msg->h.job, msg->h.task, msg->h.attempt, msg->u.task.count);
        if (w->welcomed)
            on_task(w, msg);
        break;
    case PROTO_SCENE_BUNDLE:
        on_bundle(w, msg);
        break;
    case PROTO_HEARTBEAT:
        break;
    case PROTO_BYE:
        start_over(w, msg->u.text.text);
        break;
    default:
        logf_(w, "dropped an out-of-protocol %s from the master", proto_type_name(msg->h.type));
        break;
    }
}

/* Receives [header][payload] from the master: a bundle at most. */
static void handle_message(worker_t *w)
{
    proto_frames_t fr;
    proto_recv_result_t got =
        proto_recv(w->sock, &fr, 2, PROTO_HEADER_SIZE + (size_t)PROTO_MAX_BUNDLE, ZMQ_DONTWAIT);
    if (got != PROTO_RECV_OK || fr.count != 2) {
        log_at(w, VBLOG_WARN, "dropped a malformed message from the master");
        proto_frames_close(&fr);
        return;
    }
    proto_records_t recs = {.tasks = w->decode_records,
                            .task_capacity = PROTO_MAX_TASK_PIXELS,
                            .meshes = w->decode_meshes,
                            .mesh_capacity = PROTO_MAX_MESHES};
    proto_msg_t msg;
    char err[VB_ERR_LEN];
    int rc = proto_frames_decode(&fr, 0, &msg, &recs, err, sizeof err);
    if (rc == -2) {
        log_at(w, VBLOG_ERROR, "the master speaks another protocol: %s", err);
        send_simple(w, PROTO_REFUSE, err);
        w->refused = 1;
    } else if (rc < 0) {
        log_at(w, VBLOG_WARN, "dropped a malformed message from the master: %s", err);
    } else {
        on_message(w, &msg);
    }
    proto_frames_close(&fr);
}

/* ---- the socket to the master ------------------------------------------------------ */

static int open_master_socket(worker_t *w, char *err, size_t errlen)
{
    w->sock = zmq_socket(w->cfg.zmq_ctx, ZMQ_DEALER);
    if (!w->sock) {
        snprintf(err, errlen, "cannot create a socket: %s", zmq_strerror(errno));
        return -1;
    }
    int zero = 0, ivl = 100, ivl_max = 5000;
    int64_t max_msg = (int64_t)PROTO_MAX_BUNDLE + PROTO_HEADER_SIZE + 4096;
    /* Not ZMQ_IMMEDIATE, though this socket must queue nothing for a master
     * that is gone: with it, libzmq 4.3 terminates the socket's pipe from
     * within a recv when the connection drops (socket_base_t::hiccuped),
     * and a recv handles such commands every 100th call, which for our
     * two-frame messages is always between the frames: fq.cpp then asserts
     * (!_more) and the worker aborts. A lost connection instead closes the
     * socket, and what was queued with it (on_handshake_events), and HELLO is
     * resent only over a connection (worker_run). */
    zmq_setsockopt(w->sock, ZMQ_LINGER, &zero, sizeof zero);
    zmq_setsockopt(w->sock, ZMQ_RECONNECT_IVL, &ivl, sizeof ivl);
    zmq_setsockopt(w->sock, ZMQ_RECONNECT_IVL_MAX, &ivl_max, sizeof ivl_max);
    zmq_setsockopt(w->sock, ZMQ_MAXMSGSIZE, &max_msg, sizeof max_msg);
    if (w->curve && (zmq_setsockopt(w->sock, ZMQ_CURVE_SERVERKEY, w->cfg.master_key,
                                    strlen(w->cfg.master_key)) < 0 ||
                     zmq_setsockopt(w->sock, ZMQ_CURVE_PUBLICKEY, w->cfg.public_key,
                                    strlen(w->cfg.public_key)) < 0 ||
                     zmq_setsockopt(w->sock, ZMQ_CURVE_SECRETKEY, w->cfg.secret_key,
                                    strlen(w->cfg.secret_key)) < 0)) {
        snprintf(err, errlen, "cannot set the CURVE keys: %s", zmq_strerror(errno));
        zmq_close(w->sock);
        w->sock = NULL;
        return -1;
    }
    /* watched before it connects, so no handshake goes unseen */
    if (!(w->mon = handshake_monitor_new(w->cfg.zmq_ctx, w->sock, err, errlen))) {
        zmq_close(w->sock);
        w->sock = NULL;
        return -1;
    }
    if (zmq_connect(w->sock, w->cfg.master_endpoint) < 0) {
        snprintf(err, errlen, "cannot connect to %s: %s", w->cfg.master_endpoint,
                 zmq_strerror(errno));
        handshake_monitor_destroy(&w->mon);
        zmq_close(w->sock);
        w->sock = NULL;
        return -1;
    }
    return 0;
}

static void close_master_socket(worker_t *w)
{
    w->connected = 0;
    handshake_monitor_destroy(&w->mon);
    if (w->sock)
        zmq_close(w->sock);
    w->sock = NULL;
}

/* A failed handshake is not retried by ZeroMQ (a refused key, CURVE on one
 * side only) or retried every 100 ms (a wrong master key): either way the
 * worker says why, closes the socket and opens a new one after a backoff,
 * so a key added to the master's allow-list later is picked up. */
static void on_handshake_events(worker_t *w, double now)
{
    char msg[VB_ERR_LEN];
    handshake_result_t r;
    while (w->mon && (r = handshake_monitor_read(w->mon, w->cfg.master_endpoint, "worker", w->curve,
                                                 msg, sizeof msg)) != HANDSHAKE_NONE) {
        if (r == HANDSHAKE_OK) {
            if (w->handshake_backoff > 1.0)
                logf_(w, "%s", msg);
            w->handshake_backoff = 1.0;
            w->connected = 1;
            /* the HELLO it queued goes out now: a retry waits its backoff
             * from here, not from when it was queued */
            w->last_hello = now;
            continue;
        }
        if (r == HANDSHAKE_LOST) {
            /* what was queued for that master goes with the socket; a new
             * one reconnects at once and queues one HELLO for whichever
             * master answers next */
            close_master_socket(w);
            if (w->welcomed)
                start_over(w, msg);
            else
                release_queued(w);
            w->reopen_at = now;
            break;
        }
        log_at(w, VBLOG_WARN, "%s; trying again in %.0f s", msg, w->handshake_backoff);
        close_master_socket(w);
        release_queued(w);
        w->generation++;
        w->welcomed = 0;
        w->reopen_at = now + w->handshake_backoff;
        w->handshake_backoff = w->handshake_backoff * 2 > 30.0 ? 30.0 : w->handshake_backoff * 2;
    }
}

static void reopen_if_due(worker_t *w, double now)
{
    if (w->sock || now < w->reopen_at)
        return;
    char err[VB_ERR_LEN];
    if (open_master_socket(w, err, sizeof err) < 0) {
        log_at(w, VBLOG_WARN, "%s; trying again in %.0f s", err, w->handshake_backoff);
        w->reopen_at = now + w->handshake_backoff;
        return;
    }
    w->hello_backoff = 0.1;
    send_hello(w);
}

/* ---- lifecycle -------------------------------------------------------------------- */

/* The CURVE keys, copied: cfg's strings need not outlive worker_new. */
static int copy_keys(worker_t *w, const worker_config_t *cfg, char *err, size_t errlen)
{
    w->curve = cfg->public_key || cfg->secret_key || cfg->master_key;
    if (!w->curve)
        return 0;
    const char *k[3] = {cfg->public_key, cfg->secret_key, cfg->master_key};
    for (int i = 0; i < 3; i++)
        if (!k[i] ||
            (size_t)snprintf(w->keys[i], sizeof w->keys[i], "%s", k[i]) >= sizeof w->keys[i]) {
            snprintf(err, errlen,
                     "CURVE needs this worker's key pair and the master's public key (Z85)");
            return -1;
        }
    w->cfg.public_key = w->keys[0];
    w->cfg.secret_key = w->keys[1];
    w->cfg.master_key = w->keys[2];
    return 0;
}

worker_t *worker_new(const worker_config_t *cfg, char *err, size_t errlen)
{
    if (cfg->threads < 1 || cfg->threads > PROTO_MAX_THREADS) {
        snprintf(err, errlen, "threads must be 1..%d", PROTO_MAX_THREADS);
        return NULL;
    }
    if (cfg->scenes && !cfg->device) {
        /* a shared tracer lives on the device it was built on */
        snprintf(err, errlen, "a shared scene store needs the process's shared device");
        return NULL;
    }
    if (sodium_init() < 0) {
        snprintf(err, errlen, "libsodium failed to initialise");
        return NULL;
    }
    worker_t *w = calloc(1, sizeof *w);
    if (!w) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    w->cfg = *cfg;
    snprintf(w->name, sizeof w->name, "%s", cfg->name ? cfg->name : "worker");
#ifdef VB_FAULT_INJECTION
    const char *lie = getenv("VB_FAULT_LIE_EVERY");
    w->lie_every = lie ? strtoul(lie, NULL, 10) : 0;
    const char *bit = getenv("VB_FAULT_LIE_BIT");
    w->lie_bit = bit ? strtoul(bit, NULL, 10) : 0;
    const char *slow = getenv("VB_FAULT_SLOW");
    w->slow = slow ? strtod(slow, NULL) : 0;
    const char *delay = getenv("VB_FAULT_DELAY_MS");
    w->delay = delay ? strtod(delay, NULL) / 1000.0 : 0;
    w->hoard = getenv("VB_FAULT_HOARD") != NULL;
    w->malformed = getenv("VB_FAULT_MALFORMED") != NULL;
#endif
    pthread_mutex_init(&w->lock, NULL);
    pthread_cond_init(&w->cond, NULL);
    w->decode_records = malloc(PROTO_MAX_TASK_PIXELS * sizeof *w->decode_records);
    w->decode_meshes = malloc(PROTO_MAX_MESHES * sizeof *w->decode_meshes);
    w->threads = calloc((size_t)cfg->threads, sizeof *w->threads);
    if (!w->decode_records || !w->decode_meshes || !w->threads) {
        snprintf(err, errlen, "out of memory");
        worker_destroy(&w);
        return NULL;
    }
    w->device = cfg->device;
    if (!w->device) {
        if (tracer_device_new(&w->device, err, errlen) < 0) {
            worker_destroy(&w);
            return NULL;
        }
        w->own_device = 1;
    }
    proto_build_id(tracer_device_isa(w->device), w->build);
    snprintf(w->wake_endpoint, sizeof w->wake_endpoint, "inproc://vb-worker-wake-%p", (void *)w);
    w->wake = zmq_socket(cfg->zmq_ctx, ZMQ_PULL);
    /* sock and its monitor: open_master_socket */
    if (!w->wake || zmq_bind(w->wake, w->wake_endpoint) < 0) {
        snprintf(err, errlen, "cannot create sockets: %s", zmq_strerror(errno));
        worker_destroy(&w);
        return NULL;
    }
    int zero = 0;
    zmq_setsockopt(w->wake, ZMQ_LINGER, &zero, sizeof zero);
    if (copy_keys(w, cfg, err, errlen) < 0) {
        worker_destroy(&w);
        return NULL;
    }
    w->handshake_backoff = 1.0;
    if (open_master_socket(w, err, errlen) < 0) {
        worker_destroy(&w);
        return NULL;
    }
    for (int i = 0; i < cfg->threads; i++) {
        w->threads[i].w = w;
        if (pthread_create(&w->threads[i].thread, NULL, render_main, &w->threads[i]) != 0) {
            snprintf(err, errlen, "cannot start render thread %d", i);
            worker_destroy(&w);
            return NULL;
        }
        w->threads[i].started = 1;
    }
    return w;
}

int worker_run(worker_t *w, const atomic_int *stop)
{
    w->hello_backoff = 0.1;
    w->last_from_master = now_s();
    send_hello(w);
    while (!(stop && atomic_load(stop)) && !w->refused) {
        /* wake always; the master's socket and its monitor while open */
        zmq_pollitem_t items[3] = {
            {w->wake, 0, ZMQ_POLLIN, 0},
            {w->sock, 0, ZMQ_POLLIN, 0},
            {w->sock ? handshake_monitor_socket(w->mon) : NULL, 0, ZMQ_POLLIN, 0}};
        if (zmq_poll(items, w->sock ? 3 : 1, 50) < 0 && errno != EINTR)
            break;
        if (items[0].revents & ZMQ_POLLIN) {
            char b;
            while (zmq_recv(w->wake, &b, 1, ZMQ_DONTWAIT) >= 0)
                ;
            drain_done(w);
        }
        for (int k = 0; k < 256 && w->sock && (items[1].revents & ZMQ_POLLIN); k++) {
            handle_message(w);
            int ev = 0;
            size_t sz = sizeof ev;
            zmq_getsockopt(w->sock, ZMQ_EVENTS, &ev, &sz);
            if (!(ev & ZMQ_POLLIN))
                break;
        }
        if (w->sock && (items[2].revents & ZMQ_POLLIN))
            on_handshake_events(w, now_s());
        reopen_if_due(w, now_s());
        double now = now_s();
        if (!w->welcomed) {
            /* HELLO again with backoff until the master answers; only over
             * a connection (a socket queues what it cannot send yet) */
            if (w->connected && now - w->last_hello >= w->hello_backoff) {
                send_hello(w);
                w->hello_backoff = w->hello_backoff * 2 > 5.0 ? 5.0 : w->hello_backoff * 2;
            }
        } else {
            double hb = w->heartbeat_ms / 1000.0;
            if (now - w->last_from_master > 5 * hb)
                start_over(w, "the master is silent");
            else if (now - w->last_sent >= hb)
                send_simple(w, PROTO_HEARTBEAT, NULL);
        }
    }
    /* Leaving: release what has not started, return what is being traced. */
    release_queued(w);
    for (;;) {
        pthread_mutex_lock(&w->lock);
        int busy = w->busy;
        pthread_mutex_unlock(&w->lock);
        drain_done(w);
        if (!busy)
            break;
        zmq_pollitem_t wake = {w->wake, 0, ZMQ_POLLIN, 0};
        zmq_poll(&wake, 1, 20);
        char b;
        while (zmq_recv(w->wake, &b, 1, ZMQ_DONTWAIT) >= 0)
            ;
    }
    drain_done(w);
    if (w->welcomed && !w->refused)
        send_simple(w, PROTO_BYE, "worker stopping");
    logf_(w, "stopped");
    return w->refused ? 1 : 0;
}

void worker_destroy(worker_t **wp)
{
    if (!wp || !*wp)
        return;
    worker_t *w = *wp;
    pthread_mutex_lock(&w->lock);
    w->quit = 1;
    pthread_cond_broadcast(&w->cond);
    pthread_mutex_unlock(&w->lock);
    if (w->threads)
        for (int i = 0; i < w->cfg.threads; i++)
            if (w->threads[i].started)
                pthread_join(w->threads[i].thread, NULL);
    release_queued(w);
    while (w->done) {
        wtask_t *next = w->done->next;
        task_free(w->done);
        w->done = next;
    }
    while (w->cache) {
        scene_entry_t *next = w->cache->next;
        drop_scene(w, w->cache);
        free(w->cache);
        w->cache = next;
    }
    close_master_socket(w);
    if (w->wake)
        zmq_close(w->wake);
    if (w->own_device)
        tracer_device_destroy(&w->device);
    pthread_mutex_destroy(&w->lock);
    pthread_cond_destroy(&w->cond);
    explicit_bzero(w->keys, sizeof w->keys);
    free(w->threads);
    free(w->decode_records);
    free(w->decode_meshes);
    free(w->payload);
    free(w);
    *wp = NULL;
}
