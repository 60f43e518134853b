"""Warps between the unit square and directions, with their densities (numpy, vectorised).

Naming follows Mitsuba 3's ``warp.h``: ``square_to_X(u)`` maps uniform points to
directions, ``X_to_square(d)`` inverts it, ``square_to_X_pdf(d)`` is the density
per unit solid angle. Local frames have the normal along +z.

The equal-area octahedral map is Clarberg's "Fast equal-area mapping of the
(hemi)sphere using SIMD" (2008), as used by pbrt-v4; it makes a square's mass
proportional to its solid angle, so pdf_solid_angle = pdf_square / (4 pi).
"""
from __future__ import annotations

import numpy as np

INV_PI = 1.0 / np.pi
INV_2PI = 0.5 / np.pi
INV_4PI = 0.25 / np.pi


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


# ----------------------------------------------------------------------------- sphere, equal area
def square_to_sphere_equal_area(u: np.ndarray) -> np.ndarray:
    """Clarberg's equal-area octahedral map: (N, 2) in [0,1]^2 -> (N, 3) unit vectors."""
    a = 2.0 * u[:, 0] - 1.0
    b = 2.0 * u[:, 1] - 1.0
    ap, bp = np.abs(a), np.abs(b)
    signed_distance = 1.0 - (ap + bp)
    r = 1.0 - np.abs(signed_distance)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(r == 0, 1.0, (bp - ap) / r + 1.0) * (np.pi / 4)
    z = np.copysign(1.0 - r * r, signed_distance)
    s = r * np.sqrt(np.maximum(0.0, 2.0 - r * r))
    x = np.copysign(np.cos(phi), a) * s
    y = np.copysign(np.sin(phi), b) * s
    return np.stack([x, y, z], 1)


def sphere_to_square_equal_area(d: np.ndarray) -> np.ndarray:
    """Inverse of :func:`square_to_sphere_equal_area`: (N, 3) unit vectors -> (N, 2)."""
    x, y, z = np.abs(d[:, 0]), np.abs(d[:, 1]), np.abs(d[:, 2])
    r = np.sqrt(np.maximum(0.0, 1.0 - z))
    a, b = np.maximum(x, y), np.minimum(x, y)
    with np.errstate(divide="ignore", invalid="ignore"):
        b = np.where(a == 0, 0.0, b / a)
    phi = np.arctan(b) * (2.0 / np.pi)
    phi = np.where(x < y, 1.0 - phi, phi)
    v = phi * r
    u = r - v
    south = d[:, 2] < 0
    u, v = np.where(south, 1.0 - v, u), np.where(south, 1.0 - u, v)
    u = np.copysign(u, d[:, 0])
    v = np.copysign(v, d[:, 1])
    return np.clip(np.stack([(u + 1.0) * 0.5, (v + 1.0) * 0.5], 1), 0.0, 1.0)


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
