/* journal.h - a running job's journal of merged results (DIR/jobs/<id>/journal):
 * what was merged since the job's snapshot, in merge order, so that a
 * restarted master replays it through sched_take and sched_complete and
 * gets the scheduler back bit for bit (docs/DISTRIBUTED.md, "Checkpoints").
 *
 * The file (little-endian):
 *
 *   header   8-byte magic "VBJRNL1\n", u32 format version, u32 flags
 *            (JOURNAL_PVAR: records carry eq. 4.1's pvar), u64 the
 *            generation of the snapshot it follows, u64 the job id
 *   commits  each: u32 payload length, u64 sequence number (1, 2, ... in
 *            a file), the payload, u64 checksum of the length, sequence
 *            and payload
 *
 * A commit's payload: u64 byte count of its tasks, the tasks, then the
 * job's counters as JSON (the rest). A task: u64 task id, u32 pixel count,
 * then per pixel the compact record: sum[3] (3 x f64), lum_m2 (f64),
 * nonfinite (u8 with JOURNAL_NF8, else u16), rays (u32) with JOURNAL_RAYS,
 * and pvar (f64) with JOURNAL_PVAR. The pixel and the finite sample count
 * are not stored: the task's records give the pixels in order and their
 * sample counts (samples = sample_count - nonfinite). At G = 32: 33 bytes
 * a pixel, 37 for relmse, 41 for thesis, where the wire's result record is
 * 56.
 *
 * journal_t is the writing side in memory (the master's event loop): the
 * merged tasks not yet sealed into a commit, and the framed commits not yet
 * on disk. It does no I/O but journal_create. The reading side checks every
 * record before handing it out.
 */
#ifndef VB_JOURNAL_H
#define VB_JOURNAL_H

#include <stddef.h>
#include <stdint.h>

#include "tracer.h"

#define JOURNAL_VERSION 1
#define JOURNAL_HEADER_SIZE 32
#define JOURNAL_RECORD_OVERHEAD 20 /* length, sequence, checksum */
#define JOURNAL_TASK_HEADER 12     /* task id, count */
#define JOURNAL_PIXEL_SIZE 32      /* sums, M2; then nonfinite, rays, pvar by flags */
#define JOURNAL_RAYS_SIZE 4
#define JOURNAL_PVAR_SIZE 8
/* A commit larger than this is refused on read (a torn length field must
 * not make the reader trust the rest of the file). */
#define JOURNAL_MAX_PAYLOAD ((uint64_t)1 << 31)

/* JOURNAL_PVAR: records carry eq. 4.1's pvar (thesis reads it);
 * JOURNAL_RAYS: their rays (relmse weighs them; otherwise a replayed result
 * says one ray a sample, which nothing merged reads: the job's ray count
 * is in the commit's counters); JOURNAL_NF8: the NaN/Inf count in one byte
 * (G <= 255), else two. */
enum { JOURNAL_PVAR = 1, JOURNAL_RAYS = 2, JOURNAL_NF8 = 4 };
/* Bytes of one pixel's compact record under flags. */
size_t journal_pixel_size(uint32_t flags);

typedef struct journal_header {
    uint32_t version, flags;
    uint64_t generation, job;
} journal_header_t;

/* ---- writing -------------------------------------------------------------------- */

typedef struct journal journal_t;

/* NULL when out of memory. */
journal_t *journal_new(uint64_t job, uint64_t generation, uint32_t flags);
void journal_destroy(journal_t **j);

uint64_t journal_generation(const journal_t *j);
uint32_t journal_flags(const journal_t *j);
/* The sequence number the next commit gets. */
uint64_t journal_next_seq(const journal_t *j);

/* Appends one merged task (records in the task's pixel order) to the
 * unsealed tasks. 0, or -1 out of memory (the journal is then unusable
 * until journal_restart: journal_failed says so). */
int journal_note(journal_t *j, uint64_t task_id, const tracer_result_t *results, uint32_t count);
int journal_failed(const journal_t *j);
/* Bytes of unsealed tasks. */
size_t journal_pending(const journal_t *j);
/* Seals the unsealed tasks with the counters (JSON text) into a framed
 * commit appended to the unwritten bytes. 0, or -1 out of memory. */
int journal_seal(journal_t *j, const char *extras, size_t extras_len);
/* The framed commits not yet written: handed over (the journal forgets
 * them) for a writer; given back when the write failed, to be written
 * again first. */
size_t journal_unwritten(const journal_t *j);
void journal_take_unwritten(journal_t *j, uint8_t **data, size_t *len);
void journal_give_back(journal_t *j, uint8_t *data, size_t len);
/* A snapshot (generation) now holds everything up to the first `keep_from`
 * unsealed bytes: they and the unwritten commits are dropped, and the next
 * commit is sequence 1 of a fresh journal file. */
void journal_restart(journal_t *j, uint64_t generation, size_t keep_from);
/* A replay ended at sequence seq: the next commit is seq + 1. */
void journal_set_next_seq(journal_t *j, uint64_t seq);

/* The header's bytes. */
void journal_header_encode(const journal_header_t *h, uint8_t out[JOURNAL_HEADER_SIZE]);
/* Writes a journal holding only its header at path, crash-safe (a
 * temporary file with ".tmp." in its name, fsync, rename, fsync of the
 * directory). Allocates nothing (it runs in a forked child). 0, or -1 with
 * a message. */
int journal_create(const char *path, const journal_header_t *h, char *err, size_t errlen);

/* ---- reading -------------------------------------------------------------------- */

/* A whole journal file in memory, read commit by commit. */
typedef struct journal_reader {
    const uint8_t *data;
    size_t size;
    size_t pos;   /* the end of the last good commit (the header's end at first) */
    uint64_t seq; /* the last good commit's sequence number (0: none) */
    journal_header_t header;
} journal_reader_t;

/* Checks the header: 0, or -1 with a message (not a journal, a newer
 * version, torn). */
int journal_reader_init(journal_reader_t *r, const uint8_t *data, size_t size, char *err,
                        size_t errlen);

typedef struct journal_commit {
    uint64_t seq;
    const uint8_t *tasks; /* journal_task_next reads them */
    size_t tasks_len;
    const char *extras; /* the counters' JSON text (not NUL-terminated) */
    size_t extras_len;
} journal_commit_t;

/* The next commit: 1 and *c; 0 at the clean end of the file; -1 with a
 * message when what follows r->pos is not a sound commit (torn, bad
 * checksum, bad length, out of sequence): r->pos stays the end of the
 * last good one. */
int journal_next(journal_reader_t *r, journal_commit_t *c, char *err, size_t errlen);

/* The tasks of a commit, one by one. */
typedef struct journal_tasks {
    const uint8_t *p, *end;
    uint32_t flags;
} journal_tasks_t;
void journal_tasks_init(journal_tasks_t *it, const journal_commit_t *c, uint32_t flags);
/* 1 with the task's id, pixel count and its compact records (for
 * journal_result); 0 at the end; -1 when malformed. */
int journal_task_next(journal_tasks_t *it, uint64_t *task_id, uint32_t *count,
                      const uint8_t **records);
/* Rebuilds result i of a task's compact records, given the task's record i
 * (its pixel and sample count) as sched_take handed it out. -1 when the
 * stored NaN/Inf count exceeds the sample count. */
int journal_result(const uint8_t *records, uint32_t i, uint32_t flags, const tracer_task_t *task,
                   tracer_result_t *out);

#endif
