/* stats.h - the few distribution functions confidence bounds need. */
#ifndef VB_STATS_H
#define VB_STATS_H

/* Student's t CDF with dof degrees of freedom (dof >= 1). */
double stats_t_cdf(double t, double dof);

/* The two-sided half-width factor of a confidence interval: the t value
 * with P(|T| <= t) = confidence for dof degrees of freedom, e.g. 12.706 for
 * (0.95, 1) and 1.960 as dof grows. confidence in (0, 1). */
double stats_t_two_sided(double confidence, double dof);

#endif
