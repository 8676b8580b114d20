/* vberr.h - the size of an error message buffer, one for the whole tree.
 *
 * Functions that can fail fill a caller's `char *err, size_t errlen`
 * (style.md, habit 3); a caller that keeps or passes such a message sizes
 * its buffer VB_ERR_LEN. One size means a message handed from one module to
 * another is never cut short on the way: a buffer that must be smaller (to
 * leave room for a prefix the caller adds) or larger (it joins two
 * messages) says why where it is declared.
 */
#ifndef VB_VBERR_H
#define VB_VBERR_H

#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>

/* Room for a message that names a path (paths are cut at %.600s) and the
 * reason, with a prefix or two. */
#define VB_ERR_LEN 1024

/* printf into err, when the caller gave one (err may be NULL or errlen 0). */
static inline void vberr_set(char *err, size_t errlen, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
static inline void vberr_set(char *err, size_t errlen, const char *fmt, ...)
{
    if (!err || !errlen)
        return;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(err, errlen, fmt, ap);
    va_end(ap);
}

#endif
