/* fuzzdriver.h - the standalone fuzz driver shared by the fuzz targets, so
 * every `make test` runs them with no fuzzing engine:
 *
 *     fuzz_X CORPUS_DIR N
 *
 * runs every file in CORPUS_DIR (sorted by name), then N deterministic
 * mutations of them (fixed seed: a failure reproduces exactly). A target
 * gives its run function (which aborts on a broken promise; ASan and UBSan
 * catch the rest) and its own mutations, built from the helpers here. */
#ifndef VB_FUZZDRIVER_H
#define VB_FUZZDRIVER_H

#include <stddef.h>
#include <stdint.h>

#define FUZZ_MAX_INPUT (256 * 1024)

typedef struct fuzz_buf {
    unsigned char d[FUZZ_MAX_INPUT];
    size_t n;
} fuzz_buf_t;

typedef struct fuzz_target {
    const char *name;
    /* runs one input; returns a bit mask of outcomes (bit k counted under
     * outcomes[k]; 0: refused) */
    int (*run_one)(const uint8_t *data, size_t size);
    void (*mutate)(fuzz_buf_t *b, uint64_t *seed);
    void (*after_mutate)(fuzz_buf_t *b, uint64_t *seed); /* may be NULL */
    const char *outcomes[2];                             /* e.g. "as .ply"; NULL: unused */
    const char *corpus_suffix; /* a CORPUS_DIR ending in "fuzz" gets this added (or NULL) */
} fuzz_target_t;

int fuzz_main(int argc, char **argv, const fuzz_target_t *t);

/* The mutations every target starts with, by kind: 0-3 byte-level (see
 * fuzz_mutate_bytes, with the target's tokens), 4 a chunk duplicated, 5 a
 * chunk deleted. Returns 1 when it handled kind, 0 for kinds of the
 * target's own (6 and up). */
int fuzz_mutate_shared(fuzz_buf_t *b, uint64_t *s, unsigned kind, const char *const *tokens,
                       size_t ntokens);

/* xorshift64*: small, fast and the same on every host. */
uint64_t fuzz_rnd(uint64_t *s);
size_t fuzz_rnd_below(uint64_t *s, size_t n);
void fuzz_insert(fuzz_buf_t *b, size_t at, const void *p, size_t n);
void fuzz_erase(fuzz_buf_t *b, size_t at, size_t n);

/* The mutations every target uses, by kind: 0 flip a bit, 1 random byte,
 * 2 truncate, 3 insert a few random bytes or one of the target's tokens. */
void fuzz_mutate_bytes(fuzz_buf_t *b, uint64_t *s, unsigned kind, const char *const *tokens,
                       size_t ntokens);
/* Structural ones: copy a chunk of up to 256 bytes somewhere else (a
 * repeated record, key or frame); delete up to 64 bytes. */
void fuzz_dup_chunk(fuzz_buf_t *b, uint64_t *s);
void fuzz_del_chunk(fuzz_buf_t *b, uint64_t *s);
/* Text formats: the number (digits . - + e) at or after a random place,
 * within 256 bytes, becomes one of numbers. */
void fuzz_replace_number(fuzz_buf_t *b, uint64_t *s, const char *const *numbers, size_t nnumbers);

#endif
