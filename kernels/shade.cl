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
 * does the same with the product sampler (product.h) in place of the light.
 */
#include "warp.h"
#include "bsdf.h"
#include "product.h"

typedef struct { float3 wi; float3 value; } Sample;

inline float light_pdf(const Env *e, __global const float *tree, const int levels, const float3 w)
{
    return tree_pdf(tree, levels, env_world_to_square(e, w)) * env_square_to_solid_angle(w);
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
                    __global const int *mat_levels, __global const float4 *node_dirs,
                    __global const float4 *texels, const int env_w, const int env_h,
                    __global const float *rot, __global const float *tree, const int tree_levels,
                    __global float4 *wi_out, __global float4 *value_out)
{
    /* WALK_K shading points per work-item: their tree walks (light or product) run
     * together (warp.h tree_sample_k), the rest point by point. */
    const uint i0 = get_global_id(0) * WALK_K;
    const Env env = {texels, env_w, env_h, rot};
    float3 n[WALK_K], wow[WALK_K];
    float4 u[WALK_K];
    int mat[WALK_K];
    float2 guide[WALK_K];     /* guide sample: u.xy in, the point of the square out */
    float guide_pdf[WALK_K];  /* its density on the square */
    for (int k = 0; k < WALK_K; ++k) {
        const uint i = min(i0 + k, count - 1);
        n[k] = normal[i].xyz;
        wow[k] = wo_world[i].xyz;
        mat[k] = material[i];
        u[k] = u_in[i];
        guide[k] = u[k].xy;
    }
#if STRATEGY == 5
    Lobe lobes[WALK_K];
    for (int k = 0; k < WALK_K; ++k) {
        const int kind = mat_kind[mat[k]];
        lobes[k].n = env_to_map(&env, n[k]);
        lobes[k].wo = env_to_map(&env, wow[k]);
        lobes[k].axis = env_to_map(&env, (kind == BSDF_LAMBERT) ? n[k] : 2.0f * dot(wow[k], n[k]) * n[k] - wow[k]);
        lobes[k].inv_kappa = 1.0f / mat_kappa[mat[k]];
        lobes[k].levels = mat_levels[mat[k]] & 0xff;   /* depth + 256 lobe shape (product.lobe_shape) */
        lobes[k].shape = mat_levels[mat[k]] >> 8;
        lobes[k].dirs = node_dirs;
    }
    product_sample_k(tree, tree_levels, lobes, guide, guide_pdf);
#elif STRATEGY == 3 || STRATEGY == 4
    const ulong same_tree[WALK_K] = {0};
    tree_sample_k(tree, same_tree, tree_levels, guide, guide_pdf);
#endif
    for (int k = 0; k < WALK_K && i0 + k < count; ++k) {
        const uint i = i0 + k;
        float3 s, t;
        make_frame(n[k], &s, &t);
        const float3 nk = n[k], wowk = wow[k];
        const float3 wo = (float3)(dot(wowk, s), dot(wowk, t), dot(wowk, nk));
        const int kind = mat_kind[mat[k]];
        const float param = mat_param[mat[k]];
        const float3 albedo = mat_albedo[mat[k]].xyz;
        const float4 uk = u[k];

        float3 wi_w[2] = {(float3)(0.0f), (float3)(0.0f)};
        float scal[2] = {0.0f, 0.0f};
#if STRATEGY == 5
#define PDF_GUIDE(w) (product_pdf(tree, tree_levels, &lobes[k], env_world_to_square(&env, w)) \
                     * env_square_to_solid_angle(w))
#else
#define PDF_GUIDE(w) light_pdf(&env, tree, tree_levels, w)
#endif
#if STRATEGY >= 4
        {   /* light (mis) or product (wavelet) sample, weighted against the bsdf pdf */
            const float3 w = env_square_to_world(&env, guide[k]);
            const float pdf = guide_pdf[k] * env_square_to_solid_angle(w);
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
            w = env_square_to_world(&env, guide[k]);
            pdf = guide_pdf[k] * env_square_to_solid_angle(w);
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
