/* vblog.c - see vblog.h. */
#include "vblog.h"

#include <string.h>
#include <time.h>

/* Writes s with control bytes as \xNN and backslash as \\; the caller holds
 * the stream's lock. */
static void put_escaped(FILE *out, const char *s)
{
    static const char hex[] = "0123456789abcdef";
    for (const unsigned char *p = (const unsigned char *)s; *p; p++) {
        if (*p < 0x20 || *p == 0x7f) {
            putc_unlocked('\\', out);
            putc_unlocked('x', out);
            putc_unlocked(hex[*p >> 4], out);
            putc_unlocked(hex[*p & 15], out);
        } else if (*p == '\\') {
            putc_unlocked('\\', out);
            putc_unlocked('\\', out);
        } else {
            putc_unlocked((int)*p, out);
        }
    }
}

/* One line: stamp, who, then the message in pieces (prefix is ours and
 * written as is, msg may be NULL). */
static void emit(FILE *out, const char *who, const char *prefix, const char *msg)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    struct tm tm;
    gmtime_r(&ts.tv_sec, &tm);
    char stamp[32];
    strftime(stamp, sizeof stamp, "%Y-%m-%dT%H:%M:%S", &tm);
    /* the stream's lock around the whole line, so a line is written whole
     * even with several threads logging to one stream */
    flockfile(out);
    fprintf(out, "%s.%03ldZ ", stamp, ts.tv_nsec / 1000000);
    put_escaped(out, who ? who : "");
    fputs(": ", out);
    if (prefix)
        fputs(prefix, out);
    if (msg)
        put_escaped(out, msg);
    putc_unlocked('\n', out);
    fflush(out);
    funlockfile(out);
}

void vblog_write(FILE *out, const char *who, const char *fmt, va_list ap)
{
    if (!out)
        return;
    char msg[VBLOG_MSG_MAX];
    vsnprintf(msg, sizeof msg, fmt, ap);
    emit(out, who, NULL, msg);
}

/* ---- levels --------------------------------------------------------------- */

static const char *const level_names[] = {NULL, "error", "warn", "info", "debug"};

int vblog_level_parse(const char *name)
{
    for (int l = VBLOG_ERROR; name && l <= VBLOG_DEBUG; l++)
        if (strcmp(name, level_names[l]) == 0)
            return l;
    return -1;
}

const char *vblog_level_name(int level)
{
    return level >= VBLOG_ERROR && level <= VBLOG_DEBUG ? level_names[level] : "?";
}

FILE *vblog_filter(FILE *out, int threshold, vblog_level_t level)
{
    return (int)level <= (threshold ? threshold : VBLOG_DEFAULT_LEVEL) ? out : NULL;
}

/* ---- rate limit ----------------------------------------------------------- */

/* A window is over once VBLOG_WINDOW_S has passed; a clock that went back
 * also ends it, or a stepped clock would hold a key back until it caught up. */
static int window_over(const vblog_limit_slot_t *s, double now_s)
{
    return now_s - s->window_start >= VBLOG_WINDOW_S || now_s < s->window_start;
}

static void summarise(vblog_limit_slot_t *s, FILE *out, const char *who)
{
    if (!s->suppressed)
        return;
    char prefix[96];
    snprintf(prefix, sizeof prefix,
             "%llu more like this in the last %g s: ", (unsigned long long)s->suppressed,
             VBLOG_WINDOW_S);
    emit(out, who, prefix, s->last);
    s->suppressed = 0;
}

/* The slot of key: its own, else a free one, else the least recently used
 * one (after writing its pending summary). */
static vblog_limit_slot_t *slot_for(vblog_limiter_t *l, FILE *out, const char *who, const char *key)
{
    vblog_limit_slot_t *free_slot = NULL, *lru = &l->slot[0];
    for (size_t i = 0; i < VBLOG_KEYS; i++) {
        vblog_limit_slot_t *s = &l->slot[i];
        if (!s->key) {
            if (!free_slot)
                free_slot = s;
            continue;
        }
        if (s->key == key || strcmp(s->key, key) == 0)
            return s;
        if (s->used < lru->used || !lru->key)
            lru = s;
    }
    vblog_limit_slot_t *s = free_slot;
    if (!s) {
        s = lru;
        summarise(s, out, who);
    }
    s->key = key;
    s->written = 0;
    s->suppressed = 0;
    s->last[0] = '\0';
    s->window_start = 0;
    return s;
}

void vblog_limited(vblog_limiter_t *l, FILE *out, const char *who, const char *key, double now_s,
                   const char *fmt, va_list ap)
{
    if (!out)
        return;
    if (!l || !key) {
        vblog_write(out, who, fmt, ap);
        return;
    }
    vblog_limit_slot_t *s = slot_for(l, out, who, key);
    s->used = ++l->tick;
    if (s->written == 0 || window_over(s, now_s)) {
        summarise(s, out, who);
        s->window_start = now_s;
        s->written = 0;
    }
    if (s->written < VBLOG_BURST) {
        s->written++;
        vblog_write(out, who, fmt, ap);
        return;
    }
    /* held back: keep only the latest, so the summary shows a real example */
    vsnprintf(s->last, sizeof s->last, fmt, ap);
    s->suppressed++;
}

void vblog_limiter_flush(vblog_limiter_t *l, FILE *out, const char *who, double now_s)
{
    if (!l || !out)
        return;
    for (size_t i = 0; i < VBLOG_KEYS; i++) {
        vblog_limit_slot_t *s = &l->slot[i];
        if (s->key && s->suppressed && window_over(s, now_s))
            summarise(s, out, who);
    }
}
