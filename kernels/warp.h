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
#include "simd.h"

/* Index of nodes (x, y) of `level` in a tree (common.h layout: Morton order), per lane. */
INLINE uintv node_index(const int level, const uintv x, const uintv y)
{
    uintv sx, sy;
    SPREAD_BITS_INTO(sx, x);
    SPREAD_BITS_INTO(sy, y);
    return (uint)LEVEL_OFFSET(level) + (sx | (sy << 1));
}

/* The index within its level of the child of node k picked by choose_child, which left
 * (x, y) at the child's coordinates: children 4k .. 4k + 3 (common.h). */
INLINE uintv child_index(const uintv k, const uintv x, const uintv y)
{
    return 4 * k + (x & 1u) + 2 * (y & 1u);
}

/* Column (or row) of the leaf of a 2^n grid holding coordinate u of the square, per lane. */
INLINE uintv leaf_of(const realv u, const int n_levels)
{
    return as_uintv(clamp(convert_intv(floor(u * (float)(1u << n_levels))), 0, (1 << n_levels) - 1));
}

/* Density on the unit square of the walk (eq. 19-20) at points (u, v), per lane in the
 * tree at tree_base: m_leaf / m_root * 4^n. */
INLINE realv tree_pdf(__global const float *tree, const uintv tree_base, const int n_levels,
                      const realv u, const realv v)
{
    const float side = (float)(1u << n_levels);
    const realv root = GATHER(tree, tree_base);
    const realv leaf = GATHER(tree, tree_base + node_index(n_levels, leaf_of(u, n_levels), leaf_of(v, n_levels)));
    return select((realv)0.0f, leaf / root * side * side, root > 0.0f);
}

/* One step of eight walks (simd.h lanes): pick one of the four children of nodes
 * (x, y) with masses m00 m10 (top row) m01 m11 (bottom row), first the row pair then
 * the column, rescaling (ux, uy); (x, y) becomes the child. Returns the child's
 * conditional probability m_child / (m00 + m10 + m01 + m11) (eq. 21-22). Branch-free:
 * u < top / (top + bottom) is compared as u (top + bottom) < top, without a division;
 * no fused multiply-add (the numpy twin, haar.tree.choose_child_reference, rounds
 * u * sum and the subtraction apart, and tests compare the two bit for bit). A side or
 * child of zero mass is never picked (u * sum rounding up to a denormal mass could
 * otherwise pick it: right is compared by its bits, right >= +0). u past 1 - eps (or
 * NaN, a zero-mass pair) is clamped to 1 - eps. */
INLINE realv choose_child(const realv m00, const realv m10, const realv m01, const realv m11,
                           realv *ux, realv *uy, uintv *px, uintv *py)
{
#pragma OPENCL FP_CONTRACT OFF
    const realv top = m00 + m10, bottom = m01 + m11, s_row = top + bottom;
    const intv b = !(*uy * s_row < top) & (bottom > 0.0f);
    const realv row = select(top, bottom, b);
    const realv left = select(m00, m01, b), right = select(m10, m11, b), s_col = left + right;
    const intv r = !(*ux * s_col < left) & (as_intv(right) != 0);
    const realv col = select(left, right, r);
    const realv ny = (*uy * s_row - select((realv)0.0f, top, b)) / row;
    const realv nx = (*ux * s_col - select((realv)0.0f, left, r)) / col;
    *py = 2 * *py + select((uintv)0, (uintv)1, b);
    *px = 2 * *px + select((uintv)0, (uintv)1, r);
    *uy = select((realv)ONE_MINUS_EPS, ny, ny < ONE_MINUS_EPS);   /* NaN -> 1 - eps */
    *ux = select((realv)ONE_MINUS_EPS, nx, nx < ONE_MINUS_EPS);
    return (row / s_row) * (col / s_col);   /* (row col) / (s_row s_col) overflows past ~1e19 */
}

/* u in [0, 1) clamped to the largest float below 1 (NaN -> 0), per lane. */
INLINE realv clamp_unit(const realv u)
{
    return select((realv)0.0f, select((realv)ONE_MINUS_EPS, u, u < ONE_MINUS_EPS), u > 0.0f);
}

/* The points of the unit square at offsets (ux, uy) inside leaves (x, y) of a 2^n grid.
 * The offsets are first clamped to 1 - 2^(n - 23): then x + u rounds below x + 1 for
 * every x < 2^n, so each point stays inside its leaf. (x compares the bits, y the
 * floats, as numpy's twin haar.tree.leaf_point does.) */
INLINE void leaf_point(const uintv x, const uintv y, const int n_levels, realv *ux, realv *uy)
{
    const float inv = 1.0f / (float)(1u << n_levels);
    const float top = 1.0f - 0x1p-23f * (float)(1u << n_levels);
    *ux = (convert_realv(x) + select((realv)top, *ux, as_uintv(*ux) < as_uint(top))) * inv;
    *uy = (convert_realv(y) + select((realv)top, *uy, *uy < top)) * inv;
}

/* Breadth-first walks through big trees. A walk is a chain of dependent loads, one per
 * level: each level's loads wait for the previous level's choice, and a work-item's walk
 * is too long for the CPU to reach the next work-item's independent loads while it waits.
 * Levels of 512^2 nodes and more (1 MB, past a core's L2 cache) miss the caches. In a
 * stand-alone sample kernel (warp.cl, product.cl, which define WALK_BARRIERS 1; their
 * walking kernels have no early return) a work-group barrier before each step into
 * such a level makes PoCL run that step for all work-items of the group before the
 * next, so the loads of the group's
 * work-items are in flight together. Measured in groups of 64 (benchmarks/kernel_ab.py):
 * 0 to +45% at 1024^2 and 2048^2 in interleaved runs (light and product walks; this VM's
 * noise is +-20%; benchmarks/sample_bench.py: -11 to +35%), while barriers at the cached
 * levels cost up to 20% (the live values go through memory at each barrier), so that in
 * groups of 64 the barriers pay from level 9 (512^2 nodes) on.
 * With work-groups of 32 (wavlight.cl.WALK_WORK_GROUP, whose live values then stay in
 * the cache) level 8 measures better (benchmarks/kernel_ab.py, eight alternated runs each): against
 * level 9 with groups of 64, light walk 2048^2 55.2 -> 59.4 M/s, 1024^2 69.9 -> 74.6; product
 * walks at 2048^2 lambert 31.1 -> 34.9, phong 200 18.5 -> 21.1, ggx 0.2 20.1 -> 22.3,
 * ggx 0.05 22.1 -> 22.8, at 1024^2 +5 to +14%, at 256^2 and 64^2 within 2%
 * (benchmarks/kernel_ab.py). (Level 8 with groups of 64 made ggx 0.05 at 2048^2 33%
 * slower.) A
 * barrier is only legal where every work-item of the group reaches it, so the renderer's shade kernels (walks inside per-lane branches) do
 * without. */
#if defined(WALK_BARRIERS) && WALK_BARRIERS
#ifndef BARRIER_LEVEL
#define BARRIER_LEVEL 8   /* the first level (256^2 nodes) whose step waits at a barrier */
#endif
#define LEVEL_BARRIER(l) do { if ((l) + 1 >= BARRIER_LEVEL) barrier(CLK_LOCAL_MEM_FENCE); } while (0)
/* The step into level l + 1 also prefetches the children of the node it picked when the
 * next step waits at a barrier: the other work-items' steps run before they are read.
 * Measured at 1024^2 and 2048^2 (interleaved runs): lambert product walk +6 to +23%,
 * glossy ones -6 to +14%, within this VM's noise. */
#ifndef WALK_PREFETCH
#define WALK_PREFETCH 1
#endif
/* PREFETCH_STEP(tree, base, next, k, f): what the step at level `next` will read for the
 * nodes k of that level: their four children, or, where that step is a pair (pairs from
 * level f, below), their sixteen grandchildren's line. */
#define PREFETCH_STEP(tree, base, next, k, f)                                                 \
    do {                                                                                      \
        if (WALK_PREFETCH && (next) + 1 >= BARRIER_LEVEL && (next) + 1 <= N_LEVELS) {          \
            uintv pf_at_;                                                                     \
            if (PAIRED_FIRST((next), (f)))                                                    \
                pf_at_ = (base) + (uint)LEVEL_OFFSET((next) + 2) + 16 * (k);                  \
            else                                                                              \
                pf_at_ = (base) + (uint)LEVEL_OFFSET((next) + 1) + 4 * (k);                   \
            PREFETCH_LANES(tree, pf_at_);                                                     \
        }                                                                                     \
    } while (0)
#else
#define LEVEL_BARRIER(l) do { } while (0)
#define PREFETCH_STEP(tree, base, next, k, f) do { } while (0)
#endif

/* Eight samples walk the tree (N_LEVELS levels below the root, a compile-time constant
 * set by the host per tree, so the level loop unrolls) from the root to a leaf, one
 * per lane, lane k in the tree at tree_base[k]: (ux, uy) is the uniform point on entry
 * and the point of the unit square on return; returns the density there (eq. 19-20).
 * Written 8-wide (simd.h): 4x the speed of one scalar walk per work-item on an AVX2
 * CPU (12.3 -> 48.9 M samples/s at 1024^2), where PoCL does not vectorise the scalar
 * walk itself. */
#ifdef N_LEVELS
/* Paired steps through the deep levels of a mass tree: from about level PAIR_LEVEL on (and,
 * in the product walk, below its product levels) one step reads the node's sixteen
 * grandchildren, one cache line (common.h, TREE_ORIGIN), and takes two levels: the
 * children's masses are the sums of their four children, in the order tree_reduce
 * (tree.cl) added them, so bit for bit the stored ones, and the walk's choices are
 * unchanged. One dependent load per two levels instead of two where they miss the caches.
 * The pairs end at the leaves (they start at the first level >= f of N_LEVELS' parity).
 * PAIRED_FIRST(l, f): level l starts a pair; PAIRED_SECOND(l, f): level l was taken by the
 * pair before it. Compile-time. Only in walks without level barriers, the renderer's: the
 * barriers and prefetches of the stand-alone kernels hide these loads better. Measured
 * against the same walks without pairs (three alternated runs of the kernels without
 * barriers, 2^21 random points, M samples/s): 2048^2 trees light walk 34.6-36.4 -> 39.6-41.8, phong 200
 * 14.5-15.1 -> 16.6-16.8, ggx 0.2 14.9-15.2 -> 18.7-19.0, ggx 0.05 15.7-16.3 -> 18.5-18.7;
 * 1024^2 (one pair, levels 8-9) light 60.9-61.6 -> 57.7-61.0, the product walks +4 to +7%;
 * with barriers they measure 5-35% slower, and -8 to +6% with the prefetch (PREFETCH_STEP)
 * aimed at the pairs' lines. */
#ifndef PAIR_LEVEL
#if defined(WALK_BARRIERS) && WALK_BARRIERS
#define PAIR_LEVEL 64   /* none */
#else
#define PAIR_LEVEL 7
#endif
#endif
#define PAIR_START(f) ((f) + ((N_LEVELS - (f)) & 1))
#define PAIRED_FIRST(l, f) ((l) >= PAIR_START(f) && ((l) - PAIR_START(f)) % 2 == 0 && (l) + 2 <= N_LEVELS)
#define PAIRED_SECOND(l, f) ((l) > PAIR_START(f) && ((l) - PAIR_START(f)) % 2 == 1)

/* Two steps of eight walks from the nodes of index k in `level` (see above). */
INLINE void paired_step(__global const float *tree, const uintv base, const int level, uintv *k, uintv *x,
                        uintv *y, realv *ux, realv *uy)
{
#pragma OPENCL FP_CONTRACT OFF
    const uintv g = base + (uint)LEVEL_OFFSET(level + 2) + 16 * *k;
    realv q[16];
    GATHER4(tree, g, &q[0], &q[1], &q[2], &q[3]);
    GATHER4(tree, g + 4, &q[4], &q[5], &q[6], &q[7]);
    GATHER4(tree, g + 8, &q[8], &q[9], &q[10], &q[11]);
    GATHER4(tree, g + 12, &q[12], &q[13], &q[14], &q[15]);
    choose_child((q[0] + q[1]) + (q[2] + q[3]), (q[4] + q[5]) + (q[6] + q[7]), (q[8] + q[9]) + (q[10] + q[11]),
                 (q[12] + q[13]) + (q[14] + q[15]), ux, uy, x, y);
    *k = child_index(*k, *x, *y);
    const intv right = as_intv(*k & 1u) != 0, bottom = as_intv(*k & 2u) != 0;
    realv o[4];
#pragma unroll
    for (int j = 0; j < 4; ++j)
        o[j] = select(select(q[j], q[4 + j], right), select(q[8 + j], q[12 + j], right), bottom);
    choose_child(o[0], o[1], o[2], o[3], ux, uy, x, y);
    *k = child_index(*k, *x, *y);
}

INLINE realv tree_walk(__global const float *tree, const uintv tree_base, realv *ux, realv *uy)
{
    uintv x = 0, y = 0, k = 0;   /* the node's coordinates and its index in its level */
    *ux = clamp_unit(*ux);
    *uy = clamp_unit(*uy);
#pragma unroll
    for (int l = 0; l < N_LEVELS; ++l) {
        if (PAIRED_SECOND(l, PAIR_LEVEL))
            continue;
        LEVEL_BARRIER(l);
        if (PAIRED_FIRST(l, PAIR_LEVEL)) {
            paired_step(tree, tree_base, l, &k, &x, &y, ux, uy);
            PREFETCH_STEP(tree, tree_base, l + 2, k, PAIR_LEVEL);
            continue;
        }
        realv m0, m1, m2, m3;
        GATHER4(tree, tree_base + (uint)LEVEL_OFFSET(l + 1) + 4 * k, &m0, &m1, &m2, &m3);
        choose_child(m0, m1, m2, m3, ux, uy, &x, &y);
        k = child_index(k, x, y);
        PREFETCH_STEP(tree, tree_base, l + 1, k, PAIR_LEVEL);
    }
    const float side = (float)(1u << N_LEVELS);
    const realv root = GATHER(tree, tree_base);
    const realv leaf = GATHER(tree, tree_base + (uint)LEVEL_OFFSET(N_LEVELS) + k);
    leaf_point(x, y, N_LEVELS, ux, uy);
    return select((realv)0.0f, leaf / root * side * side, root > 0.0f);
}
#endif
#endif
