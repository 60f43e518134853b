"""The README's pictures of assets: the Stanford bunny shaded smooth, and a designer's GLB under a map.

Runs the shipped command line, as a user would, for two pictures in docs/figures/:

- bunny-smooth.png: benchmarks/scenes/bunny_ggx.toml (the bunny in gold ggx on a lambert floor
  under rooitou_park_1k, shaded with its vertex normals);
- designer-glb.png: the GLB of issue 38 (tests/support/assets_util.write_designer_glb, made with
  trimesh: a floor with an sRGB stripes texture, a gold metal sphere and a red non-metal sphere,
  low-poly with per-vertex normals), rendered directly (``wavlight render ASSET.glb --env MAP``:
  its materials from the file, a camera that frames it) under st_fagans_interior_512.

Both at 512 x 384, ``mis``, the background filtered bilinearly, the ACES tone curve. The bunny
and rooitou_park_1k are fetched on first use (or read from WAVLIGHT_DATA). Prints the commands
it ran as JSON. About a minute and a half on 2 cores.

    python benchmarks/readme_pictures.py [--out docs/figures]
"""
from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.normpath(os.path.join(HERE, ".."))
LOOK = ["--width", "512", "--height", "384", "--background", "bilinear", "--tonemap", "aces"]


def commands(out: str) -> list[list[str]]:
    """The two ``wavlight render`` command lines (run from the repository's root; designer.glb
    in the current folder)."""
    return [["wavlight", "render", "benchmarks/scenes/bunny_ggx.toml", *LOOK, "--spp", "256",
             "-o", os.path.join(out, "bunny-smooth.png")],
            ["wavlight", "render", "designer.glb", "--env", "data:st_fagans_interior_512", *LOOK, "--spp", "1024",
             "-o", os.path.join(out, "designer-glb.png")]]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/figures", help="folder of the pictures, relative to the repository")
    args = ap.parse_args()
    sys.path.insert(0, HERE)
    sys.path.insert(0, os.path.join(ROOT, "tests", "support"))
    import needs
    from assets_util import write_designer_glb

    needs.fetch("readme_pictures", "bunny", "rooitou_park_1k")
    wavlight = os.path.join(os.path.dirname(sys.executable), "wavlight")
    out = os.path.join(ROOT, args.out)
    os.makedirs(out, exist_ok=True)
    ran = []
    with tempfile.TemporaryDirectory(prefix="readme_pictures_") as folder:
        write_designer_glb(os.path.join(folder, "designer.glb"))
        for line in commands(args.out):
            # the repository's inputs and the outputs made absolute; designer.glb from the scratch folder
            argv = [os.path.join(ROOT, a) if a.startswith(("benchmarks/", args.out)) else a for a in line[1:]]
            r = subprocess.run([wavlight, *argv], cwd=folder, capture_output=True, text=True)
            if r.returncode != 0:
                sys.exit(f"readme_pictures: {shlex.join(line)} failed: {r.stderr.strip().splitlines()[-1:]}")
            ran.append({"command": shlex.join(line), "said": r.stderr.strip().splitlines()[-1:]})
    print(json.dumps(ran, indent=1))


if __name__ == "__main__":
    main()
