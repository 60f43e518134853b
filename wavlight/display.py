"""Display transforms: linear radiance -> what a screen shows (exposure, a tone curve, sRGB encoding).

A displayed value is, per channel,

    srgb(curve(x * 2^exposure))

- ``exposure`` (:data:`EXPOSURE`, stops): the linear value is multiplied by 2^exposure first.
- ``curve`` (:data:`TONEMAP`) maps [0, inf) to [0, 1]:

  ``clamp``  min(max(x, 0), 1): what wavlight's PNGs always held (the default: the same bytes).

  ``aces``   Narkowicz's fit of the ACES filmic curve (RRT + ODT, sampled from the ACES
             reference images through the Rec. 709 D65 ODT with its 2.4 gamma removed),
             f(x) = x (2.51 x + 0.03) / (x (2.43 x + 0.59) + 0.14), clamped to [0, 1], per
             channel, as published: "pre-exposed, so 1 on input maps to ~0.8 on output"
             (K. Narkowicz, "ACES Filmic Tone Mapping Curve", 2016,
             knarkowicz.wordpress.com/2016/01/06/aces-filmic-tone-mapping-curve; CC0 / MIT).
             Highlights roll off smoothly to white instead of clipping, and its toe deepens
             the darks a little. A per-channel fit desaturates nothing: a bright saturated
             colour stays saturated (the fit's documented limit).
- ``srgb`` is the sRGB transfer function of IEC 61966-2-1 (:func:`srgb_encode`).

NaN shows black and +Inf white. The transforms apply to display outputs (PNG, animations, the
viewer) only; linear outputs (.exr .hdr .pfm) hold the radiance itself (:mod:`wavlight.imageio`
refuses a transform for them). Two implementations of the 8-bit encoding share these
definitions: :func:`encode8`, exact in float32 (the files), and :func:`encode8_lut`, a lookup
table of the sRGB curve (the viewer's frames, within one 8-bit level of :func:`encode8`).
"""
from __future__ import annotations

import numpy as np

from .options import Option

#: the tone curves, the first the default
CURVES = ("clamp", "aces")
#: Narkowicz's ACES fit: f(x) = x (A x + B) / (x (C x + D) + E)
ACES_A, ACES_B, ACES_C, ACES_D, ACES_E = 2.51, 0.03, 2.43, 0.59, 0.14

EXPOSURE = Option("exposure", float, "Exposure of a display output (PNG, animations), stops: the linear image is "
                  "multiplied by 2^EV before the tone curve (a linear output, .exr .hdr .pfm, takes none).",
                  default=0.0, lo=-24.0, hi=24.0, metavar="EV")
TONEMAP = Option("tonemap", str, "Tone curve of a display output (PNG, animations): clamp to [0, 1], or aces, "
                 "Narkowicz's fit of the ACES filmic curve (highlights roll off to white; a linear output takes none).",
                 default=CURVES[0], values=CURVES)
#: the display settings, in the order the commands list them
DISPLAY = (EXPOSURE, TONEMAP)


def check(exposure=EXPOSURE.default, tonemap=TONEMAP.default, where: str = "display") -> tuple[float, str]:
    """(exposure, tonemap) checked by their records, or a one-line ArgumentError."""
    return EXPOSURE.check(exposure, where), TONEMAP.check(tonemap, where)


def is_identity(exposure=EXPOSURE.default, tonemap=TONEMAP.default) -> bool:
    """Whether the transform is the default one (exposure 0, clamp): the bytes wavlight's PNGs always had."""
    return float(exposure) == 0.0 and tonemap == CURVES[0]


def aces(x: np.ndarray) -> np.ndarray:
    """Narkowicz's ACES fit (module docstring) of values >= 0, before the clamp to [0, 1]."""
    return x * (ACES_A * x + ACES_B) / (x * (ACES_C * x + ACES_D) + ACES_E)


def tone_curve(x: np.ndarray, tonemap: str = TONEMAP.default) -> np.ndarray:
    """The curve's values in [0, 1] (float64 for other than float32 input) of linear values x
    (already exposed); NaN -> 0, +Inf -> 1, negative -> 0."""
    x = np.asarray(x)
    x = np.asarray(x, np.float32 if x.dtype == np.float32 else np.float64)
    y = np.fmax(x, x.dtype.type(0.0))                          # NaN -> 0 (fmax ignores NaN)
    if tonemap == "aces":
        with np.errstate(over="ignore", invalid="ignore"):
            a = aces(y)
        y = np.where(np.isfinite(a), a, 1.0).astype(y.dtype)   # +Inf (or an overflowed x^2): 1, its limit
    elif tonemap != "clamp":
        raise ValueError(f"unknown tone curve {tonemap!r} ({' | '.join(CURVES)})")
    return np.clip(y, 0.0, 1.0)


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """Clamp to [0, 1] and apply the sRGB transfer curve (IEC 61966-2-1)."""
    x = np.clip(np.nan_to_num(linear, nan=0.0, posinf=1.0), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def display(linear: np.ndarray, exposure: float = EXPOSURE.default, tonemap: str = TONEMAP.default) -> np.ndarray:
    """srgb(curve(x * 2^exposure)) in [0, 1] (float64): the reference of the 8-bit encoders."""
    x = np.asarray(linear, np.float64) * 2.0 ** float(exposure)
    return srgb_encode(tone_curve(x, tonemap))


def encode8(strip: np.ndarray, exposure: float = EXPOSURE.default, tonemap: str = TONEMAP.default) -> np.ndarray:
    """Linear float32 rows (finite) -> display uint8: :func:`display` x 255 rounded, computed in
    float32 with a few in-place temporaries (4 bytes per value instead of 40). With the default
    transform the values are exactly those wavlight's PNGs always had."""
    x = np.array(strip, np.float32)                     # a copy, worked on in place
    if float(exposure) != 0.0:
        x *= np.float32(2.0 ** float(exposure))
    if tonemap == "aces":
        np.maximum(x, np.float32(0.0), out=x)
        with np.errstate(over="ignore", invalid="ignore"):
            y = aces(x)
        np.copyto(x, np.where(np.isfinite(y), y, np.float32(1.0)))   # an overflowed x^2: 1 (its limit)
    elif tonemap != "clamp":
        raise ValueError(f"unknown tone curve {tonemap!r} ({' | '.join(CURVES)})")
    np.clip(x, np.float32(0.0), np.float32(1.0), out=x)
    low = x <= np.float32(0.0031308)
    lin = x * np.float32(12.92)
    np.power(x, np.float32(1 / 2.4), out=x)
    x *= np.float32(1.055)
    x -= np.float32(0.055)
    np.copyto(x, lin, where=low)
    x *= np.float32(255.0)
    x += np.float32(0.5)
    return x.astype(np.uint8)


#: sRGB lookup table: 8-bit values of the curve at LUT_SIZE evenly spaced values in [0, 1]
LUT_SIZE = 1 << 14
_LUT = (srgb_encode(np.linspace(0.0, 1.0, LUT_SIZE)) * 255.0 + 0.5).astype(np.uint8)


def encode8_lut(image: np.ndarray, exposure: float = EXPOSURE.default, tonemap: str = TONEMAP.default,
                alpha: bool = False) -> np.ndarray:
    """(H, W, 3) (or (H, W, 4) with ``alpha``: opaque) display uint8 of a linear (H, W, 3) image,
    the sRGB curve through a table of LUT_SIZE values (within one 8-bit level of :func:`encode8`;
    any input: NaN shows black and +Inf white)."""
    top = np.float32(LUT_SIZE - 1)
    h, w = image.shape[:2]
    x = np.empty((h, w, 4 if alpha else 3), np.float32)
    if alpha:
        x[..., 3] = top                    # the top of the table: 255
    if tonemap == "clamp":
        np.multiply(image, np.float32(2.0 ** exposure) * top, out=x[..., :3])
    else:
        np.multiply(image, np.float32(2.0 ** exposure), out=x[..., :3])
        x[..., :3] = tone_curve(x[..., :3], tonemap) * top
    np.fmax(x, np.float32(0.0), out=x)     # fmax / fmin: NaN -> 0, +Inf -> the top
    np.fmin(x, top, out=x)
    x += np.float32(0.5)
    return np.take(_LUT, x.astype(np.uint16))
