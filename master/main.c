/* main.c - the vbrender-master daemon.
 *
 *   vbrender-master [--workers ENDPOINT] [--control ENDPOINT]  (default tcp ports 7070, 7071)
 *                   [--heartbeat-ms N] [--lease-ms N]
 *                   [--state DIR|none] [--checkpoint-s S] [--keep-finished N]
 *                   [--key master.key --allow-workers DIR --allow-clients DIR
 *                    [--admin-clients DIR] | --insecure]
 *                   [--verify-share P] [--log-level LEVEL] [--version]
 *
 * Logs to stderr with timestamps; SIGTERM or SIGINT stops it cleanly,
 * SIGHUP reloads the allow-lists. */
#include <errno.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <zmq.h>

#include "keys.h"
#include "master.h"
#include "proto.h"
#include "vberr.h"
#include "vblog.h"

/* The globals: a signal handler can reach nothing else. A lock-free atomic
 * is safe to store from a handler (C11 7.14.1.1). */
static atomic_int stop_requested;
static atomic_int reload_requested;

static void on_signal(int sig)
{
    if (sig == SIGHUP)
        atomic_store(&reload_requested, 1);
    else
        atomic_store(&stop_requested, 1);
}

static const char usage[] =
    "usage: vbrender-master [--workers ENDPOINT] [--control ENDPOINT]\n"
    "                       [--heartbeat-ms N] [--lease-ms N] [--backup-factor K] [--ban-s S]\n"
    "                       [--state DIR|none] [--checkpoint-s S] [--keep-finished N]\n"
    "                       [--key FILE --allow-workers DIR --allow-clients DIR\n"
    "                        [--admin-clients DIR] | --insecure]\n"
    "                       [--verify-share P]\n"
    "  --workers ENDPOINT   where workers connect (default " MASTER_DEFAULT_WORKERS
    ": needs --key or\n"
    "                       --insecure)\n"
    "  --control ENDPOINT   where clients connect (default " MASTER_DEFAULT_CONTROL ": the same)\n"
    "  --heartbeat-ms N     heartbeat interval (default " MASTER_DEFAULT_HEARTBEAT_MS_TEXT ")\n"
    "  --lease-ms N         the longest a task may go unanswered before it is issued\n"
    "                       again (default " MASTER_DEFAULT_LEASE_MS_TEXT
    "); below it a lease runs out after\n"
    "                       8 of the job's typical task times (the median of its last\n"
    "                       64), never under 2 s\n"
    "  --backup-factor K    a task out K typical task times gets a backup copy on an\n"
    "                       idle worker, and the first answer wins "
    "(default " MASTER_DEFAULT_BACKUP_FACTOR_TEXT ";\n"
    "                       0: no backups)\n"
    "  --ban-s S            a worker with 3 results refused (malformed, out of range) is\n"
    "                       dropped and refused S seconds, doubled on each repeat up to an\n"
    "                       hour (default " MASTER_DEFAULT_BAN_S_TEXT ")\n"
    "  --state DIR          jobs, checkpoints and images survive a restart here\n"
    "                       (default ./" MASTER_DEFAULT_STATE "); none: keep them in memory only\n"
    "  --checkpoint-s S     checkpoint running jobs this often "
    "(default " MASTER_DEFAULT_CHECKPOINT_S_TEXT ")\n"
    "  --keep-finished N    ended jobs kept before the oldest are deleted "
    "(default " MASTER_DEFAULT_KEEP_FINISHED_TEXT ")\n"
    "  --max-bundle-mib N   a job's scene and meshes, at most "
    "(default " MASTER_DEFAULT_MAX_BUNDLE_MIB_TEXT ")\n"
    "  --max-queued-per-client N  queued and running jobs of one client "
    "(default " MASTER_DEFAULT_MAX_QUEUED_PER_CLIENT_TEXT ")\n"
    "  --max-pixels N       image width x height of one job "
    "(default " MASTER_DEFAULT_MAX_PIXELS_TEXT ");\n"
    "                       a running job holds 116 bytes a pixel (relmse; 64 to 124 by\n"
    "                       mode), 1 GB at 3840x2160, whatever its spp, plus 48 a pixel for\n"
    "                       tasks out (at most one per pixel)\n"
    "  --max-spp N          samples per pixel of one job (default " MASTER_DEFAULT_MAX_SPP_TEXT
    ")\n"
    "  --max-requests-per-s N  control requests per connection and second "
    "(default " MASTER_DEFAULT_MAX_REQUESTS_PER_S_TEXT ")\n"
    "  --verify-share P     this share of tasks (0..1, chosen by job seed and task id) also runs\n"
    "                       on a second worker and merges only when both agree bit for bit; a\n"
    "                       third worker settles a mismatch and the odd one is quarantined\n"
    "                       (default " MASTER_DEFAULT_VERIFY_SHARE_TEXT
    "; 0: off; 1: every task, never merged unverified)\n"
    "  --key FILE           this master's CURVE key pair ('vbrender keygen NAME' makes\n"
    "                       NAME.key and NAME.pub): both sockets then encrypt and admit\n"
    "                       only the keys listed below\n"
    "  --allow-workers DIR  public keys (.pub files) of the workers admitted\n"
    "  --allow-clients DIR  public keys of the clients admitted\n"
    "  --admin-clients DIR  public keys of clients that may act on every job (admitted too)\n"
    "  --insecure           without --key, listen beyond loopback anyway (anyone who can\n"
    "                       reach the ports may submit jobs or pose as a worker)\n"
    "  --io-threads N       ZeroMQ I/O threads (default 3 with --key, else 1). With --key they do "
    "the\n"
    "                       encryption, one connection each: with many workers and cores\n"
    "                       to spare, 3 keep them from limiting the master\n"
    "  --log-level LEVEL    error, warn, info (default) or debug (a line per task)\n"
    "  --version            print the build id and exit\n"
    "Without --key only loopback endpoints are bound (tcp://127.x, tcp://localhost,\n"
    "tcp://[::1], ipc://, inproc://) unless --insecure is given.\n"
    "Signals: TERM or INT: stop issuing tasks, tell the workers BYE, write a last\n"
    "checkpoint of every running job (with --state; it resumes on the next start) and\n"
    "exit 0. HUP: read the allow-lists again (with --key; peers whose key was removed\n"
    "are dropped at their next message). See docs/OPERATIONS.md.\n";

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

/* What the command line gives: the master's config and what main itself
 * acts on before master_new. */
typedef struct master_opts {
    master_config_t cfg;
    const char *key_file;
    double io_threads; /* 0: 3 with --key (the crypto runs there), else 1 */
} master_opts_t;

/* Options not taken up yet; any other value is the exit status. */
#define ARGS_GO_ON (-1)

static int bad_value(const char *flag, const char *want, const char *v)
{
    fprintf(stderr, "vbrender-master: %s needs %s (got '%s')\n", flag, want, v ? v : "");
    return 2;
}

static int print_version(void)
{
    char build[PROTO_BUILD_SIZE + 1];
    proto_host_build_id(build);
    printf("vbrender-master %s\n", build);
    return 0;
}

/* The --max-* limits: positive integers, each with its own range. Returns
 * 1 when o is one (v taken), 0 when not, 2 after a message. */
static int parse_limit(const char *o, const char *v, master_config_t *cfg)
{
    if (strcmp(o, "--max-bundle-mib") != 0 && strcmp(o, "--max-queued-per-client") != 0 &&
        strcmp(o, "--max-pixels") != 0 && strcmp(o, "--max-spp") != 0 &&
        strcmp(o, "--max-requests-per-s") != 0)
        return 0;
    double v_keep;
    double hi = strcmp(o, "--max-pixels") == 0       ? (double)(1u << 28)
                : strcmp(o, "--max-bundle-mib") == 0 ? (double)(PROTO_MAX_BUNDLE >> 20)
                                                     : 4294967295.0;
    if (parse_count(v, 1, hi, &v_keep) < 0 || v_keep != (double)(uint64_t)v_keep) {
        fprintf(stderr, "vbrender-master: %s needs an integer from 1 to %.0f (got '%s')\n", o, hi,
                v ? v : "");
        return 2;
    }
    if (strcmp(o, "--max-bundle-mib") == 0)
        cfg->max_bundle_mib = (uint32_t)v_keep;
    else if (strcmp(o, "--max-queued-per-client") == 0)
        cfg->max_queued_per_client = (uint32_t)v_keep;
    else if (strcmp(o, "--max-pixels") == 0)
        cfg->max_pixels = (uint64_t)v_keep;
    else if (strcmp(o, "--max-spp") == 0)
        cfg->max_spp = (uint32_t)v_keep;
    else
        cfg->max_requests_per_s = (uint32_t)v_keep;
    return 1;
}

/* The other options with a checked value: 1 when o is one (v taken), 0 when
 * not, 2 after a message. */
static int parse_number(const char *o, const char *v, master_opts_t *opts)
{
    master_config_t *cfg = &opts->cfg;
    double v_keep;
    if (strcmp(o, "--checkpoint-s") == 0) {
        if (parse_count(v, 0.05, 86400, &cfg->checkpoint_s) < 0)
            return bad_value(o, "seconds from 0.05 to 86400", v);
    } else if (strcmp(o, "--verify-share") == 0) {
        if (parse_count(v, 0, 1, &cfg->verify_share) < 0)
            return bad_value(o, "a share from 0 to 1", v);
    } else if (strcmp(o, "--keep-finished") == 0) {
        if (parse_count(v, 1, 1e7, &v_keep) < 0 || v_keep != (double)(uint32_t)v_keep)
            return bad_value(o, "an integer from 1 to 10000000", v);
        cfg->keep_finished = (uint32_t)v_keep;
    } else if (strcmp(o, "--io-threads") == 0) {
        if (parse_count(v, 1, 64, &opts->io_threads) < 0 ||
            opts->io_threads != (double)(int)opts->io_threads)
            return bad_value(o, "an integer from 1 to 64", v);
    } else if (strcmp(o, "--heartbeat-ms") == 0) {
        if (parse_ms(v, &cfg->heartbeat_ms) < 0)
            return bad_value(o, "10..3600000", v);
    } else if (strcmp(o, "--ban-s") == 0) {
        if (parse_count(v, 0.1, 3600, &cfg->ban_s) < 0)
            return bad_value(o, "seconds from 0.1 to 3600", v);
    } else if (strcmp(o, "--backup-factor") == 0) {
        if (parse_count(v, 0, 1000, &cfg->backup_factor) < 0 ||
            (cfg->backup_factor > 0 && cfg->backup_factor < 1.5))
            return bad_value(o, "0 (no backups) or a factor from 1.5 to 1000", v);
        if (cfg->backup_factor == 0)
            cfg->backup_factor = -1; /* the config's "none" */
    } else if (strcmp(o, "--lease-ms") == 0) {
        if (parse_ms(v, &cfg->lease_ms) < 0)
            return bad_value(o, "10..3600000", v);
    } else if (strcmp(o, "--log-level") == 0) {
        if ((cfg->log_level = vblog_level_parse(v)) < 0)
            return bad_value(o, "error, warn, info or debug", v);
    } else {
        return parse_limit(o, v, cfg);
    }
    return 1;
}

/* Endpoints, directories and files: 1 when o is one with its value v, 0
 * when not. */
static int parse_path(const char *o, const char *v, master_opts_t *opts)
{
    master_config_t *cfg = &opts->cfg;
    if (!v)
        return 0;
    if (strcmp(o, "--state") == 0)
        cfg->state_dir = strcmp(v, "none") == 0 ? NULL : v;
    else if (strcmp(o, "--workers") == 0)
        cfg->worker_endpoint = v;
    else if (strcmp(o, "--control") == 0)
        cfg->control_endpoint = v;
    else if (strcmp(o, "--key") == 0)
        opts->key_file = v;
    else if (strcmp(o, "--allow-workers") == 0)
        cfg->allow_workers_dir = v;
    else if (strcmp(o, "--allow-clients") == 0)
        cfg->allow_clients_dir = v;
    else if (strcmp(o, "--admin-clients") == 0)
        cfg->admin_clients_dir = v;
    else
        return 0;
    return 1;
}

static int parse_args(int argc, char **argv, master_opts_t *opts)
{
    master_config_t *cfg = &opts->cfg;
    memset(opts, 0, sizeof *opts);
    cfg->worker_endpoint = MASTER_DEFAULT_WORKERS;
    cfg->control_endpoint = MASTER_DEFAULT_CONTROL;
    cfg->state_dir = MASTER_DEFAULT_STATE;
    cfg->log = stderr;
    cfg->verify_share = MASTER_DEFAULT_VERIFY_SHARE;
    cfg->reload = &reload_requested;
    for (int i = 1; i < argc; i++) {
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        int taken;
        if (strcmp(argv[i], "-h") == 0 || strcmp(argv[i], "--help") == 0) {
            fputs(usage, stdout);
            return 0;
        } else if (strcmp(argv[i], "--version") == 0) {
            return print_version();
        } else if (strcmp(argv[i], "--insecure") == 0) {
            cfg->insecure = 1;
        } else if ((taken = parse_number(argv[i], v, opts)) == 2) {
            return 2;
        } else if (taken || parse_path(argv[i], v, opts)) {
            i++;
        } else {
            fprintf(stderr, "vbrender-master: unknown or incomplete option '%s'\n%s", argv[i],
                    usage);
            return 2;
        }
    }
    return ARGS_GO_ON;
}

/* The options that only make sense together: 0, or 2 after a message. */
static int check_security(const master_opts_t *opts)
{
    const master_config_t *cfg = &opts->cfg;
    int have_lists = cfg->allow_workers_dir || cfg->allow_clients_dir || cfg->admin_clients_dir;
    if (opts->key_file && cfg->insecure) {
        fprintf(stderr, "vbrender-master: --insecure and --key contradict each other\n");
        return 2;
    }
    if (!opts->key_file && have_lists) {
        fprintf(
            stderr,
            "vbrender-master: --allow-workers, --allow-clients and --admin-clients need --key\n");
        return 2;
    }
    if (opts->key_file &&
        (!cfg->allow_workers_dir || !(cfg->allow_clients_dir || cfg->admin_clients_dir))) {
        fprintf(stderr,
                "vbrender-master: --key needs --allow-workers DIR and --allow-clients DIR (or "
                "--admin-clients DIR): the keys it admits\n");
        return 2;
    }
    return 0;
}

/* Loads the key, takes the signals, runs the master until one comes:
 * the exit status. */
static int run(master_opts_t *opts)
{
    master_config_t *cfg = &opts->cfg;
    char err[VB_ERR_LEN];
    keys_pair_t key;
    if (opts->key_file) {
        if (keys_load_secret(opts->key_file, &key, err, sizeof err) < 0) {
            fprintf(stderr, "vbrender-master: %s\n", err);
            return 1;
        }
        cfg->curve_secret_key = key.secret_z85;
    }
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGHUP, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);
    void *ctx = zmq_ctx_new();
    if (opts->io_threads ==
        0) /* measured (bench/run-curve.sh): 3 cut CURVE's cost from 30 % to 3 % */
        opts->io_threads = opts->key_file ? 3 : 1;
    zmq_ctx_set(ctx, ZMQ_IO_THREADS, (int)opts->io_threads); /* before the first socket */
    cfg->zmq_ctx = ctx;
    if (!cfg->state_dir)
        fprintf(
            stderr,
            "vbrender-master: warning: --state none: jobs are kept in memory only and a restart "
            "loses them\n");
    master_t *m = master_new(cfg, err, sizeof err);
    explicit_bzero(&key, sizeof key); /* the master keeps its own copy */
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

int main(int argc, char **argv)
{
    master_opts_t opts;
    int rc = parse_args(argc, argv, &opts);
    if (rc != ARGS_GO_ON)
        return rc;
    if ((rc = check_security(&opts)) != 0)
        return rc;
    return run(&opts);
}
