/* control.h - the client side of the master's control protocol (JSON over a
 * REQ socket, proto/PROTOCOL.md): scene bundles, requests, images.
 */
#ifndef VB_CONTROL_H
#define VB_CONTROL_H

#include <cJSON.h>
#include <stddef.h>

#include "image.h"

typedef struct control control_t;

/* A REQ socket to the master's control endpoint, with a receive timeout. */
control_t *control_new(void *zmq_ctx, const char *endpoint, int timeout_ms, char *err, size_t errlen);
void control_destroy(control_t **c);

/* Sends a request (and binary frames) and returns the parsed reply (free
 * with cJSON_Delete), or NULL with a message when the master does not
 * answer in time or the reply is not JSON. A reply {"ok": false, "error":
 * "..."} is returned as is: the caller reports its error. Extra reply
 * frames, if any, are stored until control_take_frames. */
cJSON *control_request(control_t *c, const cJSON *req, const void *const *frames, const size_t *sizes,
                       int nframes, char *err, size_t errlen);

/* Reads a scene file and the mesh files it names, renames the meshes to
 * bundle names (mesh0.ply, ...), and submits it with the given settings
 * (a JSON object of submit fields; may be NULL) and, if not NULL, a
 * reference image (channels R, G, B) the master measures the error
 * against. Returns the job id, or 0 with a message. */
unsigned long long control_submit(control_t *c, const char *scene_path, const cJSON *settings,
                                  const image_t *reference, char *err, size_t errlen);

/* Fetches a job's image (channels R, G, B, samples, variance) with the
 * job's status in *job (free with cJSON_Delete). NULL with a message. */
image_t *control_fetch(control_t *c, unsigned long long job, cJSON **job_status, char *err, size_t errlen);

#endif
