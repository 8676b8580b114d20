/* vmath.h - small vector math for the renderer: float 3-vectors (the
 * precision Embree works in), an orthonormal basis, the thesis's luminance.
 * Header-only and inline because it sits on every ray's path. */
#ifndef VB_VMATH_H
#define VB_VMATH_H

#include <math.h>
#include <stdint.h>
#include <string.h>

#define VMATH_PI 3.14159265358979323846f
#define VMATH_INV_PI 0.31830988618379067154f
#define VMATH_INV_SQRT_PI 0.56418958354775628695f

/* The Taylor coefficients of sin and cos of (pi / 2) g in g, as floats:
 * vmath_sincos_turn's polynomials. */
#define VMATH_TURN_S1 0x1.921fb6p+0f
#define VMATH_TURN_S3 -0x1.4abbcep-1f
#define VMATH_TURN_S5 0x1.466bc6p-4f
#define VMATH_TURN_S7 -0x1.32d2ccp-8f
#define VMATH_TURN_S9 0x1.507834p-13f
#define VMATH_TURN_C2 -0x1.3bd3ccp+0f
#define VMATH_TURN_C4 0x1.03c1f0p-2f
#define VMATH_TURN_C6 -0x1.55d3c8p-6f
#define VMATH_TURN_C8 0x1.e1f506p-11f

typedef struct vec3 {
    float x, y, z;
} vec3_t;

static inline vec3_t vec3_make(float x, float y, float z)
{
    vec3_t v = {x, y, z};
    return v;
}
static inline vec3_t vec3_add(vec3_t a, vec3_t b)
{
    return vec3_make(a.x + b.x, a.y + b.y, a.z + b.z);
}
static inline vec3_t vec3_sub(vec3_t a, vec3_t b)
{
    return vec3_make(a.x - b.x, a.y - b.y, a.z - b.z);
}
static inline vec3_t vec3_mul(vec3_t a, vec3_t b)
{
    return vec3_make(a.x * b.x, a.y * b.y, a.z * b.z);
}
static inline vec3_t vec3_scale(vec3_t a, float s)
{
    return vec3_make(a.x * s, a.y * s, a.z * s);
}
static inline vec3_t vec3_neg(vec3_t a)
{
    return vec3_make(-a.x, -a.y, -a.z);
}
static inline float vec3_dot(vec3_t a, vec3_t b)
{
    return a.x * b.x + a.y * b.y + a.z * b.z;
}
static inline vec3_t vec3_cross(vec3_t a, vec3_t b)
{
    return vec3_make(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}
static inline float vec3_length(vec3_t a)
{
    return sqrtf(vec3_dot(a, a));
}
static inline vec3_t vec3_normalize(vec3_t a)
{
    return vec3_scale(a, 1.0f / vec3_length(a));
}
static inline float vec3_max_comp(vec3_t a)
{
    return fmaxf(a.x, fmaxf(a.y, a.z));
}
static inline int vec3_is_zero(vec3_t a)
{
    return a.x == 0.0f && a.y == 0.0f && a.z == 0.0f;
}
static inline int vec3_is_finite(vec3_t a)
{
    return isfinite(a.x) && isfinite(a.y) && isfinite(a.z);
}

/* sin and cos of 2 pi u, u in [-1/8, 1) (past 1 too, a turn being a
 * turn, while 4u is exact): the quarter turn u falls in, and
 * the rest, g in [-1/2, 1/2) of a quarter turn (both exact: 4u and the
 * subtractions are), into degree-9 and degree-8 polynomials, within
 * 1e-7 of the true values. Only IEEE additions and multiplications in a
 * fixed order, so the wavefront kernel's vector copy of it
 * (wave_diffuse.c) gives the same bits, on every host (libm's sinf and
 * cosf are calls, one lane at a time, and pick an FMA variant where the
 * CPU has FMA). */
static inline void vmath_sincos_turn(float u, float *s, float *c)
{
    float x = 4.0f * u;
    int q = (int)x;
    float f = x - (float)q;
    int up = f >= 0.5f;
    float g = up ? f - 1.0f : f, g2 = g * g;
    q = (q + up) & 3;
    float ps =
        g *
        (VMATH_TURN_S1 +
         g2 * (VMATH_TURN_S3 + g2 * (VMATH_TURN_S5 + g2 * (VMATH_TURN_S7 + g2 * VMATH_TURN_S9))));
    float pc = 1.0f + g2 * (VMATH_TURN_C2 +
                            g2 * (VMATH_TURN_C4 + g2 * (VMATH_TURN_C6 + g2 * VMATH_TURN_C8)));
    *s = q == 0 ? ps : q == 1 ? pc : q == 2 ? -ps : -pc;
    *c = q == 0 ? pc : q == 1 ? -ps : q == 2 ? -pc : ps;
}

/* The point at barycentrics (u, v) of triangle (a, b, c): (1-u-v) a + u b + v c. */
static inline vec3_t vec3_barycentric(vec3_t a, vec3_t b, vec3_t c, float u, float v)
{
    float w = 1.0f - u - v;
    return vec3_make(w * a.x + u * b.x + v * c.x, w * a.y + u * b.y + v * c.y,
                     w * a.z + u * b.z + v * c.z);
}

/* Luminance as the thesis defines it (P = 0.3 R + 0.59 G + 0.11 B); used for
 * every per-pixel statistic and for light selection. */
static inline double vmath_luminance(double r, double g, double b)
{
    return 0.3 * r + 0.59 * g + 0.11 * b;
}

/* Orthonormal basis around unit n (Duff et al. 2017, branchless). */
static inline void vec3_onb(vec3_t n, vec3_t *t, vec3_t *b)
{
    float sign = copysignf(1.0f, n.z);
    float a = -1.0f / (sign + n.z);
    float c = n.x * n.y * a;
    *t = vec3_make(1.0f + sign * n.x * n.x * a, sign * c, -sign * n.x);
    *b = vec3_make(c, sign + n.y * n.y * a, -n.y);
}

/* Offsets a surface point along the geometric normal n (pointing to the side
 * the new ray leaves on) by a few ulps of the point's own magnitude (Wachter
 * and Binder, Ray Tracing Gems ch. 6). A fixed epsilon fails at some scene
 * scale; this stays correct from 1e-3 to 1e9. 16 ulps, not their 256: a
 * hit point here is a barycentric blend of float vertices, a few ulps off
 * its plane, and 256 ulps of a coordinate near 1e6 is 16 scene units, which
 * moved the Cornell box's contact shadows by 8 % of a 4x4 block (30 % of a
 * pixel) once the box was translated by 1e6 (test_cornell_any_scale). */
static inline float vmath_offset_coord(float p, float n)
{
    const float origin = 1.0f / 32.0f, float_scale = 1.0f / 65536.0f, int_scale = 16.0f;
    if (fabsf(p) < origin)
        return p + float_scale * n;
    int32_t of = (int32_t)(int_scale * n);
    int32_t bits;
    memcpy(&bits, &p, sizeof bits);
    bits += (p < 0.0f) ? -of : of;
    float r;
    memcpy(&r, &bits, sizeof r);
    return r;
}

static inline vec3_t vec3_offset_ray_origin(vec3_t p, vec3_t n)
{
    return vec3_make(vmath_offset_coord(p.x, n.x), vmath_offset_coord(p.y, n.y),
                     vmath_offset_coord(p.z, n.z));
}

#endif
