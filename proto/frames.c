/* frames.c - see frames.h. */
#include "frames.h"

#include <errno.h>
#include <stdint.h>
#include <stdio.h>

proto_recv_result_t proto_recv(void *sock, proto_frames_t *fr, int max_parts, size_t max_bytes,
                               int flags)
{
    fr->count = 0;
    fr->dropped = 0;
    fr->bytes = 0;
    if (max_parts < 1 || max_parts > PROTO_FRAMES_MAX)
        max_parts = PROTO_FRAMES_MAX;
    int more = 1;
    while (more) {
        zmq_msg_t f;
        zmq_msg_init(&f);
        if (zmq_msg_recv(&f, sock, flags) < 0) {
            int e = errno;
            zmq_msg_close(&f);
            errno = e;
            break;
        }
        more = zmq_msg_more(&f);
        size_t size = zmq_msg_size(&f);
        fr->bytes = size > SIZE_MAX - fr->bytes ? SIZE_MAX : fr->bytes + size;
        if (fr->count < max_parts) {
            fr->part[fr->count++] = f;
        } else {
            zmq_msg_close(&f);
            fr->dropped++;
        }
    }
    if (fr->count == 0)
        return PROTO_RECV_NONE;
    if (fr->dropped > 0)
        return PROTO_RECV_TOO_MANY;
    if (fr->bytes > max_bytes)
        return PROTO_RECV_TOO_BIG;
    return PROTO_RECV_OK;
}

void proto_frames_close(proto_frames_t *fr)
{
    for (int i = 0; i < fr->count; i++)
        zmq_msg_close(&fr->part[i]);
    fr->count = 0;
}

int proto_frames_decode(proto_frames_t *fr, int first, proto_msg_t *msg, proto_records_t *recs,
                        char *err, size_t errlen)
{
    if (first < 0 || first + 2 > fr->count) {
        snprintf(err, errlen, "%d frames, no header and payload at frame %d", fr->count, first);
        return -1;
    }
    zmq_msg_t *h = &fr->part[first], *p = &fr->part[first + 1];
    return proto_decode(zmq_msg_data(h), zmq_msg_size(h), zmq_msg_data(p), zmq_msg_size(p), msg,
                        recs, err, errlen);
}

int proto_send(void *sock, const void *const *parts, const size_t *sizes, size_t n, int flags)
{
    for (size_t i = 0; i < n; i++) {
        int more = i + 1 < n ? ZMQ_SNDMORE : 0;
        /* "" for an empty part: zmq_send's buffer is not NULL even at size 0 */
        const void *data = parts[i] ? parts[i] : "";
        if (zmq_send(sock, data, sizes[i], flags | more) < 0)
            return -1;
    }
    return 0;
}
