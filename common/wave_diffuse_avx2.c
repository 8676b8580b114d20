/* wave_diffuse_avx2.c - the diffuse kernel (wave_diffuse.c) built for
 * AVX2 at 8 lanes, for hosts that have it (wave.h, WAVE_LANES_AVX2). The
 * Makefile builds this file with -mavx2: everything it compiles, the
 * inline functions of the headers included, so the kernel calls nothing
 * built without AVX on its common path. No FMA: -mavx2 does not imply
 * it, and -ffp-contract=off keeps each product and sum rounded as in the
 * baseline build. */
#define DIFFUSE_AVX2
#include "wave_diffuse.c"
