/* test_mesh.c - Check suite for the mesh reader (common/mesh.c): the shared
 * scan data, the same mesh in every supported encoding, polygon fans,
 * skipped elements and properties, normals, and one test per error class
 * (each must fail with -1, leave *out NULL and name the file and the fault). */
#include <check.h>
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#include <zlib.h>

#include "mesh.h"
#include "testutil.h"

#define PATHLEN 1024
#define ERRLEN 1024

/* ---- helpers ------------------------------------------------------------ */

typedef struct bytes {
    unsigned char d[8192];
    size_t n;
} bytes;

static void put(bytes *b, const void *p, size_t n)
{
    ck_assert_uint_le(b->n + n, sizeof b->d);
    memcpy(b->d + b->n, p, n);
    b->n += n;
}

static void put_text(bytes *b, const char *s)
{
    put(b, s, strlen(s));
}

/* Stores the n low bytes of v in the given byte order. */
static void put_uint(bytes *b, uint64_t v, unsigned n, int big)
{
    unsigned char t[8];
    for (unsigned i = 0; i < n; i++)
        t[big ? n - 1 - i : i] = (unsigned char)(v >> (8 * i));
    put(b, t, n);
}

static void put_f32(bytes *b, float f, int big)
{
    uint32_t u;
    memcpy(&u, &f, 4);
    put_uint(b, u, 4, big);
}

static void put_f64(bytes *b, double d, int big)
{
    uint64_t u;
    memcpy(&u, &d, 8);
    put_uint(b, u, 8, big);
}

static const char *write_bytes(char *path, size_t len, const char *name, const bytes *b)
{
    tu_tmp_path(path, len, name);
    FILE *f = fopen(path, "wb");
    ck_assert_ptr_nonnull(f);
    ck_assert_uint_eq(fwrite(b->d, 1, b->n, f), b->n);
    fclose(f);
    return path;
}

static mesh_t *load_ok(const char *path)
{
    char err[ERRLEN];
    mesh_t *m = NULL;
    int r = mesh_load(path, &m, err, sizeof err);
    ck_assert_msg(r == 0, "mesh_load(%s) failed: %s", path, err);
    ck_assert_ptr_nonnull(m);
    return m;
}

static mesh_t *load_text_ok(const char *name, const char *text)
{
    char path[PATHLEN];
    ck_assert_ptr_nonnull(tu_write_tmp(path, sizeof path, name, text));
    return load_ok(path);
}

/* Loads a file that must fail: -1, *out NULL, and a message that names the
 * file and contains each of the (up to two) expected substrings. */
static void expect_fail_path(const char *path, const char *want1, const char *want2)
{
    char err[ERRLEN];
    mesh_t *sentinel = (mesh_t *)&err; /* any non-NULL value */
    mesh_t *m = sentinel;
    int r = mesh_load(path, &m, err, sizeof err);
    ck_assert_int_eq(r, -1);
    ck_assert_ptr_null(m);
    ck_assert_msg(strstr(err, path) != NULL, "message does not name %s: %s", path, err);
    ck_assert_msg(strstr(err, want1) != NULL, "message lacks \"%s\": %s", want1, err);
    if (want2)
        ck_assert_msg(strstr(err, want2) != NULL, "message lacks \"%s\": %s", want2, err);
}

static void expect_fail_text(const char *name, const char *text, const char *want1,
                             const char *want2)
{
    char path[PATHLEN];
    ck_assert_ptr_nonnull(tu_write_tmp(path, sizeof path, name, text));
    expect_fail_path(path, want1, want2);
}

static void expect_fail_bytes(const char *name, const bytes *b, const char *want1,
                              const char *want2)
{
    char path[PATHLEN];
    write_bytes(path, sizeof path, name, b);
    expect_fail_path(path, want1, want2);
}

static void check_tri(const mesh_t *m, size_t t, uint32_t a, uint32_t b, uint32_t c)
{
    ck_assert_uint_lt(t, m->triangle_count);
    const uint32_t *i = m->indices + 3 * t;
    ck_assert_msg(i[0] == a && i[1] == b && i[2] == c,
                  "triangle %zu is (%u %u %u), expected (%u %u %u)", t, (unsigned)i[0],
                  (unsigned)i[1], (unsigned)i[2], (unsigned)a, (unsigned)b, (unsigned)c);
}

static void check_pos(const mesh_t *m, size_t v, float x, float y, float z)
{
    ck_assert_uint_lt(v, m->vertex_count);
    const float *p = m->positions + 3 * v;
    ck_assert_msg(p[0] == x && p[1] == y && p[2] == z,
                  "vertex %zu is (%.9g %.9g %.9g), expected (%.9g %.9g %.9g)", v, p[0], p[1], p[2],
                  x, y, z);
}

static void check_all_in_range(const mesh_t *m)
{
    for (size_t i = 0; i < 3 * m->triangle_count; i++)
        ck_assert_uint_lt(m->indices[i], m->vertex_count);
}

static void check_unit_normals(const mesh_t *m)
{
    ck_assert_ptr_nonnull(m->normals);
    for (size_t v = 0; v < m->vertex_count; v++) {
        const float *n = m->normals + 3 * v;
        double len = sqrt((double)n[0] * n[0] + (double)n[1] * n[1] + (double)n[2] * n[2]);
        ck_assert_msg(fabs(len - 1.0) < 1e-5, "normal %zu has length %g", v, len);
    }
}

/* ---- shared scan data --------------------------------------------------- */

/* The larger scans live in ../shared/data, beside the repository, when it is
 * there; without it their tests say SKIPPED and pass. The Happy Buddha the
 * shipped scene uses is in the repository (scenes/data). */
static const char *shared_or_skip(char *path, size_t len, const char *rel)
{
    tu_shared_path(path, len, rel);
    if (access(path, R_OK) == 0)
        return path;
    printf("SKIPPED: %s: no ../shared beside the repository\n", rel);
    fflush(stdout);
    return NULL;
}

START_TEST(shipped_happy_buddha_binary)
{
    char path[PATHLEN];
    mesh_t *m = load_ok(tu_root_path(path, sizeof path, "scenes/data/happy_buddha_15k.ply"));
    ck_assert_uint_eq(m->vertex_count, 7517);
    ck_assert_uint_eq(m->triangle_count, 15546);
    ck_assert_ptr_null(m->normals);
    /* First vertex and face, read from the file with Python's struct. */
    check_pos(m, 0, -0.00477885315194726f, 0.06590870022773743f, -0.04747316613793373f);
    check_tri(m, 0, 0, 6, 1);
    check_all_in_range(m);
    mesh_destroy(&m);
    ck_assert_ptr_null(m);
}
END_TEST

START_TEST(shared_bunny_ascii_extra_props)
{
    char path[PATHLEN];
    if (!shared_or_skip(path, sizeof path, "data/bun_zipper_res2.ply"))
        return;
    mesh_t *m = load_ok(path);
    ck_assert_uint_eq(m->vertex_count, 8171);
    ck_assert_uint_eq(m->triangle_count, 16301);
    ck_assert_ptr_null(m->normals);
    /* "-0.036872 0.127727 0.00440925 0.850855 0.5": confidence/intensity skipped */
    check_pos(m, 0, -0.036872f, 0.127727f, 0.00440925f);
    check_pos(m, 1, -0.0453607f, 0.128854f, 0.00114541f);
    check_tri(m, 0, 1541, 2416, 1103);
    check_all_in_range(m);
    mesh_destroy(&m);
}
END_TEST

START_TEST(shared_cornell_obj_negative_indices)
{
    char path[PATHLEN];
    if (!shared_or_skip(path, sizeof path, "data/CornellBox-Original.obj"))
        return;
    mesh_t *m = load_ok(path);
    ck_assert_uint_eq(m->vertex_count, 72);   /* 72 "v" lines */
    ck_assert_uint_eq(m->triangle_count, 36); /* 18 quads */
    /* Every face is "f -4 -3 -2 -1" right after its four vertices, so quad k
     * uses vertices 4k..4k+3. */
    for (uint32_t k = 0; k < 18; k++) {
        check_tri(m, 2 * k, 4 * k, 4 * k + 1, 4 * k + 2);
        check_tri(m, 2 * k + 1, 4 * k, 4 * k + 2, 4 * k + 3);
    }
    check_pos(m, 0, -1.01f, 0.00f, 0.99f); /* floor, first v line */
    check_pos(m, 71, 0.23f, 1.98f, 0.16f); /* light, last v line (tab separated) */
    mesh_destroy(&m);
}
END_TEST

START_TEST(shared_dragon_normals)
{
    char path[PATHLEN];
    if (!shared_or_skip(path, sizeof path, "data/dragon_vrip_res3.ply"))
        return;
    mesh_t *m = load_ok(path);
    ck_assert_uint_eq(m->vertex_count, 22998);
    ck_assert_uint_eq(m->triangle_count, 47794);
    /* The file's normals are not unit length and 84 are (0 0 0). */
    check_unit_normals(m);
    /* First vertex normal in the file: 1.569258 -2.518971 -4.290431. */
    double l = sqrt(1.569258 * 1.569258 + 2.518971 * 2.518971 + 4.290431 * 4.290431);
    ck_assert_float_eq_tol(m->normals[0], 1.569258 / l, 1e-6);
    ck_assert_float_eq_tol(m->normals[1], -2.518971 / l, 1e-6);
    ck_assert_float_eq_tol(m->normals[2], -4.290431 / l, 1e-6);
    check_all_in_range(m);
    mesh_destroy(&m);
}
END_TEST

START_TEST(shared_lucy_binary)
{
    char path[PATHLEN];
    if (!shared_or_skip(path, sizeof path, "data/lucy_100k.ply"))
        return;
    mesh_t *m = load_ok(path);
    ck_assert_uint_eq(m->vertex_count, 49987); /* SOURCES.md */
    ck_assert_uint_eq(m->triangle_count, 99970);
    check_pos(m, 0, 728.8809814453125f, 5.004640102386475f, 31.22330093383789f);
    check_tri(m, 0, 49494, 29144, 49518);
    check_all_in_range(m);
    mesh_destroy(&m);
}
END_TEST

/* ---- one mesh, every encoding ------------------------------------------- */

/* Five vertices, a quad and a triangle: triangles (0 1 2) (0 2 3) (3 2 4). */
static const float ref_pos[5][3] = {
    {0.0f, 0.0f, 0.0f}, {1.0f, 0.0f, 0.0f},   {1.0f, 1.0f, 0.0f},
    {0.0f, 1.0f, 0.0f}, {0.5f, 1.5f, -0.25f},
};
static const uint32_t ref_tri[3][3] = {{0, 1, 2}, {0, 2, 3}, {3, 2, 4}};

static void check_ref(const mesh_t *m)
{
    ck_assert_uint_eq(m->vertex_count, 5);
    ck_assert_uint_eq(m->triangle_count, 3);
    for (size_t v = 0; v < 5; v++)
        check_pos(m, v, ref_pos[v][0], ref_pos[v][1], ref_pos[v][2]);
    for (size_t t = 0; t < 3; t++)
        check_tri(m, t, ref_tri[t][0], ref_tri[t][1], ref_tri[t][2]);
}

START_TEST(same_mesh_ascii_ply)
{
    mesh_t *m =
        load_text_ok("eq_ascii.ply", "ply\n"
                                     "format ascii 1.0\n"
                                     "comment the reference mesh\n"
                                     "obj_info whatever\n"
                                     "element vertex 5\n"
                                     "property float x\nproperty float y\nproperty float z\n"
                                     "element face 2\n"
                                     "property list uchar int vertex_indices\n"
                                     "end_header\n"
                                     "0 0 0\n1 0 0\n1 1 0\n0 1 0\n0.5 1.5 -0.25\n"
                                     "4 0 1 2 3\n3 3 2 4\n");
    check_ref(m);
    ck_assert_ptr_null(m->normals);
    mesh_destroy(&m);
}
END_TEST

START_TEST(same_mesh_binary_le)
{
    bytes b = {.n = 0};
    put_text(&b, "ply\nformat binary_little_endian 1.0\nelement vertex 5\n"
                 "property float32 x\nproperty float32 y\nproperty float32 z\n"
                 "element face 2\nproperty list uint8 int32 vertex_indices\nend_header\n");
    for (int v = 0; v < 5; v++)
        for (int k = 0; k < 3; k++)
            put_f32(&b, ref_pos[v][k], 0);
    put_uint(&b, 4, 1, 0);
    for (uint32_t i = 0; i < 4; i++)
        put_uint(&b, i, 4, 0);
    put_uint(&b, 3, 1, 0);
    put_uint(&b, 3, 4, 0);
    put_uint(&b, 2, 4, 0);
    put_uint(&b, 4, 4, 0);
    char path[PATHLEN];
    mesh_t *m = load_ok(write_bytes(path, sizeof path, "eq_le.ply", &b));
    check_ref(m);
    mesh_destroy(&m);
}
END_TEST

/* Big endian, and other types throughout: double positions, an extra uchar
 * vertex property, a ushort count with uint indices named vertex_index. */
START_TEST(same_mesh_binary_be)
{
    bytes b = {.n = 0};
    put_text(&b, "ply\nformat binary_big_endian 1.0\nelement vertex 5\n"
                 "property double x\nproperty uchar red\nproperty float64 y\n"
                 "property double z\n"
                 "element face 2\nproperty list ushort uint vertex_index\nend_header\n");
    for (int v = 0; v < 5; v++) {
        put_f64(&b, ref_pos[v][0], 1);
        put_uint(&b, 200, 1, 1);
        put_f64(&b, ref_pos[v][1], 1);
        put_f64(&b, ref_pos[v][2], 1);
    }
    put_uint(&b, 4, 2, 1);
    for (uint32_t i = 0; i < 4; i++)
        put_uint(&b, i, 4, 1);
    put_uint(&b, 3, 2, 1);
    put_uint(&b, 3, 4, 1);
    put_uint(&b, 2, 4, 1);
    put_uint(&b, 4, 4, 1);
    char path[PATHLEN];
    mesh_t *m = load_ok(write_bytes(path, sizeof path, "eq_be.ply", &b));
    check_ref(m);
    mesh_destroy(&m);
}
END_TEST

START_TEST(same_mesh_obj)
{
    /* CRLF, comments, every face-vertex form, a relative index, a w
     * coordinate and statements that must be ignored. */
    mesh_t *m = load_text_ok("eq.obj", "# reference mesh\r\n"
                                       "mtllib none.mtl\r\n"
                                       "o thing\r\ng group\r\ns off\r\nusemtl red\r\n"
                                       "v 0 0 0\r\nv 1 0 0 1.0\r\nv 1 1 0 0.2 0.3 0.4\r\n"
                                       "v\t0 1 0\r\n"
                                       "vt 0 0\r\nvn 0 0 1\r\n"
                                       "f 1/1 2//1 3/1/1 -1   # quad, last one relative\r\n"
                                       "l 1 2\r\np 3\r\n"
                                       "v 0.5 1.5 -0.25\r\n"
                                       "f 4 -3 5\r\n");
    check_ref(m);
    ck_assert_ptr_null(m->normals);
    mesh_destroy(&m);
}
END_TEST

/* MESH_ATTRIBUTES: vn read; a position used with two normals becomes two
 * vertices (a hard edge), one used with one normal stays one; a corner
 * without a normal gets its face's; bad normal indices are refused. */
START_TEST(obj_vertex_normals)
{
    static const char text[] = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\n"
                               "vn 0 0 2\nvn 0 -1 0\n"
                               "f 1//1 2//1 3//1\n"   /* +z */
                               "f 1//-2 3//-2 4//1\n" /* +z, relative */
                               "f 1//2 2//2 5\n";     /* -y; vertex 5 without */
    char path[PATHLEN], err[ERRLEN];
    tu_write_tmp(path, sizeof path, "vn.obj", text);
    mesh_t *m = NULL;
    ck_assert_msg(mesh_load_flags(path, MESH_ATTRIBUTES, 0, &m, err, sizeof err) == 0, "%s", err);
    /* (1,+z) (2,+z) (3,+z) (4,+z) (1,-y) (2,-y) (5,none) */
    ck_assert_uint_eq(m->vertex_count, 7);
    ck_assert_uint_eq(m->triangle_count, 3);
    ck_assert_ptr_nonnull(m->normals);
    for (int t = 0; t < 3; t++)
        for (int k = 0; k < 3; k++) {
            const float *n = m->normals + 3 * m->indices[3 * t + k];
            float want_y = t == 2 ? -1.0f : 0.0f, want_z = t == 2 ? 0.0f : 1.0f;
            ck_assert_msg(fabsf(n[0]) < 1e-6f && fabsf(n[1] - want_y) < 1e-6f &&
                              fabsf(n[2] - want_z) < 1e-6f,
                          "triangle %d corner %d: normal (%g %g %g)", t, k, n[0], n[1], n[2]);
        }
    /* the first triangle's corners keep their positions */
    check_pos(m, m->indices[1], 1.0f, 0.0f, 0.0f);
    mesh_destroy(&m);
    /* without the flag: as always, vn unread */
    m = load_ok(path);
    ck_assert_uint_eq(m->vertex_count, 5);
    ck_assert_ptr_null(m->normals);
    mesh_destroy(&m);
    tu_write_tmp(path, sizeof path, "vn-bad.obj",
                 "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\n"
                 "f 1//1 2//1 3//4\n");
    ck_assert_int_eq(mesh_load_flags(path, MESH_ATTRIBUTES, 0, &m, err, sizeof err), -1);
    ck_assert_msg(strstr(err, "line 5") && strstr(err, "normal index out of range"), "%s", err);
    /* vt: a position with two coordinates becomes two vertices */
    tu_write_tmp(path, sizeof path, "vt.obj",
                 "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\n"
                 "vt 0 0\nvt 1 0\nvt 0 1\nvt 0.5 0.5\n"
                 "f 1/1 2/2 3/3\nf 2/2 4/4 3/4\n");
    ck_assert_msg(mesh_load_flags(path, MESH_ATTRIBUTES, 0, &m, err, sizeof err) == 0, "%s", err);
    ck_assert_uint_eq(m->vertex_count, 5); /* (3, vt 3) and (3, vt 4) */
    ck_assert_ptr_nonnull(m->uvs);
    ck_assert(m->normals && m->normals[2] == 1.0f); /* none in the file: from the faces */
    const float *uv = m->uvs + 2 * m->indices[4];
    ck_assert(uv[0] == 0.5f && uv[1] == 0.5f);
    uv = m->uvs + 2 * m->indices[2];
    /* vt 0 1: v counted from the image's top, 1 - v (as Mitsuba's reader) */
    ck_assert(uv[0] == 0.0f && uv[1] == 0.0f);
    ck_assert(m->uvs[2 * m->indices[5]] == 0.5f);
    mesh_destroy(&m);
    tu_write_tmp(path, sizeof path, "vn-short.obj", "v 0 0 0\nvn 0 0\n");
    ck_assert_int_eq(mesh_load_flags(path, MESH_ATTRIBUTES, 0, &m, err, sizeof err), -1);
    ck_assert_msg(strstr(err, "line 2") && strstr(err, "normal needs 3"), "%s", err);
}
END_TEST

/* One shape of a Mitsuba .serialized file into out: the header, then the
 * zlib stream of flags, counts, positions (normals when given), indices. */
static void put_serialized_shape(bytes *out, unsigned version, uint32_t flags, const float *pos,
                                 const float *nrm, uint64_t nv, const uint32_t *idx, uint64_t nt)
{
    static bytes raw;
    raw.n = 0;
    put_uint(&raw, flags, 4, 0);
    if (version == 4)
        put(&raw, "shape", 6);
    put_uint(&raw, nv, 8, 0);
    put_uint(&raw, nt, 8, 0);
    for (uint64_t i = 0; i < 3 * nv; i++)
        put_f32(&raw, pos[i], 0);
    for (uint64_t i = 0; nrm && i < 3 * nv; i++)
        put_f32(&raw, nrm[i], 0);
    for (uint64_t i = 0; i < 3 * nt; i++)
        put_uint(&raw, idx[i], 4, 0);
    unsigned char z[4096];
    uLongf zn = sizeof z;
    ck_assert_int_eq(compress2(z, &zn, raw.d, raw.n, 6), Z_OK);
    put_uint(out, 0x041C, 2, 0);
    put_uint(out, version, 2, 0);
    put(out, z, zn);
}

/* Mitsuba's .serialized: the shape shape_index names (of two), its
 * normals; version 3 (uint32 offsets) and 4 (uint64, a name); what a
 * broken file is refused with. */
START_TEST(serialized_shapes)
{
    static const float tri_pos[] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    static const float quad_pos[] = {0, 0, 2, 1, 0, 2, 1, 1, 2, 0, 1, 2};
    static const float quad_nrm[] = {0, 0, 2, 0, 0, 2, 0, 0, 2, 0, 0, 2};
    static const uint32_t tri_idx[] = {0, 1, 2}, quad_idx[] = {0, 1, 2, 0, 2, 3};
    char path[PATHLEN], err[ERRLEN];
    for (unsigned version = 3; version <= 4; version++) {
        static bytes b;
        b.n = 0;
        size_t off0 = b.n;
        put_serialized_shape(&b, version, 0x1000, tri_pos, NULL, 3, tri_idx, 1);
        size_t off1 = b.n;
        put_serialized_shape(&b, version, 0x1001, quad_pos, quad_nrm, 4, quad_idx, 2);
        put_uint(&b, off0, version == 4 ? 8 : 4, 0);
        put_uint(&b, off1, version == 4 ? 8 : 4, 0);
        put_uint(&b, 2, 4, 0);
        write_bytes(path, sizeof path, "two.serialized", &b);
        mesh_t *m = NULL;
        ck_assert_msg(mesh_load_flags(path, 0, 1, &m, err, sizeof err) == 0, "%s", err);
        ck_assert_uint_eq(m->vertex_count, 4);
        ck_assert_uint_eq(m->triangle_count, 2);
        check_pos(m, 2, 1, 1, 2);
        check_tri(m, 1, 0, 2, 3);
        ck_assert_ptr_nonnull(m->normals);
        ck_assert(m->normals[2] == 1.0f); /* normalised */
        mesh_destroy(&m);
        ck_assert_msg(mesh_load_flags(path, 0, 0, &m, err, sizeof err) == 0, "%s", err);
        ck_assert_uint_eq(m->triangle_count, 1);
        ck_assert_ptr_null(m->normals);
        mesh_destroy(&m);
        ck_assert_int_eq(mesh_load_flags(path, 0, 2, &m, err, sizeof err), -1);
        ck_assert_msg(strstr(err, "shape_index 2: the file holds 2 shapes"), "%s", err);
        /* cut inside the second shape's stream: its offsets still say where */
        bytes cut = b;
        memmove(cut.d + off1 + 8, cut.d + off1 + 20, cut.n - off1 - 20);
        cut.n -= 12;
        write_bytes(path, sizeof path, "cut.serialized", &cut);
        ck_assert_int_eq(mesh_load_flags(path, 0, 1, &m, err, sizeof err), -1);
        ck_assert_msg(strstr(err, "zlib") || strstr(err, "outside the file"), "%s", err);
        /* an index past the vertices */
        b.n = 0;
        static const uint32_t bad_idx[] = {0, 1, 7};
        put_serialized_shape(&b, version, 0x1000, tri_pos, NULL, 3, bad_idx, 1);
        put_uint(&b, 0, version == 4 ? 8 : 4, 0);
        put_uint(&b, 1, 4, 0);
        write_bytes(path, sizeof path, "bad.serialized", &b);
        ck_assert_int_eq(mesh_load_flags(path, 0, 0, &m, err, sizeof err), -1);
        ck_assert_msg(strstr(err, "vertex 7 out of range"), "%s", err);
    }
    /* a count that claims more shapes than the file has room for */
    static bytes b;
    b.n = 0;
    put_uint(&b, 0x041C, 2, 0);
    put_uint(&b, 3, 2, 0);
    put_uint(&b, 1000000, 4, 0);
    write_bytes(path, sizeof path, "dict.serialized", &b);
    mesh_t *m = NULL;
    ck_assert_int_eq(mesh_load_flags(path, 0, 0, &m, err, sizeof err), -1);
    ck_assert_msg(strstr(err, "dictionary is corrupt"), "%s", err);
}
END_TEST

START_TEST(obj_forward_reference)
{
    /* Positive indices are checked against the final count. */
    mesh_t *m = load_text_ok("fwd.obj", "f 1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\n");
    ck_assert_uint_eq(m->triangle_count, 1);
    check_tri(m, 0, 0, 1, 2);
    mesh_destroy(&m);
}
END_TEST

START_TEST(ascii_numbers_exact)
{
    /* Text must give the correctly rounded float, as strtod does. */
    mesh_t *m = load_text_ok("exact.obj", "v 0.1 -2.5e-3 123456.789\n"
                                          "v 1e-40 3.4028234e38 0.30000000000000004441\n"
                                          "v +7 .5 1.\n"
                                          "v 3.40282347e+38 -3.40282347e+38 -0\n"
                                          "f 1 2 3\n");
    check_pos(m, 0, (float)strtod("0.1", NULL), (float)strtod("-2.5e-3", NULL),
              (float)strtod("123456.789", NULL));
    check_pos(m, 1, (float)strtod("1e-40", NULL), (float)strtod("3.4028234e38", NULL),
              (float)strtod("0.30000000000000004441", NULL));
    check_pos(m, 2, 7.0f, 0.5f, 1.0f);
    /* FLT_MAX as printed with 9 digits is a little above it: still FLT_MAX. */
    check_pos(m, 3, FLT_MAX, -FLT_MAX, 0.0f);
    ck_assert(signbit(m->positions[11]));
    mesh_destroy(&m);
}
END_TEST

/* ---- fans, skipping, normals -------------------------------------------- */

START_TEST(fan_quad_and_pentagon)
{
    mesh_t *m = load_text_ok("fan.ply", "ply\nformat ascii 1.0\nelement vertex 6\n"
                                        "property float x\nproperty float y\nproperty float z\n"
                                        "element face 2\nproperty list uchar uint vertex_indices\n"
                                        "end_header\n"
                                        "0 0 0\n1 0 0\n1 1 0\n0 1 0\n-1 0.5 0\n2 2 2\n"
                                        "4 0 1 2 3\n"
                                        "5 5 0 1 2 3\n");
    ck_assert_uint_eq(m->triangle_count, 2 + 3);
    check_tri(m, 0, 0, 1, 2);
    check_tri(m, 1, 0, 2, 3);
    check_tri(m, 2, 5, 0, 1);
    check_tri(m, 3, 5, 1, 2);
    check_tri(m, 4, 5, 2, 3);
    mesh_destroy(&m);

    m = load_text_ok("fan.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv -1 0.5 0\n"
                                "f 5 4 3 2 1\n");
    ck_assert_uint_eq(m->triangle_count, 3);
    check_tri(m, 0, 4, 3, 2);
    check_tri(m, 1, 4, 2, 1);
    check_tri(m, 2, 4, 1, 0);
    mesh_destroy(&m);
}
END_TEST

static const char skip_header[] =
    "ply\nformat %s 1.0\n"
    "element material 1\nproperty uchar r\nproperty list uchar float weights\n"
    "element vertex 4\n"
    "property float x\nproperty list uint8 int16 neighbours\nproperty float y\n"
    "property short quality\nproperty float z\nproperty uint flags\n"
    "element face 2\nproperty uchar kind\nproperty list int uint vertex_indices\n"
    "property list uchar float texcoord\nproperty double area\n"
    "element edge 2\nproperty int vertex1\nproperty int vertex2\n"
    "element empty 7\n"
    "end_header\n";

/* Unknown elements (before and after), lists inside vertex and face
 * elements, and scalar properties of every size must all be skipped. */
START_TEST(skip_unknown_ascii)
{
    char text[2048];
    int n = snprintf(text, sizeof text, skip_header, "ascii");
    ck_assert_int_gt(n, 0);
    snprintf(text + n, sizeof text - (size_t)n, "%s",
             "9 3 0.5 0.25 0.25\n"
             "0 2 1 2 1 -7 0 4294967295\n"
             "1 0 0 -1 0 0\n"
             "1 1 3 1 2 2 0\n"
             "0 1 5 0 9 1 0\n"
             "\n"
             "7 4 0 1 2 3 6 0 0 1 0 1 1 1.0\n"
             "7 3 2 1 0 0 0.5\n"
             "0 1\n1 2\n");
    mesh_t *m = load_text_ok("skip.ply", text);
    ck_assert_uint_eq(m->vertex_count, 4);
    check_pos(m, 0, 0, 1, 0);
    check_pos(m, 1, 1, 0, 0);
    check_pos(m, 2, 1, 1, 2);
    check_pos(m, 3, 0, 0, 1);
    ck_assert_uint_eq(m->triangle_count, 3);
    check_tri(m, 0, 0, 1, 2);
    check_tri(m, 1, 0, 2, 3);
    check_tri(m, 2, 2, 1, 0);
    mesh_destroy(&m);
}
END_TEST

static void skip_binary(int big, const char *name)
{
    bytes b = {.n = 0};
    char head[2048];
    snprintf(head, sizeof head, skip_header, big ? "binary_big_endian" : "binary_little_endian");
    put_text(&b, head);
    /* material */
    put_uint(&b, 9, 1, big);
    put_uint(&b, 3, 1, big);
    for (int i = 0; i < 3; i++)
        put_f32(&b, 0.25f, big);
    /* vertices: x, list<int16>, y, short, z, uint */
    const float xyz[4][3] = {{0, 1, 0}, {1, 0, 0}, {1, 1, 2}, {0, 0, 1}};
    for (int v = 0; v < 4; v++) {
        put_f32(&b, xyz[v][0], big);
        put_uint(&b, (unsigned)v, 1, big);
        for (int i = 0; i < v; i++)
            put_uint(&b, 0xBEEF, 2, big);
        put_f32(&b, xyz[v][1], big);
        put_uint(&b, 0xFFFF, 2, big);
        put_f32(&b, xyz[v][2], big);
        put_uint(&b, 0xFFFFFFFFu, 4, big);
    }
    /* faces: kind, list<uint> (int count), list<float>, double */
    put_uint(&b, 7, 1, big);
    put_uint(&b, 4, 4, big);
    for (uint32_t i = 0; i < 4; i++)
        put_uint(&b, i, 4, big);
    put_uint(&b, 2, 1, big);
    put_f32(&b, 0.5f, big);
    put_f32(&b, 0.5f, big);
    put_f64(&b, 1.0, big);
    put_uint(&b, 7, 1, big);
    put_uint(&b, 3, 4, big);
    put_uint(&b, 2, 4, big);
    put_uint(&b, 1, 4, big);
    put_uint(&b, 0, 4, big);
    put_uint(&b, 0, 1, big);
    put_f64(&b, 0.5, big);
    /* edges */
    for (int i = 0; i < 4; i++)
        put_uint(&b, (unsigned)i, 4, big);

    char path[PATHLEN];
    mesh_t *m = load_ok(write_bytes(path, sizeof path, name, &b));
    ck_assert_uint_eq(m->vertex_count, 4);
    for (size_t v = 0; v < 4; v++)
        check_pos(m, v, xyz[v][0], xyz[v][1], xyz[v][2]);
    ck_assert_uint_eq(m->triangle_count, 3);
    check_tri(m, 0, 0, 1, 2);
    check_tri(m, 1, 0, 2, 3);
    check_tri(m, 2, 2, 1, 0);
    mesh_destroy(&m);
}

START_TEST(skip_unknown_binary_le)
{
    skip_binary(0, "skip_le.ply");
}
END_TEST

START_TEST(skip_unknown_binary_be)
{
    skip_binary(1, "skip_be.ply");
}
END_TEST

START_TEST(normals_normalised_and_zero_repaired)
{
    /* Vertex 3 has a zero normal: it gets the normal of the triangles that
     * use it, (0 0 1) here; vertex 4 is used by nothing: (0 0 1) too. */
    mesh_t *m =
        load_text_ok("normals.ply", "ply\nformat ascii 1.0\nelement vertex 5\n"
                                    "property float x\nproperty float y\nproperty float z\n"
                                    "property float nx\nproperty float ny\nproperty float nz\n"
                                    "element face 2\nproperty list uchar int vertex_indices\n"
                                    "end_header\n"
                                    "0 0 0  3 0 4\n"
                                    "1 0 0  0 -2 0\n"
                                    "1 1 0  1e-30 0 0\n"
                                    "0 1 0  0 0 0\n"
                                    "9 9 9  0 -0 0\n"
                                    "3 0 1 2\n3 0 2 3\n");
    check_unit_normals(m);
    const float *n = m->normals;
    ck_assert_float_eq(n[0], 0.6f);
    ck_assert_float_eq(n[2], 0.8f);
    ck_assert_float_eq(n[4], -1.0f);
    ck_assert_float_eq(n[6], 1.0f);
    ck_assert_float_eq(n[9], 0.0f);
    ck_assert_float_eq(n[10], 0.0f);
    ck_assert_float_eq(n[11], 1.0f);
    ck_assert_float_eq(n[14], 1.0f);
    mesh_destroy(&m);
}
END_TEST

START_TEST(partial_normals_ignored)
{
    mesh_t *m =
        load_text_ok("partial.ply", "ply\nformat ascii 1.0\nelement vertex 3\n"
                                    "property float x\nproperty float y\nproperty float z\n"
                                    "property float nx\n"
                                    "element face 1\nproperty list uchar int vertex_indices\n"
                                    "end_header\n"
                                    "0 0 0 1\n1 0 0 1\n0 1 0 1\n3 0 1 2\n");
    ck_assert_ptr_null(m->normals);
    ck_assert_uint_eq(m->triangle_count, 1);
    mesh_destroy(&m);
}
END_TEST

START_TEST(load_buffer_and_destroy)
{
    static const char obj[] = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
    char err[ERRLEN];
    mesh_t *m = NULL;
    ck_assert_int_eq(
        mesh_load_buffer("mem.OBJ", (const unsigned char *)obj, strlen(obj), &m, err, sizeof err),
        0);
    ck_assert_uint_eq(m->triangle_count, 1);
    mesh_destroy(&m);
    ck_assert_ptr_null(m);
    mesh_destroy(&m); /* *m == NULL */
    mesh_destroy(NULL);
    /* The same bytes under a name that is not .obj: no format to pick. */
    m = (mesh_t *)&err;
    ck_assert_int_eq(
        mesh_load_buffer("mem.txt", (const unsigned char *)obj, strlen(obj), &m, err, sizeof err),
        -1);
    ck_assert_ptr_null(m);
    ck_assert_ptr_nonnull(strstr(err, "mem.txt"));
    ck_assert_ptr_nonnull(strstr(err, "unsupported format"));
    /* A tiny error buffer is cut, not overrun. */
    char small[8];
    memset(small, 'x', sizeof small);
    ck_assert_int_eq(
        mesh_load_buffer("a_long_name.ply", (const unsigned char *)"ply\n", 4, &m, small, 5), -1);
    ck_assert_int_eq(small[4], '\0');
    ck_assert_int_eq(small[5], 'x');
}
END_TEST

/* ---- errors: one test per class ----------------------------------------- */

#define PLY_XYZ_HEAD(fmt, nv, nf)                                                                  \
    "ply\nformat " fmt " 1.0\nelement vertex " #nv "\n"                                            \
    "property float x\nproperty float y\nproperty float z\n"                                       \
    "element face " #nf "\nproperty list uchar int vertex_indices\nend_header\n"
/* PLY_XYZ_HEAD is 9 lines, so the data starts on line 10. The values are
 * padded so that the up-front count check passes and the fault is found
 * where it is. */
#define V3 "0.0 0.0 0.0\n1.0 0.0 0.0\n0.0 1.0 0.0\n"

START_TEST(err_malformed_header)
{
    expect_fail_text("bad_head.ply", "ply\nformat ascii 1.0\nelement vertex many\n", "line 3",
                     "malformed header");
    expect_fail_text("bad_head2.ply",
                     "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"
                     "property quaternion y\nend_header\n",
                     "line 5", "unknown property type");
    expect_fail_text("bad_head3.ply", "ply\nformat ascii 1.0\nelement vertex 1\n",
                     "malformed header", "end_header");
    expect_fail_text("bad_head4.ply",
                     "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"
                     "property float y\nend_header\n0 0\n",
                     "lacks x, y or z", NULL);
    expect_fail_text("bad_head5.ply",
                     "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"
                     "bogus line\nend_header\n",
                     "line 5", "unknown keyword");
}
END_TEST

START_TEST(err_unsupported_format)
{
    expect_fail_text("middle.ply",
                     "ply\nformat binary_middle_endian 1.0\nelement vertex 0\nend_header\n",
                     "line 2", "unsupported format");
    expect_fail_text("v2.ply", "ply\nformat ascii 2.0\nend_header\n", "unsupported format",
                     "version");
    expect_fail_text("mesh.stl", "solid cube\nendsolid\n", "unsupported format", NULL);
    expect_fail_text("empty.stl", "", "empty", NULL);
}
END_TEST

/* Huge counts in the header of a small file are refused from the header,
 * against the file's size, before a vertex is read or memory is taken for
 * them (the message says so: a loader that tried would fail otherwise). */
START_TEST(err_huge_count_small_file)
{
    expect_fail_text("huge.ply",
                     "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\n"
                     "property float x\nproperty float y\nproperty float z\n"
                     "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                     "0123456789abcdef",
                     "vertex count 4000000000 is more than the file can hold", "line 3");
    expect_fail_text("huge_face.ply",
                     PLY_XYZ_HEAD("ascii", 3, 9000000000000000000) "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
                     "face count 9000000000000000000 is more than the file can hold", "line 7");
    /* Counts past 64 bits do not parse. */
    expect_fail_text("huge_parse.ply",
                     "ply\nformat ascii 1.0\nelement vertex 99999999999999999999999\n",
                     "bad element count", "line 3");
}
END_TEST

START_TEST(err_truncated_binary)
{
    bytes b = {.n = 0};
    put_text(&b, PLY_XYZ_HEAD("binary_little_endian", 3, 2));
    for (int i = 0; i < 9; i++)
        put_f32(&b, (float)i, 0);
    put_uint(&b, 5, 1, 0);
    for (uint32_t i = 0; i < 5; i++)
        put_uint(&b, i % 3, 4, 0);
    /* Second face: a count of 4 and only two indices. */
    put_uint(&b, 4, 1, 0);
    put_uint(&b, 0, 4, 0);
    put_uint(&b, 1, 4, 0);
    expect_fail_bytes("trunc.ply", &b, "truncated", "byte ");
    /* Cut inside the vertices: the count check already sees it. */
    b.n = strlen(PLY_XYZ_HEAD("binary_little_endian", 3, 2)) + 20;
    expect_fail_bytes("trunc2.ply", &b, "truncated", "vertex count");
}
END_TEST

START_TEST(err_truncated_ascii)
{
    expect_fail_text("trunc_a.ply", PLY_XYZ_HEAD("ascii", 3, 1) "0.0 0.0 0.0\n1.0 0.0 0.0\n0.0 1",
                     "truncated", "line 12");
    expect_fail_text("trunc_b.ply", PLY_XYZ_HEAD("ascii", 3, 1) V3 "4 0 1 2", "truncated",
                     "line 13");
    /* Too short for the counts at all: found before anything is read. */
    expect_fail_text("trunc_c.ply", PLY_XYZ_HEAD("ascii", 3, 1) "0 0 0\n1 0 0\n0 1", "truncated",
                     "line 3: element vertex count 3");
}
END_TEST

START_TEST(err_too_few_values_on_line)
{
    expect_fail_text("few.ply",
                     PLY_XYZ_HEAD("ascii", 3, 1) "0.0 0.0 0.0\n1.0 0.0\n0.0 1.0 0.0\n3 0 1 2\n",
                     "line 11", "fewer values");
    expect_fail_text("many.ply", PLY_XYZ_HEAD("ascii", 3, 1) "0 0 0\n1 0 0 7\n0 1 0\n3 0 1 2\n",
                     "line 11", "more values");
}
END_TEST

START_TEST(err_index_out_of_range)
{
    expect_fail_text("range.ply", PLY_XYZ_HEAD("ascii", 3, 2) V3 "3 0 1 2\n3 0 1 3\n",
                     "line 14: face 1, index 2", "vertex 3 is out of range");
    expect_fail_text("neg.ply", PLY_XYZ_HEAD("ascii", 3, 1) V3 "3 0 -1 2\n", "line 13",
                     "out of range");
    bytes b = {.n = 0};
    put_text(&b, PLY_XYZ_HEAD("binary_big_endian", 3, 1));
    for (int i = 0; i < 9; i++)
        put_f32(&b, 0.0f, 1);
    put_uint(&b, 3, 1, 1);
    put_uint(&b, 0, 4, 1);
    put_uint(&b, 1000, 4, 1);
    put_uint(&b, 2, 4, 1);
    expect_fail_bytes("range_be.ply", &b, "face 0, index 1", "vertex 1000 is out of range");
    expect_fail_text("range.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 4\n", "line 5",
                     "index 3: vertex 4 is out of range");
    expect_fail_text("range_rel.obj", "v 0 0 0\nv 1 0 0\nf -1 -2 -3\nv 0 1 0\n", "line 3",
                     "relative index -3");
    expect_fail_text("zero.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 0 3\n", "line 4",
                     "index 2: 0 is not a valid index");
}
END_TEST

START_TEST(err_nan_coordinate)
{
    expect_fail_text("nan.ply", PLY_XYZ_HEAD("ascii", 3, 1) "0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n",
                     "line 11", "vertex 1: y coordinate is NaN");
    expect_fail_text("inf.obj", "v 0 0 0\nv 1 0 0\nv 0 1e39 0\nf 1 2 3\n", "line 3", "not finite");
    bytes b = {.n = 0};
    put_text(&b, PLY_XYZ_HEAD("binary_little_endian", 3, 1));
    for (int i = 0; i < 9; i++)
        put_f32(&b, i == 8 ? NAN : 0.0f, 0);
    put_uint(&b, 3, 1, 0);
    for (uint32_t i = 0; i < 3; i++)
        put_uint(&b, i, 4, 0);
    expect_fail_bytes("nan_le.ply", &b, "vertex 2: z coordinate is NaN", "byte ");
    expect_fail_text("nan_normal.ply",
                     "ply\nformat ascii 1.0\nelement vertex 1\n"
                     "property float x\nproperty float y\nproperty float z\n"
                     "property float nx\nproperty float ny\nproperty float nz\n"
                     "end_header\n0 0 0 inf 0 0\n",
                     "line 11", "normal is not finite");
}
END_TEST

START_TEST(err_bad_number)
{
    expect_fail_text("num.ply", PLY_XYZ_HEAD("ascii", 3, 1) "0 0 0\n1.2.3 0 0\n0 1 0\n3 0 1 2\n",
                     "line 11", "bad number \"1.2.3\"");
    expect_fail_text("num_idx.ply", PLY_XYZ_HEAD("ascii", 3, 1) V3 "3 0 1x 2\n", "line 13",
                     "bad number");
    expect_fail_text("num.obj", "v 0 0 0\nv 1 zero 0\n", "line 2", "bad number \"zero\"");
    expect_fail_text("num_f.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3a\n", "line 4",
                     "bad vertex \"3a\"");
    expect_fail_text("short_v.obj", "v 0 0\n", "line 1", "3 coordinates");
}
END_TEST

START_TEST(err_face_too_small)
{
    expect_fail_text("two.ply", PLY_XYZ_HEAD("ascii", 3, 1) V3 "2 0 1\n", "line 13",
                     "face 0 has 2 vertices");
    expect_fail_text("two.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", "line 4", "has 2 vertices");
}
END_TEST

START_TEST(err_size_overflow)
{
    /* A skipped list claiming 2^32-1 int items: count * size must not wrap
     * or be trusted. */
    bytes b = {.n = 0};
    put_text(&b, "ply\nformat binary_little_endian 1.0\n"
                 "element junk 1\nproperty list uint int stuff\n"
                 "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                 "element face 1\nproperty list uchar int vertex_indices\nend_header\n");
    put_uint(&b, 0xFFFFFFFFu, 4, 0);
    for (int i = 0; i < 9; i++)
        put_f32(&b, 0.0f, 0);
    put_uint(&b, 3, 1, 0);
    for (uint32_t i = 0; i < 3; i++)
        put_uint(&b, i, 4, 0);
    expect_fail_bytes("overflow.ply", &b, "truncated", "4294967295 items");
    /* Element counts whose sum of sizes exceeds 64 bits. */
    expect_fail_text("overflow2.ply",
                     "ply\nformat binary_little_endian 1.0\n"
                     "element a 9223372036854775807\nproperty double v\n"
                     "element vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
                     "end_header\n",
                     "element a count 9223372036854775807", "line 3");
    /* A float list count that is not an integer. */
    b.n = 0;
    put_text(&b, "ply\nformat binary_little_endian 1.0\n"
                 "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                 "element face 1\nproperty list float int vertex_indices\nend_header\n");
    for (int i = 0; i < 9; i++)
        put_f32(&b, 0.0f, 0);
    put_f32(&b, 3.5f, 0);
    for (uint32_t i = 0; i < 3; i++)
        put_uint(&b, i, 4, 0);
    expect_fail_bytes("float_count.ply", &b, "bad list count", "byte ");
}
END_TEST

START_TEST(err_no_triangles)
{
    expect_fail_text("empty.ply", PLY_XYZ_HEAD("ascii", 3, 0) "0 0 0\n1 0 0\n0 1 0\n",
                     "no triangles", NULL);
    expect_fail_text("noface.ply",
                     "ply\nformat ascii 1.0\nelement vertex 1\n"
                     "property float x\nproperty float y\nproperty float z\n"
                     "end_header\n0 0 0\n",
                     "no triangles", NULL);
    expect_fail_text("points.obj", "# only points\nv 0 0 0\nv 1 0 0\np 1 2\n", "no triangles",
                     NULL);
    expect_fail_text("empty.obj", "", "no triangles", NULL);
}
END_TEST

START_TEST(err_missing_file)
{
    char path[PATHLEN];
    tu_tmp_path(path, sizeof path, "does-not-exist.ply");
    remove(path);
    expect_fail_path(path, "cannot open", NULL);
}
END_TEST

/* ------------------------------------------------------------------------ */

static Suite *mesh_suite(void)
{
    Suite *s = suite_create("mesh");
    TCase *tc = tcase_create("shared");
    tcase_set_timeout(tc, 60);
    tcase_add_test(tc, shipped_happy_buddha_binary);
    tcase_add_test(tc, shared_bunny_ascii_extra_props);
    tcase_add_test(tc, shared_cornell_obj_negative_indices);
    tcase_add_test(tc, shared_dragon_normals);
    tcase_add_test(tc, shared_lucy_binary);
    suite_add_tcase(s, tc);

    tc = tcase_create("formats");
    tcase_add_test(tc, same_mesh_ascii_ply);
    tcase_add_test(tc, same_mesh_binary_le);
    tcase_add_test(tc, same_mesh_binary_be);
    tcase_add_test(tc, same_mesh_obj);
    tcase_add_test(tc, obj_vertex_normals);
    tcase_add_test(tc, serialized_shapes);
    tcase_add_test(tc, obj_forward_reference);
    tcase_add_test(tc, ascii_numbers_exact);
    tcase_add_test(tc, fan_quad_and_pentagon);
    tcase_add_test(tc, skip_unknown_ascii);
    tcase_add_test(tc, skip_unknown_binary_le);
    tcase_add_test(tc, skip_unknown_binary_be);
    tcase_add_test(tc, normals_normalised_and_zero_repaired);
    tcase_add_test(tc, partial_normals_ignored);
    tcase_add_test(tc, load_buffer_and_destroy);
    suite_add_tcase(s, tc);

    tc = tcase_create("errors");
    tcase_add_test(tc, err_malformed_header);
    tcase_add_test(tc, err_unsupported_format);
    tcase_add_test(tc, err_huge_count_small_file);
    tcase_add_test(tc, err_truncated_binary);
    tcase_add_test(tc, err_truncated_ascii);
    tcase_add_test(tc, err_too_few_values_on_line);
    tcase_add_test(tc, err_index_out_of_range);
    tcase_add_test(tc, err_nan_coordinate);
    tcase_add_test(tc, err_bad_number);
    tcase_add_test(tc, err_face_too_small);
    tcase_add_test(tc, err_size_overflow);
    tcase_add_test(tc, err_no_triangles);
    tcase_add_test(tc, err_missing_file);
    suite_add_tcase(s, tc);
    return s;
}

int main(void)
{
    SRunner *sr = srunner_create(mesh_suite());
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed == 0 ? 0 : 1;
}
