"""Base-colour textures: sRGB decoding, the device's one buffer of texels, and the bilinear
lookup with repeat through per-hit texture coordinates.

A texture is decoded once, at load, from its 8-bit sRGB values to linear float32 (the sRGB
transfer function of IEC 61966-2-1, by a 256-entry table). The textures of a scene share one
buffer (:func:`atlas`): their texels as rows of four floats (r, g, b, 0), one after the other,
and a table of (first texel, width, height, 0) per texture. A hit's texture coordinates are
the barycentric interpolation of its face's three vertex coordinates, with embree's (u, v):
uv = (1 - u - v) uv0 + u uv1 + v uv2 (:func:`hit_uv`). The lookup (:func:`lookup`) is
bilinear between texel centres with repeat wrapping, in the OpenGL convention that trimesh's
loaders give (v = 0 the image's bottom row, row 0 of the image its top):
x = u W - 1/2, y = (1 - v) H - 1/2, texels floor(x), floor(x) + 1 (modulo W) and likewise in y.
numpy twins of kernels/texture.h (``texture_uv``, ``texture_rgb``), computed in float32 in the
kernel's order.
"""
from __future__ import annotations

import numpy as np

from .errors import WavlightError

#: the largest texture read (4096 x 4096 texels); larger images are refused with their size
MAX_TEXTURE_TEXELS = 1 << 24
#: all the textures of a scene together: 2^26 texels are 1 GiB as float RGBA on the device
MAX_ATLAS_TEXELS = 1 << 26


def _srgb_table() -> np.ndarray:
    c = np.arange(256, dtype=np.float64) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


#: linear value of each 8-bit sRGB code (IEC 61966-2-1)
SRGB_TO_LINEAR = _srgb_table()


def decode_srgb8(pixels) -> np.ndarray:
    """(H, W, 3) float32 linear values of 8-bit sRGB codes (H, W, 3) or (H, W, 4) (alpha dropped)."""
    a = np.asarray(pixels)
    if a.dtype != np.uint8 or a.ndim != 3 or a.shape[2] not in (3, 4):
        raise WavlightError(f"textures.decode_srgb8: expected (H, W, 3 or 4) uint8 codes, got {a.dtype} {a.shape}")
    return SRGB_TO_LINEAR[a[:, :, :3]]


def from_image(image) -> np.ndarray:
    """A PIL image (a base-colour texture, sRGB) as (H, W, 3) float32 linear values; a
    WavlightError for an image too large or unreadable."""
    width, height = image.size
    if width * height > MAX_TEXTURE_TEXELS or width < 1 or height < 1:
        raise WavlightError(f"a texture of {width}x{height} texels; at most {MAX_TEXTURE_TEXELS} texels are read")
    try:
        rgb = np.asarray(image.convert("RGB"), np.uint8)
    except Exception as e:   # PIL raises many types for truncated or broken files
        raise WavlightError(f"unreadable texture: {str(e).splitlines()[0] if str(e) else type(e).__name__}") from None
    return decode_srgb8(rgb)


def atlas(textures) -> tuple[np.ndarray, np.ndarray]:
    """The textures (H, W, 3) as one buffer: texels (T, 4) float32 (r, g, b, 0) and the table
    (n, 4) int32 of (first texel, width, height, 0); one dummy texel and row without textures."""
    textures = list(textures)
    total = sum(t.shape[0] * t.shape[1] for t in textures)
    if total > MAX_ATLAS_TEXELS:
        raise WavlightError(f"the scene's textures hold {total} texels; at most {MAX_ATLAS_TEXELS} "
                            f"({MAX_ATLAS_TEXELS * 16 >> 30} GiB as float RGBA)")
    texels = np.zeros((max(total, 1), 4), np.float32)
    table = np.zeros((max(len(textures), 1), 4), np.int32)
    first = 0
    for k, t in enumerate(textures):   # textures, not texels
        h, w = t.shape[:2]
        texels[first:first + h * w, :3] = t.reshape(-1, 3)
        table[k] = (first, w, h, 0)
        first += h * w
    return texels, table


def face_uv(faces, vertex_uv) -> np.ndarray:
    """(F, 6) float32: each face's three vertices' (u, v), the rows the kernel reads."""
    f = np.asarray(faces, np.int64)
    uv = np.asarray(vertex_uv, np.float32)
    return np.ascontiguousarray(uv[f].reshape(len(f), 6))


def hit_uv(face_uv_rows, face, bu, bv) -> np.ndarray:
    """(N, 2) float32 texture coordinates of hits on ``face`` at embree's barycentric (bu, bv):
    (1 - bu - bv) uv0 + bu uv1 + bv uv2, in float32 in the kernel's order."""
    rows = np.asarray(face_uv_rows, np.float32)[np.asarray(face, np.int64)]
    bu, bv = np.asarray(bu, np.float32), np.asarray(bv, np.float32)
    w0 = np.float32(1) - bu - bv
    u = w0 * rows[:, 0] + bu * rows[:, 2] + bv * rows[:, 4]
    v = w0 * rows[:, 1] + bu * rows[:, 3] + bv * rows[:, 5]
    return np.stack([u, v], 1).astype(np.float32)


def _wrap(x, n):
    """(first texel index, weight of the next) of coordinate x (float32, texel units) on a
    repeating axis of n texels."""
    nf = n.astype(np.float32)
    xr = x - nf * np.floor(x / nf)
    x0 = np.floor(xr)
    frac = xr - x0
    i0 = np.clip(np.nan_to_num(x0, nan=0.0, posinf=0.0, neginf=0.0), -2.0 ** 30, 2.0 ** 30).astype(np.int64)
    i0 = np.where(i0 >= n, i0 - n, i0)
    i0 = np.where(i0 < 0, i0 + n, i0)
    i0 = np.clip(i0, 0, n - 1)
    i1 = np.where(i0 + 1 >= n, 0, i0 + 1)
    return i0, i1, np.clip(frac, np.float32(0), np.float32(1)).astype(np.float32)


def lookup(texels, table, texture, uv) -> np.ndarray:
    """(N, 3) float32: the bilinear, repeating lookup of texture index ``texture`` (N,) (-1: no
    texture, giving 1) at texture coordinates uv (N, 2), in the buffer of :func:`atlas`."""
    texels = np.asarray(texels, np.float32)
    table = np.asarray(table, np.int64)
    texture = np.asarray(texture, np.int64)
    uv = np.asarray(uv, np.float32)
    out = np.ones((len(texture), 3), np.float32)
    has = texture >= 0
    if not has.any():
        return out
    row = table[texture[has]]
    first, w, h = row[:, 0], row[:, 1], row[:, 2]
    x = uv[has, 0] * w.astype(np.float32) - np.float32(0.5)
    y = (np.float32(1) - uv[has, 1]) * h.astype(np.float32) - np.float32(0.5)
    x0, x1, fx = _wrap(x.astype(np.float32), w)
    y0, y1, fy = _wrap(y.astype(np.float32), h)
    c = [texels[first + yy * w + xx, :3] for yy, xx in ((y0, x0), (y0, x1), (y1, x0), (y1, x1))]
    gx, gy = (np.float32(1) - fx)[:, None], (np.float32(1) - fy)[:, None]
    out[has] = gy * (gx * c[0] + fx[:, None] * c[1]) + fy[:, None] * (gx * c[2] + fx[:, None] * c[3])
    return out
