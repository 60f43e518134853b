#!/usr/bin/env python3
"""Plastic in the lighting bake: what plastic's coat (its second transfer, stored for the blocks
that see plastic) costs in file bytes, bake time and frame time, and how close its frames are.
The bunny of benchmarks/plastic_speed.py on its lambert floor under rooitou_park_1k, in plastic
(alpha 0.15, ior 1.5) and in ggx (alpha 0.15) with the same albedo, baked with the same fixed
model (``--levels``, ``--spp``, ``--terms``, priority area, ``--tolerance``), one after the
other (a shared machine: the load average is recorded; the bake seconds are noisy); each
bake's frames under the map turned by 110 degrees against ``mis`` of that
turned scene (``--ref-spp``): the relative L2 error over the pixels that see a surface, the
reference's own noise taken out. Then the unbiased frame (``--converge-spp``) of each bake under
that turn: its relative standard error over those pixels and its seconds; for plastic also with
product trees that leave the coat out (``converge.coat_weights`` replaced by zeros: the trees of
the base's transfer alone, the shading unchanged), the evidence for sampling the coat.

Usage:
    python benchmarks/plastic_bake.py [--size 128] [--levels 6] [--spp 16] [--terms 512]
                                      [--tolerance 0.02] [--ref-spp 256] [--repeats 3] [-o FILE]
Writes benchmarks/results/plastic_bake.json (with the run's provenance): per material the file's
bytes, the entries of the transfer and of the coat, the coat's blocks, the bake seconds (as it
reports them), the median frame seconds over ``--repeats`` frames, the frame's error and the
unbiased frame's relative standard error.
"""
import argparse
import os
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def corrected_error(image, ref, mask) -> float:
    """Relative L2 error against the truth: ||image - ref||^2 less sum(stderr^2), over ||ref||^2."""
    diff = (image - ref.image)[mask].astype(np.float64)
    noise = (ref.stderr[mask].astype(np.float64) ** 2).sum()
    return float(np.sqrt(max((diff ** 2).sum() - noise, 0.0) / (ref.image[mask].astype(np.float64) ** 2).sum()))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--levels", type=int, default=6)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--terms", type=int, default=512)
    ap.add_argument("--tolerance", type=float, default=0.02)
    ap.add_argument("--ref-spp", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--converge-spp", type=int, default=16)
    sys.path.insert(0, HERE)
    import needs
    from plastic_speed import MATERIALS, scene
    from provenance import add_output_argument, provenance, write_result

    add_output_argument(ap, "plastic_bake")
    args = ap.parse_args()
    needs.fetch("plastic_bake", "rooitou_park_1k", "bunny")
    prov = provenance()
    import wavlight

    turn = 110.0
    result = {"size": args.size, "levels": args.levels, "spp": args.spp, "terms": args.terms,
              "tolerance": args.tolerance, "ref_spp": args.ref_spp, "rotate_y": turn, "load_average_1min": [],
              "materials": {}}
    with tempfile.TemporaryDirectory() as folder:
        for name, material in MATERIALS.items():   # two materials
            result["load_average_1min"].append(os.getloadavg()[0])
            d = scene(material, args.size)
            sc = wavlight.load_dict(d)
            path = os.path.join(folder, f"{name}.wlt")
            tr = wavlight.bake(sc, path, spp=args.spp, levels=args.levels, terms=args.terms, priority="area",
                               tolerance=args.tolerance, seed=1)
            tr.frame(rotate_y=turn)   # the programs built
            frames = [tr.frame_timed(rotate_y=turn)[1]["frame_seconds"] for _ in range(args.repeats)]
            image = tr.frame(rotate_y=turn)
            turned = dict(d, environment=dict(d["environment"], rotate_y=turn))
            ref = wavlight.render_full(wavlight.load_dict(turned), spp=args.ref_spp, strategy="mis", seed=7)
            hits = np.asarray(tr._s["albedo"]).sum(-1) > 0
            m = tr.measured
            entry_bytes = tr._s["entry_data"].shape[1] * tr._s["entry_data"].itemsize + 4
            row = {"file_bytes": tr.file_bytes, "entries": tr.entries, "coat_entries": m.get("coat_entries", 0),
                   "coat_blocks": int(len(tr._s["coat_blocks"])) if "coat_blocks" in tr._s else 0,
                   "blocks": tr.blocks[0] * tr.blocks[1], "entry_bytes": entry_bytes,
                   "compression_error": round(m["compression_error"], 5),
                   "coat_compression_error": (round(m["coat_compression_error"], 5)
                                              if "coat_compression_error" in m else None),
                   "bake_seconds": m["bake_seconds"], "rays": m["rays"],
                   "frame_seconds": frames, "median_frame_seconds": float(np.median(frames)),
                   "frame_error": round(corrected_error(image, ref, hits), 5),
                   "mis_noise": round(float(np.sqrt((ref.stderr[hits].astype(np.float64) ** 2).sum()
                                                    / (ref.image[hits].astype(np.float64) ** 2).sum())), 5)}
            from wavlight.relight import converge

            def unbiased(label):
                r = converge.ConvergeFrames(tr, sc).frame(rotate_y=turn, spp=args.converge_spp, seed=3)
                se, image = r.stderr[hits].astype(np.float64), r.image[hits].astype(np.float64)
                rel = np.sqrt((se ** 2).sum() / (image ** 2).sum())
                row[label] = {"relative_stderr": round(float(rel), 5), "seconds": r.stats["render_seconds"]}

            converge.ConvergeFrames(tr, sc).frame(rotate_y=turn, spp=1, seed=1)   # the programs built
            unbiased("converge")
            if name == "plastic":
                kept = converge.coat_weights
                converge.coat_weights = lambda t: np.zeros_like(kept(t))
                try:
                    unbiased("converge_trees_without_coat")
                finally:
                    converge.coat_weights = kept
            result["materials"][name] = row
            tr.close()
            print(f"{name}: {row}", file=sys.stderr, flush=True)
    p, g = result["materials"]["plastic"], result["materials"]["ggx"]
    result["file_bytes_ratio"] = round(p["file_bytes"] / g["file_bytes"], 4)
    write_result(args.output, result, prov)


if __name__ == "__main__":
    main()
