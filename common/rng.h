/* rng.h - counter-based random numbers: every number is a pure function of
 * (seed, pixel, sample index, dimension).
 *
 * No generator state lives in a thread or a worker: a sample's stream is
 * rebuilt from its coordinates wherever and whenever it is drawn, so the
 * same sample gives the same path on any thread, worker or retry, and the
 * layers of a pixel are independent batches. A stream is SplitMix64 started
 * at a hash of the coordinates; the dimension is its counter. */
#ifndef VB_RNG_H
#define VB_RNG_H

#include <stdint.h>

typedef struct rng_stream {
    uint64_t base;
    uint64_t dim;
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
    rng_stream_t s = {h, 0};
    return s;
}

/* The 64 random bits of dimension `dim` of a stream (no state change). */
static inline uint64_t rng_bits_at(const rng_stream_t *s, uint64_t dim)
{
    return rng_mix64(s->base + (dim + 1) * 0x9e3779b97f4a7c15ULL);
}

/* Next dimension as a float in [0, 1): the top 24 bits, so never 1.0f. */
static inline float rng_next_float(rng_stream_t *s)
{
    uint64_t bits = rng_bits_at(s, s->dim++);
    return (float)(bits >> 40) * 0x1.0p-24f;
}

/* Next dimension as a double in [0, 1), 53 bits. */
static inline double rng_next_double(rng_stream_t *s)
{
    uint64_t bits = rng_bits_at(s, s->dim++);
    return (double)(bits >> 11) * 0x1.0p-53;
}

#endif
