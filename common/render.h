/* render.h - a whole render on this machine's threads: layers of G samples
 * for every pixel, traced by the core, merged into a film.
 *
 * Layers run in order; within a layer, threads take batches of pixels from
 * a shared counter and merge each pixel's result themselves (a pixel belongs
 * to one batch per layer), then wait for each other at the layer's end. So
 * every pixel merges its layers in order and the film is identical, bit for
 * bit, for any thread count. The distributed master reuses the same core
 * calls over the network.
 */
#ifndef VB_RENDER_H
#define VB_RENDER_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "film.h"
#include "progress.h"
#include "tracer.h"

#define RENDER_DEFAULT_GRANULARITY 32
#define RENDER_MAX_THREADS 256

typedef struct render_settings {
    tracer_settings_t tracer;
    uint32_t spp;         /* samples per pixel */
    uint32_t granularity; /* G: samples per pixel per layer */
    int threads;          /* worker threads, >= 1 */
    progress_mode_t progress;
    FILE *progress_out; /* where progress goes (stderr); NULL: none */
} render_settings_t;

typedef struct render_summary {
    double seconds;
    uint64_t samples; /* taken, finite or not */
    uint64_t rays;
    uint64_t nonfinite;
    uint32_t layers;
} render_summary_t;

/* Renders into film (which must match the camera's size and may already
 * hold earlier layers: its samples count as "so far"). Returns 0, or -1
 * with a message. */
int render_run(const tracer_t *tracer, film_t *film, const render_settings_t *settings,
               render_summary_t *summary, char *err, size_t errlen);

/* "12.3M" style figure, into buf. */
const char *render_si(double value, char *buf, size_t len);

#endif
