/* Directions: tangent frames, sin / cos / atan2 without library calls, the lat-long
 * square of the light tree and the equirectangular nearest-texel lookup of the scene format.
 * numpy twins: wavlight/warp.py and wavlight/envmap.py.
 */
#ifndef WAVLIGHT_SPHERE_H
#define WAVLIGHT_SPHERE_H
#include "common.h"

#define PI_F 3.14159265358979323846f
#define INV_PI_F 0.31830988618379067154f
#define INV_2PI_F 0.15915494309189533577f
#define INV_4PI_F 0.07957747154594766788f

/* Scalar code only, for PoCL's work-item vectoriser (the shade kernel is one point per
 * work-item, vectorised 8 wide across work-items). LLVM's SLP vectoriser runs first and
 * bundles two isomorphic scalar chains that meet in one operation (two fabs feeding a
 * compare, two selects with swapped operands, adjacent stores, a 3-float struct that
 * the ABI passes as <2 x float> + float) into a 2-vector; PoCL's vectoriser then gives
 * up on the whole kernel (measured 2-3x slower). So: 3-vectors as three floats with
 * pointer outputs, no vector types, and where two chains meet, they are written
 * differently on purpose (noted at each place). tests/test_vectorised.py watches it. */

/* |v| written as max(v, -v): the partner of a fabs() in a pair that must not be bundled. */
#define ABS_ALT(v) fmax((v), -(v))

/* Orthonormal frame (s, t) about a unit normal n (Duff et al. 2017). */
__attribute__((always_inline)) inline void make_frame(const float nx, const float ny, const float nz,
                                                      float *sx, float *sy, float *sz, float *tx, float *ty, float *tz)
{
    const float sign = nz >= 0.0f ? 1.0f : -1.0f;
    const float a = -1.0f / (sign + nz);
    const float b = nx * ny * a;
    *sx = 1.0f + sign * nx * nx * a; *sy = sign * b; *sz = -sign * nx;
    *tx = b; *ty = sign + ny * ny * a; *tz = -ny;
}

/* sin and cos of x (|x| up to a few pi) without library calls: PoCL's sin and cos
 * carry a large-argument reduction call that stops the work-item vectoriser. Quadrant
 * q = rint(2 x / pi), two-part Cody-Waite reduction, Cephes' sinf / cosf polynomials on
 * [-pi/4, pi/4]: about 1e-7 absolute error (tests/test_kernels.py). */
__attribute__((always_inline)) inline void fast_sincos(const float x, float *s, float *c)
{
    const float j = rint(x * 0.63661977236758134f);
    const int q = (int)j;
    float y = fma(-j, 1.5707963705062866f, x);
    y = fma(-j, -4.3711388286737929e-08f, y);
    const float z = y * y;
    const float sp = ((-1.9515295891e-4f * z + 8.3321608736e-3f) * z - 1.6666654611e-1f) * z * y + y;
    const float cp = ((2.443315711809948e-5f * z - 1.388731625493765e-3f) * z + 4.166664568298827e-2f) * z * z
                     - 0.5f * z + 1.0f;
    const int swap = q & 1;
    const float ss = swap ? cp : sp;
    const float cc = swap ? sp : cp;
    *s = (q & 2) ? -ss : ss;                                        /* select ... */
    *c = as_float(as_uint(cc) ^ ((uint)((q + 1) & 2) << 30));       /* ... and sign-bit xor: not a pair */
}

/* atan2(y, x) in (-pi, pi] to ~2 ulp of pi (measured in tests/test_kernels.py), branch-free:
 * PoCL's atan2 and acos calls cost half of the shade kernel (measured 2x). The octant is
 * reduced to t = min/max in [0, 1], then to [-tan(pi/8), tan(pi/8)] about pi/4, where
 * the odd polynomial of Cephes' atanf holds. */
__attribute__((always_inline)) inline float fast_atan2(const float y, const float x)
{
    const float ax = fabs(x), ay = ABS_ALT(y);   /* not two fabs (see above) */
    const float hi = fmax(ax, ay), lo = fmin(ax, ay);
    float t = hi > 0.0f ? lo / hi : 0.0f;
    const int big = t > 0.41421356237309503f;          /* tan(pi/8) */
    const float z = big ? (t - 1.0f) / (t + 1.0f) : t;
    const float z2 = z * z;
    float a = (((8.05374449538e-2f * z2 - 1.38776856032e-1f) * z2 + 1.99777106478e-1f) * z2
               - 3.33329491539e-1f) * z2 * z + z;
    a += big ? 0.25f * PI_F : 0.0f;
    a = ay > ax ? 0.5f * PI_F - a : a;
    a = x < 0.0f ? PI_F - a : a;
    return y < 0.0f ? -a : a;
}

/* The environment's rotation map_from_world (row-major 3x3, global memory). */
__attribute__((always_inline)) inline void env_to_map(__global const float *m, const float x, const float y, const float z,
                                                      float *dx, float *dy, float *dz)
{
    *dx = m[0] * x + m[1] * y + m[2] * z;
    *dy = m[3] * x + m[4] * y + m[5] * z;
    *dz = m[6] * x + m[7] * y + m[8] * z;
}

/* The lat-long square of the light tree: phi = 2 pi u, theta = pi v (map frame),
 * with du dv / d omega = 1 / (2 pi^2 sin theta). numpy twin: Environment.square_to_world,
 * world_to_square, square_to_solid_angle. */
__attribute__((always_inline)) inline void env_square_to_world(__global const float *m, const float u, const float v,
                                                               float *x, float *y, float *z)
{
    float sp, cp, st, ct;
    fast_sincos(2.0f * PI_F * u, &sp, &cp);
    fast_sincos(PI_F * v, &st, &ct);
    const float dx = sp * st, dy = ct, dz = -cp * st;
    *x = m[0] * dx + m[3] * dy + m[6] * dz;   /* map_from_world transposed */
    *y = m[1] * dx + m[4] * dy + m[7] * dz;
    *z = m[2] * dx + m[5] * dy + m[8] * dz;
}

__attribute__((always_inline)) inline void env_world_to_square(__global const float *m, const float x, const float y,
                                                               const float z, float *u, float *v)
{
    float dx, dy, dz;
    env_to_map(m, x, y, z, &dx, &dy, &dz);
    float uu = fast_atan2(dx, -dz) * INV_2PI_F;
    uu -= floor(uu);
    /* theta = atan2(sin, cos): accurate at the poles, unlike acos */
    const float vv = fast_atan2(sqrt(dx * dx + dz * dz), dy) * INV_PI_F;
    *u = fmin(uu, ONE_MINUS_EPS);
    *v = fmin(vv, ONE_MINUS_EPS);
}

/* rotate_y turns about +Y: sin(theta) is the same in world and map frames. */
__attribute__((always_inline)) inline float env_square_to_solid_angle(const float x, const float z)
{
    const float s = sqrt(x * x + z * z);  /* sin(theta), accurate near the poles */
    return s > 0.0f ? 1.0f / (2.0f * PI_F * PI_F * s) : 0.0f;
}

/* Index of the texel (width w, height h, row-major) holding point (u, v) of the square. */
__attribute__((always_inline)) inline int env_texel(const int w, const int h, const float u, const float v)
{
    const int col = min((int)(u * w), w - 1);
    const int row = min((int)(v * h), h - 1);
    return row * w + col;
}
#endif
