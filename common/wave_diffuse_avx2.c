/* wave_diffuse_avx2.c - the diffuse kernel (wave_diffuse.c) built for
 * AVX2 at 8 lanes, for hosts that have it (wave.h, WAVE_LANES_AVX2). The
 * target applies to everything this file compiles, the inline functions
 * of the headers included, so the kernel calls nothing built without AVX
 * on its common path. No FMA: AVX2 alone does not imply it, and
 * -ffp-contract=off keeps each product and sum rounded as in the
 * baseline build. */
#pragma GCC target("avx2")
#define DIFFUSE_AVX2
#include "wave_diffuse.c"
