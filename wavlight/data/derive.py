"""Make the shipped maps from their 1k originals: ``python -m wavlight.data.derive``.

It lives beside the assets it writes so that the package carries its own recipe: each
registry entry with ``derived_from`` is the 1024 x 512 original (fetched through the registry,
or found in ``WAVLIGHT_DATA``) reduced by :func:`downsample` to 512 x 256 and written as a
half-float OpenEXR file with lossless zip compression (:func:`write_exr`). The script prints
each file's size and sha256 for registry.toml, and ``--check`` only compares the pixels of the
files in the package with a fresh derivation.

:func:`downsample` is an exact box filter on the sphere: a new texel's value is the mean of the
old texels it covers weighted by their solid angle (a lat-long row from theta0 to theta1 spans
cos theta0 - cos theta1 per unit of phi), so that its radiance integrated over its solid angle
equals the sum of theirs: the map's energy, and that of any region made of whole new texels, is
kept exactly (before half-float rounding, a relative 2^-11 at most). A plain mean of the four
texels would shift energy towards the poles.
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from . import ASSETS, asset, file_sha256, path, registry
from ..errors import WavlightError

#: the shipped maps' width over the originals'
FACTOR = 2
#: OpenEXR's largest finite half value: a texel above it would become Inf
HALF_MAX = 65504.0


def downsample(pixels: np.ndarray, factor: int) -> np.ndarray:
    """(H / factor, W / factor, C) float64: the lat-long map ``pixels`` (H, W, C) reduced by
    ``factor`` in both directions, each new texel the solid-angle-weighted mean of the
    factor x factor texels it covers (module docstring). H and W must be multiples of factor."""
    p = np.asarray(pixels, np.float64)
    h, w, c = p.shape
    if h % factor or w % factor:
        raise WavlightError(f"downsample: a {w}x{h} map is not a multiple of {factor} in both directions")
    theta = np.arange(h + 1) * np.pi / h
    row_weight = np.cos(theta[:-1]) - np.cos(theta[1:])              # each row's solid angle per unit phi
    summed = (p * row_weight[:, None, None]).reshape(h // factor, factor, w // factor, factor, c).sum(axis=(1, 3))
    return summed / (factor * row_weight.reshape(h // factor, factor).sum(axis=1))[:, None, None]


def write_exr(file, pixels: np.ndarray) -> None:
    """Write (H, W, 3) pixels as a half-float OpenEXR file with zip compression and no date
    (the same pixels give the same bytes)."""
    import OpenImageIO as oiio

    with np.errstate(over="ignore"):
        half = np.asarray(pixels).astype(np.float16)
    if not np.all(np.isfinite(half)):
        raise WavlightError(f"{file}: values above {HALF_MAX:g} do not fit a half float")
    spec = oiio.ImageSpec(half.shape[1], half.shape[0], half.shape[2], oiio.HALF)
    spec.attribute("compression", "zip")
    spec.attribute("DateTime", "")
    out = oiio.ImageOutput.create(str(file))
    if out is None or not out.open(str(file), spec) or not out.write_image(half):
        raise WavlightError(f"{file}: cannot write ({oiio.geterror()})")
    out.close()


def derived(name: str) -> np.ndarray:
    """(H, W, 3) float16: the pixels shipped map ``name`` should hold, from its original."""
    from ..envmap import read_image

    original = read_image(str(path(asset(name).derived_from)))
    return downsample(original, FACTOR).astype(np.float16)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m wavlight.data.derive", description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="compare the shipped files' pixels; write nothing")
    args = ap.parse_args(argv)
    from ..envmap import read_image

    status = 0
    for a in registry().values():
        if a.derived_from is None:
            continue
        target = ASSETS / a.file
        try:
            pixels = derived(a.name)
            if args.check:
                same = np.array_equal(read_image(str(target)), pixels.astype(np.float32))
                print(f"{a.name}: {'same pixels' if same else 'DIFFERENT pixels'} as derived from {a.derived_from}")
                status |= not same
                continue
            write_exr(target, pixels)
        except WavlightError as e:
            print(f"derive: {e}", file=sys.stderr)
            return 2
        print(f'{a.name}: {target.stat().st_size} bytes, sha256 = "{file_sha256(target)}"')
    return status


if __name__ == "__main__":
    sys.exit(main())
