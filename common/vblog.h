/* vblog.h - the daemons' log lines: UTC timestamp with milliseconds, who
 * speaks, the message; one line per call, flushed, so logs of several
 * processes interleave readably.
 *
 * Peers put text into log lines (job names, error strings), so every byte
 * < 0x20 or == 0x7f of who and the message is written as \xNN and a
 * backslash as \\: a newline in a job name cannot forge a line, an escape
 * sequence cannot repaint a terminal, and the escaping stays unambiguous.
 * All other bytes (UTF-8 included) are written as they are. */
#ifndef VB_VBLOG_H
#define VB_VBLOG_H

#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>

/* Longest formatted message kept, terminator included; longer ones are cut
 * (before escaping, so an escape is never cut in half). */
#define VBLOG_MSG_MAX 1024

/* Writes "2026-11-23T14:53:46.051Z who: message\n" to out (nothing if out
 * is NULL). */
void vblog_write(FILE *out, const char *who, const char *fmt, va_list ap)
    __attribute__((format(printf, 3, 0)));

/* Levels, most severe first. A daemon's --log-level names the least severe
 * level it writes; every line has one (the daemons' plain lines are info,
 * the rate-limited peer-provoked ones warn). */
typedef enum vblog_level {
    VBLOG_ERROR = 1, /* the daemon cannot do part of its work (state not saved) */
    VBLOG_WARN,      /* something went wrong that it works around (a refused peer) */
    VBLOG_INFO,      /* what an operator follows: jobs, workers joining and leaving */
    VBLOG_DEBUG,     /* per task: what a developer follows */
} vblog_level_t;
/* The level a threshold of 0 (a config left zeroed) stands for. */
#define VBLOG_DEFAULT_LEVEL VBLOG_INFO

/* The level named "error", "warn", "info" or "debug", or -1. */
int vblog_level_parse(const char *name);
/* The name of a level ("?" for none). */
const char *vblog_level_name(int level);
/* out when a line of level passes threshold (the least severe level written;
 * 0: VBLOG_DEFAULT_LEVEL), else NULL. Give the result to vblog_write or
 * vblog_limited as their out: a filtered line is then neither written nor
 * counted against its rate limit. The threshold lives in the caller's
 * config, not here, so that no global state is shared. */
FILE *vblog_filter(FILE *out, int threshold, vblog_level_t level);

/* Rate limit: at most VBLOG_BURST lines of one key per VBLOG_WINDOW_S
 * window. 10 lines show what goes wrong; a flood of bad messages then costs
 * one summary line per key and window instead of megabytes a second. */
#define VBLOG_BURST 10
#define VBLOG_WINDOW_S 10.0
/* Kinds of line tracked at once; a daemon has a handful of limited kinds,
 * so 32 leaves room without scanning far. */
#define VBLOG_KEYS 32

typedef struct vblog_limit_slot {
    const char *key;          /* NULL: slot free */
    double window_start;      /* now_s of the window's first line */
    uint64_t used;            /* limiter tick of the last use, for LRU reuse */
    unsigned written;         /* lines written in this window */
    uint64_t suppressed;      /* lines held back in this window */
    char last[VBLOG_MSG_MAX]; /* the last line held back, unescaped */
} vblog_limit_slot_t;

/* Per-key rate limit for log lines: at most VBLOG_BURST lines of one key per
 * VBLOG_WINDOW_S window; the rest are counted and summarised as
 * "who: N more like this in the last 10 s: <last suppressed message>" when
 * the window ends (the next line of that key or vblog_limiter_flush,
 * whichever comes first). A window starts at the first line of a key after
 * the previous one ended. Keys are string literals naming a kind of line
 * (e.g. "malformed"), compared by strcmp, and must outlive the limiter. The
 * table holds VBLOG_KEYS keys; a new key beyond that takes the least
 * recently used slot, whose pending summary is written first so no count is
 * lost. Embed it in the caller's state; all zero bytes is a valid empty
 * limiter. Not locked: callers of one limiter must serialise (the daemons
 * log from their one event loop). */
typedef struct vblog_limiter {
    vblog_limit_slot_t slot[VBLOG_KEYS];
    uint64_t tick;
} vblog_limiter_t;

/* Writes the line as vblog_write does unless its key is over its burst in
 * the current window; now_s is the caller's clock in seconds (monotonic is
 * best). A NULL limiter or key writes the line unlimited; a NULL out writes
 * nothing and counts nothing. */
void vblog_limited(vblog_limiter_t *l, FILE *out, const char *who, const char *key, double now_s,
                   const char *fmt, va_list ap) __attribute__((format(printf, 6, 0)));
/* Writes the pending summaries of windows that have ended by now_s (call it
 * from a periodic timer so a burst's summary is not held back forever). */
void vblog_limiter_flush(vblog_limiter_t *l, FILE *out, const char *who, double now_s);

#endif
