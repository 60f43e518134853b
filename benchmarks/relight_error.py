"""Relit frames: speed against accuracy, against converged `mis` renders of the same lighting.

Scenes (benchmarks/relight_common.py): the bunny of benchmarks/scenes/bunny_ggx.toml (ggx 0.2 on a lambert
floor) under st_fagans_interior_1k and under potsdamer_platz_1k, and the same bunny in lambert
(albedo 0.7) on its floor under rooitou_park_1k (a diffuse object with hard shadows from the
sun). Each scene is baked at its map's own rotation (0) with texel levels n in --levels and the
automatic choice (levels, terms and priority from the pilot bake), at camera samples --bake-spp
(auto: the pilot's choice too);
its frames are made under three lightings none of the bakes saw: the map turned to each of
--rotations (not the bake's held-out 137 degrees) and another map (the swap: st_fagans ->
empty_warehouse_01, potsdamer -> kiara_1_dawn, rooitou -> immenstadter_horn), for every K in
--terms and every priority in --priorities (and, for the automatic bake, its own K and
priority). The reference of each lighting is `mis` at --ref-spp of the scene dict with that
environment (environment.rotate_y = r, or environment.file swapped).

Errors (relight_common.errors): relative L2 ||I - R|| / ||R|| raw and with the reference's own
noise sqrt(sum stderr^2) / ||R|| taken out in quadrature; relMSE mean((I - R)^2 / (R^2 + 0.01)),
raw and minus the reference's variance (wavlight.evaluation.metrics.relmse); the relative H1
(Sobolev) error of values and gradients (Ng et al. 2003), raw and corrected likewise. Times:
frame_seconds and its parts, median of --repeat frames after one warm-up frame per bake; the
bake's seconds (and pilot seconds), rays, file size from the bake file (bakes and references are
cached in /tmp/relight-bench/; a cached bake reports the time and load of the run that made it).

The bake's own noise: the automatic choice at --chart-spp is baked again with seed 1 (same n, K,
priority); ||I_0 - I_1|| / (sqrt 2 ||R||) is one bake's random error (camera samples, shadow
rays, dithering), and sqrt(error^2 - noise^2) what is left: the bias of texels, terms and
compression (--no-seed-pair leaves it out).

The priority that wins: per (scene, lighting, bake, K < 4^n) the priority with the lowest error
(ties shared); reported as wins and as the geometric mean of error / best error.

Timing: with --wait-minutes M > 0, waits for the 1-minute load average to fall below --wait-load
(polling every 60 s, at most M minutes), then runs anyway; the load is in the provenance.

The result keeps no per-frame rows: the priority summary; the summary (a table of columns and
rows: per scene, bake, bake spp and K, at the winning priority, the means over the three
lightings of the errors and frame_seconds, rel_l2_max the worst lighting; K "auto": the
automatic bake at its own K and priority); per scene and bake spp the automatic choice against
its target, on the worst lighting (targets); the references, the bakes (a table), the pilot of
each scene's automatic choice, and the bake's own noise.

Chart: docs/figures/relight-error.png and .svg, relative L2 (noise-corrected, mean over the three
lightings) against frame time, a line per (scene, n) at --chart-spp camera samples and the
winning priority, points labelled by K, the automatic choice starred. --chart-only measures
nothing: it prints the tables of the result file (-o) and draws its chart again.

    python benchmarks/relight_error.py [--size 128] [--ref-spp 2048] [--levels 5,6,7] [--bake-spp auto,16]
        [--terms 32,64,128,256,512,1024,2048,4096] [--priorities transfer,area,magnitude]
        [--rotations 60,200] [--repeat 5] [--chart-spp auto] [--only SUBSTR] [--no-auto] [--no-reuse]
        [--no-chart] [--no-seed-pair] [--figure docs/figures/relight-error] [--wait-load 1.0]
        [--wait-minutes 0] [-o FILE]
    python benchmarks/relight_error.py --chart-only [-o FILE] [--figure STEM]

The figures in benchmarks/results/relight_error.json come from

    python benchmarks/relight_error.py --ref-spp 16384 --bake-spp auto,16,64
"""
from __future__ import annotations

import json
import os
import statistics
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import relight_common as rc  # noqa: E402

SCENES = [("bunny_ggx/st_fagans_interior_1k", "empty_warehouse_01_1k", 0.02),
          ("bunny_ggx/potsdamer_platz_1k", "kiara_1_dawn_1k", 0.02),
          ("bunny_lambert/rooitou_park_1k", "immenstadter_horn_1k", 0.05)]
TERMS = (32, 64, 128, 256, 512, 1024, 2048, 4096)
FIGURE = os.path.join(rc.ROOT, "docs", "figures", "relight-error")
#: the result's tables: the speed-against-accuracy summary and the bakes
SUMMARY_COLUMNS = ("scene", "bake", "bake_spp", "n", "K", "terms_used", "priority", "rel_l2", "rel_l2_max", "relmse", "h1",
                   "frame_seconds")
BAKE_COLUMNS = ("scene", "bake", "bake_spp", "spp", "n", "terms", "priority", "bake_seconds", "pilot_seconds", "rays",
                "rays_per_second", "file_bytes", "entries", "entries_full", "compression_error", "level_error",
                "term_error", "noise", "predicted_error", "bake_load_average", "cached")
#: what the result keeps of a reference's cache record
REFERENCE_KEYS = ("spp", "seed", "size", "render_seconds", "wall_seconds", "load_average", "cached")


def ints(text):
    return [int(x) for x in text.split(",") if x]


def spp_labels(text):
    """--bake-spp: camera samples, or "auto" (the bake's pilot chooses them)."""
    return [x if x == "auto" else int(x) for x in text.split(",") if x]


def frames(transfer, env, rot, terms, priority, repeat):
    """The frame (from the first of ``repeat``) and the medians of its timings."""
    stats = []
    image = None
    for i in range(repeat):
        img, st = transfer.frame_timed(env, rot, 1.0, terms, priority)
        if image is None:
            image = img
        stats.append(st)
    med = {k: statistics.median(s[k] for s in stats) for k in
           ("frame_seconds", "lighting_seconds", "terms_seconds", "product_seconds", "assembly_seconds")}
    return image, med, stats[0]["terms"], stats[0]["entries_read"]


def priority_summary(rows):
    """Which priority has the lowest error, per (scene, lighting, bake, K) with K below all terms."""
    groups = {}
    for r in rows:
        if r["K"] == "auto" or r["K"] >= 4 ** r["n"]:
            continue
        groups.setdefault((r["scene"], r["lighting"], r["bake"], r["K"]), {})[r["priority"]] = r["rel_l2_raw"]
    out = {}
    for subset, pick in (("all", lambda k: True), ("K<=256", lambda k: k[3] <= 256), ("K>=512", lambda k: k[3] >= 512)):
        wins, ratios = {}, {}
        for key, by in groups.items():
            if not pick(key) or len(by) < 2:
                continue
            best = min(by.values())
            winners = [p for p, v in by.items() if v <= best * (1 + 1e-9)]
            for p in winners:
                wins[p] = wins.get(p, 0) + 1 / len(winners)
            for p, v in by.items():
                ratios.setdefault(p, []).append(v / best if best > 0 else 1.0)
        out[subset] = {p: {"wins": round(wins.get(p, 0.0), 2), "groups": len(ratios[p]),
                           "geomean_error_over_best": float(np.exp(np.mean(np.log(ratios[p]))))}
                       for p in sorted(ratios)}
    by_scene = {}
    for key, by in groups.items():
        for p, v in by.items():
            by_scene.setdefault(key[0], {}).setdefault(p, []).append(v / min(by.values()))
    out["by_scene_geomean_error_over_best"] = {s: {p: float(np.exp(np.mean(np.log(v)))) for p, v in d.items()}
                                              for s, d in by_scene.items()}
    overall = out["all"]
    winner = min(overall, key=lambda p: overall[p]["geomean_error_over_best"]) if overall else None
    out["winner"] = winner
    return out


def mean_rows(sel, keys):
    """Rows of ``sel`` grouped by ``keys``: the means over the group's lightings."""
    out = {}
    for r in sel:
        out.setdefault(tuple(r[k] for k in keys), []).append(r)
    return [{**dict(zip(keys, key)), "terms_used": v[0]["terms_used"], "priority": v[0]["priority"],
             **{c: float(np.mean([r[c] for r in v])) for c in ("rel_l2", "rel_l2_raw", "relmse", "h1", "frame_seconds")},
             "rel_l2_max": float(max(r["rel_l2"] for r in v))}
            for key, v in out.items()]


def pilots(bakes) -> dict:
    """The pilot bake of each scene's automatic choice (its error at every level and term count)."""
    return {b["scene"]: b["pilot"] for b in bakes if b["bake"] == "auto" and b.get("pilot")}


def tables(rows, targets, bake_spps) -> dict:
    """What the result keeps of the frames' rows: the priority summary, the speed-against-accuracy
    summary at the winning priority (K = "auto": the automatic bake at its own K and priority),
    means over the lightings, and the automatic choice against its target, per lighting."""
    winner = priority_summary(rows)
    best = winner["winner"]
    keys = ("scene", "bake", "bake_spp", "n", "K")
    summary = mean_rows([r for r in rows if r["priority"] == best and r["K"] != "auto"], keys)
    automatic = [r for r in rows if r["K"] == "auto"]
    summary += mean_rows(automatic, keys)
    target_check = {}
    for scene_name, target in targets.items():
        for spp in bake_spps:
            sel = [r for r in automatic if r["scene"] == scene_name and r["bake_spp"] == spp]
            if sel:
                worst = max(r["rel_l2"] for r in sel)
                target_check[f"{scene_name} spp={spp}"] = {
                    "scene": scene_name, "bake_spp": spp, "n": sel[0]["n"], "K": sel[0]["terms_used"],
                    "priority": sel[0]["priority"], "target_rel_l2": target, "max_rel_l2": worst,
                    "max_rel_l2_raw": max(r["rel_l2_raw"] for r in sel), "max_relmse": max(r["relmse"] for r in sel),
                    "per_lighting": {r["lighting"]: {"rel_l2": r["rel_l2"], "relmse": r["relmse"]} for r in sel},
                    "frame_seconds": float(np.mean([r["frame_seconds"] for r in sel])), "met": bool(worst <= target)}
    return {"priority_summary": winner, "chosen_priority": best, "targets": target_check,
            "summary": rc.columns(summary, SUMMARY_COLUMNS)}


def chart(result, path_stem):
    """The chart of a result (its summary at --chart-spp, or the largest bake spp it has)."""
    from matplotlib import ticker
    from matplotlib.figure import Figure

    rows, size, priority = rc.from_columns(result["summary"]), result["size"], result["chosen_priority"]
    spp = result["chart_spp"] if result["chart_spp"] in result["bake_spp"] else result["bake_spp"][-1]
    targets = {v["scene"]: v["target_rel_l2"] for v in result["targets"].values()}
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    fig = Figure(figsize=(max(5.0 * len(scenes), 7.0), 4.6), layout="constrained")
    axes = fig.subplots(1, len(scenes), squeeze=False)[0]
    for ax, scene in zip(axes, scenes):
        sel = [r for r in rows if r["scene"] == scene and r["bake_spp"] == spp]
        for bake in dict.fromkeys(r["bake"] for r in sel):
            pts = sorted((r for r in sel if r["bake"] == bake and r["K"] != "auto"), key=lambda r: r["K"])
            auto_pt = [r for r in sel if r["bake"] == bake and r["K"] == "auto"]
            if not pts:
                continue
            x = [1e3 * r["frame_seconds"] for r in pts]
            y = [max(r["rel_l2"], 1e-5) for r in pts]
            n = pts[0]["n"]
            label = f"n = {n}" if not bake.startswith("auto") else f"auto (n = {n})"
            line, = ax.plot(x, y, "o-", ms=3.5, lw=1.2, label=label)
            for r, xx, yy in zip(pts, x, y):
                ax.annotate(str(r["K"]), (xx, yy), textcoords="offset points", xytext=(3, 3), fontsize=6.5,
                            color=line.get_color())
            for a in auto_pt:
                ax.plot([1e3 * a["frame_seconds"]], [max(a["rel_l2"], 1e-5)], "*", ms=11, color=line.get_color(),
                        mec="k", mew=0.6, label=f"automatic: K = {a['terms_used']}, {a['priority']}")
        if scene in targets:
            ax.axhline(targets[scene], color="0.4", ls="--", lw=0.9)
            ax.text(0.02, targets[scene], f" target {100 * targets[scene]:g}%",
                    transform=ax.get_yaxis_transform(), va="bottom", fontsize=7, color="0.3")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.xaxis.set_major_formatter(ticker.FuncFormatter(lambda v, _: f"{v:g}"))
        ax.xaxis.set_minor_formatter(ticker.NullFormatter())
        ax.yaxis.set_major_locator(ticker.FixedLocator([0.005, 0.01, 0.015, 0.02, 0.03, 0.04, 0.05, 0.07, 0.1, 0.15, 0.2]))
        ax.yaxis.set_major_formatter(ticker.FuncFormatter(lambda v, _: f"{100 * v:g}%"))
        ax.yaxis.set_minor_formatter(ticker.NullFormatter())
        ax.set_title(scene.replace("/", " under "), fontsize=9)
        ax.set_xlabel(f"frame time (ms, {size}x{size})")
        ax.set_ylabel("relative L2 error (reference noise removed)")
        ax.grid(True, which="both", alpha=0.25)
        ax.legend(fontsize=7)
    fig.suptitle(f"Relit frames against converged mis: mean over two rotations and a swapped map\n"
                 f"bake {spp} camera samples, priority '{priority}', points labelled by K", fontsize=9)
    os.makedirs(os.path.dirname(os.path.abspath(path_stem)), exist_ok=True)
    for ext in ("png", "svg"):
        fig.savefig(f"{path_stem}.{ext}", dpi=130, **({"metadata": {"Date": None}} if ext == "svg" else {}))
    return [f"{path_stem}.png", f"{path_stem}.svg"]


def report(result):
    """The tables of a result, printed."""
    print("references (mis): noise = sqrt(sum stderr^2) / ||R||")
    print(rc.table([{"case": k, **v} for k, v in result["references"].items()],
                   ["case", "spp", "noise_rel_l2", "render_seconds"]))
    print("\nbakes")
    print(rc.table(rc.from_columns(result["bakes"]), ["scene", "bake", "bake_spp", "n", "terms", "priority", "bake_seconds",
                                     "pilot_seconds", "rays", "rays_per_second", "file_bytes", "entries",
                                     "compression_error"]))
    winner = result["priority_summary"]
    print(f"\npriority (rel L2 / best per scene, lighting, bake, K < 4^n): winner = {winner['winner']}")
    for subset in ("all", "K<=256", "K>=512"):
        print(f"  {subset:7s} " + "  ".join(f"{p}: wins {v['wins']:.1f}/{v['groups']} geomean "
                                          f"x{v['geomean_error_over_best']:.3f}" for p, v in winner[subset].items()))
    for s, d in winner["by_scene_geomean_error_over_best"].items():
        print(f"  {s}: " + "  ".join(f"{p} x{v:.3f}" for p, v in d.items()))
    print(f"\nspeed against accuracy (priority {result['chosen_priority']}; K auto: the automatic bake's own K and "
          "priority; mean over lightings; rel_l2 with the reference noise removed)")
    print(rc.table(rc.from_columns(result["summary"]), ["scene", "bake", "bake_spp", "K", "terms_used", "rel_l2", "rel_l2_max",
                                                         "relmse", "h1", "frame_seconds"],
                   {"frame_seconds": "{:.4f}", "rel_l2": "{:.4f}", "rel_l2_max": "{:.4f}", "relmse": "{:.2e}",
                    "h1": "{:.4f}"}))
    print("\nautomatic choice (levels, terms, priority from the pilot bake): targets (worst lighting)")
    print(rc.table([{"case": k, **v} for k, v in result["targets"].items()],
                   ["case", "n", "K", "priority", "max_rel_l2", "max_rel_l2_raw", "max_relmse", "target_rel_l2", "met",
                    "frame_seconds"], {"max_rel_l2": "{:.4f}", "max_rel_l2_raw": "{:.4f}", "max_relmse": "{:.2e}",
                                       "frame_seconds": "{:.4f}"}))
    if result["bake_noise"]:
        print("\nthe bake's own noise (automatic choice, two seeds: ||I_0 - I_1|| / (sqrt 2 ||R||)) and the rest of "
              "the error")
        print(rc.table(result["bake_noise"], ["scene", "lighting", "bake_spp", "n", "K", "rel_l2", "bake_noise_rel_l2",
                                              "rest_rel_l2"],
                       {c: "{:.4f}" for c in ("rel_l2", "bake_noise_rel_l2", "rest_rel_l2")}))


def main():
    ap = rc.parser(__doc__)
    ap.add_argument("--size", type=int, default=128, help="image width and height")
    ap.add_argument("--ref-spp", type=int, default=2048, help="samples per pixel of the mis references")
    ap.add_argument("--levels", default="5,6,7", help="texel levels n of the fixed-level bakes")
    ap.add_argument("--bake-spp", default="auto,16",
                    help="camera samples of the bakes, comma-separated; auto: the pilot's choice")
    ap.add_argument("--terms", default=",".join(map(str, TERMS)), help="the K of the frames")
    ap.add_argument("--priorities", default="transfer,area,magnitude", help="the terms' priorities")
    ap.add_argument("--rotations", default="60,200", help="rotate_y of the turned lightings (degrees)")
    ap.add_argument("--repeat", type=int, default=5, help="frames per case (the median time)")
    ap.add_argument("--only", default="", help="substring filter on scene names")
    ap.add_argument("--no-auto", action="store_true", help="leave out the automatic bakes")
    ap.add_argument("--no-reuse", action="store_true", help="bake and render again instead of using the cache")
    ap.add_argument("--no-chart", action="store_true", help="write no chart")
    ap.add_argument("--chart-only", action="store_true",
                    help="measure nothing: print the tables of the result file (-o) and draw its chart")
    ap.add_argument("--chart-spp", type=lambda x: x if x == "auto" else int(x), default="auto",
                    help="the bakes' camera samples the chart shows (a number or auto)")
    ap.add_argument("--no-seed-pair", action="store_true",
                    help="leave out the second bake (seed 1) of the automatic choice that measures the bake's noise")
    ap.add_argument("--figure", default=FIGURE, help="chart path without extension")
    args = rc.parse(ap, "relight_error", 0)
    if args.chart_only:
        with open(args.output) as fh:
            result = json.load(fh)
        report(result)
        for f in chart(result, args.figure):
            print(f"wrote {f}", file=sys.stderr)
        return
    started = rc.begin(args)

    levels, bake_spps, terms = ints(args.levels), spp_labels(args.bake_spp), ints(args.terms)
    priorities = [p for p in args.priorities.split(",") if p]
    rotations = [float(x) for x in args.rotations.split(",") if x]
    reuse = not args.no_reuse
    rows, bakes, references, seed_noise = [], [], {}, []
    targets = {}
    t_start = time.perf_counter()
    for scene_name, swap, target in SCENES:
        if args.only and args.only not in scene_name:
            continue
        targets[scene_name] = target
        base = rc.scene_dict(scene_name)
        lightings = [(f"rotate_y={r:g}", r, None) for r in rotations] + [(f"swap={swap}", 0.0, swap)]
        refs = {}
        for name, rot, env in lightings:
            img, err, info = rc.cached_reference(rc.lit(base, rot, env), args.size, args.ref_spp, reuse=reuse)
            refs[name] = (img, err)
            references[f"{scene_name} {name}"] = {
                **{k: info.get(k) for k in REFERENCE_KEYS}, "noise_rel_l2": rc.reference_noise(img, err),
                "mean": float(np.mean(img))}
            print(f"{scene_name} {name}: reference {info['spp']} spp, noise "
                  f"{references[f'{scene_name} {name}']['noise_rel_l2']:.4f}{' (cached)' if info['cached'] else ''}",
                  file=sys.stderr, flush=True)
        configs = [(f"n={n}", n) for n in levels] + ([] if args.no_auto else [("auto", None)])
        for spp in bake_spps:
            for bake_name, n in configs:
                auto = n is None
                transfer, info = rc.cached_bake(base, args.size, None if spp == "auto" else spp, levels=n,
                                                terms=None if auto else 256,
                                                priority=None if auto else "area", reuse=reuse)
                m = transfer.measured
                bake_row = {"scene": scene_name, "bake": bake_name, "bake_spp": spp, "spp": transfer.spp,
                            "n": transfer.n_levels,
                            "terms": transfer.terms, "priority": transfer.priority,
                            "bake_seconds": m.get("bake_seconds"), "pilot_seconds": m.get("pilot_seconds"),
                            "rays": m.get("rays"), "rays_per_second": m.get("rays_per_second"),
                            "file_bytes": transfer.file_bytes, "entries": transfer.entries,
                            "entries_full": m.get("entries_full"), "compression_error": m.get("compression_error"),
                            "level_error": m.get("level_error"), "term_error": m.get("term_error"),
                            "noise": m.get("noise"), "predicted_error": m.get("predicted_error"),
                            "pilot": m.get("pilot"), "bake_load_average": info.get("load_average"),
                            "cached": info["cached"]}
                bakes.append(bake_row)
                print(f"{scene_name} bake {bake_name} spp {spp} ({transfer.spp}): n={transfer.n_levels} K={transfer.terms} "
                      f"{transfer.priority}, {m.get('bake_seconds')} s, {transfer.file_bytes / 1e6:.1f} MB"
                      f"{' (cached)' if info['cached'] else ''}", file=sys.stderr, flush=True)
                envs = {None: None}
                for _, _, env in lightings:
                    if env is not None:
                        envs[env] = transfer.environment(rc.envmap(env))
                transfer.frame_timed(None, 60.0, 1.0, 256, "area")   # warm-up: device buffers, kernels
                side2 = 4 ** transfer.n_levels
                cases = [(k, p) for p in priorities for k in terms if k <= max(side2, terms[0])]
                if auto:
                    cases.append(("auto", None))
                for light_name, rot, env in lightings:
                    ref, ref_err = refs[light_name]
                    for k, p in cases:
                        image, med, used, entries = frames(transfer, envs[env], rot, None if k == "auto" else k,
                                                           p, args.repeat)
                        rows.append({"scene": scene_name, "lighting": light_name, "bake": bake_name,
                                     "bake_spp": spp, "n": transfer.n_levels, "K": k, "terms_used": used,
                                     "priority": p or transfer.priority, "entries_read": entries,
                                     "size": args.size, **med, **rc.errors(image, ref, ref_err)})
                if auto and spp == args.chart_spp and not args.no_seed_pair:
                    # the bake's own noise: the same model baked with another seed; the frames' difference
                    # has twice the variance of one bake's random error (camera samples, shadow rays,
                    # dithering), what is left of the error beyond it is bias (texels, terms, compression)
                    other, _ = rc.cached_bake(base, args.size, transfer.spp, levels=transfer.n_levels, terms=transfer.terms,
                                              priority=transfer.priority, seed=1, reuse=reuse)
                    for light_name, rot, env in lightings:
                        ref = refs[light_name][0]
                        a = transfer.frame(envs[env], rot)
                        b = other.frame(other.environment(rc.envmap(env)) if env else None, rot)
                        noise = float(np.linalg.norm(a.astype(np.float64) - b) / (np.sqrt(2.0) * np.linalg.norm(ref)))
                        err = [r for r in rows if r["scene"] == scene_name and r["bake"] == "auto" and r["K"] == "auto"
                               and r["bake_spp"] == spp and r["lighting"] == light_name][0]["rel_l2"]
                        seed_noise.append({"scene": scene_name, "lighting": light_name, "bake_spp": spp,
                                           "n": transfer.n_levels, "K": transfer.terms, "bake_noise_rel_l2": noise,
                                           "rel_l2": err, "rest_rel_l2": float(np.sqrt(max(err ** 2 - noise ** 2, 0.0)))})
                    other.close()
                transfer.close()
    result = {"size": args.size, "ref_spp": args.ref_spp, "levels": levels, "bake_spp": bake_spps, "terms": terms,
              "priorities": priorities, "rotations": rotations, "repeat": args.repeat, "chart_spp": args.chart_spp,
              "swaps": {s: w for s, w, _ in SCENES}, "seconds": round(time.perf_counter() - t_start, 1),
              **tables(rows, targets, bake_spps), "references": references,
              "bakes": rc.columns(bakes, BAKE_COLUMNS), "pilots": pilots(bakes), "bake_noise": seed_noise}
    result = rc.rounded(result, 4)
    figures = [] if args.no_chart or not rows else chart(result, args.figure)
    result["figures"] = [os.path.relpath(os.path.abspath(f), rc.ROOT) for f in figures]
    report(result)
    rc.finish(args.output, result, started)


if __name__ == "__main__":
    main()
