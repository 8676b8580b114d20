/* wave_dielectric.c - the wavefront kernel of smooth glass: Fresnel
 * reflection or refraction, chosen by one number. */
#include "wave.h"

void wave_kernel_dielectric(const wave_ctx_t *c, wave_state_t *w, const uint16_t *slots, size_t n)
{
    for (size_t j = 0; j < n; j++) {
        uint16_t s = slots[j];
        vec3_t p;
        material_hit_t mh;
        const material_t *m = wave_surface(c, w, s, &p, &mh);
        material_sample_t bs;
        w->shadow[s] = 0;
        rng_seek(&w->rng[s], tracer_bounce_dim(w->depth[s]) + 4);
        w->alive[s] = material_sample_dielectric(m, &mh, &w->rng[s], &bs);
        if (w->alive[s])
            wave_follow(w, s, p, &mh, &bs);
    }
}
