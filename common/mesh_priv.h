/* mesh_priv.h - the interface between the mesh front end (mesh.c) and its
 * format readers (ply.c, obj.c); not for use outside those files.
 *
 * mesh.c owns the error context and the mesh under construction (the
 * builder): a reader checks every value it takes from the file, then hands
 * vertices to mesh_store_vertex and triangles to mesh_emit_tri; mesh.c
 * turns the builder into a mesh_t once the reader has succeeded.
 */
#ifndef VB_MESH_PRIV_H
#define VB_MESH_PRIV_H

#include <stddef.h>
#include <stdint.h>

#include "mesh.h"

/* ---- errors ------------------------------------------------------------- */

typedef struct mesh_ctx {
    const char *name; /* file name for messages */
    char *err;
    size_t errlen;
    unsigned flags;       /* MESH_* of mesh.h */
    uint32_t shape_index; /* which shape of a file of several (serialized) */
} mesh_ctx;

/* Writes "name: message" into the caller's buffer; returns -1. */
__attribute__((format(printf, 2, 3))) int mesh_fail(const mesh_ctx *c, const char *fmt, ...);

/* Writes "name: line N: message" (text) or "name: byte N: message"
 * (binary PLY, where loc is a byte offset); returns -1. */
__attribute__((format(printf, 4, 5))) int mesh_fail_at(const mesh_ctx *c, int binary, size_t loc,
                                                       const char *fmt, ...);

/* Length of a token for quoting in messages: enough to recognise it, short
 * enough that a megabyte-long garbage token does not fill the message. */
static inline int mesh_quote_len(size_t len)
{
    return len > 40 ? 40 : (int)len;
}

/* ---- the mesh under construction ---------------------------------------- */

typedef struct mesh_builder {
    float *pos;          /* 3 per vertex */
    float *nrm;          /* 3 per vertex, or NULL */
    float *uv;           /* 2 per vertex, or NULL (MESH_ATTRIBUTES) */
    size_t nv, vcap;     /* vcap is in vertices */
    uint32_t *idx;       /* 3 per triangle */
    size_t nt, tcap;     /* tcap is in triangles */
    size_t zero_normals; /* normals to repair once the faces are known */
} mesh_builder;

/* The values a vertex may carry, as indices into the array handed to
 * mesh_store_vertex. */
enum { MESH_X, MESH_Y, MESH_Z, MESH_NX, MESH_NY, MESH_NZ, MESH_VALUES };

/* Grows an array of items of `item` bytes to hold at least `need` items.
 * Returns the new block (the old one on no change) or NULL, in which case
 * the old block is still valid and *cap unchanged. */
void *mesh_grow(void *p, size_t *cap, size_t need, size_t item);

/* Makes room for `more` triangles; 0, or -1 when out of memory. */
int mesh_reserve_tris(mesh_builder *b, size_t more);

/* Appends a triangle; the caller has reserved room. Inline: once per
 * triangle of the file. */
static inline void mesh_emit_tri(mesh_builder *b, uint32_t a, uint32_t v1, uint32_t v2)
{
    uint32_t *t = b->idx + 3 * b->nt++;
    t[0] = a;
    t[1] = v1;
    t[2] = v2;
}

/* Checks and stores vertex i from v[MESH_X..MESH_NZ] (normals only if
 * b->nrm); room for it is the caller's. `number` is how the vertex is named
 * in messages (0-based in PLY, 1-based in OBJ, as each format numbers
 * them); binary and loc place the message as for mesh_fail_at. */
int mesh_store_vertex(const mesh_ctx *c, mesh_builder *b, size_t i, const double *v, int binary,
                      size_t loc, size_t number);

/* ---- the format readers ------------------------------------------------- */

/* Each reads the whole buffer into b (empty on entry); 0, or -1 with the
 * message written through c. The builder is freed by the caller either way. */
int ply_load(const mesh_ctx *c, const unsigned char *data, size_t size, mesh_builder *b);
int obj_load(const mesh_ctx *c, const unsigned char *data, size_t size, mesh_builder *b);
int serialized_load(const mesh_ctx *c, const unsigned char *data, size_t size, mesh_builder *b);

#endif
