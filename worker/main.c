/* main.c - the vbrender-worker daemon.
 *
 *   vbrender-worker --master tcp://HOST:7070 [--threads N] [--name NAME]
 *                   [--key worker.key --master-key master.pub]
 *                   [--log-level LEVEL] [--version]
 *
 * SIGTERM or SIGINT: returns or releases its tasks, says BYE, exits 0.
 * Exit 1 when the master refuses it (protocol or build mismatch, its key
 * removed while connected) or a key file is unusable. A failed handshake
 * (a key the master does not admit, the wrong master key) is logged and
 * tried again with backoff. */
#include <errno.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <zmq.h>

#include "defaults.h"
#include "keys.h"
#include "proto.h"
#include "vberr.h"
#include "vblog.h"
#include "worker.h"

/* SIGTERM and SIGINT are blocked in every thread and taken by one thread
 * with sigwait, not by a handler. A process-directed signal goes to any
 * thread that does not block it, and this process has threads it does not
 * own: ZeroMQ's I/O threads and the TBB pool Embree starts on the first
 * BVH build. Under ThreadSanitizer, which runs a handler only when the
 * receiving thread next enters its runtime, a signal that landed on an idle
 * TBB thread (asleep in a raw futex syscall) never ran, and the worker
 * never stopped. The mask is set before the first thread starts, so every
 * later thread, the TBB pool included, inherits it. */
typedef struct signal_waiter {
    sigset_t set;
    atomic_int *stop;
} signal_waiter_t;

static void *wait_for_signal(void *arg)
{
    signal_waiter_t *sw = arg;
    int sig = 0;
    while (sigwait(&sw->set, &sig) != 0)
        ;
    atomic_store(sw->stop, 1);
    return NULL;
}

static const char usage[] =
    "usage: vbrender-worker --master tcp://HOST:" MASTER_DEFAULT_WORKER_PORT
    " [--threads N] [--name NAME]\n"
    "                       [--key worker.key --master-key master.pub]\n"
    "                       [--log-level LEVEL] [--version]\n"
    "  --master ENDPOINT   the master's worker endpoint\n"
    "  --threads N         render threads (default: all cores)\n"
    "  --name NAME         name in log lines (default: worker-PID)\n"
    "  --key FILE          this worker's CURVE key pair ('vbrender keygen NAME'); its\n"
    "                      .pub must be in the master's --allow-workers directory\n"
    "  --master-key FILE   the master's public key (its .pub file)\n"
    "  --log-level LEVEL   error, warn, info (default) or debug (a line per task)\n"
    "  --version           print the build id and exit\n"
    "Signals: TERM or INT: hand back the tasks not started, finish and return the\n"
    "ones being traced, say BYE to the master and exit 0 (1 if the master refused\n"
    "it). HUP is not handled (it ends the process). See docs/OPERATIONS.md.\n";

/* Options not taken up yet; any other value is the exit status. */
#define ARGS_GO_ON (-1)

typedef struct worker_opts {
    worker_config_t cfg;
    char name[64];
    const char *key_file, *master_key_file;
} worker_opts_t;

/* An option with a value: 1 when o is one (v taken), 0 when not, 2 after
 * a message. */
static int parse_option(const char *o, const char *v, worker_opts_t *opts)
{
    worker_config_t *cfg = &opts->cfg;
    if (strcmp(o, "--threads") == 0) {
        char *end;
        errno = 0;
        long t = v ? strtol(v, &end, 10) : 0;
        if (!v || errno || *end || t < 1 || t > 4096) {
            fprintf(stderr, "vbrender-worker: --threads needs 1..4096 (got '%s')\n", v ? v : "");
            return 2;
        }
        cfg->threads = (int)t;
    } else if (strcmp(o, "--log-level") == 0) {
        if ((cfg->log_level = vblog_level_parse(v)) < 0) {
            fprintf(stderr,
                    "vbrender-worker: --log-level needs error, warn, info or debug (got '%s')\n",
                    v ? v : "");
            return 2;
        }
    } else if (!v) {
        return 0;
    } else if (strcmp(o, "--master") == 0) {
        cfg->master_endpoint = v;
    } else if (strcmp(o, "--key") == 0) {
        opts->key_file = v;
    } else if (strcmp(o, "--master-key") == 0) {
        opts->master_key_file = v;
    } else if (strcmp(o, "--name") == 0) {
        cfg->name = v;
    } else {
        return 0;
    }
    return 1;
}

static int parse_args(int argc, char **argv, worker_opts_t *opts)
{
    worker_config_t *cfg = &opts->cfg;
    memset(opts, 0, sizeof *opts);
    long cores = sysconf(_SC_NPROCESSORS_ONLN);
    cfg->threads = cores > 0 ? (int)cores : 1;
    cfg->log = stderr;
    snprintf(opts->name, sizeof opts->name, "worker-%ld", (long)getpid());
    cfg->name = opts->name;
    for (int i = 1; i < argc; i++) {
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        int taken;
        if (strcmp(argv[i], "-h") == 0 || strcmp(argv[i], "--help") == 0) {
            fputs(usage, stdout);
            return 0;
        } else if (strcmp(argv[i], "--version") == 0) {
            char build[PROTO_BUILD_SIZE + 1];
            proto_host_build_id(build);
            printf("vbrender-worker %s\n", build);
            return 0;
        } else if ((taken = parse_option(argv[i], v, opts)) == 2) {
            return 2;
        } else if (taken) {
            i++;
        } else {
            fprintf(stderr, "vbrender-worker: unknown or incomplete option '%s'\n%s", argv[i],
                    usage);
            return 2;
        }
    }
    if (!cfg->master_endpoint) {
        fprintf(stderr, "vbrender-worker: --master ENDPOINT is required\n%s", usage);
        return 2;
    }
    if (!opts->key_file != !opts->master_key_file) {
        fprintf(stderr, "vbrender-worker: --key and --master-key go together\n");
        return 2;
    }
    return ARGS_GO_ON;
}

/* Blocks TERM and INT in this thread, and so in every later one, and starts
 * the thread that takes them: 0, or an errno value. */
static int start_signal_waiter(signal_waiter_t *sw, pthread_t *waiter)
{
    sigemptyset(&sw->set);
    sigaddset(&sw->set, SIGTERM);
    sigaddset(&sw->set, SIGINT);
    int err_no = pthread_sigmask(SIG_BLOCK, &sw->set, NULL);
    if (err_no == 0)
        err_no = pthread_create(waiter, NULL, wait_for_signal, sw);
    return err_no;
}

/* Runs the worker until a signal or the master's refusal: the exit status. */
static int run(worker_opts_t *opts, keys_pair_t *key)
{
    worker_config_t *cfg = &opts->cfg;
    signal(SIGPIPE, SIG_IGN);
    atomic_int stop;
    atomic_init(&stop, 0);
    signal_waiter_t sw;
    sw.stop = &stop;
    pthread_t waiter;
    int err_no = start_signal_waiter(&sw, &waiter);
    if (err_no != 0) {
        fprintf(stderr, "vbrender-worker: cannot set up signal handling: %s\n", strerror(err_no));
        return 1;
    }
    void *ctx = zmq_ctx_new();
    cfg->zmq_ctx = ctx;
    int rc = 1;
    char err[VB_ERR_LEN];
    worker_t *w = worker_new(cfg, err, sizeof err);
    explicit_bzero(key, sizeof *key); /* the worker keeps its own copy */
    if (w)
        rc = worker_run(w, &stop);
    else
        fprintf(stderr, "vbrender-worker: %s\n", err);
    worker_destroy(&w);
    zmq_ctx_term(ctx);
    /* No signal came (refused, or worker_new failed): wake the waiter with
     * one aimed at it. If one did come, the waiter has returned or is
     * returning, and this one is discarded with it. */
    if (!atomic_load(&stop))
        pthread_kill(waiter, SIGTERM);
    pthread_join(waiter, NULL);
    return rc;
}

int main(int argc, char **argv)
{
    worker_opts_t opts;
    int rc = parse_args(argc, argv, &opts);
    if (rc != ARGS_GO_ON)
        return rc;
    char err[VB_ERR_LEN];
    keys_pair_t key;
    char master_key[KEYS_Z85_LEN + 1];
    memset(&key, 0, sizeof key);
    if (opts.key_file) {
        if (keys_load_secret(opts.key_file, &key, err, sizeof err) < 0 ||
            keys_load_public(opts.master_key_file, master_key, err, sizeof err) < 0) {
            fprintf(stderr, "vbrender-worker: %s\n", err);
            return 1;
        }
        opts.cfg.public_key = key.public_z85;
        opts.cfg.secret_key = key.secret_z85;
        opts.cfg.master_key = master_key;
    }
    return run(&opts, &key);
}
