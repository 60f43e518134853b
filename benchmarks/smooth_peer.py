#!/usr/bin/env python3
"""Smooth shading against Mitsuba 3: the bunny (benchmarks/scenes/bunny_ggx.toml) rendered by
wavlight with its vertex normals and by Mitsuba 3 with the same corner normals
(wavlight.evaluation.peers, ``scalar_rgb``: the LLVM variant needs a newer libLLVM than some
systems have), and by wavlight with face normals (``face_normals = true`` on every object, the
old faceted image). Over the bunny's pixels (those whose centre ray hits it): the relative
bias of the mean, sum(wavlight - Mitsuba) / sum(Mitsuba), and the mean absolute relative
difference per pixel, beside wavlight's own relative standard error. docs/decisions/shading-normals.md.

Usage:
    python benchmarks/smooth_peer.py [--size 128] [--spp 256] [-o FILE]

Writes benchmarks/results/smooth_peer.json (benchmarks/provenance.py) unless -o names another.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from provenance import provenance, write_result  # noqa: E402

import wavlight  # noqa: E402
from wavlight import camera  # noqa: E402
from wavlight.evaluation import peers  # noqa: E402
from wavlight.raytrace import RayTracer  # noqa: E402

SCENE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "scenes", "bunny_ggx.toml")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("-o", dest="out", default="smooth_peer")
    args = ap.parse_args()
    prov = provenance()
    scene = wavlight.load_scene(SCENE)
    w = h = args.size
    o, d = camera.camera_rays(scene, np.arange(w * h) % w, np.arange(w * h) // w, np.full((w * h, 2), 0.5), w, h)
    prim, _ = RayTracer(scene.vertices, scene.faces).intersect(o, d)
    bunny = np.isin(prim, np.arange(*scene.objects[0].faces_range)).reshape(h, w)
    peers.VARIANT = "scalar_rgb"
    t0 = time.perf_counter()
    theirs = peers.render_mitsuba(scene, "mis", spp=args.spp, width=w, height=h, seed=3).image[bunny].astype(np.float64)
    mitsuba_seconds = time.perf_counter() - t0
    out = {"scene": os.path.relpath(SCENE), "size": args.size, "spp": args.spp, "bunny_pixels": int(bunny.sum()),
           "mitsuba_seconds": round(mitsuba_seconds, 2), "variant": peers.VARIANT}
    for label, sc in (("smooth", scene), ("faceted", scene.faceted())):
        r = wavlight.render_full(sc, strategy="mis", spp=args.spp, width=w, height=h, seed=4)
        ours = r.image[bunny].astype(np.float64)
        lum = lambda a: a @ np.array([0.2126, 0.7152, 0.0722])   # noqa: E731
        a, b = lum(ours), lum(theirs)
        out[label] = {"bias": round(float((a.sum() - b.sum()) / b.sum()), 5),
                      "mean_abs_rel_diff": round(float(np.mean(np.abs(a - b) / np.maximum(b, 1e-6))), 5),
                      "wavlight_rel_stderr": round(float(np.mean(lum(r.stderr[bunny]) / np.maximum(a, 1e-6))), 5)}
        print(label, out[label], flush=True)
    write_result(args.out, out, prov)


if __name__ == "__main__":
    main()
