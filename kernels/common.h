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
 * one 16-byte load from one cache line (row-major levels put the two pairs a row
 * apart, two lines) and carries its node's index down as 4k + child. Measured on the
 * product walk at 1024^2 (interleaved runs, bit-identical samples): +8 to +25%. The
 * host keeps trees row-major (y 2^l + x; wavlight.distributions.device_order converts).
 */
#ifndef WAVLIGHT_COMMON_H
#define WAVLIGHT_COMMON_H

#define LEVEL_OFFSET(l) ((((1ul) << (2 * (l))) - 1ul) / 3ul)

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
