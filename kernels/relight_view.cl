/* Frames from a moving camera (Chen & Gao sec. 2.2, eq. 6-8, the view the varying factor): the
 * double product B = <T1, f_r(x, ., wo) rho> of baked transfer T1 = L V cos (Haar coefficients
 * on the world-frame lat-long square of N = 2^n texels, three channels, compressed and quantized
 * in blocks of POINTS points: wavlight/relight/view_bake.py) and the BRDF without its albedo,
 * evaluated top-down over T1's quadtree (eq. 13's nonstandard basis). plastic walks as two items,
 * its coat (VIEW_COAT) and its base (VIEW_BASE, the albedo's part), from its row of the plastic
 * table (``table`` at ``table_row[i]``; other kinds read neither).
 * numpy twin: wavlight/relight/view_walk.py product_reference.
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
 * REFINE (delta + w) / g, delta the angle between its centre and the lobe's axis (the mirror
 * direction), w the lobe's width, g = max(1, sqrt(phi / mass)) rounded up to a power of two
 * 2^k, k <= MASS_STEPS, for a node holding the share phi of T1's mass (the sum of its channels'
 * |A| times its area over the root's; mass = 0: g = 1; cos and sin of the scaled radius from the
 * table ``scaled``); or at texel level. A leaf adds A (N^2 / 4^l) f(centre) rho
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
 * One work-item per item, a private stack of the nodes to refine (at most 3 n + 1). A refined
 * node's four children are tested and evaluated together, lane by lane of float4 (the CPU's
 * vector unit across the children; one BRDF call per four leaves), and only the children to be
 * refined are pushed; the nodes visited are the root and four per refined node. */
#include "bsdf.h"
#include "texture.h"
#ifndef TEXTURES
#define TEXTURES 0   /* 1: some material has a base-colour texture (texture.h): view_assemble reads it */
#endif

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
#ifndef MASS_STEPS
#define MASS_STEPS 8      /* view_walk.py MASS_STEPS */
#endif
#define RHO_MAX 4.0f      /* view_walk.py RHO_MAX */
#define RHO_FLOOR 0.5f    /* view_walk.py RHO_FLOOR */
#define STACK 40
/* scalar forms (kernels/simd.h redefines sqrt and fmax for the lane vectors) */
#if defined(WL_INLINE_BUILTINS)
#define SQRT1(x) __builtin_sqrtf(x)
#else
#define SQRT1(x) sqrt(x)
#endif
#define MAX1(a, b) ((a) > (b) ? (a) : (b))
/* float3 products written out (the library's dot and length are calls on some PoCL builds) */
#define DOT3(a, b) ((a).x * (b).x + (a).y * (b).y + (a).z * (b).z)
#define LEN3(a) SQRT1(DOT3(a, a))

/* plastic (Mitsuba 3's roughplastic, kernels/bsdf.h) walks as two items, its lobes (f cos =
 * coat + albedo base): VIEW_COAT, F(wo . h, eta) times ggx's f (pa = alpha^2), and VIEW_BASE,
 * T(cos_o) T(cos_i) / (pi eta^2 (1 - R_int)) (the albedo's part, lambert-like; tco = the table's
 * diffuse scale times T(cos_o), per item). Their table: the material's row of the plastic table
 * (PLASTIC_STRIDE floats: eta, sampling weight, diffuse scale, alpha, T at PLASTIC_RES cosines);
 * numpy twin: view_walk.py brdf_reference. */
#define VIEW_COAT 4   /* view_walk.py VIEW_COAT */
#define VIEW_BASE 5   /* view_walk.py VIEW_BASE */

/* T(c) of the row at tr, linear between its entries (bsdf.h plastic_transmittance, one lane) */
inline float view_transmittance(__global const float *table, const uint tr, const float c)
{
    const float x = clamp(c, 0.0f, 1.0f) * (float)(PLASTIC_RES - 1);
    const uint i = min((uint)x, (uint)(PLASTIC_RES - 2));
    const float v0 = table[tr + PLASTIC_HEAD + i], v1 = table[tr + PLASTIC_HEAD + 1 + i];
    return v0 + (v1 - v0) * (x - (float)i);
}

/* the unpolarized Fresnel reflectance from outside at cosine c >= 0 (bsdf.h fresnel_dielectric) */
inline float view_fresnel(const float c, const float eta)
{
    const float ci = fabs(c);
    const float inv = 1.0f / eta;
    const float ct = SQRT1(MAX1(1.0f - (1.0f - ci * ci) * inv * inv, 0.0f));
    const float a_s = (ci - eta * ct) / (ci + eta * ct), a_p = (ct - eta * ci) / (ct + eta * ci);
    return ci == 0.0f ? 1.0f : 0.5f * (a_s * a_s + a_p * a_p);
}

/* f_r(wi, wo) without albedo and without cos theta_i (T1 holds the cosine), in the local frame
 * (normal +z): lambert 1 / pi, normalized phong (e + 2) / (2 pi) cos^e(alpha) (pa = e), ggx
 * D G1(wo) G1(wi) / (4 cos_i cos_o) with G1(wi) / cos_i = 2 / (z + sqrt(a2 + (1 - a2) z^2)) at
 * z = max(cos_i, 0) (finite at the horizon; below it T1 is 0). For ggx pa = a2 = alpha^2 and
 * g1o = a2 G1(wo) / (2 pi cos_o) (per item), and D = a2 / (pi (nhz^2 (a2 - 1) + 1)^2) with
 * nhz^2 = hz^2 / |h|^2 (h = wi + wo unnormalized) is a2 |h|^4 / (pi q^2), q = hz^2 (a2 - 1) + |h|^2:
 * f = g1o |h|^4 / (q^2 (z + sqrt(a2 + (1 - a2) z^2))), one square root and one division. */
inline float view_brdf(const int kd, const float pa, const float ix, const float iy, const float iz,
                       const float ox, const float oy, const float oz, const float g1o,
                       __global const float *table, const uint tr, const float tco)
{
    if (kd == VIEW_BASE) return iz > 0.0f ? tco * view_transmittance(table, tr, iz) : 0.0f;
    if (kd == VIEW_COAT) {
        const float hx = ix + ox, hy = iy + oy, hz = iz + oz;
        if (!(hz > 0.0f) || !((ix * hx + iy * hy + iz * hz) > 0.0f)) return 0.0f;
        const float hh = hx * hx + hy * hy + hz * hz;
        const float q = hz * hz * (pa - 1.0f) + hh;
        const float z = MAX1(iz, 0.0f);
        const float oh = (ox * hx + oy * hy + oz * hz) / SQRT1(hh);
        return view_fresnel(oh, table[tr]) * g1o * (hh * hh) / (q * q * (z + SQRT1(pa + (1.0f - pa) * z * z)));
    }
    if (kd == BSDF_PHONG) {
        const float ca = MAX1(iz * oz - ix * ox - iy * oy, 0.0f);
        return ca > 0.0f ? (pa + 2.0f) * INV_2PI_F * exp2(pa * log2(ca)) : 0.0f;
    }
    if (kd == BSDF_GGX) {
        const float hx = ix + ox, hy = iy + oy, hz = iz + oz;
        if (!(hz > 0.0f) || !((ix * hx + iy * hy + iz * hz) > 0.0f)) return 0.0f;   /* nhz > 0, wi . h > 0 */
        const float hh = hx * hx + hy * hy + hz * hz;
        const float q = hz * hz * (pa - 1.0f) + hh;
        const float z = MAX1(iz, 0.0f);
        return g1o * (hh * hh) / (q * q * (z + SQRT1(pa + (1.0f - pa) * z * z)));
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

/* four lanes: sqrt lane by lane (simd.h's inline sqrt covers float and its LANES vectors) */
#define SQRT4(q_) ((float4)(SQRT1((q_).x), SQRT1((q_).y), SQRT1((q_).z), SQRT1((q_).w)))
inline int any4(const int4 m)
{
    return (m.x | m.y | m.z | m.w) != 0;
}

/* view_brdf on four directions (the same item) */
inline float4 view_brdf4(const int kd, const float pa, const float4 ix, const float4 iy, const float4 iz,
                         const float ox, const float oy, const float oz, const float g1o,
                         __global const float *table, const uint tr, const float tco)
{
    if (kd == VIEW_BASE) {   /* the transmittance's entries lane by lane */
        const float4 t = (float4)(view_transmittance(table, tr, iz.x), view_transmittance(table, tr, iz.y),
                                  view_transmittance(table, tr, iz.z), view_transmittance(table, tr, iz.w));
        return iz > 0.0f ? tco * t : (float4)(0.0f);
    }
    if (kd == VIEW_COAT) {   /* ggx's four lanes times view_fresnel's */
        const float4 hx = ix + ox, hy = iy + oy, hz = iz + oz;
        const float4 hh = hx * hx + hy * hy + hz * hz;
        const float4 q = hz * hz * (pa - 1.0f) + hh;
        const float4 z = iz > 0.0f ? iz : (float4)(0.0f);
        const float4 f = g1o * (hh * hh) / (q * q * (z + SQRT4(pa + (1.0f - pa) * z * z)));
        const float4 oh = (ox * hx + oy * hy + oz * hz) / SQRT4(hh);
        const float eta = table[tr], inv = 1.0f / eta;
        const float4 ct2 = 1.0f - (1.0f - oh * oh) * (inv * inv);
        const float4 ct = SQRT4(ct2 > 0.0f ? ct2 : (float4)(0.0f));
        const float4 a_s = (oh - eta * ct) / (oh + eta * ct), a_p = (ct - eta * oh) / (ct + eta * oh);
        const float4 fr = oh == 0.0f ? (float4)(1.0f) : 0.5f * (a_s * a_s + a_p * a_p);
        return ((hz > 0.0f) & (ix * hx + iy * hy + iz * hz > 0.0f)) ? fr * f : (float4)(0.0f);
    }
    if (kd == BSDF_PHONG) {
        const float4 ca = iz * oz - ix * ox - iy * oy;
        const float4 cp = ca > 0.0f ? ca : (float4)(1.0f);
        return ca > 0.0f ? (pa + 2.0f) * INV_2PI_F * exp2(pa * log2(cp)) : (float4)(0.0f);
    }
    if (kd == BSDF_GGX) {
        const float4 hx = ix + ox, hy = iy + oy, hz = iz + oz;
        const float4 hh = hx * hx + hy * hy + hz * hz;
        const float4 q = hz * hz * (pa - 1.0f) + hh;
        const float4 z = iz > 0.0f ? iz : (float4)(0.0f);
        const float4 f = g1o * (hh * hh) / (q * q * (z + SQRT4(pa + (1.0f - pa) * z * z)));
        return ((hz > 0.0f) & (ix * hx + iy * hy + iz * hz > 0.0f)) ? f : (float4)(0.0f);
    }
    return (float4)(INV_PI_F);
}

/* view_ramp on four lanes */
inline float4 view_ramp4(const float4 x, const float4 s)
{
    return x >= s ? x : (x <= -s ? (float4)(0.0f) : (x + s) * (x + s) / (4.0f * s));
}

/* k = min(ceil(log2(share) / 2), MASS_STEPS) for share = phi / mass > 1, else 0: the walk's
 * g = 2^k >= sqrt(share) (numpy twin: view_walk.py mass_steps) */
inline uint view_mass_steps(const float share)
{
    if (!(share > 1.0f)) return 0u;
    const uint bits = as_uint(share);
    const int c = (int)((bits >> 23) & 0xFFu) - 127 + ((bits & 0x7FFFFFu) != 0u ? 1 : 0);   /* ceil(log2) */
    const uint k = (uint)(c + 1) >> 1;
    return k < MASS_STEPS ? k : MASS_STEPS;
}

__kernel void view_product(const uint count, const uint n_levels, const uint n_blocks,
                           __global const uint *point, __global const float *weight, __global const float *geom,
                           __global const int *kind, __global const float *param, __global const float4 *centres,
                           __global const float4 *rows, __global const float2 *scaled, __global const int *offsets,
                           __global const float *scale, __global const VQTYPE *data, const float mass,
                           __global const float *table, __global const uint *table_row,
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
    /* 1 / (the root's mass x mass): a node's phi / mass is its |average| sum x this / 4^l */
    const float root_mass = fabs(root.x) + fabs(root.y) + fabs(root.z);
    const float per_mass = mass > 0.0f && root_mass > 0.0f ? (1.0f / root_mass) / mass : 0.0f;
    /* geom: shading normal n, view direction, lobe axis (world), the lobe width w, cos w, sin w,
     * T1's normal m, the correction tolerance tau */
    __global const float *g = geom + 16 * (size_t)i;
    const float3 n = (float3)(g[0], g[1], g[2]);
    const float3 m = (float3)(g[12], g[13], g[14]);
    const float tau = g[15];
    const float ml = LEN3(m);
    const float dn = LEN3(n - m);
    const int kd = kind[i];
    if (kd == BSDF_LAMBERT && (tau <= 0.0f || DOT3(n, m) >= ml * (1.0f - 1e-6f))) {
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
    const float ox = DOT3(wo, s), oy = DOT3(wo, t), oz = DOT3(wo, n);
    const int ggx_like = kd == BSDF_GGX || kd == VIEW_COAT;
    const float pa = ggx_like ? param[i] * param[i] : param[i];   /* ggx, plastic's coat: alpha^2 */
    const uint tr = kd >= VIEW_COAT ? table_row[i] : 0u;          /* plastic: the material's table row */
    const float tco = kd == VIEW_BASE ? table[tr + 2] * view_transmittance(table, tr, oz) : 0.0f;
    float g1o = 0.0f;
    if (ggx_like) {                                           /* a2 G1(wo) / (2 pi cos_o), 0 below */
        const float c2 = MAX1(oz * oz, 1e-30f);
        const float tan2 = MAX1(1.0f - c2, 0.0f) / c2;
        g1o = oz > 0.0f ? 2.0f / (1.0f + SQRT1(1.0f + pa * tan2)) * pa * INV_2PI_F / oz : 0.0f;
    }
    uint node[STACK];
    float3 avg[STACK];
    int top = 0;
    float3 acc = (float3)(0.0f);
    uint nodes = 1u;
    {   /* the root: a leaf, or the first node to refine */
        const float4 rr = rows[0];
        const float3 c = centres[0].xyz;
        const float nc = DOT3(c, n);
        if (nc >= -rr.w) {
            int leaf = n_levels == 0u;
            if (!leaf) {
                const uint k = view_mass_steps(root_mass * per_mass);
                const float need = rr.x * (float)(1u << k) - w;
                const float2 sc = k > 0u ? scaled[k - 1u] : (float2)(rr.y, rr.z);
                const float cq = sc.x, sq = sc.y;
                leaf = need <= 0.0f || (need < PI_F && DOT3(c, axis) <= cq * cw + sq * sw);
                if (leaf && tau > 0.0f) {
                    const float sr = rr.w > 1.0f ? 1.0f : rr.w;
                    leaf = sr * dn <= tau * MAX1(DOT3(c, m), MAX1(sr, RHO_FLOOR));
                }
            }
            if (leaf) {
                float f = view_brdf(kd, pa, DOT3(c, s), DOT3(c, t), nc, ox, oy, oz, g1o, table, tr, tco);
                if (tau > 0.0f) {
                    const float sr = rr.w > 1.0f ? 1.0f : rr.w;
                    const float den = view_ramp(DOT3(c, m), sr * ml);
                    f *= den > 0.0f ? fmin(view_ramp(nc, sr) / den, RHO_MAX) : 0.0f;
                }
                acc = root * (n2 * f);
            } else {
                node[0] = 0u;
                avg[0] = root;
                top = 1;
            }
        }
    }
    while (top > 0) {
        /* a node to refine: its four children at once (lanes (dx, dy) = (0, 0), (1, 0), (0, 1), (1, 1)) */
        --top;
        const uint code = node[top];
        const float3 a = avg[top];
        const uint l = code >> 24, y = (code >> 12) & 0xFFFu, x = code & 0xFFFu;
        const uint s_l = 1u << l;
        const uint i1 = y * side + s_l + x, i2 = (s_l + y) * side + x, i3 = (s_l + y) * side + s_l + x;
        const float3 c1 = view_coeff(i1, n_blocks, b, j, wt, offsets, scale, data);
        const float3 c2 = view_coeff(i2, n_blocks, b, j, wt, offsets, scale, data);
        const float3 c3 = view_coeff(i3, n_blocks, b, j, wt, offsets, scale, data);
        const float k = (float)s_l;
        float3 ak[4];
        ak[0] = a + k * (c1 + c2 + c3);
        ak[1] = a + k * (-c1 + c2 - c3);
        ak[2] = a + k * (c1 - c2 - c3);
        ak[3] = a + k * (-c1 - c2 + c3);
        const uint l1 = l + 1u, s1 = 2u * s_l;
        nodes += 4u;
        const float4 r0 = rows[s1 - 1u + 2u * y], r1 = rows[s1 - 1u + 2u * y + 1u];
        const uint cb = (s1 * s1 - 1u) / 3u + 2u * y * s1 + 2u * x;
        const float4 e0 = centres[cb], e1 = centres[cb + 1u], e2 = centres[cb + s1], e3 = centres[cb + s1 + 1u];
        const float4 cx = (float4)(e0.x, e1.x, e2.x, e3.x), cy = (float4)(e0.y, e1.y, e2.y, e3.y),
                     cz = (float4)(e0.z, e1.z, e2.z, e3.z);
        const float4 rx = (float4)(r0.x, r0.x, r1.x, r1.x), ry = (float4)(r0.y, r0.y, r1.y, r1.y),
                     rz = (float4)(r0.z, r0.z, r1.z, r1.z), rw = (float4)(r0.w, r0.w, r1.w, r1.w);
        const float4 nc = cx * n.x + cy * n.y + cz * n.z;
        const int4 live = nc >= -rw;                          /* not wholly below the horizon */
        int4 leaf;
        if (l1 == n_levels) {
            leaf = (int4)(-1);
        } else {
            /* g = 2^k >= sqrt(phi / mass) per child: a node holding much of T1's mass refines further */
            const float4 share = (float4)(fabs(ak[0].x) + fabs(ak[0].y) + fabs(ak[0].z),
                                          fabs(ak[1].x) + fabs(ak[1].y) + fabs(ak[1].z),
                                          fabs(ak[2].x) + fabs(ak[2].y) + fabs(ak[2].z),
                                          fabs(ak[3].x) + fabs(ak[3].y) + fabs(ak[3].z)) * (per_mass / (float)(s1 * s1));
            const int4 big = share > 1.0f;
            float4 rxg = rx, cq = ry, sq = rz;
            if (any4(big)) {                                  /* lane by lane, cos and sin tabulated */
                const float g4[4] = {share.x, share.y, share.z, share.w};
                float r4[4] = {rx.x, rx.y, rx.z, rx.w}, c4[4] = {ry.x, ry.y, ry.z, ry.w},
                      s4[4] = {rz.x, rz.y, rz.z, rz.w};
                for (int q = 0; q < 4; ++q) {                 /* lanes */
                    const uint k = view_mass_steps(g4[q]);
                    if (k > 0u) {
                        const float2 sc = scaled[(s1 - 1u + 2u * y + (uint)(q >> 1)) * MASS_STEPS + k - 1u];
                        r4[q] *= (float)(1u << k);
                        c4[q] = sc.x;
                        s4[q] = sc.y;
                    }
                }
                rxg = (float4)(r4[0], r4[1], r4[2], r4[3]);
                cq = (float4)(c4[0], c4[1], c4[2], c4[3]);
                sq = (float4)(s4[0], s4[1], s4[2], s4[3]);
            }
            const float4 need = rxg - w;                      /* g r / REFINE - w: refine while delta < it */
            leaf = (need <= 0.0f) | ((need < PI_F) & (cx * axis.x + cy * axis.y + cz * axis.z <= cq * cw + sq * sw));
            if (tau > 0.0f) {
                const float4 sr = rw > 1.0f ? (float4)(1.0f) : rw;
                const float4 mc = cx * m.x + cy * m.y + cz * m.z;
                const float4 hi = sr > RHO_FLOOR ? sr : (float4)(RHO_FLOOR);
                leaf &= sr * dn <= tau * (mc > hi ? mc : hi);
            }
        }
        const int4 add = live & leaf;
        if (any4(add)) {
            float4 f = view_brdf4(kd, pa, cx * s.x + cy * s.y + cz * s.z, cx * t.x + cy * t.y + cz * t.z, nc,
                                  ox, oy, oz, g1o, table, tr, tco);
            if (tau > 0.0f) {
                const float4 sr = rw > 1.0f ? (float4)(1.0f) : rw;
                const float4 den = view_ramp4(cx * m.x + cy * m.y + cz * m.z, sr * ml);
                const float4 rho = view_ramp4(nc, sr) / den;
                f *= den > 0.0f ? (rho < RHO_MAX ? rho : (float4)(RHO_MAX)) : (float4)(0.0f);
            }
            f = add ? f * (n2 / (float)(s1 * s1)) : (float4)(0.0f);
            acc += ak[0] * f.x + ak[1] * f.y + ak[2] * f.z + ak[3] * f.w;
        }
        const int4 go = live & ~leaf;
        const uint lc = (l1 << 24) | ((2u * y) << 12) | (2u * x);
        /* pushed in reverse lane order: popped in lane order */
        if (go.w) { node[top] = lc + (1u << 12) + 1u; avg[top++] = ak[3]; }
        if (go.z) { node[top] = lc + (1u << 12); avg[top++] = ak[2]; }
        if (go.y) { node[top] = lc + 1u; avg[top++] = ak[1]; }
        if (go.x) { node[top] = lc; avg[top++] = ak[0]; }
    }
    out[3 * i] = acc.x;
    out[3 * i + 1] = acc.y;
    out[3 * i + 2] = acc.z;
    visited[i] = nodes;
}

/* ------------------------------------------------------------------ the frame around the walks
 * numpy twins: wavlight/relight/view_frames.py ViewFrames.hit_points (surface_cache.py
 * lattice_points) and the assembly
 * of ViewFrames.frame's numpy backend. Lattice coordinates and the environment's direction
 * angles in double precision where the device has it (as numpy computes them: the same lattice
 * triangle and texel but within rounding of their borders), else in float. */
#ifdef cl_khr_fp64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double wide;
#else
typedef float wide;
#endif
#define WCLAMP(x, lo, hi) ((x) < (lo) ? (lo) : ((x) > (hi) ? (hi) : (x)))

/* The index inside its face's lattice of point (i, j) (i + j <= k): rows of constant j. */
inline long view_local(const long i, const long j, const long k)
{
    return j * (k + 1) - j * (j - 1) / 2 + i;
}

/* Per camera ray: the three cache points and normalized barycentric weights of its hit on face
 * prim (-1: a miss, weights 0) at embree's (u, v), the lattice triangle holding it (module
 * docstring of surface_cache.py); a point is left out (weight 0) on the face's back (dir . n_face >= 0)
 * or where its normal is further than the crease from the face's (n_point . n_face < cos_crease).
 * used[p] = 1 for every point of weight > 0 (the points the frame's walks shade). */
__kernel void view_lookup(const uint count, __global const int *prim, __global const float *hit_u,
                          __global const float *hit_v, __global const float *dir, __global const int *face_k,
                          __global const long *face_base, __global const int *lattice,
                          __global const float *point_normal, __global const float *face_normal,
                          const float cos_crease, __global uint *ids, __global float *weights,
                          __global uchar *used)
{
    const uint p = get_global_id(0);
    if (p >= count) return;
    const int f = prim[p];
    if (f < 0) {
        for (int q = 0; q < 3; ++q) {
            ids[3 * p + q] = 0u;
            weights[3 * p + q] = 0.0f;
        }
        return;
    }
    const long k = face_k[f];
    const wide fu = (wide)hit_u[p] * (wide)k, fv = (wide)hit_v[p] * (wide)k;
    const long i = WCLAMP((long)fu, 0L, k - 1);
    const long j = WCLAMP((long)fv, 0L, k - 1 - i);
    const wide a = WCLAMP(fu - (wide)i, (wide)0, (wide)1), b = WCLAMP(fv - (wide)j, (wide)0, (wide)1);
    const int upper = (a + b > (wide)1) && (i + j <= k - 2);
    wide w[3];
    long at[3];
    if (upper) {
        w[0] = a + b - (wide)1; w[1] = (wide)1 - b; w[2] = (wide)1 - a;
        at[0] = view_local(i + 1, j + 1, k); at[1] = view_local(i + 1, j, k); at[2] = view_local(i, j + 1, k);
    } else {
        w[0] = (wide)1 - a - b; w[1] = a; w[2] = b;
        at[0] = view_local(i, j, k); at[1] = view_local(i + 1, j, k); at[2] = view_local(i, j + 1, k);
    }
    const float nx = face_normal[3 * f], ny = face_normal[3 * f + 1], nz = face_normal[3 * f + 2];
    const int front = nx * dir[3 * p] + ny * dir[3 * p + 1] + nz * dir[3 * p + 2] < 0.0f;
    const long base = face_base[f];
    uint id[3];
    wide total = (wide)0;
    for (int q = 0; q < 3; ++q) {
        id[q] = (uint)lattice[base + at[q]];
        const float c = point_normal[3 * id[q]] * nx + point_normal[3 * id[q] + 1] * ny
                        + point_normal[3 * id[q] + 2] * nz;
        w[q] = (front && c >= cos_crease) ? WCLAMP(w[q], (wide)0, (wide)1) : (wide)0;
        total += w[q];
    }
    for (int q = 0; q < 3; ++q) {
        const float wq = total > (wide)0 ? (float)(w[q] / total) : 0.0f;
        ids[3 * p + q] = id[q];
        weights[3 * p + q] = wq;
        if (wq > 0.0f) used[id[q]] = (uchar)1;
    }
}

/* atan2(y, x) in float within a few 1e-7 (Cephes' atanf polynomial on [0, tan(pi / 8)], the
 * rest by atan(a) = pi / 4 + atan((a - 1) / (a + 1)) and the octants): the library's is a call. */
inline float view_atan2(const float y, const float x)
{
    const float ax = x < 0.0f ? -x : x, ay = y < 0.0f ? -y : y;
    const float hi = MAX1(ax, ay), lo = ax < ay ? ax : ay;
    const float a = hi > 0.0f ? lo / hi : 0.0f;
    const int mid = a > 0.41421356f;
    const float t = mid ? (a - 1.0f) / (a + 1.0f) : a;
    const float z = t * t;
    float r = ((8.05374449538e-2f * z - 1.38776856032e-1f) * z + 1.99777106478e-1f) * z - 3.33329491539e-1f;
    r = r * z * t + t;
    r += mid ? 0.78539816f : 0.0f;
    r = ay > ax ? 1.57079633f - r : r;
    r = x < 0.0f ? 3.14159265f - r : r;
    return y < 0.0f ? -r : r;
}

/* The environment's texel (col, row) of world direction d: phi = atan2(x, -z) and theta = acos(y)
 * in the map's frame (map_from_world, row-major), u = phi / (2 pi) mod 1, v = theta / pi, each
 * at most the double below 1, col = floor(u W) (at most W - 1), row = floor(v H). In float; in
 * wide precision again where u W or v H lies within VIEW_TEXEL_EPS (W or H) of a texel border
 * (the float angles' error is far below it), so that the texel is the one numpy's float64 finds. */
#define VIEW_TEXEL_EPS 1e-5f
inline void view_texel(const float dx, const float dy, const float dz, __global const wide *M, const uint width,
                       const uint height, uint *col, uint *row)
{
    const float mx = dx * (float)M[0] + dy * (float)M[1] + dz * (float)M[2];
    const float my = dx * (float)M[3] + dy * (float)M[4] + dz * (float)M[5];
    const float mz = dx * (float)M[6] + dy * (float)M[7] + dz * (float)M[8];
    float u = view_atan2(mx, -mz) * INV_2PI_F;
    u = u < 0.0f ? u + 1.0f : u;
    const float yc = WCLAMP(my, -1.0f, 1.0f);
    const float v = view_atan2(SQRT1((1.0f - yc) * (1.0f + yc)), yc) * INV_PI_F;   /* acos */
    const float su = u * (float)width, sv = v * (float)height;
    const float fu = su - (float)(int)su, fv = sv - (float)(int)sv;
    const float eu = VIEW_TEXEL_EPS * (float)width, ev = VIEW_TEXEL_EPS * (float)height;
    if (fu > eu && fu < 1.0f - eu && fv > ev && fv < 1.0f - ev) {
        *col = min((uint)su, width - 1u);
        *row = min((uint)sv, height - 1u);
        return;
    }
    const wide wx = dx, wy = dy, wz = dz;
    const wide nx = wx * M[0] + wy * M[1] + wz * M[2];
    const wide ny = wx * M[3] + wy * M[4] + wz * M[5];
    const wide nz = wx * M[6] + wy * M[7] + wz * M[8];
    wide wu = atan2(nx, -nz) * (wide)0.15915494309189535;     /* 1 / (2 pi) */
    wu = wu < (wide)0 ? wu + (wide)1 : wu;                     /* u - floor(u), u in [-1/2, 1/2] */
    const wide wv = acos(WCLAMP(ny, (wide)-1, (wide)1)) * (wide)0.3183098861837907;   /* 1 / pi */
    const wide below = (wide)1 - (wide)1.1102230246251565e-16;                       /* the double below 1 */
    *col = min((uint)((wu < below ? wu : below) * (wide)width), width - 1u);
    *row = min((uint)((wv < below ? wv : below) * (wide)height), height - 1u);
}

#ifndef BACKGROUND_MODE   /* what misses see: 0 the nearest texel, 1 view_bilinear, 2 nothing */
#define BACKGROUND_MODE 0   /* (wavlight.envmap.BACKGROUND_MODE, wavlight.options.BACKGROUND) */
#endif
#if BACKGROUND_MODE == 1
/* The map (rows of 3 floats, width x height) in world direction d, filtered bilinearly between
 * its texel centres, wrapping in u and clamped in v (kernels/sphere.h env_bilinear on rows of 3;
 * u, v as view_texel's exact branch). numpy twin: wavlight.envmap.Environment.eval_background. */
INLINE void view_bilinear(const float dx, const float dy, const float dz, __global const wide *M,
                          __global const float *env, const uint width, const uint height, float *r, float *g,
                          float *b)
{
    const wide wx = dx, wy = dy, wz = dz;
    const wide nx = wx * M[0] + wy * M[1] + wz * M[2];
    const wide ny = wx * M[3] + wy * M[4] + wz * M[5];
    const wide nz = wx * M[6] + wy * M[7] + wz * M[8];
    wide wu = atan2(nx, -nz) * (wide)0.15915494309189535;     /* 1 / (2 pi) */
    wu = wu < (wide)0 ? wu + (wide)1 : wu;
    const wide wv = acos(WCLAMP(ny, (wide)-1, (wide)1)) * (wide)0.3183098861837907;   /* 1 / pi */
    const int w = (int)width, h = (int)height;
    const float x = (float)wu * (float)w - 0.5f;
    const float y = __builtin_fminf(__builtin_fmaxf((float)wv * (float)h - 0.5f, 0.0f), (float)(h - 1));
    const float x0 = __builtin_floorf(x), y0 = __builtin_floorf(y);
    const float fx = x - x0, fy = y - y0, gx = 1.0f - fx, gy = 1.0f - fy;
    int c0 = (int)x0;
    c0 = c0 < 0 ? c0 + w : (c0 >= w ? c0 - w : c0);
    const int c1 = c0 + 1 >= w ? 0 : c0 + 1;
    const int r0 = min((int)y0, h - 1), r1 = min(r0 + 1, h - 1);
    __global const float *a = env + 3 * ((size_t)r0 * w + c0), *bb = env + 3 * ((size_t)r0 * w + c1);
    __global const float *c = env + 3 * ((size_t)r1 * w + c0), *d = env + 3 * ((size_t)r1 * w + c1);
    *r = (a[0] * gx + bb[0] * fx) * gy + (c[0] * gx + d[0] * fx) * fy;
    *g = (a[1] * gx + bb[1] * fx) * gy + (c[1] * gx + d[1] * fx) * fy;
    *b = (a[2] * gx + bb[2] * fx) * gy + (c[2] * gx + d[2] * fx) * fy;
}
#endif

/* Adds ray p's blend sum_k w_k B[rows[ids_k]] over its three cache points (those of weight > 0
 * whose row is not -1) to (r, g, b). */
inline void add_blend(__global const float *B, __global const int *rows, __global const uint *ids,
                      __global const float *weights, const uint p, float *r, float *g, float *b)
{
    for (int q = 0; q < 3; ++q) {
        const float wq = weights[3 * p + q];
        const int at = rows[ids[3 * p + q]];
        if (wq > 0.0f && at >= 0) {
            *r += wq * B[3 * at];
            *g += wq * B[3 * at + 1];
            *b += wq * B[3 * at + 2];
        }
    }
}

/* Per camera ray: a hit's albedo x sum_k w_k B_k + sum_k w_k C_k (B the walks' products, row[p]
 * the row of cache point p, -1: none; C_k plastic's coat, the row coat_row[p] of B, -1 where the
 * point is not plastic; the albedo its material's, with TEXTURES 1 times the material's texture at
 * the hit: texture.h at embree's bary, rows u v; numpy twin ViewFrames.hit_albedo), a miss's the
 * environment's nearest texel in the ray's direction (with BACKGROUND_MODE 1: view_bilinear's
 * filter; with 2: 0, the background hidden)
 * (phi = atan2(x, -z), theta = acos(y) in the map's frame, map_from_world the rotation:
 * wavlight/envmap.py Environment.world_to_square). */
__kernel void view_assemble(const uint count, __global const int *prim, __global const uint *ids,
                            __global const float *weights, __global const int *row, __global const int *coat_row,
                            __global const float *B,
                            __global const int *face_material, __global const float *albedo,
                            __global const float *bary, __global const float *face_uv,
                            __global const int *mat_texture, __global const float *tex_atlas,
                            __global const int *tex_table, __global const float *dir, __global const float *env,
                            const uint env_width, const uint env_height, __global const wide *map_from_world,
                            __global float *out)
{
    const uint p = get_global_id(0);
    if (p >= count) return;
    const int f = prim[p];
    float r = 0.0f, g = 0.0f, bl = 0.0f;
    if (f >= 0) {
        add_blend(B, row, ids, weights, p, &r, &g, &bl);
        const int mt = face_material[f];
        r *= albedo[3 * mt];
        g *= albedo[3 * mt + 1];
        bl *= albedo[3 * mt + 2];
#if TEXTURES
        {   /* times the material's texture at the hit (texture.h, its lanes all this ray's) */
            realv tu, tv, tr, tg, tb;
            texture_uv(face_uv, (uintv)((uint)f), (realv)bary[2 * p], (realv)bary[2 * p + 1], &tu, &tv);
            texture_rgb(tex_atlas, tex_table, (intv)mat_texture[mt], tu, tv, &tr, &tg, &tb);
            r *= tr.s0;
            g *= tg.s0;
            bl *= tb.s0;
        }
#endif
        add_blend(B, coat_row, ids, weights, p, &r, &g, &bl);   /* plastic's coat, not tinted (-1: none) */
    } else {
#if BACKGROUND_MODE == 1
        view_bilinear(dir[3 * p], dir[3 * p + 1], dir[3 * p + 2], map_from_world, env, env_width, env_height, &r, &g,
                      &bl);
#elif BACKGROUND_MODE == 0
        uint col, rw;
        view_texel(dir[3 * p], dir[3 * p + 1], dir[3 * p + 2], map_from_world, env_width, env_height, &col, &rw);
        __global const float *e = env + 3 * ((size_t)rw * env_width + col);
        r = e[0];
        g = e[1];
        bl = e[2];
#endif
    }
    out[3 * p] = r;
    out[3 * p + 1] = g;
    out[3 * p + 2] = bl;
}
