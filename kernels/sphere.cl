/* Direction <-> lat-long square maps of sphere.h, batched: for tests against their
 * numpy twins (wavlight.envmap.Environment.world_to_square, square_to_world). */
#include "sphere.h"

__kernel void world_to_square(__global const float *rot, __global const float4 *w,
                              __global float2 *uv_out)
{
    const uint i = get_global_id(0);
    const Env env = {0, 0, 0, rot};
    uv_out[i] = env_world_to_square(&env, w[i].xyz);
}

__kernel void atan2_points(__global const float2 *yx, __global float *out)
{
    const uint i = get_global_id(0);
    out[i] = fast_atan2(yx[i].x, yx[i].y);
}
