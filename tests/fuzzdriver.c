/* fuzzdriver.c - see fuzzdriver.h. */
#include "fuzzdriver.h"

#include <dirent.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

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
        input in = {NULL, NULL, 0};
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

uint64_t fuzz_rnd(uint64_t *s)
{
    *s ^= *s >> 12;
    *s ^= *s << 25;
    *s ^= *s >> 27;
    return *s * UINT64_C(2685821657736338717);
}

size_t fuzz_rnd_below(uint64_t *s, size_t n)
{
    return n ? (size_t)(fuzz_rnd(s) % n) : 0;
}

void fuzz_insert(fuzz_buf_t *b, size_t at, const void *p, size_t n)
{
    if (at > b->n || n > FUZZ_MAX_INPUT - b->n)
        return;
    memmove(b->d + at + n, b->d + at, b->n - at);
    memcpy(b->d + at, p, n);
    b->n += n;
}

void fuzz_erase(fuzz_buf_t *b, size_t at, size_t n)
{
    if (at > b->n)
        return;
    if (n > b->n - at)
        n = b->n - at;
    memmove(b->d + at, b->d + at + n, b->n - at - n);
    b->n -= n;
}

void fuzz_mutate_bytes(fuzz_buf_t *b, uint64_t *s, unsigned kind, const char *const *tokens,
                       size_t ntokens)
{
    size_t n = b->n;
    switch (kind) {
    case 0:
        if (n)
            b->d[fuzz_rnd_below(s, n)] ^= (unsigned char)(1u << (fuzz_rnd(s) % 8));
        break;
    case 1:
        if (n)
            b->d[fuzz_rnd_below(s, n)] = (unsigned char)fuzz_rnd(s);
        break;
    case 2:
        b->n = fuzz_rnd_below(s, n + 1);
        break;
    default: {
        unsigned char r[8];
        size_t at = fuzz_rnd_below(s, n + 1);
        if (fuzz_rnd(s) & 1) {
            const char *t = tokens[fuzz_rnd_below(s, ntokens)];
            fuzz_insert(b, at, t, strlen(t));
        } else {
            size_t k = 1 + fuzz_rnd_below(s, sizeof r);
            for (size_t i = 0; i < k; i++)
                r[i] = (unsigned char)fuzz_rnd(s);
            fuzz_insert(b, at, r, k);
        }
        break;
    }
    }
}

void fuzz_dup_chunk(fuzz_buf_t *b, uint64_t *s)
{
    size_t n = b->n;
    if (!n)
        return;
    size_t from = fuzz_rnd_below(s, n),
           len = 1 + fuzz_rnd_below(s, n - from < 256 ? n - from : 256);
    unsigned char tmp[256];
    memcpy(tmp, b->d + from, len);
    fuzz_insert(b, fuzz_rnd_below(s, n + 1), tmp, len);
}

void fuzz_del_chunk(fuzz_buf_t *b, uint64_t *s)
{
    if (b->n)
        fuzz_erase(b, fuzz_rnd_below(s, b->n), 1 + fuzz_rnd_below(s, 64));
}

static int is_num_char(unsigned char ch)
{
    return (ch >= '0' && ch <= '9') || ch == '.' || ch == '-' || ch == '+' || ch == 'e';
}

void fuzz_replace_number(fuzz_buf_t *b, uint64_t *s, const char *const *numbers, size_t nnumbers)
{
    size_t n = b->n;
    if (!n)
        return;
    size_t at = fuzz_rnd_below(s, n), tries = 0;
    while (at < n && !(b->d[at] >= '0' && b->d[at] <= '9') && tries++ < 256)
        at++;
    if (at >= n || !(b->d[at] >= '0' && b->d[at] <= '9'))
        return;
    while (at > 0 && is_num_char(b->d[at - 1]))
        at--;
    size_t end = at;
    while (end < n && is_num_char(b->d[end]))
        end++;
    const char *t = numbers[fuzz_rnd_below(s, nnumbers)];
    fuzz_erase(b, at, end - at);
    fuzz_insert(b, at, t, strlen(t));
}

/* A CORPUS_DIR whose last component is "fuzz" (with or without a trailing
 * slash) gets the target's suffix: `make test` passes every target the same
 * folder. */
static void corpus_dir(const char *arg, const char *suffix, char *out, size_t len)
{
    size_t n = strlen(arg);
    while (n > 1 && arg[n - 1] == '/')
        n--;
    int is_fuzz = n >= 4 && memcmp(arg + n - 4, "fuzz", 4) == 0 && (n == 4 || arg[n - 5] == '/');
    snprintf(out, len, "%.*s%s", (int)n, arg, is_fuzz && suffix ? suffix : "");
}

/* Runs an exact-size copy: no slack after the end for a bad read to hit. */
static int run_copy(const fuzz_target_t *t, const unsigned char *data, size_t size)
{
    unsigned char *copy = malloc(size ? size : 1);
    if (!copy)
        abort();
    memcpy(copy, data, size);
    int r = t->run_one(copy, size);
    free(copy);
    return r;
}

int fuzz_main(int argc, char **argv, const fuzz_target_t *t)
{
    if (argc != 3) {
        fprintf(stderr, "usage: %s CORPUS_DIR N\n", argv[0]);
        return 2;
    }
    char *endp = NULL;
    long long iters = strtoll(argv[2], &endp, 10);
    if (!endp || *endp != '\0' || iters < 0) {
        fprintf(stderr, "%s: N must be a non-negative integer\n", t->name);
        return 2;
    }
    char dir[4096];
    corpus_dir(argv[1], t->corpus_suffix, dir, sizeof dir);
    corpus c = {NULL, 0, 0};
    if (load_corpus(dir, &c) != 0 || c.n == 0) {
        fprintf(stderr, "%s: no corpus files in %s\n", t->name, dir);
        corpus_free(&c);
        return 2;
    }
    fuzz_buf_t *b = malloc(sizeof *b);
    if (!b) {
        corpus_free(&c);
        return 2;
    }
    for (size_t i = 0; i < c.n; i++) {
        int r = run_copy(t, c.v[i].data, c.v[i].size);
        printf("  %-28s %s\n", c.v[i].name,
               r & 1   ? (t->outcomes[0] ? t->outcomes[0] : "accepted")
               : r & 2 ? (t->outcomes[1] ? t->outcomes[1] : "accepted")
                       : "refused");
    }
    long long counts[2] = {0, 0};
    uint64_t seed = UINT64_C(0x9E3779B97F4A7C15);
    for (long long it = 0; it < iters; it++) {
        const input *src = &c.v[fuzz_rnd_below(&seed, c.n)];
        b->n = src->size < FUZZ_MAX_INPUT ? src->size : FUZZ_MAX_INPUT;
        memcpy(b->d, src->data, b->n);
        /* Mostly one mutation, sometimes a few: single changes keep most of
         * the structure and so reach deeper into the parser. */
        do
            t->mutate(b, &seed);
        while (fuzz_rnd(&seed) % 3 == 0);
        if (t->after_mutate)
            t->after_mutate(b, &seed);
        int r = run_copy(t, b->d, b->n);
        counts[0] += r & 1;
        counts[1] += (r >> 1) & 1;
    }
    printf("%s: %zu corpus files in %s, %lld mutations (%lld %s", t->name, c.n, dir, iters,
           counts[0], t->outcomes[0] ? t->outcomes[0] : "accepted");
    if (t->outcomes[1])
        printf(", %lld %s", counts[1], t->outcomes[1]);
    printf("), no crash\n");
    free(b);
    corpus_free(&c);
    return 0;
}

int fuzz_mutate_shared(fuzz_buf_t *b, uint64_t *s, unsigned kind, const char *const *tokens,
                       size_t ntokens)
{
    if (kind <= 3)
        fuzz_mutate_bytes(b, s, kind, tokens, ntokens);
    else if (kind == 4)
        fuzz_dup_chunk(b, s);
    else if (kind == 5)
        fuzz_del_chunk(b, s);
    else
        return 0;
    return 1;
}
