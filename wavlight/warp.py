"""Warps between the unit square and directions, with their densities (numpy, vectorised).

Naming follows Mitsuba 3's ``warp.h``: ``square_to_X(u)`` maps uniform points to
directions and ``square_to_X_pdf(d)`` is the density per unit solid angle (no inverse
warps are needed here). Local frames have the normal along +z.
The environment's own square (the light tree's lat-long parameterization) is in
:mod:`wavlight.envmap`.
"""
from __future__ import annotations

import numpy as np

INV_PI = 1.0 / np.pi
INV_2PI = 0.5 / np.pi


def _norm(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# ----------------------------------------------------------------------------- hemisphere
def square_to_uniform_hemisphere(u: np.ndarray) -> np.ndarray:
    """(N, 2) -> (N, 3) directions, uniform over the +z hemisphere."""
    z = u[:, 0]
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = 2.0 * np.pi * u[:, 1]
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


def square_to_uniform_hemisphere_pdf(d: np.ndarray) -> np.ndarray:
    return np.where(d[:, 2] > 0, INV_2PI, 0.0)


def square_to_cosine_hemisphere(u: np.ndarray) -> np.ndarray:
    """(N, 2) -> (N, 3) directions with density cos(theta) / pi (Malley: concentric disk lifted)."""
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
    return np.maximum(d[:, 2], 0.0) * INV_PI


# ----------------------------------------------------------------------------- frames
def frame(n: np.ndarray):
    """Orthonormal tangent frames (s, t) for unit normals n (N, 3) (Duff et al. 2017)."""
    sign = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    s = np.stack([1.0 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], 1)
    t = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], 1)
    return s, t


def to_local(v, s, t, n):
    return np.stack([np.einsum("ij,ij->i", v, s), np.einsum("ij,ij->i", v, t),
                     np.einsum("ij,ij->i", v, n)], 1)


def to_world(v, s, t, n):
    return v[:, 0:1] * s + v[:, 1:2] * t + v[:, 2:3] * n
