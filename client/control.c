/* control.c - see control.h. */
#include "control.h"

#include <ctype.h>
#include <errno.h>
#include <sodium.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <zmq.h>

#include "frames.h"
#include "handshake.h"
#include "mitsuba.h"
#include "proto.h"

struct control {
    void *ctx;
    void *sock;
    char endpoint[256];
    int timeout_ms;           /* the most a try waits to send and for the reply */
    int lost;                 /* the last request got no answer in time */
    proto_frames_t reply;     /* the last reply, [json][binary...], until drop_extra */
    int curve;                /* the socket is a CURVE client */
    char keys[3][64];         /* public, secret, master: Z85 */
    handshake_monitor_t *mon; /* sock's handshakes */
    int closed_in_row;        /* handshakes closed without a word, in a row */
    int failed;               /* a handshake failed for good: handshake_error says why */
    char handshake_error[768];
};

static double now_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* The most binary parts a reply may carry: a fetched image's channels. */
#define CONTROL_MAX_EXTRA 16

static void drop_extra(control_t *c)
{
    proto_frames_close(&c->reply);
}

/* The binary parts after the reply's JSON. */
static int extra_count(const control_t *c)
{
    return c->reply.count > 1 ? c->reply.count - 1 : 0;
}

static void close_socket(control_t *c)
{
    handshake_monitor_destroy(&c->mon); /* before the socket it watches */
    if (c->sock)
        zmq_close(c->sock);
    c->sock = NULL;
    c->closed_in_row = 0;
    c->failed = 0;
}

static int open_socket(control_t *c, char *err, size_t errlen)
{
    c->sock = zmq_socket(c->ctx, ZMQ_REQ);
    if (!c->sock) {
        snprintf(err, errlen, "cannot create a socket: %s", zmq_strerror(errno));
        return -1;
    }
    int zero = 0;
    zmq_setsockopt(c->sock, ZMQ_LINGER, &zero, sizeof zero);
    if (c->curve &&
        (zmq_setsockopt(c->sock, ZMQ_CURVE_SERVERKEY, c->keys[2], strlen(c->keys[2])) < 0 ||
         zmq_setsockopt(c->sock, ZMQ_CURVE_PUBLICKEY, c->keys[0], strlen(c->keys[0])) < 0 ||
         zmq_setsockopt(c->sock, ZMQ_CURVE_SECRETKEY, c->keys[1], strlen(c->keys[1])) < 0)) {
        snprintf(err, errlen, "cannot set the CURVE keys: %s", zmq_strerror(errno));
        close_socket(c);
        return -1;
    }
    /* watched before it connects, so no handshake goes unseen */
    if (!(c->mon = handshake_monitor_new(c->ctx, c->sock, err, errlen))) {
        close_socket(c);
        return -1;
    }
    if (zmq_connect(c->sock, c->endpoint) < 0) {
        snprintf(err, errlen, "cannot connect to %s: %s", c->endpoint, zmq_strerror(errno));
        close_socket(c);
        return -1;
    }
    return 0;
}

/* Reads the handshake events so far: 1 when one failed for good. A refused
 * key or CURVE on one side only ends the connection (ZeroMQ does not try
 * again); a handshake closed without a word twice in a row is a wrong
 * master key (once could be a master going down mid-handshake). */
static int handshake_failed(control_t *c)
{
    char msg[sizeof c->handshake_error];
    handshake_result_t r;
    while (!c->failed && c->mon &&
           (r = handshake_monitor_read(c->mon, c->endpoint, "client", c->curve, msg, sizeof msg)) !=
               HANDSHAKE_NONE) {
        if (r == HANDSHAKE_OK)
            c->closed_in_row = 0;
        else if (r == HANDSHAKE_LOST)
            continue; /* a master going away: the request's deadline covers it */
        else if (r != HANDSHAKE_CLOSED || ++c->closed_in_row >= 2) {
            c->failed = 1;
            snprintf(c->handshake_error, sizeof c->handshake_error, "%s", msg);
        }
    }
    return c->failed;
}

/* Waits until the socket has events, the deadline passes or a handshake
 * fails: 1, 0 or -1. */
static int wait_socket(control_t *c, short events, double deadline)
{
    for (;;) {
        if (handshake_failed(c))
            return -1;
        double left = deadline - now_seconds();
        if (left <= 0)
            return 0;
        zmq_pollitem_t it[2] = {{c->sock, 0, events, 0},
                                {handshake_monitor_socket(c->mon), 0, ZMQ_POLLIN, 0}};
        int rc = zmq_poll(it, 2, (long)(left * 1000.0) + 1);
        if (rc < 0 && errno != EINTR)
            return 0;
        if (rc > 0 && (it[0].revents & events))
            return 1;
    }
}

control_t *control_new_with_keys(void *zmq_ctx, const char *endpoint, int timeout_ms,
                                 const control_keys_t *keys, char *err, size_t errlen)
{
    control_t *c = calloc(1, sizeof *c);
    if (!c) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    c->ctx = zmq_ctx;
    c->timeout_ms = timeout_ms > 0 ? timeout_ms : 10000;
    snprintf(c->endpoint, sizeof c->endpoint, "%s", endpoint);
    if (keys) {
        const char *k[3] = {keys->public_key, keys->secret_key, keys->master_key};
        for (int i = 0; i < 3; i++)
            if (!k[i] ||
                (size_t)snprintf(c->keys[i], sizeof c->keys[i], "%s", k[i]) >= sizeof c->keys[i]) {
                snprintf(err, errlen,
                         "CURVE needs this client's key pair and the master's public key");
                control_destroy(&c);
                return NULL;
            }
        c->curve = 1;
    }
    if (open_socket(c, err, errlen) < 0) {
        control_destroy(&c);
        return NULL;
    }
    return c;
}

control_t *control_new(void *zmq_ctx, const char *endpoint, int timeout_ms, char *err,
                       size_t errlen)
{
    return control_new_with_keys(zmq_ctx, endpoint, timeout_ms, NULL, err, errlen);
}

void control_destroy(control_t **cp)
{
    if (!cp || !*cp)
        return;
    drop_extra(*cp);
    close_socket(*cp);
    explicit_bzero((*cp)->keys, sizeof(*cp)->keys);
    free(*cp);
    *cp = NULL;
}

/* A REQ socket that missed its reply (or sent part of a request) is
 * stuck: open a new one. A reply to the old one is then dropped. */
static void reopen_socket(control_t *c)
{
    close_socket(c);
    char e2[256];
    open_socket(c, e2, sizeof e2);
}

/* One try: send, then wait up to timeout_ms for the reply. */
static cJSON *request_once(control_t *c, const cJSON *req, const void *const *frames,
                           const size_t *sizes, int nframes, int timeout_ms, char *err,
                           size_t errlen)
{
    drop_extra(c);
    c->lost = 0;
    if (!c->sock && open_socket(c, err, errlen) < 0)
        return NULL;
    /* the send waits too: a REQ socket without a peer may block in it */
    zmq_setsockopt(c->sock, ZMQ_SNDTIMEO, &timeout_ms, sizeof timeout_ms);
    zmq_setsockopt(c->sock, ZMQ_RCVTIMEO, &timeout_ms, sizeof timeout_ms);
    const double deadline = now_seconds() + timeout_ms / 1000.0;
    char *text = cJSON_PrintUnformatted(req);
    if (!text) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    /* a failed handshake ends in silence: watch for it while waiting */
    int ready = wait_socket(c, ZMQ_POLLOUT, deadline);
    if (ready < 0) {
        /* closed, not reopened: a new handshake now would fail the same
         * way (and be logged by the master again); the next request opens
         * a socket */
        snprintf(err, errlen, "%s", c->handshake_error);
        cJSON_free(text);
        close_socket(c);
        return NULL;
    }
    int rc = ready ? zmq_send(c->sock, text, strlen(text), nframes > 0 ? ZMQ_SNDMORE : 0) : -1;
    if (!ready)
        errno = EAGAIN;
    cJSON_free(text);
    if (rc >= 0 && nframes > 0)
        rc = proto_send(c->sock, frames, sizes, (size_t)nframes, 0);
    if (rc < 0) {
        int e = errno;
        if (e == EAGAIN) {
            snprintf(err, errlen, "cannot send to the master at %s within %.1f s (is it running?)",
                     c->endpoint, timeout_ms / 1000.0);
            c->lost = 1;
        } else {
            snprintf(err, errlen, "cannot send to %s: %s", c->endpoint, zmq_strerror(e));
        }
        reopen_socket(c);
        return NULL;
    }
    ready = wait_socket(c, ZMQ_POLLIN, deadline);
    if (ready < 0) {
        snprintf(err, errlen, "%s", c->handshake_error);
        close_socket(c);
        return NULL;
    }
    /* parts past the limit are dropped: fetch_image then finds the
     * channels do not match and says the reply is malformed */
    if (!ready || proto_recv(c->sock, &c->reply, 1 + CONTROL_MAX_EXTRA, SIZE_MAX, ZMQ_DONTWAIT) ==
                      PROTO_RECV_NONE) {
        snprintf(err, errlen, "no answer from the master at %s within %.1f s (is it running?)",
                 c->endpoint, timeout_ms / 1000.0);
        c->lost = 1;
        reopen_socket(c);
        return NULL;
    }
    cJSON *body =
        cJSON_ParseWithLength(zmq_msg_data(&c->reply.part[0]), zmq_msg_size(&c->reply.part[0]));
    if (!body)
        snprintf(err, errlen, "the master's reply is not JSON");
    return body;
}

cJSON *control_request(control_t *c, const cJSON *req, const void *const *frames,
                       const size_t *sizes, int nframes, char *err, size_t errlen)
{
    return request_once(c, req, frames, sizes, nframes, c->timeout_ms, err, errlen);
}

int control_frame_count(const control_t *c)
{
    return extra_count(c);
}

const void *control_frame(const control_t *c, int i, size_t *size)
{
    if (i < 0 || i >= extra_count(c)) {
        *size = 0;
        return NULL;
    }
    /* zmq_msg_data and zmq_msg_size do not change the message */
    zmq_msg_t *m = (zmq_msg_t *)&c->reply.part[1 + i];
    *size = zmq_msg_size(m);
    return zmq_msg_data(m);
}

int control_lost(const control_t *c)
{
    return c->lost;
}

static void sleep_seconds(double s)
{
    if (!(s > 0))
        return;
    struct timespec ts = {(time_t)s, (long)((s - (double)(time_t)s) * 1e9)};
    while (nanosleep(&ts, &ts) < 0 && errno == EINTR) {
    }
}

cJSON *control_request_retry(control_t *c, const cJSON *req, const void *const *frames,
                             const size_t *sizes, int nframes, control_retry_t *retry, char *err,
                             size_t errlen)
{
    if (!retry || !(retry->timeout_s > 0))
        return control_request(c, req, frames, sizes, nframes, err, errlen);
    retry->unreachable = 0;
    const double deadline = now_seconds() + retry->timeout_s;
    /* a lost reply shows only as a timeout: tries short enough that a
     * restart is noticed and several tries fit in timeout_s */
    double per_try = retry->timeout_s / 5;
    if (per_try < 0.5)
        per_try = 0.5;
    if (per_try > c->timeout_ms / 1000.0)
        per_try = c->timeout_ms / 1000.0;
    double backoff = 0.25;
    int told = 0;
    for (;;) {
        double left = deadline - now_seconds();
        if (left <= 0)
            break;
        double t = per_try < left ? per_try : left;
        int ms = (int)(t * 1000.0);
        cJSON *reply = request_once(c, req, frames, sizes, nframes, ms > 0 ? ms : 1, err, errlen);
        if (reply || !c->lost)
            return reply;
        left = deadline - now_seconds();
        if (left <= 0)
            break;
        if (!told && retry->on_outage)
            retry->on_outage(retry->arg, c->endpoint, retry->timeout_s);
        told = 1;
        sleep_seconds(backoff < left ? backoff : left);
        backoff = backoff * 2 < 2.0 ? backoff * 2 : 2.0;
    }
    retry->unreachable = 1;
    snprintf(err, errlen, "master at %s unreachable for %g s", c->endpoint, retry->timeout_s);
    return NULL;
}

/* ---- bundles ------------------------------------------------------------------- */

static unsigned char *read_all(const char *path, size_t *size, char *err, size_t errlen)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        snprintf(err, errlen, "%s: cannot open: %s", path, strerror(errno));
        return NULL;
    }
    unsigned char *buf = NULL;
    long n = -1;
    if (fseek(f, 0, SEEK_END) == 0)
        n = ftell(f);
    if (n < 0 || fseek(f, 0, SEEK_SET) != 0 || (unsigned long)n > PROTO_MAX_MESH_BYTES) {
        snprintf(err, errlen, "%s: cannot read it (not a regular file, or over %u bytes)", path,
                 PROTO_MAX_MESH_BYTES);
        fclose(f);
        return NULL;
    }
    buf = malloc((size_t)n + 1);
    if (!buf || fread(buf, 1, (size_t)n, f) != (size_t)n) {
        snprintf(err, errlen, "%s: cannot read: %s", path, strerror(errno));
        free(buf);
        fclose(f);
        return NULL;
    }
    buf[n] = '\0';
    fclose(f);
    *size = (size_t)n;
    return buf;
}

/* 32 hex digits from 16 random bytes: a submit's request id. Random, not
 * a counter, so two clients (or two runs of one) never share one. */
static int new_request_id(char out[33], char *err, size_t errlen)
{
    if (sodium_init() < 0) {
        snprintf(err, errlen, "cannot make a request id: libsodium failed to start");
        return -1;
    }
    unsigned char bytes[16];
    randombytes_buf(bytes, sizeof bytes);
    sodium_bin2hex(out, 33, bytes, sizeof bytes);
    return 0;
}

/* The frames of a submit request: [0] the scene JSON, then one per mesh
 * file, then the reference's R, G, B planes (borrowed, not freed). */
typedef struct submit_frames {
    void *frames[PROTO_MAX_MESHES + 4];
    size_t sizes[PROTO_MAX_MESHES + 4];
    int count;
    int owned;         /* frames[1..owned-1] are ours to free */
    int json_is_cjson; /* frames[0] came from cJSON_Print (else from read_all) */
} submit_frames_t;

static void submit_frames_free(submit_frames_t *fr)
{
    for (int i = 1; i < fr->owned; i++)
        free(fr->frames[i]);
    if (fr->json_is_cjson)
        cJSON_free(fr->frames[0]);
    else
        free(fr->frames[0]);
}

/* A mesh file's bundle name: meshN plus its extension in lower case (the
 * extension tells OBJ from PLY). */
static void bundle_name(int mesh, const char *file, char *out, size_t len)
{
    const char *ext = strrchr(file, '.');
    char lower[16] = "";
    for (int k = 0; ext && ext[k] && k < 15; k++)
        lower[k] = (char)tolower((unsigned char)ext[k]), lower[k + 1] = '\0';
    snprintf(out, len, "mesh%d%s", mesh, lower);
}

/* Reads every mesh file the scene's shapes name (relative to the scene's
 * folder), adds it as a frame and rewrites its "file" to its bundle name. */
static int bundle_meshes(cJSON *scene, const char *scene_path, cJSON *names, submit_frames_t *fr,
                         char *err, size_t errlen)
{
    char dir[4096];
    snprintf(dir, sizeof dir, "%s", scene_path);
    char *slash = strrchr(dir, '/');
    if (slash)
        *slash = '\0';
    else
        snprintf(dir, sizeof dir, ".");
    const cJSON *shapes = scene ? cJSON_GetObjectItemCaseSensitive(scene, "shapes") : NULL;
    if (!cJSON_IsArray(shapes))
        shapes = NULL;
    const cJSON *sh;
    int mesh = 0;
    /* the environment map and bitmap textures travel as the meshes do */
    cJSON *env = scene ? cJSON_GetObjectItemCaseSensitive(scene, "environment") : NULL;
    cJSON *env_map = cJSON_GetObjectItemCaseSensitive(env, "map");
    int env_done = !cJSON_IsString(env_map);
    const cJSON *mats = scene ? cJSON_GetObjectItemCaseSensitive(scene, "materials") : NULL;
    const cJSON *mat = cJSON_IsObject(mats) ? mats->child : NULL;
    for (sh = shapes ? shapes->child : NULL;; sh = sh ? sh->next : NULL) {
        cJSON *file;
        if (sh) {
            file = cJSON_GetObjectItemCaseSensitive(sh, "file");
            const cJSON *type = cJSON_GetObjectItemCaseSensitive(sh, "type");
            if (!cJSON_IsString(type) || strcmp(type->valuestring, "mesh") != 0 ||
                !cJSON_IsString(file))
                continue;
        } else if (!env_done) {
            file = env_map;
            env_done = 1;
        } else if (mat) {
            const cJSON *albedo = cJSON_GetObjectItemCaseSensitive(mat, "albedo");
            const cJSON *type = cJSON_GetObjectItemCaseSensitive(albedo, "type");
            file = cJSON_GetObjectItemCaseSensitive(albedo, "file");
            mat = mat->next;
            if (!cJSON_IsString(type) || strcmp(type->valuestring, "bitmap") != 0 ||
                !cJSON_IsString(file))
                continue;
        } else {
            break;
        }
        if (mesh == PROTO_MAX_MESHES) {
            snprintf(err, errlen, "%s: more than %d mesh files", scene_path, PROTO_MAX_MESHES);
            return -1;
        }
        char path[8192], merr[1024], name[64];
        if (file->valuestring[0] == '/')
            snprintf(path, sizeof path, "%s", file->valuestring);
        else
            snprintf(path, sizeof path, "%s/%s", dir, file->valuestring);
        unsigned char *data = read_all(path, &fr->sizes[fr->count], merr, sizeof merr);
        if (!data) {
            snprintf(err, errlen, "%s: a file it names: %s", scene_path, merr);
            return -1;
        }
        fr->frames[fr->count++] = data;
        fr->owned = fr->count;
        bundle_name(mesh++, file->valuestring, name, sizeof name);
        cJSON_SetValuestring(file, name);
        cJSON_AddItemToArray(names, cJSON_CreateString(name));
    }
    return 0;
}

/* Frame 0: the rewritten scene, or the file's text as it is when it does
 * not parse (the master's own error then names the line). */
static int scene_frame(const cJSON *scene, const char *scene_path, submit_frames_t *fr, char *err,
                       size_t errlen)
{
    if (scene) {
        fr->frames[0] = cJSON_PrintUnformatted(scene);
        fr->sizes[0] = fr->frames[0] ? strlen(fr->frames[0]) : 0;
        fr->json_is_cjson = 1;
        return 0;
    }
    fr->frames[0] = read_all(scene_path, &fr->sizes[0], err, errlen);
    return fr->frames[0] ? 0 : -1;
}

static int reference_frames(cJSON *req, const image_t *reference, submit_frames_t *fr, char *err,
                            size_t errlen)
{
    const char *names[3] = {"R", "G", "B"};
    cJSON *r = cJSON_AddObjectToObject(req, "reference");
    cJSON_AddNumberToObject(r, "width", reference->width);
    cJSON_AddNumberToObject(r, "height", reference->height);
    for (int k = 0; k < 3; k++) {
        float *plane = image_channel(reference, names[k]);
        if (!plane) {
            snprintf(err, errlen, "the reference has no channel %s", names[k]);
            return -1;
        }
        fr->frames[fr->count] = plane;
        fr->sizes[fr->count++] = (size_t)reference->width * reference->height * sizeof(float);
    }
    return 0;
}

static unsigned long long reply_job(const cJSON *reply, char *err, size_t errlen)
{
    const cJSON *ok = cJSON_GetObjectItemCaseSensitive(reply, "ok");
    const cJSON *id = cJSON_GetObjectItemCaseSensitive(reply, "job");
    const cJSON *e = cJSON_GetObjectItemCaseSensitive(reply, "error");
    if (cJSON_IsTrue(ok) && cJSON_IsNumber(id))
        return (unsigned long long)id->valuedouble;
    snprintf(err, errlen, "%s", cJSON_IsString(e) ? e->valuestring : "the master refused the job");
    return 0;
}

static cJSON *submit_request(const char *scene_path, const cJSON *settings, const char *request_id)
{
    const char *base = strrchr(scene_path, '/');
    base = base ? base + 1 : scene_path;
    cJSON *req = cJSON_CreateObject();
    cJSON_AddStringToObject(req, "cmd", "submit");
    cJSON_AddStringToObject(req, "name", base);
    /* a retried submit after a lost reply names the job it meant */
    cJSON_AddStringToObject(req, "request_id", request_id);
    cJSON_AddArrayToObject(req, "meshes");
    for (const cJSON *it = settings ? settings->child : NULL; it; it = it->next)
        cJSON_AddItemToObject(req, it->string, cJSON_Duplicate(it, 1));
    return req;
}

cJSON *control_scene_json(const char *path, const control_defines_t *defines, int *raw_ok,
                          char *err, size_t errlen)
{
    *raw_ok = 0;
    if (mitsuba_is_scene_path(path))
        return mitsuba_scene_json(path, defines ? defines->items : NULL,
                                  defines ? defines->count : 0, err, errlen);
    if (defines && defines->count > 0) {
        snprintf(err, errlen, "-D sets a parameter of a Mitsuba scene (.xml), not of %s", path);
        return NULL;
    }
    size_t size = 0;
    unsigned char *text = read_all(path, &size, err, errlen);
    if (!text)
        return NULL;
    cJSON *scene = cJSON_ParseWithLength((const char *)text, size);
    free(text);
    *raw_ok = scene == NULL;
    if (!scene)
        snprintf(err, errlen, "%s: not valid JSON", path);
    return scene;
}

unsigned long long control_submit(control_t *c, const char *scene_path, const cJSON *settings,
                                  const image_t *reference, control_retry_t *retry, char *err,
                                  size_t errlen)
{
    return control_submit_defines(c, scene_path, NULL, settings, reference, retry, err, errlen);
}

unsigned long long control_submit_defines(control_t *c, const char *scene_path,
                                          const control_defines_t *defines, const cJSON *settings,
                                          const image_t *reference, control_retry_t *retry,
                                          char *err, size_t errlen)
{
    char request_id[33];
    if (new_request_id(request_id, err, errlen) < 0)
        return 0;
    /* a JSON scene that does not parse goes as it is: the master says the
     * same with a line number */
    int raw_ok = 0;
    cJSON *scene = control_scene_json(scene_path, defines, &raw_ok, err, errlen);
    if (!scene && !raw_ok)
        return 0;
    cJSON *req = submit_request(scene_path, settings, request_id);
    submit_frames_t fr = {.count = 1, .owned = 1};
    unsigned long long job = 0;
    if (bundle_meshes(scene, scene_path, cJSON_GetObjectItemCaseSensitive(req, "meshes"), &fr, err,
                      errlen) == 0 &&
        scene_frame(scene, scene_path, &fr, err, errlen) == 0 &&
        (!reference || reference_frames(req, reference, &fr, err, errlen) == 0)) {
        cJSON *reply = control_request_retry(c, req, (const void *const *)fr.frames, fr.sizes,
                                             fr.count, retry, err, errlen);
        if (reply)
            job = reply_job(reply, err, errlen);
        cJSON_Delete(reply);
    }
    submit_frames_free(&fr);
    cJSON_Delete(scene);
    cJSON_Delete(req);
    return job;
}

image_t *control_fetch(control_t *c, unsigned long long job, cJSON **job_status, char *err,
                       size_t errlen)
{
    *job_status = NULL;
    cJSON *req = cJSON_CreateObject();
    cJSON_AddStringToObject(req, "cmd", "fetch");
    cJSON_AddNumberToObject(req, "job", (double)job);
    cJSON *reply = control_request(c, req, NULL, NULL, 0, err, errlen);
    cJSON_Delete(req);
    if (!reply)
        return NULL;
    image_t *img = NULL;
    const cJSON *ok = cJSON_GetObjectItemCaseSensitive(reply, "ok");
    const cJSON *st = cJSON_GetObjectItemCaseSensitive(reply, "job");
    const cJSON *ch = cJSON_GetObjectItemCaseSensitive(reply, "channels");
    if (!cJSON_IsTrue(ok)) {
        const cJSON *e = cJSON_GetObjectItemCaseSensitive(reply, "error");
        snprintf(err, errlen, "%s", cJSON_IsString(e) ? e->valuestring : "fetch refused");
        goto done;
    }
    const cJSON *w = cJSON_GetObjectItemCaseSensitive(st, "width"),
                *h = cJSON_GetObjectItemCaseSensitive(st, "height");
    int n = cJSON_GetArraySize(ch);
    if (!cJSON_IsNumber(w) || !cJSON_IsNumber(h) || n != extra_count(c)) {
        snprintf(err, errlen, "the master's image reply is malformed");
        goto done;
    }
    img = image_new((int)w->valuedouble, (int)h->valuedouble);
    size_t plane = img ? (size_t)img->width * img->height * sizeof(float) : 0;
    for (int i = 0; img && i < n; i++) {
        const cJSON *name = cJSON_GetArrayItem(ch, i);
        float *dst = cJSON_IsString(name) ? image_add_channel(img, name->valuestring) : NULL;
        if (!dst || zmq_msg_size(&c->reply.part[1 + i]) != plane) {
            snprintf(err, errlen, "the master's image reply is malformed (channel %d)", i);
            image_destroy(&img);
            break;
        }
        memcpy(dst, zmq_msg_data(&c->reply.part[1 + i]), plane);
    }
    if (img)
        *job_status = cJSON_Duplicate(st, 1);
done:
    drop_extra(c);
    cJSON_Delete(reply);
    return img;
}
