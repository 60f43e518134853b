/* Product samples (product.h product_walk), one per work-item, for the renderer's
 * wavelet strategy (the guide samples kernels/shade.cl consumes), the benchmarks and
 * the tests. Per point: world-frame normal and direction to the viewer (float4 rows),
 * material index (kind, kappa and depth + 256 shape from the material tables) and
 * uniform u (u_stride floats apart) -> point of the square (u plane then v plane of
 * uv_out) and its density on the square. Built per tree depth (-DN_LEVELS), largest
 * product depth (-DPRODUCT_LEVELS) and set of lobe shapes (-DLOBE_SHAPES), so that PoCL
 * vectorises it across work-items. Launch any global size >= count.
 */
#include "product.h"
#if !defined(N_LEVELS) || !defined(PRODUCT_LEVELS)
#error "product.cl is built with -DN_LEVELS (light tree depth) and -DPRODUCT_LEVELS (largest product depth)"
#endif

__kernel void product_sample_points(__global const float *tree, __global const float *rot, const uint count,
                                    __global const float *normal, __global const float *wo_world,
                                    __global const int *material, __global const float *mat_kappa,
                                    __global const int *mat_levels, __global const float *u_in,
                                    const uint u_stride, __global const float *angles,
                                    __global float *uv_out, __global float *pdf_out)
{
    const uint i = min((uint)get_global_id(0), count - 1);
    const int m = material[i];
    const Lobe lb = make_lobe(rot, normal[4 * i], normal[4 * i + 1], normal[4 * i + 2],
                              wo_world[4 * i], wo_world[4 * i + 1], wo_world[4 * i + 2], mat_kappa[m], mat_levels[m]);
    float ux = u_in[i * u_stride], uy = u_in[i * u_stride + 1];
    const float pdf = product_walk(tree, angles, &lb, &ux, &uy);
    if (get_global_id(0) < count) {
        uv_out[i] = ux;          /* u and v planes (see warp.cl) */
        uv_out[count + i] = uy;
        pdf_out[i] = pdf;
    }
}
