/* material.h - the four materials a scene may use, and their BSDFs.
 *
 * diffuse (Lambertian albedo), emitter (one-sided RGB radiance on the side
 * of the triangle's geometric normal, over an optional diffuse albedo that
 * is black unless given), mirror (perfect
 * specular reflection, RGB reflectance) and dielectric (smooth glass with
 * exact Fresnel, index of refraction). Nothing more until a scene needs it.
 * Directions are in world space; n is the shading normal.
 *
 * As pbrt's BSDFs do, each material owns its sampling: material_sample
 * says where a path goes next and with what weight, material_eval what a
 * light sample's direction is worth. They are inline because they run at
 * every bounce: called across translation units (from material.c) they cost
 * the tracer about 4 % more instructions. */
#ifndef VB_MATERIAL_H
#define VB_MATERIAL_H

#include "rng.h"
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
    /* diffuse and emitter: black from behind (a hit on the side away from
     * the geometric normal ends the path), as Mitsuba's BSDFs are unless
     * wrapped in "twosided". 0 for our own scenes' materials. */
    uint8_t one_sided;
    /* diffuse: the texture (scene_t.textures) its albedo comes from, or -1 */
    int32_t albedo_texture;
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

/* The local geometry a material sees where a path meets it. */
typedef struct material_hit {
    vec3_t wo;  /* unit direction back along the incoming ray */
    vec3_t ngf; /* geometric normal, turned to wo's side */
    vec3_t ns;  /* shading normal on wo's side, never hiding wo */
    int front;  /* wo is on the geometric normal's side (entering a dielectric) */
} material_hit_t;

/* A direction sampled from a material's BSDF. */
typedef struct material_sample {
    vec3_t wi;     /* where the path goes on (not normalised) */
    vec3_t weight; /* the path throughput is multiplied by this: f cos / pdf */
    float pdf;     /* solid-angle pdf of wi; meaningless when specular */
    int specular;  /* a delta lobe: light sampling could not have found wi */
    int transmits; /* wi leaves through the surface, to the other side of ngf */
    float eta;     /* transmits only: eta_t / eta_i of the interface crossed */
} material_sample_t;

/* 1 when m reflects diffusely (diffuse, and an emitter's own surface):
 * those are the materials a light sample can reach. */
static inline int material_is_diffuse(const material_t *m)
{
    return m->type == MATERIAL_DIFFUSE || m->type == MATERIAL_EMITTER;
}

/* Lambertian: a cosine-weighted direction about the shading normal. */
static inline int material_sample_diffuse(const material_t *m, const material_hit_t *h,
                                          rng_stream_t *rng, material_sample_t *out)
{
    float u1 = rng_next_float(rng), u2 = rng_next_float(rng);
    vec3_t wi = material_sample_cosine(h->ns, u1, u2);
    float cos_i = vec3_dot(h->ns, wi);
    if (vec3_dot(h->ngf, wi) <= 0.0f || cos_i <= 0.0f)
        return 0;
    out->wi = wi;
    out->weight = m->albedo;
    out->pdf = cos_i * VMATH_INV_PI;
    out->specular = 0;
    out->transmits = 0;
    return 1;
}

/* A specular reflection of wo about the shading normal; weight `weight`. */
static inline int material_sample_reflection(const material_hit_t *h, vec3_t weight,
                                             material_sample_t *out)
{
    vec3_t wi = material_reflect(h->wo, h->ns);
    if (vec3_dot(h->ngf, wi) <= 0.0f)
        return 0;
    out->wi = wi;
    out->weight = weight;
    out->pdf = 0.0f;
    out->specular = 1;
    out->transmits = 0;
    return 1;
}

/* Smooth glass: reflection with the Fresnel probability, else refraction.
 * Reflection leaves the throughput as it is (a weight of exactly 1). */
static inline int material_sample_dielectric(const material_t *m, const material_hit_t *h,
                                             rng_stream_t *rng, material_sample_t *out)
{
    float eta = h->front ? m->ior : 1.0f / m->ior;
    float cos_i = vec3_dot(h->ns, h->wo), cos_t;
    float F = material_fresnel(cos_i, eta, &cos_t);
    if (rng_next_float(rng) < F)
        return material_sample_reflection(h, vec3_make(1.0f, 1.0f, 1.0f), out);
    vec3_t wi = vec3_add(vec3_scale(h->wo, -1.0f / eta), vec3_scale(h->ns, cos_i / eta - cos_t));
    if (vec3_dot(h->ngf, wi) >= 0.0f)
        return 0;
    /* radiance is compressed into the denser medium (pbrt's 1/eta^2); the
     * tracer undoes it with eta where only the path's importance matters */
    float k = 1.0f / (eta * eta);
    out->wi = wi;
    out->weight = vec3_make(k, k, k);
    out->pdf = 0.0f;
    out->specular = 1;
    out->transmits = 1;
    out->eta = eta;
    return 1;
}

/* Samples wi from m's BSDF at h, drawing from rng what the material needs
 * (diffuse 2 numbers, dielectric 1, mirror none). Returns 0 when the path
 * ends here (wi would cross the geometric surface), else 1 and *out. */
static inline int material_sample(const material_t *m, const material_hit_t *h, rng_stream_t *rng,
                                  material_sample_t *out)
{
    out->eta = 1.0f; /* set by the dielectric when it transmits; defined for the rest */
    if (material_is_diffuse(m))
        return material_sample_diffuse(m, h, rng, out);
    if (m->type == MATERIAL_MIRROR)
        return material_sample_reflection(h, m->albedo, out);
    return material_sample_dielectric(m, h, rng, out);
}

/* m's BSDF toward wi (a light sample's direction): returns 0 when m is
 * specular or wi is below the shading or geometric normal; else 1 with
 * *cos_s, the cosine at the shading normal, and *pdf, the density with which
 * material_sample would have chosen wi. f cos = albedo * cos_s / pi: the
 * tracer applies it in its own order of operations. */
static inline int material_eval(const material_t *m, const material_hit_t *h, vec3_t wi,
                                float *cos_s, float *pdf)
{
    if (!material_is_diffuse(m))
        return 0; /* a delta lobe: no light sample lies on it */
    float c = vec3_dot(h->ns, wi);
    if (!(c > 0.0f) || !(vec3_dot(h->ngf, wi) > 0.0f))
        return 0;
    *cos_s = c;
    *pdf = c * VMATH_INV_PI;
    return 1;
}

#endif
