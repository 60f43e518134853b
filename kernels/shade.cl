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
                    __global const int *material, __global const float4 *u_in,
                    __global const int *mat_kind, __global const float *mat_param,
                    __global const float4 *mat_albedo, __global const float *mat_kappa,
                    __global const int *mat_levels, __global const float4 *node_dirs,
                    __global const float4 *texels, const int env_w, const int env_h,
                    __global const float *rot, __global const float *tree, const int tree_levels,
                    __global float4 *wi_out, __global float4 *value_out)
{
    const uint i = get_global_id(0);
    const Env env = {texels, env_w, env_h, rot};
    const float3 n = normal[i].xyz;
    float3 s, t;
    make_frame(n, &s, &t);
    const float3 wow = wo_world[i].xyz;
    const float3 wo = (float3)(dot(wow, s), dot(wow, t), dot(wow, n));
    const int m = material[i];
    const int kind = mat_kind[m];
    const float param = mat_param[m];
    const float3 albedo = mat_albedo[m].xyz;
    const float4 u = u_in[i];

    float3 wi_w[2] = {(float3)(0.0f), (float3)(0.0f)};
    float scal[2] = {0.0f, 0.0f};
#if STRATEGY == 5
    Lobe lobe;
    lobe.n = env_to_map(&env, n);
    lobe.axis = env_to_map(&env, (kind == BSDF_LAMBERT) ? n : 2.0f * dot(wow, n) * n - wow);
    lobe.kappa = mat_kappa[m];
    lobe.levels = mat_levels[m];
    lobe.shape = kind;
    lobe.dirs = node_dirs;
#define SAMPLE_GUIDE(uu, pdfp) product_sample(tree, tree_levels, &lobe, uu, pdfp)
#define PDF_GUIDE(w) (product_pdf(tree, tree_levels, &lobe, env_world_to_square(&env, w)) \
                     * env_square_to_solid_angle(w))
#else
#define SAMPLE_GUIDE(uu, pdfp) tree_sample(tree, tree_levels, uu, pdfp)
#define PDF_GUIDE(w) light_pdf(&env, tree, tree_levels, w)
#endif
#if STRATEGY >= 4
    {   /* light (mis) or product (wavelet) sample, weighted against the bsdf pdf */
        float pdf_sq;
        const float2 uv = SAMPLE_GUIDE(u.xy, &pdf_sq);
        const float3 w = env_square_to_world(&env, uv);
        const float pdf = pdf_sq * env_square_to_solid_angle(w);
        const float3 wl = (float3)(dot(w, s), dot(w, t), dot(w, n));
        const float f = bsdf_eval_cos(kind, param, wl, wo);
        wi_w[0] = w;
        if (pdf > 0.0f && f > 0.0f)  /* the other pdf only where the estimate can be non-zero */
            scal[0] = f / pdf * power_heuristic(pdf, bsdf_pdf(kind, param, wl, wo));
    }
    {   /* bsdf sample, weighted against the light pdf */
        const float3 wl = bsdf_sample(kind, param, wo, u.zw);
        const float pdf = bsdf_pdf(kind, param, wl, wo);
        const float3 w = wl.x * s + wl.y * t + wl.z * n;
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
        wl = (float3)(sqrt(fmax(0.0f, 1.0f - u.x * u.x)) * cos(2.0f * PI_F * u.y),
                      sqrt(fmax(0.0f, 1.0f - u.x * u.x)) * sin(2.0f * PI_F * u.y), u.x);
        pdf = wl.z > 0.0f ? INV_2PI_F : 0.0f;
        w = wl.x * s + wl.y * t + wl.z * n;
#elif STRATEGY == 1
        wl = cosine_hemisphere(u.xy);
        pdf = fmax(wl.z, 0.0f) * INV_PI_F;
        w = wl.x * s + wl.y * t + wl.z * n;
#elif STRATEGY == 2
        wl = bsdf_sample(kind, param, wo, u.xy);
        pdf = bsdf_pdf(kind, param, wl, wo);
        w = wl.x * s + wl.y * t + wl.z * n;
#else
        float pdf_sq;
        const float2 uv = tree_sample(tree, tree_levels, u.xy, &pdf_sq);
        w = env_square_to_world(&env, uv);
        pdf = pdf_sq * env_square_to_solid_angle(w);
        wl = (float3)(dot(w, s), dot(w, t), dot(w, n));
#endif
        wi_w[0] = w;
        if (pdf > 0.0f)
            scal[0] = bsdf_eval_cos(kind, param, wl, wo) / pdf;
    }
#endif
    for (int k = 0; k < 2; ++k) {
        const float3 v = (scal[k] > 0.0f && isfinite(scal[k])) ? scal[k] * albedo * env_eval(&env, wi_w[k])
                                                              : (float3)(0.0f);
        wi_out[2 * i + k] = (float4)(wi_w[k], 0.0f);
        value_out[2 * i + k] = (float4)(v, 0.0f);
    }
}
