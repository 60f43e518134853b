#!/usr/bin/env python3
"""The cost of plastic: the bunny under rooitou_park_1k in plastic (alpha 0.15) against the same
scene in ggx (alpha 0.15), rendered with ``mis`` and ``wavelet`` (its default budget), the two
materials alternating within each repeat (a shared machine: record the load average). Then
the error at equal spp of ``mis`` and ``wavelet`` on benchmarks/plastic_peer.py's plastic scenes
(a sphere and the bunny under rooitou_park_1k, the sphere under st_fagans_interior_1k; 96²,
``--spp``, two seeds): relMSE against ``mis`` at 1024 spp, and the render seconds.

Usage:
    python benchmarks/plastic_speed.py [--size 256] [--spp 16] [--repeats 3] [-o FILE]
Writes benchmarks/results/plastic_speed.json (with the run's provenance): per material and
strategy the render seconds of each repeat (render_full's timings) and their median; per
plastic scene and strategy the relMSE and seconds of each seed.
"""
import argparse
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
MATERIALS = {"plastic": {"type": "plastic", "albedo": [0.7, 0.25, 0.1], "alpha": 0.15, "ior": 1.5},
             "ggx": {"type": "ggx", "albedo": [0.7, 0.25, 0.1], "roughness": 0.15}}


def scene(material: dict, size: int) -> dict:
    return {"render": {"width": size, "height": size, "seed": 1},
            "camera": {"eye": [0.0, 1.4, 4.2], "target": [-0.15, 1.0, 0.0], "fov_y": 30.0},
            "environment": {"file": "data:rooitou_park_1k"},
            "objects": [{"mesh": "data:bunny", "scale": 10.0, "material": "m"},
                        {"shape": "quad", "center": [0.0, 0.33, 0.0], "size": 6.0, "material": "floor"}],
            "materials": {"m": material, "floor": {"type": "lambert", "albedo": [0.5, 0.5, 0.5]}}}


def equal_spp(spp: int, size: int = 96, ref_spp: int = 1024) -> dict:
    """relMSE (mean of (x - ref)^2 / (ref^2 + 0.01)) and seconds of mis and wavelet per seed."""
    import plastic_peer as pp
    import wavlight

    out = {}
    for obj, sky in (("sphere", "sun"), ("bunny", "sun"), ("sphere", "indoor")):
        sc = wavlight.load_dict(pp.scene_dict(obj, sky, pp.PLASTIC, size))
        ref = wavlight.render_full(sc, strategy="mis", spp=ref_spp, seed=99)
        for strategy in ("mis", "wavelet"):   # compile before timing
            wavlight.render_full(sc, strategy=strategy, spp=1, seed=5)
        case = out[f"{obj}/{sky}"] = {"mis": [], "wavelet": []}
        for seed in (1, 2):
            for strategy in ("mis", "wavelet"):
                r = wavlight.render_full(sc, strategy=strategy, spp=spp, seed=seed)
                rel = float(np.mean((r.image - ref.image) ** 2 / (ref.image ** 2 + 1e-2)))
                case[strategy].append({"relmse": round(rel, 6), "seconds": round(float(r.stats["render_seconds"]), 3)})
        print(f"{obj}/{sky}: " + ", ".join(f"{k} relMSE {np.mean([x['relmse'] for x in v]):.5f}"
                                           for k, v in case.items()), file=sys.stderr, flush=True)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=3)
    sys.path.insert(0, HERE)
    import needs
    from provenance import add_output_argument, provenance, write_result

    add_output_argument(ap, "plastic_speed")
    args = ap.parse_args()
    needs.fetch("plastic_speed", "rooitou_park_1k", "st_fagans_interior_1k", "bunny")
    prov = provenance()
    import wavlight

    scenes = {k: wavlight.load_dict(scene(m, args.size)) for k, m in MATERIALS.items()}
    for sc in scenes.values():   # compile each program before timing
        for strategy in ("mis", "wavelet"):
            wavlight.render_full(sc, strategy=strategy, spp=1, width=16, height=16)
    seconds = {f"{k}/{s}": [] for k in MATERIALS for s in ("mis", "wavelet")}
    load = []
    for _ in range(args.repeats):
        load.append(os.getloadavg()[0])
        for strategy in ("mis", "wavelet"):
            for k, sc in scenes.items():
                r = wavlight.render_full(sc, strategy=strategy, spp=args.spp)
                seconds[f"{k}/{strategy}"].append(round(float(r.stats["render_seconds"]), 3))
    result = {"size": args.size, "spp": args.spp, "repeats": args.repeats, "load_average_1min": load,
              "render_seconds": seconds,
              "median_seconds": {k: float(np.median(v)) for k, v in seconds.items()},
              "equal_spp": equal_spp(args.spp)}
    for k, v in result["median_seconds"].items():
        print(f"{k}: {v:.3f} s", file=sys.stderr)
    write_result(args.output, result, prov)


if __name__ == "__main__":
    main()
