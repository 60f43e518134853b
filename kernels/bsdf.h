/* lambert, phong and ggx in the local frame (normal +z): f cos without albedo,
 * sampling and pdf per unit solid angle. numpy twin: wavlight/bsdfs.py.
 */
#ifndef WAVLIGHT_BSDF_H
#define WAVLIGHT_BSDF_H
#include "sphere.h"

#define BSDF_LAMBERT 0
#define BSDF_PHONG 1
#define BSDF_GGX 2

inline float3 reflect_local(const float3 wo) { return (float3)(-wo.x, -wo.y, wo.z); }

inline float3 cosine_hemisphere(const float2 u)
{
    const float a = 2.0f * u.x - 1.0f, b = 2.0f * u.y - 1.0f;
    float r, phi;
    if (a == 0.0f && b == 0.0f) { r = 0.0f; phi = 0.0f; }
    else if (fabs(a) > fabs(b)) { r = a; phi = (PI_F / 4.0f) * (b / a); }
    else { r = b; phi = PI_F / 2.0f - (PI_F / 4.0f) * (a / b); }
    const float x = r * cos(phi), y = r * sin(phi);
    return (float3)(x, y, sqrt(fmax(0.0f, 1.0f - x * x - y * y)));
}

inline float ggx_d(const float3 h, const float alpha)
{
    if (h.z <= 0.0f) return 0.0f;
    const float a2 = alpha * alpha;
    const float d = h.z * h.z * (a2 - 1.0f) + 1.0f;
    return a2 / (PI_F * d * d);
}

inline float ggx_g1(const float3 w, const float alpha)
{
    if (w.z <= 0.0f) return 0.0f;
    const float c2 = fmax(w.z * w.z, 1e-30f);
    const float tan2 = fmax(1.0f - c2, 0.0f) / c2;
    return 2.0f / (1.0f + sqrt(1.0f + alpha * alpha * tan2));
}

inline float3 half_vector(const float3 wi, const float3 wo)
{
    const float3 h = wi + wo;
    const float l = length(h);
    return l > 0.0f ? h / l : (float3)(0.0f, 0.0f, 1.0f);
}

inline float bsdf_eval_cos(const int kind, const float param, const float3 wi, const float3 wo)
{
    if (kind == BSDF_LAMBERT)
        return fmax(wi.z, 0.0f) * INV_PI_F;
    if (kind == BSDF_PHONG) {
        const float ca = fmax(dot(wi, reflect_local(wo)), 0.0f);
        return (param + 2.0f) * INV_2PI_F * pow(ca, param) * fmax(wi.z, 0.0f);
    }
    const float3 h = half_vector(wi, wo);
    if (wi.z <= 0.0f || wo.z <= 0.0f || dot(wi, h) <= 0.0f) return 0.0f;
    return ggx_d(h, param) * ggx_g1(wi, param) * ggx_g1(wo, param) / (4.0f * fmax(wo.z, 1e-12f));
}

inline float bsdf_pdf(const int kind, const float param, const float3 wi, const float3 wo)
{
    if (kind == BSDF_LAMBERT)
        return fmax(wi.z, 0.0f) * INV_PI_F;
    if (kind == BSDF_PHONG) {
        const float ca = fmax(dot(wi, reflect_local(wo)), 0.0f);
        return (param + 1.0f) * INV_2PI_F * pow(ca, param);
    }
    const float3 h = half_vector(wi, wo);
    if (wo.z <= 0.0f || dot(wi, h) <= 0.0f || dot(wo, h) <= 0.0f) return 0.0f;
    return ggx_g1(wo, param) * ggx_d(h, param) / (4.0f * fmax(wo.z, 1e-12f));
}

/* Heitz 2018, "Sampling the GGX distribution of visible normals". */
inline float3 ggx_sample_vndf(const float3 wo, const float alpha, const float2 u)
{
    const float3 vh = normalize((float3)(alpha * wo.x, alpha * wo.y, wo.z));
    const float lensq = vh.x * vh.x + vh.y * vh.y;
    const float3 t1 = lensq > 0.0f ? (float3)(-vh.y, vh.x, 0.0f) * rsqrt(lensq) : (float3)(1.0f, 0.0f, 0.0f);
    const float3 t2 = cross(vh, t1);
    const float r = sqrt(u.x), phi = 2.0f * PI_F * u.y;
    const float p1 = r * cos(phi);
    float p2 = r * sin(phi);
    const float s = 0.5f * (1.0f + vh.z);
    p2 = (1.0f - s) * sqrt(fmax(0.0f, 1.0f - p1 * p1)) + s * p2;
    const float p3 = sqrt(fmax(0.0f, 1.0f - p1 * p1 - p2 * p2));
    const float3 nh = p1 * t1 + p2 * t2 + p3 * vh;
    const float3 h = normalize((float3)(alpha * nh.x, alpha * nh.y, fmax(1e-7f, nh.z)));
    return 2.0f * dot(wo, h) * h - wo;
}

inline float3 bsdf_sample(const int kind, const float param, const float3 wo, const float2 u)
{
    if (kind == BSDF_LAMBERT)
        return cosine_hemisphere(u);
    if (kind == BSDF_PHONG) {
        const float cos_a = pow(u.x, 1.0f / (param + 1.0f));
        const float sin_a = sqrt(fmax(0.0f, 1.0f - cos_a * cos_a));
        const float phi = 2.0f * PI_F * u.y;
        const float3 r = reflect_local(wo);
        float3 s, t;
        make_frame(r, &s, &t);
        return sin_a * cos(phi) * s + sin_a * sin(phi) * t + cos_a * r;
    }
    return ggx_sample_vndf(wo, param, u);
}
#endif
