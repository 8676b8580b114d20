/* image.h - float images with named channels, written and read as OpenEXR
 * (through the OpenEXR 3 C API, openexr.h) and written as a PNG preview.
 *
 * An image is width x height pixels, row 0 at the top, each channel a
 * separate float plane. EXR files carry float32 channels (scanline, ZIP
 * compression) and typed header attributes; vbrender writes R, G, B (linear
 * radiance), "samples" and "variance", plus attributes such as vb.seed.
 */
#ifndef VB_IMAGE_H
#define VB_IMAGE_H

#include <stddef.h>
#include <stdint.h>

#define IMAGE_MAX_CHANNELS 16
#define IMAGE_MAX_ATTRS 32
#define IMAGE_NAME_LEN 64
#define IMAGE_STRING_LEN 256

typedef enum { IMAGE_ATTR_STRING, IMAGE_ATTR_INT, IMAGE_ATTR_DOUBLE } image_attr_type_t;

typedef struct image_attr {
    char name[IMAGE_NAME_LEN];
    image_attr_type_t type;
    char s[IMAGE_STRING_LEN];
    int32_t i;
    double d;
} image_attr_t;

typedef struct image {
    int width, height;
    int channel_count;
    char channel_names[IMAGE_MAX_CHANNELS][IMAGE_NAME_LEN];
    float *channels[IMAGE_MAX_CHANNELS]; /* each width*height floats, owned */
    int attr_count;
    image_attr_t attrs[IMAGE_MAX_ATTRS];
} image_t;

/* A new image with no channels; NULL on bad size or out of memory.
 * Sizes up to 65536 x 65536 with at most 2^28 pixels are accepted. */
image_t *image_new(int width, int height);
/* Frees the image and sets *img to NULL; accepts NULL. */
void image_destroy(image_t **img);

/* Adds a zero-filled channel and returns its plane (owned by the image),
 * or NULL if the name is empty, too long, already present, or the channel
 * table is full, or out of memory. */
float *image_add_channel(image_t *img, const char *name);
/* The plane of a named channel, or NULL. */
float *image_channel(const image_t *img, const char *name);

/* Header attributes; setting a name again replaces it. Return 0, or -1 when
 * the name or value is too long or the table is full. */
int image_set_string(image_t *img, const char *name, const char *value);
int image_set_int(image_t *img, const char *name, int32_t value);
int image_set_double(image_t *img, const char *name, double value);
/* The attribute with that name, or NULL. */
const image_attr_t *image_attr(const image_t *img, const char *name);

/* Writes every channel as float32, and every attribute, to an EXR file.
 * The file appears atomically (written to a temporary name, then renamed).
 * Returns 0, or -1 with a message naming the path in err. */
int image_write_exr(const image_t *img, const char *path, char *err, size_t errlen);

/* Reads an EXR file (scanline or tiled, any compression the library reads;
 * half, float or uint channels become float). Standard attributes are
 * skipped; string, int, float and double attributes are kept (float as
 * double). Returns 0 with *out set, or -1 with a message in err.
 * Details: only the first part of a multi-part file and the full-resolution
 * level of a tiled one are read; deep and subsampled channels are refused;
 * the data window's origin is dropped (pixel (0,0) is its top-left corner);
 * the structural attributes tiles/name/type/version/chunkCount count as
 * standard; attributes whose name or value does not fit image_attr_t, or
 * beyond IMAGE_MAX_ATTRS, are skipped rather than failing the read. */
int image_read_exr(const char *path, image_t **out, char *err, size_t errlen);

/* The same from a file held in memory (a job bundle's); name is used in
 * messages. */
int image_read_exr_buffer(const char *name, const unsigned char *data, size_t size, image_t **out,
                          char *err, size_t errlen);
/* The same, refusing an image of more than max_pixels pixels before any
 * of it is allocated (a bitmap texture's cap). */
int image_read_exr_buffer_capped(const char *name, const unsigned char *data, size_t size,
                                 long long max_pixels, image_t **out, char *err, size_t errlen);

/* Writes an 8-bit sRGB PNG of channels R, G, B (clamped to [0, 1] after the
 * sRGB transfer curve, scaled by exposure first). -1 with a message when the
 * image lacks R, G or B, or on I/O failure. Like the EXR writer, both PNG
 * writers replace path atomically (temporary name, then rename). */
int image_write_png(const image_t *img, const char *path, float exposure, char *err, size_t errlen);

/* Writes a PNG of one channel mapped through a colour ramp (black - blue -
 * red - yellow - white) from lo to hi, for sample-count heat maps. */
int image_write_heatmap_png(const image_t *img, const char *channel, float lo, float hi,
                            const char *path, char *err, size_t errlen);

/* The pixel maps of the two PNG writers, for images encoded elsewhere (the
 * dashboard's previews): a linear value as the 8-bit sRGB byte
 * image_write_png stores (clamped to [0, 1] first; NaN gives 0), and the
 * heat-map colour of t in [0, 1] (clamped) as image_write_heatmap_png
 * gives it. */
unsigned char image_srgb_byte(double linear);
void image_heat_rgb(double t, unsigned char rgb[3]);

#endif
