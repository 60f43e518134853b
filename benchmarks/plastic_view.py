#!/usr/bin/env python3
"""Plastic in the view bake: what plastic's two lobes cost in a view frame against ggx, and how
close the frames are to ``mis``. A view bake holds T1 = L V cos, no BRDF, so one bake serves both
materials: a sphere on a floor under rooitou_park_1k (the sun), view-baked once, its frames made
with the sphere and the floor in plastic (alpha 0.15 and 0.4, ior 1.5) and in ggx of the same
alphas and albedos, the two alternated within each repeat (a shared machine: the load average is
recorded). Per material, from an eye turned 40 degrees from the bake's camera: the viewer's
frame (``point`` mode, one ray per pixel; ``--point-repeats`` alternated frames after the others),
the written frame (``pixel`` mode, 4 x 4 rays) and the
unbiased frame (``--converge-spp``, the trees of the camera kept after the first repeat), their
seconds (medians over ``--repeats``), the nodes per walk, and the frames' relative L2 error
against ``mis`` (``--ref-spp``; the reference's noise taken out) over the pixels that see a surface,
and the unbiased frame's bias over its standard error (the whole image, per channel), beside
that of a second ``mis`` of another seed (a sun's heavy tail makes the whole image's z wide); and
at ``--check-size`` four unbiased frames pooled against two ``mis`` of 1024 spp (``bias_check``).

Usage:
    python benchmarks/plastic_view.py [--size 256] [--levels 5] [--density 2000] [--repeats 3]
                                      [--converge-spp 16] [--ref-spp 256] [--point-repeats 20] [-o FILE]
Writes benchmarks/results/plastic_view.json (with the run's provenance).
"""
import argparse
import dataclasses
import os
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))

MATERIALS = {"plastic": ({"type": "plastic", "albedo": [0.7, 0.25, 0.1], "alpha": 0.15, "ior": 1.5},
                         {"type": "plastic", "albedo": [0.4, 0.45, 0.5], "alpha": 0.4, "ior": 1.5}),
             "ggx": ({"type": "ggx", "albedo": [0.7, 0.25, 0.1], "roughness": 0.15},
                     {"type": "ggx", "albedo": [0.4, 0.45, 0.5], "roughness": 0.4})}


def scene(materials, size: int, eye=(0.0, 1.5, 3.5)) -> dict:
    return {"render": {"width": size, "height": size, "seed": 1},
            "camera": {"eye": list(eye), "target": [0.0, 0.5, 0.0], "fov_y": 40.0},
            "environment": {"file": "data:rooitou_park_1k"},
            "objects": [{"shape": "sphere", "center": [0.0, 0.6, 0.0], "radius": 0.6, "subdivisions": 5,
                         "material": "ball"},
                        {"shape": "quad", "center": [0.0, 0.0, 0.0], "size": 6.0, "material": "floor"}],
            "materials": {"ball": materials[0], "floor": materials[1]}}


def turned_eye(deg: float = 40.0):
    a = np.radians(deg)
    x, z = 0.0, 3.5
    return [float(x * np.cos(a) + z * np.sin(a)), 1.5, float(-x * np.sin(a) + z * np.cos(a))]


def corrected_error(image, ref, mask) -> float:
    """Relative L2 error against the truth: ||image - ref||^2 less sum(stderr^2), over ||ref||^2."""
    diff = (image - ref.image)[mask].astype(np.float64)
    noise = (ref.stderr[mask].astype(np.float64) ** 2).sum()
    return float(np.sqrt(max((diff ** 2).sum() - noise, 0.0) / (ref.image[mask].astype(np.float64) ** 2).sum()))


def whole_z(a, var_a, b, var_b):
    """The whole image's difference a - b over its standard error, per channel."""
    return [round(float(v), 2) for v in (a - b).sum((0, 1)) / np.sqrt((var_a + var_b).sum((0, 1)))]


def bias_check(wavlight, view_frames, size: int, eye, target, folder) -> dict:
    """Plastic's unbiased view frame at ``size``: four frames of 64 spp (seeds 6-9) pooled, against
    two mis frames of 1024 spp (seeds 8, 9), beside the two mis frames against each other (the
    whole image's z per channel; under a sun mis's standard error is itself too small for it)."""
    base = wavlight.load_dict(scene(MATERIALS["plastic"], size))
    tr = wavlight.bake(base, os.path.join(folder, "check.wlt"), vary="view", levels=5, density=2000, seed=1)
    frames = view_frames.ViewFrames(tr, base)
    refs = [wavlight.render_full(wavlight.load_dict(scene(MATERIALS["plastic"], size, eye)), spp=1024,
                                 strategy="mis", seed=s) for s in (8, 9)]
    runs = [frames.converge(eye, target, spp=64, seed=s) for s in (6, 7, 8, 9)]
    pooled = np.mean([r.image.astype(np.float64) for r in runs], 0)
    var = np.sum([r.stderr.astype(np.float64) ** 2 for r in runs], 0) / len(runs) ** 2
    img = [r.image.astype(np.float64) for r in refs]
    rv = [r.stderr.astype(np.float64) ** 2 for r in refs]
    tr.close()
    return {"size": size, "spp": "4 x 64", "mis_spp": 1024,
            "z_pooled_vs_mis_seed_8": whole_z(pooled, var, img[0], rv[0]),
            "z_pooled_vs_mis_seed_9": whole_z(pooled, var, img[1], rv[1]),
            "z_mis_seed_8_vs_seed_9": whole_z(img[0], rv[0], img[1], rv[1])}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--levels", type=int, default=5)
    ap.add_argument("--density", type=float, default=2000.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--point-repeats", type=int, default=20)
    ap.add_argument("--check-size", type=int, default=96,
                    help="the unbiased frames' check: four frames of 64 spp pooled against two mis of 1024 spp")
    ap.add_argument("--converge-spp", type=int, default=16)
    ap.add_argument("--ref-spp", type=int, default=256)
    sys.path.insert(0, HERE)
    import needs
    from provenance import add_output_argument, provenance, write_result

    add_output_argument(ap, "plastic_view")
    args = ap.parse_args()
    needs.fetch("plastic_view", "rooitou_park_1k")
    prov = provenance()
    import wavlight
    from wavlight.relight import view_frames

    eye = turned_eye()
    target = [0.0, 0.5, 0.0]
    result = {"size": args.size, "levels": args.levels, "density": args.density, "repeats": args.repeats,
              "converge_spp": args.converge_spp, "ref_spp": args.ref_spp, "eye": eye, "load_average_1min": [],
              "materials": {}}
    with tempfile.TemporaryDirectory() as folder:
        base = wavlight.load_dict(scene(MATERIALS["plastic"], args.size))
        tr = wavlight.bake(base, os.path.join(folder, "view.wlt"), vary="view", levels=args.levels,
                           density=args.density, seed=1)
        result["bake_seconds"] = tr.measured.get("bake_seconds")
        result["cache_points"] = tr.measured.get("cache", {}).get("points") if isinstance(
            tr.measured.get("cache"), dict) else None
        frames, refs, times = {}, {}, {k: {"point": [], "pixel": [], "converge": []} for k in MATERIALS}
        for name, mats in MATERIALS.items():
            other = wavlight.load_dict(scene(mats, args.size))
            frames[name] = view_frames.ViewFrames(tr, dataclasses.replace(base, materials=other.materials))
            for mode in ("point", "pixel"):                      # programs built
                frames[name].frame(eye, target, mode=mode, width=16, height=16)
            frames[name].converge(eye, target, spp=1, seed=0, width=16, height=16)
            moved = wavlight.load_dict(scene(mats, args.size, eye))
            refs[name] = wavlight.render_full(moved, spp=args.ref_spp, strategy="mis", seed=7)
            # a second mis of another seed: how far two mis frames lie apart in the same z
            refs[name + "/again"] = wavlight.render_full(moved, spp=args.ref_spp, strategy="mis", seed=8)
        rows = {k: {} for k in MATERIALS}
        for _ in range(args.repeats):
            result["load_average_1min"].append(os.getloadavg()[0])
            for name in MATERIALS:   # alternated
                f = frames[name]
                img, st = f.frame(eye, target, mode="point")
                times[name]["point"].append(st["frame_seconds"])
                rows[name]["point"] = (img, st)
                img, st = f.frame(eye, target, mode="pixel", supersample=4)
                times[name]["pixel"].append(st["frame_seconds"])
                rows[name]["pixel"] = (img, st)
                r = f.converge(eye, target, spp=args.converge_spp, seed=3)
                times[name]["converge"].append(r.stats["render_seconds"])
                rows[name]["converge"] = r
        # the viewer's frame (~50 ms): more repeats, alternated, for its median
        point = {k: [] for k in MATERIALS}
        for _ in range(args.point_repeats):
            for name in MATERIALS:
                point[name].append(frames[name].frame(eye, target, mode="point")[1]["frame_seconds"])
        result["load_average_1min"].append(os.getloadavg()[0])
        for name in MATERIALS:
            times[name]["point"] = point[name]
            ref = refs[name]
            hits = ref.stderr.max(-1) > 0
            r = rows[name]["converge"]
            se = np.sqrt(r.stderr.astype(np.float64) ** 2 + ref.stderr.astype(np.float64) ** 2)
            z = (r.image.astype(np.float64) - ref.image).sum((0, 1)) / np.sqrt((se ** 2).sum((0, 1)))
            again = refs[name + "/again"]
            z_mis = (again.image.astype(np.float64) - ref.image).sum((0, 1)) / np.sqrt(
                (again.stderr.astype(np.float64) ** 2 + ref.stderr.astype(np.float64) ** 2).sum((0, 1)))
            result["materials"][name] = {
                "seconds": times[name],
                "median_seconds": {k: float(np.median(v)) for k, v in times[name].items()},
                "nodes_per_point": {m: rows[name][m][1]["nodes_per_point"] for m in ("point", "pixel")},
                "frame_error": {m: round(corrected_error(rows[name][m][0], ref, hits), 5) for m in ("point", "pixel")},
                "converge_relative_stderr": round(float(np.sqrt((r.stderr[hits].astype(np.float64) ** 2).sum()
                                                                / (r.image[hits].astype(np.float64) ** 2).sum())), 5),
                "converge_z_per_channel": [round(float(v), 3) for v in z],
                "mis_seed_8_z_per_channel": [round(float(v), 3) for v in z_mis],
                "mis_noise": round(float(np.sqrt((ref.stderr[hits].astype(np.float64) ** 2).sum()
                                                 / (ref.image[hits].astype(np.float64) ** 2).sum())), 5)}
            print(f"{name}: {result['materials'][name]}", file=sys.stderr, flush=True)
        result["bias_check"] = bias_check(wavlight, view_frames, args.check_size, eye, target, folder)
        p, g = result["materials"]["plastic"]["median_seconds"], result["materials"]["ggx"]["median_seconds"]
        result["plastic_over_ggx"] = {k: round(p[k] / g[k], 3) for k in p}
        tr.close()
    write_result(args.output, result, prov)


if __name__ == "__main__":
    main()
