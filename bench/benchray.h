/* benchray.h - one closest-hit query on an Embree scene, shared by the
 * benchmarks that cast rays outside the tracer (bench_core, bench_trilist).
 */
#ifndef VB_BENCHRAY_H
#define VB_BENCHRAY_H

#include <embree3/rtcore.h>
#include <math.h>
#include <string.h>

#include "vmath.h"

/* Casts o + t d, t > 0, with rtcIntersect1 into *rh; 1 if it hit. */
static inline int benchray_intersect(RTCScene sc, vec3_t o, vec3_t d, struct RTCRayHit *rh)
{
    struct RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    memset(rh, 0, sizeof *rh);
    rh->ray.org_x = o.x;
    rh->ray.org_y = o.y;
    rh->ray.org_z = o.z;
    rh->ray.dir_x = d.x;
    rh->ray.dir_y = d.y;
    rh->ray.dir_z = d.z;
    rh->ray.tfar = INFINITY;
    rh->ray.mask = 0xffffffffu;
    rh->hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh->hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(sc, &ctx, rh);
    return rh->hit.geomID != RTC_INVALID_GEOMETRY_ID;
}

#endif
