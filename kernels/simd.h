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
#define convert_uintv SIMD_CAT(convert_uint, LANES)
#define as_uintv SIMD_CAT(as_uint, LANES)
#define as_intv SIMD_CAT(as_int, LANES)
#define as_realv SIMD_CAT(as_float, LANES)
#define vloadv SIMD_CAT(vload, LANES)
#define vstorev SIMD_CAT(vstore, LANES)

/* Inline builtins (-DINLINE_BUILTINS=1, which wavlight.cl passes on PoCL CPU devices). The
 * PoCL of the PyPI wheels (pocl-binary-distribution 3.0, LLVM 14) calls its kernel
 * library out of line: each select, clamp, fmin, vload4 or sqrt was a function call,
 * and a call clobbers every vector register (the System V ABI saves none), so the walks
 * spilled their live vectors around each of some 1500 call sites in the product kernel
 * (1024^2 leaves). These equivalents
 * are operators and clang builtins, which LLVM inlines (vblendvps, vmaxps, vsqrtps,
 * vroundps, vfmadd, merged loads): the product walk (ggx 0.05) over 1024^2 leaves went
 * from 11.5 to 26 M samples/s, over 256^2 from 7 to 28, over 64^2 from 13 to 35, the
 * bunny's wavelet render from 2.8 to 1.7 s. With Debian's PoCL 3.1 (LLVM 15), which
 * inlines its library, they are as fast or a few percent faster. They keep the library's semantics for the types the kernels use:
 * select tests the mask's sign bit, as the vector ternary does; fmin / fmax return the
 * other argument where one is NaN; rsqrt is 1 / sqrt (the library's is within 2 ulp).
 * tests/test_device.py checks them against the library, bit for bit. Other devices'
 * compilers inline their builtins and may not know clang's; a PoCL on LLVM 13 or older
 * (no __builtin_elementwise_*) keeps the library's. */
#ifndef INLINE_BUILTINS
#define INLINE_BUILTINS 0
#endif
#if INLINE_BUILTINS && defined(__has_builtin)   /* clang 14 and newer (PoCL 3.0 links LLVM 14) */
#if __has_builtin(__builtin_elementwise_floor) && __has_builtin(__builtin_elementwise_roundeven) && \
    __has_builtin(__builtin_reduce_or) && __has_builtin(__builtin_reduce_and)
#define WL_INLINE_BUILTINS 1
#endif
#endif
#ifdef WL_INLINE_BUILTINS
#pragma clang diagnostic ignored "-Wpsabi"   /* 16-lane vectors by value (LANES = 16) without AVX-512 */
#define OVERLOAD inline __attribute__((always_inline, overloadable))
#if LANES == 8
#define LANEWISE(f, x) ((realv)(f((x).s0), f((x).s1), f((x).s2), f((x).s3), f((x).s4), f((x).s5), f((x).s6), f((x).s7)))
#define LANEWISE3(f, x, y, z) ((realv)(f((x).s0, (y).s0, (z).s0), f((x).s1, (y).s1, (z).s1), f((x).s2, (y).s2, (z).s2), \
                                       f((x).s3, (y).s3, (z).s3), f((x).s4, (y).s4, (z).s4), f((x).s5, (y).s5, (z).s5), \
                                       f((x).s6, (y).s6, (z).s6), f((x).s7, (y).s7, (z).s7)))
#define ulongv ulong8
#else
#define LANEWISE(f, x) ((realv)(f((x).s0), f((x).s1), f((x).s2), f((x).s3), f((x).s4), f((x).s5), f((x).s6), f((x).s7), \
                                f((x).s8), f((x).s9), f((x).sa), f((x).sb), f((x).sc), f((x).sd), f((x).se), f((x).sf)))
#define LANEWISE3(f, x, y, z) ((realv)(f((x).s0, (y).s0, (z).s0), f((x).s1, (y).s1, (z).s1), f((x).s2, (y).s2, (z).s2), \
                                       f((x).s3, (y).s3, (z).s3), f((x).s4, (y).s4, (z).s4), f((x).s5, (y).s5, (z).s5), \
                                       f((x).s6, (y).s6, (z).s6), f((x).s7, (y).s7, (z).s7), f((x).s8, (y).s8, (z).s8), \
                                       f((x).s9, (y).s9, (z).s9), f((x).sa, (y).sa, (z).sa), f((x).sb, (y).sb, (z).sb), \
                                       f((x).sc, (y).sc, (z).sc), f((x).sd, (y).sd, (z).sd), f((x).se, (y).se, (z).se), \
                                       f((x).sf, (y).sf, (z).sf)))
#define ulongv ulong16
#endif
#define WL_VECTOR_OPS(R, I)                                                                            \
    OVERLOAD R wl_fmin(const R a, const R b) { return ((a < b) | (b != b)) ? a : b; }                   \
    OVERLOAD R wl_fmax(const R a, const R b) { return ((a > b) | (b != b)) ? a : b; }                   \
    OVERLOAD R wl_fmin(const R a, const float b) { return wl_fmin(a, (R)b); }                           \
    OVERLOAD R wl_fmax(const R a, const float b) { return wl_fmax(a, (R)b); }                           \
    OVERLOAD R wl_fmin(const float a, const R b) { return wl_fmin((R)a, b); }                           \
    OVERLOAD R wl_fmax(const float a, const R b) { return wl_fmax((R)a, b); }                           \
    OVERLOAD R wl_clamp(const R x, const float lo, const float hi) { return wl_fmin(wl_fmax(x, lo), hi); } \
    OVERLOAD R wl_clamp(const R x, const R lo, const R hi) { return wl_fmin(wl_fmax(x, lo), hi); }      \
    OVERLOAD I wl_isfinite(const R x) { return (as_##I(x) & 0x7fffffff) < 0x7f800000; }                 \
    OVERLOAD R wl_fabs(const R x) { return as_##R(as_##I(x) & 0x7fffffff); }                            \
    OVERLOAD R wl_sqrt(const R x) { return LANEWISE(__builtin_sqrtf, x); }                              \
    OVERLOAD R wl_rsqrt(const R x) { return 1.0f / wl_sqrt(x); }                                        \
    OVERLOAD R wl_floor(const R x) { return __builtin_elementwise_floor(x); }                           \
    OVERLOAD R wl_rint(const R x) { return __builtin_elementwise_roundeven(x); }                        \
    OVERLOAD R wl_fma(const R a, const R b, const R c) { return LANEWISE3(__builtin_fmaf, a, b, c); }   \
    OVERLOAD int wl_any(const I m) { return __builtin_reduce_or(m) < 0; }                               \
    OVERLOAD int wl_all(const I m) { return __builtin_reduce_and(m) < 0; }
/* select(a, b, c): b where c's sign bit is set, else a; vector conditions only */
OVERLOAD realv wl_select(const realv a, const realv b, const intv c) { return (c < 0) ? b : a; }
OVERLOAD realv wl_select(const realv a, const float b, const intv c) { return wl_select(a, (realv)b, c); }
OVERLOAD realv wl_select(const float a, const realv b, const intv c) { return wl_select((realv)a, b, c); }
OVERLOAD intv wl_select(const intv a, const intv b, const intv c) { return (c < 0) ? b : a; }
OVERLOAD uintv wl_select(const uintv a, const uintv b, const intv c) { return (c < 0) ? b : a; }
#define WL_INT_OPS(T, S)                                                                               \
    OVERLOAD T wl_min(const T a, const T b) { return a < b ? a : b; }                                   \
    OVERLOAD T wl_max(const T a, const T b) { return a > b ? a : b; }                                   \
    OVERLOAD T wl_min(const T a, const S b) { return wl_min(a, (T)b); }                                 \
    OVERLOAD T wl_max(const T a, const S b) { return wl_max(a, (T)b); }                                 \
    OVERLOAD T wl_clamp(const T x, const S lo, const S hi) { return wl_min(wl_max(x, lo), hi); }
WL_VECTOR_OPS(realv, intv)
WL_INT_OPS(intv, int)
WL_INT_OPS(uintv, uint)
OVERLOAD uintv wl_mul_hi(const uintv a, const uintv b)
{
    return __builtin_convertvector((__builtin_convertvector(a, ulongv) * __builtin_convertvector(b, ulongv)) >> 32,
                                   uintv);
}
OVERLOAD float wl_fmin(const float a, const float b) { return ((a < b) | (b != b)) ? a : b; }
OVERLOAD float wl_fmax(const float a, const float b) { return ((a > b) | (b != b)) ? a : b; }
OVERLOAD float wl_clamp(const float x, const float lo, const float hi) { return wl_fmin(wl_fmax(x, lo), hi); }
OVERLOAD int wl_isfinite(const float x) { return (as_int(x) & 0x7fffffff) < 0x7f800000; }
OVERLOAD float wl_fabs(const float x) { return as_float(as_int(x) & 0x7fffffff); }
OVERLOAD float wl_sqrt(const float x) { return __builtin_sqrtf(x); }
OVERLOAD int wl_min(const int a, const int b) { return a < b ? a : b; }
OVERLOAD int wl_max(const int a, const int b) { return a > b ? a : b; }
OVERLOAD uint wl_min(const uint a, const uint b) { return a < b ? a : b; }
OVERLOAD uint wl_max(const uint a, const uint b) { return a > b ? a : b; }
#undef WL_VECTOR_OPS
#undef WL_INT_OPS
/* PoCL's headers define some builtin names as macros of their own (select -> _cl_select) */
#undef select
#undef fmin
#undef fmax
#undef clamp
#undef isfinite
#undef fabs
#undef sqrt
#undef rsqrt
#undef floor
#undef rint
#undef fma
#undef any
#undef all
#undef mul_hi
#undef min
#undef max
#define select wl_select
#define fmin wl_fmin
#define fmax wl_fmax
#define clamp wl_clamp
#define isfinite wl_isfinite
#define fabs wl_fabs
#define sqrt wl_sqrt
#define rsqrt wl_rsqrt
#define floor wl_floor
#define rint wl_rint
#define fma wl_fma
#define any wl_any
#define all wl_all
#define mul_hi wl_mul_hi
#define min wl_min
#define max wl_max
/* Loads and stores of 2, 4 and LANES adjacent floats at p + j. For LLVM 15 and newer
 * (Debian's PoCL 3.1) float by float, which LLVM merges into vector loads; through a vector
 * type of alignment 4 the product walk at 1024^2 ran 2x slower there (12.9 against 26.5
 * M/s; vload4 22.8). For LLVM 14 (the PyPI PoCL 3.0) through that type: float by float
 * the product walk was as fast (26.8 M/s), but the light walk 12% slower (120 against 137
 * M/s at 64^2) and vload4 is a call there. */
#if __clang_major__ >= 15
#define LOAD2_(p, j) ((float2)((p)[(j)], (p)[(j) + 1]))
#define LOAD4_(p, j) ((float4)((p)[(j)], (p)[(j) + 1], (p)[(j) + 2], (p)[(j) + 3]))
INLINE realv load_lanes_(__global const float *p)
{
    realv r;
    for (int k = 0; k < LANES; ++k) r[k] = p[k];
    return r;
}
#define LOADV_(p, j) load_lanes_((p) + (j))
#define STOREV_(v, p, j) do { for (int k_ = 0; k_ < LANES; ++k_) ((p) + (j))[k_] = (v)[k_]; } while (0)
#else
typedef float2 __attribute__((aligned(4))) float2_unaligned;
typedef float4 __attribute__((aligned(4))) float4_unaligned;
typedef realv __attribute__((aligned(4))) realv_unaligned;
#define LOAD2_(p, j) (*(__global const float2_unaligned *)((p) + (j)))
#define LOAD4_(p, j) (*(__global const float4_unaligned *)((p) + (j)))
#define LOADV_(p, j) (*(__global const realv_unaligned *)((p) + (j)))
#define STOREV_(v, p, j) (*(__global realv_unaligned *)((p) + (j)) = (v))
#endif
#else
#define LOAD2_(p, j) vload2(0, (p) + (j))
#define LOAD4_(p, j) vload4(0, (p) + (j))
#define LOADV_(p, j) vloadv(0, (p) + (j))
#define STOREV_(v, p, j) vstorev((v), 0, (p) + (j))
#endif

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
        const float2 q0_ = LOAD2_(p, (i).s0), q1_ = LOAD2_(p, (i).s1);                                 \
        const float2 q2_ = LOAD2_(p, (i).s2), q3_ = LOAD2_(p, (i).s3);                                 \
        const float2 q4_ = LOAD2_(p, (i).s4), q5_ = LOAD2_(p, (i).s5);                                 \
        const float2 q6_ = LOAD2_(p, (i).s6), q7_ = LOAD2_(p, (i).s7);                                 \
        *(a) = (realv)(q0_.x, q1_.x, q2_.x, q3_.x, q4_.x, q5_.x, q6_.x, q7_.x);                       \
        *(b) = (realv)(q0_.y, q1_.y, q2_.y, q3_.y, q4_.y, q5_.y, q6_.y, q7_.y);                       \
    } while (0)
#define GATHER3(p, i, a, b, c) do { GATHER2(p, i, a, b); *(c) = GATHER(p, (i) + 2); } while (0)
#define GATHER4(p, i, a, b, c, d)                                                                     \
    do {                                                                                              \
        const float4 q0_ = LOAD4_(p, (i).s0), q1_ = LOAD4_(p, (i).s1);                                 \
        const float4 q2_ = LOAD4_(p, (i).s2), q3_ = LOAD4_(p, (i).s3);                                 \
        const float4 q4_ = LOAD4_(p, (i).s4), q5_ = LOAD4_(p, (i).s5);                                 \
        const float4 q6_ = LOAD4_(p, (i).s6), q7_ = LOAD4_(p, (i).s7);                                 \
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
#define LOAD_LANES(p, idx, base, count) (((base) + LANES <= (count)) ? LOADV_(p, base) : GATHER(p, idx))

/* out[base .. base + LANES - 1] = v, for the lanes below count only */
#define STORE_LANES(v, out, base, count)                                              \
    do {                                                                              \
        if ((base) + LANES <= (count)) STOREV_((v), (out), (base));               \
        else for (uint k_ = 0; (base) + k_ < (count); ++k_) (out)[(base) + k_] = (v)[k_]; \
    } while (0)

#endif
