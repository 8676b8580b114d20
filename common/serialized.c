/* serialized.c - Mitsuba's .serialized meshes, the reader behind mesh_load
 * for files that start with its identifier (see mesh_priv.h).
 *
 * The format (Mitsuba 0.6 to 3, "serialized" shape plugin): a file holds
 * one or more shapes, each a little-endian header - uint16 0x041C, uint16
 * version (3 or 4) - then a zlib stream: uint32 flags, a NUL-terminated
 * name (version 4 only), uint64 vertex and triangle counts, the positions,
 * the normals, texture coordinates and colours the flags name, then the
 * triangles' uint32 indices (uint64 past 2^32 vertices). The file ends with
 * the shapes' offsets (uint32 in version 3, uint64 in 4) and their count
 * (uint32). mesh_ctx.shape_index picks the shape. zlib inflates; every
 * count and offset is checked against what is there before it is used. */
#include <limits.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <zlib.h>

#include "mesh_priv.h"

#define SER_ID 0x041C
#define SER_NORMALS 0x0001u
#define SER_TEXCOORDS 0x0002u
#define SER_COLORS 0x0008u
#define SER_FACE_NORMALS 0x0010u
#define SER_SINGLE 0x1000u
#define SER_DOUBLE 0x2000u
/* a shape above this many bytes once inflated is refused */
#define SER_MAX_INFLATED ((size_t)1 << 32)

static uint64_t le(const unsigned char *p, int bytes)
{
    uint64_t v = 0;
    for (int i = bytes - 1; i >= 0; i--)
        v = v << 8 | p[i];
    return v;
}

/* Value i of an array of little-endian floats (real 4) or doubles (8). */
static double real_at(const unsigned char *p, size_t i, size_t real)
{
    uint64_t bits = le(p + i * real, (int)real);
    if (real == 8) {
        double d;
        memcpy(&d, &bits, 8);
        return d;
    }
    uint32_t u = (uint32_t)bits;
    float f;
    memcpy(&f, &u, 4);
    return f;
}

/* Inflates the zlib stream at data[0..size) into a new buffer. */
static unsigned char *inflate_all(const mesh_ctx *c, const unsigned char *data, size_t size,
                                  size_t *out_size)
{
    z_stream z;
    memset(&z, 0, sizeof z);
    if (inflateInit(&z) != Z_OK) {
        mesh_fail(c, "zlib: cannot start");
        return NULL;
    }
    size_t cap = size * 4 + 1024, len = 0;
    unsigned char *buf = malloc(cap);
    int rc = buf ? Z_OK : Z_MEM_ERROR;
    z.next_in = (unsigned char *)data;
    while (rc == Z_OK) {
        if (len == cap) {
            if (cap >= SER_MAX_INFLATED) {
                rc = Z_BUF_ERROR;
                break;
            }
            unsigned char *nb = realloc(buf, cap * 2);
            if (!nb) {
                rc = Z_MEM_ERROR;
                break;
            }
            buf = nb;
            cap *= 2;
        }
        /* zlib counts in uInt: feed and drain at most 1 GiB at a time */
        size_t in_left = size - (size_t)(z.next_in - data);
        z.avail_in = (uInt)(in_left < (1u << 30) ? in_left : (1u << 30));
        z.next_out = buf + len;
        z.avail_out = (uInt)(cap - len < (1u << 30) ? cap - len : (1u << 30));
        uInt before = z.avail_out;
        rc = inflate(&z, Z_NO_FLUSH);
        len += before - z.avail_out;
        if (rc == Z_BUF_ERROR && z.avail_out > 0)
            break; /* input ended before the stream did */
        if (rc == Z_BUF_ERROR)
            rc = Z_OK;
    }
    inflateEnd(&z);
    if (rc != Z_STREAM_END) {
        free(buf);
        mesh_fail(c, "zlib: %s",
                  rc == Z_MEM_ERROR   ? "out of memory"
                  : rc == Z_BUF_ERROR ? "the stream is cut short (or too large)"
                                      : "corrupt data");
        return NULL;
    }
    *out_size = len;
    return buf;
}

/* Where shape `index` starts and ends in the file, from the dictionary at
 * its end (its version read from the first shape's header). */
static int find_shape(const mesh_ctx *c, const unsigned char *data, size_t size, uint32_t index,
                      size_t *begin, size_t *end)
{
    if (size < 8 || le(data, 2) != SER_ID)
        return mesh_fail(c, "not a serialized mesh (no 0x041C identifier)");
    unsigned version = (unsigned)le(data + 2, 2);
    if (version != 3 && version != 4)
        return mesh_fail(c, "serialized version %u is not supported (3 or 4)", version);
    size_t w = version == 4 ? 8 : 4;
    uint64_t count = le(data + size - 4, 4);
    if (count == 0 || count > (size - 4) / w)
        return mesh_fail(c, "its shape dictionary is corrupt (%llu shapes)",
                         (unsigned long long)count);
    if (index >= count)
        return mesh_fail(c, "shape_index %u: the file holds %llu shape%s", index,
                         (unsigned long long)count, count == 1 ? "" : "s");
    size_t dict = size - 4 - (size_t)count * w;
    uint64_t b = le(data + dict + (size_t)index * w, (int)w);
    uint64_t e = index + 1 < count ? le(data + dict + (size_t)(index + 1) * w, (int)w) : dict;
    if (!(b + 4 <= e && e <= dict))
        return mesh_fail(c, "shape %u: offsets %llu..%llu outside the file", index,
                         (unsigned long long)b, (unsigned long long)e);
    if (le(data + b, 2) != SER_ID || le(data + b + 2, 2) != version)
        return mesh_fail(c, "shape %u: no 0x041C identifier at offset %llu", index,
                         (unsigned long long)b);
    *begin = (size_t)b;
    *end = (size_t)e;
    return 0;
}

int serialized_load(const mesh_ctx *c, const unsigned char *data, size_t size, mesh_builder *b)
{
    size_t begin = 0, end = 0;
    if (find_shape(c, data, size, c->shape_index, &begin, &end) < 0)
        return -1;
    unsigned version = (unsigned)le(data + begin + 2, 2);
    size_t n = 0;
    unsigned char *raw = inflate_all(c, data + begin + 4, end - begin - 4, &n);
    if (!raw)
        return -1;
    int rc = -1;
    size_t at = 4;
    uint32_t flags = n >= 4 ? (uint32_t)le(raw, 4) : 0;
    if (n < 4)
        goto cut;
    if (version == 4) {
        const unsigned char *nul = memchr(raw + at, 0, n - at);
        if (!nul)
            goto cut;
        at = (size_t)(nul - raw) + 1;
    }
    if (n - at < 16)
        goto cut;
    uint64_t nv = le(raw + at, 8), nt = le(raw + at + 8, 8);
    at += 16;
    if (!(flags & (SER_SINGLE | SER_DOUBLE)) || (flags & SER_SINGLE && flags & SER_DOUBLE)) {
        mesh_fail(c, "shape %u: flags 0x%x name neither single nor double precision",
                  c->shape_index, flags);
        goto done;
    }
    size_t real = flags & SER_DOUBLE ? 8 : 4;
    int wide = nv > UINT32_MAX;
    if (nv == 0 || nt == 0 || wide) {
        mesh_fail(c,
                  "shape %u: %llu vertices, %llu triangles (1 to 2^32 - 1 vertices, at least "
                  "1 triangle)",
                  c->shape_index, (unsigned long long)nv, (unsigned long long)nt);
        goto done;
    }
    int normals = (flags & SER_NORMALS) && !(flags & SER_FACE_NORMALS);
    size_t per_vertex = real * (3 + (flags & SER_NORMALS ? 3 : 0) +
                                (flags & SER_TEXCOORDS ? 2 : 0) + (flags & SER_COLORS ? 3 : 0));
    if (nv > (n - at) / per_vertex || nt > (n - at - (size_t)nv * per_vertex) / 12)
        goto cut;
    b->pos = malloc((size_t)nv * 3 * sizeof(float));
    b->nrm = normals ? malloc((size_t)nv * 3 * sizeof(float)) : NULL;
    if (!b->pos || (normals && !b->nrm) || mesh_reserve_tris(b, (size_t)nt) != 0) {
        mesh_fail(c, "out of memory for %llu vertices", (unsigned long long)nv);
        goto done;
    }
    b->vcap = (size_t)nv;
    const unsigned char *pos = raw + at, *nrm = pos + (size_t)nv * 3 * real;
    const unsigned char *tex = nrm + (flags & SER_NORMALS ? (size_t)nv * 3 * real : 0);
    if ((flags & SER_TEXCOORDS) && (c->flags & MESH_ATTRIBUTES)) {
        b->uv = malloc((size_t)nv * 2 * sizeof(float));
        if (!b->uv) {
            mesh_fail(c, "out of memory for %llu vertices", (unsigned long long)nv);
            goto done;
        }
        for (size_t i = 0; i < 2 * (size_t)nv; i++) {
            double d = real_at(tex, i, real);
            b->uv[i] = isfinite(d) && fabs(d) < 1e30 ? (float)d : 0.0f;
        }
    }
    for (size_t v = 0; v < (size_t)nv; v++) {
        double val[MESH_VALUES] = {0};
        for (int k = 0; k < 3; k++) {
            val[k] = real_at(pos, 3 * v + (size_t)k, real);
            if (normals)
                val[MESH_NX + k] = real_at(nrm, 3 * v + (size_t)k, real);
        }
        if (mesh_store_vertex(c, b, v, val, 0, 0, v) != 0)
            goto done;
        b->nv++;
    }
    const unsigned char *idx = raw + at + (size_t)nv * per_vertex;
    for (size_t t = 0; t < (size_t)nt; t++) {
        uint32_t tri[3];
        for (int k = 0; k < 3; k++) {
            tri[k] = (uint32_t)le(idx + (3 * t + (size_t)k) * 4, 4);
            if (tri[k] >= nv) {
                mesh_fail(c, "shape %u: triangle %zu: vertex %u out of range (%llu vertices)",
                          c->shape_index, t, tri[k], (unsigned long long)nv);
                goto done;
            }
        }
        mesh_emit_tri(b, tri[0], tri[1], tri[2]);
    }
    rc = 0;
    goto done;
cut:
    mesh_fail(c, "shape %u: the data ends before its counts say", c->shape_index);
done:
    free(raw);
    return rc;
}
