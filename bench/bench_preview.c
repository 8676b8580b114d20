/* bench_preview.c - a dashboard's preview polling, for bench/run-preview.sh:
 * asks the master for a preview of a job at a fixed rate until the job
 * ends, reading every frame as a viewer would, and prints what it cost.
 *
 *   bench_preview ENDPOINT JOB INTERVAL_S [MAX_WIDTH MAX_HEIGHT]
 *
 * Prints one JSON object: previews, interval_s, width, height, bytes (of
 * the frames), latency_ms_mean and latency_ms_max (request to last frame),
 * cpu_seconds (this process's). Exit status: 0 once the job has ended, 1
 * on an error reply or no reply within 10 s, 2 bad usage.
 */
#include <cJSON.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>
#include <zmq.h>

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static int arg_num(const char *s, double lo, double hi, double *out)
{
    char *end;
    errno = 0;
    double v = strtod(s, &end);
    if (errno || end == s || *end || !(v >= lo && v <= hi))
        return -1;
    *out = v;
    return 0;
}

static int int_of(const cJSON *o, const char *k)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(o, k);
    return cJSON_IsNumber(v) ? (int)v->valuedouble : -1;
}

/* What the polling saw so far. */
typedef struct tally {
    long previews;
    double bytes, latency_sum, latency_max;
    int width, height;
} tally_t;

/* One preview round trip on s: 1 if the job has ended, 0 if it runs on,
 * -1 on an error (said on stderr). */
static int one_preview(void *s, const char *text, tally_t *t)
{
    double t0 = now_s();
    if (zmq_send(s, text, strlen(text), 0) < 0) {
        fprintf(stderr, "bench_preview: cannot send: %s\n", zmq_strerror(errno));
        return -1;
    }
    zmq_msg_t m;
    zmq_msg_init(&m);
    if (zmq_msg_recv(&m, s, 0) < 0) {
        fprintf(stderr, "bench_preview: no reply: %s\n", zmq_strerror(errno));
        zmq_msg_close(&m);
        return -1;
    }
    cJSON *r = cJSON_ParseWithLength(zmq_msg_data(&m), zmq_msg_size(&m));
    int more = zmq_msg_more(&m);
    while (more) { /* the RGB and samples frames, read as a viewer would */
        zmq_msg_close(&m);
        zmq_msg_init(&m);
        if (zmq_msg_recv(&m, s, 0) < 0)
            break;
        t->bytes += (double)zmq_msg_size(&m);
        more = zmq_msg_more(&m);
    }
    zmq_msg_close(&m);
    double dt = now_s() - t0;
    const cJSON *job = cJSON_GetObjectItemCaseSensitive(r, "job");
    const cJSON *st = cJSON_GetObjectItemCaseSensitive(job, "state");
    const char *state = cJSON_IsString(st) ? st->valuestring : "";
    int rc = strcmp(state, "done") == 0 || strcmp(state, "failed") == 0 ||
             strcmp(state, "cancelled") == 0;
    if (!cJSON_IsTrue(cJSON_GetObjectItemCaseSensitive(r, "ok"))) {
        const cJSON *e = cJSON_GetObjectItemCaseSensitive(r, "error");
        fprintf(stderr, "bench_preview: %s\n", cJSON_IsString(e) ? e->valuestring : "bad reply");
        rc = -1;
    } else {
        t->previews++;
        t->latency_sum += dt;
        t->latency_max = dt > t->latency_max ? dt : t->latency_max;
        t->width = int_of(r, "width");
        t->height = int_of(r, "height");
    }
    cJSON_Delete(r);
    return rc;
}

int main(int argc, char **argv)
{
    double job, interval, max_w = 256, max_h = 256;
    if ((argc != 4 && argc != 6) || arg_num(argv[2], 1, 9007199254740992.0, &job) < 0 ||
        arg_num(argv[3], 0.001, 3600, &interval) < 0 ||
        (argc == 6 &&
         (arg_num(argv[4], 1, 4096, &max_w) < 0 || arg_num(argv[5], 1, 4096, &max_h) < 0))) {
        fputs("usage: bench_preview ENDPOINT JOB INTERVAL_S [MAX_WIDTH MAX_HEIGHT]\n", stderr);
        return 2;
    }
    char text[256];
    snprintf(text, sizeof text,
             "{\"cmd\":\"preview\",\"job\":%.0f,\"max_width\":%.0f,\"max_height\":%.0f}", job,
             max_w, max_h);
    void *ctx = zmq_ctx_new();
    void *s = zmq_socket(ctx, ZMQ_REQ);
    int zero = 0, timeout = 10000;
    zmq_setsockopt(s, ZMQ_LINGER, &zero, sizeof zero);
    zmq_setsockopt(s, ZMQ_RCVTIMEO, &timeout, sizeof timeout);
    tally_t t = {0};
    int rc = zmq_connect(s, argv[1]) == 0 ? 0 : -1;
    /* a fixed rate: each preview is due interval_s after the last was due */
    for (double due = now_s(); rc == 0; due += interval) {
        double wait = due - now_s();
        if (wait > 0) {
            struct timespec ts = {(time_t)wait, (long)((wait - (double)(time_t)wait) * 1e9)};
            nanosleep(&ts, NULL);
        }
        rc = one_preview(s, text, &t);
    }
    zmq_close(s);
    zmq_ctx_term(ctx);
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    double cpu = (double)ru.ru_utime.tv_sec + 1e-6 * (double)ru.ru_utime.tv_usec +
                 (double)ru.ru_stime.tv_sec + 1e-6 * (double)ru.ru_stime.tv_usec;
    printf("{\"previews\":%ld,\"interval_s\":%g,\"width\":%d,\"height\":%d,\"bytes\":%.0f,"
           "\"latency_ms_mean\":%.3f,\"latency_ms_max\":%.3f,\"cpu_seconds\":%.3f}\n",
           t.previews, interval, t.width, t.height, t.bytes,
           t.previews ? 1e3 * t.latency_sum / (double)t.previews : 0.0, 1e3 * t.latency_max, cpu);
    return rc == 1 ? 0 : 1;
}
