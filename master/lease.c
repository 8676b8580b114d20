/* lease.c - see lease.h. A growable ring buffer. */
#include "lease.h"

#include <stdlib.h>
#include <string.h>

struct lease_queue {
    lease_t *ring;
    size_t head, len, cap;
};

lease_queue_t *lease_queue_new(void)
{
    return calloc(1, sizeof(lease_queue_t));
}

void lease_queue_destroy(lease_queue_t **q)
{
    if (!q || !*q)
        return;
    free((*q)->ring);
    free(*q);
    *q = NULL;
}

int lease_push(lease_queue_t *q, const lease_t *l)
{
    if (q->len == q->cap) {
        size_t cap = q->cap ? 2 * q->cap : 256;
        lease_t *r = malloc(cap * sizeof *r);
        if (!r)
            return -1;
        /* unwrap into the new buffer, oldest first */
        for (size_t i = 0; i < q->len; i++)
            r[i] = q->ring[(q->head + i) % q->cap];
        free(q->ring);
        q->ring = r;
        q->cap = cap;
        q->head = 0;
    }
    q->ring[(q->head + q->len) % q->cap] = *l;
    q->len++;
    return 0;
}

int lease_pop_expired(lease_queue_t *q, double now, lease_t *out)
{
    if (q->len == 0 || !(q->ring[q->head].deadline < now))
        return 0;
    *out = q->ring[q->head];
    q->head = (q->head + 1) % q->cap;
    q->len--;
    return 1;
}

size_t lease_count(const lease_queue_t *q)
{
    return q->len;
}
