#!/usr/bin/env python3
"""The cost of plastic: the bunny under rooitou_park_1k in plastic (alpha 0.15) against the same
scene in ggx (alpha 0.15), rendered with ``mis`` and ``wavelet`` (its default budget), the two
materials alternating within each repeat (a shared machine: record the load average).

Usage:
    python benchmarks/plastic_speed.py [--size 256] [--spp 16] [--repeats 3] [-o FILE]
Writes benchmarks/results/plastic_speed.json (with the run's provenance): per material and
strategy the render seconds of each repeat (render_full's timings) and their median.
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
    needs.fetch("plastic_speed", "rooitou_park_1k", "bunny")
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
              "median_seconds": {k: float(np.median(v)) for k, v in seconds.items()}}
    for k, v in result["median_seconds"].items():
        print(f"{k}: {v:.3f} s", file=sys.stderr)
    write_result(args.output, result, prov)


if __name__ == "__main__":
    main()
