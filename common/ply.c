/* ply.c - the PLY reader (ascii, binary little and big endian) behind
 * mesh_load; see mesh_priv.h for how it fills the mesh under construction.
 *
 * The header is parsed first into a table of elements and their properties,
 * each property given a role (a vertex value, the face index list, or
 * nothing: skipped). ply_check_counts then bounds every element count by
 * the bytes left in the file before the body is read, so a lying header
 * fails with a message instead of a huge malloc.
 *
 * Ascii PLY is line based: each element on its own line, blank lines
 * allowed between elements. Values of skipped properties are not parsed.
 * Polygons are split into triangle fans.
 */
#include <inttypes.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "mesh_priv.h"
#include "numparse.h"

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
/* Roles 0..5 are the MESH_* slots of a vertex; R_NONE is skipped. */
enum { R_NONE = MESH_VALUES, R_INDICES };

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

/* The header being parsed: the table so far, and what it has declared. */
typedef struct ply_parse {
    ply_header *h;
    size_t line; /* the header line being parsed, 1-based */
    int have_format;
    int have_role[MESH_VALUES + 2];
} ply_parse;

/* Splits data[pos, end) into words. Returns how many (at most
 * PLY_MAX_TOKENS); *too_many is set when more words follow. */
static size_t ply_split_words(const unsigned char *data, size_t pos, size_t end,
                              tok t[PLY_MAX_TOKENS], int *too_many)
{
    size_t nt = 0;
    *too_many = 0;
    for (size_t i = pos; i < end;) {
        while (i < end && num_is_blank(data[i]))
            i++;
        if (i == end)
            break;
        size_t s = i;
        while (i < end && !num_is_blank(data[i]))
            i++;
        if (nt == PLY_MAX_TOKENS) {
            *too_many = 1;
            break;
        }
        t[nt].s = (const char *)data + s;
        t[nt].n = i - s;
        nt++;
    }
    return nt;
}

/* "format ascii|binary_little_endian|binary_big_endian 1.0" */
static int ply_header_format(const mesh_ctx *c, ply_parse *ps, const tok *t, size_t nt)
{
    size_t line = ps->line;
    if (ps->have_format)
        return mesh_fail_at(c, 0, line, "malformed header: second format line");
    if (nt != 3)
        return mesh_fail_at(c, 0, line, "malformed header: format needs a type and a version");
    if (tok_is(t[1], "ascii"))
        ps->h->format = PLY_ASCII;
    else if (tok_is(t[1], "binary_little_endian"))
        ps->h->format = PLY_LE;
    else if (tok_is(t[1], "binary_big_endian"))
        ps->h->format = PLY_BE;
    else
        return mesh_fail_at(c, 0, line, "unsupported format \"%.*s\"", mesh_quote_len(t[1].n),
                            t[1].s);
    if (!tok_is(t[2], "1.0"))
        return mesh_fail_at(c, 0, line, "unsupported format version \"%.*s\"",
                            mesh_quote_len(t[2].n), t[2].s);
    ps->have_format = 1;
    return 0;
}

/* "element NAME COUNT": a new entry in the element table. */
static int ply_header_element(const mesh_ctx *c, ply_parse *ps, const tok *t, size_t nt)
{
    ply_header *h = ps->h;
    size_t line = ps->line;
    if (!ps->have_format)
        return mesh_fail_at(c, 0, line, "malformed header: element before format");
    if (nt != 3)
        return mesh_fail_at(c, 0, line, "malformed header: element needs a name and a count");
    int64_t cnt;
    if (t[2].s[0] == '-' || t[2].s[0] == '+' || num_parse_int(t[2].s, t[2].n, &cnt) != 0)
        return mesh_fail_at(c, 0, line, "malformed header: bad element count \"%.*s\"",
                            mesh_quote_len(t[2].n), t[2].s);
    int kind = tok_is(t[1], "vertex") ? EK_VERTEX : tok_is(t[1], "face") ? EK_FACE : EK_OTHER;
    for (size_t i = 0; i < h->nelems; i++)
        if (kind != EK_OTHER && h->elems[i].kind == kind)
            return mesh_fail_at(c, 0, line, "malformed header: second element %.*s",
                                mesh_quote_len(t[1].n), t[1].s);
    void *q = mesh_grow(h->elems, &h->ecap, h->nelems + 1, sizeof *h->elems);
    if (!q)
        return mesh_fail(c, "out of memory");
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
    return 0;
}

/* The types of "property TYPE NAME" or "property list CTYPE ITYPE NAME"
 * into *p, and the name into *name. */
static int ply_property_type(const mesh_ctx *c, size_t line, const tok *t, size_t nt, ply_prop *p,
                             tok *name)
{
    if (nt >= 2 && tok_is(t[1], "list")) {
        if (nt != 5)
            return mesh_fail_at(c, 0, line,
                                "malformed header: list property needs "
                                "a count type, an item type and a name");
        int ct = lookup_type(t[2]), it = lookup_type(t[3]);
        if (ct < 0 || it < 0) {
            tok bad = ct < 0 ? t[2] : t[3];
            return mesh_fail_at(c, 0, line, "malformed header: unknown property type \"%.*s\"",
                                mesh_quote_len(bad.n), bad.s);
        }
        p->is_list = 1;
        p->count_type = (unsigned char)ct;
        p->type = (unsigned char)it;
        *name = t[4];
        return 0;
    }
    if (nt != 3)
        return mesh_fail_at(c, 0, line, "malformed header: property needs a type and a name");
    int ty = lookup_type(t[1]);
    if (ty < 0)
        return mesh_fail_at(c, 0, line, "malformed header: unknown property type \"%.*s\"",
                            mesh_quote_len(t[1].n), t[1].s);
    p->type = (unsigned char)ty;
    *name = t[2];
    return 0;
}

/* The role of a property by its element and name: x..nz of the vertex, the
 * face's index list, or none (left as R_NONE). Each role at most once. */
static int ply_property_role(const mesh_ctx *c, ply_parse *ps, const ply_elem *el, ply_prop *p,
                             tok name)
{
    size_t line = ps->line;
    if (el->kind == EK_VERTEX) {
        static const char *const vnames[MESH_VALUES] = {"x", "y", "z", "nx", "ny", "nz"};
        for (int r = 0; r < MESH_VALUES; r++) {
            if (!tok_is(name, vnames[r]))
                continue;
            if (p->is_list)
                return mesh_fail_at(c, 0, line,
                                    "malformed header: vertex property %s "
                                    "must not be a list",
                                    vnames[r]);
            if (ps->have_role[r])
                return mesh_fail_at(c, 0, line, "malformed header: second vertex property %s",
                                    vnames[r]);
            ps->have_role[r] = 1;
            p->role = (unsigned char)r;
        }
    } else if (el->kind == EK_FACE &&
               (tok_is(name, "vertex_indices") || tok_is(name, "vertex_index"))) {
        if (!p->is_list)
            return mesh_fail_at(c, 0, line, "malformed header: face property %.*s must be a list",
                                mesh_quote_len(name.n), name.s);
        if (ps->have_role[R_INDICES])
            return mesh_fail_at(c, 0, line, "malformed header: second face index list");
        ps->have_role[R_INDICES] = 1;
        p->role = R_INDICES;
    }
    return 0;
}

/* "property ...": appended to the last element. */
static int ply_header_property(const mesh_ctx *c, ply_parse *ps, const tok *t, size_t nt)
{
    ply_header *h = ps->h;
    if (h->nelems == 0)
        return mesh_fail_at(c, 0, ps->line, "malformed header: property before any element");
    ply_elem *el = &h->elems[h->nelems - 1];
    ply_prop p = {0, 0, 0, R_NONE};
    tok name = {NULL, 0};
    if (ply_property_type(c, ps->line, t, nt, &p, &name) != 0 ||
        ply_property_role(c, ps, el, &p, name) != 0)
        return -1;
    void *q = mesh_grow(h->props, &h->pcap, h->nprops + 1, sizeof *h->props);
    if (!q)
        return mesh_fail(c, "out of memory");
    h->props = q;
    h->props[h->nprops++] = p;
    el->nprops++;
    return 0;
}

/* One header line after the first, split into words. Returns 1 at
 * end_header, 0 to go on, -1 on error. */
static int ply_header_line(const mesh_ctx *c, ply_parse *ps, const tok *t, size_t nt, int too_many)
{
    if (nt == 0)
        return 0;
    if (tok_is(t[0], "comment") || tok_is(t[0], "obj_info"))
        return 0;
    if (too_many)
        return mesh_fail_at(c, 0, ps->line, "malformed header: too many words");
    if (tok_is(t[0], "format"))
        return ply_header_format(c, ps, t, nt);
    if (tok_is(t[0], "element"))
        return ply_header_element(c, ps, t, nt);
    if (tok_is(t[0], "property"))
        return ply_header_property(c, ps, t, nt);
    if (tok_is(t[0], "end_header")) {
        if (nt != 1)
            return mesh_fail_at(c, 0, ps->line, "malformed header: text after end_header");
        return 1;
    }
    return mesh_fail_at(c, 0, ps->line, "malformed header: unknown keyword \"%.*s\"",
                        mesh_quote_len(t[0].n), t[0].s);
}

/* After end_header: what the rest of the reader relies on is there. */
static int ply_header_check(const mesh_ctx *c, const ply_parse *ps)
{
    ply_header *h = ps->h;
    if (!ps->have_format)
        return mesh_fail(c, "malformed header: no format line");
    const ply_elem *vert = NULL, *face = NULL;
    for (size_t i = 0; i < h->nelems; i++) {
        if (h->elems[i].kind == EK_VERTEX)
            vert = &h->elems[i];
        if (h->elems[i].kind == EK_FACE)
            face = &h->elems[i];
    }
    if (!vert)
        return mesh_fail(c, "malformed header: no vertex element");
    if (!ps->have_role[MESH_X] || !ps->have_role[MESH_Y] || !ps->have_role[MESH_Z])
        return mesh_fail_at(c, 0, vert->line, "malformed header: element vertex lacks x, y or z");
    if (face && !ps->have_role[R_INDICES])
        return mesh_fail_at(c, 0, face->line,
                            "malformed header: element face has no vertex_indices list");
    h->has_normals = ps->have_role[MESH_NX] && ps->have_role[MESH_NY] && ps->have_role[MESH_NZ];
    if (!h->has_normals) {
        /* A partial normal is not a normal: treat its parts as unknown. */
        for (size_t i = 0; i < h->nprops; i++)
            if (h->props[i].role >= MESH_NX && h->props[i].role <= MESH_NZ)
                h->props[i].role = R_NONE;
    }
    return 0;
}

/* Reads the header lines up to end_header into *h (freed by the caller
 * with ply_header_free, also on failure). */
static int ply_parse_header(const mesh_ctx *c, const unsigned char *data, size_t size,
                            ply_header *h)
{
    ply_parse ps;
    memset(&ps, 0, sizeof ps);
    ps.h = h;
    memset(h, 0, sizeof *h);
    h->format = -1;

    size_t pos = 0;
    for (int r = 0; r == 0;) {
        ps.line++;
        if (pos >= size)
            return mesh_fail_at(c, 0, ps.line, "malformed header: file ends before end_header");
        const unsigned char *nl = memchr(data + pos, '\n', size - pos);
        if (!nl)
            return mesh_fail_at(c, 0, ps.line, "malformed header: file ends before end_header");
        size_t end = (size_t)(nl - data);
        size_t next = end + 1;
        if (end > pos && data[end - 1] == '\r')
            end--;

        tok t[PLY_MAX_TOKENS];
        int too_many;
        size_t nt = ply_split_words(data, pos, end, t, &too_many);
        pos = next;

        if (ps.line == 1) {
            if (nt != 1 || !tok_is(t[0], "ply"))
                return mesh_fail_at(c, 0, ps.line, "malformed header: first line is not \"ply\"");
            continue;
        }
        r = ply_header_line(c, &ps, t, nt, too_many);
        if (r < 0)
            return -1;
    }
    h->data_off = pos;
    h->data_line = ps.line + 1;
    return ply_header_check(c, &ps);
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
            return mesh_fail_at(c, 0, el->line,
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
        return mesh_fail_at(c, 0, vert->line,
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

/* Where the binary body is being read. */
typedef struct bin_reader {
    const unsigned char *data;
    size_t size, off;
    int big;   /* big endian */
    size_t nv; /* vertex count, for index checks */
} bin_reader;

/* The n indices of face i (n >= 3, all in the file, room for n - 2
 * triangles reserved) as a fan. */
static int ply_binary_face(const mesh_ctx *c, bin_reader *rd, const ply_prop *p, uint64_t i,
                           int64_t n, mesh_builder *b)
{
    unsigned isz = type_size[p->type];
    uint32_t first = 0, prev = 0;
    for (int64_t j = 0; j < n; j++, rd->off += isz) {
        int64_t x;
        if (bits_to_int(load_bits(rd->data + rd->off, isz, rd->big), p->type, &x) != 0)
            return mesh_fail_at(c, 1, rd->off,
                                "face %" PRIu64 ", index %" PRId64 ": not an integer", i, j);
        if (x < 0 || (uint64_t)x >= rd->nv)
            return mesh_fail_at(c, 1, rd->off,
                                "face %" PRIu64 ", index %" PRId64 ": vertex %" PRId64
                                " is out of range (vertex count %zu)",
                                i, j, x, rd->nv);
        uint32_t u = (uint32_t)x;
        if (j == 0)
            first = u;
        else if (j >= 2)
            mesh_emit_tri(b, first, prev, u);
        prev = u;
    }
    return 0;
}

/* A list property of element i, which started at byte `start`: skipped, or
 * the face's indices. */
static int ply_binary_list(const mesh_ctx *c, bin_reader *rd, const ply_elem *el, const ply_prop *p,
                           uint64_t i, size_t start, mesh_builder *b)
{
    unsigned csz = type_size[p->count_type], isz = type_size[p->type];
    int64_t n;
    if (rd->size - rd->off < csz)
        return mesh_fail_at(c, 1, rd->off, "truncated in element %s %" PRIu64, el->name, i);
    if (bits_to_int(load_bits(rd->data + rd->off, csz, rd->big), p->count_type, &n) != 0 || n < 0)
        return mesh_fail_at(c, 1, rd->off, "element %s %" PRIu64 ": bad list count", el->name, i);
    rd->off += csz;
    if ((uint64_t)n > (rd->size - rd->off) / isz)
        return mesh_fail_at(c, 1, rd->off,
                            "truncated: element %s %" PRIu64 " has a list of %" PRId64
                            " items but only %zu bytes are left",
                            el->name, i, n, rd->size - rd->off);
    if (p->role != R_INDICES) {
        rd->off += (size_t)n * isz;
        return 0;
    }
    if (n < 3)
        return mesh_fail_at(c, 1, start,
                            "face %" PRIu64 " has %" PRId64 " vertices (need at least 3)", i, n);
    if (mesh_reserve_tris(b, (size_t)n - 2) != 0)
        return mesh_fail(c, "out of memory");
    return ply_binary_face(c, rd, p, i, n, b);
}

/* Element i of el: its values, then the vertex if it is one. */
static int ply_binary_element(const mesh_ctx *c, const ply_header *h, const ply_elem *el,
                              uint64_t i, bin_reader *rd, mesh_builder *b)
{
    const ply_prop *props = h->props + el->first;
    size_t start = rd->off;
    double v[MESH_VALUES] = {0};
    for (size_t k = 0; k < el->nprops; k++) {
        const ply_prop *p = &props[k];
        if (p->is_list) {
            if (ply_binary_list(c, rd, el, p, i, start, b) != 0)
                return -1;
            continue;
        }
        unsigned sz = type_size[p->type];
        if (rd->size - rd->off < sz)
            return mesh_fail_at(c, 1, rd->off, "truncated in element %s %" PRIu64, el->name, i);
        if (p->role < MESH_VALUES)
            v[p->role] = bits_to_double(load_bits(rd->data + rd->off, sz, rd->big), p->type);
        rd->off += sz;
    }
    if (el->kind == EK_VERTEX && mesh_store_vertex(c, b, (size_t)i, v, 1, start, (size_t)i) != 0)
        return -1;
    return 0;
}

static int ply_read_binary(const mesh_ctx *c, const ply_header *h, const unsigned char *data,
                           size_t size, mesh_builder *b)
{
    bin_reader rd = {data, size, h->data_off, h->format == PLY_BE, b->nv};
    for (size_t e = 0; e < h->nelems; e++) {
        const ply_elem *el = &h->elems[e];
        if (el->nprops == 0)
            continue;
        for (uint64_t i = 0; i < el->count; i++)
            if (ply_binary_element(c, h, el, i, &rd, b) != 0)
                return -1;
    }
    return 0;
}

/* ------------------------------------------------------------------------ */
/* PLY ascii body                                                           */

typedef struct cursor {
    const char *p, *end;
    size_t line;
    size_t nv; /* vertex count, for index checks */
} cursor;

/* Next value on the current line. 1 and the token, or 0 with a message. */
static int next_value(const mesh_ctx *c, cursor *cur, const ply_elem *el, uint64_t i, tok *t)
{
    while (cur->p < cur->end && num_is_blank((unsigned char)*cur->p))
        cur->p++;
    if (cur->p == cur->end) {
        mesh_fail_at(c, 0, cur->line, "truncated: file ends inside element %s %" PRIu64, el->name,
                     i);
        return 0;
    }
    if (*cur->p == '\n') {
        mesh_fail_at(c, 0, cur->line,
                     "element %s %" PRIu64 " has fewer values than the header "
                     "declares",
                     el->name, i);
        return 0;
    }
    t->s = cur->p;
    while (cur->p < cur->end && !num_is_blank((unsigned char)*cur->p) && *cur->p != '\n')
        cur->p++;
    t->n = (size_t)(cur->p - t->s);
    return 1;
}

static int text_to_int(tok t, int type, int64_t *out)
{
    if (type != PT_FLOAT32 && type != PT_FLOAT64)
        return num_parse_int(t.s, t.n, out);
    double d;
    if (num_parse_double(t.s, t.n, &d) != 0 ||
        !(d >= -9007199254740992.0 && d <= 9007199254740992.0) || d != floor(d))
        return -1;
    *out = (int64_t)d;
    return 0;
}

/* The n indices of face i (n >= 3, room for n - 2 triangles reserved) as
 * a fan. */
static int ply_ascii_face(const mesh_ctx *c, cursor *cur, const ply_elem *el, const ply_prop *p,
                          uint64_t i, int64_t n, mesh_builder *b)
{
    uint32_t first = 0, prev = 0;
    tok t;
    for (int64_t j = 0; j < n; j++) {
        int64_t x;
        if (!next_value(c, cur, el, i, &t))
            return -1;
        if (text_to_int(t, p->type, &x) != 0)
            return mesh_fail_at(c, 0, cur->line,
                                "face %" PRIu64 ", index %" PRId64 ": bad number \"%.*s\"", i, j,
                                mesh_quote_len(t.n), t.s);
        if (x < 0 || (uint64_t)x >= cur->nv)
            return mesh_fail_at(c, 0, cur->line,
                                "face %" PRIu64 ", index %" PRId64 ": vertex %" PRId64
                                " is out of range (vertex count %zu)",
                                i, j, x, cur->nv);
        uint32_t u = (uint32_t)x;
        if (j == 0)
            first = u;
        else if (j >= 2)
            mesh_emit_tri(b, first, prev, u);
        prev = u;
    }
    return 0;
}

/* A list property of element i whose count token is t: skipped, or the
 * face's indices. */
static int ply_ascii_list(const mesh_ctx *c, cursor *cur, const ply_elem *el, const ply_prop *p,
                          uint64_t i, tok t, mesh_builder *b)
{
    int64_t n;
    if (text_to_int(t, p->count_type, &n) != 0 || n < 0)
        return mesh_fail_at(c, 0, cur->line, "element %s %" PRIu64 ": bad list count \"%.*s\"",
                            el->name, i, mesh_quote_len(t.n), t.s);
    /* Each value takes at least two characters; this bounds the
     * reservation below by the bytes actually there. */
    if ((uint64_t)n > (uint64_t)(cur->end - cur->p) / 2 + 1)
        return mesh_fail_at(c, 0, cur->line,
                            "truncated: element %s %" PRIu64 " has a list of %" PRId64 " items",
                            el->name, i, n);
    if (p->role != R_INDICES) {
        for (int64_t j = 0; j < n; j++)
            if (!next_value(c, cur, el, i, &t))
                return -1;
        return 0;
    }
    if (n < 3)
        return mesh_fail_at(c, 0, cur->line,
                            "face %" PRIu64 " has %" PRId64 " vertices (need at least 3)", i, n);
    if (mesh_reserve_tris(b, (size_t)n - 2) != 0)
        return mesh_fail(c, "out of memory");
    return ply_ascii_face(c, cur, el, p, i, n, b);
}

/* Element i of el, on the line at the cursor: its values, nothing more,
 * then the vertex if it is one. */
static int ply_ascii_element(const mesh_ctx *c, const ply_header *h, const ply_elem *el, uint64_t i,
                             cursor *cur, mesh_builder *b)
{
    const ply_prop *props = h->props + el->first;
    double v[MESH_VALUES] = {0};
    tok t;
    for (size_t k = 0; k < el->nprops; k++) {
        const ply_prop *p = &props[k];
        if (!next_value(c, cur, el, i, &t))
            return -1;
        if (p->is_list) {
            if (ply_ascii_list(c, cur, el, p, i, t, b) != 0)
                return -1;
            continue;
        }
        if (p->role < MESH_VALUES && num_parse_double(t.s, t.n, &v[p->role]) != 0)
            return mesh_fail_at(c, 0, cur->line, "element %s %" PRIu64 ": bad number \"%.*s\"",
                                el->name, i, mesh_quote_len(t.n), t.s);
    }
    while (cur->p < cur->end && num_is_blank((unsigned char)*cur->p))
        cur->p++;
    if (cur->p < cur->end && *cur->p != '\n')
        return mesh_fail_at(c, 0, cur->line,
                            "element %s %" PRIu64 " has more values than "
                            "the header declares",
                            el->name, i);
    if (el->kind == EK_VERTEX &&
        mesh_store_vertex(c, b, (size_t)i, v, 0, cur->line, (size_t)i) != 0)
        return -1;
    return 0;
}

static int ply_read_ascii(const mesh_ctx *c, const ply_header *h, const unsigned char *data,
                          size_t size, mesh_builder *b)
{
    cursor cur = {(const char *)data + h->data_off, (const char *)data + size, h->data_line, b->nv};
    for (size_t e = 0; e < h->nelems; e++) {
        const ply_elem *el = &h->elems[e];
        if (el->nprops == 0)
            continue;
        for (uint64_t i = 0; i < el->count; i++) {
            while (cur.p < cur.end && (num_is_blank((unsigned char)*cur.p) || *cur.p == '\n'))
                if (*cur.p++ == '\n')
                    cur.line++;
            if (cur.p == cur.end)
                return mesh_fail_at(c, 0, cur.line,
                                    "truncated: the header declares %" PRIu64
                                    " %s elements, the file ends after %" PRIu64,
                                    el->count, el->name, i);
            if (ply_ascii_element(c, h, el, i, &cur, b) != 0)
                return -1;
        }
    }
    return 0;
}

/* ------------------------------------------------------------------------ */
/* PLY file                                                                 */

/* The count of the element of that kind, 0 when there is none. */
static size_t ply_count_of(const ply_header *h, int kind)
{
    size_t n = 0;
    for (size_t e = 0; e < h->nelems; e++)
        if (h->elems[e].kind == kind)
            n = (size_t)h->elems[e].count;
    return n;
}

int ply_load(const mesh_ctx *c, const unsigned char *data, size_t size, mesh_builder *b)
{
    ply_header h;
    int r = ply_parse_header(c, data, size, &h);
    if (r == 0)
        r = ply_check_counts(c, &h, size);
    if (r == 0) {
        size_t nv = ply_count_of(&h, EK_VERTEX);
        size_t nf = ply_count_of(&h, EK_FACE);
        /* Sizes are bounded by ply_check_counts; no overflow on any target
         * where size_t holds the file size. */
        b->pos = malloc(nv ? nv * 3 * sizeof(float) : 1);
        b->nrm = h.has_normals ? malloc(nv ? nv * 3 * sizeof(float) : 1) : NULL;
        b->nv = b->vcap = nv;
        if (!b->pos || (h.has_normals && !b->nrm))
            r = mesh_fail(c, "out of memory");
        else if (nf && mesh_reserve_tris(b, nf) != 0) /* one triangle per face at least */
            r = mesh_fail(c, "out of memory");
        else if (h.format == PLY_ASCII)
            r = ply_read_ascii(c, &h, data, size, b);
        else
            r = ply_read_binary(c, &h, data, size, b);
    }
    ply_header_free(&h);
    return r;
}
