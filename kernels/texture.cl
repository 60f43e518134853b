/* texture.h batched, eight points per work-item: for tests against the numpy twins
 * (wavlight.textures.hit_uv, lookup). Per point: the face, embree's (bu, bv), the texture. */
#include "texture.h"

__kernel void texture_lookup(__global const float *face_uv, __global const int *face,
                             __global const float *bary, __global const int *tex, const uint count,
                             __global const float *atlas, __global const int *table,
                             __global float *uv_out, __global float *rgb_out)
{
    const uint base = LANE_BASE();
    if (base >= count) return;
    const uintv i = LANE_INDEX(count);
    realv bu, bv, u, v, r, g, b;
    GATHER2(bary, 2 * i, &bu, &bv);
    texture_uv(face_uv, as_uintv(GATHER_INT(face, i)), bu, bv, &u, &v);
    texture_rgb(atlas, table, GATHER_INT(tex, i), u, v, &r, &g, &b);
    STORE_LANES(u, uv_out, base, count);
    STORE_LANES(v, uv_out + count, base, count);
    STORE_LANES(r, rgb_out, base, count);
    STORE_LANES(g, rgb_out + count, base, count);
    STORE_LANES(b, rgb_out + 2 * count, base, count);
}
