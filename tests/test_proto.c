/* test_proto.c - the wire protocol (proto/proto.c) against its golden
 * vectors and its limits.
 *
 * The vectors in proto/vectors/ were written by an independent generator
 * (proto/vectors/gen-vectors.py, Python's struct module), and the values
 * each one must decode to are spelled out here again, not derived from the
 * encoder: a byte-order or offset slip on either side fails. Re-encoding a
 * decoded vector must give back its exact bytes. Beyond the vectors: round
 * trips at every edge value, every truncation of the larger payloads, every
 * single-byte change of every vector, and random frames, none of which may
 * crash, and each of which must be refused or decode to something that
 * re-encodes to the same bytes (one message, one encoding).
 */
#include <check.h>
#include <float.h>
#include <math.h>
#include <sodium.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "proto.h"
#include "testutil.h"

#define VEC_CAP 16 /* record capacity used when decoding the vectors */

/* ---- fixtures -------------------------------------------------------- */

typedef struct vec {
    uint8_t *h, *p;
    size_t hn, pn;
} vec_t;

static int hexval(int c)
{
    if (c >= '0' && c <= '9')
        return c - '0';
    if (c >= 'a' && c <= 'f')
        return c - 'a' + 10;
    if (c >= 'A' && c <= 'F')
        return c - 'A' + 10;
    return -1;
}

/* One frame from one line of hex (spaces ignored, "-" = empty). */
static uint8_t *parse_hex_line(const char *line, size_t *n)
{
    size_t len = strlen(line);
    uint8_t *out = malloc(len / 2 + 1);
    ck_assert_ptr_nonnull(out);
    size_t k = 0;
    int hi = -1;
    if (strcmp(line, "-") == 0) {
        *n = 0;
        return out;
    }
    for (size_t i = 0; i < len; i++) {
        if (line[i] == ' ' || line[i] == '\t' || line[i] == '\r')
            continue;
        int v = hexval((unsigned char)line[i]);
        ck_assert_msg(v >= 0, "bad hex character '%c'", line[i]);
        if (hi < 0) {
            hi = v;
        } else {
            out[k++] = (uint8_t)(hi << 4 | v);
            hi = -1;
        }
    }
    ck_assert_msg(hi < 0, "odd number of hex digits");
    *n = k;
    return out;
}

static vec_t load_vec(const char *name)
{
    char rel[256], path[4096];
    snprintf(rel, sizeof rel, "proto/vectors/%s", name);
    tu_root_path(path, sizeof path, rel);
    FILE *f = fopen(path, "rb");
    ck_assert_msg(f != NULL, "cannot open %s", path);
    vec_t v = {NULL, NULL, 0, 0};
    static char line[1 << 16];
    int frames = 0;
    while (fgets(line, sizeof line, f)) {
        size_t len = strlen(line);
        while (len && (line[len - 1] == '\n' || line[len - 1] == '\r'))
            line[--len] = '\0';
        if (len == 0 || line[0] == '#')
            continue;
        ck_assert_msg(frames < 2, "%s: more than two frames", name);
        if (frames++ == 0)
            v.h = parse_hex_line(line, &v.hn);
        else
            v.p = parse_hex_line(line, &v.pn);
    }
    fclose(f);
    ck_assert_msg(frames == 2, "%s: %d frames, expected 2", name, frames);
    return v;
}

static void free_vec(vec_t *v)
{
    free(v->h);
    free(v->p);
}

/* A message and buffers ready to receive anything. */
typedef struct rx {
    proto_msg_t m;
    proto_records_t recs;
    tracer_task_t *tasks;
    tracer_result_t *results;
    proto_mesh_file_t meshes[PROTO_MAX_MESHES];
} rx_t;

static rx_t *rx_new(uint32_t capacity)
{
    rx_t *r = calloc(1, sizeof *r);
    ck_assert_ptr_nonnull(r);
    r->tasks = calloc(capacity ? capacity : 1, sizeof *r->tasks);
    r->results = calloc(capacity ? capacity : 1, sizeof *r->results);
    ck_assert(r->tasks && r->results);
    return r;
}

static void rx_reset(rx_t *r, uint32_t capacity)
{
    /* garbage in the message: the decoder must not trust any of it */
    memset(&r->m, 0xa5, sizeof r->m);
    memset(&r->recs, 0, sizeof r->recs);
    r->recs.tasks = r->tasks;
    r->recs.task_capacity = capacity;
    r->recs.results = r->results;
    r->recs.result_capacity = capacity;
    r->recs.meshes = r->meshes;
    r->recs.mesh_capacity = PROTO_MAX_MESHES;
}

static void rx_free(rx_t *r)
{
    free(r->tasks);
    free(r->results);
    free(r);
}

static int decode(rx_t *r, uint32_t capacity, const uint8_t *h, size_t hn, const uint8_t *p,
                  size_t pn, char *err, size_t errlen)
{
    rx_reset(r, capacity);
    err[0] = '\0';
    return proto_decode(h, hn, p, pn, &r->m, &r->recs, err, errlen);
}

/* Encodes msg and checks it gives exactly h and p. */
static void expect_encodes_to(const proto_msg_t *m, const uint8_t *h, size_t hn, const uint8_t *p,
                              size_t pn)
{
    uint8_t hdr[PROTO_HEADER_SIZE];
    uint8_t *buf = malloc(pn ? pn : 1);
    char err[256] = "";
    ck_assert_ptr_nonnull(buf);
    ck_assert_uint_eq(hn, PROTO_HEADER_SIZE);
    ck_assert_uint_eq(proto_payload_size(m), pn);
    long n = proto_encode(m, hdr, buf, pn, err, sizeof err);
    ck_assert_msg(n == (long)pn, "encode gave %ld (%s), expected %zu", n, err, pn);
    ck_assert(memcmp(hdr, h, PROTO_HEADER_SIZE) == 0);
    ck_assert(pn == 0 || memcmp(buf, p, pn) == 0);
    free(buf);
}

/* Decodes a valid vector and re-encodes it to its own bytes. */
static rx_t *decode_valid(const char *name, vec_t *v)
{
    char err[256];
    *v = load_vec(name);
    rx_t *r = rx_new(VEC_CAP);
    int rc = decode(r, VEC_CAP, v->h, v->hn, v->p, v->pn, err, sizeof err);
    ck_assert_msg(rc == 0, "%s: decode returned %d: %s", name, rc, err);
    ck_assert_uint_eq(r->m.h.version, PROTO_VERSION);
    ck_assert_uint_eq(r->m.h.payload_size, v->pn);
    expect_encodes_to(&r->m, v->h, v->hn, v->p, v->pn);
    return r;
}

static void expect_header(const proto_msg_t *m, uint16_t type, uint64_t job, uint64_t task,
                          uint32_t attempt, uint32_t payload_size)
{
    ck_assert_uint_eq(m->h.type, type);
    ck_assert_uint_eq(m->h.job, job);
    ck_assert_uint_eq(m->h.task, task);
    ck_assert_uint_eq(m->h.attempt, attempt);
    ck_assert_uint_eq(m->h.payload_size, payload_size);
}

static void expect_seq_hash(const uint8_t *hash, uint8_t first)
{
    for (int i = 0; i < PROTO_HASH_SIZE; i++)
        ck_assert_uint_eq(hash[i], (uint8_t)(first + i));
}

/* Bit-exact double comparison: -0.0 and 0.0 differ on the wire. */
static void expect_f64(double got, double want)
{
    ck_assert_msg(memcmp(&got, &want, sizeof got) == 0, "got %.17g, expected %.17g", got, want);
}

#define JOB UINT64_C(0x1122334455667788)

/* ---- valid vectors ---------------------------------------------------- */

START_TEST(vec_hello)
{
    vec_t v;
    rx_t *r = decode_valid("hello.hex", &v);
    expect_header(&r->m, PROTO_HELLO, 0, 0, 0, 36);
    ck_assert_uint_eq(r->m.u.hello.threads, 16);
    ck_assert_str_eq(r->m.u.hello.build, "vbrender-p2-t2-avx2-gcc12.2");
    rx_free(r);
    free_vec(&v);
}
END_TEST

START_TEST(vec_welcome)
{
    vec_t v;
    rx_t *r = decode_valid("welcome.hex", &v);
    expect_header(&r->m, PROTO_WELCOME, 0, 0, 0, 8);
    ck_assert_uint_eq(r->m.u.welcome.heartbeat_ms, 1000);
    ck_assert_uint_eq(r->m.u.welcome.lease_ms, 30000);
    rx_free(r);
    free_vec(&v);
}
END_TEST

START_TEST(vec_refuse)
{
    vec_t v;
    rx_t *r = decode_valid("refuse.hex", &v);
    const char *want = "build differs: vbrender-p2-t2-sse4.2-gcc12.2";
    expect_header(&r->m, PROTO_REFUSE, 0, 0, 0, (uint32_t)(4 + strlen(want)));
    ck_assert_str_eq(r->m.u.text.text, want);
    rx_free(r);
    free_vec(&v);
}
END_TEST

START_TEST(vec_credit)
{
    vec_t v;
    rx_t *r = decode_valid("credit.hex", &v);
    expect_header(&r->m, PROTO_CREDIT, 0, 0, 0, 4);
    ck_assert_uint_eq(r->m.u.credit, 8);
    rx_free(r);
    free_vec(&v);
}
END_TEST

START_TEST(vec_scene_request)
{
    vec_t v;
    rx_t *r = decode_valid("scene_request.hex", &v);
    expect_header(&r->m, PROTO_SCENE_REQUEST, 0, 0, 0, 32);
    expect_seq_hash(r->m.u.scene_hash, 0x00);
    rx_free(r);
    free_vec(&v);
}
END_TEST

START_TEST(vec_scene_bundle)
{
    vec_t v;
    rx_t *r = decode_valid("scene_bundle.hex", &v);
    const char *json = "{\"meshes\":[\"quad.obj\"]}";
    /* 40 head + 23 json + (2 + 8 + 4 + 8) + (2 + 9 + 4 + 0) */
    expect_header(&r->m, PROTO_SCENE_BUNDLE, 0, 0, 0, 100);
    const proto_bundle_t *b = &r->m.u.bundle;
    expect_seq_hash(b->hash, 0x20);
    ck_assert_uint_eq(b->json_size, 23);
    ck_assert(memcmp(b->json, json, 23) == 0);
    /* zero copy: the pointers lie in the payload frame */
    ck_assert_ptr_eq(b->json, (const char *)v.p + 40);
    ck_assert_uint_eq(b->mesh_count, 2);
    ck_assert_str_eq(b->meshes[0].name, "quad.obj");
    ck_assert_uint_eq(b->meshes[0].size, 8);
    ck_assert(memcmp(b->meshes[0].data, "v 0 0 0\n", 8) == 0);
    ck_assert_ptr_eq(b->meshes[0].data, v.p + 40 + 23 + 2 + 8 + 4);
    ck_assert_str_eq(b->meshes[1].name, "empty.ply");
    ck_assert_uint_eq(b->meshes[1].size, 0);
    rx_free(r);
    free_vec(&v);
}
END_TEST

START_TEST(vec_task)
{
    vec_t v;
    rx_t *r = decode_valid("task.hex", &v);
    expect_header(&r->m, PROTO_TASK, JOB, 42, 3, 56 + 2 * 48);
    const proto_task_t *t = &r->m.u.task;
    expect_seq_hash(t->scene_hash, 0x00);
    ck_assert_uint_eq(t->settings.seed, UINT64_C(0xDEADBEEFCAFEF00D));
    ck_assert_int_eq(t->settings.integrator, SCENE_INTEGRATOR_NAIVE);
    ck_assert_int_eq(t->settings.sampler, RNG_SAMPLER_SOBOL);
    ck_assert_uint_eq(t->settings.max_depth, 8);
    ck_assert_uint_eq(t->layer, 5);
    ck_assert_uint_eq(t->count, 2);
    ck_assert_ptr_eq(t->records, r->tasks);
    const tracer_task_t *a = &t->records[0], *b = &t->records[1];
    ck_assert_uint_eq(a->pixel, 7);
    ck_assert_uint_eq(a->sample_count, 16);
    ck_assert_uint_eq(a->first_sample, 80);
    ck_assert_uint_eq(a->prior_count, 80);
    expect_f64(a->prior_sum[0], 1.5);
    expect_f64(a->prior_sum[1], 0.25);
    expect_f64(a->prior_sum[2], 0.0);
    ck_assert_uint_eq(b->pixel, 1000000);
    ck_assert_uint_eq(b->sample_count, 4096);
    ck_assert_uint_eq(b->first_sample, UINT64_C(1) << 32);
    ck_assert_uint_eq(b->prior_count, 3);
    expect_f64(b->prior_sum[0], 0.1);
    expect_f64(b->prior_sum[1], 2.0);
    expect_f64(b->prior_sum[2], 1e300);
    rx_free(r);
    free_vec(&v);
}
END_TEST

START_TEST(vec_result)
{
    vec_t v;
    rx_t *r = decode_valid("result.hex", &v);
    expect_header(&r->m, PROTO_RESULT, JOB, 42, 3, 24 + 2 * 56);
    const proto_result_t *res = &r->m.u.result;
    ck_assert_uint_eq(res->rays, UINT64_C(123456789012));
    ck_assert_uint_eq(res->busy_us, 250000);
    ck_assert_uint_eq(res->count, 2);
    ck_assert_ptr_eq(res->records, r->results);
    const tracer_result_t *a = &res->records[0], *b = &res->records[1];
    ck_assert_uint_eq(a->pixel, 7);
    ck_assert_uint_eq(a->samples, 15);
    ck_assert_uint_eq(a->nonfinite, 1);
    ck_assert_uint_eq(a->rays, 83);
    expect_f64(a->sum[0], 3.0);
    expect_f64(a->sum[1], 0.5);
    expect_f64(a->sum[2], 0.125);
    expect_f64(a->lum_m2, 0.75);
    expect_f64(a->pvar, 0.01);
    ck_assert_uint_eq(b->pixel, 1000000);
    ck_assert_uint_eq(b->samples, 4096);
    ck_assert_uint_eq(b->nonfinite, 0);
    ck_assert_uint_eq(b->rays, UINT32_MAX); /* saturated */
    expect_f64(b->sum[0], 5e-324);          /* the smallest subnormal */
    expect_f64(b->sum[1], 4096.0);
    expect_f64(b->sum[2], 0.0);
    expect_f64(b->lum_m2, 0.0);
    expect_f64(b->pvar, 0.0);
    rx_free(r);
    free_vec(&v);
}
END_TEST

START_TEST(vec_heartbeat)
{
    vec_t v;
    rx_t *r = decode_valid("heartbeat.hex", &v);
    expect_header(&r->m, PROTO_HEARTBEAT, 0, 0, 0, 0);
    ck_assert_uint_eq(v.pn, 0);
    rx_free(r);
    free_vec(&v);
}
END_TEST

START_TEST(vec_bye)
{
    vec_t v;
    rx_t *r = decode_valid("bye.hex", &v);
    expect_header(&r->m, PROTO_BYE, 0, 0, 0, 24);
    ck_assert_str_eq(r->m.u.text.text, "worker shutting down");
    rx_free(r);
    free_vec(&v);
}
END_TEST

START_TEST(vec_task_failed)
{
    vec_t v;
    rx_t *r = decode_valid("task_failed.hex", &v);
    const char *want = "scene: mesh quad.obj: bad vertex";
    expect_header(&r->m, PROTO_TASK_FAILED, JOB, 42, 3, (uint32_t)(4 + strlen(want)));
    ck_assert_str_eq(r->m.u.text.text, want);
    rx_free(r);
    free_vec(&v);
}
END_TEST

/* ---- invalid vectors -------------------------------------------------- */

static const struct {
    const char *file;
    int rc;
    const char *msg; /* must appear in the error */
} invalid_vectors[] = {
    {"bad_magic.hex", -1, "header: bad magic 0x50524257"},
    {"wrong_version.hex", -2, "peer speaks protocol version 1, this build speaks 2"},
    {"unknown_type.hex", -1, "unknown message type 12"},
    {"short_header.hex", -1, "header: 31 bytes"},
    {"size_mismatch.hex", -1, "payload_size 8 but the payload frame has 4 bytes"},
    {"credit_zero.hex", -1, "CREDIT: credit 0 out of range"},
    {"hello_bad_build.hex", -1, "HELLO: build id byte 8 is 0x07"},
    {"text_with_nul.hex", -1, "BYE: text byte 1 is NUL"},
    {"count_over_limit.hex", -1, "TASK: count 70000 exceeds 65536"},
    {"truncated_record.hex", -1, "TASK: payload is 128 bytes, 2 records need 152"},
    {"bad_integrator.hex", -1, "TASK: integrator 3 is not 0 (path)"},
    {"reserved_set.hex", -1, "TASK: reserved byte 1 is 0x01"},
    {"bad_sampler.hex", -1, "TASK: sampler 2 is neither"},
    {"task_zero_samples.hex", -1, "TASK: record 0: sample_count 0 out of range"},
    {"task_inf_prior.hex", -1, "TASK: record 0: prior_sum[0] is infinite"},
    {"nan_in_record.hex", -1, "RESULT: record 1: pvar is NaN"},
    {"result_negative.hex", -1, "RESULT: record 0: sum[2] is negative"},
    {"result_few_rays.hex", -1, "RESULT: record 0: rays 3 fewer than its 4 samples"},
    {"result_zero_samples.hex", -1, "RESULT: record 0: samples 0 + nonfinite 0 out of range"},
    {"duplicate_mesh_name.hex", -1, "mesh 1: duplicate name \"quad.obj\""},
    {"name_with_slash.hex", -1, "mesh 0: name contains '/'"},
    {"name_dotdot.hex", -1, "mesh 0: name \"..\" is not a file name"},
    {"bundle_trailing.hex", -1, "1 bytes left over after the last mesh"},
};

START_TEST(vec_invalid)
{
    char name[128], err[256];
    snprintf(name, sizeof name, "invalid/%s", invalid_vectors[_i].file);
    vec_t v = load_vec(name);
    rx_t *r = rx_new(VEC_CAP);
    int rc = decode(r, VEC_CAP, v.h, v.hn, v.p, v.pn, err, sizeof err);
    ck_assert_msg(rc == invalid_vectors[_i].rc, "%s: rc %d, expected %d (%s)", name, rc,
                  invalid_vectors[_i].rc, err);
    ck_assert_msg(strstr(err, invalid_vectors[_i].msg) != NULL, "%s: message \"%s\" lacks \"%s\"",
                  name, err, invalid_vectors[_i].msg);
    rx_free(r);
    free_vec(&v);
}
END_TEST

/* ---- round trips at the edges ----------------------------------------- */

/* Encodes m, checks the size, decodes into r; returns the payload (caller
 * frees) so bundle pointers stay valid. */
static uint8_t *round_trip(const proto_msg_t *m, rx_t *r, uint32_t capacity)
{
    uint8_t hdr[PROTO_HEADER_SIZE];
    size_t size = proto_payload_size(m);
    uint8_t *buf = malloc(size ? size : 1);
    char err[256] = "";
    ck_assert_ptr_nonnull(buf);
    long n = proto_encode(m, hdr, buf, size, err, sizeof err);
    ck_assert_msg(n == (long)size, "encode %s: %ld (%s)", proto_type_name(m->h.type), n, err);
    int rc = decode(r, capacity, hdr, sizeof hdr, buf, size, err, sizeof err);
    ck_assert_msg(rc == 0, "decode %s: %d (%s)", proto_type_name(m->h.type), rc, err);
    ck_assert_uint_eq(r->m.h.type, m->h.type);
    ck_assert_uint_eq(r->m.h.job, m->h.job);
    ck_assert_uint_eq(r->m.h.task, m->h.task);
    ck_assert_uint_eq(r->m.h.attempt, m->h.attempt);
    ck_assert_uint_eq(r->m.h.payload_size, size);
    /* one message, one encoding */
    expect_encodes_to(&r->m, hdr, sizeof hdr, buf, size);
    return buf;
}

static proto_msg_t *msg_new(uint16_t type)
{
    proto_msg_t *m = calloc(1, sizeof *m);
    ck_assert_ptr_nonnull(m);
    m->h.type = type;
    m->h.job = UINT64_MAX;
    m->h.task = UINT64_MAX - 1;
    m->h.attempt = UINT32_MAX;
    return m;
}

START_TEST(rt_hello)
{
    proto_msg_t *m = msg_new(PROTO_HELLO);
    rx_t *r = rx_new(1);
    const uint32_t threads[2] = {1, PROTO_MAX_THREADS};
    /* 32 characters: no NUL on the wire at all */
    const char *builds[3] = {"x", "0123456789abcdefghijklmnopqrstuv", " ~printable edges~ "};
    for (int i = 0; i < 2; i++)
        for (int k = 0; k < 3; k++) {
            m->u.hello.threads = threads[i];
            snprintf(m->u.hello.build, sizeof m->u.hello.build, "%s", builds[k]);
            free(round_trip(m, r, 1));
            ck_assert_uint_eq(r->m.u.hello.threads, threads[i]);
            ck_assert_str_eq(r->m.u.hello.build, builds[k]);
        }
    rx_free(r);
    free(m);
}
END_TEST

START_TEST(rt_welcome_credit_request_heartbeat)
{
    proto_msg_t *m = msg_new(PROTO_WELCOME);
    rx_t *r = rx_new(1);
    const uint32_t ms[2] = {1, 3600000};
    for (int i = 0; i < 2; i++) {
        m->u.welcome.heartbeat_ms = ms[i];
        m->u.welcome.lease_ms = ms[1 - i];
        free(round_trip(m, r, 1));
        ck_assert_uint_eq(r->m.u.welcome.heartbeat_ms, ms[i]);
        ck_assert_uint_eq(r->m.u.welcome.lease_ms, ms[1 - i]);
    }
    m->h.type = PROTO_CREDIT;
    const uint32_t credits[2] = {1, PROTO_MAX_CREDIT};
    for (int i = 0; i < 2; i++) {
        m->u.credit = credits[i];
        free(round_trip(m, r, 1));
        ck_assert_uint_eq(r->m.u.credit, credits[i]);
    }
    m->h.type = PROTO_SCENE_REQUEST;
    memset(m->u.scene_hash, 0xff, PROTO_HASH_SIZE);
    free(round_trip(m, r, 1));
    for (int i = 0; i < PROTO_HASH_SIZE; i++)
        ck_assert_uint_eq(r->m.u.scene_hash[i], 0xff);
    m->h.type = PROTO_HEARTBEAT;
    free(round_trip(m, r, 0));
    rx_free(r);
    free(m);
}
END_TEST

START_TEST(rt_text)
{
    const uint16_t types[3] = {PROTO_REFUSE, PROTO_BYE, PROTO_TASK_FAILED};
    proto_msg_t *m = msg_new(PROTO_REFUSE);
    rx_t *r = rx_new(1);
    char text[PROTO_TEXT_MAX + 1];
    m->u.text.text = text;
    for (int t = 0; t < 3; t++) {
        m->h.type = types[t];
        text[0] = '\0';
        free(round_trip(m, r, 1));
        ck_assert_str_eq(r->m.u.text.text, "");
        ck_assert_uint_eq(r->m.h.payload_size, 4);
        /* the longest text, with every non-NUL byte value (UTF-8 or not) */
        for (int i = 0; i < PROTO_TEXT_MAX; i++)
            text[i] = (char)(1 + i % 255);
        text[PROTO_TEXT_MAX] = '\0';
        free(round_trip(m, r, 1));
        ck_assert_uint_eq(r->m.h.payload_size, 4 + PROTO_TEXT_MAX);
        ck_assert(memcmp(r->m.u.text.text, text, PROTO_TEXT_MAX + 1) == 0);
    }
    rx_free(r);
    free(m);
}
END_TEST

START_TEST(rt_bundle_empty)
{
    proto_msg_t *m = msg_new(PROTO_SCENE_BUNDLE);
    rx_t *r = rx_new(1);
    memset(m->u.bundle.hash, 0xab, PROTO_HASH_SIZE);
    uint8_t *buf = round_trip(m, r, 1);
    ck_assert_uint_eq(r->m.h.payload_size, 40);
    ck_assert_uint_eq(r->m.u.bundle.json_size, 0);
    ck_assert_uint_eq(r->m.u.bundle.mesh_count, 0);
    ck_assert_uint_eq(r->m.u.bundle.hash[31], 0xab);
    free(buf);
    rx_free(r);
    free(m);
}
END_TEST

START_TEST(rt_bundle_max_meshes)
{
    proto_msg_t *m = msg_new(PROTO_SCENE_BUNDLE);
    rx_t *r = rx_new(1);
    static const char json[] = "{\"camera\":{}}";
    static const uint8_t data[3] = {0, 0xff, 7};
    static proto_mesh_file_t meshes[PROTO_MAX_MESHES];
    proto_bundle_t *b = &m->u.bundle;
    b->json = json;
    b->json_size = (uint32_t)strlen(json);
    b->mesh_count = PROTO_MAX_MESHES;
    b->meshes = meshes;
    for (uint32_t i = 0; i < PROTO_MAX_MESHES; i++) {
        /* the longest names, distinct only in their first characters */
        memset(meshes[i].name, 'n', PROTO_MAX_NAME);
        meshes[i].name[0] = (char)('0' + i / 10);
        meshes[i].name[1] = (char)('0' + i % 10);
        meshes[i].name[PROTO_MAX_NAME] = '\0';
        meshes[i].data = data;
        meshes[i].size = i % 4; /* 0..3 bytes; size 0 too */
        if (meshes[i].size == 0)
            meshes[i].data = NULL;
    }
    uint8_t *buf = round_trip(m, r, 1);
    const proto_bundle_t *d = &r->m.u.bundle;
    ck_assert_ptr_eq(d->meshes, r->meshes); /* the caller's buffer */
    ck_assert_uint_eq(d->mesh_count, PROTO_MAX_MESHES);
    ck_assert(memcmp(d->json, json, strlen(json)) == 0);
    for (uint32_t i = 0; i < PROTO_MAX_MESHES; i++) {
        ck_assert_str_eq(d->meshes[i].name, b->meshes[i].name);
        ck_assert_uint_eq(d->meshes[i].size, i % 4);
        ck_assert(d->meshes[i].data >= buf && d->meshes[i].data <= buf + r->m.h.payload_size);
        ck_assert(memcmp(d->meshes[i].data, data, d->meshes[i].size) == 0);
    }
    free(buf);
    rx_free(r);
    free(m);
}
END_TEST

START_TEST(rt_task_edges)
{
    proto_msg_t *m = msg_new(PROTO_TASK);
    const uint32_t n = PROTO_MAX_TASK_PIXELS;
    tracer_task_t *recs = calloc(n, sizeof *recs);
    rx_t *r = rx_new(n);
    ck_assert_ptr_nonnull(recs);
    memset(m->u.task.scene_hash, 0x5a, PROTO_HASH_SIZE);
    m->u.task.settings.seed = UINT64_MAX;
    m->u.task.settings.integrator = SCENE_INTEGRATOR_PATH;
    m->u.task.settings.sampler = RNG_SAMPLER_SOBOL;
    m->u.task.settings.max_depth = UINT32_MAX;
    m->u.task.layer = UINT32_MAX;
    m->u.task.records = recs;
    static const double sums[5] = {0.0, -0.0, 5e-324, DBL_MAX, 1.0};
    for (uint32_t i = 0; i < n; i++) {
        recs[i].pixel = UINT32_MAX - i;
        recs[i].sample_count = 1 + i % TRACER_MAX_TASK_SAMPLES;
        recs[i].first_sample = UINT64_MAX - recs[i].sample_count; /* the last range that fits */
        recs[i].prior_count = UINT64_MAX - i;
        for (int c = 0; c < 3; c++)
            recs[i].prior_sum[c] = sums[(i + (uint32_t)c) % 5];
    }
    const uint32_t counts[2] = {1, n};
    for (int k = 0; k < 2; k++) {
        m->u.task.count = counts[k];
        free(round_trip(m, r, counts[k])); /* capacity exactly the count */
        const proto_task_t *t = &r->m.u.task;
        ck_assert_uint_eq(t->count, counts[k]);
        ck_assert_uint_eq(t->settings.seed, UINT64_MAX);
        ck_assert_int_eq(t->settings.integrator, SCENE_INTEGRATOR_PATH);
        ck_assert_int_eq(t->settings.sampler, RNG_SAMPLER_SOBOL);
        ck_assert_uint_eq(t->settings.max_depth, UINT32_MAX);
        ck_assert_uint_eq(t->layer, UINT32_MAX);
        ck_assert_uint_eq(t->scene_hash[0], 0x5a);
        ck_assert(memcmp(t->records, recs, counts[k] * sizeof *recs) == 0);
    }
    rx_free(r);
    free(recs);
    free(m);
}
END_TEST

START_TEST(rt_result_edges)
{
    proto_msg_t *m = msg_new(PROTO_RESULT);
    const uint32_t n = PROTO_MAX_TASK_PIXELS;
    tracer_result_t *recs = calloc(n, sizeof *recs);
    rx_t *r = rx_new(n);
    ck_assert_ptr_nonnull(recs);
    m->u.result.rays = UINT64_MAX;
    m->u.result.busy_us = UINT64_MAX - 1;
    /* count 0: no records, no buffer needed on either side */
    m->u.result.count = 0;
    m->u.result.records = NULL;
    free(round_trip(m, r, 0));
    ck_assert_uint_eq(r->m.u.result.count, 0);
    ck_assert_uint_eq(r->m.h.payload_size, 24);
    ck_assert_uint_eq(r->m.u.result.rays, UINT64_MAX);
    ck_assert_uint_eq(r->m.u.result.busy_us, UINT64_MAX - 1);

    static const double vals[5] = {0.0, -0.0, 5e-324, DBL_MAX, 0.5};
    for (uint32_t i = 0; i < n; i++) {
        recs[i].pixel = i * 7919u;
        recs[i].samples = i % (TRACER_MAX_TASK_SAMPLES + 1);
        recs[i].nonfinite = TRACER_MAX_TASK_SAMPLES - recs[i].samples; /* sum: the most */
        if (recs[i].samples == TRACER_MAX_TASK_SAMPLES)
            recs[i].nonfinite = 0;
        if (i % 3 == 0 && recs[i].samples > 0)
            recs[i].nonfinite = 0;
        for (int c = 0; c < 3; c++)
            recs[i].sum[c] = vals[(i + (uint32_t)c) % 5];
        recs[i].lum_m2 = vals[(i + 3) % 5];
        recs[i].pvar = vals[(i + 4) % 5];
        recs[i].rays = i % 2 ? UINT32_MAX - i : recs[i].samples + recs[i].nonfinite;
    }
    m->u.result.records = recs;
    m->u.result.count = n;
    free(round_trip(m, r, n));
    ck_assert_uint_eq(r->m.u.result.count, n);
    ck_assert(memcmp(r->m.u.result.records, recs, n * sizeof *recs) == 0);
    rx_free(r);
    free(recs);
    free(m);
}
END_TEST

/* ---- the encoder refuses what the decoder would ------------------------ */

static void expect_encode_fails(const proto_msg_t *m, size_t cap, const char *want)
{
    uint8_t hdr[PROTO_HEADER_SIZE];
    uint8_t buf[256];
    char err[256] = "";
    ck_assert(cap <= sizeof buf);
    long n = proto_encode(m, hdr, buf, cap, err, sizeof err);
    ck_assert_msg(n == -1, "encode %s accepted (%ld), expected \"%s\"", proto_type_name(m->h.type),
                  n, want);
    ck_assert_msg(strstr(err, want) != NULL, "message \"%s\" lacks \"%s\"", err, want);
}

START_TEST(enc_rejects_fields)
{
    proto_msg_t *m = msg_new(0);
    expect_encode_fails(m, 256, "unknown message type 0");
    m->h.type = PROTO_TYPE_MAX + 1;
    expect_encode_fails(m, 256, "unknown message type 12");

    m->h.type = PROTO_HELLO;
    snprintf(m->u.hello.build, sizeof m->u.hello.build, "ok");
    m->u.hello.threads = 0;
    expect_encode_fails(m, 256, "HELLO: threads 0 out of range");
    m->u.hello.threads = PROTO_MAX_THREADS + 1;
    expect_encode_fails(m, 256, "HELLO: threads 4097 out of range");
    m->u.hello.threads = 1;
    snprintf(m->u.hello.build, sizeof m->u.hello.build, "tab\there");
    expect_encode_fails(m, 256, "build id byte 3 is 0x09");
    m->u.hello.build[0] = '\0';
    expect_encode_fails(m, 256, "HELLO: empty build id");
    memset(m->u.hello.build, 'a', sizeof m->u.hello.build); /* 33 bytes, no NUL */
    expect_encode_fails(m, 256, "build id longer than 32");
    snprintf(m->u.hello.build, sizeof m->u.hello.build, "ok");
    expect_encode_fails(m, 35, "HELLO: payload needs 36 bytes, the buffer has 35");

    m->h.type = PROTO_WELCOME;
    m->u.welcome.heartbeat_ms = 0;
    m->u.welcome.lease_ms = 1;
    expect_encode_fails(m, 256, "WELCOME: heartbeat_ms 0 out of range");
    m->u.welcome.heartbeat_ms = 1;
    m->u.welcome.lease_ms = 3600001;
    expect_encode_fails(m, 256, "WELCOME: lease_ms 3600001 out of range");

    m->h.type = PROTO_CREDIT;
    m->u.credit = 0;
    expect_encode_fails(m, 256, "CREDIT: credit 0");
    m->u.credit = PROTO_MAX_CREDIT + 1;
    expect_encode_fails(m, 256, "CREDIT: credit 1025");

    m->h.type = PROTO_TASK_FAILED;
    char text[PROTO_TEXT_MAX + 1];
    memset(text, 'x', sizeof text); /* 1025 bytes, no NUL */
    m->u.text.text = text;
    expect_encode_fails(m, 256, "TASK_FAILED: text longer than 1024");
    snprintf(text, sizeof text, "abc");
    expect_encode_fails(m, 6, "TASK_FAILED: payload needs 7 bytes, the buffer has 6");
    free(m);
}
END_TEST

START_TEST(enc_rejects_bundle)
{
    proto_msg_t *m = msg_new(PROTO_SCENE_BUNDLE);
    proto_bundle_t *b = &m->u.bundle;
    proto_mesh_file_t meshes[2];
    memset(meshes, 0, sizeof meshes);
    static const uint8_t data[1] = {1};
    b->json_size = 1;
    expect_encode_fails(m, 256, "SCENE_BUNDLE: json is NULL");
    b->json = "{";
    b->json_size = PROTO_MAX_SCENE_JSON + 1;
    expect_encode_fails(m, 256, "json_size 67108865 exceeds 67108864");
    b->json_size = 1;
    b->mesh_count = PROTO_MAX_MESHES + 1;
    expect_encode_fails(m, 256, "mesh_count 65 exceeds 64");
    b->mesh_count = 2;
    expect_encode_fails(m, 256, "SCENE_BUNDLE: meshes is NULL");
    b->meshes = meshes;
    snprintf(meshes[0].name, sizeof meshes[0].name, "a.obj");
    meshes[0].data = data;
    meshes[0].size = 1;
    meshes[1] = meshes[0];
    expect_encode_fails(m, 256, "mesh 1: duplicate name \"a.obj\" (also mesh 0)");

    static const struct {
        const char *name;
        const char *want;
    } bad_names[] = {
        {"", "mesh 1: name_len 0 out of range"},
        {".", "mesh 1: name \".\" is not a file name"},
        {"..", "mesh 1: name \"..\" is not a file name"},
        {"d/a.obj", "mesh 1: name contains '/'"},
        {"d\\a.obj", "mesh 1: name contains '\\'"},
        {"a\x7f", "mesh 1: name byte 1 is 0x7f"},
        {"\xc3\xa9.obj", "mesh 1: name byte 0 is 0xc3"},
    };
    for (size_t i = 0; i < sizeof bad_names / sizeof bad_names[0]; i++) {
        snprintf(meshes[1].name, sizeof meshes[1].name, "%s", bad_names[i].name);
        expect_encode_fails(m, 256, bad_names[i].want);
    }
    memset(meshes[1].name, 'n', sizeof meshes[1].name); /* 129 bytes, no NUL */
    expect_encode_fails(m, 256, "mesh 1: name_len 129 out of range");
    /* "..." and ".a" are plain file names */
    snprintf(meshes[1].name, sizeof meshes[1].name, "...");
    uint8_t hdr[PROTO_HEADER_SIZE], buf[256];
    char err[256];
    ck_assert_int_gt(proto_encode(m, hdr, buf, sizeof buf, err, sizeof err), 0);

    meshes[1].size = 2;
    meshes[1].data = NULL;
    expect_encode_fails(m, 256, "mesh 1: data is NULL");
    meshes[1].data = data;
    meshes[1].size = PROTO_MAX_MESH_BYTES + 1;
    expect_encode_fails(m, 256, "mesh 1: size 1073741825 exceeds 1073741824");
    /* Each mesh under its limit, the sum over the bundle's: refused before
     * anything reads the (absent) data. */
    meshes[0].size = PROTO_MAX_MESH_BYTES;
    meshes[1].size = PROTO_MAX_MESH_BYTES;
    expect_encode_fails(m, 256, "exceeds 1610612736");
    free(m);
}
END_TEST

START_TEST(enc_rejects_task_result)
{
    proto_msg_t *m = msg_new(PROTO_TASK);
    tracer_task_t t = {1, 1, 0, 0, {0, 0, 0}};
    m->u.task.count = 1;
    expect_encode_fails(m, 256, "TASK: records is NULL");
    m->u.task.records = &t;
    m->u.task.count = 0;
    expect_encode_fails(m, 256, "TASK: count 0");
    m->u.task.count = PROTO_MAX_TASK_PIXELS + 1;
    expect_encode_fails(m, 256, "TASK: count 65537 exceeds 65536");
    m->u.task.count = 1;
    m->u.task.settings.integrator = (scene_integrator_t)3;
    expect_encode_fails(m, 256, "TASK: integrator 3 is not 0 (path)");
    m->u.task.settings.integrator = SCENE_INTEGRATOR_NAIVE;
    m->u.task.settings.sampler = (rng_sampler_t)2;
    expect_encode_fails(m, 256, "TASK: sampler 2 is neither");
    m->u.task.settings.sampler = RNG_SAMPLER_INDEPENDENT;
    t.sample_count = 0;
    expect_encode_fails(m, 256, "TASK: record 0: sample_count 0 out of range");
    t.sample_count = TRACER_MAX_TASK_SAMPLES + 1;
    expect_encode_fails(m, 256, "TASK: record 0: sample_count 4097 out of range");
    t.sample_count = 2;
    t.first_sample = UINT64_MAX - 1;
    expect_encode_fails(m, 256, "TASK: record 0: first_sample 18446744073709551614 + sample_count");
    t.first_sample = 0;
    t.prior_sum[1] = NAN;
    expect_encode_fails(m, 256, "TASK: record 0: prior_sum[1] is NaN");
    t.prior_sum[1] = -INFINITY;
    expect_encode_fails(m, 256, "TASK: record 0: prior_sum[1] is infinite");
    t.prior_sum[1] = -1e-300;
    expect_encode_fails(m, 256, "TASK: record 0: prior_sum[1] is negative");
    t.prior_sum[1] = 0;
    expect_encode_fails(m, 103, "TASK: payload needs 104 bytes, the buffer has 103");

    memset(m, 0, sizeof *m);
    m->h.type = PROTO_RESULT;
    tracer_result_t r = {1, 1, 0, 1, {0, 0, 0}, 0, 0};
    m->u.result.count = 1;
    expect_encode_fails(m, 256, "RESULT: records is NULL");
    m->u.result.records = &r;
    m->u.result.count = PROTO_MAX_TASK_PIXELS + 1;
    expect_encode_fails(m, 256, "RESULT: count 65537 exceeds 65536");
    m->u.result.count = 1;
    r.samples = 0;
    expect_encode_fails(m, 256, "RESULT: record 0: samples 0 + nonfinite 0 out of range");
    r.samples = 4000;
    r.nonfinite = 97;
    expect_encode_fails(m, 256, "RESULT: record 0: samples 4000 + nonfinite 97 out of range");
    r.nonfinite = UINT32_MAX; /* must not wrap to a small sum */
    expect_encode_fails(m, 256, "out of range 1..4096");
    r.samples = 0;
    r.nonfinite = 1;
    r.lum_m2 = INFINITY;
    expect_encode_fails(m, 256, "RESULT: record 0: lum_m2 is infinite");
    r.lum_m2 = 0;
    r.sum[0] = -NAN;
    expect_encode_fails(m, 256, "RESULT: record 0: sum[0] is NaN");
    r.sum[0] = 0;
    r.pvar = -0.5;
    expect_encode_fails(m, 256, "RESULT: record 0: pvar is negative");
    r.pvar = 0;
    /* every sample traces at least its camera ray */
    r.samples = 3;
    r.nonfinite = 2;
    r.rays = 4;
    expect_encode_fails(m, 256, "RESULT: record 0: rays 4 fewer than its 5 samples");
    r.rays = 0xdeadbeef;
    uint8_t hdr[PROTO_HEADER_SIZE], buf[80];
    char err[256];
    ck_assert_int_eq(proto_encode(m, hdr, buf, sizeof buf, err, sizeof err), 80);
    ck_assert(buf[24 + 12] == 0xef && buf[24 + 13] == 0xbe && buf[24 + 14] == 0xad &&
              buf[24 + 15] == 0xde);
    free(m);
}
END_TEST

/* ---- truncation, extension, capacity ----------------------------------- */

static void expect_refused(const uint8_t *h, size_t hn, const uint8_t *p, size_t pn,
                           uint32_t capacity, const char *what, size_t at)
{
    char err[256];
    rx_t *r = rx_new(capacity);
    int rc = decode(r, capacity, h, hn, p, pn, err, sizeof err);
    ck_assert_msg(rc == -1, "%s at %zu: rc %d", what, at, rc);
    ck_assert_msg(err[0] != '\0', "%s at %zu: no message", what, at);
    rx_free(r);
}

static void set_payload_size(uint8_t *h, uint32_t n)
{
    for (int i = 0; i < 4; i++)
        h[28 + i] = (uint8_t)(n >> (8 * i));
}

START_TEST(truncated_payloads)
{
    static const char *const files[] = {"task.hex",   "result.hex",       "scene_bundle.hex",
                                        "hello.hex",  "welcome.hex",      "refuse.hex",
                                        "credit.hex", "scene_request.hex"};
    for (size_t f = 0; f < sizeof files / sizeof files[0]; f++) {
        vec_t v = load_vec(files[f]);
        uint8_t h[PROTO_HEADER_SIZE];
        for (size_t len = 0; len < v.pn; len++) {
            /* An exact-size copy, so ASan sees a read past the end. */
            uint8_t *p = malloc(len ? len : 1);
            ck_assert_ptr_nonnull(p);
            memcpy(p, v.p, len);
            /* header unchanged: its payload_size no longer matches */
            expect_refused(v.h, v.hn, p, len, VEC_CAP, files[f], len);
            /* header made to agree: the layout check must catch it */
            memcpy(h, v.h, sizeof h);
            set_payload_size(h, (uint32_t)len);
            expect_refused(h, sizeof h, p, len, VEC_CAP, files[f], len);
            free(p);
        }
        /* one byte too many */
        uint8_t *p = calloc(v.pn + 1, 1);
        ck_assert_ptr_nonnull(p);
        memcpy(p, v.p, v.pn);
        memcpy(h, v.h, sizeof h);
        set_payload_size(h, (uint32_t)v.pn + 1);
        expect_refused(h, sizeof h, p, v.pn + 1, VEC_CAP, files[f], v.pn + 1);
        free(p);
        free_vec(&v);
    }
}
END_TEST

START_TEST(truncated_header)
{
    vec_t v = load_vec("task.hex");
    for (size_t len = 0; len < PROTO_HEADER_SIZE; len++) {
        uint8_t *h = malloc(len ? len : 1);
        ck_assert_ptr_nonnull(h);
        memcpy(h, v.h, len);
        expect_refused(h, len, v.p, v.pn, VEC_CAP, "header", len);
        free(h);
    }
    uint8_t longer[PROTO_HEADER_SIZE + 1] = {0};
    memcpy(longer, v.h, PROTO_HEADER_SIZE);
    expect_refused(longer, sizeof longer, v.p, v.pn, VEC_CAP, "header", sizeof longer);
    expect_refused(NULL, 0, v.p, v.pn, VEC_CAP, "NULL header", 0);
    free_vec(&v);
}
END_TEST

/* Record buffers are the caller's, apart from the message: a decode sets
 * every pointer in the message itself, so none left from an earlier
 * message (of another type) is trusted. */
START_TEST(no_leftover_pointers)
{
    ck_assert_uint_le(sizeof(proto_msg_t), 512);
    char err[256];
    vec_t task = load_vec("task.hex"), result = load_vec("result.hex");
    rx_t *r = rx_new(2);
    ck_assert_int_eq(decode(r, 2, task.h, task.hn, task.p, task.pn, err, sizeof err), 0);
    ck_assert_ptr_eq(r->m.u.task.records, r->tasks);
    /* a RESULT next, with only a task buffer: refused, although the
     * message still holds the TASK's pointer */
    r->recs.results = NULL;
    ck_assert_int_eq(
        proto_decode(result.h, result.hn, result.p, result.pn, &r->m, &r->recs, err, sizeof err),
        -1);
    ck_assert(strstr(err, "RESULT: no record buffer") != NULL);
    /* and with one, the records land there and nowhere else */
    r->recs.results = r->results;
    ck_assert_int_eq(
        proto_decode(result.h, result.hn, result.p, result.pn, &r->m, &r->recs, err, sizeof err),
        0);
    ck_assert_ptr_eq(r->m.u.result.records, r->results);
    /* no buffers at all: records and texts are refused, fixed types pass */
    ck_assert_int_eq(proto_decode(task.h, task.hn, task.p, task.pn, &r->m, NULL, err, sizeof err),
                     -1);
    ck_assert_str_eq(err, "TASK: count 2 exceeds the receive capacity 0");
    free_vec(&task);
    free_vec(&result);
    vec_t bye = load_vec("bye.hex"), credit = load_vec("credit.hex");
    ck_assert_int_eq(proto_decode(bye.h, bye.hn, bye.p, bye.pn, &r->m, NULL, err, sizeof err), -1);
    ck_assert(strstr(err, "BYE: no text buffer") != NULL);
    ck_assert_int_eq(
        proto_decode(credit.h, credit.hn, credit.p, credit.pn, &r->m, NULL, err, sizeof err), 0);
    free_vec(&bye);
    free_vec(&credit);
    rx_free(r);
}
END_TEST

START_TEST(over_capacity)
{
    char err[256];
    vec_t v = load_vec("task.hex"); /* 2 records */
    rx_t *r = rx_new(2);
    ck_assert_int_eq(decode(r, 1, v.h, v.hn, v.p, v.pn, err, sizeof err), -1);
    ck_assert_str_eq(err, "TASK: count 2 exceeds the receive capacity 1");
    ck_assert_int_eq(decode(r, 2, v.h, v.hn, v.p, v.pn, err, sizeof err), 0);
    /* a capacity without a buffer */
    rx_reset(r, 2);
    r->recs.tasks = NULL;
    ck_assert_int_eq(proto_decode(v.h, v.hn, v.p, v.pn, &r->m, &r->recs, err, sizeof err), -1);
    ck_assert(strstr(err, "TASK: no record buffer") != NULL);
    free_vec(&v);

    v = load_vec("result.hex");
    ck_assert_int_eq(decode(r, 0, v.h, v.hn, v.p, v.pn, err, sizeof err), -1);
    ck_assert_str_eq(err, "RESULT: count 2 exceeds the receive capacity 0");
    rx_reset(r, 2);
    r->recs.results = NULL;
    ck_assert_int_eq(proto_decode(v.h, v.hn, v.p, v.pn, &r->m, &r->recs, err, sizeof err), -1);
    ck_assert(strstr(err, "RESULT: no record buffer") != NULL);
    free_vec(&v);
    rx_free(r);
}
END_TEST

/* ---- arbitrary bytes --------------------------------------------------- */

/* xorshift64*: deterministic, so a failure reproduces. */
static uint64_t rnd(uint64_t *s)
{
    *s ^= *s >> 12;
    *s ^= *s << 25;
    *s ^= *s >> 27;
    return *s * UINT64_C(2685821657736338717);
}

/* Decodes and, if accepted, demands the one encoding back; else -1/-2 with
 * a message. Returns rc. */
static int decode_any(rx_t *r, uint32_t cap, const uint8_t *h, size_t hn, const uint8_t *p,
                      size_t pn)
{
    char err[256];
    int rc = decode(r, cap, h, hn, p, pn, err, sizeof err);
    if (rc == 0)
        expect_encodes_to(&r->m, h, hn, p, pn);
    else
        ck_assert_msg((rc == -1 || rc == -2) && err[0] != '\0', "rc %d, message \"%s\"", rc, err);
    return rc;
}

START_TEST(random_frames)
{
    uint64_t s = UINT64_C(0x243F6A8885A308D3);
    rx_t *r = rx_new(8);
    int accepted = 0;
    /* Pure noise: refused, every time. */
    for (int it = 0; it < 10000; it++) {
        size_t hn = rnd(&s) % 4 ? PROTO_HEADER_SIZE : (size_t)(rnd(&s) % 40);
        size_t pn = (size_t)(rnd(&s) % 600);
        uint8_t *h = malloc(hn ? hn : 1), *p = malloc(pn ? pn : 1);
        ck_assert(h && p);
        for (size_t i = 0; i < hn; i++)
            h[i] = (uint8_t)rnd(&s);
        for (size_t i = 0; i < pn; i++)
            p[i] = (uint8_t)rnd(&s);
        ck_assert_int_ne(decode_any(r, 8, h, hn, p, pn), 0);
        free(h);
        free(p);
    }
    /* A believable header over noise: reaches every payload decoder. */
    for (int it = 0; it < 10000; it++) {
        uint8_t h[PROTO_HEADER_SIZE];
        size_t pn = (size_t)(rnd(&s) % 4 ? rnd(&s) % 64 : rnd(&s) % 600);
        uint8_t *p = malloc(pn ? pn : 1);
        ck_assert_ptr_nonnull(p);
        for (size_t i = 0; i < sizeof h; i++)
            h[i] = (uint8_t)rnd(&s);
        memcpy(h, "VBRP", 4);
        h[4] = PROTO_VERSION & 0xff;
        h[5] = PROTO_VERSION >> 8;
        h[6] = (uint8_t)(rnd(&s) % 13);
        h[7] = 0;
        set_payload_size(h, (uint32_t)pn);
        for (size_t i = 0; i < pn; i++)
            p[i] = (uint8_t)(rnd(&s) % 3 ? rnd(&s) % 4 : rnd(&s)); /* zeros are likelier */
        accepted += decode_any(r, 8, h, sizeof h, p, pn) == 0;
        free(p);
    }
    ck_assert_int_gt(accepted, 0); /* e.g. heartbeats, scene requests */
    rx_free(r);
}
END_TEST

START_TEST(every_byte_of_every_vector)
{
    static const char *const files[] = {"hello.hex",  "welcome.hex",       "refuse.hex",
                                        "credit.hex", "scene_request.hex", "scene_bundle.hex",
                                        "task.hex",   "result.hex",        "heartbeat.hex",
                                        "bye.hex",    "task_failed.hex"};
    static const uint8_t values[] = {0x00, 0x01, 0x2f, 0x7f, 0x80, 0xf0, 0xff};
    rx_t *r = rx_new(VEC_CAP);
    for (size_t f = 0; f < sizeof files / sizeof files[0]; f++) {
        vec_t v = load_vec(files[f]);
        uint8_t *all = malloc(v.hn + v.pn);
        ck_assert_ptr_nonnull(all);
        for (size_t at = 0; at < v.hn + v.pn; at++)
            for (size_t k = 0; k < sizeof values + 8; k++) {
                memcpy(all, v.h, v.hn);
                memcpy(all + v.hn, v.p, v.pn);
                if (k < sizeof values)
                    all[at] = values[k];
                else
                    all[at] ^= (uint8_t)(1u << (k - sizeof values));
                decode_any(r, VEC_CAP, all, v.hn, all + v.hn, v.pn);
            }
        free(all);
        free_vec(&v);
    }
    rx_free(r);
}
END_TEST

/* ---- small things ------------------------------------------------------ */

START_TEST(version_refusal)
{
    vec_t v = load_vec("hello.hex");
    char err[256];
    rx_t *r = rx_new(1);
    const uint16_t versions[3] = {0, PROTO_VERSION - 1, 0xffff};
    for (int i = 0; i < 3; i++) {
        v.h[4] = (uint8_t)versions[i];
        v.h[5] = (uint8_t)(versions[i] >> 8);
        ck_assert_int_eq(decode(r, 1, v.h, v.hn, v.p, v.pn, err, sizeof err), -2);
        char want[128];
        snprintf(want, sizeof want, "peer speaks protocol version %u, this build speaks %d",
                 (unsigned)versions[i], PROTO_VERSION);
        ck_assert_str_eq(err, want);
    }
    /* a bad magic wins over the version: it is not our protocol at all */
    v.h[0] ^= 1;
    ck_assert_int_eq(decode(r, 1, v.h, v.hn, v.p, v.pn, err, sizeof err), -1);
    /* no message buffer: still refused, nothing written */
    ck_assert_int_eq(proto_decode(v.h, v.hn, v.p, v.pn, &r->m, &r->recs, NULL, 0), -1);
    err[0] = 'x';
    ck_assert_int_eq(proto_decode(v.h, v.hn, v.p, v.pn, &r->m, &r->recs, err, 0), -1);
    ck_assert_int_eq(err[0], 'x');
    ck_assert_int_eq(proto_decode(v.h, v.hn, v.p, v.pn, NULL, &r->recs, err, sizeof err), -1);
    rx_free(r);
    free_vec(&v);
}
END_TEST

START_TEST(type_names)
{
    static const char *const want[] = {"?",      "HELLO",         "WELCOME",      "REFUSE",
                                       "CREDIT", "SCENE_REQUEST", "SCENE_BUNDLE", "TASK",
                                       "RESULT", "HEARTBEAT",     "BYE",          "TASK_FAILED"};
    for (uint16_t t = 0; t <= PROTO_TYPE_MAX; t++)
        ck_assert_str_eq(proto_type_name(t), want[t]);
    ck_assert_str_eq(proto_type_name(PROTO_TYPE_MAX + 1), "?");
    ck_assert_str_eq(proto_type_name(0xffff), "?");
}
END_TEST

START_TEST(build_id)
{
    char id[PROTO_BUILD_SIZE + 1], want[64];
#if defined(__clang__)
    snprintf(want, sizeof want, "vbrender-p%d-t%d-avx2-clang%d.%d", PROTO_VERSION, TRACER_VERSION,
             __clang_major__, __clang_minor__);
#elif defined(__GNUC__)
    snprintf(want, sizeof want, "vbrender-p%d-t%d-avx2-gcc%d.%d", PROTO_VERSION, TRACER_VERSION,
             __GNUC__, __GNUC_MINOR__);
#else
    snprintf(want, sizeof want, "vbrender-p%d-t%d-avx2-cc", PROTO_VERSION, TRACER_VERSION);
#endif
    proto_build_id("avx2", id);
    ck_assert_str_eq(id, want);

    /* cut to 32, and always a valid HELLO build id */
    proto_build_id("a-very-long-isa-name-that-goes-on-and-on", id);
    ck_assert_uint_eq(strlen(id), PROTO_BUILD_SIZE);
    snprintf(want, sizeof want, "vbrender-p%d-t%d-a-very-long-isa-name", PROTO_VERSION,
             TRACER_VERSION);
    ck_assert(strncmp(id, want, PROTO_BUILD_SIZE) == 0);
    proto_build_id("sse\n4.2", id);
    snprintf(want, sizeof want, "vbrender-p%d-t%d-sse?4.2-", PROTO_VERSION, TRACER_VERSION);
    ck_assert(strncmp(id, want, strlen(want)) == 0);
    proto_build_id(NULL, id);
    snprintf(want, sizeof want, "vbrender-p%d-t%d-?-", PROTO_VERSION, TRACER_VERSION);
    ck_assert(strncmp(id, want, strlen(want)) == 0);

    proto_msg_t *m = msg_new(PROTO_HELLO);
    rx_t *r = rx_new(1);
    m->u.hello.threads = 8;
    proto_build_id("sse\x01"
                   "4.2-and-more-and-more-and-more",
                   m->u.hello.build);
    free(round_trip(m, r, 1));
    ck_assert_str_eq(r->m.u.hello.build, m->u.hello.build);
    rx_free(r);
    free(m);
}
END_TEST

START_TEST(payload_sizes)
{
    proto_msg_t *m = msg_new(PROTO_HEARTBEAT);
    ck_assert_uint_eq(proto_payload_size(m), 0);
    m->h.type = PROTO_HELLO;
    ck_assert_uint_eq(proto_payload_size(m), 36);
    m->h.type = PROTO_WELCOME;
    ck_assert_uint_eq(proto_payload_size(m), 8);
    m->h.type = PROTO_CREDIT;
    ck_assert_uint_eq(proto_payload_size(m), 4);
    m->h.type = PROTO_SCENE_REQUEST;
    ck_assert_uint_eq(proto_payload_size(m), 32);
    m->h.type = PROTO_BYE;
    m->u.text.text = "hello";
    ck_assert_uint_eq(proto_payload_size(m), 9);
    m->h.type = PROTO_TASK;
    m->u.task.count = 3;
    ck_assert_uint_eq(proto_payload_size(m), 56 + 3 * 48);
    memset(&m->u, 0, sizeof m->u);
    m->h.type = PROTO_RESULT;
    m->u.result.count = 3;
    ck_assert_uint_eq(proto_payload_size(m), 24 + 3 * 56);
    memset(&m->u, 0, sizeof m->u);
    m->h.type = PROTO_SCENE_BUNDLE;
    m->u.bundle.json_size = 10;
    m->u.bundle.mesh_count = 1;
    proto_mesh_file_t mesh = {.name = "a.ply", .size = 7};
    m->u.bundle.meshes = &mesh;
    ck_assert_uint_eq(proto_payload_size(m), 40 + 10 + 2 + 5 + 4 + 7);
    m->u.bundle.mesh_count = 1000; /* invalid, but no read past the array */
    ck_assert_uint_ge(proto_payload_size(m), 40 + 10);
    m->h.type = 0;
    ck_assert_uint_eq(proto_payload_size(m), 0);
    ck_assert_uint_eq(proto_payload_size(NULL), 0);
    free(m);
}
END_TEST

/* The bundle hash against an independent computation (Python hashlib's
 * BLAKE2b-256 over the framed fields), and framing: moving bytes between
 * the JSON and a mesh name changes the hash. */
START_TEST(test_bundle_hash)
{
    ck_assert(sodium_init() >= 0);
    proto_mesh_file_t mesh = {.name = "mesh0.ply", .data = (const uint8_t *)"ply\nxyz", .size = 7};
    proto_bundle_t b = {.json = "{\"a\":1}", .json_size = 7, .mesh_count = 1, .meshes = &mesh};
    uint8_t h[PROTO_HASH_SIZE];
    proto_bundle_hash(&b, h);
    char hex[2 * PROTO_HASH_SIZE + 1];
    for (int i = 0; i < PROTO_HASH_SIZE; i++)
        snprintf(hex + 2 * i, 3, "%02x", h[i]);
    ck_assert_str_eq(hex, "e16cccef6855f8a82a0a51a363d7649808baacd49cab7cffb903430067cc184c");
    proto_bundle_t empty = {.json = "{}", .json_size = 2};
    proto_bundle_hash(&empty, h);
    for (int i = 0; i < PROTO_HASH_SIZE; i++)
        snprintf(hex + 2 * i, 3, "%02x", h[i]);
    ck_assert_str_eq(hex, "376b7bb907c1489aca4a1b2d71b8c5175b37b0f48d1dae633d70e7bb326dea1d");
    /* "{\"a\":1}m" + "esh0.ply" is not "{\"a\":1}" + "mesh0.ply" */
    proto_mesh_file_t shifted_mesh = mesh;
    snprintf(shifted_mesh.name, sizeof shifted_mesh.name, "esh0.ply");
    proto_bundle_t shifted = b;
    shifted.json = "{\"a\":1}m";
    shifted.json_size = 8;
    shifted.meshes = &shifted_mesh;
    uint8_t h2[PROTO_HASH_SIZE];
    proto_bundle_hash(&b, h);
    proto_bundle_hash(&shifted, h2);
    ck_assert(memcmp(h, h2, PROTO_HASH_SIZE) != 0);
}
END_TEST

static Suite *proto_suite(void)
{
    Suite *s = suite_create("proto");
    TCase *tc = tcase_create("vectors");
    tcase_add_test(tc, vec_hello);
    tcase_add_test(tc, test_bundle_hash);
    tcase_add_test(tc, vec_welcome);
    tcase_add_test(tc, vec_refuse);
    tcase_add_test(tc, vec_credit);
    tcase_add_test(tc, vec_scene_request);
    tcase_add_test(tc, vec_scene_bundle);
    tcase_add_test(tc, vec_task);
    tcase_add_test(tc, vec_result);
    tcase_add_test(tc, vec_heartbeat);
    tcase_add_test(tc, vec_bye);
    tcase_add_test(tc, vec_task_failed);
    tcase_add_loop_test(tc, vec_invalid, 0,
                        (int)(sizeof invalid_vectors / sizeof invalid_vectors[0]));
    suite_add_tcase(s, tc);

    tc = tcase_create("round trips");
    tcase_set_timeout(tc, 60);
    tcase_add_test(tc, rt_hello);
    tcase_add_test(tc, rt_welcome_credit_request_heartbeat);
    tcase_add_test(tc, rt_text);
    tcase_add_test(tc, rt_bundle_empty);
    tcase_add_test(tc, rt_bundle_max_meshes);
    tcase_add_test(tc, rt_task_edges);
    tcase_add_test(tc, rt_result_edges);
    suite_add_tcase(s, tc);

    tc = tcase_create("refusals");
    tcase_set_timeout(tc, 120);
    tcase_add_test(tc, enc_rejects_fields);
    tcase_add_test(tc, enc_rejects_bundle);
    tcase_add_test(tc, enc_rejects_task_result);
    tcase_add_test(tc, truncated_payloads);
    tcase_add_test(tc, truncated_header);
    tcase_add_test(tc, over_capacity);
    tcase_add_test(tc, no_leftover_pointers);
    tcase_add_test(tc, random_frames);
    tcase_add_test(tc, every_byte_of_every_vector);
    tcase_add_test(tc, version_refusal);
    suite_add_tcase(s, tc);

    tc = tcase_create("misc");
    tcase_add_test(tc, type_names);
    tcase_add_test(tc, build_id);
    tcase_add_test(tc, payload_sizes);
    suite_add_tcase(s, tc);
    return s;
}

int main(void)
{
    SRunner *sr = srunner_create(proto_suite());
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed == 0 ? 0 : 1;
}
