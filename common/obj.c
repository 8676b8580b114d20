/* obj.c - the Wavefront OBJ reader behind mesh_load; see mesh_priv.h for
 * how it fills the mesh under construction.
 *
 * Only "v x y z" and "f a b c ..." lines are read (polygons become
 * triangle fans); vn, vt, o, g, s, usemtl, mtllib, l, p and comments are
 * skipped. Positive indices may refer to vertices defined later in the
 * file; negative ones are relative to the vertices defined so far (the
 * spec).
 */
#include <inttypes.h>
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
    size_t corner = 0;
    rd->faces++;
    for (;; corner++) {
        q = obj_skip_blank(q, eol);
        if (q == eol || *q == '#')
            break;
        const char *s = q;
        q = obj_word_end(q, eol);
        uint32_t u = 0;
        if (obj_corner(c, rd, b, s, (size_t)(q - s), corner, &u) != 0)
            return -1;
        if (corner == 0) {
            first = u;
        } else if (corner >= 2) {
            if (mesh_reserve_tris(b, 1) != 0)
                return mesh_fail(c, "out of memory");
            mesh_emit_tri(b, first, prev, u);
        }
        prev = u;
    }
    if (corner < 3)
        return mesh_fail_at(c, 0, rd->line, "face %zu has %zu vertices (need at least 3)",
                            rd->faces, corner);
    return 0;
}

int obj_load(const mesh_ctx *c, const unsigned char *data, size_t size, mesh_builder *b)
{
    const char *p = (const char *)data, *end = p + size;
    obj_reader rd;
    memset(&rd, 0, sizeof rd);

    while (p < end) {
        rd.line++;
        const char *eol = memchr(p, '\n', (size_t)(end - p));
        if (!eol)
            eol = end;
        const char *q = obj_skip_blank(p, eol);
        p = eol < end ? eol + 1 : end;
        if (q == eol || (q[0] != 'v' && q[0] != 'f') ||
            (eol - q > 1 && !num_is_blank((unsigned char)q[1])))
            continue; /* vn, vt, o, g, s, usemtl, mtllib, #, l, p, blank... */
        int r = q[0] == 'v' ? obj_vertex(c, &rd, q + 1, eol, b) : obj_face(c, &rd, q + 1, eol, b);
        if (r != 0)
            return -1;
    }
    if ((uint64_t)rd.max_idx > b->nv)
        return mesh_fail_at(c, 0, rd.max_line,
                            "face %zu, index %zu: vertex %" PRId64
                            " is out of range (the file has %zu vertices)",
                            rd.max_face, rd.max_corner, rd.max_idx, b->nv);
    return 0;
}
