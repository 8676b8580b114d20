/* stats.c - see stats.h. The t CDF through the regularised incomplete beta
 * function (continued fraction, Lentz's method); quantiles by bisection,
 * which is plenty fast for a value computed once per job and dof. */
#include "stats.h"

#include <math.h>

/* Lentz's method: the floor that keeps a denominator off zero, the
 * relative change that ends the fraction, and the most terms taken. */
#define STATS_CF_TINY 1e-300
#define STATS_CF_EPS 1e-15
#define STATS_CF_MAX_TERMS 300
/* The quantile's bisection: the largest t tried, the most halvings, and
 * the relative width that ends it. */
#define STATS_T_MAX 1e12
#define STATS_BISECT_STEPS 200
#define STATS_BISECT_REL_WIDTH 1e-12

static double beta_cf(double a, double b, double x)
{
    const double tiny = STATS_CF_TINY, eps = STATS_CF_EPS;
    double qab = a + b, qap = a + 1, qam = a - 1, c = 1, d = 1 - qab * x / qap;
    if (fabs(d) < tiny)
        d = tiny;
    d = 1 / d;
    double h = d;
    for (int m = 1; m <= STATS_CF_MAX_TERMS; m++) {
        int m2 = 2 * m;
        double aa = m * (b - m) * x / ((qam + m2) * (a + m2));
        d = 1 + aa * d;
        if (fabs(d) < tiny)
            d = tiny;
        c = 1 + aa / c;
        if (fabs(c) < tiny)
            c = tiny;
        d = 1 / d;
        h *= d * c;
        aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2));
        d = 1 + aa * d;
        if (fabs(d) < tiny)
            d = tiny;
        c = 1 + aa / c;
        if (fabs(c) < tiny)
            c = tiny;
        d = 1 / d;
        double del = d * c;
        h *= del;
        if (fabs(del - 1) < eps)
            break;
    }
    return h;
}

/* I_x(a, b) */
static double inc_beta(double a, double b, double x)
{
    if (x <= 0)
        return 0;
    if (x >= 1)
        return 1;
    double bt = exp(lgamma(a + b) - lgamma(a) - lgamma(b) + a * log(x) + b * log(1 - x));
    if (x < (a + 1) / (a + b + 2))
        return bt * beta_cf(a, b, x) / a;
    return 1 - bt * beta_cf(b, a, 1 - x) / b;
}

double stats_t_cdf(double t, double dof)
{
    double x = dof / (dof + t * t);
    double tail = 0.5 * inc_beta(dof / 2, 0.5, x);
    return t >= 0 ? 1 - tail : tail;
}

double stats_t_two_sided(double confidence, double dof)
{
    double target = 0.5 + confidence / 2, lo = 0, hi = 1;
    while (stats_t_cdf(hi, dof) < target && hi < STATS_T_MAX)
        hi *= 2;
    for (int i = 0; i < STATS_BISECT_STEPS && hi - lo > STATS_BISECT_REL_WIDTH * hi; i++) {
        double mid = 0.5 * (lo + hi);
        if (stats_t_cdf(mid, dof) < target)
            lo = mid;
        else
            hi = mid;
    }
    return 0.5 * (lo + hi);
}
