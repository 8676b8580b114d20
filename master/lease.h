/* lease.h - task leases in issue order, and the task times they run out by.
 *
 * Each job has its own queue of the copies of tasks it has out, in the
 * order they were sent. A lease runs out when the copy has been out longer
 * than the job's current lease length (lease_length: a multiple of the
 * job's measured task time, within a floor and the --lease-ms ceiling), one
 * length for every copy of the job at a given moment, so the oldest copy is
 * always the first to run out: the master's timer looks only at the head
 * of each job's queue, never at every task. The same order names the task
 * that has been out longest, the first candidate for a backup copy.
 *
 * A lease is fenced by (task, attempt, worker slot) within its job's queue: one whose copy
 * was answered, taken back or sent again since is stale (the caller judges
 * that; staleness is for good, as attempt numbers only grow) and is
 * skipped and popped when it reaches the head.
 */
#ifndef VB_LEASE_H
#define VB_LEASE_H

#include <stddef.h>
#include <stdint.h>

typedef struct lease { /* in its job's queue */
    uint64_t task;
    uint32_t attempt;
    uint32_t slot; /* the worker it was sent to: slot + 1 */
    double sent;   /* master_now() when it was sent */
} lease_t;

typedef struct lease_queue lease_queue_t;

lease_queue_t *lease_queue_new(void);
void lease_queue_destroy(lease_queue_t **q);

/* Appends a lease; its send time must not be earlier than the last one's
 * (copies are sent in time order). -1 when out of memory. */
int lease_push(lease_queue_t *q, const lease_t *l);

/* The i-th oldest lease (0: the head), or NULL past the end. Valid until
 * the next push or pop. */
const lease_t *lease_at(const lease_queue_t *q, size_t i);

/* Drops the head, if any. */
void lease_pop(lease_queue_t *q);

/* Takes the oldest lease if it was sent before `before`: 1 and *out; 0
 * when none was. */
int lease_pop_sent_before(lease_queue_t *q, double before, lease_t *out);

size_t lease_count(const lease_queue_t *q);

/* ---- task times ------------------------------------------------------------------ */

/* The last LEASE_TIMES task times of a job (seconds from a copy being sent
 * to its answer): a window, so that the percentile follows the job as its
 * tasks get cheaper (adaptive layers take fewer pixels) or dearer. */
#define LEASE_TIMES 64
/* Times needed before the percentile is believed: until then leases are
 * the ceiling and no backup copy goes out. */
#define LEASE_TIMES_MIN 4

typedef struct lease_times {
    float s[LEASE_TIMES];
    uint32_t n, next; /* times kept (up to LEASE_TIMES), slot of the next */
} lease_times_t;

void lease_times_add(lease_times_t *t, double seconds);

/* The q-quantile (0..1, nearest rank) of the times kept; 0 when fewer than
 * LEASE_TIMES_MIN are. */
double lease_times_quantile(const lease_times_t *t, double q);

/* How long a copy may be out before its lease runs out: factor x the
 * typical task time, at least floor_s, at most ceiling_s; the ceiling while
 * the task time is unknown (0). */
double lease_length(double task_s, double factor, double floor_s, double ceiling_s);

#endif
