/* master.h - the master: queues jobs, hands layer tasks to workers, merges
 * their results, answers clients.
 *
 * One thread, one event loop over two ROUTER sockets: workers (the binary
 * protocol of proto/) and control (JSON requests, proto/PROTOCOL.md). No
 * state outside the master_t, so a test or the embedded `vbrender render`
 * can run a master in a thread of its own over ZeroMQ's inproc transport.
 */
#ifndef VB_MASTER_H
#define VB_MASTER_H

#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "defaults.h" /* MASTER_DEFAULT_*: what a zeroed config field means */

typedef struct master master_t;

typedef struct master_config {
    void *zmq_ctx;                /* the ZeroMQ context to use (not owned) */
    const char *worker_endpoint;  /* e.g. tcp port 7070 on every interface, or inproc */
    const char *control_endpoint; /* e.g. tcp port 7071, or inproc */
    uint32_t heartbeat_ms;        /* 0: MASTER_DEFAULT_HEARTBEAT_MS */
    uint32_t lease_ms;            /* 0: MASTER_DEFAULT_LEASE_MS; the longest a task may
                                     go unanswered before it is issued again (leases
                                     follow the job's task times below it) */
    uint32_t worker_timeout_ms;   /* 0: MASTER_DEFAULT_WORKER_TIMEOUT_HEARTBEATS beats */
    /* A task out this many times the job's typical task time gets a backup
     * copy on an idle worker (the first answer wins). 0:
     * MASTER_DEFAULT_BACKUP_FACTOR; negative: no backups. */
    double backup_factor;
    /* A worker whose results are refused MASTER_MAX_BAD_RESULTS times is
     * dropped and refused this long, doubled on each repeat. 0:
     * MASTER_DEFAULT_BAN_S. */
    double ban_s;
    int allow_shutdown;     /* accept the "shutdown" control command */
    const char *state_dir;  /* durable state (store.h); NULL: in memory only */
    double checkpoint_s;    /* 0: MASTER_DEFAULT_CHECKPOINT_S */
    uint32_t keep_finished; /* ended jobs kept; 0: MASTER_DEFAULT_KEEP_FINISHED */
    /* Limits, each checked before a request's data is copied (0: default). */
    uint32_t max_bundle_mib;        /* scene JSON and meshes of one job */
    uint32_t max_queued_per_client; /* queued and running jobs of one client */
    uint64_t max_pixels;            /* width x height of one job */
    uint32_t max_spp;               /* samples per pixel of one job */
    uint32_t max_requests_per_s;    /* control requests of one connection */
    /* Verification by replication: this share of tasks (chosen by job seed
     * and task id) also goes to a second worker, and is merged only when
     * both results agree bit for bit. 0: none; 1: every task. */
    double verify_share;
    FILE *log;     /* NULL: silent */
    int log_level; /* least severe level logged (vblog_level_t); 0: info */
    /* transport security (auth.h) */
    const char *curve_secret_key;  /* Z85 (keys.h): both sockets speak CURVE and admit
                                      the listed keys only; NULL: no CURVE, and then
                                      loopback endpoints only unless insecure */
    const char *allow_workers_dir; /* .pub files: workers admitted (needed with a key) */
    const char *allow_clients_dir; /* .pub files: clients admitted */
    const char *admin_clients_dir; /* .pub files: clients that may act on every job */
    int insecure;                  /* without a key, bind beyond loopback anyway */
    atomic_int *reload;            /* non-zero (SIGHUP): master_run reads the
                                      allow-lists again and clears it; may be NULL */
} master_config_t;

/* Binds both sockets; with a state directory, recovers every job in it.
 * NULL with a message (e.g. address in use, state directory unusable). */
master_t *master_new(const master_config_t *cfg, char *err, size_t errlen);

/* Runs the event loop until *stop becomes non-zero or a shutdown command
 * arrives; reloads the allow-lists when *cfg.reload is set. Returns 0. */
int master_run(master_t *m, const atomic_int *stop);

void master_destroy(master_t **m);

#endif
