/* lease.c - see lease.h. A growable ring buffer, and a window of times. */
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
        size_t cap = q->cap ? 2 * q->cap : 64;
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

const lease_t *lease_at(const lease_queue_t *q, size_t i)
{
    return i < q->len ? &q->ring[(q->head + i) % q->cap] : NULL;
}

void lease_pop(lease_queue_t *q)
{
    if (q->len == 0)
        return;
    q->head = (q->head + 1) % q->cap;
    q->len--;
}

int lease_pop_sent_before(lease_queue_t *q, double before, lease_t *out)
{
    if (q->len == 0 || !(q->ring[q->head].sent < before))
        return 0;
    *out = q->ring[q->head];
    lease_pop(q);
    return 1;
}

size_t lease_count(const lease_queue_t *q)
{
    return q->len;
}

/* ---- task times ------------------------------------------------------------------ */

void lease_times_add(lease_times_t *t, double seconds)
{
    if (!(seconds >= 0)) /* a clock step back, or NaN: not a time */
        return;
    t->s[t->next] = (float)seconds;
    t->next = (t->next + 1) % LEASE_TIMES;
    if (t->n < LEASE_TIMES)
        t->n++;
}

double lease_times_quantile(const lease_times_t *t, double q)
{
    if (t->n < LEASE_TIMES_MIN)
        return 0;
    float v[LEASE_TIMES];
    memcpy(v, t->s, t->n * sizeof v[0]);
    /* insertion sort: 64 values, asked a few times a second */
    for (uint32_t i = 1; i < t->n; i++) {
        float x = v[i];
        uint32_t k = i;
        for (; k > 0 && v[k - 1] > x; k--)
            v[k] = v[k - 1];
        v[k] = x;
    }
    q = q < 0 ? 0 : q > 1 ? 1 : q;
    uint32_t rank = (uint32_t)(q * (double)(t->n - 1) + 0.5);
    return v[rank];
}

double lease_length(double task_s, double factor, double floor_s, double ceiling_s)
{
    if (!(task_s > 0) || !(factor > 0))
        return ceiling_s;
    double len = factor * task_s;
    len = len < floor_s ? floor_s : len;
    return len > ceiling_s ? ceiling_s : len;
}
