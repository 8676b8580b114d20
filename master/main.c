/* main.c - the vbrender-master daemon.
 *
 *   vbrender-master [--workers ENDPOINT] [--control ENDPOINT]  (default tcp ports 7070, 7071)
 *                   [--heartbeat-ms N] [--lease-ms N]
 *                   [--state DIR|none] [--checkpoint-s S] [--keep-finished N]
 *                   [--verify-share P]
 *
 * Logs to stderr with timestamps; SIGTERM or SIGINT stops it cleanly. */
#include <errno.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <zmq.h>

#include "master.h"
#include "proto.h"

/* The one global: a signal handler can reach nothing else. A lock-free
 * atomic is safe to store from a handler (C11 7.14.1.1). */
static atomic_int stop_requested;

static void on_signal(int sig)
{
    (void)sig;
    atomic_store(&stop_requested, 1);
}

static const char usage[] =
    "usage: vbrender-master [--workers ENDPOINT] [--control ENDPOINT]\n"
    "                       [--heartbeat-ms N] [--lease-ms N]\n"
    "                       [--state DIR|none] [--checkpoint-s S] [--keep-finished N]\n"
    "                       [--verify-share P]\n"
    "  --workers ENDPOINT   where workers connect (default tcp://*:7070)\n"
    "  --control ENDPOINT   where clients connect (default tcp://*:7071)\n"
    "  --heartbeat-ms N     heartbeat interval (default 1000)\n"
    "  --lease-ms N         a task unanswered this long is issued again (default 60000)\n"
    "  --state DIR          jobs, checkpoints and images survive a restart here\n"
    "                       (default ./vbrender-state); none: keep them in memory only\n"
    "  --checkpoint-s S     checkpoint running jobs this often (default 10)\n"
    "  --keep-finished N    ended jobs kept before the oldest are deleted (default 1000)\n"
    "  --max-bundle-mib N   a job's scene and meshes, at most (default 1024)\n"
    "  --max-queued-per-client N  queued and running jobs of one client (default 100)\n"
    "  --max-pixels N       image width x height of one job (default 67108864)\n"
    "  --max-spp N          samples per pixel of one job (default 1048576)\n"
    "  --max-requests-per-s N  control requests per connection and second (default 100)\n"
    "  --verify-share P     this share of tasks (0..1, chosen by job seed and task id) also runs\n"
    "                       on a second worker and merges only when both agree bit for bit; a\n"
    "                       third worker settles a mismatch and the odd one is quarantined\n"
    "                       (default 0.01; 0: off; 1: every task, never merged unverified)\n"
    "  --version            print the build id and exit\n"
    "Signals: TERM or INT checkpoint every running job and stop.\n";

static int parse_count(const char *s, double lo, double hi, double *out)
{
    if (!s || !*s)
        return -1;
    char *end;
    errno = 0;
    double v = strtod(s, &end);
    if (errno || *end || !(v >= lo && v <= hi))
        return -1;
    *out = v;
    return 0;
}

static int parse_ms(const char *s, uint32_t *out)
{
    if (!s || !*s)
        return -1;
    char *end;
    errno = 0;
    unsigned long v = strtoul(s, &end, 10);
    if (errno || *end || v < 10 || v > 3600000 || s[0] == '-')
        return -1;
    *out = (uint32_t)v;
    return 0;
}

int main(int argc, char **argv)
{
    master_config_t cfg;
    memset(&cfg, 0, sizeof cfg);
    cfg.worker_endpoint = MASTER_DEFAULT_WORKERS;
    cfg.control_endpoint = MASTER_DEFAULT_CONTROL;
    cfg.state_dir = MASTER_DEFAULT_STATE;
    cfg.log = stderr;
    cfg.verify_share = MASTER_DEFAULT_VERIFY_SHARE;
    double v_keep;
    for (int i = 1; i < argc; i++) {
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(argv[i], "-h") == 0 || strcmp(argv[i], "--help") == 0) {
            fputs(usage, stdout);
            return 0;
        } else if (strcmp(argv[i], "--version") == 0) {
            char build[PROTO_BUILD_SIZE + 1];
            __builtin_cpu_init();
            proto_build_id(__builtin_cpu_supports("avx2") ? "avx2" : "sse4.2", build);
            printf("vbrender-master %s\n", build);
            return 0;
        } else if (strcmp(argv[i], "--state") == 0 && v) {
            cfg.state_dir = strcmp(v, "none") == 0 ? NULL : v;
            i++;
        } else if (strcmp(argv[i], "--checkpoint-s") == 0) {
            if (parse_count(v, 0.05, 86400, &cfg.checkpoint_s) < 0) {
                fprintf(stderr, "vbrender-master: --checkpoint-s needs seconds from 0.05 to 86400 (got '%s')\n",
                        v ? v : "");
                return 2;
            }
            i++;
        } else if (strcmp(argv[i], "--max-bundle-mib") == 0 || strcmp(argv[i], "--max-queued-per-client") == 0 ||
                   strcmp(argv[i], "--max-pixels") == 0 || strcmp(argv[i], "--max-spp") == 0 ||
                   strcmp(argv[i], "--max-requests-per-s") == 0) {
            /* positive integers; each limit's own range */
            double hi = strcmp(argv[i], "--max-pixels") == 0 ? (double)(1u << 28)
                        : strcmp(argv[i], "--max-bundle-mib") == 0 ? (double)(PROTO_MAX_BUNDLE >> 20)
                                                                    : 4294967295.0;
            if (parse_count(v, 1, hi, &v_keep) < 0 || v_keep != (double)(uint64_t)v_keep) {
                fprintf(stderr, "vbrender-master: %s needs an integer from 1 to %.0f (got '%s')\n", argv[i], hi,
                        v ? v : "");
                return 2;
            }
            if (strcmp(argv[i], "--max-bundle-mib") == 0)
                cfg.max_bundle_mib = (uint32_t)v_keep;
            else if (strcmp(argv[i], "--max-queued-per-client") == 0)
                cfg.max_queued_per_client = (uint32_t)v_keep;
            else if (strcmp(argv[i], "--max-pixels") == 0)
                cfg.max_pixels = (uint64_t)v_keep;
            else if (strcmp(argv[i], "--max-spp") == 0)
                cfg.max_spp = (uint32_t)v_keep;
            else
                cfg.max_requests_per_s = (uint32_t)v_keep;
            i++;
        } else if (strcmp(argv[i], "--verify-share") == 0) {
            if (parse_count(v, 0, 1, &cfg.verify_share) < 0) {
                fprintf(stderr, "vbrender-master: --verify-share needs a share from 0 to 1 (got '%s')\n", v ? v : "");
                return 2;
            }
            i++;
        } else if (strcmp(argv[i], "--keep-finished") == 0) {
            if (parse_count(v, 1, 1e7, &v_keep) < 0 || v_keep != (double)(uint32_t)v_keep) {
                fprintf(stderr, "vbrender-master: --keep-finished needs an integer from 1 to 10000000 (got '%s')\n",
                        v ? v : "");
                return 2;
            }
            cfg.keep_finished = (uint32_t)v_keep;
            i++;
        } else if (strcmp(argv[i], "--workers") == 0 && v) {
            cfg.worker_endpoint = v;
            i++;
        } else if (strcmp(argv[i], "--control") == 0 && v) {
            cfg.control_endpoint = v;
            i++;
        } else if (strcmp(argv[i], "--heartbeat-ms") == 0) {
            if (parse_ms(v, &cfg.heartbeat_ms) < 0) {
                fprintf(stderr, "vbrender-master: --heartbeat-ms needs 10..3600000 (got '%s')\n", v ? v : "");
                return 2;
            }
            i++;
        } else if (strcmp(argv[i], "--lease-ms") == 0) {
            if (parse_ms(v, &cfg.lease_ms) < 0) {
                fprintf(stderr, "vbrender-master: --lease-ms needs 10..3600000 (got '%s')\n", v ? v : "");
                return 2;
            }
            i++;
        } else {
            fprintf(stderr, "vbrender-master: unknown or incomplete option '%s'\n%s", argv[i], usage);
            return 2;
        }
    }
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);
    void *ctx = zmq_ctx_new();
    cfg.zmq_ctx = ctx;
    char err[512];
    if (!cfg.state_dir)
        fprintf(stderr, "vbrender-master: warning: --state none: jobs are kept in memory only and a restart "
                        "loses them\n");
    master_t *m = master_new(&cfg, err, sizeof err);
    if (!m) {
        fprintf(stderr, "vbrender-master: %s\n", err);
        zmq_ctx_term(ctx);
        return 1;
    }
    master_run(m, &stop_requested);
    master_destroy(&m);
    zmq_ctx_term(ctx);
    return 0;
}
