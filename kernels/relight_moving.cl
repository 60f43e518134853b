/* The moving object's occlusion D (wavlight/relight/moving.py; Chen & Gao sec. 2.2 and eq. 12):
 * per camera sample that sees the rest of the scene, one direction of the defensive mixture of
 * the pixel's product T1 x L and the BSDF, and its unoccluded contribution albedo f cos L / p.
 * The host traces the samples whose direction meets the object's bounding sphere against the
 * object (and the rest); D is the contribution of those the object blocks and the rest does not.
 * The directions do not depend on the object's place. numpy twin:
 * wavlight.relight.moving.mixture_samples_reference (around
 * wavlight.relight.converge.mixture_directions).
 *
 * Per sample (eight per work-item, simd.h): the camera ray (direction d from the eye, the rest's
 * triangle prim at distance t) gives the hit point p, its face normal turned towards the viewer
 * and its material, and the shadow-ray origin p moved max(OFFSET_RELATIVE |p|, the face's offset
 * floor, the eye's) along the normal (wavlight/raytrace.py). Four uniforms: Philox stream
 * `stream` of tile `tile` at index first + slot (rng.h; first: the pass's first sample). The
 * pixel's product tree (tree_offset + slot / spp, N_LEVELS levels, eq. 17) is walked with
 * (u0, u1) (warp.h tree_walk, eq. 19-22);
 * inside the texel it reached, the leaf of the lighting's own resolution is chosen in proportion
 * to its mass by the rest of u0 (the texel's k^2 leaves as a running sum, light_cdf, bisected),
 * the point inside the leaf by the rest of u0 and of u1. With probability alpha (u2 < alpha:
 * DEFENSIVE, 1 for a pixel whose product is 0) the direction is the BSDF's instead (u2 / alpha,
 * u3). The density is the mixture's at the chosen direction, both techniques':
 *     p = (1 - alpha) p_tree(uv) (m_leaf / m_texel) k^2 / (2 pi^2 sin theta) + alpha p_bsdf,
 * the leaf masses m taken as differences of light_cdf, the same numbers the sampler bisects,
 * so that the density is that of the sampler exactly. Outputs as planes of count floats:
 * origin x y z, direction x y z, albedo f cos L / p r g b (0 where p or f cos is 0 or the value
 * is not finite; L the environment's nearest texel). */
#include "warp.h"
#include "bsdf.h"
#include "rng.h"
#include "hit.h"
#ifndef N_LEVELS
#error "relight_moving.cl is built with -DN_LEVELS (the product trees' depth)"
#endif

/* The running sum of the k^2 leaf masses of a texel (light_cdf from row0) before leaf j, and
 * leaf j's mass (the difference of two running sums: the sampler's and the density's). */
INLINE realv leaf_below(__global const float *light_cdf, const uintv row0, const uintv j, realv *mass)
{
    const realv below = select(GATHER(light_cdf, row0 + max(j, 1u) - 1u), (realv)0.0f, as_intv(j) == 0);
    *mass = GATHER(light_cdf, row0 + j) - below;
    return below;
}

__kernel void moving_directions(const uint count, __global const uint *slot_in, __global const float *dirs,
                                __global const int *prim, __global const float *tfar,
                                const float eye_x, const float eye_y, const float eye_z, const float eye_offset,
                                __global const float *face_normal, __global const int *face_material,
                                __global const int *mat_kind, __global const float *mat_param,
                                __global const float *mat_albedo,
                                __global const float *tree, const uint tree_stride, const uint tree_offset,
                                const uint spp, __global const float *light_cdf, const uint k,
                                __global const float *texels, const int env_w, const int env_h,
                                __global const float *rot, const float defensive,
                                const uint tile, const uint stream, const uint first, const uint k0,
                                const uint k1,
                                __global float *out)
{
    const uint base = LANE_BASE();
    if (base >= count) return;
    tree += TREE_ORIGIN;   /* (common.h) */
    const uintv i = LANE_INDEX(count);
    /* the hit and its shading frame */
    realv dx, dy, dz;
    GATHER3(dirs, 3 * i, &dx, &dy, &dz);
    const uintv f = as_uintv(max(GATHER_INT(prim, i), 0));
    realv nx, ny, nz, px, py, pz, eps;
    hit_point(dx, dy, dz, GATHER(tfar, i), f, face_normal, eye_x, eye_y, eye_z, eye_offset,
              &nx, &ny, &nz, &px, &py, &pz, &eps);
    realv sx, sy, sz, tx, ty, tz;
    make_frame(nx, ny, nz, &sx, &sy, &sz, &tx, &ty, &tz);
    const realv ox = -(dx * sx + dy * sy + dz * sz), oy = -(dx * tx + dy * ty + dz * tz);
    const realv oz = -(dx * nx + dy * ny + dz * nz);
    const intv mat = GATHER_INT(face_material, f);
    const intv kind = GATHER_INT(mat_kind, mat);
    const realv param = GATHER(mat_param, mat);
    /* the uniforms, the pixel's tree */
    const uintv slot = as_uintv(GATHER_INT((__global const int *)slot_in, i));
    realv u0, u1, u2, u3;
    rng_uniforms(slot + first, tile, stream, k0, k1, &u0, &u1, &u2, &u3);
    uintv unused;
    const uintv tree_base = (div_small(slot, spp, &unused) + tree_offset) * tree_stride;
    const intv has_product = GATHER(tree, tree_base) > 0.0f;
    const realv alpha = select((realv)1.0f, (realv)defensive, has_product);
    /* the product's direction: the tree's texel, then the leaf inside it */
    realv gu = u0, gv = u1;
    tree_walk(tree, tree_base, &gu, &gv);
    const uint side = 1u << N_LEVELS, kk = k * k;
    const uintv col = as_uintv(min(convert_intv(gu * (float)side), (int)side - 1));
    const uintv row = as_uintv(min(convert_intv(gv * (float)side), (int)side - 1));
    const realv fu = gu * (float)side - convert_realv(col), fv = gv * (float)side - convert_realv(row);
    const uintv row0 = (row * side + col) * kk;
    const realv total = GATHER(light_cdf, row0 + (kk - 1u));
    const realv target = fu * total;
    uintv lo = 0, hi = kk;   /* how many of the running sums are <= target */
    intv active = lo < hi;
    while (any(active)) {
        const uintv mid = (lo + hi) >> 1;
        const intv below = GATHER(light_cdf, row0 + min(mid, kk - 1u)) <= target;
        lo = select(lo, mid + 1u, active & below);
        hi = select(hi, mid, active & ~below);
        active = lo < hi;
    }
    const uintv leaf = min(lo, kk - 1u);
    realv mass;
    const realv below = leaf_below(light_cdf, row0, leaf, &mass);
    realv s = select(fu, (target - below) / mass, mass > 0.0f);
    s = clamp(s, 0.0f, ONE_MINUS_EPS);
    const uintv sub_r = leaf / k, sub_c = leaf - (leaf / k) * k;
    const float inv = 1.0f / (float)(side * k);
    const realv pu = (convert_realv(col * k + sub_c) + s) * inv, pv = (convert_realv(row * k + sub_r) + fv) * inv;
    realv sp, cp, st, ct;
    fast_sincos(2.0f * PI_F * pu, &sp, &cp);
    fast_sincos(PI_F * pv, &st, &ct);
    const realv qx = sp * st, qy = ct, qz = -cp * st;
    /* the BSDF's direction */
    const intv use_b = u2 < alpha;
    const realv ub0 = clamp(select((realv)0.0f, u2 / alpha, use_b), 0.0f, ONE_MINUS_EPS);
    const realv ub1 = clamp(u3, 0.0f, ONE_MINUS_EPS);
    realv bx, by, bz;
    bsdf_sample(kind, param, ox, oy, oz, ub0, ub1, &bx, &by, &bz);
    realv wx = select(qx, bx * sx + by * tx + bz * nx, use_b);
    realv wy = select(qy, bx * sy + by * ty + bz * ny, use_b);
    realv wz = select(qz, bx * sz + by * tz + bz * nz, use_b);
    const realv len = sqrt(wx * wx + wy * wy + wz * wz);
    wx /= len;
    wy /= len;
    wz /= len;
    /* the mixture's density there: the product's (tree, leaf inside the texel, solid angle) */
    const realv sin_theta = sqrt(wx * wx + wz * wz);
    realv au = fast_atan2(wx, -wz) * INV_2PI_F;
    au -= floor(au);
    au = fmin(au, ONE_MINUS_EPS);
    const realv av = fmin(fast_atan2(sin_theta, wy) * INV_PI_F, ONE_MINUS_EPS);
    const realv p_tree = tree_pdf(tree, tree_base, N_LEVELS, au, av);
    const uintv ccol = as_uintv(min(convert_intv(au * (float)side), (int)side - 1));
    const uintv crow = as_uintv(min(convert_intv(av * (float)side), (int)side - 1));
    const realv cu = au * (float)side - convert_realv(ccol), cv = av * (float)side - convert_realv(crow);
    const uintv crow0 = (crow * side + ccol) * kk;
    const uintv cleaf = as_uintv(min(convert_intv(cv * (float)k), (int)k - 1)) * k
                        + as_uintv(min(convert_intv(cu * (float)k), (int)k - 1));
    const realv ctotal = GATHER(light_cdf, crow0 + (kk - 1u));
    realv cmass;
    leaf_below(light_cdf, crow0, cleaf, &cmass);
    const realv factor = select((realv)0.0f, cmass / ctotal * (float)kk, ctotal > 0.0f);
    const realv p_prod = select((realv)0.0f, p_tree * factor * env_square_to_solid_angle(wx, wz), has_product);
    /* the BSDF's density and f cos */
    const realv lx = wx * sx + wy * sy + wz * sz, ly = wx * tx + wy * ty + wz * tz;
    const realv lz = wx * nx + wy * ny + wz * nz;
    realv fcos, p_bsdf;
    bsdf_eval_pdf(kind, param, lx, ly, lz, ox, oy, oz, &fcos, &p_bsdf);
    const realv pdf = (1.0f - alpha) * p_prod + alpha * p_bsdf;
    realv weight = select((realv)0.0f, fcos / pdf, (pdf > 0.0f) & (fcos > 0.0f));
    weight = select((realv)0.0f, weight, isfinite(weight));
    /* the environment's radiance, the albedo */
    realv eu, ev;
    env_world_to_square(rot, wx, wy, wz, &eu, &ev);
    realv lr, lg, lb, unused_l;
    GATHER4(texels, 4 * env_texel(env_w, env_h, eu, ev), &lr, &lg, &lb, &unused_l);
    realv ar, ag, ab, unused_a;
    GATHER4(mat_albedo, 4 * as_uintv(mat), &ar, &ag, &ab, &unused_a);
    STORE_LANES(px + nx * eps, out, base, count);
    STORE_LANES(py + ny * eps, out + count, base, count);
    STORE_LANES(pz + nz * eps, out + 2 * count, base, count);
    STORE_LANES(wx, out + 3 * count, base, count);
    STORE_LANES(wy, out + 4 * count, base, count);
    STORE_LANES(wz, out + 5 * count, base, count);
    STORE_LANES(ar * weight * lr, out + 6 * count, base, count);
    STORE_LANES(ag * weight * lg, out + 7 * count, base, count);
    STORE_LANES(ab * weight * lb, out + 8 * count, base, count);
}
