/* test_sched.c - the scheduler as a pure module: a hand-worked example of
 * Procedure 2, task dependencies, and the same film whatever order results
 * arrive in (with requeues). Results are synthetic but depend on the task's
 * "so far" sums, so a scheduler that handed out stale priors would differ. */
#include <check.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "rng.h"
#include "sched.h"

/* Synthetic tracer: deterministic in (pixel, first sample, prior sums). */
static void fake_results(const sched_task_t *t, tracer_result_t *r, const double *pvar_by_pixel)
{
    for (uint32_t i = 0; i < t->count; i++) {
        const tracer_task_t *k = &t->records[i];
        memset(&r[i], 0, sizeof r[i]);
        r[i].pixel = k->pixel;
        r[i].samples = k->sample_count;
        for (int c = 0; c < 3; c++)
            r[i].sum[c] = 0.25 * k->sample_count * (c + 1) + 1e-3 * k->prior_sum[c] +
                          1e-6 * (double)k->prior_count + 1e-4 * k->pixel + 1e-5 * (double)k->first_sample;
        r[i].lum_m2 = 0.01 * k->sample_count;
        r[i].pvar = pvar_by_pixel ? pvar_by_pixel[k->pixel]
                                  : (double)((k->pixel * 7 + k->first_sample * 3) % 11);
    }
}

static sched_t *make(uint32_t w, uint32_t h, uint32_t spp, uint32_t g, sched_adaptive_t a,
                     uint32_t uniform, uint32_t range)
{
    sched_config_t c = {.width = w, .height = h, .spp = spp, .granularity = g, .adaptive = a,
                        .uniform_layers = uniform, .range_pixels = range};
    char err[256];
    sched_t *s = sched_new(&c, err, sizeof err);
    ck_assert_msg(s != NULL, "%s", err);
    return s;
}

/* Completes every ready task of one layer in order, with given pvars. */
static void run_layer(sched_t *s, uint32_t layer, const double *pvar)
{
    sched_task_t t;
    tracer_result_t r[16];
    char err[256];
    int rc;
    sched_task_t held[16];
    int n = 0;
    while ((rc = sched_next(s, &t)) == 1) {
        ck_assert_uint_eq(t.layer, layer);
        held[n++] = t;
    }
    for (int i = 0; i < n; i++) {
        fake_results(&held[i], r, pvar);
        ck_assert_msg(sched_complete(s, held[i].id, r, held[i].count, err, sizeof err) == 0, "%s", err);
    }
}

/* The thesis's Procedure 2 by hand: 4 pixels, G = 2, spp 10 (5 layers), two
 * uniform layers, 2 pixels per range.
 *   layer 0 pvar [1 4 2 9]: layer 2 uses threshold 4 -> pixels {1, 3}
 *   layer 1 pvar [3 1 5 0]: layer 3 uses threshold 2.25 -> pixels {0, 2}
 *   layer 2 pvar [- .5 - 7]: snapshot [3 .5 5 7], threshold 3.875 -> layer 4 {2, 3}
 * Final samples: 6, 6, 8, 8. */
START_TEST(test_procedure2_by_hand)
{
    sched_t *s = make(4, 1, 10, 2, SCHED_ADAPTIVE_THESIS, 2, 2);
    ck_assert_uint_eq(sched_layer_count(s), 5);
    ck_assert_uint_eq(sched_range_count(s), 2);
    const double l0[4] = {1, 4, 2, 9}, l1[4] = {3, 1, 5, 0}, l2[4] = {-1, 0.5, -1, 7};
    const double l3[4] = {0, 0, 0, 0}, l4[4] = {0, 0, 0, 0};
    /* layer 0's tasks are ready; layer 1's wait for them */
    run_layer(s, 0, l0);
    /* now layer 1 ready and layer 2 decided from layer 0 only */
    ck_assert(fabs(sched_threshold(s, 2) - 4.0) < 1e-15);
    const int want2[4] = {0, 1, 0, 1};
    for (uint32_t p = 0; p < 4; p++)
        ck_assert_int_eq(sched_pixel_in_layer(s, 2, p), want2[p]);
    ck_assert_int_eq(sched_pixel_in_layer(s, 3, 0), -1); /* not decided yet */
    run_layer(s, 1, l1);
    ck_assert(fabs(sched_threshold(s, 3) - 2.25) < 1e-15);
    const int want3[4] = {1, 0, 1, 0};
    for (uint32_t p = 0; p < 4; p++)
        ck_assert_int_eq(sched_pixel_in_layer(s, 3, p), want3[p]);
    run_layer(s, 2, l2);
    ck_assert(fabs(sched_threshold(s, 4) - 3.875) < 1e-15);
    const int want4[4] = {0, 0, 1, 1};
    for (uint32_t p = 0; p < 4; p++)
        ck_assert_int_eq(sched_pixel_in_layer(s, 4, p), want4[p]);
    run_layer(s, 3, l3);
    run_layer(s, 4, l4);
    ck_assert(sched_done(s));
    sched_task_t t;
    ck_assert_int_eq(sched_next(s, &t), -1);
    const film_t *f = sched_film(s);
    const uint64_t want_samples[4] = {6, 6, 8, 8};
    for (int p = 0; p < 4; p++)
        ck_assert_uint_eq(f->pixels[p].count, want_samples[p]);
    ck_assert_uint_eq(sched_samples_done(s), 28);
    ck_assert_uint_eq(sched_pixel_layers(s), 14);
    ck_assert_uint_eq(sched_pixel_layers_skipped(s), 6);
    sched_destroy(&s);
}
END_TEST

/* A layer's task waits for the same range's previous layer; tasks carry
 * exactly the pixel's previous layers as their "so far" sums. */
START_TEST(test_dependencies_and_priors)
{
    sched_t *s = make(8, 1, 6, 2, SCHED_ADAPTIVE_NONE, UINT32_MAX, 4);
    sched_task_t a, b, c;
    ck_assert_int_eq(sched_next(s, &a), 1);
    ck_assert_int_eq(sched_next(s, &b), 1);
    ck_assert_uint_eq(a.layer, 0);
    ck_assert_uint_eq(b.layer, 0);
    ck_assert_int_eq(sched_next(s, &c), 0); /* layer 1 waits */
    tracer_result_t r[4];
    char err[256];
    fake_results(&b, r, NULL);
    ck_assert(sched_complete(s, b.id, r, b.count, err, sizeof err) == 0);
    ck_assert_int_eq(sched_next(s, &c), 1); /* (1, range of b) only */
    ck_assert_uint_eq(c.layer, 1);
    ck_assert_uint_eq(c.range, b.range);
    ck_assert_uint_eq(c.records[0].first_sample, 2);
    ck_assert_uint_eq(c.records[0].prior_count, 2);
    ck_assert(c.records[0].prior_sum[0] == r[0].sum[0]);
    ck_assert_int_eq(sched_next(s, &c), 0);
    /* duplicate and unknown completions are refused, nothing merged */
    ck_assert_int_eq(sched_complete(s, b.id, r, b.count, err, sizeof err), -2);
    ck_assert_int_eq(sched_complete(s, 999, r, 1, err, sizeof err), -2);
    /* a result with the wrong pixel or count is refused, and the task stays out */
    fake_results(&a, r, NULL);
    r[2].pixel = 7;
    ck_assert_int_eq(sched_complete(s, a.id, r, a.count, err, sizeof err), -1);
    ck_assert_msg(strstr(err, "pixel") != NULL, "%s", err);
    ck_assert_int_eq(sched_complete(s, a.id, r, a.count - 1, err, sizeof err), -1);
    fake_results(&a, r, NULL);
    r[1].samples = 1;
    ck_assert_int_eq(sched_complete(s, a.id, r, a.count, err, sizeof err), -1);
    ck_assert_uint_eq(sched_film(s)->pixels[a.records[0].pixel].count, 0);
    /* requeue gives the same task back first */
    ck_assert_int_eq(sched_requeue(s, a.id), 0);
    sched_task_t again;
    ck_assert_int_eq(sched_next(s, &again), 1);
    ck_assert_uint_eq(again.id, a.id);
    ck_assert_int_eq(sched_requeue(s, 12345), -1);
    sched_destroy(&s);
}
END_TEST

/* Runs a whole job handing tasks out to `workers` simulated workers that
 * finish in a pseudo-random order, sometimes losing a task (requeue). */
static film_t *simulate(sched_adaptive_t a, uint64_t order_seed, int workers, uint64_t *skipped)
{
    sched_t *s = make(37, 23, 64, 8, a, 3, 50);
    sched_task_t inflight[64];
    int n = 0;
    tracer_result_t *r = malloc(64 * sizeof *r);
    char err[256];
    uint64_t step = 0;
    for (;;) {
        sched_task_t t;
        int rc;
        while (n < workers && (rc = sched_next(s, &t)) == 1)
            inflight[n++] = t;
        if (n == 0) {
            ck_assert(sched_done(s));
            break;
        }
        rng_stream_t st = rng_stream(order_seed, 0, step++);
        int pick = (int)(rng_next_float(&st) * n);
        if (rng_next_float(&st) < 0.1f) {
            ck_assert(sched_requeue(s, inflight[pick].id) == 0);
        } else {
            fake_results(&inflight[pick], r, NULL);
            ck_assert_msg(sched_complete(s, inflight[pick].id, r, inflight[pick].count, err, sizeof err) == 0, "%s", err);
        }
        inflight[pick] = inflight[--n];
    }
    free(r);
    film_t *f = film_new(37, 23);
    memcpy(f->pixels, sched_film(s)->pixels, 37 * 23 * sizeof(film_pixel_t));
    *skipped = sched_pixel_layers_skipped(s);
    sched_destroy(&s);
    return f;
}

START_TEST(test_order_does_not_matter)
{
    for (int a = 0; a < 2; a++) {
        uint64_t sk0, sk;
        film_t *ref = simulate((sched_adaptive_t)a, 1, 1, &sk0);
        if (a == 1)
            ck_assert_msg(sk0 > 0, "adaptive run skipped nothing");
        else
            ck_assert_uint_eq(sk0, 0);
        for (int trial = 0; trial < 4; trial++) {
            film_t *f = simulate((sched_adaptive_t)a, 100 + (uint64_t)trial, 2 + trial * 3, &sk);
            ck_assert_msg(memcmp(ref->pixels, f->pixels, 37 * 23 * sizeof(film_pixel_t)) == 0,
                          "adaptive=%d trial %d: film differs", a, trial);
            ck_assert_uint_eq(sk, sk0);
            film_destroy(&f);
        }
        film_destroy(&ref);
    }
}
END_TEST

/* An explicit flag sequence: only flagged layers apply the skip rule, and a
 * malformed sequence is refused. */
START_TEST(test_flag_sequence)
{
    char err[256];
    /* 6 layers; the rule applies at layers 2 and 4 only */
    sched_config_t c = {.width = 4, .height = 1, .spp = 12, .granularity = 2, .adaptive = SCHED_ADAPTIVE_THESIS,
                        .uniform_layers = UINT32_MAX, .range_pixels = 2, .flags = "001010"};
    sched_t *s = sched_new(&c, err, sizeof err);
    ck_assert_msg(s != NULL, "%s", err);
    ck_assert_uint_eq(sched_uniform_layers(s), 2);
    const double pv[4] = {1, 4, 2, 9};
    for (uint32_t l = 0; l < 6; l++)
        run_layer(s, l, pv);
    ck_assert(sched_done(s));
    /* layers 2 and 4 keep pixels 1 and 3 (at or above the mean 4), 3 and 5 keep all */
    const uint64_t want[4] = {8, 12, 8, 12};
    for (int p = 0; p < 4; p++)
        ck_assert_uint_eq(sched_film(s)->pixels[p].count, want[p]);
    sched_destroy(&s);
    const char *bad[] = {"00101", "0010100", "00102x", NULL};
    for (int i = 0; bad[i]; i++) {
        c.flags = bad[i];
        ck_assert(sched_new(&c, err, sizeof err) == NULL);
        ck_assert_msg(strstr(err, "flag sequence") != NULL, "%s", err);
    }
    c.flags = "001010";
    c.adaptive = SCHED_ADAPTIVE_NONE;
    ck_assert(sched_new(&c, err, sizeof err) == NULL);
}
END_TEST

/* Results whose layer means are given per pixel by lum(pixel, layer). */
typedef double (*lum_fn)(uint32_t pixel, uint32_t layer);

static void run_all(sched_t *s, lum_fn f, uint32_t g)
{
    sched_task_t t;
    tracer_result_t r[64];
    char err[256];
    int rc;
    while ((rc = sched_next(s, &t)) != -1) {
        ck_assert_int_eq(rc, 1); /* one at a time: always something ready */
        for (uint32_t i = 0; i < t.count; i++) {
            memset(&r[i], 0, sizeof r[i]);
            r[i].pixel = t.records[i].pixel;
            r[i].samples = t.records[i].sample_count;
            double l = f(r[i].pixel, t.layer) * r[i].samples;
            r[i].sum[0] = r[i].sum[1] = r[i].sum[2] = l; /* luminance of (l,l,l) is l */
            r[i].lum_m2 = 0.01 * g;
            r[i].pvar = f(r[i].pixel, t.layer);
        }
        ck_assert_msg(sched_complete(s, t.id, r, t.count, err, sizeof err) == 0, "%s", err);
    }
}

/* pixels 0-7 steady, pixels 8-15 jump between layers */
static double steady_or_noisy(uint32_t p, uint32_t layer)
{
    return p < 8 ? 0.5 : (layer % 2 ? 0.2 : 0.8);
}

START_TEST(test_target_error_stops)
{
    char err[256];
    sched_config_t c = {.width = 16, .height = 1, .spp = 64, .granularity = 4, .adaptive = SCHED_ADAPTIVE_NONE,
                        .uniform_layers = UINT32_MAX, .range_pixels = 4, .target_error = 0.05,
                        .confidence = 0.95, .target_share = 1.0};
    sched_t *s = sched_new(&c, err, sizeof err);
    ck_assert_msg(s != NULL, "%s", err);
    run_all(s, steady_or_noisy, 4);
    ck_assert(sched_done(s));
    const film_t *f = sched_film(s);
    /* steady pixels converge after SCHED_TARGET_MIN_LAYERS layers (decided two
     * layers later: they stop within 2 more); noisy ones never do */
    for (uint32_t p = 0; p < 16; p++) {
        if (p < 8)
            ck_assert_msg(f->pixels[p].count <= 4u * (SCHED_TARGET_MIN_LAYERS + 2) &&
                              f->pixels[p].count >= 4u * SCHED_TARGET_MIN_LAYERS,
                          "steady pixel %u took %llu samples", p, (unsigned long long)f->pixels[p].count);
        else
            ck_assert_uint_eq(f->pixels[p].count, 64);
    }
    ck_assert_uint_eq(sched_converged(s), 8);
    ck_assert(!sched_stopped_on_target(s)); /* only half converged */
    sched_destroy(&s);
    /* a share of one half: the job itself stops early */
    c.target_share = 0.5;
    s = sched_new(&c, err, sizeof err);
    run_all(s, steady_or_noisy, 4);
    ck_assert(sched_done(s));
    ck_assert(sched_stopped_on_target(s));
    ck_assert(sched_film(s)->pixels[15].count < 64);
    sched_destroy(&s);
}
END_TEST

/* relerr and variance keep the noisy pixels and skip the steady ones. */
START_TEST(test_relerr_and_variance_modes)
{
    char err[256];
    for (int mode = SCHED_ADAPTIVE_VARIANCE; mode <= SCHED_ADAPTIVE_RELERR; mode++) {
        sched_config_t c = {.width = 16, .height = 1, .spp = 64, .granularity = 4, .adaptive = (sched_adaptive_t)mode,
                            .uniform_layers = 4, .range_pixels = 4};
        sched_t *s = sched_new(&c, err, sizeof err);
        ck_assert_msg(s != NULL, "%s", err);
        run_all(s, steady_or_noisy, 4);
        const film_t *f = sched_film(s);
        for (uint32_t p = 0; p < 16; p++) {
            if (p < 8)
                ck_assert_msg(f->pixels[p].count < 64, "%s: steady pixel %u never skipped",
                              sched_adaptive_name((sched_adaptive_t)mode), p);
            else
                ck_assert_uint_eq(f->pixels[p].count, 64);
        }
        sched_destroy(&s);
    }
    ck_assert_int_eq(sched_adaptive_from_name("relerr"), SCHED_ADAPTIVE_RELERR);
    ck_assert_int_eq(sched_adaptive_from_name("bogus"), -1);
}
END_TEST

/* one noisy pixel in the middle of a 5x5 image */
static double one_hot(uint32_t p, uint32_t layer)
{
    return p == 12 ? (layer % 2 ? 0.0 : 10.0) : 0.5 + 0.001 * p;
}

START_TEST(test_dilation)
{
    char err[256];
    for (int dil = 0; dil < 2; dil++) {
        sched_config_t c = {.width = 5, .height = 5, .spp = 16, .granularity = 4, .adaptive = SCHED_ADAPTIVE_VARIANCE,
                            .uniform_layers = 2, .range_pixels = 25, .dilate = dil};
        sched_t *s = sched_new(&c, err, sizeof err);
        ck_assert_msg(s != NULL, "%s", err);
        run_all(s, one_hot, 4);
        int in_layer3 = 0;
        for (uint32_t p = 0; p < 25; p++)
            in_layer3 += sched_pixel_in_layer(s, 3, p);
        /* without dilation only the noisy pixel and those at or over the mean;
         * with it, at least its 3x3 neighbourhood */
        ck_assert_int_eq(sched_pixel_in_layer(s, 3, 12), 1);
        if (dil)
            for (int dy = -1; dy <= 1; dy++)
                for (int dx = -1; dx <= 1; dx++)
                    ck_assert_int_eq(sched_pixel_in_layer(s, 3, (uint32_t)(12 + dy * 5 + dx)), 1);
        else
            ck_assert_int_lt(in_layer3, 9);
        sched_destroy(&s);
    }
}
END_TEST

/* Random selection: the same seed gives the same layers; below-threshold
 * pixels sometimes run. */
START_TEST(test_random_selection)
{
    char err[256];
    uint64_t counts[2][64];
    for (int run = 0; run < 2; run++) {
        sched_config_t c = {.width = 64, .height = 1, .spp = 64, .granularity = 4, .adaptive = SCHED_ADAPTIVE_THESIS,
                            .uniform_layers = 2, .range_pixels = 16, .random_selection = 1, .seed = 77};
        sched_t *s = sched_new(&c, err, sizeof err);
        run_all(s, steady_or_noisy, 4);
        for (uint32_t p = 0; p < 64; p++)
            counts[run][p] = sched_film(s)->pixels[p].count;
        sched_destroy(&s);
    }
    ck_assert(memcmp(counts[0], counts[1], sizeof counts[0]) == 0);
    /* pvar = 0.5 for pixels 0-7 is below the mean (about 0.5 ... 0.8): without
     * randomness they would all get exactly the same count; with it they differ */
    int differ = 0;
    for (uint32_t p = 1; p < 8; p++)
        differ |= counts[0][p] != counts[0][0];
    ck_assert(differ);
}
END_TEST

START_TEST(test_bad_configs)
{
    char err[256];
    sched_config_t c = {.width = 0, .height = 4, .spp = 8, .granularity = 2, .adaptive = SCHED_ADAPTIVE_NONE,
                        .uniform_layers = UINT32_MAX};
    ck_assert(sched_new(&c, err, sizeof err) == NULL);
    c.width = 4;
    c.granularity = 0;
    ck_assert(sched_new(&c, err, sizeof err) == NULL);
    c.granularity = 1;
    c.adaptive = SCHED_ADAPTIVE_THESIS;
    ck_assert(sched_new(&c, err, sizeof err) == NULL);
    ck_assert_msg(strstr(err, "granularity") != NULL, "%s", err);
    c.granularity = 32;
    c.spp = 100; /* last layer is partial: 4 layers, 32+32+32+4 */
    sched_t *s = sched_new(&c, err, sizeof err);
    ck_assert(s != NULL);
    ck_assert_uint_eq(sched_layer_count(s), 4);
    ck_assert_uint_eq(sched_uniform_layers(s), 2);
    sched_destroy(&s);
}
END_TEST

/* A submit must not freeze the master: sched_new for a job of about a
 * million layers does no per-layer work beyond zeroed allocations (the t
 * factors are computed when first needed). Not timed: 20 of them took about
 * 20 minutes when every t factor was computed up front, and Check's timeout
 * catches that; now they take milliseconds. */
START_TEST(test_many_layers_new_is_cheap)
{
    char err[256];
    for (int i = 0; i < 20; i++) {
        /* 2^25 samples in layers of 32: 2^20 layers of one pixel; relerr and a
         * target error read both t tables */
        sched_config_t c = {.width = 1, .height = 1, .spp = 1u << 25, .granularity = 32,
                            .adaptive = i % 2 ? SCHED_ADAPTIVE_RELERR : SCHED_ADAPTIVE_THESIS,
                            .uniform_layers = UINT32_MAX, .target_error = 0.01, .confidence = 0.99};
        sched_t *s = sched_new(&c, err, sizeof err);
        ck_assert_msg(s != NULL, "%s", err);
        ck_assert_uint_eq(sched_layer_count(s), 1u << 20);
        /* a few layers still run, and read the (lazy) t factors */
        sched_task_t t;
        tracer_result_t r;
        for (uint32_t l = 0; l < 6; l++) {
            ck_assert_int_eq(sched_next(s, &t), 1);
            ck_assert_uint_eq(t.layer, l);
            memset(&r, 0, sizeof r);
            r.pixel = 0;
            r.samples = 32;
            r.sum[0] = r.sum[1] = r.sum[2] = 16.0 + 0.5 * (l % 2);
            r.lum_m2 = 1.0;
            r.pvar = 1.0;
            ck_assert_msg(sched_complete(s, t.id, &r, 1, err, sizeof err) == 0, "%s", err);
        }
        ck_assert_uint_eq(sched_samples_done(s), 6 * 32);
        sched_destroy(&s);
    }
}
END_TEST

int main(void)
{
    Suite *s = suite_create("sched");
    TCase *tc = tcase_create("procedure2");
    tcase_add_test(tc, test_procedure2_by_hand);
    tcase_add_test(tc, test_dependencies_and_priors);
    tcase_add_test(tc, test_order_does_not_matter);
    tcase_add_test(tc, test_flag_sequence);
    tcase_add_test(tc, test_target_error_stops);
    tcase_add_test(tc, test_relerr_and_variance_modes);
    tcase_add_test(tc, test_dilation);
    tcase_add_test(tc, test_random_selection);
    tcase_add_test(tc, test_bad_configs);
    tcase_add_test(tc, test_many_layers_new_is_cheap);
    suite_add_tcase(s, tc);
    SRunner *sr = srunner_create(s);
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed ? 1 : 0;
}
