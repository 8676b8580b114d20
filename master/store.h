/* store.h - the master's durable state: one directory that holds everything
 * a restarted master needs to carry on (vbrender-master --state DIR).
 *
 *   DIR/meta                      the next job id and the boot count
 *   DIR/jobs/<id>/submit          the submit request as received (JSON and
 *                                 binary frames): rebuilt into a job exactly
 *                                 as a client's submission is
 *   DIR/jobs/<id>/snapshot        the scheduler (film included), the job's
 *                                 counters and a generation number
 *   DIR/jobs/<id>/journal         the results merged since that snapshot, in
 *                                 merge order (journal.h: not a record)
 *   DIR/jobs/<id>/checkpoint      (format 1, read and replaced by a snapshot)
 *   DIR/jobs/<id>/image.exr       the final image (done, failed, cancelled)
 *   DIR/jobs/<id>/final           the job's closing status (JSON)
 *
 * Every file is one record: a header (magic, format version, kind), the
 * payload, and a trailer (payload length, a 256-bit checksum of all before
 * it). The checksum is four interleaved 64-bit multiply-fold lanes, not
 * BLAKE2b: it guards against torn and corrupt files, not against forgery
 * (whoever can write the state directory owns the master anyway), and it
 * runs at memory speed, where BLAKE2b was 60 % of a 1080p checkpoint's CPU.
 * Files are written crash-safe: a temporary file, fsync, rename, fsync of
 * the directory. A file that fails its checks is reported, never trusted.
 *
 * Snapshots and final images are written by a forked child (as redis
 * writes its RDB file), so the master's event loop never waits on a disk:
 * the child sees a copy-on-write snapshot of the master's memory. One child
 * at a time; it reports each job's outcome through a pipe.
 */
#ifndef VB_STORE_H
#define VB_STORE_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <sys/types.h>

#include "vberr.h"

/* 2: snapshot and journal (STORE_KIND_SNAPSHOT, journal.h) in place of
 * checkpoint and checkpoint.prev. Records of version 1 are still read
 * (a state directory of the master before is taken over: persist.c); a
 * newer version than this is refused. */
#define STORE_FORMAT_VERSION 2
#define STORE_FORMAT_OLDEST 1

/* What a record holds (the header's kind: a file of one kind is never read
 * as another). */
typedef enum {
    STORE_KIND_META = 1,
    STORE_KIND_SUBMIT = 2,
    STORE_KIND_CHECKPOINT = 3,
    STORE_KIND_FINAL = 4,
    STORE_KIND_SNAPSHOT = 5
} store_kind_t;

typedef struct store store_t;

/* Opens (creating if needed) the state directory and reads its meta record.
 * NULL with a message when the directory cannot be used, or when its meta
 * was written by a newer master (a format version past
 * STORE_FORMAT_VERSION: the message names the file and both versions).
 * The meta is rewritten at this version. */
store_t *store_open(const char *dir, char *err, size_t errlen);
void store_close(store_t **s);

const char *store_dir(const store_t *s);
/* Times this state directory has been opened (1 for a new one). */
uint32_t store_boots(const store_t *s);

/* Job ids increase across restarts and are never reused: the next id is
 * max(meta's, every job directory's + 1). store_take_job_id makes the id
 * durable before returning it. 0 with a message on a failed write. */
uint64_t store_take_job_id(store_t *s, char *err, size_t errlen);

/* ---- records -------------------------------------------------------------- */

/* A record being written (crash-safe): store_rec_begin, store_rec_write any
 * number of times, store_rec_commit (fsync, rename, fsync dir). Allocates
 * nothing, so it may run in a forked child. */
/* The records' checksum, fed in pieces of any size. */
typedef struct store_sum {
    uint64_t lane[4];
    uint64_t total;
    uint8_t pend[32];
    unsigned npend;
} store_sum_t;
void store_sum_init(store_sum_t *c);
void store_sum_update(store_sum_t *c, const void *data, size_t len);
void store_sum_final(const store_sum_t *c, uint8_t out[32]);

/* Records are written with O_DIRECT where the file system takes it: the
 * page cache's copy was nine tenths of a checkpoint's CPU (2 s a GB
 * against 0.1), and nothing reads a record back but a restart. Writes
 * then go out whole aligned blocks from an aligned buffer; the last one is
 * padded and the file cut to its length before the fsync. */
#define STORE_ALIGN 4096
#define STORE_WRITE_BUF (1 << 20)

/* Appends len bytes to the file at path at offset (its durable size:
 * whatever lies past it is cut off first, so a torn record never precedes
 * a good one) and fdatasyncs it. With bounce (STORE_WRITE_BUF bytes,
 * STORE_ALIGN-aligned) the write is O_DIRECT where the file system takes
 * it; NULL, or a file system that refuses it, the page cache's way. 0, or
 * -1 with a message. */
int store_append(const char *path, uint64_t offset, const void *data, size_t len, uint8_t *bounce,
                 char *err, size_t errlen);

typedef struct store_rec_writer {
    int fd;
    int failed;
    int direct;       /* fd is O_DIRECT */
    uint64_t length;  /* of the payload */
    uint64_t written; /* bytes of the file handed to write(2) */
    store_sum_t hash;
    size_t buffered;
    uint8_t *buf; /* STORE_WRITE_BUF bytes, aligned, in space */
    uint8_t space[STORE_WRITE_BUF + STORE_ALIGN];
    char tmp[4096], path[4096];
    char err[VB_ERR_LEN];
} store_rec_writer_t;

/* w: a megabyte, on the heap. */
int store_rec_begin(store_rec_writer_t *w, const char *path, store_kind_t kind);
/* Same signature as sched_write_fn: 0, or -1 once a write failed. */
int store_rec_write(void *w, const void *data, size_t len);
/* keep_prev: the file being replaced is kept as PATH.prev (checkpoints).
 * 0, or -1 with w->err set. Commit is finish (trailer, fsync, close) then
 * install (rename into place, fsync of the directory). */
int store_rec_commit(store_rec_writer_t *w, int keep_prev);
int store_rec_finish(store_rec_writer_t *w);
int store_rec_install(store_rec_writer_t *w, int keep_prev);
void store_rec_abort(store_rec_writer_t *w);

/* A record read whole and checked: kind, version, length, checksum. */
typedef struct store_rec {
    uint8_t *data; /* the payload */
    size_t size;
    size_t pos;       /* for store_rec_read */
    uint32_t version; /* the format it was written in */
} store_rec_t;

/* 0 with *rec filled; -1 with a message (missing: "no such file"; torn or
 * corrupt: what failed). */
int store_rec_load(const char *path, store_kind_t kind, store_rec_t *rec, char *err, size_t errlen);
/* The same checks on a record already in memory (data, size: a whole
 * file); rec->data is a copy of the payload. */
int store_rec_parse(const uint8_t *data, size_t size, store_kind_t kind, store_rec_t *rec,
                    char *err, size_t errlen);
/* A record of one piece, written whole (begin, write, commit): 0, or -1
 * with a message. */
int store_rec_save(const char *path, store_kind_t kind, const void *data, size_t len, char *err,
                   size_t errlen);
/* Same signature as sched_read_fn: reads exactly len bytes, -1 if short. */
int store_rec_read(void *rec, void *data, size_t len);
void store_rec_free(store_rec_t *rec);

/* Length-prefixed blocks inside a payload (u64 length, bytes). */
int store_rec_write_block(store_rec_writer_t *w, const void *data, size_t len);
/* Points *data at the next block inside rec (no copy); -1 if torn. */
int store_rec_read_block(store_rec_t *rec, const uint8_t **data, size_t *len);

/* ---- jobs ------------------------------------------------------------------ */

/* DIR/jobs/<id>/NAME into out. */
void store_job_path(const store_t *s, uint64_t id, const char *name, char *out, size_t outlen);
/* Creates DIR/jobs/<id>. */
int store_job_dir(const store_t *s, uint64_t id, char *err, size_t errlen);
/* Removes the job's directory and every file in it. */
int store_job_remove(const store_t *s, uint64_t id, char *err, size_t errlen);
/* Removes temporary files a crash left in the job's directory. */
void store_job_clean(const store_t *s, uint64_t id);
/* Ids of the job directories, ascending (free with free). -1 on error. */
int store_job_ids(const store_t *s, uint64_t **ids, size_t *count, char *err, size_t errlen);

/* ---- the background writer --------------------------------------------------- */

/* Runs fn in a forked child; fn reports each outcome with store_bg_report
 * (one line each) and returns its exit status. Returns 0 when started, -1
 * with a message (a child still running, or fork failed). */
typedef int (*store_bg_fn)(void *ctx, int report_fd);
int store_bg_start(store_t *s, store_bg_fn fn, void *ctx, char *err, size_t errlen);
/* From the child: "ID ok" or "ID error MESSAGE" (one line). */
void store_bg_report(int report_fd, uint64_t id, const char *error);
int store_bg_running(const store_t *s);
/* Non-blocking. When the child has finished: calls on_report(ctx, id, error
 * or NULL) for every line it wrote, returns 1 (and *exit_status). 0 while it
 * runs or when there is none. A child that died without reporting a job
 * leaves that job unreported: the caller treats it as not written. */
typedef void (*store_bg_report_fn)(void *ctx, uint64_t id, const char *error);
int store_bg_poll(store_t *s, store_bg_report_fn on_report, void *ctx, int *exit_status);
/* The last finished child: its wall and CPU seconds, and how long the
 * fork itself held the caller. */
typedef struct store_bg_stats {
    uint64_t runs;
    double wall_s, cpu_s, fork_ms;
} store_bg_stats_t;
store_bg_stats_t store_bg_last(const store_t *s);
/* Waits for a running child (at shutdown). */
void store_bg_wait(store_t *s, store_bg_report_fn on_report, void *ctx);

#endif
