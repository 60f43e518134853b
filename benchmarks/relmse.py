"""Error against a high-spp reference, at equal spp and at equal time, per strategy.

Scenes: a sphere and the bunny (on a floor), each in ggx alpha 0.05, ggx alpha 0.2
and phong n = 200, plus a lambert sphere (the case where product sampling has
little to gain), under rooitou_park_1k (tiny sun), st_fagans_interior_1k (many
small lights) and potsdamer_platz_1k (smooth overcast): fetched data (wavlight.data,
downloaded on first use, or read from WAVLIGHT_DATA). For every scene and
strategy (wavelet, mis, mis_comp, light, bsdf) and spp in --spp, --seeds renders are
made; the reference is `mis` at --ref-spp with its own seed. Ratios: wavelet over
mis, wavelet over mis_comp (mis with MIS compensation, the stronger baseline, as
pbrt-v4 renders by default) and mis_comp over mis, each at equal spp and at equal
time (the time of the denominator's strategy).

relMSE = mean over pixels and channels of ((x - ref)^2 - se_ref^2) / (ref^2 + 0.01)
(wavlight.evaluation.metrics.relmse): the reference's own variance (its squared standard error,
from the same render) is subtracted, so the figure estimates the error against the
true image. Equal
time: relMSE scales as 1/spp for these unbiased estimators, so the relMSE a
strategy reaches in the time mis takes at s spp (setup included) is
relMSE(s) * t_strategy(s) / t_mis(s), where t (the median over seeds, strategies
rendered in turn seed by seed) includes each render's setup (light tree, product
tables) but not the once-per-process kernel compilation.
--sampler stratified renders the compared images with stratified pixel samples.
--candidates M gives the wavelet strategy M resampling candidates and --slots S (2 or 4)
its directions (shadow rays) per sample, instead of what a render chooses from the scene's
shadows (strategies.AUTO_BUDGET: the lone spheres 16 and 2, the bunny on its floor 8 and 4).
--floor D estimates, per spp, the pixel-footprint floor: the relMSE left when every
pixel sample is shaded exactly (no direction noise), from an image whose pixel
samples average D mis estimates each: floor = (D relMSE_D - relMSE_mis) / (D - 1).
No direction sampler can go below it at that spp, so floor / relMSE_mis bounds the
wavelet / mis ratio from below. Prints one JSON object and writes it, with the run's
provenance (benchmarks/provenance.py: commit, CPU, OpenCL platform, command), to the result
file: benchmarks/results/relmse.json, or relmse-floor.json with --floor, unless -o names
another ("-": none; give other configurations their own -o).

    python benchmarks/relmse.py [--spp 4,16,64] [--seeds 3] [--size 128] [--ref-spp 1024]
                                [--sampler independent|stratified] [--floor D] [--candidates M] [--slots S]
                                [--only NAME] [-o FILE]

The figures in benchmarks/results/ come from

    python benchmarks/relmse.py --size 96 --seeds 4                        # relmse.json
    python benchmarks/relmse.py --size 96 --seeds 4 --spp 16 --floor 32    # relmse-floor.json

(the floor at 4, 16 and 64 spp, --floor 32 without --spp, takes about four times as long:
some 40 minutes on two shared cores).
"""
from __future__ import annotations

import argparse
import copy
import json
import os
import sys

import numpy as np

from wavlight.evaluation.metrics import relmse

HERE = os.path.dirname(os.path.abspath(__file__))
MAPS = ["rooitou_park_1k", "st_fagans_interior_1k", "potsdamer_platz_1k"]   # wavlight.data assets
MATERIALS = {"ggx0.05": {"type": "ggx", "roughness": 0.05}, "ggx0.2": {"type": "ggx", "roughness": 0.2},
             "phong200": {"type": "phong", "exponent": 200.0}, "lambert": {"type": "lambert"}}
STRATEGIES = ["wavelet", "mis", "mis_comp", "light", "bsdf"]

SPHERE = {"camera": {"eye": [0.0, 0.0, 4.0], "target": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0], "fov_y": 32.0},
          "objects": [{"shape": "sphere", "center": [0.0, 0.0, 0.0], "radius": 1.0, "material": "m"}]}
FLOOR = {"shape": "quad", "center": [0.0, 0.33, 0.0], "normal": [0.0, 1.0, 0.0], "size": 6.0, "material": "floor"}
BUNNY = {"camera": {"eye": [0.0, 1.4, 4.2], "target": [-0.15, 1.0, 0.0], "up": [0.0, 1.0, 0.0], "fov_y": 30.0},
         "objects": [{"mesh": "data:bunny", "scale": 10.0, "material": "m"}, FLOOR],
         "materials": {"floor": {"type": "lambert", "albedo": [0.5, 0.5, 0.5]}}}


def scenes():
    """(name, scene dict for wavlight.load_dict): the sphere alone under each map in each
    material, the bunny on its floor in each glossy one."""
    for geometry, body in (("sphere", SPHERE), ("bunny", BUNNY)):
        for mat, mat_body in MATERIALS.items():
            if geometry == "bunny" and mat == "lambert":
                continue
            for env in MAPS:
                d = copy.deepcopy(body)
                d["environment"] = {"file": f"data:{env}"}
                d.setdefault("materials", {})["m"] = {**mat_body, "albedo": [0.9, 0.9, 0.9]}
                yield f"{geometry}/{mat}/{env}", d


def floor_image(scene, spp, size, seed, directions, sampler):
    """The image at `spp` whose every pixel sample is shaded with the mean of `directions`
    independent `mis` estimates (same camera ray, same hit): its error is the pixel-footprint
    variance that no direction sampler can remove, plus the mis direction variance / directions."""
    from wavlight import integrator

    r = integrator._Renderer(scene, "mis", spp, size, size, seed, None, sampler_name=sampler)
    eye = scene.camera.eye

    def averaged(tile, first, x0, y0, w, h, k):
        d, prim, t, u, uv = r.camera_samples(tile, first, x0, y0, w, h, k)
        total = 0.0
        for j in range(directions):   # D, not samples: each a batched launch over the pass
            # the shading numbers of another seed (stratified per pixel as the compared renders')
            draws = u._replace(seed=(1 << 40) + directions * seed + j)
            total = total + r.visible_sum(r.shader.shade_rays(eye, d, prim, t, draws, uv))
        return total / directions

    r._samples = averaged
    image = np.zeros((size, size, 3))
    for (i, x0, y0, w, h) in integrator._tiles(size, size, spp):
        image[y0:y0 + h, x0:x0 + w] = r.tile(i, x0, y0, w, h)[0]
    return image


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--spp", default="4,16,64")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--only", default="", help="substring filter on scene names")
    ap.add_argument("--sampler", default="independent", choices=["independent", "stratified"],
                    help="pixel-sample uniforms of the compared renders (the reference: independent)")
    ap.add_argument("--floor", type=int, default=0, metavar="D",
                    help="also estimate the footprint floor with D directions per pixel sample")
    ap.add_argument("--candidates", type=int, default=None, metavar="M",
                    help="the wavelet strategy's resampling candidates (default: chosen from the scene)")
    ap.add_argument("--slots", type=int, default=None, choices=(2, 4),
                    help="the wavelet strategy's directions per sample (default: chosen from the scene)")
    sys.path.insert(0, HERE)
    import needs
    from provenance import provenance, result_path, write_result

    ap.add_argument("-o", "--output", "--out", dest="output", default=None, metavar="FILE",
                    help="result file (default benchmarks/results/relmse.json, relmse-floor.json "
                         "with --floor; '-': none, stdout only)")
    args = ap.parse_args()
    if args.output is None:
        args.output = result_path("relmse-floor" if args.floor > 1 else "relmse")
    needs.fetch("relmse", *MAPS, "bunny")

    prov = provenance()
    import wavlight

    spps = [int(s) for s in args.spp.split(",")]
    # Compile every strategy's kernels once (a batch user pays this once per process and
    # configuration, not per render); the light tree and tables are rebuilt by every render
    # and counted in its time.
    warm = wavlight.load_scene(os.path.join(HERE, "..", "scenes", "default.toml"))
    for strategy in STRATEGIES:
        wavlight.render_full(warm, spp=1, strategy=strategy, width=8, height=8)
    results = {"size": args.size, "ref_spp": args.ref_spp, "seeds": args.seeds, "spp": spps,
               "sampler": args.sampler, "floor_directions": args.floor,
               "wavelet_candidates": args.candidates, "wavelet_slots": args.slots, "scenes": {}}
    for name, d in scenes():
        if args.only and args.only not in name:
            continue
        scene = wavlight.load_dict(d)
        kw = dict(width=args.size, height=args.size)
        # the walk kernels are built per tree depth, product depth and lobe shapes: compile
        # this scene's variants before timing (once per process and configuration)
        for strategy in STRATEGIES:
            wavlight.render_full(scene, spp=1, strategy=strategy, width=8, height=8, sampler=args.sampler,
                                 wavelet_candidates=args.candidates, wavelet_slots=args.slots)
        ref = wavlight.render_full(scene, spp=args.ref_spp, strategy="mis", seed=10_000, **kw)
        row = {"reference_seconds": ref.stats["render_seconds"], **{s: {} for s in STRATEGIES}}
        for spp in spps:
            # strategies interleaved seed by seed, and the median time: a burst of load on this
            # shared machine then slows every strategy alike instead of one
            errs, secs = {s: [] for s in STRATEGIES}, {s: [] for s in STRATEGIES}
            for seed in range(args.seeds):
                for strategy in STRATEGIES:
                    r = wavlight.render_full(scene, spp=spp, strategy=strategy, seed=seed, sampler=args.sampler,
                                             wavelet_candidates=args.candidates, wavelet_slots=args.slots, **kw)
                    errs[strategy].append(relmse(r.image, ref.image, ref.stderr))
                    if strategy == "wavelet":   # what the render chose from the scene's shadows
                        row["wavelet_budget"] = {k: r.stats[k] for k in (
                            "wavelet_candidates", "wavelet_slots", "visibility_variance")}
                    secs[strategy].append(r.stats["setup_seconds"] + r.stats["render_seconds"])
            for strategy in STRATEGIES:
                e = errs[strategy]
                row[strategy][str(spp)] = {"relmse": float(np.mean(e)),
                                           "relmse_sd": float(np.std(e, ddof=1)) if len(e) > 1 else None,
                                           "seconds": float(np.median(secs[strategy]))}
        for spp in spps:
            s = str(spp)
            mis = row["mis"][s]
            for strategy in STRATEGIES:
                cell = row[strategy][s]
                cell["equal_time_relmse"] = cell["relmse"] * cell["seconds"] / mis["seconds"]
            for num, den in (("wavelet", "mis"), ("wavelet", "mis_comp"), ("mis_comp", "mis")):
                a, b = row[num][s], row[den][s]
                row.setdefault(f"{num}_over_{den}", {})[s] = {
                    "equal_spp": a["relmse"] / b["relmse"],
                    "equal_time": a["relmse"] * a["seconds"] / b["seconds"] / b["relmse"]}
            if args.floor > 1:
                # relMSE(D) = floor + dir / D and relMSE(mis) = floor + dir give the floor; one
                # floor image per seed (the seeds of the compared renders), their spread reported
                d = args.floor
                e_d = [relmse(floor_image(scene, spp, args.size, seed, d, args.sampler), ref.image, ref.stderr)
                       for seed in range(args.seeds)]
                fl = [(d * e - mis["relmse"]) / (d - 1) for e in e_d]
                mean = max(0.0, float(np.mean(fl)))
                row.setdefault("footprint_floor", {})[s] = {
                    "relmse": mean, "relmse_sd": float(np.std(fl, ddof=1)) if len(fl) > 1 else None,
                    "over_mis": mean / mis["relmse"]}
        results["scenes"][name] = row
        print(f"{name}: " + " ".join(f"{k}={v['equal_spp']:.3f}/{v['equal_time']:.3f}"
                                     for k, v in row["wavelet_over_mis"].items())
              + " | over mis_comp " + " ".join(f"{k}={v['equal_spp']:.3f}/{v['equal_time']:.3f}"
                                               for k, v in row["wavelet_over_mis_comp"].items()),
              file=sys.stderr, flush=True)
    print(json.dumps(results, indent=1))
    write_result(args.output, results, prov)


if __name__ == "__main__":
    main()
