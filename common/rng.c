/* rng.c - the sobol sampler's pairs computed ahead for many streams
 * (rng_sobol_fill, rng.h).
 *
 * A pair costs about a hundred integer operations one stream at a time
 * (three Laine-Karras scrambles, three bit reversals, the second Sobol
 * dimension, the pair's key), which made the sobol sampler about a tenth
 * of a diffuse sample's time. Eight streams' pairs in AVX2 vectors, or
 * sixteen in AVX-512's (one source for both widths: rng_fill.inc), take a
 * handful of operations each: byte shuffles reverse the bits, and the
 * second dimension takes rng.h's five shift-and-XOR steps. The pair's
 * 64-bit key stays scalar (AVX2 has no 64-bit multiply). Integer
 * operations: the same bits on every ISA. */
#include "rng.h"

#include <immintrin.h>
#include <string.h>

/* The third and fourth Sobol dimensions' generator matrices (columns:
 * direction numbers v_k = m_k / 2^k from m = 1, 3 and 1, 3, 1 by Bratley
 * and Fox's recurrence, bit-reversed), three columns at a time: entry
 * [c][d][e] is the XOR of dimension d's reversed columns 3c .. 3c + 2
 * picked by the bits of e, so an index's 24 bits take eight lookups
 * (in vectors, one permute each). test_sampler computes the columns again
 * from the polynomials and checks the products. */
_Static_assert(RNG_SOBOL_INDEX_BITS % 3 == 0, "the index in whole chunks of three bits");
static const uint32_t sobol_chunks[RNG_SOBOL_INDEX_BITS / 3][2][8] __attribute__((aligned(32))) = {
    {{0x00000000u, 0x00000001u, 0x00000003u, 0x00000002u, 0x00000006u, 0x00000007u, 0x00000005u,
      0x00000004u},
     {0x00000000u, 0x00000001u, 0x00000003u, 0x00000002u, 0x00000004u, 0x00000005u, 0x00000007u,
      0x00000006u}},
    {{0x00000000u, 0x00000009u, 0x00000017u, 0x0000001eu, 0x0000003au, 0x00000033u, 0x0000002du,
      0x00000024u},
     {0x00000000u, 0x0000000au, 0x0000001fu, 0x00000015u, 0x0000002eu, 0x00000024u, 0x00000031u,
      0x0000003bu}},
    {{0x00000000u, 0x00000071u, 0x000000a3u, 0x000000d2u, 0x00000116u, 0x00000167u, 0x000001b5u,
      0x000001c4u},
     {0x00000000u, 0x00000045u, 0x000000c9u, 0x0000008cu, 0x0000011bu, 0x0000015eu, 0x000001d2u,
      0x00000197u}},
    {{0x00000000u, 0x00000339u, 0x00000677u, 0x0000054eu, 0x000009aau, 0x00000a93u, 0x00000fddu,
      0x00000ce4u},
     {0x00000000u, 0x000002a4u, 0x0000079au, 0x0000053eu, 0x00000b67u, 0x000009c3u, 0x00000cfdu,
      0x00000e59u}},
    {{0x00000000u, 0x00001601u, 0x00003903u, 0x00002f02u, 0x00007706u, 0x00006107u, 0x00004e05u,
      0x00005804u},
     {0x00000000u, 0x0000101eu, 0x0000302du, 0x00002033u, 0x00004041u, 0x0000505fu, 0x0000706cu,
      0x00006072u}},
    {{0x00000000u, 0x0000aa09u, 0x00010117u, 0x0001ab1eu, 0x0003033au, 0x0003a933u, 0x0002022du,
      0x0002a824u},
     {0x00000000u, 0x0000a0c3u, 0x0001f104u, 0x000151c7u, 0x0002e28au, 0x00024249u, 0x0003138eu,
      0x0003b34du}},
    {{0x00000000u, 0x00060671u, 0x000909a3u, 0x000f0fd2u, 0x00171616u, 0x00111067u, 0x001e1fb5u,
      0x001819c4u},
     {0x00000000u, 0x000457dfu, 0x000c9baeu, 0x0008cc71u, 0x0011a105u, 0x0015f6dau, 0x001d3aabu,
      0x00196d74u}},
    {{0x00000000u, 0x003a3939u, 0x00717777u, 0x004b4e4eu, 0x00a3aaaau, 0x00999393u, 0x00d2ddddu,
      0x00e8e4e4u},
     {0x00000000u, 0x002a7289u, 0x0079e7dbu, 0x00539552u, 0x00b6dba4u, 0x009ca92du, 0x00cf3c7fu,
      0x00e54ef6u}},
};

void rng_sobol23_reversed(uint32_t index, uint32_t out[2])
{
    uint32_t a = 0, b = 0;
    for (int c = 0; c < RNG_SOBOL_INDEX_BITS / 3; c++) {
        uint32_t e = (index >> (3 * c)) & 7u;
        a ^= sobol_chunks[c][0][e];
        b ^= sobol_chunks[c][1][e];
    }
    out[0] = a;
    out[1] = b;
}

/* A pair's key: its scrambles' seeds, and (but for a joined pair, which
 * takes its partner's) its index shuffle's. */
static inline uint64_t sobol_pair_key(uint64_t sequence_key, uint32_t pair)
{
    return rng_mix64(sequence_key ^ (pair + 1) * 0x9e3779b97f4a7c15ULL);
}

void rng_sobol_pair(uint64_t sequence_key, uint32_t index_reversed, uint32_t pair, uint32_t out[2])
{
    uint64_t pair_key = sobol_pair_key(sequence_key, pair);
    uint32_t partner = rng_sobol_partner(pair);
    int joined = partner != pair;
    uint64_t shuffle_key = joined ? sobol_pair_key(sequence_key, partner) : pair_key;
    /* the two scrambles' seeds */
    uint32_t seed0 = (uint32_t)(pair_key >> 32), seed1 = rng_hash32(seed0);
    /* owen(x) = reverse(laine_karras(reverse(x))): the index's reversal
     * is the stream's, and the other dimensions come reversed */
    uint32_t j = rng_reverse32(rng_laine_karras(index_reversed, (uint32_t)shuffle_key)) &
                 ((1u << RNG_SOBOL_INDEX_BITS) - 1);
    uint32_t x[2] = {j, rng_sobol1_reversed(j)};
    if (joined)
        rng_sobol23_reversed(j, x);
    out[0] = rng_reverse32(rng_laine_karras(x[0], seed0));
    out[1] = rng_reverse32(rng_laine_karras(x[1], seed1));
}

/* Pairs to compute, gathered before any is computed: what each lane's
 * vectors load (its shuffle's key, its scrambles' seed, its index, whether
 * it is a joined pair), and where its bits go. The vectors load each field
 * long after its scalar stores: a vector load right after the eight stores
 * it spans waits for them to reach the cache (store forwarding does not
 * join them). Eight items gathered, then computed, had put a third of the
 * fill's time on those loads; gathered a run at a time, the Cornell box
 * under sobol ran 3 % faster (Intel Xeon, bench_core, with either ISA's
 * kernels), glass 2 %. */
#define FILL_RUN 64
typedef struct fill_run {
    uint32_t key[FILL_RUN], seed0[FILL_RUN], index_reversed[FILL_RUN];
    int32_t joined[FILL_RUN];
    rng_stream_t *stream[FILL_RUN];
    uint32_t slot[FILL_RUN];
    size_t n;
    int any_joined;
} fill_run_t;

/* The fill at each width (rng_fill.inc): AVX2's 8 lanes, and AVX-512's 16
 * (with its byte shuffles, AVX512BW), which the caller asks for only beside
 * other 512-bit code (wave.c: the diffuse kernel's 16 lanes). */
#define FREP(...) __VA_ARGS__, __VA_ARGS__
#define FW 8
#define FTARGET "avx2"
#define FNAME(x) fill8_##x
#define FSHUFB(t, i) _mm256_shuffle_epi8((__m256i)(t), (__m256i)(i))
#define FPERM8(table, i)                                                                           \
    _mm256_permutevar8x32_epi32(_mm256_load_si256((const __m256i *)(table)), (__m256i)(i))
#include "rng_fill.inc"

#define FREP(...) __VA_ARGS__, __VA_ARGS__, __VA_ARGS__, __VA_ARGS__
#define FW 16
#define FTARGET "avx2,avx512f,avx512bw"
#define FNAME(x) fill16_##x
#define FSHUFB(t, i) _mm512_shuffle_epi8((__m512i)(t), (__m512i)(i))
/* (the table in both halves: the index's fourth bit picks the same entry) */
#define FPERM8(table, i)                                                                           \
    _mm512_permutexvar_epi32((__m512i)(i),                                                         \
                             _mm512_broadcast_i64x4(_mm256_load_si256((const __m256i *)(table))))
#include "rng_fill.inc"

void rng_sobol_fill(rng_stream_t *const *streams, size_t n, const uint32_t *first_pair,
                    uint32_t pairs, int wide)
{
    if (pairs > RNG_BATCH_PAIRS)
        pairs = RNG_BATCH_PAIRS;
    for (size_t i = 0; i < n; i++) {
        rng_stream_t *s = streams[i];
        if (!s->sobol)
            continue; /* (its batch stays empty: rng_stream's) */
        s->batch_pair = first_pair[i];
        /* none past the quasi-random dimensions (hashed) */
        s->batch_pairs = first_pair[i] + pairs <= RNG_SOBOL_DIMS / 2 ? pairs : 0;
    }
    int vectors = __builtin_cpu_supports("avx2");
    void (*flush)(fill_run_t *) =
        wide && __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw")
            ? fill16_flush
            : fill8_flush;
    fill_run_t run;
    run.n = 0;
    run.any_joined = 0;
    /* the samples of one task share their sequence, so neighbouring items
     * mostly share their pair's key */
    uint64_t last_sequence = 0, pair_key = 0, shuffle_key = 0;
    uint32_t last_pair = UINT32_MAX;
    int32_t last_joined = 0;
    /* pair by pair, so that neighbouring items share the pair's key */
    for (uint32_t k = 0; k < pairs; k++) {
        for (size_t i = 0; i < n; i++) {
            rng_stream_t *s = streams[i];
            if (!s->sobol || s->batch_pairs == 0)
                continue;
            uint32_t pair = first_pair[i] + k;
            if (!vectors) {
                rng_sobol_pair(s->sequence_key, s->index_reversed, pair, s->batch_bits + 2 * k);
                continue;
            }
            if (s->sequence_key != last_sequence || pair != last_pair) {
                last_sequence = s->sequence_key;
                last_pair = pair;
                pair_key = sobol_pair_key(last_sequence, last_pair);
                uint32_t partner = rng_sobol_partner(last_pair);
                last_joined = -(partner != last_pair);
                shuffle_key = last_joined ? sobol_pair_key(last_sequence, partner) : pair_key;
            }
            size_t m = run.n++;
            run.key[m] = (uint32_t)shuffle_key;
            run.seed0[m] = (uint32_t)(pair_key >> 32);
            run.index_reversed[m] = s->index_reversed;
            run.joined[m] = last_joined;
            run.any_joined |= last_joined;
            run.stream[m] = s;
            run.slot[m] = k;
            if (run.n == FILL_RUN)
                flush(&run);
        }
    }
    if (run.n > 0)
        flush(&run);
}
