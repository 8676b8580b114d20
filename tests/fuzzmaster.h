/* fuzzmaster.h - what the fuzz targets of the master's decoders (fuzz_ctl,
 * fuzz_store, fuzz_ckpt) share with the program that writes their seed
 * inputs (tests/gen_fuzz_seeds.c):
 *
 *  - the scheduler configs a fuzzed checkpoint is loaded with: a checkpoint
 *    only loads for the config it was saved with (its fingerprint), so the
 *    seeds are saved with these same configs;
 *  - sealing a payload into a sound store record, and repairing the
 *    checkpoint stream's checksum. A mutation almost never keeps either
 *    checksum right, and a decoder checks them first (the record's) or
 *    last (the stream's): an input can ask for them to be made right, so
 *    that the fuzzer reaches what comes after. They copy store.c's record
 *    layout (with its store_sum) and sched_save.c's stream checksum;
 *    gen_fuzz_seeds compares them with the real writers' output, so a
 *    change there is noticed;
 *  - the size bound on submissions (fuzz_submit_too_big).
 */
#ifndef VB_FUZZMASTER_H
#define VB_FUZZMASTER_H

#include <cJSON.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "rng.h"
#include "sched.h"
#include "store.h"

/* fuzz_ctl's input: the frames of one control request (the JSON, then the
 * binary frames), each followed by this separator but the last. */
#define FUZZ_CTL_SEP "\n--frame\n"

#define FUZZ_CKPT_CONFIGS 3

/* Small images, every adaptive rule and option somewhere: A the thesis's
 * rule over 4 ranges; B relerr with a target error, dilation, random
 * selection and 2 replicates (a version 7 stream), one pixel a range; C
 * the variance rule with a flag sequence. */
static inline void fuzz_ckpt_config(unsigned which, sched_config_t *c)
{
    memset(c, 0, sizeof *c);
    switch (which % FUZZ_CKPT_CONFIGS) {
    case 0:
        *c = (sched_config_t){.width = 4,
                              .height = 4,
                              .spp = 24,
                              .granularity = 4,
                              .adaptive = SCHED_ADAPTIVE_THESIS,
                              .uniform_layers = UINT32_MAX,
                              .range_pixels = 4,
                              .seed = 7};
        break;
    case 1:
        *c = (sched_config_t){.width = 5,
                              .height = 3,
                              .spp = 20,
                              .granularity = 2,
                              .adaptive = SCHED_ADAPTIVE_RELERR,
                              .uniform_layers = 2,
                              .random_selection = 1,
                              .dilate = 1,
                              .seed = 3,
                              .target_error = 0.05,
                              .confidence = 0.9,
                              .target_share = 0.8,
                              .replicates = 2};
        break;
    default:
        *c = (sched_config_t){.width = 3,
                              .height = 2,
                              .spp = 14,
                              .granularity = 2,
                              .adaptive = SCHED_ADAPTIVE_VARIANCE,
                              .uniform_layers = UINT32_MAX,
                              .range_pixels = 2,
                              .flags = "0010110",
                              .seed = 11};
        break;
    }
}

/* store.c's record: header (magic, version, kind), payload, trailer
 * (payload length, store_sum of everything before the sum). */
#define FUZZ_REC_HEADER 16
#define FUZZ_REC_TRAILER 40

static inline void fuzz_put_le(uint8_t *p, uint64_t v, int bytes)
{
    for (int i = 0; i < bytes; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}

/* Writes the sound record of kind holding payload[0..n) to out (n +
 * FUZZ_REC_HEADER + FUZZ_REC_TRAILER bytes). */
static inline void fuzz_seal_record(store_kind_t kind, const uint8_t *payload, size_t n,
                                    uint8_t *out)
{
    static const uint8_t magic[8] = {'V', 'B', 'S', 'T', 'A', 'T', 'E', '\n'};
    memcpy(out, magic, 8);
    fuzz_put_le(out + 8, STORE_FORMAT_VERSION, 4);
    fuzz_put_le(out + 12, (uint32_t)kind, 4);
    if (n)
        memcpy(out + FUZZ_REC_HEADER, payload, n);
    fuzz_put_le(out + FUZZ_REC_HEADER + n, n, 8);
    store_sum_t c;
    store_sum_init(&c);
    store_sum_update(&c, out, FUZZ_REC_HEADER + n + 8);
    store_sum_final(&c, out + FUZZ_REC_HEADER + n + 8);
}

/* sched_save.c's stream checksum: 8-byte words (the last one zero-padded), each
 * folded in by a bijection, then the length, then a final mix. */
static inline uint64_t fuzz_sched_checksum(const uint8_t *p, size_t n)
{
    uint64_t h = 0, w;
    size_t i = 0;
    for (; i + 8 <= n; i += 8) {
        memcpy(&w, p + i, 8);
        h = (h ^ w) * 0x9e3779b97f4a7c15ULL;
        h ^= h >> 29;
    }
    w = 0;
    memcpy(&w, p + i, n - i);
    h = (h ^ w) * 0x9e3779b97f4a7c15ULL;
    h ^= h >> 29;
    h = (h ^ (uint64_t)n) * 0x9e3779b97f4a7c15ULL;
    h ^= h >> 29;
    return rng_mix64(h);
}

/* Makes the last 8 bytes of a checkpoint stream its checksum. */
static inline void fuzz_fix_sched_checksum(uint8_t *stream, size_t n)
{
    if (n < 8)
        return;
    uint64_t sum = fuzz_sched_checksum(stream, n - 8);
    memcpy(stream + n - 8, &sum, 8);
}

/* The master takes any image the scene format allows (2^26 pixels) and any
 * spp, and then allocates its scheduler: gigabytes for the largest, which
 * libFuzzer would report as running out of memory. That is the size of a
 * job, not a fault in its parsing; so a target skips a submission whose
 * scene (frame JSON, as the loader reads it: cJSON, first key wins) or
 * request asks for more than 64 x 64 pixels or 1024 layers. 1: skip it. */
static inline int fuzz_submit_too_big(const cJSON *req, const void *scene_json, size_t n)
{
    cJSON *scene = cJSON_ParseWithLength(scene_json, n);
    const cJSON *cam = cJSON_GetObjectItemCaseSensitive(scene, "camera");
    const cJSON *render = cJSON_GetObjectItemCaseSensitive(scene, "render");
    const cJSON *w = cJSON_GetObjectItemCaseSensitive(cam, "width");
    const cJSON *h = cJSON_GetObjectItemCaseSensitive(cam, "height");
    const cJSON *spp = cJSON_GetObjectItemCaseSensitive(req, "spp");
    const cJSON *g = cJSON_GetObjectItemCaseSensitive(req, "granularity");
    if (!cJSON_IsNumber(spp))
        spp = cJSON_GetObjectItemCaseSensitive(render, "spp");
    double pixels =
        (cJSON_IsNumber(w) ? w->valuedouble : 1) * (cJSON_IsNumber(h) ? h->valuedouble : 1);
    /* a granularity below 1 is refused whatever the spp */
    double gv = cJSON_IsNumber(g) ? (g->valuedouble >= 1 ? g->valuedouble : 1) : 32;
    double layers = (cJSON_IsNumber(spp) ? spp->valuedouble : 64) / gv;
    cJSON_Delete(scene);
    /* NaN and negative sizes are the loader's to refuse */
    return pixels > 64 * 64 || layers > 1024;
}

#endif
