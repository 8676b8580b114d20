/* sched_save.c - checkpoints: a scheduler saved as a stream (sched_save)
 * and restored from one (sched_load), versions 6 to 8 and the version 5 streams
 * of older masters, and the consistency checks a restored state must pass
 * before a job resumes from it (a corrupt or hostile file is refused with
 * the section and value that are wrong, never trusted). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "rng.h"
#include "sched_priv.h"
#include "vmath.h"

/* write and read calls carry at most this much: the pipe or socket behind
 * them need not take a gigabyte film in one call. */
#define SAVE_CHUNK ((size_t)1 << 20)

static const uint8_t save_magic[8] = {'V', 'B', 'S', 'C', 'H', 'E', 'D', '\n'};

/* The oldest stream this build still reads (sched_load_v5 below). */
#define SCHED_SAVE_VERSION_V5 5
/* Version 5's film pixel: 64-bit counts, the last eq. 4.1 value, layers. */
typedef struct film_pixel_v5 {
    uint64_t count, nonfinite;
    double sum[3], comp[3], lum_m2, pvar;
    uint32_t layers;
} film_pixel_v5_t;

/* The fingerprint: what a restored scheduler must share with the saved one
 * (settings first, so a mismatch names the setting, not what it derives). */
enum {
    FP_WIDTH,
    FP_HEIGHT,
    FP_SPP,
    FP_GRANULARITY,
    FP_ADAPTIVE,
    FP_UNIFORM,
    FP_HAS_FLAGS,
    FP_FLAGS,
    FP_RANGE_PIXELS,
    FP_RANDOM_SELECTION,
    FP_DILATE,
    FP_SEED,
    FP_TARGET_ERROR,
    FP_CONFIDENCE,
    FP_TARGET_SHARE,
    FP_PIXELS,
    FP_LAYERS,
    FP_RANGES,
    FP_PIXEL_BYTES,
    FP_COUNT
};
static const char *const fp_names[FP_COUNT] = {"width",
                                               "height",
                                               "spp",
                                               "granularity",
                                               "adaptive",
                                               "uniform layers",
                                               "flag sequence (present)",
                                               "flag sequence",
                                               "range_pixels",
                                               "random_selection",
                                               "dilate",
                                               "seed",
                                               "target_error",
                                               "confidence",
                                               "target_share",
                                               "pixels",
                                               "layers",
                                               "ranges",
                                               "film pixel size"};

static uint64_t f64_bits(double x)
{
    uint64_t u;
    memcpy(&u, &x, sizeof u);
    return u;
}

static void fingerprint(const sched_t *s, uint64_t fp[FP_COUNT], size_t pixel_bytes)
{
    uint64_t h = 0xcbf29ce484222325ULL; /* FNV-1a of the flag sequence */
    for (uint32_t l = 0; s->flags && l < s->layers; l++)
        h = (h ^ (uint8_t)s->flags[l]) * 0x100000001b3ULL;
    fp[FP_WIDTH] = s->cfg.width;
    fp[FP_HEIGHT] = s->cfg.height;
    fp[FP_SPP] = s->cfg.spp;
    fp[FP_GRANULARITY] = s->cfg.granularity;
    fp[FP_ADAPTIVE] = (uint64_t)s->cfg.adaptive;
    fp[FP_UNIFORM] = s->uniform;
    fp[FP_HAS_FLAGS] = s->flags != NULL;
    fp[FP_FLAGS] = s->flags ? h : 0;
    fp[FP_RANGE_PIXELS] = s->range_pixels;
    fp[FP_RANDOM_SELECTION] = (uint64_t)(int64_t)s->cfg.random_selection;
    fp[FP_DILATE] = (uint64_t)(int64_t)s->cfg.dilate;
    fp[FP_SEED] = s->cfg.seed;
    fp[FP_TARGET_ERROR] = f64_bits(s->cfg.target_error);
    fp[FP_CONFIDENCE] = f64_bits(s->cfg.confidence); /* as normalised by sched_new */
    fp[FP_TARGET_SHARE] = f64_bits(s->cfg.target_share);
    fp[FP_PIXELS] = s->npix;
    fp[FP_LAYERS] = s->layers;
    fp[FP_RANGES] = s->ranges;
    fp[FP_PIXEL_BYTES] = pixel_bytes;
}

/* A checksum of the stream, the same however it is cut into calls: words
 * of 8 bytes (a partial one kept back), each folded in by a bijection, so
 * one changed word always changes the sum. Not cryptographic: it catches
 * corruption that the consistency checks cannot see (a finite film value
 * with a flipped bit). */
typedef struct cksum {
    uint64_t h, total;
    uint8_t pend[8];
    unsigned npend;
} cksum_t;

static void ck_word(cksum_t *c, uint64_t w)
{
    uint64_t h = (c->h ^ w) * 0x9e3779b97f4a7c15ULL;
    c->h = h ^ (h >> 29);
}

static void ck_update(cksum_t *c, const void *data, size_t len)
{
    const uint8_t *p = data;
    uint64_t w;
    c->total += len;
    while (len > 0 && c->npend > 0) {
        c->pend[c->npend++] = *p++;
        len--;
        if (c->npend == 8) {
            memcpy(&w, c->pend, 8);
            ck_word(c, w);
            c->npend = 0;
        }
    }
    for (; len >= 8; p += 8, len -= 8) {
        memcpy(&w, p, 8);
        ck_word(c, w);
    }
    while (len > 0) { /* here npend == 0 and len < 8 */
        c->pend[c->npend++] = *p++;
        len--;
    }
}

static uint64_t ck_final(const cksum_t *c0)
{
    cksum_t c = *c0;
    uint64_t w = 0;
    memcpy(&w, c.pend, c.npend);
    ck_word(&c, w);
    ck_word(&c, c.total);
    return rng_mix64(c.h);
}

static void tag_bytes(const char *tag, uint8_t out[8])
{
    size_t n = strlen(tag);
    memset(out, 0, 8);
    memcpy(out, tag, n < 8 ? n : 8);
}

typedef struct saver {
    sched_write_fn write;
    void *ctx;
    cksum_t ck;
    int rc;
} saver_t;

static int put(saver_t *w, const void *data, size_t len)
{
    const uint8_t *p = data;
    while (len > 0 && w->rc == 0) {
        size_t n = len < SAVE_CHUNK ? len : SAVE_CHUNK;
        ck_update(&w->ck, p, n);
        w->rc = w->write(w->ctx, p, n);
        p += n;
        len -= n;
    }
    return w->rc;
}

static int put_head(saver_t *w, const char *tag, uint64_t bytes)
{
    uint8_t h[16];
    tag_bytes(tag, h);
    memcpy(h + 8, &bytes, 8);
    return put(w, h, sizeof h);
}

static int put_section(saver_t *w, const char *tag, const void *data, size_t bytes)
{
    if (put_head(w, tag, bytes))
        return w->rc;
    return put(w, data, bytes);
}

/* Zeros, as a section's body (a window slot that holds no layer). */
static int put_zeros(saver_t *w, size_t bytes)
{
    static const uint8_t zero[4096];
    while (bytes > 0 && w->rc == 0) {
        size_t n = bytes < sizeof zero ? bytes : sizeof zero;
        put(w, zero, n);
        bytes -= n;
    }
    return w->rc;
}

/* Counters, in this order in the "counters" section. */
enum {
    CT_COMPLETE,
    CT_CONVERGED,
    CT_STOPPED,
    CT_SAMPLES,
    CT_PIXEL_LAYERS,
    CT_SKIPPED,
    CT_NONFINITE,
    CT_DECIDED, /* version 6 */
    CT_COUNT
};
#define CT_COUNT_V5 CT_DECIDED

/* The window's layers per slot: layer, or UINT32_MAX for an empty slot. */
static void window_layers(const sched_t *s, uint32_t layer_of[2])
{
    layer_of[0] = layer_of[1] = UINT32_MAX;
    for (uint32_t l = s->complete; l < s->decided_n; l++)
        layer_of[l & 1] = l;
}

/* The version a checkpoint of this job is written in (sched.h). */
static uint32_t version_of(const sched_t *s)
{
    return s->crv                    ? SCHED_SAVE_VERSION_CALIBRATED
           : sched_replicates(s) > 1 ? SCHED_SAVE_VERSION_REPLICATES
                                     : SCHED_SAVE_VERSION;
}

/* Whether a checkpoint of this job has array a's section. */
static int saved(const sched_t *s, const pixel_array_t *a)
{
    return !a->only_if_kept || a->kept(s);
}

int sched_save(const sched_t *s, sched_write_fn write, void *ctx)
{
    /* Everything here lives on the stack or in *s: this runs in a forked
     * child, where malloc may be locked by a thread that no longer exists. */
    saver_t w = {write, ctx, {0, 0, {0}, 0}, 0};
    const size_t n = s->npix, mb = member_bytes(s);
    uint32_t vc[2] = {version_of(s), FP_COUNT}, layer_of[2];
    uint64_t fp[FP_COUNT];
    fingerprint(s, fp, sizeof(film_pixel_t));
    window_layers(s, layer_of);
    const uint64_t ct[CT_COUNT] = {s->complete,     s->converged,    (uint64_t)s->stopped_on_target,
                                   s->samples_done, s->pixel_layers, s->skipped,
                                   s->nonfinite,    s->decided_n};
    if (put(&w, save_magic, sizeof save_magic) || put(&w, vc, sizeof vc) ||
        put(&w, fp, sizeof fp) || put_section(&w, "counters", ct, sizeof ct) ||
        put_section(&w, "film", s->film->pixels, n * sizeof(film_pixel_t)))
        return w.rc;
    /* The window, slot by slot; a slot with no layer in it is all zeros.
     * Outstanding tasks go out as ready: their records are not saved, and
     * sched_next rebuilds them from the film (layer l of a range is merged
     * only when it completes, so the film holds exactly its priors). */
    if (put_head(&w, "member", 2 * mb))
        return w.rc;
    for (int k = 0; k < 2; k++)
        if (layer_of[k] == UINT32_MAX ? put_zeros(&w, mb) : put(&w, s->member[k], mb))
            return w.rc;
    if (put_head(&w, "state", 2 * (size_t)s->ranges))
        return w.rc;
    uint8_t buf[4096];
    for (int k = 0; k < 2; k++)
        for (size_t c0 = 0; c0 < s->ranges; c0 += sizeof buf) {
            size_t m = s->ranges - c0 < sizeof buf ? s->ranges - c0 : sizeof buf;
            for (size_t i = 0; i < m; i++) {
                uint8_t st = layer_of[k] == UINT32_MAX ? ST_WAITING : s->state[k][c0 + i];
                buf[i] = st == ST_OUT ? ST_READY : st;
            }
            if (put(&w, buf, m))
                return w.rc;
        }
    uint8_t slots[2 * (sizeof(uint32_t) + sizeof(double))] = {0};
    for (int k = 0; k < 2; k++)
        if (layer_of[k] != UINT32_MAX) {
            memcpy(slots + 4 * k, &s->range_done[k], 4);
            memcpy(slots + 8 + 8 * k, &s->threshold[k], 8);
        }
    if (put_section(&w, "slots", slots, sizeof slots))
        return w.rc;
    for (size_t i = 0; i < sched_pixel_array_count; i++)
        if (saved(s, &sched_pixel_arrays[i]) &&
            put_section(&w, sched_pixel_arrays[i].name, sched_array_of(s, &sched_pixel_arrays[i]),
                        sched_array_bytes(s, &sched_pixel_arrays[i])))
            return w.rc;
    if (put_head(&w, "end", sizeof(uint64_t)))
        return w.rc;
    uint64_t sum = ck_final(&w.ck);
    return put(&w, &sum, sizeof sum);
}

size_t sched_save_bytes(const sched_t *s)
{
    const size_t head = 16; /* a section's tag and length */
    size_t n = sizeof save_magic + 2 * sizeof(uint32_t) + FP_COUNT * sizeof(uint64_t);
    n += head + CT_COUNT * sizeof(uint64_t);
    n += head + (size_t)s->npix * sizeof(film_pixel_t);
    n += head + 2 * member_bytes(s) + head + 2 * (size_t)s->ranges;
    n += head + 2 * (sizeof(uint32_t) + sizeof(double));
    for (size_t i = 0; i < sched_pixel_array_count; i++)
        if (saved(s, &sched_pixel_arrays[i]))
            n += head + sched_array_bytes(s, &sched_pixel_arrays[i]);
    return n + head + sizeof(uint64_t);
}

typedef struct loader {
    sched_read_fn read;
    void *ctx;
    cksum_t ck;
} loader_t;

static int get(loader_t *r, void *data, size_t len, const char *what, char *err, size_t errlen)
{
    uint8_t *p = data;
    while (len > 0) {
        size_t n = len < SAVE_CHUNK ? len : SAVE_CHUNK;
        if (r->read(r->ctx, p, n) != 0) {
            snprintf(err, errlen, "checkpoint: truncated or unreadable (reading %s)", what);
            return -1;
        }
        ck_update(&r->ck, p, n);
        p += n;
        len -= n;
    }
    return 0;
}

/* A section's head: its tag and its size, both fixed by the config. */
static int get_head(loader_t *r, const char *tag, size_t bytes, char *err, size_t errlen)
{
    uint8_t h[16], want[8];
    uint64_t n;
    if (get(r, h, sizeof h, tag, err, errlen))
        return -1;
    tag_bytes(tag, want);
    if (memcmp(h, want, 8) != 0) {
        snprintf(err, errlen, "checkpoint: section \"%s\" expected, another tag in its place", tag);
        return -1;
    }
    memcpy(&n, h + 8, 8);
    if (n != bytes) {
        snprintf(err, errlen, "checkpoint: section \"%s\" holds %llu bytes, this config needs %zu",
                 tag, (unsigned long long)n, bytes);
        return -1;
    }
    return 0;
}

static int get_section(loader_t *r, const char *tag, void *data, size_t bytes, char *err,
                       size_t errlen)
{
    if (get_head(r, tag, bytes, err, errlen))
        return -1;
    return get(r, data, bytes, tag, err, errlen);
}

/* The header: magic, version (into *version: 5 to 8), fingerprint. */
static int load_header(const sched_t *s, loader_t *r, uint32_t *version, char *err, size_t errlen)
{
    uint8_t magic[8];
    uint32_t vc[2];
    uint64_t fp[FP_COUNT], want[FP_COUNT];
    if (get(r, magic, sizeof magic, "header", err, errlen))
        return -1;
    if (memcmp(magic, save_magic, sizeof magic) != 0) {
        snprintf(err, errlen, "checkpoint: not a scheduler checkpoint (bad magic)");
        return -1;
    }
    if (get(r, vc, sizeof vc, "header", err, errlen))
        return -1;
    if (vc[0] < SCHED_SAVE_VERSION_V5 || vc[0] > SCHED_SAVE_VERSION_CALIBRATED) {
        snprintf(err, errlen,
                 "checkpoint: format version %u, this build reads versions %u to %u (a newer "
                 "master wrote it?)",
                 vc[0], SCHED_SAVE_VERSION_V5, SCHED_SAVE_VERSION_CALIBRATED);
        return -1;
    }
    /* a job's replicates and target and its stream's version go together
     * (sched_save); a job with both may come from an older master's 7 */
    const uint32_t want_version = version_of(s);
    const int older_calibrated =
        want_version == SCHED_SAVE_VERSION_CALIBRATED && vc[0] == SCHED_SAVE_VERSION_REPLICATES;
    if (vc[0] != SCHED_SAVE_VERSION_V5 && vc[0] != want_version && !older_calibrated) {
        snprintf(err, errlen,
                 "checkpoint: format version %u is for a job %s, this config has %u replicates "
                 "and %s target error",
                 vc[0],
                 vc[0] == SCHED_SAVE_VERSION_CALIBRATED   ? "with replicates and a target error"
                 : vc[0] == SCHED_SAVE_VERSION_REPLICATES ? "with replicates and no target error"
                                                          : "without replicates",
                 sched_replicates(s), s->cfg.target_error > 0 ? "a" : "no");
        return -1;
    }
    if (vc[0] == SCHED_SAVE_VERSION_V5 && sched_replicates(s) > 1) {
        snprintf(err, errlen, "checkpoint: format version 5 has no replicates, this config has %u",
                 sched_replicates(s));
        return -1;
    }
    *version = vc[0];
    if (vc[1] != FP_COUNT) {
        snprintf(err, errlen, "checkpoint: %u config fingerprint fields, format version %u has %u",
                 vc[1], vc[0], FP_COUNT);
        return -1;
    }
    if (get(r, fp, sizeof fp, "header", err, errlen))
        return -1;
    fingerprint(s, want,
                vc[0] == SCHED_SAVE_VERSION_V5 ? sizeof(film_pixel_v5_t) : sizeof(film_pixel_t));
    for (int i = 0; i < FP_COUNT; i++) {
        if (fp[i] == want[i])
            continue;
        if (i == FP_TARGET_ERROR || i == FP_CONFIDENCE || i == FP_TARGET_SHARE) {
            double a, b;
            memcpy(&a, &fp[i], sizeof a);
            memcpy(&b, &want[i], sizeof b);
            snprintf(
                err, errlen,
                "checkpoint: the saved job's config differs in %s (saved %.17g, this config %.17g)",
                fp_names[i], a, b);
        } else {
            snprintf(
                err, errlen,
                "checkpoint: the saved job's config differs in %s (saved %llu, this config %llu)",
                fp_names[i], (unsigned long long)fp[i], (unsigned long long)want[i]);
        }
        return -1;
    }
    return 0;
}

/* The counters every version has, into s; checked against the config. */
static int apply_counters(sched_t *s, const uint64_t *ct, char *err, size_t errlen)
{
    if (ct[CT_COMPLETE] > s->layers || ct[CT_STOPPED] > 1 || ct[CT_CONVERGED] > s->npix) {
        snprintf(err, errlen,
                 "checkpoint: counters out of range (%llu layers complete of %u, stopped %llu, "
                 "converged %llu of %u pixels)",
                 (unsigned long long)ct[CT_COMPLETE], s->layers, (unsigned long long)ct[CT_STOPPED],
                 (unsigned long long)ct[CT_CONVERGED], s->npix);
        return -1;
    }
    s->complete = (uint32_t)ct[CT_COMPLETE];
    s->converged = ct[CT_CONVERGED];
    s->stopped_on_target = (int)ct[CT_STOPPED];
    s->samples_done = ct[CT_SAMPLES];
    s->pixel_layers = ct[CT_PIXEL_LAYERS];
    s->skipped = ct[CT_SKIPPED];
    s->nonfinite = ct[CT_NONFINITE];
    return 0;
}

/* Version 6 (sched_save): reads the stream into s (made by sched_new for
 * the caller's config, so every size comes from the config, none from the
 * stream). */
static int load_v6(sched_t *s, loader_t *r, uint32_t version, char *err, size_t errlen)
{
    const size_t n = s->npix, mb = member_bytes(s);
    uint64_t ct[CT_COUNT];
    uint8_t slots[2 * (sizeof(uint32_t) + sizeof(double))];
    if (get_section(r, "counters", ct, sizeof ct, err, errlen) ||
        apply_counters(s, ct, err, errlen))
        return -1;
    uint64_t want_d = ct[CT_DECIDED] == 0                     ? 0
                      : (uint64_t)s->complete + 2 < s->layers ? (uint64_t)s->complete + 2
                                                              : s->layers;
    if (ct[CT_DECIDED] != want_d) {
        snprintf(err, errlen, "checkpoint: %llu layers decided, expected %llu with %u complete",
                 (unsigned long long)ct[CT_DECIDED], (unsigned long long)want_d, s->complete);
        return -1;
    }
    s->decided_n = (uint32_t)ct[CT_DECIDED];
    if (get_section(r, "film", s->film->pixels, n * sizeof(film_pixel_t), err, errlen) ||
        get_head(r, "member", 2 * mb, err, errlen) ||
        get(r, s->member[0], mb, "member", err, errlen) ||
        get(r, s->member[1], mb, "member", err, errlen) ||
        get_head(r, "state", 2 * (size_t)s->ranges, err, errlen) ||
        get(r, s->state[0], s->ranges, "state", err, errlen) ||
        get(r, s->state[1], s->ranges, "state", err, errlen) ||
        get_section(r, "slots", slots, sizeof slots, err, errlen))
        return -1;
    for (int k = 0; k < 2; k++) {
        memcpy(&s->range_done[k], slots + 4 * k, 4);
        memcpy(&s->threshold[k], slots + 8 + 8 * k, 8);
    }
    for (size_t i = 0; i < sched_pixel_array_count; i++) {
        const pixel_array_t *a = &sched_pixel_arrays[i];
        if (s->crv && a->offset == offsetof(sched_t, crv) &&
            version < SCHED_SAVE_VERSION_CALIBRATED) {
            /* an older master's: its pixels keep the statistic of before */
            for (size_t p = 0; p < n; p++)
                s->crv[p] = -1;
            continue;
        }
        if (saved(s, a) &&
            get_section(r, a->name, *sched_array_slot(s, a), sched_array_bytes(s, a), err, errlen))
            return -1;
    }
    return get_head(r, "end", sizeof(uint64_t), err, errlen);
}

/* Reads n bytes of a section in chunks into buf (at most SAVE_CHUNK), each
 * passed to fn with its offset in the section. */
typedef void (*chunk_fn)(sched_t *s, const uint8_t *data, size_t offset, size_t len, void *ctx);
static int get_chunked(loader_t *r, sched_t *s, const char *tag, size_t bytes, uint8_t *buf,
                       chunk_fn fn, void *ctx, char *err, size_t errlen)
{
    if (get_head(r, tag, bytes, err, errlen))
        return -1;
    for (size_t off = 0; off < bytes; off += SAVE_CHUNK) {
        size_t k = bytes - off < SAVE_CHUNK ? bytes - off : SAVE_CHUNK;
        if (get(r, buf, k, tag, err, errlen))
            return -1;
        if (fn)
            fn(s, buf, off, k, ctx);
    }
    return 0;
}

/* Version 5 kept every layer: its member bits (layer l at bit l * npix + p),
 * cell states (l * ranges + r), decided flags, thresholds and range counts
 * per layer. Only the window's layers are kept from them. */
static void v5_member(sched_t *s, const uint8_t *d, size_t off, size_t len, void *ctx)
{
    (void)ctx;
    const size_t lo = off * 8, hi = (off + len) * 8; /* the chunk's bits */
    for (uint32_t l = s->complete; l < s->decided_n; l++) {
        const size_t b0 = (size_t)l * s->npix, b1 = b0 + s->npix; /* the layer's bits */
        for (size_t bit = b0 > lo ? b0 : lo; bit < (b1 < hi ? b1 : hi); bit++)
            if ((d[(bit >> 3) - off] >> (bit & 7)) & 1)
                set_member(s, l, (uint32_t)(bit - b0));
    }
}
static void v5_state(sched_t *s, const uint8_t *d, size_t off, size_t len, void *ctx)
{
    (void)ctx;
    for (uint32_t l = s->complete; l < s->decided_n; l++) {
        const size_t c0 = (size_t)l * s->ranges, c1 = c0 + s->ranges;
        for (size_t c = c0 > off ? c0 : off; c < (c1 < off + len ? c1 : off + len); c++)
            s->state[l & 1][c - c0] = d[c - off];
    }
}
/* A section that must be all zeros (version 5's batch counts in a mode
 * that keeps none). */
static void v5_zeros(sched_t *s, const uint8_t *d, size_t off, size_t len, void *ctx)
{
    (void)s;
    (void)off;
    for (size_t i = 0; i < len; i++)
        *(int *)ctx |= d[i] != 0;
}
/* Per-layer arrays: the window's layers' elements, in slot order. */
typedef struct v5_layer_ctx {
    size_t elem;
    uint8_t *out; /* 2 elements */
} v5_layer_ctx_t;
static void v5_per_layer(sched_t *s, const uint8_t *d, size_t off, size_t len, void *ctx)
{
    v5_layer_ctx_t *c = ctx;
    for (uint32_t l = s->complete; l < s->decided_n; l++)
        for (size_t b = 0; b < c->elem; b++) {
            size_t at = (size_t)l * c->elem + b;
            if (at >= off && at < off + len)
                c->out[(l & 1) * c->elem + b] = d[at - off];
        }
}
/* The decided flags: how many, as a prefix (checked for being one). */
typedef struct v5_decided_ctx {
    uint32_t prefix;
    int gap; /* a decided layer after an undecided one, or a flag not 0/1 */
} v5_decided_ctx_t;
static void v5_decided(sched_t *s, const uint8_t *d, size_t off, size_t len, void *ctx)
{
    (void)s;
    v5_decided_ctx_t *c = ctx;
    for (size_t i = 0; i < len; i++) {
        if (d[i] > 1 || (d[i] == 1 && c->prefix != off + i))
            c->gap = 1;
        else if (d[i] == 1)
            c->prefix++;
    }
}

/* Version 5 into this version's state. The snapshot and the statistics
 * after each layer in flight (by parity) become the prev_* values: a pixel
 * that merged the layer `complete` by then read the snapshot as of layer
 * complete - 1 in version 5; here it reads prev_*, which must then hold
 * that, which is the value after the layer complete - 1... as it left the
 * pixel: its flight value if it took part, the older snapshot if not. */
static int load_v5(sched_t *s, loader_t *r, char *err, size_t errlen)
{
    const size_t n = s->npix, L = s->layers, R = s->ranges;
    const int target = s->cfg.target_error > 0, counts = sched_keeps_counts(s),
              cost = sched_weighs_cost(s);
    const size_t tn = target ? n : 0, cn = counts ? n : 0, kn = cost ? n : 0;
    uint64_t ct[CT_COUNT_V5];
    int rc = -1;
    uint8_t *buf = malloc(SAVE_CHUNK);
    film_pixel_v5_t *old = malloc(SAVE_CHUNK);
    double *dv[3] = {calloc(n, sizeof(double)), calloc(n, sizeof(double)),
                     calloc(n, sizeof(double))};
    double *rv[3] = {calloc(tn + 1, sizeof(double)), calloc(tn + 1, sizeof(double)),
                     calloc(tn + 1, sizeof(double))};
    uint32_t *nv[3] = {calloc(cn + 1, sizeof(uint32_t)), calloc(cn + 1, sizeof(uint32_t)),
                       calloc(cn + 1, sizeof(uint32_t))};
    float *cv[3] = {calloc(kn + 1, sizeof(float)), calloc(kn + 1, sizeof(float)),
                    calloc(kn + 1, sizeof(float))};
    uint64_t *usamp = calloc(kn + 1, sizeof(uint64_t));
    uint32_t rdone[2] = {0, 0};
    v5_decided_ctx_t dc = {0, 0};
    v5_layer_ctx_t thc = {sizeof(double), (uint8_t *)s->threshold},
                   rdc = {sizeof(uint32_t), (uint8_t *)rdone};
    if (!buf || !old || !dv[0] || !dv[1] || !dv[2] || !rv[0] || !rv[1] || !rv[2] || !nv[0] ||
        !nv[1] || !nv[2] || !cv[0] || !cv[1] || !cv[2] || !usamp) {
        snprintf(err, errlen, "out of memory");
        goto out;
    }
    if (get_section(r, "counters", ct, sizeof ct, err, errlen) ||
        apply_counters(s, ct, err, errlen) || get_head(r, "film", n * sizeof *old, err, errlen))
        goto out;
    const size_t per = SAVE_CHUNK / sizeof *old;
    for (size_t p0 = 0; p0 < n; p0 += per) {
        size_t k = n - p0 < per ? n - p0 : per;
        if (get(r, old, k * sizeof *old, "film", err, errlen))
            goto out;
        for (size_t i = 0; i < k; i++) {
            film_pixel_t *fp = &s->film->pixels[p0 + i];
            if (old[i].count > s->cfg.spp || old[i].nonfinite > s->cfg.spp) {
                snprintf(err, errlen, "checkpoint: film pixel %zu: %llu + %llu samples", p0 + i,
                         (unsigned long long)old[i].count, (unsigned long long)old[i].nonfinite);
                goto out;
            }
            memcpy(fp->sum, old[i].sum, sizeof fp->sum);
            memcpy(fp->comp, old[i].comp, sizeof fp->comp);
            fp->lum_m2 = old[i].lum_m2;
            fp->count = (uint32_t)old[i].count;
            fp->nonfinite = (uint32_t)old[i].nonfinite;
            if (s->pvar_cur)
                s->pvar_cur[p0 + i] = old[i].pvar;
        }
    }
    /* Version 5's sections come member, decided, ...: the window must be
     * known before the member bits. It is: decided = complete + 2 (at most
     * all layers), or none before the first task (checked below). */
    const size_t member_total = (L * n + 7) / 8;
    s->decided_n = (uint32_t)(s->complete + 2 < L ? s->complete + 2 : L);
    if (get_chunked(r, s, "member", member_total, buf, v5_member, NULL, err, errlen) ||
        get_chunked(r, s, "decided", L, buf, v5_decided, &dc, err, errlen))
        goto out;
    if (dc.gap || (dc.prefix != s->decided_n && !(dc.prefix == 0 && s->complete == 0))) {
        snprintf(err, errlen, "checkpoint: %u layers decided, expected %u with %u complete",
                 dc.prefix, s->decided_n, s->complete);
        goto out;
    }
    if (dc.prefix == 0) { /* saved before its first task: nothing decided */
        s->decided_n = 0;
        memset(s->member[0], 0, member_bytes(s));
        memset(s->member[1], 0, member_bytes(s));
    }
    if (get_chunked(r, s, "thresh", L * sizeof(double), buf, v5_per_layer, &thc, err, errlen) ||
        get_chunked(r, s, "state", L * R, buf, v5_state, NULL, err, errlen) ||
        get_chunked(r, s, "rdone", L * sizeof(uint32_t), buf, v5_per_layer, &rdc, err, errlen))
        goto out;
    s->range_done[0] = rdone[0];
    s->range_done[1] = rdone[1];
    if (get_section(r, "var", dv[0], n * sizeof(double), err, errlen) ||
        get_section(r, "pvar0", dv[1], n * sizeof(double), err, errlen) ||
        get_section(r, "pvar1", dv[2], n * sizeof(double), err, errlen) ||
        get_section(r, "rvar", rv[0], tn * sizeof(double), err, errlen) ||
        get_section(r, "rvar0", rv[1], tn * sizeof(double), err, errlen) ||
        get_section(r, "rvar1", rv[2], tn * sizeof(double), err, errlen) ||
        get_section(r, "nbat", nv[0], cn * sizeof(uint32_t), err, errlen) ||
        get_section(r, "nbat0", nv[1], cn * sizeof(uint32_t), err, errlen) ||
        get_section(r, "nbat1", nv[2], cn * sizeof(uint32_t), err, errlen))
        goto out;
    /* batches, then its mean and M2, which nothing read (dropped) */
    int stray_batches = 0;
    if (s->batches ? get_section(r, "batches", s->batches, n * sizeof(uint32_t), err, errlen)
                   : get_chunked(r, s, "batches", n * sizeof(uint32_t), buf, v5_zeros,
                                 &stray_batches, err, errlen))
        goto out;
    if (stray_batches) {
        snprintf(err, errlen, "checkpoint: batch counts in a mode that keeps none");
        goto out;
    }
    if (get_chunked(r, s, "bmean", n * sizeof(double), buf, NULL, NULL, err, errlen) ||
        get_chunked(r, s, "bm2", n * sizeof(double), buf, NULL, NULL, err, errlen) ||
        get_section(r, "ubat", s->ubatches, cn * sizeof(uint32_t), err, errlen) ||
        get_section(r, "umean", s->umean, cn * sizeof(double), err, errlen) ||
        get_section(r, "um2", s->um2, cn * sizeof(double), err, errlen) ||
        get_section(r, "urays", s->urays, kn * sizeof(uint64_t), err, errlen) ||
        get_section(r, "usamp", usamp, kn * sizeof(uint64_t), err, errlen) ||
        get_section(r, "cost", cv[0], kn * sizeof(float), err, errlen) ||
        get_section(r, "cost0", cv[1], kn * sizeof(float), err, errlen) ||
        get_section(r, "cost1", cv[2], kn * sizeof(float), err, errlen) ||
        get_head(r, "end", sizeof(uint64_t), err, errlen))
        goto out;
    for (size_t p = 0; p < kn; p++) {
        if (usamp[p] > s->cfg.spp) {
            snprintf(err, errlen, "checkpoint: pixel %zu: %llu uniform-layer samples", p,
                     (unsigned long long)usamp[p]);
            goto out;
        }
        s->usamples[p] = (uint32_t)usamp[p];
    }
    /* prev_*: the statistics as of layer complete - 1 where it merged it */
    const uint32_t c = s->complete;
    for (uint32_t p = 0; p < n && s->decided_n > c; p++) {
        const int k = is_member(s, c, p) && s->state[c & 1][p / s->range_pixels] == ST_DONE
                          ? 1 + (int)(c & 1)
                          : 0;
        if (s->prev_metric)
            s->prev_metric[p] = dv[k][p];
        if (s->prev_rvar)
            s->prev_rvar[p] = rv[k][p];
        if (s->prev_nb)
            s->prev_nb[p] = nv[k][p];
        if (s->prev_cost)
            s->prev_cost[p] = cv[k][p];
    }
    rc = 0;
out:
    free(buf);
    free(old);
    for (int k = 0; k < 3; k++) {
        free(dv[k]);
        free(rv[k]);
        free(nv[k]);
        free(cv[k]);
    }
    free(usamp);
    return rc;
}

static const char *state_name(uint8_t st)
{
    static const char *const names[] = {"waiting", "ready", "outstanding", "done"};
    return st <= ST_DONE ? names[st] : "?";
}

static unsigned popcount8(uint8_t b)
{
    unsigned n = 0;
    for (; b; b &= (uint8_t)(b - 1))
        n++;
    return n;
}

/* The window: each slot's cells, counts, members and threshold must be what
 * the scheduler's own transitions leave, and a slot with no layer empty. */
static int check_window(const sched_t *s, char *err, size_t errlen)
{
    const uint32_t R = s->ranges;
    const size_t mb = member_bytes(s);
    uint32_t layer_of[2];
    window_layers(s, layer_of);
    for (int k = 0; k < 2; k++) {
        const uint32_t l = layer_of[k];
        if (l == UINT32_MAX) {
            int stray = s->range_done[k] != 0 || f64_bits(s->threshold[k]) != 0; /* -0 too */
            for (size_t i = 0; i < mb && !stray; i++)
                stray = s->member[k][i] != 0;
            for (uint32_t r = 0; r < R && !stray; r++)
                stray = s->state[k][r] != ST_WAITING;
            if (stray) {
                snprintf(err, errlen,
                         "checkpoint: window slot %d holds no layer, yet member bits, cell states "
                         "or counts are set",
                         k);
                return -1;
            }
            continue;
        }
        if (s->npix % 8 && (s->member[k][mb - 1] >> (s->npix % 8)) != 0) {
            snprintf(err, errlen, "checkpoint: member bits past the last pixel (layer %u)", l);
            return -1;
        }
        double t = s->threshold[k];
        if (sched_applies_skip_rule(s, l) ? isnan(t) : t != 0) {
            snprintf(err, errlen, "checkpoint: threshold %g of layer %u", t, l);
            return -1;
        }
        uint32_t done = 0;
        for (uint32_t r = 0; r < R; r++) {
            uint8_t st = s->state[k][r];
            if (st != ST_WAITING && st != ST_READY && st != ST_DONE) {
                snprintf(err, errlen,
                         "checkpoint: cell state %u at layer %u, range %u is not waiting, ready or "
                         "done",
                         st, l, r);
                return -1;
            }
            /* rule 1: a cell runs once its range's previous layer is done;
             * then at once (done) if the layer has none of its pixels */
            int may = l == 0 || cell_state(s, l - 1, r) == ST_DONE;
            if ((st != ST_WAITING) != may) {
                snprintf(err, errlen,
                         "checkpoint: cell state %s at layer %u, range %u contradicts rule 1 "
                         "(previous layer's cell %s)",
                         state_name(st), l, r, l ? state_name(cell_state(s, l - 1, r)) : "none");
                return -1;
            }
            if (st == ST_READY && range_members(s, l, r) == 0) {
                snprintf(err, errlen,
                         "checkpoint: cell state ready at layer %u, range %u, which has no pixels",
                         l, r);
                return -1;
            }
            done += st == ST_DONE;
        }
        if (done != s->range_done[k] || done == R) {
            snprintf(err, errlen,
                     "checkpoint: layer %u has range_done %u and %u cells done of %u, yet is not "
                     "complete",
                     l, s->range_done[k], done, R);
            return -1;
        }
    }
    uint64_t window_members = 0;
    for (int k = 0; k < 2; k++)
        for (size_t i = 0; layer_of[k] != UINT32_MAX && i < mb; i++)
            window_members += popcount8(s->member[k][i]);
    if (s->pixel_layers + s->skipped != (uint64_t)s->decided_n * s->npix ||
        s->pixel_layers < window_members) {
        snprintf(
            err, errlen,
            "checkpoint: pixel_layers %llu and skipped %llu for %u decided layers of %u pixels",
            (unsigned long long)s->pixel_layers, (unsigned long long)s->skipped, s->decided_n,
            s->npix);
        return -1;
    }
    if (s->cfg.target_error == 0 && (s->converged || s->stopped_on_target)) {
        snprintf(err, errlen, "checkpoint: converged %llu / stopped %d without a target error",
                 (unsigned long long)s->converged, s->stopped_on_target);
        return -1;
    }
    return 0;
}

/* What Welford over at most `most` layer means in range can make. */
static int welford_plausible(uint32_t n, double mean, double m2, uint32_t most)
{
    return n <= most && mean >= 0 && mean <= 2 * SCHED_MAX_RADIANCE && m2 >= 0 && isfinite(m2) &&
           (n > 0 || mean == 0) && (n > 1 || m2 == 0);
}

/* Pixel p: finite film values, samples a whole number of layers (only the
 * last may be short), statistics that results in range can make. */
static int check_pixel(const sched_t *s, uint32_t p, char *err, size_t errlen)
{
    const film_pixel_t *fp = &s->film->pixels[p];
    const uint32_t G = s->cfg.granularity;
    /* at most the complete layers and those of the window it merged */
    uint64_t merged = s->complete;
    for (uint32_t l = s->complete; l < s->decided_n; l++)
        merged += is_member(s, l, p) && s->state[l & 1][p / s->range_pixels] == ST_DONE;
    const uint64_t taken = (uint64_t)fp->count + fp->nonfinite,
                   most = merged * G < s->cfg.spp ? merged * G : s->cfg.spp;
    static const char *const names[7] = {"sum[0]",  "sum[1]",  "sum[2]", "comp[0]",
                                         "comp[1]", "comp[2]", "lum_m2"};
    const double v[7] = {fp->sum[0],  fp->sum[1],  fp->sum[2], fp->comp[0],
                         fp->comp[1], fp->comp[2], fp->lum_m2};
    for (int k = 0; k < 7; k++)
        if (!isfinite(v[k])) {
            snprintf(err, errlen, "checkpoint: film pixel %u: %s is not finite (%g)", p, names[k],
                     v[k]);
            return -1;
        }
    if (taken > most || (taken % G != 0 && taken % G != s->cfg.spp % G)) {
        snprintf(err, errlen,
                 "checkpoint: film pixel %u holds %u + %u nonfinite samples: not whole layers of "
                 "%u, or more than the %llu layers it can have merged take",
                 p, fp->count, fp->nonfinite, G, (unsigned long long)merged);
        return -1;
    }
    const uint32_t layers = (uint32_t)((taken + G - 1) / G);
    /* each replicate's sum: a part of the film's (its samples are the film's) */
    const uint32_t reps = sched_replicates(s);
    if (reps > 1) {
        const double whole = vmath_luminance(fp->sum[0], fp->sum[1], fp->sum[2]);
        double part = 0;
        for (uint32_t r = 1; r < reps; r++) {
            const double v = s->rep_lum[(size_t)p * (reps - 1) + r - 1];
            part += v;
            if (!(v >= 0) || (layers <= r && v != 0) || !(part <= whole * (1 + 1e-9) + 1e-300)) {
                snprintf(err, errlen,
                         "checkpoint: pixel %u: replicate %u's luminance sum %g (the pixel's %g, "
                         "%u layers)",
                         p, r, v, whole, layers);
                return -1;
            }
        }
    }
    if (s->pvar_cur && !(s->pvar_cur[p] >= 0 &&
                         s->pvar_cur[p] <= (double)G * SCHED_MAX_RADIANCE * SCHED_MAX_RADIANCE)) {
        snprintf(err, errlen, "checkpoint: pixel %u: eq. 4.1 %g", p, s->pvar_cur[p]);
        return -1;
    }
    if (s->prev_metric) {
        double m = s->prev_metric[p];
        if (isnan(m) || m == -INFINITY || (sched_pools_neighbours(s) && m < 0)) {
            snprintf(err, errlen, "checkpoint: pixel %u: adaptive metric %g", p, m);
            return -1;
        }
    }
    if (s->prev_rvar && !(s->prev_rvar[p] >= 0)) {
        snprintf(err, errlen, "checkpoint: pixel %u: relative variance %g", p, s->prev_rvar[p]);
        return -1;
    }
    if (s->crv && !(s->crv[p] >= 0 || s->crv[p] == -1)) {
        snprintf(err, errlen, "checkpoint: pixel %u: calibrated relative variance %g", p,
                 s->crv[p]);
        return -1;
    }
    if (s->batches) {
        /* what results in range can make: a mean of layer luminances in
         * [0, SCHED_MAX_RADIANCE] (2x: rounding), a sum of squares >= 0,
         * both 0 before the first batch and the sum still 0 after it.
         * Anything else can turn the metrics NaN or infinite on the next
         * merge (Welford's update assumes them) */
        const uint32_t nb = s->batches[p];
        if (nb > layers || s->prev_nb[p] > nb ||
            !welford_plausible(s->ubatches[p], s->umean[p], s->um2[p], nb)) {
            snprintf(err, errlen,
                     "checkpoint: pixel %u: batch statistics (%u batches of %u layers, %u before "
                     "the last; %u uniform, mean %g, m2 %g)",
                     p, nb, layers, s->prev_nb[p], s->ubatches[p], s->umean[p], s->um2[p]);
            return -1;
        }
    }
    if (s->urays) {
        const uint64_t rays = s->urays[p], n = s->usamples[p];
        if (n > taken || rays < n || (n == 0) != (rays == 0)) {
            snprintf(err, errlen,
                     "checkpoint: pixel %u: %llu rays for %llu uniform-layer samples of %llu taken",
                     p, (unsigned long long)rays, (unsigned long long)n, (unsigned long long)taken);
            return -1;
        }
        const float c = s->prev_cost[p];
        if (!(c == 0 || (c >= 1 && isfinite(c)))) {
            snprintf(err, errlen, "checkpoint: pixel %u: %g rays per sample", p, (double)c);
            return -1;
        }
    }
    return 0;
}

static int check_pixels(const sched_t *s, char *err, size_t errlen)
{
    uint64_t total = 0, nonfinite = 0;
    for (uint32_t p = 0; p < s->npix; p++) {
        if (check_pixel(s, p, err, errlen) < 0)
            return -1;
        total += (uint64_t)s->film->pixels[p].count + s->film->pixels[p].nonfinite;
        nonfinite += s->film->pixels[p].nonfinite;
    }
    if (total != s->samples_done || nonfinite != s->nonfinite) {
        snprintf(
            err, errlen,
            "checkpoint: samples_done %llu and nonfinite %llu, but the film holds %llu and %llu",
            (unsigned long long)s->samples_done, (unsigned long long)s->nonfinite,
            (unsigned long long)total, (unsigned long long)nonfinite);
        return -1;
    }
    return 0;
}

sched_t *sched_load(const sched_config_t *cfg, sched_read_fn read, void *ctx, char *err,
                    size_t errlen)
{
    sched_t *s = sched_new(cfg, err, errlen);
    if (!s)
        return NULL;
    loader_t r = {read, ctx, {0, 0, {0}, 0}};
    uint64_t sum_read = 0, sum = 0;
    uint32_t version = 0;
    if (load_header(s, &r, &version, err, errlen) ||
        (version != SCHED_SAVE_VERSION_V5 ? load_v6(s, &r, version, err, errlen)
                                          : load_v5(s, &r, err, errlen))) {
        sched_destroy(&s);
        return NULL;
    }
    /* The checksum is compared after the consistency checks: they name a
     * problem better. */
    sum = ck_final(&r.ck);
    if (get(&r, &sum_read, sizeof sum_read, "checksum", err, errlen) ||
        check_window(s, err, errlen) || check_pixels(s, err, errlen)) {
        sched_destroy(&s);
        return NULL;
    }
    if (sum_read != sum) {
        snprintf(err, errlen, "checkpoint: checksum mismatch (the stream is corrupt)");
        sched_destroy(&s);
        return NULL;
    }
    for (uint32_t p = 0; p < s->npix; p++) {
        const film_pixel_t *fp = &s->film->pixels[p];
        s->at_cap += (uint64_t)fp->count + fp->nonfinite == s->cfg.spp;
    }
    /* The ready queue in id order: results merge per pixel in layer order
     * and decisions read snapshots only, so the order tasks are issued in
     * changes nothing. */
    for (int k = 0; k < 2; k++)
        s->ready[k].head = s->ready[k].tail = 0;
    for (uint32_t l = s->complete; l < s->decided_n; l++)
        for (uint32_t rr = 0; rr < s->ranges; rr++)
            if (s->state[l & 1][rr] == ST_READY)
                sched_push_ready(s, task_id(s, l, rr));
    return s;
}
