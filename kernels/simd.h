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
 * loads clamp the index to count - 1, stores go through STORE_LANES (vstore8 when all
 * eight exist, else lane by lane).
 */
#ifndef WAVLIGHT_SIMD_H
#define WAVLIGHT_SIMD_H

#define LANES 8
typedef float8 realv;
typedef int8 intv;
typedef uint8 uintv;

#define GATHER(p, i) ((realv)((p)[(i).s0], (p)[(i).s1], (p)[(i).s2], (p)[(i).s3], \
                              (p)[(i).s4], (p)[(i).s5], (p)[(i).s6], (p)[(i).s7]))
#define GATHER_INT(p, i) ((intv)((p)[(i).s0], (p)[(i).s1], (p)[(i).s2], (p)[(i).s3], \
                                 (p)[(i).s4], (p)[(i).s5], (p)[(i).s6], (p)[(i).s7]))

/* The point indices of this work-item's lanes, clamped to count - 1 (for loads). */
#define LANE_INDEX(count) min((uintv)(0, 1, 2, 3, 4, 5, 6, 7) + (uint)get_global_id(0) * LANES, \
                              (uintv)((count) - 1))
#define LANE_BASE() ((uint)get_global_id(0) * LANES)

/* p[i] per lane: one vload8 when all eight lanes exist (idx = base .. base + 7), else a gather */
#define LOAD_LANES(p, idx, base, count) (((base) + LANES <= (count)) ? vload8(0, (p) + (base)) : GATHER(p, idx))

/* out[base .. base + 7] = v, for the lanes below count only */
#define STORE_LANES(v, out, base, count)                                              \
    do {                                                                              \
        if ((base) + LANES <= (count)) vstore8((v), 0, (out) + (base));               \
        else for (uint k_ = 0; (base) + k_ < (count); ++k_) (out)[(base) + k_] = (v)[k_]; \
    } while (0)

#endif
