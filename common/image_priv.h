/* image_priv.h - what the image container (image.c) shares with its file
 * formats (exr.c, png.c); not for use outside those files.
 */
#ifndef VB_IMAGE_PRIV_H
#define VB_IMAGE_PRIV_H

#include <stddef.h>

#include "image.h"

/* Limits from image.h: a side up to 65536, at most 2^28 pixels. */
#define IMAGE_MAX_SIDE 65536
#define IMAGE_MAX_PIXELS (1LL << 28)

/* printf into the caller's message buffer; nothing when err is NULL or
 * errlen is 0. */
__attribute__((format(printf, 3, 4))) void image_set_err(char *err, size_t errlen, const char *fmt,
                                                         ...);

#endif
