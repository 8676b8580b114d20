/* tracer_priv.h - what tracer.c and the wavefront engine (wave.h) share:
 * the tracer's structure, ray casting, and the small pieces of shading
 * whose bits both engines must reproduce exactly (the hit point's inset,
 * the normals' orientation, the MIS weight, the sampler's layout). Not a
 * public interface: common/tracer.c and common/wave*.c include it, and
 * bench_core, which times the very ray casting calls the tracer makes. */
#ifndef VB_TRACER_PRIV_H
#define VB_TRACER_PRIV_H

#include <embree3/rtcore.h>
#include <math.h>

#include "bvh.h"
#include "lights.h"
#include "rng.h"
#include "texture.h"
#include "tracer.h"
#include "trilist.h"

struct tracer {
    tracer_device_t *dev;
    RTCScene rtc;     /* Embree's BVH (TRACER_ACCEL_EMBREE), or NULL */
    bvh_t *bvh;       /* our traversal of a BVH Embree built, or NULL */
    trilist_t *small; /* a scene tested whole, without a BVH */
    const scene_t *scene;
    tracer_engine_t engine;
    int shading_lanes; /* the wavefront's diffuse kernel's build: 4, 8 or 16 lanes (wave.h) */
};

/* ---- ray casting -------------------------------------------------------- */

typedef struct tracer_hit {
    uint32_t tri;
    float t, u, v;
} tracer_hit_t;

/* Where a shadow segment o -> o + d stops short of its target: the light's
 * own surface is not an occluder. */
#define TRACER_SHADOW_TFAR 0.99999f

/* Embree's nearest hit of o + t d on scene sc (bench_core times the same
 * call on its own scenes). */
static inline int tracer_embree_intersect(RTCScene sc, vec3_t o, vec3_t d, tracer_hit_t *h)
{
    struct RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    struct RTCRayHit rh;
    rh.ray.org_x = o.x;
    rh.ray.org_y = o.y;
    rh.ray.org_z = o.z;
    rh.ray.tnear = 0.0f;
    rh.ray.dir_x = d.x;
    rh.ray.dir_y = d.y;
    rh.ray.dir_z = d.z;
    rh.ray.time = 0.0f;
    rh.ray.tfar = INFINITY;
    rh.ray.mask = 0xffffffffu;
    rh.ray.id = 0;
    rh.ray.flags = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(sc, &ctx, &rh);
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID)
        return 0;
    h->tri = rh.hit.primID;
    h->t = rh.ray.tfar;
    h->u = rh.hit.u;
    h->v = rh.hit.v;
    return 1;
}

/* 1 if Embree finds nothing on o + t d, t in [0, TRACER_SHADOW_TFAR). */
static inline int tracer_embree_unoccluded(RTCScene sc, vec3_t o, vec3_t d)
{
    struct RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    struct RTCRay r;
    r.org_x = o.x;
    r.org_y = o.y;
    r.org_z = o.z;
    r.tnear = 0.0f;
    r.dir_x = d.x;
    r.dir_y = d.y;
    r.dir_z = d.z;
    r.time = 0.0f;
    r.tfar = TRACER_SHADOW_TFAR;
    r.mask = 0xffffffffu;
    r.id = 0;
    r.flags = 0;
    rtcOccluded1(sc, &ctx, &r);
    return r.tfar >= 0.0f;
}

/* Rays cast together: one Embree packet of AVX2's width (the ISA the
 * device is pinned to). Embree's packet traversal measured 1.2-1.3x its
 * one-ray calls on our recorded path rays (bench_core "packets of 8";
 * shadow rays 1.5-1.6x), and gave each of those 6.6 million rays the very
 * hit, t, u and v bits of rtcIntersect1 / rtcOccluded1. The wavefront
 * engine fixes which rays share a packet by their task and sample alone
 * (wave.c), so the image does not depend on it either way.
 *
 * A scene casts the way that measured faster (issue 23): on a host with
 * AVX2, through our traversal of a BVH Embree built (bvh.h), one ray at a
 * time: 1.47x Embree's ROBUST packets on the Buddha's recorded extension
 * rays, its shadow rays 1.0-1.1x; but a scene with smooth glass keeps
 * Embree's packets (tracer_own_traversal): ours cast cornell-glass's
 * extension rays 0.96x and its shadow rays 0.64x as fast, rays through
 * glass and to its one light being coherent enough for packets. */
#define TRACER_PACKET 8

/* A packet's rays: origins, unit directions (shadow rays: segments). */
typedef struct tracer_packet {
    vec3_t o[TRACER_PACKET], d[TRACER_PACKET];
} tracer_packet_t;

/* The packet's first n rays as Embree's 8-wide ray, t in [0, tfar); the
 * idle lanes carry a copy of ray 0, masked off in valid. */
static inline void tracer_embree_ray8(const tracer_packet_t *p, size_t n, float tfar,
                                      struct RTCRay8 *r, int *valid)
{
    for (size_t i = 0; i < TRACER_PACKET; i++) {
        size_t k = i < n ? i : 0;
        valid[i] = i < n ? -1 : 0;
        r->org_x[i] = p->o[k].x;
        r->org_y[i] = p->o[k].y;
        r->org_z[i] = p->o[k].z;
        r->tnear[i] = 0.0f;
        r->dir_x[i] = p->d[k].x;
        r->dir_y[i] = p->d[k].y;
        r->dir_z[i] = p->d[k].z;
        r->time[i] = 0.0f;
        r->tfar[i] = tfar;
        r->mask[i] = 0xffffffffu;
        r->id[i] = 0;
        r->flags[i] = 0;
    }
}

/* The nearest hits of the packet's first n rays: hit[i] is 1 and h[i] the
 * hit when ray i hits something (tracer_intersect for each). */
static inline void tracer_intersect_packet(const tracer_t *tr, const tracer_packet_t *p, size_t n,
                                           int *hit, tracer_hit_t *h)
{
    if (tr->bvh) {
        for (size_t i = 0; i < n; i++)
            hit[i] = bvh_intersect(tr->bvh, p->o[i], p->d[i], INFINITY, &h[i].tri, &h[i].t, &h[i].u,
                                   &h[i].v);
        return;
    }
    if (tr->small) { /* two rays a call: faster, the same bits */
        size_t i = 0;
        for (; i + 1 < n; i += 2) {
            uint32_t tri[2];
            float t[2], u[2], v[2];
            trilist_intersect_pair(tr->small, p->o + i, p->d + i, hit + i, tri, t, u, v);
            for (int k = 0; k < 2; k++)
                if (hit[i + k]) /* (a miss writes nothing) */
                    h[i + k] = (tracer_hit_t){tri[k], t[k], u[k], v[k]};
        }
        for (; i < n; i++)
            hit[i] = trilist_intersect(tr->small, p->o[i], p->d[i], INFINITY, &h[i].tri, &h[i].t,
                                       &h[i].u, &h[i].v);
        return;
    }
    _Alignas(32) int valid[TRACER_PACKET];
    struct RTCRayHit8 rh;
    tracer_embree_ray8(p, n, INFINITY, &rh.ray, valid);
    for (size_t i = 0; i < TRACER_PACKET; i++) {
        rh.hit.geomID[i] = RTC_INVALID_GEOMETRY_ID;
        rh.hit.instID[0][i] = RTC_INVALID_GEOMETRY_ID;
    }
    struct RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    rtcIntersect8(valid, tr->rtc, &ctx, &rh);
    for (size_t i = 0; i < n; i++) {
        hit[i] = rh.hit.geomID[i] != RTC_INVALID_GEOMETRY_ID;
        h[i].tri = rh.hit.primID[i];
        h[i].t = rh.ray.tfar[i];
        h[i].u = rh.hit.u[i];
        h[i].v = rh.hit.v[i];
    }
}

/* clear[i] is 1 when the packet's segment i (tracer_unoccluded) is free. */
static inline void tracer_unoccluded_packet(const tracer_t *tr, const tracer_packet_t *p, size_t n,
                                            int *clear)
{
    if (tr->bvh) {
        for (size_t i = 0; i < n; i++)
            clear[i] = !bvh_occluded(tr->bvh, p->o[i], p->d[i], TRACER_SHADOW_TFAR);
        return;
    }
    if (tr->small) { /* two rays a call, as above */
        size_t i = 0;
        for (; i + 1 < n; i += 2) {
            int occ[2];
            trilist_occluded_pair(tr->small, p->o + i, p->d + i, TRACER_SHADOW_TFAR, occ);
            clear[i] = !occ[0];
            clear[i + 1] = !occ[1];
        }
        for (; i < n; i++)
            clear[i] = !trilist_occluded(tr->small, p->o[i], p->d[i], TRACER_SHADOW_TFAR);
        return;
    }
    _Alignas(32) int valid[TRACER_PACKET];
    struct RTCRay8 r;
    tracer_embree_ray8(p, n, TRACER_SHADOW_TFAR, &r, valid);
    struct RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    rtcOccluded8(valid, tr->rtc, &ctx, &r);
    for (size_t i = 0; i < n; i++)
        clear[i] = r.tfar[i] >= 0.0f;
}

static inline int tracer_intersect(const tracer_t *tr, vec3_t o, vec3_t d, tracer_hit_t *h)
{
    if (tr->bvh)
        return bvh_intersect(tr->bvh, o, d, INFINITY, &h->tri, &h->t, &h->u, &h->v);
    if (tr->small)
        return trilist_intersect(tr->small, o, d, INFINITY, &h->tri, &h->t, &h->u, &h->v);
    return tracer_embree_intersect(tr->rtc, o, d, h);
}

/* The nearest hit of a camera ray: with the scene's hide_emitters, past
 * every emitting triangle in the way (*rays counts the rays cast beyond
 * the first), as Mitsuba's skip_area_emitters. */
static inline int tracer_intersect_camera(const tracer_t *tr, vec3_t o, vec3_t d, tracer_hit_t *h,
                                          uint32_t *rays)
{
    const scene_t *s = tr->scene;
    for (int skipped = 0;; skipped++) {
        if (!tracer_intersect(tr, o, d, h))
            return 0;
        if (!s->hide_emitters || skipped == 64 ||
            s->materials[s->tri_material[h->tri]].type != MATERIAL_EMITTER)
            return 1;
        vec3_t ng = s->tri_normal[h->tri];
        o = vec3_offset_ray_origin(vec3_add(o, vec3_scale(d, h->t)),
                                   vec3_dot(ng, d) > 0.0f ? ng : vec3_neg(ng));
        (*rays)++;
    }
}

/* 1 if the segment o -> o + d (d unnormalised, t in [0, 1)) is free. */
static inline int tracer_unoccluded(const tracer_t *tr, vec3_t o, vec3_t d)
{
    if (tr->bvh)
        return !bvh_occluded(tr->bvh, o, d, TRACER_SHADOW_TFAR);
    if (tr->small)
        return !trilist_occluded(tr->small, o, d, TRACER_SHADOW_TFAR);
    return tracer_embree_unoccluded(tr->rtc, o, d);
}

/* A hit rounded onto a triangle's edge lies on the plane of the face
 * across that edge too, so half the directions leaving it go out through
 * that face at t = 0 and are never stopped: a crack along every edge of a
 * closed mesh (10^-8 of the rays in a closed cube). The shading point keeps
 * at least TRACER_EDGE_INSET of each barycentric coordinate instead, a
 * shift of 2^-16 of the triangle that puts it inside its own face. */
#define TRACER_EDGE_INSET 0x1p-16f

static inline void tracer_inset_from_edges(tracer_hit_t *h)
{
    /* (comparisons, not fmaxf: that is a libm call without -ffast-math) */
    float u = h->u < TRACER_EDGE_INSET ? TRACER_EDGE_INSET : h->u;
    float v = h->v < TRACER_EDGE_INSET ? TRACER_EDGE_INSET : h->v;
    if (u + v > 1.0f - TRACER_EDGE_INSET) {
        float k = (1.0f - TRACER_EDGE_INSET) / (u + v);
        u *= k;
        v *= k;
    }
    h->u = u;
    h->v = v;
}

static inline float tracer_power_heuristic(float a, float b)
{
    float a2 = a * a, b2 = b * b;
    return a2 / (a2 + b2);
}

/* The normals at a hit, turned to the side the ray came from. */
static inline material_hit_t tracer_orient_normals(const scene_t *s, const tracer_hit_t *h,
                                                   vec3_t wo, float cos_o)
{
    vec3_t ng = s->tri_normal[h->tri];
    material_hit_t mh = {.wo = wo, .front = cos_o > 0.0f};
    mh.ngf = cos_o < 0.0f ? vec3_neg(ng) : ng;
    mh.ns = mh.ngf;
    if (s->tri_smooth[h->tri]) {
        const uint32_t *vi = s->indices + 3 * h->tri;
        vec3_t n = vec3_normalize(vec3_barycentric(scene_vertex_normal(s, vi[0]),
                                                   scene_vertex_normal(s, vi[1]),
                                                   scene_vertex_normal(s, vi[2]), h->u, h->v));
        if (vec3_dot(n, mh.ngf) < 0.0f)
            n = vec3_neg(n);
        /* A shading normal that hides wo would make the BSDF take light
         * from behind the surface: fall back to the geometric one. */
        if (vec3_is_finite(n) && vec3_dot(n, wo) > 0.0f)
            mh.ns = n;
    }
    return mh;
}

/* Next-event estimation toward the environment, once lights_pick_env took
 * it: the direction from (u1, u2), its shadow segment from p and what the
 * path gains when that segment is free, MIS-weighted against the BSDF.
 * 0 when the BSDF gives that direction nothing. Both engines call it, so
 * the bits are the same. */
static inline int tracer_env_direct(const scene_t *s, const material_t *m, vec3_t albedo,
                                    vec3_t beta, vec3_t p, const material_hit_t *mh, double u1,
                                    float u2, vec3_t *from, vec3_t *seg, vec3_t *gain)
{
    float light_pdf;
    vec3_t radiance;
    vec3_t wl = lights_env_sample(s, u1, u2, &light_pdf, &radiance);
    float cos_s, bsdf_pdf;
    if (!(light_pdf > 0.0f) || !material_eval(m, mh, wl, &cos_s, &bsdf_pdf))
        return 0;
    *from = vec3_offset_ray_origin(p, mh->ngf);
    *seg = vec3_scale(wl, s->env_distance);
    float w = tracer_power_heuristic(light_pdf, bsdf_pdf);
    float k = w * cos_s * VMATH_INV_PI / light_pdf;
    *gain = vec3_mul(vec3_mul(beta, albedo), vec3_scale(radiance, k));
    return 1;
}

/* Next-event estimation toward light k with no area (lights_pick_delta
 * took it, with probability pick) from a diffuse surface: its shadow
 * segment and what the path gains when it is free (no MIS: no bounce
 * could find such a light). 0 when it gives p nothing. Both engines call
 * it. */
static inline int tracer_delta_direct(const scene_t *s, const material_t *m, vec3_t albedo,
                                      vec3_t beta, vec3_t p, const material_hit_t *mh, size_t k,
                                      float pick, vec3_t *from, vec3_t *seg, vec3_t *gain)
{
    vec3_t wl, light, target;
    float cos_s, bsdf_pdf;
    if (!lights_delta_sample(s, k, p, &wl, &light, &target) ||
        !material_eval(m, mh, wl, &cos_s, &bsdf_pdf))
        return 0;
    *from = vec3_offset_ray_origin(p, mh->ngf);
    *seg = vec3_sub(target, *from);
    *gain = vec3_mul(vec3_mul(beta, albedo), vec3_scale(light, cos_s * VMATH_INV_PI / pick));
    return 1;
}

/* L after a ray that left the scene: plus the environment's radiance,
 * weighted against next-event estimation unless the last bounce was
 * specular (or there is none). */
static inline vec3_t tracer_env_miss(const scene_t *s, vec3_t L, vec3_t beta, vec3_t d,
                                     int specular, float prev_pdf, int nee)
{
    float w = 1.0f, light_pdf;
    vec3_t radiance = lights_env_eval(s, d, &light_pdf);
    if (nee && !specular)
        w = tracer_power_heuristic(prev_pdf, light_pdf);
    return vec3_add(L, vec3_mul(beta, vec3_scale(radiance, w)));
}

/* The dimension of a thin lens's two numbers: read with rng_bits_at, far
 * from every bounce's, so the rest of the path draws what it always did. */
#define TRACER_LENS_DIM (UINT64_MAX - 4)

/* A camera ray of pixel (px, py) from the sample's stream: its film point
 * from the first two numbers; through a thin lens, the point on the lens
 * from two of its own (TRACER_LENS_DIM). Both engines start paths here. */
static inline void tracer_camera_ray(const camera_t *cam, rng_stream_t *rng, uint32_t px,
                                     uint32_t py, vec3_t *o, vec3_t *d)
{
    float fu = rng_next_float(rng), fv = rng_next_float(rng);
    vec3_t dir = camera_ray_dir(cam, px, py, fu, fv);
    if (cam->ortho) {
        /* the film point's offset from the centre, along forward */
        *o = vec3_add(vec3_add(cam->position, vec3_sub(dir, cam->forward)),
                      vec3_scale(cam->forward, cam->ortho_near));
        *d = cam->forward;
        return;
    }
    if (!(cam->aperture > 0.0f)) {
        *o = cam->position;
        *d = vec3_normalize(dir);
        return;
    }
    float lu = (float)(rng_bits_at(rng, TRACER_LENS_DIM) >> 40) * 0x1.0p-24f;
    float lv = (float)(rng_bits_at(rng, TRACER_LENS_DIM + 1) >> 40) * 0x1.0p-24f;
    camera_thinlens(cam, dir, lu, lv, o, d);
}

/* Where bounce `depth`'s numbers start under the sobol sampler: after the
 * camera's pair, six per bounce: [0] roulette, [1] a glossy material's
 * choice of lobe (it was the light pick, which now shares the light point's
 * pair), [2, 3] the light and the point on it, [4, 5] BSDF sample, so the
 * 2D uses are Sobol pairs (rng.h). */
static inline uint64_t tracer_bounce_dim(uint32_t depth)
{
    return 2 + 6 * (uint64_t)depth;
}

/* A light sample from p with the numbers (ul, u2): its direction *wl,
 * solid-angle density *light_pdf (the choice of light included) and
 * radiance, and the shadow segment from *from along *seg, which leaves p
 * on wl's side of the geometric normal ngf. 0 when it gives nothing. A
 * light with no area (*delta 1) has a density of its choice alone, and
 * its radiance is what it delivers (intensity / distance^2). */
static inline int tracer_sample_light(const scene_t *s, vec3_t p, vec3_t ngf, double ul, float u2,
                                      vec3_t *wl, float *light_pdf, vec3_t *radiance, vec3_t *from,
                                      vec3_t *seg, int *delta)
{
    vec3_t target = {0, 0, 0};
    int env = lights_pick_env(s, &ul);
    size_t k;
    *delta = !env && lights_pick_delta(s, &ul, &k, light_pdf);
    if (*delta) {
        if (!lights_delta_sample(s, k, p, wl, radiance, &target))
            return 0;
    } else if (env) {
        *wl = lights_env_sample(s, ul, u2, light_pdf, radiance);
        if (!(*light_pdf > 0.0f))
            return 0;
    } else {
        vec3_t q, nl;
        float area_pdf;
        uint32_t lt;
        if (!lights_sample_from(s, p, ul, u2, &q, &nl, &area_pdf, &lt, &target))
            return 0;
        vec3_t to = vec3_sub(q, p);
        float dist2 = vec3_dot(to, to);
        if (!(dist2 > 0.0f))
            return 0;
        *wl = vec3_scale(to, 1.0f / sqrtf(dist2));
        float cos_l = -vec3_dot(nl, *wl);
        if (!(cos_l > 0.0f))
            return 0;
        *light_pdf = area_pdf * dist2 / cos_l;
        *radiance = s->materials[s->tri_material[lt]].radiance;
    }
    /* (rough glass: a light behind the surface is seen through it) */
    *from = vec3_offset_ray_origin(p, vec3_dot(ngf, *wl) > 0.0f ? ngf : vec3_neg(ngf));
    *seg = env ? vec3_scale(*wl, s->env_distance) : vec3_sub(target, *from);
    return 1;
}

/* Next-event estimation at p on a glossy material m (material.h) with
 * the light-sample numbers (ul, u2): the shadow segment from *from along
 * *seg and what the path gains when it is free, MIS-weighted against the
 * BSDF. 0 when there is nothing to test. */
static inline int tracer_glossy_direct(const scene_t *s, const material_t *m, vec3_t beta, vec3_t p,
                                       const material_hit_t *mh, double ul, float u2, vec3_t *from,
                                       vec3_t *seg, vec3_t *gain)
{
    vec3_t wl, radiance, f_cos;
    float light_pdf, bsdf_pdf;
    int delta;
    if (!tracer_sample_light(s, p, mh->ngf, ul, u2, &wl, &light_pdf, &radiance, from, seg,
                             &delta) ||
        !material_glossy_eval(m, mh, wl, &f_cos, &bsdf_pdf))
        return 0;
    /* (a light with no area: no bounce could find it) */
    float w = delta ? 1.0f : tracer_power_heuristic(light_pdf, bsdf_pdf);
    *gain = vec3_mul(vec3_mul(beta, f_cos), vec3_scale(radiance, w / light_pdf));
    return 1;
}

/* m, or when its albedo is a texture, *copy with the albedo where h hit
 * (the copy the BSDF reads). */
static inline const material_t *tracer_textured(const scene_t *s, const material_t *m,
                                                const tracer_hit_t *h, material_t *copy)
{
    if (m->albedo_texture < 0)
        return m;
    *copy = *m;
    copy->albedo = texture_albedo(s, m, h->tri, h->u, h->v);
    return copy;
}

/* The shading of a glossy material at a hit, the same in both engines:
 * the light sample (its numbers at the bounce's [2, 3]; *shadow 1 when
 * its segment is to be tested, see tracer_glossy_direct) and the BSDF
 * sample (the lobe's number at [1], the direction's at [4, 5]). Returns 0
 * when the path ends here. */
static inline int tracer_shade_glossy(const scene_t *s, const material_t *m, rng_stream_t *rng,
                                      uint32_t depth, int nee, vec3_t beta, vec3_t p,
                                      const material_hit_t *mh, int *shadow, vec3_t *from,
                                      vec3_t *seg, vec3_t *gain, material_sample_t *bs)
{
    uint64_t dim = tracer_bounce_dim(depth);
    *shadow = 0;
    if (nee && material_glossy_has_lobe(m)) {
        rng_seek(rng, dim + 2);
        double ul = rng_next_double(rng);
        float u2 = rng_next_float(rng);
        *shadow = tracer_glossy_direct(s, m, beta, p, mh, ul, u2, from, seg, gain);
    }
    rng_seek(rng, dim + 1);
    float u_lobe = rng_next_float(rng);
    rng_seek(rng, dim + 4);
    float u1 = rng_next_float(rng);
    float u2 = rng_next_float(rng);
    return material_glossy_sample(m, mh, u_lobe, u1, u2, bs);
}

#endif
