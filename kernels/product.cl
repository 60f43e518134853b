/* Product samples (product.h product_walk) as a stand-alone kernel, for the benchmarks
 * and the tests (the renderer's wavelet strategy runs the same walk inside
 * kernels/shade.cl). Per point: world-frame normal and direction to the viewer (float4 rows),
 * material index (kind, kappa and depth + 256 shape + 65536 tree from the material
 * tables) and
 * uniform u (u_stride floats apart) -> point of the square (u plane then v plane of
 * uv_out) and its density on the square. Built per tree depth (-DN_LEVELS), largest
 * product depth (-DPRODUCT_LEVELS), set of lobe shapes (-DLOBE_SHAPES) and number of
 * light trees in the buffer (-DPRODUCT_TREES, default 1), so that the walk unrolls.
 * Eight points per work-item (simd.h): launch ceil(count / 8) work-items or more,
 * count >= 1, in whole work-groups (every work-item walks, also past count: the walk
 * waits at work-group barriers, warp.h).
 */
#ifndef WALK_BARRIERS
#define WALK_BARRIERS 1   /* breadth-first walks (warp.h); the kernel has no early return */
#endif
#include "product.h"
#if !defined(N_LEVELS) || !defined(PRODUCT_LEVELS)
#error "product.cl is built with -DN_LEVELS (light tree depth) and -DPRODUCT_LEVELS (largest product depth)"
#endif

__kernel void product_sample_points(__global const float *tree, __global const float *rot, const uint count,
                                    __global const float *normal, __global const float *wo_world,
                                    __global const int *material, __global const float *mat_kappa,
                                    __global const int *mat_levels, __global const float *u_in,
                                    const uint u_stride,
                                    __global float *uv_out, __global float *pdf_out)
{
    const uint base = LANE_BASE();
    const uintv i = LANE_INDEX(count);
    const intv m = GATHER_INT(material, i);
    realv nx, ny, nz, ex, ey, ez, ux, uy;
    GATHER3(normal, 4 * i, &nx, &ny, &nz);
    GATHER3(wo_world, 4 * i, &ex, &ey, &ez);
    GATHER2(u_in, i * u_stride, &ux, &uy);
    const Lobe lb = make_lobe(rot, nx, ny, nz, ex, ey, ez, GATHER(mat_kappa, m), GATHER_INT(mat_levels, m));
    const realv pdf = product_walk(tree + TREE_ORIGIN, &lb, &ux, &uy);   /* (common.h) */
    STORE_LANES(ux, uv_out, base, count);          /* u and v planes (see warp.cl) */
    STORE_LANES(uy, uv_out + count, base, count);
    STORE_LANES(pdf, pdf_out, base, count);
}
