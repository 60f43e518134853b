/* Building sampling trees bottom-up (Chen & Gao sec. 4.3, eq. 17-18).
 *
 * The mass of a parent square is the sum of its four children's masses; in
 * scaling coefficients this is F^0_{l,t} = (1/2) sum of the four F^0_{l+1,t'}
 * (the relation behind eq. 22). One launch per level, coarsest last, batched
 * over trees: global size (4^level, n_trees).
 */
#include "common.h"

__kernel void tree_reduce(__global float *tree, const ulong tree_stride, const int level)
{
    const ulong node = get_global_id(0);
    const ulong t = get_global_id(1);
    const uint side = 1u << level;
    const uint x = (uint)(node % side), y = (uint)(node / side);
    __global float *base = tree + t * tree_stride;
    __global const float *child = base + LEVEL_OFFSET(level + 1);
    const uint cside = side << 1;
    const uint c = (2 * y) * cside + 2 * x;
    base[LEVEL_OFFSET(level) + node] = (child[c] + child[c + 1]) + (child[c + cside] + child[c + cside + 1]);
}
