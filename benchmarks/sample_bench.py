"""Sample generation alone (no ray tracing): product samples/s and light samples/s.

For each light-tree resolution (the environment resampled to 2^n x 2^n leaves) and
each material lobe, time the `product_sample_points` kernel (kernels/product.cl:
the top-down product warp of kernels/product.h) and the light tree's `warp_sample`
on 2^21 random shading points, and the eq. 25 product pyramids of
wavlight.haar.ProductPyramids (dense per-point trees, the alternative design) in
trees/s. Prints one JSON object. Timings are kernel time after a warm-up, best of 3,
including host<->device copies of inputs and outputs ("with_copies") and without.

    python benchmarks/sample_bench.py [--env ../shared/data/envmaps/rooitou_park_1k.hdr]
"""
from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def best_of(fn, repeat=3):
    fn()
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--env", default=os.path.join(HERE, "..", "..", "shared", "data", "envmaps",
                                                  "rooitou_park_1k.hdr"))
    ap.add_argument("--count", type=int, default=1 << 21)
    args = ap.parse_args()

    from wavlight import bsdfs, cl, product
    from wavlight.distributions import HaarTree
    from wavlight.envmap import Environment, read_image

    env = Environment(read_image(args.env), name=args.env)
    rt = cl.runtime()
    q = cl.thread_queue()
    n = args.count
    # work-items: each walks cl.WALK_K samples; work-groups of 64 as the renderer launches them
    items = -(-n // (cl.WALK_K * 64)) * 64
    rng = np.random.default_rng(1)
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    wo = rng.normal(size=(n, 3))
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    wo *= np.sign(np.einsum("ij,ij->i", wo, nrm))[:, None]
    axis = 2 * np.einsum("ij,ij->i", wo, nrm)[:, None] * nrm - wo
    u = rng.random((n, 2), dtype=np.float32)
    texels = np.zeros((env.height * env.width, 4), np.float32)
    texels[:, :3] = env.pixels.reshape(-1, 3)
    texels_buf = cl.to_device(texels)
    rot = cl.to_device(env.map_from_world.astype(np.float32).ravel())
    u_buf = cl.to_device(u)
    uv_buf, pdf_buf = cl.empty(8 * n), cl.empty(4 * n)
    prog = cl.program("product.cl")
    out = {"env": os.path.basename(args.env), "count": n, "device": rt.description, "levels": {}}
    materials = {"lambert": (bsdfs.LAMBERT, 0.0), "phong200": (bsdfs.PHONG, 200.0),
                 "ggx0.2": (bsdfs.GGX, 0.2), "ggx0.05": (bsdfs.GGX, 0.05)}
    for n_levels in (6, 8, 10, 11):
        tree = HaarTree(env.luminance_square(n_levels))
        row = {"tree_bytes": tree.stride * 4}
        warp = cl.kernel(cl.program("warp.cl"), "warp_sample")

        def light():
            warp(q, (items,), (64,), tree.buffer, np.uint64(tree.stride), np.int32(n_levels), np.uint32(n),
                 np.uint32(n), u_buf, uv_buf, pdf_buf)
            q.finish()
        row["light_samples_per_second"] = round(n / best_of(light))
        for name, (kind, param) in materials.items():
            kappa = product.lobe_kappa(kind, param)
            depth = product.product_levels(kappa, n_levels)
            ak = np.concatenate([axis if kind != bsdfs.LAMBERT else nrm, np.full((n, 1), kappa)], 1)
            nl = np.concatenate([nrm, np.full((n, 1), depth + 256 * product.lobe_shape(kind, param))], 1)
            ak_buf, nl_buf = cl.to_device(ak.astype(np.float32)), cl.to_device(nl.astype(np.float32))
            dirs = cl.to_device(product.node_directions(depth))
            knl = cl.kernel(prog, "product_sample_points")

            def run():
                knl(q, (items,), (64,), tree.buffer, np.int32(n_levels), texels_buf, np.int32(env.width),
                    np.int32(env.height), rot, np.uint32(n), ak_buf, nl_buf, u_buf, dirs, uv_buf, pdf_buf)
                q.finish()

            def run_with_copies():
                a, b, c = cl.to_device(ak.astype(np.float32)), cl.to_device(nl.astype(np.float32)), cl.to_device(u)
                knl(q, (items,), (64,), tree.buffer, np.int32(n_levels), texels_buf, np.int32(env.width),
                    np.int32(env.height), rot, np.uint32(n), a, b, c, dirs, uv_buf, pdf_buf)
                cl.read(uv_buf, (n, 2), np.float32, q)
                cl.read(pdf_buf, (n,), np.float32, q)
            row[name] = {"product_depth": depth,
                         "product_samples_per_second": round(n / best_of(run)),
                         "with_copies": round(n / best_of(run_with_copies))}
        out["levels"][str(n_levels)] = row
    # The alternative design: dense per-point product pyramids by eq. 25 (wavlight.haar).
    try:
        from wavlight import haar
        pyr = {}
        for m in (4, 5, 6):
            g = haar.forward(env.luminance_square(m).astype(np.float32))
            pp = haar.ProductPyramids(g, m)
            trees = 4096
            h = rng.random((trees, 1 << m, 1 << m)).astype(np.float32)
            pyr[str(m)] = {"trees_per_second": round(trees / best_of(lambda: pp(h)))}
        out["eq25_dense_product_pyramids"] = pyr
    except Exception as e:  # report, do not hide
        out["eq25_dense_product_pyramids"] = {"error": f"{type(e).__name__}: {e}"}
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
