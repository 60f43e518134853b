/* The unbiased relit frame (wavlight/relight/converge.py; Chen & Gao sec. 2.2 eq. 6-8 and 12,
 * sec. 4.3-4.4 eq. 17-25): the pixels' product trees T1 x L, and each camera sample's
 * directions from the defensive mixture of that product, the BSDF and the lighting, with their
 * unoccluded estimates. The host traces the camera rays before and the shadow rays after
 * (embree). numpy twins: wavlight.relight.converge.tile_trees_reference (converge_trees) and
 * wavlight.relight.converge.shade_reference (converge_shade).
 *
 * converge_trees: per pixel of a tile, the transfer's texels on 2^m x 2^m texels (m = N_LEVELS)
 * from the bake's quantized entries (the top-left 2^m x 2^m coefficients of its 2^n x 2^n
 * transform times 4^(n - m) are the transform of the summed texels), inverse-transformed top
 * down (eq. 13: four children from a node's scaling coefficient and its three wavelets), each
 * texel's value H_t (the integral of f cos V over the texel, times the pixel's hit scale c)
 * clamped to H+_t = max(H_t, 0) (the compressed transfer's ringing), times the lighting's
 * luminance mass gl_t of the texel: the product's leaves, eq. 25 at the finest level (no finer
 * wavelets), summed bottom up into the pyramid the warp walks (eq. 17, parent = sum of its
 * children in float32: kernels/warp.h). The same pass gives the pixel's relit value
 * G = sum over t with gl_t > 0 of H+_t R_t (R_t the texel's mean radiance), the control
 * variate's integral. With COAT (a bake with plastic's coat) the coefficients are the
 * transfer's plus wp times the coat's (wp = 1 / lum(a_p) where the pixel's block holds a coat),
 * and relit's fourth value is the coat's share of the pixel's scaling coefficient, clamped to
 * [0, 1] (0 without COAT). Level l's scaling coefficients, in Morton order, give level l + 1's
 * (children 4k .. 4k + 3 of node k) in private memory; the leaves are written as they come, and
 * the levels above them as their sums, each node once. Eight pixels of one block row per
 * work-item (lanes): their entries are eight adjacent values of each entry row, and their
 * offsets one row of the table for all lanes.
 *
 * converge_spread: per pixel, the angular spread of the mirror directions of its footprint's
 * fixed grid of rays (twin: wavlight.relight.converge.footprint_spread), which decides where
 * converge_shade resamples.
 *
 * converge_shade: per camera sample (eight per work-item, pixel-major: sample r is sample
 * r mod k of tile pixel r / k), a miss sees the map; a hit gets its shading frame (hit.h) and
 * SLOTS directions of the mixture (1 - alpha - beta) product + alpha BSDF + beta lighting
 * (alpha = defensive, 1 - beta where the pixel's product is 0; beta = light):
 *   - product: the pixel's tree walked with (u0, u1) (warp.h tree_walk, eq. 19-22), then
 *     inside the texel a leaf of the lighting's own resolution in proportion to its mass
 *     (its place in the texel's running sum, leaf_cdf, bisected), then inside the leaf a
 *     piece of a map pixel in proportion to the pieces' masses (place_in_leaf);
 *   - lighting: a texel in proportion to its mass by u0 (texel_cdf), then the same with (u1, u3);
 *   - BSDF: bsdf_sample with (u2 / alpha, u3);
 * u2 chooses. The pdf is the mixture's at the chosen direction, every technique's:
 *     p = (1 - alpha - beta) p_tree f_leaf J + alpha p_bsdf + beta p_texel 4^m f_leaf J,
 * f_leaf = (leaf mass / texel mass) k^2 x (piece mass / leaf mass) / (piece area / leaf area),
 * J = 1 / (2 pi^2 sin theta), all read from the tables the sampler reads (masses as
 * differences of the same running sums). Each slot's estimate is albedo f cos L / p / SLOTS,
 * traced by the host (plastic: (coat + albedo base) L / p / SLOTS, bsdf.h material_eval_pdf,
 * its two lobes sampled by material_sample); with CONTROL the sample also carries, without a
 * shadow ray, k (G - sum over slots of g / p / SLOTS), k the albedo (plastic: tinted towards
 * its luminance by the coat's share of the pixel's transfer, relit's fourth value),
 * g(w) = H+_t / Omega_t L(w) (H+_t = the pixel's
 * leaf / gl_t, read with the tree's pdf). A hit whose pixel's footprint spread exceeds
 * coherence times its lobe's width draws CANDIDATES mixture directions instead (no shadow
 * rays), stratified over the pixel's k x CANDIDATES, weights w = target / p with
 * target = Y(L) [(f cos)^0.6 T^0.4 + 0.05 f cos + 0.1 T] (T = H+_t / Omega_t), and picks SLOTS
 * of them by one systematic uniform, each estimated as albedo f cos L x (sum w / CANDIDATES) /
 * target / SLOTS (resampled importance sampling). Outputs as planes of count floats: direct r g b (a miss's
 * radiance, a hit's control-variate part), origin x y z, then per slot the direction x y z,
 * then per slot the estimate r g b. Uniforms: Philox (rng.h) of tile `tile` at index
 * first + r, four per camera sample in stream dir_stream (rng.CONVERGE_DIRECTIONS[0]) for its
 * slots, RNG_CONVERGE_RESAMPLE for its candidates, RNG_CONVERGE_PICK for the picks; slot or
 * candidate j takes point j of the R4 lattice shifted by them (lattice): one Philox draw per
 * sample, and its directions spread over the uniforms' cube.
 */
#ifndef BACKGROUND_MODE   /* what misses see: 0 the map's pixel, 1 filtered bilinearly, 2 nothing */
#define BACKGROUND_MODE 0   /* (wavlight.envmap.BACKGROUND_MODE, wavlight.options.BACKGROUND) */
#endif
#include "warp.h"
#include "bsdf.h"
#include "rng.h"
#include "hit.h"
#include "texture.h"
#ifndef TEXTURES
#define TEXTURES 0   /* 1: some material has a base-colour texture (texture.h) */
#endif
#ifndef N_LEVELS
#error "converge.cl is built with -DN_LEVELS (the product trees' depth)"
#endif
#ifndef SLOTS
#define SLOTS 2
#endif
#ifndef CANDIDATES
#define CANDIDATES 0   /* 0: no resampled directions */
#endif
#ifndef CONTROL
#define CONTROL 1
#endif
#ifndef LATTICE0
#error "converge.cl is built with -DLATTICE0 .. -DLATTICE3 (wavlight.relight.converge.LATTICE)"
#endif
#define LOBE_POWER 0.6f
#define TARGET_BSDF 0.05f
#define TARGET_TRANSFER 0.1f

/* ----------------------------------------------------------------------------- the trees */
#ifndef QBITS
#define QBITS 8
#endif
#if QBITS == 8
#define QTYPE char
#define QVEC char8
#else
#define QTYPE short
#define QVEC short8
#endif
#define BLOCK_SIDE 16
#define BLOCK_PIXELS (BLOCK_SIDE * BLOCK_SIDE)

/* LANES adjacent quantized values (8 or 16 bits) as floats. */
INLINE realv load_entries(__global const QTYPE *q)
{
#if LANES == 8 && INLINE_BUILTINS
    return __builtin_convertvector(*(__global const QVEC *)q, float8);
#elif LANES == 8
    return convert_float8(vload8(0, q));
#else
    realv v;
    for (int j = 0; j < LANES; ++j) v[j] = (float)q[j];
    return v;
#endif
}

/* Bits 0, 2, 4, .. of v packed into bits 0, 1, 2, .. (the inverse of SPREAD_BITS_INTO). */
INLINE uint compact_bits(uint v)
{
    v &= 0x55555555u;
    v = (v | (v >> 1)) & 0x33333333u;
    v = (v | (v >> 2)) & 0x0f0f0f0fu;
    v = (v | (v >> 4)) & 0x00ff00ffu;
    v = (v | (v >> 8)) & 0x0000ffffu;
    return v;
}

/* Coefficient (row, col) of the 2^m x 2^m layout (m = N_LEVELS: the top-left block of the bake's)
 * for the lanes' pixels, whose entry rows start at pixel pix0: q scale, 0 where the block keeps
 * no entry of it; block_offsets: the block's row of the offset table, coefficient-major. With
 * COAT, plus wp times plastic's coat's (the transform is linear: the coefficients of
 * H + wp H_coat), from the coat's offsets (coat_offsets: the block's row, -1 where the block
 * holds no coat) and entries; wp = 1 / lum(a_p) on a pixel that sees plastic, else 0. */
#ifndef COAT
#define COAT 0
#endif
#define COAT_ARGS __global const int *coat_offsets, __global const float *coat_scale, __global const QTYPE *coat_data, \
                  const realv wp
#define COAT_PASS coat_offsets, coat_scale, coat_data, wp
INLINE realv coefficient(__global const int *block_offsets, __global const float *scale, __global const QTYPE *data,
                         COAT_ARGS, const uint pix0, const uint row, const uint col)
{
    const int o = block_offsets[(row << N_LEVELS) + col];
    realv v = o < 0 ? (realv)0.0f : load_entries(data + (size_t)max(o, 0) * BLOCK_PIXELS + pix0) * scale[max(o, 0)];
#if COAT
    const int oc = coat_offsets[(row << N_LEVELS) + col];
    if (oc >= 0)
        v += load_entries(coat_data + (size_t)oc * BLOCK_PIXELS + pix0) * (coat_scale[oc] * wp);
#endif
    return v;
}

/* The four children (Morton order) of a node of scaling coefficient a at level l, node k: eq. 13
 * with its three wavelets. */
INLINE void children(__global const int *block_offsets, __global const float *scale, __global const QTYPE *data,
                     COAT_ARGS, const uint pix0, const int l, const uint k, const realv a, realv v[4])
{
    const uint s = 1u << l, x = compact_bits(k), y = compact_bits(k >> 1);
    const realv d1 = coefficient(block_offsets, scale, data, COAT_PASS, pix0, y, s + x);
    const realv d2 = coefficient(block_offsets, scale, data, COAT_PASS, pix0, s + y, x);
    const realv d3 = coefficient(block_offsets, scale, data, COAT_PASS, pix0, s + y, s + x);
    v[0] = 0.5f * ((a + d1) + (d2 + d3));
    v[1] = 0.5f * ((a - d1) + (d2 - d3));
    v[2] = 0.5f * ((a + d1) - (d2 + d3));
    v[3] = 0.5f * ((a - d1) - (d2 - d3));
}

/* Global size: 2 x (the tile's blocks) x BLOCK_SIDE work-items of LANES = 8 pixels; the tile is
 * the w x h pixels at (x0, y0) of the image (width image_w), its blocks those of block row
 * block_row from block column bx0; tree p = (y - y0) w + (x - x0) at out + p tree_stride
 * (node 0 at TREE_ORIGIN), its G at relit + 4 p; pixels of scale c = 0 (every camera sample of the
 * bake missed: no transfer) get a root of 0 and nothing below it. offsets: per block its row of the offset table
 * over the 4^m coefficients of the 2^m x 2^m layout (block-major: one block's lookups share
 * cache lines). gl and radiance: the lighting's leaf masses and mean radiance (r, g, b, pad) of
 * the 4^m texels in Morton order. hs = 2^m 4^(n - m). The levels above the last two live in
 * private memory, eight trees to a vector (node[] holds a level's scaling coefficients top
 * down, then its masses bottom up); the last two levels are made sixteen leaves at a time
 * from their level m - 2 node, written as they come: each node is written to the trees once. */
__kernel void converge_trees(__global const int *offsets, __global const float *scale, __global const QTYPE *data,
                             const uint blocks_w, const uint block_row, const uint bx0, const uint x0, const uint y0,
                             const uint w, const uint h, const uint image_w, __global const float *hit_scale,
                             const float hs, __global const float *gl, __global const float *radiance,
                             const uint tree_stride, __global float *out, __global float *relit,
                             __global const int *coat_block_offsets, __global const float *coat_scale,
                             __global const QTYPE *coat_data, __global const float *coat_weight)
{
#if LANES != 8
#error "converge_trees takes eight pixels of a block row per work-item (LANES 8)"
#endif
    const uint gid = get_global_id(0);
    const uint part = gid & 1u, yy = (gid >> 1) % BLOCK_SIDE, j = gid / (2 * BLOCK_SIDE);
    const uint xx0 = j * BLOCK_SIDE + part * LANES;   /* the first lane's column in the tile */
    if (yy >= h || xx0 >= w) return;
    const uint live = min((uint)LANES, w - xx0);
    const uint pix0 = yy * BLOCK_SIDE + part * LANES;
    __global const int *bo = offsets + (size_t)(block_row * blocks_w + bx0 + j) * (1u << (2 * N_LEVELS));
    __global float *tree = out + TREE_ORIGIN;
    const uintv lane_x = min(LANE_IDS, (uintv)(live - 1u)) + xx0;   /* the last live lane repeats beyond w */
    const uintv tb = (yy * w + lane_x) * tree_stride;
    const realv c = GATHER(hit_scale, (y0 + yy) * image_w + x0 + lane_x) * hs;
#if COAT
    const realv wp = GATHER(coat_weight, (y0 + yy) * image_w + x0 + lane_x);
    __global const int *coat_offsets = coat_block_offsets
                                       + (size_t)(block_row * blocks_w + bx0 + j) * (1u << (2 * N_LEVELS));
#else
    const realv wp = 0.0f;
    __global const int *coat_offsets = coat_block_offsets;
#endif
    if (all(c == 0.0f)) {   /* pixels the bake saw no surface in: a root of 0 (no product), G = 0 */
        for (uint q = 0; q < live; ++q) {
            tree[tb[q]] = 0.0f;
            vstore4((float4)0.0f, 0, relit + 4 * (yy * w + xx0 + q));
        }
        return;
    }
    realv gr = 0.0f, gg = 0.0f, gb = 0.0f;
#define TOP_LEVELS (N_LEVELS >= 2 ? N_LEVELS - 1 : 1)   /* levels 0 .. TOP_LEVELS - 1 in private memory */
    realv node[LEVEL_OFFSET(TOP_LEVELS)];
    /* levels 0 .. m - 2: the scaling coefficients */
    node[0] = coefficient(bo, scale, data, COAT_PASS, pix0, 0u, 0u);
    /* the coat's share of the pixel's mean transfer (its scaling coefficients'): the control
     * variate's tint (converge_shade), 0 without a coat */
    const realv coat_root = wp * coefficient(coat_offsets, coat_scale, coat_data, coat_offsets, coat_scale, coat_data,
                                             (realv)0.0f, pix0, 0u, 0u);
    const realv share = COAT ? clamp(select((realv)0.0f, coat_root / node[0], node[0] > 0.0f), 0.0f, 1.0f)
                             : (realv)0.0f;
    for (int l = 0; l + 1 < TOP_LEVELS; ++l) {
        const uint at = (uint)LEVEL_OFFSET(l), below = (uint)LEVEL_OFFSET(l + 1);
        for (uint k = 0; k < (1u << (2 * l)); ++k)
            children(bo, scale, data, COAT_PASS, pix0, l, k, node[at + k], node + below + 4 * k);
    }
    /* level m - 1 (for m >= 2) and the leaves: gl_t H+_t written, G summed; the masses of
     * level m - 1 written, those of level m - 2 kept */
    const int l1 = TOP_LEVELS - 1;
    const uint leaf0 = (uint)LEVEL_OFFSET(N_LEVELS);
    for (uint k = 0; k < (1u << (2 * l1)); ++k) {
        realv mid[4];
        if (N_LEVELS >= 2) {
            children(bo, scale, data, COAT_PASS, pix0, l1, k, node[(uint)LEVEL_OFFSET(l1) + k], mid);
        } else {
            mid[0] = node[0];
        }
        realv sum = 0.0f;
        for (int q1 = 0; q1 < (N_LEVELS >= 2 ? 4 : 1); ++q1) {
            const uint k1 = N_LEVELS >= 2 ? 4 * k + q1 : k;   /* the level m - 1 node */
            realv v[4];
            children(bo, scale, data, COAT_PASS, pix0, N_LEVELS - 1, k1, mid[q1], v);
            for (int q = 0; q < 4; ++q) {
                const uint t = 4 * k1 + q;
                const realv hv = fmax(v[q] * c, 0.0f);
                const float g = gl[t];
                if (g > 0.0f) {
                    gr += hv * radiance[4 * t];
                    gg += hv * radiance[4 * t + 1];
                    gb += hv * radiance[4 * t + 2];
                }
                v[q] = g * hv;
            }
            const realv mass = (v[0] + v[1]) + (v[2] + v[3]);   /* in the order of tree_reduce */
            for (uint q = 0; q < live; ++q) {
                __global float *p = tree + tb[q];
                p[leaf0 + 4 * k1] = v[0][q];
                p[leaf0 + 4 * k1 + 1] = v[1][q];
                p[leaf0 + 4 * k1 + 2] = v[2][q];
                p[leaf0 + 4 * k1 + 3] = v[3][q];
                if (N_LEVELS >= 2)
                    p[(uint)LEVEL_OFFSET(N_LEVELS - 1) + k1] = mass[q];
            }
            mid[q1] = mass;
        }
        node[(uint)LEVEL_OFFSET(l1) + k] = N_LEVELS >= 2 ? (mid[0] + mid[1]) + (mid[2] + mid[3]) : mid[0];
    }
    /* the levels above: parent = (c0 + c1) + (c2 + c3) */
    for (int l = l1 - 1; l >= 0; --l) {
        const uint at = (uint)LEVEL_OFFSET(l), below = (uint)LEVEL_OFFSET(l + 1);
        for (uint k = 0; k < (1u << (2 * l)); ++k)
            node[at + k] = (node[below + 4 * k] + node[below + 4 * k + 1])
                           + (node[below + 4 * k + 2] + node[below + 4 * k + 3]);
    }
    for (uint q = 0; q < live; ++q) {
        __global float *p = tree + tb[q];
        for (uint i = 0; i < (uint)LEVEL_OFFSET(TOP_LEVELS); ++i)
            p[i] = node[i][q];
        __global float *g = relit + 4 * (yy * w + xx0 + q);
        g[0] = gr[q];
        g[1] = gg[q];
        g[2] = gb[q];
        g[3] = share[q];
    }
#undef TOP_LEVELS
}

/* ----------------------------------------------------------------------------- the lighting */
/* The lighting inside the texels (wavlight.relight.converge._TexelLight.tables): leaf_cdf the
 * running sums of each texel's k x k leaf masses (texel-major, row-major inside), texel_total
 * each texel's last running sum, leaf_guide per texel k^2 + 1 counts (entry g: how many of its
 * running sums are <= (g / k^2) total: the leaf of a point fu of the texel lies between those of
 * g = floor(fu k^2) and g + 1, so that a bisection there takes a step or two inside one cache
 * line, not log2(k^2) steps across the texel's table), texel_cdf the running sum of the texels'
 * masses, columns (share of the first map column, first and second
 * map column as uint bits, 0) per leaf column and rows (share of the first map row in v and in
 * solid angle, first and second map row) per leaf row, map (r, g, b, luminance) per map pixel;
 * 2^top leaves a side, k = 2^kbits per texel side. */
#define LIGHT_ARGS __global const float *leaf_cdf, __global const float *texel_total, __global const uint *leaf_guide, \
                   __global const float *texel_cdf, __global const uint *texel_guide, __global const float *columns,  \
                   __global const float *rows, __global const float *map, __global const float *map_lum,             \
                   const uint map_w, const uint top, const uint kbits
#define LIGHT leaf_cdf, texel_total, leaf_guide, texel_cdf, texel_guide, columns, rows, map, map_lum, map_w, top, kbits

/* How many of the n texels' running sums (texel_cdf) are <= u x total, total their last, per lane:
 * between the guide's counts of u's cell and the next (texel_guide: per cell g of n, how many
 * running sums are <= (g / n) total, in float32 as here), then by bisection: the plain bisection's
 * answer in a step or two instead of log2 n. */
INLINE uintv texels_at_most(__global const float *texel_cdf, __global const uint *texel_guide, const uint n,
                            const realv u)
{
    const realv target = u * texel_cdf[n - 1u];
    const uintv g = as_uintv(clamp(convert_intv(u * (float)n), 0, (int)n - 1));
    uintv lo = GATHER_T(uintv, texel_guide, g), hi = GATHER_T(uintv, texel_guide, g + 1u);
    intv active = lo < hi;
    while (any(active)) {
        const uintv mid = (lo + hi) >> 1;
        const intv below = GATHER(texel_cdf, min(mid, n - 1u)) <= target;
        lo = select(lo, mid + 1u, active & below);
        hi = select(hi, mid, active & ~below);
        active = lo < hi;
    }
    return lo;
}

/* The pieces of leaves (a, b) over the map's pixels: masses (luminance x share of the leaf's
 * solid angle) in the order (row 0, col 0), (0, 1), (1, 0), (1, 1), the first column's share
 * hc of the leaf's width and the first row's hr of its height, the pixels' columns and rows. */
typedef struct {
    realv m0, m1, m2, m3, hc, hr;
    uintv c0, c1, r0, r1;
} Pieces;

INLINE Pieces leaf_pieces(LIGHT_ARGS, const uintv a, const uintv b)
{
    Pieces p;
    realv cs, c0, c1, unused, rs, ra, r0, r1;
    GATHER4(columns, 4 * a, &cs, &c0, &c1, &unused);
    GATHER4(rows, 4 * b, &rs, &ra, &r0, &r1);
    p.c0 = as_uintv(c0);
    p.c1 = as_uintv(c1);
    p.r0 = as_uintv(r0);
    p.r1 = as_uintv(r1);
    p.hc = cs;
    p.hr = rs;
    p.m0 = GATHER(map_lum, p.r0 * map_w + p.c0) * cs * ra;
    p.m1 = GATHER(map_lum, p.r0 * map_w + p.c1) * (1.0f - cs) * ra;
    p.m2 = GATHER(map_lum, p.r1 * map_w + p.c0) * cs * (1.0f - ra);
    p.m3 = GATHER(map_lum, p.r1 * map_w + p.c1) * (1.0f - cs) * (1.0f - ra);
    return p;
}

/* The density of a point in piece (lower, right) against uniform in the leaf: the piece's share
 * of the leaf's mass over its share of the leaf's area (0 where either is 0). */
INLINE realv piece_factor(const Pieces *p, const realv total, const intv right, const intv lower)
{
    const realv piece = select(select(p->m0, p->m1, right), select(p->m2, p->m3, right), lower);
    const realv area = select(p->hc, 1.0f - p->hc, right) * select(p->hr, 1.0f - p->hr, lower);
    return select((realv)0.0f, piece / total / area, (total > 0.0f) & (area > 0.0f));
}

/* A point (fu, fv) of the leaf from uniforms (su, sv): a row of pieces, then a piece in it, in
 * proportion to their masses, uniform inside it. */
INLINE void place_in_leaf(const Pieces *p, const realv su, const realv sv, realv *fu, realv *fv)
{
    const realv total = ((p->m0 + p->m1) + p->m2) + p->m3, upper = p->m0 + p->m1;
    const intv lower = sv * total >= upper;
    realv sv2 = select(sv * total / upper, (sv * total - upper) / (total - upper), lower);
    sv2 = select(sv, clamp(sv2, 0.0f, ONE_MINUS_EPS), isfinite(sv2));
    const realv a0 = select(p->m0, p->m2, lower), a1 = select(p->m1, p->m3, lower), s01 = a0 + a1;
    const intv right = su * s01 >= a0;
    realv su2 = select(su * s01 / a0, (su * s01 - a0) / a1, right);
    su2 = select(su, clamp(su2, 0.0f, ONE_MINUS_EPS), isfinite(su2));
    *fu = select(su2 * p->hc, p->hc + su2 * (1.0f - p->hc), right);
    *fv = select(sv2 * p->hr, p->hr + sv2 * (1.0f - p->hr), lower);
}

/* The running sum of texel row0's leaves before leaf j, and leaf j's mass. */
INLINE realv leaf_below(__global const float *cdf, const uintv row0, const uintv j, realv *mass)
{
    const realv below = select(GATHER(cdf, row0 + max(j, 1u) - 1u), (realv)0.0f, j == 0u);
    *mass = GATHER(cdf, row0 + j) - below;
    return below;
}

/* The point (u, v) of the square placed inside texel (col, row) at offsets (fu, fv): a leaf by
 * fu's place in the texel's running sum (its rest the offset inside the leaf), then the map's
 * pieces inside the leaf. */
INLINE void place_in_texel(LIGHT_ARGS, const uintv col, const uintv row, const realv fu, const realv fv, realv *u,
                           realv *v)
{
    const uint side = 1u << N_LEVELS, k = 1u << kbits, kk = k * k;
    const uintv t = row * side + col, row0 = t * kk;
    const realv target = fu * GATHER(texel_total, t);
    /* how many running sums are <= target: between the guide's counts of fu's cell and the next */
    const uintv g = t * (kk + 1u) + as_uintv(clamp(convert_intv(fu * (float)kk), 0, (int)kk - 1));
    uintv lo = GATHER_T(uintv, leaf_guide, g), hi = GATHER_T(uintv, leaf_guide, g + 1u);
    intv active = lo < hi;
    while (any(active)) {
        const uintv mid = (lo + hi) >> 1;
        const intv below = GATHER(leaf_cdf, row0 + min(mid, kk - 1u)) <= target;
        lo = select(lo, mid + 1u, active & below);
        hi = select(hi, mid, active & ~below);
        active = lo < hi;
    }
    const uintv leaf = min(lo, kk - 1u);
    realv mass;
    const realv below = leaf_below(leaf_cdf, row0, leaf, &mass);
    const realv s = clamp(select(fu, (target - below) / mass, mass > 0.0f), 0.0f, ONE_MINUS_EPS);
    const uintv a = (col << kbits) + (leaf & (k - 1u)), b = (row << kbits) + (leaf >> kbits);
    const Pieces p = leaf_pieces(LIGHT, a, b);
    realv pu, pv;
    place_in_leaf(&p, s, clamp(fv, 0.0f, ONE_MINUS_EPS), &pu, &pv);
    const float inv = 1.0f / (float)(1u << top);
    *u = fmin((convert_realv(a) + pu) * inv, ONE_MINUS_EPS);
    *v = fmin((convert_realv(b) + pv) * inv, ONE_MINUS_EPS);
}

/* At points (au, av) of the square: their texel (col, row), the density factor of
 * place_in_texel against uniform in the texel (returned) and the map pixel's radiance there
 * (the piece that holds the point: the turned map's nearest pixel). */
INLINE realv light_at(LIGHT_ARGS, const realv au, const realv av, uintv *col, uintv *row, realv *lr, realv *lg,
                      realv *lb)
{
    const uint side = 1u << N_LEVELS, k = 1u << kbits, kk = k * k, count = 1u << top;
    const realv x = au * (float)count, y = av * (float)count;
    const uintv a = as_uintv(clamp(convert_intv(x), 0, (int)count - 1));
    const uintv b = as_uintv(clamp(convert_intv(y), 0, (int)count - 1));
    *col = a >> kbits;
    *row = b >> kbits;
    const uintv row0 = (*row * side + *col) * kk;
    const realv total = GATHER(texel_total, *row * side + *col);
    realv mass;
    leaf_below(leaf_cdf, row0, ((b & (k - 1u)) << kbits) + (a & (k - 1u)), &mass);
    const realv f = select((realv)0.0f, mass / total * (float)kk, total > 0.0f);
    const Pieces p = leaf_pieces(LIGHT, a, b);
    const intv right = x - convert_realv(a) >= p.hc, lower = y - convert_realv(b) >= p.hr;
    const realv ptotal = ((p.m0 + p.m1) + p.m2) + p.m3;
    realv unused;
    GATHER4(map, 4 * (select(p.r0, p.r1, lower) * map_w + select(p.c0, p.c1, right)), lr, lg, lb, &unused);
    return f * piece_factor(&p, ptotal, right, lower);
}

/* World directions <-> the world-frame lat-long square (rotate_y = 0; the map's rotation is in
 * the tables): u = atan2(x, -z) / 2 pi, v = theta / pi. */
INLINE void square_to_world(const realv u, const realv v, realv *x, realv *y, realv *z)
{
    realv sp, cp, st, ct;
    fast_sincos(2.0f * PI_F * u, &sp, &cp);
    fast_sincos(PI_F * v, &st, &ct);
    *x = sp * st;
    *y = ct;
    *z = -cp * st;
}

INLINE void world_to_square(const realv x, const realv y, const realv z, realv *u, realv *v)
{
    realv uu = fast_atan2(x, -z) * INV_2PI_F;
    uu -= floor(uu);
    *u = fmin(uu, ONE_MINUS_EPS);
    *v = fmin(fast_atan2(sqrt(x * x + z * z), y) * INV_PI_F, ONE_MINUS_EPS);
}

/* ----------------------------------------------------------------------------- the mixture */
/* A camera sample's shading point: frame (s, t, n), view in it, material, its pixel's tree and
 * the mixture's shares. */
typedef struct {
    realv sx, sy, sz, tx, ty, tz, nx, ny, nz, ox, oy, oz, param;
    realv gx, gy, gz;   /* the geometric normal (towards the viewer): no light from below it */
    intv kind, has_product;
    uintv tree_base, table_row;   /* table_row: the material's row of the plastic table */
    realv alpha;
} Point;

/* One direction of the mixture: world direction, f cos (no albedo), the part of it the albedo
 * multiplies (all of it but plastic's coat: bsdf.h material_eval_pdf), the mixture's pdf per
 * solid angle, the transfer per solid angle T = H+_t / Omega_t, the radiance. */
typedef struct {
    realv x, y, z, fcos, fd, pdf, transfer, r, g, b;
} Direction;

#define SAMPLE_ARGS __global const float *tree, __global const float *gl, __global const float *omega, LIGHT_ARGS, \
                    const float light, __global const float *mat_table
#define SAMPLE tree, gl, omega, LIGHT, light, mat_table

/* The albedo's colour a (one channel) applied to f cos: (f cos - fd) + a fd (plastic's coat is
 * not tinted; the other kinds' fd is f cos: a f cos). */
INLINE realv tinted(const realv fcos, const realv fd, const realv a)
{
    return (fcos - fd) + a * fd;
}

INLINE Direction mixture_direction(SAMPLE_ARGS, const Point *pt, const realv u0, const realv u1, const realv u2,
                                   const realv u3)
{
    const uint side = 1u << N_LEVELS;
    /* the product's texel: the tree's walk (a pixel without a product has a root of 0 and
     * nothing written below it: its walk's point is clamped into the square, and not used) */
    realv gu = u0, gv = u1;
    tree_walk(tree, pt->tree_base, &gu, &gv);
    uintv col = as_uintv(clamp(convert_intv(gu * (float)side), 0, (int)side - 1));
    uintv row = as_uintv(clamp(convert_intv(gv * (float)side), 0, (int)side - 1));
    realv fu = clamp(gu * (float)side - convert_realv(col), 0.0f, ONE_MINUS_EPS);
    realv fv = clamp(gv * (float)side - convert_realv(row), 0.0f, ONE_MINUS_EPS);
    const intv use_b = u2 < pt->alpha;
    const intv use_l = ~use_b & (u2 < pt->alpha + light);
    if (light > 0.0f && any(use_l)) {   /* the lighting's texel: u0 in the texels' running sum; (u1, u3) inside */
        const uint texels = side * side;
        const uintv t = min(texels_at_most(texel_cdf, texel_guide, texels, u0), texels - 1u);
        col = select(col, t & (side - 1u), use_l);
        row = select(row, t >> N_LEVELS, use_l);
        fu = select(fu, u1, use_l);
        fv = select(fv, u3, use_l);
    }
    realv pu, pv, qx, qy, qz;
    place_in_texel(LIGHT, col, row, fu, fv, &pu, &pv);
    square_to_world(pu, pv, &qx, &qy, &qz);
    /* the BSDF's */
    realv bx, by, bz;
    material_sample(pt->kind, pt->param, mat_table, pt->table_row, pt->ox, pt->oy, pt->oz,
                    clamp(select((realv)0.0f, u2 / pt->alpha, use_b), 0.0f, ONE_MINUS_EPS),
                    clamp(u3, 0.0f, ONE_MINUS_EPS), &bx, &by, &bz);
    realv wx = select(qx, bx * pt->sx + by * pt->tx + bz * pt->nx, use_b);
    realv wy = select(qy, bx * pt->sy + by * pt->ty + bz * pt->ny, use_b);
    realv wz = select(qz, bx * pt->sz + by * pt->tz + bz * pt->nz, use_b);
    const realv len = sqrt(wx * wx + wy * wy + wz * wz);
    Direction d;
    d.x = wx / len;
    d.y = wy / len;
    d.z = wz / len;
    /* the mixture's density there */
    realv au, av;
    world_to_square(d.x, d.y, d.z, &au, &av);
    uintv ccol, crow;
    const realv factor = light_at(LIGHT, au, av, &ccol, &crow, &d.r, &d.g, &d.b);
    const realv jac = env_square_to_solid_angle(d.x, d.z);
    const uintv leaf_index = node_index(N_LEVELS, ccol, crow);
    const realv root = GATHER(tree, pt->tree_base), leaf = GATHER(tree, pt->tree_base + leaf_index);
    const float texels = (float)(side * side);
    const realv p_tree = select((realv)0.0f, leaf / root * texels, root > 0.0f);
    const realv p_prod = select((realv)0.0f, p_tree * factor * jac, pt->has_product);
    realv p_light = 0.0f;
    if (light > 0.0f) {
        const uintv t = crow * side + ccol;
        const realv mass = GATHER(texel_cdf, t) - select(GATHER(texel_cdf, max(t, 1u) - 1u), (realv)0.0f, t == 0u);
        p_light = mass / texel_cdf[side * side - 1u] * texels * factor * jac;
    }
    const realv lx = d.x * pt->sx + d.y * pt->sy + d.z * pt->sz, ly = d.x * pt->tx + d.y * pt->ty + d.z * pt->tz;
    const realv lz = d.x * pt->nx + d.y * pt->ny + d.z * pt->nz;
    realv p_bsdf;
    material_eval_pdf(pt->kind, pt->param, mat_table, pt->table_row, lx, ly, lz, pt->ox, pt->oy, pt->oz, &d.fcos,
                      &d.fd, &p_bsdf);
    const intv above = d.x * pt->gx + d.y * pt->gy + d.z * pt->gz > 0.0f;
    d.fcos = select((realv)0.0f, d.fcos, above);
    d.fd = select((realv)0.0f, d.fd, above);
    const realv pdf = (1.0f - pt->alpha - light) * p_prod + pt->alpha * p_bsdf + light * p_light;
    d.pdf = select((realv)0.0f, pdf, isfinite(pdf));
    const realv g = GATHER(gl, leaf_index - (uint)LEVEL_OFFSET(N_LEVELS));
    d.transfer = select((realv)0.0f, leaf / g / GATHER(omega, crow), (g > 0.0f) & pt->has_product);
    return d;
}

/* f / pdf where both are positive and it is finite, else 0 */
INLINE realv ratio(const realv f, const realv pdf)
{
    const realv r = f / pdf;
    return select((realv)0.0f, r, (pdf > 0.0f) & (f > 0.0f) & isfinite(r));
}

/* The resampling target Y(L) [(f cos)^0.6 T^0.4 + 0.05 f cos + 0.1 T]
 * (wavlight.relight.converge.resampling_target). */
INLINE realv resampling_target(const Direction *d)
{
    const realv f = fmax(d->fcos, 0.0f), t = fmax(d->transfer, 0.0f);
    const realv both = select((realv)0.0f, exp2(LOBE_POWER * log2(f) + (1.0f - LOBE_POWER) * log2(t)),
                              (f > 0.0f) & (t > 0.0f));
    return (0.2126f * d->r + 0.7152f * d->g + 0.0722f * d->b) * (both + TARGET_BSDF * f + TARGET_TRANSFER * t);
}

/* frac(u + j alpha): point j of the rank-1 lattice of the R4 sequence (Roberts 2018) shifted by
 * u, alpha in 24-bit fixed point (LATTICE0 .. LATTICE3, wavlight.relight.converge.LATTICE), so
 * that the sum is exact in float32 (numpy twin: wavlight.relight.converge.lattice). Each point is
 * uniform as u is; the points of one u are spread over the unit cube. */
INLINE realv lattice(const realv u, const uintv j, const uint alpha)
{
    const realv c = u + convert_realv((j * alpha) & 0xFFFFFFu) * 0x1p-24f;
    return select(c, c - 1.0f, c >= 1.0f);
}

/* Direction j of the lattice of uniforms u0 .. u3 (mixture_direction's). */
INLINE Direction lattice_direction(SAMPLE_ARGS, const Point *pt, const realv u0, const realv u1, const realv u2,
                                   const realv u3, const uintv j)
{
    return mixture_direction(SAMPLE, pt, lattice(u0, j, LATTICE0), lattice(u1, j, LATTICE1),
                             lattice(u2, j, LATTICE2), lattice(u3, j, LATTICE3));
}

__kernel void converge_shade(const uint count, const uint k, const uint first, __global const float *dirs,
                             __global const int *prim, __global const float *tfar, const float eye_x,
                             const float eye_y, const float eye_z, const float eye_offset,
                             __global const float *face_normal, __global const int *face_material,
                             __global const float *bary, __global const int *corner, __global const float *normals,
                             const int smooth, __global const int *mat_kind, __global const float *mat_param,
                             __global const float *mat_albedo, __global const float *mat_width,
                             __global const float *mat_table, __global const float *face_uv,
                             __global const int *mat_texture, __global const float *tex_atlas,
                             __global const int *tex_table,
                             __global const float *trees, const uint tree_stride, __global const float *relit,
                             __global const float *spread, __global const float *gl, __global const float *omega,
                             LIGHT_ARGS, const int map_h, const float map_shift, const float defensive,
                             const float light, const float coherence,
                             const uint tile, const uint dir_stream, const uint k0, const uint k1,
                             __global float *out)
{
    const uint base = LANE_BASE();
    if (base >= count) return;
    __global const float *tree = trees + TREE_ORIGIN;   /* (common.h) */
    const uintv i = LANE_INDEX(count);
    uintv unused_j;
    const uintv pixel = div_small(i, k, &unused_j);
    realv dx, dy, dz;
    GATHER3(dirs, 3 * i, &dx, &dy, &dz);
    const intv p_id = GATHER_INT(prim, i);
    const intv hit = p_id >= 0;
    realv out_v[6 + 6 * SLOTS];
    for (int q = 0; q < 6 + 6 * SLOTS; ++q) out_v[q] = 0.0f;
    /* a miss: the map in direction d (its pixel, with BACKGROUND_MODE 1 filtered bilinearly in
     * the map's own square: u + map_shift, map_h rows; with 2 nothing: the background hidden) */
#if BACKGROUND_MODE != 2
    {
        realv au, av;
        world_to_square(dx, dy, dz, &au, &av);
        realv r, g, b;
#if BACKGROUND_MODE == 1
        realv mu = au + map_shift;
        mu = mu - floor(mu);
        env_bilinear(map, (int)map_w, map_h, mu, av, &r, &g, &b);
#else
        uintv ccol, crow;
        light_at(LIGHT, au, av, &ccol, &crow, &r, &g, &b);
#endif
        out_v[0] = select(r, (realv)0.0f, hit);
        out_v[1] = select(g, (realv)0.0f, hit);
        out_v[2] = select(b, (realv)0.0f, hit);
    }
#endif
    if (any(hit)) {
        const uintv f = as_uintv(max(p_id, 0));
        Point pt;
        realv px, py, pz, eps;
        hit_point(dx, dy, dz, GATHER(tfar, i), f, face_normal, eye_x, eye_y, eye_z, eye_offset,
                  &pt.gx, &pt.gy, &pt.gz, &px, &py, &pz, &eps);
        pt.nx = pt.gx;
        pt.ny = pt.gy;
        pt.nz = pt.gz;
        if (smooth) {   /* the shading normal (hit.h) at embree's barycentrics */
            realv bu, bv;
            GATHER2(bary, 2 * i, &bu, &bv);
            shading_normal(dx, dy, dz, bu, bv, f, corner, normals, pt.gx, pt.gy, pt.gz, &pt.nx, &pt.ny, &pt.nz);
        }
        make_frame(pt.nx, pt.ny, pt.nz, &pt.sx, &pt.sy, &pt.sz, &pt.tx, &pt.ty, &pt.tz);
        pt.ox = -(dx * pt.sx + dy * pt.sy + dz * pt.sz);
        pt.oy = -(dx * pt.tx + dy * pt.ty + dz * pt.tz);
        pt.oz = -(dx * pt.nx + dy * pt.ny + dz * pt.nz);
        const intv mat = GATHER_INT(face_material, f);
        pt.kind = GATHER_INT(mat_kind, mat);
        pt.param = GATHER(mat_param, mat);
        pt.table_row = as_uintv(mat) * (uint)PLASTIC_STRIDE;
        pt.tree_base = pixel * tree_stride;
        pt.has_product = GATHER(tree, pt.tree_base) > 0.0f;
        pt.alpha = select((realv)(1.0f - light), (realv)defensive, pt.has_product);
        out_v[3] = px + pt.gx * eps;   /* shadow rays from the geometric surface */
        out_v[4] = py + pt.gy * eps;
        out_v[5] = pz + pt.gz * eps;
        realv ar, ag, ab;   /* the albedo, times the material's texture at the hit (texture.h) */
        albedo_at_hit(mat_albedo, TEXTURES, face_uv, tex_atlas, tex_table, mat_texture, bary, i, f, mat, &ar, &ag, &ab);
#if CANDIDATES
        const intv resample = hit & (GATHER(spread, pixel) > coherence * GATHER(mat_width, mat));
#else
        const intv resample = 0;
#endif
        const intv mix = hit & ~resample;
        const float share = 1.0f / (float)SLOTS;
        if (any(mix)) {   /* the mixture's directions, one shadow ray each */
            realv cr = 0.0f, cg = 0.0f, cb = 0.0f, u0, u1, u2, u3;
            rng_uniforms(first + i, tile, dir_stream, k0, k1, &u0, &u1, &u2, &u3);
            for (int s = 0; s < SLOTS; ++s) {
                const Direction d = lattice_direction(SAMPLE, &pt, u0, u1, u2, u3, (uintv)s);
                const realv w = select((realv)0.0f, ratio(d.fcos, d.pdf) * share, mix);
                const realv wd = select((realv)0.0f, w * (d.fd / d.fcos), w > 0.0f);   /* the albedo's part */
                out_v[6 + 3 * s] = select((realv)0.0f, d.x, mix);
                out_v[7 + 3 * s] = select((realv)0.0f, d.y, mix);
                out_v[8 + 3 * s] = select((realv)0.0f, d.z, mix);
                out_v[6 + 3 * SLOTS + 3 * s] = tinted(w, wd, ar) * d.r;
                out_v[7 + 3 * SLOTS + 3 * s] = tinted(w, wd, ag) * d.g;
                out_v[8 + 3 * SLOTS + 3 * s] = tinted(w, wd, ab) * d.b;
                if (CONTROL) {   /* g / pdf, g = T L */
                    const realv gp = d.transfer / d.pdf;
                    const intv ok = (d.pdf > 0.0f) & isfinite(gp * d.r) & isfinite(gp * d.g) & isfinite(gp * d.b);
                    cr += select((realv)0.0f, gp * d.r, ok);
                    cg += select((realv)0.0f, gp * d.g, ok);
                    cb += select((realv)0.0f, gp * d.b, ok);
                }
            }
            if (CONTROL) {   /* the tint k = (1 - s) a + s lum(a), s the coat's share (0 without plastic) */
                realv gr, gg, gb, cs;
                GATHER4(relit, 4 * pixel, &gr, &gg, &gb, &cs);
                const realv la = cs * (0.2126f * ar + 0.7152f * ag + 0.0722f * ab);
                out_v[0] = select(out_v[0], ((1.0f - cs) * ar + la) * (gr - cr * share), mix);
                out_v[1] = select(out_v[1], ((1.0f - cs) * ag + la) * (gg - cg * share), mix);
                out_v[2] = select(out_v[2], ((1.0f - cs) * ab + la) * (gb - cb * share), mix);
            }
        }
#if CANDIDATES
        if (any(resample)) {   /* CANDIDATES mixture directions, SLOTS of them picked and traced */
            realv u0, u1, u2, u3;
            rng_uniforms(first + i, tile, RNG_CONVERGE_RESAMPLE, k0, k1, &u0, &u1, &u2, &u3);
            realv weight[CANDIDATES], cx[CANDIDATES], cy[CANDIDATES], cz[CANDIDATES], cv[CANDIDATES], cd[CANDIDATES];
            realv cr[CANDIDATES], cg[CANDIDATES], cb[CANDIDATES];
            realv total = 0.0f;
            for (uint c = 0; c < CANDIDATES; ++c) {
                const Direction d = lattice_direction(SAMPLE, &pt, u0, u1, u2, u3, (uintv)c);
                const realv target = resampling_target(&d);
                const realv w = target / d.pdf;
                weight[c] = select((realv)0.0f, w, (d.pdf > 0.0f) & isfinite(w));
                total += weight[c];
                /* what a pick's estimate needs: f cos / target, and the direction and radiance */
                cx[c] = d.x;
                cy[c] = d.y;
                cz[c] = d.z;
                cv[c] = select((realv)0.0f, d.fcos / target, target > 0.0f);
                cd[c] = select((realv)0.0f, d.fd / target, target > 0.0f);
                cr[c] = d.r;
                cg[c] = d.g;
                cb[c] = d.b;
            }
            realv up, unused1, unused2, unused4;
            rng_uniforms(first + i, tile, RNG_CONVERGE_PICK, k0, k1, &up, &unused1, &unused2, &unused4);
            for (int s = 0; s < SLOTS; ++s) {   /* the first candidate whose running sum passes (u + s) / SLOTS */
                const realv at = (up + (float)s) * share * total;
                realv cum = 0.0f, px_ = cx[CANDIDATES - 1], py_ = cy[CANDIDATES - 1], pz_ = cz[CANDIDATES - 1];
                realv pv = cv[CANDIDATES - 1], pdd = cd[CANDIDATES - 1], pr = cr[CANDIDATES - 1];
                realv pg = cg[CANDIDATES - 1];
                realv pb = cb[CANDIDATES - 1];
                intv found = 0;
                for (uint c = 0; c < CANDIDATES; ++c) {
                    cum += weight[c];
                    const intv take = ~found & (cum > at);
                    px_ = select(px_, cx[c], take);
                    py_ = select(py_, cy[c], take);
                    pz_ = select(pz_, cz[c], take);
                    pv = select(pv, cv[c], take);
                    pdd = select(pdd, cd[c], take);
                    pr = select(pr, cr[c], take);
                    pg = select(pg, cg[c], take);
                    pb = select(pb, cb[c], take);
                    found |= take;
                }
                /* f cos L / target x (sum w) / CANDIDATES / SLOTS */
                realv v = pv * (total / (float)CANDIDATES * share);
                const intv live = resample & isfinite(v);
                v = select((realv)0.0f, v, live);
                const realv vd = select((realv)0.0f, pdd * (total / (float)CANDIDATES * share), live);
                out_v[6 + 3 * s] = select(out_v[6 + 3 * s], px_, resample);
                out_v[7 + 3 * s] = select(out_v[7 + 3 * s], py_, resample);
                out_v[8 + 3 * s] = select(out_v[8 + 3 * s], pz_, resample);
                out_v[6 + 3 * SLOTS + 3 * s] = select(out_v[6 + 3 * SLOTS + 3 * s], tinted(v, vd, ar) * pr, resample);
                out_v[7 + 3 * SLOTS + 3 * s] = select(out_v[7 + 3 * SLOTS + 3 * s], tinted(v, vd, ag) * pg, resample);
                out_v[8 + 3 * SLOTS + 3 * s] = select(out_v[8 + 3 * SLOTS + 3 * s], tinted(v, vd, ab) * pb, resample);
            }
        }
#endif
    }
    for (int q = 0; q < 6 + 6 * SLOTS; ++q)
        STORE_LANES(out_v[q], out + (size_t)q * count, base, count);
}

/* ----------------------------------------------------------------------------- the footprints */
/* Eight pixels per work-item, each with `rays` grid rays (pixel-major) along dirs that hit faces
 * prim (-1: a miss): per hit the face normal n turned towards the viewer, the mirror direction
 * r = d - 2 (d . n) n; the pixel's spread sqrt(2 (1 - |sum r| / hits)) (0 where at most one ray
 * hits). */
__kernel void converge_spread(const uint count, const uint rays, __global const float *dirs, __global const int *prim,
                              __global const float *face_normal, __global float *out)
{
    const uint base = LANE_BASE();
    if (base >= count) return;
    const uintv p = LANE_INDEX(count);
    realv sx = 0.0f, sy = 0.0f, sz = 0.0f, hits = 0.0f;
    for (uint j = 0; j < rays; ++j) {
        const uintv i = p * rays + j;
        realv dx, dy, dz;
        GATHER3(dirs, 3 * i, &dx, &dy, &dz);
        const intv f = GATHER_INT(prim, i);
        const intv hit = f >= 0;
        realv nx, ny, nz, unused;
        GATHER4(face_normal, 4 * as_uintv(max(f, 0)), &nx, &ny, &nz, &unused);
        const realv dn = dx * nx + dy * ny + dz * nz;
        const realv flip = select((realv)1.0f, (realv)-1.0f, dn > 0.0f);
        const realv dnf = dn * flip;   /* d . n with n turned towards the viewer */
        sx += select((realv)0.0f, dx - 2.0f * dnf * (nx * flip), hit);
        sy += select((realv)0.0f, dy - 2.0f * dnf * (ny * flip), hit);
        sz += select((realv)0.0f, dz - 2.0f * dnf * (nz * flip), hit);
        hits += select((realv)0.0f, (realv)1.0f, hit);
    }
    const realv length = sqrt(sx * sx + sy * sy + sz * sz) / fmax(hits, 1.0f);
    STORE_LANES(select((realv)0.0f, sqrt(fmax(2.0f * (1.0f - length), 0.0f)), hits > 1.0f), out, base, count);
}
