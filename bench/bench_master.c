/* bench_master.c - master capacity ("Distributed system", section 6): how
 * many pixel-layer results per second one master merges.
 *
 * Runs a real master_t (master_new / master_run, in a thread of this
 * process) and K synthetic workers (threads, one DEALER socket each) that
 * speak the wire protocol through proto_encode / proto_decode exactly as a
 * worker does: HELLO with this build's id, CREDIT, and for every TASK an
 * immediate RESULT whose records match the task's pixels (samples = the
 * record's sample_count, constant sums, a pvar that varies with pixel and
 * layer so the adaptive skip rule drops about half the pixels of its
 * layers). Nothing is traced. A job is submitted over the control socket
 * (REQ, JSON) on a synthetic one-quad scene of --size x --size pixels, and
 * status is polled until it is done.
 *
 * --verify-share P runs the master with that share of tasks verified by
 * replication (master/verify.c): a chosen task goes to two synthetic
 * workers, whose answers agree since they are a pure function of the task.
 * Copies must go to workers of different identity (address without keys),
 * so over tcp each synthetic worker connects from its own loopback address
 * (127.0.0.10 + k); over inproc they all share one and nothing can be
 * verified (the chosen tasks are merged unverified).
 *
 * Reported (JSON): pixel-layer results merged (status samples / G), job
 * seconds, results/s, and the CPU time of the master's thread (its
 * pthread CPU clock, read from outside: master.c is not instrumented), of
 * the synthetic workers' threads and of the whole process (the rest is
 * ZeroMQ's I/O thread for tcp, and this thread's status polls). Results
 * per master-thread CPU second is the rate one master core sustains when
 * it is the bottleneck; the master's CPU utilization says whether it was.
 *
 * --curve (tcp only) runs the master with CURVE keys (auth.h) and the
 * synthetic workers and the control socket as CURVE clients with admitted
 * keys: what encryption and the per-message key check cost. ZeroMQ
 * encrypts and decrypts in its I/O threads; --worker-context own gives the
 * synthetic workers a context (an I/O thread) of their own, as remote
 * workers would have, so the master's I/O thread does only the master's
 * half of the crypto.
 *
 * usage: bench_master [--workers K] [--transport inproc|tcp] [--port P]
 *                     [--size N] [--spp S] [--granularity G]
 *                     [--adaptive none|thesis] [--uniform-layers U]
 *                     [--credit C] [--max-seconds T] [--verify-share P]
 *                     [--json OUT.json]
 *                     [--curve] [--worker-context shared|own] [--io-threads N]
 *
 * --io-threads N gives the master's context N I/O threads (ZeroMQ binds each
 * connection to one of them): with CURVE, the crypto of several workers'
 * connections is then spread out.
 */
#include <cJSON.h>
#include <dirent.h>
#include <errno.h>
#include <inttypes.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>
#include <zmq.h>

#include "frames.h"
#include "jsonget.h"
#include "keys.h"
#include "master.h"
#include "proto.h"
#include "vberr.h"

#define MAX_SYNTH 64

static const char usage_text[] =
    "usage: bench_master [options]\n"
    "  --workers K            synthetic workers, threads of this process (default 1, at most 64)\n"
    "  --transport T          inproc or tcp (loopback; default inproc)\n"
    "  --port P               tcp: workers on P, control on P+1 (default 17570)\n"
    "  --size N               image N x N (default 1024)\n"
    "  --spp S                samples per pixel (default 1024)\n"
    "  --granularity G        samples per pixel per layer (default 32)\n"
    "  --adaptive MODE        none or thesis (default none)\n"
    "  --uniform-layers U     layers before the skip rule applies (default: the master's, half)\n"
    "  --credit C             tasks each synthetic worker asks for at once (default 8)\n"
    "  --max-seconds T        cancel the job after T s and report what was merged (default 60)\n"
    "  --verify-share P       share of tasks the master verifies on two workers (default 0; tcp)\n"
    "  --json FILE            write the result as JSON (default: stdout only)\n"
    "  --curve                tcp: CURVE keys on the master, the workers and the control socket\n"
    "  --worker-context C     shared (default: one ZeroMQ context for all) or own (the\n"
    "                         synthetic workers get their own context and I/O thread)\n"
    "  --io-threads N         ZeroMQ I/O threads of the master's context (default 1)\n";

typedef struct args {
    uint64_t workers, port, size, spp, granularity, credit, uniform_layers, max_seconds, io_threads;
    int have_uniform, tcp, curve, own_context;
    double verify_share;
    const char *adaptive;
    const char *json;
} args_t;

/* CURVE keys of a --curve run (Z85). */
typedef struct bench_keys {
    keys_pair_t master, worker, client;
    char dir[64]; /* the allow-lists: dir/workers, dir/clients */
} bench_keys_t;

typedef struct synth {
    void *ctx;
    char endpoint[96];
    const bench_keys_t *keys; /* NULL: no CURVE */
    uint32_t credit;
    const atomic_int *stop;
    pthread_t thread;
    int started;
    clockid_t clock;
    volatile int ready; /* clock is valid */
    /* counters, written by the thread only */
    uint64_t tasks, records;
    uint64_t bytes_in, bytes_out;
    int failed;
    char error[VB_ERR_LEN];
} synth_t;

typedef struct master_thread {
    master_t *m;
    atomic_int stop;
    pthread_t thread;
} master_thread_t;

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static double clock_s(clockid_t c)
{
    struct timespec ts;
    if (clock_gettime(c, &ts) < 0)
        return 0.0;
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
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

/* ZeroMQ's I/O threads, found by name: "ZMQbg/IO/N" in the master's
 * context, "1/ZMQbg/IO/N" in the workers' own (ZMQ_THREAD_NAME_PREFIX 1).
 * Their CPU time is where ZeroMQ encrypts and decrypts. */
#define MAX_IO_THREADS 16
typedef struct io_threads {
    pid_t tid[MAX_IO_THREADS];
    int workers[MAX_IO_THREADS]; /* of the workers' own context */
    double cpu0[MAX_IO_THREADS];
    int n;
} io_threads_t;

/* The CPU clock of thread tid of this process, encoded as glibc's
 * pthread_getcpuclockid encodes one (Linux: ~tid << 3 | per-thread | sched). */
static clockid_t tid_clock(pid_t tid)
{
    return (clockid_t)((~(unsigned)tid << 3) | 6u);
}

static void io_threads_start(io_threads_t *io)
{
    io->n = 0;
    DIR *d = opendir("/proc/self/task");
    struct dirent *e;
    while (d && (e = readdir(d)) != NULL && io->n < MAX_IO_THREADS) {
        char path[300], name[32] = "";
        snprintf(path, sizeof path, "/proc/self/task/%s/comm", e->d_name);
        FILE *f = e->d_name[0] != '.' ? fopen(path, "r") : NULL;
        if (!f)
            continue;
        if (!fgets(name, sizeof name, f))
            name[0] = '\0';
        fclose(f);
        int mine = strncmp(name, "ZMQbg/IO/", 9) == 0,
            theirs = strncmp(name, "1/ZMQbg/IO/", 11) == 0;
        if (!mine && !theirs)
            continue;
        io->tid[io->n] = (pid_t)atoi(e->d_name);
        io->workers[io->n] = theirs;
        io->cpu0[io->n] = clock_s(tid_clock(io->tid[io->n]));
        io->n++;
    }
    if (d)
        closedir(d);
}

/* CPU seconds since io_threads_start of the master's (which = 0) or the
 * workers' (which = 1) I/O threads: all of them, and the busiest one. */
static double io_threads_cpu(const io_threads_t *io, int which, double *busiest)
{
    double sum = 0, max = 0;
    for (int i = 0; i < io->n; i++)
        if (io->workers[i] == which) {
            double c = clock_s(tid_clock(io->tid[i])) - io->cpu0[i];
            sum += c;
            max = c > max ? c : max;
        }
    if (busiest)
        *busiest = max;
    return sum;
}

/* A hash of (pixel, layer) to [0, 1): the synthetic eq. 4.1 statistic. */
static double synth_pvar(uint32_t pixel, uint32_t layer)
{
    uint64_t z = ((uint64_t)layer << 32 | pixel) + 0x9e3779b97f4a7c15ull;
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    z ^= z >> 31;
    return (double)(z >> 11) * (1.0 / 9007199254740992.0);
}

/* ---- synthetic worker ------------------------------------------------------ */

static int synth_send(synth_t *s, void *sock, const proto_msg_t *msg, uint8_t *payload, size_t cap)
{
    uint8_t header[PROTO_HEADER_SIZE];
    long n = proto_encode(msg, header, payload, cap, s->error, sizeof s->error);
    if (n < 0)
        return -1;
    if (zmq_send(sock, header, PROTO_HEADER_SIZE, ZMQ_SNDMORE) < 0 ||
        zmq_send(sock, payload, (size_t)n, 0) < 0) {
        snprintf(s->error, sizeof s->error, "send: %s", zmq_strerror(errno));
        return -1;
    }
    s->bytes_out += PROTO_HEADER_SIZE + (uint64_t)n;
    return 0;
}

/* A synthetic worker's socket, its message and record buffers, and where its
 * conversation with the master stands. */
typedef struct synth_io {
    void *sock;
    tracer_task_t *task_rec;
    tracer_result_t *res_rec;
    uint8_t *payload;
    size_t result_cap;
    proto_msg_t *in, *out;
    proto_records_t *recs;
    double last_sent; /* for the heartbeats */
    int welcomed;
} synth_io_t;

/* The outgoing message, cleared, of the given type. */
static proto_msg_t *synth_out(synth_io_t *io, uint16_t type)
{
    memset(io->out, 0, sizeof *io->out);
    io->out->h.type = type;
    return io->out;
}

/* Buffers, socket (with the worker's CURVE keys if any) and connection. */
static int synth_open(synth_t *s, synth_io_t *io)
{
    size_t task_cap = 64 + (size_t)PROTO_TASK_RECORD_SIZE * PROTO_MAX_TASK_PIXELS;
    io->result_cap = 64 + (size_t)PROTO_RESULT_RECORD_SIZE * PROTO_MAX_TASK_PIXELS;
    io->task_rec = malloc(PROTO_MAX_TASK_PIXELS * sizeof *io->task_rec);
    io->res_rec = malloc(PROTO_MAX_TASK_PIXELS * sizeof *io->res_rec);
    io->payload = malloc(io->result_cap > task_cap ? io->result_cap : task_cap);
    io->in = malloc(sizeof *io->in);
    io->out = malloc(sizeof *io->out);
    io->recs = calloc(1, sizeof *io->recs);
    io->sock = zmq_socket(s->ctx, ZMQ_DEALER);
    if (!io->task_rec || !io->res_rec || !io->payload || !io->in || !io->out || !io->recs ||
        !io->sock) {
        snprintf(s->error, sizeof s->error, "out of memory or no socket");
        s->failed = 1;
        return -1;
    }
    int zero = 0;
    zmq_setsockopt(io->sock, ZMQ_LINGER, &zero, sizeof zero);
    if (s->keys) {
        zmq_setsockopt(io->sock, ZMQ_CURVE_SERVERKEY, s->keys->master.public_z85, KEYS_Z85_LEN);
        zmq_setsockopt(io->sock, ZMQ_CURVE_PUBLICKEY, s->keys->worker.public_z85, KEYS_Z85_LEN);
        zmq_setsockopt(io->sock, ZMQ_CURVE_SECRETKEY, s->keys->worker.secret_z85, KEYS_Z85_LEN);
    }
    if (zmq_connect(io->sock, s->endpoint) < 0) {
        snprintf(s->error, sizeof s->error, "connect %s: %s", s->endpoint, zmq_strerror(errno));
        s->failed = 1;
        return -1;
    }
    return 0;
}

/* HELLO with this build's id, as a worker of this host would send it. */
static int synth_hello(synth_t *s, synth_io_t *io)
{
    proto_msg_t *out = synth_out(io, PROTO_HELLO);
    out->u.hello.threads = 1;
    __builtin_cpu_init();
    proto_build_id(__builtin_cpu_supports("avx2") ? "avx2" : "sse4.2", out->u.hello.build);
    if (synth_send(s, io->sock, out, io->payload, io->result_cap) < 0) {
        s->failed = 1;
        return -1;
    }
    io->last_sent = now_s();
    return 0;
}

/* The RESULT of a task, at once: records that match its pixels. */
static int synth_answer_task(synth_t *s, synth_io_t *io)
{
    const proto_msg_t *in = io->in;
    const proto_task_t *t = &in->u.task;
    for (uint32_t i = 0; i < t->count; i++) {
        const tracer_task_t *r = &t->records[i];
        double n = (double)r->sample_count;
        io->res_rec[i] = (tracer_result_t){.pixel = r->pixel,
                                           .samples = r->sample_count,
                                           .nonfinite = 0,
                                           .rays = 6 * r->sample_count,
                                           .sum = {0.5 * n, 0.4 * n, 0.3 * n},
                                           .lum_m2 = 0.01 * n,
                                           .pvar = synth_pvar(r->pixel, t->layer)};
    }
    proto_msg_t *out = synth_out(io, PROTO_RESULT);
    out->h.job = in->h.job;
    out->h.task = in->h.task;
    out->h.attempt = in->h.attempt;
    out->u.result.rays = (uint64_t)t->count * (t->count ? t->records[0].sample_count : 0) * 6;
    out->u.result.busy_us = 1;
    out->u.result.count = t->count;
    out->u.result.records = io->res_rec;
    if (synth_send(s, io->sock, out, io->payload, io->result_cap) < 0) {
        s->failed = 1;
        return -1;
    }
    s->tasks++;
    s->records += t->count;
    return 0;
}

/* One decoded message from the master: WELCOME -> CREDIT, TASK -> RESULT,
 * REFUSE or BYE -> stop (an error unless the benchmark is over). -1: read
 * no further messages now. */
static int synth_on_message(synth_t *s, synth_io_t *io)
{
    const proto_msg_t *in = io->in;
    if (in->h.type == PROTO_WELCOME) {
        io->welcomed = 1;
        synth_out(io, PROTO_CREDIT)->u.credit = s->credit;
        if (synth_send(s, io->sock, io->out, io->payload, io->result_cap) < 0)
            s->failed = 1;
    } else if (in->h.type == PROTO_TASK) {
        return synth_answer_task(s, io);
    } else if (in->h.type == PROTO_REFUSE || in->h.type == PROTO_BYE) {
        if (!atomic_load(s->stop)) {
            snprintf(s->error, sizeof s->error, "master said %s: %.200s",
                     proto_type_name(in->h.type), in->u.text.text);
            s->failed = 1;
        }
        return -1;
    }
    return 0;
}

/* Reads and answers every message waiting on the socket. */
static void synth_drain(synth_t *s, synth_io_t *io)
{
    for (;;) {
        proto_frames_t fr;
        proto_recv_result_t got = proto_recv(io->sock, &fr, 2, SIZE_MAX, ZMQ_DONTWAIT);
        if (got == PROTO_RECV_NONE)
            break;
        if (got != PROTO_RECV_OK || fr.count != 2) {
            snprintf(s->error, sizeof s->error, "master sent a message that is not two frames");
            s->failed = 1;
            proto_frames_close(&fr);
            break;
        }
        s->bytes_in += fr.bytes;
        io->recs->tasks = io->task_rec;
        io->recs->task_capacity = PROTO_MAX_TASK_PIXELS;
        int drc = proto_frames_decode(&fr, 0, io->in, io->recs, s->error, sizeof s->error);
        proto_frames_close(&fr);
        if (drc < 0) {
            s->failed = 1;
            break;
        }
        if (synth_on_message(s, io) < 0)
            break;
        io->last_sent = now_s();
    }
}

/* Answers the master until the benchmark stops it or something fails,
 * with a heartbeat when idle, then says BYE. */
static void synth_loop(synth_t *s, synth_io_t *io)
{
    while (!atomic_load(s->stop) && !s->failed) {
        zmq_pollitem_t it = {io->sock, 0, ZMQ_POLLIN, 0};
        int rc = zmq_poll(&it, 1, 100);
        if (rc < 0) {
            if (errno == EINTR)
                continue;
            break;
        }
        if (rc > 0) {
            synth_drain(s, io);
            continue;
        }
        if (io->welcomed && now_s() - io->last_sent > 0.3) {
            if (synth_send(s, io->sock, synth_out(io, PROTO_HEARTBEAT), io->payload,
                           io->result_cap) < 0)
                s->failed = 1;
            io->last_sent = now_s();
        }
    }
    if (!s->failed) {
        synth_out(io, PROTO_BYE)->u.text.text = "benchmark over";
        synth_send(s, io->sock, io->out, io->payload, io->result_cap);
    }
}

static void synth_free(synth_io_t *io)
{
    if (io->sock)
        zmq_close(io->sock);
    free(io->task_rec);
    free(io->res_rec);
    free(io->payload);
    free(io->in);
    free(io->out);
    free(io->recs);
}

static void *synth_main(void *arg)
{
    synth_t *s = arg;
    prctl(PR_SET_NAME, "vb-synth", 0, 0, 0);
    pthread_getcpuclockid(pthread_self(), &s->clock);
    s->ready = 1;
    synth_io_t io = {0};
    if (synth_open(s, &io) == 0 && synth_hello(s, &io) == 0)
        synth_loop(s, &io);
    synth_free(&io);
    return NULL;
}

/* ---- master and control ------------------------------------------------------ */

static void *master_main(void *arg)
{
    master_thread_t *mt = arg;
    prctl(PR_SET_NAME, "vb-master", 0, 0, 0); /* for perf report --comm */
    master_run(mt->m, &mt->stop);
    return NULL;
}

/* One REQ round trip: [json][extra frame] -> parsed reply. */
static cJSON *request(void *req_sock, const cJSON *body, const char *frame, size_t frame_len,
                      char *err, size_t errlen)
{
    char *text = cJSON_PrintUnformatted(body);
    if (!text) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    int rc = zmq_send(req_sock, text, strlen(text), frame ? ZMQ_SNDMORE : 0);
    cJSON_free(text);
    if (rc >= 0 && frame)
        rc = zmq_send(req_sock, frame, frame_len, 0);
    if (rc < 0) {
        snprintf(err, errlen, "control send: %s", zmq_strerror(errno));
        return NULL;
    }
    zmq_msg_t m;
    zmq_msg_init(&m);
    if (zmq_msg_recv(&m, req_sock, 0) < 0) {
        snprintf(err, errlen, "control: no reply (%s)", zmq_strerror(errno));
        zmq_msg_close(&m);
        return NULL;
    }
    cJSON *reply = cJSON_ParseWithLength(zmq_msg_data(&m), zmq_msg_size(&m));
    int more = zmq_msg_more(&m);
    zmq_msg_close(&m);
    while (more) { /* fetch frames: not used here */
        zmq_msg_init(&m);
        if (zmq_msg_recv(&m, req_sock, 0) < 0)
            more = 0;
        else
            more = zmq_msg_more(&m);
        zmq_msg_close(&m);
    }
    if (!reply)
        snprintf(err, errlen, "control: reply is not JSON");
    else if (!cJSON_IsTrue(cJSON_GetObjectItemCaseSensitive(reply, "ok"))) {
        const cJSON *e = cJSON_GetObjectItemCaseSensitive(reply, "error");
        snprintf(err, errlen, "master: %s", cJSON_IsString(e) ? e->valuestring : "error");
        cJSON_Delete(reply);
        reply = NULL;
    }
    return reply;
}

static int parse_args(int argc, char **argv, args_t *a)
{
    *a = (args_t){.workers = 1,
                  .io_threads = 1,
                  .port = 17570,
                  .size = 1024,
                  .spp = 1024,
                  .granularity = 32,
                  .credit = 8,
                  .max_seconds = 60,
                  .adaptive = "none"};
    for (int i = 1; i < argc; i++) {
        const char *o = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        int bad = 0;
        if (strcmp(o, "-h") == 0 || strcmp(o, "--help") == 0) {
            fputs(usage_text, stdout);
            exit(0);
        } else if (strcmp(o, "--workers") == 0)
            bad = parse_u64(v, 1, MAX_SYNTH, &a->workers);
        else if (strcmp(o, "--port") == 0)
            bad = parse_u64(v, 1024, 65534, &a->port);
        else if (strcmp(o, "--size") == 0)
            bad = parse_u64(v, 1, 8192, &a->size);
        else if (strcmp(o, "--spp") == 0)
            bad = parse_u64(v, 1, 1u << 20, &a->spp);
        else if (strcmp(o, "--granularity") == 0)
            bad = parse_u64(v, 1, TRACER_MAX_TASK_SAMPLES, &a->granularity);
        else if (strcmp(o, "--credit") == 0)
            bad = parse_u64(v, 1, PROTO_MAX_CREDIT, &a->credit);
        else if (strcmp(o, "--io-threads") == 0)
            bad = parse_u64(v, 1, 16, &a->io_threads);
        else if (strcmp(o, "--max-seconds") == 0)
            bad = parse_u64(v, 1, 3600, &a->max_seconds);
        else if (strcmp(o, "--uniform-layers") == 0) {
            bad = parse_u64(v, 0, 1000000, &a->uniform_layers);
            a->have_uniform = 1;
        } else if (strcmp(o, "--transport") == 0) {
            bad = !v || (strcmp(v, "inproc") != 0 && strcmp(v, "tcp") != 0);
            a->tcp = v && strcmp(v, "tcp") == 0;
        } else if (strcmp(o, "--adaptive") == 0) {
            bad = !v || (strcmp(v, "none") != 0 && strcmp(v, "thesis") != 0);
            a->adaptive = v;
        } else if (strcmp(o, "--verify-share") == 0) {
            char *end = NULL;
            a->verify_share = v ? strtod(v, &end) : -1;
            bad = !v || *end || !(a->verify_share >= 0 && a->verify_share <= 1);
        } else if (strcmp(o, "--json") == 0) {
            bad = !v;
            a->json = v;
        } else if (strcmp(o, "--curve") == 0) {
            a->curve = 1;
            continue; /* takes no value */
        } else if (strcmp(o, "--worker-context") == 0) {
            bad = !v || (strcmp(v, "shared") != 0 && strcmp(v, "own") != 0);
            a->own_context = v && strcmp(v, "own") == 0;
        } else {
            fprintf(stderr, "bench_master: unknown option '%s'\n%s", o, usage_text);
            return 2;
        }
        if (bad) {
            fprintf(stderr, "bench_master: bad value for %s: '%s'\n%s", o, v ? v : "", usage_text);
            return 2;
        }
        i++;
    }
    return 0;
}

/* Writes one .pub file: dir/sub/name.pub. */
static int write_pub(const char *dir, const char *sub, const char *name, const char *z85)
{
    char path[256];
    snprintf(path, sizeof path, "%s/%s", dir, sub);
    if (mkdir(path, 0700) < 0 && errno != EEXIST)
        return -1;
    snprintf(path, sizeof path, "%s/%s/%s.pub", dir, sub, name);
    FILE *f = fopen(path, "w");
    if (!f)
        return -1;
    fprintf(f, "%s\n", z85);
    return fclose(f);
}

/* Fresh key pairs, and the allow-lists in a scratch directory. */
static int make_keys(bench_keys_t *k, char *err, size_t errlen)
{
    if (keys_generate(&k->master, err, errlen) < 0 || keys_generate(&k->worker, err, errlen) < 0 ||
        keys_generate(&k->client, err, errlen) < 0)
        return -1;
    snprintf(k->dir, sizeof k->dir, "/tmp/bench-master-keys-XXXXXX");
    if (!mkdtemp(k->dir) || write_pub(k->dir, "workers", "synth", k->worker.public_z85) < 0 ||
        write_pub(k->dir, "clients", "bench", k->client.public_z85) < 0) {
        snprintf(err, errlen, "cannot write the allow-lists under %s: %s", k->dir, strerror(errno));
        return -1;
    }
    return 0;
}

static void remove_keys(const bench_keys_t *k)
{
    char path[256];
    snprintf(path, sizeof path, "%s/workers/synth.pub", k->dir);
    unlink(path);
    snprintf(path, sizeof path, "%s/clients/bench.pub", k->dir);
    unlink(path);
    snprintf(path, sizeof path, "%s/workers", k->dir);
    rmdir(path);
    snprintf(path, sizeof path, "%s/clients", k->dir);
    rmdir(path);
    rmdir(k->dir);
}

/* One benchmark run: the master (in a thread), the synthetic workers and
 * the control socket, with the contexts, endpoints and keys they share.
 * Lives on main's stack: the synthetic workers point into it. */
typedef struct bench {
    const args_t *a;
    char wep[64], cep[64]; /* worker and control endpoints */
    bench_keys_t keys;
    char workers_dir[128], clients_dir[128];
    void *ctx, *wctx; /* the master's, the synthetic workers' (may be the same) */
    master_thread_t mt;
    int master_started;
    clockid_t master_clock;
    synth_t synth[MAX_SYNTH];
    atomic_int synth_stop;
    void *req; /* the control socket */
    char err[VB_ERR_LEN];
} bench_t;

/* Clock readings at the job's start. */
typedef struct bench_clocks {
    io_threads_t io;
    double wall, master_cpu, proc_cpu, synth_cpu[MAX_SYNTH];
} bench_clocks_t;

/* What the run measured, at the job's end. */
typedef struct bench_figures {
    double seconds, samples, results; /* from the master's status */
    double wall, master_cpu, proc_cpu, synth_cpu;
    double master_io_cpu, master_io_busiest, worker_io_cpu;
    uint64_t tasks, records, bytes_in, bytes_out;
} bench_figures_t;

/* Combinations parse_args cannot judge option by option; 0 or the exit code. */
static int check_args(const args_t *a)
{
    if (a->curve && !a->tcp) {
        fprintf(stderr,
                "bench_master: --curve needs --transport tcp (ZeroMQ does not secure inproc)\n");
        return 2;
    }
    if (a->own_context && !a->tcp) {
        fprintf(
            stderr,
            "bench_master: --worker-context own needs --transport tcp (inproc is per context)\n");
        return 2;
    }
    return 0;
}

static void endpoints(bench_t *b)
{
    if (b->a->tcp) {
        snprintf(b->wep, sizeof b->wep, "tcp://127.0.0.1:%" PRIu64, b->a->port);
        snprintf(b->cep, sizeof b->cep, "tcp://127.0.0.1:%" PRIu64, b->a->port + 1);
    } else {
        snprintf(b->wep, sizeof b->wep, "inproc://bench-workers");
        snprintf(b->cep, sizeof b->cep, "inproc://bench-control");
    }
}

/* Endpoints, CURVE keys (--curve) and the ZeroMQ contexts. */
static int bench_init(bench_t *b, const args_t *a)
{
    memset(b, 0, sizeof *b);
    b->a = a;
    endpoints(b);
    if (a->curve && make_keys(&b->keys, b->err, sizeof b->err) < 0) {
        fprintf(stderr, "bench_master: %s\n", b->err);
        return -1;
    }
    snprintf(b->workers_dir, sizeof b->workers_dir, "%s/workers", b->keys.dir);
    snprintf(b->clients_dir, sizeof b->clients_dir, "%s/clients", b->keys.dir);
    b->ctx = zmq_ctx_new();
    zmq_ctx_set(b->ctx, ZMQ_IO_THREADS, (int)a->io_threads); /* before its first socket */
    b->wctx = a->own_context ? zmq_ctx_new() : b->ctx;
    if (b->wctx != b->ctx)
        zmq_ctx_set(b->wctx, ZMQ_THREAD_NAME_PREFIX, 1); /* tells its I/O threads apart */
    return 0;
}

/* master_new, and master_run in a thread of its own. */
static int start_master(bench_t *b)
{
    master_config_t mc;
    memset(&mc, 0, sizeof mc);
    mc.zmq_ctx = b->ctx;
    mc.worker_endpoint = b->wep;
    mc.control_endpoint = b->cep;
    mc.log = getenv("VB_LOG") ? stderr : NULL;
    mc.verify_share = b->a->verify_share;
    if (b->a->curve) {
        mc.curve_secret_key = b->keys.master.secret_z85;
        mc.allow_workers_dir = b->workers_dir;
        mc.allow_clients_dir = b->clients_dir;
    }
    b->mt.m = master_new(&mc, b->err, sizeof b->err);
    if (!b->mt.m) {
        fprintf(stderr, "bench_master: %s\n", b->err);
        return -1;
    }
    pthread_create(&b->mt.thread, NULL, master_main, &b->mt);
    b->master_started = 1;
    pthread_getcpuclockid(b->mt.thread, &b->master_clock);
    return 0;
}

static void start_synths(bench_t *b)
{
    const args_t *a = b->a;
    for (uint64_t i = 0; i < a->workers; i++) {
        synth_t *s = &b->synth[i];
        *s = (synth_t){.ctx = b->wctx,
                       .keys = a->curve ? &b->keys : NULL,
                       .credit = (uint32_t)a->credit,
                       .stop = &b->synth_stop};
        if (a->tcp) /* an address each: verified copies go to workers of another identity */
            snprintf(s->endpoint, sizeof s->endpoint, "tcp://127.0.0.%" PRIu64 ":0;%s", 10 + i,
                     b->wep + strlen("tcp://"));
        else
            snprintf(s->endpoint, sizeof s->endpoint, "%s", b->wep);
        pthread_create(&s->thread, NULL, synth_main, s);
        s->started = 1;
        /* staggered, as real workers join: ZeroMQ gives an accepted
         * connection to its least loaded I/O thread, and connections
         * accepted at once all see the same loads */
        struct timespec gap = {0, 20 * 1000 * 1000};
        nanosleep(&gap, NULL);
    }
}

/* The REQ socket to the master's control endpoint (a CURVE client with
 * --curve). */
static int connect_control(bench_t *b)
{
    b->req = zmq_socket(b->ctx, ZMQ_REQ);
    int zero = 0, timeout = 30000;
    zmq_setsockopt(b->req, ZMQ_LINGER, &zero, sizeof zero);
    zmq_setsockopt(b->req, ZMQ_RCVTIMEO, &timeout, sizeof timeout);
    if (b->a->curve) {
        const bench_keys_t *k = &b->keys;
        zmq_setsockopt(b->req, ZMQ_CURVE_SERVERKEY, k->master.public_z85, KEYS_Z85_LEN);
        zmq_setsockopt(b->req, ZMQ_CURVE_PUBLICKEY, k->client.public_z85, KEYS_Z85_LEN);
        zmq_setsockopt(b->req, ZMQ_CURVE_SECRETKEY, k->client.secret_z85, KEYS_Z85_LEN);
    }
    if (zmq_connect(b->req, b->cep) < 0) {
        fprintf(stderr, "bench_master: connect %s: %s\n", b->cep, zmq_strerror(errno));
        return -1;
    }
    return 0;
}

/* Until the master lists every synthetic worker (10 s at most) and every
 * worker's CPU clock is known. */
static int wait_for_workers(bench_t *b)
{
    cJSON *q = cJSON_CreateObject();
    cJSON_AddStringToObject(q, "cmd", "workers");
    for (double t0 = now_s();;) {
        cJSON *r = request(b->req, q, NULL, 0, b->err, sizeof b->err);
        if (!r) {
            fprintf(stderr, "bench_master: %s\n", b->err);
            cJSON_Delete(q);
            return -1;
        }
        int n = cJSON_GetArraySize(cJSON_GetObjectItemCaseSensitive(r, "workers"));
        cJSON_Delete(r);
        if (n == (int)b->a->workers)
            break;
        if (now_s() - t0 > 10) {
            fprintf(stderr, "bench_master: only %d of %" PRIu64 " synthetic workers joined\n", n,
                    b->a->workers);
            cJSON_Delete(q);
            return -1;
        }
        struct timespec ts = {0, 10 * 1000 * 1000};
        nanosleep(&ts, NULL);
    }
    cJSON_Delete(q);
    for (uint64_t i = 0; i < b->a->workers; i++)
        while (!b->synth[i].ready) {
            struct timespec ts = {0, 1000 * 1000};
            nanosleep(&ts, NULL);
        }
    return 0;
}

/* Submits the job (one emitting quad: nothing is traced anyway), with the
 * clocks read just before; its id in *job. */
static int submit_job(bench_t *b, bench_clocks_t *c, double *job)
{
    const args_t *a = b->a;
    char scene[1024];
    int scene_len = snprintf(
        scene, sizeof scene,
        "{\"camera\": {\"position\": [0, 2, -3], \"look_at\": [0, 0, 0], \"up\": [0, 1, 0], "
        "\"fov\": 40, \"width\": %" PRIu64 ", \"height\": %" PRIu64 "},"
        " \"render\": {\"spp\": 1, \"seed\": 1, \"integrator\": \"path\"},"
        " \"materials\": {\"light\": {\"type\": \"emitter\", \"radiance\": [1, 1, 1]}},"
        " \"shapes\": [{\"type\": \"quad\", \"material\": \"light\", \"vertices\": "
        "[[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]]}]}",
        a->size, a->size);
    cJSON *q = cJSON_CreateObject();
    cJSON_AddStringToObject(q, "cmd", "submit");
    cJSON_AddStringToObject(q, "name", "synthetic.json");
    cJSON_AddNumberToObject(q, "spp", (double)a->spp);
    cJSON_AddNumberToObject(q, "granularity", (double)a->granularity);
    cJSON_AddStringToObject(q, "adaptive", a->adaptive);
    if (a->have_uniform)
        cJSON_AddNumberToObject(q, "uniform_layers", (double)a->uniform_layers);
    io_threads_start(&c->io);
    c->wall = now_s();
    c->master_cpu = clock_s(b->master_clock);
    c->proc_cpu = clock_s(CLOCK_PROCESS_CPUTIME_ID);
    for (uint64_t i = 0; i < a->workers; i++)
        c->synth_cpu[i] = clock_s(b->synth[i].clock);
    cJSON *r = request(b->req, q, scene, (size_t)scene_len, b->err, sizeof b->err);
    cJSON_Delete(q);
    if (!r) {
        fprintf(stderr, "bench_master: submit: %s\n", b->err);
        return -1;
    }
    *job = json_num(r, "job");
    cJSON_Delete(r);
    return 0;
}

/* Cancels the job (the reply does not matter: the status polls follow it). */
static void cancel_job(bench_t *b, double job)
{
    cJSON *c = cJSON_CreateObject();
    cJSON_AddStringToObject(c, "cmd", "cancel");
    cJSON_AddNumberToObject(c, "job", job);
    cJSON *cr = request(b->req, c, NULL, 0, b->err, sizeof b->err);
    cJSON_Delete(c);
    cJSON_Delete(cr);
}

/* Polls the job's status until it is over, cancelling it once past
 * --max-seconds from wall0. The last status (the caller's), or NULL when
 * a poll or a synthetic worker failed. */
static cJSON *poll_until_done(bench_t *b, double job, double wall0, int *cancelled)
{
    cJSON *q = cJSON_CreateObject(), *status = NULL;
    cJSON_AddStringToObject(q, "cmd", "status");
    cJSON_AddNumberToObject(q, "job", job);
    for (;;) {
        struct timespec ts = {0, 100 * 1000 * 1000}; /* as often as `vbrender wait` */
        nanosleep(&ts, NULL);
        cJSON *r = request(b->req, q, NULL, 0, b->err, sizeof b->err);
        if (!r) {
            fprintf(stderr, "bench_master: status: %s\n", b->err);
            goto fail;
        }
        cJSON_Delete(status);
        status = cJSON_DetachItemFromObject(r, "job");
        cJSON_Delete(r);
        const char *st = json_str(status, "state");
        if (strcmp(st, "done") == 0 || strcmp(st, "failed") == 0 || strcmp(st, "cancelled") == 0)
            break;
        for (uint64_t i = 0; i < b->a->workers; i++)
            if (b->synth[i].failed) {
                fprintf(stderr, "bench_master: synthetic worker %" PRIu64 ": %s\n", i + 1,
                        b->synth[i].error);
                goto fail;
            }
        if (!*cancelled && now_s() - wall0 > (double)b->a->max_seconds) {
            cancel_job(b, job);
            *cancelled = 1;
        }
    }
    cJSON_Delete(q);
    return status;
fail:
    cJSON_Delete(q);
    cJSON_Delete(status);
    return NULL;
}

/* The clocks at the job's end against c, the synthetic workers' counters
 * and the master's figures from its last status. */
static void collect_figures(const bench_t *b, const bench_clocks_t *c, const cJSON *status,
                            bench_figures_t *f)
{
    memset(f, 0, sizeof *f);
    f->wall = now_s() - c->wall;
    f->master_cpu = clock_s(b->master_clock) - c->master_cpu;
    f->proc_cpu = clock_s(CLOCK_PROCESS_CPUTIME_ID) - c->proc_cpu;
    for (uint64_t i = 0; i < b->a->workers; i++) {
        const synth_t *s = &b->synth[i];
        f->synth_cpu += clock_s(s->clock) - c->synth_cpu[i];
        f->tasks += s->tasks;
        f->records += s->records;
        f->bytes_in += s->bytes_in;
        f->bytes_out += s->bytes_out;
    }
    f->master_io_cpu = io_threads_cpu(&c->io, 0, &f->master_io_busiest);
    f->worker_io_cpu = io_threads_cpu(&c->io, 1, NULL);
    f->seconds = json_num(status, "seconds");
    f->samples = json_num(status, "samples");
    f->results = f->samples / (double)b->a->granularity;
}

/* The result's first keys: what was run. */
static cJSON *result_json_settings(const args_t *a)
{
    cJSON *out = cJSON_CreateObject();
    cJSON_AddStringToObject(out, "benchmark", "master");
    cJSON_AddStringToObject(out, "transport", a->tcp ? "tcp" : "inproc");
    cJSON_AddBoolToObject(out, "curve", a->curve);
    cJSON_AddStringToObject(out, "worker_context", a->own_context ? "own" : "shared");
    cJSON_AddNumberToObject(out, "workers", (double)a->workers);
    cJSON_AddNumberToObject(out, "credit", (double)a->credit);
    cJSON_AddNumberToObject(out, "width", (double)a->size);
    cJSON_AddNumberToObject(out, "height", (double)a->size);
    cJSON_AddNumberToObject(out, "spp", (double)a->spp);
    cJSON_AddNumberToObject(out, "granularity", (double)a->granularity);
    cJSON_AddStringToObject(out, "adaptive", a->adaptive);
    cJSON_AddNumberToObject(out, "verify_share", a->verify_share);
    return out;
}

/* ns per result of a CPU time, 0 without results. */
static double ns_per_result(double cpu, double results)
{
    return results > 0 ? cpu / results * 1e9 : 0;
}

/* The whole result: settings, the master's status and the figures. */
static cJSON *result_json(const args_t *a, const cJSON *status, const bench_figures_t *f)
{
    cJSON *out = result_json_settings(a);
    double results = f->results, seconds = f->seconds, master_cpu = f->master_cpu;
    cJSON_AddNumberToObject(out, "tasks_verified", json_num(status, "tasks_verified"));
    cJSON_AddNumberToObject(out, "tasks_unverified", json_num(status, "tasks_unverified"));
    cJSON_AddNumberToObject(out, "verify_mismatches", json_num(status, "verify_mismatches"));
    cJSON_AddStringToObject(out, "state", json_str(status, "state"));
    cJSON_AddNumberToObject(out, "layers", json_num(status, "layers"));
    cJSON_AddNumberToObject(out, "layers_done", json_num(status, "layers_done"));
    cJSON_AddNumberToObject(out, "pixel_layers_skipped", json_num(status, "pixel_layers_skipped"));
    cJSON_AddNumberToObject(out, "samples", f->samples);
    cJSON_AddNumberToObject(out, "results", results);
    cJSON_AddNumberToObject(out, "results_sent_by_workers", (double)f->records);
    cJSON_AddNumberToObject(out, "tasks", (double)f->tasks);
    cJSON_AddNumberToObject(out, "task_pixels",
                            f->tasks ? (double)f->records / (double)f->tasks : 0);
    cJSON_AddNumberToObject(out, "seconds", seconds);
    cJSON_AddNumberToObject(out, "results_per_second", seconds > 0 ? results / seconds : 0);
    cJSON_AddNumberToObject(out, "tasks_per_second", seconds > 0 ? (double)f->tasks / seconds : 0);
    cJSON_AddNumberToObject(out, "wire_megabytes_per_second",
                            seconds > 0 ? (double)(f->bytes_in + f->bytes_out) / seconds / 1e6 : 0);
    cJSON_AddNumberToObject(out, "wall_seconds", f->wall);
    cJSON_AddNumberToObject(out, "master_cpu_seconds", master_cpu);
    cJSON_AddNumberToObject(out, "master_cpu_utilization", f->wall > 0 ? master_cpu / f->wall : 0);
    cJSON_AddNumberToObject(out, "results_per_master_cpu_second",
                            master_cpu > 0 ? results / master_cpu : 0);
    cJSON_AddNumberToObject(out, "master_ns_per_result", ns_per_result(master_cpu, results));
    /* ZeroMQ's I/O threads of the master's context (shared: the workers' too) */
    cJSON_AddNumberToObject(out, "master_io_cpu_seconds", f->master_io_cpu);
    cJSON_AddNumberToObject(out, "master_io_ns_per_result",
                            ns_per_result(f->master_io_cpu, results));
    cJSON_AddNumberToObject(out, "master_io_threads", (double)a->io_threads);
    /* a host with a core per thread is bounded by its busiest master thread */
    cJSON_AddNumberToObject(out, "master_io_busiest_ns_per_result",
                            ns_per_result(f->master_io_busiest, results));
    cJSON_AddNumberToObject(out, "worker_io_cpu_seconds", f->worker_io_cpu);
    cJSON_AddNumberToObject(out, "process_ns_per_result", ns_per_result(f->proc_cpu, results));
    cJSON_AddNumberToObject(out, "workers_cpu_seconds", f->synth_cpu);
    cJSON_AddNumberToObject(out, "other_cpu_seconds", f->proc_cpu - master_cpu - f->synth_cpu);
    cJSON_AddNumberToObject(out, "process_cpu_seconds", f->proc_cpu);
    return out;
}

/* The result on stdout, and in --json's file. */
static int write_result(const args_t *a, const cJSON *out)
{
    char *text = cJSON_Print(out);
    if (!text)
        return 0;
    printf("%s\n", text);
    if (a->json) {
        FILE *f = fopen(a->json, "w");
        if (!f || fprintf(f, "%s\n", text) < 0 || fclose(f) != 0) {
            fprintf(stderr, "bench_master: cannot write %s: %s\n", a->json, strerror(errno));
            cJSON_free(text);
            return -1;
        }
    }
    cJSON_free(text);
    return 0;
}

static void print_summary(const args_t *a, const bench_figures_t *f)
{
    double results = f->results, seconds = f->seconds, master_cpu = f->master_cpu;
    fprintf(stderr,
            "bench_master: %s%s, %" PRIu64 " worker(s), %s, G %" PRIu64
            ": %.3g results in %.2f s = %.3g results/s; "
            "master thread %.2f CPU s (%.0f%%) = %.3g results per master CPU s\n",
            a->tcp ? "tcp" : "inproc", a->curve ? " with CURVE" : "", a->workers, a->adaptive,
            a->granularity, results, seconds, seconds > 0 ? results / seconds : 0, master_cpu,
            f->wall > 0 ? 100 * master_cpu / f->wall : 0,
            master_cpu > 0 ? results / master_cpu : 0);
}

/* The job and its report, once master and synthetic workers run; the exit
 * code: 0 when the job is done or was cancelled after --max-seconds. */
static int bench_run(bench_t *b)
{
    bench_clocks_t c;
    double job;
    int cancelled = 0;
    if (connect_control(b) < 0 || wait_for_workers(b) < 0 || submit_job(b, &c, &job) < 0)
        return 1;
    cJSON *status = poll_until_done(b, job, c.wall, &cancelled);
    if (!status)
        return 1;
    bench_figures_t f;
    collect_figures(b, &c, status, &f);
    cJSON *out = result_json(b->a, status, &f);
    int rc = 1;
    if (write_result(b->a, out) == 0) {
        print_summary(b->a, &f);
        rc = strcmp(json_str(status, "state"), "done") == 0 || cancelled ? 0 : 1;
    }
    cJSON_Delete(out);
    cJSON_Delete(status);
    return rc;
}

/* Stops and joins what runs, closes the sockets and contexts, removes
 * the keys' scratch directory. */
static void bench_cleanup(bench_t *b)
{
    atomic_store(&b->synth_stop, 1);
    for (uint64_t i = 0; i < b->a->workers; i++)
        if (b->synth[i].started)
            pthread_join(b->synth[i].thread, NULL);
    if (b->master_started) {
        atomic_store(&b->mt.stop, 1);
        pthread_join(b->mt.thread, NULL);
        master_destroy(&b->mt.m);
    }
    if (b->req)
        zmq_close(b->req);
    if (b->wctx != b->ctx)
        zmq_ctx_term(b->wctx);
    zmq_ctx_term(b->ctx);
    if (b->a->curve)
        remove_keys(&b->keys);
}

int main(int argc, char **argv)
{
    signal(SIGPIPE, SIG_IGN);
    args_t a;
    int rc = parse_args(argc, argv, &a);
    if (rc == 0)
        rc = check_args(&a);
    if (rc)
        return rc;
    bench_t b;
    if (bench_init(&b, &a) < 0)
        return 1;
    rc = 1;
    if (start_master(&b) == 0) {
        start_synths(&b);
        rc = bench_run(&b);
    }
    bench_cleanup(&b);
    return rc;
}
