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
    save_images([(path, image)])


def save_images(outputs) -> None:
    """Write several (path, image) pairs all or nothing: every image goes to its temporary
    file first, and the temporaries are renamed over the targets only once all are written
    (an error in any leaves none of them written)."""
    outputs = [(str(path), image) for path, image in outputs]
    temps = []
    try:
        for path, image in outputs:
            temps.append((_write_temporary(path, image), path))
        for tmp, path in temps:
            os.replace(tmp, path)
    except OSError as e:
        _remove(t for t, _ in temps)
        raise WavlightError(f"{path}: cannot write ({e.strerror})") from None
    except BaseException:
        _remove(t for t, _ in temps)
        raise


def _remove(paths):
    for tmp in paths:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _write_temporary(path: str, image) -> str:
    """Check the image and the target, write the pixels to a temporary file beside the target
    and return its name (removed again if anything fails)."""
    import OpenImageIO as oiio

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
        # a writer may report a failed write (a full disk) only in its error text, while
        # write_image and close return True (OpenImageIO's PNG writer does): both count
        err = out.geterror()
        ok = out.close() and ok
        err = (err + " " + out.geterror()).strip()
        if not ok or err:
            raise WavlightError(f"{path}: write failed ({err.splitlines()[0].strip() if err else 'unknown error'})")
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes files private; outputs get the usual mode
        return tmp
    except OSError as e:
        _remove([tmp])
        raise WavlightError(f"{path}: cannot write ({e.strerror})") from None
    except BaseException:
        _remove([tmp])
        raise
