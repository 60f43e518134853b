/* Wavelet product importance sampling, top-down (Chen & Gao sec. 4.3-4.4; Clarberg
 * et al. 2005). numpy twin: wavlight/strategies/product.py.
 *
 * The importance of a node s at level l is its product scaling coefficient
 * approximated by the first term of eq. 25, F^0_s ~ 2^l G^0_s H^0_s: the
 * environment's exact box mass (the light tree; for lambert lobes the MIS-compensated
 * one, max(L - mean, 0), see PRODUCT_TREES) times the BRDF x cosine of the
 * shading point evaluated at the node's centre direction d_s with a lobe
 * pre-filtered to the node's size (x = 1 - d_s . axis, k_l = 1 / (1/kappa + r_l^2),
 * r_l = 0.35 pi / 2^l the lobe blur (phong: 0.2 pi / 2^l), h_l = 0.75 pi / 2^l the
 * horizon blur):
 *     lambert  I = mass clamp(d_s . n + h_l, 0, 1)
 *     phong    I = mass (1 + k_l x / 8)^-8 clamp(d_s . n + h_l, 0, 1)   (~ exp(-k_l x))
 *     ggx      I = mass (1 + k_l x)^-2 clamp(d_s . n / h_l + 1, 0, 1)         (alpha <= 0.1)
 *     ggx      I = mass pi D_{alpha_l}(h_s) clamp(d_s . n / h_l + 1, 0, 1),     (alpha > 0.1)
 *              h_s = normalize(d_s + wo), alpha_l^2 = alpha^2 + r_l^2 / 2
 * axis = mirror direction (phong, ggx) or normal (lambert). For wide ggx lobes the
 * microfacet distribution at the true half vector keeps the lobe's real shape
 * (stretched and off-specular at grazing views), which the isotropic profile misses:
 * image relMSE over mis at 16 spp, ggx 0.2 spheres, 0.83 / 0.21 / 0.27 against
 * 1.02 / 0.25 / 0.37 under rooitou / st_fagans / potsdamer. For narrow lobes the
 * isotropic profile measured better (ggx 0.05 under st_fagans: 0.19 against 0.27),
 * hence the switch (wavlight.product.lobe_shape). Only the
 * four children of each visited node are evaluated (their sixteen children at the
 * LOOKAHEAD_LEVELS coarsest levels, see below): O(levels) per sample, no
 * per-point tree. Node centre directions are carried down the walk as the sines and
 * cosines of their angles, the children's from the parent's by the angle-sum formulas
 * (NodeAngles; numpy twin wavlight.product.centre_angles): no table and no gathers
 * (a table of the angles, read per lane, measured 11-35% slower at 1024^2). The lobe
 * is turned into the map frame once per point (make_lobe). Below the product depth P
 * the BRDF is taken as constant and the walk continues in the light tree (choose_child
 * on the masses). The pdf is exact:
 *     pdf_square = prod_l I(child_l) / sum I(siblings_l) * mass(leaf) / mass(node_P) * 4^n
 * and product_pdf recomputes it for any direction. Where all four children have
 * zero importance the walk falls back to their light masses (same rule in both).
 */
#ifndef WAVLIGHT_PRODUCT_H
#define WAVLIGHT_PRODUCT_H
#include "warp.h"
#include "sphere.h"

/* A level-l node spans pi / 2^l in theta (2 pi sin(theta) / 2^l in phi). The lobe is
 * widened by LOBE_BLUR_F / 2^l, phong's by PHONG_BLUR_F / 2^l (less than the node's
 * half size: wider lobes waste samples on bright nodes outside the lobe), the horizon
 * softened by HORIZON_BLUR_F / 2^l (3/4 of the node's theta extent: a node whose
 * centre lies further below the horizon gets no product samples; the BSDF sample
 * covers it). Measured per shading point (relative variance of wavelet over mis on
 * the sphere's visible points, 128 points x 512 samples): phong with 0.2 pi instead of
 * 0.35 pi, n = 200: 0.55 / 0.050 / 0.27 -> 0.42 / 0.043 / 0.20 under rooitou /
 * st_fagans / potsdamer, and 15-40% lower on four of five other maps and at n = 50
 * and 1000; 0.1 pi and 0.5 pi were worse. ggx measured best at 0.35 pi (0.2 pi: up
 * to 15% worse), and the horizon blur (0.4 pi to 2 pi) made no difference. */
#define LOBE_BLUR_F (0.35f * PI_F)
#define PHONG_BLUR_F (0.2f * PI_F)
#define HORIZON_BLUR_F (0.75f * PI_F)

#define LOBE_LAMBERT 0
#define LOBE_PHONG 1
#define LOBE_GGX 2        /* narrow ggx: isotropic profile about the mirror direction */
#define LOBE_GGX_HALF 3   /* wide ggx (alpha > 0.1): D at the true half vector */

#ifndef LOBE_SHAPES   /* bit mask of the shapes a program evaluates (the host sets it from the materials) */
#define LOBE_SHAPES 15
#endif
#define HAS_SHAPE(s) (LOBE_SHAPES & (1 << (s)))

/* Eight shading points' lobes (simd.h lanes). */
typedef struct {
    realv ax, ay, az;   /* lobe axis, in the map frame */
    realv nx, ny, nz;   /* shading normal, in the map frame */
    realv wx, wy, wz;   /* direction to the viewer, in the map frame (ggx: the half vector) */
    realv wn;           /* wo . n */
    realv inv_kappa;    /* 1 / lobe concentration (phong n, ggx 1 / (2 alpha^2)); inf for lambert */
    intv levels;        /* product depth P (<= tree levels) */
    intv shape;         /* LOBE_LAMBERT | LOBE_PHONG | LOBE_GGX | LOBE_GGX_HALF */
    uintv base;         /* offset of the lane's light tree in the buffer (PRODUCT_TREES > 1) */
} Lobe;

/* The product walk reads one of PRODUCT_TREES light trees per lane, one after another in
 * the buffer (wavlight.strategies.WaveletStrategy: the plain light tree, and the MIS-
 * compensated one for lambert materials); with one tree the offset is 0 at compile time. */
#ifndef PRODUCT_TREES
#define PRODUCT_TREES 1
#endif
#if PRODUCT_TREES > 1
#define TREE_BASE(lb) ((lb)->base)
#else
#define TREE_BASE(lb) ((uintv)0)
#endif

/* The lobes from world-frame normals n and directions to the viewer o: axis = n
 * (lambert) or the mirror direction; code = depth + 256 shape + 65536 tree (as the host
 * packs it, wavlight/shading.py); rot = map_from_world (row-major). */
INLINE Lobe make_lobe(__global const float *rot, const realv nx, const realv ny, const realv nz,
                      const realv ox, const realv oy, const realv oz, const realv kappa, const intv code)
{
    Lobe lb;
    const intv shape = (code >> 8) & 0xff;
    const intv lambert = shape == LOBE_LAMBERT;
    const realv c2 = 2.0f * (ox * nx + oy * ny + oz * nz);
    const realv ax = select(c2 * nx - ox, nx, lambert);
    const realv ay = select(c2 * ny - oy, ny, lambert);
    const realv az = select(c2 * nz - oz, nz, lambert);
    lb.ax = rot[0] * ax + rot[1] * ay + rot[2] * az;
    lb.ay = rot[3] * ax + rot[4] * ay + rot[5] * az;
    lb.az = rot[6] * ax + rot[7] * ay + rot[8] * az;
    lb.nx = rot[0] * nx + rot[1] * ny + rot[2] * nz;
    lb.ny = rot[3] * nx + rot[4] * ny + rot[5] * nz;
    lb.nz = rot[6] * nx + rot[7] * ny + rot[8] * nz;
    lb.wx = rot[0] * ox + rot[1] * oy + rot[2] * oz;
    lb.wy = rot[3] * ox + rot[4] * oy + rot[5] * oz;
    lb.wz = rot[6] * ox + rot[7] * oy + rot[8] * oz;
    lb.wn = ox * nx + oy * ny + oz * nz;
    lb.inv_kappa = 1.0f / kappa;
    lb.levels = code & 0xff;
    lb.shape = shape;
#if defined(N_LEVELS) && PRODUCT_TREES > 1
    lb.base = as_uintv(code >> 16) * (uint)TREE_STRIDE(N_LEVELS);   /* tree index x tree stride (common.h) */
#else
    lb.base = 0;
#endif
    return lb;
}

/* Importance (before the light mass) of the children of level-`level` nodes whose
 * centre directions d (map frame, unit) have d . n = cos_n, d . axis = cos_a and
 * d . wo = cos_w (used by LOBE_GGX_HALF only): the lobe formulas of the header comment. */
INLINE realv lobe_weight(const Lobe *lb, const realv cos_n, const realv cos_a, const realv cos_w, const int level)
{
    /* the child's level is level + 1: inv = 2^-(level + 1), exactly and without a division */
    const float scale = (float)(2u << level), inv = as_float((uint)(126 - level) << 23);
    const float r = LOBE_BLUR_F * inv, rp = PHONG_BLUR_F * inv, rh = HORIZON_BLUR_F * inv;
    const realv x1 = 1.0f - cos_a;
#ifdef TRIVIAL_LOBE
    return fmax(cos_n + cos_a + cos_w, 0.0f);
#endif
    const realv step = clamp(cos_n * (scale * (1.0f / HORIZON_BLUR_F)) + 1.0f, 0.0f, 1.0f);
    const realv hor = clamp(cos_n + rh, 0.0f, 1.0f);
    realv w = 0.0f;
#if LOBE_SHAPES == (1 << LOBE_LAMBERT)
    /* a program for lambert alone skips the phong profile, which is 1 exactly for kappa = 0
     * (one division per evaluation): lambert walk at 1024^2 +24-30% in three interleaved
     * runs (benchmarks/kernel_ab.py: 20.6 -> 25.5, 18.8 -> 23.8, 21.2 -> 27.6 M/s) */
    return hor;
#endif
#if HAS_SHAPE(LOBE_LAMBERT) || HAS_SHAPE(LOBE_PHONG)
    {   /* phong: (1 + k x / 8)^-8 ~ exp(-k x), times the (softened) cosine; lambert is its
         * kappa = 0 case (inv_kappa = inf: g = 1 exactly), the cosine alone */
        const realv a8 = 8.0f * fmin(lb->inv_kappa + rp * rp, 1e30f);   /* 8 / kappa_l */
        realv g = a8 / (a8 + x1);
        g *= g; g *= g;
        w = select(w, g * g * hor, lb->shape <= LOBE_PHONG);
    }
#endif
#if HAS_SHAPE(LOBE_GGX)
    {   /* (1 + c x)^-2 = (a / (a + x))^2, c = 1 / a */
        const realv a = fmin(lb->inv_kappa + r * r, 1e30f);
        const realv g = a / (a + x1);
        w = select(w, g * g * step, lb->shape == LOBE_GGX);
    }
#endif
#if HAS_SHAPE(LOBE_GGX_HALF)
    {   /* pi D(h) with alpha widened; h = d + wo: h . n = cos_n + wo . n, |h|^2 = 2 + 2 cos_w */
        const realv a2 = 0.5f * (lb->inv_kappa + r * r);     /* alpha_l^2 = alpha^2 + r^2 / 2 */
        const realv hn = fmax(cos_n + lb->wn, 0.0f);
        /* D ~ a2 / (cos^2 (a2 - 1) + 1)^2 with cos^2 = hn^2 / |h|^2: one division */
        const realv hh = fmax(2.0f + 2.0f * cos_w, 0.0f);
        const realv q = hh / (hn * hn * (a2 - 1.0f) + hh);
        w = select(w, (a2 * q * q) * step, lb->shape == LOBE_GGX_HALF);
    }
#endif
    return w;
}

/* Node centre directions are d(theta, phi) = (sin phi sin theta, cos theta, -cos phi sin theta)
 * (map frame). Their dot products with the lobe's vectors v split into a part per column
 * (phi) and one per row (theta): d . v = sin theta (sin phi v_x - cos phi v_z) + cos theta v_y.
 * LobeColumn holds the column parts for v = n, axis, wo; the four (or sixteen) children
 * of a node share two (four) columns and two (four) rows. */
typedef struct {
    realv n, a, w;
} LobeColumn;

INLINE LobeColumn lobe_column(const Lobe *lb, const realv sin_phi, const realv cos_phi)
{
    LobeColumn c;
    c.n = sin_phi * lb->nx - cos_phi * lb->nz;
    c.a = sin_phi * lb->ax - cos_phi * lb->az;
#if HAS_SHAPE(LOBE_GGX_HALF)
    c.w = sin_phi * lb->wx - cos_phi * lb->wz;
#else
    c.w = 0.0f;
#endif
    return c;
}

/* lobe_weight at the direction of column c and row (sin theta, cos theta). */
INLINE realv lobe_weight_at(const Lobe *lb, const LobeColumn *c, const realv sin_theta, const realv cos_theta,
                            const int level)
{
    return lobe_weight(lb, sin_theta * c->n + cos_theta * lb->ny, sin_theta * c->a + cos_theta * lb->ay,
                       sin_theta * c->w + cos_theta * lb->wy, level);
}

/* w0..w3 = the importances i0..i3, or the light masses m0..m3 where the importances sum
 * to zero or are not finite (the same rule in the walk and the pdf). */
INLINE void importances_or_masses(const realv i0, const realv i1, const realv i2, const realv i3,
                                  const realv m0, const realv m1, const realv m2, const realv m3,
                                  realv *w0, realv *w1, realv *w2, realv *w3)
{
    const realv sum = ((i0 + i1) + i2) + i3;
    const intv ok = (sum > 0.0f) & isfinite(sum);
    *w0 = select(m0, i0, ok);
    *w1 = select(m1, i1, ok);
    *w2 = select(m2, i2, ok);
    *w3 = select(m3, i3, ok);
}

/* The centre directions of a walk's current nodes, per lane, as the sines and cosines of
 * their angles: d = (sin phi sin theta, cos theta, -cos phi sin theta). The root's centre
 * is phi = pi, theta = pi / 2. A level-L node spans 2 pi / 2^L in phi and pi / 2^L in
 * theta, so its children's centres lie at phi -+ pi / 2^(L+1) and theta -+ pi / 2^(L+2):
 * their sines and cosines follow from the parent's by the angle-sum formulas with the
 * constants below (no table, no gather; float32 rounding drifts by a few ulp over the
 * product levels, far below a node's size). */
typedef struct {
    realv sp, cp, st, ct;
} NodeAngles;

INLINE NodeAngles root_angles(void)
{
    NodeAngles a;
    a.sp = 0.0f; a.cp = -1.0f; a.st = 1.0f; a.ct = 0.0f;
    return a;
}

/* sin and cos of pi / 2^k, k = 0 .. 15 */
__constant float SIN_PI_2K[16] = {0.0f, 1.0f, 0x1.6a09e6p-1f, 0x1.87de2ap-2f, 0x1.8f8b84p-3f, 0x1.917a6cp-4f,
                                  0x1.91f660p-5f, 0x1.921560p-6f, 0x1.921d20p-7f, 0x1.921f10p-8f, 0x1.921f8cp-9f,
                                  0x1.921faap-10f, 0x1.921fb2p-11f, 0x1.921fb4p-12f, 0x1.921fb6p-13f, 0x1.921fb6p-14f};
__constant float COS_PI_2K[16] = {-1.0f, 0.0f, 0x1.6a09e6p-1f, 0x1.d906bcp-1f, 0x1.f6297cp-1f, 0x1.fd88dap-1f,
                                  0x1.ff621ep-1f, 0x1.ffd886p-1f, 0x1.fff622p-1f, 0x1.fffd88p-1f, 0x1.ffff62p-1f,
                                  0x1.ffffd8p-1f, 0x1.fffff6p-1f, 0x1.fffffep-1f, 1.0f, 1.0f};

/* sin and cos of a - d (s0, c0) and a + d (s1, c1) from those of a, d = pi / 2^k. */
INLINE void split_angle(const realv s, const realv c, const int k, realv *s0, realv *c0, realv *s1, realv *c1)
{
    const float sd = SIN_PI_2K[k], cd = COS_PI_2K[k];
    const realv sc = s * cd, cs = c * sd, cc = c * cd, ss = s * sd;
    *s0 = sc - cs;
    *c0 = cc + ss;
    *s1 = sc + cs;
    *c1 = cc - ss;
}

/* The centre angles of the children of nodes at `level` with centre angles a: columns 0
 * and 1 (phi), rows 0 and 1 (theta). */
INLINE NodeAngles child_angles(const NodeAngles *a, const int level, const intv right, const intv bottom)
{
    realv s0, c0, s1, c1;
    NodeAngles r;
    split_angle(a->sp, a->cp, level + 1, &s0, &c0, &s1, &c1);
    r.sp = select(s0, s1, right);
    r.cp = select(c0, c1, right);
    split_angle(a->st, a->ct, level + 2, &s0, &c0, &s1, &c1);
    r.st = select(s0, s1, bottom);
    r.ct = select(c0, c1, bottom);
    return r;
}

/* Importances of the four children (00 10 01 11) of nodes at `level` with centre angles
 * a, whose light masses are m0..m3, into w0..w3. Where all four are zero (or the sum is
 * not finite) the light masses are used instead. */
INLINE void child_importances(const Lobe *lb, const NodeAngles *a,
                              const realv m0, const realv m1, const realv m2, const realv m3,
                              const int level, realv *w0, realv *w1, realv *w2, realv *w3)
{
    realv sp0, cp0, sp1, cp1, st0, ct0, st1, ct1;
    split_angle(a->sp, a->cp, level + 1, &sp0, &cp0, &sp1, &cp1);
    split_angle(a->st, a->ct, level + 2, &st0, &ct0, &st1, &ct1);
    const LobeColumn c0 = lobe_column(lb, sp0, cp0), c1 = lobe_column(lb, sp1, cp1);
    const realv i0 = m0 * lobe_weight_at(lb, &c0, st0, ct0, level);
    const realv i1 = m1 * lobe_weight_at(lb, &c1, st0, ct0, level);
    const realv i2 = m2 * lobe_weight_at(lb, &c0, st1, ct1, level);
    const realv i3 = m3 * lobe_weight_at(lb, &c1, st1, ct1, level);
    importances_or_masses(i0, i1, i2, i3, m0, m1, m2, m3, w0, w1, w2, w3);
}

/* Levels whose children's importances look one level ahead (numpy twin:
 * wavlight.product.LOOKAHEAD_LEVELS): a child's importance is the sum of its own four
 * children's mass x lobe (level + 2 nodes, lobe blurred to their size) instead of its
 * mass x the lobe at its centre. At the coarse levels a bright light and the lobe can
 * share a node whose centre misses both; the finer sum sees where they overlap.
 * Measured (spheres, 16 spp, 4 seeds, relMSE of wavelet over mis, none -> 3 levels):
 * phong 200 0.67 / 0.11 / 0.50 -> 0.57 / 0.08 / 0.38 under rooitou / st_fagans /
 * potsdamer, ggx 0.05 0.71 / 0.15 / 0.49 -> 0.68 / 0.12 / 0.40, ggx 0.2 0.84 / 0.20 /
 * 0.28 -> 0.76 / 0.16 / 0.22, lambert 0.78 / 0.57 / 0.47 -> 0.61 / 0.41 / 0.33; 2 levels
 * gained less, 4 little more. It costs 20-50% of the product walk's speed (12
 * more lobe evaluations per look-ahead level). -DLOOKAHEAD_LEVELS=0 is only for
 * timing the walk without it. */
#ifndef LOOKAHEAD_LEVELS
#define LOOKAHEAD_LEVELS 3
#endif

/* child_importances with the look-ahead, for the nodes of index k in `level` (level + 2 <=
 * the tree's depth): the children's own masses m0..m3
 * are the fallback where the sum is zero or not finite. */
INLINE void child_importances_ahead(const Lobe *lb, const NodeAngles *a, __global const float *tree,
                                    const realv m0, const realv m1, const realv m2, const realv m3,
                                    const uintv k, const int level,
                                    realv *w0, realv *w1, realv *w2, realv *w3)
{
    /* the sixteen grandchildren, 16 k .. 16 k + 15 of level + 2: four per child (common.h) */
    const uintv g = TREE_BASE(lb) + (uint)LEVEL_OFFSET(level + 2) + 16 * k;
    LobeColumn cols[4];
    realv st[4], ct[4];
    realv mass[4][4];
    {   /* the grandchildren's four columns and rows: the children's split once more */
        realv sp0, cp0, sp1, cp1, st0, ct0, st1, ct1, sa, ca, sb, cb;
        split_angle(a->sp, a->cp, level + 1, &sp0, &cp0, &sp1, &cp1);
        split_angle(sp0, cp0, level + 2, &sa, &ca, &sb, &cb);
        cols[0] = lobe_column(lb, sa, ca);
        cols[1] = lobe_column(lb, sb, cb);
        split_angle(sp1, cp1, level + 2, &sa, &ca, &sb, &cb);
        cols[2] = lobe_column(lb, sa, ca);
        cols[3] = lobe_column(lb, sb, cb);
        split_angle(a->st, a->ct, level + 2, &st0, &ct0, &st1, &ct1);
        split_angle(st0, ct0, level + 3, &st[0], &ct[0], &st[1], &ct[1]);
        split_angle(st1, ct1, level + 3, &st[2], &ct[2], &st[3], &ct[3]);
    }
    /* their masses by rows and columns: child c's four at g + 4 c, (column, row) order 00 10 01 11 */
    GATHER4(tree, g, &mass[0][0], &mass[0][1], &mass[1][0], &mass[1][1]);
    GATHER4(tree, g + 4, &mass[0][2], &mass[0][3], &mass[1][2], &mass[1][3]);
    GATHER4(tree, g + 8, &mass[2][0], &mass[2][1], &mass[3][0], &mass[3][1]);
    GATHER4(tree, g + 12, &mass[2][2], &mass[2][3], &mass[3][2], &mass[3][3]);
#define GC(i, j) (mass[i][j] * lobe_weight_at(lb, &cols[j], st[i], ct[i], level + 1))
    const realv i0 = (GC(0, 0) + GC(0, 1)) + (GC(1, 0) + GC(1, 1));   /* child 00: rows 0-1, columns 0-1 */
    const realv i1 = (GC(0, 2) + GC(0, 3)) + (GC(1, 2) + GC(1, 3));   /* child 10 */
    const realv i2 = (GC(2, 0) + GC(2, 1)) + (GC(3, 0) + GC(3, 1));   /* child 01 */
    const realv i3 = (GC(2, 2) + GC(2, 3)) + (GC(3, 2) + GC(3, 3));   /* child 11 */
#undef GC
    importances_or_masses(i0, i1, i2, i3, m0, m1, m2, m3, w0, w1, w2, w3);
}

/* The importances of the four children of the nodes of index k in `level` (compile-time
 * after unrolling), look-ahead at the coarse levels. */
INLINE void node_importances(const Lobe *lb, const NodeAngles *a, __global const float *tree,
                             const realv m0, const realv m1, const realv m2, const realv m3,
                             const uintv k, const int level, const int n_levels,
                             realv *i0, realv *i1, realv *i2, realv *i3)
{
    if (level < LOOKAHEAD_LEVELS && level + 2 <= n_levels)
        child_importances_ahead(lb, a, tree, m0, m1, m2, m3, k, level, i0, i1, i2, i3);
    else
        child_importances(lb, a, m0, m1, m2, m3, level, i0, i1, i2, i3);
}

/* Node index of level `depth` (per lane) containing the leaf of index k in level n_levels:
 * its ancestor's index is k >> 2 (n_levels - depth) (common.h). */
INLINE uintv node_of_leaf(const intv depth, const int n_levels, const uintv k)
{
    const uintv d = as_uintv(depth);
    return (((uintv)1 << (2 * d)) - 1) / 3 + (k >> (2 * ((uint)n_levels - d)));
}

#if defined(N_LEVELS) && defined(PRODUCT_LEVELS)
/* The density on the square of the walk that ended in the leaf of index k with product p
 * of its conditionals over the product levels: p * mass(leaf) / mass(node at depth P) *
 * 4^n, 0 where that node or the lane's whole tree (an all-black map) has no mass. */
INLINE realv product_density(__global const float *tree, const Lobe *lb, const realv p, const uintv k)
{
    const intv depth = min(lb->levels, N_LEVELS);
    const uint side = 1u << N_LEVELS;
    const realv node_mass = GATHER(tree, TREE_BASE(lb) + node_of_leaf(depth, N_LEVELS, k));
    const realv leaf = GATHER(tree, TREE_BASE(lb) + (uint)LEVEL_OFFSET(N_LEVELS) + k);
    const realv pdf = select((realv)0.0f, p * (leaf / node_mass) * (float)side * (float)side, node_mass > 0.0f);
#if PRODUCT_TREES > 1
    return select((realv)0.0f, pdf, GATHER(tree, lb->base) > 0.0f);
#else
    return tree[0] > 0.0f ? pdf : (realv)0.0f;   /* (a scalar test: 1, not a -1 lane mask) */
#endif
}

#if PRODUCT_LEVELS > 14
#error "PRODUCT_LEVELS > 14: the walk's angle steps pi / 2^k reach k = PRODUCT_LEVELS + 1, SIN_PI_2K ends at 15"
#endif
/* Eight product samples: lobe lb for each lane's first P levels (P <= PRODUCT_LEVELS, a
 * compile-time bound), then the light tree; (ux, uy) uniform in, point of the square
 * out; returns the density on the square. Unrolled over N_LEVELS, eight lanes in vector
 * types (simd.h). The importances are computed for every lane at levels <
 * PRODUCT_LEVELS and selected per lane (every load stays in the tree). PRODUCT_LEVELS
 * must be at least every lane's depth (the host builds with the largest). */
/* The root's four children: their light masses m and importances i (node_importances at
 * level 0), the same for every walk of one lobe: the resampling estimator (shade.cl,
 * RIS_PRODUCT) computes them once per shading point for all its candidates. */
/* With CACHE_LEVEL_1 (PRODUCT_LEVELS > 1 and N_LEVELS > 1) the same for level 1: the
 * masses m1[c][.] and importances i1[c][.] of the four children of each level-1 node c,
 * computed as the walk would (the same angles, the same look-ahead), so the walks and pdfs
 * that use them give the same values bit for bit; the candidates then skip level 1's
 * look-ahead (sixteen lobe evaluations and five four-float gathers each). */
#if PRODUCT_LEVELS > 1 && N_LEVELS > 1
#define CACHE_LEVEL_1 1
#else
#define CACHE_LEVEL_1 0
#endif
typedef struct {
    realv m[4], i[4];
#if CACHE_LEVEL_1
    realv m1[4][4], i1[4][4];
#endif
} RootChildren;

INLINE RootChildren root_children(__global const float *tree, const Lobe *lb)
{
    RootChildren r;
    const NodeAngles a = root_angles();
    GATHER4(tree, TREE_BASE(lb) + (uint)LEVEL_OFFSET(1), &r.m[0], &r.m[1], &r.m[2], &r.m[3]);
    if (0 < PRODUCT_LEVELS)
        node_importances(lb, &a, tree, r.m[0], r.m[1], r.m[2], r.m[3], (uintv)0, 0, N_LEVELS,
                         &r.i[0], &r.i[1], &r.i[2], &r.i[3]);
    else
        r.i[0] = r.m[0], r.i[1] = r.m[1], r.i[2] = r.m[2], r.i[3] = r.m[3];
#if CACHE_LEVEL_1
#pragma unroll
    for (int c = 0; c < 4; ++c) {
        const NodeAngles ac = child_angles(&a, 0, (intv)(c & 1 ? -1 : 0), (intv)(c & 2 ? -1 : 0));
        GATHER4(tree, TREE_BASE(lb) + (uint)(LEVEL_OFFSET(2) + 4 * c), &r.m1[c][0], &r.m1[c][1], &r.m1[c][2],
                &r.m1[c][3]);
        node_importances(lb, &ac, tree, r.m1[c][0], r.m1[c][1], r.m1[c][2], r.m1[c][3], (uintv)c, 1, N_LEVELS,
                         &r.i1[c][0], &r.i1[c][1], &r.i1[c][2], &r.i1[c][3]);
    }
#endif
    return r;
}

#if CACHE_LEVEL_1
/* v[k][0..3] for the level-1 node k (0..3) of each lane, into o[0..3]. */
INLINE void pick_level_1(const realv v[4][4], const uintv k, realv o[4])
{
    const intv right = as_intv(k & 1u) != 0, bottom = as_intv(k & 2u) != 0;
#pragma unroll
    for (int j = 0; j < 4; ++j)
        o[j] = select(select(v[0][j], v[1][j], right), select(v[2][j], v[3][j], right), bottom);
}
#endif

/* The first level the product walk may pair (warp.h): below its product levels. A constant
 * expression (a call to max() here was not folded, and the loop's tests then ran at run
 * time: ggx 0.2 at 256^2 lost a third of its speed). */
#define PRODUCT_PAIR_FROM ((PAIR_LEVEL) > (PRODUCT_LEVELS) ? (PAIR_LEVEL) : (PRODUCT_LEVELS))

/* product_walk with the root's children given (root, from root_children) or computed (NULL). */
INLINE realv product_walk_from(__global const float *tree, const Lobe *lb, const RootChildren *root,
                               realv *ux, realv *uy)
{
    uintv x = 0, y = 0, k = 0;   /* the node's coordinates and its index in its level */
    realv p = 1.0f;
    NodeAngles a = root_angles();
    *ux = clamp_unit(*ux);
    *uy = clamp_unit(*uy);
#pragma unroll
    for (int l = 0; l < N_LEVELS; ++l) {
        /* below the product levels, the light tree's levels from PAIR_LEVEL on two at a time */
        if (PAIRED_SECOND(l, PRODUCT_PAIR_FROM))
            continue;
        /* barriers (warp.h) only where the walk follows the light tree alone: with barriers
         * inside the product levels, Intel's OpenCL CPU runtime returned other points than
         * the same walk without barriers (tests/test_shading.py
         * test_breadth_first_walks_match_depth_first); the product levels of the usual lobes
         * are above BARRIER_LEVEL anyway (ggx 0.05: 7 levels) */
        if (l >= PRODUCT_LEVELS)
            LEVEL_BARRIER(l);
        if (PAIRED_FIRST(l, PRODUCT_PAIR_FROM)) {
            paired_step(tree, TREE_BASE(lb), l, &k, &x, &y, ux, uy);
            PREFETCH_STEP(tree, TREE_BASE(lb), l + 2, k, PRODUCT_PAIR_FROM);
            continue;
        }
        realv m0, m1, m2, m3;
        if (l == 0 && root) {
            m0 = root->m[0]; m1 = root->m[1]; m2 = root->m[2]; m3 = root->m[3];
#if CACHE_LEVEL_1
        } else if (l == 1 && root) {
            realv o[4];
            pick_level_1(root->m1, k, o);
            m0 = o[0]; m1 = o[1]; m2 = o[2]; m3 = o[3];
#endif
        } else {
            GATHER4(tree, TREE_BASE(lb) + (uint)LEVEL_OFFSET(l + 1) + 4 * k, &m0, &m1, &m2, &m3);
        }
        realv w0 = m0, w1 = m1, w2 = m2, w3 = m3;
        const intv in_product = l < lb->levels;
        if (l < PRODUCT_LEVELS) {   /* compile-time */
            realv i0, i1, i2, i3;
            if (l == 0 && root) {
                i0 = root->i[0]; i1 = root->i[1]; i2 = root->i[2]; i3 = root->i[3];
#if CACHE_LEVEL_1
            } else if (l == 1 && root) {
                realv o[4];
                pick_level_1(root->i1, k, o);
                i0 = o[0]; i1 = o[1]; i2 = o[2]; i3 = o[3];
#endif
            } else {
                node_importances(lb, &a, tree, m0, m1, m2, m3, k, l, N_LEVELS, &i0, &i1, &i2, &i3);
            }
            w0 = select(m0, i0, in_product);
            w1 = select(m1, i1, in_product);
            w2 = select(m2, i2, in_product);
            w3 = select(m3, i3, in_product);
        }
        const realv q = choose_child(w0, w1, w2, w3, ux, uy, &x, &y);
        k = child_index(k, x, y);
        PREFETCH_STEP(tree, TREE_BASE(lb), l + 1, k, PRODUCT_PAIR_FROM);
        if (l < PRODUCT_LEVELS) {
            p *= select((realv)1.0f, q, in_product);
            if (l + 1 < PRODUCT_LEVELS)
                a = child_angles(&a, l, as_intv(x & 1u) != 0, as_intv(y & 1u) != 0);
        }
    }
    leaf_point(x, y, N_LEVELS, ux, uy);
    return product_density(tree, lb, p, k);
}

INLINE realv product_walk(__global const float *tree, const Lobe *lb, realv *ux, realv *uy)
{
    return product_walk_from(tree, lb, (const RootChildren *)0, ux, uy);
}

/* Density on the square of product_walk at points (u, v), for any directions (MIS); with
 * the root's children given (root) or computed (NULL). */
INLINE realv product_pdf_from(__global const float *tree, const Lobe *lb, const RootChildren *root,
                              const realv u, const realv v)
{
    const intv depth = min(lb->levels, N_LEVELS);
    const uintv leaf = node_index(N_LEVELS, leaf_of(u, N_LEVELS), leaf_of(v, N_LEVELS)) - (uint)LEVEL_OFFSET(N_LEVELS);
    realv p = 1.0f;
    NodeAngles a = root_angles();
#pragma unroll
    for (int l = 0; l < PRODUCT_LEVELS && l < N_LEVELS; ++l) {
        const uintv child = leaf >> (2 * (N_LEVELS - l - 1)), parent = child >> 2;   /* indices in levels l + 1, l */
        realv m0, m1, m2, m3, i0, i1, i2, i3;
        if (l == 0 && root) {
            i0 = root->i[0]; i1 = root->i[1]; i2 = root->i[2]; i3 = root->i[3];
#if CACHE_LEVEL_1
        } else if (l == 1 && root) {
            realv o[4];
            pick_level_1(root->i1, parent, o);
            i0 = o[0]; i1 = o[1]; i2 = o[2]; i3 = o[3];
#endif
        } else {
            GATHER4(tree, TREE_BASE(lb) + (uint)LEVEL_OFFSET(l + 1) + 4 * parent, &m0, &m1, &m2, &m3);
            node_importances(lb, &a, tree, m0, m1, m2, m3, parent, l, N_LEVELS, &i0, &i1, &i2, &i3);
        }
        const realv sum = (i0 + i1) + (i2 + i3);
        const intv right = as_intv(child & 1u) != 0, bottom = as_intv(child & 2u) != 0;
        if (l + 1 < PRODUCT_LEVELS)
            a = child_angles(&a, l, right, bottom);
        const realv mine = select(select(i0, i1, right), select(i2, i3, right), bottom);
        p *= select((realv)1.0f, mine / sum, l < depth);
    }
    return product_density(tree, lb, p, leaf);
}

INLINE realv product_pdf(__global const float *tree, const Lobe *lb, const realv u, const realv v)
{
    return product_pdf_from(tree, lb, (const RootChildren *)0, u, v);
}
#endif
#endif
