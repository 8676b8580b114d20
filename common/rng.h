/* rng.h - counter-based random numbers: every number is a pure function of
 * (seed, pixel, sample index, dimension).
 *
 * No generator state lives in a thread or a worker: a sample's stream is
 * rebuilt from its coordinates wherever and whenever it is drawn, so the
 * same sample gives the same path on any thread, worker or retry, and the
 * layers of a pixel are independent batches. A stream is SplitMix64 started
 * at a hash of the coordinates; the dimension is its counter.
 *
 * Two samplers share the stream type:
 * - independent (rng_stream): every number is hashed, as above.
 * - sobol (rng_stream_sobol): randomised quasi-Monte Carlo after Burley,
 *   "Practical Hash-based Owen Scrambling" (JCGT 2020). Dimensions come in
 *   pairs; pair p of sample i of a layer is point shuffle_p(i) of the first
 *   two Sobol dimensions, each Owen-scrambled. A layer of G samples (sample
 *   indices layer*G .. layer*G+G-1: one task record) is one randomised
 *   replicate: its shuffle and scrambles are seeded by hash(seed, pixel,
 *   layer*G, pair), so distinct layers are independent batches, as the
 *   adaptive modes and the target error assume, and every point is uniform
 *   on [0,1)^2 (unbiased). For a power-of-two G a layer's points of one
 *   pair form a (0,m,2)-net. Dimensions from RNG_SOBOL_DIMS on are hashed
 *   as in the independent sampler. tracer.c places each use of a number at
 *   a fixed dimension (rng_seek), so the 2D uses fall on pairs. */
#ifndef VB_RNG_H
#define VB_RNG_H

#include <stdint.h>

/* The samplers a job may choose (the wire codes of proto/PROTOCOL.md). */
typedef enum rng_sampler {
    RNG_SAMPLER_INDEPENDENT = 0,
    RNG_SAMPLER_SOBOL = 1,
} rng_sampler_t;

/* Dimensions below this are quasi-random under the sobol sampler: the
 * camera pair and the first RNG_SOBOL_BOUNCES bounces of tracer.c's layout.
 * Two: on the Cornell box, one, two and four bounces gave the same relMSE
 * at 64 spp (within 5 %), and each pair costs about 25 ns a sample. */
#define RNG_SOBOL_BOUNCES 2
#define RNG_SOBOL_DIMS (2 + 6 * RNG_SOBOL_BOUNCES)
/* A layer holds at most 2^12 samples (TRACER_MAX_TASK_SAMPLES): the Sobol
 * index needs no more bits (two 6-bit table lookups, rng_sobol1_reversed). */
#define RNG_SOBOL_INDEX_BITS 12

typedef struct rng_stream {
    uint64_t base;
    uint64_t dim;
    uint64_t layer_key;      /* sobol: hash of (seed, pixel, layer); 0 when independent */
    uint32_t index;          /* sobol: sample index within its layer */
    uint32_t index_reversed; /* sobol: its bits reversed (each pair's shuffle takes it) */
    uint32_t sobol;          /* 1 under the sobol sampler */
    uint32_t pair_plus1;     /* sobol: the pair whose two numbers pair_bits holds, + 1 */
    uint32_t pair_bits[2];   /* (a cache: a pair's two numbers cost one shuffle) */
} rng_stream_t;

/* Stafford's Mix13 finaliser (the one SplitMix64 uses): a bijection on 64
 * bits with full avalanche. */
static inline uint64_t rng_mix64(uint64_t z)
{
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
}

/* The stream of sample `sample_index` of pixel `pixel` under `seed`. Each
 * coordinate passes through the bijective mixer in turn, so distinct
 * coordinates give unrelated streams. */
static inline rng_stream_t rng_stream(uint64_t seed, uint64_t pixel, uint64_t sample_index)
{
    uint64_t h = rng_mix64(seed + 0x9e3779b97f4a7c15ULL);
    h = rng_mix64(h ^ (pixel * 0xd1b54a32d192ed03ULL));
    h = rng_mix64(h ^ (sample_index * 0xaef17502108ef2d9ULL));
    rng_stream_t s = {h, 0, 0, 0, 0, 0, 0, {0, 0}};
    return s;
}

static inline uint32_t rng_reverse32(uint32_t x)
{
    x = __builtin_bswap32(x);
    x = ((x >> 1) & 0x55555555u) | ((x & 0x55555555u) << 1);
    x = ((x >> 2) & 0x33333333u) | ((x & 0x33333333u) << 2);
    return ((x >> 4) & 0x0f0f0f0fu) | ((x & 0x0f0f0f0fu) << 4);
}

/* The sobol stream of sample `sample_index` of pixel `pixel`, in the layer
 * whose first sample is `layer_first` (<= sample_index; a task record's
 * first_sample, layer * G). The layer is the randomised replicate: its
 * first sample names its scrambles, and the sample's place in it is its
 * Sobol index. Dimensions past RNG_SOBOL_DIMS draw from the same hash as
 * rng_stream's. */
static inline rng_stream_t rng_stream_sobol(uint64_t seed, uint64_t pixel, uint64_t sample_index,
                                            uint64_t layer_first)
{
    rng_stream_t s = rng_stream(seed, pixel, sample_index);
    uint64_t h = rng_mix64(seed ^ 0x50b01a7e5c4a3b1eULL);
    h = rng_mix64(h ^ (pixel * 0xd1b54a32d192ed03ULL));
    s.layer_key = rng_mix64(h ^ (layer_first * 0xaef17502108ef2d9ULL));
    s.index = (uint32_t)(sample_index - layer_first);
    s.index_reversed = rng_reverse32(s.index);
    s.sobol = 1;
    return s;
}

/* Moves a sobol stream to dimension `dim`, so that each use of a number
 * (a bounce's light point, its BSDF sample...) keeps its own dimension
 * whatever was drawn before it. The independent stream ignores it and
 * draws in order, so its renders are those of before the sobol sampler. */
static inline void rng_seek(rng_stream_t *s, uint64_t dim)
{
    if (s->sobol)
        s->dim = dim;
}

/* Wellons' lowbias32: a 32-bit bijection with good avalanche. */
static inline uint32_t rng_hash32(uint32_t x)
{
    x ^= x >> 16;
    x *= 0x7feb352du;
    x ^= x >> 15;
    x *= 0x846ca68bu;
    return x ^ (x >> 16);
}

/* Burley's Laine-Karras-style hash: bit k of the result is bit k of x
 * flipped by a function of the bits below it and the seed (the constants
 * are even), and x -> result is a bijection. On reversed bits it is a
 * nested uniform (Owen) scramble: reverse(laine_karras(reverse(x))) flips
 * bit k from the top by a hash of the bits above it, which preserves every
 * elementary interval's point count; a uniform seed makes it uniform. */
static inline uint32_t rng_laine_karras(uint32_t x, uint32_t seed)
{
    x += seed;
    x ^= x * 0x6c50b47cu;
    x ^= x * 0xb82f1e52u;
    x ^= x * 0xc7afe638u;
    x ^= x * 0x8d22f6e6u;
    return x;
}

/* The second Sobol dimension (primitive polynomial x + 1) of an index below
 * 2^RNG_SOBOL_INDEX_BITS, bit-reversed (the scramble works on reversed
 * bits, so this saves a reversal): the generator matrix is Pascal's
 * triangle mod 2, its columns XORed in by six index bits at a time from
 * two tables (a loop over the 12 bits cost a fifth of a pair). The first
 * dimension reversed is the index itself. */
static inline uint32_t rng_sobol1_reversed(uint32_t i)
{
    static const uint32_t lo[64] = {
        0x00000000u, 0x00000001u, 0x00000003u, 0x00000002u, 0x00000005u, 0x00000004u, 0x00000006u,
        0x00000007u, 0x0000000fu, 0x0000000eu, 0x0000000cu, 0x0000000du, 0x0000000au, 0x0000000bu,
        0x00000009u, 0x00000008u, 0x00000011u, 0x00000010u, 0x00000012u, 0x00000013u, 0x00000014u,
        0x00000015u, 0x00000017u, 0x00000016u, 0x0000001eu, 0x0000001fu, 0x0000001du, 0x0000001cu,
        0x0000001bu, 0x0000001au, 0x00000018u, 0x00000019u, 0x00000033u, 0x00000032u, 0x00000030u,
        0x00000031u, 0x00000036u, 0x00000037u, 0x00000035u, 0x00000034u, 0x0000003cu, 0x0000003du,
        0x0000003fu, 0x0000003eu, 0x00000039u, 0x00000038u, 0x0000003au, 0x0000003bu, 0x00000022u,
        0x00000023u, 0x00000021u, 0x00000020u, 0x00000027u, 0x00000026u, 0x00000024u, 0x00000025u,
        0x0000002du, 0x0000002cu, 0x0000002eu, 0x0000002fu, 0x00000028u, 0x00000029u, 0x0000002bu,
        0x0000002au,
    };
    static const uint32_t hi[64] = {
        0x00000000u, 0x00000055u, 0x000000ffu, 0x000000aau, 0x00000101u, 0x00000154u, 0x000001feu,
        0x000001abu, 0x00000303u, 0x00000356u, 0x000003fcu, 0x000003a9u, 0x00000202u, 0x00000257u,
        0x000002fdu, 0x000002a8u, 0x00000505u, 0x00000550u, 0x000005fau, 0x000005afu, 0x00000404u,
        0x00000451u, 0x000004fbu, 0x000004aeu, 0x00000606u, 0x00000653u, 0x000006f9u, 0x000006acu,
        0x00000707u, 0x00000752u, 0x000007f8u, 0x000007adu, 0x00000f0fu, 0x00000f5au, 0x00000ff0u,
        0x00000fa5u, 0x00000e0eu, 0x00000e5bu, 0x00000ef1u, 0x00000ea4u, 0x00000c0cu, 0x00000c59u,
        0x00000cf3u, 0x00000ca6u, 0x00000d0du, 0x00000d58u, 0x00000df2u, 0x00000da7u, 0x00000a0au,
        0x00000a5fu, 0x00000af5u, 0x00000aa0u, 0x00000b0bu, 0x00000b5eu, 0x00000bf4u, 0x00000ba1u,
        0x00000909u, 0x0000095cu, 0x000009f6u, 0x000009a3u, 0x00000808u, 0x0000085du, 0x000008f7u,
        0x000008a2u,
    };
    return lo[i & 63u] ^ hi[(i >> 6) & 63u];
}

/* 32 bits of dimension dim < RNG_SOBOL_DIMS of a sobol stream. The index
 * is shuffled by a nested uniform scramble of its bits from the lowest up
 * (Burley's): for i < 2^m the low m bits are permuted and the bits above
 * become one constant (cut to RNG_SOBOL_INDEX_BITS), so a layer of 2^m
 * samples is an aligned block of the Sobol sequence, a (0,m,2)-net. The
 * shuffle differs per pair so that pairs are not correlated. */
static inline uint32_t rng_sobol_bits(rng_stream_t *s, uint64_t dim)
{
    uint32_t pair_plus1 = (uint32_t)(dim >> 1) + 1;
    if (s->pair_plus1 != pair_plus1) {
        uint64_t pair_key = rng_mix64(s->layer_key ^ pair_plus1 * 0x9e3779b97f4a7c15ULL);
        /* the index shuffle's and the two scrambles' seeds */
        uint32_t seed0 = (uint32_t)(pair_key >> 32), seed1 = rng_hash32(seed0);
        /* owen(x) = reverse(laine_karras(reverse(x))): the index's reversal
         * is the stream's, and the second dimension comes reversed */
        uint32_t j = rng_reverse32(rng_laine_karras(s->index_reversed, (uint32_t)pair_key)) &
                     ((1u << RNG_SOBOL_INDEX_BITS) - 1);
        s->pair_bits[0] = rng_reverse32(rng_laine_karras(j, seed0));
        s->pair_bits[1] = rng_reverse32(rng_laine_karras(rng_sobol1_reversed(j), seed1));
        s->pair_plus1 = pair_plus1;
    }
    return s->pair_bits[dim & 1];
}

/* The 64 random bits of dimension `dim` of a stream (no state change). */
static inline uint64_t rng_bits_at(const rng_stream_t *s, uint64_t dim)
{
    return rng_mix64(s->base + (dim + 1) * 0x9e3779b97f4a7c15ULL);
}

/* 64 bits of the next dimension: under sobol, the quasi-random 32 bits on
 * top of 32 hashed ones, so every bit is uniform. */
static inline uint64_t rng_next_bits(rng_stream_t *s)
{
    uint64_t dim = s->dim++;
    uint64_t bits = rng_bits_at(s, dim);
    if (s->sobol && dim < RNG_SOBOL_DIMS)
        bits = ((uint64_t)rng_sobol_bits(s, dim) << 32) | (bits & 0xffffffffULL);
    return bits;
}

/* Next dimension as a float in [0, 1): the top 24 bits, so never 1.0f.
 * (rng_next_bits's, without hashing the low bits a float drops.) */
static inline float rng_next_float(rng_stream_t *s)
{
    if (s->sobol && s->dim < RNG_SOBOL_DIMS)
        return (float)(rng_sobol_bits(s, s->dim++) >> 8) * 0x1.0p-24f;
    return (float)(rng_next_bits(s) >> 40) * 0x1.0p-24f;
}

/* Next dimension as a double in [0, 1), 53 bits. */
static inline double rng_next_double(rng_stream_t *s)
{
    return (double)(rng_next_bits(s) >> 11) * 0x1.0p-53;
}

#endif
