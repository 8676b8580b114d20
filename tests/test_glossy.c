/* test_glossy.c - Check suite for the glossy materials of material.h
 * (conductor, plastic, thin dielectric) and the microfacet distributions
 * of microfacet.h under them.
 *
 * - chi-square: the directions material_glossy_sample draws against the
 *   density material_glossy_eval reports, binned over the hemisphere, as
 *   Mitsuba's test_chi2 does (bins whose expectation is small pooled, the
 *   directions it failed to draw or drew on a delta lobe as one more bin);
 * - the sample's pdf and weight are the eval's;
 * - reciprocity; a white furnace (no material returns more than it
 *   receives, at any angle, grazing included); the smooth limit (alpha
 *   1e-4 reflects what the smooth material does, with no NaN);
 * - the conductor presets, Fresnel and the plastic's tables against values
 *   worked out by hand or by Mitsuba. */
#include <check.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "material.h"

/* a surface facing +z, seen from wo */
static material_hit_t hit_from(vec3_t wo)
{
    material_hit_t h = {.wo = vec3_normalize(wo), .front = 1};
    h.ngf = h.ns = vec3_make(0, 0, 1);
    return h;
}

static material_t conductor(float alpha, microfacet_type_t d, const char *preset)
{
    material_t m = {.type = MATERIAL_CONDUCTOR,
                    .albedo = vec3_make(1, 1, 1),
                    .alpha = alpha,
                    .distribution = d,
                    .albedo_texture = -1};
    ck_assert(material_conductor_preset(preset, &m.eta, &m.k) >= 0);
    material_prepare(&m, 1.0f, NULL, 0);
    return m;
}

static material_t glass(float alpha, microfacet_type_t d, float ior)
{
    material_t m = {.type = MATERIAL_ROUGH_DIELECTRIC,
                    .alpha = alpha,
                    .distribution = d,
                    .ior = ior,
                    .albedo_texture = -1};
    return m;
}

static material_t plastic(float alpha, microfacet_type_t d, float albedo, float ior)
{
    material_t m = {.type = MATERIAL_PLASTIC,
                    .albedo = vec3_make(albedo, albedo, albedo),
                    .specular = vec3_make(1, 1, 1),
                    .alpha = alpha,
                    .distribution = d,
                    .ior = ior,
                    .albedo_texture = -1};
    material_prepare(&m, albedo, NULL, 0);
    return m;
}

/* the uniforms of sample i: a hash, independent between the three */
static float uniform(uint64_t i, int k)
{
    uint64_t z = i * 0x9e3779b97f4a7c15ULL + (uint64_t)(k + 1) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    z ^= z >> 31;
    return (float)(z >> 40) * 0x1.0p-24f;
}

/* ---- chi-square ---------------------------------------------------------------- */

enum { THETA_BINS = 30, PHI_BINS = 60, SUB = 10, CHI_SAMPLES = 1000000 };

/* The upper tail of the chi-square distribution of k degrees of freedom
 * at x (Wilson and Hilferty's normal approximation, good to 1e-3 here). */
static double chi2_tail(double x, double k)
{
    double z = (pow(x / k, 1.0 / 3) - (1 - 2 / (9 * k))) / sqrt(2 / (9 * k));
    return 0.5 * erfc(z / sqrt(2));
}

typedef struct {
    const char *name;
    int kind; /* 0 conductor, 1 plastic, 2 rough glass seen from outside, 3 from inside */
    float alpha;
    microfacet_type_t d;
    float theta_o; /* degrees */
} chi_case_t;

static const chi_case_t chi_cases[] = {
    {"rough conductor, Beckmann 0.1, 30 deg", 0, 0.1f, MICROFACET_BECKMANN, 30},
    {"rough conductor, Beckmann 0.4, 0 deg", 0, 0.4f, MICROFACET_BECKMANN, 0},
    {"rough conductor, Beckmann 0.4, 75 deg", 0, 0.4f, MICROFACET_BECKMANN, 75},
    {"rough conductor, Beckmann 1, 89 deg", 0, 1.0f, MICROFACET_BECKMANN, 89},
    {"rough conductor, GGX 0.1, 30 deg", 0, 0.1f, MICROFACET_GGX, 30},
    {"rough conductor, GGX 0.4, 60 deg", 0, 0.4f, MICROFACET_GGX, 60},
    {"rough conductor, GGX 0.8, 85 deg", 0, 0.8f, MICROFACET_GGX, 85},
    {"rough plastic, Beckmann 0.2, 20 deg", 1, 0.2f, MICROFACET_BECKMANN, 20},
    {"rough plastic, GGX 0.3, 70 deg", 1, 0.3f, MICROFACET_GGX, 70},
    {"rough plastic, GGX 0.05, 45 deg", 1, 0.05f, MICROFACET_GGX, 45},
    {"smooth plastic (its base), 40 deg", 1, 0.0f, MICROFACET_BECKMANN, 40},
    {"rough glass, Beckmann 0.2, 30 deg", 2, 0.2f, MICROFACET_BECKMANN, 30},
    {"rough glass, GGX 0.5, 80 deg", 2, 0.5f, MICROFACET_GGX, 80},
    {"rough glass from inside, GGX 0.3, 20 deg", 3, 0.3f, MICROFACET_GGX, 20},
    {"rough glass from inside, Beckmann 0.3, 50 deg (total reflection)", 3, 0.3f,
     MICROFACET_BECKMANN, 50},
};

static vec3_t dir_of(double theta, double phi)
{
    return vec3_make((float)(sin(theta) * cos(phi)), (float)(sin(theta) * sin(phi)),
                     (float)cos(theta));
}

START_TEST(chi_square_sampling)
{
    const chi_case_t *c = &chi_cases[_i];
    material_t m = c->kind >= 2 ? glass(c->alpha, c->d, 1.5f)
                   : c->kind    ? plastic(c->alpha, c->d, 0.5f, 1.5f)
                                : conductor(c->alpha, c->d, "Cu");
    double th = c->theta_o * M_PI / 180;
    material_hit_t h = hit_from(vec3_make((float)sin(th), 0, (float)cos(th)));
    h.front = c->kind != 3;
    /* glass: the whole sphere, in bins of the same size */
    const int tbins = c->kind >= 2 ? 2 * THETA_BINS : THETA_BINS;
    const double trange = c->kind >= 2 ? M_PI : M_PI / 2;
    static double observed[2 * THETA_BINS * PHI_BINS], expected[2 * THETA_BINS * PHI_BINS];
    memset(observed, 0, sizeof observed);
    double drawn = 0;
    for (uint64_t i = 0; i < CHI_SAMPLES; i++) {
        material_sample_t bs;
        if (!material_glossy_sample(&m, &h, uniform(i, 0), uniform(i, 1), uniform(i, 2), &bs) ||
            bs.specular)
            continue;
        vec3_t w = vec3_normalize(bs.wi);
        double t = acos(fmin(1.0, fmax(-1.0, w.z))), p = atan2(w.y, w.x);
        if (p < 0)
            p += 2 * M_PI;
        int ti = (int)(t / trange * tbins), pi = (int)(p / (2 * M_PI) * PHI_BINS);
        ck_assert_msg(ti < tbins, "%s: a direction below the surface", c->name);
        if (pi >= PHI_BINS)
            pi = PHI_BINS - 1;
        observed[ti * PHI_BINS + pi]++;
        drawn++;
    }
    /* the density over each bin, by the midpoint rule on SUB x SUB cells */
    double total = 0;
    for (int ti = 0; ti < tbins; ti++)
        for (int pi = 0; pi < PHI_BINS; pi++) {
            double sum = 0, dt = trange / tbins / SUB, dp = 2 * M_PI / PHI_BINS / SUB;
            for (int a = 0; a < SUB; a++)
                for (int b = 0; b < SUB; b++) {
                    double t = (ti * SUB + a + 0.5) * dt, p = (pi * SUB + b + 0.5) * dp;
                    vec3_t f;
                    float pdf;
                    if (material_glossy_eval(&m, &h, dir_of(t, p), &f, &pdf))
                        sum += pdf * sin(t) * dt * dp;
                }
            expected[ti * PHI_BINS + pi] = sum * CHI_SAMPLES;
            total += sum;
        }
    ck_assert_msg(total <= 1.0 + 2e-3, "%s: the density integrates to %g", c->name, total);
    /* pool the small bins; the directions not drawn are one more bin */
    double chi = 0, pool_o = 0, pool_e = 0;
    int bins = 0;
    for (int k = 0; k < tbins * PHI_BINS; k++) {
        if (expected[k] < 5) {
            pool_o += observed[k];
            pool_e += expected[k];
            continue;
        }
        chi += (observed[k] - expected[k]) * (observed[k] - expected[k]) / expected[k];
        bins++;
    }
    double rest_o = CHI_SAMPLES - drawn + pool_o, rest_e = CHI_SAMPLES * (1 - total) + pool_e;
    if (rest_e >= 5) {
        chi += (rest_o - rest_e) * (rest_o - rest_e) / rest_e;
        bins++;
    } else {
        ck_assert_msg(rest_o < 40, "%s: %g samples where %g were expected", c->name, rest_o,
                      rest_e);
    }
    double p = chi2_tail(chi, bins - 1);
    /* Sidak's correction over the cases, at 1 % */
    double alpha = 1 - pow(0.99, 1.0 / (sizeof chi_cases / sizeof chi_cases[0]));
    ck_assert_msg(p > alpha, "%s: chi2 %g over %d bins, p %g", c->name, chi, bins, p);
}
END_TEST

/* ---- the sample against the evaluation ----------------------------------------- */

static material_t some_material(int k)
{
    switch (k) {
    case 0:
        return conductor(0.15f, MICROFACET_BECKMANN, "Au");
    case 1:
        return conductor(0.5f, MICROFACET_GGX, "Al");
    case 2:
        return plastic(0.1f, MICROFACET_BECKMANN, 0.6f, 1.6f);
    case 3:
        return plastic(0.4f, MICROFACET_GGX, 0.3f, 1.3f);
    case 4:
        return plastic(0.0f, MICROFACET_BECKMANN, 0.8f, 1.5f);
    case 5:
        return glass(0.2f, MICROFACET_BECKMANN, 1.5f);
    default:
        return glass(0.4f, MICROFACET_GGX, 1.33f);
    }
}

START_TEST(sample_agrees_with_eval)
{
    material_t m = some_material(_i);
    for (int a = 0; a < 12; a++) {
        double th = (5 + 16.0 * (a % 6)) * M_PI / 180;
        material_hit_t h = hit_from(vec3_make((float)sin(th), 0.1f, (float)cos(th)));
        h.front = a < 6; /* glass: from outside, then from inside */
        int checked = 0;
        for (uint64_t i = 0; i < 20000; i++) {
            material_sample_t bs;
            if (!material_glossy_sample(&m, &h, uniform(i, 0), uniform(i, 1), uniform(i, 2), &bs) ||
                bs.specular)
                continue;
            vec3_t f;
            float pdf;
            ck_assert(isfinite(bs.pdf) && bs.pdf > 0);
            ck_assert_msg(material_glossy_eval(&m, &h, bs.wi, &f, &pdf), "case %d: no eval", _i);
            ck_assert_msg(fabsf(pdf / bs.pdf - 1) < 2e-3, "case %d, %d deg: pdf %g, eval %g", _i,
                          5 + 16 * a, bs.pdf, pdf);
            vec3_t want = vec3_scale(f, 1 / pdf);
            ck_assert_msg(fabsf(bs.weight.x - want.x) <= 2e-3f * want.x + 1e-6f &&
                              fabsf(bs.weight.z - want.z) <= 2e-3f * want.z + 1e-6f,
                          "case %d: weight %g, f cos / pdf %g", _i, bs.weight.x, want.x);
            checked++;
        }
        ck_assert(checked > 1000);
    }
}
END_TEST

/* f(wo, wi) / cos_i = f(wi, wo) / cos_o */
START_TEST(reciprocal)
{
    material_t m = some_material(_i);
    for (uint64_t i = 0; i < 2000; i++) {
        double t1 = uniform(i, 0) * 1.5, p1 = uniform(i, 1) * 2 * M_PI;
        double t2 = uniform(i, 2) * 1.5, p2 = uniform(i, 3) * 2 * M_PI;
        vec3_t a = dir_of(t1, p1), b = dir_of(t2, p2);
        material_hit_t ha = hit_from(a), hb = hit_from(b);
        vec3_t fab, fba;
        float pab, pba;
        int ok1 = material_glossy_eval(&m, &ha, b, &fab, &pab);
        int ok2 = material_glossy_eval(&m, &hb, a, &fba, &pba);
        ck_assert_int_eq(ok1, ok2);
        if (!ok1)
            continue;
        double x = fab.x / b.z, y = fba.x / a.z;
        ck_assert_msg(fabs(x - y) <= 1e-3 * fmax(x, y) + 1e-7, "case %d: f %g and %g", _i, x, y);
    }
}
END_TEST

/* ---- energy -------------------------------------------------------------------- */

/* A white material at every angle, grazing included, returns at most what
 * it receives: the mean sample weight (its directional albedo) is below
 * 1 within its noise, and never NaN. */
START_TEST(white_furnace)
{
    material_t ms[] = {conductor(0.05f, MICROFACET_BECKMANN, "none"),
                       conductor(0.6f, MICROFACET_GGX, "none"),
                       conductor(1e-4f, MICROFACET_GGX, "none"),
                       conductor(0.0f, MICROFACET_BECKMANN, "none"),
                       plastic(0.0f, MICROFACET_BECKMANN, 1.0f, 1.5f),
                       plastic(0.2f, MICROFACET_BECKMANN, 1.0f, 1.5f),
                       plastic(0.7f, MICROFACET_GGX, 1.0f, 2.5f),
                       plastic(1e-4f, MICROFACET_GGX, 1.0f, 1.5f),
                       glass(0.1f, MICROFACET_BECKMANN, 1.5f),
                       glass(0.7f, MICROFACET_GGX, 1.5f),
                       glass(1e-4f, MICROFACET_GGX, 1.5f)};
    const material_t *m = &ms[_i];
    static const double angles[] = {0, 30, 60, 80, 89, 89.9};
    for (size_t a = 0; a < sizeof angles / sizeof angles[0]; a++) {
        double th = angles[a] * M_PI / 180;
        material_hit_t h = hit_from(vec3_make((float)sin(th), 0, (float)cos(th)));
        double sum = 0, sum2 = 0;
        const int n = 200000;
        for (uint64_t i = 0; i < (uint64_t)n; i++) {
            material_sample_t bs;
            if (!material_glossy_sample(m, &h, uniform(i, 0), uniform(i, 1), uniform(i, 2), &bs))
                continue;
            ck_assert_msg(isfinite(bs.weight.x) && bs.weight.x >= 0, "case %zu, %g deg: weight %g",
                          (size_t)_i, angles[a], bs.weight.x);
            /* energy, not radiance: a transmission's 1/eta^2 undone */
            double wgt = bs.transmits ? bs.weight.x * bs.eta * bs.eta : bs.weight.x;
            sum += wgt;
            sum2 += wgt * wgt;
        }
        double mean = sum / n, sd = sqrt(fmax(0, sum2 / n - mean * mean) / n);
        /* rough plastic's coat table is interpolated linearly between
         * cosines 0 and 1/63: at 89.9 degrees its base and coat overlap by
         * 0.1 % (Mitsuba's model does the same) */
        double slack = m->type == MATERIAL_PLASTIC && m->alpha > 0 ? 2e-3 : 1e-4;
        ck_assert_msg(mean <= 1 + 5 * sd + slack, "case %d at %g deg: albedo %g (+- %g)", _i,
                      angles[a], mean, sd);
        if (m->type == MATERIAL_CONDUCTOR && angles[a] <= 60 && m->alpha < 0.1f)
            ck_assert_msg(mean > 0.97, "case %d at %g deg: a white mirror returns %g", _i,
                          angles[a], mean);
    }
}
END_TEST

/* alpha at its floor: what the smooth material reflects */
START_TEST(smooth_limit)
{
    for (int kind = 0; kind < 2; kind++) {
        material_t rough = kind ? plastic(1e-4f, MICROFACET_BECKMANN, 0.5f, 1.5f)
                                : conductor(1e-4f, MICROFACET_BECKMANN, "Au");
        material_t smooth = kind ? plastic(0.0f, MICROFACET_BECKMANN, 0.5f, 1.5f)
                                 : conductor(0.0f, MICROFACET_BECKMANN, "Au");
        for (int a = 0; a < 4; a++) {
            double th = (10 + 20 * a) * M_PI / 180;
            material_hit_t h = hit_from(vec3_make((float)sin(th), 0, (float)cos(th)));
            double sr = 0, ss = 0;
            const int n = 100000;
            for (uint64_t i = 0; i < (uint64_t)n; i++) {
                material_sample_t br, bsm;
                if (material_glossy_sample(&rough, &h, uniform(i, 0), uniform(i, 1), uniform(i, 2),
                                           &br)) {
                    ck_assert(isfinite(br.weight.y));
                    sr += br.weight.y;
                }
                if (material_glossy_sample(&smooth, &h, uniform(i, 0), uniform(i, 1), uniform(i, 2),
                                           &bsm))
                    ss += bsm.weight.y;
            }
            /* plastic: the rough base's internal reflectance is integrated
             * (0.588 at index 1.5), the smooth one's a fit (0.597), as in
             * Mitsuba: 2.2 % more light from the smooth base */
            ck_assert_msg(fabs(sr / ss - 1) < (kind ? 0.03 : 0.01),
                          "%s at %d deg: rough %g, smooth %g", kind ? "plastic" : "conductor",
                          10 + 20 * a, sr / n, ss / n);
        }
    }
}
END_TEST

/* ---- values -------------------------------------------------------------------- */

START_TEST(fresnel_values)
{
    float ct;
    /* normal incidence: ((n - 1) / (n + 1))^2 */
    ck_assert(fabsf(microfacet_fresnel(1.0f, 1.5f, &ct) - 0.04f) < 1e-6f);
    ck_assert(fabsf(ct + 1.0f) < 1e-6f);
    /* from inside, beyond the critical angle: total reflection */
    ck_assert(microfacet_fresnel(-0.3f, 1.5f, &ct) == 1.0f);
    /* index matched: nothing reflected */
    ck_assert(microfacet_fresnel(0.5f, 1.0f, &ct) == 0.0f);
    /* a conductor at normal incidence: ((n-1)^2 + k^2) / ((n+1)^2 + k^2) */
    float n = 0.2f, k = 3.9f;
    float want = ((n - 1) * (n - 1) + k * k) / ((n + 1) * (n + 1) + k * k);
    ck_assert(fabsf(microfacet_fresnel_conductor(1.0f, n, k) - want) < 1e-5f);
    /* "none" is a perfect mirror at every angle */
    vec3_t e, kk;
    ck_assert(material_conductor_preset("none", &e, &kk) == 0);
    for (float c = 0.05f; c <= 1.0f; c += 0.1f)
        ck_assert(fabsf(microfacet_fresnel_conductor(c, e.x, kk.x) - 1.0f) < 1e-5f);
    /* Mitsuba 3.9.1's gold in RGB mode */
    ck_assert(material_conductor_preset("Au", &e, &kk) > 0);
    ck_assert(fabsf(e.x - 0.143036f) < 1e-6f && fabsf(kk.z - 1.60336f) < 1e-6f);
    ck_assert(material_conductor_preset("Unobtainium", &e, &kk) < 0);
}
END_TEST

/* The distributions are densities of projected area: the integral of
 * D(m) cos(m) over the hemisphere is 1, and the visible normals of any
 * direction integrate to 1. */
START_TEST(distributions_normalised)
{
    for (int t = 0; t < 2; t++)
        for (int a = 0; a < 3; a++) {
            microfacet_t d = {(microfacet_type_t)t, a == 0 ? 0.1f : a == 1 ? 0.5f : 1.0f};
            double sum = 0;
            enum { T = 2000, P = 16 };
            for (int i = 0; i < T; i++)
                for (int j = 0; j < P; j++) {
                    double th = (i + 0.5) / T * M_PI / 2, ph = (j + 0.5) / P * 2 * M_PI;
                    vec3_t m = dir_of(th, ph);
                    sum += microfacet_d(&d, m) * m.z * sin(th) * (M_PI / 2 / T) * (2 * M_PI / P);
                }
            ck_assert_msg(fabs(sum - 1) < 2e-3, "type %d alpha %g: %g", t, d.alpha, sum);
            vec3_t wo = vec3_normalize(vec3_make(0.8f, 0.1f, 0.4f));
            double vis = 0;
            for (int i = 0; i < T; i++)
                for (int j = 0; j < 4 * P; j++) {
                    double th = (i + 0.5) / T * M_PI / 2, ph = (j + 0.5) / (4 * P) * 2 * M_PI;
                    vec3_t m = dir_of(th, ph);
                    vis += microfacet_pdf_visible(&d, wo, m) * sin(th) * (M_PI / 2 / T) *
                           (2 * M_PI / (4 * P));
                }
            /* Beckmann's G1 is Walter's fit, exact to about 1 % */
            ck_assert_msg(fabs(vis - 1) < (t == MICROFACET_GGX ? 3e-3 : 0.02),
                          "type %d alpha %g: visible normals integrate to %g", t, d.alpha, vis);
        }
}
END_TEST

/* Beckmann's visible normal from its parts (the stretched direction, the
 * slope's part from u1, the part from u2), as rough plastic's coat tables
 * compute them once a grid line, is microfacet_sample_visible's, bit for
 * bit: over directions from normal to grazing and numbers up to both ends
 * of [0, 1] (clamped alike). */
START_TEST(beckmann_slope_parts)
{
    static const float us[] = {0.0f,  1e-7f,  1e-6f,        0.013f,         0.25f, 0.5f,
                               0.77f, 0.999f, 1.0f - 1e-6f, 0x1.fffffep-1f, 1.0f};
    enum { NU = sizeof us / sizeof us[0] };
    size_t checked = 0;
    for (int a = 0; a < 3; a++) {
        microfacet_t d = {MICROFACET_BECKMANN, a == 0 ? 0.005f : a == 1 ? 0.1f : 0.7f};
        for (int k = 0; k <= 40; k++) {
            float mu = k == 0 ? 1e-6f : (float)k / 40;
            vec3_t wo = vec3_normalize(vec3_make(sqrtf(1 - mu * mu), k % 3 == 0 ? 0.3f : 0.0f, mu));
            microfacet_stretched_t st = microfacet_stretch(&d, wo);
            for (int i = 0; i < NU; i++)
                for (int j = 0; j < NU; j++) {
                    vec3_t want = microfacet_sample_visible(&d, wo, us[i], us[j]);
                    vec3_t got = microfacet_slope_normal(
                        &d, st, microfacet_beckmann_slope_x(st.cos_i, us[i]),
                        microfacet_beckmann_slope_y(us[j]));
                    ck_assert_msg(memcmp(&want, &got, sizeof want) == 0,
                                  "alpha %g mu %g u (%a, %a): (%a %a %a), want (%a %a %a)", d.alpha,
                                  mu, us[i], us[j], got.x, got.y, got.z, want.x, want.y, want.z);
                    checked++;
                }
        }
    }
    ck_assert_uint_eq(checked, 3 * 41 * NU * NU);
}
END_TEST

/* A coat's transmittance from direction cosine mu, each point of the
 * 32 x 32 rule drawn by microfacet_sample_visible itself (material.c takes
 * Beckmann's slopes a grid line at a time): the table must hold these
 * bits. */
static float coat_transmittance_direct(const microfacet_t *d, float mu, float eta)
{
    enum { N = 32 };
    double x[N], w[N];
    material_gauss_legendre(N, x, w);
    vec3_t wi = vec3_make(sqrtf(1 - mu * mu), 0, mu);
    double sum = 0;
    for (int a = 0; a < N; a++)
        for (int b = 0; b < N; b++) {
            float u1 = (float)(x[b] * 0.5 + 0.5), u2 = (float)(x[a] * 0.5 + 0.5);
            vec3_t m = microfacet_sample_visible(d, wi, u1, u2);
            float cos_t, c = vec3_dot(wi, m);
            float f = microfacet_fresnel(c, eta, &cos_t);
            float eta_ti = c >= 0 ? 1 / eta : eta;
            vec3_t wo = vec3_sub(vec3_scale(m, c * eta_ti + cos_t), vec3_scale(wi, eta_ti));
            float g = wo.z * wi.z >= 0 ? 0 : microfacet_g1(d, wo, m) * (1 - f);
            sum += g * w[a] * w[b] * 0.25;
        }
    return (float)sum;
}

START_TEST(beckmann_coat_table_bits)
{
    for (int a = 0; a < 2; a++) {
        material_t p = plastic(a ? 0.3f : 0.05f, MICROFACET_BECKMANN, 0.5f, 1.5f);
        microfacet_t d = {MICROFACET_BECKMANN, p.alpha};
        for (int i = 0; i < MATERIAL_COAT_RES; i += 9) {
            float mu = fmaxf(1e-6f, (float)i / (MATERIAL_COAT_RES - 1));
            float want = coat_transmittance_direct(&d, mu, 1.5f);
            ck_assert_msg(memcmp(&p.coat_t[i], &want, sizeof want) == 0,
                          "alpha %g row %d: %a, sample by sample %a", p.alpha, i, p.coat_t[i],
                          want);
        }
    }
}
END_TEST

/* Rough plastic's coat: at tiny roughness its transmittance is one minus
 * Fresnel's reflectance; its internal reflectance approaches the smooth
 * plastic's hemispherical fit. */
START_TEST(plastic_coat_tables)
{
    material_t r = plastic(1e-3f, MICROFACET_GGX, 0.5f, 1.5f);
    /* (Beckmann's tables take its slopes a grid line at a time) */
    material_t rb = plastic(1e-3f, MICROFACET_BECKMANN, 0.5f, 1.5f);
    for (int i = 8; i < MATERIAL_COAT_RES; i += 8) {
        float mu = (float)i / (MATERIAL_COAT_RES - 1), ct;
        float want = 1 - microfacet_fresnel(mu, 1.5f, &ct);
        ck_assert_msg(fabsf(r.coat_t[i] - want) < 5e-3f, "mu %g: %g, want %g", mu, r.coat_t[i],
                      want);
        ck_assert_msg(fabsf(rb.coat_t[i] - want) < 5e-3f, "Beckmann, mu %g: %g, want %g", mu,
                      rb.coat_t[i], want);
    }
    ck_assert_msg(fabsf(rb.internal - r.internal) < 2e-3f, "internal: Beckmann %g, GGX %g",
                  rb.internal, r.internal);
    /* a second plastic with the same coat takes the first's tables */
    material_t again = {.type = MATERIAL_PLASTIC,
                        .albedo = vec3_make(0.1f, 0.2f, 0.3f),
                        .specular = vec3_make(1, 1, 1),
                        .alpha = 1e-3f,
                        .distribution = MICROFACET_GGX,
                        .ior = 1.5f,
                        .albedo_texture = -1};
    material_prepare(&again, 0.2f, &r, 1);
    ck_assert(memcmp(again.coat_t, r.coat_t, sizeof r.coat_t) == 0 && again.internal == r.internal);
    ck_assert(again.coat_weight != r.coat_weight);
    float fdr = microfacet_fresnel_diffuse_reflectance(1 / 1.5f);
    ck_assert_msg(fabsf(r.internal - fdr) < 0.01f, "internal %g, smooth %g", r.internal, fdr);
    /* rougher coats trap less light inside, and every coat lets less
     * through at grazing than head-on (the values themselves:
     * eval_as_mitsuba) */
    float prev_internal = 1;
    for (int a = 0; a < 4; a++) {
        material_t g = plastic(0.05f + 0.2f * a, MICROFACET_GGX, 0.5f, 1.5f);
        ck_assert(g.internal < prev_internal);
        ck_assert(g.coat_t[1] < g.coat_t[MATERIAL_COAT_RES / 2]);
        prev_internal = g.internal;
    }
}
END_TEST

/* The thin pane: reflection R' = R + T^2 R / (1 - R^2) = 2R / (1 + R),
 * chosen with that probability, and straight through otherwise. */
START_TEST(thin_dielectric)
{
    material_t m = {.type = MATERIAL_THIN_DIELECTRIC, .ior = 1.5f, .albedo_texture = -1};
    material_hit_t h = hit_from(vec3_make(0.5f, 0, 0.866f));
    float ct, R = microfacet_fresnel(vec3_dot(h.ns, h.wo), 1.5f, &ct);
    float want = 2 * R / (1 + R);
    int reflected = 0;
    const int n = 100000;
    for (uint64_t i = 0; i < (uint64_t)n; i++) {
        material_sample_t bs;
        ck_assert(material_glossy_sample(&m, &h, uniform(i, 0), 0.5f, 0.5f, &bs));
        ck_assert(bs.specular && bs.weight.x == 1.0f && bs.eta == 1.0f);
        if (bs.transmits) {
            ck_assert(bs.wi.x == -h.wo.x && bs.wi.z == -h.wo.z);
        } else {
            ck_assert(fabsf(bs.wi.x + h.wo.x) < 1e-6f && fabsf(bs.wi.z - h.wo.z) < 1e-6f);
            reflected++;
        }
    }
    ck_assert_msg(fabs((double)reflected / n - want) < 5 * sqrt(want * (1 - want) / n),
                  "reflected %g, want %g", (double)reflected / n, want);
    vec3_t f;
    float pdf;
    ck_assert(!material_glossy_eval(&m, &h, vec3_make(0, 0, 1), &f, &pdf));
}
END_TEST

/* ---- against Mitsuba's own values ------------------------------------------------ */

/* Mitsuba 3.9.1's BSDF values (eval: f cos, and pdf) for the same
 * materials and directions (scalar_rgb; bench/peer's Python, BSDF.eval and
 * BSDF.pdf on a surface facing +z): wo at (theta, phi) to_, po_, wi at
 * ti, pi. Ours agree to 1e-3 (the rough plastic's coat tables included);
 * Beckmann's pdf to 2 %, since ours is the density its sampling really
 * has (microfacet_g1_visible). */
typedef struct {
    const char *name;
    double to_, po_, ti, pi;
    float f[3];
    float pdf;
} mitsuba_eval_t;

static const mitsuba_eval_t mitsuba_evals[] = {
    {"conductor_cu_beck02", 0.3, 0, 0.35, 3, {1.92888, 1.25574, 1.03464}, 2.02621},
    {"conductor_cu_beck02", 1.2, 0.5, 0.2, 3.5, {0.00482225, 0.00314127, 0.00260086}, 0.00507161},
    {"conductor_cu_beck02", 0.05, 0, 0.6, 1, {0.164889, 0.107346, 0.0884389}, 0.173206},
    {"conductor_cu_beck02", 1, 0, 1, 3.14159, {3.48663, 2.29534, 1.93856}, 3.68208},
    {"conductor_cu_beck02", 0.7, 1, 1.3, 2, {6.22593e-20, 4.05327e-20, 3.34311e-20}, 6.55287e-20},
    {"conductor_al_ggx005", 0.3, 0, 0.35, 3, {14.2222, 14.0651, 14.0821}, 15.3276},
    {"conductor_al_ggx005", 1.2, 0.5, 0.2, 3.5, {0.00932537, 0.00922094, 0.00923418}, 0.0100725},
    {"conductor_al_ggx005", 0.05, 0, 0.6, 1, {0.0192863, 0.0190733, 0.0190964}, 0.0207889},
    {"conductor_al_ggx005", 1, 0, 1, 3.14159, {53.839, 53.2312, 53.3927}, 58.8243},
    {"conductor_al_ggx005", 0.7, 1, 1.3, 2, {0.000557866, 0.000551682, 0.000552372}, 0.000606301},
    {"plastic_smooth", 0.3, 0, 0.35, 3, {0.182386, 0.0303976, 0.0303976}, 0.259689},
    {"plastic_smooth", 1.2, 0.5, 0.2, 3.5, {0.167493, 0.0279155, 0.0279155}, 0.185312},
    {"plastic_smooth", 0.05, 0, 0.6, 1, {0.159849, 0.0266415, 0.0266415}, 0.228275},
    {"plastic_smooth", 1, 0, 1, 3.14159, {0.0969864, 0.0161644, 0.0161644}, 0.131506},
    {"plastic_smooth", 0.7, 1, 1.3, 2, {0.0407978, 0.00679964, 0.00679964}, 0.0725121},
    {"rplastic_ggx03", 0.3, 0, 0.35, 3, {0.179588, 0.179588, 0.158924}, 0.34088},
    {"rplastic_ggx03", 1.2, 0.5, 0.2, 3.5, {0.142573, 0.142573, 0.123432}, 0.286288},
    {"rplastic_ggx03", 0.05, 0, 0.6, 1, {0.134977, 0.134977, 0.116949}, 0.260451},
    {"rplastic_ggx03", 1, 0, 1, 3.14159, {0.186202, 0.186202, 0.175629}, 0.373324},
    {"rplastic_ggx03", 0.7, 1, 1.3, 2, {0.0348839, 0.0348839, 0.0299911}, 0.0791252},
    {"rplastic_beck01_nl", 0.3, 0, 0.35, 3, {0.829209, 0.830551, 0.833374}, 4.31374},
    {"rplastic_beck01_nl", 1.2, 0.5, 0.2, 3.5, {0.00398777, 0.0052124, 0.00778808}, 0.0785363},
    {"rplastic_beck01_nl", 0.05, 0, 0.6, 1, {0.00385494, 0.00503027, 0.00750226}, 0.114756},
    {"rplastic_beck01_nl", 1, 0, 1, 3.14159, {2.21325, 2.21395, 2.21543}, 9.61322},
    {"rplastic_beck01_nl", 0.7, 1, 1.3, 2, {0.000979504, 0.00128031, 0.00191296}, 0.0356524},
};

/* the same for rough glass, on both sides (theta above 90 degrees: below
 * the surface, inside the glass); one pair Mitsuba gives nothing: ours too */
static const mitsuba_eval_t mitsuba_glass_evals[] = {
    {"rdielectric_beck01", 0.3, 0, 0.35, 3, {0.301941, 0.301941, 0.301941}, 0.301941},
    {"rdielectric_beck01", 0.5, 0, 2.9, 3.3, {0.304767, 0.304767, 0.304767}, 0.689555},
    {"rdielectric_beck01", 1.2, 0.5, 2.5, 3.5, {2.01822, 2.01822, 2.01822}, 4.56635},
    {"rdielectric_beck01", 2.8, 0.2, 2.7, 3, {0.178224, 0.178224, 0.178224}, 0.178224},
    {"rdielectric_beck01", 2.6, 0, 0.4, 3.2, {0, 0, 0}, 0},
    {"rdielectric_beck01", 2.9, 1, 0.2, 4, {0.00235189, 0.00235189, 0.00235189}, 0.00103948},
    {"rdielectric_ggx03", 0.3, 0, 0.35, 3, {0.0181531, 0.0181531, 0.0181531}, 0.0182074},
    {"rdielectric_ggx03", 0.5, 0, 2.9, 3.3, {1.58308, 1.58308, 1.58308}, 2.80413},
    {"rdielectric_ggx03", 1.2, 0.5, 2.5, 3.5, {0.426031, 0.426031, 0.426031}, 0.762953},
    {"rdielectric_ggx03", 2.8, 0.2, 2.7, 3, {0.0170501, 0.0170501, 0.0170501}, 0.0171354},
    {"rdielectric_ggx03", 2.6, 0, 0.4, 3.2, {0.712483, 0.712483, 0.712483}, 0.404396},
    {"rdielectric_ggx03", 2.9, 1, 0.2, 4, {9.41666, 9.41666, 9.41666}, 5.32837},
};

static material_t named_material(const char *n)
{
    if (strcmp(n, "conductor_cu_beck02") == 0)
        return conductor(0.2f, MICROFACET_BECKMANN, "Cu");
    if (strcmp(n, "conductor_al_ggx005") == 0)
        return conductor(0.05f, MICROFACET_GGX, "Al");
    material_t m = plastic(0.0f, MICROFACET_BECKMANN, 0.6f, 1.49f / 1.000277f);
    m.albedo = vec3_make(0.6f, 0.1f, 0.1f);
    if (strcmp(n, "rplastic_ggx03") == 0) {
        m = plastic(0.3f, MICROFACET_GGX, 0.7f, 1.49f / 1.000277f);
        m.albedo = vec3_make(0.7f, 0.7f, 0.6f);
    } else if (strcmp(n, "rplastic_beck01_nl") == 0) {
        m = plastic(0.1f, MICROFACET_BECKMANN, 0.1f, 2.0f / 1.000277f);
        m.albedo = vec3_make(0.07f, 0.09f, 0.13f);
        m.nonlinear = 1;
    }
    material_prepare(&m, (m.albedo.x + m.albedo.y + m.albedo.z) / 3, NULL, 0);
    return m;
}

START_TEST(eval_as_mitsuba)
{
    for (size_t i = 0; i < sizeof mitsuba_evals / sizeof mitsuba_evals[0]; i++) {
        const mitsuba_eval_t *e = &mitsuba_evals[i];
        material_t m = named_material(e->name);
        material_hit_t h = hit_from(dir_of(e->to_, e->po_));
        vec3_t f;
        float pdf;
        ck_assert_msg(material_glossy_eval(&m, &h, dir_of(e->ti, e->pi), &f, &pdf), "%s: no value",
                      e->name);
        float got[3] = {f.x, f.y, f.z};
        for (int c = 0; c < 3; c++)
            ck_assert_msg(fabsf(got[c] - e->f[c]) <= 1e-3f * e->f[c],
                          "%s, case %zu, channel %d: %g, Mitsuba %g", e->name, i, c, got[c],
                          e->f[c]);
        float tol = m.distribution == MICROFACET_BECKMANN ? 0.02f : 1e-3f;
        ck_assert_msg(fabsf(pdf - e->pdf) <= tol * e->pdf, "%s, case %zu: pdf %g, Mitsuba %g",
                      e->name, i, pdf, e->pdf);
    }
    for (size_t i = 0; i < sizeof mitsuba_glass_evals / sizeof mitsuba_glass_evals[0]; i++) {
        const mitsuba_eval_t *e = &mitsuba_glass_evals[i];
        material_t m = strstr(e->name, "ggx")
                           ? glass(0.3f, MICROFACET_GGX, 1.33f)
                           : glass(0.1f, MICROFACET_BECKMANN, 1.5046f / 1.000277f);
        vec3_t wo = dir_of(e->to_, e->po_), wi = dir_of(e->ti, e->pi);
        int inside = wo.z < 0;
        if (inside) {
            /* our frame's normal is on the viewer's side: mirror both */
            wo.z = -wo.z;
            wi.z = -wi.z;
        }
        material_hit_t h = hit_from(wo);
        h.front = !inside;
        vec3_t f = {0, 0, 0};
        float pdf = 0;
        int got = material_glossy_eval(&m, &h, wi, &f, &pdf);
        if (e->f[0] == 0) {
            ck_assert_msg(!got, "%s, case %zu: %g where Mitsuba has nothing", e->name, i, f.x);
            continue;
        }
        ck_assert_msg(got, "%s, case %zu: no value", e->name, i);
        ck_assert_msg(fabsf(f.x - e->f[0]) <= 1e-3f * e->f[0], "%s, case %zu: %g, Mitsuba %g",
                      e->name, i, f.x, e->f[0]);
        float tol = m.distribution == MICROFACET_BECKMANN ? 0.02f : 1e-3f;
        ck_assert_msg(fabsf(pdf - e->pdf) <= tol * e->pdf, "%s, case %zu: pdf %g, Mitsuba %g",
                      e->name, i, pdf, e->pdf);
    }
}
END_TEST

static Suite *glossy_suite(void)
{
    Suite *s = suite_create("glossy");
    TCase *tc = tcase_create("glossy");
    tcase_set_timeout(tc, 300);
    tcase_add_loop_test(tc, chi_square_sampling, 0, sizeof chi_cases / sizeof chi_cases[0]);
    tcase_add_loop_test(tc, sample_agrees_with_eval, 0, 7);
    tcase_add_loop_test(tc, reciprocal, 0, 5);
    tcase_add_loop_test(tc, white_furnace, 0, 11);
    tcase_add_test(tc, smooth_limit);
    tcase_add_test(tc, fresnel_values);
    tcase_add_test(tc, distributions_normalised);
    tcase_add_test(tc, beckmann_slope_parts);
    tcase_add_test(tc, beckmann_coat_table_bits);
    tcase_add_test(tc, plastic_coat_tables);
    tcase_add_test(tc, thin_dielectric);
    tcase_add_test(tc, eval_as_mitsuba);
    suite_add_tcase(s, tc);
    return s;
}

int main(void)
{
    SRunner *sr = srunner_create(glossy_suite());
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed ? EXIT_FAILURE : EXIT_SUCCESS;
}
