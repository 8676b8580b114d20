/* master_priv.h - the master's inside, shared by the files it is split into,
 * one concern each:
 *
 *   master.c    lifecycle, the event loop and its named periodic tasks
 *   jobs.c      the job store in memory: lookup, finishing, status JSON,
 *               retention and deletion
 *   submit.c    a submit request (or a stored one) turned into a job, step
 *               by step, every field checked
 *   peers.c     workers: sending, joining, losing them, their messages, and
 *               dispatch of ready tasks
 *   ctl.c       the control commands, as a table
 *   persist.c   durable state: submissions, checkpoints (a snapshot and a
 *               journal of merged results, journal.h), final images, and
 *               recovery at startup (through store.h)
 *   lease.c     task leases in the order sent, and task times (lease.h)
 *   verify.c    verification by replication: a seeded share of tasks goes
 *               to two (on a mismatch three) different workers and is
 *               merged only when two results agree bit for bit
 *   auth.c      CURVE keys, the ZAP handler and its allow-lists (auth.h)
 *
 * Work is fenced by (job, task, attempt): a result counts only if its job
 * is running, its task is outstanding with that worker, and its attempt is
 * the task's current one; anything else is late or a duplicate and is
 * dropped. A task being verified has several copies out at once, each
 * fenced by (job, task, attempt, worker): every copy gets its own attempt
 * number, and the task's holder names its verify entry instead of a worker
 * (verify_holds). Bad messages are logged, counted and dropped: the master
 * never exits on input.
 */
#ifndef VB_MASTER_PRIV_H
#define VB_MASTER_PRIV_H

#include <cJSON.h>
#include <stdint.h>
#include <zmq.h>

#include "auth.h"
#include "lease.h"
#include "master.h"
#include "offload.h"
#include "proto.h"
#include "sched.h"
#include "store.h"
#include "tracer.h"
#include "vberr.h"
#include "vblog.h"

#define MASTER_MAX_WORKERS 4096
#define MASTER_MAX_IDENTITY 255
#define MASTER_MAX_TASK_FAILURES 8 /* a job fails after this many TASK_FAILED */
#define MASTER_POLL_MS 50          /* event loop wake-up when idle */
#define MASTER_TIMER_S 0.1         /* periodic tasks run this often */
#define MASTER_WORKER_BATCH 4096   /* worker messages per loop turn */
#define MASTER_EVAL_S 0.25         /* error against a reference, this often */
#define MASTER_CONTROL_HWM 4       /* replies queued per client before drops */
#define MASTER_MAX_REQUEST_ID 64
#define MASTER_RATE_BUCKETS 1024 /* connections whose request rate is tracked */
#define MASTER_MAX_BAD_RESULTS 3 /* refused results before a worker is banned */
#define MASTER_BAN_MAX_S 3600.0  /* no ban is longer (the first: --ban-s, each repeat doubles) */
/* Leases lost in a row (run out, unanswered) before a worker gets no new
 * task until it answers one: the circuit breaker. */
#define MASTER_BREAKER_LEASES 3
/* Leases and backups are judged against this quantile of the job's last
 * LEASE_TIMES task times (lease.h): the median, which a minority of slow
 * workers cannot drag up. */
#define MASTER_TASK_QUANTILE 0.5
/* A lease runs out after MASTER_LEASE_FACTOR task times, never sooner than
 * the floor (a hiccup of a host or the network is not a lost task), never
 * later than --lease-ms. */
#define MASTER_LEASE_FACTOR 8.0
#define MASTER_LEASE_FLOOR_S 2.0
#define MASTER_CONTROL_MAX_BYTES ((int64_t)PROTO_MAX_BUNDLE + (1 << 20))
/* A job with this many verified tasks waiting for a copy to go out takes
 * no new tasks: with --verify-share 1 and no second worker, results would
 * otherwise pile up unmerged without bound. */
#define MASTER_VERIFY_MAX_QUEUED 1024
/* holder[] of a task out for verification: this bit and the index of its
 * entry in the job's verify state (worker slots stay below it). */
#define MASTER_VERIFY_HOLDER 0x80000000u
#define MASTER_MAX_WHO 64 /* peer_identity: a key or an address, with its NUL */
/* Attempt numbers of boot b start at (b & MASK) << SHIFT: a million
 * attempts a boot before one could equal a late result's of the boot before. */
#define MASTER_ATTEMPT_BOOT_MASK 0xfffu
#define MASTER_ATTEMPT_BOOT_SHIFT 20
/* The largest message a worker may send: a RESULT for the most pixels (the
 * header, 24 bytes of fixed fields, the records) and room to spare. */
#define MASTER_MAX_WORKER_MSG                                                                      \
    ((int64_t)PROTO_HEADER_SIZE + 24 + (int64_t)PROTO_RESULT_RECORD_SIZE * PROTO_MAX_TASK_PIXELS + \
     4096)
#define MASTER_KEYS_TEXT 256 /* auth_describe's summary of the allow-lists, for one log line */

typedef enum { JOB_QUEUED, JOB_RUNNING, JOB_DONE, JOB_FAILED, JOB_CANCELLED } job_state_t;
extern const char *const job_state_names[];

/* How a send went. */
typedef enum {
    SEND_OK = 0,
    SEND_UNREACHABLE = -1, /* the peer is gone: the worker's fault */
    SEND_BAD_MESSAGE = -2  /* the message cannot be encoded: its job's fault */
} send_status_t;

/* A connected worker, as the master sees it. */
/* Columns of a point of a job's error series (job_t.series). */
#define JOB_SERIES_COLUMNS 5

typedef struct peer {
    uint8_t id[MASTER_MAX_IDENTITY];
    size_t id_len;
    char host[64];
    char key[64]; /* its CURVE public key (Z85), "" without keys */
    char build[PROTO_BUILD_SIZE + 1];
    uint32_t threads;
    uint32_t credit;
    uint32_t outstanding;
    uint32_t owed;        /* tasks taken back while it still works on them
                             (lease ran out, job ended): their late results
                             return credit, other unmatched results do not */
    uint32_t bad_results; /* results refused as out of range or misfit */
    uint32_t leases_lost; /* leases run out in a row; MASTER_BREAKER_LEASES opens
                             the breaker, an answer closes it */
    uint64_t backups;     /* backup copies sent to it */
    double joined, last_seen, last_sent;
    uint64_t rays, tasks_done, busy_us, samples;
    uint64_t tasks_reissued; /* taken back from it: lease ran out, failed, refused */
    int alive;
} peer_t;

typedef struct job {
    uint64_t id;
    job_state_t state;
    char error[VB_ERR_LEN];
    char name[128];
    char request_id[MASTER_MAX_REQUEST_ID + 1];
    char owner[128]; /* the client that submitted it: its key, or its address without keys */
    /* the bundle, shipped to workers by hash; freed once the job has ended
     * and its image is durable */
    uint8_t hash[PROTO_HASH_SIZE];
    char *json;
    size_t json_size;
    uint32_t mesh_count;
    char (*mesh_names)[PROTO_MAX_NAME + 1];
    uint8_t **mesh_data;
    uint32_t *mesh_sizes;
    /* settings */
    uint32_t width, height, spp, granularity;
    sched_adaptive_t adaptive;
    tracer_settings_t tracer;
    double time_limit, target_error;
    sched_config_t sched_cfg; /* what sched was made with (checkpoints) */
    char *flags;              /* sched_cfg.flags points here */
    /* progress */
    sched_t *sched;
    uint32_t *attempt;     /* per task id - 1 */
    uint32_t *holder;      /* per task id - 1: worker slot + 1, 0 none (calloc'd:
                              no O(tasks) work at submit) */
    uint32_t *sent_ms;     /* per task id - 1: when its plain copy was sent, in ms
                              since epoch (its task time when answered) */
    double epoch;          /* master_now() when this master took the job */
    lease_queue_t *leases; /* the copies it has out, oldest first (lease.h) */
    lease_times_t times;   /* its last task times */
    uint64_t backups;      /* backup copies sent */
    uint64_t backups_won;  /* tasks whose backup copy answered first */
    uint32_t outstanding, reissued, failures;
    int requeue_refused; /* a task the scheduler would not take back: fail at the next tick */
    double submitted, started, finished;
    double run_before; /* seconds run before the last restart */
    uint64_t rays, busy_us, late_results;
    int stopped_issuing; /* time limit reached: no new tasks */
    /* error against a reference (--reference), over time and samples */
    float *ref[3], *cur[3];
    double *series; /* JOB_SERIES_COLUMNS per point: seconds, samples, relMSE, RMSE,
                       rays (what the samples cost, for equal-cost comparisons) */
    size_t series_n, series_cap;
    double last_eval;
    uint32_t last_eval_layers;
    /* durability (a master with --state) */
    uint64_t ckpt_samples; /* samples in the last durable checkpoint */
    uint64_t ckpt_writing; /* samples in the one being written */
    double last_ckpt;
    int in_write; /* in the background write under way: PERSIST_* */
    /* checkpoints: a snapshot and a journal of what was merged since
     * (persist.c, journal.h); journal NULL without a store */
    struct journal *journal;
    uint64_t snap_gen;        /* generation of the snapshot on disk; 0: none yet */
    uint64_t snap_bytes;      /* its size */
    uint64_t journal_bytes;   /* the journal file's size: what is durable in it */
    int need_snapshot;        /* the journal cannot go on: a snapshot first */
    int journal_writing;      /* its commits are with the writer thread */
    uint64_t journal_samples; /* samples those commits bring it to */
    size_t snap_keep_from;    /* journal_pending at the fork of the snapshot being written */
    int final_durable;        /* image and final status are on disk */
    char storage_error[VB_ERR_LEN];
    char recovered[VB_ERR_LEN];
    char *summary;           /* status of an ended job whose film is freed, as
                                JSON text: a tenth of the memory of its tree */
    struct preview *preview; /* the last preview asked for, kept (ctl.c): of its film,
                                or of its stored image once the film is freed */
    /* verification by replication (verify.c) */
    struct verify_job *verify;           /* its tasks out to several workers; NULL: none */
    uint64_t tasks_verified;             /* merged once two results agreed */
    uint64_t verify_mismatches;          /* tasks whose results differed */
    uint64_t tasks_unverified;           /* chosen, but merged on one result (no second worker) */
    uint32_t verify_waiting;             /* tasks whose next copy no connected worker may run */
    uint32_t verify_waiting_for;         /* 2 or 3: the worker they wait for */
    char (*quarantined)[MASTER_MAX_WHO]; /* workers quarantined over its results */
    size_t quarantined_n;
    struct job *next;
} job_t;

struct master {
    master_config_t cfg;
    void *workers_sock, *control_sock;
    peer_t *workers;
    uint32_t worker_count;
    job_t *jobs, *jobs_tail; /* in submission order */
    uint64_t next_job;       /* without a store */
    uint32_t rr;             /* round-robin start for dispatch */
    char build[PROTO_BUILD_SIZE + 1];
    uint8_t *payload; /* encode buffer */
    size_t payload_cap;
    tracer_result_t *results;                    /* decode buffer */
    store_t *store;                              /* NULL: --state none, or embedded */
    offload_t *offload;                          /* slow control work, off the loop */
    char (*inflight)[MASTER_MAX_REQUEST_ID + 1]; /* request ids being submitted */
    size_t inflight_n, inflight_cap;
    uint32_t attempt_base; /* first attempt number of this boot */
    uint64_t *doomed;      /* job ids to remove from the store */
    size_t doomed_n, doomed_cap;
    char storage_error[VB_ERR_LEN];
    struct ctl_bucket *buckets; /* request rate per control connection */
    char (*quarantine)[128];    /* workers refused: key, or address without keys */
    size_t quarantine_n, quarantine_cap;
    struct peer_ban *bans; /* workers refused for a while over bad results */
    size_t bans_n, bans_cap;
    uint64_t backups, banned;
    uint64_t malformed, dropped_late, rate_limited;
    uint64_t requeue_refused;       /* tasks the scheduler would not take back (job_requeue) */
    uint64_t tasks_issued;          /* TASK messages sent, copies for verification included */
    uint64_t reissued_deleted_jobs; /* tasks_reissued of jobs deleted since the start */
    /* background writes of checkpoints only (not final images): what they
     * cost, for the benchmark and the dashboard */
    int bg_final;       /* the write under way includes a final image */
    uint64_t ckpt_runs; /* journal commits written and snapshots forked */
    double ckpt_cpu_s, ckpt_wall_s, ckpt_fork_ms_max;
    struct persist_writer *writer; /* the journal writer thread (persist.c) */
    uint64_t journal_bytes_written, journal_commits;
    uint64_t snapshot_bytes_written, snapshots_written;
    uint64_t results_bytes_merged; /* wire size of the result records merged */
    vblog_limiter_t limiter;       /* lines a peer can provoke at will */
    auth_t *auth;                  /* NULL: no CURVE */
    double last_timer;
    int shutdown;
};

/* master.c */
double master_now(void);
/* Whether a client key (Z85) is in --admin-clients. */
int master_is_admin(master_t *m, const char *key);
/* A line at info level; master_log_at at another (vblog.h). */
void master_log(master_t *m, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
void master_log_at(master_t *m, vblog_level_t level, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
/* A line any peer can provoke (bad input), at warn level: rate-limited per
 * key (a string literal naming the kind of line), repeats summarised. */
void master_log_limited(master_t *m, const char *key, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
/* The CURVE public key (Z85) a received frame came with: the User-Id the
 * ZAP handler gave its peer; "" on a master without CURVE. Any frame of a
 * message carries it (the identity frame of a ROUTER too). */
const char *master_peer_key(zmq_msg_t *frame);
/* Whether the frame's peer is still admitted to the domain
 * (AUTH_DOMAIN_WORKERS or AUTH_DOMAIN_CONTROL): a key removed from an
 * allow-list on SIGHUP stays connected until it is asked this. Always 1 on
 * a master without CURVE. */
int master_peer_allowed(master_t *m, const char *domain, zmq_msg_t *frame);
/* Whether the frame's peer may act on every job: a key in --admin-clients,
 * or any peer of a master without CURVE (which listens on loopback only,
 * unless told --insecure). */
int master_peer_is_admin(master_t *m, zmq_msg_t *frame);

/* jobs.c */
job_t *job_find(master_t *m, uint64_t id);
job_t *job_find_by_hash(master_t *m, const uint8_t *hash);
job_t *job_find_by_request(master_t *m, const char *request_id);
void job_append(master_t *m, job_t *j);
void job_free(job_t *j);
void job_release_all(master_t *m, job_t *j);
void job_finish(master_t *m, job_t *j, job_state_t st, const char *why);
int job_ended(const job_t *j);
double job_seconds(const job_t *j, double now);
void job_eval_error(job_t *j, double now);
cJSON *job_json(const job_t *j, int with_series);
/* Frees what an ended job no longer needs once its image is durable. */
void job_shed(job_t *j);
/* Unlinks and frees a job, and queues its files for removal. */
void job_delete(master_t *m, job_t *j);
/* Deletes the oldest ended jobs past --keep-finished. */
void job_retention(master_t *m);
/* Takes a task back from its holder and hands it to the scheduler again. */
void job_reissue(master_t *m, job_t *j, size_t cell);
/* Hands a task the scheduler gave out (and nobody holds now) back to it;
 * a refusal is logged and counted in m->requeue_refused. */
void job_requeue(master_t *m, job_t *j, uint64_t task);
/* The job's typical task time (MASTER_TASK_QUANTILE of its last ones), 0
 * while too few are known; and how long a copy may be out before its lease
 * runs out (lease_length with the master's floor and --lease-ms). */
double job_task_seconds(const job_t *j);
double job_lease_seconds(const master_t *m, const job_t *j);
/* Records a copy of task sent now to worker slot (index + 1) with attempt. */
void job_lease(master_t *m, job_t *j, uint64_t task, uint32_t attempt, uint32_t slot, double now);
/* now as milliseconds since the job's epoch (sent_ms). */
uint32_t job_ms(const job_t *j, double now);
/* After a merge: finishes the job when the scheduler is done, else adds a
 * point to its error series per finished layer. */
void job_merged(master_t *m, job_t *j);

/* submit.c: a frame of a submit request */
typedef struct submit_frame {
    const void *data;
    size_t size;
} submit_frame_t;
typedef struct submit_limits {
    uint64_t max_bundle_bytes;
    uint64_t max_pixels;
    uint32_t max_spp;
} submit_limits_t;
/* Builds a queued job (no id yet) from a submit request and its binary
 * frames: validates the whole scene, loaded from the bundle exactly as a
 * worker will load it, and every setting. NULL with a message. limits
 * NULL: a stored request, recovered (accepted once under the limits of its
 * day; without "replicates" it is from a master of before them, and its
 * job has none). */
job_t *submit_parse(const cJSON *req, const submit_frame_t *frames, int nframes,
                    const submit_limits_t *limits, char *err, size_t errlen);
/* A mesh file name as a bundle may carry it (proto/PROTOCOL.md): 1 to
 * PROTO_MAX_NAME characters from A-Z a-z 0-9 . _ -, not starting with '.'. */
int submit_name_ok(const char *name);

/* peers.c */
void peer_handle_message(master_t *m);
void peer_lost(master_t *m, peer_t *w, const char *why);
int peer_send(master_t *m, peer_t *w, proto_msg_t *msg);
void peer_heartbeats(master_t *m, double now);
void peer_say_bye_all(master_t *m);
/* Who a worker is for quarantine: its key, or its address without keys. */
const char *peer_identity(const peer_t *w);
/* Refuses the worker from now on (until a restart or readmit), drops it. */
void peer_quarantine(master_t *m, peer_t *w, const char *why);
/* 1 if who (a key or an address) is quarantined. */
int peer_quarantined(const master_t *m, const char *who);
/* Lets who in again: 0, or -1 if it was not quarantined. */
int peer_readmit(master_t *m, const char *who);
void dispatch(master_t *m);
/* Sends task t of job j to w (slot: its index) with the task's next attempt
 * number, stored in *attempt; msg is scratch space. SEND_*. */
int peer_send_task(master_t *m, peer_t *w, job_t *j, const sched_task_t *t, proto_msg_t *msg,
                   uint32_t *attempt);
/* Counts an accepted result's work (rays, busy time, samples) for the job
 * and the worker. */
void peer_count_result(peer_t *w, job_t *j, const proto_msg_t *msg);
/* A result of a task w held was refused (malformed, out of range, misfit;
 * the caller has handed the task back): counted and logged, and at
 * MASTER_MAX_BAD_RESULTS the worker is dropped and banned for a while. */
void peer_bad_result(master_t *m, peer_t *w, job_t *j, uint64_t task, const char *err);
/* Seconds who (a key or an address) is still banned for; 0 if not. */
double peer_banned_for(master_t *m, const char *who, double now);
/* The bans still running, as objects {worker, seconds_left, bans}. */
void peer_bans_json(master_t *m, cJSON *arr, double now);
/* The circuit breaker: a lease of w ran out; w answered a task (any answer
 * to a task it holds or is owed closes the breaker); whether it is open
 * (w gets no new task). */
void peer_lease_lost(master_t *m, peer_t *w);
void peer_answered(master_t *m, peer_t *w);
int peer_breaker_open(const peer_t *w);
/* Quarantines who (a key or an address) whether or not it is connected:
 * every connection of it is refused and dropped. */
void peer_quarantine_identity(master_t *m, const char *who, const char *why);

/* verify.c: verification by replication (see the top of verify.c) */
/* Whether task_id of a job with this seed is verified at this share: a
 * pure function (same seed, same tasks); share 0 none, share 1 all. */
int verify_selected(uint64_t seed, uint64_t task_id, double share);
static inline int verify_holds(const job_t *j, size_t cell)
{
    return (j->holder[cell] & MASTER_VERIFY_HOLDER) != 0;
}
/* Whether dispatch sends t out for verification rather than once. */
int verify_wanted(master_t *m, const job_t *j, uint64_t task_id);
/* Sends t (just handed out by the scheduler) to w as the first of its
 * copies; the next copies wait for other workers. 1, or -1 when out of
 * memory (the task went back to the scheduler). */
int verify_start(master_t *m, job_t *j, const sched_task_t *t, peer_t *w, proto_msg_t *msg,
                 double now);
/* Sends w a copy some verified task waits for, if w may run one (another
 * worker than those with a copy): 1 if something was sent or tried, 0 if
 * none fits. msg: the caller's scratch message. */
int verify_dispatch_copy(master_t *m, peer_t *w, proto_msg_t *msg, double now);
/* Whether any job has copies waiting for a worker. */
int verify_copies_waiting(const master_t *m);
/* A backup copy of task cell + 1, out once (to its holder) for too long,
 * to w: the task becomes an entry whose first valid answer is merged and
 * whose other copy is then dropped as late. 1 if sent or tried (w may be
 * lost, or the job failed), 0 if it does not qualify or out of memory. */
int verify_backup(master_t *m, job_t *j, size_t cell, peer_t *w, proto_msg_t *msg, double now);
/* Whether the task of a cell held by verify still has the copy that worker
 * slot (index + 1) was sent with attempt: a lease that names it is live. */
int verify_copy_live(const job_t *j, size_t cell, uint32_t slot, uint32_t attempt);
/* Whether the job takes no new tasks for now (MASTER_VERIFY_MAX_QUEUED). */
int verify_saturated(const job_t *j);
/* A RESULT or TASK_FAILED for a task being verified (bad: a RESULT whose
 * records did not decode, and why): 0 if it was for a copy w holds
 * (handled), -1 if not (the caller counts it unmatched). */
int verify_on_result(master_t *m, peer_t *w, job_t *j, const proto_msg_t *msg, const char *bad);
/* The lease of a copy ran out: the copy goes to another worker. */
void verify_lease_expired(master_t *m, job_t *j, size_t cell, const lease_t *l);
/* Worker slot (index + 1) is gone: the copies it held go out again (and its
 * answers are dropped if it was quarantined). Returns the copies. */
uint32_t verify_peer_lost(master_t *m, job_t *j, uint32_t slot);
/* The job ended: copies out are released (owed) and the state is freed. */
void verify_release_all(master_t *m, job_t *j);
void verify_free(job_t *j);
/* Periodic: tasks that wait for a worker that is not there (status), and
 * with a share below 1, one result merged when no second worker is left. */
void verify_tick(master_t *m);
/* A task merged on one result by the plain path: counted when it was
 * chosen for verification. */
void verify_note_plain(master_t *m, job_t *j, uint64_t task_id);
/* Names who among the job's quarantined workers. */
void verify_note_quarantined(job_t *j, const char *who);
/* The job's verification fields in its status object. */
void verify_json(const job_t *j, cJSON *o);

/* ctl.c */
void ctl_handle_message(master_t *m);
/* Replies to the control work the offload thread has finished. */
void ctl_offload_done(master_t *m);
/* "job": N of a request as a job id: a positive integer a double holds
 * exactly. 0, or -1 when absent or not such a number. */
int ctl_job_id(const cJSON *req, uint64_t *id);

/* persist.c */
enum { PERSIST_SNAPSHOT = 1, PERSIST_FINAL = 2 };
/* Writes a submission and gives the job its id (the offload thread). */
int persist_submission(store_t *store, job_t *j, const void *req, size_t req_size,
                       const submit_frame_t *frames, int nframes, char *err, size_t errlen);
/* Where an ended job's image is; "" without a store. */
void persist_image_path(master_t *m, const job_t *j, char *out, size_t outlen);
void persist_tick(master_t *m, double now, int force);
void persist_recover(master_t *m);
void persist_finish(master_t *m); /* at shutdown: last checkpoints, wait */
/* Stops the journal writer thread (master_destroy). */
void persist_destroy(master_t *m);
/* A task's results were merged (sched_complete succeeded): counted, and
 * journalled in merge order for the next checkpoint. */
void persist_note(master_t *m, job_t *j, uint64_t task_id, const tracer_result_t *results,
                  uint32_t count);
/* A checkpoint's counters (its extras block, parsed) into j; anything but
 * a number in its counter's range counts as 0. */
void persist_apply_extras(job_t *j, const cJSON *o);

#endif
