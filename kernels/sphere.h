/* Directions, eight at a time: tangent frames, sin / cos / atan2 without library calls,
 * the lat-long square of the light tree and the equirectangular nearest-texel lookup of
 * the scene format.
 * numpy twins: wavlight/warp.py and wavlight/envmap.py.
 */
#ifndef WAVLIGHT_SPHERE_H
#define WAVLIGHT_SPHERE_H
#include "common.h"
#include "simd.h"

#define PI_F 3.14159265358979323846f
#define INV_PI_F 0.31830988618379067154f
#define INV_2PI_F 0.15915494309189533577f
#define INV_4PI_F 0.07957747154594766788f

/* Eight directions at a time (simd.h): 3-vectors are three realv, results come back
 * through pointers. */

/* Orthonormal frame (s, t) about a unit normal n (Duff et al. 2017). */
inline void make_frame(const realv nx, const realv ny, const realv nz,
                       realv *sx, realv *sy, realv *sz, realv *tx, realv *ty, realv *tz)
{
    const realv sign = select((realv)-1.0f, (realv)1.0f, nz >= 0.0f);
    const realv a = -1.0f / (sign + nz);
    const realv b = nx * ny * a;
    *sx = 1.0f + sign * nx * nx * a; *sy = sign * b; *sz = -sign * nx;
    *tx = b; *ty = sign + ny * ny * a; *tz = -ny;
}

/* sin and cos of x (|x| up to a few pi), 8 lanes without library calls. Quadrant
 * q = rint(2 x / pi), two-part Cody-Waite reduction, Cephes' sinf / cosf polynomials on
 * [-pi/4, pi/4]: about 1e-7 absolute error (tests/test_kernels.py). */
inline void fast_sincos(const realv x, realv *s, realv *c)
{
    const realv j = rint(x * 0.63661977236758134f);
    const intv q = convert_intv(j);
    realv y = fma(-j, (realv)1.5707963705062866f, x);
    y = fma(-j, (realv)-4.3711388286737929e-08f, y);
    const realv z = y * y;
    const realv sp = ((-1.9515295891e-4f * z + 8.3321608736e-3f) * z - 1.6666654611e-1f) * z * y + y;
    const realv cp = ((2.443315711809948e-5f * z - 1.388731625493765e-3f) * z + 4.166664568298827e-2f) * z * z
                     - 0.5f * z + 1.0f;
    const intv swap = (q & 1) != 0;
    const realv ss = select(sp, cp, swap), cc = select(cp, sp, swap);
    *s = select(ss, -ss, (q & 2) != 0);
    *c = select(cc, -cc, ((q + 1) & 2) != 0);
}

/* atan2(y, x) in (-pi, pi] to ~2 ulp of pi (measured in tests/test_kernels.py), branch-free:
 * PoCL's atan2 and acos calls cost half of the shade kernel (measured 2x). The octant is
 * reduced to t = min/max in [0, 1], then to [-tan(pi/8), tan(pi/8)] about pi/4, where
 * the odd polynomial of Cephes' atanf holds. */
inline realv fast_atan2(const realv y, const realv x)
{
    const realv ax = fabs(x), ay = fabs(y);
    const realv hi = fmax(ax, ay), lo = fmin(ax, ay);
    const realv t = select((realv)0.0f, lo / hi, hi > 0.0f);
    const intv big = t > 0.41421356237309503f;          /* tan(pi/8) */
    const realv z = select(t, (t - 1.0f) / (t + 1.0f), big);
    const realv z2 = z * z;
    realv a = (((8.05374449538e-2f * z2 - 1.38776856032e-1f) * z2 + 1.99777106478e-1f) * z2
               - 3.33329491539e-1f) * z2 * z + z;
    a += select((realv)0.0f, (realv)(0.25f * PI_F), big);
    a = select(a, 0.5f * PI_F - a, ay > ax);
    a = select(a, PI_F - a, x < 0.0f);
    return select(a, -a, y < 0.0f);
}

/* The lat-long square of the light tree: phi = 2 pi u, theta = pi v (map frame),
 * with du dv / d omega = 1 / (2 pi^2 sin theta); m = map_from_world (row-major 3x3).
 * numpy twin: Environment.square_to_world, world_to_square, square_to_solid_angle. */
inline void env_square_to_world(__global const float *m, const realv u, const realv v,
                                realv *x, realv *y, realv *z)
{
    realv sp, cp, st, ct;
    fast_sincos(2.0f * PI_F * u, &sp, &cp);
    fast_sincos(PI_F * v, &st, &ct);
    const realv dx = sp * st, dy = ct, dz = -cp * st;
    *x = m[0] * dx + m[3] * dy + m[6] * dz;   /* map_from_world transposed */
    *y = m[1] * dx + m[4] * dy + m[7] * dz;
    *z = m[2] * dx + m[5] * dy + m[8] * dz;
}

inline void env_world_to_square(__global const float *m, const realv x, const realv y, const realv z,
                                realv *u, realv *v)
{
    const realv dx = m[0] * x + m[1] * y + m[2] * z;
    const realv dy = m[3] * x + m[4] * y + m[5] * z;
    const realv dz = m[6] * x + m[7] * y + m[8] * z;
    realv uu = fast_atan2(dx, -dz) * INV_2PI_F;
    uu -= floor(uu);
    /* theta = atan2(sin, cos): accurate at the poles, unlike acos */
    const realv vv = fast_atan2(sqrt(dx * dx + dz * dz), dy) * INV_PI_F;
    *u = fmin(uu, ONE_MINUS_EPS);
    *v = fmin(vv, ONE_MINUS_EPS);
}

/* rotate_y turns about +Y: sin(theta) is the same in world and map frames. */
inline realv env_square_to_solid_angle(const realv x, const realv z)
{
    const realv s = sqrt(x * x + z * z);  /* sin(theta), accurate near the poles */
    return select((realv)0.0f, 1.0f / (2.0f * PI_F * PI_F * s), s > 0.0f);
}

/* Index of the texel (width w, height h, row-major) holding point (u, v) of the square. */
inline uintv env_texel(const int w, const int h, const realv u, const realv v)
{
    const intv col = min(convert_intv(u * (float)w), w - 1);
    const intv row = min(convert_intv(v * (float)h), h - 1);
    return as_uintv(row * w + col);
}

/* The map texels (rows of 4 floats: r, g, b, unused) of width w and height h at points (u, v) of
 * its square, interpolated bilinearly between texel centres: wrapping in u (longitude), clamped
 * in v (the poles). What a camera ray that misses sees with background = "bilinear"; the
 * lighting stays the nearest texel's. numpy twin: wavlight.envmap.bilinear. */
inline void env_bilinear(__global const float *texels, const int w, const int h, const realv u, const realv v,
                         realv *r, realv *g, realv *b)
{
    const realv x = u * (float)w - 0.5f;
    const realv y = clamp(v * (float)h - 0.5f, 0.0f, (float)(h - 1));
    const realv x0 = floor(x), y0 = floor(y);
    const realv fx = x - x0, fy = y - y0;
    intv c0 = convert_intv(x0);
    c0 = select(c0, c0 + w, c0 < 0);
    c0 = select(c0, c0 - w, c0 >= w);
    const intv c1 = select(c0 + 1, (intv)0, c0 + 1 >= w);
    const intv r0 = min(convert_intv(y0), h - 1), r1 = min(r0 + 1, h - 1);
    realv ar, ag, ab, br, bg, bb, cr, cg, cb, dr, dg, db, unused;
    GATHER4(texels, 4 * as_uintv(r0 * w + c0), &ar, &ag, &ab, &unused);
    GATHER4(texels, 4 * as_uintv(r0 * w + c1), &br, &bg, &bb, &unused);
    GATHER4(texels, 4 * as_uintv(r1 * w + c0), &cr, &cg, &cb, &unused);
    GATHER4(texels, 4 * as_uintv(r1 * w + c1), &dr, &dg, &db, &unused);
    const realv gx = 1.0f - fx, gy = 1.0f - fy;
    *r = (ar * gx + br * fx) * gy + (cr * gx + dr * fx) * fy;
    *g = (ag * gx + bg * fx) * gy + (cg * gx + dg * fx) * fy;
    *b = (ab * gx + bb * fx) * gy + (cb * gx + db * fx) * fy;
}
#endif
