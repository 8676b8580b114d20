/* closedmesh.h - closed triangle meshes built in memory, for the tests
 * and benchmarks of ray casting (test_trilist, bench_trilist): vertices
 * are shared exactly between the triangles that meet there, so a mesh is
 * watertight in floating point as well.
 */
#ifndef VB_CLOSEDMESH_H
#define VB_CLOSEDMESH_H

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef struct closedmesh {
    float *pos;    /* xyz per vertex */
    uint32_t *idx; /* three per triangle */
    size_t nv, nt, cap_v, cap_t;
} closedmesh_t;

static inline void *closedmesh_grow_(void *p, size_t *cap, size_t each)
{
    *cap = *cap ? 2 * *cap : 64;
    p = realloc(p, *cap * each);
    if (!p) {
        fprintf(stderr, "closedmesh: out of memory\n");
        abort();
    }
    return p;
}

/* The index of vertex (x, y, z), added if no vertex has those bits. */
static inline uint32_t closedmesh_vertex(closedmesh_t *m, float x, float y, float z)
{
    for (size_t i = 0; i < m->nv; i++)
        if (m->pos[3 * i] == x && m->pos[3 * i + 1] == y && m->pos[3 * i + 2] == z)
            return (uint32_t)i;
    if (m->nv == m->cap_v)
        m->pos = closedmesh_grow_(m->pos, &m->cap_v, 3 * sizeof(float));
    m->pos[3 * m->nv] = x;
    m->pos[3 * m->nv + 1] = y;
    m->pos[3 * m->nv + 2] = z;
    return (uint32_t)m->nv++;
}

static inline void closedmesh_tri(closedmesh_t *m, uint32_t a, uint32_t b, uint32_t c)
{
    if (m->nt == m->cap_t)
        m->idx = closedmesh_grow_(m->idx, &m->cap_t, 3 * sizeof(uint32_t));
    m->idx[3 * m->nt] = a;
    m->idx[3 * m->nt + 1] = b;
    m->idx[3 * m->nt + 2] = c;
    m->nt++;
}

static inline void closedmesh_free(closedmesh_t *m)
{
    free(m->pos);
    free(m->idx);
    memset(m, 0, sizeof *m);
}

/* The midpoint of edge (a, b) pushed onto the unit sphere: the same bits
 * for (b, a), so both faces of the edge share it. */
static inline uint32_t closedmesh_midpoint_(closedmesh_t *m, uint32_t a, uint32_t b)
{
    float p[3];
    double len = 0;
    for (int k = 0; k < 3; k++) {
        p[k] = m->pos[3 * a + k] + m->pos[3 * b + k];
        len += (double)p[k] * p[k];
    }
    len = sqrt(len);
    return closedmesh_vertex(m, (float)(p[0] / len), (float)(p[1] / len), (float)(p[2] / len));
}

/* An icosphere of radius 1: 20 * 4^levels triangles sharing every edge. */
static inline closedmesh_t closedmesh_icosphere(int levels)
{
    closedmesh_t m = {0};
    const float t = 1.6180339887f, s = 1.0f / sqrtf(1.0f + t * t), a = t * s;
    const float v[12][3] = {{-s, a, 0}, {s, a, 0}, {-s, -a, 0}, {s, -a, 0},
                            {0, -s, a}, {0, s, a}, {0, -s, -a}, {0, s, -a},
                            {a, 0, -s}, {a, 0, s}, {-a, 0, -s}, {-a, 0, s}};
    for (int i = 0; i < 12; i++)
        closedmesh_vertex(&m, v[i][0], v[i][1], v[i][2]);
    static const uint32_t f[20][3] = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                                      {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                                      {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                                      {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
    for (int i = 0; i < 20; i++)
        closedmesh_tri(&m, f[i][0], f[i][1], f[i][2]);
    for (int l = 0; l < levels; l++) {
        closedmesh_t n = {0};
        for (size_t i = 0; i < m.nv; i++)
            closedmesh_vertex(&n, m.pos[3 * i], m.pos[3 * i + 1], m.pos[3 * i + 2]);
        for (size_t i = 0; i < m.nt; i++) {
            uint32_t x = m.idx[3 * i], y = m.idx[3 * i + 1], z = m.idx[3 * i + 2];
            uint32_t xy = closedmesh_midpoint_(&n, x, y), yz = closedmesh_midpoint_(&n, y, z),
                     zx = closedmesh_midpoint_(&n, z, x);
            closedmesh_tri(&n, x, xy, zx);
            closedmesh_tri(&n, y, yz, xy);
            closedmesh_tri(&n, z, zx, yz);
            closedmesh_tri(&n, xy, yz, zx);
        }
        closedmesh_free(&m);
        m = n;
    }
    return m;
}

#endif
