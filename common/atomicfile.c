/* atomicfile.c - write to a temporary, fsync, rename. See atomicfile.h. */
#include "atomicfile.h"

#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

/* "PATH: WHAT: WHY" into the caller's buffer; returns -1. */
static int report(char *err, size_t errlen, const char *path, const char *what, const char *why)
{
    if (err && errlen > 0)
        snprintf(err, errlen, "%s: %s: %s", path, what, why);
    return -1;
}

int atomicfile_open(const char *path, char *tmp, size_t tmplen, char *err, size_t errlen)
{
    int n = snprintf(tmp, tmplen, "%s.tmp.%ld", path, (long)getpid());
    if (n < 0 || (size_t)n >= tmplen)
        return report(err, errlen, path, "cannot open for writing", "path too long");
    int fd = open(tmp, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0666);
    if (fd < 0)
        return report(err, errlen, path, "cannot open for writing", strerror(errno));
    return fd;
}

int atomicfile_commit(int fd, const char *tmp, const char *path, char *err, size_t errlen)
{
    /* fsync before rename: otherwise a crash can leave the new name
     * pointing at an empty file on some file systems. */
    if (fsync(fd) != 0 && errno != EINVAL && errno != EROFS) {
        report(err, errlen, path, "cannot sync", strerror(errno));
        close(fd);
        unlink(tmp);
        return -1;
    }
    if (close(fd) != 0) {
        report(err, errlen, path, "cannot close", strerror(errno));
        unlink(tmp);
        return -1;
    }
    if (rename(tmp, path) != 0) {
        if (err && errlen > 0)
            snprintf(err, errlen, "%s: cannot rename %s into place: %s", path, tmp,
                     strerror(errno));
        unlink(tmp);
        return -1;
    }
    return 0;
}

void atomicfile_abandon(int fd, const char *tmp)
{
    close(fd);
    unlink(tmp);
}
