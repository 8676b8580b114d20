/* testutil.h - small helpers shared by the Check suites: where the data and
 * the binary under test are, and scratch files. The Makefile sets VB_ROOT,
 * VB_SHARED, VB_BIN and VB_TMP; the defaults let a suite run by hand from
 * the project root. */
#ifndef VB_TESTUTIL_H
#define VB_TESTUTIL_H

#include <stddef.h>

/* Path under the project root / ../shared / the scratch folder, written into
 * buf (the caller's), which is returned. */
const char *tu_root_path(char *buf, size_t len, const char *rel);
const char *tu_shared_path(char *buf, size_t len, const char *rel);
const char *tu_tmp_path(char *buf, size_t len, const char *name);
/* The vbrender binary under test. */
const char *tu_bin(void);

/* Writes text to a scratch file named name; returns its path in buf. */
const char *tu_write_tmp(char *buf, size_t len, const char *name, const char *text);

/* Runs a shell command, captures stdout+stderr (up to outlen-1 bytes) and
 * returns the exit status (or -1 if it could not be run). */
int tu_run(const char *cmd, char *out, size_t outlen);

/* Sleeps ms milliseconds (through signals); the monotonic clock in ms. */
void tu_sleep_ms(int ms);
double tu_now_ms(void);

#endif
