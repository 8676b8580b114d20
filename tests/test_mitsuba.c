/* test_mitsuba.c - Mitsuba 3 scene files (common/mitsuba.c): spectra as
 * Mitsuba converts them, the file structure (defaults, -D, includes,
 * paths, refs, transforms), the shipped scene, a refusal naming file and
 * line for what we do not render, and our image of the shipped scene
 * against Mitsuba's own (tests/data/mitsuba/). */
#include <check.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "camera.h"
#include "film.h"
#include "image.h"
#include "lights.h"
#include "mitsuba.h"
#include "render.h"
#include "scene.h"
#include "testutil.h"
#include "texture.h"
#include "tracer.h"
#include "vberr.h"

/* ---- helpers ---------------------------------------------------------------- */

static const cJSON *get(const cJSON *o, const char *key)
{
    const cJSON *it = cJSON_GetObjectItemCaseSensitive(o, key);
    ck_assert_msg(it != NULL, "no \"%s\"", key);
    return it;
}

static double num_at(const cJSON *arr, int i)
{
    const cJSON *it = cJSON_GetArrayItem(arr, i);
    ck_assert_msg(cJSON_IsNumber(it), "item %d is not a number", i);
    return it->valuedouble;
}

static void assert_vec3(const cJSON *arr, double x, double y, double z, double tol)
{
    ck_assert_int_eq(cJSON_GetArraySize(arr), 3);
    double want[3] = {x, y, z};
    for (int i = 0; i < 3; i++)
        ck_assert_msg(fabs(num_at(arr, i) - want[i]) <= tol, "[%d] = %.9g, want %.9g", i,
                      num_at(arr, i), want[i]);
}

/* A scratch folder of its own for a test's files. */
static const char *scratch_dir(char *buf, size_t len, const char *name)
{
    tu_tmp_path(buf, len, name);
    char cmd[2048], out[256];
    snprintf(cmd, sizeof cmd, "rm -rf '%s' && mkdir -p '%s/sub'", buf, buf);
    ck_assert_int_eq(tu_run(cmd, out, sizeof out), 0);
    return buf;
}

static void write_file(const char *dir, const char *name, const char *text)
{
    char path[2048];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE *f = fopen(path, "w");
    ck_assert_msg(f != NULL, "cannot write %s", path);
    fputs(text, f);
    fclose(f);
}

static cJSON *shipped(const char *const *defines, size_t n)
{
    char path[1024], err[VB_ERR_LEN];
    tu_root_path(path, sizeof path, "scenes/mitsuba/cornell-box.xml");
    cJSON *j = mitsuba_scene_json(path, defines, n, err, sizeof err);
    ck_assert_msg(j != NULL, "%s", err);
    return j;
}

/* ---- spectra ----------------------------------------------------------------- */

/* The values Mitsuba 3.9.1 gives (mi.spectrum_list_to_srgb, bounded and
 * under D65 for a reflectance, neither for a radiance): ours to 1e-5. */
START_TEST(spectrum_as_mitsuba)
{
    double rgb[3];
    double nm[] = {400, 500, 600, 700}, flat[] = {0.78, 0.78, 0.78, 0.78},
           emit[] = {0, 8, 15.6, 18.4};
    ck_assert_int_eq(mitsuba_spectrum_rgb(nm, flat, 4, 1, rgb), 0);
    double want_flat[3] = {0.776368, 0.779809, 0.776029};
    for (int c = 0; c < 3; c++)
        ck_assert_msg(fabs(rgb[c] - want_flat[c]) < 1e-5, "reflectance[%d] %.7f", c, rgb[c]);
    ck_assert_int_eq(mitsuba_spectrum_rgb(nm, emit, 4, 0, rgb), 0);
    double want_emit[3] = {20.7108, 10.8546, 2.77115};
    for (int c = 0; c < 3; c++)
        ck_assert_msg(fabs(rgb[c] / want_emit[c] - 1) < 1e-5, "radiance[%d] %.7f", c, rgb[c]);
    /* white under D65 is white; a reflectance is clamped to 1 */
    double full[] = {360, 830}, one[] = {1, 1}, big[] = {3, 3};
    ck_assert_int_eq(mitsuba_spectrum_rgb(full, one, 2, 1, rgb), 0);
    for (int c = 0; c < 3; c++)
        ck_assert(fabs(rgb[c] - 1) < 2e-3);
    ck_assert_int_eq(mitsuba_spectrum_rgb(full, big, 2, 1, rgb), 0);
    ck_assert(rgb[0] == 1 && rgb[1] == 1 && rgb[2] == 1);
    /* one wavelength, or not ascending: refused */
    double down[] = {500, 400};
    ck_assert_int_eq(mitsuba_spectrum_rgb(full, one, 1, 1, rgb), -1);
    ck_assert_int_eq(mitsuba_spectrum_rgb(down, one, 2, 1, rgb), -1);
}
END_TEST

/* ---- the shipped scene ---------------------------------------------------------- */

/* mitsuba_scene_load: a Mitsuba file as the scene it becomes, its meshes
 * found beside it from any working folder; a JSON file as scene_load reads
 * it; a broken file refused with its name and line. */
START_TEST(scene_load_either_kind)
{
    char path[2048], err[VB_ERR_LEN];
    scene_t *s = NULL;
    tu_root_path(path, sizeof path, "scenes/mitsuba/cornell-box.xml");
    ck_assert_msg(mitsuba_scene_load(path, &s, err, sizeof err) == 0, "%s", err);
    ck_assert_int_eq(s->camera.width, 256);   /* its <default name="res"> */
    ck_assert_uint_gt(s->triangle_count, 12); /* the OBJ meshes in meshes/ */
    ck_assert_uint_gt(s->light_count, 0);
    scene_destroy(&s);
    tu_root_path(path, sizeof path, "scenes/cornell-box.json");
    ck_assert_msg(mitsuba_scene_load(path, &s, err, sizeof err) == 0, "%s", err);
    ck_assert_uint_eq(s->triangle_count, 32);
    scene_destroy(&s);
    char dir[1024];
    scratch_dir(dir, sizeof dir, "mitsuba-load");
    write_file(dir, "broken.xml",
               "<scene version=\"3.0.0\">\n  <shape type=\"sphere\">\n</scene>\n");
    snprintf(path, sizeof path, "%s/broken.xml", dir);
    s = (scene_t *)1;
    ck_assert_int_eq(mitsuba_scene_load(path, &s, err, sizeof err), -1);
    ck_assert(s == NULL);
    ck_assert_msg(strstr(err, "broken.xml:") != NULL, "%s", err);
}
END_TEST

START_TEST(shipped_scene)
{
    cJSON *j = shipped(NULL, 0);
    const cJSON *cam = get(j, "camera");
    assert_vec3(get(cam, "position"), 278, 273, -800, 1e-9);
    assert_vec3(get(cam, "look_at"), 278, 273, -799, 1e-9);
    assert_vec3(get(cam, "up"), 0, 1, 0, 1e-12);
    ck_assert(fabs(get(cam, "fov")->valuedouble - 39.3077) < 1e-9);
    ck_assert_int_eq((int)get(cam, "width")->valuedouble, 256);
    const cJSON *render = get(j, "render");
    ck_assert_int_eq((int)get(render, "spp")->valuedouble, 64);
    ck_assert_int_eq((int)get(render, "max_depth")->valuedouble, 0); /* -1: unlimited */
    ck_assert_int_eq((int)get(render, "rr_depth")->valuedouble, 5);  /* Mitsuba's default */
    const cJSON *mats = get(j, "materials");
    const cJSON *white = get(mats, "white"), *red = get(mats, "red");
    ck_assert(cJSON_IsTrue(get(white, "twosided")));
    assert_vec3(get(white, "albedo"), 0.725, 0.71, 0.68, 1e-12);
    ck_assert(cJSON_IsFalse(get(red, "twosided")));
    /* Mitsuba 3.9.1's conversion of the red wall's spectrum */
    assert_vec3(get(red, "albedo"), 0.494084, 0.0639747, 0.0454572, 2e-6);
    /* the light: a rectangle scaled, turned to face down and moved under
     * the ceiling, emitting Mitsuba's RGB of its spectrum */
    const cJSON *shapes = get(j, "shapes");
    ck_assert_int_eq(cJSON_GetArraySize(shapes), 8);
    const cJSON *light = cJSON_GetArrayItem(shapes, 7);
    ck_assert_str_eq(get(light, "type")->valuestring, "triangles");
    const cJSON *lm = get(mats, get(light, "material")->valuestring);
    ck_assert_str_eq(get(lm, "type")->valuestring, "emitter");
    assert_vec3(get(lm, "radiance"), 20.7725, 10.7766, 3.74761, 1e-4);
    assert_vec3(get(lm, "albedo"), 0.78, 0.78, 0.78, 1e-12);
    const cJSON *v = get(light, "vertices"), *idx = get(light, "indices");
    assert_vec3(cJSON_GetArrayItem(v, 0), 213, 548.7, 227, 1e-9);
    assert_vec3(cJSON_GetArrayItem(v, 2), 343, 548.7, 332, 1e-9);
    double p[3][3];
    for (int k = 0; k < 3; k++)
        for (int c = 0; c < 3; c++)
            p[k][c] = num_at(cJSON_GetArrayItem(v, (int)num_at(cJSON_GetArrayItem(idx, 0), k)), c);
    double e1[3] = {p[1][0] - p[0][0], p[1][1] - p[0][1], p[1][2] - p[0][2]};
    double e2[3] = {p[2][0] - p[0][0], p[2][1] - p[0][1], p[2][2] - p[0][2]};
    double ny = e1[2] * e2[0] - e1[0] * e2[2];
    ck_assert_msg(ny < 0, "the light faces up (normal y %g)", ny);
    /* meshes by absolute path, in their own frame */
    const cJSON *floor = cJSON_GetArrayItem(shapes, 0);
    ck_assert_str_eq(get(floor, "type")->valuestring, "mesh");
    ck_assert(get(floor, "file")->valuestring[0] == '/');
    ck_assert_int_eq(cJSON_GetArraySize(get(get(floor, "transform"), "matrix")), 16);
    /* and it loads as our scene */
    char *text = cJSON_PrintUnformatted(j), err[VB_ERR_LEN];
    scene_t *s = NULL;
    ck_assert_msg(
        scene_load_string(text, strlen(text), "cornell-box.xml", ".", &s, err, sizeof err) == 0,
        "%s", err);
    ck_assert_int_eq(s->warning_count, 0);
    ck_assert_uint_eq(s->triangle_count, 32);
    scene_destroy(&s);
    cJSON_free(text);
    cJSON_Delete(j);
    /* -D overrides the file's <default>s */
    const char *defs[] = {"spp=16", "res=48"};
    j = shipped(defs, 2);
    ck_assert_int_eq((int)get(get(j, "render"), "spp")->valuedouble, 16);
    ck_assert_int_eq((int)get(get(j, "camera"), "width")->valuedouble, 48);
    cJSON_Delete(j);
}
END_TEST

/* ---- structure ---------------------------------------------------------------- */

static const char sensor_xml[] =
    "    <sensor type=\"perspective\">\n"
    "        <float name=\"fov\" value=\"40\"/>\n"
    "        <transform name=\"to_world\"><lookat origin=\"0, 0, 10\" target=\"0, 0, 0\"/>"
    "</transform>\n"
    "        <film type=\"hdrfilm\"><integer name=\"width\" value=\"20\"/>"
    "<integer name=\"height\" value=\"10\"/><rfilter type=\"box\"/></film>\n"
    "    </sensor>\n";

/* <default> and -D, <include> found through <path>, a ref to an id the
 * include declared, a transform chain applied in order, fov_axis x */
START_TEST(structure)
{
    char dir[1024], main_path[1200], err[VB_ERR_LEN], text[4096];
    scratch_dir(dir, sizeof dir, "mitsuba-structure");
    write_file(dir, "sub/inc.xml",
               "<scene version=\"3.0.0\">\n"
               "    <bsdf type=\"diffuse\" id=\"grey\">\n"
               "        <rgb name=\"reflectance\" value=\"$c\"/>\n"
               "    </bsdf>\n"
               "</scene>\n");
    snprintf(text, sizeof text,
             "<scene version=\"3.0.0\">\n"
             "    <default name=\"c\" value=\"0.25\"/>\n"
             "    <path value=\"sub\"/>\n"
             "    <include filename=\"inc.xml\"/>\n"
             "%s"
             "    <shape type=\"rectangle\">\n"
             "        <transform name=\"to_world\">\n"
             "            <translate x=\"1\"/>\n"
             "            <scale value=\"2\"/>\n"
             "        </transform>\n"
             "        <ref id=\"grey\"/>\n"
             "    </shape>\n"
             "</scene>\n",
             sensor_xml);
    write_file(dir, "main.xml", text);
    snprintf(main_path, sizeof main_path, "%s/main.xml", dir);
    cJSON *j = mitsuba_scene_json(main_path, NULL, 0, err, sizeof err);
    ck_assert_msg(j != NULL, "%s", err);
    assert_vec3(get(get(get(j, "materials"), "grey"), "albedo"), 0.25, 0.25, 0.25, 0);
    /* (-1, -1, 0) translated by x 1, then scaled by 2 */
    const cJSON *rect = cJSON_GetArrayItem(get(j, "shapes"), 0);
    assert_vec3(cJSON_GetArrayItem(get(rect, "vertices"), 0), 0, -2, 0, 1e-12);
    assert_vec3(cJSON_GetArrayItem(get(rect, "vertices"), 2), 4, 2, 0, 1e-12);
    /* 40 degrees across a 2:1 film: tan(v/2) = tan(20 deg) / 2 */
    const cJSON *cam = get(j, "camera");
    double want = 2 * atan(tan(20 * M_PI / 180) / 2) * 180 / M_PI;
    ck_assert(fabs(get(cam, "fov")->valuedouble - want) < 1e-9);
    assert_vec3(get(cam, "position"), 0, 0, 10, 0);
    cJSON_Delete(j);
    const char *defs[] = {"c=0.5"};
    j = mitsuba_scene_json(main_path, defs, 1, err, sizeof err);
    ck_assert_msg(j != NULL, "%s", err);
    assert_vec3(get(get(get(j, "materials"), "grey"), "albedo"), 0.5, 0.5, 0.5, 0);
    cJSON_Delete(j);
    ck_assert(mitsuba_is_scene_path("a/b.XML") && !mitsuba_is_scene_path("a.json"));
}
END_TEST

/* ---- refusals --------------------------------------------------------------------- */

typedef struct refusal {
    const char *body; /* the scene's elements after the sensor */
    int line;         /* the line the message must name (the body starts at line 3) */
    const char *says;
    int no_sensor;
} refusal_t;

static const refusal_t refusals[] = {
    {"<bsdf type=\"hair\" id=\"c\"/>\n<shape type=\"cube\"><ref id=\"c\"/></shape>", 3,
     "bsdf type \"hair\" is not supported (supported: diffuse, twosided, dielectric, "
     "thindielectric, roughdielectric, conductor, roughconductor, plastic, roughplastic)",
     0},
    {"<shape type=\"cube\">\n<bsdf type=\"roughconductor\"><float name=\"alpha_u\" "
     "value=\"0.1\"/><float name=\"alpha_v\" value=\"0.2\"/></bsdf></shape>",
     4, "anisotropic roughness (alpha_u 0.1, alpha_v 0.2) is not supported", 0},
    {"<shape type=\"cube\">\n<bsdf type=\"conductor\"><string name=\"material\" "
     "value=\"Unobtainium\"/></bsdf></shape>",
     4, "conductor material \"Unobtainium\" is not known (known: none, a-C, Ag", 0},
    {"<shape type=\"cube\">\n<bsdf type=\"roughplastic\"><string name=\"distribution\" "
     "value=\"phong\"/></bsdf></shape>",
     4, "distribution \"phong\" is not supported (beckmann, ggx)", 0},
    {"<shape type=\"cube\"><bsdf type=\"plastic\"/>\n<emitter type=\"area\"><rgb "
     "name=\"radiance\" value=\"1\"/></emitter></shape>",
     4, "an area emitter on a plastic is not supported", 0},
    {"<shape type=\"cube\"><bsdf type=\"twosided\">\n<bsdf type=\"thindielectric\"/>"
     "</bsdf></shape>",
     4, "twosided around \"thindielectric\" is not supported", 0},
    {"<shape type=\"cube\"><bsdf type=\"conductor\">\n<spectrum name=\"eta\" "
     "value=\"400:1, 700:2\"/></bsdf></shape>",
     4, "a spectral eta is not supported (give an <rgb>)", 0},
    {"<shape type=\"cube\">\n<bsdf type=\"roughplastic\"><float name=\"int_ior\" "
     "value=\"1.3\"/><float name=\"ext_ior\" value=\"1.3\"/></bsdf></shape>",
     4, "int_ior and ext_ior must differ", 0},
    {"<shape type=\"cube\">\n<bsdf type=\"diffuse\">\n<float name=\"foo\" value=\"1\"/>\n"
     "</bsdf></shape>",
     5, "property \"foo\" of bsdf \"diffuse\" is not supported", 0},
    {"<shape type=\"rectangle\"><bsdf type=\"roughdielectric\">\n<texture name=\"alpha\" "
     "type=\"checkerboard\"/></bsdf></shape>",
     4, "a textured alpha is not supported", 0},
    {"<shape type=\"hyperboloid\"/>", 3,
     "shape type \"hyperboloid\" is not supported (supported: obj, ply, serialized, rectangle, "
     "cube, sphere, disk, cylinder)",
     0},
    {"<shape type=\"cylinder\">\n<point name=\"p1\" x=\"0\" y=\"0\" z=\"0\"/></shape>", 3,
     "the cylinder needs a positive radius and p0 != p1", 0},
    {"<emitter type=\"projector\"/>", 3,
     "emitter type \"projector\" is not supported (supported: area on a shape, constant, envmap, "
     "point, spot, directional)",
     0},
    {"<emitter type=\"spot\">\n<texture name=\"texture\" type=\"checkerboard\"/></emitter>"
     "<shape type=\"cube\"/>",
     3, "a spot light's texture is not supported", 0},
    {"<emitter type=\"point\"><point name=\"position\" x=\"1\" y=\"1\" z=\"1\"/>\n"
     "<transform name=\"to_world\"><translate x=\"1\"/></transform></emitter>"
     "<shape type=\"cube\"/>",
     3, "give either position or to_world", 0},
    {"<emitter type=\"envmap\">\n<string name=\"filename\" value=\"sky.png\"/></emitter>", 3,
     "envmap \"sky.png\": only OpenEXR and Radiance HDR maps are supported", 0},
    {"<shape type=\"cube\">\n\n<bsdf type=\"diffuse\"><rgb name=\"reflectance\" value=\"$x\"/>"
     "</bsdf></shape>",
     5, "parameter \"$x\" is not defined", 0},
    {"<shape type=\"cube\">\n<bsdf type=\"diffuse\">\n</shape>", 5, "XML:", 0},
    {"<shape type=\"obj\"><string name=\"filename\" value=\"nowhere.obj\"/></shape>", 3,
     "file \"nowhere.obj\" not found", 0},
    {"<include filename=\"main.xml\"/>", 3, "nested more than 16 deep", 0},
    {"<texture type=\"mesh_attribute\" id=\"t\"/>\n<shape type=\"rectangle\"><bsdf "
     "type=\"diffuse\"><ref name=\"reflectance\" id=\"t\"/></bsdf></shape>",
     3, "texture type \"mesh_attribute\" is not supported (supported: checkerboard, bitmap)", 0},
    {"<texture type=\"bitmap\" id=\"t\"/>\n<shape type=\"rectangle\"><bsdf type=\"diffuse\">"
     "<ref name=\"reflectance\" id=\"t\"/></bsdf></shape>",
     3, "the bitmap needs a filename", 0},
    {"<shape type=\"rectangle\"><bsdf type=\"diffuse\">\n<texture type=\"bitmap\" "
     "name=\"reflectance\"><string name=\"filename\" value=\"a.png\"/><string "
     "name=\"filter_type\" value=\"ewa\"/></texture></bsdf></shape>",
     4, "filter_type \"ewa\" is not supported (bilinear, nearest)", 0},
    {"<shape type=\"rectangle\"><bsdf type=\"diffuse\">\n<texture type=\"bitmap\" "
     "name=\"reflectance\"><string name=\"filename\" value=\"nowhere.png\"/></texture>"
     "</bsdf></shape>",
     4, "file \"nowhere.png\" not found", 0},
    {"<shape type=\"cube\"><bsdf type=\"diffuse\"><texture type=\"checkerboard\" "
     "name=\"reflectance\"/></bsdf></shape>",
     3, "a texture on a cube shape is not supported", 0},
    {"<shape type=\"rectangle\"><emitter type=\"area\"><texture type=\"checkerboard\" "
     "name=\"radiance\"/></emitter></shape>",
     3, "a texture for \"radiance\" is not supported", 0},
    {"<shape type=\"rectangle\"><transform name=\"to_world\"><translate z=\"9.995\"/>"
     "</transform></shape>",
     3, "near_clip", 0},
    {"<integrator type=\"volpath\"/>", 3,
     "integrator type \"volpath\" is not supported (supported: path, direct)", 0},
    {"<integrator type=\"direct\"><integer name=\"shading_samples\" value=\"2\"/>"
     "<integer name=\"bsdf_samples\" value=\"1\"/></integrator>\n<shape type=\"cube\"/>",
     3, "give either shading_samples or emitter_samples/bsdf_samples", 0},
    {"<integrator type=\"direct\"><integer name=\"shading_samples\" value=\"0\"/>"
     "</integrator>\n<shape type=\"cube\"/>",
     3, "emitter_samples and bsdf_samples cannot both be 0", 0},
    {"<integrator type=\"direct\"><integer name=\"emitter_samples\" value=\"65\"/>"
     "</integrator>\n<shape type=\"cube\"/>",
     3, "emitter_samples = 65 is out of range [0, 64]", 0},
    {"<sensor type=\"perspective\">\n<float name=\"fov\" value=\"abc\"/></sensor>", 4,
     "\"abc\" is not a number", 1},
    {"<sensor type=\"perspective\"><float name=\"fov\" value=\"40\"/>\n"
     "<film type=\"hdrfilm\"><rfilter type=\"tent\"/></film></sensor>",
     4, "rfilter type \"tent\" is not supported (supported: box, gaussian)", 1},
    {"<sensor type=\"perspective\"><float name=\"fov\" value=\"40\"/>\n<film type=\"hdrfilm\">"
     "<rfilter type=\"gaussian\"><float name=\"stddev\" value=\"9\"/></rfilter></film></sensor>",
     4, "stddev 9 is outside (0, 4]", 1},
    {"<emitter type=\"constant\"/>\n<emitter type=\"constant\"/><shape type=\"cube\"/>", 4,
     "a second environment (constant or envmap) is not supported", 0},
    {"<shape type=\"cube\"/>", 1, "the scene has no <sensor>", 1},
    {"<sensor type=\"perspective\"><float name=\"fov\" value=\"40\"/>\n<film type=\"hdrfilm\">"
     "<integer name=\"width\" value=\"10\"/><integer name=\"crop_offset_x\" value=\"8\"/>"
     "<integer name=\"crop_width\" value=\"5\"/></film></sensor>",
     4, "the crop window (8, 0) 5x576 leaves the 10x576 film", 1},
    {"<sensor type=\"orthographic\">\n<float name=\"fov\" value=\"40\"/>"
     "<film type=\"hdrfilm\"/></sensor>",
     3, "an orthographic sensor has no fov", 1},
    {"<sensor type=\"thinlens\"><float name=\"fov\" value=\"40\"/>\n"
     "<film type=\"hdrfilm\"/></sensor>",
     3, "a thinlens sensor needs aperture_radius > 0", 1},
    {"<shape type=\"sphere\"><boolean name=\"flip_normals\" value=\"true\"/></shape>", 3,
     "flip_normals on a sphere is not supported", 0},
    {"<texture type=\"checkerboard\"/>", 3, "<texture type=\"checkerboard\"> is not supported", 0},
};

/* Every scene outside the subset: refused, naming the file, the line and
 * what is not supported; the process goes on (Check forks: a crash fails). */
START_TEST(refused_with_file_and_line)
{
    const refusal_t *r = &refusals[_i];
    char dir[1024], path[1200], err[VB_ERR_LEN], text[4096], want[1400];
    scratch_dir(dir, sizeof dir, "mitsuba-refusal");
    /* the sensor on line 2, the body from line 3 */
    snprintf(text, sizeof text, "<scene version=\"3.0.0\">\n%s\n%s\n</scene>\n",
             r->no_sensor ? ""
                          : "<sensor type=\"perspective\"><float name=\"fov\" value=\"40\"/>"
                            "<transform name=\"to_world\"><lookat origin=\"0, 0, 10\" "
                            "target=\"0, 0, 0\"/></transform><film type=\"hdrfilm\">"
                            "<rfilter type=\"box\"/></film></sensor>",
             r->body);
    write_file(dir, "main.xml", text);
    snprintf(path, sizeof path, "%s/main.xml", dir);
    cJSON *j = mitsuba_scene_json(path, NULL, 0, err, sizeof err);
    ck_assert_msg(j == NULL, "case %d accepted", _i);
    snprintf(want, sizeof want, "main.xml:%d: ", r->line);
    ck_assert_msg(strstr(err, want) != NULL, "case %d: \"%s\" does not name %s", _i, err, want);
    ck_assert_msg(strstr(err, r->says) != NULL, "case %d: \"%s\" does not say %s", _i, err,
                  r->says);
}
END_TEST

/* A cylinder placed by p0, p1 and radius (Mitsuba's), through the loader:
 * every vertex at the radius from the axis, between the two ends. */
START_TEST(cylinder_placed)
{
    char dir[1024], path[1200], err[VB_ERR_LEN];
    scratch_dir(dir, sizeof dir, "mitsuba-cylinder");
    write_file(dir, "main.xml",
               "<scene version=\"3.0.0\"><sensor type=\"perspective\"><float name=\"fov\" "
               "value=\"40\"/><transform name=\"to_world\"><lookat origin=\"0, 0, 20\" "
               "target=\"0, 0, 0\"/></transform><film type=\"hdrfilm\"/></sensor>"
               "<shape type=\"cylinder\"><float name=\"radius\" value=\"0.5\"/><point name=\"p0\" "
               "x=\"1\" y=\"2\" z=\"3\"/><point name=\"p1\" x=\"1\" y=\"4\" z=\"3\"/>"
               "<transform name=\"to_world\"><translate x=\"1\"/></transform></shape></scene>");
    snprintf(path, sizeof path, "%s/main.xml", dir);
    cJSON *j = mitsuba_scene_json(path, NULL, 0, err, sizeof err);
    ck_assert_msg(j != NULL, "%s", err);
    char *text = cJSON_PrintUnformatted(j);
    cJSON_Delete(j);
    scene_t *s = NULL;
    ck_assert_msg(scene_load_string(text, strlen(text), "cyl", dir, &s, err, sizeof err) == 0, "%s",
                  err);
    cJSON_free(text);
    ck_assert(s->vertex_count > 1000);
    for (size_t v = 0; v < s->vertex_count; v++) {
        vec3_t p = scene_vertex(s, (uint32_t)v);
        /* the axis runs from (2, 2, 3) to (2, 4, 3) */
        float dx = p.x - 2, dz = p.z - 3;
        ck_assert_msg(fabsf(sqrtf(dx * dx + dz * dz) - 0.5f) < 1e-5f && p.y > 2 - 1e-5f &&
                          p.y < 4 + 1e-5f,
                      "vertex %zu at (%g, %g, %g)", v, p.x, p.y, p.z);
    }
    scene_destroy(&s);
}
END_TEST

START_TEST(refused_versions)
{
    char dir[1024], path[1200], err[VB_ERR_LEN];
    scratch_dir(dir, sizeof dir, "mitsuba-version");
    snprintf(path, sizeof path, "%s/old.xml", dir);
    write_file(dir, "old.xml", "<scene version=\"0.6.0\">\n</scene>\n");
    ck_assert(mitsuba_scene_json(path, NULL, 0, err, sizeof err) == NULL);
    ck_assert_msg(strstr(err, "old.xml:1: scene version 0.6.0") != NULL, "%s", err);
    write_file(dir, "old.xml", "<scene>\n</scene>\n");
    ck_assert(mitsuba_scene_json(path, NULL, 0, err, sizeof err) == NULL);
    ck_assert_msg(strstr(err, "has no version") != NULL, "%s", err);
    write_file(dir, "old.xml", "<bsdf version=\"3.0.0\" type=\"diffuse\"/>\n");
    ck_assert(mitsuba_scene_json(path, NULL, 0, err, sizeof err) == NULL);
    ck_assert_msg(strstr(err, "not one <scene>") != NULL, "%s", err);
    const char *bad[] = {"noequals"};
    write_file(dir, "old.xml", "<scene version=\"3.0.0\">\n</scene>\n");
    ck_assert(mitsuba_scene_json(path, bad, 1, err, sizeof err) == NULL);
    ck_assert_msg(strstr(err, "expected name=value") != NULL, "%s", err);
}
END_TEST

/* ---- the gaussian filter and the environment ---------------------------------------- */

static double gauss_mass(double a, double b, double sd)
{
    /* the filter's integral over [a, b], by Simpson's rule on 2,000 steps */
    double r = 4 * sd, bias = exp(-r * r / (2 * sd * sd)), sum = 0, h = (b - a) / 2000;
    for (int i = 0; i <= 2000; i++) {
        double x = a + i * h, f = exp(-x * x / (2 * sd * sd)) - bias;
        sum += (i == 0 || i == 2000 ? 1 : i % 2 ? 4 : 2) * f;
    }
    return sum * h / 3;
}

/* Filter importance sampling: the positions the gaussian filter gives
 * evenly spaced numbers fall in each of 16 bins across [-2, 2] pixels (4
 * stddev) as the filter's own mass there (within 0.5 % of the total);
 * the box filter keeps the number as it is. */
START_TEST(gaussian_filter_samples)
{
    camera_t cam;
    char err[256];
    ck_assert(camera_init(&cam, vec3_make(0, 0, 0), vec3_make(0, 0, 1), vec3_make(0, 1, 0), 40, 8,
                          8, err, sizeof err) == 0);
    for (int i = 0; i < 100; i++)
        ck_assert(camera_filter_pos(&cam, i / 100.0f) == i / 100.0f);
    ck_assert(camera_set_gaussian(&cam, 0.5, err, sizeof err) == 0);
    ck_assert(camera_set_gaussian(&cam, 0, err, sizeof err) == -1);
    enum { N = 200000, BINS = 16 };
    int count[BINS] = {0};
    for (int i = 0; i < N; i++) {
        float x = camera_filter_pos(&cam, (i + 0.5f) / N) - 0.5f;
        ck_assert_msg(x >= -2.0f && x <= 2.0f, "offset %g outside the radius", x);
        int b = (int)((x + 2.0f) / 4.0f * BINS);
        count[b < BINS ? b : BINS - 1]++;
    }
    double total = gauss_mass(-2, 2, 0.5);
    for (int b = 0; b < BINS; b++) {
        double want = gauss_mass(-2 + 4.0 * b / BINS, -2 + 4.0 * (b + 1) / BINS, 0.5) / total;
        ck_assert_msg(fabs((double)count[b] / N - want) < 0.005,
                      "bin %d: %g of the samples, %g "
                      "of the filter",
                      b, (double)count[b] / N, want);
    }
}
END_TEST

static film_t *render_xml_with(const char *rel, const char *const *defs, size_t ndefs, uint32_t spp,
                               scene_integrator_t integrator, rng_sampler_t sampler,
                               scene_t **scene_out);
/* render_xml_with's max_depth instead of the scene's, when not 0 (each
 * test runs in its own process) */
static uint32_t max_depth_override;

static film_t *render_xml(const char *rel, const char *const *defs, size_t ndefs, uint32_t spp,
                          scene_t **scene_out)
{
    /* (scene_integrator_t)-1: the scene's own */
    return render_xml_with(rel, defs, ndefs, spp, (scene_integrator_t)-1, RNG_SAMPLER_SOBOL,
                           scene_out);
}

static film_t *render_xml_with(const char *rel, const char *const *defs, size_t ndefs, uint32_t spp,
                               scene_integrator_t integrator, rng_sampler_t sampler,
                               scene_t **scene_out)
{
    char path[1024], err[VB_ERR_LEN];
    if (rel[0] == '/')
        snprintf(path, sizeof path, "%s", rel);
    else
        tu_root_path(path, sizeof path, rel);
    cJSON *j = mitsuba_scene_json(path, defs, ndefs, err, sizeof err);
    ck_assert_msg(j != NULL, "%s", err);
    char *text = cJSON_PrintUnformatted(j);
    cJSON_Delete(j);
    scene_t *s = NULL;
    ck_assert_msg(scene_load_string(text, strlen(text), rel, ".", &s, err, sizeof err) == 0, "%s",
                  err);
    cJSON_free(text);
    tracer_device_t *dev = NULL;
    tracer_t *t = NULL;
    ck_assert_msg(tracer_device_new(&dev, err, sizeof err) == 0, "%s", err);
    ck_assert_msg(tracer_new(dev, s, &t, err, sizeof err) == 0, "%s", err);
    film_t *f = film_new(s->camera.width, s->camera.height);
    render_settings_t rs;
    memset(&rs, 0, sizeof rs);
    rs.tracer.seed = 3;
    rs.tracer.integrator = (int)integrator < 0 ? s->integrator : integrator;
    rs.tracer.sampler = sampler;
    rs.tracer.max_depth = max_depth_override ? max_depth_override : s->max_depth;
    rs.spp = spp;
    rs.granularity = 32;
    rs.threads = 2;
    rs.progress = PROGRESS_NONE;
    render_summary_t sum;
    ck_assert_msg(render_run(t, f, &rs, &sum, err, sizeof err) == 0, "%s", err);
    ck_assert_uint_eq(film_total_nonfinite(f), 0);
    tracer_destroy(&t);
    tracer_device_destroy(&dev);
    *scene_out = s;
    return f;
}

/* A diffuse plane under a constant environment (next-event estimation
 * toward it, MIS against the bounce, and the rays that leave the scene):
 * every pixel exactly reflectance x radiance, whatever the filter. */
START_TEST(constant_environment)
{
    scene_t *s = NULL;
    film_t *f = render_xml("scenes/mitsuba/furnace-plane.xml", NULL, 0, 256, &s);
    ck_assert(s->has_env && s->env_pick == 1.0f && s->camera.filter == CAMERA_FILTER_GAUSSIAN);
    ck_assert(s->camera.aperture == 0.2f && s->camera.focus_distance == 4.0f); /* a thin lens */
    /* the OBJ's vn read: its triangles are smooth, their normal +z */
    const double want[3] = {0.5, 1.2, 0.35};
    double mean[3] = {0, 0, 0};
    for (uint32_t p = 0; p < 16 * 16; p++) {
        double rgb[3];
        film_mean(f, p, rgb);
        for (int c = 0; c < 3; c++) {
            mean[c] += rgb[c] / 256;
            ck_assert_msg(fabs(rgb[c] / want[c] - 1) < 0.03, "pixel %u channel %d: %g, want %g", p,
                          c, rgb[c], want[c]);
        }
    }
    for (int c = 0; c < 3; c++)
        ck_assert_msg(fabs(mean[c] / want[c] - 1) < 0.003, "mean channel %d: %g, want %g", c,
                      mean[c], want[c]);
    int smooth = 0;
    for (size_t t = 0; t < s->triangle_count; t++)
        smooth += s->tri_smooth[t];
    ck_assert_int_eq(smooth, 2);
    film_destroy(&f);
    scene_destroy(&s);
}
END_TEST

/* Light samples pick emitters as Mitsuba's do: each light with no area,
 * the environment and the emitting triangles together are one emitter
 * each, picked alike (lights.xml: a point, a spot and a directional light,
 * a constant environment, an area light: a fifth each). By power, the spot
 * got 4 % of the samples and the environment half, and our relMSE at equal
 * spp was 2.5x Mitsuba's (bench/RESULTS.md, "Equal time"). */
START_TEST(emitters_picked_as_mitsuba)
{
    char path[1024], err[VB_ERR_LEN];
    tu_root_path(path, sizeof path, "scenes/mitsuba/lights.xml");
    cJSON *j = mitsuba_scene_json(path, NULL, 0, err, sizeof err);
    ck_assert_msg(j != NULL, "%s", err);
    char *text = cJSON_PrintUnformatted(j);
    cJSON_Delete(j);
    scene_t *s = NULL;
    ck_assert_msg(scene_load_string(text, strlen(text), "lights.xml", ".", &s, err, sizeof err) ==
                      0,
                  "%s", err);
    cJSON_free(text);
    ck_assert(s->has_env && s->delta_count == 3 && s->light_count > 0);
    ck_assert_msg(fabsf(s->env_pick - 0.2f) < 1e-7f, "environment %g", s->env_pick);
    /* of the rest, three of four */
    ck_assert_msg(fabsf(s->delta_pick - 0.75f) < 1e-7f, "lights with no area %g", s->delta_pick);
    for (size_t k = 0; k < 3; k++)
        ck_assert_msg(fabs(s->delta_cdf[k] - (k + 1) / 3.0) < 1e-12, "light %zu: cdf %g", k,
                      s->delta_cdf[k]);
    /* and the area light the last fifth: its triangles' area pdfs sum to
     * 0.2 / area over its area */
    double share = 0;
    for (size_t i = 0; i < s->light_count; i++) {
        uint32_t t = s->light_tris[i];
        const uint32_t *vi = s->indices + 3 * t;
        vec3_t a = scene_vertex(s, vi[0]), e1 = vec3_sub(scene_vertex(s, vi[1]), a),
               e2 = vec3_sub(scene_vertex(s, vi[2]), a);
        share += (double)s->tri_light_pdf[t] * 0.5 * (double)vec3_length(vec3_cross(e1, e2));
    }
    ck_assert_msg(fabs(share - 0.2) < 1e-5, "area light %g", share);
    scene_destroy(&s);

    /* Veach's lights: each emitting shape (a material of its own) an equal
     * share, whatever its power (by power, the small ones got 0.2 % each,
     * and our relMSE at equal spp was 6.5-8x Mitsuba's) */
    tu_root_path(path, sizeof path, "scenes/mitsuba/veach-mis.xml");
    j = mitsuba_scene_json(path, NULL, 0, err, sizeof err);
    ck_assert_msg(j != NULL, "%s", err);
    text = cJSON_PrintUnformatted(j);
    cJSON_Delete(j);
    ck_assert_msg(
        scene_load_string(text, strlen(text), "veach-mis.xml", ".", &s, err, sizeof err) == 0, "%s",
        err);
    cJSON_free(text);
    double by_material[64] = {0};
    ck_assert(s->material_count <= 64);
    for (size_t i = 0; i < s->light_count; i++) {
        uint32_t t = s->light_tris[i];
        const uint32_t *vi = s->indices + 3 * t;
        vec3_t a = scene_vertex(s, vi[0]), e1 = vec3_sub(scene_vertex(s, vi[1]), a),
               e2 = vec3_sub(scene_vertex(s, vi[2]), a);
        by_material[s->tri_material[t]] +=
            (double)s->tri_light_pdf[t] * 0.5 * (double)vec3_length(vec3_cross(e1, e2));
    }
    int emitters = 0;
    for (size_t k = 0; k < s->material_count; k++)
        emitters += by_material[k] > 0;
    ck_assert_int_eq(emitters, 5);
    for (size_t k = 0; k < s->material_count; k++)
        if (by_material[k] > 0)
            ck_assert_msg(fabs(by_material[k] - 0.2) < 1e-4, "emitter material %zu: %g", k,
                          by_material[k]);
    scene_destroy(&s);
}
END_TEST

/* Mitsuba's spheres are tessellated by the pixels they span: the fewest
 * subdivisions whose gap to the true sphere is at most 1/64 of a pixel
 * where the sphere is nearest the eye (a pixel's angle at the image's
 * corner, or an orthographic pixel's width) and at most 2e-3 of the
 * radius (a sphere under a pixel still shows its area to 0.4 %), and at
 * most 6 (81,920 triangles). Veach's five lights at 32 and at 1024
 * pixels, and the orthographic view's sphere at 32 and 2048. */
static int subdivisions_wanted(double pixels)
{
    int n = 0;
    while (n < 6 && (pixels * scene_icosphere_gap(n) > 1.0 / 64 || scene_icosphere_gap(n) > 2e-3))
        n++;
    return n;
}

START_TEST(spheres_tessellated_by_pixels)
{
    static const struct {
        const char *scene, *res;
        int least, most; /* the spheres' fewest and most subdivisions */
    } cases[] = {{"scenes/mitsuba/veach-mis.xml", "res=32", 4, 4},
                 {"scenes/mitsuba/veach-mis.xml", "res=1024", 4, 6},
                 {"scenes/mitsuba/ortho.xml", "res=32", 4, 4},
                 {"scenes/mitsuba/ortho.xml", "res=2048", 6, 6}};
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++) {
        char path[1024], err[VB_ERR_LEN];
        tu_root_path(path, sizeof path, cases[c].scene);
        const char *defs[] = {cases[c].res};
        cJSON *j = mitsuba_scene_json(path, defs, 1, err, sizeof err);
        ck_assert_msg(j != NULL, "%s", err);
        const cJSON *cam = get(j, "camera");
        double h = get(cam, "height")->valuedouble, w = get(cam, "width")->valuedouble;
        const cJSON *ortho = cJSON_GetObjectItemCaseSensitive(cam, "orthographic");
        double eye[3], tan_v = 0, pixel_width = 0;
        for (int k = 0; k < 3; k++)
            eye[k] = num_at(get(cam, "position"), k);
        if (ortho)
            pixel_width = 2 * num_at(ortho, 1) / h;
        else
            tan_v = tan(get(cam, "fov")->valuedouble * M_PI / 360);
        double pixel_angle = 2 * tan_v / h / (1 + tan_v * tan_v * (1 + (w / h) * (w / h)));
        int least = 99, most = -1, spheres = 0;
        const cJSON *sh;
        cJSON_ArrayForEach(sh, get(j, "shapes"))
        {
            if (strcmp(get(sh, "type")->valuestring, "sphere") != 0)
                continue;
            /* (placed by center and radius alone: the matrix is the identity) */
            const cJSON *m = get(get(sh, "transform"), "matrix");
            for (int e = 0; e < 16; e++)
                ck_assert(num_at(m, e) == (e % 5 == 0 ? 1 : 0));
            double r = get(sh, "radius")->valuedouble, dist = 0;
            for (int k = 0; k < 3; k++) {
                double d = num_at(get(sh, "center"), k) - eye[k];
                dist += d * d;
            }
            double pixels = ortho ? r / pixel_width : r / ((sqrt(dist) - r) * pixel_angle);
            int n = (int)get(sh, "subdivisions")->valuedouble;
            ck_assert_msg(n == subdivisions_wanted(pixels),
                          "%s %s: a sphere of radius %g (%g pixels): %d subdivisions, want %d",
                          cases[c].scene, cases[c].res, r, pixels, n, subdivisions_wanted(pixels));
            least = n < least ? n : least;
            most = n > most ? n : most;
            spheres++;
        }
        ck_assert_int_eq(spheres, strstr(cases[c].scene, "veach") ? 5 : 1);
        ck_assert_int_eq(least, cases[c].least);
        ck_assert_int_eq(most, cases[c].most);
        cJSON_Delete(j);
    }
}
END_TEST

/* An environment map as Mitsuba 3.9.1's envmap reads it: a 4x3 map whose
 * red channel is 1 + column + 10 row, looked up from five directions
 * (Mitsuba's own values: bilinear between pixel centres half a pixel
 * from the seam, rows from pole to pole); and its sampling: the mean of
 * 1 / pdf over many samples is the sphere's 4 pi, and of L / pdf the
 * integral of L, which a fine grid of lookups gives. */
START_TEST(environment_map_as_mitsuba)
{
    char exr[1024], err[VB_ERR_LEN], json[2048];
    image_t *img = image_new(4, 3);
    float *r = image_add_channel(img, "R"), *g = image_add_channel(img, "G"),
          *b = image_add_channel(img, "B");
    for (int j = 0; j < 3; j++)
        for (int i = 0; i < 4; i++) {
            r[j * 4 + i] = (float)(1 + i + 10 * j);
            g[j * 4 + i] = b[j * 4 + i] = 1;
        }
    tu_tmp_path(exr, sizeof exr, "env43.exr");
    ck_assert_msg(image_write_exr(img, exr, err, sizeof err) == 0, "%s", err);
    image_destroy(&img);
    snprintf(json, sizeof json,
             "{\"camera\": {\"position\": [0, 0, 5], \"look_at\": [0, 0, 0], \"fov\": 30, "
             "\"width\": 4, \"height\": 4}, \"environment\": {\"map\": \"%s\"},"
             " \"materials\": {\"m\": {\"type\": \"diffuse\", \"albedo\": [0.5, 0.5, 0.5]}},"
             " \"shapes\": [{\"type\": \"quad\", \"material\": \"m\", \"vertices\": [[0, 0, 0], "
             "[1, 0, 0], [1, 1, 0], [0, 1, 0]]}]}",
             exr);
    scene_t *s = NULL;
    ck_assert_msg(scene_load_string(json, strlen(json), "env.json", ".", &s, err, sizeof err) == 0,
                  "%s", err);
    ck_assert(s->has_env && s->env_map && s->env_pick == 1.0f);
    static const double dirs[][4] = {{0, 0, -1, 12.5},
                                     {1, 0, 0, 11.5},
                                     {0, 0.5, -0.8660254, 9.1667},
                                     {-0.3, -0.4, 0.866, 15.3322},
                                     {0.1, 0.9, 0.42, 5.1987}};
    for (int k = 0; k < 5; k++) {
        double l =
            sqrt(dirs[k][0] * dirs[k][0] + dirs[k][1] * dirs[k][1] + dirs[k][2] * dirs[k][2]);
        vec3_t d =
            vec3_make((float)(dirs[k][0] / l), (float)(dirs[k][1] / l), (float)(dirs[k][2] / l));
        float got = lights_env_radiance(s, d).x;
        ck_assert_msg(fabs(got - dirs[k][3]) < 2e-3 * dirs[k][3], "direction %d: %g, Mitsuba %g", k,
                      got, dirs[k][3]);
    }
    /* sampling against the density it reports */
    double inv_pdf = 0, l_over_pdf = 0;
    int off = 0;
    enum { N = 400000 };
    for (int i = 0; i < N; i++) {
        float pdf;
        double u1 = (i + 0.5) / N;
        float u2 = (float)(((uint64_t)i * 0x9e3779b97f4a7c15ULL >> 40) * 0x1.0p-24);
        vec3_t rad;
        vec3_t d = lights_env_sample(s, u1, u2, &pdf, &rad);
        ck_assert_msg(pdf > 0 && fabs(vec3_length(d) - 1) < 1e-5, "sample %d: pdf %g", i, pdf);
        /* the sample reads the cell it picked; going back from d finds it
         * again, but for rounding: near a pole, where d's azimuth is
         * mostly rounding, and beside the sun's pixel, where a 1e-6 shift
         * moves the bilinear value by 0.1 % */
        off += fabs(lights_env_pdf(s, d) / pdf - 1) > 1e-3 ||
               fabs(lights_env_radiance(s, d).x / rad.x - 1) > 1e-3;
        inv_pdf += 1.0 / pdf / N;
        l_over_pdf += rad.x / pdf / N;
    }
    ck_assert_msg(off < N / 10000, "%d of %d samples off the lookup of their direction", off, N);
    double integral = 0;
    enum { T = 600, P = 1200 };
    for (int t = 0; t < T; t++)
        for (int q = 0; q < P; q++) {
            double th = (t + 0.5) / T * M_PI, ph = (q + 0.5) / P * 2 * M_PI;
            vec3_t d =
                vec3_make((float)(sin(th) * cos(ph)), (float)cos(th), (float)(sin(th) * sin(ph)));
            integral += lights_env_radiance(s, d).x * sin(th) * (M_PI / T) * (2 * M_PI / P);
        }
    ck_assert_msg(fabs(inv_pdf / (4 * M_PI) - 1) < 0.01, "mean 1 / pdf %g, want 4 pi", inv_pdf);
    ck_assert_msg(fabs(l_over_pdf / integral - 1) < 0.01, "mean L / pdf %g, integral %g",
                  l_over_pdf, integral);
    scene_destroy(&s);
}
END_TEST

/* Each light's next-event estimation, MIS-weighted against the bounce
 * (the path integrator), against the bounce alone (naive: light counted
 * only where a path hits it): the same image within 5 sigma, over the
 * whole image and each quadrant, on the shipped scenes that have an area
 * light and a constant environment (checker.xml) and an environment map
 * with a sun (envmap.xml). Independent samples: the variance of a mean is
 * then the pixels' own. */
/* (not lights.xml: no bounce finds a light with no area; test_tracer's
 * delta_lights_exact checks those against their closed forms) */
static const char *const mis_scenes[] = {"scenes/mitsuba/checker.xml", "scenes/mitsuba/envmap.xml",
                                         "scenes/mitsuba/materials.xml"};

/* Two 16x16 renders of one image by different estimators agree within 5
 * sigma over the image and each quadrant; and the test can tell: over the
 * image (and over each quadrant when quadrants_tell), 5 sigma is below
 * `tell` of the mean. */
static void films_agree(const film_t *a, const film_t *b, const char *what, double tell,
                        int quadrants_tell)
{
    double m[2][5] = {{0}}, v[2][5] = {{0}};
    for (int which = 0; which < 2; which++)
        for (uint32_t p = 0; p < 16 * 16; p++) {
            double rgb[3];
            film_mean(which ? b : a, p, rgb);
            double lum = 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2];
            double var = film_variance_of_mean(which ? b : a, p);
            int q = (int)((p / 16) / 8 * 2 + (p % 16) / 8);
            m[which][q] += lum;
            v[which][q] += var;
            m[which][4] += lum;
            v[which][4] += var;
        }
    for (int q = 0; q < 5; q++) {
        double sigma = sqrt(v[0][q] + v[1][q]);
        ck_assert_msg(fabs(m[0][q] - m[1][q]) <= 5 * sigma, "%s, %s: %g against %g, 5 sigma %g",
                      what, q < 4 ? "a quadrant" : "the image", m[0][q], m[1][q], 5 * sigma);
        ck_assert_msg((q < 4 && !quadrants_tell) || 5 * sigma < tell * m[0][q],
                      "%s: sigma %g too wide for mean %g", what, sigma, m[0][q]);
    }
}

START_TEST(mis_agrees_with_bsdf_sampling)
{
    const char *defs[] = {"res=16"};
    scene_t *s1 = NULL, *s2 = NULL;
    film_t *path = render_xml_with(mis_scenes[_i], defs, 1, 4096, SCENE_INTEGRATOR_PATH,
                                   RNG_SAMPLER_INDEPENDENT, &s1);
    film_t *naive = render_xml_with(mis_scenes[_i], defs, 1, 4096, SCENE_INTEGRATOR_NAIVE,
                                    RNG_SAMPLER_INDEPENDENT, &s2);
    char what[256];
    snprintf(what, sizeof what, "%s: MIS against BSDF sampling alone", mis_scenes[_i]);
    films_agree(path, naive, what, 0.2, 1);
    film_destroy(&path);
    film_destroy(&naive);
    scene_destroy(&s1);
    scene_destroy(&s2);
}
END_TEST

/* The direct integrator (Mitsuba's `direct`) against the path integrator
 * cut to one bounce (max_depth 2: what the camera sees emitting, and light
 * reflected once), which estimate the same image: with light samples and
 * BSDF samples MIS-weighted (2 and 2, 2 and 3), light samples alone, BSDF
 * samples alone, within 5 sigma over the image and each quadrant, on
 * Veach's scene (scenes/mitsuba/veach-mis.xml: plates from alpha 0.005
 * to 0.1, lights from radius 0.033 to 0.9). One and one is traced as that
 * path (direct_one_and_one_is_the_path). */
static const struct {
    const char *emitter, *bsdf;
    uint32_t spp; /* light samples alone need the most */
} direct_defs[] = {{"emitter_samples=2", "bsdf_samples=2", 2048},
                   {"emitter_samples=2", "bsdf_samples=3", 2048},
                   {"emitter_samples=1", "bsdf_samples=0", 8192},
                   {"emitter_samples=0", "bsdf_samples=1", 2048}};

START_TEST(direct_agrees_with_one_bounce)
{
    const char *defs[] = {"res=16", direct_defs[_i].emitter, direct_defs[_i].bsdf};
    uint32_t spp = direct_defs[_i].spp;
    scene_t *s1 = NULL, *s2 = NULL;
    film_t *direct = render_xml_with("scenes/mitsuba/veach-mis.xml", defs, 3, spp,
                                     SCENE_INTEGRATOR_DIRECT, RNG_SAMPLER_INDEPENDENT, &s1);
    ck_assert_int_eq(s1->integrator, SCENE_INTEGRATOR_DIRECT);
    max_depth_override = 2;
    film_t *path = render_xml_with("scenes/mitsuba/veach-mis.xml", defs, 3, spp,
                                   SCENE_INTEGRATOR_PATH, RNG_SAMPLER_INDEPENDENT, &s2);
    max_depth_override = 0;
    char what[256];
    snprintf(what, sizeof what, "direct (%s, %s) against the path to depth 2", defs[1], defs[2]);
    /* the image to 7 % (light samples alone on near-mirror plates are
     * Veach's worst case; a quadrant may be wider) */
    films_agree(direct, path, what, 0.35, 0);
    film_destroy(&direct);
    film_destroy(&path);
    scene_destroy(&s1);
    scene_destroy(&s2);
}
END_TEST

/* One light sample and one BSDF sample: the direct integrator is traced
 * as the path integrator cut to two segments (tracer.c, as_traced: the
 * same estimator term for term, which the wavefront engine runs), so the
 * two give the same image bit for bit, under the default sampler. */
START_TEST(direct_one_and_one_is_the_path)
{
    const char *defs[] = {"res=16", "emitter_samples=1", "bsdf_samples=1"};
    scene_t *s1 = NULL, *s2 = NULL;
    film_t *direct = render_xml_with("scenes/mitsuba/veach-mis.xml", defs, 3, 64,
                                     SCENE_INTEGRATOR_DIRECT, RNG_SAMPLER_SOBOL, &s1);
    max_depth_override = 2;
    film_t *path = render_xml_with("scenes/mitsuba/veach-mis.xml", defs, 3, 64,
                                   SCENE_INTEGRATOR_PATH, RNG_SAMPLER_SOBOL, &s2);
    max_depth_override = 0;
    double sum = 0;
    for (uint32_t p = 0; p < 16 * 16; p++) {
        double a[3], b[3];
        film_mean(direct, p, a);
        film_mean(path, p, b);
        for (int c = 0; c < 3; c++)
            ck_assert_msg(a[c] == b[c], "pixel %u channel %d: direct %.9g, path %.9g", p, c, a[c],
                          b[c]);
        sum += a[0] + a[1] + a[2];
    }
    ck_assert(sum > 0);
    film_destroy(&direct);
    film_destroy(&path);
    scene_destroy(&s1);
    scene_destroy(&s2);
}
END_TEST

/* ---- the image, against Mitsuba's ------------------------------------------------- */

static double luminance(const float *r, const float *g, const float *b, size_t i)
{
    return 0.2126 * r[i] + 0.7152 * g[i] + 0.0722 * b[i];
}

/* The shipped scenes at 32x32 against Mitsuba 3.9.1's images of the same
 * files (llvm_ad_rgb, 65,536 spp, tests/data/mitsuba/, made by
 * bench/peer/mitsuba_scene.py): the image mean within 1 % (about 5 sigma
 * of ours at 1,024 spp) and each 8x8 block's within 4 % or 5 sigma of
 * ours, whichever is wider, so a mirrored view, a swapped wall colour, a
 * missing one-sided back, a light facing the wrong way or a texture's
 * pattern off by a cell fails. Measured: means within 0.2 %, blocks
 * within 1 %, but for Veach's scene, whose highlights of tiny lights in
 * near-mirror plates are rare paths under our light selection by power
 * (the largest light takes 99 % of the light samples): blocks within
 * 3.3 % at 8,192 spp over two seeds. */
static const struct {
    const char *scene, *reference;
    uint32_t spp;    /* a bright sun in the map needs more */
    const char *def; /* a parameter beside res=32, or NULL */
} compared[] = {
    {"scenes/mitsuba/cornell-box.xml", "tests/data/mitsuba/cornell-box-32.exr", 1024, NULL},
    {"scenes/mitsuba/checker.xml", "tests/data/mitsuba/checker-32.exr", 1024, NULL},
    {"scenes/mitsuba/envmap.xml", "tests/data/mitsuba/envmap-32.exr", 2048, NULL},
    {"scenes/mitsuba/envmap.xml", "tests/data/mitsuba/envmap-hidden-32.exr", 2048, "hide=true"},
    /* the same map as Mitsuba wrote it in Radiance HDR, read by each */
    {"scenes/mitsuba/envmap.xml", "tests/data/mitsuba/envmap-hdr-32.exr", 2048,
     "map=textures/sky.hdr"},
    {"scenes/mitsuba/ortho.xml", "tests/data/mitsuba/ortho-32.exr", 1024, NULL},
    {"scenes/mitsuba/materials.xml", "tests/data/mitsuba/materials-32.exr", 2048, NULL},
    {"scenes/mitsuba/veach-mis.xml", "tests/data/mitsuba/veach-mis-32.exr", 4096, NULL},
    {"scenes/mitsuba/bitmap.xml", "tests/data/mitsuba/bitmap-32.exr", 1024, NULL},
    {"scenes/mitsuba/lights.xml", "tests/data/mitsuba/lights-32.exr", 2048, NULL},
};

START_TEST(matches_mitsuba)
{
    const char *defs[] = {"res=32", compared[_i].def};
    scene_t *s = NULL;
    film_t *f =
        render_xml(compared[_i].scene, defs, compared[_i].def ? 2 : 1, compared[_i].spp, &s);
    char ref_path[1024], err[VB_ERR_LEN];
    tu_root_path(ref_path, sizeof ref_path, compared[_i].reference);
    image_t *ref = NULL;
    ck_assert_msg(image_read_exr(ref_path, &ref, err, sizeof err) == 0, "%s", err);
    ck_assert_int_eq(ref->width, 32);
    const float *R = image_channel(ref, "R"), *G = image_channel(ref, "G"),
                *B = image_channel(ref, "B");
    ck_assert(R && G && B);
    double block_ours[16] = {0}, block_ref[16] = {0}, block_var[16] = {0}, all_ours = 0,
           all_ref = 0;
    for (uint32_t p = 0; p < 32 * 32; p++) {
        double rgb[3];
        film_mean(f, p, rgb);
        double ours = 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2];
        double theirs = luminance(R, G, B, p);
        int blk = (int)((p / 32) / 8 * 4 + (p % 32) / 8);
        block_ours[blk] += ours;
        block_ref[blk] += theirs;
        block_var[blk] += film_variance_of_mean(f, p);
        all_ours += ours;
        all_ref += theirs;
    }
    ck_assert_msg(fabs(all_ours / all_ref - 1) < 0.01, "%s: image mean %g, Mitsuba's %g",
                  compared[_i].scene, all_ours / 1024, all_ref / 1024);
    for (int b = 0; b < 16; b++)
        /* (a block nearly black, under 0.2 % of the image's mean: compared
         * in absolute terms) */
        ck_assert_msg(
            fabs(block_ours[b] - block_ref[b]) <
                fmax(fmax(0.04 * block_ref[b], 5 * sqrt(block_var[b])), 0.002 * all_ref / 16),
            "%s: block %d (row %d, column %d): mean %g, Mitsuba's %g, 5 sigma %g",
            compared[_i].scene, b, b / 4, b % 4, block_ours[b] / 64, block_ref[b] / 64,
            5 * sqrt(block_var[b]) / 64);
    image_destroy(&ref);
    film_destroy(&f);
    scene_destroy(&s);
}
END_TEST

/* The checkerboard as Mitsuba 3.9.1 evaluates it (its values at these
 * coordinates, to_uv scale 8 and u offset 0.1), through texture_albedo at
 * the corners of a triangle whose coordinates are the triangle's own. */
START_TEST(checkerboard_as_mitsuba)
{
    static const char json[] =
        "{\"camera\": {\"position\": [0, 0, 5], \"look_at\": [0, 0, 0], \"fov\": 30, "
        "\"width\": 4, \"height\": 4},"
        " \"materials\": {\"c\": {\"type\": \"diffuse\", \"albedo\": {\"type\": \"checkerboard\","
        " \"color0\": [0.2, 0.2, 0.2], \"color1\": [0.4, 0.4, 0.4], \"to_uv\": [8, 0, 0.1, 0, 8, "
        "0]}}},"
        " \"shapes\": [{\"type\": \"triangles\", \"material\": \"c\","
        " \"vertices\": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], \"uvs\": [[0, 0], [1, 0], [0, 1]],"
        " \"indices\": [[0, 1, 2]]}]}";
    scene_t *s = NULL;
    char err[VB_ERR_LEN];
    ck_assert_msg(scene_load_string(json, strlen(json), "tex.json", ".", &s, err, sizeof err) == 0,
                  "%s", err);
    ck_assert_uint_eq(s->texture_count, 1);
    ck_assert_ptr_nonnull(s->uvs);
    const material_t *m = &s->materials[0];
    /* (u, v) = barycentrics = texture coordinates here; Mitsuba's answers */
    static const float at[][3] = {{0.01f, 0.01f, 0.2f}, {0.07f, 0.01f, 0.4f}, {0.01f, 0.07f, 0.4f},
                                  {0.07f, 0.07f, 0.2f}, {0.1f, 0.2f, 0.2f},   {0.051f, 0.0f, 0.4f}};
    for (size_t k = 0; k < sizeof at / sizeof at[0]; k++) {
        vec3_t a = texture_albedo(s, m, 0, at[k][0], at[k][1]);
        ck_assert_msg(a.x == at[k][2], "(%g, %g): %g, Mitsuba says %g", at[k][0], at[k][1], a.x,
                      at[k][2]);
    }
    /* an untextured material is its albedo */
    material_t plain = *m;
    plain.albedo_texture = -1;
    plain.albedo = vec3_make(0.3f, 0.3f, 0.3f);
    ck_assert(texture_albedo(s, &plain, 0, 0.5f, 0.5f).y == 0.3f);
    scene_destroy(&s);
}
END_TEST

/* Mitsuba's crop window: the Cornell box's film cut to (8, 4) 16x20 at
 * 32x32 draws that window of Mitsuba's full image (its reference),
 * blocks of 4x4 within 4 % or 5 sigma. */
START_TEST(crop_window)
{
    char dir[1024], src[1024], path[1200], text[16384], root[1024];
    scratch_dir(dir, sizeof dir, "mitsuba-crop");
    tu_root_path(src, sizeof src, "scenes/mitsuba/cornell-box.xml");
    tu_root_path(root, sizeof root, "scenes/mitsuba");
    FILE *f = fopen(src, "rb");
    ck_assert_ptr_nonnull(f);
    size_t n = fread(text, 1, sizeof text - 1, f);
    fclose(f);
    text[n] = '\0';
    char out[20000];
    const char *scene = strstr(text, "<scene version=\"3.0.0\">"),
               *film = strstr(text, "<integer name=\"width\"");
    ck_assert(scene && film && scene < film);
    scene += strlen("<scene version=\"3.0.0\">");
    snprintf(out, sizeof out,
             "%.*s\n<path value=\"%s\"/>%.*s<integer name=\"crop_offset_x\" value=\"8\"/>"
             "<integer name=\"crop_offset_y\" value=\"4\"/><integer name=\"crop_width\" "
             "value=\"16\"/><integer name=\"crop_height\" value=\"20\"/>\n%s",
             (int)(scene - text), text, root, (int)(film - scene), scene, film);
    write_file(dir, "crop.xml", out);
    snprintf(path, sizeof path, "%s/crop.xml", dir);
    const char *defs[] = {"res=32"};
    scene_t *s = NULL;
    film_t *fm = render_xml_with(path, defs, 1, 2048, SCENE_INTEGRATOR_PATH, RNG_SAMPLER_SOBOL, &s);
    ck_assert(s->camera.width == 16 && s->camera.height == 20 && s->camera.film_width == 32);
    char ref_path[1024], err[VB_ERR_LEN];
    tu_root_path(ref_path, sizeof ref_path, "tests/data/mitsuba/cornell-box-32.exr");
    image_t *ref = NULL;
    ck_assert_msg(image_read_exr(ref_path, &ref, err, sizeof err) == 0, "%s", err);
    const float *R = image_channel(ref, "R"), *G = image_channel(ref, "G"),
                *B = image_channel(ref, "B");
    for (int by = 0; by < 5; by++)
        for (int bx = 0; bx < 4; bx++) {
            double ours = 0, theirs = 0, var = 0;
            for (int y = 4 * by; y < 4 * by + 4; y++)
                for (int x = 4 * bx; x < 4 * bx + 4; x++) {
                    double rgb[3];
                    film_mean(fm, (uint32_t)(y * 16 + x), rgb);
                    ours += 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2];
                    var += film_variance_of_mean(fm, (uint32_t)(y * 16 + x));
                    theirs += luminance(R, G, B, (size_t)((y + 4) * 32 + x + 8));
                }
            ck_assert_msg(fabs(ours - theirs) < fmax(0.04 * theirs, 5 * sqrt(var)),
                          "block (%d, %d): %g, Mitsuba's %g", bx, by, ours / 16, theirs / 16);
        }
    image_destroy(&ref);
    film_destroy(&fm);
    scene_destroy(&s);
}
END_TEST

static Suite *mitsuba_suite(void)
{
    Suite *su = suite_create("mitsuba");
    TCase *tc = tcase_create("convert");
    tcase_add_test(tc, spectrum_as_mitsuba);
    tcase_add_test(tc, shipped_scene);
    tcase_add_test(tc, scene_load_either_kind);
    tcase_add_test(tc, structure);
    tcase_add_loop_test(tc, refused_with_file_and_line, 0,
                        (int)(sizeof refusals / sizeof refusals[0]));
    tcase_add_test(tc, refused_versions);
    tcase_add_test(tc, emitters_picked_as_mitsuba);
    tcase_add_test(tc, gaussian_filter_samples);
    tcase_add_test(tc, checkerboard_as_mitsuba);
    tcase_add_test(tc, environment_map_as_mitsuba);
    tcase_add_test(tc, spheres_tessellated_by_pixels);
    suite_add_tcase(su, tc);
    tc = tcase_create("image");
    tcase_add_test(tc, constant_environment);
    tcase_add_loop_test(tc, mis_agrees_with_bsdf_sampling, 0,
                        (int)(sizeof mis_scenes / sizeof mis_scenes[0]));
    tcase_set_timeout(tc, 120);
    tcase_add_loop_test(tc, matches_mitsuba, 0, (int)(sizeof compared / sizeof compared[0]));
    tcase_add_test(tc, cylinder_placed);
    tcase_add_test(tc, crop_window);
    tcase_add_test(tc, direct_one_and_one_is_the_path);
    tcase_add_loop_test(tc, direct_agrees_with_one_bounce, 0,
                        (int)(sizeof direct_defs / sizeof direct_defs[0]));
    suite_add_tcase(su, tc);
    return su;
}

int main(void)
{
    SRunner *sr = srunner_create(mitsuba_suite());
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed == 0 ? EXIT_SUCCESS : EXIT_FAILURE;
}
