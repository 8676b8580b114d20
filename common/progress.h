/* progress.h - progress for long work: a bar redrawn in place on a terminal,
 * plain lines (every 10 % or 10 s) otherwise, nothing when quiet. */
#ifndef VB_PROGRESS_H
#define VB_PROGRESS_H

#include <stdio.h>

typedef enum { PROGRESS_AUTO = 0, PROGRESS_BAR, PROGRESS_LINES, PROGRESS_NONE } progress_mode_t;

typedef struct progress progress_t;

/* AUTO picks BAR when out is a terminal, LINES otherwise. NULL when out of
 * memory. The label starts every line. */
progress_t *progress_new(FILE *out, progress_mode_t mode, const char *label);
/* fraction in [0, 1]; detail is a short text such as "layer 3/8, 1.2M samples/s". */
void progress_update(progress_t *p, double fraction, const char *detail);
/* Ends the bar's line (prints 100 %). */
void progress_finish(progress_t *p, const char *detail);
void progress_destroy(progress_t **p);

#endif
