/* master.c - lifecycle, the event loop, and its periodic tasks (see
 * master_priv.h for how the master is split). */
#include "master.h"

#include <errno.h>
#include <inttypes.h>
#include <sodium.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "master_priv.h"
#include "vblog.h"

double master_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

void master_log(master_t *m, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vblog_write(vblog_filter(m->cfg.log, m->cfg.log_level, VBLOG_INFO), "master", fmt, ap);
    va_end(ap);
}

void master_log_at(master_t *m, vblog_level_t level, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vblog_write(vblog_filter(m->cfg.log, m->cfg.log_level, level), "master", fmt, ap);
    va_end(ap);
}

void master_log_limited(master_t *m, const char *key, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vblog_limited(&m->limiter, vblog_filter(m->cfg.log, m->cfg.log_level, VBLOG_WARN), "master",
                  key, master_now(), fmt, ap);
    va_end(ap);
}

int master_is_admin(master_t *m, const char *key)
{
    return m->auth && auth_is_admin(m->auth, key);
}

const char *master_peer_key(zmq_msg_t *frame)
{
    const char *k = zmq_msg_gets(frame, "User-Id");
    return k ? k : "";
}

int master_peer_allowed(master_t *m, const char *domain, zmq_msg_t *frame)
{
    return !m->auth || auth_allowed(m->auth, domain, master_peer_key(frame));
}

int master_peer_is_admin(master_t *m, zmq_msg_t *frame)
{
    return !m->auth || auth_is_admin(m->auth, master_peer_key(frame));
}

/* SIGHUP: the allow-lists again; peers whose key went are dropped as
 * their next message arrives (master_peer_allowed). */
static void reload_keys(master_t *m)
{
    char msg[VB_ERR_LEN];
    if (!m->auth)
        master_log(m,
                   "reload asked for, but this master runs without --key: no allow-lists to read");
    else if (auth_reload(m->auth, msg, sizeof msg) < 0)
        master_log_at(m, VBLOG_WARN, "cannot reload the allow-lists, keeping the old ones: %s",
                      msg);
    else
        master_log(m, "allow-lists reloaded: %s", msg);
}

/* ---- periodic tasks ------------------------------------------------------------- */

/* Tasks whose lease ran out go out again. Each job's queue is in the order
 * the copies were sent and one length applies to all of them
 * (job_lease_seconds), so only the heads are looked at; a lease whose copy
 * was answered or sent again since is stale and skipped. */
static void expire_leases(master_t *m, double now)
{
    for (job_t *j = m->jobs; j; j = j->next) {
        if (j->state != JOB_RUNNING || !j->holder || !j->leases)
            continue;
        double before = now - job_lease_seconds(m, j);
        lease_t l;
        while (j->state == JOB_RUNNING && lease_pop_sent_before(j->leases, before, &l)) {
            size_t c = (size_t)(l.task - 1);
            if (verify_holds(j, c)) {
                verify_lease_expired(m, j, c, &l); /* one copy of several */
                continue;
            }
            if (j->holder[c] != l.slot || j->attempt[c] != l.attempt)
                continue;
            peer_t *w = &m->workers[l.slot - 1];
            master_log_at(m, VBLOG_WARN,
                          "job %" PRIu64 " task %" PRIu64
                          ": lease ran out on %s after %.1f s (task time %.3f s); issuing it "
                          "again",
                          j->id, l.task, w->host, now - l.sent, job_task_seconds(j));
            /* No credit back here: the slow worker still holds the task, and
             * its late result (ignored) returns the credit then. */
            w->owed++;
            peer_lease_lost(m, w);
            job_reissue(m, j, c);
        }
    }
}

/* Time limits, and the error against a reference every MASTER_EVAL_S. */
static void job_clocks(master_t *m, double now)
{
    for (job_t *j = m->jobs; j; j = j->next) {
        if (j->state != JOB_RUNNING)
            continue;
        if (j->time_limit > 0 && !j->stopped_issuing && job_seconds(j, now) >= j->time_limit) {
            j->stopped_issuing = 1;
            master_log(m, "job %" PRIu64 ": time limit %.1f s reached; finishing the tasks out",
                       j->id, j->time_limit);
        }
        if (j->stopped_issuing && j->outstanding == 0) {
            job_finish(m, j, JOB_DONE, "time limit reached");
            continue;
        }
        if (j->requeue_refused) {
            job_finish(m, j, JOB_FAILED,
                       "the scheduler could not take a task back (out of memory); "
                       "the image so far is kept");
            continue;
        }
        if (j->ref[0] && (now - j->last_eval >= MASTER_EVAL_S ||
                          sched_layers_complete(j->sched) != j->last_eval_layers))
            job_eval_error(j, now);
    }
}

static void periodic(master_t *m, double now)
{
    peer_heartbeats(m, now);
    expire_leases(m, now);
    verify_tick(m);
    job_clocks(m, now);
    vblog_limiter_flush(&m->limiter, m->cfg.log, "master", now);
    if (m->store)
        persist_tick(m, now, 0);
    else
        job_retention(m);
}

/* ---- lifecycle ------------------------------------------------------------------- */

/* With keys: a CURVE server whose ZAP domain tells the handler which
 * allow-list applies. */
static int secure_socket(master_t *m, void *sock, const char *domain, char *err, size_t errlen)
{
    return m->auth ? auth_secure_socket(m->auth, sock, domain, err, errlen) : 0;
}

/* A socket option that must hold: the message-size limits guard the
 * decoder, and peers.c relies on ROUTER_MANDATORY to see a lost worker. */
static int set_option(void *sock, const char *sock_name, int option, const char *option_name,
                      const void *value, size_t size, char *err, size_t errlen)
{
    if (zmq_setsockopt(sock, option, value, size) == 0)
        return 0;
    snprintf(err, errlen, "cannot set %s on the %s socket: %s", option_name, sock_name,
             zmq_strerror(errno));
    return -1;
}

static int set_options(master_t *m, char *err, size_t errlen)
{
    int zero = 0, one = 1, hwm = MASTER_CONTROL_HWM;
    int64_t max_worker_msg = MASTER_MAX_WORKER_MSG, max_control = MASTER_CONTROL_MAX_BYTES;
    void *w = m->workers_sock, *c = m->control_sock;
    if (set_option(w, "worker", ZMQ_LINGER, "LINGER", &zero, sizeof zero, err, errlen) < 0 ||
        set_option(c, "control", ZMQ_LINGER, "LINGER", &zero, sizeof zero, err, errlen) < 0 ||
        set_option(w, "worker", ZMQ_ROUTER_MANDATORY, "ROUTER_MANDATORY", &one, sizeof one, err,
                   errlen) < 0 ||
        set_option(w, "worker", ZMQ_MAXMSGSIZE, "MAXMSGSIZE", &max_worker_msg,
                   sizeof max_worker_msg, err, errlen) < 0 ||
        set_option(c, "control", ZMQ_MAXMSGSIZE, "MAXMSGSIZE", &max_control, sizeof max_control,
                   err, errlen) < 0)
        return -1;
    /* replies a client does not read are dropped past a few, not queued */
    return set_option(c, "control", ZMQ_SNDHWM, "SNDHWM", &hwm, sizeof hwm, err, errlen);
}

static int open_sockets(master_t *m, char *err, size_t errlen)
{
    const master_config_t *cfg = &m->cfg;
    m->workers_sock = zmq_socket(cfg->zmq_ctx, ZMQ_ROUTER);
    m->control_sock = zmq_socket(cfg->zmq_ctx, ZMQ_ROUTER);
    if (!m->workers_sock || !m->control_sock) {
        snprintf(err, errlen, "cannot create sockets: %s", zmq_strerror(errno));
        return -1;
    }
    if (set_options(m, err, errlen) < 0)
        return -1;
    if (secure_socket(m, m->workers_sock, AUTH_DOMAIN_WORKERS, err, errlen) < 0 ||
        secure_socket(m, m->control_sock, AUTH_DOMAIN_CONTROL, err, errlen) < 0)
        return -1;
    if (zmq_bind(m->workers_sock, cfg->worker_endpoint) < 0) {
        snprintf(err, errlen, "cannot bind the worker socket to %s: %s", cfg->worker_endpoint,
                 zmq_strerror(errno));
        return -1;
    }
    if (zmq_bind(m->control_sock, cfg->control_endpoint) < 0) {
        snprintf(err, errlen, "cannot bind the control socket to %s: %s", cfg->control_endpoint,
                 zmq_strerror(errno));
        return -1;
    }
    return 0;
}

/* A zero in the config means "the default". */
static void apply_defaults(master_config_t *c)
{
    if (!c->heartbeat_ms)
        c->heartbeat_ms = MASTER_DEFAULT_HEARTBEAT_MS;
    if (!c->lease_ms)
        c->lease_ms = MASTER_DEFAULT_LEASE_MS;
    if (c->backup_factor == 0)
        c->backup_factor = MASTER_DEFAULT_BACKUP_FACTOR;
    if (!(c->ban_s > 0))
        c->ban_s = MASTER_DEFAULT_BAN_S;
    if (!c->worker_timeout_ms)
        c->worker_timeout_ms = MASTER_DEFAULT_WORKER_TIMEOUT_HEARTBEATS * c->heartbeat_ms;
    if (!(c->checkpoint_s > 0))
        c->checkpoint_s = MASTER_DEFAULT_CHECKPOINT_S;
    if (!c->keep_finished)
        c->keep_finished = MASTER_DEFAULT_KEEP_FINISHED;
    if (!c->max_bundle_mib)
        c->max_bundle_mib = MASTER_DEFAULT_MAX_BUNDLE_MIB;
    if (!c->max_queued_per_client)
        c->max_queued_per_client = MASTER_DEFAULT_MAX_QUEUED_PER_CLIENT;
    if (!c->max_pixels)
        c->max_pixels = MASTER_DEFAULT_MAX_PIXELS;
    if (!c->max_spp)
        c->max_spp = MASTER_DEFAULT_MAX_SPP;
    if (!c->max_requests_per_s)
        c->max_requests_per_s = MASTER_DEFAULT_MAX_REQUESTS_PER_S;
}

/* The state directory, if any, and the offload thread that writes to it. */
static int open_state(master_t *m, char *err, size_t errlen)
{
    if (m->cfg.state_dir) {
        if (!(m->store = store_open(m->cfg.state_dir, err, errlen)))
            return -1;
        /* attempts of this boot never equal a late result's from the last */
        m->attempt_base = (store_boots(m->store) & MASTER_ATTEMPT_BOOT_MASK)
                          << MASTER_ATTEMPT_BOOT_SHIFT;
    }
    submit_limits_t limits = {.max_bundle_bytes = (uint64_t)m->cfg.max_bundle_mib << 20,
                              .max_pixels = m->cfg.max_pixels,
                              .max_spp = m->cfg.max_spp};
    m->offload = offload_new(m->store, &limits, err, errlen);
    return m->offload ? 0 : -1;
}

/* With a secret key, the ZAP handler: before the sockets bind, as ZeroMQ
 * admits every key without one. */
static int start_auth(master_t *m, char *err, size_t errlen)
{
    const master_config_t *cfg = &m->cfg;
    if (!cfg->curve_secret_key)
        return 0;
    auth_config_t ac = {cfg->zmq_ctx, cfg->curve_secret_key, cfg->allow_workers_dir,
                        cfg->allow_clients_dir, cfg->admin_clients_dir,
                        /* it logs refusals only */
                        vblog_filter(cfg->log, cfg->log_level, VBLOG_WARN)};
    if (!(m->auth = auth_new(&ac, err, errlen)))
        return -1;
    m->cfg.curve_secret_key = NULL; /* the caller's; auth keeps its own copy */
    return 0;
}

/* Says where the master listens and who may reach it. */
static void log_listening(master_t *m)
{
    const master_config_t *cfg = &m->cfg;
    master_log(m, "listening: workers %s, control %s, build %s", cfg->worker_endpoint,
               cfg->control_endpoint, m->build);
    if (m->auth) {
        char keys[MASTER_KEYS_TEXT];
        auth_describe(m->auth, keys, sizeof keys);
        master_log(m, "CURVE on both sockets: %s", keys);
        return;
    }
    int wl = auth_endpoint_is_local(cfg->worker_endpoint),
        cl = auth_endpoint_is_local(cfg->control_endpoint);
    if (!wl || !cl)
        master_log(m,
                   "warning: --insecure: no CURVE keys, so anyone who can reach %s%s%s may %s, "
                   "and the "
                   "traffic is not encrypted",
                   wl ? "" : cfg->worker_endpoint, !wl && !cl ? " or " : "",
                   cl ? "" : cfg->control_endpoint,
                   !wl && !cl ? "pose as a worker or submit jobs"
                   : !wl      ? "pose as a worker"
                              : "submit jobs");
}

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
    apply_defaults(&m->cfg);
    m->workers = calloc(MASTER_MAX_WORKERS, sizeof *m->workers);
    m->results = malloc(PROTO_MAX_TASK_PIXELS * sizeof *m->results);
    if (!m->workers || !m->results) {
        snprintf(err, errlen, "out of memory");
        master_destroy(&m);
        return NULL;
    }
    /* without keys, loopback only unless --insecure: checked before the
     * state directory is made */
    if (!cfg->curve_secret_key &&
        (auth_check_bind(cfg->worker_endpoint, cfg->insecure, err, errlen) < 0 ||
         auth_check_bind(cfg->control_endpoint, cfg->insecure, err, errlen) < 0)) {
        master_destroy(&m);
        return NULL;
    }
    /* The build id pins the ISA: a worker on another ISA could trace other bits. */
    proto_host_build_id(m->build);
    if (open_state(m, err, errlen) < 0 || start_auth(m, err, errlen) < 0 ||
        open_sockets(m, err, errlen) < 0) {
        master_destroy(&m);
        return NULL;
    }
    log_listening(m);
    if (m->store)
        persist_recover(m);
    return m;
}

int master_run(master_t *m, const atomic_int *stop)
{
    zmq_pollitem_t items[3] = {{m->workers_sock, 0, ZMQ_POLLIN, 0},
                               {m->control_sock, 0, ZMQ_POLLIN, 0},
                               {NULL, offload_fd(m->offload), ZMQ_POLLIN, 0}};
    while (!(stop && atomic_load(stop)) && !m->shutdown) {
        if (m->cfg.reload && atomic_exchange(m->cfg.reload, 0))
            reload_keys(m);
        int rc = zmq_poll(items, 3, MASTER_POLL_MS);
        if (rc < 0 && errno != EINTR)
            break;
        /* bounded batches so neither socket starves the other */
        for (int k = 0; k < MASTER_WORKER_BATCH && (items[0].revents & ZMQ_POLLIN); k++) {
            peer_handle_message(m);
            int ev = 0;
            size_t sz = sizeof ev;
            /* unchecked: on a failure ev stays 0 and the batch ends here */
            zmq_getsockopt(m->workers_sock, ZMQ_EVENTS, &ev, &sz);
            if (!(ev & ZMQ_POLLIN))
                break;
        }
        if (items[1].revents & ZMQ_POLLIN)
            ctl_handle_message(m);
        if (items[2].revents & ZMQ_POLLIN)
            ctl_offload_done(m);
        double now = master_now();
        if (now - m->last_timer >= MASTER_TIMER_S) {
            periodic(m, now);
            m->last_timer = now;
        }
        dispatch(m);
    }
    peer_say_bye_all(m);
    if (m->store)
        persist_finish(m);
    master_log(m, "stopped");
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
    offload_destroy(&m->offload); /* before the store it writes to */
    persist_destroy(m);
    auth_destroy(&m->auth); /* after the sockets it guards */
    store_close(&m->store);
    free(m->inflight);
    free(m->buckets);
    free(m->quarantine);
    free(m->bans);
    job_t *j = m->jobs;
    while (j) {
        job_t *next = j->next;
        job_free(j);
        j = next;
    }
    free(m->doomed);
    free(m->workers);
    free(m->results);
    free(m->payload);
    free(m);
    *mp = NULL;
}
