"""Chi-square goodness-of-fit test of a sampler against its density (numpy).

A port of the idea behind Mitsuba 3's ``ChiSquareTest`` (``src/python/python/chi2.py``),
written from scratch: histogram the samples in a grid of cells, integrate the
density over every cell by quadrature, pool the cells that expect fewer than
``min_expected`` samples, reject if any sample falls in a cell whose integrated
density is zero, and compute the p-value of Pearson's statistic with
``scipy.stats.chi2.sf``. The significance level is Sidak-corrected for the number
of chi-square tests run by a test file, so that the probability of a false
rejection anywhere in that file stays at ``significance`` (1 %).

Two domains:

* :class:`SphereGrid` - unit directions, cells in (z = cos theta, phi) of a local
  frame (a rotation), so that a narrow lobe can be put at the frame's pole and
  given rings of its own. The solid-angle measure is dz dphi, so the cell
  integral needs no Jacobian.
* :class:`SquareGrid` - points of the unit square (or any rectangle), measure du dv.

Quadrature: a tensor rule of ``quad`` x ``quad`` nodes per cell, Gauss-Legendre
(for smooth densities) or midpoint (exact for densities that are constant on
sub-cells aligned with the cell grid, such as a sampling tree's leaves). Every
test integrates twice, with ``quad`` and ``2 quad`` nodes, uses the finer result,
and takes the difference d_i as the size of the quadrature error in cell i. An
error d_i shifts Pearson's statistic by about sum d_i^2 / E_i on average, plus a
random term of standard deviation 2 sqrt(sum d_i^2 / E_i). The test refuses to
decide (``ok = False``, "quadrature not converged") unless sum d_i^2 / E_i <=
``quad_budget`` (0.25): the shift is then at most ~1, against a statistic whose
spread is sqrt(2 dof).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, NamedTuple

import numpy as np
from scipy import stats


def sidak_alpha(significance: float, n_tests: int) -> float:
    """Per-test level giving family-wise level ``significance`` over ``n_tests`` independent tests."""
    return 1.0 - (1.0 - significance) ** (1.0 / max(1, n_tests))


def _rule(quad: int, kind: str):
    """Nodes and weights of a 1D rule on [0, 1]."""
    if kind == "gauss":
        x, w = np.polynomial.legendre.leggauss(quad)
        return 0.5 * (x + 1.0), 0.5 * w
    if kind == "midpoint":
        return (np.arange(quad) + 0.5) / quad, np.full(quad, 1.0 / quad)
    raise ValueError(f"unknown quadrature rule {kind!r}")


def _tensor_nodes(e0, e1, quad, kind):
    """Quadrature nodes of every cell of the grid with edges e0 x e1.

    returns x0, x1 (n0, n1, q, q) node coordinates and w (n0, n1, q, q) weights
    (cell measure included, in the grid's own coordinates).
    """
    t, w = _rule(quad, kind)
    lo0, h0 = e0[:-1], np.diff(e0)
    lo1, h1 = e1[:-1], np.diff(e1)
    x0 = lo0[:, None, None, None] + h0[:, None, None, None] * t[None, None, :, None]
    x1 = lo1[None, :, None, None] + h1[None, :, None, None] * t[None, None, None, :]
    ww = (h0[:, None, None, None] * h1[None, :, None, None]) * (w[:, None] * w[None, :])[None, None]
    shape = (len(h0), len(h1), quad, quad)
    return np.broadcast_to(x0, shape), np.broadcast_to(x1, shape), ww


@dataclass
class SphereGrid:
    """Cells on the sphere: ``z_edges`` (ascending, -1 .. 1) x ``phi_edges`` (ascending, 0 .. 2 pi).

    ``frame`` : (3, 3) rotation whose rows are the local x, y, z axes in world
    coordinates (local = frame @ world). Its z row is the grid's pole.
    """

    z_edges: np.ndarray
    phi_edges: np.ndarray
    frame: np.ndarray = field(default_factory=lambda: np.eye(3))

    @staticmethod
    def uniform(nz: int = 32, nphi: int = 64, frame=None) -> "SphereGrid":
        """Equal-area cells: uniform in z and phi."""
        return SphereGrid(np.linspace(-1, 1, nz + 1), np.linspace(0, 2 * np.pi, nphi + 1),
                          np.eye(3) if frame is None else np.asarray(frame, float))

    @staticmethod
    def lobe(axis, theta_core: float, n_core: int = 24, n_outer: int = 8, nphi: int = 48,
             extra_z=()) -> "SphereGrid":
        """Rings about ``axis``: ``n_core`` uniform in theta up to ``theta_core``, the rest
        uniform in z down to the antipode; ``extra_z`` adds z edges (e.g. a known jump)."""
        frame = frame_about(np.asarray(axis, float))
        theta_core = min(float(theta_core), np.pi)
        z_core = np.cos(np.linspace(0, theta_core, n_core + 1))
        z_outer = np.linspace(-1, np.cos(theta_core), n_outer + 1) if theta_core < np.pi else [-1.0]
        z = np.unique(np.concatenate([z_core, z_outer, np.asarray(extra_z, float), [-1.0, 1.0]]))
        return SphereGrid(z, np.linspace(0, 2 * np.pi, nphi + 1), frame)

    @property
    def shape(self):
        return len(self.z_edges) - 1, len(self.phi_edges) - 1

    def labels(self):
        return "z", "phi"

    def nodes(self, quad, kind):
        z, phi, w = _tensor_nodes(np.asarray(self.z_edges, float), np.asarray(self.phi_edges, float), quad, kind)
        r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
        local = np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)
        return local @ self.frame, w  # world = frame^T local

    def bin(self, d):
        """Cell indices (i_z, i_phi) of unit directions d (N, 3); -1 where invalid."""
        d = np.asarray(d, float)
        local = d @ self.frame.T
        z = np.clip(local[:, 2], -1.0, 1.0)
        phi = np.mod(np.arctan2(local[:, 1], local[:, 0]), 2 * np.pi)
        return _bin1(z, self.z_edges), _bin1(phi, self.phi_edges)

    def validate(self, d):
        d = np.asarray(d, float)
        if d.ndim != 2 or d.shape[1] != 3:
            return f"expected (N, 3) directions, got shape {d.shape}"
        bad = ~np.all(np.isfinite(d), 1)
        if bad.any():
            return f"{bad.sum()} sample(s) are not finite, e.g. {d[bad][:3].tolist()}"
        norm_err = np.abs(np.linalg.norm(d, axis=1) - 1.0)
        if norm_err.max() > 1e-5:
            i = int(np.argmax(norm_err))
            return f"{(norm_err > 1e-5).sum()} sample(s) are not unit vectors, e.g. {d[i].tolist()}"
        return None


@dataclass
class SquareGrid:
    """Cells on a rectangle: ``x_edges`` x ``y_edges`` (ascending). Samples are (N, 2) points."""

    x_edges: np.ndarray
    y_edges: np.ndarray

    @staticmethod
    def uniform(nx: int, ny: int | None = None) -> "SquareGrid":
        return SquareGrid(np.linspace(0, 1, nx + 1), np.linspace(0, 1, (ny or nx) + 1))

    @property
    def shape(self):
        return len(self.x_edges) - 1, len(self.y_edges) - 1

    def labels(self):
        return "x", "y"

    def nodes(self, quad, kind):
        x, y, w = _tensor_nodes(np.asarray(self.x_edges, float), np.asarray(self.y_edges, float), quad, kind)
        return np.stack([x, y], -1), w

    def bin(self, p):
        p = np.asarray(p, float)
        return _bin1(p[:, 0], self.x_edges), _bin1(p[:, 1], self.y_edges)

    def validate(self, p):
        p = np.asarray(p, float)
        if p.ndim != 2 or p.shape[1] != 2:
            return f"expected (N, 2) points, got shape {p.shape}"
        bad = ~np.all(np.isfinite(p), 1)
        if bad.any():
            return f"{bad.sum()} sample(s) are not finite, e.g. {p[bad][:3].tolist()}"
        return None


def _bin1(x, edges):
    """Index of the half-open cell [e_i, e_i+1) holding x (the last cell is closed); -1 outside."""
    edges = np.asarray(edges, float)
    i = np.searchsorted(edges, x, side="right") - 1
    i = np.where(x == edges[-1], len(edges) - 2, i)
    return np.where((x < edges[0]) | (x > edges[-1]), -1, i)


def integrate_cells(pdf: Callable, grid, quad: int = 6, rule: str = "gauss", chunk: int = 1 << 20):
    """Integral of ``pdf`` over every cell of ``grid``: (n0, n1) float64."""
    pts, w = grid.nodes(quad, rule)
    flat = pts.reshape(-1, pts.shape[-1])
    vals = np.empty(len(flat))
    for s in range(0, len(flat), chunk):
        vals[s:s + chunk] = np.asarray(pdf(np.ascontiguousarray(flat[s:s + chunk])), float)
    if not np.all(np.isfinite(vals)):
        raise AssertionError("pdf returned non-finite values at quadrature nodes")
    return (vals.reshape(w.shape) * w).sum(axis=(2, 3))


def integral(pdf: Callable, grid, quad: int = 6, rule: str = "gauss"):
    """(I_quad, I_2quad): the integral of ``pdf`` over the grid's whole domain at two resolutions."""
    return (float(integrate_cells(pdf, grid, quad, rule).sum()),
            float(integrate_cells(pdf, grid, 2 * quad, rule).sum()))


class Chi2Result(NamedTuple):
    ok: bool
    p: float
    message: str


def _table(a, title, max_rows=12, max_cols=16):
    """A block-summed text table of a 2D array (rows = first grid axis)."""
    a = np.asarray(a, float)
    r = -(-a.shape[0] // max_rows)
    c = -(-a.shape[1] // max_cols)
    pad = np.zeros((-(-a.shape[0] // r) * r, -(-a.shape[1] // c) * c))
    pad[:a.shape[0], :a.shape[1]] = a
    b = pad.reshape(pad.shape[0] // r, r, pad.shape[1] // c, c).sum(axis=(1, 3))
    lines = [f"{title} (blocks of {r}x{c} cells)"]
    lines += [" ".join(f"{v:9.1f}" for v in row) for row in b]
    return "\n".join(lines)


def chi2_test(samples: np.ndarray, pdf: Callable, grid, *, n_tests: int = 1,
              significance: float = 0.01, quad: int = 6, rule: str = "gauss",
              min_expected: float = 5.0, quad_budget: float = 0.25) -> Chi2Result:
    """Pearson chi-square test of ``samples`` against the density ``pdf`` on ``grid``.

    samples : (N, 3) unit directions (SphereGrid) or (N, 2) points (SquareGrid)
    pdf : callable mapping (M, 3) or (M, 2) float64 -> (M,) density w.r.t. the grid's
        measure (solid angle, or area)
    n_tests : number of chi-square tests in the family (Sidak correction)
    returns : Chi2Result(ok, p, message); the message holds both tables when it rejects.
    """
    samples = np.asarray(samples, float)
    n = len(samples)
    problem = grid.validate(samples)
    if problem:
        return Chi2Result(False, 0.0, f"invalid samples: {problem}")

    i0, i1 = grid.bin(samples)
    outside = (i0 < 0) | (i1 < 0)
    if outside.any():
        return Chi2Result(False, 0.0, f"{outside.sum()} sample(s) outside the grid, e.g. "
                                      f"{samples[outside][:3].tolist()}")
    shape = grid.shape
    observed = np.zeros(shape)
    np.add.at(observed, (i0, i1), 1.0)

    expected_q = n * integrate_cells(pdf, grid, quad, rule)
    expected = n * integrate_cells(pdf, grid, 2 * quad, rule)
    alpha = sidak_alpha(significance, n_tests)
    head = (f"chi-square: {n} samples, {shape[0]}x{shape[1]} cells, "
            f"sum of expected = {expected.sum():.2f}, alpha = {alpha:.3g} (Sidak over {n_tests})")

    # Quadrature must be converged well below the counting noise, or the verdict means nothing.
    qerr = (expected - expected_q) ** 2 / np.maximum(expected, 1.0)
    if qerr.sum() > quad_budget:
        k = np.unravel_index(int(np.argmax(qerr)), shape)
        return Chi2Result(False, 0.0, f"{head}\nquadrature not converged: sum d^2/E = {qerr.sum():.3f} "
                                      f"> {quad_budget}; worst cell {tuple(int(v) for v in k)} expects "
                                      f"{expected_q[k]:.3f} with {quad} nodes and {expected[k]:.3f} "
                                      f"with {2 * quad}")

    if np.any(expected < 0):
        return Chi2Result(False, 0.0, f"{head}\nthe pdf integrates to a negative value in "
                                      f"{(expected < 0).sum()} cell(s)")

    # Samples where the density integrates to zero are an error on their own.
    zero = (expected == 0) & (observed > 0)
    if zero.any():
        ks = np.argwhere(zero)[:5].tolist()
        return Chi2Result(False, 0.0, f"{head}\n{int(observed[zero].sum())} sample(s) in "
                                      f"{zero.sum()} cell(s) of zero integrated pdf, e.g. cells {ks}\n"
                                      + _table(observed, "observed") + "\n" + _table(expected, "expected"))

    # Pool the cells expecting too few samples into one bin (merged into the smallest
    # regular bin when even the pool expects too few).
    e, o = expected.ravel(), observed.ravel()
    small = e < min_expected
    bins_e = list(e[~small])
    bins_o = list(o[~small])
    pool_e, pool_o = e[small].sum(), o[small].sum()
    if pool_e >= min_expected or not bins_e:
        bins_e.append(pool_e)
        bins_o.append(pool_o)
    else:
        j = int(np.argmin(bins_e))
        bins_e[j] += pool_e
        bins_o[j] += pool_o
    bins_e, bins_o = np.array(bins_e), np.array(bins_o)
    dof = len(bins_e) - 1
    if dof < 1:
        return Chi2Result(False, 0.0, f"{head}\ntoo few bins for a test ({len(bins_e)}); "
                                      "use more samples or fewer cells")
    contrib = np.where(bins_e > 0, (bins_o - bins_e) ** 2 / np.where(bins_e > 0, bins_e, 1.0), 0.0)
    stat = float(contrib.sum())
    p = float(stats.chi2.sf(stat, dof))
    ok = p > alpha
    msg = (f"{head}\n{small.sum()} cell(s) pooled, {len(bins_e)} bins, dof = {dof}, "
           f"statistic = {stat:.2f}, p = {p:.4g} -> {'accept' if ok else 'REJECT'}")
    if not ok:
        cell_c = np.where(expected > 0, (observed - expected) ** 2 / np.where(expected > 0, expected, 1), 0)
        worst = np.argsort(cell_c.ravel())[::-1][:10]
        rows = [f"  cell {tuple(int(v) for v in np.unravel_index(k, shape))}: observed {o[k]:.0f}, "
                f"expected {e[k]:.2f}, contribution {cell_c.ravel()[k]:.2f}" for k in worst]
        msg += ("\nlargest contributions:\n" + "\n".join(rows) + "\n"
                + _table(observed, f"observed ({grid.labels()[0]} down, {grid.labels()[1]} across)") + "\n"
                + _table(expected, "expected"))
    return Chi2Result(ok, p, msg)


def frame_about(axis: np.ndarray) -> np.ndarray:
    """(3, 3) rotation with rows (s, t, axis): an orthonormal frame whose pole is ``axis``."""
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    s = np.cross(helper, a)
    s /= np.linalg.norm(s)
    t = np.cross(a, s)
    return np.stack([s, t, a])
