/* Philox-4x32-10 (Salmon et al. 2011) over the lanes of a work-item: the independent
 * sampler's uniforms, drawn where they are used. Counter (c0, c1, c2, c3) = (sample
 * index in its tile, tile index, stream, 0); key = the seed's two 32-bit halves.
 * numpy twin and the layout: wavlight/rng.py. */
#ifndef WAVLIGHT_RNG_H
#define WAVLIGHT_RNG_H
#include "simd.h"

#define RNG_JITTER 0u
#define RNG_SHADING 1u

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
#endif
