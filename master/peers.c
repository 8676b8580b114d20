/* peers.c - workers as the master sees them (master_priv.h): sending,
 * joining, losing them, their messages, and dispatch of ready tasks.
 *
 * A worker that goes silent, says BYE or cannot be reached loses its tasks,
 * which go back to the scheduler and out again with the next attempt
 * number. A message that cannot be encoded is its job's fault, not the
 * worker's: the job fails and the worker carries on.
 */
#include <errno.h>
#include <inttypes.h>
#include <stdlib.h>
#include <string.h>

#include "frames.h"
#include "master_priv.h"

/* All a worker may send in one message: its routing id (at most 255 bytes),
 * a header and the largest RESULT. ZMQ_MAXMSGSIZE bounds each part alone. */
#define WORKER_MSG_MAX_BYTES (256 + PROTO_HEADER_SIZE + PROTO_MAX_RESULT_PAYLOAD)

/* ---- sending ------------------------------------------------------------------ */

static int ensure_payload(master_t *m, size_t need)
{
    if (need <= m->payload_cap)
        return 0;
    uint8_t *p = realloc(m->payload, need);
    if (!p)
        return -1;
    m->payload = p;
    m->payload_cap = need;
    return 0;
}

/* Encodes msg into m->payload: its length, or -1 with a message. */
static long encode(master_t *m, proto_msg_t *msg, uint8_t header[PROTO_HEADER_SIZE], char *err,
                   size_t errlen)
{
    size_t need = proto_payload_size(msg);
    if (ensure_payload(m, need ? need : 1) < 0) {
        snprintf(err, errlen, "out of memory for a %zu-byte message", need);
        return -1;
    }
    return proto_encode(msg, header, m->payload, m->payload_cap, err, errlen);
}

static int send_frames(master_t *m, const uint8_t *id, size_t id_len, const uint8_t *header, long n)
{
    const void *parts[3] = {id, header, m->payload};
    const size_t sizes[3] = {id_len, PROTO_HEADER_SIZE, (size_t)n};
    if (proto_send(m->workers_sock, parts, sizes, 3, ZMQ_DONTWAIT) < 0)
        return SEND_UNREACHABLE;
    return SEND_OK;
}

int peer_send(master_t *m, peer_t *w, proto_msg_t *msg)
{
    uint8_t header[PROTO_HEADER_SIZE];
    char err[VB_ERR_LEN];
    long n = encode(m, msg, header, err, sizeof err);
    if (n < 0) {
        master_log(m, "cannot encode %s for job %" PRIu64 ": %s", proto_type_name(msg->h.type),
                   msg->h.job, err);
        return SEND_BAD_MESSAGE;
    }
    int rc = send_frames(m, w->id, w->id_len, header, n);
    if (rc == SEND_OK)
        w->last_sent = master_now();
    return rc;
}

/* To a peer that is not (or not yet) a worker: best effort. */
static void send_raw_to(master_t *m, const uint8_t *id, size_t id_len, proto_msg_t *msg)
{
    uint8_t header[PROTO_HEADER_SIZE];
    char err[VB_ERR_LEN];
    long n = encode(m, msg, header, err, sizeof err);
    if (n >= 0)
        (void)send_frames(m, id, id_len, header, n); /* a peer that left cannot be told */
}

static void send_text(master_t *m, const uint8_t *id, size_t id_len, int type, const char *text)
{
    char cut[PROTO_TEXT_MAX + 1]; /* a longer text is cut, not refused */
    snprintf(cut, sizeof cut, "%s", text);
    proto_msg_t msg = {.h.type = (uint16_t)type, .u.text.text = cut};
    send_raw_to(m, id, id_len, &msg);
}

/* ---- workers ------------------------------------------------------------------- */

static peer_t *find_peer(master_t *m, const uint8_t *id, size_t len)
{
    for (uint32_t i = 0; i < m->worker_count; i++)
        if (m->workers[i].alive && m->workers[i].id_len == len &&
            memcmp(m->workers[i].id, id, len) == 0)
            return &m->workers[i];
    return NULL;
}

/* Gives back every task the worker holds. */
void peer_lost(master_t *m, peer_t *w, const char *why)
{
    uint32_t slot = (uint32_t)(w - m->workers) + 1;
    uint32_t back = 0;
    for (job_t *j = m->jobs; j; j = j->next) {
        if (j->state != JOB_RUNNING || !j->holder)
            continue;
        back += verify_peer_lost(m, j, slot);
        size_t cells = (size_t)sched_layer_count(j->sched) * sched_range_count(j->sched);
        for (size_t c = 0; c < cells && j->outstanding > 0; c++)
            if (j->holder[c] == slot) {
                job_reissue(m, j, c);
                back++;
            }
    }
    master_log(m, "worker %s (%u threads) gone: %s; %u task%s issued again", w->host, w->threads,
               why, back, back == 1 ? "" : "s");
    w->alive = 0;
    w->credit = 0;
    w->outstanding = 0;
}

void peer_heartbeats(master_t *m, double now)
{
    for (uint32_t i = 0; i < m->worker_count; i++) {
        peer_t *w = &m->workers[i];
        if (!w->alive)
            continue;
        if (now - w->last_seen > m->cfg.worker_timeout_ms / 1000.0) {
            peer_lost(m, w, "silent");
            continue;
        }
        if (now - w->last_sent >= m->cfg.heartbeat_ms / 1000.0) {
            proto_msg_t hb = {.h.type = PROTO_HEARTBEAT};
            if (peer_send(m, w, &hb) == SEND_UNREACHABLE)
                peer_lost(m, w, "unreachable");
        }
    }
}

void peer_say_bye_all(master_t *m)
{
    /* so workers reconnect rather than wait out a timeout */
    for (uint32_t i = 0; i < m->worker_count; i++)
        if (m->workers[i].alive) {
            proto_msg_t bye = {.h.type = PROTO_BYE, .u.text.text = "master stopping"};
            (void)peer_send(m, &m->workers[i], &bye); /* leaving anyway */
        }
}

const char *peer_identity(const peer_t *w)
{
    return w->key[0] ? w->key : w->host;
}

int peer_quarantined(const master_t *m, const char *who)
{
    for (size_t i = 0; i < m->quarantine_n; i++)
        if (strcmp(m->quarantine[i], who) == 0)
            return 1;
    return 0;
}

static void quarantine_add(master_t *m, const char *who)
{
    if (!peer_quarantined(m, who)) {
        if (m->quarantine_n == m->quarantine_cap) {
            size_t cap = m->quarantine_cap ? 2 * m->quarantine_cap : 8;
            char(*q)[128] = realloc(m->quarantine, cap * sizeof *q);
            if (q) {
                m->quarantine = q;
                m->quarantine_cap = cap;
            }
        }
        if (m->quarantine_n < m->quarantine_cap)
            snprintf(m->quarantine[m->quarantine_n++], sizeof m->quarantine[0], "%s", who);
    }
}

void peer_quarantine(master_t *m, peer_t *w, const char *why)
{
    const char *who = peer_identity(w);
    quarantine_add(m, who);
    master_log(
        m, "worker %s quarantined: %s (refused until the master restarts or an admin readmits it)",
        who, why);
    char text[512];
    snprintf(text, sizeof text, "quarantined: %.400s", why);
    send_text(m, w->id, w->id_len, PROTO_REFUSE, text);
    peer_lost(m, w, "quarantined");
}

void peer_quarantine_identity(master_t *m, const char *who, const char *why)
{
    char id[MASTER_MAX_WHO];
    snprintf(id, sizeof id, "%s", who); /* who may live in a peer this drops */
    int connected = 0;
    for (uint32_t i = 0; i < m->worker_count; i++)
        if (m->workers[i].alive && strcmp(peer_identity(&m->workers[i]), id) == 0) {
            peer_quarantine(m, &m->workers[i], why);
            connected = 1;
        }
    if (!connected && !peer_quarantined(m, id)) {
        quarantine_add(m, id);
        master_log(
            m,
            "worker %s quarantined: %s (it had left; refused until the master restarts or an admin "
            "readmits it)",
            id, why);
    }
}

int peer_readmit(master_t *m, const char *who)
{
    for (size_t i = 0; i < m->quarantine_n; i++)
        if (strcmp(m->quarantine[i], who) == 0) {
            memmove(&m->quarantine[i], &m->quarantine[i + 1],
                    (m->quarantine_n - i - 1) * sizeof m->quarantine[0]);
            m->quarantine_n--;
            master_log(m, "worker %s readmitted", who);
            return 0;
        }
    return -1;
}

/* ---- bans and the circuit breaker ------------------------------------------------ */

/* A worker refused for a while: its identity, until when, and how many
 * times it has been banned (each ban doubles the last). */
typedef struct peer_ban {
    char who[MASTER_MAX_WHO];
    double until;
    uint32_t strikes;
} peer_ban_t;

static peer_ban_t *ban_find(master_t *m, const char *who)
{
    for (size_t i = 0; i < m->bans_n; i++)
        if (strcmp(m->bans[i].who, who) == 0)
            return &m->bans[i];
    return NULL;
}

double peer_banned_for(master_t *m, const char *who, double now)
{
    const peer_ban_t *b = ban_find(m, who);
    return b && b->until > now ? b->until - now : 0;
}

/* The entry for who, new or the one whose ban ended longest ago when the
 * list is full (MASTER_MAX_WORKERS identities); NULL when out of memory. */
static peer_ban_t *ban_entry(master_t *m, const char *who)
{
    peer_ban_t *b = ban_find(m, who);
    if (b)
        return b;
    if (m->bans_n == m->bans_cap && m->bans_cap < MASTER_MAX_WORKERS) {
        size_t cap = m->bans_cap ? 2 * m->bans_cap : 8;
        peer_ban_t *nb = realloc(m->bans, cap * sizeof *nb);
        if (nb) {
            m->bans = nb;
            m->bans_cap = cap;
        }
    }
    if (m->bans_n < m->bans_cap) {
        b = &m->bans[m->bans_n++];
    } else {
        if (m->bans_n == 0)
            return NULL;
        b = &m->bans[0];
        for (size_t i = 1; i < m->bans_n; i++)
            if (m->bans[i].until < b->until)
                b = &m->bans[i];
    }
    memset(b, 0, sizeof *b);
    snprintf(b->who, sizeof b->who, "%s", who);
    return b;
}

/* Drops the worker and refuses its identity for --ban-s, doubled on each
 * repeat up to MASTER_BAN_MAX_S. */
static void peer_ban(master_t *m, peer_t *w, const char *why)
{
    char who[MASTER_MAX_WHO];
    snprintf(who, sizeof who, "%s", peer_identity(w));
    double now = master_now(), len = m->cfg.ban_s;
    peer_ban_t *b = ban_entry(m, who);
    if (b) {
        for (uint32_t k = 0; k < b->strikes && len < MASTER_BAN_MAX_S; k++)
            len *= 2;
        len = len > MASTER_BAN_MAX_S ? MASTER_BAN_MAX_S : len;
        b->strikes++;
        b->until = now + len;
    }
    m->banned++;
    master_log(m, "worker %s banned for %.0f s (ban %u): %s", who, len, b ? b->strikes : 1, why);
    char text[512];
    snprintf(text, sizeof text, "banned for %.0f s: %.400s", len, why);
    send_text(m, w->id, w->id_len, PROTO_REFUSE, text);
    peer_lost(m, w, "banned");
}

void peer_bad_result(master_t *m, peer_t *w, job_t *j, uint64_t task, const char *err)
{
    m->malformed++;
    w->bad_results++;
    master_log_limited(m, "bad-result",
                       "job %" PRIu64 " task %" PRIu64
                       ": bad result %u from %s (a ban at %d): %s; the task is issued again",
                       j->id, task, w->bad_results, peer_identity(w), MASTER_MAX_BAD_RESULTS, err);
    if (w->bad_results >= MASTER_MAX_BAD_RESULTS) {
        char why[VB_ERR_LEN];
        snprintf(why, sizeof why, "%u results refused; the last: %.700s", w->bad_results, err);
        peer_ban(m, w, why);
    }
}

void peer_lease_lost(master_t *m, peer_t *w)
{
    if (++w->leases_lost == MASTER_BREAKER_LEASES)
        master_log(m,
                   "worker %s: %d leases ran out in a row; no new task for it until it answers "
                   "one",
                   w->host, MASTER_BREAKER_LEASES);
}

void peer_answered(master_t *m, peer_t *w)
{
    if (w->leases_lost >= MASTER_BREAKER_LEASES)
        master_log(m, "worker %s answered again; it gets tasks again", w->host);
    w->leases_lost = 0;
}

int peer_breaker_open(const peer_t *w)
{
    return w->leases_lost >= MASTER_BREAKER_LEASES;
}

void peer_bans_json(master_t *m, cJSON *arr, double now)
{
    for (size_t i = 0; arr && i < m->bans_n; i++) {
        if (!(m->bans[i].until > now))
            continue;
        cJSON *o = cJSON_CreateObject();
        cJSON_AddStringToObject(o, "worker", m->bans[i].who);
        cJSON_AddNumberToObject(o, "seconds_left", m->bans[i].until - now);
        cJSON_AddNumberToObject(o, "bans", m->bans[i].strikes);
        cJSON_AddItemToArray(arr, o);
    }
}

/* ---- dispatch ------------------------------------------------------------------- */

static peer_t *next_peer_with_credit(master_t *m, uint32_t from, uint32_t *slot)
{
    for (uint32_t k = 0; k < m->worker_count; k++) {
        uint32_t i = (from + k) % m->worker_count;
        if (m->workers[i].alive && m->workers[i].credit > 0 && !peer_breaker_open(&m->workers[i])) {
            *slot = i;
            return &m->workers[i];
        }
    }
    return NULL;
}

int peer_send_task(master_t *m, peer_t *w, job_t *j, const sched_task_t *t, proto_msg_t *msg,
                   uint32_t *attempt)
{
    size_t c = (size_t)(t->id - 1);
    memset(msg, 0, sizeof *msg);
    msg->h.type = PROTO_TASK;
    msg->h.job = j->id;
    msg->h.task = t->id;
    msg->h.attempt = *attempt = j->attempt[c] =
        j->attempt[c] ? j->attempt[c] + 1 : m->attempt_base + 1;
    memcpy(msg->u.task.scene_hash, j->hash, PROTO_HASH_SIZE);
    msg->u.task.settings = j->tracer;
    msg->u.task.layer = t->layer;
    msg->u.task.count = t->count;
    msg->u.task.records = t->records;
    int rc = peer_send(m, w, msg);
    m->tasks_issued += rc == SEND_OK;
    return rc;
}

/* Sends task t, just handed out by j's scheduler, to worker w (index i):
 * once, or when chosen, as the first copy of a verified task. 1, or -1
 * when out of memory. */
static int send_new(master_t *m, peer_t *w, uint32_t i, job_t *j, const sched_task_t *t,
                    proto_msg_t *msg, double now)
{
    if (verify_wanted(m, j, t->id))
        return verify_start(m, j, t, w, msg, now);
    size_t c = (size_t)(t->id - 1);
    uint32_t attempt;
    int rc = peer_send_task(m, w, j, t, msg, &attempt);
    if (rc == SEND_BAD_MESSAGE) {
        job_requeue(m, j, t->id);
        job_finish(m, j, JOB_FAILED, "a task of this job cannot be encoded (see the master's log)");
        return 1;
    }
    if (rc == SEND_UNREACHABLE) {
        job_requeue(m, j, t->id);
        peer_lost(m, w, "unreachable");
        return 1;
    }
    j->holder[c] = i + 1;
    j->sent_ms[c] = job_ms(j, now);
    job_lease(m, j, t->id, attempt, i + 1, now);
    j->outstanding++;
    w->outstanding++;
    w->credit--;
    master_log_at(m, VBLOG_DEBUG, "job %" PRIu64 " task %" PRIu64 " (attempt %u) issued to %s",
                  j->id, t->id, attempt, w->host);
    return 1;
}

/* Whether lease l of job j still names a copy out (plain or one of
 * several): a stale lease stays stale, attempts only grow. */
static int lease_live(const job_t *j, const lease_t *l)
{
    size_t c = (size_t)(l->task - 1);
    if (verify_holds(j, c))
        return verify_copy_live(j, c, l->slot, l->attempt);
    return j->holder[c] == l->slot && j->attempt[c] == l->attempt;
}

/* A backup copy for worker w (slot + 1 = its index + 1) of the task of j
 * that has been out longest, if that is more than --backup-factor task
 * times: MapReduce's answer to stragglers. Only a task sent once qualifies
 * (a task out as several copies has its own rules, verify.c); one that w
 * itself holds sets *blocked, so that dispatch offers it to the next
 * worker. 1 if a copy was sent or tried, 0 if none qualifies. */
static int send_backup(master_t *m, peer_t *w, job_t *j, proto_msg_t *msg, double now, int *blocked)
{
    double task_s = job_task_seconds(j);
    if (!(m->cfg.backup_factor > 0) || !(task_s > 0))
        return 0;
    double before = now - m->cfg.backup_factor * task_s;
    uint32_t slot = (uint32_t)(w - m->workers) + 1;
    size_t k = 0;
    for (const lease_t *l; (l = lease_at(j->leases, k)) && l->sent < before;) {
        size_t c = (size_t)(l->task - 1);
        if (!lease_live(j, l)) {
            if (k == 0)
                lease_pop(j->leases); /* stale for good: off the head */
            else
                k++;
            continue;
        }
        if (verify_holds(j, c)) {
            k++; /* a backup is out already, or it is being verified */
            continue;
        }
        if (l->slot == slot) {
            *blocked = 1;
            k++;
            continue;
        }
        return verify_backup(m, j, c, w, msg, now);
    }
    return 0;
}

/* Hands worker w (index i) the oldest running job's next ready task,
 * starting queued jobs as it goes; a job with none ready and a straggler
 * out gets a backup copy of it instead. 1 if something was sent or tried,
 * 0 if nothing suits w (*blocked: something might suit another worker),
 * -1 when out of memory. */
static int dispatch_new(master_t *m, peer_t *w, uint32_t i, proto_msg_t *msg, double now,
                        int *blocked)
{
    for (job_t *j = m->jobs; j; j = j->next) {
        if (j->state == JOB_QUEUED) {
            j->state = JOB_RUNNING;
            j->started = now;
            master_log(m, "job %" PRIu64 " started: %s %ux%u, %u spp, G %u, adaptive %s", j->id,
                       j->name, j->width, j->height, j->spp, j->granularity,
                       sched_adaptive_name(j->adaptive));
        }
        if (j->state != JOB_RUNNING || verify_saturated(j))
            continue;
        sched_task_t t;
        /* past its time limit a job takes no new task, but its last ones
         * may still get backups */
        if (!j->stopped_issuing && sched_next(j->sched, &t) == SCHED_NEXT_TASK)
            return send_new(m, w, i, j, &t, msg, now);
        int rc = send_backup(m, w, j, msg, now, blocked);
        if (rc != 0)
            return rc;
    }
    return 0;
}

/* Hands ready tasks to workers with credit, one task per worker in turn
 * (round robin from the worker after the last one served), so a trickle of
 * ready tasks spreads over all workers instead of filling the first. Copies
 * waiting for verification go first. A worker given nothing ends the round
 * unless copies wait or a backup it may not run (its own task) may suit the
 * next worker: then the round goes on until it comes back to it. */
void dispatch(master_t *m)
{
    double now = master_now();
    proto_msg_t msg; /* scratch for every task sent */
    uint32_t from = m->rr, first_miss = UINT32_MAX;
    for (;;) {
        uint32_t i = 0;
        int blocked = 0;
        peer_t *w = next_peer_with_credit(m, from, &i);
        if (!w || i == first_miss)
            break;
        int rc = verify_dispatch_copy(m, w, &msg, now);
        if (rc == 0)
            rc = dispatch_new(m, w, i, &msg, now, &blocked);
        if (rc < 0)
            break;
        from = i + 1;
        if (rc > 0) {
            m->rr = from;
            first_miss = UINT32_MAX;
        } else if (!blocked && !verify_copies_waiting(m)) {
            break;
        } else if (first_miss == UINT32_MAX) {
            first_miss = i;
        }
    }
}

/* ---- worker messages ------------------------------------------------------------- */

static void on_task_failed(master_t *m, peer_t *w, job_t *j, size_t c, const char *text)
{
    j->holder[c] = 0;
    j->outstanding--;
    w->outstanding--;
    j->failures++;
    master_log_limited(m, "task-failed", "job %" PRIu64 " task %zu failed on %s: %s", j->id, c + 1,
                       w->host, text);
    if (j->failures >= MASTER_MAX_TASK_FAILURES) {
        char why[VB_ERR_LEN];
        snprintf(why, sizeof why, "workers failed %u tasks; last: %.400s", j->failures, text);
        job_finish(m, j, JOB_FAILED, why);
    } else {
        j->reissued++;
        w->tasks_reissued++;
        job_requeue(m, j, (uint64_t)c + 1); /* outstanding until now: taken back */
    }
}

/* The most tasks a worker may hold or be owed: what an honest worker of
 * its size asks for. */
static uint32_t credit_cap(const peer_t *w)
{
    uint64_t cap = (uint64_t)PROTO_CREDIT_PER_THREAD * (w->threads ? w->threads : 1);
    return cap > PROTO_MAX_CREDIT ? PROTO_MAX_CREDIT : (uint32_t)cap;
}

/* A result that matches no task the worker holds: late (its task was taken
 * back, which returns the credit) or made up (which returns nothing, so
 * results cannot forge credit). */
static void unmatched_result(master_t *m, peer_t *w, job_t *j)
{
    if (w->owed > 0) {
        w->owed--;
        w->credit++;
        peer_answered(m, w); /* late, but an answer: the breaker closes */
    }
    if (j)
        j->late_results++;
    m->dropped_late++;
}

/* A malformed RESULT that answers no task its sender holds: dropped. */
static void malformed_result(master_t *m, const char *why)
{
    m->malformed++;
    master_log_limited(m, "malformed", "dropped a malformed RESULT (%" PRIu64 " so far): %s",
                       m->malformed, why);
}

/* An answer of w that matches no task it holds: malformed (bad: why), or
 * late or made up (unmatched_result). */
static void unheld_result(master_t *m, peer_t *w, job_t *j, const char *bad)
{
    if (bad)
        malformed_result(m, bad);
    else
        unmatched_result(m, w, j);
}

/* A RESULT or TASK_FAILED from w; bad (not NULL): a RESULT whose header
 * decoded but whose payload did not, with what is wrong. A bad result for
 * a task w holds hands the task back at once, with a new attempt. */
static void on_result(master_t *m, peer_t *w, proto_msg_t *msg, const char *bad)
{
    job_t *j = job_find(m, msg->h.job);
    if (!j || j->state != JOB_RUNNING || !j->holder) {
        unheld_result(m, w, NULL, bad);
        return;
    }
    uint64_t id = msg->h.task;
    size_t cells = (size_t)sched_layer_count(j->sched) * sched_range_count(j->sched);
    uint32_t slot = (uint32_t)(w - m->workers) + 1;
    if (id != 0 && id <= cells && verify_holds(j, id - 1)) {
        if (verify_on_result(m, w, j, msg, bad) < 0)
            unheld_result(m, w, j, bad);
        return;
    }
    if (id == 0 || id > cells || j->holder[id - 1] != slot ||
        j->attempt[id - 1] != msg->h.attempt) {
        unheld_result(m, w, j, bad);
        return;
    }
    w->credit++; /* a result of a task it holds returns the task's credit */
    size_t c = (size_t)(id - 1);
    if (msg->h.type == PROTO_TASK_FAILED) {
        peer_answered(m, w);
        on_task_failed(m, w, j, c, msg->u.text.text);
        return;
    }
    char err[VB_ERR_LEN];
    int rc = bad ? SCHED_BAD_RESULT
                 : sched_complete(j->sched, id, msg->u.result.records, msg->u.result.count, err,
                                  sizeof err);
    j->holder[c] = 0;
    j->outstanding--;
    w->outstanding--;
    if (rc < 0) {
        /* a result that does not fit its task: dropped, the task issued
         * again at once, and counted against the worker */
        j->reissued++;
        w->tasks_reissued++;
        job_requeue(m, j, id); /* still outstanding: nothing was merged */
        peer_bad_result(m, w, j, id, bad ? bad : err);
        return;
    }
    persist_note(m, j, id, msg->u.result.records, msg->u.result.count);
    double now = master_now();
    lease_times_add(&j->times, now - (j->epoch + j->sent_ms[c] / 1000.0));
    peer_answered(m, w);
    peer_count_result(w, j, msg);
    master_log_at(m, VBLOG_DEBUG, "job %" PRIu64 " task %" PRIu64 " merged from %s", j->id, id,
                  w->host);
    verify_note_plain(m, j, id);
    job_merged(m, j);
}

void peer_count_result(peer_t *w, job_t *j, const proto_msg_t *msg)
{
    j->rays += msg->u.result.rays;
    j->busy_us += msg->u.result.busy_us;
    w->rays += msg->u.result.rays;
    w->busy_us += msg->u.result.busy_us;
    w->tasks_done++;
    for (uint32_t i = 0; i < msg->u.result.count; i++)
        w->samples += msg->u.result.records[i].samples + msg->u.result.records[i].nonfinite;
}

static void on_hello(master_t *m, const uint8_t *id, size_t id_len, const char *host,
                     const char *key, proto_msg_t *msg)
{
    double banned = peer_banned_for(m, key && *key ? key : host, master_now());
    if (banned > 0) {
        char text[160];
        snprintf(text, sizeof text, "banned for another %.0f s: this worker's results were refused",
                 banned);
        master_log_limited(m, "banned", "refused banned worker %s (%.0f s left)",
                           key && *key ? key : host, banned);
        send_text(m, id, id_len, PROTO_REFUSE, text);
        return;
    }
    if (peer_quarantined(m, key && *key ? key : host)) {
        master_log_limited(m, "quarantined", "refused quarantined worker %s",
                           key && *key ? key : host);
        send_text(m, id, id_len, PROTO_REFUSE,
                  "quarantined: this worker's results were refused (an admin can "
                  "readmit it: vbrender readmit)");
        return;
    }
    if (strcmp(msg->u.hello.build, m->build) != 0) {
        char text[512];
        snprintf(text, sizeof text,
                 "build mismatch: master is %s, worker is %s (they could trace different bits)",
                 m->build, msg->u.hello.build);
        master_log_limited(m, "refused", "refused worker %s: %s", host, text);
        send_text(m, id, id_len, PROTO_REFUSE, text);
        return;
    }
    peer_t *w = find_peer(m, id, id_len);
    if (w) /* a reconnect with the same identity: forget its old tasks */
        peer_lost(m, w, "said hello again");
    uint32_t slot = m->worker_count;
    for (uint32_t i = 0; i < m->worker_count; i++)
        if (!m->workers[i].alive && m->workers[i].outstanding == 0) {
            slot = i;
            break;
        }
    if (slot == m->worker_count) {
        if (m->worker_count == MASTER_MAX_WORKERS) {
            char text[64];
            snprintf(text, sizeof text, "too many workers (%d)", MASTER_MAX_WORKERS);
            send_text(m, id, id_len, PROTO_REFUSE, text);
            return;
        }
        m->worker_count++;
    }
    w = &m->workers[slot];
    memset(w, 0, sizeof *w);
    memcpy(w->id, id, id_len);
    w->id_len = id_len;
    snprintf(w->host, sizeof w->host, "%s", host);
    snprintf(w->key, sizeof w->key, "%s", key ? key : "");
    snprintf(w->build, sizeof w->build, "%s", msg->u.hello.build);
    w->threads = msg->u.hello.threads;
    w->joined = w->last_seen = master_now();
    w->alive = 1;
    proto_msg_t reply;
    memset(&reply, 0, sizeof reply);
    reply.h.type = PROTO_WELCOME;
    reply.u.welcome.heartbeat_ms = m->cfg.heartbeat_ms;
    reply.u.welcome.lease_ms = m->cfg.lease_ms;
    master_log(m, "worker %s joined: %u threads, %s", w->host, w->threads, w->build);
    if (peer_send(m, w, &reply) == SEND_UNREACHABLE)
        peer_lost(m, w, "unreachable");
}

static void on_scene_request(master_t *m, peer_t *w, proto_msg_t *msg)
{
    job_t *j = job_find_by_hash(m, msg->u.scene_hash);
    if (!j) {
        master_log_limited(m, "unknown-scene", "worker %s asked for an unknown scene", w->host);
        return;
    }
    proto_mesh_file_t *meshes = calloc(PROTO_MAX_MESHES, sizeof *meshes);
    if (!meshes)
        return;
    proto_msg_t b = {.h.type = PROTO_SCENE_BUNDLE, .h.job = j->id};
    memcpy(b.u.bundle.hash, j->hash, PROTO_HASH_SIZE);
    b.u.bundle.json = j->json;
    b.u.bundle.json_size = (uint32_t)j->json_size;
    b.u.bundle.mesh_count = j->mesh_count;
    b.u.bundle.meshes = meshes;
    for (uint32_t i = 0; i < j->mesh_count; i++) {
        memcpy(meshes[i].name, j->mesh_names[i], sizeof meshes[i].name);
        meshes[i].data = j->mesh_data[i];
        meshes[i].size = j->mesh_sizes[i];
    }
    int rc = peer_send(m, w, &b);
    free(meshes);
    if (rc == SEND_BAD_MESSAGE)
        job_finish(m, j, JOB_FAILED,
                   "its scene bundle cannot be encoded for workers (see the master's log)");
    else if (rc == SEND_UNREACHABLE)
        peer_lost(m, w, "unreachable");
}

static void on_message(master_t *m, const uint8_t *id, size_t id_len, proto_msg_t *msg,
                       const char *bad)
{
    peer_t *w = find_peer(m, id, id_len);
    if (!w) {
        if (bad) {
            malformed_result(m, bad);
        } else if (msg->h.type == PROTO_RESULT || msg->h.type == PROTO_TASK_FAILED) {
            /* from a worker dropped meanwhile (silent, partitioned): its
             * tasks went out again, so this result is late */
            job_t *j = job_find(m, msg->h.job);
            if (j)
                j->late_results++;
            m->dropped_late++;
        }
        /* e.g. the master restarted: tell the worker to start over */
        send_text(m, id, id_len, PROTO_BYE, "unknown worker: say HELLO first");
        return;
    }
    w->last_seen = master_now();
    if (bad) {
        on_result(m, w, msg, bad);
        return;
    }
    switch (msg->h.type) {
    case PROTO_CREDIT: {
        /* credit, tasks held and tasks owed never exceed what a worker of
         * its size asks for: re-sent CREDIT cannot hoard tasks */
        uint64_t have = (uint64_t)w->credit + w->outstanding + w->owed, cap = credit_cap(w);
        uint64_t add = have >= cap ? 0 : cap - have;
        w->credit += (uint32_t)(msg->u.credit < add ? msg->u.credit : add);
        break;
    }
    case PROTO_SCENE_REQUEST:
        on_scene_request(m, w, msg);
        break;
    case PROTO_RESULT:
    case PROTO_TASK_FAILED:
        on_result(m, w, msg, NULL);
        break;
    case PROTO_HEARTBEAT:
        break;
    case PROTO_BYE:
        peer_lost(m, w, "said bye");
        break;
    default:
        m->malformed++;
        master_log_limited(m, "out-of-protocol", "dropped an out-of-protocol %s from worker %s",
                           proto_type_name(msg->h.type), w->host);
        break;
    }
}

/* A message that is not [identity][header][payload]: counted, dropped. */
static int frames_malformed(master_t *m, const proto_frames_t *fr, proto_recv_result_t rc)
{
    if (rc == PROTO_RECV_OK && fr->count == 3)
        return 0;
    m->malformed++;
    if (rc == PROTO_RECV_TOO_BIG)
        master_log_limited(m, "frames", "dropped a worker message of %zu bytes", fr->bytes);
    else
        master_log_limited(m, "frames", "dropped a worker message with %s frames",
                           rc == PROTO_RECV_TOO_MANY ? "too many" : "too few");
    return 1;
}

void peer_handle_message(master_t *m)
{
    proto_frames_t fr;
    proto_recv_result_t got =
        proto_recv(m->workers_sock, &fr, 3, WORKER_MSG_MAX_BYTES, ZMQ_DONTWAIT);
    if (frames_malformed(m, &fr, got)) {
        proto_frames_close(&fr);
        return;
    }
    char host[64];
    const char *peer = zmq_msg_gets(&fr.part[1], "Peer-Address");
    snprintf(host, sizeof host, "%s", peer ? peer : "local");
    const uint8_t *id = zmq_msg_data(&fr.part[0]);
    size_t id_len = zmq_msg_size(&fr.part[0]);
    /* results only: a worker sends no bundle or task, so none is stored */
    proto_records_t recs = {.results = m->results, .result_capacity = PROTO_MAX_TASK_PIXELS};
    proto_msg_t msg;
    msg.h.type = 0; /* proto_decode sets it once the header is read */
    char err[VB_ERR_LEN];
    int rc = proto_frames_decode(&fr, 1, &msg, &recs, err, sizeof err);
    if (!master_peer_allowed(m, AUTH_DOMAIN_WORKERS, &fr.part[1])) {
        /* its key left --allow-workers (SIGHUP) while it was connected */
        peer_t *w = find_peer(m, id, id_len);
        master_log_limited(m, "worker-key-revoked",
                           "refused a message from worker %s: key %s no longer allowed", host,
                           master_peer_key(&fr.part[1]));
        if (w)
            peer_lost(m, w, "key no longer allowed");
        send_text(m, id, id_len, PROTO_REFUSE,
                  "this worker's key is no longer allowed by the master");
    } else if (rc == -2) { /* another protocol version or magic */
        char text[VB_ERR_LEN + 32];
        snprintf(text, sizeof text, "master refuses: %s", err);
        m->malformed++;
        master_log_limited(m, "refused", "refused a peer: %s", err);
        send_text(m, id, id_len, PROTO_REFUSE, text);
    } else if (rc < 0 && msg.h.type == PROTO_RESULT) {
        /* its header decoded (proto_decode fills it first), its records did
         * not: a bad answer to a task its sender may hold */
        on_message(m, id, id_len, &msg, err);
    } else if (rc < 0) {
        m->malformed++;
        master_log_limited(m, "malformed",
                           "dropped a malformed worker message (%" PRIu64 " so far): %s",
                           m->malformed, err);
    } else if (msg.h.type == PROTO_HELLO) {
        const char *key = zmq_msg_gets(&fr.part[1], "User-Id");
        on_hello(m, id, id_len, host, key, &msg);
    } else {
        on_message(m, id, id_len, &msg, NULL);
    }
    proto_frames_close(&fr);
}
