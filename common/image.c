/* image.c - the image container: float planes with names, and typed
 * header attributes. See image.h for the contract. The file formats are
 * exr.c (OpenEXR in and out) and png.c (8-bit previews); both replace files
 * atomically through atomicfile.c.
 */
#include "image.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "image_priv.h"

void image_set_err(char *err, size_t errlen, const char *fmt, ...)
{
    if (!err || errlen == 0)
        return;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(err, errlen, fmt, ap);
    va_end(ap);
}

/* ------------------------------------------------------------------ */
/* Image and channel table                                             */

image_t *image_new(int width, int height)
{
    if (width <= 0 || height <= 0 || width > IMAGE_MAX_SIDE || height > IMAGE_MAX_SIDE)
        return NULL;
    if ((long long)width * height > IMAGE_MAX_PIXELS)
        return NULL;
    image_t *img = calloc(1, sizeof *img);
    if (!img)
        return NULL;
    img->width = width;
    img->height = height;
    return img;
}

void image_destroy(image_t **img)
{
    if (!img || !*img)
        return;
    for (int c = 0; c < (*img)->channel_count; c++)
        free((*img)->channels[c]);
    free(*img);
    *img = NULL;
}

static int channel_index(const image_t *img, const char *name)
{
    for (int c = 0; c < img->channel_count; c++)
        if (strcmp(img->channel_names[c], name) == 0)
            return c;
    return -1;
}

float *image_add_channel(image_t *img, const char *name)
{
    if (!img || !name || !name[0] || strlen(name) >= IMAGE_NAME_LEN)
        return NULL;
    if (img->channel_count >= IMAGE_MAX_CHANNELS || channel_index(img, name) >= 0)
        return NULL;
    float *plane = calloc((size_t)img->width * (size_t)img->height, sizeof *plane);
    if (!plane)
        return NULL;
    int c = img->channel_count++;
    memcpy(img->channel_names[c], name, strlen(name) + 1);
    img->channels[c] = plane;
    return plane;
}

float *image_channel(const image_t *img, const char *name)
{
    if (!img || !name)
        return NULL;
    int c = channel_index(img, name);
    return c < 0 ? NULL : img->channels[c];
}

/* ------------------------------------------------------------------ */
/* Attributes                                                          */

/* The slot for name: the existing one (to replace it) or a fresh one. */
static image_attr_t *attr_slot(image_t *img, const char *name)
{
    if (!img || !name || !name[0] || strlen(name) >= IMAGE_NAME_LEN)
        return NULL;
    for (int a = 0; a < img->attr_count; a++)
        if (strcmp(img->attrs[a].name, name) == 0)
            return &img->attrs[a];
    if (img->attr_count >= IMAGE_MAX_ATTRS)
        return NULL;
    image_attr_t *slot = &img->attrs[img->attr_count++];
    memset(slot, 0, sizeof *slot);
    memcpy(slot->name, name, strlen(name) + 1);
    return slot;
}

int image_set_string(image_t *img, const char *name, const char *value)
{
    if (!value || strlen(value) >= IMAGE_STRING_LEN)
        return -1;
    image_attr_t *a = attr_slot(img, name);
    if (!a)
        return -1;
    a->type = IMAGE_ATTR_STRING;
    memset(a->s, 0, sizeof a->s);
    memcpy(a->s, value, strlen(value) + 1);
    return 0;
}

int image_set_int(image_t *img, const char *name, int32_t value)
{
    image_attr_t *a = attr_slot(img, name);
    if (!a)
        return -1;
    a->type = IMAGE_ATTR_INT;
    a->i = value;
    return 0;
}

int image_set_double(image_t *img, const char *name, double value)
{
    image_attr_t *a = attr_slot(img, name);
    if (!a)
        return -1;
    a->type = IMAGE_ATTR_DOUBLE;
    a->d = value;
    return 0;
}

const image_attr_t *image_attr(const image_t *img, const char *name)
{
    if (!img || !name)
        return NULL;
    for (int a = 0; a < img->attr_count; a++)
        if (strcmp(img->attrs[a].name, name) == 0)
            return &img->attrs[a];
    return NULL;
}
