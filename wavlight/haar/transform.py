"""The nonstandard 2D Haar transform (Chen & Gao sec. 4.1, eq. 13; Stollnitz et al. 1996): the dense
layout of coefficients, forward and inverse transforms on the host and on the device
(kernels/haar.cl). Conventions: :mod:`wavlight.haar`."""
from __future__ import annotations

import numpy as np

from .. import cl
from ..errors import ArgumentError, check_int, check_integers, check_real
from .tree import tree_size

MAX_LEVELS = 31  # flat indices 4^n - 1 fit int64


# ============================================================================= layout
def coeff_index(level, x, y, m, n_levels: int):
    """Flat dense index of basis function (level, x, y, m); m = 0 is the scaling function
    (level = x = y = 0). Vectorised."""
    where = "haar.coeff_index"
    n_levels = check_int(where, "n_levels", n_levels, 0, MAX_LEVELS)
    level, x, y, m = broadcast_sets(where, {k: check_integers(where, k, v) for k, v in
                                        (("level", level), ("x", x), ("y", y), ("m", m))})
    if np.any((m < 0) | (m > 3)):
        raise ArgumentError(f"{where}: m must be 0 (scaling) or 1, 2, 3 (wavelets), got {m[(m < 0) | (m > 3)][0]}")
    wav = m > 0
    if np.any(wav & ((level < 0) | (level >= n_levels))):
        raise ArgumentError(f"{where}: a wavelet's level must be in [0, {n_levels}), got "
                            f"{level[wav & ((level < 0) | (level >= n_levels))][0]}")
    side = np.left_shift(1, np.where(wav, level, 0))
    if np.any(wav & ((x < 0) | (y < 0) | (x >= side) | (y >= side))):
        raise ArgumentError(f"{where}: a wavelet's x and y must be in [0, 2^level)")
    s = np.left_shift(1, level)
    row = np.where((m == 2) | (m == 3), s + y, y)
    col = np.where((m == 1) | (m == 3), s + x, x)
    return np.where(m == 0, 0, row * (1 << n_levels) + col)


def coeff_basis(index, n_levels: int):
    """(level, x, y, m) of flat dense indices; the scaling function is (0, 0, 0, 0). Vectorised."""
    n_levels = check_int("haar.coeff_basis", "n_levels", n_levels, 0, MAX_LEVELS)
    index = check_integers("haar.coeff_basis", "index", index, 4 ** n_levels)
    row, col = np.divmod(index, 1 << n_levels)
    big = np.maximum(row, col)
    level = np.frexp(np.maximum(big, 1).astype(np.float64))[1].astype(np.int64) - 1
    s = np.left_shift(1, level)
    m = np.where(big == 0, 0, np.where(row < s, 1, np.where(col < s, 2, 3)))
    x = np.where((m == 1) | (m == 3), col - s, col)
    y = np.where((m == 2) | (m == 3), row - s, row)
    z = np.zeros_like(index)
    return np.where(m == 0, z, level), np.where(m == 0, z, x), np.where(m == 0, z, y), m


def node_scale(n_levels: int) -> np.ndarray:
    """2^l for every node of a pyramid: F^0 = node_scale * masses (eq. 17)."""
    n_levels = check_int("haar.node_scale", "n_levels", n_levels, 0, MAX_LEVELS)
    return np.concatenate([np.full(4 ** l, 2.0 ** l) for l in range(n_levels + 1)])


def levels_of(a: np.ndarray, where: str, name: str) -> int:
    """n of (..., 2^n, 2^n) arrays, else ArgumentError."""
    side = a.shape[-1] if a.ndim >= 2 else 0
    if a.ndim < 2 or a.shape[-2] != side or side < 1 or side & (side - 1):
        raise ArgumentError(f"{where}: {name} must be (..., 2^n, 2^n) arrays, got shape {a.shape}")
    return side.bit_length() - 1


def as_float(a, where: str, name: str) -> np.ndarray:
    """a as a float array (float32 or wider) of finite real numbers, else ArgumentError."""
    a = check_real(where, name, a, finite=True)
    return a.astype(np.result_type(a.dtype, np.float32), copy=False)


def checked_square(a, where: str, name: str):
    """a as finite float (..., 2^n, 2^n) arrays, and n."""
    a = as_float(a, where, name)
    return a, levels_of(a, where, name)


def broadcast_sets(where: str, arrays: dict) -> list:
    """The named arrays broadcast together, else ArgumentError naming their shapes."""
    try:
        return np.broadcast_arrays(*arrays.values())
    except ValueError:
        shapes = ", ".join(f"{k} {np.shape(v)}" for k, v in arrays.items())
        raise ArgumentError(f"{where}: shapes do not broadcast: {shapes}") from None


def embed(c: np.ndarray, n: int) -> np.ndarray:
    """Coefficients of resolution 2^k zero-padded to 2^n (the same function)."""
    k = c.shape[-1]
    if k == 1 << n:
        return c
    out = np.zeros(c.shape[:-2] + (1 << n, 1 << n), c.dtype)
    out[..., :k, :k] = c
    return out


def details(c: np.ndarray, l: int):
    """The three wavelet blocks (m = 1, 2, 3) of level l, each (..., 2^l, 2^l)."""
    s = 1 << l
    return c[..., :s, s:2 * s], c[..., s:2 * s, :s], c[..., s:2 * s, s:2 * s]


# ============================================================================= transform (sec. 4.1)
def forward(images) -> np.ndarray:
    """Orthonormal nonstandard Haar transform of (..., 2^n, 2^n) images (eq. 13), dense layout."""
    a, n = checked_square(images, "haar.forward", "images")
    out = np.empty_like(a)
    s = a * 2.0 ** -n  # F^0_{n,t} = 2^-n * pixel
    for l in range(n - 1, -1, -1):
        h = 1 << l
        a00, a01 = s[..., 0::2, 0::2], s[..., 0::2, 1::2]
        a10, a11 = s[..., 1::2, 0::2], s[..., 1::2, 1::2]
        out[..., :h, h:2 * h] = 0.5 * ((a00 - a01) + (a10 - a11))
        out[..., h:2 * h, :h] = 0.5 * ((a00 + a01) - (a10 + a11))
        out[..., h:2 * h, h:2 * h] = 0.5 * ((a00 - a01) - (a10 - a11))
        s = 0.5 * ((a00 + a01) + (a10 + a11))
    out[..., 0, 0] = s[..., 0, 0]
    return out


def scaling_levels(c: np.ndarray, last: int):
    """Yield (l, F^0_l) for l = 0..last from dense coefficients, top down (inverse steps)."""
    s = c[..., 0:1, 0:1]
    yield 0, s
    for l in range(last):
        h = 1 << l
        d1, d2, d3 = details(c, l)
        nxt = np.empty(s.shape[:-2] + (2 * h, 2 * h), s.dtype)
        nxt[..., 0::2, 0::2] = 0.5 * ((s + d1) + (d2 + d3))
        nxt[..., 0::2, 1::2] = 0.5 * ((s - d1) + (d2 - d3))
        nxt[..., 1::2, 0::2] = 0.5 * ((s + d1) - (d2 + d3))
        nxt[..., 1::2, 1::2] = 0.5 * ((s - d1) - (d2 - d3))
        s = nxt
        yield l + 1, s


def inverse(coeffs) -> np.ndarray:
    """Images (..., 2^n, 2^n) from dense coefficients; inverse of :func:`forward`."""
    c, n = checked_square(coeffs, "haar.inverse", "coeffs")
    for _, s in scaling_levels(c, n):
        pass
    return s * 2.0 ** n



def texel_values(coeffs, which, x, y) -> np.ndarray:
    """(N,) float64: ``inverse(coeffs)[which, y, x]`` for dense coefficient sets (T, 2^n, 2^n),
    without the whole inverse: per texel its n + 1 scaling values top down (eq. 13's children
    0.5 (F^0 +- d1 +- d2 +- d3)), 3n + 1 coefficients read; a loop over levels, not texels."""
    c, n = checked_square(coeffs, "haar.texel_values", "coeffs")
    if c.ndim != 3:
        raise ArgumentError(f"haar.texel_values: coeffs must be (T, 2^n, 2^n), got shape {c.shape}")
    which, x, y = (np.asarray(a, np.int64).reshape(-1) for a in (which, x, y))
    side = 1 << n
    flat = c.reshape(len(c), side * side)
    s = flat[which, 0].astype(np.float64)
    for l in range(n):   # levels, not texels
        h = 1 << l
        xl, yl = x >> (n - l), y >> (n - l)
        s1 = 1 - 2 * ((x >> (n - l - 1)) & 1)
        s2 = 1 - 2 * ((y >> (n - l - 1)) & 1)
        d1 = flat[which, yl * side + h + xl]
        d2 = flat[which, (h + yl) * side + xl]
        d3 = flat[which, (h + yl) * side + h + xl]
        s = 0.5 * (s + s1 * d1 + s2 * d2 + (s1 * s2) * d3)
    return s * 2.0 ** n


# ============================================================================= OpenCL (kernels/haar.cl)
def forward_cl(images, queue=None):
    """Forward transform of (..., 2^n, 2^n) images on the device (any leading axes, e.g.
    colour channels or a batch, folded into one batch of T), one launch per level.

    returns coeffs (..., 2^n, 2^n) float32 (dense layout) and the box-mass pyramids
    (..., tree_size(n)) float32 computed on the way (haar/tree.py layout).
    """
    where = "haar.forward_cl"
    img = np.ascontiguousarray(as_float(images, where, "images"), np.float32)
    if img.ndim < 2:
        raise ArgumentError(f"{where}: images must be (..., 2^n, 2^n), got shape {img.shape}")
    n = levels_of(img, where, "images")
    lead, side, stride = img.shape[:-2], 1 << n, tree_size(n)
    img = img.reshape(-1, side, side)
    T = img.shape[0]
    if T == 0 or n == 0:  # no image, or one pixel: F^0 = pixel = mass
        return img.reshape(lead + (side, side)).copy(), img.reshape(lead + (stride,)).copy()
    queue = queue or cl.thread_queue()
    prog = cl.program("haar.cl")
    src = cl.to_device(img)
    pyr = cl.empty(4 * T * stride)
    coef = cl.empty(img.nbytes)
    cl.kernel(prog, "haar_load_leaves")(queue, (side * side, T), None, src, pyr, np.uint64(stride),
                                        np.int32(n))
    knl = cl.kernel(prog, "haar_forward_level")
    for level in range(n - 1, -1, -1):
        knl(queue, (4 ** level, T), None, pyr, np.uint64(stride), coef, np.int32(n), np.int32(level))
    return (cl.read(coef, img.shape, np.float32, queue).reshape(lead + (side, side)),
            cl.read(pyr, (T, stride), np.float32, queue).reshape(lead + (stride,)))


def inverse_cl(coeffs, queue=None):
    """Inverse transform of (..., 2^n, 2^n) dense coefficients on the device (any leading axes,
    folded into one batch), one launch per level (kernels/haar.cl ``haar_inverse_level``;
    numpy twin :func:`inverse`): images of the same shape, float32."""
    where = "haar.inverse_cl"
    c = np.ascontiguousarray(as_float(coeffs, where, "coeffs"), np.float32)
    if c.ndim < 2:
        raise ArgumentError(f"{where}: coeffs must be (..., 2^n, 2^n), got shape {c.shape}")
    n = levels_of(c, where, "coeffs")
    shape = c.shape
    c = c.reshape((-1,) + shape[-2:])
    T = c.shape[0]
    if T == 0 or n == 0:   # one pixel: pixel = F^0
        out = c.copy()
    else:
        queue = queue or cl.thread_queue()
        knl = cl.kernel(cl.program("haar.cl"), "haar_inverse_level")
        src = cl.to_device(c)
        first = np.zeros((T, c[0].size), np.float32)   # level 0: F^0 of each set, at its tree's start
        first[:, 0] = c[:, 0, 0]
        bufs = [cl.to_device(first), cl.empty(c.nbytes)]
        for level in range(n):
            scale = np.float32(2.0 ** n if level == n - 1 else 1.0)
            knl(queue, (4 ** level, T), None, src, bufs[0], bufs[1], np.int32(n), np.int32(level), scale)
            bufs.reverse()
        out = cl.read(bufs[0], c.shape, np.float32, queue)
    return out.reshape(shape)
