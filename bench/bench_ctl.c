/* bench_ctl.c - a small control-socket client for bench/run-distributed.sh:
 * prints the master's JSON replies whole (the `vbrender workers` table
 * rounds its figures, and the benchmark has no Python ZeroMQ binding).
 *
 *   bench_ctl ENDPOINT workers               the "workers" reply
 *   bench_ctl ENDPOINT status JOB            the job's status object
 *   bench_ctl ENDPOINT wait-workers N [S]    until N workers have joined (S s, default 20)
 *   bench_ctl ENDPOINT wait JOB [S]          polls status every 100 ms (as `vbrender
 *                                            wait` does) until the job ends, then prints
 *                                            its status; S s at most (default 600)
 *
 * Exit status: 0 ok (for wait: the job is done), 1 error, timeout, or the job
 * failed or was cancelled, 2 bad usage.
 */
#include <cJSON.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <zmq.h>

static const char usage_text[] =
    "usage: bench_ctl ENDPOINT workers | status JOB | wait-workers N [SECONDS] | "
    "wait JOB [SECONDS]\n";

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static int parse_num(const char *s, double lo, double hi, double *out)
{
    if (!s || !*s)
        return -1;
    errno = 0;
    char *end;
    double v = strtod(s, &end);
    if (errno || *end || !(v >= lo && v <= hi))
        return -1;
    *out = v;
    return 0;
}

/* One REQ round trip. The REQ socket is made anew each time, so a lost
 * reply cannot wedge it. NULL with a message on stderr. */
static cJSON *request(void *ctx, const char *endpoint, const cJSON *body)
{
    void *s = zmq_socket(ctx, ZMQ_REQ);
    int zero = 0, timeout = 10000;
    zmq_setsockopt(s, ZMQ_LINGER, &zero, sizeof zero);
    zmq_setsockopt(s, ZMQ_RCVTIMEO, &timeout, sizeof timeout);
    cJSON *reply = NULL;
    char *text = cJSON_PrintUnformatted(body);
    if (!text || zmq_connect(s, endpoint) < 0 || zmq_send(s, text, strlen(text), 0) < 0) {
        fprintf(stderr, "bench_ctl: cannot send to %s: %s\n", endpoint, zmq_strerror(errno));
        goto out;
    }
    zmq_msg_t m;
    zmq_msg_init(&m);
    if (zmq_msg_recv(&m, s, 0) < 0) {
        fprintf(stderr, "bench_ctl: no reply from %s: %s\n", endpoint, zmq_strerror(errno));
        zmq_msg_close(&m);
        goto out;
    }
    reply = cJSON_ParseWithLength(zmq_msg_data(&m), zmq_msg_size(&m));
    zmq_msg_close(&m);
    if (!reply)
        fprintf(stderr, "bench_ctl: the reply is not JSON\n");
    else if (!cJSON_IsTrue(cJSON_GetObjectItemCaseSensitive(reply, "ok"))) {
        const cJSON *e = cJSON_GetObjectItemCaseSensitive(reply, "error");
        fprintf(stderr, "bench_ctl: master: %s\n", cJSON_IsString(e) ? e->valuestring : "error");
        cJSON_Delete(reply);
        reply = NULL;
    }
out:
    cJSON_free(text);
    zmq_close(s);
    return reply;
}

static void print_json(const cJSON *o)
{
    char *text = cJSON_PrintUnformatted(o);
    printf("%s\n", text ? text : "null");
    cJSON_free(text);
}

static void sleep_ms(long ms)
{
    struct timespec ts = {ms / 1000, (ms % 1000) * 1000000L};
    nanosleep(&ts, NULL);
}

int main(int argc, char **argv)
{
    if (argc < 3) {
        fputs(usage_text, stderr);
        return 2;
    }
    const char *ep = argv[1], *cmd = argv[2];
    double arg = 0, limit = 0;
    int rc = 2;
    if (strcmp(cmd, "workers") == 0 && argc == 3)
        rc = 0;
    else if (strcmp(cmd, "status") == 0 && argc == 4)
        rc = parse_num(argv[3], 1, 9007199254740992.0, &arg) < 0 ? 2 : 0;
    else if ((strcmp(cmd, "wait") == 0 || strcmp(cmd, "wait-workers") == 0) &&
             (argc == 4 || argc == 5)) {
        limit = strcmp(cmd, "wait") == 0 ? 600 : 20;
        rc = parse_num(argv[3], 0, 9007199254740992.0, &arg) < 0 ||
                     (argc == 5 && parse_num(argv[4], 0.1, 86400, &limit) < 0)
                 ? 2
                 : 0;
    }
    if (rc) {
        fputs(usage_text, stderr);
        return 2;
    }
    void *ctx = zmq_ctx_new();
    cJSON *q = cJSON_CreateObject();
    int is_workers = strcmp(cmd, "workers") == 0 || strcmp(cmd, "wait-workers") == 0;
    cJSON_AddStringToObject(q, "cmd", is_workers ? "workers" : "status");
    if (!is_workers)
        cJSON_AddNumberToObject(q, "job", arg);
    int poll = strcmp(cmd, "wait") == 0 || strcmp(cmd, "wait-workers") == 0;
    double t0 = now_s();
    rc = 1;
    for (;;) {
        cJSON *r = request(ctx, ep, q);
        if (!r)
            break;
        if (!poll) {
            print_json(is_workers ? r : cJSON_GetObjectItemCaseSensitive(r, "job"));
            cJSON_Delete(r);
            rc = 0;
            break;
        }
        if (is_workers) {
            int n = cJSON_GetArraySize(cJSON_GetObjectItemCaseSensitive(r, "workers"));
            if (n >= (int)arg) {
                print_json(r);
                cJSON_Delete(r);
                rc = 0;
                break;
            }
        } else {
            const cJSON *job = cJSON_GetObjectItemCaseSensitive(r, "job");
            const cJSON *st = cJSON_GetObjectItemCaseSensitive(job, "state");
            const char *s = cJSON_IsString(st) ? st->valuestring : "";
            if (strcmp(s, "done") == 0 || strcmp(s, "failed") == 0 || strcmp(s, "cancelled") == 0) {
                print_json(job);
                rc = strcmp(s, "done") == 0 ? 0 : 1;
                cJSON_Delete(r);
                break;
            }
        }
        cJSON_Delete(r);
        if (now_s() - t0 > limit) {
            fprintf(stderr, "bench_ctl: %s: still waiting after %.0f s\n", cmd, limit);
            break;
        }
        sleep_ms(is_workers ? 20 : 100);
    }
    cJSON_Delete(q);
    zmq_ctx_term(ctx);
    return rc;
}
