/* control.h - the client side of the master's control protocol (JSON over a
 * REQ socket, proto/PROTOCOL.md): scene bundles, requests, images.
 */
#ifndef VB_CONTROL_H
#define VB_CONTROL_H

#include <cJSON.h>
#include <stddef.h>

#include "image.h"

typedef struct control control_t;

/* CURVE keys for a master that uses them (keys.h, Z85). */
typedef struct control_keys {
    const char *public_key, *secret_key; /* this client's key pair */
    const char *master_key;              /* the master's public key */
} control_keys_t;

/* A REQ socket to the master's control endpoint, with a receive timeout. */
control_t *control_new(void *zmq_ctx, const char *endpoint, int timeout_ms, char *err,
                       size_t errlen);

/* The same as a CURVE client (keys NULL: without CURVE). Either way the
 * socket's handshakes are watched: a request to a master that refuses this
 * client's key, or that this client cannot handshake with (the wrong
 * master key, CURVE on one side only), fails at once with a message saying
 * so (handshake.h) instead of waiting out the timeout; control_lost is then
 * 0, so nothing retries it. */
control_t *control_new_with_keys(void *zmq_ctx, const char *endpoint, int timeout_ms,
                                 const control_keys_t *keys, char *err, size_t errlen);
void control_destroy(control_t **c);

/* Sends a request (and binary frames) and returns the parsed reply (free
 * with cJSON_Delete), or NULL with a message when the master does not
 * answer in time or the reply is not JSON. A reply {"ok": false, "error":
 * "..."} is returned as is: the caller reports its error. Extra reply
 * frames, if any, are stored until control_take_frames. Neither the send
 * nor the receive waits longer than the timeout given to control_new. */
cJSON *control_request(control_t *c, const cJSON *req, const void *const *frames,
                       const size_t *sizes, int nframes, char *err, size_t errlen);

/* The binary frames after the JSON of the last reply (a preview's image
 * and samples, say): how many, and frame i's bytes (NULL when i is out of
 * range) with its size. Valid until the next request. */
int control_frame_count(const control_t *c);
const void *control_frame(const control_t *c, int i, size_t *size);

/* Whether the last request got no answer in time: the master is down,
 * restarting or busy, and it may or may not have received the request. */
int control_lost(const control_t *c);

/* How control_request_retry keeps asking a master that does not answer. */
typedef struct control_retry {
    double timeout_s; /* give up when the master stays silent this long; <= 0: one try */
    /* called once per outage, before the first retry (may be NULL) */
    void (*on_outage)(void *arg, const char *endpoint, double timeout_s);
    void *arg;
    int unreachable; /* out: 1 when it gave up after timeout_s */
} control_retry_t;

/* control_request, sent again (the same request, the same frames) while
 * the reply is lost, with a backoff of 0.25 s growing to 2 s, until the
 * master answers or retry->timeout_s has passed since the call. A try
 * waits at most the control_new timeout, and at most a fifth of
 * timeout_s (at least 0.5 s) so that several tries fit in it. Only a
 * request that is safe to repeat may be sent this way. retry NULL: one try. */
cJSON *control_request_retry(control_t *c, const cJSON *req, const void *const *frames,
                             const size_t *sizes, int nframes, control_retry_t *retry, char *err,
                             size_t errlen);

/* Reads a scene file and the mesh files it names, renames the meshes to
 * bundle names (mesh0.ply, ...), and submits it with the given settings
 * (a JSON object of submit fields; may be NULL) and, if not NULL, a
 * reference image (channels R, G, B) the master measures the error
 * against. The request carries a fresh random "request_id", so it is
 * retried as control_request_retry says (retry may be NULL: one try)
 * without queueing the job twice. Returns the job id, or 0 with a
 * message. */
unsigned long long control_submit(control_t *c, const char *scene_path, const cJSON *settings,
                                  const image_t *reference, control_retry_t *retry, char *err,
                                  size_t errlen);

/* A Mitsuba scene's -D name=value parameters (mitsuba.h), for
 * control_submit and control_scene_json. */
typedef struct control_defines {
    const char *const *items;
    size_t count;
} control_defines_t;

/* The scene at path as the master will get it: a JSON scene parsed, or a
 * Mitsuba scene (.xml) converted with defines (may be NULL). NULL with a
 * message; *raw_ok is set when a JSON file's text did not parse, which
 * control_submit then sends as it is (the master names the line). */
cJSON *control_scene_json(const char *path, const control_defines_t *defines, int *raw_ok,
                          char *err, size_t errlen);

/* control_submit for a scene that may be a Mitsuba file, with its
 * parameters. */
unsigned long long control_submit_defines(control_t *c, const char *scene_path,
                                          const control_defines_t *defines, const cJSON *settings,
                                          const image_t *reference, control_retry_t *retry,
                                          char *err, size_t errlen);

/* Fetches a job's image (channels R, G, B, samples, variance) with the
 * job's status in *job (free with cJSON_Delete). NULL with a message. */
image_t *control_fetch(control_t *c, unsigned long long job, cJSON **job_status, char *err,
                       size_t errlen);

#endif
