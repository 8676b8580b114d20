/* test_store.c - the master's durable records (master/store.c), reading a
 * checkpoint's counters (master/persist.c) and task leases
 * (master/lease.c). */
#include <check.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "journal.h"
#include "lease.h"
#include "master_priv.h" /* persist_apply_extras */
#include "store.h"
#include "testutil.h"

#define PATHLEN 1024

/* A fresh directory for one test. */
static const char *fresh_dir(char *buf, size_t len, const char *name)
{
    char file[128], cmd[PATHLEN + 16], out[256];
    snprintf(file, sizeof file, "store-%ld-%s", (long)getpid(), name);
    tu_tmp_path(buf, len, file);
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", buf);
    tu_run(cmd, out, sizeof out);
    return buf;
}

static void rm_rf(const char *dir)
{
    char cmd[PATHLEN + 16], out[256];
    snprintf(cmd, sizeof cmd, "rm -rf '%.1000s'", dir);
    tu_run(cmd, out, sizeof out);
}

static void write_rec(const char *path, store_kind_t kind, const void *data, size_t len,
                      int keep_prev)
{
    store_rec_writer_t *w = malloc(sizeof *w);
    ck_assert_ptr_nonnull(w);
    ck_assert_int_eq(store_rec_begin(w, path, kind), 0);
    /* in uneven pieces: the checksum must not depend on them */
    size_t off = 0, step = 1;
    while (off < len) {
        size_t n = len - off < step ? len - off : step;
        ck_assert_int_eq(store_rec_write(w, (const char *)data + off, n), 0);
        off += n;
        step = step * 3 + 1;
    }
    ck_assert_msg(store_rec_commit(w, keep_prev) == 0, "%s", w->err);
    free(w);
}

static uint8_t *read_file(const char *path, size_t *n)
{
    FILE *f = fopen(path, "rb");
    ck_assert_ptr_nonnull(f);
    fseek(f, 0, SEEK_END);
    long size = ftell(f);
    fseek(f, 0, SEEK_SET);
    uint8_t *d = malloc((size_t)size + 1);
    ck_assert_ptr_nonnull(d);
    ck_assert_uint_eq(fread(d, 1, (size_t)size, f), (size_t)size);
    fclose(f);
    *n = (size_t)size;
    return d;
}

START_TEST(record_round_trip)
{
    char dir[PATHLEN], path[PATHLEN + 16], err[1024];
    fresh_dir(dir, sizeof dir, "rt");
    ck_assert_int_eq(mkdir(dir, 0700), 0);
    snprintf(path, sizeof path, "%s/rec", dir);
    uint8_t data[5000];
    for (size_t i = 0; i < sizeof data; i++)
        data[i] = (uint8_t)(i * 131 + 7);
    write_rec(path, STORE_KIND_CHECKPOINT, data, sizeof data, 0);
    store_rec_t rec;
    ck_assert_msg(store_rec_load(path, STORE_KIND_CHECKPOINT, &rec, err, sizeof err) == 0, "%s",
                  err);
    ck_assert_uint_eq(rec.size, sizeof data);
    ck_assert_int_eq(memcmp(rec.data, data, sizeof data), 0);
    uint8_t first[10];
    ck_assert_int_eq(store_rec_read(&rec, first, sizeof first), 0);
    ck_assert_int_eq(memcmp(first, data, sizeof first), 0);
    store_rec_free(&rec);
    /* another kind is refused */
    ck_assert_int_eq(store_rec_load(path, STORE_KIND_FINAL, &rec, err, sizeof err), -1);
    ck_assert_msg(strstr(err, "another kind"), "%s", err);
    /* no temporary file is left behind */
    char cmd[PATHLEN + 64], out[4096];
    snprintf(cmd, sizeof cmd, "ls '%s'", dir);
    tu_run(cmd, out, sizeof out);
    ck_assert_msg(strstr(out, ".tmp.") == NULL, "left behind: %s", out);
    rm_rf(dir);
}
END_TEST

/* The two directories the size tests write in: one in the test directory
 * and one on tmpfs (/dev/shm), which may refuse O_DIRECT. */
static void two_dirs(char dirs[2][PATHLEN], const char *name)
{
    fresh_dir(dirs[0], PATHLEN, name);
    snprintf(dirs[1], PATHLEN, "/dev/shm/vb-%s-%ld", name, (long)getpid());
}

/* Makes dirs[d] afresh: 0, or -1 where there is no /dev/shm. */
static int make_dir(char dirs[2][PATHLEN], int d)
{
    rm_rf(dirs[d]);
    if (mkdir(dirs[d], 0700) == 0)
        return 0;
    ck_assert_int_eq(d, 1);
    return -1;
}

/* Records of every size around the O_DIRECT blocks (store.h) come back
 * whole, the file cut to its length (header 16, trailer 40 bytes): in the
 * test directory, and on tmpfs, which may refuse O_DIRECT (the page cache's
 * way is taken then). */
START_TEST(record_sizes_across_blocks)
{
    char dirs[2][PATHLEN], path[PATHLEN + 16], err[1024];
    two_dirs(dirs, "sizes");
    const size_t frame = 16 + 40;
    const size_t sizes[] = {0,
                            1,
                            STORE_ALIGN - frame - 1,
                            STORE_ALIGN - frame,
                            STORE_ALIGN - frame + 1,
                            STORE_WRITE_BUF - frame,
                            STORE_WRITE_BUF - frame + 1,
                            3 * (size_t)STORE_WRITE_BUF + 12345};
    uint8_t *data = malloc(sizes[7]);
    ck_assert_ptr_nonnull(data);
    for (size_t i = 0; i < sizes[7]; i++)
        data[i] = (uint8_t)(i * 131 + 7 + (i >> 12));
    for (int d = 0; d < 2; d++) {
        if (make_dir(dirs, d) < 0)
            continue;
        for (size_t k = 0; k < sizeof sizes / sizeof sizes[0]; k++) {
            snprintf(path, sizeof path, "%s/rec%zu", dirs[d], k);
            write_rec(path, STORE_KIND_SNAPSHOT, data, sizes[k], 0);
            struct stat st;
            ck_assert_int_eq(stat(path, &st), 0);
            ck_assert_msg((size_t)st.st_size == sizes[k] + frame, "%s: %lld bytes for %zu", path,
                          (long long)st.st_size, sizes[k]);
            store_rec_t rec;
            ck_assert_msg(store_rec_load(path, STORE_KIND_SNAPSHOT, &rec, err, sizeof err) == 0,
                          "%s: %s", path, err);
            ck_assert_uint_eq(rec.size, sizes[k]);
            ck_assert(sizes[k] == 0 || memcmp(rec.data, data, sizes[k]) == 0);
            store_rec_free(&rec);
        }
        rm_rf(dirs[d]);
    }
    free(data);
}
END_TEST

/* store_append (the journal's writes): appends at every kind of offset
 * give the file exactly the bytes appended, whatever lay past the offset is
 * cut, with O_DIRECT (a bounce buffer) and without, here and on tmpfs. */
START_TEST(append_across_blocks)
{
    char dirs[2][PATHLEN], path[PATHLEN + 16], err[1024];
    two_dirs(dirs, "append");
    const size_t pieces[] = {
        32, 1, STORE_ALIGN - 33, 5000, STORE_WRITE_BUF + 17, 3, 2 * STORE_ALIGN};
    size_t total = 0;
    for (size_t k = 0; k < sizeof pieces / sizeof pieces[0]; k++)
        total += pieces[k];
    uint8_t *data = malloc(total);
    ck_assert_ptr_nonnull(data);
    for (size_t i = 0; i < total; i++)
        data[i] = (uint8_t)(i * 167 + 11 + (i >> 13));
    void *bounce = NULL;
    ck_assert_int_eq(posix_memalign(&bounce, STORE_ALIGN, STORE_WRITE_BUF), 0);
    for (int d = 0; d < 2; d++) {
        if (make_dir(dirs, d) < 0)
            continue;
        for (int direct = 0; direct < 2; direct++) {
            snprintf(path, sizeof path, "%.1000s/file%d", dirs[d], direct);
            FILE *f = fopen(path, "wb");
            ck_assert_ptr_nonnull(f);
            fclose(f);
            size_t at = 0;
            for (size_t k = 0; k < sizeof pieces / sizeof pieces[0]; k++) {
                ck_assert_msg(store_append(path, at, data + at, pieces[k], direct ? bounce : NULL,
                                           err, sizeof err) == 0,
                              "%s", err);
                at += pieces[k];
            }
            /* a piece written again over a longer file: the rest is cut */
            ck_assert_int_eq(
                store_append(path, 100, data + 100, 50, direct ? bounce : NULL, err, sizeof err),
                0);
            size_t n;
            uint8_t *got = read_file(path, &n);
            ck_assert_uint_eq(n, 150);
            ck_assert_int_eq(memcmp(got, data, 150), 0);
            free(got);
            ck_assert_int_eq(store_append(path, 150, data + 150, total - 150,
                                          direct ? bounce : NULL, err, sizeof err),
                             0);
            got = read_file(path, &n);
            ck_assert_uint_eq(n, total);
            ck_assert_int_eq(memcmp(got, data, total), 0);
            free(got);
        }
        rm_rf(dirs[d]);
    }
    /* a missing file is an error with its name, not a new file */
    snprintf(path, sizeof path, "%s/none/file", dirs[0]);
    ck_assert_int_eq(store_append(path, 0, data, 10, bounce, err, sizeof err), -1);
    ck_assert_msg(strstr(err, "cannot open") && strstr(err, "none/file"), "%s", err);
    free(bounce);
    free(data);
}
END_TEST

/* Every truncation and every single-bit flip is found: garbage is never
 * read as a record. */
START_TEST(record_damage_found)
{
    char dir[PATHLEN], path[PATHLEN + 16], err[1024];
    fresh_dir(dir, sizeof dir, "dmg");
    ck_assert_int_eq(mkdir(dir, 0700), 0);
    snprintf(path, sizeof path, "%s/rec", dir);
    const char text[] = "{\"state\":\"done\",\"samples\":123456}";
    write_rec(path, STORE_KIND_FINAL, text, sizeof text - 1, 0);
    size_t n;
    uint8_t *good = read_file(path, &n);
    store_rec_t rec;
    ck_assert_int_eq(store_rec_parse(good, n, STORE_KIND_FINAL, &rec, err, sizeof err), 0);
    store_rec_free(&rec);
    for (size_t cut = 0; cut < n; cut++) {
        ck_assert_msg(store_rec_parse(good, cut, STORE_KIND_FINAL, &rec, err, sizeof err) == -1,
                      "a record cut at %zu of %zu bytes was accepted", cut, n);
        ck_assert(err[0] != '\0');
    }
    uint8_t *bad = malloc(n);
    for (size_t byte = 0; byte < n; byte++)
        for (int bit = 0; bit < 8; bit++) {
            memcpy(bad, good, n);
            bad[byte] ^= (uint8_t)(1u << bit);
            ck_assert_msg(store_rec_parse(bad, n, STORE_KIND_FINAL, &rec, err, sizeof err) == -1,
                          "bit %d of byte %zu flipped was accepted", bit, byte);
        }
    /* the messages say what is wrong */
    memcpy(bad, good, n);
    bad[n / 2] ^= 1;
    store_rec_parse(bad, n, STORE_KIND_FINAL, &rec, err, sizeof err);
    ck_assert_msg(strstr(err, "checksum"), "%s", err);
    memcpy(bad, good, n);
    bad[8] = 9; /* format version */
    store_rec_parse(bad, n, STORE_KIND_FINAL, &rec, err, sizeof err);
    ck_assert_msg(strstr(err, "format version 9"), "%s", err);
    free(bad);
    free(good);
    rm_rf(dir);
}
END_TEST

START_TEST(keep_prev)
{
    char dir[PATHLEN], path[PATHLEN + 16], prev[PATHLEN + 32], err[1024];
    fresh_dir(dir, sizeof dir, "prev");
    ck_assert_int_eq(mkdir(dir, 0700), 0);
    snprintf(path, sizeof path, "%s/checkpoint", dir);
    snprintf(prev, sizeof prev, "%s.prev", path);
    write_rec(path, STORE_KIND_CHECKPOINT, "one", 3, 1);
    ck_assert_int_ne(access(prev, F_OK), 0);
    write_rec(path, STORE_KIND_CHECKPOINT, "two", 3, 1);
    store_rec_t rec;
    ck_assert_int_eq(store_rec_load(path, STORE_KIND_CHECKPOINT, &rec, err, sizeof err), 0);
    ck_assert_int_eq(memcmp(rec.data, "two", 3), 0);
    store_rec_free(&rec);
    ck_assert_int_eq(store_rec_load(prev, STORE_KIND_CHECKPOINT, &rec, err, sizeof err), 0);
    ck_assert_int_eq(memcmp(rec.data, "one", 3), 0);
    store_rec_free(&rec);
    rm_rf(dir);
}
END_TEST

/* Ids increase across reopenings and never repeat, even when the meta
 * record is lost: the job directories carry them too. */
START_TEST(job_ids_increase)
{
    char dir[PATHLEN], err[1024], path[PATHLEN + 64];
    fresh_dir(dir, sizeof dir, "ids");
    store_t *s = store_open(dir, err, sizeof err);
    ck_assert_msg(s != NULL, "%s", err);
    ck_assert_uint_eq(store_boots(s), 1);
    uint64_t a = store_take_job_id(s, err, sizeof err), b = store_take_job_id(s, err, sizeof err);
    ck_assert_uint_eq(a, 1);
    ck_assert_uint_eq(b, 2);
    ck_assert_int_eq(store_job_dir(s, b, err, sizeof err), 0);
    store_close(&s);
    s = store_open(dir, err, sizeof err);
    ck_assert_ptr_nonnull(s);
    ck_assert_uint_eq(store_boots(s), 2);
    ck_assert_uint_eq(store_take_job_id(s, err, sizeof err), 3);
    store_close(&s);
    /* meta gone: the directory of job 2 still says ids 1 and 2 are taken */
    snprintf(path, sizeof path, "%s/meta", dir);
    ck_assert_int_eq(unlink(path), 0);
    s = store_open(dir, err, sizeof err);
    ck_assert_ptr_nonnull(s);
    ck_assert_uint_ge(store_take_job_id(s, err, sizeof err), 3);
    uint64_t *ids;
    size_t count;
    ck_assert_int_eq(store_job_ids(s, &ids, &count, err, sizeof err), 0);
    ck_assert_uint_eq(count, 1);
    ck_assert_uint_eq(ids[0], 2);
    free(ids);
    ck_assert_int_eq(store_job_remove(s, 2, err, sizeof err), 0);
    ck_assert_int_eq(store_job_ids(s, &ids, &count, err, sizeof err), 0);
    ck_assert_uint_eq(count, 0);
    free(ids);
    store_close(&s);
    rm_rf(dir);
}
END_TEST

typedef struct seen {
    uint64_t ids[8];
    char errors[8][64];
    int n;
} seen_t;

static void on_report(void *ctx, uint64_t id, const char *error)
{
    seen_t *s = ctx;
    if (s->n < 8) {
        s->ids[s->n] = id;
        snprintf(s->errors[s->n], sizeof s->errors[s->n], "%s", error ? error : "");
        s->n++;
    }
}

static int child_writes(void *ctx, int fd)
{
    (void)ctx;
    store_bg_report(fd, 7, NULL);
    store_bg_report(fd, 8, "disk\nfull");
    return 3;
}

START_TEST(background_writer)
{
    char dir[PATHLEN], err[1024];
    fresh_dir(dir, sizeof dir, "bg");
    store_t *s = store_open(dir, err, sizeof err);
    ck_assert_ptr_nonnull(s);
    ck_assert_int_eq(store_bg_start(s, child_writes, NULL, err, sizeof err), 0);
    ck_assert(store_bg_running(s));
    /* one child at a time */
    ck_assert_int_eq(store_bg_start(s, child_writes, NULL, err, sizeof err), -1);
    seen_t seen = {0};
    int status = -1, done = 0;
    for (int i = 0; i < 5000 && !done; i++) {
        done = store_bg_poll(s, on_report, &seen, &status);
        if (!done)
            usleep(1000);
    }
    ck_assert(done);
    ck_assert_int_eq(status, 3);
    ck_assert_int_eq(seen.n, 2);
    ck_assert_uint_eq(seen.ids[0], 7);
    ck_assert_str_eq(seen.errors[0], "");
    ck_assert_uint_eq(seen.ids[1], 8);
    ck_assert_str_eq(seen.errors[1], "disk full"); /* one line per report */
    ck_assert(!store_bg_running(s));
    ck_assert_uint_eq(store_bg_last(s).runs, 1);
    store_close(&s);
    rm_rf(dir);
}
END_TEST

START_TEST(checksum_split_invariant)
{
    uint8_t data[1000], a[32], b[32];
    for (size_t i = 0; i < sizeof data; i++)
        data[i] = (uint8_t)(i ^ (i >> 3));
    store_sum_t c;
    store_sum_init(&c);
    store_sum_update(&c, data, sizeof data);
    store_sum_final(&c, a);
    for (size_t cut = 0; cut <= sizeof data; cut += 37) {
        store_sum_init(&c);
        store_sum_update(&c, data, cut);
        store_sum_update(&c, data + cut, sizeof data - cut);
        store_sum_final(&c, b);
        ck_assert_int_eq(memcmp(a, b, 32), 0);
    }
    /* a zero byte appended is another input */
    store_sum_init(&c);
    uint8_t longer[1001] = {0};
    memcpy(longer, data, sizeof data);
    store_sum_update(&c, longer, sizeof longer);
    store_sum_final(&c, b);
    ck_assert_int_ne(memcmp(a, b, 32), 0);
}
END_TEST

START_TEST(lease_fifo)
{
    lease_queue_t *q = lease_queue_new();
    ck_assert_ptr_nonnull(q);
    lease_t out;
    ck_assert_int_eq(lease_pop_sent_before(q, 100.0, &out), 0);
    ck_assert_ptr_null(lease_at(q, 0));
    /* more than the first allocation, wrapping around as it goes */
    for (uint64_t i = 0; i < 1000; i++) {
        lease_t l = {.task = i + 1, .attempt = 1, .sent = (double)i};
        ck_assert_int_eq(lease_push(q, &l), 0);
        if (i % 3 == 0) {
            ck_assert_int_eq(lease_pop_sent_before(q, 1e9, &out), 1);
        }
    }
    size_t left = lease_count(q);
    ck_assert_uint_eq(left, 1000 - 334);
    /* lease_at walks them oldest first without taking any */
    for (size_t i = 1; i < left; i++)
        ck_assert(lease_at(q, i)->sent > lease_at(q, i - 1)->sent);
    ck_assert_ptr_null(lease_at(q, left));
    ck_assert_uint_eq(lease_count(q), left);
    /* only those sent before the time, oldest first */
    double last = -1;
    size_t popped = 0;
    while (lease_pop_sent_before(q, 900.5, &out)) {
        ck_assert(out.sent < 900.5);
        ck_assert(out.sent > last);
        last = out.sent;
        popped++;
    }
    ck_assert_uint_eq(lease_count(q), left - popped);
    ck_assert_int_eq(lease_pop_sent_before(q, 900.5, &out), 0);
    ck_assert_double_eq(last, 900.0);
    lease_pop(q);
    ck_assert_uint_eq(lease_count(q), left - popped - 1);
    ck_assert_double_eq(lease_at(q, 0)->sent, 902.0); /* 901 went with lease_pop */
    lease_queue_destroy(&q);
    ck_assert_ptr_null(q);
}
END_TEST

/* The median of the window follows the job: a minority of slow tasks
 * (a straggling worker's) does not move it, a change of the job's own
 * task time does once it fills half the window. */
START_TEST(lease_task_times)
{
    lease_times_t t = {0};
    ck_assert_double_eq(lease_times_quantile(&t, 0.5), 0);
    for (int i = 0; i < LEASE_TIMES_MIN - 1; i++)
        lease_times_add(&t, 1.0);
    ck_assert_double_eq(lease_times_quantile(&t, 0.5), 0); /* too few to believe */
    lease_times_add(&t, 1.0);
    ck_assert_double_eq(lease_times_quantile(&t, 0.5), 1.0);
    /* 10 fast to 1 slow (10x): the median stays the fast time */
    for (int i = 0; i < 200; i++)
        lease_times_add(&t, i % 11 == 10 ? 10.0 : 0.25);
    ck_assert_double_eq(lease_times_quantile(&t, 0.5), 0.25);
    ck_assert_double_eq(lease_times_quantile(&t, 1.0), 10.0);
    ck_assert_double_eq(lease_times_quantile(&t, 0.0), 0.25);
    /* the job's tasks get dearer: the window follows */
    for (int i = 0; i < LEASE_TIMES; i++)
        lease_times_add(&t, 2.0);
    ck_assert_double_eq(lease_times_quantile(&t, 0.5), 2.0);
    /* not a time: ignored */
    lease_times_add(&t, -1.0);
    lease_times_add(&t, NAN);
    ck_assert_double_eq(lease_times_quantile(&t, 0.0), 2.0);
    /* the lease: factor x task time within floor and ceiling; the ceiling
     * while the task time is unknown */
    ck_assert_double_eq(lease_length(0, 8, 2, 60), 60);
    ck_assert_double_eq(lease_length(0.1, 8, 2, 60), 2);
    ck_assert_double_eq(lease_length(1.0, 8, 2, 60), 8);
    ck_assert_double_eq(lease_length(100, 8, 2, 60), 60);
}
END_TEST

/* Found by tests/fuzz_ckpt.c (libFuzzer with UBSan): a checkpoint's
 * counters are JSON numbers, and one past its integer type's range
 * ("reissued": 1e999, "rays": 1e20) was converted anyway: undefined
 * behaviour. Out of range they count as 0, as negative ones do. */
START_TEST(checkpoint_counters_out_of_range)
{
    cJSON *o = cJSON_Parse("{\"seconds\":1e999,\"rays\":1e20,\"busy_us\":18446744073709551616,"
                           "\"reissued\":1e999,\"late_results\":-5,\"failures\":4294967296}");
    job_t *j = calloc(1, sizeof *j);
    ck_assert_ptr_nonnull(o);
    ck_assert_ptr_nonnull(j);
    persist_apply_extras(j, o);
    ck_assert(j->run_before == 0);
    ck_assert_uint_eq(j->rays, 0);
    ck_assert_uint_eq(j->busy_us, 0);
    ck_assert_uint_eq(j->reissued, 0);
    ck_assert_uint_eq(j->late_results, 0);
    ck_assert_uint_eq(j->failures, 0);
    cJSON_Delete(o);
    /* in range: as they are */
    o = cJSON_Parse("{\"seconds\":2.5,\"rays\":9007199254740992,\"busy_us\":18446744073709549568,"
                    "\"reissued\":4294967295,\"late_results\":3,\"failures\":8}");
    ck_assert_ptr_nonnull(o);
    persist_apply_extras(j, o);
    ck_assert(j->run_before == 2.5);
    ck_assert_uint_eq(j->rays, UINT64_C(9007199254740992));
    ck_assert_uint_eq(j->busy_us, UINT64_C(18446744073709549568));
    ck_assert_uint_eq(j->reissued, 4294967295u);
    ck_assert_uint_eq(j->late_results, 3);
    ck_assert_uint_eq(j->failures, 8);
    cJSON_Delete(o);
    job_free(j);
}
END_TEST

/* The journal: what the writer seals reads back commit by commit, task by
 * task, record by record (pixels and finite counts from the task); a torn
 * or corrupt last record is refused with the position of the last good one;
 * a snapshot (journal_restart) drops what it holds. */
START_TEST(journal_round_trip)
{
    for (uint32_t flags = 0; flags <= (JOURNAL_PVAR | JOURNAL_RAYS | JOURNAL_NF8); flags++) {
        journal_t *j = journal_new(9, 2, flags);
        ck_assert_ptr_nonnull(j);
        tracer_result_t r[3];
        tracer_task_t task[3];
        for (uint32_t i = 0; i < 3; i++) {
            task[i] = (tracer_task_t){.pixel = 10 + i, .sample_count = 16};
            r[i] = (tracer_result_t){.pixel = 10 + i,
                                     .samples = 16 - i,
                                     .nonfinite = i,
                                     .rays = 40 + i,
                                     .sum = {1.0 / 3, 2, 3e20},
                                     .lum_m2 = 0.5 * i,
                                     .pvar = 0.25 + i};
        }
        ck_assert_int_eq(journal_note(j, 5, r, 3), 0);
        ck_assert_int_eq(journal_note(j, 6, r, 2), 0);
        ck_assert_uint_eq(journal_pending(j),
                          2 * JOURNAL_TASK_HEADER + 5 * journal_pixel_size(flags));
        ck_assert_int_eq(journal_seal(j, "{\"rays\":1}", 10), 0);
        ck_assert_int_eq(journal_note(j, 7, r + 1, 1), 0);
        ck_assert_int_eq(journal_seal(j, "{}", 2), 0);
        journal_header_t h = {
            .version = JOURNAL_VERSION, .flags = flags, .generation = 2, .job = 9};
        uint8_t *body;
        size_t n;
        journal_take_unwritten(j, &body, &n);
        ck_assert_uint_eq(journal_unwritten(j), 0);
        uint8_t *file = malloc(JOURNAL_HEADER_SIZE + n);
        journal_header_encode(&h, file);
        memcpy(file + JOURNAL_HEADER_SIZE, body, n);
        size_t size = JOURNAL_HEADER_SIZE + n;
        journal_reader_t rd;
        char err[256];
        ck_assert_int_eq(journal_reader_init(&rd, file, size, err, sizeof err), 0);
        ck_assert_uint_eq(rd.header.generation, 2);
        ck_assert_uint_eq(rd.header.flags, flags);
        journal_commit_t c;
        ck_assert_int_eq(journal_next(&rd, &c, err, sizeof err), 1);
        ck_assert_uint_eq(c.seq, 1);
        ck_assert(c.extras_len == 10 && memcmp(c.extras, "{\"rays\":1}", 10) == 0);
        journal_tasks_t it;
        journal_tasks_init(&it, &c, flags);
        uint64_t id;
        uint32_t count;
        const uint8_t *rec;
        ck_assert_int_eq(journal_task_next(&it, &id, &count, &rec), 1);
        ck_assert(id == 5 && count == 3);
        for (uint32_t i = 0; i < 3; i++) {
            tracer_result_t back;
            ck_assert_int_eq(journal_result(rec, i, flags, &task[i], &back), 0);
            tracer_result_t want = r[i];
            if (!(flags & JOURNAL_PVAR))
                want.pvar = 0;
            if (!(flags & JOURNAL_RAYS)) /* one ray a sample */
                want.rays = task[i].sample_count;
            ck_assert(memcmp(&back, &want, sizeof back) == 0);
        }
        ck_assert_int_eq(journal_task_next(&it, &id, &count, &rec), 1);
        ck_assert(id == 6 && count == 2);
        ck_assert_int_eq(journal_task_next(&it, &id, &count, &rec), 0);
        size_t first_end = rd.pos;
        ck_assert_int_eq(journal_next(&rd, &c, err, sizeof err), 1);
        ck_assert_uint_eq(c.seq, 2);
        ck_assert_int_eq(journal_next(&rd, &c, err, sizeof err), 0);
        /* torn: the second commit cut short */
        ck_assert_int_eq(journal_reader_init(&rd, file, size - 3, err, sizeof err), 0);
        ck_assert_int_eq(journal_next(&rd, &c, err, sizeof err), 1);
        ck_assert_int_eq(journal_next(&rd, &c, err, sizeof err), -1);
        ck_assert_msg(strstr(err, "torn"), "%s", err);
        ck_assert_uint_eq(rd.pos, first_end);
        /* corrupt: any byte of the second commit's payload flipped (each
         * byte feeds one of the checksum's four lanes) */
        for (size_t at = first_end + 12; at < size - 8; at++) {
            file[at] ^= 1;
            ck_assert_int_eq(journal_reader_init(&rd, file, size, err, sizeof err), 0);
            ck_assert_int_eq(journal_next(&rd, &c, err, sizeof err), 1);
            ck_assert_msg(journal_next(&rd, &c, err, sizeof err) == -1,
                          "flags %u: byte %zu flipped, accepted", flags, at);
            ck_assert_msg(strstr(err, "checksum"), "%s", err);
            ck_assert_uint_eq(rd.pos, first_end);
            file[at] ^= 1;
        }
        file[size - 12] ^= 1;
        /* a newer journal format is refused */
        file[8] = JOURNAL_VERSION + 1;
        ck_assert_int_eq(journal_reader_init(&rd, file, size, err, sizeof err), -1);
        ck_assert_msg(strstr(err, "version"), "%s", err);
        free(file);
        free(body);
        /* a snapshot taken with 1 task noted: only what came after stays */
        ck_assert_int_eq(journal_note(j, 8, r, 1), 0);
        size_t at = journal_pending(j);
        ck_assert_int_eq(journal_note(j, 9, r, 2), 0);
        journal_restart(j, 3, at);
        ck_assert_uint_eq(journal_next_seq(j), 1);
        ck_assert_uint_eq(journal_generation(j), 3);
        ck_assert_uint_eq(journal_pending(j), JOURNAL_TASK_HEADER + 2 * journal_pixel_size(flags));
        journal_destroy(&j);
        ck_assert_ptr_null(j);
    }
}
END_TEST

/* journal_create: a header-only journal, crash-safe. */
START_TEST(journal_created)
{
    char dir[4096], path[4200], err[256];
    tu_tmp_path(dir, sizeof dir, "journal-create");
    mkdir(dir, 0700);
    snprintf(path, sizeof path, "%s/journal", dir);
    journal_header_t h = {.version = JOURNAL_VERSION, .generation = 7, .job = 3};
    ck_assert_msg(journal_create(path, &h, err, sizeof err) == 0, "%s", err);
    struct stat st;
    ck_assert_int_eq(stat(path, &st), 0);
    ck_assert_int_eq(st.st_size, JOURNAL_HEADER_SIZE);
    unlink(path);
    rmdir(dir);
}
END_TEST

static Suite *store_suite(void)
{
    Suite *s = suite_create("store");
    TCase *tc = tcase_create("store");
    tcase_set_timeout(tc, 60);
    tcase_add_test(tc, record_round_trip);
    tcase_add_test(tc, record_sizes_across_blocks);
    tcase_add_test(tc, append_across_blocks);
    tcase_add_test(tc, record_damage_found);
    tcase_add_test(tc, keep_prev);
    tcase_add_test(tc, job_ids_increase);
    tcase_add_test(tc, background_writer);
    tcase_add_test(tc, checksum_split_invariant);
    tcase_add_test(tc, lease_fifo);
    tcase_add_test(tc, lease_task_times);
    tcase_add_test(tc, checkpoint_counters_out_of_range);
    tcase_add_test(tc, journal_round_trip);
    tcase_add_test(tc, journal_created);
    suite_add_tcase(s, tc);
    return s;
}

int main(void)
{
    SRunner *sr = srunner_create(store_suite());
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed == 0 ? EXIT_SUCCESS : EXIT_FAILURE;
}
