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

/* The light whose share of the cumulative power holds u in [0, 1): a
 * binary search in light_cdf. Returns a triangle index. */
static inline uint32_t lights_pick(const scene_t *s, double u)
{
    size_t lo = 0, hi = s->light_count - 1;
    while (lo < hi) {
        size_t mid = (lo + hi) / 2;
        if (s->light_cdf[mid] > u)
            hi = mid;
        else
            lo = mid + 1;
    }
    return s->light_tris[lo];
}

/* Picks a light by power with u and a point *q on it with (u1, u2);
 * returns its triangle. The density of *q is lights_area_pdf per area. */
static inline uint32_t lights_sample(const scene_t *s, double u, float u1, float u2, vec3_t *q)
{
    uint32_t tri = lights_pick(s, u);
    *q = scene_sample_point(s, tri, u1, u2);
    return tri;
}

/* Density per unit area with which lights_sample gives a point on tri
 * (0 for a triangle that is not a light). Callers turn it into a
 * solid-angle density as pdf * distance^2 / cos at the light. */
static inline float lights_area_pdf(const scene_t *s, uint32_t tri)
{
    return s->tri_light_pdf[tri];
}

#endif
