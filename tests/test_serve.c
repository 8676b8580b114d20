/* test_serve.c - Check suite for `vbrender serve` (client/serve.c).
 *
 * Unit tests of the handlers' pure parts: routes and methods, preview
 * sizes, the status for a master's errors, the /metrics text from canned
 * control replies (line for line), and the PNG encoders (decoded again
 * with libpng).
 *
 * The "live" case runs a real vbrender-master, a vbrender-worker and
 * `vbrender serve` on loopback and talks HTTP to it with a plain socket
 * client: the metrics agree with the master's own jobs and workers
 * replies, the preview changes while the job runs (SKIPPED when the master
 * has no preview command), bad requests get their statuses, cancel works,
 * and with the master killed the API says 503 "master unreachable" until a
 * new master on the same endpoint answers again.
 */
#include <arpa/inet.h>
#include <cJSON.h>
#include <check.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <netinet/in.h>
#include <png.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>
#include <zmq.h>

#include "control.h"
#include "image.h"
#include "serve.h"
#include "testutil.h"

/* ---- routes, sizes, errors ------------------------------------------------------- */

START_TEST(routes)
{
    static const struct {
        const char *method, *path;
        int status;
        serve_route_kind_t kind;
        unsigned long long job;
    } cases[] = {
        {"GET", "/", 200, SERVE_JOBS_PAGE, 0},
        {"HEAD", "/", 200, SERVE_JOBS_PAGE, 0},
        {"GET", "/workers", 200, SERVE_WORKERS_PAGE, 0},
        {"GET", "/job/7", 200, SERVE_JOB_PAGE, 7},
        {"GET", "/static/app.js", 200, SERVE_ASSET_JS, 0},
        {"GET", "/static/app.css", 200, SERVE_ASSET_CSS, 0},
        {"GET", "/api/jobs", 200, SERVE_API_JOBS, 0},
        {"GET", "/api/workers", 200, SERVE_API_WORKERS, 0},
        {"GET", "/api/job/12", 200, SERVE_API_JOB, 12},
        {"GET", "/api/job/12/preview.png", 200, SERVE_API_PREVIEW, 12},
        {"GET", "/api/job/9007199254740992/samples.png", 200, SERVE_API_SAMPLES,
         9007199254740992ULL},
        {"POST", "/api/job/3/cancel", 200, SERVE_API_CANCEL, 3},
        {"GET", "/metrics", 200, SERVE_METRICS, 0},
        {"GET", "/api/job/3/cancel", 405, SERVE_API_CANCEL, 3},
        {"POST", "/api/jobs", 405, SERVE_API_JOBS, 0},
        {"DELETE", "/job/1", 405, SERVE_JOB_PAGE, 1},
        {"GET", "/nope", 404, 0, 0},
        {"GET", "/job/0", 404, 0, 0},
        {"GET", "/job/01", 404, 0, 0},
        {"GET", "/job/-1", 404, 0, 0},
        {"GET", "/job/abc", 404, 0, 0},
        {"GET", "/job/7/", 404, 0, 0},
        {"GET", "/api/job/9007199254740993", 404, 0, 0},
        {"GET", "/api/job/99999999999999999999", 404, 0, 0},
        {"GET", "/api/job/5/other.png", 404, 0, 0},
        {"GET", "/api/job/", 404, 0, 0},
        {"GET", "", 404, 0, 0},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        serve_route_t rt;
        char msg[256];
        int st = serve_parse_route(cases[i].method, cases[i].path, &rt, msg, sizeof msg);
        ck_assert_msg(st == cases[i].status, "%s %s: %d, want %d (%s)", cases[i].method,
                      cases[i].path, st, cases[i].status, msg);
        if (st == 404) {
            ck_assert_ptr_nonnull(strstr(msg, "no such page"));
            continue;
        }
        ck_assert_int_eq(rt.kind, cases[i].kind);
        ck_assert(rt.job == cases[i].job);
        if (st == 405) {
            ck_assert_str_eq(rt.allow, cases[i].kind == SERVE_API_CANCEL ? "POST" : "GET, HEAD");
            ck_assert_ptr_nonnull(strstr(msg, cases[i].method));
        }
    }
}
END_TEST

START_TEST(sizes)
{
    int v = -1;
    char msg[256];
    ck_assert_int_eq(serve_parse_size(NULL, "w", &v, msg, sizeof msg), 0);
    ck_assert_int_eq(v, SERVE_PREVIEW_DEFAULT);
    ck_assert_int_eq(serve_parse_size("1", "w", &v, msg, sizeof msg), 0);
    ck_assert_int_eq(v, 1);
    ck_assert_int_eq(serve_parse_size("4096", "h", &v, msg, sizeof msg), 0);
    ck_assert_int_eq(v, 4096);
    static const char *const bad[] = {
        "0", "4097", "-1", "+5", "abc", "12x", "", " 12", "1e3", "3.5", "99999999999999999999"};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        v = 77;
        msg[0] = '\0';
        ck_assert_msg(serve_parse_size(bad[i], "h", &v, msg, sizeof msg) == -1, "'%s' accepted",
                      bad[i]);
        ck_assert_int_eq(v, 77);
        ck_assert_msg(strstr(msg, "h must be an integer from 1 to 4096") != NULL, "%s", msg);
    }
}
END_TEST

START_TEST(same_origin)
{
    ck_assert_int_eq(serve_same_origin(NULL, "127.0.0.1:8080"), 1);
    ck_assert_int_eq(serve_same_origin(NULL, NULL), 1);
    ck_assert_int_eq(serve_same_origin("http://127.0.0.1:8080", "127.0.0.1:8080"), 1);
    ck_assert_int_eq(serve_same_origin("http://evil.example", "127.0.0.1:8080"), 0);
    ck_assert_int_eq(serve_same_origin("http://127.0.0.1:8081", "127.0.0.1:8080"), 0);
    ck_assert_int_eq(serve_same_origin("https://127.0.0.1:8080", "127.0.0.1:8080"), 0);
    ck_assert_int_eq(serve_same_origin("null", "127.0.0.1:8080"), 0);
    ck_assert_int_eq(serve_same_origin("http://127.0.0.1:8080", NULL), 0);
}
END_TEST

START_TEST(error_statuses)
{
    ck_assert_int_eq(serve_error_status("status: no such job 4"), 404);
    ck_assert_int_eq(serve_error_status("cancel: job 4 belongs to another client (an admin key "
                                        "may act on it)"),
                     403);
    ck_assert_int_eq(serve_error_status("unknown command \"preview\" (submit, status)"), 501);
    ck_assert_int_eq(serve_error_status("preview: give \"job\": N, a job id"), 400);
}
END_TEST

/* The command line: bad options are usage errors (2), an address that
 * cannot be bound a failure (1), each with a message. */
START_TEST(command_line)
{
    static const struct {
        const char *args;
        int status;
        const char *says;
    } cases[] = {
        {"serve --bogus", 2, "unexpected argument '--bogus'"},
        {"serve --listen", 2, "--listen needs a value"},
        {"serve --key some.key", 2, "--key and --master-key go together"},
        {"serve --listen nonsense", 1, "--listen needs ADDR:PORT"},
        {"serve --listen 127.0.0.1:http", 1, "--listen 127.0.0.1:http"},
        {"serve --listen 192.0.2.1:8080", 1, "cannot listen on 192.0.2.1:8080"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        char cmd[1024], out[4096];
        snprintf(cmd, sizeof cmd, "timeout 10 '%s' %s", tu_bin(), cases[i].args);
        int rc = tu_run(cmd, out, sizeof out);
        ck_assert_msg(rc == cases[i].status && strstr(out, cases[i].says), "%s: %d: %s",
                      cases[i].args, rc, out);
    }
}
END_TEST

/* ---- /metrics -------------------------------------------------------------------- */

static const char canned_jobs[] =
    "{\"ok\":true,\"jobs\":["
    "{\"id\":1,\"state\":\"done\",\"rays_per_second\":5,\"samples_per_second\":1},"
    "{\"id\":2,\"state\":\"running\",\"rays_per_second\":1500000,\"samples_per_second\":250000.5},"
    "{\"id\":3,\"state\":\"running\",\"rays_per_second\":500000,\"samples_per_second\":0.25},"
    "{\"id\":4,\"state\":\"queued\"},{\"id\":5,\"state\":\"queued\"},"
    "{\"id\":6,\"state\":\"weird\\\"one\"}]}";

static const char canned_workers[] =
    "{\"ok\":true,\"workers\":["
    "{\"host\":\"a\",\"threads\":8,\"tasks_outstanding\":3},"
    "{\"host\":\"b\",\"threads\":4,\"tasks_outstanding\":1}],"
    "\"master\":{\"malformed_messages\":2,\"late_results\":7,\"rate_limited_requests\":0,"
    "\"tasks_issued\":1234,\"tasks_reissued\":5,\"jobs_queued\":3,\"jobs_running\":2,"
    "\"tasks_outstanding\":6,\"backups\":9,\"workers_banned\":1}}";

static const char expected_metrics[] =
    "# HELP vbrender_jobs Jobs this client may see on the master, by state.\n"
    "# TYPE vbrender_jobs gauge\n"
    "vbrender_jobs{state=\"queued\"} 2\n"
    "vbrender_jobs{state=\"running\"} 2\n"
    "vbrender_jobs{state=\"done\"} 1\n"
    "vbrender_jobs{state=\"failed\"} 0\n"
    "vbrender_jobs{state=\"cancelled\"} 0\n"
    "vbrender_jobs{state=\"weird\\\"one\"} 1\n"
    "# HELP vbrender_workers_connected Workers connected to the master.\n"
    "# TYPE vbrender_workers_connected gauge\n"
    "vbrender_workers_connected 2\n"
    "# HELP vbrender_worker_threads Render threads of the connected workers.\n"
    "# TYPE vbrender_worker_threads gauge\n"
    "vbrender_worker_threads 12\n"
    "# HELP vbrender_rays_per_second Rays per second of the running jobs, summed.\n"
    "# TYPE vbrender_rays_per_second gauge\n"
    "vbrender_rays_per_second 2000000\n"
    "# HELP vbrender_samples_per_second Samples per second of the running jobs, summed.\n"
    "# TYPE vbrender_samples_per_second gauge\n"
    "vbrender_samples_per_second 250000.75\n"
    "# HELP vbrender_tasks_issued_total Tasks the master sent to workers.\n"
    "# TYPE vbrender_tasks_issued_total counter\n"
    "vbrender_tasks_issued_total 1234\n"
    "# HELP vbrender_tasks_reissued_total Tasks sent again after a worker was lost or too slow.\n"
    "# TYPE vbrender_tasks_reissued_total counter\n"
    "vbrender_tasks_reissued_total 5\n"
    "# HELP vbrender_late_results_total Results dropped because they came after their task was "
    "reissued or ended.\n"
    "# TYPE vbrender_late_results_total counter\n"
    "vbrender_late_results_total 7\n"
    "# HELP vbrender_malformed_messages_total Malformed messages the master dropped.\n"
    "# TYPE vbrender_malformed_messages_total counter\n"
    "vbrender_malformed_messages_total 2\n"
    "# HELP vbrender_backup_tasks_total Backup copies of tasks out too long, sent to idle "
    "workers.\n"
    "# TYPE vbrender_backup_tasks_total counter\n"
    "vbrender_backup_tasks_total 9\n"
    "# HELP vbrender_workers_banned_total Workers dropped and refused for a while over refused "
    "results.\n"
    "# TYPE vbrender_workers_banned_total counter\n"
    "vbrender_workers_banned_total 1\n"
    "# HELP vbrender_rate_limited_requests_total Requests the master refused for their rate.\n"
    "# TYPE vbrender_rate_limited_requests_total counter\n"
    "vbrender_rate_limited_requests_total 0\n"
    "# HELP vbrender_queue_depth Jobs waiting to start.\n"
    "# TYPE vbrender_queue_depth gauge\n"
    "vbrender_queue_depth 3\n"
    "# HELP vbrender_outstanding_tasks Tasks sent to workers and not answered yet.\n"
    "# TYPE vbrender_outstanding_tasks gauge\n"
    "vbrender_outstanding_tasks 6\n";

/* Compares line by line, so that a failure names the first line that differs. */
static void assert_same_lines(const char *got, const char *want)
{
    int line = 1;
    while (*got || *want) {
        size_t g = strcspn(got, "\n"), w = strcspn(want, "\n");
        ck_assert_msg(g == w && strncmp(got, want, g) == 0, "line %d: got '%.*s', want '%.*s'",
                      line, (int)g, got, (int)w, want);
        got += g + (got[g] == '\n');
        want += w + (want[w] == '\n');
        line++;
    }
}

START_TEST(metrics_text)
{
    cJSON *jobs = cJSON_Parse(canned_jobs), *workers = cJSON_Parse(canned_workers);
    ck_assert_ptr_nonnull(jobs);
    ck_assert_ptr_nonnull(workers);
    char *text = serve_metrics_text(jobs, workers);
    ck_assert_ptr_nonnull(text);
    assert_same_lines(text, expected_metrics);
    /* every sample's family has its HELP and TYPE, and counters end in _total */
    for (const char *p = text; *p; p = strchr(p, '\n') + 1) {
        if (*p == '#')
            continue;
        char name[128], type_line[160];
        size_t n = strcspn(p, "{ ");
        snprintf(name, sizeof name, "%.*s", (int)n, p);
        snprintf(type_line, sizeof type_line, "# TYPE %s ", name);
        const char *t = strstr(text, type_line);
        ck_assert_msg(t != NULL, "%s has no TYPE line", name);
        int counter = strncmp(t + strlen(type_line), "counter", 7) == 0;
        ck_assert_msg(counter == (n > 6 && strcmp(name + n - 6, "_total") == 0), "%s", name);
    }
    free(text);
    cJSON_Delete(jobs);
    cJSON_Delete(workers);
}
END_TEST

/* An older master: no task counters, no queue figures (counted from the
 * lists instead), and a reply without lists reads as zero. */
START_TEST(metrics_missing_fields)
{
    cJSON *jobs = cJSON_Parse(canned_jobs);
    cJSON *workers = cJSON_Parse("{\"ok\":true,\"workers\":[{\"threads\":3,\"tasks_outstanding\":"
                                 "2}],\"master\":{\"malformed_messages\":1}}");
    char *text = serve_metrics_text(jobs, workers);
    ck_assert_ptr_nonnull(text);
    ck_assert_ptr_null(strstr(text, "tasks_issued"));
    ck_assert_ptr_null(strstr(text, "tasks_reissued"));
    ck_assert_ptr_null(strstr(text, "late_results"));
    ck_assert_ptr_nonnull(strstr(text, "\nvbrender_malformed_messages_total 1\n"));
    ck_assert_ptr_nonnull(strstr(text, "\nvbrender_queue_depth 2\n"));
    ck_assert_ptr_nonnull(strstr(text, "\nvbrender_outstanding_tasks 2\n"));
    ck_assert_ptr_nonnull(strstr(text, "\nvbrender_worker_threads 3\n"));
    free(text);
    cJSON *empty = cJSON_Parse("{\"ok\":true}");
    text = serve_metrics_text(empty, empty);
    ck_assert_ptr_nonnull(text);
    ck_assert_ptr_nonnull(strstr(text, "\nvbrender_jobs{state=\"running\"} 0\n"));
    ck_assert_ptr_nonnull(strstr(text, "\nvbrender_workers_connected 0\n"));
    free(text);
    cJSON_Delete(empty);
    cJSON_Delete(jobs);
    cJSON_Delete(workers);
}
END_TEST

/* ---- PNG ------------------------------------------------------------------------- */

/* Decodes a PNG as 8-bit RGB: malloc'd pixels, or NULL. */
static unsigned char *decode_png(const unsigned char *png, size_t size, int *w, int *h)
{
    png_image im;
    memset(&im, 0, sizeof im);
    im.version = PNG_IMAGE_VERSION;
    if (!png_image_begin_read_from_memory(&im, png, size))
        return NULL;
    im.format = PNG_FORMAT_RGB;
    unsigned char *px = malloc(PNG_IMAGE_SIZE(im));
    if (!px || !png_image_finish_read(&im, NULL, px, 0, NULL)) {
        free(px);
        png_image_free(&im);
        return NULL;
    }
    *w = (int)im.width;
    *h = (int)im.height;
    return px;
}

START_TEST(png_tonemap)
{
    /* 3 x 2: black, mid grey, white, over-white, a negative and a NaN
     * (both black), one channel each so the order shows */
    const float lin[18] = {0, 0,    0, 0.5f, 0.5f, 0.5f,  1,   1, 1,
                           4, 0.2f, 0, -1,   0,    0.18f, NAN, 1, 0.01f};
    size_t size = 0;
    char err[256];
    unsigned char *png = serve_png_rgb(lin, 3, 2, &size, err, sizeof err);
    ck_assert_msg(png != NULL, "%s", err);
    ck_assert_uint_gt(size, 8);
    ck_assert_int_eq(memcmp(png, "\x89PNG", 4), 0);
    int w = 0, h = 0;
    unsigned char *px = decode_png(png, size, &w, &h);
    ck_assert_ptr_nonnull(px);
    ck_assert_int_eq(w, 3);
    ck_assert_int_eq(h, 2);
    for (int i = 0; i < 18; i++)
        ck_assert_msg(px[i] == image_srgb_byte(lin[i]), "byte %d: %u, want %u", i, px[i],
                      image_srgb_byte(lin[i]));
    ck_assert_int_eq(px[0], 0);
    ck_assert_int_eq(px[3], 188); /* sRGB of 0.5 */
    ck_assert_int_eq(px[6], 255);
    ck_assert_int_eq(px[9], 255);
    ck_assert_int_eq(px[12], 0);
    ck_assert_int_eq(px[15], 0);
    free(px);
    free(png);
    ck_assert_ptr_null(serve_png_rgb(lin, 0, 2, &size, err, sizeof err));
    ck_assert_ptr_null(serve_png_rgb(lin, 4097, 1, &size, err, sizeof err));
}
END_TEST

START_TEST(png_heatmap)
{
    const float v[5] = {0, 16, 32, 64, 100};
    size_t size = 0;
    char err[256];
    unsigned char *png = serve_png_heat(v, 5, 1, 64, &size, err, sizeof err);
    ck_assert_msg(png != NULL, "%s", err);
    int w = 0, h = 0;
    unsigned char *px = decode_png(png, size, &w, &h);
    ck_assert_ptr_nonnull(px);
    ck_assert_int_eq(w, 5);
    ck_assert_int_eq(h, 1);
    static const unsigned char want[5][3] = {
        {0, 0, 0}, {0, 0, 255}, {255, 0, 0}, {255, 255, 255}, {255, 255, 255}};
    for (int i = 0; i < 5; i++)
        for (int k = 0; k < 3; k++)
            ck_assert_msg(px[3 * i + k] == want[i][k], "pixel %d channel %d: %u", i, k,
                          px[3 * i + k]);
    free(px);
    free(png);
}
END_TEST

/* ---- processes ------------------------------------------------------------------- */

#define MAX_PROCS 8

typedef struct proc {
    pid_t pid;
    char log[1024];
} proc_t;

static proc_t procs[MAX_PROCS];
static int nprocs;

/* Starts args (NULL-terminated) with its output in a log under VB_TMP; it
 * dies with this process (a failed test leaves nothing running). */
static proc_t *start(const char *name, const char *const *args)
{
    ck_assert_int_lt(nprocs, MAX_PROCS);
    proc_t *p = &procs[nprocs];
    char file[128];
    snprintf(file, sizeof file, "serve-%ld-%s.log", (long)getpid(), name);
    tu_tmp_path(p->log, sizeof p->log, file);
    int fd = open(p->log, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    ck_assert_msg(fd >= 0, "%s: %s", p->log, strerror(errno));
    pid_t parent = getpid(), pid = fork();
    ck_assert_int_ge(pid, 0);
    if (pid == 0) {
        prctl(PR_SET_PDEATHSIG, SIGKILL);
        if (getppid() != parent)
            _exit(127);
        dup2(fd, 1);
        dup2(fd, 2);
        execv(args[0], (char *const *)args);
        _exit(127);
    }
    close(fd);
    p->pid = pid;
    nprocs++;
    return p;
}

static void stop(proc_t *p)
{
    if (p->pid > 0) {
        kill(p->pid, SIGKILL);
        waitpid(p->pid, NULL, 0);
        p->pid = 0;
    }
}

static void teardown(void)
{
    for (int i = nprocs - 1; i >= 0; i--)
        stop(&procs[i]);
    nprocs = 0;
}

static const char *read_log(const proc_t *p, char *buf, size_t len)
{
    buf[0] = '\0';
    FILE *f = fopen(p->log, "rb");
    if (f) {
        size_t n = fread(buf, 1, len - 1, f);
        buf[n] = '\0';
        fclose(f);
    }
    return buf;
}

/* Waits until the log of p holds text (or p exits, or 10 s pass). */
static int wait_log(proc_t *p, const char *text, char *buf, size_t len)
{
    double end = tu_now_ms() + 10000;
    while (tu_now_ms() < end) {
        if (strstr(read_log(p, buf, len), text))
            return 1;
        if (waitpid(p->pid, NULL, WNOHANG) == p->pid) {
            p->pid = 0;
            read_log(p, buf, len);
            return 0;
        }
        tu_sleep_ms(20);
    }
    return 0;
}

static const char *bin_path(char *buf, size_t len, const char *name)
{
    const char *dir = getenv("VB_BINDIR");
    snprintf(buf, len, "%s/%s", dir && *dir ? dir : "bin", name);
    return buf;
}

/* A master on 127.0.0.1 (workers at port, control at port + 1), started
 * once it has bound both; 0 when the ports were taken. */
static proc_t *start_master(int port)
{
    char bin[1024], wep[64], cep[64], log[8192];
    snprintf(wep, sizeof wep, "tcp://127.0.0.1:%d", port);
    snprintf(cep, sizeof cep, "tcp://127.0.0.1:%d", port + 1);
    const char *args[] = {bin_path(bin, sizeof bin, "vbrender-master"),
                          "--workers",
                          wep,
                          "--control",
                          cep,
                          "--heartbeat-ms",
                          "200",
                          "--state",
                          "none",
                          NULL};
    proc_t *m = start("master", args);
    if (wait_log(m, "listening", log, sizeof log))
        return m;
    ck_assert_msg(strstr(log, "cannot bind") != NULL, "the master did not start:\n%s", log);
    return NULL;
}

/* ---- HTTP ------------------------------------------------------------------------ */

typedef struct http_reply {
    int status;
    char headers[4096];
    unsigned char *body; /* malloc'd, NUL-terminated */
    size_t size;
} http_reply_t;

/* One HTTP/1.0 request to 127.0.0.1:port (the server closes after it),
 * with more header lines (each ending in \r\n) in headers. */
static int http_with(int port, const char *method, const char *path, const char *headers,
                     http_reply_t *r)
{
    memset(r, 0, sizeof *r);
    int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    struct sockaddr_in sa = {.sin_family = AF_INET, .sin_port = htons((uint16_t)port)};
    sa.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    struct timeval tv = {20, 0};
    setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    if (fd < 0 || connect(fd, (struct sockaddr *)&sa, sizeof sa) < 0) {
        if (fd >= 0)
            close(fd);
        return -1;
    }
    char req[1024];
    int n =
        snprintf(req, sizeof req, "%s %s HTTP/1.0\r\nHost: 127.0.0.1:%d\r\n%s%s\r\n", method, path,
                 port, strcmp(method, "POST") == 0 ? "Content-Length: 0\r\n" : "", headers);
    ck_assert_int_eq(write(fd, req, (size_t)n), n);
    size_t cap = 1 << 16, len = 0;
    unsigned char *buf = malloc(cap);
    ssize_t got;
    while (buf && (got = read(fd, buf + len, cap - len - 1)) > 0)
        if ((len += (size_t)got) + 1 == cap)
            buf = realloc(buf, cap *= 2);
    close(fd);
    ck_assert_ptr_nonnull(buf);
    buf[len] = '\0';
    unsigned char *end = (unsigned char *)strstr((char *)buf, "\r\n\r\n");
    if (sscanf((char *)buf, "HTTP/1.%*d %d", &r->status) != 1 || !end) {
        free(buf);
        return -1;
    }
    snprintf(r->headers, sizeof r->headers, "%.*s", (int)(end - buf), (char *)buf);
    r->size = len - (size_t)(end + 4 - buf);
    r->body = malloc(r->size + 1);
    memcpy(r->body, end + 4, r->size);
    r->body[r->size] = '\0';
    free(buf);
    return 0;
}

static int http(int port, const char *method, const char *path, http_reply_t *r)
{
    return http_with(port, method, path, "", r);
}

static http_reply_t http_ok(int port, const char *method, const char *path, int status)
{
    http_reply_t r;
    ck_assert_msg(http(port, method, path, &r) == 0, "%s %s: no HTTP reply", method, path);
    ck_assert_msg(r.status == status, "%s %s: %d, want %d: %s", method, path, r.status, status,
                  (char *)r.body);
    return r;
}

/* The value of a sample line ("name 12" or "name{labels} 12") of a
 * metrics text; NAN when it is not there. */
static double metric_value(const char *text, const char *name)
{
    size_t n = strlen(name);
    for (const char *p = text; p && *p; p = strchr(p, '\n'), p = p ? p + 1 : NULL)
        if (strncmp(p, name, n) == 0 && p[n] == ' ')
            return strtod(p + n + 1, NULL);
    return NAN;
}

/* ---- the live case --------------------------------------------------------------- */

typedef struct cluster {
    proc_t *master, *worker, *serve;
    int port;      /* the master's worker port; control is port + 1 */
    int http_port; /* vbrender serve's */
    char cep[64];
    void *zmq;
    control_t *ctl;
} cluster_t;

static cJSON *ask(cluster_t *c, const char *cmd)
{
    char err[512];
    cJSON *req = cJSON_CreateObject();
    cJSON_AddStringToObject(req, "cmd", cmd);
    cJSON *r = control_request(c->ctl, req, NULL, NULL, 0, err, sizeof err);
    cJSON_Delete(req);
    ck_assert_msg(r != NULL, "%s: %s", cmd, err);
    return r;
}

static void start_cluster(cluster_t *c)
{
    memset(c, 0, sizeof *c);
    char log[8192], bin[1024];
    for (int i = 0; i < 4 && !c->master; i++) {
        c->port = 24000 + (int)(getpid() % 1000) * 8 + 2 * i;
        c->master = start_master(c->port);
    }
    ck_assert_msg(c->master != NULL, "no free ports for the master");
    char wep[64];
    snprintf(wep, sizeof wep, "tcp://127.0.0.1:%d", c->port);
    snprintf(c->cep, sizeof c->cep, "tcp://127.0.0.1:%d", c->port + 1);
    const char *wargs[] = {bin_path(bin, sizeof bin, "vbrender-worker"),
                           "--master",
                           wep,
                           "--threads",
                           "2",
                           "--name",
                           "w1",
                           NULL};
    c->worker = start("worker", wargs);
    const char *sargs[] = {tu_bin(), "serve", "--master", c->cep, "--listen", "127.0.0.1:0", NULL};
    c->serve = start("serve", sargs);
    ck_assert_msg(wait_log(c->serve, "http://127.0.0.1:", log, sizeof log), "serve: %s", log);
    c->http_port = atoi(strstr(log, "http://127.0.0.1:") + 17);
    ck_assert_int_gt(c->http_port, 0);
    char err[512];
    c->zmq = zmq_ctx_new();
    c->ctl = control_new(c->zmq, c->cep, 5000, err, sizeof err);
    ck_assert_msg(c->ctl != NULL, "%s", err);
}

static void stop_cluster(cluster_t *c)
{
    control_destroy(&c->ctl);
    teardown();
    zmq_ctx_term(c->zmq);
}

/* The worker runs only while the test lets the job advance (advance): it
 * is frozen (SIGSTOP) whenever the test looks, so the job cannot end, or
 * stop changing, behind the test's back, however fast the host. */
static void freeze(cluster_t *c)
{
    ck_assert_msg(tu_freeze(c->worker->pid) == 0, "the worker did not stop");
}

/* The job's merged samples (0 while there is no job). */
static double job_samples(cluster_t *c)
{
    cJSON *j = ask(c, "jobs");
    const cJSON *job = cJSON_GetArrayItem(cJSON_GetObjectItem(j, "jobs"), 0);
    double samples = job ? cJSON_GetNumberValue(cJSON_GetObjectItem(job, "samples")) : 0;
    cJSON_Delete(j);
    return samples;
}

/* Thaws the worker for short slices until the master has merged more
 * samples than before, and freezes it again. */
static void advance(cluster_t *c)
{
    double had = job_samples(c), end = tu_now_ms() + 30000;
    do {
        ck_assert_msg(tu_now_ms() < end, "no samples merged in 30 s");
        kill(c->worker->pid, SIGCONT);
        tu_sleep_ms(2);
        freeze(c);
    } while (job_samples(c) <= had);
}

/* Submits the Cornell box, a job of 1024 layers, with the worker frozen;
 * the master lists the worker. */
static unsigned long long submit_long_job(cluster_t *c)
{
    char scene[1024], err[1024];
    double end = tu_now_ms() + 15000;
    for (;;) {
        cJSON *w = ask(c, "workers");
        int workers = cJSON_GetArraySize(cJSON_GetObjectItem(w, "workers"));
        cJSON_Delete(w);
        if (workers == 1)
            break;
        ck_assert_msg(tu_now_ms() < end, "the worker did not join in 15 s");
        tu_sleep_ms(20);
    }
    freeze(c);
    tu_root_path(scene, sizeof scene, "scenes/cornell-box.json");
    cJSON *settings = cJSON_CreateObject();
    cJSON_AddNumberToObject(settings, "spp", 4096);
    cJSON_AddNumberToObject(settings, "granularity", 4);
    unsigned long long id = control_submit(c->ctl, scene, settings, NULL, NULL, err, sizeof err);
    cJSON_Delete(settings);
    ck_assert_msg(id > 0, "submit: %s", err);
    return id;
}

/* Lets the job run until it has samples; it is running then (and stays
 * so: the worker is frozen). */
static void wait_running(cluster_t *c)
{
    advance(c);
    cJSON *j = ask(c, "jobs");
    const cJSON *job = cJSON_GetArrayItem(cJSON_GetObjectItem(j, "jobs"), 0);
    ck_assert_msg(
        job && strcmp(cJSON_GetStringValue(cJSON_GetObjectItem(job, "state")), "running") == 0,
        "the job does not run");
    cJSON_Delete(j);
}

/* The metrics agree with the master's own replies. */
static void check_metrics(cluster_t *c)
{
    http_reply_t r = http_ok(c->http_port, "GET", "/metrics", 200);
    ck_assert_ptr_nonnull(strstr(r.headers, "text/plain; version=0.0.4"));
    const char *t = (const char *)r.body;
    cJSON *w = ask(c, "workers");
    const cJSON *list = cJSON_GetObjectItem(w, "workers");
    double threads = 0;
    const cJSON *it;
    cJSON_ArrayForEach(it, list) threads +=
        cJSON_GetNumberValue(cJSON_GetObjectItem(it, "threads"));
    ck_assert_double_eq(metric_value(t, "vbrender_workers_connected"), cJSON_GetArraySize(list));
    ck_assert_double_eq(metric_value(t, "vbrender_worker_threads"), threads);
    ck_assert_double_eq(metric_value(t, "vbrender_worker_threads"), 2);
    ck_assert_double_eq(metric_value(t, "vbrender_jobs{state=\"running\"}"), 1);
    ck_assert_double_eq(metric_value(t, "vbrender_jobs{state=\"done\"}"), 0);
    ck_assert_double_eq(metric_value(t, "vbrender_queue_depth"), 0);
    ck_assert_double_eq(metric_value(t, "vbrender_malformed_messages_total"),
                        cJSON_GetNumberValue(cJSON_GetObjectItem(cJSON_GetObjectItem(w, "master"),
                                                                 "malformed_messages")));
    /* counters of a master that has them: grown since the scrape, if at all */
    const cJSON *issued = cJSON_GetObjectItem(cJSON_GetObjectItem(w, "master"), "tasks_issued");
    if (cJSON_IsNumber(issued)) {
        double v = metric_value(t, "vbrender_tasks_issued_total");
        ck_assert_msg(v > 0 && v <= issued->valuedouble, "tasks issued %g, master %g", v,
                      issued->valuedouble);
    }
    ck_assert_msg(metric_value(t, "vbrender_rays_per_second") > 0, "%s", t);
    ck_assert_msg(metric_value(t, "vbrender_samples_per_second") > 0, "%s", t);
    cJSON_Delete(w);
    free(r.body);
}

/* Two previews with samples merged between them differ; SKIPPED by a
 * master without the preview command. Returns 0 when skipped. */
static int check_preview(cluster_t *c, unsigned long long job)
{
    char path[128];
    snprintf(path, sizeof path, "/api/job/%llu/preview.png?w=64&h=48", job);
    http_reply_t a;
    ck_assert_int_eq(http(c->http_port, "GET", path, &a), 0);
    if (a.status == 501) {
        printf("SKIPPED: preview: the master has no preview command yet (%s)\n", (char *)a.body);
        fflush(stdout);
        free(a.body);
        return 0;
    }
    ck_assert_msg(a.status == 200, "%s: %d %s", path, a.status, (char *)a.body);
    ck_assert_ptr_nonnull(strstr(a.headers, "image/png"));
    int w, h, w2, h2;
    unsigned char *pa = decode_png(a.body, a.size, &w, &h);
    ck_assert_ptr_nonnull(pa);
    ck_assert_msg(w <= 64 && h <= 48 && w >= 1 && h >= 1, "preview %dx%d", w, h);
    int changed = 0;
    for (int tries = 0; tries < 1000 && !changed; tries++) {
        advance(c);
        http_reply_t b = http_ok(c->http_port, "GET", path, 200);
        unsigned char *pb = decode_png(b.body, b.size, &w2, &h2);
        ck_assert_ptr_nonnull(pb);
        ck_assert(w2 == w && h2 == h);
        changed = memcmp(pa, pb, (size_t)w * h * 3) != 0;
        free(pb);
        free(b.body);
    }
    ck_assert_msg(changed, "the preview did not change over 1000 merges");
    free(pa);
    free(a.body);
    snprintf(path, sizeof path, "/api/job/%llu/samples.png", job);
    http_reply_t s = http_ok(c->http_port, "GET", path, 200);
    ck_assert_msg(strstr(s.headers, "X-Heatmap-Max: ") != NULL, "%s", s.headers);
    free(s.body);
    return 1;
}

static void check_bad_requests(cluster_t *c)
{
    static const struct {
        const char *method, *path;
        int status;
        const char *says;
    } cases[] = {
        {"GET", "/api/job/999", 404, "no such job 999"},
        {"POST", "/api/job/999/cancel", 404, "no such job 999"},
        {"GET", "/api/job/1/preview.png?w=0", 400, "w must be an integer"},
        {"GET", "/api/job/1/samples.png?h=5000", 400, "h must be an integer"},
        {"GET", "/no/such/page", 404, "no such page"},
        {"POST", "/api/jobs", 405, "takes GET, HEAD"},
        {"GET", "/api/job/1/cancel", 405, "takes POST"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        http_reply_t r = http_ok(c->http_port, cases[i].method, cases[i].path, cases[i].status);
        ck_assert_msg(strstr((char *)r.body, cases[i].says), "%s: %s", cases[i].path,
                      (char *)r.body);
        free(r.body);
    }
    /* the pages are there, the job's with its id */
    http_reply_t r = http_ok(c->http_port, "GET", "/job/1", 200);
    ck_assert_ptr_nonnull(strstr((char *)r.body, "action=\"/api/job/1/cancel\""));
    free(r.body);
    r = http_ok(c->http_port, "GET", "/", 200);
    ck_assert_ptr_nonnull(strstr(r.headers, "text/html"));
    free(r.body);
}

/* Requests from several connections at once (threads of serve sharing
 * its one control connection): every one answered. */
typedef struct burst {
    int port, failures;
    pthread_t thread;
} burst_t;

static void *burst_thread(void *arg)
{
    burst_t *b = arg;
    static const char *const paths[] = {"/api/jobs", "/metrics", "/api/workers", "/api/job/1", "/"};
    for (int i = 0; i < 10; i++) {
        http_reply_t r;
        if (http(b->port, "GET", paths[i % 5], &r) < 0 || r.status != 200)
            b->failures++;
        free(r.body);
    }
    return NULL;
}

static void check_concurrent(cluster_t *c)
{
    burst_t b[6];
    for (int i = 0; i < 6; i++) {
        b[i].port = c->http_port;
        b[i].failures = 0;
        ck_assert_int_eq(pthread_create(&b[i].thread, NULL, burst_thread, &b[i]), 0);
    }
    int failures = 0;
    for (int i = 0; i < 6; i++) {
        pthread_join(b[i].thread, NULL);
        failures += b[i].failures;
    }
    ck_assert_msg(failures == 0, "%d of 60 concurrent requests failed", failures);
}

/* The master killed: 503 "master unreachable"; a new one: answers again. */
static void check_master_away(cluster_t *c)
{
    stop(c->master);
    http_reply_t r = http_ok(c->http_port, "GET", "/api/jobs", 503);
    ck_assert_msg(strstr((char *)r.body, "\"master unreachable: "), "%s", (char *)r.body);
    free(r.body);
    r = http_ok(c->http_port, "GET", "/metrics", 503);
    ck_assert_ptr_nonnull(strstr((char *)r.body, "master unreachable"));
    free(r.body);
    c->master = start_master(c->port);
    ck_assert_msg(c->master != NULL, "the master could not bind its ports again");
    double end = tu_now_ms() + 15000;
    for (;;) {
        ck_assert_int_eq(http(c->http_port, "GET", "/api/jobs", &r), 0);
        int st = r.status;
        free(r.body);
        if (st == 200)
            break;
        ck_assert_msg(st == 503, "status %d while the master comes back", st);
        ck_assert_msg(tu_now_ms() < end, "serve did not recover in 15 s");
        tu_sleep_ms(200);
    }
}

START_TEST(live)
{
    cluster_t c;
    start_cluster(&c);
    unsigned long long job = submit_long_job(&c);
    ck_assert(job == 1);
    wait_running(&c);
    check_metrics(&c);
    check_preview(&c, job);
    check_bad_requests(&c);
    check_concurrent(&c);
    http_reply_t r = http_ok(c.http_port, "GET", "/api/job/1", 200);
    ck_assert_ptr_nonnull(strstr((char *)r.body, "\"state\":\"running\""));
    free(r.body);
    /* a form on another site's page may not cancel (CSRF) */
    ck_assert_int_eq(
        http_with(c.http_port, "POST", "/api/job/1/cancel", "Origin: http://evil.example\r\n", &r),
        0);
    ck_assert_msg(r.status == 403 && strstr((char *)r.body, "cross-site request refused"), "%d %s",
                  r.status, (char *)r.body);
    free(r.body);
    r = http_ok(c.http_port, "POST", "/api/job/1/cancel", 200);
    ck_assert_msg(strstr((char *)r.body, "\"state\":\"cancelled\""), "%s", (char *)r.body);
    free(r.body);
    r = http_ok(c.http_port, "GET", "/metrics", 200);
    ck_assert_double_eq(metric_value((char *)r.body, "vbrender_jobs{state=\"cancelled\"}"), 1);
    free(r.body);
    check_master_away(&c);
    /* SIGTERM ends serve cleanly (under the sanitizers: without a leak) */
    kill(c.serve->pid, SIGTERM);
    int st = -1;
    for (int i = 0; i < 100 && waitpid(c.serve->pid, &st, WNOHANG) == 0; i++)
        tu_sleep_ms(50);
    ck_assert_msg(WIFEXITED(st) && WEXITSTATUS(st) == 0, "serve: status 0x%x after SIGTERM", st);
    c.serve->pid = 0;
    stop_cluster(&c);
}
END_TEST

int main(void)
{
    signal(SIGPIPE, SIG_IGN);
    Suite *s = suite_create("serve");
    TCase *unit = tcase_create("unit");
    tcase_add_test(unit, routes);
    tcase_add_test(unit, sizes);
    tcase_add_test(unit, same_origin);
    tcase_add_test(unit, error_statuses);
    tcase_add_test(unit, command_line);
    tcase_add_test(unit, metrics_text);
    tcase_add_test(unit, metrics_missing_fields);
    tcase_add_test(unit, png_tonemap);
    tcase_add_test(unit, png_heatmap);
    suite_add_tcase(s, unit);
    TCase *live_tc = tcase_create("live");
    tcase_add_checked_fixture(live_tc, NULL, teardown);
    tcase_set_timeout(live_tc, 120);
    tcase_add_test(live_tc, live);
    suite_add_tcase(s, live_tc);
    SRunner *sr = srunner_create(s);
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed ? 1 : 0;
}
