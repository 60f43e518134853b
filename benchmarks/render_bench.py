"""Renderer throughput: the bunny on a floor under a real 1k map, 512x512, 16 spp.

Prints one JSON object: per strategy (default mis, light, bsdf) the load, setup and render
seconds, rays/s and samples/s, best of --repeat runs (setup includes the light
tree and kernel compilation on a fresh process only for the first run; later
runs reuse the per-process program cache, which is what a batch user sees).
"embree_alone": embreex by itself on the same camera rays plus one shadow ray per hit,
the floor under the render time for that many rays. With --mitsuba, also runs
benchmarks/mitsuba_peer.py (Mitsuba 3, `direct` integrator, same scene, spp and
resolution) and reports the ratio. The same object, with the run's provenance
(benchmarks/provenance.py: commit, CPU, OpenCL platform, command), goes to the result
file, benchmarks/results/render_bench.json unless -o names another ("-": none).

    python benchmarks/render_bench.py [--scene benchmarks/scenes/bunny_ggx.toml] [--spp 16] [--repeat 2]
                                      [--strategies mis,light,bsdf] [--mitsuba] [-o FILE]

The figures in benchmarks/results/render_bench.json come from

    python benchmarks/render_bench.py --strategies mis,light,bsdf,wavelet,mis_comp --repeat 3 --mitsuba
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))


def embree_alone(scene, args):
    """embreex by itself on this scene's rays: the camera rays of the render (closest hit) and
    one shadow ray per hit towards a random upper-hemisphere direction (occlusion), on all
    cores as the renderer runs it. The floor under wavlight's render time for the same rays."""
    import numpy as np

    from wavlight.camera import camera_rays
    from wavlight.raytrace import RayTracer
    from wavlight.threads import default_threads

    tracer = RayTracer(scene.vertices, scene.faces, threads=default_threads(per_core=1))
    rng = np.random.default_rng(0)
    n = args.width * args.height * args.spp
    pix = np.arange(args.width * args.height)
    px = np.repeat(pix % args.width, args.spp).astype(np.float64)
    py = np.repeat(pix // args.width, args.spp).astype(np.float64)
    o, d = camera_rays(scene, px, py, rng.random((n, 2)), args.width, args.height)
    o = np.ascontiguousarray(o, np.float32)
    d = np.ascontiguousarray(d, np.float32)
    t0 = time.perf_counter()
    prim, t = tracer.intersect(o, d)
    t_hit = time.perf_counter() - t0
    hit = prim >= 0
    n_f, p, origin = tracer.surface(o[0], d[hit], t[hit], prim[hit])   # as the renderer's shadow rays
    w = rng.normal(size=(len(p), 3)).astype(np.float32)
    w = np.where((np.einsum("ij,ij->i", w, n_f) < 0)[:, None], -w, w)
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    t0 = time.perf_counter()
    tracer.occluded(origin, w)
    t_occ = time.perf_counter() - t0
    return {"camera_rays": n, "closest_hit_seconds": round(t_hit, 4),
            "closest_hit_rays_per_second": round(n / t_hit), "shadow_rays": int(len(p)),
            "occlusion_seconds": round(t_occ, 4), "occlusion_rays_per_second": round(len(p) / t_occ),
            "threads": tracer.threads}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default=os.path.join(HERE, "scenes", "bunny_ggx.toml"))
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--height", type=int, default=512)
    ap.add_argument("--strategies", default="mis,light,bsdf")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--mitsuba", action="store_true")
    from provenance import add_output_argument, provenance, write_result

    add_output_argument(ap, "render_bench")
    args = ap.parse_args()
    prov = provenance()

    import wavlight
    from wavlight import cl

    t0 = time.perf_counter()
    scene = wavlight.load_scene(args.scene)
    load = time.perf_counter() - t0
    out = {"scene": os.path.relpath(args.scene), "width": args.width, "height": args.height, "spp": args.spp,
           "triangles": int(len(scene.faces)), "device": cl.runtime().description,
           "load_seconds": round(load, 3), "cpus": os.cpu_count(), "wavlight": {}}
    for strategy in args.strategies.split(","):
        runs = []
        for _ in range(args.repeat):
            r = wavlight.render_full(scene, spp=args.spp, strategy=strategy, width=args.width, height=args.height)
            runs.append(r.stats)
        best = min(runs, key=lambda s: s["render_seconds"])
        out["wavlight"][strategy] = {k: best[k] for k in (
            "setup_seconds", "render_seconds", "rays", "rays_per_second", "samples_per_second")}
        out["wavlight"][strategy]["first_setup_seconds"] = runs[0]["setup_seconds"]
        for k in ("wavelet_candidates", "wavelet_slots", "visibility_variance"):   # the budget it chose
            if k in best:
                out["wavlight"][strategy][k] = best[k]
    import resource

    out["peak_rss_mib"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)  # the renders
    out["embree_alone"] = embree_alone(scene, args)
    if args.mitsuba:
        out["mitsuba"] = {}
        for strategy in args.strategies.split(","):
            if strategy not in ("mis", "light", "bsdf"):  # Mitsuba's direct integrator has these three
                continue
            cmd = [sys.executable, os.path.join(HERE, "mitsuba_peer.py"), args.scene, "--spp", str(args.spp),
                   "--width", str(args.width), "--height", str(args.height), "--strategy", strategy,
                   "-o", "-"]
            res = subprocess.run(cmd, capture_output=True, text=True)
            if res.returncode != 0:
                out["mitsuba"][strategy] = {"error": res.stderr.strip().splitlines()[-1:]}
                continue
            m = json.loads(res.stdout.strip().splitlines()[-1])
            out["mitsuba"][strategy] = m
            w = out["wavlight"][strategy]
            out["mitsuba"][strategy]["wavlight_over_mitsuba_render"] = round(
                w["render_seconds"] / m["render_seconds"], 3)
            out["mitsuba"][strategy]["wavlight_over_mitsuba_total"] = round(
                (w["render_seconds"] + w["setup_seconds"] + load)
                / (m["render_seconds"] + m.get("setup_seconds", 0) + m.get("jit_seconds", 0)), 3)
    print(json.dumps(out, indent=1))
    write_result(args.output, out, prov)


if __name__ == "__main__":
    main()
