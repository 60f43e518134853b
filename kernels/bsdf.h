/* lambert, phong, ggx and plastic in the local frame (normal +z): f cos without albedo,
 * sampling and pdf per unit solid angle, eight directions at a time (simd.h), each
 * lane with its own material kind and parameter. numpy twin: wavlight/bsdfs.py.
 * plastic (Mitsuba 3's roughplastic, docs/decisions/plastic-material.md) reads its
 * row of the plastic table (PLASTIC_STRIDE floats per material: eta, specular sampling
 * weight, diffuse scale, alpha, the transmittance at PLASTIC_RES cosines), and its
 * albedo does not factor out: material_eval_pdf also returns the part of f cos the
 * albedo multiplies (the diffuse part; all of it for the other kinds).
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
#define BSDF_PLASTIC 3
#ifndef BSDF_KINDS
#define BSDF_KINDS 7
#endif
#define PLASTIC_RES 64
#define PLASTIC_HEAD 4
#define PLASTIC_STRIDE (PLASTIC_HEAD + PLASTIC_RES)
#define HAS_KIND(k) (BSDF_KINDS & (1 << (k)))

/* Smith G1 for ggx with alpha^2 = a2 at a direction of cosine z. */
inline realv ggx_g1(const realv z, const realv a2)
{
    const realv c2 = fmax(z * z, 1e-30f);
    const realv tan2 = fmax(1.0f - c2, 0.0f) / c2;
    return select((realv)0.0f, 2.0f / (1.0f + sqrt(1.0f + a2 * tan2)), z > 0.0f);
}

/* ggx f cos (no albedo), its visible-normal pdf and wo . h for roughness alpha. */
inline void ggx_eval_pdf(const realv alpha, const realv ix, const realv iy, const realv iz,
                         const realv ox, const realv oy, const realv oz, realv *f, realv *pdf, realv *oh_out)
{
    const realv a2 = alpha * alpha;
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
    *f = select((realv)0.0f, base * ggx_g1(iz, a2), (iz > 0.0f) & (oz > 0.0f) & (ih > 0.0f));
    *pdf = select((realv)0.0f, base, (oz > 0.0f) & (ih > 0.0f) & (oh > 0.0f));
    *oh_out = oh;
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
        realv gf, gp, oh;
        ggx_eval_pdf(param, ix, iy, iz, ox, oy, oz, &gf, &gp, &oh);
        const intv g = kind == BSDF_GGX;
        fv = select(fv, gf, g);
        pv = select(pv, gp, g);
    }
#endif
    *f = fv;
    *pdf = pv;
}

/* The cosine hemisphere by the concentric-disk map (Shirley & Chiu). */
inline void cosine_sample(const realv u0, const realv u1, realv *wx, realv *wy, realv *wz)
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
    *wx = lx;
    *wy = ly;
    *wz = sqrt(fmax(0.0f, 1.0f - lx * lx - ly * ly));
}

/* ggx's visible normals (Heitz 2018) for roughness alpha, reflected about wo. */
inline void ggx_sample(const realv alpha, const realv ox, const realv oy, const realv oz,
                       const realv u0, const realv u1, realv *wx, realv *wy, realv *wz)
{
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
    *wx = d2 * hx - ox;
    *wy = d2 * hy - oy;
    *wz = d2 * hz - oz;
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
        realv lx, ly, lz;
        cosine_sample(u0, u1, &lx, &ly, &lz);
        const intv l = kind == BSDF_LAMBERT;
        x = select(x, lx, l);
        y = select(y, ly, l);
        z = select(z, lz, l);
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
        realv gx, gy, gz;
        ggx_sample(param, ox, oy, oz, u0, u1, &gx, &gy, &gz);
        const intv g = kind == BSDF_GGX;
        x = select(x, gx, g);
        y = select(y, gy, g);
        z = select(z, gz, g);
    }
#endif
    *wx = x;
    *wy = y;
    *wz = z;
}
/* Unpolarized Fresnel reflectance of a dielectric of relative index eta > 1 seen from
 * outside at cosine c >= 0 (Mitsuba 3's fresnel, include/mitsuba/render/fresnel.h). */
inline realv fresnel_dielectric(const realv c, const realv eta)
{
    const realv ci = fabs(c);
    const realv inv = 1.0f / eta;
    const realv ct = sqrt(fmax(1.0f - (1.0f - ci * ci) * inv * inv, 0.0f));
    const realv a_s = (ci - eta * ct) / (ci + eta * ct), a_p = (ct - eta * ci) / (ct + eta * ci);
    return select(0.5f * (a_s * a_s + a_p * a_p), (realv)1.0f, ci == 0.0f);
}

/* The plastic row's transmittance T(c), c in [0, 1], linear between entries (Mitsuba's
 * lerp_gather); row: each lane's row offset in the table. */
inline realv plastic_transmittance(__global const float *table, const uintv row, const realv c)
{
    const realv x = clamp(c, 0.0f, 1.0f) * (float)(PLASTIC_RES - 1);
    const uintv i = min(convert_uintv(x), (uintv)(PLASTIC_RES - 2));
    const realv v0 = GATHER(table, row + PLASTIC_HEAD + i), v1 = GATHER(table, row + PLASTIC_HEAD + 1 + i);
    return v0 + (v1 - v0) * (x - convert_realv(i));
}

/* The probability of the specular lobe at view cosine oz (roughplastic's sample). */
inline realv plastic_spec_prob(__global const float *table, const uintv row, const realv oz)
{
    const realv t = plastic_transmittance(table, row, oz), w = GATHER(table, row + 1);
    const realv ps = (1.0f - t) * w, pd = t * (1.0f - w);
    return select((realv)0.0f, ps / (ps + pd), ps + pd > 0.0f);
}

/* Every kind: f cos (no albedo) into *f, the part of it the albedo multiplies into *fd, the
 * sampling pdf into *pdf. plastic: F(wo.h) ggx + T(cos_o) T(cos_i) cos_i / (pi eta^2 (1 - R_int)),
 * the second the albedo's; pdf q ggx's + (1 - q) cos_i / pi. row = material x PLASTIC_STRIDE. */
inline void material_eval_pdf(const intv kind, const realv param, __global const float *table, const uintv row,
                              const realv ix, const realv iy, const realv iz, const realv ox, const realv oy,
                              const realv oz, realv *f, realv *fd, realv *pdf)
{
    bsdf_eval_pdf(kind, param, ix, iy, iz, ox, oy, oz, f, pdf);
    *fd = *f;
#if HAS_KIND(BSDF_PLASTIC)
    {
        const realv eta = GATHER(table, row), scale = GATHER(table, row + 2), alpha = GATHER(table, row + 3);
        realv g, gp, oh;
        ggx_eval_pdf(alpha, ix, iy, iz, ox, oy, oz, &g, &gp, &oh);
        const realv spec = fresnel_dielectric(oh, eta) * g;
        const realv diff = scale * iz * plastic_transmittance(table, row, iz) * plastic_transmittance(table, row, oz);
        const realv q = plastic_spec_prob(table, row, oz);
        const intv ok = (iz > 0.0f) & (oz > 0.0f);
        const intv p = kind == BSDF_PLASTIC;
        *f = select(*f, select((realv)0.0f, spec + diff, ok), p);
        *fd = select(*fd, select((realv)0.0f, diff, ok), p);
        *pdf = select(*pdf, select((realv)0.0f, q * gp + (1.0f - q) * iz * INV_PI_F, ok), p);
    }
#endif
}

/* Every kind's sampler: plastic takes the specular lobe (ggx's visible normals) where u0 < q,
 * else the cosine, with u0 rescaled to [0, 1) within its choice. */
inline void material_sample(const intv kind, const realv param, __global const float *table, const uintv row,
                            const realv ox, const realv oy, const realv oz, const realv u0, const realv u1,
                            realv *wx, realv *wy, realv *wz)
{
    bsdf_sample(kind, param, ox, oy, oz, u0, u1, wx, wy, wz);
#if HAS_KIND(BSDF_PLASTIC)
    {
        const realv q = plastic_spec_prob(table, row, oz);
        const intv spec = u0 < q;
        const realv v = fmin(select((u0 - q) / (1.0f - q), u0 / q, spec), 0x1.fffffep-1f);
        realv gx, gy, gz, cx, cy, cz;
        ggx_sample(GATHER(table, row + 3), ox, oy, oz, v, u1, &gx, &gy, &gz);
        cosine_sample(v, u1, &cx, &cy, &cz);
        const intv p = kind == BSDF_PLASTIC;
        *wx = select(*wx, select(cx, gx, spec), p);
        *wy = select(*wy, select(cy, gy, spec), p);
        *wz = select(*wz, select(cz, gz, spec), p);
    }
#endif
}
#endif
