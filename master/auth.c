/* auth.c - see auth.h. */
#include "auth.h"

#include <arpa/inet.h>
#include <errno.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <zmq.h>

#include "keys.h"
#include "vberr.h"
#include "vblog.h"

#define ZAP_ENDPOINT "inproc://zeromq.zap.01"
#define ZAP_MAX_FRAMES 8       /* RFC 27: six, and one credential frame for CURVE */
#define ZAP_FLUSH_MS 1000      /* the handler wakes this often to flush log summaries */
#define ZAP_CURVE_KEY_BYTES 32 /* a CURVE credential frame: the client's public key, binary */

/* The allow-lists, swapped whole on reload. */
typedef struct auth_lists {
    keys_set_t *workers, *clients, *admins;
} auth_lists_t;

struct auth {
    auth_config_t cfg;
    char secret[KEYS_Z85_LEN + 1];
    char workers_dir[4096], clients_dir[4096], admins_dir[4096];
    pthread_mutex_t lock; /* guards lists: the handler and the master read, reload writes */
    auth_lists_t lists;
    void *zap;     /* REP, the handler thread's */
    void *stop_rx; /* PAIR, the handler thread's: a message says stop */
    void *stop_tx; /* PAIR, the owner's */
    char stop_endpoint[64];
    pthread_t thread;
    int started;
    vblog_limiter_t limiter; /* the handler thread's own: refusals are peer-provoked */
};

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* ---- lists ------------------------------------------------------------------------- */

static void lists_free(auth_lists_t *l)
{
    keys_set_destroy(&l->workers);
    keys_set_destroy(&l->clients);
    keys_set_destroy(&l->admins);
}

static int lists_load(const auth_t *a, auth_lists_t *l, char *err, size_t errlen)
{
    memset(l, 0, sizeof *l);
    if (!(l->workers = keys_set_load_dir(a->workers_dir, err, errlen)))
        return -1;
    if ((a->clients_dir[0] && !(l->clients = keys_set_load_dir(a->clients_dir, err, errlen))) ||
        (a->admins_dir[0] && !(l->admins = keys_set_load_dir(a->admins_dir, err, errlen)))) {
        lists_free(l);
        return -1;
    }
    return 0;
}

static void describe_lists(const auth_lists_t *l, char *msg, size_t msglen)
{
    size_t w = keys_set_count(l->workers), c = keys_set_count(l->clients),
           a = keys_set_count(l->admins);
    snprintf(msg, msglen, "%zu worker key%s, %zu client key%s, %zu admin key%s", w,
             w == 1 ? "" : "s", c, c == 1 ? "" : "s", a, a == 1 ? "" : "s");
}

/* Whether key is admitted to domain by lists l (the caller holds the lock). */
static int admitted(const auth_lists_t *l, const char *domain, const char *key)
{
    if (strcmp(domain, AUTH_DOMAIN_WORKERS) == 0)
        return keys_set_contains(l->workers, key);
    if (strcmp(domain, AUTH_DOMAIN_CONTROL) == 0)
        return keys_set_contains(l->clients, key) || keys_set_contains(l->admins, key);
    return 0;
}

int auth_allowed(auth_t *a, const char *domain, const char *user_id)
{
    if (!a || !domain || !user_id)
        return 0;
    pthread_mutex_lock(&a->lock);
    int ok = admitted(&a->lists, domain, user_id);
    pthread_mutex_unlock(&a->lock);
    return ok;
}

int auth_is_admin(auth_t *a, const char *user_id)
{
    if (!a || !user_id)
        return 0;
    pthread_mutex_lock(&a->lock);
    int ok = keys_set_contains(a->lists.admins, user_id);
    pthread_mutex_unlock(&a->lock);
    return ok;
}

int auth_reload(auth_t *a, char *msg, size_t msglen)
{
    auth_lists_t fresh;
    char err[VB_ERR_LEN];
    if (lists_load(a, &fresh, err, sizeof err) < 0) {
        snprintf(msg, msglen, "%s", err);
        return -1;
    }
    pthread_mutex_lock(&a->lock);
    auth_lists_t old = a->lists;
    a->lists = fresh;
    describe_lists(&a->lists, msg, msglen);
    pthread_mutex_unlock(&a->lock);
    /* nobody can hold the old lists: every reader holds the lock */
    lists_free(&old);
    return 0;
}

void auth_describe(auth_t *a, char *msg, size_t msglen)
{
    pthread_mutex_lock(&a->lock);
    describe_lists(&a->lists, msg, msglen);
    pthread_mutex_unlock(&a->lock);
}

/* ---- the ZAP handler ----------------------------------------------------------------- */

static void refusal(auth_t *a, const char *key, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
static void refusal(auth_t *a, const char *key, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vblog_limited(&a->limiter, a->cfg.log, "master", key, now_s(), fmt, ap);
    va_end(ap);
}

/* Frame i as a terminated string (cut to cap - 1 bytes). */
static const char *frame_str(zmq_msg_t *f, int n, int i, char *buf, size_t cap)
{
    buf[0] = '\0';
    if (i < n) {
        size_t len = zmq_msg_size(&f[i]);
        if (len > cap - 1)
            len = cap - 1;
        memcpy(buf, zmq_msg_data(&f[i]), len);
        buf[len] = '\0';
    }
    return buf;
}

static int frame_is(zmq_msg_t *f, int n, int i, const char *text)
{
    return i < n && zmq_msg_size(&f[i]) == strlen(text) &&
           memcmp(zmq_msg_data(&f[i]), text, strlen(text)) == 0;
}

static void reply(auth_t *a, zmq_msg_t *f, int n, const char *code, const char *text,
                  const char *user_id)
{
    /* RFC 27: version, request id, status code, status text, user id, metadata.
     * The sends are unchecked: the reply goes over inproc to libzmq itself,
     * and fails only while the context terminates, when no handshake waits. */
    zmq_send(a->zap, "1.0", 3, ZMQ_SNDMORE);
    if (n > 1)
        zmq_send(a->zap, zmq_msg_data(&f[1]), zmq_msg_size(&f[1]), ZMQ_SNDMORE);
    else
        zmq_send(a->zap, "", 0, ZMQ_SNDMORE);
    zmq_send(a->zap, code, strlen(code), ZMQ_SNDMORE);
    zmq_send(a->zap, text, strlen(text), ZMQ_SNDMORE);
    zmq_send(a->zap, user_id, strlen(user_id), ZMQ_SNDMORE);
    zmq_send(a->zap, "", 0, 0);
}

static void handle_request(auth_t *a)
{
    zmq_msg_t f[ZAP_MAX_FRAMES];
    int n = 0, more = 1, extra = 0;
    while (more) {
        zmq_msg_t x;
        zmq_msg_init(&x);
        if (zmq_msg_recv(&x, a->zap, ZMQ_DONTWAIT) < 0) {
            zmq_msg_close(&x);
            break;
        }
        more = zmq_msg_more(&x);
        if (n < ZAP_MAX_FRAMES)
            f[n++] = x;
        else {
            zmq_msg_close(&x);
            extra = 1;
        }
    }
    if (n == 0)
        return; /* nothing to answer: a REP socket gets whole messages */
    char domain[32], address[64], key[KEYS_Z85_LEN + 1] = "";
    frame_str(f, n, 2, domain, sizeof domain);
    frame_str(f, n, 3, address, sizeof address);
    if (extra || n < 6 || !frame_is(f, n, 0, "1.0")) {
        /* only libzmq asks here; answer anyway, or the handshake would hang */
        reply(a, f, n, "500", "malformed ZAP request", "");
    } else if (!frame_is(f, n, 5, "CURVE") || n != 7 ||
               zmq_msg_size(&f[6]) != ZAP_CURVE_KEY_BYTES) {
        reply(a, f, n, "400", "CURVE required", "");
        refusal(a, "zap-mechanism", "refused a peer at %s: not a CURVE handshake", address);
    } else {
        zmq_z85_encode(key, zmq_msg_data(&f[6]), ZAP_CURVE_KEY_BYTES);
        pthread_mutex_lock(&a->lock);
        int ok = admitted(&a->lists, domain, key);
        pthread_mutex_unlock(&a->lock);
        if (ok) {
            reply(a, f, n, "200", "OK", key);
        } else if (strcmp(domain, AUTH_DOMAIN_WORKERS) == 0) {
            reply(a, f, n, "400", "worker key not allowed", "");
            refusal(a, "zap-refused-worker",
                    "refused worker key %s from %s: not in --allow-workers", key, address);
        } else if (strcmp(domain, AUTH_DOMAIN_CONTROL) == 0) {
            reply(a, f, n, "400", "client key not allowed", "");
            refusal(a, "zap-refused-client",
                    "refused client key %s from %s: not in --allow-clients or "
                    "--admin-clients",
                    key, address);
        } else {
            reply(a, f, n, "400", "unknown domain", "");
            refusal(a, "zap-domain", "refused key %s from %s: unknown ZAP domain '%s'", key,
                    address, domain);
        }
    }
    for (int i = 0; i < n; i++)
        zmq_msg_close(&f[i]);
}

static void *zap_main(void *arg)
{
    auth_t *a = arg;
    zmq_pollitem_t items[2] = {{a->zap, 0, ZMQ_POLLIN, 0}, {a->stop_rx, 0, ZMQ_POLLIN, 0}};
    for (;;) {
        int rc = zmq_poll(items, 2, ZAP_FLUSH_MS);
        if (rc < 0 && errno != EINTR)
            break;
        if (rc > 0 && (items[1].revents & ZMQ_POLLIN))
            break;
        if (rc > 0 && (items[0].revents & ZMQ_POLLIN))
            handle_request(a);
        vblog_limiter_flush(&a->limiter, a->cfg.log, "master", now_s());
    }
    return NULL;
}

/* ---- lifecycle ----------------------------------------------------------------------- */

static int copy_path(char *dst, size_t cap, const char *src, char *err, size_t errlen)
{
    if ((size_t)snprintf(dst, cap, "%s", src ? src : "") >= cap) {
        snprintf(err, errlen, "path too long: %.200s", src);
        return -1;
    }
    return 0;
}

auth_t *auth_new(const auth_config_t *cfg, char *err, size_t errlen)
{
    if (!cfg->secret_key || !keys_valid_z85(cfg->secret_key)) {
        snprintf(err, errlen, "the master's secret key is not a Z85 CURVE key");
        return NULL;
    }
    if (!cfg->workers_dir) {
        snprintf(err, errlen, "CURVE needs an allow-list of worker keys (--allow-workers DIR)");
        return NULL;
    }
    if (!zmq_has("curve")) {
        snprintf(err, errlen, "this libzmq has no CURVE support");
        return NULL;
    }
    auth_t *a = calloc(1, sizeof *a);
    if (!a) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    a->cfg = *cfg;
    memcpy(a->secret, cfg->secret_key, sizeof a->secret);
    a->cfg.secret_key = a->secret;
    pthread_mutex_init(&a->lock, NULL);
    if (copy_path(a->workers_dir, sizeof a->workers_dir, cfg->workers_dir, err, errlen) < 0 ||
        copy_path(a->clients_dir, sizeof a->clients_dir, cfg->clients_dir, err, errlen) < 0 ||
        copy_path(a->admins_dir, sizeof a->admins_dir, cfg->admins_dir, err, errlen) < 0 ||
        lists_load(a, &a->lists, err, errlen) < 0) {
        auth_destroy(&a);
        return NULL;
    }
    /* the handler's sockets are made and bound here, before any master
     * socket binds, then handed to its thread (pthread_create is the
     * memory barrier ZeroMQ asks for when a socket changes threads) */
    snprintf(a->stop_endpoint, sizeof a->stop_endpoint, "inproc://vb-auth-stop-%p", (void *)a);
    a->zap = zmq_socket(cfg->zmq_ctx, ZMQ_REP);
    a->stop_rx = zmq_socket(cfg->zmq_ctx, ZMQ_PAIR);
    a->stop_tx = zmq_socket(cfg->zmq_ctx, ZMQ_PAIR);
    if (!a->zap || !a->stop_rx || !a->stop_tx) {
        snprintf(err, errlen, "cannot create the ZAP handler's sockets: %s", zmq_strerror(errno));
        auth_destroy(&a);
        return NULL;
    }
    /* LINGER is valid on every socket type: these cannot fail, and a
     * linger left at its default would only delay auth_destroy */
    int zero = 0;
    zmq_setsockopt(a->zap, ZMQ_LINGER, &zero, sizeof zero);
    zmq_setsockopt(a->stop_rx, ZMQ_LINGER, &zero, sizeof zero);
    zmq_setsockopt(a->stop_tx, ZMQ_LINGER, &zero, sizeof zero);
    if (zmq_bind(a->zap, ZAP_ENDPOINT) < 0) {
        snprintf(err, errlen, "cannot bind the ZAP handler to %s: %s (one per ZeroMQ context)",
                 ZAP_ENDPOINT, zmq_strerror(errno));
        auth_destroy(&a);
        return NULL;
    }
    if (zmq_bind(a->stop_rx, a->stop_endpoint) < 0 ||
        zmq_connect(a->stop_tx, a->stop_endpoint) < 0) {
        snprintf(err, errlen, "cannot connect the ZAP handler's stop socket: %s",
                 zmq_strerror(errno));
        auth_destroy(&a);
        return NULL;
    }
    if (pthread_create(&a->thread, NULL, zap_main, a) != 0) {
        snprintf(err, errlen, "cannot start the ZAP handler thread");
        auth_destroy(&a);
        return NULL;
    }
    a->started = 1;
    return a;
}

void auth_destroy(auth_t **ap)
{
    if (!ap || !*ap)
        return;
    auth_t *a = *ap;
    if (a->started) {
        /* a blocking send to a connected inproc PAIR: it returns once
         * queued, and fails only while the context terminates, which
         * also ends the thread's poll */
        zmq_send(a->stop_tx, "", 0, 0);
        pthread_join(a->thread, NULL);
    }
    if (a->zap)
        zmq_close(a->zap);
    if (a->stop_rx)
        zmq_close(a->stop_rx);
    if (a->stop_tx)
        zmq_close(a->stop_tx);
    vblog_limiter_flush(&a->limiter, a->cfg.log, "master", now_s() + 2 * VBLOG_WINDOW_S);
    lists_free(&a->lists);
    pthread_mutex_destroy(&a->lock);
    explicit_bzero(a->secret, sizeof a->secret);
    free(a);
    *ap = NULL;
}

int auth_secure_socket(auth_t *a, void *sock, const char *domain, char *err, size_t errlen)
{
    int one = 1;
    if (zmq_setsockopt(sock, ZMQ_CURVE_SERVER, &one, sizeof one) < 0 ||
        zmq_setsockopt(sock, ZMQ_CURVE_SECRETKEY, a->secret, KEYS_Z85_LEN) < 0 ||
        zmq_setsockopt(sock, ZMQ_ZAP_DOMAIN, domain, strlen(domain)) < 0) {
        snprintf(err, errlen, "cannot make the %s socket a CURVE server: %s", domain,
                 zmq_strerror(errno));
        return -1;
    }
    return 0;
}

/* ---- endpoints ----------------------------------------------------------------------- */

int auth_endpoint_is_local(const char *ep)
{
    if (!ep)
        return 0;
    if (strncmp(ep, "inproc://", 9) == 0 || strncmp(ep, "ipc://", 6) == 0)
        return 1;
    if (strncmp(ep, "tcp://", 6) != 0)
        return 0;
    const char *host = ep + 6;
    if (strncmp(host, "[::1]:", 6) == 0)
        return 1;
    const char *colon = strrchr(host, ':');
    size_t len = colon ? (size_t)(colon - host) : 0;
    char name[64];
    if (!colon || len == 0 || len >= sizeof name)
        return 0;
    memcpy(name, host, len);
    name[len] = '\0';
    if (strcmp(name, "localhost") == 0)
        return 1;
    /* an IPv4 literal in 127/8; anything else (a name, *, an interface) may
     * reach beyond this host */
    struct in_addr in;
    return inet_pton(AF_INET, name, &in) == 1 &&
           (ntohl(in.s_addr) >> IN_CLASSA_NSHIFT) == IN_LOOPBACKNET;
}

int auth_check_bind(const char *endpoint, int insecure, char *err, size_t errlen)
{
    if (insecure || auth_endpoint_is_local(endpoint))
        return 0;
    snprintf(err, errlen,
             "refusing to listen on %s without CURVE keys: anyone who can reach it could submit "
             "jobs or pose as a "
             "worker. Give --key with --allow-workers/--allow-clients (see 'vbrender keygen'), "
             "bind a loopback "
             "address, or pass --insecure to accept that",
             endpoint);
    return -1;
}
