/* lambert, phong and ggx in the local frame (normal +z): f cos without albedo,
 * sampling and pdf per unit solid angle. numpy twin: wavlight/bsdfs.py.
 * Scalar code for PoCL's work-item vectoriser (see sphere.h): directions are three
 * floats, results come back through pointers, and every kind is branch-free
 * arithmetic selected per lane. -DBSDF_KINDS (bit mask of the kinds a program
 * evaluates; the host sets it from the scene's materials) drops the others.
 */
#ifndef WAVLIGHT_BSDF_H
#define WAVLIGHT_BSDF_H
#include "sphere.h"

#define BSDF_LAMBERT 0
#define BSDF_PHONG 1
#define BSDF_GGX 2
#ifndef BSDF_KINDS
#define BSDF_KINDS 7
#endif
#define HAS_KIND(k) (BSDF_KINDS & (1 << (k)))

/* Smith G1 for ggx with alpha^2 = a2 at a direction of cosine z. */
__attribute__((always_inline)) inline float ggx_g1(const float z, const float a2)
{
    const float c2 = fmax(z * z, 1e-30f);
    const float tan2 = fmax(1.0f - c2, 0.0f) / c2;
    return z > 0.0f ? 2.0f / (1.0f + sqrt(1.0f + a2 * tan2)) : 0.0f;
}

/* f(wi, wo) cos_i (no albedo) into *f and the sampling pdf of wi into *pdf. */
__attribute__((always_inline)) inline void bsdf_eval_pdf(const int kind, const float param,
                                                         const float ix, const float iy, const float iz,
                                                         const float ox, const float oy, const float oz,
                                                         float *f, float *pdf)
{
    float fv = 0.0f, pv = 0.0f;
#if HAS_KIND(BSDF_LAMBERT)
    if (kind == BSDF_LAMBERT) {
        fv = fmax(iz, 0.0f) * INV_PI_F;
        pv = fv;
    }
#endif
#if HAS_KIND(BSDF_PHONG)
    if (kind == BSDF_PHONG) {   /* cos alpha = wi . reflect(wo), reflect(wo) = (-ox, -oy, oz) */
        const float ca = fmax(iz * oz - ix * ox - iy * oy, 0.0f);
        const float pw = ca > 0.0f ? exp2(param * log2(ca)) : 0.0f;
        fv = (param + 2.0f) * INV_2PI_F * pw * fmax(iz, 0.0f);
        pv = (param + 1.0f) * INV_2PI_F * pw;
    }
#endif
#if HAS_KIND(BSDF_GGX)
    if (kind == BSDF_GGX) {
        const float a2 = param * param;
        const float hx = ix + ox, hy = iy + oy, hz = iz + oz;
        const float hh = hx * hx + hy * hy + hz * hz;
        const int ok = hh > 0.0f;
        const float il = ok ? rsqrt(hh) : 0.0f;
        const float nhz = ok ? hz * il : 1.0f;                         /* h = (0, 0, 1) if wi = -wo */
        const float ih = ok ? (ix * hx + iy * hy + iz * hz) * il : iz;
        const float oh = ok ? (ox * hx + oy * hy + oz * hz) * il : oz;
        const float d = nhz * nhz * (a2 - 1.0f) + 1.0f;
        const float D = nhz > 0.0f ? a2 / (PI_F * d * d) : 0.0f;
        const float base = D * ggx_g1(oz, a2) / (4.0f * fmax(oz, 1e-12f));
        fv = (iz > 0.0f && oz > 0.0f && ih > 0.0f) ? base * ggx_g1(iz, a2) : 0.0f;
        pv = (oz > 0.0f && ih > 0.0f && oh > 0.0f) ? base : 0.0f;
    }
#endif
    *f = fv;
    *pdf = pv;
}

/* A direction wi drawn from the bsdf's sampling density for uniform (u0, u1):
 * lambert the concentric-disk cosine map (Shirley & Chiu), phong its lobe about the
 * mirror direction, ggx the visible normals (Heitz 2018). */
__attribute__((always_inline)) inline void bsdf_sample(const int kind, const float param,
                                                       const float ox, const float oy, const float oz,
                                                       const float u0, const float u1,
                                                       float *wx, float *wy, float *wz)
{
    float x = 0.0f, y = 0.0f, z = 1.0f;
#if HAS_KIND(BSDF_LAMBERT)
    if (kind == BSDF_LAMBERT) {
        const float a = fma(2.0f, u0, -1.0f), b = (u1 + u1) - 1.0f;   /* not a pair (sphere.h) */
        const int zero = a == 0.0f && b == 0.0f;
        const int wide = fabs(a) > ABS_ALT(b);
        const float r = zero ? 0.0f : (wide ? a : b);
        const float phi = zero ? 0.0f : (wide ? (PI_F / 4.0f) * (b / a) : PI_F / 2.0f - (PI_F / 4.0f) * (a / b));
        float sp, cp;
        fast_sincos(phi, &sp, &cp);
        x = r * cp;
        y = r * sp;
        z = sqrt(fmax(0.0f, 1.0f - x * x - y * y));
    }
#endif
#if HAS_KIND(BSDF_PHONG)
    if (kind == BSDF_PHONG) {
        const float cos_a = exp2(log2(u0) / (param + 1.0f));
        const float sin_a = sqrt(fmax(0.0f, 1.0f - cos_a * cos_a));
        float sp, cp;
        fast_sincos(2.0f * PI_F * u1, &sp, &cp);
        float sx, sy, sz, tx, ty, tz;
        make_frame(-ox, -oy, oz, &sx, &sy, &sz, &tx, &ty, &tz);   /* about reflect(wo) */
        const float cs = sin_a * cp, sn = sin_a * sp;
        x = cs * sx + sn * tx - cos_a * ox;
        y = cs * sy + sn * ty - cos_a * oy;
        z = cs * sz + sn * tz + cos_a * oz;
    }
#endif
#if HAS_KIND(BSDF_GGX)
    if (kind == BSDF_GGX) {
        const float alpha = param;
        const float vx0 = alpha * ox, vy0 = alpha * oy;
        const float il = rsqrt(vx0 * vx0 + vy0 * vy0 + oz * oz);
        const float vx = vx0 * il, vy = vy0 * il, vz = oz * il;       /* stretched view direction */
        const float lensq = vx * vx + vy * vy;
        const float inv = lensq > 0.0f ? rsqrt(lensq) : 0.0f;
        const float t1x = lensq > 0.0f ? -vy * inv : 1.0f, t1y = vx * inv;   /* t1 = (-vy, vx, 0) / len */
        const float t2x = -vz * t1y, t2y = vz * t1x, t2z = vx * t1y - vy * t1x;   /* t2 = v x t1 */
        const float r = sqrt(u0);
        float sp, cp;
        fast_sincos(2.0f * PI_F * u1, &sp, &cp);
        const float p1 = r * cp;
        const float s = 0.5f * (1.0f + vz);
        const float p2 = (1.0f - s) * sqrt(fmax(0.0f, 1.0f - p1 * p1)) + s * (r * sp);
        const float p3 = sqrt(fmax(0.0f, 1.0f - p1 * p1 - p2 * p2));
        const float nx = p1 * t1x + p2 * t2x + p3 * vx;
        const float ny = p1 * t1y + p2 * t2y + p3 * vy;
        const float nz = p2 * t2z + p3 * vz;
        const float hx0 = alpha * nx, hy0 = alpha * ny, hz0 = fmax(1e-7f, nz);
        const float ih = rsqrt(hx0 * hx0 + hy0 * hy0 + hz0 * hz0);
        const float hx = hx0 * ih, hy = hy0 * ih, hz = hz0 * ih;
        const float d2 = 2.0f * (ox * hx + oy * hy + oz * hz);
        x = d2 * hx - ox;
        y = d2 * hy - oy;
        z = d2 * hz - oz;
    }
#endif
    *wx = x;
    *wy = y;
    *wz = z;
}
#endif
