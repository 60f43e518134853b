"""The unbiased relit frame (wavlight.relight.converge) against `mis` and `wavelet` on the same
frames: relMSE against spp and against time, and the pixel-footprint floor.

Scenes (benchmarks/relight_common.py), all shadowed: the bunny of benchmarks/scenes/bunny_ggx.toml (ggx 0.2
on a lambert floor) under rooitou_park_1k (the sun) and under potsdamer_platz_1k, and a ggx 0.2
sphere on the same floor under rooitou_park_1k. Each is baked once at its map's own rotation (the
automatic choice of texel levels, terms and priority, --bake-spp camera samples; cached in
/tmp/relight-bench/) and every frame is under the map turned to --rotation degrees (the bake saw
neither this rotation nor, in its compression, anything but its held-out 137 degrees). The
reference is `mis` at --ref-spp of the scene dict with environment.rotate_y = --rotation.

For spp in --spp and seeds 0 .. --seeds - 1: converge with each of --slots (directions per camera
sample; its camera samples are stratified over the pixel), `mis` and `wavelet` (the renderer's
default independent pixel samples) and, unless --no-stratified, `mis` and `wavelet` with
stratified pixel samples too. relMSE = mean(((x - r)^2 - s_r^2) / (r^2 + 0.01))
(wavlight.evaluation.metrics.relmse: the reference's variance subtracted), and its parts over
the pixels that see the object, the floor and the background (relmse_by_region). Seconds: the wall time
of the call (converge: the product pyramids, the tracer and the frame; mis and wavelet: their
setup_seconds + render_seconds), the median over seeds. Equal time: relMSE x seconds /
seconds_wavelet (relMSE ~ 1/spp). Amortized: converge's seconds plus the bake's seconds / --frames.

The pixel-footprint floor at --floor-spp (benchmarks/relmse.py floor_image, D = --floor
directions per pixel sample): the relMSE left when every camera sample is shaded exactly, floor =
(D relMSE_D - relMSE_mis) / (D - 1), per pixel sampler (independent: the floor under `wavelet`
and `mis` as rendered; stratified: the floor under converge's stratified camera samples). No
direction sampler goes below it, so where floor / relMSE_wavelet exceeds 1/3 the target
"converge <= wavelet / 3 at equal spp" cannot be met by better directions alone.

Timing: with --wait-minutes M > 0, waits for the 1-minute load average to fall below --wait-load
(polling every 60 s, at most M minutes), then runs anyway; the load is in the provenance.

    python benchmarks/relight_converge.py [--size 128] [--spp 1,4,16,64] [--seeds 3] [--ref-spp 16384]
        [--bake-spp 16] [--rotation 60] [--frames 100] [--floor 32] [--floor-spp 16] [--no-stratified]
        [--only SUBSTR] [--slots 2,4] [--product-levels M] [--light BETA] [--defensive ALPHA] [--no-control]
        [--candidates M] [--coherence K]
        [--wait-load 1.0] [--wait-minutes 0] [-o FILE]

The figures in benchmarks/results/relight_converge.json come from

    python benchmarks/relight_converge.py --wait-minutes 40
"""
from __future__ import annotations

import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import relight_common as rc  # noqa: E402

SCENES = ["bunny_ggx/rooitou_park_1k", "bunny_ggx/potsdamer_platz_1k", "sphere_ggx/rooitou_park_1k"]


def regions(scene, size: int) -> dict:
    """Masks (size, size) of the pixels whose centre ray sees the object, the floor (the
    scene's last material: the lambert floor) or the background. relmse_by_region holds each
    region's part of the image's relMSE: the parts sum to it."""
    from wavlight.camera import camera_rays
    from wavlight.raytrace import RayTracer

    pix = np.arange(size * size)
    o, d = camera_rays(scene, pix % size, pix // size, np.full((len(pix), 2), 0.5, np.float32), size, size)
    prim, _ = RayTracer(scene.vertices, scene.faces).intersect(o, d)
    mat = np.where(prim >= 0, scene.face_material[np.maximum(prim, 0)], -1).reshape(size, size)
    floor = int(scene.face_material[-1])
    return {"object": (mat >= 0) & (mat != floor), "floor": mat == floor, "background": mat < 0}


def main():
    ap = rc.parser(__doc__)
    ap.add_argument("--size", type=int, default=128, help="image width and height")
    ap.add_argument("--spp", default="1,4,16,64", help="samples per pixel of every method, comma-separated")
    ap.add_argument("--seeds", type=int, default=3, help="renders per method and spp")
    ap.add_argument("--ref-spp", type=int, default=16384, help="samples per pixel of the mis reference")
    ap.add_argument("--bake-spp", type=int, default=16, help="camera samples of the bake")
    ap.add_argument("--rotation", type=float, default=60.0, help="rotate_y of the frames (degrees)")
    ap.add_argument("--frames", type=int, default=100, help="frames the bake is amortized over")
    ap.add_argument("--floor", type=int, default=32, metavar="D", help="directions per pixel sample of the floor (0: none)")
    ap.add_argument("--floor-spp", type=int, default=16, help="spp of the floor and of the 1/3 target")
    ap.add_argument("--no-stratified", action="store_true", help="leave out mis and wavelet with stratified samples")
    ap.add_argument("--only", default="", help="substring filter on scene names")
    ap.add_argument("--slots", default="2,4", help="converge's directions per camera sample, comma-separated")
    ap.add_argument("--product-levels", type=int, default=None,
                    help="converge's product-tree levels at most (default: wavlight.relight.converge.PRODUCT_LEVELS)")
    ap.add_argument("--light", type=float, default=None,
                    help="converge's share of the lighting alone in its mixture (default: LIGHT_SHARE)")
    ap.add_argument("--defensive", type=float, default=None,
                    help="converge's share of the BSDF in its mixture (default: DEFENSIVE)")
    ap.add_argument("--no-control", action="store_true",
                    help="converge without the relit frame as control variate")
    ap.add_argument("--candidates", type=int, default=None,
                    help="converge's candidates per resampled camera sample, 0: none (default: CANDIDATES)")
    ap.add_argument("--coherence", type=float, default=None,
                    help="converge resamples where the footprint's spread exceeds this times the lobe's width "
                         "(default: COHERENCE; 0: every camera sample)")
    args = rc.parse(ap, "relight_converge", 0)
    started = rc.begin(args)
    knobs = {k: v for k, v in (("levels", args.product_levels), ("light", args.light), ("defensive", args.defensive),
                                ("candidates", args.candidates), ("coherence", args.coherence)) if v is not None}
    if args.no_control:
        knobs["control"] = False
    import wavlight
    from wavlight.evaluation.metrics import relmse
    from wavlight.relight.converge import converge

    import relmse as relmse_bench   # benchmarks/relmse.py: floor_image

    spps = [int(s) for s in args.spp.split(",") if s]
    slots = [int(k) for k in args.slots.split(",") if k]
    conv = [f"converge_s{k}" for k in slots]
    methods = conv + ["mis", "wavelet"] + ([] if args.no_stratified else
                                                               ["mis_stratified", "wavelet_stratified"])
    t_start = time.perf_counter()
    out = {}
    for name in SCENES:
        if args.only and args.only not in name:
            continue
        base = rc.scene_dict(name)
        scene = rc.load(base)
        turned_dict = rc.lit(base, args.rotation)
        turned = rc.load(turned_dict)
        ref, ref_err, ref_info = rc.cached_reference(turned_dict, args.size, args.ref_spp)
        transfer, bake_info = rc.cached_bake(base, args.size, args.bake_spp)
        m = transfer.measured
        print(f"{name}: reference {args.ref_spp} spp (noise {rc.reference_noise(ref, ref_err):.4f}), bake n="
              f"{transfer.n_levels} K={transfer.terms} {transfer.priority} {m.get('bake_seconds')} s", file=sys.stderr,
              flush=True)
        # compile every variant once, untimed
        for strategy in ("mis", "wavelet"):
            for sampler in ("independent", "stratified"):
                wavlight.render_full(turned, spp=1, strategy=strategy, width=8, height=8, sampler=sampler)
        converge(transfer, scene, rotate_y=args.rotation, spp=1, seed=99, **knobs)

        region = regions(turned, args.size)

        def run(method, spp, seed):
            t0 = time.perf_counter()
            if method.startswith("converge"):
                r = converge(transfer, scene, rotate_y=args.rotation, spp=spp, seed=seed,
                             slots=int(method[len("converge_s"):]), **knobs)
                seconds = time.perf_counter() - t0
            else:
                strategy, _, sampler = method.partition("_")
                r = wavlight.render_full(turned, spp=spp, strategy=strategy, width=args.size, height=args.size,
                                         seed=seed, sampler=sampler or "independent")
                seconds = r.stats["setup_seconds"] + r.stats["render_seconds"]
            return relmse(r.image, ref, ref_err), seconds, r

        def by_region(image):
            c = (((image - ref) ** 2 - ref_err ** 2) / (ref ** 2 + rc.EPS)).mean(2)
            return {k: float(c[m].sum() / c.size) for k, m in region.items()}

        row = {"reference": {**ref_info, "noise_rel_l2": rc.reference_noise(ref, ref_err)},
               "bake": {"n_levels": transfer.n_levels, "terms": transfer.terms, "priority": transfer.priority,
                        "bake_seconds": m.get("bake_seconds"), "pilot_seconds": m.get("pilot_seconds"),
                        "rays": m.get("rays"), "file_bytes": transfer.file_bytes,
                        "bake_load_average": bake_info.get("load_average"), "cached": bake_info["cached"]},
               "methods": {k: {} for k in methods}}
        for spp in spps:
            errs, secs, extra = {k: [] for k in methods}, {k: [] for k in methods}, {}
            parts = {k: [] for k in methods}
            for seed in range(args.seeds):
                for method in methods:   # interleaved seed by seed: a burst of load slows all alike
                    e, s, r = run(method, spp, seed)
                    errs[method].append(e)
                    secs[method].append(s)
                    parts[method].append(by_region(r.image))
                    if method == "wavelet":
                        extra["wavelet_budget"] = {k: r.stats.get(k) for k in
                                                   ("wavelet_candidates", "wavelet_slots", "visibility_variance")}
                    if method.startswith("converge"):
                        extra.setdefault(f"{method}_rays", []).append(r.stats["rays"])
                        extra[f"{method}_resampled"] = r.stats["resampled_share"]
            for method in methods:
                e = errs[method]
                row["methods"][method][str(spp)] = {
                    **rc.mean_sd(e), "relmse_seeds": [float(x) for x in e], "seconds": float(np.median(secs[method])),
                    "relmse_by_region": {k: float(np.mean([p[k] for p in parts[method]])) for k in region},
                    **({"rays": int(np.mean(extra[f"{method}_rays"])), "resampled_share": extra[f"{method}_resampled"]}
                       if f"{method}_rays" in extra else {})}
            row.setdefault("wavelet_budget", {})[str(spp)] = extra.get("wavelet_budget")
            w = row["methods"]["wavelet"][str(spp)]
            bake_s = m.get("bake_seconds") or 0.0
            for method in methods:
                c = row["methods"][method][str(spp)]
                c["over_wavelet_equal_spp"] = c["relmse"] / w["relmse"]
                c["over_wavelet_equal_time"] = c["relmse"] * c["seconds"] / (w["relmse"] * w["seconds"])
                if method.startswith("converge"):
                    c["seconds_amortized"] = c["seconds"] + bake_s / args.frames
                    c["over_wavelet_equal_time_amortized"] = (c["relmse"] * c["seconds_amortized"]
                                                              / (w["relmse"] * w["seconds"]))
            print(f"{name} spp {spp}: " + " ".join(f"{k}={row['methods'][k][str(spp)]['relmse']:.3e}" for k in methods),
                  file=sys.stderr, flush=True)
        if args.floor > 1:
            d, s = args.floor, args.floor_spp
            floors = {}
            for sampler, mis_key in (("independent", "mis"), ("stratified", "mis_stratified")):
                if mis_key not in methods:
                    continue
                mis_at = row["methods"][mis_key].get(str(s))
                if mis_at is None:
                    mis_at = {"relmse": float(np.mean([run(mis_key, s, seed)[0] for seed in range(args.seeds)]))}
                t0 = time.perf_counter()
                e_d = [relmse(relmse_bench.floor_image(turned, s, args.size, seed, d, sampler), ref, ref_err)
                       for seed in range(args.seeds)]
                fl = rc.mean_sd([(d * e - mis_at["relmse"]) / (d - 1) for e in e_d])
                mean = fl["relmse"] = max(0.0, fl["relmse"])
                wav = row["methods"]["wavelet" if sampler == "independent" else "wavelet_stratified"].get(str(s))
                floors[sampler] = {**fl, "over_mis": mean / mis_at["relmse"],
                                   "over_wavelet": mean / row["methods"]["wavelet"][str(s)]["relmse"]
                                   if str(s) in row["methods"]["wavelet"] else None,
                                   "over_wavelet_same_sampler": mean / wav["relmse"] if wav else None,
                                   "seconds": round(time.perf_counter() - t0, 1)}
            row["footprint_floor"] = {"spp": s, "directions": d, **floors}
        if str(args.floor_spp) in row["methods"]["wavelet"]:
            s = str(args.floor_spp)
            floor = row.get("footprint_floor", {})
            t = row["target"] = {
                "spp": args.floor_spp, "target": 1 / 3,
                **{f"{k}_over_wavelet": row["methods"][k][s]["over_wavelet_equal_spp"] for k in conv},
                "floor_stratified_over_wavelet": floor.get("stratified", {}).get("over_wavelet"),
                "floor_independent_over_wavelet": floor.get("independent", {}).get("over_wavelet")}
            t["met"] = bool(min(t[f"{k}_over_wavelet"] for k in conv) <= 1 / 3)
        out[name] = row
        transfer.close()

    # tables
    lines = []
    for name, row in out.items():
        for spp in spps:
            cells = {"scene": name, "spp": spp}
            for method in methods:
                c = row["methods"][method][str(spp)]
                cells[method] = f"{c['relmse']:.3e}/{c['seconds']:.2f}s"
            c2 = row["methods"][conv[0]][str(spp)]
            cells["conv/wav spp"] = f"{c2['over_wavelet_equal_spp']:.3f}"
            cells["conv/wav time"] = f"{c2['over_wavelet_equal_time']:.3f}"
            cells[f"amortized/{args.frames}"] = f"{c2['over_wavelet_equal_time_amortized']:.3f}"
            lines.append(cells)
    print(f"relMSE / seconds (median of seeds); {conv[0]} over wavelet at equal spp, equal time, "
          f"equal time with the bake amortized over {args.frames} frames")
    print(rc.table(lines, ["scene", "spp", *methods, "conv/wav spp", "conv/wav time", f"amortized/{args.frames}"]))
    print(f"\nfootprint floor at {args.floor_spp} spp (D = {args.floor}) and the 1/3 target")
    frows = []
    for name, row in out.items():
        f = row.get("footprint_floor", {})
        t = row.get("target", {})
        frows.append({"scene": name, **{f"{k}/wavelet": t.get(f"{k}_over_wavelet") for k in conv},
                      "floor_indep/wavelet": f.get("independent", {}).get("over_wavelet"),
                      "floor_strat/wavelet": f.get("stratified", {}).get("over_wavelet"),
                      "floor_strat/wavelet_strat": f.get("stratified", {}).get("over_wavelet_same_sampler"),
                      "floor_indep": f.get("independent", {}).get("relmse"),
                      "floor_strat": f.get("stratified", {}).get("relmse"), "met": t.get("met")})
    print(rc.table(frows, list(frows[0]) if frows else ["scene"]))
    rc.finish(args.output, {"size": args.size, "spp": spps, "seeds": args.seeds, "ref_spp": args.ref_spp,
                            "bake_spp": args.bake_spp, "rotation": args.rotation, "amortized_frames": args.frames,
                            "floor_directions": args.floor, "floor_spp": args.floor_spp, "methods": methods,
                            "seconds": round(time.perf_counter() - t_start, 1), "scenes": out}, started)


if __name__ == "__main__":
    main()
