"""Frames from a moving camera (wavlight.relight.view_frames) on the bunny of benchmarks/scenes/bunny_ggx.toml and
its rough variants: per scene, the view bake at the automatic choice (levels from the pilot, the
default cache) and per frame mode its approximate frame's relative L2 error against a converged
``mis`` render from the same camera, split into bunny / floor / background, raw and with the
reference's noise taken out in quadrature (sqrt(max(e^2 - s^2, 0)) / |R|, s^2 the sum of the
reference's stderr^2 over the region), beside the reference's own noise (s / |R|), with one
centre ray per pixel and with S x S centre rays box-filtered (``mis`` integrates over the pixel's
footprint, and the bunny's facets are smaller than a pixel: one ray per pixel aliases their
highlights, an error of the sampling, not of the shading); and the
frame's time at --size x --size (median of --frames after one untimed frame, with its parts:
camera rays, cache lookup, the product kernel, assembly).

Scenes (dicts, benchmarks/relight_common.py): ``bunny_ggx`` (ggx 0.2 gold, the scene file),
``bunny_ggx05`` (the same bunny in ggx roughness 0.5), ``bunny_lambert`` (lambert 0.7), all on
the lambert floor under the park with its sun. The camera is the scene's eye turned --turn
degrees about the target (a view the scene file does not have). The error is measured at
--error-size against ``mis`` at --mis-spp (cached in /tmp/relight-bench/references); the bakes
are cached in /tmp/relight-bench/view-bakes (keyed by the scene, the settings and the bake's
sources).

    python benchmarks/relight_view.py [--scenes bunny_ggx,bunny_ggx05,bunny_lambert]
        [--modes point,point:0:0.15:0,pixel,pixel:0.1:0.15:0] [--size 512] [--error-size 256] [--supersample 1,4]
        [--mis-spp 1024] [--frames 15] [--still-frames 3]
        [--levels auto] [--refine 0.6] [--turn 40] [-o FILE]

Each scene's written frame (``wavlight frame``'s settings, view_frames.STILL: ``pixel`` at 4 x 4 rays)
is timed at --size too.

The figures in benchmarks/results/relight_view.json come from the defaults.
"""
from __future__ import annotations

import copy
import hashlib
import inspect
import json
import os
import statistics
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import relight_common as common  # noqa: E402

PARTS = ("rays_seconds", "lookup_seconds", "product_seconds", "assembly_seconds", "frame_seconds")
ENV = "rooitou_park_1k"


def bunny_ggx05() -> dict:
    d = common.bunny_ggx(ENV)
    d["materials"]["gold"] = dict(d["materials"]["gold"], roughness=0.5)
    return d


SCENES = {"bunny_ggx": lambda: common.bunny_ggx(ENV), "bunny_ggx05": bunny_ggx05,
          "bunny_lambert": lambda: common.bunny_lambert(ENV)}


def turned(d: dict, degrees: float) -> dict:
    """The dict with its eye turned ``degrees`` about the vertical through the target."""
    from wavlight.relight import view_frames

    d = copy.deepcopy(d)
    cam = d["camera"]
    eye = view_frames.orbit_eyes(cam["eye"], cam["target"], max(1, round(360.0 / degrees)))[1]
    cam["eye"] = [float(x) for x in eye]
    return d


def bake_key(d: dict, levels) -> str:
    from wavlight.relight import surface_cache, view_bake

    src = "".join(inspect.getsource(f) for f in (surface_cache.build_cache, view_bake._point_samples,
                                                  view_bake.point_transfer, view_bake._bake_block,
                                                  view_bake.bake_view))
    h = hashlib.sha256(json.dumps([d, levels, common.source_hash(common.BAKE_SOURCES), src],
                                  sort_keys=True, default=str).encode())
    return h.hexdigest()[:20]


def cached_view_bake(d: dict, levels):
    """(Transfer, info) of the view bake of ``d``, from the cache or made by this call."""
    import wavlight

    folder = os.path.join(common.CACHE, "view-bakes")
    os.makedirs(folder, exist_ok=True)
    key = bake_key(d, levels)
    path, side = os.path.join(folder, f"{key}.wlt"), os.path.join(folder, f"{key}.json")
    if os.path.exists(path) and os.path.exists(side):
        with open(side) as fh:
            return wavlight.Transfer.load(path), dict(json.load(fh), cached=True)
    t0 = time.perf_counter()
    tr = wavlight.bake(common.load(d), path, vary="view", levels=levels)
    info = {"wall_seconds": round(time.perf_counter() - t0, 3), "load_average": common.load_average()}
    with open(side, "w") as fh:
        json.dump(info, fh)
    return tr, dict(info, cached=False)


def regions(frames, d: dict, size: int) -> dict:
    """Masks (size, size) of the pixels whose centre ray hits the bunny, the floor, nothing."""
    import wavlight

    scene = common.load(d)
    pix = np.arange(size * size)
    o, dirs = wavlight.camera.camera_rays(scene, pix % size, pix // size, np.full((len(pix), 2), 0.5, np.float32),
                                          size, size)
    prim, _ = frames.tracer.intersect(o, dirs)
    mat = np.where(prim >= 0, scene.face_material[np.maximum(prim, 0)], -1)
    floor = scene.face_material[-1]
    return {"bunny": ((prim >= 0) & (mat != floor)).reshape(size, size),
            "floor": ((prim >= 0) & (mat == floor)).reshape(size, size),
            "background": (prim < 0).reshape(size, size), "all": np.ones((size, size), bool)}


def region_errors(image, ref, stderr, masks: dict) -> dict:
    """Per region: relative L2 raw, noise-corrected, and the reference's noise."""
    x, r, s = (np.asarray(a, np.float64) for a in (image, ref, stderr))
    out = {}
    for name, m in masks.items():
        e2, n2, s2 = float(((x - r)[m] ** 2).sum()), float((r[m] ** 2).sum()), float((s[m] ** 2).sum())
        n2 = max(n2, 1e-300)
        out[name] = {"raw": np.sqrt(e2 / n2), "corrected": np.sqrt(max(e2 - s2, 0.0) / n2),
                     "noise": np.sqrt(s2 / n2), "pixels": int(m.sum())}
    return out


def main():
    ap = common.parser(__doc__)
    ap.add_argument("--scenes", default="bunny_ggx,bunny_ggx05,bunny_lambert")
    ap.add_argument("--modes", default="point,point:0:0.15:0,pixel,pixel:0.1:0.15:0",
                    help="the approximate frame's settings (ViewFrames.frame), MODE[:TAU[:REFINE[:MASS]]] (TAU: the "
                         "pixel mode's cosine correction, 0 none, default view_frames.TAU; REFINE default "
                         "--refine; MASS default view_walk.MASS, 0 the walk by the lobe alone)")
    ap.add_argument("--still-frames", type=int, default=3, help="timed written frames (view_frames.STILL) per scene")
    ap.add_argument("--size", type=int, default=512, help="timed frames: width and height")
    ap.add_argument("--error-size", type=int, default=256, help="the error's frames and references: width, height")
    ap.add_argument("--mis-spp", type=int, default=1024, help="samples per pixel of the mis references")
    ap.add_argument("--supersample", default="1,4",
                    help="the error's frames at S x S centre rays per pixel (box-filtered), per S: mis integrates "
                         "over the pixel, and the bunny's facets are smaller than a pixel")
    ap.add_argument("--frames", type=int, default=15, help="timed frames per setting")
    ap.add_argument("--levels", default="auto", help="texel levels n of the bakes, or auto (the pilot's)")
    ap.add_argument("--refine", type=float, default=None, help="the walk's refine (default view_walk.REFINE)")
    ap.add_argument("--turn", type=float, default=40.0, help="degrees the eye turns about the target")
    args = common.parse(ap, "relight_view", 0.0)
    started = common.begin(args)
    from wavlight.relight import view_frames, view_walk

    refine = view_walk.REFINE if args.refine is None else args.refine
    levels = None if args.levels == "auto" else int(args.levels)
    rows, scenes = [], {}
    for name in [s for s in args.scenes.split(",") if s]:
        d = turned(SCENES[name](), args.turn)
        ref, stderr, rinfo = common.cached_reference(d, args.error_size, args.mis_spp)
        tr, binfo = cached_view_bake(d, levels)
        summary = tr.summary()
        frames = view_frames.ViewFrames(tr, common.load(d))
        cam = frames.scene.camera
        masks = regions(frames, d, args.error_size)
        scenes[name] = {"eye": cam.eye.tolist(), "target": cam.target.tolist(), "material": d["materials"]["gold"],
                        "n_levels": tr.n_levels, "cache_points": summary["cache"]["points"],
                        "spacing": summary["cache"]["spacing"], "bake_seconds": summary["bake_seconds"],
                        "bake_cached": binfo["cached"], "file_bytes": summary["file_bytes"],
                        "compression_error": summary["measured"]["compression_error"],
                        "reference": {"spp": args.mis_spp, "size": args.error_size, "cached": rinfo["cached"],
                                      "wall_seconds": rinfo.get("wall_seconds")}}
        for spec in [m for m in args.modes.split(",") if m]:
            mode, tau, ref_, mass = (spec.split(":") + ["", "", ""])[:4]
            opts = {"refine": float(ref_) if ref_ else refine, "mode": mode,
                    "tau": float(tau) if tau else view_frames.TAU, "mass": float(mass) if mass else view_walk.MASS}
            err = {}
            for ss in sorted({1, *[int(x) for x in args.supersample.split(",") if x]}):
                big = args.error_size * ss
                image, _ = frames.frame(cam.eye, cam.target, cam.fov_y, big, big, **opts)
                image = image.reshape(args.error_size, ss, args.error_size, ss, 3).mean((1, 3))
                err[f"ss{ss}"] = region_errors(image, ref, stderr, masks)
            frames.frame(cam.eye, cam.target, cam.fov_y, args.size, args.size, **opts)   # untimed: the build
            stats = [frames.frame(cam.eye, cam.target, cam.fov_y, args.size, args.size, **opts)[1]
                     for _ in range(args.frames)]
            med = {p: statistics.median(s[p] for s in stats) for p in PARTS}
            rows.append({"scene": name, "mode": mode, "tau": opts["tau"] if mode == "pixel" else None,
                         "refine": opts["refine"], "mass": opts["mass"], "errors": err, **med,
                         "frames_per_second": 1.0 / med["frame_seconds"],
                         "items_shaded": stats[-1]["cache_points_shaded"],
                         "nodes_per_item": stats[-1]["nodes_per_point"]})
            for ss, e in err.items():
                print(f"{name:14s} {spec:16s} {ss:4s} fps {rows[-1]['frames_per_second']:5.2f}  "
                      + "  ".join(f"{k} {v['raw']:.4f}/{v['corrected']:.4f} (noise {v['noise']:.4f})"
                                  for k, v in e.items()), flush=True)
        frames.frame(cam.eye, cam.target, cam.fov_y, args.size, args.size, **view_frames.STILL)   # untimed: the build
        stats = [frames.frame(cam.eye, cam.target, cam.fov_y, args.size, args.size, **view_frames.STILL)[1]
                 for _ in range(args.still_frames)]
        scenes[name]["still"] = dict(view_frames.STILL, **{p: statistics.median(s[p] for s in stats) for p in PARTS})
        still = view_frames.STILL
        print(f"{name:14s} written frame ({still['mode']}, {still['supersample']}^2 rays) at {args.size}^2: "
              f"{scenes[name]['still']['frame_seconds']:.3f} s", flush=True)
        tr.close()
    data = {"size": args.size, "error_size": args.error_size, "supersample": args.supersample, "mis_spp": args.mis_spp, "turn": args.turn,
            "environment": ENV, "scenes": scenes, "rows": common.rounded(rows)}
    print(common.finish(args.output, data, started))


if __name__ == "__main__":
    main()
