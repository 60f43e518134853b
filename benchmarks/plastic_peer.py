#!/usr/bin/env python3
"""wavlight's plastic against Mitsuba 3's roughplastic, rendered: a sphere and the bunny, each
under a map with a sun (rooitou_park_1k) and an indoor map (st_fagans_interior_1k).

Each case is a plastic object (albedo [0.7, 0.25, 0.1], alpha 0.15, ior 1.5) on a plastic floor
(albedo 0.5, alpha 0.4, ior 1.5). wavlight renders it with ``mis`` (one light and one BSDF
sample, power heuristic) and Mitsuba 3 (wavlight.evaluation.peers: the same camera, the map
upsampled 8x by nearest neighbour, twosided roughplastic with ggx, nonlinear false, ext_ior 1)
with ``direct`` (one emitter and one BSDF sample) over ``--seeds`` seeds. Over the pixels whose
centre sees geometry: the bias (mean of wavlight - Mitsuba over the mean of Mitsuba, per
channel) with its standard error (wavlight's per-pixel standard errors and Mitsuba's spread
over its seeds), over the pixels whose four corners see geometry, z = bias / standard error, and the relative MSE of wavlight against the
Mitsuba mean with Mitsuba's own noise removed. A lambert control (the same scene, both
materials lambert) measures the part of the difference that comes from the map lookups
(Mitsuba's bilinear lookup of the upsampled map against wavlight's nearest texel,
wavlight.evaluation.peers).

Usage:
    python benchmarks/plastic_peer.py [--size 128] [--spp 256] [--seeds 4] [-o FILE]
Writes benchmarks/results/plastic_peer.json (with the run's provenance).
"""
import argparse
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))

MAPS = {"sun": "data:rooitou_park_1k", "indoor": "data:st_fagans_interior_1k"}
OBJECTS = {
    "sphere": {"shape": "sphere", "center": [0.0, 0.9, 0.0], "radius": 0.6, "subdivisions": 6},
    "bunny": {"mesh": "data:bunny", "scale": 10.0},
}
CAMERAS = {
    "sphere": {"eye": [0.0, 1.4, 3.2], "target": [0.0, 0.8, 0.0], "up": [0.0, 1.0, 0.0], "fov_y": 35.0},
    "bunny": {"eye": [0.0, 1.4, 4.2], "target": [-0.15, 1.0, 0.0], "up": [0.0, 1.0, 0.0], "fov_y": 30.0},
}
PLASTIC = {"object": {"type": "plastic", "albedo": [0.7, 0.25, 0.1], "alpha": 0.15, "ior": 1.5},
           "floor": {"type": "plastic", "albedo": [0.5, 0.5, 0.5], "alpha": 0.4, "ior": 1.5}}
LAMBERT = {"object": {"type": "lambert", "albedo": [0.7, 0.25, 0.1]},
           "floor": {"type": "lambert", "albedo": [0.5, 0.5, 0.5]}}


def scene_dict(obj: str, sky: str, materials: dict, size: int) -> dict:
    return {"render": {"width": size, "height": size, "seed": 1},
            "camera": CAMERAS[obj],
            "environment": {"file": MAPS[sky]},
            "objects": [{**OBJECTS[obj], "material": "object"},
                        {"shape": "quad", "center": [0.0, 0.33, 0.0], "normal": [0.0, 1.0, 0.0], "size": 6.0,
                         "material": "floor"}],
            "materials": materials}


def geometry_mask(scene, size):
    """Pixels whose four corners see geometry: the silhouettes' pixels, which also see the map
    directly, are left out (there the two renderers' direct lookups of the map differ,
    wavlight.evaluation.peers)."""
    from wavlight import camera, raytrace

    tracer = raytrace.RayTracer(scene.vertices, scene.faces)
    py, px = np.divmod(np.arange(size * size), size)
    mask = np.ones(size * size, bool)
    for corner in ((0.01, 0.01), (0.99, 0.01), (0.01, 0.99), (0.99, 0.99)):
        o, d = camera.camera_rays(scene, px, py, np.tile(corner, (size * size, 1)), size, size)
        mask &= tracer.intersect(np.ascontiguousarray(o), d)[0] >= 0
    return mask.reshape(size, size)


def compare(scene, size, spp, seeds):
    import wavlight
    from wavlight.evaluation import peers

    ours = wavlight.render_full(scene, strategy="mis", spp=spp * seeds, seed=11, width=size, height=size)
    runs = np.stack([peers.render_mitsuba(scene, "mis", spp=spp, width=size, height=size, seed=100 + s).image
                     for s in range(seeds)]).astype(np.float64)
    theirs = runs.mean(0)
    theirs_se = runs.std(0, ddof=1) / np.sqrt(seeds)
    mask = geometry_mask(scene, size)
    m = int(mask.sum())
    diff = (ours.image - theirs)[mask]
    se = np.sqrt((ours.stderr[mask] ** 2 + theirs_se[mask] ** 2).sum(0)) / m
    level = theirs[mask].mean(0)
    bias = diff.mean(0) / level
    # relMSE against Mitsuba's mean, the variance of that mean removed
    rel = ((ours.image - theirs)[mask] ** 2 - theirs_se[mask] ** 2) / (theirs[mask] ** 2 + 1e-2)
    own = (ours.stderr[mask] ** 2) / (theirs[mask] ** 2 + 1e-2)
    return {"pixels": m, "wavlight_spp": spp * seeds, "mitsuba_spp": f"{seeds} x {spp}",
            "mean_mitsuba": [round(float(x), 5) for x in level],
            "bias_relative": [round(float(x), 5) for x in bias],
            "bias_stderr_relative": [round(float(x), 5) for x in se / level],
            "bias_z": [round(float(x), 2) for x in diff.mean(0) / se],
            "relmse_vs_mitsuba": round(float(rel.mean()), 5),
            "relmse_wavlight_own": round(float(own.mean()), 5)}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--spp", type=int, default=256, help="Mitsuba's spp per seed (wavlight: spp x seeds)")
    ap.add_argument("--seeds", type=int, default=4)
    sys.path.insert(0, HERE)
    import needs
    from provenance import add_output_argument, provenance, write_result

    add_output_argument(ap, "plastic_peer")
    args = ap.parse_args()
    needs.fetch("plastic_peer", "rooitou_park_1k", "st_fagans_interior_1k", "bunny")
    prov = provenance(opencl="subprocess")
    import wavlight
    from wavlight.evaluation import peers

    if not peers.available():
        sys.exit("plastic_peer: Mitsuba 3 (llvm_ad_rgb) is not available: pip install 'wavlight[peers]'")
    results = {"size": args.size, "spp": args.spp, "seeds": args.seeds, "cases": {}}
    for obj in OBJECTS:
        for sky in MAPS:
            for label, mats in (("plastic", PLASTIC), ("lambert_control", LAMBERT)):
                scene = wavlight.load_dict(scene_dict(obj, sky, mats, args.size))
                r = compare(scene, args.size, args.spp, args.seeds)
                results["cases"][f"{obj}/{sky}/{label}"] = r
                print(f"{obj}/{sky}/{label}: bias {r['bias_relative']} +- {r['bias_stderr_relative']} "
                      f"(z {r['bias_z']}), relMSE {r['relmse_vs_mitsuba']} (own {r['relmse_wavlight_own']})",
                      file=sys.stderr, flush=True)
    path = write_result(args.output, results, prov)
    if path:
        print(f"wrote {path}", file=sys.stderr)


if __name__ == "__main__":
    main()
