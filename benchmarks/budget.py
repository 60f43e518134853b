"""The wavelet strategy's budget: resampling candidates M and slots S against mis.

For each of relmse.py's glossy scenes (the sphere alone and the bunny on its floor; with
--no-floor the bunny alone, whose shadows are its own), renders mis and wavelet with each
configuration MxS at --size, 16 spp, seeds 0..--seeds-1 in turn (one seed of every
configuration before the next seed, so that a slow stretch of this VM slows all alike), and
gives each configuration's relMSE against a mis reference at 1024 spp, its median time
(setup included) and its ratios to mis at equal spp and at equal time (relMSE x time): the
measurement behind strategies.AUTO_BUDGET (README, "Budget from the scene's shadows"). Each
scene's visibility variance (wavlight.occlusion) is reported beside them. Prints one JSON
object and writes it, with the run's provenance (benchmarks/provenance.py: commit, CPU,
OpenCL platform, command), to benchmarks/results/budget.json, or budget-no-floor.json with
--no-floor, unless -o names another ("-": none).

    python benchmarks/budget.py [--size 256] [--seeds 4] [--configs 8x2,16x2,32x2,8x4,16x4]
                                [--only ggx0.2,phong200] [--no-floor] [-o FILE]

The default command (all 18 glossy scenes, five configurations) takes about 40 minutes on
two shared cores; the figures in benchmarks/results/budget.json come from its two ggx 0.2
scenes under st_fagans (the sphere alone and the bunny on its floor) and three configurations:

    python benchmarks/budget.py --configs 8x2,16x2,8x4 --only ggx0.2/st_fagans_interior_1k
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

import wavlight
from wavlight.evaluation.metrics import relmse
from wavlight.raytrace import RayTracer
from wavlight import occlusion

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import needs  # noqa: E402
import relmse as relmse_bench  # noqa: E402  (its scenes)


def _without_floor(d: dict) -> dict:
    """The scene dict without its floor (the objects of relmse.FLOOR's shape left out)."""
    return {**d, "objects": [o for o in d["objects"] if o.get("shape") != "quad"]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--configs", default="8x2,16x2,32x2,8x4,16x4", help="candidates x slots, comma-separated")
    ap.add_argument("--only", default="", help="comma-separated substrings of scene names")
    ap.add_argument("--no-floor", action="store_true", help="the bunny without its floor (spheres left out)")
    from provenance import provenance, result_path, write_result

    ap.add_argument("-o", "--output", "--out", dest="output", default=None, metavar="FILE",
                    help="result file (default benchmarks/results/budget.json, budget-no-floor.json "
                         "with --no-floor; '-': none, stdout only)")
    args = ap.parse_args()
    if args.output is None:
        args.output = result_path("budget-no-floor" if args.no_floor else "budget")
    prov = provenance()
    needs.fetch("budget.py", *relmse_bench.MAPS, "bunny")
    configs = [tuple(int(x) for x in c.split("x")) for c in args.configs.split(",")]
    dicts = {k: d for k, d in relmse_bench.scenes() if "lambert" not in k}
    if args.no_floor:
        dicts = {k.replace("bunny", "bunny-alone"): _without_floor(v) for k, v in dicts.items()
                 if k.startswith("bunny")}
    if args.only:
        dicts = {k: v for k, v in dicts.items() if any(o in k for o in args.only.split(","))}
    runs = [("mis", {})] + [(f"{m}x{s}", dict(wavelet_candidates=m, wavelet_slots=s)) for m, s in configs]
    results = {"size": args.size, "spp": args.spp, "seeds": args.seeds, "ref_spp": args.ref_spp,
               "configs": [r[0] for r in runs[1:]], "scenes": {}}
    for name, d in dicts.items():
        scene = wavlight.load_dict(d)
        for label, kw in runs:   # compile each configuration's kernels before timing
            wavlight.render_full(scene, spp=1, width=8, height=8, strategy="wavelet" if kw else "mis", **kw)
        ref = wavlight.render_full(scene, spp=args.ref_spp, strategy="mis", seed=10_000,
                                   width=args.size, height=args.size)
        errs = {label: [] for label, _ in runs}
        secs = {label: [] for label, _ in runs}
        for seed in range(args.seeds):
            for label, kw in runs:
                r = wavlight.render_full(scene, spp=args.spp, seed=seed, width=args.size, height=args.size,
                                         strategy="wavelet" if kw else "mis", **kw)
                errs[label].append(relmse(r.image, ref.image, ref.stderr))
                secs[label].append(r.stats["setup_seconds"] + r.stats["render_seconds"])
        mis_e, mis_t = float(np.mean(errs["mis"])), float(np.median(secs["mis"]))
        row = {"visibility_variance": round(occlusion.visibility_variance(
            scene, RayTracer(scene.vertices, scene.faces), args.size, args.size), 4)}
        for label, _ in runs:
            e, t = float(np.mean(errs[label])), float(np.median(secs[label]))
            row[label] = {"relmse": e, "seconds": t, "equal_spp": e / mis_e, "equal_time": e * t / (mis_e * mis_t)}
        results["scenes"][name] = row
        print(f"{name}: " + " ".join(f"{lb} {row[lb]['equal_spp']:.3f}/{row[lb]['equal_time']:.3f}"
                                     for lb, _ in runs[1:]), file=sys.stderr, flush=True)
    print(json.dumps(results, indent=1))
    write_result(args.output, results, prov)


if __name__ == "__main__":
    main()
