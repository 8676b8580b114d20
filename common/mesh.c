/* mesh.c - reader for triangle mesh files: PLY (ascii, binary little and big
 * endian) and Wavefront OBJ. See mesh.h for the API.
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
 *  - Ascii PLY is line based: each element on its own line, blank lines
 *    allowed between elements. Values of skipped properties are not parsed.
 *  - OBJ positive indices may refer to vertices defined later in the file;
 *    negative ones are relative to the vertices defined so far (the spec).
 *  - Decimal numbers give exactly what strtod gives, rounded once to float;
 *    the fast path below is exact (Clinger), not an approximation.
 */
#include "mesh.h"

#include <errno.h>
#include <float.h>
#include <inttypes.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

/* ------------------------------------------------------------------------ */
/* Errors                                                                   */

typedef struct mesh_ctx {
    const char *name;
    char *err;
    size_t errlen;
} mesh_ctx;

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

__attribute__((format(printf, 2, 3))) static int fail(const mesh_ctx *c, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vset_err(c, NULL, 0, fmt, ap);
    va_end(ap);
    return -1;
}

/* Binary PLY errors name a byte offset, text errors a line. */
__attribute__((format(printf, 4, 5))) static int fail_at(const mesh_ctx *c, int binary, size_t loc,
                                                         const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vset_err(c, binary ? "byte" : "line", loc, fmt, ap);
    va_end(ap);
    return -1;
}

/* Length of a token for quoting in messages: enough to recognise it, short
 * enough that a megabyte-long garbage token does not fill the message. */
static int quote_len(size_t len)
{
    return len > 40 ? 40 : (int)len;
}

/* ------------------------------------------------------------------------ */
/* Mesh under construction                                                  */

typedef struct builder {
    float *pos;          /* 3 per vertex */
    float *nrm;          /* 3 per vertex, or NULL */
    size_t nv, vcap;     /* vcap is in vertices */
    uint32_t *idx;       /* 3 per triangle */
    size_t nt, tcap;     /* tcap is in triangles */
    size_t zero_normals; /* normals to repair once the faces are known */
} builder;

static void builder_free(builder *b)
{
    free(b->pos);
    free(b->nrm);
    free(b->idx);
    memset(b, 0, sizeof *b);
}

/* Grows an array of items of `item` bytes to hold at least `need` items.
 * Returns the new block (the old one on no change) or NULL, in which case
 * the old block is still valid and *cap unchanged. */
static void *grow(void *p, size_t *cap, size_t need, size_t item)
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

static int reserve_tris(builder *b, size_t more)
{
    if (more > SIZE_MAX - b->nt)
        return -1;
    if (b->nt + more <= b->tcap && b->idx)
        return 0;
    void *q = grow(b->idx, &b->tcap, b->nt + more, 3 * sizeof(uint32_t));
    if (!q)
        return -1;
    b->idx = q;
    return 0;
}

/* Caller has reserved room. */
static void emit_tri(builder *b, uint32_t a, uint32_t v1, uint32_t v2)
{
    uint32_t *t = b->idx + 3 * b->nt++;
    t[0] = a;
    t[1] = v1;
    t[2] = v2;
}

enum { C_X, C_Y, C_Z, C_NX, C_NY, C_NZ, C_COUNT };

/* Checks and stores vertex i from v[C_X..C_NZ] (normals only if b->nrm).
 * `number` is how the vertex is named in messages (0-based in PLY, 1-based
 * in OBJ, as each format numbers them). */
static int store_vertex(const mesh_ctx *c, builder *b, size_t i, const double *v, int binary,
                        size_t loc, size_t number)
{
    static const char axis[] = "xyz";
    for (int k = 0; k < 3; k++) {
        if (isnan(v[k]))
            return fail_at(c, binary, loc, "vertex %zu: %c coordinate is NaN (not finite)", number,
                           axis[k]);
        /* Also catches values that are finite as double but round to Inf as
         * float (converting those is undefined behaviour in C). Values just
         * above FLT_MAX that round down to it, such as FLT_MAX printed with
         * 9 digits, are kept: 0x1.ffffffp127 is the midpoint to 2^128. */
        double a = fabs(v[k]);
        if (!(a < 0x1.ffffffp127))
            return fail_at(c, binary, loc, "vertex %zu: %c coordinate %g is not finite as a float",
                           number, axis[k], v[k]);
        b->pos[3 * i + (size_t)k] = a > FLT_MAX ? (v[k] < 0 ? -FLT_MAX : FLT_MAX) : (float)v[k];
    }
    if (!b->nrm)
        return 0;
    double m = 0.0;
    for (int k = 3; k < 6; k++) {
        if (!isfinite(v[k]))
            return fail_at(c, binary, loc, "vertex %zu: normal is not finite", number);
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
    double x = v[C_NX] / m, y = v[C_NY] / m, z = v[C_NZ] / m;
    double len = sqrt(x * x + y * y + z * z);
    n[0] = (float)(x / len);
    n[1] = (float)(y / len);
    n[2] = (float)(z / len);
    return 0;
}

/* Replaces zero-length normals as described at the top of the file. */
static int repair_normals(builder *b)
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
static int finish(const mesh_ctx *c, builder *b, mesh_t **out)
{
    if (b->nt == 0)
        return fail(c, "no triangles");
    if (b->nrm && b->zero_normals && repair_normals(b) != 0)
        return fail(c, "out of memory");
    mesh_t *m = calloc(1, sizeof *m);
    if (!m)
        return fail(c, "out of memory");
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
    m->indices = b->idx;
    m->vertex_count = b->nv;
    m->triangle_count = b->nt;
    memset(b, 0, sizeof *b);
    *out = m;
    return 0;
}

/* ------------------------------------------------------------------------ */
/* Numbers in text                                                          */

static int is_blank(unsigned char ch) /* white space other than '\n' */
{
    return ch == ' ' || ch == '\t' || ch == '\r' || ch == '\v' || ch == '\f';
}

static int is_digit(unsigned char ch)
{
    return (unsigned)(ch - '0') < 10u;
}

/* Integer token, optional sign, decimal digits only, no overflow. */
static int parse_int(const char *s, size_t len, int64_t *out)
{
    size_t i = 0;
    int neg = 0;
    if (i < len && (s[i] == '+' || s[i] == '-')) {
        neg = s[i] == '-';
        i++;
    }
    if (i == len)
        return -1;
    uint64_t v = 0;
    for (; i < len; i++) {
        unsigned d = (unsigned)((unsigned char)s[i] - '0');
        if (d > 9 || v > (UINT64_C(9223372036854775807) - d) / 10)
            return -1;
        v = v * 10 + d;
    }
    *out = neg ? -(int64_t)v : (int64_t)v;
    return 0;
}

static const double pow10_exact[23] = {1e0,  1e1,  1e2,  1e3,  1e4,  1e5,  1e6,  1e7,
                                       1e8,  1e9,  1e10, 1e11, 1e12, 1e13, 1e14, 1e15,
                                       1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22};

/* A whole token as a double, bit-identical to strtod. The common case (at
 * most 19 significant digits, mantissa <= 2^53, |power of ten| <= 22) is one
 * exact integer conversion and one correctly rounded multiply or divide;
 * everything else (nan, inf, hex, long mantissas, big exponents) goes to
 * strtod on a NUL-terminated copy, because the buffer itself is not
 * terminated and strtod must not run past the token. */
static int parse_double(const char *s, size_t len, double *out)
{
    const char *p = s, *e = s + len;
    int neg = 0, sig = 0, nd = 0;
    uint64_t m = 0;
    long e10 = 0;

    if (FLT_EVAL_METHOD != 0)
        goto slow; /* the exactness argument needs plain double arithmetic */
    if (p < e && (*p == '+' || *p == '-')) {
        neg = *p == '-';
        p++;
    }
    for (; p < e && is_digit((unsigned char)*p); p++, nd++) {
        if (m || *p != '0') {
            if (sig == 19)
                goto slow;
            m = m * 10 + (uint64_t)(*p - '0');
            sig++;
        }
    }
    if (p < e && *p == '.') {
        for (p++; p < e && is_digit((unsigned char)*p); p++, nd++) {
            if (m || *p != '0') {
                if (sig == 19)
                    goto slow;
                m = m * 10 + (uint64_t)(*p - '0');
                sig++;
            }
            e10--;
        }
    }
    if (nd == 0)
        goto slow;
    if (p < e && (*p == 'e' || *p == 'E')) {
        int eneg = 0;
        long x = 0;
        p++;
        if (p < e && (*p == '+' || *p == '-')) {
            eneg = *p == '-';
            p++;
        }
        if (p == e || !is_digit((unsigned char)*p))
            return -1;
        for (; p < e && is_digit((unsigned char)*p); p++)
            if (x < 100000)
                x = x * 10 + (*p - '0');
        e10 += eneg ? -x : x;
    }
    if (p != e)
        goto slow;
    if (m == 0) {
        *out = neg ? -0.0 : 0.0;
        return 0;
    }
    if (m > (UINT64_C(1) << 53) || e10 < -22 || e10 > 22)
        goto slow;
    {
        double v = (double)m;
        v = e10 < 0 ? v / pow10_exact[-e10] : v * pow10_exact[e10];
        *out = neg ? -v : v;
        return 0;
    }
slow:;
    char buf[128];
    if (len == 0 || len >= sizeof buf)
        return -1;
    memcpy(buf, s, len);
    buf[len] = '\0';
    char *end = NULL;
    double v = strtod(buf, &end);
    if (end != buf + len)
        return -1;
    *out = v;
    return 0;
}

/* ------------------------------------------------------------------------ */
/* PLY header                                                               */

enum { PT_INT8, PT_UINT8, PT_INT16, PT_UINT16, PT_INT32, PT_UINT32, PT_FLOAT32, PT_FLOAT64 };

static const unsigned char type_size[8] = {1, 1, 2, 2, 4, 4, 4, 8};

static const struct {
    const char *name;
    int type;
} type_names[] = {
    {"char", PT_INT8},     {"int8", PT_INT8},       {"uchar", PT_UINT8},    {"uint8", PT_UINT8},
    {"short", PT_INT16},   {"int16", PT_INT16},     {"ushort", PT_UINT16},  {"uint16", PT_UINT16},
    {"int", PT_INT32},     {"int32", PT_INT32},     {"uint", PT_UINT32},    {"uint32", PT_UINT32},
    {"float", PT_FLOAT32}, {"float32", PT_FLOAT32}, {"double", PT_FLOAT64}, {"float64", PT_FLOAT64},
};

enum { PLY_ASCII, PLY_LE, PLY_BE };
enum { EK_OTHER, EK_VERTEX, EK_FACE };
/* Roles 0..5 are the C_* slots of a vertex; R_NONE is skipped. */
enum { R_NONE = C_COUNT, R_INDICES };

typedef struct ply_prop {
    unsigned char type;       /* value type (item type for lists) */
    unsigned char count_type; /* lists only */
    unsigned char is_list;
    unsigned char role;
} ply_prop;

typedef struct ply_elem {
    char name[32]; /* for messages; longer names are cut */
    uint64_t count;
    size_t line;          /* header line, for messages */
    size_t first, nprops; /* range in ply_header.props */
    int kind;
} ply_elem;

typedef struct ply_header {
    int format;
    ply_elem *elems;
    size_t nelems, ecap;
    ply_prop *props;
    size_t nprops, pcap;
    size_t data_off;  /* first byte after end_header's newline */
    size_t data_line; /* line number of that byte (text) */
    int has_normals;
} ply_header;

static void ply_header_free(ply_header *h)
{
    free(h->elems);
    free(h->props);
}

typedef struct tok {
    const char *s;
    size_t n;
} tok;

static int tok_is(tok t, const char *word)
{
    size_t n = strlen(word);
    return t.n == n && memcmp(t.s, word, n) == 0;
}

static int lookup_type(tok t)
{
    for (size_t i = 0; i < sizeof type_names / sizeof type_names[0]; i++)
        if (tok_is(t, type_names[i].name))
            return type_names[i].type;
    return -1;
}

#define PLY_MAX_TOKENS 8

static int ply_parse_header(const mesh_ctx *c, const unsigned char *data, size_t size,
                            ply_header *h)
{
    size_t pos = 0, line = 0;
    int have_format = 0, done = 0;
    int have_role[C_COUNT + 2] = {0};
    memset(h, 0, sizeof *h);
    h->format = -1;

    while (!done) {
        line++;
        if (pos >= size)
            return fail_at(c, 0, line, "malformed header: file ends before end_header");
        const unsigned char *nl = memchr(data + pos, '\n', size - pos);
        if (!nl)
            return fail_at(c, 0, line, "malformed header: file ends before end_header");
        size_t end = (size_t)(nl - data);
        size_t next = end + 1;
        if (end > pos && data[end - 1] == '\r')
            end--;

        tok t[PLY_MAX_TOKENS];
        size_t nt = 0;
        int too_many = 0;
        for (size_t i = pos; i < end;) {
            while (i < end && is_blank(data[i]))
                i++;
            if (i == end)
                break;
            size_t s = i;
            while (i < end && !is_blank(data[i]))
                i++;
            if (nt == PLY_MAX_TOKENS) {
                too_many = 1;
                break;
            }
            t[nt].s = (const char *)data + s;
            t[nt].n = i - s;
            nt++;
        }
        pos = next;

        if (line == 1) {
            if (nt != 1 || !tok_is(t[0], "ply"))
                return fail_at(c, 0, line, "malformed header: first line is not \"ply\"");
            continue;
        }
        if (nt == 0)
            continue;
        if (tok_is(t[0], "comment") || tok_is(t[0], "obj_info"))
            continue;
        if (too_many)
            return fail_at(c, 0, line, "malformed header: too many words");

        if (tok_is(t[0], "format")) {
            if (have_format)
                return fail_at(c, 0, line, "malformed header: second format line");
            if (nt != 3)
                return fail_at(c, 0, line, "malformed header: format needs a type and a version");
            if (tok_is(t[1], "ascii"))
                h->format = PLY_ASCII;
            else if (tok_is(t[1], "binary_little_endian"))
                h->format = PLY_LE;
            else if (tok_is(t[1], "binary_big_endian"))
                h->format = PLY_BE;
            else
                return fail_at(c, 0, line, "unsupported format \"%.*s\"", quote_len(t[1].n),
                               t[1].s);
            if (!tok_is(t[2], "1.0"))
                return fail_at(c, 0, line, "unsupported format version \"%.*s\"", quote_len(t[2].n),
                               t[2].s);
            have_format = 1;
        } else if (tok_is(t[0], "element")) {
            if (!have_format)
                return fail_at(c, 0, line, "malformed header: element before format");
            if (nt != 3)
                return fail_at(c, 0, line, "malformed header: element needs a name and a count");
            int64_t cnt;
            if (t[2].s[0] == '-' || t[2].s[0] == '+' || parse_int(t[2].s, t[2].n, &cnt) != 0)
                return fail_at(c, 0, line, "malformed header: bad element count \"%.*s\"",
                               quote_len(t[2].n), t[2].s);
            int kind = tok_is(t[1], "vertex") ? EK_VERTEX
                       : tok_is(t[1], "face") ? EK_FACE
                                              : EK_OTHER;
            for (size_t i = 0; i < h->nelems; i++)
                if (kind != EK_OTHER && h->elems[i].kind == kind)
                    return fail_at(c, 0, line, "malformed header: second element %.*s",
                                   quote_len(t[1].n), t[1].s);
            void *q = grow(h->elems, &h->ecap, h->nelems + 1, sizeof *h->elems);
            if (!q)
                return fail(c, "out of memory");
            h->elems = q;
            ply_elem *el = &h->elems[h->nelems++];
            memset(el, 0, sizeof *el);
            size_t nlen = t[1].n < sizeof el->name - 1 ? t[1].n : sizeof el->name - 1;
            memcpy(el->name, t[1].s, nlen);
            el->name[nlen] = '\0';
            el->count = (uint64_t)cnt;
            el->line = line;
            el->first = h->nprops;
            el->kind = kind;
        } else if (tok_is(t[0], "property")) {
            if (h->nelems == 0)
                return fail_at(c, 0, line, "malformed header: property before any element");
            ply_elem *el = &h->elems[h->nelems - 1];
            ply_prop p = {0, 0, 0, R_NONE};
            tok name;
            if (nt >= 2 && tok_is(t[1], "list")) {
                if (nt != 5)
                    return fail_at(c, 0, line,
                                   "malformed header: list property needs "
                                   "a count type, an item type and a name");
                int ct = lookup_type(t[2]), it = lookup_type(t[3]);
                if (ct < 0 || it < 0) {
                    tok bad = ct < 0 ? t[2] : t[3];
                    return fail_at(c, 0, line, "malformed header: unknown property type \"%.*s\"",
                                   quote_len(bad.n), bad.s);
                }
                p.is_list = 1;
                p.count_type = (unsigned char)ct;
                p.type = (unsigned char)it;
                name = t[4];
            } else {
                if (nt != 3)
                    return fail_at(c, 0, line,
                                   "malformed header: property needs a type and a name");
                int ty = lookup_type(t[1]);
                if (ty < 0)
                    return fail_at(c, 0, line, "malformed header: unknown property type \"%.*s\"",
                                   quote_len(t[1].n), t[1].s);
                p.type = (unsigned char)ty;
                name = t[2];
            }
            if (el->kind == EK_VERTEX) {
                static const char *const vnames[C_COUNT] = {"x", "y", "z", "nx", "ny", "nz"};
                for (int r = 0; r < C_COUNT; r++) {
                    if (!tok_is(name, vnames[r]))
                        continue;
                    if (p.is_list)
                        return fail_at(c, 0, line,
                                       "malformed header: vertex property %s "
                                       "must not be a list",
                                       vnames[r]);
                    if (have_role[r])
                        return fail_at(c, 0, line, "malformed header: second vertex property %s",
                                       vnames[r]);
                    have_role[r] = 1;
                    p.role = (unsigned char)r;
                }
            } else if (el->kind == EK_FACE &&
                       (tok_is(name, "vertex_indices") || tok_is(name, "vertex_index"))) {
                if (!p.is_list)
                    return fail_at(c, 0, line,
                                   "malformed header: face property %.*s must be a list",
                                   quote_len(name.n), name.s);
                if (have_role[R_INDICES])
                    return fail_at(c, 0, line, "malformed header: second face index list");
                have_role[R_INDICES] = 1;
                p.role = R_INDICES;
            }
            void *q = grow(h->props, &h->pcap, h->nprops + 1, sizeof *h->props);
            if (!q)
                return fail(c, "out of memory");
            h->props = q;
            h->props[h->nprops++] = p;
            el->nprops++;
        } else if (tok_is(t[0], "end_header")) {
            if (nt != 1)
                return fail_at(c, 0, line, "malformed header: text after end_header");
            done = 1;
        } else {
            return fail_at(c, 0, line, "malformed header: unknown keyword \"%.*s\"",
                           quote_len(t[0].n), t[0].s);
        }
    }
    h->data_off = pos;
    h->data_line = line + 1;

    if (!have_format)
        return fail(c, "malformed header: no format line");
    const ply_elem *vert = NULL, *face = NULL;
    for (size_t i = 0; i < h->nelems; i++) {
        if (h->elems[i].kind == EK_VERTEX)
            vert = &h->elems[i];
        if (h->elems[i].kind == EK_FACE)
            face = &h->elems[i];
    }
    if (!vert)
        return fail(c, "malformed header: no vertex element");
    if (!have_role[C_X] || !have_role[C_Y] || !have_role[C_Z])
        return fail_at(c, 0, vert->line, "malformed header: element vertex lacks x, y or z");
    if (face && !have_role[R_INDICES])
        return fail_at(c, 0, face->line,
                       "malformed header: element face has no vertex_indices list");
    h->has_normals = have_role[C_NX] && have_role[C_NY] && have_role[C_NZ];
    if (!h->has_normals) {
        /* A partial normal is not a normal: treat its parts as unknown. */
        for (size_t i = 0; i < h->nprops; i++)
            if (h->props[i].role >= C_NX && h->props[i].role <= C_NZ)
                h->props[i].role = R_NONE;
    }
    return 0;
}

/* Fails if the element counts cannot fit in the bytes after the header,
 * taking for each element the least it can occupy (a face at least three
 * indices, text at least one character and one separator per value). This
 * bounds every allocation below by a small multiple of the file size. */
static int ply_check_counts(const mesh_ctx *c, const ply_header *h, size_t size)
{
    int binary = h->format != PLY_ASCII;
    uint64_t avail = (uint64_t)(size - h->data_off) + (binary ? 0 : 1);
    uint64_t used = 0;
    for (size_t e = 0; e < h->nelems; e++) {
        const ply_elem *el = &h->elems[e];
        uint64_t min = 0;
        for (size_t i = 0; i < el->nprops; i++) {
            const ply_prop *p = &h->props[el->first + i];
            if (binary)
                min += p->is_list ? type_size[p->count_type] +
                                        (p->role == R_INDICES ? 3u * type_size[p->type] : 0u)
                                  : type_size[p->type];
            else
                min += 2u * (p->is_list ? 1u + (p->role == R_INDICES ? 3u : 0u) : 1u);
        }
        if (min == 0)
            continue;
        if (el->count > (avail - used) / min)
            return fail_at(c, 0, el->line,
                           "element %s count %" PRIu64 " is more than the file can hold "
                           "(needs at least %" PRIu64 " bytes per %s, %" PRIu64
                           " bytes left; truncated file or bad count)",
                           el->name, el->count, min, el->name, avail - used);
        used += el->count * min;
    }
    const ply_elem *vert = NULL;
    for (size_t e = 0; e < h->nelems; e++)
        if (h->elems[e].kind == EK_VERTEX)
            vert = &h->elems[e];
    if (vert->count > UINT32_MAX)
        return fail_at(c, 0, vert->line,
                       "element vertex count %" PRIu64 " is too large for 32-bit indices",
                       vert->count);
    return 0;
}

/* ------------------------------------------------------------------------ */
/* PLY binary body                                                          */

static uint64_t load_bits(const unsigned char *p, unsigned n, int big)
{
    uint64_t v = 0;
    if (big)
        for (unsigned i = 0; i < n; i++)
            v = v << 8 | p[i];
    else
        for (unsigned i = n; i-- > 0;)
            v = v << 8 | p[i];
    return v;
}

static double bits_to_double(uint64_t u, int type)
{
    switch (type) {
    case PT_INT8: {
        uint8_t x = (uint8_t)u;
        int8_t s;
        memcpy(&s, &x, 1);
        return s;
    }
    case PT_UINT8:
        return (double)(uint8_t)u;
    case PT_INT16: {
        uint16_t x = (uint16_t)u;
        int16_t s;
        memcpy(&s, &x, 2);
        return s;
    }
    case PT_UINT16:
        return (double)(uint16_t)u;
    case PT_INT32: {
        uint32_t x = (uint32_t)u;
        int32_t s;
        memcpy(&s, &x, 4);
        return s;
    }
    case PT_UINT32:
        return (double)(uint32_t)u;
    case PT_FLOAT32: {
        uint32_t x = (uint32_t)u;
        float f;
        memcpy(&f, &x, 4);
        return f;
    }
    default: {
        double d;
        memcpy(&d, &u, 8);
        return d;
    }
    }
}

/* An integer-valued binary scalar (list count or index); floating types are
 * accepted when they hold an exact integer. Returns -1 otherwise. */
static int bits_to_int(uint64_t u, int type, int64_t *out)
{
    if (type != PT_FLOAT32 && type != PT_FLOAT64) {
        *out = (int64_t)bits_to_double(u, type); /* exact for <= 32-bit ints */
        return 0;
    }
    double d = bits_to_double(u, type);
    if (!(d >= -9007199254740992.0 && d <= 9007199254740992.0) || d != floor(d))
        return -1;
    *out = (int64_t)d;
    return 0;
}

static int ply_read_binary(const mesh_ctx *c, const ply_header *h, const unsigned char *data,
                           size_t size, builder *b)
{
    int big = h->format == PLY_BE;
    size_t off = h->data_off;
    const size_t nv = b->nv;

    for (size_t e = 0; e < h->nelems; e++) {
        const ply_elem *el = &h->elems[e];
        const ply_prop *props = h->props + el->first;
        if (el->nprops == 0)
            continue;
        for (uint64_t i = 0; i < el->count; i++) {
            size_t start = off;
            double v[C_COUNT] = {0};
            for (size_t k = 0; k < el->nprops; k++) {
                const ply_prop *p = &props[k];
                if (!p->is_list) {
                    unsigned sz = type_size[p->type];
                    if (size - off < sz)
                        return fail_at(c, 1, off, "truncated in element %s %" PRIu64, el->name, i);
                    if (p->role < C_COUNT)
                        v[p->role] = bits_to_double(load_bits(data + off, sz, big), p->type);
                    off += sz;
                    continue;
                }
                unsigned csz = type_size[p->count_type], isz = type_size[p->type];
                int64_t n;
                if (size - off < csz)
                    return fail_at(c, 1, off, "truncated in element %s %" PRIu64, el->name, i);
                if (bits_to_int(load_bits(data + off, csz, big), p->count_type, &n) != 0 || n < 0)
                    return fail_at(c, 1, off, "element %s %" PRIu64 ": bad list count", el->name,
                                   i);
                off += csz;
                if ((uint64_t)n > (size - off) / isz)
                    return fail_at(c, 1, off,
                                   "truncated: element %s %" PRIu64 " has a list of %" PRId64
                                   " items but only %zu bytes are left",
                                   el->name, i, n, size - off);
                if (p->role != R_INDICES) {
                    off += (size_t)n * isz;
                    continue;
                }
                if (n < 3)
                    return fail_at(c, 1, start,
                                   "face %" PRIu64 " has %" PRId64 " vertices (need at least 3)", i,
                                   n);
                if (reserve_tris(b, (size_t)n - 2) != 0)
                    return fail(c, "out of memory");
                uint32_t first = 0, prev = 0;
                for (int64_t j = 0; j < n; j++, off += isz) {
                    int64_t x;
                    if (bits_to_int(load_bits(data + off, isz, big), p->type, &x) != 0)
                        return fail_at(c, 1, off,
                                       "face %" PRIu64 ", index %" PRId64 ": not an integer", i, j);
                    if (x < 0 || (uint64_t)x >= nv)
                        return fail_at(c, 1, off,
                                       "face %" PRIu64 ", index %" PRId64 ": vertex %" PRId64
                                       " is out of range (vertex count %zu)",
                                       i, j, x, nv);
                    uint32_t u = (uint32_t)x;
                    if (j == 0)
                        first = u;
                    else if (j >= 2)
                        emit_tri(b, first, prev, u);
                    prev = u;
                }
            }
            if (el->kind == EK_VERTEX && store_vertex(c, b, (size_t)i, v, 1, start, (size_t)i) != 0)
                return -1;
        }
    }
    return 0;
}

/* ------------------------------------------------------------------------ */
/* PLY ascii body                                                           */

typedef struct cursor {
    const char *p, *end;
    size_t line;
} cursor;

/* Next value on the current line. 1 and the token, or 0 with a message. */
static int next_value(const mesh_ctx *c, cursor *cur, const ply_elem *el, uint64_t i, tok *t)
{
    while (cur->p < cur->end && is_blank((unsigned char)*cur->p))
        cur->p++;
    if (cur->p == cur->end) {
        fail_at(c, 0, cur->line, "truncated: file ends inside element %s %" PRIu64, el->name, i);
        return 0;
    }
    if (*cur->p == '\n') {
        fail_at(c, 0, cur->line,
                "element %s %" PRIu64 " has fewer values than the header "
                "declares",
                el->name, i);
        return 0;
    }
    t->s = cur->p;
    while (cur->p < cur->end && !is_blank((unsigned char)*cur->p) && *cur->p != '\n')
        cur->p++;
    t->n = (size_t)(cur->p - t->s);
    return 1;
}

static int text_to_int(tok t, int type, int64_t *out)
{
    if (type != PT_FLOAT32 && type != PT_FLOAT64)
        return parse_int(t.s, t.n, out);
    double d;
    if (parse_double(t.s, t.n, &d) != 0 || !(d >= -9007199254740992.0 && d <= 9007199254740992.0) ||
        d != floor(d))
        return -1;
    *out = (int64_t)d;
    return 0;
}

static int ply_read_ascii(const mesh_ctx *c, const ply_header *h, const unsigned char *data,
                          size_t size, builder *b)
{
    cursor cur = {(const char *)data + h->data_off, (const char *)data + size, h->data_line};
    const size_t nv = b->nv;

    for (size_t e = 0; e < h->nelems; e++) {
        const ply_elem *el = &h->elems[e];
        const ply_prop *props = h->props + el->first;
        if (el->nprops == 0)
            continue;
        for (uint64_t i = 0; i < el->count; i++) {
            while (cur.p < cur.end && (is_blank((unsigned char)*cur.p) || *cur.p == '\n'))
                if (*cur.p++ == '\n')
                    cur.line++;
            if (cur.p == cur.end)
                return fail_at(c, 0, cur.line,
                               "truncated: the header declares %" PRIu64
                               " %s elements, the file ends after %" PRIu64,
                               el->count, el->name, i);
            double v[C_COUNT] = {0};
            tok t;
            for (size_t k = 0; k < el->nprops; k++) {
                const ply_prop *p = &props[k];
                if (!next_value(c, &cur, el, i, &t))
                    return -1;
                if (!p->is_list) {
                    if (p->role < C_COUNT && parse_double(t.s, t.n, &v[p->role]) != 0)
                        return fail_at(c, 0, cur.line,
                                       "element %s %" PRIu64 ": bad number \"%.*s\"", el->name, i,
                                       quote_len(t.n), t.s);
                    continue;
                }
                int64_t n;
                if (text_to_int(t, p->count_type, &n) != 0 || n < 0)
                    return fail_at(c, 0, cur.line,
                                   "element %s %" PRIu64 ": bad list count \"%.*s\"", el->name, i,
                                   quote_len(t.n), t.s);
                /* Each value takes at least two characters; this bounds the
                 * reservation below by the bytes actually there. */
                if ((uint64_t)n > (uint64_t)(cur.end - cur.p) / 2 + 1)
                    return fail_at(c, 0, cur.line,
                                   "truncated: element %s %" PRIu64 " has a list of %" PRId64
                                   " items",
                                   el->name, i, n);
                if (p->role != R_INDICES) {
                    for (int64_t j = 0; j < n; j++)
                        if (!next_value(c, &cur, el, i, &t))
                            return -1;
                    continue;
                }
                if (n < 3)
                    return fail_at(c, 0, cur.line,
                                   "face %" PRIu64 " has %" PRId64 " vertices (need at least 3)", i,
                                   n);
                if (reserve_tris(b, (size_t)n - 2) != 0)
                    return fail(c, "out of memory");
                uint32_t first = 0, prev = 0;
                for (int64_t j = 0; j < n; j++) {
                    int64_t x;
                    if (!next_value(c, &cur, el, i, &t))
                        return -1;
                    if (text_to_int(t, p->type, &x) != 0)
                        return fail_at(c, 0, cur.line,
                                       "face %" PRIu64 ", index %" PRId64 ": bad number \"%.*s\"",
                                       i, j, quote_len(t.n), t.s);
                    if (x < 0 || (uint64_t)x >= nv)
                        return fail_at(c, 0, cur.line,
                                       "face %" PRIu64 ", index %" PRId64 ": vertex %" PRId64
                                       " is out of range (vertex count %zu)",
                                       i, j, x, nv);
                    uint32_t u = (uint32_t)x;
                    if (j == 0)
                        first = u;
                    else if (j >= 2)
                        emit_tri(b, first, prev, u);
                    prev = u;
                }
            }
            while (cur.p < cur.end && is_blank((unsigned char)*cur.p))
                cur.p++;
            if (cur.p < cur.end && *cur.p != '\n')
                return fail_at(c, 0, cur.line,
                               "element %s %" PRIu64 " has more values than "
                               "the header declares",
                               el->name, i);
            if (el->kind == EK_VERTEX &&
                store_vertex(c, b, (size_t)i, v, 0, cur.line, (size_t)i) != 0)
                return -1;
        }
    }
    return 0;
}

static int ply_load(const mesh_ctx *c, const unsigned char *data, size_t size, builder *b)
{
    ply_header h;
    int r = ply_parse_header(c, data, size, &h);
    if (r == 0)
        r = ply_check_counts(c, &h, size);
    if (r == 0) {
        size_t nv = 0;
        for (size_t e = 0; e < h.nelems; e++)
            if (h.elems[e].kind == EK_VERTEX)
                nv = (size_t)h.elems[e].count;
        size_t nf = 0;
        for (size_t e = 0; e < h.nelems; e++)
            if (h.elems[e].kind == EK_FACE)
                nf = (size_t)h.elems[e].count;
        /* Sizes are bounded by ply_check_counts; no overflow on any target
         * where size_t holds the file size. */
        b->pos = malloc(nv ? nv * 3 * sizeof(float) : 1);
        b->nrm = h.has_normals ? malloc(nv ? nv * 3 * sizeof(float) : 1) : NULL;
        b->nv = b->vcap = nv;
        if (!b->pos || (h.has_normals && !b->nrm))
            r = fail(c, "out of memory");
        else if (nf && reserve_tris(b, nf) != 0) /* one triangle per face at least */
            r = fail(c, "out of memory");
        else if (h.format == PLY_ASCII)
            r = ply_read_ascii(c, &h, data, size, b);
        else
            r = ply_read_binary(c, &h, data, size, b);
    }
    ply_header_free(&h);
    return r;
}

/* ------------------------------------------------------------------------ */
/* OBJ                                                                      */

static int obj_load(const mesh_ctx *c, const unsigned char *data, size_t size, builder *b)
{
    const char *p = (const char *)data, *end = p + size;
    size_t line = 0, faces = 0;
    /* Positive indices may point forward, so they are checked at the end
     * against the final count; the largest one is kept for the message. */
    int64_t max_idx = 0;
    size_t max_line = 0, max_face = 0, max_corner = 0;

    for (; p < end; line++) {
        const char *eol = memchr(p, '\n', (size_t)(end - p));
        if (!eol)
            eol = end;
        const char *q = p;
        p = eol < end ? eol + 1 : end;
        while (q < eol && is_blank((unsigned char)*q))
            q++;
        if (q == eol || (q[0] != 'v' && q[0] != 'f') ||
            (eol - q > 1 && !is_blank((unsigned char)q[1])))
            continue; /* vn, vt, o, g, s, usemtl, mtllib, #, l, p, blank... */

        if (q[0] == 'v') {
            double v[C_COUNT] = {0};
            q++;
            for (int k = 0; k < 3; k++) {
                while (q < eol && is_blank((unsigned char)*q))
                    q++;
                if (q == eol || *q == '#')
                    return fail_at(c, 0, line + 1, "vertex needs 3 coordinates, found %d", k);
                const char *s = q;
                while (q < eol && !is_blank((unsigned char)*q))
                    q++;
                if (parse_double(s, (size_t)(q - s), &v[k]) != 0)
                    return fail_at(c, 0, line + 1, "bad number \"%.*s\"",
                                   quote_len((size_t)(q - s)), s);
            }
            if (b->nv == UINT32_MAX)
                return fail_at(c, 0, line + 1, "too many vertices for 32-bit indices");
            if (b->nv == b->vcap) {
                void *np = grow(b->pos, &b->vcap, b->nv + 1, 3 * sizeof(float));
                if (!np)
                    return fail(c, "out of memory");
                b->pos = np;
            }
            if (store_vertex(c, b, b->nv, v, 0, line + 1, b->nv + 1) != 0)
                return -1;
            b->nv++;
            continue;
        }

        /* f v1[/vt[/vn]] v2... */
        uint32_t first = 0, prev = 0;
        size_t corner = 0;
        faces++;
        for (q++;; corner++) {
            while (q < eol && is_blank((unsigned char)*q))
                q++;
            if (q == eol || *q == '#')
                break;
            const char *s = q;
            while (q < eol && !is_blank((unsigned char)*q))
                q++;
            size_t n = (size_t)(q - s), ilen = 0;
            while (ilen < n && s[ilen] != '/')
                ilen++;
            int64_t x;
            int bad = parse_int(s, ilen, &x) != 0;
            for (size_t j = ilen; j < n && !bad; j++) /* the vt/vn part is checked, not used */
                bad = !(is_digit((unsigned char)s[j]) || s[j] == '/' || s[j] == '-');
            if (bad)
                return fail_at(c, 0, line + 1, "face %zu: bad vertex \"%.*s\"", faces, quote_len(n),
                               s);
            if (x == 0)
                return fail_at(c, 0, line + 1,
                               "face %zu, index %zu: 0 is not a valid index "
                               "(OBJ indices start at 1)",
                               faces, corner + 1);
            if (x < 0) {
                if (-x > (int64_t)b->nv)
                    return fail_at(c, 0, line + 1,
                                   "face %zu, index %zu: relative index %" PRId64
                                   " is out of range (%zu vertices so far)",
                                   faces, corner + 1, x, b->nv);
                x += (int64_t)b->nv;
            } else {
                if (x > (int64_t)UINT32_MAX)
                    return fail_at(c, 0, line + 1,
                                   "face %zu, index %zu: %" PRId64 " is out of range", faces,
                                   corner + 1, x);
                if (x > max_idx) {
                    max_idx = x;
                    max_line = line + 1;
                    max_face = faces;
                    max_corner = corner + 1;
                }
                x -= 1;
            }
            uint32_t u = (uint32_t)x;
            if (corner == 0) {
                first = u;
            } else if (corner >= 2) {
                if (reserve_tris(b, 1) != 0)
                    return fail(c, "out of memory");
                emit_tri(b, first, prev, u);
            }
            prev = u;
        }
        if (corner < 3)
            return fail_at(c, 0, line + 1, "face %zu has %zu vertices (need at least 3)", faces,
                           corner);
    }
    if ((uint64_t)max_idx > b->nv)
        return fail_at(c, 0, max_line,
                       "face %zu, index %zu: vertex %" PRId64
                       " is out of range (the file has %zu vertices)",
                       max_face, max_corner, max_idx, b->nv);
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
    mesh_ctx c = {name ? name : "(buffer)", err, errlen};
    if (err && errlen)
        err[0] = '\0';
    if (out)
        *out = NULL;
    if (!out || (!data && size))
        return fail(&c, "invalid arguments");

    builder b;
    memset(&b, 0, sizeof b);
    int r;
    if ((size >= 4 && memcmp(data, "ply\n", 4) == 0) ||
        (size >= 5 && memcmp(data, "ply\r\n", 5) == 0))
        r = ply_load(&c, data, size, &b);
    else if (ends_with_obj(c.name))
        r = obj_load(&c, data, size, &b);
    else if (size == 0)
        r = fail(&c, "empty file");
    else
        r = fail(&c, "unsupported format: not PLY (first line is not \"ply\") "
                     "and the name does not end in .obj");
    if (r == 0)
        r = finish(&c, &b, out);
    builder_free(&b);
    return r;
}

int mesh_load(const char *path, mesh_t **out, char *err, size_t errlen)
{
    mesh_ctx c = {path ? path : "(null)", err, errlen};
    if (out)
        *out = NULL;
    if (!path || !out)
        return fail(&c, "invalid arguments");
    FILE *f = fopen(path, "rb");
    if (!f)
        return fail(&c, "cannot open: %s", strerror(errno));
    struct stat st;
    if (fstat(fileno(f), &st) != 0 || !S_ISREG(st.st_mode)) {
        fclose(f);
        return fail(&c, "not a regular file");
    }
    if ((uintmax_t)st.st_size > (uintmax_t)SIZE_MAX / 2) {
        fclose(f);
        return fail(&c, "file too large");
    }
    size_t size = (size_t)st.st_size;
    unsigned char *buf = malloc(size ? size : 1);
    if (!buf) {
        fclose(f);
        return fail(&c, "out of memory reading %zu bytes", size);
    }
    size_t got = fread(buf, 1, size, f);
    fclose(f);
    if (got != size) {
        free(buf);
        return fail(&c, "read error (got %zu of %zu bytes)", got, size);
    }
    int r = mesh_load_buffer(path, buf, size, out, err, errlen);
    free(buf);
    return r;
}

void mesh_destroy(mesh_t **m)
{
    if (!m || !*m)
        return;
    free((*m)->positions);
    free((*m)->normals);
    free((*m)->indices);
    free(*m);
    *m = NULL;
}
