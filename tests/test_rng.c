/* test_rng.c - the counter-based sampler: purity, range, uniformity and
 * independence across dimensions, samples, pixels and seeds.
 *
 * Chi-square statistics are compared with mean + 6 standard deviations of
 * their distribution (k - 1 + 6 sqrt(2 (k - 1))): a real defect (a stuck
 * bit, a correlated stream) exceeds that by orders of magnitude, chance
 * almost never does. */
#include <check.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "rng.h"

static double chi2_limit(int cells)
{
    double dof = cells - 1;
    return dof + 6.0 * sqrt(2.0 * dof);
}

START_TEST(test_pure_function)
{
    for (uint64_t s = 0; s < 4; s++) {
        rng_stream_t a = rng_stream(s, 1234, 99), b = rng_stream(s, 1234, 99);
        for (int d = 0; d < 64; d++)
            ck_assert(rng_next_float(&a) == rng_next_float(&b));
        /* random access equals sequential */
        rng_stream_t c = rng_stream(s, 1234, 99);
        ck_assert(rng_bits_at(&c, 17) == rng_bits_at(&c, 17));
        for (int d = 0; d < 17; d++)
            (void)rng_next_float(&c);
        ck_assert_uint_eq(c.dim, 17);
    }
    /* every coordinate matters */
    rng_stream_t base = rng_stream(1, 2, 3);
    rng_stream_t others[3] = {rng_stream(2, 2, 3), rng_stream(1, 3, 3), rng_stream(1, 2, 4)};
    for (int i = 0; i < 3; i++)
        ck_assert(rng_bits_at(&base, 0) != rng_bits_at(&others[i], 0));
    /* swapping pixel and sample index gives another stream */
    rng_stream_t sw1 = rng_stream(1, 5, 9), sw2 = rng_stream(1, 9, 5);
    ck_assert(rng_bits_at(&sw1, 0) != rng_bits_at(&sw2, 0));
}
END_TEST

START_TEST(test_range)
{
    float lo = 1, hi = 0;
    for (uint64_t i = 0; i < 200000; i++) {
        rng_stream_t s = rng_stream(7, i, i >> 3);
        for (int d = 0; d < 4; d++) {
            float u = rng_next_float(&s);
            ck_assert(u >= 0.0f && u < 1.0f);
            double v = rng_next_double(&s);
            ck_assert(v >= 0.0 && v < 1.0);
            lo = u < lo ? u : lo;
            hi = u > hi ? u : hi;
        }
    }
    ck_assert(lo < 1e-4f && hi > 1.0f - 1e-4f);
}
END_TEST

/* 1D uniformity of each of the first 16 dimensions over many samples. */
START_TEST(test_uniform_per_dimension)
{
    enum { BINS = 64, N = 200000 };
    for (int d = 0; d < 16; d++) {
        uint32_t hist[BINS] = {0};
        for (uint64_t i = 0; i < N; i++) {
            rng_stream_t s = rng_stream(3, i % 4096, i / 4096);
            s.dim = (uint64_t)d;
            hist[(int)(rng_next_float(&s) * BINS)]++;
        }
        double e = (double)N / BINS, chi2 = 0;
        for (int b = 0; b < BINS; b++)
            chi2 += (hist[b] - e) * (hist[b] - e) / e;
        ck_assert_msg(chi2 < chi2_limit(BINS), "dimension %d: chi2 %.1f", d, chi2);
    }
}
END_TEST

typedef float (*pair_fn)(uint64_t i, int which);

/* 2D chi-square of (first, second) pairs on a 16 x 16 grid. */
static double pair_chi2(pair_fn f, uint64_t n)
{
    enum { G = 16 };
    static uint32_t hist[G][G];
    memset(hist, 0, sizeof hist);
    for (uint64_t i = 0; i < n; i++)
        hist[(int)(f(i, 0) * G)][(int)(f(i, 1) * G)]++;
    double e = (double)n / (G * G), chi2 = 0;
    for (int a = 0; a < G; a++)
        for (int b = 0; b < G; b++)
            chi2 += (hist[a][b] - e) * (hist[a][b] - e) / e;
    return chi2;
}

static float dims_pair(uint64_t i, int which)
{
    rng_stream_t s = rng_stream(11, i, 0);
    s.dim = (uint64_t)which; /* consecutive dimensions of one sample */
    return rng_next_float(&s);
}
static float samples_pair(uint64_t i, int which)
{
    rng_stream_t s = rng_stream(11, 77, 2 * i + (uint64_t)which); /* neighbouring samples */
    return rng_next_float(&s);
}
static float pixels_pair(uint64_t i, int which)
{
    rng_stream_t s = rng_stream(11, 2 * i + (uint64_t)which, 5); /* neighbouring pixels */
    return rng_next_float(&s);
}
static float seeds_pair(uint64_t i, int which)
{
    rng_stream_t s = rng_stream(100 + (uint64_t)which, i, 0); /* neighbouring seeds */
    return rng_next_float(&s);
}
static float layers_pair(uint64_t i, int which)
{
    /* the same sample slot in two consecutive layers of G = 32 */
    rng_stream_t s = rng_stream(11, i / 32, (i % 32) + 32 * (uint64_t)which);
    return rng_next_float(&s);
}

START_TEST(test_independence)
{
    const struct {
        const char *what;
        pair_fn f;
    } cases[] = {{"dimensions", dims_pair},
                 {"samples", samples_pair},
                 {"pixels", pixels_pair},
                 {"seeds", seeds_pair},
                 {"layers", layers_pair}};
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++) {
        double chi2 = pair_chi2(cases[c].f, 256000);
        ck_assert_msg(chi2 < chi2_limit(256), "%s: 2D chi2 %.1f", cases[c].what, chi2);
        /* and no linear correlation beyond 6 / sqrt(n) */
        double sx = 0, sy = 0, sxy = 0, sxx = 0, syy = 0;
        const int n = 200000;
        for (uint64_t i = 0; i < (uint64_t)n; i++) {
            double x = cases[c].f(i, 0), y = cases[c].f(i, 1);
            sx += x;
            sy += y;
            sxy += x * y;
            sxx += x * x;
            syy += y * y;
        }
        double r = (sxy - sx * sy / n) / sqrt((sxx - sx * sx / n) * (syy - sy * sy / n));
        ck_assert_msg(fabs(r) < 6.0 / sqrt(n), "%s: correlation %.5f", cases[c].what, r);
    }
}
END_TEST

/* A weak mixer fails these checks: the test can tell (a stream whose
 * dimensions are the plain counter is visibly correlated). */
START_TEST(test_checks_catch_a_bad_generator)
{
    enum { G = 16 };
    static uint32_t hist[G][G];
    memset(hist, 0, sizeof hist);
    const uint64_t n = 256000;
    for (uint64_t i = 0; i < n; i++) {
        float a = (float)((i * 2654435761u) & 0xffffff) * 0x1.0p-24f;
        float b = (float)(((i * 2654435761u) + 1) & 0xffffff) * 0x1.0p-24f;
        hist[(int)(a * G)][(int)(b * G)]++;
    }
    double e = (double)n / (G * G), chi2 = 0;
    for (int x = 0; x < G; x++)
        for (int y = 0; y < G; y++)
            chi2 += (hist[x][y] - e) * (hist[x][y] - e) / e;
    ck_assert(chi2 > chi2_limit(256));
}
END_TEST

int main(void)
{
    Suite *s = suite_create("rng");
    TCase *tc = tcase_create("sampler");
    tcase_set_timeout(tc, 300);
    tcase_add_test(tc, test_pure_function);
    tcase_add_test(tc, test_range);
    tcase_add_test(tc, test_uniform_per_dimension);
    tcase_add_test(tc, test_independence);
    tcase_add_test(tc, test_checks_catch_a_bad_generator);
    suite_add_tcase(s, tc);
    SRunner *sr = srunner_create(s);
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed ? 1 : 0;
}
