/* fuzz_bitmap.c - fuzz target for the bitmap textures' decoders
 * (bitmap_decode in common/bitmap.c: PNG through libpng, JPEG through
 * libjpeg, OpenEXR through image_read_exr_buffer, Radiance HDR through
 * stb_image after our check that its texels are all there): what a
 * worker does with the texture and environment files a scene bundle
 * carries.
 *
 * LLVMFuzzerTestOneInput aborts if a result breaks the API's promises: on
 * failure no texels and a message naming the file; on success a size
 * within BITMAP_MAX_TEXELS and texels that are numbers (8-bit sources in
 * [0, 1], Radiance HDR ones finite and not negative). Only our code is instrumented: a fault inside
 * the libraries shows up only when it crashes. Build with -DVB_LIBFUZZER and -fsanitize=fuzzer for
 * libFuzzer.
 *
 * Without VB_LIBFUZZER the standalone driver (fuzzdriver.h) runs it:
 *
 *     fuzz_bitmap CORPUS_DIR N      (tests/data/fuzz-bitmap: PNGs, one with
 *                                    alpha, JPEGs, one grey, Radiance HDRs,
 *                                    one run-length encoded, one flat)
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "bitmap.h"

/* 1 if the image was decoded, 0 if it was refused. OpenEXR inputs are
 * left to fuzz_exr (the same reader, exr.c): OpenEXR's own allocations
 * for a crafted header drove ASan's resident memory here past
 * libFuzzer's 2 GB. */
static int run_one(const uint8_t *data, size_t size)
{
    if (size >= 4 && data[0] == 0x76 && data[1] == 0x2f && data[2] == 0x31 && data[3] == 0x01)
        return 0;
    char err[512];
    err[0] = '\0';
    bitmap_t b;
    int raw = size > 0 && (data[size - 1] & 1); /* both paths of the 8-bit decoders */
    /* (a 4096th of a scene's cap: 64x64 texels. The size check comes
     * before any texel is decoded, so the decoders' paths are the same;
     * large images, each size its own allocator class, drove ASan's
     * resident memory past libFuzzer's 2 GB) */
    int r =
        bitmap_decode("fuzz.img", data, size, raw, BITMAP_MAX_TEXELS / 4096, &b, err, sizeof err);
    if (r != 0) {
        if (r != -1 || b.rgb != NULL || !strstr(err, "fuzz.img"))
            abort();
        return 0;
    }
    if (!b.rgb || b.width < 1 || b.height < 1 ||
        (uint64_t)b.width * (uint64_t)b.height > BITMAP_MAX_TEXELS / 4096)
        abort();
    int hdr = bitmap_is_hdr(data, size);
    int eight_bit = size >= 3 && data[0] != 0x76 && !hdr; /* not OpenEXR */
    for (size_t i = 0; i < (size_t)b.width * b.height * 3; i++)
        if ((eight_bit && !(b.rgb[i] >= 0.0f && b.rgb[i] <= 1.0f)) ||
            (hdr && !(b.rgb[i] >= 0.0f && isfinite(b.rgb[i]))))
            abort();
    bitmap_free(&b);
    return 1;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    run_one(data, size);
    return 0;
}

#ifndef VB_LIBFUZZER

#include "fuzzdriver.h"

static void mutate(fuzz_buf_t *b, uint64_t *s)
{
    /* chunk and marker names the decoders branch on */
    static const char *const tokens[] = {
        "IHDR",
        "IDAT",
        "IEND",
        "PLTE",
        "tRNS",
        "gAMA",
        "sRGB",
        "iCCP",
        "\xff\xd8",
        "\xff\xc0",
        "\xff\xc2",
        "\xff\xc4",
        "\xff\xda",
        "\xff\xdb",
        "\xff\xd9",
        "channels",
        "dataWindow",
        "#?RADIANCE\n",
        "#?RGBE\n",
        "FORMAT=32-bit_rle_rgbe\n\n",
        "-Y ",
        " +X ",
        "\x02\x02\x00\x08",
    };
    size_t n = b->n;
    unsigned kind = (unsigned)(fuzz_rnd(s) % 8);
    if (fuzz_mutate_shared(b, s, kind, tokens, sizeof tokens / sizeof tokens[0]))
        return;
    if (n < 4)
        return;
    /* a big-endian 16- or 32-bit field (PNG and JPEG sizes are) set to an
     * edge value */
    static const uint32_t words[] = {0, 1, 0xFF, 0xFFFF, 0x10000, 0x7FFFFFFF, 0xFFFFFFFF, 5000};
    uint32_t w = words[fuzz_rnd_below(s, sizeof words / sizeof words[0])];
    size_t at = fuzz_rnd_below(s, n - 3);
    int bytes = kind == 6 ? 2 : 4;
    for (int i = 0; i < bytes; i++)
        b->d[at + (size_t)i] = (unsigned char)(w >> (8 * (bytes - 1 - i)));
}

int main(int argc, char **argv)
{
    static const fuzz_target_t target = {"fuzz_bitmap", run_one,           mutate,
                                         NULL,          {"decoded", NULL}, "-bitmap"};
    return fuzz_main(argc, argv, &target);
}

#endif /* VB_LIBFUZZER */
