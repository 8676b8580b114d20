/* handshake.c - see handshake.h. */
#include "handshake.h"

#include <errno.h>
#include <sodium.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <zmq.h>

#include "frames.h"

#define WATCHED                                                                                    \
    (ZMQ_EVENT_HANDSHAKE_SUCCEEDED | ZMQ_EVENT_HANDSHAKE_FAILED_AUTH |                             \
     ZMQ_EVENT_HANDSHAKE_FAILED_PROTOCOL | ZMQ_EVENT_HANDSHAKE_FAILED_NO_DETAIL |                  \
     ZMQ_EVENT_DISCONNECTED)

struct handshake_monitor {
    void *watched;
    void *pair; /* receives the events */
};

handshake_monitor_t *handshake_monitor_new(void *zmq_ctx, void *sock, char *err, size_t errlen)
{
    handshake_monitor_t *h = calloc(1, sizeof *h);
    if (!h) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    /* a random name: a closed monitor's inproc name is released later, by
     * ZeroMQ's reaper, so the socket's address alone could still be taken */
    if (sodium_init() < 0) {
        snprintf(err, errlen, "libsodium failed to initialise");
        free(h);
        return NULL;
    }
    char ep[96];
    snprintf(ep, sizeof ep, "inproc://vb-handshake-%p-%08x%08x", sock, randombytes_random(),
             randombytes_random());
    int zero = 0;
    if (zmq_socket_monitor(sock, ep, WATCHED) < 0) {
        snprintf(err, errlen, "cannot monitor a socket: %s", zmq_strerror(errno));
        free(h);
        return NULL;
    }
    h->watched = sock;
    h->pair = zmq_socket(zmq_ctx, ZMQ_PAIR);
    if (!h->pair || zmq_setsockopt(h->pair, ZMQ_LINGER, &zero, sizeof zero) < 0 ||
        zmq_connect(h->pair, ep) < 0) {
        snprintf(err, errlen, "cannot watch a socket's handshakes: %s", zmq_strerror(errno));
        handshake_monitor_destroy(&h);
        return NULL;
    }
    return h;
}

void handshake_monitor_destroy(handshake_monitor_t **hp)
{
    if (!hp || !*hp)
        return;
    handshake_monitor_t *h = *hp;
    zmq_socket_monitor(h->watched, NULL, 0);
    if (h->pair)
        zmq_close(h->pair);
    free(h);
    *hp = NULL;
}

void *handshake_monitor_socket(handshake_monitor_t *h)
{
    return h->pair;
}

/* Where the keys come from: the client also reads them from the
 * environment, which a user may not think of. */
static const char *key_options(const char *who)
{
    return strcmp(who, "client") == 0
               ? "--key and --master-key, or VBRENDER_KEY and VBRENDER_MASTER_KEY"
               : "--key and --master-key";
}

handshake_result_t handshake_describe(uint16_t event, uint32_t value, const char *ep,
                                      const char *who, int curve, char *msg, size_t msglen)
{
    switch (event) {
    case ZMQ_EVENT_HANDSHAKE_SUCCEEDED:
        snprintf(msg, msglen, "handshake with %s succeeded", ep);
        return HANDSHAKE_OK;
    case ZMQ_EVENT_HANDSHAKE_FAILED_AUTH:
        if (value == 400)
            snprintf(msg, msglen, "the master at %s refused this %s's key (not in its allow-list)",
                     ep, who);
        else
            snprintf(msg, msglen, "the master at %s refused this %s's key (ZAP status %u%s)", ep,
                     who, value,
                     value == 300   ? ": a temporary failure"
                     : value == 500 ? ": the master's ZAP handler failed"
                                    : "");
        return HANDSHAKE_REFUSED;
    case ZMQ_EVENT_HANDSHAKE_FAILED_PROTOCOL:
        if (value == ZMQ_PROTOCOL_ERROR_ZMTP_MECHANISM_MISMATCH) {
            if (curve)
                snprintf(
                    msg, msglen,
                    "handshake with %s failed: the master does not use CURVE keys, this %s does "
                    "(drop %s)",
                    ep, who, key_options(who));
            else
                snprintf(msg, msglen,
                         "handshake with %s failed: the master requires CURVE keys (give this %s "
                         "%s)",
                         ep, who, key_options(who));
            return HANDSHAKE_MISMATCH;
        }
        snprintf(msg, msglen, "handshake with %s failed: ZMTP protocol error 0x%08x%s", ep, value,
                 value == ZMQ_PROTOCOL_ERROR_ZMTP_CRYPTOGRAPHIC ? " (cryptographic: wrong keys?)"
                                                                : "");
        return HANDSHAKE_PROTOCOL;
    case ZMQ_EVENT_HANDSHAKE_FAILED_NO_DETAIL:
        /* a wrong server key shows only this way: the master cannot decrypt
         * our HELLO and closes without a word */
        if (curve)
            snprintf(msg, msglen,
                     "handshake with %s failed: the master closed the connection during the CURVE "
                     "handshake (%s); wrong master key? --master-key must be that master's .pub",
                     ep, strerror((int)value));
        else
            snprintf(
                msg, msglen,
                "handshake with %s failed: the peer closed the connection during the handshake "
                "(%s): a master that requires CURVE keys (give this %s %s), or not a vbrender "
                "master?",
                ep, strerror((int)value), who, key_options(who));
        return HANDSHAKE_CLOSED;
    case ZMQ_EVENT_DISCONNECTED:
        snprintf(msg, msglen, "the connection to %s was lost", ep);
        return HANDSHAKE_LOST;
    default:
        return HANDSHAKE_NONE;
    }
}

handshake_result_t handshake_monitor_read(handshake_monitor_t *h, const char *endpoint,
                                          const char *who, int curve, char *msg, size_t msglen)
{
    /* two frames: 6 bytes (u16 event, u32 value, native order), the endpoint */
    proto_frames_t fr;
    if (proto_recv(h->pair, &fr, 2, SIZE_MAX, ZMQ_DONTWAIT) == PROTO_RECV_NONE)
        return HANDSHAKE_NONE;
    handshake_result_t r = HANDSHAKE_NONE;
    zmq_msg_t *a = &fr.part[0];
    if (zmq_msg_size(a) == 6) {
        uint16_t event;
        uint32_t value;
        memcpy(&event, zmq_msg_data(a), 2);
        memcpy(&value, (const uint8_t *)zmq_msg_data(a) + 2, 4);
        r = handshake_describe(event, value, endpoint, who, curve, msg, msglen);
    }
    proto_frames_close(&fr);
    return r;
}
