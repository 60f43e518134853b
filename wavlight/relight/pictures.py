"""The viewer's pictures: a linear frame times 2^exposure through a tone curve
(:data:`wavlight.display.CURVES`, the curves of ``wavlight render --tonemap``), encoded to 8-bit
sRGB in numpy (a lookup table of the sRGB curve, :func:`wavlight.display.encode8_lut`) as JPEG
(Pillow) or raw RGBA, and the binary message that carries one to the page: a 4-byte
little-endian length, a JSON header, the picture."""
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


def message(header: dict, payload: bytes = b"") -> bytes:
    """One binary frame message: uint32 LE length of the JSON header, the header, the payload."""
    text = json.dumps(header, separators=(",", ":")).encode()
    return struct.pack("<I", len(text)) + text + payload
