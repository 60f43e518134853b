"""What a lighting bake's unbiased frame costs, pass by pass and part by part (Chen & Gao eq. 12's
estimator in wavlight.relight.converge): the bound of the viewer's converge (64 spp within 5 s at
256 x 256, benchmarks/viewer_converge.py) and of the frame's time against `wavelet`'s
(benchmarks/relight_converge_speed.py).

The bake: benchmarks/viewer_converge.py's (benchmarks/scenes/bunny_ggx.toml under
st_fagans_interior_1k, --size x --size, 16 camera samples; cached in /tmp/wavlight-viewer-converge).

- ``passes``: a ConvergeFrames as the viewer's converge thread holds it (prepared, the lighting
  warmed, ``--threads`` tile threads, the bilinear background), the viewer's schedule of passes
  (2, 2, 4, 8, 16, 32 spp, seeds 0, 1, ...) --rounds times: each pass's wall and CPU seconds (the
  process's, over all its threads, the OpenCL device's included) and the 1-minute load average;
  the CPU seconds per spp of the large passes and the fixed CPU cost of a pass (a least-squares
  line through CPU = fixed + per_spp x spp over every pass).
- ``first_frame``: a ConvergeFrames made anew and its first 16-spp frame of the map turned to
  120 degrees, on one tile thread (so that the parts add up to the wall time): setup (tracer,
  tables, kernels), the lighting's tables, the tiles' product trees and footprint spreads, and the
  passes' camera rays, embree's camera and shadow rays, the shading kernel (launch, uploads and
  the read that waits for it) and the rest (the host's sums), wall seconds each, --rounds times.

    python benchmarks/converge_passes.py [--size 256] [--rounds 2] [--threads 2]
        -> benchmarks/results/converge_passes.json
"""
from __future__ import annotations

import argparse
import collections
import os
import statistics
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from provenance import add_output_argument, provenance, write_result  # noqa: E402

SCHEDULE = (2, 2, 4, 8, 16, 32)
FIRST_SPP = 16
ROTATION = 120.0


def timed_parts(parts):
    """Wrap each (object, attribute, label) so that its calls' wall seconds add up in the counter
    returned (restored by the second value, a function)."""
    counter, saved = collections.Counter(), []
    for obj, name, label in parts:
        fn = getattr(obj, name)
        saved.append((obj, name, fn))

        def timed(*args, _fn=fn, _label=label, **kwargs):
            t0 = time.perf_counter()
            try:
                return _fn(*args, **kwargs)
            finally:
                counter[_label] += time.perf_counter() - t0
        setattr(obj, name, timed)

    def restore():
        for obj, name, fn in saved:
            setattr(obj, name, fn)
    return counter, restore


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=256, help="the bake's width and height")
    ap.add_argument("--rounds", type=int, default=2, help="schedules of passes, and first frames")
    ap.add_argument("--threads", type=int, default=2, help="tile threads of the passes (the viewer's ALONE_THREADS)")
    add_output_argument(ap, "converge_passes")
    args = ap.parse_args()
    import numpy as np

    import relight_common as rc
    import needs
    import viewer_converge

    needs.fetch("converge_passes", *rc.ASSETS)
    prov = provenance()
    from wavlight import camera
    from wavlight.raytrace import RayTracer
    from wavlight.relight import converge as cm
    from wavlight.relight import converge_kernels as ck

    base = rc.scene_dict(viewer_converge.SCENE)
    scene = rc.load(base)
    transfer, info = viewer_converge.baked(base, scene, args.size)
    result = {"scene": viewer_converge.SCENE, "size": args.size, "bake": info, "threads": args.threads,
              "schedule": list(SCHEDULE), "passes": [], "first_frame": []}

    frames = cm.ConvergeFrames(transfer, scene, threads=args.threads)
    frames.prepare(background="bilinear")
    frames.warm(None, ROTATION + 7.0, background="bilinear")
    frames.frame(None, ROTATION + 7.0, 1.0, 2, 99, background="bilinear")   # the kernels' first launches
    for r in range(args.rounds):
        for seed, spp in enumerate(SCHEDULE):
            load = os.getloadavg()[0]
            c0, t0 = time.process_time(), time.perf_counter()
            frames.frame(None, ROTATION + 7.0, 1.0, spp, 100 * r + seed, background="bilinear")
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            result["passes"].append({"round": r, "spp": spp, "wall_seconds": round(wall, 4),
                                     "cpu_seconds": round(cpu, 4), "load_average_1min": round(load, 2)})
            print(f"pass {spp:2d} spp: {wall:.3f} s wall, {cpu:.3f} CPU s (load {load:.1f})", file=sys.stderr,
                  flush=True)
    frames.close()
    spp = np.array([p["spp"] for p in result["passes"]], float)
    cpu = np.array([p["cpu_seconds"] for p in result["passes"]])
    per_spp, fixed = np.polyfit(spp, cpu, 1)
    large = [p["cpu_seconds"] / p["spp"] for p in result["passes"] if p["spp"] >= 16]
    result["passes_summary"] = {"cpu_seconds_per_spp_fit": round(float(per_spp), 4),
                                "cpu_seconds_per_pass_fit": round(float(fixed), 4),
                                "cpu_seconds_per_spp_large_passes_median": round(statistics.median(large), 4),
                                "cpu_seconds_schedule_median": round(statistics.median(
                                    [sum(p["cpu_seconds"] for p in result["passes"] if p["round"] == r)
                                     for r in range(args.rounds)]), 3)}

    parts = [(cm.ConvergeFrames, "lighting", "lighting tables"), (cm.ConvergeFrames, "tile_trees", "product trees"),
             (cm.ConvergeFrames, "spread", "footprint spreads"), (camera, "pass_rays", "camera rays (kernel)"),
             (RayTracer, "intersect_uv", "embree camera rays"), (RayTracer, "occluded", "embree shadow rays"),
             (ck.ShadeKernel, "__call__", "converge_shade (uploads, launch, read)")]
    for r in range(args.rounds):
        counter, restore = timed_parts(parts)
        try:
            load = os.getloadavg()[0]
            c0, t0 = time.process_time(), time.perf_counter()
            fresh = cm.ConvergeFrames(transfer, scene, threads=1)
            out = fresh.frame(None, ROTATION, 1.0, FIRST_SPP, r)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        finally:
            restore()
        row = {"round": r, "wall_seconds": round(wall, 4), "cpu_seconds": round(cpu, 4),
               "load_average_1min": round(load, 2), "setup": round(fresh.setup_seconds, 4),
               **{k: round(v, 4) for k, v in counter.items()}}
        row["rest"] = round(wall - fresh.setup_seconds - sum(counter.values()), 4)
        row["passes_render_seconds"] = out.stats["render_seconds"]
        fresh.close()
        result["first_frame"].append(row)
        print(f"first frame: {row}", file=sys.stderr, flush=True)
    write_result(args.output, result, prov)


if __name__ == "__main__":
    main()
