/* bvh.c - a watertight traversal of ours over a BVH Embree builds (bvh.h). */
#include "bvh.h"

#include <immintrin.h>
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Children a node, triangles a leaf: AVX2's lanes. */
#define BVH_WIDTH 8
/* Rows of a leaf: trilist's, three vertices and the plane's normal. */
#define BVH_ROWS 12
/* Entries the traversal stack holds: a node pushes at most 7 of its 8
 * children, the hierarchy is at most BVH_MAX_DEPTH deep. */
#define BVH_MAX_DEPTH 40
#define BVH_STACK (BVH_MAX_DEPTH * (BVH_WIDTH - 1) + 1)

typedef struct bvh_node {
    float lo[3][BVH_WIDTH], hi[3][BVH_WIDTH]; /* a child's box; empty: lo +inf, hi -inf */
    int32_t child[BVH_WIDTH];                 /* node index, or ~leaf index */
} bvh_node_t;

typedef struct bvh_leaf {
    float rows[BVH_ROWS][BVH_WIDTH]; /* NaN past the last triangle */
    int32_t tri[BVH_WIDTH];
} bvh_leaf_t;

typedef struct bvh_best {
    float t, e1, e2, det;
    int32_t tri; /* INT32_MAX: none yet */
} bvh_best_t;

struct bvh {
    bvh_node_t *nodes;
    size_t node_count;
    bvh_leaf_t *leaves;
    size_t leaf_count;
    int32_t root; /* node index, ~leaf index, or BVH_EMPTY */
    int (*trace)(const struct bvh *b, const float o[3], const float d[3], float tfar, int any,
                 bvh_best_t *best);
    const char *kernel;
};

#define BVH_EMPTY INT32_MIN

/* ---- building: Embree's builder into temporary nodes, then flattened ---- */

typedef struct build_item {
    int leaf;
    unsigned count;
    void *child[BVH_WIDTH];
    struct RTCBounds bounds[BVH_WIDTH];
    uint32_t prim[BVH_WIDTH];
} build_item_t;

static void *build_node(RTCThreadLocalAllocator alloc, unsigned int count, void *user)
{
    (void)user;
    build_item_t *n = rtcThreadLocalAlloc(alloc, sizeof *n, 16);
    if (n) {
        n->leaf = 0;
        n->count = count;
    }
    return n;
}

static void build_children(void *node, void **children, unsigned int count, void *user)
{
    (void)user;
    build_item_t *n = node;
    for (unsigned i = 0; i < count && i < BVH_WIDTH; i++)
        n->child[i] = children[i];
}

static void build_bounds(void *node, const struct RTCBounds **bounds, unsigned int count,
                         void *user)
{
    (void)user;
    build_item_t *n = node;
    for (unsigned i = 0; i < count && i < BVH_WIDTH; i++)
        n->bounds[i] = *bounds[i];
}

static void *build_leaf(RTCThreadLocalAllocator alloc, const struct RTCBuildPrimitive *prims,
                        size_t count, void *user)
{
    (void)user;
    build_item_t *n = rtcThreadLocalAlloc(alloc, sizeof *n, 16);
    if (!n)
        return NULL;
    n->leaf = 1;
    n->count = (unsigned)count;
    /* in index order: a leaf's layout does not depend on the build's threads */
    for (size_t i = 0; i < count; i++) {
        uint32_t p = prims[i].primID;
        size_t j = i;
        for (; j > 0 && n->prim[j - 1] > p; j--)
            n->prim[j] = n->prim[j - 1];
        n->prim[j] = p;
    }
    return n;
}

typedef struct split_user {
    const float *positions;
    const uint32_t *indices;
} split_user_t;

/* A point of positions as a vector (x, y, z, 0). */
static inline __m128 split_point(const float *p)
{
    return _mm_set_ps(0.0f, p[2], p[1], p[0]);
}

/* a where mask is set, else b */
static inline __m128 split_select(__m128 mask, __m128 a, __m128 b)
{
    return _mm_or_ps(_mm_and_ps(mask, a), _mm_andnot_ps(mask, b));
}

/* A triangle's part of a box cut at `position` along `dim` (Embree's
 * spatial splits): its vertices and where its edges cross the plane, each
 * side's bounds clipped to the reference's own. Embree asks this for every
 * reference at every candidate plane, so it was most of a 100k-triangle
 * build (0.32 s of the Buddha's, 2 threads): x, y and z go together in one
 * SSE vector (0.22 s), each lane with the scalar code's operations (a < lo
 * ? a : lo is minps), so the bounds keep the bits test_bvh's scalar
 * version gives them. */
static inline void split_bounds(const float *p0, const float *p1, const float *p2, __m128 plo,
                                __m128 phi, unsigned int dim, float position,
                                struct RTCBounds *left, struct RTCBounds *right)
{
    const __m128 plane = _mm_set1_ps(position);
    const __m128 on_dim =
        _mm_castsi128_ps(_mm_set_epi32(0, dim == 2 ? -1 : 0, dim == 1 ? -1 : 0, dim == 0 ? -1 : 0));
    /* (named, not indexed by side, so they stay in registers; branch-free
     * selects measured slower than the branches) */
    __m128 lo0 = _mm_set1_ps(INFINITY), lo1 = lo0;
    __m128 hi0 = _mm_set1_ps(-INFINITY), hi1 = hi0;
    for (int e = 0; e < 3; e++) {
        const float *pa = e == 0 ? p0 : e == 1 ? p1 : p2, *pb = e == 0 ? p1 : e == 1 ? p2 : p0;
        __m128 a = split_point(pa), b = split_point(pb);
        float ca = pa[dim], cb = pb[dim];
        /* a vertex on the plane bounds both parts (Embree's own splitter
         * does the same): the part right of the plane starts there too */
        if (ca <= position) {
            lo0 = _mm_min_ps(a, lo0);
            hi0 = _mm_max_ps(a, hi0);
        }
        if (ca >= position) {
            lo1 = _mm_min_ps(a, lo1);
            hi1 = _mm_max_ps(a, hi1);
        }
        if ((ca < position && cb > position) || (ca > position && cb < position)) {
            float f = (position - ca) / (cb - ca);
            __m128 x = _mm_add_ps(a, _mm_mul_ps(_mm_set1_ps(f), _mm_sub_ps(b, a)));
            x = split_select(on_dim, plane, x);
            lo0 = _mm_min_ps(x, lo0);
            hi0 = _mm_max_ps(x, hi0);
            lo1 = _mm_min_ps(x, lo1);
            hi1 = _mm_max_ps(x, hi1);
        }
    }
    __m128 l0 = _mm_max_ps(lo0, plo), h0 = _mm_min_ps(hi0, phi);
    __m128 l1 = _mm_max_ps(lo1, plo), h1 = _mm_min_ps(hi1, phi);
    /* the left side ends at the plane, the right one starts there */
    h0 = split_select(on_dim, _mm_min_ps(h0, plane), h0);
    l1 = split_select(on_dim, _mm_max_ps(l1, plane), l1);
    /* RTCBounds is (lower xyz, pad, upper xyz, pad), 16-byte aligned; the
     * pads get the lanes' zeros, as before */
    _mm_store_ps(&left->lower_x, l0);
    _mm_store_ps(&left->upper_x, h0);
    _mm_store_ps(&right->lower_x, l1);
    _mm_store_ps(&right->upper_x, h1);
}

static void build_split(const struct RTCBuildPrimitive *prim, unsigned int dim, float position,
                        struct RTCBounds *left, struct RTCBounds *right, void *user)
{
    const split_user_t *su = user;
    const uint32_t *vi = su->indices + 3 * prim->primID;
    split_bounds(su->positions + 3 * vi[0], su->positions + 3 * vi[1], su->positions + 3 * vi[2],
                 _mm_set_ps(0.0f, prim->lower_z, prim->lower_y, prim->lower_x),
                 _mm_set_ps(0.0f, prim->upper_z, prim->upper_y, prim->upper_x), dim, position, left,
                 right);
}

void bvh_split_bounds(const float p0[3], const float p1[3], const float p2[3],
                      const struct RTCBounds *box, unsigned int dim, float position,
                      struct RTCBounds *left, struct RTCBounds *right)
{
    split_bounds(p0, p1, p2, _mm_set_ps(0.0f, box->lower_z, box->lower_y, box->lower_x),
                 _mm_set_ps(0.0f, box->upper_z, box->upper_y, box->upper_x), dim, position, left,
                 right);
}

typedef struct flatten {
    bvh_t *b;
    const float *positions;
    const uint32_t *indices;
    size_t node_cap, leaf_cap;
    int failed;
} flatten_t;

/* Room in *items (count of them, cap allocated, each bytes apiece,
 * cache-line aligned) for one more; -1 when out of memory. */
static int flatten_room(void **items, size_t count, size_t *cap, size_t each)
{
    if (count < *cap)
        return 0;
    size_t grown = *cap ? 2 * *cap : 64;
    void *p = aligned_alloc(64, grown * each);
    if (!p)
        return -1;
    if (count)
        memcpy(p, *items, count * each);
    free(*items);
    *items = p;
    *cap = grown;
    return 0;
}

static int32_t flatten_leaf(flatten_t *f, const build_item_t *n)
{
    bvh_t *b = f->b;
    if (flatten_room((void **)&b->leaves, b->leaf_count, &f->leaf_cap, sizeof *b->leaves) < 0) {
        f->failed = 1;
        return BVH_EMPTY;
    }
    bvh_leaf_t *l = &b->leaves[b->leaf_count];
    for (int r = 0; r < BVH_ROWS; r++)
        for (int j = 0; j < BVH_WIDTH; j++)
            l->rows[r][j] = NAN;
    for (int j = 0; j < BVH_WIDTH; j++)
        l->tri[j] = INT32_MAX;
    for (unsigned j = 0; j < n->count && j < BVH_WIDTH; j++) {
        uint32_t tri = n->prim[j];
        float v[9];
        for (int k = 0; k < 9; k++)
            v[k] = l->rows[k][j] = f->positions[3 * f->indices[3 * tri + k / 3] + k % 3];
        float e1[3] = {v[3] - v[0], v[4] - v[1], v[5] - v[2]};
        float e2[3] = {v[6] - v[0], v[7] - v[1], v[8] - v[2]};
        l->rows[9][j] = e1[1] * e2[2] - e1[2] * e2[1];
        l->rows[10][j] = e1[2] * e2[0] - e1[0] * e2[2];
        l->rows[11][j] = e1[0] * e2[1] - e1[1] * e2[0];
        l->tri[j] = (int32_t)tri;
    }
    return ~(int32_t)b->leaf_count++;
}

static int32_t flatten_item(flatten_t *f, const build_item_t *n, int depth)
{
    if (!n || depth > BVH_MAX_DEPTH) {
        f->failed = 1;
        return BVH_EMPTY;
    }
    if (n->leaf)
        return flatten_leaf(f, n);
    bvh_t *b = f->b;
    if (flatten_room((void **)&b->nodes, b->node_count, &f->node_cap, sizeof *b->nodes) < 0) {
        f->failed = 1;
        return BVH_EMPTY;
    }
    size_t at = b->node_count++;
    bvh_node_t node;
    for (int j = 0; j < BVH_WIDTH; j++) {
        for (int k = 0; k < 3; k++) {
            node.lo[k][j] = INFINITY;
            node.hi[k][j] = -INFINITY;
        }
        node.child[j] = BVH_EMPTY;
    }
    for (unsigned j = 0; j < n->count && j < BVH_WIDTH; j++) {
        const struct RTCBounds *bd = &n->bounds[j];
        node.lo[0][j] = bd->lower_x;
        node.lo[1][j] = bd->lower_y;
        node.lo[2][j] = bd->lower_z;
        node.hi[0][j] = bd->upper_x;
        node.hi[1][j] = bd->upper_y;
        node.hi[2][j] = bd->upper_z;
        node.child[j] = flatten_item(f, n->child[j], depth + 1);
        if (f->failed)
            return BVH_EMPTY;
    }
    b->nodes[at] = node;
    return (int32_t)at;
}

static int bvh_trace_avx2(const bvh_t *b, const float o[3], const float d[3], float tfar, int any,
                          bvh_best_t *best);
static int bvh_trace_avx512(const bvh_t *b, const float o[3], const float d[3], float tfar, int any,
                            bvh_best_t *best);

int bvh_use_kernel(bvh_t *b, const char *name)
{
    __builtin_cpu_init();
    if (strcmp(name, "avx512") == 0 && __builtin_cpu_supports("avx512vl")) {
        b->trace = bvh_trace_avx512;
        b->kernel = "avx512";
        return 0;
    }
    if (strcmp(name, "avx2") == 0 && bvh_supported()) {
        b->trace = bvh_trace_avx2;
        b->kernel = "avx2";
        return 0;
    }
    return -1;
}

const char *bvh_kernel(const bvh_t *b)
{
    return b->kernel;
}

int bvh_supported(void)
{
    __builtin_cpu_init();
    /* (flag bits, not 1) */
    return __builtin_cpu_supports("avx2") != 0 && __builtin_cpu_supports("fma") != 0;
}

bvh_t *bvh_new(RTCDevice device, const float *positions, const uint32_t *indices, size_t count,
               char *err, size_t errlen)
{
    bvh_t *b = calloc(1, sizeof *b);
    if (!b) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    b->root = BVH_EMPTY;
    if (bvh_use_kernel(b, "avx512") < 0 && bvh_use_kernel(b, "avx2") < 0) {
        snprintf(err, errlen, "this host has no AVX2: the BVH traversal needs it");
        free(b);
        return NULL;
    }
    if (count == 0)
        return b;
    if (count > (size_t)INT32_MAX / 2) {
        snprintf(err, errlen, "%zu triangles: more than the BVH indexes", count);
        free(b);
        return NULL;
    }
    /* room for the references spatial splits add */
    size_t capacity = 2 * count;
    struct RTCBuildPrimitive *prims = aligned_alloc(32, capacity * sizeof *prims);
    if (!prims) {
        snprintf(err, errlen, "out of memory");
        free(b);
        return NULL;
    }
    for (size_t i = 0; i < count; i++) {
        float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
        for (int c = 0; c < 3; c++)
            for (int k = 0; k < 3; k++) {
                float x = positions[3 * indices[3 * i + c] + k];
                lo[k] = x < lo[k] ? x : lo[k];
                hi[k] = x > hi[k] ? x : hi[k];
            }
        prims[i] = (struct RTCBuildPrimitive){.lower_x = lo[0],
                                              .lower_y = lo[1],
                                              .lower_z = lo[2],
                                              .geomID = 0,
                                              .upper_x = hi[0],
                                              .upper_y = hi[1],
                                              .upper_z = hi[2],
                                              .primID = (unsigned)i};
    }
    RTCBVH h = rtcNewBVH(device);
    if (!h) {
        snprintf(err, errlen, "rtcNewBVH failed: Embree error %d", (int)rtcGetDeviceError(device));
        free(prims);
        free(b);
        return NULL;
    }
    struct RTCBuildArguments a = rtcDefaultBuildArguments();
    a.byteSize = sizeof a;
    /* with spatial splits: 1.16x the rays/s of plain binned SAH on the
     * Buddha's recorded path rays, for 12 % more references */
    a.buildQuality = RTC_BUILD_QUALITY_HIGH;
    a.maxBranchingFactor = BVH_WIDTH;
    a.maxDepth = BVH_MAX_DEPTH;
    /* a leaf costs one 8-wide test whatever its count, and Embree's builder
     * splits every child it can until a node has 8: so nothing of 8 or
     * fewer triangles is split (leaves of 2.7 triangles and 0.72x the
     * rays/s otherwise, on the Buddha) */
    a.sahBlockSize = BVH_WIDTH;
    a.minLeafSize = BVH_WIDTH;
    a.maxLeafSize = BVH_WIDTH;
    a.traversalCost = 1.0f;
    a.intersectionCost = 1.0f;
    a.bvh = h;
    a.primitives = prims;
    a.primitiveCount = count;
    a.primitiveArrayCapacity = capacity;
    split_user_t su = {positions, indices};
    a.splitPrimitive = build_split;
    a.userPtr = &su;
    a.createNode = build_node;
    a.setNodeChildren = build_children;
    a.setNodeBounds = build_bounds;
    a.createLeaf = build_leaf;
    void *root = rtcBuildBVH(&a);
    flatten_t f = {.b = b, .positions = positions, .indices = indices};
    if (!root || rtcGetDeviceError(device) != RTC_ERROR_NONE)
        f.failed = 1;
    else
        b->root = flatten_item(&f, root, 0);
    rtcReleaseBVH(h);
    free(prims);

    if (f.failed) {
        snprintf(err, errlen, "building the BVH over %zu triangles failed (Embree or memory)",
                 count);
        bvh_destroy(&b);
        return NULL;
    }
    return b;
}

void bvh_destroy(bvh_t **bp)
{
    if (!bp || !*bp)
        return;
    free((*bp)->nodes);
    free((*bp)->leaves);
    free(*bp);
    *bp = NULL;
}

size_t bvh_bytes(const bvh_t *b)
{
    return sizeof *b + b->node_count * sizeof(bvh_node_t) + b->leaf_count * sizeof(bvh_leaf_t);
}

/* ---- traversal ------------------------------------------------------------ */

typedef float bvh_vf __attribute__((vector_size(4 * BVH_WIDTH)));
typedef int32_t bvh_vi __attribute__((vector_size(4 * BVH_WIDTH)));

/* The far slab distance widened by 1 + 2 gamma(3) (pbrt-v4's
 * Bounds3::IntersectP, after Ize): covers the reciprocal's, subtraction's
 * and product's rounding. */
#define BVH_FAR_SCALE (1.0f + 2.0f * (3.0f * 0x1p-24f) / (1.0f - 3.0f * 0x1p-24f))
/* a * b + c rounded once, in both builds' 8 lanes */
#define BVH_FMA(a, b, c) ((bvh_vf)_mm256_fmadd_ps((__m256)(a), (__m256)(b), (__m256)(c)))

#define KNAME bvh_trace_avx2
#define KFIX bvh_fix_avx2
#define KTARGET "avx2,fma"
#include "bvh_kernel.inc"
#undef KNAME
#undef KFIX
#undef KTARGET

#define KNAME bvh_trace_avx512
#define KFIX bvh_fix_avx512
#define KTARGET "avx2,fma,avx512f,avx512vl"
#include "bvh_kernel.inc"
#undef KNAME
#undef KFIX
#undef KTARGET

typedef int (*bvh_trace_fn)(const bvh_t *b, const float o[3], const float d[3], float tfar, int any,
                            bvh_best_t *best);

static int bvh_trace(const bvh_t *b, const float o[3], const float d[3], float tfar, int any,
                     bvh_best_t *best)
{
    return b->trace(b, o, d, tfar, any, best);
}

int bvh_intersect(const bvh_t *b, vec3_t o, vec3_t d, float tfar, uint32_t *tri, float *t, float *u,
                  float *v)
{
    const float of[3] = {o.x, o.y, o.z}, df[3] = {d.x, d.y, d.z};
    bvh_best_t best;
    if (!bvh_trace(b, of, df, tfar, 0, &best))
        return 0;
    *tri = (uint32_t)best.tri;
    *t = best.t;
    *u = best.e1 / best.det;
    *v = best.e2 / best.det;
    return 1;
}

int bvh_occluded(const bvh_t *b, vec3_t o, vec3_t d, float tfar)
{
    const float of[3] = {o.x, o.y, o.z}, df[3] = {d.x, d.y, d.z};
    bvh_best_t best;
    return bvh_trace(b, of, df, tfar, 1, &best);
}
