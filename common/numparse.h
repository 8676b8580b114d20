/* numparse.h - numbers in text that is not NUL-terminated, for the mesh
 * readers (ply.c, obj.c): a token is a pointer and a length inside the file
 * buffer, and nothing here reads past it.
 *
 * num_parse_double gives exactly what strtod gives for the whole token (one
 * rounding, no approximation), only faster in the common case.
 */
#ifndef VB_NUMPARSE_H
#define VB_NUMPARSE_H

#include <stddef.h>
#include <stdint.h>

/* White space other than '\n' (lines matter to the text formats). Inline:
 * the readers call these once per byte. */
static inline int num_is_blank(unsigned char ch)
{
    return ch == ' ' || ch == '\t' || ch == '\r' || ch == '\v' || ch == '\f';
}

static inline int num_is_digit(unsigned char ch)
{
    return (unsigned)(ch - '0') < 10u;
}

/* The whole token s[0..len) as a decimal integer: optional sign, digits
 * only, within int64_t. 0 and *out set, or -1 (empty, bad char, overflow). */
int num_parse_int(const char *s, size_t len, int64_t *out);

/* The whole token s[0..len) as a double, bit-identical to strtod on a
 * NUL-terminated copy (so "nan", "inf" and hex floats are accepted too).
 * 0 and *out set, or -1 when strtod would not consume the whole token, or
 * the token is empty, or it needs strtod and is 128 characters or more. */
int num_parse_double(const char *s, size_t len, double *out);

#endif
