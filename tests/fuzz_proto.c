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
 * target the same folder, tests/data/fuzz, which holds the mesh fuzzer's
 * corpus; so a CORPUS_DIR whose last component is "fuzz" is read as
 * "fuzz-proto" beside it (tests/data/fuzz-proto: the valid vectors of
 * proto/vectors/ as raw inputs, written by proto/vectors/gen-vectors.py).
 */
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "proto.h"

#define FUZZ_CAPACITY 64

/* Checks a decoded message; any breach is a bug, so abort. */
static void check_result(int rc, const proto_msg_t *m, const char *err, const uint8_t *h,
                         size_t hn, const uint8_t *p, size_t pn)
{
    if (rc != 0) {
        if ((rc != -1 && rc != -2) || err[0] == '\0')
            abort();
        return;
    }
    if (hn != PROTO_HEADER_SIZE || m->h.payload_size != pn || m->h.version != PROTO_VERSION)
        abort();
    if (m->h.type == PROTO_TASK && (m->u.task.count < 1 || m->u.task.count > FUZZ_CAPACITY))
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
    proto_msg_t *m = calloc(1, sizeof *m);
    if (!h || !p || !tasks || !results || !m)
        abort();
    memcpy(h, data + 1, hn);
    memcpy(p, data + 1 + hn, pn);
    m->capacity = FUZZ_CAPACITY;
    m->u.result.records = results;
    m->u.task.records = tasks;
    char err[256];
    err[0] = '\0';
    int rc = proto_decode(h, hn, p, pn, m, err, sizeof err);
    check_result(rc, m, err, h, hn, p, pn);
    free(m);
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

#include <dirent.h>

#define FUZZ_MAX_INPUT (64 * 1024)

typedef struct input {
    char *name;
    unsigned char *data;
    size_t size;
} input;

typedef struct corpus {
    input *v;
    size_t n, cap;
} corpus;

static void corpus_free(corpus *c)
{
    for (size_t i = 0; i < c->n; i++) {
        free(c->v[i].name);
        free(c->v[i].data);
    }
    free(c->v);
}

static int cmp_input(const void *a, const void *b)
{
    return strcmp(((const input *)a)->name, ((const input *)b)->name);
}

static int read_file(const char *path, unsigned char **data, size_t *size)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return -1;
    size_t cap = 4096, n = 0;
    unsigned char *buf = malloc(cap);
    while (buf) {
        if (n == cap) {
            unsigned char *nb = cap < FUZZ_MAX_INPUT ? realloc(buf, cap * 2) : NULL;
            if (!nb) {
                free(buf);
                buf = NULL;
                break;
            }
            buf = nb;
            cap *= 2;
        }
        size_t got = fread(buf + n, 1, cap - n, f);
        n += got;
        if (got == 0)
            break;
    }
    int bad = !buf || ferror(f);
    fclose(f);
    if (bad) {
        free(buf);
        return -1;
    }
    *data = buf;
    *size = n;
    return 0;
}

/* Sorted by name, so the mutation sequence does not depend on readdir order. */
static int load_corpus(const char *dir, corpus *c)
{
    DIR *d = opendir(dir);
    if (!d)
        return -1;
    struct dirent *e;
    int rc = 0;
    while ((e = readdir(d)) != NULL) {
        if (e->d_name[0] == '.')
            continue;
        char path[4096];
        if (snprintf(path, sizeof path, "%s/%s", dir, e->d_name) >= (int)sizeof path)
            continue;
        input in = { NULL, NULL, 0 };
        if (read_file(path, &in.data, &in.size) != 0)
            continue; /* a subfolder or unreadable: not an input */
        size_t len = strlen(e->d_name) + 1;
        in.name = malloc(len);
        if (c->n == c->cap) {
            size_t ncap = c->cap ? 2 * c->cap : 16;
            input *nv = realloc(c->v, ncap * sizeof *nv);
            if (nv) {
                c->v = nv;
                c->cap = ncap;
            }
        }
        if (!in.name || c->n == c->cap) {
            free(in.name);
            free(in.data);
            rc = -1;
            break;
        }
        memcpy(in.name, e->d_name, len);
        c->v[c->n++] = in;
    }
    closedir(d);
    if (rc == 0 && c->n > 0)
        qsort(c->v, c->n, sizeof *c->v, cmp_input);
    return rc;
}

/* `make test` runs every fuzz target on tests/data/fuzz; this target's
 * corpus is tests/data/fuzz-proto, so ".../fuzz" (with or without a
 * trailing slash) is taken to mean ".../fuzz-proto". Any other folder is
 * used as given. */
static void corpus_dir(const char *arg, char *out, size_t len)
{
    size_t n = strlen(arg);
    while (n > 1 && arg[n - 1] == '/')
        n--;
    int is_fuzz = n >= 4 && memcmp(arg + n - 4, "fuzz", 4) == 0 && (n == 4 || arg[n - 5] == '/');
    snprintf(out, len, "%.*s%s", (int)n, arg, is_fuzz ? "-proto" : "");
}

/* xorshift64*: small, fast and the same on every host. */
static uint64_t rnd(uint64_t *s)
{
    *s ^= *s >> 12;
    *s ^= *s << 25;
    *s ^= *s >> 27;
    return *s * UINT64_C(2685821657736338717);
}

static size_t rnd_below(uint64_t *s, size_t n)
{
    return n ? (size_t)(rnd(s) % n) : 0;
}

/* Working buffer for one mutated input. */
typedef struct buf {
    unsigned char d[FUZZ_MAX_INPUT];
    size_t n;
} buf;

static void insert_bytes(buf *b, size_t at, const void *p, size_t n)
{
    if (at > b->n || n > FUZZ_MAX_INPUT - b->n)
        return;
    memmove(b->d + at + n, b->d + at, b->n - at);
    memcpy(b->d + at, p, n);
    b->n += n;
}

static void erase_bytes(buf *b, size_t at, size_t n)
{
    if (at > b->n)
        return;
    if (n > b->n - at)
        n = b->n - at;
    memmove(b->d + at, b->d + at + n, b->n - at - n);
    b->n -= n;
}

static void put_le(unsigned char *p, uint64_t v, int bytes)
{
    for (int i = 0; i < bytes; i++)
        p[i] = (unsigned char)(v >> (8 * i));
}

/* Makes the header's payload_size agree with the payload again, so that a
 * change to the payload reaches the payload's decoder instead of dying at
 * the header's size check. */
static void fix_payload_size(buf *b)
{
    if (b->n < 1 + PROTO_HEADER_SIZE || b->d[0] != PROTO_HEADER_SIZE)
        return;
    put_le(b->d + 1 + 28, b->n - 1 - PROTO_HEADER_SIZE, 4);
}

static void mutate(buf *b, uint64_t *s)
{
    static const uint32_t words[] = {
        0u, 1u, 2u, 3u, 0x7Fu, 0x80u, 0xFFu, 0x100u, 0xFFFFu, 0x10000u, 0x10001u,
        64u, 65u, 128u, 129u, 1024u, 1025u, 4096u, 4097u, 3600000u, 3600001u,
        0x7FFFFFFFu, 0x80000000u, 0xFFFFFFFFu, 0x04000000u, 0x04000001u, 0x40000001u,
        0x60000001u, PROTO_MAGIC, 2u, 12u,
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
        UINT64_C(0xFFFFFFFFFFFFFFFF),
        UINT64_C(0xFFFFFFFFFFFFF000),
    };
    static const char *const tokens[] = { "/", "\\", "..", ".", "\x7f", "a.obj", "\xc3\xa9" };
    size_t n = b->n;
    switch (rnd(s) % 11) {
    case 0: /* flip a bit */
        if (n)
            b->d[rnd_below(s, n)] ^= (unsigned char)(1u << (rnd(s) % 8));
        break;
    case 1: /* random byte */
        if (n)
            b->d[rnd_below(s, n)] = (unsigned char)rnd(s);
        break;
    case 2: /* truncate */
        b->n = rnd_below(s, n + 1);
        break;
    case 3: { /* insert a few random bytes or a token */
        unsigned char r[8];
        size_t at = rnd_below(s, n + 1);
        if (rnd(s) & 1) {
            const char *t = tokens[rnd_below(s, sizeof tokens / sizeof tokens[0])];
            insert_bytes(b, at, t, strlen(t));
        } else {
            size_t k = 1 + rnd_below(s, sizeof r);
            for (size_t i = 0; i < k; i++)
                r[i] = (unsigned char)rnd(s);
            insert_bytes(b, at, r, k);
        }
        break;
    }
    case 4: { /* duplicate a chunk somewhere else (records, meshes) */
        if (!n)
            break;
        size_t from = rnd_below(s, n), len = 1 + rnd_below(s, n - from < 256 ? n - from : 256);
        unsigned char tmp[256];
        memcpy(tmp, b->d + from, len);
        insert_bytes(b, rnd_below(s, n + 1), tmp, len);
        break;
    }
    case 5: /* delete a chunk */
        if (n)
            erase_bytes(b, rnd_below(s, n), 1 + rnd_below(s, 64));
        break;
    case 6: /* another header length now and then */
        if (n)
            b->d[0] = (unsigned char)(rnd(s) % 4 ? PROTO_HEADER_SIZE + rnd_below(s, 3) - 1
                                                 : rnd(s));
        break;
    case 7:
    case 8: { /* an awkward u32 at a 4-byte-aligned field of either frame */
        if (n < 5)
            break;
        size_t at = 1 + 4 * rnd_below(s, (n - 1) / 4);
        if (at + 4 <= n)
            put_le(b->d + at, words[rnd_below(s, sizeof words / sizeof words[0])], 4);
        break;
    }
    case 9: { /* an awkward f64 or u64 anywhere */
        if (n < 9)
            break;
        size_t at = 1 + rnd_below(s, n - 8);
        put_le(b->d + at, dwords[rnd_below(s, sizeof dwords / sizeof dwords[0])], 8);
        break;
    }
    default: { /* a u16 (version, type, name_len) */
        if (n < 3)
            break;
        size_t at = 1 + rnd_below(s, n - 2);
        static const uint16_t shorts[] = { 0, 1, 2, 11, 12, 128, 129, 0xFFFF };
        put_le(b->d + at, shorts[rnd_below(s, sizeof shorts / sizeof shorts[0])], 2);
        break;
    }
    }
}

int main(int argc, char **argv)
{
    if (argc != 3) {
        fprintf(stderr, "usage: %s CORPUS_DIR N\n", argv[0]);
        return 2;
    }
    char *endp = NULL;
    long long iters = strtoll(argv[2], &endp, 10);
    if (!endp || *endp != '\0' || iters < 0) {
        fprintf(stderr, "fuzz_proto: N must be a non-negative integer\n");
        return 2;
    }
    char dir[4096];
    corpus_dir(argv[1], dir, sizeof dir);
    corpus c = { NULL, 0, 0 };
    if (load_corpus(dir, &c) != 0 || c.n == 0) {
        fprintf(stderr, "fuzz_proto: no corpus files in %s\n", dir);
        corpus_free(&c);
        return 2;
    }
    buf *b = malloc(sizeof *b);
    if (!b) {
        corpus_free(&c);
        return 2;
    }

    for (size_t i = 0; i < c.n; i++) {
        /* An exact-size copy: no slack after the end for a bad read to hit. */
        unsigned char *copy = malloc(c.v[i].size ? c.v[i].size : 1);
        if (!copy)
            abort();
        memcpy(copy, c.v[i].data, c.v[i].size);
        int r = run_one(copy, c.v[i].size);
        free(copy);
        printf("  %-28s %s\n", c.v[i].name, r ? "decodes" : "refused");
    }

    long long accepted = 0;
    uint64_t seed = UINT64_C(0x9E3779B97F4A7C15);
    for (long long it = 0; it < iters; it++) {
        const input *src = &c.v[rnd_below(&seed, c.n)];
        b->n = src->size < FUZZ_MAX_INPUT ? src->size : FUZZ_MAX_INPUT;
        memcpy(b->d, src->data, b->n);
        /* Mostly one mutation, sometimes a few: single changes keep most
         * of the structure and so reach deeper into the decoder. */
        do
            mutate(b, &seed);
        while (rnd(&seed) % 3 == 0);
        if (rnd(&seed) % 4 != 0)
            fix_payload_size(b);
        unsigned char *in = malloc(b->n ? b->n : 1);
        if (!in)
            abort();
        memcpy(in, b->d, b->n);
        accepted += run_one(in, b->n);
        free(in);
    }
    printf("fuzz_proto: %zu corpus files in %s, %lld mutations (%lld decoded), no crash\n", c.n,
           dir, iters, accepted);
    free(b);
    corpus_free(&c);
    return 0;
}

#endif /* VB_LIBFUZZER */
