/* test_scene.c - Check suite for the JSON scene loader (common/scene.c):
 * the two shipped scenes, one test per class of bad input (each must return
 * -1, leave *out NULL and name the scene, the JSON path and the fault), the
 * warnings, every shape type and the transform, and a small mutation fuzz
 * loop over the Cornell box text. */
#include <check.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "scene.h"
#include "testutil.h"
#include "tracer.h"

#define PATHLEN 1024
#define ERRLEN 1024
#define TEXTLEN 8192

/* ---- helpers ------------------------------------------------------------ */

#define CAM_OK                                                                                     \
    "\"camera\": {\"position\": [0, 0, -5], \"look_at\": [0, 0, 0], \"up\": [0, 1, 0], "           \
    "\"fov\": 40, \"width\": 32, \"height\": 24}"
#define MATS_OK                                                                                    \
    "\"materials\": {\"white\": {\"type\": \"diffuse\", \"albedo\": [0.5, 0.5, 0.5]}, "            \
    "\"light\": {\"type\": \"emitter\", \"radiance\": [4, 4, 4]}}"
#define QUAD_WHITE                                                                                 \
    "{\"type\": \"quad\", \"material\": \"white\", \"vertices\": [[0, 0, 0], [1, 0, 0], "          \
    "[1, 1, 0], [0, 1, 0]]}"
#define QUAD_LIGHT                                                                                 \
    "{\"type\": \"quad\", \"material\": \"light\", \"vertices\": [[0, 3, 0], [0, 3, 1], "          \
    "[1, 3, 1], [1, 3, 0]]}"
#define SHAPES_OK "\"shapes\": [" QUAD_WHITE ", " QUAD_LIGHT "]"

/* A scene from its four top-level members (NULL leaves one out). */
static const char *build(char *buf, size_t len, const char *cam, const char *render,
                         const char *mats, const char *shapes)
{
    const char *part[4] = {cam, render, mats, shapes};
    size_t n = 0;
    buf[n++] = '{';
    int first = 1;
    for (int i = 0; i < 4; i++) {
        if (!part[i])
            continue;
        int w = snprintf(buf + n, len - n, "%s\n%s", first ? "" : ",", part[i]);
        ck_assert_int_gt(w, 0);
        ck_assert_uint_lt((size_t)w, len - n);
        n += (size_t)w;
        first = 0;
    }
    ck_assert_uint_lt(n + 3, len);
    buf[n++] = '\n';
    buf[n++] = '}';
    buf[n] = '\0';
    return buf;
}

static scene_t *load_ok(const char *json, const char *name)
{
    char err[ERRLEN] = "";
    scene_t *s = NULL;
    int rc = scene_load_string(json, strlen(json), name, NULL, &s, err, sizeof err);
    ck_assert_msg(rc == 0, "%s failed to load: %s", name, err);
    ck_assert_ptr_nonnull(s);
    return s;
}

/* Loads json, expecting failure with a message that contains the name and
 * every one of up to three fragments (NULL ends the list). */
static void expect_fail_base(const char *json, size_t len, const char *name, const char *base,
                             const char *a, const char *b, const char *c)
{
    char err[ERRLEN] = "";
    scene_t *s = (scene_t *)(uintptr_t)1;
    int rc = scene_load_string(json, len, name, base, &s, err, sizeof err);
    if (getenv("VB_VERBOSE"))
        fprintf(stderr, "  %s\n", err);
    ck_assert_msg(rc == -1, "%s: expected failure, got %d", name, rc);
    ck_assert_ptr_null(s);
    ck_assert_msg(strstr(err, name) != NULL, "message does not name %s: %s", name, err);
    const char *want[3] = {a, b, c};
    for (int i = 0; i < 3 && want[i]; i++)
        ck_assert_msg(strstr(err, want[i]) != NULL, "message lacks \"%s\": %s", want[i], err);
}

static void expect_fail(const char *json, const char *name, const char *a, const char *b,
                        const char *c)
{
    expect_fail_base(json, strlen(json), name, NULL, a, b, c);
}

static void expect_file_fail(const char *path, const char *a, const char *b)
{
    char err[ERRLEN] = "";
    scene_t *s = (scene_t *)(uintptr_t)1;
    int rc = scene_load(path, &s, err, sizeof err);
    if (getenv("VB_VERBOSE"))
        fprintf(stderr, "  %s\n", err);
    ck_assert_msg(rc == -1, "%s: expected failure", path);
    ck_assert_ptr_null(s);
    ck_assert_msg(strstr(err, path) != NULL, "message does not name %s: %s", path, err);
    if (a)
        ck_assert_msg(strstr(err, a) != NULL, "message lacks \"%s\": %s", a, err);
    if (b)
        ck_assert_msg(strstr(err, b) != NULL, "message lacks \"%s\": %s", b, err);
}

static int has_warning(const scene_t *s, const char *frag)
{
    for (int i = 0; i < s->warning_count; i++)
        if (strstr(s->warnings[i], frag))
            return 1;
    return 0;
}

static char *read_text(const char *path, size_t *len)
{
    FILE *f = fopen(path, "rb");
    ck_assert_msg(f != NULL, "cannot open %s", path);
    char *buf = malloc(65536);
    ck_assert_ptr_nonnull(buf);
    size_t n = fread(buf, 1, 65535, f);
    fclose(f);
    buf[n] = '\0';
    *len = n;
    return buf;
}

/* The scratch folder, without a trailing slash. */
static const char *tmp_dir(char *buf, size_t len)
{
    tu_tmp_path(buf, len, "");
    size_t n = strlen(buf);
    if (n > 1 && buf[n - 1] == '/')
        buf[n - 1] = '\0';
    return buf;
}

static const float *vertex(const scene_t *s, size_t tri, int k)
{
    return s->positions + 3 * s->indices[3 * tri + k];
}

static void assert_vec(const float *p, double x, double y, double z, double tol)
{
    ck_assert_msg(fabs(p[0] - x) <= tol && fabs(p[1] - y) <= tol && fabs(p[2] - z) <= tol,
                  "got (%.7g, %.7g, %.7g), want (%g, %g, %g)", p[0], p[1], p[2], x, y, z);
}

/* ---- the shipped scenes ------------------------------------------------- */

START_TEST(cornell_box)
{
    char path[PATHLEN], err[ERRLEN] = "";
    scene_t *s = NULL;
    tu_root_path(path, sizeof path, "scenes/cornell-box.json");
    ck_assert_msg(scene_load(path, &s, err, sizeof err) == 0, "%s", err);
    ck_assert_uint_eq(s->triangle_count, 32);
    ck_assert_uint_eq(s->material_count, 4);
    ck_assert_uint_eq(s->light_count, 2);
    ck_assert_uint_eq(s->dropped_degenerate, 0);
    ck_assert_int_eq(s->camera.width, 256);
    ck_assert_int_eq(s->camera.height, 256);
    ck_assert_int_eq(s->warning_count, 0);
    ck_assert_uint_eq(s->spp, 256);
    ck_assert_uint_eq(s->seed, 1);
    ck_assert_int_eq(s->integrator, SCENE_INTEGRATOR_PATH);
    ck_assert_ptr_null(s->normals);
    ck_assert_double_eq(s->light_cdf[s->light_count - 1], 1.0);
    for (size_t i = 0; i < s->light_count; i++) {
        uint32_t t = s->light_tris[i];
        ck_assert_uint_lt(t, s->triangle_count);
        ck_assert_str_eq(s->materials[s->tri_material[t]].name, "light");
        ck_assert_msg(s->tri_normal[t].y < -0.99f, "light normal y = %g", s->tri_normal[t].y);
        for (int k = 0; k < 3; k++)
            ck_assert_float_eq_tol(vertex(s, t, k)[1], 548.7f, 1e-3f);
    }
    scene_destroy(&s);
    ck_assert_ptr_null(s);
}
END_TEST

START_TEST(cornell_light_pdf)
{
    char path[PATHLEN], err[ERRLEN] = "";
    scene_t *s = NULL;
    tu_root_path(path, sizeof path, "scenes/cornell-box.json");
    ck_assert_msg(scene_load(path, &s, err, sizeof err) == 0, "%s", err);
    double sum = 0;
    size_t lights = 0;
    for (size_t t = 0; t < s->triangle_count; t++) {
        const float *a = vertex(s, t, 0), *b = vertex(s, t, 1), *c = vertex(s, t, 2);
        double e1[3], e2[3];
        for (int d = 0; d < 3; d++) {
            e1[d] = (double)b[d] - a[d];
            e2[d] = (double)c[d] - a[d];
        }
        double cx = e1[1] * e2[2] - e1[2] * e2[1], cy = e1[2] * e2[0] - e1[0] * e2[2],
               cz = e1[0] * e2[1] - e1[1] * e2[0];
        double area = 0.5 * sqrt(cx * cx + cy * cy + cz * cz);
        if (s->tri_light_pdf[t] > 0)
            lights++;
        sum += s->tri_light_pdf[t] * area;
    }
    ck_assert_uint_eq(lights, 2);
    ck_assert_double_eq_tol(sum, 1.0, 1e-6);
    scene_destroy(&s);
}
END_TEST

START_TEST(happy_buddha)
{
    char path[PATHLEN], err[ERRLEN] = "";
    scene_t *s = NULL;
    tu_root_path(path, sizeof path, "scenes/happy-buddha.json");
    ck_assert_msg(scene_load(path, &s, err, sizeof err) == 0, "%s", err);
    ck_assert_uint_eq(s->triangle_count + s->dropped_degenerate, 15546 + 4);
    ck_assert_uint_eq(s->material_count, 3);
    ck_assert_uint_eq(s->light_count, 2);
    ck_assert_int_eq(s->camera.width, 256);
    /* the statue sits on the floor (y = 0) after scale 5 and translate */
    float ymin = INFINITY, ymax = -INFINITY;
    for (size_t t = 0; t < s->triangle_count; t++)
        if (strcmp(s->materials[s->tri_material[t]].name, "statue") == 0)
            for (int k = 0; k < 3; k++) {
                float y = vertex(s, t, k)[1];
                ymin = fminf(ymin, y);
                ymax = fmaxf(ymax, y);
            }
    ck_assert_msg(ymin > -0.05f && ymin < 0.05f && ymax > 0.5f && ymax < 2.5f,
                  "statue y range [%g, %g]", ymin, ymax);
    scene_destroy(&s);
}
END_TEST

/* ---- bad input ---------------------------------------------------------- */

START_TEST(bad_malformed_json)
{
    const char *json = "{\n  \"camera\": {\"fov\": 40},\n  \"render\": {\"spp\": ,},\n}\n";
    char err[ERRLEN] = "";
    scene_t *s = (scene_t *)(uintptr_t)1;
    ck_assert_int_eq(scene_load_string(json, strlen(json), "bad.json", NULL, &s, err, sizeof err),
                     -1);
    ck_assert_ptr_null(s);
    ck_assert_msg(strncmp(err, "bad.json:3:", 11) == 0, "want bad.json:3:COL, got: %s", err);
    int line = 0, col = 0;
    ck_assert_int_eq(sscanf(err, "bad.json:%d:%d:", &line, &col), 2);
    ck_assert_int_eq(line, 3);
    ck_assert_int_eq(col, 21); /* the ',' where a value should be */
    ck_assert_ptr_nonnull(strstr(err, "malformed"));
}
END_TEST

START_TEST(bad_top_level)
{
    expect_fail("[1, 2, 3]", "arr.json", "object", "top level", NULL);
    expect_fail("\"text\"", "str.json", "object", NULL, NULL);
}
END_TEST

START_TEST(bad_missing_camera)
{
    char buf[TEXTLEN];
    expect_fail(build(buf, sizeof buf, NULL, NULL, MATS_OK, SHAPES_OK), "nocam.json", "camera",
                "missing", NULL);
}
END_TEST

START_TEST(bad_camera_position_two)
{
    char buf[TEXTLEN];
    const char *cam = "\"camera\": {\"position\": [0, 0], \"look_at\": [0, 0, 1], \"fov\": 40, "
                      "\"width\": 8, \"height\": 8}";
    expect_fail(build(buf, sizeof buf, cam, NULL, MATS_OK, SHAPES_OK), "cam2.json",
                "camera.position", "3 numbers", NULL);
}
END_TEST

START_TEST(bad_fov_string)
{
    char buf[TEXTLEN];
    const char *cam = "\"camera\": {\"position\": [0, 0, -5], \"look_at\": [0, 0, 0], "
                      "\"fov\": \"40\", \"width\": 8, \"height\": 8}";
    expect_fail(build(buf, sizeof buf, cam, NULL, MATS_OK, SHAPES_OK), "fov.json", "camera.fov",
                "expected a number", NULL);
}
END_TEST

START_TEST(bad_camera_basis)
{
    char buf[TEXTLEN];
    const char *same = "\"camera\": {\"position\": [1, 2, 3], \"look_at\": [1, 2, 3], "
                       "\"fov\": 40, \"width\": 8, \"height\": 8}";
    expect_fail(build(buf, sizeof buf, same, NULL, MATS_OK, SHAPES_OK), "same.json", "camera",
                "look_at equals position", NULL);
    /* looking straight down with the default up (0, 1, 0) */
    const char *down = "\"camera\": {\"position\": [0, 5, 0], \"look_at\": [0, 0, 0], "
                       "\"fov\": 40, \"width\": 8, \"height\": 8}";
    expect_fail(build(buf, sizeof buf, down, NULL, MATS_OK, SHAPES_OK), "down.json", "camera",
                "parallel", NULL);
    const char *fov = "\"camera\": {\"position\": [0, 0, -5], \"look_at\": [0, 0, 0], "
                      "\"fov\": 180, \"width\": 8, \"height\": 8}";
    expect_fail(build(buf, sizeof buf, fov, NULL, MATS_OK, SHAPES_OK), "fov180.json", "camera",
                "fov", NULL);
}
END_TEST

START_TEST(bad_shape_material)
{
    char buf[TEXTLEN];
    const char *missing = "\"shapes\": [" QUAD_LIGHT ", {\"type\": \"quad\", \"vertices\": "
                          "[[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]}]";
    expect_fail(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, missing), "nomat.json",
                "shapes[1].material", "missing", NULL);
    const char *unknown = "\"shapes\": [" QUAD_LIGHT ", {\"type\": \"quad\", \"material\": "
                          "\"wite\", \"vertices\": [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]}]";
    expect_fail(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, unknown), "unkmat.json",
                "shapes[1].material", "unknown material", "wite");
}
END_TEST

START_TEST(bad_material_type)
{
    char buf[TEXTLEN];
    const char *mats = "\"materials\": {\"white\": {\"type\": \"diffuse\", \"albedo\": [0.5, 0.5, "
                       "0.5]}, \"light\": {\"type\": \"hair\", \"radiance\": [1, 1, 1]}}";
    expect_fail(build(buf, sizeof buf, CAM_OK, NULL, mats, SHAPES_OK), "mtype.json",
                "materials.light", "unknown material type", "hair");
}
END_TEST

/* scene_check: what the client and the master load to check a job (they
 * never trace it): the same scene and settings, the same faults named, but
 * no rough-plastic coat tables (a million samples each), and no tracer. */
START_TEST(checked_only)
{
    char buf[TEXTLEN], err[ERRLEN] = "";
    const char *mats =
        "\"materials\": {\"white\": {\"type\": \"plastic\", \"albedo\": [0.2, 0.3, 0.4], "
        "\"roughness\": 0.1}, \"light\": {\"type\": \"emitter\", \"radiance\": [4, 4, 4]}}";
    const char *json =
        build(buf, sizeof buf, CAM_OK, "\"render\": {\"spp\": 96, \"seed\": 5}", mats, SHAPES_OK);
    scene_t *full = load_ok(json, "coat.json"), *checked = NULL;
    ck_assert_msg(
        scene_check_string(json, strlen(json), "coat.json", NULL, &checked, err, sizeof err) == 0,
        "%s", err);
    ck_assert(!full->checked_only && checked->checked_only);
    ck_assert(checked->camera.width == 32 && checked->camera.height == 24);
    ck_assert(checked->spp == full->spp && checked->seed == full->seed && checked->spp == 96);
    ck_assert(checked->triangle_count == full->triangle_count &&
              checked->material_count == full->material_count);
    /* the coat: computed for tracing, left out when checking */
    ck_assert(full->materials[0].coat_t[MATERIAL_COAT_RES - 1] > 0.5f &&
              full->materials[0].internal > 0.0f);
    ck_assert(checked->materials[0].coat_t[MATERIAL_COAT_RES - 1] == 0.0f);
    tracer_device_t *dev = NULL;
    tracer_t *t = NULL;
    ck_assert_msg(tracer_device_new(&dev, err, sizeof err) == 0, "%s", err);
    ck_assert_int_eq(tracer_new(dev, checked, &t, err, sizeof err), -1);
    ck_assert_msg(strstr(err, "checked") != NULL, "%s", err);
    ck_assert_msg(tracer_new(dev, full, &t, err, sizeof err) == 0, "%s", err);
    tracer_destroy(&t);
    tracer_device_destroy(&dev);
    scene_destroy(&checked);
    scene_destroy(&full);
    /* a fault: the same message either way */
    const char *bad = build(buf, sizeof buf, CAM_OK, NULL,
                            "\"materials\": {\"white\": {\"type\": \"plastic\", \"ior\": 1}, "
                            "\"light\": {\"type\": \"emitter\", \"radiance\": [4, 4, 4]}}",
                            SHAPES_OK);
    char err2[ERRLEN] = "";
    ck_assert_int_eq(scene_load_string(bad, strlen(bad), "bad.json", NULL, &full, err, sizeof err),
                     -1);
    ck_assert_int_eq(
        scene_check_string(bad, strlen(bad), "bad.json", NULL, &checked, err2, sizeof err2), -1);
    ck_assert_str_eq(err, err2);
    ck_assert(full == NULL && checked == NULL);
}
END_TEST

/* The glossy materials: their fields read, their faults named. */
START_TEST(glossy_materials)
{
    char buf[TEXTLEN];
    const char *mats =
        "\"materials\": {\"white\": {\"type\": \"conductor\", \"preset\": \"Au\", \"roughness\": "
        "0.2, \"distribution\": \"ggx\", \"twosided\": false}, \"light\": {\"type\": \"emitter\", "
        "\"radiance\": [4, 4, 4]}, \"p\": {\"type\": \"plastic\", \"albedo\": [0.2, 0.3, 0.4], "
        "\"ior\": 1.6, \"nonlinear\": true}, \"t\": {\"type\": \"thindielectric\"}, \"e\": "
        "{\"type\": \"conductor\", \"eta\": [0.2, 0.9, 1.1], \"k\": [3.9, 2.4, 2.1]}}";
    scene_t *s = load_ok(build(buf, sizeof buf, CAM_OK, NULL, mats, SHAPES_OK), "glossy.json");
    const material_t *au = &s->materials[0], *p = &s->materials[2], *t = &s->materials[3],
                     *e = &s->materials[4];
    ck_assert_int_eq(au->type, MATERIAL_CONDUCTOR);
    ck_assert(au->alpha == 0.2f && au->distribution == MICROFACET_GGX && au->one_sided);
    ck_assert(fabsf(au->eta.x - 0.143036f) < 1e-6f && au->albedo.y == 1.0f);
    ck_assert_int_eq(p->type, MATERIAL_PLASTIC);
    ck_assert(p->alpha == 0.0f && p->ior == 1.6f && p->nonlinear && p->specular.z == 1.0f);
    ck_assert(p->internal > 0.5f && p->internal < 0.7f); /* the smooth coat's fit */
    ck_assert(t->type == MATERIAL_THIN_DIELECTRIC && fabsf(t->ior - 1.5042f) < 1e-3f);
    ck_assert(e->eta.y == 0.9f && e->k.z == 2.1f);
    scene_destroy(&s);
    static const struct {
        const char *mat, *says;
    } bad[] = {
        {"{\"type\": \"conductor\", \"preset\": \"Mithril\"}", "unknown conductor \"Mithril\""},
        {"{\"type\": \"conductor\", \"preset\": \"Au\", \"eta\": [1, 1, 1]}",
         "either a preset or eta and k"},
        {"{\"type\": \"conductor\", \"k\": [1, 1, 1]}", "k needs eta"},
        {"{\"type\": \"conductor\", \"eta\": [0, 1, 1], \"k\": [0, 1, 1]}",
         "eta and k cannot both be 0"},
        {"{\"type\": \"conductor\", \"roughness\": 5}", "out of range"},
        {"{\"type\": \"plastic\", \"roughness\": 0.1, \"distribution\": \"phong\"}",
         "\"beckmann\" or \"ggx\""},
        {"{\"type\": \"plastic\", \"ior\": 1}", "a coat of index 1"},
        {"{\"type\": \"plastic\", \"specular\": [2, 1, 1]}", "specular components"},
        {"{\"type\": \"plastic\", \"albedo\": [1.5, 1, 1]}", "albedo components"},
        {"{\"type\": \"plastic\", \"nonlinear\": 1}", "true or false"},
        {"{\"type\": \"conductor\", \"reflectance\": [1, 2, 1]}", "reflectance components"},
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        char m[512];
        snprintf(m, sizeof m,
                 "\"materials\": {\"white\": %s, \"light\": {\"type\": \"emitter\", \"radiance\": "
                 "[4, 4, 4]}}",
                 bad[i].mat);
        expect_fail(build(buf, sizeof buf, CAM_OK, NULL, m, SHAPES_OK), "glossy-bad.json",
                    "materials.white", bad[i].says, NULL);
    }
}
END_TEST

START_TEST(bad_shape_type)
{
    char buf[TEXTLEN];
    const char *shapes =
        "\"shapes\": [" QUAD_LIGHT ", {\"type\": \"cube\", \"material\": \"white\"}]";
    expect_fail(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, shapes), "stype.json", "shapes[1]",
                "unknown shape type", "cube");
}
END_TEST

START_TEST(bad_mesh_missing)
{
    char buf[TEXTLEN], dir[PATHLEN];
    const char *shapes = "\"shapes\": [" QUAD_LIGHT ", {\"type\": \"mesh\", \"material\": "
                         "\"white\", \"file\": \"no-such-mesh.ply\"}]";
    build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, shapes);
    tmp_dir(dir, sizeof dir);
    /* the mesh path is resolved against base_dir and named in the message */
    char full[PATHLEN + 32];
    int w = snprintf(full, sizeof full, "%s/no-such-mesh.ply", dir);
    ck_assert_uint_lt((size_t)w, sizeof full);
    expect_fail_base(buf, strlen(buf), "mmiss.json", dir, "shapes[1].file", full, "cannot open");
}
END_TEST

START_TEST(bad_mesh_malformed)
{
    char buf[TEXTLEN], dir[PATHLEN], ply[PATHLEN];
    /* the header promises 3 vertices and a face; the body has two */
    tu_write_tmp(ply, sizeof ply, "scene-broken.ply",
                 "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                 "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
                 "end_header\n0 0 0\n1 0 0\n");
    const char *shapes = "\"shapes\": [" QUAD_LIGHT ", " QUAD_WHITE ", {\"type\": \"mesh\", "
                         "\"material\": \"white\", \"file\": \"scene-broken.ply\"}]";
    build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, shapes);
    tmp_dir(dir, sizeof dir);
    expect_fail_base(buf, strlen(buf), "mbad.json", dir, "shapes[2].file", "scene-broken.ply",
                     NULL);
}
END_TEST

START_TEST(bad_triangle_index)
{
    char buf[TEXTLEN];
    const char *shapes = "\"shapes\": [" QUAD_LIGHT ", {\"type\": \"triangles\", \"material\": "
                         "\"white\", \"vertices\": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "
                         "\"indices\": [[0, 1, 2], [0, 1, 3]]}]";
    expect_fail(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, shapes), "idx.json",
                "shapes[1].indices[1]", "out of range", NULL);
    const char *neg =
        "\"shapes\": [{\"type\": \"triangles\", \"material\": \"white\", "
        "\"vertices\": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], \"indices\": [[0, -1, 2]]}]";
    expect_fail(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, neg), "neg.json",
                "shapes[0].indices[0]", "out of range", NULL);
    const char *frac =
        "\"shapes\": [{\"type\": \"triangles\", \"material\": \"white\", "
        "\"vertices\": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], \"indices\": [[0, 1.5, 2]]}]";
    expect_fail(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, frac), "frac.json",
                "shapes[0].indices[0]", "integer", NULL);
}
END_TEST

START_TEST(bad_nonfinite)
{
    char buf[TEXTLEN];
    const char *shapes =
        "\"shapes\": [" QUAD_LIGHT ", {\"type\": \"quad\", \"material\": "
        "\"white\", \"vertices\": [[0, 0, 0], [1e999, 0, 0], [1, 1, 0], [0, 1, 0]]}]";
    expect_fail(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, shapes), "infq.json",
                "shapes[1].vertices[1]", "finite", NULL);
    const char *cam = "\"camera\": {\"position\": [0, -1e999, -5], \"look_at\": [0, 0, 0], "
                      "\"fov\": 40, \"width\": 8, \"height\": 8}";
    expect_fail(build(buf, sizeof buf, cam, NULL, MATS_OK, SHAPES_OK), "infc.json",
                "camera.position", "finite", NULL);
    const char *fov = "\"camera\": {\"position\": [0, 0, -5], \"look_at\": [0, 0, 0], "
                      "\"fov\": 1e999, \"width\": 8, \"height\": 8}";
    expect_fail(build(buf, sizeof buf, fov, NULL, MATS_OK, SHAPES_OK), "inff.json", "camera.fov",
                "finite", NULL);
    /* finite in the file, infinite once transformed */
    const char *big = "\"shapes\": [" QUAD_LIGHT ", {\"type\": \"quad\", \"material\": \"white\", "
                      "\"vertices\": [[0, 0, 0], [1e38, 0, 0], [1, 1, 0], [0, 1, 0]], "
                      "\"transform\": {\"scale\": 1e10}}]";
    expect_fail(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, big), "ovf.json", "shapes[1]",
                "not finite", NULL);
}
END_TEST

START_TEST(bad_empty_scene)
{
    char buf[TEXTLEN];
    expect_fail(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, "\"shapes\": []"), "empty.json",
                "shapes", "empty", NULL);
    expect_fail(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, NULL), "noshapes.json", "shapes",
                "missing", NULL);
}
END_TEST

START_TEST(bad_only_degenerate)
{
    char buf[TEXTLEN];
    const char *shapes = "\"shapes\": [{\"type\": \"triangles\", \"material\": \"light\", "
                         "\"vertices\": [[0, 0, 0], [1, 0, 0], [2, 0, 0]], "
                         "\"indices\": [[0, 1, 2], [0, 0, 1]]}]";
    expect_fail(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, shapes), "degen.json", "shapes",
                "degenerate", NULL);
}
END_TEST

static void resolution_fail(const char *w, const char *h, const char *path, const char *word)
{
    char cam[512], buf[TEXTLEN], name[64];
    snprintf(cam, sizeof cam,
             "\"camera\": {\"position\": [0, 0, -5], \"look_at\": [0, 0, 0], \"fov\": 40, "
             "\"width\": %s, \"height\": %s}",
             w, h);
    snprintf(name, sizeof name, "res-%sx%s.json", w, h);
    expect_fail(build(buf, sizeof buf, cam, NULL, MATS_OK, SHAPES_OK), name, path, word, NULL);
}

START_TEST(bad_resolution)
{
    resolution_fail("0", "8", "camera", "absurd resolution");
    resolution_fail("8", "-4", "camera", "absurd resolution");
    resolution_fail("100000", "8", "camera", "absurd resolution");
    resolution_fail("1.5", "8", "camera.width", "integer");
    resolution_fail("20000", "20000", "camera", "absurd resolution");
    /* each side within bounds but more than SCENE_MAX_PIXELS */
    resolution_fail("16384", "4097", "camera", "absurd resolution");
    /* the largest accepted: 16384 x 4096 = 2^26 pixels */
    char cam[512], buf[TEXTLEN];
    snprintf(cam, sizeof cam,
             "\"camera\": {\"position\": [0, 0, -5], \"look_at\": [0, 0, 0], \"fov\": 40, "
             "\"width\": %d, \"height\": %u}",
             SCENE_MAX_SIDE, SCENE_MAX_PIXELS / SCENE_MAX_SIDE);
    scene_t *s = load_ok(build(buf, sizeof buf, cam, NULL, MATS_OK, SHAPES_OK), "max.json");
    ck_assert_int_eq(s->camera.width, SCENE_MAX_SIDE);
    scene_destroy(&s);
}
END_TEST

START_TEST(bad_albedo_over_one)
{
    char buf[TEXTLEN];
    const char *mats = "\"materials\": {\"white\": {\"type\": \"diffuse\", \"albedo\": [0.5, 1.2, "
                       "0.5]}, \"light\": {\"type\": \"emitter\", \"radiance\": [1, 1, 1]}}";
    expect_fail(build(buf, sizeof buf, CAM_OK, NULL, mats, SHAPES_OK), "alb.json",
                "materials.white", "albedo", "[0, 1]");
    const char *mirror = "\"materials\": {\"white\": {\"type\": \"mirror\", \"reflectance\": [1.5, "
                         "1, 1]}, \"light\": {\"type\": \"emitter\", \"radiance\": [1, 1, 1]}}";
    expect_fail(build(buf, sizeof buf, CAM_OK, NULL, mirror, SHAPES_OK), "refl.json",
                "materials.white", "reflectance", NULL);
}
END_TEST

START_TEST(bad_negative_radiance)
{
    char buf[TEXTLEN];
    const char *mats = "\"materials\": {\"white\": {\"type\": \"diffuse\", \"albedo\": [0.5, 0.5, "
                       "0.5]}, \"light\": {\"type\": \"emitter\", \"radiance\": [1, -1, 1]}}";
    expect_fail(build(buf, sizeof buf, CAM_OK, NULL, mats, SHAPES_OK), "rad.json",
                "materials.light", "radiance", NULL);
}
END_TEST

START_TEST(bad_material_twice)
{
    char buf[TEXTLEN];
    const char *mats = "\"materials\": {\"white\": {\"type\": \"diffuse\", \"albedo\": [0.5, 0.5, "
                       "0.5]}, \"light\": {\"type\": \"emitter\", \"radiance\": [1, 1, 1]}, "
                       "\"white\": {\"type\": \"diffuse\", \"albedo\": [0.1, 0.1, 0.1]}}";
    expect_fail(build(buf, sizeof buf, CAM_OK, NULL, mats, SHAPES_OK), "twice.json",
                "materials.white", "twice", NULL);
}
END_TEST

START_TEST(bad_render_fields)
{
    char buf[TEXTLEN];
    expect_fail(build(buf, sizeof buf, CAM_OK, "\"render\": {\"integrator\": \"bdpt\"}", MATS_OK,
                      SHAPES_OK),
                "integ.json", "render.integrator", "expected", NULL);
    expect_fail(build(buf, sizeof buf, CAM_OK, "\"render\": {\"spp\": 0}", MATS_OK, SHAPES_OK),
                "spp.json", "render.spp", "out of range", NULL);
    expect_fail(build(buf, sizeof buf, CAM_OK, "\"render\": {\"seed\": -1}", MATS_OK, SHAPES_OK),
                "seed.json", "render.seed", "out of range", NULL);
    expect_fail(build(buf, sizeof buf, CAM_OK, "\"render\": {\"spp\": 2.5}", MATS_OK, SHAPES_OK),
                "sppf.json", "render.spp", "integer", NULL);
    expect_fail(build(buf, sizeof buf, CAM_OK, "\"render\": [1]", MATS_OK, SHAPES_OK), "rarr.json",
                "render", "object", NULL);
}
END_TEST

START_TEST(bad_scale_zero)
{
    char buf[TEXTLEN];
    const char *shapes =
        "\"shapes\": [" QUAD_LIGHT ", {\"type\": \"quad\", \"material\": \"white\", "
        "\"vertices\": [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], "
        "\"transform\": {\"scale\": [1, 0, 1]}}]";
    expect_fail(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, shapes), "scale.json",
                "shapes[1].transform", "scale", "non-zero");
    const char *s0 = "\"shapes\": [" QUAD_LIGHT ", {\"type\": \"quad\", \"material\": \"white\", "
                     "\"vertices\": [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], "
                     "\"transform\": {\"scale\": 0}}]";
    expect_fail(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, s0), "scale0.json",
                "shapes[1].transform", "non-zero", NULL);
}
END_TEST

START_TEST(bad_files)
{
    char path[PATHLEN];
    /* does not exist */
    tu_tmp_path(path, sizeof path, "no-such-scene.json");
    remove(path);
    expect_file_fail(path, "cannot open", NULL);
    /* a directory */
    char dir[PATHLEN];
    tmp_dir(dir, sizeof dir);
    expect_file_fail(dir, "not a regular file", NULL);
    /* empty */
    tu_write_tmp(path, sizeof path, "scene-empty.json", "");
    expect_file_fail(path, ":1:1", "malformed");
    /* random binary bytes */
    tu_tmp_path(path, sizeof path, "scene-random.json");
    FILE *f = fopen(path, "wb");
    ck_assert_ptr_nonnull(f);
    uint32_t x = 0x9e3779b9u;
    for (int i = 0; i < 4096; i++) {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        fputc((int)(x & 0xff) | (i == 0 ? 0x80 : 0), f);
    }
    fclose(f);
    expect_file_fail(path, "malformed", NULL);
}
END_TEST

/* ---- warnings ----------------------------------------------------------- */

/* A light so small (or lights so unequal) that single precision cannot hold
 * its sampling pdf is refused, not traced into NaN pixels. */
START_TEST(bad_light_scale)
{
    const char *tiny = "{\"camera\":{\"position\":[0,0,-5],\"look_at\":[0,0,0],\"width\":8,"
                       "\"height\":8,\"fov\":40},"
                       "\"materials\":{\"l\":{\"type\":\"emitter\",\"radiance\":[1,1,1]},\"w\":{"
                       "\"type\":\"diffuse\",\"albedo\":[0.5,0.5,0.5]}},"
                       "\"shapes\":[{\"type\":\"quad\",\"material\":\"w\",\"vertices\":[[-1,-1,0],["
                       "1,-1,0],[1,1,0],[-1,1,0]]},"
                       "{\"type\":\"quad\",\"material\":\"l\",\"transform\":{\"scale\":1e-20},"
                       "\"vertices\":[[-1,-1,-1],[-1,1,-1],[1,1,-1],[1,-1,-1]]}]}";
    expect_fail(tiny, "tiny-light", "shapes", "single-precision", NULL);
    const char *unequal = "{\"camera\":{\"position\":[0,0,-5],\"look_at\":[0,0,0],\"width\":8,"
                          "\"height\":8,\"fov\":40},"
                          "\"materials\":{\"l\":{\"type\":\"emitter\",\"radiance\":[1,1,1]}},"
                          "\"shapes\":[{\"type\":\"quad\",\"material\":\"l\",\"vertices\":[[-1,-1,"
                          "0],[-1,1,0],[1,1,0],[1,-1,0]]},"
                          "{\"type\":\"quad\",\"material\":\"l\",\"transform\":{\"scale\":1e25},"
                          "\"vertices\":[[-1,-1,-1],[-1,1,-1],[1,1,-1],[1,-1,-1]]}]}";
    expect_fail(unequal, "unequal-lights", "shapes", "single-precision", NULL);
}
END_TEST

START_TEST(warn_degenerate)
{
    char buf[TEXTLEN];
    const char *shapes = "\"shapes\": [" QUAD_LIGHT ", {\"type\": \"triangles\", \"material\": "
                         "\"white\", \"vertices\": [[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]], "
                         "\"indices\": [[0, 1, 2], [0, 1, 3], [2, 2, 1], [1, 3, 2]]}]";
    scene_t *s = load_ok(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, shapes), "dg.json");
    ck_assert_uint_eq(s->dropped_degenerate, 2);
    ck_assert_uint_eq(s->triangle_count, 4);
    ck_assert(has_warning(s, "degenerate"));
    ck_assert(has_warning(s, "dg.json"));
    /* the kept triangles are the right ones, in order: light, light, [0,1,2], [1,3,2] */
    assert_vec(vertex(s, 2, 0), 0, 0, 0, 0);
    assert_vec(vertex(s, 2, 1), 1, 0, 0, 0);
    assert_vec(vertex(s, 2, 2), 0, 1, 0, 0);
    assert_vec(vertex(s, 3, 0), 1, 0, 0, 0);
    assert_vec(vertex(s, 3, 1), 2, 0, 0, 0);
    ck_assert_uint_eq(s->tri_material[3], 0);
    ck_assert_uint_eq(s->light_count, 2);
    for (size_t t = 0; t < s->triangle_count; t++)
        ck_assert_msg((s->tri_light_pdf[t] > 0) == (t < 2), "pdf of %zu", t);
    scene_destroy(&s);
}
END_TEST

START_TEST(warn_no_light)
{
    char buf[TEXTLEN];
    const char *mats =
        "\"materials\": {\"white\": {\"type\": \"diffuse\", \"albedo\": [0.5, 0.5, 0.5]}}";
    scene_t *s = load_ok(build(buf, sizeof buf, CAM_OK, NULL, mats, "\"shapes\": [" QUAD_WHITE "]"),
                         "dark.json");
    ck_assert(has_warning(s, "no light"));
    ck_assert_uint_eq(s->light_count, 0);
    ck_assert_float_eq(s->tri_light_pdf[0], 0.0f);
    scene_destroy(&s);
    /* an emitter with zero radiance is no light either */
    const char *zero = "\"materials\": {\"white\": {\"type\": \"diffuse\", \"albedo\": [0.5, 0.5, "
                       "0.5]}, \"light\": {\"type\": \"emitter\", \"radiance\": [0, 0, 0]}}";
    s = load_ok(build(buf, sizeof buf, CAM_OK, NULL, zero, SHAPES_OK), "dark0.json");
    ck_assert(has_warning(s, "no light"));
    ck_assert_uint_eq(s->light_count, 0);
    scene_destroy(&s);
}
END_TEST

START_TEST(warn_unknown_field)
{
    char buf[TEXTLEN];
    const char *mats = "\"materials\": {\"white\": {\"type\": \"diffuse\", \"albedo\": [0.5, 0.5, "
                       "0.5], \"albdo\": [1, 0, 0]}, \"light\": {\"type\": \"emitter\", "
                       "\"radiance\": [1, 1, 1]}}";
    char json[TEXTLEN + 64];
    build(buf, sizeof buf, CAM_OK, NULL, mats, SHAPES_OK);
    /* "comment" and "name" are ignored quietly; "extra" is not */
    int w = snprintf(json, sizeof json, "{\"comment\": \"c\", \"name\": \"n\", \"extra\": 1,%s",
                     buf + 1);
    ck_assert_uint_lt((size_t)w, sizeof json);
    scene_t *s = load_ok(json, "typo.json");
    ck_assert_int_eq(s->warning_count, 2);
    ck_assert(has_warning(s, "materials.white.albdo"));
    ck_assert(has_warning(s, "extra"));
    ck_assert(!has_warning(s, "comment"));
    ck_assert_float_eq(s->materials[0].albedo.x, 0.5f);
    scene_destroy(&s);
}
END_TEST

/* ---- features ----------------------------------------------------------- */

START_TEST(feature_defaults_and_render)
{
    char buf[TEXTLEN];
    scene_t *s = load_ok(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, SHAPES_OK), "def.json");
    ck_assert_uint_eq(s->spp, 64);
    ck_assert_uint_eq(s->seed, 1);
    ck_assert_int_eq(s->integrator, SCENE_INTEGRATOR_PATH);
    ck_assert_uint_eq(s->max_depth, 0);
    ck_assert_int_eq(s->warning_count, 0);
    scene_destroy(&s);
    s = load_ok(build(buf, sizeof buf, CAM_OK,
                      "\"render\": {\"spp\": 7, \"seed\": 9007199254740992, \"integrator\": "
                      "\"naive\", \"max_depth\": 5}",
                      MATS_OK, SHAPES_OK),
                "render.json");
    ck_assert_uint_eq(s->spp, 7);
    ck_assert_uint_eq(s->seed, 9007199254740992ull);
    ck_assert_int_eq(s->integrator, SCENE_INTEGRATOR_NAIVE);
    ck_assert_uint_eq(s->max_depth, 5);
    ck_assert(s->direct_emitter_samples == 1 && s->direct_bsdf_samples == 1);
    scene_destroy(&s);
    s = load_ok(build(buf, sizeof buf, CAM_OK,
                      "\"render\": {\"integrator\": \"direct\", \"emitter_samples\": 3, "
                      "\"bsdf_samples\": 0}",
                      MATS_OK, SHAPES_OK),
                "direct.json");
    ck_assert_int_eq(s->integrator, SCENE_INTEGRATOR_DIRECT);
    ck_assert(s->direct_emitter_samples == 3 && s->direct_bsdf_samples == 0);
    scene_destroy(&s);
    expect_fail(build(buf, sizeof buf, CAM_OK,
                      "\"render\": {\"integrator\": \"direct\", \"emitter_samples\": 0, "
                      "\"bsdf_samples\": 0}",
                      MATS_OK, SHAPES_OK),
                "direct0.json", "render", "cannot both be 0", NULL);
    expect_fail(
        build(buf, sizeof buf, CAM_OK, "\"render\": {\"bsdf_samples\": 65}", MATS_OK, SHAPES_OK),
        "direct65.json", "render.bsdf_samples", "out of range", NULL);
}
END_TEST

/* Mitsuba's disk and cylinder, tessellated: the disk's area within 3e-5
 * of pi, its normal +z (or -z flipped), its texture coordinates (r, phi /
 * 2 pi); the cylinder's side 2 pi, normals outward, every vertex on the
 * unit circle. */
START_TEST(feature_disk_cylinder)
{
    char buf[TEXTLEN];
    for (int flip = 0; flip < 2; flip++)
        for (int cyl = 0; cyl < 2; cyl++) {
            char shapes[512];
            snprintf(shapes, sizeof shapes,
                     "\"shapes\": [{\"type\": \"%s\", \"material\": \"white\"%s}, " QUAD_LIGHT "]",
                     cyl ? "cylinder" : "disk", flip ? ", \"flip_normals\": true" : "");
            scene_t *s =
                load_ok(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, shapes), "round.json");
            ck_assert_int_eq(s->warning_count, 0); /* no degenerate triangle dropped */
            double area = 0;
            size_t n = 0;
            for (size_t t = 0; t < s->triangle_count; t++) {
                if (s->tri_material[t] != 0)
                    continue;
                const uint32_t *vi = s->indices + 3 * t;
                vec3_t a = scene_vertex(s, vi[0]), b = scene_vertex(s, vi[1]),
                       c = scene_vertex(s, vi[2]);
                area += 0.5 * vec3_length(vec3_cross(vec3_sub(b, a), vec3_sub(c, a)));
                vec3_t ng = s->tri_normal[t],
                       mid = vec3_scale(vec3_add(vec3_add(a, b), c), 1 / 3.0f);
                if (cyl) {
                    /* outward: along the centroid's radial direction */
                    float radial = ng.x * mid.x + ng.y * mid.y;
                    ck_assert_msg(flip ? radial < 0 : radial > 0, "triangle %zu faces %s", t,
                                  flip ? "out" : "in");
                    ck_assert(fabsf(vec3_length(vec3_make(a.x, a.y, 0)) - 1) < 1e-6f);
                    ck_assert(a.z >= 0 && a.z <= 1);
                } else {
                    ck_assert(ng.z == (flip ? -1.0f : 1.0f));
                }
                n++;
            }
            double want = cyl ? 2 * M_PI : M_PI;
            ck_assert_msg(fabs(area / want - 1) < 3e-5, "%s area %g", cyl ? "cylinder" : "disk",
                          area);
            ck_assert_uint_eq(n, cyl ? 2 * 512 : 512 * (2 * 16 - 1));
            scene_destroy(&s);
        }
    /* a textured disk keeps Mitsuba's coordinates: (r, phi / 2 pi) */
    const char *mats = "\"materials\": {\"white\": {\"type\": \"diffuse\", \"albedo\": {\"type\": "
                       "\"checkerboard\", \"color0\": [0.1, 0.1, 0.1], \"color1\": [0.9, 0.9, "
                       "0.9]}}, \"light\": {\"type\": \"emitter\", \"radiance\": [4, 4, 4]}}";
    scene_t *s = load_ok(build(buf, sizeof buf, CAM_OK, NULL, mats,
                               "\"shapes\": [{\"type\": \"disk\", \"material\": \"white\", "
                               "\"segments\": 8}, " QUAD_LIGHT "]"),
                         "disk-uv.json");
    ck_assert_ptr_nonnull(s->uvs);
    /* the disk's vertices come first: 9 columns (the seam twice) of 17 rings */
    ck_assert_uint_ge(s->vertex_count, 9 * 17);
    for (size_t v = 0; v < 9 * 17; v++) {
        vec3_t p = scene_vertex(s, (uint32_t)v);
        float r = sqrtf(p.x * p.x + p.y * p.y);
        if (r < 1e-3f)
            continue; /* the centre: any angle */
        ck_assert(fabsf(s->uvs[2 * v] - r) < 1e-6f);
        float phi = atan2f(p.y, p.x) / (2 * (float)M_PI), got = s->uvs[2 * v + 1];
        /* the seam: -0.5 and 0.5 are the same angle */
        ck_assert_msg(fabsf(got - phi) < 1e-5f || fabsf(fabsf(got - phi) - 1) < 1e-5f,
                      "vertex %zu: v %g, phi / 2 pi %g", v, got, phi);
    }
    scene_destroy(&s);
    /* a textured sphere: (phi / 2 pi, theta / pi) about its centre, phi
     * in [0, 2 pi) except across the seam, where a triangle's corners go
     * past 1 */
    s = load_ok(build(buf, sizeof buf, CAM_OK, NULL, mats,
                      "\"shapes\": [{\"type\": \"sphere\", \"material\": \"white\", "
                      "\"center\": [1, 2, 3], \"radius\": 2, \"subdivisions\": 3}, " QUAD_LIGHT
                      "]"),
                "sphere-uv.json");
    for (size_t v = 0; v < 20 * 64 * 3; v++) {
        vec3_t p = vec3_scale(vec3_sub(scene_vertex(s, (uint32_t)v), vec3_make(1, 2, 3)), 0.5f);
        float u = s->uvs[2 * v], w = s->uvs[2 * v + 1];
        ck_assert_msg(fabsf(w - acosf(fmaxf(-1, fminf(1, p.z))) / (float)M_PI) < 1e-5f,
                      "vertex %zu: v %g", v, w);
        if (fabsf(p.x) < 1e-6f && fabsf(p.y) < 1e-6f)
            continue; /* a pole */
        float phi = atan2f(p.y, p.x) / (2 * (float)M_PI);
        if (phi < 0)
            phi += 1;
        ck_assert_msg(fabsf(u - phi) < 1e-5f || fabsf(u - phi - 1) < 1e-5f,
                      "vertex %zu: u %g, phi / 2 pi %g", v, u, phi);
    }
    scene_destroy(&s);
    expect_fail(
        build(buf, sizeof buf, CAM_OK, NULL, MATS_OK,
              "\"shapes\": [{\"type\": \"disk\", \"material\": \"white\", \"segments\": 2}]"),
        "disk2.json", "shapes[0].segments", "out of range", NULL);
}
END_TEST

/* "crop": the image is a window of the film; outside it, refused */
START_TEST(camera_crop)
{
    char buf[TEXTLEN];
    const char *cam = "\"camera\": {\"position\": [0, 0, -5], \"look_at\": [0, 0, 0], \"fov\": 40, "
                      "\"width\": 32, \"height\": 24, \"crop\": [4, 2, 10, 8]}";
    scene_t *s = load_ok(build(buf, sizeof buf, cam, NULL, MATS_OK, SHAPES_OK), "crop.json");
    ck_assert(s->camera.width == 10 && s->camera.height == 8 && s->camera.film_width == 32 &&
              s->camera.crop_x == 4 && s->camera.crop_y == 2);
    scene_destroy(&s);
    const char *bad = "\"camera\": {\"position\": [0, 0, -5], \"look_at\": [0, 0, 0], \"fov\": 40, "
                      "\"width\": 32, \"height\": 24, \"crop\": [30, 2, 10, 8]}";
    expect_fail(build(buf, sizeof buf, bad, NULL, MATS_OK, SHAPES_OK), "crop-bad.json",
                "camera.crop", "leaves the 32x24 film", NULL);
    const char *odd = "\"camera\": {\"position\": [0, 0, -5], \"look_at\": [0, 0, 0], \"fov\": 40, "
                      "\"width\": 32, \"height\": 24, \"crop\": [1, 2, 3]}";
    expect_fail(build(buf, sizeof buf, odd, NULL, MATS_OK, SHAPES_OK), "crop-odd.json",
                "camera.crop", "expected 4 integers", NULL);
}
END_TEST

START_TEST(feature_triangles)
{
    char buf[TEXTLEN];
    const char *shapes = "\"shapes\": [{\"type\": \"triangles\", \"material\": \"light\", "
                         "\"vertices\": [[0, 0, 0], [2, 0, 0], [2, 0, 2], [0, 0, 2]], "
                         "\"indices\": [[0, 2, 1], [0, 3, 2]]}]";
    scene_t *s = load_ok(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, shapes), "tris.json");
    ck_assert_uint_eq(s->triangle_count, 2);
    ck_assert_uint_eq(s->vertex_count, 4);
    assert_vec(vertex(s, 0, 1), 2, 0, 2, 0);
    assert_vec(vertex(s, 0, 2), 2, 0, 0, 0);
    assert_vec(vertex(s, 1, 1), 0, 0, 2, 0);
    /* (2,0,2) x (2,0,0) = (0, 4, 0): up */
    ck_assert_float_eq_tol(s->tri_normal[0].y, 1.0f, 1e-6f);
    ck_assert_float_eq_tol(s->tri_normal[1].y, 1.0f, 1e-6f);
    ck_assert_uint_eq(s->tri_material[0], 1);
    ck_assert_uint_eq(s->light_count, 2);
    /* two triangles of equal area and radiance: equal probability, pdf 1/4 */
    ck_assert_double_eq_tol(s->light_cdf[0], 0.5, 1e-12);
    ck_assert_float_eq_tol(s->tri_light_pdf[0], 0.25f, 1e-6f);
    scene_destroy(&s);
}
END_TEST

START_TEST(feature_quad_winding)
{
    char buf[TEXTLEN];
    scene_t *s = load_ok(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, SHAPES_OK), "wind.json");
    ck_assert_uint_eq(s->triangle_count, 4);
    /* white quad (0,0,0) (1,0,0) (1,1,0) (0,1,0): cross(v1-v0, v2-v0) = +z */
    for (int t = 0; t < 2; t++) {
        ck_assert_float_eq_tol(s->tri_normal[t].z, 1.0f, 1e-6f);
        ck_assert_float_eq_tol(s->tri_normal[t].x, 0.0f, 1e-6f);
    }
    /* split (v0, v1, v2), (v0, v2, v3) */
    assert_vec(vertex(s, 0, 0), 0, 0, 0, 0);
    assert_vec(vertex(s, 0, 1), 1, 0, 0, 0);
    assert_vec(vertex(s, 0, 2), 1, 1, 0, 0);
    assert_vec(vertex(s, 1, 2), 0, 1, 0, 0);
    /* light quad (0,3,0) (0,3,1) (1,3,1): (0,0,1) x (1,0,1) = (0, 1, 0) */
    for (int t = 2; t < 4; t++)
        ck_assert_float_eq_tol(s->tri_normal[t].y, 1.0f, 1e-6f);
    scene_destroy(&s);
}
END_TEST

START_TEST(feature_transform)
{
    char buf[TEXTLEN];
    const char *shapes =
        "\"shapes\": [{\"type\": \"quad\", \"material\": \"white\", \"vertices\": [[0, 0, 0], "
        "[1, 0, 0], [1, 1, 0], [0, 1, 0]], \"transform\": {\"scale\": 2, \"rotate\": [0, 90, 0], "
        "\"translate\": [1, 2, 3]}}, "
        /* X then Y: (0,1,0) -X90-> (0,0,1) -Y90-> (1,0,0); Y then X would give (0,0,1) */
        "{\"type\": \"triangles\", \"material\": \"white\", \"vertices\": [[0, 1, 0], [0, 0, 0], "
        "[1, 1, 1]], \"indices\": [[0, 1, 2]], \"transform\": {\"rotate\": [90, 90, 0]}}, "
        /* per-axis scale, then Z rotation: (1,1,1) -S-> (1,2,3) -Z90-> (-2,1,3) */
        "{\"type\": \"triangles\", \"material\": \"white\", \"vertices\": [[1, 1, 1], [0, 0, 0], "
        "[0, 1, 0]], \"indices\": [[0, 1, 2]], \"transform\": {\"scale\": [1, 2, 3], "
        "\"rotate\": [0, 0, 90]}}, " QUAD_LIGHT "]";
    scene_t *s = load_ok(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, shapes), "xf.json");
    ck_assert_uint_eq(s->triangle_count, 6);
    /* (x, y, z) -> scale 2 -> Y90: (2z, 2y, -2x) -> + (1, 2, 3) */
    assert_vec(vertex(s, 0, 0), 1, 2, 3, 1e-5);
    assert_vec(vertex(s, 0, 1), 1, 2, 1, 1e-5);
    assert_vec(vertex(s, 0, 2), 1, 4, 1, 1e-5);
    assert_vec(vertex(s, 1, 2), 1, 4, 3, 1e-5);
    /* +z rotated 90 degrees about y is +x */
    ck_assert_float_eq_tol(s->tri_normal[0].x, 1.0f, 1e-6f);
    ck_assert_float_eq_tol(s->tri_normal[1].x, 1.0f, 1e-6f);
    assert_vec(vertex(s, 2, 0), 1, 0, 0, 1e-6);
    assert_vec(vertex(s, 3, 0), -2, 1, 3, 1e-5);
    assert_vec(vertex(s, 3, 2), -2, 0, 0, 1e-5);
    scene_destroy(&s);
}
END_TEST

START_TEST(feature_mirror_scale)
{
    char buf[TEXTLEN];
    /* a quad at z = 1 facing +z, mirrored through z = 0: it lies at z = -1
     * and (the loader swaps the winding) faces -z, away from the mirror
     * plane as the original faced away from it. */
    const char *shapes = "\"shapes\": [" QUAD_LIGHT ", {\"type\": \"quad\", \"material\": "
                         "\"white\", \"vertices\": [[0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], "
                         "\"transform\": {\"scale\": [1, 1, -1]}}]";
    scene_t *s = load_ok(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, shapes), "mirror.json");
    ck_assert_uint_eq(s->triangle_count, 4);
    for (size_t t = 2; t < 4; t++) {
        for (int k = 0; k < 3; k++)
            ck_assert_float_eq(vertex(s, t, k)[2], -1.0f);
        ck_assert_msg(s->tri_normal[t].z < -0.999f, "mirrored normal z = %g", s->tri_normal[t].z);
    }
    /* an all-negative scale (det < 0) is a point reflection: +z becomes -z */
    const char *neg = "\"shapes\": [" QUAD_LIGHT ", {\"type\": \"quad\", \"material\": "
                      "\"white\", \"vertices\": [[0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], "
                      "\"transform\": {\"scale\": -2}}]";
    scene_destroy(&s);
    s = load_ok(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, neg), "neg.json");
    for (size_t t = 2; t < 4; t++)
        ck_assert_msg(s->tri_normal[t].z < -0.999f, "point-reflected normal z = %g",
                      s->tri_normal[t].z);
    /* two negative axes (det > 0) is a rotation: the winding stays, +z stays */
    const char *two = "\"shapes\": [" QUAD_LIGHT ", {\"type\": \"quad\", \"material\": "
                      "\"white\", \"vertices\": [[0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], "
                      "\"transform\": {\"scale\": [-1, -1, 1]}}]";
    scene_destroy(&s);
    s = load_ok(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, two), "two.json");
    for (size_t t = 2; t < 4; t++)
        ck_assert_msg(s->tri_normal[t].z > 0.999f, "normal z = %g", s->tri_normal[t].z);
    scene_destroy(&s);
}
END_TEST

static void check_sphere(const scene_t *s, size_t first, size_t ntri, const double c[3], double r,
                         double mirror_x)
{
    ck_assert_ptr_nonnull(s->normals);
    for (size_t t = first; t < first + ntri; t++) {
        ck_assert_int_eq(s->tri_smooth[t], 1);
        double cen[3] = {0, 0, 0};
        for (int k = 0; k < 3; k++) {
            const float *p = vertex(s, t, k);
            const float *n = s->normals + 3 * s->indices[3 * t + k];
            double d[3] = {p[0] - c[0], p[1] - c[1], p[2] - c[2]};
            double dist = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
            ck_assert_msg(fabs(dist - r) <= 1e-5 * r, "vertex at distance %.9g, radius %g", dist,
                          r);
            /* vertex normal = (p - c) / r */
            for (int i = 0; i < 3; i++) {
                ck_assert_msg(fabs(n[i] - d[i] / dist) < 1e-5, "vertex normal off");
                cen[i] += p[i] / 3.0;
            }
        }
        vec3_t g = s->tri_normal[t];
        double out = g.x * (cen[0] - c[0]) + g.y * (cen[1] - c[1]) + g.z * (cen[2] - c[2]);
        ck_assert_msg(out > 0, "triangle %zu faces inward (mirror %g)", t, mirror_x);
    }
}

START_TEST(feature_sphere)
{
    char buf[TEXTLEN];
    const char *shapes = "\"shapes\": [" QUAD_LIGHT ", {\"type\": \"sphere\", \"material\": "
                         "\"white\", \"center\": [1, 2, 3], \"radius\": 0.5, \"subdivisions\": 2}]";
    scene_t *s = load_ok(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, shapes), "sph.json");
    ck_assert_uint_eq(s->dropped_degenerate, 0);
    ck_assert_uint_eq(s->triangle_count, 2 + 20 * 16);
    /* the quad before the sphere has no vertex normals */
    ck_assert_int_eq(s->tri_smooth[0], 0);
    ck_assert_int_eq(s->tri_smooth[1], 0);
    const double c[3] = {1, 2, 3};
    check_sphere(s, 2, 320, c, 0.5, 1);
    /* total area close to 4 pi r^2 (a subdivided icosahedron is a bit less) */
    double area = 0;
    for (size_t t = 2; t < s->triangle_count; t++) {
        const float *a = vertex(s, t, 0), *b = vertex(s, t, 1), *d = vertex(s, t, 2);
        double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
        double e2[3] = {d[0] - a[0], d[1] - a[1], d[2] - a[2]};
        double x = e1[1] * e2[2] - e1[2] * e2[1], y = e1[2] * e2[0] - e1[0] * e2[2],
               z = e1[0] * e2[1] - e1[1] * e2[0];
        area += 0.5 * sqrt(x * x + y * y + z * z);
    }
    double full = 4 * M_PI * 0.25;
    ck_assert_msg(area < full && area > 0.95 * full, "area %g vs %g", area, full);
    scene_destroy(&s);

    /* default subdivisions (4), mirrored by the transform: still outward */
    const char *mir = "\"shapes\": [" QUAD_LIGHT ", {\"type\": \"sphere\", \"material\": "
                      "\"white\", \"center\": [1, 0, 0], \"radius\": 2, "
                      "\"transform\": {\"scale\": [-1, 1, 1], \"translate\": [0, 5, 0]}}]";
    s = load_ok(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, mir), "sphm.json");
    ck_assert_uint_eq(s->triangle_count, 2 + 20 * 256);
    const double cm[3] = {-1, 5, 0};
    check_sphere(s, 2, 20 * 256, cm, 2, -1);
    scene_destroy(&s);

    /* subdivisions 0 (the icosahedron) and the bounds */
    const char *ico = "\"shapes\": [{\"type\": \"sphere\", \"material\": \"light\", \"center\": "
                      "[0, 0, 0], \"radius\": 1, \"subdivisions\": 0}]";
    s = load_ok(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, ico), "ico.json");
    ck_assert_uint_eq(s->triangle_count, 20);
    ck_assert_uint_eq(s->light_count, 20);
    scene_destroy(&s);
    const char *too = "\"shapes\": [{\"type\": \"sphere\", \"material\": \"light\", \"center\": "
                      "[0, 0, 0], \"radius\": 1, \"subdivisions\": 8}]";
    expect_fail(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, too), "sub8.json",
                "shapes[0].subdivisions", "out of range", NULL);
    const char *rad = "\"shapes\": [{\"type\": \"sphere\", \"material\": \"light\", \"center\": "
                      "[0, 0, 0], \"radius\": 0}]";
    expect_fail(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, rad), "rad0.json", "shapes[0].radius",
                "out of range", NULL);
}
END_TEST

/* scene_icosphere_gap(n), which mitsuba.c tessellates spheres by, is the
 * widest gap between each icosphere shape_sphere makes and its true
 * sphere: 1 - the least distance from the centre to a face's plane,
 * measured on the meshes (radius 1, so the floats' rounding is ~1e-7), and
 * every vertex on the sphere. */
START_TEST(sphere_gap_as_stated)
{
    char buf[TEXTLEN], shapes[256];
    for (int n = 0; n <= SCENE_MAX_SPHERE_SUBDIVISIONS; n++) {
        snprintf(shapes, sizeof shapes,
                 "\"shapes\": [" QUAD_LIGHT ", {\"type\": \"sphere\", \"material\": "
                 "\"white\", \"center\": [0, 0, 0], \"radius\": 1, \"subdivisions\": %d}]",
                 n);
        scene_t *s = load_ok(build(buf, sizeof buf, CAM_OK, NULL, MATS_OK, shapes), "gap.json");
        ck_assert_uint_eq(s->triangle_count, 2 + ((size_t)20 << (2 * n)));
        double nearest = 2, farthest_vertex = 0;
        for (size_t t = 2; t < s->triangle_count; t++) {
            double p[3][3];
            for (int k = 0; k < 3; k++)
                for (int d = 0; d < 3; d++)
                    p[k][d] = vertex(s, t, k)[d];
            double e1[3], e2[3], nrm[3];
            for (int d = 0; d < 3; d++) {
                e1[d] = p[1][d] - p[0][d];
                e2[d] = p[2][d] - p[0][d];
            }
            nrm[0] = e1[1] * e2[2] - e1[2] * e2[1];
            nrm[1] = e1[2] * e2[0] - e1[0] * e2[2];
            nrm[2] = e1[0] * e2[1] - e1[1] * e2[0];
            double len = sqrt(nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]);
            nearest =
                fmin(nearest, fabs(nrm[0] * p[0][0] + nrm[1] * p[0][1] + nrm[2] * p[0][2]) / len);
            for (int k = 0; k < 3; k++)
                farthest_vertex =
                    fmax(farthest_vertex,
                         fabs(sqrt(p[k][0] * p[k][0] + p[k][1] * p[k][1] + p[k][2] * p[k][2]) - 1));
        }
        double gap = scene_icosphere_gap(n), measured = 1 - nearest;
        ck_assert_msg(fabs(measured - gap) < 3e-7 + 1e-4 * gap,
                      "%d subdivisions: gap %.9g, scene_icosphere_gap says %.9g", n, measured, gap);
        ck_assert_msg(farthest_vertex < 3e-7, "%d subdivisions: a vertex %g off the sphere", n,
                      farthest_vertex);
        /* a quarter for each subdivision more */
        if (n > 0)
            ck_assert(gap < 0.33 * scene_icosphere_gap(n - 1));
        scene_destroy(&s);
    }
}
END_TEST

START_TEST(feature_materials)
{
    char buf[TEXTLEN];
    const char *mats =
        "\"materials\": {\"white\": {\"type\": \"diffuse\", \"albedo\": [0.5, 0.25, 0.125]}, "
        "\"light\": {\"type\": \"emitter\", \"radiance\": [3, 2, 1], \"albedo\": [0.75, 0.5, "
        "0.25]}, "
        "\"dark\": {\"type\": \"emitter\", \"radiance\": [1, 1, 1]}, "
        "\"chrome\": {\"type\": \"mirror\"}, \"glass\": {\"type\": \"dielectric\", \"ior\": 1.33}, "
        "\"crown\": {\"type\": \"dielectric\"}}";
    scene_t *s = load_ok(build(buf, sizeof buf, CAM_OK, NULL, mats, SHAPES_OK), "mats.json");
    ck_assert_uint_eq(s->material_count, 6);
    ck_assert_int_eq(s->warning_count, 0);
    const material_t *m = s->materials;
    ck_assert_str_eq(m[1].name, "light");
    ck_assert_int_eq(m[1].type, MATERIAL_EMITTER);
    ck_assert_float_eq(m[1].radiance.x, 3.0f);
    ck_assert_float_eq(m[1].albedo.x, 0.75f);
    ck_assert_float_eq(m[1].albedo.z, 0.25f);
    ck_assert_float_eq(m[2].albedo.x, 0.0f); /* an emitter's albedo defaults to black */
    ck_assert_int_eq(m[3].type, MATERIAL_MIRROR);
    ck_assert_float_eq(m[3].albedo.y, 1.0f); /* reflectance defaults to 1 */
    ck_assert_int_eq(m[4].type, MATERIAL_DIELECTRIC);
    ck_assert_float_eq_tol(m[4].ior, 1.33f, 1e-6f);
    ck_assert_float_eq(m[5].ior, 1.5f);
    scene_destroy(&s);
    const char *ior = "\"materials\": {\"light\": {\"type\": \"emitter\", \"radiance\": [1, 1, 1]},"
                      " \"white\": {\"type\": \"dielectric\", \"ior\": 0}}";
    expect_fail(build(buf, sizeof buf, CAM_OK, NULL, ior, SHAPES_OK), "ior.json",
                "materials.white.ior", "out of range", NULL);
}
END_TEST

/* ---- robustness --------------------------------------------------------- */

static uint64_t rng_state;

static uint32_t rnd(uint32_t n)
{
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 7;
    rng_state ^= rng_state << 17;
    return (uint32_t)((rng_state >> 11) % n);
}

/* Replaces the number (kind 0) or the contents of the string (kind 1) that
 * starts at or after `at` with `with`; returns the new length. */
static size_t replace_token(char *t, size_t n, size_t cap, size_t at, int kind, const char *with)
{
    size_t a = at, b;
    if (kind == 0) {
        while (a < n && !(t[a] >= '0' && t[a] <= '9'))
            a++;
        while (a > 0 && strchr("-+.eE0123456789", t[a - 1]) && t[a - 1] != '\0')
            a--;
        b = a;
        while (b < n && strchr("-+.eE0123456789", t[b]) && t[b] != '\0')
            b++;
    } else {
        while (a < n && t[a] != '"')
            a++;
        a++;
        b = a;
        while (b < n && t[b] != '"')
            b++;
    }
    size_t wl = strlen(with);
    if (a >= n || b > n || n - (b - a) + wl > cap)
        return n;
    memmove(t + a + wl, t + b, n - b);
    memcpy(t + a, with, wl);
    return n - (b - a) + wl;
}

START_TEST(fuzz_mutations)
{
    char path[PATHLEN];
    size_t len;
    char *orig = read_text(tu_root_path(path, sizeof path, "scenes/cornell-box.json"), &len);
    ck_assert_uint_gt(len, 100);
    static const char alphabet[] = "{}[]\",:-+.eE0123456789 \n\\tnfu";
    static const char *const numbers[] = {"0",          "-1", "1e999",  "-1e999", "1e-320", "0.5",
                                          "2",          "3",  "7",      "8",      "1e30",   "16384",
                                          "4294967296", "-0", "100000", "1.5",    "180"};
    static const char *const words[] = {"quad",     "triangles", "mesh",       "sphere", "diffuse",
                                        "emitter",  "mirror",    "dielectric", "white",  "light",
                                        "camera",   "shapes",    "materials",  "render", "type",
                                        "vertices", "indices",   "transform",  "scale",  "rotate",
                                        "albedo",   "radiance",  "naive",      "",       "\\u0000"};
    rng_state = 0x243f6a8885a308d3ull;
    int ok = 0, bad = 0;
    for (int iter = 0; iter < 2000; iter++) {
        /* the buffer is exactly the text (no terminator), so a read past
         * len shows under ASan */
        size_t cap = len + 256, n = len;
        char *t = malloc(cap);
        ck_assert_ptr_nonnull(t);
        memcpy(t, orig, len);
        int edits = 1 + (int)rnd(4);
        for (int e = 0; e < edits && n > 0; e++) {
            size_t at = rnd((uint32_t)n);
            switch (rnd(8)) {
            case 0: /* delete */
                memmove(t + at, t + at + 1, n - at - 1);
                n--;
                break;
            case 1: /* insert */
                if (n < cap) {
                    memmove(t + at + 1, t + at, n - at);
                    t[at] = rnd(4) ? alphabet[rnd(sizeof alphabet - 1)] : (char)rnd(256);
                    n++;
                }
                break;
            case 2: /* flip a bit */
                t[at] = (char)(t[at] ^ (1 << rnd(8)));
                break;
            case 3: /* replace with a JSON-ish character */
                t[at] = alphabet[rnd(sizeof alphabet - 1)];
                break;
            case 4: /* the next number becomes another, often a bad one */
            case 5:
                n = replace_token(t, n, cap, at, 0,
                                  numbers[rnd(sizeof numbers / sizeof numbers[0])]);
                break;
            case 6: /* the next string becomes another name the loader knows */
                n = replace_token(t, n, cap, at, 1, words[rnd(sizeof words / sizeof words[0])]);
                break;
            default: /* truncate */
                n = at;
                break;
            }
        }
        char *exact = malloc(n ? n : 1);
        ck_assert_ptr_nonnull(exact);
        memcpy(exact, t, n);
        free(t);
        char err[ERRLEN];
        err[0] = '\0';
        scene_t *s = (scene_t *)(uintptr_t)1;
        int rc = scene_load_string(exact, n, "fuzz.json", NULL, &s, err, sizeof err);
        ck_assert_msg(rc == 0 || rc == -1, "rc %d", rc);
        if (rc == 0) {
            ck_assert_ptr_nonnull(s);
            ck_assert_uint_gt(s->triangle_count, 0);
            scene_destroy(&s);
            ok++;
        } else {
            ck_assert_ptr_null(s);
            ck_assert_msg(err[0] != '\0', "empty message for a failed load (iteration %d)", iter);
            bad++;
        }
        free(exact);
    }
    if (getenv("VB_VERBOSE"))
        fprintf(stderr, "fuzz: %d loaded, %d refused\n", ok, bad);
    ck_assert_int_gt(ok, 0);
    ck_assert_int_gt(bad, 0);
    free(orig);
}
END_TEST

/* The cut-off points of a nested JSON path and the warning table: many
 * warnings never overflow SCENE_MAX_WARNINGS, long keys never overflow the
 * message buffers. */
START_TEST(long_names_many_warnings)
{
    char buf[TEXTLEN], cam[4096];
    char key[700];
    memset(key, 'k', sizeof key - 1);
    key[sizeof key - 1] = '\0';
    int n = snprintf(cam, sizeof cam,
                     "\"camera\": {\"position\": [0, 0, -5], \"look_at\": [0, 0, 0], \"fov\": 40, "
                     "\"width\": 8, \"height\": 8");
    for (int i = 0; i < 12; i++)
        n += snprintf(cam + n, sizeof cam - (size_t)n, ", \"x%d%.200s\": 1", i, key);
    snprintf(cam + n, sizeof cam - (size_t)n, "}");
    scene_t *s = load_ok(build(buf, sizeof buf, cam, NULL, MATS_OK, SHAPES_OK), "warn.json");
    ck_assert_int_eq(s->warning_count, SCENE_MAX_WARNINGS);
    for (int i = 0; i < s->warning_count; i++)
        ck_assert_uint_lt(strlen(s->warnings[i]), SCENE_WARNING_LEN);
    scene_destroy(&s);
    /* a material name too long for material_t, and one that fits */
    char mats[2048];
    snprintf(mats, sizeof mats,
             "\"materials\": {\"%.*s\": {\"type\": \"diffuse\", \"albedo\": [1, 1, 1]}, "
             "\"light\": {\"type\": \"emitter\", \"radiance\": [1, 1, 1]}}",
             MATERIAL_NAME_LEN, key);
    expect_fail(build(buf, sizeof buf, CAM_OK, NULL, mats, SHAPES_OK), "longmat.json", "materials.",
                "1 to 63", NULL);
    /* an error message longer than the caller's buffer is cut, terminated */
    char small[24];
    memset(small, 'x', sizeof small);
    scene_t *s2 = NULL;
    ck_assert_int_eq(scene_load_string("[]", 2, "small.json", NULL, &s2, small, sizeof small), -1);
    ck_assert_uint_eq(strlen(small), sizeof small - 1);
}
END_TEST

/* ---- suite -------------------------------------------------------------- */

static Suite *scene_suite(void)
{
    Suite *su = suite_create("scene");
    TCase *tc = tcase_create("shipped");
    tcase_set_timeout(tc, 60);
    tcase_add_test(tc, cornell_box);
    tcase_add_test(tc, cornell_light_pdf);
    tcase_add_test(tc, happy_buddha);
    suite_add_tcase(su, tc);

    tc = tcase_create("errors");
    tcase_add_test(tc, bad_malformed_json);
    tcase_add_test(tc, bad_top_level);
    tcase_add_test(tc, bad_missing_camera);
    tcase_add_test(tc, bad_camera_position_two);
    tcase_add_test(tc, bad_fov_string);
    tcase_add_test(tc, bad_camera_basis);
    tcase_add_test(tc, bad_shape_material);
    tcase_add_test(tc, bad_material_type);
    tcase_add_test(tc, glossy_materials);
    tcase_add_test(tc, feature_disk_cylinder);
    tcase_add_test(tc, camera_crop);
    tcase_add_test(tc, bad_shape_type);
    tcase_add_test(tc, bad_mesh_missing);
    tcase_add_test(tc, bad_mesh_malformed);
    tcase_add_test(tc, bad_triangle_index);
    tcase_add_test(tc, bad_nonfinite);
    tcase_add_test(tc, bad_empty_scene);
    tcase_add_test(tc, bad_only_degenerate);
    tcase_add_test(tc, bad_resolution);
    tcase_add_test(tc, bad_albedo_over_one);
    tcase_add_test(tc, bad_negative_radiance);
    tcase_add_test(tc, bad_material_twice);
    tcase_add_test(tc, bad_render_fields);
    tcase_add_test(tc, bad_scale_zero);
    tcase_add_test(tc, bad_files);
    suite_add_tcase(su, tc);

    tc = tcase_create("warnings");
    tcase_add_test(tc, warn_degenerate);
    tcase_add_test(tc, warn_no_light);
    tcase_add_test(tc, warn_unknown_field);
    suite_add_tcase(su, tc);

    tc = tcase_create("features");
    tcase_add_test(tc, feature_defaults_and_render);
    tcase_add_test(tc, feature_triangles);
    tcase_add_test(tc, feature_quad_winding);
    tcase_add_test(tc, feature_transform);
    tcase_add_test(tc, feature_mirror_scale);
    tcase_add_test(tc, feature_sphere);
    tcase_add_test(tc, sphere_gap_as_stated);
    tcase_add_test(tc, feature_materials);
    tcase_add_test(tc, checked_only);
    suite_add_tcase(su, tc);

    tc = tcase_create("robustness");
    tcase_set_timeout(tc, 60);
    tcase_add_test(tc, bad_light_scale);
    tcase_add_test(tc, fuzz_mutations);
    tcase_add_test(tc, long_names_many_warnings);
    suite_add_tcase(su, tc);
    return su;
}

int main(void)
{
    SRunner *sr = srunner_create(scene_suite());
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed == 0 ? EXIT_SUCCESS : EXIT_FAILURE;
}
