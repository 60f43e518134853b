"""The viewer's pictures: a linear frame times 2^exposure through a tone curve
(:data:`wavlight.display.CURVES`, the curves of ``wavlight render --tonemap``), encoded to 8-bit
sRGB in numpy (a lookup table of the sRGB curve, :func:`wavlight.display.encode8_lut`) as JPEG
(Pillow) or raw RGBA, or as the PNG the page downloads (:func:`png`); and the binary message
that carries one to the page: a 4-byte little-endian length, a JSON header, the picture.

A background hidden (the page's ``show_background`` false) is in the frame itself: a lighting or
a view bake's frames with background ``none`` (:data:`wavlight.options.BACKGROUND`: camera
samples that miss contribute 0), black where the camera sees only the map. The PNG of such a
frame has straight (not premultiplied) alpha where a ``coverage`` is known: a lighting bake's
share (H, W) of the bake's camera samples of each pixel that hit a surface
(:func:`wavlight.relight.converge.bake_hits` over the bake's spp) is the alpha, and the colour
is the frame divided by it (the surface's own colour on a silhouette's pixel; 0 where it is 0).
A view bake's frames do not keep their hit shares: its PNG stays opaque, hidden pixels black
(docs/decisions/viewer-designer-tools.md).
"""
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


def encode(image: np.ndarray, exposure: float, encoding: str, tonemap: str = TONEMAP.default) -> bytes:
    """The frame's picture as the page decodes it: JPEG (quality :data:`JPEG_QUALITY`) or raw
    RGBA rows (W x H x 4 bytes)."""
    if encoding == "raw":
        return tone_map(image, exposure, alpha=True, tonemap=tonemap).tobytes()
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(tone_map(image, exposure, tonemap=tonemap)).save(out, "JPEG", quality=JPEG_QUALITY)
    return out.getvalue()


def straight(image: np.ndarray, coverage: np.ndarray) -> np.ndarray:
    """(H, W, 3): the linear ``image`` of a frame without background divided by its ``coverage``
    (H, W) where that is > 0 (a silhouette's pixel: the surface's colour, not its share), 0 where
    it is 0: the colour of a straight-alpha picture whose alpha is the coverage."""
    cover = np.asarray(coverage, np.float32)[..., None]
    return np.where(cover > 0, np.asarray(image, np.float32) / np.where(cover > 0, cover, 1.0), 0.0).astype(np.float32)


def png(image: np.ndarray, exposure: float, tonemap: str = TONEMAP.default, coverage=None) -> bytes:
    """The frame as the page shows it (times 2^exposure through the tone curve, 8-bit sRGB) as a
    PNG: RGB, or with ``coverage`` (the background hidden, ``image`` a frame without background)
    RGBA with straight alpha: the colour :func:`straight` (the frame over the coverage), the alpha
    the coverage (0: transparent and black)."""
    from PIL import Image

    if coverage is not None and coverage.shape == image.shape[:2]:
        picture = tone_map(straight(image, coverage), exposure, alpha=True, tonemap=tonemap)
        picture[..., 3] = np.round(np.clip(coverage, 0.0, 1.0) * 255.0).astype(np.uint8)
    else:
        picture = tone_map(image, exposure, tonemap=tonemap)
    out = io.BytesIO()
    Image.fromarray(picture).save(out, "PNG")
    return out.getvalue()


def message(header: dict, payload: bytes = b"") -> bytes:
    """One binary frame message: uint32 LE length of the JSON header, the header, the payload."""
    text = json.dumps(header, separators=(",", ":")).encode()
    return struct.pack("<I", len(text)) + text + payload
