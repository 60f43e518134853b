"""What base-colour textures cost the bakes that vary an object or the view, and where a view
frame takes its albedo from. One scene, made in a temporary folder: texture_cost.py's GLB (a
floor with a stripes texture of --texels² texels, a metal sphere) and a square pyramid whose one
material has the stripes too (the object that moves), under --env, seen at --size². Each bake is
made of the textured scene and of the same scene with its textures dropped, alternating
(--repeat times each): the bake's wall seconds, its file's bytes and
the median time of five frames of each, alternating frame by frame (an object bake's at 4 spp, a
view bake's approximate frame in its default mode). Then,
for view bakes of --densities cache points per unit area, the error of the frames' albedo factor
against the pixel's integral of the textured albedo (16 x 16 rays per pixel): the albedo at each
ray's hit (what the frames take) against the blend of the hit's three cache points' textured
albedo (what the cache carries), at 1 and 4 x 4 rays per pixel; relative L2 over the image.
Prints one JSON object and writes it, with the run's provenance (benchmarks/provenance.py), to
benchmarks/results/texture_bakes.json (-o FILE another, "-" none).

    python benchmarks/texture_bakes.py [--texels 64] [--size 128] [--repeat 2] [--densities 400,4000]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))

def write_pyramid(folder, texels):
    """The tests' textured pyramid (tests/support/assets_util.write_textured_pyramid), its
    stripes ``texels`` wide."""
    import PIL.Image

    sys.path.insert(0, os.path.join(os.path.dirname(HERE), "tests", "support"))
    from assets_util import stripes_image, write_textured_pyramid

    write_textured_pyramid(folder)
    PIL.Image.fromarray(stripes_image(texels, texels)).save(os.path.join(folder, "stripes.png"))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--texels", type=int, default=64)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--densities", default="400,4000")
    ap.add_argument("--env", default="data:rooitou_park_512")
    from provenance import add_output_argument, provenance, write_result
    from texture_cost import write_glb

    add_output_argument(ap, "texture_bakes")
    args = ap.parse_args()
    prov = provenance()

    import wavlight
    from wavlight.camera import camera_rays
    from wavlight.relight.moving import MovingObject
    from wavlight.relight.surface_cache import build_cache, lattice_points
    from wavlight.relight.view_bake import point_albedo
    from wavlight.relight.view_frames import ViewFrames

    eye, target = [1.5, 2.2, 3.2], [0.0, 0.3, 0.0]
    with tempfile.TemporaryDirectory() as folder:
        write_glb(os.path.join(folder, "a.glb"), args.texels)
        write_pyramid(folder, args.texels)
        textured = wavlight.load_dict({
            "render": {"width": args.size, "height": args.size},
            "camera": {"eye": [0.0, 2.0, 4.0], "target": [0.0, 0.3, 0.0], "fov_y": 40.0},
            "environment": {"file": args.env},
            "objects": [{"mesh": "a.glb"}, {"mesh": "p.obj", "name": "tile", "scale": 0.5,
                                             "translate": [0.6, 0.0, 0.5]}]}, base_dir=folder)
        plain = dataclasses.replace(textured, materials=[dataclasses.replace(m, texture=-1)
                                                         for m in textured.materials])
        assert textured.textured and not plain.textured
        out = {"texels": args.texels, "size": args.size, "environment": args.env, "object_bake": {}, "view_bake": {}}
        for _ in range(args.repeat):   # the two scenes' bakes alternating, then their frames alternating
            for kind in ("object_bake", "view_bake"):
                made = {}
                for name, scene in (("textured", textured), ("untextured", plain)):
                    path = os.path.join(folder, f"{kind}_{name}.wlt")
                    t0 = time.perf_counter()
                    if kind == "object_bake":
                        tr = wavlight.bake(scene, path, spp=16, levels=6, terms=256, priority="area", vary="object",
                                           object="tile", static_spp=256)
                        seconds = time.perf_counter() - t0
                        mover = MovingObject(tr, scene)
                        frame = (lambda m=mover: m.frame((1.0, 0.0, 0.2), spp=4, seed=0))
                    else:
                        tr = wavlight.bake(scene, path, vary="view", levels=5)
                        seconds = time.perf_counter() - t0
                        frames = ViewFrames(tr, scene)
                        frame = (lambda f=frames: f.frame(eye, target, width=args.size, height=args.size))
                    made[name] = (seconds, os.path.getsize(path), frame)
                    frame()   # (the first frame: programs built, tables uploaded)
                times = {name: [] for name in made}
                for _ in range(5):   # frames alternating
                    for name, (_, _, frame) in made.items():
                        t0 = time.perf_counter()
                        frame()
                        times[name].append(time.perf_counter() - t0)
                for name, (seconds, size, _) in made.items():
                    out[kind].setdefault(name, []).append(
                        {"bake_seconds": round(seconds, 2), "file_bytes": size,
                         "frame_seconds": round(float(np.median(times[name])), 4)})
        # the view frames' albedo factor: at the hit, or blended from the cache's points
        size = args.size
        out["view_albedo_error"] = []
        for density in [float(x) for x in args.densities.split(",")] + [None]:
            tr = wavlight.bake(textured, None, vary="view", levels=3, density=density, tolerance=1e-2)
            frames = ViewFrames(tr, textured)
            cache = build_cache(textured, density)   # the bake's own (deterministic)
            albedo_of_points = point_albedo(textured, cache)
            seen = dataclasses.replace(textured, camera=frames.camera(eye, target))

            def blended(prim, u, v, c=cache, a=albedo_of_points):
                ids, w = lattice_points(c.face_k, c.face_base, c.lattice, prim, u, v)
                return np.einsum("ij,ijc->ic", w, a[ids]).astype(np.float32)

            def image(albedo, ss, f=frames, seen=seen):
                k = np.arange(size * size * ss * ss)   # a pixel's ss x ss sub-pixel centres, adjacent
                pixel, sub = k // (ss * ss), k % (ss * ss)
                off = np.stack([(sub % ss + 0.5) / ss, (sub // ss + 0.5) / ss], 1).astype(np.float32)
                o, d = camera_rays(seen, pixel % size, pixel // size, off, size, size)
                prim, _, u, v = f.tracer.intersect_uv(o, d)
                hit = prim >= 0
                a = np.zeros((len(prim), 3), np.float32)
                a[hit] = albedo(prim[hit], u[hit], v[hit])
                return a.reshape(size * size, ss * ss, 3).mean(1)

            exact = image(frames.hit_albedo, 16)
            assert len(cache) == tr.header["cache"]["points"]
            row = {"density": cache.density, "spacing": round(cache.spacing, 5), "points": len(cache)}
            for name, albedo in (("hit", frames.hit_albedo), ("cache", blended)):
                for ss in (1, 4):
                    a = image(albedo, ss)
                    row[f"{name}_{ss}x{ss}"] = round(float(np.linalg.norm(a - exact) / np.linalg.norm(exact)), 5)
            out["view_albedo_error"].append(row)
    out["load_average_end"] = os.getloadavg()[0]
    print(json.dumps(out, indent=1))
    write_result(args.output, out, prov)


if __name__ == "__main__":
    main()
