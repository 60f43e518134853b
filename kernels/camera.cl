/* Pinhole camera rays through jittered points of the pixels (box filter), for one
 * pass of a tile: ray r = p k + j is sample j of pixel p of the w-pixel-wide tile
 * whose top-left pixel is (x0, y0) (pixel-major, row 0 of the image at the top).
 * Its jitter is words 0 and 1 of Philox stream RNG_JITTER at sample index first + r
 * of tile `tile` (rng.h); with `stratified` (the stratified sampler) moved into cell
 * permute_index(j, ...) of the pixel's grid, the order keyed by word 0 of stream
 * RNG_STRATA at index first + p (stratify_pair). Image-plane point x = (px + jx) sx - ox,
 * y = oy - (py + jy) sy; direction = normalize(fwd + x right + y up), written as
 * rows of 3 floats. numpy twin: wavlight.camera.camera_rays with
 * wavlight.rng.Stream's JITTER numbers. */
#include "rng.h"

__kernel void camera_rays(const int x0, const int y0, const uint w, const uint k, const uint count,
                          const uint first, const uint tile, const uint k0, const uint k1, const int stratified,
                          const float fx, const float fy, const float fz, const float rx, const float ry,
                          const float rz, const float ux, const float uy, const float uz,
                          const float sx, const float sy, const float ox, const float oy,
                          __global float *dirs_out)
{
    const uint base = LANE_BASE();
    if (base >= count) return;
    const uintv r = LANE_IDS + base;
    realv jx, jy, unused0, unused1;
    rng_uniforms(first + r, tile, RNG_JITTER, k0, k1, &jx, &jy, &unused0, &unused1);
    uintv j;
    const uintv pixel = div_small(r, k, &j);   /* (count < 2^22: wavlight.camera.MAX_PASS_RAYS) */
    if (stratified) {
        uintv key, unused2, unused3, unused4;
        philox4x32_10(first + pixel, (uintv)tile, (uintv)RNG_STRATA, (uintv)0u, k0, k1, &key, &unused2, &unused3,
                      &unused4);
        stratify_pair(&jx, &jy, j, k, key);
    }
    const realv px = convert_realv(as_intv(pixel % w) + x0), py = convert_realv(as_intv(pixel / w) + y0);
    const realv x = (px + jx) * sx - ox, y = oy - (py + jy) * sy;
    const realv dx = fx + x * rx + y * ux, dy = fy + x * ry + y * uy, dz = fz + x * rz + y * uz;
    const realv len = sqrt(dx * dx + dy * dy + dz * dz);
    const realv nx = dx / len, ny = dy / len, nz = dz / len;
    for (uint l = 0; l < LANES && base + l < count; ++l) {
        __global float *row = dirs_out + 3 * (base + l);
        row[0] = nx[l];
        row[1] = ny[l];
        row[2] = nz[l];
    }
}
