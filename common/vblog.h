/* vblog.h - the daemons' log lines: UTC timestamp with milliseconds, who
 * speaks, the message; one line per call, flushed, so logs of several
 * processes interleave readably. */
#ifndef VB_VBLOG_H
#define VB_VBLOG_H

#include <stdarg.h>
#include <stdio.h>

/* Writes "2026-11-23T14:53:46.051Z who: message\n" to out (nothing if out
 * is NULL). */
void vblog_write(FILE *out, const char *who, const char *fmt, va_list ap);

#endif
