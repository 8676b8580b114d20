/* proto.c - encoder and decoder of the vbrender wire protocol (see proto.h
 * and proto/PROTOCOL.md, which gives every byte).
 *
 * Every integer is written and read one byte at a time with explicit shifts,
 * and doubles travel as the little-endian bytes of their IEEE-754 bits, so
 * neither host byte order nor struct padding can reach the wire. The same
 * validators check a message on both sides: the encoder refuses what the
 * decoder would refuse, so a peer of this build never sends what another
 * peer of this build rejects. The decoder checks each length against what
 * is left before it reads, and each count against its limit and the
 * caller's capacity before it writes a record.
 */
#include "proto.h"

#include <sodium.h>

#include <inttypes.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

/* Fixed parts of the payloads (PROTOCOL.md has the tables). */
#define HELLO_SIZE (4 + PROTO_BUILD_SIZE)
#define WELCOME_SIZE 8
#define TEXT_HEAD 4
#define CREDIT_SIZE 4
#define BUNDLE_HEAD (PROTO_HASH_SIZE + 8)
#define TASK_HEAD (PROTO_HASH_SIZE + 8 + 1 + 1 + 2 + 4 + 4 + 4)
#define RESULT_HEAD 24
_Static_assert(PROTO_MAX_RESULT_PAYLOAD ==
                   RESULT_HEAD + (size_t)PROTO_RESULT_RECORD_SIZE * PROTO_MAX_TASK_PIXELS,
               "proto.h and proto.c agree on a RESULT's head");
#define MESH_HEAD 6 /* name_len u16 + size u32, around the name */
#define WELCOME_MAX_MS 3600000u

#if defined(__GNUC__)
#define PROTO_PRINTF(a, b) __attribute__((format(printf, a, b)))
#else
#define PROTO_PRINTF(a, b)
#endif

PROTO_PRINTF(3, 4)
static int fail(char *err, size_t errlen, const char *fmt, ...)
{
    if (err && errlen) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(err, errlen, fmt, ap);
        va_end(ap);
    }
    return -1;
}

/* The message is a stack value; what made it large lives in proto_records_t. */
_Static_assert(sizeof(proto_msg_t) <= 512, "proto_msg_t must stay small enough for the stack");

/* ---- little-endian bytes ------------------------------------------------ */

static uint8_t *put_u8(uint8_t *p, uint8_t v)
{
    p[0] = v;
    return p + 1;
}

static uint8_t *put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
    return p + 2;
}

/* Written out, not as loops: GCC merges these shifts into one load or
 * store (the master decodes millions of records a second), while the byte
 * order stays explicit and independent of the host. */
static uint8_t *put_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
    p[2] = (uint8_t)(v >> 16);
    p[3] = (uint8_t)(v >> 24);
    return p + 4;
}

static uint8_t *put_u64(uint8_t *p, uint64_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
    p[2] = (uint8_t)(v >> 16);
    p[3] = (uint8_t)(v >> 24);
    p[4] = (uint8_t)(v >> 32);
    p[5] = (uint8_t)(v >> 40);
    p[6] = (uint8_t)(v >> 48);
    p[7] = (uint8_t)(v >> 56);
    return p + 8;
}

/* The double's bits, not its value: memcpy is the one defined way to get
 * them, and the bits then go out in fixed byte order like any u64. */
static uint8_t *put_f64(uint8_t *p, double v)
{
    uint64_t bits;
    memcpy(&bits, &v, sizeof bits);
    return put_u64(p, bits);
}

static uint8_t *put_bytes(uint8_t *p, const void *src, size_t n)
{
    if (n)
        memcpy(p, src, n);
    return p + n;
}

static uint16_t get_u16(const uint8_t *p)
{
    return (uint16_t)(p[0] | (uint16_t)p[1] << 8);
}

static uint32_t get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static uint64_t get_u64(const uint8_t *p)
{
    return (uint64_t)p[0] | (uint64_t)p[1] << 8 | (uint64_t)p[2] << 16 | (uint64_t)p[3] << 24 |
           (uint64_t)p[4] << 32 | (uint64_t)p[5] << 40 | (uint64_t)p[6] << 48 |
           (uint64_t)p[7] << 56;
}

static double get_f64(const uint8_t *p)
{
    uint64_t bits = get_u64(p);
    double v;
    memcpy(&v, &bits, sizeof v);
    return v;
}

/* ---- field validators, shared by encoder and decoder ---------------------- */

/* Names what is wrong with a radiance sum or a statistic, or NULL. -0.0
 * compares equal to 0 and passes: it is a sum of nothing, bit for bit. */
static const char *f64_problem(double v)
{
    if (isnan(v))
        return "is NaN";
    if (isinf(v))
        return "is infinite";
    if (v < 0)
        return "is negative";
    return NULL;
}

static int printable(unsigned char c)
{
    return c >= 0x20 && c <= 0x7e;
}

static int check_hello(const proto_hello_t *h, char *err, size_t errlen)
{
    if (h->threads < 1 || h->threads > PROTO_MAX_THREADS)
        return fail(err, errlen, "HELLO: threads %" PRIu32 " out of range 1..%d", h->threads,
                    PROTO_MAX_THREADS);
    size_t n = strnlen(h->build, sizeof h->build);
    if (n > PROTO_BUILD_SIZE)
        return fail(err, errlen, "HELLO: build id longer than %d bytes", PROTO_BUILD_SIZE);
    if (n == 0)
        return fail(err, errlen, "HELLO: empty build id");
    for (size_t i = 0; i < n; i++)
        if (!printable((unsigned char)h->build[i]))
            return fail(err, errlen, "HELLO: build id byte %zu is 0x%02x, not printable ASCII", i,
                        (unsigned char)h->build[i]);
    return 0;
}

static int check_welcome(const proto_welcome_t *w, char *err, size_t errlen)
{
    if (w->heartbeat_ms < 1 || w->heartbeat_ms > WELCOME_MAX_MS)
        return fail(err, errlen, "WELCOME: heartbeat_ms %" PRIu32 " out of range 1..%u",
                    w->heartbeat_ms, WELCOME_MAX_MS);
    if (w->lease_ms < 1 || w->lease_ms > WELCOME_MAX_MS)
        return fail(err, errlen, "WELCOME: lease_ms %" PRIu32 " out of range 1..%u", w->lease_ms,
                    WELCOME_MAX_MS);
    return 0;
}

static int check_credit(uint32_t credit, char *err, size_t errlen)
{
    if (credit < 1 || credit > PROTO_MAX_CREDIT)
        return fail(err, errlen, "CREDIT: credit %" PRIu32 " out of range 1..%d", credit,
                    PROTO_MAX_CREDIT);
    return 0;
}

/* A mesh name becomes a file name in the worker's scene cache, so nothing
 * in it may leave that folder or hide in it. */
static int check_mesh_name(const char *name, size_t len, uint32_t i, char *err, size_t errlen)
{
    if (len < 1 || len > PROTO_MAX_NAME)
        return fail(err, errlen, "SCENE_BUNDLE: mesh %" PRIu32 ": name_len %zu out of range 1..%d",
                    i, len, PROTO_MAX_NAME);
    for (size_t k = 0; k < len; k++) {
        unsigned char c = (unsigned char)name[k];
        if (!printable(c))
            return fail(err, errlen,
                        "SCENE_BUNDLE: mesh %" PRIu32 ": name byte %zu is 0x%02x, not printable "
                        "ASCII",
                        i, k, c);
        if (c == '/' || c == '\\')
            return fail(err, errlen, "SCENE_BUNDLE: mesh %" PRIu32 ": name contains '%c'", i, c);
    }
    if ((len == 1 && name[0] == '.') || (len == 2 && name[0] == '.' && name[1] == '.'))
        return fail(err, errlen, "SCENE_BUNDLE: mesh %" PRIu32 ": name \"%.*s\" is not a file name",
                    i, (int)len, name);
    return 0;
}

/* meshes[i] against the ones before it: a second file of the same name
 * would silently replace the first in the worker's cache. */
static int check_mesh_unique(const proto_mesh_file_t *meshes, uint32_t i, char *err, size_t errlen)
{
    for (uint32_t k = 0; k < i; k++)
        if (strcmp(meshes[k].name, meshes[i].name) == 0)
            return fail(err, errlen,
                        "SCENE_BUNDLE: mesh %" PRIu32 ": duplicate name \"%s\" (also mesh %" PRIu32
                        ")",
                        i, meshes[i].name, k);
    return 0;
}

static int check_integrator(int v, char *err, size_t errlen)
{
    if (v != SCENE_INTEGRATOR_PATH && v != SCENE_INTEGRATOR_NAIVE && v != SCENE_INTEGRATOR_DIRECT)
        return fail(err, errlen, "TASK: integrator %d is not 0 (path), 1 (naive) or 2 (direct)", v);
    return 0;
}

static int check_sampler(int v, char *err, size_t errlen)
{
    if (v != RNG_SAMPLER_INDEPENDENT && v != RNG_SAMPLER_SOBOL)
        return fail(err, errlen, "TASK: sampler %d is neither 0 (independent) nor 1 (sobol)", v);
    return 0;
}

static int check_task_count(uint32_t count, char *err, size_t errlen)
{
    if (count == 0)
        return fail(err, errlen, "TASK: count 0 (a task has at least one record)");
    if (count > PROTO_MAX_TASK_PIXELS)
        return fail(err, errlen, "TASK: count %" PRIu32 " exceeds %d", count,
                    PROTO_MAX_TASK_PIXELS);
    return 0;
}

static int check_result_count(uint32_t count, char *err, size_t errlen)
{
    if (count > PROTO_MAX_TASK_PIXELS)
        return fail(err, errlen, "RESULT: count %" PRIu32 " exceeds %d", count,
                    PROTO_MAX_TASK_PIXELS);
    return 0;
}

static int check_task_record(const tracer_task_t *r, uint32_t i, char *err, size_t errlen)
{
    if (r->sample_count < 1 || r->sample_count > TRACER_MAX_TASK_SAMPLES)
        return fail(err, errlen,
                    "TASK: record %" PRIu32 ": sample_count %" PRIu32 " out of range 1..%d", i,
                    r->sample_count, TRACER_MAX_TASK_SAMPLES);
    /* Sample indices are seeds; a range that wraps would reuse index 0. */
    if (r->first_sample > UINT64_MAX - r->sample_count)
        return fail(err, errlen,
                    "TASK: record %" PRIu32 ": first_sample %" PRIu64 " + sample_count wraps", i,
                    r->first_sample);
    for (int c = 0; c < 3; c++) {
        const char *why = f64_problem(r->prior_sum[c]);
        if (why)
            return fail(err, errlen, "TASK: record %" PRIu32 ": prior_sum[%d] %s", i, c, why);
    }
    return 0;
}

static int check_result_record(const tracer_result_t *r, uint32_t i, char *err, size_t errlen)
{
    /* A result answers one task record, which took 1..TRACER_MAX_TASK_SAMPLES
     * samples, each either finite (in samples) or not (in nonfinite). */
    uint64_t taken = (uint64_t)r->samples + r->nonfinite;
    if (taken < 1 || taken > TRACER_MAX_TASK_SAMPLES)
        return fail(err, errlen,
                    "RESULT: record %" PRIu32 ": samples %" PRIu32 " + nonfinite %" PRIu32
                    " out of range 1..%d",
                    i, r->samples, r->nonfinite, TRACER_MAX_TASK_SAMPLES);
    /* every sample traces at least its camera ray */
    if (r->rays < taken)
        return fail(err, errlen,
                    "RESULT: record %" PRIu32 ": rays %" PRIu32 " fewer than its %" PRIu64
                    " samples (each traces at least one)",
                    i, r->rays, taken);
    static const char *const names[5] = {"sum[0]", "sum[1]", "sum[2]", "lum_m2", "pvar"};
    const double v[5] = {r->sum[0], r->sum[1], r->sum[2], r->lum_m2, r->pvar};
    for (int k = 0; k < 5; k++) {
        const char *why = f64_problem(v[k]);
        if (why)
            return fail(err, errlen, "RESULT: record %" PRIu32 ": %s %s", i, names[k], why);
    }
    return 0;
}

/* ---- sizes ---------------------------------------------------------------- */

/* A text's length, up to one byte past the limit so that check_msg sees
 * one too long; NULL is the empty text. */
static size_t text_len(const char *text)
{
    return text ? strnlen(text, PROTO_TEXT_MAX + 1) : 0;
}

size_t proto_payload_size(const proto_msg_t *msg)
{
    if (!msg)
        return 0;
    switch (msg->h.type) {
    case PROTO_HELLO:
        return HELLO_SIZE;
    case PROTO_WELCOME:
        return WELCOME_SIZE;
    case PROTO_REFUSE:
    case PROTO_BYE:
    case PROTO_TASK_FAILED:
        return TEXT_HEAD + text_len(msg->u.text.text);
    case PROTO_CREDIT:
        return CREDIT_SIZE;
    case PROTO_SCENE_REQUEST:
        return PROTO_HASH_SIZE;
    case PROTO_SCENE_BUNDLE: {
        /* Files past the limit (or without an array) are not read: the
         * caller's array need not hold them, and proto_encode refuses such
         * a message anyway. */
        const proto_bundle_t *b = &msg->u.bundle;
        uint32_t n = b->meshes && b->mesh_count <= PROTO_MAX_MESHES ? b->mesh_count : 0;
        uint64_t size = (uint64_t)BUNDLE_HEAD + b->json_size;
        for (uint32_t i = 0; i < n; i++)
            size += MESH_HEAD + strnlen(b->meshes[i].name, sizeof b->meshes[i].name) +
                    (uint64_t)b->meshes[i].size;
        return size > SIZE_MAX ? SIZE_MAX : (size_t)size;
    }
    case PROTO_TASK:
        return TASK_HEAD + (size_t)PROTO_TASK_RECORD_SIZE * msg->u.task.count;
    case PROTO_RESULT:
        return RESULT_HEAD + (size_t)PROTO_RESULT_RECORD_SIZE * msg->u.result.count;
    case PROTO_HEARTBEAT:
        return 0;
    default:
        return 0;
    }
}

/* ---- encoder -------------------------------------------------------------- */

static int check_bundle(const proto_bundle_t *b, char *err, size_t errlen)
{
    if (b->json_size > PROTO_MAX_SCENE_JSON)
        return fail(err, errlen, "SCENE_BUNDLE: json_size %" PRIu32 " exceeds %u", b->json_size,
                    PROTO_MAX_SCENE_JSON);
    if (b->json_size > 0 && !b->json)
        return fail(err, errlen, "SCENE_BUNDLE: json is NULL");
    if (b->mesh_count > PROTO_MAX_MESHES)
        return fail(err, errlen, "SCENE_BUNDLE: mesh_count %" PRIu32 " exceeds %d", b->mesh_count,
                    PROTO_MAX_MESHES);
    if (b->mesh_count > 0 && !b->meshes)
        return fail(err, errlen, "SCENE_BUNDLE: meshes is NULL");
    uint64_t total = (uint64_t)BUNDLE_HEAD + b->json_size;
    for (uint32_t i = 0; i < b->mesh_count; i++) {
        const proto_mesh_file_t *m = &b->meshes[i];
        size_t len = strnlen(m->name, sizeof m->name);
        if (check_mesh_name(m->name, len, i, err, errlen) != 0 ||
            check_mesh_unique(b->meshes, i, err, errlen) != 0)
            return -1;
        if (m->size > PROTO_MAX_MESH_BYTES)
            return fail(err, errlen, "SCENE_BUNDLE: mesh %" PRIu32 ": size %" PRIu32 " exceeds %u",
                        i, m->size, PROTO_MAX_MESH_BYTES);
        if (m->size > 0 && !m->data)
            return fail(err, errlen, "SCENE_BUNDLE: mesh %" PRIu32 ": data is NULL", i);
        total += MESH_HEAD + len + m->size;
    }
    if (total > PROTO_MAX_BUNDLE)
        return fail(err, errlen, "SCENE_BUNDLE: payload of %" PRIu64 " bytes exceeds %u", total,
                    PROTO_MAX_BUNDLE);
    return 0;
}

/* Everything proto_decode would check, on the caller's structs. */
static int check_msg(const proto_msg_t *msg, char *err, size_t errlen)
{
    uint16_t type = msg->h.type;
    switch (type) {
    case PROTO_HELLO:
        return check_hello(&msg->u.hello, err, errlen);
    case PROTO_WELCOME:
        return check_welcome(&msg->u.welcome, err, errlen);
    case PROTO_REFUSE:
    case PROTO_BYE:
    case PROTO_TASK_FAILED:
        if (text_len(msg->u.text.text) > PROTO_TEXT_MAX)
            return fail(err, errlen, "%s: text longer than %d bytes", proto_type_name(type),
                        PROTO_TEXT_MAX);
        return 0;
    case PROTO_CREDIT:
        return check_credit(msg->u.credit, err, errlen);
    case PROTO_SCENE_REQUEST:
    case PROTO_HEARTBEAT:
        return 0;
    case PROTO_SCENE_BUNDLE:
        return check_bundle(&msg->u.bundle, err, errlen);
    case PROTO_TASK: {
        const proto_task_t *t = &msg->u.task;
        if (check_integrator((int)t->settings.integrator, err, errlen) != 0 ||
            check_sampler((int)t->settings.sampler, err, errlen) != 0 ||
            check_task_count(t->count, err, errlen) != 0)
            return -1;
        if (!t->records)
            return fail(err, errlen, "TASK: records is NULL");
        for (uint32_t i = 0; i < t->count; i++)
            if (check_task_record(&t->records[i], i, err, errlen) != 0)
                return -1;
        return 0;
    }
    case PROTO_RESULT: {
        const proto_result_t *r = &msg->u.result;
        if (check_result_count(r->count, err, errlen) != 0)
            return -1;
        if (r->count > 0 && !r->records)
            return fail(err, errlen, "RESULT: records is NULL");
        for (uint32_t i = 0; i < r->count; i++)
            if (check_result_record(&r->records[i], i, err, errlen) != 0)
                return -1;
        return 0;
    }
    default:
        return fail(err, errlen, "header: unknown message type %u", (unsigned)type);
    }
}

static void write_header(const proto_header_t *h, uint32_t payload_size,
                         uint8_t out[PROTO_HEADER_SIZE])
{
    uint8_t *p = out;
    p = put_u32(p, PROTO_MAGIC);
    p = put_u16(p, PROTO_VERSION);
    p = put_u16(p, h->type);
    p = put_u64(p, h->job);
    p = put_u64(p, h->task);
    p = put_u32(p, h->attempt);
    put_u32(p, payload_size);
}

static void write_hello(const proto_hello_t *h, uint8_t *p)
{
    /* NUL-padded: every byte after the id is 0, never stack garbage. */
    uint8_t build[PROTO_BUILD_SIZE] = {0};
    memcpy(build, h->build, strnlen(h->build, PROTO_BUILD_SIZE));
    p = put_u32(p, h->threads);
    put_bytes(p, build, sizeof build);
}

static void write_welcome(const proto_welcome_t *w, uint8_t *p)
{
    p = put_u32(p, w->heartbeat_ms);
    put_u32(p, w->lease_ms);
}

static void write_text(const proto_text_t *t, uint8_t *p)
{
    size_t n = text_len(t->text); /* check_msg: at most PROTO_TEXT_MAX */
    p = put_u32(p, (uint32_t)n);
    put_bytes(p, t->text, n);
}

static void write_bundle(const proto_bundle_t *b, uint8_t *p)
{
    p = put_bytes(p, b->hash, PROTO_HASH_SIZE);
    p = put_u32(p, b->json_size);
    p = put_u32(p, b->mesh_count);
    p = put_bytes(p, b->json, b->json_size);
    for (uint32_t i = 0; i < b->mesh_count; i++) {
        const proto_mesh_file_t *m = &b->meshes[i];
        size_t len = strnlen(m->name, PROTO_MAX_NAME);
        p = put_u16(p, (uint16_t)len);
        p = put_bytes(p, m->name, len);
        p = put_u32(p, m->size);
        p = put_bytes(p, m->data, m->size);
    }
}

static void write_task(const proto_task_t *t, uint8_t *p)
{
    p = put_bytes(p, t->scene_hash, PROTO_HASH_SIZE);
    p = put_u64(p, t->settings.seed);
    p = put_u8(p, (uint8_t)t->settings.integrator);
    p = put_u8(p, (uint8_t)t->settings.sampler);
    for (int i = 0; i < 2; i++)
        p = put_u8(p, 0);
    p = put_u32(p, t->settings.max_depth);
    p = put_u32(p, t->layer);
    p = put_u32(p, t->count);
    for (uint32_t i = 0; i < t->count; i++) {
        const tracer_task_t *r = &t->records[i];
        p = put_u32(p, r->pixel);
        p = put_u32(p, r->sample_count);
        p = put_u64(p, r->first_sample);
        p = put_u64(p, r->prior_count);
        for (int c = 0; c < 3; c++)
            p = put_f64(p, r->prior_sum[c]);
    }
}

static void write_result(const proto_result_t *res, uint8_t *p)
{
    p = put_u64(p, res->rays);
    p = put_u64(p, res->busy_us);
    p = put_u32(p, res->count);
    p = put_u32(p, 0);
    for (uint32_t i = 0; i < res->count; i++) {
        const tracer_result_t *r = &res->records[i];
        p = put_u32(p, r->pixel);
        p = put_u32(p, r->samples);
        p = put_u32(p, r->nonfinite);
        p = put_u32(p, r->rays);
        for (int c = 0; c < 3; c++)
            p = put_f64(p, r->sum[c]);
        p = put_f64(p, r->lum_m2);
        p = put_f64(p, r->pvar);
    }
}

static void write_payload(const proto_msg_t *msg, uint8_t *p)
{
    switch (msg->h.type) {
    case PROTO_HELLO:
        write_hello(&msg->u.hello, p);
        break;
    case PROTO_WELCOME:
        write_welcome(&msg->u.welcome, p);
        break;
    case PROTO_REFUSE:
    case PROTO_BYE:
    case PROTO_TASK_FAILED:
        write_text(&msg->u.text, p);
        break;
    case PROTO_CREDIT:
        put_u32(p, msg->u.credit);
        break;
    case PROTO_SCENE_REQUEST:
        put_bytes(p, msg->u.scene_hash, PROTO_HASH_SIZE);
        break;
    case PROTO_SCENE_BUNDLE:
        write_bundle(&msg->u.bundle, p);
        break;
    case PROTO_TASK:
        write_task(&msg->u.task, p);
        break;
    case PROTO_RESULT:
        write_result(&msg->u.result, p);
        break;
    default: /* HEARTBEAT: nothing */
        break;
    }
}

long proto_encode(const proto_msg_t *msg, uint8_t header[PROTO_HEADER_SIZE], uint8_t *payload,
                  size_t cap, char *err, size_t errlen)
{
    if (!msg || !header)
        return fail(err, errlen, "proto_encode: no message or no header buffer");
    if (check_msg(msg, err, errlen) != 0)
        return -1;
    size_t size = proto_payload_size(msg);
    if (size > cap)
        return fail(err, errlen, "%s: payload needs %zu bytes, the buffer has %zu",
                    proto_type_name(msg->h.type), size, cap);
    if (size > 0 && !payload)
        return fail(err, errlen, "%s: payload buffer is NULL", proto_type_name(msg->h.type));
    /* check_msg bounds every type's size by PROTO_MAX_BUNDLE (< 2^31), so
     * it fits a u32 field and a long. */
    write_header(&msg->h, (uint32_t)size, header);
    write_payload(msg, payload);
    return (long)size;
}

/* ---- decoder -------------------------------------------------------------- */

static int decode_hello(const uint8_t *p, size_t n, proto_hello_t *h, char *err, size_t errlen)
{
    if (n != HELLO_SIZE)
        return fail(err, errlen, "HELLO: payload is %zu bytes, expected %d", n, HELLO_SIZE);
    h->threads = get_u32(p);
    const uint8_t *b = p + 4;
    size_t len = 0;
    while (len < PROTO_BUILD_SIZE && b[len] != 0)
        len++;
    /* Bytes after the NUL would make two different byte strings name the
     * same build; one id has one encoding. */
    for (size_t i = len; i < PROTO_BUILD_SIZE; i++)
        if (b[i] != 0)
            return fail(err, errlen, "HELLO: build id has byte 0x%02x after its NUL", b[i]);
    memset(h->build, 0, sizeof h->build);
    memcpy(h->build, b, len);
    return check_hello(h, err, errlen);
}

static int decode_text(uint16_t type, const uint8_t *p, size_t n, proto_records_t *recs,
                       proto_text_t *t, char *err, size_t errlen)
{
    const char *name = proto_type_name(type);
    if (!recs)
        return fail(err, errlen, "%s: no text buffer (recs is NULL)", name);
    if (n < TEXT_HEAD)
        return fail(err, errlen, "%s: payload is %zu bytes, shorter than text_len", name, n);
    uint32_t len = get_u32(p);
    if (len > PROTO_TEXT_MAX)
        return fail(err, errlen, "%s: text_len %" PRIu32 " exceeds %d", name, len, PROTO_TEXT_MAX);
    if (n - TEXT_HEAD != len)
        return fail(err, errlen, "%s: payload is %zu bytes, text_len %" PRIu32 " needs %" PRIu32,
                    name, n, len, len + TEXT_HEAD);
    for (uint32_t i = 0; i < len; i++)
        if (p[TEXT_HEAD + i] == 0)
            return fail(err, errlen, "%s: text byte %" PRIu32 " is NUL", name, i);
    memcpy(recs->text, p + TEXT_HEAD, len);
    recs->text[len] = '\0';
    t->text = recs->text;
    return 0;
}

/* Mesh i of a bundle from *q (with *left bytes after it) into meshes[i]; q
 * and left move past it. meshes[0..i-1] are the files before it. */
static int decode_mesh(const uint8_t **q, size_t *left, uint32_t i, proto_mesh_file_t *meshes,
                       char *err, size_t errlen)
{
    proto_mesh_file_t *m = &meshes[i];
    if (*left < 2)
        return fail(err, errlen,
                    "SCENE_BUNDLE: mesh %" PRIu32 ": name_len cut off (%zu bytes left)", i, *left);
    size_t len = get_u16(*q);
    *q += 2;
    *left -= 2;
    if (len < 1 || len > PROTO_MAX_NAME)
        return fail(err, errlen, "SCENE_BUNDLE: mesh %" PRIu32 ": name_len %zu out of range 1..%d",
                    i, len, PROTO_MAX_NAME);
    if (len > *left)
        return fail(err, errlen,
                    "SCENE_BUNDLE: mesh %" PRIu32 ": name_len %zu exceeds the %zu bytes left", i,
                    len, *left);
    if (check_mesh_name((const char *)*q, len, i, err, errlen) != 0)
        return -1;
    memcpy(m->name, *q, len);
    m->name[len] = '\0';
    if (check_mesh_unique(meshes, i, err, errlen) != 0)
        return -1;
    *q += len;
    *left -= len;
    if (*left < 4)
        return fail(err, errlen, "SCENE_BUNDLE: mesh %" PRIu32 ": size cut off (%zu bytes left)", i,
                    *left);
    m->size = get_u32(*q);
    *q += 4;
    *left -= 4;
    if (m->size > PROTO_MAX_MESH_BYTES)
        return fail(err, errlen, "SCENE_BUNDLE: mesh %" PRIu32 ": size %" PRIu32 " exceeds %u", i,
                    m->size, PROTO_MAX_MESH_BYTES);
    if (m->size > *left)
        return fail(err, errlen,
                    "SCENE_BUNDLE: mesh %" PRIu32 ": size %" PRIu32 " exceeds the %zu bytes left",
                    i, m->size, *left);
    m->data = *q;
    *q += m->size;
    *left -= m->size;
    return 0;
}

static int decode_bundle(const uint8_t *p, size_t n, proto_records_t *recs, proto_bundle_t *b,
                         char *err, size_t errlen)
{
    if (n > PROTO_MAX_BUNDLE)
        return fail(err, errlen, "SCENE_BUNDLE: payload of %zu bytes exceeds %u", n,
                    PROTO_MAX_BUNDLE);
    if (n < BUNDLE_HEAD)
        return fail(err, errlen,
                    "SCENE_BUNDLE: payload is %zu bytes, shorter than the %d-byte head", n,
                    BUNDLE_HEAD);
    memcpy(b->hash, p, PROTO_HASH_SIZE);
    b->json_size = get_u32(p + PROTO_HASH_SIZE);
    b->mesh_count = get_u32(p + PROTO_HASH_SIZE + 4);
    if (b->json_size > PROTO_MAX_SCENE_JSON)
        return fail(err, errlen, "SCENE_BUNDLE: json_size %" PRIu32 " exceeds %u", b->json_size,
                    PROTO_MAX_SCENE_JSON);
    if (b->mesh_count > PROTO_MAX_MESHES)
        return fail(err, errlen, "SCENE_BUNDLE: mesh_count %" PRIu32 " exceeds %d", b->mesh_count,
                    PROTO_MAX_MESHES);
    uint32_t capacity = recs && recs->meshes ? recs->mesh_capacity : 0;
    if (b->mesh_count > capacity)
        return fail(err, errlen,
                    "SCENE_BUNDLE: mesh_count %" PRIu32 " exceeds the receive capacity %" PRIu32,
                    b->mesh_count, capacity);
    const uint8_t *q = p + BUNDLE_HEAD;
    size_t left = n - BUNDLE_HEAD;
    if (b->json_size > left)
        return fail(err, errlen, "SCENE_BUNDLE: json_size %" PRIu32 " exceeds the %zu bytes left",
                    b->json_size, left);
    b->json = (const char *)q;
    q += b->json_size;
    left -= b->json_size;
    for (uint32_t i = 0; i < b->mesh_count; i++)
        if (decode_mesh(&q, &left, i, recs->meshes, err, errlen) != 0)
            return -1;
    b->meshes = b->mesh_count > 0 ? recs->meshes : NULL;
    if (left != 0)
        return fail(err, errlen, "SCENE_BUNDLE: %zu bytes left over after the last mesh", left);
    return 0;
}

static int decode_task(const uint8_t *p, size_t n, proto_records_t *recs, proto_task_t *t,
                       char *err, size_t errlen)
{
    uint32_t capacity = recs ? recs->task_capacity : 0;
    if (n < TASK_HEAD)
        return fail(err, errlen, "TASK: payload is %zu bytes, shorter than the %d-byte head", n,
                    TASK_HEAD);
    memcpy(t->scene_hash, p, PROTO_HASH_SIZE);
    const uint8_t *q = p + PROTO_HASH_SIZE;
    t->settings.seed = get_u64(q);
    uint8_t integrator = q[8], sampler = q[9];
    /* reserved bytes 1 and 2 (byte 0 became the sampler) */
    for (int i = 1; i < 3; i++)
        if (q[9 + i] != 0)
            return fail(err, errlen, "TASK: reserved byte %d is 0x%02x, must be 0", i, q[9 + i]);
    if (check_integrator(integrator, err, errlen) != 0 || check_sampler(sampler, err, errlen) != 0)
        return -1;
    t->settings.integrator = (scene_integrator_t)integrator;
    t->settings.sampler = (rng_sampler_t)sampler;
    t->settings.max_depth = get_u32(q + 12);
    t->layer = get_u32(q + 16);
    t->count = get_u32(q + 20);
    if (check_task_count(t->count, err, errlen) != 0)
        return -1;
    if (t->count > capacity)
        return fail(err, errlen, "TASK: count %" PRIu32 " exceeds the receive capacity %" PRIu32,
                    t->count, capacity);
    size_t want = TASK_HEAD + (size_t)PROTO_TASK_RECORD_SIZE * t->count;
    if (n != want)
        return fail(err, errlen, "TASK: payload is %zu bytes, %" PRIu32 " records need %zu", n,
                    t->count, want);
    if (!recs || !recs->tasks)
        return fail(err, errlen, "TASK: no record buffer (recs->tasks is NULL)");
    q = p + TASK_HEAD;
    for (uint32_t i = 0; i < t->count; i++, q += PROTO_TASK_RECORD_SIZE) {
        tracer_task_t *r = &recs->tasks[i];
        r->pixel = get_u32(q);
        r->sample_count = get_u32(q + 4);
        r->first_sample = get_u64(q + 8);
        r->prior_count = get_u64(q + 16);
        for (int c = 0; c < 3; c++)
            r->prior_sum[c] = get_f64(q + 24 + 8 * c);
        if (check_task_record(r, i, err, errlen) != 0)
            return -1;
    }
    t->records = recs->tasks;
    return 0;
}

static int decode_result(const uint8_t *p, size_t n, proto_records_t *recs, proto_result_t *res,
                         char *err, size_t errlen)
{
    uint32_t capacity = recs ? recs->result_capacity : 0;
    if (n < RESULT_HEAD)
        return fail(err, errlen, "RESULT: payload is %zu bytes, shorter than the %d-byte head", n,
                    RESULT_HEAD);
    res->rays = get_u64(p);
    res->busy_us = get_u64(p + 8);
    res->count = get_u32(p + 16);
    uint32_t reserved = get_u32(p + 20);
    if (reserved != 0)
        return fail(err, errlen, "RESULT: reserved field is 0x%08" PRIx32 ", must be 0", reserved);
    if (check_result_count(res->count, err, errlen) != 0)
        return -1;
    if (res->count > capacity)
        return fail(err, errlen, "RESULT: count %" PRIu32 " exceeds the receive capacity %" PRIu32,
                    res->count, capacity);
    size_t want = RESULT_HEAD + (size_t)PROTO_RESULT_RECORD_SIZE * res->count;
    if (n != want)
        return fail(err, errlen, "RESULT: payload is %zu bytes, %" PRIu32 " records need %zu", n,
                    res->count, want);
    if (res->count == 0)
        return 0;
    if (!recs || !recs->results)
        return fail(err, errlen, "RESULT: no record buffer (recs->results is NULL)");
    const uint8_t *q = p + RESULT_HEAD;
    for (uint32_t i = 0; i < res->count; i++, q += PROTO_RESULT_RECORD_SIZE) {
        tracer_result_t *r = &recs->results[i];
        r->pixel = get_u32(q);
        r->samples = get_u32(q + 4);
        r->nonfinite = get_u32(q + 8);
        r->rays = get_u32(q + 12);
        for (int c = 0; c < 3; c++)
            r->sum[c] = get_f64(q + 16 + 8 * c);
        r->lum_m2 = get_f64(q + 40);
        r->pvar = get_f64(q + 48);
        if (check_result_record(r, i, err, errlen) != 0)
            return -1;
    }
    res->records = recs->results;
    return 0;
}

/* The header frame into *h, checked against the payload frame's size: 0,
 * -1 or -2 (another version) as proto_decode. */
static int decode_header(const uint8_t *header, size_t header_size, size_t payload_size,
                         proto_header_t *h, char *err, size_t errlen)
{
    if (!header || header_size != PROTO_HEADER_SIZE)
        return fail(err, errlen, "header: %zu bytes, expected %d", header ? header_size : 0,
                    PROTO_HEADER_SIZE);
    uint32_t magic = get_u32(header);
    if (magic != PROTO_MAGIC)
        return fail(err, errlen, "header: bad magic 0x%08" PRIx32 " (expected 0x%08x)", magic,
                    PROTO_MAGIC);
    /* Magic and version sit at the same offsets in every version, so this
     * check holds whatever else another version changed. */
    uint16_t version = get_u16(header + 4);
    if (version != PROTO_VERSION) {
        fail(err, errlen, "peer speaks protocol version %u, this build speaks %d",
             (unsigned)version, PROTO_VERSION);
        return -2;
    }
    h->version = version;
    h->type = get_u16(header + 6);
    h->job = get_u64(header + 8);
    h->task = get_u64(header + 16);
    h->attempt = get_u32(header + 24);
    h->payload_size = get_u32(header + 28);
    if (h->type < 1 || h->type > PROTO_TYPE_MAX)
        return fail(err, errlen, "header: unknown message type %u", (unsigned)h->type);
    if (h->payload_size != payload_size)
        return fail(err, errlen,
                    "header: payload_size %" PRIu32 " but the payload frame has %zu "
                    "bytes",
                    h->payload_size, payload_size);
    return 0;
}

int proto_decode(const uint8_t *header, size_t header_size, const uint8_t *payload,
                 size_t payload_size, proto_msg_t *out, proto_records_t *recs, char *err,
                 size_t errlen)
{
    if (!out)
        return fail(err, errlen, "proto_decode: no output message");
    /* Every pointer in *out is set below, from this payload and recs, or
     * is NULL: none from an earlier message can be read as this one's. */
    memset(out, 0, sizeof *out);
    proto_header_t h;
    int rc = decode_header(header, header_size, payload_size, &h, err, errlen);
    if (rc != 0)
        return rc;
    if (payload_size > 0 && !payload)
        return fail(err, errlen, "payload: NULL with %zu bytes", payload_size);
    out->h = h;

    const uint8_t *p = payload;
    size_t n = payload_size;
    switch (h.type) {
    case PROTO_HELLO:
        return decode_hello(p, n, &out->u.hello, err, errlen);
    case PROTO_WELCOME:
        if (n != WELCOME_SIZE)
            return fail(err, errlen, "WELCOME: payload is %zu bytes, expected %d", n, WELCOME_SIZE);
        out->u.welcome.heartbeat_ms = get_u32(p);
        out->u.welcome.lease_ms = get_u32(p + 4);
        return check_welcome(&out->u.welcome, err, errlen);
    case PROTO_CREDIT:
        if (n != CREDIT_SIZE)
            return fail(err, errlen, "CREDIT: payload is %zu bytes, expected %d", n, CREDIT_SIZE);
        out->u.credit = get_u32(p);
        return check_credit(out->u.credit, err, errlen);
    case PROTO_SCENE_REQUEST:
        if (n != PROTO_HASH_SIZE)
            return fail(err, errlen, "SCENE_REQUEST: payload is %zu bytes, expected %d", n,
                        PROTO_HASH_SIZE);
        memcpy(out->u.scene_hash, p, PROTO_HASH_SIZE);
        return 0;
    case PROTO_SCENE_BUNDLE:
        return decode_bundle(p, n, recs, &out->u.bundle, err, errlen);
    case PROTO_TASK:
        return decode_task(p, n, recs, &out->u.task, err, errlen);
    case PROTO_RESULT:
        return decode_result(p, n, recs, &out->u.result, err, errlen);
    case PROTO_HEARTBEAT:
        if (n != 0)
            return fail(err, errlen, "HEARTBEAT: payload is %zu bytes, expected 0", n);
        return 0;
    case PROTO_REFUSE:
    case PROTO_BYE:
    case PROTO_TASK_FAILED:
        return decode_text(h.type, p, n, recs, &out->u.text, err, errlen);
    default: /* unreachable: the type was range-checked above */
        return fail(err, errlen, "header: unknown message type %u", (unsigned)h.type);
    }
}

/* ---- names ---------------------------------------------------------------- */

const char *proto_type_name(uint16_t type)
{
    static const char *const names[PROTO_TYPE_MAX + 1] = {
        "?",    "HELLO",  "WELCOME",   "REFUSE", "CREDIT",      "SCENE_REQUEST", "SCENE_BUNDLE",
        "TASK", "RESULT", "HEARTBEAT", "BYE",    "TASK_FAILED",
    };
    return type <= PROTO_TYPE_MAX ? names[type] : "?";
}

void proto_build_id(const char *isa, char out[PROTO_BUILD_SIZE + 1])
{
    char cc[32];
    /* clang defines __GNUC__ too (as 4.2), so it is asked first: a clang
     * build must not claim to be gcc 4.2 and pass for one. */
#if defined(__clang__)
    snprintf(cc, sizeof cc, "clang%d.%d", __clang_major__, __clang_minor__);
#elif defined(__GNUC__)
    snprintf(cc, sizeof cc, "gcc%d.%d", __GNUC__, __GNUC_MINOR__);
#else
    snprintf(cc, sizeof cc, "cc");
#endif
    /* A longer id is cut to PROTO_BUILD_SIZE, as proto.h promises. */
    if (snprintf(out, PROTO_BUILD_SIZE + 1, "vbrender-p%d-t%d-%s-%s", PROTO_VERSION, TRACER_VERSION,
                 isa ? isa : "?", cc) > PROTO_BUILD_SIZE)
        out[PROTO_BUILD_SIZE] = '\0';
    /* The id goes into HELLO, which only carries printable ASCII; an odd
     * ISA string must not make this build unable to say hello. */
    for (char *c = out; *c; c++)
        if (!printable((unsigned char)*c))
            *c = '?';
}

static void hash_u32(crypto_generichash_state *hs, uint32_t v)
{
    uint8_t b[4] = {(uint8_t)v, (uint8_t)(v >> 8), (uint8_t)(v >> 16), (uint8_t)(v >> 24)};
    crypto_generichash_update(hs, b, 4);
}

void proto_bundle_hash(const proto_bundle_t *b, uint8_t out[PROTO_HASH_SIZE])
{
    crypto_generichash_state hs;
    crypto_generichash_init(&hs, NULL, 0, PROTO_HASH_SIZE);
    hash_u32(&hs, b->json_size);
    hash_u32(&hs, b->mesh_count);
    crypto_generichash_update(&hs, (const unsigned char *)b->json, b->json_size);
    for (uint32_t k = 0; k < b->mesh_count; k++) {
        const proto_mesh_file_t *m = &b->meshes[k];
        uint32_t len = (uint32_t)strlen(m->name);
        hash_u32(&hs, len);
        crypto_generichash_update(&hs, (const unsigned char *)m->name, len);
        hash_u32(&hs, m->size);
        crypto_generichash_update(&hs, m->data, m->size);
    }
    crypto_generichash_final(&hs, out, PROTO_HASH_SIZE);
}

void proto_host_build_id(char out[PROTO_BUILD_SIZE + 1])
{
    __builtin_cpu_init();
    proto_build_id(__builtin_cpu_supports("avx2") ? "avx2" : "sse4.2", out);
}
