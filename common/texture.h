/* texture.h - what a textured material's albedo is where a path hits it
 * (scene_t.textures). Inline: the tracer looks it up at every hit on a
 * textured surface, and both engines call this one function, so their
 * bits agree. An untextured material costs one compare. */
#ifndef VB_TEXTURE_H
#define VB_TEXTURE_H

#include <math.h>
#include <stdint.h>

#include "scene.h"

/* Texel coordinate i of a side of n texels, wrapped as t says (drjit's
 * texture rules, which Mitsuba's bitmap uses). */
static inline int texture_wrap(int i, int n, texture_wrap_t t)
{
    if (t == TEXTURE_WRAP_CLAMP)
        return i < 0 ? 0 : i >= n ? n - 1 : i;
    if (t == TEXTURE_WRAP_MIRROR) {
        int m = i % (2 * n);
        if (m < 0)
            m += 2 * n;
        return m >= n ? 2 * n - 1 - m : m;
    }
    int m = i % n;
    return m < 0 ? m + n : m;
}

static inline vec3_t texture_texel(const texture_t *t, int x, int y)
{
    const float *p = t->rgb + 3 * ((size_t)texture_wrap(y, t->height, t->wrap) * t->width +
                                   texture_wrap(x, t->width, t->wrap));
    return vec3_make(p[0], p[1], p[2]);
}

/* A bitmap at (su, sv): the nearest texel, or bilinear between the four
 * around (texel centres at half-integers). Coordinates far outside the
 * image (beyond +-2^24) are clamped first, so the integer conversion is
 * defined. */
static inline vec3_t texture_bitmap(const texture_t *t, float su, float sv)
{
    su = fminf(fmaxf(su, -16777216.0f), 16777216.0f);
    sv = fminf(fmaxf(sv, -16777216.0f), 16777216.0f);
    float fx = su * (float)t->width, fy = sv * (float)t->height;
    if (t->nearest)
        return texture_texel(t, (int)floorf(fx), (int)floorf(fy));
    fx -= 0.5f;
    fy -= 0.5f;
    float x0 = floorf(fx), y0 = floorf(fy), tx = fx - x0, ty = fy - y0;
    int x = (int)x0, y = (int)y0;
    vec3_t a = texture_texel(t, x, y), b = texture_texel(t, x + 1, y);
    vec3_t c = texture_texel(t, x, y + 1), d = texture_texel(t, x + 1, y + 1);
    vec3_t top = vec3_add(vec3_scale(a, 1.0f - tx), vec3_scale(b, tx));
    vec3_t bottom = vec3_add(vec3_scale(c, 1.0f - tx), vec3_scale(d, tx));
    return vec3_add(vec3_scale(top, 1.0f - ty), vec3_scale(bottom, ty));
}

/* Texture `index` of the scene at barycentric (u, v) of triangle tri
 * (the scene has texture coordinates). */
static inline vec3_t texture_at(const scene_t *s, int32_t index, uint32_t tri, float u, float v)
{
    const texture_t *t = &s->textures[index];
    const uint32_t *vi = s->indices + 3 * tri;
    const float *a = s->uvs + 2 * vi[0], *b = s->uvs + 2 * vi[1], *c = s->uvs + 2 * vi[2];
    float w = 1.0f - u - v;
    float tu = w * a[0] + u * b[0] + v * c[0], tv = w * a[1] + u * b[1] + v * c[1];
    float su = t->to_uv[0] * tu + t->to_uv[1] * tv + t->to_uv[2];
    float sv = t->to_uv[3] * tu + t->to_uv[4] * tv + t->to_uv[5];
    if (t->kind == TEXTURE_BITMAP)
        return texture_bitmap(t, su, sv);
    /* Mitsuba's checkerboard: which half of its period each coordinate is in */
    int hu = su - floorf(su) > 0.5f, hv = sv - floorf(sv) > 0.5f;
    return hu == hv ? t->color0 : t->color1;
}

/* The albedo of material m at barycentric (u, v) of triangle tri. */
static inline vec3_t texture_albedo(const scene_t *s, const material_t *m, uint32_t tri, float u,
                                    float v)
{
    if (m->albedo_texture < 0 || !s->uvs)
        return m->albedo;
    return texture_at(s, m->albedo_texture, tri, u, v);
}

#endif
