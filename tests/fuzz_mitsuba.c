/* fuzz_mitsuba.c - fuzz target for the Mitsuba scene importer
 * (common/mitsuba.c), then the scene loader on what it writes: the path a
 * user's scene.xml takes through `vbrender render` and `submit`.
 *
 * An input is the XML text, written to fuzz.xml in a scratch folder that
 * also holds what a scene may name: inc.xml (an include), meshes/
 * square-vn.obj and square-vt.obj, textures/sky.exr (a 4x3 map).
 * LLVMFuzzerTestOneInput aborts if a result breaks the API's promises: a
 * refusal is NULL with a message naming a file; an accepted scene is a JSON
 * object that scene_load_string either loads (a camera, triangles) or
 * refuses with a message. Build with -DVB_LIBFUZZER and -fsanitize=fuzzer
 * for libFuzzer.
 *
 * Without VB_LIBFUZZER the standalone driver (fuzzdriver.h) runs it:
 *
 *     fuzz_mitsuba CORPUS_DIR N      (tests/data/fuzz-mitsuba)
 */
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "image.h"
#include "mitsuba.h"
#include "scene.h"

static char scratch[256];

static void put(const char *name, const char *text)
{
    char path[512];
    snprintf(path, sizeof path, "%s/%s", scratch, name);
    FILE *f = fopen(path, "wb");
    if (!f)
        abort();
    fputs(text, f);
    fclose(f);
}

static void cleanup(void)
{
    static const char *const files[] = {"fuzz.xml",
                                        "inc.xml",
                                        "meshes/square-vn.obj",
                                        "meshes/square-vt.obj",
                                        "textures/sky.exr",
                                        "meshes",
                                        "textures",
                                        ""};
    for (int i = 0; i < 8; i++) {
        char path[512];
        snprintf(path, sizeof path, "%s/%s", scratch, files[i]);
        remove(path);
    }
}

/* The scratch folder and the files scenes may name, once per process
 * (removed at exit). */
static void setup(void)
{
    if (scratch[0])
        return;
    const char *tmp = getenv("TMPDIR");
    snprintf(scratch, sizeof scratch, "%s/vb-fuzz-mitsuba.XXXXXX", tmp && *tmp ? tmp : "/tmp");
    if (!mkdtemp(scratch))
        abort();
    atexit(cleanup);
    char dir[512];
    snprintf(dir, sizeof dir, "%s/meshes", scratch);
    mkdir(dir, 0700);
    snprintf(dir, sizeof dir, "%s/textures", scratch);
    mkdir(dir, 0700);
    put("inc.xml", "<scene version=\"3.0.0\"><bsdf type=\"diffuse\" id=\"inc\">"
                   "<rgb name=\"reflectance\" value=\"0.3\"/></bsdf></scene>\n");
    put("meshes/square-vn.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\n"
                                "f 1//1 2//1 3//1\nf 1//1 3//1 4//1\n");
    put("meshes/square-vt.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\n"
                                "vt 1 1\nvt 0 1\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n");
    image_t *img = image_new(4, 3);
    const char *names[3] = {"R", "G", "B"};
    for (int c = 0; c < 3; c++) {
        float *p = image_add_channel(img, names[c]);
        for (int i = 0; i < 12; i++)
            p[i] = (float)(1 + i + c);
    }
    char path[512], err[256];
    snprintf(path, sizeof path, "%s/textures/sky.exr", scratch);
    if (!img || image_write_exr(img, path, err, sizeof err) != 0)
        abort();
    image_destroy(&img);
}

/* 1 if the scene converted and loaded, 0 if refused. */
static int run_one(const uint8_t *data, size_t size)
{
    setup();
    char path[512], err[1024];
    snprintf(path, sizeof path, "%s/fuzz.xml", scratch);
    FILE *f = fopen(path, "wb");
    if (!f || fwrite(data, 1, size, f) != size)
        abort();
    fclose(f);
    static const char *const defines[] = {"spp=4", "res=8"};
    err[0] = '\0';
    cJSON *j = mitsuba_scene_json(path, defines, 2, err, sizeof err);
    if (!j) {
        /* a refusal names a file: this one, or one it names */
        if (!err[0] || !strchr(err, ':'))
            abort();
        return 0;
    }
    if (!cJSON_IsObject(j))
        abort();
    char *text = cJSON_PrintUnformatted(j);
    cJSON_Delete(j);
    if (!text)
        abort();
    scene_t *s = NULL;
    err[0] = '\0';
    int r = scene_load_string(text, strlen(text), "fuzz.xml", scratch, &s, err, sizeof err);
    cJSON_free(text);
    if (r != 0) {
        if (s || !err[0])
            abort();
        return 0;
    }
    if (!s || s->triangle_count == 0 || s->camera.width < 1 || s->camera.height < 1)
        abort();
    scene_destroy(&s);
    return 1;
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
    static const char *const tokens[] = {
        "<",
        ">",
        "/>",
        "\"",
        "=",
        "</shape>",
        "</bsdf>",
        "<shape type=\"rectangle\">",
        "<shape type=\"cube\">",
        "<shape type=\"obj\"><string name=\"filename\" value=\"meshes/square-vt.obj\"/>",
        "<bsdf type=\"diffuse\">",
        "<bsdf type=\"dielectric\">",
        "<bsdf type=\"twosided\">",
        "<emitter type=\"area\"><rgb name=\"radiance\" value=\"5\"/></emitter>",
        "<emitter type=\"constant\"/>",
        "<emitter type=\"envmap\"><string name=\"filename\" value=\"textures/sky.exr\"/>"
        "</emitter>",
        "<texture type=\"checkerboard\" name=\"reflectance\"/>",
        "<ref id=\"inc\"/>",
        "<include filename=\"inc.xml\"/>",
        "<include filename=\"fuzz.xml\"/>",
        "<default name=\"x\" value=\"1\"/>",
        "$x",
        "$spp",
        "<transform name=\"to_world\"><scale value=\"2\"/></transform>",
        "<rotate x=\"1\" angle=\"90\"/>",
        "<matrix value=\"1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\"/>",
        "<lookat origin=\"0,0,5\" target=\"0,0,0\"/>",
        "<rfilter type=\"gaussian\"/>",
        "<spectrum name=\"reflectance\" value=\"400:0.5, 700:0.6\"/>",
        "<float name=\"fov\" value=\"1e999\"/>",
        "<integer name=\"width\" value=\"-1\"/>",
        "0",
        "-1",
        "1e30",
        "nan",
    };
    unsigned kind = (unsigned)(fuzz_rnd(s) % 8);
    fuzz_mutate_shared(b, s, kind, tokens, sizeof tokens / sizeof tokens[0]);
}

int main(int argc, char **argv)
{
    static const fuzz_target_t target = {"fuzz_mitsuba", run_one,          mutate,
                                         NULL,           {"loaded", NULL}, "-mitsuba"};
    return fuzz_main(argc, argv, &target);
}

#endif /* VB_LIBFUZZER */
