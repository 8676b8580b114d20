/* fuzz_journal.c - fuzz target for a job's journal (master/journal.c), as
 * recovery reads it (master/persist.c, replay_journal): the header, then
 * commit by commit, each commit's tasks and their compact records.
 *
 * An input is a whole journal file. Aborts on a broken promise: a refusal
 * without a message, a read position that goes past the file or back, a
 * failed read that moves it, a commit or task that points outside the
 * input, and a commit that, re-encoded by the writer (journal_note and
 * journal_seal, with the sequence number and flags read), is not the same
 * bytes as read. Build with -DVB_LIBFUZZER and -fsanitize=fuzzer for
 * libFuzzer.
 *
 * Without VB_LIBFUZZER the standalone driver (fuzzdriver.h) runs it:
 *
 *     fuzz_journal CORPUS_DIR N      (tests/data/fuzz-journal, by gen_fuzz_seeds)
 */
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "journal.h"
#include "store.h"

static void inside(const uint8_t *p, size_t n, const uint8_t *data, size_t size)
{
    if (p < data || n > size || p + n > data + size)
        abort();
}

/* The task's records as sched_take hands them out: a sample count no
 * stored NaN/Inf count exceeds (u16). */
static const tracer_task_t any_task = {.pixel = 7, .sample_count = 65535};

static int run_one(const uint8_t *data, size_t size)
{
    journal_reader_t r;
    char err[256];
    err[0] = '\0';
    if (journal_reader_init(&r, data, size, err, sizeof err) < 0) {
        if (err[0] == '\0')
            abort();
        return 0;
    }
    int out = 1;
    journal_t *w = journal_new(r.header.job, r.header.generation, r.header.flags);
    tracer_result_t *res = NULL;
    size_t cap = 0;
    for (;;) {
        size_t before = r.pos;
        journal_commit_t c;
        err[0] = '\0';
        int rc = journal_next(&r, &c, err, sizeof err);
        if (r.pos > size || r.pos < before)
            abort();
        if (rc <= 0) {
            if ((rc < 0 && (err[0] == '\0' || r.pos != before)) || (rc == 0 && r.pos != size))
                abort();
            break;
        }
        inside(c.tasks, c.tasks_len, data, size);
        inside((const uint8_t *)c.extras, c.extras_len, data, size);
        out |= 2;
        /* re-encode: the same bytes */
        journal_tasks_t it;
        journal_tasks_init(&it, &c, r.header.flags);
        uint64_t task;
        uint32_t count;
        const uint8_t *records;
        int t, ok = w != NULL;
        while ((t = journal_task_next(&it, &task, &count, &records)) == 1) {
            inside(records, 0, data, size);
            if (count > cap) {
                tracer_result_t *nr = realloc(res, count * sizeof *nr);
                if (!nr)
                    abort();
                res = nr;
                cap = count;
            }
            for (uint32_t i = 0; i < count; i++)
                if (journal_result(records, i, r.header.flags, &any_task, &res[i]) < 0 ||
                    res[i].samples + res[i].nonfinite != any_task.sample_count)
                    abort();
            if (ok && journal_note(w, task, res, count) < 0)
                ok = 0;
        }
        if (t < 0 || !ok) {
            journal_destroy(&w);
            continue; /* malformed tasks: replay stops there */
        }
        journal_set_next_seq(w, c.seq);
        if (journal_seal(w, c.extras, c.extras_len) == 0) {
            uint8_t *bytes;
            size_t n;
            journal_take_unwritten(w, &bytes, &n);
            if (n != r.pos - before || memcmp(bytes, data + before, n) != 0)
                abort();
            free(bytes);
        }
    }
    journal_destroy(&w);
    free(res);
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

static uint64_t get_le(const unsigned char *p, int bytes)
{
    uint64_t v = 0;
    for (int i = bytes - 1; i >= 0; i--)
        v = v << 8 | p[i];
    return v;
}

static void mutate(fuzz_buf_t *b, uint64_t *s)
{
    static const uint64_t words[] = {0,  1,  2,      7,       8,          12,        20,
                                     38, 46, 0xFFFF, 0x10000, 0x7FFFFFFF, 0xFFFFFFFF};
    static const char *const tokens[] = {"VBJRNL1\n", "{\"rays\":1}", "{}", "\"series\""};
    unsigned kind = (unsigned)(fuzz_rnd(s) % 8);
    if (fuzz_mutate_shared(b, s, kind, tokens, sizeof tokens / sizeof tokens[0]))
        return;
    if (b->n < 8)
        return;
    /* an awkward length, count, sequence or flags field */
    put_le(b->d + fuzz_rnd_below(s, b->n - 3), words[fuzz_rnd_below(s, sizeof words / 8)],
           kind == 6 ? 4 : 2);
}

/* Most mutants get their records' checksums repaired, so the fuzzer gets
 * past them to the tasks. */
static void repair(fuzz_buf_t *b, uint64_t *s)
{
    if (fuzz_rnd(s) % 8 == 0)
        return;
    size_t at = JOURNAL_HEADER_SIZE;
    while (at + JOURNAL_RECORD_OVERHEAD <= b->n) {
        uint64_t plen = get_le(b->d + at, 4);
        if (plen > b->n - at - JOURNAL_RECORD_OVERHEAD)
            break;
        store_sum_t c;
        store_sum_init(&c);
        store_sum_update(&c, b->d + at, 12 + (size_t)plen);
        uint8_t sum[32];
        store_sum_final(&c, sum);
        memcpy(b->d + at + 12 + plen, sum, 8);
        at += JOURNAL_RECORD_OVERHEAD + (size_t)plen;
    }
}

int main(int argc, char **argv)
{
    static const fuzz_target_t target = {"fuzz_journal",        run_one,   mutate, repair,
                                         {"header", "commits"}, "-journal"};
    return fuzz_main(argc, argv, &target);
}

#endif /* VB_LIBFUZZER */
