/* lights.c - building the scene's light distribution (see lights.h). */
#include "lights.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>

lights_status_t lights_build(scene_t *s, const double *power, double total_power,
                             const double *group_power, char *err, size_t errlen)
{
    size_t lights = 0;
    for (size_t t = 0; t < s->triangle_count; t++)
        lights += power[t] > 0;
    s->light_tris = malloc(lights * sizeof(uint32_t));
    s->light_cdf = malloc(lights * sizeof(double));
    if (!s->light_tris || !s->light_cdf) {
        snprintf(err, errlen, "out of memory for lights");
        return LIGHTS_NO_MEMORY;
    }
    double acc = 0;
    for (size_t t = 0; t < s->triangle_count; t++) {
        if (power[t] <= 0)
            continue;
        const material_t *m = &s->materials[s->tri_material[t]];
        double group = group_power ? group_power[s->tri_material[t]] : 1.0;
        acc += group_power ? power[t] / group : power[t];
        s->light_tris[s->light_count] = (uint32_t)t;
        s->light_cdf[s->light_count++] = acc / total_power;
        /* pdf per unit area of picking a point on t: (weight / total) /
         * area, the power being the area times the radiance's luminance */
        double pdf = vmath_luminance(m->radiance.x, m->radiance.y, m->radiance.z) /
                     (group_power ? group * total_power : total_power);
        s->tri_light_pdf[t] = (float)pdf;
        /* The tracer divides by this in single precision: lights whose
         * sizes differ by ~1e19 (or a light of area ~1e-38) cannot be
         * sampled there, and a wrong pdf would poison the image. */
        if (!(s->tri_light_pdf[t] > 0.0f) || !isfinite(s->tri_light_pdf[t]) ||
            !(s->light_cdf[s->light_count - 1] >
              (s->light_count > 1 ? s->light_cdf[s->light_count - 2] : 0.0))) {
            snprintf(err, errlen,
                     "light sizes out of single-precision range (light triangle %zu "
                     "has area pdf %g): rescale the scene",
                     t, pdf);
            return LIGHTS_OUT_OF_RANGE;
        }
    }
    s->light_cdf[s->light_count - 1] = 1.0;
    /* the search's guide: one bucket a light (a search then reads about
     * two entries, where a search of all reads log2 of their count, most of
     * them cache misses: 410k triangles of veach-mis.xml's emitting
     * spheres, 19 steps) */
    if (s->light_count > LIGHTS_GUIDE_MIN) {
        size_t m = s->light_count;
        s->light_guide = malloc((m + 1) * sizeof(uint32_t));
        if (!s->light_guide) {
            snprintf(err, errlen, "out of memory for lights");
            return LIGHTS_NO_MEMORY;
        }
        size_t i = 0;
        for (size_t j = 0; j <= m; j++) {
            /* the first entry above j / m (what the search of all gives) */
            const double u = (double)j / (double)m;
            while (i + 1 < s->light_count && !(s->light_cdf[i] > u))
                i++;
            s->light_guide[j] = (uint32_t)i;
        }
    }
    return LIGHTS_OK;
}
