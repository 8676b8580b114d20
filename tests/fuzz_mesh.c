/* fuzz_mesh.c - fuzz target for the mesh reader (common/mesh.c).
 *
 * LLVMFuzzerTestOneInput feeds one input to mesh_load_buffer twice, once
 * named .ply and once .obj, and aborts if a result breaks the API's promises
 * (indices in range, finite positions, unit normals, *out NULL and a message
 * on failure). Build with -DVB_LIBFUZZER and -fsanitize=fuzzer for libFuzzer.
 *
 * Without VB_LIBFUZZER this file also has a standalone driver, so the target
 * runs in every `make test` with no fuzzing engine:
 *
 *     fuzz_mesh CORPUS_DIR N
 *
 * runs every file in CORPUS_DIR, then N deterministic mutations of them
 * (fixed seed: a failure reproduces exactly). Each mutated input is passed in
 * a buffer of exactly its size so ASan sees any read past the end. Exit 0
 * when nothing crashed; the sanitizers turn memory errors into crashes.
 */
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <math.h>

#include "mesh.h"

/* Checks a result of mesh_load_buffer; any breach is a bug, so abort. */
static void check_result(int r, const mesh_t *m, const char *err)
{
    if (r != 0) {
        if (r != -1 || m != NULL || err[0] == '\0')
            abort();
        return;
    }
    if (!m || !m->positions || !m->indices || m->triangle_count == 0)
        abort();
    for (size_t i = 0; i < 3 * m->triangle_count; i++)
        if (m->indices[i] >= m->vertex_count)
            abort();
    for (size_t i = 0; i < 3 * m->vertex_count; i++)
        if (!isfinite(m->positions[i]))
            abort();
    if (m->normals) {
        for (size_t v = 0; v < m->vertex_count; v++) {
            const float *n = m->normals + 3 * v;
            double len = sqrt((double)n[0] * n[0] + (double)n[1] * n[1] + (double)n[2] * n[2]);
            if (!(fabs(len - 1.0) < 1e-4))
                abort();
        }
    }
}

/* Bit 0: loaded as PLY-named, bit 1: loaded as OBJ-named (for statistics). */
static int run_one(const uint8_t *data, size_t size)
{
    static const char *const names[2] = { "fuzz.ply", "fuzz.obj" };
    int loaded = 0;
    for (int i = 0; i < 2; i++) {
        char err[256];
        mesh_t *m = NULL;
        err[0] = '\0';
        int r = mesh_load_buffer(names[i], data, size, &m, err, sizeof err);
        check_result(r, m, err);
        if (r == 0)
            loaded |= 1 << i;
        mesh_destroy(&m);
    }
    return loaded;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    run_one(data, size);
    return 0;
}

#ifndef VB_LIBFUZZER

#include <dirent.h>

#define FUZZ_MAX_INPUT (256 * 1024)

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

static int is_num_char(unsigned char ch)
{
    return (ch >= '0' && ch <= '9') || ch == '.' || ch == '-' || ch == '+' || ch == 'e';
}

static void mutate(buf *b, uint64_t *s)
{
    static const char *const numbers[] = {
        "nan", "-nan", "inf", "-inf", "-1", "0", "1", "2", "3", "-2147483648", "2147483647",
        "4294967295", "4294967296", "18446744073709551615", "99999999999999999999999",
        "1e39", "-1e400", "1e-400", "255", "256", "65535", "0x10", "1.5", "", "1/2/3", "-0",
    };
    static const uint32_t words[] = {
        0u, 1u, 2u, 3u, 0x7Fu, 0x80u, 0xFFu, 0xFFFFu, 0x7FFFFFFFu, 0x80000000u, 0xFFFFFFFFu,
        0x7FC00000u /* NaN */, 0x7F800000u /* +Inf */, 0x3F800000u /* 1.0f */,
    };
    static const char *const tokens[] = {
        "\n", "\r\n", " ", "\t", "/", "#", "f ", "v ", "\nf 1 2 3\n", "\nv 1 2 3\n",
        "element edge 2\nproperty int a\n", "property list uint uint x\n",
        "property float nx\n", "element face 3\n", "end_header\n", "comment c\n", "3 0 1 2\n",
    };
    size_t n = b->n;
    switch (rnd(s) % 9) {
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
    case 4: { /* duplicate a chunk somewhere else */
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
    case 6:
    case 7: { /* replace a number (text) by an awkward one */
        if (!n)
            break;
        size_t at = rnd_below(s, n), tries = 0;
        while (at < n && !(b->d[at] >= '0' && b->d[at] <= '9') && tries++ < 256)
            at++;
        if (at >= n || !(b->d[at] >= '0' && b->d[at] <= '9'))
            break;
        while (at > 0 && is_num_char(b->d[at - 1]))
            at--;
        size_t end = at;
        while (end < n && is_num_char(b->d[end]))
            end++;
        const char *t = numbers[rnd_below(s, sizeof numbers / sizeof numbers[0])];
        erase_bytes(b, at, end - at);
        insert_bytes(b, at, t, strlen(t));
        break;
    }
    default: { /* overwrite a binary word, either byte order */
        if (n < 4)
            break;
        uint32_t w = words[rnd_below(s, sizeof words / sizeof words[0])];
        size_t at = rnd_below(s, n - 3);
        int big = (int)(rnd(s) & 1);
        for (int i = 0; i < 4; i++)
            b->d[at + (size_t)(big ? 3 - i : i)] = (unsigned char)(w >> (8 * i));
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
        fprintf(stderr, "fuzz_mesh: N must be a non-negative integer\n");
        return 2;
    }
    corpus c = { NULL, 0, 0 };
    if (load_corpus(argv[1], &c) != 0 || c.n == 0) {
        fprintf(stderr, "fuzz_mesh: no corpus files in %s\n", argv[1]);
        corpus_free(&c);
        return 2;
    }
    buf *b = malloc(sizeof *b);
    if (!b) {
        corpus_free(&c);
        return 2;
    }

    long long loaded_ply = 0, loaded_obj = 0;
    for (size_t i = 0; i < c.n; i++) {
        /* An exact-size copy: no slack after the end for a bad read to hit. */
        unsigned char *copy = malloc(c.v[i].size ? c.v[i].size : 1);
        if (!copy)
            abort();
        memcpy(copy, c.v[i].data, c.v[i].size);
        int r = run_one(copy, c.v[i].size);
        free(copy);
        printf("  %-28s %s\n", c.v[i].name, r & 1 ? "loads (as .ply)" : r & 2 ? "loads (as .obj)"
                                                                      : "rejected");
    }

    uint64_t seed = UINT64_C(0x9E3779B97F4A7C15);
    for (long long it = 0; it < iters; it++) {
        const input *src = &c.v[rnd_below(&seed, c.n)];
        b->n = src->size < FUZZ_MAX_INPUT ? src->size : FUZZ_MAX_INPUT;
        memcpy(b->d, src->data, b->n);
        /* Mostly one mutation, sometimes a few: single changes keep most
         * of the structure and so reach deeper into the parser. */
        do
            mutate(b, &seed);
        while (rnd(&seed) % 3 == 0);
        unsigned char *in = malloc(b->n ? b->n : 1);
        if (!in)
            abort();
        memcpy(in, b->d, b->n);
        int r = run_one(in, b->n);
        free(in);
        loaded_ply += r & 1;
        loaded_obj += (r >> 1) & 1;
    }
    printf("fuzz_mesh: %zu corpus files, %lld mutations (%lld loaded as .ply, %lld as .obj), "
           "no crash\n", c.n, iters, loaded_ply, loaded_obj);
    free(b);
    corpus_free(&c);
    return 0;
}

#endif /* VB_LIBFUZZER */
