/* test_verify.c - which tasks the master verifies by replication
 * (master/verify.c): a pure function of (job seed, task id) and the share,
 * so a job checks the same tasks on every run and after a restart. */
#include <check.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#include "master_priv.h"

#define IDS 10000

static int count(uint64_t seed, double share)
{
    int n = 0;
    for (uint64_t id = 1; id <= IDS; id++)
        n += verify_selected(seed, id, share);
    return n;
}

START_TEST(test_same_seed_same_tasks)
{
    for (uint64_t id = 1; id <= IDS; id++)
        ck_assert_int_eq(verify_selected(7, id, 0.3), verify_selected(7, id, 0.3));
    /* another seed chooses another set of about the same size */
    int differ = 0;
    for (uint64_t id = 1; id <= IDS; id++)
        differ += verify_selected(7, id, 0.3) != verify_selected(8, id, 0.3);
    ck_assert_msg(differ > IDS / 5, "seeds 7 and 8 choose sets that differ in only %d of %d ids",
                  differ, IDS);
}
END_TEST

START_TEST(test_share_zero_and_one)
{
    static const uint64_t seeds[] = {0, 1, 42, UINT64_MAX};
    for (size_t s = 0; s < sizeof seeds / sizeof seeds[0]; s++) {
        ck_assert_int_eq(count(seeds[s], 0.0), 0);
        ck_assert_int_eq(count(seeds[s], -1.0), 0);
        ck_assert_int_eq(count(seeds[s], NAN), 0);
        ck_assert_int_eq(count(seeds[s], 1.0), IDS);
        ck_assert_int_eq(count(seeds[s], 2.0), IDS);
    }
    ck_assert(verify_selected(3, UINT64_MAX, 1.0));
    ck_assert(!verify_selected(3, UINT64_MAX, 0.0));
}
END_TEST

/* About p of 10,000 ids, within 5 standard deviations of a binomial, for
 * several seeds; and a share's set grows with the share (one threshold on
 * one hash per id), so 0.01 picks a subset of what 0.25 picks. */
START_TEST(test_share_p)
{
    static const double shares[] = {0.01, 0.1, 0.25, 0.5, 0.9};
    for (uint64_t seed = 1; seed <= 5; seed++)
        for (size_t k = 0; k < sizeof shares / sizeof shares[0]; k++) {
            double p = shares[k], sd = sqrt(IDS * p * (1 - p));
            int n = count(seed * 1000003, p);
            ck_assert_msg(fabs(n - IDS * p) <= 5 * sd, "seed %llu share %g: %d of %d ids",
                          (unsigned long long)seed, p, n, IDS);
        }
    for (uint64_t id = 1; id <= IDS; id++)
        if (verify_selected(99, id, 0.01))
            ck_assert(verify_selected(99, id, 0.25));
}
END_TEST

static Suite *verify_suite(void)
{
    Suite *s = suite_create("verify");
    TCase *tc = tcase_create("selection");
    tcase_add_test(tc, test_same_seed_same_tasks);
    tcase_add_test(tc, test_share_zero_and_one);
    tcase_add_test(tc, test_share_p);
    suite_add_tcase(s, tc);
    return s;
}

int main(void)
{
    SRunner *sr = srunner_create(verify_suite());
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed == 0 ? EXIT_SUCCESS : EXIT_FAILURE;
}
