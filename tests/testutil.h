/* testutil.h - small helpers shared by the Check suites: where the data and
 * the binary under test are, and scratch files. The Makefile sets VB_ROOT,
 * VB_SHARED, VB_BIN and VB_TMP; the defaults let a suite run by hand from
 * the project root. */
#ifndef VB_TESTUTIL_H
#define VB_TESTUTIL_H

#include <stddef.h>
#include <sys/types.h>

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

/* 1 when every thread of pid has stopped (SIGSTOP takes effect when a
 * thread next leaves the kernel, not when kill returns), or pid is gone. */
int tu_stopped(pid_t pid);
/* SIGSTOP to pid, and waits (up to 10 s) until all its threads have
 * stopped: then it sends nothing more. 0, or -1 when it did not stop. */
int tu_freeze(pid_t pid);

#endif
