/* Building sampling trees bottom-up (Chen & Gao sec. 4.3, eq. 17-18).
 *
 * The mass of a parent square is the sum of its four children's masses; in
 * scaling coefficients this is F^0_{l,t} = (1/2) sum of the four F^0_{l+1,t'}
 * (the relation behind eq. 22). One launch per level, coarsest last, batched
 * over trees: global size (4^level, n_trees), after tree_load_leaves has put the leaves
 * in the device's Morton order (common.h; wavlight.haar.tree.HaarTree).
 */
#include "common.h"

/* The leaves of T row-major 2^n x 2^n images into their trees' level n, in Morton order.
 * Global size (4^n, T). */
__kernel void tree_load_leaves(__global float *tree, const ulong tree_stride, __global const float *leaves,
                               const int n)
{
    const uint i = get_global_id(0);
    const ulong t = get_global_id(1);
    const uint x = i & ((1u << n) - 1u), y = i >> n;
    tree += TREE_ORIGIN;   /* (common.h) */
    tree[t * tree_stride + LEVEL_OFFSET(n) + morton_index(x, y)] = leaves[(t << (2 * n)) + i];
}

__kernel void tree_reduce(__global float *tree, const ulong tree_stride, const int level)
{
    const ulong node = get_global_id(0);   /* its index in the level (Morton order, common.h) */
    const ulong t = get_global_id(1);
    __global float *base = tree + TREE_ORIGIN + t * tree_stride;
    __global const float *child = base + LEVEL_OFFSET(level + 1) + 4 * node;   /* 00 10 01 11 */
    base[LEVEL_OFFSET(level) + node] = (child[0] + child[1]) + (child[2] + child[3]);
}
