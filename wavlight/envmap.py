"""Distant environment light: an equirectangular RGB image, looked up nearest-texel.

Lookup (scene-format doc, same u, v as Mitsuba 3's envmap): for a world direction d,
undo ``rotate_y`` (world = R_y * map), then u = atan2(d.x, -d.z) / 2 pi wrapped to
[0, 1), v = acos(d.y) / pi, texel (floor(u W), floor(v H)), row 0 at +Y.

Importance for light sampling lives on a 2^n x 2^n equal-area octahedral square
(:mod:`wavlight.warp`): each leaf holds a conservative mean luminance over its
patch of sphere (sub-points about 8 per texel, each taking the max of its 3 x 3
neighbourhood), plus a defensive floor of ``DEFENSIVE`` times the map's mean, so
that the pdf is positive wherever the map is, for any non-black map. The leaf side is the
smallest power of two whose square has at least as many leaves as the map has
texels, at most 2^10.

The built-in procedural sky (``procedural = "sky"`` in a scene) is a smooth
gradient plus a small, very bright sun disk, made at 512 x 256 texels; see
:func:`procedural_sky` for its keys.
"""
from __future__ import annotations

import os
import warnings

import numpy as np

from . import warp
from .errors import WavlightError

LUMINANCE = np.array([0.2126, 0.7152, 0.0722], np.float32)
DEFENSIVE = 1e-3
MAX_TEXELS = 1 << 26


def read_image(path: str) -> np.ndarray:
    """(H, W, 3) float32 linear RGB from any format OpenImageIO reads."""
    import OpenImageIO as oiio

    if not os.path.isfile(path):
        raise WavlightError(f"{path}: no such file")
    config = oiio.ImageSpec()
    config.attribute("pnm:pfmflip", 1)  # PFM stores the bottom row first; read it upright
    inp = oiio.ImageInput.open(path, config)
    if inp is None:
        raise WavlightError(f"{path}: cannot read image ({oiio.geterror().strip() or 'unknown format'})")
    try:
        spec = inp.spec()
        if spec.width * spec.height > MAX_TEXELS:
            raise WavlightError(f"{path}: image of {spec.width}x{spec.height} texels is too large")
        px = inp.read_image(format=oiio.FLOAT)
    finally:
        inp.close()
    if px is None or px.size == 0:
        raise WavlightError(f"{path}: cannot read pixels")
    px = np.asarray(px, np.float32).reshape(spec.height, spec.width, spec.nchannels)
    if spec.nchannels == 1:
        px = np.repeat(px, 3, axis=2)
    elif spec.nchannels == 2:
        px = np.concatenate([px[..., :1]] * 3, axis=2)
    return np.ascontiguousarray(px[..., :3])


def sanitize(pixels: np.ndarray, name: str) -> np.ndarray:
    """Replace NaN, Inf and negative texels with 0, with one warning that counts them."""
    bad = ~np.isfinite(pixels) | (pixels < 0)
    if bad.any():
        texels = int(bad.any(axis=-1).sum())
        warnings.warn(f"{name}: {texels} texel(s) with NaN, Inf or negative values: those values set to 0",
                      stacklevel=2)
        pixels = np.where(bad, np.float32(0), pixels).astype(np.float32)
    return pixels


def procedural_sky(sun_elevation=35.0, sun_azimuth=30.0, sun_radius=0.75, sun_radiance=2.0e4,
                   zenith=(0.25, 0.45, 0.95), horizon=(0.9, 0.95, 1.0), ground=(0.3, 0.27, 0.24),
                   width=512, height=256) -> np.ndarray:
    """A lat-long sky: zenith-to-horizon gradient, flat ground, sun disk.

    Angles in degrees; the sun's azimuth is measured from -Z towards +X (the u = 0.5 + az/360 column).
    """
    v = (np.arange(height) + 0.5) / height
    u = (np.arange(width) + 0.5) / width
    theta = v * np.pi
    phi = u * 2 * np.pi
    d = np.stack(np.broadcast_arrays(
        np.sin(theta)[:, None] * np.sin(phi)[None, :], np.cos(theta)[:, None] + 0 * phi[None, :],
        -np.sin(theta)[:, None] * np.cos(phi)[None, :]), -1)
    up = np.clip(d[..., 1], 0, 1)[..., None]
    t = up ** 0.4
    sky = (1 - t) * np.array(horizon) + t * np.array(zenith)
    img = np.where(d[..., 1:2] >= 0, sky, np.array(ground))
    el, az = np.radians(sun_elevation), np.radians(sun_azimuth)
    sun = np.array([np.cos(el) * np.sin(az), np.sin(el), -np.cos(el) * np.cos(az)])
    disk = d @ sun > np.cos(np.radians(sun_radius))
    img[disk] = sun_radiance * np.array([1.0, 0.95, 0.85])
    return img.astype(np.float32)


def rotation_y(degrees: float) -> np.ndarray:
    """R_y for rotate_y: +90 sends +X to -Z (right-handed about +Y)."""
    a = np.radians(degrees)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


class Environment:
    """An equirectangular environment map with scale and rotate_y.

    pixels : (H, W, 3) float32, sanitised and multiplied by ``scale``.
    """

    def __init__(self, pixels: np.ndarray, scale: float = 1.0, rotate_y: float = 0.0, name="environment"):
        pixels = sanitize(np.asarray(pixels, np.float32), name)
        if pixels.ndim != 3 or pixels.shape[2] != 3 or pixels.shape[0] < 1 or pixels.shape[1] < 1:
            raise WavlightError(f"{name}: expected an (H, W, 3) image, got shape {pixels.shape}")
        self.name = name
        self.pixels = np.ascontiguousarray(pixels * np.float32(scale))
        self.height, self.width = self.pixels.shape[:2]
        self.rotate_y = float(rotate_y)
        self.map_from_world = rotation_y(rotate_y).T
        self.world_from_map = rotation_y(rotate_y)
        self._flat = self.pixels.reshape(-1, 3)
        self._square = None

    # -- lookup
    def texel_index(self, d_world: np.ndarray) -> np.ndarray:
        """Flat texel indices (row * W + col) for world directions (N, 3)."""
        d = d_world @ self.map_from_world.T
        u = np.arctan2(d[:, 0], -d[:, 2]) * warp.INV_2PI
        u = u - np.floor(u)
        v = np.arccos(np.clip(d[:, 1], -1.0, 1.0)) * warp.INV_PI
        col = np.minimum((u * self.width).astype(np.int64), self.width - 1)
        row = np.minimum((v * self.height).astype(np.int64), self.height - 1)
        return row * self.width + col

    def eval(self, d_world: np.ndarray) -> np.ndarray:
        """Radiance (N, 3) float32 arriving from world directions d (N, 3) (nearest texel)."""
        return self._flat[self.texel_index(d_world)]

    @property
    def is_black(self) -> bool:
        return not np.any(self.pixels > 0)

    # -- importance on the equal-area square (for the light strategy)
    def square_levels(self) -> int:
        texels = self.width * self.height
        n = 0
        while 4 ** n < texels and n < 10:
            n += 1
        return max(n, 1)

    def subpoint_grid(self, n_levels: int) -> int:
        """Side G of the sub-point grid: about 8 sub-points per texel, at least 2 per leaf side."""
        side = 1 << n_levels
        g = side
        while g * g < 8 * self.width * self.height and g < 4096:
            g *= 2
        return max(g, 2 * side)

    def subpoint_luminance_reference(self, grid: int) -> np.ndarray:
        """(G, G) luminance at the sub-points of the equal-area square (numpy twin of the kernel)."""
        c = (np.arange(grid) + 0.5) / grid
        uu, vv = np.meshgrid(c, c)
        d_sq = warp.square_to_sphere_equal_area(np.stack([uu.ravel(), vv.ravel()], 1))
        d_map = np.stack([d_sq[:, 0], d_sq[:, 2], -d_sq[:, 1]], 1)
        idx = self.texel_index(d_map @ self.world_from_map.T)
        return (self._flat @ LUMINANCE)[idx].reshape(grid, grid).astype(np.float32)

    def subpoint_luminance(self, grid: int) -> np.ndarray:
        """(G, G) luminance at the sub-points (kernel ``subpoint_luminance``, kernels/envmap.cl)."""
        from . import cl

        lum = np.ascontiguousarray(self._flat @ LUMINANCE, np.float32)
        out = cl.empty(grid * grid * 4)
        q = cl.thread_queue()
        knl = cl.kernel(cl.program("envmap.cl"), "subpoint_luminance")
        knl(q, (grid, grid), None, cl.to_device(lum), np.int32(self.width), np.int32(self.height),
            np.int32(grid), out)
        return cl.read(out, (grid, grid), np.float32, q)

    def luminance_square(self, n_levels: int | None = None, reference: bool = False) -> np.ndarray:
        """(2^n, 2^n) float32 leaf importance on the equal-area square, with the defensive floor.

        Leaf (row y, column x) covers square points u in [x, x+1)/2^n, v in [y, y+1)/2^n.
        Each leaf holds the mean over its sub-points of the max luminance in a 3 x 3
        sub-point neighbourhood: a conservative estimate, so that a texel smaller
        than a leaf still gives the leaves it touches their share (not just the floor).
        """
        n = self.square_levels() if n_levels is None else n_levels
        side = 1 << n
        g = self.subpoint_grid(n)
        sub = (self.subpoint_luminance_reference if reference else self.subpoint_luminance)(g)
        padded = np.pad(sub, 1, mode="edge")
        dilated = sub.copy()
        for dy in (0, 1, 2):
            for dx in (0, 1, 2):
                np.maximum(dilated, padded[dy:dy + g, dx:dx + g], out=dilated)
        k = g // side
        leaves = dilated.reshape(side, k, side, k).mean(axis=(1, 3))
        # Defensive floor from the map's own solid-angle-weighted mean: positive for any non-black map.
        theta = (np.arange(self.height) + 0.5) / self.height * np.pi
        texel_sr = (2 * np.pi / self.width) * (np.cos(theta - np.pi / (2 * self.height))
                                               - np.cos(theta + np.pi / (2 * self.height)))
        mean = float(((self._flat @ LUMINANCE).reshape(self.height, self.width) * texel_sr[:, None]).sum()
                     / (4 * np.pi))
        return (leaves + DEFENSIVE * mean).astype(np.float32)

    def map_to_world(self, d_square_frame: np.ndarray) -> np.ndarray:
        """Equal-area square frame (octahedral z = map +Y) to world directions."""
        d = d_square_frame[:, [0, 2, 1]] * np.array([1.0, 1.0, -1.0])
        return d @ self.world_from_map.T

    def world_to_map(self, d_world: np.ndarray) -> np.ndarray:
        """World directions to the equal-area square frame (inverse of :meth:`map_to_world`)."""
        d = d_world @ self.map_from_world.T
        return np.stack([d[:, 0], -d[:, 2], d[:, 1]], 1)
