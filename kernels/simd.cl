/* The builtins of simd.h over eight-lane vectors, for the test that compares its inline
 * equivalents (-DINLINE_BUILTINS=1) with the device's library (=0): tests/test_device.py.
 * Per lane i: floats a, b, c, an int mask m and uints x, y in; one row of outputs
 * (out + k count, k in the order below) per operation; GATHER2 / GATHER4 read a at odd
 * offsets (count >= 5). builtins_inlined tells whether the inline equivalents are in use. */
#include "simd.h"

#define N_BUILTIN_OUTPUTS 29

__kernel void builtin_ops(const uint count, __global const float *a_in, __global const float *b_in,
                          __global const float *c_in, __global const int *m_in, __global const uint *x_in,
                          __global const uint *y_in, __global float *out)
{
    const uint base = LANE_BASE();
    if (base >= count) return;
    const uintv i = LANE_INDEX(count);
    const realv a = GATHER(a_in, i), b = GATHER(b_in, i), c = GATHER(c_in, i);
    const intv m = GATHER_INT(m_in, i);
    const uintv x = GATHER_T(uintv, x_in, i), y = GATHER_T(uintv, y_in, i);
    realv r[N_BUILTIN_OUTPUTS] = {
        select(a, b, m), select(a, 0.0f, m), fmin(a, b), fmax(a, b), fmin(a, 1e30f), fmax(a, 0.0f),
        clamp(a, 0.0f, 1.0f), as_realv(isfinite(a)), fabs(a), sqrt(fabs(a)), rsqrt(fabs(a)), floor(a), rint(a),
        fma(a, b, c), as_realv(min(m, 3)), as_realv(max(x, y)), as_realv(clamp(m, 0, 7)), as_realv(mul_hi(x, y)),
        (realv)((float)any(m) + 2.0f * (float)all(m)), fmax(0.0f, a), as_realv(max(m, 0)), as_realv(min(x, y)),
        as_realv(select(x, y, m)), 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f};
    const uintv j = min(i, (uintv)(count - 5)) + 1u;   /* odd offsets, inside a */
    GATHER4(a_in, j, &r[23], &r[24], &r[25], &r[26]);
    GATHER2(a_in, j + 2u, &r[27], &r[28]);
    for (int k = 0; k < N_BUILTIN_OUTPUTS; ++k)
        STORE_LANES(r[k], out + k * count, base, count);
}

__kernel void builtins_inlined(__global int *out)
{
#ifdef WL_INLINE_BUILTINS
    out[0] = 1;
#else
    out[0] = 0;
#endif
}
