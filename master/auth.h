/* auth.h - who may talk to the master: CURVE (ZeroMQ RFC 26) on both of its
 * sockets, and a ZAP handler (RFC 27) that admits exactly the listed keys.
 *
 * The handler is a thread of its own with a REP socket bound to
 * inproc://zeromq.zap.01 on the master's context (ZeroMQ asks it about every
 * CURVE handshake on that context). The two sockets carry the ZAP domains
 * "workers" and "control", so it can tell a worker from a client:
 *
 *   workers  keys in the --allow-workers directory
 *   control  keys in --allow-clients or --admin-clients (an admin may act on
 *            every job; whether a key is one is auth_is_admin's answer)
 *
 * It answers 200 with the key (Z85) as the User-Id, which ZeroMQ then puts
 * on every frame from that peer (zmq_msg_gets(frame, "User-Id")), or 400;
 * each refusal is logged, with the key and the peer's address, at a bounded
 * rate. auth_reload (SIGHUP) reads the directories again and swaps the
 * lists under a mutex: new handshakes see the new lists at once, and
 * auth_allowed, cheap enough to ask per message, lets the master drop a
 * peer whose key was removed while it was connected.
 *
 * Without keys the master may only bind loopback endpoints (auth_check_bind)
 * unless it is told --insecure.
 */
#ifndef VB_AUTH_H
#define VB_AUTH_H

#include <stddef.h>
#include <stdio.h>

#define AUTH_DOMAIN_WORKERS "workers"
#define AUTH_DOMAIN_CONTROL "control"

typedef struct auth auth_t;

typedef struct auth_config {
    void *zmq_ctx;           /* the master's context (not owned) */
    const char *secret_key;  /* the master's secret key, Z85 (keys.h) */
    const char *workers_dir; /* .pub files of the workers admitted */
    const char *clients_dir; /* .pub files of the clients admitted; NULL: none */
    const char *admins_dir;  /* clients that may act on every job; NULL: none */
    FILE *log;               /* refusals; NULL: silent */
} auth_config_t;

/* Loads the allow-lists and starts the handler. Must come before the
 * master's sockets bind: a CURVE server on a context without a handler
 * admits every key. NULL with a message (a directory or key file is bad,
 * another handler is bound on this context). */
auth_t *auth_new(const auth_config_t *cfg, char *err, size_t errlen);

/* Stops the handler; after the sockets it guards are closed. */
void auth_destroy(auth_t **a);

/* Makes sock (a ROUTER, before bind) a CURVE server of the given domain. */
int auth_secure_socket(auth_t *a, void *sock, const char *domain, char *err, size_t errlen);

/* Reads the directories again and, if all of them load, swaps the lists in;
 * otherwise keeps the old ones. 0 with a summary in msg ("3 worker keys,
 * ..."), or -1 with why in msg. */
int auth_reload(auth_t *a, char *msg, size_t msglen);

/* The lists as a summary for a log line. */
void auth_describe(auth_t *a, char *msg, size_t msglen);

/* Whether user_id (a Z85 key) is admitted to the domain now. Thread-safe;
 * a mutex and a binary search. */
int auth_allowed(auth_t *a, const char *domain, const char *user_id);

/* Whether user_id is in --admin-clients. */
int auth_is_admin(auth_t *a, const char *user_id);

/* Whether a master without keys may bind endpoint: loopback only
 * (tcp://127.x.y.z, tcp://localhost, tcp://[::1], ipc://, inproc://)
 * unless insecure. -1 with a message naming the endpoint and --insecure. */
int auth_check_bind(const char *endpoint, int insecure, char *err, size_t errlen);

/* Whether endpoint is reachable from this host only (as above). */
int auth_endpoint_is_local(const char *endpoint);

#endif
