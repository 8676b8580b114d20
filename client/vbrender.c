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
 * cancelled, I/O, no master), 2 bad usage, 130 render interrupted (the
 * first SIGINT or SIGTERM cancels the job and writes the image so far,
 * marked partial in its header; a second exits at once).
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
#include "defaults.h"
#include "image.h"
#include "jsonget.h"
#include "keys.h"
#include "master.h"
#include "mitsuba.h"
#include "progress.h"
#include "proto.h"
#include "render.h"
#include "sched.h"
#include "serve.h"
#include "settings.h"
#include "vberr.h"
#include "vblog.h"
#include "worker.h"

static const char usage_head[] =
    "usage: vbrender COMMAND ...\n"
    "\n"
    "  render SCENE [-o OUT.exr] [settings] [--workers N] [--threads T]\n"
    "        render on this machine (a master and N local workers in this process)\n"
    "  submit SCENE [settings] [--master EP] [--timeout S]   queue a job; prints its id last\n"
    "        SCENE: our JSON (SCENE.json) or a Mitsuba 3 file (SCENE.xml; docs/SCENES.md\n"
    "        lists what of it we render, and anything else is refused with its line)\n"
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
    "  workers           connected workers: host, threads, rays/s, tasks done, busy\n"
    "                    seconds, backup copies run, tasks held (sent, not yet\n"
    "                    answered), state (breaker: no tasks until it answers one)\n"
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
    "settings (render and submit):\n";

/* After the settings' lines, which come from their table (settings.h). */
static const char usage_tail[] =
    "  -D NAME=VALUE           a Mitsuba scene's parameter, as mitsuba -D (over its\n"
    "                          <default>)\n"
    "  --reference REF.exr     track the error against REF over time and samples\n"
    "                          (OUT.error.json beside the image)\n"
    "\n"
    "other options:\n"
    "  --master EP             control endpoint (default " CLIENT_DEFAULT_MASTER ")\n"
    "  --key FILE              this client's key pair, for a master that uses CURVE\n"
    "                          keys (default: $VBRENDER_KEY)\n"
    "  --master-key FILE       that master's public key (default: $VBRENDER_MASTER_KEY)\n"
    "  --timeout SECONDS       submit, wait: while the master does not answer (say it\n"
    "                          restarts), ask again for this long "
    "(default " CLIENT_DEFAULT_TIMEOUT_S_TEXT ")\n"
    "  --workers N             render: local workers (default " CLIENT_DEFAULT_WORKERS_TEXT ")\n"
    "  --threads T             render: threads in all (default: all cores)\n"
    "  --progress MODE         auto, bar, lines or none (default auto)\n"
    "  --log-level LEVEL       render: the embedded master's and workers' log lines on\n"
    "                          stderr at error, warn, info or debug (default: none;\n"
    "                          with $VB_LOG set, info)\n"
    "  --version               the build id\n"
    "  -h, --help              this text\n"
    "Ctrl-C during render cancels the job and writes the image so far (its header\n"
    "marked partial: vb.partial) and exits 130; a second Ctrl-C exits at once.\n";

static void print_usage(FILE *f)
{
    fputs(usage_head, f);
    settings_usage(f);
    fputs(usage_tail, f);
}

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

#define ARGS_MAX_DEFINES 64

typedef struct args {
    const char *positional;
    const char *output;
    const char *reference; /* --reference REF.exr */
    const char *master;
    const char *key_file, *master_key_file; /* --key, --master-key */
    cJSON *settings;                        /* submit fields (settings.h) */
    double timeout_s;                       /* --timeout */
    uint64_t workers, threads;
    progress_mode_t progress;
    int have_workers, have_threads;
    const char *define[ARGS_MAX_DEFINES]; /* -D name=value, for a Mitsuba scene */
    size_t define_count;
} args_t;

/* What a command's arguments may hold besides --master, --key,
 * --master-key and --progress (parse_args's allow_* arguments). */
enum {
    ALLOW_SETTINGS = 1, /* job settings, --reference, --workers, --threads */
    ALLOW_OUTPUT = 2,   /* -o OUT.exr */
    ALLOW_TIMEOUT = 4   /* --timeout S */
};

/* usage_error's message, and -2 for parse_option's caller. */
static int option_error(const char *fmt, const char *arg)
{
    usage_error(fmt, arg);
    return -2;
}

/* One of the client's own options (a job setting is not one): the number
 * of words it takes after o (0 or 1), -1 if o is none of them, or -2 after
 * a usage message. */
static int parse_option(const char *o, const char *v, args_t *a, unsigned allow)
{
    static const char *const progress_names[] = {"auto", "bar", "lines", "none"};
    int settings = (allow & ALLOW_SETTINGS) != 0;
    if ((allow & ALLOW_OUTPUT) && (strcmp(o, "-o") == 0 || strcmp(o, "--output") == 0)) {
        if (!v || v[0] == '-')
            return option_error("%s needs a file name", o);
        a->output = v;
    } else if (strcmp(o, "--master") == 0) {
        if (!v || !*v)
            return option_error(
                "%s needs an endpoint such as tcp://host:" MASTER_DEFAULT_CONTROL_PORT, o);
        a->master = v;
    } else if (strcmp(o, "--key") == 0 || strcmp(o, "--master-key") == 0) {
        if (!v || !*v)
            return option_error("%s needs a file name", o);
        *(strcmp(o, "--key") == 0 ? &a->key_file : &a->master_key_file) = v;
    } else if ((allow & ALLOW_TIMEOUT) && strcmp(o, "--timeout") == 0) {
        char *end;
        errno = 0;
        double t = v ? strtod(v, &end) : -1;
        if (!v || errno || *end || !(t > 0) || !(t <= 1e9))
            return option_error("--timeout needs a number of seconds > 0 (got '%s')", v ? v : "");
        a->timeout_s = t;
    } else if (strcmp(o, "--progress") == 0) {
        int m = 0;
        while (m < 4 && (!v || strcmp(v, progress_names[m]) != 0))
            m++;
        if (m == 4)
            return option_error("--progress must be auto, bar, lines or none (got '%s')",
                                v ? v : "");
        a->progress = (progress_mode_t)m;
    } else if (settings && strcmp(o, "--workers") == 0) {
        if (parse_u64(v, 1, 64, &a->workers) < 0)
            return option_error("--workers needs an integer from 1 to 64 (got '%s')", v ? v : "");
        a->have_workers = 1;
    } else if (settings && strcmp(o, "--threads") == 0) {
        if (parse_u64(v, 1, RENDER_MAX_THREADS, &a->threads) < 0)
            return option_error("--threads needs an integer from 1 to 256 (got '%s')", v ? v : "");
        a->have_threads = 1;
    } else if (settings && strncmp(o, "-D", 2) == 0) {
        /* Mitsuba's -D name=value (or -Dname=value) */
        const char *d = o[2] ? o + 2 : v;
        if (!d || !strchr(d, '=') || d[0] == '=')
            return option_error("-D needs name=value (got '%s')", d ? d : "");
        if (a->define_count == ARGS_MAX_DEFINES)
            return option_error("%s", "more than 64 -D parameters");
        a->define[a->define_count++] = d;
        return o[2] ? 0 : 1;
    } else if (settings && strcmp(o, "--reference") == 0) {
        if (!v || v[0] == '-')
            return option_error("%s", "--reference needs an EXR file");
        a->reference = v;
    } else {
        return -1;
    }
    return 1;
}

/* argv into a; the job settings (with ALLOW_SETTINGS) through their table
 * (settings.h). 0, or the exit status after a usage message. */
static int parse_args(int argc, char **argv, args_t *a, int allow_settings, int allow_output,
                      int allow_timeout)
{
    unsigned allow = (allow_settings ? ALLOW_SETTINGS : 0) | (allow_output ? ALLOW_OUTPUT : 0) |
                     (allow_timeout ? ALLOW_TIMEOUT : 0);
    a->settings = cJSON_CreateObject();
    a->master = CLIENT_DEFAULT_MASTER;
    a->timeout_s = CLIENT_DEFAULT_TIMEOUT_S;
    a->workers = CLIENT_DEFAULT_WORKERS;
    long cores = sysconf(_SC_NPROCESSORS_ONLN);
    a->threads = cores > 0 ? (uint64_t)cores : 1;
    a->progress = PROGRESS_AUTO;
    for (int i = 0; i < argc; i++) {
        const char *o = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        char err[VB_ERR_LEN];
        int takes =
            (allow & ALLOW_SETTINGS) ? settings_parse_flag(o, v, a->settings, err, sizeof err) : -1;
        if (takes == -2)
            return usage_error("%s", err);
        if (takes == -1)
            takes = parse_option(o, v, a, allow);
        if (takes == -2)
            return 2;
        if (takes == -1) {
            if (o[0] == '-' && o[1] != '\0')
                return usage_error("unknown option '%s'", o);
            if (a->positional)
                return usage_error("unexpected argument '%s'", o);
            a->positional = o;
            takes = 0;
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

static int job_ended(const cJSON *job)
{
    const char *s = json_str(job, "state");
    return strcmp(s, "done") == 0 || strcmp(s, "failed") == 0 || strcmp(s, "cancelled") == 0;
}

static double job_fraction(const cJSON *job)
{
    double layers = json_num(job, "layers"), done = json_num(job, "layers_done");
    double s = json_num(job, "samples"), max = json_num(job, "max_samples");
    double f1 = layers > 0 ? done / layers : 0, f2 = max > 0 ? s / max : 0;
    return f1 > f2 ? f1 : f2;
}

static void progress_detail(const cJSON *job, char *buf, size_t len)
{
    char a[32], b[32];
    double frac = job_fraction(job), el = json_num(job, "seconds");
    double eta = frac > 0 ? el / frac - el : 0;
    int n = snprintf(buf, len, "layer %.0f/%.0f, %s samples, %s rays/s, ETA %.0fs",
                     json_num(job, "layers_done"), json_num(job, "layers"),
                     render_si(json_num(job, "samples"), a, sizeof a),
                     render_si(json_num(job, "rays_per_second"), b, sizeof b), eta);
    if (cJSON_GetObjectItemCaseSensitive(job, "relmse") && n > 0 && (size_t)n < len)
        snprintf(buf + n, len - (size_t)n, ", relMSE %.3g", json_num(job, "relmse"));
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
    const char *se = json_str(st, "storage_error"), *rec = json_str(st, "recovered");
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
    const char *wf = json_str(st, "waiting_for");
    if (*wf && strcmp(wf, v->waiting_for) != 0) {
        view_break(v);
        fprintf(stderr, "vbrender: job %llu: %.0f tasks wait for %s to verify them\n", job,
                json_num(st, "verify_waiting"), wf);
    }
    snprintf(v->waiting_for, sizeof v->waiting_for, "%s", wf);
}

/* Polls status until the job ends; returns the final status, or NULL with
 * a message (one saying the job may still run when the master stayed away
 * for timeout_s; timeout_s <= 0: no retries). When *interrupts becomes
 * non-zero (interrupts may be NULL) it stops polling and returns the last
 * status, the job not ended (NULL if none came yet). */
static cJSON *watch_job(control_t *c, unsigned long long job, progress_mode_t mode,
                        double timeout_s, const atomic_int *interrupts, char *err, size_t errlen)
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
    int interrupted = 0;
    for (;;) {
        if (interrupts && atomic_load(interrupts)) {
            interrupted = 1;
            break;
        }
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
            const char *e = json_str(reply, "error");
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
            snprintf(end, sizeof end, "%s in %.2fs", json_str(st, "state"),
                     json_num(st, "seconds"));
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
    if (st && !job_ended(st) && !interrupted) {
        cJSON_Delete(st);
        st = NULL;
    }
    return st;
}

static cJSON *wait_job(control_t *c, unsigned long long job, progress_mode_t mode, double timeout_s,
                       char *err, size_t errlen)
{
    return watch_job(c, job, mode, timeout_s, NULL, err, errlen);
}

/* Writes OUT.exr, OUT.png and OUT-samples.png from a fetched image. */
static int write_outputs(image_t *img, const cJSON *job, const char *out_exr, char *err,
                         size_t errlen)
{
    image_set_string(img, "vb.seed", json_str(job, "seed"));
    image_set_string(img, "vb.integrator", json_str(job, "integrator"));
    image_set_string(img, "vb.sampler", json_str(job, "sampler"));
    image_set_string(img, "vb.adaptive", json_str(job, "adaptive"));
    image_set_string(img, "vb.scene", json_str(job, "scene"));
    image_set_double(img, "vb.total_samples", json_num(job, "samples"));
    image_set_double(img, "vb.render_seconds", json_num(job, "seconds"));
    image_set_int(img, "vb.spp", (int32_t)fmin(json_num(job, "spp"), 2147483647.0));
    image_set_int(img, "vb.granularity", (int32_t)json_num(job, "granularity"));
    /* what the variance channel is: calibrated by replicates (2 or more) or not */
    image_set_int(img, "vb.replicates", (int32_t)json_num(job, "replicates"));
    image_set_double(img, "vb.nonfinite_samples", json_num(job, "nonfinite"));
    char png[4096], heat[4096];
    replace_extension(out_exr, ".png", png, sizeof png);
    replace_extension(out_exr, "-samples.png", heat, sizeof heat);
    if (image_write_exr(img, out_exr, err, errlen) < 0 ||
        image_write_png(img, png, 1.0f, err, errlen) < 0 ||
        image_write_heatmap_png(img, "samples", 0.0f, (float)json_num(job, "spp"), heat, err,
                                errlen) < 0)
        return -1;
    printf("%s\n%s\n%s\n", out_exr, png, heat);
    const cJSON *series = cJSON_GetObjectItemCaseSensitive(job, "error_series");
    if (series) {
        /* error against the reference over wall time and samples */
        char path[4096];
        replace_extension(out_exr, ".error.json", path, sizeof path);
        cJSON *doc = cJSON_CreateObject();
        cJSON_AddStringToObject(doc, "columns", "seconds samples relmse rmse rays");
        cJSON_AddItemToObject(doc, "series", cJSON_Duplicate(series, 1));
        cJSON_AddItemToObject(doc, "job", cJSON_Duplicate(job, 1));
        cJSON_DeleteItemFromObject(cJSON_GetObjectItemCaseSensitive(doc, "job"), "error_series");
        char *text = cJSON_Print(doc);
        cJSON_Delete(doc);
        FILE *f = fopen(path, "w");
        if (!f || !text || fputs(text, f) < 0) {
            snprintf(err, errlen, "%.600s: cannot write: %s", path, strerror(errno));
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
    double secs = json_num(job, "seconds") > 0 ? json_num(job, "seconds") : 1e-9;
    if (workers > 0) /* embedded: say what ran it; a remote job's workers are the master's */
        snprintf(where, sizeof where, ", %d worker%s, %d threads", workers, workers == 1 ? "" : "s",
                 threads);
    fprintf(
        stderr,
        "vbrender: %.0fx%.0f, %.0f spp max, %s, adaptive %s, seed %s%s: "
        "%.2f s, %s samples (%s samples/s), %s rays (%s rays/s), %.0f NaN/Inf samples left out\n",
        json_num(job, "width"), json_num(job, "height"), json_num(job, "spp"),
        json_str(job, "integrator"), json_str(job, "adaptive"), json_str(job, "seed"), where,
        json_num(job, "seconds"), render_si(json_num(job, "samples"), a1, sizeof a1),
        render_si(json_num(job, "samples") / secs, a2, sizeof a2),
        render_si(json_num(job, "rays"), a3, sizeof a3),
        render_si(json_num(job, "rays") / secs, a4, sizeof a4), json_num(job, "nonfinite"));
    if (cJSON_GetObjectItemCaseSensitive(job, "pixels_at_cap")) {
        /* which pixels the rule stopped and which only the cap did: a pixel
         * at the cap is one the target error could not vouch for */
        const double pixels = json_num(job, "width") * json_num(job, "height"),
                     at_cap = json_num(job, "pixels_at_cap");
        fprintf(stderr,
                "vbrender: target error %g: %.0f of %.0f pixels stopped below the cap "
                "(%.1f %%), %.0f ran to the cap of %.0f spp%s\n",
                json_num(job, "target_error"), pixels - at_cap, pixels,
                pixels > 0 ? 100.0 * (pixels - at_cap) / pixels : 0.0, at_cap, json_num(job, "spp"),
                cJSON_IsTrue(cJSON_GetObjectItemCaseSensitive(job, "stopped_on_target"))
                    ? " (the job stopped once its target share of pixels had met the target)"
                    : "");
    }
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

/* The master and workers of one embedded render, over inproc. */
typedef struct embedded {
    void *ctx;
    embedded_master_t em;
    embedded_worker_t *ew;
    uint64_t workers;        /* in ew */
    tracer_device_t *device; /* one Embree device for all the workers */
    worker_scenes_t *scenes; /* and each scene loaded once for them all */
    control_t *c;
} embedded_t;

/* Starts the master and a->workers workers sharing a->threads, and a
 * control connection to the master: 0, or -1 with a message (either way
 * embedded_stop cleans up). log_level 0: the master and workers are silent
 * unless VB_LOG is set. */
static int embedded_start(embedded_t *e, const args_t *a, int log_level, char *err, size_t errlen)
{
    static const char wep[] = "inproc://vbrender-workers", cep[] = "inproc://vbrender-control";
    memset(e, 0, sizeof *e);
    e->ctx = zmq_ctx_new();
    master_config_t mc;
    memset(&mc, 0, sizeof mc);
    mc.zmq_ctx = e->ctx;
    mc.worker_endpoint = wep;
    mc.control_endpoint = cep;
    mc.allow_shutdown = 1;
    mc.log = getenv("VB_LOG") || log_level ? stderr : NULL;
    mc.log_level = log_level;
    if (!(e->ew = calloc(a->workers, sizeof *e->ew))) {
        snprintf(err, errlen, "out of memory");
        return -1;
    }
    e->workers = a->workers;
    if (!(e->em.m = master_new(&mc, err, errlen)))
        return -1;
    pthread_create(&e->em.thread, NULL, master_thread, &e->em);
    if (tracer_device_new(&e->device, err, errlen) < 0)
        return -1;
    if (!(e->scenes = worker_scenes_new())) {
        snprintf(err, errlen, "out of memory");
        return -1;
    }
    int per = (int)(a->threads / a->workers), extra = (int)(a->threads % a->workers);
    for (uint64_t i = 0; i < a->workers; i++) {
        char name[32];
        snprintf(name, sizeof name, "worker-%llu", (unsigned long long)i + 1);
        worker_config_t wc = {.zmq_ctx = e->ctx,
                              .master_endpoint = wep,
                              .threads = per + ((int)i < extra ? 1 : 0),
                              .log = mc.log,
                              .log_level = log_level,
                              .name = name,
                              .device = e->device,
                              .scenes = e->scenes};
        if (!(e->ew[i].w = worker_new(&wc, err, errlen)))
            return -1;
        pthread_create(&e->ew[i].thread, NULL, worker_thread, &e->ew[i]);
        e->ew[i].started = 1;
    }
    /* in-process: a lost reply is a bug, not a restart; no retries */
    e->c = control_new(e->ctx, cep, CLIENT_EMBEDDED_TIMEOUT_MS, err, errlen);
    return e->c ? 0 : -1;
}

/* Stops and frees what embedded_start started; a worker first finishes the
 * task it traces. */
static void embedded_stop(embedded_t *e)
{
    for (uint64_t i = 0; e->ew && i < e->workers; i++)
        if (e->ew[i].started) {
            atomic_store(&e->ew[i].stop, 1);
            pthread_join(e->ew[i].thread, NULL);
        }
    for (uint64_t i = 0; e->ew && i < e->workers; i++)
        worker_destroy(&e->ew[i].w);
    worker_scenes_destroy(&e->scenes);
    tracer_device_destroy(&e->device);
    if (e->em.m) {
        atomic_store(&e->em.stop, 1);
        pthread_join(e->em.thread, NULL);
        master_destroy(&e->em.m);
    }
    control_destroy(&e->c);
    free(e->ew);
    e->ew = NULL;
    if (e->ctx)
        zmq_ctx_term(e->ctx);
    e->ctx = NULL;
}

/* Ctrl-C (SIGINT) and SIGTERM during render. They are blocked in every
 * thread (the mask is set before the first thread starts, so all inherit
 * it, the TBB pool Embree starts included: worker/main.c says why) and
 * taken by one thread with sigwait, so no work runs in a handler. The first
 * asks the render to stop (interrupts, read by the main thread, which
 * cancels the job and writes the image so far); a second ends the process
 * at once with exit status 130. */
typedef struct interrupt_watch {
    sigset_t set;
    atomic_int interrupts; /* signals taken */
    atomic_int over;       /* the render is over: the next signal ends the watch */
    pthread_t thread;
    int started;
} interrupt_watch_t;

static void *watch_interrupts(void *arg)
{
    interrupt_watch_t *iw = arg;
    for (;;) {
        int sig = 0;
        if (sigwait(&iw->set, &sig) != 0)
            continue;
        if (atomic_load(&iw->over))
            return NULL;
        if (atomic_fetch_add(&iw->interrupts, 1) > 0) {
            static const char msg[] = "\nvbrender: interrupted again: exiting at once\n";
            ssize_t n = write(STDERR_FILENO, msg, sizeof msg - 1);
            (void)n; /* exiting either way */
            _exit(130);
        }
    }
}

/* 0, or an errno value. */
static int interrupt_watch_start(interrupt_watch_t *iw)
{
    memset(iw, 0, sizeof *iw);
    atomic_init(&iw->interrupts, 0);
    atomic_init(&iw->over, 0);
    sigemptyset(&iw->set);
    sigaddset(&iw->set, SIGINT);
    sigaddset(&iw->set, SIGTERM);
    int e = pthread_sigmask(SIG_BLOCK, &iw->set, NULL);
    if (e == 0)
        e = pthread_create(&iw->thread, NULL, watch_interrupts, iw);
    iw->started = e == 0;
    return e;
}

/* Ends the watch with a signal aimed at its thread. Both stay blocked: one
 * that comes now is discarded when the process exits. */
static void interrupt_watch_stop(interrupt_watch_t *iw)
{
    if (!iw->started)
        return;
    atomic_store(&iw->over, 1);
    pthread_kill(iw->thread, SIGTERM);
    pthread_join(iw->thread, NULL);
    iw->started = 0;
}

/* Parses render's arguments, names the output and shows the scene's
 * warnings: -1 to go on, else the exit status. */
static int render_prepare(int argc, char **argv, args_t *a, char *out_exr, size_t len)
{
    int rc = parse_args(argc, argv, a, 1, 1, 0);
    if (rc || !a->positional)
        return rc ? rc : usage_error("%s", "render needs a scene file: vbrender render SCENE.json");
    if (a->key_file || a->master_key_file)
        return usage_error("%s", "render runs its master in this process: it takes no keys");
    if (a->output) {
        snprintf(out_exr, len, "%s", a->output);
    } else {
        const char *base = strrchr(a->positional, '/');
        replace_extension(base ? base + 1 : a->positional, ".exr", out_exr, len);
    }
    if (check_writable(out_exr) < 0)
        return 1;
    if (a->workers > a->threads)
        a->threads = a->workers;
    /* scene warnings are the client's to show: load it once here (a
     * Mitsuba scene as the JSON it becomes) */
    char err[VB_ERR_LEN];
    scene_t *scene = NULL;
    int rc_load;
    if (mitsuba_is_scene_path(a->positional)) {
        control_defines_t defines = {a->define, a->define_count};
        int raw = 0;
        cJSON *json = control_scene_json(a->positional, &defines, &raw, err, sizeof err);
        char *text = json ? cJSON_PrintUnformatted(json) : NULL;
        char dir[4096] = ".";
        const char *slash = strrchr(a->positional, '/');
        if (slash)
            snprintf(dir, sizeof dir, "%.*s", (int)(slash - a->positional), a->positional);
        if (json && !text)
            snprintf(err, sizeof err, "out of memory");
        rc_load = text ? scene_check_string(text, strlen(text), a->positional, dir, &scene, err,
                                            sizeof err)
                       : -1;
        cJSON_free(text);
        cJSON_Delete(json);
    } else if (a->define_count > 0) {
        return usage_error("-D sets a parameter of a Mitsuba scene (.xml), not of %s",
                           a->positional);
    } else {
        rc_load = scene_check(a->positional, &scene, err, sizeof err);
    }
    if (rc_load < 0) {
        fprintf(stderr, "vbrender: %s\n", err);
        return 1;
    }
    for (int i = 0; i < scene->warning_count; i++)
        fprintf(stderr, "vbrender: warning: %s\n", scene->warnings[i]);
    scene_destroy(&scene);
    return -1;
}

/* Stops issuing the job's work as `vbrender cancel` does; the image so far
 * stays to be fetched. */
static void cancel_job(control_t *c, unsigned long long id)
{
    char err[VB_ERR_LEN];
    cJSON *req = cJSON_CreateObject();
    cJSON_AddStringToObject(req, "cmd", "cancel");
    cJSON_AddNumberToObject(req, "job", (double)id);
    cJSON *reply = control_request(c, req, NULL, NULL, 0, err, sizeof err);
    cJSON_Delete(req);
    if (!reply)
        fprintf(stderr, "vbrender: cannot cancel job %llu: %s\n", id, err);
    else if (!cJSON_IsTrue(cJSON_GetObjectItemCaseSensitive(reply, "ok")))
        fprintf(stderr, "vbrender: cannot cancel job %llu: %s\n", id, json_str(reply, "error"));
    cJSON_Delete(reply);
}

/* Fetches the job's image and writes the outputs: the exit status. An
 * interrupted job's image is the image so far, its header marked partial
 * (vb.partial 1, vb.layers_done of vb.layers; vb.total_samples as always),
 * and the status 130. */
static int render_write(control_t *c, unsigned long long id, const char *out_exr, const args_t *a,
                        int interrupted)
{
    char err[VB_ERR_LEN];
    cJSON *job = NULL;
    image_t *img = control_fetch(c, id, &job, err, sizeof err);
    int done = img && strcmp(json_str(job, "state"), "done") == 0, rc = 1;
    int partial = interrupted && !done;
    if (img && partial) {
        image_set_int(img, "vb.partial", 1);
        image_set_int(img, "vb.layers_done", (int32_t)json_num(job, "layers_done"));
        image_set_int(img, "vb.layers", (int32_t)json_num(job, "layers"));
    }
    if (!img || write_outputs(img, job, out_exr, err, sizeof err) < 0) {
        fprintf(stderr, "vbrender: %s\n", err);
    } else {
        print_summary(job, (int)a->workers, (int)a->threads);
        rc = done ? 0 : 1;
        if (partial)
            fprintf(stderr,
                    "vbrender: interrupted: wrote partial image %s (%.0f samples, %.0f of %.0f "
                    "layers)\n",
                    out_exr, json_num(job, "samples"), json_num(job, "layers_done"),
                    json_num(job, "layers"));
        else if (!done)
            fprintf(stderr, "vbrender: job %s: %s\n", json_str(job, "state"),
                    json_str(job, "error"));
    }
    image_destroy(&img);
    cJSON_Delete(job);
    return partial ? 130 : rc;
}

/* Submits the job to an embedded master and waits for it, or for an
 * interrupt: the exit status. */
static int render_embedded(const args_t *a, const char *out_exr, int log_level,
                           const atomic_int *interrupts)
{
    char err[VB_ERR_LEN];
    embedded_t e;
    int rc = 1;
    image_t *ref = NULL;
    if (embedded_start(&e, a, log_level, err, sizeof err) < 0 ||
        (a->reference && image_read_exr(a->reference, &ref, err, sizeof err) < 0)) {
        fprintf(stderr, "vbrender: %s\n", err);
        goto done;
    }
    if (atomic_load(interrupts)) {
        image_destroy(&ref);
        fprintf(stderr, "vbrender: interrupted before the render started\n");
        rc = 130;
        goto done;
    }
    unsigned long long id =
        control_submit_defines(e.c, a->positional, &(control_defines_t){a->define, a->define_count},
                               a->settings, ref, NULL, err, sizeof err);
    image_destroy(&ref);
    if (!id) {
        fprintf(stderr, "vbrender: %s\n", err);
        goto done;
    }
    cJSON *job = watch_job(e.c, id, a->progress, 0, interrupts, err, sizeof err);
    int ended = job && job_ended(job), stopped = atomic_load(interrupts) && !ended;
    cJSON_Delete(job);
    if (!ended && !stopped)
        fprintf(stderr, "vbrender: %s\n", err);
    if (stopped) {
        fprintf(stderr,
                "vbrender: interrupted: stopping job %llu and writing the image so far "
                "(interrupt again to exit at once)\n",
                id);
        cancel_job(e.c, id);
    }
    if (ended || stopped)
        rc = render_write(e.c, id, out_exr, a, stopped);
done:
    embedded_stop(&e);
    return rc;
}

static int cmd_render(int argc, char **argv, int log_level)
{
    interrupt_watch_t iw;
    int err_no = interrupt_watch_start(&iw);
    if (err_no) {
        fprintf(stderr, "vbrender: cannot set up signal handling: %s\n", strerror(err_no));
        return 1;
    }
    args_t a;
    memset(&a, 0, sizeof a);
    char out_exr[4096];
    int rc = render_prepare(argc, argv, &a, out_exr, sizeof out_exr);
    if (rc == -1)
        rc = render_embedded(&a, out_exr, log_level, &iw.interrupts);
    interrupt_watch_stop(&iw);
    cJSON_Delete(a.settings);
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
    char err[VB_ERR_LEN];
    if (keys_load_secret(kf, mine, err, sizeof err) < 0 ||
        keys_load_public(mf, master, err, sizeof err) < 0) {
        fprintf(stderr, "vbrender: %s\n", err);
        *status = 1;
        return -1;
    }
    return 1;
}

/* ---- the commands' work, once connected: each prints its own messages and
 * returns the exit status ------------------------------------------------------------- */

static int run_submit(control_t *c, const char *cmd, const args_t *a, unsigned long long job)
{
    (void)cmd, (void)job;
    char err[VB_ERR_LEN];
    image_t *ref = NULL;
    if (a->reference && image_read_exr(a->reference, &ref, err, sizeof err) < 0) {
        fprintf(stderr, "vbrender: %s\n", err);
        return 1;
    }
    control_retry_t retry = {a->timeout_s, say_outage, NULL, 0};
    unsigned long long id =
        control_submit_defines(c, a->positional, &(control_defines_t){a->define, a->define_count},
                               a->settings, ref, &retry, err, sizeof err);
    image_destroy(&ref);
    if (!id) {
        if (retry.unreachable) /* some try may have reached it */
            fprintf(stderr, "vbrender: %s; the job may have been queued (see 'vbrender jobs')\n",
                    err);
        else
            fprintf(stderr, "vbrender: %s\n", err);
        return 1;
    }
    printf("%llu\n", id);
    return 0;
}

static int run_wait(control_t *c, const char *cmd, const args_t *a, unsigned long long job)
{
    (void)cmd;
    char err[VB_ERR_LEN];
    cJSON *st = wait_job(c, job, a->progress, a->timeout_s, err, sizeof err);
    if (!st) {
        fprintf(stderr, "vbrender: %s\n", err);
        return 1;
    }
    print_summary(st, 0, 0);
    int rc = strcmp(json_str(st, "state"), "done") == 0 ? 0 : 1;
    if (rc)
        fprintf(stderr, "vbrender: job %llu %s: %s\n", job, json_str(st, "state"),
                *json_str(st, "error") ? json_str(st, "error") : "no reason given");
    cJSON_Delete(st);
    return rc;
}

static int run_fetch(control_t *c, const char *cmd, const args_t *a, unsigned long long job)
{
    (void)cmd;
    char err[VB_ERR_LEN];
    cJSON *st = NULL;
    image_t *img = control_fetch(c, job, &st, err, sizeof err);
    int rc = 0;
    if (!img || write_outputs(img, st, a->output, err, sizeof err) < 0) {
        fprintf(stderr, "vbrender: %s\n", err);
        rc = 1;
    }
    image_destroy(&img);
    cJSON_Delete(st);
    return rc;
}

static void print_workers(const cJSON *list)
{
    printf("%-24s %7s %12s %12s %10s %8s %6s %8s\n", "host", "threads", "rays/s", "tasks done",
           "busy s", "backups", "held", "state");
    const cJSON *w;
    cJSON_ArrayForEach(w, list)
    {
        char r[32];
        /* "breaker": its leases kept running out; no task until it answers */
        const char *state = json_str(w, "state");
        /* held: tasks it has been sent and not answered */
        printf("%-24s %7.0f %12s %12.0f %10.1f %8.0f %6.0f %8s\n", json_str(w, "host"),
               json_num(w, "threads"), render_si(json_num(w, "rays_per_second"), r, sizeof r),
               json_num(w, "tasks_done"), json_num(w, "busy_seconds"), json_num(w, "backups"),
               json_num(w, "tasks_outstanding"), *state ? state : "ok");
    }
}

static void print_jobs(const cJSON *list)
{
    printf("%6s %-10s %-24s %9s %8s %12s %9s\n", "job", "state", "scene", "size", "layers",
           "samples", "seconds");
    const cJSON *j;
    cJSON_ArrayForEach(j, list)
    {
        char size[32], layers[32], s[32];
        snprintf(size, sizeof size, "%.0fx%.0f", json_num(j, "width"), json_num(j, "height"));
        snprintf(layers, sizeof layers, "%.0f/%.0f", json_num(j, "layers_done"),
                 json_num(j, "layers"));
        printf("%6.0f %-10s %-24s %9s %8s %12s %9.2f\n", json_num(j, "id"), json_str(j, "state"),
               json_str(j, "scene"), size, layers, render_si(json_num(j, "samples"), s, sizeof s),
               json_num(j, "seconds"));
        /* a durable master's notes on the job's state files, under its row */
        if (*json_str(j, "storage_error"))
            printf("%6s storage error: %s\n", "", json_str(j, "storage_error"));
        if (*json_str(j, "recovered"))
            printf("%6s recovered from %s\n", "", json_str(j, "recovered"));
    }
}

/* One job: its status as JSON on stdout, for people and scripts, and its
 * notes in words on stderr, so stdout stays JSON. */
static void print_job(const cJSON *st, unsigned long long job)
{
    char *text = cJSON_Print(st);
    printf("%s\n", text ? text : "{}");
    cJSON_free(text);
    if (*json_str(st, "storage_error"))
        fprintf(stderr, "vbrender: job %llu: storage error: %s\n", job,
                json_str(st, "storage_error"));
    if (*json_str(st, "recovered"))
        fprintf(stderr, "vbrender: job %llu: recovered from %s\n", job, json_str(st, "recovered"));
}

/* status, jobs, workers, cancel, delete, readmit: one request, one reply. */
static int run_request(control_t *c, const char *cmd, const args_t *a, unsigned long long job)
{
    char err[VB_ERR_LEN];
    cJSON *req = cJSON_CreateObject();
    cJSON_AddStringToObject(req, "cmd", strcmp(cmd, "status") == 0 && !job ? "jobs" : cmd);
    if (job)
        cJSON_AddNumberToObject(req, "job", (double)job);
    if (strcmp(cmd, "readmit") == 0)
        cJSON_AddStringToObject(req, "worker", a->positional);
    cJSON *reply = control_request(c, req, NULL, NULL, 0, err, sizeof err);
    cJSON_Delete(req);
    if (!reply || !cJSON_IsTrue(cJSON_GetObjectItemCaseSensitive(reply, "ok"))) {
        fprintf(stderr, "vbrender: %s\n", reply ? json_str(reply, "error") : err);
        cJSON_Delete(reply);
        return 1;
    }
    const cJSON *list =
        cJSON_GetObjectItemCaseSensitive(reply, strcmp(cmd, "workers") == 0 ? "workers" : "jobs");
    const cJSON *deleted = cJSON_GetObjectItemCaseSensitive(reply, "deleted");
    if (strcmp(cmd, "readmit") == 0)
        printf("readmitted %s\n", a->positional);
    else if (strcmp(cmd, "delete") == 0)
        printf("deleted job %llu\n",
               cJSON_IsNumber(deleted) ? (unsigned long long)deleted->valuedouble : job);
    else if (strcmp(cmd, "workers") == 0)
        print_workers(list);
    else if (list)
        print_jobs(list);
    else
        print_job(cJSON_GetObjectItemCaseSensitive(reply, "job"), job);
    cJSON_Delete(reply);
    return 0;
}

/* ---- the command table ------------------------------------------------------------ */

enum {
    TAKES_SCENE = 1,   /* a scene file (required) */
    TAKES_JOB = 2,     /* a job id (required) */
    TAKES_OPT_JOB = 4, /* a job id or nothing */
    TAKES_WORKER = 8   /* a worker's key or address (required) */
};

typedef struct command {
    const char *name;
    unsigned takes;      /* TAKES_*: its positional argument */
    unsigned allow;      /* ALLOW_*: its options */
    const char *missing; /* TAKES_SCENE, TAKES_WORKER: the message when it is missing */
    int (*run)(control_t *c, const char *cmd, const args_t *a, unsigned long long job);
} command_t;

static const command_t commands[] = {
    {"submit", TAKES_SCENE, ALLOW_SETTINGS | ALLOW_TIMEOUT,
     "submit needs a scene file: vbrender submit SCENE.json", run_submit},
    {"status", TAKES_OPT_JOB, 0, NULL, run_request},
    {"wait", TAKES_JOB, ALLOW_TIMEOUT, NULL, run_wait},
    {"fetch", TAKES_JOB, ALLOW_OUTPUT, NULL, run_fetch},
    {"cancel", TAKES_JOB, 0, NULL, run_request},
    {"delete", TAKES_JOB, 0, NULL, run_request},
    {"jobs", 0, 0, NULL, run_request},
    {"workers", 0, 0, NULL, run_request},
    {"readmit", TAKES_WORKER, 0,
     "readmit needs a worker: its key (Z85), or its address without keys", run_request},
};

/* The positional argument and -o against what the command takes: 0, or
 * the exit status after a usage message. */
static int check_command_args(const command_t *d, const args_t *a, unsigned long long *job)
{
    const char *p = a->positional;
    if ((d->takes & (TAKES_SCENE | TAKES_WORKER)) && !p)
        return usage_error("%s", d->missing);
    if (((d->takes & TAKES_JOB) || ((d->takes & TAKES_OPT_JOB) && p)) &&
        (!p || parse_job_id(p, job) < 0))
        return usage_error("%s needs a job id (a positive integer)", d->name);
    if (!d->takes && p)
        return usage_error("unexpected argument '%s'", p);
    if ((d->allow & ALLOW_OUTPUT) && !a->output)
        return usage_error("%s needs -o OUT.exr", d->name);
    return 0;
}

/* Connects to the master (with the keys, if any) and runs the command. */
static int connect_and_run(const command_t *d, const args_t *a, unsigned long long job)
{
    keys_pair_t mine;
    char master_key[KEYS_Z85_LEN + 1], err[2048];
    int rc = 1;
    int have_keys = load_client_keys(a, &mine, master_key, &rc);
    if (have_keys < 0)
        return rc;
    control_keys_t keys = {mine.public_z85, mine.secret_z85, master_key};
    void *ctx = zmq_ctx_new();
    control_t *c = control_new_with_keys(ctx, a->master, CLIENT_REQUEST_TIMEOUT_MS,
                                         have_keys ? &keys : NULL, err, sizeof err);
    if (have_keys)
        explicit_bzero(&mine, sizeof mine); /* control keeps its own copy */
    if (!c)
        fprintf(stderr, "vbrender: %s\n", err);
    else
        rc = d->run(c, d->name, a, job);
    control_destroy(&c);
    zmq_ctx_term(ctx);
    return rc;
}

static int simple_command(const char *cmd, int argc, char **argv)
{
    const command_t *d = NULL;
    for (size_t i = 0; !d && i < sizeof commands / sizeof commands[0]; i++)
        if (strcmp(cmd, commands[i].name) == 0)
            d = &commands[i];
    if (!d)
        return usage_error("unknown command '%s'", cmd);
    args_t a;
    memset(&a, 0, sizeof a);
    unsigned long long job = 0;
    int rc = parse_args(argc, argv, &a, (d->allow & ALLOW_SETTINGS) != 0,
                        (d->allow & ALLOW_OUTPUT) != 0, (d->allow & ALLOW_TIMEOUT) != 0);
    if (!rc)
        rc = check_command_args(d, &a, &job);
    if (!rc && (d->allow & ALLOW_OUTPUT) && check_writable(a.output) < 0)
        rc = 1;
    if (!rc)
        rc = connect_and_run(d, &a, job);
    cJSON_Delete(a.settings);
    return rc;
}

/* ---- keygen ----------------------------------------------------------------------- */

static int cmd_keygen(int argc, char **argv)
{
    if (argc != 1 || argv[0][0] == '-' || !argv[0][0])
        return usage_error(
            "%s", "keygen needs a name: vbrender keygen NAME (writes NAME.key and NAME.pub)");
    keys_pair_t k;
    char err[VB_ERR_LEN];
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
    char err[VB_ERR_LEN];
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

/* Takes --log-level LEVEL out of argv (every command accepts it; only
 * render's embedded master and workers log): 0 with *level set (0 when not
 * given), else the exit status after a message. */
static int take_log_level(int *argc, char **argv, int *level)
{
    *level = 0;
    for (int i = 1; i < *argc; i++) {
        if (strcmp(argv[i], "--log-level") != 0)
            continue;
        const char *v = i + 1 < *argc ? argv[i + 1] : NULL;
        if ((*level = vblog_level_parse(v)) < 0)
            return usage_error("--log-level must be error, warn, info or debug (got '%s')",
                               v ? v : "");
        memmove(argv + i, argv + i + 2, (size_t)(*argc - i - 2) * sizeof *argv);
        *argc -= 2;
        i--;
    }
    return 0;
}

int main(int argc, char **argv)
{
    signal(SIGPIPE, SIG_IGN);
    if (argc == 2 && strcmp(argv[1], "--version") == 0) {
        char build[PROTO_BUILD_SIZE + 1];
        proto_host_build_id(build);
        printf("vbrender %s\n", build);
        return 0;
    }
    int log_level, rc = take_log_level(&argc, argv, &log_level);
    if (rc)
        return rc;
    if (argc < 2) {
        print_usage(stderr);
        return 2;
    }
    if (strcmp(argv[1], "-h") == 0 || strcmp(argv[1], "--help") == 0 ||
        strcmp(argv[1], "help") == 0) {
        print_usage(stdout);
        return 0;
    }
    for (int i = 2; i < argc; i++)
        if (strcmp(argv[i], "-h") == 0 || strcmp(argv[i], "--help") == 0) {
            print_usage(stdout);
            return 0;
        }
    if (strcmp(argv[1], "render") == 0)
        return cmd_render(argc - 2, argv + 2, log_level);
    if (strcmp(argv[1], "compare") == 0)
        return cmd_compare(argc - 2, argv + 2);
    if (strcmp(argv[1], "keygen") == 0)
        return cmd_keygen(argc - 2, argv + 2);
    if (strcmp(argv[1], "serve") == 0)
        return serve_main(argc - 2, argv + 2);
    for (size_t i = 0; i < sizeof commands / sizeof commands[0]; i++)
        if (strcmp(argv[1], commands[i].name) == 0)
            return simple_command(argv[1], argc - 2, argv + 2);
    fprintf(stderr, "vbrender: unknown command '%s' (run 'vbrender --help')\n", argv[1]);
    return 2;
}
