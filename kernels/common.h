/* Shared definitions for wavlight's OpenCL kernels.
 *
 * Sampling trees ("scaling-coefficient pyramids", Chen & Gao sec. 4.3) are stored
 * as box masses: node (l, x, y) holds the integral of the function over its square
 * of side 2^-l, i.e. F(s) A(s) = 2^-l F^0_{l,t} (eq. 17). Level l has 4^l nodes in
 * row-major order (y * 2^l + x) starting at LEVEL_OFFSET(l) = (4^l - 1) / 3; a tree
 * with leaf level n holds (4^(n+1) - 1) / 3 floats. Many trees of one size sit one
 * after another, tree_stride floats apart.
 */
#ifndef WAVLIGHT_COMMON_H
#define WAVLIGHT_COMMON_H

#define LEVEL_OFFSET(l) ((((1ul) << (2 * (l))) - 1ul) / 3ul)

/* Largest float below 1: uniform variates are clamped to [0, ONE_MINUS_EPS]. */
#define ONE_MINUS_EPS 0x1.fffffep-1f

#endif
