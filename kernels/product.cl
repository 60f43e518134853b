/* Product samples alone (no BRDF evaluation, no rays): for benchmarks and tests.
 * Per sample: lobe (axis, normal, kappa, depth, shape) and u -> square point and
 * pdf on the square (product.h). Each work-item walks WALK_K samples together:
 * launch ceil(count / WALK_K) items. */
#include "product.h"

__kernel void product_sample_points(__global const float *tree, const int n_levels,
                                    __global const float4 *texels, const int env_w, const int env_h,
                                    __global const float *rot, const uint count,
                                    __global const float4 *axis_kappa, __global const float4 *normal_levels,
                                    __global const float2 *u_in, __global const float4 *node_dirs,
                                    __global float2 *uv_out, __global float *pdf_out)
{
    const uint i0 = get_global_id(0) * WALK_K;
    const Env env = {texels, env_w, env_h, rot};
    Lobe lobe[WALK_K];
    float2 u[WALK_K];
    float pdf[WALK_K];
    for (int k = 0; k < WALK_K; ++k) {
        const uint i = min(i0 + k, count - 1);
        const float4 ak = axis_kappa[i], nl = normal_levels[i];
        lobe[k].axis = env_to_map(&env, ak.xyz);
        lobe[k].inv_kappa = 1.0f / ak.w;
        lobe[k].n = env_to_map(&env, nl.xyz);
        lobe[k].wo = 2.0f * dot(lobe[k].axis, lobe[k].n) * lobe[k].n - lobe[k].axis; /* axis = mirror */
        lobe[k].dirs = node_dirs;
        lobe[k].levels = (int)nl.w & 0xff;
        lobe[k].shape = (int)nl.w >> 8;
        u[k] = u_in[i];
    }
    product_sample_k(tree, n_levels, lobe, u, pdf);
    for (int k = 0; k < WALK_K && i0 + k < count; ++k) {
        uv_out[i0 + k] = u[k];
        pdf_out[i0 + k] = pdf[k];
    }
}
