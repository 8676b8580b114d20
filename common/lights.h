/* lights.h - the scene's lights: its emissive triangles, each emitting
 * material one emitter picked alike and a triangle of it by power (or all
 * by power, one material alone), and a uniform point on the one chosen.
 *
 * lights_build turns the per-triangle power the loader measured into the
 * distribution the scene keeps (light_tris, light_cdf, light_count and the
 * per-triangle area pdf tri_light_pdf); the scene owns those arrays, so a
 * loaded scene stays one immutable block that any thread reads. Sampling
 * is inline here because it runs once per bounce of every path. */
#ifndef VB_LIGHTS_H
#define VB_LIGHTS_H

#include <math.h>
#include <stddef.h>
#include <stdint.h>

#include "scene.h"
#include "vmath.h"

/* What lights_build returns. */
typedef enum {
    LIGHTS_OK = 0,
    LIGHTS_NO_MEMORY = -1,
    /* an area pdf does not fit a float: the scene must be rescaled */
    LIGHTS_OUT_OF_RANGE = -2
} lights_status_t;

/* Builds the light distribution of s from power[t], the emitted power of
 * each of s's triangle_count triangles (0 for a non-light), and their sum
 * total_power (> 0 and finite). With group_power (one entry a material:
 * the power of its triangles, 0 for a non-light), each emitting material
 * is one group of the total_power groups, picked alike, and a triangle
 * of it by power within it (Mitsuba 3 picks its emitters alike, and a
 * point on the one picked by area). Returns LIGHTS_OK, or a failure with a
 * message in err; what was allocated is in s either way, for
 * scene_destroy. */
lights_status_t lights_build(scene_t *s, const double *power, double total_power,
                             const double *group_power, char *err, size_t errlen);

/* The first entry of cdf[0..n) (ascending, the last 1) above u: a binary
 * search. */
static inline size_t lights_cdf_search(const double *cdf, size_t n, double u)
{
    size_t lo = 0, hi = n - 1;
    while (lo < hi) {
        size_t mid = (lo + hi) / 2;
        if (cdf[mid] > u)
            hi = mid;
        else
            lo = mid + 1;
    }
    return lo;
}

/* The fewest lights that get a search guide (scene_t.light_guide). */
#define LIGHTS_GUIDE_MIN 16
/* The emitting spheres a light sample tests by their CDF ranges before it
 * searches (lights_sample_from). */
#define LIGHTS_SPHERE_SCAN 8

/* The index (into light_tris, light_cdf) of the light whose share of the
 * cumulative power holds u in [0, 1): lights_cdf_search's answer. With a
 * guide, the search runs between the entries its bucket of u gives, and
 * the answer is checked (the first entry above u, or the last): a u
 * whose bucket rounding put it a bucket off is searched over all. */
static inline size_t lights_pick_index(const scene_t *s, double u)
{
    const size_t n = s->light_count; /* the guide's buckets too */
    if (s->light_guide && u >= 0.0 && u < 1.0) {
        size_t j = (size_t)(u * (double)n);
        j = j < n ? j : n - 1;
        size_t lo = s->light_guide[j], hi = s->light_guide[j + 1];
        while (lo < hi) {
            size_t mid = (lo + hi) / 2;
            if (s->light_cdf[mid] > u)
                hi = mid;
            else
                lo = mid + 1;
        }
        if ((lo == n - 1 || s->light_cdf[lo] > u) && (lo == 0 || !(s->light_cdf[lo - 1] > u)))
            return lo;
    }
    return lights_cdf_search(s->light_cdf, n, u);
}

/* lights_sample's point on light i, the one u picked (below). The diffuse
 * kernel (wave_diffuse.c) does the same operations in vectors in a scene
 * without emitting spheres: a change here goes there too (test_tracer's
 * engines_agree compares the two). */
static inline vec3_t lights_point_on(const scene_t *s, size_t i, double u, float u2)
{
    double lo = i ? s->light_cdf[i - 1] : 0.0, hi = s->light_cdf[i];
    float u1 = (float)((u - lo) / (hi - lo));
    if (!(u1 < 1.0f)) /* rounded up to 1 (or u outside [lo, hi)) */
        u1 = 0x1.fffffep-1f;
    if (!(u1 >= 0.0f))
        u1 = 0.0f;
    return scene_sample_point(s, s->light_tris[i], u1, u2);
}

/* Picks a light by power and a point *q on it, uniform by area, from two
 * numbers, as Mitsuba 3 and pbrt do; returns its triangle. u picks the
 * light, and where it fell within that light's share of the power,
 * rescaled to [0, 1), is the point's first number (u2 the second). A
 * stratified pair (u, u2) then stratifies the points over all the lights
 * together (a quad light's two triangles as one); a number of its own for
 * the pick left each triangle's points stratified on their own: 2 to 4 %
 * more relMSE on the Cornell box (256 and 1024 spp) and dark-bright (256).
 * u is a double, so the rescaled number keeps a float's 24 bits for any
 * light count below 2^29.
 * The density of *q is lights_area_pdf per area. */
static inline uint32_t lights_sample(const scene_t *s, double u, float u2, vec3_t *q)
{
    size_t i = lights_pick_index(s, u);
    *q = lights_point_on(s, i, u, u2);
    return s->light_tris[i];
}

/* Whether a light sample's first number u takes the environment: then u
 * is rescaled to [0, 1) for lights_env_direction; else, in a scene with
 * an environment, to [0, 1) for lights_sample. In a scene without one, u
 * is left as it is (the triangles' samples keep their bits). */
static inline int lights_pick_env(const scene_t *s, double *u)
{
    if (!s->has_env)
        return 0;
    double pe = s->env_pick;
    if (*u < pe) {
        *u = *u / pe;
        return 1;
    }
    *u = (*u - pe) / (1.0 - pe);
    return 0;
}

/* After lights_pick_env said no: whether the sample takes a light with no
 * area; then *k is which and its probability of being picked is *pick
 * (the environment's share included), else u is rescaled to [0, 1) for
 * lights_sample. A scene without such lights leaves u as it is. */
static inline int lights_pick_delta(const scene_t *s, double *u, size_t *k, float *pick)
{
    if (!s->delta_count)
        return 0;
    double pd = s->delta_pick;
    if (!(*u < pd)) {
        *u = (*u - pd) / (1.0 - pd);
        return 0;
    }
    double v = *u / pd;
    *k = lights_cdf_search(s->delta_cdf, s->delta_count, v);
    double share = s->delta_cdf[*k] - (*k ? s->delta_cdf[*k - 1] : 0.0);
    *pick = (float)((s->has_env ? 1.0 - s->env_pick : 1.0) * pd * share);
    return 1;
}

/* Light k (a light with no area) seen from p: the direction toward it,
 * the radiance-times-solid-angle it delivers (intensity / distance^2 with
 * the spot's falloff, or the irradiance), and the end of the shadow
 * segment (its position, or far outside the scene). 0 when it gives p
 * nothing (p on the light, outside the spot's cone). */
static inline int lights_delta_sample(const scene_t *s, size_t k, vec3_t p, vec3_t *wl,
                                      vec3_t *light, vec3_t *target)
{
    const scene_light_t *l = &s->delta_lights[k];
    if (l->kind == SCENE_LIGHT_DIRECTIONAL) {
        *wl = vec3_neg(l->direction);
        *light = l->intensity;
        *target = vec3_add(p, vec3_scale(*wl, s->env_distance));
        return 1;
    }
    vec3_t to = vec3_sub(l->position, p);
    float d2 = vec3_dot(to, to);
    if (!(d2 > 0.0f))
        return 0;
    *wl = vec3_scale(to, 1.0f / sqrtf(d2));
    float falloff = 1.0f;
    if (l->kind == SCENE_LIGHT_SPOT) {
        float c = -vec3_dot(*wl, l->direction);
        if (!(c > l->cos_cutoff))
            return 0;
        if (c < l->cos_beam)
            falloff = (l->cutoff - acosf(fminf(c, 1.0f))) * l->inv_transition;
    }
    *light = vec3_scale(l->intensity, falloff / d2);
    *target = l->position;
    return 1;
}

/* A direction uniform on the sphere (density 1 / (4 pi)) from two numbers. */
static inline vec3_t lights_env_direction(double u1, float u2)
{
    float z = (float)(1.0 - 2.0 * u1);
    float r = sqrtf(fmaxf(0.0f, 1.0f - z * z)), sp, cp;
    vmath_sincos_turn(u2, &sp, &cp);
    return vec3_make(r * cp, r * sp, z);
}

/* ---- the environment map (scene_t.env_map) ---- */

static inline vec3_t lights_env_mul(const float m[9], vec3_t v)
{
    return vec3_make(m[0] * v.x + m[1] * v.y + m[2] * v.z, m[3] * v.x + m[4] * v.y + m[5] * v.z,
                     m[6] * v.x + m[7] * v.y + m[8] * v.z);
}

/* The map's coordinates of a local direction, as Mitsuba's envmap reads
 * them: x in [0, env_w) across the columns (pixel centres on the
 * integers, half a pixel from the seam), y in [0, env_h - 1] down from the
 * pole (+y) to the other; *cx, *cy the cell. */
static inline void lights_env_xy(const scene_t *s, vec3_t l, float *x, float *y, int *cx, int *cy)
{
    float u = atan2f(l.x, -l.z) * (0.5f * VMATH_INV_PI);
    float v = acosf(fminf(1.0f, fmaxf(-1.0f, l.y))) * VMATH_INV_PI;
    u -= 0.5f / (float)s->env_w;
    u -= floorf(u);
    *x = u * (float)s->env_w;
    *y = v * (float)(s->env_h - 1);
    int ix = (int)*x, iy = (int)*y;
    *cx = ix < s->env_w - 1 ? ix : s->env_w - 1;
    *cy = iy < s->env_h - 2 ? iy : s->env_h - 2;
}

/* The radiance at the map's coordinates (x, y) in cell (cx, cy)
 * (lights_env_xy), bilinear between pixel centres, and into *pdf the
 * density of a light sample there, at sin theta from the poles. */
static inline vec3_t lights_env_cell(const scene_t *s, float x, float y, int cx, int cy,
                                     float sin_theta, float *pdf)
{
    *pdf = s->env_pick * s->env_cell_pdf[(size_t)cy * (size_t)s->env_w + (size_t)cx] /
           (2.0f * VMATH_PI * VMATH_PI * sin_theta);
    float wx = x - (float)cx, wy = y - (float)cy;
    size_t row = (size_t)s->env_w + 1;
    const float *p00 = s->env_rgb + 3 * ((size_t)cy * row + (size_t)cx), *p01 = p00 + 3 * row;
    float c[3];
    for (int k = 0; k < 3; k++) {
        float top = (1.0f - wx) * p00[k] + wx * p00[3 + k];
        float bottom = (1.0f - wx) * p01[k] + wx * p01[3 + k];
        c[k] = (1.0f - wy) * top + wy * bottom;
    }
    return vec3_make(c[0], c[1], c[2]);
}

/* Radiance arriving from world direction d (unit length), and into *pdf
 * the solid-angle density with which a light sample gives d: the
 * environment's pick times its own density. One lookup of the map's cell
 * serves both. */
static inline vec3_t lights_env_eval(const scene_t *s, vec3_t d, float *pdf)
{
    if (!s->env_map) {
        *pdf = s->env_pdf;
        return s->env_radiance;
    }
    vec3_t l = lights_env_mul(s->env_to_local, d);
    float x, y;
    int cx, cy;
    lights_env_xy(s, l, &x, &y, &cx, &cy);
    float sin_theta = sqrtf(fmaxf(l.x * l.x + l.z * l.z, 1e-12f));
    return lights_env_cell(s, x, y, cx, cy, sin_theta, pdf);
}

/* lights_env_eval's radiance alone, and its density alone. */
static inline vec3_t lights_env_radiance(const scene_t *s, vec3_t d)
{
    float pdf;
    return lights_env_eval(s, d, &pdf);
}

static inline float lights_env_pdf(const scene_t *s, vec3_t d)
{
    float pdf;
    lights_env_eval(s, d, &pdf);
    return pdf;
}

/* Where u in [0, 1) falls in cdf[0..n) (last entry 1), and its place
 * within that entry's share, rescaled to [0, 1). */
static inline size_t lights_cdf_pick(const double *cdf, size_t n, double u, double *rest)
{
    size_t lo = lights_cdf_search(cdf, n, u);
    double a = lo ? cdf[lo - 1] : 0.0, b = cdf[lo];
    double r = b > a ? (u - a) / (b - a) : 0.5;
    *rest = r < 0.0 ? 0.0 : r < 1.0 ? r : 0x1.fffffffffffffp-1;
    return lo;
}

/* A world direction toward the environment from two numbers, its density
 * and the radiance from it (what lights_env_eval gives for it, up to
 * rounding): the constant one uniform on the sphere; a map by cell (u1
 * picks the row, its rest the column, that rest the place across it), u2
 * the place down the cell. Its sines and cosines are vmath_sincos_turn's
 * (libm's were calls, and FMA variants on some hosts). */
static inline vec3_t lights_env_sample(const scene_t *s, double u1, float u2, float *pdf,
                                       vec3_t *radiance)
{
    if (!s->env_map) {
        *pdf = s->env_pdf;
        *radiance = s->env_radiance;
        return lights_env_direction(u1, u2);
    }
    size_t w = (size_t)s->env_w;
    double r1, r2;
    size_t j = lights_cdf_pick(s->env_row_cdf, (size_t)s->env_h - 1, u1, &r1);
    size_t i = lights_cdf_pick(s->env_col_cdf + j * w, w, r1, &r2);
    float u = (float)(((double)i + r2) / (double)w) + 0.5f / (float)s->env_w;
    float v = ((float)j + u2) / (float)(s->env_h - 1);
    float st, ct, sp, cp;
    vmath_sincos_turn(0.5f * v, &st, &ct);
    vmath_sincos_turn(u, &sp, &cp);
    vec3_t l = vec3_make(sp * st, ct, -cp * st);
    vec3_t d = vec3_normalize(lights_env_mul(s->env_to_world, l));
    /* the cell and the place in it are known: lights_env_eval's lookup
     * without going back from d through atan2 and acos (a tenth of a
     * render under a map) */
    float x = (float)((double)i + r2), y = (float)j + u2;
    *radiance = lights_env_cell(s, x, y, (int)i, (int)j, fmaxf(st, 1e-6f), pdf);
    return d;
}

/* Density per unit area with which lights_sample gives a point on tri
 * (0 for a triangle that is not a light). Callers turn it into a
 * solid-angle density as pdf * distance^2 / cos at the light. */
static inline float lights_area_pdf(const scene_t *s, uint32_t tri)
{
    return s->tri_light_pdf[tri];
}

/* The cone sphere sp subtends from p: its axis toward the centre, the
 * distance to the centre, and 1 - cos of its half angle (exact for tiny
 * angles: sin^2 / (1 + cos)). 0 when p is inside the sphere. */
static inline int lights_sphere_cone(const scene_sphere_t *sp, vec3_t p, vec3_t *axis, float *dc,
                                     float *one_minus_cos)
{
    vec3_t to = vec3_sub(sp->center, p);
    float d2 = vec3_dot(to, to), r2 = sp->radius * sp->radius;
    if (!(d2 > r2))
        return 0;
    *dc = sqrtf(d2);
    *axis = vec3_scale(to, 1.0f / *dc);
    float sin2 = r2 / d2, cos_max = sqrtf(1.0f - sin2);
    *one_minus_cos = sin2 / (1.0f + cos_max);
    return 1;
}

/* The solid-angle density with which a light sample from p takes a
 * direction toward emitting sphere k (0 from inside it). */
static inline float lights_sphere_pdf(const scene_t *s, int32_t k, vec3_t p)
{
    const scene_sphere_t *sp = &s->spheres[k];
    vec3_t axis;
    float dc, omc;
    if (!lights_sphere_cone(sp, p, &axis, &dc, &omc))
        return 0.0f;
    return sp->pick / (2.0f * VMATH_PI * omc);
}

/* The solid-angle density with which a light sample from o would have
 * found the point at distance t on light triangle tri, hit at cosine
 * cos_l (> 0) along a unit direction: by area, or through the cone of
 * the sphere it belongs to. */
static inline float lights_hit_pdf(const scene_t *s, uint32_t tri, vec3_t o, float t, float cos_l)
{
    if (s->tri_sphere && s->tri_sphere[tri] >= 0)
        return lights_sphere_pdf(s, s->tri_sphere[tri], o);
    return lights_area_pdf(s, tri) * t * t / cos_l;
}

/* The share of a shadow segment its test may leave out at its end, at
 * least tracer_priv.h's 1 - TRACER_SHADOW_TFAR: a segment that stops at a
 * sphere's clear ball must still be tested up to where that ball is
 * clear. */
#define LIGHTS_SHADOW_SLACK 0x1p-16f

/* lights_sample from p: a light (*light_tri, one of its triangles) and a
 * point *q on it, its normal *nl, and
 * *area_pdf, the density per area at q (for a triangle lights_area_pdf;
 * for a sphere's, a direction in the cone from p, its nearest point on
 * the sphere, and the cone's density turned per area), and *target, where
 * the shadow ray toward q may end: q lifted off the light
 * (vec3_offset_ray_origin), or, toward a sphere with a clear ball
 * (scene_sphere_t.clear_radius), where the ray is well inside that ball:
 * nothing else is there and the sphere's faces lie inside the surface
 * the ray meets at q, so the test gives the same answer at a fraction of
 * the walk through the sphere's faces (veach-mis.xml: 1.35-1.45x the samples/s).
 * 0 when the light gives p nothing (p inside an emitting sphere). */
static inline int lights_sample_from(const scene_t *s, vec3_t p, double u, float u2, vec3_t *q,
                                     vec3_t *nl, float *area_pdf, uint32_t *light_tri,
                                     vec3_t *target)
{
    /* An emitting sphere's triangles are consecutive in the light CDF: u
     * in its range would pick one of them, and only the sphere matters
     * (its cone is sampled, the triangle gives its material). The first
     * LIGHTS_SPHERE_SCAN spheres are found by their ranges, without the
     * search's cache misses among all their triangles' entries (in
     * veach-mis.xml's direct render about 10 % of the time was the
     * search, 12 % the triangle's point, which a sphere discards). */
    int32_t k = -1;
    for (size_t j = 0; j < s->sphere_count && j < LIGHTS_SPHERE_SCAN; j++)
        if (u >= s->spheres[j].cdf_lo && u < s->spheres[j].cdf_hi) {
            k = (int32_t)j;
            break;
        }
    uint32_t tri;
    if (k >= 0) {
        tri = s->spheres[k].light_tri;
    } else {
        size_t i = lights_pick_index(s, u);
        tri = s->light_tris[i];
        k = s->tri_sphere ? s->tri_sphere[tri] : -1;
        if (k < 0) {
            *light_tri = tri;
            *q = lights_point_on(s, i, u, u2);
            *nl = s->tri_normal[tri];
            *area_pdf = lights_area_pdf(s, tri);
            *target = vec3_offset_ray_origin(*q, *nl);
            return 1;
        }
    }
    *light_tri = tri;
    const scene_sphere_t *sp = &s->spheres[k];
    vec3_t axis;
    float dc, omc;
    if (!lights_sphere_cone(sp, p, &axis, &dc, &omc))
        return 0;
    /* the first number, rescaled over the whole sphere's share */
    float u1 = (float)((u - sp->cdf_lo) / (sp->cdf_hi - sp->cdf_lo));
    u1 = u1 < 0.0f ? 0.0f : u1 >= 1.0f ? 0x1.fffffep-1f : u1;
    float one_minus_cos_t = u1 * omc, cos_t = 1.0f - one_minus_cos_t;
    float sin2_t = one_minus_cos_t * (2.0f - one_minus_cos_t);
    float sin_t = sqrtf(sin2_t > 0.0f ? sin2_t : 0.0f), sin_p, cos_p;
    vmath_sincos_turn(u2, &sin_p, &cos_p);
    vec3_t t, b;
    vec3_onb(axis, &t, &b);
    vec3_t d = vec3_add(vec3_add(vec3_scale(t, sin_t * cos_p), vec3_scale(b, sin_t * sin_p)),
                        vec3_scale(axis, cos_t));
    /* the nearest intersection of p + x d with the sphere */
    float r2 = sp->radius * sp->radius, disc = r2 - dc * dc * sin2_t;
    float x = dc * cos_t - sqrtf(disc > 0.0f ? disc : 0.0f);
    *q = vec3_add(p, vec3_scale(d, x));
    *nl = vec3_normalize(vec3_sub(*q, sp->center));
    float cos_l = -vec3_dot(*nl, d);
    if (!(cos_l > 0.0f) || !(x > 0.0f))
        return 0;
    *area_pdf = sp->pick / (2.0f * VMATH_PI * omc) * cos_l / (x * x);
    /* the ray's end: where it enters the ball midway between the sphere
     * and its clear radius, when the part of the segment the test leaves
     * out (LIGHTS_SHADOW_SLACK of it) stays inside the clear ball */
    float clear = sp->clear_radius, mid = 0.5f * (sp->radius + clear);
    float disc_mid = mid * mid - dc * dc * sin2_t;
    float x_mid = dc * cos_t - sqrtf(disc_mid > 0.0f ? disc_mid : 0.0f);
    if (clear > 0.0f && x_mid > 0.0f && x_mid < x && x_mid * LIGHTS_SHADOW_SLACK < clear - mid)
        *target = vec3_add(p, vec3_scale(d, x_mid));
    else
        *target = vec3_offset_ray_origin(*q, *nl);
    return 1;
}

#endif
