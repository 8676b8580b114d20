/* microfacet.h - the microfacet distributions the rough materials use
 * (Beckmann and GGX, isotropic), their shadowing, the sampling of visible
 * normals, and the Fresnel terms, as Mitsuba 3 computes them.
 *
 * Everything is in the local frame of the shading normal (z up). The
 * formulas and the sampling maps are Mitsuba 3's (include/mitsuba/render/
 * microfacet.h and fresnel.h, BSD licence): Beckmann's visible normals by
 * its numerical inversion in erf space, GGX's by its concentric-disk
 * construction, Smith's G1 by Walter's rational fit for Beckmann. Using the
 * same maps keeps the precomputed tables of rough plastic (material.c)
 * equal to Mitsuba's to the last quadrature node. Not a hot path for the
 * scenes without rough materials: nothing here runs for them. */
#ifndef VB_MICROFACET_H
#define VB_MICROFACET_H

#include <math.h>

#include "vmath.h"

typedef enum { MICROFACET_BECKMANN = 0, MICROFACET_GGX = 1 } microfacet_type_t;

/* The smallest roughness: Mitsuba clamps to it too. Below it the lobe is
 * narrower than float directions resolve. */
#define MICROFACET_MIN_ALPHA 1e-4f

typedef struct microfacet {
    microfacet_type_t type;
    float alpha;
} microfacet_t;

/* The distribution's density of normals m (a unit vector, m.z > 0 for a
 * nonzero value). */
static inline float microfacet_d(const microfacet_t *d, vec3_t m)
{
    float a2 = d->alpha * d->alpha, c2 = m.z * m.z, r;
    if (d->type == MICROFACET_BECKMANN)
        r = expf(-((m.x * m.x + m.y * m.y) / a2) / c2) / (VMATH_PI * a2 * (c2 * c2));
    else {
        float t = (m.x * m.x + m.y * m.y) / a2 + c2;
        r = 1.0f / (VMATH_PI * a2 * (t * t));
    }
    return r * m.z > 1e-20f ? r : 0.0f;
}

/* Smith's shadowing of direction v by facets of normal m: 0 when v sees
 * m's back. */
static inline float microfacet_g1(const microfacet_t *d, vec3_t v, vec3_t m)
{
    if (!(vec3_dot(v, m) * v.z > 0.0f))
        return 0.0f;
    float xy = d->alpha * d->alpha * (v.x * v.x + v.y * v.y);
    if (xy == 0.0f)
        return 1.0f;
    float t2 = xy / (v.z * v.z);
    if (d->type == MICROFACET_BECKMANN) {
        float a = 1.0f / sqrtf(t2), a2 = a * a;
        return a >= 1.6f ? 1.0f : (3.535f * a + 2.181f * a2) / (1.0f + 2.276f * a + 2.577f * a2);
    }
    return 2.0f / (1.0f + sqrtf(1.0f + t2));
}

/* The shadowing whose visible normals microfacet_sample_visible draws:
 * Smith's exact G1. For GGX it is microfacet_g1; for Beckmann, G1 uses
 * Walter's fit (as Mitsuba's BSDF values do) while the sampling inverts
 * the exact one, which differs by up to about 1 % at grazing angles, so
 * the density a sample reports comes from this one. */
static inline float microfacet_g1_visible(const microfacet_t *d, vec3_t v, vec3_t m)
{
    if (d->type == MICROFACET_GGX)
        return microfacet_g1(d, v, m);
    if (!(vec3_dot(v, m) * v.z > 0.0f))
        return 0.0f;
    float xy = d->alpha * d->alpha * (v.x * v.x + v.y * v.y);
    if (xy == 0.0f)
        return 1.0f;
    float a = v.z / sqrtf(xy); /* 1 / (alpha tan theta) */
    float lambda = 0.5f * (erff(a) - 1.0f) + expf(-a * a) / (2.0f * a) * VMATH_INV_SQRT_PI;
    return 1.0f / (1.0f + lambda);
}

/* erf's inverse on (-1, 1): Giles' single-precision fit ("Approximating
 * the erfinv function", 2010), the one Mitsuba's drjit uses. */
static inline float microfacet_erfinv(float x)
{
    float w = -logf((1.0f - x) * (1.0f + x)), p;
    if (w < 5.0f) {
        w -= 2.5f;
        p = 2.81022636e-08f;
        p = 3.43273939e-07f + p * w;
        p = -3.5233877e-06f + p * w;
        p = -4.39150654e-06f + p * w;
        p = 0.00021858087f + p * w;
        p = -0.00125372503f + p * w;
        p = -0.00417768164f + p * w;
        p = 0.246640727f + p * w;
        p = 1.50140941f + p * w;
    } else {
        w = sqrtf(w) - 3.0f;
        p = -0.000200214257f;
        p = 0.000100950558f + p * w;
        p = 0.00134934322f + p * w;
        p = -0.00367342844f + p * w;
        p = 0.00573950773f + p * w;
        p = -0.0076224613f + p * w;
        p = 0.00943887047f + p * w;
        p = 1.00167406f + p * w;
        p = 2.83297682f + p * w;
    }
    return p * x;
}

static inline float microfacet_safe_sqrt(float x)
{
    return sqrtf(x > 0.0f ? x : 0.0f);
}

/* Beckmann's visible slope, its two parts: along the direction's azimuth
 * from u1 (and the direction's cosine) alone, across it from u2 alone, so
 * a grid of (u1, u2) needs each once (coat_integral). */
static inline float microfacet_beckmann_slope_x(float cos_i, float u1)
{
    float tan_i = microfacet_safe_sqrt(1.0f - cos_i * cos_i) / cos_i, cot_i = 1.0f / tan_i;
    float maxval = erff(cot_i);
    u1 = fmaxf(fminf(u1, 1.0f - 1e-6f), 1e-6f);
    float x = maxval - (maxval + 1.0f) * erff(sqrtf(-logf(u1)));
    /* tan_i * exp(-cot^2) at normal incidence is 0 * 0, not NaN */
    float tail = tan_i > 0.0f ? tan_i * expf(-cot_i * cot_i) : 0.0f;
    u1 *= 1.0f + maxval + VMATH_INV_SQRT_PI * tail;
    for (int i = 0; i < 3; i++) {
        float slope = microfacet_erfinv(x);
        float e = tan_i > 0.0f ? tan_i * expf(-slope * slope) : 0.0f;
        float value = 1.0f + x + VMATH_INV_SQRT_PI * e - u1;
        float derivative = 1.0f - slope * tan_i;
        x -= value / derivative;
    }
    return microfacet_erfinv(x);
}

static inline float microfacet_beckmann_slope_y(float u2)
{
    u2 = fmaxf(fminf(u2, 1.0f - 1e-6f), 1e-6f);
    return microfacet_erfinv(2.0f * u2 - 1.0f);
}

/* A visible slope of the distribution at alpha 1 for a direction of
 * cosine cos_i, from two uniforms. */
static inline void microfacet_visible_slope(const microfacet_t *d, float cos_i, float u1, float u2,
                                            float *sx, float *sy)
{
    if (d->type == MICROFACET_BECKMANN) {
        *sx = microfacet_beckmann_slope_x(cos_i, u1);
        *sy = microfacet_beckmann_slope_y(u2);
        return;
    }
    /* GGX: a point of the concentric disk, squeezed to the visible half */
    float x = 2.0f * u1 - 1.0f, y = 2.0f * u2 - 1.0f, px = 0.0f, py = 0.0f;
    if (x != 0.0f || y != 0.0f) {
        int q13 = fabsf(x) < fabsf(y);
        float r = q13 ? y : x, rp = q13 ? x : y;
        /* the angle in turns: (pi / 4) rp / r */
        float turn = 0.125f * (rp / r), sp, cp;
        if (q13)
            turn = 0.25f - turn;
        vmath_sincos_turn(turn, &sp, &cp);
        px = r * cp;
        py = r * sp;
    }
    float s = 0.5f * (1.0f + cos_i);
    py = microfacet_safe_sqrt(1.0f - px * px) * (1.0f - s) + py * s;
    float pz = microfacet_safe_sqrt(1.0f - px * px - py * py);
    float sin_i = microfacet_safe_sqrt(1.0f - cos_i * cos_i);
    float norm = 1.0f / (sin_i * py + cos_i * pz);
    *sx = (cos_i * py - sin_i * pz) * norm;
    *sy = px * norm;
}

/* microfacet_sample_visible in its steps: wo stretched to alpha 1 (its
 * cosine there and its azimuth's sine and cosine), then a slope there
 * (microfacet_visible_slope) turned back into a normal. */
typedef struct microfacet_stretched {
    float cos_i, sin_phi, cos_phi;
} microfacet_stretched_t;

static inline microfacet_stretched_t microfacet_stretch(const microfacet_t *d, vec3_t wo)
{
    vec3_t w = vec3_normalize(vec3_make(d->alpha * wo.x, d->alpha * wo.y, wo.z));
    microfacet_stretched_t st = {w.z, 0.0f, 1.0f};
    float sin2 = 1.0f - w.z * w.z;
    if (fabsf(sin2) > 4.0f * 0x1p-24f) {
        float inv = 1.0f / sqrtf(sin2);
        st.sin_phi = fmaxf(-1.0f, fminf(1.0f, w.y * inv));
        st.cos_phi = fmaxf(-1.0f, fminf(1.0f, w.x * inv));
    }
    return st;
}

static inline vec3_t microfacet_slope_normal(const microfacet_t *d, microfacet_stretched_t st,
                                             float sx, float sy)
{
    float tx = (st.cos_phi * sx - st.sin_phi * sy) * d->alpha;
    float ty = (st.sin_phi * sx + st.cos_phi * sy) * d->alpha;
    return vec3_normalize(vec3_make(-tx, -ty, 1.0f));
}

/* A normal m of the facets wo sees (wo.z > 0), from two uniforms: density
 * microfacet_pdf_visible. */
static inline vec3_t microfacet_sample_visible(const microfacet_t *d, vec3_t wo, float u1, float u2)
{
    microfacet_stretched_t st = microfacet_stretch(d, wo);
    float sx, sy;
    microfacet_visible_slope(d, st.cos_i, u1, u2, &sx, &sy);
    return microfacet_slope_normal(d, st, sx, sy);
}

/* The density of the normals microfacet_sample_visible gives for wo. */
static inline float microfacet_pdf_visible(const microfacet_t *d, vec3_t wo, vec3_t m)
{
    return microfacet_d(d, m) * microfacet_g1_visible(d, wo, m) * fabsf(vec3_dot(wo, m)) / wo.z;
}

/* ---- Fresnel --------------------------------------------------------------- */

/* The reflectance of a smooth dielectric interface of relative index eta
 * (inside over outside) for light at cosine cos_i, which is negative from
 * inside; *cos_t, the transmitted cosine, has the opposite sign. */
static inline float microfacet_fresnel(float cos_i, float eta, float *cos_t)
{
    float eta_it = cos_i >= 0.0f ? eta : 1.0f / eta;
    float eta_ti = cos_i >= 0.0f ? 1.0f / eta : eta;
    float ct2 = 1.0f - (1.0f - cos_i * cos_i) * (eta_ti * eta_ti);
    float ci = fabsf(cos_i), ct = microfacet_safe_sqrt(ct2);
    float r;
    if (eta == 1.0f)
        r = 0.0f;
    else if (ci == 0.0f)
        r = 1.0f;
    else {
        float as = (ci - eta_it * ct) / (ci + eta_it * ct);
        float ap = (ct - eta_it * ci) / (ct + eta_it * ci);
        r = 0.5f * (as * as + ap * ap);
    }
    *cos_t = cos_i >= 0.0f ? -ct : ct;
    return r;
}

/* The reflectance of a conductor of complex index eta + i k at cosine
 * cos_i >= 0. */
static inline float microfacet_fresnel_conductor(float cos_i, float eta, float k)
{
    float c2 = cos_i * cos_i, s2 = 1.0f - c2, s4 = s2 * s2;
    float t1 = eta * eta - k * k - s2;
    float a2pb2 = microfacet_safe_sqrt(t1 * t1 + 4.0f * k * k * eta * eta);
    float a = microfacet_safe_sqrt(0.5f * (a2pb2 + t1));
    float term1 = a2pb2 + c2, term2 = 2.0f * cos_i * a;
    float rs = (term1 - term2) / (term1 + term2);
    float term3 = a2pb2 * c2 + s4, term4 = term2 * s2;
    float rp = rs * (term3 - term4) / (term3 + term4);
    return 0.5f * (rs + rp);
}

static inline vec3_t microfacet_fresnel_conductor3(float cos_i, vec3_t eta, vec3_t k)
{
    return vec3_make(microfacet_fresnel_conductor(cos_i, eta.x, k.x),
                     microfacet_fresnel_conductor(cos_i, eta.y, k.y),
                     microfacet_fresnel_conductor(cos_i, eta.z, k.z));
}

/* The hemispherical average of the dielectric reflectance, Mitsuba's fits
 * (Egan and Hilgeman below 1, d'Eon and Irving above). */
static inline float microfacet_fresnel_diffuse_reflectance(float eta)
{
    float inv = 1.0f / eta;
    if (eta < 1.0f)
        return 0.0636f * inv + (eta * (eta * -1.4399f + 0.7099f) + 0.6681f);
    return 0.919317f +
           inv * (-3.4793f +
                  inv * (6.75335f + inv * (-7.80989f + inv * (4.98554f + inv * -1.36881f))));
}

#endif
