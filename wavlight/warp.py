"""Warps between the unit square and directions, with their densities (numpy, vectorised).

Naming follows Mitsuba 3's ``warp.h``: ``square_to_X(u)`` maps uniform points to
directions and ``square_to_X_pdf(d)`` is the density per unit solid angle (no inverse
warps are needed here). Local frames have the normal along +z.
The environment's own square (the light tree's lat-long parameterization) is in
:mod:`wavlight.envmap`.
"""
from __future__ import annotations

import numpy as np

from .errors import ArgumentError, check_real

INV_PI = 1.0 / np.pi
INV_2PI = 0.5 / np.pi


def _norm(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _rows(where: str, name: str, a, width: int, count: int | None = None) -> np.ndarray:
    """a as an (N, width) array of numbers (N = count if given), else ArgumentError."""
    a = check_real(where, name, a)
    if a.ndim != 2 or a.shape[1] != width or (count is not None and len(a) != count):
        want = f"({'N' if count is None else count}, {width})"
        raise ArgumentError(f"{where}: {name} must be {want}, got shape {a.shape}")
    return a


def _unit_square(where: str, u) -> np.ndarray:
    """u as (N, 2) points of [0, 1]^2 (NaN refused), else ArgumentError."""
    u = _rows(where, "u", u, 2)
    if u.size and not (np.all(u >= 0) and np.all(u <= 1)):
        raise ArgumentError(f"{where}: u must lie in [0, 1]^2 (no NaN), got values in [{np.min(u)}, {np.max(u)}]")
    return u


# ----------------------------------------------------------------------------- hemisphere
def square_to_uniform_hemisphere(u: np.ndarray) -> np.ndarray:
    """(N, 2) -> (N, 3) directions, uniform over the +z hemisphere."""
    u = _unit_square("warp.square_to_uniform_hemisphere", u)
    z = u[:, 0]
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = 2.0 * np.pi * u[:, 1]
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


def square_to_uniform_hemisphere_pdf(d: np.ndarray) -> np.ndarray:
    d = _rows("warp.square_to_uniform_hemisphere_pdf", "d", d, 3)
    return np.where(d[:, 2] > 0, INV_2PI, 0.0)


def square_to_cosine_hemisphere(u: np.ndarray) -> np.ndarray:
    """(N, 2) -> (N, 3) directions with density cos(theta) / pi (Malley: concentric disk lifted)."""
    u = _unit_square("warp.square_to_cosine_hemisphere", u)
    a = 2.0 * u[:, 0] - 1.0
    b = 2.0 * u[:, 1] - 1.0
    use_a = np.abs(a) > np.abs(b)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(use_a, a, b)
        phi = np.where(use_a, (np.pi / 4) * (b / a), np.pi / 2 - (np.pi / 4) * (a / b))
    phi = np.where((a == 0) & (b == 0), 0.0, phi)
    x, y = r * np.cos(phi), r * np.sin(phi)
    z = np.sqrt(np.maximum(0.0, 1.0 - x * x - y * y))
    return np.stack([x, y, z], 1)


def square_to_cosine_hemisphere_pdf(d: np.ndarray) -> np.ndarray:
    d = _rows("warp.square_to_cosine_hemisphere_pdf", "d", d, 3)
    return np.maximum(d[:, 2], 0.0) * INV_PI


# ----------------------------------------------------------------------------- frames
def frame(n: np.ndarray):
    """Orthonormal tangent frames (s, t) for unit normals n (N, 3) (Duff et al. 2017)."""
    n = _rows("warp.frame", "n", n, 3)
    sign = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    s = np.stack([1.0 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], 1)
    t = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], 1)
    return s, t


def _frame_args(where: str, v, s, t, n):
    v = _rows(where, "v", v, 3)
    return (v,) + tuple(_rows(where, k, a, 3, len(v)) for k, a in (("s", s), ("t", t), ("n", n)))


def to_local(v, s, t, n):
    """World vectors v (N, 3) in the frames (s, t, n) (each (N, 3))."""
    v, s, t, n = _frame_args("warp.to_local", v, s, t, n)
    return np.stack([np.einsum("ij,ij->i", v, s), np.einsum("ij,ij->i", v, t),
                     np.einsum("ij,ij->i", v, n)], 1)


def to_world(v, s, t, n):
    """Local vectors v (N, 3) of the frames (s, t, n) (each (N, 3)) in world space."""
    v, s, t, n = _frame_args("warp.to_world", v, s, t, n)
    return v[:, 0:1] * s + v[:, 1:2] * t + v[:, 2:3] * n
