/* fuzz_ckpt.c - fuzz target for checkpoints: the payload of a checkpoint
 * record as master/persist.c (recover_progress) reads it, a block of
 * counters (JSON, persist_apply_extras) and then the scheduler's stream
 * (sched_load in master/sched_save.c).
 *
 * An input is one byte K, then the payload. K & 3 picks the scheduler
 * config the job was made with (fuzzmaster.h: A, B, C; 3 is A); K & 4 set:
 * the stream's checksum (its last 8 bytes) is made right first, so that a
 * mutated stream is judged by the consistency checks alone and, when it
 * passes them, loads.
 *
 * Promises checked (abort on a breach):
 *  - a refusal has a message;
 *  - a loaded scheduler saves exactly the stream it was loaded from (one
 *    of the older version it reads, version 5, is saved as this one);
 *  - it runs: tasks handed out (some requeued) are in range and their
 *    synthetic results are accepted; it never stalls with nothing ready
 *    and nothing out; its samples stay within spp per pixel;
 *  - what it then saves loads again, when the film it was loaded with is
 *    one a render can make (film_plausible: sums and moments non-negative
 *    and well within a double's range). sched_load checks that the film is
 *    finite and adds up, not how large it is: a checkpoint may hold a sum
 *    of 1e308, and then every result for that pixel is refused (the
 *    merge would overflow): the job gets no further. Only a forged state
 *    file (both checksums right) holds such values, and store.h does not
 *    defend against forgery; nothing crashes. With such a film results
 *    may be refused here too (the task goes back).
 * So a checkpoint that passes sched_load's checks but would wedge or crash
 * the resumed job is a finding too. Build with -DVB_LIBFUZZER and
 * -fsanitize=fuzzer for libFuzzer.
 *
 * Without VB_LIBFUZZER the standalone driver (fuzzdriver.h) runs it:
 *
 *     fuzz_ckpt CORPUS_DIR N      (tests/data/fuzz-ckpt, by gen_fuzz_seeds)
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fuzzmaster.h"
#include "master_priv.h"

#define HELD_MAX 6
#define STEPS_MAX 400

/* A growing buffer that sched_save writes into. */
typedef struct membuf {
    uint8_t *p;
    size_t n, cap;
} membuf_t;

static int mem_write(void *ctx, const void *data, size_t len)
{
    membuf_t *m = ctx;
    if (len > m->cap - m->n) {
        size_t cap = m->cap ? m->cap : 4096;
        while (len > cap - m->n)
            cap *= 2;
        uint8_t *np = realloc(m->p, cap);
        if (!np)
            abort();
        m->p = np;
        m->cap = cap;
    }
    memcpy(m->p + m->n, data, len);
    m->n += len;
    return 0;
}

static uint64_t step_rnd(uint64_t *s)
{
    *s = *s * 6364136223846793005ULL + 1442695040888963407ULL;
    return *s >> 33;
}

/* A tracer's results, deterministic in the task's records and in range
 * (sched_complete refuses results past SCHED_MAX_RADIANCE a sample). */
static void fake_results(const sched_task_t *t, tracer_result_t *r)
{
    for (uint32_t i = 0; i < t->count; i++) {
        const tracer_task_t *k = &t->records[i];
        memset(&r[i], 0, sizeof r[i]);
        r[i].pixel = k->pixel;
        r[i].samples = k->sample_count;
        r[i].rays = k->sample_count * (1 + k->pixel % 4);
        for (int c = 0; c < 3; c++)
            r[i].sum[c] = 0.25 * k->sample_count * (c + 1) + 1e-4 * k->pixel +
                          1e-6 * (double)(k->prior_count % 1000);
        r[i].lum_m2 = 0.01 * k->sample_count;
        r[i].pvar = (double)((k->pixel * 7 + k->first_sample * 3) % 11);
    }
}

static void check_task(const sched_t *s, const sched_config_t *cfg, const sched_task_t *t)
{
    const uint32_t npix = cfg->width * cfg->height;
    if (t->layer >= sched_layer_count(s) || t->range >= sched_range_count(s) ||
        t->id != 1 + (uint64_t)t->layer * sched_range_count(s) + t->range || t->count < 1 ||
        t->count > npix)
        abort();
    const uint32_t reps = cfg->replicates > 1 ? cfg->replicates : 1, G = cfg->granularity;
    for (uint32_t i = 0; i < t->count; i++) {
        const tracer_task_t *k = &t->records[i];
        /* the replicate's index, and the pixel's layers taken before it
         * (rng_replicate_first_sample) */
        const uint64_t r = rng_replicate_of(k->first_sample),
                       index = k->first_sample - (r << RNG_REPLICATE_SHIFT),
                       taken = r + reps * (index / G);
        if (k->pixel >= npix || k->sample_count < 1 || k->sample_count > G || r >= reps ||
            index % G != 0 || taken > t->layer || taken * G + k->sample_count > cfg->spp)
            abort();
    }
}

/* Runs a restored scheduler for a while: hand out, requeue, complete.
 * With an implausible film (film_plausible) a merge may be refused as one
 * that would overflow it; the task goes back, as the master's would. */
static void drive(sched_t *s, const sched_config_t *cfg, uint64_t seed, int plausible)
{
    sched_task_t held[HELD_MAX];
    tracer_result_t res[64];
    char err[VB_ERR_LEN];
    int nheld = 0;
    for (int step = 0; step < STEPS_MAX; step++) {
        uint64_t r = step_rnd(&seed);
        if (nheld < HELD_MAX && r % 4 != 0) {
            sched_task_t t;
            int rc = sched_next(s, &t);
            if (rc == SCHED_NEXT_TASK) {
                check_task(s, cfg, &t);
                held[nheld++] = t;
                continue;
            }
            if (rc != SCHED_NEXT_NONE_READY && rc != SCHED_NEXT_ALL_ISSUED)
                abort();
            if (nheld == 0) {
                if (rc == SCHED_NEXT_NONE_READY)
                    abort(); /* nothing ready, nothing out: the job would wait forever */
                break;       /* every task handed out or done */
            }
        }
        if (nheld == 0)
            continue;
        int k = (int)((r >> 8) % (uint64_t)nheld);
        if ((r >> 16) % 5 == 0) {
            if (sched_requeue(s, held[k].id) != SCHED_OK)
                abort();
        } else {
            if (held[k].count > sizeof res / sizeof res[0])
                abort();
            fake_results(&held[k], res);
            int rc = sched_complete(s, held[k].id, res, held[k].count, err, sizeof err);
            if (rc != SCHED_OK && plausible) {
                fprintf(stderr, "fuzz_ckpt: a restored scheduler refuses a good result: %s\n", err);
                abort();
            }
            if (rc != SCHED_OK &&
                (rc != SCHED_BAD_RESULT || sched_requeue(s, held[k].id) != SCHED_OK))
                abort();
        }
        held[k] = held[--nheld];
    }
    if (sched_samples_done(s) > (uint64_t)cfg->spp * cfg->width * cfg->height)
        abort();
}

/* Results are non-negative and at most SCHED_MAX_RADIANCE (1e30) a sample,
 * so a render's sums and moments stay far below this. */
static int film_plausible(const film_t *f)
{
    const double big = 1e100;
    for (size_t p = 0; p < (size_t)f->width * f->height; p++) {
        const film_pixel_t *x = &f->pixels[p];
        for (int c = 0; c < 3; c++)
            if (!(x->sum[c] >= 0 && x->sum[c] <= big) || !(fabs(x->comp[c]) <= big))
                return 0;
        if (!(x->lum_m2 >= 0 && x->lum_m2 <= big))
            return 0;
    }
    return 1;
}

/* Bit 0: the counters parsed; bit 1: the scheduler loaded. */
static int run_one(const uint8_t *data, size_t size)
{
    if (size == 0)
        return 0;
    sched_config_t cfg;
    fuzz_ckpt_config((data[0] & 3) % FUZZ_CKPT_CONFIGS, &cfg);
    store_rec_t rec = {.data = malloc(size - 1 ? size - 1 : 1), .size = size - 1};
    if (!rec.data)
        abort();
    memcpy(rec.data, data + 1, size - 1);
    if ((data[0] & 4) && rec.size >= 8) {
        uint64_t len = 0;
        for (int i = 7; i >= 0; i--)
            len = len << 8 | rec.data[i];
        if (len <= rec.size - 8)
            fuzz_fix_sched_checksum(rec.data + 8 + len, rec.size - 8 - (size_t)len);
    }
    int out = 0;
    const uint8_t *text;
    size_t len;
    cJSON *extras = NULL;
    if (store_rec_read_block(&rec, &text, &len) == 0 &&
        (extras = cJSON_ParseWithLength((const char *)text, len))) {
        out = 1;
        job_t *j = calloc(1, sizeof *j);
        if (!j)
            abort();
        persist_apply_extras(j, extras);
        if (j->series_n > j->series_cap)
            abort();
        job_free(j);
        char err[VB_ERR_LEN];
        err[0] = '\0';
        size_t start = rec.pos;
        sched_t *s = sched_load(&cfg, store_rec_read, &rec, err, sizeof err);
        if (!s && err[0] == '\0')
            abort();
        if (s) {
            out |= 2;
            membuf_t m = {NULL, 0, 0};
            /* an older stream (sched_load converts version 5) is saved as
             * this version: then only its loading again is promised */
            uint32_t version = 0;
            memcpy(&version, rec.data + start + 8, sizeof version);
            if (sched_save(s, mem_write, &m) != 0 ||
                (version == SCHED_SAVE_VERSION &&
                 (m.n != rec.pos - start || memcmp(m.p, rec.data + start, m.n) != 0)))
                abort();
            int plausible = film_plausible(sched_film(s));
            drive(s, &cfg, (uint64_t)size * 0x9E3779B97F4A7C15ULL, plausible);
            m.n = 0;
            if (sched_save(s, mem_write, &m) != 0)
                abort();
            store_rec_t again = {.data = m.p, .size = m.n};
            sched_t *s2 = sched_load(&cfg, store_rec_read, &again, err, sizeof err);
            if (!s2 && plausible) {
                fprintf(stderr, "fuzz_ckpt: a resumed scheduler's checkpoint does not load: %s\n",
                        err);
                abort();
            }
            sched_destroy(&s2);
            free(m.p);
            sched_destroy(&s);
        }
    }
    cJSON_Delete(extras);
    free(rec.data);
    return out;
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

static void mutate(fuzz_buf_t *b, uint64_t *s)
{
    static const uint64_t words[] = {
        0,
        1,
        2,
        3,
        4,
        5,
        6,
        7,
        15,
        16,
        0xFF,
        0xFFFFFFFFu,
        UINT64_C(0xFFFFFFFFFFFFFFFF),
        UINT64_C(0x7FF0000000000000) /* +Inf */,
        UINT64_C(0x7FF8000000000000) /* NaN */,
        UINT64_C(0xFFF0000000000000) /* -Inf */,
        UINT64_C(0x3FF0000000000000) /* 1.0 */,
        UINT64_C(0x8000000000000000) /* -0.0 */,
        UINT64_C(0xBFF0000000000000) /* -1.0 */,
    };
    static const char *const numbers[] = {
        "0", "-1", "1e999", "1e20", "4294967296", "18446744073709551616", "1e300", "0.5"};
    static const char *const tokens[] = {"\"",
                                         ",",
                                         "[",
                                         "]",
                                         "{",
                                         "}",
                                         "null",
                                         "\"series\":[[1,2,3,4]],",
                                         "\"rays\":",
                                         "\"seconds\":",
                                         "\"failures\":"};
    size_t n = b->n;
    unsigned kind = (unsigned)(fuzz_rnd(s) % 12);
    if (fuzz_mutate_shared(b, s, kind, tokens, sizeof tokens / sizeof tokens[0]))
        return;
    switch (kind) {
    case 6:
        fuzz_replace_number(b, s, numbers, sizeof numbers / sizeof numbers[0]);
        break;
    case 7: /* one cell state, decided flag or counter byte: small values */
        if (n > 1)
            b->d[1 + fuzz_rnd_below(s, n - 1)] = (unsigned char)fuzz_rnd_below(s, 5);
        break;
    default: { /* an awkward 4- or 8-byte value, usually aligned with the stream's fields */
        if (n < 10)
            break;
        int bytes = fuzz_rnd(s) & 1 ? 8 : 4;
        size_t at = 1 + fuzz_rnd_below(s, n - 1 - (size_t)bytes);
        put_le(b->d + at, words[fuzz_rnd_below(s, sizeof words / sizeof words[0])], bytes);
        break;
    }
    }
}

/* Three in four: the stream's checksum is made right (the driver's inputs
 * say so in K; libFuzzer's leave K as the fuzzer has it). */
static void mostly_fixed(fuzz_buf_t *b, uint64_t *s)
{
    if (b->n && fuzz_rnd(s) % 4 != 0)
        b->d[0] |= 4;
}

int main(int argc, char **argv)
{
    static const fuzz_target_t target = {
        "fuzz_ckpt", run_one, mutate, mostly_fixed, {"counters read", "loaded"}, "-ckpt"};
    return fuzz_main(argc, argv, &target);
}

#endif /* VB_LIBFUZZER */
