"""The defensive mixture the unbiased frames of every bake share (Chen & Gao sec. 4.3-4.4,
eq. 17-25; Veach's balance heuristic over the mixture's components): directions drawn with
probability 1 - alpha - beta from a pixel's product T1 x L (its tree walked by the hierarchical
warp, inside a texel by the lighting's own leaves and the map's pixels: :class:`TexelLight`),
alpha = ``defensive`` from the BSDF and beta = ``light`` from the lighting alone, each weighted by
f cos / the mixture's pdf (:func:`mixture_directions`, :func:`shade_by_mixture`); the resampling
target of a sample whose footprint is wider than its lobe (:func:`resampling_target`); the
lattice of a sample's slots (:func:`lattice`); the directions of the lat-long square
(:func:`square_to_world`, :func:`world_to_square`, :func:`solid_angle_jacobian`); the per-pixel
mean and standard error of a frame's samples (:func:`mean_and_error`); and the scene a bake was
made from, checked against it (:func:`scene_of`).

:mod:`.converge` (a lighting bake's frames), :mod:`.moving` (an object's) and :mod:`.view` (a
camera's) import them; the kernels' numpy twins (:mod:`.converge`'s shade_reference) use the same
pieces.
"""
from __future__ import annotations

import os
from typing import NamedTuple

import numpy as np

from .. import bsdfs, rng
from ..envmap import bilinear, luminance
from ..errors import ArgumentError, WavlightError, check_number
from ..haar.tree import morton_index
from ..scene import check_scene, load_scene
from ..warp import frame as tangent_frame
from ..warp import to_local
from . import lighting

#: the mixture's shares: the BSDF (defensive) and the lighting alone; the product has the rest
DEFENSIVE = 0.3
LIGHT_SHARE = 0.1
#: the resampling target (:func:`resampling_target`): the sample's lobe to this power, the
#: transfer to the rest, and the shares of f cos and of T that keep it positive
LOBE_POWER = 0.6
TARGET_BSDF = 0.05
TARGET_TRANSFER = 0.1
#: directions per camera sample at most (slot j takes point j of the lattice below)
MAX_SLOTS = len(rng.CONVERGE_DIRECTIONS)
#: a camera sample's slots (and a resampled one's candidates) are the points j of the rank-1
#: lattice of the R4 sequence (Roberts 2018: alpha_i = phi^-i, phi^5 = phi + 1) shifted by one
#: Philox draw of four uniforms, frac(u_i + j alpha_i) (:func:`lattice`): each point uniform,
#: the points of a sample spread over the cube; alpha_i in 24-bit fixed point, so that the sum
#: is exact in float32 (the kernel adds the same floats)
LATTICE = (14372620, 12312662, 10547948, 9036163)


def check_scene_matches(transfer, scene):
    """The scene a bake was made from, as loaded now: a WavlightError if its content or camera
    differs from the bake's (the transfer would be of another scene)."""
    if scene.content_hash != transfer.scene.get("content_hash"):
        raise WavlightError(f"{scene.path}: the scene has changed since {transfer.path} was baked (its content "
                            "hash differs): bake it again")
    cam = transfer.camera
    same = all(np.allclose(getattr(scene.camera, k), cam[k], rtol=0, atol=1e-9) for k in ("eye", "target", "up"))
    if not same or abs(float(scene.camera.fov_y) - float(cam["fov_y"])) > 1e-9:
        raise WavlightError(f"{scene.path}: its camera differs from the one {transfer.path} was baked for")


def check_shares(where: str, defensive, light):
    """The mixture's shares: defensive (the BSDF's) and light (the lighting's) in [0, 1), with
    defensive + light < 1 where a pixel has a product and the BSDF's share left to the others."""
    defensive = check_number(where, "defensive", defensive, 0.0, 1.0)
    light = check_number(where, "light", light, 0.0, 1.0)
    if light >= 1.0 or defensive + light >= 1.0:
        raise ArgumentError(f"{where}: defensive + light must be below 1 (the product's share), got "
                            f"{defensive:g} + {light:g}")
    return defensive, light


def scene_of(transfer, scene):
    """The scene ``transfer`` was baked from: ``scene`` (a Scene or a file), or loaded from the
    path the bake recorded; checked (:func:`check_scene_matches`): a one-line WavlightError where
    it is not there or not the baked one."""
    if scene is None:
        path = transfer.scene.get("path")
        if not path:
            raise WavlightError(f"{transfer.path}: baked from a scene given as a dict: pass its scene")
        if not os.path.isfile(path):
            raise WavlightError(f"{transfer.path}: its scene {path} is not there: pass the scene (--scene FILE)")
        scene = load_scene(path)
    elif isinstance(scene, (str, os.PathLike)):
        scene = load_scene(scene)
    check_scene(scene)
    check_scene_matches(transfer, scene)
    return scene


def square_to_world(uv: np.ndarray) -> np.ndarray:
    """World directions (N, 3) of points of the world-frame lat-long square (rotate_y = 0)."""
    phi, theta = 2 * np.pi * uv[:, 0], np.pi * uv[:, 1]
    st = np.sin(theta)
    return np.stack([np.sin(phi) * st, np.cos(theta), -np.cos(phi) * st], 1)


def world_to_square(d: np.ndarray) -> np.ndarray:
    """The inverse of :func:`square_to_world` (points in [0, 1)^2)."""
    u = np.arctan2(d[:, 0], -d[:, 2]) / (2 * np.pi)
    u = u - np.floor(u)
    v = np.arccos(np.clip(d[:, 1], -1.0, 1.0)) / np.pi
    one_below = np.nextafter(1.0, 0.0)
    return np.stack([np.minimum(u, one_below), np.minimum(v, one_below)], 1)


def solid_angle_jacobian(d: np.ndarray) -> np.ndarray:
    """du dv / d omega = 1 / (2 pi^2 sin theta) at world directions (0 at the poles)."""
    s = np.hypot(d[:, 0], d[:, 2])
    with np.errstate(divide="ignore"):
        return np.where(s > 0, 1.0 / (2 * np.pi ** 2 * np.where(s > 0, s, 1.0)), 0.0)


class TexelLight:
    """The lighting inside the transfer's texels at the map's resolution: leaf masses (exact
    integrals of luminance, world frame, turned) grouped by texel, for sampling a point inside a
    texel in proportion to them and for the density factor of that choice.

    The leaves are the world-frame square's 2^m x 2^m cells (m >= the map's square levels, so a
    leaf is at most one map pixel wide and tall). Turned by an angle that is not a whole number
    of map columns, a leaf overlaps up to 2 x 2 of the map's pixels; with ``map_pixels`` (the
    default) the point is placed inside the leaf in proportion to those pieces (their luminance
    times their share of the leaf's solid angle), so that a sun one map pixel wide is sampled in
    proportion to its own radiance, not to its leaf's mean with a dark neighbour; and
    :meth:`radiance` is the map pixel's. Without, the point is uniform in its leaf (what the
    moving object's kernel does, kernels/relight_moving.cl)."""

    def __init__(self, environment, n_levels: int, rotate_y: float, map_pixels: bool = True, projector=None):
        top = max(environment.square_levels(), n_levels)
        self.n, self.top, self.k = n_levels, top, 1 << (top - n_levels)
        self.rotate_y = float(rotate_y)
        self.map_pixels = bool(map_pixels)
        # where every leaf lies inside 2 x 2 of the map's pixels, its mean radiance is theirs
        # weighted by their shares of its solid angle (:meth:`_leaf_radiance`); else (a map wider
        # or taller than 2^11) the projector integrates the map over each leaf
        nested = (1 << top) >= max(environment.width, environment.height)
        if self.map_pixels:
            self._pieces(environment, rotate_y)
        if self.map_pixels and nested:
            rgb, projector = self._leaf_radiance(), None
        else:
            if projector is None or projector.environment is not environment or projector.n_levels != top:
                projector = lighting.Projector(environment, top)
            rgb = projector(rotate_y)
        self.projector = projector   # (for another rotation of the same map: :meth:`Projector.__call__` alone)
        leaf_angles = lighting.texel_solid_angles(top)[:, None]
        masses = luminance(rgb) * leaf_angles                                          # (M, M)
        side, k = 1 << n_levels, self.k
        self.rgb = rgb
        self.texel_angles = lighting.texel_solid_angles(n_levels)
        # each texel's mean radiance: its leaves' integrals over its solid angle (exact, nested)
        self.texel_radiance = ((rgb * leaf_angles[:, :, None]).reshape(side, k, side, k, 3).sum((1, 3))
                               / self.texel_angles[:, None, None]).reshape(side * side, 3)
        blocks = masses.reshape(side, k, side, k).transpose(0, 2, 1, 3).reshape(side * side, k * k)
        self.texel_mass = blocks.sum(1)
        self.texel_luminance = (self.texel_mass.reshape(side, side)
                                / lighting.texel_solid_angles(n_levels)[:, None])
        self.cdf = np.cumsum(blocks, axis=1)
        self.blocks = blocks

    def _leaf_radiance(self) -> np.ndarray:
        """(M, M, 3) float64: each leaf's mean radiance, the exact integral of the turned map
        (piecewise constant) over the leaf's solid angle over that angle, as lighting.Projector
        gives it: the leaf's 2 x 2 pieces of map pixels weighted by their shares of its width
        (phi) and of its solid angle (rows), when no leaf is wider or taller than a map pixel."""
        share = self.row_angle_share[:, None, None]
        by_rows = share * self.map_rgb[self.rows[0]] + (1.0 - share) * self.map_rgb[self.rows[1]]   # (M, W, 3)
        share = self.col_share[None, :, None]
        return share * by_rows[:, self.cols[0]] + (1.0 - share) * by_rows[:, self.cols[1]]

    def _pieces(self, environment, rotate_y: float):
        """Per leaf column: the map columns of its two pieces and the first's share of the leaf's
        width; per leaf row: the map rows, the first's share of the height and of the solid angle
        (the map turned by rotate_y: map u = world u + rotate_y / 360, as lighting.Projector)."""
        count = 1 << self.top
        h, w = environment.height, environment.width
        self.map_rgb = environment.pixels.astype(np.float64)
        self.map_lum = luminance(self.map_rgb)
        x0 = ((np.arange(count) / count + float(rotate_y) / 360.0) % 1.0) * w   # a leaf's left edge, map columns
        first = np.floor(x0)
        self.col_share = np.clip((first + 1.0 - x0) * count / w, 0.0, 1.0)
        self.cols = np.stack([first.astype(np.int64) % w, (first.astype(np.int64) + 1) % w])
        y0 = np.arange(count) * h / count
        first = np.floor(y0)
        self.row_share = np.clip((first + 1.0 - y0) * count / h, 0.0, 1.0)
        self.rows = np.stack([np.minimum(first.astype(np.int64), h - 1), np.minimum(first.astype(np.int64) + 1, h - 1)])
        theta = np.pi * np.arange(count + 1) / count
        split = np.pi * (np.arange(count) + self.row_share) / count
        band = np.cos(theta[:-1]) - np.cos(theta[1:])                  # > 0: every row has solid angle
        self.row_angle_share = np.clip((np.cos(theta[:-1]) - np.cos(split)) / band, 0.0, 1.0)

    def _piece_masses(self, a, b):
        """(4, N) the pieces' luminance times their share of leaf (column a, row b)'s solid angle,
        in the order (row 0, col 0), (row 0, col 1), (row 1, col 0), (row 1, col 1)."""
        wc, wr = self.col_share[a], self.row_angle_share[b]
        out = []
        for r, share_r in ((0, wr), (1, 1.0 - wr)):        # the 2 x 2 pieces, not samples
            for c, share_c in ((0, wc), (1, 1.0 - wc)):
                out.append(self.map_lum[self.rows[r, b], self.cols[c, a]] * share_c * share_r)
        return np.stack(out)

    def _place_in_leaf(self, a, b, su, sv):
        """Points (fu, fv) inside leaves (column a, row b) from uniforms su, sv, in proportion to
        the pieces' masses, and the density factor of that placement against uniform in the leaf."""
        m = self._piece_masses(a, b)
        total = m.sum(0)
        top = m[0] + m[1]
        one_below = np.nextafter(1.0, 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            lower = sv * total >= top                       # the second row piece
            sv2 = np.where(lower, (sv * total - top) / (total - top), sv * total / top)
            sv2 = np.where(np.isfinite(sv2), np.clip(sv2, 0.0, one_below), sv)
            m0, m1 = np.where(lower, m[2], m[0]), np.where(lower, m[3], m[1])
            right = su * (m0 + m1) >= m0
            su2 = np.where(right, (su * (m0 + m1) - m0) / m1, su * (m0 + m1) / m0)
            su2 = np.where(np.isfinite(su2), np.clip(su2, 0.0, one_below), su)
        hc, hr = self.col_share[a], self.row_share[b]
        fu = np.where(right, hc + su2 * (1.0 - hc), su2 * hc)
        fv = np.where(lower, hr + sv2 * (1.0 - hr), sv2 * hr)
        return fu, fv, self._piece_factor(m, total, right, lower, a, b)

    def _piece_factor(self, m, total, right, lower, a, b):
        """The density of a point in piece (lower, right) of leaves (a, b) against uniform in the
        leaf: the piece's share of the leaf's mass over its share of the leaf's area."""
        piece = np.where(lower, np.where(right, m[3], m[2]), np.where(right, m[1], m[0]))
        area = (np.where(right, 1.0 - self.col_share[a], self.col_share[a])
                * np.where(lower, 1.0 - self.row_share[b], self.row_share[b]))
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.where((total > 0) & (area > 0),
                         piece / np.where(total > 0, total, 1.0) / np.where(area > 0, area, 1.0), 0.0)
        return f

    def _leaf_of(self, uv):
        """Leaf column a and row b of points uv, and whether each lies in its leaf's second
        column piece (right) and second row piece (lower) of the map's pixels."""
        count = 1 << self.top
        x = np.asarray(uv, np.float64) * count
        cell = np.minimum(x.astype(np.int64), count - 1)
        a, b = cell[:, 0], cell[:, 1]
        if not self.map_pixels:
            return a, b, None, None
        return a, b, x[:, 0] - a >= self.col_share[a], x[:, 1] - b >= self.row_share[b]

    def leaf_masses(self) -> np.ndarray:
        """(2^n, 2^n) float32: the lighting's luminance mass of each texel on the unit square,
        its mean luminance times 4^-n: the factor gl_t of the product trees' leaves (eq. 25 at
        the finest level: the box mass of the lighting times the transfer's texel value)."""
        side = 1 << self.n
        return (self.texel_luminance * (1.0 / (side * side))).astype(np.float32)

    def tables(self) -> dict:
        """The lighting on the device's terms (kernels/converge.cl LIGHT_ARGS), float32 and uint32
        bits: the running sums of each texel's leaf masses (leaf_cdf, texel-major), each texel's
        last one (texel_total), the guide to them (leaf_guide: per texel and cell g of k^2 cells,
        how many running sums are <= (g / k^2) total, in float32 as the kernel multiplies), the
        running sum of the texels' masses (texel_cdf) and its guide alike (texel_guide: per cell g
        of the texels' count n, how many running sums are <= (g / n) of the last), per leaf column its first map column's share of the leaf's
        width and its two map columns (columns), per leaf row the first map row's share of the
        leaf's height and of its solid angle and its two map rows (rows), the map's pixels
        (r, g, b, luminance), and per texel in Morton order (the trees' leaf order) the leaf
        masses of :meth:`leaf_masses` and the mean radiance (r, g, b, 0); the texel rows' solid
        angles (omega)."""
        if not self.map_pixels:
            raise ArgumentError("relight.TexelLight.tables: the kernels place points by the map's pixels")
        count, side = 1 << self.top, 1 << self.n
        columns = np.zeros((count, 4), np.float32)
        columns[:, 0] = self.col_share
        columns.view(np.uint32)[:, 1:3] = self.cols.T.astype(np.uint32)
        rows = np.zeros((count, 4), np.float32)
        rows[:, 0], rows[:, 1] = self.row_share, self.row_angle_share
        rows.view(np.uint32)[:, 2:4] = self.rows.T.astype(np.uint32)
        h, w = self.map_lum.shape
        pixels = np.empty((h * w, 4), np.float32)
        pixels[:, :3] = self.map_rgb.reshape(-1, 3)
        pixels[:, 3] = self.map_lum.reshape(-1)
        row, col = np.divmod(np.arange(side * side), side)
        morton = np.argsort(morton_index(col, row))        # texel (row-major) of each Morton index
        radiance = np.zeros((side * side, 4), np.float32)
        radiance[:, :3] = self.texel_radiance[morton]
        cdf = np.ascontiguousarray(self.cdf, np.float32)                      # (texels, k^2), rows non-decreasing
        texels, kk = cdf.shape
        total = cdf[:, -1]
        cells = (np.arange(kk + 1, dtype=np.float32) / np.float32(kk))[None, :] * total[:, None]   # float32 products
        # counts per row by one search: non-negative float32 bits order as their values; the
        # texel's index above them keeps the rows apart
        offset = np.arange(texels, dtype=np.int64)[:, None] << 32
        keys = (offset | cdf.view(np.uint32).astype(np.int64)).reshape(-1)
        guide = np.searchsorted(keys, (offset | cells.view(np.uint32).astype(np.int64)).reshape(-1), side="right")
        guide = (guide.reshape(texels, kk + 1) - np.arange(texels)[:, None] * kk).astype(np.uint32)
        texel_cdf = np.cumsum(self.texel_mass).astype(np.float32)                 # non-decreasing (rounding is monotone)
        texel_cells = (np.arange(texels + 1, dtype=np.float32) / np.float32(texels)) * texel_cdf[-1]   # float32 products
        texel_guide = np.searchsorted(texel_cdf, texel_cells, side="right").astype(np.uint32)
        return {"levels": self.n, "top": self.top, "kbits": self.top - self.n, "map_width": w, "map_height": h,
                "map_shift": np.float32(self.rotate_y / 360.0),
                "leaf_cdf": cdf.reshape(-1), "texel_total": np.ascontiguousarray(total),
                "leaf_guide": guide.reshape(-1),
                "texel_cdf": texel_cdf, "texel_guide": texel_guide, "columns": columns, "rows": rows,
                "map": pixels, "map_lum": np.ascontiguousarray(pixels[:, 3]), "leaf_masses": np.ascontiguousarray(self.leaf_masses().reshape(-1)[morton]),
                "radiance": radiance, "omega": self.texel_angles.astype(np.float32)}

    def radiance(self, uv):
        """(N, 3): the lighting's radiance at points uv of the square: the map pixel's under the
        point (with ``map_pixels``; the piece of its leaf that holds it), else its leaf's mean."""
        a, b, right, lower = self._leaf_of(uv)
        if not self.map_pixels:
            return self.rgb[b, a]
        row = np.where(lower, self.rows[1, b], self.rows[0, b])
        return self.map_rgb[row, np.where(right, self.cols[1, a], self.cols[0, a])]

    def background(self, uv, background: str = "nearest"):
        """(N, 3): what camera rays that miss see at points uv of the world-frame square: the map
        pixel (:meth:`radiance`), with ``background="bilinear"`` the turned map filtered
        bilinearly (:func:`wavlight.envmap.bilinear`, the kernel's float32 steps), with
        ``background="none"`` 0 (the background hidden)."""
        if background == "none":
            return np.zeros((len(uv), 3))
        if background != "bilinear":
            return self.radiance(uv)
        u = np.asarray(uv[:, 0], np.float32) + np.float32(self.rotate_y / 360.0)
        return bilinear(self.map_rgb, u - np.floor(u), uv[:, 1]).astype(np.float64)

    def _texel(self, uv):
        side = 1 << self.n
        cell = np.minimum((uv * side).astype(np.int64), side - 1)
        return cell[:, 1] * side + cell[:, 0], uv * side - cell

    def sample(self, uv):
        """Points of the product tree's texels (uniform inside them) moved to a leaf chosen by the
        luminance inside the texel (the point's position in its texel reused as the uniforms),
        then inside the leaf by the map's pixels (``map_pixels``): (uv (N, 2), density factor
        (N,) against uniform in the texel)."""
        t, frac = self._texel(uv)
        k, side = self.k, 1 << self.n
        one_below = np.nextafter(1.0, 0.0)
        if k == 1:
            leaf = np.zeros(len(uv), np.int64)
            s, factor = np.clip(frac[:, 0], 0.0, one_below), np.where(self.texel_mass[t] > 0, 1.0, 0.0)
        else:
            total = self.texel_mass[t]
            target = frac[:, 0] * total
            leaf = np.minimum(entries_at_most(self.cdf, t, target), k * k - 1)
            below = np.where(leaf > 0, self.cdf[t, np.maximum(leaf - 1, 0)], 0.0)
            mass = self.blocks[t, leaf]
            with np.errstate(divide="ignore", invalid="ignore"):
                s = np.where(mass > 0, (target - below) / np.where(mass > 0, mass, 1.0), frac[:, 0])
                factor = np.where(total > 0, mass / np.where(total > 0, total, 1.0) * k * k, 0.0)
            s = np.clip(s, 0.0, one_below)
        a = (t % side) * k + leaf % k
        b = (t // side) * k + leaf // k
        sv = np.clip(frac[:, 1], 0.0, one_below)
        if self.map_pixels:
            fu, fv, inner = self._place_in_leaf(a, b, s, sv)
            factor = factor * inner
        else:
            fu, fv = s, sv
        count = 1 << self.top
        out = np.stack([np.minimum((a + fu) / count, one_below), np.minimum((b + fv) / count, one_below)], 1)
        return out, factor

    def sample_light(self, a, b, c):
        """Points of the square drawn from the lighting alone: a texel in proportion to its mass
        by ``a``, then the point (b, c) of the texel moved to a leaf by :meth:`sample` (three
        uniforms, so that each choice has all of its bits): the lighting's technique of the
        mixture, density :meth:`light_pdf` per unit square."""
        cdf = self._texel_cdf()
        t = np.minimum(np.searchsorted(cdf, a * cdf[-1], side="right"), len(cdf) - 1)
        side = 1 << self.n
        one_below = np.nextafter(1.0, 0.0)
        uv = np.stack([(t % side + np.clip(b, 0.0, one_below)) / side, (t // side + np.clip(c, 0.0, one_below)) / side],
                      1)
        return self.sample(uv)[0]

    def light_pdf(self, uv):
        """The density per unit square of :meth:`sample_light` at points uv (N, 2)."""
        t, _ = self._texel(uv)
        total = self._texel_cdf()[-1]
        if total <= 0:
            return np.zeros(len(uv))
        return self.texel_mass[t] / total * float(4 ** self.n) * self.factor(uv)

    def _texel_cdf(self):
        if getattr(self, "_cdf", None) is None:
            self._cdf = np.cumsum(self.texel_mass)
        return self._cdf

    def factor(self, uv):
        """The density factor of :meth:`sample` at points uv (N, 2) against uniform in the texel:
        (leaf mass / texel mass) k^2, times the piece's inside the leaf (``map_pixels``); 0 where
        the texel holds no light."""
        t, _ = self._texel(uv)
        k = self.k
        a, b, right, lower = self._leaf_of(uv)
        total = self.texel_mass[t]
        leaf = (b % k) * k + a % k
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.where(total > 0, self.blocks[t, leaf] / np.where(total > 0, total, 1.0) * k * k, 0.0)
        if self.map_pixels:
            m = self._piece_masses(a, b)
            f = f * self._piece_factor(m, m.sum(0), right, lower, a, b)
        return f


def entries_at_most(cdf: np.ndarray, rows: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Per sample i, how many entries of the non-decreasing row ``cdf[rows[i]]`` are <= target[i]
    (``np.searchsorted(..., side="right")`` row by row), by a bisection over all samples at once:
    log2 of the row's length gathers of one value per sample, never a copy of the rows."""
    lo = np.zeros(len(rows), np.int64)
    hi = np.full(len(rows), cdf.shape[1], np.int64)
    active = lo < hi
    while active.any():
        mid = (lo + hi) // 2
        below = cdf[rows, np.minimum(mid, cdf.shape[1] - 1)] <= target
        lo = np.where(active & below, mid + 1, lo)
        hi = np.where(active & ~below, mid, hi)
        active = lo < hi
    return lo


def mean_and_error(sums: np.ndarray, squares: np.ndarray, spp: int):
    """Per-pixel mean and its standard error from the sums and sums of squares of ``spp``
    independent samples (inf with a single sample)."""
    mean = sums / spp
    if spp > 1:
        return mean, np.sqrt(np.maximum(squares - spp * mean ** 2, 0.0) / (spp - 1) / spp)
    return mean, np.full_like(mean, np.inf)


def lattice(u: np.ndarray, j) -> np.ndarray:
    """(N, 4) float32: frac(u + j alpha) for uniforms u (N, 4) float32 and lattice points j (N,)
    or a scalar, alpha = LATTICE / 2^24 (numpy twin of kernels/converge.cl ``lattice``, the same
    float32 operations)."""
    j = np.asarray(j, np.uint64)
    offset = np.stack([((j * np.uint64(a)) & np.uint64(0xFFFFFF)).astype(np.float32) for a in LATTICE], -1)
    c = np.asarray(u, np.float32) + offset * np.float32(2.0 ** -24)    # four axes, not samples
    return np.where(c >= 1, c - np.float32(1), c).astype(np.float32)


def resampling_target(fcos, radiance, transfer):
    """The target of the resampled directions (:func:`shade_by_resampling`) at directions of
    the camera sample's f cos, the lighting's ``radiance`` (N, 3) and the pixel's transfer T
    per solid angle: Y(L) [(f cos)^LOBE_POWER T^(1 - LOBE_POWER) + TARGET_BSDF f cos +
    TARGET_TRANSFER T], Y the luminance. The first term is the sample's own lobe with the
    visibility the transfer holds; the second keeps it positive wherever f cos L is, so that the
    estimate is unbiased where the transfer missed a direction."""
    fcos, transfer = np.maximum(fcos, 0.0), np.maximum(transfer, 0.0)
    return luminance(radiance) * (fcos ** LOBE_POWER * transfer ** (1.0 - LOBE_POWER) + TARGET_BSDF * fcos
                                  + TARGET_TRANSFER * transfer)


class Hits(NamedTuple):
    """Camera samples that hit: their index among the tile's samples, pixel, shading frame
    (s, t, n: the shading normal turned to the viewer), view in it, shadow-ray origin, material,
    the geometric normal turned to the viewer (directions below it carry no light)."""

    index: np.ndarray
    pixel: np.ndarray
    axes: tuple
    wo: np.ndarray
    origin: np.ndarray
    mat: np.ndarray
    kind: np.ndarray
    param: np.ndarray
    geometric: np.ndarray

    @classmethod
    def of(cls, scene, tracer, d, t, prim, hit, spp: int, bary=None):
        """``bary`` (N, 2): embree's barycentrics of all the rays (None: every face flat)."""
        if bary is not None and tracer.smooth:
            b = np.asarray(bary)[hit]
            nrm, geo, _, origin = tracer.hit(scene.camera.eye, d[hit], t[hit], prim[hit], b[:, 0], b[:, 1])
        else:
            nrm, _, origin = tracer.surface(scene.camera.eye, d[hit], t[hit], prim[hit])
            geo = nrm
        nrm = nrm.astype(np.float64)
        s_ax, t_ax = tangent_frame(nrm)
        wo = to_local(-d[hit].astype(np.float64), s_ax, t_ax, nrm)
        mat = scene.face_material[prim[hit]]
        return cls(np.asarray(hit), np.asarray(hit) // spp, (s_ax, t_ax, nrm), wo, origin, mat,
                   scene.material_kind[mat], scene.material_param[mat], geo.astype(np.float64))

    def subset(self, sel):
        return Hits(self.index[sel], self.pixel[sel], tuple(a[sel] for a in self.axes), self.wo[sel],
                     self.origin[sel], self.mat[sel], self.kind[sel], self.param[sel], self.geometric[sel])

    def candidates(self, m: int):
        """Each sample m times in a row, the candidates of :func:`shade_by_resampling`: their
        ``index`` is their row among the tile's samples' m candidates each (sample-major)."""
        rows = (self.index[:, None] * m + np.arange(m)).reshape(-1)
        return Hits(rows, *(tuple(np.repeat(a, m, 0) for a in f) if isinstance(f, tuple) else np.repeat(f, m, 0)
                             for f in self[1:]))


def shade_by_mixture(scene, tracer, d, t, prim, hit, trees, inside, mass, spp: int, key, environment,
                     defensive: float, slots: int, light: float = 0.0, first: int = 0, uv=None):
    """The radiance (len(hit), 3) of the camera samples ``hit`` (of spp per pixel, directions
    ``d`` with hits ``prim`` at ``t``) from ``slots`` directions each of the defensive mixture
    (:func:`mixture_directions`, the lighting's share ``light``; the pixels' product trees
    ``trees`` of totals ``mass``) seen from ``scene``'s camera, each evaluated with the true
    f cos, ``environment``'s radiance and a shadow ray; the uniforms are Philox stream
    (``key`` = (seed, tile), rng.CONVERGE_DIRECTIONS[slot]), from sample ``first`` of the tile
    on. The mixture alone, in numpy (the view bake's unbiased frame, :mod:`.view`; the lighting
    bake's runs in kernels/converge.cl, twin :func:`shade_reference`); ``uv`` the barycentrics of
    the rays' hits, for the shading normals (None: flat). Returns it and the rays traced."""
    if slots > MAX_SLOTS:   # one stream per slot
        raise ArgumentError(f"relight.shade_by_mixture: at most {MAX_SLOTS} slots, got {slots}")
    hits = Hits.of(scene, tracer, d, t, prim, hit, spp, None if uv is None else np.stack(uv, axis=1))
    has_p = mass[hits.pixel] > 0
    alpha = np.where(has_p, defensive, 1.0 - light)   # pixels without a product: the BSDF and the lighting
    total = np.zeros((len(hit), 3))
    rays = 0
    for slot in range(slots if len(hit) else 0):   # directions per camera sample, not samples
        u_all = rng.uniforms(*key, rng.CONVERGE_DIRECTIONS[slot], first, len(d))
        direction, weight = mixture_directions(trees, inside, u_all, hits.index, spp, has_p, alpha, hits.kind,
                                               hits.param, hits.wo, hits.axes, light, geometric=hits.geometric)
        weight = weight / slots
        live = np.flatnonzero(weight > 0)
        blocked = tracer.occluded(hits.origin[live], direction[live].astype(np.float32))
        rays += len(live)
        total[live] += (weight[live] * ~blocked)[:, None] * environment.eval(direction[live])
    return scene.material_albedo[hits.mat].astype(np.float64) * total, rays


def mixture_directions(trees, inside, u_all, hit, spp: int, has_product, alpha, kind, param, wo, axes,
                       light: float = 0.0, with_pdf: bool = False, geometric=None, table=None,
                       with_share: bool = False):
    """Directions of the defensive mixture and their weights, for the samples ``hit`` of
    ``len(u_all)`` (spp per pixel, each pixel's product tree in ``trees``): with probability
    1 - alpha - light the product (its tree by the hierarchical warp, eq. 17-22, then inside
    the texel by the lighting, ``inside``), with probability alpha the BSDF, with probability
    ``light`` the lighting alone (:meth:`TexelLight.sample_light`: where a noisy transfer
    hides a bright light, the lighting still finds it); ``geometric`` the hits' geometric normals
    (f cos = 0 below them: docs/decisions/shading-normals.md); ``axes`` (s, t, n) the hits' tangent
    frames, ``wo`` the view in them. The pdf is the mixture's, every technique's at the chosen
    direction, so that f cos / pdf is unbiased. ``table``: the samples' rows of the plastic
    table (:attr:`wavlight.scene.Scene.material_table`; None: no plastic), whose BSDF sampling
    takes either lobe (bsdfs.plastic_sample). Returns unit directions (N, 3) and f cos / pdf
    (N,) (0 where either is 0 or not finite); with ``with_pdf`` also the mixture's pdf (N,) per
    solid angle; with ``with_share`` last the share of f cos the albedo multiplies (N,) (1 but for
    plastic's coat: the sample's colour is 1 - share + share albedo, :func:`tint_of`)."""
    s_ax, t_ax, nrm = axes
    u = u_all[hit].astype(np.float64)
    uv_tree, _ = trees.sample(np.ascontiguousarray(u_all[:, :2]), spp)   # every sample slot, in pixel order
    uv_p, _ = inside.sample(uv_tree[hit].astype(np.float64))
    d_p = square_to_world(uv_p)
    use_b = u[:, 2] < alpha          # the BSDF's uniforms: u.z rescaled below alpha, and u.w
    ub = np.clip(np.stack([np.where(use_b, u[:, 2] / alpha, 0.0), u[:, 3]], 1), 0.0, np.nextafter(1.0, 0.0))
    wl_b = bsdfs.sample_each(kind, param, ub, wo, table)
    d_b = wl_b[:, :1] * s_ax + wl_b[:, 1:2] * t_ax + wl_b[:, 2:3] * nrm
    direction = np.where(use_b[:, None], d_b, d_p)
    if light > 0:                    # the lighting's: u.z in [alpha, alpha + light) chooses it, and its
        use_l = ~use_b & (u[:, 2] < alpha + light)   # direction takes the product's unused u.x, u.y and u.w
        if use_l.any():
            direction[use_l] = square_to_world(inside.sample_light(u[use_l, 0], u[use_l, 1], u[use_l, 3]))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    uv = world_to_square(direction)
    p_tree = trees.pdf(np.ascontiguousarray(spread_to(uv, hit, len(u_all)), np.float32), spp)[hit]
    p_prod = np.where(has_product, p_tree.astype(np.float64) * inside.factor(uv), 0.0) * solid_angle_jacobian(direction)
    wl = to_local(direction, s_ax, t_ax, nrm)
    fcos, p_bsdf, fd = bsdfs.eval_pdf_each(kind, param, wl, wo, table, with_diffuse=True)
    if geometric is not None:
        fcos = np.where(np.einsum("ij,ij->i", direction, geometric) > 0, fcos, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        share = np.where(fcos > 0, fd / np.where(fcos > 0, fcos, 1.0), 1.0)
    pdf = (1 - alpha - light) * p_prod + alpha * p_bsdf
    if light > 0:
        pdf = pdf + light * inside.light_pdf(uv) * solid_angle_jacobian(direction)
    with np.errstate(divide="ignore", invalid="ignore"):
        weight = np.where((pdf > 0) & (fcos > 0), fcos / pdf, 0.0)
    weight = np.where(np.isfinite(weight), weight, 0.0)
    out = (direction, weight, np.where(np.isfinite(pdf), pdf, 0.0)) if with_pdf else (direction, weight)
    return out + (share,) if with_share else out


def tint_of(share, albedo) -> np.ndarray:
    """(N, 3): the colour of a sample whose f cos (without albedo) has ``share`` (N,) multiplied by
    the albedo (N, 3): 1 - share + share albedo (the albedo itself but for plastic's coat)."""
    share = np.asarray(share, np.float64)[:, None]
    return (1.0 - share) + share * np.asarray(albedo, np.float64)


def spread_to(values: np.ndarray, at: np.ndarray, count: int) -> np.ndarray:
    """(count, 2): ``values`` at rows ``at``, the point (0.5, 0.5) elsewhere (the tree pdf kernel
    takes one point per sample of every pixel)."""
    out = np.full((count, 2), 0.5)
    out[at] = values
    return out
