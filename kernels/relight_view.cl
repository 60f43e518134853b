/* Frames from a moving camera (Chen & Gao sec. 2.2, eq. 6-8, the view the varying factor): the
 * double product B = <T1(x), f_r(x, ., wo)> of a surface point's baked transfer T1 = L V cos
 * (Haar coefficients on the world-frame lat-long square of N = 2^n texels, three channels,
 * compressed and quantized in blocks of POINTS points: wavlight/relight/view.py) and the BRDF
 * without its albedo, evaluated top-down over T1's quadtree (eq. 13's nonstandard basis).
 * numpy twin: wavlight/relight/view.py product_reference.
 *
 * With T1 as a function on the unit square (texel values), B = sum_t T1_t f_t
 * = integral T1 f du dv N^2. A node (l, x, y) of side 2^-l holds T1's average A over its
 * square; its children's averages are A + 2^l (s1 c1 + s2 c2 + s1 s2 c3), c_m its three
 * wavelet coefficients (the dense layout of wavlight/haar: c1 at [y, s + x], c2 at [s + y, x],
 * c3 at [s + y, s + x], s = 2^l), s1 = +1 on the left half, s2 = +1 on the top half. A node is
 * a leaf of the walk when f is nearly constant over it: its angular radius r (of the node's
 * row, tabulated) is at most REFINE (delta + w), delta the angle between its centre and the
 * lobe's axis (the mirror direction), w the lobe's width; or at texel level. A leaf adds
 * A (N^2 / 4^l) f(centre) (the midpoint rule over the node; exact for constant f). A node
 * wholly below the point's horizon adds nothing (T1 = 0 there: max(cos, 0) is inside it) and
 * is not read. lambert's f = 1 / pi is constant: B = A_root N^2 / pi from the one scaling
 * coefficient. Only the coefficients of nodes the walk refines are read: the entry of
 * coefficient i in the point's block is offsets[i B + b] (-1: not kept), its value
 * scale[o] q[o ROW + c POINTS + j] for channel c of the block's point j.
 *
 * One work-item per item (a point with its normal n, view direction wo, material and lobe
 * axis), a private stack of at most 3 n + 1 nodes. */
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

__kernel void view_product(const uint count, const uint n_levels, const uint n_blocks,
                           __global const uint *point, __global const float *geom, __global const int *kind,
                           __global const float *param, __global const float4 *centres,
                           __global const float4 *rows, __global const int *offsets,
                           __global const float *scale, __global const VQTYPE *data,
                           __global float *out, __global uint *visited)
{
    const uint i = get_global_id(0);
    if (i >= count) return;
    const uint p = point[i], b = p / POINTS, j = p % POINTS;
    const uint side = 1u << n_levels;
    const float n2 = (float)(side * side);
    float3 root = (float3)(0.0f);
    {
        const int o = offsets[b];
        if (o >= 0) {
            const size_t at = (size_t)o * ROW + j;
            root = scale[o] * (float3)((float)data[at], (float)data[at + POINTS], (float)data[at + 2 * POINTS]);
        }
    }
    const int kd = kind[i];
    if (kd == BSDF_LAMBERT) {
        const float3 v = root * (n2 * INV_PI_F);
        out[3 * i] = v.x;
        out[3 * i + 1] = v.y;
        out[3 * i + 2] = v.z;
        visited[i] = 1u;
        return;
    }
    /* geom: normal, view direction, lobe axis (world), the lobe width w, cos w, sin w */
    __global const float *g = geom + 12 * (size_t)i;
    const float3 n = (float3)(g[0], g[1], g[2]);
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
        if (dot(c, n) < -rr.w) continue;                      /* wholly below the horizon */
        int leaf = l == n_levels;
        if (!leaf) {
            const float need = rr.x - w;                      /* r / REFINE - w: refine while delta < it */
            leaf = need <= 0.0f || (need < PI_F && dot(c, axis) <= rr.y * cw + rr.z * sw);   /* cos(need) */
        }
        if (leaf) {
            const float f = view_brdf(kd, pa, dot(c, s), dot(c, t), dot(c, n), ox, oy, oz, g1o);
            acc += a * (n2 / (float)(s_l * s_l) * f);
            continue;
        }
        const uint i1 = y * side + s_l + x, i2 = (s_l + y) * side + x, i3 = (s_l + y) * side + s_l + x;
        float3 c1 = (float3)(0.0f), c2 = (float3)(0.0f), c3 = (float3)(0.0f);
        {
            const int o1 = offsets[(size_t)i1 * n_blocks + b];
            const int o2 = offsets[(size_t)i2 * n_blocks + b];
            const int o3 = offsets[(size_t)i3 * n_blocks + b];
            if (o1 >= 0) { const size_t at = (size_t)o1 * ROW + j;
                c1 = scale[o1] * (float3)((float)data[at], (float)data[at + POINTS], (float)data[at + 2 * POINTS]); }
            if (o2 >= 0) { const size_t at = (size_t)o2 * ROW + j;
                c2 = scale[o2] * (float3)((float)data[at], (float)data[at + POINTS], (float)data[at + 2 * POINTS]); }
            if (o3 >= 0) { const size_t at = (size_t)o3 * ROW + j;
                c3 = scale[o3] * (float3)((float)data[at], (float)data[at + POINTS], (float)data[at + 2 * POINTS]); }
        }
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
