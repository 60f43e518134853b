"""The bake's speed: is it bound by its shadow rays? The bunny of benchmarks/scenes/bunny_ggx.toml (under
rooitou_park_1k) at 512 x 512, 64 x 64 texels (levels 6), K = 256, priority "area" (given, so no
pilot bake runs), 16 camera samples.

1. The bake (wavlight.bake, its default threads): seconds, shadow rays, rays/s (the bake's own
   figure: rays / (seconds - pilot seconds)). The file goes to the cache in /tmp/relight-bench/
   (benchmarks/relight_frame.py reads it).
2. embree's own occlusion rate on the same rays: for --sample-tiles blocks spread evenly over the
   image, the bake's camera samples and texel rays (wavlight.relight.bake.camera_samples and
   texel_rays, with the bake's seeds and points per texel), then RayTracer.occluded alone on
   exactly those origins and directions, (a) as the bake runs it: a pool of 2 x cores threads,
   one block's rays per call on a one-thread tracer, and (b) one call on a tracer with
   os.cpu_count() threads; best of --repeat. The same sample blocks are also baked whole
   (bake_block, the same pool) for the bake's rate on those very rays. Ratios: bake rays/s over
   the faster of (a) and (b) (target >= 0.8), for the whole bake and for the sample.
3. The stages of the sample blocks one after another on one thread (camera samples, texel rays,
   occlusion, Haar transform, compression with quantization): where the time that is not rays
   goes (the OpenCL kernels use every core even here; the Haar transform is numpy's, as in the
   bake's blocks).
4. The pilot bakes alone (choose_model with spp, levels, terms and priority left to it), timed apart.

Timing: waits for the 1-minute load average to fall below --wait-load (default 1.0, polling
every 60 s for --wait-minutes, default 40), then runs anyway; the load is in the provenance.

    python benchmarks/relight_bake.py [--size 512] [--levels 6] [--terms 256] [--priority area] [--spp 16]
        [--sample-tiles 16] [--repeat 3] [--reuse] [--no-pilot] [--wait-load 1.0] [--wait-minutes 40]
        [-o FILE]

The figures in benchmarks/results/relight_bake.json come from

    python benchmarks/relight_bake.py --wait-minutes 10
"""
from __future__ import annotations

import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import relight_common as rc  # noqa: E402

SCENE = rc.BAKE_SCENE


def main():
    ap = rc.parser(__doc__)
    rc.add_bake_arguments(ap)
    ap.add_argument("--terms", type=int, default=256, help="the bake's default terms K")
    ap.add_argument("--priority", default="area", help="the terms' priority")
    ap.add_argument("--sample-tiles", type=int, default=16, help="blocks of the embree comparison and the stages")
    ap.add_argument("--repeat", type=int, default=3, help="rounds of the embree comparison (the best is kept)")
    ap.add_argument("--reuse", action="store_true", help="take the bake from the cache if it is there (its "
                                                         "seconds are then those of the run that made it)")
    ap.add_argument("--no-pilot", action="store_true", help="leave out the pilot bake alone (4.)")
    args = rc.parse(ap, "relight_bake", 40)
    started = rc.begin(args)
    from wavlight import haar
    from wavlight.relight import bake as B
    from wavlight.relight import lighting, store
    from wavlight.raytrace import RayTracer
    from wavlight.threads import default_threads

    d = rc.scene_dict(SCENE)
    scene = rc.load(d)
    threads = default_threads()   # the bake's pool
    # 1. the bake
    load_bake = rc.load_average()
    transfer, info = rc.cached_bake(d, args.size, args.spp, levels=args.levels, terms=args.terms,
                                    priority=args.priority, reuse=args.reuse)
    m = transfer.measured
    bake = {"seconds": m["bake_seconds"], "pilot_seconds": m["pilot_seconds"], "rays": m["rays"],
            "rays_per_second": m["rays_per_second"], "wall_seconds": info.get("wall_seconds"),
            "file_bytes": transfer.file_bytes, "entries": transfer.entries, "entries_full": m.get("entries_full"),
            "compression_error": m.get("compression_error"), "n_levels": transfer.n_levels, "terms": transfer.terms,
            "priority": transfer.priority, "cached": info["cached"], "load_average": info.get("load_average", load_bake),
            "load_average_end": info.get("load_average_end"), "threads": threads, "path": info["path"]}
    print(f"bake: {bake['seconds']} s, {bake['rays']} rays, {bake['rays_per_second'] / 1e6:.3f} M rays/s"
          f"{' (cached)' if info['cached'] else ''}", file=sys.stderr, flush=True)
    n = transfer.n_levels
    # 2. the same rays, embree alone
    tiles, _ = B._tiles(args.size, args.size)
    pick = np.unique(np.linspace(0, len(tiles) - 1, args.sample_tiles).round().astype(int))
    sample = [tiles[i] for i in pick]
    worker = B._Worker(scene)
    env = scene.environment
    held = lighting.coefficients(lighting.project(env, n, env.rotate_y + B.HELD_OUT_DEGREES)).reshape(3, -1).T
    settings = B.Settings(args.size, args.size, args.spp, n, 0.02 / np.sqrt(3.0), 8, held * float(4 ** n), 0,
                          points=B.texel_points(scene, n))   # as wavlight.bake makes them
    B.bake_block(worker, settings, sample[0])   # untimed: the kernels compiled in this process (a cached bake)
    rays, stages = [], {"camera_samples": 0.0, "texel_rays": 0.0, "occluded": 0.0, "haar": 0.0, "compress": 0.0}
    for tile in sample:   # one thread, one after another: the stages' times
        block_id, x0, y0, w, h = tile
        t0 = time.perf_counter()
        ps = B.camera_samples(scene, worker.tracer, args.size, args.size, x0, y0, w, h, args.spp, 0, block_id)
        t1 = time.perf_counter()
        dirs, weight, picked = B.texel_rays(ps, n, 0, block_id, worker.kinds, points=settings.points)
        t2 = time.perf_counter()
        live = np.flatnonzero(weight > 0)
        o = np.ascontiguousarray(np.take(ps.origin, picked[live].astype(np.int64), axis=0))
        dd = np.ascontiguousarray(np.take(dirs, live, axis=0))
        t3 = time.perf_counter()
        blocked = worker.tracer.occluded(o, dd)
        t4 = time.perf_counter()
        out = np.zeros(len(weight), np.float32)
        out[live] = np.where(blocked, 0.0, weight[live])
        coeffs = haar.forward(out.reshape(-1, 1 << n, 1 << n))   # numpy's, as bake_block
        coeffs = B._padded(np.asarray(coeffs, np.float32).reshape(w * h, 4 ** n), w, h)
        t5 = time.perf_counter()
        store.compress_block(coeffs, settings.held_out, settings.tolerance, 8, np.random.default_rng([0, block_id]))
        t6 = time.perf_counter()
        for k, v in zip(stages, (t1 - t0, t2 - t1, t4 - t3, t5 - t4, t6 - t5)):
            stages[k] += v
        rays.append((o, dd))
    sample_rays = int(sum(len(o) for o, _ in rays))
    one = RayTracer(scene.vertices, scene.faces, threads=1)
    many = RayTracer(scene.vertices, scene.faces, threads=default_threads(per_core=1))
    allo = np.concatenate([o for o, _ in rays])
    alld = np.concatenate([x for _, x in rays])
    pool_s, single_s, bake_s = [], [], []
    with ThreadPoolExecutor(threads) as pool:
        for _ in range(args.repeat):   # interleaved: a burst of load slows each alike
            t0 = time.perf_counter()
            list(pool.map(lambda r: one.occluded(*r), rays))
            pool_s.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            many.occluded(allo, alld)
            single_s.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            res = list(pool.map(lambda tile: B.bake_block(worker, settings, tile), sample))
            bake_s.append(time.perf_counter() - t0)
    sample_bake_rays = int(sum(r["rays"] for r in res))
    embree_pool = sample_rays / min(pool_s)
    embree_single = sample_rays / min(single_s)
    embree = max(embree_pool, embree_single)
    sample_bake = sample_bake_rays / min(bake_s)
    stage_total = sum(stages.values())
    embree_part = {"sample_tiles": [int(t[0]) for t in sample], "rays": sample_rays,
                   "pool_threads": threads, "pool_seconds": [round(x, 4) for x in pool_s],
                   "pool_rays_per_second": round(embree_pool), "tracer_threads": many.threads,
                   "single_call_seconds": [round(x, 4) for x in single_s],
                   "single_call_rays_per_second": round(embree_single),
                   "rays_per_second": round(embree), "sample_bake_rays": sample_bake_rays,
                   "sample_bake_seconds": [round(x, 4) for x in bake_s],
                   "sample_bake_rays_per_second": round(sample_bake)}
    ratio = {"bake_over_embree": bake["rays_per_second"] / embree,
             "sample_bake_over_embree": sample_bake / embree, "target": 0.8}
    ratio["met"] = bool(ratio["bake_over_embree"] >= 0.8)
    stage_part = {k: round(v, 4) for k, v in stages.items()}
    stage_part["share"] = {k: round(v / stage_total, 4) for k, v in stages.items()}
    stage_part["rays_per_second_of_occluded_one_thread"] = round(sample_rays / stages["occluded"])
    # 4. the pilot
    pilot = None
    if not args.no_pilot:
        t0 = time.perf_counter()
        model = B.choose_model(scene, 0.02, None, 0, width=args.size, height=args.size)
        pilot = {"seconds": round(time.perf_counter() - t0, 3), "spp": model["spp"], "n_levels": model["n_levels"],
                 "terms": model["terms"],
                 "priority": model["priority"], "pilot": model["pilot"]}
    size_target = {"seconds": bake["seconds"], "target_seconds": 180, "met": bool(bake["seconds"] <= 180)}
    print(f"bake {args.size}x{args.size}, {1 << n}x{1 << n} texels, {args.spp} spp: {bake['seconds']:.1f} s "
          f"(pilot {bake['pilot_seconds']:.2f} s), {bake['rays']:,} rays, {bake['rays_per_second'] / 1e6:.3f} M rays/s; "
          f"{bake['file_bytes'] / 1e6:.1f} MB; target <= 180 s: {'met' if size_target['met'] else 'NOT met'}")
    print(f"embree alone on {sample_rays:,} rays of {len(sample)} blocks: pool of {threads} {embree_pool / 1e6:.3f}, "
          f"one call with {many.threads} threads {embree_single / 1e6:.3f} M rays/s; the bake on the same blocks "
          f"{sample_bake / 1e6:.3f} M rays/s")
    print(f"ratio bake / embree: whole bake {ratio['bake_over_embree']:.3f}, sample {ratio['sample_bake_over_embree']:.3f} "
          f"(target >= 0.8: {'met' if ratio['met'] else 'NOT met'})")
    print("stages of the sample on one thread: " + ", ".join(f"{k} {v:.2f} s ({100 * stage_part['share'][k]:.0f}%)"
                                                              for k, v in stages.items()))
    if pilot:
        print(f"pilot bake alone: {pilot['seconds']:.2f} s -> n = {pilot['n_levels']}, K = {pilot['terms']}, "
              f"{pilot['priority']}")
    rc.finish(args.output, {"scene": SCENE, "size": args.size, "spp": args.spp, "levels": args.levels,
                            "terms": args.terms, "priority": args.priority, "texel_points": settings.points,
                            "bake": bake, "embree": embree_part, "ratio": ratio, "stages_one_thread": stage_part,
                            "pilot": pilot, "target_seconds": size_target}, started)


if __name__ == "__main__":
    main()
