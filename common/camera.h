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

/* The pixel filter: where in the image plane a pixel's samples fall. Every
 * sample still belongs to one pixel (its estimate and layer statistics
 * stay the pixel's own); a filter wider than the pixel is sampled, not
 * splatted (filter importance sampling, as pbrt-v4 does), which converges
 * to what splatting with the same filter converges to. */
typedef enum camera_filter {
    CAMERA_FILTER_BOX = 0, /* uniform in the pixel square */
    /* Mitsuba 3's gaussian: exp(-x^2 / (2 stddev^2)) minus its value at
     * the radius 4 stddev, per axis, around the pixel's centre */
    CAMERA_FILTER_GAUSSIAN
} camera_filter_t;

/* Entries of a filter's inverse CDF table (linear between them). */
#define CAMERA_FILTER_TABLE 1024

typedef struct camera {
    vec3_t position, forward, right, up; /* right and up scaled to the film */
    int width, height;
    camera_filter_t filter;
    /* gaussian: the offset from the pixel's centre, in pixels, at
     * u = i / CAMERA_FILTER_TABLE */
    float filter_icdf[CAMERA_FILTER_TABLE + 1];
} camera_t;

/* Fills c; returns -1 with a message when the basis is degenerate (look_at
 * equal to position, up parallel to the view) or the fov is outside (0,180). */
int camera_init(camera_t *c, vec3_t position, vec3_t look_at, vec3_t up, double fov_deg, int width,
                int height, char *err, size_t errlen);

/* Sets a gaussian pixel filter of standard deviation stddev pixels (its
 * radius is 4 stddev). Returns -1 with a message unless 0 < stddev <= 4. */
int camera_set_gaussian(camera_t *c, double stddev, char *err, size_t errlen);

/* Where a sample with uniform u falls along one axis, from the pixel's
 * lower edge: u itself for the box filter. */
static inline float camera_filter_pos(const camera_t *c, float u)
{
    if (c->filter == CAMERA_FILTER_BOX)
        return u;
    float x = u * (float)CAMERA_FILTER_TABLE;
    int i = (int)x;
    if (i >= CAMERA_FILTER_TABLE)
        i = CAMERA_FILTER_TABLE - 1;
    float t = x - (float)i;
    return 0.5f + (1.0f - t) * c->filter_icdf[i] + t * c->filter_icdf[i + 1];
}

/* Direction (not normalised) of the ray through the film point of pixel
 * (px, py) that the filter gives uniforms (u1, u2): (px+u1, py+u2) under
 * the box filter. */
static inline vec3_t camera_ray_dir(const camera_t *c, uint32_t px, uint32_t py, float u1, float u2)
{
    u1 = camera_filter_pos(c, u1);
    u2 = camera_filter_pos(c, u2);
    float sx = 2.0f * ((float)px + u1) / (float)c->width - 1.0f;
    float sy = 1.0f - 2.0f * ((float)py + u2) / (float)c->height;
    return vec3_add(c->forward, vec3_add(vec3_scale(c->right, sx), vec3_scale(c->up, sy)));
}

#endif
