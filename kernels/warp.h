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
 * probability m_child / (m00 + m10 + m01 + m11) (eq. 21-22). */
inline float choose_child(const float m00, const float m10, const float m01, const float m11,
                          float2 *uu, uint *px, uint *py)
{
    float2 u = *uu;
    const float top = m00 + m10, bottom = m01 + m11;
    /* top (row 2y) or bottom (row 2y + 1) pair */
    const float p_top = top / (top + bottom);
    float left, right, p_row;
    if (u.y < p_top) {
        u.y = u.y / p_top;
        left = m00; right = m10; *py = 2 * *py; p_row = p_top;
    } else {
        u.y = (u.y - p_top) / (1.0f - p_top);
        left = m01; right = m11; *py = 2 * *py + 1; p_row = 1.0f - p_top;
    }
    u.y = fmin(u.y, ONE_MINUS_EPS);
    /* left (column 2x) or right (column 2x + 1) child */
    const float p_left = left / (left + right);
    float p_col;
    if (u.x < p_left) {
        u.x = u.x / p_left; *px = 2 * *px; p_col = p_left;
    } else {
        u.x = (u.x - p_left) / (1.0f - p_left); *px = 2 * *px + 1; p_col = 1.0f - p_left;
    }
    u.x = fmin(u.x, ONE_MINUS_EPS);
    *uu = u;
    return p_row * p_col;
}

/* The point of the unit square at offset u inside leaf (x, y) of a 2^n grid. */
inline float2 leaf_point(const uint x, const uint y, const int n_levels, const float2 u)
{
    /* (x + u) / 2^n may round up onto the next leaf's edge: stay inside the chosen leaf. */
    const float inv = 1.0f / (float)(1u << n_levels);
    return (float2)(fmin(((float)x + u.x) * inv, nextafter((float)(x + 1) * inv, 0.0f)),
                    fmin(((float)y + u.y) * inv, nextafter((float)(y + 1) * inv, 0.0f)));
}

/* Walk a tree's levels [level0, n_levels) from node (x, y) of level0; returns the
 * point in the unit square and leaves the leaf in (*x, *y). */
inline float2 tree_descend(__global const float *base, const int level0, const int n_levels,
                           float2 u, uint *px, uint *py)
{
    u = clamp(u, 0.0f, ONE_MINUS_EPS);
    for (int l = level0; l < n_levels; ++l) {
        const uint cside = 2u << l;
        __global const float *child = base + LEVEL_OFFSET(l + 1);
        const uint c = (2 * *py) * cside + 2 * *px;
        choose_child(child[c], child[c + 1], child[c + cside], child[c + cside + 1], &u, px, py);
    }
    return leaf_point(*px, *py, n_levels, u);
}

inline float2 tree_sample(__global const float *base, const int n_levels, float2 u, float *pdf)
{
    uint x = 0, y = 0;
    const float2 uv = tree_descend(base, 0, n_levels, u, &x, &y);
    *pdf = tree_pdf(base, n_levels, uv);
    return uv;
}
#endif
