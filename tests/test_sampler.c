/* test_sampler.c - the sobol sampler of rng.h: a pure function of its
 * coordinates, in [0, 1), one scrambled Sobol sequence per pixel (a
 * (0, m, 2)-net per pair in its first 2^m samples and in every layer of
 * G = 2^m; a joined pair and its partner one 4D net), unbiased with far less variance
 * than independent numbers on a smooth integrand, and layers whose spread never understates the
 * error of their mean.
 *
 * Statistical checks use 5 standard errors: a defect (a shared scramble,
 * a correlated pair) misses by far more, chance almost never does. */
#include <check.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "rng.h"

/* The number of dimension `dim` of sample `i` of layer `layer` (size g). */
static uint64_t bits_of(uint64_t seed, uint64_t pixel, uint32_t g, uint32_t layer, uint32_t i,
                        uint64_t dim)
{
    rng_stream_t s = rng_stream_sobol(seed, pixel, (uint64_t)layer * g + i);
    rng_seek(&s, dim);
    return rng_next_bits(&s);
}

static double unit_of(uint64_t seed, uint64_t pixel, uint32_t g, uint32_t layer, uint32_t i,
                      uint64_t dim)
{
    return (double)(bits_of(seed, pixel, g, layer, i, dim) >> 11) * 0x1.0p-53;
}

START_TEST(test_sobol_pure_function)
{
    for (uint64_t dim = 0; dim < RNG_SOBOL_DIMS + 8; dim++) {
        ck_assert(bits_of(3, 77, 32, 5, 9, dim) == bits_of(3, 77, 32, 5, 9, dim));
        /* every coordinate matters */
        uint64_t b = bits_of(3, 77, 32, 5, 9, dim);
        ck_assert(b != bits_of(4, 77, 32, 5, 9, dim));
        ck_assert(b != bits_of(3, 78, 32, 5, 9, dim));
        ck_assert(b != bits_of(3, 77, 32, 6, 9, dim));
        ck_assert(b != bits_of(3, 77, 32, 5, 10, dim));
    }
    /* sequential draws equal seeks */
    rng_stream_t s = rng_stream_sobol(1, 2, 70);
    for (uint64_t dim = 0; dim < 40; dim++)
        ck_assert(rng_next_bits(&s) == bits_of(1, 2, 32, 2, 6, dim));
    /* past the quasi-random dimensions: the independent stream's hash */
    rng_stream_t q = rng_stream_sobol(1, 2, 70), h = rng_stream(1, 2, 70);
    for (uint64_t dim = RNG_SOBOL_DIMS; dim < RNG_SOBOL_DIMS + 16; dim++)
        ck_assert(rng_bits_at(&q, dim) == rng_bits_at(&h, dim));
    /* the independent stream draws in order: rng_seek leaves it alone */
    rng_stream_t a = rng_stream(1, 2, 3), b = rng_stream(1, 2, 3);
    rng_seek(&a, 9);
    ck_assert(rng_next_float(&a) == rng_next_float(&b));
}
END_TEST

/* The second Sobol dimension (reversed) against its generator matrix,
 * Pascal's triangle mod 2 built by Pascal's rule: column c of the index's
 * bit c holds C(c, r) mod 2 in bit r. Every index below 2^20, and the
 * top of the 24-bit range. */
START_TEST(test_sobol_second_dimension_matrix)
{
    uint32_t column[RNG_SOBOL_INDEX_BITS];
    uint32_t row = 1; /* C(c, r) mod 2 for r = 0..c, in bit r */
    for (int c = 0; c < RNG_SOBOL_INDEX_BITS; c++) {
        column[c] = row;
        row ^= row << 1; /* C(c + 1, r) = C(c, r) + C(c, r - 1) */
    }
    for (uint32_t k = 0; k < (1u << 20) + 4096; k++) {
        uint32_t i = k < (1u << 20) ? k : (1u << RNG_SOBOL_INDEX_BITS) - 1 - (k - (1u << 20));
        uint32_t want = 0;
        for (int c = 0; c < RNG_SOBOL_INDEX_BITS; c++)
            if (i >> c & 1)
                want ^= column[c];
        ck_assert_msg(rng_sobol1_reversed(i) == want, "index %u: %08x, the matrix %08x", i,
                      rng_sobol1_reversed(i), want);
    }
}
END_TEST

/* rng_sobol_fill (eight streams at a time in vectors where the host has
 * AVX2, sixteen where it has AVX-512 and the call asks for them) gives the
 * bits each stream computes alone, for every pair, index and sequence;
 * draws outside what it filled are untouched. */
START_TEST(test_sobol_fill_same_bits)
{
    enum { N = 4099 }; /* not a multiple of the eight or sixteen lanes */
    static rng_stream_t filled[N], alone[N];
    static rng_stream_t *ptr[N];
    static uint32_t first[N];
    for (uint32_t case_ = 0; case_ < 2 * RNG_BATCH_PAIRS; case_++) {
        uint32_t pairs = 1 + case_ % RNG_BATCH_PAIRS;
        int wide = (int)(case_ / RNG_BATCH_PAIRS);
        for (size_t i = 0; i < N; i++) {
            uint64_t h = rng_mix64(i * 7919 + pairs);
            /* indices over all 24 bits, and other sequences (replicates) */
            uint64_t pixel = h >> 40, sample = (h & 0xffffff) | ((h >> 60) << RNG_REPLICATE_SHIFT);
            /* and runs of one task's samples (one sequence), as the
             * engine fills them */
            if (i % 4 != 0) {
                pixel = i / 64;
                sample = i % 64 + ((i / 64 % 3) << RNG_REPLICATE_SHIFT);
            }
            filled[i] =
                i % 97 == 5 ? rng_stream(9, pixel, sample) : rng_stream_sobol(9, pixel, sample);
            alone[i] = filled[i];
            ptr[i] = &filled[i];
            /* some past the quasi-random pairs: left to the hash */
            first[i] = (uint32_t)(i % 2 ? h >> 32 : i / 256) % (RNG_SOBOL_DIMS / 2 + 1);
        }
        rng_sobol_fill(ptr, N, first, pairs, wide);
        for (size_t i = 0; i < N; i++) {
            for (uint64_t dim = 0; dim < RNG_SOBOL_DIMS + 4; dim++) {
                rng_stream_t a = filled[i], b = alone[i];
                rng_seek(&a, dim);
                rng_seek(&b, dim);
                ck_assert_msg(rng_next_bits(&a) == rng_next_bits(&b),
                              "stream %zu, dim %llu, first pair %u", i, (unsigned long long)dim,
                              (unsigned)first[i]);
            }
            if (filled[i].sobol && first[i] + pairs <= RNG_SOBOL_DIMS / 2)
                ck_assert_uint_eq(filled[i].batch_pairs, pairs);
            else
                ck_assert_uint_eq(filled[i].batch_pairs, 0);
        }
        /* a later fill replaces the batch */
        rng_sobol_fill(ptr, 1, (const uint32_t[]){0}, 1, wide);
        ck_assert(filled[0].batch_pair == 0 || !filled[0].sobol);
    }
}
END_TEST

START_TEST(test_sobol_range)
{
    float lo = 1, hi = 0;
    for (uint32_t layer = 0; layer < 64; layer++)
        for (uint32_t i = 0; i < 32; i++) {
            rng_stream_t s = rng_stream_sobol(7, layer * 31u, layer * 32u + i);
            for (int d = 0; d < RNG_SOBOL_DIMS + 4; d++) {
                float u = rng_next_float(&s);
                ck_assert(u >= 0.0f && u < 1.0f);
                lo = u < lo ? u : lo;
                hi = u > hi ? u : hi;
            }
            s.dim = 0;
            for (int d = 0; d < RNG_SOBOL_DIMS + 4; d++) {
                double v = rng_next_double(&s);
                ck_assert(v >= 0.0 && v < 1.0);
            }
        }
    ck_assert(lo < 1e-3f && hi > 1.0f - 1e-3f);
}
END_TEST

/* A layer of G = 2^m samples in `dims` dimensions dim[0..dims) is a
 * (t, m, dims)-net: each elementary box of volume 2^(t-m) (sides 2^-a_k,
 * a_1 + ... + a_dims = m - t) holds exactly 2^t of its points. */
static void check_net_dims(uint64_t seed, uint64_t pixel, uint32_t m, uint32_t layer,
                           const uint64_t *dim, int dims, uint32_t t)
{
    const uint32_t g = 1u << m;
    static uint32_t x[4][4096];
    for (uint32_t i = 0; i < g; i++)
        for (int k = 0; k < dims; k++)
            x[k][i] = (uint32_t)(bits_of(seed, pixel, g, layer, i, dim[k]) >> 32);
    static uint16_t count[4096];
    uint32_t a[4] = {0}; /* the box's shape: every composition of m - t */
    for (;;) {
        uint32_t used = 0;
        for (int k = 0; k + 1 < dims; k++)
            used += a[k];
        if (used <= m - t) {
            a[dims - 1] = m - t - used;
            memset(count, 0, sizeof count);
            for (uint32_t i = 0; i < g; i++) {
                uint32_t cell = 0;
                for (int k = 0; k < dims; k++)
                    cell = (cell << a[k]) | (a[k] ? x[k][i] >> (32 - a[k]) : 0);
                count[cell]++;
            }
            for (uint32_t c = 0; c < (1u << (m - t)); c++)
                ck_assert_msg(count[c] == 1u << t,
                              "G %u layer %u dims %lu,%lu..: box %u,%u,%u,%u cell %u holds %u, "
                              "not 2^%u",
                              g, layer, (unsigned long)dim[0], (unsigned long)dim[1], a[0], a[1],
                              a[2], a[3], c, count[c], t);
        }
        /* the next shape: a[0..dims-1) counted up to m - t */
        int k = dims - 2;
        while (k >= 0 && a[k] == m - t) /* (a carry) */
            a[k--] = 0;
        if (k < 0)
            break;
        a[k]++;
    }
}

/* A layer of G = 2^m samples, pair (2k, 2k + 1): exactly one point in each
 * elementary interval [a 2^-j, (a+1) 2^-j) x [b 2^-(m-j), (b+1) 2^-(m-j)),
 * but for the pair joined with the camera pair's (rng.h), whose own
 * projection is the third and fourth Sobol dimensions': t <= 2 up to
 * 2^12 samples (1 from 2^4 to 2^10, 2 at 2^3, 2^11 and 2^12). */
static void check_net(uint64_t seed, uint64_t pixel, uint32_t m, uint32_t layer, uint64_t pair)
{
    const uint64_t dim[2] = {2 * pair, 2 * pair + 1};
    uint32_t t = rng_sobol_partner((uint32_t)pair) == pair ? 0
                 : m <= 1                                  ? 0
                 : m == 3 || m >= 11                       ? 2
                 : m == 4                                  ? 0
                                                           : 1;
    check_net_dims(seed, pixel, m, layer, dim, 2, t);
}

START_TEST(test_sobol_layer_is_a_net)
{
    for (uint64_t pair = 0; pair < RNG_SOBOL_DIMS / 2; pair++)
        for (uint32_t layer = 0; layer < 8; layer++) {
            check_net(11, 1000 + layer, 5, layer, pair); /* G = 32, the default */
            check_net(12, 3, 4, layer, pair);
            check_net(13, 5, 0, layer, pair);
        }
    check_net(14, 6, 10, 3, 2);
    check_net(15, 7, 12, 1, 0); /* G = 4096, the largest */
}
END_TEST

/* 1 if pairs a and b of a layer of 2^8 samples fill the 32 boxes of
 * sides 1/4, 1/2, 1/2, 1/2 evenly, 8 points each, as a (3,8,4)-net does;
 * independent pairs almost never do. */
static int boxes_even(uint64_t seed, uint64_t pixel, uint64_t a, uint64_t b)
{
    enum { M = 8, G = 1 << M, BOXES = 32 };
    uint16_t count[BOXES] = {0};
    const uint64_t dim[4] = {2 * a, 2 * a + 1, 2 * b, 2 * b + 1};
    static const int bits[4] = {2, 1, 1, 1};
    for (uint32_t i = 0; i < G; i++) {
        uint32_t cell = 0;
        for (int d = 0; d < 4; d++)
            cell = (cell << bits[d]) |
                   (uint32_t)(bits_of(seed, pixel, G, 0, i, dim[d]) >> (64 - bits[d]));
        count[cell]++;
    }
    for (uint32_t c = 0; c < BOXES; c++)
        if (count[c] != G / BOXES)
            return 0;
    return 1;
}

/* A joined pair and its partner are one 4D Sobol net: the film point and
 * the first light point, the first and second BSDF directions, each
 * stratified with the other, in a layer and in a pixel's first 2^m
 * samples (t from the four dimensions' generator matrices: 2 up to 2^7
 * samples, 3 at 2^8 and 2^9, 2 at 2^10 and 2^11). Padded pairs are not:
 * the light pair with the BSDF pair, the camera's with the BSDF's. */
START_TEST(test_sobol_joined_pairs_are_nets)
{
    static const uint64_t joined[2] = {RNG_SOBOL_LIGHT_PAIR, RNG_SOBOL_BSDF2_PAIR};
    for (int k = 0; k < 2; k++) {
        uint64_t partner = rng_sobol_partner((uint32_t)joined[k]);
        ck_assert_uint_ne(partner, joined[k]);
        ck_assert_uint_eq(rng_sobol_partner((uint32_t)partner), partner); /* no chains */
        const uint64_t dim[4] = {2 * partner, 2 * partner + 1, 2 * joined[k], 2 * joined[k] + 1};
        for (uint32_t m = 2; m <= 11; m++) {
            uint32_t t = m == 8 || m == 9 ? 3 : 2;
            check_net_dims(31 + (uint64_t)k, 90 + m, m, 0, dim, 4, t);
            check_net_dims(33 + (uint64_t)k, 7, m, 5, dim, 4, t); /* a layer deep in */
        }
        /* each of the 2D projections across the two pairs: t <= 2 */
        for (int a = 0; a < 2; a++)
            for (int b = 2; b < 4; b++)
                for (uint32_t m = 4; m <= 12; m++) {
                    const uint64_t d2[2] = {dim[a], dim[b]};
                    check_net_dims(35, 11 * m, m, 1, d2, 2, 2);
                }
        ck_assert(boxes_even(36, 3 + (uint64_t)k, partner, joined[k]));
    }
    /* padded pairs: the first light pair and BSDF pair, the camera pair
     * and the first BSDF pair, the second light pair and BSDF pair */
    ck_assert_msg(!boxes_even(37, 3, RNG_SOBOL_LIGHT_PAIR, 3), "light and BSDF pairs form a net");
    ck_assert_msg(!boxes_even(38, 3, 0, 3), "camera and BSDF pairs form a net");
    ck_assert_msg(!boxes_even(39, 3, 5, RNG_SOBOL_BSDF2_PAIR), "second light and BSDF form a net");
}
END_TEST

/* The third and fourth Sobol dimensions against their generator matrices,
 * from the polynomials x^2 + x + 1 and x^3 + x + 1 and the initial
 * direction numbers 1, 3 and 1, 3, 1 (Joe and Kuo's; Bratley and Fox's
 * recurrence). */
START_TEST(test_sobol_third_fourth_dimension_matrix)
{
    static const uint32_t degree[2] = {2, 3}, coeffs[2] = {1, 1}, init[2][3] = {{1, 3}, {1, 3, 1}};
    uint32_t column[2][RNG_SOBOL_INDEX_BITS];
    for (int d = 0; d < 2; d++) {
        uint32_t mk[RNG_SOBOL_INDEX_BITS + 1];
        uint32_t s = degree[d];
        for (uint32_t k = 1; k <= RNG_SOBOL_INDEX_BITS; k++) {
            if (k <= s) {
                mk[k] = init[d][k - 1];
            } else {
                mk[k] = mk[k - s] ^ (mk[k - s] << s);
                for (uint32_t i = 1; i < s; i++)
                    if (coeffs[d] >> (s - 1 - i) & 1)
                        mk[k] ^= mk[k - i] << i;
            }
            /* v_k = m_k / 2^k, reversed: m_k's k bits reversed, at the bottom */
            uint32_t r = 0;
            for (uint32_t b = 0; b < k; b++)
                r |= (mk[k] >> b & 1) << (k - 1 - b);
            column[d][k - 1] = r;
        }
    }
    for (uint32_t k = 0; k < (1u << 16) + 4096; k++) {
        uint32_t i = k < (1u << 16) ? k * 97u % (1u << RNG_SOBOL_INDEX_BITS)
                                    : (1u << RNG_SOBOL_INDEX_BITS) - 1 - (k - (1u << 16));
        uint32_t want[2] = {0, 0}, got[2];
        for (int c = 0; c < RNG_SOBOL_INDEX_BITS; c++)
            if (i >> c & 1) {
                want[0] ^= column[0][c];
                want[1] ^= column[1][c];
            }
        rng_sobol23_reversed(i, got);
        ck_assert_msg(got[0] == want[0] && got[1] == want[1], "index %u: %08x %08x, want %08x %08x",
                      i, got[0], got[1], want[0], want[1]);
    }
}
END_TEST

/* A pixel's samples are one sequence: its first 2^m samples (the layers of
 * G = 32 it took so far, under uniform sampling) form a (0, m, 2)-net, for
 * every m, and so does any aligned block deep into it. */
START_TEST(test_sobol_pixel_is_a_sequence)
{
    for (uint64_t pair = 0; pair < RNG_SOBOL_DIMS / 2; pair++)
        for (uint32_t m = 5; m <= 12; m++)
            check_net(16, 40 + pair, m, 0, pair);
    check_net(17, 8, 11, 300, 1); /* samples 614400 .. 616447 */
}
END_TEST

START_TEST(test_sobol_pixels_and_sequences_differ)
{
    /* two pixels, and the same place in two sequences of one pixel (sample
     * i and i + 2^RNG_SOBOL_INDEX_BITS), give unrelated points: about one
     * in 32 shares its 1/32 stratum by chance */
    const uint64_t next = (uint64_t)1 << RNG_SOBOL_INDEX_BITS;
    for (uint64_t dim = 0; dim < RNG_SOBOL_DIMS; dim++) {
        int same = 0;
        for (uint32_t i = 0; i < 32; i++) {
            rng_stream_t p = rng_stream_sobol(9, 4, i), q = rng_stream_sobol(9, 5, i);
            rng_stream_t r = rng_stream_sobol(9, 4, next + i);
            rng_seek(&p, dim);
            rng_seek(&q, dim);
            rng_seek(&r, dim);
            uint32_t a = (uint32_t)(rng_next_bits(&p) >> 32);
            uint32_t b = (uint32_t)(rng_next_bits(&q) >> 32);
            uint32_t c = (uint32_t)(rng_next_bits(&r) >> 32);
            same += (a >> 27) == (b >> 27);
            same += (a >> 27) == (c >> 27);
        }
        ck_assert_msg(same < 16, "dimension %lu: %d of 64 points share their 1/32 stratum",
                      (unsigned long)dim, same);
    }
}
END_TEST

typedef struct replicates {
    double mean; /* over replicates of the replicate means */
    double var;  /* variance of one replicate's mean */
} replicates_t;

/* R replicates (a layer of G samples of each of R pixels, so independent)
 * of the mean of u_dx * u_dy. */
static replicates_t product_replicates(int sobol, uint64_t dx, uint64_t dy, uint32_t g, int r)
{
    double sum = 0, sum2 = 0;
    for (int k = 0; k < r; k++) {
        uint32_t pixel = (uint32_t)k, layer = (uint32_t)k % 4;
        double m = 0;
        for (uint32_t i = 0; i < g; i++) {
            double x, y;
            if (sobol) {
                x = unit_of(21, pixel, g, layer, i, dx);
                y = unit_of(21, pixel, g, layer, i, dy);
            } else {
                rng_stream_t s = rng_stream(21, pixel, (uint64_t)layer * g + i);
                x = rng_next_double(&s);
                y = rng_next_double(&s);
            }
            m += x * y;
        }
        m /= g;
        sum += m;
        sum2 += m * m;
    }
    replicates_t out = {sum / r, 0};
    out.var = (sum2 - sum * sum / r) / (r - 1);
    return out;
}

START_TEST(test_sobol_unbiased_and_better)
{
    enum { R = 4096, G = 32 };
    replicates_t ind = product_replicates(0, 0, 1, G, R);
    /* pairs (0,1), (2,3) ... the last (L, L+1); then across pairs and into
     * the hash */
    enum { L = RNG_SOBOL_DIMS - 2 };
    static const uint64_t dims[][2] = {{0, 1},         {2, 3},        {4, 5}, {L, L + 1},
                                       {0, 2},         {1, 5},        {3, L}, {L + 1, L + 2},
                                       {L + 2, L + 3}, {L + 8, L + 9}};
    for (size_t k = 0; k < sizeof dims / sizeof dims[0]; k++) {
        replicates_t s = product_replicates(1, dims[k][0], dims[k][1], G, R);
        double se = sqrt(s.var / R);
        ck_assert_msg(fabs(s.mean - 0.25) <= 5 * se + 1e-12, "dims %lu,%lu: mean %.6f (se %.2g)",
                      (unsigned long)dims[k][0], (unsigned long)dims[k][1], s.mean, se);
        int same_pair =
            dims[k][1] == dims[k][0] + 1 && dims[k][0] % 2 == 0 && dims[k][1] < RNG_SOBOL_DIMS;
        if (same_pair) /* a 2D net: far below independent points' variance */
            ck_assert_msg(s.var < ind.var / 20, "dims %lu,%lu: variance %.3g vs independent %.3g",
                          (unsigned long)dims[k][0], (unsigned long)dims[k][1], s.var, ind.var);
        else /* across pairs: each 1D stratified at least, never worse */
            ck_assert_msg(s.var < ind.var * 1.2, "dims %lu,%lu: variance %.3g vs independent %.3g",
                          (unsigned long)dims[k][0], (unsigned long)dims[k][1], s.var, ind.var);
    }
    /* a layer that is not a power of two (G = 24) is still unbiased */
    replicates_t odd = product_replicates(1, 2, 3, 24, R);
    ck_assert(fabs(odd.mean - 0.25) <= 5 * sqrt(odd.var / R));
}
END_TEST

/* The adaptive modes and the target error estimate the error of a pixel's
 * mean from the spread of its layer means, as if they were independent.
 * Within one sequence they are not: later layers fill the strata earlier
 * ones left, so the mean of k layers is better than k independent layers
 * would give. Check that the estimate errs on that side only: over R
 * pixels, the mean of s^2 / k (s^2: the sample variance of a pixel's k
 * layer means) is well above the variance of the pixels' means for a
 * smooth integrand, a discontinuous one and one across pairs, and equal to
 * it in the hashed dimensions, whose layers are independent. */
typedef double (*integrand_fn)(rng_stream_t *s);

static double smooth_product(rng_stream_t *s)
{
    rng_seek(s, 2);
    double x = rng_next_double(s), y = rng_next_double(s);
    return x * y;
}

static double disc_triangle(rng_stream_t *s)
{
    rng_seek(s, 0);
    double x = rng_next_double(s), y = rng_next_double(s);
    return x + y < 0.7 ? 1.0 : 0.0;
}

static double across_pairs(rng_stream_t *s)
{
    rng_seek(s, 3);
    double x = rng_next_double(s), y = rng_next_double(s); /* dims 3 and 4 */
    return (x < 0.3) + y * y;
}

static double hashed_dims(rng_stream_t *s)
{
    rng_seek(s, RNG_SOBOL_DIMS + 1);
    double x = rng_next_double(s), y = rng_next_double(s);
    return x < 0.2 ? 5.0 * y : 0.0;
}

START_TEST(test_sobol_layer_spread_conservative)
{
    enum { R = 4096, K = 8, G = 32 };
    static const struct {
        const char *name;
        integrand_fn f;
        double min_ratio, max_ratio; /* estimate / true variance of the mean */
    } cases[] = {
        /* measured 35x, 3.4x, 14x and 1.00x; independent layers give 1 */
        {"smooth", smooth_product, 5.0, 1e9},
        {"discontinuous", disc_triangle, 1.5, 1e9},
        {"across pairs", across_pairs, 3.0, 1e9},
        {"hashed", hashed_dims, 0.9, 1.12},
    };
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++) {
        double est = 0, sum = 0, sum2 = 0;
        for (uint32_t p = 0; p < R; p++) {
            double lm[K], mean = 0;
            for (uint32_t l = 0; l < K; l++) {
                lm[l] = 0;
                for (uint32_t i = 0; i < G; i++) {
                    rng_stream_t s = rng_stream_sobol(31, p, (uint64_t)l * G + i);
                    lm[l] += cases[c].f(&s);
                }
                lm[l] /= G;
                mean += lm[l] / K;
            }
            double s2 = 0;
            for (uint32_t l = 0; l < K; l++)
                s2 += (lm[l] - mean) * (lm[l] - mean) / (K - 1);
            est += s2 / K / R;
            sum += mean;
            sum2 += mean * mean;
        }
        double truth = (sum2 - sum * sum / R) / (R - 1);
        double ratio = est / truth;
        ck_assert_msg(ratio >= cases[c].min_ratio && ratio <= cases[c].max_ratio,
                      "%s: layer spread gives %.3g for a variance of the mean of %.3g (%.2fx)",
                      cases[c].name, est, truth, ratio);
    }
}
END_TEST

/* Each point alone is uniform over replicates: the first, a middle and the
 * last sample of a layer, per dimension (chi-square, 64 cells). */
START_TEST(test_sobol_points_uniform)
{
    enum { BINS = 64, R = 16384 };
    static const uint32_t which[3] = {0, 13, 31};
    for (uint64_t dim = 0; dim < RNG_SOBOL_DIMS; dim += 3)
        for (int w = 0; w < 3; w++) {
            uint32_t hist[BINS] = {0};
            for (uint32_t k = 0; k < R; k++)
                hist[(int)(unit_of(5, k, 32, k % 7, which[w], dim) * BINS)]++;
            double e = (double)R / BINS, chi2 = 0;
            for (int b = 0; b < BINS; b++)
                chi2 += (hist[b] - e) * (hist[b] - e) / e;
            double limit = BINS - 1 + 6.0 * sqrt(2.0 * (BINS - 1));
            ck_assert_msg(chi2 < limit, "dimension %lu, sample %u: chi2 %.1f", (unsigned long)dim,
                          which[w], chi2);
        }
}
END_TEST

static Suite *sampler_suite(void)
{
    Suite *s = suite_create("sampler");
    TCase *tc = tcase_create("sobol");
    tcase_set_timeout(tc, 120);
    tcase_add_test(tc, test_sobol_pure_function);
    tcase_add_test(tc, test_sobol_second_dimension_matrix);
    tcase_add_test(tc, test_sobol_third_fourth_dimension_matrix);
    tcase_add_test(tc, test_sobol_joined_pairs_are_nets);
    tcase_add_test(tc, test_sobol_fill_same_bits);
    tcase_add_test(tc, test_sobol_range);
    tcase_add_test(tc, test_sobol_layer_is_a_net);
    tcase_add_test(tc, test_sobol_pixel_is_a_sequence);
    tcase_add_test(tc, test_sobol_pixels_and_sequences_differ);
    tcase_add_test(tc, test_sobol_layer_spread_conservative);
    tcase_add_test(tc, test_sobol_unbiased_and_better);
    tcase_add_test(tc, test_sobol_points_uniform);
    suite_add_tcase(s, tc);
    return s;
}

int main(void)
{
    SRunner *sr = srunner_create(sampler_suite());
    srunner_run_all(sr, CK_NORMAL);
    int failed = srunner_ntests_failed(sr);
    srunner_free(sr);
    return failed == 0 ? 0 : 1;
}
