/* Hierarchical warping of uniform points by sampling trees. The walk itself is
 * tree_walk (warp.h): one sample per work-item; the host builds this program per
 * tree depth (-DN_LEVELS) so that the walk unrolls and PoCL vectorises it across
 * work-items. -DBATCHED=1: sample i uses tree i / samples_per_tree, so the same
 * kernel serves per-shading-point trees; BATCHED=0: every sample uses the one tree
 * (no integer division per sample).
 * Launch any global size >= count (work-items past count store nothing).
 */
#include "warp.h"
#if !defined(N_LEVELS) || !defined(BATCHED)
#error "warp.cl is built with -DN_LEVELS (tree depth) and -DBATCHED (0: one tree, 1: one tree per samples_per_tree)"
#endif

__kernel void warp_sample(__global const float *tree, const ulong tree_stride, const uint samples_per_tree,
                          const uint count, __global const float *u_in, const uint u_stride,
                          __global float *uv_out, __global float *pdf_out)
{
    const uint i = min((uint)get_global_id(0), count - 1);
#if BATCHED
    __global const float *t = tree + (ulong)(i / samples_per_tree) * tree_stride;
#else
    __global const float *t = tree;
#endif
    float ux = u_in[i * u_stride], uy = u_in[i * u_stride + 1];
    const float pdf = tree_walk(t, &ux, &uy);
    if (get_global_id(0) < count) {
        uv_out[i] = ux;          /* u then v planes: two adjacent stores would be paired */
        uv_out[count + i] = uy;  /* by LLVM's SLP vectoriser, which stops PoCL's */
        pdf_out[i] = pdf;        /* work-item vectoriser */
    }
}

__kernel void warp_pdf(__global const float *tree, const ulong tree_stride, const int n_levels,
                       const uint samples_per_tree, __global const float2 *uv_in,
                       __global float *pdf_out)
{
    const uint i = get_global_id(0);
    pdf_out[i] = tree_pdf(tree + (ulong)(i / samples_per_tree) * tree_stride, n_levels, uv_in[i]);
}
