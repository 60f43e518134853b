/* Product samples alone (no BRDF evaluation, no rays): for benchmarks and tests.
 * Per sample: lobe (axis, normal, kappa, depth, shape) and u -> square point and
 * pdf on the square (product.h). */
#include "product.h"

__kernel void product_sample_points(__global const float *tree, const int n_levels,
                                    __global const float4 *texels, const int env_w, const int env_h,
                                    __global const float *rot,
                                    __global const float4 *axis_kappa, __global const float4 *normal_levels,
                                    __global const float2 *u_in, __global const float4 *node_dirs,
                                    __global float2 *uv_out, __global float *pdf_out)
{
    const uint i = get_global_id(0);
    const Env env = {texels, env_w, env_h, rot};
    const float4 ak = axis_kappa[i], nl = normal_levels[i];
    Lobe lobe;
    lobe.axis = env_to_map(&env, ak.xyz);
    lobe.kappa = ak.w;
    lobe.n = env_to_map(&env, nl.xyz);
    lobe.dirs = node_dirs;
    lobe.levels = (int)nl.w & 0xff;
    lobe.shape = (int)nl.w >> 8;
    float pdf;
    uv_out[i] = product_sample(tree, n_levels, &lobe, u_in[i], &pdf);
    pdf_out[i] = pdf;
}
