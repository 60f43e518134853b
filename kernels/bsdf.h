/* lambert, phong and ggx in the local frame (normal +z): f cos without albedo,
 * sampling and pdf per unit solid angle, eight directions at a time (simd.h), each
 * lane with its own material kind and parameter. numpy twin: wavlight/bsdfs.py.
 * Every kind is branch-free arithmetic selected per lane; -DBSDF_KINDS (bit mask of
 * the kinds a program evaluates; the host sets it from the scene's materials) drops
 * the others.
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
inline realv ggx_g1(const realv z, const realv a2)
{
    const realv c2 = fmax(z * z, 1e-30f);
    const realv tan2 = fmax(1.0f - c2, 0.0f) / c2;
    return select((realv)0.0f, 2.0f / (1.0f + sqrt(1.0f + a2 * tan2)), z > 0.0f);
}

/* f(wi, wo) cos_i (no albedo) into *f and the sampling pdf of wi into *pdf. */
inline void bsdf_eval_pdf(const intv kind, const realv param, const realv ix, const realv iy, const realv iz,
                          const realv ox, const realv oy, const realv oz, realv *f, realv *pdf)
{
    realv fv = 0.0f, pv = 0.0f;
#if HAS_KIND(BSDF_LAMBERT)
    {
        const realv c = fmax(iz, 0.0f) * INV_PI_F;
        fv = select(fv, c, kind == BSDF_LAMBERT);
        pv = select(pv, c, kind == BSDF_LAMBERT);
    }
#endif
#if HAS_KIND(BSDF_PHONG)
    {   /* cos alpha = wi . reflect(wo), reflect(wo) = (-ox, -oy, oz) */
        const realv ca = fmax(iz * oz - ix * ox - iy * oy, 0.0f);
        const realv pw = select((realv)0.0f, exp2(param * log2(ca)), ca > 0.0f);
        fv = select(fv, (param + 2.0f) * INV_2PI_F * pw * fmax(iz, 0.0f), kind == BSDF_PHONG);
        pv = select(pv, (param + 1.0f) * INV_2PI_F * pw, kind == BSDF_PHONG);
    }
#endif
#if HAS_KIND(BSDF_GGX)
    {
        const realv a2 = param * param;
        const realv hx = ix + ox, hy = iy + oy, hz = iz + oz;
        const realv hh = hx * hx + hy * hy + hz * hz;
        const intv ok = hh > 0.0f;
        const realv il = select((realv)0.0f, rsqrt(hh), ok);
        const realv nhz = select((realv)1.0f, hz * il, ok);             /* h = (0, 0, 1) if wi = -wo */
        const realv ih = select(iz, (ix * hx + iy * hy + iz * hz) * il, ok);
        const realv oh = select(oz, (ox * hx + oy * hy + oz * hz) * il, ok);
        const realv d = nhz * nhz * (a2 - 1.0f) + 1.0f;
        const realv D = select((realv)0.0f, a2 / (PI_F * d * d), nhz > 0.0f);
        const realv base = D * ggx_g1(oz, a2) / (4.0f * fmax(oz, 1e-12f));
        const intv g = kind == BSDF_GGX;
        fv = select(fv, select((realv)0.0f, base * ggx_g1(iz, a2), (iz > 0.0f) & (oz > 0.0f) & (ih > 0.0f)), g);
        pv = select(pv, select((realv)0.0f, base, (oz > 0.0f) & (ih > 0.0f) & (oh > 0.0f)), g);
    }
#endif
    *f = fv;
    *pdf = pv;
}

/* Directions drawn from the bsdf's sampling density for uniforms (u0, u1): lambert
 * the concentric-disk cosine map (Shirley & Chiu), phong its lobe about the mirror
 * direction, ggx the visible normals (Heitz 2018). */
inline void bsdf_sample(const intv kind, const realv param, const realv ox, const realv oy, const realv oz,
                        const realv u0, const realv u1, realv *wx, realv *wy, realv *wz)
{
    realv x = 0.0f, y = 0.0f, z = 1.0f;
#if HAS_KIND(BSDF_LAMBERT)
    {
        const realv a = 2.0f * u0 - 1.0f, b = 2.0f * u1 - 1.0f;
        const intv zero = (a == 0.0f) & (b == 0.0f);
        const intv wide = fabs(a) > fabs(b);
        const realv r = select(select(b, a, wide), (realv)0.0f, zero);
        const realv phi = select(select(PI_F / 2.0f - (PI_F / 4.0f) * (a / b), (PI_F / 4.0f) * (b / a), wide),
                                 (realv)0.0f, zero);
        realv sp, cp;
        fast_sincos(phi, &sp, &cp);
        const realv lx = r * cp, ly = r * sp;
        const intv l = kind == BSDF_LAMBERT;
        x = select(x, lx, l);
        y = select(y, ly, l);
        z = select(z, sqrt(fmax(0.0f, 1.0f - lx * lx - ly * ly)), l);
    }
#endif
#if HAS_KIND(BSDF_PHONG)
    {
        const realv cos_a = exp2(log2(u0) / (param + 1.0f));
        const realv sin_a = sqrt(fmax(0.0f, 1.0f - cos_a * cos_a));
        realv sp, cp;
        fast_sincos(2.0f * PI_F * u1, &sp, &cp);
        realv sx, sy, sz, tx, ty, tz;
        make_frame(-ox, -oy, oz, &sx, &sy, &sz, &tx, &ty, &tz);   /* about reflect(wo) */
        const realv cs = sin_a * cp, sn = sin_a * sp;
        const intv p = kind == BSDF_PHONG;
        x = select(x, cs * sx + sn * tx - cos_a * ox, p);
        y = select(y, cs * sy + sn * ty - cos_a * oy, p);
        z = select(z, cs * sz + sn * tz + cos_a * oz, p);
    }
#endif
#if HAS_KIND(BSDF_GGX)
    {
        const realv alpha = param;
        const realv vx0 = alpha * ox, vy0 = alpha * oy;
        const realv il = rsqrt(vx0 * vx0 + vy0 * vy0 + oz * oz);
        const realv vx = vx0 * il, vy = vy0 * il, vz = oz * il;        /* stretched view direction */
        const realv lensq = vx * vx + vy * vy;
        const intv ok = lensq > 0.0f;
        const realv inv = select((realv)0.0f, rsqrt(lensq), ok);
        const realv t1x = select((realv)1.0f, -vy * inv, ok), t1y = vx * inv;   /* t1 = (-vy, vx, 0) / len */
        const realv t2x = -vz * t1y, t2y = vz * t1x, t2z = vx * t1y - vy * t1x;   /* t2 = v x t1 */
        const realv r = sqrt(u0);
        realv sp, cp;
        fast_sincos(2.0f * PI_F * u1, &sp, &cp);
        const realv p1 = r * cp;
        const realv s = 0.5f * (1.0f + vz);
        const realv p2 = (1.0f - s) * sqrt(fmax(0.0f, 1.0f - p1 * p1)) + s * (r * sp);
        const realv p3 = sqrt(fmax(0.0f, 1.0f - p1 * p1 - p2 * p2));
        const realv nx = p1 * t1x + p2 * t2x + p3 * vx;
        const realv ny = p1 * t1y + p2 * t2y + p3 * vy;
        const realv nz = p2 * t2z + p3 * vz;
        const realv hx0 = alpha * nx, hy0 = alpha * ny, hz0 = fmax(1e-7f, nz);
        const realv ih = rsqrt(hx0 * hx0 + hy0 * hy0 + hz0 * hz0);
        const realv hx = hx0 * ih, hy = hy0 * ih, hz = hz0 * ih;
        const realv d2 = 2.0f * (ox * hx + oy * hy + oz * hz);
        const intv g = kind == BSDF_GGX;
        x = select(x, d2 * hx - ox, g);
        y = select(y, d2 * hy - oy, g);
        z = select(z, d2 * hz - oz, g);
    }
#endif
    *wx = x;
    *wy = y;
    *wz = z;
}
#endif
