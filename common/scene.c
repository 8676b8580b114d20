/* scene.c - the JSON scene loader (see scene.h and scenes/README.md).
 *
 * cJSON parses; this file checks every field and flattens shapes into one
 * world-space triangle list. Errors carry "FILE: json.path: message", built
 * where the decision is made; the loader owns everything it allocates until
 * it hands the finished scene over.
 */
#include "scene.h"

#include <cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "bitmap.h"
#include "image.h"
#include "lights.h"
#include "mesh.h"
#include "vberr.h"

/* JSON paths in messages are cut at PATH_LEN; a cut path still locates the
 * error, so truncation is intended here. */
#pragma GCC diagnostic ignored "-Wformat-truncation"

#define MAX_SCENE_FILE_BYTES (256u << 20)
#define MAX_VERTICES 0xfffffff0u
#define PATH_LEN 160

typedef struct xform {
    double m[3][3];
    double t[3];
    double nm[3][3]; /* inverse transpose, for normals */
    int flips;       /* negative determinant: winding is reversed */
} xform_t;

typedef struct loader {
    const char *name;
    const char *base_dir;
    const scene_blob_t *blobs; /* in-memory mesh files, or NULL: the file system */
    size_t blob_count;
    char *err;
    size_t errlen;
    scene_t *s;
    float *pos, *nrm, *uv; /* uv: when the scene has textures */
    size_t nv, cap_v;
    size_t texture_cap;
    int want_uv; /* a material has a texture: keep texture coordinates */
    uint32_t *idx, *mat;
    size_t nt, cap_t;
    /* emitting spheres as they are loaded: their triangles [first, first +
     * count) of the loader's list */
    scene_sphere_t *sph;
    size_t *sph_first, *sph_tris, nsph;
    int check_only; /* scene_check*: no tables precomputed for tracing */
} loader_t;

static int fail(loader_t *L, const char *path, const char *fmt, ...)
{
    char msg[VB_ERR_LEN];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    if (path && *path)
        snprintf(L->err, L->errlen, "%s: %s: %s", L->name, path, msg);
    else
        snprintf(L->err, L->errlen, "%s: %s", L->name, msg);
    return -1;
}

static void warn(scene_t *s, const char *fmt, ...)
{
    if (s->warning_count >= SCENE_MAX_WARNINGS)
        return;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(s->warnings[s->warning_count++], SCENE_WARNING_LEN, fmt, ap);
    va_end(ap);
}

/* Warns about keys a reader would not expect, so a typo ("albdo") is seen
 * rather than silently defaulted. */
static void check_keys(loader_t *L, const cJSON *obj, const char *path, const char *const *allowed)
{
    for (const cJSON *it = obj->child; it; it = it->next) {
        int ok = it->string == NULL;
        for (int i = 0; !ok && allowed[i]; i++)
            ok = strcmp(it->string, allowed[i]) == 0;
        if (!ok && strcmp(it->string, "comment") != 0 && strcmp(it->string, "name") != 0)
            warn(L->s, "%s: %s%s%s: unknown field ignored", L->name, path, *path ? "." : "",
                 it->string);
    }
}

static int get_number(loader_t *L, const cJSON *obj, const char *key, const char *path,
                      int required, double lo, double hi, double *out)
{
    const cJSON *it = cJSON_GetObjectItemCaseSensitive(obj, key);
    char p[PATH_LEN];
    snprintf(p, sizeof p, "%s%s%s", path, *path ? "." : "", key);
    if (!it) {
        if (required)
            return fail(L, p, "missing (expected a number)");
        return 0;
    }
    if (!cJSON_IsNumber(it))
        return fail(L, p, "expected a number");
    double v = it->valuedouble;
    if (!isfinite(v))
        return fail(L, p, "not a finite number");
    if (v < lo || v > hi)
        return fail(L, p, "%g is out of range [%g, %g]", v, lo, hi);
    *out = v;
    return 0;
}

static int get_integer(loader_t *L, const cJSON *obj, const char *key, const char *path,
                       int required, double lo, double hi, double *out)
{
    double v = *out;
    if (get_number(L, obj, key, path, required, lo, hi, &v) < 0)
        return -1;
    if (v != floor(v)) {
        char p[PATH_LEN];
        snprintf(p, sizeof p, "%s%s%s", path, *path ? "." : "", key);
        return fail(L, p, "expected an integer (got %g)", v);
    }
    *out = v;
    return 0;
}

static int parse_vec3_item(loader_t *L, const cJSON *it, const char *p, double out[3])
{
    if (!cJSON_IsArray(it) || cJSON_GetArraySize(it) != 3)
        return fail(L, p, "expected an array of 3 numbers");
    int i = 0;
    for (const cJSON *e = it->child; e; e = e->next, i++) {
        if (!cJSON_IsNumber(e))
            return fail(L, p, "element %d is not a number", i);
        if (!isfinite(e->valuedouble))
            return fail(L, p, "element %d is not finite (NaN or Inf)", i);
        out[i] = e->valuedouble;
    }
    return 0;
}

static int get_vec3(loader_t *L, const cJSON *obj, const char *key, const char *path, int required,
                    double out[3])
{
    const cJSON *it = cJSON_GetObjectItemCaseSensitive(obj, key);
    char p[PATH_LEN];
    snprintf(p, sizeof p, "%s%s%s", path, *path ? "." : "", key);
    if (!it)
        return required ? fail(L, p, "missing (expected an array of 3 numbers)") : 0;
    return parse_vec3_item(L, it, p, out);
}

static vec3_t to_vec3(const double d[3])
{
    return vec3_make((float)d[0], (float)d[1], (float)d[2]);
}

/* ---- camera and render defaults ---------------------------------------- */

static int parse_camera(loader_t *L, const cJSON *root)
{
    const cJSON *cam = cJSON_GetObjectItemCaseSensitive(root, "camera");
    if (!cam)
        return fail(L, "camera", "missing");
    if (!cJSON_IsObject(cam))
        return fail(L, "camera", "expected an object");
    static const char *const keys[] = {
        "position", "look_at",        "up",           "fov",
        "width",    "height",         "filter",       "filter_stddev",
        "aperture", "focus_distance", "orthographic", "crop",
        NULL};
    check_keys(L, cam, "camera", keys);
    double pos[3], at[3], up[3] = {0, 1, 0}, fov = 0, w = 0, h = 0;
    if (get_vec3(L, cam, "position", "camera", 1, pos) < 0 ||
        get_vec3(L, cam, "look_at", "camera", 1, at) < 0 ||
        get_vec3(L, cam, "up", "camera", 0, up) < 0 ||
        get_number(L, cam, "fov", "camera", !cJSON_GetObjectItemCaseSensitive(cam, "orthographic"),
                   -INFINITY, INFINITY, &fov) < 0 ||
        get_integer(L, cam, "width", "camera", 1, -INFINITY, INFINITY, &w) < 0 ||
        get_integer(L, cam, "height", "camera", 1, -INFINITY, INFINITY, &h) < 0)
        return -1;
    if (w < 1 || h < 1 || w > SCENE_MAX_SIDE || h > SCENE_MAX_SIDE || w * h > SCENE_MAX_PIXELS)
        return fail(L, "camera", "absurd resolution %gx%g (each side 1..%d, at most %u pixels)", w,
                    h, SCENE_MAX_SIDE, SCENE_MAX_PIXELS);
    char msg[VB_ERR_LEN];
    /* "orthographic": [half width, half height, near]: fov is unused */
    const cJSON *orth = cJSON_GetObjectItemCaseSensitive(cam, "orthographic");
    double ortho[3] = {0, 0, 0};
    if (orth && parse_vec3_item(L, orth, "camera.orthographic", ortho) < 0)
        return -1;
    if (orth)
        fov = 90;
    if (camera_init(&L->s->camera, to_vec3(pos), to_vec3(at), to_vec3(up), fov, (int)w, (int)h, msg,
                    sizeof msg) < 0)
        return fail(L, "camera", "%s", msg);
    if (orth &&
        camera_set_orthographic(&L->s->camera, ortho[0], ortho[1], ortho[2], msg, sizeof msg) < 0)
        return fail(L, "camera.orthographic", "%s", msg);
    /* "aperture" (a radius) and "focus_distance": a thin lens */
    double aperture = 0, focus = 0;
    if (get_number(L, cam, "aperture", "camera", 0, 0, 1e30, &aperture) < 0 ||
        get_number(L, cam, "focus_distance", "camera", 0, 0, 1e30, &focus) < 0)
        return -1;
    if (aperture > 0 && camera_set_thinlens(&L->s->camera, aperture, focus, msg, sizeof msg) < 0)
        return fail(L, "camera", "%s", msg);
    /* "crop": [x, y, width, height] of the film: the image is that window */
    const cJSON *crop = cJSON_GetObjectItemCaseSensitive(cam, "crop");
    if (crop) {
        double v[4];
        int n = 0;
        for (const cJSON *e = cJSON_IsArray(crop) ? crop->child : NULL; e && n < 5;
             e = e->next, n++)
            if (n < 4 && cJSON_IsNumber(e) && e->valuedouble == floor(e->valuedouble) &&
                fabs(e->valuedouble) < 1e9)
                v[n] = e->valuedouble;
            else
                n = 5;
        if (n != 4)
            return fail(L, "camera.crop", "expected 4 integers: x, y, width, height");
        if (camera_set_crop(&L->s->camera, (int)v[0], (int)v[1], (int)v[2], (int)v[3], msg,
                            sizeof msg) < 0)
            return fail(L, "camera.crop", "%s", msg);
    }
    /* "filter": "box" (default) or "gaussian" ("filter_stddev" pixels, 0.5) */
    const cJSON *filter = cJSON_GetObjectItemCaseSensitive(cam, "filter");
    double stddev = 0.5;
    if (get_number(L, cam, "filter_stddev", "camera", 0, -INFINITY, INFINITY, &stddev) < 0)
        return -1;
    if (filter) {
        const char *f = cJSON_IsString(filter) ? filter->valuestring : "";
        if (strcmp(f, "gaussian") == 0) {
            if (camera_set_gaussian(&L->s->camera, stddev, msg, sizeof msg) < 0)
                return fail(L, "camera.filter_stddev", "%s", msg);
        } else if (strcmp(f, "box") != 0) {
            return fail(L, "camera.filter", "expected \"box\" or \"gaussian\"");
        }
    }
    return 0;
}

static int parse_render(loader_t *L, const cJSON *root)
{
    scene_t *s = L->s;
    s->spp = 64;
    s->seed = 1;
    s->integrator = SCENE_INTEGRATOR_PATH;
    s->max_depth = 0;
    s->rr_depth = SCENE_RR_DEPTH;
    s->rr_threshold = SCENE_RR_THRESHOLD;
    s->rr_cap = SCENE_RR_CAP;
    s->direct_emitter_samples = s->direct_bsdf_samples = 1;
    const cJSON *r = cJSON_GetObjectItemCaseSensitive(root, "render");
    if (!r)
        return 0;
    if (!cJSON_IsObject(r))
        return fail(L, "render", "expected an object");
    static const char *const keys[] = {"spp",          "seed",          "integrator",
                                       "max_depth",    "rr_depth",      "emitter_samples",
                                       "bsdf_samples", "hide_emitters", NULL};
    check_keys(L, r, "render", keys);
    double spp = s->spp, seed = (double)s->seed, depth = 0, rr = SCENE_RR_DEPTH, es = 1, bs = 1;
    if (get_integer(L, r, "spp", "render", 0, 1, 4294967295.0, &spp) < 0 ||
        get_integer(L, r, "seed", "render", 0, 0, 9007199254740992.0, &seed) < 0 ||
        get_integer(L, r, "max_depth", "render", 0, 0, 1e6, &depth) < 0 ||
        get_integer(L, r, "rr_depth", "render", 0, 1, SCENE_MAX_RR_DEPTH, &rr) < 0 ||
        get_integer(L, r, "emitter_samples", "render", 0, 0, SCENE_MAX_DIRECT_SAMPLES, &es) < 0 ||
        get_integer(L, r, "bsdf_samples", "render", 0, 0, SCENE_MAX_DIRECT_SAMPLES, &bs) < 0)
        return -1;
    if (es + bs == 0)
        return fail(L, "render", "emitter_samples and bsdf_samples cannot both be 0");
    s->direct_emitter_samples = (uint32_t)es;
    s->direct_bsdf_samples = (uint32_t)bs;
    const cJSON *hide = cJSON_GetObjectItemCaseSensitive(r, "hide_emitters");
    if (hide && !cJSON_IsBool(hide))
        return fail(L, "render.hide_emitters", "expected true or false");
    s->hide_emitters = (uint8_t)(hide && cJSON_IsTrue(hide));
    s->rr_depth = (uint32_t)rr;
    s->spp = (uint32_t)spp;
    s->seed = (uint64_t)seed;
    s->max_depth = (uint32_t)depth;
    const cJSON *in = cJSON_GetObjectItemCaseSensitive(r, "integrator");
    if (in) {
        int v = cJSON_IsString(in) ? scene_integrator_from_name(in->valuestring) : -1;
        if (v < 0)
            return fail(L, "render.integrator", "expected \"path\", \"naive\" or \"direct\"");
        s->integrator = (scene_integrator_t)v;
    }
    return 0;
}

/* The map's pixels (scaled, the first column repeated after the last) and
 * its sampling distribution: each cell between four pixels weighted by
 * their mean luminance times sin(theta) at its centre. */
static int build_env_map(loader_t *L, const image_t *img, double scale)
{
    scene_t *s = L->s;
    const float *ch[3] = {image_channel(img, "R"), image_channel(img, "G"),
                          image_channel(img, "B")};
    if (!ch[0] || !ch[1] || !ch[2])
        return fail(L, "environment.map", "the image has no R, G and B channels");
    int w = img->width, h = img->height;
    if (w < 2 || h < 3)
        return fail(L, "environment.map", "the image is %dx%d (at least 2x3)", w, h);
    size_t row = (size_t)w + 1, cells = (size_t)w * (size_t)(h - 1);
    s->env_rgb = malloc(row * (size_t)h * 3 * sizeof(float));
    s->env_row_cdf = malloc((size_t)(h - 1) * sizeof(double));
    s->env_col_cdf = malloc(cells * sizeof(double));
    s->env_cell_pdf = malloc(cells * sizeof(float));
    if (!s->env_rgb || !s->env_row_cdf || !s->env_col_cdf || !s->env_cell_pdf)
        return fail(L, "environment.map", "out of memory for a %dx%d map", w, h);
    for (int y = 0; y < h; y++)
        for (size_t x = 0; x < row; x++)
            for (int k = 0; k < 3; k++) {
                float v = ch[k][(size_t)y * (size_t)w + (x < (size_t)w ? x : 0)];
                if (!(v >= 0) || !isfinite(v))
                    return fail(L, "environment.map", "pixel (%zu, %d) is negative or not finite",
                                x, y);
                float sv = (float)(v * scale);
                if (!isfinite(sv))
                    return fail(L, "environment.scale", "the scaled map overflows");
                s->env_rgb[3 * ((size_t)y * row + x) + (size_t)k] = sv;
            }
    double total = 0;
    double *weight = s->env_col_cdf; /* weights first, then each row's cdf in place */
    for (int j = 0; j < h - 1; j++) {
        double sin_theta = sin((j + 0.5) / (h - 1) * 3.14159265358979323846), sum = 0;
        for (int i = 0; i < w; i++) {
            double lum = 0;
            for (int dy = 0; dy < 2; dy++)
                for (int dx = 0; dx < 2; dx++) {
                    const float *p = s->env_rgb + 3 * ((size_t)(j + dy) * row + (size_t)(i + dx));
                    lum += vmath_luminance(p[0], p[1], p[2]);
                }
            weight[(size_t)j * (size_t)w + (size_t)i] = lum / 4 * sin_theta;
            sum += lum / 4 * sin_theta;
        }
        s->env_row_cdf[j] = sum;
        total += sum;
    }
    if (!(total > 0) || !isfinite(total))
        return 0; /* black: no light */
    double acc = 0;
    for (int j = 0; j < h - 1; j++) {
        double row_sum = s->env_row_cdf[j], racc = 0;
        acc += row_sum;
        s->env_row_cdf[j] = acc / total;
        for (int i = 0; i < w; i++) {
            double *c = &weight[(size_t)j * (size_t)w + (size_t)i];
            s->env_cell_pdf[(size_t)j * (size_t)w + (size_t)i] =
                (float)(*c / total * (double)cells);
            racc += *c;
            *c = row_sum > 0 ? racc / row_sum : (i + 1.0) / w;
        }
        weight[(size_t)j * (size_t)w + (size_t)(w - 1)] = 1.0;
    }
    s->env_row_cdf[h - 2] = 1.0;
    s->env_w = w;
    s->env_h = h;
    s->env_map = 1;
    s->has_env = 1;
    return 0;
}

/* "environment": {"radiance": [r, g, b]}: light from every direction no
 * triangle blocks; or {"map": "file.exr", "scale": s, "to_world": [9
 * numbers]}: a latitude-longitude map, as Mitsuba's envmap reads one
 * (finish sets up its sampling). */
/* The most texels an environment map may have: a 16K x 8K map (1.5 GB of
 * floats), larger than any texture, since a sky carries the lighting. */
#define ENV_MAX_TEXELS ((size_t)16384 * 8192)

static int load_env_image(loader_t *L, const char *file, image_t **img);

static int parse_environment(loader_t *L, const cJSON *root)
{
    const cJSON *e = cJSON_GetObjectItemCaseSensitive(root, "environment");
    if (!e)
        return 0;
    if (!cJSON_IsObject(e))
        return fail(L, "environment", "expected an object");
    static const char *const keys[] = {"radiance", "map", "scale", "to_world", NULL};
    check_keys(L, e, "environment", keys);
    const cJSON *map = cJSON_GetObjectItemCaseSensitive(e, "map");
    if (map) {
        if (!cJSON_IsString(map) || !*map->valuestring)
            return fail(L, "environment.map",
                        "expected an image file's name (OpenEXR or Radiance HDR)");
        double scale = 1, m[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
        if (get_number(L, e, "scale", "environment", 0, 0, 1e30, &scale) < 0)
            return -1;
        const cJSON *tw = cJSON_GetObjectItemCaseSensitive(e, "to_world");
        if (tw) {
            int n = 0;
            for (const cJSON *it = cJSON_IsArray(tw) ? tw->child : NULL; it; it = it->next, n++)
                if (n >= 9 || !cJSON_IsNumber(it) || !isfinite(it->valuedouble))
                    return fail(L, "environment.to_world", "expected 9 finite numbers");
                else
                    m[n] = it->valuedouble;
            if (n != 9)
                return fail(L, "environment.to_world", "expected 9 finite numbers");
        }
        /* a rotation: its inverse is its transpose, within rounding */
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 3; b++) {
                double dot = m[a] * m[b] + m[3 + a] * m[3 + b] + m[6 + a] * m[6 + b];
                if (fabs(dot - (a == b)) > 1e-4)
                    return fail(L, "environment.to_world", "not a rotation");
            }
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < 3; b++) {
                L->s->env_to_world[3 * a + b] = (float)m[3 * a + b];
                L->s->env_to_local[3 * a + b] = (float)m[3 * b + a];
            }
        image_t *img = NULL;
        if (load_env_image(L, map->valuestring, &img) < 0)
            return -1;
        int rc = build_env_map(L, img, scale);
        image_destroy(&img);
        return rc;
    }
    double rad[3];
    if (get_vec3(L, e, "radiance", "environment", 1, rad) < 0)
        return -1;
    for (int k = 0; k < 3; k++)
        if (!(rad[k] >= 0 && rad[k] <= 1e30))
            return fail(L, "environment.radiance", "each must be between 0 and 1e30");
    L->s->env_radiance = to_vec3(rad);
    L->s->has_env = vmath_luminance(rad[0], rad[1], rad[2]) > 0;
    return 0;
}

/* "lights": [{"type": "point", "position": [x, y, z], "intensity": [r,
 * g, b]}, {"type": "spot", "position", "direction" (its axis),
 * "intensity", "cutoff_angle" (degrees, default 20), "beam_width"
 * (default 3/4 of the cutoff)}, {"type": "directional", "direction"
 * (where the light goes), "irradiance"}]: lights with no area
 * (scene_light_t), as Mitsuba's point, spot and directional emitters. */
static int parse_lights(loader_t *L, const cJSON *root)
{
    const cJSON *arr = cJSON_GetObjectItemCaseSensitive(root, "lights");
    if (!arr)
        return 0;
    if (!cJSON_IsArray(arr))
        return fail(L, "lights", "expected an array");
    int n = cJSON_GetArraySize(arr);
    if (n > SCENE_MAX_DELTA_LIGHTS)
        return fail(L, "lights", "more than %d lights", SCENE_MAX_DELTA_LIGHTS);
    if (n == 0)
        return 0;
    scene_t *s = L->s;
    s->delta_lights = calloc((size_t)n, sizeof *s->delta_lights);
    if (!s->delta_lights)
        return fail(L, "lights", "out of memory");
    int i = 0;
    for (const cJSON *it = arr->child; it; it = it->next, i++) {
        char p[PATH_LEN];
        snprintf(p, sizeof p, "lights[%d]", i);
        if (!cJSON_IsObject(it))
            return fail(L, p, "expected an object with a \"type\"");
        const cJSON *type = cJSON_GetObjectItemCaseSensitive(it, "type");
        static const char *const kinds[] = {"point", "spot", "directional"};
        int kind = -1;
        for (int k = 0; k < 3 && cJSON_IsString(type); k++)
            if (strcmp(type->valuestring, kinds[k]) == 0)
                kind = k;
        if (kind < 0)
            return fail(L, p, "\"type\" must be \"point\", \"spot\" or \"directional\"");
        static const char *const keys[] = {"type",       "position",     "direction",  "intensity",
                                           "irradiance", "cutoff_angle", "beam_width", NULL};
        check_keys(L, it, p, keys);
        scene_light_t *l = &s->delta_lights[i];
        l->kind = (scene_light_kind_t)kind;
        double pos[3] = {0, 0, 0}, dir[3] = {0, 0, 1}, val[3];
        const char *what = kind == SCENE_LIGHT_DIRECTIONAL ? "irradiance" : "intensity";
        if ((kind != SCENE_LIGHT_DIRECTIONAL && get_vec3(L, it, "position", p, 1, pos) < 0) ||
            (kind != SCENE_LIGHT_POINT && get_vec3(L, it, "direction", p, 1, dir) < 0) ||
            get_vec3(L, it, what, p, 1, val) < 0)
            return -1;
        for (int k = 0; k < 3; k++)
            if (!(val[k] >= 0 && val[k] <= 1e30) || !(fabs(pos[k]) < 1e30))
                return fail(L, p, "%s must be in [0, 1e30] and the position finite", what);
        double len = sqrt(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
        if (!(len > 0 && len < 1e30))
            return fail(L, p, "direction must not be zero");
        l->position = to_vec3(pos);
        l->direction =
            vec3_make((float)(dir[0] / len), (float)(dir[1] / len), (float)(dir[2] / len));
        l->intensity = to_vec3(val);
        if (kind == SCENE_LIGHT_SPOT) {
            double cutoff = 20, beam = -1;
            if (get_number(L, it, "cutoff_angle", p, 0, 1e-3, 180, &cutoff) < 0 ||
                get_number(L, it, "beam_width", p, 0, 0, 180, &beam) < 0)
                return -1;
            if (beam < 0)
                beam = cutoff * 3 / 4;
            if (!(beam < cutoff))
                return fail(L, p, "beam_width must be below cutoff_angle");
            double c = cutoff * M_PI / 180, b = beam * M_PI / 180;
            l->cutoff = (float)c;
            l->cos_cutoff = (float)cos(c);
            l->cos_beam = (float)cos(b);
            l->inv_transition = (float)(1 / (c - b));
        }
        s->delta_count++;
    }
    return 0;
}

/* The lights with no area: their share of the light samples, and the
 * triangles' area pdfs scaled by what is left. As Mitsuba 3 picks its
 * emitters, each light is one emitter and the emitting triangles together
 * one more, all picked alike: by power, a spot's narrow cone counted as
 * little light, and it went short of samples where it is the brightest
 * (scenes/mitsuba/lights.xml: 2.5x Mitsuba's relMSE at equal spp, with the
 * environment's share below). A black light is never picked. */
static int finish_delta_lights(loader_t *L)
{
    scene_t *s = L->s;
    if (!s->delta_count)
        return 0;
    s->delta_cdf = malloc(s->delta_count * sizeof *s->delta_cdf);
    if (!s->delta_cdf)
        return fail(L, "lights", "out of memory");
    double total = 0;
    for (size_t i = 0; i < s->delta_count; i++) {
        const scene_light_t *l = &s->delta_lights[i];
        double lum = vmath_luminance(l->intensity.x, l->intensity.y, l->intensity.z);
        total += lum > 0 ? 1.0 : 0.0;
        s->delta_cdf[i] = total;
    }
    if (!(total > 0) || !isfinite(total)) {
        /* all black: never picked */
        s->delta_count = 0;
        return 0;
    }
    for (size_t i = 0; i < s->delta_count; i++)
        s->delta_cdf[i] /= total;
    s->delta_cdf[s->delta_count - 1] = 1.0;
    s->delta_pick = s->light_count > 0 ? (float)(total / (total + 1.0)) : 1.0f;
    for (size_t i = 0; i < s->light_count; i++)
        s->tri_light_pdf[s->light_tris[i]] *= 1.0f - s->delta_pick;
    return 0;
}

/* The length of the diagonal of the box around every vertex. */
static double scene_diagonal(const scene_t *s)
{
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (size_t v = 0; v < s->vertex_count; v++)
        for (int k = 0; k < 3; k++) {
            lo[k] = fmin(lo[k], s->positions[3 * v + k]);
            hi[k] = fmax(hi[k], s->positions[3 * v + k]);
        }
    double d2 = 0;
    for (int k = 0; k < 3; k++)
        d2 += (hi[k] - lo[k]) * (hi[k] - lo[k]);
    return sqrt(d2);
}

/* The environment's share of the light samples: one emitter among the
 * others (finish_delta_lights), as Mitsuba picks its emitters: half beside
 * triangle lights alone, a fifth beside them and three lights with no
 * area, all without any; and the length of a shadow segment that leaves
 * the scene's bounds from inside. */
static void finish_environment(scene_t *s)
{
    if (!s->has_env)
        return;
    s->env_pick = 1.0f / (float)(1 + s->delta_count + (s->light_count > 0));
    for (size_t i = 0; i < s->light_count; i++)
        s->tri_light_pdf[s->light_tris[i]] *= 1.0f - s->env_pick;
    s->env_pdf = (float)(s->env_pick / (4.0 * 3.14159265358979323846));
    s->env_distance = (float)(2.0 * scene_diagonal(s) + 1.0);
}

/* ---- materials ---------------------------------------------------------- */

/* A bitmap's bytes: its blob from the bundle, or the file beside the
 * scene (read whole; *owned is the buffer to free). */
static int read_asset(loader_t *L, const char *q, const char *file, const unsigned char **data,
                      size_t *size, unsigned char **owned)
{
    *owned = NULL;
    if (L->blobs) {
        for (size_t i = 0; i < L->blob_count; i++)
            if (strcmp(L->blobs[i].name, file) == 0) {
                *data = L->blobs[i].data;
                *size = L->blobs[i].size;
                return 0;
            }
        return fail(L, q, "\"%s\" is not in the scene bundle", file);
    }
    char full[4096];
    if (file[0] == '/' || !L->base_dir || !*L->base_dir)
        snprintf(full, sizeof full, "%s", file);
    else
        snprintf(full, sizeof full, "%s/%s", L->base_dir, file);
    FILE *f = fopen(full, "rb");
    if (!f)
        return fail(L, q, "%s: cannot open: %s", full, strerror(errno));
    struct stat st;
    if (fstat(fileno(f), &st) != 0 || !S_ISREG(st.st_mode) || st.st_size > (1l << 30)) {
        fclose(f);
        return fail(L, q, "%s: not a regular file of at most 1 GiB", full);
    }
    unsigned char *buf = malloc((size_t)st.st_size + 1);
    if (!buf || fread(buf, 1, (size_t)st.st_size, f) != (size_t)st.st_size) {
        fclose(f);
        free(buf);
        return fail(L, q, "%s: cannot read", full);
    }
    fclose(f);
    *data = *owned = buf;
    *size = (size_t)st.st_size;
    return 0;
}

/* The environment map's image, from the bundle or beside the scene: an
 * OpenEXR file, or a Radiance HDR one (bitmap_decode), as Mitsuba's
 * envmap reads both. */
static int load_env_image(loader_t *L, const char *file, image_t **img)
{
    const unsigned char *data = NULL;
    size_t size = 0;
    unsigned char *owned = NULL;
    if (read_asset(L, "environment.map", file, &data, &size, &owned) < 0)
        return -1;
    char msg[VB_ERR_LEN];
    int rc;
    if (bitmap_is_hdr(data, size)) {
        bitmap_t b;
        rc = bitmap_decode(file, data, size, 0, ENV_MAX_TEXELS, &b, msg, sizeof msg);
        if (rc == 0) {
            *img = image_new(b.width, b.height);
            float *ch[3] = {NULL, NULL, NULL};
            if (*img)
                for (int c = 0; c < 3; c++)
                    ch[c] = image_add_channel(*img, c == 0 ? "R" : c == 1 ? "G" : "B");
            if (!ch[0] || !ch[1] || !ch[2]) {
                image_destroy(img);
                snprintf(msg, sizeof msg, "%s: out of memory", file);
                rc = -1;
            } else {
                size_t texels = (size_t)b.width * (size_t)b.height;
                for (size_t i = 0; i < texels; i++)
                    for (int c = 0; c < 3; c++)
                        ch[c][i] = b.rgb[3 * i + c];
            }
            bitmap_free(&b);
        }
    } else {
        rc = image_read_exr_buffer(file, data, size, img, msg, sizeof msg);
    }
    free(owned);
    return rc < 0 ? fail(L, "environment.map", "%s", msg) : 0;
}

/* A bitmap texture's fields into tx: its file decoded, "filter"
 * ("bilinear" or "nearest"), "wrap" ("repeat", "mirror" or "clamp"),
 * "raw" (the stored values, not sRGB-decoded). Texels are clamped to
 * [0, 1] (an albedo above 1 would create energy; only OpenEXR can hold
 * one), with a warning; v gets the mean. */
static int parse_bitmap(loader_t *L, const cJSON *t, const char *q, texture_t *tx, double v[3])
{
    const cJSON *file = cJSON_GetObjectItemCaseSensitive(t, "file");
    const cJSON *filter = cJSON_GetObjectItemCaseSensitive(t, "filter");
    const cJSON *wrap = cJSON_GetObjectItemCaseSensitive(t, "wrap");
    const cJSON *raw = cJSON_GetObjectItemCaseSensitive(t, "raw");
    if (!cJSON_IsString(file) || !*file->valuestring)
        return fail(L, q, "a bitmap needs \"file\" (a PNG, JPEG or OpenEXR image)");
    if (filter && (!cJSON_IsString(filter) || (strcmp(filter->valuestring, "bilinear") != 0 &&
                                               strcmp(filter->valuestring, "nearest") != 0)))
        return fail(L, q, "filter: expected \"bilinear\" or \"nearest\"");
    static const char *const wraps[] = {"repeat", "mirror", "clamp"};
    tx->wrap = TEXTURE_WRAP_REPEAT;
    if (wrap) {
        int w = -1;
        for (int i = 0; i < 3 && cJSON_IsString(wrap); i++)
            if (strcmp(wrap->valuestring, wraps[i]) == 0)
                w = i;
        if (w < 0)
            return fail(L, q, "wrap: expected \"repeat\", \"mirror\" or \"clamp\"");
        tx->wrap = (texture_wrap_t)w;
    }
    if (raw && !cJSON_IsBool(raw))
        return fail(L, q, "raw: expected true or false");
    tx->nearest = (uint8_t)(filter && strcmp(filter->valuestring, "nearest") == 0);
    const unsigned char *data = NULL;
    size_t size = 0;
    unsigned char *owned = NULL;
    if (read_asset(L, q, file->valuestring, &data, &size, &owned) < 0)
        return -1;
    bitmap_t b;
    char msg[VB_ERR_LEN];
    int rc = bitmap_decode(file->valuestring, data, size, raw && cJSON_IsTrue(raw),
                           BITMAP_MAX_TEXELS, &b, msg, sizeof msg);
    free(owned);
    if (rc < 0)
        return fail(L, q, "%s", msg);
    size_t n = (size_t)b.width * b.height * 3, clamped = 0;
    double sum[3] = {0, 0, 0};
    for (size_t i = 0; i < n; i++) {
        float x = b.rgb[i];
        if (!(x >= 0.0f && x <= 1.0f)) {
            b.rgb[i] = x > 1.0f ? 1.0f : 0.0f; /* (NaN too) */
            clamped++;
        }
        sum[i % 3] += b.rgb[i];
    }
    if (clamped)
        warn(L->s, "%s: %s: %zu texel values outside [0, 1] clamped", L->name, q, clamped);
    tx->kind = TEXTURE_BITMAP;
    tx->width = b.width;
    tx->height = b.height;
    tx->rgb = b.rgb;
    for (int k = 0; k < 3; k++)
        v[k] = sum[k] / (double)(n / 3);
    /* what a material's sampling weights read (material_prepare) */
    tx->color0 = tx->color1 = to_vec3(v);
    return 0;
}

/* An albedo given as a texture, appended to the scene's textures: a
 * checkerboard {"type": "checkerboard", "color0": [r, g, b], "color1":
 * [r, g, b], "to_uv": [6 numbers]}, or a bitmap {"type": "bitmap",
 * "file": name, "filter", "wrap", "raw", "to_uv"} (parse_bitmap). *index
 * is its place, v its color0 or mean (for the range check; color1 passes
 * it too). */
static int parse_texture(loader_t *L, const cJSON *t, const char *p, const char *field,
                         int32_t *index, double v[3])
{
    char q[PATH_LEN];
    snprintf(q, sizeof q, "%s.%s", p, field);
    const cJSON *type = cJSON_GetObjectItemCaseSensitive(t, "type");
    int bitmap = cJSON_IsString(type) && strcmp(type->valuestring, "bitmap") == 0;
    if (!bitmap && (!cJSON_IsString(type) || strcmp(type->valuestring, "checkerboard") != 0))
        return fail(L, q, "a texture's \"type\" must be \"checkerboard\" or \"bitmap\"");
    static const char *const checker_keys[] = {"type", "color0", "color1", "to_uv", NULL};
    static const char *const bitmap_keys[] = {"type", "file",  "filter", "wrap",
                                              "raw",  "to_uv", NULL};
    check_keys(L, t, q, bitmap ? bitmap_keys : checker_keys);
    double c0[3], c1[3], m[6] = {1, 0, 0, 0, 1, 0};
    if (!bitmap &&
        (get_vec3(L, t, "color0", q, 1, c0) < 0 || get_vec3(L, t, "color1", q, 1, c1) < 0))
        return -1;
    const cJSON *uv = cJSON_GetObjectItemCaseSensitive(t, "to_uv");
    if (uv) {
        int n = 0;
        for (const cJSON *e = cJSON_IsArray(uv) ? uv->child : NULL; e; e = e->next, n++)
            if (n >= 6 || !cJSON_IsNumber(e) || !isfinite(e->valuedouble) ||
                fabs(e->valuedouble) > 1e30)
                return fail(L, q, "to_uv: expected 6 finite numbers");
            else
                m[n] = e->valuedouble;
        if (n != 6)
            return fail(L, q, "to_uv: expected 6 finite numbers");
    }
    for (int k = 0; !bitmap && k < 3; k++)
        if (!(c0[k] >= 0 && c0[k] <= 1 && c1[k] >= 0 && c1[k] <= 1))
            return fail(L, q, "colours must be in [0, 1]: more would create energy");
    scene_t *s = L->s;
    if (s->texture_count == L->texture_cap) {
        size_t cap = L->texture_cap ? 2 * L->texture_cap : 4;
        texture_t *nt = realloc(s->textures, cap * sizeof *nt);
        if (!nt)
            return fail(L, q, "out of memory");
        s->textures = nt;
        L->texture_cap = cap;
    }
    texture_t *tx = &s->textures[s->texture_count];
    memset(tx, 0, sizeof *tx);
    for (int k = 0; k < 6; k++)
        tx->to_uv[k] = (float)m[k];
    if (bitmap) {
        if (parse_bitmap(L, t, q, tx, v) < 0)
            return -1;
    } else {
        tx->kind = TEXTURE_CHECKERBOARD;
        tx->color0 = to_vec3(c0);
        tx->color1 = to_vec3(c1);
        for (int k = 0; k < 3; k++)
            v[k] = c0[k];
    }
    *index = (int32_t)s->texture_count++;
    return 0;
}

/* "twosided": false makes a diffuse surface (or an emitter's albedo)
 * black from behind; the default, true, reflects on both sides. */
static int get_twosided(loader_t *L, const cJSON *it, const char *p, material_t *m)
{
    const cJSON *t = cJSON_GetObjectItemCaseSensitive(it, "twosided");
    if (t && !cJSON_IsBool(t)) {
        char q[PATH_LEN];
        snprintf(q, sizeof q, "%s.twosided", p);
        return fail(L, q, "expected true or false");
    }
    m->one_sided = (uint8_t)(t && cJSON_IsFalse(t));
    return 0;
}

/* "roughness" (alpha, 0 or absent: the smooth material; else at least
 * MICROFACET_MIN_ALPHA, as Mitsuba clamps it) and "distribution". */
static int get_roughness(loader_t *L, const cJSON *it, const char *p, material_t *m)
{
    double alpha = 0;
    if (get_number(L, it, "roughness", p, 0, 0, 4, &alpha) < 0)
        return -1;
    m->alpha = alpha > 0 ? fmaxf((float)alpha, MICROFACET_MIN_ALPHA) : 0.0f;
    m->distribution = MICROFACET_BECKMANN;
    const cJSON *d = cJSON_GetObjectItemCaseSensitive(it, "distribution");
    if (!d)
        return 0;
    char q[PATH_LEN];
    snprintf(q, sizeof q, "%s.distribution", p);
    if (!cJSON_IsString(d) ||
        (strcmp(d->valuestring, "beckmann") != 0 && strcmp(d->valuestring, "ggx") != 0))
        return fail(L, q, "expected \"beckmann\" or \"ggx\"");
    m->distribution = strcmp(d->valuestring, "ggx") == 0 ? MICROFACET_GGX : MICROFACET_BECKMANN;
    return 0;
}

/* conductor, plastic and thindielectric (material.h says what each
 * field means); v gets the reflectance or albedo to range-check. */
static int parse_glossy_fields(loader_t *L, const cJSON *it, const char *p, material_t *m,
                               double v[3])
{
    char q[PATH_LEN];
    if (m->type == MATERIAL_THIN_DIELECTRIC || m->type == MATERIAL_ROUGH_DIELECTRIC) {
        static const char *const keys[] = {"type", "ior", "roughness", "distribution", NULL};
        check_keys(L, it, p, keys);
        double ior = 1.5046 / 1.000277; /* Mitsuba's defaults: bk7 in air */
        if (get_number(L, it, "ior", p, 0, 1.0 / 8, 8.0, &ior) < 0)
            return -1;
        m->ior = (float)ior;
        if (m->type == MATERIAL_THIN_DIELECTRIC)
            return 0;
        if (get_roughness(L, it, p, m) < 0)
            return -1;
        if (!cJSON_GetObjectItemCaseSensitive(it, "roughness"))
            m->alpha = 0.1f; /* Mitsuba's default */
        if (!(m->alpha > 0.0f) || m->ior == 1.0f) {
            snprintf(q, sizeof q, "%s.%s", p, m->ior == 1.0f ? "ior" : "roughness");
            return fail(L, q,
                        "rough glass needs a roughness above 0 and an index other than 1 "
                        "(use dielectric for smooth glass)");
        }
        return 0;
    }
    if (m->type == MATERIAL_CONDUCTOR) {
        static const char *const keys[] = {"type",      "reflectance",  "preset",   "eta", "k",
                                           "roughness", "distribution", "twosided", NULL};
        check_keys(L, it, p, keys);
        const cJSON *preset = cJSON_GetObjectItemCaseSensitive(it, "preset");
        int has_eta = cJSON_GetObjectItemCaseSensitive(it, "eta") != NULL;
        snprintf(q, sizeof q, "%s.preset", p);
        if (preset && has_eta)
            return fail(L, q, "give either a preset or eta and k, not both");
        if (preset && !cJSON_IsString(preset))
            return fail(L, q, "expected a name (%s)", material_conductor_presets());
        if (material_conductor_preset(preset ? preset->valuestring : "none", &m->eta, &m->k) < 0)
            return fail(L, q, "unknown conductor \"%s\" (known: %s)", preset->valuestring,
                        material_conductor_presets());
        double eta[3], k[3] = {0, 0, 0};
        if (has_eta) {
            if (get_vec3(L, it, "eta", p, 1, eta) < 0 || get_vec3(L, it, "k", p, 0, k) < 0)
                return -1;
            for (int c = 0; c < 3; c++)
                if (!(eta[c] >= 0 && eta[c] <= 100 && k[c] >= 0 && k[c] <= 100))
                    return fail(L, p, "eta and k must be in [0, 100]");
            if (eta[0] + k[0] == 0 || eta[1] + k[1] == 0 || eta[2] + k[2] == 0)
                return fail(L, p, "eta and k cannot both be 0");
            m->eta = to_vec3(eta);
            m->k = to_vec3(k);
        } else if (cJSON_GetObjectItemCaseSensitive(it, "k")) {
            snprintf(q, sizeof q, "%s.k", p);
            return fail(L, q, "k needs eta");
        }
        return get_vec3(L, it, "reflectance", p, 0, v) < 0 || get_roughness(L, it, p, m) < 0
                   ? -1
                   : get_twosided(L, it, p, m);
    }
    static const char *const keys[] = {"type",         "albedo",    "specular", "ior", "roughness",
                                       "distribution", "nonlinear", "twosided", NULL};
    check_keys(L, it, p, keys);
    double spec[3] = {1, 1, 1}, ior = 1.49 / 1.000277; /* polypropylene in air */
    v[0] = v[1] = v[2] = 0.5;
    const cJSON *albedo = cJSON_GetObjectItemCaseSensitive(it, "albedo");
    if (cJSON_IsObject(albedo) ? parse_texture(L, albedo, p, "albedo", &m->albedo_texture, v) < 0
                               : get_vec3(L, it, "albedo", p, 0, v) < 0)
        return -1;
    if (get_vec3(L, it, "specular", p, 0, spec) < 0 ||
        get_number(L, it, "ior", p, 0, 1.0 / 8, 8.0, &ior) < 0 || get_roughness(L, it, p, m) < 0 ||
        get_twosided(L, it, p, m) < 0)
        return -1;
    for (int c = 0; c < 3; c++)
        if (!(spec[c] >= 0 && spec[c] <= 1))
            return fail(L, p, "specular components must be in [0, 1] (got %g)", spec[c]);
    if (ior == 1.0) {
        snprintf(q, sizeof q, "%s.ior", p);
        return fail(L, q, "a coat of index 1 is not there: use a diffuse material");
    }
    const cJSON *nl = cJSON_GetObjectItemCaseSensitive(it, "nonlinear");
    if (nl && !cJSON_IsBool(nl)) {
        snprintf(q, sizeof q, "%s.nonlinear", p);
        return fail(L, q, "expected true or false");
    }
    m->nonlinear = (uint8_t)(nl && cJSON_IsTrue(nl));
    m->specular = to_vec3(spec);
    m->ior = (float)ior;
    return 0;
}

/* The fields of a material by its type, into *m, and its albedo (or
 * reflectance) into v, still to be range-checked. */
static int parse_material_fields(loader_t *L, const cJSON *it, const char *p, material_t *m,
                                 double v[3])
{
    switch (m->type) {
    case MATERIAL_DIFFUSE: {
        static const char *const keys[] = {"type", "albedo", "twosided", NULL};
        check_keys(L, it, p, keys);
        const cJSON *albedo = cJSON_GetObjectItemCaseSensitive(it, "albedo");
        if (cJSON_IsObject(albedo))
            return parse_texture(L, albedo, p, "albedo", &m->albedo_texture, v) < 0
                       ? -1
                       : get_twosided(L, it, p, m);
        return get_vec3(L, it, "albedo", p, 1, v) < 0 ? -1 : get_twosided(L, it, p, m);
    }
    case MATERIAL_MIRROR: {
        static const char *const keys[] = {"type", "reflectance", NULL};
        check_keys(L, it, p, keys);
        return get_vec3(L, it, "reflectance", p, 0, v);
    }
    case MATERIAL_EMITTER: {
        static const char *const keys[] = {"type", "radiance", "albedo", "twosided", NULL};
        check_keys(L, it, p, keys);
        double rad[3];
        if (get_vec3(L, it, "radiance", p, 1, rad) < 0)
            return -1;
        for (int k = 0; k < 3; k++)
            if (rad[k] < 0 || rad[k] > 1e30)
                return fail(L, p, "radiance must be between 0 and 1e30");
        m->radiance = to_vec3(rad);
        /* a light's own surface may also reflect diffusely (default: black) */
        v[0] = v[1] = v[2] = 0;
        return get_vec3(L, it, "albedo", p, 0, v) < 0 ? -1 : get_twosided(L, it, p, m);
    }
    case MATERIAL_DIELECTRIC: {
        static const char *const keys[] = {"type", "ior", NULL};
        check_keys(L, it, p, keys);
        double ior = 1.5;
        if (get_number(L, it, "ior", p, 0, 1.0 / 8, 8.0, &ior) < 0)
            return -1;
        m->ior = (float)ior;
        return 0;
    }
    case MATERIAL_CONDUCTOR:
    case MATERIAL_PLASTIC:
    case MATERIAL_THIN_DIELECTRIC:
    case MATERIAL_ROUGH_DIELECTRIC:
    case MATERIAL_TYPE_COUNT:
        return parse_glossy_fields(L, it, p, m, v);
    }
    return 0;
}

/* One "name": {material} entry, appended to the scene's table (room for it
 * is allocated). */
static int parse_material(loader_t *L, const cJSON *it)
{
    char p[PATH_LEN];
    snprintf(p, sizeof p, "materials.%s", it->string);
    if (strlen(it->string) == 0 || strlen(it->string) >= MATERIAL_NAME_LEN)
        return fail(L, p, "material name must be 1 to %d characters", MATERIAL_NAME_LEN - 1);
    for (size_t j = 0; j < L->s->material_count; j++)
        if (strcmp(L->s->materials[j].name, it->string) == 0)
            return fail(L, p, "material defined twice");
    if (!cJSON_IsObject(it))
        return fail(L, p, "expected an object with a \"type\"");
    const cJSON *type = cJSON_GetObjectItemCaseSensitive(it, "type");
    if (!cJSON_IsString(type))
        return fail(L, p,
                    "missing \"type\" (diffuse, emitter, mirror, dielectric, conductor, "
                    "plastic, thindielectric or roughdielectric)");
    int t = material_type_from_name(type->valuestring);
    if (t < 0)
        return fail(L, p,
                    "unknown material type \"%s\" (expected diffuse, emitter, mirror, dielectric, "
                    "conductor, plastic, thindielectric or roughdielectric)",
                    type->valuestring);
    material_t *m = &L->s->materials[L->s->material_count];
    memcpy(m->name, it->string, strlen(it->string) + 1);
    m->type = (material_type_t)t;
    m->albedo_texture = -1;
    double v[3] = {1, 1, 1};
    if (parse_material_fields(L, it, p, m, v) < 0)
        return -1;
    if (m->type != MATERIAL_DIELECTRIC)
        for (int k = 0; k < 3; k++)
            if (v[k] < 0 || v[k] > 1)
                return fail(
                    L, p, "%s components must be in [0, 1] (got %g): more would create energy",
                    m->type == MATERIAL_MIRROR || m->type == MATERIAL_CONDUCTOR ? "reflectance"
                                                                                : "albedo",
                    v[k]);
    m->albedo = to_vec3(v);
    float mean = (float)(v[0] + v[1] + v[2]) / 3.0f;
    if (m->albedo_texture >= 0) {
        /* Mitsuba's mean of a checkerboard: of its two colours */
        const texture_t *t = &L->s->textures[m->albedo_texture];
        mean = (t->color0.x + t->color0.y + t->color0.z + t->color1.x + t->color1.y + t->color1.z) /
               6.0f;
    }
    if (!L->check_only)
        material_prepare(m, mean, L->s->materials, L->s->material_count);
    L->s->material_count++;
    return 0;
}

static int parse_materials(loader_t *L, const cJSON *root)
{
    const cJSON *mats = cJSON_GetObjectItemCaseSensitive(root, "materials");
    if (!mats)
        return fail(L, "materials", "missing");
    if (!cJSON_IsObject(mats))
        return fail(L, "materials", "expected an object of name: material");
    int n = cJSON_GetArraySize(mats);
    if (n == 0)
        return fail(L, "materials", "no materials defined");
    L->s->materials = calloc((size_t)n, sizeof(material_t));
    if (!L->s->materials)
        return fail(L, "materials", "out of memory");
    for (const cJSON *it = mats->child; it; it = it->next)
        if (parse_material(L, it) < 0)
            return -1;
    return 0;
}

static int find_material(loader_t *L, const cJSON *shape, const char *path, uint32_t *out)
{
    const cJSON *m = cJSON_GetObjectItemCaseSensitive(shape, "material");
    char p[PATH_LEN];
    snprintf(p, sizeof p, "%s.material", path);
    if (!cJSON_IsString(m))
        return fail(L, p, "missing (expected a material name)");
    for (size_t i = 0; i < L->s->material_count; i++)
        if (strcmp(L->s->materials[i].name, m->valuestring) == 0) {
            *out = (uint32_t)i;
            return 0;
        }
    return fail(L, p, "unknown material \"%s\"", m->valuestring);
}

/* ---- transforms --------------------------------------------------------- */

static void mat_mul(double a[3][3], double b[3][3], double out[3][3])
{
    double r[3][3];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            r[i][j] = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
    memcpy(out, r, sizeof r);
}

static void rotation(int axis, double deg, double r[3][3])
{
    double a = deg * 3.14159265358979323846 / 180.0, c = cos(a), s = sin(a);
    memset(r, 0, 9 * sizeof(double));
    int i = (axis + 1) % 3, j = (axis + 2) % 3;
    r[axis][axis] = 1;
    r[i][i] = c;
    r[i][j] = -s;
    r[j][i] = s;
    r[j][j] = c;
}

/* "matrix": 16 numbers, a 4x4 affine transform row by row (last row
 * 0 0 0 1), alone in its transform: what an imported scene (mitsuba.c)
 * composes. */
static int parse_matrix(loader_t *L, const cJSON *t, const cJSON *mx, const char *p, xform_t *x)
{
    char q[PATH_LEN];
    snprintf(q, sizeof q, "%s.matrix", p);
    if (cJSON_GetArraySize(t) != 1)
        return fail(L, p, "\"matrix\" takes no scale, rotate or translate beside it");
    double e[16];
    int n = 0;
    for (const cJSON *it = cJSON_IsArray(mx) ? mx->child : NULL; it; it = it->next, n++) {
        if (n == 16 || !cJSON_IsNumber(it) || !isfinite(it->valuedouble))
            return fail(L, q, "expected 16 finite numbers (a 4x4 matrix, row by row)");
        e[n] = it->valuedouble;
    }
    if (n != 16)
        return fail(L, q, "expected 16 finite numbers (a 4x4 matrix, row by row)");
    if (e[12] != 0 || e[13] != 0 || e[14] != 0 || e[15] != 1)
        return fail(L, q, "the last row must be 0 0 0 1 (an affine transform)");
    for (int i = 0; i < 3; i++) {
        for (int j = 0; j < 3; j++)
            x->m[i][j] = e[4 * i + j];
        x->t[i] = e[4 * i + 3];
    }
    const double(*m)[3] = x->m;
    double det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) -
                 m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
                 m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    if (!(fabs(det) > 0) || !isfinite(1.0 / det))
        return fail(L, q, "the matrix is singular");
    /* normals: the inverse transpose, the cofactors over det */
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            int i1 = (i + 1) % 3, i2 = (i + 2) % 3, j1 = (j + 1) % 3, j2 = (j + 2) % 3;
            x->nm[i][j] = (m[i1][j1] * m[i2][j2] - m[i1][j2] * m[i2][j1]) / det;
        }
    x->flips = det < 0;
    return 0;
}

/* transform: {"scale": s | [sx,sy,sz], "rotate": [x,y,z] degrees (applied X,
 * then Y, then Z), "translate": [x,y,z]}; scale first, translate last; or
 * {"matrix": [16 numbers]} (parse_matrix). */
static int parse_transform(loader_t *L, const cJSON *shape, const char *path, xform_t *x)
{
    memset(x, 0, sizeof *x);
    for (int i = 0; i < 3; i++)
        x->m[i][i] = x->nm[i][i] = 1;
    const cJSON *t = cJSON_GetObjectItemCaseSensitive(shape, "transform");
    if (!t)
        return 0;
    char p[PATH_LEN];
    snprintf(p, sizeof p, "%s.transform", path);
    if (!cJSON_IsObject(t))
        return fail(L, p, "expected an object");
    static const char *const keys[] = {"scale", "rotate", "translate", "matrix", NULL};
    check_keys(L, t, p, keys);
    const cJSON *mx = cJSON_GetObjectItemCaseSensitive(t, "matrix");
    if (mx)
        return parse_matrix(L, t, mx, p, x);
    double sc[3] = {1, 1, 1}, rot[3] = {0, 0, 0};
    const cJSON *s = cJSON_GetObjectItemCaseSensitive(t, "scale");
    if (cJSON_IsNumber(s)) {
        sc[0] = sc[1] = sc[2] = s->valuedouble;
    } else if (s) {
        char q[PATH_LEN];
        snprintf(q, sizeof q, "%s.scale", p);
        if (parse_vec3_item(L, s, q, sc) < 0)
            return -1;
    }
    for (int i = 0; i < 3; i++)
        if (!isfinite(sc[i]) || sc[i] == 0)
            return fail(L, p, "scale must be finite and non-zero");
    if (get_vec3(L, t, "rotate", p, 0, rot) < 0 || get_vec3(L, t, "translate", p, 0, x->t) < 0)
        return -1;
    double S[3][3] = {{sc[0], 0, 0}, {0, sc[1], 0}, {0, 0, sc[2]}}, R[3][3];
    double M[3][3];
    memcpy(M, S, sizeof M);
    for (int axis = 0; axis < 3; axis++) {
        rotation(axis, rot[axis], R);
        mat_mul(R, M, M);
    }
    memcpy(x->m, M, sizeof M);
    /* normals: R * S^-1 */
    double Si[3][3] = {{1 / sc[0], 0, 0}, {0, 1 / sc[1], 0}, {0, 0, 1 / sc[2]}};
    memcpy(M, Si, sizeof M);
    for (int axis = 0; axis < 3; axis++) {
        rotation(axis, rot[axis], R);
        mat_mul(R, M, M);
    }
    memcpy(x->nm, M, sizeof M);
    x->flips = sc[0] * sc[1] * sc[2] < 0;
    return 0;
}

/* ---- geometry accumulation --------------------------------------------- */

static int reserve(loader_t *L, size_t add_v, size_t add_t, int with_normals)
{
    if (add_v > MAX_VERTICES - L->nv)
        return fail(L, NULL, "too many vertices (more than %u)", MAX_VERTICES);
    if (L->nv + add_v > L->cap_v) {
        size_t cap = L->cap_v ? L->cap_v : 1024;
        while (cap < L->nv + add_v)
            cap *= 2;
        float *p = realloc(L->pos, cap * 3 * sizeof(float));
        if (!p)
            return fail(L, NULL, "out of memory for %zu vertices", cap);
        L->pos = p;
        if (L->want_uv) {
            float *u = realloc(L->uv, cap * 2 * sizeof(float));
            if (!u)
                return fail(L, NULL, "out of memory for %zu vertices", cap);
            L->uv = u;
        }
        if (L->nrm) {
            float *n = realloc(L->nrm, cap * 3 * sizeof(float));
            if (!n)
                return fail(L, NULL, "out of memory for %zu vertices", cap);
            L->nrm = n;
        }
        L->cap_v = cap;
    }
    if (with_normals && !L->nrm) {
        L->nrm = calloc(L->cap_v * 3, sizeof(float));
        if (!L->nrm)
            return fail(L, NULL, "out of memory for normals");
    }
    if (L->nt + add_t > L->cap_t) {
        size_t cap = L->cap_t ? L->cap_t : 1024;
        while (cap < L->nt + add_t)
            cap *= 2;
        uint32_t *i = realloc(L->idx, cap * 3 * sizeof(uint32_t));
        if (!i)
            return fail(L, NULL, "out of memory for %zu triangles", cap);
        L->idx = i;
        uint32_t *m = realloc(L->mat, cap * sizeof(uint32_t));
        if (!m)
            return fail(L, NULL, "out of memory for %zu triangles", cap);
        L->mat = m;
        L->cap_t = cap;
    }
    return 0;
}

/* Appends a transformed vertex (capacity reserved by the caller). */
static void push_vertex(loader_t *L, const xform_t *x, const double p[3], const double *n)
{
    float *d = L->pos + 3 * L->nv;
    if (L->uv)
        L->uv[2 * L->nv] = L->uv[2 * L->nv + 1] = 0.0f;
    for (int i = 0; i < 3; i++)
        d[i] = (float)(x->m[i][0] * p[0] + x->m[i][1] * p[1] + x->m[i][2] * p[2] + x->t[i]);
    if (L->nrm) {
        float *dn = L->nrm + 3 * L->nv;
        dn[0] = dn[1] = dn[2] = 0;
        if (n) {
            double w[3], len = 0;
            for (int i = 0; i < 3; i++) {
                w[i] = x->nm[i][0] * n[0] + x->nm[i][1] * n[1] + x->nm[i][2] * n[2];
                len += w[i] * w[i];
            }
            len = sqrt(len);
            if (len > 0 && isfinite(len))
                for (int i = 0; i < 3; i++)
                    dn[i] = (float)(w[i] / len);
        }
    }
    L->nv++;
}

static int check_coords(loader_t *L, const char *path, size_t first)
{
    for (size_t v = first; v < L->nv; v++)
        for (int i = 0; i < 3; i++)
            if (!isfinite(L->pos[3 * v + i]))
                return fail(L, path, "vertex %zu is not finite after the transform (overflow)",
                            v - first);
    return 0;
}

static void push_triangle(loader_t *L, const xform_t *x, uint32_t a, uint32_t b, uint32_t c,
                          uint32_t mat)
{
    uint32_t *d = L->idx + 3 * L->nt;
    d[0] = a;
    d[1] = x->flips ? c : b;
    d[2] = x->flips ? b : c;
    L->mat[L->nt++] = mat;
}

static int parse_points(loader_t *L, const cJSON *arr, const char *path, size_t want,
                        double (*out)[3])
{
    if (!cJSON_IsArray(arr))
        return fail(L, path, "missing or not an array of points");
    if (want && (size_t)cJSON_GetArraySize(arr) != want)
        return fail(L, path, "expected %zu points, got %d", want, cJSON_GetArraySize(arr));
    size_t i = 0;
    for (const cJSON *e = arr->child; e; e = e->next, i++) {
        char p[PATH_LEN];
        snprintf(p, sizeof p, "%s[%zu]", path, i);
        if (parse_vec3_item(L, e, p, out[i]) < 0)
            return -1;
    }
    return 0;
}

static int shape_quad(loader_t *L, const cJSON *sh, const char *path, const xform_t *x,
                      uint32_t mat)
{
    static const char *const keys[] = {"type", "material", "vertices", "transform", NULL};
    check_keys(L, sh, path, keys);
    double v[4][3];
    char p[PATH_LEN];
    snprintf(p, sizeof p, "%s.vertices", path);
    if (parse_points(L, cJSON_GetObjectItemCaseSensitive(sh, "vertices"), p, 4, v) < 0)
        return -1;
    if (reserve(L, 4, 2, 0) < 0)
        return -1;
    uint32_t base = (uint32_t)L->nv;
    for (int i = 0; i < 4; i++)
        push_vertex(L, x, v[i], NULL);
    push_triangle(L, x, base, base + 1, base + 2, mat);
    push_triangle(L, x, base, base + 2, base + 3, mat);
    return check_coords(L, path, base);
}

static int shape_triangles(loader_t *L, const cJSON *sh, const char *path, const xform_t *x,
                           uint32_t mat)
{
    static const char *const keys[] = {"type",      "material", "vertices", "indices",
                                       "transform", "uvs",      NULL};
    check_keys(L, sh, path, keys);
    const cJSON *va = cJSON_GetObjectItemCaseSensitive(sh, "vertices");
    const cJSON *ia = cJSON_GetObjectItemCaseSensitive(sh, "indices");
    char p[PATH_LEN];
    snprintf(p, sizeof p, "%s.vertices", path);
    if (!cJSON_IsArray(va) || cJSON_GetArraySize(va) < 3)
        return fail(L, p, "expected an array of at least 3 points");
    size_t nv = (size_t)cJSON_GetArraySize(va);
    snprintf(p, sizeof p, "%s.indices", path);
    if (!cJSON_IsArray(ia) || cJSON_GetArraySize(ia) < 1)
        return fail(L, p, "expected an array of [a, b, c] index triples");
    size_t nt = (size_t)cJSON_GetArraySize(ia);
    if (reserve(L, nv, nt, 0) < 0)
        return -1;
    uint32_t base = (uint32_t)L->nv;
    size_t i = 0;
    /* "uvs": a texture coordinate pair per vertex (optional) */
    const cJSON *ua = cJSON_GetObjectItemCaseSensitive(sh, "uvs");
    if (ua && (!cJSON_IsArray(ua) || (size_t)cJSON_GetArraySize(ua) != nv)) {
        snprintf(p, sizeof p, "%s.uvs", path);
        return fail(L, p, "expected one [u, v] per vertex (%zu)", nv);
    }
    const cJSON *ue = ua ? ua->child : NULL;
    for (const cJSON *e = va->child; e; e = e->next, i++) {
        double v[3];
        snprintf(p, sizeof p, "%s.vertices[%zu]", path, i);
        if (parse_vec3_item(L, e, p, v) < 0)
            return -1;
        push_vertex(L, x, v, NULL);
        if (ue) {
            snprintf(p, sizeof p, "%s.uvs[%zu]", path, i);
            const cJSON *a = cJSON_GetArrayItem(ue, 0), *b = cJSON_GetArrayItem(ue, 1);
            if (!cJSON_IsArray(ue) || cJSON_GetArraySize(ue) != 2 || !cJSON_IsNumber(a) ||
                !cJSON_IsNumber(b) || !(fabs(a->valuedouble) <= 1e30) ||
                !(fabs(b->valuedouble) <= 1e30))
                return fail(L, p, "expected [u, v], two finite numbers");
            if (L->uv) {
                L->uv[2 * (L->nv - 1)] = (float)a->valuedouble;
                L->uv[2 * (L->nv - 1) + 1] = (float)b->valuedouble;
            }
            ue = ue->next;
        }
    }
    i = 0;
    for (const cJSON *e = ia->child; e; e = e->next, i++) {
        snprintf(p, sizeof p, "%s.indices[%zu]", path, i);
        if (!cJSON_IsArray(e) || cJSON_GetArraySize(e) != 3)
            return fail(L, p, "expected [a, b, c]");
        uint32_t t[3];
        int k = 0;
        for (const cJSON *c = e->child; c; c = c->next, k++) {
            double d = cJSON_IsNumber(c) ? c->valuedouble : -1;
            if (!cJSON_IsNumber(c) || d != floor(d))
                return fail(L, p, "index %d is not an integer", k);
            if (d < 0 || d >= (double)nv)
                return fail(L, p, "index %g out of range (the shape has %zu vertices)", d, nv);
            t[k] = base + (uint32_t)d;
        }
        push_triangle(L, x, t[0], t[1], t[2], mat);
    }
    return check_coords(L, path, base);
}

static int shape_mesh(loader_t *L, const cJSON *sh, const char *path, const xform_t *x,
                      uint32_t mat)
{
    static const char *const keys[] = {"type",    "material",     "file",        "transform",
                                       "normals", "flip_normals", "shape_index", NULL};
    check_keys(L, sh, path, keys);
    const cJSON *f = cJSON_GetObjectItemCaseSensitive(sh, "file");
    char p[PATH_LEN];
    /* "normals": "file" (the file's vertex normals: PLY's, not OBJ's vn;
     * else flat), "face" (flat) or "file_or_smooth" (PLY's or OBJ's, else
     * angle-weighted vertex normals, as Mitsuba reads a mesh);
     * "flip_normals" turns every face */
    const cJSON *nj = cJSON_GetObjectItemCaseSensitive(sh, "normals");
    const cJSON *fj = cJSON_GetObjectItemCaseSensitive(sh, "flip_normals");
    enum { NORMALS_FILE, NORMALS_FACE, NORMALS_SMOOTH } normals = NORMALS_FILE;
    if (nj) {
        const char *v = cJSON_IsString(nj) ? nj->valuestring : "";
        snprintf(p, sizeof p, "%s.normals", path);
        if (strcmp(v, "face") == 0)
            normals = NORMALS_FACE;
        else if (strcmp(v, "file_or_smooth") == 0)
            normals = NORMALS_SMOOTH;
        else if (strcmp(v, "file") != 0)
            return fail(L, p, "expected \"file\", \"face\" or \"file_or_smooth\"");
    }
    if (fj && !cJSON_IsBool(fj)) {
        snprintf(p, sizeof p, "%s.flip_normals", path);
        return fail(L, p, "expected true or false");
    }
    xform_t xf = *x;
    xf.flips ^= cJSON_IsTrue(fj);
    x = &xf;
    /* "file" keeps what our scenes always had: OBJ vn unread */
    unsigned mesh_flags = normals == NORMALS_SMOOTH ? MESH_ATTRIBUTES : 0;
    if (normals == NORMALS_FACE && L->want_uv)
        mesh_flags = MESH_ATTRIBUTES; /* the coordinates; the normals are dropped below */
    /* "shape_index": which shape of a file of several (Mitsuba's
     * .serialized); 0 */
    double shape_d = 0;
    if (get_integer(L, sh, "shape_index", path, 0, 0, 4294967295.0, &shape_d) < 0)
        return -1;
    uint32_t shape_index = (uint32_t)shape_d;
    snprintf(p, sizeof p, "%s.file", path);
    if (!cJSON_IsString(f) || !*f->valuestring)
        return fail(L, p, "missing (expected a mesh path relative to the scene file)");
    mesh_t *m = NULL;
    char merr[VB_ERR_LEN];
    if (L->blobs) {
        const scene_blob_t *b = NULL;
        for (size_t i = 0; i < L->blob_count && !b; i++)
            if (strcmp(L->blobs[i].name, f->valuestring) == 0)
                b = &L->blobs[i];
        if (!b)
            return fail(L, p, "mesh \"%s\" is not in the scene bundle", f->valuestring);
        if (mesh_load_buffer_flags(b->name, b->data, b->size, mesh_flags, shape_index, &m, merr,
                                   sizeof merr) < 0)
            return fail(L, p, "%s", merr);
    } else {
        char full[4096];
        if (f->valuestring[0] == '/' || !L->base_dir || !*L->base_dir)
            snprintf(full, sizeof full, "%s", f->valuestring);
        else
            snprintf(full, sizeof full, "%s/%s", L->base_dir, f->valuestring);
        if (mesh_load_flags(full, mesh_flags, shape_index, &m, merr, sizeof merr) < 0)
            return fail(L, p, "%s", merr);
    }
    if (normals == NORMALS_FACE) {
        free(m->normals);
        m->normals = NULL;
    } else if (normals == NORMALS_SMOOTH && !m->normals && mesh_smooth_normals(m) < 0) {
        mesh_destroy(&m);
        return fail(L, path, "out of memory for the mesh's normals");
    }
    int rc = reserve(L, m->vertex_count, m->triangle_count, m->normals != NULL);
    if (rc == 0) {
        uint32_t base = (uint32_t)L->nv;
        for (size_t v = 0; v < m->vertex_count; v++) {
            double pd[3] = {m->positions[3 * v], m->positions[3 * v + 1], m->positions[3 * v + 2]};
            double nd[3];
            if (m->normals)
                for (int i = 0; i < 3; i++)
                    nd[i] = m->normals[3 * v + i];
            push_vertex(L, x, pd, m->normals ? nd : NULL);
            if (L->uv && m->uvs) {
                L->uv[2 * (L->nv - 1)] = m->uvs[2 * v];
                L->uv[2 * (L->nv - 1) + 1] = m->uvs[2 * v + 1];
            }
        }
        for (size_t t = 0; t < m->triangle_count; t++)
            push_triangle(L, x, base + m->indices[3 * t], base + m->indices[3 * t + 1],
                          base + m->indices[3 * t + 2], mat);
        rc = check_coords(L, path, base);
    }
    mesh_destroy(&m);
    return rc;
}

/* A vertex with texture coordinates (u, v), when the scene keeps them. */
static void push_vertex_uv(loader_t *L, const xform_t *x, const double p[3], const double *n,
                           double u, double v)
{
    push_vertex(L, x, p, n);
    if (L->uv) {
        L->uv[2 * (L->nv - 1)] = (float)u;
        L->uv[2 * (L->nv - 1) + 1] = (float)v;
    }
}

/* Mitsuba's texture coordinates of a sphere, (phi / 2 pi, theta / pi)
 * with phi in [0, 2 pi) about +z and theta from +z, at a triangle's three
 * unit directions: a triangle across the seam (phi 0) takes its corners'
 * phi on the same side, and a corner at a pole (where phi is any angle)
 * the other two's mean. */
static void sphere_uvs(const double n[3][3], double uv[3][2])
{
    int pole[3];
    for (int q = 0; q < 3; q++) {
        double phi = atan2(n[q][1], n[q][0]);
        if (phi < 0)
            phi += 2 * M_PI;
        uv[q][0] = phi / (2 * M_PI);
        uv[q][1] = acos(fmax(-1.0, fmin(1.0, n[q][2]))) / M_PI;
        pole[q] = fabs(n[q][0]) < 1e-12 && fabs(n[q][1]) < 1e-12;
    }
    double lo = 1, hi = 0;
    for (int q = 0; q < 3; q++)
        if (!pole[q]) {
            lo = fmin(lo, uv[q][0]);
            hi = fmax(hi, uv[q][0]);
        }
    for (int q = 0; q < 3; q++)
        if (!pole[q] && hi - lo > 0.5 && uv[q][0] < 0.5)
            uv[q][0] += 1;
    for (int q = 0; q < 3; q++)
        if (pole[q]) {
            double sum = 0;
            int cnt = 0;
            for (int o = 0; o < 3; o++)
                if (!pole[o]) {
                    sum += uv[o][0];
                    cnt++;
                }
            uv[q][0] = cnt ? sum / cnt : 0;
        }
}

/* An emitting sphere, for light samples through the cone it subtends
 * (scene_sphere_t): when its material emits and its transform keeps it a
 * sphere (a similarity: orthogonal columns of one length). */
static int note_sphere_light(loader_t *L, const xform_t *x, const double c[3], double r,
                             uint32_t mat, size_t first_tri)
{
    const material_t *m = &L->s->materials[mat];
    if (m->type != MATERIAL_EMITTER ||
        !(vmath_luminance(m->radiance.x, m->radiance.y, m->radiance.z) > 0))
        return 0;
    double len[3], dot = 0;
    for (int j = 0; j < 3; j++)
        len[j] = sqrt(x->m[0][j] * x->m[0][j] + x->m[1][j] * x->m[1][j] + x->m[2][j] * x->m[2][j]);
    for (int a = 0; a < 3; a++)
        for (int b = a + 1; b < 3; b++)
            dot = fmax(dot, fabs(x->m[0][a] * x->m[0][b] + x->m[1][a] * x->m[1][b] +
                                 x->m[2][a] * x->m[2][b]) /
                                (len[a] * len[b]));
    if (dot > 1e-6 || fabs(len[1] / len[0] - 1) > 1e-6 || fabs(len[2] / len[0] - 1) > 1e-6)
        return 0; /* an ellipsoid: sampled by area */
    size_t n = L->nsph + 1;
    scene_sphere_t *sph = realloc(L->sph, n * sizeof *sph);
    size_t *fi = sph ? realloc(L->sph_first, n * sizeof *fi) : NULL;
    if (sph)
        L->sph = sph;
    if (fi)
        L->sph_first = fi;
    size_t *ct = fi ? realloc(L->sph_tris, n * sizeof *ct) : NULL;
    if (!ct)
        return fail(L, NULL, "out of memory");
    L->sph_tris = ct;
    double w[3];
    for (int i = 0; i < 3; i++)
        w[i] = x->m[i][0] * c[0] + x->m[i][1] * c[1] + x->m[i][2] * c[2] + x->t[i];
    L->sph[L->nsph] = (scene_sphere_t){.center = to_vec3(w), .radius = (float)(r * len[0])};
    L->sph_first[L->nsph] = first_tri;
    L->sph_tris[L->nsph] = L->nt - first_tri;
    L->nsph++;
    return 0;
}

double scene_icosphere_gap(int subdivisions)
{
    /* 1 - the least distance from the centre to a face's plane, over the
     * faces shape_sphere makes (the face nearest the centre is the one
     * whose corners are farthest apart; each face's nearest point to the
     * centre lies inside it); test_scene measures it on the meshes */
    static const double gap[SCENE_MAX_SPHERE_SUBDIVISIONS + 1] = {
        0.2053456,   0.06582765,  0.01775306,  0.004528368,
        0.001137884, 2.848354e-4, 7.123167e-5, 1.780935e-5};
    if (subdivisions < 0)
        return 1.0;
    if (subdivisions > SCENE_MAX_SPHERE_SUBDIVISIONS)
        subdivisions = SCENE_MAX_SPHERE_SUBDIVISIONS;
    return gap[subdivisions];
}

/* An icosphere: the icosahedron subdivided n times, vertices pushed onto the
 * sphere, with exact normals (p - c) / r for smooth shading. Vertices are not
 * shared between faces; they are computed identically on both sides of an
 * edge (commutative midpoints), so the surface is watertight. */
static int shape_sphere(loader_t *L, const cJSON *sh, const char *path, const xform_t *x,
                        uint32_t mat)
{
    static const char *const keys[] = {"type",         "material",  "center", "radius",
                                       "subdivisions", "transform", NULL};
    check_keys(L, sh, path, keys);
    double c[3], r = 0, sub = 4;
    if (get_vec3(L, sh, "center", path, 1, c) < 0 ||
        get_number(L, sh, "radius", path, 1, 1e-30, 1e30, &r) < 0 ||
        get_integer(L, sh, "subdivisions", path, 0, 0, SCENE_MAX_SPHERE_SUBDIVISIONS, &sub) < 0)
        return -1;
    const double g = (1.0 + sqrt(5.0)) / 2.0;
    static const int faces[20][3] = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                                     {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                                     {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                                     {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
    double ico[12][3] = {{-1, g, 0},  {1, g, 0},  {-1, -g, 0}, {1, -g, 0}, {0, -1, g},  {0, 1, g},
                         {0, -1, -g}, {0, 1, -g}, {g, 0, -1},  {g, 0, 1},  {-g, 0, -1}, {-g, 0, 1}};
    size_t n = (size_t)sub, per_face = (size_t)1 << (2 * n), ntri = 20 * per_face;
    if (reserve(L, 3 * ntri, ntri, 1) < 0)
        return -1;
    uint32_t first = (uint32_t)L->nv;
    size_t first_tri = L->nt;
    /* Each face is split into a (2^n)^2 grid of sub-triangles by barycentric
     * steps; each corner is projected onto the unit sphere. */
    size_t k = (size_t)1 << n;
    for (int f = 0; f < 20; f++) {
        const double *A = ico[faces[f][0]], *B = ico[faces[f][1]], *C = ico[faces[f][2]];
        for (size_t i = 0; i < k; i++)
            for (size_t j = 0; j + i < k; j++)
                for (int up = 0; up < 2; up++) {
                    if (up && i + j + 1 >= k)
                        continue;
                    size_t bi[3][2] = {{i, j}, {i + 1, j}, {i, j + 1}};
                    if (up) {
                        size_t alt[3][2] = {{i + 1, j}, {i + 1, j + 1}, {i, j + 1}};
                        memcpy(bi, alt, sizeof bi);
                    }
                    uint32_t vid[3];
                    double nrm[3][3], uv[3][2];
                    for (int q = 0; q < 3; q++) {
                        double a = (double)bi[q][0] / (double)k, b = (double)bi[q][1] / (double)k;
                        double len = 0;
                        for (int d = 0; d < 3; d++) {
                            nrm[q][d] = A[d] * (1 - a - b) + B[d] * a + C[d] * b;
                            len += nrm[q][d] * nrm[q][d];
                        }
                        len = sqrt(len);
                        for (int d = 0; d < 3; d++)
                            nrm[q][d] /= len;
                    }
                    if (L->uv)
                        sphere_uvs(nrm, uv);
                    for (int q = 0; q < 3; q++) {
                        double pnt[3];
                        for (int d = 0; d < 3; d++)
                            pnt[d] = c[d] + r * nrm[q][d];
                        vid[q] = (uint32_t)L->nv;
                        push_vertex_uv(L, x, pnt, nrm[q], L->uv ? uv[q][0] : 0,
                                       L->uv ? uv[q][1] : 0);
                    }
                    push_triangle(L, x, vid[0], vid[1], vid[2], mat);
                }
    }
    if (check_coords(L, path, first) < 0)
        return -1;
    return note_sphere_light(L, x, c, r, mat, first_tri);
}

/* Mitsuba's disk and cylinder as triangles: the unit disk in the xy
 * plane (normal +z, texture coordinates (r, phi / 2 pi) with phi in
 * [-pi, pi]), or the open cylinder of radius 1 from z 0 to 1 (normals
 * outward and exact at the vertices, coordinates (phi / 2 pi, z) with phi
 * in [0, 2 pi)), each around its axis in "segments" (default 512: the
 * polygon's area is within 3e-5 of the circle's). The seam's vertices
 * are shared by position, so the surface is watertight there. */
static int shape_round(loader_t *L, const cJSON *sh, const char *path, const xform_t *x,
                       uint32_t mat, int cylinder)
{
    static const char *const keys[] = {"type",      "material",     "segments",
                                       "transform", "flip_normals", NULL};
    check_keys(L, sh, path, keys);
    double seg = 512;
    if (get_integer(L, sh, "segments", path, 0, 3, 65536, &seg) < 0)
        return -1;
    const cJSON *fl = cJSON_GetObjectItemCaseSensitive(sh, "flip_normals");
    if (fl && !cJSON_IsBool(fl))
        return fail(L, path, "flip_normals: expected true or false");
    int flip = fl && cJSON_IsTrue(fl);
    double out = flip ? -1 : 1; /* which way the normals face */
    size_t n = (size_t)seg, rings = cylinder ? 1 : 16;
    if (reserve(L, (n + 1) * (rings + 1), 2 * n * rings, 1) < 0)
        return -1;
    uint32_t first = (uint32_t)L->nv;
    for (size_t j = 0; j <= rings; j++)
        for (size_t i = 0; i <= n; i++) {
            /* the seam's two columns: the same angle, exactly */
            double t = (i == n ? 0 : (double)i / (double)n);
            double phi = cylinder ? 2 * M_PI * t : -M_PI + 2 * M_PI * t;
            double c = cos(phi), sn = sin(phi), f = (double)j / (double)rings;
            double u = cylinder ? (double)i / (double)n : f;
            double v = cylinder ? f : (double)i / (double)n - 0.5;
            if (cylinder) {
                double pt[3] = {c, sn, f}, nrm[3] = {out * c, out * sn, 0};
                push_vertex_uv(L, x, pt, nrm, u, v);
            } else {
                double pt[3] = {f * c, f * sn, 0}, nrm[3] = {0, 0, out};
                push_vertex_uv(L, x, pt, nrm, u, v);
            }
        }
    for (size_t j = 0; j < rings; j++)
        for (size_t i = 0; i < n; i++) {
            uint32_t a = first + (uint32_t)(j * (n + 1) + i), b = a + 1;
            uint32_t c = a + (uint32_t)(n + 1), d = c + 1;
            /* counter-clockwise seen from the normal's side; the disk's
             * centre ring is a fan (its other half would have no area) */
            uint32_t t[2][3] = {{a, b, d}, {a, d, c}};
            if (!cylinder) {
                uint32_t disk[2][3] = {{a, d, b}, {a, c, d}};
                memcpy(t, disk, sizeof t);
            }
            for (int k = cylinder || j > 0 ? 0 : 1; k < 2; k++)
                push_triangle(L, x, t[k][0], t[k][flip ? 2 : 1], t[k][flip ? 1 : 2], mat);
        }
    return check_coords(L, path, first);
}

static int parse_shapes(loader_t *L, const cJSON *root)
{
    const cJSON *shapes = cJSON_GetObjectItemCaseSensitive(root, "shapes");
    if (!shapes)
        return fail(L, "shapes", "missing");
    if (!cJSON_IsArray(shapes))
        return fail(L, "shapes", "expected an array");
    size_t i = 0;
    for (const cJSON *sh = shapes->child; sh; sh = sh->next, i++) {
        char p[PATH_LEN];
        snprintf(p, sizeof p, "shapes[%zu]", i);
        if (!cJSON_IsObject(sh))
            return fail(L, p, "expected an object");
        const cJSON *type = cJSON_GetObjectItemCaseSensitive(sh, "type");
        if (!cJSON_IsString(type))
            return fail(L, p, "missing \"type\" (quad, triangles, mesh, sphere, disk or cylinder)");
        uint32_t mat = 0;
        xform_t x;
        if (find_material(L, sh, p, &mat) < 0 || parse_transform(L, sh, p, &x) < 0)
            return -1;
        int rc;
        if (strcmp(type->valuestring, "quad") == 0)
            rc = shape_quad(L, sh, p, &x, mat);
        else if (strcmp(type->valuestring, "triangles") == 0)
            rc = shape_triangles(L, sh, p, &x, mat);
        else if (strcmp(type->valuestring, "mesh") == 0)
            rc = shape_mesh(L, sh, p, &x, mat);
        else if (strcmp(type->valuestring, "sphere") == 0)
            rc = shape_sphere(L, sh, p, &x, mat);
        else if (strcmp(type->valuestring, "disk") == 0 ||
                 strcmp(type->valuestring, "cylinder") == 0)
            rc = shape_round(L, sh, p, &x, mat, strcmp(type->valuestring, "cylinder") == 0);
        else
            rc = fail(L, p,
                      "unknown shape type \"%s\" (expected quad, triangles, mesh, sphere, disk or "
                      "cylinder)",
                      type->valuestring);
        if (rc < 0)
            return -1;
    }
    return 0;
}

/* ---- finishing: normals, degenerate triangles, lights ------------------ */

/* Hands the loader's arrays to the scene, so scene_destroy frees them on
 * any error from here on. */
static void hand_over_arrays(loader_t *L)
{
    scene_t *s = L->s;
    s->positions = L->pos;
    s->normals = L->nrm;
    s->uvs = L->uv;
    s->vertex_count = L->nv;
    s->indices = L->idx;
    s->tri_material = L->mat;
    L->pos = L->nrm = L->uv = NULL;
    L->idx = L->mat = NULL;
}

/* The geometric normal of triangle v (unnormalised) and its length, from
 * the float positions the tracer will see, in double. 0 when the triangle
 * has no area there (it could only produce NaNs), else 1. */
static int face_normal(const scene_t *s, const uint32_t *v, double n[3], double *len)
{
    double p[3][3];
    for (int k = 0; k < 3; k++)
        for (int d = 0; d < 3; d++)
            p[k][d] = s->positions[3 * v[k] + d];
    double e1[3], e2[3];
    for (int d = 0; d < 3; d++) {
        e1[d] = p[1][d] - p[0][d];
        e2[d] = p[2][d] - p[0][d];
    }
    n[0] = e1[1] * e2[2] - e1[2] * e2[1];
    n[1] = e1[2] * e2[0] - e1[0] * e2[2];
    n[2] = e1[0] * e2[1] - e1[1] * e2[0];
    *len = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    return (*len > 0) && isfinite(*len) && isfinite((float)(n[0] / *len));
}

/* Light power of the triangles kept, filled by keep_triangles. */
typedef struct light_sum {
    double *power; /* per kept triangle; 0 when not a light */
    double total;
    size_t lights;
    double *sphere_len; /* per kept triangle of an emitting sphere: its normal's
                         * length (finish_spheres); NULL without spheres */
} light_sum_t;

/* Drops degenerate triangles (compacting indices and materials) and gives
 * the kept ones their normal, smooth flag and light power. Returns how many
 * are kept. */
static size_t keep_triangles(scene_t *s, size_t nt, light_sum_t *ls)
{
    size_t kept = 0;
    for (size_t t = 0; t < nt; t++) {
        const uint32_t *v = s->indices + 3 * t;
        double n[3], len;
        if (!face_normal(s, v, n, &len)) {
            s->dropped_degenerate++;
            continue;
        }
        if (kept != t) {
            memmove(s->indices + 3 * kept, v, 3 * sizeof(uint32_t));
            s->tri_material[kept] = s->tri_material[t];
            if (s->tri_sphere)
                s->tri_sphere[kept] = s->tri_sphere[t];
        }
        s->tri_normal[kept] =
            vec3_make((float)(n[0] / len), (float)(n[1] / len), (float)(n[2] / len));
        if (ls->sphere_len)
            ls->sphere_len[kept] = len;
        int smooth = s->normals != NULL;
        for (int k = 0; smooth && k < 3; k++) {
            const float *vn = s->normals + 3 * s->indices[3 * kept + k];
            smooth = !(vn[0] == 0 && vn[1] == 0 && vn[2] == 0);
        }
        s->tri_smooth[kept] = (uint8_t)smooth;
        const material_t *m = &s->materials[s->tri_material[kept]];
        if (m->type == MATERIAL_EMITTER) {
            double lum = vmath_luminance(m->radiance.x, m->radiance.y, m->radiance.z);
            if (lum > 0) {
                ls->power[kept] = 0.5 * len * lum;
                ls->total += ls->power[kept];
                ls->lights++;
            }
        }
        kept++;
    }
    return kept;
}

/* The light list, its power CDF and each light triangle's area pdf
 * (lights_build, common/lights.c). */
static int build_light_cdf(loader_t *L, const light_sum_t *ls)
{
    /* Each emitting material one emitter, picked alike, as Mitsuba 3 picks
     * its emitters: by power, Veach's small bright lights (veach-mis.xml)
     * got 0.2 % of the light samples each beside his big one, and our
     * relMSE at equal spp was 6.5-8x Mitsuba's. One material alone keeps
     * the power weights, so its bits are those of before. */
    scene_t *s = L->s;
    double *group = calloc(s->material_count, sizeof *group);
    if (!group)
        return fail(L, NULL, "out of memory");
    for (size_t t = 0; t < s->triangle_count; t++)
        group[s->tri_material[t]] += ls->power[t];
    size_t groups = 0;
    for (size_t k = 0; k < s->material_count; k++)
        groups += group[k] > 0;
    char msg[VB_ERR_LEN];
    lights_status_t rc = groups > 1
                             ? lights_build(s, ls->power, (double)groups, group, msg, sizeof msg)
                             : lights_build(s, ls->power, ls->total, NULL, msg, sizeof msg);
    free(group);
    if (rc != LIGHTS_OK)
        return fail(L, rc == LIGHTS_OUT_OF_RANGE ? "shapes" : NULL, "%s", msg);
    return 0;
}

/* Each emitting sphere's clear ball (scene_sphere_t.clear_radius): the
 * nearest other triangle's bounding box bounds how near it comes to the
 * centre, from below; the ball stops short of it by 2^-10 of its radius,
 * far wider than the shadow ray's rounding and the part of a segment its
 * test leaves out at the end (lights_sample_from checks that). */
static void clear_balls(scene_t *s)
{
    if (s->sphere_count > SCENE_SPHERE_CLEAR_PAIRS / (s->triangle_count + 1))
        return;
    for (size_t k = 0; k < s->sphere_count; k++) {
        scene_sphere_t *sp = &s->spheres[k];
        double c[3] = {sp->center.x, sp->center.y, sp->center.z};
        double reach = SCENE_SPHERE_CLEAR * sp->radius, nearest2 = reach * reach;
        for (size_t t = 0; t < s->triangle_count; t++) {
            if (s->tri_sphere[t] == (int32_t)k)
                continue;
            const uint32_t *ix = s->indices + 3 * t;
            double d2 = 0;
            for (int a = 0; a < 3; a++) {
                double v0 = s->positions[3 * ix[0] + a], v1 = s->positions[3 * ix[1] + a],
                       v2 = s->positions[3 * ix[2] + a];
                double lo = fmin(v0, fmin(v1, v2)), hi = fmax(v0, fmax(v1, v2));
                double gap = c[a] < lo ? lo - c[a] : c[a] > hi ? c[a] - hi : 0.0;
                d2 += gap * gap;
            }
            if (d2 < nearest2)
                nearest2 = d2;
        }
        double clear = sqrt(nearest2) * (1.0 - 0x1p-10);
        sp->clear_radius = clear > sp->radius ? (float)clear : 0.0f;
    }
}

/* Each emitting sphere's share of the light samples (its triangles'
 * probabilities, with every other light's share taken out) and its range
 * of the light CDF (its triangles are consecutive there). sphere_len:
 * each kept triangle's normal length, as keep_triangles found it (once: a
 * second face_normal of every sphere triangle was 9 % of a 1-spp render of
 * veach-mis.xml, whose spheres have 410k triangles). */
static int finish_spheres(loader_t *L, const double *sphere_len)
{
    scene_t *s = L->s;
    if (!L->nsph || !s->light_count)
        return 0;
    s->spheres = L->sph;
    s->sphere_count = L->nsph;
    L->sph = NULL;
    for (size_t k = 0; k < s->sphere_count; k++) {
        s->spheres[k].cdf_lo = 2;
        s->spheres[k].cdf_hi = -1;
    }
    double *pick = calloc(s->sphere_count, sizeof *pick);
    if (!pick)
        return fail(L, NULL, "out of memory");
    for (size_t i = 0; i < s->light_count; i++) {
        uint32_t t = s->light_tris[i];
        int32_t k = s->tri_sphere[t];
        if (k < 0)
            continue;
        pick[k] += (double)s->tri_light_pdf[t] * 0.5 * sphere_len[t];
        scene_sphere_t *sp = &s->spheres[k];
        sp->cdf_lo = fmin(sp->cdf_lo, i ? s->light_cdf[i - 1] : 0.0);
        sp->cdf_hi = fmax(sp->cdf_hi, s->light_cdf[i]);
        sp->light_tri = t;
    }
    for (size_t k = 0; k < s->sphere_count; k++)
        s->spheres[k].pick = (float)pick[k];
    free(pick);
    clear_balls(s);
    return 0;
}

/* Normals, degenerate triangles and lights, once every shape is in. */
static int finish(loader_t *L)
{
    scene_t *s = L->s;
    hand_over_arrays(L);
    size_t nt = L->nt;
    if (nt == 0)
        return fail(L, "shapes", "no triangles: the scene is empty");
    s->tri_normal = malloc(nt * sizeof(vec3_t));
    s->tri_smooth = calloc(nt, 1);
    s->tri_light_pdf = calloc(nt, sizeof(float));
    light_sum_t ls = {calloc(nt, sizeof(double)), 0, 0, NULL};
    if (!s->tri_normal || !s->tri_smooth || !s->tri_light_pdf || !ls.power) {
        free(ls.power);
        return fail(L, NULL, "out of memory for %zu triangles", nt);
    }
    if (L->nsph) {
        s->tri_sphere = malloc(nt * sizeof *s->tri_sphere);
        ls.sphere_len = malloc(nt * sizeof *ls.sphere_len);
        if (!s->tri_sphere || !ls.sphere_len) {
            free(ls.power);
            free(ls.sphere_len);
            return fail(L, NULL, "out of memory for %zu triangles", nt);
        }
        for (size_t t = 0; t < nt; t++)
            s->tri_sphere[t] = -1;
        for (size_t k = 0; k < L->nsph; k++)
            for (size_t t = L->sph_first[k]; t < L->sph_first[k] + L->sph_tris[k]; t++)
                s->tri_sphere[t] = (int32_t)k;
    }
    size_t kept = keep_triangles(s, nt, &ls);
    if (s->dropped_degenerate)
        warn(s, "%s: dropped %zu degenerate (zero-area) triangle%s", L->name, s->dropped_degenerate,
             s->dropped_degenerate == 1 ? "" : "s");
    s->triangle_count = kept;
    int rc = 0;
    if (kept == 0) {
        rc = fail(L, "shapes", "no triangles left: all %zu are degenerate", nt);
    } else if (ls.lights == 0 || !(ls.total > 0) || !isfinite(ls.total)) {
        if (ls.lights && !isfinite(ls.total))
            rc = fail(L, "materials", "total light power overflows");
        else if (!s->has_env && !s->delta_count)
            warn(s,
                 "%s: the scene has no light (no emitter with radiance > 0): the image will be "
                 "black",
                 L->name);
    } else {
        rc = build_light_cdf(L, &ls);
    }
    free(ls.power);
    if (rc == 0 && s->delta_count) {
        double diagonal = scene_diagonal(s);
        /* a shadow segment this long leaves the scene (a directional light's) */
        s->env_distance = (float)(2.0 * diagonal + 1.0);
        rc = finish_delta_lights(L);
    }
    if (rc == 0)
        finish_environment(s);
    if (rc == 0)
        rc = finish_spheres(L, ls.sphere_len);
    free(ls.sphere_len);
    return rc;
}

/* Line and column of a byte offset, for malformed-JSON messages. */
static void line_col(const char *text, size_t off, int *line, int *col)
{
    *line = 1;
    *col = 1;
    for (size_t i = 0; i < off && text[i]; i++) {
        if (text[i] == '\n') {
            (*line)++;
            *col = 1;
        } else {
            (*col)++;
        }
    }
}

static int load(const char *json, size_t len, const char *name, const char *base_dir,
                const scene_blob_t *blobs, size_t blob_count, int check_only, scene_t **out,
                char *err, size_t errlen)
{
    *out = NULL;
    loader_t L = {.name = name ? name : "<scene>",
                  .base_dir = base_dir,
                  .err = err,
                  .errlen = errlen,
                  .blobs = blobs,
                  .blob_count = blob_count,
                  .check_only = check_only};
    L.s = calloc(1, sizeof(scene_t));
    if (L.s)
        L.s->checked_only = check_only;
    if (!L.s)
        return fail(&L, NULL, "out of memory");
    const char *end = NULL;
    cJSON *root = cJSON_ParseWithLengthOpts(json, len, &end, 0);
    int rc = 0;
    if (!root) {
        int line, col;
        size_t off = end && end >= json ? (size_t)(end - json) : 0;
        line_col(json, off, &line, &col);
        snprintf(err, errlen, "%s:%d:%d: malformed JSON", L.name, line, col);
        rc = -1;
    } else if (!cJSON_IsObject(root)) {
        rc = fail(&L, NULL, "expected a JSON object at the top level");
    } else {
        static const char *const keys[] = {"camera",      "render", "materials", "shapes",
                                           "environment", "lights", NULL};
        check_keys(&L, root, "", keys);
        rc = parse_camera(&L, root);
        if (rc == 0)
            rc = parse_environment(&L, root);
        if (rc == 0)
            rc = parse_lights(&L, root);
        if (rc == 0)
            rc = parse_render(&L, root);
        if (rc == 0)
            rc = parse_materials(&L, root);
        L.want_uv = L.s->texture_count > 0;
        if (rc == 0)
            rc = parse_shapes(&L, root);
        if (rc == 0)
            rc = finish(&L);
    }
    cJSON_Delete(root);
    free(L.pos);
    free(L.uv);
    free(L.nrm);
    free(L.idx);
    free(L.mat);
    free(L.sph);
    free(L.sph_first);
    free(L.sph_tris);
    if (rc < 0) {
        scene_destroy(&L.s);
        return -1;
    }
    *out = L.s;
    return 0;
}

int scene_load_string(const char *json, size_t len, const char *name, const char *base_dir,
                      scene_t **out, char *err, size_t errlen)
{
    return load(json, len, name, base_dir, NULL, 0, 0, out, err, errlen);
}

int scene_check_string(const char *json, size_t len, const char *name, const char *base_dir,
                       scene_t **out, char *err, size_t errlen)
{
    return load(json, len, name, base_dir, NULL, 0, 1, out, err, errlen);
}

/* an empty bundle still resolves against blobs, never the file system */
static const scene_blob_t no_blobs = {"", NULL, 0};

int scene_load_bundle(const char *json, size_t len, const char *name, const scene_blob_t *blobs,
                      size_t blob_count, scene_t **out, char *err, size_t errlen)
{
    return load(json, len, name, NULL, blob_count ? blobs : &no_blobs, blob_count, 0, out, err,
                errlen);
}

int scene_check_bundle(const char *json, size_t len, const char *name, const scene_blob_t *blobs,
                       size_t blob_count, scene_t **out, char *err, size_t errlen)
{
    return load(json, len, name, NULL, blob_count ? blobs : &no_blobs, blob_count, 1, out, err,
                errlen);
}

static int load_file(const char *path, int check_only, scene_t **out, char *err, size_t errlen)
{
    *out = NULL;
    FILE *f = fopen(path, "rb");
    if (!f) {
        snprintf(err, errlen, "%s: cannot open: %s", path, strerror(errno));
        return -1;
    }
    struct stat st;
    if (fstat(fileno(f), &st) != 0 || !S_ISREG(st.st_mode)) {
        fclose(f);
        snprintf(err, errlen, "%s: not a regular file (a directory?)", path);
        return -1;
    }
    char *buf = NULL;
    long size = -1;
    if (fseek(f, 0, SEEK_END) == 0)
        size = ftell(f);
    if (size < 0 || fseek(f, 0, SEEK_SET) != 0) {
        fclose(f);
        snprintf(err, errlen, "%s: cannot read (not a regular file?)", path);
        return -1;
    }
    if ((unsigned long)size > MAX_SCENE_FILE_BYTES) {
        fclose(f);
        snprintf(err, errlen, "%s: scene file too large (%ld bytes; meshes belong in mesh files)",
                 path, size);
        return -1;
    }
    buf = malloc((size_t)size + 1);
    if (!buf || fread(buf, 1, (size_t)size, f) != (size_t)size) {
        free(buf);
        fclose(f);
        snprintf(err, errlen, "%s: cannot read: %s", path, strerror(errno));
        return -1;
    }
    fclose(f);
    buf[size] = '\0';
    char dir[4096];
    snprintf(dir, sizeof dir, "%s", path);
    char *slash = strrchr(dir, '/');
    if (slash)
        *slash = '\0';
    else
        snprintf(dir, sizeof dir, ".");
    int rc = load(buf, (size_t)size, path, dir, NULL, 0, check_only, out, err, errlen);
    free(buf);
    return rc;
}

int scene_load(const char *path, scene_t **out, char *err, size_t errlen)
{
    return load_file(path, 0, out, err, errlen);
}

int scene_check(const char *path, scene_t **out, char *err, size_t errlen)
{
    return load_file(path, 1, out, err, errlen);
}

void scene_destroy(scene_t **sp)
{
    if (!sp || !*sp)
        return;
    scene_t *s = *sp;
    free(s->materials);
    free(s->positions);
    free(s->normals);
    free(s->uvs);
    for (size_t i = 0; i < s->texture_count; i++)
        free(s->textures[i].rgb);
    free(s->textures);
    free(s->env_rgb);
    free(s->env_row_cdf);
    free(s->env_col_cdf);
    free(s->env_cell_pdf);
    free(s->indices);
    free(s->tri_material);
    free(s->tri_normal);
    free(s->tri_smooth);
    free(s->tri_light_pdf);
    free(s->light_tris);
    free(s->light_cdf);
    free(s->light_guide);
    free(s->delta_lights);
    free(s->delta_cdf);
    free(s->spheres);
    free(s->tri_sphere);
    free(s);
    *sp = NULL;
}

const char *scene_integrator_name(scene_integrator_t integrator)
{
    return integrator == SCENE_INTEGRATOR_NAIVE    ? "naive"
           : integrator == SCENE_INTEGRATOR_DIRECT ? "direct"
                                                   : "path";
}

int scene_integrator_from_name(const char *name)
{
    if (strcmp(name, "path") == 0)
        return SCENE_INTEGRATOR_PATH;
    if (strcmp(name, "naive") == 0)
        return SCENE_INTEGRATOR_NAIVE;
    if (strcmp(name, "direct") == 0)
        return SCENE_INTEGRATOR_DIRECT;
    return -1;
}
