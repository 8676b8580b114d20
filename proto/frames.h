/* frames.h - one multi-part ZeroMQ message received or sent in one call,
 * for every socket of the master, the worker and the client.
 *
 * A receive takes every part of the message off the socket, so the next
 * receive starts at the next message whatever this one held: parts past the
 * caller's limit are received and closed unread, and the message is marked
 * too long or too big for the caller to count and refuse. Routing frames
 * are ordinary parts here: a ROUTER's identity is part 0, a REQ peer's
 * empty delimiter part 1; the caller knows its socket's envelope.
 */
#ifndef VB_FRAMES_H
#define VB_FRAMES_H

#include <stddef.h>
#include <zmq.h>

#include "proto.h"

/* The most parts one receive keeps: a control request is [identity][empty]
 * [json] and a scene plus its mesh files. */
#define PROTO_FRAMES_MAX (PROTO_MAX_MESHES + 4)

/* proto_recv's verdicts. */
typedef enum proto_recv_result {
    PROTO_RECV_OK = 0,        /* every part is in part[0..count) */
    PROTO_RECV_NONE = -1,     /* nothing received (errno: EAGAIN, ETERM, ...) */
    PROTO_RECV_TOO_MANY = -2, /* more parts than the limit: the first ones kept */
    PROTO_RECV_TOO_BIG = -3   /* more bytes in all than the limit: the parts kept */
} proto_recv_result_t;

/* A received message. Its parts stay open until proto_frames_close. */
typedef struct proto_frames {
    zmq_msg_t part[PROTO_FRAMES_MAX];
    int count;    /* parts kept in part[] */
    int dropped;  /* parts past the limit: received and closed */
    size_t bytes; /* size of every part received, kept or dropped */
} proto_frames_t;

/* Receives every part of one message from sock into *fr (any earlier
 * content is not closed: call proto_frames_close first). At most max_parts
 * (1..PROTO_FRAMES_MAX) are kept; max_bytes bounds the total (SIZE_MAX: no
 * bound but the socket's own ZMQ_MAXMSGSIZE per part). flags go to every
 * part's receive (ZMQ_DONTWAIT: ZeroMQ delivers a message whole, so once its
 * first part is there the rest are too). A receive that fails after the
 * first part ends the message where it is, with what came. */
proto_recv_result_t proto_recv(void *sock, proto_frames_t *fr, int max_parts, size_t max_bytes,
                               int flags);

/* Closes the kept parts; fr can then receive again. */
void proto_frames_close(proto_frames_t *fr);

/* Decodes parts first (the header) and first + 1 (the payload) with
 * proto_decode: first is 1 after a ROUTER's identity, else 0. -1 with a
 * message when those parts are not there. */
int proto_frames_decode(proto_frames_t *fr, int first, proto_msg_t *msg, proto_records_t *recs,
                        char *err, size_t errlen);

/* Sends n parts as one message: each with flags, all but the last with
 * ZMQ_SNDMORE (the last one too when flags has it, for parts the caller
 * sends after). Stops at the first part that fails: 0, or -1 with errno. A
 * NULL part of size 0 is an empty part. */
int proto_send(void *sock, const void *const *parts, const size_t *sizes, size_t n, int flags);

#endif
