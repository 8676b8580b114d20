/* wave_diffuse_avx512.c - the diffuse kernel (wave_diffuse.c) built for
 * AVX-512 at 16 lanes, as wave_diffuse_avx2.c builds it for AVX2 (the
 * Makefile's flags; no FMA: -ffp-contract=off keeps each product and sum
 * rounded as in the baseline build). The tracer picks it only beside the
 * triangle list's AVX-512 kernel (tracer.c, shading_lanes_for). */
#define DIFFUSE_AVX512
#include "wave_diffuse.c"
