/* camera.h - the pinhole camera: position, look-at point, up vector and
 * vertical field of view, as in the Cornell box data. Image row 0 is the
 * top; the image's +x is forward x up, so the published Cornell box (red
 * wall at x = 556) shows its red wall on the left, as every picture of it
 * does. Pixels use a box filter: a sample's position is uniform in the
 * pixel square. */
#ifndef VB_CAMERA_H
#define VB_CAMERA_H

#include <stddef.h>
#include <stdint.h>

#include "vmath.h"

typedef struct camera {
    vec3_t position, forward, right, up; /* right and up scaled to the film */
    int width, height;
} camera_t;

/* Fills c; returns -1 with a message when the basis is degenerate (look_at
 * equal to position, up parallel to the view) or the fov is outside (0,180). */
int camera_init(camera_t *c, vec3_t position, vec3_t look_at, vec3_t up, double fov_deg, int width,
                int height, char *err, size_t errlen);

/* Direction (not normalised) of the ray through film point (px+u1, py+u2). */
static inline vec3_t camera_ray_dir(const camera_t *c, uint32_t px, uint32_t py, float u1, float u2)
{
    float sx = 2.0f * ((float)px + u1) / (float)c->width - 1.0f;
    float sy = 1.0f - 2.0f * ((float)py + u2) / (float)c->height;
    return vec3_add(c->forward, vec3_add(vec3_scale(c->right, sx), vec3_scale(c->up, sy)));
}

#endif
