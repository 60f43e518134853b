"""Interleaved A/B of the sample-generation kernels of this checkout against another revision.

Builds `warp.cl` (light walk) and `product.cl` (product walk) from the kernel sources of the
revision --against names (read with `git show`, so run it in a checkout) and from this
checkout, and times both on the same 2^21 random shading points and light tree, alternating
launch by launch and keeping each kernel's best time: on a shared VM whose speed drifts by
20-40% between runs, two runs one after the other cannot resolve a 15% change, alternating
launches can. In the output "before" is the --against build, "now" this checkout's.
Each build gets the tree layout, arguments and work-groups its own sources expect: a
`product.cl` that reads a table of node angles (`*angles`) gets the table from that
revision's `node_angles` (wavlight/product.py); a kernels/common.h without the Morton tree
layout walks a row-major copy of the same tree, one without the trees' cache-line origin
(TREE_ORIGIN) a copy with node 0 at the buffer's start; the walks run in work-groups of the
revision's `cl.WALK_WORK_GROUP` (64 where its wavlight/cl.py has none). The kernels' other
arguments must be this checkout's (as they are from 3291f7c on). "identical" says whether
both builds returned the same points and densities bit for bit. Prints one JSON object and
writes it, with the run's provenance (benchmarks/provenance.py), to
benchmarks/results/kernel_ab.json (-o FILE another, "-" none).

    python benchmarks/kernel_ab.py --against REVISION [--levels 10] [--repeat 12] [-o FILE]

The figures in benchmarks/results/kernel_ab.json come from

    python benchmarks/kernel_ab.py --against c515c20 --levels 11

(c515c20: the stand-alone walks with level barriers from 512^2 nodes, BARRIER_LEVEL 9, in
work-groups of 64; this checkout's from 256^2 nodes in groups of 32, kernels/warp.h).
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import time

import numpy as np

from sample_bench import benchmark_materials, random_shading_points  # (benchmarks/ is on the path)

HERE = os.path.dirname(os.path.abspath(__file__))


def git_show(commit, path):
    return subprocess.run(["git", "-C", HERE, "show", f"{commit}:{path}"], capture_output=True, text=True,
                          check=True).stdout


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--against", required=True)
    ap.add_argument("--levels", type=int, default=10)
    ap.add_argument("--repeat", type=int, default=12)
    ap.add_argument("--env", default="data:rooitou_park_1k", help="a map file or data:NAME (wavlight.data)")
    from provenance import add_output_argument, provenance, write_result

    add_output_argument(ap, "kernel_ab")
    args = ap.parse_args()
    prov = provenance()

    import pyopencl as pcl

    from wavlight import cl
    from wavlight.strategies import product
    from wavlight.haar.tree import HaarTree
    from wavlight.envmap import Environment, read_image

    old_angles = None   # the angle table of a build whose product walk reads one
    if "*angles" in git_show(args.against, "kernels/product.cl"):
        old_py = git_show(args.against, "wavlight/product.py")
        ns = {"np": np}
        exec(old_py[old_py.index("def node_angles(levels: int)"):old_py.index("def node_angles_bytes")], ns)
        old_angles = ns["node_angles"]

    def old_program(name, **defines):
        def load(fname, seen):
            if fname in seen:
                return ""
            seen.add(fname)
            return re.sub(r'^\s*#include\s+"([^"]+)"\s*$', lambda m: load(m.group(1), seen),
                          git_show(args.against, f"kernels/{fname}"), flags=re.M)
        # as cl.program builds them (a revision without the flag ignores it)
        defines.setdefault("INLINE_BUILTINS", int(cl.inline_builtins(cl.runtime().device)))
        opts = [f"-D{k}={v}" for k, v in sorted(defines.items())] + [f"-DLANES={cl.LANES}"]
        return pcl.Program(cl.runtime().context, load(name, set())).build(options=opts)

    from wavlight.data import resolve

    env = Environment(read_image(resolve(args.env, kind="environment map")))
    q = cl.thread_queue()
    n = 1 << 21
    items = cl.items(n, cl.LANES)
    n4, wo4, u = random_shading_points(np.random.default_rng(1), n)
    rot = cl.to_device(env.map_from_world.astype(np.float32).ravel())
    u_buf, n_buf, wo_buf, mat_buf = cl.to_device(u), cl.to_device(n4), cl.to_device(wo4), cl.to_device(np.zeros(n, np.int32))
    uv_buf, pdf_buf = cl.empty(8 * n), cl.empty(4 * n)
    tree = HaarTree(env.luminance_square(args.levels))
    old_common = git_show(args.against, "kernels/common.h")
    trees = {"now": tree.buffer,   # the device layout of this checkout, and of --against:
             "before": tree.buffer if "TREE_ORIGIN" in old_common
             else cl.to_device(tree.device_nodes()) if "Morton" in old_common   # node 0 first
             else cl.to_device(tree.nodes())}   # row-major: sources without the Morton layout
    materials = benchmark_materials()
    # each version's work-groups as it launches its walks: its cl.WALK_WORK_GROUP, or
    # cl.WORK_GROUP (64) where it has none
    found = re.search(r"^WALK_WORK_GROUP = (\d+)", git_show(args.against, "wavlight/cl.py"), re.M)
    groups = {"before": int(found.group(1)) if found else 64, "now": cl.WALK_WORK_GROUP}
    runs, outputs = {}, {}
    for ver in ("before", "now"):
        prog = old_program if ver == "before" else cl.program
        angles_fn = old_angles if ver == "before" else None
        tree_buf = trees[ver]
        group = groups[ver]
        w = pcl.Kernel(prog("warp.cl", N_LEVELS=args.levels, BATCHED=0), "warp_sample")
        runs[("light", ver)] = lambda w=w, tree_buf=tree_buf, group=group: w(q, (items,), (group,), tree_buf,
                                                                           np.uint64(tree.stride),
                                             np.uint32(n), np.uint32(n), u_buf, np.uint32(2), uv_buf, pdf_buf)
        for name, (kind, param) in materials.items():
            kappa = product.lobe_kappa(kind, param)
            depth = product.product_levels(kappa, args.levels)
            shape = product.lobe_shape(kind, param)
            k = pcl.Kernel(prog("product.cl", N_LEVELS=args.levels, PRODUCT_LEVELS=depth, LOBE_SHAPES=1 << shape),
                           "product_sample_points")
            kargs = (tree_buf, rot, np.uint32(n), n_buf, wo_buf, mat_buf, cl.to_device(np.array([kappa], np.float32)),
                     cl.to_device(np.array([depth + 256 * shape], np.int32)), u_buf, np.uint32(2),
                     *([cl.to_device(angles_fn(depth))] if angles_fn else []), uv_buf, pdf_buf)
            runs[(name, ver)] = lambda k=k, kargs=kargs, group=group: k(q, (items,), (group,), *kargs)
    for key, f in runs.items():   # compile and warm up, keep the outputs
        f()
        q.finish()
        outputs[key] = (cl.read(uv_buf, (2, n), np.float32, q), cl.read(pdf_buf, (n,), np.float32, q))
    best = {}
    for _ in range(args.repeat):
        for key, f in runs.items():
            t = time.perf_counter()
            f()
            q.finish()
            best[key] = min(best.get(key, 9.0), time.perf_counter() - t)
    out = {"against": args.against, "levels": args.levels, "work_groups": groups, "count": n, "repeat": args.repeat,
           "device": cl.runtime().description,
           "M_samples_per_second": {name: {"before": round(n / best[(name, "before")] / 1e6, 1),
                                           "now": round(n / best[(name, "now")] / 1e6, 1),
                                           "identical": all(np.array_equal(a, b) for a, b in
                                                            zip(outputs[(name, "before")], outputs[(name, "now")]))}
                                    for name in ["light", *materials]}}
    print(json.dumps(out, indent=1))
    write_result(args.output, out, prov)


if __name__ == "__main__":
    main()
