/* material.c - material names; the BSDFs themselves are inline in
 * material.h because they sit on the tracer's hot path. */
#include "material.h"

#include <math.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static const char *const type_names[] = {"diffuse",        "emitter",        "mirror",
                                         "dielectric",     "conductor",      "plastic",
                                         "thindielectric", "roughdielectric"};

int material_type_from_name(const char *name)
{
    for (int i = 0; i < (int)(sizeof type_names / sizeof type_names[0]); i++)
        if (strcmp(name, type_names[i]) == 0)
            return i;
    return -1;
}

const char *material_type_name(material_type_t type)
{
    return (unsigned)type < sizeof type_names / sizeof type_names[0] ? type_names[type] : "?";
}

/* ---- conductor presets ---------------------------------------------------- */

/* Mitsuba 3.9.1's values of its named conductors in its RGB variants
 * (scalar_rgb): the spectral data of its resources/data/ior, converted as
 * it converts them, read back with mi.traverse (bench/peer: a conductor
 * with each "material", its eta.value and k.value). "none" is its perfect
 * mirror. */
static const struct {
    const char *name;
    float eta[3], k[3];
} presets[] = {
    {"none", {0, 0, 0}, {1, 1, 1}},
    {"a-C", {2.94405, 2.22714, 1.96816}, {0.887465, 0.799299, 0.81529}},
    {"Ag", {0.155276, 0.116728, 0.138388}, {4.82835, 3.12222, 2.1469}},
    {"Al", {1.6575, 0.880405, 0.521244}, {9.22381, 6.2695, 4.837}},
    {"AlAs", {3.6053, 3.23294, 2.21632}, {0.000679437, 0, 0.00751271}},
    {"AlSb", {0, 4.13937, 4.66925}, {0, 0.0940091, 1.30057}},
    {"Au", {0.143036, 0.375307, 1.44205}, {3.983, 2.38556, 1.60336}},
    {"Be", {4.18501, 3.18503, 2.78406}, {3.83547, 3.01012, 2.86899}},
    {"Cr", {4.36967, 2.91651, 1.6549}, {5.20655, 4.23131, 3.7547}},
    {"CsI", {2.1449, 1.70232, 1.66243}, {0, 0, 0}},
    {"Cu", {0.201005, 0.92375, 1.10222}, {3.91326, 2.45305, 2.14209}},
    {"Cu2O", {3.55177, 2.94987, 2.75188}, {0.114207, 0.193897, 0.606134}},
    {"CuO", {3.24754, 2.44781, 2.21022}, {0.52109, 0.570031, 0.722179}},
    {"d-C", {2.70872, 2.31883, 2.2289}, {0, 0, 0}},
    {"Hg", {2.39894, 1.44003, 0.90957}, {6.32759, 4.37192, 3.42176}},
    {"HgTe", {4.77904, 3.2312, 2.6599}, {1.63161, 1.58081, 1.72929}},
    {"Ir", {3.0863, 2.08219, 1.61791}, {5.59215, 4.06709, 3.26731}},
    {"K", {0.0640432, 0.0464098, 0.0381849}, {2.1042, 1.34894, 0.913126}},
    {"Li", {0.265791, 0.195618, 0.220949}, {3.54015, 2.31112, 1.66861}},
    {"MgO", {2.08958, 1.65072, 1.59488}, {4.3327e-12, 0, 2.49865e-11}},
    {"Mo", {4.48397, 3.52513, 2.77631}, {4.11144, 3.42083, 3.15061}},
    {"Na_palik", {0.0602694, 0.0561409, 0.0619884}, {3.17927, 2.11249, 1.57904}},
    {"Nb", {3.42007, 2.79009, 2.39563}, {3.44139, 2.73767, 2.57975}},
    {"Ni_palik", {2.3673, 1.66337, 1.46708}, {4.49881, 3.05015, 2.34544}},
    {"Rh", {2.58579, 1.86022, 1.55426}, {6.78226, 4.70299, 3.97607}},
    {"Se", {4.05831, 2.84294, 2.82085}, {0.75405, 0.638444, 0.521808}},
    {"SiC", {3.17234, 2.52597, 2.47937}, {7.53766e-07, 0, 1.01925e-05}},
    {"SnTe", {4.52425, 1.98164, 1.28159}, {0, 0, 0}},
    {"Ta", {2.06272, 2.39294, 2.62793}, {2.40836, 1.74149, 1.94703}},
    {"Te", {7.39023, 4.4821, 2.63711}, {3.25602, 3.52706, 3.29205}},
    {"ThF4", {1.83071, 1.44223, 1.38765}, {0, 0, 0}},
    {"TiC", {3.70053, 2.83742, 2.58229}, {3.26564, 2.35159, 2.17279}},
    {"TiN", {1.64845, 1.15052, 1.37982}, {3.36833, 1.9435, 1.10207}},
    {"TiO2", {3.45661, 2.80174, 2.90517}, {0.000105265, 0, 0.000652887}},
    {"VC", {3.65757, 2.75274, 2.53267}, {3.0683, 2.19869, 1.96319}},
    {"V_palik", {4.27758, 3.51295, 2.76107}, {3.4913, 2.88945, 3.11152}},
    {"VN", {2.8656, 2.11919, 1.94009}, {3.03224, 2.05612, 1.61631}},
    {"W", {4.37082, 3.30025, 2.99841}, {3.50064, 2.60487, 2.27323}},
};

int material_conductor_preset(const char *name, vec3_t *eta, vec3_t *k)
{
    for (size_t i = 0; i < sizeof presets / sizeof presets[0]; i++)
        if (strcmp(presets[i].name, name) == 0) {
            *eta = vec3_make(presets[i].eta[0], presets[i].eta[1], presets[i].eta[2]);
            *k = vec3_make(presets[i].k[0], presets[i].k[1], presets[i].k[2]);
            return (int)i;
        }
    return -1;
}

const char *material_conductor_presets(void)
{
    return "none, a-C, Ag, Al, AlAs, AlSb, Au, Be, Cr, CsI, Cu, Cu2O, CuO, d-C, Hg, HgTe, Ir, K, "
           "Li, MgO, Mo, Na_palik, Nb, Ni_palik, Rh, Se, SiC, SnTe, Ta, Te, ThF4, TiC, TiN, TiO2, "
           "VC, V_palik, VN, W";
}

/* ---- rough plastic's coat ------------------------------------------------- */

void material_gauss_legendre(int n, double *x, double *w)
{
    for (int i = 0; i < (n + 1) / 2; i++) {
        double z = cos(M_PI * (i + 0.75) / (n + 0.5)), dp = 1;
        for (int it = 0; it < 100; it++) {
            double p0 = 1, p1 = z;
            for (int k = 2; k <= n; k++) {
                double p2 = ((2.0 * k - 1) * z * p1 - (k - 1.0) * p0) / k;
                p0 = p1;
                p1 = p2;
            }
            dp = n * (z * p1 - p0) / (z * z - 1);
            double dz = p1 / dp;
            z -= dz;
            if (fabs(dz) < 1e-15)
                break;
        }
        x[i] = -z;
        x[n - 1 - i] = z;
        w[i] = w[n - 1 - i] = 2 / ((1 - z * z) * dp * dp);
    }
}

/* The two rules a coat's rows take (coat_integral), computed once a coat. */
enum { COAT_RULE_ABOVE = 32, COAT_RULE_BELOW = 128 };
typedef struct coat_rules {
    double x32[COAT_RULE_ABOVE], w32[COAT_RULE_ABOVE];
    double x128[COAT_RULE_BELOW], w128[COAT_RULE_BELOW];
} coat_rules_t;

/* The share of light from direction wi (wi.z = mu) that a rough
 * dielectric interface of index eta lets through (transmit) or reflects,
 * counted once (Mitsuba's eval_transmittance and eval_reflectance: a
 * Gauss-Legendre rule over the visible normals' sample square, 32 points a
 * side above eta 1, 128 below). */
static double coat_integral(const coat_rules_t *r, const microfacet_t *d, float mu, float eta,
                            int transmit)
{
    enum { MAXN = COAT_RULE_BELOW };
    int n = eta > 1 ? COAT_RULE_ABOVE : COAT_RULE_BELOW;
    const double *x = eta > 1 ? r->x32 : r->x128, *w = eta > 1 ? r->w32 : r->w128;
    vec3_t wi = vec3_make(sqrtf(1 - mu * mu), 0, mu);
    /* Beckmann's slope is one part from u1 and one from u2: each computed
     * once for the grid's n values, not n^2 times (erf, log and exp were
     * most of a coat's time), with the same operations as
     * microfacet_sample_visible, so the same bits */
    microfacet_stretched_t st = microfacet_stretch(d, wi);
    float slope_x[MAXN], slope_y[MAXN];
    int split = d->type == MICROFACET_BECKMANN;
    for (int k = 0; split && k < n; k++) {
        float u = (float)(x[k] * 0.5 + 0.5);
        slope_x[k] = microfacet_beckmann_slope_x(st.cos_i, u);
        slope_y[k] = microfacet_beckmann_slope_y(u);
    }
    double sum = 0;
    for (int a = 0; a < n; a++)
        for (int b = 0; b < n; b++) {
            /* meshgrid: the first coordinate (u1, b) runs fastest */
            vec3_t m = split ? microfacet_slope_normal(d, st, slope_x[b], slope_y[a])
                             : microfacet_sample_visible(d, wi, (float)(x[b] * 0.5 + 0.5),
                                                         (float)(x[a] * 0.5 + 0.5));
            float cos_t, c = vec3_dot(wi, m);
            float f = microfacet_fresnel(c, eta, &cos_t);
            vec3_t wo;
            float g;
            if (transmit) {
                float eta_ti = c >= 0 ? 1 / eta : eta;
                wo = vec3_sub(vec3_scale(m, c * eta_ti + cos_t), vec3_scale(wi, eta_ti));
                g = wo.z * wi.z >= 0 ? 0 : microfacet_g1(d, wo, m) * (1 - f);
            } else {
                wo = vec3_sub(vec3_scale(m, 2 * c), wi);
                g = wo.z <= 0 || wi.z <= 0 ? 0 : microfacet_g1(d, wo, m) * f;
            }
            sum += g * w[a] * w[b] * 0.25;
        }
    return sum;
}

/* A share of a coat's rows (material_prepare): rows first, first + step,
 * ... of the transmittance table, and each row's term of the internal
 * reflectance. */
enum { COAT_MAX_THREADS = 16 };
typedef struct coat_rows {
    const coat_rules_t *rules;
    microfacet_t d;
    float ior;
    float *coat_t;
    double internal_row[MATERIAL_COAT_RES];
    int first, step;
} coat_rows_t;

static void *coat_rows(void *arg)
{
    coat_rows_t *j = arg;
    for (int i = j->first; i < MATERIAL_COAT_RES; i += j->step) {
        float mu = fmaxf(1e-6f, (float)i / (MATERIAL_COAT_RES - 1));
        j->coat_t[i] = (float)coat_integral(j->rules, &j->d, mu, j->ior, 1);
        j->internal_row[i] = coat_integral(j->rules, &j->d, mu, 1.0f / j->ior, 0) * mu;
    }
    return NULL;
}

void material_prepare(material_t *m, float albedo_mean, const material_t *prepared, size_t count)
{
    if (m->type != MATERIAL_PLASTIC)
        return;
    float s_mean = (m->specular.x + m->specular.y + m->specular.z) / 3.0f;
    m->coat_weight = s_mean + albedo_mean > 0.0f ? s_mean / (albedo_mean + s_mean) : 0.5f;
    m->inv_eta2 = 1.0f / (m->ior * m->ior);
    if (!(m->alpha > 0.0f)) {
        m->internal = microfacet_fresnel_diffuse_reflectance(1.0f / m->ior);
        return;
    }
    for (size_t i = 0; i < count; i++) {
        const material_t *o = &prepared[i];
        if (o->type == MATERIAL_PLASTIC && o->alpha == m->alpha &&
            o->distribution == m->distribution && o->ior == m->ior) {
            memcpy(m->coat_t, o->coat_t, sizeof m->coat_t);
            m->internal = o->internal;
            return;
        }
    }
    coat_rules_t rules;
    material_gauss_legendre(COAT_RULE_ABOVE, rules.x32, rules.w32);
    material_gauss_legendre(COAT_RULE_BELOW, rules.x128, rules.w128);
    coat_rows_t job = {&rules, material_microfacet(m), m->ior, m->coat_t, {0}, 0, 1};
    /* The rows on every core: a coat is a million visible-normal samples
     * (0.15-0.5 s on one core), which small renders of Mitsuba's scenes
     * spent most of their time on. Each row is its own, and the internal
     * reflectance sums them in order afterwards: the same bits on any
     * number of threads. */
    long cores = sysconf(_SC_NPROCESSORS_ONLN);
    int threads = cores < 1 ? 1 : cores > COAT_MAX_THREADS ? COAT_MAX_THREADS : (int)cores;
    coat_rows_t jobs[COAT_MAX_THREADS];
    pthread_t tid[COAT_MAX_THREADS];
    int started[COAT_MAX_THREADS] = {0};
    for (int k = 0; k < threads; k++) {
        jobs[k] = job;
        jobs[k].first = k;
        jobs[k].step = threads;
        started[k] = k > 0 && pthread_create(&tid[k], NULL, coat_rows, &jobs[k]) == 0;
    }
    /* this thread: job 0, and any job whose thread did not start */
    for (int k = 0; k < threads; k++)
        if (!started[k])
            coat_rows(&jobs[k]);
    for (int k = 1; k < threads; k++)
        if (started[k])
            pthread_join(tid[k], NULL);
    double internal = 0;
    for (int i = 0; i < MATERIAL_COAT_RES; i++)
        internal += jobs[i % threads].internal_row[i];
    m->internal = (float)(internal / MATERIAL_COAT_RES * 2);
}
