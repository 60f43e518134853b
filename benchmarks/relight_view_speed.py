"""The view bake's unbiased frame against rendering the moved camera's view from scratch, in time
and in error (Chen & Gao sec. 2, eq. 6-8 and 12 with the view as the varying factor: once T1 is
baked on the surface cache, sampling T1 x f_r puts the visibility inside the sampled product).

Case ``bunny_eye``: benchmarks/scenes/bunny_ggx.toml under rooitou_park_1k (its sun: hard
shadows), view-baked from the scene's camera at the automatic choice (benchmarks/relight_view.py's
bake, cached in /tmp/relight-bench/view-bakes), the frame from the eye turned --turn degrees about
the target (a view the bake was not made from).

Per image size (--sizes), at --spp samples per pixel, --seeds seeds, methods interleaved seed by
seed (a burst of load slows all alike):

- ``converge``: `wavlight frame VIEWBAKE --eye ... --spp N`'s frame: a ViewFrames made once the
  bake file and the scene are loaded (its ray tracer), then its first frame (the device tables,
  the product trees of every tile, the passes): the wall time of both. The lighting inside the
  product's texels is the process's, kept per map by the warm-up's frames
  (wavlight.relight.view_frames.texel_light; ``lighting_kept``): a process that makes one frame
  (the command line) makes it once more, 0.2-0.4 CPU s from a 1k map;
- ``converge_new_camera``: a frame of a ViewFrames that made frames before from another camera
  (its trees made anew for this one): the viewer's frame after the camera moved;
- ``converge_same_camera``: the next frame from the same camera (another seed): the trees kept,
  only the passes (progressive refinement);
- ``wavelet``: `wavlight render --strategy wavelet` of the moved camera's scene: setup_seconds +
  render_seconds (the scene loaded before).

Errors: relMSE against ``mis`` of the moved camera's view at --ref-spp (noise-corrected,
wavlight.evaluation.metrics.relmse; the reference cached in /tmp/relight-bench/references). Per
method its median seconds (wall, and the process's CPU seconds over all its threads) and mean
relMSE; over wavelet: the time ratio, the relMSE ratio at equal spp and the equal-time relMSE
ratio (relMSE x seconds over wavelet's; below 1 the bake's frame wins), with the bake's wall time
amortized over 10, 100 and 1000 frames, and the break-even frame count (none where the frame
alone loses). Target: the equal-time ratio of ``converge`` at most 1.0.

    python benchmarks/relight_view_speed.py [--sizes 256,512] [--spp 16] [--seeds 3] [--ref-spp 1024]
        [--turn 40] [--slots S] [--defensive A] [--levels M] [--candidates C] [--no-control]
        [--wait-load 1.0] [--wait-minutes 0] [-o FILE]

The figures in benchmarks/results/relight_view_speed.json come from

    python benchmarks/relight_view_speed.py --sizes 256,512
"""
from __future__ import annotations

import os
import statistics
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import relight_common as rc  # noqa: E402
import relight_view as rv  # noqa: E402

TARGET = 1.0
AMORTIZED = (10, 100, 1000)
METHODS = ("converge", "converge_new_camera", "converge_same_camera", "wavelet")


def main():
    ap = rc.parser(__doc__)
    ap.add_argument("--sizes", default="256,512", help="image widths and heights, comma-separated")
    ap.add_argument("--spp", type=int, default=16, help="samples per pixel of every method")
    ap.add_argument("--seeds", type=int, default=3, help="frames per method")
    ap.add_argument("--ref-spp", type=int, default=1024, help="samples per pixel of the mis reference")
    ap.add_argument("--turn", type=float, default=40.0, help="degrees the eye turns about the target")
    ap.add_argument("--slots", type=int, default=None,
                    help="directions per camera sample (default view_converge.SLOTS)")
    ap.add_argument("--defensive", type=float, default=None, help="the BSDF's share (default view_converge.DEFENSIVE)")
    ap.add_argument("--levels", type=int, default=None,
                    help="product-tree levels at most (default wavlight.relight.view_frames.PRODUCT_LEVELS)")
    ap.add_argument("--candidates", type=int, default=None,
                    help="candidates of a resampled camera sample (default view_converge.CANDIDATES, 0: none)")
    ap.add_argument("--no-control", action="store_true", help="without the control variate")
    args = rc.parse(ap, "relight_view_speed", 0)
    started = rc.begin(args)
    import wavlight
    from wavlight.evaluation.metrics import relmse
    from wavlight.relight import view_frames
    from wavlight.relight import view_converge as vc

    if args.levels is not None:
        view_frames.PRODUCT_LEVELS = args.levels
    knobs = {k: v for k, v in (("slots", args.slots), ("defensive", args.defensive), ("candidates", args.candidates))
             if v is not None}
    if args.no_control:
        knobs["control"] = False
    sizes = [int(s) for s in args.sizes.split(",") if s]
    t_start = time.perf_counter()
    base = rc.bunny_ggx(rv.ENV)
    moved = rv.turned(base, args.turn)
    other = rv.turned(base, args.turn + 5.0)   # the camera before, for converge_new_camera
    scene = rc.load(base)
    changed = rc.load(moved)
    eye, target = moved["camera"]["eye"], moved["camera"]["target"]
    transfer, bake_info = rv.cached_view_bake(base, None)
    bake_seconds = float(bake_info.get("wall_seconds") or transfer.measured.get("bake_seconds") or 0.0)
    out = {"case": "bunny_eye", "baked": f"bunny_ggx/{rv.ENV}", "turn": args.turn, "eye": eye, "target": target,
           "target_equal_time": TARGET, "bake": {"n_levels": transfer.n_levels, "file_bytes": transfer.file_bytes,
                                                 "wall_seconds": bake_seconds, "cached": bake_info["cached"]},
           "sizes": {}}
    for size in sizes:
        ref, ref_err, ref_info = rc.cached_reference(moved, size, args.ref_spp)
        print(f"{size}: bake n={transfer.n_levels} {bake_seconds:.0f} s, reference {args.ref_spp} spp (noise "
              f"{rc.reference_noise(ref, ref_err):.4f})", file=sys.stderr, flush=True)
        # compile and warm every kernel, untimed
        wavlight.render_full(changed, spp=1, strategy="wavelet", width=8, height=8)
        warm = view_frames.ViewFrames(transfer, scene)
        warm.converge(other["camera"]["eye"], target, width=size, height=size, spp=1, seed=99, **knobs)
        runs = {k: {"seconds": [], "cpu_seconds": [], "relmse": [], "stats": [], "load": []} for k in METHODS}

        def record(method, result, seconds, cpu):
            runs[method]["seconds"].append(seconds)
            runs[method]["cpu_seconds"].append(cpu)
            runs[method]["relmse"].append(relmse(result.image, ref, ref_err))
            runs[method]["stats"].append(result.stats)
            runs[method]["load"].append(rc.load_average()[0])

        for seed in range(args.seeds):
            c0 = time.process_time()
            r = wavlight.render_full(changed, spp=args.spp, strategy="wavelet", width=size, height=size, seed=seed)
            record("wavelet", r, r.stats["setup_seconds"] + r.stats["render_seconds"], time.process_time() - c0)
            c0, t0 = time.process_time(), time.perf_counter()
            frames = view_frames.ViewFrames(transfer, scene)   # the bake and the scene loaded: its tracer timed
            r = frames.converge(eye, target, width=size, height=size, spp=args.spp, seed=seed, **knobs)
            record("converge", r, time.perf_counter() - t0, time.process_time() - c0)
            del frames
            warm.converge(other["camera"]["eye"], target, width=size, height=size, spp=1, seed=seed, **knobs)
            c0 = time.process_time()
            r = warm.converge(eye, target, width=size, height=size, spp=args.spp, seed=seed, **knobs)
            record("converge_new_camera", r, r.stats["frame_seconds"], time.process_time() - c0)
            c0 = time.process_time()
            r = warm.converge(eye, target, width=size, height=size, spp=args.spp, seed=seed + 1000, **knobs)
            record("converge_same_camera", r, r.stats["frame_seconds"], time.process_time() - c0)
        row = {"reference": {**{k: ref_info.get(k) for k in ("spp", "seed", "cached", "wall_seconds")},
                             "noise_rel_l2": rc.reference_noise(ref, ref_err)},
               "methods": {}}
        for method, run in runs.items():
            st = run["stats"][0]
            row["methods"][method] = {
                "seconds": float(statistics.median(run["seconds"])), "seconds_seeds": run["seconds"],
                "cpu_seconds": float(statistics.median(run["cpu_seconds"])),
                **rc.mean_sd(run["relmse"]), "relmse_seeds": [float(x) for x in run["relmse"]],
                "load_average": run["load"],
                **{k: st.get(k) for k in ("rays", "product_levels", "slots", "tiles", "tiles_kept", "kept_tree_bytes",
                                          "trees_thread_seconds", "pass_spp", "pass_samples", "setup_seconds",
                                          "render_seconds", "lighting_kept") if k in st}}
        w = row["methods"]["wavelet"]
        for method in METHODS[:-1]:
            c = row["methods"][method]
            c["time_over_wavelet"] = c["seconds"] / w["seconds"]
            c["cpu_over_wavelet"] = c["cpu_seconds"] / w["cpu_seconds"]
            c["relmse_over_wavelet"] = c["relmse"] / w["relmse"]
            c["equal_time_over_wavelet"] = c["relmse"] * c["seconds"] / (w["relmse"] * w["seconds"])
            c["equal_cpu_over_wavelet"] = c["relmse"] * c["cpu_seconds"] / (w["relmse"] * w["cpu_seconds"])
            c["amortized"] = {str(n): c["relmse"] * (c["seconds"] + bake_seconds / n) / (w["relmse"] * w["seconds"])
                              for n in AMORTIZED}
            gap = w["relmse"] * w["seconds"] - c["relmse"] * c["seconds"]
            c["break_even_frames"] = (float(bake_seconds * c["relmse"] / gap) if gap > 0 else None)
        c = row["methods"]["converge"]
        row["targets"] = {"equal_time_over_wavelet": c["equal_time_over_wavelet"], "equal_time_target": TARGET,
                          "equal_time_met": bool(c["equal_time_over_wavelet"] <= TARGET)}
        out["sizes"][str(size)] = row
        print(f"{size}: " + " ".join(f"{k} {row['methods'][k]['relmse']:.3e}/{row['methods'][k]['seconds']:.2f}s"
                                     for k in METHODS), file=sys.stderr, flush=True)
        del warm
    transfer.close()

    lines = []
    for size, row in out["sizes"].items():
        m = row["methods"]
        cells = {"size": size, "wavelet s": m["wavelet"]["seconds"]}
        for k, label in (("converge", "frame"), ("converge_new_camera", "new camera"),
                         ("converge_same_camera", "same camera")):
            cells[f"{label} s"] = m[k]["seconds"]
            cells[f"{label} time/wav"] = m[k]["time_over_wavelet"]
            cells[f"{label} eq-time"] = m[k]["equal_time_over_wavelet"]
        cells["relMSE/wav"] = m["converge"]["relmse_over_wavelet"]
        cells["cpu/wav"] = m["converge"]["cpu_over_wavelet"]
        cells["amortized 10/100/1000"] = "/".join(f"{m['converge']['amortized'][str(n)]:.2f}" for n in AMORTIZED)
        cells["break-even"] = m["converge"]["break_even_frames"]
        cells["met"] = row["targets"]["equal_time_met"]
        lines.append(cells)
    print(f"{args.spp} spp, {args.seeds} seeds: seconds (median), time over wavelet's setup + render, equal-time "
          "relMSE ratio (relMSE x seconds over wavelet's)")
    print(rc.table(lines, list(lines[0]) if lines else ["size"]))
    rc.finish(args.output, rc.rounded({"sizes": sizes, "spp": args.spp, "seeds": args.seeds, "ref_spp": args.ref_spp,
                                       "levels": view_frames.PRODUCT_LEVELS, "slots": knobs.get("slots", vc.SLOTS),
                                       "defensive": knobs.get("defensive", vc.DEFENSIVE),
                                       "control": not args.no_control, "target": TARGET,
                                       "amortized_frames": list(AMORTIZED), "case": out,
                                       "seconds": round(time.perf_counter() - t_start, 1)}), started)


if __name__ == "__main__":
    main()
