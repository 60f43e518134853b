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
 * light and product samples walk their trees here (warp.h tree_walk, product.h
 * product_walk): the program is built per light-tree depth (-DN_LEVELS) and, for
 * wavelet, per largest product depth and set of lobe shapes (-DPRODUCT_LEVELS,
 * -DLOBE_SHAPES). One launch per batch: as a separate kernel the light walk took
 * 2.9 ms per 52 k points waited on alone against 1.7 ms back to back, and the render
 * was 15-30% slower (light 1.42 -> 1.02-1.19 s, mis 1.75 -> 1.54 s, with the other
 * changes of that commit).
 *
 * Eight points per work-item in vector types (simd.h; launch ceil(count / 8)
 * work-items or more): measured 3.7x over one scalar point per work-item on an AVX2
 * CPU. Inputs are rows of 3 floats (normal, wo_world) and u rows of 4; outputs are
 * planes of `count` floats: wi_out holds slot 0 x, y, z then slot 1 x, y, z,
 * value_out the same for r, g, b. -DBSDF_KINDS: the material kinds present (bsdf.h).
 */
#include "warp.h"
#include "bsdf.h"
#include "product.h"
#if STRATEGY >= 3 && !defined(N_LEVELS)
#error "shade.cl with the light or product sample is built with -DN_LEVELS (the light tree's depth)"
#endif

inline realv power_heuristic(const realv pa, const realv pb)
{
    const realv big = fmax(pa, pb);
    const realv a = pa / big, b = pb / big;
    return select((realv)0.0f, a * a / (a * a + b * b), big > 0.0f);
}

/* Density per unit solid angle of the light tree at world directions (x, y, z) (MIS weight). */
inline realv light_pdf(__global const float *rot, __global const float *tree, const int levels,
                       const realv x, const realv y, const realv z)
{
    realv u, v;
    env_world_to_square(rot, x, y, z, &u, &v);
    return tree_pdf(tree, (uintv)0, levels, u, v) * env_square_to_solid_angle(x, z);
}

__kernel void shade(__global const float *normal, __global const float *wo_world,
                    __global const int *material, __global const float *u_in, const uint count,
                    __global const int *mat_kind, __global const float *mat_param,
                    __global const float *mat_albedo, __global const float *mat_kappa,
                    __global const int *mat_levels, __global const float *angles,
                    __global const float *texels, const int env_w, const int env_h,
                    __global const float *rot, __global const float *tree,
                    __global float *wi_out, __global float *value_out)
{
    const uint base = LANE_BASE();
    if (base >= count) return;
    const uintv i = LANE_INDEX(count);
    const realv u0 = GATHER(u_in, 4 * i), u1 = GATHER(u_in, 4 * i + 1);
#if STRATEGY == 3 || STRATEGY == 4
    /* the light sample first, while little else is live (the walk is a chain of gathers) */
    realv gu = u0, gv = u1;
    const realv square_pdf = tree_walk(tree, (uintv)0, &gu, &gv);
#endif
    const intv mat = GATHER_INT(material, i);
    const realv nx = GATHER(normal, 3 * i), ny = GATHER(normal, 3 * i + 1), nz = GATHER(normal, 3 * i + 2);
    const realv ex = GATHER(wo_world, 3 * i), ey = GATHER(wo_world, 3 * i + 1), ez = GATHER(wo_world, 3 * i + 2);
    realv sx, sy, sz, tx, ty, tz;
    make_frame(nx, ny, nz, &sx, &sy, &sz, &tx, &ty, &tz);
    const realv ox = ex * sx + ey * sy + ez * sz, oy = ex * tx + ey * ty + ez * tz, oz = ex * nx + ey * ny + ez * nz;
    const intv kind = GATHER_INT(mat_kind, mat);
    const realv param = GATHER(mat_param, mat);
    /* slot a (and b): world direction, scalar f / pdf (x MIS weight) */
    realv ax = 0.0f, ay = 0.0f, az = 0.0f, sa = 0.0f;
    realv bx = 0.0f, by = 0.0f, bz = 0.0f, sb = 0.0f;
#if STRATEGY == 5
    const Lobe lobe = make_lobe(rot, nx, ny, nz, ex, ey, ez, GATHER(mat_kappa, mat), GATHER_INT(mat_levels, mat));
#endif
#if STRATEGY >= 3
    {   /* the light (light, mis) or product (wavelet) sample from u.xy */
#if STRATEGY == 5
        realv gu = u0, gv = u1;
        const realv square_pdf = product_walk(tree, angles, &lobe, &gu, &gv);
#endif
        env_square_to_world(rot, gu, gv, &ax, &ay, &az);
        const realv pdf = square_pdf * env_square_to_solid_angle(ax, az);
        const realv lx = ax * sx + ay * sy + az * sz, ly = ax * tx + ay * ty + az * tz;
        const realv lz = ax * nx + ay * ny + az * nz;
        realv f, pdf_bsdf;
        bsdf_eval_pdf(kind, param, lx, ly, lz, ox, oy, oz, &f, &pdf_bsdf);
#if STRATEGY == 3
        sa = select((realv)0.0f, f / pdf, pdf > 0.0f);
#else
        /* the other pdf matters only where the estimate can be non-zero */
        sa = select((realv)0.0f, f / pdf * power_heuristic(pdf, pdf_bsdf), (pdf > 0.0f) & (f > 0.0f));
#endif
    }
#endif
#if STRATEGY >= 4
    {   /* the bsdf sample from u.zw, weighted against the guide's pdf */
        realv lx, ly, lz, f, pdf;
        bsdf_sample(kind, param, ox, oy, oz, GATHER(u_in, 4 * i + 2), GATHER(u_in, 4 * i + 3), &lx, &ly, &lz);
        bsdf_eval_pdf(kind, param, lx, ly, lz, ox, oy, oz, &f, &pdf);
        bx = lx * sx + ly * tx + lz * nx;
        by = lx * sy + ly * ty + lz * ny;
        bz = lx * sz + ly * tz + lz * nz;
#if STRATEGY == 5
        realv gu, gv;
        env_world_to_square(rot, bx, by, bz, &gu, &gv);
        const realv other = product_pdf(tree, angles, &lobe, gu, gv) * env_square_to_solid_angle(bx, bz);
#else
        const realv other = light_pdf(rot, tree, N_LEVELS, bx, by, bz);
#endif
        sb = select((realv)0.0f, f / pdf * power_heuristic(pdf, other), (pdf > 0.0f) & (f > 0.0f));
    }
#endif
#if STRATEGY <= 2
    {
        realv lx, ly, lz, pdf;
#if STRATEGY == 0   /* uniform hemisphere */
        const realv r = sqrt(fmax(0.0f, 1.0f - u0 * u0));
        realv sp, cp;
        fast_sincos(2.0f * PI_F * u1, &sp, &cp);
        lx = r * cp;
        ly = r * sp;
        lz = u0;
        pdf = select((realv)0.0f, (realv)INV_2PI_F, lz > 0.0f);
#elif STRATEGY == 1   /* cosine hemisphere: the lambert sampler */
        bsdf_sample((intv)BSDF_LAMBERT, param, ox, oy, oz, u0, u1, &lx, &ly, &lz);
        pdf = fmax(lz, 0.0f) * INV_PI_F;
#else
        bsdf_sample(kind, param, ox, oy, oz, u0, u1, &lx, &ly, &lz);
#endif
        realv f, pdf_bsdf;
        bsdf_eval_pdf(kind, param, lx, ly, lz, ox, oy, oz, &f, &pdf_bsdf);
#if STRATEGY == 2
        pdf = pdf_bsdf;
#endif
        ax = lx * sx + ly * tx + lz * nx;
        ay = lx * sy + ly * ty + lz * ny;
        az = lx * sz + ly * tz + lz * nz;
        sa = select((realv)0.0f, f / pdf, pdf > 0.0f);
    }
#endif
    /* estimates: albedo x scalar x environment radiance (zero where the scalar is not a
     * positive finite number) */
    sa = select((realv)0.0f, sa, (sa > 0.0f) & isfinite(sa));
    sb = select((realv)0.0f, sb, (sb > 0.0f) & isfinite(sb));
    realv ua, va, ub, vb;
    env_world_to_square(rot, ax, ay, az, &ua, &va);
    env_world_to_square(rot, bx, by, bz, &ub, &vb);
    const uintv ka = 4 * env_texel(env_w, env_h, ua, va), kb = 4 * env_texel(env_w, env_h, ub, vb);
    const uintv am = as_uintv(4 * mat);
    const realv ar = GATHER(mat_albedo, am), ag = GATHER(mat_albedo, am + 1), ab = GATHER(mat_albedo, am + 2);
    STORE_LANES(ax, wi_out, base, count);
    STORE_LANES(ay, wi_out + count, base, count);
    STORE_LANES(az, wi_out + 2 * count, base, count);
    STORE_LANES(bx, wi_out + 3 * count, base, count);
    STORE_LANES(by, wi_out + 4 * count, base, count);
    STORE_LANES(bz, wi_out + 5 * count, base, count);
    STORE_LANES(sa * ar * GATHER(texels, ka), value_out, base, count);
    STORE_LANES(sa * ag * GATHER(texels, ka + 1), value_out + count, base, count);
    STORE_LANES(sa * ab * GATHER(texels, ka + 2), value_out + 2 * count, base, count);
    STORE_LANES(sb * ar * GATHER(texels, kb), value_out + 3 * count, base, count);
    STORE_LANES(sb * ag * GATHER(texels, kb + 1), value_out + 4 * count, base, count);
    STORE_LANES(sb * ab * GATHER(texels, kb + 2), value_out + 5 * count, base, count);
}

/* Radiance of the environment seen along world directions (3 planes of count floats)
 * -> 3 planes (r, g, b): the camera rays that miss the scene. numpy twin:
 * Environment.eval. */
__kernel void env_radiance(__global const float *dirs, const uint count, __global const float *texels,
                           const int env_w, const int env_h, __global const float *rot,
                           __global float *rgb_out)
{
    const uint base = LANE_BASE();
    if (base >= count) return;
    const uintv i = LANE_INDEX(count);
    realv u, v;
    env_world_to_square(rot, LOAD_LANES(dirs, i, base, count), LOAD_LANES(dirs + count, i, base, count),
                        LOAD_LANES(dirs + 2 * count, i, base, count), &u, &v);
    const uintv k = 4 * env_texel(env_w, env_h, u, v);
    STORE_LANES(GATHER(texels, k), rgb_out, base, count);
    STORE_LANES(GATHER(texels, k + 1), rgb_out + count, base, count);
    STORE_LANES(GATHER(texels, k + 2), rgb_out + 2 * count, base, count);
}
