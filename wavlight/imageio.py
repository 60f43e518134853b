"""Writing images: linear float (.exr, .hdr, .pfm) or clamped, sRGB-encoded 8-bit (.png), atomically.

Negative pixels (an unbiased estimator's shadowed pixels at low spp can average below 0:
the wavelet strategy's control variate) are kept by .exr and .pfm, written as 0 to .hdr,
whose RGBE encoding has no sign (it turned -0.5 into 1.5), and clamped to 0 in .png.

The file appears complete or not at all: pixels go to a temporary file in the
same folder, which is renamed over the target only after a successful write.
"""
from __future__ import annotations

import os
import tempfile

import numpy as np

from .errors import ArgumentError, WavlightError

LINEAR = (".exr", ".hdr", ".pfm")
DISPLAY = (".png",)
FORMATS = LINEAR + DISPLAY


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """Clamp to [0, 1] and apply the sRGB transfer curve."""
    x = np.clip(np.nan_to_num(linear, nan=0.0, posinf=1.0), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def save_image(path: str, image: np.ndarray) -> None:
    """Write an (H, W, 3) float image; the format follows the extension (.exr .hdr .pfm .png)."""
    import OpenImageIO as oiio

    path = str(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in FORMATS:
        raise WavlightError(f"{path}: unsupported output format {ext or '(none)'!r} "
                            f"(use {', '.join(FORMATS)})")
    try:
        image = np.asarray(image, np.float32)
    except (TypeError, ValueError):
        raise ArgumentError(f"{path}: expected an (H, W, 3) image of numbers, got {type(image).__name__}") from None
    if image.ndim != 3 or image.shape[2] != 3:
        raise WavlightError(f"{path}: expected an (H, W, 3) image, got shape {image.shape}")
    if not np.all(np.isfinite(image)):
        raise WavlightError(f"{path}: refusing to write an image with NaN or Inf pixels")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise WavlightError(f"{path}: folder {folder} does not exist")
    if ext in DISPLAY:
        pixels, fmt = (srgb_encode(image) * 255.0 + 0.5).astype(np.uint8), oiio.UINT8
    elif ext == ".hdr":   # RGBE has no sign
        pixels, fmt = np.ascontiguousarray(np.maximum(image, 0.0)), oiio.FLOAT
    else:
        pixels, fmt = np.ascontiguousarray(image), oiio.FLOAT
    if os.path.isdir(path):
        raise WavlightError(f"{path}: is a folder")
    try:
        fd, tmp = tempfile.mkstemp(prefix=".wavlight-", suffix=ext, dir=folder)
    except OSError as e:
        raise WavlightError(f"{path}: cannot write ({e.strerror})") from None
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    try:
        out = oiio.ImageOutput.create(tmp)
        if out is None:
            raise WavlightError(f"{path}: cannot create writer ({oiio.geterror().strip()})")
        spec = oiio.ImageSpec(image.shape[1], image.shape[0], 3, fmt)
        ok = out.open(tmp, spec) and out.write_image(pixels)
        err = out.geterror()
        out.close()
        if not ok:
            raise WavlightError(f"{path}: write failed ({err.strip() or 'unknown error'})")
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes files private; outputs get the usual mode
        os.replace(tmp, path)
    except OSError as e:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise WavlightError(f"{path}: cannot write ({e.strerror})") from None
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
