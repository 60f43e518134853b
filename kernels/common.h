/* Shared definitions for wavlight's OpenCL kernels.
 *
 * Sampling trees ("scaling-coefficient pyramids", Chen & Gao sec. 4.3) are stored
 * as box masses: node (l, x, y) holds the integral of the function over its square
 * of side 2^-l, i.e. F(s) A(s) = 2^-l F^0_{l,t} (eq. 17). Level l has 4^l nodes
 * starting at LEVEL_OFFSET(l) = (4^l - 1) / 3; a tree with leaf level n holds
 * (4^(n+1) - 1) / 3 floats. Many trees of one size sit one after another, tree_stride
 * floats apart. On the device a level is in Morton (Z) order: node (x, y) at
 * morton_index(x, y), the bits of x at the even positions and those of y at the odd
 * ones, so the four children of node k of level l are nodes 4k .. 4k + 3 of level
 * l + 1 (top-left, top-right, bottom-left, bottom-right): a walk step reads them with
 * one 16-byte load, from one cache line three times in four (LEVEL_OFFSET(l) is 5 mod
 * 16 floats from level 2 on; row-major levels put the two pairs a row apart, always two
 * lines), and carries its node's index down as 4k + child, with no bit interleaving
 * per step. Measured against row-major walks (benchmarks/kernel_ab.py --against a revision
 * whose trees are row-major, interleaved, bit-identical samples): light
 * walk +9 / +37 / +32% at 256^2 / 1024^2 / 2048^2, product walks +5 to +21% / +11 to
 * +47% / +10 to +45%. The host keeps trees row-major (y 2^l + x):
 * wavlight.haar.tree.device_order / host_order convert, tree_load_leaves (tree.cl)
 * places the leaves.
 *
 * A light tree's node 0 sits TREE_ORIGIN = 11 floats into its place in the buffer, and
 * trees sit TREE_STRIDE(n) floats apart (a multiple of 16): as LEVEL_OFFSET(l) is 5 mod
 * 16 from level 2 on and OpenCL buffers are at least 64-byte aligned, every level from 2
 * on then starts on a 64-byte cache line, and a node's four children (one walk step) and
 * its sixteen grandchildren (the product walk's look-ahead) each lie in one line instead
 * of straddling two. Kernels that take a light tree add TREE_ORIGIN to its pointer on
 * entry. Measured with the product kernel on copies of one tree made alike but for the
 * origin (four alternated runs, bit-identical samples): 2048^2 trees +18 to +25% (phong 200
 * 14.7-15.8 -> 18.3-18.7 M/s, ggx 0.05 16.0-18.9 -> 18.4-23.1), 1024^2 ggx 0.05 +10%
 * (21.2-23.3 -> 25.3-25.7), phong 200 within noise; 256^2 no change. (An origin of 3,
 * which keeps the groups of four in one line but not the sixteen, measures close to 11;
 * for a walk without the look-ahead it measures no better than none.)
 */
#ifndef WAVLIGHT_COMMON_H
#define WAVLIGHT_COMMON_H

#define LEVEL_OFFSET(l) ((((1ul) << (2 * (l))) - 1ul) / 3ul)
#define TREE_ORIGIN 11
#define TREE_STRIDE(n) ((LEVEL_OFFSET((n) + 1) + TREE_ORIGIN + 15ul) & ~15ul)

/* Bits 0..15 of v moved to the even bit positions 0, 2, .., 30 (a macro so that it serves
 * uint and uint vectors alike; v is evaluated once, into t). */
#define SPREAD_BITS_INTO(t, v)                     \
    do {                                           \
        t = (v) & 0x0000ffffu;                     \
        t = (t | (t << 8)) & 0x00ff00ffu;          \
        t = (t | (t << 4)) & 0x0f0f0f0fu;          \
        t = (t | (t << 2)) & 0x33333333u;          \
        t = (t | (t << 1)) & 0x55555555u;          \
    } while (0)

/* Index of node (x, y) within its level on the device (Morton order, above). */
inline __attribute__((always_inline)) uint morton_index(const uint x, const uint y)
{
    uint sx, sy;
    SPREAD_BITS_INTO(sx, x);
    SPREAD_BITS_INTO(sy, y);
    return sx | (sy << 1);
}

/* Largest float below 1: uniform variates are clamped to [0, ONE_MINUS_EPS]. */
#define ONE_MINUS_EPS 0x1.fffffep-1f

#endif
