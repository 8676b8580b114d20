/* handshake.h - why a connection to the master failed its handshake, in
 * words, from ZeroMQ's socket monitor (zmq_socket_monitor).
 *
 * Without it a refused key shows only as silence: ZeroMQ drops the
 * connection and a REQ socket waits out its timeout. What libzmq 4.3 reports
 * on the connecting side:
 *
 *   key not in the master's allow-list   HANDSHAKE_FAILED_AUTH, value 400
 *                                        (the ZAP status code); no reconnect
 *   wrong master public key              HANDSHAKE_FAILED_NO_DETAIL (errno of
 *                                        the closed connection), again on every
 *                                        reconnect: the master cannot decrypt
 *                                        the HELLO and closes without a word,
 *                                        so this side cannot tell it from a
 *                                        connection lost mid-handshake
 *   CURVE on one side only               HANDSHAKE_FAILED_PROTOCOL, value
 *                                        ZMQ_PROTOCOL_ERROR_ZMTP_MECHANISM_MISMATCH;
 *                                        no reconnect
 *
 * Used by the client (control.c) and the worker, one monitor per socket.
 */
#ifndef VB_HANDSHAKE_H
#define VB_HANDSHAKE_H

#include <stddef.h>
#include <stdint.h>

typedef struct handshake_monitor handshake_monitor_t;

typedef enum {
    HANDSHAKE_NONE = 0, /* no event, or one that says nothing about the handshake */
    HANDSHAKE_OK,       /* HANDSHAKE_SUCCEEDED */
    HANDSHAKE_REFUSED,  /* the master's ZAP handler refused the key */
    HANDSHAKE_MISMATCH, /* one side uses CURVE, the other does not */
    HANDSHAKE_CLOSED,   /* closed during the handshake, no reason given */
    HANDSHAKE_PROTOCOL, /* another protocol error */
    HANDSHAKE_LOST      /* DISCONNECTED: a connection (after a handshake or during one) closed */
} handshake_result_t;

/* Watches sock's handshakes (sock: the caller's, not yet connected, so no
 * event is missed). NULL with a message. */
handshake_monitor_t *handshake_monitor_new(void *zmq_ctx, void *sock, char *err, size_t errlen);

/* Stops watching; before the watched socket is closed. */
void handshake_monitor_destroy(handshake_monitor_t **h);

/* The socket to poll for events (ZMQ_POLLIN). */
void *handshake_monitor_socket(handshake_monitor_t *h);

/* Reads one pending event without waiting: HANDSHAKE_NONE when there is
 * none (or it is of no interest). A failure's description goes to msg:
 * what failed at endpoint and the likely cause; who ("client", "worker")
 * and curve (whether this side uses CURVE) shape the words. */
handshake_result_t handshake_monitor_read(handshake_monitor_t *h, const char *endpoint,
                                          const char *who, int curve, char *msg, size_t msglen);

/* The words alone, for an event already read: event and value as the
 * monitor gives them. */
handshake_result_t handshake_describe(uint16_t event, uint32_t value, const char *endpoint,
                                      const char *who, int curve, char *msg, size_t msglen);

#endif
