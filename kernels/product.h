/* Wavelet product importance sampling, top-down (Chen & Gao sec. 4.3-4.4; Clarberg
 * et al. 2005). numpy twin: wavlight/product.py.
 *
 * The importance of a node s at level l is its product scaling coefficient
 * approximated by the first term of eq. 25, F^0_s ~ 2^l G^0_s H^0_s: the
 * environment's exact box mass (the light tree) times the BRDF x cosine of the
 * shading point evaluated at the node's centre direction d_s with a lobe
 * pre-filtered to the node's size (x = 1 - d_s . axis, k_l = 1 / (1/kappa + r_l^2),
 * r_l = 0.35 pi / 2^l the lobe blur, h_l = 0.75 pi / 2^l the horizon blur):
 *     lambert  I = mass clamp(d_s . n + h_l, 0, 1)
 *     phong    I = mass (1 + k_l x / 8)^-8 clamp(d_s . n + h_l, 0, 1)   (~ exp(-k_l x))
 *     ggx      I = mass (1 + k_l x)^-2 clamp(d_s . n / h_l + 1, 0, 1)
 * axis = mirror direction (phong, ggx) or normal (lambert). Only the
 * four children of each visited node are evaluated: O(levels) per sample, no
 * per-point tree. Node centre directions come from a table (map frame, tree
 * layout, levels <= P), the lobe is turned into the map frame once per point. Below the product depth P the BRDF is taken as constant and the
 * walk continues in the light tree (tree_descend, unchanged). The pdf is exact:
 *     pdf_square = prod_l I(child_l) / sum I(siblings_l) * mass(leaf) / mass(node_P) * 4^n
 * and product_pdf recomputes it for any direction. Where all four children have
 * zero importance the walk falls back to their light masses (same rule in both).
 */
#ifndef WAVLIGHT_PRODUCT_H
#define WAVLIGHT_PRODUCT_H
#include "warp.h"
#include "sphere.h"

/* A level-l node spans pi / 2^l in theta (2 pi sin(theta) / 2^l in phi). The lobe is
 * widened by LOBE_BLUR_F / 2^l (less than the node's half size: wider lobes waste
 * samples on bright nodes outside the lobe, measured), the horizon softened by
 * HORIZON_BLUR_F / 2^l (3/4 of the node's theta extent: a node whose centre lies
 * further below the horizon gets no product samples; the BSDF sample covers it). */
#define LOBE_BLUR_F (0.35f * PI_F)
#define HORIZON_BLUR_F (0.75f * PI_F)

#define LOBE_LAMBERT 0
#define LOBE_PHONG 1
#define LOBE_GGX 2

typedef struct {
    float3 axis;   /* lobe axis, in the map frame */
    float3 n;      /* shading normal, in the map frame */
    float kappa;   /* lobe concentration: phong n, ggx 1 / (2 alpha^2) */
    int levels;    /* product depth P (<= tree levels) */
    int shape;     /* LOBE_LAMBERT | LOBE_PHONG | LOBE_GGX (= the BRDF kind) */
    __global const float4 *dirs; /* map-frame centre directions of the nodes of levels <= P, tree layout */
} Lobe;

inline float node_importance(const Lobe *lb, const float mass, const uint x, const uint y, const int level)
{
    const float inv = 1.0f / (float)(1u << level);
    const float3 d = lb->dirs[LEVEL_OFFSET(level) + (ulong)y * (1u << level) + x].xyz;
    const float r = LOBE_BLUR_F * inv, rh = HORIZON_BLUR_F * inv;
    const float cos_n = dot(d, lb->n);
    const float x1 = 1.0f - dot(d, lb->axis);
    if (lb->shape == LOBE_GGX) {           /* (1 + c x)^-2, step at the horizon */
        const float c = 1.0f / (1.0f / lb->kappa + r * r);
        const float g = 1.0f / (1.0f + c * x1);
        return mass * g * g * clamp(cos_n / rh + 1.0f, 0.0f, 1.0f);
    }
    const float hor = clamp(cos_n + rh, 0.0f, 1.0f);
    if (lb->shape == LOBE_PHONG) {         /* (1 + k x / 8)^-8 ~ exp(-k x), von Mises-Fisher, x cosine */
        const float kappa = 1.0f / (1.0f / lb->kappa + r * r);
        float g = 1.0f / (1.0f + 0.125f * kappa * x1);
        g *= g; g *= g;
        return mass * (g * g) * hor;
    }
    return mass * hor;                     /* lambert: cosine */
}

/* Importances of the four children of node (x, y) at `level`, into i[0..3] = 00 10 01 11. */
inline void child_importances(__global const float *tree, const Lobe *lb, const uint x,
                              const uint y, const int level, float *i)
{
    const uint cside = 2u << level;
    __global const float *child = tree + LEVEL_OFFSET(level + 1);
    const uint c = (2 * y) * cside + 2 * x;
    const float m[4] = {child[c], child[c + 1], child[c + cside], child[c + cside + 1]};
    float sum = 0.0f;
    for (int k = 0; k < 4; ++k) {
        i[k] = node_importance(lb, m[k], 2 * x + (k & 1), 2 * y + (k >> 1), level + 1);
        sum += i[k];
    }
    if (!(sum > 0.0f) || !isfinite(sum))
        for (int k = 0; k < 4; ++k) i[k] = m[k];
}

inline float2 product_sample(__global const float *tree, const int n_levels, const Lobe *lb,
                             float2 u, float *pdf)
{
    uint x = 0, y = 0;
    float p = 1.0f;
    const int depth = min(lb->levels, n_levels);
    u = clamp(u, 0.0f, ONE_MINUS_EPS);
    for (int l = 0; l < depth; ++l) {
        float i[4];
        child_importances(tree, lb, x, y, l, i);
        p *= choose_child(i[0], i[1], i[2], i[3], &u, &x, &y);
    }
    const float node_mass = tree[LEVEL_OFFSET(depth) + (ulong)y * (1u << depth) + x];
    const float2 uv = tree_descend(tree, depth, n_levels, u, &x, &y);
    const uint side = 1u << n_levels;
    const float leaf = tree[LEVEL_OFFSET(n_levels) + (ulong)y * side + x];
    *pdf = (tree[0] > 0.0f && node_mass > 0.0f) ? p * (leaf / node_mass) * (float)side * (float)side : 0.0f;
    return uv;
}

inline float product_pdf(__global const float *tree, const int n_levels, const Lobe *lb,
                         const float2 uv)
{
    if (!(tree[0] > 0.0f)) return 0.0f;
    const int depth = min(lb->levels, n_levels);
    const uint side = 1u << n_levels;
    const uint lx = (uint)clamp((int)floor(uv.x * side), 0, (int)side - 1);
    const uint ly = (uint)clamp((int)floor(uv.y * side), 0, (int)side - 1);
    float p = 1.0f;
    for (int l = 0; l < depth; ++l) {
        const uint cx = lx >> (n_levels - l - 1), cy = ly >> (n_levels - l - 1);
        float i[4];
        child_importances(tree, lb, cx >> 1, cy >> 1, l, i);
        const float sum = (i[0] + i[1]) + (i[2] + i[3]);
        p *= i[(cx & 1) + 2 * (cy & 1)] / sum;
    }
    const uint nx = lx >> (n_levels - depth), ny = ly >> (n_levels - depth);
    const float node_mass = tree[LEVEL_OFFSET(depth) + (ulong)ny * (1u << depth) + nx];
    const float leaf = tree[LEVEL_OFFSET(n_levels) + (ulong)ly * side + lx];
    return node_mass > 0.0f ? p * (leaf / node_mass) * (float)side * (float)side : 0.0f;
}
#endif
