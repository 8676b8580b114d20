/* serve.h - `vbrender serve`: a web dashboard and Prometheus metrics for a
 * running master, served over HTTP (libmicrohttpd). It is one more client
 * of the control protocol (control.h): the master stays lean and knows
 * nothing of HTTP.
 *
 * Routes (GET or HEAD unless said):
 *   /                          the jobs page
 *   /job/ID                    a job: its image so far, samples heat map,
 *                              plots of error and samples over time, its
 *                              settings, a cancel button
 *   /workers                   the workers page
 *   /static/app.css, app.js    what the pages share
 *   /api/jobs, /api/job/ID, /api/workers   the master's replies to jobs,
 *                              status and workers, as JSON
 *   /api/job/ID/preview.png?w=W&h=H    the image so far, tone-mapped (sRGB)
 *                              within W x H (1..4096, default 256)
 *   /api/job/ID/samples.png?w=W&h=H    samples per pixel as a heat map from
 *                              0 to the most any pixel has (header
 *                              X-Heatmap-Max)
 *   POST /api/job/ID/cancel    cancel (the master checks the key owns it);
 *                              the job as JSON, or to a browser's form
 *                              (Accept: text/html) 303 back to /job/ID
 *   /metrics                   Prometheus text format 0.0.4
 *
 * Errors are JSON {"ok": false, "error": "..."} with 400 (bad size), 403
 * (another client's job, or a cancel posted from another site's page), 404 (no such job or path),
 * 405 (method), 501 (a master without previews), 502 or 503 ("master unreachable: ...").
 */
#ifndef VB_SERVE_H
#define VB_SERVE_H

#include <cJSON.h>
#include <stddef.h>

#define SERVE_PREVIEW_DEFAULT 256 /* preview size when the query gives none */
#define SERVE_PREVIEW_MAX 4096

/* Runs `vbrender serve [options]` (the arguments after "serve") until
 * SIGINT or SIGTERM; returns the exit status (0, 1 failure, 2 usage). */
int serve_main(int argc, char **argv);

typedef enum serve_route_kind {
    SERVE_JOBS_PAGE,
    SERVE_JOB_PAGE,
    SERVE_WORKERS_PAGE,
    SERVE_ASSET_CSS,
    SERVE_ASSET_JS,
    SERVE_API_JOBS,
    SERVE_API_JOB,
    SERVE_API_WORKERS,
    SERVE_API_PREVIEW,
    SERVE_API_SAMPLES,
    SERVE_API_CANCEL,
    SERVE_METRICS,
} serve_route_kind_t;

typedef struct serve_route {
    serve_route_kind_t kind;
    unsigned long long job; /* the routes under /job/ and /api/job/: the id */
    const char *allow;      /* the methods the path takes (for a 405's Allow) */
} serve_route_t;

/* Maps a method and a path (without its query) to a route. Returns 200
 * with *out set, 404 (no such path, or a job id that is not a positive
 * integer) or 405 (the path exists, not for this method; out->allow set),
 * with a message in msg. */
int serve_parse_route(const char *method, const char *path, serve_route_t *out, char *msg,
                      size_t msglen);

/* A preview dimension from the query (NULL or absent: the default): 0 with
 * *out set, or -1 with a message (an HTTP 400). name is for the message. */
int serve_parse_size(const char *text, const char *name, int *out, char *msg, size_t msglen);

/* Whether a POST may act: 1 without an Origin header (not a browser's
 * cross-site request: scripts, curl), else only when Origin is this
 * server as the request's Host names it. A page elsewhere could otherwise
 * make a visitor's browser cancel jobs with this client's key (CSRF). */
int serve_same_origin(const char *origin, const char *host);

/* The HTTP status for a master's {"ok": false} error message: 404 for no
 * such job, 403 for another client's job, 501 for an unknown command (a
 * master from before preview), 400 otherwise. */
int serve_error_status(const char *msg);

/* The /metrics text for a master's replies to `jobs` and `workers` (whole
 * replies, "ok" and all). A counter the master does not report is left
 * out. malloc'd; NULL when out of memory. */
char *serve_metrics_text(const cJSON *jobs, const cJSON *workers);

/* PNGs in memory (malloc'd, *size set), or NULL with a message: linear RGB
 * (w*h*3 floats, interleaved, row 0 at the top) tone-mapped as `fetch`
 * writes its PNG (sRGB, exposure 1), and one float per pixel as the heat
 * map `fetch` writes for samples (black, blue, red, yellow, white), from 0 to
 * hi. */
unsigned char *serve_png_rgb(const float *rgb, int w, int h, size_t *size, char *err,
                             size_t errlen);
unsigned char *serve_png_heat(const float *v, int w, int h, float hi, size_t *size, char *err,
                              size_t errlen);

/* The pages and what they share, built into the binary from client/web/
 * (the Makefile turns each file into a string). */
extern const char serve_asset_jobs_html[], serve_asset_job_html[], serve_asset_workers_html[],
    serve_asset_app_css[], serve_asset_app_js[];

#endif
