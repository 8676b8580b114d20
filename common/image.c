/* image.c - float images with named channels: OpenEXR output and input
 * through the OpenEXR 3 C API (OpenEXRCore), and 8-bit PNG previews (sRGB
 * and heat map) through libpng. See image.h for the contract.
 *
 * Every file is written to "<path>.tmp.<pid>" and renamed over <path> only
 * once it is complete and synced, so a reader never sees half a file and a
 * failed write leaves any previous file in place. Library messages are
 * routed into the caller's err buffer (no stderr, no global state).
 */
#include "image.h"

#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <math.h>
#include <png.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <openexr.h>

/* Limits from image.h: a side up to 65536, at most 2^28 pixels. */
#define IMAGE_MAX_SIDE 65536
#define IMAGE_MAX_PIXELS (1LL << 28)

/* EXR names longer than this need the "long names" header flag, which
 * older readers reject, so it is only switched on when needed. */
#define EXR_SHORT_NAME_MAX 31

static void set_err(char *err, size_t errlen, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

static void set_err(char *err, size_t errlen, const char *fmt, ...)
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

/* ------------------------------------------------------------------ */
/* Atomic file replacement                                             */

/* "<path>.tmp.<pid>"; -1 when the name does not fit. */
static int tmp_name(char *buf, size_t len, const char *path)
{
    int n = snprintf(buf, len, "%s.tmp.%ld", path, (long)getpid());
    return (n < 0 || (size_t)n >= len) ? -1 : 0;
}

/* Makes the finished temporary file durable and moves it over path. The
 * fd is closed in every case; the temporary is removed on failure. */
static int commit_tmp(int fd, const char *tmp, const char *path, char *err, size_t errlen)
{
    /* fsync before rename: otherwise a crash can leave the new name
     * pointing at an empty file on some file systems. */
    if (fsync(fd) != 0 && errno != EINVAL && errno != EROFS) {
        set_err(err, errlen, "%s: cannot sync: %s", path, strerror(errno));
        close(fd);
        unlink(tmp);
        return -1;
    }
    if (close(fd) != 0) {
        set_err(err, errlen, "%s: cannot close: %s", path, strerror(errno));
        unlink(tmp);
        return -1;
    }
    if (rename(tmp, path) != 0) {
        set_err(err, errlen, "%s: cannot rename %s into place: %s", path, tmp, strerror(errno));
        unlink(tmp);
        return -1;
    }
    return 0;
}

/* ------------------------------------------------------------------ */
/* OpenEXR                                                             */

/* Per-call state reached from the library's callbacks through the context
 * user_data: the first error message (the root cause; later ones tend to
 * be generic follow-ups) and, when writing, our file descriptor. */
typedef struct exr_io {
    char msg[512];
    int have_msg;
    int fd;
} exr_io_t;

static void exr_error_cb(exr_const_context_t ctxt, exr_result_t code, const char *msg)
{
    void *ud = NULL;
    if (exr_get_user_data(ctxt, &ud) != EXR_ERR_SUCCESS || !ud)
        return;
    exr_io_t *io = ud;
    if (io->have_msg)
        return;
    snprintf(io->msg, sizeof io->msg, "%s", msg ? msg : exr_get_default_error_message(code));
    io->have_msg = 1;
}

/* The library's message for a failed call, else its generic text. */
static const char *exr_why(const exr_io_t *io, exr_result_t rv)
{
    return io->have_msg ? io->msg : exr_get_default_error_message(rv);
}

/* Custom writer: the library would open the file itself, but then we
 * could neither report open errors with errno nor fsync before rename. */
static int64_t exr_write_cb(exr_const_context_t ctxt, void *userdata, const void *buffer,
                            uint64_t sz, uint64_t offset, exr_stream_error_func_ptr_t error_cb)
{
    exr_io_t *io = userdata;
    const unsigned char *p = buffer;
    uint64_t done = 0;
    if (offset > (uint64_t)INT64_MAX - sz) {
        error_cb(ctxt, EXR_ERR_WRITE_IO, "write offset out of range");
        return -1;
    }
    while (done < sz) {
        size_t want = (size_t)(sz - done);
        ssize_t n = pwrite(io->fd, p + done, want, (off_t)(offset + done));
        if (n < 0) {
            if (errno == EINTR)
                continue;
            error_cb(ctxt, EXR_ERR_WRITE_IO, "write failed: %s", strerror(errno));
            return -1;
        }
        if (n == 0) {
            error_cb(ctxt, EXR_ERR_WRITE_IO, "write failed: no space written");
            return -1;
        }
        done += (uint64_t)n;
    }
    return (int64_t)done;
}

/* OpenEXRCore 3.1.5 keeps the compressed form of a chunk when it is exactly
 * as large as the raw form, but readers (this library included) take
 * "packed size == unpacked size" to mean "stored raw" and then decode zlib
 * bytes as pixels. Tiny images hit this (a 2x2 float channel compresses to
 * 16 bytes). This hook runs the library's compressor, then stores the raw
 * bytes whenever compression did not actually shrink the chunk. */
typedef struct compress_hook {
    exr_result_t (*orig)(exr_encode_pipeline_t *enc);
} compress_hook_t;

static exr_result_t exr_compress_or_raw(exr_encode_pipeline_t *enc)
{
    const compress_hook_t *hook = enc->encoding_user_data;
    exr_result_t rv = hook->orig(enc);
    if (rv != EXR_ERR_SUCCESS || enc->compressed_bytes < enc->packed_bytes)
        return rv;
    if (!enc->compressed_buffer || enc->compressed_buffer == enc->packed_buffer)
        return rv; /* already raw */
    if (enc->compressed_alloc_size < enc->packed_bytes)
        return EXR_ERR_OUT_OF_MEMORY;
    memcpy(enc->compressed_buffer, enc->packed_buffer, (size_t)enc->packed_bytes);
    enc->compressed_bytes = (size_t)enc->packed_bytes;
    return EXR_ERR_SUCCESS;
}

/* Encodes all channels of img into the part, one chunk of scanlines at a
 * time. The library stores channels sorted by name, so each encoder
 * channel is matched to our plane by name, not by position. */
static int exr_write_pixels(exr_context_t ctx, int part, const image_t *img, exr_io_t *io,
                            const char *path, char *err, size_t errlen)
{
    int32_t lines = 0;
    exr_result_t rv = exr_get_scanlines_per_chunk(ctx, part, &lines);
    if (rv != EXR_ERR_SUCCESS || lines <= 0) {
        set_err(err, errlen, "%s: cannot query chunk size: %s", path, exr_why(io, rv));
        return -1;
    }
    exr_encode_pipeline_t enc = EXR_ENCODE_PIPELINE_INITIALIZER;
    compress_hook_t hook = {NULL};
    int inited = 0, ret = 0;
    const size_t w = (size_t)img->width;
    for (int y = 0; y < img->height; y += lines) {
        exr_chunk_info_t cinfo;
        rv = exr_write_scanline_chunk_info(ctx, part, y, &cinfo);
        if (rv == EXR_ERR_SUCCESS) {
            if (!inited) {
                rv = exr_encoding_initialize(ctx, part, &cinfo, &enc);
                inited = rv == EXR_ERR_SUCCESS;
            } else {
                rv = exr_encoding_update(ctx, part, &cinfo, &enc);
            }
        }
        if (rv != EXR_ERR_SUCCESS) {
            set_err(err, errlen, "%s: cannot prepare scanlines at y=%d: %s", path, y,
                    exr_why(io, rv));
            ret = -1;
            break;
        }
        for (int c = 0; c < enc.channel_count; c++) {
            exr_coding_channel_info_t *ch = &enc.channels[c];
            int k = channel_index(img, ch->channel_name);
            if (k < 0) { /* cannot happen: we declared exactly these */
                set_err(err, errlen, "%s: library returned unknown channel %s", path,
                        ch->channel_name);
                ret = -1;
                break;
            }
            ch->encode_from_ptr = (const uint8_t *)(img->channels[k] + (size_t)y * w);
            ch->user_pixel_stride = (int32_t)sizeof(float);
            ch->user_line_stride = (int32_t)(w * sizeof(float));
            ch->user_bytes_per_element = (int16_t)sizeof(float);
            ch->user_data_type = EXR_PIXEL_FLOAT;
        }
        if (ret != 0)
            break;
        rv = exr_encoding_choose_default_routines(ctx, part, &enc);
        if (rv == EXR_ERR_SUCCESS && enc.compress_fn) {
            hook.orig = enc.compress_fn;
            enc.compress_fn = exr_compress_or_raw;
            enc.encoding_user_data = &hook;
        }
        if (rv == EXR_ERR_SUCCESS)
            rv = exr_encoding_run(ctx, part, &enc);
        if (rv != EXR_ERR_SUCCESS) {
            set_err(err, errlen, "%s: cannot write scanlines at y=%d: %s", path, y,
                    exr_why(io, rv));
            ret = -1;
            break;
        }
    }
    if (inited)
        exr_encoding_destroy(ctx, &enc);
    return ret;
}

/* Defines the part (size, ZIP, channels, attributes) and writes it. */
static int exr_write_ctx(exr_context_t ctx, const image_t *img, exr_io_t *io, const char *path,
                         char *err, size_t errlen)
{
    int part = 0;
    exr_result_t rv = exr_add_part(ctx, NULL, EXR_STORAGE_SCANLINE, &part);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_initialize_required_attr_simple(ctx, part, img->width, img->height,
                                                 EXR_COMPRESSION_ZIP);
    if (rv != EXR_ERR_SUCCESS) {
        set_err(err, errlen, "%s: cannot set up header: %s", path, exr_why(io, rv));
        return -1;
    }
    int long_names = 0;
    for (int c = 0; c < img->channel_count; c++)
        long_names |= strlen(img->channel_names[c]) > EXR_SHORT_NAME_MAX;
    for (int a = 0; a < img->attr_count; a++)
        long_names |= strlen(img->attrs[a].name) > EXR_SHORT_NAME_MAX;
    if (long_names && (rv = exr_set_longname_support(ctx, 1)) != EXR_ERR_SUCCESS) {
        set_err(err, errlen, "%s: cannot enable long names: %s", path, exr_why(io, rv));
        return -1;
    }
    for (int c = 0; c < img->channel_count; c++) {
        /* Perceptual treatment only steers lossy codecs; ZIP ignores it. */
        rv = exr_add_channel(ctx, part, img->channel_names[c], EXR_PIXEL_FLOAT,
                             EXR_PERCEPTUALLY_LOGARITHMIC, 1, 1);
        if (rv != EXR_ERR_SUCCESS) {
            set_err(err, errlen, "%s: cannot add channel %s: %s", path, img->channel_names[c],
                    exr_why(io, rv));
            return -1;
        }
    }
    for (int a = 0; a < img->attr_count; a++) {
        const image_attr_t *at = &img->attrs[a];
        switch (at->type) {
        case IMAGE_ATTR_STRING:
            rv = exr_attr_set_string(ctx, part, at->name, at->s);
            break;
        case IMAGE_ATTR_INT:
            rv = exr_attr_set_int(ctx, part, at->name, at->i);
            break;
        case IMAGE_ATTR_DOUBLE:
            rv = exr_attr_set_double(ctx, part, at->name, at->d);
            break;
        default:
            rv = EXR_ERR_INVALID_ARGUMENT;
            break;
        }
        if (rv != EXR_ERR_SUCCESS) {
            set_err(err, errlen, "%s: cannot set attribute %s: %s", path, at->name,
                    exr_why(io, rv));
            return -1;
        }
    }
    rv = exr_write_header(ctx);
    if (rv != EXR_ERR_SUCCESS) {
        set_err(err, errlen, "%s: cannot write header: %s", path, exr_why(io, rv));
        return -1;
    }
    return exr_write_pixels(ctx, part, img, io, path, err, errlen);
}

int image_write_exr(const image_t *img, const char *path, char *err, size_t errlen)
{
    if (!path || !path[0]) {
        set_err(err, errlen, "(no path): cannot write EXR: empty path");
        return -1;
    }
    if (!img || img->channel_count <= 0) {
        set_err(err, errlen, "%s: cannot write EXR: image has no channels", path);
        return -1;
    }
    char tmp[PATH_MAX];
    if (tmp_name(tmp, sizeof tmp, path) != 0) {
        set_err(err, errlen, "%s: cannot open for writing: path too long", path);
        return -1;
    }
    exr_io_t io;
    memset(&io, 0, sizeof io);
    io.fd = open(tmp, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0666);
    if (io.fd < 0) {
        set_err(err, errlen, "%s: cannot open for writing: %s", path, strerror(errno));
        return -1;
    }

    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    init.error_handler_fn = exr_error_cb;
    init.user_data = &io;
    init.write_fn = exr_write_cb;

    exr_context_t ctx = NULL;
    exr_result_t rv = exr_start_write(&ctx, path, EXR_WRITE_FILE_DIRECTLY, &init);
    int ret;
    if (rv != EXR_ERR_SUCCESS) {
        set_err(err, errlen, "%s: cannot start EXR write: %s", path, exr_why(&io, rv));
        ret = -1;
    } else {
        ret = exr_write_ctx(ctx, img, &io, path, err, errlen);
    }
    if (ctx) {
        /* exr_finish writes the chunk offset table, so it can fail too. */
        rv = exr_finish(&ctx);
        if (ret == 0 && rv != EXR_ERR_SUCCESS) {
            set_err(err, errlen, "%s: cannot finish EXR: %s", path, exr_why(&io, rv));
            ret = -1;
        }
    }
    if (ret != 0) {
        close(io.fd);
        unlink(tmp);
        return -1;
    }
    return commit_tmp(io.fd, tmp, path, err, errlen);
}

/* Header attributes that describe the layout rather than the content;
 * image_read_exr does not hand them back. */
static int exr_standard_attr(const char *name)
{
    static const char *const std_names[] = {
        "channels",
        "compression",
        "dataWindow",
        "displayWindow",
        "lineOrder",
        "pixelAspectRatio",
        "screenWindowCenter",
        "screenWindowWidth",
        /* multi-part / tiled structure */
        "tiles",
        "name",
        "type",
        "version",
        "chunkCount",
    };
    for (size_t k = 0; k < sizeof std_names / sizeof std_names[0]; k++)
        if (strcmp(name, std_names[k]) == 0)
            return 1;
    return 0;
}

/* Copies the string/int/float/double attributes of the part. Attributes
 * whose name or value does not fit image_attr_t, or beyond the table
 * size, are skipped rather than failing the read of an otherwise good
 * file. */
static int exr_read_attrs(exr_context_t ctx, int part, image_t *img, exr_io_t *io, const char *path,
                          char *err, size_t errlen)
{
    int32_t count = 0;
    exr_result_t rv = exr_get_attribute_count(ctx, part, &count);
    if (rv != EXR_ERR_SUCCESS) {
        set_err(err, errlen, "%s: cannot list attributes: %s", path, exr_why(io, rv));
        return -1;
    }
    for (int32_t k = 0; k < count; k++) {
        const exr_attribute_t *a = NULL;
        rv = exr_get_attribute_by_index(ctx, part, EXR_ATTR_LIST_FILE_ORDER, k, &a);
        if (rv != EXR_ERR_SUCCESS || !a) {
            set_err(err, errlen, "%s: cannot read attribute %d: %s", path, (int)k, exr_why(io, rv));
            return -1;
        }
        if (!a->name || exr_standard_attr(a->name))
            continue;
        switch (a->type) {
        case EXR_ATTR_STRING: {
            if (!a->string || a->string->length < 0 || a->string->length >= IMAGE_STRING_LEN)
                break;
            char s[IMAGE_STRING_LEN];
            if (a->string->length > 0)
                memcpy(s, a->string->str, (size_t)a->string->length);
            s[a->string->length] = '\0';
            image_set_string(img, a->name, s);
            break;
        }
        case EXR_ATTR_INT:
            image_set_int(img, a->name, a->i);
            break;
        case EXR_ATTR_FLOAT:
            image_set_double(img, a->name, (double)a->f);
            break;
        case EXR_ATTR_DOUBLE:
            image_set_double(img, a->name, a->d);
            break;
        default:
            break;
        }
    }
    return 0;
}

/* Decodes one chunk whose top-left pixel is (x0, y0) in image coordinates
 * into the float planes. Setting the user type to FLOAT makes the library
 * convert HALF and UINT samples for us. */
static int exr_decode_chunk(exr_context_t ctx, int part, const exr_chunk_info_t *cinfo, int x0,
                            int y0, exr_decode_pipeline_t *dec, int *inited, image_t *img,
                            exr_io_t *io, const char *path, char *err, size_t errlen)
{
    if (x0 < 0 || y0 < 0 || cinfo->width <= 0 || cinfo->height <= 0 ||
        cinfo->width > img->width - x0 || cinfo->height > img->height - y0) {
        set_err(err, errlen, "%s: chunk at (%d,%d) lies outside the data window", path, x0, y0);
        return -1;
    }
    exr_result_t rv;
    if (!*inited) {
        rv = exr_decoding_initialize(ctx, part, cinfo, dec);
        *inited = rv == EXR_ERR_SUCCESS;
    } else {
        rv = exr_decoding_update(ctx, part, cinfo, dec);
    }
    if (rv != EXR_ERR_SUCCESS) {
        set_err(err, errlen, "%s: cannot decode chunk at (%d,%d): %s", path, x0, y0,
                exr_why(io, rv));
        return -1;
    }
    const size_t w = (size_t)img->width;
    for (int c = 0; c < dec->channel_count; c++) {
        exr_coding_channel_info_t *ch = &dec->channels[c];
        int k = channel_index(img, ch->channel_name);
        if (k < 0 || ch->width != cinfo->width || ch->height != cinfo->height) {
            set_err(err, errlen, "%s: unexpected layout of channel %s", path,
                    ch->channel_name ? ch->channel_name : "?");
            return -1;
        }
        ch->decode_to_ptr = (uint8_t *)(img->channels[k] + (size_t)y0 * w + (size_t)x0);
        ch->user_pixel_stride = (int32_t)sizeof(float);
        ch->user_line_stride = (int32_t)(w * sizeof(float));
        ch->user_bytes_per_element = (int16_t)sizeof(float);
        ch->user_data_type = EXR_PIXEL_FLOAT;
    }
    rv = exr_decoding_choose_default_routines(ctx, part, dec);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_decoding_run(ctx, part, dec);
    if (rv != EXR_ERR_SUCCESS) {
        set_err(err, errlen, "%s: cannot decode chunk at (%d,%d): %s", path, x0, y0,
                exr_why(io, rv));
        return -1;
    }
    return 0;
}

static int exr_read_pixels(exr_context_t ctx, int part, exr_storage_t storage,
                           const exr_attr_box2i_t *dw, image_t *img, exr_io_t *io, const char *path,
                           char *err, size_t errlen)
{
    exr_decode_pipeline_t dec = EXR_DECODE_PIPELINE_INITIALIZER;
    int inited = 0, ret = 0;
    exr_result_t rv;
    if (storage == EXR_STORAGE_SCANLINE) {
        int32_t lines = 0;
        rv = exr_get_scanlines_per_chunk(ctx, part, &lines);
        if (rv != EXR_ERR_SUCCESS || lines <= 0) {
            set_err(err, errlen, "%s: cannot query chunk size: %s", path, exr_why(io, rv));
            return -1;
        }
        /* Chunks start at dataWindow.min.y and every `lines` rows after. */
        for (int row = 0; row < img->height && ret == 0; row += lines) {
            exr_chunk_info_t cinfo;
            rv = exr_read_scanline_chunk_info(ctx, part, dw->min.y + row, &cinfo);
            if (rv != EXR_ERR_SUCCESS) {
                set_err(err, errlen, "%s: cannot read scanlines at y=%d: %s", path, dw->min.y + row,
                        exr_why(io, rv));
                ret = -1;
                break;
            }
            ret = exr_decode_chunk(ctx, part, &cinfo, 0, cinfo.start_y - dw->min.y, &dec, &inited,
                                   img, io, path, err, errlen);
        }
    } else {
        /* Tiled: level (0,0) is the full-resolution image; mip/rip levels
         * below it are ignored. */
        uint32_t tw = 0, th = 0;
        exr_tile_level_mode_t lmode;
        exr_tile_round_mode_t rmode;
        rv = exr_get_tile_descriptor(ctx, part, &tw, &th, &lmode, &rmode);
        if (rv != EXR_ERR_SUCCESS || tw == 0 || th == 0) {
            set_err(err, errlen, "%s: cannot read tile description: %s", path, exr_why(io, rv));
            return -1;
        }
        int tiles_x = (int)(((uint64_t)img->width + tw - 1) / tw);
        int tiles_y = (int)(((uint64_t)img->height + th - 1) / th);
        for (int ty = 0; ty < tiles_y && ret == 0; ty++) {
            for (int tx = 0; tx < tiles_x && ret == 0; tx++) {
                exr_chunk_info_t cinfo;
                rv = exr_read_tile_chunk_info(ctx, part, tx, ty, 0, 0, &cinfo);
                if (rv != EXR_ERR_SUCCESS) {
                    set_err(err, errlen, "%s: cannot read tile (%d,%d): %s", path, tx, ty,
                            exr_why(io, rv));
                    ret = -1;
                    break;
                }
                ret = exr_decode_chunk(ctx, part, &cinfo, (int)((uint64_t)tx * tw),
                                       (int)((uint64_t)ty * th), &dec, &inited, img, io, path, err,
                                       errlen);
            }
        }
    }
    if (inited)
        exr_decoding_destroy(ctx, &dec);
    return ret;
}

/* Reads part 0 of an open context into a new image. */
static int exr_read_ctx(exr_context_t ctx, image_t **out, exr_io_t *io, const char *path, char *err,
                        size_t errlen)
{
    const int part = 0;
    exr_storage_t storage;
    exr_result_t rv = exr_get_storage(ctx, part, &storage);
    if (rv != EXR_ERR_SUCCESS) {
        set_err(err, errlen, "%s: cannot read storage type: %s", path, exr_why(io, rv));
        return -1;
    }
    if (storage == EXR_STORAGE_DEEP_SCANLINE || storage == EXR_STORAGE_DEEP_TILED) {
        set_err(err, errlen, "%s: deep EXR not supported", path);
        return -1;
    }
    if (storage != EXR_STORAGE_SCANLINE && storage != EXR_STORAGE_TILED) {
        set_err(err, errlen, "%s: unknown EXR storage type %d", path, (int)storage);
        return -1;
    }
    exr_attr_box2i_t dw;
    rv = exr_get_data_window(ctx, part, &dw);
    if (rv != EXR_ERR_SUCCESS) {
        set_err(err, errlen, "%s: cannot read data window: %s", path, exr_why(io, rv));
        return -1;
    }
    long long w = (long long)dw.max.x - dw.min.x + 1;
    long long h = (long long)dw.max.y - dw.min.y + 1;
    if (w <= 0 || h <= 0 || w > IMAGE_MAX_SIDE || h > IMAGE_MAX_SIDE || w * h > IMAGE_MAX_PIXELS) {
        set_err(err, errlen, "%s: unsupported image size %lldx%lld", path, w, h);
        return -1;
    }
    const exr_attr_chlist_t *chl = NULL;
    rv = exr_get_channels(ctx, part, &chl);
    if (rv != EXR_ERR_SUCCESS || !chl) {
        set_err(err, errlen, "%s: cannot read channel list: %s", path, exr_why(io, rv));
        return -1;
    }
    if (chl->num_channels > IMAGE_MAX_CHANNELS) {
        set_err(err, errlen, "%s: %d channels, at most %d supported", path, chl->num_channels,
                IMAGE_MAX_CHANNELS);
        return -1;
    }
    image_t *img = image_new((int)w, (int)h);
    if (!img) {
        set_err(err, errlen, "%s: out of memory", path);
        return -1;
    }
    for (int c = 0; c < chl->num_channels; c++) {
        const exr_attr_chlist_entry_t *e = &chl->entries[c];
        const char *name = e->name.str ? e->name.str : "";
        if (e->x_sampling != 1 || e->y_sampling != 1) {
            set_err(err, errlen, "%s: channel %s is subsampled (not supported)", path, name);
            image_destroy(&img);
            return -1;
        }
        if (e->pixel_type != EXR_PIXEL_UINT && e->pixel_type != EXR_PIXEL_HALF &&
            e->pixel_type != EXR_PIXEL_FLOAT) {
            set_err(err, errlen, "%s: channel %s has unknown pixel type", path, name);
            image_destroy(&img);
            return -1;
        }
        if (!image_add_channel(img, name)) {
            set_err(err, errlen,
                    "%s: cannot add channel \"%s\" (bad or duplicate name, "
                    "or out of memory)",
                    path, name);
            image_destroy(&img);
            return -1;
        }
    }
    if (exr_read_attrs(ctx, part, img, io, path, err, errlen) != 0 ||
        exr_read_pixels(ctx, part, storage, &dw, img, io, path, err, errlen) != 0) {
        image_destroy(&img);
        return -1;
    }
    *out = img;
    return 0;
}

int image_read_exr(const char *path, image_t **out, char *err, size_t errlen)
{
    if (out)
        *out = NULL;
    if (!path || !path[0] || !out) {
        set_err(err, errlen, "%s: cannot read EXR: bad arguments", path ? path : "(null)");
        return -1;
    }
    /* Check access and the magic number ourselves: the library's messages
     * for these common cases are less direct than errno and "not an
     * OpenEXR file". */
    FILE *f = fopen(path, "rb");
    if (!f) {
        set_err(err, errlen, "%s: cannot open: %s", path, strerror(errno));
        return -1;
    }
    unsigned char magic[4];
    size_t got = fread(magic, 1, sizeof magic, f);
    if (got != sizeof magic && ferror(f)) { /* e.g. EISDIR */
        set_err(err, errlen, "%s: cannot read: %s", path, strerror(errno));
        fclose(f);
        return -1;
    }
    fclose(f);
    static const unsigned char exr_magic[4] = {0x76, 0x2f, 0x31, 0x01};
    if (got != sizeof magic || memcmp(magic, exr_magic, sizeof magic) != 0) {
        set_err(err, errlen, "%s: not an OpenEXR file", path);
        return -1;
    }

    exr_io_t io;
    memset(&io, 0, sizeof io);
    io.fd = -1;
    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    init.error_handler_fn = exr_error_cb;
    init.user_data = &io;
    /* A damaged chunk table is an error, not something to guess around:
     * reconstruction could hand back a partly filled image as success. */
    init.flags = EXR_CONTEXT_FLAG_DISABLE_CHUNK_RECONSTRUCTION;

    exr_context_t ctx = NULL;
    exr_result_t rv = exr_start_read(&ctx, path, &init);
    int ret;
    if (rv != EXR_ERR_SUCCESS) {
        set_err(err, errlen, "%s: cannot read EXR header: %s", path, exr_why(&io, rv));
        ret = -1;
    } else {
        ret = exr_read_ctx(ctx, out, &io, path, err, errlen);
    }
    if (ctx)
        exr_finish(&ctx);
    return ret;
}

/* ------------------------------------------------------------------ */
/* PNG                                                                 */

/* libpng reports errors through a callback that must not return; we
 * keep its message and jump back to the setjmp in png_encode. */
typedef struct png_msg {
    char text[256];
} png_msg_t;

static void png_error_cb(png_structp png, png_const_charp msg)
{
    png_msg_t *m = png_get_error_ptr(png);
    if (m)
        snprintf(m->text, sizeof m->text, "%s", msg ? msg : "libpng error");
    png_longjmp(png, 1);
}

static void png_warning_cb(png_structp png, png_const_charp msg)
{
    (void)png; /* warnings are not errors; keep them off stderr */
    (void)msg;
}

/* Encodes w x h packed RGB8 pixels to f. Everything allocated here is
 * created before setjmp and not reassigned afterwards, so its value is
 * well defined after a longjmp; `volatile` keeps that true if this
 * function is ever changed. */
static int png_encode(FILE *f, int w, int h, const unsigned char *rgb, png_msg_t *m)
{
    png_structp volatile png =
        png_create_write_struct(PNG_LIBPNG_VER_STRING, m, png_error_cb, png_warning_cb);
    if (!png) {
        snprintf(m->text, sizeof m->text, "out of memory");
        return -1;
    }
    png_infop volatile info = png_create_info_struct(png);
    if (!info) {
        png_structp p = png;
        png_destroy_write_struct(&p, NULL);
        snprintf(m->text, sizeof m->text, "out of memory");
        return -1;
    }
    if (setjmp(png_jmpbuf(png))) {
        png_structp p = png;
        png_infop i = info;
        png_destroy_write_struct(&p, &i);
        return -1;
    }
    png_init_io(png, f);
    png_set_IHDR(png, info, (png_uint_32)w, (png_uint_32)h, 8, PNG_COLOR_TYPE_RGB,
                 PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    png_set_sRGB(png, info, PNG_sRGB_INTENT_PERCEPTUAL);
    png_write_info(png, info);
    for (int y = 0; y < h; y++)
        png_write_row(png, rgb + (size_t)y * (size_t)w * 3);
    png_write_end(png, info);
    png_structp p = png;
    png_infop i = info;
    png_destroy_write_struct(&p, &i);
    return 0;
}

/* Writes packed RGB8 pixels to path through a temporary file. */
static int png_write_file(const char *path, int w, int h, const unsigned char *rgb, char *err,
                          size_t errlen)
{
    char tmp[PATH_MAX];
    if (tmp_name(tmp, sizeof tmp, path) != 0) {
        set_err(err, errlen, "%s: cannot open for writing: path too long", path);
        return -1;
    }
    int fd = open(tmp, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0666);
    if (fd < 0) {
        set_err(err, errlen, "%s: cannot open for writing: %s", path, strerror(errno));
        return -1;
    }
    /* A separate descriptor for stdio, so fclose flushes without closing
     * the one we still need for fsync. */
    int fd2 = dup(fd);
    FILE *f = fd2 >= 0 ? fdopen(fd2, "wb") : NULL;
    if (!f) {
        set_err(err, errlen, "%s: cannot open for writing: %s", path, strerror(errno));
        if (fd2 >= 0)
            close(fd2);
        close(fd);
        unlink(tmp);
        return -1;
    }
    png_msg_t m;
    memset(&m, 0, sizeof m);
    int rc = png_encode(f, w, h, rgb, &m);
    if (rc != 0) {
        set_err(err, errlen, "%s: cannot write PNG: %s", path, m.text);
        fclose(f);
        close(fd);
        unlink(tmp);
        return -1;
    }
    if (fclose(f) != 0) {
        set_err(err, errlen, "%s: cannot write PNG: %s", path, strerror(errno));
        close(fd);
        unlink(tmp);
        return -1;
    }
    return commit_tmp(fd, tmp, path, err, errlen);
}

/* The sRGB OETF (IEC 61966-2-1), with the linear toe near black. */
static double srgb_encode(double v)
{
    return v <= 0.0031308 ? 12.92 * v : 1.055 * pow(v, 1.0 / 2.4) - 0.055;
}

static unsigned char to_byte(double v)
{
    if (!(v > 0.0)) /* also maps NaN to 0 */
        return 0;
    if (v >= 1.0)
        return 255;
    return (unsigned char)(v * 255.0 + 0.5);
}

unsigned char image_srgb_byte(double v)
{
    /* Clamp before the curve: pow() of a negative is NaN, and the curve
     * maps [0,1] onto [0,1], so this equals clamping after. */
    if (!(v > 0.0))
        v = 0.0;
    else if (v > 1.0)
        v = 1.0;
    return to_byte(srgb_encode(v));
}

/* Packed RGB8 buffer for the image, or NULL (with err set). */
static unsigned char *rgb_alloc(const image_t *img, const char *path, char *err, size_t errlen)
{
    unsigned char *rgb = malloc((size_t)img->width * (size_t)img->height * 3);
    if (!rgb)
        set_err(err, errlen, "%s: out of memory", path);
    return rgb;
}

int image_write_png(const image_t *img, const char *path, float exposure, char *err, size_t errlen)
{
    if (!img || !path || !path[0]) {
        set_err(err, errlen, "%s: cannot write PNG: bad arguments", path ? path : "(null)");
        return -1;
    }
    static const char *const names[3] = {"R", "G", "B"};
    const float *planes[3];
    for (int k = 0; k < 3; k++) {
        planes[k] = image_channel(img, names[k]);
        if (!planes[k]) {
            set_err(err, errlen, "%s: no channel %s", path, names[k]);
            return -1;
        }
    }
    unsigned char *rgb = rgb_alloc(img, path, err, errlen);
    if (!rgb)
        return -1;
    const size_t n = (size_t)img->width * (size_t)img->height;
    for (size_t p = 0; p < n; p++) {
        for (int k = 0; k < 3; k++) {
            double v = (double)planes[k][p] * (double)exposure;
            rgb[p * 3 + (size_t)k] = image_srgb_byte(v);
        }
    }
    int rc = png_write_file(path, img->width, img->height, rgb, err, errlen);
    free(rgb);
    return rc;
}

/* Black - blue - red - yellow - white at t = 0, 1/4, 1/2, 3/4, 1. */
static void heat_ramp(double t, double out[3])
{
    static const double stops[5][3] = {
        {0, 0, 0}, {0, 0, 1}, {1, 0, 0}, {1, 1, 0}, {1, 1, 1},
    };
    double s = t * 4.0;
    int i = (int)s;
    if (i >= 4) {
        i = 3;
    }
    double f = s - i;
    for (int k = 0; k < 3; k++)
        out[k] = stops[i][k] + (stops[i + 1][k] - stops[i][k]) * f;
}

void image_heat_rgb(double t, unsigned char rgb[3])
{
    if (!(t > 0.0)) /* also NaN */
        t = 0.0;
    else if (t > 1.0)
        t = 1.0;
    double c[3];
    heat_ramp(t, c);
    for (int k = 0; k < 3; k++)
        rgb[k] = to_byte(c[k]);
}

int image_write_heatmap_png(const image_t *img, const char *channel, float lo, float hi,
                            const char *path, char *err, size_t errlen)
{
    if (!img || !channel || !path || !path[0]) {
        set_err(err, errlen, "%s: cannot write PNG: bad arguments", path ? path : "(null)");
        return -1;
    }
    const float *plane = image_channel(img, channel);
    if (!plane) {
        set_err(err, errlen, "%s: no channel %s", path, channel);
        return -1;
    }
    unsigned char *rgb = rgb_alloc(img, path, err, errlen);
    if (!rgb)
        return -1;
    const double dlo = lo, range = (double)hi - (double)lo;
    const int usable = range > 0.0 && isfinite(range);
    const size_t n = (size_t)img->width * (size_t)img->height;
    for (size_t p = 0; p < n; p++) {
        double t = usable ? ((double)plane[p] - dlo) / range : 0.0;
        image_heat_rgb(t, rgb + p * 3);
    }
    int rc = png_write_file(path, img->width, img->height, rgb, err, errlen);
    free(rgb);
    return rc;
}
