/* Luminance of the environment at the sub-points of the equal-area square, the
 * input of the light tree (numpy twin: Environment.subpoint_luminance_reference).
 * Sub-point (i, j) of a G x G grid sits at ((i + 0.5) / G, (j + 0.5) / G); the
 * square's frame is the map's own (octahedral z = map +Y), so no rotation here.
 */
#include "sphere.h"

__kernel void subpoint_luminance(__global const float *lum, const int width, const int height,
                                 const int grid, __global float *out)
{
    const int i = get_global_id(0), j = get_global_id(1);
    const float2 p = (float2)(((float)i + 0.5f) / grid, ((float)j + 0.5f) / grid);
    const float3 q = equal_area_square_to_sphere(p);
    const float3 d = (float3)(q.x, q.z, -q.y);
    float u = atan2(d.x, -d.z) * INV_2PI_F;
    u -= floor(u);
    const float v = acos(clamp(d.y, -1.0f, 1.0f)) * INV_PI_F;
    const int col = min((int)(u * width), width - 1);
    const int row = min((int)(v * height), height - 1);
    out[j * grid + i] = lum[row * width + col];
}
