/* Hierarchical warping of uniform points by sampling trees. The walk itself is
 * tree_walk (warp.h): eight samples per work-item (simd.h; launch ceil(count / 8)
 * work-items or more, count >= 1, in whole work-groups: every work-item walks, also
 * past count, because the walk waits at work-group barriers); the host builds this
 * program per tree depth (-DN_LEVELS) so that the walk unrolls. -DBATCHED=1: sample i uses tree i / samples_per_tree, so the
 * same kernel serves per-shading-point trees; BATCHED=0: every sample uses the one
 * tree (no integer division per sample). Outputs: the u plane then the v plane of
 * uv_out, and the density on the square.
 */
#ifndef WALK_BARRIERS
#define WALK_BARRIERS 1   /* breadth-first walks (warp.h); warp_sample has no early return */
#endif
#include "warp.h"
#if !defined(N_LEVELS) || !defined(BATCHED)
#error "warp.cl is built with -DN_LEVELS (tree depth) and -DBATCHED (0: one tree, 1: one tree per samples_per_tree)"
#endif

__kernel void warp_sample(__global const float *tree, const ulong tree_stride, const uint samples_per_tree,
                          const uint count, __global const float *u_in, const uint u_stride,
                          __global float *uv_out, __global float *pdf_out)
{
    const uint base = LANE_BASE();
    const uintv i = LANE_INDEX(count);
    tree += TREE_ORIGIN;   /* (common.h) */
#if BATCHED
    const uintv tree_base = (i / samples_per_tree) * (uint)tree_stride;
#else
    const uintv tree_base = 0;
#endif
    realv ux, uy;
    GATHER2(u_in, i * u_stride, &ux, &uy);
    const realv pdf = tree_walk(tree, tree_base, &ux, &uy);
    STORE_LANES(ux, uv_out, base, count);
    STORE_LANES(uy, uv_out + count, base, count);
    STORE_LANES(pdf, pdf_out, base, count);
}

/* tree_pdf at count points (u, v rows of uv_in), eight per work-item like warp_sample. */
__kernel void warp_pdf(__global const float *tree, const ulong tree_stride, const int n_levels,
                       const uint samples_per_tree, const uint count, __global const float *uv_in,
                       __global float *pdf_out)
{
    const uint base = LANE_BASE();
    if (base >= count) return;
    const uintv i = LANE_INDEX(count);
    const uintv tree_base = (i / samples_per_tree) * (uint)tree_stride;
    tree += TREE_ORIGIN;
    STORE_LANES(tree_pdf(tree, tree_base, n_levels, GATHER(uv_in, 2 * i), GATHER(uv_in, 2 * i + 1)),
                pdf_out, base, count);
}
