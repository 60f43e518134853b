/* Relighting from precomputed transfer (Chen & Gao sec. 2.2, eq. 6-8): the bake's texel
 * rays and the frame's sparse product of transfer and lighting coefficients.
 * numpy twins: wavlight/relight/bake.py (texel_rays_reference), wavlight/relight/frame.py
 * (product_reference). */
#include "rng.h"
#include "bsdf.h"

/* Pair g = p 4^n + t of a tile (pixel p, texel t = row 2^n + col of the world-frame lat-long
 * square); eight pairs per work-item, all of one pixel (4^n is a multiple of eight). The
 * pixel's camera samples come as groups (the samples on one triangle: one normal and
 * material; wavlight/relight/bake.py): group j of pixel p at p S + j, of count[p] groups,
 * with its normal, mean view direction wo, material, weight c_j = (sum of its samples' albedo
 * ratios) / S and its members (sample indices members[first_j .. first_j + size_j - 1]).
 * The texel gets Q = TEXEL_POINTS points, g x g strata (g = 1, 2 or 4) uniform in solid angle
 * (u from col, cos theta from row) at one jitter (u0, u1) of Philox stream RNG_TEXEL at pair index first + g of tile
 * `tile`; f_jq = c_j f cos(point q; group j). One (j, q) is picked with probability
 * f_jq / sum f (reservoir sampling, step k's uniform step_uniform(key, k), key u2's 24 bits), and the
 * shadow ray goes from a member of group j chosen by u3 towards point q, with
 * weight = Omega_t sum f / Q: weight x V is an unbiased estimate of the pixel's mean over
 * its samples of the texel's Q-point quadrature of f cos V, exact where V is the same over
 * the texel and the pixel. A texel the BRDF does not reach gets weight 0 (no ray). */
#ifndef TEXEL_POINTS
#define TEXEL_POINTS 4   /* 16: 4 x 4 strata; 4: 2 x 2; 1: one point over the whole texel */
#endif
#define TEXEL_GRID (TEXEL_POINTS == 16 ? 4 : (TEXEL_POINTS == 4 ? 2 : 1))
__kernel void bake_texel_rays(const uint count, const uint first, const uint n_levels, const uint samples,
                              const uint tile, const uint k0, const uint k1, __global const uint *group_count,
                              __global const float *normal, __global const float *wo,
                              __global const int *kind, __global const float *param,
                              __global const float *weight, __global const uint *group_first,
                              __global const uint *group_size, __global const uint *members,
                              __global float *dir_out, __global float *weight_out, __global uint *pick_out)
{
    const uint base = LANE_BASE();
    if (base >= count) return;
    const uintv gidx = LANE_INDEX(count);
    const uint side = 1u << n_levels;
    const uint p = base >> (2u * n_levels);            /* one pixel for all lanes */
    const uintv t = gidx & (side * side - 1u);
    const uintv row = t >> n_levels, col = t & (side - 1u);
    realv u0, u1, u2, u3;
    rng_uniforms(first + gidx, tile, RNG_TEXEL, k0, k1, &u0, &u1, &u2, &u3);
    const realv inv = 1.0f / (float)side;
    realv st0, z0, st1, z1;
    fast_sincos(PI_F * convert_realv(row) * inv, &st0, &z0);
    fast_sincos(PI_F * convert_realv(row + 1u) * inv, &st1, &z1);
    realv dx[TEXEL_POINTS], dy[TEXEL_POINTS], dz[TEXEL_POINTS];
    for (int q = 0; q < TEXEL_POINTS; ++q) {
        const realv uu = (convert_realv(col) + ((float)(q % TEXEL_GRID) + u0) * (1.0f / TEXEL_GRID)) * inv;
        const realv zz = z0 + ((float)(q / TEXEL_GRID) + u1) * (1.0f / TEXEL_GRID) * (z1 - z0);
        const realv sn = sqrt(fmax(1.0f - zz * zz, 0.0f));
        realv sp, cp;
        fast_sincos(2.0f * PI_F * uu, &sp, &cp);
        dx[q] = sp * sn;
        dy[q] = zz;
        dz[q] = -cp * sn;
    }
    realv total = 0.0f, px = dx[0], py = dy[0], pz = dz[0];
    const uintv key = convert_uintv(u2 * 16777216.0f);
    uint step = 0u;
    uintv picked = (uintv)(p * samples);
    const uint groups = group_count[p];
    for (uint j = 0; j < groups; ++j) {
        const uint gj = p * samples + j;
        const float nx = normal[3 * gj], ny = normal[3 * gj + 1], nz = normal[3 * gj + 2];
        const float wx = wo[3 * gj], wy = wo[3 * gj + 1], wz = wo[3 * gj + 2];
        realv sx, sy, sz, tx, ty, tz;
        make_frame((realv)nx, (realv)ny, (realv)nz, &sx, &sy, &sz, &tx, &ty, &tz);
        const realv ox = wx * sx + wy * sy + wz * sz, oy = wx * tx + wy * ty + wz * tz;
        const realv oz = (realv)(wx * nx + wy * ny + wz * nz);
        const int kd = kind[gj];
        const realv pa = (realv)param[gj];
        const float c = weight[gj];
        realv ix[TEXEL_POINTS], iy[TEXEL_POINTS], iz[TEXEL_POINTS];
        intv above = (intv)0;
        for (int q = 0; q < TEXEL_POINTS; ++q) {
            ix[q] = dx[q] * sx + dy[q] * sy + dz[q] * sz;
            iy[q] = dx[q] * tx + dy[q] * ty + dz[q] * tz;
            iz[q] = dx[q] * nx + dy[q] * ny + dz[q] * nz;
            above |= iz[q] > 0.0f;
        }
        if (!any(above)) {           /* the texel lies below this group's horizon: f = 0 */
            step += TEXEL_POINTS;    /* step k stays item j Q + q, as in the twin */
            continue;
        }
        for (int q = 0; q < TEXEL_POINTS; ++q) {
            realv fv = 0.0f, unused;
            /* the group's one material kind, as a constant: each branch keeps that BRDF alone */
#if HAS_KIND(BSDF_LAMBERT)
            if (kd == BSDF_LAMBERT) bsdf_eval_pdf((intv)BSDF_LAMBERT, pa, ix[q], iy[q], iz[q], ox, oy, oz, &fv, &unused);
#endif
#if HAS_KIND(BSDF_PHONG)
            if (kd == BSDF_PHONG) bsdf_eval_pdf((intv)BSDF_PHONG, pa, ix[q], iy[q], iz[q], ox, oy, oz, &fv, &unused);
#endif
#if HAS_KIND(BSDF_GGX)
            if (kd == BSDF_GGX) bsdf_eval_pdf((intv)BSDF_GGX, pa, ix[q], iy[q], iz[q], ox, oy, oz, &fv, &unused);
#endif
            fv = select(fv * c, (realv)0.0f, !(fv > 0.0f));
            /* reservoir step: take (j, q) with probability fv / (total + fv) */
            const realv grown = total + fv;
            const intv take = step_uniform(key, step++) * grown < fv;
            px = select(px, dx[q], take);
            py = select(py, dy[q], take);
            pz = select(pz, dz[q], take);
            picked = select(picked, (uintv)gj, take);
            total = grown;
        }
    }
    /* a member of the picked group, by u3: its sample's origin starts the shadow ray */
    uintv sample;
    for (uint l = 0; l < LANES; ++l) {
        const uint gj = picked[l];
        const uint size = max(group_size[gj], 1u);
        const uint k = min((uint)(u3[l] * (float)size), size - 1u);
        sample[l] = members[p * samples + group_first[gj] + k];
    }
    const realv omega = (z0 - z1) * (2.0f * PI_F) * inv;
    const realv w = select((realv)0.0f, omega * total * (1.0f / TEXEL_POINTS), total > 0.0f);
    for (uint l = 0; l < LANES && base + l < count; ++l) {
        __global float *d = dir_out + 3 * (base + l);
        d[0] = px[l];
        d[1] = py[l];
        d[2] = pz[l];
        weight_out[base + l] = w[l];
        pick_out[base + l] = sample[l];
    }
}

/* The sparse product of a frame (wavlight/relight/frame.py): for the K kept lighting
 * coefficients c_k with weights L_k (RGB times N^2, a pad), block b's pixels sum
 * q_o scale_o L_k over the k whose entry o = offsets[c_k, b] exists (>= 0); entry o is the row
 * data[o] of QBITS-bit coefficients of the block's PIXELS pixels. One work-item takes
 * TILE_BLOCKS consecutive blocks and keeps their sums in private memory while it walks the K
 * coefficients (one row of the offset table each), eight pixels to a vector. The output is
 * three planes (channel, block, pixel). */
#ifndef QBITS
#define QBITS 8
#endif
#ifndef PIXELS
#define PIXELS 256
#endif
#ifndef TILE_BLOCKS
#define TILE_BLOCKS 4
#endif
#if QBITS == 8
#define QTYPE char
#define QTYPE8 char8
#else
#define QTYPE short
#define QTYPE8 short8
#endif
#if INLINE_BUILTINS
/* a vector load and conversion without the library's out-of-line calls (kernels/simd.h); entry
 * rows and the eight-pixel offsets inside them keep the vector's alignment */
#define QLOAD8(p) __builtin_convertvector(*(__global const QTYPE8 *)(p), float8)
#else
#define QLOAD8(p) convert_float8(vload8(0, (p)))
#endif
#define VECTORS (PIXELS / 8)

__kernel void frame_product(const uint n_terms, const uint n_blocks, __global const int *columns,
                            __global const float4 *light, __global const int *offsets,
                            __global const float *scale, __global const QTYPE *data, __global float *out)
{
    const uint b0 = get_global_id(0) * TILE_BLOCKS;
    if (b0 >= n_blocks) return;
    const uint tiles = min((uint)TILE_BLOCKS, n_blocks - b0);
    float8 acc[TILE_BLOCKS * 3 * VECTORS];
    for (uint j = 0; j < TILE_BLOCKS * 3 * VECTORS; ++j) acc[j] = (float8)0.0f;
    for (uint k = 0; k < n_terms; ++k) {
        __global const int *row = offsets + (size_t)columns[k] * n_blocks + b0;
        const float4 L = light[k];
        for (uint j = 0; j < tiles; ++j) {
            const int o = row[j];
            if (o < 0) continue;
            const float s = scale[o];
            const float lr = L.x * s, lg = L.y * s, lb = L.z * s;
            __global const QTYPE *q = data + (size_t)o * PIXELS;
            float8 *a = acc + j * 3 * VECTORS;
            for (uint v = 0; v < VECTORS; ++v) {
                const float8 x = QLOAD8(q + 8 * v);
                a[v] += x * lr;
                a[VECTORS + v] += x * lg;
                a[2 * VECTORS + v] += x * lb;
            }
        }
    }
    const size_t plane = (size_t)n_blocks * PIXELS;
    for (uint j = 0; j < tiles; ++j)
        for (uint c = 0; c < 3; ++c)
            for (uint v = 0; v < VECTORS; ++v)
                vstore8(acc[(j * 3 + c) * VECTORS + v], 0, out + c * plane + (size_t)(b0 + j) * PIXELS + 8 * v);
}

/* The environment seen where a frame's pixels' camera samples miss: background pixel i's
 * samples s with bit s of mask[i] set, each at its direction's u0 (u at rotate_y = 0) and map
 * row (v does not turn about +Y), float32 as the host computed them; the map turned by
 * rotate_y has the sample at u = frac(u0 + shift), shift = rotate_y / 360, column floor(u W)
 * (nearest texel, as Environment.eval); out[i] = (1 / samples) times the sum of those texels.
 * Eight pixels per work-item. numpy twin: wavlight/relight/frame.py background_reference. */
__kernel void frame_background(const uint count, const uint samples, const int env_w, const float shift,
                               __global const ulong *mask, __global const float *u0, __global const int *row,
                               __global const float *env, __global float *out)
{
    const uint base = LANE_BASE();
    if (base >= count) return;
    const uintv i = LANE_INDEX(count);
    uintv lo = 0u, hi = 0u;
    for (uint l = 0; l < LANES; ++l) {
        const ulong bits = mask[i[l]];
        lo[l] = (uint)bits;
        hi[l] = (uint)(bits >> 32);
    }
    realv r = 0.0f, g = 0.0f, b = 0.0f;
    for (uint s = 0; s < samples; ++s) {
        const uintv bit = (s < 32u ? (lo >> s) : (hi >> (s - 32u))) & 1u;
        const uintv at = i * samples + s;
        realv u = GATHER(u0, at) + shift;
        u = u - floor(u);
        const intv col = min(convert_intv(u * (float)env_w), env_w - 1);
        const uintv tex = 3u * as_uintv(GATHER_T(intv, row, at) * env_w + col);
        const intv use = as_intv(bit) != 0;
        r += select((realv)0.0f, GATHER(env, tex), use);
        g += select((realv)0.0f, GATHER(env, tex + 1u), use);
        b += select((realv)0.0f, GATHER(env, tex + 2u), use);
    }
    const float inv = 1.0f / (float)samples;
    for (uint l = 0; l < LANES && base + l < count; ++l) {
        out[3 * (base + l)] = r[l] * inv;
        out[3 * (base + l) + 1] = g[l] * inv;
        out[3 * (base + l) + 2] = b[l] * inv;
    }
}
