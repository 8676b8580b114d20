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

#include "microfacet.h"
#include "rng.h"
#include "vmath.h"

typedef enum {
    MATERIAL_DIFFUSE = 0,
    MATERIAL_EMITTER,
    MATERIAL_MIRROR,
    MATERIAL_DIELECTRIC,
    /* the materials of Mitsuba's scenes (material_glossy_*): */
    MATERIAL_CONDUCTOR,        /* a metal: smooth, or rough (alpha > 0) */
    MATERIAL_PLASTIC,          /* a diffuse base under a dielectric coat, smooth or rough */
    MATERIAL_THIN_DIELECTRIC,  /* a thin pane: reflects, or lets light through unbent */
    MATERIAL_ROUGH_DIELECTRIC, /* rough glass: reflects and refracts through microfacets */
    MATERIAL_TYPE_COUNT
} material_type_t;

#define MATERIAL_NAME_LEN 64
/* Entries of rough plastic's table of the coat's transmittance by cosine
 * (Mitsuba's MI_ROUGH_TRANSMITTANCE_RES). */
#define MATERIAL_COAT_RES 64

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
    /* diffuse and plastic: the texture (scene_t.textures) its albedo comes
     * from, or -1 */
    int32_t albedo_texture;
    /* conductor: the complex index of refraction eta + i k, per channel
     * (albedo is its specular reflectance) */
    vec3_t eta, k;
    /* plastic: the coat's specular reflectance (albedo is the base's);
     * ior is the coat's index (thin dielectric: the pane's) */
    vec3_t specular;
    /* conductor and plastic: the roughness and its distribution; alpha 0
     * is the smooth material */
    float alpha;
    microfacet_type_t distribution;

    /* plastic: the base's internal reflections scale with its albedo */
    uint8_t nonlinear;
    /* plastic, derived by material_prepare: the probability weight of the
     * coat's lobe, 1 / ior^2, the base's internal reflectance, and (rough)
     * the coat's transmittance by cosine */
    float coat_weight, inv_eta2, internal;
    float coat_t[MATERIAL_COAT_RES];
} material_t;

/* "diffuse", "emitter", ...; returns -1 for an unknown name. */
int material_type_from_name(const char *name);
const char *material_type_name(material_type_t type);

/* The n-point Gauss-Legendre rule on [-1, 1], nodes x[0..n) and weights
 * w[0..n) (Newton on the Legendre polynomial from Chebyshev guesses, in
 * double): the quadrature of rough plastic's coat tables (material.c),
 * and of the tests that check them. */
void material_gauss_legendre(int n, double *x, double *w);

/* Derives what a material's sampling needs from its parameters, once at
 * load: rough plastic integrates its coat's transmittance numerically (as
 * Mitsuba does, Gauss-Legendre over its visible normals: about 0.15 s),
 * unless one of the `count` materials already prepared has the same coat
 * (distribution, roughness and index), whose tables it copies.
 * `albedo_mean` is the mean of the base's albedo (over a texture, of its
 * two colours). */
void material_prepare(material_t *m, float albedo_mean, const material_t *prepared, size_t count);

/* The conductor presets Mitsuba names ("Au", "Cu", "none"...), as its RGB
 * mode converts their spectra. Returns 0 and the index, -1 if unknown. */
int material_conductor_preset(const char *name, vec3_t *eta, vec3_t *k);
/* The names, comma-separated, for an error message. */
const char *material_conductor_presets(void);

/* Cosine-weighted direction about n from two uniforms; pdf = cos / pi. */
static inline vec3_t material_sample_cosine(vec3_t n, float u1, float u2)
{
    float r = sqrtf(u1), sp, cp;
    vmath_sincos_turn(u2, &sp, &cp);
    float x = r * cp, y = r * sp;
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

/* ---- the glossy materials: conductor, plastic, thin dielectric ---------- */

/* The materials of Mitsuba's scenes, shaded by material_glossy_eval and
 * material_glossy_sample (the wavefront engine's wave_<material>.c and the
 * scalar engine both call them). Directions: wo toward the viewer, wi
 * toward the light, as in material_eval. Smooth conductor and thin
 * dielectric are deltas; plastic always has its diffuse base. */
static inline int material_is_glossy(const material_t *m)
{
    return m->type >= MATERIAL_CONDUCTOR;
}

/* 1 when m has a lobe a light sample can reach (not a delta). */
static inline int material_glossy_has_lobe(const material_t *m)
{
    return m->type == MATERIAL_PLASTIC || m->type == MATERIAL_ROUGH_DIELECTRIC ||
           (m->type == MATERIAL_CONDUCTOR && m->alpha > 0.0f);
}

/* The shading normal's frame: local z is n. */
typedef struct material_frame {
    vec3_t t, b, n;
} material_frame_t;

static inline material_frame_t material_frame(vec3_t n)
{
    material_frame_t f = {.n = n};
    vec3_onb(n, &f.t, &f.b);
    return f;
}

static inline vec3_t material_to_local(const material_frame_t *f, vec3_t v)
{
    return vec3_make(vec3_dot(v, f->t), vec3_dot(v, f->b), vec3_dot(v, f->n));
}

static inline vec3_t material_to_world(const material_frame_t *f, vec3_t v)
{
    return vec3_add(vec3_add(vec3_scale(f->t, v.x), vec3_scale(f->b, v.y)), vec3_scale(f->n, v.z));
}

static inline microfacet_t material_microfacet(const material_t *m)
{
    microfacet_t d = {m->distribution, m->alpha};
    return d;
}

/* Rough plastic's coat transmittance at cosine c in [0, 1], interpolated
 * in its table (Mitsuba's lerp_gather). */
static inline float material_coat_t(const material_t *m, float c)
{
    float x = c * (float)(MATERIAL_COAT_RES - 1);
    int i = (int)x;
    if (i > MATERIAL_COAT_RES - 2)
        i = MATERIAL_COAT_RES - 2;
    if (i < 0)
        i = 0;
    float t = x - (float)i;
    return m->coat_t[i] * (1.0f - t) + m->coat_t[i + 1] * t;
}

/* Plastic's coat reflectance at cosine c: Fresnel when smooth, one minus
 * the coat's transmittance when rough. */
static inline float material_plastic_coat_f(const material_t *m, float c)
{
    if (m->alpha > 0.0f)
        return 1.0f - material_coat_t(m, c);
    float ct;
    return microfacet_fresnel(c, m->ior, &ct);
}

/* The probability of sampling plastic's coat rather than its base, seen
 * at cosine cos_o (Mitsuba's weighting by the lobes' reflectances). */
static inline float material_plastic_coat_prob(const material_t *m, float cos_o)
{
    float f = material_plastic_coat_f(m, cos_o);
    float ps = f * m->coat_weight, pd = (1.0f - f) * (1.0f - m->coat_weight);
    return ps + pd > 0.0f ? ps / (ps + pd) : 0.5f;
}

/* Plastic's base albedo, with the light its coat reflects back into it. */
static inline vec3_t material_plastic_base(const material_t *m)
{
    vec3_t d = m->albedo;
    if (m->nonlinear)
        return vec3_make(d.x / (1.0f - d.x * m->internal), d.y / (1.0f - d.y * m->internal),
                         d.z / (1.0f - d.z * m->internal));
    return vec3_scale(d, 1.0f / (1.0f - m->internal));
}

/* f cos of plastic's base toward wi (local, both cosines positive). */
static inline vec3_t material_plastic_base_f(const material_t *m, float cos_o, float cos_i)
{
    float k;
    if (m->alpha > 0.0f)
        k = VMATH_INV_PI * m->inv_eta2 * cos_i * material_coat_t(m, cos_o) *
            material_coat_t(m, cos_i);
    else {
        float ct;
        float fo = microfacet_fresnel(cos_o, m->ior, &ct),
              fi = microfacet_fresnel(cos_i, m->ior, &ct);
        k = cos_i * VMATH_INV_PI * m->inv_eta2 * (1.0f - fo) * (1.0f - fi);
    }
    return vec3_scale(material_plastic_base(m), k);
}

/* The microfacet lobe's D G / (4 cos_o) and the density of sampling it
 * (visible normals, microfacet_g1_visible) for local wo, wi with half
 * vector H. */
static inline float material_microfacet_lobe(const microfacet_t *d, vec3_t wo, vec3_t wi, vec3_t H,
                                             float *pdf)
{
    float D = microfacet_d(d, H);
    *pdf = D * microfacet_g1_visible(d, wo, H) / (4.0f * wo.z);
    return D * microfacet_g1(d, wo, H) * microfacet_g1(d, wi, H) / (4.0f * wo.z);
}

/* Rough glass (Walter et al.'s model, as Mitsuba's roughdielectric) for
 * local wo (wo.z > 0: the frame's normal is on the viewer's side) and wi
 * on either side; eta is the far side's index over the near side's.
 * Returns f cos (radiance: a transmission carries the 1/eta^2 of the
 * smooth dielectric) and *pdf, or 0 with *pdf 0 when wi gets nothing. */
static inline float material_rough_dielectric_eval(const microfacet_t *d, float eta, vec3_t wo,
                                                   vec3_t wi, float *pdf)
{
    *pdf = 0.0f;
    int reflect = wi.z > 0.0f;
    vec3_t H = vec3_normalize(vec3_add(wo, reflect ? wi : vec3_scale(wi, eta)));
    if (H.z < 0.0f)
        H = vec3_neg(H);
    float dot_o = vec3_dot(wo, H), dot_i = vec3_dot(wi, H);
    if (!(dot_o > 0.0f) || !(dot_i * wi.z > 0.0f))
        return 0.0f;
    float D = microfacet_d(d, H), ct;
    float F = microfacet_fresnel(dot_o, eta, &ct);
    float G = microfacet_g1(d, wo, H) * microfacet_g1(d, wi, H);
    float visible = D * microfacet_g1_visible(d, wo, H) * dot_o / wo.z;
    if (reflect) {
        *pdf = visible * F / (4.0f * dot_i);
        return F * D * G / (4.0f * wo.z);
    }
    float denom = dot_o + eta * dot_i;
    *pdf = fabsf(visible * (1.0f - F) * eta * eta * dot_i / (denom * denom));
    return fabsf((1.0f - F) * D * G * dot_o * dot_i / (wo.z * denom * denom));
}

/* m's BSDF toward wi: 0 when m has no lobe there (a delta, wi below the
 * shading or geometric normal); else 1, *f_cos (the BSDF times the cosine
 * at the shading normal) and *pdf, the density with which
 * material_glossy_sample chooses wi. */
static inline int material_glossy_eval(const material_t *m, const material_hit_t *h, vec3_t wi,
                                       vec3_t *f_cos, float *pdf)
{
    if (!material_glossy_has_lobe(m))
        return 0;
    material_frame_t fr = material_frame(h->ns);
    vec3_t lo = material_to_local(&fr, h->wo), li = material_to_local(&fr, wi);
    microfacet_t d = material_microfacet(m);
    if (m->type == MATERIAL_ROUGH_DIELECTRIC) {
        /* wi on the side of the geometric normal its lobe is on */
        float side = vec3_dot(h->ngf, wi);
        if (!(lo.z > 0.0f) || li.z == 0.0f || !((li.z > 0.0f) == (side > 0.0f)) || side == 0.0f)
            return 0;
        float f =
            material_rough_dielectric_eval(&d, h->front ? m->ior : 1.0f / m->ior, lo, li, pdf);
        *f_cos = vec3_make(f, f, f);
        return *pdf > 0.0f;
    }
    if (!(vec3_dot(h->ngf, wi) > 0.0f) || !(lo.z > 0.0f) || !(li.z > 0.0f))
        return 0;
    vec3_t H = vec3_normalize(vec3_add(lo, li));
    float lobe_pdf;
    if (m->type == MATERIAL_CONDUCTOR) {
        float lobe = material_microfacet_lobe(&d, lo, li, H, &lobe_pdf);
        if (!(lobe > 0.0f))
            return 0;
        vec3_t F = microfacet_fresnel_conductor3(vec3_dot(lo, H), m->eta, m->k);
        *f_cos = vec3_scale(vec3_mul(m->albedo, F), lobe);
        *pdf = lobe_pdf;
        return 1;
    }
    /* plastic */
    float p_coat = material_plastic_coat_prob(m, lo.z);
    vec3_t f = material_plastic_base_f(m, lo.z, li.z);
    float p = (1.0f - p_coat) * li.z * VMATH_INV_PI;
    if (m->alpha > 0.0f) {
        float ct, F = microfacet_fresnel(vec3_dot(lo, H), m->ior, &ct);
        float lobe = material_microfacet_lobe(&d, lo, li, H, &lobe_pdf);
        f = vec3_add(f, vec3_scale(m->specular, F * lobe));
        p += p_coat * lobe_pdf;
    }
    *f_cos = f;
    *pdf = p;
    return p > 0.0f;
}

/* Samples wi from m's BSDF at h from three uniforms: u_lobe picks a lobe
 * (plastic's coat or base, a pane's reflection or transmission), (u1, u2)
 * the direction in it. Returns 0 when the path ends here. */
static inline int material_glossy_sample(const material_t *m, const material_hit_t *h, float u_lobe,
                                         float u1, float u2, material_sample_t *out)
{
    out->eta = 1.0f;
    out->transmits = 0;
    float cos_o = vec3_dot(h->ns, h->wo);
    if (!(cos_o > 0.0f))
        return 0;
    if (m->type == MATERIAL_THIN_DIELECTRIC) {
        /* the pane's two faces and the light bouncing between them */
        float ct, r = microfacet_fresnel(cos_o, m->ior, &ct);
        r *= 2.0f / (1.0f + r);
        if (u_lobe <= r)
            return material_sample_reflection(h, vec3_make(1.0f, 1.0f, 1.0f), out);
        out->wi = vec3_neg(h->wo);
        out->weight = vec3_make(1.0f, 1.0f, 1.0f);
        out->pdf = 0.0f;
        out->specular = 1;
        out->transmits = 1;
        return 1;
    }
    if (m->type == MATERIAL_ROUGH_DIELECTRIC) {
        /* a visible normal, then reflection with Fresnel's probability, else refraction */
        material_frame_t fr = material_frame(h->ns);
        vec3_t lo = material_to_local(&fr, h->wo);
        microfacet_t d = material_microfacet(m);
        float eta = h->front ? m->ior : 1.0f / m->ior;
        vec3_t mn = microfacet_sample_visible(&d, lo, u1, u2);
        float c = vec3_dot(lo, mn), ct;
        float F = microfacet_fresnel(c, eta, &ct);
        float g1v = microfacet_g1_visible(&d, lo, mn);
        if (!(c > 0.0f) || !(g1v > 0.0f))
            return 0;
        vec3_t li;
        int reflect = u_lobe <= F;
        if (reflect)
            li = vec3_sub(vec3_scale(mn, 2.0f * c), lo);
        else
            li = vec3_sub(vec3_scale(mn, c / eta + ct), vec3_scale(lo, 1.0f / eta));
        float g = microfacet_g1(&d, li, mn) * microfacet_g1(&d, lo, mn) / g1v;
        out->wi = material_to_world(&fr, li);
        float side = vec3_dot(h->ngf, out->wi);
        if (!(g > 0.0f) ||
            (reflect ? !(side > 0.0f) || !(li.z > 0.0f) : !(side < 0.0f) || !(li.z < 0.0f)))
            return 0;
        float k = reflect ? g : g / (eta * eta);
        out->weight = vec3_make(k, k, k);
        material_rough_dielectric_eval(&d, eta, lo, li, &out->pdf);
        out->specular = 0;
        out->transmits = !reflect;
        out->eta = reflect ? 1.0f : eta;
        return out->pdf > 0.0f;
    }
    if (m->type == MATERIAL_CONDUCTOR && !(m->alpha > 0.0f))
        return material_sample_reflection(
            h, vec3_mul(m->albedo, microfacet_fresnel_conductor3(cos_o, m->eta, m->k)), out);
    float p_coat = m->type == MATERIAL_PLASTIC ? material_plastic_coat_prob(m, cos_o) : 1.0f;
    if (m->type == MATERIAL_PLASTIC && !(m->alpha > 0.0f) && u_lobe < p_coat) {
        /* smooth plastic's coat: a delta */
        float ct, F = microfacet_fresnel(cos_o, m->ior, &ct);
        return material_sample_reflection(h, vec3_scale(m->specular, F / p_coat), out);
    }
    material_frame_t fr = material_frame(h->ns);
    vec3_t lo = material_to_local(&fr, h->wo), li;
    if (u_lobe < p_coat) {
        microfacet_t d = material_microfacet(m);
        vec3_t mn = microfacet_sample_visible(&d, lo, u1, u2);
        li = vec3_sub(vec3_scale(mn, 2.0f * vec3_dot(lo, mn)), lo);
        if (!(li.z > 0.0f))
            return 0;
        if (m->type == MATERIAL_CONDUCTOR) {
            /* f cos / pdf of the visible normals' sample: F G1(wi) G1(wo) /
             * G1_visible(wo), which is F G1(wi) under GGX */
            vec3_t F = microfacet_fresnel_conductor3(vec3_dot(lo, mn), m->eta, m->k);
            out->wi = material_to_world(&fr, li);
            float g1v = microfacet_g1_visible(&d, lo, mn);
            if (!(vec3_dot(h->ngf, out->wi) > 0.0f) || !(g1v > 0.0f))
                return 0;
            out->weight = vec3_scale(vec3_mul(m->albedo, F),
                                     microfacet_g1(&d, li, mn) * microfacet_g1(&d, lo, mn) / g1v);
            out->pdf = microfacet_d(&d, mn) * g1v / (4.0f * lo.z);
            out->specular = 0;
            return out->pdf > 0.0f;
        }
    } else {
        /* plastic's base: cosine-weighted */
        float r = sqrtf(u1), sp, cp;
        vmath_sincos_turn(u2, &sp, &cp);
        li = vec3_make(r * cp, r * sp, sqrtf(fmaxf(0.0f, 1.0f - u1)));
        if (!(li.z > 0.0f))
            return 0;
        if (!(m->alpha > 0.0f)) {
            float ct, fo = microfacet_fresnel(cos_o, m->ior, &ct);
            float fi = microfacet_fresnel(li.z, m->ior, &ct);
            out->wi = material_to_world(&fr, li);
            if (!(vec3_dot(h->ngf, out->wi) > 0.0f))
                return 0;
            out->weight = vec3_scale(material_plastic_base(m),
                                     m->inv_eta2 * (1.0f - fo) * (1.0f - fi) / (1.0f - p_coat));
            out->pdf = (1.0f - p_coat) * li.z * VMATH_INV_PI;
            out->specular = 0;
            return out->pdf > 0.0f;
        }
    }
    /* rough plastic: either lobe's direction, weighed by the whole BSDF */
    out->wi = material_to_world(&fr, li);
    vec3_t f_cos;
    float pdf;
    if (!material_glossy_eval(m, h, out->wi, &f_cos, &pdf))
        return 0;
    out->weight = vec3_scale(f_cos, 1.0f / pdf);
    out->pdf = pdf;
    out->specular = 0;
    return 1;
}

#endif
