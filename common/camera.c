/* camera.c - see camera.h. */
#include "camera.h"

#include <math.h>
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
    c->film_width = width;
    c->film_height = height;
    c->crop_x = c->crop_y = 0;
    c->filter = CAMERA_FILTER_BOX;
    c->aperture = 0.0f;
    c->focus_distance = 0.0f;
    c->right_unit = right;
    c->up_unit = true_up;
    c->ortho = 0;
    c->ortho_near = 0.0f;
    return 0;
}

int camera_set_orthographic(camera_t *c, double half_w, double half_h, double near, char *err,
                            size_t errlen)
{
    if (!(half_w > 0 && half_w < 1e30 && half_h > 0 && half_h < 1e30 && near >= 0 && near < 1e30)) {
        snprintf(err, errlen, "an orthographic camera needs positive extents and near >= 0");
        return -1;
    }
    c->ortho = 1;
    c->ortho_near = (float)near;
    c->right = vec3_scale(c->right_unit, (float)half_w);
    c->up = vec3_scale(c->up_unit, (float)half_h);
    return 0;
}

int camera_set_thinlens(camera_t *c, double aperture, double focus_distance, char *err,
                        size_t errlen)
{
    if (!(aperture > 0 && aperture < 1e30) || !(focus_distance > 0 && focus_distance < 1e30)) {
        snprintf(err, errlen,
                 "a thin lens needs aperture_radius > 0 and focus_distance > 0 (got %g, %g)",
                 aperture, focus_distance);
        return -1;
    }
    c->aperture = (float)aperture;
    c->focus_distance = (float)focus_distance;
    return 0;
}

/* The gaussian's CDF on [-r, r], unnormalised: the integral from -r to x
 * of exp(-t^2 / (2 s^2)) - exp(-r^2 / (2 s^2)). */
static double gaussian_cdf(double x, double s, double r)
{
    double k = 1.0 / (s * sqrt(2.0));
    double bias = exp(-r * r / (2 * s * s));
    return s * sqrt(M_PI / 2) * (erf(x * k) + erf(r * k)) - bias * (x + r);
}

int camera_set_gaussian(camera_t *c, double stddev, char *err, size_t errlen)
{
    if (!(stddev > 0 && stddev <= 4)) {
        snprintf(err, errlen, "the gaussian filter's stddev must be in (0, 4] pixels (got %g)",
                 stddev);
        return -1;
    }
    double r = 4 * stddev, total = gaussian_cdf(r, stddev, r);
    c->filter = CAMERA_FILTER_GAUSSIAN;
    c->filter_icdf[0] = (float)-r;
    c->filter_icdf[CAMERA_FILTER_TABLE] = (float)r;
    /* each node by bisection on the exact CDF (it increases strictly) */
    for (int i = 1; i < CAMERA_FILTER_TABLE; i++) {
        double want = total * i / CAMERA_FILTER_TABLE, lo = -r, hi = r;
        for (int it = 0; it < 100 && hi - lo > 1e-12 * r; it++) {
            double mid = 0.5 * (lo + hi);
            if (gaussian_cdf(mid, stddev, r) < want)
                lo = mid;
            else
                hi = mid;
        }
        c->filter_icdf[i] = (float)(0.5 * (lo + hi));
    }
    return 0;
}

int camera_set_crop(camera_t *c, int x, int y, int w, int h, char *err, size_t errlen)
{
    if (x < 0 || y < 0 || w < 1 || h < 1 || x > c->film_width - w || y > c->film_height - h) {
        snprintf(err, errlen, "crop window (%d, %d) %dx%d leaves the %dx%d film", x, y, w, h,
                 c->film_width, c->film_height);
        return -1;
    }
    c->crop_x = x;
    c->crop_y = y;
    c->width = w;
    c->height = h;
    return 0;
}
