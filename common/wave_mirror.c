/* wave_mirror.c - the wavefront kernel of mirrors: a specular reflection
 * about the shading normal, weighted by the reflectance. */
#include "wave.h"

void wave_kernel_mirror(const wave_ctx_t *c, wave_state_t *w, const uint16_t *slots, size_t n)
{
    for (size_t j = 0; j < n; j++) {
        uint16_t s = slots[j];
        vec3_t p;
        material_hit_t mh;
        const material_t *m = wave_surface(c, w, s, &p, &mh);
        material_sample_t bs;
        w->shadow[s] = 0;
        w->alive[s] = material_sample_reflection(&mh, m->albedo, &bs);
        if (w->alive[s])
            wave_follow(w, s, p, &mh, &bs);
    }
}
