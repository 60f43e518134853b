/* Hierarchical warping of uniform points by sampling trees, batched: sample i uses
 * tree i / samples_per_tree, so the same kernels serve the single environment
 * tree and per-shading-point product trees. The walk itself is in warp.h; each
 * work-item walks WALK_K samples together (launch ceil(count / WALK_K) items).
 */
#include "warp.h"

__kernel void warp_sample(__global const float *tree, const ulong tree_stride, const int n_levels,
                          const uint samples_per_tree, const uint count, __global const float2 *u_in,
                          __global float2 *uv_out, __global float *pdf_out)
{
    const uint i0 = get_global_id(0) * WALK_K;
    ulong off[WALK_K];
    float2 u[WALK_K];
    float pdf[WALK_K];
    for (int k = 0; k < WALK_K; ++k) {
        const uint i = min(i0 + k, count - 1);
        off[k] = (ulong)(i / samples_per_tree) * tree_stride;
        u[k] = u_in[i];
    }
    tree_sample_k(tree, off, n_levels, u, pdf);
    for (int k = 0; k < WALK_K && i0 + k < count; ++k) {
        uv_out[i0 + k] = u[k];
        pdf_out[i0 + k] = pdf[k];
    }
}

__kernel void warp_pdf(__global const float *tree, const ulong tree_stride, const int n_levels,
                       const uint samples_per_tree, __global const float2 *uv_in,
                       __global float *pdf_out)
{
    const uint i = get_global_id(0);
    pdf_out[i] = tree_pdf(tree + (ulong)(i / samples_per_tree) * tree_stride, n_levels, uv_in[i]);
}
