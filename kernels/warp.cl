/* Hierarchical warping of uniform points by sampling trees, batched: sample i uses
 * tree i / samples_per_tree, so the same kernels serve the single environment
 * tree and per-shading-point product trees. The walk itself is in warp.h.
 */
#include "warp.h"

__kernel void warp_sample(__global const float *tree, const ulong tree_stride, const int n_levels,
                          const uint samples_per_tree, __global const float2 *u_in,
                          __global float2 *uv_out, __global float *pdf_out)
{
    const uint i = get_global_id(0);
    float pdf;
    uv_out[i] = tree_sample(tree + (ulong)(i / samples_per_tree) * tree_stride, n_levels, u_in[i], &pdf);
    pdf_out[i] = pdf;
}

__kernel void warp_pdf(__global const float *tree, const ulong tree_stride, const int n_levels,
                       const uint samples_per_tree, __global const float2 *uv_in,
                       __global float *pdf_out)
{
    const uint i = get_global_id(0);
    pdf_out[i] = tree_pdf(tree + (ulong)(i / samples_per_tree) * tree_stride, n_levels, uv_in[i]);
}
