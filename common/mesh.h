/* mesh.h - triangle mesh files: PLY (ascii, binary little/big endian) and OBJ.
 *
 * A small reader of our own rather than Assimp: see README.md ("Mesh files")
 * for the load-time comparison that decided it. It reads positions, optional
 * per-vertex normals (PLY nx/ny/nz only) and faces; polygons with more than
 * three vertices are split into a triangle fan. Everything else in the file
 * (colours, texture coordinates, materials, groups) is skipped.
 *
 * Every value that comes from the file is checked: counts against the file
 * size, indices against the vertex count, coordinates for NaN/Inf. Errors
 * name the file and the line (text formats) or byte offset (binary PLY).
 */
#ifndef VB_MESH_H
#define VB_MESH_H

#include <stddef.h>
#include <stdint.h>

typedef struct mesh {
    float *positions;  /* 3 * vertex_count floats, x y z */
    float *normals;    /* 3 * vertex_count floats, or NULL when absent */
    float *uvs;        /* 2 * vertex_count floats (MESH_ATTRIBUTES), or NULL */
    uint32_t *indices; /* 3 * triangle_count vertex indices */
    size_t vertex_count;
    size_t triangle_count;
} mesh_t;

/* Reads a mesh file, choosing the format by content (PLY starts with "ply\n")
 * and otherwise by the .obj extension. On success returns 0 and stores a new
 * mesh in *out (free with mesh_destroy). On failure returns -1, leaves *out
 * NULL and writes a message naming the file and place into err. */
int mesh_load(const char *path, mesh_t **out, char *err, size_t errlen);

/* The same from a buffer already in memory; name is used in messages and to
 * pick OBJ by extension. Used by the fuzz target. */
int mesh_load_buffer(const char *name, const unsigned char *data, size_t size, mesh_t **out,
                     char *err, size_t errlen);

/* mesh_load_flags: also read what a vertex carries besides its normal in
 * PLY: an OBJ file's vertex normals (vn) and texture coordinates (vt), a
 * serialized file's texture coordinates. A position used with different
 * normals or coordinates becomes one vertex per pair; a corner without a
 * normal gets its faces' mean normal, one without coordinates (0, 0). Off
 * by default: our own scenes' OBJ meshes have always been read without. */
#define MESH_ATTRIBUTES 1u

/* mesh_load and mesh_load_buffer with MESH_* flags, and shape_index: which
 * shape of a file that holds several (Mitsuba's .serialized, recognised by
 * its 0x041C identifier; 0 for the other formats). */
int mesh_load_flags(const char *path, unsigned flags, uint32_t shape_index, mesh_t **out, char *err,
                    size_t errlen);
int mesh_load_buffer_flags(const char *name, const unsigned char *data, size_t size, unsigned flags,
                           uint32_t shape_index, mesh_t **out, char *err, size_t errlen);

/* Gives a mesh without normals smooth vertex normals: each the sum of its
 * triangles' unit normals weighted by the triangle's angle at the vertex,
 * normalised (as Mitsuba 3 computes them). Returns -1 when out of memory. */
int mesh_smooth_normals(mesh_t *m);

/* Frees a mesh and sets *m to NULL. Accepts NULL and *m == NULL. */
void mesh_destroy(mesh_t **m);

#endif
