/* A frame in which one object moves (wavlight/relight/moving.py; Chen & Gao sec. 2.2 and eq. 12).
 *
 * moving_occlusion: the object's occlusion D for camera samples that see the rest of the scene.
 * Per camera sample, ND directions of the defensive mixture of the pixel's product T1 x L and the
 * BSDF, stratified over the pixel's spp x ND directions, each with its unoccluded contribution
 * albedo f cos L / p; only the directions whose ray meets the object's box (its bounding box in
 * its own frame, grown, at this frame's place) are written, as records for the host to trace
 * against the object (and the rest): D is ND^-1 times the contributions of those the object
 * blocks and the rest does not. numpy twin: wavlight.relight.moving.occlusion_records_reference
 * (around wavlight.relight.converge.mixture_directions).
 *
 * Per sample (eight per work-item, simd.h): the camera ray (direction d from the eye, the rest's
 * triangle prim at distance t) gives the hit point p, its face normal turned towards the viewer
 * and its material (with -DTEXTURES=1 its albedo times its base-colour texture at the hit: texture.h,
 * the face's texture coordinates face_uv interpolated at embree's bary), and the shadow-ray origin
 * p moved max(OFFSET_RELATIVE |p|, the face's offset floor, the eye's) along the normal
 * (kernels/hit.h). Direction j of the sample (j < ND) takes the
 * four words of Philox counter (first + slot, tile, stream, j) (rng.h), its pairs (u0, u1) and
 * (u2, u3) stratified over the pixel's K = spp ND directions (cell number (slot % spp) ND + j,
 * stratify_pair, keyed by words 1 and 2 of stream RNG_STRATA at index first + slot / spp: the
 * camera jitter's strata take word 0). The pixel's product tree (tree_offset + slot / spp, N_LEVELS
 * levels, eq. 17) is walked with (u0, u1) (warp.h tree_walk, eq. 19-22); inside the texel it
 * reached, the leaf of the lighting's own resolution is chosen in proportion to its mass by the
 * rest of u0 (the texel's k^2 leaves as a running sum, light_cdf, bisected), the point inside the
 * leaf by the rest of u0 and of u1. With probability alpha (u2 < alpha: DEFENSIVE, 1 for a pixel
 * whose product is 0) the direction is the BSDF's instead (u2 / alpha, u3). The density is the
 * mixture's at the chosen direction, both techniques':
 *     p = (1 - alpha) p_tree(uv) (m_leaf / m_texel) k^2 / (2 pi^2 sin theta) + alpha p_bsdf,
 * the leaf masses m taken as differences of light_cdf, the same numbers the sampler bisects,
 * so that the density is that of the sampler exactly. L is the environment's nearest texel; the
 * contribution is 0 where p or f cos is 0 or it is not finite. Work is skipped where it cannot
 * give a record: a product direction whose texel lies outside the cone from the shadow-ray origin
 * around the sphere holding the box (grown by the texel's angular radius) is never completed, and
 * the weight is computed only for directions that meet the box.
 *
 * Records: 10 words, the launch index i ND + j, then the bits of the floats of the shadow-ray
 * origin x y z and the direction x y z in the object's own frame (local = R^T (world - T), ready
 * for its ray tracer) and of the contribution r g b. Work-item g writes its records (in the order
 * j, then lane) to its own region of LANES ND records of `region` and their number to counts[g];
 * moving_compact then copies the regions one after the other (the host's running sum of counts),
 * so that the records' order does not depend on the device's scheduling.
 *
 * moving_points: the shading points of the camera samples of the pixels rendered in full (those
 * that may see the object): the closer of the rest's hit and the object's (traced by the host in
 * the object's frame; its face normal turned to the world by R), the normal turned towards the
 * viewer, the material, the shadow-ray origin and the pixel's four stratified shading uniforms
 * (Philox stream `stream` at index first + slot, pairs stratified over the pixel's spp samples as
 * the stratified sampler does, keyed by words 1 and 2 of RNG_STRATA at first + slot / spp); a miss
 * sees the environment; with -DTEXTURES=1 the base-colour texture's value at the hit (the rest's
 * faces' texture coordinates face_uv, the object's object_face_uv; 1 without a texture), which
 * the shade kernel multiplies into the albedo. The host shades them with the `wavelet` strategy's shade kernel
 * (wavlight.shading.KernelShader). numpy twin: wavlight.relight.moving.shading_points_reference. */
#include "warp.h"
#include "bsdf.h"
#include "rng.h"
#include "hit.h"
#include "texture.h"
#ifndef TEXTURES
#define TEXTURES 0   /* 1: some material has a base-colour texture (texture.h) */
#endif
#ifndef N_LEVELS
#error "relight_moving.cl is built with -DN_LEVELS (the product trees' depth)"
#endif
#ifndef ND
#error "relight_moving.cl is built with -DND (directions per camera sample)"
#endif
#define RECORD 10
/* the largest angle between a texel's centre direction and any of its directions: half its
 * height plus half its width along its widest latitude, 1.5 pi / 2^N_LEVELS, and a slack for
 * float32 (the cone test below only skips work: it must never skip a direction that meets) */
#define TEXEL_RADIUS (1.5f * PI_F / (float)(1u << N_LEVELS) + 1e-3f)

/* The running sum of the k^2 leaf masses of a texel (light_cdf from row0) before leaf j, and
 * leaf j's mass (the difference of two running sums: the sampler's and the density's). */
INLINE realv leaf_below(__global const float *light_cdf, const uintv row0, const uintv j, realv *mass)
{
    const realv below = select(GATHER(light_cdf, row0 + max(j, 1u) - 1u), (realv)0.0f, as_intv(j) == 0);
    *mass = GATHER(light_cdf, row0 + j) - below;
    return below;
}

/* The pair's uniforms of Philox counter (index, tile, stream, j), words 0 .. 3. */
INLINE void counter_uniforms(const uintv index, const uint tile, const uint stream, const uint j, const uint k0,
                             const uint k1, realv *u0, realv *u1, realv *u2, realv *u3)
{
    uintv r0, r1, r2, r3;
    philox4x32_10(index, (uintv)tile, (uintv)stream, (uintv)j, k0, k1, &r0, &r1, &r2, &r3);
    *u0 = word_to_unit(r0);
    *u1 = word_to_unit(r1);
    *u2 = word_to_unit(r2);
    *u3 = word_to_unit(r3);
}

/* The product's point on the square inside the texel (col, row) the tree walk reached with
 * (fu, fv) left of its uniforms: the leaf of the lighting's own resolution in proportion to its
 * mass by fu (the texel's k^2 leaves as a running sum, light_cdf, bisected), the point inside the
 * leaf by the rest of fu and by fv; its world direction q. */
INLINE void product_point(__global const float *light_cdf, const uint k, const uintv col, const uintv row,
                          const realv fu, const realv fv, realv *qx, realv *qy, realv *qz)
{
    const uint side = 1u << N_LEVELS, kk = k * k;
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
    *qx = sp * st;
    *qy = ct;
    *qz = -cp * st;
}

/* The defensive mixture's weight f cos / p at the unit world direction w: the density is the
 * mixture's, both techniques' (the product's: tree, leaf inside the texel, solid angle), at a
 * point with frame (s, t, n), view o in that frame, material (kind, param), the pixel's tree at
 * tree_base (has_product: its root > 0), BSDF weight alpha; 0 where p or f cos is 0 or the weight
 * is not finite. *share: the part of f cos the albedo multiplies, over f cos (1 but for plastic's
 * coat: bsdf.h material_eval_pdf, its row of the plastic table at row). */
INLINE realv mixture_weight(__global const float *tree, const uintv tree_base, const intv has_product,
                            __global const float *light_cdf, const uint k, const realv alpha,
                            const intv kind, const realv param, __global const float *mat_table, const uintv row,
                            realv *share,
                            const realv sx, const realv sy, const realv sz, const realv tx, const realv ty,
                            const realv tz, const realv nx, const realv ny, const realv nz,
                            const realv ox, const realv oy, const realv oz,
                            const realv wx, const realv wy, const realv wz)
{
    const uint side = 1u << N_LEVELS, kk = k * k;
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
    realv fcos, fd, p_bsdf;
    material_eval_pdf(kind, param, mat_table, row, lx, ly, lz, ox, oy, oz, &fcos, &fd, &p_bsdf);
    *share = select((realv)1.0f, fd / fcos, fcos > 0.0f);
    const realv pdf = (1.0f - alpha) * p_prod + alpha * p_bsdf;
    const realv weight = select((realv)0.0f, fcos / pdf, (pdf > 0.0f) & (fcos > 0.0f));
    return select((realv)0.0f, weight, isfinite(weight));
}

/* Whether rays from o along w meet the box [lo, hi] of the object's own frame, the object placed
 * at world = R local + T (place: R row-major, then T; box: lo x y z, hi x y z; the host grows the
 * object's box so that float32 rounding never drops a ray that meets the object). A slab test
 * whose minima and maxima drop NaN (0 / 0: a ray in a face's plane). */
INLINE intv meets_box(__global const float *place, __global const float *box, const realv ox, const realv oy,
                      const realv oz, const realv wx, const realv wy, const realv wz)
{
    const realv rx = ox - place[9], ry = oy - place[10], rz = oz - place[11];
    realv t_near = -INFINITY, t_far = INFINITY;
#pragma unroll
    for (int a = 0; a < 3; ++a) {   /* local = R^T (world - T): column a of R */
        const realv o = rx * place[a] + ry * place[3 + a] + rz * place[6 + a];
        const realv w = wx * place[a] + wy * place[3 + a] + wz * place[6 + a];
        const realv t0 = (box[a] - o) / w, t1 = (box[3 + a] - o) / w;
        t_near = fmax(t_near, fmin(t0, t1));
        t_far = fmin(t_far, fmax(t0, t1));
    }
    return (t_near <= t_far) & (t_far >= 0.0f);
}

__kernel void moving_occlusion(const uint count, __global const uint *slot_in, __global const float *dirs,
                               __global const int *prim, __global const float *tfar,
                               const float eye_x, const float eye_y, const float eye_z, const float eye_offset,
                               __global const float *face_normal, __global const int *face_material,
                               __global const float *bary, __global const int *corner,
                               __global const float *normals, const int smooth,
                               __global const int *mat_kind, __global const float *mat_param,
                               __global const float *mat_albedo, __global const float *mat_table,
                               __global const float *face_uv, __global const int *mat_texture,
                               __global const float *tex_atlas, __global const int *tex_table,
                               __global const float *tree, const uint tree_stride, const uint tree_offset,
                               const uint spp, __global const float *light_cdf, const uint k,
                               __global const float *texels, const int env_w, const int env_h,
                               __global const float *rot, const float defensive,
                               __global const float *place, __global const float *box,
                               __global const float *sphere, const uint tile, const uint stream, const uint first, const uint k0,
                               const uint k1, __global uint *region, __global uint *counts)
{
    const uint base = LANE_BASE();
    if (base >= count) return;
    tree += TREE_ORIGIN;   /* (common.h) */
    const uintv i = LANE_INDEX(count);
    /* the hit and its shading frame */
    realv dx, dy, dz;
    GATHER3(dirs, 3 * i, &dx, &dy, &dz);
    const uintv f = as_uintv(max(GATHER_INT(prim, i), 0));
    realv gx, gy, gz, px, py, pz, eps;
    hit_point(dx, dy, dz, GATHER(tfar, i), f, face_normal, eye_x, eye_y, eye_z, eye_offset,
              &gx, &gy, &gz, &px, &py, &pz, &eps);
    realv nx = gx, ny = gy, nz = gz;   /* the shading normal (hit.h), the face's where flat */
    if (smooth) {
        realv bu, bv;
        GATHER2(bary, 2 * i, &bu, &bv);
        shading_normal(dx, dy, dz, bu, bv, f, corner, normals, gx, gy, gz, &nx, &ny, &nz);
    }
    realv sx, sy, sz, tx, ty, tz;
    make_frame(nx, ny, nz, &sx, &sy, &sz, &tx, &ty, &tz);
    const realv ox = -(dx * sx + dy * sy + dz * sz), oy = -(dx * tx + dy * ty + dz * tz);
    const realv oz = -(dx * nx + dy * ny + dz * nz);
    const realv qx = px + gx * eps, qy = py + gy * eps, qz = pz + gz * eps;   /* from the geometric surface */
    const intv mat = GATHER_INT(face_material, f);
    const intv kind = GATHER_INT(mat_kind, mat);
    const realv param = GATHER(mat_param, mat);
    realv ar, ag, ab;   /* the albedo, times the material's texture at the hit (texture.h) */
    albedo_at_hit(mat_albedo, TEXTURES, face_uv, tex_atlas, tex_table, mat_texture, bary, i, f, mat, &ar, &ag, &ab);
    const uintv table_row = as_uintv(mat) * (uint)PLASTIC_STRIDE;   /* its row of the plastic table */
    /* the pixel's tree and strata */
    const uintv slot = as_uintv(GATHER_INT((__global const int *)slot_in, i));
    uintv sample;
    const uintv pixel = div_small(slot, spp, &sample);
    const uintv tree_base = (pixel + tree_offset) * tree_stride;
    const intv has_product = GATHER(tree, tree_base) > 0.0f;
    const realv alpha = select((realv)1.0f, (realv)defensive, has_product);
    uintv unused0, key_guide, key_bsdf, unused3;
    philox4x32_10(first + pixel, (uintv)tile, (uintv)RNG_STRATA, (uintv)0u, k0, k1, &unused0, &key_guide, &key_bsdf,
                  &unused3);
    /* the cone from the shadow-ray origin around the sphere that holds the object's box: a texel
     * none of whose directions is within it holds no direction that meets the box */
    const realv cx = sphere[0] - qx, cy = sphere[1] - qy, cz = sphere[2] - qz;
    const realv dist = sqrt(cx * cx + cy * cy + cz * cz);
    const realv sin_cone = fmin(sphere[3] / dist, 1.0f);
    const realv cone = select(fast_atan2(sin_cone, sqrt(fmax(1.0f - sin_cone * sin_cone, 0.0f))), (realv)PI_F,
                              dist <= sphere[3]) + TEXEL_RADIUS;
    realv sin_unused, cos_cone;
    fast_sincos(fmin(cone, PI_F), &sin_unused, &cos_cone);
    cos_cone = select(cos_cone - 1e-4f, (realv)-2.0f, cone >= PI_F);
    const realv ax = cx / dist, ay = cy / dist, az = cz / dist;
    const uint g = get_global_id(0), cells = spp * ND, side = 1u << N_LEVELS;
    __global uint *out = region + (size_t)g * (LANES * ND * RECORD);
    uint written = 0;
    for (uint j = 0; j < ND; ++j) {
        realv u0, u1, u2, u3;
        counter_uniforms(first + slot, tile, stream, j, k0, k1, &u0, &u1, &u2, &u3);
        const uintv cell = sample * ND + j;
        stratify_pair(&u0, &u1, cell, cells, key_guide);
        stratify_pair(&u2, &u3, cell, cells, key_bsdf);
        /* the product's texel (the tree walk), and whether it may hold a direction to the object */
        realv gu = u0, gv = u1;
        tree_walk(tree, tree_base, &gu, &gv);
        const uintv col = as_uintv(min(convert_intv(gu * (float)side), (int)side - 1));
        const uintv row = as_uintv(min(convert_intv(gv * (float)side), (int)side - 1));
        const realv fu = gu * (float)side - convert_realv(col), fv = gv * (float)side - convert_realv(row);
        realv sp, cp, st, ct;
        fast_sincos(2.0f * PI_F * (convert_realv(col) + 0.5f) / (float)side, &sp, &cp);
        fast_sincos(PI_F * (convert_realv(row) + 0.5f) / (float)side, &st, &ct);
        const intv near = sp * st * ax + ct * ay - cp * st * az >= cos_cone;
        /* the BSDF's direction */
        const intv use_b = u2 < alpha;
        const realv ub0 = clamp(select((realv)0.0f, u2 / alpha, use_b), 0.0f, ONE_MINUS_EPS);
        const realv ub1 = clamp(u3, 0.0f, ONE_MINUS_EPS);
        realv bx, by, bz;
        material_sample(kind, param, mat_table, table_row, ox, oy, oz, ub0, ub1, &bx, &by, &bz);
        realv wx = bx * sx + by * tx + bz * nx, wy = bx * sy + by * ty + bz * ny, wz = bx * sz + by * tz + bz * nz;
        /* the product's direction inside its texel, where it may reach the object */
        const intv product_near = near & ~use_b;
        if (any(product_near)) {
            realv px_, py_, pz_;
            product_point(light_cdf, k, col, row, fu, fv, &px_, &py_, &pz_);
            wx = select(wx, px_, product_near);
            wy = select(wy, py_, product_near);
            wz = select(wz, pz_, product_near);
        }
        const intv maybe = use_b | product_near;
        if (!any(maybe))
            continue;
        const realv len = sqrt(wx * wx + wy * wy + wz * wz);
        wx /= len;
        wy /= len;
        wz /= len;
        const intv meets = maybe & meets_box(place, box, qx, qy, qz, wx, wy, wz);
        if (!any(meets))
            continue;
        /* (no light from below the geometric surface: docs/decisions/shading-normals.md) */
        realv share;
        const realv weight = select((realv)0.0f,
                                    mixture_weight(tree, tree_base, has_product, light_cdf, k, alpha, kind, param,
                                                   mat_table, table_row, &share, sx, sy, sz, tx, ty, tz, nx, ny, nz,
                                                   ox, oy, oz, wx, wy, wz),
                                    wx * gx + wy * gy + wz * gz > 0.0f);
        /* the environment's radiance, the albedo */
        realv eu, ev;
        env_world_to_square(rot, wx, wy, wz, &eu, &ev);
        realv lr, lg, lb, unused_l;
        GATHER4(texels, 4 * env_texel(env_w, env_h, eu, ev), &lr, &lg, &lb, &unused_l);
        /* the colour: the albedo, plastic's 1 - share + share albedo (its coat untinted) */
        const realv vr = (1.0f - share + share * ar) * weight * lr, vg = (1.0f - share + share * ag) * weight * lg;
        const realv vb = (1.0f - share + share * ab) * weight * lb;
        const intv live = meets & (weight > 0.0f) & ((vr > 0.0f) | (vg > 0.0f) | (vb > 0.0f));
        if (!any(live))
            continue;
        /* the ray in the object's own frame (local = R^T (world - T)) */
        const realv rx = qx - place[9], ry = qy - place[10], rz = qz - place[11];
        const realv lox = rx * place[0] + ry * place[3] + rz * place[6];
        const realv loy = rx * place[1] + ry * place[4] + rz * place[7];
        const realv loz = rx * place[2] + ry * place[5] + rz * place[8];
        const realv lwx = wx * place[0] + wy * place[3] + wz * place[6];
        const realv lwy = wx * place[1] + wy * place[4] + wz * place[7];
        const realv lwz = wx * place[2] + wy * place[5] + wz * place[8];
        for (uint l = 0; l < LANES && base + l < count; ++l) {
            if (!live[l])
                continue;
            __global uint *rec = out + written * RECORD;
            rec[0] = (base + l) * ND + j;
            rec[1] = as_uint(lox[l]);
            rec[2] = as_uint(loy[l]);
            rec[3] = as_uint(loz[l]);
            rec[4] = as_uint(lwx[l]);
            rec[5] = as_uint(lwy[l]);
            rec[6] = as_uint(lwz[l]);
            rec[7] = as_uint(vr[l]);
            rec[8] = as_uint(vg[l]);
            rec[9] = as_uint(vb[l]);
            ++written;
        }
    }
    counts[g] = written;
}

/* The records of work-items 0 .. groups - 1, one after the other: work-item g's counts[g] records
 * from its region to out from record offsets[g] on. */
__kernel void moving_compact(const uint groups, __global const uint *region, __global const uint *counts,
                             __global const uint *offsets, __global uint *out)
{
    const uint g = get_global_id(0);
    if (g >= groups) return;
    __global const uint *from = region + (size_t)g * (LANES * ND * RECORD);
    __global uint *to = out + (size_t)offsets[g] * RECORD;
    const uint n = counts[g] * RECORD;
    for (uint r = 0; r < n; ++r)
        to[r] = from[r];
}

__kernel void moving_points(const uint count, __global const uint *slot_in, __global const float *dirs,
                            __global const int *prim, __global const float *tfar,
                            __global const int *prim_object, __global const float *tfar_object,
                            const float eye_x, const float eye_y, const float eye_z, const float eye_offset,
                            __global const float *face_normal, __global const int *face_material,
                            __global const float *bary, __global const int *corner,
                            __global const float *normals, const int smooth,
                            __global const float *object_normal,
                            __global const float *bary_object, __global const int *object_corner,
                            __global const float *object_normals, const int object_smooth,
                            const int object_material, __global const float *face_uv,
                            __global const float *object_face_uv, __global const int *mat_texture,
                            __global const float *tex_atlas, __global const int *tex_table,
                            const float object_offset, __global const float *place,
                            __global const float *texels, const int env_w, const int env_h,
                            __global const float *rot, const uint spp,
                            const uint tile, const uint stream, const uint first, const uint k0,
                            const uint k1, __global float *out, __global int *material_out)
{
    const uint base = LANE_BASE();
    if (base >= count) return;
    const uintv i = LANE_INDEX(count);
    realv dx, dy, dz;
    GATHER3(dirs, 3 * i, &dx, &dy, &dz);
    const intv fr = GATHER_INT(prim, i), fo = GATHER_INT(prim_object, i);
    const realv tr = GATHER(tfar, i), to = GATHER(tfar_object, i);
    const intv on_object = (fo >= 0) & ((fr < 0) | (to < tr));
    const intv hit = on_object | (fr >= 0);
    /* the rest's shading point: the face normal g, the shading normal n (hit.h) */
    realv gx, gy, gz, px, py, pz, eps;
    hit_point(dx, dy, dz, tr, as_uintv(max(fr, 0)), face_normal, eye_x, eye_y, eye_z, eye_offset,
              &gx, &gy, &gz, &px, &py, &pz, &eps);
    realv nx = gx, ny = gy, nz = gz;
    if (smooth) {
        realv bu, bv;
        GATHER2(bary, 2 * i, &bu, &bv);
        shading_normal(dx, dy, dz, bu, bv, as_uintv(max(fr, 0)), corner, normals, gx, gy, gz, &nx, &ny, &nz);
    }
    /* the object's: its face normal turned to the world, towards the viewer; its shading normal
     * interpolated in its own frame (the view turned there: local = R^T world), then turned */
    if (any(on_object)) {
        realv lx, ly, lz, unused;
        GATHER4(object_normal, 4 * as_uintv(max(fo, 0)), &lx, &ly, &lz, &unused);
        realv mx = place[0] * lx + place[1] * ly + place[2] * lz;
        realv my = place[3] * lx + place[4] * ly + place[5] * lz;
        realv mz = place[6] * lx + place[7] * ly + place[8] * lz;
        const realv flip = select((realv)1.0f, (realv)-1.0f, mx * dx + my * dy + mz * dz > 0.0f);
        mx *= flip;
        my *= flip;
        mz *= flip;
        realv sx = mx, sy = my, sz = mz;
        if (object_smooth) {
            const realv ldx = dx * place[0] + dy * place[3] + dz * place[6];
            const realv ldy = dx * place[1] + dy * place[4] + dz * place[7];
            const realv ldz = dx * place[2] + dy * place[5] + dz * place[8];
            realv bu, bv, qnx, qny, qnz;
            GATHER2(bary_object, 2 * i, &bu, &bv);
            shading_normal(ldx, ldy, ldz, bu, bv, as_uintv(max(fo, 0)), object_corner, object_normals, lx, ly, lz,
                           &qnx, &qny, &qnz);
            sx = place[0] * qnx + place[1] * qny + place[2] * qnz;
            sy = place[3] * qnx + place[4] * qny + place[5] * qnz;
            sz = place[6] * qnx + place[7] * qny + place[8] * qnz;
        }
        const realv qx = eye_x + dx * to, qy = eye_y + dy * to, qz = eye_z + dz * to;
        const realv size = fmax(fmax(fabs(qx), fabs(qy)), fabs(qz));
        const realv e = fmax(fmax((float)OFFSET_RELATIVE * size, object_offset), eye_offset);
        nx = select(nx, sx, on_object);
        ny = select(ny, sy, on_object);
        nz = select(nz, sz, on_object);
        gx = select(gx, mx, on_object);
        gy = select(gy, my, on_object);
        gz = select(gz, mz, on_object);
        px = select(px, qx, on_object);
        py = select(py, qy, on_object);
        pz = select(pz, qz, on_object);
        eps = select(eps, e, on_object);
    }
    const intv mat = select(select(GATHER_INT(face_material, as_uintv(max(fr, 0))), (intv)object_material, on_object),
                            (intv)-1, ~hit);
    /* the texture's value at the hit, the rest's or the object's (1 without one, and for misses) */
    realv hr = 1.0f, hg = 1.0f, hb = 1.0f;
#if TEXTURES
    if (any(hit)) {
        realv bu, bv, ou, ov, tu, tv, su, sv;
        GATHER2(bary, 2 * i, &bu, &bv);
        GATHER2(bary_object, 2 * i, &ou, &ov);
        texture_uv(face_uv, as_uintv(max(fr, 0)), bu, bv, &tu, &tv);
        texture_uv(object_face_uv, as_uintv(max(fo, 0)), ou, ov, &su, &sv);
        realv tr, tg, tb;
        texture_rgb(tex_atlas, tex_table, select((intv)-1, GATHER_INT(mat_texture, as_uintv(max(mat, 0))), hit),
                    select(tu, su, on_object), select(tv, sv, on_object), &tr, &tg, &tb);
        hr = tr;
        hg = tg;
        hb = tb;
    }
#endif
    /* the environment for misses */
    realv er = 0.0f, eg = 0.0f, eb = 0.0f;
    if (!all(hit)) {
        realv eu, ev;
        env_world_to_square(rot, dx, dy, dz, &eu, &ev);
        realv r, g, b, unused;
        GATHER4(texels, 4 * env_texel(env_w, env_h, eu, ev), &r, &g, &b, &unused);
        er = select(r, 0.0f, hit);
        eg = select(g, 0.0f, hit);
        eb = select(b, 0.0f, hit);
    }
    /* the pixel's stratified shading uniforms */
    const uintv slot = as_uintv(GATHER_INT((__global const int *)slot_in, i));
    uintv sample;
    const uintv pixel = div_small(slot, spp, &sample);
    uintv unused0, key_guide, key_bsdf, unused3;
    philox4x32_10(first + pixel, (uintv)tile, (uintv)RNG_STRATA, (uintv)0u, k0, k1, &unused0, &key_guide, &key_bsdf,
                  &unused3);
    realv u0, u1, u2, u3;
    rng_uniforms(first + slot, tile, stream, k0, k1, &u0, &u1, &u2, &u3);
    stratify_pair(&u0, &u1, sample, spp, key_guide);
    stratify_pair(&u2, &u3, sample, spp, key_bsdf);
    /* planes: shading normal x y z, origin x y z (along the face normal), u0 .. u3, direct r g b,
     * face normal x y z, the texture's value r g b */
    STORE_LANES(nx, out, base, count);
    STORE_LANES(ny, out + count, base, count);
    STORE_LANES(nz, out + 2 * count, base, count);
    STORE_LANES(px + gx * eps, out + 3 * count, base, count);
    STORE_LANES(py + gy * eps, out + 4 * count, base, count);
    STORE_LANES(pz + gz * eps, out + 5 * count, base, count);
    STORE_LANES(gx, out + 13 * count, base, count);
    STORE_LANES(gy, out + 14 * count, base, count);
    STORE_LANES(gz, out + 15 * count, base, count);
    STORE_LANES(u0, out + 6 * count, base, count);
    STORE_LANES(u1, out + 7 * count, base, count);
    STORE_LANES(u2, out + 8 * count, base, count);
    STORE_LANES(u3, out + 9 * count, base, count);
    STORE_LANES(er, out + 10 * count, base, count);
    STORE_LANES(eg, out + 11 * count, base, count);
    STORE_LANES(eb, out + 12 * count, base, count);
    STORE_LANES(hr, out + 16 * count, base, count);
    STORE_LANES(hg, out + 17 * count, base, count);
    STORE_LANES(hb, out + 18 * count, base, count);
    for (uint l = 0; l < LANES && base + l < count; ++l)
        material_out[base + l] = mat[l];
}
