/* Hierarchical warping by a sampling tree (Chen & Gao sec. 4.3, eq. 19-22;
 * Clarberg et al. 2005). Shared by warp.cl and every kernel that samples a tree.
 *
 * A sample walks from the root to a leaf. At each node it picks the top or bottom
 * pair of children with probability proportional to their mass, then the left or
 * right child of that pair, rescaling the used uniform number into [0, 1) each
 * time so that stratified inputs stay stratified. A child's conditional
 * probability is m_child / m_parent = (1/2) F^0_{l+1} / F^0_l (eq. 22). In the
 * leaf the point lands uniformly; its density on the unit square is
 *     pdf = m_leaf / m_root * 4^n                                   (eq. 19-20)
 * and tree_pdf evaluates the same expression at any point. Nodes of zero mass are
 * never entered; a tree whose root is zero gives pdf 0 ("no sample").
 */
#ifndef WAVLIGHT_WARP_H
#define WAVLIGHT_WARP_H
#include "common.h"

inline float tree_pdf(__global const float *base, const int n_levels, float2 uv)
{
    const uint side = 1u << n_levels;
    const uint x = (uint)clamp((int)floor(uv.x * side), 0, (int)side - 1);
    const uint y = (uint)clamp((int)floor(uv.y * side), 0, (int)side - 1);
    const float root = base[0];
    const float leaf = base[LEVEL_OFFSET(n_levels) + (ulong)y * side + x];
    return (root > 0.0f) ? leaf / root * (float)side * (float)side : 0.0f;
}

/* One step of the walk: pick one of the four children of node (x, y) with masses
 * m00 m10 (top row) m01 m11 (bottom row), first the row pair then the column,
 * rescaling u; (x, y) becomes the child. Returns the child's conditional
 * probability m_child / (m00 + m10 + m01 + m11) (eq. 21-22). Branch-free (selects),
 * so that several walks interleave without mispredictions (see tree_sample_k).
 * The choices compare u * sum against a mass (u < top / (top + bottom) without
 * the division), and the two rescaled coordinates and the probability come from
 * one float4 division: divisions, not loads, bound these walks (measured). */
inline float choose_child(const float m00, const float m10, const float m01, const float m11,
                          float2 *uu, uint *px, uint *py)
{
#pragma OPENCL FP_CONTRACT OFF
    /* (no fused multiply-add: the numpy twin rounds u * sum and the subtraction apart) */
    const float2 u = *uu;
    const float top = m00 + m10, bottom = m01 + m11, s_row = top + bottom;
    /* top (row 2y) or bottom (row 2y + 1) pair */
    const int b = !(u.y * s_row < top);
    const float row = b ? bottom : top;
    const float left = b ? m01 : m00, right = b ? m11 : m10, s_col = left + right;
    /* left (column 2x) or right (column 2x + 1) child */
    const int r = !(u.x * s_col < left);
    const float col = r ? right : left;
    const float4 q = (float4)(u.y * s_row - (b ? top : 0.0f), u.x * s_col - (r ? left : 0.0f), row * col, 0.0f)
                   / (float4)(row, col, s_row * s_col, 1.0f);
    *py = 2 * *py + (uint)b;
    *px = 2 * *px + (uint)r;
    *uu = (float2)(fmin(q.s1, ONE_MINUS_EPS), fmin(q.s0, ONE_MINUS_EPS));
    return q.s2;
}

/* The four children of node (x, y) at `level`, as (m00, m10, m01, m11). */
inline float4 children_of(__global const float *base, const int level, const uint x, const uint y)
{
    const uint cside = 2u << level;
    __global const float *c = base + LEVEL_OFFSET(level + 1) + (ulong)(2 * y) * cside + 2 * x;
    return (float4)(c[0], c[1], c[cside], c[cside + 1]);
}

/* The point of the unit square at offset u inside leaf (x, y) of a 2^n grid. */
inline float2 leaf_point(const uint x, const uint y, const int n_levels, const float2 u)
{
    /* (x + u) / 2^n may round up onto the next leaf's edge: stay inside the chosen leaf. */
    const float inv = 1.0f / (float)(1u << n_levels);
    return (float2)(fmin(((float)x + u.x) * inv, nextafter((float)(x + 1) * inv, 0.0f)),
                    fmin(((float)y + u.y) * inv, nextafter((float)(y + 1) * inv, 0.0f)));
}

/* WALK_K samples walk their trees together, level by level: sample k uses the tree
 * at base + off[k], u[k] is its uniform point on entry and its point of the unit
 * square on return, pdf[k] its density there (eq. 19-20). One walk is a chain of
 * dependent loads, one per level; WALK_K independent chains in one loop overlap
 * in the memory system (measured 3.5x over one walk per work-item on a 1024^2
 * tree; WALK_K is set by the host, wavlight/cl.py). */
inline void tree_sample_k(__global const float *base, const ulong *off, const int n_levels,
                          float2 *u, float *pdf)
{
    uint x[WALK_K], y[WALK_K];
    for (int k = 0; k < WALK_K; ++k) {
        x[k] = 0; y[k] = 0;
        u[k] = clamp(u[k], 0.0f, ONE_MINUS_EPS);
    }
    for (int l = 0; l < n_levels; ++l)
        for (int k = 0; k < WALK_K; ++k) {
            const float4 m = children_of(base + off[k], l, x[k], y[k]);
            choose_child(m.s0, m.s1, m.s2, m.s3, &u[k], &x[k], &y[k]);
        }
    const uint side = 1u << n_levels;
    for (int k = 0; k < WALK_K; ++k) {
        __global const float *t = base + off[k];
        u[k] = leaf_point(x[k], y[k], n_levels, u[k]);
        const float root = t[0], leaf = t[LEVEL_OFFSET(n_levels) + (ulong)y[k] * side + x[k]];
        pdf[k] = (root > 0.0f) ? leaf / root * (float)side * (float)side : 0.0f;
    }
}
#endif
