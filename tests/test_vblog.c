/* test_vblog.c - log lines: control bytes escaped so a peer's text cannot
 * forge a line; the per-key rate limiter's burst, summary, independence of
 * keys, window reset and a full key table; levels (--log-level): names,
 * the filter, and filtered lines left out of the rate limit. (The flag
 * itself, on every binary, is tested in test_cli.c.) */
#include <check.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>

#include "vblog.h"

/* Everything written to f so far, NUL-terminated; the caller frees it. */
static char *slurp(FILE *f)
{
    fflush(f);
    long n = ftell(f);
    ck_assert(n >= 0);
    char *buf = malloc((size_t)n + 1);
    ck_assert_ptr_nonnull(buf);
    rewind(f);
    ck_assert_uint_eq(fread(buf, 1, (size_t)n, f), (size_t)n);
    buf[n] = '\0';
    return buf;
}

static size_t count(const char *text, const char *needle)
{
    size_t n = 0;
    for (const char *p = text; (p = strstr(p, needle)) != NULL; p += strlen(needle))
        n++;
    return n;
}

static void put(FILE *f, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void put(FILE *f, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vblog_write(f, "master", fmt, ap);
    va_end(ap);
}

static void lim(vblog_limiter_t *l, FILE *f, const char *key, double now, const char *fmt, ...)
    __attribute__((format(printf, 5, 6)));
static void lim(vblog_limiter_t *l, FILE *f, const char *key, double now, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vblog_limited(l, f, "master", key, now, fmt, ap);
    va_end(ap);
}

START_TEST(test_escape)
{
    FILE *f = tmpfile();
    ck_assert_ptr_nonnull(f);
    put(f, "job %s queued",
        "evil\n2026-01-01T00:00:00.000Z master: fake\x1b[31m a\\b \x7f caf\xc3\xa9");
    char *out = slurp(f);
    ck_assert_uint_eq(count(out, "\n"), 1);
    ck_assert_int_eq(out[strlen(out) - 1], '\n');
    ck_assert_ptr_nonnull(
        strstr(out, "Z master: job evil\\x0a2026-01-01T00:00:00.000Z master: fake\\x1b[31m "
                    "a\\\\b \\x7f caf\xc3\xa9 queued\n"));
    /* the stamp: 2026-11-23T14:53:46.051Z */
    ck_assert_uint_ge(strlen(out), 25);
    ck_assert_int_eq(out[4], '-');
    ck_assert_int_eq(out[10], 'T');
    ck_assert_int_eq(out[19], '.');
    ck_assert_int_eq(out[23], 'Z');
    ck_assert_int_eq(out[24], ' ');
    free(out);
    fclose(f);
}
END_TEST

START_TEST(test_burst_and_summary)
{
    FILE *f = tmpfile();
    ck_assert_ptr_nonnull(f);
    vblog_limiter_t l = {0};
    const double t0 = 1000.0;
    for (int i = 0; i < 1000; i++)
        lim(&l, f, "malformed", t0 + 0.001 * i, "bad message %d", i);
    char *out = slurp(f);
    ck_assert_uint_eq(count(out, "\n"), VBLOG_BURST);
    ck_assert_uint_eq(count(out, "bad message"), VBLOG_BURST);
    ck_assert_ptr_nonnull(strstr(out, "master: bad message 9\n"));
    ck_assert_ptr_null(strstr(out, "bad message 10\n"));
    free(out);
    /* the window has not ended: nothing to summarise yet */
    vblog_limiter_flush(&l, f, "master", t0 + VBLOG_WINDOW_S / 2);
    out = slurp(f);
    ck_assert_uint_eq(count(out, "\n"), VBLOG_BURST);
    free(out);
    vblog_limiter_flush(&l, f, "master", t0 + VBLOG_WINDOW_S);
    out = slurp(f);
    ck_assert_uint_eq(count(out, "\n"), VBLOG_BURST + 1);
    ck_assert_ptr_nonnull(
        strstr(out, "Z master: 990 more like this in the last 10 s: bad message 999\n"));
    free(out);
    /* summarised once only */
    vblog_limiter_flush(&l, f, "master", t0 + 3 * VBLOG_WINDOW_S);
    out = slurp(f);
    ck_assert_uint_eq(count(out, "\n"), VBLOG_BURST + 1);
    free(out);
    fclose(f);
}
END_TEST

START_TEST(test_summary_escaped_on_next_line)
{
    FILE *f = tmpfile();
    ck_assert_ptr_nonnull(f);
    vblog_limiter_t l = {0};
    for (int i = 0; i < VBLOG_BURST + 3; i++)
        lim(&l, f, "refused", 5.0, "refused %s", "a\nb");
    /* the next line of the key after the window brings the summary first */
    lim(&l, f, "refused", 5.0 + VBLOG_WINDOW_S + 1, "refused later");
    char *out = slurp(f);
    ck_assert_uint_eq(count(out, "\n"), VBLOG_BURST + 2);
    ck_assert_uint_eq(count(out, "refused a\\x0ab\n"), VBLOG_BURST + 1);
    const char *sum = strstr(out, "master: 3 more like this in the last 10 s: refused a\\x0ab\n");
    ck_assert_ptr_nonnull(sum);
    const char *later = strstr(out, "master: refused later\n");
    ck_assert_ptr_nonnull(later);
    ck_assert(sum < later);
    free(out);
    fclose(f);
}
END_TEST

START_TEST(test_keys_independent)
{
    FILE *f = tmpfile();
    ck_assert_ptr_nonnull(f);
    vblog_limiter_t l = {0};
    for (int i = 0; i < 50; i++) {
        lim(&l, f, "malformed", 1.0 + 0.01 * i, "A %d", i);
        lim(&l, f, "late", 1.0 + 0.01 * i, "B %d", i);
    }
    char *out = slurp(f);
    ck_assert_uint_eq(count(out, "\n"), 2 * VBLOG_BURST);
    ck_assert_uint_eq(count(out, "master: A "), VBLOG_BURST);
    ck_assert_uint_eq(count(out, "master: B "), VBLOG_BURST);
    free(out);
    vblog_limiter_flush(&l, f, "master", 1.0 + VBLOG_WINDOW_S);
    out = slurp(f);
    ck_assert_uint_eq(count(out, "\n"), 2 * VBLOG_BURST + 2);
    ck_assert_ptr_nonnull(strstr(out, "40 more like this in the last 10 s: A 49\n"));
    ck_assert_ptr_nonnull(strstr(out, "40 more like this in the last 10 s: B 49\n"));
    free(out);
    fclose(f);
}
END_TEST

START_TEST(test_window_reset)
{
    FILE *f = tmpfile();
    ck_assert_ptr_nonnull(f);
    vblog_limiter_t l = {0};
    for (int i = 0; i < 15; i++)
        lim(&l, f, "k", 0.0, "first %d", i);
    /* just inside the window: still held back */
    lim(&l, f, "k", VBLOG_WINDOW_S - 0.001, "first 15");
    for (int i = 0; i < 15; i++)
        lim(&l, f, "k", VBLOG_WINDOW_S, "second %d", i);
    char *out = slurp(f);
    ck_assert_uint_eq(count(out, "master: first "), VBLOG_BURST);
    ck_assert_ptr_nonnull(strstr(out, "master: 6 more like this in the last 10 s: first 15\n"));
    ck_assert_uint_eq(count(out, "master: second "), VBLOG_BURST);
    ck_assert_uint_eq(count(out, "\n"), 2 * VBLOG_BURST + 1);
    free(out);
    vblog_limiter_flush(&l, f, "master", 2 * VBLOG_WINDOW_S);
    out = slurp(f);
    ck_assert_ptr_nonnull(strstr(out, "master: 5 more like this in the last 10 s: second 14\n"));
    ck_assert_uint_eq(count(out, "\n"), 2 * VBLOG_BURST + 2);
    free(out);
    fclose(f);
}
END_TEST

START_TEST(test_more_keys_than_slots)
{
    enum { NKEYS = 3 * VBLOG_KEYS + 4, PER = VBLOG_BURST + 2 };
    char keys[NKEYS][24];
    for (int k = 0; k < NKEYS; k++)
        snprintf(keys[k], sizeof keys[k], "kind-%d", k);
    FILE *f = tmpfile();
    ck_assert_ptr_nonnull(f);
    vblog_limiter_t l = {0};
    /* each key over its burst in turn: an evicted key's pending count is
     * written when its slot is reused, the rest at the flush */
    for (int k = 0; k < NKEYS; k++)
        for (int i = 0; i < PER; i++)
            lim(&l, f, keys[k], 1.0, "%s line %d", keys[k], i);
    vblog_limiter_flush(&l, f, "master", 1.0 + VBLOG_WINDOW_S);
    char *out = slurp(f);
    ck_assert_uint_eq(count(out, "\n"), (size_t)NKEYS * (VBLOG_BURST + 1));
    ck_assert_uint_eq(count(out, "2 more like this in the last 10 s: "), NKEYS);
    for (int k = 0; k < NKEYS; k++) {
        char want[128 + sizeof keys]; /* GCC bounds keys[k] by the whole array */
        snprintf(want, sizeof want, "master: 2 more like this in the last 10 s: %s line %d\n",
                 keys[k], PER - 1);
        ck_assert_msg(strstr(out, want) != NULL, "no summary for %s", keys[k]);
    }
    free(out);
    fclose(f);

    /* keys cycling through more kinds than slots: each comes back to a
     * fresh slot, so the lines are all written rather than lost */
    f = tmpfile();
    ck_assert_ptr_nonnull(f);
    vblog_limiter_t l2 = {0};
    enum { CYCLE = VBLOG_KEYS + 8, ROUNDS = 20 };
    for (int r = 0; r < ROUNDS; r++)
        for (int k = 0; k < CYCLE; k++)
            lim(&l2, f, keys[k], 1.0, "round %d", r);
    vblog_limiter_flush(&l2, f, "master", 1.0 + VBLOG_WINDOW_S);
    out = slurp(f);
    ck_assert_uint_eq(count(out, "\n"), (size_t)CYCLE * ROUNDS);
    ck_assert_uint_eq(count(out, "more like this"), 0);
    free(out);
    fclose(f);
}
END_TEST

START_TEST(test_null_out_and_key)
{
    vblog_limiter_t l = {0};
    /* no stream: nothing written, nothing counted */
    for (int i = 0; i < 3 * VBLOG_BURST; i++)
        lim(&l, NULL, "k", 0.0, "x %d", i);
    vblog_limiter_flush(&l, NULL, "master", 100.0);
    FILE *f = tmpfile();
    ck_assert_ptr_nonnull(f);
    for (int i = 0; i < VBLOG_BURST; i++)
        lim(&l, f, "k", 0.0, "y %d", i);
    /* no key: never limited */
    for (int i = 0; i < 3 * VBLOG_BURST; i++)
        lim(&l, f, NULL, 0.0, "z %d", i);
    char *out = slurp(f);
    ck_assert_uint_eq(count(out, "master: y "), VBLOG_BURST);
    ck_assert_uint_eq(count(out, "master: z "), 3 * VBLOG_BURST);
    free(out);
    fclose(f);
}
END_TEST

/* A line at level under threshold, as the daemons' log functions write it. */
static void put_at(FILE *f, int threshold, vblog_level_t level, const char *text)
{
    put(vblog_filter(f, threshold, level), "%s", text);
}

START_TEST(test_level_names)
{
    static const char *const names[] = {"error", "warn", "info", "debug"};
    for (int i = 0; i < 4; i++) {
        ck_assert_int_eq(vblog_level_parse(names[i]), VBLOG_ERROR + i);
        ck_assert_str_eq(vblog_level_name(VBLOG_ERROR + i), names[i]);
    }
    /* a bad level: the flag's parser turns -1 into a usage error */
    ck_assert_int_eq(vblog_level_parse("loud"), -1);
    ck_assert_int_eq(vblog_level_parse("INFO"), -1);
    ck_assert_int_eq(vblog_level_parse(""), -1);
    ck_assert_int_eq(vblog_level_parse(NULL), -1);
    ck_assert_str_eq(vblog_level_name(0), "?");
}
END_TEST

START_TEST(test_level_filter)
{
    FILE *f = tmpfile();
    ck_assert_ptr_nonnull(f);
    put_at(f, VBLOG_INFO, VBLOG_DEBUG, "debug at info");
    put_at(f, VBLOG_INFO, VBLOG_INFO, "info at info");
    put_at(f, VBLOG_INFO, VBLOG_ERROR, "error at info");
    put_at(f, VBLOG_DEBUG, VBLOG_DEBUG, "debug at debug");
    put_at(f, 0, VBLOG_DEBUG, "debug at default");
    put_at(f, 0, VBLOG_INFO, "info at default");
    put_at(f, VBLOG_ERROR, VBLOG_WARN, "warn at error");
    put_at(f, VBLOG_ERROR, VBLOG_ERROR, "error at error");
    char *out = slurp(f);
    ck_assert_ptr_null(strstr(out, "debug at info"));
    ck_assert_ptr_nonnull(strstr(out, "info at info"));
    ck_assert_ptr_nonnull(strstr(out, "error at info"));
    ck_assert_ptr_nonnull(strstr(out, "debug at debug"));
    ck_assert_ptr_null(strstr(out, "debug at default"));
    ck_assert_ptr_nonnull(strstr(out, "info at default"));
    ck_assert_ptr_null(strstr(out, "warn at error"));
    ck_assert_ptr_nonnull(strstr(out, "error at error"));
    ck_assert_uint_eq(count(out, "\n"), 5);
    free(out);
    fclose(f);
}
END_TEST

/* A filtered line is not counted against its key's burst: once the level
 * lets them through, the full burst is written. */
START_TEST(test_filtered_not_limited)
{
    vblog_limiter_t l = {0};
    FILE *f = tmpfile();
    ck_assert_ptr_nonnull(f);
    for (int i = 0; i < 3 * VBLOG_BURST; i++)
        lim(&l, vblog_filter(f, VBLOG_ERROR, VBLOG_WARN), "refused", 0.0, "hidden %d", i);
    for (int i = 0; i < VBLOG_BURST; i++)
        lim(&l, vblog_filter(f, VBLOG_WARN, VBLOG_WARN), "refused", 1.0, "shown %d", i);
    vblog_limiter_flush(&l, f, "master", 100.0);
    char *out = slurp(f);
    ck_assert_uint_eq(count(out, "master: shown "), VBLOG_BURST);
    ck_assert_ptr_null(strstr(out, "hidden"));
    ck_assert_ptr_null(strstr(out, "more like this"));
    free(out);
    fclose(f);
}
END_TEST

int main(void)
{
    Suite *s = suite_create("vblog");
    TCase *tc = tcase_create("escape");
    tcase_add_test(tc, test_escape);
    suite_add_tcase(s, tc);
    tc = tcase_create("limit");
    tcase_add_test(tc, test_burst_and_summary);
    tcase_add_test(tc, test_summary_escaped_on_next_line);
    tcase_add_test(tc, test_keys_independent);
    tcase_add_test(tc, test_window_reset);
    tcase_add_test(tc, test_more_keys_than_slots);
    tcase_add_test(tc, test_null_out_and_key);
    suite_add_tcase(s, tc);
    tc = tcase_create("level");
    tcase_add_test(tc, test_level_names);
    tcase_add_test(tc, test_level_filter);
    tcase_add_test(tc, test_filtered_not_limited);
    suite_add_tcase(s, tc);
    SRunner *sr = srunner_create(s);
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed ? 1 : 0;
}
