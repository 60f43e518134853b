"""The product walk of a view bake's approximate frame (Chen & Gao sec. 2.2, eq. 6-8, with the view
as the varying factor; the top-down reconstruction of eq. 13) and its device wrappers:

    B(x, wo) = <T1(x), T2>,  T1(x, w) = L(w) V(x, w) max(cos theta, 0)  (per cache point, baked),
    T2 = f_r(x, ., wo)  (per frame; the albedo factored out: f_r = albedo x shape).

plastic (f cos = coat + albedo x base, wavlight.bsdfs.plastic_parts; Mitsuba 3's roughplastic)
walks as two items, kinds VIEW_COAT (F(wo . h, eta) times ggx of its alpha: refined as ggx's
lobe) and VIEW_BASE (T(cos_o) T(cos_i) / (pi eta^2 (1 - R_int)), refined as lambert's lobe,
walked: T(cos_i) is not constant), each reading its material's row of the plastic table; the
frame adds albedo x the base's value and the coat's (:meth:`wavlight.relight.view_frames.ViewFrames.lobes`).

The walk (kernel ``view_product`` in kernels/relight_view.cl, numpy twin :func:`product_reference`).
An item is one cache point (:mod:`wavlight.relight.surface_cache`) or the blend of a hit's three
with their barycentric weights (the product is linear in T1: the walk reads the points'
coefficients and blends them), a shading normal, a view direction and a material. The product
<T1, f_r> is evaluated top-down over T1's quadtree: a node's average from its parent's and its
three wavelet coefficients (eq. 13), refined until f_r is nearly constant over it (its angular
radius r <= refine (delta + w) / g, delta the angle from the lobe's axis, the mirror direction,
w the lobe's width), then its average times f_r at its centre (the midpoint rule); nodes below
the shading normal's horizon are skipped. The midpoint rule's first-order error is T1's mass
inside the node times f_r's change across it, and a sun puts much of the mass in a few nodes
away from their centres: a node holding a share phi of T1's mass (its channels' |average| times
its area over the root's) is refined further, g = max(1, sqrt(phi / mass)) rounded up to a power
of two (docs/decisions/view-walk-mass.md). lambert items need only the scaling coefficient:
B = T^_0 N^2 / pi.

The cosine's correction (``tau``, the frame's ``pixel`` mode, :mod:`wavlight.relight.view_frames`).
T1 holds max(cos, 0) at the points' normals, whose blend m = sum_k w_k n_k makes sum_k w_k T1_k =
L V (m . w) above the points' horizons; with ``tau`` > 0 a leaf's factor rho (at most RHO_MAX)
turns that cosine into the shading normal n's, max(n . w, 0) / (m . w) smoothed over the node
(:func:`ramp`), and a node is also refined while |n - m| sin r > tau max(m . c, sin r,
RHO_FLOOR) (T1 is small near m's horizon); ``tau`` = 0 keeps the baked cosine (rho = 1). lambert
items take the scaling coefficient where rho is constant (tau = 0, or n along m), and walk
otherwise.

On the device the walk refines a node by testing its four children together (float4 lanes,
kernels/relight_view.cl) (:class:`ViewDevice`); :class:`FrameDevice` holds the frame's tables for
the kernels ``view_lookup`` (per ray its three cache points and weights, numpy twin
:meth:`wavlight.relight.view_frames.ViewFrames.hit_points`, and a flag per cache point used) and
``view_assemble`` (per ray the albedo times the blend of its points' B_k, or the environment's
texel).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import bsdfs, cl, textures
from ..envmap import BACKGROUND_MODE
from ..warp import frame as tangent_frame
from ..warp import to_local
from .frame import DeviceEntries
from .mixture import square_to_world
from .settings import FRAME
from .surface_cache import CREASE_DEGREES, POINTS

#: the walk refines a node until its angular radius is at most REFINE (delta + w) / g,
#: g = max(1, sqrt(phi / MASS)) for a node holding the share phi of T1's mass (0: g = 1)
REFINE = FRAME["refine"].default
MASS = FRAME["mass"].default
#: g is rounded up to a power of two 2^k, k <= MASS_STEPS (cos and sin of the scaled radius tabulated)
MASS_STEPS = 8
#: a view direction this close to the tangent plane is lifted to it (silhouette points)
MIN_COS_VIEW = 1e-3
#: plastic walks as two items, its lobes (f cos = coat + albedo x base, wavlight.bsdfs.plastic_parts):
#: the coat F(wo . h) ggx (parameter alpha) and the base T(cos_o) T(cos_i) / (pi eta^2 (1 - R_int))
#: (kernels/relight_view.cl VIEW_COAT, VIEW_BASE); their table rows: the scene's plastic table
VIEW_COAT = 4
VIEW_BASE = 5


def brdf_reference(kind: np.ndarray, param: np.ndarray, wi: np.ndarray, wo: np.ndarray, table=None) -> np.ndarray:
    """f_r(wi, wo) without albedo and without cos theta_i, local frames (N, 3) (the kernel's
    ``view_brdf``; for cos_i > 0 it is :func:`wavlight.bsdfs.eval_cos` / cos_i; plastic's lobes
    VIEW_COAT and VIEW_BASE are :func:`wavlight.bsdfs.plastic_parts` / cos_i, ``table`` (N,
    PLASTIC_STRIDE) their rows of the plastic table; below the horizon ggx and the coat stay
    finite, the base is 0: T1 is 0 there, but a node's centre may be below it)."""
    kind = np.broadcast_to(kind, len(wi))
    param = np.broadcast_to(np.asarray(param, np.float64), len(wi))
    out = np.full(len(wi), 1.0 / np.pi)
    base = kind == VIEW_BASE
    if base.any():
        diff = bsdfs.plastic_parts(wi[base], wo[base], np.asarray(table, np.float64)[base])[1]
        iz = wi[base, 2]
        out[base] = np.where(iz > 0, diff / np.where(iz > 0, iz, 1.0), 0.0)
    ix, iy, iz = wi[:, 0], wi[:, 1], wi[:, 2]
    ox, oy, oz = wo[:, 0], wo[:, 1], wo[:, 2]
    ph = kind == bsdfs.PHONG
    if ph.any():
        ca = np.maximum(iz * oz - ix * ox - iy * oy, 0.0)[ph]
        with np.errstate(divide="ignore"):
            out[ph] = np.where(ca > 0, (param[ph] + 2) / (2 * np.pi) * ca ** param[ph], 0.0)
    gg = (kind == bsdfs.GGX) | (kind == VIEW_COAT)
    if gg.any():   # plastic's coat: ggx's factor times F(wo . h) (below)
        a2 = param[gg] ** 2
        h = wi[gg] + wo[gg]
        hh = np.einsum("ij,ij->i", h, h)
        ok = hh > 0
        nhz = np.where(ok, h[:, 2] / np.sqrt(np.where(ok, hh, 1.0)), 0.0)
        ih = np.einsum("ij,ij->i", wi[gg], h)
        d = nhz * nhz * (a2 - 1) + 1
        D = a2 / (np.pi * d * d)
        c2 = np.maximum(oz[gg] ** 2, 1e-30)
        g1o = np.where(oz[gg] > 0, 2 / (1 + np.sqrt(1 + a2 * np.maximum(1 - c2, 0) / c2)), 0.0)
        z = np.maximum(iz[gg], 0.0)
        gi = 2 / (z + np.sqrt(a2 + (1 - a2) * z * z))
        good = ok & (nhz > 0) & (ih > 0) & (oz[gg] > 0)
        out[gg] = np.where(good, D * g1o / (4 * np.maximum(oz[gg], 1e-30)) * gi, 0.0)
    coat = kind == VIEW_COAT
    if coat.any():   # F(wo . h, eta) (Mitsuba's fresnel; as bsdfs.plastic_parts, but finite below the horizon as ggx)
        h = wi[coat] + wo[coat]
        hl = np.linalg.norm(h, axis=1)
        oh = np.einsum("ij,ij->i", wo[coat], h) / np.where(hl > 0, hl, 1.0)
        out[coat] *= bsdfs.fresnel_dielectric(np.maximum(oh, 0.0), np.asarray(table, np.float64)[coat, 0])[0]
    return out


def lobe(kind: np.ndarray, param: np.ndarray, normal: np.ndarray, wo: np.ndarray):
    """Each item's lobe axis (the mirror direction; the normal for lambert) and width (as
    :func:`wavlight.bsdfs.lobe_width`: ggx 2 alpha, phong 1 / sqrt(e + 1), lambert pi / 2),
    world frame (plastic's coat as ggx, its base as lambert)."""
    kind = np.asarray(kind)
    axis = 2.0 * np.einsum("ij,ij->i", wo, normal)[:, None] * normal - wo
    diffuse = (kind == bsdfs.LAMBERT) | (kind == VIEW_BASE)
    axis = np.where(diffuse[:, None], normal, axis)
    # plastic's coat is as wide as ggx of its alpha, its base as lambert
    as_kind = np.where(kind == VIEW_COAT, bsdfs.GGX, np.where(kind == VIEW_BASE, bsdfs.LAMBERT, kind))
    return axis, bsdfs.lobe_width(as_kind, param)


def lifted_view(normal: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """View directions (N, 3) at least MIN_COS_VIEW above the tangent plane (a silhouette point's
    mean normal may face slightly away from the eye)."""
    c = np.einsum("ij,ij->i", wo, normal)
    w = np.where((c < MIN_COS_VIEW)[:, None], wo + (MIN_COS_VIEW - c)[:, None] * normal, wo)
    return w / np.linalg.norm(w, axis=1, keepdims=True)


@dataclass
class NodeTables:
    """Per quadtree node (level order, node (l, x, y) at (4^l - 1) / 3 + y 2^l + x) its centre's
    world direction (float4, w = 0), and per node row (l, y) at 2^l - 1 + y: q = r / refine,
    cos and sin of it, and sin r (2 where r >= pi / 2: never wholly below a horizon), r the
    largest angle from the centre to the node's border (its region's farthest point); and per
    row and k = 1 .. MASS_STEPS (row-major) cos and sin of min(2^k q, pi), for the walk's g = 2^k."""

    centres: np.ndarray
    rows: np.ndarray
    radius: np.ndarray
    scaled: np.ndarray


_TABLES = {}


def node_tables(n_levels: int, refine: float) -> NodeTables:
    """The tables of a quadtree of n levels for ``refine`` (kept per pair)."""
    key = (int(n_levels), float(refine))
    found = _TABLES.get(key)
    if found is not None:
        return found
    centres, radius = [], []
    edge = np.linspace(0.0, 1.0, 65)
    for l in range(n_levels + 1):   # levels, not nodes
        s = 1 << l
        y, x = np.mgrid[0:s, 0:s]
        uv = np.stack([(x.ravel() + 0.5) / s, (y.ravel() + 0.5) / s], 1)
        centres.append(square_to_world(uv))
        # the border of node (0, y) of each row: rows are congruent under turns about +Y
        rows_y = np.arange(s)[:, None]
        border = np.concatenate([np.stack([edge + 0 * rows_y, 0 * edge + rows_y], -1),
                                 np.stack([edge + 0 * rows_y, 0 * edge + rows_y + 1], -1),
                                 np.stack([0 * edge + 0 * rows_y, edge + rows_y], -1),
                                 np.stack([0 * edge + 1 + 0 * rows_y, edge + rows_y], -1)], 1) / s
        b = square_to_world(np.clip(border.reshape(-1, 2), 0.0, 1.0)).reshape(s, -1, 3)
        c = square_to_world(np.stack([np.full(s, 0.5 / s), (np.arange(s) + 0.5) / s], 1))
        ang = np.arccos(np.clip(np.einsum("rkj,rj->rk", b, c), -1.0, 1.0)).max(1)
        radius.append(np.minimum(ang * (1 + 1e-3) + 1e-6, np.pi))
    r = np.concatenate(radius)
    q = r / refine
    rows = np.stack([q, np.cos(np.minimum(q, np.pi)), np.sin(np.minimum(q, np.pi)),
                     np.where(r < np.pi / 2, np.sin(r), 2.0)], 1).astype(np.float32)
    qk = np.minimum(q[:, None] * 2.0 ** np.arange(1, MASS_STEPS + 1), np.pi)
    scaled = np.stack([np.cos(qk), np.sin(qk)], -1).astype(np.float32)          # (rows, MASS_STEPS, 2)
    cen = np.zeros((sum(4 ** l for l in range(n_levels + 1)), 4), np.float32)
    cen[:, :3] = np.concatenate(centres)
    tables = _TABLES[key] = NodeTables(cen, rows, r, scaled)
    return tables


def _items(kind, param, normal, wo, t1_normal, tau):
    """(I, 16) float32 per item: shading normal, view direction, lobe axis, width, cos and sin of
    it, T1's normal, the cosine's correction tolerance."""
    axis, width = lobe(kind, param, normal, wo)
    tau = np.broadcast_to(np.asarray(tau, np.float64), len(kind))
    return np.concatenate([normal, wo, axis, width[:, None], np.cos(width)[:, None], np.sin(width)[:, None],
                           t1_normal, tau[:, None]], 1).astype(np.float32)


def _coefficients(offsets, scale, data, points: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """(len(points), 3, len(columns)) float64: the stored coefficients ``columns`` of the points
    (0 where a block keeps none)."""
    b, j = points // POINTS, points % POINTS
    o = np.asarray(offsets[np.asarray(columns, np.int64)[None, :], b[:, None]], np.int64)   # (I, C)
    keep = o >= 0
    oc = np.where(keep, o, 0)
    sc = np.where(keep, np.asarray(scale)[oc], 0.0)
    out = np.empty((len(points), 3, len(columns)))
    for c in range(3):   # channels
        out[:, c] = np.asarray(data)[oc, (c * POINTS + j)[:, None]] * sc
    return out


def _blended(offsets, scale, data, points: np.ndarray, weights: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """(I, C, 3) float64: sum_k weights[:, k] x coefficient columns[:, c] of points[:, k], per item
    its own columns (I, C)."""
    out = np.zeros(columns.shape + (3,))
    data = np.asarray(data)
    for k in range(points.shape[1]):   # the item's points (1 or 3)
        b, j = points[:, k] // POINTS, points[:, k] % POINTS
        o = np.asarray(offsets[columns, b[:, None]], np.int64)
        keep = o >= 0
        oc = np.where(keep, o, 0)
        sc = np.where(keep, np.asarray(scale)[oc], 0.0) * weights[:, k:k + 1]
        for c in range(3):   # channels
            out[:, :, c] += data[oc, (c * POINTS + j)[:, None]] * sc
    return out


def ramp(x, s):
    """The mean of max(x', 0) over x' uniform in [x - s, x + s] (the kernel's ``view_ramp``)."""
    x, s = np.asarray(x, np.float64), np.asarray(s, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        mid = (x + s) ** 2 / (4.0 * s)
    return np.where(x >= s, x, np.where(x <= -s, 0.0, mid))


#: the cosine's correction factor rho is at most RHO_MAX (a node near T1's horizon); its
#: refinement bounds |n - m| sin r by tau max(m . c, sin r, RHO_FLOOR) (the kernel's constants)
RHO_MAX = 4.0
RHO_FLOOR = 0.5


def mass_steps(share: np.ndarray) -> np.ndarray:
    """k = min(ceil(log2(share) / 2), MASS_STEPS) where share = phi / mass > 1, else 0 (NaN too):
    g = 2^k >= sqrt(share), ceil(log2) from the float32's exponent and mantissa bits as the
    kernel's ``view_mass_steps`` takes it (infinity: MASS_STEPS)."""
    share = np.atleast_1d(np.asarray(share, np.float32))
    bits = share.view(np.uint32).astype(np.int64)
    c = ((bits >> 23) & 0xFF) - 127 + ((bits & 0x7FFFFF) != 0)   # ceil(log2(share)) for share >= 1
    return np.where(share > 1.0, np.minimum((c + 1) // 2, MASS_STEPS), 0).astype(np.int64)


def product_reference(offsets, scale, data, n_levels: int, points: np.ndarray, kind, param, normal, wo,
                      refine: float = REFINE, weights=None, t1_normal=None, tau: float = 0.0,
                      mass: float = MASS, table=None):
    """numpy twin of ``view_product``: (B (I, 3) float64, nodes visited (I,)) for items (cache
    points ``points`` (I,) or (I, K) blended with ``weights`` (I, K), shaded with ``normal`` and
    view direction wo (world, unit), material kind and parameter; ``t1_normal`` the blend of the
    points' normals (default ``normal``), ``tau`` the cosine's correction tolerance, 0 for
    none, and ``mass`` the share of T1's mass above which a node refines further, 0 for none:
    kernels/relight_view.cl; ``table`` (I, PLASTIC_STRIDE) the plastic table's row of each item
    of plastic's lobes, VIEW_COAT and VIEW_BASE), level by level over the frontier of all items' nodes
    (float64; the kernel's float32 takes the same nodes but where a test lies within rounding
    of its threshold)."""
    points = np.asarray(points, np.int64)
    if points.ndim == 1:
        points = points[:, None]
    weights = np.ones(points.shape) if weights is None else np.asarray(weights, np.float64).reshape(points.shape)
    kind = np.asarray(kind, np.int64)
    param = np.asarray(param, np.float64)
    normal, wo = np.asarray(normal, np.float64), np.asarray(wo, np.float64)
    m_all = normal if t1_normal is None else np.asarray(t1_normal, np.float64)
    tau = float(tau)
    side = 1 << n_levels
    n2 = float(side * side)
    tables = node_tables(n_levels, refine)
    axis, width = lobe(kind, param, normal, wo)
    s_ax, t_ax = tangent_frame(normal)
    wo_l = to_local(wo, s_ax, t_ax, normal)
    ml = np.linalg.norm(m_all, axis=1)
    dn = np.linalg.norm(normal - m_all, axis=1)
    root = _blended(offsets, scale, data, points, weights, np.zeros((len(points), 1), np.int64))[:, 0]
    root_mass = np.abs(root).sum(1)
    per_mass = np.divide(1.0, root_mass * mass, out=np.zeros_like(root_mass), where=(root_mass > 0) & (mass > 0))
    out = np.zeros((len(points), 3))
    visited = np.ones(len(points), np.int64)
    lam = (kind == bsdfs.LAMBERT) & ((tau <= 0) | (np.einsum("ij,ij->i", normal, m_all) >= ml * (1 - 1e-6)))
    out[lam] = root[lam] * (n2 / np.pi / (np.maximum(ml[lam], 1e-6) if tau > 0 else np.ones(lam.sum())))[:, None]
    item = np.flatnonzero(~lam)
    x = np.zeros(len(item), np.int64)
    y = np.zeros(len(item), np.int64)
    avg = root[item]
    visited[item] = 0
    for level in range(n_levels + 1):   # levels of the tree, not nodes
        if not len(item):
            break
        s = 1 << level
        np.add.at(visited, item, 1)
        row = tables.rows[s - 1 + y].astype(np.float64)
        r_eps = tables.radius[s - 1 + y] / refine
        c = tables.centres[(s * s - 1) // 3 + y * s + x, :3].astype(np.float64)
        sin_r = np.where(tables.radius[s - 1 + y] < np.pi / 2, np.sin(tables.radius[s - 1 + y]), 1.0)
        nc = np.einsum("ij,ij->i", c, normal[item])
        live = nc >= -np.where(tables.radius[s - 1 + y] < np.pi / 2, sin_r, 2.0)
        k = mass_steps(np.abs(avg).sum(1) * per_mass[item] / (s * s))   # of phi / mass
        r_eps = r_eps * 2.0 ** k
        need = r_eps - width[item]
        at = (s - 1 + y) * MASS_STEPS + np.maximum(k - 1, 0)
        scaled = tables.scaled.reshape(-1, 2)[at].astype(np.float64)
        cq, sq = np.where(k > 0, scaled[:, 0], row[:, 1]), np.where(k > 0, scaled[:, 1], row[:, 2])
        cos_need = cq * np.cos(width[item]) + sq * np.sin(width[item])
        leaf = (need <= 0) | ((need < np.pi) & (np.einsum("ij,ij->i", c, axis[item]) <= cos_need))
        mc = np.einsum("ij,ij->i", c, m_all[item])
        if tau > 0:
            leaf &= sin_r * dn[item] <= tau * np.maximum(mc, np.maximum(sin_r, RHO_FLOOR))
        leaf |= level == n_levels
        at = live & leaf
        if at.any():
            ii = item[at]
            wl = np.stack([np.einsum("ij,ij->i", c[at], a[ii]) for a in (s_ax, t_ax, normal)], 1)
            f = brdf_reference(kind[ii], param[ii], wl, wo_l[ii], None if table is None else np.asarray(table)[ii])
            if tau > 0:
                den = ramp(mc[at], sin_r[at] * ml[ii])
                with np.errstate(divide="ignore", invalid="ignore"):
                    rho = np.where(den > 0, np.minimum(ramp(nc[at], sin_r[at]) / den, RHO_MAX), 0.0)
                f = f * rho
            np.add.at(out, ii, avg[at] * (n2 / (s * s) * f)[:, None])
        go = live & ~leaf
        if not go.any():
            break
        item, x, y, avg = item[go], x[go], y[go], avg[go]
        cols = np.stack([y * side + s + x, (s + y) * side + x, (s + y) * side + s + x], 1)   # (M, 3)
        cm = _blended(offsets, scale, data, points[item], weights[item], cols)              # (M, 3 m, 3 ch)
        c1, c2, c3 = cm[:, 0], cm[:, 1], cm[:, 2]
        kids = []
        for dy in (0, 1):   # the four children
            for dx in (0, 1):
                s1, s2 = (1 if dx == 0 else -1), (1 if dy == 0 else -1)
                kids.append((2 * x + dx, 2 * y + dy, avg + s * (s1 * c1 + s2 * c2 + s1 * s2 * c3)))
        item = np.concatenate([item] * 4)
        x = np.concatenate([k[0] for k in kids])
        y = np.concatenate([k[1] for k in kids])
        avg = np.concatenate([k[2] for k in kids])
    return out, visited


class ViewDevice:
    """The bake file's entries as device buffers (:class:`wavlight.relight.frame.DeviceEntries`)
    and the kernel ``view_product`` over them."""

    def __init__(self, transfer):
        s = transfer._s
        self.entries = DeviceEntries(s["offsets"], s["entry_scale"], s["entry_data"])
        self.n_levels, self.n_blocks = transfer.n_levels, int(s["offsets"].shape[1])
        self._tables = {}
        self._plastic = None

    def walk(self, points, kind, param, normal, wo, refine: float = REFINE, weights=None, t1_normal=None,
             tau: float = 0.0, queue=None, mass: float = MASS, table=None, rows=None):
        """Launch ``view_product`` on the items (see :func:`product_reference`): its output
        buffers, B (I, 3) float32 and nodes visited (I,) uint32, left on the device. Items of
        plastic's lobes (VIEW_COAT, VIEW_BASE) read ``table`` (the scene's plastic table,
        (materials, PLASTIC_STRIDE), uploaded once) at ``rows`` (I,) (material x PLASTIC_STRIDE)."""
        queue = queue or cl.thread_queue()
        points = np.asarray(points)
        count = len(points)
        per = 1 if points.ndim == 1 else points.shape[1]
        weights = np.ones(count * per, np.float32) if weights is None else np.asarray(weights, np.float32)
        tables = self._tables.get(refine)
        if tables is None:
            t = node_tables(self.n_levels, refine)
            tables = self._tables[refine] = (cl.to_device(t.centres), cl.to_device(t.rows),
                                             cl.to_device(t.scaled))
        prog = cl.program("relight_view.cl", QBITS=self.entries.bits, POINTS=POINTS, K=per, MASS_STEPS=MASS_STEPS)
        normal = np.asarray(normal, np.float64)
        geom = _items(np.asarray(kind), np.asarray(param, np.float64), normal, np.asarray(wo, np.float64),
                      normal if t1_normal is None else np.asarray(t1_normal, np.float64), tau)
        out = cl.scratch("view_walk_out", 12 * count)
        visited = cl.scratch("view_walk_visited", 4 * count)
        table_b = self.plastic_table(table)
        rows = np.zeros(count, np.uint32) if rows is None else np.ascontiguousarray(rows, np.uint32)
        cl.kernel(prog, "view_product")(
            queue, (-(-count // cl.WORK_GROUP) * cl.WORK_GROUP,), (cl.WORK_GROUP,), np.uint32(count),
            np.uint32(self.n_levels), np.uint32(self.n_blocks),
            cl.upload("view_walk_points", np.ascontiguousarray(points, np.uint32), queue),
            cl.upload("view_walk_weights", np.ascontiguousarray(weights, np.float32), queue),
            cl.upload("view_walk_geom", geom, queue),
            cl.upload("view_walk_kind", np.asarray(kind, np.int32), queue),
            cl.upload("view_walk_param", np.asarray(param, np.float32), queue),
            tables[0], tables[1], tables[2], self.entries.offsets[0], self.entries.scale[0], self.entries.data[0],
            np.float32(mass), table_b, cl.upload("view_walk_rows", rows, queue), out, visited)
        return out, visited

    def plastic_table(self, table):
        """The plastic table on the device (uploaded again only when another table is given; a
        row of zeros where there is none)."""
        t = np.ascontiguousarray(np.zeros(bsdfs.PLASTIC_STRIDE) if table is None or not np.size(table) else table,
                                 np.float32).reshape(-1)
        key = t.tobytes()
        if self._plastic is None or self._plastic[0] != key:
            self._plastic = (key, cl.to_device(t))
        return self._plastic[1]

    def products(self, points, kind, param, normal, wo, refine: float = REFINE, weights=None, t1_normal=None,
                 tau: float = 0.0, queue=None, mass: float = MASS, table=None, rows=None):
        """(B (I, 3) float32, nodes visited (I,) uint32) of the items (see :func:`product_reference`)."""
        queue = queue or cl.thread_queue()
        count = len(points)
        if not count:
            return np.zeros((0, 3), np.float32), np.zeros(0, np.uint32)
        out, visited = self.walk(points, kind, param, normal, wo, refine, weights, t1_normal, tau, queue, mass, table,
                                 rows)
        return cl.read(out, (count, 3), np.float32, queue), cl.read(visited, (count,), np.uint32, queue)


def device_has_doubles() -> bool:
    """Whether the OpenCL device computes in double precision (kernels/relight_view.cl's ``wide``)."""
    return "cl_khr_fp64" in cl.runtime().device.extensions.split()


class FrameDevice:
    """The frame's tables on the device, for the kernels ``view_lookup`` and ``view_assemble``
    (kernels/relight_view.cl): per face its lattice k, first entry, normal and material, the
    lattice's cache points, the points' normals, the materials' albedo, the environment's texels
    and rotation."""

    def __init__(self, frames, device: ViewDevice):
        self.points = len(frames.position)
        self.wide = np.float64 if device_has_doubles() else np.float32
        env = frames.environment
        self.face_k = cl.to_device(np.ascontiguousarray(frames.face_k, np.int32))
        self.face_base = cl.to_device(np.ascontiguousarray(frames.face_base, np.int64))
        self.lattice = cl.to_device(np.ascontiguousarray(frames.lattice, np.int32))
        self.normal = cl.to_device(np.ascontiguousarray(frames.normal32, np.float32))
        self.face_normal = cl.to_device(np.ascontiguousarray(frames.face_normal32, np.float32))
        self.face_material = cl.to_device(np.ascontiguousarray(frames.scene.face_material, np.int32))
        self.albedo = cl.to_device(np.ascontiguousarray(frames.albedo_of, np.float32).reshape(-1))
        # base-colour textures (kernels/texture.h): the faces' texture coordinates, each material's
        # texture and the scene's texels; dummies without textures
        self.textured = bool(getattr(frames, "textured", False))
        sc = frames.scene
        if self.textured:
            texels, table = sc.texture_atlas()
            self.textures = (cl.to_device(textures.face_uv(sc.faces, sc.vertex_uv)), cl.to_device(sc.material_texture),
                             cl.to_device(texels), cl.to_device(table))
        else:
            dummy = cl.to_device(np.zeros(8, np.float32))
            self.textures = (dummy, cl.to_device(np.full(max(len(sc.materials), 1), -1, np.int32)), dummy,
                             cl.to_device(np.zeros(4, np.int32)))
        self.env = cl.to_device(np.ascontiguousarray(env.pixels, np.float32).reshape(-1))
        self.env_size = (np.uint32(env.width), np.uint32(env.height))
        self.map_from_world = cl.to_device(np.ascontiguousarray(env.map_from_world, self.wide).reshape(-1))
        self.cos_crease = np.float32(np.cos(np.radians(CREASE_DEGREES)))
        self._zeros = np.zeros(self.points, np.uint8)
        self.program = cl.program("relight_view.cl", QBITS=device.entries.bits, POINTS=POINTS, K=1,
                                  MASS_STEPS=MASS_STEPS, TEXTURES=int(self.textured),
                                  BACKGROUND_MODE=BACKGROUND_MODE[env.background])

    def lookup(self, prim, u, v, d, queue, points: bool = True):
        """Launch ``view_lookup`` on camera rays (prim (N,) int32, -1 a miss; embree's u, v; unit
        directions d (N, 3) float32): the buffers of their cache points (N, 3) uint32 and weights
        (N, 3) float32 (the device twin of :meth:`wavlight.relight.view_frames.ViewFrames.hit_points`,
        all rays), the ray buffers, and with ``points`` the cache points of weight > 0 (sorted;
        the one wait for the device), without them None (the inputs are uploaded without a wait
        each: the queue is in order)."""
        count = len(prim)
        prim_b = cl.upload("view_prim", np.ascontiguousarray(prim, np.int32), queue, blocking=False)
        dir_b = cl.upload("view_dir", np.ascontiguousarray(d, np.float32), queue, blocking=False)
        used = cl.upload("view_used", self._zeros, queue, blocking=False)
        ids, w = cl.scratch("view_ids", 12 * count), cl.scratch("view_weights", 12 * count)
        cl.kernel(self.program, "view_lookup")(
            queue, (cl.items(count),), (cl.WORK_GROUP,), np.uint32(count), prim_b,
            cl.upload("view_u", np.ascontiguousarray(u, np.float32), queue, blocking=False),
            cl.upload("view_v", np.ascontiguousarray(v, np.float32), queue, blocking=False), dir_b, self.face_k,
            self.face_base, self.lattice, self.normal, self.face_normal, self.cos_crease, ids, w, used)
        if not points:
            return ids, w, prim_b, dir_b, None
        return ids, w, prim_b, dir_b, np.flatnonzero(cl.read(used, (self.points,), np.uint8, queue))

    def assemble(self, count, prim_b, ids, w, dir_b, points, B, queue, image=None, coat=None, uv=None) -> np.ndarray:
        """Launch ``view_assemble``: (N, 3) float32 (into ``image`` if given), a hit's albedo x the
        blend of its points' B (rows of ``B`` in the order of ``points``) plus the blend of the
        coat rows of its plastic points (``coat``: (cache points, row of B) pairs, or None), a
        miss's environment texel; in a textured scene the albedo times the texture at the hit, at
        embree's barycentrics ``uv`` = (u (N,), v (N,)) of the rays."""
        if self.textured and uv is None:
            raise ValueError("FrameDevice.assemble: a textured scene needs the hits' barycentrics (uv)")
        bary = (cl.upload("view_bary", np.ascontiguousarray(np.stack([np.asarray(uv[0], np.float32),
                                                                      np.asarray(uv[1], np.float32)], 1)), queue)
                if self.textured else self.textures[0])   # (not read without textures)
        row = np.full(self.points, -1, np.int32)
        row[points] = np.arange(len(points), dtype=np.int32)
        coat_row = np.full(self.points, -1, np.int32)
        if coat is not None and len(coat[0]):
            coat_row[coat[0]] = coat[1]
        out = cl.scratch("view_image", 12 * count)
        cl.kernel(self.program, "view_assemble")(
            queue, (cl.items(count),), (cl.WORK_GROUP,), np.uint32(count), prim_b, ids, w,
            cl.upload("view_row", row, queue), cl.upload("view_coat_row", coat_row, queue), B, self.face_material,
            self.albedo, bary, *self.textures, dir_b, self.env, *self.env_size,
            self.map_from_world, out)
        if image is None:
            return cl.read(out, (count, 3), np.float32, queue)
        cl.opencl().enqueue_copy(queue, image, out)
        return image

