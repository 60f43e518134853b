/* Directions: tangent frames, the equal-area octahedral map (Clarberg 2008, as in
 * pbrt-v4) and the equirectangular nearest-texel lookup of the scene format.
 * numpy twins: wavlight/warp.py and wavlight/envmap.py.
 */
#ifndef WAVLIGHT_SPHERE_H
#define WAVLIGHT_SPHERE_H
#include "common.h"

#define PI_F 3.14159265358979323846f
#define INV_PI_F 0.31830988618379067154f
#define INV_2PI_F 0.15915494309189533577f
#define INV_4PI_F 0.07957747154594766788f

/* Orthonormal frame (s, t) about a unit normal n (Duff et al. 2017). */
inline void make_frame(const float3 n, float3 *s, float3 *t)
{
    const float sign = n.z >= 0.0f ? 1.0f : -1.0f;
    const float a = -1.0f / (sign + n.z);
    const float b = n.x * n.y * a;
    *s = (float3)(1.0f + sign * n.x * n.x * a, sign * b, -sign * n.x);
    *t = (float3)(b, sign + n.y * n.y * a, -n.y);
}

/* The environment: lat-long texels (float4 RGB_), rotation map_from_world (row-major 3x3). */
typedef struct {
    __global const float4 *texels;
    int width, height;
    __global const float *rot; /* map_from_world, row-major */
} Env;

inline float3 env_to_map(const Env *e, const float3 w)
{
    __global const float *m = e->rot;
    return (float3)(m[0] * w.x + m[1] * w.y + m[2] * w.z,
                    m[3] * w.x + m[4] * w.y + m[5] * w.z,
                    m[6] * w.x + m[7] * w.y + m[8] * w.z);
}

inline float3 env_to_world(const Env *e, const float3 d)
{
    __global const float *m = e->rot; /* transpose */
    return (float3)(m[0] * d.x + m[3] * d.y + m[6] * d.z,
                    m[1] * d.x + m[4] * d.y + m[7] * d.z,
                    m[2] * d.x + m[5] * d.y + m[8] * d.z);
}

/* The lat-long square of the light tree: phi = 2 pi u, theta = pi v (map frame),
 * with du dv / d omega = 1 / (2 pi^2 sin theta). numpy twin: Environment.square_to_world,
 * world_to_square, square_to_solid_angle. */
inline float3 env_square_to_world(const Env *e, const float2 uv)
{
    const float phi = 2.0f * PI_F * uv.x, theta = PI_F * uv.y;
    const float st = sin(theta);
    return env_to_world(e, (float3)(sin(phi) * st, cos(theta), -cos(phi) * st));
}

/* atan2(y, x) in (-pi, pi] to ~2 ulp of pi (measured in tests/test_kernels.py), branch-free:
 * PoCL's atan2 and acos calls cost half of the shade kernel (measured 2x). The octant is
 * reduced to t = min/max in [0, 1], then to [-tan(pi/8), tan(pi/8)] about pi/4, where
 * the odd polynomial of Cephes' atanf holds. */
inline float fast_atan2(const float y, const float x)
{
    const float ax = fabs(x), ay = fabs(y);
    const float hi = fmax(ax, ay), lo = fmin(ax, ay);
    float t = hi > 0.0f ? lo / hi : 0.0f;
    const int big = t > 0.41421356237309503f;          /* tan(pi/8) */
    const float z = big ? (t - 1.0f) / (t + 1.0f) : t;
    const float z2 = z * z;
    float a = (((8.05374449538e-2f * z2 - 1.38776856032e-1f) * z2 + 1.99777106478e-1f) * z2
               - 3.33329491539e-1f) * z2 * z + z;
    a += big ? 0.25f * PI_F : 0.0f;
    a = ay > ax ? 0.5f * PI_F - a : a;
    a = x < 0.0f ? PI_F - a : a;
    return y < 0.0f ? -a : a;
}

inline float2 env_world_to_square(const Env *e, const float3 w)
{
    const float3 d = env_to_map(e, w);
    float u = fast_atan2(d.x, -d.z) * INV_2PI_F;
    u -= floor(u);
    /* theta = atan2(sin, cos): accurate at the poles, unlike acos */
    const float v = fast_atan2(sqrt(d.x * d.x + d.z * d.z), d.y) * INV_PI_F;
    return (float2)(fmin(u, ONE_MINUS_EPS), fmin(v, ONE_MINUS_EPS));
}

/* rotate_y turns about +Y: sin(theta) is the same in world and map frames. */
inline float env_square_to_solid_angle(const float3 w)
{
    const float s = sqrt(w.x * w.x + w.z * w.z);  /* sin(theta), accurate near the poles */
    return s > 0.0f ? 1.0f / (2.0f * PI_F * PI_F * s) : 0.0f;
}

inline float3 env_eval(const Env *e, const float3 w)
{
    const float2 uv = env_world_to_square(e, w);
    const int col = min((int)(uv.x * e->width), e->width - 1);
    const int row = min((int)(uv.y * e->height), e->height - 1);
    return e->texels[row * e->width + col].xyz;
}
#endif
