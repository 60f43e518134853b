/* Shading of direct environment lighting: for each shading point draw one (or,
 * for MIS, two) directions with the strategy chosen by -DSTRATEGY and return the
 * unoccluded estimator value  albedo f cos L / pdf  (times the MIS weight: the
 * power heuristic, or the balance heuristic with -DMIS_BALANCE=1) with its
 * direction; the host traces shadow rays for the non-zero values. numpy twin:
 * wavlight/strategies/reference.py (shade_reference).
 *
 * STRATEGY: 0 uniform, 1 cosine, 2 bsdf, 3 light, 4 mis, 5 wavelet. Single
 * strategies use u.xy and write slot 0 (slot 1 is zero); MIS draws the light
 * sample from u.xy into slot 0 and the bsdf sample from u.zw into slot 1; wavelet
 * does the same with the product sampler (product.h) in place of the light. The
 * light and product samples walk their trees here (warp.h tree_walk, product.h
 * product_walk): the program is built per light-tree depth (-DN_LEVELS) and, for
 * wavelet, per largest product depth and set of lobe shapes (-DPRODUCT_LEVELS,
 * -DLOBE_SHAPES). One launch per batch: as a separate kernel the light walk takes
 * 2.9 ms per 52 k points waited on alone against 1.7 ms back to back, and renders with
 * it measured 15-30% slower (benchmarks/render_bench.py, other changes to this kernel
 * included: light 1.42 s against 1.02-1.19 s, mis 1.75 s against 1.54 s).
 *
 * Two kernels share shade_lanes: shade_rays (the renderer's: camera rays straight
 * from the ray tracer, misses included, hit set-up done here) and shade (shading
 * points given directly; the tests'). Eight points per work-item in vector types
 * (simd.h; launch ceil(count / 8) work-items or more): measured 3.7x over one scalar
 * point per work-item on an AVX2 CPU. -DBSDF_KINDS: the material kinds present
 * (bsdf.h). With plastic among them each slot's albedo becomes its direction's colour
 * 1 - k + k albedo, k the share of f cos the albedo multiplies (bsdf.h material_eval_pdf;
 * 1 for the other kinds), and wavelet's product sample a mixture of two walks for plastic
 * (mixture_walk; -DPLASTIC_DIFFUSE_LEVELS).
 */
#ifndef BACKGROUND_MODE   /* what camera rays that miss see: 0 the nearest texel, 1 env_bilinear, 2 nothing */
#define BACKGROUND_MODE 0   /* (wavlight.envmap.BACKGROUND_MODE, wavlight.options.BACKGROUND) */
#endif
#include "warp.h"
#include "bsdf.h"
#include "product.h"
#include "rng.h"
#include "hit.h"
#include "texture.h"
#ifndef TEXTURES
#define TEXTURES 0   /* 1: some material has a base-colour texture (texture.h) */
#endif
#if STRATEGY >= 3 && !defined(N_LEVELS)
#error "shade.cl with the light or product sample is built with -DN_LEVELS (the light tree's depth)"
#endif

inline realv power_heuristic(const realv pa, const realv pb)
{
    const realv big = fmax(pa, pb);
    const realv a = pa / big, b = pb / big;
    return select((realv)0.0f, a * a / (a * a + b * b), big > 0.0f);
}

inline realv balance_heuristic(const realv pa, const realv pb)
{
    const realv big = fmax(pa, pb);
    const realv a = pa / big, b = pb / big;
    return select((realv)0.0f, a / (a + b), big > 0.0f);
}

/* The MIS weight of the two-sample strategies (numpy twin: Strategy.heuristic): the power
 * heuristic for mis and mis_comp (as pbrt-v4 and Mitsuba 3), the balance heuristic for
 * wavelet (wavlight.strategies.WaveletStrategy says why). */
#if defined(MIS_BALANCE) && MIS_BALANCE
#define mis_weight balance_heuristic
#else
#define mis_weight power_heuristic
#endif

/* Density per unit solid angle of the light tree at world directions (x, y, z) (MIS weight). */
inline realv light_pdf(__global const float *rot, __global const float *tree, const int levels,
                       const realv x, const realv y, const realv z)
{
    realv u, v;
    env_world_to_square(rot, x, y, z, &u, &v);
    return tree_pdf(tree, (uintv)0, levels, u, v) * env_square_to_solid_angle(x, z);
}

/* The tables every shading launch reads: materials, the wavelet lobes' data, the
 * environment and the light (or product) tree. */
#define SHADE_TABLE_ARGS __global const int *mat_kind, __global const float *mat_param,            \
                         __global const float *mat_albedo, __global const float *mat_table,        \
                         __global const float *mat_kappa,                                          \
                         __global const int *mat_levels,                                           \
                         __global const float *texels, const int env_w, const int env_h,           \
                         __global const float *rot, __global const float *tree
#define SHADE_TABLES mat_kind, mat_param, mat_albedo, mat_table, mat_kappa, mat_levels, texels, env_w, env_h, \
                     rot, tree

/* Resampled importance sampling from product candidates (wavelet with -DRIS_PRODUCT = M_p,
 * -DRIS_BSDF = M_b; numpy twin wavlight.strategies.ris_shade_reference, which says why it is
 * unbiased): candidate j from the uniforms frac(u.xy + j R2) (R2 in 24-bit fixed point:
 * exact float32 offsets), from the product walk for j < M_p, else from the BSDF; weight
 * w_j = f cos lum(L) / (M_p p_prod + M_b p_bsdf); two directions resampled with u.z and
 * u.z + 1/2, each with the scalar sum(w) / (2 lum(L(y))) (the kernel's value is scalar x
 * albedo x L(y)). With RIS_CONTROL_VARIATE (the default) the estimate also carries,
 * without a shadow ray, albedo U - value_a - value_b, U = sum_j w_j L(x_j) / lum(L(x_j))
 * the candidates' own MIS estimate of the unshadowed integral per channel: unbiased as
 * both U and value_a + value_b are, and exact U where both directions are visible.
 * The candidates are a loop, not unrolled: the walk inside it is. */
#ifdef RIS_PRODUCT
#ifndef RIS_CONTROL_VARIATE
#define RIS_CONTROL_VARIATE 1
#endif
#define RIS_CANDIDATES (RIS_PRODUCT + RIS_BSDF)
#ifndef RIS_SLOTS
#define RIS_SLOTS 2   /* directions resampled per shading sample, one shadow ray each: 2 or 4 */
#endif
#if RIS_SLOTS != 2 && RIS_SLOTS != 4
#error "RIS_SLOTS is 2 or 4"
#endif
#define R2_FIXED_X 12664746u
#define R2_FIXED_Y 9560334u

/* The luminance of the texel at (u, v) of the square (envmap.LUMINANCE), and its r, g, b. */
inline realv texel_luminance(__global const float *texels, const int env_w, const int env_h,
                             const realv u, const realv v, realv *r, realv *g, realv *b)
{
    realv unused;
    GATHER4(texels, 4 * env_texel(env_w, env_h, u, v), r, g, b, &unused);
    return 0.2126f * *r + 0.7152f * *g + 0.0722f * *b;
}

/* One slot's step of the inverse CDF over the candidates: the slot takes candidate (x, y, z)
 * of texel luminance l if it has found none yet and the running sum cum reaches its
 * threshold t with a positive weight (pos), or the candidate is the last one. */
inline void ris_pick(const realv cum, const realv t, const intv pos, const intv last, const realv x, const realv y,
                     const realv z, const realv l, const realv k, intv *found, realv *px, realv *py, realv *pz,
                     realv *pl, realv *pk)
{
    const intv take = !*found & ((pos & (cum >= t)) | last);
    *px = select(*px, x, take);
    *py = select(*py, y, take);
    *pz = select(*pz, z, take);
    *pl = select(*pl, l, take);
    *pk = select(*pk, k, take);
    *found |= take;
}

/* frac(u + offset) for an offset in [0, 1), as the twin computes it */
inline realv shifted_uniform(const realv u, const uint fixed_offset)
{
    const realv c = u + (float)(fixed_offset & 0xFFFFFFu) * 0x1p-24f;
    return select(c, c - 1.0f, c >= 1.0f);
}
#endif

/* Slots per shading sample: two (every strategy), or four for the resampling estimator
 * built with RIS_SLOTS 4. */
#if defined(RIS_PRODUCT) && RIS_SLOTS == 4
#define SLOTS 4
#else
#define SLOTS 2
#endif

/* Two directions (slot a, slot b; with SLOTS 4 also c and d) and their unoccluded estimates
 * (r, g, b) per lane, and the part of the estimate that needs no shadow ray (o: the
 * resampling estimator's control variate, zero otherwise). */
typedef struct {
    realv ax, ay, az, bx, by, bz;
    realv ra, ga, ba, rb, gb, bb;
#if SLOTS == 4
    realv c_x, c_y, c_z, d_x, d_y, d_z;
    realv rc, gc, bc, rd, gd, bd;
#endif
    realv o_r, o_g, o_b;
} Shaded;

/* The share of f cos the albedo multiplies (material_eval_pdf's fd / f; 1 where f is 0):
 * a slot's colour is 1 - k + k albedo (bsdfs.tint), the albedo for every kind but plastic. */
#define DIFFUSE_SHARE(fd, f) select((realv)1.0f, (fd) / (f), (f) > 0.0f)

#if STRATEGY == 5 && HAS_KIND(BSDF_PLASTIC)
#ifndef PLASTIC_DIFFUSE_LEVELS
#error "shade.cl for wavelet with plastic is built with -DPLASTIC_DIFFUSE_LEVELS (its diffuse lobe's depth)"
#endif
/* Plastic's product sample is a one-sample mixture of two walks: its specular lobe (the
 * material's own, a ggx lobe) with probability q = plastic_spec_prob, else its diffuse lobe
 * (the lambert shape at depth PLASTIC_DIFFUSE_LEVELS, the material's light tree); density
 * q p_spec + (1 - q) p_diffuse, exact as each walk's is (numpy twin:
 * WaveletStrategy.sample). Other kinds: q = 1, their own lobe. */
INLINE Lobe pick_lobe(const Lobe *a, const Lobe *b, const intv use_b)
{
    Lobe r;
    r.ax = select(a->ax, b->ax, use_b); r.ay = select(a->ay, b->ay, use_b); r.az = select(a->az, b->az, use_b);
    r.nx = select(a->nx, b->nx, use_b); r.ny = select(a->ny, b->ny, use_b); r.nz = select(a->nz, b->nz, use_b);
    r.wx = select(a->wx, b->wx, use_b); r.wy = select(a->wy, b->wy, use_b); r.wz = select(a->wz, b->wz, use_b);
    r.wn = select(a->wn, b->wn, use_b);
    r.inv_kappa = select(a->inv_kappa, b->inv_kappa, use_b);
    r.levels = select(a->levels, b->levels, use_b);
    r.shape = select(a->shape, b->shape, use_b);
    r.base = select(a->base, b->base, use_b);
    return r;
}

/* The mixture's walk from (u, v) (u chooses the lobe and is rescaled), its density on the square. */
INLINE realv mixture_walk(__global const float *tree, const Lobe *spec, const Lobe *diff, const realv q,
                          realv *u, realv *v)
{
    const intv use_d = !(*u < q);
    *u = select(*u / q, (*u - q) / (1.0f - q), use_d);
    const Lobe walk = pick_lobe(spec, diff, use_d), other = pick_lobe(spec, diff, !use_d);
    const realv p_walk = product_walk(tree, &walk, u, v);
    const realv p_other = product_pdf(tree, &other, *u, *v);
    return select(q * p_walk + (1.0f - q) * p_other, (1.0f - q) * p_walk + q * p_other, use_d);
}

INLINE realv mixture_pdf(__global const float *tree, const Lobe *spec, const Lobe *diff, const realv q,
                         const realv u, const realv v)
{
    return q * product_pdf(tree, spec, u, v) + (1.0f - q) * product_pdf(tree, diff, u, v);
}

#ifdef RIS_PRODUCT
/* The resampling estimator's candidates share each lobe's root children (root_children): the
 * lane's pick of the two, field by field. */
INLINE RootChildren pick_root(const RootChildren *a, const RootChildren *b, const intv use_b)
{
    RootChildren r;
#pragma unroll
    for (int c = 0; c < 4; ++c) {
        r.m[c] = select(a->m[c], b->m[c], use_b);
        r.i[c] = select(a->i[c], b->i[c], use_b);
#if CACHE_LEVEL_1
#pragma unroll
        for (int k = 0; k < 4; ++k) {
            r.m1[c][k] = select(a->m1[c][k], b->m1[c][k], use_b);
            r.i1[c][k] = select(a->i1[c][k], b->i1[c][k], use_b);
        }
#endif
    }
    return r;
}

/* mixture_walk and mixture_pdf with the two lobes' root children given (the same values). */
INLINE realv mixture_walk_from(__global const float *tree, const Lobe *spec, const Lobe *diff,
                               const RootChildren *root_s, const RootChildren *root_d, const realv q,
                               realv *u, realv *v)
{
    const intv use_d = !(*u < q);
    *u = select(*u / q, (*u - q) / (1.0f - q), use_d);
    const Lobe walk = pick_lobe(spec, diff, use_d), other = pick_lobe(spec, diff, !use_d);
    const RootChildren root_walk = pick_root(root_s, root_d, use_d);
    const realv p_walk = product_walk_from(tree, &walk, &root_walk, u, v);
    const RootChildren root_other = pick_root(root_s, root_d, !use_d);
    const realv p_other = product_pdf_from(tree, &other, &root_other, *u, *v);
    return select(q * p_walk + (1.0f - q) * p_other, (1.0f - q) * p_walk + q * p_other, use_d);
}

INLINE realv mixture_pdf_from(__global const float *tree, const Lobe *spec, const Lobe *diff,
                              const RootChildren *root_s, const RootChildren *root_d, const realv q,
                              const realv u, const realv v)
{
    return q * product_pdf_from(tree, spec, root_s, u, v) + (1.0f - q) * product_pdf_from(tree, diff, root_d, u, v);
}
#endif
#endif

/* Where a world direction (x, y, z) leaves below the geometric surface (g: the geometric normal
 * facing the viewer), f is 0: light does not reach through the surface because the shading
 * normal leans (docs/decisions/shading-normals.md). numpy twin: ShadingPoints.bsdf_eval_cos. */
#define ABOVE_GEOMETRIC(f, x, y, z) select((realv)0.0f, (f), (x) * gx + (y) * gy + (z) * gz > 0.0f)

/* Shade the lanes' points: world shading normal n (facing the viewer), world geometric normal g
 * (facing the viewer), world view direction e = wo, material mat, uniforms u0 .. u3; estimates
 * are zero where live is 0. */
inline Shaded shade_lanes(SHADE_TABLE_ARGS, const realv nx, const realv ny, const realv nz,
                          const realv gx, const realv gy, const realv gz,
                          const realv ex, const realv ey, const realv ez, const intv mat,
                          const realv tint_r, const realv tint_g, const realv tint_b,
                          const realv u0, const realv u1, const realv u2, const realv u3, const intv live)
{
#if STRATEGY == 3 || STRATEGY == 4
    /* the light sample first, while little else is live (the walk is a chain of gathers) */
    realv gu = u0, gv = u1;
    const realv square_pdf = tree_walk(tree, (uintv)0, &gu, &gv);
#endif
    realv sx, sy, sz, tx, ty, tz;
    make_frame(nx, ny, nz, &sx, &sy, &sz, &tx, &ty, &tz);
    const realv ox = ex * sx + ey * sy + ez * sz, oy = ex * tx + ey * ty + ez * tz, oz = ex * nx + ey * ny + ez * nz;
    const intv kind = GATHER_INT(mat_kind, mat);
    const realv param = GATHER(mat_param, mat);
    const uintv row = as_uintv(mat) * (uint)PLASTIC_STRIDE;   /* the plastic table's row */
    realv ka = 1.0f, kb = 1.0f;   /* each slot's share of f cos that the albedo multiplies */
#if SLOTS == 4
    realv kc = 1.0f, kd = 1.0f;
#endif
    /* slot a (and b): world direction, scalar f / pdf (x MIS weight) */
    realv ax = 0.0f, ay = 0.0f, az = 0.0f, sa = 0.0f;
    realv bx = 0.0f, by = 0.0f, bz = 0.0f, sb = 0.0f;
#if SLOTS == 4
    realv c_x = 0.0f, c_y = 0.0f, c_z = 0.0f, sc = 0.0f, d_x = 0.0f, d_y = 0.0f, d_z = 0.0f, sd = 0.0f;
#endif
    realv cv_r = 0.0f, cv_g = 0.0f, cv_b = 0.0f;   /* U, the control variate (RIS) */
    intv ris_finite = -1;                          /* both slots' scalars finite (RIS) */
#if STRATEGY == 5
    const intv lobe_code = GATHER_INT(mat_levels, mat);
    const Lobe lobe = make_lobe(rot, nx, ny, nz, ex, ey, ez, GATHER(mat_kappa, mat), lobe_code);
#if HAS_KIND(BSDF_PLASTIC)
    const Lobe lobe_d = make_lobe(rot, nx, ny, nz, ex, ey, ez, (realv)0.0f,
                                  (lobe_code & ~0xffff) | (LOBE_LAMBERT << 8) | PLASTIC_DIFFUSE_LEVELS);
    const realv lobe_q = select((realv)1.0f, plastic_spec_prob(mat_table, row, oz), kind == BSDF_PLASTIC);
#endif
#endif
#if STRATEGY == 5 && defined(RIS_PRODUCT)
    {   /* wavelet with candidates: resampled from product (and BSDF) candidates */
        /* each candidate's direction, weight and texel luminance (the target's, kept for the
         * chosen ones' estimates) */
        realv cx[RIS_CANDIDATES], cy[RIS_CANDIDATES], cz[RIS_CANDIDATES], cw[RIS_CANDIDATES], cl[RIS_CANDIDATES];
        realv ck[RIS_CANDIDATES];   /* each candidate's share of f cos the albedo multiplies */
        realv total = 0.0f;
        const RootChildren root = root_children(tree, &lobe);   /* shared by every candidate's walk */
#if HAS_KIND(BSDF_PLASTIC)
        const RootChildren root_d = root_children(tree, &lobe_d);   /* plastic's diffuse lobe's */
        realv alb_r, alb_g, alb_b, alb_unused;   /* the control variate's colours (plastic) */
        GATHER4(mat_albedo, as_uintv(4 * mat), &alb_r, &alb_g, &alb_b, &alb_unused);
#endif
#pragma unroll 1
        for (int j = 0; j < RIS_CANDIDATES; ++j) {
            const realv cu = shifted_uniform(u0, (uint)j * R2_FIXED_X), cv = shifted_uniform(u1, (uint)j * R2_FIXED_Y);
            realv dx, dy, dz, p_prod, f, fd, p_bsdf, lx, ly, lz, su, sv;   /* (su, sv): d on the square */
            if (j < RIS_PRODUCT) {
                realv gu = cu, gv = cv;
#if HAS_KIND(BSDF_PLASTIC)
                const realv square_pdf = mixture_walk_from(tree, &lobe, &lobe_d, &root, &root_d, lobe_q, &gu, &gv);
#else
                const realv square_pdf = product_walk_from(tree, &lobe, &root, &gu, &gv);
#endif
                env_square_to_world(rot, gu, gv, &dx, &dy, &dz);
                p_prod = square_pdf * env_square_to_solid_angle(dx, dz);
                lx = dx * sx + dy * sy + dz * sz;
                ly = dx * tx + dy * ty + dz * tz;
                lz = dx * nx + dy * ny + dz * nz;
                material_eval_pdf(kind, param, mat_table, row, lx, ly, lz, ox, oy, oz, &f, &fd, &p_bsdf);
                env_world_to_square(rot, dx, dy, dz, &su, &sv);   /* the texel of d, as for every direction */
            } else {
                material_sample(kind, param, mat_table, row, ox, oy, oz, cu, cv, &lx, &ly, &lz);
                material_eval_pdf(kind, param, mat_table, row, lx, ly, lz, ox, oy, oz, &f, &fd, &p_bsdf);
                dx = lx * sx + ly * tx + lz * nx;
                dy = lx * sy + ly * ty + lz * ny;
                dz = lx * sz + ly * tz + lz * nz;
                env_world_to_square(rot, dx, dy, dz, &su, &sv);
#if HAS_KIND(BSDF_PLASTIC)
                p_prod = mixture_pdf_from(tree, &lobe, &lobe_d, &root, &root_d, lobe_q, su, sv) *
                         env_square_to_solid_angle(dx, dz);
#else
                p_prod = product_pdf_from(tree, &lobe, &root, su, sv) * env_square_to_solid_angle(dx, dz);
#endif
            }
            f = ABOVE_GEOMETRIC(f, dx, dy, dz);
            ck[j] = DIFFUSE_SHARE(fd, f);
            realv tr, tg, tb;
            cl[j] = texel_luminance(texels, env_w, env_h, su, sv, &tr, &tg, &tb);
            const realv target = f * cl[j];
            const realv denom = (float)RIS_PRODUCT * p_prod + (float)RIS_BSDF * p_bsdf;
            const realv w = target / denom;
            cw[j] = select((realv)0.0f, w, (denom > 0.0f) & (target > 0.0f) & isfinite(w));
            cx[j] = dx; cy[j] = dy; cz[j] = dz;
            total += cw[j];
            if (RIS_CONTROL_VARIATE) {   /* w_j L(x_j) / lum(L(x_j)): w_j > 0 implies lum > 0 */
                const realv k = select((realv)0.0f, cw[j] / cl[j], cw[j] > 0.0f);
#if HAS_KIND(BSDF_PLASTIC)   /* times the candidate's tint (the albedo but for plastic), here */
                cv_r += k * tr * (1.0f - ck[j] + ck[j] * alb_r);
                cv_g += k * tg * (1.0f - ck[j] + ck[j] * alb_g);
                cv_b += k * tb * (1.0f - ck[j] + ck[j] * alb_b);
#else
                cv_r += k * tr; cv_g += k * tg; cv_b += k * tb;
#endif
            }
        }
        /* each slot takes the first candidate of positive weight whose running sum reaches
         * u total (the last one if rounding leaves none) */
        const realv ta = u2 * total, tb = select(u2 + 0.5f, u2 - 0.5f, u2 >= 0.5f) * total;
        realv cum = 0.0f, la = 0.0f, lb = 0.0f;
        intv found_a = 0, found_b = 0;
#if SLOTS == 4   /* slots c and d at u.z + 1/4 and u.z + 3/4 */
        const realv tc = select(u2 + 0.25f, u2 - 0.75f, u2 >= 0.75f) * total;
        const realv td = select(u2 + 0.75f, u2 - 0.25f, u2 >= 0.25f) * total;
        realv lc = 0.0f, ld = 0.0f;
        intv found_c = 0, found_d = 0;
#endif
#pragma unroll 1
        for (int j = 0; j < RIS_CANDIDATES; ++j) {
            cum += cw[j];
            const intv last = (intv)(j == RIS_CANDIDATES - 1 ? -1 : 0);
            const intv pos = cw[j] > 0.0f;   /* (u.z = 0 must not pick a zero-weight candidate) */
            ris_pick(cum, ta, pos, last, cx[j], cy[j], cz[j], cl[j], ck[j], &found_a, &ax, &ay, &az, &la, &ka);
            ris_pick(cum, tb, pos, last, cx[j], cy[j], cz[j], cl[j], ck[j], &found_b, &bx, &by, &bz, &lb, &kb);
#if SLOTS == 4
            ris_pick(cum, tc, pos, last, cx[j], cy[j], cz[j], cl[j], ck[j], &found_c, &c_x, &c_y, &c_z, &lc, &kc);
            ris_pick(cum, td, pos, last, cx[j], cy[j], cz[j], cl[j], ck[j], &found_d, &d_x, &d_y, &d_z, &ld, &kd);
#endif
        }
        const float share = 1.0f / (float)SLOTS;   /* each slot's part of sum(w) */
        sa = select((realv)0.0f, share * total / la, (total > 0.0f) & (la > 0.0f));
        sb = select((realv)0.0f, share * total / lb, (total > 0.0f) & (lb > 0.0f));
        ris_finite = isfinite(sa) & isfinite(sb);
#if SLOTS == 4
        sc = select((realv)0.0f, share * total / lc, (total > 0.0f) & (lc > 0.0f));
        sd = select((realv)0.0f, share * total / ld, (total > 0.0f) & (ld > 0.0f));
        ris_finite &= isfinite(sc) & isfinite(sd);
#endif
    }
#elif STRATEGY >= 3
    {   /* the light (light, mis) or product (wavelet) sample from u.xy */
#if STRATEGY == 5
        realv gu = u0, gv = u1;
#if HAS_KIND(BSDF_PLASTIC)
        const realv square_pdf = mixture_walk(tree, &lobe, &lobe_d, lobe_q, &gu, &gv);
#else
        const realv square_pdf = product_walk(tree, &lobe, &gu, &gv);
#endif
#endif
        env_square_to_world(rot, gu, gv, &ax, &ay, &az);
        const realv pdf = square_pdf * env_square_to_solid_angle(ax, az);
        const realv lx = ax * sx + ay * sy + az * sz, ly = ax * tx + ay * ty + az * tz;
        const realv lz = ax * nx + ay * ny + az * nz;
        realv f, fd, pdf_bsdf;
        material_eval_pdf(kind, param, mat_table, row, lx, ly, lz, ox, oy, oz, &f, &fd, &pdf_bsdf);
        f = ABOVE_GEOMETRIC(f, ax, ay, az);
        ka = DIFFUSE_SHARE(fd, f);
#if STRATEGY == 3
        sa = select((realv)0.0f, f / pdf, pdf > 0.0f);
#else
        /* the other pdf matters only where the estimate can be non-zero */
        sa = select((realv)0.0f, f / pdf * mis_weight(pdf, pdf_bsdf), (pdf > 0.0f) & (f > 0.0f));
#endif
    }
#endif
#if STRATEGY >= 4 && !(STRATEGY == 5 && defined(RIS_PRODUCT))
    {   /* the bsdf sample from u.zw, weighted against the guide's pdf */
        realv lx, ly, lz, f, fd, pdf;
        material_sample(kind, param, mat_table, row, ox, oy, oz, u2, u3, &lx, &ly, &lz);
        material_eval_pdf(kind, param, mat_table, row, lx, ly, lz, ox, oy, oz, &f, &fd, &pdf);
        kb = DIFFUSE_SHARE(fd, f);
        bx = lx * sx + ly * tx + lz * nx;
        by = lx * sy + ly * ty + lz * ny;
        bz = lx * sz + ly * tz + lz * nz;
        f = ABOVE_GEOMETRIC(f, bx, by, bz);
#if STRATEGY == 5
        realv gu, gv;
        env_world_to_square(rot, bx, by, bz, &gu, &gv);
#if HAS_KIND(BSDF_PLASTIC)
        const realv other = mixture_pdf(tree, &lobe, &lobe_d, lobe_q, gu, gv) * env_square_to_solid_angle(bx, bz);
#else
        const realv other = product_pdf(tree, &lobe, gu, gv) * env_square_to_solid_angle(bx, bz);
#endif
#else
        const realv other = light_pdf(rot, tree, N_LEVELS, bx, by, bz);
#endif
        sb = select((realv)0.0f, f / pdf * mis_weight(pdf, other), (pdf > 0.0f) & (f > 0.0f));
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
        cosine_sample(u0, u1, &lx, &ly, &lz);
        pdf = fmax(lz, 0.0f) * INV_PI_F;
#else
        material_sample(kind, param, mat_table, row, ox, oy, oz, u0, u1, &lx, &ly, &lz);
#endif
        realv f, fd, pdf_bsdf;
        material_eval_pdf(kind, param, mat_table, row, lx, ly, lz, ox, oy, oz, &f, &fd, &pdf_bsdf);
        ka = DIFFUSE_SHARE(fd, f);
#if STRATEGY == 2
        pdf = pdf_bsdf;
#endif
        ax = lx * sx + ly * tx + lz * nx;
        ay = lx * sy + ly * ty + lz * ny;
        az = lx * sz + ly * tz + lz * nz;
        f = ABOVE_GEOMETRIC(f, ax, ay, az);
        sa = select((realv)0.0f, f / pdf, pdf > 0.0f);
    }
#endif
    /* estimates: albedo x scalar x environment radiance (zero where the scalar is not a
     * positive finite number, and in the lanes that are not live) */
    sa = select((realv)0.0f, sa, live & (sa > 0.0f) & isfinite(sa));
    sb = select((realv)0.0f, sb, live & (sb > 0.0f) & isfinite(sb));
    realv ua, va, ub, vb;
    env_world_to_square(rot, ax, ay, az, &ua, &va);
    env_world_to_square(rot, bx, by, bz, &ub, &vb);
    const uintv texel_a = 4 * env_texel(env_w, env_h, ua, va), texel_b = 4 * env_texel(env_w, env_h, ub, vb);
    const uintv am = as_uintv(4 * mat);
    realv ar, ag, ab, unused, ta_r, ta_g, ta_b, tb_r, tb_g, tb_b;
    GATHER4(mat_albedo, am, &ar, &ag, &ab, &unused);
    ar *= tint_r;   /* the albedo times the texture's lookup at the hit (1 without one) */
    ag *= tint_g;
    ab *= tint_b;
    GATHER4(texels, texel_a, &ta_r, &ta_g, &ta_b, &unused);
    GATHER4(texels, texel_b, &tb_r, &tb_g, &tb_b, &unused);
    Shaded s;
    s.ax = ax; s.ay = ay; s.az = az; s.bx = bx; s.by = by; s.bz = bz;
#if HAS_KIND(BSDF_PLASTIC)   /* each slot's colour: 1 - k + k albedo (bsdfs.tint) */
#define TINT(k, a) (1.0f - (k) + (k) * (a))
#else
#define TINT(k, a) (a)
#endif
    s.ra = sa * TINT(ka, ar) * ta_r;
    s.ga = sa * TINT(ka, ag) * ta_g;
    s.ba = sa * TINT(ka, ab) * ta_b;
    s.rb = sb * TINT(kb, ar) * tb_r;
    s.gb = sb * TINT(kb, ag) * tb_g;
    s.bb = sb * TINT(kb, ab) * tb_b;
#if SLOTS == 4
    {
        sc = select((realv)0.0f, sc, live & (sc > 0.0f) & isfinite(sc));
        sd = select((realv)0.0f, sd, live & (sd > 0.0f) & isfinite(sd));
        realv uc, vc, ud, vd, tc_r, tc_g, tc_b, td_r, td_g, td_b;
        env_world_to_square(rot, c_x, c_y, c_z, &uc, &vc);
        env_world_to_square(rot, d_x, d_y, d_z, &ud, &vd);
        GATHER4(texels, 4 * env_texel(env_w, env_h, uc, vc), &tc_r, &tc_g, &tc_b, &unused);
        GATHER4(texels, 4 * env_texel(env_w, env_h, ud, vd), &td_r, &td_g, &td_b, &unused);
        s.c_x = c_x; s.c_y = c_y; s.c_z = c_z; s.d_x = d_x; s.d_y = d_y; s.d_z = d_z;
        s.rc = sc * TINT(kc, ar) * tc_r; s.gc = sc * TINT(kc, ag) * tc_g; s.bc = sc * TINT(kc, ab) * tc_b;
        s.rd = sd * TINT(kd, ar) * td_r; s.gd = sd * TINT(kd, ag) * td_g; s.bd = sd * TINT(kd, ab) * td_b;
    }
#endif
#if STRATEGY == 5 && defined(RIS_PRODUCT)
    if (RIS_CONTROL_VARIATE) {
        /* albedo U - value_a - value_b; where it or a slot's scalar is not finite (an
         * overflow), the whole sample is 0, offset and values together (numpy twin: the same) */
#if HAS_KIND(BSDF_PLASTIC)   /* U carries each candidate's colour already */
#define U_TIMES_ALBEDO(a, u) (u)
#else   /* (in the expression: a product kept apart from it rounds otherwise, without the fma) */
#define U_TIMES_ALBEDO(a, u) (a) * (u)
#endif
#if SLOTS == 4
        const realv o_r = U_TIMES_ALBEDO(ar, cv_r) - s.ra - s.rb - s.rc - s.rd;
        const realv o_g = U_TIMES_ALBEDO(ag, cv_g) - s.ga - s.gb - s.gc - s.gd;
        const realv o_b = U_TIMES_ALBEDO(ab, cv_b) - s.ba - s.bb - s.bc - s.bd;
#else
        const realv o_r = U_TIMES_ALBEDO(ar, cv_r) - s.ra - s.rb, o_g = U_TIMES_ALBEDO(ag, cv_g) - s.ga - s.gb;
        const realv o_b = U_TIMES_ALBEDO(ab, cv_b) - s.ba - s.bb;
#endif
        const intv ok = live & ris_finite & isfinite(o_r) & isfinite(o_g) & isfinite(o_b);
        s.o_r = select((realv)0.0f, o_r, ok);
        s.o_g = select((realv)0.0f, o_g, ok);
        s.o_b = select((realv)0.0f, o_b, ok);
        s.ra = select((realv)0.0f, s.ra, ok); s.ga = select((realv)0.0f, s.ga, ok); s.ba = select((realv)0.0f, s.ba, ok);
        s.rb = select((realv)0.0f, s.rb, ok); s.gb = select((realv)0.0f, s.gb, ok); s.bb = select((realv)0.0f, s.bb, ok);
#if SLOTS == 4
        s.rc = select((realv)0.0f, s.rc, ok); s.gc = select((realv)0.0f, s.gc, ok); s.bc = select((realv)0.0f, s.bc, ok);
        s.rd = select((realv)0.0f, s.rd, ok); s.gd = select((realv)0.0f, s.gd, ok); s.bd = select((realv)0.0f, s.bd, ok);
#endif
        return s;
    }
#endif
    s.o_r = s.o_g = s.o_b = 0.0f;
    return s;
}

/* The estimates as planes of count floats: slot a r, g, b, then slot b r, g, b (then c, d). */
inline void store_values(const Shaded *s, __global float *value_out, const uint base, const uint count)
{
    STORE_LANES(s->ra, value_out, base, count);
    STORE_LANES(s->ga, value_out + count, base, count);
    STORE_LANES(s->ba, value_out + 2 * count, base, count);
    STORE_LANES(s->rb, value_out + 3 * count, base, count);
    STORE_LANES(s->gb, value_out + 4 * count, base, count);
    STORE_LANES(s->bb, value_out + 5 * count, base, count);
#if SLOTS == 4
    STORE_LANES(s->rc, value_out + 6 * count, base, count);
    STORE_LANES(s->gc, value_out + 7 * count, base, count);
    STORE_LANES(s->bc, value_out + 8 * count, base, count);
    STORE_LANES(s->rd, value_out + 9 * count, base, count);
    STORE_LANES(s->gd, value_out + 10 * count, base, count);
    STORE_LANES(s->bd, value_out + 11 * count, base, count);
#endif
}

/* Shading points given directly: shading normals, geometric normals and view directions as
 * rows of 3 floats, material ids, with has_tint rows of 3 floats multiplying each point's
 * albedo (a texture's value there), u rows of 4; wi_out and value_out as planes (slot,
 * component, point), offset_out (the part without a shadow ray) as planes r, g, b. The tests'
 * entry point; the renderer uses shade_rays. */
__kernel void shade(__global const float *normal, __global const float *geometric, __global const float *wo_world,
                    __global const int *material, __global const float *tint, const int has_tint,
                    __global const float *u_in, const uint count,
                    SHADE_TABLE_ARGS, __global float *wi_out, __global float *value_out,
                    __global float *offset_out)
{
    const uint base = LANE_BASE();
    if (base >= count) return;
    tree += TREE_ORIGIN;   /* the light tree's node 0 (common.h) */
    const uintv i = LANE_INDEX(count);
    realv nx, ny, nz, gx, gy, gz, ex, ey, ez, u0, u1, u2, u3;
    GATHER3(normal, 3 * i, &nx, &ny, &nz);
    GATHER3(geometric, 3 * i, &gx, &gy, &gz);
    GATHER3(wo_world, 3 * i, &ex, &ey, &ez);
    GATHER4(u_in, 4 * i, &u0, &u1, &u2, &u3);
    realv tr = 1.0f, tg = 1.0f, tb = 1.0f;
    if (has_tint) GATHER3(tint, 3 * i, &tr, &tg, &tb);
    const Shaded s = shade_lanes(SHADE_TABLES, nx, ny, nz, gx, gy, gz, ex, ey, ez, GATHER_INT(material, i),
                                 tr, tg, tb, u0, u1, u2, u3, (intv)-1);
    STORE_LANES(s.ax, wi_out, base, count);
    STORE_LANES(s.ay, wi_out + count, base, count);
    STORE_LANES(s.az, wi_out + 2 * count, base, count);
    STORE_LANES(s.bx, wi_out + 3 * count, base, count);
    STORE_LANES(s.by, wi_out + 4 * count, base, count);
    STORE_LANES(s.bz, wi_out + 5 * count, base, count);
#if SLOTS == 4
    STORE_LANES(s.c_x, wi_out + 6 * count, base, count);
    STORE_LANES(s.c_y, wi_out + 7 * count, base, count);
    STORE_LANES(s.c_z, wi_out + 8 * count, base, count);
    STORE_LANES(s.d_x, wi_out + 9 * count, base, count);
    STORE_LANES(s.d_y, wi_out + 10 * count, base, count);
    STORE_LANES(s.d_z, wi_out + 11 * count, base, count);
#endif
    store_values(&s, value_out, base, count);
    STORE_LANES(s.o_r, offset_out, base, count);
    STORE_LANES(s.o_g, offset_out + count, base, count);
    STORE_LANES(s.o_b, offset_out + 2 * count, base, count);
}

/* (x, y, z) of the lanes below count into rows out[(point) * stride + offset + 0..2]. */
inline void store_rows3(const realv x, const realv y, const realv z, __global float *out, const uint stride,
                        const uint offset, const uint base, const uint count)
{
    for (uint k = 0; k < LANES && base + k < count; ++k) {
        __global float *row = out + (base + k) * stride + offset;
        row[0] = x[k];
        row[1] = y[k];
        row[2] = z[k];
    }
}

/* The renderer's entry point: camera rays straight from the ray tracer. Per ray:
 * direction (rows of 3 floats) from the eye, the hit triangle prim (-1: a miss) at
 * distance tfar, four uniforms: with draw_u, Philox stream RNG_SHADING of tile
 * rng_tile at sample index rng_first + ray (rng.h; the independent sampler), and with
 * rng_k > 0 (the stratified sampler; rays r = p k + j, k = rng_k samples per pixel) each
 * pair moved into its cell (stratify_pair, keyed by words 1 and 2 of stream RNG_STRATA
 * at index rng_first + p, as the camera kernel's jitter by word 0); else u_in (rows of 4). A miss sees the environment (direct_out,
 * its nearest texel, with BACKGROUND_MODE 1 env_bilinear's filtered value, with 2 zero (the background hidden);
 * 3 planes r, g, b; for hits the estimate's part without a shadow ray, Shaded's o) and has
 * zero estimates. A hit takes its face
 * normal, flipped to face the viewer (two-sided shading), with smooth != 0 its shading normal
 * (hit.h shading_normal, from embree's barycentrics bary (rows of 2 floats u, v), the faces'
 * corner rows and the normals), its face's material (with -DTEXTURES=1 its albedo times its
 * texture at the hit: texture.h, the face's texture coordinates face_uv interpolated at bary) and
 * shade_lanes' directions and estimates; origin_out (rows of 3) is the hit point p
 * moved max(OFFSET_RELATIVE |p|, face_normal's 4th column, eye_offset) along the face normal
 * (wavlight/raytrace.py: the offset floors of the face and of the eye), where its
 * shadow rays start; wi_out holds rows of
 * 3 SLOTS floats (slot a x y z, slot b x y z, and c, d), value_out planes as in shade. Vectors of
 * eight rays of one pixel mostly agree on hit or miss: each part runs only when some
 * lane needs it. numpy twin: wavlight.shading.shade_rays_reference. */
__kernel void shade_rays(__global const float *dirs, __global const int *prim, __global const float *tfar,
                         const float eye_x, const float eye_y, const float eye_z, const float eye_offset,
                         __global const float *face_normal, __global const int *face_material,
                         __global const float *bary, __global const int *corner, __global const float *normals,
                         const int smooth, __global const float *face_uv,
                         __global const int *mat_texture, __global const float *tex_atlas,
                         __global const int *tex_table,
                         __global const float *u_in, const int draw_u, const uint rng_tile,
                         const uint rng_first, const uint rng_k0, const uint rng_k1, const uint rng_k,
                         const uint count,
                         SHADE_TABLE_ARGS, __global float *origin_out, __global float *wi_out, __global float *value_out,
                         __global float *direct_out)
{
    const uint base = LANE_BASE();
    if (base >= count) return;
    tree += TREE_ORIGIN;   /* the light tree's node 0 (common.h) */
    const uintv i = LANE_INDEX(count);
    const intv face = GATHER_INT(prim, i);
    const intv hit = face >= 0;
    realv dx, dy, dz;
    GATHER3(dirs, 3 * i, &dx, &dy, &dz);
    realv er = 0.0f, eg = 0.0f, eb = 0.0f;
#if BACKGROUND_MODE != 2   /* (2: the background hidden, misses add 0) */
    if (!all(hit)) {
        realv u, v;
        env_world_to_square(rot, dx, dy, dz, &u, &v);
        realv r, g, b;
#if BACKGROUND_MODE == 1
        env_bilinear(texels, env_w, env_h, u, v, &r, &g, &b);
#else
        realv unused;
        GATHER4(texels, 4 * env_texel(env_w, env_h, u, v), &r, &g, &b, &unused);
#endif
        er = select(r, 0.0f, hit);
        eg = select(g, 0.0f, hit);
        eb = select(b, 0.0f, hit);
    }
#endif
    STORE_LANES(er, direct_out, base, count);
    STORE_LANES(eg, direct_out + count, base, count);
    STORE_LANES(eb, direct_out + 2 * count, base, count);
    Shaded s;
    if (any(hit)) {
        const uintv f = as_uintv(max(face, 0));
        realv gx, gy, gz, px, py, pz, eps;
        hit_point(dx, dy, dz, GATHER(tfar, i), f, face_normal, eye_x, eye_y, eye_z, eye_offset,
                  &gx, &gy, &gz, &px, &py, &pz, &eps);
        store_rows3(px + gx * eps, py + gy * eps, pz + gz * eps, origin_out, 3, 0, base, count);
        realv nx = gx, ny = gy, nz = gz;
        if (smooth) {
            realv bu, bv;
            GATHER2(bary, 2 * i, &bu, &bv);
            shading_normal(dx, dy, dz, bu, bv, f, corner, normals, gx, gy, gz, &nx, &ny, &nz);
        }
        realv u0, u1, u2, u3;
        if (draw_u) {
            rng_uniforms(rng_first + LANE_IDS + base, rng_tile, RNG_SHADING, rng_k0, rng_k1, &u0, &u1, &u2, &u3);
            if (rng_k) {   /* the stratified sampler: ray r is sample r % k of pixel r / k */
                uintv j, unused, key_guide, key_bsdf, unused3;
                const uintv pixel = div_small(LANE_IDS + base, rng_k, &j);   /* (count < 2^22: the host checks) */
                philox4x32_10(rng_first + pixel, (uintv)rng_tile, (uintv)RNG_STRATA, (uintv)0u, rng_k0, rng_k1,
                              &unused, &key_guide, &key_bsdf, &unused3);
                stratify_pair(&u0, &u1, j, rng_k, key_guide);
                stratify_pair(&u2, &u3, j, rng_k, key_bsdf);
            }
        } else {
            GATHER4(u_in, 4 * i, &u0, &u1, &u2, &u3);
        }
        const intv mat = GATHER_INT(face_material, f);
        realv tr = 1.0f, tg = 1.0f, tb = 1.0f;
#if TEXTURES
        texture_at_hit(face_uv, tex_atlas, tex_table, mat_texture, bary, i, f, mat, &tr, &tg, &tb);
#endif
        s = shade_lanes(SHADE_TABLES, nx, ny, nz, gx, gy, gz, -dx, -dy, -dz, mat, tr, tg, tb, u0, u1, u2, u3,
                        hit);
        STORE_LANES(er + s.o_r, direct_out, base, count);   /* (er: 0 for hits) */
        STORE_LANES(eg + s.o_g, direct_out + count, base, count);
        STORE_LANES(eb + s.o_b, direct_out + 2 * count, base, count);
    } else {
        s.ax = s.ay = s.az = s.bx = s.by = s.bz = 0.0f;
        s.ra = s.ga = s.ba = s.rb = s.gb = s.bb = 0.0f;
#if SLOTS == 4
        s.c_x = s.c_y = s.c_z = s.d_x = s.d_y = s.d_z = 0.0f;
        s.rc = s.gc = s.bc = s.rd = s.gd = s.bd = 0.0f;
#endif
    }
    store_rows3(s.ax, s.ay, s.az, wi_out, 3 * SLOTS, 0, base, count);
    store_rows3(s.bx, s.by, s.bz, wi_out, 3 * SLOTS, 3, base, count);
#if SLOTS == 4
    store_rows3(s.c_x, s.c_y, s.c_z, wi_out, 12, 6, base, count);
    store_rows3(s.d_x, s.d_y, s.d_z, wi_out, 12, 9, base, count);
#endif
    store_values(&s, value_out, base, count);
}
