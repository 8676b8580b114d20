/* gen_fuzz_seeds.c - writes the seed corpora of the fuzz targets whose
 * inputs are made by the project's own writers (make fuzz-seeds):
 *
 *   tests/data/fuzz-ctl    control requests (fuzz_ctl's frame format)
 *   tests/data/fuzz-store  state records: real files from store.c's writer,
 *                          and their payloads for sealing
 *   tests/data/fuzz-ckpt   checkpoint payloads: schedulers of fuzzmaster.h's
 *                          configs run with synthetic results and saved at
 *                          several points (fresh, tasks out, mid, done)
 *   tests/data/fuzz-journal  job journals (master/journal.c's writer): with
 *                          and without pvar, a few commits of merged tasks
 *   tests/data/fuzz-exr    small EXR files: image_write_exr's, and HALF /
 *                          UINT, other compressions and tiled ones written
 *                          with the OpenEXR C API
 *
 * Every submission seed is checked to be accepted by submit_parse and every
 * checkpoint seed to load, so the seeds start the fuzzers deep inside the
 * decoders; and the record sealing and checksum repair of fuzzmaster.h are
 * checked against the real writers.
 *
 *     gen_fuzz_seeds DATA_DIR           write the seeds
 *     gen_fuzz_seeds --check DATA_DIR   compare them with the committed ones
 *
 * --check (run by `make test`) leaves out the EXR files, whose bytes depend
 * on the OpenEXR version; the others depend on this project alone, so a
 * difference means a format changed and the corpus is stale: run
 * `make fuzz-seeds` and commit.
 */
#include <errno.h>
#include <fcntl.h>
#include <openexr.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "fuzzmaster.h"
#include "image.h"
#include "journal.h"
#include "master_priv.h"

typedef struct gen {
    const char *root;
    int check;
    int written, compared, failed;
    char tmp[256]; /* a scratch state directory */
} gen_t;

static void die(const char *fmt, ...) __attribute__((format(printf, 1, 2), noreturn));
static void die(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fprintf(stderr, "gen_fuzz_seeds: ");
    vfprintf(stderr, fmt, ap);
    fprintf(stderr, "\n");
    va_end(ap);
    exit(1);
}

static uint8_t *read_all(const char *path, size_t *n)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    size_t cap = 1 << 16;
    uint8_t *p = malloc(cap);
    *n = 0;
    size_t got;
    while (p && (got = fread(p + *n, 1, cap - *n, f)) > 0) {
        *n += got;
        if (*n == cap) {
            uint8_t *np = realloc(p, cap *= 2);
            if (!np)
                free(p);
            p = np;
        }
    }
    fclose(f);
    return p;
}

/* Writes DIR/fuzz-TARGET/NAME, or compares it with the committed file. */
static void emit(gen_t *g, const char *target, const char *name, const void *data, size_t n)
{
    char dir[1024], path[1400];
    snprintf(dir, sizeof dir, "%s/fuzz-%s", g->root, target);
    snprintf(path, sizeof path, "%s/%s", dir, name);
    if (g->check) {
        size_t have = 0;
        uint8_t *old = read_all(path, &have);
        if (!old || have != n || memcmp(old, data, n) != 0) {
            fprintf(stderr, "gen_fuzz_seeds: %s %s\n", path,
                    old ? "differs from what the writers make now" : "is missing");
            g->failed++;
        }
        free(old);
        g->compared++;
        return;
    }
    mkdir(dir, 0755);
    FILE *f = fopen(path, "wb");
    if (!f || fwrite(data, 1, n, f) != n || fclose(f) != 0)
        die("cannot write %s: %s", path, strerror(errno));
    g->written++;
}

/* A seed of one leading byte, then bytes. */
static void emit_k(gen_t *g, const char *target, const char *name, uint8_t k, const void *data,
                   size_t n)
{
    uint8_t *buf = malloc(n + 1);
    if (!buf)
        die("out of memory");
    buf[0] = k;
    memcpy(buf + 1, data, n);
    emit(g, target, name, buf, n + 1);
    free(buf);
}

/* ---- scenes and requests ---------------------------------------------------------- */

static const char scene_basic[] =
    "{\"camera\": {\"position\": [0, 1, -4], \"look_at\": [0, 1, 0], \"fov\": 40, \"width\": 8, "
    "\"height\": 6},\n"
    " \"render\": {\"spp\": 16, \"seed\": 5},\n"
    " \"materials\": {\"grey\": {\"type\": \"diffuse\", \"albedo\": [0.5, 0.5, 0.5]},\n"
    "   \"glass\": {\"type\": \"dielectric\", \"ior\": 1.5},\n"
    "   \"lamp\": {\"type\": \"emitter\", \"radiance\": [10, 10, 10]}},\n"
    " \"shapes\": [\n"
    "  {\"type\": \"quad\", \"material\": \"grey\", \"vertices\": [[-2, 0, -2], [-2, 0, 2], [2, 0, "
    "2], [2, 0, -2]]},\n"
    "  {\"type\": \"sphere\", \"material\": \"glass\", \"center\": [0, 0.5, 0], \"radius\": 0.5, "
    "\"subdivisions\": 1},\n"
    "  {\"type\": \"quad\", \"material\": \"lamp\", \"vertices\": [[-0.5, 3, -0.5], [0.5, 3, "
    "-0.5], [0.5, 3, 0.5], "
    "[-0.5, 3, 0.5]]}]}\n";

static const char scene_mesh[] =
    "{\"camera\": {\"position\": [0, 0, -3], \"look_at\": [0, 0, 0], \"up\": [0, 1, 0], \"fov\": "
    "50, \"width\": 4, "
    "\"height\": 4},\n"
    " \"render\": {\"spp\": 8, \"integrator\": \"naive\", \"max_depth\": 3},\n"
    " \"materials\": {\"m\": {\"type\": \"mirror\", \"reflectance\": [0.9, 0.9, 0.9]},\n"
    "   \"lamp\": {\"type\": \"emitter\", \"radiance\": [4, 4, 4], \"albedo\": [0.1, 0.1, 0.1]}},\n"
    " \"shapes\": [\n"
    "  {\"type\": \"mesh\", \"material\": \"m\", \"file\": \"tri.obj\", \"transform\": {\"scale\": "
    "[1, -1, 1], "
    "\"rotate\": [0, 30, 0], \"translate\": [0, 0, 1]}},\n"
    "  {\"type\": \"mesh\", \"material\": \"lamp\", \"file\": \"quad.ply\", \"transform\": "
    "{\"scale\": 2}},\n"
    "  {\"type\": \"triangles\", \"material\": \"m\", \"vertices\": [[0, 0, 2], [1, 0, 2], [0, 1, "
    "2]], "
    "\"indices\": [[0, 1, 2]]}]}\n";

static const char mesh_obj[] = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf -3 -1 -2\n";
static const char mesh_ply[] =
    "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
    "property float z\nproperty float nx\nproperty float ny\nproperty float nz\n"
    "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
    "0 0 0 0 0 -1\n1 0 0 0 0 -1\n1 1 0 0 0 -1\n0 1 0 0 0 -1\n4 0 3 2 1\n";

typedef struct request {
    const char *name;
    const char *json;
    int nframes;
    submit_frame_t frames[8];
    int must_submit; /* submit_parse must accept it */
} request_t;

/* The reference planes of an 8 x 6 image. */
static float ref_planes[3][48];

static int make_requests(request_t *r)
{
    for (int c = 0; c < 3; c++)
        for (int i = 0; i < 48; i++)
            ref_planes[c][i] = 0.01f * (float)(i + 16 * c);
    const submit_frame_t basic = {scene_basic, sizeof scene_basic - 1},
                         mesh = {scene_mesh, sizeof scene_mesh - 1},
                         obj = {mesh_obj, sizeof mesh_obj - 1},
                         ply = {mesh_ply, sizeof mesh_ply - 1};
    int n = 0;
    r[n++] = (request_t){"submit-basic",
                         "{\"cmd\":\"submit\",\"name\":\"basic.json\",\"spp\":8,\"granularity\":4}",
                         1,
                         {basic},
                         1};
    r[n++] = (request_t){
        "submit-meshes",
        "{\"cmd\":\"submit\",\"name\":\"mesh.json\",\"meshes\":[\"tri.obj\",\"quad.ply\"],"
        "\"request_id\":\"fuzz-seed_2\"}",
        3,
        {mesh, obj, ply},
        1};
    r[n++] = (request_t){"submit-reference",
                         "{\"cmd\":\"submit\",\"reference\":true,\"spp\":4,\"granularity\":2,"
                         "\"adaptive\":\"variance\"}",
                         4,
                         {basic,
                          {ref_planes[0], sizeof ref_planes[0]},
                          {ref_planes[1], sizeof ref_planes[1]},
                          {ref_planes[2], sizeof ref_planes[2]}},
                         1};
    r[n++] = (request_t){
        "submit-options",
        "{\"cmd\":\"submit\",\"spp\":12,\"granularity\":2,\"adaptive\":\"relerr\",\"target_error\":"
        "0.05,"
        "\"confidence\":0.9,\"target_share\":0.8,\"uniform_layers\":2,\"random_selection\":true,"
        "\"dilate\":true,\"seed\":42,\"max_depth\":5,\"integrator\":\"naive\",\"time_limit\":30.5}",
        1,
        {basic},
        1};
    r[n++] = (request_t){"submit-flags",
                         "{\"cmd\":\"submit\",\"spp\":8,\"granularity\":2,\"adaptive\":\"thesis\","
                         "\"flags\":\"0011\"}",
                         1,
                         {basic},
                         1};
    r[n++] = (request_t){"submit-none",
                         "{\"cmd\":\"submit\",\"adaptive\":\"none\",\"granularity\":1}",
                         1,
                         {mesh},
                         0};
    r[n++] = (request_t){"submit-noscene", "{\"cmd\":\"submit\"}", 0, {{NULL, 0}}, 0};
    r[n++] = (request_t){"status", "{\"cmd\":\"status\",\"job\":3}", 0, {{NULL, 0}}, 0};
    r[n++] =
        (request_t){"fetch", "{\"cmd\":\"fetch\",\"job\":9007199254740992}", 0, {{NULL, 0}}, 0};
    r[n++] = (request_t){"cancel", "{\"cmd\":\"cancel\",\"job\":1.5}", 0, {{NULL, 0}}, 0};
    r[n++] = (request_t){"delete", "{\"cmd\":\"delete\",\"job\":17}", 0, {{NULL, 0}}, 0};
    r[n++] = (request_t){"jobs", "{\"cmd\":\"jobs\"}", 0, {{NULL, 0}}, 0};
    r[n++] = (request_t){"workers", "{\"cmd\":\"workers\"}", 0, {{NULL, 0}}, 0};
    r[n++] = (request_t){"shutdown", "{\"cmd\":\"shutdown\"}", 0, {{NULL, 0}}, 0};
    return n;
}

static void check_submit(const request_t *r)
{
    cJSON *req = cJSON_Parse(r->json);
    char err[VB_ERR_LEN] = "";
    if (!req)
        die("%s: the request is not JSON", r->name);
    job_t *j = submit_parse(req, r->frames, r->nframes, NULL, err, sizeof err);
    if (r->must_submit && !j)
        die("%s: submit_parse refuses the seed: %s", r->name, err);
    if (r->must_submit && fuzz_submit_too_big(req, r->frames[0].data, r->frames[0].size))
        die("%s: over fuzz_submit_too_big's bound", r->name);
    job_free(j);
    cJSON_Delete(req);
}

static void gen_ctl(gen_t *g, const request_t *r, int n)
{
    static const char sep[] = FUZZ_CTL_SEP;
    for (int i = 0; i < n; i++) {
        check_submit(&r[i]);
        size_t len = strlen(r[i].json);
        for (int f = 0; f < r[i].nframes; f++)
            len += sizeof sep - 1 + r[i].frames[f].size;
        uint8_t *buf = malloc(len), *p = buf;
        if (!buf)
            die("out of memory");
        memcpy(p, r[i].json, strlen(r[i].json));
        p += strlen(r[i].json);
        for (int f = 0; f < r[i].nframes; f++) {
            memcpy(p, sep, sizeof sep - 1);
            p += sizeof sep - 1;
            memcpy(p, r[i].frames[f].data, r[i].frames[f].size);
            p += r[i].frames[f].size;
        }
        char name[64];
        snprintf(name, sizeof name, "%s.bin", r[i].name);
        emit(g, "ctl", name, buf, len);
        free(buf);
    }
}

/* ---- records --------------------------------------------------------------------- */

/* Commits w, then returns the file's bytes (and removes it). */
static uint8_t *commit_and_read(store_rec_writer_t *w, size_t *n)
{
    char path[4096];
    snprintf(path, sizeof path, "%s", w->path);
    if (store_rec_commit(w, 0) < 0)
        die("%s", w->err);
    uint8_t *data = read_all(path, n);
    if (!data)
        die("cannot read back %s", path);
    unlink(path);
    return data;
}

/* Emits a real record twice for fuzz_store: the whole file (K = kind) and
 * its payload (K = kind | 4, sealed by the target), after checking that
 * fuzz_seal_record makes the same file from that payload. */
static void emit_record(gen_t *g, const char *name, store_kind_t kind, const uint8_t *file,
                        size_t n)
{
    static const char *const kinds[] = {"", "meta", "submit", "checkpoint", "final"};
    if (n < FUZZ_REC_HEADER + FUZZ_REC_TRAILER)
        die("%s: a record of %zu bytes", name, n);
    size_t plen = n - FUZZ_REC_HEADER - FUZZ_REC_TRAILER;
    uint8_t *sealed = malloc(n);
    if (!sealed)
        die("out of memory");
    fuzz_seal_record(kind, file + FUZZ_REC_HEADER, plen, sealed);
    if (memcmp(sealed, file, n) != 0)
        die("fuzzmaster.h's fuzz_seal_record no longer matches store.c's record layout");
    free(sealed);
    char fname[128];
    uint8_t k = (uint8_t)(kind - 1);
    snprintf(fname, sizeof fname, "%s-%s-file.bin", kinds[kind], name);
    emit_k(g, "store", fname, k, file, n);
    snprintf(fname, sizeof fname, "%s-%s-payload.bin", kinds[kind], name);
    emit_k(g, "store", fname, (uint8_t)(k | 4), file + FUZZ_REC_HEADER, plen);
}

static void rec_begin(gen_t *g, store_rec_writer_t *w, const char *file, store_kind_t kind)
{
    char path[512];
    snprintf(path, sizeof path, "%s/%s", g->tmp, file);
    if (store_rec_begin(w, path, kind) < 0)
        die("%s", w->err);
}

static void gen_meta(gen_t *g)
{
    char err[512];
    store_t *s = store_open(g->tmp, err, sizeof err);
    if (!s || store_take_job_id(s, err, sizeof err) != 1 ||
        store_take_job_id(s, err, sizeof err) != 2)
        die("store: %s", err);
    store_close(&s);
    char path[512];
    snprintf(path, sizeof path, "%s/meta", g->tmp);
    size_t n;
    uint8_t *data = read_all(path, &n);
    if (!data)
        die("cannot read %s", path);
    unlink(path);
    emit_record(g, "3-1", STORE_KIND_META, data, n);
    free(data);
    snprintf(path, sizeof path, "%s/jobs", g->tmp);
    rmdir(path);
}

/* As persist_submission writes it. */
static void gen_submit_record(gen_t *g, const request_t *r)
{
    store_rec_writer_t *w = malloc(sizeof *w);
    if (!w)
        die("out of memory");
    rec_begin(g, w, "submit", STORE_KIND_SUBMIT);
    uint32_t n = (uint32_t)r->nframes;
    int rc = store_rec_write_block(w, r->json, strlen(r->json));
    rc = rc < 0 ? rc : store_rec_write(w, &n, sizeof n);
    for (int i = 0; rc == 0 && i < r->nframes; i++)
        rc = store_rec_write_block(w, r->frames[i].data, r->frames[i].size);
    if (rc < 0)
        die("%s", w->err);
    size_t len;
    uint8_t *data = commit_and_read(w, &len);
    emit_record(g, r->name + strlen("submit-"), STORE_KIND_SUBMIT, data, len);
    free(data);
    free(w);
}

static void gen_final(gen_t *g, const char *name, const char *json)
{
    store_rec_writer_t *w = malloc(sizeof *w);
    if (!w)
        die("out of memory");
    rec_begin(g, w, "final", STORE_KIND_FINAL);
    if (store_rec_write_block(w, json, strlen(json)) < 0)
        die("%s", w->err);
    size_t len;
    uint8_t *data = commit_and_read(w, &len);
    emit_record(g, name, STORE_KIND_FINAL, data, len);
    free(data);
    free(w);
}

/* ---- checkpoints ----------------------------------------------------------------- */

static void fake_results(const sched_task_t *t, tracer_result_t *r)
{
    for (uint32_t i = 0; i < t->count; i++) {
        const tracer_task_t *k = &t->records[i];
        memset(&r[i], 0, sizeof r[i]);
        r[i].pixel = k->pixel;
        r[i].samples =
            k->sample_count - (k->pixel == 1 && k->first_sample == 0); /* one NaN sample */
        r[i].nonfinite = k->sample_count - r[i].samples;
        r[i].rays = 3 * k->sample_count + k->pixel % 5;
        for (int c = 0; c < 3; c++)
            r[i].sum[c] =
                0.25 * k->sample_count * (c + 1) + 1e-3 * k->prior_sum[c] + 1e-4 * k->pixel;
        r[i].lum_m2 = 0.01 * k->sample_count;
        r[i].pvar = (double)((k->pixel * 7 + k->first_sample * 3) % 11);
    }
}

/* Runs s until `complete` tasks are done, leaving `out` more handed out. */
static void run_tasks(sched_t *s, int complete, int out)
{
    sched_task_t held[8];
    tracer_result_t res[64];
    char err[512];
    int done = 0;
    while (done < complete) {
        int n = 0;
        while (n < 2 && sched_next(s, &held[n]) == SCHED_NEXT_TASK)
            n++;
        if (n == 0)
            return; /* finished */
        for (int i = 0; i < n; i++) {
            fake_results(&held[i], res);
            if (sched_complete(s, held[i].id, res, held[i].count, err, sizeof err) != SCHED_OK)
                die("sched_complete: %s", err);
            done++;
        }
    }
    for (int i = 0; i < out && sched_next(s, &held[0]) == SCHED_NEXT_TASK; i++)
        ;
}

/* As write_checkpoint writes it; returns the record file's bytes. */
static uint8_t *checkpoint_record(gen_t *g, const sched_t *s, const char *extras, size_t *n)
{
    store_rec_writer_t *w = malloc(sizeof *w);
    if (!w)
        die("out of memory");
    rec_begin(g, w, "checkpoint", STORE_KIND_CHECKPOINT);
    if (store_rec_write_block(w, extras, strlen(extras)) < 0 ||
        sched_save(s, store_rec_write, w) != 0)
        die("checkpoint: %s", w->err);
    uint8_t *data = commit_and_read(w, n);
    free(w);
    return data;
}

/* The checkpoint must load through the master's own reading of it. */
static void check_loads(const uint8_t *file, size_t n, const sched_config_t *cfg, const char *name)
{
    store_rec_t rec;
    char err[1024];
    const uint8_t *text;
    size_t len;
    if (store_rec_parse(file, n, STORE_KIND_CHECKPOINT, &rec, err, sizeof err) < 0 ||
        store_rec_read_block(&rec, &text, &len) < 0)
        die("%s: %s", name, err);
    size_t start = rec.pos;
    uint8_t *copy = malloc(rec.size - start);
    if (!copy)
        die("out of memory");
    memcpy(copy, rec.data + start, rec.size - start);
    fuzz_fix_sched_checksum(copy, rec.size - start);
    if (memcmp(copy, rec.data + start, rec.size - start) != 0)
        die("fuzzmaster.h's fuzz_sched_checksum no longer matches sched_save.c's checksum");
    free(copy);
    sched_t *s = sched_load(cfg, store_rec_read, &rec, err, sizeof err);
    if (!s)
        die("%s: the checkpoint does not load: %s", name, err);
    sched_destroy(&s);
    store_rec_free(&rec);
}

static void gen_checkpoints(gen_t *g)
{
    static const struct {
        int complete, out;
    } points[] = {{0, 0}, {3, 2}, {14, 1}, {1000000, 0}};
    static const char *const extras[] = {
        "{\"seconds\":0,\"rays\":0,\"busy_us\":0,\"reissued\":0,\"late_results\":0,\"failures\":0}",
        "{\"seconds\":1.5,\"rays\":12345,\"busy_us\":2500000,\"reissued\":2,\"late_results\":1,"
        "\"failures\":1,"
        "\"series\":[[0.5,96,0.25,0.125,288],[1,192,0.125,0.0625,600]]}",
    };
    for (unsigned c = 0; c < FUZZ_CKPT_CONFIGS; c++) {
        sched_config_t cfg;
        fuzz_ckpt_config(c, &cfg);
        char err[512];
        sched_t *s = sched_new(&cfg, err, sizeof err);
        if (!s)
            die("config %c: %s", 'A' + c, err);
        int done = 0;
        for (size_t p = 0; p < sizeof points / sizeof points[0]; p++) {
            run_tasks(s, points[p].complete - done, points[p].out);
            done = points[p].complete;
            size_t n;
            uint8_t *file = checkpoint_record(g, s, extras[p % 2], &n);
            char name[64];
            snprintf(name, sizeof name, "%c-%zu", 'A' + c, p);
            check_loads(file, n, &cfg, name);
            /* fuzz_ckpt: K = config, checksum repair on */
            char fname[80];
            snprintf(fname, sizeof fname, "%s.bin", name);
            emit_k(g, "ckpt", fname, (uint8_t)(c | 4), file + FUZZ_REC_HEADER,
                   n - FUZZ_REC_HEADER - FUZZ_REC_TRAILER);
            /* fuzz_store: config A's, as whole files and payloads */
            if (c == 0 && (p == 1 || p == 3))
                emit_record(g, name, STORE_KIND_CHECKPOINT, file, n);
            free(file);
            /* a restored scheduler carries on: later points come from it */
            sched_t *again = NULL;
            file = checkpoint_record(g, s, extras[0], &n);
            store_rec_t rec;
            const uint8_t *text;
            size_t len;
            if (store_rec_parse(file, n, STORE_KIND_CHECKPOINT, &rec, err, sizeof err) == 0 &&
                store_rec_read_block(&rec, &text, &len) == 0)
                again = sched_load(&cfg, store_rec_read, &rec, err, sizeof err);
            if (!again)
                die("%s: cannot restore: %s", name, err);
            store_rec_free(&rec);
            free(file);
            sched_destroy(&s);
            s = again;
        }
        sched_destroy(&s);
    }
}

/* ---- EXR --------------------------------------------------------------------------- */

static void quiet(exr_const_context_t c, exr_result_t code, const char *msg)
{
    (void)c;
    (void)code;
    (void)msg;
}

typedef struct chan {
    const char *name;
    exr_pixel_type_t type;
} chan_t;

/* An EXR that image_write_exr never writes (test_image.c's write_custom_exr,
 * smaller): channels of any type holding a ramp, any compression, scanline
 * or tiled (tiles of 4 x 4). */
static int write_custom_exr(const char *path, int tiled, int w, int h, exr_compression_t comp,
                            const chan_t *chs, int n)
{
    uint8_t data[4][4 * 64 * 64];
    for (int c = 0; c < n; c++)
        for (int i = 0; i < w * h; i++) {
            float f = 0.125f * (float)i + (float)c;
            uint32_t u = (uint32_t)i * 3u + (uint32_t)c;
            uint16_t half = (uint16_t)(0x3C00 + (i & 0x3FF)); /* 1.0 and up */
            if (chs[c].type == EXR_PIXEL_HALF)
                memcpy(data[c] + 2 * i, &half, 2);
            else
                memcpy(data[c] + 4 * i, chs[c].type == EXR_PIXEL_UINT ? (void *)&u : (void *)&f, 4);
        }
    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    init.error_handler_fn = quiet;
    exr_context_t ctx = NULL;
    exr_result_t rv = exr_start_write(&ctx, path, EXR_WRITE_FILE_DIRECTLY, &init);
    if (rv)
        return rv;
    int part = 0;
    const int tile = 4;
    rv = exr_add_part(ctx, NULL, tiled ? EXR_STORAGE_TILED : EXR_STORAGE_SCANLINE, &part);
    if (!rv)
        rv = exr_initialize_required_attr_simple(ctx, part, w, h, comp);
    if (!rv && tiled)
        rv =
            exr_set_tile_descriptor(ctx, part, tile, tile, EXR_TILE_ONE_LEVEL, EXR_TILE_ROUND_DOWN);
    for (int c = 0; !rv && c < n; c++)
        rv = exr_add_channel(ctx, part, chs[c].name, chs[c].type, EXR_PERCEPTUALLY_LOGARITHMIC, 1,
                             1);
    if (!rv)
        rv = exr_attr_set_float(ctx, part, "fattr", 0.5f);
    if (!rv)
        rv = exr_attr_set_string(ctx, part, "vb.note", "seed");
    if (!rv)
        rv = exr_write_header(ctx);
    int32_t lines = 1;
    if (!rv && !tiled)
        rv = exr_get_scanlines_per_chunk(ctx, part, &lines);
    exr_encode_pipeline_t enc = EXR_ENCODE_PIPELINE_INITIALIZER;
    int inited = 0;
    int step_y = tiled ? tile : lines, step_x = tiled ? tile : w;
    for (int y = 0; !rv && y < h; y += step_y)
        for (int x = 0; !rv && x < w; x += step_x) {
            exr_chunk_info_t ci;
            rv = tiled ? exr_write_tile_chunk_info(ctx, part, x / tile, y / tile, 0, 0, &ci)
                       : exr_write_scanline_chunk_info(ctx, part, y, &ci);
            if (!rv)
                rv = inited ? exr_encoding_update(ctx, part, &ci, &enc)
                            : exr_encoding_initialize(ctx, part, &ci, &enc);
            if (rv)
                break;
            inited = 1;
            for (int c = 0; c < enc.channel_count; c++) {
                exr_coding_channel_info_t *ch = &enc.channels[c];
                int k = 0;
                while (k < n && strcmp(chs[k].name, ch->channel_name) != 0)
                    k++;
                int bpe = chs[k].type == EXR_PIXEL_HALF ? 2 : 4;
                ch->encode_from_ptr = data[k] + ((size_t)y * (size_t)w + (size_t)x) * (size_t)bpe;
                ch->user_pixel_stride = bpe;
                ch->user_line_stride = w * bpe;
                ch->user_bytes_per_element = (int16_t)bpe;
                ch->user_data_type = (uint16_t)chs[k].type;
            }
            rv = exr_encoding_choose_default_routines(ctx, part, &enc);
            if (!rv)
                rv = exr_encoding_run(ctx, part, &enc);
        }
    if (inited)
        exr_encoding_destroy(ctx, &enc);
    exr_result_t frv = exr_finish(&ctx);
    return rv ? rv : frv;
}

static void emit_exr_file(gen_t *g, const char *path, const char *name)
{
    image_t *img = NULL;
    char err[512];
    if (image_read_exr(path, &img, err, sizeof err) < 0)
        die("%s: image_read_exr refuses the seed: %s", name, err);
    image_destroy(&img);
    size_t n;
    uint8_t *data = read_all(path, &n);
    if (!data)
        die("cannot read %s", path);
    emit(g, "exr", name, data, n);
    free(data);
    unlink(path);
}

static void gen_exr(gen_t *g)
{
    char path[512], err[512];
    snprintf(path, sizeof path, "%s/seed.exr", g->tmp);
    /* image_write_exr's own: the master's final images, vbrender's output */
    static const struct {
        int w, h, attrs;
        const char *chans[5];
    } own[] = {{4, 3, 1, {"R", "G", "B", "samples", "variance"}},
               {1, 1, 0, {"Y"}},
               {7, 2, 1, {"R", "G", "B"}}};
    for (size_t i = 0; i < sizeof own / sizeof own[0]; i++) {
        image_t *img = image_new(own[i].w, own[i].h);
        for (int c = 0; c < 5 && own[i].chans[c]; c++) {
            float *p = image_add_channel(img, own[i].chans[c]);
            for (int k = 0; k < own[i].w * own[i].h; k++)
                p[k] = 0.5f * (float)k + (float)c;
        }
        if (own[i].attrs) {
            image_set_string(img, "vb.scene", "cornell-box.json");
            image_set_int(img, "vb.spp", 64);
            image_set_double(img, "vb.seconds", 1.25);
            image_set_string(img, "a.very.long.attribute.name.beyond.thirty.one.chars", "x");
        }
        if (image_write_exr(img, path, err, sizeof err) < 0)
            die("%s", err);
        image_destroy(&img);
        char name[64];
        snprintf(name, sizeof name, "own-%zu.exr", i);
        emit_exr_file(g, path, name);
    }
    static const chan_t mixed[3] = {
        {"H", EXR_PIXEL_HALF}, {"U", EXR_PIXEL_UINT}, {"F", EXR_PIXEL_FLOAT}};
    static const chan_t halfs[3] = {
        {"B", EXR_PIXEL_HALF}, {"G", EXR_PIXEL_HALF}, {"R", EXR_PIXEL_HALF}};
    static const struct {
        const char *name;
        int tiled, w, h;
        exr_compression_t comp;
        const chan_t *chs;
    } custom[] = {
        {"none-mixed", 0, 5, 3, EXR_COMPRESSION_NONE, mixed},
        {"rle-mixed", 0, 5, 3, EXR_COMPRESSION_RLE, mixed},
        {"zips-mixed", 0, 5, 3, EXR_COMPRESSION_ZIPS, mixed},
        {"zip-mixed", 0, 6, 20, EXR_COMPRESSION_ZIP, mixed},
        {"piz-mixed", 0, 6, 5, EXR_COMPRESSION_PIZ, mixed},
        {"pxr24-mixed", 0, 5, 3, EXR_COMPRESSION_PXR24, mixed},
        {"b44-half", 0, 8, 8, EXR_COMPRESSION_B44, halfs},
        {"b44a-half", 0, 8, 4, EXR_COMPRESSION_B44A, halfs},
        {"tiled-none", 1, 9, 7, EXR_COMPRESSION_NONE, mixed},
        {"tiled-zip", 1, 6, 5, EXR_COMPRESSION_ZIP, mixed},
        {"tiled-rle-half", 1, 4, 4, EXR_COMPRESSION_RLE, halfs},
    };
    for (size_t i = 0; i < sizeof custom / sizeof custom[0]; i++) {
        int rv = write_custom_exr(path, custom[i].tiled, custom[i].w, custom[i].h, custom[i].comp,
                                  custom[i].chs, 3);
        if (rv)
            die("%s: the OpenEXR library cannot write it (%d)", custom[i].name, rv);
        char name[64];
        snprintf(name, sizeof name, "%s.exr", custom[i].name);
        emit_exr_file(g, path, name);
    }
}

/* ---- journals ------------------------------------------------------------------- */

/* A journal as the master writes it: the header, then commits of merged
 * tasks (synthetic results: exact, NaN/Inf counts, large sums) and counters. */
static void gen_journal(gen_t *g, const char *name, uint32_t flags, int commits)
{
    journal_header_t h = {.version = JOURNAL_VERSION, .flags = flags, .generation = 3, .job = 42};
    uint8_t head[JOURNAL_HEADER_SIZE];
    journal_header_encode(&h, head);
    journal_t *j = journal_new(h.job, h.generation, flags);
    if (!j)
        die("out of memory");
    tracer_result_t r[6];
    uint64_t task = 1;
    for (int c = 0; c < commits; c++) {
        for (int t = 0; t < 2; t++, task++) {
            uint32_t n = (uint32_t)(task % 3 + (t ? 4 : 1));
            for (uint32_t i = 0; i < n; i++)
                r[i] = (tracer_result_t){.pixel = i,
                                         .samples = 8 - (i & 1),
                                         .nonfinite = i & 1,
                                         .rays = 8 + i,
                                         .sum = {0.5 * i, 1e3 + c, i ? 1e30 : 0},
                                         .lum_m2 = 0.25 * i,
                                         .pvar = 0.125 * (double)(task + i)};
            if (journal_note(j, task, r, n) < 0)
                die("out of memory");
        }
        char extras[128];
        snprintf(extras, sizeof extras,
                 "{\"seconds\":%d.5,\"rays\":%d,\"busy_us\":%d,\"series\":[[1,2,3,4,5]]}", c,
                 1000 * (c + 1), 77 * c);
        if (journal_seal(j, extras, strlen(extras)) < 0)
            die("out of memory");
    }
    uint8_t *body;
    size_t n;
    journal_take_unwritten(j, &body, &n);
    uint8_t *file = malloc(sizeof head + n + 1);
    if (!file)
        die("out of memory");
    memcpy(file, head, sizeof head);
    if (n)
        memcpy(file + sizeof head, body, n);
    emit(g, "journal", name, file, sizeof head + n);
    free(file);
    free(body);
    journal_destroy(&j);
}

static void gen_journals(gen_t *g)
{
    gen_journal(g, "empty", 0, 0);
    gen_journal(g, "plain-1", 0, 1);
    gen_journal(g, "plain-3", 0, 3);
    gen_journal(g, "pvar-2", JOURNAL_PVAR, 2);
    gen_journal(g, "relmse-2", JOURNAL_RAYS | JOURNAL_NF8, 2); /* the default mode's */
    gen_journal(g, "thesis-2", JOURNAL_PVAR | JOURNAL_NF8, 2);
}

int main(int argc, char **argv)
{
    gen_t g = {0};
    if (argc == 3 && strcmp(argv[1], "--check") == 0) {
        g.check = 1;
        g.root = argv[2];
    } else if (argc == 2 && argv[1][0] != '-') {
        g.root = argv[1];
    } else {
        fprintf(stderr, "usage: gen_fuzz_seeds [--check] DATA_DIR\n");
        return 2;
    }
    const char *base = getenv("TMPDIR") ? getenv("TMPDIR") : "/tmp";
    snprintf(g.tmp, sizeof g.tmp, "%s/vb-fuzz-seeds.XXXXXX", base);
    if (!mkdtemp(g.tmp))
        die("mkdtemp %s: %s", g.tmp, strerror(errno));

    request_t req[16];
    int nreq = make_requests(req);
    gen_ctl(&g, req, nreq);
    gen_meta(&g);
    for (int i = 0; i < 3; i++)
        gen_submit_record(&g, &req[i]);
    gen_final(
        &g, "done",
        "{\"id\":2,\"state\":\"done\",\"scene\":\"basic.json\",\"request_id\":\"fuzz-seed_2\","
        "\"width\":8,\"height\":6,\"spp\":8,\"samples\":384,\"error_series\":[[0.5,96,0.25,0.125,"
        "288]]"
        "}");
    gen_final(&g, "cancelled",
              "{\"id\":7,\"state\":\"cancelled\",\"scene\":\"mesh.json\",\"error\":\"cancelled by "
              "a client\"}");
    gen_checkpoints(&g);
    gen_journals(&g);
    if (!g.check)
        gen_exr(&g);
    rmdir(g.tmp);
    if (g.check) {
        if (g.failed) {
            fprintf(
                stderr,
                "gen_fuzz_seeds: %d of %d seed files are stale: run `make fuzz-seeds` and commit "
                "tests/data/fuzz-*\n",
                g.failed, g.compared);
            return 1;
        }
        printf("gen_fuzz_seeds: %d seed files as the writers make them\n", g.compared);
    } else {
        printf("gen_fuzz_seeds: %d seed files written under %s\n", g.written, g.root);
    }
    return 0;
}
