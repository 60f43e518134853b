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
 * rescaling (ux, uy); (x, y) becomes the child. Returns the child's conditional
 * probability m_child / (m00 + m10 + m01 + m11) (eq. 21-22). Scalar and branch-free
 * (selects; u < top / (top + bottom) is compared as u (top + bottom) < top), so that
 * PoCL vectorises the work-item loop of a kernel built on it (see tree_walk). */
inline float choose_child(const float m00, const float m10, const float m01, const float m11,
                          float *ux, float *uy, uint *px, uint *py)
{
#pragma OPENCL FP_CONTRACT OFF
    /* (no fused multiply-add: the numpy twin rounds u * sum and the subtraction apart) */
    const float top = m00 + m10, bottom = m01 + m11, s_row = top + bottom;
    /* top (row 2y) or bottom (row 2y + 1) pair; never a side of zero mass, which
     * u * sum rounding up to a denormal mass could otherwise pick */
    const int b = !(*uy * s_row < top) & (bottom > 0.0f);
    const float row = b ? bottom : top;
    const float left = b ? m01 : m00, right = b ? m11 : m10, s_col = left + right;
    /* left (column 2x) or right (column 2x + 1) child */
    const int r = !(*ux * s_col < left) & (as_uint(right) != 0u);   /* right >= +0: the bits (see below) */
    const float col = r ? right : left;
    const float ny = (*uy * s_row - (b ? top : 0.0f)) / row;
    const float nx = (*ux * s_col - (r ? left : 0.0f)) / col;
    *py = 2 * *py + (uint)b;
    *px = 2 * *px + (uint)r;
    /* Clamp below 1; NaN (a zero-mass pair) -> 1 - eps. x compares the bits (nx >= +0,
     * so the integer order is the float order and NaN's bits are above 1's), y the
     * floats: the same clamp, but not two identical chains, which LLVM's SLP vectoriser
     * pairs into a 2-vector, which stops PoCL's work-item vectoriser (measured 1.5x). */
    *uy = ny < ONE_MINUS_EPS ? ny : ONE_MINUS_EPS;
    *ux = as_uint(nx) < as_uint(ONE_MINUS_EPS) ? nx : ONE_MINUS_EPS;
    return (row * col) / (s_row * s_col);
}

/* Index of node (x, y) of `level` in a tree (common.h layout). */
inline uint node_index(const int level, const uint x, const uint y)
{
    return (uint)LEVEL_OFFSET(level) + y * (1u << level) + x;
}

/* u in [0, 1) clamped to the largest float below 1 (NaN -> 0). */
inline float clamp_unit(const float u)
{
    return u > 0.0f ? (u < ONE_MINUS_EPS ? u : ONE_MINUS_EPS) : 0.0f;
}

/* The point of the unit square at offset (ux, uy) inside leaf (x, y) of a 2^n grid.
 * The offsets are first clamped to 1 - 2^(n - 23): then x + u rounds below x + 1 for
 * every x < 2^n, so the point stays inside the chosen leaf. */
inline void leaf_point(const uint x, const uint y, const int n_levels, float *ux, float *uy)
{
    const float inv = 1.0f / (float)(1u << n_levels);
    const float top = 1.0f - 0x1p-23f * (float)(1u << n_levels);
    *ux = ((float)x + (as_uint(*ux) < as_uint(top) ? *ux : top)) * inv;   /* (as choose_child) */
    *uy = ((float)y + (*uy < top ? *uy : top)) * inv;
}

/* One sample walks the tree (N_LEVELS levels below the root) from the root to a leaf:
 * (ux, uy) is its uniform point on entry and its point of the unit square on return;
 * returns its density there (eq. 19-20). One walk per work-item, scalar types only,
 * and the depth a compile-time constant (-DN_LEVELS, set by the host per tree): the
 * level loop unrolls and PoCL vectorises the work-item loop, 8 walks per AVX
 * instruction with gathers (measured 1.4-1.6x over interleaving 8 walks in one
 * work-item). */
#ifdef N_LEVELS
__attribute__((always_inline)) inline float tree_walk(__global const float *tree, float *ux, float *uy)
{
    const int n_levels = N_LEVELS;
    uint x = 0, y = 0;
    *ux = clamp_unit(*ux);
    *uy = clamp_unit(*uy);
#pragma unroll
    for (int l = 0; l < N_LEVELS; ++l) {
        const uint cside = 2u << l;
        __global const float *c = tree + node_index(l + 1, 2 * x, 2 * y);
        choose_child(c[0], c[1], c[cside], c[cside + 1], ux, uy, &x, &y);
    }
    leaf_point(x, y, n_levels, ux, uy);
    const uint side = 1u << n_levels;
    const float root = tree[0], leaf = tree[node_index(n_levels, x, y)];
    return (root > 0.0f) ? leaf / root * (float)side * (float)side : 0.0f;
}
#endif
#endif
