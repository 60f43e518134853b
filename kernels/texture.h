/* Base-colour textures: a hit's texture coordinates from its face's three vertex
 * coordinates and embree's barycentric (u, v), and the bilinear lookup with repeat in the
 * scene's one buffer of texels (rows of r, g, b, 0; a table of first texel, width, height,
 * 0 per texture). v = 0 is the image's bottom row (OpenGL's convention, trimesh's loaders').
 * numpy twin: wavlight/textures.py (hit_uv, lookup). */
#ifndef WAVLIGHT_TEXTURE_H
#define WAVLIGHT_TEXTURE_H
#include "simd.h"

/* uv = (1 - bu - bv) uv0 + bu uv1 + bv uv2 of faces f (face_uv: rows of 6 floats). */
INLINE void texture_uv(__global const float *face_uv, const uintv f, const realv bu, const realv bv,
                       realv *u, realv *v)
{
    realv u0, v0, u1, v1, u2, v2;
    GATHER2(face_uv, 6 * f, &u0, &v0);
    GATHER2(face_uv, 6 * f + 2, &u1, &v1);
    GATHER2(face_uv, 6 * f + 4, &u2, &v2);
    const realv w0 = 1.0f - bu - bv;
    *u = w0 * u0 + bu * u1 + bv * u2;
    *v = w0 * v0 + bu * v1 + bv * v2;
}

/* First texel index, next index (both modulo n) and the next one's weight at coordinate x
 * (texel units) on a repeating axis of n texels. */
INLINE void texture_wrap(const realv x, const intv n, intv *i0, intv *i1, realv *frac)
{
    const realv nf = convert_realv(n);
    const realv xr = x - nf * floor(x / nf);
    const realv x0 = floor(xr);
    *frac = clamp(xr - x0, 0.0f, 1.0f);
    intv i = convert_intv(clamp(select(x0, (realv)0.0f, x0 != x0), -1073741824.0f, 1073741824.0f));
    i = select(i, i - n, i >= n);
    i = select(i, i + n, i < 0);
    i = min(max(i, 0), n - 1);
    *i0 = i;
    *i1 = select(i + 1, (intv)0, i + 1 >= n);
}

/* The bilinear, repeating lookup of texture tex (-1: none, giving 1) at (u, v). */
INLINE void texture_rgb(__global const float *atlas, __global const int *table, const intv tex,
                        const realv u, const realv v, realv *r, realv *g, realv *b)
{
    const intv has = tex >= 0;
    const uintv row = as_uintv(4 * max(tex, 0));
    const intv first = GATHER_INT(table, row), w = GATHER_INT(table, row + 1), h = GATHER_INT(table, row + 2);
    intv x0, x1, y0, y1;
    realv fx, fy, unused;
    texture_wrap(u * convert_realv(w) - 0.5f, w, &x0, &x1, &fx);
    texture_wrap((1.0f - v) * convert_realv(h) - 0.5f, h, &y0, &y1, &fy);
    realv r00, g00, b00, r01, g01, b01, r10, g10, b10, r11, g11, b11;
    GATHER4(atlas, as_uintv(4 * (first + y0 * w + x0)), &r00, &g00, &b00, &unused);
    GATHER4(atlas, as_uintv(4 * (first + y0 * w + x1)), &r01, &g01, &b01, &unused);
    GATHER4(atlas, as_uintv(4 * (first + y1 * w + x0)), &r10, &g10, &b10, &unused);
    GATHER4(atlas, as_uintv(4 * (first + y1 * w + x1)), &r11, &g11, &b11, &unused);
    const realv gx = 1.0f - fx, gy = 1.0f - fy;
    *r = select((realv)1.0f, gy * (gx * r00 + fx * r01) + fy * (gx * r10 + fx * r11), has);
    *g = select((realv)1.0f, gy * (gx * g00 + fx * g01) + fy * (gx * g10 + fx * g11), has);
    *b = select((realv)1.0f, gy * (gx * b00 + fx * b01) + fy * (gx * b10 + fx * b11), has);
}

/* The base colour of material mat's texture at the hit of lanes' faces f, at embree's
 * barycentrics (bary: rows of (u, v), row i): 1 where the material has no texture. */
INLINE void texture_at_hit(__global const float *face_uv, __global const float *atlas, __global const int *table,
                           __global const int *mat_texture, __global const float *bary, const uintv i,
                           const uintv f, const intv mat, realv *r, realv *g, realv *b)
{
    realv bu, bv, tu, tv;
    GATHER2(bary, 2 * i, &bu, &bv);
    texture_uv(face_uv, f, bu, bv, &tu, &tv);
    texture_rgb(atlas, table, GATHER_INT(mat_texture, mat), tu, tv, r, g, b);
}

/* A hit's albedo: material mat's row of mat_albedo (rows of r, g, b, 0), with ``textured`` (the
 * program's TEXTURES, folded by the compiler) times its texture there (texture_at_hit; numpy twin
 * Scene.albedo_at). */
INLINE void albedo_at_hit(__global const float *mat_albedo, const int textured, __global const float *face_uv,
                          __global const float *atlas, __global const int *table, __global const int *mat_texture,
                          __global const float *bary, const uintv i, const uintv f, const intv mat, realv *r,
                          realv *g, realv *b)
{
    realv unused;
    GATHER4(mat_albedo, 4 * as_uintv(mat), r, g, b, &unused);
    if (textured) {
        realv tr, tg, tb;
        texture_at_hit(face_uv, atlas, table, mat_texture, bary, i, f, mat, &tr, &tg, &tb);
        *r *= tr;
        *g *= tg;
        *b *= tb;
    }
}
#endif
