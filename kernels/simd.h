/* Eight shading points per work-item, in OpenCL vector types (float8 / int8 / uint8).
 *
 * PoCL could vectorise a one-point-per-work-item kernel across work-items itself, but
 * whether it does is LLVM's cost-model call and depends on the CPU: with AVX-512 it
 * did; on AVX2-only CPUs it judges the gathers unprofitable and runs scalar code
 * (measured on an AMD EPYC: the light tree walk 12.3 M samples/s scalar, 48.9 M/s
 * written 8-wide with these types, same results bit for bit). Written with vector
 * types the kernels are 8-wide on every CPU. Conventions: comparisons give int8 masks
 * (-1 true, 0 false) and select(a, b, mask) / mask ? b : a pick per lane; per-lane
 * loads from tables are GATHER; a work-item owns points 8 g .. 8 g + 7 (LANE_INDEX),
 * loads clamp the index to count - 1, stores go through STORE_LANES (one vector store
 * when all lanes exist, else lane by lane).
 */
#ifndef WAVLIGHT_SIMD_H
#define WAVLIGHT_SIMD_H

/* The walks ask for full unrolling over the tree's levels; past ~10 levels LLVM may decline
 * ("loop not unrolled"), which is correct code, only slower. Without this its warning count
 * went straight to the user's terminal from PoCL's compiler ("4 warnings generated."). */
#pragma clang diagnostic ignored "-Wpass-failed"

/* Kernel helpers are forced inline: LLVM in PoCL left the product walk and its importance
 * functions as calls (Lobe and outputs through memory). */
#define INLINE inline __attribute__((always_inline))

#ifndef LANES
#define LANES 8      /* the host passes wavlight.cl.LANES; 16 also works, measured no faster on AVX2 */
#endif
#define SIMD_CAT_(a, b) a##b
#define SIMD_CAT(a, b) SIMD_CAT_(a, b)
typedef SIMD_CAT(float, LANES) realv;
typedef SIMD_CAT(int, LANES) intv;
typedef SIMD_CAT(uint, LANES) uintv;
#define convert_realv SIMD_CAT(convert_float, LANES)
#define convert_intv SIMD_CAT(convert_int, LANES)
#define as_uintv SIMD_CAT(as_uint, LANES)
#define as_intv SIMD_CAT(as_int, LANES)
#define vloadv SIMD_CAT(vload, LANES)
#define vstorev SIMD_CAT(vstore, LANES)

#if LANES == 8
#define LANE_IDS ((uintv)(0, 1, 2, 3, 4, 5, 6, 7))
#define GATHER_T(T, p, i) ((T)((p)[(i).s0], (p)[(i).s1], (p)[(i).s2], (p)[(i).s3], \
                               (p)[(i).s4], (p)[(i).s5], (p)[(i).s6], (p)[(i).s7]))
#elif LANES == 16
#define LANE_IDS ((uintv)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15))
#define GATHER_T(T, p, i) ((T)((p)[(i).s0], (p)[(i).s1], (p)[(i).s2], (p)[(i).s3], \
                               (p)[(i).s4], (p)[(i).s5], (p)[(i).s6], (p)[(i).s7], \
                               (p)[(i).s8], (p)[(i).s9], (p)[(i).sa], (p)[(i).sb], \
                               (p)[(i).sc], (p)[(i).sd], (p)[(i).se], (p)[(i).sf]))
#else
#error "LANES is 8 or 16"
#endif
#define GATHER(p, i) GATHER_T(realv, p, i)

/* Two (three, four) adjacent floats per lane, p[i] .. p[i + 1] (p[i + 2], p[i + 3]), into
 * a, b (, c, d): one 8-byte (12-, 16-byte) load per lane instead of two (three, four)
 * scalar gathers. */
#if LANES == 8
#define GATHER2(p, i, a, b)                                                                           \
    do {                                                                                              \
        const float2 q0_ = vload2(0, (p) + (i).s0), q1_ = vload2(0, (p) + (i).s1);                     \
        const float2 q2_ = vload2(0, (p) + (i).s2), q3_ = vload2(0, (p) + (i).s3);                     \
        const float2 q4_ = vload2(0, (p) + (i).s4), q5_ = vload2(0, (p) + (i).s5);                     \
        const float2 q6_ = vload2(0, (p) + (i).s6), q7_ = vload2(0, (p) + (i).s7);                     \
        *(a) = (realv)(q0_.x, q1_.x, q2_.x, q3_.x, q4_.x, q5_.x, q6_.x, q7_.x);                       \
        *(b) = (realv)(q0_.y, q1_.y, q2_.y, q3_.y, q4_.y, q5_.y, q6_.y, q7_.y);                       \
    } while (0)
#define GATHER3(p, i, a, b, c)                                                                        \
    do {                                                                                              \
        const float3 q0_ = vload3(0, (p) + (i).s0), q1_ = vload3(0, (p) + (i).s1);                     \
        const float3 q2_ = vload3(0, (p) + (i).s2), q3_ = vload3(0, (p) + (i).s3);                     \
        const float3 q4_ = vload3(0, (p) + (i).s4), q5_ = vload3(0, (p) + (i).s5);                     \
        const float3 q6_ = vload3(0, (p) + (i).s6), q7_ = vload3(0, (p) + (i).s7);                     \
        *(a) = (realv)(q0_.x, q1_.x, q2_.x, q3_.x, q4_.x, q5_.x, q6_.x, q7_.x);                       \
        *(b) = (realv)(q0_.y, q1_.y, q2_.y, q3_.y, q4_.y, q5_.y, q6_.y, q7_.y);                       \
        *(c) = (realv)(q0_.z, q1_.z, q2_.z, q3_.z, q4_.z, q5_.z, q6_.z, q7_.z);                       \
    } while (0)
#define GATHER4(p, i, a, b, c, d)                                                                     \
    do {                                                                                              \
        const float4 q0_ = vload4(0, (p) + (i).s0), q1_ = vload4(0, (p) + (i).s1);                     \
        const float4 q2_ = vload4(0, (p) + (i).s2), q3_ = vload4(0, (p) + (i).s3);                     \
        const float4 q4_ = vload4(0, (p) + (i).s4), q5_ = vload4(0, (p) + (i).s5);                     \
        const float4 q6_ = vload4(0, (p) + (i).s6), q7_ = vload4(0, (p) + (i).s7);                     \
        *(a) = (realv)(q0_.x, q1_.x, q2_.x, q3_.x, q4_.x, q5_.x, q6_.x, q7_.x);                       \
        *(b) = (realv)(q0_.y, q1_.y, q2_.y, q3_.y, q4_.y, q5_.y, q6_.y, q7_.y);                       \
        *(c) = (realv)(q0_.z, q1_.z, q2_.z, q3_.z, q4_.z, q5_.z, q6_.z, q7_.z);                       \
        *(d) = (realv)(q0_.w, q1_.w, q2_.w, q3_.w, q4_.w, q5_.w, q6_.w, q7_.w);                       \
    } while (0)
#else
#define GATHER2(p, i, a, b) do { *(a) = GATHER(p, i); *(b) = GATHER(p, (i) + 1); } while (0)
#define GATHER3(p, i, a, b, c) do { GATHER2(p, i, a, b); *(c) = GATHER(p, (i) + 2); } while (0)
#define GATHER4(p, i, a, b, c, d) \
    do { *(a) = GATHER(p, i); *(b) = GATHER(p, (i) + 1); *(c) = GATHER(p, (i) + 2); *(d) = GATHER(p, (i) + 3); } while (0)
#endif
#define GATHER_INT(p, i) GATHER_T(intv, p, i)

/* Ask the CPU to fetch the cache line of p[i] for every lane, without waiting for it
 * (lane by lane by name: a loop over lane indices measured slower). */
#define PF_(p, i, s) __builtin_prefetch((p) + (i).s)
#if LANES == 8
#define PREFETCH_LANES(p, i) do { PF_(p, i, s0); PF_(p, i, s1); PF_(p, i, s2); PF_(p, i, s3); \
                                  PF_(p, i, s4); PF_(p, i, s5); PF_(p, i, s6); PF_(p, i, s7); } while (0)
#else
#define PREFETCH_LANES(p, i) do { PF_(p, i, s0); PF_(p, i, s1); PF_(p, i, s2); PF_(p, i, s3); \
                                  PF_(p, i, s4); PF_(p, i, s5); PF_(p, i, s6); PF_(p, i, s7); \
                                  PF_(p, i, s8); PF_(p, i, s9); PF_(p, i, sa); PF_(p, i, sb); \
                                  PF_(p, i, sc); PF_(p, i, sd); PF_(p, i, se); PF_(p, i, sf); } while (0)
#endif

/* The point indices of this work-item's lanes, clamped to count - 1 (for loads). */
#define LANE_INDEX(count) min(LANE_IDS + (uint)get_global_id(0) * LANES, \
                              (uintv)(max((uint)(count), 1u) - 1u))
#define LANE_BASE() ((uint)get_global_id(0) * LANES)

/* p[i] per lane: one vector load when all lanes exist (idx = base .. base + LANES - 1), else a gather */
#define LOAD_LANES(p, idx, base, count) (((base) + LANES <= (count)) ? vloadv(0, (p) + (base)) : GATHER(p, idx))

/* out[base .. base + LANES - 1] = v, for the lanes below count only */
#define STORE_LANES(v, out, base, count)                                              \
    do {                                                                              \
        if ((base) + LANES <= (count)) vstorev((v), 0, (out) + (base));               \
        else for (uint k_ = 0; (base) + k_ < (count); ++k_) (out)[(base) + k_] = (v)[k_]; \
    } while (0)

#endif
