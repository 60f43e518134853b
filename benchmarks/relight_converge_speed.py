"""The lighting bake's unbiased frame against rendering the changed scene from scratch, in time
and in error (Chen & Gao sec. 2, eq. 6-8 and 12: once T1 is baked, sampling T1 x T2 puts the
visibility inside the sampled product, so a frame of a changed scene needs fewer samples).

Cases: a bake, and the lighting that changes its scene.

- ``bunny_turned``: bunny_ggx/st_fagans_interior_1k baked, the map turned to 120 degrees;
- ``bunny_potsdamer``: the same bake under potsdamer_platz_1k, turned to 120 degrees;
- ``spot_sun``: spot_lambert/rooitou_park_1k (diffuse Spot on a floor under the park's sun)
  baked, the map turned to 30 degrees.

Per case and image size (--sizes), at --spp samples per pixel, --seeds seeds, methods interleaved
seed by seed (a burst of load slows all alike):

- ``converge``: `wavlight frame BAKE --spp N`'s frame: a ConvergeFrames made once the bake file
  and the scene are loaded (ray tracer, tables), then its first frame (the pixels' footprints,
  the lighting's tables, every tile's product trees, the passes): ``frame_seconds`` of
  `--json`, ``setup_seconds`` + ``render_seconds``;
- ``converge_new_lighting``: a frame of a ConvergeFrames that made frames before, under a lighting
  it has not kept (its tables and trees made anew; the tracer and footprints kept): the viewer's
  frame after a change of the map or its rotation;
- ``converge_same_lighting``: the next frame under the same lighting (another seed): its trees
  kept, only the passes (progressive refinement);
- ``wavelet``: `wavlight render --strategy wavelet` of the changed scene: setup_seconds +
  render_seconds (the scene loaded before).

Errors: relMSE against ``mis`` of the changed scene at --ref-spp (noise-corrected,
wavlight.evaluation.metrics.relmse; the reference cached in /tmp/relight-bench/). Per method
its median seconds (wall, and the process's CPU seconds over all its threads: less sensitive to
other loads on a shared machine) and mean relMSE; over wavelet: the time ratio and the equal-time relMSE ratio,
relMSE x seconds over wavelet's (below 1 the bake's frame wins); with the bake's wall time
amortized over 10, 100 and 1000 frames, and the break-even frame count (the frames over which
the bake's time must be spread for equal-time parity; none where the frame alone loses).
Targets: ``converge`` in at most 1.3 x wavelet's time, equal-time relMSE ratio at most 0.5 on the
bunny cases and 0.6 on the sun case.

    python benchmarks/relight_converge_speed.py [--sizes 256,512] [--spp 16] [--seeds 3]
        [--ref-spp 2048] [--bake-spp 16] [--levels M] [--footprint-grid G] [--slots S] [--candidates C]
        [--only SUBSTR]
        [--wait-load 1.0] [--wait-minutes 0] [-o FILE]

The figures in benchmarks/results/relight_converge_speed.json come from

    python benchmarks/relight_converge_speed.py --wait-minutes 10
"""
from __future__ import annotations

import os
import statistics
import sys
import time


HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import relight_common as rc  # noqa: E402

#: (case, baked scene, frame's map (None: the baked one), frame's rotation, equal-time target)
CASES = [("bunny_turned", "bunny_ggx/st_fagans_interior_1k", None, 120.0, 0.5),
         ("bunny_potsdamer", "bunny_ggx/st_fagans_interior_1k", "potsdamer_platz_1k", 120.0, 0.5),
         ("spot_sun", "spot_lambert/rooitou_park_1k", None, 30.0, 0.6)]
TIME_TARGET = 1.3
AMORTIZED = (10, 100, 1000)
METHODS = ("converge", "converge_new_lighting", "converge_same_lighting", "wavelet")


def main():
    ap = rc.parser(__doc__)
    ap.add_argument("--sizes", default="256,512", help="image widths and heights, comma-separated")
    ap.add_argument("--spp", type=int, default=16, help="samples per pixel of every method")
    ap.add_argument("--seeds", type=int, default=3, help="frames per method")
    ap.add_argument("--ref-spp", type=int, default=2048, help="samples per pixel of the mis reference")
    ap.add_argument("--bake-spp", type=int, default=16, help="camera samples of the bake")
    ap.add_argument("--levels", type=int, default=None,
                    help="converge's product-tree levels at most (default: wavlight.relight.converge.PRODUCT_LEVELS)")
    ap.add_argument("--footprint-grid", type=int, default=None,
                    help="rays per side of the footprint grid (default: wavlight.relight.converge.FOOTPRINT_GRID)")
    ap.add_argument("--slots", type=int, default=None, help="converge's directions per camera sample (default 2)")
    ap.add_argument("--candidates", type=int, default=None,
                    help="converge's candidates per resampled camera sample (default: CANDIDATES)")
    ap.add_argument("--only", default="", help="substring filter on case names")
    args = rc.parse(ap, "relight_converge_speed", 0)
    started = rc.begin(args)
    import wavlight
    from wavlight.evaluation.metrics import relmse
    from wavlight.relight import converge as cm

    if args.footprint_grid is not None:
        cm.FOOTPRINT_GRID = args.footprint_grid
    knobs = {k: v for k, v in (("levels", args.levels), ("slots", args.slots), ("candidates", args.candidates))
             if v is not None}
    sizes = [int(s) for s in args.sizes.split(",") if s]
    t_start = time.perf_counter()
    out = {}
    for case, name, env_name, rotation, target in CASES:
        if args.only and args.only not in case:
            continue
        base = rc.scene_dict(name)
        scene = rc.load(base)
        changed = rc.load(rc.lit(base, rotation, env_name))
        out[case] = {"baked": name, "env": env_name or "baked", "rotate_y": rotation, "target_equal_time": target,
                     "sizes": {}}
        for size in sizes:
            ref, ref_err, ref_info = rc.cached_reference(rc.lit(base, rotation, env_name), size, args.ref_spp)
            transfer, bake_info = rc.cached_bake(base, size, args.bake_spp)
            env = None if env_name is None else transfer.environment(rc.envmap(env_name))   # loaded, as the CLI does
            bake_seconds = float(bake_info.get("wall_seconds") or transfer.measured.get("bake_seconds") or 0.0)
            print(f"{case} {size}: bake n={transfer.n_levels} K={transfer.terms} {bake_seconds:.0f} s, reference "
                  f"{args.ref_spp} spp (noise {rc.reference_noise(ref, ref_err):.4f})", file=sys.stderr, flush=True)
            # compile and warm every kernel, untimed
            wavlight.render_full(changed, spp=1, strategy="wavelet", width=8, height=8)
            warm = cm.ConvergeFrames(transfer, scene)
            warm.frame(env, rotation + 1.0, spp=1, seed=99, **knobs)
            runs = {k: {"seconds": [], "cpu_seconds": [], "relmse": [], "stats": []} for k in METHODS}

            def record(method, result, seconds, cpu):
                runs[method]["seconds"].append(seconds)
                runs[method]["cpu_seconds"].append(cpu)
                runs[method]["relmse"].append(relmse(result.image, ref, ref_err))
                runs[method]["stats"].append(result.stats)

            for seed in range(args.seeds):
                c0 = time.process_time()
                r = wavlight.render_full(changed, spp=args.spp, strategy="wavelet", width=size, height=size, seed=seed)
                record("wavelet", r, r.stats["setup_seconds"] + r.stats["render_seconds"], time.process_time() - c0)
                frames = cm.ConvergeFrames(transfer, scene)   # the bake and the scene loaded: not timed
                c0 = time.process_time()
                r = frames.frame(env, rotation, spp=args.spp, seed=seed, **knobs)
                record("converge", r, frames.setup_seconds + r.stats["render_seconds"], time.process_time() - c0)
                frames.close()
                del frames
                warm.release_lighting()
                c0 = time.process_time()
                r = warm.frame(env, rotation, spp=args.spp, seed=seed, **knobs)
                record("converge_new_lighting", r, r.stats["render_seconds"], time.process_time() - c0)
                c0 = time.process_time()
                r = warm.frame(env, rotation, spp=args.spp, seed=seed + 1000, **knobs)
                record("converge_same_lighting", r, r.stats["render_seconds"], time.process_time() - c0)
            warm.close()
            row = {"bake": {"n_levels": transfer.n_levels, "terms": transfer.terms, "spp": transfer.spp,
                            "file_bytes": transfer.file_bytes, "wall_seconds": bake_seconds,
                            "cached": bake_info["cached"]},
                   "reference": {**{k: ref_info.get(k) for k in ("spp", "seed", "cached", "wall_seconds")},
                                 "noise_rel_l2": rc.reference_noise(ref, ref_err)},
                   "methods": {}}
            for method, run in runs.items():
                st = run["stats"][0]
                row["methods"][method] = {
                    "seconds": float(statistics.median(run["seconds"])), "seconds_seeds": run["seconds"],
                    "cpu_seconds": float(statistics.median(run["cpu_seconds"])),
                    **rc.mean_sd(run["relmse"]), "relmse_seeds": [float(x) for x in run["relmse"]],
                    **{k: st.get(k) for k in ("rays", "resampled_share", "product_levels", "lighting_seconds",
                                              "tiles_kept", "kept_tree_bytes", "setup_seconds", "render_seconds",
                                              "wavelet_candidates", "wavelet_slots") if k in st}}
            w = row["methods"]["wavelet"]
            for method in METHODS[:-1]:
                c = row["methods"][method]
                c["time_over_wavelet"] = c["seconds"] / w["seconds"]
                c["cpu_over_wavelet"] = c["cpu_seconds"] / w["cpu_seconds"]
                c["relmse_over_wavelet"] = c["relmse"] / w["relmse"]
                c["equal_time_over_wavelet"] = c["relmse"] * c["seconds"] / (w["relmse"] * w["seconds"])
                c["amortized"] = {str(n): c["relmse"] * (c["seconds"] + bake_seconds / n) / (w["relmse"] * w["seconds"])
                                  for n in AMORTIZED}
                gap = w["relmse"] * w["seconds"] - c["relmse"] * c["seconds"]
                c["break_even_frames"] = (float(bake_seconds * c["relmse"] / gap) if gap > 0 else None)
            c = row["methods"]["converge"]
            row["targets"] = {"time_over_wavelet": c["time_over_wavelet"], "time_target": TIME_TARGET,
                              "time_met": bool(c["time_over_wavelet"] <= TIME_TARGET),
                              "equal_time_over_wavelet": c["equal_time_over_wavelet"], "equal_time_target": target,
                              "equal_time_met": bool(c["equal_time_over_wavelet"] <= target)}
            out[case]["sizes"][str(size)] = row
            print(f"{case} {size}: " + " ".join(f"{k} {row['methods'][k]['relmse']:.3e}/{row['methods'][k]['seconds']:.2f}s"
                                                 for k in METHODS), file=sys.stderr, flush=True)
            transfer.close()

    lines = []
    for case, entry in out.items():
        for size, row in entry["sizes"].items():
            m = row["methods"]
            cells = {"case": case, "size": size, "wavelet s": m["wavelet"]["seconds"]}
            for k, label in (("converge", "frame"), ("converge_new_lighting", "new lighting"),
                             ("converge_same_lighting", "same lighting")):
                cells[f"{label} s"] = m[k]["seconds"]
                cells[f"{label} time/wav"] = m[k]["time_over_wavelet"]
                cells[f"{label} eq-time"] = m[k]["equal_time_over_wavelet"]
            cells["relMSE/wav"] = m["converge"]["relmse_over_wavelet"]
            cells["cpu/wav"] = m["converge"]["cpu_over_wavelet"]
            cells["amortized 10/100/1000"] = "/".join(f"{m['converge']['amortized'][str(n)]:.2f}" for n in AMORTIZED)
            cells["break-even"] = m["converge"]["break_even_frames"]
            cells["met"] = row["targets"]["time_met"] and row["targets"]["equal_time_met"]
            lines.append(cells)
    print(f"{args.spp} spp, {args.seeds} seeds: seconds (median), time over wavelet's setup + render, equal-time "
          "relMSE ratio (relMSE x seconds over wavelet's)")
    print(rc.table(lines, list(lines[0]) if lines else ["case"]))
    rc.finish(args.output, rc.rounded({"sizes": sizes, "spp": args.spp, "seeds": args.seeds, "ref_spp": args.ref_spp,
                                       "bake_spp": args.bake_spp, "levels": args.levels or cm.PRODUCT_LEVELS,
                                       "footprint_grid": cm.FOOTPRINT_GRID, "knobs": knobs, "time_target": TIME_TARGET,
                                       "amortized_frames": list(AMORTIZED), "cases": out,
                                       "seconds": round(time.perf_counter() - t_start, 1)}), started)


if __name__ == "__main__":
    main()
