/* fuzz_ctl.c - fuzz target for control requests as the master's control
 * handler (master/ctl.c) decodes them: the JSON request, then the binary
 * frames after it.
 *
 * An input is the request's frames, each but the last followed by
 * FUZZ_CTL_SEP (fuzzmaster.h): the JSON first, then the binary frames (for
 * submit: the scene JSON, the mesh files, the reference's three planes).
 * Each frame is copied into a buffer of exactly its size, so ASan sees a
 * read past the end of any of them.
 *
 * ctl_handle_message itself reads a ZeroMQ socket and answers on it, so it
 * is not called; what it does with the bytes is: more than PROTO_MAX_MESHES
 * + 1 binary frames are refused, the JSON is parsed (cJSON) and must be an
 * object, a "job" is read by ctl_job_id, and a submit goes to submit_parse.
 * This target does the same, calling ctl_job_id and submit_parse on every
 * object (neither looks at "cmd", so any request reaches both), and aborts
 * on a broken promise: a job id in 1..2^53, a refusal with a message, and an
 * accepted job that holds exactly the frames it was given (scene JSON, mesh
 * names and bytes, reference planes) with a scheduler and one holder per
 * task. A submission bigger than fuzz_submit_too_big allows is not parsed
 * (the size of a job, not a parsing fault). Build with -DVB_LIBFUZZER and
 * -fsanitize=fuzzer for libFuzzer.
 *
 * Without VB_LIBFUZZER the standalone driver (fuzzdriver.h) runs it:
 *
 *     fuzz_ctl CORPUS_DIR N      (tests/data/fuzz-ctl, by gen_fuzz_seeds)
 */
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fuzzmaster.h"
#include "master_priv.h"

/* ctl_handle_message keeps identity, empty, JSON and this many more. */
#define CTL_MAX_EXTRA (PROTO_MAX_MESHES + 1)

/* The first sep in p[0..n), or NULL (memmem is a GNU extension). */
static const uint8_t *find_sep(const uint8_t *p, size_t n, const char *sep, size_t seplen)
{
    for (size_t i = 0; i + seplen <= n; i++)
        if (p[i] == (uint8_t)sep[0] && memcmp(p + i, sep, seplen) == 0)
            return p + i;
    return NULL;
}

/* Checks what submit_parse returned; any breach is a bug, so abort. */
static void check_job(const job_t *j, const char *err, const cJSON *req, const submit_frame_t *f,
                      int n)
{
    if (!j) {
        if (err[0] == '\0')
            abort();
        return;
    }
    int ref = cJSON_GetObjectItemCaseSensitive(req, "reference") != NULL;
    if (j->state != JOB_QUEUED || !j->sched || n < 1 ||
        j->mesh_count != (uint32_t)(n - 1 - 3 * ref))
        abort();
    if (j->json_size != f[0].size || memcmp(j->json, f[0].data, f[0].size) != 0 ||
        j->json[j->json_size] != '\0')
        abort();
    for (uint32_t i = 0; i < j->mesh_count; i++) {
        const char *name = j->mesh_names[i];
        if (name[0] == '\0' || strlen(name) > PROTO_MAX_NAME || strchr(name, '/') ||
            strchr(name, '\\'))
            abort();
        if (j->mesh_sizes[i] != f[1 + i].size ||
            memcmp(j->mesh_data[i], f[1 + i].data, f[1 + i].size) != 0)
            abort();
    }
    size_t plane = (size_t)j->width * j->height * sizeof(float);
    for (int c = 0; c < 3; c++) {
        if (!ref != !j->ref[c])
            abort();
        if (ref && memcmp(j->ref[c], f[1 + j->mesh_count + (uint32_t)c].data, plane) != 0)
            abort();
    }
    if (j->width < 1 || j->height < 1 || j->spp < 1 || j->granularity < 1 ||
        j->granularity > TRACER_MAX_TASK_SAMPLES || !(j->time_limit >= 0) || j->target_error < 0)
        abort();
    size_t n_rid = strlen(j->request_id);
    if (strspn(j->request_id, "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_-") !=
        n_rid)
        abort();
    size_t cells = (size_t)sched_layer_count(j->sched) * sched_range_count(j->sched);
    for (size_t c = 0; c < cells; c++)
        if (j->holder[c] != 0 || j->attempt[c] != 0)
            abort();
}

/* Bit 0: a job id was read; bit 1: a submission was accepted. */
static int run_one(const uint8_t *data, size_t size)
{
    static const char sep[] = FUZZ_CTL_SEP;
    const size_t seplen = sizeof sep - 1;
    uint8_t *copy[1 + CTL_MAX_EXTRA];
    submit_frame_t frames[1 + CTL_MAX_EXTRA];
    int n = 0, overflow = 0;
    size_t at = 0;
    for (;;) {
        const uint8_t *end = find_sep(data + at, size - at, sep, seplen);
        size_t len = end ? (size_t)(end - (data + at)) : size - at;
        if (n == 1 + CTL_MAX_EXTRA) {
            overflow = 1;
            break;
        }
        copy[n] = malloc(len ? len : 1);
        if (!copy[n])
            abort();
        memcpy(copy[n], data + at, len);
        frames[n] = (submit_frame_t){copy[n], len};
        n++;
        if (!end)
            break;
        at += len + seplen;
    }
    int out = 0;
    cJSON *req = cJSON_ParseWithLength((const char *)frames[0].data, frames[0].size);
    if (!overflow && cJSON_IsObject(req)) {
        uint64_t id = 0;
        if (ctl_job_id(req, &id) == 0) {
            if (id < 1 || id > (UINT64_C(1) << 53))
                abort();
            out |= 1;
        }
        const submit_frame_t *extra = frames + 1;
        int nextra = n - 1;
        if (!fuzz_submit_too_big(req, nextra ? extra[0].data : "", nextra ? extra[0].size : 0)) {
            char err[VB_ERR_LEN];
            err[0] = '\0';
            /* the master's own caps too, small: their checks come first */
            static const submit_limits_t limits = {
                .max_bundle_bytes = 1u << 20, .max_pixels = 64 * 64, .max_spp = 1u << 16};
            job_t *j = submit_parse(req, extra, nextra, &limits, err, sizeof err);
            check_job(j, err, req, extra, nextra);
            if (j)
                out |= 2;
            job_free(j);
        }
    }
    cJSON_Delete(req);
    for (int i = 0; i < n; i++)
        free(copy[i]);
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

static void mutate(fuzz_buf_t *b, uint64_t *s)
{
    static const char *const numbers[] = {
        "0",
        "1",
        "2",
        "3",
        "-1",
        "-0",
        "0.5",
        "1.5",
        "1e999",
        "-1e999",
        "1e-400",
        "1e308",
        "64",
        "65",
        "4096",
        "4097",
        "16384",
        "16385",
        "4294967295",
        "4294967296",
        "9007199254740992",
        "9007199254740993",
        "18446744073709551616",
        "1e20",
        "0.999999",
        "0.9999999",
        "1000000",
        "1000001",
    };
    static const char *const tokens[] = {
        FUZZ_CTL_SEP,
        "\"",
        ",",
        ":",
        "{",
        "}",
        "[",
        "]",
        "null",
        "true",
        "false",
        "\"\"",
        "[]",
        "{}",
        "\"cmd\":\"submit\",",
        "\"cmd\":\"status\",",
        "\"job\":",
        "\"meshes\":[\"m.obj\"],",
        "\"reference\":true,",
        "\"request_id\":\"r-1\",",
        "\"flags\":\"0101\",",
        "\"adaptive\":\"relerr\",",
        "\"adaptive\":\"none\",",
        "\"integrator\":\"naive\",",
        "\"target_error\":0.1,",
        "\"spp\":",
        "\"granularity\":",
        "\"uniform_layers\":",
        "\"time_limit\":",
        "\"name\":",
        "\"a/b\"",
        "\"\\u0000\"",
        "\"file\":\"tri.obj\"",
        "\"width\":",
        "\"height\":",
        "{\"type\":\"sphere\",\"material\":\"m\",",
    };
    unsigned kind = (unsigned)(fuzz_rnd(s) % 9);
    if (fuzz_mutate_shared(b, s, kind, tokens, sizeof tokens / sizeof tokens[0]))
        return;
    switch (kind) {
    default:
        fuzz_replace_number(b, s, numbers, sizeof numbers / sizeof numbers[0]);
        break;
    }
}

int main(int argc, char **argv)
{
    static const fuzz_target_t target = {
        "fuzz_ctl", run_one, mutate, NULL, {"with a job id", "submitted"}, "-ctl"};
    return fuzz_main(argc, argv, &target);
}

#endif /* VB_LIBFUZZER */
