/* offload.c - see offload.h. */
#include "offload.h"

#include <errno.h>
#include <fcntl.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "master_priv.h"

struct offload {
    store_t *store;
    submit_limits_t limits;
    pthread_t thread;
    int started;
    pthread_mutex_t lock;
    pthread_cond_t cond;
    offload_item_t *todo, *todo_tail; /* guarded by lock */
    offload_item_t *done, *done_tail; /* guarded by lock */
    size_t pending;                   /* guarded by lock */
    int quit;                         /* guarded by lock */
    int pipe_r, pipe_w;               /* a byte per done item wakes the loop */
};

offload_item_t *offload_item_new(offload_kind_t kind)
{
    offload_item_t *it = calloc(1, sizeof *it);
    if (!it)
        return NULL;
    it->kind = kind;
    zmq_msg_init(&it->client);
    for (int i = 0; i < OFFLOAD_MAX_FRAMES; i++)
        zmq_msg_init(&it->frames[i]);
    return it;
}

void offload_item_free(offload_item_t *it)
{
    if (!it)
        return;
    zmq_msg_close(&it->client);
    for (int i = 0; i < OFFLOAD_MAX_FRAMES; i++)
        zmq_msg_close(&it->frames[i]);
    cJSON_Delete(it->req);
    job_free(it->job);
    image_destroy(&it->image);
    free(it);
}

static void do_submit(offload_t *o, offload_item_t *it)
{
    submit_frame_t frames[OFFLOAD_MAX_FRAMES];
    for (int i = 0; i < it->nframes; i++)
        frames[i] = (submit_frame_t){zmq_msg_data(&it->frames[i]), zmq_msg_size(&it->frames[i])};
    /* frames[0] is the request's JSON, then the scene and its files */
    job_t *j =
        submit_parse(it->req, frames + 1, it->nframes - 1, &o->limits, it->err, sizeof it->err);
    if (!j)
        return;
    snprintf(j->owner, sizeof j->owner, "%s", it->owner);
    if (o->store) {
        /* shorter than it->err by the prefix added below, so the message
         * always fits whole */
        char err[VB_ERR_LEN - 64];
        /* the stored request names the job's replicates: recovered without
         * them it would be taken for an older master's (submit_parse) */
        char *text = NULL;
        if (!cJSON_GetObjectItemCaseSensitive(it->req, "replicates") &&
            (!cJSON_AddNumberToObject(it->req, "replicates", JOB_DEFAULT_REPLICATES) ||
             !(text = cJSON_PrintUnformatted(it->req)))) {
            snprintf(it->err, sizeof it->err, "out of memory");
            job_free(j);
            return;
        }
        int rc = persist_submission(o->store, j, text ? text : frames[0].data,
                                    text ? strlen(text) : frames[0].size, frames + 1,
                                    it->nframes - 1, err, sizeof err);
        free(text);
        if (rc < 0) {
            snprintf(it->err, sizeof it->err, "the master cannot store the job: %s", err);
            job_free(j);
            return;
        }
    }
    it->job = j;
}

static void *run(void *arg)
{
    offload_t *o = arg;
    pthread_mutex_lock(&o->lock);
    for (;;) {
        while (!o->todo && !o->quit)
            pthread_cond_wait(&o->cond, &o->lock);
        if (o->quit)
            break;
        offload_item_t *it = o->todo;
        o->todo = it->next;
        if (!o->todo)
            o->todo_tail = NULL;
        it->next = NULL;
        pthread_mutex_unlock(&o->lock);
        if (it->kind == OFFLOAD_SUBMIT)
            do_submit(o, it);
        else if (it->kind == OFFLOAD_FETCH &&
                 image_read_exr(it->path, &it->image, it->err, sizeof it->err) < 0)
            it->image = NULL;
        pthread_mutex_lock(&o->lock);
        if (o->done_tail)
            o->done_tail->next = it;
        else
            o->done = it;
        o->done_tail = it;
        /* a full pipe already says "look": nothing is lost by a failed write */
        char b = 1;
        (void)!write(o->pipe_w, &b, 1);
    }
    pthread_mutex_unlock(&o->lock);
    return NULL;
}

offload_t *offload_new(store_t *store, const submit_limits_t *limits, char *err, size_t errlen)
{
    offload_t *o = calloc(1, sizeof *o);
    if (!o) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    o->store = store;
    o->limits = *limits;
    o->pipe_r = o->pipe_w = -1;
    int p[2];
    if (pipe(p) != 0) {
        snprintf(err, errlen, "pipe: %s", strerror(errno));
        free(o);
        return NULL;
    }
    o->pipe_r = p[0];
    o->pipe_w = p[1];
    /* fcntl on a pipe just made fails only with EBADF: unchecked */
    for (int i = 0; i < 2; i++) {
        (void)fcntl(p[i], F_SETFL, fcntl(p[i], F_GETFL) | O_NONBLOCK);
        (void)fcntl(p[i], F_SETFD, FD_CLOEXEC);
    }
    pthread_mutex_init(&o->lock, NULL);
    pthread_cond_init(&o->cond, NULL);
    if (pthread_create(&o->thread, NULL, run, o) != 0) {
        snprintf(err, errlen, "cannot start the control thread");
        offload_destroy(&o);
        return NULL;
    }
    o->started = 1;
    return o;
}

static void free_list(offload_item_t *it)
{
    while (it) {
        offload_item_t *next = it->next;
        offload_item_free(it);
        it = next;
    }
}

void offload_destroy(offload_t **op)
{
    if (!op || !*op)
        return;
    offload_t *o = *op;
    if (o->started) {
        pthread_mutex_lock(&o->lock);
        o->quit = 1;
        pthread_cond_signal(&o->cond);
        pthread_mutex_unlock(&o->lock);
        pthread_join(o->thread, NULL);
    }
    free_list(o->todo);
    free_list(o->done);
    /* the wake-up pipe carries no data: nothing is lost if a close fails */
    if (o->pipe_r >= 0)
        (void)close(o->pipe_r);
    if (o->pipe_w >= 0)
        (void)close(o->pipe_w);
    pthread_mutex_destroy(&o->lock);
    pthread_cond_destroy(&o->cond);
    free(o);
    *op = NULL;
}

void offload_push(offload_t *o, offload_item_t *it)
{
    it->next = NULL;
    pthread_mutex_lock(&o->lock);
    if (o->todo_tail)
        o->todo_tail->next = it;
    else
        o->todo = it;
    o->todo_tail = it;
    o->pending++;
    pthread_cond_signal(&o->cond);
    pthread_mutex_unlock(&o->lock);
}

int offload_fd(const offload_t *o)
{
    return o->pipe_r;
}

offload_item_t *offload_take_done(offload_t *o)
{
    char buf[256];
    while (read(o->pipe_r, buf, sizeof buf) > 0) {
    }
    pthread_mutex_lock(&o->lock);
    offload_item_t *list = o->done;
    for (offload_item_t *it = list; it; it = it->next)
        o->pending--;
    o->done = o->done_tail = NULL;
    pthread_mutex_unlock(&o->lock);
    return list;
}

size_t offload_pending(const offload_t *o)
{
    pthread_mutex_lock((pthread_mutex_t *)&o->lock);
    size_t n = o->pending;
    pthread_mutex_unlock((pthread_mutex_t *)&o->lock);
    return n;
}
