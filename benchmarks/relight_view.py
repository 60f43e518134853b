"""Frames from a moving camera (wavlight.relight.view) on the bunny of scenes/bunny_ggx.toml: the
view bake's time and size per surface-cache size, the approximate frame's time at --size x --size
(median of --frames after one untimed frame, with its parts: camera rays, cache lookup, the
product kernel, assembly) and its relative L2 error against a converged ``mis`` render from the
same camera, per cache size and per refine (the walk's node size against the lobe: fewer or more
product terms per point). The camera is the scene's eye turned --turn degrees about the target
(a view the scene file does not have). The error of mis's own noise is reported beside
(``mis_noise``: |stderr| / |image|); errors below it are not resolved.

    python benchmarks/relight_view.py [--size 512] [--levels 6] [--points 16384,65536]
        [--refine 0.25,0.15,0.1] [--frames 5] [--mis-spp 64] [--turn 40] [-o FILE]

The figures in benchmarks/results/relight_view.json come from the defaults.
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from provenance import add_output_argument, provenance, write_result  # noqa: E402

SCENE = os.path.join(os.path.dirname(HERE), "scenes", "bunny_ggx.toml")
PARTS = ("rays_seconds", "lookup_seconds", "product_seconds", "assembly_seconds", "frame_seconds")


def relative_l2(a, b, mask=None):
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if mask is not None:
        a, b = a[mask], b[mask]
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--levels", type=int, default=6, help="texels 2^n x 2^n of the bakes")
    ap.add_argument("--points", default="16384,65536", help="surface cache sizes (points over the scene's area)")
    ap.add_argument("--refine", default="0.25,0.15,0.1", help="the walk's refine values")
    ap.add_argument("--frames", type=int, default=5, help="timed frames per setting")
    ap.add_argument("--mis-spp", type=int, default=64, help="samples per pixel of the mis reference")
    ap.add_argument("--turn", type=float, default=40.0, help="degrees the eye turns about the target")
    add_output_argument(ap, "relight_view")
    args = ap.parse_args()
    prov = provenance()
    import wavlight
    from wavlight.relight import view

    scene = wavlight.load_scene(SCENE)
    eye = view.orbit_eyes(scene.camera.eye, scene.camera.target, max(1, round(360.0 / args.turn)))[1]
    cam = dataclasses.replace(scene.camera, eye=eye)
    t0 = time.perf_counter()
    ref = wavlight.render_full(dataclasses.replace(scene, camera=cam), spp=args.mis_spp, strategy="mis",
                               width=args.size, height=args.size, seed=5)
    mis_seconds = time.perf_counter() - t0
    hit = None
    rows = []
    folder = tempfile.mkdtemp(prefix="relight-view-bench-")
    for points in [int(x) for x in args.points.split(",") if x]:
        path = os.path.join(folder, f"bunny-{points}.wlt")
        area = sum(0.5 * np.linalg.norm(np.cross(*(scene.vertices[scene.faces[:, k]].astype(np.float64)
                                                   - scene.vertices[scene.faces[:, 0]] for k in (1, 2))), axis=1))
        tr = wavlight.bake(scene, path, vary="view", levels=args.levels, density=points / area)
        summary = tr.summary()
        frames = view.ViewFrames(tr, scene)
        if hit is None:
            prim, _ = frames.tracer.intersect(*wavlight.camera.camera_rays(
                dataclasses.replace(scene, camera=cam), np.arange(args.size ** 2) % args.size,
                np.arange(args.size ** 2) // args.size, np.full((args.size ** 2, 2), 0.5, np.float32), args.size,
                args.size))
            hit = (prim >= 0).reshape(args.size, args.size)
        for refine in [float(x) for x in args.refine.split(",") if x]:
            frames.frame(eye, cam.target, cam.fov_y, args.size, args.size, refine=refine)    # untimed: the build
            stats, image = [], None
            for _ in range(args.frames):
                image, st = frames.frame(eye, cam.target, cam.fov_y, args.size, args.size, refine=refine)
                stats.append(st)
            med = {p: statistics.median(s[p] for s in stats) for p in PARTS}
            rows.append({"cache_points": summary["cache"]["points"], "spacing": summary["cache"]["spacing"],
                         "refine": refine, "bake_seconds": summary["bake_seconds"],
                         "rays_per_second": summary["rays_per_second"], "file_bytes": summary["file_bytes"],
                         "compression_error": summary["measured"]["compression_error"], **med,
                         "frames_per_second": 1.0 / med["frame_seconds"],
                         "cache_points_shaded": stats[-1]["cache_points_shaded"],
                         "nodes_per_point": stats[-1]["nodes_per_point"],
                         "relative_l2_vs_mis": relative_l2(image, ref.image),
                         "relative_l2_vs_mis_surfaces": relative_l2(image, ref.image, hit)})
            print(rows[-1], flush=True)
        tr.close()
        os.unlink(path)
    os.rmdir(folder)
    data = {"scene": "scenes/bunny_ggx.toml", "size": args.size, "levels": args.levels, "eye": eye.tolist(),
            "target": cam.target.tolist(), "mis": {"spp": args.mis_spp, "seconds": round(mis_seconds, 2),
                                                   "mis_noise": float(np.linalg.norm(ref.stderr)
                                                                      / np.linalg.norm(ref.image))},
            "rows": rows}
    print(write_result(args.output, data, prov))


if __name__ == "__main__":
    main()
