/* test_lights.c - Check suite for common/lights.{h,c}: the power
 * distribution lights_build makes from per-triangle power, picking by it,
 * points on a light, and the two ways building fails. Scenes are built by
 * hand (no loader) so each case states its powers. */
#include <check.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "lights.h"

#define ERRLEN 256

/* n right triangles of area 1/2 in the z = 0 plane, triangle t shifted to
 * x = 2t; material 0 is diffuse, material 1 an emitter of luminance 1. */
static scene_t *flat_scene(size_t n)
{
    scene_t *s = calloc(1, sizeof *s);
    ck_assert_ptr_nonnull(s);
    s->materials = calloc(2, sizeof *s->materials);
    s->material_count = 2;
    s->materials[0].type = MATERIAL_DIFFUSE;
    s->materials[1].type = MATERIAL_EMITTER;
    s->materials[1].radiance = vec3_make(1, 1, 1);
    s->positions = calloc(9 * n, sizeof(float));
    s->indices = calloc(3 * n, sizeof(uint32_t));
    s->tri_material = calloc(n, sizeof(uint32_t));
    s->tri_light_pdf = calloc(n, sizeof(float));
    for (size_t t = 0; t < n; t++) {
        float *p = s->positions + 9 * t;
        p[0] = (float)(2 * t);
        p[3] = (float)(2 * t) + 1.0f;
        p[6] = (float)(2 * t);
        p[7] = 1.0f;
        for (uint32_t k = 0; k < 3; k++)
            s->indices[3 * t + k] = (uint32_t)(3 * t + k);
    }
    s->vertex_count = 3 * n;
    s->triangle_count = n;
    return s;
}

/* flat_scene(4) with triangles 1 and 3 lights of power 1 and 3, built. */
static scene_t *two_lights(void)
{
    scene_t *s = flat_scene(4);
    s->tri_material[1] = s->tri_material[3] = 1;
    double power[4] = {0, 1.0, 0, 3.0};
    char err[ERRLEN];
    ck_assert_int_eq(lights_build(s, power, 4.0, NULL, err, sizeof err), LIGHTS_OK);
    return s;
}

START_TEST(distribution_follows_power)
{
    scene_t *s = two_lights();
    ck_assert_uint_eq(s->light_count, 2);
    ck_assert_uint_eq(s->light_tris[0], 1);
    ck_assert_uint_eq(s->light_tris[1], 3);
    ck_assert_double_eq_tol(s->light_cdf[0], 0.25, 1e-15);
    ck_assert_double_eq(s->light_cdf[1], 1.0);
    /* area pdf = luminance / total power, 0 off the lights */
    ck_assert_float_eq(lights_area_pdf(s, 0), 0.0f);
    ck_assert_float_eq_tol(lights_area_pdf(s, 1), 0.25f, 1e-7f);
    ck_assert_float_eq_tol(lights_area_pdf(s, 3), 0.25f, 1e-7f);
    /* picking: u below the first cdf entry is light 0, at or above it light 1 */
    ck_assert_uint_eq(lights_pick_index(s, 0.0), 0);
    ck_assert_uint_eq(lights_pick_index(s, 0.2499), 0);
    ck_assert_uint_eq(lights_pick_index(s, 0.25), 1);
    ck_assert_uint_eq(lights_pick_index(s, 0.9999999), 1);
    scene_destroy(&s);
}
END_TEST

/* With many lights the search starts from a guide (scene_t.light_guide):
 * the same index as the search of all for every u tried, powers spanning
 * six orders of magnitude: each cdf entry, its neighbours one ulp off,
 * each bucket's edges and their neighbours, and random numbers, as well
 * as 0, the largest double below 1, and u outside [0, 1). */
START_TEST(guided_pick_same_index)
{
    const size_t n = 5000;
    scene_t *s = flat_scene(n);
    double *power = calloc(n, sizeof *power);
    ck_assert_ptr_nonnull(power);
    uint64_t x = 12345;
    double total = 0;
    for (size_t t = 0; t < n; t++) {
        x = x * 6364136223846793005ULL + 1442695040888963407ULL;
        if (t % 7 == 3)
            continue; /* not a light */
        s->tri_material[t] = 1;
        power[t] = pow(10.0, (double)(x >> 11) * 0x1p-53 * 6.0 - 3.0);
        total += power[t];
    }
    char err[ERRLEN];
    ck_assert_int_eq(lights_build(s, power, total, NULL, err, sizeof err), LIGHTS_OK);
    ck_assert_ptr_nonnull(s->light_guide);
    const size_t m = s->light_count; /* the guide's buckets */
    size_t tried = 0;
    for (size_t k = 0; k < 4 * m + 4 * s->light_count + 20000; k++) {
        double u;
        if (k < 4 * m) { /* around bucket edges */
            double e = (double)(k / 4) / (double)m;
            u = k % 4 == 0   ? e
                : k % 4 == 1 ? nextafter(e, 0.0)
                : k % 4 == 2 ? nextafter(e, 1.0)
                             : e;
        } else if (k < 4 * m + 4 * s->light_count) { /* around cdf entries */
            size_t i = k - 4 * m;
            double c = s->light_cdf[i / 4];
            u = i % 4 == 0   ? c
                : i % 4 == 1 ? nextafter(c, 0.0)
                : i % 4 == 2 ? nextafter(c, 1.0)
                             : c;
        } else {
            x = x * 6364136223846793005ULL + 1442695040888963407ULL;
            u = (double)(x >> 11) * 0x1p-53;
        }
        ck_assert_uint_eq(lights_pick_index(s, u),
                          lights_cdf_search(s->light_cdf, s->light_count, u));
        tried++;
    }
    const double odd[] = {0.0, 0x1.fffffffffffffp-1, 1.0, -0.0, -1e-300, 2.0, NAN};
    for (size_t k = 0; k < sizeof odd / sizeof odd[0]; k++)
        ck_assert_uint_eq(lights_pick_index(s, odd[k]),
                          lights_cdf_search(s->light_cdf, s->light_count, odd[k]));
    ck_assert_uint_gt(tried, 40000);
    free(power);
    scene_destroy(&s);
}
END_TEST

/* With group_power, each emitting material is one emitter, picked alike,
 * a triangle by power within it (as Mitsuba picks its emitters): a dim
 * light of two triangles and a bright one of one get half the samples
 * each, and every area pdf times its area is the triangle's own share. */
START_TEST(distribution_by_emitter)
{
    scene_t *s = flat_scene(4);
    s->materials = realloc(s->materials, 3 * sizeof *s->materials);
    ck_assert_ptr_nonnull(s->materials);
    s->material_count = 3;
    s->materials[2] = s->materials[1];
    s->materials[2].radiance = vec3_make(10, 10, 10);
    s->tri_material[0] = s->tri_material[1] = 1;
    s->tri_material[3] = 2;
    /* area 0.5 each: power 0.5, 0.5 (material 1) and 5 (material 2) */
    double power[4] = {0.5, 0.5, 0, 5.0}, group[3] = {0, 1.0, 5.0};
    char err[ERRLEN];
    ck_assert_int_eq(lights_build(s, power, 2.0, group, err, sizeof err), LIGHTS_OK);
    ck_assert_uint_eq(s->light_count, 3);
    ck_assert_double_eq_tol(s->light_cdf[0], 0.25, 1e-15);
    ck_assert_double_eq_tol(s->light_cdf[1], 0.5, 1e-15);
    ck_assert_double_eq(s->light_cdf[2], 1.0);
    const double share[4] = {0.25, 0.25, 0, 0.5};
    for (uint32_t t = 0; t < 4; t++)
        ck_assert_msg(fabs(lights_area_pdf(s, t) * 0.5 - share[t]) < 1e-7,
                      "triangle %u: pdf %g x area 0.5, want %g", t, lights_area_pdf(s, t),
                      share[t]);
    /* and by power, the bright one took 5/6 */
    scene_t *p = flat_scene(4);
    p->materials = realloc(p->materials, 3 * sizeof *p->materials);
    ck_assert_ptr_nonnull(p->materials);
    p->material_count = 3;
    p->materials[2] = s->materials[2];
    memcpy(p->tri_material, s->tri_material, 4 * sizeof *p->tri_material);
    ck_assert_int_eq(lights_build(p, power, 6.0, NULL, err, sizeof err), LIGHTS_OK);
    ck_assert_float_eq_tol(lights_area_pdf(p, 3) * 0.5f, 5.0f / 6.0f, 1e-6f);
    scene_destroy(&p);
    scene_destroy(&s);
}
END_TEST

START_TEST(points_lie_on_the_light)
{
    scene_t *s = flat_scene(3);
    s->tri_material[2] = 1;
    double power[3] = {0, 0, 0.5};
    char err[ERRLEN];
    ck_assert_int_eq(lights_build(s, power, 0.5, NULL, err, sizeof err), LIGHTS_OK);
    ck_assert_uint_eq(s->light_count, 1);
    double mean_x = 0, mean_y = 0;
    const int n = 64;
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++) {
            vec3_t q;
            uint32_t tri = lights_sample(s, (i + 0.5) / n, (j + 0.5f) / n, &q);
            ck_assert_uint_eq(tri, 2);
            /* inside the triangle (4,0,0), (5,0,0), (4,1,0) */
            ck_assert(q.z == 0.0f && q.x >= 4.0f && q.y >= 0.0f);
            ck_assert_float_le(q.x - 4.0f + q.y, 1.0f + 1e-6f);
            mean_x += q.x;
            mean_y += q.y;
        }
    /* uniform by area: the mean is the centroid (13/3, 1/3) */
    ck_assert_double_eq_tol(mean_x / (n * n), 13.0 / 3.0, 1e-3);
    ck_assert_double_eq_tol(mean_y / (n * n), 1.0 / 3.0, 1e-3);
    scene_destroy(&s);
}
END_TEST

/* lights_sample takes the light and the point's first number from one u:
 * a stratified grid of (u, u2) over two lights of power 1 and 3
 * gives each light its share of the points exactly, and on each light the
 * same point as scene_sample_point for the rescaled u, so the points of each
 * light form a stratified grid of their own (uniform by area: the mean is
 * the centroid, to the grid's 1e-3). */
START_TEST(reuse_stratifies_over_all_lights)
{
    scene_t *s = two_lights();
    const int n = 64;
    int count[4] = {0};
    double mean_x[4] = {0}, mean_y[4] = {0};
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++) {
            double u = (i + 0.5) / n;
            float u2 = (j + 0.5f) / n;
            vec3_t q;
            uint32_t tri = lights_sample(s, u, u2, &q);
            ck_assert(tri == 1 || tri == 3);
            double lo = tri == 1 ? 0.0 : 0.25, hi = tri == 1 ? 0.25 : 1.0;
            vec3_t want = scene_sample_point(s, tri, (float)((u - lo) / (hi - lo)), u2);
            ck_assert(q.x == want.x && q.y == want.y && q.z == want.z);
            count[tri]++;
            mean_x[tri] += q.x;
            mean_y[tri] += q.y;
        }
    ck_assert_int_eq(count[1], n * n / 4);
    ck_assert_int_eq(count[3], 3 * n * n / 4);
    /* light t is the triangle (2t,0,0), (2t+1,0,0), (2t,1,0): centroid (2t + 1/3, 1/3) */
    for (int t = 1; t <= 3; t += 2) {
        ck_assert_double_eq_tol(mean_x[t] / count[t], 2 * t + 1.0 / 3.0, 1e-3);
        ck_assert_double_eq_tol(mean_y[t] / count[t], 1.0 / 3.0, 1e-3);
    }
    /* the ends of [0, 1) stay on the lights, the rescaled number below 1 */
    vec3_t q;
    ck_assert_uint_eq(lights_sample(s, 0.0, 0.5f, &q), 1);
    ck_assert_uint_eq(lights_sample(s, 0x1.fffffffffffffp-1, 0.5f, &q), 3);
    ck_assert(q.x >= 6.0f && q.y >= 0.0f && q.x - 6.0f + q.y <= 1.0f + 1e-6f);
    scene_destroy(&s);
}
END_TEST

START_TEST(out_of_float_range)
{
    /* a light 1e-40 of the total has an area pdf below the smallest float */
    scene_t *s = flat_scene(2);
    s->tri_material[0] = s->tri_material[1] = 1;
    s->materials[1].radiance = vec3_make(1e-40f, 1e-40f, 1e-40f);
    double power[2] = {0.5e-40, 1e300};
    char err[ERRLEN] = "";
    ck_assert_int_eq(lights_build(s, power, 1e300, NULL, err, sizeof err), LIGHTS_OUT_OF_RANGE);
    ck_assert_ptr_nonnull(strstr(err, "single-precision"));
    scene_destroy(&s);
}
END_TEST

static Suite *lights_suite(void)
{
    Suite *su = suite_create("lights");
    TCase *tc = tcase_create("distribution");
    tcase_add_test(tc, distribution_follows_power);
    tcase_add_test(tc, distribution_by_emitter);
    tcase_add_test(tc, guided_pick_same_index);
    tcase_add_test(tc, points_lie_on_the_light);
    tcase_add_test(tc, reuse_stratifies_over_all_lights);
    tcase_add_test(tc, out_of_float_range);
    suite_add_tcase(su, tc);
    return su;
}

int main(void)
{
    SRunner *sr = srunner_create(lights_suite());
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed == 0 ? EXIT_SUCCESS : EXIT_FAILURE;
}
