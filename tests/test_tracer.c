/* test_tracer.c - the renderer against answers known in advance.
 *
 * Every statistical assertion uses the variance the renderer itself reports:
 * the mean luminance of a region is compared with its expected value within
 * 5 standard deviations of that mean (pixels are independent, so the
 * region's variance is the sum of its pixels' variances over n^2). A bug
 * that biases the estimate by more than the noise fails; an unlucky seed
 * essentially never does (5 sigma: 6e-7 per comparison).
 */
#include <cJSON.h>
#include <check.h>
#include <dirent.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <xmmintrin.h>

#include "film.h"
#include "lights.h"
#include "mitsuba.h"
#include "render.h"
#include "scene.h"
#include "testutil.h"
#include "tracer.h"
#include "tracer_priv.h" /* the packets the wavefront engine casts */
#include "vberr.h"

#define NSIGMA 5.0

/* ---- fixtures -------------------------------------------------------- */

static scene_t *load_text(const char *json)
{
    scene_t *s = NULL;
    char err[1024];
    int rc = scene_load_string(json, strlen(json), "test-scene", ".", &s, err, sizeof err);
    ck_assert_msg(rc == 0, "scene failed to load: %s", err);
    return s;
}

static char *read_file(const char *path)
{
    FILE *f = fopen(path, "rb");
    ck_assert_msg(f != NULL, "cannot open %s", path);
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    char *buf = malloc((size_t)n + 1);
    ck_assert(buf != NULL);
    ck_assert(fread(buf, 1, (size_t)n, f) == (size_t)n);
    buf[n] = '\0';
    fclose(f);
    return buf;
}

/* The Cornell box from scenes/, at a smaller square resolution (the camera's
 * field of view depends only on the aspect ratio, which stays 1). */
static cJSON *cornell_json(int size)
{
    char path[1024];
    char *text = read_file(tu_root_path(path, sizeof path, "scenes/cornell-box.json"));
    cJSON *root = cJSON_Parse(text);
    free(text);
    ck_assert(root != NULL);
    cJSON *cam = cJSON_GetObjectItem(root, "camera");
    cJSON_ReplaceItemInObject(cam, "width", cJSON_CreateNumber(size));
    cJSON_ReplaceItemInObject(cam, "height", cJSON_CreateNumber(size));
    return root;
}

static scene_t *load_json(cJSON *root)
{
    char *text = cJSON_PrintUnformatted(root);
    scene_t *s = load_text(text);
    cJSON_free(text);
    return s;
}

/* A render on a tracer whose own kernels run for isa (tracer_use_isa), or
 * the widest the host runs (NULL). */
static film_t *render_accel_isa(const scene_t *s, tracer_accel_t accel, const char *isa,
                                uint64_t seed, scene_integrator_t integ, rng_sampler_t sampler,
                                uint32_t spp, int threads, uint32_t granularity, uint64_t *rays)
{
    tracer_t *t = NULL;
    tracer_device_t *dev = NULL;
    char err[512];
    ck_assert_msg(tracer_device_new(&dev, err, sizeof err) == 0, "%s", err);
    ck_assert_msg(tracer_new_accel(dev, s, accel, &t, err, sizeof err) == 0, "%s", err);
    if (isa)
        ck_assert_int_eq(tracer_use_isa(t, isa), 0);
    film_t *f = film_new(s->camera.width, s->camera.height);
    ck_assert(f != NULL);
    render_settings_t rs;
    memset(&rs, 0, sizeof rs);
    rs.tracer.seed = seed;
    rs.tracer.integrator = integ;
    rs.tracer.sampler = sampler;
    rs.spp = spp;
    rs.granularity = granularity;
    rs.threads = threads;
    rs.progress = PROGRESS_NONE;
    rs.progress_out = NULL;
    render_summary_t sum;
    ck_assert_msg(render_run(t, f, &rs, &sum, err, sizeof err) == 0, "%s", err);
    ck_assert_uint_eq(sum.samples, (uint64_t)spp * (uint64_t)f->width * (uint64_t)f->height);
    if (rays)
        *rays = sum.rays;
    tracer_destroy(&t);
    tracer_device_destroy(&dev);
    return f;
}

static film_t *render_accel(const scene_t *s, tracer_accel_t accel, uint64_t seed,
                            scene_integrator_t integ, rng_sampler_t sampler, uint32_t spp,
                            int threads, uint32_t granularity, uint64_t *rays)
{
    return render_accel_isa(s, accel, NULL, seed, integ, sampler, spp, threads, granularity, rays);
}

static film_t *render_sampler(const scene_t *s, uint64_t seed, scene_integrator_t integ,
                              rng_sampler_t sampler, uint32_t spp, int threads,
                              uint32_t granularity)
{
    return render_accel(s, TRACER_ACCEL_AUTO, seed, integ, sampler, spp, threads, granularity,
                        NULL);
}

static film_t *render(const scene_t *s, uint64_t seed, scene_integrator_t integ, uint32_t spp,
                      int threads, uint32_t granularity)
{
    return render_sampler(s, seed, integ, RNG_SAMPLER_INDEPENDENT, spp, threads, granularity);
}

/* Loads the scene JSON root (its camera made size x size) as `name`, its
 * meshes relative to dir, and calls fn on it. */
static void call_on_small(cJSON *root, int size, const char *name, const char *dir,
                          void (*fn)(scene_t *sc, const char *name))
{
    cJSON *cam = cJSON_GetObjectItem(root, "camera");
    cJSON_ReplaceItemInObject(cam, "width", cJSON_CreateNumber(size));
    cJSON_ReplaceItemInObject(cam, "height", cJSON_CreateNumber(size));
    char *small = cJSON_PrintUnformatted(root);
    scene_t *sc = NULL;
    char err[VB_ERR_LEN];
    ck_assert_msg(scene_load_string(small, strlen(small), name, dir, &sc, err, sizeof err) == 0,
                  "%s: %s", name, err);
    cJSON_free(small);
    fn(sc, name);
    scene_destroy(&sc);
}

/* Calls fn on every scene shipped in scenes/ (and the Mitsuba scenes in
 * scenes/mitsuba/, as mitsuba.c reads them), its camera made size x size;
 * fails unless there are at least 5 and 1. */
static void for_each_shipped_scene(int size, void (*fn)(scene_t *sc, const char *name))
{
    for (int mitsuba = 0; mitsuba < 2; mitsuba++) {
        char dir[1024];
        tu_root_path(dir, sizeof dir, mitsuba ? "scenes/mitsuba" : "scenes");
        DIR *d = opendir(dir);
        ck_assert_msg(d != NULL, "cannot open %s", dir);
        int scenes = 0;
        for (struct dirent *e; (e = readdir(d));) {
            size_t n = strlen(e->d_name);
            const char *ext = mitsuba ? ".xml" : ".json";
            if (n <= strlen(ext) || strcmp(e->d_name + n - strlen(ext), ext) != 0)
                continue;
            char path[2048], err[VB_ERR_LEN];
            snprintf(path, sizeof path, "%s/%s", dir, e->d_name);
            cJSON *root;
            if (mitsuba) {
                root = mitsuba_scene_json(path, NULL, 0, err, sizeof err);
                ck_assert_msg(root != NULL, "%s", err);
            } else {
                char *text = read_file(path);
                root = cJSON_Parse(text);
                free(text);
                ck_assert_msg(root != NULL, "%s is not JSON", path);
            }
            call_on_small(root, size, e->d_name, dir, fn);
            cJSON_Delete(root);
            scenes++;
        }
        closedir(d);
        ck_assert_msg(scenes >= (mitsuba ? 1 : 5), "only %d scenes in %s", scenes, dir);
    }
}

static void renders_something(scene_t *sc, const char *name)
{
    film_t *f = render(sc, 1, SCENE_INTEGRATOR_PATH, 8, 1, 8);
    double sum = 0;
    for (uint32_t p = 0; p < 32 * 32; p++) {
        double rgb[3];
        film_mean(f, p, rgb);
        sum += rgb[0] + rgb[1] + rgb[2];
    }
    ck_assert_msg(isfinite(sum) && sum > 0, "%s renders %g", name, sum);
    ck_assert_uint_eq(film_total_nonfinite(f), 0);
    film_destroy(&f);
}

/* Every scene shipped in scenes/ loads from a bare clone (its meshes are in
 * scenes/data) and renders to a finite image that is not black: at 32x32
 * and 8 spp, since what is checked is that nothing is missing. */
START_TEST(test_every_shipped_scene)
{
    for_each_shipped_scene(32, renders_something);
}
END_TEST

typedef struct region_stat {
    double mean; /* mean over pixels of the pixel mean luminance */
    double var;  /* variance of that mean */
} region_stat_t;

static region_stat_t region(const film_t *f, int x0, int y0, int x1, int y1)
{
    region_stat_t r = {0, 0};
    int n = 0;
    for (int y = y0; y < y1; y++)
        for (int x = x0; x < x1; x++) {
            uint32_t p = (uint32_t)(y * f->width + x);
            double rgb[3];
            film_mean(f, p, rgb);
            r.mean += vmath_luminance(rgb[0], rgb[1], rgb[2]);
            r.var += film_variance_of_mean(f, p);
            n++;
        }
    r.mean /= n;
    r.var /= (double)n * n;
    return r;
}

static void assert_all_finite(const film_t *f)
{
    for (int i = 0; i < f->width * f->height; i++) {
        double rgb[3];
        film_mean(f, (uint32_t)i, rgb);
        ck_assert_msg(isfinite(rgb[0]) && isfinite(rgb[1]) && isfinite(rgb[2]),
                      "pixel %d is not finite", i);
        ck_assert(isfinite(film_variance_of_mean(f, (uint32_t)i)));
    }
}

/* Blocks of two films agree within NSIGMA combined sigma (+ rel_tol). */
static void assert_films_agree(const film_t *a, const film_t *b, int blocks, double rel_tol,
                               const char *what)
{
    ck_assert_int_eq(a->width, b->width);
    int bw = a->width / blocks, bh = a->height / blocks;
    for (int by = 0; by < blocks; by++)
        for (int bx = 0; bx < blocks; bx++) {
            region_stat_t ra = region(a, bx * bw, by * bh, (bx + 1) * bw, (by + 1) * bh);
            region_stat_t rb = region(b, bx * bw, by * bh, (bx + 1) * bw, (by + 1) * bh);
            double bound = NSIGMA * sqrt(ra.var + rb.var) + rel_tol * fabs(ra.mean) + 1e-12;
            ck_assert_msg(fabs(ra.mean - rb.mean) <= bound,
                          "%s: block (%d,%d): %.6g vs %.6g differ by %.3g > bound %.3g", what, bx,
                          by, ra.mean, rb.mean, fabs(ra.mean - rb.mean), bound);
        }
}

/* A closed cube [-1,1]^3 with inward-facing quads of one material. */
static void furnace_box(char *buf, size_t len, const char *material_json, const char *extra_shapes,
                        const char *camera_json)
{
    snprintf(
        buf, len,
        "{\"camera\": %s,"
        "\"materials\": {\"f\": %s, \"glass\": {\"type\": \"dielectric\", \"ior\": 1.5},"
        "  \"mirror\": {\"type\": \"mirror\"}},"
        "\"shapes\": ["
        "{\"type\":\"quad\",\"material\":\"f\",\"vertices\":[[-1,-1,-1],[-1,-1,1],[1,-1,1],[1,-1,-"
        "1]]},"
        "{\"type\":\"quad\",\"material\":\"f\",\"vertices\":[[-1,1,-1],[1,1,-1],[1,1,1],[-1,1,1]]},"
        "{\"type\":\"quad\",\"material\":\"f\",\"vertices\":[[-1,-1,-1],[-1,1,-1],[-1,1,1],[-1,-1,"
        "1]]},"
        "{\"type\":\"quad\",\"material\":\"f\",\"vertices\":[[1,-1,-1],[1,-1,1],[1,1,1],[1,1,-1]]},"
        "{\"type\":\"quad\",\"material\":\"f\",\"vertices\":[[-1,-1,-1],[1,-1,-1],[1,1,-1],[-1,1,-"
        "1]]},"
        "{\"type\":\"quad\",\"material\":\"f\",\"vertices\":[[-1,-1,1],[-1,1,1],[1,1,1],[1,-1,1]]}"
        "%s]}",
        camera_json, material_json, extra_shapes);
}

static const char *const inside_camera = "{\"position\":[0,0,0],\"look_at\":[0,0,1],\"up\":[0,1,0],"
                                         "\"fov\":90,\"width\":16,\"height\":16}";

/* ---- furnaces --------------------------------------------------------- */

/* Every surface emits Le and reflects diffusely with albedo a: radiance is
 * Le / (1 - a) everywhere, per channel, at any depth of the sum: an emitter
 * that also reflects counts its emission and its reflection once each. */
static void furnace_case(scene_integrator_t integ, const double a[3], uint32_t spp)
{
    static const double Le[3] = {1, 0.5, 0.25};
    char mat[256], json[4096];
    snprintf(mat, sizeof mat,
             "{\"type\":\"emitter\",\"radiance\":[%g,%g,%g],\"albedo\":[%g,%g,%g]}", Le[0], Le[1],
             Le[2], a[0], a[1], a[2]);
    furnace_box(json, sizeof json, mat, "", inside_camera);
    scene_t *s = load_text(json);
    ck_assert_uint_eq(s->light_count, 12);
    film_t *f = render(s, 7, integ, spp, 2, 32);
    assert_all_finite(f);
    region_stat_t r = region(f, 0, 0, 16, 16);
    double expect =
        vmath_luminance(Le[0] / (1.0 - a[0]), Le[1] / (1.0 - a[1]), Le[2] / (1.0 - a[2]));
    ck_assert_msg(r.var > 0, "no variance reported");
    ck_assert_msg(fabs(r.mean - expect) <= NSIGMA * sqrt(r.var),
                  "furnace a=(%g %g %g) (%s): mean %.6f, expected %.6f, sigma %.3g", a[0], a[1],
                  a[2], scene_integrator_name(integ), r.mean, expect, sqrt(r.var));
    /* with a grey albedo, colour ratios survive every bounce */
    double rgb[3] = {0, 0, 0};
    for (int i = 0; i < 256; i++) {
        double px[3];
        film_mean(f, (uint32_t)i, px);
        for (int c = 0; c < 3; c++)
            rgb[c] += px[c];
    }
    if (a[0] == a[1] && a[1] == a[2])
        ck_assert_msg(fabs(rgb[1] / rgb[0] - 0.5) < 1e-6 && fabs(rgb[2] / rgb[0] - 0.25) < 1e-6,
                      "colour ratios drifted: %g %g", rgb[1] / rgb[0], rgb[2] / rgb[0]);
    film_destroy(&f);
    scene_destroy(&s);
}

START_TEST(test_furnace_path)
{
    furnace_case(SCENE_INTEGRATOR_PATH, (const double[3]){0.5, 0.5, 0.5}, 64);
}
END_TEST

START_TEST(test_furnace_path_bright)
{
    furnace_case(SCENE_INTEGRATOR_PATH, (const double[3]){0.9, 0.9, 0.9}, 64);
}
END_TEST

START_TEST(test_furnace_naive)
{
    furnace_case(SCENE_INTEGRATOR_NAIVE, (const double[3]){0.5, 0.5, 0.5}, 64);
}
END_TEST

/* Emitters that also reflect, with an albedo of another colour than their
 * radiance: light samples from an emitting surface (its albedo times the
 * other walls' radiance) and its own emission hit by BSDF sampling must
 * each be counted once, channel by channel, by both integrators. */
START_TEST(test_furnace_coloured_albedo)
{
    const double a[3] = {0.3, 0.6, 0.85};
    furnace_case(SCENE_INTEGRATOR_PATH, a, 64);
    furnace_case(SCENE_INTEGRATOR_NAIVE, a, 64);
}
END_TEST

/* A black-body box of radiance Le around a lossless glass or mirror sphere:
 * whatever the path does inside the sphere it ends on a wall, so every pixel
 * is Le (with glass this also checks the 1/eta^2 radiance scaling cancels). */
static void specular_furnace(const char *material)
{
    char extra[256], json[4096];
    snprintf(extra, sizeof extra,
             ",{\"type\":\"sphere\",\"material\":\"%s\",\"center\":[0,0,0.2],\"radius\":0.5,"
             "\"subdivisions\":4}",
             material);
    furnace_box(json, sizeof json, "{\"type\":\"emitter\",\"radiance\":[0.75,0.75,0.75]}", extra,
                "{\"position\":[0,0,-0.9],\"look_at\":[0,0,0.2],\"up\":[0,1,0],\"fov\":50,"
                "\"width\":16,\"height\":16}");
    scene_t *s = load_text(json);
    for (int integ = 0; integ < 2; integ++) {
        film_t *f = render(s, 3, (scene_integrator_t)integ, 32, 2, 32);
        assert_all_finite(f);
        region_stat_t r = region(f, 0, 0, 16, 16);
        ck_assert_msg(fabs(r.mean - 0.75) <= NSIGMA * sqrt(r.var) + 1e-6,
                      "%s furnace (%s): mean %.7f, sigma %.3g", material,
                      scene_integrator_name((scene_integrator_t)integ), r.mean, sqrt(r.var));
        film_destroy(&f);
    }
    scene_destroy(&s);
}

START_TEST(test_glass_furnace)
{
    specular_furnace("glass");
}
END_TEST

START_TEST(test_mirror_furnace)
{
    specular_furnace("mirror");
}
END_TEST

/* ---- radiance scale: Russian roulette and dielectrics ----------------- */

/* An axis-aligned box of material mat with outward normals (so a dielectric
 * is entered from outside), as six quads appended to buf. */
static void append_box(char *buf, size_t len, const char *mat, const double lo[3],
                       const double hi[3])
{
    /* per face: the axis it faces along, its side, and its corners in the
     * order that makes the normal point out (right-hand rule) */
    static const int faces[6][4][3] = {
        {{0, 0, 0}, {0, 1, 0}, {1, 1, 0}, {1, 0, 0}}, /* -z */
        {{0, 0, 1}, {1, 0, 1}, {1, 1, 1}, {0, 1, 1}}, /* +z */
        {{0, 0, 0}, {0, 0, 1}, {0, 1, 1}, {0, 1, 0}}, /* -x */
        {{1, 0, 0}, {1, 1, 0}, {1, 1, 1}, {1, 0, 1}}, /* +x */
        {{0, 0, 0}, {1, 0, 0}, {1, 0, 1}, {0, 0, 1}}, /* -y */
        {{0, 1, 0}, {0, 1, 1}, {1, 1, 1}, {1, 1, 0}}, /* +y */
    };
    for (int f = 0; f < 6; f++) {
        size_t used = strlen(buf);
        used += (size_t)snprintf(buf + used, len - used,
                                 ",{\"type\":\"quad\",\"material\":\"%s\",\"vertices\":[", mat);
        for (int v = 0; v < 4; v++) {
            const int *c = faces[f][v];
            used +=
                (size_t)snprintf(buf + used, len - used, "%s[%g,%g,%g]", v ? "," : "",
                                 c[0] ? hi[0] : lo[0], c[1] ? hi[1] : lo[1], c[2] ? hi[2] : lo[2]);
        }
        snprintf(buf + used, len - used, "]}");
    }
}

/* nslabs glass slabs between a camera and the far wall of a furnace of
 * black emitters of radiance 0.75: every path ends on a wall through
 * lossless interfaces, so each sample is 0.75 but for Russian roulette.
 * *rel_var: the per-sample variance over 0.75^2. */
static double slab_furnace(int nslabs, uint32_t spp, double *rel_var)
{
    char extra[8192] = "", json[16384];
    for (int i = 0; i < nslabs; i++) {
        double lo[3] = {-0.8, -0.8, -0.6 + 0.3 * i}, hi[3] = {0.8, 0.8, -0.45 + 0.3 * i};
        append_box(extra, sizeof extra, "glass", lo, hi);
    }
    furnace_box(json, sizeof json, "{\"type\":\"emitter\",\"radiance\":[0.75,0.75,0.75]}", extra,
                "{\"position\":[0,0,-0.9],\"look_at\":[0,0,1],\"up\":[0,1,0],\"fov\":20,"
                "\"width\":8,\"height\":8}");
    scene_t *s = load_text(json);
    film_t *f = render(s, 5, SCENE_INTEGRATOR_PATH, spp, 2, 32);
    assert_all_finite(f);
    region_stat_t r = region(f, 0, 0, 8, 8);
    ck_assert_msg(fabs(r.mean - 0.75) <= NSIGMA * sqrt(r.var) + 1e-6,
                  "%d glass slabs in a furnace: mean %.7f, expected 0.75 (sigma %.3g)", nslabs,
                  r.mean, sqrt(r.var));
    *rel_var = r.var * 64.0 * spp / (0.75 * 0.75);
    film_destroy(&f);
    scene_destroy(&s);
    return r.mean;
}

/* A path inside glass carries 1/eta^2 of compressed radiance in beta; the
 * roulette must judge it as the same path outside (eta_scale = eta^2), and
 * leave paths that never crossed a dielectric as they were: survival is
 * the throughput over the scene's threshold, at most its cap, so a path is
 * spared while its throughput stays above the cap times the threshold. */
START_TEST(test_roulette_undoes_radiance_compression)
{
    const vec3_t betas[] = {vec3_make(0.8f, 0.5f, 0.2f), vec3_make(0.1f, 0.03f, 0.05f),
                            vec3_make(2.0f, 1.0f, 0.5f), vec3_make(0.02f, 0.02f, 0.02f)};
    const float etas[] = {1.5f, 1.0f / 1.5f, 2.4f, 1.33f};
    /* at the defaults, a threshold of 1/4 and a cap of 0.99 */
    const float want[] = {0.99f, 0.4f, 0.99f, 0.08f};
    ck_assert(SCENE_RR_THRESHOLD == 0.25f && SCENE_RR_CAP == 0.99f);
    char json[4096];
    furnace_box(json, sizeof json, "{\"type\":\"emitter\",\"radiance\":[1,1,1]}", "",
                inside_camera);
    scene_t *s = load_text(json);
    ck_assert(s->rr_threshold == SCENE_RR_THRESHOLD && s->rr_cap == SCENE_RR_CAP);
    scene_t mitsuba = *s; /* Mitsuba's rule (bench_core's --roulette mitsuba) */
    mitsuba.rr_threshold = 1.0f;
    mitsuba.rr_cap = 0.95f;
    for (size_t i = 0; i < sizeof betas / sizeof betas[0]; i++) {
        vec3_t b = betas[i];
        float outside = tracer_roulette_probability(s, b, 1.0f);
        ck_assert_msg(fabsf(outside - want[i]) <= 1e-6f, "beta %g: survives with %g, want %g",
                      vec3_max_comp(b), outside, want[i]);
        ck_assert(tracer_roulette_probability(&mitsuba, b, 1.0f) == fminf(0.95f, vec3_max_comp(b)));
        for (size_t e = 0; e < sizeof etas / sizeof etas[0]; e++) {
            float eta2 = etas[e] * etas[e];
            float inside = tracer_roulette_probability(s, vec3_scale(b, 1.0f / eta2), eta2);
            ck_assert_msg(fabsf(inside - outside) <= 1e-6f * outside,
                          "beta %g through eta %g: survives with %g inside, %g outside", b.x,
                          etas[e], inside, outside);
        }
    }
    scene_destroy(&s);
}
END_TEST

/* The scene's roulette threshold: in a furnace (every wall emits 1 and
 * reflects 0.6, radiance 2.5 everywhere) paths at 1/4 go on longer than
 * at Mitsuba's 1 (more rays), the estimate stays unbiased at both, and its
 * variance falls: the roulette no longer kills paths that still carry a
 * third of the light and multiplies their survivors' worth. */
START_TEST(test_roulette_threshold_spares_paths)
{
    char json[4096];
    furnace_box(json, sizeof json,
                "{\"type\":\"emitter\",\"radiance\":[1,1,1],\"albedo\":[0.6,0.6,0.6]}", "",
                inside_camera);
    scene_t *s = load_text(json);
    ck_assert(s->rr_threshold == SCENE_RR_THRESHOLD);
    region_stat_t r[2];
    uint64_t rays[2];
    const float thresholds[2] = {1.0f, SCENE_RR_THRESHOLD};
    for (int k = 0; k < 2; k++) {
        s->rr_threshold = thresholds[k];
        film_t *f = render_accel(s, TRACER_ACCEL_AUTO, 7, SCENE_INTEGRATOR_PATH,
                                 RNG_SAMPLER_INDEPENDENT, 64, 2, 32, &rays[k]);
        assert_all_finite(f);
        r[k] = region(f, 0, 0, 16, 16);
        ck_assert_msg(fabs(r[k].mean - 2.5) <= NSIGMA * sqrt(r[k].var),
                      "threshold %g: mean %.6f, expected 2.5 (sigma %.3g)", thresholds[k],
                      r[k].mean, sqrt(r[k].var));
        film_destroy(&f);
    }
    ck_assert_msg(rays[1] > rays[0] + rays[0] / 10, "rays at 1/4: %llu, at 1: %llu",
                  (unsigned long long)rays[1], (unsigned long long)rays[0]);
    ck_assert_msg(r[1].var < 0.5 * r[0].var, "variance at 1/4: %.3g, at 1: %.3g", r[1].var,
                  r[0].var);
    scene_destroy(&s);
}
END_TEST

/* Three slabs put the roulette's first decisions inside glass. Deciding on
 * the compressed beta (q = 0.44 there, then 2.25x brighter survivors) gave
 * a per-sample relative variance of about 1.4; on beta * eta_scale the
 * survivors are worth at most 1/0.99^2 more and it is about 0.1. */
START_TEST(test_roulette_variance_inside_glass)
{
    double rel_var;
    slab_furnace(3, 256, &rel_var);
    ck_assert_msg(rel_var < 0.4, "per-sample relative variance %.3f behind 3 glass slabs", rel_var);
}
END_TEST

/* Dielectric entry and exit: 1/eta^2 on the way in, eta^2 on the way out;
 * through one slab no roulette is drawn on most paths and the furnace gives
 * Le, with a variance from the few paths reflected inside long enough to
 * meet the roulette. */
START_TEST(test_glass_slab_furnace)
{
    double rel_var;
    slab_furnace(1, 64, &rel_var);
    ck_assert_msg(rel_var < 0.01, "per-sample relative variance %.4f through one slab", rel_var);
}
END_TEST

/* ---- analytic direct lighting ---------------------------------------- */

/* Form factor from a differential area to a parallel square of half side s
 * centred at height h above it (four corner rectangles of the standard
 * closed form). */
static double square_form_factor(double s, double h)
{
    double A = s / h, q = A / sqrt(1.0 + A * A);
    return 4.0 / M_PI * q * atan(q);
}

START_TEST(test_form_factor_formula)
{
    /* the closed form against a midpoint-rule integral of cos cos / (pi r^2) */
    double s = 0.5, h = 1.0, sum = 0;
    int n = 1000;
    double dx = 2 * s / n;
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++) {
            double x = -s + (i + 0.5) * dx, y = -s + (j + 0.5) * dx;
            double r2 = x * x + y * y + h * h;
            sum += h * h / (M_PI * r2 * r2) * dx * dx;
        }
    ck_assert_msg(fabs(sum - square_form_factor(s, h)) < 1e-6, "%.9f vs %.9f", sum,
                  square_form_factor(s, h));
}
END_TEST

/* A diffuse floor (albedo rho) under a black square emitter of radiance Le:
 * the floor point under its centre has radiance rho * Le * F exactly (no
 * indirect light: the emitter absorbs and a plane cannot see itself). */
static void direct_case(scene_integrator_t integ, uint32_t spp)
{
    const double rho = 0.5, Le = 1.0, s = 0.5, h = 1.0;
    const char *json =
        "{\"camera\":{\"position\":[0,0.5,0],\"look_at\":[0,0,0],\"up\":[0,0,1],\"fov\":0.5,"
        "\"width\":8,\"height\":8},"
        "\"materials\":{\"floor\":{\"type\":\"diffuse\",\"albedo\":[0.5,0.5,0.5]},"
        "\"light\":{\"type\":\"emitter\",\"radiance\":[1,1,1]}},"
        "\"shapes\":["
        "{\"type\":\"quad\",\"material\":\"floor\",\"vertices\":[[-50,0,-50],[-50,0,50],[50,0,50],["
        "50,0,-50]]},"
        "{\"type\":\"quad\",\"material\":\"light\",\"vertices\":[[-0.5,1,-0.5],[0.5,1,-0.5],[0.5,1,"
        "0.5],[-0.5,1,0.5]]}]}";
    scene_t *s_ = load_text(json);
    film_t *f = render(s_, 11, integ, spp, 2, 32);
    assert_all_finite(f);
    region_stat_t r = region(f, 0, 0, 8, 8);
    /* The pixels see a spot of radius 0.5 tan(0.25 deg) = 0.002 where the
     * irradiance varies by less than 1e-5 relative. */
    double expect = rho * Le * square_form_factor(s, h);
    ck_assert_msg(fabs(r.mean - expect) <= NSIGMA * sqrt(r.var) + 1e-5 * expect,
                  "direct light (%s): %.7f vs exact %.7f (sigma %.3g)",
                  scene_integrator_name(integ), r.mean, expect, sqrt(r.var));
    film_destroy(&f);
    scene_destroy(&s_);
}

START_TEST(test_direct_light_path)
{
    direct_case(SCENE_INTEGRATOR_PATH, 256);
}
END_TEST

START_TEST(test_direct_light_naive)
{
    direct_case(SCENE_INTEGRATOR_NAIVE, 1024);
}
END_TEST

/* ---- MIS and light selection ----------------------------------------- */

/* A unit emitter of radiance 1 facing down at y = 1, over shapes, seen
 * from camera (a narrow view): the mean luminance of its 8x8 pixels. */
static region_stat_t under_light(const char *shapes, const char *camera, uint32_t spp)
{
    char json[8192];
    snprintf(
        json, sizeof json,
        "{\"camera\":%s,\"materials\":{\"mirror\":{\"type\":\"mirror\",\"reflectance\":[0.5,0.5,"
        "0.5]},\"glass\":{\"type\":\"dielectric\",\"ior\":1.5},"
        "\"light\":{\"type\":\"emitter\",\"radiance\":[1,1,1]}},"
        "\"shapes\":[{\"type\":\"quad\",\"material\":\"light\",\"vertices\":[[-0.5,1,-0.5],"
        "[0.5,1,-0.5],[0.5,1,0.5],[-0.5,1,0.5]]}%s]}",
        camera, shapes);
    scene_t *s = load_text(json);
    ck_assert_uint_eq(s->light_count, 2);
    film_t *f = render(s, 13, SCENE_INTEGRATOR_PATH, spp, 2, 32);
    assert_all_finite(f);
    region_stat_t r = region(f, 0, 0, 8, 8);
    film_destroy(&f);
    scene_destroy(&s);
    return r;
}

/* An emitter reached through a specular vertex gets MIS weight 1: light
 * sampling cannot find a direction on a delta lobe, so the BSDF path is the
 * only estimator of that light. A mirror of albedo 0.5 under the light, seen
 * straight down, is 0.5 in every sample; behind a glass slab seen straight
 * up the light is (1 - R) / (1 + R) with R = 0.04 at normal incidence. */
START_TEST(test_light_after_specular_weighs_one)
{
    region_stat_t m = under_light(
        ",{\"type\":\"quad\",\"material\":\"mirror\",\"vertices\":[[-50,0,-50],[-50,0,50],[50,0,"
        "50],[50,0,-50]]}",
        "{\"position\":[0,0.5,0],\"look_at\":[0,0,0],\"up\":[0,0,1],\"fov\":0.5,\"width\":8,"
        "\"height\":8}",
        16);
    ck_assert_msg(fabs(m.mean - 0.5) < 1e-6 && m.var == 0.0,
                  "light in a mirror: %.7f (variance %.3g), expected 0.5 exactly", m.mean, m.var);
    char slab[4096] = "";
    const double lo[3] = {-0.6, 0.4, -0.6}, hi[3] = {0.6, 0.5, 0.6};
    append_box(slab, sizeof slab, "glass", lo, hi);
    region_stat_t g = under_light(slab,
                                  "{\"position\":[0,0.2,0],\"look_at\":[0,1,0],\"up\":[0,0,1],"
                                  "\"fov\":0.5,\"width\":8,\"height\":8}",
                                  256);
    const double expect = 0.96 / 1.04;
    ck_assert_msg(fabs(g.mean - expect) <= NSIGMA * sqrt(g.var) + 1e-4,
                  "light behind a glass slab: %.5f, expected %.5f (sigma %.3g)", g.mean, expect,
                  sqrt(g.var));
}
END_TEST

/* The density the tracer's MIS gives a light point it hits (lights_area_pdf
 * per unit area) is the density with which lights_sample picks it: for
 * lights of different sizes and colours, the share of stratified picks on
 * each triangle is its pdf times its area, and those shares sum to 1. */
START_TEST(test_light_selection_matches_area_pdf)
{
    const char *json =
        "{\"camera\":{\"position\":[0,3,-5],\"look_at\":[0,0,0],\"up\":[0,1,0],\"fov\":40,"
        "\"width\":4,\"height\":4},"
        "\"materials\":{\"floor\":{\"type\":\"diffuse\",\"albedo\":[0.5,0.5,0.5]},"
        "\"a\":{\"type\":\"emitter\",\"radiance\":[1,1,1]},"
        "\"b\":{\"type\":\"emitter\",\"radiance\":[10,2,0.5],\"albedo\":[0.3,0.3,0.3]},"
        "\"c\":{\"type\":\"emitter\",\"radiance\":[0,0,300]}},"
        "\"shapes\":["
        "{\"type\":\"quad\",\"material\":\"floor\",\"vertices\":[[-4,0,-4],[-4,0,4],[4,0,4],[4,0,-"
        "4]]},"
        "{\"type\":\"quad\",\"material\":\"a\",\"vertices\":[[-2,2,-0.5],[-1,2,-0.5],[-1,2,0.5],[-"
        "2,"
        "2,0.5]]},"
        "{\"type\":\"quad\",\"material\":\"b\",\"vertices\":[[0,2,-0.25],[2,2,-0.25],[2,2,0.25],"
        "[0,2,0.25]]},"
        "{\"type\":\"quad\",\"material\":\"c\",\"vertices\":[[1,3,1],[1.1,3,1],[1.1,3,1.1],[1,3,1."
        "1]]}]}";
    scene_t *s = load_text(json);
    ck_assert_uint_eq(s->light_count, 6);
    const uint32_t n = 1000000;
    uint32_t *count = calloc(s->triangle_count, sizeof *count);
    ck_assert_ptr_nonnull(count);
    for (uint32_t i = 0; i < n; i++) {
        vec3_t q;
        count[lights_sample(s, (i + 0.5) / n, 0.5f, &q)]++;
    }
    double total = 0;
    for (uint32_t t = 0; t < s->triangle_count; t++) {
        const uint32_t *v = s->indices + 3 * t;
        vec3_t p0 = scene_vertex(s, v[0]), p1 = scene_vertex(s, v[1]), p2 = scene_vertex(s, v[2]);
        double area = 0.5 * vec3_length(vec3_cross(vec3_sub(p1, p0), vec3_sub(p2, p0)));
        double p = (double)lights_area_pdf(s, t) * area;
        ck_assert_msg(fabs((double)count[t] / n - p) <= 2.0 / n + 1e-5 * p,
                      "triangle %u: picked %.6f of the time, pdf x area %.6f", t,
                      (double)count[t] / n, p);
        ck_assert_msg((count[t] > 0) == (s->materials[s->tri_material[t]].type == MATERIAL_EMITTER),
                      "triangle %u picked %u times", t, count[t]);
        total += p;
    }
    ck_assert_msg(fabs(total - 1.0) < 1e-5, "light pdfs integrate to %.9f", total);
    free(count);
    scene_destroy(&s);
}
END_TEST

/* ---- the Cornell box -------------------------------------------------- */

START_TEST(test_path_and_naive_agree_cornell)
{
    cJSON *root = cornell_json(32);
    scene_t *s = load_json(root);
    cJSON_Delete(root);
    film_t *p = render(s, 1, SCENE_INTEGRATOR_PATH, 64, 2, 32);
    film_t *n = render(s, 2, SCENE_INTEGRATOR_NAIVE, 256, 2, 32);
    assert_films_agree(p, n, 4, 0.0, "path vs naive");
    /* and the whole image, tighter */
    region_stat_t rp = region(p, 0, 0, 32, 32), rn = region(n, 0, 0, 32, 32);
    ck_assert_msg(fabs(rp.mean - rn.mean) <= NSIGMA * sqrt(rp.var + rn.var), "%.6f vs %.6f",
                  rp.mean, rn.mean);
    /* MIS must be worth something: the path integrator's variance is lower */
    ck_assert_msg(rp.var * 64 < rn.var * 256, "path variance per sample is not below naive's");
    film_destroy(&p);
    film_destroy(&n);
    scene_destroy(&s);
}
END_TEST

START_TEST(test_cornell_red_wall_on_left)
{
    cJSON *root = cornell_json(16);
    scene_t *s = load_json(root);
    cJSON_Delete(root);
    film_t *f = render(s, 1, SCENE_INTEGRATOR_PATH, 16, 2, 16);
    double left[3] = {0}, right[3] = {0};
    for (int y = 4; y < 12; y++)
        for (int x = 0; x < 3; x++) {
            double a[3], b[3];
            film_mean(f, (uint32_t)(y * 16 + x + 1), a);
            film_mean(f, (uint32_t)(y * 16 + 14 - x), b);
            for (int c = 0; c < 3; c++) {
                left[c] += a[c];
                right[c] += b[c];
            }
        }
    /* a mirrored camera would swap them: red dominates the left, green the right */
    ck_assert_msg(left[0] > 2 * left[1] && right[1] > 1.3 * right[0] && left[0] > 2 * right[0],
                  "left (%g %g %g) should be red, right (%g %g %g) green", left[0], left[1],
                  left[2], right[0], right[1], right[2]);
    film_destroy(&f);
    scene_destroy(&s);
}
END_TEST

/* ---- determinism ------------------------------------------------------ */

START_TEST(test_deterministic_across_threads)
{
    cJSON *root = cornell_json(24);
    scene_t *s = load_json(root);
    cJSON_Delete(root);
    film_t *a = render(s, 42, SCENE_INTEGRATOR_PATH, 48, 1, 16);
    film_t *b = render(s, 42, SCENE_INTEGRATOR_PATH, 48, 2, 16);
    film_t *c = render(s, 42, SCENE_INTEGRATOR_PATH, 48, 2, 16);
    film_t *d = render(s, 42, SCENE_INTEGRATOR_PATH, 48, 3, 16);
    film_t *e = render(s, 43, SCENE_INTEGRATOR_PATH, 48, 2, 16);
    size_t bytes = (size_t)a->width * (size_t)a->height * sizeof(film_pixel_t);
    ck_assert_msg(memcmp(a->pixels, b->pixels, bytes) == 0, "1 vs 2 threads differ");
    ck_assert_msg(memcmp(b->pixels, c->pixels, bytes) == 0, "two 2-thread runs differ");
    ck_assert_msg(memcmp(a->pixels, d->pixels, bytes) == 0, "1 vs 3 threads differ");
    ck_assert_msg(memcmp(a->pixels, e->pixels, bytes) != 0, "another seed gave the same image");
    film_destroy(&a);
    film_destroy(&b);
    film_destroy(&c);
    film_destroy(&d);
    film_destroy(&e);
    scene_destroy(&s);
}
END_TEST

/* The sobol sampler: its joined pairs where tracer.c draws them,
 * bit-identical for 1, 2 and 3 threads, and the same
 * image as independent numbers within noise (its variance channel assumes
 * independent samples, so it overstates a sobol mean's variance: the check
 * is looser, never tighter). */
START_TEST(test_sobol_deterministic_and_agrees)
{
    /* the pairs rng.h joins are the first light sample's with the film
     * point's, and the second BSDF sample's with the first's
     * (tracer_bounce_dim's layout: [2, 3] of a bounce the light, [4, 5]
     * the BSDF) */
    ck_assert_uint_eq(tracer_bounce_dim(0) + 2, 2 * RNG_SOBOL_LIGHT_PAIR);
    ck_assert_uint_eq(rng_sobol_partner(RNG_SOBOL_LIGHT_PAIR), 0);
    ck_assert_uint_eq(tracer_bounce_dim(1) + 4, 2 * RNG_SOBOL_BSDF2_PAIR);
    ck_assert_uint_eq(2 * rng_sobol_partner(RNG_SOBOL_BSDF2_PAIR), tracer_bounce_dim(0) + 4);
    cJSON *root = cornell_json(24);
    scene_t *s = load_json(root);
    cJSON_Delete(root);
    film_t *a = render_sampler(s, 42, SCENE_INTEGRATOR_PATH, RNG_SAMPLER_SOBOL, 48, 1, 16);
    film_t *b = render_sampler(s, 42, SCENE_INTEGRATOR_PATH, RNG_SAMPLER_SOBOL, 48, 2, 16);
    film_t *c = render_sampler(s, 42, SCENE_INTEGRATOR_PATH, RNG_SAMPLER_SOBOL, 48, 3, 16);
    film_t *ind = render(s, 42, SCENE_INTEGRATOR_PATH, 48, 2, 16);
    size_t bytes = (size_t)a->width * (size_t)a->height * sizeof(film_pixel_t);
    ck_assert_msg(memcmp(a->pixels, b->pixels, bytes) == 0, "sobol: 1 vs 2 threads differ");
    ck_assert_msg(memcmp(a->pixels, c->pixels, bytes) == 0, "sobol: 1 vs 3 threads differ");
    ck_assert_msg(memcmp(a->pixels, ind->pixels, bytes) != 0, "sobol gave independent's image");
    film_t *n = render(s, 2, SCENE_INTEGRATOR_PATH, 256, 2, 32);
    region_stat_t ra = region(a, 0, 0, 24, 24), rn = region(n, 0, 0, 24, 24);
    ck_assert_msg(fabs(ra.mean - rn.mean) <= NSIGMA * sqrt(ra.var + rn.var), "%.6f vs %.6f",
                  ra.mean, rn.mean);
    assert_films_agree(a, n, 4, 0.0, "sobol vs independent");
    film_destroy(&a);
    film_destroy(&b);
    film_destroy(&c);
    film_destroy(&ind);
    film_destroy(&n);
    scene_destroy(&s);
}
END_TEST

/* Our own kernels built for AVX-512, for AVX2 and for the baseline
 * (tracer_use_isa, what bench_core --isa avx2 measures as an AVX2-only
 * host): the same image, bit for bit, through the triangle list and
 * through our BVH (which has no baseline kernel), the diffuse shading's
 * AVX-512 (16 lanes), AVX2 (8) and baseline (4) builds included; a name
 * the tracer has no kernels for is refused. */
START_TEST(test_isa_same_bits)
{
    cJSON *root = cornell_json(16);
    scene_t *s = load_json(root);
    cJSON_Delete(root);
    __builtin_cpu_init();
    const int avx512 = __builtin_cpu_supports("avx512vl") != 0, avx2 = bvh_supported();
    const tracer_accel_t accels[] = {TRACER_ACCEL_TRILIST, TRACER_ACCEL_BVH};
    for (int a = 0; a < 2 && avx2; a++) {
        film_t *ref = render_accel_isa(s, accels[a], "avx2", 5, SCENE_INTEGRATOR_PATH,
                                       RNG_SAMPLER_SOBOL, 32, 2, 16, NULL);
        film_t *wide = render_accel_isa(s, accels[a], avx512 ? "avx512" : NULL, 5,
                                        SCENE_INTEGRATOR_PATH, RNG_SAMPLER_SOBOL, 32, 2, 16, NULL);
        size_t bytes = (size_t)ref->width * (size_t)ref->height * sizeof(film_pixel_t);
        ck_assert_msg(memcmp(ref->pixels, wide->pixels, bytes) == 0,
                      "accel %d: the avx2 kernels' image differs", (int)accels[a]);
        film_destroy(&ref);
        film_destroy(&wide);
    }
    /* the baseline: every host runs it */
    film_t *base = render_accel_isa(s, TRACER_ACCEL_TRILIST, "sse2", 5, SCENE_INTEGRATOR_PATH,
                                    RNG_SAMPLER_SOBOL, 32, 2, 16, NULL);
    film_t *best = render_accel_isa(s, TRACER_ACCEL_TRILIST, NULL, 5, SCENE_INTEGRATOR_PATH,
                                    RNG_SAMPLER_SOBOL, 32, 2, 16, NULL);
    ck_assert_msg(memcmp(base->pixels, best->pixels,
                         (size_t)base->width * (size_t)base->height * sizeof(film_pixel_t)) == 0,
                  "the baseline kernels' image differs from the widest's");
    film_destroy(&base);
    film_destroy(&best);
    tracer_t *t = NULL;
    tracer_device_t *dev = NULL;
    char err[512];
    ck_assert_msg(tracer_device_new(&dev, err, sizeof err) == 0, "%s", err);
    ck_assert_msg(tracer_new(dev, s, &t, err, sizeof err) == 0, "%s", err);
    /* the diffuse shading's build: 16 lanes beside the list's AVX-512
     * kernel only, so the images above compared it with 8 and 4 lanes */
    ck_assert_int_eq(tracer_shading_lanes(t), avx512 ? 16 : avx2 ? 8 : 4);
    ck_assert_int_eq(tracer_use_isa(t, "sse2"), 0);
    ck_assert_int_eq(tracer_shading_lanes(t), 4);
    ck_assert_int_eq(tracer_use_isa(t, "avx1024"), -1);
    ck_assert_int_eq(tracer_use_isa(t, "avx512"), avx512 ? 0 : -1);
    if (avx2) {
        ck_assert_int_eq(tracer_use_isa(t, "avx2"), 0);
        ck_assert_int_eq(tracer_shading_lanes(t), 8);
    }
    tracer_destroy(&t);
    if (avx2) {
        ck_assert_msg(tracer_new_accel(dev, s, TRACER_ACCEL_BVH, &t, err, sizeof err) == 0, "%s",
                      err);
        ck_assert_int_eq(tracer_use_isa(t, "sse2"), -1);
        /* our traversal keeps to 256 bits, and so does the shading beside it */
        ck_assert_int_eq(tracer_shading_lanes(t), 8);
        ck_assert_int_eq(tracer_use_isa(t, "avx512"), avx512 ? 0 : -1);
        ck_assert_int_eq(tracer_shading_lanes(t), 8);
        tracer_destroy(&t);
    }
    tracer_device_destroy(&dev);
    scene_destroy(&s);
}
END_TEST

/* The core API directly: the same task gives the same result whether it is
 * traced alone or in a batch, in any order. */
START_TEST(test_tasks_independent_of_batching)
{
    cJSON *root = cornell_json(16);
    scene_t *s = load_json(root);
    cJSON_Delete(root);
    /* through the triangle list, through our BVH, and through Embree, whose
     * rays go in packets of a chunk's paths (wave.h): tasks of 20 to 69
     * samples, so some are two or three chunks */
    const tracer_accel_t accels[] = {TRACER_ACCEL_TRILIST, TRACER_ACCEL_EMBREE, TRACER_ACCEL_BVH};
    for (int a = 0; a < 2 + bvh_supported(); a++) {
        tracer_t *t = NULL;
        tracer_device_t *dev = NULL;
        char err[256];
        ck_assert(tracer_device_new(&dev, err, sizeof err) == 0);
        ck_assert(tracer_new_accel(dev, s, accels[a], &t, err, sizeof err) == 0);
        tracer_settings_t st = {5, SCENE_INTEGRATOR_PATH, 0,
                                a ? RNG_SAMPLER_SOBOL : RNG_SAMPLER_INDEPENDENT};
        tracer_task_t tasks[8], reversed[8];
        uint32_t total = 0;
        for (int i = 0; i < 8; i++) {
            memset(&tasks[i], 0, sizeof tasks[i]);
            tasks[i].pixel = (uint32_t)(i * 29 + 3);
            tasks[i].sample_count = 20 + 7 * (uint32_t)i;
            tasks[i].first_sample = 64;
            tasks[i].prior_count = 64;
            tasks[i].prior_sum[0] = 3.0 + i;
            tasks[i].prior_sum[1] = 2.0;
            tasks[i].prior_sum[2] = 1.0;
            total += tasks[i].sample_count;
            reversed[7 - i] = tasks[i];
        }
        tracer_result_t batch[8], backwards[8], single;
        tracer_stats_t stats = {0, 0};
        ck_assert(tracer_trace(t, &st, tasks, 8, batch, &stats, err, sizeof err) == 0);
        ck_assert_uint_eq(stats.samples, total);
        ck_assert(stats.rays >= stats.samples);
        /* each record's rays are its samples' own: they add up to the call's */
        uint64_t record_rays = 0;
        for (int i = 0; i < 8; i++) {
            ck_assert_uint_ge(batch[i].rays, tasks[i].sample_count);
            record_rays += batch[i].rays;
        }
        ck_assert_uint_eq(record_rays, stats.rays);
        ck_assert(tracer_trace(t, &st, reversed, 8, backwards, NULL, err, sizeof err) == 0);
        for (int i = 7; i >= 0; i--) {
            ck_assert(tracer_trace(t, &st, &tasks[i], 1, &single, NULL, err, sizeof err) == 0);
            ck_assert_msg(memcmp(&single, &batch[i], sizeof single) == 0,
                          "accel %d: task %d differs", a, i);
            ck_assert_msg(memcmp(&backwards[7 - i], &batch[i], sizeof single) == 0,
                          "accel %d: task %d differs in the reversed list", a, i);
            ck_assert_uint_eq(single.samples + single.nonfinite, tasks[i].sample_count);
            ck_assert(single.pvar >= 0);
        }
        /* bad tasks are refused, not traced */
        tasks[0].pixel = 16 * 16;
        ck_assert(tracer_trace(t, &st, tasks, 1, batch, NULL, err, sizeof err) == -1);
        ck_assert_msg(strstr(err, "outside") != NULL, "%s", err);
        tasks[0].pixel = 0;
        tasks[0].sample_count = TRACER_MAX_TASK_SAMPLES + 1;
        ck_assert(tracer_trace(t, &st, tasks, 1, batch, NULL, err, sizeof err) == -1);
        tracer_destroy(&t);
        tracer_device_destroy(&dev);
    }
    scene_destroy(&s);
}
END_TEST

/* eq. 4.1 by hand: the statistic from the samples tracer_sample gives. */
START_TEST(test_pvar_matches_definition)
{
    cJSON *root = cornell_json(16);
    scene_t *s = load_json(root);
    cJSON_Delete(root);
    tracer_t *t = NULL;
    tracer_device_t *dev = NULL;
    char err[256];
    ck_assert(tracer_device_new(&dev, err, sizeof err) == 0);
    ck_assert(tracer_new(dev, s, &t, err, sizeof err) == 0);
    /* _i: 0 independent, 1 sobol */
    tracer_settings_t st = {9, SCENE_INTEGRATOR_PATH, 0, (rng_sampler_t)_i};
    tracer_task_t task = {.pixel = 120,
                          .sample_count = 32,
                          .first_sample = 32,
                          .prior_count = 32,
                          .prior_sum = {4.0, 3.0, 2.0}};
    tracer_result_t r;
    ck_assert(tracer_trace(t, &st, &task, 1, &r, NULL, err, sizeof err) == 0);
    double lum_prior = vmath_luminance(4.0, 3.0, 2.0), run = lum_prior, P[32];
    double sum[3] = {0, 0, 0};
    uint64_t rays = 0;
    for (int i = 0; i < 32; i++) {
        float rgb[3];
        rays += tracer_sample(t, &st, 120, 32 + (uint64_t)i, rgb);
        for (int c = 0; c < 3; c++)
            sum[c] += rgb[c];
        run += vmath_luminance(rgb[0], rgb[1], rgb[2]);
        P[i] = run / (32.0 + i + 1);
    }
    double pvar = 0;
    for (int i = 0; i < 31; i++)
        pvar += (P[i] - P[31]) * (P[i] - P[31]);
    ck_assert_msg(fabs(r.pvar - pvar) <= 1e-9 * (pvar + 1e-30), "pvar %.12g vs %.12g", r.pvar,
                  pvar);
    for (int c = 0; c < 3; c++)
        ck_assert(fabs(r.sum[c] - sum[c]) <= 1e-12 * (fabs(sum[c]) + 1));
    ck_assert_uint_eq(r.rays, rays); /* what relmse weighs a pixel's samples by */
    ck_assert_uint_gt(rays, 32);     /* the Cornell box: bounces and shadow rays too */
    tracer_destroy(&t);
    tracer_device_destroy(&dev);
    scene_destroy(&s);
}
END_TEST

/* ---- hard cases for numerical stability ------------------------------- */

static void transform_points(cJSON *arr, double k, double t)
{
    cJSON *p;
    cJSON_ArrayForEach(p, arr)
    {
        cJSON *c;
        cJSON_ArrayForEach(c, p) cJSON_SetNumberValue(c, c->valuedouble * k + t);
    }
}

static film_t *cornell_transformed(double k, double t, int size, uint32_t spp)
{
    cJSON *root = cornell_json(size);
    cJSON *cam = cJSON_GetObjectItem(root, "camera");
    cJSON *c;
    cJSON_ArrayForEach(c, cJSON_GetObjectItem(cam, "position"))
        cJSON_SetNumberValue(c, c->valuedouble * k + t);
    cJSON_ArrayForEach(c, cJSON_GetObjectItem(cam, "look_at"))
        cJSON_SetNumberValue(c, c->valuedouble * k + t);
    cJSON *sh;
    cJSON_ArrayForEach(sh, cJSON_GetObjectItem(root, "shapes"))
        transform_points(cJSON_GetObjectItem(sh, "vertices"), k, t);
    scene_t *s = load_json(root);
    cJSON_Delete(root);
    film_t *f = render(s, 1, SCENE_INTEGRATOR_PATH, spp, 2, 32);
    scene_destroy(&s);
    assert_all_finite(f);
    return f;
}

/* 256 spp: with new rays offset by 256 ulps of their origin (16 scene
 * units at 1e6) the translated box's contact shadows were 8 % off in a
 * block, inside the 5-sigma bound at 64 spp; at 256 spp it fails. */
START_TEST(test_cornell_any_scale)
{
    film_t *ref = cornell_transformed(1.0, 0.0, 32, 256);
    const double cases[][2] = {{1e-3, 0.0}, {1e5, 0.0}, {1.0, 1e6}};
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        film_t *f = cornell_transformed(cases[i][0], cases[i][1], 32, 256);
        char what[64];
        snprintf(what, sizeof what, "scale %g translate %g", cases[i][0], cases[i][1]);
        /* 4x4 blocks: light leaks or acne would shift a block by far more */
        assert_films_agree(ref, f, 4, 1e-3, what);
        film_destroy(&f);
    }
    film_destroy(&ref);
}
END_TEST

/* A camera 1 cm above an infinite-looking floor, looking 0.3 to 0.7 degrees
 * below the horizon, under a huge black emitter: the exact answer is
 * rho * Le * F with F = 1 - 3e-8; acne would darken it. */
START_TEST(test_grazing_camera)
{
    const char *json = "{\"camera\":{\"position\":[0,0.01,0],\"look_at\":[0,-0.00872654,1],\"up\":["
                       "0,1,0],\"fov\":0.4,"
                       "\"width\":16,\"height\":16},"
                       "\"materials\":{\"floor\":{\"type\":\"diffuse\",\"albedo\":[0.5,0.5,0.5]},"
                       "\"sky\":{\"type\":\"emitter\",\"radiance\":[1,1,1]}},"
                       "\"shapes\":["
                       "{\"type\":\"quad\",\"material\":\"floor\",\"vertices\":[[-5000,0,-5000],[-"
                       "5000,0,5000],[5000,0,5000],[5000,0,-5000]]},"
                       "{\"type\":\"quad\",\"material\":\"sky\",\"vertices\":[[-5000,1,-5000],["
                       "5000,1,-5000],[5000,1,5000],[-5000,1,5000]]}]}";
    scene_t *s = load_text(json);
    for (int integ = 0; integ < 2; integ++) {
        film_t *f = render(s, 5, (scene_integrator_t)integ, 64, 2, 32);
        assert_all_finite(f);
        region_stat_t r = region(f, 0, 0, 16, 16);
        double expect = 0.5 * square_form_factor(5000, 1);
        ck_assert_msg(fabs(r.mean - expect) <= NSIGMA * sqrt(r.var) + 1e-6,
                      "grazing (%s): %.7f vs %.7f, sigma %.3g",
                      scene_integrator_name((scene_integrator_t)integ), r.mean, expect,
                      sqrt(r.var));
        for (int i = 0; i < 256; i++) {
            double rgb[3];
            film_mean(f, (uint32_t)i, rgb);
            ck_assert_msg(rgb[1] > 0.25, "pixel %d dark (%.4f): self-shadowing", i, rgb[1]);
        }
        film_destroy(&f);
    }
    scene_destroy(&s);
}
END_TEST

/* The Cornell floor cut into 2 x 3000 slivers (aspect ratio about 3000) plus
 * degenerate triangles: the degenerate ones are dropped and counted, and the
 * image matches the plain box (light leaking between slivers would not). */
START_TEST(test_slivers_and_degenerates)
{
    cJSON *root = cornell_json(32);
    cJSON *shapes = cJSON_GetObjectItem(root, "shapes");
    cJSON_DeleteItemFromArray(shapes, 0); /* the floor quad */
    const int n = 3000, degenerate = 5;
    const double v0[3] = {552.8, 0, 0}, v1[3] = {0, 0, 0}, v2[3] = {0, 0, 559.2},
                 v3[3] = {549.6, 0, 559.2};
    cJSON *sh = cJSON_CreateObject();
    cJSON_AddStringToObject(sh, "type", "triangles");
    cJSON_AddStringToObject(sh, "material", "white");
    cJSON *verts = cJSON_AddArrayToObject(sh, "vertices");
    cJSON *idx = cJSON_AddArrayToObject(sh, "indices");
    double pt[3];
    for (int d = 0; d < 3; d++)
        pt[d] = v0[d];
    cJSON_AddItemToArray(verts, cJSON_CreateDoubleArray(pt, 3));
    int count = 1;
    for (int edge = 0; edge < 2; edge++) {
        const double *a = edge ? v2 : v1, *b = edge ? v3 : v2;
        for (int i = 0; i <= n; i++) {
            for (int d = 0; d < 3; d++)
                pt[d] = a[d] + (b[d] - a[d]) * i / n;
            cJSON_AddItemToArray(verts, cJSON_CreateDoubleArray(pt, 3));
            if (i > 0) {
                int tri[3] = {0, count - 1, count};
                cJSON_AddItemToArray(idx, cJSON_CreateIntArray(tri, 3));
            }
            count++;
        }
    }
    /* zero-area triangles: a repeated vertex, and three collinear points */
    for (int i = 0; i < degenerate; i++) {
        int tri[3] = {1 + i, 1 + i, 2 + i};
        int col[3] = {1, 2 + i, 3 + i}; /* on the edge v1 -> v2: collinear */
        cJSON_AddItemToArray(idx, cJSON_CreateIntArray(i % 2 ? col : tri, 3));
    }
    cJSON_AddItemToArray(shapes, sh);
    scene_t *s = load_json(root);
    cJSON_Delete(root);
    ck_assert_uint_eq(s->dropped_degenerate, (size_t)degenerate);
    ck_assert_uint_eq(s->triangle_count, 30 + 2 * (size_t)n);
    int warned = 0;
    for (int i = 0; i < s->warning_count; i++)
        warned |= strstr(s->warnings[i], "degenerate") != NULL;
    ck_assert(warned);
    film_t *f = render(s, 1, SCENE_INTEGRATOR_PATH, 64, 2, 32);
    film_t *ref = cornell_transformed(1.0, 0.0, 32, 64);
    assert_all_finite(f);
    assert_films_agree(ref, f, 4, 1e-3, "sliver floor");
    film_destroy(&f);
    film_destroy(&ref);
    scene_destroy(&s);
}
END_TEST

/* The Cornell light shrunk 1000x per side and made 1e6x brighter (same
 * power): fireflies, but no NaN/Inf, and independent renders agree with
 * each other and, away from the light's own pixels, with the normal box. */
START_TEST(test_tiny_bright_light)
{
    cJSON *root = cornell_json(32);
    cJSON *mats = cJSON_GetObjectItem(root, "materials");
    cJSON *light = cJSON_GetObjectItem(mats, "light");
    double rad[3] = {17e6, 12e6, 4e6};
    cJSON_ReplaceItemInObject(light, "radiance", cJSON_CreateDoubleArray(rad, 3));
    cJSON *shapes = cJSON_GetObjectItem(root, "shapes");
    cJSON *lq = cJSON_GetArrayItem(shapes, cJSON_GetArraySize(shapes) - 1);
    double cx = 278, cz = 279.5, hw = 0.065, hd = 0.0525;
    double q[4][3] = {{cx + hw, 548.7, cz - hd},
                      {cx + hw, 548.7, cz + hd},
                      {cx - hw, 548.7, cz + hd},
                      {cx - hw, 548.7, cz - hd}};
    cJSON *verts = cJSON_CreateArray();
    for (int i = 0; i < 4; i++)
        cJSON_AddItemToArray(verts, cJSON_CreateDoubleArray(q[i], 3));
    cJSON_ReplaceItemInObject(lq, "vertices", verts);
    scene_t *s = load_json(root);
    cJSON_Delete(root);
    film_t *a = render(s, 1, SCENE_INTEGRATOR_PATH, 64, 2, 32);
    film_t *b = render(s, 2, SCENE_INTEGRATOR_PATH, 64, 2, 32);
    ck_assert_uint_eq(film_total_nonfinite(a) + film_total_nonfinite(b), 0);
    assert_all_finite(a);
    assert_all_finite(b);
    /* below the light's row: the ceiling pixels may see the light itself */
    region_stat_t ra = region(a, 0, 8, 32, 32), rb = region(b, 0, 8, 32, 32);
    ck_assert_msg(fabs(ra.mean - rb.mean) <= NSIGMA * sqrt(ra.var + rb.var), "%.6g vs %.6g",
                  ra.mean, rb.mean);
    film_t *ref = cornell_transformed(1.0, 0.0, 32, 64);
    region_stat_t rr = region(ref, 0, 8, 32, 32);
    /* a point light and a 13 cm one light the box almost alike: within 3 % */
    ck_assert_msg(fabs(ra.mean - rr.mean) <= NSIGMA * sqrt(ra.var + rr.var) + 0.03 * rr.mean,
                  "tiny light %.6g vs normal %.6g", ra.mean, rr.mean);
    film_destroy(&a);
    film_destroy(&b);
    film_destroy(&ref);
    scene_destroy(&s);
}
END_TEST

/* A glass ball over a diffuse floor under a small light: the caustic is
 * reached only through specular chains, which the two integrators sample in
 * different ways (light hit after a specular bounce vs BSDF sampling); they
 * must agree. */
START_TEST(test_glass_caustic)
{
    const char *json = "{\"camera\":{\"position\":[0,3,-5],\"look_at\":[0,0.6,0],\"up\":[0,1,0],"
                       "\"fov\":35,\"width\":16,\"height\":16},"
                       "\"materials\":{\"floor\":{\"type\":\"diffuse\",\"albedo\":[0.7,0.7,0.7]},"
                       "\"glass\":{\"type\":\"dielectric\",\"ior\":1.5},"
                       "\"light\":{\"type\":\"emitter\",\"radiance\":[20,20,20]}},"
                       "\"shapes\":["
                       "{\"type\":\"quad\",\"material\":\"floor\",\"vertices\":[[-4,0,-4],[-4,0,4],"
                       "[4,0,4],[4,0,-4]]},"
                       "{\"type\":\"sphere\",\"material\":\"glass\",\"center\":[0,1.2,0],"
                       "\"radius\":0.7,\"subdivisions\":4},"
                       "{\"type\":\"quad\",\"material\":\"light\",\"vertices\":[[-0.5,5,-0.5],[0.5,"
                       "5,-0.5],[0.5,5,0.5],[-0.5,5,0.5]]}]}";
    scene_t *s = load_text(json);
    film_t *p = render(s, 1, SCENE_INTEGRATOR_PATH, 256, 2, 32);
    film_t *n = render(s, 2, SCENE_INTEGRATOR_NAIVE, 1024, 2, 32);
    assert_all_finite(p);
    assert_all_finite(n);
    ck_assert_uint_eq(film_total_nonfinite(p), 0);
    assert_films_agree(p, n, 2, 0.0, "caustic path vs naive");
    film_destroy(&p);
    film_destroy(&n);
    scene_destroy(&s);
}
END_TEST

/* A pixel whose every sample is the same: a million samples through tasks
 * and the film keep the mean exact to 1e-12 and the variance at 0. */
START_TEST(test_million_constant_samples)
{
    char json[4096];
    furnace_box(json, sizeof json, "{\"type\":\"emitter\",\"radiance\":[0.1,0.7,3.3]}", "",
                "{\"position\":[0,0,0],\"look_at\":[0,0,1],\"up\":[0,1,0],\"fov\":60,\"width\":1,"
                "\"height\":1}");
    scene_t *s = load_text(json);
    tracer_t *t = NULL;
    tracer_device_t *dev = NULL;
    char err[256];
    ck_assert(tracer_device_new(&dev, err, sizeof err) == 0);
    ck_assert(tracer_new(dev, s, &t, err, sizeof err) == 0);
    film_t *f = film_new(1, 1);
    tracer_settings_t st = {1, SCENE_INTEGRATOR_PATH, 0, RNG_SAMPLER_INDEPENDENT};
    const uint32_t per = TRACER_MAX_TASK_SAMPLES;
    const uint64_t total = 1000000;
    for (uint64_t first = 0; first < total; first += per) {
        tracer_task_t task = {.pixel = 0,
                              .first_sample = first,
                              .sample_count =
                                  (uint32_t)(total - first < per ? total - first : per)};
        film_prior(f, &task);
        tracer_result_t r;
        ck_assert(tracer_trace(t, &st, &task, 1, &r, NULL, err, sizeof err) == 0);
        ck_assert(film_merge(f, &r) == 0);
    }
    ck_assert_uint_eq(f->pixels[0].count, total);
    double rgb[3];
    film_mean(f, 0, rgb);
    const double expect[3] = {(float)0.1, (float)0.7, (float)3.3};
    for (int c = 0; c < 3; c++)
        ck_assert_msg(fabs(rgb[c] - expect[c]) <= 1e-12 * expect[c], "channel %d: %.17g vs %.17g",
                      c, rgb[c], expect[c]);
    ck_assert(film_variance_of_mean(f, 0) <= 1e-24);
    film_destroy(&f);
    tracer_destroy(&t);
    tracer_device_destroy(&dev);
    scene_destroy(&s);
}
END_TEST

/* The camera inside a closed white cube, the cube inside a closed emitter
 * box facing it: a ray or shadow ray through a crack between the cube's
 * triangles reaches light, so the image is exactly black only if no ray
 * of the 10^8 (10^7 under sanitizers) leaks. The triangle list (what the
 * tracer uses for these 24 triangles), and Embree's ROBUST BVH. */
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define LEAK_TEST_RAYS 10000000ull
#else
#define LEAK_TEST_RAYS 100000000ull
#endif

START_TEST(test_closed_cube_no_leak)
{
    char json[8192];
    furnace_box(
        json, sizeof json, "{\"type\":\"diffuse\",\"albedo\":[0.8,0.8,0.8]}",
        ",{\"type\":\"quad\",\"material\":\"sky\",\"vertices\":[[-2,-2,-2],[-2,-2,2],[2,-2,"
        "2],[2,-2,-2]]},"
        "{\"type\":\"quad\",\"material\":\"sky\",\"vertices\":[[-2,2,-2],[2,2,-2],[2,2,2],[-"
        "2,2,2]]},"
        "{\"type\":\"quad\",\"material\":\"sky\",\"vertices\":[[-2,-2,-2],[-2,2,-2],[-2,2,2],"
        "[-2,-2,2]]},"
        "{\"type\":\"quad\",\"material\":\"sky\",\"vertices\":[[2,-2,-2],[2,-2,2],[2,2,2],[2,"
        "2,-2]]},"
        "{\"type\":\"quad\",\"material\":\"sky\",\"vertices\":[[-2,-2,-2],[2,-2,-2],[2,2,-2],"
        "[-2,2,-2]]},"
        "{\"type\":\"quad\",\"material\":\"sky\",\"vertices\":[[-2,-2,2],[-2,2,2],[2,2,2],[2,"
        "-2,2]]}",
        inside_camera);
    /* furnace_box names its materials; add the emitter */
    char *m = strstr(json, "\"mirror\"");
    ck_assert(m != NULL);
    char patched[8400];
    snprintf(patched, sizeof patched,
             "%.*s\"sky\": {\"type\": \"emitter\", \"radiance\": [1, 1, 1]}, %s", (int)(m - json),
             json, m);
    scene_t *s = load_text(patched);
    ck_assert_uint_eq(s->triangle_count, 24);
    ck_assert_int_eq(tracer_accel_for(s), TRACER_ACCEL_TRILIST);
    const tracer_accel_t accels[] = {TRACER_ACCEL_TRILIST, TRACER_ACCEL_EMBREE, TRACER_ACCEL_BVH};
    static const char *names[] = {"trilist", "embree", "bvh"};
    for (int a = 0; a < 2 + bvh_supported(); a++) {
        /* Embree's ROBUST mode and a BVH are slower: a tenth of the rays */
        uint64_t want = a == 0 ? LEAK_TEST_RAYS : LEAK_TEST_RAYS / 10, rays = 0;
        /* about 11 rays per sample in this box at albedo 0.8 */
        uint32_t spp = (uint32_t)(want / (16 * 16 * 10) + 32) / 32 * 32;
        film_t *f = render_accel(s, accels[a], 3, SCENE_INTEGRATOR_PATH, RNG_SAMPLER_SOBOL, spp, 2,
                                 32, &rays);
        ck_assert_msg(rays >= want, "only %llu rays", (unsigned long long)rays);
        for (uint32_t i = 0; i < 256; i++) {
            double rgb[3];
            film_mean(f, i, rgb);
            ck_assert_msg(rgb[0] == 0.0 && rgb[1] == 0.0 && rgb[2] == 0.0,
                          "%s: pixel %u sees light through the cube: %g", names[a], i, rgb[0]);
        }
        film_destroy(&f);
    }
    scene_destroy(&s);
}
END_TEST

/* The Cornell box traced with the triangle list and with Embree: the same
 * image within noise, block by block. */
START_TEST(test_trilist_and_embree_agree_cornell)
{
    cJSON *root = cornell_json(32);
    scene_t *s = load_json(root);
    cJSON_Delete(root);
    ck_assert_int_eq(tracer_accel_for(s), TRACER_ACCEL_TRILIST);
    film_t *a = render_accel(s, TRACER_ACCEL_TRILIST, 9, SCENE_INTEGRATOR_PATH,
                             RNG_SAMPLER_INDEPENDENT, 256, 2, 32, NULL);
    film_t *b = render_accel(s, TRACER_ACCEL_EMBREE, 10, SCENE_INTEGRATOR_PATH,
                             RNG_SAMPLER_INDEPENDENT, 256, 2, 32, NULL);
    assert_films_agree(a, b, 8, 0.0, "trilist vs embree");
    if (bvh_supported()) {
        film_t *c = render_accel(s, TRACER_ACCEL_BVH, 11, SCENE_INTEGRATOR_PATH,
                                 RNG_SAMPLER_INDEPENDENT, 256, 2, 32, NULL);
        assert_films_agree(a, c, 8, 0.0, "trilist vs our bvh");
        film_destroy(&c);
    }
    film_destroy(&a);
    film_destroy(&b);
    scene_destroy(&s);
}
END_TEST

/* Rays cast in Embree packets (what the wavefront engine casts) against the
 * same rays one a call (what the scalar engine casts): the same hit,
 * triangle, t, u and v bits, and the same occlusion, whichever rays share
 * the packet and however full it is. On the 15k-triangle Buddha: random
 * rays, and rays and segments aimed exactly at vertices and edge midpoints
 * of the mesh (the shared edges where a watertight test must decide). */
START_TEST(test_packets_match_single_rays)
{
    char path[1024], err[VB_ERR_LEN];
    scene_t *s = NULL;
    ck_assert_msg(scene_load(tu_root_path(path, sizeof path, "scenes/happy-buddha.json"), &s, err,
                             sizeof err) == 0,
                  "%s", err);
    tracer_device_t *dev = NULL;
    tracer_t *t = NULL;
    ck_assert_msg(tracer_device_new(&dev, err, sizeof err) == 0, "%s", err);
    ck_assert_msg(tracer_new_accel(dev, s, TRACER_ACCEL_EMBREE, &t, err, sizeof err) == 0, "%s",
                  err);
    rng_stream_t rng = rng_stream(17, 0, 0);
    size_t hits = 0, occluded = 0, rays = 0;
    for (uint32_t round = 0; round < 12000; round++) {
        /* 1 to 8 rays a packet */
        size_t n = 1 + round % TRACER_PACKET;
        tracer_packet_t pk;
        for (size_t i = 0; i < n; i++) {
            vec3_t o = vec3_make(rng_next_float(&rng) * 2.0f - 1.0f, rng_next_float(&rng) * 1.5f,
                                 rng_next_float(&rng) * 2.0f - 1.0f);
            uint32_t tri = (uint32_t)(rng_next_float(&rng) * (float)s->triangle_count);
            if (tri >= s->triangle_count)
                tri = s->triangle_count - 1;
            const uint32_t *idx = s->indices + 3 * (size_t)tri;
            vec3_t a = vec3_make(s->positions[3 * idx[0]], s->positions[3 * idx[0] + 1],
                                 s->positions[3 * idx[0] + 2]);
            vec3_t b = vec3_make(s->positions[3 * idx[1]], s->positions[3 * idx[1] + 1],
                                 s->positions[3 * idx[1] + 2]);
            vec3_t target;
            switch ((round + i) % 3) {
            case 0: /* a vertex */
                target = a;
                break;
            case 1: /* an edge's midpoint */
                target = vec3_scale(vec3_add(a, b), 0.5f);
                break;
            default: /* anywhere */
                target = vec3_make(rng_next_float(&rng) * 4.0f - 2.0f, rng_next_float(&rng) * 3.0f,
                                   rng_next_float(&rng) * 4.0f - 2.0f);
            }
            pk.o[i] = o;
            pk.d[i] = vec3_sub(target, o);
        }
        tracer_packet_t unit = pk;
        for (size_t i = 0; i < n; i++)
            unit.d[i] = vec3_normalize(pk.d[i]);
        int hit[TRACER_PACKET], clear[TRACER_PACKET];
        tracer_hit_t h[TRACER_PACKET];
        tracer_intersect_packet(t, &unit, n, hit, h);
        tracer_unoccluded_packet(t, &pk, n, clear);
        for (size_t i = 0; i < n; i++, rays++) {
            tracer_hit_t one = {0, 0, 0, 0};
            int hit1 = tracer_intersect(t, unit.o[i], unit.d[i], &one);
            ck_assert_msg(hit[i] == hit1, "round %u ray %zu: packet hit %d, alone %d", round, i,
                          hit[i], hit1);
            if (hit1) {
                hits++;
                ck_assert_msg(h[i].tri == one.tri && memcmp(&h[i].t, &one.t, sizeof one.t) == 0 &&
                                  memcmp(&h[i].u, &one.u, sizeof one.u) == 0 &&
                                  memcmp(&h[i].v, &one.v, sizeof one.v) == 0,
                              "round %u ray %zu: packet tri %u t %a u %a v %a, alone tri %u t "
                              "%a u %a v %a",
                              round, i, h[i].tri, h[i].t, h[i].u, h[i].v, one.tri, one.t, one.u,
                              one.v);
            }
            int clear1 = tracer_unoccluded(t, pk.o[i], pk.d[i]);
            ck_assert_msg(clear[i] == clear1, "round %u segment %zu: packet %d, alone %d", round, i,
                          clear[i], clear1);
            occluded += !clear1;
        }
    }
    /* both answers occur often enough to mean something */
    ck_assert_msg(hits > rays / 4 && occluded > rays / 10 && occluded < rays - rays / 10,
                  "%zu rays: %zu hits, %zu occluded", rays, hits, occluded);
    tracer_destroy(&t);
    tracer_device_destroy(&dev);
    scene_destroy(&s);
}
END_TEST

/* Paths are traced with denormals flushed to zero (as Embree asks), in
 * both engines: an emitter of denormal radiance, seen straight on, gives
 * exactly black; and tracer_trace gives the caller its own floating-point
 * mode back. */
START_TEST(test_denormals_flushed_while_tracing)
{
    const char *json =
        "{\"camera\": {\"position\": [0, 0, 3], \"look_at\": [0, 0, 0], \"fov\": 20, "
        "\"width\": 2, \"height\": 2},"
        " \"materials\": {\"l\": {\"type\": \"emitter\", \"radiance\": [1e-39, 2e-39, 1e-39]}},"
        " \"shapes\": [{\"type\": \"quad\", \"material\": \"l\", \"vertices\": [[-5, -5, 0], "
        "[5, -5, 0], [5, 5, 0], [-5, 5, 0]]}]}";
    scene_t *s = load_text(json);
    ck_assert(s->materials[0].radiance.y > 0.0f && s->materials[0].radiance.y < 0x1p-126f);
    tracer_device_t *dev = NULL;
    tracer_t *t = NULL;
    char err[VB_ERR_LEN];
    ck_assert_msg(tracer_device_new(&dev, err, sizeof err) == 0, "%s", err);
    ck_assert_msg(tracer_new(dev, s, &t, err, sizeof err) == 0, "%s", err);
    const unsigned int before = _mm_getcsr();
    for (int engine = 0; engine < 2; engine++) {
        tracer_use_engine(t, engine ? TRACER_ENGINE_SCALAR : TRACER_ENGINE_WAVEFRONT);
        tracer_task_t task = {.pixel = 1, .sample_count = 8};
        tracer_result_t r;
        tracer_settings_t st = {
            .seed = 1, .integrator = SCENE_INTEGRATOR_PATH, .sampler = RNG_SAMPLER_SOBOL};
        ck_assert_msg(tracer_trace(t, &st, &task, 1, &r, NULL, err, sizeof err) == 0, "%s", err);
        ck_assert_uint_eq(r.samples, 8);
        ck_assert_msg(r.sum[0] == 0 && r.sum[1] == 0 && r.sum[2] == 0, "engine %d: %g %g %g",
                      engine, r.sum[0], r.sum[1], r.sum[2]);
        ck_assert_uint_eq(_mm_getcsr(), before);
    }
    tracer_destroy(&t);
    tracer_device_destroy(&dev);
    scene_destroy(&s);
}
END_TEST

/* Traces the same task list with both engines (tracer.h) and checks that
 * every result is the same bits: sums, sample and ray counts, the layer
 * statistics. Tasks of 1 to 61 samples, so runs of tasks split at
 * WAVE_MAX_SAMPLES and paths of several tasks share the wavefront. */
static void assert_engines_agree_isa(const scene_t *s, tracer_accel_t accel, const char *isa,
                                     const tracer_settings_t *st, const char *what)
{
    tracer_device_t *dev = NULL;
    tracer_t *t = NULL;
    char err[VB_ERR_LEN];
    ck_assert_msg(tracer_device_new(&dev, err, sizeof err) == 0, "%s", err);
    ck_assert_msg(tracer_new_accel(dev, s, accel, &t, err, sizeof err) == 0, "%s", err);
    if (isa)
        ck_assert_int_eq(tracer_use_isa(t, isa), 0);
    uint32_t npix = (uint32_t)s->camera.width * (uint32_t)s->camera.height;
    tracer_task_t *tasks = calloc(npix, sizeof *tasks);
    tracer_result_t *a = calloc(npix, sizeof *a), *b = calloc(npix, sizeof *b);
    ck_assert(tasks && a && b);
    for (uint32_t p = 0; p < npix; p++) {
        tasks[p].pixel = (p * 7u) % npix;
        tasks[p].sample_count = 1 + (p * 13u) % 61u;
        tasks[p].first_sample = (p % 3u) * 32u;
        tasks[p].prior_count = tasks[p].first_sample;
        tasks[p].prior_sum[0] = 0.25 * (double)tasks[p].first_sample;
    }
    tracer_stats_t sa = {0, 0}, sb = {0, 0};
    tracer_use_engine(t, TRACER_ENGINE_WAVEFRONT);
    ck_assert_msg(tracer_trace(t, st, tasks, npix, a, &sa, err, sizeof err) == 0, "%s", err);
    tracer_use_engine(t, TRACER_ENGINE_SCALAR);
    ck_assert_msg(tracer_trace(t, st, tasks, npix, b, &sb, err, sizeof err) == 0, "%s", err);
    ck_assert_uint_eq(sa.rays, sb.rays);
    ck_assert_uint_eq(sa.samples, sb.samples);
    for (uint32_t p = 0; p < npix; p++)
        ck_assert_msg(memcmp(&a[p], &b[p], sizeof a[p]) == 0,
                      "%s: task %u (pixel %u): wavefront %.9g %.9g %.9g (%u rays), scalar %.9g "
                      "%.9g %.9g (%u rays)",
                      what, p, tasks[p].pixel, a[p].sum[0], a[p].sum[1], a[p].sum[2], a[p].rays,
                      b[p].sum[0], b[p].sum[1], b[p].sum[2], b[p].rays);
    free(tasks);
    free(a);
    free(b);
    tracer_destroy(&t);
    tracer_device_destroy(&dev);
}

static void assert_engines_agree(const scene_t *s, tracer_accel_t accel,
                                 const tracer_settings_t *st, const char *what)
{
    assert_engines_agree_isa(s, accel, NULL, st, what);
}

/* The wavefront engine and the scalar one give the same bits on every
 * shipped scene (24x24), under both samplers and both integrators, with
 * and without a depth limit, through the triangle list and Embree, and
 * with the baseline build of the shading kernels as with the widest. */
static void engines_agree_on(scene_t *sc, const char *name)
{
    static const struct {
        scene_integrator_t integrator;
        rng_sampler_t sampler;
        uint32_t max_depth;
    } variants[] = {
        {SCENE_INTEGRATOR_PATH, RNG_SAMPLER_SOBOL, 0},
        {SCENE_INTEGRATOR_PATH, RNG_SAMPLER_INDEPENDENT, 0},
        {SCENE_INTEGRATOR_NAIVE, RNG_SAMPLER_SOBOL, 0},
        {SCENE_INTEGRATOR_PATH, RNG_SAMPLER_SOBOL, 3},
    };
    for (size_t v = 0; v < sizeof variants / sizeof variants[0]; v++) {
        tracer_settings_t st = {.seed = 5 + v,
                                .integrator = variants[v].integrator,
                                .max_depth = variants[v].max_depth,
                                .sampler = variants[v].sampler};
        char what[512];
        snprintf(what, sizeof what, "%s, variant %zu", name, v);
        assert_engines_agree(sc, TRACER_ACCEL_AUTO, &st, what);
    }
    {
        /* (our traversal has no baseline kernel: Embree's for the others) */
        const tracer_accel_t accel = tracer_accel_for(sc) == TRACER_ACCEL_TRILIST
                                         ? TRACER_ACCEL_TRILIST
                                         : TRACER_ACCEL_EMBREE;
        tracer_settings_t st = {.seed = 4, .sampler = RNG_SAMPLER_SOBOL};
        char what[512];
        snprintf(what, sizeof what, "%s, baseline kernels", name);
        assert_engines_agree_isa(sc, accel, "sse2", &st, what);
    }
    if (tracer_accel_for(sc) == TRACER_ACCEL_TRILIST) {
        tracer_settings_t st = {.seed = 3, .sampler = RNG_SAMPLER_SOBOL};
        assert_engines_agree(sc, TRACER_ACCEL_EMBREE, &st, name);
        if (bvh_supported())
            assert_engines_agree(sc, TRACER_ACCEL_BVH, &st, name);
    }
}

START_TEST(test_engines_agree)
{
    for_each_shipped_scene(24, engines_agree_on);
}
END_TEST

/* Lights with no area, against their closed forms: a diffuse plane (albedo
 * 1/2) seen from straight above, lit by a point light of intensity 4 at
 * height 1 (radiance 2 / (pi d^3)), then by a directional light of
 * irradiance 2 at 30 degrees (1 cos 30 / pi everywhere); each pixel's mean
 * against the radiance integrated over its footprint, to 0.5 %. A point
 * light lying on the plane gives it nothing, and no NaN. */
static const char delta_fmt[] =
    "{\"camera\": {\"position\": [0, 0, 5], \"look_at\": [0, 0, 0], \"fov\": 20, \"width\": 6, "
    "\"height\": 6},"
    " \"materials\": {\"w\": {\"type\": \"diffuse\", \"albedo\": [0.5, 0.5, 0.5]}},"
    " \"shapes\": [{\"type\": \"quad\", \"material\": \"w\", \"vertices\": [[-4, -4, 0], [4, -4, "
    "0], [4, 4, 0], [-4, 4, 0]]}], \"lights\": [%s]}";

START_TEST(delta_lights_exact)
{
    static const char *const lights[] = {
        "{\"type\": \"point\", \"position\": [0, 0, 1], \"intensity\": [4, 4, 4]}",
        "{\"type\": \"directional\", \"direction\": [0, 0.5, -0.8660254], \"irradiance\": [2, 2, "
        "2]}",
        "{\"type\": \"point\", \"position\": [0.5, 0, 0], \"intensity\": [4, 4, 4]}",
    };
    char json[2048];
    for (int c = 0; c < 3; c++) {
        snprintf(json, sizeof json, delta_fmt, lights[c]);
        scene_t *s = load_text(json);
        ck_assert_uint_eq(s->delta_count, 1);
        ck_assert(s->delta_pick == 1.0f && s->light_count == 0);
        film_t *f = render_sampler(s, 9, SCENE_INTEGRATOR_PATH, RNG_SAMPLER_SOBOL, 256, 2, 16);
        ck_assert_uint_eq(film_total_nonfinite(f), 0);
        double half = 5 * tan(10 * M_PI / 180); /* the plane's half extent in view */
        for (uint32_t p = 0; p < 36; p++) {
            double rgb[3];
            film_mean(f, p, rgb);
            double want = 0;
            if (c == 0) {
                /* the footprint of pixel (px, py): by symmetry its sign does not matter */
                double x0 = -half + 2 * half * (p % 6) / 6, y0 = -half + 2 * half * (p / 6) / 6;
                for (int a = 0; a < 32; a++)
                    for (int b = 0; b < 32; b++) {
                        double x = x0 + 2 * half / 6 * (a + 0.5) / 32;
                        double y = y0 + 2 * half / 6 * (b + 0.5) / 32;
                        double d = sqrt(x * x + y * y + 1);
                        want += 2 / (M_PI * d * d * d) / 1024;
                    }
            } else if (c == 1) {
                want = 0.8660254 / M_PI;
            }
            ck_assert_msg(c == 2 ? rgb[0] == 0 : fabs(rgb[0] / want - 1) < 5e-3,
                          "light %d, pixel %u: %g, want %g", c, p, rgb[0], want);
        }
        film_destroy(&f);
        scene_destroy(&s);
    }
}
END_TEST

/* A spot's falloff, by hand: full inside beam_width (15 degrees), half
 * way down the ramp at 17.5, nothing past cutoff_angle (20). */
START_TEST(spot_falloff)
{
    char json[2048];
    snprintf(json, sizeof json, delta_fmt,
             "{\"type\": \"spot\", \"position\": [0, 0, 1], \"direction\": [0, 0, -1], "
             "\"intensity\": [1, 2, 3], \"cutoff_angle\": 20, \"beam_width\": 15}");
    scene_t *s = load_text(json);
    static const double deg[] = {0, 10, 17.5, 19.9, 20.5, 60};
    static const double falloff[] = {1, 1, 0.5, 0.02, 0, 0};
    for (int i = 0; i < 6; i++) {
        double t = tan(deg[i] * M_PI / 180);
        vec3_t p = vec3_make((float)t, 0, 0), wl, light, target;
        int got = lights_delta_sample(s, 0, p, &wl, &light, &target);
        double d2 = 1 + t * t;
        ck_assert_int_eq(got, falloff[i] > 0);
        if (got)
            ck_assert_msg(fabs(light.y * d2 / 2 - falloff[i]) < 1e-3, "%g deg: %g, want %g", deg[i],
                          light.y * d2 / 2, falloff[i]);
    }
    scene_destroy(&s);
}
END_TEST

/* An emitting sphere (radius 0.5, radiance 1, centre 2 above a diffuse
 * plane of albedo 1/2, out of view), sampled through its cone: each pixel against the
 * closed form albedo L (r / d)^2 cos(theta) (the whole sphere above the
 * horizon) integrated over its footprint, to 0.5 %; and the cone's density
 * against the one a light sample reports. */
START_TEST(sphere_light_exact)
{
    static const char json[] =
        "{\"camera\": {\"position\": [0, 0, 5], \"look_at\": [0, 0, 0], \"fov\": 20, \"width\": "
        "6, \"height\": 6},"
        " \"materials\": {\"w\": {\"type\": \"diffuse\", \"albedo\": [0.5, 0.5, 0.5]}, \"l\": "
        "{\"type\": \"emitter\", \"radiance\": [1, 1, 1]}},"
        " \"shapes\": [{\"type\": \"quad\", \"material\": \"w\", \"vertices\": [[-4, -4, 0], [4, "
        "-4, 0], [4, 4, 0], [-4, 4, 0]]}, {\"type\": \"sphere\", \"material\": \"l\", \"center\": "
        "[0, 2.5, 2], \"radius\": 0.5, \"subdivisions\": 6}]}";
    scene_t *s = load_text(json);
    ck_assert_uint_eq(s->sphere_count, 1);
    ck_assert(fabsf(s->spheres[0].pick - 1.0f) < 1e-5f && s->spheres[0].cdf_lo == 0.0);
    /* the density a sample reports is the cone's */
    vec3_t p = vec3_make(0.3f, -0.2f, 0.0f);
    for (int i = 0; i < 64; i++) {
        vec3_t q, nl;
        float area_pdf;
        uint32_t lt;
        vec3_t target;
        ck_assert(lights_sample_from(s, p, (i + 0.5) / 64, (float)((i * 37 % 64) + 0.5f) / 64, &q,
                                     &nl, &area_pdf, &lt, &target));
        vec3_t to = vec3_sub(q, p);
        float d2 = vec3_dot(to, to), cos_l = -vec3_dot(nl, vec3_scale(to, 1 / sqrtf(d2)));
        float solid = area_pdf * d2 / cos_l, want = lights_hit_pdf(s, lt, p, sqrtf(d2), cos_l);
        ck_assert_msg(fabsf(solid / want - 1) < 1e-3f, "sample %d: %g against %g", i, solid, want);
        ck_assert(fabsf(vec3_length(vec3_sub(q, vec3_make(0, 2.5f, 2))) - 0.5f) < 1e-5f);
    }
    film_t *f = render_sampler(s, 9, SCENE_INTEGRATOR_PATH, RNG_SAMPLER_SOBOL, 1024, 2, 16);
    double half = 5 * tan(10 * M_PI / 180);
    for (uint32_t px = 0; px < 36; px++) {
        double rgb[3], want = 0;
        film_mean(f, px, rgb);
        /* row 0 at the top of the image: +y (the camera's up) */
        double x0 = -half + 2 * half * (px % 6) / 6, y0 = half - 2 * half * (px / 6 + 1) / 6;
        for (int a = 0; a < 32; a++)
            for (int b = 0; b < 32; b++) {
                double x = x0 + 2 * half / 6 * (a + 0.5) / 32;
                double y = y0 + 2 * half / 6 * (b + 0.5) / 32;
                double d2 = x * x + (y - 2.5) * (y - 2.5) + 4, cos_t = 2 / sqrt(d2);
                want += 0.5 * 0.25 / d2 * cos_t / 1024;
            }
        ck_assert_msg(fabs(rgb[0] / want - 1) < 5e-3, "pixel %u: %g, want %g", px, rgb[0], want);
    }
    film_destroy(&f);
    scene_destroy(&s);
}
END_TEST

/* A shadow ray toward an emitting sphere stops in the sphere's clear ball
 * (scene_sphere_t.clear_radius): the ball reaches to the nearest other
 * triangle (at most two radii, none when that triangle is nearer than
 * the sphere's surface), the ray's end lies on the segment toward the
 * point sampled, inside the ball and outside the sphere, and the test
 * gives the answer the whole segment gives, an occluder inside two radii
 * (a small quad under the sphere) included. */
START_TEST(sphere_shadow_stops_in_clear_ball)
{
    /* the floor 2 below the sphere's centre, a small quad 0.65 below it
     * (a ball of two radii would end the rays above it) */
    const char *fmt =
        "{\"camera\": {\"position\": [0, 0, 5], \"look_at\": [0, 0, 0], \"fov\": 20, "
        "\"width\": 6, \"height\": 6}, \"materials\": {\"w\": {\"type\": \"diffuse\", "
        "\"albedo\": [0.5, 0.5, 0.5]}, \"l\": {\"type\": \"emitter\", \"radiance\": [1, 1, "
        "1]}}, \"shapes\": [{\"type\": \"quad\", \"material\": \"w\", \"vertices\": [[-4, "
        "-4, 0], [4, -4, 0], [4, 4, 0], [-4, 4, 0]]}, {\"type\": \"quad\", \"material\": "
        "\"w\", \"vertices\": [[-0.3, 2.2, %g], [0.3, 2.2, %g], [0.3, 2.8, %g], [-0.3, 2.8, "
        "%g]]}, {\"type\": \"sphere\", \"material\": \"l\", \"center\": [0, 2.5, 2], "
        "\"radius\": 0.5, \"subdivisions\": 4}]}";
    /* the small quad's height: 1.35 (inside two radii), -1 (out of the
     * way: the floor bounds the ball), 1.7 (inside the sphere's radius:
     * no ball) */
    const double height[3] = {1.35, -1.0, 1.7};
    const float want_clear[3] = {0.65f, 1.0f, 0.0f};
    tracer_device_t *dev = NULL;
    char err[256], json[2048];
    ck_assert(tracer_device_new(&dev, err, sizeof err) == 0);
    for (int c = 0; c < 3; c++) {
        snprintf(json, sizeof json, fmt, height[c], height[c], height[c], height[c]);
        scene_t *s = load_text(json);
        ck_assert_uint_eq(s->sphere_count, 1);
        const scene_sphere_t *sp = &s->spheres[0];
        ck_assert_msg(fabsf(sp->clear_radius - want_clear[c]) <= 2e-3f * (want_clear[c] + 1e-3f),
                      "case %d: clear radius %g, want about %g", c, sp->clear_radius,
                      want_clear[c]);
        ck_assert(sp->clear_radius <= want_clear[c]);
        tracer_t *t = NULL;
        ck_assert_msg(tracer_new(dev, s, &t, err, sizeof err) == 0, "%s", err);
        size_t occluded = 0, shortened = 0, n = 0;
        for (int i = 0; i < 400; i++) {
            /* floor points around the sphere's foot */
            vec3_t p = vec3_make(-1.5f + 3.0f * (float)(i % 20) / 19,
                                 1.0f + 3.0f * (float)(i / 20) / 19, 0.0f);
            vec3_t q, nl, target;
            float pdf;
            uint32_t lt;
            if (!lights_sample_from(s, p, (i * 0.618034) - floor(i * 0.618034), (float)(i % 7) / 7,
                                    &q, &nl, &pdf, &lt, &target))
                continue;
            n++;
            vec3_t lifted = vec3_offset_ray_origin(q, nl);
            vec3_t from = vec3_offset_ray_origin(p, vec3_make(0, 0, 1));
            if (memcmp(&target, &lifted, sizeof target) != 0) {
                shortened++;
                float rc = vec3_length(vec3_sub(target, sp->center));
                ck_assert_msg(rc > sp->radius && rc < sp->clear_radius,
                              "sample %d: end %g from the centre", i, rc);
                /* on the segment toward q */
                vec3_t a = vec3_sub(target, p), b = vec3_sub(q, p);
                ck_assert(vec3_length(vec3_cross(a, b)) <= 1e-5f * vec3_length(a) * vec3_length(b));
                ck_assert(vec3_dot(a, b) > 0 && vec3_length(a) < vec3_length(b));
            }
            int whole = tracer_unoccluded(t, from, vec3_sub(lifted, from));
            int stopped = tracer_unoccluded(t, from, vec3_sub(target, from));
            ck_assert_msg(whole == stopped, "case %d sample %d: %d against %d", c, i, stopped,
                          whole);
            occluded += !whole;
        }
        ck_assert_uint_gt(n, 300);
        if (c < 2)
            ck_assert_uint_eq(shortened, n);
        else
            ck_assert_uint_eq(shortened, 0);
        if (c == 0)
            ck_assert_uint_gt(occluded, 10);
        tracer_destroy(&t);
        scene_destroy(&s);
    }
    tracer_device_destroy(&dev);
}
END_TEST

/* With more emitting spheres than lights_sample_from finds by their CDF
 * ranges (LIGHTS_SPHERE_SCAN) and an emitting quad between them, every
 * light sample lands on the light the search of all triangles picks: the
 * same sphere (whose cone then gives the point) or the same triangle and
 * point, over 20,000 numbers and at each range's edges. */
START_TEST(sphere_lights_found_as_searched)
{
    char json[4096];
    int at = snprintf(json, sizeof json,
                      "{\"camera\": {\"position\": [0, 0, 30], \"look_at\": [0, 0, 0], \"fov\": "
                      "20, \"width\": 4, \"height\": 4}, \"materials\": {\"w\": {\"type\": "
                      "\"diffuse\", \"albedo\": [0.5, 0.5, 0.5]}, \"q\": {\"type\": "
                      "\"emitter\", \"radiance\": [2, 2, 2]}");
    for (int k = 0; k < LIGHTS_SPHERE_SCAN + 3; k++)
        at += snprintf(json + at, sizeof json - (size_t)at,
                       ", \"l%d\": {\"type\": \"emitter\", \"radiance\": [%d, 1, 1]}", k, k + 1);
    at += snprintf(json + at, sizeof json - (size_t)at,
                   "}, \"shapes\": [{\"type\": \"quad\", \"material\": \"w\", \"vertices\": "
                   "[[-40, -40, 0], [40, -40, 0], [40, 40, 0], [-40, 40, 0]]}");
    for (int k = 0; k < LIGHTS_SPHERE_SCAN + 3; k++) {
        at += snprintf(json + at, sizeof json - (size_t)at,
                       ", {\"type\": \"sphere\", \"material\": \"l%d\", \"center\": [%d, 3, 4], "
                       "\"radius\": %g, \"subdivisions\": 2}",
                       k, 3 * k - 15, 0.2 + 0.1 * k);
        if (k == 4)
            at += snprintf(json + at, sizeof json - (size_t)at,
                           ", {\"type\": \"quad\", \"material\": \"q\", \"vertices\": [[-1, "
                           "-1, 6], [-1, 1, 6], [1, 1, 6], [1, -1, 6]]}");
    }
    snprintf(json + at, sizeof json - (size_t)at, "]}");
    scene_t *s = load_text(json);
    ck_assert_uint_eq(s->sphere_count, LIGHTS_SPHERE_SCAN + 3);
    const vec3_t p = vec3_make(0.5f, -0.25f, 0.0f);
    uint64_t x = 99;
    size_t spheres = 0, quads = 0;
    for (int i = 0; i < 20000 + 4 * (int)s->sphere_count; i++) {
        double u;
        if (i < 4 * (int)s->sphere_count) { /* a range's edges */
            const scene_sphere_t *sp = &s->spheres[i / 4];
            double e = i % 2 ? sp->cdf_hi : sp->cdf_lo;
            u = i % 4 < 2 ? e : nextafter(e, 0.0);
            if (!(u >= 0.0 && u < 1.0))
                continue;
        } else {
            x = x * 6364136223846793005ULL + 1442695040888963407ULL;
            u = (double)(x >> 11) * 0x1p-53;
        }
        const float u2 = (float)(i % 97) / 97.0f;
        const size_t want = lights_cdf_search(s->light_cdf, s->light_count, u);
        const uint32_t want_tri = s->light_tris[want];
        vec3_t q, nl, target;
        float pdf;
        uint32_t lt;
        int ok = lights_sample_from(s, p, u, u2, &q, &nl, &pdf, &lt, &target);
        if (s->tri_sphere[want_tri] >= 0) {
            ck_assert_int_eq(s->tri_sphere[lt], s->tri_sphere[want_tri]);
            ck_assert_uint_eq(s->tri_material[lt], s->tri_material[want_tri]);
            spheres++;
        } else {
            ck_assert(ok);
            ck_assert_uint_eq(lt, want_tri);
            vec3_t wq = lights_point_on(s, want, u, u2);
            ck_assert(memcmp(&q, &wq, sizeof q) == 0);
            quads++;
        }
    }
    ck_assert_uint_gt(spheres, 1000);
    ck_assert_uint_gt(quads, 100);
    scene_destroy(&s);
}
END_TEST

/* hide_emitters (Mitsuba's): camera rays pass through an emitting quad
 * (seen from its black back) to the plane it lights; rays that never meet
 * it draw the same bits either way. */
START_TEST(hide_emitters_passes_through)
{
    static const char fmt[] =
        "{\"camera\": {\"position\": [0, 0, 5], \"look_at\": [0, 0, 0], \"fov\": 40, \"width\": 8, "
        "\"height\": 8}, \"render\": {\"hide_emitters\": %s},"
        " \"materials\": {\"w\": {\"type\": \"diffuse\", \"albedo\": [0.5, 0.5, 0.5]}, \"l\": "
        "{\"type\": \"emitter\", \"radiance\": [5, 5, 5]}},"
        " \"shapes\": [{\"type\": \"quad\", \"material\": \"w\", \"vertices\": [[-4, -4, 0], [4, "
        "-4, 0], [4, 4, 0], [-4, 4, 0]]}, {\"type\": \"quad\", \"material\": \"l\", \"vertices\": "
        "[[-0.4, -0.4, 1], [-0.4, 0.4, 1], [0.4, 0.4, 1], [0.4, -0.4, 1]]}]}";
    char json[2048];
    film_t *f[2];
    for (int hide = 0; hide < 2; hide++) {
        snprintf(json, sizeof json, fmt, hide ? "true" : "false");
        scene_t *s = load_text(json);
        ck_assert_int_eq(s->hide_emitters, hide);
        f[hide] = render_sampler(s, 4, SCENE_INTEGRATOR_PATH, RNG_SAMPLER_SOBOL, 64, 1, 16);
        scene_destroy(&s);
    }
    double centre[2][3], corner[2][3];
    for (int hide = 0; hide < 2; hide++) {
        film_mean(f[hide], 4 * 8 + 4, centre[hide]);
        film_mean(f[hide], 0, corner[hide]);
    }
    /* the quad's back is black; behind it, the plane it lights */
    ck_assert(centre[0][0] == 0 && centre[1][0] > 0.1);
    ck_assert(corner[0][0] > 0 && corner[0][0] == corner[1][0]);
    film_destroy(&f[0]);
    film_destroy(&f[1]);
}
END_TEST

static Suite *tracer_suite(void)
{
    Suite *s = suite_create("tracer");
    TCase *tc = tcase_create("physics");
    tcase_set_timeout(tc, 600);
    tcase_add_test(tc, test_furnace_path);
    tcase_add_test(tc, test_every_shipped_scene);
    tcase_add_test(tc, test_furnace_path_bright);
    tcase_add_test(tc, test_furnace_naive);
    tcase_add_test(tc, delta_lights_exact);
    tcase_add_test(tc, spot_falloff);
    tcase_add_test(tc, sphere_light_exact);
    tcase_add_test(tc, sphere_lights_found_as_searched);
    tcase_add_test(tc, sphere_shadow_stops_in_clear_ball);
    tcase_add_test(tc, hide_emitters_passes_through);
    tcase_add_test(tc, test_furnace_coloured_albedo);
    tcase_add_test(tc, test_glass_furnace);
    tcase_add_test(tc, test_mirror_furnace);
    tcase_add_test(tc, test_roulette_undoes_radiance_compression);
    tcase_add_test(tc, test_roulette_variance_inside_glass);
    tcase_add_test(tc, test_roulette_threshold_spares_paths);
    tcase_add_test(tc, test_glass_slab_furnace);
    tcase_add_test(tc, test_form_factor_formula);
    tcase_add_test(tc, test_direct_light_path);
    tcase_add_test(tc, test_direct_light_naive);
    tcase_add_test(tc, test_light_after_specular_weighs_one);
    tcase_add_test(tc, test_light_selection_matches_area_pdf);
    tcase_add_test(tc, test_path_and_naive_agree_cornell);
    tcase_add_test(tc, test_cornell_red_wall_on_left);
    suite_add_tcase(s, tc);
    TCase *det = tcase_create("determinism");
    tcase_set_timeout(det, 600);
    tcase_add_test(det, test_deterministic_across_threads);
    tcase_add_test(det, test_tasks_independent_of_batching);
    tcase_add_test(det, test_sobol_deterministic_and_agrees);
    tcase_add_loop_test(det, test_pvar_matches_definition, 0, 2);
    suite_add_tcase(s, det);
    /* Its own case, out of the ThreadSanitizer run (Makefile TSAN_RUN): it
     * traces on one thread, and its Embree builds leave TBB's worker
     * threads, uninstrumented, racing the process's exit. */
    TCase *engines = tcase_create("engines");
    tcase_set_timeout(engines, 600);
    tcase_add_test(engines, test_engines_agree);
    suite_add_tcase(s, engines);
    TCase *hard = tcase_create("hard cases");
    tcase_set_timeout(hard, 600);
    tcase_add_test(hard, test_cornell_any_scale);
    tcase_add_test(hard, test_grazing_camera);
    tcase_add_test(hard, test_slivers_and_degenerates);
    tcase_add_test(hard, test_tiny_bright_light);
    tcase_add_test(hard, test_glass_caustic);
    tcase_add_test(hard, test_million_constant_samples);
    tcase_add_test(hard, test_closed_cube_no_leak);
    tcase_add_test(hard, test_trilist_and_embree_agree_cornell);
    tcase_add_test(hard, test_isa_same_bits);
    tcase_add_test(hard, test_packets_match_single_rays);
    tcase_add_test(hard, test_denormals_flushed_while_tracing);
    suite_add_tcase(s, hard);
    return s;
}

int main(void)
{
    SRunner *sr = srunner_create(tracer_suite());
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed ? 1 : 0;
}
