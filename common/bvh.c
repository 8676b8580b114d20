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

/* A triangle's part of a box cut at `position` along `dim` (Embree's
 * spatial splits): its vertices and where its edges cross the plane, each
 * side's bounds clipped to the reference's own. */
static void build_split(const struct RTCBuildPrimitive *prim, unsigned int dim, float position,
                        struct RTCBounds *left, struct RTCBounds *right, void *user)
{
    const split_user_t *su = user;
    const uint32_t *vi = su->indices + 3 * prim->primID;
    float lo[2][3], hi[2][3];
    for (int s = 0; s < 2; s++)
        for (int k = 0; k < 3; k++) {
            lo[s][k] = INFINITY;
            hi[s][k] = -INFINITY;
        }
    for (int e = 0; e < 3; e++) {
        const float *a = su->positions + 3 * vi[e], *b = su->positions + 3 * vi[(e + 1) % 3];
        float pa = a[dim], pb = b[dim];
        int s = pa <= position ? 0 : 1;
        for (int k = 0; k < 3; k++) {
            lo[s][k] = a[k] < lo[s][k] ? a[k] : lo[s][k];
            hi[s][k] = a[k] > hi[s][k] ? a[k] : hi[s][k];
        }
        if ((pa < position && pb > position) || (pa > position && pb < position)) {
            float f = (position - pa) / (pb - pa);
            for (int k = 0; k < 3; k++) {
                float x = (unsigned)k == dim ? position : a[k] + f * (b[k] - a[k]);
                for (int q = 0; q < 2; q++) {
                    lo[q][k] = x < lo[q][k] ? x : lo[q][k];
                    hi[q][k] = x > hi[q][k] ? x : hi[q][k];
                }
            }
        }
    }
    const float plo[3] = {prim->lower_x, prim->lower_y, prim->lower_z};
    const float phi[3] = {prim->upper_x, prim->upper_y, prim->upper_z};
    struct RTCBounds *out[2] = {left, right};
    for (int s = 0; s < 2; s++) {
        float l[3], h[3];
        for (int k = 0; k < 3; k++) {
            l[k] = lo[s][k] > plo[k] ? lo[s][k] : plo[k];
            h[k] = hi[s][k] < phi[k] ? hi[s][k] : phi[k];
        }
        if (s == 0)
            h[dim] = h[dim] < position ? h[dim] : position;
        else
            l[dim] = l[dim] > position ? l[dim] : position;
        *out[s] = (struct RTCBounds){.lower_x = l[0],
                                     .lower_y = l[1],
                                     .lower_z = l[2],
                                     .upper_x = h[0],
                                     .upper_y = h[1],
                                     .upper_z = h[2]};
    }
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
    if (strcmp(name, "avx2") == 0 && __builtin_cpu_supports("avx2")) {
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
    return __builtin_cpu_supports("avx2") != 0; /* (a flag bit, not 1) */
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

#define KNAME bvh_trace_avx2
#define KFIX bvh_fix_avx2
#define KTARGET "avx2"
#include "bvh_kernel.inc"
#undef KNAME
#undef KFIX
#undef KTARGET

#define KNAME bvh_trace_avx512
#define KFIX bvh_fix_avx512
#define KTARGET "avx2,avx512f,avx512vl"
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
