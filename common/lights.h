/* lights.h - the scene's lights: its emissive triangles, chosen in
 * proportion to their power, and a uniform point on the one chosen.
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
 * total_power (> 0 and finite). Returns LIGHTS_OK, or a failure with a
 * message in err; what was allocated is in s either way, for
 * scene_destroy. */
lights_status_t lights_build(scene_t *s, const double *power, double total_power, char *err,
                             size_t errlen);

/* The index (into light_tris, light_cdf) of the light whose share of the
 * cumulative power holds u in [0, 1): a binary search in light_cdf. */
static inline size_t lights_pick_index(const scene_t *s, double u)
{
    size_t lo = 0, hi = s->light_count - 1;
    while (lo < hi) {
        size_t mid = (lo + hi) / 2;
        if (s->light_cdf[mid] > u)
            hi = mid;
        else
            lo = mid + 1;
    }
    return lo;
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
    double lo = i ? s->light_cdf[i - 1] : 0.0, hi = s->light_cdf[i];
    float u1 = (float)((u - lo) / (hi - lo));
    if (!(u1 < 1.0f)) /* rounded up to 1 (or u outside [lo, hi)) */
        u1 = 0x1.fffffep-1f;
    if (!(u1 >= 0.0f))
        u1 = 0.0f;
    uint32_t tri = s->light_tris[i];
    *q = scene_sample_point(s, tri, u1, u2);
    return tri;
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

/* A direction uniform on the sphere (density 1 / (4 pi)) from two numbers. */
static inline vec3_t lights_env_direction(double u1, float u2)
{
    float z = (float)(1.0 - 2.0 * u1);
    float r = sqrtf(fmaxf(0.0f, 1.0f - z * z)), phi = 2.0f * VMATH_PI * u2;
    return vec3_make(r * cosf(phi), r * sinf(phi), z);
}

/* Density per unit area with which lights_sample gives a point on tri
 * (0 for a triangle that is not a light). Callers turn it into a
 * solid-angle density as pdf * distance^2 / cos at the light. */
static inline float lights_area_pdf(const scene_t *s, uint32_t tri)
{
    return s->tri_light_pdf[tri];
}

#endif
