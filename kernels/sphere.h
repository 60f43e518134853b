/* Directions: tangent frames, the equal-area octahedral map (Clarberg 2008, as in
 * pbrt-v4) and the equirectangular nearest-texel lookup of the scene format.
 * numpy twins: wavlight/warp.py and wavlight/envmap.py.
 */
#ifndef WAVLIGHT_SPHERE_H
#define WAVLIGHT_SPHERE_H

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

inline float2 equal_area_sphere_to_square(const float3 d)
{
    const float x = fabs(d.x), y = fabs(d.y), z = fabs(d.z);
    const float r = sqrt(fmax(0.0f, 1.0f - z));
    const float a = fmax(x, y);
    float b = fmin(x, y);
    b = (a == 0.0f) ? 0.0f : b / a;
    float phi = atan(b) * 2.0f * INV_PI_F;
    if (x < y) phi = 1.0f - phi;
    float v = phi * r;
    float u = r - v;
    if (d.z < 0.0f) { const float tmp = u; u = 1.0f - v; v = 1.0f - tmp; }
    u = copysign(u, d.x);
    v = copysign(v, d.y);
    return clamp((float2)((u + 1.0f) * 0.5f, (v + 1.0f) * 0.5f), 0.0f, 1.0f);
}

inline float3 equal_area_square_to_sphere(const float2 p)
{
    const float a = 2.0f * p.x - 1.0f, b = 2.0f * p.y - 1.0f;
    const float ap = fabs(a), bp = fabs(b);
    const float sd = 1.0f - (ap + bp);
    const float r = 1.0f - fabs(sd);
    const float phi = ((r == 0.0f) ? 1.0f : (bp - ap) / r + 1.0f) * (PI_F / 4.0f);
    const float z = copysign(1.0f - r * r, sd);
    const float s = r * sqrt(fmax(0.0f, 2.0f - r * r));
    return (float3)(copysign(cos(phi), a) * s, copysign(sin(phi), b) * s, z);
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

inline float3 env_eval(const Env *e, const float3 w)
{
    const float3 d = env_to_map(e, w);
    float u = atan2(d.x, -d.z) * INV_2PI_F;
    u -= floor(u);
    const float v = acos(clamp(d.y, -1.0f, 1.0f)) * INV_PI_F;
    const int col = min((int)(u * e->width), e->width - 1);
    const int row = min((int)(v * e->height), e->height - 1);
    return e->texels[row * e->width + col].xyz;
}

/* Equal-area square frame (octahedral z = map +Y) <-> world. */
inline float3 env_square_to_world(const Env *e, const float2 uv)
{
    const float3 q = equal_area_square_to_sphere(uv);
    return env_to_world(e, (float3)(q.x, q.z, -q.y));
}

inline float2 env_world_to_square(const Env *e, const float3 w)
{
    const float3 d = env_to_map(e, w);
    return equal_area_sphere_to_square((float3)(d.x, -d.z, d.y));
}
#endif
