/* atomicfile.h - replacing a file atomically: the new content is written to
 * "<path>.tmp.<pid>", synced, and renamed over path only once complete, so
 * a reader never sees half a file and a failed write leaves any previous
 * file in place. Used by the EXR and PNG writers (exr.c, png.c).
 *
 * Messages name the final path ("PATH: cannot ...: why"), as the caller's
 * user knows it, not the temporary.
 */
#ifndef VB_ATOMICFILE_H
#define VB_ATOMICFILE_H

#include <stddef.h>

/* Creates the temporary file for path (mode 0666 before umask, O_CLOEXEC)
 * and writes its name into tmp[tmplen]. Returns the descriptor, or -1 with
 * "PATH: cannot open for writing: ..." in err. */
int atomicfile_open(const char *path, char *tmp, size_t tmplen, char *err, size_t errlen);

/* Makes the finished temporary durable (fsync) and renames it over path.
 * fd is closed in every case; the temporary is removed on failure. Returns
 * 0, or -1 with a message in err. */
int atomicfile_commit(int fd, const char *tmp, const char *path, char *err, size_t errlen);

/* Gives up a write: closes fd and removes the temporary. */
void atomicfile_abandon(int fd, const char *tmp);

#endif
