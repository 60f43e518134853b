"""Tree layout A/B: the light walk (kernels/warp.cl) on row-major levels against Morton order.

The sampling trees store each level row-major (kernels/common.h), so a walk step reads
its four children from two rows, two cache lines apart. In Morton (Z) order the four
children of a node are four consecutive floats, one cache line. This script measures
whether that would pay: it builds warp.cl as is and with node_index replaced by the
Morton index (children at c .. c + 3), permutes the same light tree into Morton order,
and times both on the same 2^21 uniform points, alternating launch by launch (this VM's
speed drifts by 20-40% between runs), median of --repeat launches each. Both builds
must return bit-identical points and densities (checked). Prints one JSON object.
The light walk is the product walk's memory access pattern without its arithmetic, so
the gain measured here bounds the product walk's.

    python benchmarks/layout_ab.py [--env ../shared/data/envmaps/rooitou_park_1k.hdr] [--levels 8,9,10,11]
"""
from __future__ import annotations

import argparse
import json
import os
import re
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
MORTON_INDEX = """
INLINE uintv spread_bits(uintv v)   /* bits b of v to bits 2b */
{
    v &= 0x0000ffffu;
    v = (v | (v << 8)) & 0x00ff00ffu;
    v = (v | (v << 4)) & 0x0f0f0f0fu;
    v = (v | (v << 2)) & 0x33333333u;
    return (v | (v << 1)) & 0x55555555u;
}
INLINE uintv node_index(const int level, const uintv x, const uintv y)
{
    return (uint)LEVEL_OFFSET(level) + (spread_bits(x) | (spread_bits(y) << 1));
}
"""


def morton_order(tree, n_levels):
    """The tree (row-major levels, kernels/common.h) with every level in Morton order."""
    from wavlight.distributions import level_offset

    out = np.empty_like(tree)
    for level in range(n_levels + 1):
        side = 1 << level
        y, x = np.mgrid[0:side, 0:side]
        code = np.zeros_like(x)
        for b in range(level):
            code |= ((x >> b) & 1) << (2 * b) | ((y >> b) & 1) << (2 * b + 1)
        o = level_offset(level)
        out[o + code.ravel()] = tree[o:o + side * side]
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--env", default=os.path.join(HERE, "..", "..", "shared", "data", "envmaps",
                                                  "rooitou_park_1k.hdr"))
    ap.add_argument("--levels", default="8,9,10,11")
    ap.add_argument("--repeat", type=int, default=9)
    args = ap.parse_args()

    import pyopencl as pcl

    from wavlight import cl
    from wavlight.distributions import HaarTree
    from wavlight.envmap import Environment, read_image

    env = Environment(read_image(os.path.normpath(args.env)), name=args.env)
    ctx, queue = cl.runtime().context, cl.thread_queue()
    count = 1 << 21
    rng = np.random.default_rng(1)
    u = cl.to_device(rng.random((count, 2), dtype=np.float32))
    uv = pcl.Buffer(ctx, pcl.mem_flags.READ_WRITE, count * 8)
    pdf = pcl.Buffer(ctx, pcl.mem_flags.READ_WRITE, count * 4)
    src = cl.kernel_source("warp.cl")
    morton_src = re.sub(r"INLINE uintv node_index\(const int level, const uintv x, const uintv y\)\n\{\n.*?\n\}\n",
                        MORTON_INDEX, src, count=1, flags=re.S)
    morton_src = morton_src.replace("GATHER2(tree, c + cside, &m2, &m3);", "GATHER2(tree, c + 2, &m2, &m3);", 1)
    assert morton_src.count("spread_bits") == 3 and "c + 2," in morton_src, "warp.h changed: update this script"
    out = {"env": os.path.basename(args.env), "samples": count, "repeat": args.repeat, "levels": {}}
    for n in [int(v) for v in args.levels.split(",")]:
        tree = HaarTree(env.luminance_square(n)).nodes()[0].astype(np.float32)
        opts = [f"-DN_LEVELS={n}", "-DBATCHED=0", f"-DLANES={cl.LANES}"]
        runs, buffers = {}, {}   # (set_args keeps no reference to its buffers)
        for name, text, data in (("row_major", src, tree), ("morton", morton_src, morton_order(tree, n))):
            kernel = pcl.Kernel(pcl.Program(ctx, text).build(options=opts), "warp_sample")
            buffers[name] = cl.to_device(data)
            kernel.set_args(buffers[name], np.uint64(0), np.uint32(1), np.uint32(count), u, np.uint32(2),
                            uv, pdf)
            runs[name] = kernel
        results, times = {}, {k: [] for k in runs}
        for rep in range(args.repeat + 1):
            for name, kernel in runs.items():
                t = time.perf_counter()
                pcl.enqueue_nd_range_kernel(queue, kernel, (cl.items(count, cl.LANES),), (64,))
                queue.finish()
                if rep:
                    times[name].append(time.perf_counter() - t)
                else:   # first launch: keep the outputs for the identity check
                    results[name] = (cl.read(uv, (count, 2), np.float32), cl.read(pdf, (count,), np.float32))
        same = all(np.array_equal(a, b) for a, b in zip(results["row_major"], results["morton"]))
        row = {k: round(count / float(np.median(v)) / 1e6, 1) for k, v in times.items()}
        row["morton_over_row_major"] = round(row["morton"] / row["row_major"], 3)
        row["identical"] = bool(same)
        out["levels"][f"{1 << n}^2"] = row
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
