/* store.c - see store.h. */
#define _GNU_SOURCE /* O_DIRECT */
#include "store.h"

#include <assert.h>

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <signal.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/time.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "le.h"

static const char store_magic[8] = {'V', 'B', 'S', 'T', 'A', 'T', 'E', '\n'};
#define STORE_HEADER_SIZE 16
#define STORE_SUM_SIZE 32 /* the checksum, 256 bits */
#define STORE_TRAILER_SIZE (8 + STORE_SUM_SIZE)
/* check_record's reasons: short texts of its own, not a passed-on message */
#define STORE_REASON_LEN 128
/* A record larger than this is refused on load (a torn length field must
 * not make us allocate the address space). */
#define STORE_MAX_RECORD ((uint64_t)8 << 30)
/* The background writer's report buffer: its first size, and the room a
 * read wants (it grows by doubling). */
#define STORE_BG_BUF0 8192
#define STORE_BG_READ_ROOM 4096
#define STORE_BG_WAIT_US 2000 /* store_bg_wait polls the child this often */

struct store {
    char dir[2048];
    uint64_t next_id;
    uint32_t boots;
    pid_t bg_pid;
    int bg_fd;    /* read end of the child's report pipe */
    char *bg_buf; /* what the child reported so far */
    size_t bg_len, bg_cap;
    double bg_started, bg_fork_ms;
    store_bg_stats_t last;
};

static double mono_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

store_bg_stats_t store_bg_last(const store_t *s)
{
    return s->last;
}

/* ---- the checksum ------------------------------------------------------------- */

void store_sum_init(store_sum_t *c)
{
    memset(c, 0, sizeof *c);
    for (int i = 0; i < 4; i++)
        c->lane[i] = 0x9e3779b97f4a7c15ULL * (uint64_t)(i + 1);
}

/* Each step is a bijection of the lane for a given word and of the word for
 * a given lane: one changed word always changes its lane's final value. */
static inline uint64_t fold(uint64_t h, uint64_t w)
{
    h = (h ^ w) * 0xff51afd7ed558ccdULL;
    return h ^ (h >> 32);
}

static void sum_block(store_sum_t *c, const uint8_t *p)
{
    for (int i = 0; i < 4; i++) {
        uint64_t w;
        memcpy(&w, p + 8 * i, 8);
        c->lane[i] = fold(c->lane[i], w);
    }
}

void store_sum_update(store_sum_t *c, const void *data, size_t len)
{
    const uint8_t *p = data;
    c->total += len;
    while (len > 0 && c->npend > 0) {
        c->pend[c->npend++] = *p++;
        len--;
        if (c->npend == 32) {
            sum_block(c, c->pend);
            c->npend = 0;
        }
    }
    for (; len >= 32; p += 32, len -= 32)
        sum_block(c, p);
    while (len > 0) {
        c->pend[c->npend++] = *p++;
        len--;
    }
}

void store_sum_final(const store_sum_t *c0, uint8_t out[32])
{
    store_sum_t c = *c0;
    memset(c.pend + c.npend, 0, 32 - c.npend);
    sum_block(&c, c.pend);
    for (int i = 0; i < 4; i++) {
        /* the length and the other lanes into each lane (splitmix64's finaliser) */
        uint64_t h = c.lane[i] ^ c.total ^ c.lane[(i + 1) & 3] * 0xc4ceb9fe1a85ec53ULL;
        h ^= h >> 33;
        h *= 0xff51afd7ed558ccdULL;
        h ^= h >> 33;
        h *= 0xc4ceb9fe1a85ec53ULL;
        h ^= h >> 33;
        le_put_u64(out + 8 * i, h);
    }
}

/* ---- crash-safe records ------------------------------------------------------ */

/* close(2) where its result cannot matter: a descriptor only read from, a
 * pipe end, or one abandoned after a failure that is already reported.
 * (The close of a record just written is checked: store_rec_finish.) */
static void close_quietly(int fd)
{
    (void)close(fd);
}

static int write_all(int fd, const void *data, size_t len)
{
    const uint8_t *p = data;
    while (len > 0) {
        ssize_t n = write(fd, p, len);
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0)
            return -1;
        p += n;
        len -= (size_t)n;
    }
    return 0;
}

static int fsync_dir_of(const char *path)
{
    char dir[4096];
    snprintf(dir, sizeof dir, "%s", path);
    char *slash = strrchr(dir, '/');
    if (slash)
        *slash = '\0';
    else
        snprintf(dir, sizeof dir, ".");
    int fd = open(dir, O_RDONLY | O_DIRECTORY);
    if (fd < 0)
        return -1;
    int rc = fsync(fd);
    close_quietly(fd);
    /* some file systems cannot fsync a directory; the rename still holds */
    return rc == 0 || errno == EINVAL || errno == EROFS ? 0 : -1;
}

static int open_direct(const char *path, int flags)
{
    return open(path, flags | O_DIRECT, 0600);
}

static int undirect(int fd)
{
    int fl = fcntl(fd, F_GETFL);
    return fl < 0 ? -1 : fcntl(fd, F_SETFL, fl & ~O_DIRECT);
}

static int pwrite_all(int fd, const uint8_t *data, size_t len, uint64_t at)
{
    for (size_t done = 0; done < len;) {
        ssize_t n = pwrite(fd, data + done, len - done, (off_t)(at + done));
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0)
            return -1;
        done += (size_t)n;
    }
    return 0;
}

/* Appends len bytes at offset on an O_DIRECT descriptor: whole aligned
 * blocks through the bounce buffer, the first one read back (its head is
 * the file's durable end, rewritten as it was: a torn write of that block
 * leaves those bytes either way), the last one padded, which the caller
 * cuts off. -1 with errno (EINVAL: the file system refuses the alignment). */
static int append_direct(int fd, uint8_t *bounce, uint64_t offset, const uint8_t *data, size_t len)
{
    uint64_t at = offset - offset % STORE_ALIGN;
    size_t have = (size_t)(offset - at);
    if (have > 0) {
        ssize_t r = pread(fd, bounce, STORE_ALIGN, (off_t)at);
        if (r < (ssize_t)have) {
            if (r >= 0)
                errno = EIO;
            return -1;
        }
    }
    for (size_t done = 0; done < len;) {
        size_t n = len - done < STORE_WRITE_BUF - have ? len - done : STORE_WRITE_BUF - have;
        memcpy(bounce + have, data + done, n);
        have += n;
        done += n;
        size_t out = have; /* full (aligned), or the last: padded */
        if (out % STORE_ALIGN) {
            out += STORE_ALIGN - out % STORE_ALIGN;
            memset(bounce + have, 0, out - have);
        }
        if (pwrite_all(fd, bounce, out, at) < 0)
            return -1;
        at += out;
        have = 0;
    }
    return 0;
}

int store_append(const char *path, uint64_t offset, const void *data, size_t len, uint8_t *bounce,
                 char *err, size_t errlen)
{
    int direct = bounce != NULL;
    int fd = direct ? open_direct(path, O_RDWR | O_CLOEXEC) : -1;
    if (fd < 0) { /* tmpfs, say: no O_DIRECT */
        direct = 0;
        fd = open(path, O_WRONLY | O_CLOEXEC);
    }
    if (fd < 0) {
        vberr_set(err, errlen, "cannot open %.600s: %s", path, strerror(errno));
        return -1;
    }
    const char *what = "truncate";
    int ok = ftruncate(fd, (off_t)offset) == 0;
    if (ok && direct) {
        what = "write";
        ok = append_direct(fd, bounce, offset, data, len) == 0;
        if (!ok && errno == EINVAL && undirect(fd) == 0)
            direct = 0, ok = 1; /* refused for its alignment: written again below */
    }
    if (ok && !direct) {
        what = "write";
        ok = pwrite_all(fd, data, len, offset) == 0;
    }
    if (ok) { /* the last block's padding, or what a refused one left */
        what = "truncate";
        ok = ftruncate(fd, (off_t)(offset + len)) == 0;
    }
    if (ok) {
        what = "fdatasync";
        ok = fdatasync(fd) == 0 || errno == EINVAL || errno == EROFS;
    }
    if (!ok)
        vberr_set(err, errlen, "%s of %.600s failed: %s", what, path, strerror(errno));
    (void)close(fd); /* after fdatasync, close reports nothing more about the data */
    return ok ? 0 : -1;
}

/* A write on an O_DIRECT descriptor that the file system refused for its
 * alignment (EINVAL): the descriptor goes back to the page cache. */
static int write_out(store_rec_writer_t *w, const void *data, size_t len)
{
    if (write_all(w->fd, data, len) == 0)
        return 0;
    if (!(w->direct && errno == EINVAL) || undirect(w->fd) < 0)
        return -1;
    w->direct = 0;
    /* a refused write wrote nothing: the file ends where it did */
    if (lseek(w->fd, (off_t)w->written, SEEK_SET) < 0)
        return -1;
    return write_all(w->fd, data, len);
}

/* Writes the buffer out. An O_DIRECT descriptor takes whole aligned blocks
 * only: a flush is either of a full buffer (aligned) or the record's last,
 * padded with zeros, which store_rec_finish cuts off. */
static int flush_buf(store_rec_writer_t *w)
{
    if (w->failed)
        return -1;
    size_t n = w->buffered, out = n;
    if (n == 0)
        return 0;
    if (w->direct && n % STORE_ALIGN) {
        out = n + STORE_ALIGN - n % STORE_ALIGN;
        memset(w->buf + n, 0, out - n);
    }
    if (write_out(w, w->buf, out) < 0) {
        snprintf(w->err, sizeof w->err, "%.600s: write failed: %s", w->tmp, strerror(errno));
        w->failed = 1;
        return -1;
    }
    w->written += n;
    w->buffered = 0;
    return 0;
}

static int raw_write(store_rec_writer_t *w, const void *data, size_t len)
{
    const uint8_t *p = data;
    if (len >= STORE_WRITE_BUF && !w->direct && !w->failed) {
        /* a large block (a film) goes straight to the file: copying it
         * through the buffer first was a tenth of a checkpoint's CPU (with
         * O_DIRECT it must be copied: the film is not aligned) */
        if (flush_buf(w) < 0)
            return -1;
        if (write_all(w->fd, p, len) < 0) {
            snprintf(w->err, sizeof w->err, "%.600s: write failed: %s", w->tmp, strerror(errno));
            w->failed = 1;
        }
        w->written += len;
        return w->failed ? -1 : 0;
    }
    while (len > 0 && !w->failed) {
        size_t room = STORE_WRITE_BUF - w->buffered;
        size_t n = len < room ? len : room;
        memcpy(w->buf + w->buffered, p, n);
        w->buffered += n;
        p += n;
        len -= n;
        if (w->buffered == STORE_WRITE_BUF)
            flush_buf(w); /* a failure sets w->failed, which ends the loop */
    }
    return w->failed ? -1 : 0;
}

int store_rec_begin(store_rec_writer_t *w, const char *path, store_kind_t kind)
{
    w->fd = -1;
    w->failed = 0;
    w->direct = 0;
    w->length = 0;
    w->written = 0;
    w->buffered = 0;
    w->buf = w->space + (STORE_ALIGN - (uintptr_t)w->space % STORE_ALIGN) % STORE_ALIGN;
    w->err[0] = '\0';
    snprintf(w->path, sizeof w->path, "%s", path);
    snprintf(w->tmp, sizeof w->tmp, "%s.tmp.%ld", path, (long)getpid());
    const int flags = O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC;
    w->fd = open_direct(w->tmp, flags);
    if (w->fd >= 0)
        w->direct = 1;
    else if (errno == EINVAL) /* a file system without O_DIRECT (tmpfs) */
        w->fd = open(w->tmp, flags, 0600);
    if (w->fd < 0) {
        snprintf(w->err, sizeof w->err, "cannot create %.600s: %s", w->tmp, strerror(errno));
        w->failed = 1;
        return -1;
    }
    store_sum_init(&w->hash);
    uint8_t header[STORE_HEADER_SIZE];
    memcpy(header, store_magic, 8);
    le_put_u32(header + 8, STORE_FORMAT_VERSION);
    le_put_u32(header + 12, (uint32_t)kind);
    store_sum_update(&w->hash, header, sizeof header);
    return raw_write(w, header, sizeof header);
}

int store_rec_write(void *wp, const void *data, size_t len)
{
    store_rec_writer_t *w = wp;
    if (w->failed)
        return -1;
    store_sum_update(&w->hash, data, len);
    w->length += len;
    return raw_write(w, data, len);
}

int store_rec_write_block(store_rec_writer_t *w, const void *data, size_t len)
{
    uint8_t n[8];
    le_put_u64(n, len);
    if (store_rec_write(w, n, 8) < 0)
        return -1;
    return len ? store_rec_write(w, data, len) : 0;
}

void store_rec_abort(store_rec_writer_t *w)
{
    if (w->fd >= 0) {
        close_quietly(w->fd);
        w->fd = -1;
    }
    /* Unchecked: the write has failed and says so; a temporary file left
     * behind in a job's directory is removed at the next start
     * (store_job_clean), and is never read as a record. */
    if (w->tmp[0])
        (void)unlink(w->tmp);
    w->failed = 1;
}

int store_rec_finish(store_rec_writer_t *w)
{
    if (w->failed) {
        store_rec_abort(w);
        return -1;
    }
    uint8_t trailer[STORE_TRAILER_SIZE];
    le_put_u64(trailer, w->length);
    store_sum_update(&w->hash, trailer, 8);
    store_sum_final(&w->hash, trailer + 8);
    if (raw_write(w, trailer, sizeof trailer) < 0 || flush_buf(w) < 0) {
        store_rec_abort(w);
        return -1;
    }
    /* the last O_DIRECT block's padding */
    if (ftruncate(w->fd, (off_t)w->written) != 0) {
        snprintf(w->err, sizeof w->err, "%.600s: truncate failed: %s", w->tmp, strerror(errno));
        store_rec_abort(w);
        return -1;
    }
    /* fsync before rename: otherwise a crash can leave the new name
     * pointing at blocks that were never written */
    if (fsync(w->fd) != 0 && errno != EINVAL && errno != EROFS) {
        snprintf(w->err, sizeof w->err, "%.600s: fsync failed: %s", w->tmp, strerror(errno));
        store_rec_abort(w);
        return -1;
    }
    if (close(w->fd) != 0) {
        w->fd = -1;
        snprintf(w->err, sizeof w->err, "%.600s: close failed: %s", w->tmp, strerror(errno));
        store_rec_abort(w);
        return -1;
    }
    w->fd = -1;
    return 0;
}

int store_rec_install(store_rec_writer_t *w, int keep_prev)
{
    if (keep_prev) {
        char prev[4096 + 8];
        snprintf(prev, sizeof prev, "%s.prev", w->path);
        /* a crash between these two renames leaves only PATH.prev: the
         * loader falls back to it */
        if (rename(w->path, prev) != 0 && errno != ENOENT) {
            snprintf(w->err, sizeof w->err, "cannot rename %.600s: %s", w->path, strerror(errno));
            store_rec_abort(w);
            return -1;
        }
    }
    if (rename(w->tmp, w->path) != 0) {
        snprintf(w->err, sizeof w->err, "cannot rename %.600s into place: %s", w->tmp,
                 strerror(errno));
        store_rec_abort(w);
        return -1;
    }
    w->tmp[0] = '\0';
    if (fsync_dir_of(w->path) < 0) {
        snprintf(w->err, sizeof w->err, "cannot fsync the directory of %.600s: %s", w->path,
                 strerror(errno));
        return -1;
    }
    return 0;
}

int store_rec_commit(store_rec_writer_t *w, int keep_prev)
{
    if (store_rec_finish(w) < 0)
        return -1;
    return store_rec_install(w, keep_prev);
}

/* Checks a whole record in memory; NULL when it is sound, else why not. */
static const char *check_record(const uint8_t *all, uint64_t size, store_kind_t kind, char *why,
                                size_t whylen)
{
    if (size < STORE_HEADER_SIZE + STORE_TRAILER_SIZE || size > STORE_MAX_RECORD)
        return "torn (too short)";
    if (memcmp(all, store_magic, 8) != 0)
        return "not a vbrender state file (bad magic)";
    if (le_get_u32(all + 8) < STORE_FORMAT_OLDEST || le_get_u32(all + 8) > STORE_FORMAT_VERSION) {
        snprintf(why, whylen, "format version %u, this master reads %d to %d", le_get_u32(all + 8),
                 STORE_FORMAT_OLDEST, STORE_FORMAT_VERSION);
        return why;
    }
    if (le_get_u32(all + 12) != (uint32_t)kind)
        return "a record of another kind";
    if (le_get_u64(all + size - STORE_TRAILER_SIZE) !=
        size - STORE_HEADER_SIZE - STORE_TRAILER_SIZE)
        return "torn (length mismatch)";
    uint8_t hash[STORE_SUM_SIZE];
    store_sum_t c;
    store_sum_init(&c);
    store_sum_update(&c, all, (size_t)(size - STORE_SUM_SIZE));
    store_sum_final(&c, hash);
    if (memcmp(hash, all + size - STORE_SUM_SIZE, STORE_SUM_SIZE) != 0)
        return "corrupt (checksum mismatch)";
    return NULL;
}

int store_rec_parse(const uint8_t *data, size_t size, store_kind_t kind, store_rec_t *rec,
                    char *err, size_t errlen)
{
    memset(rec, 0, sizeof *rec);
    char buf[STORE_REASON_LEN];
    const char *why = check_record(data, size, kind, buf, sizeof buf);
    if (why) {
        vberr_set(err, errlen, "%s", why);
        return -1;
    }
    size_t plen = size - STORE_HEADER_SIZE - STORE_TRAILER_SIZE;
    rec->data = malloc(plen ? plen : 1);
    if (!rec->data) {
        vberr_set(err, errlen, "out of memory");
        return -1;
    }
    memcpy(rec->data, data + STORE_HEADER_SIZE, plen);
    rec->size = plen;
    rec->version = le_get_u32(data + 8);
    return 0;
}

int store_rec_save(const char *path, store_kind_t kind, const void *data, size_t len, char *err,
                   size_t errlen)
{
    store_rec_writer_t *w = malloc(sizeof *w);
    if (!w) {
        vberr_set(err, errlen, "out of memory");
        return -1;
    }
    int rc = 0;
    if (store_rec_begin(w, path, kind) < 0 || store_rec_write(w, data, len) < 0 ||
        store_rec_commit(w, 0) < 0) {
        vberr_set(err, errlen, "%.600s", w->err);
        rc = -1;
    }
    free(w);
    return rc;
}

int store_rec_load(const char *path, store_kind_t kind, store_rec_t *rec, char *err, size_t errlen)
{
    memset(rec, 0, sizeof *rec);
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0) {
        vberr_set(err, errlen, "%.600s: %s", path,
                  errno == ENOENT ? "no such file" : strerror(errno));
        return -1;
    }
    struct stat st;
    if (fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
        vberr_set(err, errlen, "%.600s: not a regular file", path);
        close_quietly(fd);
        return -1;
    }
    uint64_t size = (uint64_t)st.st_size;
    if (size < STORE_HEADER_SIZE + STORE_TRAILER_SIZE || size > STORE_MAX_RECORD) {
        vberr_set(err, errlen, "%.600s: torn (%" PRIu64 " bytes)", path, size);
        close_quietly(fd);
        return -1;
    }
    uint8_t *all = malloc(size);
    if (!all) {
        vberr_set(err, errlen, "%.600s: out of memory (%" PRIu64 " bytes)", path, size);
        close_quietly(fd);
        return -1;
    }
    size_t got = 0;
    while (got < size) {
        ssize_t n = read(fd, all + got, size - got);
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0)
            break;
        got += (size_t)n;
    }
    close_quietly(fd);
    char buf[STORE_REASON_LEN];
    const char *why = got != size ? "short read" : check_record(all, size, kind, buf, sizeof buf);
    if (why) {
        vberr_set(err, errlen, "%.600s: %s", path, why);
        free(all);
        return -1;
    }
    /* keep the payload only */
    size_t plen = (size_t)(size - STORE_HEADER_SIZE - STORE_TRAILER_SIZE);
    memmove(all, all + STORE_HEADER_SIZE, plen);
    rec->data = all;
    rec->size = plen;
    rec->pos = 0;
    return 0;
}

int store_rec_read(void *rp, void *data, size_t len)
{
    store_rec_t *rec = rp;
    if (len > rec->size - rec->pos)
        return -1;
    memcpy(data, rec->data + rec->pos, len);
    rec->pos += len;
    return 0;
}

int store_rec_read_block(store_rec_t *rec, const uint8_t **data, size_t *len)
{
    uint8_t n[8];
    if (store_rec_read(rec, n, 8) < 0)
        return -1;
    uint64_t l = le_get_u64(n);
    if (l > rec->size - rec->pos)
        return -1;
    *data = rec->data + rec->pos;
    *len = (size_t)l;
    rec->pos += (size_t)l;
    return 0;
}

void store_rec_free(store_rec_t *rec)
{
    free(rec->data);
    memset(rec, 0, sizeof *rec);
}

/* ---- the directory ------------------------------------------------------------ */

static int mkdir_p(const char *dir)
{
    char tmp[4096];
    snprintf(tmp, sizeof tmp, "%s", dir);
    for (char *p = tmp + 1; *p; p++)
        if (*p == '/') {
            *p = '\0';
            if (mkdir(tmp, 0700) != 0 && errno != EEXIST)
                return -1;
            *p = '/';
        }
    return mkdir(tmp, 0700) != 0 && errno != EEXIST ? -1 : 0;
}

static int write_meta(store_t *s, char *err, size_t errlen)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/meta", s->dir);
    uint8_t body[12];
    le_put_u64(body, s->next_id);
    le_put_u32(body + 8, s->boots);
    return store_rec_save(path, STORE_KIND_META, body, sizeof body, err, errlen);
}

const char *store_dir(const store_t *s)
{
    return s->dir;
}
uint32_t store_boots(const store_t *s)
{
    return s->boots;
}

void store_job_path(const store_t *s, uint64_t id, const char *name, char *out, size_t outlen)
{
    snprintf(out, outlen, "%s/jobs/%" PRIu64 "%s%s", s->dir, id, name ? "/" : "", name ? name : "");
}

int store_job_dir(const store_t *s, uint64_t id, char *err, size_t errlen)
{
    char path[4096];
    store_job_path(s, id, NULL, path, sizeof path);
    if (mkdir(path, 0700) != 0 && errno != EEXIST) {
        vberr_set(err, errlen, "cannot create %.600s: %s", path, strerror(errno));
        return -1;
    }
    if (fsync_dir_of(path) < 0) {
        vberr_set(err, errlen, "cannot fsync the directory of %.600s: %s", path, strerror(errno));
        return -1;
    }
    return 0;
}

int store_job_remove(const store_t *s, uint64_t id, char *err, size_t errlen)
{
    char path[4096];
    store_job_path(s, id, NULL, path, sizeof path);
    DIR *d = opendir(path);
    if (!d)
        return errno == ENOENT
                   ? 0
                   : (vberr_set(err, errlen, "cannot open %.600s: %s", path, strerror(errno)), -1);
    struct dirent *e;
    int rc = 0;
    while ((e = readdir(d)) != NULL) {
        if (strcmp(e->d_name, ".") == 0 || strcmp(e->d_name, "..") == 0)
            continue;
        char f[4096 + 260];
        snprintf(f, sizeof f, "%s/%s", path, e->d_name);
        if (unlink(f) != 0 && errno != ENOENT) {
            vberr_set(err, errlen, "cannot remove %.600s: %s", f, strerror(errno));
            rc = -1;
        }
    }
    closedir(d);
    if (rc == 0 && rmdir(path) != 0 && errno != ENOENT) {
        vberr_set(err, errlen, "cannot remove %.600s: %s", path, strerror(errno));
        rc = -1;
    }
    if (rc == 0 && fsync_dir_of(path) < 0) {
        /* removed, but a crash may bring the job back at the next start */
        vberr_set(err, errlen, "removed %.600s, but cannot fsync its parent directory: %s", path,
                  strerror(errno));
        rc = -1;
    }
    return rc;
}

void store_job_clean(const store_t *s, uint64_t id)
{
    char path[4096];
    store_job_path(s, id, NULL, path, sizeof path);
    DIR *d = opendir(path);
    if (!d)
        return;
    struct dirent *e;
    while ((e = readdir(d)) != NULL)
        if (strstr(e->d_name, ".tmp.")) {
            char f[4096 + 260];
            snprintf(f, sizeof f, "%s/%s", path, e->d_name);
            (void)unlink(f); /* best effort: one left is tried again at the next start */
        }
    closedir(d);
}

static int cmp_u64(const void *a, const void *b)
{
    uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
    return x < y ? -1 : x > y;
}

int store_job_ids(const store_t *s, uint64_t **ids, size_t *count, char *err, size_t errlen)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/jobs", s->dir);
    *ids = NULL;
    *count = 0;
    DIR *d = opendir(path);
    if (!d) {
        vberr_set(err, errlen, "cannot open %.600s: %s", path, strerror(errno));
        return -1;
    }
    size_t cap = 0;
    struct dirent *e;
    while ((e = readdir(d)) != NULL) {
        const char *n = e->d_name;
        if (!*n || strspn(n, "0123456789") != strlen(n) || strlen(n) > 19 || n[0] == '0')
            continue; /* not ours */
        if (*count == cap) {
            cap = cap ? 2 * cap : 64;
            uint64_t *ni = realloc(*ids, cap * sizeof *ni);
            if (!ni) {
                closedir(d);
                free(*ids);
                *ids = NULL;
                vberr_set(err, errlen, "out of memory");
                return -1;
            }
            *ids = ni;
        }
        (*ids)[(*count)++] = strtoull(n, NULL, 10);
    }
    closedir(d);
    if (*count)
        qsort(*ids, *count, sizeof **ids, cmp_u64);
    return 0;
}

/* The format version in a state file's header; 0 when it has none (missing,
 * short, another magic). */
static uint32_t meta_version(const char *path)
{
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0)
        return 0;
    uint8_t h[STORE_HEADER_SIZE];
    ssize_t n = read(fd, h, sizeof h);
    close_quietly(fd);
    return n == (ssize_t)sizeof h && memcmp(h, store_magic, 8) == 0 ? le_get_u32(h + 8) : 0;
}

store_t *store_open(const char *dir, char *err, size_t errlen)
{
    store_t *s = calloc(1, sizeof *s);
    if (!s) {
        vberr_set(err, errlen, "out of memory");
        return NULL;
    }
    s->bg_fd = -1;
    if (strlen(dir) == 0 || strlen(dir) >= sizeof s->dir - 64) {
        vberr_set(err, errlen, "--state: a directory path of 1 to %zu characters",
                  sizeof s->dir - 64);
        free(s);
        return NULL;
    }
    snprintf(s->dir, sizeof s->dir, "%s", dir);
    char jobs[4096];
    snprintf(jobs, sizeof jobs, "%s/jobs", s->dir);
    if (mkdir_p(jobs) != 0) {
        vberr_set(err, errlen, "cannot create the state directory %.600s: %s", jobs,
                  strerror(errno));
        free(s);
        return NULL;
    }
    char path[4096], lerr[VB_ERR_LEN];
    snprintf(path, sizeof path, "%s/meta", s->dir);
    store_rec_t rec;
    s->next_id = 1;
    uint32_t version = meta_version(path);
    if (version > STORE_FORMAT_VERSION) {
        vberr_set(err, errlen,
                  "%.600s: state format version %u, written by a newer vbrender-master; this one "
                  "reads versions %d to %d (refusing to touch it)",
                  path, version, STORE_FORMAT_OLDEST, STORE_FORMAT_VERSION);
        free(s);
        return NULL;
    }
    if (store_rec_load(path, STORE_KIND_META, &rec, lerr, sizeof lerr) == 0) {
        if (rec.size >= 12) {
            s->next_id = le_get_u64(rec.data);
            s->boots = le_get_u32(rec.data + 8);
        }
        store_rec_free(&rec);
    } else if (access(path, F_OK) == 0) {
        /* the job directories still give the ids in use (below) */
        fprintf(stderr, "vbrender-master: %s; job ids continue from the job directories\n", lerr);
    }
    uint64_t *ids;
    size_t n;
    if (store_job_ids(s, &ids, &n, err, errlen) < 0) {
        free(s);
        return NULL;
    }
    if (n && ids[n - 1] + 1 > s->next_id)
        s->next_id = ids[n - 1] + 1;
    free(ids);
    if (s->next_id == 0)
        s->next_id = 1;
    s->boots++;
    if (write_meta(s, err, errlen) < 0) {
        free(s);
        return NULL;
    }
    return s;
}

uint64_t store_take_job_id(store_t *s, char *err, size_t errlen)
{
    uint64_t id = s->next_id++;
    if (write_meta(s, err, errlen) < 0) {
        s->next_id--;
        return 0;
    }
    return id;
}

void store_close(store_t **sp)
{
    if (!sp || !*sp)
        return;
    store_t *s = *sp;
    store_bg_wait(s, NULL, NULL);
    free(s->bg_buf);
    free(s);
    *sp = NULL;
}

/* ---- background writer ---------------------------------------------------------- */

int store_bg_running(const store_t *s)
{
    return s->bg_pid > 0;
}

int store_bg_start(store_t *s, store_bg_fn fn, void *ctx, char *err, size_t errlen)
{
    if (s->bg_pid > 0) {
        vberr_set(err, errlen, "a background write is still running");
        return -1;
    }
    int p[2];
    if (pipe(p) != 0) {
        vberr_set(err, errlen, "pipe: %.600s", strerror(errno));
        return -1;
    }
    /* fcntl on a pipe just made fails only with EBADF: unchecked here and below */
    (void)fcntl(p[0], F_SETFD, FD_CLOEXEC);
    fflush(NULL); /* nothing buffered is written twice */
    double t0 = mono_s();
    const pid_t parent = getpid();
    pid_t pid = fork();
    if (pid < 0) {
        vberr_set(err, errlen, "fork: %.600s", strerror(errno));
        close_quietly(p[0]);
        close_quietly(p[1]);
        return -1;
    }
    if (pid == 0) {
        close_quietly(p[0]);
        /* the child must not take the master's signals as its own stop */
        signal(SIGTERM, SIG_DFL);
        signal(SIGINT, SIG_IGN);
        /* nor outlive it: a writer left over from a killed master would
         * rename its snapshot (and a fresh journal) into place under the
         * next master, which has replayed and appended to the journal by
         * then. The check covers a death before the prctl. */
        if (prctl(PR_SET_PDEATHSIG, SIGKILL) != 0 || getppid() != parent)
            _exit(1);
        int rc = fn(ctx, p[1]);
        close_quietly(p[1]);
        _exit(rc);
    }
    s->bg_fork_ms = (mono_s() - t0) * 1e3;
    s->bg_started = t0;
    close_quietly(p[1]);
    (void)fcntl(p[0], F_SETFL, fcntl(p[0], F_GETFL) | O_NONBLOCK);
    s->bg_pid = pid;
    s->bg_fd = p[0];
    s->bg_len = 0;
    return 0;
}

void store_bg_report(int fd, uint64_t id, const char *error)
{
    /* the id and " error " before a whole message; under PIPE_BUF (4096),
     * so a line is one atomic write */
    char line[VB_ERR_LEN + 32];
    int n = error ? snprintf(line, sizeof line, "%" PRIu64 " error %s", id, error)
                  : snprintf(line, sizeof line, "%" PRIu64 " ok", id);
    if (n < 0)
        return;
    if ((size_t)n >= sizeof line - 1)
        n = (int)sizeof line - 2;
    for (int i = 0; i < n; i++)
        if (line[i] == '\n')
            line[i] = ' ';
    line[n++] = '\n';
    /* Unchecked: the child has nobody else to tell. A job whose line does
     * not arrive counts as not written (store_bg_poll), which is the truth. */
    (void)write_all(fd, line, (size_t)n);
}

static void drain(store_t *s)
{
    for (;;) {
        if (s->bg_cap - s->bg_len < STORE_BG_READ_ROOM) {
            size_t cap = s->bg_cap ? 2 * s->bg_cap : STORE_BG_BUF0;
            char *nb = realloc(s->bg_buf, cap);
            if (!nb)
                return;
            s->bg_buf = nb;
            s->bg_cap = cap;
        }
        ssize_t n = read(s->bg_fd, s->bg_buf + s->bg_len, s->bg_cap - s->bg_len - 1);
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0)
            return;
        s->bg_len += (size_t)n;
    }
}

static void deliver(store_t *s, store_bg_report_fn on_report, void *ctx)
{
    s->bg_buf[s->bg_len] = '\0';
    char *line = s->bg_buf;
    while (on_report && line && *line) {
        char *nl = strchr(line, '\n');
        if (!nl)
            break; /* a torn last line: that job counts as not written */
        *nl = '\0';
        char *end;
        uint64_t id = strtoull(line, &end, 10);
        if (strncmp(end, " ok", 3) == 0)
            on_report(ctx, id, NULL);
        else if (strncmp(end, " error ", 7) == 0)
            on_report(ctx, id, end + 7);
        line = nl + 1;
    }
    s->bg_len = 0;
}

int store_bg_poll(store_t *s, store_bg_report_fn on_report, void *ctx, int *exit_status)
{
    if (s->bg_pid <= 0)
        return 0;
    if (s->bg_buf || s->bg_cap == 0)
        drain(s);
    int status;
    struct rusage ru;
    memset(&ru, 0, sizeof ru);
    pid_t r = wait4(s->bg_pid, &status, WNOHANG, &ru);
    if (r == 0)
        return 0;
    s->last.runs++;
    s->last.wall_s = mono_s() - s->bg_started;
    s->last.cpu_s = (double)ru.ru_utime.tv_sec + 1e-6 * (double)ru.ru_utime.tv_usec +
                    (double)ru.ru_stime.tv_sec + 1e-6 * (double)ru.ru_stime.tv_usec;
    s->last.fork_ms = s->bg_fork_ms;
    drain(s);
    close_quietly(s->bg_fd);
    s->bg_fd = -1;
    s->bg_pid = 0;
    if (exit_status)
        *exit_status = r > 0 && WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    if (s->bg_buf)
        deliver(s, on_report, ctx);
    return 1;
}

void store_bg_wait(store_t *s, store_bg_report_fn on_report, void *ctx)
{
    while (s->bg_pid > 0) {
        if (store_bg_poll(s, on_report, ctx, NULL))
            break;
        usleep(STORE_BG_WAIT_US);
    }
}
