/* lease.h - task leases in deadline order.
 *
 * Every lease has the same length, so leases expire in the order they were
 * granted: a FIFO is a deadline-ordered queue, and the master's timer looks
 * only at its head instead of scanning every task of every job. A lease is
 * fenced by (job, task, attempt): one whose task was completed or issued
 * again since is stale, and the caller skips it when it pops. A task sent
 * to several workers for verification has one lease per copy: (job, task,
 * attempt, worker slot) names the copy.
 */
#ifndef VB_LEASE_H
#define VB_LEASE_H

#include <stddef.h>
#include <stdint.h>

typedef struct lease {
    uint64_t job;
    uint64_t task;
    uint32_t attempt;
    uint32_t slot; /* the worker it was sent to: slot + 1 */
    double deadline;
} lease_t;

typedef struct lease_queue lease_queue_t;

lease_queue_t *lease_queue_new(void);
void lease_queue_destroy(lease_queue_t **q);

/* Appends a lease; its deadline must not be earlier than the last one's
 * (leases are granted in time order with one length). -1 when out of
 * memory. */
int lease_push(lease_queue_t *q, const lease_t *l);

/* Takes the oldest lease if its deadline is before now: 1 and *out; 0 when
 * none has expired. */
int lease_pop_expired(lease_queue_t *q, double now, lease_t *out);

size_t lease_count(const lease_queue_t *q);

#endif
