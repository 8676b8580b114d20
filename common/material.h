/* material.h - the four materials a scene may use, and their BSDFs.
 *
 * diffuse (Lambertian albedo), emitter (one-sided RGB radiance on the side
 * of the triangle's geometric normal, over an optional diffuse albedo that
 * is black unless given), mirror (perfect
 * specular reflection, RGB reflectance) and dielectric (smooth glass with
 * exact Fresnel, index of refraction). Nothing more until a scene needs it.
 * Directions are in world space; n is the shading normal. */
#ifndef VB_MATERIAL_H
#define VB_MATERIAL_H

#include "vmath.h"

typedef enum {
    MATERIAL_DIFFUSE = 0,
    MATERIAL_EMITTER,
    MATERIAL_MIRROR,
    MATERIAL_DIELECTRIC
} material_type_t;

#define MATERIAL_NAME_LEN 64

typedef struct material {
    char name[MATERIAL_NAME_LEN];
    material_type_t type;
    vec3_t albedo;   /* diffuse albedo (emitters too), or mirror reflectance */
    vec3_t radiance; /* emitter only */
    float ior;       /* dielectric only: inside over outside */
} material_t;

/* "diffuse", "emitter", ...; returns -1 for an unknown name. */
int material_type_from_name(const char *name);
const char *material_type_name(material_type_t type);

/* Cosine-weighted direction about n from two uniforms; pdf = cos / pi. */
static inline vec3_t material_sample_cosine(vec3_t n, float u1, float u2)
{
    float r = sqrtf(u1), phi = 2.0f * VMATH_PI * u2;
    float x = r * cosf(phi), y = r * sinf(phi);
    float z = sqrtf(fmaxf(0.0f, 1.0f - u1));
    vec3_t t, b;
    vec3_onb(n, &t, &b);
    return vec3_add(vec3_add(vec3_scale(t, x), vec3_scale(b, y)), vec3_scale(n, z));
}

static inline vec3_t material_reflect(vec3_t wo, vec3_t n)
{
    return vec3_sub(vec3_scale(n, 2.0f * vec3_dot(wo, n)), wo);
}

/* Fresnel reflectance of a smooth dielectric for unpolarised light.
 * cos_i > 0 is the cosine on the incident side, eta = eta_t / eta_i.
 * Sets *cos_t (positive) when light is transmitted; returns 1 at total
 * internal reflection. */
static inline float material_fresnel(float cos_i, float eta, float *cos_t)
{
    float sin2_t = (1.0f - cos_i * cos_i) / (eta * eta);
    if (sin2_t >= 1.0f) {
        *cos_t = 0.0f;
        return 1.0f;
    }
    float ct = sqrtf(1.0f - sin2_t);
    float r_par = (eta * cos_i - ct) / (eta * cos_i + ct);
    float r_perp = (cos_i - eta * ct) / (cos_i + eta * ct);
    *cos_t = ct;
    return 0.5f * (r_par * r_par + r_perp * r_perp);
}

#endif
