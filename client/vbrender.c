/* vbrender.c - the command-line client.
 *
 *   vbrender render SCENE.json [-o OUT.exr] [job settings] [--workers N] [--threads T]
 *   vbrender submit SCENE.json [job settings] [--master EP]   (prints the job id last)
 *   vbrender status [JOB] | wait JOB | fetch JOB -o OUT.exr | cancel JOB | delete JOB | jobs |
 * workers vbrender keygen NAME   (NAME.key and NAME.pub: a CURVE key pair)
 *
 * The commands for a running master take --key client.key --master-key
 * master.pub (or VBRENDER_KEY, VBRENDER_MASTER_KEY) for a master that uses
 * CURVE keys.
 *
 * `render` is the embedded default: it runs the same master and worker code
 * in this process over ZeroMQ's inproc transport, so its pixels equal those
 * of a distributed run with the same settings.
 *
 * Exit status: 0 done, 1 the work failed (bad scene, job failed or
 * cancelled, I/O, no master), 2 bad usage.
 *
 * `submit` and `wait` outlast a master restart: while the master does not
 * answer they ask again (a submit with the same request id, so the job is
 * queued once) for up to --timeout seconds.
 */
#include <errno.h>
#include <inttypes.h>
#include <math.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#include <zmq.h>

#include "compare.h"
#include "control.h"
#include "image.h"
#include "keys.h"
#include "master.h"
#include "progress.h"
#include "render.h"
#include "sched.h"
#include "serve.h"
#include "worker.h"

#define DEFAULT_MASTER "tcp://localhost:7071"
#define DEFAULT_TIMEOUT_S 300.0  /* submit, wait: how long a master may stay away */
#define REQUEST_TIMEOUT_MS 10000 /* a request to a master (one try) */

static const char usage_text[] =
    "usage: vbrender COMMAND ...\n"
    "\n"
    "  render SCENE.json [-o OUT.exr] [settings] [--workers N] [--threads T]\n"
    "        render on this machine (a master and N local workers in this process)\n"
    "  submit SCENE.json [settings] [--master EP] [--timeout S]   queue a job; prints its id last\n"
    "  status [JOB]      a job's state (all jobs without JOB)\n"
    "  wait JOB [--timeout S]   progress until the job ends; exit 1 if it failed or was\n"
    "                    cancelled, or if the master stayed away for S seconds\n"
    "  fetch JOB -o OUT.exr   the image (also OUT.png and OUT-samples.png, a heat map)\n"
    "  cancel JOB        stop a job (its image so far can still be fetched)\n"
    "  readmit WORKER    let a quarantined worker in again (its key, or its address\n"
    "                    without keys; admins only)\n"
    "  delete JOB        cancel a job if it runs, then remove it, its image and its\n"
    "                    saved state from the master\n"
    "  jobs              all jobs\n"
    "  workers           connected workers: host, threads, rays/s, tasks done\n"
    "  serve [--master EP] [--listen ADDR:PORT]   a web dashboard and Prometheus metrics\n"
    "                    (/metrics) at http://127.0.0.1:8080/; --listen another address\n"
    "                    (0.0.0.0:8080) serves other machines too: anybody reaching it\n"
    "                    sees the jobs and may cancel them with this client's key\n"
    "  keygen NAME       a CURVE key pair: NAME.key (secret, mode 0600) and NAME.pub\n"
    "                    (the public key, for the master's allow-lists or --master-key)\n"
    "  compare A.exr REF.exr [--threshold E] [--error-map OUT.png]\n"
    "        error of A against REF: relMSE, RMSE, mean abs. relative error, max,\n"
    "        share of pixels with relative error above E (default 0.05)\n"
    "\n"
    "settings (render and submit):\n"
    "  --spp N                 most samples per pixel (default: the scene's)\n"
    "  --granularity G         samples per pixel per layer (default 32)\n"
    "  --adaptive MODE         thesis (eq. 4.1, default), variance (of the pixel mean),\n"
    "                          relerr (t-bound of layer means over mean) or none (uniform)\n"
    "  --random-selection      pixels below the threshold still run with probability m/T\n"
    "  --dilate                also sample the neighbours of selected pixels\n"
    "  --target-error E        stop a pixel when its confidence half-width <= E x mean,\n"
    "  --confidence C          at confidence C (default 0.95); the job stops when\n"
    "  --target-share S        a share S of the pixels have (default 1)\n"
    "  --reference REF.exr     track the error against REF over time and samples\n"
    "                          (OUT.error.json beside the image)\n"
    "  --uniform-layers K      layers before the skip rule applies (default: half)\n"
    "  --flags 0011...         the thesis's flag sequence: 1 where a layer applies the\n"
    "                          skip rule, one per layer (overrides --uniform-layers)\n"
    "  --seed S                random seed (default: the scene's)\n"
    "  --time-limit SECONDS    stop issuing work after this long\n"
    "  --integrator path|naive path: NEE + MIS (default); naive: light only when hit\n"
    "  --max-depth D           most path segments (default 0: unlimited)\n"
    "\n"
    "other options:\n"
    "  --master EP             control endpoint (default " DEFAULT_MASTER ")\n"
    "  --key FILE              this client's key pair, for a master that uses CURVE\n"
    "                          keys (default: $VBRENDER_KEY)\n"
    "  --master-key FILE       that master's public key (default: $VBRENDER_MASTER_KEY)\n"
    "  --timeout SECONDS       submit, wait: while the master does not answer (say it\n"
    "                          restarts), ask again for this long (default 300)\n"
    "  --workers N             render: local workers (default 1)\n"
    "  --threads T             render: threads in all (default: all cores)\n"
    "  --progress MODE         auto, bar, lines or none (default auto)\n"
    "  -h, --help              this text\n";

static int usage_error(const char *fmt, const char *arg)
{
    fprintf(stderr, "vbrender: ");
    fprintf(stderr, fmt, arg);
    fprintf(stderr, "\n(run 'vbrender --help' for usage)\n");
    return 2;
}

static int parse_u64(const char *s, uint64_t lo, uint64_t hi, uint64_t *out)
{
    if (!s || !*s || *s == '-' || *s == '+')
        return -1;
    errno = 0;
    char *end;
    unsigned long long v = strtoull(s, &end, 10);
    if (errno || *end || v < lo || v > hi)
        return -1;
    *out = v;
    return 0;
}

static void replace_extension(const char *path, const char *ext, char *out, size_t len)
{
    snprintf(out, len, "%s", path);
    char *dot = strrchr(out, '.'), *slash = strrchr(out, '/');
    if (dot && (!slash || dot > slash))
        *dot = '\0';
    size_t n = strlen(out);
    snprintf(out + n, len - n, "%s", ext);
}

/* ---- arguments ------------------------------------------------------------------ */

typedef struct args {
    const char *positional;
    const char *output;
    const char *reference; /* --reference REF.exr */
    const char *master;
    const char *key_file, *master_key_file; /* --key, --master-key */
    cJSON *settings;                        /* submit fields */
    double timeout_s;                       /* --timeout */
    uint64_t workers, threads;
    progress_mode_t progress;
    int have_workers, have_threads;
} args_t;

static int parse_args(int argc, char **argv, args_t *a, int allow_settings, int allow_output,
                      int allow_timeout)
{
    a->settings = cJSON_CreateObject();
    a->master = DEFAULT_MASTER;
    a->timeout_s = DEFAULT_TIMEOUT_S;
    a->workers = 1;
    long cores = sysconf(_SC_NPROCESSORS_ONLN);
    a->threads = cores > 0 ? (uint64_t)cores : 1;
    a->progress = PROGRESS_AUTO;
    for (int i = 0; i < argc; i++) {
        const char *o = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        uint64_t n;
        int takes = 1;
        if (allow_output && (strcmp(o, "-o") == 0 || strcmp(o, "--output") == 0)) {
            if (!v || v[0] == '-')
                return usage_error("%s needs a file name", o);
            a->output = v;
        } else if (strcmp(o, "--master") == 0) {
            if (!v || !*v)
                return usage_error("%s needs an endpoint such as tcp://host:7071", o);
            a->master = v;
        } else if (strcmp(o, "--key") == 0 || strcmp(o, "--master-key") == 0) {
            if (!v || !*v)
                return usage_error("%s needs a file name", o);
            if (strcmp(o, "--key") == 0)
                a->key_file = v;
            else
                a->master_key_file = v;
        } else if (allow_timeout && strcmp(o, "--timeout") == 0) {
            char *end;
            errno = 0;
            double t = v ? strtod(v, &end) : -1;
            if (!v || errno || *end || !(t > 0) || !(t <= 1e9))
                return usage_error("--timeout needs a number of seconds > 0 (got '%s')",
                                   v ? v : "");
            a->timeout_s = t;
        } else if (strcmp(o, "--progress") == 0) {
            if (v && strcmp(v, "auto") == 0)
                a->progress = PROGRESS_AUTO;
            else if (v && strcmp(v, "bar") == 0)
                a->progress = PROGRESS_BAR;
            else if (v && strcmp(v, "lines") == 0)
                a->progress = PROGRESS_LINES;
            else if (v && strcmp(v, "none") == 0)
                a->progress = PROGRESS_NONE;
            else
                return usage_error("--progress must be auto, bar, lines or none (got '%s')",
                                   v ? v : "");
        } else if (allow_settings && strcmp(o, "--workers") == 0) {
            if (parse_u64(v, 1, 64, &a->workers) < 0)
                return usage_error("--workers needs an integer from 1 to 64 (got '%s')",
                                   v ? v : "");
            a->have_workers = 1;
        } else if (allow_settings && strcmp(o, "--threads") == 0) {
            if (parse_u64(v, 1, RENDER_MAX_THREADS, &a->threads) < 0)
                return usage_error("--threads needs an integer from 1 to 256 (got '%s')",
                                   v ? v : "");
            a->have_threads = 1;
        } else if (allow_settings && strcmp(o, "--spp") == 0) {
            if (parse_u64(v, 1, UINT32_MAX, &n) < 0)
                return usage_error("--spp needs an integer from 1 to 4294967295 (got '%s')",
                                   v ? v : "");
            cJSON_AddNumberToObject(a->settings, "spp", (double)n);
        } else if (allow_settings && strcmp(o, "--granularity") == 0) {
            if (parse_u64(v, 1, TRACER_MAX_TASK_SAMPLES, &n) < 0)
                return usage_error("--granularity needs an integer from 1 to 4096 (got '%s')",
                                   v ? v : "");
            cJSON_AddNumberToObject(a->settings, "granularity", (double)n);
        } else if (allow_settings && strcmp(o, "--uniform-layers") == 0) {
            if (parse_u64(v, 0, 1000000, &n) < 0)
                return usage_error("--uniform-layers needs an integer from 0 to 1000000 (got '%s')",
                                   v ? v : "");
            cJSON_AddNumberToObject(a->settings, "uniform_layers", (double)n);
        } else if (allow_settings && strcmp(o, "--flags") == 0) {
            if (!v || !*v || strspn(v, "01") != strlen(v))
                return usage_error("--flags needs a sequence of 0 and 1, one per layer (got '%s')",
                                   v ? v : "");
            cJSON_AddStringToObject(a->settings, "flags", v);
        } else if (allow_settings && strcmp(o, "--seed") == 0) {
            if (parse_u64(v, 0, 9007199254740992ULL, &n) < 0)
                return usage_error("--seed needs an integer from 0 to 2^53 (got '%s')", v ? v : "");
            cJSON_AddNumberToObject(a->settings, "seed", (double)n);
        } else if (allow_settings && strcmp(o, "--max-depth") == 0) {
            if (parse_u64(v, 0, 1000000, &n) < 0)
                return usage_error("--max-depth needs an integer from 0 to 1000000 (got '%s')",
                                   v ? v : "");
            cJSON_AddNumberToObject(a->settings, "max_depth", (double)n);
        } else if (allow_settings && strcmp(o, "--time-limit") == 0) {
            char *end;
            errno = 0;
            double t = v ? strtod(v, &end) : -1;
            if (!v || errno || *end || !(t > 0) || !isfinite(t))
                return usage_error("--time-limit needs a number of seconds > 0 (got '%s')",
                                   v ? v : "");
            cJSON_AddNumberToObject(a->settings, "time_limit", t);
        } else if (allow_settings && strcmp(o, "--adaptive") == 0) {
            if (!v || sched_adaptive_from_name(v) < 0)
                return usage_error("--adaptive must be thesis, variance, relerr or none (got '%s')",
                                   v ? v : "");
            cJSON_AddStringToObject(a->settings, "adaptive", v);
        } else if (allow_settings &&
                   (strcmp(o, "--target-error") == 0 || strcmp(o, "--confidence") == 0 ||
                    strcmp(o, "--target-share") == 0)) {
            char *end;
            errno = 0;
            double t = v ? strtod(v, &end) : -1;
            int conf = strcmp(o, "--confidence") == 0;
            if (!v || errno || *end || !(t > 0) || !isfinite(t) || (conf && !(t < 1)) ||
                (strcmp(o, "--target-share") == 0 && t > 1))
                return usage_error(conf ? "--confidence needs a probability in (0, 1) (got '%s')"
                                        : "%s needs a positive number (a share: at most 1)",
                                   conf ? (v ? v : "") : o);
            cJSON_AddNumberToObject(a->settings,
                                    conf          ? "confidence"
                                    : o[9] == 'e' ? "target_error"
                                                  : "target_share",
                                    t);
        } else if (allow_settings && strcmp(o, "--random-selection") == 0) {
            cJSON_AddTrueToObject(a->settings, "random_selection");
            takes = 0;
        } else if (allow_settings && strcmp(o, "--dilate") == 0) {
            cJSON_AddTrueToObject(a->settings, "dilate");
            takes = 0;
        } else if (allow_settings && strcmp(o, "--reference") == 0) {
            if (!v || v[0] == '-')
                return usage_error("%s", "--reference needs an EXR file");
            a->reference = v;
        } else if (allow_settings && strcmp(o, "--integrator") == 0) {
            if (!v || scene_integrator_from_name(v) < 0)
                return usage_error("--integrator must be path or naive (got '%s')", v ? v : "");
            cJSON_AddStringToObject(a->settings, "integrator", v);
        } else if (o[0] == '-' && o[1] != '\0') {
            return usage_error("unknown option '%s'", o);
        } else {
            takes = 0;
            if (a->positional)
                return usage_error("unexpected argument '%s'", o);
            a->positional = o;
        }
        i += takes;
    }
    return 0;
}

static int parse_job_id(const char *s, unsigned long long *out)
{
    uint64_t v;
    if (parse_u64(s, 1, UINT64_MAX, &v) < 0)
        return -1;
    *out = v;
    return 0;
}

/* ---- shared output ------------------------------------------------------------- */

static const char *jstr(const cJSON *o, const char *k)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(o, k);
    return cJSON_IsString(v) ? v->valuestring : "";
}

static double jnum(const cJSON *o, const char *k)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(o, k);
    return cJSON_IsNumber(v) ? v->valuedouble : 0.0;
}

static int job_ended(const cJSON *job)
{
    const char *s = jstr(job, "state");
    return strcmp(s, "done") == 0 || strcmp(s, "failed") == 0 || strcmp(s, "cancelled") == 0;
}

static double job_fraction(const cJSON *job)
{
    double layers = jnum(job, "layers"), done = jnum(job, "layers_done");
    double s = jnum(job, "samples"), max = jnum(job, "max_samples");
    double f1 = layers > 0 ? done / layers : 0, f2 = max > 0 ? s / max : 0;
    return f1 > f2 ? f1 : f2;
}

static void progress_detail(const cJSON *job, char *buf, size_t len)
{
    char a[32], b[32];
    double frac = job_fraction(job), el = jnum(job, "seconds");
    double eta = frac > 0 ? el / frac - el : 0;
    int n = snprintf(buf, len, "layer %.0f/%.0f, %s samples, %s rays/s, ETA %.0fs",
                     jnum(job, "layers_done"), jnum(job, "layers"),
                     render_si(jnum(job, "samples"), a, sizeof a),
                     render_si(jnum(job, "rays_per_second"), b, sizeof b), eta);
    if (cJSON_GetObjectItemCaseSensitive(job, "relmse") && n > 0 && (size_t)n < len)
        snprintf(buf + n, len - (size_t)n, ", relMSE %.3g", jnum(job, "relmse"));
}

/* What wait shows on stderr: the progress, and lines between its updates. */
typedef struct wait_view {
    progress_t *prog;
    int bar;   /* the progress is a bar redrawn in place */
    int drawn; /* ... and it is on the screen: end its line before another */
    char storage_error[512], recovered[512]; /* as last shown */
    char waiting_for[64];                    /* verification: the worker awaited */
} wait_view_t;

/* Ends a half-drawn bar's line, so a message does not overwrite it; the
 * next update draws the bar again below the message. */
static void view_break(wait_view_t *v)
{
    if (v && v->bar && v->drawn) {
        fputc('\n', stderr);
        v->drawn = 0;
    }
}

static void say_outage(void *arg, const char *endpoint, double timeout_s)
{
    view_break(arg);
    fprintf(stderr, "vbrender: master at %s not answering; retrying (up to %g s)\n", endpoint,
            timeout_s);
    fflush(stderr);
}

/* Says what the master reports about a job's state files, once per new text. */
static void show_job_notes(wait_view_t *v, unsigned long long job, const cJSON *st)
{
    const char *se = jstr(st, "storage_error"), *rec = jstr(st, "recovered");
    if (*se && strncmp(se, v->storage_error, sizeof v->storage_error - 1) != 0) {
        view_break(v);
        fprintf(stderr, "vbrender: job %llu: storage error: %s\n", job, se);
        snprintf(v->storage_error, sizeof v->storage_error, "%s", se);
    }
    if (*rec && strncmp(rec, v->recovered, sizeof v->recovered - 1) != 0) {
        view_break(v);
        fprintf(stderr, "vbrender: job %llu: recovered from %s\n", job, rec);
        snprintf(v->recovered, sizeof v->recovered, "%s", rec);
    }
    /* --verify-share 1 without a second worker: the job makes no progress */
    const char *wf = jstr(st, "waiting_for");
    if (*wf && strcmp(wf, v->waiting_for) != 0) {
        view_break(v);
        fprintf(stderr, "vbrender: job %llu: %.0f tasks wait for %s to verify them\n", job,
                jnum(st, "verify_waiting"), wf);
    }
    snprintf(v->waiting_for, sizeof v->waiting_for, "%s", wf);
}

/* Polls status until the job ends; returns the final status, or NULL with
 * a message (one saying the job may still run when the master stayed away
 * for timeout_s; timeout_s <= 0: no retries). */
static cJSON *wait_job(control_t *c, unsigned long long job, progress_mode_t mode, double timeout_s,
                       char *err, size_t errlen)
{
    char label[32];
    snprintf(label, sizeof label, "job %llu", job);
    wait_view_t view;
    memset(&view, 0, sizeof view);
    view.prog = progress_new(stderr, mode, label);
    view.bar = mode == PROGRESS_BAR || (mode == PROGRESS_AUTO && isatty(fileno(stderr)));
    control_retry_t retry = {timeout_s, say_outage, &view, 0};
    cJSON *req = cJSON_CreateObject();
    cJSON_AddStringToObject(req, "cmd", "status");
    cJSON_AddNumberToObject(req, "job", (double)job);
    cJSON *st = NULL;
    for (;;) {
        /* status is safe to ask again: a restarted master answers it anew */
        cJSON *reply = control_request_retry(c, req, NULL, NULL, 0, &retry, err, errlen);
        if (!reply) {
            if (retry.unreachable) {
                size_t n = strlen(err);
                if (n < errlen)
                    snprintf(err + n, errlen - n, "; job %llu may still be running", job);
            }
            break;
        }
        if (!cJSON_IsTrue(cJSON_GetObjectItemCaseSensitive(reply, "ok"))) {
            /* e.g. "no such job" from a master that restarted without it */
            const char *e = jstr(reply, "error");
            snprintf(err, errlen, "job %llu: %s", job,
                     *e ? e : "the master refused the status request");
            cJSON_Delete(reply);
            break;
        }
        cJSON_Delete(st);
        st = cJSON_DetachItemFromObject(reply, "job");
        cJSON_Delete(reply);
        show_job_notes(&view, job, st);
        char detail[160];
        progress_detail(st, detail, sizeof detail);
        if (job_ended(st)) {
            char end[64];
            snprintf(end, sizeof end, "%s in %.2fs", jstr(st, "state"), jnum(st, "seconds"));
            progress_finish(view.prog, end);
            view.drawn = 0;
            break;
        }
        progress_update(view.prog, job_fraction(st), detail);
        view.drawn = 1;
        struct timespec ts = {0, 100 * 1000 * 1000};
        nanosleep(&ts, NULL);
    }
    view_break(&view);
    progress_destroy(&view.prog);
    cJSON_Delete(req);
    if (st && !job_ended(st)) {
        cJSON_Delete(st);
        st = NULL;
    }
    return st;
}

/* Writes OUT.exr, OUT.png and OUT-samples.png from a fetched image. */
static int write_outputs(image_t *img, const cJSON *job, const char *out_exr, char *err,
                         size_t errlen)
{
    image_set_string(img, "vb.seed", jstr(job, "seed"));
    image_set_string(img, "vb.integrator", jstr(job, "integrator"));
    image_set_string(img, "vb.adaptive", jstr(job, "adaptive"));
    image_set_string(img, "vb.scene", jstr(job, "scene"));
    image_set_double(img, "vb.total_samples", jnum(job, "samples"));
    image_set_double(img, "vb.render_seconds", jnum(job, "seconds"));
    image_set_int(img, "vb.spp", (int32_t)fmin(jnum(job, "spp"), 2147483647.0));
    image_set_int(img, "vb.granularity", (int32_t)jnum(job, "granularity"));
    image_set_double(img, "vb.nonfinite_samples", jnum(job, "nonfinite"));
    char png[4096], heat[4096];
    replace_extension(out_exr, ".png", png, sizeof png);
    replace_extension(out_exr, "-samples.png", heat, sizeof heat);
    if (image_write_exr(img, out_exr, err, errlen) < 0 ||
        image_write_png(img, png, 1.0f, err, errlen) < 0 ||
        image_write_heatmap_png(img, "samples", 0.0f, (float)jnum(job, "spp"), heat, err, errlen) <
            0)
        return -1;
    printf("%s\n%s\n%s\n", out_exr, png, heat);
    const cJSON *series = cJSON_GetObjectItemCaseSensitive(job, "error_series");
    if (series) {
        /* error against the reference over wall time and samples */
        char path[4096];
        replace_extension(out_exr, ".error.json", path, sizeof path);
        cJSON *doc = cJSON_CreateObject();
        cJSON_AddStringToObject(doc, "columns", "seconds samples relmse rmse");
        cJSON_AddItemToObject(doc, "series", cJSON_Duplicate(series, 1));
        cJSON_AddItemToObject(doc, "job", cJSON_Duplicate(job, 1));
        cJSON_DeleteItemFromObject(cJSON_GetObjectItemCaseSensitive(doc, "job"), "error_series");
        char *text = cJSON_Print(doc);
        cJSON_Delete(doc);
        FILE *f = fopen(path, "w");
        if (!f || !text || fputs(text, f) < 0) {
            snprintf(err, errlen, "%.1500s: cannot write: %s", path, strerror(errno));
            if (f)
                fclose(f);
            cJSON_free(text);
            return -1;
        }
        fclose(f);
        cJSON_free(text);
        printf("%s\n", path);
    }
    return 0;
}

static int check_writable(const char *out_exr)
{
    char dir[4096];
    snprintf(dir, sizeof dir, "%s", out_exr);
    char *slash = strrchr(dir, '/');
    if (slash)
        *(slash == dir ? slash + 1 : slash) = '\0';
    else
        snprintf(dir, sizeof dir, ".");
    if (access(dir, W_OK) != 0) {
        fprintf(stderr, "vbrender: cannot write %s: folder %s: %s\n", out_exr, dir,
                strerror(errno));
        return -1;
    }
    return 0;
}

static void print_summary(const cJSON *job, int workers, int threads)
{
    char a1[32], a2[32], a3[32], a4[32], where[64] = "";
    double secs = jnum(job, "seconds") > 0 ? jnum(job, "seconds") : 1e-9;
    if (workers > 0) /* embedded: say what ran it; a remote job's workers are the master's */
        snprintf(where, sizeof where, ", %d worker%s, %d threads", workers, workers == 1 ? "" : "s",
                 threads);
    fprintf(
        stderr,
        "vbrender: %.0fx%.0f, %.0f spp max, %s, adaptive %s, seed %s%s: "
        "%.2f s, %s samples (%s samples/s), %s rays (%s rays/s), %.0f NaN/Inf samples left out\n",
        jnum(job, "width"), jnum(job, "height"), jnum(job, "spp"), jstr(job, "integrator"),
        jstr(job, "adaptive"), jstr(job, "seed"), where, jnum(job, "seconds"),
        render_si(jnum(job, "samples"), a1, sizeof a1),
        render_si(jnum(job, "samples") / secs, a2, sizeof a2),
        render_si(jnum(job, "rays"), a3, sizeof a3),
        render_si(jnum(job, "rays") / secs, a4, sizeof a4), jnum(job, "nonfinite"));
}

/* ---- render: the embedded master and workers ------------------------------------ */

typedef struct embedded_master {
    master_t *m;
    atomic_int stop; /* read by the master thread */
    pthread_t thread;
} embedded_master_t;

typedef struct embedded_worker {
    worker_t *w;
    atomic_int stop; /* read by the worker thread */
    pthread_t thread;
    int started;
} embedded_worker_t;

static void *master_thread(void *arg)
{
    embedded_master_t *em = arg;
    master_run(em->m, &em->stop);
    return NULL;
}

static void *worker_thread(void *arg)
{
    embedded_worker_t *ew = arg;
    worker_run(ew->w, &ew->stop);
    return NULL;
}

static int cmd_render(int argc, char **argv)
{
    args_t a;
    memset(&a, 0, sizeof a);
    int rc = parse_args(argc, argv, &a, 1, 1, 0);
    if (rc || !a.positional) {
        cJSON_Delete(a.settings);
        return rc ? rc : usage_error("%s", "render needs a scene file: vbrender render SCENE.json");
    }
    if (a.key_file || a.master_key_file) {
        cJSON_Delete(a.settings);
        return usage_error("%s", "render runs its master in this process: it takes no keys");
    }
    char out_exr[4096];
    if (a.output) {
        snprintf(out_exr, sizeof out_exr, "%s", a.output);
    } else {
        const char *base = strrchr(a.positional, '/');
        replace_extension(base ? base + 1 : a.positional, ".exr", out_exr, sizeof out_exr);
    }
    if (check_writable(out_exr) < 0) {
        cJSON_Delete(a.settings);
        return 1;
    }
    if (a.workers > a.threads)
        a.threads = a.workers;
    /* scene warnings are the client's to show: load it once here */
    char err[2048];
    scene_t *scene = NULL;
    if (scene_load(a.positional, &scene, err, sizeof err) < 0) {
        fprintf(stderr, "vbrender: %s\n", err);
        cJSON_Delete(a.settings);
        return 1;
    }
    for (int i = 0; i < scene->warning_count; i++)
        fprintf(stderr, "vbrender: warning: %s\n", scene->warnings[i]);
    scene_destroy(&scene);

    void *ctx = zmq_ctx_new();
    char wep[64], cep[64];
    snprintf(wep, sizeof wep, "inproc://vbrender-workers");
    snprintf(cep, sizeof cep, "inproc://vbrender-control");
    master_config_t mc;
    memset(&mc, 0, sizeof mc);
    mc.zmq_ctx = ctx;
    mc.worker_endpoint = wep;
    mc.control_endpoint = cep;
    mc.allow_shutdown = 1;
    mc.log = getenv("VB_LOG") ? stderr : NULL;
    embedded_master_t em;
    memset(&em, 0, sizeof em);
    tracer_device_t *device = NULL; /* one Embree device for all the workers */
    embedded_worker_t *ew = calloc(a.workers, sizeof *ew);
    control_t *c = NULL;
    image_t *img = NULL;
    cJSON *job = NULL;
    rc = 1;
    em.m = master_new(&mc, err, sizeof err);
    if (!em.m || !ew) {
        fprintf(stderr, "vbrender: %s\n", em.m ? "out of memory" : err);
        goto done;
    }
    pthread_create(&em.thread, NULL, master_thread, &em);
    if (tracer_device_new(&device, err, sizeof err) < 0) {
        fprintf(stderr, "vbrender: %s\n", err);
        goto done;
    }
    int per = (int)(a.threads / a.workers), extra = (int)(a.threads % a.workers);
    for (uint64_t i = 0; i < a.workers; i++) {
        char name[32];
        snprintf(name, sizeof name, "worker-%llu", (unsigned long long)i + 1);
        worker_config_t wc = {.zmq_ctx = ctx,
                              .master_endpoint = wep,
                              .threads = per + ((int)i < extra ? 1 : 0),
                              .log = mc.log,
                              .name = name,
                              .device = device};
        ew[i].w = worker_new(&wc, err, sizeof err);
        if (!ew[i].w) {
            fprintf(stderr, "vbrender: %s\n", err);
            goto done;
        }
        pthread_create(&ew[i].thread, NULL, worker_thread, &ew[i]);
        ew[i].started = 1;
    }
    image_t *ref = NULL;
    if (a.reference && image_read_exr(a.reference, &ref, err, sizeof err) < 0) {
        fprintf(stderr, "vbrender: %s\n", err);
        goto done;
    }
    c = control_new(ctx, cep, 600000, err, sizeof err);
    /* in-process: a lost reply is a bug, not a restart; no retries */
    unsigned long long id =
        c ? control_submit(c, a.positional, a.settings, ref, NULL, err, sizeof err) : 0;
    image_destroy(&ref);
    if (!id) {
        fprintf(stderr, "vbrender: %s\n", err);
        goto done;
    }
    job = wait_job(c, id, a.progress, 0, err, sizeof err);
    if (!job) {
        fprintf(stderr, "vbrender: %s\n", err);
        goto done;
    }
    cJSON *st = NULL;
    img = control_fetch(c, id, &st, err, sizeof err);
    if (!img) {
        fprintf(stderr, "vbrender: %s\n", err);
        goto done;
    }
    cJSON_Delete(job);
    job = st;
    if (write_outputs(img, job, out_exr, err, sizeof err) < 0) {
        fprintf(stderr, "vbrender: %s\n", err);
        goto done;
    }
    print_summary(job, (int)a.workers, (int)a.threads);
    rc = strcmp(jstr(job, "state"), "done") == 0 ? 0 : 1;
    if (rc)
        fprintf(stderr, "vbrender: job %s: %s\n", jstr(job, "state"), jstr(job, "error"));
done:
    for (uint64_t i = 0; ew && i < a.workers; i++)
        if (ew[i].started) {
            atomic_store(&ew[i].stop, 1);
            pthread_join(ew[i].thread, NULL);
        }
    for (uint64_t i = 0; ew && i < a.workers; i++)
        worker_destroy(&ew[i].w);
    tracer_device_destroy(&device);
    if (em.m) {
        atomic_store(&em.stop, 1);
        pthread_join(em.thread, NULL);
        master_destroy(&em.m);
    }
    control_destroy(&c);
    free(ew);
    image_destroy(&img);
    cJSON_Delete(job);
    cJSON_Delete(a.settings);
    zmq_ctx_term(ctx);
    return rc;
}

/* ---- commands for a running master ----------------------------------------------- */

/* The CURVE keys from --key and --master-key, else VBRENDER_KEY and
 * VBRENDER_MASTER_KEY: 1 with keys loaded, 0 without keys, -1 after a
 * message (2 as the exit status: usage; 1: a file). */
static int load_client_keys(const args_t *a, keys_pair_t *mine, char master[KEYS_Z85_LEN + 1],
                            int *status)
{
    const char *kf = a->key_file, *mf = a->master_key_file;
    if (!kf && getenv("VBRENDER_KEY") && *getenv("VBRENDER_KEY"))
        kf = getenv("VBRENDER_KEY");
    if (!mf && getenv("VBRENDER_MASTER_KEY") && *getenv("VBRENDER_MASTER_KEY"))
        mf = getenv("VBRENDER_MASTER_KEY");
    if (!kf && !mf)
        return 0;
    if (!kf || !mf) {
        *status = usage_error(
            "%s", "--key and --master-key go together (or VBRENDER_KEY and VBRENDER_MASTER_KEY)");
        return -1;
    }
    char err[1024];
    if (keys_load_secret(kf, mine, err, sizeof err) < 0 ||
        keys_load_public(mf, master, err, sizeof err) < 0) {
        fprintf(stderr, "vbrender: %s\n", err);
        *status = 1;
        return -1;
    }
    return 1;
}

static int simple_command(const char *cmd, int argc, char **argv)
{
    args_t a;
    memset(&a, 0, sizeof a);
    int is_fetch = strcmp(cmd, "fetch") == 0;
    int is_submit = strcmp(cmd, "submit") == 0;
    int is_wait = strcmp(cmd, "wait") == 0;
    int is_delete = strcmp(cmd, "delete") == 0;
    int is_readmit = strcmp(cmd, "readmit") == 0;
    int rc = parse_args(argc, argv, &a, is_submit, is_fetch, is_submit || is_wait);
    if (rc) {
        cJSON_Delete(a.settings);
        return rc;
    }
    unsigned long long job = 0;
    int needs_job = is_wait || is_fetch || is_delete || strcmp(cmd, "cancel") == 0;
    if (is_submit && !a.positional)
        rc = usage_error("%s", "submit needs a scene file: vbrender submit SCENE.json");
    else if ((needs_job || (strcmp(cmd, "status") == 0 && a.positional)) &&
             (!a.positional || parse_job_id(a.positional, &job) < 0))
        rc = usage_error("%s needs a job id (a positive integer)", cmd);
    else if (is_readmit && !a.positional)
        rc =
            usage_error("%s", "readmit needs a worker: its key (Z85), or its address without keys");
    else if (!needs_job && !is_submit && !is_readmit && strcmp(cmd, "status") != 0 && a.positional)
        rc = usage_error("unexpected argument '%s'", a.positional);
    else if (is_fetch && !a.output)
        rc = usage_error("%s", "fetch needs -o OUT.exr");
    if (rc) {
        cJSON_Delete(a.settings);
        return rc;
    }
    if (is_fetch && check_writable(a.output) < 0) {
        cJSON_Delete(a.settings);
        return 1;
    }
    keys_pair_t mine;
    char master_key[KEYS_Z85_LEN + 1];
    int have_keys = load_client_keys(&a, &mine, master_key, &rc);
    if (have_keys < 0) {
        cJSON_Delete(a.settings);
        return rc;
    }
    control_keys_t keys = {mine.public_z85, mine.secret_z85, master_key};
    void *ctx = zmq_ctx_new();
    char err[2048];
    control_t *c = control_new_with_keys(ctx, a.master, REQUEST_TIMEOUT_MS,
                                         have_keys ? &keys : NULL, err, sizeof err);
    if (have_keys)
        explicit_bzero(&mine, sizeof mine); /* control keeps its own copy */
    rc = 1;
    if (!c) {
        fprintf(stderr, "vbrender: %s\n", err);
        goto done;
    }
    if (is_submit) {
        image_t *ref = NULL;
        if (a.reference && image_read_exr(a.reference, &ref, err, sizeof err) < 0) {
            fprintf(stderr, "vbrender: %s\n", err);
            goto done;
        }
        control_retry_t retry = {a.timeout_s, say_outage, NULL, 0};
        unsigned long long id =
            control_submit(c, a.positional, a.settings, ref, &retry, err, sizeof err);
        image_destroy(&ref);
        if (!id) {
            if (retry.unreachable) /* some try may have reached it */
                fprintf(stderr,
                        "vbrender: %s; the job may have been queued (see 'vbrender jobs')\n", err);
            else
                fprintf(stderr, "vbrender: %s\n", err);
            goto done;
        }
        printf("%llu\n", id);
        rc = 0;
    } else if (is_wait) {
        cJSON *st = wait_job(c, job, a.progress, a.timeout_s, err, sizeof err);
        if (!st) {
            fprintf(stderr, "vbrender: %s\n", err);
            goto done;
        }
        print_summary(st, 0, 0);
        rc = strcmp(jstr(st, "state"), "done") == 0 ? 0 : 1;
        if (rc)
            fprintf(stderr, "vbrender: job %llu %s: %s\n", job, jstr(st, "state"),
                    *jstr(st, "error") ? jstr(st, "error") : "no reason given");
        cJSON_Delete(st);
    } else if (is_fetch) {
        cJSON *st = NULL;
        image_t *img = control_fetch(c, job, &st, err, sizeof err);
        if (!img || write_outputs(img, st, a.output, err, sizeof err) < 0)
            fprintf(stderr, "vbrender: %s\n", err);
        else
            rc = 0;
        image_destroy(&img);
        cJSON_Delete(st);
    } else {
        cJSON *req = cJSON_CreateObject();
        cJSON_AddStringToObject(req, "cmd", strcmp(cmd, "status") == 0 && !job ? "jobs" : cmd);
        if (job)
            cJSON_AddNumberToObject(req, "job", (double)job);
        if (is_readmit)
            cJSON_AddStringToObject(req, "worker", a.positional);
        cJSON *reply = control_request(c, req, NULL, NULL, 0, err, sizeof err);
        cJSON_Delete(req);
        if (!reply) {
            fprintf(stderr, "vbrender: %s\n", err);
            goto done;
        }
        if (!cJSON_IsTrue(cJSON_GetObjectItemCaseSensitive(reply, "ok"))) {
            fprintf(stderr, "vbrender: %s\n", jstr(reply, "error"));
            cJSON_Delete(reply);
            goto done;
        }
        const cJSON *list = cJSON_GetObjectItemCaseSensitive(
            reply, strcmp(cmd, "workers") == 0 ? "workers" : "jobs");
        if (is_readmit) {
            printf("readmitted %s\n", a.positional);
        } else if (is_delete) {
            const cJSON *d = cJSON_GetObjectItemCaseSensitive(reply, "deleted");
            printf("deleted job %llu\n",
                   cJSON_IsNumber(d) ? (unsigned long long)d->valuedouble : job);
        } else if (strcmp(cmd, "workers") == 0) {
            printf("%-24s %7s %12s %12s %10s\n", "host", "threads", "rays/s", "tasks done",
                   "busy s");
            const cJSON *w;
            cJSON_ArrayForEach(w, list)
            {
                char r[32];
                printf("%-24s %7.0f %12s %12.0f %10.1f\n", jstr(w, "host"), jnum(w, "threads"),
                       render_si(jnum(w, "rays_per_second"), r, sizeof r), jnum(w, "tasks_done"),
                       jnum(w, "busy_seconds"));
            }
        } else if (list) {
            printf("%6s %-10s %-24s %9s %8s %12s %9s\n", "job", "state", "scene", "size", "layers",
                   "samples", "seconds");
            const cJSON *j;
            cJSON_ArrayForEach(j, list)
            {
                char size[32], layers[32], s[32];
                snprintf(size, sizeof size, "%.0fx%.0f", jnum(j, "width"), jnum(j, "height"));
                snprintf(layers, sizeof layers, "%.0f/%.0f", jnum(j, "layers_done"),
                         jnum(j, "layers"));
                printf("%6.0f %-10s %-24s %9s %8s %12s %9.2f\n", jnum(j, "id"), jstr(j, "state"),
                       jstr(j, "scene"), size, layers, render_si(jnum(j, "samples"), s, sizeof s),
                       jnum(j, "seconds"));
                /* a durable master's notes on the job's state files, under its row */
                if (*jstr(j, "storage_error"))
                    printf("%6s storage error: %s\n", "", jstr(j, "storage_error"));
                if (*jstr(j, "recovered"))
                    printf("%6s recovered from %s\n", "", jstr(j, "recovered"));
            }
        } else {
            /* one job: its status as JSON, for people and scripts */
            const cJSON *st = cJSON_GetObjectItemCaseSensitive(reply, "job");
            char *text = cJSON_Print(st);
            printf("%s\n", text ? text : "{}");
            cJSON_free(text);
            /* and in words on stderr, so stdout stays JSON */
            if (*jstr(st, "storage_error"))
                fprintf(stderr, "vbrender: job %llu: storage error: %s\n", job,
                        jstr(st, "storage_error"));
            if (*jstr(st, "recovered"))
                fprintf(stderr, "vbrender: job %llu: recovered from %s\n", job,
                        jstr(st, "recovered"));
        }
        cJSON_Delete(reply);
        rc = 0;
    }
done:
    control_destroy(&c);
    cJSON_Delete(a.settings);
    zmq_ctx_term(ctx);
    return rc;
}

/* ---- keygen ----------------------------------------------------------------------- */

static int cmd_keygen(int argc, char **argv)
{
    if (argc != 1 || argv[0][0] == '-' || !argv[0][0])
        return usage_error(
            "%s", "keygen needs a name: vbrender keygen NAME (writes NAME.key and NAME.pub)");
    keys_pair_t k;
    char err[1024];
    if (keys_generate(&k, err, sizeof err) < 0 || keys_write(argv[0], &k, err, sizeof err) < 0) {
        explicit_bzero(&k, sizeof k);
        fprintf(stderr, "vbrender: %s\n", err);
        return 1;
    }
    printf("%s.key  key pair (keep it secret: mode 0600)\n%s.pub  public key %s\n", argv[0],
           argv[0], k.public_z85);
    explicit_bzero(&k, sizeof k);
    return 0;
}

/* ---- compare ---------------------------------------------------------------------- */

static int cmd_compare(int argc, char **argv)
{
    const char *files[2] = {NULL, NULL}, *map = NULL;
    double threshold = 0.05;
    int nfiles = 0;
    for (int i = 0; i < argc; i++) {
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(argv[i], "--threshold") == 0) {
            char *end;
            errno = 0;
            threshold = v ? strtod(v, &end) : -1;
            if (!v || errno || *end || !(threshold >= 0) || !isfinite(threshold))
                return usage_error("--threshold needs a relative error >= 0 (got '%s')",
                                   v ? v : "");
            i++;
        } else if (strcmp(argv[i], "--error-map") == 0) {
            if (!v || v[0] == '-')
                return usage_error("%s", "--error-map needs a PNG file name");
            map = v;
            i++;
        } else if (argv[i][0] == '-' && argv[i][1]) {
            return usage_error("unknown option '%s'", argv[i]);
        } else if (nfiles < 2) {
            files[nfiles++] = argv[i];
        } else {
            return usage_error("unexpected argument '%s'", argv[i]);
        }
    }
    if (nfiles != 2)
        return usage_error("%s", "compare needs two images: vbrender compare A.exr REF.exr");
    image_t *a = NULL, *r = NULL;
    char err[1024];
    int rc = 1;
    if (image_read_exr(files[0], &a, err, sizeof err) < 0 ||
        image_read_exr(files[1], &r, err, sizeof err) < 0) {
        fprintf(stderr, "vbrender: %s\n", err);
        goto done;
    }
    compare_result_t res;
    if (compare_images(a, r, threshold, &res, err, sizeof err) < 0) {
        fprintf(stderr, "vbrender: cannot compare %s with %s: %s\n", files[0], files[1], err);
        goto done;
    }
    printf("relMSE %.9g\nRMSE %.9g\nMARE %.9g\nmax %.9g\nabove %.9g %.9g\n", res.relmse, res.rmse,
           res.mare, res.max_abs, threshold, res.above);
    if (map) {
        image_t *e = compare_error_image(a, r);
        if (!e ||
            image_write_heatmap_png(e, "error", 0.0f, (float)(threshold > 0 ? 4 * threshold : 1.0),
                                    map, err, sizeof err) < 0) {
            fprintf(stderr, "vbrender: %s\n", e ? err : "out of memory");
            image_destroy(&e);
            goto done;
        }
        image_destroy(&e);
    }
    rc = 0;
done:
    image_destroy(&a);
    image_destroy(&r);
    return rc;
}

int main(int argc, char **argv)
{
    signal(SIGPIPE, SIG_IGN);
    if (argc < 2) {
        fputs(usage_text, stderr);
        return 2;
    }
    if (strcmp(argv[1], "-h") == 0 || strcmp(argv[1], "--help") == 0 ||
        strcmp(argv[1], "help") == 0) {
        fputs(usage_text, stdout);
        return 0;
    }
    for (int i = 2; i < argc; i++)
        if (strcmp(argv[i], "-h") == 0 || strcmp(argv[i], "--help") == 0) {
            fputs(usage_text, stdout);
            return 0;
        }
    if (strcmp(argv[1], "render") == 0)
        return cmd_render(argc - 2, argv + 2);
    if (strcmp(argv[1], "compare") == 0)
        return cmd_compare(argc - 2, argv + 2);
    if (strcmp(argv[1], "keygen") == 0)
        return cmd_keygen(argc - 2, argv + 2);
    if (strcmp(argv[1], "serve") == 0)
        return serve_main(argc - 2, argv + 2);
    static const char *const commands[] = {"submit", "status", "wait",    "fetch",  "cancel",
                                           "delete", "jobs",   "workers", "readmit"};
    for (size_t i = 0; i < sizeof commands / sizeof commands[0]; i++)
        if (strcmp(argv[1], commands[i]) == 0)
            return simple_command(argv[1], argc - 2, argv + 2);
    fprintf(stderr, "vbrender: unknown command '%s' (run 'vbrender --help')\n", argv[1]);
    return 2;
}
