/* scene.h - a scene loaded from its JSON file (format: scenes/README.md):
 * camera, materials, triangles, the emissive triangles that are its lights,
 * and the render defaults.
 *
 * Loading flattens every shape (quads, inline triangles, mesh files, spheres)
 * into one triangle list in world space with a material per triangle. The
 * result is immutable: the tracer and any number of threads read it. Every
 * problem in the file is reported with the file name, the JSON path (or the
 * line for malformed JSON) and what is wrong; nothing in a scene file can
 * crash the loader.
 */
#ifndef VB_SCENE_H
#define VB_SCENE_H

#include <stddef.h>
#include <stdint.h>

#include "camera.h"
#include "material.h"
#include "vmath.h"

#define SCENE_MAX_WARNINGS 8
#define SCENE_WARNING_LEN 256
/* Resolution bounds: anything outside is refused as absurd. */
#define SCENE_MAX_SIDE 16384
#define SCENE_MAX_PIXELS (1u << 26)

/* path: next-event estimation MIS-weighted against the bounce; naive:
 * the bounce alone; direct: Mitsuba's direct integrator, one bounce of
 * light, emitter and BSDF samples MIS-weighted (scene_t.direct_*). */
typedef enum {
    SCENE_INTEGRATOR_PATH = 0,
    SCENE_INTEGRATOR_NAIVE = 1,
    SCENE_INTEGRATOR_DIRECT = 2
} scene_integrator_t;
/* the most emitter or BSDF samples the direct integrator takes per hit */
#define SCENE_MAX_DIRECT_SAMPLES 64

/* Russian roulette's default start: after this many segments; and its
 * latest (roulette keeps the estimate unbiased, and it ends every path:
 * without it two perfect mirrors could hold one forever). */
#define SCENE_RR_DEPTH 5
/* Russian roulette's threshold and cap (scene_t.rr_threshold, rr_cap): a
 * path survives with probability its throughput over the threshold, at
 * most the cap, so it is spared until its throughput falls below about
 * the threshold. Mitsuba 3's rule is the throughput itself (a threshold
 * of 1) capped at 0.95, which killed paths that still carried much of a
 * closed room's light and paid for it in variance: a threshold of 1/4 has
 * 0.82x the relMSE x time of 1 on the Cornell box, 0.58x on glass, 0.87x
 * on dark-bright and materials.xml, and 1.01x on the open scenes
 * checker.xml and lights.xml; a cap of 0.99 another 0.92x on glass, whose
 * paths inside the glass keep their throughput, and the same elsewhere
 * (bench/RESULTS.md, "Russian roulette"). Below 1, the cap still ends
 * every path (two perfect mirrors facing each other). */
#define SCENE_RR_THRESHOLD 0.25f
#define SCENE_RR_CAP 0.99f
#define SCENE_MAX_RR_DEPTH 1024

/* A texture (texture.h looks it up). Texture coordinates (u, v) map to
 * (u', v') = to_uv (u, v, 1). A checkerboard (Mitsuba's): color0 where
 * the fractional parts of u' and v' are both above 1/2 or both not, else
 * color1. A bitmap (Mitsuba's): its texels (linear RGB, row 0 at v' = 0)
 * at (u' width, v' height), bilinear between texel centres or the
 * nearest, repeated, mirrored or clamped outside [0, 1). */
typedef enum { TEXTURE_CHECKERBOARD = 0, TEXTURE_BITMAP = 1 } texture_kind_t;
typedef enum { TEXTURE_WRAP_REPEAT = 0, TEXTURE_WRAP_MIRROR, TEXTURE_WRAP_CLAMP } texture_wrap_t;

typedef struct texture {
    texture_kind_t kind;
    vec3_t color0, color1;
    float to_uv[6]; /* u' = [0] u + [1] v + [2], v' = [3] u + [4] v + [5] */
    /* bitmap: width x height texels, 3 floats each (owned by the scene) */
    int width, height;
    float *rgb;
    uint8_t nearest; /* 0: bilinear */
    texture_wrap_t wrap;
} texture_t;

/* A light with no area (Mitsuba's point, spot and directional emitters):
 * only light samples reach it. Point and spot: intensity (W/sr) from
 * position, the spot's falling to 0 from beam_width to cutoff off its
 * axis (Mitsuba's linear ramp in angle); directional: irradiance arriving
 * along direction from outside the scene. */
typedef enum {
    SCENE_LIGHT_POINT = 0,
    SCENE_LIGHT_SPOT,
    SCENE_LIGHT_DIRECTIONAL
} scene_light_kind_t;

typedef struct scene_light {
    scene_light_kind_t kind;
    vec3_t position;  /* point, spot */
    vec3_t direction; /* spot: its axis; directional: where the light goes (unit) */
    vec3_t intensity; /* point, spot: intensity; directional: irradiance */
    float cos_cutoff, cos_beam, cutoff, inv_transition; /* spot (radians) */
} scene_light_t;

/* the most such lights a scene may have */
#define SCENE_MAX_DELTA_LIGHTS 1024

/* An emitting sphere (a "sphere" shape of an emitter material placed by a
 * similarity): light samples that pick one of its triangles take a
 * direction in the cone it subtends instead of a point by area (pbrt's
 * and Mitsuba's sampling of spheres), with the sphere's whole share of
 * the light samples, pick, and its range [cdf_lo, cdf_hi) of light_cdf. */
typedef struct scene_sphere {
    vec3_t center;
    float radius;
    float pick;
    double cdf_lo, cdf_hi;
    uint32_t light_tri; /* one of its light triangles (its material) */
    /* The radius of the ball about its centre that no other triangle
     * reaches (at most SCENE_SPHERE_CLEAR radii), or 0 when that ball is
     * no wider than the sphere: a shadow ray toward the sphere may stop
     * where it enters the ball (lights_sample_from), since the sphere's
     * own faces lie inside its true surface, which the ray meets only at
     * its end. */
    float clear_radius;
} scene_sphere_t;

/* The widest clear ball a sphere light is given, in its radii: a shadow
 * ray's test near a finely tessellated sphere walks down the hierarchy
 * of its faces, which a ball of 1.5 radii already leaves out (veach-mis.xml
 * ran as fast with 1.5 as with 3). */
#define SCENE_SPHERE_CLEAR 2.0
/* Clear balls are found by testing every sphere light against every
 * triangle; past this many pairs the spheres keep none (correct, only
 * slower: their shadow rays run to the sphere). */
#define SCENE_SPHERE_CLEAR_PAIRS ((size_t)1 << 28)

typedef struct scene {
    camera_t camera;

    /* Render defaults from the "render" object (command-line flags win). */
    uint32_t spp;
    uint64_t seed;
    scene_integrator_t integrator;
    uint32_t max_depth; /* 0: unlimited (Russian roulette ends paths) */
    uint32_t rr_depth;  /* segments before Russian roulette (SCENE_RR_DEPTH) */
    float rr_threshold; /* roulette's throughput scale (SCENE_RR_THRESHOLD) */
    float rr_cap;       /* its survival's cap (SCENE_RR_CAP); bench_core sets
                         * both to Mitsuba's, 1 and 0.95, to compare
                         * samples/s like with like */
                        /* the direct integrator: light samples and BSDF samples per hit,
                         * each 0..SCENE_MAX_DIRECT_SAMPLES, not both 0 (default 1 and 1) */
    uint32_t direct_emitter_samples, direct_bsdf_samples;
    /* Mitsuba's hide_emitters: camera rays pass through emitting triangles
     * and see no environment (what they light is still lit) */
    uint8_t hide_emitters;

    material_t *materials;
    /* the textures materials name (material_t.albedo_texture), and each
     * vertex's texture coordinates: NULL unless a material has a texture
     * (a scene pays only for what it uses) */
    texture_t *textures;
    size_t texture_count;
    float *uvs; /* 2 per vertex */
    size_t material_count;

    float *positions; /* 3 per vertex, world space */
    float *normals;   /* 3 per vertex, or NULL; zero vector = none */
    size_t vertex_count;
    uint32_t *indices;      /* 3 per triangle */
    uint32_t *tri_material; /* per triangle */
    vec3_t *tri_normal;     /* per triangle: unit geometric normal, from winding */
    uint8_t *tri_smooth;    /* per triangle: 1 when all three vertex normals exist */
    float *tri_light_pdf;   /* per triangle: area pdf of light sampling (0: not a light) */
    size_t triangle_count;

    /* Lights: emissive triangles, each emitting material one emitter
     * picked alike (as Mitsuba picks its emitters), a triangle by power
     * within it; one material alone: by power (lights_build). */
    uint32_t *light_tris;
    double *light_cdf; /* light_count entries, last is 1 */
    size_t light_count;
    /* Where the search of light_cdf starts and ends for u in bucket
     * [j / n, (j + 1) / n), one bucket a light (n = light_count):
     * light_guide[j] and [j + 1] (lights_pick_index); NULL for a few
     * lights. */
    uint32_t *light_guide;
    /* Lights with no area (scene_light_t), each one emitter beside the
     * emitting triangles together (as Mitsuba picks its emitters): a light
     * sample that does not take the environment takes one of them with
     * probability delta_pick (by delta_cdf, alike), else a triangle (whose
     * tri_light_pdf then holds the 1 - delta_pick). None: delta_pick 0. */
    scene_light_t *delta_lights;
    double *delta_cdf;
    size_t delta_count;
    float delta_pick;
    /* emitting spheres (scene_sphere_t) and each triangle's (its index,
     * or -1; NULL when the scene has none) */
    scene_sphere_t *spheres;
    size_t sphere_count;
    int32_t *tri_sphere;

    /* The environment: radiance arriving from every direction where no
     * triangle blocks it (Mitsuba's constant emitter). A light sample takes
     * it with probability env_pick (one emitter among the lights with no
     * area and the emitting triangles together), else a triangle (whose
     * tri_light_pdf then holds the 1 - env_pick) or a light with no area. */
    int has_env;
    vec3_t env_radiance;
    float env_pick;
    float env_pdf;      /* its solid-angle density: env_pick / (4 pi) */
    float env_distance; /* a shadow segment this long leaves the scene */
    /* an environment map (Mitsuba's envmap) instead of a constant: a
     * latitude-longitude image, env_w x env_h, as env_rgb rows of env_w + 1
     * pixels (the last repeats the first), radiance scale applied; the
     * rotation between world and map; and the sampling distribution over
     * its (env_h - 1) x env_w cells, by luminance x sin(theta) */
    int env_map;
    int env_w, env_h;
    float *env_rgb;
    float env_to_local[9], env_to_world[9];
    double *env_row_cdf; /* env_h - 1 */
    double *env_col_cdf; /* (env_h - 1) x env_w, each row's own */
    float *env_cell_pdf; /* density in (u, v) of a direction in each cell */

    size_t dropped_degenerate; /* zero-area triangles left out */
    int warning_count;
    char warnings[SCENE_MAX_WARNINGS][SCENE_WARNING_LEN];
    int checked_only; /* from scene_check*: not to be traced (tracer_new refuses it) */
} scene_t;

/* Vertex i's position, and its normal (the zero vector when it has none). */
static inline vec3_t scene_vertex(const scene_t *s, uint32_t i)
{
    const float *p = s->positions + 3 * i;
    return vec3_make(p[0], p[1], p[2]);
}

static inline vec3_t scene_vertex_normal(const scene_t *s, uint32_t i)
{
    const float *n = s->normals + 3 * i;
    return vec3_make(n[0], n[1], n[2]);
}

/* The point at barycentrics (u, v) of triangle tri. */
static inline vec3_t scene_point(const scene_t *s, uint32_t tri, float u, float v)
{
    const uint32_t *vi = s->indices + 3 * tri;
    return vec3_barycentric(scene_vertex(s, vi[0]), scene_vertex(s, vi[1]), scene_vertex(s, vi[2]),
                            u, v);
}

/* A uniformly distributed point on triangle tri from two uniforms. */
static inline vec3_t scene_sample_point(const scene_t *s, uint32_t tri, float u1, float u2)
{
    float su = sqrtf(u1);
    return scene_point(s, tri, su * u2, 1.0f - su);
}

/* A "sphere" shape is an icosphere of 0 to SCENE_MAX_SPHERE_SUBDIVISIONS
 * subdivisions (20 * 4^n triangles). Its vertices lie on the sphere and
 * its faces inside it; scene_icosphere_gap(n) is the widest gap between
 * the two, relative to the radius (0.21 for the icosahedron, 7.1e-5 at
 * 6 subdivisions: a quarter for each one more), for those who choose n
 * by what an error that size costs (mitsuba.c, by the pixels it spans). */
#define SCENE_MAX_SPHERE_SUBDIVISIONS 7
double scene_icosphere_gap(int subdivisions);

/* Loads a scene file; mesh paths are relative to its folder. Returns 0 and
 * a new scene in *out (free with scene_destroy), or -1 with *out NULL and a
 * message in err ("FILE: json.path: what is wrong"). */
int scene_load(const char *path, scene_t **out, char *err, size_t errlen);

/* The same from JSON text; name is used in messages, base_dir resolves
 * mesh paths. */
int scene_load_string(const char *json, size_t len, const char *name, const char *base_dir,
                      scene_t **out, char *err, size_t errlen);

/* A mesh file held in memory, named as the scene's "file" fields name it. */
typedef struct scene_blob {
    const char *name;
    const unsigned char *data;
    size_t size;
} scene_blob_t;

/* The same, resolving every mesh "file" against blobs (by exact name)
 * instead of the file system: how a worker loads a scene bundle shipped by
 * the master. A name not among the blobs is an error. */
int scene_load_bundle(const char *json, size_t len, const char *name, const scene_blob_t *blobs,
                      size_t blob_count, scene_t **out, char *err, size_t errlen);

/* The three loads above for a party that checks a scene and reads its
 * settings but never traces it (the client before it submits, the master
 * when it takes a job): the same checks and messages, without what a
 * material precomputes for tracing (a rough plastic's coat tables, 0.15 to
 * 0.5 s each, which `vbrender render` computed once for each of its three
 * parties). tracer_new refuses such a scene. */
int scene_check(const char *path, scene_t **out, char *err, size_t errlen);
int scene_check_string(const char *json, size_t len, const char *name, const char *base_dir,
                       scene_t **out, char *err, size_t errlen);
int scene_check_bundle(const char *json, size_t len, const char *name, const scene_blob_t *blobs,
                       size_t blob_count, scene_t **out, char *err, size_t errlen);

/* Frees the scene and sets *s to NULL; accepts NULL. */
void scene_destroy(scene_t **s);

const char *scene_integrator_name(scene_integrator_t integrator);
/* "path", "naive" or "direct"; -1 for anything else. */
int scene_integrator_from_name(const char *name);

#endif
