"""The viewer's pictures: a linear frame times 2^exposure through a tone curve
(:data:`wavlight.display.CURVES`, the curves of ``wavlight render --tonemap``), encoded to 8-bit
sRGB in numpy (a lookup table of the sRGB curve, :func:`wavlight.display.encode8_lut`) as JPEG
(Pillow) or raw RGBA, or as the PNG the page downloads (:func:`png`); and the binary message
that carries one to the page: a 4-byte little-endian length, a JSON header, the picture.

A background hidden (the page's ``show_background`` false) is a ``coverage`` of the frame's
pixels: the share (H, W) of the bake's camera samples of each pixel that hit a surface
(:func:`wavlight.relight.converge.bake_hits` over the bake's spp). Where it is 0 (the camera sees
only the map) the picture is black, and transparent in the PNG, whose alpha is the coverage (a
silhouette's pixel keeps its colour, the map's share of its missed samples included: the frame
does not hold the two parts apart)."""
from __future__ import annotations

import io
import json
import struct

import numpy as np

from ..display import TONEMAP, encode8_lut

#: frame encodings a page may ask for (``encoding=`` in the URL); the first is the default
#: (benchmarks/viewer_fps.py measures both)
ENCODINGS = ("jpeg", "raw")
JPEG_QUALITY = 90


def tone_map(image: np.ndarray, exposure: float = 0.0, alpha: bool = False,
             tonemap: str = TONEMAP.default) -> np.ndarray:
    """(H, W, 3) (or (H, W, 4) with ``alpha``: opaque) uint8 sRGB of the linear (H, W, 3) image
    times 2^exposure through the tone curve; NaN shows black and +Inf white
    (:func:`wavlight.display.encode8_lut`: within one 8-bit level of the written PNGs)."""
    return encode8_lut(image, exposure, tonemap, alpha)


def _covered(picture: np.ndarray, coverage) -> np.ndarray:
    """The tone-mapped ``picture`` black where ``coverage`` (H, W) is 0 (None, or another size:
    unchanged)."""
    if coverage is None or coverage.shape != picture.shape[:2]:
        return picture
    picture[coverage <= 0, :3] = 0
    return picture


def encode(image: np.ndarray, exposure: float, encoding: str, tonemap: str = TONEMAP.default,
           coverage=None) -> bytes:
    """The frame's picture as the page decodes it: JPEG (quality :data:`JPEG_QUALITY`) or raw
    RGBA rows (W x H x 4 bytes); with ``coverage`` (the background hidden), black where it is 0."""
    if encoding == "raw":
        return _covered(tone_map(image, exposure, alpha=True, tonemap=tonemap), coverage).tobytes()
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(_covered(tone_map(image, exposure, tonemap=tonemap), coverage)).save(out, "JPEG",
                                                                                         quality=JPEG_QUALITY)
    return out.getvalue()


def png(image: np.ndarray, exposure: float, tonemap: str = TONEMAP.default, coverage=None) -> bytes:
    """The frame as the page shows it (times 2^exposure through the tone curve, 8-bit sRGB) as a
    PNG: RGB, or with ``coverage`` (the background hidden) RGBA, alpha the coverage (0: transparent
    and black)."""
    from PIL import Image

    picture = tone_map(image, exposure, alpha=coverage is not None, tonemap=tonemap)
    if coverage is not None and coverage.shape == picture.shape[:2]:
        picture[..., 3] = np.round(np.clip(coverage, 0.0, 1.0) * 255.0).astype(np.uint8)
        picture = _covered(picture, coverage)
    out = io.BytesIO()
    Image.fromarray(picture).save(out, "PNG")
    return out.getvalue()


def message(header: dict, payload: bytes = b"") -> bytes:
    """One binary frame message: uint32 LE length of the JSON header, the header, the payload."""
    text = json.dumps(header, separators=(",", ":")).encode()
    return struct.pack("<I", len(text)) + text + payload
