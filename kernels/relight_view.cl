/* Frames from a moving camera (Chen & Gao sec. 2.2, eq. 6-8, the view the varying factor): the
 * double product B = <T1, f_r(x, ., wo) rho> of baked transfer T1 = L V cos (Haar coefficients
 * on the world-frame lat-long square of N = 2^n texels, three channels, compressed and quantized
 * in blocks of POINTS points: wavlight/relight/view.py) and the BRDF without its albedo,
 * evaluated top-down over T1's quadtree (eq. 13's nonstandard basis).
 * numpy twin: wavlight/relight/view.py product_reference.
 *
 * An item is K cache points with weights (K = 1: a cache point; K = 3: a pixel, its lattice
 * triangle's points and barycentric weights): its T1 is sum_k w_k T1_k (the product is linear
 * in T1, so its coefficients are the blend of the points' coefficients), shaded with normal n
 * and view direction wo (the point's own, or the pixel's face normal and camera ray). With T1
 * as a function on the unit square (texel values), B = sum_t T1_t f_t = integral T1 f du dv N^2.
 * A node (l, x, y) of side 2^-l holds T1's average A over its square; its children's averages
 * are A + 2^l (s1 c1 + s2 c2 + s1 s2 c3), c_m its three wavelet coefficients (the dense layout
 * of wavlight/haar: c1 at [y, s + x], c2 at [s + y, x], c3 at [s + y, s + x], s = 2^l), s1 = +1
 * on the left half, s2 = +1 on the top half. A node is a leaf of the walk when f is nearly
 * constant over it: its angular radius r (of the node's row, tabulated) is at most
 * REFINE (delta + w), delta the angle between its centre and the lobe's axis (the mirror
 * direction), w the lobe's width; or at texel level. A leaf adds A (N^2 / 4^l) f(centre) rho
 * (the midpoint rule over the node; exact for constant f). A node wholly below n's horizon is
 * skipped and not read (no light reaches the surface from there).
 *
 * The cosine. T1 holds max(cos, 0) at the points' normals; where their blend m = sum_k w_k n_k
 * (not normalized) is the item's T1 normal, sum_k w_k T1_k = L V (m . w) above every point's
 * horizon. With a correction tolerance tau > 0 the leaf's factor is rho = h(n . c, sin r) /
 * h(m . c, |m| sin r), h(x, s) the mean of max(x', 0) over x' uniform in [x - s, x + s] (the
 * node's spread of the cosine), at most RHO_MAX: the item's own max(n . w, 0) in place of the
 * baked one; a node is also refined while |n - m| sin r > tau max(m . c, sin r, RHO_FLOOR) (rho
 * varies over it; T1 is small near m's horizon). tau = 0: rho = 1 (the baked cosine).
 * lambert's f = 1 / pi is constant: where rho is constant over the sphere (tau = 0, or n = m / |m|
 * and rho = 1 / |m|) B = A_root N^2 / pi rho from the one scaling coefficient. Only the coefficients of nodes the walk refines are read: the entry
 * of coefficient i in a point's block b is offsets[i B + b] (-1: not kept), its value
 * scale[o] q[o ROW + c POINTS + j] for channel c of the block's point j.
 *
 * One work-item per item, a private stack of at most 3 n + 1 nodes. */
#include "bsdf.h"

#ifndef QBITS
#define QBITS 8
#endif
#ifndef POINTS
#define POINTS 256
#endif
#if QBITS == 8
#define VQTYPE char
#else
#define VQTYPE short
#endif
#define ROW (3 * POINTS)
#ifndef K
#define K 1
#endif
#define RHO_MAX 4.0f      /* view.py RHO_MAX */
#define RHO_FLOOR 0.5f    /* view.py RHO_FLOOR */
#define STACK 40
/* scalar forms (kernels/simd.h redefines sqrt and fmax for the lane vectors) */
#if defined(WL_INLINE_BUILTINS)
#define SQRT1(x) __builtin_sqrtf(x)
#else
#define SQRT1(x) sqrt(x)
#endif
#define MAX1(a, b) ((a) > (b) ? (a) : (b))

/* f_r(wi, wo) without albedo and without cos theta_i (T1 holds the cosine), in the local frame
 * (normal +z): lambert 1 / pi, normalized phong (e + 2) / (2 pi) cos^e(alpha), ggx
 * D G1(wo) G1(wi) / (4 cos_i cos_o) with G1(wi) / cos_i = 2 / (z + sqrt(a2 + (1 - a2) z^2)) at
 * z = max(cos_i, 0) (finite at the horizon; below it T1 is 0). */
inline float view_brdf(const int kd, const float pa, const float ix, const float iy, const float iz,
                       const float ox, const float oy, const float oz, const float g1o)
{
    if (kd == BSDF_PHONG) {
        const float ca = MAX1(iz * oz - ix * ox - iy * oy, 0.0f);
        return ca > 0.0f ? (pa + 2.0f) * INV_2PI_F * exp2(pa * log2(ca)) : 0.0f;
    }
    if (kd == BSDF_GGX) {
        const float a2 = pa * pa;
        const float hx = ix + ox, hy = iy + oy, hz = iz + oz;
        const float hh = hx * hx + hy * hy + hz * hz;
        if (!(hh > 0.0f)) return 0.0f;
        const float il = 1.0f / SQRT1(hh);
        const float nhz = hz * il;
        if (!(nhz > 0.0f) || !((ix * hx + iy * hy + iz * hz) > 0.0f) || !(oz > 0.0f)) return 0.0f;
        const float d = nhz * nhz * (a2 - 1.0f) + 1.0f;
        const float D = a2 / (PI_F * d * d);
        const float z = MAX1(iz, 0.0f);
        const float gi = 2.0f / (z + SQRT1(a2 + (1.0f - a2) * z * z));
        return D * g1o / (4.0f * oz) * gi;
    }
    return INV_PI_F;
}

/* the blend sum_k w_k c_k of coefficient i of the item's points */
inline float3 view_coeff(const uint i, const uint n_blocks, const uint *b, const uint *j, const float *wt,
                         __global const int *offsets, __global const float *scale, __global const VQTYPE *data)
{
    float3 v = (float3)(0.0f);
    for (int k = 0; k < K; ++k) {
        const int o = offsets[(size_t)i * n_blocks + b[k]];
        if (o >= 0) {
            const size_t at = (size_t)o * ROW + j[k];
            v += (wt[k] * scale[o]) * (float3)((float)data[at], (float)data[at + POINTS], (float)data[at + 2 * POINTS]);
        }
    }
    return v;
}

/* the mean of max(x', 0) over x' in [x - s, x + s] */
inline float view_ramp(const float x, const float s)
{
    return x >= s ? x : (x <= -s ? 0.0f : (x + s) * (x + s) / (4.0f * s));
}

__kernel void view_product(const uint count, const uint n_levels, const uint n_blocks,
                           __global const uint *point, __global const float *weight, __global const float *geom,
                           __global const int *kind, __global const float *param, __global const float4 *centres,
                           __global const float4 *rows, __global const int *offsets,
                           __global const float *scale, __global const VQTYPE *data,
                           __global float *out, __global uint *visited)
{
    const uint i = get_global_id(0);
    if (i >= count) return;
    uint b[K], j[K];
    float wt[K];
    for (int k = 0; k < K; ++k) {
        const uint p = point[K * i + k];
        b[k] = p / POINTS;
        j[k] = p % POINTS;
        wt[k] = weight[K * i + k];
    }
    const uint side = 1u << n_levels;
    const float n2 = (float)(side * side);
    const float3 root = view_coeff(0u, n_blocks, b, j, wt, offsets, scale, data);
    /* geom: shading normal n, view direction, lobe axis (world), the lobe width w, cos w, sin w,
     * T1's normal m, the correction tolerance tau */
    __global const float *g = geom + 16 * (size_t)i;
    const float3 n = (float3)(g[0], g[1], g[2]);
    const float3 m = (float3)(g[12], g[13], g[14]);
    const float tau = g[15];
    const float ml = length(m);
    const float dn = length(n - m);
    const int kd = kind[i];
    if (kd == BSDF_LAMBERT && (tau <= 0.0f || dot(n, m) >= ml * (1.0f - 1e-6f))) {
        const float3 v = root * (n2 * INV_PI_F / (tau > 0.0f ? MAX1(ml, 1e-6f) : 1.0f));
        out[3 * i] = v.x;
        out[3 * i + 1] = v.y;
        out[3 * i + 2] = v.z;
        visited[i] = 1u;
        return;
    }
    const float3 wo = (float3)(g[3], g[4], g[5]);
    const float3 axis = (float3)(g[6], g[7], g[8]);
    const float w = g[9], cw = g[10], sw = g[11];
    const float sign = n.z >= 0.0f ? 1.0f : -1.0f;
    const float fa = -1.0f / (sign + n.z);
    const float fb = n.x * n.y * fa;
    const float3 s = (float3)(1.0f + sign * n.x * n.x * fa, sign * fb, -sign * n.x);
    const float3 t = (float3)(fb, sign + n.y * n.y * fa, -n.y);
    const float ox = dot(wo, s), oy = dot(wo, t), oz = dot(wo, n);
    const float pa = param[i];
    float g1o = 0.0f;
    if (kd == BSDF_GGX) {
        const float a2 = pa * pa;
        const float c2 = MAX1(oz * oz, 1e-30f);
        const float tan2 = MAX1(1.0f - c2, 0.0f) / c2;
        g1o = oz > 0.0f ? 2.0f / (1.0f + SQRT1(1.0f + a2 * tan2)) : 0.0f;
    }
    uint node[STACK];
    float3 avg[STACK];
    int top = 0;
    node[0] = 0u;
    avg[0] = root;
    top = 1;
    float3 acc = (float3)(0.0f);
    uint nodes = 0u;
    while (top > 0) {
        --top;
        const uint code = node[top];
        const float3 a = avg[top];
        const uint l = code >> 24, y = (code >> 12) & 0xFFFu, x = code & 0xFFFu;
        const uint s_l = 1u << l;
        ++nodes;
        const float4 rr = rows[s_l - 1u + y];                 /* r / REFINE, cos, sin of it, sin r */
        const float3 c = centres[(s_l * s_l - 1u) / 3u + y * s_l + x].xyz;
        const float nc = dot(c, n);
        if (nc < -rr.w) continue;                             /* wholly below the horizon */
        int leaf = l == n_levels;
        if (!leaf) {
            const float need = rr.x - w;                      /* r / REFINE - w: refine while delta < it */
            leaf = need <= 0.0f || (need < PI_F && dot(c, axis) <= rr.y * cw + rr.z * sw);   /* cos(need) */
            if (leaf && tau > 0.0f) {
                const float sr = rr.w > 1.0f ? 1.0f : rr.w;
                leaf = sr * dn <= tau * MAX1(dot(c, m), MAX1(sr, RHO_FLOOR));
            }
        }
        if (leaf) {
            float f = view_brdf(kd, pa, dot(c, s), dot(c, t), nc, ox, oy, oz, g1o);
            if (tau > 0.0f) {
                const float sr = rr.w > 1.0f ? 1.0f : rr.w;
                const float den = view_ramp(dot(c, m), sr * ml);
                f *= den > 0.0f ? fmin(view_ramp(nc, sr) / den, RHO_MAX) : 0.0f;
            }
            acc += a * (n2 / (float)(s_l * s_l) * f);
            continue;
        }
        const uint i1 = y * side + s_l + x, i2 = (s_l + y) * side + x, i3 = (s_l + y) * side + s_l + x;
        const float3 c1 = view_coeff(i1, n_blocks, b, j, wt, offsets, scale, data);
        const float3 c2 = view_coeff(i2, n_blocks, b, j, wt, offsets, scale, data);
        const float3 c3 = view_coeff(i3, n_blocks, b, j, wt, offsets, scale, data);
        const float k = (float)s_l;
        const uint l1 = (l + 1u) << 24;
        /* children: (dx, dy) = (0, 0) top-left, (1, 0), (0, 1), (1, 1) */
        node[top] = l1 | ((2u * y) << 12) | (2u * x);
        avg[top++] = a + k * (c1 + c2 + c3);
        node[top] = l1 | ((2u * y) << 12) | (2u * x + 1u);
        avg[top++] = a + k * (-c1 + c2 - c3);
        node[top] = l1 | ((2u * y + 1u) << 12) | (2u * x);
        avg[top++] = a + k * (c1 - c2 - c3);
        node[top] = l1 | ((2u * y + 1u) << 12) | (2u * x + 1u);
        avg[top++] = a + k * (-c1 - c2 + c3);
    }
    out[3 * i] = acc.x;
    out[3 * i + 1] = acc.y;
    out[3 * i + 2] = acc.z;
    visited[i] = nodes;
}
