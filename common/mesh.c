/* mesh.c - the mesh front end: the public mesh_ API (see mesh.h), the
 * error context and the mesh under construction that the format readers
 * fill (mesh_priv.h). The readers themselves are ply.c and obj.c; the
 * number parsing they share is numparse.c.
 *
 * The whole file is held in memory and parsed with a cursor; nothing is ever
 * read outside [data, data + size), so the same code serves files and the
 * fuzz target. Every count from a file is checked against the bytes that are
 * left before anything is allocated for it, so a lying header fails with a
 * message instead of a huge malloc.
 *
 * Decisions worth knowing:
 *  - PLY normals (nx, ny, nz, all three or they are ignored) are normalised.
 *    A zero-length normal is neither an error nor a reason to drop all
 *    normals (real scans such as the Stanford dragon re-saved by MeshLab
 *    contain a few): it is replaced by the normalised sum of the unit normals
 *    of the triangles that use the vertex, or (0, 0, 1) for a vertex no
 *    non-degenerate triangle uses, so every normal is unit length.
 *  - Coordinates are checked here (mesh_store_vertex), for every format:
 *    NaN, and values that are not finite once rounded to float, fail.
 */
#include "mesh.h"

#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "mesh_priv.h"

/* ------------------------------------------------------------------------ */
/* Errors                                                                   */

/* Writes "name: [line N: |byte N: ]message" into the caller's buffer. */
static void vset_err(const mesh_ctx *c, const char *loc_kind, size_t loc, const char *fmt,
                     va_list ap)
{
    if (!c->err || c->errlen == 0)
        return;
    int n = loc_kind ? snprintf(c->err, c->errlen, "%s: %s %zu: ", c->name, loc_kind, loc)
                     : snprintf(c->err, c->errlen, "%s: ", c->name);
    if (n < 0 || (size_t)n >= c->errlen)
        return;
    vsnprintf(c->err + n, c->errlen - (size_t)n, fmt, ap);
}

int mesh_fail(const mesh_ctx *c, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vset_err(c, NULL, 0, fmt, ap);
    va_end(ap);
    return -1;
}

/* Binary PLY errors name a byte offset, text errors a line. */
int mesh_fail_at(const mesh_ctx *c, int binary, size_t loc, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vset_err(c, binary ? "byte" : "line", loc, fmt, ap);
    va_end(ap);
    return -1;
}

/* ------------------------------------------------------------------------ */
/* Mesh under construction                                                  */

static void builder_free(mesh_builder *b)
{
    free(b->pos);
    free(b->nrm);
    free(b->uv);
    free(b->idx);
    memset(b, 0, sizeof *b);
}

/* Grows an array of items of `item` bytes to hold at least `need` items.
 * Returns the new block (the old one on no change) or NULL, in which case
 * the old block is still valid and *cap unchanged. */
void *mesh_grow(void *p, size_t *cap, size_t need, size_t item)
{
    if (need <= *cap && p)
        return p;
    size_t ncap = *cap ? *cap : 1024;
    while (ncap < need)
        ncap = ncap > SIZE_MAX / 2 ? need : ncap * 2;
    if (ncap > SIZE_MAX / item)
        return NULL;
    void *q = realloc(p, ncap * item);
    if (q)
        *cap = ncap;
    return q;
}

int mesh_reserve_tris(mesh_builder *b, size_t more)
{
    if (more > SIZE_MAX - b->nt)
        return -1;
    if (b->nt + more <= b->tcap && b->idx)
        return 0;
    void *q = mesh_grow(b->idx, &b->tcap, b->nt + more, 3 * sizeof(uint32_t));
    if (!q)
        return -1;
    b->idx = q;
    return 0;
}

/* Vertex values as described at the top of the file. */
int mesh_store_vertex(const mesh_ctx *c, mesh_builder *b, size_t i, const double *v, int binary,
                      size_t loc, size_t number)
{
    static const char axis[] = "xyz";
    for (int k = 0; k < 3; k++) {
        if (isnan(v[k]))
            return mesh_fail_at(c, binary, loc, "vertex %zu: %c coordinate is NaN (not finite)",
                                number, axis[k]);
        /* Also catches values that are finite as double but round to Inf as
         * float (converting those is undefined behaviour in C). Values just
         * above FLT_MAX that round down to it, such as FLT_MAX printed with
         * 9 digits, are kept: 0x1.ffffffp127 is the midpoint to 2^128. */
        double a = fabs(v[k]);
        if (!(a < 0x1.ffffffp127))
            return mesh_fail_at(c, binary, loc,
                                "vertex %zu: %c coordinate %g is not finite as a float", number,
                                axis[k], v[k]);
        b->pos[3 * i + (size_t)k] = a > FLT_MAX ? (v[k] < 0 ? -FLT_MAX : FLT_MAX) : (float)v[k];
    }
    if (!b->nrm)
        return 0;
    double m = 0.0;
    for (int k = 3; k < 6; k++) {
        if (!isfinite(v[k]))
            return mesh_fail_at(c, binary, loc, "vertex %zu: normal is not finite", number);
        if (fabs(v[k]) > m)
            m = fabs(v[k]);
    }
    float *n = b->nrm + 3 * i;
    if (m == 0.0) {
        n[0] = n[1] = n[2] = 0.0f;
        b->zero_normals++;
        return 0;
    }
    /* Scale by the largest component first so squaring cannot overflow. */
    double x = v[MESH_NX] / m, y = v[MESH_NY] / m, z = v[MESH_NZ] / m;
    double len = sqrt(x * x + y * y + z * z);
    n[0] = (float)(x / len);
    n[1] = (float)(y / len);
    n[2] = (float)(z / len);
    return 0;
}

/* Replaces zero-length normals as described at the top of the file. */
static int repair_normals(mesh_builder *b)
{
    unsigned char *zero = calloc(b->nv ? b->nv : 1, 1);
    if (!zero)
        return -1;
    for (size_t i = 0; i < b->nv; i++) {
        const float *n = b->nrm + 3 * i;
        zero[i] = n[0] == 0.0f && n[1] == 0.0f && n[2] == 0.0f;
    }
    for (size_t t = 0; t < b->nt; t++) {
        const uint32_t *tri = b->idx + 3 * t;
        if (!zero[tri[0]] && !zero[tri[1]] && !zero[tri[2]])
            continue;
        const float *p0 = b->pos + 3 * (size_t)tri[0];
        const float *p1 = b->pos + 3 * (size_t)tri[1];
        const float *p2 = b->pos + 3 * (size_t)tri[2];
        double e1[3], e2[3];
        for (int k = 0; k < 3; k++) {
            e1[k] = (double)p1[k] - p0[k];
            e2[k] = (double)p2[k] - p0[k];
        }
        double f[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                       e1[0] * e2[1] - e1[1] * e2[0]};
        double m = fmax(fabs(f[0]), fmax(fabs(f[1]), fabs(f[2])));
        if (!(m > 0.0))
            continue;
        /* Unit face normals: bounded sums, no overflow whatever the scale. */
        for (int k = 0; k < 3; k++)
            f[k] /= m;
        double len = sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
        for (int corner = 0; corner < 3; corner++) {
            if (!zero[tri[corner]])
                continue;
            float *n = b->nrm + 3 * (size_t)tri[corner];
            for (int k = 0; k < 3; k++)
                n[k] += (float)(f[k] / len);
        }
    }
    for (size_t i = 0; i < b->nv; i++) {
        if (!zero[i])
            continue;
        float *n = b->nrm + 3 * i;
        double len = sqrt((double)n[0] * n[0] + (double)n[1] * n[1] + (double)n[2] * n[2]);
        if (len > 0.0) {
            for (int k = 0; k < 3; k++)
                n[k] = (float)(n[k] / len);
        } else {
            n[0] = 0.0f;
            n[1] = 0.0f;
            n[2] = 1.0f;
        }
    }
    free(zero);
    return 0;
}

/* Hands the arrays over to a new mesh_t; on success the builder is empty. */
static int builder_finish(const mesh_ctx *c, mesh_builder *b, mesh_t **out)
{
    if (b->nt == 0)
        return mesh_fail(c, "no triangles");
    if (b->nrm && b->zero_normals && repair_normals(b) != 0)
        return mesh_fail(c, "out of memory");
    mesh_t *m = calloc(1, sizeof *m);
    if (!m)
        return mesh_fail(c, "out of memory");
    /* Give back the slack of the growth strategy; failure is harmless. */
    void *q = realloc(b->idx, b->nt * 3 * sizeof(uint32_t));
    if (q)
        b->idx = q;
    if (b->nv > 0 && b->vcap > b->nv) {
        q = realloc(b->pos, b->nv * 3 * sizeof(float));
        if (q)
            b->pos = q;
    }
    m->positions = b->pos;
    m->normals = b->nrm;
    m->uvs = b->uv;
    m->indices = b->idx;
    m->vertex_count = b->nv;
    m->triangle_count = b->nt;
    memset(b, 0, sizeof *b);
    *out = m;
    return 0;
}

/* ------------------------------------------------------------------------ */
/* Public API                                                               */

static int ends_with_obj(const char *name)
{
    size_t n = strlen(name);
    if (n < 4)
        return 0;
    const char *s = name + n - 4;
    return s[0] == '.' && (s[1] | 0x20) == 'o' && (s[2] | 0x20) == 'b' && (s[3] | 0x20) == 'j';
}

int mesh_load_buffer(const char *name, const unsigned char *data, size_t size, mesh_t **out,
                     char *err, size_t errlen)
{
    return mesh_load_buffer_flags(name, data, size, 0, 0, out, err, errlen);
}

int mesh_load_buffer_flags(const char *name, const unsigned char *data, size_t size, unsigned flags,
                           uint32_t shape_index, mesh_t **out, char *err, size_t errlen)
{
    mesh_ctx c = {name ? name : "(buffer)", err, errlen, flags, shape_index};
    if (err && errlen)
        err[0] = '\0';
    if (out)
        *out = NULL;
    if (!out || (!data && size))
        return mesh_fail(&c, "invalid arguments");

    mesh_builder b;
    memset(&b, 0, sizeof b);
    int r;
    if ((size >= 4 && memcmp(data, "ply\n", 4) == 0) ||
        (size >= 5 && memcmp(data, "ply\r\n", 5) == 0))
        r = ply_load(&c, data, size, &b);
    else if (size >= 2 && data[0] == 0x1C && data[1] == 0x04)
        r = serialized_load(&c, data, size, &b);
    else if (ends_with_obj(c.name))
        r = obj_load(&c, data, size, &b);
    else if (size == 0)
        r = mesh_fail(&c, "empty file");
    else
        r = mesh_fail(&c, "unsupported format: not PLY (first line is not \"ply\") "
                          "and the name does not end in .obj");
    if (r == 0)
        r = builder_finish(&c, &b, out);
    builder_free(&b);
    return r;
}

int mesh_load(const char *path, mesh_t **out, char *err, size_t errlen)
{
    return mesh_load_flags(path, 0, 0, out, err, errlen);
}

int mesh_load_flags(const char *path, unsigned flags, uint32_t shape_index, mesh_t **out, char *err,
                    size_t errlen)
{
    mesh_ctx c = {path ? path : "(null)", err, errlen, flags, shape_index};
    if (out)
        *out = NULL;
    if (!path || !out)
        return mesh_fail(&c, "invalid arguments");
    FILE *f = fopen(path, "rb");
    if (!f)
        return mesh_fail(&c, "cannot open: %s", strerror(errno));
    struct stat st;
    if (fstat(fileno(f), &st) != 0 || !S_ISREG(st.st_mode)) {
        fclose(f);
        return mesh_fail(&c, "not a regular file");
    }
    if ((uintmax_t)st.st_size > (uintmax_t)SIZE_MAX / 2) {
        fclose(f);
        return mesh_fail(&c, "file too large");
    }
    size_t size = (size_t)st.st_size;
    unsigned char *buf = malloc(size ? size : 1);
    if (!buf) {
        fclose(f);
        return mesh_fail(&c, "out of memory reading %zu bytes", size);
    }
    size_t got = fread(buf, 1, size, f);
    fclose(f);
    if (got != size) {
        free(buf);
        return mesh_fail(&c, "read error (got %zu of %zu bytes)", got, size);
    }
    int r = mesh_load_buffer_flags(path, buf, size, flags, shape_index, out, err, errlen);
    free(buf);
    return r;
}

int mesh_smooth_normals(mesh_t *m)
{
    double *acc = calloc(3 * m->vertex_count + 1, sizeof(double));
    float *n = malloc((3 * m->vertex_count + 1) * sizeof(float));
    if (!acc || !n) {
        free(acc);
        free(n);
        return -1;
    }
    for (size_t t = 0; t < m->triangle_count; t++) {
        const uint32_t *vi = m->indices + 3 * t;
        double p[3][3];
        for (int k = 0; k < 3; k++)
            for (int c = 0; c < 3; c++)
                p[k][c] = m->positions[3 * vi[k] + c];
        double e1[3], e2[3], fn[3];
        for (int c = 0; c < 3; c++) {
            e1[c] = p[1][c] - p[0][c];
            e2[c] = p[2][c] - p[0][c];
        }
        fn[0] = e1[1] * e2[2] - e1[2] * e2[1];
        fn[1] = e1[2] * e2[0] - e1[0] * e2[2];
        fn[2] = e1[0] * e2[1] - e1[1] * e2[0];
        double len = sqrt(fn[0] * fn[0] + fn[1] * fn[1] + fn[2] * fn[2]);
        if (!(len > 0) || !isfinite(len))
            continue; /* a degenerate triangle has no normal to give */
        for (int k = 0; k < 3; k++) {
            /* the angle at corner k, between the edges to the other two */
            double a[3], b[3], la = 0, lb = 0, dot = 0;
            for (int c = 0; c < 3; c++) {
                a[c] = p[(k + 1) % 3][c] - p[k][c];
                b[c] = p[(k + 2) % 3][c] - p[k][c];
                la += a[c] * a[c];
                lb += b[c] * b[c];
                dot += a[c] * b[c];
            }
            double cosv = dot / sqrt(la * lb);
            double angle = acos(cosv < -1 ? -1 : cosv > 1 ? 1 : cosv);
            if (!isfinite(angle))
                continue;
            for (int c = 0; c < 3; c++)
                acc[3 * vi[k] + c] += fn[c] / len * angle;
        }
    }
    for (size_t v = 0; v < m->vertex_count; v++) {
        double *a = acc + 3 * v;
        double len = sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
        for (int c = 0; c < 3; c++)
            n[3 * v + c] = len > 0 && isfinite(len) ? (float)(a[c] / len) : 0.0f;
    }
    free(acc);
    free(m->normals);
    m->normals = n;
    return 0;
}

void mesh_destroy(mesh_t **m)
{
    if (!m || !*m)
        return;
    free((*m)->positions);
    free((*m)->normals);
    free((*m)->uvs);
    free((*m)->indices);
    free(*m);
    *m = NULL;
}
