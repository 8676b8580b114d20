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
 * index needs no more bits, and fewer make rng_sobol1 quicker. */
#define RNG_SOBOL_INDEX_BITS 12

typedef struct rng_stream {
    uint64_t base;
    uint64_t dim;
    uint64_t layer_key;    /* sobol: hash of (seed, pixel, layer); 0 when independent */
    uint32_t index;        /* sobol: sample index within its layer */
    uint32_t sobol;        /* 1 under the sobol sampler */
    uint32_t pair_plus1;   /* sobol: the pair whose two numbers pair_bits holds, + 1 */
    uint32_t pair_bits[2]; /* (a cache: a pair's two numbers cost one shuffle) */
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
    rng_stream_t s = {h, 0, 0, 0, 0, 0, {0, 0}};
    return s;
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

static inline uint32_t rng_reverse32(uint32_t x)
{
    x = __builtin_bswap32(x);
    x = ((x >> 1) & 0x55555555u) | ((x & 0x55555555u) << 1);
    x = ((x >> 2) & 0x33333333u) | ((x & 0x33333333u) << 2);
    return ((x >> 4) & 0x0f0f0f0fu) | ((x & 0x0f0f0f0fu) << 4);
}

/* Burley's Laine-Karras-style hash: bit k of the result is bit k of x
 * flipped by a function of the bits below it and the seed (the constants
 * are even), and x -> result is a bijection. */
static inline uint32_t rng_laine_karras(uint32_t x, uint32_t seed)
{
    x += seed;
    x ^= x * 0x6c50b47cu;
    x ^= x * 0xb82f1e52u;
    x ^= x * 0xc7afe638u;
    x ^= x * 0x8d22f6e6u;
    return x;
}

/* Nested uniform (Owen) scramble of a 32-bit fraction: bit k from the top
 * flipped by a hash of the bits above it. Preserves every elementary
 * interval's point count; a uniform seed makes the result uniform. */
static inline uint32_t rng_owen32(uint32_t x, uint32_t seed)
{
    return rng_reverse32(rng_laine_karras(rng_reverse32(x), seed));
}

/* The second Sobol dimension (primitive polynomial x + 1) of an index below
 * 2^RNG_SOBOL_INDEX_BITS: the generator matrix is Pascal's triangle mod 2.
 * Branch-free, as the index bits are random. The first is rng_reverse32. */
static inline uint32_t rng_sobol1(uint32_t i)
{
    static const uint32_t v[RNG_SOBOL_INDEX_BITS] = {
        0x80000000u, 0xc0000000u, 0xa0000000u, 0xf0000000u, 0x88000000u, 0xcc000000u,
        0xaa000000u, 0xff000000u, 0x80800000u, 0xc0c00000u, 0xa0a00000u, 0xf0f00000u};
    uint32_t r = 0;
    for (int b = 0; b < RNG_SOBOL_INDEX_BITS; b++)
        r ^= v[b] & (0u - ((i >> b) & 1u));
    return r;
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
        uint32_t j = rng_owen32(s->index, (uint32_t)pair_key) & ((1u << RNG_SOBOL_INDEX_BITS) - 1);
        /* owen(reverse(j)) = reverse(laine_karras(j)) */
        s->pair_bits[0] = rng_reverse32(rng_laine_karras(j, seed0));
        s->pair_bits[1] = rng_owen32(rng_sobol1(j), seed1);
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
