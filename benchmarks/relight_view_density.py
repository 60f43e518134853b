"""Frames from a moving camera over the surface cache's density and the walk's terms: the
approximate frame's relative L2 error against converged ``mis`` against its frame time.

Scenes (benchmarks/relight_view.py): the rough bunnies, ``bunny_ggx05`` (ggx 0.5) and
``bunny_lambert``, on the lambert floor under the park with its sun, seen from the scene's eye
turned --turn degrees about the target. Per scene and cache of --points points over the scene's
area (``wavlight.relight.view_bake.bake_view``'s ``cache_points``; the default cache is
wavlight.relight.settings.CACHE_POINTS) at --levels texel levels, and per walk refine in --refines (the walk's
terms: a node is refined where the BRDF varies over it by more than refine; smaller refines
walk more nodes per point) with the walk's --mass (view_walk.MASS by default; 0: by the lobe alone),
the ``point`` frame at one ray per pixel: its relative L2 error
against ``mis`` at --mis-spp (the reference's noise taken out in quadrature; over the whole
image and over the bunny) at --error-size, and its time at --size (median of --frames after one
untimed frame), with the nodes walked per point.

Chart: docs/figures/relight-view-error.png and .svg, error against frame time, a line per
cache, points labelled by refine. Bakes are cached in /tmp/relight-bench/view-bakes.

    python benchmarks/relight_view_density.py [--scenes bunny_ggx05,bunny_lambert]
        [--points 4096,16384,65536] [--levels 6] [--refines 0.6,0.3,0.15,0.08] [--mass M] [--size 512]
        [--error-size 256] [--mis-spp 1024] [--frames 9] [--turn 40] [--figure STEM] [-o FILE]

The figures in benchmarks/results/relight_view_density.json come from the defaults.
"""
from __future__ import annotations

import hashlib
import json
import os
import statistics
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import relight_common as common  # noqa: E402
import relight_view as rv  # noqa: E402

FIGURE = os.path.join(HERE, "..", "docs", "figures", "relight-view-error")


def cached_bake(d: dict, levels: int, points: int):
    """(Transfer, info) of the view bake of ``d`` with a cache of ``points`` points."""
    import wavlight
    from wavlight.relight import view_bake

    folder = os.path.join(common.CACHE, "view-bakes")
    os.makedirs(folder, exist_ok=True)
    key = hashlib.sha256(f"{rv.bake_key(d, levels)}/{points}".encode()).hexdigest()[:20]
    path, side = os.path.join(folder, f"d{key}.wlt"), os.path.join(folder, f"d{key}.json")
    if os.path.exists(path) and os.path.exists(side):
        with open(side) as fh:
            return wavlight.Transfer.load(path), dict(json.load(fh), cached=True)
    t0 = time.perf_counter()
    tr = view_bake.bake_view(common.load(d), path, levels=levels, cache_points=points)
    info = {"wall_seconds": round(time.perf_counter() - t0, 3), "load_average": common.load_average()}
    with open(side, "w") as fh:
        json.dump(info, fh)
    return tr, dict(info, cached=False)


def chart(rows, path_stem) -> list:
    from matplotlib import ticker
    from matplotlib.figure import Figure

    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    fig = Figure(figsize=(5.2 * len(scenes), 4.2), layout="constrained")
    axes = fig.subplots(1, len(scenes), squeeze=False)[0]
    for ax, scene in zip(axes, scenes):
        for points in sorted({r["cache_points_asked"] for r in rows if r["scene"] == scene}):
            sel = sorted((r for r in rows if r["scene"] == scene and r["cache_points_asked"] == points),
                         key=lambda r: r["frame_seconds"])
            x = [1e3 * r["frame_seconds"] for r in sel]
            y = [100 * r["error_all"] for r in sel]
            ax.plot(x, y, marker="o", label=f"{points:,} asked, {sel[0]['cache_points']:,} cache points")
            for r, xi, yi in zip(sel, x, y):
                ax.annotate(f"{r['refine']:g}", (xi, yi), textcoords="offset points", xytext=(3, 3), fontsize=7)
        ax.axhline(3.0, color="grey", ls="--", lw=0.8)
        ax.text(ax.get_xlim()[0], 3.0, " target 3%", va="bottom", fontsize=7, color="grey")
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(ticker.FormatStrFormatter("%g"))
        ax.xaxis.set_minor_formatter(ticker.FormatStrFormatter("%g"))
        ax.set_xlabel("frame time at 512² (ms)")
        ax.set_ylabel("relative L2 error, whole image (%)")
        ax.set_title(scene, fontsize=9)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle("View frames (point mode, one ray per pixel) against converged mis; points labelled by refine",
                 fontsize=9)
    out = []
    for ext in ("png", "svg"):
        fig.savefig(f"{path_stem}.{ext}", dpi=130)
        out.append(f"{path_stem}.{ext}")
    return out


def main():
    ap = common.parser(__doc__)
    ap.add_argument("--scenes", default="bunny_ggx05,bunny_lambert")
    ap.add_argument("--points", default="4096,16384,65536", help="cache points over the scene's area")
    ap.add_argument("--levels", type=int, default=6, help="texel levels n of the bakes")
    ap.add_argument("--refines", default="0.6,0.3,0.15,0.08", help="the walk's refine values")
    ap.add_argument("--mass", type=float, default=None,
                    help="the walk's mass (default view_walk.MASS; 0: by the lobe alone)")
    ap.add_argument("--size", type=int, default=512, help="timed frames: width and height")
    ap.add_argument("--error-size", type=int, default=256, help="the error's frames and references")
    ap.add_argument("--mis-spp", type=int, default=1024, help="samples per pixel of the mis references")
    ap.add_argument("--frames", type=int, default=9, help="timed frames per setting")
    ap.add_argument("--turn", type=float, default=40.0, help="degrees the eye turns about the target")
    ap.add_argument("--figure", default=FIGURE, help="chart path without extension")
    args = common.parse(ap, "relight_view_density", 0.0)
    started = common.begin(args)
    from wavlight.relight import view_frames, view_walk

    mass = view_walk.MASS if args.mass is None else args.mass

    rows, bakes = [], []
    for name in [s for s in args.scenes.split(",") if s]:
        d = rv.turned(rv.SCENES[name](), args.turn)
        ref, stderr, _ = common.cached_reference(d, args.error_size, args.mis_spp)
        for points in [int(x) for x in args.points.split(",") if x]:
            tr, info = cached_bake(d, args.levels, points)
            summary = tr.summary()
            bakes.append({"scene": name, "cache_points_asked": points, "cache_points": summary["cache"]["points"],
                          "spacing": summary["cache"]["spacing"], "n_levels": tr.n_levels,
                          "bake_seconds": summary["bake_seconds"], "file_bytes": summary["file_bytes"],
                          "cached": info["cached"]})
            frames = view_frames.ViewFrames(tr, common.load(d))
            cam = frames.scene.camera
            masks = rv.regions(frames, d, args.error_size)
            for refine in [float(x) for x in args.refines.split(",") if x]:
                image, _ = frames.frame(cam.eye, cam.target, cam.fov_y, args.error_size, args.error_size,
                                        mode="point", refine=refine, mass=mass)
                err = rv.region_errors(image, ref, stderr, masks)
                frames.frame(cam.eye, cam.target, cam.fov_y, args.size, args.size, mode="point", refine=refine,
                             mass=mass)
                stats = [frames.frame(cam.eye, cam.target, cam.fov_y, args.size, args.size, mode="point",
                                      refine=refine, mass=mass)[1] for _ in range(args.frames)]
                row = {"scene": name, "cache_points_asked": points, "cache_points": summary["cache"]["points"],
                       "refine": refine, "mass": mass, "error_all": err["all"]["corrected"],
                       "error_bunny": err["bunny"]["corrected"],
                       "error_floor": err["floor"]["corrected"],
                       "frame_seconds": statistics.median(s["frame_seconds"] for s in stats),
                       "nodes_per_point": stats[-1]["nodes_per_point"]}
                rows.append(row)
                print(f"{name:14s} {points:7d} points refine {refine:5.2f}: {1e3 * row['frame_seconds']:6.1f} ms, "
                      f"error {row['error_all']:.4f} (bunny {row['error_bunny']:.4f}), "
                      f"{row['nodes_per_point']:.0f} nodes/point", flush=True)
            tr.close()
    figures = chart(rows, args.figure)
    data = {"size": args.size, "error_size": args.error_size, "mis_spp": args.mis_spp, "turn": args.turn,
            "levels": args.levels, "environment": rv.ENV, "bakes": bakes, "rows": common.rounded(rows),
            "figures": [os.path.relpath(f, os.path.join(HERE, "..")) for f in figures]}
    print(common.finish(args.output, data, started))


if __name__ == "__main__":
    main()
