/* The materials of bsdf.h, batched: for tests against their numpy twins (wavlight.bsdfs).
 * One point per work-item, broadcast to the eight lanes of bsdf.h's functions (lane 0
 * kept). table: the plastic table (PLASTIC_STRIDE floats per material), mat: each point's
 * material (its row), kind and param per point. */
#include "bsdf.h"

/* f cos, its albedo's part and the pdf of directions wi (light) for views wo, local frame. */
__kernel void material_eval_points(__global const float4 *wi, __global const float4 *wo,
                                   __global const int *kind, __global const float *param,
                                   __global const int *mat, __global const float *table,
                                   __global float4 *out)
{
    const uint i = get_global_id(0);
    realv f, fd, pdf;
    material_eval_pdf((intv)kind[i], (realv)param[i], table, (uintv)(uint)(mat[i] * PLASTIC_STRIDE),
                      (realv)wi[i].x, (realv)wi[i].y, (realv)wi[i].z, (realv)wo[i].x, (realv)wo[i].y,
                      (realv)wo[i].z, &f, &fd, &pdf);
    out[i] = (float4)(f.s0, fd.s0, pdf.s0, 0.0f);
}

/* Sampled directions for views wo and uniforms u. */
__kernel void material_sample_points(__global const float4 *wo, __global const float2 *u,
                                     __global const int *kind, __global const float *param,
                                     __global const int *mat, __global const float *table,
                                     __global float4 *out)
{
    const uint i = get_global_id(0);
    realv x, y, z;
    material_sample((intv)kind[i], (realv)param[i], table, (uintv)(uint)(mat[i] * PLASTIC_STRIDE),
                    (realv)wo[i].x, (realv)wo[i].y, (realv)wo[i].z, (realv)u[i].x, (realv)u[i].y, &x, &y, &z);
    out[i] = (float4)(x.s0, y.s0, z.s0, 0.0f);
}
