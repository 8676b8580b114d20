/* verify.c - verification by replication (master_priv.h).
 *
 * A task is chosen for verification by a hash of (job seed, task id), so a
 * job verifies the same tasks wherever and whenever it runs. A chosen task
 * goes to one worker and, as a copy, to a second whose identity (its key,
 * or its address without keys: peer_identity) differs, so a worker cannot
 * vouch for itself by connecting twice. Each result is range-checked as it
 * arrives (sched_check) and kept; the task is merged (sched_complete) only
 * when two results agree bit for bit in every record. When two differ, a
 * third worker with yet another identity runs it and the majority wins: the
 * agreeing result is merged and the worker that differs is quarantined. If
 * all three differ nobody can be believed: all are dropped and the task goes
 * back to the scheduler, to be issued afresh with its next attempt.
 *
 * With a share below 1, a task chosen when fewer than two identities are
 * connected is sent once and counted unverified when merged (peers.c), and
 * one whose second copy no connected worker may run is merged on its one
 * result (verify_tick). With share 1 nothing is merged unverified: the
 * copies wait, and the job's status says for whom.
 *
 * The scheduler holds the task as outstanding through all this: it is
 * completed or requeued exactly once. Meanwhile the job's holder[] of the
 * task names its entry here (MASTER_VERIFY_HOLDER | index); each copy has
 * its own attempt number, worker slot and lease. A copy whose lease runs
 * out or whose worker is lost goes to another worker; an answer that
 * matches no copy held is unmatched (peers.c's credit rules).
 *
 * Determinism: verification changes who computes a task, never what is
 * merged: the merged result is one of two identical ones for the records
 * the scheduler handed out.
 */
#include <inttypes.h>
#include <stdlib.h>
#include <string.h>

#include "master_priv.h"
#include "rng.h"

#define VERIFY_COPIES 3 /* two, and a third to settle a mismatch */
#define NO_ENTRY UINT32_MAX

/* One copy of a task: free (slot 0, not answered), held by a worker (slot),
 * or answered (its result kept until the task is decided). */
typedef struct vcopy {
    uint32_t slot;    /* worker index + 1 while it holds the copy */
    uint32_t attempt; /* the attempt number it was sent with */
    double sent;      /* when (its task time once answered) */
    int answered;
    tracer_result_t *res;     /* the answer, range-checked */
    char who[MASTER_MAX_WHO]; /* identity of the worker it went to */
} vcopy_t;

typedef struct ventry {
    uint64_t task;  /* 0: a free entry */
    uint32_t count; /* records of the task */
    int queued;     /* in the queue of entries that need a copy sent */
    int backup;     /* a straggler's task with a backup copy: the first valid
                       answer is merged, no agreement needed */
    uint32_t next_free;
    vcopy_t c[VERIFY_COPIES];
} ventry_t;

struct verify_job {
    ventry_t *pool; /* entries by index (holder[] names them) */
    uint32_t cap, free_head;
    uint32_t *queue; /* entries that need a copy sent, oldest first */
    uint32_t qlen, qcap;
};
typedef struct verify_job verify_job_t;

int verify_selected(uint64_t seed, uint64_t task_id, double share)
{
    if (!(share > 0))
        return 0;
    if (share >= 1)
        return 1;
    /* its own stream: unrelated to the samples' (rng_stream) */
    uint64_t h = rng_mix64(seed ^ 0x5645524946590a00ULL);
    h = rng_mix64(h ^ (task_id * 0x9e3779b97f4a7c15ULL));
    return (double)(h >> 11) * 0x1.0p-53 < share;
}

/* ---- entries ------------------------------------------------------------------ */

static uint32_t held(const ventry_t *e)
{
    uint32_t n = 0;
    for (int k = 0; k < VERIFY_COPIES; k++)
        n += e->c[k].slot != 0;
    return n;
}

static uint32_t answered(const ventry_t *e)
{
    uint32_t n = 0;
    for (int k = 0; k < VERIFY_COPIES; k++)
        n += e->c[k].answered;
    return n;
}

/* Two copies, or three once two answers differ (answers kept always
 * differ: two that agree are merged at once); a backup entry needs one
 * copy out until one answers. */
static uint32_t wanted(const ventry_t *e)
{
    if (e->backup)
        return 1;
    return answered(e) >= 2 ? 3 : 2;
}

static int needs_copy(const ventry_t *e)
{
    return held(e) + answered(e) < wanted(e);
}

/* 1 if who holds or answered a copy of the task. */
static int has_who(const ventry_t *e, const char *who)
{
    for (int k = 0; k < VERIFY_COPIES; k++)
        if ((e->c[k].slot || e->c[k].answered) && strcmp(e->c[k].who, who) == 0)
            return 1;
    return 0;
}

/* Whether worker w may run a copy of the entry's task: a verified task
 * goes to another identity than those with a copy, a backup to another
 * connection than the one that holds it. */
static int may_take(const master_t *m, const ventry_t *e, const peer_t *w)
{
    if (!e->backup)
        return !has_who(e, peer_identity(w));
    uint32_t slot = (uint32_t)(w - m->workers) + 1;
    for (int k = 0; k < VERIFY_COPIES; k++)
        if (e->c[k].slot == slot)
            return 0;
    return 1;
}

static int free_copy(const ventry_t *e)
{
    for (int k = 0; k < VERIFY_COPIES; k++)
        if (!e->c[k].slot && !e->c[k].answered)
            return k;
    return -1;
}

static void forget_answer(vcopy_t *c)
{
    free(c->res);
    c->res = NULL;
    c->answered = 0;
}

/* Whether w can take a copy now or later: connected, its breaker closed,
 * and credit to use or tasks out that will return some. A worker whose
 * every credit is owed for tasks taken back (a hoarder) cannot, until a
 * late answer returns one: copies must not wait for it. */
static int can_work(const peer_t *w)
{
    return w->alive && !peer_breaker_open(w) && w->credit + w->outstanding > 0;
}

/* Up to max distinct identities of the workers that can work, into ids. */
static uint32_t alive_identities(const master_t *m, const char **ids, uint32_t max)
{
    uint32_t n = 0;
    for (uint32_t i = 0; i < m->worker_count && n < max; i++) {
        if (!can_work(&m->workers[i]))
            continue;
        const char *who = peer_identity(&m->workers[i]);
        uint32_t k = 0;
        while (k < n && strcmp(ids[k], who) != 0)
            k++;
        if (k == n)
            ids[n++] = who;
    }
    return n;
}

/* Whether some connected worker may run the entry's next copy. ids: up to
 * VERIFY_COPIES + 1 identities (alive_identities): an entry names at most
 * VERIFY_COPIES, so with that many plus one, one is always left. */
static int can_place(const ventry_t *e, const char **ids, uint32_t n)
{
    for (uint32_t k = 0; k < n; k++)
        if (!has_who(e, ids[k]))
            return 1;
    return 0;
}

static int same_results(const tracer_result_t *a, const tracer_result_t *b, uint32_t count)
{
    for (uint32_t i = 0; i < count; i++)
        if (a[i].pixel != b[i].pixel || a[i].samples != b[i].samples ||
            a[i].nonfinite != b[i].nonfinite || a[i].rays != b[i].rays ||
            memcmp(a[i].sum, b[i].sum, sizeof a[i].sum) != 0 ||
            memcmp(&a[i].lum_m2, &b[i].lum_m2, 8) != 0 || memcmp(&a[i].pvar, &b[i].pvar, 8) != 0)
            return 0;
    return 1;
}

static verify_job_t *state_of(job_t *j)
{
    if (!j->verify && (j->verify = calloc(1, sizeof *j->verify)))
        j->verify->free_head = NO_ENTRY;
    return j->verify;
}

/* A new entry for task: its index, or NO_ENTRY when out of memory. */
static uint32_t entry_new(job_t *j, uint64_t task, uint32_t count)
{
    verify_job_t *v = state_of(j);
    if (!v)
        return NO_ENTRY;
    if (v->free_head == NO_ENTRY) {
        uint32_t cap = v->cap ? 2 * v->cap : 64;
        if (cap > ~MASTER_VERIFY_HOLDER)
            return NO_ENTRY;
        ventry_t *p = realloc(v->pool, cap * sizeof *p);
        if (!p)
            return NO_ENTRY;
        memset(p + v->cap, 0, (cap - v->cap) * sizeof *p);
        for (uint32_t i = cap; i-- > v->cap;) {
            p[i].next_free = v->free_head;
            v->free_head = i;
        }
        v->pool = p;
        v->cap = cap;
    }
    uint32_t idx = v->free_head;
    ventry_t *e = &v->pool[idx];
    v->free_head = e->next_free;
    memset(e, 0, sizeof *e);
    e->task = task;
    e->count = count;
    return idx;
}

static void queue_remove_at(verify_job_t *v, uint32_t pos)
{
    v->pool[v->queue[pos]].queued = 0;
    memmove(&v->queue[pos], &v->queue[pos + 1], (v->qlen - pos - 1) * sizeof v->queue[0]);
    v->qlen--;
}

/* Queues the entry if it needs a copy sent. Out of memory, it stays out of
 * the queue and verify_tick tries again. */
static void enqueue(verify_job_t *v, uint32_t idx)
{
    ventry_t *e = &v->pool[idx];
    if (e->queued || !needs_copy(e))
        return;
    if (v->qlen == v->qcap) {
        uint32_t cap = v->qcap ? 2 * v->qcap : 64;
        uint32_t *q = realloc(v->queue, cap * sizeof *q);
        if (!q)
            return;
        v->queue = q;
        v->qcap = cap;
    }
    v->queue[v->qlen++] = idx;
    e->queued = 1;
}

static void entry_free(verify_job_t *v, uint32_t idx)
{
    ventry_t *e = &v->pool[idx];
    for (uint32_t q = 0; e->queued && q < v->qlen; q++)
        if (v->queue[q] == idx)
            queue_remove_at(v, q);
    for (int k = 0; k < VERIFY_COPIES; k++)
        forget_answer(&e->c[k]);
    e->task = 0;
    e->next_free = v->free_head;
    v->free_head = idx;
}

/* A copy taken back while its worker still works on it: its late answer
 * returns the credit (peers.c, owed). */
static void release_copy(master_t *m, vcopy_t *c)
{
    peer_t *w = &m->workers[c->slot - 1];
    if (w->outstanding)
        w->outstanding--;
    w->owed++;
    c->slot = 0;
}

/* The task is decided (merged or handed back): its entry goes. */
static void entry_close(master_t *m, job_t *j, uint32_t idx)
{
    ventry_t *e = &j->verify->pool[idx];
    for (int k = 0; k < VERIFY_COPIES; k++)
        if (e->c[k].slot)
            release_copy(m, &e->c[k]);
    j->holder[e->task - 1] = 0;
    if (j->outstanding)
        j->outstanding--;
    entry_free(j->verify, idx);
}

/* Nothing to believe: the task goes back to the scheduler (once: it held
 * it as outstanding until now) and out again with its next attempt. */
static void entry_drop(master_t *m, job_t *j, uint32_t idx)
{
    uint64_t task = j->verify->pool[idx].task;
    entry_close(m, j, idx);
    j->reissued++;
    job_requeue(m, j, task);
}

typedef enum { MERGE_VERIFIED, MERGE_UNVERIFIED, MERGE_BACKUP } merge_kind_t;

/* Merges res for the entry's task and closes the entry. The job may end
 * here (job_merged): nothing of it may be touched after. */
static void entry_merge(master_t *m, job_t *j, uint32_t idx, const tracer_result_t *res,
                        merge_kind_t kind)
{
    ventry_t *e = &j->verify->pool[idx];
    char err[VB_ERR_LEN];
    if (sched_complete(j->sched, e->task, res, e->count, err, sizeof err) != SCHED_OK) {
        /* checked when it arrived; the pixels it reads have not changed */
        master_log(m,
                   "job %" PRIu64 " task %" PRIu64
                   ": an agreed result did not merge (%s); issuing it again",
                   j->id, e->task, err);
        entry_drop(m, j, idx);
        return;
    }
    persist_note(m, j, e->task, res, e->count);
    if (kind == MERGE_VERIFIED)
        j->tasks_verified++;
    else if (kind == MERGE_UNVERIFIED)
        j->tasks_unverified++;
    else
        verify_note_plain(m, j, e->task); /* it went out as a plain task */
    entry_close(m, j, idx);
    job_merged(m, j);
}

/* ---- sending ------------------------------------------------------------------ */

/* Sends copy k of entry idx to w. SEND_OK: the copy is held by w. After
 * SEND_BAD_MESSAGE the job has failed and its state is gone; after
 * SEND_UNREACHABLE w is lost. */
static int send_copy(master_t *m, job_t *j, uint32_t idx, int k, peer_t *w, proto_msg_t *msg,
                     double now)
{
    uint64_t task = j->verify->pool[idx].task;
    sched_task_t t;
    if (sched_outstanding(j->sched, task, &t) != SCHED_OK) {
        master_log(m,
                   "job %" PRIu64 " task %" PRIu64
                   ": being verified but not outstanding in the scheduler",
                   j->id, task);
        job_finish(m, j, JOB_FAILED,
                   "internal error: a verified task was lost (see the master's log)");
        return SEND_BAD_MESSAGE;
    }
    uint32_t attempt;
    int rc = peer_send_task(m, w, j, &t, msg, &attempt);
    if (rc == SEND_BAD_MESSAGE) {
        job_finish(m, j, JOB_FAILED, "a task of this job cannot be encoded (see the master's log)");
        return rc;
    }
    if (rc == SEND_UNREACHABLE) {
        peer_lost(m, w, "unreachable");
        return rc;
    }
    uint32_t slot = (uint32_t)(w - m->workers) + 1;
    vcopy_t *c = &j->verify->pool[idx].c[k];
    c->slot = slot;
    c->attempt = attempt;
    c->sent = now;
    snprintf(c->who, sizeof c->who, "%s", peer_identity(w));
    job_lease(m, j, task, attempt, slot, now);
    w->outstanding++;
    w->credit--;
    return SEND_OK;
}

int verify_wanted(master_t *m, const job_t *j, uint64_t task_id)
{
    double share = m->cfg.verify_share;
    if (!verify_selected(j->tracer.seed, task_id, share))
        return 0;
    const char *ids[2];
    /* share 1 never merges one result: the copy waits for a second worker */
    return share >= 1 || alive_identities(m, ids, 2) == 2;
}

int verify_start(master_t *m, job_t *j, const sched_task_t *t, peer_t *w, proto_msg_t *msg,
                 double now)
{
    uint32_t idx = entry_new(j, t->id, t->count);
    if (idx == NO_ENTRY) {
        master_log(m, "job %" PRIu64 " task %" PRIu64 ": out of memory to verify it; trying later",
                   j->id, t->id);
        job_requeue(m, j, t->id); /* just handed out: it takes it back */
        return -1;
    }
    j->holder[t->id - 1] = MASTER_VERIFY_HOLDER | idx;
    j->outstanding++;
    if (send_copy(m, j, idx, 0, w, msg, now) != SEND_BAD_MESSAGE)
        enqueue(j->verify, idx); /* the second copy, or this one again */
    return 1;
}

int verify_dispatch_copy(master_t *m, peer_t *w, proto_msg_t *msg, double now)
{
    for (job_t *j = m->jobs; j; j = j->next) {
        verify_job_t *v = j->verify;
        if (j->state != JOB_RUNNING || !v)
            continue;
        for (uint32_t q = 0; q < v->qlen;) {
            uint32_t idx = v->queue[q];
            ventry_t *e = &v->pool[idx];
            if (!needs_copy(e)) {
                queue_remove_at(v, q); /* stale: a copy came back meanwhile */
                continue;
            }
            if (!may_take(m, e, w)) {
                q++;
                continue;
            }
            int rc = send_copy(m, j, idx, free_copy(e), w, msg, now);
            if (rc == SEND_OK && !needs_copy(&v->pool[idx]))
                queue_remove_at(v, q);
            return 1;
        }
    }
    return 0;
}

int verify_copies_waiting(const master_t *m)
{
    for (const job_t *j = m->jobs; j; j = j->next)
        if (j->state == JOB_RUNNING && j->verify && j->verify->qlen > 0)
            return 1;
    return 0;
}

int verify_saturated(const job_t *j)
{
    return j->verify && j->verify->qlen >= MASTER_VERIFY_MAX_QUEUED;
}

int verify_backup(master_t *m, job_t *j, size_t cell, peer_t *w, proto_msg_t *msg, double now)
{
    uint64_t task = (uint64_t)cell + 1;
    uint32_t holder = j->holder[cell];
    sched_task_t t;
    if (holder == 0 || verify_holds(j, cell) || sched_outstanding(j->sched, task, &t) != SCHED_OK)
        return 0;
    uint32_t idx = entry_new(j, task, t.count);
    if (idx == NO_ENTRY)
        return 0; /* out of memory: the task stays with its one worker */
    ventry_t *e = &j->verify->pool[idx];
    e->backup = 1;
    e->c[0].slot = holder;
    e->c[0].attempt = j->attempt[cell];
    e->c[0].sent = j->epoch + j->sent_ms[cell] / 1000.0;
    snprintf(e->c[0].who, sizeof e->c[0].who, "%s", peer_identity(&m->workers[holder - 1]));
    j->holder[cell] = MASTER_VERIFY_HOLDER | idx; /* still one task outstanding */
    double out = now - e->c[0].sent;
    if (send_copy(m, j, idx, 1, w, msg, now) == SEND_OK) {
        j->backups++;
        m->backups++;
        w->backups++;
        master_log_at(m, VBLOG_DEBUG,
                      "job %" PRIu64 " task %" PRIu64 ": out %.3f s on %s (task time %.3f s); "
                      "backup copy sent to %s",
                      j->id, task, out, m->workers[holder - 1].host, job_task_seconds(j), w->host);
    }
    return 1; /* after SEND_BAD_MESSAGE the job has failed; after UNREACHABLE w is gone */
}

int verify_copy_live(const job_t *j, size_t cell, uint32_t slot, uint32_t attempt)
{
    const ventry_t *e = &j->verify->pool[j->holder[cell] & ~MASTER_VERIFY_HOLDER];
    for (int k = 0; k < VERIFY_COPIES; k++)
        if (e->c[k].slot == slot && e->c[k].attempt == attempt)
            return 1;
    return 0;
}

/* ---- answers ------------------------------------------------------------------ */

static void copy_failed(master_t *m, peer_t *w, job_t *j, uint32_t idx, int k, const char *text)
{
    ventry_t *e = &j->verify->pool[idx];
    e->c[k].slot = 0;
    j->failures++;
    master_log_limited(m, "task-failed", "job %" PRIu64 " task %" PRIu64 " failed on %s: %s", j->id,
                       e->task, w->host, text);
    if (j->failures >= MASTER_MAX_TASK_FAILURES) {
        char why[VB_ERR_LEN];
        snprintf(why, sizeof why, "workers failed %u tasks; last: %.400s", j->failures, text);
        job_finish(m, j, JOB_FAILED, why);
        return;
    }
    j->reissued++;
    enqueue(j->verify, idx);
}

/* Malformed, out of range or misfit: counted against the worker, as in
 * peers.c, and the copy goes to another worker at once. */
static void copy_refused(master_t *m, peer_t *w, job_t *j, uint32_t idx, int k, const char *err)
{
    ventry_t *e = &j->verify->pool[idx];
    e->c[k].slot = 0;
    j->reissued++;
    enqueue(j->verify, idx);
    peer_bad_result(m, w, j, e->task, err); /* may ban w */
}

/* Two answers agree with each other and not with a third (answered copy
 * `odd`, or none): the task is merged and the odd worker quarantined. */
static void agreed(master_t *m, job_t *j, uint32_t idx, int k, int other, int odd,
                   const tracer_result_t *res)
{
    ventry_t *e = &j->verify->pool[idx];
    char liar[MASTER_MAX_WHO] = "", why[VB_ERR_LEN] = "";
    if (odd >= 0) {
        snprintf(liar, sizeof liar, "%s", e->c[odd].who);
        snprintf(why, sizeof why,
                 "its result for job %" PRIu64 " task %" PRIu64 " differs from those of %s and %s, "
                 "which agree",
                 j->id, e->task, e->c[k].who, e->c[other].who);
        master_log(m, "job %" PRIu64 " task %" PRIu64 ": %s agrees with %s; %s differs", j->id,
                   e->task, e->c[k].who, e->c[other].who, liar);
        verify_note_quarantined(j, liar);
    }
    entry_merge(m, j, idx, res, MERGE_VERIFIED); /* may end the job */
    if (liar[0])
        peer_quarantine_identity(m, liar, why);
}

/* A range-checked answer to copy k: merged when it agrees with another,
 * kept otherwise (a mismatch calls a third worker; three different answers
 * are all dropped). */
static void copy_answered(master_t *m, job_t *j, uint32_t idx, int k, const tracer_result_t *res)
{
    ventry_t *e = &j->verify->pool[idx];
    int others[VERIFY_COPIES], n = 0;
    e->c[k].slot = 0;
    if (e->backup) {
        if (k != 0)
            j->backups_won++;                      /* copy 0 is the straggler's own */
        entry_merge(m, j, idx, res, MERGE_BACKUP); /* may end the job */
        return;
    }
    for (int i = 0; i < VERIFY_COPIES; i++)
        if (i != k && e->c[i].answered)
            others[n++] = i;
    for (int i = 0; i < n; i++)
        if (same_results(e->c[others[i]].res, res, e->count)) {
            agreed(m, j, idx, k, others[i], n == 2 ? others[1 - i] : -1, res);
            return;
        }
    if (n == 2) {
        master_log(m,
                   "job %" PRIu64 " task %" PRIu64
                   ": %s, %s and %s returned three different results; all "
                   "dropped, the task is issued again",
                   j->id, e->task, e->c[others[0]].who, e->c[others[1]].who, e->c[k].who);
        entry_drop(m, j, idx);
        return;
    }
    if (!(e->c[k].res = malloc(e->count * sizeof *res))) {
        master_log(m,
                   "job %" PRIu64 " task %" PRIu64 ": out of memory to keep a result; asking again",
                   j->id, e->task);
        enqueue(j->verify, idx);
        return;
    }
    memcpy(e->c[k].res, res, e->count * sizeof *res);
    e->c[k].answered = 1;
    if (n == 1) {
        j->verify_mismatches++;
        master_log(m,
                   "job %" PRIu64 " task %" PRIu64
                   ": results of %s and %s differ; a third worker decides",
                   j->id, e->task, e->c[others[0]].who, e->c[k].who);
    }
    const char *ids[VERIFY_COPIES + 1];
    uint32_t nid = alive_identities(m, ids, VERIFY_COPIES + 1);
    if (n == 0 && m->cfg.verify_share < 1 && !held(e) && !can_place(e, ids, nid)) {
        entry_merge(m, j, idx, e->c[k].res, MERGE_UNVERIFIED); /* no second worker left */
        return;
    }
    enqueue(j->verify, idx);
}

int verify_on_result(master_t *m, peer_t *w, job_t *j, const proto_msg_t *msg, const char *bad)
{
    uint32_t idx = j->holder[msg->h.task - 1] & ~MASTER_VERIFY_HOLDER;
    ventry_t *e = &j->verify->pool[idx];
    uint32_t slot = (uint32_t)(w - m->workers) + 1;
    int k = 0;
    while (k < VERIFY_COPIES && !(e->c[k].slot == slot && e->c[k].attempt == msg->h.attempt))
        k++;
    if (k == VERIFY_COPIES)
        return -1;
    w->credit++; /* a result of a copy it holds returns the copy's credit */
    if (w->outstanding)
        w->outstanding--;
    if (msg->h.type == PROTO_TASK_FAILED) {
        peer_answered(m, w);
        copy_failed(m, w, j, idx, k, msg->u.text.text);
        return 0;
    }
    char err[VB_ERR_LEN];
    if (bad || sched_check(j->sched, e->task, msg->u.result.records, msg->u.result.count, err,
                           sizeof err) != SCHED_OK) {
        copy_refused(m, w, j, idx, k, bad ? bad : err);
        return 0;
    }
    lease_times_add(&j->times, master_now() - e->c[k].sent);
    peer_answered(m, w);
    peer_count_result(w, j, msg);
    copy_answered(m, j, idx, k, msg->u.result.records);
    return 0;
}

/* ---- losing copies ------------------------------------------------------------ */

void verify_lease_expired(master_t *m, job_t *j, size_t cell, const lease_t *l)
{
    uint32_t idx = j->holder[cell] & ~MASTER_VERIFY_HOLDER;
    ventry_t *e = &j->verify->pool[idx];
    for (int k = 0; k < VERIFY_COPIES; k++)
        if (e->c[k].slot == l->slot && e->c[k].attempt == l->attempt) {
            master_log(m,
                       "job %" PRIu64 " task %" PRIu64
                       ": lease of a copy ran out on %s; sending it again",
                       j->id, l->task, m->workers[l->slot - 1].host);
            peer_lease_lost(m, &m->workers[l->slot - 1]);
            release_copy(m, &e->c[k]); /* no credit back: it still works on it */
            j->reissued++;
            enqueue(j->verify, idx);
            return;
        }
}

uint32_t verify_peer_lost(master_t *m, job_t *j, uint32_t slot)
{
    (void)m;
    verify_job_t *v = j->verify;
    uint32_t back = 0;
    for (uint32_t idx = 0; v && idx < v->cap; idx++) {
        ventry_t *e = &v->pool[idx];
        if (!e->task)
            continue;
        for (int k = 0; k < VERIFY_COPIES; k++)
            if (e->c[k].slot == slot) {
                e->c[k].slot = 0; /* peer_lost zeroes the worker's counts */
                back++;
                enqueue(v, idx);
            }
    }
    j->reissued += back;
    return back;
}

void verify_release_all(master_t *m, job_t *j)
{
    verify_job_t *v = j->verify;
    for (uint32_t idx = 0; v && idx < v->cap; idx++)
        if (v->pool[idx].task)
            entry_close(m, j, idx);
    j->verify_waiting = 0;
    j->verify_waiting_for = 0;
    verify_free(j);
}

void verify_free(job_t *j)
{
    verify_job_t *v = j->verify;
    if (!v)
        return;
    for (uint32_t idx = 0; idx < v->cap; idx++)
        for (int k = 0; k < VERIFY_COPIES; k++)
            free(v->pool[idx].c[k].res);
    free(v->pool);
    free(v->queue);
    free(v);
    j->verify = NULL;
}

/* ---- periodic ------------------------------------------------------------------- */

/* One job's entries: answers of workers quarantined since are dropped,
 * entries that need a copy are queued, and those no connected worker may
 * take a copy of are counted (status) or, below share 1, merged on their
 * one answer. */
static void tick_job(master_t *m, job_t *j, const char **ids, uint32_t nid)
{
    uint32_t waiting = 0, waiting_for = 0;
    for (uint32_t idx = 0; j->verify && idx < j->verify->cap; idx++) {
        ventry_t *e = &j->verify->pool[idx];
        if (!e->task)
            continue;
        if (e->backup) { /* any worker but its holder may take a copy */
            if (needs_copy(e))
                enqueue(j->verify, idx);
            continue;
        }
        for (int k = 0; k < VERIFY_COPIES; k++)
            if (e->c[k].answered && peer_quarantined(m, e->c[k].who))
                forget_answer(&e->c[k]);
        if (!needs_copy(e))
            continue;
        enqueue(j->verify, idx);
        if (can_place(e, ids, nid))
            continue;
        if (m->cfg.verify_share < 1 && answered(e) == 1 && !held(e)) {
            int k = 0;
            while (!e->c[k].answered)
                k++;
            entry_merge(m, j, idx, e->c[k].res, MERGE_UNVERIFIED); /* may end the job */
            if (j->state != JOB_RUNNING)
                return;
            continue;
        }
        waiting++;
        waiting_for = wanted(e) > waiting_for ? wanted(e) : waiting_for;
    }
    j->verify_waiting = waiting;
    j->verify_waiting_for = waiting_for;
}

void verify_tick(master_t *m)
{
    const char *ids[VERIFY_COPIES + 1];
    uint32_t nid = alive_identities(m, ids, VERIFY_COPIES + 1);
    for (job_t *j = m->jobs; j; j = j->next)
        if (j->state == JOB_RUNNING && j->verify)
            tick_job(m, j, ids, nid);
}

/* ---- counting and status ---------------------------------------------------------- */

void verify_note_plain(master_t *m, job_t *j, uint64_t task_id)
{
    if (verify_selected(j->tracer.seed, task_id, m->cfg.verify_share))
        j->tasks_unverified++;
}

void verify_note_quarantined(job_t *j, const char *who)
{
    for (size_t i = 0; i < j->quarantined_n; i++)
        if (strcmp(j->quarantined[i], who) == 0)
            return;
    char(*q)[MASTER_MAX_WHO] = realloc(j->quarantined, (j->quarantined_n + 1) * sizeof *q);
    if (!q)
        return; /* out of memory: the master's log still names it */
    j->quarantined = q;
    snprintf(j->quarantined[j->quarantined_n++], sizeof q[0], "%s", who);
}

void verify_json(const job_t *j, cJSON *o)
{
    cJSON_AddNumberToObject(o, "tasks",
                            (double)sched_layer_count(j->sched) * sched_range_count(j->sched));
    cJSON_AddNumberToObject(o, "tasks_verified", (double)j->tasks_verified);
    cJSON_AddNumberToObject(o, "verify_mismatches", (double)j->verify_mismatches);
    cJSON_AddNumberToObject(o, "tasks_unverified", (double)j->tasks_unverified);
    cJSON *q = cJSON_AddArrayToObject(o, "quarantined");
    for (size_t i = 0; q && i < j->quarantined_n; i++)
        cJSON_AddItemToArray(q, cJSON_CreateString(j->quarantined[i]));
    if (j->verify_waiting) {
        cJSON_AddNumberToObject(o, "verify_waiting", j->verify_waiting);
        cJSON_AddStringToObject(o, "waiting_for",
                                j->verify_waiting_for >= 3 ? "a third worker" : "a second worker");
    }
}
