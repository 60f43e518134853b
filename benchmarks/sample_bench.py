"""Sample generation alone (no ray tracing): product samples/s and light samples/s.

For each light-tree resolution (the environment resampled to 2^n x 2^n leaves) and
each material lobe, time the `product_sample_points` kernel (kernels/product.cl:
the top-down product warp of kernels/product.h, which the renderer's wavelet
strategy runs inline in its shade kernel) and the light tree's `warp_sample` on 2^21
random shading points (random normals and view directions: the least coherent case), and the eq. 25 product pyramids of
wavlight.haar.ProductPyramids (dense per-point trees, the alternative design) in
trees/s, built on the device (and "with_copies_to_host": through ProductPyramids.__call__,
which uploads H and returns the trees row-major on the host). "without_lookahead": the product walk built without its look-ahead
importances at the coarse levels (kernels/product.h), for comparison;
"without_barriers": the walk depth-first, without the stand-alone kernels' level
barriers (kernels/warp.h), as the renderer's shade kernel runs it inline. "per_point_16"
(and without barriers): 16 consecutive samples share each random shading point, as a
pixel's samples do in the renderer (its eight-lane vectors then walk one lobe). Prints
one JSON object. Timings are kernel time after a warm-up, the best of 3 rounds in which
every figure is timed once in turn (a slow stretch of this shared VM then costs one round
of many figures, not every repeat of a few), including host<->device copies of inputs
and outputs ("with_copies") and without. The same object, with the run's provenance
(benchmarks/provenance.py: commit, CPU, OpenCL platform, command), goes to the result file,
benchmarks/results/sample_bench.json unless -o names another ("-": none). The figures there
come from the default command:

    python benchmarks/sample_bench.py [--env data:rooitou_park_1k] [-o FILE]
"""
from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np



def random_shading_points(rng, n):
    """n shading points with random normals and view directions (the least coherent case):
    normals and directions to the viewer as float4 rows (the product kernel's layout), and
    one uniform pair each; float32."""
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    wo = rng.normal(size=(n, 3))
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    wo *= np.sign(np.einsum("ij,ij->i", wo, nrm))[:, None]
    n4, wo4 = np.zeros((n, 4), np.float32), np.zeros((n, 4), np.float32)
    n4[:, :3], wo4[:, :3] = nrm, wo
    return n4, wo4, rng.random((n, 2), dtype=np.float32)


def benchmark_materials():
    """The lobes the sample benchmarks time: name -> (kind, parameter)."""
    from wavlight import bsdfs

    return {"lambert": (bsdfs.LAMBERT, 0.0), "phong200": (bsdfs.PHONG, 200.0),
            "ggx0.2": (bsdfs.GGX, 0.2), "ggx0.05": (bsdfs.GGX, 0.05)}


#: samples per shading point in the coherent runs: a pixel's samples at 16 spp (Clarberg et
#: al. 2005 draw 100 per point; the random runs draw one)
PER_POINT = 16


class Rounds:
    """Timings in interleaved rounds: ``rate(fn, count)`` registers a run (and warms it up:
    compilation, first touch) and returns a placeholder; ``run()`` times every function
    registered since the last call once per round, ``repeat`` rounds (the benchmark calls
    it once per light tree, so that a tree stays as warm in the caches as the renderer
    keeps it); ``fill(out)`` puts count / best time in place of each placeholder. A slow
    stretch of this shared VM (seconds long) then costs one round of many figures instead
    of every repeat of the few timed during it."""

    def __init__(self, repeat=3):
        self.repeat, self.fns, self.best = repeat, [], []

    def rate(self, fn, count):
        fn()
        self.fns.append(fn)
        return ("rate", len(self.fns) - 1, count)

    def run(self):
        first = len(self.best)
        self.best += [np.inf] * (len(self.fns) - first)
        for _ in range(self.repeat):
            for i in range(first, len(self.fns)):
                t = time.perf_counter()
                self.fns[i]()
                self.best[i] = min(self.best[i], time.perf_counter() - t)

    def fill(self, out):
        self.run()

        def rates(x):
            if isinstance(x, dict):
                return {k: rates(v) for k, v in x.items()}
            if isinstance(x, tuple) and len(x) == 3 and x[0] == "rate":
                return round(x[2] / self.best[x[1]])
            return x
        return rates(out)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--env", default="data:rooitou_park_1k", help="a map file or data:NAME (wavlight.data)")
    ap.add_argument("--count", type=int, default=1 << 21)
    from provenance import add_output_argument, provenance, write_result

    add_output_argument(ap, "sample_bench")
    args = ap.parse_args()
    prov = provenance()

    from wavlight import cl
    from wavlight.strategies import product
    from wavlight.haar.tree import HaarTree
    from wavlight.envmap import Environment, read_image

    from wavlight.data import resolve

    env = Environment(read_image(resolve(args.env, kind="environment map")), name=args.env)
    rt = cl.runtime()
    q = cl.thread_queue()
    n = args.count
    # eight points per work-item (kernels/simd.h); work-groups of cl.WALK_WORK_GROUP for the kernels
    # with level barriers (HaarTree.sample's), of cl.WORK_GROUP for the walks without (the renderer's)
    items = cl.items(n, cl.LANES)
    rng = np.random.default_rng(1)
    n4, wo4, u = random_shading_points(rng, n)
    material = np.zeros(n, np.int32)   # one material per run: the table has one row
    rot = cl.to_device(env.map_from_world.astype(np.float32).ravel())
    u_buf, n_buf, wo_buf, mat_buf = cl.to_device(u), cl.to_device(n4), cl.to_device(wo4), cl.to_device(material)
    # the renderer's pattern: consecutive samples share a shading point (a pixel's samples,
    # PER_POINT of them), each with its own u
    nc4, woc4, _ = random_shading_points(rng, -(-n // PER_POINT))
    nc_buf = cl.to_device(np.ascontiguousarray(np.repeat(nc4, PER_POINT, 0)[:n]))
    woc_buf = cl.to_device(np.ascontiguousarray(np.repeat(woc4, PER_POINT, 0)[:n]))
    uv_buf, pdf_buf = cl.empty(8 * n), cl.empty(4 * n)
    out = {"env": os.path.basename(args.env), "count": n, "device": rt.description,
           "shading_points": "random normals and view directions, one sample each", "levels": {}}
    materials = benchmark_materials()
    rounds = Rounds()
    for n_levels in (6, 8, 10, 11):
        tree = HaarTree(env.luminance_square(n_levels))
        row = {"tree_bytes": tree.stride * 4}
        warp = cl.kernel(cl.program("warp.cl", N_LEVELS=n_levels, BATCHED=0), "warp_sample")

        def light(warp=warp, tree=tree):
            warp(q, (cl.items(n, cl.LANES),), (cl.WALK_WORK_GROUP,), tree.buffer, np.uint64(tree.stride), np.uint32(n), np.uint32(n),
                 u_buf, np.uint32(2), uv_buf, pdf_buf)
            q.finish()
        row["light_samples_per_second"] = rounds.rate(light, n)
        for name, (kind, param) in materials.items():
            kappa = product.lobe_kappa(kind, param)
            depth = product.product_levels(kappa, n_levels)
            shape = product.lobe_shape(kind, param)
            kappa_buf = cl.to_device(np.array([kappa], np.float32))
            code_buf = cl.to_device(np.array([depth + 256 * shape], np.int32))
            prog = cl.program("product.cl", N_LEVELS=n_levels, PRODUCT_LEVELS=depth, LOBE_SHAPES=1 << shape)
            knl = cl.kernel(prog, "product_sample_points")

            def launch(nb, wb, ub, knl=knl, group=cl.WALK_WORK_GROUP, tree=tree, kappa_buf=kappa_buf,
                       code_buf=code_buf):
                knl(q, (items,), (group,), tree.buffer, rot, np.uint32(n), nb, wb, mat_buf, kappa_buf,
                    code_buf, ub, np.uint32(2), uv_buf, pdf_buf)

            def timed(*a, launch=launch, **k):
                return lambda: (launch(*a, **k), q.finish())

            def run_with_copies(launch=launch):
                launch(cl.to_device(n4), cl.to_device(wo4), cl.to_device(u))
                cl.read(uv_buf, (2, n), np.float32, q)
                cl.read(pdf_buf, (n,), np.float32, q)
            row[name] = {"product_depth": depth,
                         "product_samples_per_second": rounds.rate(timed(n_buf, wo_buf, u_buf), n),
                         "with_copies": rounds.rate(run_with_copies, n)}
            # the same walk without the look-ahead importances (kernels/product.h)
            plain = cl.kernel(cl.program("product.cl", N_LEVELS=n_levels, PRODUCT_LEVELS=depth,
                                         LOBE_SHAPES=1 << shape, LOOKAHEAD_LEVELS=0), "product_sample_points")
            row[name]["without_lookahead"] = rounds.rate(timed(n_buf, wo_buf, u_buf, plain), n)
            # the same walk depth-first, without the level barriers (kernels/warp.h): as the
            # renderer's shade kernel runs it
            inline = cl.kernel(cl.program("product.cl", N_LEVELS=n_levels, PRODUCT_LEVELS=depth,
                                          LOBE_SHAPES=1 << shape, WALK_BARRIERS=0), "product_sample_points")
            row[name]["without_barriers"] = rounds.rate(timed(n_buf, wo_buf, u_buf, inline, cl.WORK_GROUP), n)
            # PER_POINT samples per shading point in a row, with and without the barriers
            row[name][f"per_point_{PER_POINT}"] = rounds.rate(timed(nc_buf, woc_buf, u_buf), n)
            row[name][f"per_point_{PER_POINT}_without_barriers"] = rounds.rate(
                timed(nc_buf, woc_buf, u_buf, inline, cl.WORK_GROUP), n)
        out["levels"][str(n_levels)] = row
        rounds.run()
    # The alternative design: dense per-point product pyramids by eq. 25 (wavlight.haar).
    try:
        from wavlight import haar
        pyr = {}
        for m in (4, 5, 6, 7, 8):   # P = 7 is the phong 200 / ggx 0.05 depth; 8 the device's largest
            g = haar.forward(env.luminance_square(m).astype(np.float32))
            pp = haar.ProductPyramids(g, m)
            trees = 4096 >> max(0, 2 * (m - 6))   # about 90 MB of trees at P >= 6
            h = rng.random((trees, 1 << m, 1 << m)).astype(np.float32)
            h_buf, out_buf = cl.to_device(h), cl.empty(4 * trees * pp.stride)

            def on_device(pp=pp, h_buf=h_buf, out_buf=out_buf, trees=trees):   # bound now: timed later
                pp.enqueue(q, h_buf, trees, out_buf)
                q.finish()
            # on the device, ready for the warp (as a renderer would use them); and through
            # __call__: upload, kernel, read-back and conversion to the host's row-major layout
            pyr[str(m)] = {"trees_per_second": rounds.rate(on_device, trees),
                           "with_copies_to_host": rounds.rate(lambda pp=pp, h=h: pp(h), trees)}
        out["eq25_dense_product_pyramids"] = pyr
    except Exception as e:  # report, do not hide
        out["eq25_dense_product_pyramids"] = {"error": f"{type(e).__name__}: {e}"}
    out = rounds.fill(out)
    print(json.dumps(out, indent=1))
    write_result(args.output, out, prov)


if __name__ == "__main__":
    main()
