/* testutil.c - see testutil.h. */
#include "testutil.h"

#include <dirent.h>
#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>

static const char *env_or(const char *name, const char *fallback)
{
    const char *v = getenv(name);
    return (v && *v) ? v : fallback;
}

const char *tu_root_path(char *buf, size_t len, const char *rel)
{
    snprintf(buf, len, "%s/%s", env_or("VB_ROOT", "."), rel);
    return buf;
}

const char *tu_shared_path(char *buf, size_t len, const char *rel)
{
    snprintf(buf, len, "%s/%s", env_or("VB_SHARED", "../shared"), rel);
    return buf;
}

const char *tu_tmp_path(char *buf, size_t len, const char *name)
{
    const char *dir = env_or("VB_TMP", "/tmp");
    mkdir(dir, 0777);
    snprintf(buf, len, "%s/%s", dir, name);
    return buf;
}

const char *tu_bin(void)
{
    return env_or("VB_BIN", "bin/vbrender");
}

const char *tu_write_tmp(char *buf, size_t len, const char *name, const char *text)
{
    tu_tmp_path(buf, len, name);
    FILE *f = fopen(buf, "wb");
    if (!f)
        return NULL;
    fputs(text, f);
    fclose(f);
    return buf;
}

int tu_run(const char *cmd, char *out, size_t outlen)
{
    char full[8192];
    snprintf(full, sizeof full, "%s 2>&1", cmd);
    FILE *p = popen(full, "r");
    if (!p)
        return -1;
    size_t n = 0;
    if (out && outlen)
        out[0] = '\0';
    char chunk[4096];
    size_t got;
    while ((got = fread(chunk, 1, sizeof chunk, p)) > 0) {
        if (out && n + 1 < outlen) {
            size_t take = got < outlen - 1 - n ? got : outlen - 1 - n;
            memcpy(out + n, chunk, take);
            n += take;
            out[n] = '\0';
        }
    }
    int st = pclose(p);
    if (st == -1)
        return -1;
    return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
}

void tu_sleep_ms(int ms)
{
    struct timespec ts = {ms / 1000, (long)(ms % 1000) * 1000000L};
    while (nanosleep(&ts, &ts) < 0 && errno == EINTR)
        ;
}

double tu_now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

int tu_stopped(pid_t pid)
{
    char path[64], line[512];
    snprintf(path, sizeof path, "/proc/%ld/task", (long)pid);
    DIR *dir = opendir(path);
    if (!dir)
        return 1;
    int all = 1;
    struct dirent *e;
    while (all && (e = readdir(dir)) != NULL) {
        if (e->d_name[0] == '.')
            continue;
        snprintf(path, sizeof path, "/proc/%ld/task/%.20s/stat", (long)pid, e->d_name);
        FILE *f = fopen(path, "r");
        if (!f)
            continue;
        /* pid (comm) state ...: the comm may hold spaces and parentheses */
        const char *close = fgets(line, sizeof line, f) ? strrchr(line, ')') : NULL;
        all = !close || close[1] != ' ' || strchr("TtZX", close[2]) != NULL;
        fclose(f);
    }
    closedir(dir);
    return all;
}

int tu_freeze(pid_t pid)
{
    if (kill(pid, SIGSTOP) < 0)
        return -1;
    for (double end = tu_now_ms() + 10000; !tu_stopped(pid); tu_sleep_ms(1))
        if (tu_now_ms() > end)
            return -1;
    return 0;
}
