"""The README's picture: `wavelet` next to `mis` at equal time on the built-in default scene.

Renders scenes/default.toml (320 x 240, procedural sky: no file outside the repository) with
`mis` at --spp samples per pixel and measures its time (setup + sampling, kernels compiled
beforehand by an untimed 8 x 8 render of each strategy). `wavelet` then gets the spp that takes
the same time: a pilot at --spp gives its seconds per sample, and the render at the spp that
fits mis's time is measured again. Both are compared with a `mis` reference at --ref-spp
(another seed; its own variance subtracted, wavlight.evaluation.metrics.relmse) and written side
by side, each labelled with strategy, spp, seconds and relMSE, to docs/figures/wavelet-vs-mis.png.
Prints one JSON object with what it rendered. About half a minute on 2 cores.

    python benchmarks/readme_figure.py [--spp 16] [--ref-spp 512] [--out docs/figures/wavelet-vs-mis.png]
"""
from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.normpath(os.path.join(HERE, ".."))
SCENE = os.path.join(ROOT, "scenes", "default.toml")
REFERENCE_SEED = 1_000_003


def timed(scene, strategy, spp, seed=0):
    """(RenderResult, seconds): setup + sampling, as the experiments time a render."""
    import wavlight

    t0 = time.perf_counter()
    result = wavlight.render_full(scene, spp=spp, strategy=strategy, seed=seed)
    return result, time.perf_counter() - t0


def panel(image, label, font):
    """An 8-bit sRGB panel of the linear image with a caption strip below it."""
    from PIL import Image, ImageDraw

    from wavlight.imageio import srgb_encode

    pixels = (srgb_encode(image) * 255 + 0.5).astype(np.uint8)
    h, w = pixels.shape[:2]
    strip = 26
    out = Image.new("RGB", (w, h + strip), (255, 255, 255))
    out.paste(Image.fromarray(pixels), (0, 0))
    ImageDraw.Draw(out).text((6, h + 5), label, fill=(0, 0, 0), font=font)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=16, help="mis's samples per pixel (default 16)")
    ap.add_argument("--ref-spp", type=int, default=512, help="the mis reference's spp (default 512)")
    ap.add_argument("--out", default=os.path.join(ROOT, "docs", "figures", "wavelet-vs-mis.png"))
    args = ap.parse_args()

    from PIL import Image, ImageFont

    import wavlight
    from wavlight.evaluation import metrics

    scene = wavlight.load_scene(SCENE)
    for strategy in ("mis", "wavelet"):   # compile the kernels outside the timed renders
        wavlight.render_full(scene, spp=1, width=8, height=8, strategy=strategy)

    reference = wavlight.render_full(scene, spp=args.ref_spp, strategy="mis", seed=REFERENCE_SEED)
    mis, mis_seconds = timed(scene, "mis", args.spp)
    _, pilot_seconds = timed(scene, "wavelet", args.spp)
    wavelet_spp = max(1, round(args.spp * mis_seconds / pilot_seconds))
    wavelet, wavelet_seconds = timed(scene, "wavelet", wavelet_spp)

    rows = []
    for name, result, spp, seconds in (("mis", mis, args.spp, mis_seconds),
                                       ("wavelet", wavelet, wavelet_spp, wavelet_seconds)):
        err = metrics.relmse(result.image, reference.image, reference.stderr)
        budget = ""
        if result.stats.get("wavelet_candidates"):
            budget = f" ({result.stats['wavelet_candidates']} candidates, {result.stats['wavelet_slots']} slots)"
        rows.append({"strategy": name, "spp": spp, "seconds": round(seconds, 3), "relmse": round(float(err), 5),
                     "budget": budget.strip(" ()") or None})

    font = ImageFont.load_default(size=14)
    panels = [panel(r.image, f"{row['strategy']}, {row['spp']} spp, {row['seconds']:.2f} s, "
                             f"relMSE {row['relmse']:.4f}", font)
              for r, row in zip((mis, wavelet), rows)]
    gap = 8
    figure = Image.new("RGB", (sum(p.width for p in panels) + gap, panels[0].height), (255, 255, 255))
    figure.paste(panels[0], (0, 0))
    figure.paste(panels[1], (panels[0].width + gap, 0))
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    figure.save(args.out)

    print(json.dumps({"scene": os.path.relpath(SCENE, ROOT), "width": scene.width, "height": scene.height,
                      "reference": {"strategy": "mis", "spp": args.ref_spp, "seed": REFERENCE_SEED},
                      "wavelet_pilot_seconds": round(pilot_seconds, 3), "renders": rows,
                      "relmse_ratio": round(rows[1]["relmse"] / rows[0]["relmse"], 3),
                      "output": os.path.relpath(os.path.abspath(args.out), ROOT)}, indent=1))


if __name__ == "__main__":
    main()
