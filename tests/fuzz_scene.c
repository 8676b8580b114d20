/* fuzz_scene.c - fuzz target for the scene loader (common/scene.c): a scene
 * JSON file as scene_load_bundle reads it, which is how workers and the
 * master load every submitted scene.
 *
 * An input is the JSON text. Its mesh "file" fields resolve against three
 * fixed mesh files held in memory (tri.obj, quad.ply with normals, and a
 * binary bin.ply): the mesh readers have their own target (fuzz_mesh), so
 * here they only have to load. LLVMFuzzerTestOneInput aborts if a result
 * breaks the API's promises: on failure *out NULL and a message; on
 * success a resolution in bounds, at least one triangle, indices and
 * materials in range, finite positions, unit geometric normals, light
 * probabilities and a light CDF that make sense. Build with -DVB_LIBFUZZER
 * and -fsanitize=fuzzer for libFuzzer.
 *
 * Without VB_LIBFUZZER the standalone driver (fuzzdriver.h) runs it:
 *
 *     fuzz_scene CORPUS_DIR N      (tests/data/fuzz-scene)
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "scene.h"

static const char tri_obj[] = "# one triangle\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
static const char quad_ply[] =
    "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
    "property float z\nproperty float nx\nproperty float ny\nproperty float nz\n"
    "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
    "0 0 0 0 0 1\n1 0 0 0 0 1\n1 1 0 0 0 1\n0 1 0 0 0 1\n4 0 1 2 3\n";
/* binary little endian: 3 float vertices, one uchar/uint triangle */
static const unsigned char bin_ply[] =
    "ply\nformat binary_little_endian 1.0\nelement vertex 3\n"
    "property float x\nproperty float y\nproperty float z\n"
    "element face 1\nproperty list uchar uint vertex_indices\nend_header\n"
    "\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00"
    "\x00\x00\x80\x3f\x00\x00\x00\x00\x00\x00\x00\x00"
    "\x00\x00\x00\x00\x00\x00\x80\x3f\x00\x00\x00\x00"
    "\x03\x00\x00\x00\x00\x01\x00\x00\x00\x02\x00\x00\x00";

/* Checks a result of scene_load_bundle; any breach is a bug, so abort. */
static void check_result(int r, const scene_t *s, const char *err)
{
    if (r != 0) {
        if (r != -1 || s != NULL || err[0] == '\0')
            abort();
        return;
    }
    if (!s || s->triangle_count == 0 || s->material_count == 0 || !s->positions || !s->indices)
        abort();
    const camera_t *c = &s->camera;
    if (c->width < 1 || c->height < 1 || c->width > SCENE_MAX_SIDE || c->height > SCENE_MAX_SIDE ||
        (uint64_t)c->width * (uint64_t)c->height > SCENE_MAX_PIXELS || s->spp < 1)
        abort();
    if (s->warning_count < 0 || s->warning_count > SCENE_MAX_WARNINGS)
        abort();
    for (size_t i = 0; i < 3 * s->vertex_count; i++)
        if (!isfinite(s->positions[i]))
            abort();
    for (size_t t = 0; t < s->triangle_count; t++) {
        for (int k = 0; k < 3; k++)
            if (s->indices[3 * t + (size_t)k] >= s->vertex_count)
                abort();
        if (s->tri_material[t] >= s->material_count)
            abort();
        vec3_t n = s->tri_normal[t];
        double len = sqrt((double)n.x * n.x + (double)n.y * n.y + (double)n.z * n.z);
        if (!(fabs(len - 1.0) < 1e-3) || !(s->tri_light_pdf[t] >= 0))
            abort();
    }
    double prev = 0;
    for (size_t l = 0; l < s->light_count; l++) {
        if (s->light_tris[l] >= s->triangle_count || !(s->light_cdf[l] >= prev) ||
            !(s->light_cdf[l] <= 1))
            abort();
        prev = s->light_cdf[l];
    }
    if (s->light_count && s->light_cdf[s->light_count - 1] != 1)
        abort();
}

/* 1 if the scene loaded, 0 if it was refused. */
static int run_one(const uint8_t *data, size_t size)
{
    const scene_blob_t blobs[3] = {
        {"tri.obj", (const unsigned char *)tri_obj, sizeof tri_obj - 1},
        {"quad.ply", (const unsigned char *)quad_ply, sizeof quad_ply - 1},
        {"bin.ply", bin_ply, sizeof bin_ply - 1},
    };
    char err[512];
    err[0] = '\0';
    scene_t *s = NULL;
    int r = scene_load_bundle((const char *)data, size, "fuzz.json", blobs, 3, &s, err, sizeof err);
    check_result(r, s, err);
    scene_destroy(&s);
    return r == 0;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    run_one(data, size);
    return 0;
}

#ifndef VB_LIBFUZZER

#include "fuzzdriver.h"

static void mutate(fuzz_buf_t *b, uint64_t *s)
{
    static const char *const numbers[] = {
        "0",       "1",     "2",      "7",       "8",          "-1",         "-0",
        "0.5",     "1e999", "-1e999", "1e-400",  "1e30",       "1e31",       "1e-30",
        "1e-31",   "3e38",  "3.5e38", "179.999", "180",        "0.125",      "8",
        "8.01",    "16384", "16385",  "8192",    "4294967295", "4294967296", "9007199254740993",
        "1000001", "1e300", "nan",
    };
    static const char *const tokens[] = {
        "\"",
        ",",
        ":",
        "{",
        "}",
        "[",
        "]",
        "null",
        "true",
        "false",
        "\"\"",
        "[]",
        "{}",
        "[0,0,0]",
        "[1,1,1]",
        "\"type\":\"sphere\",",
        "\"type\":\"mesh\",",
        "\"type\":\"triangles\",",
        "\"type\":\"quad\",",
        "\"file\":\"tri.obj\",",
        "\"file\":\"quad.ply\",",
        "\"file\":\"bin.ply\",",
        "\"file\":\"nope.obj\",",
        "\"transform\":{\"scale\":[1,-1,1]},",
        "\"rotate\":[0,90,0],",
        "\"subdivisions\":",
        "\"type\":\"emitter\",",
        "\"type\":\"dielectric\",",
        "\"type\":\"mirror\",",
        "\"radiance\":",
        "\"albedo\":",
        "\"ior\":",
        "\"indices\":[[0,1,2]],",
        "\"comment\":\"c\",",
        "\"albdo\":1,",
    };
    unsigned kind = (unsigned)(fuzz_rnd(s) % 9);
    if (fuzz_mutate_shared(b, s, kind, tokens, sizeof tokens / sizeof tokens[0]))
        return;
    switch (kind) {
    default:
        fuzz_replace_number(b, s, numbers, sizeof numbers / sizeof numbers[0]);
        break;
    }
}

int main(int argc, char **argv)
{
    static const fuzz_target_t target = {"fuzz_scene", run_one,          mutate,
                                         NULL,         {"loaded", NULL}, "-scene"};
    return fuzz_main(argc, argv, &target);
}

#endif /* VB_LIBFUZZER */
