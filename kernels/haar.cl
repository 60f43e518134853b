/* Haar wavelet kernels (Chen & Gao sec. 4.1, 4.4, eq. 13, 17, 25); numpy twins in
 * wavlight/haar/, whose module notes fix the conventions.
 *
 * Coefficients use the dense in-place layout of a 2^n x 2^n array: [0][0] the
 * scaling coefficient, level l (s = 2^l) wavelets at [y][s+x] (m = 1, left - right),
 * [s+y][x] (m = 2, top - bottom), [s+y][s+x] (m = 3, diagonal). Pyramids are box
 * masses 2^-l F^0_{l,t} at the offsets of common.h: those of the transform row-major
 * within a level (y 2^l + x, the host's layout), the product trees for the warp in the
 * device's Morton order (morton_index).
 */
#include "common.h"

/* Forward transform, step 0: leaf masses = pixel * 4^-n. Global size (4^n, T). */
__kernel void haar_load_leaves(__global const float *images, __global float *pyr,
                               const ulong tree_stride, const int n)
{
    const ulong i = get_global_id(0), t = get_global_id(1);
    const ulong npix = 1ul << (2 * n);
    pyr[t * tree_stride + LEVEL_OFFSET(n) + i] = ldexp(images[t * npix + i], -2 * n);
}

/* Forward transform, one level (coarsest last): a node's mass is the sum of its
 * children's, its wavelet coefficients 2^l times signed sums of them (eq. 13, 17).
 * Global size (4^level, T). */
__kernel void haar_forward_level(__global float *pyr, const ulong tree_stride,
                                 __global float *coeffs, const int n, const int level)
{
    const uint node = get_global_id(0);
    const ulong t = get_global_id(1);
    const uint s = 1u << level, cs = 2u * s, side = 1u << n;
    const uint x = node & (s - 1), y = node >> level;
    __global float *base = pyr + t * tree_stride;
    __global const float *child = base + LEVEL_OFFSET(level + 1);
    const uint c = (2 * y) * cs + 2 * x;
    const float m00 = child[c], m01 = child[c + 1], m10 = child[c + cs], m11 = child[c + cs + 1];
    const float parent = (m00 + m01) + (m10 + m11);
    base[LEVEL_OFFSET(level) + node] = parent;
    const float scale = ldexp(1.0f, level);
    __global float *co = coeffs + t * side * side;
    co[y * side + s + x] = scale * ((m00 - m01) + (m10 - m11));
    co[(s + y) * side + x] = scale * ((m00 + m01) - (m10 + m11));
    co[(s + y) * side + s + x] = scale * ((m00 - m01) - (m10 - m11));
    if (level == 0)
        co[0] = parent;
}

/* Inverse transform, one level (coarsest first): the scaling coefficients F^0 of level
 * level + 1 from those of `level` (cur) and the level's three wavelets, written to nxt
 * times `scale` (1, and 2^n at the last level: pixel = 2^n F^0_n). cur and nxt hold a
 * tree's 2^l x 2^l scaling coefficients row-major at t * 4^n. Global size (4^level, T). */
__kernel void haar_inverse_level(__global const float *coeffs, __global const float *cur,
                                 __global float *nxt, const int n, const int level, const float scale)
{
    const uint node = get_global_id(0);
    const ulong t = get_global_id(1);
    const uint s = 1u << level, cs = 2u * s, side = 1u << n;
    const uint x = node & (s - 1), y = node >> level;
    __global const float *co = coeffs + t * side * side;
    const float a = cur[t * side * side + node];
    const float d1 = co[y * side + s + x], d2 = co[(s + y) * side + x], d3 = co[(s + y) * side + s + x];
    __global float *out = nxt + t * side * side + (2 * y) * cs + 2 * x;
    const float h = 0.5f * scale;
    out[0] = h * ((a + d1) + (d2 + d3));
    out[1] = h * ((a - d1) + (d2 - d3));
    out[cs] = h * ((a + d1) - (d2 + d3));
    out[cs + 1] = h * ((a - d1) - (d2 - d3));
}

/* Product pyramids of one shared G and T coefficient sets H (eq. 25), one work-group
 * per tree, global size (WG, T), local size (WG, 1):
 *   1. H's scaling coefficients top-down to level m (inverse transform steps), in local memory;
 *   2. leaf masses at level P >= m: G's mass times H's value 2^m H^0_m (H is constant there),
 *      which is eq. 25 at the leaves (no finer wavelets of H);
 *   3. parent = sum of the four children up to the root, which equals eq. 25 at every level
 *      and keeps the pyramid additive in float32, as the warp (warp.h) needs.
 * Levels 0..L (L <= P) are written to out + t * tree_stride in Morton order, the walks'
 * level order (common.h; node 0 at the tree's start, not at a light tree's TREE_ORIGIN). g_leaf holds G's 4^P masses at level P, row-major; each local buffer
 * holds 4^P floats, row-major. */
__kernel void haar_product_tree(__global const float *g_leaf, __global const float *h_coeffs,
                                const int m, const int P, const int L,
                                __global float *out, const ulong tree_stride, const ulong tree_origin,
                                const int nonnegative, __local float *buf_a, __local float *buf_b)
{
    const uint lid = get_local_id(0), wg = get_local_size(0);
    const ulong t = get_global_id(1);
    const uint hside = 1u << m;
    __global const float *h = h_coeffs + t * hside * hside;
    __global float *tree = out + tree_origin + t * tree_stride;   /* node 0 of tree t */
    __local float *cur = buf_a, *nxt = buf_b, *tmp;

    /* 1. H^0_l for l = 0..m */
    if (lid == 0)
        cur[0] = h[0];
    barrier(CLK_LOCAL_MEM_FENCE);
    for (int l = 0; l < m; ++l) {
        const uint s = 1u << l, cs = 2u * s;
        for (uint i = lid; i < s * s; i += wg) {
            const uint x = i & (s - 1), y = i >> l;
            const float a = cur[i];
            const float d1 = h[y * hside + s + x];
            const float d2 = h[(s + y) * hside + x];
            const float d3 = h[(s + y) * hside + s + x];
            const uint c = (2 * y) * cs + 2 * x;
            nxt[c] = 0.5f * ((a + d1) + (d2 + d3));
            nxt[c + 1] = 0.5f * ((a - d1) + (d2 - d3));
            nxt[c + cs] = 0.5f * ((a + d1) - (d2 + d3));
            nxt[c + cs + 1] = 0.5f * ((a - d1) - (d2 - d3));
        }
        barrier(CLK_LOCAL_MEM_FENCE);
        tmp = cur; cur = nxt; nxt = tmp;
    }

    /* 2. leaf masses at level P */
    const uint side = 1u << P;
    const int shift = P - m;
    const float hscale = (float)hside;
    for (uint i = lid; i < side * side; i += wg) {
        const uint x = i & (side - 1), y = i >> P;
        float v = g_leaf[i] * (cur[(y >> shift) * hside + (x >> shift)] * hscale);
        if (nonnegative)
            v = fmax(v, 0.0f);
        nxt[i] = v;
        if (P <= L)
            tree[LEVEL_OFFSET(P) + morton_index(x, y)] = v;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    tmp = cur; cur = nxt; nxt = tmp;

    /* 3. reduce to the root */
    for (int l = P - 1; l >= 0; --l) {
        const uint s = 1u << l, cs = 2u * s;
        for (uint i = lid; i < s * s; i += wg) {
            const uint x = i & (s - 1), y = i >> l;
            const uint c = (2 * y) * cs + 2 * x;
            const float v = (cur[c] + cur[c + 1]) + (cur[c + cs] + cur[c + cs + 1]);
            nxt[i] = v;
            if (l <= L)
                tree[LEVEL_OFFSET(l) + morton_index(x, y)] = v;
        }
        barrier(CLK_LOCAL_MEM_FENCE);
        tmp = cur; cur = nxt; nxt = tmp;
    }
}
