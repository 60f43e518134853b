/* The view bake's unbiased frame: each pixel's product tree T1 x f_r (wavlight/relight/view_converge.py;
 * Chen & Gao sec. 2.2 eq. 6-8 with the view as the varying factor, eq. 13 and 17-25). The camera
 * samples are shaded by converge_shade of kernels/converge.cl on these trees (its mixture, pdfs,
 * control variate); the host traces the camera and shadow rays (embree).
 * numpy twin: wavlight.relight.view_converge.trees_reference.
 *
 * view_converge_trees: per pixel (one work-item), the hit of its centre ray with its three cache
 * points and weights (view_lookup of kernels/relight_view.cl). Their T1 on 2^m x 2^m texels
 * (m = N_LEVELS <= n): the top-left 2^m x 2^m block of each point's 2^n x 2^n coefficients is the
 * transform of its coarser texels (eq. 13), read from the bake's quantized entries, blended with
 * the weights and reduced to luminance (the transform is linear), inverse-transformed top down
 * (four children from a node's scaling coefficient and its three wavelets: node value A / 2^l for
 * the average A of the non-standard basis), so that a texel's value times hs = 2^m 4^(n - m) is
 * Y(T1) summed over the bake's texels inside it: Y(sum_t L_t G_t), G_t the integral of V cos over
 * bake texel t. With f_r the mean of the BRDF at the centres of the texel's VC_SUB x VC_SUB parts
 * (the pixel's face normal, turned towards the viewer, its view direction -d, its material; 0
 * below the face's horizon: the midpoint rule over the parts), the leaf is
 *     leaf_t = max(f_r Y(T1_t), 0) / 4^m   where gl_t > 0, else 0
 * (gl_t the lighting's luminance mass of the texel, :meth:`_TexelLight.leaf_masses`, = Y(R_t) / 4^m,
 * R_t its mean radiance): leaf_t = H+_t gl_t with H+_t = max(f_r Y(T1_t) / Y(R_t), 0), about f_r G_t,
 * the integral of f_r cos V over the texel, as converge_shade reads it (T = leaf / gl / Omega_t),
 * and the pixel's relit value G = sum_t H+_t R_t (the control variate's integral). On plastic f_r
 * is base + coat / lum(albedo) (view_product's VIEW_BASE and VIEW_COAT; the coat in the units of
 * the albedo's luminance, as the lighting bake's trees hold it) and relit's fourth value is the
 * coat's share of sum_t H+_t Y(R_t), the tint converge_shade gives the control variate (0 on
 * other kinds). The levels
 * above are sums of their four children (c0 + c1) + (c2 + c3) in Morton order, as
 * wavlight.haar.tree.build_reference sums them; pixels without a cache point (a miss, a back
 * face) get a root of 0 and nothing below it.
 */
#include "relight_view.cl"

#ifndef N_LEVELS
#define N_LEVELS 5
#endif
#ifndef VC_SUB
#define VC_SUB 1   /* f_r's points per texel side */
#endif
#define VC_SIDE (1u << N_LEVELS)
#define VC_TEXELS (VC_SIDE * VC_SIDE)
#define VC_NODES LEVEL_OFFSET(N_LEVELS + 1)
/* wavlight.envmap.LUMINANCE */
#define VC_LR 0.2126f
#define VC_LG 0.7152f
#define VC_LB 0.0722f
/* plastic's coat in the trees is divided by the albedo's luminance, at least this (view_converge.py MIN_LUMINANCE) */
#define VC_MIN_LUM 1e-3f

/* Bits 0, 2, 4, .. of v packed into bits 0, 1, 2, .. */
inline uint vc_compact(uint v)
{
    v &= 0x55555555u;
    v = (v | (v >> 1)) & 0x33333333u;
    v = (v | (v >> 2)) & 0x0f0f0f0fu;
    v = (v | (v >> 4)) & 0x00ff00ffu;
    v = (v | (v >> 8)) & 0x0000ffffu;
    return v;
}

/* The luminance of the weighted blend of coefficient (row, col) of the 2^m x 2^m layout (the
 * top-left block of the bake's 2^n x 2^n) over the pixel's three cache points (block b[k], row j[k]
 * in it, weight wt[k]); offsets: per block its entries of the 4^m coefficients (block-major, so
 * that a pixel's lookups share cache lines). */
inline float vc_coeff(const uint row, const uint col, const uint *b, const uint *j, const float *wt,
                      __global const int *offsets, __global const float *scale, __global const VQTYPE *data)
{
    const uint i = (row << N_LEVELS) + col;
    float v = 0.0f;
    for (int k = 0; k < 3; ++k) {
        if (!(wt[k] > 0.0f)) continue;
        const int o = offsets[(size_t)b[k] * VC_TEXELS + i];
        if (o >= 0) {
            const size_t at = (size_t)o * ROW + j[k];
            v += (wt[k] * scale[o]) * (VC_LR * (float)data[at] + VC_LG * (float)data[at + POINTS]
                                       + VC_LB * (float)data[at + 2 * POINTS]);
        }
    }
    return v;
}

/* Global size >= count: pixel p's tree at out + p tree_stride (node 0 at TREE_ORIGIN, Morton
 * levels), its G at relit + 4 p (r, g, b, the coat's share). ids, weights: (count, 3) from view_lookup; prim,
 * dirs: the centre rays' faces (-1: a miss) and unit directions; face_normal (faces, 3);
 * texel_dir (4^m, VC_SUB^2, 4) the directions of the centres of each texel's VC_SUB x VC_SUB parts
 * (row-major in the texel), gl (4^m) and radiance (4^m, 4): the lighting's
 * leaf masses and mean radiance, all in Morton order; offsets (blocks, 4^m) the entries of the
 * coefficients of the 2^m x 2^m layout per block (row-major). */
__kernel void view_converge_trees(const uint count, __global const uint *ids, __global const float *weights,
                                  __global const int *prim,
                                  __global const float *dirs, __global const float *face_normal,
                                  __global const int *face_material, __global const int *mat_kind,
                                  __global const float *mat_param, __global const int *offsets,
                                  __global const float *scale, __global const VQTYPE *data,
                                  __global const float4 *texel_dir, __global const float *gl,
                                  __global const float *radiance, const float hs, const uint tree_stride,
                                  __global float *out, __global float *relit, __global const float *mat_albedo,
                                  __global const float *table)
{
    const uint p = get_global_id(0);
    if (p >= count) return;
    __global float *tree = out + (size_t)p * tree_stride + TREE_ORIGIN;
    __global float *g_out = relit + 4 * (size_t)p;
    const int f = prim[p];
    uint b[3], j[3];
    float wt[3];
    float total = 0.0f;
    for (int k = 0; k < 3; ++k) {
        const uint q = ids[3 * p + k];
        b[k] = q / POINTS;
        j[k] = q % POINTS;
        wt[k] = weights[3 * p + k];
        total += wt[k];
    }
    if (f < 0 || !(total > 0.0f)) {   /* no cache point: no product */
        tree[0] = 0.0f;
        g_out[0] = g_out[1] = g_out[2] = g_out[3] = 0.0f;
        return;
    }
    float node[VC_NODES];
    node[0] = vc_coeff(0u, 0u, b, j, wt, offsets, scale, data);
    for (uint l = 0; l < N_LEVELS; ++l) {
        const uint at = (uint)LEVEL_OFFSET(l), below = (uint)LEVEL_OFFSET(l + 1), s = 1u << l;
        for (uint k = 0; k < (1u << (2 * l)); ++k) {
            const uint x = vc_compact(k), y = vc_compact(k >> 1);
            const float a = node[at + k];
            const float d1 = vc_coeff(y, s + x, b, j, wt, offsets, scale, data);
            const float d2 = vc_coeff(s + y, x, b, j, wt, offsets, scale, data);
            const float d3 = vc_coeff(s + y, s + x, b, j, wt, offsets, scale, data);
            node[below + 4 * k] = 0.5f * ((a + d1) + (d2 + d3));
            node[below + 4 * k + 1] = 0.5f * ((a - d1) + (d2 - d3));
            node[below + 4 * k + 2] = 0.5f * ((a + d1) - (d2 + d3));
            node[below + 4 * k + 3] = 0.5f * ((a - d1) - (d2 - d3));
        }
    }
    /* the pixel's shading frame (the face normal turned towards the viewer) and view */
    const float dx = dirs[3 * p], dy = dirs[3 * p + 1], dz = dirs[3 * p + 2];
    float nx = face_normal[3 * f], ny = face_normal[3 * f + 1], nz = face_normal[3 * f + 2];
    if (nx * dx + ny * dy + nz * dz > 0.0f) {
        nx = -nx;
        ny = -ny;
        nz = -nz;
    }
    const float sign = nz >= 0.0f ? 1.0f : -1.0f;
    const float fa = -1.0f / (sign + nz);
    const float fb = nx * ny * fa;
    const float sx = 1.0f + sign * nx * nx * fa, sy = sign * fb, sz = -sign * nx;
    const float tx = fb, ty = sign + ny * ny * fa, tz = -ny;
    const float ox = -(dx * sx + dy * sy + dz * sz), oy = -(dx * tx + dy * ty + dz * tz);
    const float oz = -(dx * nx + dy * ny + dz * nz);
    const int mat = face_material[f];
    const int kd = mat_kind[mat];
    /* plastic: f_r = base + coat / lum(albedo) (its two lobes, view_product's VIEW_BASE and
     * VIEW_COAT; the coat in units of the albedo's luminance, as the shade's tint takes it) */
    const int plastic = kd == BSDF_PLASTIC;
    const uint tr = plastic ? (uint)mat * PLASTIC_STRIDE : 0u;
    const float alpha = plastic ? table[tr + 3] : mat_param[mat];
    const float pa = kd == BSDF_GGX || plastic ? alpha * alpha : mat_param[mat];
    const float tco = plastic ? table[tr + 2] * view_transmittance(table, tr, oz) : 0.0f;
    const float inv_la = plastic ? 1.0f / MAX1(VC_LR * mat_albedo[3 * mat] + VC_LG * mat_albedo[3 * mat + 1]
                                               + VC_LB * mat_albedo[3 * mat + 2], VC_MIN_LUM) : 0.0f;
    float g1o = 0.0f;
    if (kd == BSDF_GGX || plastic) {   /* a2 G1(wo) / (2 pi cos_o), 0 below (view_product's) */
        const float c2 = MAX1(oz * oz, 1e-30f);
        const float tan2 = MAX1(1.0f - c2, 0.0f) / c2;
        g1o = oz > 0.0f ? 2.0f / (1.0f + SQRT1(1.0f + pa * tan2)) * pa * INV_2PI_F / oz : 0.0f;
    }
    /* the leaves and G */
    const uint leaf0 = (uint)LEVEL_OFFSET(N_LEVELS);
    const float per_texel = 1.0f / (float)VC_TEXELS;
    float gr = 0.0f, gg = 0.0f, gb = 0.0f, coat_y = 0.0f, all_y = 0.0f;
    for (uint t = 0; t < VC_TEXELS; ++t) {
        float fr = 0.0f, fc = 0.0f;
        for (uint q = 0; q < VC_SUB * VC_SUB; ++q) {
            const float4 c = texel_dir[t * VC_SUB * VC_SUB + q];
            const float ix = c.x * sx + c.y * sy + c.z * sz, iy = c.x * tx + c.y * ty + c.z * tz;
            const float iz = c.x * nx + c.y * ny + c.z * nz;
            if (plastic) {
                fr += iz > 0.0f ? view_brdf(VIEW_BASE, pa, ix, iy, iz, ox, oy, oz, g1o, table, tr, tco) : 0.0f;
                fc += iz > 0.0f ? view_brdf(VIEW_COAT, pa, ix, iy, iz, ox, oy, oz, g1o, table, tr, tco) : 0.0f;
            } else {
                fr += iz > 0.0f ? view_brdf(kd, pa, ix, iy, iz, ox, oy, oz, g1o, table, tr, tco) : 0.0f;
            }
        }
        fc *= inv_la / (float)(VC_SUB * VC_SUB);
        fr = fr * (1.0f / (float)(VC_SUB * VC_SUB)) + fc;
        const float g = gl[t];
        const float leaf = g > 0.0f ? MAX1(fr * (node[leaf0 + t] * hs), 0.0f) * per_texel : 0.0f;
        if (leaf > 0.0f) {
            const float h = leaf / g;
            gr += h * radiance[4 * t];
            gg += h * radiance[4 * t + 1];
            gb += h * radiance[4 * t + 2];
            if (plastic) {   /* the coat's share of the relit luminance */
                const float y = h * (VC_LR * radiance[4 * t] + VC_LG * radiance[4 * t + 1]
                                     + VC_LB * radiance[4 * t + 2]);
                all_y += y;
                coat_y += y * (fc / fr);
            }
        }
        node[leaf0 + t] = leaf;
    }
    for (int l = N_LEVELS - 1; l >= 0; --l) {
        const uint at = (uint)LEVEL_OFFSET(l), below = (uint)LEVEL_OFFSET(l + 1);
        for (uint k = 0; k < (1u << (2 * l)); ++k)
            node[at + k] = (node[below + 4 * k] + node[below + 4 * k + 1])
                           + (node[below + 4 * k + 2] + node[below + 4 * k + 3]);
    }
    for (uint i = 0; i < (uint)VC_NODES; ++i)
        tree[i] = node[i];
    g_out[0] = gr;
    g_out[1] = gg;
    g_out[2] = gb;
    g_out[3] = all_y > 0.0f ? clamp(coat_y / all_y, 0.0f, 1.0f) : 0.0f;   /* the control variate's tint */
}
