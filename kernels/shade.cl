/* Shading of direct environment lighting: for each shading point draw one (or,
 * for MIS, two) directions with the strategy chosen by -DSTRATEGY and return the
 * unoccluded estimator value  albedo f cos L / pdf  (times the power-heuristic
 * weight for MIS) with its direction; the host traces shadow rays for the
 * non-zero values. numpy twin: wavlight/strategies.py (shade_reference).
 *
 * 3-vectors travel as float4 (w unused): PoCL vectorises aligned loads far
 * better than vload3 (measured 3x).
 * STRATEGY: 0 uniform, 1 cosine, 2 bsdf, 3 light, 4 mis, 5 wavelet. Single
 * strategies use u.xy and write slot 0 (slot 1 is zero); MIS draws the light
 * sample from u.xy into slot 0 and the bsdf sample from u.zw into slot 1; wavelet
 * does the same with the product sampler (product.h) in place of the light. The
 * light and product samples (drawn from u.xy) come in as guide_uv / guide_pdf: the
 * host draws them first with warp.cl / product.cl, whose tree walks PoCL vectorises
 * across work-items (this kernel, with its float3 BSDF code, it cannot).
 */
#include "warp.h"
#include "bsdf.h"
#include "product.h"

inline float light_pdf(const Env *e, __global const float *tree, const int levels, const float3 w)
{
    return tree_pdf(tree, levels, env_world_to_square(e, w)) * env_square_to_solid_angle(w);
}

inline float product_pdf_at(__global const float *tree, const int levels, __global const float *angles,
                            const Lobe *lb, const float2 uv)
{
    return product_pdf(tree, levels, angles, lb, uv.x, uv.y);
}

inline float power_heuristic(const float pa, const float pb)
{
    const float big = fmax(pa, pb);
    if (!(big > 0.0f)) return 0.0f;
    const float a = pa / big, b = pb / big;
    return a * a / (a * a + b * b);
}

__kernel void shade(__global const float4 *normal, __global const float4 *wo_world,
                    __global const int *material, __global const float4 *u_in, const uint count,
                    __global const int *mat_kind, __global const float *mat_param,
                    __global const float4 *mat_albedo, __global const float *mat_kappa,
                    __global const int *mat_levels, __global const float *angles,
                    __global const float4 *texels, const int env_w, const int env_h,
                    __global const float *rot, __global const float *tree, const int tree_levels,
                    __global const float *guide_uv, __global const float *guide_pdf,
                    __global float4 *wi_out, __global float4 *value_out)
{
    /* One shading point per work-item. The guide sample (light or product) was drawn
     * before, by warp.cl or product.cl (vectorised across work-items): guide_uv holds
     * its point of the square (u plane, then v plane), guide_pdf its density there. */
    const uint i = get_global_id(0);
    if (i >= count) return;
    const Env env = {texels, env_w, env_h, rot};
#if STRATEGY >= 3
    const float2 guide = (float2)(guide_uv[i], guide_uv[count + i]);
    const float guide_density = guide_pdf[i];
#endif
    {
        const int mat = material[i];
        const float3 nk = normal[i].xyz, wowk = wo_world[i].xyz;
        float3 s, t;
        make_frame(nk, &s, &t);
        const float3 wo = (float3)(dot(wowk, s), dot(wowk, t), dot(wowk, nk));
        const int kind = mat_kind[mat];
        const float param = mat_param[mat];
        const float3 albedo = mat_albedo[mat].xyz;
        const float4 uk = u_in[i];
#if STRATEGY == 5
        const Lobe lobe = make_lobe(rot, nk.x, nk.y, nk.z, wowk.x, wowk.y, wowk.z, mat_kappa[mat], mat_levels[mat]);
#endif

        float3 wi_w[2] = {(float3)(0.0f), (float3)(0.0f)};
        float scal[2] = {0.0f, 0.0f};
#if STRATEGY == 5
#define PDF_GUIDE(w) (product_pdf_at(tree, tree_levels, angles, &lobe, env_world_to_square(&env, w)) \
                     * env_square_to_solid_angle(w))
#else
#define PDF_GUIDE(w) light_pdf(&env, tree, tree_levels, w)
#endif
#if STRATEGY >= 4
        {   /* light (mis) or product (wavelet) sample, weighted against the bsdf pdf */
            const float3 w = env_square_to_world(&env, guide);
            const float pdf = guide_density * env_square_to_solid_angle(w);
            const float3 wl = (float3)(dot(w, s), dot(w, t), dot(w, nk));
            const float f = bsdf_eval_cos(kind, param, wl, wo);
            wi_w[0] = w;
            if (pdf > 0.0f && f > 0.0f)  /* the other pdf only where the estimate can be non-zero */
                scal[0] = f / pdf * power_heuristic(pdf, bsdf_pdf(kind, param, wl, wo));
        }
        {   /* bsdf sample, weighted against the light pdf */
            const float3 wl = bsdf_sample(kind, param, wo, uk.zw);
            const float pdf = bsdf_pdf(kind, param, wl, wo);
            const float3 w = wl.x * s + wl.y * t + wl.z * nk;
            const float f = bsdf_eval_cos(kind, param, wl, wo);
            wi_w[1] = w;
            if (pdf > 0.0f && f > 0.0f)
                scal[1] = f / pdf * power_heuristic(pdf, PDF_GUIDE(w));
        }
#else
        {
            float3 wl, w;
            float pdf;
#if STRATEGY == 0
            wl = (float3)(sqrt(fmax(0.0f, 1.0f - uk.x * uk.x)) * cos(2.0f * PI_F * uk.y),
                          sqrt(fmax(0.0f, 1.0f - uk.x * uk.x)) * sin(2.0f * PI_F * uk.y), uk.x);
            pdf = wl.z > 0.0f ? INV_2PI_F : 0.0f;
            w = wl.x * s + wl.y * t + wl.z * nk;
#elif STRATEGY == 1
            wl = cosine_hemisphere(uk.xy);
            pdf = fmax(wl.z, 0.0f) * INV_PI_F;
            w = wl.x * s + wl.y * t + wl.z * nk;
#elif STRATEGY == 2
            wl = bsdf_sample(kind, param, wo, uk.xy);
            pdf = bsdf_pdf(kind, param, wl, wo);
            w = wl.x * s + wl.y * t + wl.z * nk;
#else
            w = env_square_to_world(&env, guide);
            pdf = guide_density * env_square_to_solid_angle(w);
            wl = (float3)(dot(w, s), dot(w, t), dot(w, nk));
#endif
            wi_w[0] = w;
            if (pdf > 0.0f)
                scal[0] = bsdf_eval_cos(kind, param, wl, wo) / pdf;
        }
#endif
        for (int j = 0; j < 2; ++j) {
            const float3 v = (scal[j] > 0.0f && isfinite(scal[j])) ? scal[j] * albedo * env_eval(&env, wi_w[j])
                                                                  : (float3)(0.0f);
            wi_out[2 * i + j] = (float4)(wi_w[j], 0.0f);
            value_out[2 * i + j] = (float4)(v, 0.0f);
        }
    }
}
