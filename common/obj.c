/* obj.c - the Wavefront OBJ reader behind mesh_load; see mesh_priv.h for
 * how it fills the mesh under construction.
 *
 * Only "v x y z" and "f a b c ..." lines are read (polygons become
 * triangle fans), and "vn" and "vt" with MESH_ATTRIBUTES; o, g, s, usemtl,
 * mtllib, l, p and comments are skipped. Positive indices may refer to vertices defined later in
 * the file; negative ones are relative to the vertices defined so far (the spec).
 */
#include <inttypes.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "mesh_priv.h"
#include "numparse.h"

/* Where the reader is, and the largest positive index seen: positive
 * indices may point forward, so they are checked at the end against the
 * final count, and the largest one is kept for the message. */
typedef struct obj_reader {
    size_t line; /* 1-based number of the line being read */
    size_t faces;
    int64_t max_idx;
    size_t max_line, max_face, max_corner;
    /* MESH_ATTRIBUTES: the vn and vt lines, and each triangle corner's vn
     * and vt index (parallel to the builder's idx; -1 for none) */
    float *vn, *vt;
    size_t nvn, vncap, nvt, vtcap;
    int64_t *corner_n, *corner_t;
    size_t ncorner, ncap, tcap;
    int any_attr;
} obj_reader;

/* Skips blanks from q up to eol. */
static const char *obj_skip_blank(const char *q, const char *eol)
{
    while (q < eol && num_is_blank((unsigned char)*q))
        q++;
    return q;
}

/* The end of the word starting at q. */
static const char *obj_word_end(const char *q, const char *eol)
{
    while (q < eol && !num_is_blank((unsigned char)*q))
        q++;
    return q;
}

/* "v x y z [w ...]" with q after the 'v'. */
static int obj_vertex(const mesh_ctx *c, const obj_reader *rd, const char *q, const char *eol,
                      mesh_builder *b)
{
    double v[MESH_VALUES] = {0};
    for (int k = 0; k < 3; k++) {
        q = obj_skip_blank(q, eol);
        if (q == eol || *q == '#')
            return mesh_fail_at(c, 0, rd->line, "vertex needs 3 coordinates, found %d", k);
        const char *s = q;
        q = obj_word_end(q, eol);
        if (num_parse_double(s, (size_t)(q - s), &v[k]) != 0)
            return mesh_fail_at(c, 0, rd->line, "bad number \"%.*s\"",
                                mesh_quote_len((size_t)(q - s)), s);
    }
    if (b->nv == UINT32_MAX)
        return mesh_fail_at(c, 0, rd->line, "too many vertices for 32-bit indices");
    if (b->nv == b->vcap) {
        void *np = mesh_grow(b->pos, &b->vcap, b->nv + 1, 3 * sizeof(float));
        if (!np)
            return mesh_fail(c, "out of memory");
        b->pos = np;
    }
    if (mesh_store_vertex(c, b, b->nv, v, 0, rd->line, b->nv + 1) != 0)
        return -1;
    b->nv++;
    return 0;
}

/* "vn x y z" or "vt u v [w]" with q after the keyword (MESH_ATTRIBUTES):
 * dims numbers appended to *arr. */
static int obj_attr_line(const mesh_ctx *c, const obj_reader *rd, const char *q, const char *eol,
                         int dims, float **arr, size_t *count, size_t *cap, const char *what)
{
    double v[3];
    for (int k = 0; k < dims; k++) {
        q = obj_skip_blank(q, eol);
        const char *s = q;
        q = obj_word_end(q, eol);
        if (s == q || *s == '#')
            return mesh_fail_at(c, 0, rd->line, "%s needs %d coordinates, found %d", what, dims, k);
        if (num_parse_double(s, (size_t)(q - s), &v[k]) != 0 || !isfinite(v[k]) ||
            fabs(v[k]) > 1e30)
            return mesh_fail_at(c, 0, rd->line, "bad %s coordinate \"%.*s\"", what,
                                mesh_quote_len((size_t)(q - s)), s);
    }
    if (*count == *cap) {
        void *np = mesh_grow(*arr, cap, *count + 1, (size_t)dims * sizeof(float));
        if (!np)
            return mesh_fail(c, "out of memory");
        *arr = np;
    }
    /* vt's v counts up from the image's bottom row; ours (and Mitsuba's,
     * whose OBJ reader flips it too) from its top */
    if (dims == 2)
        v[1] = 1.0 - v[1];
    for (int k = 0; k < dims; k++)
        (*arr)[(size_t)dims * *count + (size_t)k] = (float)v[k];
    (*count)++;
    return 0;
}

/* The vt (field 1) or vn (field 2) index of a corner "v/vt/vn", "v/vt"
 * or "v//vn" (n bytes at s), 0-based, or -1 when it names none. Negative
 * indices count back from the count read so far. */
static int obj_corner_attr(const mesh_ctx *c, const obj_reader *rd, const char *s, size_t n,
                           int field, size_t count, int64_t *out)
{
    *out = -1;
    const char *a = memchr(s, '/', n);
    if (a && field == 2)
        a = memchr(a + 1, '/', (size_t)(s + n - a - 1));
    if (!a || a + 1 == s + n || a[1] == '/')
        return 0;
    const char *e = memchr(a + 1, '/', (size_t)(s + n - a - 1));
    size_t len = (size_t)((e ? e : s + n) - (a + 1));
    const char *what = field == 2 ? "normal" : "texture coordinate";
    int64_t x;
    if (num_parse_int(a + 1, len, &x) != 0 || x == 0)
        return mesh_fail_at(c, 0, rd->line, "face %zu: bad %s index in \"%.*s\"", rd->faces, what,
                            mesh_quote_len(n), s);
    if (x < 0)
        x += (int64_t)count;
    else
        x -= 1;
    if (x < 0 || x >= (int64_t)count)
        return mesh_fail_at(c, 0, rd->line, "face %zu: %s index out of range in \"%.*s\"",
                            rd->faces, what, mesh_quote_len(n), s);
    *out = x;
    return 0;
}

/* One face corner "v[/vt[/vn]]" (n bytes at s) as a 0-based vertex index.
 * Positive indices are only range-checked here against 32 bits; the
 * largest is remembered for the check against the final vertex count. */
static int obj_corner(const mesh_ctx *c, obj_reader *rd, const mesh_builder *b, const char *s,
                      size_t n, size_t corner, uint32_t *out)
{
    size_t ilen = 0;
    while (ilen < n && s[ilen] != '/')
        ilen++;
    int64_t x;
    int bad = num_parse_int(s, ilen, &x) != 0;
    for (size_t j = ilen; j < n && !bad; j++) /* the vt/vn part is checked, not used */
        bad = !(num_is_digit((unsigned char)s[j]) || s[j] == '/' || s[j] == '-');
    if (bad)
        return mesh_fail_at(c, 0, rd->line, "face %zu: bad vertex \"%.*s\"", rd->faces,
                            mesh_quote_len(n), s);
    if (x == 0)
        return mesh_fail_at(c, 0, rd->line,
                            "face %zu, index %zu: 0 is not a valid index "
                            "(OBJ indices start at 1)",
                            rd->faces, corner + 1);
    if (x < 0) {
        if (-x > (int64_t)b->nv)
            return mesh_fail_at(c, 0, rd->line,
                                "face %zu, index %zu: relative index %" PRId64
                                " is out of range (%zu vertices so far)",
                                rd->faces, corner + 1, x, b->nv);
        x += (int64_t)b->nv;
    } else {
        if (x > (int64_t)UINT32_MAX)
            return mesh_fail_at(c, 0, rd->line, "face %zu, index %zu: %" PRId64 " is out of range",
                                rd->faces, corner + 1, x);
        if (x > rd->max_idx) {
            rd->max_idx = x;
            rd->max_line = rd->line;
            rd->max_face = rd->faces;
            rd->max_corner = corner + 1;
        }
        x -= 1;
    }
    *out = (uint32_t)x;
    return 0;
}

/* "f v1[/vt[/vn]] v2 ..." with q after the 'f', as a triangle fan. */
static int obj_face(const mesh_ctx *c, obj_reader *rd, const char *q, const char *eol,
                    mesh_builder *b)
{
    uint32_t first = 0, prev = 0;
    int64_t first_n = -1, prev_n = -1, first_t = -1, prev_t = -1;
    size_t corner = 0;
    int attrs = (c->flags & MESH_ATTRIBUTES) != 0;
    rd->faces++;
    for (;; corner++) {
        q = obj_skip_blank(q, eol);
        if (q == eol || *q == '#')
            break;
        const char *s = q;
        q = obj_word_end(q, eol);
        uint32_t u = 0;
        int64_t un = -1, ut = -1;
        if (obj_corner(c, rd, b, s, (size_t)(q - s), corner, &u) != 0 ||
            (attrs && (obj_corner_attr(c, rd, s, (size_t)(q - s), 2, rd->nvn, &un) != 0 ||
                       obj_corner_attr(c, rd, s, (size_t)(q - s), 1, rd->nvt, &ut) != 0)))
            return -1;
        if (corner == 0) {
            first = u;
            first_n = un;
            first_t = ut;
        } else if (corner >= 2) {
            if (mesh_reserve_tris(b, 1) != 0)
                return mesh_fail(c, "out of memory");
            mesh_emit_tri(b, first, prev, u);
            if (attrs) {
                size_t need = rd->ncorner + 3;
                if (need > rd->ncap) {
                    void *np = mesh_grow(rd->corner_n, &rd->ncap, need, sizeof(int64_t));
                    if (!np)
                        return mesh_fail(c, "out of memory");
                    rd->corner_n = np;
                }
                if (need > rd->tcap) {
                    void *np = mesh_grow(rd->corner_t, &rd->tcap, need, sizeof(int64_t));
                    if (!np)
                        return mesh_fail(c, "out of memory");
                    rd->corner_t = np;
                }
                int64_t *cn = rd->corner_n + rd->ncorner, *ct = rd->corner_t + rd->ncorner;
                cn[0] = first_n;
                cn[1] = prev_n;
                cn[2] = un;
                ct[0] = first_t;
                ct[1] = prev_t;
                ct[2] = ut;
                rd->ncorner = need;
                for (int k = 0; k < 3; k++)
                    rd->any_attr |= cn[k] >= 0 || ct[k] >= 0;
            }
        }
        prev = u;
        prev_n = un;
        prev_t = ut;
    }
    if (corner < 3)
        return mesh_fail_at(c, 0, rd->line, "face %zu has %zu vertices (need at least 3)",
                            rd->faces, corner);
    return 0;
}

/* MESH_ATTRIBUTES, once every face is read: one vertex per (position,
 * normal, texture coordinates) the corners use, with its normal (a corner
 * without one gets a zero normal, which mesh.c repairs from its faces) and
 * coordinates ((0, 0) without). */
static int obj_split_vertices(const mesh_ctx *c, obj_reader *rd, mesh_builder *b)
{
    size_t n = rd->ncorner, cap = 16;
    while (cap < 2 * n)
        cap *= 2;
    uint64_t *key = malloc(cap * 2 * sizeof(uint64_t)); /* (v, vn) and vt */
    uint32_t *slot_vertex = malloc(cap * sizeof(uint32_t));
    float *pos = malloc((n + 1) * 3 * sizeof(float)), *nrm = malloc((n + 1) * 3 * sizeof(float));
    float *uv = rd->nvt ? malloc((n + 1) * 2 * sizeof(float)) : NULL;
    if (!key || !slot_vertex || !pos || !nrm || (rd->nvt && !uv)) {
        free(key);
        free(slot_vertex);
        free(pos);
        free(nrm);
        free(uv);
        return mesh_fail(c, "out of memory");
    }
    memset(key, 0xff, cap * 2 * sizeof(uint64_t)); /* all ones: empty */
    size_t nv = 0;
    for (size_t i = 0; i < n; i++) {
        int64_t vn = rd->corner_n[i], vt = rd->corner_t[i];
        uint64_t k1 = ((uint64_t)b->idx[i] << 32) | (uint32_t)(vn + 1), k2 = (uint64_t)(vt + 1);
        size_t h =
            (size_t)(((k1 ^ k2 * 0xc2b2ae3d27d4eb4fULL) * 0x9e3779b97f4a7c15ULL) >> 20) & (cap - 1);
        while (key[2 * h] != UINT64_MAX && (key[2 * h] != k1 || key[2 * h + 1] != k2))
            h = (h + 1) & (cap - 1);
        if (key[2 * h] == UINT64_MAX) {
            key[2 * h] = k1;
            key[2 * h + 1] = k2;
            slot_vertex[h] = (uint32_t)nv;
            memcpy(pos + 3 * nv, b->pos + 3 * (size_t)b->idx[i], 3 * sizeof(float));
            float *nn = nrm + 3 * nv;
            nn[0] = nn[1] = nn[2] = 0;
            if (vn >= 0) {
                const float *src = rd->vn + 3 * (size_t)vn;
                double l = sqrt((double)src[0] * src[0] + (double)src[1] * src[1] +
                                (double)src[2] * src[2]);
                for (int k = 0; k < 3 && l > 0; k++)
                    nn[k] = (float)(src[k] / l);
            }
            if (nn[0] == 0 && nn[1] == 0 && nn[2] == 0)
                b->zero_normals++;
            if (uv) {
                uv[2 * nv] = vt >= 0 ? rd->vt[2 * (size_t)vt] : 0.0f;
                uv[2 * nv + 1] = vt >= 0 ? rd->vt[2 * (size_t)vt + 1] : 0.0f;
            }
            nv++;
        }
        b->idx[i] = slot_vertex[h];
    }
    free(key);
    free(slot_vertex);
    free(b->pos);
    free(b->nrm);
    free(b->uv);
    b->pos = pos;
    b->nrm = nrm;
    b->uv = uv;
    b->nv = b->vcap = nv;
    return 0;
}

/* Every line of the file, into rd and b. */
static int obj_read_lines(const mesh_ctx *c, obj_reader *rd, const char *p, const char *end,
                          mesh_builder *b)
{

    while (p < end) {
        rd->line++;
        const char *eol = memchr(p, '\n', (size_t)(end - p));
        if (!eol)
            eol = end;
        const char *q = obj_skip_blank(p, eol);
        p = eol < end ? eol + 1 : end;
        if ((c->flags & MESH_ATTRIBUTES) && eol - q > 2 && q[0] == 'v' &&
            (q[1] == 'n' || q[1] == 't') && num_is_blank((unsigned char)q[2])) {
            int r = q[1] == 'n' ? obj_attr_line(c, rd, q + 2, eol, 3, &rd->vn, &rd->nvn, &rd->vncap,
                                                "normal")
                                : obj_attr_line(c, rd, q + 2, eol, 2, &rd->vt, &rd->nvt, &rd->vtcap,
                                                "texture coordinate");
            if (r != 0)
                return -1;
            continue;
        }
        if (q == eol || (q[0] != 'v' && q[0] != 'f') ||
            (eol - q > 1 && !num_is_blank((unsigned char)q[1])))
            continue; /* vn, vt, o, g, s, usemtl, mtllib, #, l, p, blank... */
        int r = q[0] == 'v' ? obj_vertex(c, rd, q + 1, eol, b) : obj_face(c, rd, q + 1, eol, b);
        if (r != 0)
            return -1;
    }
    if ((uint64_t)rd->max_idx > b->nv)
        return mesh_fail_at(c, 0, rd->max_line,
                            "face %zu, index %zu: vertex %" PRId64
                            " is out of range (the file has %zu vertices)",
                            rd->max_face, rd->max_corner, rd->max_idx, b->nv);
    return 0;
}

int obj_load(const mesh_ctx *c, const unsigned char *data, size_t size, mesh_builder *b)
{
    obj_reader rd;
    memset(&rd, 0, sizeof rd);
    int r = obj_read_lines(c, &rd, (const char *)data, (const char *)data + size, b);
    if (r == 0 && rd.any_attr)
        r = obj_split_vertices(c, &rd, b);
    free(rd.vn);
    free(rd.vt);
    free(rd.corner_n);
    free(rd.corner_t);
    return r;
}
