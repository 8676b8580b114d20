/* fuzz_exr.c - fuzz target for the EXR reader (image_read_exr in
 * common/image.c, over the OpenEXR 3 C library): how the client reads a
 * reference image and the master reads a job's final image back.
 *
 * image_read_exr takes a path, so an input is written to an anonymous
 * in-memory file (memfd_create) and read as /proc/self/fd/N: no disk, and
 * nothing left behind. LLVMFuzzerTestOneInput aborts if a result breaks the
 * API's promises: on failure *out NULL and a message; on success a size in
 * bounds, named channels each with its plane, attributes that fit their
 * table. Only the reader's own code is instrumented: a fault inside the
 * (uninstrumented) OpenEXR library shows up only when it crashes. Build
 * with -DVB_LIBFUZZER and -fsanitize=fuzzer for libFuzzer.
 *
 * Without VB_LIBFUZZER the standalone driver (fuzzdriver.h) runs it:
 *
 *     fuzz_exr CORPUS_DIR N      (tests/data/fuzz-exr, by gen_fuzz_seeds)
 */
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/syscall.h>
#include <unistd.h>

#include "image.h"

/* memfd_create(2) by its system call: the glibc wrapper needs _GNU_SOURCE. */
static int memfd(void)
{
    return (int)syscall(SYS_memfd_create, "fuzz_exr", 0u);
}

static void check_result(int r, const image_t *img, const char *err)
{
    if (r != 0) {
        if (r != -1 || img != NULL || err[0] == '\0')
            abort();
        return;
    }
    if (!img || img->width < 1 || img->height < 1 || img->width > 65536 || img->height > 65536 ||
        (int64_t)img->width * img->height > (INT64_C(1) << 28))
        abort();
    if (img->channel_count < 0 || img->channel_count > IMAGE_MAX_CHANNELS || img->attr_count < 0 ||
        img->attr_count > IMAGE_MAX_ATTRS)
        abort();
    for (int c = 0; c < img->channel_count; c++) {
        size_t len = strnlen(img->channel_names[c], IMAGE_NAME_LEN);
        if (len == 0 || len == IMAGE_NAME_LEN || !img->channels[c])
            abort();
    }
    for (int a = 0; a < img->attr_count; a++)
        if (strnlen(img->attrs[a].name, IMAGE_NAME_LEN) == IMAGE_NAME_LEN ||
            strnlen(img->attrs[a].s, IMAGE_STRING_LEN) == IMAGE_STRING_LEN)
            abort();
}

/* 1 if the image was read, 0 if it was refused. */
static int run_one(const uint8_t *data, size_t size)
{
    int fd = memfd();
    if (fd < 0)
        abort();
    size_t done = 0;
    while (done < size) {
        ssize_t w = write(fd, data + done, size - done);
        if (w <= 0)
            abort();
        done += (size_t)w;
    }
    char path[64];
    snprintf(path, sizeof path, "/proc/self/fd/%d", fd);
    char err[512];
    err[0] = '\0';
    image_t *img = NULL;
    int r = image_read_exr(path, &img, err, sizeof err);
    check_result(r, img, err);
    image_destroy(&img);
    close(fd);
    return r == 0;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    run_one(data, size);
    return 0;
}

#ifndef VB_LIBFUZZER

#include "fuzzdriver.h"

static void put_le(unsigned char *p, uint64_t v, int bytes)
{
    for (int i = 0; i < bytes; i++)
        p[i] = (unsigned char)(v >> (8 * i));
}

static void mutate(fuzz_buf_t *b, uint64_t *s)
{
    static const uint32_t words[] = {
        0u,
        1u,
        2u,
        3u,
        4u,
        7u,
        8u,
        15u,
        16u,
        17u,
        31u,
        32u,
        0x7Fu,
        0x80u,
        0xFFu,
        0xFFFFu,
        65535u,
        65536u,
        0x7FFFFFFFu,
        0x80000000u,
        0xFFFFFFFFu,
        0x7FC00000u /* NaN */,
        0x7F800000u /* +Inf */,
    };
    /* attribute names and types (the NUL after each comes from the file) */
    static const char *const tokens[] = {
        "channels", "chlist",    "compression", "dataWindow", "box2i",  "tiles",
        "tiledesc", "lineOrder", "chunkCount",  "type",       "string", "int",
        "double",   "float",     "half",        "R",          "A",
    };
    size_t n = b->n;
    unsigned kind = (unsigned)(fuzz_rnd(s) % 9);
    if (fuzz_mutate_shared(b, s, kind, tokens, sizeof tokens / sizeof tokens[0]))
        return;
    switch (kind) {
    default: { /* an awkward 32-bit field: sizes, offsets, counts, box corners */
        if (n < 4)
            break;
        put_le(b->d + fuzz_rnd_below(s, n - 3),
               words[fuzz_rnd_below(s, sizeof words / sizeof words[0])], 4);
        break;
    }
    }
}

int main(int argc, char **argv)
{
    static const fuzz_target_t target = {"fuzz_exr", run_one, mutate, NULL, {"read", NULL}, "-exr"};
    return fuzz_main(argc, argv, &target);
}

#endif /* VB_LIBFUZZER */
