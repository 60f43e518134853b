"""The varying factor T2 = L of a relit frame (Chen & Gao sec. 2.2, eq. 6-8): the environment
projected onto the transfer's texels, its Haar coefficients, and the K of them a frame keeps
(Ng et al. 2003's nonlinear approximation).

Texels. The transfer lives on the world-frame lat-long square of side N = 2^n: texel (row r,
column c) holds the directions with u = atan2(d.x, -d.z) / 2 pi in [c, c + 1) / N and
v = acos(d.y) / pi in [r, r + 1) / N (the scene format's convention with rotate_y = 0), of
solid angle Omega_r = (cos(pi r / N) - cos(pi (r + 1) / N)) 2 pi / N. The lighting of a frame
is the map turned by ``rotate_y`` (world = R_y map: u_map = u_world + rotate_y / 360) and
scaled; its texel value is the exact mean radiance over the texel's solid angle,
integral(L d omega) / Omega, as the light tree's leaves are exact integrals: the map is
piecewise constant, so rows integrate in cos(theta) and columns in phi, the latter through
the cumulative integral along phi, periodic, so that any rotation is exact (a rotation by
whole texels is a cyclic shift of the columns).

Coefficients. :func:`wavlight.haar.forward` of each channel (the unit square's orthonormal
Haar basis); for two texel arrays A, B, sum_t A_t B_t = N^2 sum_i A^_i B^_i (Parseval), which
:mod:`wavlight.relight.frame` uses.

Terms. A frame keeps the K coefficients of largest priority, one index set for the three
channels (ranked by the luminance's coefficients): ``"magnitude"`` |L^_i|, ``"area"`` |L^_i|
times the area of the wavelet's support, 4^-l (Ng et al. 2003's area-weighted selection), or
``"transfer"`` |L^_i| times the transfer's root-mean-square coefficient i over the image
(recorded by the bake): the expected contribution of term i to the frame. The default is
chosen by measurement (benchmarks/relight_error.py; docs/decisions/relight-terms.md).
"""
from __future__ import annotations

import numpy as np

from .. import cl
from ..envmap import LUMINANCE, Environment, band_overlaps
from ..errors import ArgumentError, check_degrees, check_int, check_number
from ..haar import forward
from ..haar.transform import coeff_basis

PRIORITIES = ("transfer", "area", "magnitude")
#: texel levels n at most (2^n x 2^n texels), and lighting terms K a frame keeps at most
MAX_LEVELS = 11
MAX_TERMS = 1 << 22


def texel_solid_angles(n_levels: int) -> np.ndarray:
    """(N,) solid angle of one texel of each row of the 2^n x 2^n lat-long square."""
    side = 1 << n_levels
    z = np.cos(np.arange(side + 1) * np.pi / side)
    return (z[:-1] - z[1:]) * (2 * np.pi / side)


def texel_directions(n_levels: int) -> np.ndarray:
    """(N, N, 3) world direction of each texel's centre in (u, v)."""
    side = 1 << n_levels
    u = (np.arange(side) + 0.5) / side
    v = (np.arange(side) + 0.5) / side
    phi, theta = np.meshgrid(2 * np.pi * u, np.pi * v)
    st = np.sin(theta)
    return np.stack([np.sin(phi) * st, np.cos(theta), -np.cos(phi) * st], -1)


class Projector:
    """The lighting of one map on the 2^n x 2^n world texels at any rotation: the integration over
    rows (in cos theta) and the cumulative integral along phi are made once per map, so that a
    rotation costs one interpolation per texel edge (exact for the piecewise-constant map)."""

    def __init__(self, environment: Environment, n_levels: int):
        where = "relight.Projector"
        n = check_int(where, "n_levels", n_levels, 1, MAX_LEVELS)
        self.environment, self.n_levels = environment, n
        side = 1 << n
        h, w = environment.height, environment.width
        pixels = environment.pixels.astype(np.float64)
        # rows: the solid-angle measure in cos(theta) of texel row r's overlap with map row j
        ri, rw = band_overlaps(np.arange(side + 1) / side * np.pi, np.arange(h + 1) / h * np.pi, lambda x: -np.cos(x))
        by_rows = sum(rw[:, b, None, None] * np.take(pixels, ri[:, b], axis=0) for b in range(ri.shape[1]))
        # columns: the cumulative integral along phi at the map's column edges, periodic
        self.step = 2 * np.pi / w
        self.by_rows = by_rows * self.step                                           # (N, W, 3)
        self.cum = np.concatenate([np.zeros((side, 1, 3)), np.cumsum(self.by_rows, axis=1)], axis=1)
        self.total = self.cum[:, -1]
        self.inv_omega = 1.0 / texel_solid_angles(n)

    def edges(self, rotate_y: float | None = None):
        """Each world texel edge's place in the map turned by ``rotate_y`` degrees (default: the
        environment's own): its map column (N + 1,) int64, the fraction of that column and the
        whole turns before it (N + 1,) float64."""
        where = "relight.project"
        rot = self.environment.rotate_y if rotate_y is None else check_number(where, "rotate_y", rotate_y)
        side = 1 << self.n_levels
        w = self.environment.width
        phi = np.arange(side + 1) / side * 2 * np.pi + np.radians(rot)             # map-frame phi of the edges
        turns = np.floor(phi / (2 * np.pi))
        x = (phi - turns * 2 * np.pi) / self.step                                   # in map columns, [0, W)
        col = np.minimum(x.astype(np.int64), w - 1)
        return col, x - col, turns

    def weight(self, scale: float = 1.0) -> np.ndarray:
        """(N,) scale / Omega_r, the factor of each texel row's integral."""
        return check_number("relight.project", "scale", scale, 0.0) * self.inv_omega

    def __call__(self, rotate_y: float | None = None, scale: float = 1.0) -> np.ndarray:
        """(N, N, 3) float64: the mean radiance over each world texel's solid angle of the map
        turned by ``rotate_y`` degrees (default: the environment's own), times ``scale``."""
        col, frac, turns = self.edges(rotate_y)
        at = (np.take(self.cum, col, axis=1) + frac[None, :, None] * np.take(self.by_rows, col, axis=1)
              + turns[None, :, None] * self.total[:, None, :])                     # (N, N + 1, 3)
        return (at[:, 1:] - at[:, :-1]) * self.weight(scale)[:, None, None]


class DeviceProjector:
    """The Haar coefficients of a :class:`Projector`'s texels on the OpenCL device: the kernels
    ``lighting_tiles`` and ``lighting_top`` (kernels/relight.cl; numpy twin
    ``coefficients(projector(rotate_y, scale))``, which they equal bit for bit: the same
    operations in the same order, in double precision). The map's integrals go to the device
    once; a frame sends its N + 1 texel edges and reads the (3, N, N) coefficients back.
    Needs a device with doubles (:func:`available`)."""

    #: texels a side of a work-item's tile (it takes them through log2 TILE levels)
    TILE = 16

    def __init__(self, projector: Projector):
        self.projector = projector
        side = 1 << projector.n_levels
        self.tile = min(self.TILE, side)
        self.cum = cl.to_device(np.ascontiguousarray(projector.cum, np.float64))
        self.by_rows = cl.to_device(np.ascontiguousarray(projector.by_rows, np.float64))
        self.total = cl.to_device(np.ascontiguousarray(projector.total, np.float64))

    @staticmethod
    def available() -> bool:
        """Whether the device computes in double precision (the kernels' only precision)."""
        return "cl_khr_fp64" in cl.runtime().device.extensions.split()

    def coefficients(self, rotate_y: float | None = None, scale: float = 1.0, queue=None) -> np.ndarray:
        """(3, N, N) float64: :func:`coefficients` of ``projector(rotate_y, scale)``."""
        queue = queue or cl.thread_queue()
        p, n = self.projector, self.projector.n_levels
        side = 1 << n
        col, frac, turns = p.edges(rotate_y)
        edges = np.zeros((4, side + 1))          # one upload: columns (exact as doubles), fractions, turns, weights
        edges[0], edges[1], edges[2], edges[3, :side] = col, frac, turns, p.weight(scale)
        tiles = (side // self.tile) ** 2
        coeffs = cl.scratch("lighting_coeffs", 3 * side * side * 8)
        grid = cl.scratch("lighting_grid", 3 * tiles * 8)
        prog = cl.program("relight.cl")
        group = 4 if tiles % 4 == 0 else 1   # several groups: left to PoCL, all were one, on one core
        cl.kernel(prog, "lighting_tiles")(
            queue, (3 * tiles,), (group,), np.uint32(n), np.uint32(self.tile), np.int32(p.environment.width), self.cum,
            self.by_rows, self.total, cl.upload("lighting_edges", edges, queue), coeffs, grid)
        if tiles > 1:
            cl.kernel(prog, "lighting_top")(queue, (3,), None, np.uint32(n), np.uint32(self.tile), coeffs, grid)
        return cl.read(coeffs, (3, side, side), np.float64, queue)


def turntable(start: float, frames: int) -> list[float]:
    """The rotations, degrees, of ``frames`` frames of a full turn about +Y from ``start``:
    start reduced modulo 360 first (:func:`wavlight.errors.check_degrees`; a step added to an
    unreduced 1e17 would be lost), then 360 i / frames added."""
    start = check_degrees("relight.turntable", "start", start)
    frames = check_int("relight.turntable", "frames", frames, 1, None)
    return [start + 360.0 * i / frames for i in range(frames)]


def project(environment: Environment, n_levels: int, rotate_y: float | None = None, scale: float = 1.0) -> np.ndarray:
    """(N, N, 3) float64: the mean radiance over each world texel's solid angle of the map turned
    by ``rotate_y`` degrees (default: the environment's own) and multiplied by ``scale``; exact
    for the piecewise-constant map (module docstring; :class:`Projector` for many rotations)."""
    return Projector(environment, n_levels)(rotate_y, scale)


def coefficients(texels: np.ndarray) -> np.ndarray:
    """(3, N, N) Haar coefficients of (N, N, 3) texel values, channel by channel."""
    return forward(np.moveaxis(np.asarray(texels, np.float64), -1, 0))


def priority(coeffs: np.ndarray, kind: str = "transfer", transfer_rms: np.ndarray | None = None) -> np.ndarray:
    """(N^2,) the importance of each coefficient of (3, N, N) lighting coefficients (module
    docstring); ``transfer_rms`` (N, N) for ``"transfer"``."""
    if kind not in PRIORITIES:
        raise ArgumentError(f"relight.priority: kind must be one of {' | '.join(PRIORITIES)}, got {kind!r}")
    lum = np.abs(np.tensordot(LUMINANCE.astype(np.float64), coeffs, axes=1)).ravel()
    if kind == "magnitude":
        return lum
    if kind == "area":
        n = int(np.log2(coeffs.shape[-1]))
        level, _, _, m = coeff_basis(np.arange(lum.size), n)
        return lum * np.where(m == 0, 1.0, 4.0 ** -level.astype(np.float64))
    if transfer_rms is None:
        raise ArgumentError("relight.priority: 'transfer' needs the transfer's rms coefficients")
    return lum * np.asarray(transfer_rms, np.float64).ravel()


def select_terms(coeffs: np.ndarray, terms: int, kind: str = "transfer", transfer_rms=None) -> np.ndarray:
    """The flat indices (K,) int64 of the ``terms`` coefficients of highest priority, sorted
    by index (ties: the lower index first); coefficients of zero priority are never kept.
    The K-th largest priority t comes from a partition (O(N^2), not a sort): every index above
    t, then the lowest indices at t, the same set as the first K of a sort by (-priority, index)."""
    p = priority(coeffs, kind, transfer_rms)
    k = min(int(terms), int(np.count_nonzero(p)))
    if k <= 0:
        return np.zeros(0, np.int64)
    t = np.partition(p, p.size - k)[p.size - k]
    above = np.flatnonzero(p > t)
    at = np.flatnonzero(p == t)[:k - len(above)]
    return np.sort(np.concatenate([above, at])).astype(np.int64)
