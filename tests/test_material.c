/* test_material.c - Check suite for the BSDF sampling in common/material.h:
 * each material's material_sample (directions, weights, pdfs, and how many
 * random numbers it draws, which fixes every later draw of a path) and
 * material_eval. */
#include <check.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#include "material.h"

/* A surface facing +z seen from straight above or at an angle. */
static material_hit_t hit_from(vec3_t wo, int front)
{
    material_hit_t h = {.wo = vec3_normalize(wo), .front = front};
    h.ngf = h.ns = vec3_make(0, 0, 1);
    return h;
}

static material_t make(material_type_t type)
{
    material_t m = {.type = type, .albedo = vec3_make(0.5f, 0.25f, 1.0f), .ior = 1.5f};
    return m;
}

START_TEST(diffuse_is_cosine_weighted)
{
    material_t m = make(MATERIAL_DIFFUSE);
    material_hit_t h = hit_from(vec3_make(0.3f, 0, 1), 1);
    double mean_cos = 0;
    const int n = 4096;
    for (int i = 0; i < n; i++) {
        rng_stream_t rng = rng_stream(1, 2, (uint64_t)i);
        material_sample_t bs;
        if (!material_sample(&m, &h, &rng, &bs))
            continue;
        ck_assert_uint_eq(rng.dim, 2);
        ck_assert_int_eq(bs.specular, 0);
        ck_assert_int_eq(bs.transmits, 0);
        ck_assert(bs.weight.x == m.albedo.x && bs.weight.y == m.albedo.y);
        float c = vec3_dot(h.ns, bs.wi);
        ck_assert_float_gt(c, 0.0f);
        ck_assert_float_eq_tol(bs.pdf, c * VMATH_INV_PI, 1e-7f);
        /* the light-sample side agrees with the sampling side */
        float cos_s, pdf;
        ck_assert_int_eq(material_eval(&m, &h, bs.wi, &cos_s, &pdf), 1);
        ck_assert(cos_s == c && pdf == bs.pdf);
        mean_cos += c;
    }
    /* E[cos] under a cos/pi density is 2/3 */
    ck_assert_double_eq_tol(mean_cos / n, 2.0 / 3.0, 0.02);
}
END_TEST

/* The sines and cosines of 2 pi u the samplers take (vmath_sincos_turn, a
 * polynomial, not libm's): within 1.2e-7 of the true values for every
 * 2^-20 step of u in [-1/8, 1 + 1/64], including each quarter turn's ends
 * and u just below 1 (the GGX disk's angles start at -1/8, an environment
 * map's sample reaches half a pixel past 1), and on the unit circle to
 * 3e-7. */
START_TEST(sincos_turn_accurate)
{
    double worst = 0;
    for (int32_t i = -(1 << 17); i <= (1 << 20) + (1 << 14); i++) {
        float u = i == (1 << 20) ? 0x1.fffffep-1f : (float)i * 0x1p-20f;
        float sn, cs;
        vmath_sincos_turn(u, &sn, &cs);
        double a = 2 * M_PI * (double)u;
        double e = fmax(fabs(sn - sin(a)), fabs(cs - cos(a)));
        worst = fmax(worst, e);
        /* checked, not asserted, a million times: each ck_assert marks its
         * point through a pipe, which took the case past Check's timeout on
         * a busy host */
        if (!(e < 1.2e-7))
            ck_abort_msg("u %a: sin %.9g cos %.9g, want %.9g %.9g", (double)u, sn, cs, sin(a),
                         cos(a));
        if (!(fabs((double)sn * sn + (double)cs * cs - 1) < 3e-7))
            ck_abort_msg("u %a: sin^2 + cos^2 = %.9g", (double)u,
                         (double)sn * sn + (double)cs * cs);
    }
    ck_assert(worst > 1e-9); /* (a polynomial, not the exact values) */
}
END_TEST

START_TEST(diffuse_eval_below_is_zero)
{
    material_t m = make(MATERIAL_EMITTER);
    material_hit_t h = hit_from(vec3_make(0, 0, 1), 1);
    float cos_s = -1, pdf = -1;
    ck_assert_int_eq(material_eval(&m, &h, vec3_make(0, 1, -0.1f), &cos_s, &pdf), 0);
    ck_assert_int_eq(material_eval(&m, &h, vec3_make(0, 1, 0.1f), &cos_s, &pdf), 1);
}
END_TEST

START_TEST(mirror_reflects_and_draws_nothing)
{
    material_t m = make(MATERIAL_MIRROR);
    material_hit_t h = hit_from(vec3_make(1, 0, 1), 1);
    rng_stream_t rng = rng_stream(1, 2, 3);
    material_sample_t bs;
    ck_assert_int_eq(material_sample(&m, &h, &rng, &bs), 1);
    ck_assert_uint_eq(rng.dim, 0);
    ck_assert_int_eq(bs.specular, 1);
    ck_assert_float_eq_tol(bs.wi.x, -h.wo.x, 1e-6f);
    ck_assert_float_eq_tol(bs.wi.z, h.wo.z, 1e-6f);
    ck_assert(bs.weight.z == m.albedo.z);
    float cos_s, pdf;
    ck_assert_int_eq(material_eval(&m, &h, bs.wi, &cos_s, &pdf), 0);
}
END_TEST

START_TEST(dielectric_splits_by_fresnel)
{
    material_t m = make(MATERIAL_DIELECTRIC);
    material_hit_t h = hit_from(vec3_make(0, 0, 1), 1);
    int reflected = 0, transmitted = 0;
    const int n = 20000;
    for (int i = 0; i < n; i++) {
        rng_stream_t rng = rng_stream(5, 0, (uint64_t)i);
        material_sample_t bs;
        ck_assert_int_eq(material_sample(&m, &h, &rng, &bs), 1);
        ck_assert_uint_eq(rng.dim, 1);
        ck_assert_int_eq(bs.specular, 1);
        if (bs.transmits) {
            transmitted++;
            /* straight through, radiance scaled by 1/eta^2 */
            ck_assert_float_lt(bs.wi.z, 0.0f);
            ck_assert_float_eq_tol(bs.weight.x, 1.0f / (1.5f * 1.5f), 1e-7f);
            ck_assert(bs.eta == 1.5f);
        } else {
            reflected++;
            ck_assert(bs.weight.x == 1.0f && bs.weight.y == 1.0f && bs.weight.z == 1.0f);
        }
    }
    /* normal incidence on n = 1.5: F = ((1.5 - 1) / (1.5 + 1))^2 = 0.04 */
    ck_assert_double_eq_tol((double)reflected / n, 0.04, 0.005);
    ck_assert_int_eq(reflected + transmitted, n);
}
END_TEST

/* Entering and leaving glass at normal incidence: the compression on the
 * way in and the expansion on the way out cancel, and each transmission
 * reports the eta whose square undoes its own weight (the tracer's roulette
 * relies on that). */
START_TEST(dielectric_entry_and_exit_cancel)
{
    material_t m = make(MATERIAL_DIELECTRIC);
    float w[2] = {0, 0};
    for (int front = 1; front >= 0; front--) {
        material_hit_t h = hit_from(vec3_make(0, 0, 1), front);
        for (uint64_t i = 0; i < 100 && w[front] == 0; i++) {
            rng_stream_t rng = rng_stream(3, 4, i);
            material_sample_t bs;
            ck_assert_int_eq(material_sample(&m, &h, &rng, &bs), 1);
            if (!bs.transmits)
                continue;
            ck_assert(bs.eta == (front ? 1.5f : 1.0f / 1.5f));
            ck_assert_float_eq_tol(bs.weight.x * bs.eta * bs.eta, 1.0f, 1e-6f);
            w[front] = bs.weight.x;
        }
        ck_assert_float_gt(w[front], 0.0f);
    }
    ck_assert_float_eq_tol(w[0] * w[1], 1.0f, 1e-6f);
}
END_TEST

START_TEST(dielectric_total_internal_reflection)
{
    material_t m = make(MATERIAL_DIELECTRIC);
    /* from inside (front = 0, eta = 1/1.5) at 60 degrees: beyond the
     * critical angle of 41.8 degrees, so always reflected */
    material_hit_t h = hit_from(vec3_make(sinf(1.0472f), 0, cosf(1.0472f)), 0);
    for (uint64_t i = 0; i < 100; i++) {
        rng_stream_t rng = rng_stream(9, 9, i);
        material_sample_t bs;
        ck_assert_int_eq(material_sample(&m, &h, &rng, &bs), 1);
        ck_assert_int_eq(bs.transmits, 0);
        ck_assert_float_gt(bs.wi.z, 0.0f);
    }
}
END_TEST

static Suite *material_suite(void)
{
    Suite *su = suite_create("material");
    TCase *tc = tcase_create("sampling");
    tcase_add_test(tc, diffuse_is_cosine_weighted);
    tcase_add_test(tc, diffuse_eval_below_is_zero);
    tcase_add_test(tc, sincos_turn_accurate);
    tcase_add_test(tc, mirror_reflects_and_draws_nothing);
    tcase_add_test(tc, dielectric_splits_by_fresnel);
    tcase_add_test(tc, dielectric_total_internal_reflection);
    tcase_add_test(tc, dielectric_entry_and_exit_cancel);
    suite_add_tcase(su, tc);
    return su;
}

int main(void)
{
    SRunner *sr = srunner_create(material_suite());
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed == 0 ? EXIT_SUCCESS : EXIT_FAILURE;
}
