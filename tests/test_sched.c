/* test_sched.c - the scheduler as a pure module: a hand-worked example of
 * Procedure 2, task dependencies, and the same film whatever order results
 * arrive in (with requeues). Results are synthetic but depend on the task's
 * "so far" sums, so a scheduler that handed out stale priors would differ. */
#include <check.h>
#include <math.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include "fuzzmaster.h" /* fuzz_fix_sched_checksum */
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
        r[i].rays = k->sample_count * (1 + k->pixel % 3);
        for (int c = 0; c < 3; c++)
            r[i].sum[c] = 0.25 * k->sample_count * (c + 1) + 1e-3 * k->prior_sum[c] +
                          1e-6 * (double)k->prior_count + 1e-4 * k->pixel +
                          1e-5 * (double)k->first_sample;
        r[i].lum_m2 = 0.01 * k->sample_count;
        r[i].pvar = pvar_by_pixel ? pvar_by_pixel[k->pixel]
                                  : (double)((k->pixel * 7 + k->first_sample * 3) % 11);
    }
}

static sched_t *make(uint32_t w, uint32_t h, uint32_t spp, uint32_t g, sched_adaptive_t a,
                     uint32_t uniform, uint32_t range)
{
    sched_config_t c = {.width = w,
                        .height = h,
                        .spp = spp,
                        .granularity = g,
                        .adaptive = a,
                        .uniform_layers = uniform,
                        .range_pixels = range};
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
        ck_assert_msg(sched_complete(s, held[i].id, r, held[i].count, err, sizeof err) == 0, "%s",
                      err);
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
    ck_assert_int_eq(sched_next(s, &t), SCHED_NEXT_ALL_ISSUED);
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
    ck_assert_int_eq(sched_next(s, &c), SCHED_NEXT_NONE_READY); /* layer 1 waits */
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
    ck_assert_int_eq(sched_next(s, &c), SCHED_NEXT_NONE_READY);
    /* duplicate and unknown completions are refused, nothing merged */
    ck_assert_int_eq(sched_complete(s, b.id, r, b.count, err, sizeof err), SCHED_NOT_OUTSTANDING);
    ck_assert_int_eq(sched_complete(s, 999, r, 1, err, sizeof err), SCHED_NOT_OUTSTANDING);
    /* a result with the wrong pixel or count is refused, and the task stays out */
    fake_results(&a, r, NULL);
    r[2].pixel = 7;
    ck_assert_int_eq(sched_complete(s, a.id, r, a.count, err, sizeof err), SCHED_BAD_RESULT);
    ck_assert_msg(strstr(err, "pixel") != NULL, "%s", err);
    ck_assert_int_eq(sched_complete(s, a.id, r, a.count - 1, err, sizeof err), SCHED_BAD_RESULT);
    fake_results(&a, r, NULL);
    r[1].samples = 1;
    ck_assert_int_eq(sched_complete(s, a.id, r, a.count, err, sizeof err), SCHED_BAD_RESULT);
    /* every sample traces at least its camera ray */
    fake_results(&a, r, NULL);
    r[1].rays = a.records[1].sample_count - 1;
    ck_assert_int_eq(sched_complete(s, a.id, r, a.count, err, sizeof err), SCHED_BAD_RESULT);
    ck_assert_msg(strstr(err, "rays for") != NULL, "%s", err);
    ck_assert_uint_eq(sched_film(s)->pixels[a.records[0].pixel].count, 0);
    /* requeue gives the same task back first */
    ck_assert_int_eq(sched_requeue(s, a.id), 0);
    sched_task_t again;
    ck_assert_int_eq(sched_next(s, &again), 1);
    ck_assert_uint_eq(again.id, a.id);
    ck_assert_int_eq(sched_requeue(s, 12345), SCHED_NOT_OUTSTANDING);
    sched_destroy(&s);
}
END_TEST

/* The earlier layer's ready tasks go out first (issue 24, item 3): layer
 * l + 2 is decided only when all of layer l is in, so a layer-l task left
 * queued behind layer l + 1's (as the one order in which they became
 * ready had it) idles the workers at the boundary. Four ranges; ranges
 * 0-2 run two layers while range 3's first is out; when it comes in,
 * layer 2 is decided and (2, 0..2) are ready before (1, 3) is. */
START_TEST(test_earlier_layer_first)
{
    sched_t *s = make(16, 1, 8, 2, SCHED_ADAPTIVE_NONE, UINT32_MAX, 4);
    sched_task_t t[4], u;
    tracer_result_t r[4];
    char err[256];
    for (int i = 0; i < 4; i++) {
        ck_assert_int_eq(sched_next(s, &t[i]), 1);
        ck_assert_uint_eq(t[i].layer, 0);
    }
    uint32_t last = t[3].range;
    for (int i = 0; i < 3; i++) {
        fake_results(&t[i], r, NULL);
        ck_assert_msg(sched_complete(s, t[i].id, r, t[i].count, err, sizeof err) == 0, "%s", err);
    }
    for (int i = 0; i < 3; i++) {
        ck_assert_int_eq(sched_next(s, &u), 1);
        ck_assert_uint_eq(u.layer, 1);
        fake_results(&u, r, NULL);
        ck_assert_msg(sched_complete(s, u.id, r, u.count, err, sizeof err) == 0, "%s", err);
    }
    ck_assert_int_eq(sched_next(s, &u), SCHED_NEXT_NONE_READY); /* layer 2 waits on layer 0 */
    fake_results(&t[3], r, NULL);
    ck_assert_msg(sched_complete(s, t[3].id, r, t[3].count, err, sizeof err) == 0, "%s", err);
    ck_assert_int_eq(sched_next(s, &u), 1);
    ck_assert_uint_eq(u.layer, 1);
    ck_assert_uint_eq(u.range, last);
    for (int i = 0; i < 3; i++) {
        ck_assert_int_eq(sched_next(s, &u), 1);
        ck_assert_uint_eq(u.layer, 2);
    }
    ck_assert_int_eq(sched_next(s, &u), SCHED_NEXT_NONE_READY);
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
            ck_assert_msg(
                sched_complete(s, inflight[pick].id, r, inflight[pick].count, err, sizeof err) == 0,
                "%s", err);
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
/* A journal's replay: results logged in the order they were merged, fed
 * back through sched_take and sched_complete into a fresh scheduler, give
 * the same film and decisions, and sched_next never hands out a task that
 * sched_take took. */
START_TEST(test_take_replays_a_journal)
{
    for (int a = 0; a < 5; a++) {
        sched_config_t c = {.width = 37,
                            .height = 23,
                            .spp = 96,
                            .granularity = 8,
                            .adaptive = (sched_adaptive_t)a,
                            .uniform_layers = a ? 3 : UINT32_MAX,
                            .range_pixels = 50};
        char err[256];
        sched_t *s = sched_new(&c, err, sizeof err), *b = sched_new(&c, err, sizeof err);
        ck_assert(s && b);
        tracer_result_t *r = malloc(64 * sizeof *r);
        uint64_t *ids = NULL;
        tracer_result_t *log = NULL;
        size_t nlog = 0, nres = 0;
        sched_task_t inflight[8];
        int n = 0;
        uint64_t step = 0;
        for (;;) {
            sched_task_t t;
            while (n < 6 && sched_next(s, &t) == SCHED_NEXT_TASK)
                inflight[n++] = t;
            if (n == 0)
                break;
            rng_stream_t st = rng_stream(7, (uint64_t)a, step++);
            int pick = (int)(rng_next_float(&st) * n);
            fake_results(&inflight[pick], r, NULL);
            ids = realloc(ids, (nlog + 1) * sizeof *ids);
            log = realloc(log, (nres + inflight[pick].count + 1) * sizeof *log);
            ids[nlog++] = inflight[pick].id;
            memcpy(log + nres, r, inflight[pick].count * sizeof *r);
            nres += inflight[pick].count;
            ck_assert(sched_complete(s, inflight[pick].id, r, inflight[pick].count, err,
                                     sizeof err) == SCHED_OK);
            inflight[pick] = inflight[--n];
        }
        ck_assert(sched_done(s));
        size_t at = 0;
        for (size_t i = 0; i < nlog; i++) {
            sched_task_t t;
            ck_assert_int_eq(sched_take(b, ids[i], &t), SCHED_OK);
            ck_assert_int_eq(sched_take(b, ids[i], &t), SCHED_NOT_OUTSTANDING);
            ck_assert_msg(sched_complete(b, ids[i], log + at, t.count, err, sizeof err) == SCHED_OK,
                          "%s", err);
            at += t.count;
            if (i == nlog / 2) { /* nothing taken is handed out again */
                sched_task_t u;
                while (sched_next(b, &u) == SCHED_NEXT_TASK)
                    for (size_t k = 0; k <= i; k++)
                        ck_assert(u.id != ids[k]);
                /* put them back: the rest of the journal takes them */
                const uint64_t cells = (uint64_t)sched_layer_count(b) * sched_range_count(b);
                for (uint64_t id = 1; id <= cells; id++)
                    (void)sched_requeue(b, id);
            }
        }
        ck_assert(sched_done(b));
        ck_assert_uint_eq(sched_pixel_layers_skipped(b), sched_pixel_layers_skipped(s));
        ck_assert(memcmp(sched_film(b)->pixels, sched_film(s)->pixels,
                         37 * 23 * sizeof(film_pixel_t)) == 0);
        free(r);
        free(ids);
        free(log);
        sched_destroy(&s);
        sched_destroy(&b);
    }
}
END_TEST

START_TEST(test_flag_sequence)
{
    char err[256];
    /* 6 layers; the rule applies at layers 2 and 4 only */
    sched_config_t c = {.width = 4,
                        .height = 1,
                        .spp = 12,
                        .granularity = 2,
                        .adaptive = SCHED_ADAPTIVE_THESIS,
                        .uniform_layers = UINT32_MAX,
                        .range_pixels = 2,
                        .flags = "001010"};
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

/* Rays a sample of a pixel traces. */
typedef uint32_t (*cost_fn)(uint32_t pixel);

static uint32_t one_ray(uint32_t pixel)
{
    (void)pixel;
    return 1;
}

static void run_all_costing(sched_t *s, lum_fn f, uint32_t g, cost_fn cost)
{
    sched_task_t t;
    tracer_result_t r[64];
    char err[256];
    int rc;
    while ((rc = sched_next(s, &t)) != SCHED_NEXT_ALL_ISSUED) {
        ck_assert_int_eq(rc, 1); /* one at a time: always something ready */
        for (uint32_t i = 0; i < t.count; i++) {
            memset(&r[i], 0, sizeof r[i]);
            r[i].pixel = t.records[i].pixel;
            r[i].samples = t.records[i].sample_count;
            r[i].rays = r[i].samples * cost(r[i].pixel);
            double l = f(r[i].pixel, t.layer) * r[i].samples;
            r[i].sum[0] = r[i].sum[1] = r[i].sum[2] = l; /* luminance of (l,l,l) is l */
            r[i].lum_m2 = 0.01 * g;
            r[i].pvar = f(r[i].pixel, t.layer);
        }
        ck_assert_msg(sched_complete(s, t.id, r, t.count, err, sizeof err) == 0, "%s", err);
    }
}

static void run_all(sched_t *s, lum_fn f, uint32_t g)
{
    run_all_costing(s, f, g, one_ray);
}

/* Runs tasks one at a time until `layer` is decided (the scheduler keeps
 * the membership of the two layers in flight only). */
static void run_until_decided(sched_t *s, lum_fn f, uint32_t g, uint32_t layer)
{
    sched_task_t t;
    tracer_result_t r[64];
    char err[256];
    while (sched_pixel_in_layer(s, layer, 0) < 0) {
        ck_assert_int_eq(sched_next(s, &t), SCHED_NEXT_TASK);
        for (uint32_t i = 0; i < t.count; i++) {
            memset(&r[i], 0, sizeof r[i]);
            r[i].pixel = t.records[i].pixel;
            r[i].samples = t.records[i].sample_count;
            r[i].rays = r[i].samples;
            double l = f(r[i].pixel, t.layer) * r[i].samples;
            r[i].sum[0] = r[i].sum[1] = r[i].sum[2] = l;
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
    sched_config_t c = {.width = 16,
                        .height = 1,
                        .spp = 64,
                        .granularity = 4,
                        .adaptive = SCHED_ADAPTIVE_NONE,
                        .uniform_layers = UINT32_MAX,
                        .range_pixels = 4,
                        .target_error = 0.05,
                        .confidence = 0.95,
                        .target_share = 1.0};
    sched_t *s = sched_new(&c, err, sizeof err);
    ck_assert_msg(s != NULL, "%s", err);
    run_all(s, steady_or_noisy, 4);
    ck_assert(sched_done(s));
    const film_t *f = sched_film(s);
    /* steady pixels converge after SCHED_TARGET_MIN_LAYERS layers (decided two
     * layers later: they stop within 2 more), unless a noisy pixel is in
     * their window: their own layers say nothing of what a neighbour has
     * met. Noisy ones never converge. */
    const uint32_t steady_alone = 8 - SCHED_TARGET_POOL_RADIUS;
    for (uint32_t p = 0; p < 16; p++) {
        if (p < steady_alone)
            ck_assert_msg(f->pixels[p].count <= 4u * (SCHED_TARGET_MIN_LAYERS + 2) &&
                              f->pixels[p].count >= 4u * SCHED_TARGET_MIN_LAYERS,
                          "steady pixel %u took %llu samples", p,
                          (unsigned long long)f->pixels[p].count);
        else
            ck_assert_msg(f->pixels[p].count == 64, "pixel %u (%s) took %llu samples", p,
                          p < 8 ? "steady, a noisy one in its window" : "noisy",
                          (unsigned long long)f->pixels[p].count);
    }
    ck_assert_uint_eq(sched_converged(s), steady_alone);
    /* the rule stopped the steady pixels alone; the rest ran to the cap */
    ck_assert_uint_eq(sched_pixels_at_cap(s), 16 - steady_alone);
    ck_assert(!sched_stopped_on_target(s)); /* not all converged */
    sched_destroy(&s);
    /* a share the converged pixels reach: the job itself stops early */
    c.target_share = steady_alone / 16.0;
    s = sched_new(&c, err, sizeof err);
    run_all(s, steady_or_noisy, 4);
    ck_assert(sched_done(s));
    ck_assert(sched_stopped_on_target(s));
    ck_assert(sched_film(s)->pixels[15].count < 64);
    ck_assert_uint_eq(sched_pixels_at_cap(s), 0);
    sched_destroy(&s);
}
END_TEST

/* Layer means by replicate: 0.4 in replicate 0's layers, 0.6 in 1's. */
static double by_replicate(uint32_t p, uint32_t layer)
{
    (void)p;
    return layer % 2 ? 0.6 : 0.4;
}

/* What replicates do: a pixel's layer k is replicate k mod R's layer
 * k div R (its first sample index, rng_replicate_first_sample), and the
 * variance of the mean is the replicates' spread: on a 1 x 1 image, whose
 * window is the pixel, exactly sum w_r^2 (m_r - m)^2 / (1 - sum w_r^2). */
START_TEST(test_replicates)
{
    for (uint32_t spp = 6; spp <= 8; spp += 2) { /* 3 layers (unequal) and 4 (equal) */
        sched_config_t c = {.width = 1,
                            .height = 1,
                            .spp = spp,
                            .granularity = 2,
                            .adaptive = SCHED_ADAPTIVE_NONE,
                            .uniform_layers = UINT32_MAX,
                            .range_pixels = 1,
                            .replicates = 2};
        char err[256];
        sched_t *s = sched_new(&c, err, sizeof err);
        ck_assert_msg(s != NULL, "%s", err);
        sched_task_t t;
        tracer_result_t r;
        int rc;
        while ((rc = sched_next(s, &t)) != SCHED_NEXT_ALL_ISSUED) {
            ck_assert_int_eq(rc, SCHED_NEXT_TASK);
            const uint64_t k = t.layer;
            ck_assert_uint_eq(t.records[0].first_sample,
                              ((k % 2) << RNG_REPLICATE_SHIFT) + k / 2 * 2);
            memset(&r, 0, sizeof r);
            r.pixel = 0;
            r.samples = r.rays = t.records[0].sample_count;
            r.sum[0] = r.sum[1] = r.sum[2] = by_replicate(0, t.layer) * r.samples;
            r.lum_m2 = 0.01;
            ck_assert_msg(sched_complete(s, t.id, &r, 1, err, sizeof err) == 0, "%s", err);
        }
        const double w1 = spp == 8 ? 0.5 : 1.0 / 3, w0 = 1 - w1, m = 0.4 * w0 + 0.6 * w1;
        const double want = (w0 * w0 * (0.4 - m) * (0.4 - m) + w1 * w1 * (0.6 - m) * (0.6 - m)) /
                            (1 - w0 * w0 - w1 * w1);
        float v = -1;
        ck_assert_int_eq(sched_variance_of_mean(s, &v), 0);
        ck_assert_msg(fabs(v - want) < 1e-6 * want, "%u spp: %g, want %g", spp, v, want);
        /* the image carries it */
        image_t *img = sched_image(s);
        ck_assert(img != NULL && image_channel(img, "variance")[0] == v);
        image_destroy(&img);
        sched_destroy(&s);
        /* one sequence: the film's own variance, and samples in order */
        c.replicates = 1;
        s = sched_new(&c, err, sizeof err);
        run_all(s, by_replicate, 2);
        ck_assert_int_eq(sched_variance_of_mean(s, &v), 0);
        ck_assert(v == (float)film_variance_of_mean(sched_film(s), 0));
        sched_destroy(&s);
    }
}
END_TEST

/* every pixel steady but pixel 10, which jumps between layers */
static double one_noisy(uint32_t p, uint32_t layer)
{
    return p == 10 ? (layer % 2 ? 0.2 : 0.8) : 0.5;
}

/* A 16 x 1 job of `layers` layers of G = 4, ranges of 4 pixels, under
 * target error E at confidence 0.95. */
static sched_config_t row_target(uint32_t layers, sched_adaptive_t mode, double E,
                                 uint32_t replicates)
{
    return (sched_config_t){.width = 16,
                            .height = 1,
                            .spp = 4 * layers,
                            .granularity = 4,
                            .adaptive = mode,
                            .uniform_layers = UINT32_MAX,
                            .range_pixels = 4,
                            .target_error = E,
                            .confidence = 0.95,
                            .replicates = replicates};
}

static sched_t *new_sched(const sched_config_t *c)
{
    char err[256];
    sched_t *s = sched_new(c, err, sizeof err);
    ck_assert_msg(s != NULL, "%s", err);
    return s;
}

/* Runs a 16 x 1 job of `layers` layers of G = 4 under a target error on
 * layer means f, whose pixel 10 is the noisy one: the pixels with it in
 * their window run to the cap, the others stop after their first
 * SCHED_TARGET_MIN_LAYERS layers (SCHED_TARGET_CALIBRATED_LAYERS with
 * replicates; decided two layers later: within 2 more), pixel 10 too; or
 * every pixel runs to the cap. */
static void run_noisy_one(lum_fn f, uint32_t layers, uint32_t replicates, int all_to_cap,
                          const char *what)
{
    /* the layers a pixel's statistics come from (sched.h) */
    const uint32_t first =
        replicates > 1 ? SCHED_TARGET_CALIBRATED_LAYERS : SCHED_TARGET_MIN_LAYERS;
    sched_config_t c = row_target(layers, SCHED_ADAPTIVE_NONE, 0.05, replicates);
    sched_t *s = new_sched(&c);
    run_all(s, f, 4);
    ck_assert(sched_done(s));
    const uint64_t cap = c.spp;
    const film_t *film = sched_film(s);
    for (uint32_t p = 0; p < 16; p++) {
        const int near =
            p != 10 && p + SCHED_TARGET_POOL_RADIUS >= 10 && p <= 10 + SCHED_TARGET_POOL_RADIUS;
        const uint64_t n = film->pixels[p].count;
        if (all_to_cap || near)
            ck_assert_msg(n == cap, "%s: pixel %u took %llu samples, not the cap", what, p,
                          (unsigned long long)n);
        else
            ck_assert_msg(n >= 4u * first && n <= 4u * (first + 2),
                          "%s: pixel %u took %llu samples", what, p, (unsigned long long)n);
    }
    sched_destroy(&s);
}

/* A pixel is judged by its neighbours' first layers, never by its own: the
 * noisy pixel 10 stops as soon as the steady pixels far from it (its own
 * window is steady), while the steady pixels within SCHED_TARGET_POOL_RADIUS
 * of it go on to the end (its variance is in their window). */
START_TEST(test_target_window_excludes_self)
{
    run_noisy_one(one_noisy, 16, 1, 0, "one sequence");
}
END_TEST

/* Pixel 10's replicates disagree (0.4 in replicate 0's layers, 0.6 in
 * 1's); every other pixel's layers swing between 0.2 and 0.8, but its two
 * replicates' means agree (0.5 each), as the layers of one stratified
 * sequence do: a layer is a chunk of it, far noisier than the mean of
 * them all. */
static double swinging_chunks(uint32_t p, uint32_t layer)
{
    if (p == 10)
        return layer % 2 ? 0.6 : 0.4;
    return (layer / 2) % 2 == (layer % 2) ? 0.2 : 0.8;
}

/* With replicates the target reads the calibrated error (sched_target.c):
 * the replicates' spread over a pixel's first layers, the mean of its
 * neighbours'. The pixels whose replicates agree stop after their first
 * SCHED_TARGET_CALIBRATED_LAYERS layers, however their layers swing, but those
 * with pixel 10 in their window go on to the cap; so does every pixel when
 * the job has one sequence (the layer means' spread) or no target. */
START_TEST(test_target_calibrated_by_replicates)
{
    run_noisy_one(swinging_chunks, 32, 1, 1, "one sequence");
    run_noisy_one(swinging_chunks, 32, 2, 0, "2 replicates");
}
END_TEST

/* An adaptive rule under a target error: the pixels that met the target
 * early (pixel 10, judged by its steady neighbours, and those far from
 * it) take no more layers, and the pixels still short of it (those with
 * pixel 10 in their window) take every layer: once the early ones' frozen
 * metrics held the skip rule's threshold above them, and they skipped
 * every layer to the end of the job, there and on the Cornell box. Every
 * mode ends with every pixel at the target, as without a rule. */
START_TEST(test_target_with_adaptive_rule_converges_all)
{
    for (int mode = SCHED_ADAPTIVE_NONE; mode <= SCHED_ADAPTIVE_RELMSE; mode++) {
        sched_config_t c = row_target(400, (sched_adaptive_t)mode, 0.2, 1);
        sched_t *s = new_sched(&c);
        run_all(s, one_noisy, 4);
        ck_assert(sched_done(s));
        ck_assert_msg(sched_converged(s) == 16 && sched_stopped_on_target(s),
                      "%s: %llu of 16 pixels met the target", sched_adaptive_name(c.adaptive),
                      (unsigned long long)sched_converged(s));
        sched_destroy(&s);
    }
}
END_TEST

/* relerr and variance keep the noisy pixels and skip the steady ones.
 * relerr and relmse judge a pixel by its neighbours: the two at the border
 * (7 and 8, one steady and one noisy neighbour each) may go either way. */
START_TEST(test_relerr_and_variance_modes)
{
    char err[256];
    for (int mode = SCHED_ADAPTIVE_VARIANCE; mode <= SCHED_ADAPTIVE_RELMSE; mode++) {
        sched_config_t c = {.width = 16,
                            .height = 1,
                            .spp = 64,
                            .granularity = 4,
                            .adaptive = (sched_adaptive_t)mode,
                            .uniform_layers = 4,
                            .range_pixels = 4};
        sched_t *s = sched_new(&c, err, sizeof err);
        ck_assert_msg(s != NULL, "%s", err);
        run_all(s, steady_or_noisy, 4);
        const film_t *f = sched_film(s);
        const int pooled = mode != SCHED_ADAPTIVE_VARIANCE;
        for (uint32_t p = 0; p < 16; p++) {
            if (pooled && (p == 7 || p == 8))
                continue;
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

/* pixels 0-7 swing +-0.05 about 0.5 layer to layer, pixels 8-15 four times as far */
static double two_noise_levels(uint32_t p, uint32_t layer)
{
    double a = p < 8 ? 0.05 : 0.2;
    return 0.5 + (layer % 2 ? a : -a);
}

/* Layers pixel a took over those pixel b took, in a 16 x 1 image run with
 * 4 uniform layers and then 396 adaptive ones (an explicit flag sequence:
 * the default's uniform layer in every SCHED_UNIFORM_EVERY would cap the
 * ratios the tests below look for). */
static double layer_ratio(sched_adaptive_t mode, lum_fn f, cost_fn cost, uint32_t a, uint32_t b)
{
    char err[256], flags[401];
    memset(flags, '1', 400);
    memset(flags, '0', 4);
    flags[400] = '\0';
    sched_config_t c = {.width = 16,
                        .height = 1,
                        .spp = 4 * 400,
                        .granularity = 4,
                        .adaptive = mode,
                        .uniform_layers = UINT32_MAX,
                        .flags = flags,
                        .range_pixels = 4};
    sched_t *s = sched_new(&c, err, sizeof err);
    ck_assert_msg(s != NULL, "%s", err);
    run_all_costing(s, f, 4, cost);
    const film_t *film = sched_film(s);
    double ratio = (double)film->pixels[a].count / (double)film->pixels[b].count;
    sched_destroy(&s);
    return ratio;
}

/* What each mode balances shows in how it shares layers between pixels whose
 * relative variance differs 16-fold: relerr equalises the relative error
 * (layers in proportion to the variance, about 16:1), relmse the relMSE one
 * more layer takes off (in proportion to its square root, 4:1), which is
 * what minimises the image's relMSE for the samples spent. */
START_TEST(test_relmse_balances_sqrt_variance)
{
    double relmse = layer_ratio(SCHED_ADAPTIVE_RELMSE, two_noise_levels, one_ray, 12, 3),
           relerr = layer_ratio(SCHED_ADAPTIVE_RELERR, two_noise_levels, one_ray, 12, 3);
    ck_assert_msg(relmse > 3 && relmse < 5.5, "relmse: layers noisy / quiet %g", relmse);
    ck_assert_msg(relerr > 9, "relerr: layers noisy / quiet %g", relerr);
}
END_TEST

/* every pixel swings +-0.2 about 0.5 layer to layer */
static double one_noise_level(uint32_t p, uint32_t layer)
{
    (void)p;
    return 0.5 + (layer % 2 ? 0.2 : -0.2);
}

/* pixels 8-15 trace four rays a sample, pixels 0-7 one */
static uint32_t right_half_costs_four(uint32_t pixel)
{
    return pixel < 8 ? 1 : 4;
}

/* relmse weighs a layer's gain against its cost: with the same variance
 * everywhere, pixels whose samples trace 4x the rays get layers in
 * proportion to sqrt(1/4), half as many (n ~ sqrt(v / c) minimises the
 * image's relMSE for the rays spent); with equal costs the same pixels get
 * equal layers, so the difference is the cost's alone. */
START_TEST(test_relmse_weighs_cost)
{
    double equal = layer_ratio(SCHED_ADAPTIVE_RELMSE, one_noise_level, one_ray, 3, 12),
           costly =
               layer_ratio(SCHED_ADAPTIVE_RELMSE, one_noise_level, right_half_costs_four, 3, 12);
    ck_assert_msg(equal > 0.9 && equal < 1.1, "equal costs: layers 3 / 12 %g", equal);
    ck_assert_msg(costly > 1.7 && costly < 2.4, "4x cost: layers cheap / costly %g", costly);
}
END_TEST

/* A job of 64 x height pixels, G = 4, its layers, 8 of them uniform. */
static sched_config_t wide_config(sched_adaptive_t mode, uint32_t height, uint32_t layers)
{
    return (sched_config_t){.width = 64,
                            .height = height,
                            .spp = 4 * layers,
                            .granularity = 4,
                            .adaptive = mode,
                            .uniform_layers = 8,
                            .range_pixels = 64};
}

/* A job run to its end on the layer means f gives. */
static sched_t *run_config(const sched_config_t *c, lum_fn f)
{
    sched_t *s = new_sched(c);
    run_all(s, f, 4);
    return s;
}

static sched_t *run_64_wide(sched_adaptive_t mode, uint32_t height, uint32_t layers, lum_fn f)
{
    sched_config_t c = wide_config(mode, height, layers);
    return run_config(&c, f);
}

/* every pixel the same: layer means 0.3 to 0.7, hashed from pixel and layer */
static double alike_noise(uint32_t p, uint32_t layer)
{
    rng_stream_t r = rng_stream(0xa11cULL, p, layer);
    return 0.3 + 0.4 * rng_next_double(&r);
}

/* the same, but the right half of a 64-wide image four times as noisy (0.1
 * to 1.7) */
static double half_noisier(uint32_t p, uint32_t layer)
{
    return p % 64 < 32 ? alike_noise(p, layer) : 0.9 + 4 * (alike_noise(p, layer) - 0.5);
}

/* Pixels that differ only by their noise: relmse and relerr keep every
 * layer uniform (SCHED_ALIKE_SPREAD), since balancing them gains nothing
 * and under sobol each skipped layer breaks a pixel's nets (the white
 * furnace). thesis judges each pixel by its own noise, as published, and
 * skips; and the same relmse job skips once half the image is four times
 * as noisy. */
START_TEST(test_alike_pixels_stay_uniform)
{
    const sched_adaptive_t modes[] = {SCHED_ADAPTIVE_RELMSE, SCHED_ADAPTIVE_RELERR,
                                      SCHED_ADAPTIVE_THESIS, SCHED_ADAPTIVE_RELMSE};
    for (int k = 0; k < 4; k++) {
        sched_t *s = run_64_wide(modes[k], 32, 40, k < 3 ? alike_noise : half_noisier);
        const uint64_t skipped = sched_pixel_layers_skipped(s);
        if (k < 2)
            ck_assert_msg(skipped == 0, "%s: %llu pixel-layers skipped",
                          sched_adaptive_name(modes[k]), (unsigned long long)skipped);
        else
            ck_assert_msg(skipped > 2048, "%s: %llu pixel-layers skipped",
                          sched_adaptive_name(modes[k]), (unsigned long long)skipped);
        sched_destroy(&s);
    }
}
END_TEST

/* Under a target error the target alone decides which pixels take a
 * layer, whatever the adaptive mode: each pixel takes exactly the layers
 * it takes under --adaptive none (the noisy half runs to the cap, the
 * steady half stops when it meets the target). A skip rule on top once
 * left pixels with neither the target met nor the cap reached when the
 * job's last layer was done (the glass scene at E = 0.02: 0.89 of its
 * pixels within E where none holds 0.96). */
START_TEST(test_target_decides_alone)
{
    sched_config_t c = wide_config(SCHED_ADAPTIVE_NONE, 16, 64);
    c.target_error = 0.1;
    c.replicates = 2;
    sched_t *none = run_config(&c, half_noisier);
    const film_t *want = sched_film(none);
    uint32_t capped = 0, stopped = 0;
    for (uint32_t p = 0; p < 64 * 16; p++) {
        capped += want->pixels[p].count == c.spp;
        stopped += want->pixels[p].count < c.spp;
    }
    ck_assert_msg(capped > 100 && stopped > 100, "none: %u capped, %u stopped by the target",
                  capped, stopped);
    for (int mode = SCHED_ADAPTIVE_THESIS; mode <= SCHED_ADAPTIVE_RELMSE; mode++) {
        c.adaptive = (sched_adaptive_t)mode;
        sched_t *s = run_config(&c, half_noisier);
        const film_t *got = sched_film(s);
        for (uint32_t p = 0; p < 64 * 16; p++)
            ck_assert_msg(got->pixels[p].count == want->pixels[p].count,
                          "%s: pixel %u took %llu samples, --adaptive none %llu",
                          sched_adaptive_name(c.adaptive), p,
                          (unsigned long long)got->pixels[p].count,
                          (unsigned long long)want->pixels[p].count);
        sched_destroy(&s);
    }
    sched_destroy(&none);
}
END_TEST

/* A pixel's records number its samples from 0 up without gaps, whichever
 * layers it skipped: first_sample is the samples its earlier layers took,
 * so its samples are the first of its Sobol sequence (rng.h). */
START_TEST(test_first_sample_counts_taken_layers)
{
    char err[256];
    sched_config_t c = {.width = 16,
                        .height = 1,
                        .spp = 4 * 60,
                        .granularity = 4,
                        .adaptive = SCHED_ADAPTIVE_RELMSE,
                        .uniform_layers = 4,
                        .range_pixels = 4};
    sched_t *s = sched_new(&c, err, sizeof err);
    ck_assert_msg(s != NULL, "%s", err);
    uint64_t next[16] = {0};
    uint32_t skipping = 0;
    sched_task_t t;
    tracer_result_t r[16];
    int rc;
    while ((rc = sched_next(s, &t)) != SCHED_NEXT_ALL_ISSUED) {
        ck_assert_int_eq(rc, 1);
        for (uint32_t i = 0; i < t.count; i++) {
            const tracer_task_t *k = &t.records[i];
            ck_assert_msg(k->first_sample == next[k->pixel],
                          "pixel %u layer %u: first sample %llu, expected %llu", k->pixel, t.layer,
                          (unsigned long long)k->first_sample, (unsigned long long)next[k->pixel]);
            skipping += k->first_sample < (uint64_t)t.layer * c.granularity;
            next[k->pixel] += k->sample_count;
            memset(&r[i], 0, sizeof r[i]);
            r[i].pixel = k->pixel;
            r[i].samples = k->sample_count;
            r[i].rays = k->sample_count;
            double l = two_noise_levels(k->pixel, t.layer) * r[i].samples;
            r[i].sum[0] = r[i].sum[1] = r[i].sum[2] = l;
            r[i].lum_m2 = 0.01 * c.granularity;
            r[i].pvar = two_noise_levels(k->pixel, t.layer);
        }
        ck_assert_msg(sched_complete(s, t.id, r, t.count, err, sizeof err) == 0, "%s", err);
    }
    ck_assert_msg(skipping > 0, "no pixel skipped a layer: the test proves nothing");
    const film_t *f = sched_film(s);
    for (uint32_t p = 0; p < 16; p++)
        ck_assert_uint_eq(next[p], f->pixels[p].count);
    sched_destroy(&s);
}
END_TEST

/* Every pixel's true value 1.0. In the right half of a 64-wide image a
 * rare bright path: a layer's mean is 0.5, or 10.5 in one layer of twenty
 * (hashed from pixel and layer); the left half is steady, 1.0 +- 0.05
 * (pixels all alike keep every layer uniform: SCHED_ALIKE_SPREAD). */
static double rare_bright(uint32_t p, uint32_t layer)
{
    rng_stream_t r = rng_stream(0xb1a5ULL, p, layer);
    const double u = rng_next_double(&r);
    if (p % 64 < 32)
        return 0.95 + 0.1 * u;
    return u < 0.05 ? 10.5 : 0.5;
}

/* The mean over a film's pixels of their estimates (red channel), its
 * standard error, and the fewest and most samples a pixel took. */
typedef struct film_summary {
    double mean, sd;
    uint64_t least, most;
} film_summary_t;

static film_summary_t summarise(const film_t *f, uint32_t npix)
{
    double sum = 0, sum2 = 0;
    film_summary_t r = {0, 0, UINT64_MAX, 0};
    for (uint32_t p = 0; p < npix; p++) {
        double v = f->pixels[p].sum[0] / (double)f->pixels[p].count;
        sum += v;
        sum2 += v * v;
        r.least = f->pixels[p].count < r.least ? f->pixels[p].count : r.least;
        r.most = f->pixels[p].count > r.most ? f->pixels[p].count : r.most;
    }
    r.mean = sum / npix;
    r.sd = sqrt((sum2 / npix - r.mean * r.mean) / (npix - 1));
    return r;
}

/* relerr and relmse must not bias a pixel's mean: a pixel judged by its own
 * layers stops early exactly when it has not met the bright path yet, so the
 * image came out low (-3 to -4 % on the glass scene); judged
 * by its neighbours' uniform layers, the mean over 4096 pixels is within
 * noise of 1.
 * thesis and variance judge the pixel by itself, as published, and stay
 * biased: the test shows the effect is real, not an accident of the data. */
START_TEST(test_adaptive_unbiased)
{
    const sched_adaptive_t modes[] = {SCHED_ADAPTIVE_RELMSE, SCHED_ADAPTIVE_RELERR,
                                      SCHED_ADAPTIVE_VARIANCE};
    for (int k = 0; k < 3; k++) {
        sched_t *s = run_64_wide(modes[k], 64, 48, rare_bright);
        film_summary_t fs = summarise(sched_film(s), 4096);
        double mean = fs.mean, sd = fs.sd;
        uint64_t least = fs.least, most = fs.most;
        const char *name = sched_adaptive_name(modes[k]);
        /* it adapted: some pixels took twice the layers of others */
        ck_assert_msg(2 * least <= most, "%s: samples %llu..%llu", name, (unsigned long long)least,
                      (unsigned long long)most);
        if (modes[k] == SCHED_ADAPTIVE_VARIANCE)
            ck_assert_msg(mean < 1 - 6 * sd, "%s: mean %.4f +- %.4f, expected low", name, mean, sd);
        else
            ck_assert_msg(fabs(mean - 1) < 4 * sd, "%s: mean %.4f +- %.4f, expected 1", name, mean,
                          sd);
        sched_destroy(&s);
    }
}
END_TEST

/* A rarer bright path: a layer's mean is 0.5, or 167.2 in one layer of
 * 300 (true value 1.0), so most 5 x 5 windows have met none in their
 * first layers, and a pixel that has is the exception. */
static double rarer_bright(uint32_t p, uint32_t layer)
{
    rng_stream_t r = rng_stream(0xb1a6ULL, p, layer);
    return rng_next_double(&r) < 1.0 / 300 ? 0.5 + 0.5 * 300 : 0.5;
}

/* The target error must not bias a pixel's mean either. Judged by a window
 * that includes its own layers, a pixel that has met the bright path goes
 * on and dilutes it while one that has not stops: the image came out at
 * 0.86 here. Leaving the pixel out is not enough, as long as a neighbour's
 * statistics grow with the layers it took (with one bright layer in 333,
 * 0.84 against 0.82 with the pixel in): the pixel's bright layer
 * keeps its neighbours going, which keeps their statistics changing and so
 * the pixel going. With every pixel's statistics frozen after its first
 * SCHED_TARGET_MIN_LAYERS layers, the mean over 16384 pixels is within
 * noise of 1, with relmse's skipping as well. */
START_TEST(test_target_unbiased)
{
    char err[256];
    const sched_adaptive_t modes[] = {SCHED_ADAPTIVE_NONE, SCHED_ADAPTIVE_RELMSE};
    /* one sequence, and two replicates (the calibrated statistics) */
    for (int k = 0; k < 4; k++) {
        sched_config_t c = {.width = 128,
                            .height = 128,
                            .spp = 4 * 64,
                            .granularity = 4,
                            .adaptive = modes[k % 2],
                            .uniform_layers = 8,
                            .range_pixels = 64,
                            .target_error = 0.5,
                            .confidence = 0.95,
                            .target_share = 1.0,
                            .replicates = k < 2 ? 1 : 2};
        sched_t *s = sched_new(&c, err, sizeof err);
        ck_assert_msg(s != NULL, "%s", err);
        run_all(s, rarer_bright, 4);
        const uint32_t n = 128 * 128;
        film_summary_t fs = summarise(sched_film(s), n);
        double mean = fs.mean, sd = fs.sd;
        uint64_t least = fs.least, most = fs.most;
        char name[64];
        snprintf(name, sizeof name, "%s, %u replicates", sched_adaptive_name(modes[k % 2]),
                 c.replicates);
        /* it stopped pixels: some took far fewer samples than others */
        ck_assert_msg(sched_converged(s) > n / 4 && 3 * least <= most,
                      "%s: %llu converged, samples %llu..%llu", name,
                      (unsigned long long)sched_converged(s), (unsigned long long)least,
                      (unsigned long long)most);
        ck_assert_msg(fabs(mean - 1) < 4 * sd, "%s: mean %.4f +- %.4f, expected 1", name, mean, sd);
        sched_destroy(&s);
    }
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
        sched_config_t c = {.width = 5,
                            .height = 5,
                            .spp = 16,
                            .granularity = 4,
                            .adaptive = SCHED_ADAPTIVE_VARIANCE,
                            .uniform_layers = 2,
                            .range_pixels = 25,
                            .dilate = dil};
        sched_t *s = sched_new(&c, err, sizeof err);
        ck_assert_msg(s != NULL, "%s", err);
        run_until_decided(s, one_hot, 4, 3);
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
        sched_config_t c = {.width = 64,
                            .height = 1,
                            .spp = 64,
                            .granularity = 4,
                            .adaptive = SCHED_ADAPTIVE_THESIS,
                            .uniform_layers = 2,
                            .range_pixels = 16,
                            .random_selection = 1,
                            .seed = 77};
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
    sched_config_t c = {.width = 0,
                        .height = 4,
                        .spp = 8,
                        .granularity = 2,
                        .adaptive = SCHED_ADAPTIVE_NONE,
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

/* Results are range-checked before anything is merged: a lying or broken
 * worker's values are refused with a message, the task stays outstanding
 * (the master issues it again), and the film never becomes non-finite. */
/* A job that gives no uniform layers: the thesis runs half its layers
 * uniformly, the other modes at most SCHED_DEFAULT_UNIFORM_LAYERS, so a job
 * whose spp is only a cap (--time-limit, --target-error) still adapts. */
START_TEST(test_default_uniform_layers)
{
    char err[256];
    ck_assert_uint_eq(sched_default_uniform_layers(SCHED_ADAPTIVE_NONE, 2048), 2048);
    ck_assert_uint_eq(sched_default_uniform_layers(SCHED_ADAPTIVE_THESIS, 2048), 1024);
    ck_assert_uint_eq(sched_default_uniform_layers(SCHED_ADAPTIVE_RELERR, 2048),
                      SCHED_DEFAULT_UNIFORM_LAYERS);
    ck_assert_uint_eq(sched_default_uniform_layers(SCHED_ADAPTIVE_VARIANCE, 2048),
                      SCHED_DEFAULT_UNIFORM_LAYERS);
    ck_assert_uint_eq(sched_default_uniform_layers(SCHED_ADAPTIVE_RELERR, 6), 3);
    /* --spp 65536 --time-limit 60 at G = 32: 2048 layers, adapting after 8 */
    sched_config_t c = {.width = 2,
                        .height = 2,
                        .spp = 65536,
                        .granularity = 32,
                        .adaptive = SCHED_ADAPTIVE_RELERR,
                        .uniform_layers = UINT32_MAX};
    sched_t *s = sched_new(&c, err, sizeof err);
    ck_assert_msg(s != NULL, "%s", err);
    ck_assert_uint_eq(sched_uniform_layers(s), SCHED_DEFAULT_UNIFORM_LAYERS);
    sched_destroy(&s);
    c.adaptive = SCHED_ADAPTIVE_THESIS;
    s = sched_new(&c, err, sizeof err);
    ck_assert_msg(s != NULL, "%s", err);
    ck_assert_uint_eq(sched_uniform_layers(s), 1024);
    sched_destroy(&s);
    c.uniform_layers = 5; /* what the job says wins */
    s = sched_new(&c, err, sizeof err);
    ck_assert_msg(s != NULL, "%s", err);
    ck_assert_uint_eq(sched_uniform_layers(s), 5);
    sched_destroy(&s);
}
END_TEST

START_TEST(test_results_range_checked)
{
    sched_t *s = make(4, 1, 64, 32, SCHED_ADAPTIVE_NONE, UINT32_MAX, 4);
    sched_task_t t;
    tracer_result_t r[4];
    char err[256];
    ck_assert_int_eq(sched_next(s, &t), 1);
    static const struct {
        int field; /* 0 sum, 1 m2, 2 pvar, 3 all NaN samples, 4 sums without samples */
        double v;
        const char *want;
    } bad[] = {
        {0, NAN, "out of range"},     {0, INFINITY, "out of range"},  {0, -1.0, "out of range"},
        {0, 1.7e308, "out of range"}, {0, 32 * 2e30, "out of range"}, {1, -0.5, "out of range"},
        {1, NAN, "out of range"},     {2, INFINITY, "out of range"},  {3, 0, "implausible"},
        {4, 1.0, "out of range"},
    };
    for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
        fake_results(&t, r, NULL);
        switch (bad[k].field) {
        case 0:
            r[1].sum[2] = bad[k].v;
            break;
        case 1:
            r[1].lum_m2 = bad[k].v;
            break;
        case 2:
            r[1].pvar = bad[k].v;
            break;
        case 3:
            for (uint32_t i = 0; i < t.count; i++) {
                r[i].nonfinite = r[i].samples;
                r[i].samples = 0;
                r[i].sum[0] = r[i].sum[1] = r[i].sum[2] = r[i].lum_m2 = 0;
            }
            break;
        default:
            r[1].nonfinite = r[1].samples;
            r[1].samples = 0;
            r[1].lum_m2 = 0;
            r[1].sum[0] = bad[k].v;
            break;
        }
        ck_assert_msg(sched_complete(s, t.id, r, t.count, err, sizeof err) == SCHED_BAD_RESULT,
                      "case %zu accepted", k);
        ck_assert_msg(strstr(err, bad[k].want) != NULL, "case %zu: %s", k, err);
        ck_assert_uint_eq(sched_samples_done(s), 0);
    }
    /* just under the cap merges (the film's own overflow check,
     * film_merge_check, is tested in test_film) */
    fake_results(&t, r, NULL);
    r[0].sum[0] = 32 * 0.9e30;
    ck_assert_msg(sched_complete(s, t.id, r, t.count, err, sizeof err) == 0, "%s", err);
    const film_t *f = sched_film(s);
    for (int p = 0; p < 4; p++)
        for (int c = 0; c < 3; c++)
            ck_assert(isfinite(f->pixels[p].sum[c]));
    /* a few NaN samples are light, not lies */
    ck_assert_int_eq(sched_next(s, &t), 1);
    fake_results(&t, r, NULL);
    r[2].nonfinite = 3;
    r[2].samples -= 3;
    ck_assert_msg(sched_complete(s, t.id, r, t.count, err, sizeof err) == 0, "%s", err);
    ck_assert(sched_done(s));
    sched_destroy(&s);
}
END_TEST

/* What verification (master/verify.c) needs: an outstanding task's records
 * again, the same pointer and values sched_next gave, to send the task to a
 * second worker; and a result judged without merging (sched_check), which
 * changes nothing until sched_complete merges it. Requeued or completed
 * tasks are not outstanding. */
START_TEST(test_outstanding_and_check)
{
    sched_t *s = make(4, 1, 64, 32, SCHED_ADAPTIVE_NONE, UINT32_MAX, 2);
    sched_task_t a, b, again;
    tracer_result_t r[4];
    char err[256];
    ck_assert_int_eq(sched_outstanding(s, 1, &again),
                     SCHED_NOT_OUTSTANDING); /* nothing issued yet */
    ck_assert_int_eq(sched_next(s, &a), 1);
    ck_assert_int_eq(sched_next(s, &b), 1);
    ck_assert_int_eq(sched_outstanding(s, a.id, &again), 0);
    ck_assert_uint_eq(again.id, a.id);
    ck_assert_uint_eq(again.layer, a.layer);
    ck_assert_uint_eq(again.range, a.range);
    ck_assert_uint_eq(again.count, a.count);
    ck_assert_ptr_eq(again.records, a.records);
    ck_assert_int_eq(sched_outstanding(s, 0, &again), SCHED_NOT_OUTSTANDING);
    ck_assert_int_eq(sched_outstanding(s, 12345, &again), SCHED_NOT_OUTSTANDING);
    /* judged, not merged */
    fake_results(&a, r, NULL);
    ck_assert_msg(sched_check(s, a.id, r, a.count, err, sizeof err) == 0, "%s", err);
    ck_assert_uint_eq(sched_samples_done(s), 0);
    ck_assert_int_eq(sched_outstanding(s, a.id, &again), 0);
    r[1].sum[0] = -1.0;
    ck_assert_int_eq(sched_check(s, a.id, r, a.count, err, sizeof err), SCHED_BAD_RESULT);
    ck_assert_msg(strstr(err, "out of range") != NULL, "%s", err);
    ck_assert_int_eq(sched_check(s, a.id, r, a.count + 1, err, sizeof err), SCHED_BAD_RESULT);
    /* requeued: not outstanding until issued again, then the same records */
    ck_assert_int_eq(sched_requeue(s, b.id), 0);
    ck_assert_int_eq(sched_outstanding(s, b.id, &again), SCHED_NOT_OUTSTANDING);
    fake_results(&b, r, NULL);
    ck_assert_int_eq(sched_check(s, b.id, r, b.count, err, sizeof err), SCHED_NOT_OUTSTANDING);
    ck_assert_int_eq(sched_next(s, &again), 1);
    ck_assert_uint_eq(again.id, b.id);
    ck_assert_int_eq(sched_outstanding(s, b.id, &again), 0);
    ck_assert_ptr_eq(again.records, b.records);
    /* completed: gone */
    fake_results(&a, r, NULL);
    ck_assert_msg(sched_complete(s, a.id, r, a.count, err, sizeof err) == 0, "%s", err);
    ck_assert_int_eq(sched_outstanding(s, a.id, &again), SCHED_NOT_OUTSTANDING);
    ck_assert_int_eq(sched_check(s, a.id, r, a.count, err, sizeof err), SCHED_NOT_OUTSTANDING);
    ck_assert_uint_eq(sched_samples_done(s), 2 * 32);
    sched_destroy(&s);
}
END_TEST

/* A submit must not freeze the master: sched_new for a job of about a
 * million layers does no per-layer work beyond zeroed allocations (the t
 * factors are computed when first needed). Not timed: 20 of them took about
 * 20 minutes when every t factor was computed up front, and Check's timeout
 * catches that; now they take milliseconds. */
static void sum_pixel_state(void *ctx, const char *name, size_t bytes)
{
    if (!strchr(name, ' ')) /* the film and per-pixel arrays; the window's have spaces */
        *(size_t *)ctx += bytes;
}

/* 3840 x 2160 at 65,536 spp (2,048 layers) is accepted, and its film and
 * statistics take at most 128 bytes a pixel in the default mode, whatever
 * the layers (the scheduler is not started: that would touch 1 GB). */
START_TEST(test_production_resolution_fits)
{
    static const uint32_t spps[] = {256, 65536, 1048576};
    for (size_t i = 0; i < sizeof spps / sizeof spps[0]; i++) {
        sched_config_t c = {.width = 3840,
                            .height = 2160,
                            .spp = spps[i],
                            .granularity = 32,
                            .adaptive = SCHED_ADAPTIVE_RELMSE,
                            .uniform_layers = UINT32_MAX};
        char err[256];
        sched_t *s = sched_new(&c, err, sizeof err);
        ck_assert_msg(s != NULL, "%u spp: %s", spps[i], err);
        size_t pixel_state = 0;
        size_t total = sched_memory(s, sum_pixel_state, &pixel_state);
        const double npix = 3840.0 * 2160.0;
        ck_assert_msg(pixel_state <= 128 * npix, "%.1f bytes a pixel", pixel_state / npix);
        /* the window: two layers' membership and cells, a few rows */
        ck_assert_msg(total - pixel_state < 2 * npix, "%.1f bytes a pixel beside the state",
                      (total - pixel_state) / npix);
        sched_destroy(&s);
    }
}
END_TEST

START_TEST(test_many_layers_new_is_cheap)
{
    char err[256];
    for (int i = 0; i < 20; i++) {
        /* 2^25 samples in layers of 32: 2^20 layers of one pixel; relerr and a
         * target error read both t tables */
        sched_config_t c = {.width = 1,
                            .height = 1,
                            .spp = 1u << 25,
                            .granularity = 32,
                            .adaptive = i % 2 ? SCHED_ADAPTIVE_RELERR : SCHED_ADAPTIVE_THESIS,
                            .uniform_layers = UINT32_MAX,
                            .target_error = 0.01,
                            .confidence = 0.99};
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
            r.rays = 32;
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

/* ---- checkpoints ---------------------------------------------------------- */

typedef struct membuf {
    uint8_t *data;
    size_t len, cap, pos;
} membuf_t;

static int mem_write(void *ctx, const void *data, size_t len)
{
    membuf_t *b = ctx;
    if (b->len + len > b->cap) {
        size_t cap = b->cap ? b->cap : 4096;
        while (cap < b->len + len)
            cap *= 2;
        uint8_t *d = realloc(b->data, cap);
        if (!d)
            return -1;
        b->data = d;
        b->cap = cap;
    }
    memcpy(b->data + b->len, data, len);
    b->len += len;
    return 0;
}

static int mem_read(void *ctx, void *data, size_t len)
{
    membuf_t *b = ctx;
    if (len > b->len - b->pos)
        return -1;
    memcpy(data, b->data + b->pos, len);
    b->pos += len;
    return 0;
}

/* A copy of a saved job to edit. */
static membuf_t copy_of(const membuf_t *b)
{
    membuf_t m = {malloc(b->len), b->len, b->len, 0};
    ck_assert_ptr_nonnull(m.data);
    memcpy(m.data, b->data, b->len);
    return m;
}

static membuf_t save_mem(const sched_t *s)
{
    membuf_t b = {0};
    ck_assert_int_eq(sched_save(s, mem_write, &b), 0);
    return b;
}

/* Loads from the first len bytes of b. */
static sched_t *load_mem(const sched_config_t *c, const membuf_t *b, size_t len, char *err,
                         size_t errlen)
{
    membuf_t r = {b->data, len, len, 0};
    return sched_load(c, mem_read, &r, err, errlen);
}

/* A worker for checkpoint runs: a pixel's layer is a pure function of
 * (pixel, first sample) and of its prior sums (stale priors in a restored
 * task would show). Some pixels are noisy and most steady, in bands of two
 * rows of CK_BASE's 11 pixels (so that a pixel's neighbours are much like
 * it: relerr and relmse judge it by them), so the adaptive modes skip and
 * the target error converges; now and then a sample is NaN. */
static void hashed_results(const sched_task_t *t, tracer_result_t *r)
{
    for (uint32_t i = 0; i < t->count; i++) {
        const tracer_task_t *k = &t->records[i];
        rng_stream_t st = rng_stream(0xc0ffee, k->pixel, k->first_sample);
        double u = rng_next_double(&st), v = rng_next_double(&st);
        const uint32_t band = k->pixel / 22 % 3;
        double noise = band == 0 ? 0.9 : band == 1 ? 0.2 : 0.01;
        double mean = 0.5 + 0.05 * (k->pixel % 7) + noise * (u - 0.5); /* > 0: radiance */
        memset(&r[i], 0, sizeof r[i]);
        r[i].pixel = k->pixel;
        r[i].nonfinite = k->sample_count > 1 && v < 0.05;
        r[i].samples = k->sample_count - r[i].nonfinite;
        r[i].rays = k->sample_count * (1 + (uint32_t)(4 * u)); /* 1-4 a sample, hashed */
        for (int c = 0; c < 3; c++)
            r[i].sum[c] = mean * r[i].samples * (1.0 + 0.1 * c) + 1e-9 * k->prior_sum[c] +
                          1e-12 * (double)k->prior_count;
        r[i].lum_m2 = noise * noise * r[i].samples * (0.5 + v);
        r[i].pvar = noise * noise * (0.5 + u);
    }
}

/* A job with simulated workers finishing in a pseudo-random order and now
 * and then losing a task (requeue). */
typedef struct sim {
    sched_t *s;
    sched_task_t inflight[32];
    int n, workers;
    uint64_t seed, step;
} sim_t;

/* One event; 0 once the job is done. */
static int sim_step(sim_t *m)
{
    tracer_result_t r[64];
    char err[256];
    sched_task_t t;
    while (m->n < m->workers && sched_next(m->s, &t) == 1)
        m->inflight[m->n++] = t;
    if (m->n == 0) {
        ck_assert(sched_done(m->s));
        return 0;
    }
    rng_stream_t st = rng_stream(m->seed, 0, m->step++);
    int pick = (int)(rng_next_double(&st) * m->n);
    if (rng_next_double(&st) < 0.15) {
        ck_assert_int_eq(sched_requeue(m->s, m->inflight[pick].id), 0);
    } else {
        ck_assert_uint_le(m->inflight[pick].count, 64);
        hashed_results(&m->inflight[pick], r);
        ck_assert_msg(sched_complete(m->s, m->inflight[pick].id, r, m->inflight[pick].count, err,
                                     sizeof err) == 0,
                      "%s", err);
    }
    m->inflight[pick] = m->inflight[--m->n];
    return 1;
}

/* Replaces the sim's scheduler by one saved and restored from it: its
 * outstanding tasks are dropped, as a crashed master's are. */
static void sim_restore(sim_t *m, const sched_config_t *c)
{
    char err[256];
    membuf_t b = save_mem(m->s);
    sched_t *n = load_mem(c, &b, b.len, err, sizeof err);
    ck_assert_msg(n != NULL, "%s", err);
    free(b.data);
    sched_destroy(&m->s);
    m->s = n;
    m->n = 0;
}

/* Two finished jobs gave the same film, layers and counters. */
static void assert_same_job(const sched_t *a, const sched_t *b, const char *what, uint64_t at)
{
    ck_assert(sched_done(a) && sched_done(b));
    const film_t *fa = sched_film(a), *fb = sched_film(b);
    size_t n = (size_t)fa->width * (size_t)fa->height;
    ck_assert_msg(memcmp(fa->pixels, fb->pixels, n * sizeof(film_pixel_t)) == 0,
                  "%s, restored at step %llu: film differs", what, (unsigned long long)at);
    ck_assert_uint_eq(sched_pixel_layers(a), sched_pixel_layers(b));
    ck_assert_uint_eq(sched_pixel_layers_skipped(a), sched_pixel_layers_skipped(b));
    ck_assert_uint_eq(sched_converged(a), sched_converged(b));
    ck_assert_int_eq(sched_stopped_on_target(a), sched_stopped_on_target(b));
    ck_assert_uint_eq(sched_pixels_at_cap(a), sched_pixels_at_cap(b));
    ck_assert_uint_eq(sched_samples_done(a), sched_samples_done(b));
    ck_assert_uint_eq(sched_nonfinite(a), sched_nonfinite(b));
    ck_assert_uint_eq(sched_layers_complete(a), sched_layers_complete(b));
    /* the replicates' sums too, through the error they give */
    float *va = malloc(n * sizeof(float)), *vb = malloc(n * sizeof(float));
    ck_assert(va && vb && sched_variance_of_mean(a, va) == 0 && sched_variance_of_mean(b, vb) == 0);
    ck_assert_msg(memcmp(va, vb, n * sizeof(float)) == 0,
                  "%s, restored at step %llu: error differs", what, (unsigned long long)at);
    free(va);
    free(vb);
    for (uint32_t l = 0; l < sched_layer_count(a); l++) {
        double ta = sched_threshold(a, l), tb = sched_threshold(b, l);
        ck_assert_msg(memcmp(&ta, &tb, sizeof ta) == 0, "%s: threshold of layer %u differs", what,
                      l);
        for (uint32_t p = 0; p < n; p++)
            ck_assert_int_eq(sched_pixel_in_layer(a, l, p), sched_pixel_in_layer(b, l, p));
    }
}

typedef struct ckpt_case {
    const char *name;
    sched_config_t cfg;
} ckpt_case_t;

#define CK_BASE .width = 11, .height = 9, .spp = 48, .granularity = 4, .range_pixels = 7
/* CK_BASE with layers enough for the calibrated target's statistics
 * (SCHED_TARGET_CALIBRATED_LAYERS), 2 replicates and a target error */
#define CK_CALIBRATED                                                                              \
    .width = 11, .height = 9, .spp = 4 * 24, .granularity = 4, .range_pixels = 7,                  \
    .target_error = 0.5, .replicates = 2
static const ckpt_case_t ckpt_cases[] = {
    {"uniform", {CK_BASE, .adaptive = SCHED_ADAPTIVE_NONE, .uniform_layers = 3}},
    {"thesis", {CK_BASE, .adaptive = SCHED_ADAPTIVE_THESIS, .uniform_layers = 3}},
    {"variance", {CK_BASE, .adaptive = SCHED_ADAPTIVE_VARIANCE, .uniform_layers = 3}},
    {"relerr", {CK_BASE, .adaptive = SCHED_ADAPTIVE_RELERR, .uniform_layers = 3}},
    /* more uniform layers: relerr alone would skip the steady pixels before
     * they have the layers to converge; a target the 5 x 5 window of the
     * fake layer means (relative variance up to about 0.4) meets */
    {"relerr, target error",
     {CK_BASE, .adaptive = SCHED_ADAPTIVE_RELERR, .uniform_layers = 6, .target_error = 0.5}},
    {"uniform, target error stops the job",
     {CK_BASE, .adaptive = SCHED_ADAPTIVE_NONE, .uniform_layers = 3, .target_error = 0.5,
      .confidence = 0.9, .target_share = 0.5}},
    {"thesis, random selection, dilation",
     {CK_BASE, .adaptive = SCHED_ADAPTIVE_THESIS, .uniform_layers = 3, .random_selection = 1,
      .dilate = 1, .seed = 1234}},
    {"variance, flag sequence",
     {CK_BASE, .adaptive = SCHED_ADAPTIVE_VARIANCE, .uniform_layers = UINT32_MAX,
      .flags = "001101011011"}},
    /* uniform layers between adaptive ones: relmse's statistics grow */
    {"relmse, flag sequence",
     {CK_BASE, .adaptive = SCHED_ADAPTIVE_RELMSE, .uniform_layers = UINT32_MAX,
      .flags = "000101101101"}},
    /* a checkpoint of version 7: the replicates' sums */
    {"relmse, 3 replicates",
     {CK_BASE, .adaptive = SCHED_ADAPTIVE_RELMSE, .uniform_layers = 3, .replicates = 3}},
    /* version 8: and the calibrated statistics the target reads (layers
     * enough for them: SCHED_TARGET_CALIBRATED_LAYERS) */
    {"relmse, 2 replicates, target error",
     {CK_CALIBRATED, .adaptive = SCHED_ADAPTIVE_RELMSE, .uniform_layers = 6}},
};

/* THE property of checkpoints: a job saved after any event (tasks out,
 * tasks requeued, mid-layer), restored, and run to the end gives the film,
 * layers and counters of the same job run without interruption. Every
 * event is a save point here; each restored job finishes in another order
 * with other workers, and is itself restored once more on the way. */
START_TEST(test_checkpoint_resumes_bit_identical)
{
    const ckpt_case_t *k = &ckpt_cases[_i];
    char err[256];
    sim_t ref = {.workers = 1, .seed = 1};
    ref.s = sched_new(&k->cfg, err, sizeof err);
    ck_assert_msg(ref.s != NULL, "%s", err);
    while (sim_step(&ref))
        ;
    if (k->cfg.adaptive != SCHED_ADAPTIVE_NONE || k->cfg.target_error > 0)
        ck_assert_msg(sched_pixel_layers_skipped(ref.s) > 0, "%s: nothing skipped", k->name);
    else
        ck_assert_uint_eq(sched_pixel_layers_skipped(ref.s), 0);
    if (k->cfg.target_error > 0)
        ck_assert_msg(sched_converged(ref.s) > 0, "%s: nothing converged", k->name);
    if (k->cfg.target_share == 0.5)
        ck_assert_msg(sched_stopped_on_target(ref.s), "%s: did not stop on the target", k->name);

    sim_t a = {.workers = 6, .seed = 2};
    a.s = sched_new(&k->cfg, err, sizeof err);
    ck_assert_msg(a.s != NULL, "%s", err);
    int with_out = 0;
    for (uint64_t at = 0;; at++) {
        with_out += a.n > 0;
        membuf_t buf = save_mem(a.s);
        sim_t b = {.workers = 1 + (int)(at % 5), .seed = 1000 + at};
        b.s = load_mem(&k->cfg, &buf, buf.len, err, sizeof err);
        ck_assert_msg(b.s != NULL, "%s, step %llu: %s", k->name, (unsigned long long)at, err);
        free(buf.data);
        for (uint64_t j = 0; sim_step(&b); j++)
            if (j == 3)
                sim_restore(&b, &k->cfg);
        assert_same_job(ref.s, b.s, k->name, at);
        sched_destroy(&b.s);
        if (!sim_step(&a))
            break;
    }
    ck_assert_msg(with_out > 10, "%s: few save points with tasks out", k->name);
    assert_same_job(ref.s, a.s, k->name, 0);
    sched_destroy(&a.s);
    sched_destroy(&ref.s);
}
END_TEST

/* The bytes of a section of a saved stream (the framing in sched.h). */
static uint8_t *find_section(const membuf_t *b, const char *tag, size_t *len)
{
    uint32_t count;
    memcpy(&count, b->data + 12, sizeof count);
    size_t off = 16 + 8 * (size_t)count;
    while (off + 16 <= b->len) {
        char t[9] = {0};
        uint64_t n;
        memcpy(t, b->data + off, 8);
        memcpy(&n, b->data + off + 8, sizeof n);
        if (strcmp(t, tag) == 0) {
            *len = (size_t)n;
            return b->data + off + 16;
        }
        off += 16 + (size_t)n;
    }
    ck_abort_msg("no section %s", tag);
    return NULL;
}

/* A job without replicates saves version 6, as before them (an older
 * master reads it); one with them version 7, with their sums. Each loads
 * only into a config with the same replicates, refused otherwise with a
 * message that says so. */
START_TEST(test_checkpoint_replicates_versions)
{
    for (uint32_t reps = 1; reps <= 2; reps++) {
        sched_config_t c = {CK_BASE, .adaptive = SCHED_ADAPTIVE_NONE, .uniform_layers = 3,
                            .replicates = reps};
        char err[256] = "";
        sim_t a = {.workers = 2, .seed = 5};
        a.s = sched_new(&c, err, sizeof err);
        ck_assert_msg(a.s != NULL, "%s", err);
        for (int i = 0; i < 40; i++)
            sim_step(&a);
        membuf_t buf = save_mem(a.s);
        uint32_t version;
        memcpy(&version, buf.data + 8, sizeof version);
        ck_assert_uint_eq(version, reps > 1 ? SCHED_SAVE_VERSION_REPLICATES : SCHED_SAVE_VERSION);
        size_t len;
        if (reps > 1)
            ck_assert(find_section(&buf, "rep", &len) != NULL && len == 11 * 9 * sizeof(double));
        sched_t *b = load_mem(&c, &buf, buf.len, err, sizeof err);
        ck_assert_msg(b != NULL, "%s", err);
        sched_destroy(&b);
        c.replicates = reps > 1 ? 1 : 2;
        b = load_mem(&c, &buf, buf.len, err, sizeof err);
        ck_assert(b == NULL);
        ck_assert_msg(strstr(err, "replicates") != NULL, "%s", err);
        free(buf.data);
        sched_destroy(&a.s);
    }
}
END_TEST

/* A job with replicates and a target error saves version 8, with each
 * pixel's calibrated statistic ("crv"), which an older master refuses by
 * its version. This master still resumes such a job from an older
 * master's version 7 (the stream without "crv"): its pixels past their
 * first layers keep the layer means' spread, the others are calibrated
 * when they get there, and the job runs to its end. A version past this
 * build's is refused, naming it. */
static void expect_load_refused(const sched_config_t *c, membuf_t *m, const char *what,
                                const char *want);
START_TEST(test_checkpoint_calibrated_version)
{
    sched_config_t c = {CK_CALIBRATED, .adaptive = SCHED_ADAPTIVE_NONE, .uniform_layers = 3};
    char err[256] = "";
    sim_t a = {.workers = 2, .seed = 5};
    a.s = sched_new(&c, err, sizeof err);
    ck_assert_msg(a.s != NULL, "%s", err);
    /* past the first SCHED_TARGET_CALIBRATED_LAYERS layers of most pixels
     * (a step hands a task back one time in 7) */
    const uint32_t ranges = (11 * 9 + 6) / 7;
    for (uint32_t i = 0; i < ranges * (SCHED_TARGET_CALIBRATED_LAYERS + 5) && sim_step(&a); i++)
        ;
    membuf_t buf = save_mem(a.s);
    uint32_t version;
    memcpy(&version, buf.data + 8, sizeof version);
    ck_assert_uint_eq(version, SCHED_SAVE_VERSION_CALIBRATED);
    size_t len;
    const uint8_t *crv = find_section(&buf, "crv", &len);
    ck_assert_uint_eq(len, 11 * 9 * sizeof(double));
    /* each pixel's frozen, or -1 before */
    uint32_t frozen = 0;
    for (size_t p = 0; p < 11 * 9; p++) {
        double v;
        memcpy(&v, crv + p * sizeof v, sizeof v);
        ck_assert_msg(v >= 0 || v == -1, "pixel %zu's crv %g", p, v);
        frozen += v >= 0;
    }
    ck_assert_msg(frozen > 11 * 9 / 2, "%u of 99 pixels' crv frozen", frozen);
    /* the same stream as an older master wrote it: version 7, no "crv" */
    membuf_t old = copy_of(&buf);
    const size_t at = (size_t)(crv - buf.data) - 16, cut = 16 + len;
    memmove(old.data + at, old.data + at + cut, old.len - at - cut);
    old.len -= cut;
    const uint32_t v7 = SCHED_SAVE_VERSION_REPLICATES;
    memcpy(old.data + 8, &v7, sizeof v7);
    fuzz_fix_sched_checksum(old.data, old.len);
    sim_t b = {.workers = 3, .seed = 9};
    b.s = load_mem(&c, &old, old.len, err, sizeof err);
    ck_assert_msg(b.s != NULL, "version 7: %s", err);
    while (sim_step(&b))
        ;
    ck_assert(sched_done(b.s));
    sched_destroy(&b.s);
    free(old.data);
    /* a newer master's */
    membuf_t v9 = copy_of(&buf);
    const uint32_t nine = SCHED_SAVE_VERSION_CALIBRATED + 1;
    memcpy(v9.data + 8, &nine, sizeof nine);
    expect_load_refused(&c, &v9, "version 9", "format version 9");
    /* nor does a job without a target error take it */
    c.target_error = 0;
    membuf_t other = copy_of(&buf);
    expect_load_refused(&c, &other, "no target", "replicates and a target error");
    free(buf.data);
    sched_destroy(&a.s);
}
END_TEST

/* Loads a copy of b changed by one byte at off (to v); must fail naming `want`. */
static void expect_refused(const sched_config_t *c, const membuf_t *b, size_t off, uint8_t v,
                           const char *want)
{
    char err[256] = "";
    membuf_t m = copy_of(b);
    m.data[off] = v;
    sched_t *s = load_mem(c, &m, m.len, err, sizeof err);
    ck_assert_msg(s == NULL, "byte %zu set to %u was accepted (want: %s)", off, v, want);
    ck_assert_msg(strstr(err, want) != NULL, "byte %zu: \"%s\" does not name %s", off, err, want);
    free(m.data);
}

static int failing_write(void *ctx, const void *data, size_t len)
{
    (void)data;
    size_t *left = ctx;
    if (len > *left)
        return 7;
    *left -= len;
    return 0;
}

/* Whatever is wrong with a stream, sched_load refuses it with a message
 * naming the problem, and sched_save passes a writer's error on. */
START_TEST(test_checkpoint_refuses_garbage)
{
    char err[256];
    sched_config_t c = ckpt_cases[4].cfg; /* relerr with a target: every section in use */
    sim_t a = {.workers = 5, .seed = 3};
    a.s = sched_new(&c, err, sizeof err);
    for (int i = 0; i < 60; i++)
        ck_assert(sim_step(&a));
    ck_assert_int_gt(a.n, 0);
    membuf_t b = save_mem(a.s);
    ck_assert_uint_eq(b.len, sched_save_bytes(a.s));
    sched_t *s = load_mem(&c, &b, b.len, err, sizeof err);
    ck_assert_msg(s != NULL, "%s", err);
    sched_destroy(&s);

    /* truncated anywhere */
    const size_t cuts[] = {0, 4, 8, 12, 16, 40, 200, b.len / 2, b.len - 9, b.len - 8, b.len - 1};
    for (size_t i = 0; i < sizeof cuts / sizeof cuts[0]; i++) {
        ck_assert(load_mem(&c, &b, cuts[i], err, sizeof err) == NULL);
        ck_assert_msg(strstr(err, "truncated") != NULL, "cut at %zu: %s", cuts[i], err);
    }
    /* header: magic, format version, then every byte of the fingerprint */
    expect_refused(&c, &b, 0, 'X', "magic");
    expect_refused(&c, &b, 8, SCHED_SAVE_VERSION + 1, "version");
    uint32_t fields;
    memcpy(&fields, b.data + 12, sizeof fields);
    for (size_t off = 16; off < 16 + 8 * (size_t)fields; off++) {
        expect_refused(&c, &b, off, b.data[off] ^ 0x01, "config");
        expect_refused(&c, &b, off, b.data[off] ^ 0x80, "config");
    }
    /* another job's config */
    sched_config_t other = c;
    other.spp = 52;
    ck_assert(load_mem(&other, &b, b.len, err, sizeof err) == NULL);
    ck_assert_msg(strstr(err, "config") && strstr(err, "spp"), "%s", err);
    other = c;
    other.seed = 99;
    ck_assert(load_mem(&other, &b, b.len, err, sizeof err) == NULL);
    ck_assert_msg(strstr(err, "config") && strstr(err, "seed"), "%s", err);
    other = c;
    other.adaptive = SCHED_ADAPTIVE_THESIS;
    ck_assert(load_mem(&other, &b, b.len, err, sizeof err) == NULL);
    ck_assert_msg(strstr(err, "config") && strstr(err, "adaptive"), "%s", err);

    /* cell states: out of range, outstanding (never saved), done too early */
    size_t n;
    uint8_t *st = find_section(&b, "state", &n);
    size_t off = (size_t)(st - b.data);
    expect_refused(&c, &b, off, 7, "state");
    size_t waiting = 0; /* a cell whose previous layer's cell is not done yet */
    while (waiting < n && st[waiting] != 0)
        waiting++;
    ck_assert_uint_lt(waiting, n);
    expect_refused(&c, &b, off + waiting, 2, "state"); /* outstanding: never saved */
    expect_refused(&c, &b, off + waiting, 3, "state"); /* done before its turn */
    /* more layers decided than the two past the complete ones */
    uint8_t *dec = find_section(&b, "counters", &n); /* the eighth counter: decided */
    expect_refused(&c, &b, (size_t)(dec - b.data) + 7 * sizeof(uint64_t), dec[56] + 1, "decided");
    /* a film sum that is not finite: NaN, then +inf (top bytes of a double) */
    uint8_t *film = find_section(&b, "film", &n);
    size_t sum1 =
        (size_t)(film - b.data) + 5 * sizeof(film_pixel_t) + offsetof(film_pixel_t, sum) + 8;
    double nan = NAN, inf = INFINITY;
    membuf_t m = {malloc(b.len), b.len, b.len, 0};
    memcpy(m.data, b.data, b.len);
    memcpy(m.data + sum1, &nan, sizeof nan);
    ck_assert(load_mem(&c, &m, m.len, err, sizeof err) == NULL);
    ck_assert_msg(strstr(err, "film") && strstr(err, "finite"), "%s", err);
    memcpy(m.data + sum1, &inf, sizeof inf);
    ck_assert(load_mem(&c, &m, m.len, err, sizeof err) == NULL);
    ck_assert_msg(strstr(err, "finite"), "%s", err);
    /* a finite film value off by one ulp: only the checksum sees it */
    double v;
    memcpy(m.data, b.data, b.len);
    memcpy(&v, m.data + sum1, sizeof v);
    v = nextafter(v, 1e300);
    memcpy(m.data + sum1, &v, sizeof v);
    ck_assert(load_mem(&c, &m, m.len, err, sizeof err) == NULL);
    ck_assert_msg(strstr(err, "checksum"), "%s", err);
    /* counters that do not add up */
    memcpy(m.data, b.data, b.len);
    uint8_t *ct = find_section(&m, "counters", &n); /* the fourth counter is samples_done */
    uint64_t samples;
    memcpy(&samples, ct + 3 * sizeof samples, sizeof samples);
    samples++;
    memcpy(ct + 3 * sizeof samples, &samples, sizeof samples);
    ck_assert(load_mem(&c, &m, m.len, err, sizeof err) == NULL);
    ck_assert_msg(strstr(err, "samples_done"), "%s", err);
    free(m.data);

    /* a writer's error comes back, wherever it happens */
    for (size_t left = 0; left < b.len; left += b.len / 7) {
        size_t l = left;
        ck_assert_int_eq(sched_save(a.s, failing_write, &l), 7);
    }
    free(b.data);
    sched_destroy(&a.s);
}
END_TEST

/* A job of config c saved after 60 events of the simulated workers (and
 * shown to load as it is). */
static membuf_t saved_midway(const sched_config_t *c)
{
    char err[256];
    sim_t a = {.workers = 5, .seed = 3};
    a.s = sched_new(c, err, sizeof err);
    for (int i = 0; i < 60; i++)
        ck_assert(sim_step(&a));
    membuf_t b = save_mem(a.s);
    sched_destroy(&a.s);
    sched_t *s = load_mem(c, &b, b.len, err, sizeof err);
    ck_assert_msg(s != NULL, "%s", err);
    sched_destroy(&s);
    return b;
}

/* m, an edited copy of a saved job, with the stream's checksum made right
 * again so that only the checks can refuse it: the load refuses it, with a
 * message naming want. Frees m. */
static void expect_load_refused(const sched_config_t *c, membuf_t *m, const char *what,
                                const char *want)
{
    char err[256] = "";
    fuzz_fix_sched_checksum(m->data, m->len);
    sched_t *s = load_mem(c, m, m->len, err, sizeof err);
    ck_assert_msg(s == NULL, "%s was accepted", what);
    ck_assert_msg(strstr(err, want) != NULL, "%s", err);
    free(m->data);
}

/* Found by tests/fuzz_ckpt.c: streams whose batch statistics no run can
 * make loaded, checksum and all: a negative M2 (the sum of squared
 * deviations of a pixel's layer means), a mean of -8e306, a mean of 5e6
 * with no batch yet. The resumed job's relerr metric for that pixel was
 * then NaN (the square root of a negative M2, or of one that Welford's
 * update drove negative), or its M2 overflowed on the next merge, and
 * every later checkpoint was refused for it. Such values are refused. */
static void expect_batch_refused(const sched_config_t *c, const membuf_t *b, const char *tag,
                                 double v)
{
    char what[128];
    membuf_t m = copy_of(b);
    size_t n, p = 0;
    double x;
    /* the uniform layers' statistics (relerr, relmse) or all layers' */
    uint8_t *bm2 = find_section(&m, "um2", &n), *sec = find_section(&m, tag, &n);
    while (p < n / sizeof x && (memcpy(&x, bm2 + p * sizeof x, sizeof x), x <= 0))
        p++; /* a pixel with two batches or more */
    ck_assert_msg(p < n / sizeof x, "no pixel with a batch M2 yet");
    if (strcmp(tag, "batches") == 0 || strcmp(tag, "ubat") == 0 || strcmp(tag, "pnb") == 0) {
        uint32_t k = (uint32_t)v;
        memcpy(sec + p * sizeof k, &k, sizeof k);
    } else {
        memcpy(sec + p * sizeof v, &v, sizeof v);
    }
    snprintf(what, sizeof what, "%s %g at pixel %zu", tag, v, p);
    expect_load_refused(c, &m, what, "batch");
}

START_TEST(test_checkpoint_refuses_impossible_batches)
{
    sched_config_t c = ckpt_cases[4].cfg; /* relerr with a target */
    membuf_t b = saved_midway(&c);
    expect_batch_refused(&c, &b, "batches", 0);    /* a mean and an M2, but no batch */
    expect_batch_refused(&c, &b, "batches", 1);    /* an M2 from one batch */
    expect_batch_refused(&c, &b, "batches", 1000); /* more batches than layers */
    expect_batch_refused(&c, &b, "pnb", 1000);     /* more before the last than after */
    expect_batch_refused(&c, &b, "um2", -0.25);
    expect_batch_refused(&c, &b, "umean", -8.13636e306);
    expect_batch_refused(&c, &b, "umean", 1e300);
    expect_batch_refused(&c, &b, "ubat", 1);
    expect_batch_refused(&c, &b, "ubat", 1000); /* more uniform layers than layers */
    free(b.data);
}
END_TEST

/* relmse's cost sections of a saved job, one value at a pixel that has
 * uniform-layer samples changed: the load refuses it, naming the rays. */
static void expect_cost_refused(const sched_config_t *c, const membuf_t *b, const char *tag,
                                double v)
{
    membuf_t m = copy_of(b);
    size_t n, p = 0;
    uint32_t taken = 0;
    for (const uint8_t *usamp = find_section(&m, "usamp", &n); taken == 0; p++)
        memcpy(&taken, usamp + p * sizeof taken, sizeof taken);
    p--; /* the first pixel with uniform-layer samples */
    uint8_t *sec = find_section(&m, tag, &n);
    if (strcmp(tag, "pcost") == 0) {
        float f = (float)v;
        memcpy(sec + p * sizeof f, &f, sizeof f);
    } else if (strcmp(tag, "usamp") == 0) {
        uint32_t k = (uint32_t)v;
        memcpy(sec + p * sizeof k, &k, sizeof k);
    } else {
        uint64_t k = v < 0 ? taken - 1 : (uint64_t)v; /* -1: one ray short of the samples */
        memcpy(sec + p * sizeof k, &k, sizeof k);
    }
    char what[128];
    snprintf(what, sizeof what, "%s %g at pixel %zu", tag, v, p);
    expect_load_refused(c, &m, what, "rays");
}

START_TEST(test_checkpoint_refuses_impossible_costs)
{
    sched_config_t c = ckpt_cases[8].cfg; /* relmse */
    ck_assert_int_eq(c.adaptive, SCHED_ADAPTIVE_RELMSE);
    membuf_t b = saved_midway(&c);
    expect_cost_refused(&c, &b, "urays", -1);  /* fewer rays than samples */
    expect_cost_refused(&c, &b, "urays", 0);   /* samples but no rays */
    expect_cost_refused(&c, &b, "usamp", 1e6); /* more samples than merged */
    expect_cost_refused(&c, &b, "pcost", 0.5); /* under a ray a sample */
    expect_cost_refused(&c, &b, "pcost", NAN);
    free(b.data);
}
END_TEST

int main(void)
{
    Suite *s = suite_create("sched");
    TCase *tc = tcase_create("procedure2");
    tcase_add_test(tc, test_procedure2_by_hand);
    tcase_add_test(tc, test_dependencies_and_priors);
    tcase_add_test(tc, test_earlier_layer_first);
    tcase_add_test(tc, test_order_does_not_matter);
    tcase_add_test(tc, test_take_replays_a_journal);
    tcase_add_test(tc, test_flag_sequence);
    tcase_add_test(tc, test_target_error_stops);
    tcase_add_test(tc, test_replicates);
    tcase_add_test(tc, test_target_window_excludes_self);
    tcase_add_test(tc, test_target_calibrated_by_replicates);
    tcase_add_test(tc, test_target_with_adaptive_rule_converges_all);
    tcase_add_test(tc, test_target_decides_alone);
    tcase_add_test(tc, test_relerr_and_variance_modes);
    tcase_add_test(tc, test_relmse_balances_sqrt_variance);
    tcase_add_test(tc, test_relmse_weighs_cost);
    tcase_add_test(tc, test_alike_pixels_stay_uniform);
    tcase_add_test(tc, test_first_sample_counts_taken_layers);
    tcase_add_test(tc, test_adaptive_unbiased);
    tcase_add_test(tc, test_target_unbiased);
    tcase_add_test(tc, test_dilation);
    tcase_add_test(tc, test_random_selection);
    tcase_add_test(tc, test_bad_configs);
    tcase_add_test(tc, test_default_uniform_layers);
    tcase_add_test(tc, test_results_range_checked);
    tcase_add_test(tc, test_outstanding_and_check);
    tcase_add_test(tc, test_many_layers_new_is_cheap);
    tcase_add_test(tc, test_production_resolution_fits);
    tcase_add_loop_test(tc, test_checkpoint_resumes_bit_identical, 0,
                        (int)(sizeof ckpt_cases / sizeof ckpt_cases[0]));
    tcase_add_test(tc, test_checkpoint_refuses_garbage);
    tcase_add_test(tc, test_checkpoint_replicates_versions);
    tcase_add_test(tc, test_checkpoint_calibrated_version);
    tcase_add_test(tc, test_checkpoint_refuses_impossible_batches);
    tcase_add_test(tc, test_checkpoint_refuses_impossible_costs);
    suite_add_tcase(s, tc);
    SRunner *sr = srunner_create(s);
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed ? 1 : 0;
}
