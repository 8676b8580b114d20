/* bench_memory.c - what a running job costs the master in memory, by
 * resolution, spp and adaptive mode: the scheduler's own accounting
 * (sched_memory: film, per-pixel statistics, the window of the two layers
 * in flight and the records of their tasks), array by array.
 *
 * For each case a scheduler is made and started as a master starts a job,
 * and every task of its first layer is handed out at once (as many idle
 * workers would take them): the records of tasks in flight are then at
 * their largest, a whole layer of the image. Nothing is traced or merged;
 * the arrays' sizes do not change after the start.
 *
 * usage: bench_memory [--json FILE]   (a table on stdout) */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "defaults.h"
#include "sched.h"

typedef struct item {
    char name[48];
    size_t bytes;
} item_t;

typedef struct report {
    item_t items[32];
    int n;
} report_t;

static void collect(void *ctx, const char *name, size_t bytes)
{
    report_t *r = ctx;
    if (r->n < 32) {
        snprintf(r->items[r->n].name, sizeof r->items[r->n].name, "%s", name);
        r->items[r->n++].bytes = bytes;
    }
}

typedef struct bcase {
    uint32_t w, h, spp;
    sched_adaptive_t adaptive;
    double target;
} bcase_t;

int main(int argc, char **argv)
{
    const char *json = argc == 3 && strcmp(argv[1], "--json") == 0 ? argv[2] : NULL;
    static const bcase_t cases[] = {
        {256, 256, 256, SCHED_ADAPTIVE_RELMSE, 0},
        {256, 256, 4096, SCHED_ADAPTIVE_RELMSE, 0},
        {256, 256, 65536, SCHED_ADAPTIVE_RELMSE, 0},
        {1920, 1080, 256, SCHED_ADAPTIVE_RELMSE, 0},
        {1920, 1080, 4096, SCHED_ADAPTIVE_RELMSE, 0},
        {1920, 1080, 65536, SCHED_ADAPTIVE_RELMSE, 0},
        {3840, 2160, 256, SCHED_ADAPTIVE_RELMSE, 0},
        {3840, 2160, 4096, SCHED_ADAPTIVE_RELMSE, 0},
        {3840, 2160, 65536, SCHED_ADAPTIVE_RELMSE, 0},
        {3840, 2160, 4096, SCHED_ADAPTIVE_NONE, 0},
        {3840, 2160, 4096, SCHED_ADAPTIVE_THESIS, 0},
        {3840, 2160, 4096, SCHED_ADAPTIVE_VARIANCE, 0},
        {3840, 2160, 4096, SCHED_ADAPTIVE_RELERR, 0},
        {3840, 2160, 65536, SCHED_ADAPTIVE_RELMSE, 0.01},
    };
    FILE *jf = json ? fopen(json, "w") : NULL;
    if (json && !jf) {
        perror(json);
        return 1;
    }
    if (jf)
        fprintf(jf, "{\"granularity\": 32, \"cases\": [");
    printf("| image | spp | layers | adaptive | bytes a pixel | film and statistics | in flight "
           "(window, task records) | total MB | largest shares "
           "|\n|---|--:|--:|---|--:|--:|--:|--:|---|\n");
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++) {
        const bcase_t *k = &cases[c];
        sched_config_t cfg = {.width = k->w,
                              .height = k->h,
                              .spp = k->spp,
                              .granularity = 32,
                              .adaptive = k->adaptive,
                              .uniform_layers = UINT32_MAX,
                              .target_error = k->target,
                              /* as a master's job (submit.c): the replicates' sums */
                              .replicates = JOB_DEFAULT_REPLICATES};
        char err[256];
        sched_t *s = sched_new(&cfg, err, sizeof err);
        if (!s) {
            fprintf(stderr, "bench_memory: %ux%u at %u spp: %s\n", k->w, k->h, k->spp, err);
            return 1;
        }
        sched_task_t t;
        while (sched_next(s, &t) == SCHED_NEXT_TASK)
            ;
        report_t r = {.n = 0};
        size_t total = sched_memory(s, collect, &r);
        const double npix = (double)k->w * k->h;
        size_t flight = 0;
        for (int i = 0; i < r.n; i++)
            if (strstr(r.items[i].name, "window") || strstr(r.items[i].name, "flight") ||
                strstr(r.items[i].name, "rows") || strstr(r.items[i].name, "t tables"))
                flight += r.items[i].bytes;
        char mode[48];
        snprintf(mode, sizeof mode, "%s%s", sched_adaptive_name(k->adaptive),
                 k->target > 0 ? " + target" : "");
        /* the three largest arrays, as shares of the total */
        char shares[256] = "";
        int used[32] = {0};
        for (int top = 0; top < 3; top++) {
            int best = -1;
            for (int i = 0; i < r.n; i++)
                if (!used[i] && (best < 0 || r.items[i].bytes > r.items[best].bytes))
                    best = i;
            if (best < 0)
                break;
            used[best] = 1;
            size_t len = strlen(shares);
            snprintf(shares + len, sizeof shares - len, "%s%s %.0f %%", top ? ", " : "",
                     r.items[best].name, 100.0 * (double)r.items[best].bytes / (double)total);
        }
        printf("| %ux%u | %u | %u | %s | %.1f | %.1f | %.1f | %.1f | %s |\n", k->w, k->h, k->spp,
               sched_layer_count(s), mode, (double)total / npix, (double)(total - flight) / npix,
               (double)flight / npix, (double)total / 1e6, shares);
        if (jf) {
            fprintf(jf,
                    "%s\n {\"width\": %u, \"height\": %u, \"spp\": %u, \"layers\": %u, "
                    "\"adaptive\": \"%s\", \"target_error\": %g, \"bytes\": %zu, "
                    "\"bytes_per_pixel\": %.3f, \"pixel_state_bytes_per_pixel\": %.3f, "
                    "\"in_flight_bytes_per_pixel\": %.3f, \"arrays\": {",
                    c ? "," : "", k->w, k->h, k->spp, sched_layer_count(s),
                    sched_adaptive_name(k->adaptive), k->target, total, (double)total / npix,
                    (double)(total - flight) / npix, (double)flight / npix);
            for (int i = 0; i < r.n; i++)
                fprintf(jf, "%s\"%s\": %zu", i ? ", " : "", r.items[i].name, r.items[i].bytes);
            fprintf(jf, "}}");
        }
        sched_destroy(&s);
    }
    if (jf) {
        fprintf(jf, "\n]}\n");
        fclose(jf);
    }
    return 0;
}
