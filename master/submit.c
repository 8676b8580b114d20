/* submit.c - a submit request turned into a job (master_priv.h), in steps:
 * the bundle, the scene, the settings, the scheduler, the reference, the
 * hash. A bad submission fails here, at the client, and never reaches a
 * worker. A stored submission (persist.c) goes through the same steps, so a
 * recovered job is exactly the job that was submitted. */
#include <stdlib.h>
#include <string.h>

#include "master_priv.h"
#include "scene.h"
#include "settings.h"

int submit_name_ok(const char *name)
{
    size_t n = strlen(name);
    return n >= 1 && n <= PROTO_MAX_NAME && name[0] != '.' &&
           strspn(name, "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789._-") == n;
}

/* Sizes, before anything is copied: the bundle as a worker will receive it
 * (the encoder's own limit) and the master's --max-bundle-mib. */
static int submit_sizes(const cJSON *meshes, const submit_frame_t *frames, int mesh_count,
                        const submit_limits_t *limits, char *err, size_t errlen)
{
    proto_msg_t bundle = {.h.type = PROTO_SCENE_BUNDLE}, *msg = &bundle;
    proto_mesh_file_t *files = calloc(PROTO_MAX_MESHES, sizeof *files);
    if (!files) {
        snprintf(err, errlen, "out of memory");
        return -1;
    }
    msg->u.bundle.meshes = files;
    msg->u.bundle.json = frames[0].data;
    msg->u.bundle.json_size = frames[0].size > UINT32_MAX ? UINT32_MAX : (uint32_t)frames[0].size;
    msg->u.bundle.mesh_count = (uint32_t)mesh_count;
    uint64_t total = frames[0].size;
    int i = 0;
    for (const cJSON *it = meshes ? meshes->child : NULL; it && i < mesh_count;
         it = it->next, i++) {
        total += frames[1 + i].size;
        if (cJSON_IsString(it))
            snprintf(files[i].name, sizeof files[i].name, "%s", it->valuestring);
        files[i].size = frames[1 + i].size > UINT32_MAX ? UINT32_MAX : (uint32_t)frames[1 + i].size;
    }
    size_t payload = proto_payload_size(msg);
    free(files);
    if (limits && limits->max_bundle_bytes && total > limits->max_bundle_bytes) {
        snprintf(err, errlen,
                 "the scene and its meshes are %.1f MiB; this master takes at most %.0f MiB "
                 "(--max-bundle-mib)",
                 total / 1048576.0, limits->max_bundle_bytes / 1048576.0);
        return -1;
    }
    if (payload > PROTO_MAX_BUNDLE) {
        snprintf(
            err, errlen,
            "the scene and its meshes make a %.1f MiB bundle; the protocol carries at most %u MiB",
            payload / 1048576.0, PROTO_MAX_BUNDLE >> 20);
        return -1;
    }
    return 0;
}

/* The image size and spp the job will have, from the scene JSON and the
 * request, checked against the caps before the scene is loaded. */
static int submit_caps(const cJSON *req, const submit_frame_t *json, const submit_limits_t *limits,
                       char *err, size_t errlen)
{
    if (!limits)
        return 0;
    cJSON *scene = cJSON_ParseWithLength(json->data, json->size);
    const cJSON *cam = cJSON_GetObjectItemCaseSensitive(scene, "camera");
    const cJSON *render = cJSON_GetObjectItemCaseSensitive(scene, "render");
    const cJSON *w = cJSON_GetObjectItemCaseSensitive(cam, "width"),
                *h = cJSON_GetObjectItemCaseSensitive(cam, "height");
    const cJSON *spp = cJSON_GetObjectItemCaseSensitive(req, "spp");
    if (!spp)
        spp = cJSON_GetObjectItemCaseSensitive(render, "spp");
    double pixels = cJSON_IsNumber(w) && cJSON_IsNumber(h) ? w->valuedouble * h->valuedouble : 0;
    double n = cJSON_IsNumber(spp) ? spp->valuedouble : 0;
    cJSON_Delete(scene);
    /* a malformed scene is left to the full load, which names what is wrong */
    if (limits->max_pixels && pixels > (double)limits->max_pixels) {
        snprintf(err, errlen,
                 "the image has %.0f pixels; this master takes at most %llu (--max-pixels)", pixels,
                 (unsigned long long)limits->max_pixels);
        return -1;
    }
    if (limits->max_spp && n > limits->max_spp) {
        snprintf(err, errlen, "%.0f samples per pixel; this master takes at most %u (--max-spp)", n,
                 limits->max_spp);
        return -1;
    }
    return 0;
}

/* The mesh files: names checked, data copied. */
static int submit_bundle(job_t *j, const cJSON *meshes, const submit_frame_t *frames,
                         int mesh_count, scene_blob_t *blobs, char *err, size_t errlen)
{
    j->mesh_count = (uint32_t)mesh_count;
    j->mesh_names = calloc((size_t)mesh_count + 1, sizeof *j->mesh_names);
    j->mesh_data = calloc((size_t)mesh_count + 1, sizeof *j->mesh_data);
    j->mesh_sizes = calloc((size_t)mesh_count + 1, sizeof *j->mesh_sizes);
    if (!j->mesh_names || !j->mesh_data || !j->mesh_sizes) {
        snprintf(err, errlen, "out of memory");
        return -1;
    }
    int i = 0;
    for (const cJSON *it = meshes ? meshes->child : NULL; it; it = it->next, i++) {
        if (!cJSON_IsString(it) || !submit_name_ok(it->valuestring)) {
            snprintf(
                err, errlen,
                "meshes[%d]: a name of 1 to %d characters from A-Z a-z 0-9 . _ -, not starting "
                "with '.'",
                i, PROTO_MAX_NAME);
            return -1;
        }
        size_t sz = frames[i].size;
        if (sz > PROTO_MAX_MESH_BYTES) {
            snprintf(err, errlen, "meshes[%d]: %zu bytes is over the limit", i, sz);
            return -1;
        }
        snprintf(j->mesh_names[i], sizeof j->mesh_names[i], "%s", it->valuestring);
        for (int k = 0; k < i; k++)
            if (strcmp(j->mesh_names[k], j->mesh_names[i]) == 0) {
                snprintf(err, errlen, "meshes[%d]: \"%s\" given twice", i, j->mesh_names[i]);
                return -1;
            }
        j->mesh_data[i] = malloc(sz ? sz : 1);
        if (!j->mesh_data[i]) {
            snprintf(err, errlen, "out of memory");
            return -1;
        }
        memcpy(j->mesh_data[i], frames[i].data, sz);
        j->mesh_sizes[i] = (uint32_t)sz;
        blobs[i].name = j->mesh_names[i];
        blobs[i].data = j->mesh_data[i];
        blobs[i].size = sz;
    }
    return 0;
}

/* The scene, loaded from the bundle as a worker will load it: its size and
 * render defaults. */
static int submit_scene(job_t *j, const submit_frame_t *json, const scene_blob_t *blobs, char *err,
                        size_t errlen)
{
    j->json_size = json->size;
    if (j->json_size > PROTO_MAX_SCENE_JSON) {
        snprintf(err, errlen, "scene JSON too large (%zu bytes)", j->json_size);
        return -1;
    }
    j->json = malloc(j->json_size + 1);
    if (!j->json) {
        snprintf(err, errlen, "out of memory");
        return -1;
    }
    memcpy(j->json, json->data, j->json_size);
    j->json[j->json_size] = '\0';
    scene_t *scene = NULL;
    char serr[VB_ERR_LEN - 16];
    if (scene_check_bundle(j->json, j->json_size, j->name, blobs, j->mesh_count, &scene, serr,
                           sizeof serr) < 0) {
        snprintf(err, errlen, "bad scene: %s", serr);
        return -1;
    }
    j->width = (uint32_t)scene->camera.width;
    j->height = (uint32_t)scene->camera.height;
    j->spp = scene->spp;
    j->tracer.seed = scene->seed;
    j->tracer.integrator = scene->integrator;
    j->tracer.max_depth = scene->max_depth;
    scene_destroy(&scene);
    return 0;
}

/* The job's settings over the scene's defaults (checked against the
 * settings table, settings.h), and the scheduler. `recovered`: the request
 * is one this or an older master stored (persist.c); one without
 * "replicates" is from before replicates, whose jobs had none. */
static int submit_settings(job_t *j, const cJSON *req, int recovered, char *err, size_t errlen)
{
    if (settings_check_request(req, err, errlen) < 0)
        return -1;
    /* seed: a JSON number holds integers exactly up to 2^53 only (the table's limit) */
    j->spp = (uint32_t)settings_number(req, "spp", j->spp);
    j->granularity = (uint32_t)settings_number(req, "granularity", JOB_DEFAULT_GRANULARITY);
    j->tracer.seed = (uint64_t)settings_number(req, "seed", (double)j->tracer.seed);
    j->tracer.max_depth = (uint32_t)settings_number(req, "max_depth", j->tracer.max_depth);
    j->target_error = settings_number(req, "target_error", JOB_DEFAULT_TARGET_ERROR);
    j->time_limit = settings_number(req, "time_limit", JOB_DEFAULT_TIME_LIMIT);
    /* the names are the table's choices, which these know (test_settings) */
    j->adaptive = (sched_adaptive_t)sched_adaptive_from_name(
        settings_string(req, "adaptive", JOB_DEFAULT_ADAPTIVE));
    j->tracer.integrator = (scene_integrator_t)scene_integrator_from_name(
        settings_string(req, "integrator", scene_integrator_name(j->tracer.integrator)));
    j->tracer.sampler = (rng_sampler_t)tracer_sampler_from_name(
        settings_string(req, "sampler", JOB_DEFAULT_SAMPLER));
    /* independent samples need no replicates: their own variance is the error */
    const uint32_t replicates =
        j->tracer.sampler == RNG_SAMPLER_INDEPENDENT
            ? 1
            : (uint32_t)settings_number(req, "replicates", recovered ? 1 : JOB_DEFAULT_REPLICATES);
    const char *flags = settings_string(req, "flags", NULL);
    if (flags && !(j->flags = strdup(flags))) {
        snprintf(err, errlen, "out of memory");
        return -1;
    }
    j->sched_cfg = (sched_config_t){
        .width = j->width,
        .height = j->height,
        .spp = j->spp,
        .granularity = j->granularity,
        .adaptive = j->adaptive,
        /* absent: UINT32_MAX, the scheduler's "half" */
        .uniform_layers = (uint32_t)settings_number(req, "uniform_layers", UINT32_MAX),
        .flags = j->flags,
        .random_selection = settings_switch(req, "random_selection"),
        .dilate = settings_switch(req, "dilate"),
        .seed = j->tracer.seed,
        .target_error = j->target_error,
        .confidence = settings_number(req, "confidence", JOB_DEFAULT_CONFIDENCE),
        .target_share = settings_number(req, "target_share", JOB_DEFAULT_TARGET_SHARE),
        .replicates = replicates};
    char schederr[VB_ERR_LEN - 32];
    j->sched = sched_new(&j->sched_cfg, schederr, sizeof schederr);
    if (!j->sched) {
        snprintf(err, errlen, "bad settings: %s", schederr);
        return -1;
    }
    size_t cells = (size_t)sched_layer_count(j->sched) * sched_range_count(j->sched);
    j->attempt = calloc(cells, sizeof *j->attempt);
    j->holder = calloc(cells, sizeof *j->holder);
    j->sent_ms = calloc(cells, sizeof *j->sent_ms);
    j->leases = lease_queue_new();
    j->epoch = master_now();
    if (!j->attempt || !j->holder || !j->sent_ms || !j->leases) {
        snprintf(err, errlen, "out of memory");
        return -1;
    }
    return 0;
}

/* The reference: three float32 planes R, G, B of the image's size. */
static int submit_reference(job_t *j, const submit_frame_t *frames, char *err, size_t errlen)
{
    size_t plane = (size_t)j->width * j->height * sizeof(float);
    for (int c = 0; c < 3; c++) {
        if (frames[c].size != plane) {
            snprintf(err, errlen,
                     "reference: channel %d has %zu bytes, a %ux%u image needs %zu (another size?)",
                     c, frames[c].size, j->width, j->height, plane);
            return -1;
        }
        j->ref[c] = malloc(plane);
        j->cur[c] = malloc(plane);
        if (!j->ref[c] || !j->cur[c]) {
            snprintf(err, errlen, "out of memory");
            return -1;
        }
        memcpy(j->ref[c], frames[c].data, plane);
    }
    return 0;
}

/* The bundle's content hash: what workers cache scenes by. */
static int submit_hash(job_t *j, char *err, size_t errlen)
{
    proto_bundle_t bundle = {0}, *view = &bundle;
    proto_mesh_file_t *meshes = calloc(PROTO_MAX_MESHES, sizeof *meshes);
    if (!meshes) {
        snprintf(err, errlen, "out of memory");
        return -1;
    }
    view->meshes = meshes;
    view->json = j->json;
    view->json_size = (uint32_t)j->json_size;
    view->mesh_count = j->mesh_count;
    for (uint32_t k = 0; k < j->mesh_count; k++) {
        memcpy(meshes[k].name, j->mesh_names[k], sizeof meshes[k].name);
        meshes[k].data = j->mesh_data[k];
        meshes[k].size = j->mesh_sizes[k];
    }
    proto_bundle_hash(view, j->hash);
    free(meshes);
    return 0;
}

static int submit_request_id(job_t *j, const cJSON *req, char *err, size_t errlen)
{
    const cJSON *rid = cJSON_GetObjectItemCaseSensitive(req, "request_id");
    if (!rid)
        return 0;
    const char *v = cJSON_IsString(rid) ? rid->valuestring : NULL;
    size_t n = v ? strlen(v) : 0;
    if (!v || n == 0 || n > MASTER_MAX_REQUEST_ID ||
        strspn(v, "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_-") != n) {
        snprintf(err, errlen, "request_id must be 1 to %d characters from A-Z a-z 0-9 _ -",
                 MASTER_MAX_REQUEST_ID);
        return -1;
    }
    memcpy(j->request_id, v, n + 1);
    return 0;
}

job_t *submit_parse(const cJSON *req, const submit_frame_t *frames, int nframes,
                    const submit_limits_t *limits, char *err, size_t errlen)
{
    if (nframes < 1) {
        snprintf(err, errlen, "submit needs the scene JSON as its second frame");
        return NULL;
    }
    const cJSON *meshes = cJSON_GetObjectItemCaseSensitive(req, "meshes");
    if (meshes && !cJSON_IsArray(meshes)) {
        snprintf(err, errlen, "\"meshes\" must be an array of names");
        return NULL;
    }
    int mesh_count = meshes ? cJSON_GetArraySize(meshes) : 0;
    const cJSON *refspec = cJSON_GetObjectItemCaseSensitive(req, "reference");
    int ref_frames = refspec ? 3 : 0;
    if (mesh_count != nframes - 1 - ref_frames || mesh_count > PROTO_MAX_MESHES) {
        snprintf(err, errlen, "%d mesh names%s but %d frames after the scene", mesh_count,
                 ref_frames ? " and a reference (3 frames)" : "", nframes - 1);
        return NULL;
    }
    if (submit_sizes(meshes, frames, mesh_count, limits, err, errlen) < 0 ||
        submit_caps(req, &frames[0], limits, err, errlen) < 0)
        return NULL;
    job_t *j = calloc(1, sizeof *j);
    if (!j) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    const cJSON *name = cJSON_GetObjectItemCaseSensitive(req, "name");
    snprintf(j->name, sizeof j->name, "%s",
             cJSON_IsString(name) ? name->valuestring : "scene.json");
    scene_blob_t blobs[PROTO_MAX_MESHES];
    if (submit_request_id(j, req, err, errlen) < 0 ||
        submit_bundle(j, meshes, frames + 1, mesh_count, blobs, err, errlen) < 0 ||
        submit_scene(j, &frames[0], blobs, err, errlen) < 0 ||
        submit_settings(j, req, limits == NULL, err, errlen) < 0 ||
        (refspec && submit_reference(j, frames + 1 + mesh_count, err, errlen) < 0) ||
        submit_hash(j, err, errlen) < 0) {
        job_free(j);
        return NULL;
    }
    j->state = JOB_QUEUED;
    return j;
}
