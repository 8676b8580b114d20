/* camera.h - the pinhole camera: position, look-at point, up vector and
 * vertical field of view, as in the Cornell box data. Image row 0 is the
 * top; the image's +x is forward x up, so the published Cornell box (red
 * wall at x = 556) shows its red wall on the left, as every picture of it
 * does. Pixels use a box filter: a sample's position is uniform in the
 * pixel square. */
#ifndef VB_CAMERA_H
#define VB_CAMERA_H

#include <math.h>
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
    int width, height;                   /* the image: the crop window of the film */
    /* the film rays are laid out over, and the window of it the image is
     * (Mitsuba's crop; the whole film unless camera_set_crop) */
    int film_width, film_height, crop_x, crop_y;
    camera_filter_t filter;
    /* a thin lens (Mitsuba's thinlens) when aperture > 0: rays leave a disk
     * of that radius around the position, through the point the pinhole
     * ray meets at focus_distance along forward */
    float aperture, focus_distance;
    vec3_t right_unit, up_unit;
    /* orthographic (Mitsuba's): rays along forward from the film's point
     * on a plane (right and up then hold its half extents), ortho_near in
     * front of position */
    int ortho;
    float ortho_near;
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

/* Renders only the window (x, y, w, h) of the film camera_init laid out:
 * the image becomes w x h (width, height), its rays those of the film's
 * pixels there. -1 with a message when the window leaves the film. */
int camera_set_crop(camera_t *c, int x, int y, int w, int h, char *err, size_t errlen);

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

/* Makes c orthographic: the film spans half_w along right and half_h along
 * up from position, rays start near in front of it. -1 with a message
 * unless the extents are positive and near >= 0. */
int camera_set_orthographic(camera_t *c, double half_w, double half_h, double near, char *err,
                            size_t errlen);

/* Makes c a thin-lens camera: 0 < aperture (radius), 0 < focus_distance.
 * Returns -1 with a message otherwise. */
int camera_set_thinlens(camera_t *c, double aperture, double focus_distance, char *err,
                        size_t errlen);

/* The thin lens's ray for the pinhole direction dir (camera_ray_dir) and
 * two uniforms on the lens (Shirley and Chiu's concentric disk). */
static inline void camera_thinlens(const camera_t *c, vec3_t dir, float u1, float u2, vec3_t *o,
                                   vec3_t *d)
{
    float a = 2.0f * u1 - 1.0f, b = 2.0f * u2 - 1.0f, r = 0.0f, phi = 0.0f;
    if (a != 0.0f || b != 0.0f) {
        if (fabsf(a) > fabsf(b)) {
            r = a;
            phi = (VMATH_PI / 4.0f) * (b / a);
        } else {
            r = b;
            phi = (VMATH_PI / 2.0f) - (VMATH_PI / 4.0f) * (a / b);
        }
    }
    float lx = c->aperture * r * cosf(phi), ly = c->aperture * r * sinf(phi);
    vec3_t lens =
        vec3_add(c->position, vec3_add(vec3_scale(c->right_unit, lx), vec3_scale(c->up_unit, ly)));
    vec3_t focus = vec3_add(c->position, vec3_scale(dir, c->focus_distance));
    *o = lens;
    *d = vec3_normalize(vec3_sub(focus, lens));
}

/* Direction (not normalised) of the ray through the film point of pixel
 * (px, py) that the filter gives uniforms (u1, u2): (px+u1, py+u2) under
 * the box filter. */
static inline vec3_t camera_ray_dir(const camera_t *c, uint32_t px, uint32_t py, float u1, float u2)
{
    u1 = camera_filter_pos(c, u1);
    u2 = camera_filter_pos(c, u2);
    float sx = 2.0f * ((float)(px + (uint32_t)c->crop_x) + u1) / (float)c->film_width - 1.0f;
    float sy = 1.0f - 2.0f * ((float)(py + (uint32_t)c->crop_y) + u2) / (float)c->film_height;
    return vec3_add(c->forward, vec3_add(vec3_scale(c->right, sx), vec3_scale(c->up, sy)));
}

#endif
