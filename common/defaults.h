/* defaults.h - every default of vbrender in one place: ports and
 * endpoints, the master's timing and limits, the client's timeouts and a
 * job's settings when neither the request nor the scene gives one.
 *
 * Numbers are plain literals (no arithmetic) so that a usage text can
 * quote them (the *_TEXT names); what a value means is said beside it.
 * Only the master's config fields that are 0 in a zeroed config take
 * these (master.c), so a test that zeroes its config gets the same
 * master as the daemon except where a comment says otherwise. */
#ifndef VB_DEFAULTS_H
#define VB_DEFAULTS_H

/* DEFAULTS_STR(MASTER_DEFAULT_LEASE_MS) is "60000": a default quoted in a
 * usage text as a string literal (the *_TEXT names at the end). */
#define DEFAULTS_STR_(x) #x
#define DEFAULTS_STR(x) DEFAULTS_STR_(x)

/* ---- ports and endpoints ---- */
#define MASTER_DEFAULT_WORKER_PORT "7070"  /* workers connect here */
#define MASTER_DEFAULT_CONTROL_PORT "7071" /* clients connect here */
#define MASTER_DEFAULT_WORKERS "tcp://*:" MASTER_DEFAULT_WORKER_PORT
#define MASTER_DEFAULT_CONTROL "tcp://*:" MASTER_DEFAULT_CONTROL_PORT
#define CLIENT_DEFAULT_MASTER "tcp://localhost:" MASTER_DEFAULT_CONTROL_PORT

/* ---- the master daemon ---- */
#define MASTER_DEFAULT_STATE "vbrender-state"
#define MASTER_DEFAULT_CHECKPOINT_S 10
#define MASTER_DEFAULT_KEEP_FINISHED 1000
#define MASTER_DEFAULT_HEARTBEAT_MS 1000
/* a worker silent this many beats is dropped */
#define MASTER_DEFAULT_WORKER_TIMEOUT_HEARTBEATS 5
#define MASTER_DEFAULT_LEASE_MS 60000 /* the ceiling; leases follow task times below it */
/* a task out this many of its job's typical task times gets a backup copy
 * on an idle worker (docs/DISTRIBUTED.md: how it was chosen) */
#define MASTER_DEFAULT_BACKUP_FACTOR 3
/* a worker with 3 results refused is refused this long, doubled on each repeat */
#define MASTER_DEFAULT_BAN_S 10
#define MASTER_DEFAULT_MAX_BUNDLE_MIB 1024
#define MASTER_DEFAULT_MAX_QUEUED_PER_CLIENT 100
#define MASTER_DEFAULT_MAX_PIXELS 67108864 /* 8192 x 8192 */
#define MASTER_DEFAULT_MAX_SPP 1048576     /* 2^20 */
#define MASTER_DEFAULT_MAX_REQUESTS_PER_S 100
#define MASTER_DEFAULT_VERIFY_SHARE 0.01 /* the daemon's; 0 in a zeroed config */

/* ---- the client ---- */
#define CLIENT_DEFAULT_TIMEOUT_S 300          /* submit, wait: how long a master may stay away */
#define CLIENT_REQUEST_TIMEOUT_MS 10000       /* a request to a master (one try) */
#define CLIENT_EMBEDDED_TIMEOUT_MS 600000     /* render: a request to its own in-process master */
#define CLIENT_DEFAULT_WORKERS 1              /* render: local workers */
#define SERVE_DEFAULT_LISTEN "127.0.0.1:8080" /* serve: this machine only */
#define SERVE_REQUEST_TIMEOUT_MS 2000         /* serve: a page waits at most this for the master */

/* ---- a job's settings (settings.h) where neither request nor scene sets them ---- */
#define JOB_DEFAULT_GRANULARITY 32    /* samples per pixel per layer */
#define JOB_DEFAULT_ADAPTIVE "relmse" /* the study: bench/RESULTS.md, docs/ADAPTIVE.md */
#define JOB_DEFAULT_SAMPLER "sobol"   /* Owen-scrambled Sobol, one sequence per pixel */
/* Independent replicates of a pixel's sequence (rng_replicate_first_sample):
 * two cost 2-10 % relMSE at equal spp on the Cornell scenes (256 to 1024
 * spp, nothing on glass) and give the calibrated error of the variance
 * channel; more cost more (bench/error/calibrate.py, docs/ADAPTIVE.md). */
#define JOB_DEFAULT_REPLICATES 2
#define JOB_DEFAULT_CONFIDENCE 0.95
#define JOB_DEFAULT_TARGET_SHARE 1
#define JOB_DEFAULT_TARGET_ERROR 0 /* 0: no error target */
#define JOB_DEFAULT_TIME_LIMIT 0   /* 0: no time limit */

/* ---- the same numbers as text, for the usage texts ---- */
#define MASTER_DEFAULT_HEARTBEAT_MS_TEXT DEFAULTS_STR(MASTER_DEFAULT_HEARTBEAT_MS)
#define MASTER_DEFAULT_LEASE_MS_TEXT DEFAULTS_STR(MASTER_DEFAULT_LEASE_MS)
#define MASTER_DEFAULT_CHECKPOINT_S_TEXT DEFAULTS_STR(MASTER_DEFAULT_CHECKPOINT_S)
#define MASTER_DEFAULT_KEEP_FINISHED_TEXT DEFAULTS_STR(MASTER_DEFAULT_KEEP_FINISHED)
#define MASTER_DEFAULT_MAX_BUNDLE_MIB_TEXT DEFAULTS_STR(MASTER_DEFAULT_MAX_BUNDLE_MIB)
#define MASTER_DEFAULT_MAX_QUEUED_PER_CLIENT_TEXT DEFAULTS_STR(MASTER_DEFAULT_MAX_QUEUED_PER_CLIENT)
#define MASTER_DEFAULT_MAX_PIXELS_TEXT DEFAULTS_STR(MASTER_DEFAULT_MAX_PIXELS)
#define MASTER_DEFAULT_MAX_SPP_TEXT DEFAULTS_STR(MASTER_DEFAULT_MAX_SPP)
#define MASTER_DEFAULT_MAX_REQUESTS_PER_S_TEXT DEFAULTS_STR(MASTER_DEFAULT_MAX_REQUESTS_PER_S)
#define MASTER_DEFAULT_VERIFY_SHARE_TEXT DEFAULTS_STR(MASTER_DEFAULT_VERIFY_SHARE)
#define MASTER_DEFAULT_BACKUP_FACTOR_TEXT DEFAULTS_STR(MASTER_DEFAULT_BACKUP_FACTOR)
#define MASTER_DEFAULT_BAN_S_TEXT DEFAULTS_STR(MASTER_DEFAULT_BAN_S)
#define CLIENT_DEFAULT_TIMEOUT_S_TEXT DEFAULTS_STR(CLIENT_DEFAULT_TIMEOUT_S)
#define CLIENT_DEFAULT_WORKERS_TEXT DEFAULTS_STR(CLIENT_DEFAULT_WORKERS)

#endif
