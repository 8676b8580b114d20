/* rng.c - the sobol sampler's pairs computed ahead for many streams
 * (rng_sobol_fill, rng.h).
 *
 * A pair costs about a hundred integer operations one stream at a time
 * (three Laine-Karras scrambles, three bit reversals, the second Sobol
 * dimension, the pair's key), which made the sobol sampler about a tenth
 * of a diffuse sample's time. Eight streams' pairs in AVX2 vectors take
 * a handful of operations each: byte shuffles reverse the bits, and the
 * second dimension takes rng.h's five shift-and-XOR steps. The pair's
 * 64-bit key stays scalar (AVX2 has no 64-bit multiply). Integer
 * operations: the same bits on every ISA. */
#include "rng.h"

#include <immintrin.h>

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

#define FILL_LANES 8

/* rng_reverse32 of each lane: bytes in reverse order, then each byte's
 * bits reversed from two 4-bit tables. */
__attribute__((target("avx2"))) static inline __m256i reverse32_x8(__m256i x)
{
    const __m256i byte_order =
        _mm256_setr_epi8(3, 2, 1, 0, 7, 6, 5, 4, 11, 10, 9, 8, 15, 14, 13, 12, 3, 2, 1, 0, 7, 6, 5,
                         4, 11, 10, 9, 8, 15, 14, 13, 12);
    /* a nibble n reversed, shifted to the high half (low_lut) or not */
    const __m256i low_lut =
        _mm256_setr_epi8(0x00, (char)0x80, 0x40, (char)0xc0, 0x20, (char)0xa0, 0x60, (char)0xe0,
                         0x10, (char)0x90, 0x50, (char)0xd0, 0x30, (char)0xb0, 0x70, (char)0xf0,
                         0x00, (char)0x80, 0x40, (char)0xc0, 0x20, (char)0xa0, 0x60, (char)0xe0,
                         0x10, (char)0x90, 0x50, (char)0xd0, 0x30, (char)0xb0, 0x70, (char)0xf0);
    const __m256i high_lut = _mm256_setr_epi8(0x0, 0x8, 0x4, 0xc, 0x2, 0xa, 0x6, 0xe, 0x1, 0x9, 0x5,
                                              0xd, 0x3, 0xb, 0x7, 0xf, 0x0, 0x8, 0x4, 0xc, 0x2, 0xa,
                                              0x6, 0xe, 0x1, 0x9, 0x5, 0xd, 0x3, 0xb, 0x7, 0xf);
    const __m256i nibble = _mm256_set1_epi8(0x0f);
    x = _mm256_shuffle_epi8(x, byte_order);
    __m256i lo = _mm256_and_si256(x, nibble);
    __m256i hi = _mm256_and_si256(_mm256_srli_epi16(x, 4), nibble);
    return _mm256_or_si256(_mm256_shuffle_epi8(low_lut, lo), _mm256_shuffle_epi8(high_lut, hi));
}

/* rng_laine_karras of each lane */
__attribute__((target("avx2"))) static inline __m256i laine_karras_x8(__m256i x, __m256i seed)
{
    x = _mm256_add_epi32(x, seed);
    x = _mm256_xor_si256(x, _mm256_mullo_epi32(x, _mm256_set1_epi32(0x6c50b47c)));
    x = _mm256_xor_si256(x, _mm256_mullo_epi32(x, _mm256_set1_epi32((int)0xb82f1e52u)));
    x = _mm256_xor_si256(x, _mm256_mullo_epi32(x, _mm256_set1_epi32((int)0xc7afe638u)));
    x = _mm256_xor_si256(x, _mm256_mullo_epi32(x, _mm256_set1_epi32((int)0x8d22f6e6u)));
    return x;
}

/* rng_hash32 of each lane */
__attribute__((target("avx2"))) static inline __m256i hash32_x8(__m256i x)
{
    x = _mm256_xor_si256(x, _mm256_srli_epi32(x, 16));
    x = _mm256_mullo_epi32(x, _mm256_set1_epi32(0x7feb352d));
    x = _mm256_xor_si256(x, _mm256_srli_epi32(x, 15));
    x = _mm256_mullo_epi32(x, _mm256_set1_epi32((int)0x846ca68bu));
    return _mm256_xor_si256(x, _mm256_srli_epi32(x, 16));
}

/* rng_sobol1_reversed of each lane: its five shift-and-XOR steps. */
__attribute__((target("avx2"))) static inline __m256i sobol1_reversed_x8(__m256i y)
{
    y = _mm256_xor_si256(y,
                         _mm256_and_si256(_mm256_srli_epi32(y, 1), _mm256_set1_epi32(0x55555555)));
    y = _mm256_xor_si256(y,
                         _mm256_and_si256(_mm256_srli_epi32(y, 2), _mm256_set1_epi32(0x33333333)));
    y = _mm256_xor_si256(y,
                         _mm256_and_si256(_mm256_srli_epi32(y, 4), _mm256_set1_epi32(0x0f0f0f0f)));
    y = _mm256_xor_si256(y,
                         _mm256_and_si256(_mm256_srli_epi32(y, 8), _mm256_set1_epi32(0x00ff00ff)));
    return _mm256_xor_si256(
        y, _mm256_and_si256(_mm256_srli_epi32(y, 16), _mm256_set1_epi32(0x0000ffff)));
}

/* rng_sobol23_reversed of each lane: eight permutes per dimension (a
 * permute reads the low three bits of each lane's index alone). */
__attribute__((target("avx2"))) static inline void sobol23_reversed_x8(__m256i j, __m256i *a,
                                                                       __m256i *b)
{
    __m256i x = _mm256_setzero_si256(), y = _mm256_setzero_si256();
    for (int c = 0; c < RNG_SOBOL_INDEX_BITS / 3; c++) {
        __m256i e = _mm256_srli_epi32(j, 3 * c);
        x = _mm256_xor_si256(x, _mm256_permutevar8x32_epi32(
                                    _mm256_load_si256((const __m256i *)sobol_chunks[c][0]), e));
        y = _mm256_xor_si256(y, _mm256_permutevar8x32_epi32(
                                    _mm256_load_si256((const __m256i *)sobol_chunks[c][1]), e));
    }
    *a = x;
    *b = y;
}

/* Lanes first .. first + FILL_LANES of a run (those past r->n are zero
 * and computed for nothing), in one pass of vectors. */
__attribute__((target("avx2"))) static void
fill_x8(const fill_run_t *r, size_t first, uint32_t out0[FILL_LANES], uint32_t out1[FILL_LANES])
{
    __m256i vkey = _mm256_loadu_si256((const __m256i *)(r->key + first));
    __m256i vseed0 = _mm256_loadu_si256((const __m256i *)(r->seed0 + first));
    __m256i vseed1 = hash32_x8(vseed0);
    __m256i j = _mm256_and_si256(
        reverse32_x8(laine_karras_x8(
            _mm256_loadu_si256((const __m256i *)(r->index_reversed + first)), vkey)),
        _mm256_set1_epi32((int)((1u << RNG_SOBOL_INDEX_BITS) - 1)));
    __m256i x0 = j, x1 = sobol1_reversed_x8(j);
    if (r->any_joined) {
        __m256i a, b, m = _mm256_loadu_si256((const __m256i *)(r->joined + first));
        sobol23_reversed_x8(j, &a, &b);
        x0 = _mm256_blendv_epi8(x0, a, m);
        x1 = _mm256_blendv_epi8(x1, b, m);
    }
    _mm256_storeu_si256((__m256i *)out0, reverse32_x8(laine_karras_x8(x0, vseed0)));
    _mm256_storeu_si256((__m256i *)out1, reverse32_x8(laine_karras_x8(x1, vseed1)));
}

/* The run's pairs, computed, to their streams; the run emptied. */
__attribute__((target("avx2"))) static void fill_run_flush(fill_run_t *r)
{
    /* the lanes past n, up to a whole vector: zero */
    for (size_t i = r->n; i % FILL_LANES; i++) {
        r->key[i] = r->seed0[i] = r->index_reversed[i] = 0;
        r->joined[i] = 0;
    }
    for (size_t first = 0; first < r->n; first += FILL_LANES) {
        uint32_t out0[FILL_LANES], out1[FILL_LANES];
        fill_x8(r, first, out0, out1);
        size_t lanes = r->n - first < FILL_LANES ? r->n - first : FILL_LANES;
        for (size_t i = 0; i < lanes; i++) {
            rng_stream_t *s = r->stream[first + i];
            s->batch_bits[2 * r->slot[first + i]] = out0[i];
            s->batch_bits[2 * r->slot[first + i] + 1] = out1[i];
        }
    }
    r->n = 0;
    r->any_joined = 0;
}

void rng_sobol_fill(rng_stream_t *const *streams, size_t n, const uint32_t *first_pair,
                    uint32_t pairs)
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
                fill_run_flush(&run);
        }
    }
    if (run.n > 0)
        fill_run_flush(&run);
}
