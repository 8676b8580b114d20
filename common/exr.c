/* exr.c - image_write_exr and image_read_exr (see image.h) through the
 * OpenEXR 3 C API (OpenEXRCore).
 *
 * Files are written through atomicfile.c: a reader never sees half a file.
 * Library messages are routed into the caller's err buffer (no stderr, no
 * global state).
 */
#include <errno.h>
#include <limits.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include <openexr.h>

#include "atomicfile.h"
#include "image.h"
#include "image_priv.h"
#include "vberr.h"

/* EXR names longer than this need the "long names" header flag, which
 * older readers reject, so it is only switched on when needed. */
#define EXR_SHORT_NAME_MAX 31

/* Per-call state reached from the library's callbacks through the context
 * user_data: the first error message (the root cause; later ones tend to
 * be generic follow-ups) and, when writing, our file descriptor. */
typedef struct exr_io {
    char msg[VB_ERR_LEN];
    int have_msg;
    int fd;
    const unsigned char *mem; /* image_read_exr_buffer: the file in memory */
    size_t mem_size;
    long long max_pixels; /* the most pixels to accept; 0: IMAGE_MAX_PIXELS */
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

/* Points each encoder channel at rows y.. of our plane of that name. */
static int exr_bind_rows(exr_encode_pipeline_t *enc, const image_t *img, int y, const char *path,
                         char *err, size_t errlen)
{
    const size_t w = (size_t)img->width;
    for (int c = 0; c < enc->channel_count; c++) {
        exr_coding_channel_info_t *ch = &enc->channels[c];
        const float *plane = image_channel(img, ch->channel_name);
        if (!plane) { /* cannot happen: we declared exactly these */
            image_set_err(err, errlen, "%s: library returned unknown channel %s", path,
                          ch->channel_name);
            return -1;
        }
        ch->encode_from_ptr = (const uint8_t *)(plane + (size_t)y * w);
        ch->user_pixel_stride = (int32_t)sizeof(float);
        ch->user_line_stride = (int32_t)(w * sizeof(float));
        ch->user_bytes_per_element = (int16_t)sizeof(float);
        ch->user_data_type = EXR_PIXEL_FLOAT;
    }
    return 0;
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
        image_set_err(err, errlen, "%s: cannot query chunk size: %s", path, exr_why(io, rv));
        return -1;
    }
    exr_encode_pipeline_t enc = EXR_ENCODE_PIPELINE_INITIALIZER;
    compress_hook_t hook = {NULL};
    int inited = 0, ret = 0;
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
            image_set_err(err, errlen, "%s: cannot prepare scanlines at y=%d: %s", path, y,
                          exr_why(io, rv));
            ret = -1;
            break;
        }
        if (exr_bind_rows(&enc, img, y, path, err, errlen) != 0) {
            ret = -1;
            break;
        }
        rv = exr_encoding_choose_default_routines(ctx, part, &enc);
        if (rv == EXR_ERR_SUCCESS && enc.compress_fn) {
            hook.orig = enc.compress_fn;
            enc.compress_fn = exr_compress_or_raw;
            enc.encoding_user_data = &hook;
        }
        if (rv == EXR_ERR_SUCCESS)
            rv = exr_encoding_run(ctx, part, &enc);
        if (rv != EXR_ERR_SUCCESS) {
            image_set_err(err, errlen, "%s: cannot write scanlines at y=%d: %s", path, y,
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
        image_set_err(err, errlen, "%s: cannot set up header: %s", path, exr_why(io, rv));
        return -1;
    }
    int long_names = 0;
    for (int c = 0; c < img->channel_count; c++)
        long_names |= strlen(img->channel_names[c]) > EXR_SHORT_NAME_MAX;
    for (int a = 0; a < img->attr_count; a++)
        long_names |= strlen(img->attrs[a].name) > EXR_SHORT_NAME_MAX;
    if (long_names && (rv = exr_set_longname_support(ctx, 1)) != EXR_ERR_SUCCESS) {
        image_set_err(err, errlen, "%s: cannot enable long names: %s", path, exr_why(io, rv));
        return -1;
    }
    for (int c = 0; c < img->channel_count; c++) {
        /* Perceptual treatment only steers lossy codecs; ZIP ignores it. */
        rv = exr_add_channel(ctx, part, img->channel_names[c], EXR_PIXEL_FLOAT,
                             EXR_PERCEPTUALLY_LOGARITHMIC, 1, 1);
        if (rv != EXR_ERR_SUCCESS) {
            image_set_err(err, errlen, "%s: cannot add channel %s: %s", path, img->channel_names[c],
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
            image_set_err(err, errlen, "%s: cannot set attribute %s: %s", path, at->name,
                          exr_why(io, rv));
            return -1;
        }
    }
    rv = exr_write_header(ctx);
    if (rv != EXR_ERR_SUCCESS) {
        image_set_err(err, errlen, "%s: cannot write header: %s", path, exr_why(io, rv));
        return -1;
    }
    return exr_write_pixels(ctx, part, img, io, path, err, errlen);
}

int image_write_exr(const image_t *img, const char *path, char *err, size_t errlen)
{
    if (!path || !path[0]) {
        image_set_err(err, errlen, "(no path): cannot write EXR: empty path");
        return -1;
    }
    if (!img || img->channel_count <= 0) {
        image_set_err(err, errlen, "%s: cannot write EXR: image has no channels", path);
        return -1;
    }
    char tmp[PATH_MAX];
    exr_io_t io;
    memset(&io, 0, sizeof io);
    io.fd = atomicfile_open(path, tmp, sizeof tmp, err, errlen);
    if (io.fd < 0)
        return -1;

    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    init.error_handler_fn = exr_error_cb;
    init.user_data = &io;
    init.write_fn = exr_write_cb;

    exr_context_t ctx = NULL;
    exr_result_t rv = exr_start_write(&ctx, path, EXR_WRITE_FILE_DIRECTLY, &init);
    int ret;
    if (rv != EXR_ERR_SUCCESS) {
        image_set_err(err, errlen, "%s: cannot start EXR write: %s", path, exr_why(&io, rv));
        ret = -1;
    } else {
        ret = exr_write_ctx(ctx, img, &io, path, err, errlen);
    }
    if (ctx) {
        /* exr_finish writes the chunk offset table, so it can fail too. */
        rv = exr_finish(&ctx);
        if (ret == 0 && rv != EXR_ERR_SUCCESS) {
            image_set_err(err, errlen, "%s: cannot finish EXR: %s", path, exr_why(&io, rv));
            ret = -1;
        }
    }
    if (ret != 0) {
        atomicfile_abandon(io.fd, tmp);
        return -1;
    }
    return atomicfile_commit(io.fd, tmp, path, err, errlen);
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
        image_set_err(err, errlen, "%s: cannot list attributes: %s", path, exr_why(io, rv));
        return -1;
    }
    for (int32_t k = 0; k < count; k++) {
        const exr_attribute_t *a = NULL;
        rv = exr_get_attribute_by_index(ctx, part, EXR_ATTR_LIST_FILE_ORDER, k, &a);
        if (rv != EXR_ERR_SUCCESS || !a) {
            image_set_err(err, errlen, "%s: cannot read attribute %d: %s", path, (int)k,
                          exr_why(io, rv));
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
        image_set_err(err, errlen, "%s: chunk at (%d,%d) lies outside the data window", path, x0,
                      y0);
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
        image_set_err(err, errlen, "%s: cannot decode chunk at (%d,%d): %s", path, x0, y0,
                      exr_why(io, rv));
        return -1;
    }
    const size_t w = (size_t)img->width;
    for (int c = 0; c < dec->channel_count; c++) {
        exr_coding_channel_info_t *ch = &dec->channels[c];
        float *plane = image_channel(img, ch->channel_name);
        if (!plane || ch->width != cinfo->width || ch->height != cinfo->height) {
            image_set_err(err, errlen, "%s: unexpected layout of channel %s", path,
                          ch->channel_name ? ch->channel_name : "?");
            return -1;
        }
        ch->decode_to_ptr = (uint8_t *)(plane + (size_t)y0 * w + (size_t)x0);
        ch->user_pixel_stride = (int32_t)sizeof(float);
        ch->user_line_stride = (int32_t)(w * sizeof(float));
        ch->user_bytes_per_element = (int16_t)sizeof(float);
        ch->user_data_type = EXR_PIXEL_FLOAT;
    }
    rv = exr_decoding_choose_default_routines(ctx, part, dec);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_decoding_run(ctx, part, dec);
    if (rv != EXR_ERR_SUCCESS) {
        image_set_err(err, errlen, "%s: cannot decode chunk at (%d,%d): %s", path, x0, y0,
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
            image_set_err(err, errlen, "%s: cannot query chunk size: %s", path, exr_why(io, rv));
            return -1;
        }
        /* Chunks start at dataWindow.min.y and every `lines` rows after. */
        for (int row = 0; row < img->height && ret == 0; row += lines) {
            exr_chunk_info_t cinfo;
            rv = exr_read_scanline_chunk_info(ctx, part, dw->min.y + row, &cinfo);
            if (rv != EXR_ERR_SUCCESS) {
                image_set_err(err, errlen, "%s: cannot read scanlines at y=%d: %s", path,
                              dw->min.y + row, exr_why(io, rv));
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
            image_set_err(err, errlen, "%s: cannot read tile description: %s", path,
                          exr_why(io, rv));
            return -1;
        }
        int tiles_x = (int)(((uint64_t)img->width + tw - 1) / tw);
        int tiles_y = (int)(((uint64_t)img->height + th - 1) / th);
        for (int ty = 0; ty < tiles_y && ret == 0; ty++) {
            for (int tx = 0; tx < tiles_x && ret == 0; tx++) {
                exr_chunk_info_t cinfo;
                rv = exr_read_tile_chunk_info(ctx, part, tx, ty, 0, 0, &cinfo);
                if (rv != EXR_ERR_SUCCESS) {
                    image_set_err(err, errlen, "%s: cannot read tile (%d,%d): %s", path, tx, ty,
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

/* Adds a float plane to img for each channel of the list. */
static int exr_read_channels(const exr_attr_chlist_t *chl, image_t *img, const char *path,
                             char *err, size_t errlen)
{
    for (int c = 0; c < chl->num_channels; c++) {
        const exr_attr_chlist_entry_t *e = &chl->entries[c];
        const char *name = e->name.str ? e->name.str : "";
        if (e->x_sampling != 1 || e->y_sampling != 1) {
            image_set_err(err, errlen, "%s: channel %s is subsampled (not supported)", path, name);
            return -1;
        }
        if (e->pixel_type != EXR_PIXEL_UINT && e->pixel_type != EXR_PIXEL_HALF &&
            e->pixel_type != EXR_PIXEL_FLOAT) {
            image_set_err(err, errlen, "%s: channel %s has unknown pixel type", path, name);
            return -1;
        }
        if (!image_add_channel(img, name)) {
            image_set_err(err, errlen,
                          "%s: cannot add channel \"%s\" (bad or duplicate name, "
                          "or out of memory)",
                          path, name);
            return -1;
        }
    }
    return 0;
}

/* Reads part 0 of an open context into a new image. */
static int exr_read_ctx(exr_context_t ctx, image_t **out, exr_io_t *io, const char *path, char *err,
                        size_t errlen)
{
    const int part = 0;
    exr_storage_t storage;
    exr_result_t rv = exr_get_storage(ctx, part, &storage);
    if (rv != EXR_ERR_SUCCESS) {
        image_set_err(err, errlen, "%s: cannot read storage type: %s", path, exr_why(io, rv));
        return -1;
    }
    if (storage == EXR_STORAGE_DEEP_SCANLINE || storage == EXR_STORAGE_DEEP_TILED) {
        image_set_err(err, errlen, "%s: deep EXR not supported", path);
        return -1;
    }
    if (storage != EXR_STORAGE_SCANLINE && storage != EXR_STORAGE_TILED) {
        image_set_err(err, errlen, "%s: unknown EXR storage type %d", path, (int)storage);
        return -1;
    }
    exr_attr_box2i_t dw;
    rv = exr_get_data_window(ctx, part, &dw);
    if (rv != EXR_ERR_SUCCESS) {
        image_set_err(err, errlen, "%s: cannot read data window: %s", path, exr_why(io, rv));
        return -1;
    }
    long long w = (long long)dw.max.x - dw.min.x + 1;
    long long h = (long long)dw.max.y - dw.min.y + 1;
    long long max_pixels = io->max_pixels ? io->max_pixels : IMAGE_MAX_PIXELS;
    if (w <= 0 || h <= 0 || w > IMAGE_MAX_SIDE || h > IMAGE_MAX_SIDE || w * h > max_pixels) {
        image_set_err(err, errlen, "%s: unsupported image size %lldx%lld", path, w, h);
        return -1;
    }
    const exr_attr_chlist_t *chl = NULL;
    rv = exr_get_channels(ctx, part, &chl);
    if (rv != EXR_ERR_SUCCESS || !chl) {
        image_set_err(err, errlen, "%s: cannot read channel list: %s", path, exr_why(io, rv));
        return -1;
    }
    if (chl->num_channels > IMAGE_MAX_CHANNELS) {
        image_set_err(err, errlen, "%s: %d channels, at most %d supported", path, chl->num_channels,
                      IMAGE_MAX_CHANNELS);
        return -1;
    }
    image_t *img = image_new((int)w, (int)h);
    if (!img) {
        image_set_err(err, errlen, "%s: out of memory", path);
        return -1;
    }
    if (exr_read_channels(chl, img, path, err, errlen) != 0 ||
        exr_read_attrs(ctx, part, img, io, path, err, errlen) != 0 ||
        exr_read_pixels(ctx, part, storage, &dw, img, io, path, err, errlen) != 0) {
        image_destroy(&img);
        return -1;
    }
    *out = img;
    return 0;
}

/* Opens name with init (a file, or a memory stream through its read
 * functions) and reads it. */
static int exr_read_with(const exr_context_initializer_t *init, exr_io_t *io, const char *name,
                         image_t **out, char *err, size_t errlen)
{
    exr_context_t ctx = NULL;
    exr_result_t rv = exr_start_read(&ctx, name, init);
    int ret;
    if (rv != EXR_ERR_SUCCESS) {
        image_set_err(err, errlen, "%s: cannot read EXR header: %s", name, exr_why(io, rv));
        ret = -1;
    } else {
        ret = exr_read_ctx(ctx, out, io, name, err, errlen);
    }
    if (ctx)
        exr_finish(&ctx);
    return ret;
}

int image_read_exr(const char *path, image_t **out, char *err, size_t errlen)
{
    if (out)
        *out = NULL;
    if (!path || !path[0] || !out) {
        image_set_err(err, errlen, "%s: cannot read EXR: bad arguments", path ? path : "(null)");
        return -1;
    }
    /* Check access and the magic number ourselves: the library's messages
     * for these common cases are less direct than errno and "not an
     * OpenEXR file". */
    FILE *f = fopen(path, "rb");
    if (!f) {
        image_set_err(err, errlen, "%s: cannot open: %s", path, strerror(errno));
        return -1;
    }
    unsigned char magic[4];
    size_t got = fread(magic, 1, sizeof magic, f);
    if (got != sizeof magic && ferror(f)) { /* e.g. EISDIR */
        image_set_err(err, errlen, "%s: cannot read: %s", path, strerror(errno));
        fclose(f);
        return -1;
    }
    fclose(f);
    static const unsigned char exr_magic[4] = {0x76, 0x2f, 0x31, 0x01};
    if (got != sizeof magic || memcmp(magic, exr_magic, sizeof magic) != 0) {
        image_set_err(err, errlen, "%s: not an OpenEXR file", path);
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

    return exr_read_with(&init, &io, path, out, err, errlen);
}

/* The library's reads of a file held in memory (image_read_exr_buffer). */
static int64_t exr_mem_read(exr_const_context_t ctxt, void *userdata, void *buffer, uint64_t sz,
                            uint64_t offset, exr_stream_error_func_ptr_t error_cb)
{
    (void)ctxt;
    (void)error_cb;
    const exr_io_t *io = userdata;
    if (offset >= io->mem_size)
        return 0;
    uint64_t n = io->mem_size - offset < sz ? io->mem_size - offset : sz;
    memcpy(buffer, io->mem + offset, (size_t)n);
    return (int64_t)n;
}

static int64_t exr_mem_size(exr_const_context_t ctxt, void *userdata)
{
    (void)ctxt;
    return (int64_t)((const exr_io_t *)userdata)->mem_size;
}

int image_read_exr_buffer(const char *name, const unsigned char *data, size_t size, image_t **out,
                          char *err, size_t errlen)
{
    return image_read_exr_buffer_capped(name, data, size, IMAGE_MAX_PIXELS, out, err, errlen);
}

int image_read_exr_buffer_capped(const char *name, const unsigned char *data, size_t size,
                                 long long max_pixels, image_t **out, char *err, size_t errlen)
{
    if (out)
        *out = NULL;
    if (!name || !out || (!data && size)) {
        image_set_err(err, errlen, "%s: cannot read EXR: bad arguments", name ? name : "(null)");
        return -1;
    }
    static const unsigned char exr_magic[4] = {0x76, 0x2f, 0x31, 0x01};
    if (size < 4 || memcmp(data, exr_magic, 4) != 0) {
        image_set_err(err, errlen, "%s: not an OpenEXR file", name);
        return -1;
    }
    exr_io_t io;
    memset(&io, 0, sizeof io);
    io.fd = -1;
    io.mem = data;
    io.mem_size = size;
    io.max_pixels = max_pixels;
    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    init.error_handler_fn = exr_error_cb;
    init.user_data = &io;
    init.read_fn = exr_mem_read;
    init.size_fn = exr_mem_size;
    init.flags = EXR_CONTEXT_FLAG_DISABLE_CHUNK_RECONSTRUCTION;
    return exr_read_with(&init, &io, name, out, err, errlen);
}
