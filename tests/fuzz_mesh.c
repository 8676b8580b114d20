/* fuzz_mesh.c - fuzz target for the mesh reader (common/mesh.c).
 *
 * LLVMFuzzerTestOneInput feeds one input to mesh_load_buffer twice, once
 * named .ply and once .obj, and aborts if a result breaks the API's promises
 * (indices in range, finite positions, unit normals, *out NULL and a message
 * on failure). Build with -DVB_LIBFUZZER and -fsanitize=fuzzer for libFuzzer.
 *
 * Without VB_LIBFUZZER this file also has a standalone driver, so the target
 * runs in every `make test` with no fuzzing engine:
 *
 *     fuzz_mesh CORPUS_DIR N
 *
 * runs every file in CORPUS_DIR, then N deterministic mutations of them
 * (fixed seed: a failure reproduces exactly). Each mutated input is passed in
 * a buffer of exactly its size so ASan sees any read past the end. Exit 0
 * when nothing crashed; the sanitizers turn memory errors into crashes.
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mesh.h"

/* Checks a result of mesh_load_buffer; any breach is a bug, so abort. */
static void check_result(int r, const mesh_t *m, const char *err)
{
    if (r != 0) {
        if (r != -1 || m != NULL || err[0] == '\0')
            abort();
        return;
    }
    if (!m || !m->positions || !m->indices || m->triangle_count == 0)
        abort();
    for (size_t i = 0; i < 3 * m->triangle_count; i++)
        if (m->indices[i] >= m->vertex_count)
            abort();
    for (size_t i = 0; i < 3 * m->vertex_count; i++)
        if (!isfinite(m->positions[i]))
            abort();
    if (m->normals) {
        for (size_t v = 0; v < m->vertex_count; v++) {
            const float *n = m->normals + 3 * v;
            double len = sqrt((double)n[0] * n[0] + (double)n[1] * n[1] + (double)n[2] * n[2]);
            if (!(fabs(len - 1.0) < 1e-4))
                abort();
        }
    }
}

/* Bit 0: loaded as PLY-named, bit 1: loaded as OBJ-named (for statistics). */
static int run_one(const uint8_t *data, size_t size)
{
    static const char *const names[2] = {"fuzz.ply", "fuzz.obj"};
    int loaded = 0;
    for (int i = 0; i < 2; i++) {
        char err[256];
        mesh_t *m = NULL;
        err[0] = '\0';
        int r = mesh_load_buffer(names[i], data, size, &m, err, sizeof err);
        check_result(r, m, err);
        if (r == 0)
            loaded |= 1 << i;
        mesh_destroy(&m);
    }
    return loaded;
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
    static const char *const numbers[] = {
        "nan",
        "-nan",
        "inf",
        "-inf",
        "-1",
        "0",
        "1",
        "2",
        "3",
        "-2147483648",
        "2147483647",
        "4294967295",
        "4294967296",
        "18446744073709551615",
        "99999999999999999999999",
        "1e39",
        "-1e400",
        "1e-400",
        "255",
        "256",
        "65535",
        "0x10",
        "1.5",
        "",
        "1/2/3",
        "-0",
    };
    static const uint32_t words[] = {
        0u,
        1u,
        2u,
        3u,
        0x7Fu,
        0x80u,
        0xFFu,
        0xFFFFu,
        0x7FFFFFFFu,
        0x80000000u,
        0xFFFFFFFFu,
        0x7FC00000u /* NaN */,
        0x7F800000u /* +Inf */,
        0x3F800000u /* 1.0f */,
    };
    static const char *const tokens[] = {
        "\n",
        "\r\n",
        " ",
        "\t",
        "/",
        "#",
        "f ",
        "v ",
        "\nf 1 2 3\n",
        "\nv 1 2 3\n",
        "element edge 2\nproperty int a\n",
        "property list uint uint x\n",
        "property float nx\n",
        "element face 3\n",
        "end_header\n",
        "comment c\n",
        "3 0 1 2\n",
    };
    size_t n = b->n;
    unsigned kind = (unsigned)(fuzz_rnd(s) % 9);
    if (fuzz_mutate_shared(b, s, kind, tokens, sizeof tokens / sizeof tokens[0]))
        return;
    switch (kind) {
    case 6:
    case 7: /* replace a number (text) by an awkward one */
        fuzz_replace_number(b, s, numbers, sizeof numbers / sizeof numbers[0]);
        break;
    default: { /* overwrite a binary word, either byte order */
        if (n < 4)
            break;
        uint32_t w = words[fuzz_rnd_below(s, sizeof words / sizeof words[0])];
        size_t at = fuzz_rnd_below(s, n - 3);
        int big = (int)(fuzz_rnd(s) & 1);
        for (int i = 0; i < 4; i++)
            b->d[at + (size_t)(big ? 3 - i : i)] = (unsigned char)(w >> (8 * i));
        break;
    }
    }
}

int main(int argc, char **argv)
{
    static const fuzz_target_t target = {"fuzz_mesh", run_one, mutate, NULL, {"as .ply", "as .obj"},
                                         "-mesh"};
    return fuzz_main(argc, argv, &target);
}

#endif /* VB_LIBFUZZER */
