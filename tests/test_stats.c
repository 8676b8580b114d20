/* test_stats.c - t quantiles against published table values. */
#include <check.h>
#include <math.h>

#include "stats.h"

START_TEST(test_t_table)
{
    const struct {
        double conf, dof, t;
    } rows[] = {{0.95, 1, 12.7062}, {0.95, 2, 4.3027}, {0.95, 3, 3.1824},  {0.95, 10, 2.2281},
                {0.95, 30, 2.0423}, {0.99, 5, 4.0321}, {0.90, 20, 1.7247}, {0.95, 1e6, 1.95996}};
    for (size_t i = 0; i < sizeof rows / sizeof rows[0]; i++) {
        double t = stats_t_two_sided(rows[i].conf, rows[i].dof);
        ck_assert_msg(fabs(t - rows[i].t) < 2e-4 * rows[i].t, "t(%g, %g) = %.5f, table %.5f",
                      rows[i].conf, rows[i].dof, t, rows[i].t);
    }
    ck_assert(fabs(stats_t_cdf(0, 4) - 0.5) < 1e-12);
    ck_assert(fabs(stats_t_cdf(2.7764, 4) - 0.975) < 1e-5);
    ck_assert(fabs(stats_t_cdf(-2.7764, 4) - 0.025) < 1e-5);
}
END_TEST

int main(void)
{
    Suite *s = suite_create("stats");
    TCase *tc = tcase_create("t");
    tcase_add_test(tc, test_t_table);
    suite_add_tcase(s, tc);
    SRunner *sr = srunner_create(s);
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed ? 1 : 0;
}
