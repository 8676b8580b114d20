/* progress.c - see progress.h. */
#include "progress.h"

#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

struct progress {
    FILE *out;
    progress_mode_t mode;
    char label[64];
    double next_fraction; /* LINES: next 10 % mark */
    double last_line;     /* LINES: time of the last line */
    int finished;
};

static double now_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

progress_t *progress_new(FILE *out, progress_mode_t mode, const char *label)
{
    progress_t *p = calloc(1, sizeof *p);
    if (!p)
        return NULL;
    p->out = out;
    if (mode == PROGRESS_AUTO)
        mode = isatty(fileno(out)) ? PROGRESS_BAR : PROGRESS_LINES;
    p->mode = mode;
    snprintf(p->label, sizeof p->label, "%s", label ? label : "");
    p->next_fraction = 0.1;
    p->last_line = now_seconds();
    return p;
}

static void draw_bar(progress_t *p, double fraction, const char *detail)
{
    const int width = 30;
    int filled = (int)(fraction * width + 0.5);
    char bar[64];
    for (int i = 0; i < width; i++)
        bar[i] = i < filled ? '#' : '.';
    bar[width] = '\0';
    fprintf(p->out, "\r%s [%s] %5.1f%%  %s\033[K", p->label, bar, 100.0 * fraction,
            detail ? detail : "");
    fflush(p->out);
}

void progress_update(progress_t *p, double fraction, const char *detail)
{
    if (!p || p->finished)
        return;
    if (fraction < 0)
        fraction = 0;
    if (fraction > 1)
        fraction = 1;
    if (p->mode == PROGRESS_BAR) {
        draw_bar(p, fraction, detail);
    } else if (p->mode == PROGRESS_LINES) {
        double t = now_seconds();
        if (fraction >= p->next_fraction || t - p->last_line >= 10.0) {
            fprintf(p->out, "%s %5.1f%%  %s\n", p->label, 100.0 * fraction, detail ? detail : "");
            fflush(p->out);
            while (p->next_fraction <= fraction)
                p->next_fraction += 0.1;
            p->last_line = t;
        }
    }
}

void progress_finish(progress_t *p, const char *detail)
{
    if (!p || p->finished)
        return;
    if (p->mode == PROGRESS_BAR) {
        draw_bar(p, 1.0, detail);
        fputc('\n', p->out);
    } else if (p->mode == PROGRESS_LINES && p->next_fraction <= 1.0 + 1e-9) {
        fprintf(p->out, "%s 100.0%%  %s\n", p->label, detail ? detail : "");
    }
    fflush(p->out);
    p->finished = 1;
}

void progress_destroy(progress_t **p)
{
    if (!p || !*p)
        return;
    free(*p);
    *p = NULL;
}
