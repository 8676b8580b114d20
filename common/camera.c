/* camera.c - see camera.h. */
#include "camera.h"

#include <stdio.h>

int camera_init(camera_t *c, vec3_t position, vec3_t look_at, vec3_t up, double fov_deg, int width,
                int height, char *err, size_t errlen)
{
    if (!(fov_deg > 0.0 && fov_deg < 180.0)) {
        snprintf(err, errlen, "fov must be between 0 and 180 degrees (got %g)", fov_deg);
        return -1;
    }
    vec3_t fwd = vec3_sub(look_at, position);
    if (!(vec3_length(fwd) > 0.0f)) {
        snprintf(err, errlen, "look_at equals position: no view direction");
        return -1;
    }
    fwd = vec3_normalize(fwd);
    vec3_t right = vec3_cross(fwd, up);
    float rl = vec3_length(right);
    if (!(rl > 1e-6f * vec3_length(up))) {
        snprintf(err, errlen, "up is zero or parallel to the view direction");
        return -1;
    }
    right = vec3_scale(right, 1.0f / rl);
    vec3_t true_up = vec3_cross(right, fwd);
    float tan_half = (float)tan(fov_deg * 0.5 * 3.14159265358979323846 / 180.0);
    float aspect = (float)width / (float)height;
    c->position = position;
    c->forward = fwd;
    c->right = vec3_scale(right, tan_half * aspect);
    c->up = vec3_scale(true_up, tan_half);
    c->width = width;
    c->height = height;
    return 0;
}
