/* vblog.c - see vblog.h. */
#include "vblog.h"

#include <time.h>

void vblog_write(FILE *out, const char *who, const char *fmt, va_list ap)
{
    if (!out)
        return;
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    struct tm tm;
    gmtime_r(&ts.tv_sec, &tm);
    char stamp[32];
    strftime(stamp, sizeof stamp, "%Y-%m-%dT%H:%M:%S", &tm);
    char msg[1024];
    vsnprintf(msg, sizeof msg, fmt, ap);
    /* one fprintf, so a line is written whole even with several threads */
    fprintf(out, "%s.%03ldZ %s: %s\n", stamp, ts.tv_nsec / 1000000, who, msg);
    fflush(out);
}
