/* texture.h - what a textured material's albedo is where a path hits it
 * (scene_t.textures). Inline: the tracer looks it up at every hit on a
 * textured surface, and both engines call this one function, so their
 * bits agree. An untextured material costs one compare. */
#ifndef VB_TEXTURE_H
#define VB_TEXTURE_H

#include <math.h>
#include <stdint.h>

#include "scene.h"

/* The albedo of material m at barycentric (u, v) of triangle tri. */
static inline vec3_t texture_albedo(const scene_t *s, const material_t *m, uint32_t tri, float u,
                                    float v)
{
    if (m->albedo_texture < 0 || !s->uvs)
        return m->albedo;
    const texture_t *t = &s->textures[m->albedo_texture];
    const uint32_t *vi = s->indices + 3 * tri;
    const float *a = s->uvs + 2 * vi[0], *b = s->uvs + 2 * vi[1], *c = s->uvs + 2 * vi[2];
    float w = 1.0f - u - v;
    float tu = w * a[0] + u * b[0] + v * c[0], tv = w * a[1] + u * b[1] + v * c[1];
    float su = t->to_uv[0] * tu + t->to_uv[1] * tv + t->to_uv[2];
    float sv = t->to_uv[3] * tu + t->to_uv[4] * tv + t->to_uv[5];
    /* Mitsuba's checkerboard: which half of its period each coordinate is in */
    int hu = su - floorf(su) > 0.5f, hv = sv - floorf(sv) > 0.5f;
    return hu == hv ? t->color0 : t->color1;
}

#endif
