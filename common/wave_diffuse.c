/* wave_diffuse.c - the wavefront kernel of diffuse surfaces (and of
 * emitters with an albedo): next-event estimation on the emissive
 * triangles, MIS-weighted against the BSDF, and a cosine-weighted bounce.
 *
 * DIFFUSE_LANES paths at a time. What is a lookup or a branch per path (the
 * sample's numbers, the light picked from the CDF and the point on it, a
 * smooth normal) is done lane by lane; the arithmetic between, sin and cos
 * included (vmath_sincos_turn), runs on vectors. Each lane does tracer.c's sample_direct and
 * material_sample_diffuse operation for operation (IEEE operations, the
 * same order, no FMA: -ffp-contract=off), so the bits are the scalar
 * engine's. wave_diffuse_avx2.c builds this file again for AVX2, 8 lanes
 * (DIFFUSE_AVX2 defined), and wave_diffuse_avx512.c for AVX-512, 16 lanes
 * (DIFFUSE_AVX512), the same operations in each lane. */
#include "wave.h"

#if defined DIFFUSE_AVX512
#define DIFFUSE_LANES WAVE_LANES_AVX512
#define DIFFUSE_KERNEL wave_kernel_diffuse_avx512
#define DIFFUSE_LINKAGE
#elif defined DIFFUSE_AVX2
#define DIFFUSE_LANES WAVE_LANES_AVX2
#define DIFFUSE_KERNEL wave_kernel_diffuse_avx2
#define DIFFUSE_LINKAGE
#else
#define DIFFUSE_LANES WAVE_LANES
#define DIFFUSE_KERNEL diffuse_baseline
#define DIFFUSE_LINKAGE static
#endif

typedef float wave_vf __attribute__((vector_size(4 * DIFFUSE_LANES)));
typedef int32_t wave_vi __attribute__((vector_size(4 * DIFFUSE_LANES)));

typedef struct {
    wave_vf x, y, z;
} wave_v3;

static inline wave_vf vsel(wave_vi m, wave_vf a, wave_vf b)
{
    return (wave_vf)(((wave_vi)a & m) | ((wave_vi)b & ~m));
}

/* sqrtf and fmaxf(0, x) of each lane: the same correctly rounded result
 * (the compiler emits the vector instruction where the target has it). */
static inline wave_vf vsqrt(wave_vf x)
{
    wave_vf r;
    for (int j = 0; j < DIFFUSE_LANES; j++)
        r[j] = sqrtf(x[j]);
    return r;
}

static inline wave_vf vmax0(wave_vf x)
{
    const wave_vf zero = {0};
    /* fmaxf(0, NaN) is 0, as here */
    return vsel(x > zero, x, zero);
}

static inline wave_vf vdot(wave_v3 a, wave_v3 b)
{
    return a.x * b.x + a.y * b.y + a.z * b.z;
}

/* vmath_sincos_turn, lane by lane in vectors: the same operations */
static inline void vsincos_turn(wave_vf u, wave_vf *s, wave_vf *c)
{
    wave_vf x = 4.0f * u;
    wave_vi q = __builtin_convertvector(x, wave_vi); /* truncates, as (int) */
    wave_vf f = x - __builtin_convertvector(q, wave_vf);
    wave_vi up = f >= 0.5f;
    wave_vf g = vsel(up, f - 1.0f, f), g2 = g * g;
    q = (q - up) & 3; /* (up is -1 where true) */
    wave_vf ps =
        g *
        (VMATH_TURN_S1 +
         g2 * (VMATH_TURN_S3 + g2 * (VMATH_TURN_S5 + g2 * (VMATH_TURN_S7 + g2 * VMATH_TURN_S9))));
    wave_vf pc = 1.0f + g2 * (VMATH_TURN_C2 +
                              g2 * (VMATH_TURN_C4 + g2 * (VMATH_TURN_C6 + g2 * VMATH_TURN_C8)));
    wave_vf nps = -ps, npc = -pc; /* sign flips, as the scalar's */
    wave_vi q0 = q == 0, q1 = q == 1, q2 = q == 2;
    *s = vsel(q0, ps, vsel(q1, pc, vsel(q2, nps, npc)));
    *c = vsel(q0, pc, vsel(q1, nps, vsel(q2, npc, ps)));
}

/* vmath_offset_coord, lane by lane in vectors */
static inline wave_vf voffset_coord(wave_vf p, wave_vf n)
{
    const wave_vf zero = {0};
    wave_vf ap = (wave_vf)((wave_vi)p & 0x7fffffff);
    wave_vi near = ap < 1.0f / 32.0f;
    wave_vf nearby = p + (1.0f / 65536.0f) * n;
    wave_vi of = __builtin_convertvector(16.0f * n, wave_vi);
    wave_vi neg = p < zero;
    wave_vi bits = (wave_vi)p + ((neg & -of) | (~neg & of));
    return vsel(near, nearby, (wave_vf)bits);
}

static inline wave_v3 voffset(wave_v3 p, wave_v3 n)
{
    return (wave_v3){voffset_coord(p.x, n.x), voffset_coord(p.y, n.y), voffset_coord(p.z, n.z)};
}

#define LOAD3(dst, j, v)                                                                           \
    do {                                                                                           \
        vec3_t v_ = (v);                                                                           \
        (dst).x[j] = v_.x;                                                                         \
        (dst).y[j] = v_.y;                                                                         \
        (dst).z[j] = v_.z;                                                                         \
    } while (0)
#define LANE3(src, j) vec3_make((src).x[j], (src).y[j], (src).z[j])

DIFFUSE_LINKAGE void DIFFUSE_KERNEL(const wave_ctx_t *c, wave_state_t *w, const uint16_t *slots,
                                    size_t n)
{
    const scene_t *sc = c->scene;
    const wave_vf zero = {0}, one = zero + 1.0f;
    wave_sobol_ahead(c, w, slots, n);
    for (size_t j0 = 0; j0 < n; j0 += DIFFUSE_LANES) {
        int lanes = n - j0 < DIFFUSE_LANES ? (int)(n - j0) : DIFFUSE_LANES;
        wave_v3 a = {zero, zero, zero}, b = a, cc = a, ng = a, nsm = a, beta = a, albedo = a, q = a,
                nl = a, rad = a;
        wave_vf u = zero, v = zero, cos_o = zero, area_pdf = one, u1 = zero, u2 = zero;
        wave_vi smooth = {0};
        /* lanes whose light sample took the environment (lights_pick_env),
         * and its numbers; lanes that took a light with no area
         * (lights_pick_delta), which and with what probability */
        unsigned env = 0, delta = 0;
        double env_u1[DIFFUSE_LANES];
        float env_u2[DIFFUSE_LANES], delta_pick[DIFFUSE_LANES];
        size_t delta_k[DIFFUSE_LANES];
        /* lanes whose light is a triangle of no sphere, in a scene of no
         * spheres: its corners, the picking number and the light's share
         * of the CDF, for the point on it in vectors (lights_point_on) */
        wave_vi on_tri = {0};
        wave_v3 la = a, lb = a, lc = a;
        wave_vf lu2 = zero;
        double lu[DIFFUSE_LANES], lcdf_lo[DIFFUSE_LANES], lcdf_hi[DIFFUSE_LANES];
        /* lane by lane: what each path looks up */
        for (int j = 0; j < DIFFUSE_LANES; j++) {
            uint16_t s = slots[j0 + (j < lanes ? (size_t)j : 0)];
            uint32_t tri = w->tri[s];
            const uint32_t *vi = sc->indices + 3 * tri;
            LOAD3(a, j, scene_vertex(sc, vi[0]));
            LOAD3(b, j, scene_vertex(sc, vi[1]));
            LOAD3(cc, j, scene_vertex(sc, vi[2]));
            LOAD3(ng, j, sc->tri_normal[tri]);
            LOAD3(beta, j, w->beta[s]);
            LOAD3(albedo, j,
                  texture_albedo(sc, &sc->materials[sc->tri_material[tri]], tri, w->u[s], w->v[s]));
            u[j] = w->u[s];
            v[j] = w->v[s];
            cos_o[j] = w->cos_o[s];
            lu[j] = lcdf_lo[j] = 0.0;
            lcdf_hi[j] = 1.0;
            if (j >= lanes)
                continue;
            if (sc->tri_smooth[tri]) {
                /* the shading normal, as the scalar engine finds it */
                tracer_hit_t h = {.tri = tri, .u = w->u[s], .v = w->v[s]};
                material_hit_t mh = tracer_orient_normals(sc, &h, vec3_neg(w->d[s]), w->cos_o[s]);
                smooth[j] = -1;
                LOAD3(nsm, j, mh.ns);
            }
            rng_stream_t *rng = &w->rng[s];
            uint64_t dim = tracer_bounce_dim(w->depth[s]);
            rng_seek(rng, dim + 2);
            if (c->nee) {
                double ul = rng_next_double(rng);
                float ul2 = rng_next_float(rng);
                if (c->env && lights_pick_env(sc, &ul)) {
                    /* the environment: this lane's NEE is done path by
                     * path below (tracer_env_direct), its vector lane
                     * left at cos_l 0, which casts no shadow ray */
                    env |= 1u << j;
                    env_u1[j] = ul;
                    env_u2[j] = ul2;
                } else if (lights_pick_delta(sc, &ul, &delta_k[j], &delta_pick[j])) {
                    /* a light with no area: likewise (tracer_delta_direct) */
                    delta |= 1u << j;
                } else if (sc->sphere_count == 0) {
                    /* lights_sample_from without spheres, but for the
                     * point: its division, square root and corners' sums
                     * are a chain of latencies a lane (perf put about a
                     * sixth of this kernel's samples on it; in vectors the
                     * Cornell box runs 0.6-1 % faster) */
                    size_t i = lights_pick_index(sc, ul);
                    uint32_t lt = sc->light_tris[i];
                    const uint32_t *li = sc->indices + 3 * lt;
                    LOAD3(la, j, scene_vertex(sc, li[0]));
                    LOAD3(lb, j, scene_vertex(sc, li[1]));
                    LOAD3(lc, j, scene_vertex(sc, li[2]));
                    lu[j] = ul;
                    lcdf_lo[j] = i ? sc->light_cdf[i - 1] : 0.0;
                    lcdf_hi[j] = sc->light_cdf[i];
                    lu2[j] = ul2;
                    on_tri[j] = -1;
                    LOAD3(nl, j, sc->tri_normal[lt]);
                    LOAD3(rad, j, sc->materials[sc->tri_material[lt]].radiance);
                    area_pdf[j] = lights_area_pdf(sc, lt);
                } else {
                    /* (an emitting sphere's cone needs the point: tracer.c's
                     * sample_direct finds it by scene_point too) */
                    vec3_t qp, nlp,
                        pp = sc->spheres ? scene_point(sc, tri, w->u[s], w->v[s])
                                         : vec3_make(0, 0, 0);
                    float apdf;
                    uint32_t lt;
                    if (lights_sample_from(sc, pp, ul, ul2, &qp, &nlp, &apdf, &lt,
                                           &w->shadow_to[s])) {
                        LOAD3(q, j, qp);
                        LOAD3(nl, j, nlp);
                        LOAD3(rad, j, sc->materials[sc->tri_material[lt]].radiance);
                        area_pdf[j] = apdf;
                    }
                }
            }
            rng_seek(rng, dim + 4);
            u1[j] = rng_next_float(rng);
            u2[j] = rng_next_float(rng);
        }
        /* the point on a triangle light (lights_point_on, scene_sample_point) */
        if (c->nee && sc->sphere_count == 0) {
            wave_vf lu1;
            for (int j = 0; j < DIFFUSE_LANES; j++)
                lu1[j] = (float)((lu[j] - lcdf_lo[j]) / (lcdf_hi[j] - lcdf_lo[j]));
            lu1 = vsel(lu1 < one, lu1, zero + 0x1.fffffep-1f);
            lu1 = vsel(lu1 >= zero, lu1, zero);
            wave_vf su = vsqrt(lu1), bu = su * lu2, bv = one - su, bw = one - bu - bv;
            q.x = vsel(on_tri, bw * la.x + bu * lb.x + bv * lc.x, q.x);
            q.y = vsel(on_tri, bw * la.y + bu * lb.y + bv * lc.y, q.y);
            q.z = vsel(on_tri, bw * la.z + bu * lb.z + bv * lc.z, q.z);
        }
        /* the hit point (vec3_barycentric) and the normals (tracer_orient_normals) */
        wave_vf bw = one - u - v;
        wave_v3 p = {bw * a.x + u * b.x + v * cc.x, bw * a.y + u * b.y + v * cc.y,
                     bw * a.z + u * b.z + v * cc.z};
        wave_vi back = cos_o < zero;
        wave_v3 ngf = {vsel(back, -ng.x, ng.x), vsel(back, -ng.y, ng.y), vsel(back, -ng.z, ng.z)};
        wave_v3 ns = {vsel(smooth, nsm.x, ngf.x), vsel(smooth, nsm.y, ngf.y),
                      vsel(smooth, nsm.z, ngf.z)};
        wave_v3 from = voffset(p, ngf);
        /* next-event estimation (sample_direct) */
        wave_vi shadow = {0};
        wave_v3 target = {zero, zero, zero}, shadow_L = target;
        if (c->nee) {
            wave_v3 to = {q.x - p.x, q.y - p.y, q.z - p.z};
            wave_vf dist2 = vdot(to, to);
            wave_vf inv = one / vsqrt(dist2);
            wave_v3 wl = {to.x * inv, to.y * inv, to.z * inv};
            wave_vf cos_l = -vdot(nl, wl);
            /* material_eval */
            wave_vf cos_s = vdot(ns, wl);
            shadow = (dist2 > zero) & (cos_l > zero) & (cos_s > zero) & (vdot(ngf, wl) > zero);
            wave_vf bsdf_pdf = cos_s * VMATH_INV_PI;
            target = voffset(q, nl);
            wave_vf light_pdf = area_pdf * dist2 / cos_l;
            wave_vf a2 = light_pdf * light_pdf, b2 = bsdf_pdf * bsdf_pdf;
            wave_vf mis = a2 / (a2 + b2);
            wave_vf k = mis * cos_s * VMATH_INV_PI / light_pdf;
            shadow_L = (wave_v3){beta.x * albedo.x * (rad.x * k), beta.y * albedo.y * (rad.y * k),
                                 beta.z * albedo.z * (rad.z * k)};
        }
        /* the bounce (material_sample_diffuse, material_sample_cosine) */
        wave_vf r = vsqrt(u1), sinp, cosp;
        vsincos_turn(u2, &sinp, &cosp);
        wave_vf x = r * cosp, y = r * sinp;
        wave_vf z = vsqrt(vmax0(one - u1));
        /* vec3_onb */
        wave_vf sign = (wave_vf)(((wave_vi)ns.z & (int32_t)0x80000000) | (wave_vi)one);
        wave_vf oa = -1.0f / (sign + ns.z);
        wave_vf oc = ns.x * ns.y * oa;
        wave_v3 t = {1.0f + sign * ns.x * ns.x * oa, sign * oc, -sign * ns.x};
        wave_v3 bt = {oc, sign + ns.y * ns.y * oa, -ns.y};
        wave_v3 wi = {t.x * x + bt.x * y + ns.x * z, t.y * x + bt.y * y + ns.y * z,
                      t.z * x + bt.z * y + ns.z * z};
        wave_vf cos_i = vdot(ns, wi);
        wave_vi alive = ~(vdot(ngf, wi) <= zero) & ~(cos_i <= zero);
        wave_vf pdf = cos_i * VMATH_INV_PI;
        wave_vf inv_len = one / vsqrt(vdot(wi, wi)); /* vec3_normalize */
        wave_v3 next_d = {wi.x * inv_len, wi.y * inv_len, wi.z * inv_len};
        wave_v3 nbeta = {beta.x * albedo.x, beta.y * albedo.y, beta.z * albedo.z};
        wave_v3 sd = {target.x - from.x, target.y - from.y, target.z - from.z};
        /* back to the paths */
        for (int j = 0; j < lanes; j++) {
            uint16_t s = slots[j0 + (size_t)j];
            w->shadow[s] = shadow[j] != 0;
            if (shadow[j]) {
                w->shadow_o[s] = LANE3(from, j);
                w->shadow_d[s] = LANE3(sd, j);
                w->shadow_L[s] = LANE3(shadow_L, j);
            }
            w->alive[s] = alive[j] != 0;
            if (!alive[j])
                continue;
            w->beta[s] = LANE3(nbeta, j);
            w->prev_pdf[s] = pdf[j];
            w->specular[s] = 0;
            w->o[s] = LANE3(from, j);
            w->next_d[s] = LANE3(next_d, j);
        }
        /* with emitting spheres, the shadow rays' ends lights_sample_from
         * gave (the same operation as target - from above) */
        for (int j = 0; sc->sphere_count && j < lanes; j++) {
            uint16_t s = slots[j0 + (size_t)j];
            if (shadow[j])
                w->shadow_d[s] = vec3_sub(w->shadow_to[s], w->shadow_o[s]);
        }
        for (int j = 0; (env | delta) && j < lanes; j++) {
            if (!((env | delta) >> j & 1))
                continue;
            uint16_t s = slots[j0 + (size_t)j];
            const material_t *m = &sc->materials[sc->tri_material[w->tri[s]]];
            material_hit_t mh = {.wo = vec3_neg(w->d[s]),
                                 .ngf = LANE3(ngf, j),
                                 .ns = LANE3(ns, j),
                                 .front = cos_o[j] > 0.0f};
            w->shadow[s] =
                (uint8_t)(env >> j & 1
                              ? tracer_env_direct(sc, m, LANE3(albedo, j), LANE3(beta, j),
                                                  LANE3(p, j), &mh, env_u1[j], env_u2[j],
                                                  &w->shadow_o[s], &w->shadow_d[s], &w->shadow_L[s])
                              : tracer_delta_direct(sc, m, LANE3(albedo, j), LANE3(beta, j),
                                                    LANE3(p, j), &mh, delta_k[j], delta_pick[j],
                                                    &w->shadow_o[s], &w->shadow_d[s],
                                                    &w->shadow_L[s]));
        }
    }
}

#if !defined DIFFUSE_AVX2 && !defined DIFFUSE_AVX512
void wave_kernel_diffuse(const wave_ctx_t *c, wave_state_t *w, const uint16_t *slots, size_t n)
{
    if (c->shading_lanes == WAVE_LANES_AVX512)
        wave_kernel_diffuse_avx512(c, w, slots, n);
    else if (c->shading_lanes == WAVE_LANES_AVX2)
        wave_kernel_diffuse_avx2(c, w, slots, n);
    else
        diffuse_baseline(c, w, slots, n);
}
#endif
