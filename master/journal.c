/* journal.c - see journal.h. */
#include "journal.h"

#include <errno.h>
#include <fcntl.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "le.h"
#include "store.h"
#include "vberr.h"

static const char journal_magic[8] = {'V', 'B', 'J', 'R', 'N', 'L', '1', '\n'};

/* A growable byte buffer. */
typedef struct jbuf {
    uint8_t *data;
    size_t len, cap;
} jbuf_t;

struct journal {
    uint64_t job, generation, seq; /* seq: the next commit's */
    uint32_t flags;
    int failed;
    jbuf_t pend; /* unsealed tasks */
    jbuf_t out;  /* framed commits not yet written */
};

static int reserve(jbuf_t *b, size_t more)
{
    if (b->cap - b->len >= more)
        return 0;
    size_t cap = b->cap ? b->cap : 4096;
    while (cap - b->len < more) {
        if (cap > SIZE_MAX / 2)
            return -1;
        cap *= 2;
    }
    uint8_t *nd = realloc(b->data, cap);
    if (!nd)
        return -1;
    b->data = nd;
    b->cap = cap;
    return 0;
}

/* The record checksum: store.h's 256 bits folded to 64. All four words:
 * each mixes only two of the sum's four lanes (a byte feeds one lane), so
 * the first alone missed a change in half the bytes
 * (test_store's journal_round_trip flips one in each lane). */
static uint64_t record_sum(const uint8_t *head, const uint8_t *payload, size_t len)
{
    store_sum_t c;
    store_sum_init(&c);
    store_sum_update(&c, head, 12);
    store_sum_update(&c, payload, len);
    uint8_t out[32];
    store_sum_final(&c, out);
    return le_get_u64(out) ^ le_get_u64(out + 8) ^ le_get_u64(out + 16) ^ le_get_u64(out + 24);
}

/* ---- writing -------------------------------------------------------------------- */

journal_t *journal_new(uint64_t job, uint64_t generation, uint32_t flags)
{
    journal_t *j = calloc(1, sizeof *j);
    if (!j)
        return NULL;
    j->job = job;
    j->generation = generation;
    j->flags = flags;
    j->seq = 1;
    return j;
}

void journal_destroy(journal_t **jp)
{
    if (!jp || !*jp)
        return;
    free((*jp)->pend.data);
    free((*jp)->out.data);
    free(*jp);
    *jp = NULL;
}

uint64_t journal_generation(const journal_t *j)
{
    return j->generation;
}

uint32_t journal_flags(const journal_t *j)
{
    return j->flags;
}

uint64_t journal_next_seq(const journal_t *j)
{
    return j->seq;
}

int journal_failed(const journal_t *j)
{
    return j->failed;
}

size_t journal_pending(const journal_t *j)
{
    return j->pend.len;
}

size_t journal_unwritten(const journal_t *j)
{
    return j->out.len;
}

size_t journal_pixel_size(uint32_t flags)
{
    return JOURNAL_PIXEL_SIZE + (flags & JOURNAL_NF8 ? 1 : 2) +
           (flags & JOURNAL_RAYS ? JOURNAL_RAYS_SIZE : 0) +
           (flags & JOURNAL_PVAR ? JOURNAL_PVAR_SIZE : 0);
}

int journal_note(journal_t *j, uint64_t task_id, const tracer_result_t *r, uint32_t count)
{
    if (j->failed)
        return -1;
    const size_t px = journal_pixel_size(j->flags);
    if (reserve(&j->pend, JOURNAL_TASK_HEADER + (size_t)count * px) < 0) {
        j->failed = 1;
        return -1;
    }
    uint8_t *p = j->pend.data + j->pend.len;
    p = le_put_u64(p, task_id);
    p = le_put_u32(p, count);
    for (uint32_t i = 0; i < count; i++) {
        for (int c = 0; c < 3; c++)
            p = le_put_f64(p, r[i].sum[c]);
        p = le_put_f64(p, r[i].lum_m2);
        /* at most the task's samples (sched_complete checked it): with
         * JOURNAL_NF8, G <= 255 */
        if (j->flags & JOURNAL_NF8)
            *p++ = (uint8_t)r[i].nonfinite;
        else
            p = le_put_u16(p, (uint16_t)r[i].nonfinite);
        if (j->flags & JOURNAL_RAYS)
            p = le_put_u32(p, r[i].rays);
        if (j->flags & JOURNAL_PVAR)
            p = le_put_f64(p, r[i].pvar);
    }
    j->pend.len = (size_t)(p - j->pend.data);
    return 0;
}

int journal_seal(journal_t *j, const char *extras, size_t extras_len)
{
    if (j->failed)
        return -1;
    size_t plen = 8 + j->pend.len + extras_len;
    if (plen > JOURNAL_MAX_PAYLOAD || reserve(&j->out, JOURNAL_RECORD_OVERHEAD + plen) < 0)
        return -1;
    uint8_t *head = j->out.data + j->out.len;
    uint8_t *p = le_put_u32(head, (uint32_t)plen);
    p = le_put_u64(p, j->seq);
    uint8_t *payload = p;
    p = le_put_u64(p, j->pend.len);
    if (j->pend.len)
        memcpy(p, j->pend.data, j->pend.len);
    p += j->pend.len;
    if (extras_len)
        memcpy(p, extras, extras_len);
    p += extras_len;
    p = le_put_u64(p, record_sum(head, payload, plen));
    j->out.len = (size_t)(p - j->out.data);
    j->pend.len = 0;
    j->seq++;
    return 0;
}

void journal_take_unwritten(journal_t *j, uint8_t **data, size_t *len)
{
    *data = j->out.data;
    *len = j->out.len;
    memset(&j->out, 0, sizeof j->out);
}

void journal_give_back(journal_t *j, uint8_t *data, size_t len)
{
    /* nothing is sealed while a write is out (persist.c), so out is empty */
    if (j->out.len == 0) {
        free(j->out.data);
        j->out.data = data;
        j->out.len = len;
        j->out.cap = len;
        return;
    }
    if (reserve(&j->out, len) < 0) {
        free(data);
        j->failed = 1;
        return;
    }
    memmove(j->out.data + len, j->out.data, j->out.len);
    memcpy(j->out.data, data, len);
    j->out.len += len;
    free(data);
}

void journal_restart(journal_t *j, uint64_t generation, size_t keep_from)
{
    if (keep_from > j->pend.len)
        keep_from = j->pend.len;
    memmove(j->pend.data, j->pend.data + keep_from, j->pend.len - keep_from);
    j->pend.len -= keep_from;
    j->out.len = 0;
    j->generation = generation;
    j->seq = 1;
}

void journal_set_next_seq(journal_t *j, uint64_t seq)
{
    j->seq = seq;
}

void journal_header_encode(const journal_header_t *h, uint8_t out[JOURNAL_HEADER_SIZE])
{
    memcpy(out, journal_magic, 8);
    uint8_t *p = le_put_u32(out + 8, h->version);
    p = le_put_u32(p, h->flags);
    p = le_put_u64(p, h->generation);
    le_put_u64(p, h->job);
}

int journal_create(const char *path, const journal_header_t *h, char *err, size_t errlen)
{
    char tmp[4096 + 32], dir[4096];
    snprintf(tmp, sizeof tmp, "%s.tmp.%ld", path, (long)getpid());
    uint8_t head[JOURNAL_HEADER_SIZE];
    journal_header_encode(h, head);
    int fd = open(tmp, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
    if (fd < 0) {
        vberr_set(err, errlen, "cannot create %.600s: %s", tmp, strerror(errno));
        return -1;
    }
    ssize_t n;
    do
        n = write(fd, head, sizeof head);
    while (n < 0 && errno == EINTR);
    if (n != (ssize_t)sizeof head || (fsync(fd) != 0 && errno != EINVAL && errno != EROFS)) {
        vberr_set(err, errlen, "%.600s: write failed: %s", tmp, n < 0 ? strerror(errno) : "short");
        (void)close(fd); /* abandoned: the failure is reported */
        (void)unlink(tmp);
        return -1;
    }
    if (close(fd) != 0 || rename(tmp, path) != 0) {
        vberr_set(err, errlen, "cannot put %.600s into place: %s", path, strerror(errno));
        (void)unlink(tmp);
        return -1;
    }
    snprintf(dir, sizeof dir, "%s", path);
    char *slash = strrchr(dir, '/');
    if (slash)
        *slash = '\0';
    int dfd = open(slash ? dir : ".", O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    int rc = dfd >= 0 ? fsync(dfd) : -1;
    int saved = errno;
    if (dfd >= 0)
        (void)close(dfd); /* only read from */
    if (rc != 0 && saved != EINVAL && saved != EROFS) {
        vberr_set(err, errlen, "cannot fsync the directory of %.600s: %s", path, strerror(saved));
        return -1;
    }
    return 0;
}

/* ---- reading -------------------------------------------------------------------- */

int journal_reader_init(journal_reader_t *r, const uint8_t *data, size_t size, char *err,
                        size_t errlen)
{
    memset(r, 0, sizeof *r);
    if (size < JOURNAL_HEADER_SIZE) {
        vberr_set(err, errlen, "torn header (%zu bytes)", size);
        return -1;
    }
    if (memcmp(data, journal_magic, 8) != 0) {
        vberr_set(err, errlen, "not a vbrender journal (bad magic)");
        return -1;
    }
    r->header.version = le_get_u32(data + 8);
    r->header.flags = le_get_u32(data + 12);
    r->header.generation = le_get_u64(data + 16);
    r->header.job = le_get_u64(data + 24);
    if (r->header.version != JOURNAL_VERSION) {
        vberr_set(err, errlen, "journal format version %u, this master reads %d", r->header.version,
                  JOURNAL_VERSION);
        return -1;
    }
    if (r->header.flags & ~(uint32_t)(JOURNAL_PVAR | JOURNAL_RAYS | JOURNAL_NF8)) {
        vberr_set(err, errlen, "unknown flags 0x%x", r->header.flags);
        return -1;
    }
    r->data = data;
    r->size = size;
    r->pos = JOURNAL_HEADER_SIZE;
    return 0;
}

int journal_next(journal_reader_t *r, journal_commit_t *c, char *err, size_t errlen)
{
    size_t left = r->size - r->pos;
    if (left == 0)
        return 0;
    const uint8_t *head = r->data + r->pos;
    if (left < JOURNAL_RECORD_OVERHEAD) {
        vberr_set(err, errlen, "torn record (%zu bytes)", left);
        return -1;
    }
    uint64_t plen = le_get_u32(head), seq = le_get_u64(head + 4);
    if (plen < 8 || plen > JOURNAL_MAX_PAYLOAD || plen > left - JOURNAL_RECORD_OVERHEAD) {
        vberr_set(err, errlen,
                  plen > left - JOURNAL_RECORD_OVERHEAD && plen >= 8
                      ? "torn record (length %llu, %zu bytes left)"
                      : "bad length %llu (%zu bytes left)",
                  (unsigned long long)plen, left);
        return -1;
    }
    const uint8_t *payload = head + 12;
    if (record_sum(head, payload, (size_t)plen) != le_get_u64(payload + plen)) {
        vberr_set(err, errlen, "corrupt record (checksum mismatch)");
        return -1;
    }
    if (seq != r->seq + 1) {
        vberr_set(err, errlen, "record %llu out of sequence (after %llu)", (unsigned long long)seq,
                  (unsigned long long)r->seq);
        return -1;
    }
    uint64_t tlen = le_get_u64(payload);
    if (tlen > plen - 8) {
        vberr_set(err, errlen, "record %llu: tasks of %llu bytes in a payload of %llu",
                  (unsigned long long)seq, (unsigned long long)tlen, (unsigned long long)plen);
        return -1;
    }
    c->seq = seq;
    c->tasks = payload + 8;
    c->tasks_len = (size_t)tlen;
    c->extras = (const char *)payload + 8 + tlen;
    c->extras_len = (size_t)(plen - 8 - tlen);
    r->pos += JOURNAL_RECORD_OVERHEAD + (size_t)plen;
    r->seq = seq;
    return 1;
}

void journal_tasks_init(journal_tasks_t *it, const journal_commit_t *c, uint32_t flags)
{
    it->p = c->tasks;
    it->end = c->tasks + c->tasks_len;
    it->flags = flags;
}

int journal_task_next(journal_tasks_t *it, uint64_t *task_id, uint32_t *count,
                      const uint8_t **records)
{
    size_t left = (size_t)(it->end - it->p);
    if (left == 0)
        return 0;
    if (left < JOURNAL_TASK_HEADER)
        return -1;
    *task_id = le_get_u64(it->p);
    *count = le_get_u32(it->p + 8);
    const size_t px = journal_pixel_size(it->flags);
    left -= JOURNAL_TASK_HEADER;
    if (*count > left / px)
        return -1;
    *records = it->p + JOURNAL_TASK_HEADER;
    it->p += JOURNAL_TASK_HEADER + (size_t)*count * px;
    return 1;
}

int journal_result(const uint8_t *records, uint32_t i, uint32_t flags, const tracer_task_t *task,
                   tracer_result_t *out)
{
    const uint8_t *p = records + (size_t)i * journal_pixel_size(flags);
    memset(out, 0, sizeof *out);
    for (int c = 0; c < 3; c++)
        out->sum[c] = le_get_f64(p + 8 * c);
    out->lum_m2 = le_get_f64(p + 24);
    p += JOURNAL_PIXEL_SIZE;
    if (flags & JOURNAL_NF8) {
        out->nonfinite = *p++;
    } else {
        out->nonfinite = le_get_u16(p);
        p += 2;
    }
    /* without JOURNAL_RAYS nothing the replay merges reads them but the
     * check that each sample traced at least its camera ray */
    out->rays = task->sample_count;
    if (flags & JOURNAL_RAYS) {
        out->rays = le_get_u32(p);
        p += JOURNAL_RAYS_SIZE;
    }
    if (flags & JOURNAL_PVAR)
        out->pvar = le_get_f64(p);
    if (out->nonfinite > task->sample_count)
        return -1;
    out->pixel = task->pixel;
    out->samples = task->sample_count - out->nonfinite;
    return 0;
}
