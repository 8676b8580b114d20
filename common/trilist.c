/* trilist.c - watertight ray casting against every triangle of a small
 * scene, 8 or 16 at a time (trilist.h). */
#include "trilist.h"

#include <immintrin.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Triangles per block of the layout: the widest kernel's lanes. */
#define TRILIST_BLOCK 16
/* Floats per triangle: three vertices and the plane's normal. */
#define TRILIST_ROWS 12

typedef struct trilist_hit {
    uint32_t tri;
    float t, u, v;
} trilist_hit_t;

typedef int (*trilist_fn)(const trilist_t *l, const float o[3], const float d[3], float tfar,
                          int any, trilist_hit_t *out);
typedef void (*trilist_pair_fn)(const trilist_t *l, const float o[2][3], const float d[2][3],
                                float tfar, int any, int hit[2], trilist_hit_t out[2]);

struct trilist {
    size_t blocks;
    float *coords; /* per block: 12 rows (v0x v0y v0z v1x .. v2z, then the
                    * normal (v1 - v0) x (v2 - v0)) of TRILIST_BLOCK floats;
                    * NaN past the last triangle */
    trilist_fn fn;
    trilist_pair_fn pair;
    const char *kernel;
};

/* Lane helpers of each width, in that width's target. */
__attribute__((target("avx512f"))) static inline float trilist_min16(__m512 v)
{
    return _mm512_reduce_min_ps(v);
}

__attribute__((target("avx2"))) static inline float trilist_min8(__m256 v)
{
    __m256 m = _mm256_min_ps(v, _mm256_permute2f128_ps(v, v, 1));
    m = _mm256_min_ps(m, _mm256_shuffle_ps(m, m, 0x4e));
    m = _mm256_min_ps(m, _mm256_shuffle_ps(m, m, 0xb1));
    return _mm256_cvtss_f32(m);
}

static inline float trilist_min4(__m128 v)
{
    __m128 m = _mm_min_ps(v, _mm_shuffle_ps(v, v, 0x4e));
    m = _mm_min_ps(m, _mm_shuffle_ps(m, m, 0xb1));
    return _mm_cvtss_f32(m);
}

/* fmaf lane by lane: the portable kernel's fused multiply-add (a
 * correctly rounded function, so the same bits as the wider kernels'
 * instruction, in software where the host has none) */
static inline __m128 trilist_fma4(__m128 a, __m128 b, __m128 c)
{
    __m128 r;
    for (int j = 0; j < 4; j++)
        r[j] = fmaf(a[j], b[j], c[j]);
    return r;
}

#define KVF trilist_vf16
#define KVI trilist_vi16
#define KW 16
#define KNAME trilist_avx512
#define KNAME2 trilist_avx512_pair
#define KFIX trilist_avx512_fix
#define KEDGES trilist_edges16
#define KTARGET "avx512f"
#define KMASK(m) ((unsigned)(m))
#define KLANEMIN(v) trilist_min16((__m512)(v))
#define KFMA(a, b, c) ((KVF)_mm512_fmadd_ps((__m512)(a), (__m512)(b), (__m512)(c)))
#define KM __mmask16
#define KGE(a, b) _mm512_cmp_ps_mask((__m512)(a), (__m512)(b), _CMP_GE_OQ)
#define KLE(a, b) _mm512_cmp_ps_mask((__m512)(a), (__m512)(b), _CMP_LE_OQ)
#define KGT(a, b) _mm512_cmp_ps_mask((__m512)(a), (__m512)(b), _CMP_GT_OQ)
#define KLT(a, b) _mm512_cmp_ps_mask((__m512)(a), (__m512)(b), _CMP_LT_OQ)
#define KEQ(a, b) _mm512_cmp_ps_mask((__m512)(a), (__m512)(b), _CMP_EQ_OQ)
#define KNE(a, b) _mm512_cmp_ps_mask((__m512)(a), (__m512)(b), _CMP_NEQ_UQ)
#define KIGE(a, b) _mm512_cmp_epi32_mask((__m512i)(a), (__m512i)(b), _MM_CMPINT_NLT)
#define KSELF(m, a, b) ((KVF)_mm512_mask_blend_ps((m), (__m512)(b), (__m512)(a)))
#define KSELI(m, a, b) ((KVI)_mm512_mask_blend_epi32((m), (__m512i)(b), (__m512i)(a)))
#include "trilist_kernel.inc"

#define KVF trilist_vf8
#define KVI trilist_vi8
#define KW 8
#define KNAME trilist_avx2
#define KNAME2 trilist_avx2_pair
#define KFIX trilist_avx2_fix
#define KEDGES trilist_edges8
#define KTARGET "avx2,fma"
#define KMASK(m) ((unsigned)_mm256_movemask_ps((__m256)(m)))
#define KLANEMIN(v) trilist_min8((__m256)(v))
#define KFMA(a, b, c) ((KVF)_mm256_fmadd_ps((__m256)(a), (__m256)(b), (__m256)(c)))
#include "trilist_kernel.inc"

/* The portable kernel: SSE2, which every x86-64 host has. */
#define KVF trilist_vf4
#define KVI trilist_vi4
#define KW 4
#define KNAME trilist_sse2
#define KNAME2 trilist_sse2_pair
#define KFIX trilist_sse2_fix
#define KEDGES trilist_edges4
#define KMASK(m) ((unsigned)_mm_movemask_ps((__m128)(m)))
#define KLANEMIN(v) trilist_min4((__m128)(v))
#define KFMA(a, b, c) ((KVF)trilist_fma4((__m128)(a), (__m128)(b), (__m128)(c)))
#include "trilist_kernel.inc"

trilist_t *trilist_new(const float *positions, const uint32_t *indices, size_t count)
{
    trilist_t *l = calloc(1, sizeof *l);
    if (!l)
        return NULL;
    l->blocks = (count + TRILIST_BLOCK - 1) / TRILIST_BLOCK;
    size_t floats = (l->blocks ? l->blocks : 1) * TRILIST_ROWS * TRILIST_BLOCK;
    l->coords = aligned_alloc(64, floats * sizeof(float));
    if (!l->coords) {
        free(l);
        return NULL;
    }
    for (size_t i = 0; i < floats; i++)
        l->coords[i] = NAN;
    for (size_t tri = 0; tri < count; tri++) {
        float *c =
            l->coords + (tri / TRILIST_BLOCK) * TRILIST_ROWS * TRILIST_BLOCK + tri % TRILIST_BLOCK;
        float v[9];
        for (int k = 0; k < 9; k++)
            v[k] = c[k * TRILIST_BLOCK] = positions[3 * indices[3 * tri + k / 3] + k % 3];
        float e1[3] = {v[3] - v[0], v[4] - v[1], v[5] - v[2]};
        float e2[3] = {v[6] - v[0], v[7] - v[1], v[8] - v[2]};
        c[9 * TRILIST_BLOCK] = e1[1] * e2[2] - e1[2] * e2[1];
        c[10 * TRILIST_BLOCK] = e1[2] * e2[0] - e1[0] * e2[2];
        c[11 * TRILIST_BLOCK] = e1[0] * e2[1] - e1[1] * e2[0];
    }
    if (trilist_use_kernel(l, "avx512") < 0 && trilist_use_kernel(l, "avx2") < 0)
        trilist_use_kernel(l, "sse2");
    return l;
}

void trilist_destroy(trilist_t **lp)
{
    if (!lp || !*lp)
        return;
    free((*lp)->coords);
    free(*lp);
    *lp = NULL;
}

int trilist_use_kernel(trilist_t *l, const char *name)
{
    static const struct {
        const char *name;
        trilist_fn fn;
        trilist_pair_fn pair;
    } kernels[] = {
        {"avx512", trilist_avx512, trilist_avx512_pair},
        {"avx2", trilist_avx2, trilist_avx2_pair},
        {"sse2", trilist_sse2, trilist_sse2_pair},
    };
    __builtin_cpu_init();
    for (size_t i = 0; i < sizeof kernels / sizeof kernels[0]; i++) {
        if (strcmp(name, kernels[i].name) != 0)
            continue;
        /* __builtin_cpu_supports wants a literal */
        int ok = i == 0   ? __builtin_cpu_supports("avx512f")
                 : i == 1 ? __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma")
                          : __builtin_cpu_supports("sse2");
        if (!ok)
            return -1;
        l->fn = kernels[i].fn;
        l->pair = kernels[i].pair;
        l->kernel = kernels[i].name;
        return 0;
    }
    return -1;
}

const char *trilist_kernel(const trilist_t *l)
{
    return l->kernel;
}

int trilist_intersect(const trilist_t *l, vec3_t o, vec3_t d, float tfar, uint32_t *tri, float *t,
                      float *u, float *v)
{
    const float of[3] = {o.x, o.y, o.z}, df[3] = {d.x, d.y, d.z};
    trilist_hit_t h;
    if (!l->fn(l, of, df, tfar, 0, &h))
        return 0;
    *tri = h.tri;
    *t = h.t;
    *u = h.u;
    *v = h.v;
    return 1;
}

int trilist_occluded(const trilist_t *l, vec3_t o, vec3_t d, float tfar)
{
    const float of[3] = {o.x, o.y, o.z}, df[3] = {d.x, d.y, d.z};
    return l->fn(l, of, df, tfar, 1, NULL);
}

void trilist_intersect_pair(const trilist_t *l, const vec3_t o[2], const vec3_t d[2], int hit[2],
                            uint32_t tri[2], float t[2], float u[2], float v[2])
{
    const float of[2][3] = {{o[0].x, o[0].y, o[0].z}, {o[1].x, o[1].y, o[1].z}};
    const float df[2][3] = {{d[0].x, d[0].y, d[0].z}, {d[1].x, d[1].y, d[1].z}};
    trilist_hit_t h[2];
    l->pair(l, of, df, INFINITY, 0, hit, h);
    for (int k = 0; k < 2; k++)
        if (hit[k]) {
            tri[k] = h[k].tri;
            t[k] = h[k].t;
            u[k] = h[k].u;
            v[k] = h[k].v;
        }
}

void trilist_occluded_pair(const trilist_t *l, const vec3_t o[2], const vec3_t d[2], float tfar,
                           int hit[2])
{
    const float of[2][3] = {{o[0].x, o[0].y, o[0].z}, {o[1].x, o[1].y, o[1].z}};
    const float df[2][3] = {{d[0].x, d[0].y, d[0].z}, {d[1].x, d[1].y, d[1].z}};
    l->pair(l, of, df, tfar, 1, hit, NULL);
}
