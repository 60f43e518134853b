/* Shading of direct environment lighting: for each shading point draw one (or,
 * for MIS, two) directions with the strategy chosen by -DSTRATEGY and return the
 * unoccluded estimator value  albedo f cos L / pdf  (times the power-heuristic
 * weight for MIS) with its direction; the host traces shadow rays for the
 * non-zero values. numpy twin: wavlight/strategies.py (shade_reference).
 *
 * STRATEGY: 0 uniform, 1 cosine, 2 bsdf, 3 light, 4 mis, 5 wavelet. Single
 * strategies use u.xy and write slot 0 (slot 1 is zero); MIS draws the light
 * sample from u.xy into slot 0 and the bsdf sample from u.zw into slot 1; wavelet
 * does the same with the product sampler (product.h) in place of the light. The
 * light and product samples (drawn from u.xy) come in as guide_uv / guide_pdf: the
 * host draws them first with warp.cl / product.cl.
 *
 * One point per work-item, scalar code only (sphere.h explains why): PoCL vectorises
 * the work-item loop, 8 points per AVX instruction (measured 3x over the float3
 * version), for every strategy but wavelet, whose MIS weight needs product_pdf
 * (a loop over the point's own product depth). Inputs are float4 rows (normal,
 * wo_world) and u rows of 4; outputs are planes of `count` floats, never adjacent
 * stores: wi_out holds slot 0 x, y, z then slot 1 x, y, z, value_out the same
 * for r, g, b. -DBSDF_KINDS: the material kinds present (bsdf.h).
 */
#include "warp.h"
#include "bsdf.h"
#include "product.h"

__attribute__((always_inline)) inline float power_heuristic(const float pa, const float pb)
{
    const float big = fmax(pa, pb);
    const float a = pa / big, b = pb / big;
    return big > 0.0f ? a * a / (a * a + b * b) : 0.0f;
}

/* Density per unit solid angle of the light tree at world direction w (MIS weight). */
__attribute__((always_inline)) inline float light_pdf(__global const float *rot, __global const float *tree,
                                                      const int levels, const float x, const float y, const float z)
{
    float u, v;
    env_world_to_square(rot, x, y, z, &u, &v);
    const uint side = 1u << levels;
    const uint cx = (uint)min((int)(u * side), (int)side - 1), cy = (uint)min((int)(v * side), (int)side - 1);
    const float root = tree[0], leaf = tree[LEVEL_OFFSET(levels) + (ulong)cy * side + cx];
    return root > 0.0f ? leaf / root * (float)side * (float)side * env_square_to_solid_angle(x, z) : 0.0f;
}

__kernel void shade(__global const float *normal, __global const float *wo_world,
                    __global const int *material, __global const float *u_in, const uint count,
                    __global const int *mat_kind, __global const float *mat_param,
                    __global const float *mat_albedo, __global const float *mat_kappa,
                    __global const int *mat_levels, __global const float *angles,
                    __global const float *texels, const int env_w, const int env_h,
                    __global const float *rot, __global const float *tree, const int tree_levels,
                    __global const float *guide_uv, __global const float *guide_pdf,
                    __global float *wi_out, __global float *value_out)
{
    const uint gi = get_global_id(0);
    const uint i = min(gi, count - 1);   /* padding work-items recompute the last point, store nothing */
    const int mat = material[i];
    const float nx = normal[4 * i], ny = normal[4 * i + 1], nz = normal[4 * i + 2];
    const float ex = wo_world[4 * i], ey = wo_world[4 * i + 1], ez = wo_world[4 * i + 2];
    float sx, sy, sz, tx, ty, tz;
    make_frame(nx, ny, nz, &sx, &sy, &sz, &tx, &ty, &tz);
    const float ox = ex * sx + ey * sy + ez * sz, oy = ex * tx + ey * ty + ez * tz, oz = ex * nx + ey * ny + ez * nz;
    const int kind = mat_kind[mat];
    const float param = mat_param[mat];
    const float u0 = u_in[4 * i], u1 = u_in[4 * i + 1];
    /* slot 0 (and 1): world direction, scalar f / pdf (x MIS weight) */
    float ax = 0.0f, ay = 0.0f, az = 0.0f, sa = 0.0f;
    float bx = 0.0f, by = 0.0f, bz = 0.0f, sb = 0.0f;
#if STRATEGY >= 3
    {   /* the light (light, mis) or product (wavelet) sample, drawn by the guide kernel */
        env_square_to_world(rot, guide_uv[i], guide_uv[count + i], &ax, &ay, &az);
        const float pdf = guide_pdf[i] * env_square_to_solid_angle(ax, az);
        const float lx = ax * sx + ay * sy + az * sz, ly = ax * tx + ay * ty + az * tz;
        const float lz = ax * nx + ay * ny + az * nz;
        float f, pdf_bsdf;
        bsdf_eval_pdf(kind, param, lx, ly, lz, ox, oy, oz, &f, &pdf_bsdf);
#if STRATEGY == 3
        sa = pdf > 0.0f ? f / pdf : 0.0f;
#else
        /* the other pdf matters only where the estimate can be non-zero */
        sa = (pdf > 0.0f && f > 0.0f) ? f / pdf * power_heuristic(pdf, pdf_bsdf) : 0.0f;
#endif
    }
#endif
#if STRATEGY >= 4
    {   /* the bsdf sample from u.zw, weighted against the guide's pdf */
        float lx, ly, lz, f, pdf;
        bsdf_sample(kind, param, ox, oy, oz, u_in[4 * i + 2], u_in[4 * i + 3], &lx, &ly, &lz);
        bsdf_eval_pdf(kind, param, lx, ly, lz, ox, oy, oz, &f, &pdf);
        bx = lx * sx + ly * tx + lz * nx;
        by = lx * sy + ly * ty + lz * ny;
        bz = lx * sz + ly * tz + lz * nz;
#if STRATEGY == 5
        const Lobe lobe = make_lobe(rot, nx, ny, nz, ex, ey, ez, mat_kappa[mat], mat_levels[mat]);
        float gu, gv;
        env_world_to_square(rot, bx, by, bz, &gu, &gv);
        const float other = product_pdf(tree, tree_levels, angles, &lobe, gu, gv) * env_square_to_solid_angle(bx, bz);
#else
        const float other = light_pdf(rot, tree, tree_levels, bx, by, bz);
#endif
        sb = (pdf > 0.0f && f > 0.0f) ? f / pdf * power_heuristic(pdf, other) : 0.0f;
    }
#endif
#if STRATEGY <= 2
    {
        float lx, ly, lz, pdf;
#if STRATEGY == 0   /* uniform hemisphere */
        const float r = sqrt(fmax(0.0f, 1.0f - u0 * u0));
        float sp, cp;
        fast_sincos(2.0f * PI_F * u1, &sp, &cp);
        lx = r * cp;
        ly = r * sp;
        lz = u0;
        pdf = lz > 0.0f ? INV_2PI_F : 0.0f;
#elif STRATEGY == 1   /* cosine hemisphere: the lambert sampler */
        bsdf_sample(BSDF_LAMBERT, 0.0f, ox, oy, oz, u0, u1, &lx, &ly, &lz);
        pdf = fmax(lz, 0.0f) * INV_PI_F;
#else
        bsdf_sample(kind, param, ox, oy, oz, u0, u1, &lx, &ly, &lz);
#endif
        float f, pdf_bsdf;
        bsdf_eval_pdf(kind, param, lx, ly, lz, ox, oy, oz, &f, &pdf_bsdf);
#if STRATEGY == 2
        pdf = pdf_bsdf;
#endif
        ax = lx * sx + ly * tx + lz * nx;
        ay = lx * sy + ly * ty + lz * ny;
        az = lx * sz + ly * tz + lz * nz;
        sa = pdf > 0.0f ? f / pdf : 0.0f;
    }
#endif
    /* estimates: albedo x scalar x environment radiance (zero where the scalar is not a
     * positive finite number) */
    sa = (sa > 0.0f && isfinite(sa)) ? sa : 0.0f;
    sb = (sb > 0.0f && isfinite(sb)) ? sb : 0.0f;
    float ua, va, ub, vb;
    env_world_to_square(rot, ax, ay, az, &ua, &va);
    env_world_to_square(rot, bx, by, bz, &ub, &vb);
    const int ka = 4 * env_texel(env_w, env_h, ua, va), kb = 4 * env_texel(env_w, env_h, ub, vb);
    const float ar = mat_albedo[4 * mat], ag = mat_albedo[4 * mat + 1], ab = mat_albedo[4 * mat + 2];
    if (gi < count) {
        wi_out[i] = ax;
        wi_out[count + i] = ay;
        wi_out[2 * count + i] = az;
        wi_out[3 * count + i] = bx;
        wi_out[4 * count + i] = by;
        wi_out[5 * count + i] = bz;
        value_out[i] = sa * ar * texels[ka];
        value_out[count + i] = sa * ag * texels[ka + 1];
        value_out[2 * count + i] = sa * ab * texels[ka + 2];
        value_out[3 * count + i] = sb * ar * texels[kb];
        value_out[4 * count + i] = sb * ag * texels[kb + 1];
        value_out[5 * count + i] = sb * ab * texels[kb + 2];
    }
}
