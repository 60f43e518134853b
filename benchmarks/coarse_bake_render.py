"""One static render made of a coarse lighting bake plus one unbiased frame, the bake counted in
full, against the ``wavelet`` strategy at equal wall time (Chen & Gao sec. 2, eq. 6-8 and 12:
once T1 is baked, sampling T1 x T2 puts the visibility inside the sampled product; the question
here is whether that pays when T1 is made for a single image).

Scenes (shadowed; each rendered as it is, its map at its own rotation):

- ``bunny_st_fagans``: benchmarks/scenes/bunny_ggx.toml under st_fagans_interior_1k turned to 120
  degrees (glossy gold bunny, many small lights);
- ``spot_sun``: Spot in lambert on a floor under the rooitou park's low sun turned to 30 degrees
  (hard shadows);
- ``dragon`` (with --dragon): benchmarks/scenes/dragon_phong.toml (phong jade dragon under
  st_fagans at 60 degrees).

Per scene and image size (--sizes):

- ``wavelet`` at each of --wavelet-spp samples per pixel, --seeds seeds, --sampler's pixel samples:
  setup_seconds + render_seconds (the scene loaded before, as for the bake);
- ``baked`` per bake setting (--bakes: ``SPPxLEVELS`` or ``SPPxLEVELSxTOLERANCE``): the bake
  (wavlight.bake with every model choice given, so no pilot: spp camera samples, 2^levels
  texels, the compression's tolerance; in a temporary file) timed in full, then per frame spp of
  --frame-spp a new ConvergeFrames (setup) and its first frame: total = bake + setup + frame.

Errors: relMSE against ``mis`` at --ref-spp (noise-corrected, wavlight.evaluation.metrics.relmse;
cached in /tmp/relight-bench/). The equal-time ratio of a baked run: its relMSE over wavelet's
relMSE at the same total seconds, wavelet's interpolated log-log between its measured spp (and
extrapolated with relMSE x seconds constant beyond them). Below 1 the coarse bake wins. Also the
asymptotic efficiency ratio (relMSE x frame seconds without the bake over wavelet's relMSE x
seconds) and the break-even time: the total seconds above which the baked render wins
(bake / (1 - efficiency ratio), none when the frame alone loses).

    python benchmarks/coarse_bake_render.py [--sizes 256] [--wavelet-spp 4,16,64] [--frame-spp 4,16,64]
        [--bakes 1x4,2x4,4x4,1x5,2x5,4x5] [--seeds 2] [--ref-spp 2048] [--sampler independent|stratified]
        [--dragon] [--only SUBSTR]
        [--wait-load 1.0] [--wait-minutes 0] [-o FILE]

The figures in benchmarks/results/coarse_bake_render.json come from the command recorded in
its provenance.
"""
from __future__ import annotations

import os
import statistics
import sys
import time
import tomllib

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import relight_common as rc  # noqa: E402

#: (scene, its dict's maker, rotation of its map)
SCENES = [("bunny_st_fagans", lambda: rc.scene_dict("bunny_ggx/st_fagans_interior_1k"), 120.0),
          ("spot_sun", lambda: rc.scene_dict("spot_lambert/rooitou_park_1k"), 30.0)]


def dragon() -> dict:
    with open(os.path.join(HERE, "scenes", "dragon_phong.toml"), "rb") as fh:
        return tomllib.load(fh)


def bake_settings(text: str) -> list:
    """'1x4,2x5x0.05' -> [(1, 4, 0.02), (2, 5, 0.05)]: camera samples, texel levels, tolerance."""
    out = []
    for item in text.split(","):
        parts = item.split("x")
        out.append((int(parts[0]), int(parts[1]), float(parts[2]) if len(parts) > 2 else 0.02))
    return out


def wavelet_at(curve, seconds: float) -> float:
    """wavelet's relMSE at ``seconds``: log-log interpolation between its measured (seconds,
    relMSE) points (sorted by seconds), relMSE x seconds constant beyond them."""
    t = np.array([p[0] for p in curve])
    e = np.array([p[1] for p in curve])
    if seconds <= t[0]:
        return float(e[0] * t[0] / seconds)
    if seconds >= t[-1]:
        return float(e[-1] * t[-1] / seconds)
    return float(np.exp(np.interp(np.log(seconds), np.log(t), np.log(e))))


def main():
    ap = rc.parser(__doc__)
    ap.add_argument("--sizes", default="256", help="image widths and heights, comma-separated")
    ap.add_argument("--wavelet-spp", default="4,16,64", help="wavelet's samples per pixel, comma-separated")
    ap.add_argument("--frame-spp", default="4,16,64", help="the unbiased frame's samples per pixel, comma-separated")
    ap.add_argument("--bakes", default="1x4,2x4,4x4,1x5,2x5,4x5",
                    help="bake settings SPPxLEVELS[xTOLERANCE], comma-separated")
    ap.add_argument("--seeds", type=int, default=2, help="renders per wavelet spp and per baked setting")
    ap.add_argument("--ref-spp", type=int, default=2048, help="samples per pixel of the mis reference")
    ap.add_argument("--sampler", default="independent", choices=("independent", "stratified"),
                    help="wavelet's pixel samples (the unbiased frame's camera samples are stratified)")
    ap.add_argument("--dragon", action="store_true", help="also the dragon (its reference rendered if not cached)")
    ap.add_argument("--only", default="", help="substring filter on scene names")
    args = rc.parse(ap, "coarse_bake_render", 0)
    started = rc.begin(args)
    import wavlight
    from wavlight.evaluation.metrics import relmse
    from wavlight.relight import converge as cm

    sizes = [int(s) for s in args.sizes.split(",") if s]
    wav_spp = [int(s) for s in args.wavelet_spp.split(",") if s]
    frame_spp = [int(s) for s in args.frame_spp.split(",") if s]
    bakes = bake_settings(args.bakes)
    scenes = list(SCENES) + ([("dragon", dragon, 60.0)] if args.dragon else [])
    t_start = time.perf_counter()
    out = {}
    for name, make, rotation in scenes:
        if args.only and args.only not in name:
            continue
        d = rc.lit(make(), rotation)
        scene = rc.load(d)
        out[name] = {"rotate_y": rotation, "sizes": {}}
        for size in sizes:
            ref, ref_err, ref_info = rc.cached_reference(d, size, args.ref_spp)
            noise = rc.reference_noise(ref, ref_err)
            print(f"{name} {size}: reference {args.ref_spp} spp (noise {noise:.4f}), load {rc.load_average()}",
                  file=sys.stderr, flush=True)
            wavlight.render_full(scene, spp=1, strategy="wavelet", width=8, height=8)   # compile, untimed
            wav = {s: {"seconds": [], "relmse": []} for s in wav_spp}
            baked = {b: {"bake_seconds": [], "setup_seconds": [], "entries": None, "file_bytes": None,
                         "frames": {s: {"seconds": [], "relmse": [], "total": []} for s in frame_spp}} for b in bakes}
            warmed = False
            for seed in range(args.seeds):
                for s in wav_spp:
                    r = wavlight.render_full(scene, spp=s, strategy="wavelet", width=size, height=size, seed=seed,
                                             sampler=args.sampler)
                    wav[s]["seconds"].append(r.stats["setup_seconds"] + r.stats["render_seconds"])
                    wav[s]["relmse"].append(relmse(r.image, ref, ref_err))
                for b in bakes:
                    bspp, levels, tol = b
                    t0 = time.perf_counter()
                    transfer = wavlight.bake(scene, width=size, height=size, spp=bspp, levels=levels, terms=64,
                                             priority="transfer", tolerance=tol, seed=100 + seed)
                    bake_seconds = time.perf_counter() - t0
                    entry = baked[b]
                    entry["bake_seconds"].append(bake_seconds)
                    entry["entries"], entry["file_bytes"] = transfer.measured.get("entries"), transfer.file_bytes
                    if not warmed:   # compile converge's kernels untimed
                        w = cm.ConvergeFrames(transfer, scene)
                        w.frame(None, rotation, spp=1, seed=99)
                        w.close()
                        warmed = True
                    for s in frame_spp:
                        frames = cm.ConvergeFrames(transfer, scene)
                        r = frames.frame(None, rotation, spp=s, seed=seed)
                        seconds = frames.setup_seconds + r.stats["render_seconds"]
                        frames.close()
                        del frames
                        f = entry["frames"][s]
                        f["seconds"].append(seconds)
                        f["total"].append(bake_seconds + seconds)
                        f["relmse"].append(relmse(r.image, ref, ref_err))
                    transfer.close()
                    last = " ".join(f"{s}:{entry['frames'][s]['relmse'][-1]:.2e}/{entry['frames'][s]['seconds'][-1]:.2f}s"
                                    for s in frame_spp)
                    print(f"  {name} {size} seed {seed} bake {bspp} spp {levels} levels tol {tol}: "
                          f"{bake_seconds:.2f} s; frames {last}; load {rc.load_average()}", file=sys.stderr, flush=True)
                print(f"  {name} {size} seed {seed} wavelet " + " ".join(
                    f"{s}:{wav[s]['relmse'][-1]:.2e}/{wav[s]['seconds'][-1]:.2f}s" for s in wav_spp),
                    file=sys.stderr, flush=True)
            wrow = {str(s): {"seconds": float(statistics.median(v["seconds"])), "seconds_seeds": v["seconds"],
                             **rc.mean_sd(v["relmse"]), "relmse_seeds": v["relmse"]} for s, v in wav.items()}
            curve = sorted((w["seconds"], w["relmse"]) for w in wrow.values())
            eff_w = float(np.median([w["seconds"] * w["relmse"] for w in wrow.values()]))
            brow = {}
            for (bspp, levels, tol), entry in baked.items():
                bake_seconds = float(statistics.median(entry["bake_seconds"]))
                frames = {}
                for s, f in entry["frames"].items():
                    total = float(statistics.median(f["total"]))
                    rel = float(np.mean(f["relmse"]))
                    sec = float(statistics.median(f["seconds"]))
                    eff = rel * sec / eff_w
                    frames[str(s)] = {"frame_seconds": sec, "total_seconds": total, **rc.mean_sd(f["relmse"]),
                                      "relmse_seeds": f["relmse"], "total_seeds": f["total"],
                                      "wavelet_relmse_at_total": wavelet_at(curve, total),
                                      "equal_time_over_wavelet": rel / wavelet_at(curve, total),
                                      "efficiency_over_wavelet": eff,
                                      "break_even_seconds": bake_seconds / (1 - eff) if eff < 1 else None}
                brow[f"{bspp}x{levels}x{tol:g}"] = {"spp": bspp, "levels": levels, "tolerance": tol,
                                                    "bake_seconds": bake_seconds,
                                                    "bake_seconds_seeds": entry["bake_seconds"],
                                                    "entries": entry["entries"], "file_bytes": entry["file_bytes"],
                                                    "frames": frames}
            out[name]["sizes"][str(size)] = {
                "reference": {**{k: ref_info.get(k) for k in ("spp", "seed", "cached", "wall_seconds")},
                              "noise_rel_l2": noise},
                "wavelet": wrow, "wavelet_relmse_x_seconds": eff_w, "baked": brow}

    lines = []
    for name, entry in out.items():
        for size, row in entry["sizes"].items():
            for s, w in row["wavelet"].items():
                lines.append({"scene": name, "size": size, "method": "wavelet", "spp": s, "total s": w["seconds"],
                              "relMSE": w["relmse"]})
            for key, b in row["baked"].items():
                for s, f in b["frames"].items():
                    lines.append({"scene": name, "size": size, "method": f"baked {key}", "bake s": b["bake_seconds"],
                                  "spp": s, "total s": f["total_seconds"], "relMSE": f["relmse"],
                                  "eq-time/wav": f["equal_time_over_wavelet"],
                                  "frame eff/wav": f["efficiency_over_wavelet"],
                                  "break-even s": f["break_even_seconds"]})
    print("total seconds = bake + ConvergeFrames setup + frame (baked), setup + render (wavelet); eq-time/wav: "
          "relMSE over wavelet's interpolated at the same total seconds (below 1: the baked render wins)")
    print(rc.table(lines, ["scene", "size", "method", "bake s", "spp", "total s", "relMSE", "eq-time/wav",
                           "frame eff/wav", "break-even s"]))
    rc.finish(args.output, rc.rounded({"sizes": sizes, "wavelet_spp": wav_spp, "frame_spp": frame_spp,
                                       "bakes": [list(b) for b in bakes], "bake_terms": 64, "seeds": args.seeds,
                                       "wavelet_sampler": args.sampler,
                                       "ref_spp": args.ref_spp, "product_levels": cm.PRODUCT_LEVELS, "scenes": out,
                                       "seconds": round(time.perf_counter() - t_start, 1)}), started)


if __name__ == "__main__":
    main()
