/* trilist.h - ray casting against a small scene without a BVH.
 *
 * A scene of a few dozen triangles (the Cornell box has 32) is faster to
 * test whole, 8 or 16 triangles per SIMD instruction, than to traverse: the
 * tracer picks this or Embree at load time by triangle count alone
 * (TRILIST_MAX_TRIANGLES), so every worker of a job makes the same choice.
 *
 * The ray-triangle test is the watertight one of Woop, Benthin and Wald
 * (JCGT 2013), as pbrt-v3/v4 write it: vertices translated to the ray
 * origin, sheared so the ray runs along +z, and the three edge functions
 * evaluated identically for the two triangles that share an edge (redone
 * in double when one is exactly zero), so a ray through a shared edge or
 * vertex of a closed mesh always hits one of its triangles. Only IEEE
 * operations in a fixed order, no FMA, no approximate reciprocals: the
 * 16-wide (AVX-512), 8-wide (AVX2) and 4-wide (SSE2) kernels give the same bits,
 * so the image does not depend on the host's ISA. The nearest hit wins,
 * ties to the lowest triangle index.
 */
#ifndef VB_TRILIST_H
#define VB_TRILIST_H

#include <stddef.h>
#include <stdint.h>

#include "vmath.h"

/* The largest scene traced without a BVH: bench_trilist measured the list
 * 1.2x (closest hit) and 1.5x (shadow) Embree's ROBUST BVH at 108
 * triangles, 0.5x and 0.3x at 192 (bench/RESULTS.md, "Core speed"); seven
 * blocks of 16. */
#define TRILIST_MAX_TRIANGLES 112

typedef struct trilist trilist_t;

/* Copies count triangles (indices into positions, xyz floats). Returns
 * NULL when out of memory. */
trilist_t *trilist_new(const float *positions, const uint32_t *indices, size_t count);
void trilist_destroy(trilist_t **l);

/* Switches to the kernel named "avx512", "avx2" or "sse2" (the widest the
 * host runs is the default); -1 if the host cannot run it or the name is
 * unknown. For tests that compare them. */
int trilist_use_kernel(trilist_t *l, const char *name);

/* The kernel in use: "avx512", "avx2" or "sse2" (same bits in all). */
const char *trilist_kernel(const trilist_t *l);

/* Nearest hit of o + t d with 0 < t < tfar: 1 and the triangle, t and
 * Embree-style barycentrics (p = (1-u-v) v0 + u v1 + v v2), or 0. */
int trilist_intersect(const trilist_t *l, vec3_t o, vec3_t d, float tfar, uint32_t *tri, float *t,
                      float *u, float *v);

/* 1 if any triangle is hit with 0 < t < tfar. */
int trilist_occluded(const trilist_t *l, vec3_t o, vec3_t d, float tfar);

/* trilist_intersect (tfar infinite) and trilist_occluded of two rays at
 * once: each ray's result the bits the one-ray call gives (hit[i] 1 when
 * ray i hits; tri, t, u, v written only then), in less time than two
 * calls (trilist_kernel.inc). */
void trilist_intersect_pair(const trilist_t *l, const vec3_t o[2], const vec3_t d[2], int hit[2],
                            uint32_t tri[2], float t[2], float u[2], float v[2]);
void trilist_occluded_pair(const trilist_t *l, const vec3_t o[2], const vec3_t d[2], float tfar,
                           int hit[2]);
#endif
