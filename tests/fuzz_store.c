/* fuzz_store.c - fuzz target for the master's state files (master/store.c
 * records, and what master/persist.c reads out of each kind).
 *
 * An input is one byte K, then the bytes. K & 3 picks the kind asked for
 * (meta, submit, checkpoint, final); K & 4 clear: the bytes are a whole
 * file, handed to store_rec_parse as they are (torn, corrupt, another
 * kind...); K & 4 set: the bytes are a payload, sealed into a sound record
 * first (fuzzmaster.h), so that the fuzzer gets past the checksum to the
 * payload's decoder. A record that parses is then read as the master reads
 * that kind at startup:
 *
 *   meta        the next job id and the boot count (store_open)
 *   submit      the request JSON and its frames as blocks, then
 *               submit_parse (recover_submitted)
 *   checkpoint  the counters' JSON block (persist_apply_extras), then the
 *               scheduler stream (sched_load) with fuzzmaster.h's config A;
 *               fuzz_ckpt goes deeper into checkpoints
 *   final       the closing status JSON and its state (recover_ended)
 *
 * Aborts on a broken promise: a refusal with a message and no data, an
 * accepted record whose payload is exactly the bytes between header and
 * trailer, a whole file accepted as more than one kind. Build with
 * -DVB_LIBFUZZER and -fsanitize=fuzzer for libFuzzer.
 *
 * Without VB_LIBFUZZER the standalone driver (fuzzdriver.h) runs it:
 *
 *     fuzz_store CORPUS_DIR N      (tests/data/fuzz-store, by gen_fuzz_seeds)
 */
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fuzzmaster.h"
#include "master_priv.h"

static const store_kind_t kinds[4] = {STORE_KIND_META, STORE_KIND_SUBMIT, STORE_KIND_CHECKPOINT,
                                      STORE_KIND_FINAL};

/* recover_submitted's reading of a submit record: the request as a block,
 * a u32 frame count, the frames as blocks. 1 if a job was made. */
static int read_submit(store_rec_t *rec)
{
    const uint8_t *text;
    size_t len;
    uint32_t n = 0;
    submit_frame_t frames[PROTO_MAX_MESHES + 4];
    if (store_rec_read_block(rec, &text, &len) < 0 || store_rec_read(rec, &n, sizeof n) < 0 ||
        n > PROTO_MAX_MESHES + 4)
        return 0;
    for (uint32_t i = 0; i < n; i++) {
        const uint8_t *d;
        if (store_rec_read_block(rec, &d, &frames[i].size) < 0)
            return 0;
        if (d < rec->data || frames[i].size > rec->size ||
            d + frames[i].size > rec->data + rec->size)
            abort();
        frames[i].data = d;
    }
    cJSON *req = cJSON_ParseWithLength((const char *)text, len);
    job_t *j = NULL;
    if (req && !fuzz_submit_too_big(req, n ? frames[0].data : "", n ? frames[0].size : 0)) {
        char err[VB_ERR_LEN];
        err[0] = '\0';
        j = submit_parse(req, frames, (int)n, NULL, err, sizeof err);
        if (!j && err[0] == '\0')
            abort();
        if (j && (j->json_size != frames[0].size || !j->sched))
            abort();
    }
    int made = j != NULL;
    job_free(j);
    cJSON_Delete(req);
    return made;
}

/* recover_progress's reading of a checkpoint: the counters, then the
 * scheduler. 1 if the scheduler loaded. */
static int read_checkpoint(store_rec_t *rec)
{
    const uint8_t *text;
    size_t len;
    cJSON *extras = NULL;
    if (store_rec_read_block(rec, &text, &len) < 0 ||
        !(extras = cJSON_ParseWithLength((const char *)text, len)))
        return 0;
    job_t *j = calloc(1, sizeof *j);
    if (!j)
        abort();
    persist_apply_extras(j, extras);
    if (j->series_n > j->series_cap)
        abort();
    sched_config_t cfg;
    fuzz_ckpt_config(0, &cfg);
    char err[VB_ERR_LEN];
    err[0] = '\0';
    sched_t *s = sched_load(&cfg, store_rec_read, rec, err, sizeof err);
    if (!s && err[0] == '\0')
        abort();
    int loaded = s != NULL;
    sched_destroy(&s);
    job_free(j);
    cJSON_Delete(extras);
    return loaded;
}

/* recover_ended's reading of a final record. */
static void read_final(store_rec_t *rec)
{
    const uint8_t *text;
    size_t len;
    if (store_rec_read_block(rec, &text, &len) < 0)
        return;
    cJSON *st = cJSON_ParseWithLength((const char *)text, len);
    const cJSON *state = cJSON_GetObjectItemCaseSensitive(st, "state");
    for (int i = JOB_DONE; cJSON_IsString(state) && i <= JOB_CANCELLED; i++)
        if (strcmp(state->valuestring, job_state_names[i]) == 0)
            break;
    cJSON_Delete(st);
}

/* Bit 0: the record parsed; bit 1: its payload decoded (a job, a
 * scheduler). */
static int run_one(const uint8_t *data, size_t size)
{
    if (size == 0)
        return 0;
    store_kind_t kind = kinds[data[0] & 3];
    int seal = (data[0] & 4) != 0;
    size_t n = size - 1 + (seal ? FUZZ_REC_HEADER + FUZZ_REC_TRAILER : 0);
    uint8_t *file = malloc(n ? n : 1);
    if (!file)
        abort();
    if (seal)
        fuzz_seal_record(kind, data + 1, size - 1, file);
    else
        memcpy(file, data + 1, size - 1);
    store_rec_t rec;
    char err[256];
    err[0] = '\0';
    int out = 0;
    int r = store_rec_parse(file, n, kind, &rec, err, sizeof err);
    if (r != 0) {
        if (r != -1 || rec.data || err[0] == '\0')
            abort();
    } else {
        if (rec.pos != 0 || n < FUZZ_REC_HEADER + FUZZ_REC_TRAILER ||
            rec.size != n - FUZZ_REC_HEADER - FUZZ_REC_TRAILER ||
            (rec.size && memcmp(rec.data, file + FUZZ_REC_HEADER, rec.size) != 0))
            abort();
        for (int k = 0; k < 4; k++) {
            store_rec_t other;
            if (kinds[k] != kind && store_rec_parse(file, n, kinds[k], &other, NULL, 0) == 0)
                abort();
        }
        out = 1;
        switch (kind) {
        case STORE_KIND_META:
            break; /* store_open: two integers when size >= 12, any values */
        case STORE_KIND_SUBMIT:
            out |= read_submit(&rec) << 1;
            break;
        case STORE_KIND_CHECKPOINT:
            out |= read_checkpoint(&rec) << 1;
            break;
        case STORE_KIND_FINAL:
            read_final(&rec);
            break;
        case STORE_KIND_SNAPSHOT:
            break; /* not among the kinds K picks: the snapshot's payload is a
                      checkpoint's with a generation after the counters */
        }
        store_rec_free(&rec);
    }
    free(file);
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
        8,
        12,
        0x7F,
        0x80,
        0xFF,
        0xFFFF,
        0x7FFFFFFF,
        0x80000000u,
        0xFFFFFFFFu,
        UINT64_C(0x100000000),
        UINT64_C(0x7FFFFFFFFFFFFFFF),
        UINT64_C(0xFFFFFFFFFFFFFFFF),
        UINT64_C(0x7FF0000000000000) /* +Inf */,
        UINT64_C(0x7FF8000000000000) /* NaN */,
    };
    static const char *const numbers[] = {
        "0",   "-1", "1e999", "1e20", "4294967296", "18446744073709551616", "9007199254740993",
        "0.5", "-0"};
    static const char *const tokens[] = {
        "\"",       ",", "[", "]", "{", "}", "null", "\"state\":\"done\"", "\"series\":[[1,2,3,4]]",
        "\"rays\":"};
    size_t n = b->n;
    unsigned kind = (unsigned)(fuzz_rnd(s) % 11);
    if (fuzz_mutate_shared(b, s, kind, tokens, sizeof tokens / sizeof tokens[0]))
        return;
    switch (kind) {
    case 6:
        fuzz_replace_number(b, s, numbers, sizeof numbers / sizeof numbers[0]);
        break;
    case 7: /* another kind, or sealed / not */
        if (n)
            b->d[0] = (unsigned char)fuzz_rnd_below(s, 8);
        break;
    default: { /* an awkward u32 or u64 anywhere (lengths, counts, fields) */
        if (n < 9)
            break;
        int bytes = fuzz_rnd(s) & 1 ? 8 : 4;
        put_le(b->d + 1 + fuzz_rnd_below(s, n - (size_t)bytes),
               words[fuzz_rnd_below(s, sizeof words / sizeof words[0])], bytes);
        break;
    }
    }
}

int main(int argc, char **argv)
{
    static const fuzz_target_t target = {"fuzz_store",          run_one, mutate, NULL,
                                         {"parsed", "decoded"}, "-store"};
    return fuzz_main(argc, argv, &target);
}

#endif /* VB_LIBFUZZER */
