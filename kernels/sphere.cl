/* Direction <-> lat-long square maps of sphere.h, batched: for tests against their
 * numpy twins (wavlight.envmap.Environment.world_to_square, square_to_world). One point
 * per work-item, broadcast to the eight lanes of sphere.h's functions (lane 0 kept). */
#include "sphere.h"

__kernel void world_to_square(__global const float *rot, __global const float4 *w,
                              __global float2 *uv_out)
{
    const uint i = get_global_id(0);
    realv u, v;
    env_world_to_square(rot, (realv)w[i].x, (realv)w[i].y, (realv)w[i].z, &u, &v);
    uv_out[i] = (float2)(u.s0, v.s0);
}

__kernel void square_to_world(__global const float *rot, __global const float2 *uv,
                              __global float4 *w_out)
{
    const uint i = get_global_id(0);
    realv x, y, z;
    env_square_to_world(rot, (realv)uv[i].x, (realv)uv[i].y, &x, &y, &z);
    w_out[i] = (float4)(x.s0, y.s0, z.s0, 0.0f);
}

__kernel void atan2_points(__global const float2 *yx, __global float *out)
{
    const uint i = get_global_id(0);
    out[i] = fast_atan2((realv)yx[i].x, (realv)yx[i].y).s0;
}

__kernel void sincos_points(__global const float *x, __global float2 *out)
{
    const uint i = get_global_id(0);
    realv s, c;
    fast_sincos((realv)x[i], &s, &c);
    out[i] = (float2)(s.s0, c.s0);
}
