/* Direction <-> lat-long square maps of sphere.h, batched: for tests against their
 * numpy twins (wavlight.envmap.Environment.world_to_square, square_to_world). */
#include "sphere.h"

__kernel void world_to_square(__global const float *rot, __global const float4 *w,
                              __global float2 *uv_out)
{
    const uint i = get_global_id(0);
    float u, v;
    env_world_to_square(rot, w[i].x, w[i].y, w[i].z, &u, &v);
    uv_out[i] = (float2)(u, v);
}

__kernel void square_to_world(__global const float *rot, __global const float2 *uv,
                              __global float4 *w_out)
{
    const uint i = get_global_id(0);
    float x, y, z;
    env_square_to_world(rot, uv[i].x, uv[i].y, &x, &y, &z);
    w_out[i] = (float4)(x, y, z, 0.0f);
}

__kernel void atan2_points(__global const float2 *yx, __global float *out)
{
    const uint i = get_global_id(0);
    out[i] = fast_atan2(yx[i].x, yx[i].y);
}

__kernel void sincos_points(__global const float *x, __global float2 *out)
{
    const uint i = get_global_id(0);
    float s, c;
    fast_sincos(x[i], &s, &c);
    out[i] = (float2)(s, c);
}
