/* serve.c - `vbrender serve`: the dashboard and /metrics (see serve.h).
 *
 * libmicrohttpd runs a thread per connection; every thread asks the master
 * through one control connection under a mutex. A socket per request would
 * cost a connection (and a CURVE handshake) each time for nothing: the
 * master answers one request at a time anyway, and a REQ socket may not be
 * shared by threads without the lock. While the master is away a request
 * waits at most SERVE_REQUEST_TIMEOUT_MS, and for FAIL_FAST_S after a lost one
 * the others fail at once instead of queueing behind a timeout each.
 */
#include "serve.h"
#include "jsonget.h"

#include <errno.h>
#include <microhttpd.h>
#include <netdb.h>
#include <png.h>
#include <pthread.h>
#include <signal.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <zmq.h>

#include "control.h"
#include "defaults.h"
#include "image.h"
#include "keys.h"

#define FAIL_FAST_S 1.0
#define MAX_JOB_ID 9007199254740992ULL /* 2^53: ids travel as JSON numbers */

static const char usage_text[] =
    "usage: vbrender serve [--master EP] [--listen ADDR:PORT] [--key FILE --master-key FILE]\n"
    "  a web dashboard (jobs, a job's image as it converges, workers) and Prometheus\n"
    "  metrics (/metrics) for a running master, at http://ADDR:PORT/\n"
    "  --master EP          the master's control endpoint (default " CLIENT_DEFAULT_MASTER ")\n"
    "  --listen ADDR:PORT   where to serve (default " SERVE_DEFAULT_LISTEN ", this machine only).\n"
    "                       Anybody who reaches it sees the jobs and may cancel them with\n"
    "                       this client's key: bind another address (0.0.0.0:8080,\n"
    "                       [::]:8080) only on a network you trust. Port 0: any free port.\n"
    "  --key FILE, --master-key FILE   CURVE keys, as for the other commands\n"
    "                       (default: $VBRENDER_KEY, $VBRENDER_MASTER_KEY)\n";

/* ---- routes and queries ---------------------------------------------------------- */

static const char ALLOW_GET[] = "GET, HEAD", ALLOW_POST[] = "POST";

/* A job id at the start of s: its length, or 0 when s does not start with
 * a positive integer below 2^53 (no sign, no leading zero). */
static size_t parse_id(const char *s, unsigned long long *id)
{
    size_t n = 0;
    unsigned long long v = 0;
    if (s[0] == '0')
        return 0;
    while (s[n] >= '0' && s[n] <= '9') {
        if (n >= 16)
            return 0;
        v = v * 10 + (unsigned long long)(s[n++] - '0');
    }
    if (n == 0 || v > MAX_JOB_ID)
        return 0;
    *id = v;
    return n;
}

/* The routes under /api/job/ID: what follows the id. */
static int job_api_route(const char *rest, serve_route_t *out)
{
    static const struct {
        const char *suffix;
        serve_route_kind_t kind;
    } subs[] = {{"", SERVE_API_JOB},
                {"/preview.png", SERVE_API_PREVIEW},
                {"/samples.png", SERVE_API_SAMPLES},
                {"/cancel", SERVE_API_CANCEL}};
    for (size_t i = 0; i < sizeof subs / sizeof subs[0]; i++)
        if (strcmp(rest, subs[i].suffix) == 0) {
            out->kind = subs[i].kind;
            return 0;
        }
    return -1;
}

static int find_route(const char *path, serve_route_t *out)
{
    static const struct {
        const char *path;
        serve_route_kind_t kind;
    } fixed[] = {{"/", SERVE_JOBS_PAGE},
                 {"/workers", SERVE_WORKERS_PAGE},
                 {"/static/app.css", SERVE_ASSET_CSS},
                 {"/static/app.js", SERVE_ASSET_JS},
                 {"/api/jobs", SERVE_API_JOBS},
                 {"/api/workers", SERVE_API_WORKERS},
                 {"/metrics", SERVE_METRICS}};
    for (size_t i = 0; i < sizeof fixed / sizeof fixed[0]; i++)
        if (strcmp(path, fixed[i].path) == 0) {
            out->kind = fixed[i].kind;
            return 0;
        }
    size_t n;
    if (strncmp(path, "/job/", 5) == 0 && (n = parse_id(path + 5, &out->job)) > 0 &&
        path[5 + n] == '\0') {
        out->kind = SERVE_JOB_PAGE;
        return 0;
    }
    if (strncmp(path, "/api/job/", 9) == 0 && (n = parse_id(path + 9, &out->job)) > 0)
        return job_api_route(path + 9 + n, out);
    return -1;
}

int serve_parse_route(const char *method, const char *path, serve_route_t *out, char *msg,
                      size_t msglen)
{
    memset(out, 0, sizeof *out);
    if (find_route(path, out) < 0) {
        snprintf(msg, msglen, "no such page: %.200s", path);
        return 404;
    }
    int post = out->kind == SERVE_API_CANCEL;
    out->allow = post ? ALLOW_POST : ALLOW_GET;
    int ok = post ? strcmp(method, "POST") == 0
                  : strcmp(method, "GET") == 0 || strcmp(method, "HEAD") == 0;
    if (!ok) {
        snprintf(msg, msglen, "%.200s takes %s, not %.16s", path, out->allow, method);
        return 405;
    }
    return 200;
}

int serve_parse_size(const char *text, const char *name, int *out, char *msg, size_t msglen)
{
    if (!text) {
        *out = SERVE_PREVIEW_DEFAULT;
        return 0;
    }
    int v = 0, n = 0;
    while (text[n] >= '0' && text[n] <= '9' && v <= SERVE_PREVIEW_MAX)
        v = v * 10 + (text[n++] - '0');
    if (n == 0 || text[n] != '\0' || v < 1 || v > SERVE_PREVIEW_MAX) {
        snprintf(msg, msglen, "%s must be an integer from 1 to %d (got '%.32s')", name,
                 SERVE_PREVIEW_MAX, text);
        return -1;
    }
    *out = v;
    return 0;
}

int serve_same_origin(const char *origin, const char *host)
{
    if (!origin)
        return 1;
    return host && strncmp(origin, "http://", 7) == 0 && strcmp(origin + 7, host) == 0;
}

int serve_error_status(const char *msg)
{
    if (strstr(msg, "no such job"))
        return 404;
    if (strstr(msg, "belongs to another client") || strstr(msg, "only an admin"))
        return 403;
    if (strstr(msg, "unknown command"))
        return 501;
    return 400;
}

/* ---- /metrics -------------------------------------------------------------------- */

/* A growing text; after a failed allocation it stays failed (text NULL). */
typedef struct text_buf {
    char *text;
    size_t len, cap;
    int failed;
} text_buf_t;

static void tb_printf(text_buf_t *b, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void tb_printf(text_buf_t *b, const char *fmt, ...)
{
    for (int pass = 0; pass < 2 && !b->failed; pass++) {
        va_list ap;
        va_start(ap, fmt);
        int n =
            vsnprintf(b->text ? b->text + b->len : NULL, b->text ? b->cap - b->len : 0, fmt, ap);
        va_end(ap);
        if (n < 0) {
            b->failed = 1;
        } else if (b->text && b->len + (size_t)n < b->cap) {
            b->len += (size_t)n;
            return;
        } else {
            size_t cap = (b->cap + (size_t)n + 1) * 2;
            char *t = realloc(b->text, cap);
            if (!t)
                b->failed = 1;
            else
                b->text = t, b->cap = cap;
        }
    }
}

/* A sample value as Prometheus reads it: integers without a fraction,
 * others to the last bit, NaN and infinities by name. */
static void format_value(double v, char *buf, size_t len)
{
    if (v != v)
        snprintf(buf, len, "NaN");
    else if (v > 1.7976931348623157e308 || v < -1.7976931348623157e308)
        snprintf(buf, len, "%sInf", v > 0 ? "+" : "-");
    else if (v == (double)(long long)v && v < 9007199254740992.0 && v > -9007199254740992.0)
        snprintf(buf, len, "%lld", (long long)v);
    else
        snprintf(buf, len, "%.17g", v);
}

static void metric_header(text_buf_t *b, const char *name, const char *type, const char *help)
{
    tb_printf(b, "# HELP %s %s\n# TYPE %s %s\n", name, help, name, type);
}

static void metric(text_buf_t *b, const char *name, const char *type, const char *help, double v)
{
    char num[64];
    format_value(v, num, sizeof num);
    metric_header(b, name, type, help);
    tb_printf(b, "%s %s\n", name, num);
}

/* A metric from a number in obj, left out when obj does not have it. */
static void metric_from(text_buf_t *b, const cJSON *obj, const char *key, const char *name,
                        const char *type, const char *help)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(obj, key);
    if (cJSON_IsNumber(v))
        metric(b, name, type, help, v->valuedouble);
}

/* A label value with \, " and newline escaped, as the format wants. */
static void label_escape(const char *s, char *out, size_t len)
{
    size_t n = 0;
    for (; *s && n + 3 < len; s++) {
        if (*s == '\\' || *s == '"' || *s == '\n') {
            out[n++] = '\\';
            out[n++] = *s == '\n' ? 'n' : *s;
        } else {
            out[n++] = *s;
        }
    }
    out[n] = '\0';
}

#define MAX_STATES 16

/* vbrender_jobs{state=...}: every state the master has, the usual five
 * always (a state with no job reads 0 rather than vanishing). */
static void metrics_jobs(text_buf_t *b, const cJSON *jobs)
{
    const char *names[MAX_STATES] = {"queued", "running", "done", "failed", "cancelled"};
    double count[MAX_STATES] = {0};
    int nstates = 5;
    const cJSON *j;
    cJSON_ArrayForEach(j, jobs)
    {
        const char *st = json_str(j, "state");
        int i = 0;
        while (i < nstates && strcmp(names[i], st) != 0)
            i++;
        if (i == nstates && nstates < MAX_STATES)
            names[nstates++] = st;
        if (i < nstates)
            count[i]++;
    }
    metric_header(b, "vbrender_jobs", "gauge", "Jobs this client may see on the master, by state.");
    for (int i = 0; i < nstates; i++) {
        char label[256], num[64];
        label_escape(names[i], label, sizeof label);
        format_value(count[i], num, sizeof num);
        tb_printf(b, "vbrender_jobs{state=\"%s\"} %s\n", label, num);
    }
}

/* The workers, their threads, and the running jobs' rates summed. */
static void metrics_throughput(text_buf_t *b, const cJSON *jobs, const cJSON *workers)
{
    double rays = 0, samples = 0, threads = 0;
    const cJSON *it;
    cJSON_ArrayForEach(it, jobs)
    {
        if (strcmp(json_str(it, "state"), "running") == 0) {
            rays += json_num(it, "rays_per_second");
            samples += json_num(it, "samples_per_second");
        }
    }
    cJSON_ArrayForEach(it, workers) threads += json_num(it, "threads");
    metric(b, "vbrender_workers_connected", "gauge", "Workers connected to the master.",
           (double)cJSON_GetArraySize(workers));
    metric(b, "vbrender_worker_threads", "gauge", "Render threads of the connected workers.",
           threads);
    metric(b, "vbrender_rays_per_second", "gauge", "Rays per second of the running jobs, summed.",
           rays);
    metric(b, "vbrender_samples_per_second", "gauge",
           "Samples per second of the running jobs, summed.", samples);
}

/* The master's own counters (the "master" object of the workers reply),
 * with the queue depth and outstanding tasks counted from the lists when
 * the master does not give them. */
static void metrics_master(text_buf_t *b, const cJSON *m, const cJSON *jobs, const cJSON *workers)
{
    metric_from(b, m, "tasks_issued", "vbrender_tasks_issued_total", "counter",
                "Tasks the master sent to workers.");
    metric_from(b, m, "tasks_reissued", "vbrender_tasks_reissued_total", "counter",
                "Tasks sent again after a worker was lost or too slow.");
    metric_from(b, m, "late_results", "vbrender_late_results_total", "counter",
                "Results dropped because they came after their task was reissued or ended.");
    metric_from(b, m, "malformed_messages", "vbrender_malformed_messages_total", "counter",
                "Malformed messages the master dropped.");
    metric_from(b, m, "backups", "vbrender_backup_tasks_total", "counter",
                "Backup copies of tasks out too long, sent to idle workers.");
    metric_from(b, m, "workers_banned", "vbrender_workers_banned_total", "counter",
                "Workers dropped and refused for a while over refused results.");
    metric_from(b, m, "rate_limited_requests", "vbrender_rate_limited_requests_total", "counter",
                "Requests the master refused for their rate.");
    double queued = 0, outstanding = 0;
    const cJSON *it;
    cJSON_ArrayForEach(it, jobs) queued += strcmp(json_str(it, "state"), "queued") == 0;
    cJSON_ArrayForEach(it, workers) outstanding += json_num(it, "tasks_outstanding");
    /* the master's figures count every job, the lists only this client's */
    const cJSON *q = cJSON_GetObjectItemCaseSensitive(m, "jobs_queued");
    const cJSON *o = cJSON_GetObjectItemCaseSensitive(m, "tasks_outstanding");
    metric(b, "vbrender_queue_depth", "gauge", "Jobs waiting to start.",
           cJSON_IsNumber(q) ? q->valuedouble : queued);
    metric(b, "vbrender_outstanding_tasks", "gauge", "Tasks sent to workers and not answered yet.",
           cJSON_IsNumber(o) ? o->valuedouble : outstanding);
}

char *serve_metrics_text(const cJSON *jobs_reply, const cJSON *workers_reply)
{
    text_buf_t b = {0};
    const cJSON *jobs = cJSON_GetObjectItemCaseSensitive(jobs_reply, "jobs");
    const cJSON *workers = cJSON_GetObjectItemCaseSensitive(workers_reply, "workers");
    const cJSON *m = cJSON_GetObjectItemCaseSensitive(workers_reply, "master");
    metrics_jobs(&b, cJSON_IsArray(jobs) ? jobs : NULL);
    metrics_throughput(&b, cJSON_IsArray(jobs) ? jobs : NULL,
                       cJSON_IsArray(workers) ? workers : NULL);
    metrics_master(&b, cJSON_IsObject(m) ? m : NULL, cJSON_IsArray(jobs) ? jobs : NULL,
                   cJSON_IsArray(workers) ? workers : NULL);
    if (b.failed) {
        free(b.text);
        return NULL;
    }
    return b.text;
}

/* ---- PNG ------------------------------------------------------------------------- */

static unsigned char *png_from_rgb8(const unsigned char *rgb, int w, int h, size_t *size, char *err,
                                    size_t errlen)
{
    png_image im;
    memset(&im, 0, sizeof im);
    im.version = PNG_IMAGE_VERSION;
    im.width = (png_uint_32)w;
    im.height = (png_uint_32)h;
    im.format = PNG_FORMAT_RGB;
    png_alloc_size_t n = 0;
    if (!png_image_write_to_memory(&im, NULL, &n, 0, rgb, 0, NULL)) {
        snprintf(err, errlen, "cannot encode a PNG: %s", im.message);
        return NULL;
    }
    unsigned char *out = malloc(n ? n : 1);
    memset(&im, 0, sizeof im);
    im.version = PNG_IMAGE_VERSION;
    im.width = (png_uint_32)w;
    im.height = (png_uint_32)h;
    im.format = PNG_FORMAT_RGB;
    if (!out || !png_image_write_to_memory(&im, out, &n, 0, rgb, 0, NULL)) {
        snprintf(err, errlen, "cannot encode a PNG: %s", out ? im.message : "out of memory");
        free(out);
        return NULL;
    }
    *size = n;
    return out;
}

static unsigned char *rgb8_alloc(int w, int h, char *err, size_t errlen)
{
    unsigned char *rgb = NULL;
    if (w >= 1 && h >= 1 && w <= SERVE_PREVIEW_MAX && h <= SERVE_PREVIEW_MAX)
        rgb = malloc((size_t)w * (size_t)h * 3);
    if (!rgb)
        snprintf(err, errlen, "cannot make a %dx%d PNG (size or memory)", w, h);
    return rgb;
}

unsigned char *serve_png_rgb(const float *lin, int w, int h, size_t *size, char *err, size_t errlen)
{
    unsigned char *rgb = rgb8_alloc(w, h, err, errlen);
    if (!rgb)
        return NULL;
    for (size_t i = 0, n = (size_t)w * (size_t)h * 3; i < n; i++)
        rgb[i] = image_srgb_byte((double)lin[i]);
    unsigned char *png = png_from_rgb8(rgb, w, h, size, err, errlen);
    free(rgb);
    return png;
}

unsigned char *serve_png_heat(const float *v, int w, int h, float hi, size_t *size, char *err,
                              size_t errlen)
{
    unsigned char *rgb = rgb8_alloc(w, h, err, errlen);
    if (!rgb)
        return NULL;
    for (size_t i = 0, n = (size_t)w * (size_t)h; i < n; i++)
        image_heat_rgb(hi > 0 ? (double)v[i] / (double)hi : 0.0, rgb + 3 * i);
    unsigned char *png = png_from_rgb8(rgb, w, h, size, err, errlen);
    free(rgb);
    return png;
}

/* ---- the master ------------------------------------------------------------------ */

typedef struct serve {
    struct MHD_Daemon *httpd;
    void *zmq;
    control_t *ctl;
    pthread_mutex_t lock; /* ctl and what follows */
    double lost_at;       /* when a request last got no answer (0: never) */
    char lost_err[512];
} serve_t;

/* What one ask() gets back besides the reply: the binary frames (copied,
 * so they outlive the lock), and on failure an HTTP status. */
typedef struct answer {
    cJSON *reply; /* NULL: status and err say why */
    int status;
    char err[768];
    void *frames[2];
    size_t sizes[2];
    int nframes;
} answer_t;

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void answer_free(answer_t *a)
{
    cJSON_Delete(a->reply);
    for (int i = 0; i < a->nframes; i++)
        free(a->frames[i]);
    memset(a, 0, sizeof *a);
}

static void copy_frames(serve_t *s, answer_t *a)
{
    int n = control_frame_count(s->ctl);
    for (int i = 0; i < n && i < 2; i++) {
        size_t size;
        const void *data = control_frame(s->ctl, i, &size);
        a->frames[i] = malloc(size ? size : 1);
        if (!a->frames[i])
            break;
        memcpy(a->frames[i], data, size);
        a->sizes[i] = size;
        a->nframes = i + 1;
    }
}

/* Sends req to the master: a->reply (which may say ok false), or NULL with
 * 503 (no answer: the master is away) or 502 (it refused the connection
 * or sent nonsense), the message starting "master unreachable". */
static void ask(serve_t *s, const cJSON *req, answer_t *a)
{
    memset(a, 0, sizeof *a);
    char err[512] = "";
    pthread_mutex_lock(&s->lock);
    if (s->lost_at > 0 && now_s() - s->lost_at < FAIL_FAST_S) {
        snprintf(err, sizeof err, "%s", s->lost_err);
        a->status = 503;
    } else if ((a->reply = control_request(s->ctl, req, NULL, NULL, 0, err, sizeof err))) {
        s->lost_at = 0;
        copy_frames(s, a);
    } else if (control_lost(s->ctl)) {
        s->lost_at = now_s();
        snprintf(s->lost_err, sizeof s->lost_err, "%s", err);
        a->status = 503;
    } else {
        a->status = 502;
    }
    pthread_mutex_unlock(&s->lock);
    if (!a->reply)
        snprintf(a->err, sizeof a->err, "master unreachable: %s", err);
}

static cJSON *request_for(const char *cmd, unsigned long long job)
{
    cJSON *req = cJSON_CreateObject();
    cJSON_AddStringToObject(req, "cmd", cmd);
    if (job)
        cJSON_AddNumberToObject(req, "job", (double)job);
    return req;
}

/* ---- HTTP ------------------------------------------------------------------------ */

/* One response: body (len bytes, kept or freed as mode says) of that
 * type, with one more header when hname is not NULL (Allow, Location). */
static enum MHD_Result respond(struct MHD_Connection *conn, int status, const char *type,
                               void *body, size_t len, enum MHD_ResponseMemoryMode mode,
                               const char *hname, const char *hvalue)
{
    struct MHD_Response *r = MHD_create_response_from_buffer(len, body, mode);
    if (!r) {
        if (mode == MHD_RESPMEM_MUST_FREE)
            free(body);
        return MHD_NO;
    }
    MHD_add_response_header(r, "Content-Type", type);
    MHD_add_response_header(r, "Cache-Control", "no-store");
    MHD_add_response_header(r, "X-Content-Type-Options", "nosniff");
    if (hname)
        MHD_add_response_header(r, hname, hvalue);
    enum MHD_Result rc = MHD_queue_response(conn, (unsigned)status, r);
    MHD_destroy_response(r);
    return rc;
}

static enum MHD_Result send_body(struct MHD_Connection *conn, int status, const char *type,
                                 void *body, size_t len, enum MHD_ResponseMemoryMode mode)
{
    return respond(conn, status, type, body, len, mode, NULL, NULL);
}

static enum MHD_Result send_json_with(struct MHD_Connection *conn, int status, const cJSON *body,
                                      const char *hname, const char *hvalue)
{
    char *text = cJSON_PrintUnformatted(body);
    if (!text)
        return MHD_NO;
    /* cJSON allocates with malloc here (no hooks set), so MHD may free it */
    return respond(conn, status, "application/json", text, strlen(text), MHD_RESPMEM_MUST_FREE,
                   hname, hvalue);
}

static enum MHD_Result send_json(struct MHD_Connection *conn, int status, const cJSON *body)
{
    return send_json_with(conn, status, body, NULL, NULL);
}

static enum MHD_Result send_error_with(struct MHD_Connection *conn, int status, const char *msg,
                                       const char *hname, const char *hvalue)
{
    cJSON *b = cJSON_CreateObject();
    cJSON_AddBoolToObject(b, "ok", 0);
    cJSON_AddStringToObject(b, "error", msg);
    enum MHD_Result rc = send_json_with(conn, status, b, hname, hvalue);
    cJSON_Delete(b);
    return rc;
}

static enum MHD_Result send_error(struct MHD_Connection *conn, int status, const char *msg)
{
    return send_error_with(conn, status, msg, NULL, NULL);
}

static const char *reply_error(const cJSON *reply)
{
    const char *e = json_str(reply, "error");
    return *e ? e : "the master refused the request";
}

static int reply_ok(const cJSON *reply)
{
    return cJSON_IsTrue(cJSON_GetObjectItemCaseSensitive(reply, "ok"));
}

/* /api/jobs, /api/job/ID, /api/workers and the cancel: the reply as it is.
 * A cancel from a browser's form goes back to the job's page. */
static enum MHD_Result handle_passthrough(serve_t *s, struct MHD_Connection *conn,
                                          const serve_route_t *rt)
{
    const char *cmd = rt->kind == SERVE_API_JOBS      ? "jobs"
                      : rt->kind == SERVE_API_WORKERS ? "workers"
                      : rt->kind == SERVE_API_CANCEL  ? "cancel"
                                                      : "status";
    cJSON *req = request_for(cmd, rt->job);
    answer_t a;
    ask(s, req, &a);
    cJSON_Delete(req);
    enum MHD_Result rc;
    const char *accept = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, "Accept");
    if (!a.reply) {
        rc = send_error(conn, a.status, a.err);
    } else if (!reply_ok(a.reply)) {
        rc = send_json(conn, serve_error_status(reply_error(a.reply)), a.reply);
    } else if (rt->kind == SERVE_API_CANCEL && accept && strstr(accept, "text/html")) {
        char where[64];
        snprintf(where, sizeof where, "/job/%llu", rt->job);
        rc = respond(conn, MHD_HTTP_SEE_OTHER, "text/plain", "", 0, MHD_RESPMEM_PERSISTENT,
                     "Location", where);
    } else {
        rc = send_json(conn, 200, a.reply);
    }
    answer_free(&a);
    return rc;
}

static enum MHD_Result handle_metrics(serve_t *s, struct MHD_Connection *conn)
{
    cJSON *rj = request_for("jobs", 0), *rw = request_for("workers", 0);
    answer_t aj, aw;
    ask(s, rj, &aj);
    ask(s, rw, &aw);
    cJSON_Delete(rj);
    cJSON_Delete(rw);
    enum MHD_Result rc;
    char msg[1024];
    answer_t *bad = !aj.reply ? &aj : !aw.reply ? &aw : NULL;
    if (bad) {
        snprintf(msg, sizeof msg, "%s\n", bad->err);
        rc = send_body(conn, bad->status, "text/plain; charset=utf-8", msg, strlen(msg),
                       MHD_RESPMEM_MUST_COPY);
    } else if (!reply_ok(aj.reply) || !reply_ok(aw.reply)) {
        snprintf(msg, sizeof msg, "%s\n", reply_error(reply_ok(aj.reply) ? aw.reply : aj.reply));
        rc = send_body(conn, 502, "text/plain; charset=utf-8", msg, strlen(msg),
                       MHD_RESPMEM_MUST_COPY);
    } else {
        char *text = serve_metrics_text(aj.reply, aw.reply);
        rc = text ? send_body(conn, 200, "text/plain; version=0.0.4; charset=utf-8", text,
                              strlen(text), MHD_RESPMEM_MUST_FREE)
                  : MHD_NO;
    }
    answer_free(&aj);
    answer_free(&aw);
    return rc;
}

/* Checks a preview reply against the contract: 0 with the size and the
 * heat map's top, or -1 with a message. */
static int preview_checked(const answer_t *a, int *w, int *h, double *hi, char *msg, size_t msglen)
{
    double fw = json_num(a->reply, "width"), fh = json_num(a->reply, "height");
    if (!(fw >= 1 && fw <= SERVE_PREVIEW_MAX && fh >= 1 && fh <= SERVE_PREVIEW_MAX) ||
        fw != (int)fw || fh != (int)fh || a->nframes != 2) {
        snprintf(msg, msglen, "the master's preview is malformed (size or frames)");
        return -1;
    }
    *w = (int)fw;
    *h = (int)fh;
    size_t px = (size_t)*w * (size_t)*h;
    if (a->sizes[0] != px * 3 * sizeof(float) || a->sizes[1] != px * sizeof(float)) {
        snprintf(msg, msglen, "the master's preview is malformed (frame sizes)");
        return -1;
    }
    /* the heat map's top: the most samples any preview pixel has, so that
     * the map shows where the samples went (the page says the range); the
     * job's spp before any sample */
    *hi = json_num(a->reply, "spp_max");
    if (!(*hi > 0))
        *hi = json_num(cJSON_GetObjectItemCaseSensitive(a->reply, "job"), "spp");
    return 0;
}

/* preview.png and samples.png: a preview request, encoded. */
static enum MHD_Result handle_preview(serve_t *s, struct MHD_Connection *conn,
                                      const serve_route_t *rt)
{
    char msg[768];
    int mw, mh;
    if (serve_parse_size(MHD_lookup_connection_value(conn, MHD_GET_ARGUMENT_KIND, "w"), "w", &mw,
                         msg, sizeof msg) < 0 ||
        serve_parse_size(MHD_lookup_connection_value(conn, MHD_GET_ARGUMENT_KIND, "h"), "h", &mh,
                         msg, sizeof msg) < 0)
        return send_error(conn, 400, msg);
    cJSON *req = request_for("preview", rt->job);
    cJSON_AddNumberToObject(req, "max_width", mw);
    cJSON_AddNumberToObject(req, "max_height", mh);
    answer_t a;
    ask(s, req, &a);
    cJSON_Delete(req);
    enum MHD_Result rc;
    int w, h;
    double hi;
    if (!a.reply) {
        rc = send_error(conn, a.status, a.err);
    } else if (!reply_ok(a.reply)) {
        const char *e = reply_error(a.reply);
        int st = serve_error_status(e);
        snprintf(msg, sizeof msg, "%s%s", st == 501 ? "this master has no previews: " : "", e);
        rc = send_error(conn, st, msg);
    } else if (preview_checked(&a, &w, &h, &hi, msg, sizeof msg) < 0) {
        rc = send_error(conn, 502, msg);
    } else {
        size_t size = 0;
        unsigned char *png =
            rt->kind == SERVE_API_PREVIEW
                ? serve_png_rgb(a.frames[0], w, h, &size, msg, sizeof msg)
                : serve_png_heat(a.frames[1], w, h, (float)hi, &size, msg, sizeof msg);
        char top[64];
        format_value(hi, top, sizeof top);
        rc = png ? respond(conn, 200, "image/png", png, size, MHD_RESPMEM_MUST_FREE,
                           "X-Heatmap-Max", top)
                 : send_error(conn, 500, msg);
    }
    answer_free(&a);
    return rc;
}

/* The job page: its template with the id in place of every @JOB@. */
static enum MHD_Result send_job_page(struct MHD_Connection *conn, unsigned long long job)
{
    const char *t = serve_asset_job_html;
    char id[32];
    int idlen = snprintf(id, sizeof id, "%llu", job);
    size_t cap = strlen(t) + 1, n = 0;
    for (const char *p = t; (p = strstr(p, "@JOB@")); p += 5)
        cap += (size_t)idlen;
    char *out = malloc(cap);
    if (!out)
        return MHD_NO;
    for (const char *p = t; *p;) {
        if (strncmp(p, "@JOB@", 5) == 0) {
            memcpy(out + n, id, (size_t)idlen);
            n += (size_t)idlen;
            p += 5;
        } else {
            out[n++] = *p++;
        }
    }
    return send_body(conn, 200, "text/html; charset=utf-8", out, n, MHD_RESPMEM_MUST_FREE);
}

static enum MHD_Result send_asset(struct MHD_Connection *conn, const char *text, const char *type)
{
    return send_body(conn, 200, type, (void *)text, strlen(text), MHD_RESPMEM_PERSISTENT);
}

static enum MHD_Result dispatch(serve_t *s, struct MHD_Connection *conn, const serve_route_t *rt)
{
    switch (rt->kind) {
    case SERVE_JOBS_PAGE:
        return send_asset(conn, serve_asset_jobs_html, "text/html; charset=utf-8");
    case SERVE_WORKERS_PAGE:
        return send_asset(conn, serve_asset_workers_html, "text/html; charset=utf-8");
    case SERVE_JOB_PAGE:
        return send_job_page(conn, rt->job);
    case SERVE_ASSET_CSS:
        return send_asset(conn, serve_asset_app_css, "text/css; charset=utf-8");
    case SERVE_ASSET_JS:
        return send_asset(conn, serve_asset_app_js, "text/javascript; charset=utf-8");
    case SERVE_METRICS:
        return handle_metrics(s, conn);
    case SERVE_API_PREVIEW:
    case SERVE_API_SAMPLES:
        return handle_preview(s, conn, rt);
    default:
        return handle_passthrough(s, conn, rt);
    }
}

static enum MHD_Result on_request(void *cls, struct MHD_Connection *conn, const char *url,
                                  const char *method, const char *version, const char *upload,
                                  size_t *upload_size, void **con_cls)
{
    (void)version;
    (void)upload;
    if (!*con_cls) {    /* the headers are in; the body (if any) comes next */
        *con_cls = cls; /* any pointer but NULL: "seen" */
        return MHD_YES;
    }
    if (*upload_size) { /* a cancel's form body says nothing we need */
        *upload_size = 0;
        return MHD_YES;
    }
    serve_route_t rt;
    char msg[512];
    int st = serve_parse_route(method, url, &rt, msg, sizeof msg);
    if (st == 405)
        return send_error_with(conn, 405, msg, "Allow", rt.allow);
    if (st != 200)
        return send_error(conn, st, msg);
    const char *origin = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, "Origin");
    const char *host = MHD_lookup_connection_value(conn, MHD_HEADER_KIND, "Host");
    if (rt.kind == SERVE_API_CANCEL && !serve_same_origin(origin, host)) {
        snprintf(msg, sizeof msg, "cross-site request refused: Origin %.200s is not http://%.200s",
                 origin, host ? host : "(no Host)");
        return send_error(conn, 403, msg);
    }
    return dispatch(cls, conn, &rt);
}

/* ---- the command ----------------------------------------------------------------- */

typedef struct serve_opts {
    const char *master, *listen, *key_file, *master_key_file;
} serve_opts_t;

static int usage_error(const char *fmt, const char *arg)
{
    fprintf(stderr, "vbrender serve: ");
    fprintf(stderr, fmt, arg);
    fprintf(stderr, "\n%s", usage_text);
    return 2;
}

static int parse_opts(int argc, char **argv, serve_opts_t *o)
{
    o->master = CLIENT_DEFAULT_MASTER;
    o->listen = SERVE_DEFAULT_LISTEN;
    o->key_file = getenv("VBRENDER_KEY");
    o->master_key_file = getenv("VBRENDER_MASTER_KEY");
    for (int i = 0; i < argc; i++) {
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        const char **slot = strcmp(argv[i], "--master") == 0       ? &o->master
                            : strcmp(argv[i], "--listen") == 0     ? &o->listen
                            : strcmp(argv[i], "--key") == 0        ? &o->key_file
                            : strcmp(argv[i], "--master-key") == 0 ? &o->master_key_file
                                                                   : NULL;
        if (!slot)
            return usage_error("unexpected argument '%s'", argv[i]);
        if (!v || !*v)
            return usage_error("%s needs a value", argv[i]);
        *slot = v;
        i++;
    }
    if (o->key_file && !*o->key_file)
        o->key_file = NULL;
    if (o->master_key_file && !*o->master_key_file)
        o->master_key_file = NULL;
    if (!o->key_file != !o->master_key_file)
        return usage_error("%s", "--key and --master-key go together (or VBRENDER_KEY and "
                                 "VBRENDER_MASTER_KEY)");
    return 0;
}

/* ADDR:PORT ([V6ADDR]:PORT for IPv6) as a socket address. */
static int resolve_listen(const char *spec, struct sockaddr_storage *sa, char *err, size_t errlen)
{
    char host[256];
    const char *colon = strrchr(spec, ':');
    size_t hl = colon ? (size_t)(colon - spec) : 0;
    if (!colon || hl == 0 || hl >= sizeof host || !colon[1]) {
        snprintf(err, errlen, "--listen needs ADDR:PORT, such as 127.0.0.1:8080 (got '%s')", spec);
        return -1;
    }
    memcpy(host, spec, hl);
    host[hl] = '\0';
    if (host[0] == '[' && host[hl - 1] == ']') {
        memmove(host, host + 1, hl - 2);
        host[hl - 2] = '\0';
    }
    struct addrinfo hints, *res = NULL;
    memset(&hints, 0, sizeof hints);
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_STREAM;
    hints.ai_flags = AI_NUMERICSERV | AI_PASSIVE;
    int rc = getaddrinfo(host, colon + 1, &hints, &res);
    if (rc != 0 || !res) {
        snprintf(err, errlen, "--listen %s: %s", spec, rc ? gai_strerror(rc) : "no address");
        return -1;
    }
    memset(sa, 0, sizeof *sa);
    memcpy(sa, res->ai_addr, res->ai_addrlen);
    freeaddrinfo(res);
    return 0;
}

static int open_master(serve_t *s, const serve_opts_t *o)
{
    char err[1024];
    keys_pair_t mine;
    char master_key[KEYS_Z85_LEN + 1];
    int keyed = o->key_file != NULL;
    if (keyed && (keys_load_secret(o->key_file, &mine, err, sizeof err) < 0 ||
                  keys_load_public(o->master_key_file, master_key, err, sizeof err) < 0)) {
        fprintf(stderr, "vbrender serve: %s\n", err);
        return -1;
    }
    control_keys_t keys = {mine.public_z85, mine.secret_z85, master_key};
    s->ctl = control_new_with_keys(s->zmq, o->master, SERVE_REQUEST_TIMEOUT_MS,
                                   keyed ? &keys : NULL, err, sizeof err);
    if (keyed)
        explicit_bzero(&mine, sizeof mine); /* control keeps its own copy */
    if (!s->ctl) {
        fprintf(stderr, "vbrender serve: %s\n", err);
        return -1;
    }
    return 0;
}

static int start_http(serve_t *s, const serve_opts_t *o)
{
    char err[512];
    struct sockaddr_storage sa;
    if (resolve_listen(o->listen, &sa, err, sizeof err) < 0) {
        fprintf(stderr, "vbrender serve: %s\n", err);
        return -1;
    }
    unsigned flags = MHD_USE_THREAD_PER_CONNECTION | MHD_USE_INTERNAL_POLLING_THREAD |
                     MHD_USE_ERROR_LOG | (sa.ss_family == AF_INET6 ? MHD_USE_IPv6 : 0);
    s->httpd = MHD_start_daemon(flags, 0, NULL, NULL, on_request, s, MHD_OPTION_SOCK_ADDR,
                                (struct sockaddr *)&sa, MHD_OPTION_CONNECTION_LIMIT, 64u,
                                MHD_OPTION_CONNECTION_TIMEOUT, 30u, MHD_OPTION_END);
    if (!s->httpd) {
        fprintf(stderr, "vbrender serve: cannot listen on %s: %s\n", o->listen,
                errno ? strerror(errno) : "libmicrohttpd refused");
        return -1;
    }
    const union MHD_DaemonInfo *info = MHD_get_daemon_info(s->httpd, MHD_DAEMON_INFO_BIND_PORT);
    char host[256];
    snprintf(host, sizeof host, "%.*s", (int)(strrchr(o->listen, ':') - o->listen), o->listen);
    printf("vbrender serve: http://%s:%u/ (master %s)\n", host, info ? info->port : 0, o->master);
    fflush(stdout);
    return 0;
}

int serve_main(int argc, char **argv)
{
    serve_opts_t o;
    int rc = parse_opts(argc, argv, &o);
    if (rc)
        return rc;
    /* blocked before any thread starts, so that every thread inherits the
     * mask and sigwait below is the one place the signals arrive */
    sigset_t stop;
    sigemptyset(&stop);
    sigaddset(&stop, SIGINT);
    sigaddset(&stop, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &stop, NULL);
    serve_t s;
    memset(&s, 0, sizeof s);
    pthread_mutex_init(&s.lock, NULL);
    s.zmq = zmq_ctx_new();
    rc = 1;
    if (s.zmq && open_master(&s, &o) == 0 && start_http(&s, &o) == 0) {
        int sig = 0;
        sigwait(&stop, &sig);
        rc = 0;
    }
    if (s.httpd)
        MHD_stop_daemon(s.httpd); /* joins its threads: nothing uses ctl after */
    control_destroy(&s.ctl);
    if (s.zmq)
        zmq_ctx_term(s.zmq);
    pthread_mutex_destroy(&s.lock);
    return rc;
}
