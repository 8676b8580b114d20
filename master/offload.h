/* offload.h - the master's slow control work, off its event loop.
 *
 * A submission is checked by loading its whole scene (meshes parsed, every
 * setting validated) and, with a state directory, written and fsync'd
 * before its id is answered; an ended job's image is read back from disk
 * for fetch. Each can take from milliseconds to seconds, and the event loop
 * must not wait on any client: heartbeats, results and other clients keep
 * flowing meanwhile. So one thread does this work in order (so job ids
 * follow submission order) and hands finished items back; the loop, which
 * owns every socket and every job, replies and adds the jobs.
 *
 * The thread touches no master state: submit_parse is pure, and the store's
 * job-id counter and job directories are written by this thread only.
 */
#ifndef VB_OFFLOAD_H
#define VB_OFFLOAD_H

#include <cJSON.h>
#include <stddef.h>
#include <stdint.h>
#include <zmq.h>

#include "image.h"
#include "proto.h"
#include "store.h"
#include "vberr.h"

#define OFFLOAD_MAX_FRAMES (PROTO_MAX_MESHES + 4)

typedef enum {
    OFFLOAD_SUBMIT = 1,
    OFFLOAD_SUBMIT_DUPLICATE = 2, /* a retry of one in flight: passes through, in order */
    OFFLOAD_FETCH = 3
} offload_kind_t;

struct job;

typedef struct offload_item {
    offload_kind_t kind;
    zmq_msg_t client; /* the requester's identity frame */
    /* submit: the request as received (JSON, then binary frames) */
    zmq_msg_t frames[OFFLOAD_MAX_FRAMES];
    int nframes;
    cJSON *req;
    /* fetch: which job, and the image file */
    uint64_t job_id;
    char path[4096];
    /* results */
    struct job *job; /* submit: the new job (with its id when stored) */
    image_t *image;  /* fetch */
    char err[VB_ERR_LEN];
    char owner[128]; /* submit: the client the job will belong to */
    struct offload_item *next;
} offload_item_t;

typedef struct offload offload_t;

struct submit_limits;
/* store may be NULL (no state directory); limits are copied. Starts the
 * thread. */
offload_t *offload_new(store_t *store, const struct submit_limits *limits, char *err,
                       size_t errlen);
/* Stops the thread after the item it is on; items not done are freed. */
void offload_destroy(offload_t **o);

/* A new item for the caller to fill: zeroed, frames initialised. */
offload_item_t *offload_item_new(offload_kind_t kind);
void offload_item_free(offload_item_t *it);
/* Hands an item to the thread (which owns it until it comes back). */
void offload_push(offload_t *o, offload_item_t *it);
/* The file descriptor that becomes readable when items are done (for
 * zmq_poll), and the done items in order (a list; NULL when none). */
int offload_fd(const offload_t *o);
offload_item_t *offload_take_done(offload_t *o);
/* Items handed over and not yet taken back. */
size_t offload_pending(const offload_t *o);

#endif
