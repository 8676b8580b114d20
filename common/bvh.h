/* bvh.h - watertight ray casting over a BVH that Embree builds.
 *
 * Embree builds the hierarchy (rtcBuildBVH: SAH with spatial splits over
 * the triangles, 8 children a node, leaves of up to 8 triangles); the
 * traversal is ours, watertight by construction (issue 23's conditions):
 *  - a box is tested as Ize's "Robust BVH Ray Traversal" (JCGT 2013) and
 *    pbrt-v4 test it: slab distances from the rounded reciprocal, the far
 *    distance widened by 1 + 2 gamma(3), so no box the ray passes through
 *    is ever culled by rounding;
 *  - a leaf's triangles get trilist's test (Woop, Benthin and Wald's
 *    watertight test, t from the plane), the very operations of the list
 *    kernel, 8 triangles at a time.
 * The nearest hit wins, ties to the lowest triangle index, whatever order
 * the leaves are visited in: a hit is the one the whole list would give
 * (trilist.h) unless two triangles' t differ by less than the box test's
 * rounding, and even then it depends on the hierarchy alone, which Embree
 * builds the same from the same triangles.
 */
#ifndef VB_BVH_H
#define VB_BVH_H

#include <embree3/rtcore.h>
#include <stddef.h>
#include <stdint.h>

#include "vmath.h"

typedef struct bvh bvh_t;

/* 1 if this host runs the traversal (AVX2 and FMA); Embree's own is used
 * otherwise. */
int bvh_supported(void);

/* Builds the hierarchy over count triangles (indices into positions, xyz
 * floats) with Embree's builder on device. Returns NULL with a message in
 * err when Embree fails or memory runs out. */
bvh_t *bvh_new(RTCDevice device, const float *positions, const uint32_t *indices, size_t count,
               char *err, size_t errlen);
void bvh_destroy(bvh_t **b);

/* The build's spatial split of one triangle (Embree's splitPrimitive
 * callback): the bounds of its parts left (<= position) and right of the
 * plane at `position` along axis dim (0-2), each within box. For tests. */
void bvh_split_bounds(const float p0[3], const float p1[3], const float p2[3],
                      const struct RTCBounds *box, unsigned int dim, float position,
                      struct RTCBounds *left, struct RTCBounds *right);

/* Switches to the traversal compiled for "avx512" (AVX-512VL: 32
 * registers, the same 8 lanes) or "avx2" (the default is the widest the
 * host runs; both give the same bits); -1 if the host cannot run it or
 * the name is unknown. For tests that compare them. */
int bvh_use_kernel(bvh_t *b, const char *name);

/* The traversal in use: "avx512" or "avx2". */
const char *bvh_kernel(const bvh_t *b);

/* Bytes the hierarchy and its triangles take. */
size_t bvh_bytes(const bvh_t *b);

/* Nearest hit of o + t d with 0 < t < tfar: 1 and the triangle, t and
 * Embree-style barycentrics (p = (1-u-v) v0 + u v1 + v v2), or 0. */
int bvh_intersect(const bvh_t *b, vec3_t o, vec3_t d, float tfar, uint32_t *tri, float *t, float *u,
                  float *v);

/* 1 if any triangle is hit with 0 < t < tfar. */
int bvh_occluded(const bvh_t *b, vec3_t o, vec3_t d, float tfar);

#endif
