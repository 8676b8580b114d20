/* worker.h - a worker: connects to a master, fetches scenes by content hash
 * (and caches them, so workers need no shared file system), traces the
 * tasks it is given on its threads with the core, and returns the results.
 *
 * A worker is stateless as far as the image goes: everything a task needs
 * comes in the task (pixels, sample indices, "so far" sums) and the scene
 * bundle. It heartbeats, reconnects with backoff when the master goes away
 * or refuses its handshake (a key it does not know, or the wrong master key:
 * logged in words, see handshake.h), and on stop releases what it has not
 * started, returns what it has, and says BYE. All state is in the worker_t:
 * several run in one process in the embedded `vbrender render`. Its threads
 * (the render threads, and the TBB pool Embree starts on the first scene)
 * inherit the caller's signal mask: a process that stops on a signal blocks
 * it before worker_new and takes it on a thread of its own (worker/main.c
 * says why).
 */
#ifndef VB_WORKER_H
#define VB_WORKER_H

#include <stdatomic.h>
#include <stddef.h>
#include <stdio.h>

typedef struct worker worker_t;

/* Scenes loaded once for all the workers of one process that are given
 * it (the embedded `vbrender render`): the first worker a scene's bundle
 * reaches loads it and builds its BVH, the others wait for it and share
 * it (a loaded scene and its tracer are only read). Thread-safe; it must
 * outlive every worker given it. */
typedef struct worker_scenes worker_scenes_t;
worker_scenes_t *worker_scenes_new(void);
void worker_scenes_destroy(worker_scenes_t **s);

typedef struct worker_config {
    void *zmq_ctx;                /* not owned */
    const char *master_endpoint;  /* e.g. tcp://host:7070 or inproc://workers */
    int threads;                  /* render threads, >= 1 */
    int cache_scenes;             /* scenes kept loaded; 0: 4 */
    FILE *log;                    /* NULL: silent */
    int log_level;                /* least severe level logged (vblog_level_t); 0: info */
    const char *name;             /* for log lines */
    struct tracer_device *device; /* the process's Embree device, shared; NULL:
                                     the worker makes (and owns) its own */
    worker_scenes_t *scenes;      /* loaded scenes shared with the process's
                                     other workers (not owned; needs device,
                                     the same for all of them); NULL: its own */
    /* CURVE (keys.h, Z85): all three, or none for a master without keys */
    const char *public_key; /* this worker's key pair */
    const char *secret_key;
    const char *master_key; /* the master's public key */
} worker_config_t;

worker_t *worker_new(const worker_config_t *cfg, char *err, size_t errlen);

/* Runs until *stop becomes non-zero (then leaves cleanly) or the master
 * refuses this worker (version or build mismatch, or its key was removed
 * from the allow-list while connected: returns 1). 0 otherwise. */
int worker_run(worker_t *w, const atomic_int *stop);

void worker_destroy(worker_t **w);

#endif
