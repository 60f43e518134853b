/* Philox-4x32-10 (Salmon et al. 2011) over the lanes of a work-item: the samplers'
 * uniforms, drawn where they are used. Counter (c0, c1, c2, c3) = (sample index in its
 * tile, tile index, stream, 0); key = the seed's two 32-bit halves. The stratified
 * sampler moves each pair into a cell of its pixel's grid (stratify_pair). numpy twins
 * and the layout: wavlight/rng.py, wavlight/sampler.py. */
#ifndef WAVLIGHT_RNG_H
#define WAVLIGHT_RNG_H
#include "simd.h"

/* The stream ids the kernels name: wavlight/rng.py declares every stream (its STREAMS) and
 * tests/test_rng_streams.py checks that these agree with it. (relight_moving.cl takes its
 * stream, rng.MOVING_DIRECTIONS, as an argument, and converge.cl the first of its direction
 * streams, rng.CONVERGE_DIRECTIONS: one per slot.) */
#define RNG_JITTER 0u
#define RNG_SHADING 1u
#define RNG_STRATA 2u   /* per pixel and pass: the cell orders of its three pairs */
#define RNG_TEXEL 8u    /* the bake's texel uniforms (relight.cl) */
#define RNG_TEXEL_COAT 9u   /* and those of its plastic coat's pass */
#define RNG_CONVERGE_RESAMPLE 74u   /* the unbiased relit frame's candidates (converge.cl) */
#define RNG_CONVERGE_PICK 75u       /* and its picks among them */

inline void philox4x32_10(uintv c0, uintv c1, uintv c2, uintv c3, uint k0, uint k1,
                          uintv *r0, uintv *r1, uintv *r2, uintv *r3)
{
    for (int round = 0; round < 10; ++round) {
        const uintv hi0 = mul_hi((uintv)0xD2511F53u, c0), lo0 = (uintv)0xD2511F53u * c0;
        const uintv hi1 = mul_hi((uintv)0xCD9E8D57u, c2), lo1 = (uintv)0xCD9E8D57u * c2;
        c0 = hi1 ^ c1 ^ k0;
        c1 = lo1;
        c2 = hi0 ^ c3 ^ k1;
        c3 = lo0;
        k0 += 0x9E3779B9u;
        k1 += 0xBB67AE85u;
    }
    *r0 = c0;
    *r1 = c1;
    *r2 = c2;
    *r3 = c3;
}

/* A 32-bit word -> float in [0, 1): (w >> 8) 2^-24. */
inline realv word_to_unit(const uintv w)
{
    return convert_realv(w >> 8) * (1.0f / 16777216.0f);
}

/* The four uniforms of samples `index` of tile `tile` in `stream`. */
inline void rng_uniforms(const uintv index, const uint tile, const uint stream, const uint k0, const uint k1,
                         realv *u0, realv *u1, realv *u2, realv *u3)
{
    uintv r0, r1, r2, r3;
    philox4x32_10(index, (uintv)tile, (uintv)stream, (uintv)0u, k0, k1, &r0, &r1, &r2, &r3);
    *u0 = word_to_unit(r0);
    *u1 = word_to_unit(r1);
    *u2 = word_to_unit(r2);
    *u3 = word_to_unit(r3);
}

/* A uniform in [0, 1) for step `step` of a per-lane key (lowbias32, a 32-bit integer hash):
 * fresh numbers for the steps of a weighted reservoir, where rescaling one uniform at each of
 * many steps would spend its 24 bits. numpy twin: wavlight.rng.step_uniforms. */
inline realv step_uniform(const uintv key, const uint step)
{
    uintv x = key + (uintv)(step * 0x9E3779B9u);
    x ^= x >> 16;
    x *= 0x7feb352du;
    x ^= x >> 15;
    x *= 0x846ca68bu;
    x ^= x >> 16;
    return word_to_unit(x);
}

/* a / d and a % d for a < 2^22 (and d >= 1) through one float division: (a + 0.5) / d
 * lies at least 0.5 / d from an integer and its rounding error is below that, so the
 * quotient is exact (a vector integer division would run lane by lane). */
inline uintv div_small(const uintv a, const uint d, uintv *rem)
{
    const uintv q = as_uintv(convert_intv((convert_realv(a) + 0.5f) / (float)d));
    *rem = a - q * d;
    return q;
}

/* Element i of a pseudo-random permutation of 0 .. l - 1 chosen by p (Kensler 2013,
 * "Correlated Multi-Jittered Sampling", Pixar Technical Memo 13-01: a hash that is a
 * bijection on the smallest power-of-two range holding l, walked until it lands below l),
 * then rotated by (p >> 16) mod l; l <= 2^22. */
inline uintv permute_index(uintv i, const uint l, const uintv p)
{
    uint w = l - 1u;
    w |= w >> 1; w |= w >> 2; w |= w >> 4; w |= w >> 8; w |= w >> 16;
    intv todo = (intv)-1;
    uintv out = i;
    while (any(todo)) {   /* cycle walking: about l / (w + 1) <= 2 rounds expected */
        i ^= p; i *= 0xe170893du; i ^= p >> 16; i ^= (i & w) >> 4;
        i ^= p >> 8; i *= 0x0929eb3fu; i ^= p >> 23; i ^= (i & w) >> 1;
        i *= 1u | p >> 27; i *= 0x6935fa69u; i ^= (i & w) >> 11; i *= 0x74dcb303u;
        i ^= (i & w) >> 2; i *= 0x9e501cc3u; i ^= (i & w) >> 2; i *= 0xc860a3dfu;
        i &= w; i ^= i >> 5;
        const intv done = todo & (i < l);
        out = select(out, i, done);
        todo &= ~done;
    }
    uintv shift;
    div_small(p >> 16, l, &shift);
    out += shift;
    return select(out, out - l, out >= l);
}

/* The stratified sampler: sample j of its pixel's k, uniforms (a, b) -> the point a, b of
 * cell permute_index(j, m n, key) of the m x n grid (m = floor(sqrt k), n = ceil(k / m)):
 * the pixel's k samples fill k distinct cells, and each is uniform on the square. */
inline void stratify_pair(realv *a, realv *b, const uintv j, const uint k, const uintv key)
{
    uint m = 1u;   /* floor(sqrt(k)), in integers */
    while ((m + 1u) * (m + 1u) <= k)
        ++m;
    const uint n = (k + m - 1u) / m;
    uintv column;
    const uintv row = div_small(permute_index(j, m * n, key), m, &column);
    /* (c + u) / m can round up to 1 in float32: keep every number below 1 */
    *a = fmin((convert_realv(column) + *a) / (float)m, 0x1.fffffep-1f);
    *b = fmin((convert_realv(row) + *b) / (float)n, 0x1.fffffep-1f);
}
#endif
