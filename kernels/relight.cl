/* Relighting from precomputed transfer (Chen & Gao sec. 2.2, eq. 6-8): the bake's texel
 * rays, the frame's sparse product of transfer and lighting coefficients and the environment
 * where the camera samples missed.
 * numpy twins: wavlight/relight/bake.py (texel_rays_reference), wavlight/relight/frame.py
 * (image_reference, background_reference, background_bilinear_reference). */
#include "rng.h"
#include "bsdf.h"

/* Pair g = p 4^n + t of a tile (pixel p, texel t = row 2^n + col of the world-frame lat-long
 * square); eight pairs per work-item, all of one pixel (4^n is a multiple of eight). The
 * pixel's camera samples come as groups (the samples on one flat triangle, or one sample on a
 * smooth face: one normal and material; wavlight/relight/bake.py): group j of pixel p at p S + j,
 * of count[p] groups, with its shading normal, geometric normal (f = 0 for directions below
 * it: docs/decisions/shading-normals.md), mean view direction wo, material, weight c_j = (sum of its samples' albedo
 * ratios) / S and its members (sample indices members[first_j .. first_j + size_j - 1]).
 * The texel gets Q = TEXEL_POINTS points, g x g strata (g = 1, 2 or 4) uniform in solid angle
 * (u from col, cos theta from row) at one jitter (u0, u1) of Philox stream RNG_TEXEL at pair index first + g of tile
 * `tile`; f_jq = c_j f cos(point q; group j). One (j, q) is picked with probability
 * f_jq / sum f (reservoir sampling, step k's uniform step_uniform(key, k), key u2's 24 bits), and the
 * shadow ray goes from a member of group j chosen by u3 towards point q, with
 * weight = Omega_t sum f / Q: weight x V is an unbiased estimate of the pixel's mean over
 * its samples of the texel's Q-point quadrature of f cos V, exact where V is the same over
 * the texel and the pixel. A texel the BRDF does not reach gets weight 0 (no ray).
 * plastic (kernels/bsdf.h) is not albedo x shape: part 0 takes the part of f cos its albedo
 * multiplies (the diffuse base; all of f for the other kinds), part 1 the coat's (f minus that,
 * plastic groups only, weight c_j = size_j / S: no albedo), each with its own stream of
 * uniforms (RNG_TEXEL, RNG_TEXEL_COAT) and its own shadow rays; material[gj] the group's
 * material (its row of the plastic table). */
#ifndef TEXEL_POINTS
#define TEXEL_POINTS 4   /* 16: 4 x 4 strata; 4: 2 x 2; 1: one point over the whole texel */
#endif
#define TEXEL_GRID (TEXEL_POINTS == 16 ? 4 : (TEXEL_POINTS == 4 ? 2 : 1))
__kernel void bake_texel_rays(const uint count, const uint first, const uint n_levels, const uint samples,
                              const uint tile, const uint k0, const uint k1, const uint stream, const uint part,
                              __global const int *material, __global const float *table,
                              __global const uint *group_count,
                              __global const float *normal, __global const float *geometric,
                              __global const float *wo,
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
    rng_uniforms(first + gidx, tile, stream, k0, k1, &u0, &u1, &u2, &u3);
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
        const float gx = geometric[3 * gj], gy = geometric[3 * gj + 1], gz = geometric[3 * gj + 2];
        const float wx = wo[3 * gj], wy = wo[3 * gj + 1], wz = wo[3 * gj + 2];
        realv sx, sy, sz, tx, ty, tz;
        make_frame((realv)nx, (realv)ny, (realv)nz, &sx, &sy, &sz, &tx, &ty, &tz);
        const realv ox = wx * sx + wy * sy + wz * sz, oy = wx * tx + wy * ty + wz * tz;
        const realv oz = (realv)(wx * nx + wy * ny + wz * nz);
        const int kd = kind[gj];
        const realv pa = (realv)param[gj];
        const float c = weight[gj];
        if (part && kd != BSDF_PLASTIC) {   /* the coat's pass: only plastic has a coat */
            step += TEXEL_POINTS;
            continue;
        }
        realv ix[TEXEL_POINTS], iy[TEXEL_POINTS], iz[TEXEL_POINTS];
        intv above = (intv)0, outside[TEXEL_POINTS];
        for (int q = 0; q < TEXEL_POINTS; ++q) {
            ix[q] = dx[q] * sx + dy[q] * sy + dz[q] * sz;
            iy[q] = dx[q] * tx + dy[q] * ty + dz[q] * tz;
            iz[q] = dx[q] * nx + dy[q] * ny + dz[q] * nz;
            outside[q] = dx[q] * gx + dy[q] * gy + dz[q] * gz > 0.0f;   /* above the geometric surface */
            above |= (iz[q] > 0.0f) & outside[q];
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
#if HAS_KIND(BSDF_PLASTIC)
            if (kd == BSDF_PLASTIC) {   /* the albedo's part (the diffuse base), or the coat's (part 1) */
                realv whole, diffuse;
                material_eval_pdf((intv)BSDF_PLASTIC, pa, table, (uintv)((uint)material[gj] * PLASTIC_STRIDE), ix[q],
                                  iy[q], iz[q], ox, oy, oz, &whole, &diffuse, &unused);
                fv = part ? whole - diffuse : diffuse;
            }
#endif
            fv = select(fv * c, (realv)0.0f, !(fv > 0.0f) | !outside[q]);
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
 * data[o] of QBITS-bit coefficients of the block's PIXELS = BLOCK^2 pixels (pixel p at row
 * p / BLOCK, column p % BLOCK of the block; block b at row b / blocks_x, column b % blocks_x of
 * the image). One work-item takes TILE_BLOCKS consecutive blocks and keeps their sums in
 * private memory while it walks the K coefficients (one row of the offset table each), eight
 * pixels to a vector. It writes the frame itself: each pixel's sums times its albedo, RGB
 * interleaved, (height, width, 3), the pixels of edge blocks beyond the image left out.
 * With COAT (plastic's coat, a second store over the blocks that see plastic): block b is the
 * image's block block_of[b], and its sums are added to the frame as they are (the albedo does
 * not multiply the coat), after the transfer's product.
 * numpy twin: frame.py image_reference (coat_reference). */
#ifndef COAT
#define COAT 0
#endif
#ifndef QBITS
#define QBITS 8
#endif
#ifndef BLOCK
#define BLOCK 16
#endif
#define PIXELS (BLOCK * BLOCK)
#if BLOCK % 8
#error "frame_product writes eight pixels of one block row at a time: BLOCK is a multiple of 8"
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

__kernel void frame_product(const uint n_terms, const uint n_blocks, const uint blocks_x, const uint width,
                            const uint height, __global const int *columns, __global const float4 *light,
                            __global const int *offsets, __global const float *scale, __global const QTYPE *data,
                            __global const float *albedo, __global const int *block_of, __global float *out)
{
    const uint b0 = get_global_id(0) * TILE_BLOCKS;
    if (b0 >= n_blocks) return;
    const uint tiles = min((uint)TILE_BLOCKS, n_blocks - b0);
    float8 acc[TILE_BLOCKS * 3 * VECTORS];
    for (uint j = 0; j < TILE_BLOCKS * 3 * VECTORS; ++j) acc[j] = (float8)0.0f;
    for (uint k = 0; k < n_terms; ++k) {
        /* ask for the offsets 8 terms on and the entries 4 terms on (10-14% of the kernel's time) */
        if (k + 8u < n_terms) __builtin_prefetch(offsets + (size_t)columns[k + 8u] * n_blocks + b0);
        if (k + 4u < n_terms) {
            __global const int *ahead = offsets + (size_t)columns[k + 4u] * n_blocks + b0;
            for (uint j = 0; j < tiles; ++j) {
                const int o = ahead[j];
                if (o < 0) continue;
                __builtin_prefetch(scale + o);
                for (uint c = 0; c < PIXELS * QBITS / 8; c += 64u)
                    __builtin_prefetch((__global const char *)(data + (size_t)o * PIXELS) + c);
            }
        }
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
    for (uint j = 0; j < tiles; ++j) {
#if COAT
        const uint b = (uint)block_of[b0 + j];
#else
        const uint b = b0 + j;
#endif
        const uint x0 = (b % blocks_x) * BLOCK, y0 = (b / blocks_x) * BLOCK;
        const float8 *a = acc + j * 3 * VECTORS;
        for (uint v = 0; v < VECTORS; ++v) {
            const uint y = y0 + (8 * v) / BLOCK, x = x0 + (8 * v) % BLOCK;
            if (y >= height) break;
            if (x >= width) continue;
            const size_t i = 3 * ((size_t)y * width + x);
            if (x + 8 <= width) {   /* eight pixels, RGB interleaved: three vectors */
                const float16 rg = __builtin_shufflevector(a[v], a[VECTORS + v], 0, 8, 1, 9, 2, 10, 3, 11, 4, 12, 5,
                                                           13, 6, 14, 7, 15);
                const float16 bb = __builtin_shufflevector(a[2 * VECTORS + v], a[2 * VECTORS + v], 0, 1, 2, 3, 4, 5,
                                                           6, 7, 0, 1, 2, 3, 4, 5, 6, 7);
                const float8 o0 = __builtin_shufflevector(rg, bb, 0, 1, 16, 2, 3, 17, 4, 5);
                const float8 o1 = __builtin_shufflevector(rg, bb, 18, 6, 7, 19, 8, 9, 20, 10);
                const float8 o2 = __builtin_shufflevector(rg, bb, 11, 21, 12, 13, 22, 14, 15, 23);
#if COAT
                vstore8(o0 + vload8(0, out + i), 0, out + i);
                vstore8(o1 + vload8(0, out + i + 8), 0, out + i + 8);
                vstore8(o2 + vload8(0, out + i + 16), 0, out + i + 16);
#else
                vstore8(o0 * vload8(0, albedo + i), 0, out + i);
                vstore8(o1 * vload8(0, albedo + i + 8), 0, out + i + 8);
                vstore8(o2 * vload8(0, albedo + i + 16), 0, out + i + 16);
#endif
            } else {
                for (uint l = 0; x + l < width; ++l) {
#if COAT
                    out[i + 3 * l] += a[v][l];
                    out[i + 3 * l + 1] += a[VECTORS + v][l];
                    out[i + 3 * l + 2] += a[2 * VECTORS + v][l];
#else
                    out[i + 3 * l] = a[v][l] * albedo[i + 3 * l];
                    out[i + 3 * l + 1] = a[VECTORS + v][l] * albedo[i + 3 * l + 1];
                    out[i + 3 * l + 2] = a[2 * VECTORS + v][l] * albedo[i + 3 * l + 2];
#endif
                }
            }
        }
    }
}

/* The environment seen where a frame's pixels' camera samples missed, added to those pixels of
 * the frame. Background pixel i (the frame's pixel pixel[i]) has count[i] missing samples in
 * slots i SLOTS .. i SLOTS + count[i] - 1 of u0 (u at rotate_y = 0) and row (the map row, as
 * float bits; -1 in the slots beyond count[i]), sorted by row and then by u0, float32 as the
 * host computed them. The map turned by rotate_y has sample j at u = frac(u0_j + shift),
 * shift = rotate_y / 360, column floor(u W) (nearest texel, as Environment.eval); the pixel
 * gets inv_samples times the sum of those texels. The texel's key (row, floor(u0 + shift),
 * column) is non-decreasing along the sorted samples (each step is a rounding, monotone), so
 * the samples of one texel are a run, and the run starting at sample j is as long as the
 * number of the pixel's samples with j's key (counted LANES at a time).
 * Most pixels' samples lie in one or two map rows (84% and 16% of the bunny's at 512^2, 64
 * samples): seg[2 i] and seg[2 i + 1] hold each row's first and last u0, its row and its
 * number of samples, so that a row whose first and last sample share a texel (most) is one
 * read of seg, and only a row that straddles a column reads its u0 slots, never the rows.
 * Pixels over more rows (a wide footprint) read both per sample.
 * numpy twin: wavlight/relight/frame.py background_reference (per sample). */
#ifndef SLOTS
#define SLOTS 64
#endif
INLINE void background_texel(const float u0, const float shift, const int env_w, int *turn, int *col)
{
    float u = u0 + shift;
    const float t = __builtin_floorf(u);   /* scalar (kernels/simd.h overloads the vectors) */
    u = u - t;
    *turn = (int)t;
    *col = min((int)(u * (float)env_w), env_w - 1);
}

/* -(the lanes' sum) of masks that are -1 where true */
INLINE int background_lanes(const intv same)
{
    int m = 0;
    for (uint l = 0; l < LANES; ++l) m -= same[l];
    return m;
}

/* The samples of slots [lo, hi) of the pixel at base (all in map row rw) in the texel (turn, col) */
INLINE int background_count_row(__global const float *u0, const size_t base, const uint lo, const uint hi,
                                const float shift, const int env_w, const int turn, const int col)
{
    intv same = (intv)0;
    for (uint v = lo / LANES * LANES; v < hi; v += LANES) {
        realv u = LOADV_(u0, base + v) + shift;
        const realv t = floor(u);
        u = u - t;
        const intv c = min(__builtin_convertvector(u * (float)env_w, intv), env_w - 1);
        const intv at = as_intv(LANE_IDS) + (int)v;
        same += (at >= (int)lo) & (at < (int)hi) & (__builtin_convertvector(t, intv) == turn) & (c == col);
    }
    return background_lanes(same);
}

/* The texels of slots [lo, hi) of one map row rw, whose last sample is in (turn1, col1), run by
 * run, added to (r, g, b) */
INLINE void background_row(__global const float *u0, const size_t base, const uint lo, const uint hi, const int rw,
                           const float first_u0, const int turn1, const int col1, const float shift, const int env_w,
                           __global const float *env, float *r, float *g, float *b)
{
    int turn, col;
    background_texel(first_u0, shift, env_w, &turn, &col);
    for (uint j = lo; j < hi;) {
        if (j > lo) background_texel(u0[base + j], shift, env_w, &turn, &col);
        const int m = (turn == turn1 && col == col1) ? (int)(hi - j)
                                                     : background_count_row(u0, base, j, hi, shift, env_w, turn, col);
        const size_t tex = 3 * ((size_t)rw * env_w + col);
        *r += (float)m * env[tex];
        *g += (float)m * env[tex + 1];
        *b += (float)m * env[tex + 2];
        j += (uint)max(m, 1);
    }
}

/* Ask for the slots of the pixel BACKGROUND_AHEAD work-items on (PoCL runs a group's work-items
 * in turn) where it will read them: a row of it straddles a column (its u0), or it spans more
 * than two rows (its u0 and rows). The slots are far apart in memory: waiting for them was
 * half the kernel's time (4.0-4.8 ms of CPU per frame of the bunny at 512^2 against 2.3-2.6). */
#define BACKGROUND_AHEAD 8u
INLINE void background_prefetch(__global const float4 *seg, const uint n, __global const float *u0,
                                __global const float *row, const size_t base, const float shift, const int env_w)
{
    const float4 s0 = seg[0], s1 = seg[1];
    int ta, ca, tb, cb, tc, cc, td, cd;
    background_texel(s0.x, shift, env_w, &ta, &ca);
    background_texel(s0.y, shift, env_w, &tb, &cb);
    background_texel(s1.x, shift, env_w, &tc, &cc);
    background_texel(s1.y, shift, env_w, &td, &cd);
    const int wide = as_uint(s0.w) + as_uint(s1.w) != n;
    if (wide || ca != cb || ta != tb || cc != cd || tc != td)
        for (uint k = 0; k < SLOTS; k += 16u) {
            __builtin_prefetch(u0 + base + k);
            if (wide) __builtin_prefetch(row + base + k);
        }
}

__kernel void frame_background(const uint count, const float inv_samples, const int env_w, const float shift,
                               __global const uint *samples, __global const float4 *seg,
                               __global const float *u0, __global const float *row, __global const uint *pixel,
                               __global const float *env, __global float *out)
{
    const uint i = get_global_id(0);
    if (i >= count) return;
    const uint n = samples[i];
    if (n == 0u) return;
    const size_t base = (size_t)i * SLOTS;
    const float4 s0 = seg[2 * i], s1 = seg[2 * i + 1];       /* (first u0, last u0, row, samples) */
    if (i + BACKGROUND_AHEAD < count) background_prefetch(seg + 2 * (i + BACKGROUND_AHEAD), samples[i + BACKGROUND_AHEAD],
                                                          u0, row, (size_t)(i + BACKGROUND_AHEAD) * SLOTS, shift, env_w);
    const uint n0 = as_uint(s0.w), n1 = as_uint(s1.w);
    float r = 0.0f, g = 0.0f, b = 0.0f;
    if (n0 + n1 == n) {                                      /* one or two rows */
        int turn1, col1;
        background_texel(s0.y, shift, env_w, &turn1, &col1);
        background_row(u0, base, 0u, n0, as_int(s0.z), s0.x, turn1, col1, shift, env_w, env, &r, &g, &b);
        if (n1) {
            background_texel(s1.y, shift, env_w, &turn1, &col1);
            background_row(u0, base, n0, n, as_int(s1.z), s1.x, turn1, col1, shift, env_w, env, &r, &g, &b);
        }
    } else {                                                 /* more rows: rows read per sample */
        for (uint j = 0; j < n;) {
            int turn, col;
            const int rw = as_int(row[base + j]);
            background_texel(u0[base + j], shift, env_w, &turn, &col);
            intv same = (intv)0;
            for (uint v = 0; v < SLOTS; v += LANES) {
                realv u = LOADV_(u0, base + v) + shift;
                const realv t = floor(u);
                u = u - t;
                const intv c = min(__builtin_convertvector(u * (float)env_w, intv), env_w - 1);
                same += (as_intv(LOADV_(row, base + v)) == rw) & (__builtin_convertvector(t, intv) == turn) &
                        (c == col);
            }
            const int m = background_lanes(same);
            const size_t tex = 3 * ((size_t)rw * env_w + col);
            r += (float)m * env[tex];
            g += (float)m * env[tex + 1];
            b += (float)m * env[tex + 2];
            j += (uint)max(m, 1);
        }
    }
    const size_t o = 3 * (size_t)pixel[i];
    out[o] += r * inv_samples;
    out[o + 1] += g * inv_samples;
    out[o + 2] += b * inv_samples;
}

/* The lighting of a frame (wavlight/relight/lighting.py): the map turned by rotate_y, its mean
 * radiance over each of the 2^n x 2^n world texels (Chen & Gao's T2), and its Haar coefficients
 * (eq. 13, the dense nonstandard layout of wavlight.haar.forward), in double precision and in
 * numpy's order of operations, contraction off: the coefficients are those of the twin,
 * lighting.coefficients(Projector(...)(rotate_y, scale)), bit for bit. The host gives each
 * texel edge e (0 .. N) its map column col = edges[e], fraction frac = edges[N + 1 + e] and
 * whole turns turns = edges[2 (N + 1) + e] (Projector.edges), and each texel row r its weight
 * edges[3 (N + 1) + r]; texel row r, edge e of channel ch is
 *     at = (cum[r, col, ch] + frac by_rows[r, col, ch]) + turns total[r, ch],
 * a texel (at[e + 1] - at[e]) weight[r] (weight = scale / Omega_r), times 2^-n. A work-item
 * takes one channel's tile of tile x tile texels (tile = min(LIGHT_TILE, N)) through the log2
 * tile finest levels, writing their details into coeffs (3, N, N) and the tile's scaling
 * coefficient into grid (3, N / tile, N / tile); lighting_top takes each channel's grid through
 * the levels left. */
#ifdef cl_khr_fp64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#ifndef LIGHT_TILE
#define LIGHT_TILE 16
#endif

/* One level of the transform of the g x g scaling coefficients s (row stride `stride`), in
 * place, a tile at (ty, tx) of the level's (g / 2)-sized blocks: details to coeffs (side N) at
 * level l. Each coefficient is written after the four it is made of were read (in place). */
INLINE void lighting_level(double *s_private, __global double *s_global, const uint g, const uint stride,
                           const uint ty, const uint tx, const uint l, const uint side, __global double *coeffs)
{
#pragma OPENCL FP_CONTRACT OFF
    const uint h = g / 2u, H = 1u << l;
    for (uint i = 0; i < h; ++i)
        for (uint j = 0; j < h; ++j) {
            const uint p = 2u * i * stride + 2u * j;
            double a00, a01, a10, a11;
            if (s_private) {
                a00 = s_private[p]; a01 = s_private[p + 1]; a10 = s_private[p + stride]; a11 = s_private[p + stride + 1];
            } else {
                a00 = s_global[p]; a01 = s_global[p + 1]; a10 = s_global[p + stride]; a11 = s_global[p + stride + 1];
            }
            const size_t I = ty * h + i, J = tx * h + j;
            coeffs[I * side + H + J] = 0.5 * ((a00 - a01) + (a10 - a11));
            coeffs[(H + I) * side + J] = 0.5 * ((a00 + a01) - (a10 + a11));
            coeffs[(H + I) * side + H + J] = 0.5 * ((a00 - a01) - (a10 - a11));
            const double s = 0.5 * ((a00 + a01) + (a10 + a11));
            if (s_private) s_private[i * stride + j] = s;
            else s_global[i * stride + j] = s;
        }
}

__kernel void lighting_tiles(const uint n_levels, const uint tile, const int map_w, __global const double *cum,
                             __global const double *by_rows, __global const double *total,
                             __global const double *edges, __global double *coeffs, __global double *grid)
{
#pragma OPENCL FP_CONTRACT OFF
    const uint side = 1u << n_levels, across = side / tile, tiles = across * across;
    __global const double *frac = edges + side + 1, *turns = edges + 2 * (side + 1), *weight = edges + 3 * (side + 1);
    const uint gid = get_global_id(0);
    if (gid >= 3u * tiles) return;
    const uint ch = gid / tiles, t = gid % tiles, ty = t / across, tx = t % across;
    const double unit = 1.0 / (double)side;   /* 2^-n, exact */
    double s[LIGHT_TILE * LIGHT_TILE];
    for (uint r = 0; r < tile; ++r) {
        const uint row = ty * tile + r;
        const double tot = total[3 * row + ch], w = weight[row];
        __global const double *c_row = cum + (size_t)row * (map_w + 1) * 3 + ch;
        __global const double *b_row = by_rows + (size_t)row * map_w * 3 + ch;
        uint e = tx * tile;
        size_t at = 3 * (size_t)edges[e];
        double prev = (c_row[at] + frac[e] * b_row[at]) + turns[e] * tot;
        for (uint c = 0; c < tile; ++c) {
            e = tx * tile + c + 1u;
            at = 3 * (size_t)edges[e];
            const double next = (c_row[at] + frac[e] * b_row[at]) + turns[e] * tot;
            s[r * LIGHT_TILE + c] = ((next - prev) * w) * unit;
            prev = next;
        }
    }
    __global double *out = coeffs + (size_t)ch * side * side;
    uint g = tile, l = n_levels;
    while (g > 1u) {
        --l;
        lighting_level(s, 0, g, LIGHT_TILE, ty, tx, l, side, out);
        g /= 2u;
    }
    if (across == 1u) out[0] = s[0];
    else grid[(size_t)ch * tiles + t] = s[0];
}

__kernel void lighting_top(const uint n_levels, const uint tile, __global double *coeffs, __global double *grid)
{
    const uint ch = get_global_id(0);
    if (ch >= 3u) return;
    const uint side = 1u << n_levels, across = side / tile;
    __global double *s = grid + (size_t)ch * across * across;
    __global double *out = coeffs + (size_t)ch * side * side;
    uint g = across, l = 0;
    while ((1u << l) < across) ++l;
    while (g > 1u) {
        --l;
        lighting_level(0, s, g, across, 0, 0, l, side, out);
        g /= 2u;
    }
    out[0] = s[0];
}
#endif

/* The same background filtered bilinearly (background = "bilinear"; display only: the frame's
 * lighting stays the map's texels). Background pixel i has count[i] missing samples in slots
 * i samples .. of uv: (u at rotate_y = 0, v) as float2, in any order; the map (rows of 3 floats,
 * env_w x env_h) turned by shift = rotate_y / 360 is interpolated between its texel centres at
 * u = frac(u0 + shift), v, wrapping in u and clamped in v (kernels/sphere.h env_bilinear, on
 * rows of 3). The pixel gets inv_samples times the sum.
 * numpy twin: wavlight/relight/frame.py background_bilinear_reference. */
__kernel void frame_background_bilinear(const uint count, const uint samples, const float inv_samples,
                                        const int env_w, const int env_h, const float shift,
                                        __global const uint *missing, __global const float2 *uv,
                                        __global const uint *pixel, __global const float *env, __global float *out)
{
    const uint i = get_global_id(0);
    if (i >= count) return;
    const uint n = missing[i];
    float r = 0.0f, g = 0.0f, b = 0.0f;
    for (uint j = 0; j < n; ++j) {
        const float2 s = uv[(size_t)i * samples + j];
        float u = s.x + shift;
        u = u - __builtin_floorf(u);
        const float x = u * (float)env_w - 0.5f;
        const float y = __builtin_fminf(__builtin_fmaxf(s.y * (float)env_h - 0.5f, 0.0f), (float)(env_h - 1));
        const float x0 = __builtin_floorf(x), y0 = __builtin_floorf(y);
        const float fx = x - x0, fy = y - y0, gx = 1.0f - fx, gy = 1.0f - fy;
        int c0 = (int)x0;
        c0 = c0 < 0 ? c0 + env_w : (c0 >= env_w ? c0 - env_w : c0);
        const int c1 = c0 + 1 >= env_w ? 0 : c0 + 1;
        const int r0 = min((int)y0, env_h - 1), r1 = min(r0 + 1, env_h - 1);
        __global const float *a = env + 3 * ((size_t)r0 * env_w + c0), *bb = env + 3 * ((size_t)r0 * env_w + c1);
        __global const float *c = env + 3 * ((size_t)r1 * env_w + c0), *d = env + 3 * ((size_t)r1 * env_w + c1);
        r += (a[0] * gx + bb[0] * fx) * gy + (c[0] * gx + d[0] * fx) * fy;
        g += (a[1] * gx + bb[1] * fx) * gy + (c[1] * gx + d[1] * fx) * fy;
        b += (a[2] * gx + bb[2] * fx) * gy + (c[2] * gx + d[2] * fx) * fy;
    }
    const size_t o = 3 * (size_t)pixel[i];
    out[o] += r * inv_samples;
    out[o + 1] += g * inv_samples;
    out[o + 2] += b * inv_samples;
}
