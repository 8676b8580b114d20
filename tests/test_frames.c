/* test_frames.c - multi-part messages (proto/frames.c) over an inproc pair:
 * every part received in one call, parts past the limit received and
 * dropped so the next message starts clean, a total over the byte limit
 * flagged with its parts kept, nothing waiting reported as such, empty
 * parts sent, and a ROUTER-style [identity][header][payload] decoded from
 * its second part. */
#include <check.h>
#include <errno.h>
#include <stdint.h>
#include <string.h>
#include <zmq.h>

#include "frames.h"
#include "proto.h"

typedef struct pair {
    void *ctx, *a, *b;
} pair_t;

static pair_t pair_open(const char *name)
{
    char ep[64];
    snprintf(ep, sizeof ep, "inproc://test-frames-%s", name);
    pair_t p = {zmq_ctx_new(), NULL, NULL};
    p.a = zmq_socket(p.ctx, ZMQ_PAIR);
    p.b = zmq_socket(p.ctx, ZMQ_PAIR);
    ck_assert_int_eq(zmq_bind(p.a, ep), 0);
    ck_assert_int_eq(zmq_connect(p.b, ep), 0);
    return p;
}

static void pair_close(pair_t *p)
{
    zmq_close(p->a);
    zmq_close(p->b);
    zmq_ctx_term(p->ctx);
}

static void send3(void *sock, const char *x, const char *y, const char *z)
{
    const void *parts[3] = {x, y, z};
    const size_t sizes[3] = {strlen(x), strlen(y), strlen(z)};
    ck_assert_int_eq(proto_send(sock, parts, sizes, 3, 0), 0);
}

START_TEST(recv_whole_message)
{
    pair_t p = pair_open("whole");
    proto_frames_t fr;
    ck_assert_int_eq(proto_recv(p.b, &fr, 3, SIZE_MAX, ZMQ_DONTWAIT), PROTO_RECV_NONE);
    ck_assert_int_eq(errno, EAGAIN);
    ck_assert_int_eq(fr.count, 0);
    send3(p.a, "id", "", "body");
    ck_assert_int_eq(proto_recv(p.b, &fr, 3, SIZE_MAX, 0), PROTO_RECV_OK);
    ck_assert_int_eq(fr.count, 3);
    ck_assert_int_eq(fr.dropped, 0);
    ck_assert_uint_eq(fr.bytes, 6);
    ck_assert_uint_eq(zmq_msg_size(&fr.part[1]), 0); /* the empty part */
    ck_assert(memcmp(zmq_msg_data(&fr.part[2]), "body", 4) == 0);
    proto_frames_close(&fr);
    ck_assert_int_eq(fr.count, 0);
    pair_close(&p);
}
END_TEST

START_TEST(recv_limits)
{
    pair_t p = pair_open("limits");
    proto_frames_t fr;
    /* too many parts: the first kept, the rest received and dropped */
    send3(p.a, "a", "b", "c");
    send3(p.a, "next", "x", "y");
    ck_assert_int_eq(proto_recv(p.b, &fr, 2, SIZE_MAX, 0), PROTO_RECV_TOO_MANY);
    ck_assert_int_eq(fr.count, 2);
    ck_assert_int_eq(fr.dropped, 1);
    ck_assert_uint_eq(fr.bytes, 3);
    proto_frames_close(&fr);
    /* the next message starts at its own first part */
    ck_assert_int_eq(proto_recv(p.b, &fr, 3, 5, 0), PROTO_RECV_TOO_BIG);
    ck_assert_int_eq(fr.count, 3); /* kept: the caller may answer its sender */
    ck_assert(memcmp(zmq_msg_data(&fr.part[0]), "next", 4) == 0);
    ck_assert_uint_eq(fr.bytes, 6);
    proto_frames_close(&fr);
    pair_close(&p);
}
END_TEST

START_TEST(send_more_and_decode)
{
    pair_t p = pair_open("decode");
    proto_msg_t msg = {.h = {.type = PROTO_BYE, .job = 7}, .u.text.text = "bye"};
    uint8_t header[PROTO_HEADER_SIZE], payload[16];
    char err[256];
    long n = proto_encode(&msg, header, payload, sizeof payload, err, sizeof err);
    ck_assert_int_eq(n, 7);
    /* an identity, then header and payload in a second call */
    const void *id[1] = {"worker-1"};
    const size_t id_size[1] = {8};
    ck_assert_int_eq(proto_send(p.a, id, id_size, 1, ZMQ_SNDMORE), 0);
    const void *parts[2] = {header, payload};
    const size_t sizes[2] = {PROTO_HEADER_SIZE, (size_t)n};
    ck_assert_int_eq(proto_send(p.a, parts, sizes, 2, 0), 0);

    proto_frames_t fr;
    ck_assert_int_eq(proto_recv(p.b, &fr, 3, SIZE_MAX, 0), PROTO_RECV_OK);
    ck_assert_int_eq(fr.count, 3);
    proto_msg_t got;
    proto_records_t recs = {0};
    ck_assert_int_eq(proto_frames_decode(&fr, 1, &got, &recs, err, sizeof err), 0);
    ck_assert_uint_eq(got.h.type, PROTO_BYE);
    ck_assert_uint_eq(got.h.job, 7);
    ck_assert_str_eq(got.u.text.text, "bye");
    ck_assert_ptr_eq(got.u.text.text, recs.text);
    /* no payload after the header at part 2 */
    ck_assert_int_eq(proto_frames_decode(&fr, 2, &got, &recs, err, sizeof err), -1);
    ck_assert(strstr(err, "3 frames") != NULL);
    proto_frames_close(&fr);
    pair_close(&p);
}
END_TEST

static Suite *frames_suite(void)
{
    Suite *s = suite_create("frames");
    TCase *tc = tcase_create("frames");
    tcase_add_test(tc, recv_whole_message);
    tcase_add_test(tc, recv_limits);
    tcase_add_test(tc, send_more_and_decode);
    suite_add_tcase(s, tc);
    return s;
}

int main(void)
{
    SRunner *sr = srunner_create(frames_suite());
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed ? 1 : 0;
}
