/* wave_glossy.c - the wavefront kernel of the glossy materials (conductor,
 * plastic, thin and rough dielectric: material_glossy_* in material.h), path by
 * path. The stages still gather each material's paths into a queue of
 * their own, so a scene without these materials never runs this file; a
 * material that measures faster with a SIMD kernel of its own (as diffuse
 * has) gets one in wave.c's table. Each path runs tracer_shade_glossy, the
 * scalar engine's own shading, so the bits are the same. */
#include "wave.h"

void wave_kernel_glossy(const wave_ctx_t *c, wave_state_t *w, const uint16_t *slots, size_t n)
{
    wave_sobol_ahead(c, w, slots, n);
    for (size_t j = 0; j < n; j++) {
        uint16_t s = slots[j];
        vec3_t p;
        material_hit_t mh;
        material_t textured;
        tracer_hit_t h = {.tri = w->tri[s], .u = w->u[s], .v = w->v[s]};
        const material_t *m =
            tracer_textured(c->scene, wave_surface(c, w, s, &p, &mh), &h, &textured);
        material_sample_t bs;
        int shadow;
        w->alive[s] = (uint8_t)tracer_shade_glossy(c->scene, m, &w->rng[s], w->depth[s], c->nee,
                                                   w->beta[s], p, &mh, &shadow, &w->shadow_o[s],
                                                   &w->shadow_d[s], &w->shadow_L[s], &bs);
        w->shadow[s] = (uint8_t)shadow;
        if (w->alive[s])
            wave_follow(w, s, p, &mh, &bs);
    }
}
