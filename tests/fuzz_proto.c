/* fuzz_proto.c - fuzz target for the wire protocol decoder (proto/proto.c).
 *
 * An input is one byte H, then the two frames: the first min(H, rest)
 * bytes are the header frame, the others the payload frame. Each frame is
 * copied into a buffer of exactly its size so ASan sees any read past the
 * end of either. LLVMFuzzerTestOneInput decodes with a capacity of 64
 * records and aborts if a result breaks the API's promises: rc is 0, -1 or
 * -2, a failure has a message, counts stay within the capacity, bundle
 * pointers stay inside the payload, and an accepted message re-encodes to
 * exactly the bytes it came from (one message, one encoding). Build with
 * -DVB_LIBFUZZER and -fsanitize=fuzzer for libFuzzer.
 *
 * Without VB_LIBFUZZER this file also has a standalone driver, so the target
 * runs in every `make test` with no fuzzing engine:
 *
 *     fuzz_proto CORPUS_DIR N
 *
 * runs every file in CORPUS_DIR, then N deterministic mutations of them
 * (fixed seed: a failure reproduces exactly). `make test` passes every fuzz
 * target the same folder name, tests/data/fuzz, and each reads its own
 * corpus beside it: here "fuzz-proto" (tests/data/fuzz-proto: the valid
 * vectors of proto/vectors/ as raw inputs, written by
 * proto/vectors/gen-vectors.py).
 */
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "proto.h"

#define FUZZ_CAPACITY 64

/* Checks a decoded message; any breach is a bug, so abort. */
static void check_result(int rc, const proto_msg_t *m, const proto_records_t *recs, const char *err,
                         const uint8_t *h, size_t hn, const uint8_t *p, size_t pn)
{
    if (rc != 0) {
        if ((rc != -1 && rc != -2) || err[0] == '\0')
            abort();
        return;
    }
    if (hn != PROTO_HEADER_SIZE || m->h.payload_size != pn || m->h.version != PROTO_VERSION)
        abort();
    if (m->h.type == PROTO_TASK && (m->u.task.count < 1 || m->u.task.count > FUZZ_CAPACITY ||
                                    m->u.task.records != recs->tasks))
        abort();
    /* every other pointer lands in the caller's buffers, never elsewhere */
    if (m->h.type == PROTO_RESULT && m->u.result.count > 0 && m->u.result.records != recs->results)
        abort();
    if (m->h.type == PROTO_RESULT && m->u.result.count > FUZZ_CAPACITY)
        abort();
    if (m->h.type == PROTO_SCENE_BUNDLE) {
        const proto_bundle_t *b = &m->u.bundle;
        const uint8_t *end = p + pn;
        const uint8_t *json = (const uint8_t *)b->json;
        if (b->mesh_count > PROTO_MAX_MESHES || json < p || b->json_size > (size_t)(end - json))
            abort();
        for (uint32_t i = 0; i < b->mesh_count; i++) {
            const proto_mesh_file_t *f = &b->meshes[i];
            size_t len = strnlen(f->name, sizeof f->name);
            if (len < 1 || len > PROTO_MAX_NAME || strchr(f->name, '/') || strchr(f->name, '\\'))
                abort();
            if (f->data < p || f->size > (size_t)(end - f->data))
                abort();
        }
    }
    /* Re-encode: the same bytes, or the decoder let something through that
     * the encoder would not send (or lost a bit on the way). */
    uint8_t hdr[PROTO_HEADER_SIZE];
    uint8_t *buf = malloc(pn ? pn : 1);
    char err2[256];
    if (!buf)
        abort();
    long n = proto_encode(m, hdr, buf, pn, err2, sizeof err2);
    if (n != (long)pn || memcmp(hdr, h, PROTO_HEADER_SIZE) != 0 || (pn && memcmp(buf, p, pn) != 0))
        abort();
    free(buf);
}

/* 1 if the input decoded, 0 if it was refused. */
static int run_one(const uint8_t *data, size_t size)
{
    if (size == 0)
        return 0;
    size_t rest = size - 1;
    size_t hn = data[0] < rest ? data[0] : rest;
    size_t pn = rest - hn;
    /* Separate exact-size copies: a header read past its end must not land
     * harmlessly in the payload. */
    uint8_t *h = malloc(hn ? hn : 1), *p = malloc(pn ? pn : 1);
    tracer_task_t *tasks = calloc(FUZZ_CAPACITY, sizeof *tasks);
    tracer_result_t *results = calloc(FUZZ_CAPACITY, sizeof *results);
    proto_mesh_file_t *meshes = calloc(PROTO_MAX_MESHES, sizeof *meshes);
    proto_records_t *recs = calloc(1, sizeof *recs);
    if (!h || !p || !tasks || !results || !meshes || !recs)
        abort();
    memcpy(h, data + 1, hn);
    memcpy(p, data + 1 + hn, pn);
    *recs = (proto_records_t){.tasks = tasks,
                              .task_capacity = FUZZ_CAPACITY,
                              .results = results,
                              .result_capacity = FUZZ_CAPACITY,
                              .meshes = meshes,
                              .mesh_capacity = PROTO_MAX_MESHES};
    proto_msg_t m;
    char err[256];
    err[0] = '\0';
    int rc = proto_decode(h, hn, p, pn, &m, recs, err, sizeof err);
    check_result(rc, &m, recs, err, h, hn, p, pn);
    free(recs);
    free(meshes);
    free(results);
    free(tasks);
    free(p);
    free(h);
    return rc == 0;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    run_one(data, size);
    return 0;
}

#ifndef VB_LIBFUZZER

#include "fuzzdriver.h"

static void put_le(unsigned char *p, uint64_t v, int bytes)
{
    for (int i = 0; i < bytes; i++)
        p[i] = (unsigned char)(v >> (8 * i));
}

/* Makes the header's payload_size agree with the payload again, so that a
 * change to the payload reaches the payload's decoder instead of dying at
 * the header's size check. */
static void fix_payload_size(fuzz_buf_t *b, uint64_t *s)
{
    /* three in four: a payload change reaches the payload decoder */
    if (fuzz_rnd(s) % 4 == 0)
        return;
    if (b->n < 1 + PROTO_HEADER_SIZE || b->d[0] != PROTO_HEADER_SIZE)
        return;
    put_le(b->d + 1 + 28, b->n - 1 - PROTO_HEADER_SIZE, 4);
}

static void mutate(fuzz_buf_t *b, uint64_t *s)
{
    static const uint32_t words[] = {
        0u,          1u,          2u,          3u,          0x7Fu,       0x80u,       0xFFu,
        0x100u,      0xFFFFu,     0x10000u,    0x10001u,    64u,         65u,         128u,
        129u,        1024u,       1025u,       4096u,       4097u,       3600000u,    3600001u,
        0x7FFFFFFFu, 0x80000000u, 0xFFFFFFFFu, 0x04000000u, 0x04000001u, 0x40000001u, 0x60000001u,
        PROTO_MAGIC, 2u,          12u,
    };
    static const uint64_t dwords[] = {
        UINT64_C(0x7FF8000000000000), /* NaN */
        UINT64_C(0xFFF8000000000000), /* -NaN */
        UINT64_C(0x7FF0000000000000), /* +Inf */
        UINT64_C(0xFFF0000000000000), /* -Inf */
        UINT64_C(0xBFF0000000000000), /* -1.0 */
        UINT64_C(0x8000000000000000), /* -0.0 */
        UINT64_C(0x7FEFFFFFFFFFFFFF), /* DBL_MAX */
        UINT64_C(0x0000000000000001), /* smallest subnormal */
        UINT64_C(0xFFFFFFFFFFFFFFFF), UINT64_C(0xFFFFFFFFFFFFF000),
    };
    static const char *const tokens[] = {"/", "\\", "..", ".", "\x7f", "a.obj", "\xc3\xa9"};
    size_t n = b->n;
    unsigned kind = (unsigned)(fuzz_rnd(s) % 11);
    if (fuzz_mutate_shared(b, s, kind, tokens, sizeof tokens / sizeof tokens[0]))
        return;
    switch (kind) {
    case 6: /* another header length now and then */
        if (n)
            b->d[0] = (unsigned char)(fuzz_rnd(s) % 4 ? PROTO_HEADER_SIZE + fuzz_rnd_below(s, 3) - 1
                                                      : fuzz_rnd(s));
        break;
    case 7:
    case 8: { /* an awkward u32 at a 4-byte-aligned field of either frame */
        if (n < 5)
            break;
        size_t at = 1 + 4 * fuzz_rnd_below(s, (n - 1) / 4);
        if (at + 4 <= n)
            put_le(b->d + at, words[fuzz_rnd_below(s, sizeof words / sizeof words[0])], 4);
        break;
    }
    case 9: { /* an awkward f64 or u64 anywhere */
        if (n < 9)
            break;
        size_t at = 1 + fuzz_rnd_below(s, n - 8);
        put_le(b->d + at, dwords[fuzz_rnd_below(s, sizeof dwords / sizeof dwords[0])], 8);
        break;
    }
    default: { /* a u16 (version, type, name_len) */
        if (n < 3)
            break;
        size_t at = 1 + fuzz_rnd_below(s, n - 2);
        static const uint16_t shorts[] = {0, 1, 2, 11, 12, 128, 129, 0xFFFF};
        put_le(b->d + at, shorts[fuzz_rnd_below(s, sizeof shorts / sizeof shorts[0])], 2);
        break;
    }
    }
}

int main(int argc, char **argv)
{
    static const fuzz_target_t target = {"fuzz_proto",     run_one,           mutate,
                                         fix_payload_size, {"decoded", NULL}, "-proto"};
    return fuzz_main(argc, argv, &target);
}

#endif /* VB_LIBFUZZER */
