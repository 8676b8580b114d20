/* rng.h - counter-based random numbers: every number is a pure function of
 * (seed, pixel, sample index, dimension).
 *
 * No generator state lives in a thread or a worker: a sample's stream is
 * rebuilt from its coordinates wherever and whenever it is drawn, so the
 * same sample gives the same path on any thread, worker or retry (and,
 * under the independent sampler, the layers of a pixel are independent
 * batches). A stream is SplitMix64 started
 * at a hash of the coordinates; the dimension is its counter.
 *
 * Two samplers share the stream type:
 * - independent (rng_stream): every number is hashed, as above.
 * - sobol (rng_stream_sobol): randomised quasi-Monte Carlo after Burley,
 *   "Practical Hash-based Owen Scrambling" (JCGT 2020). Dimensions come in
 *   pairs; pair p of a pixel's sample i is point shuffle_p(i) of the first
 *   two Sobol dimensions, each Owen-scrambled, the shuffle and scrambles
 *   seeded by hash(seed, pixel, i >> RNG_SOBOL_INDEX_BITS, pair); a
 *   joined pair takes its partner's shuffle and the third and fourth
 *   dimensions (rng_sobol_partner). So a
 *   pixel's samples are one scrambled Sobol sequence (a fresh, independent
 *   scramble every 2^RNG_SOBOL_INDEX_BITS samples): its first 2^m samples
 *   form a (0,m,2)-net, and so does every aligned block of 2^m (a layer of
 *   G = 2^m samples, layer * G onwards), whichever layers a pixel takes.
 *   Every point is uniform on [0,1)^2 (unbiased). A whole pixel's samples
 *   are stratified together, as Mitsuba's multijitter and pbrt's Sobol
 *   samplers stratify them; one scramble per layer (the first design)
 *   left the error falling as 1/N past a layer: 1.4x the relMSE at 1024
 *   spp on the Cornell box. Layers of one sequence are not independent:
 *   their spread overstates the error of their mean (test_sampler), so the
 *   adaptive modes' and the target error's variance from layers errs on
 *   the safe side. Dimensions from RNG_SOBOL_DIMS on are hashed as in the
 *   independent sampler. tracer.c places each use of a number at a fixed
 *   dimension (rng_seek), so the 2D uses fall on pairs. */
#ifndef VB_RNG_H
#define VB_RNG_H

#include <stddef.h>
#include <stdint.h>

/* The samplers a job may choose (the wire codes of proto/PROTOCOL.md). */
typedef enum rng_sampler {
    RNG_SAMPLER_INDEPENDENT = 0,
    RNG_SAMPLER_SOBOL = 1,
} rng_sampler_t;

/* Dimensions below this are quasi-random under the sobol sampler: the
 * camera pair and the first RNG_SOBOL_BOUNCES bounces of tracer.c's layout.
 * Two: on the Cornell box, one, two and four bounces gave the same relMSE
 * at 64 spp (within 5 %). Every bounce (64) took 2-4 % off the Cornell
 * box's relMSE at 256 and 1024 spp and nothing measurable off the glass
 * scene's, for 12 % and 5 % more time a sample with pairs computed one at a
 * time (64x64, 2 and 1 replicates, 6 seeds; bench/RESULTS.md, "Sampler"),
 * and still 3.9 % on the Cornell box with the wavefront engine's pairs
 * computed ahead in vectors (rng_sobol_fill; 256x256, 1 thread, AMD EPYC):
 * no gain at equal time. */
#define RNG_SOBOL_BOUNCES 2
#define RNG_SOBOL_DIMS (2 + 6 * RNG_SOBOL_BOUNCES)
/* Joined pairs: a pair that shares another pair's (its partner's)
 * shuffled index and takes the third and fourth Sobol dimensions there
 * (rng_sobol_pair), so the two are one 4D Sobol net, each of its 2D
 * projections stratified (t <= 2 up to 4096 samples; the joined pair's own
 * t is 1, mostly, where a padded pair has 0), as Mitsuba's orthogonal
 * arrays stratify every 2D projection. Padded pairs leave the joint
 * variation of two pairs random. Two joins, in tracer.c's layout
 * (tracer_bounce_dim):
 * - the first bounce's light sample (dimensions 4 and 5) with the film
 *   point (0 and 1): where what a light gives a pixel varies across the
 *   pixel (a glossy plate's highlight of a small light, a textured
 *   floor's edges, a sharp shadow), relMSE at 1024 spp fell 4.1x on
 *   checker.xml, 2.2x on veach-mis.xml, 11 % on lights.xml, 1-3 % on the
 *   Cornell box and the Buddha;
 * - the second bounce's BSDF sample (12 and 13) with the first's (6 and
 *   7): the two directions of a path's first two bounces stratified
 *   together, for the light that reaches a pixel by interreflection: a
 *   further 11 % off the Cornell box at 1024 spp (6 % at 256), 8 % off
 *   dark-bright, 7 % off the Buddha, 3 % off checker.xml; materials.xml
 *   3.5 % higher (7 of 10 seeds: its glossy second bounces lose their
 *   pair's t = 0), glass 1.6 % (within its noise).
 * Tried and not kept (bench/RESULTS.md, "Sampler"): the first BSDF pair
 * joined with the camera's instead of the light pair (6 % off the Cornell
 * box, 4 % off veach-mis.xml), the second light pair with the first BSDF
 * pair's (4 % off the Cornell box where the two BSDF pairs took 11 %), a
 * 6D net of camera, light and BSDF pairs (7 % worse on the Cornell box). */
#define RNG_SOBOL_CAMERA_PAIR 0
#define RNG_SOBOL_LIGHT_PAIR 2
#define RNG_SOBOL_BSDF1_PAIR 3
#define RNG_SOBOL_BSDF2_PAIR 6

/* The pair whose shuffled index pair `pair` takes: its partner, or itself
 * for a padded pair. */
static inline uint32_t rng_sobol_partner(uint32_t pair)
{
    return pair == RNG_SOBOL_LIGHT_PAIR   ? RNG_SOBOL_CAMERA_PAIR
           : pair == RNG_SOBOL_BSDF2_PAIR ? RNG_SOBOL_BSDF1_PAIR
                                          : pair;
}
/* Samples of a pixel per Sobol sequence: 2^24, far past any reference's
 * count; the next 2^24 take
 * an independent scramble. */
#define RNG_SOBOL_INDEX_BITS 24

/* The most pairs one rng_sobol_fill computes ahead for a stream: a
 * bounce's light pair and BSDF pair. */
#define RNG_BATCH_PAIRS 2

typedef struct rng_stream {
    uint64_t base;
    uint64_t dim;
    uint64_t sequence_key;   /* sobol: hash of (seed, pixel, sequence); 0 when independent */
    uint32_t index;          /* sobol: sample index within its sequence */
    uint32_t index_reversed; /* sobol: its bits reversed (each pair's shuffle takes it) */
    uint32_t sobol;          /* 1 under the sobol sampler */
    uint32_t pair_plus1;     /* sobol: the pair whose two numbers pair_bits holds, + 1 */
    uint32_t pair_bits[2];   /* (a cache: a pair's two numbers cost one shuffle) */
    /* sobol: pairs batch_pair .. batch_pair + batch_pairs - 1, computed
     * ahead by rng_sobol_fill for many streams at once */
    uint32_t batch_pair, batch_pairs;
    uint32_t batch_bits[2 * RNG_BATCH_PAIRS];
} rng_stream_t;

/* Stafford's Mix13 finaliser (the one SplitMix64 uses): a bijection on 64
 * bits with full avalanche. */
static inline uint64_t rng_mix64(uint64_t z)
{
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
}

/* What every stream of one pixel starts from: (seed, pixel) hashed, once
 * per task where a task's samples start together (the wavefront engine)
 * instead of once per sample. */
typedef struct rng_pixel {
    uint64_t key;       /* rng_stream's */
    uint64_t sobol_key; /* rng_stream_sobol's sequences' */
} rng_pixel_t;

static inline rng_pixel_t rng_pixel(uint64_t seed, uint64_t pixel)
{
    rng_pixel_t p;
    p.key = rng_mix64(rng_mix64(seed + 0x9e3779b97f4a7c15ULL) ^ (pixel * 0xd1b54a32d192ed03ULL));
    p.sobol_key =
        rng_mix64(rng_mix64(seed ^ 0x50b01a7e5c4a3b1eULL) ^ (pixel * 0xd1b54a32d192ed03ULL));
    return p;
}

/* The stream of sample `sample_index` of pixel p (rng_stream). */
static inline rng_stream_t rng_stream_at(const rng_pixel_t *p, uint64_t sample_index)
{
    rng_stream_t s = {.base = rng_mix64(p->key ^ (sample_index * 0xaef17502108ef2d9ULL))};
    return s;
}

/* The stream of sample `sample_index` of pixel `pixel` under `seed`. Each
 * coordinate passes through the bijective mixer in turn, so distinct
 * coordinates give unrelated streams. */
static inline rng_stream_t rng_stream(uint64_t seed, uint64_t pixel, uint64_t sample_index)
{
    rng_pixel_t p = rng_pixel(seed, pixel);
    return rng_stream_at(&p, sample_index);
}

static inline uint32_t rng_reverse32(uint32_t x)
{
    x = __builtin_bswap32(x);
    x = ((x >> 1) & 0x55555555u) | ((x & 0x55555555u) << 1);
    x = ((x >> 2) & 0x33333333u) | ((x & 0x33333333u) << 2);
    return ((x >> 4) & 0x0f0f0f0fu) | ((x & 0x0f0f0f0fu) << 4);
}

/* The sobol stream of sample `sample_index` of pixel `pixel`: point
 * sample_index mod 2^RNG_SOBOL_INDEX_BITS of the pixel's scrambled Sobol
 * sequence number sample_index >> RNG_SOBOL_INDEX_BITS. Dimensions past
 * RNG_SOBOL_DIMS draw from the same hash as rng_stream's. rng_stream_sobol_at
 * is the same from the pixel's hashes. */
static inline rng_stream_t rng_stream_sobol_at(const rng_pixel_t *p, uint64_t sample_index)
{
    rng_stream_t s = rng_stream_at(p, sample_index);
    uint64_t sequence = sample_index >> RNG_SOBOL_INDEX_BITS;
    s.sequence_key = rng_mix64(p->sobol_key ^ (sequence * 0xaef17502108ef2d9ULL));
    s.index = (uint32_t)(sample_index & ((1u << RNG_SOBOL_INDEX_BITS) - 1));
    s.index_reversed = rng_reverse32(s.index);
    s.sobol = 1;
    return s;
}

static inline rng_stream_t rng_stream_sobol(uint64_t seed, uint64_t pixel, uint64_t sample_index)
{
    rng_pixel_t p = rng_pixel(seed, pixel);
    return rng_stream_sobol_at(&p, sample_index);
}

/* Random replication (issue 24): a pixel's samples as R independent
 * replicates, so that the spread of their means estimates the error of
 * the pixel's mean (under sobol, the samples of one sequence are not
 * independent, and their own variance overstates that error 10 to 30x:
 * bench/error/calibrate.py). Whole layers go to the replicates in turn:
 * the pixel's layer k (G samples) is replicate k mod R's layer k div R,
 * at sample index r 2^RNG_REPLICATE_SHIFT + (k div R) G. Bits 24 and up
 * of an index choose the sequence (rng_stream_sobol), so each replicate
 * is its own scramble, and its layers are a prefix of its sequence (a net
 * as they add up, whichever layers the adaptive rule skips). R = 1 is the
 * index of before: the samples taken so far. `taken` is what the pixel has
 * taken, a whole number of layers. */
#define RNG_REPLICATE_SHIFT 48
#define RNG_MAX_REPLICATES 16
static inline uint64_t rng_replicate_first_sample(uint64_t taken, uint32_t granularity,
                                                  uint32_t replicates)
{
    if (replicates <= 1)
        return taken;
    uint64_t k = taken / granularity;
    return ((k % replicates) << RNG_REPLICATE_SHIFT) + (k / replicates) * granularity;
}

/* The replicate a layer's first sample index belongs to. */
static inline uint32_t rng_replicate_of(uint64_t first_sample)
{
    return (uint32_t)(first_sample >> RNG_REPLICATE_SHIFT);
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

/* RNG_HASH32, RNG_LAINE_KARRAS, RNG_SOBOL1_REVERSED: the steps of the three
 * functions below, on x in place: a uint32_t there, or a vector
 * of them in rng_fill.inc, so that both run the very same operations. */

/* Wellons' lowbias32: a 32-bit bijection with good avalanche. */
#define RNG_HASH32(x)                                                                              \
    do {                                                                                           \
        (x) ^= (x) >> 16;                                                                          \
        (x) *= 0x7feb352du;                                                                        \
        (x) ^= (x) >> 15;                                                                          \
        (x) *= 0x846ca68bu;                                                                        \
        (x) ^= (x) >> 16;                                                                          \
    } while (0)
static inline uint32_t rng_hash32(uint32_t x)
{
    RNG_HASH32(x);
    return x;
}

/* Burley's Laine-Karras-style hash: bit k of the result is bit k of x
 * flipped by a function of the bits below it and the seed (the constants
 * are even), and x -> result is a bijection. On reversed bits it is a
 * nested uniform (Owen) scramble: reverse(laine_karras(reverse(x))) flips
 * bit k from the top by a hash of the bits above it, which preserves every
 * elementary interval's point count; a uniform seed makes it uniform. */
#define RNG_LAINE_KARRAS(x, seed)                                                                  \
    do {                                                                                           \
        (x) += (seed);                                                                             \
        (x) ^= (x)*0x6c50b47cu;                                                                    \
        (x) ^= (x)*0xb82f1e52u;                                                                    \
        (x) ^= (x)*0xc7afe638u;                                                                    \
        (x) ^= (x)*0x8d22f6e6u;                                                                    \
    } while (0)
static inline uint32_t rng_laine_karras(uint32_t x, uint32_t seed)
{
    RNG_LAINE_KARRAS(x, seed);
    return x;
}

/* The second Sobol dimension (primitive polynomial x + 1) of an index
 * below 2^RNG_SOBOL_INDEX_BITS, bit-reversed (the scramble works on
 * reversed bits, so this saves a reversal). The generator matrix is
 * Pascal's triangle mod 2: bit r of the result is the XOR of the index's
 * bits c with C(c, r) odd, that is (Lucas) the bits c whose binary digits
 * include r's, a sum over supersets taken one digit of r at a time
 * (rng_fill.inc's vectors take the same five steps; test_sampler checks them
 * against the matrix itself). The first dimension reversed is the index
 * itself. */
#define RNG_SOBOL1_REVERSED(y)                                                                     \
    do {                                                                                           \
        (y) ^= ((y) >> 1) & 0x55555555u;                                                           \
        (y) ^= ((y) >> 2) & 0x33333333u;                                                           \
        (y) ^= ((y) >> 4) & 0x0f0f0f0fu;                                                           \
        (y) ^= ((y) >> 8) & 0x00ff00ffu;                                                           \
        (y) ^= ((y) >> 16) & 0x0000ffffu;                                                          \
    } while (0)
static inline uint32_t rng_sobol1_reversed(uint32_t y)
{
    RNG_SOBOL1_REVERSED(y);
    return y;
}

/* The third and fourth Sobol dimensions (Joe and Kuo's primitive
 * polynomials x^2 + x + 1 and x^3 + x + 1, pbrt's tables) of an index
 * below 2^RNG_SOBOL_INDEX_BITS, bit-reversed as rng_sobol1_reversed's:
 * the XOR of the reversed generator columns of the index's set bits. */
void rng_sobol23_reversed(uint32_t index, uint32_t out[2]);

/* The two numbers of pair `pair` (dimensions 2 pair and 2 pair + 1) of the
 * sobol sequence sequence_key, at the index whose bits reversed are
 * index_reversed. The index is shuffled by a nested uniform scramble of
 * its bits from the lowest up (Burley's): an aligned block of 2^m indices
 * (a pixel's first 2^m samples, or one layer of G = 2^m) keeps its high
 * bits together and its low m bits permuted, so it maps onto an aligned
 * block of the Sobol sequence, a (0,m,2)-net. The shuffle differs per pair
 * so that pairs are not correlated, but for a joined pair, which takes
 * its partner's shuffle (rng_sobol_partner) and the third and fourth
 * dimensions there (a (t,m,4)-net with its partner). rng_sobol_fill computes the same bits
 * for many streams at once. Out of line: draws mostly find their pair
 * computed ahead or cached, and the draws stay small enough to inline. */
void rng_sobol_pair(uint64_t sequence_key, uint32_t index_reversed, uint32_t pair, uint32_t out[2]);

/* 32 bits of dimension dim < RNG_SOBOL_DIMS of a sobol stream: from the
 * pairs rng_sobol_fill computed ahead, or the pair computed now (and kept
 * for the pair's other number). */
static inline uint32_t rng_sobol_bits(rng_stream_t *s, uint64_t dim)
{
    uint32_t pair = (uint32_t)(dim >> 1);
    uint32_t k = pair - s->batch_pair; /* (wraps past batch_pairs below it) */
    if (k < s->batch_pairs)
        return s->batch_bits[2 * k + (dim & 1)];
    if (s->pair_plus1 != pair + 1) {
        rng_sobol_pair(s->sequence_key, s->index_reversed, pair, s->pair_bits);
        s->pair_plus1 = pair + 1;
    }
    return s->pair_bits[dim & 1];
}

/* Computes ahead, for each sobol stream streams[i] of n, its pairs
 * first_pair[i] .. first_pair[i] + pairs - 1 (pairs at most
 * RNG_BATCH_PAIRS, each below RNG_SOBOL_DIMS / 2): eight at a time in
 * AVX2 vectors where the host has them, or with `wide` sixteen in AVX-512
 * vectors where it has those, the bits rng_sobol_pair gives. Streams not
 * under sobol are left as they are. Replaces what an earlier call
 * computed ahead. */
void rng_sobol_fill(rng_stream_t *const *streams, size_t n, const uint32_t *first_pair,
                    uint32_t pairs, int wide);

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
 * (rng_next_bits's, without hashing the low bits a float drops.) Always
 * inlined: GCC kept it out of line in the shading kernels' lane loops, a
 * call per number (3 % of the Cornell box's time). */
__attribute__((always_inline)) static inline float rng_next_float(rng_stream_t *s)
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
