"""The ``wavelet`` strategy: top-down product sampling (wavlight/strategies/product.py, kernels/product.h).

What is checked, after tests/strategies/test_samplers.py (which does the same for the light strategy):

1. The numpy product sampler, through ``WaveletStrategy.sample`` / ``.pdf`` on hand-built
   :class:`ShadingPoints`, for lambert, phong (n = 20, 200) and ggx (alpha 0.05, 0.3) at
   several normals and views (the lobe axis on the map's pole, 45 degrees, grazing 80
   degrees, a normal facing down), under small adversarial maps (one bright texel, a
   constant map, a 64 x 32 sky with a sun of three texels, a 3 x 2 map; rotate_y 0 and 90):
   (a) chi-square of the samples against the pdf on the lat-long square, (b) sample pdf ==
   pdf(), (c) the pdf integrates to 1 (exactly on the square, Monte Carlo on the sphere),
   (d) pdf > 0 wherever L > 0 far enough above the horizon, (e) the MIS condition: wherever
   f cos L > 0 the product or the bsdf pdf is > 0.
2. The shade kernel against its numpy twin for lobe axes on special directions (the map's
   poles, its phi = 0 seam, node centres, at normal incidence) and grazing views.
3. :func:`product_levels` and :func:`lobe_kappa` against their documented definitions.
4. Unbiasedness: the kernel's wavelet estimate at single points equals the mis estimate on
   the adversarial maps; rendered ``wavelet`` images equal ``mis`` images under real maps
   that ship with wavlight; a white furnace for every product depth.
5. ``--strategy wavelet --wavelet-levels`` through the command line.

Why the chi-square runs on leaf-aligned cells of the square. The sampler walks the light
tree from the root; at a level l < P (the product depth) it enters a child c with
probability I(c) / sum of I over c and its three siblings, where I(c) is c's box mass times
the BRDF factor evaluated at c's *centre* direction (or, where all four are 0, the masses
alone); at levels >= P it enters c with probability m(c) / m(parent); at every step it
rescales the used uniform number to [0, 1), so that, given the path, the rescaled numbers
are uniform and the point lands uniformly in the leaf. No factor depends on where in the
leaf the point is, so the density on the square,
    pdf_square(uv) = prod_l P(child_l | parent_l) * 4^n,
is a function of the leaf holding uv alone: constant on every leaf of the light tree. It is
*not* constant on the nodes of level P or coarser (the light masses vary inside them), and
on the sphere it varies inside a leaf with 1 / sin(theta). So the test bins the samples'
square points (world_to_square of the sampled directions) in cells aligned with the leaves;
the midpoint rule with one node per cell integrates the pdf exactly (the helper's second
run with 2 x 2 nodes per cell confirms it), and a second chi-square pools the samples'
positions inside their leaves and tests them for uniformity.

Statistics: fixed seeds; the chi-square tests of this file form one family of
false-rejection probability 1 % (Sidak); the other statistical checks use 5 standard errors
(integrals) or Bonferroni/Sidak thresholds stated where they are used.
"""
from __future__ import annotations

import functools
import json
import math
import subprocess
import sys
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

import wavlight
from chi2 import SquareGrid, chi2_test, sidak_alpha
from scenes_util import (camera_of, check_estimates, load, map3x2, one_texel_map, random_normals_views, ray_sphere,
                         write_env, z_threshold)
from wavlight import bsdfs, data, strategies, warp
from wavlight.strategies import product
from wavlight.haar.tree import HaarTree
from wavlight.envmap import LUMINANCE, Environment, procedural_sky, read_image
from wavlight.scene import Camera, Material, Scene
from wavlight.shading import KernelShader, NumpyShader
from wavlight.strategies import LightStrategy, ShadingPoints, WaveletStrategy

REPO = Path(__file__).resolve().parents[2]


def seed_of(name: str) -> int:
    """A fixed seed per test case (stable across runs and Python versions)."""
    return zlib.crc32(name.encode())


def uniform_sphere(n: int, rng) -> np.ndarray:
    z = rng.uniform(-1, 1, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


def unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


# ============================================================================= test configurations
def _sky():
    # 64 x 32 texels of 5.6 degrees: the default sun (0.75 degrees) covers no texel centre; a
    # 5-degree sun covers three, a small light 2e4 times brighter than the sky
    px = procedural_sky(width=64, height=32, sun_radius=5.0)
    assert 1 <= (px.max(-1) > 1000).sum() <= 8
    return px


MAPS = {
    "one_texel": lambda: Environment(one_texel_map()),
    "one_texel_rot90": lambda: Environment(one_texel_map(), rotate_y=90.0),
    "constant": lambda: Environment(np.ones((32, 64, 3), np.float32)),
    "sky": lambda: Environment(_sky()),
    "sky_rot90": lambda: Environment(_sky(), rotate_y=90.0),
    "map3x2": lambda: Environment(map3x2()),
}

ALBEDO = np.array([0.9, 0.7, 0.5], np.float32)
MATERIALS = {
    "lambert": Material("lambert", bsdfs.LAMBERT, ALBEDO, 0.0),
    "phong20": Material("phong20", bsdfs.PHONG, ALBEDO, 20.0),
    "phong200": Material("phong200", bsdfs.PHONG, ALBEDO, 200.0),
    "ggx0.05": Material("ggx0.05", bsdfs.GGX, ALBEDO, 0.05),
    "ggx0.3": Material("ggx0.3", bsdfs.GGX, ALBEDO, 0.3),
}


@dataclass(frozen=True)
class Geometry:
    """A shading point: world normal, and the view direction wo at view_deg from it."""

    normal: tuple
    view_deg: float
    azimuth: float = 0.7

    def frame(self):
        n = unit(self.normal)[None]
        s, t = warp.frame(n)
        return n[0], s[0], t[0]

    def wo_local(self):
        th = math.radians(self.view_deg)
        return np.array([math.sin(th) * math.cos(self.azimuth), math.sin(th) * math.sin(self.azimuth),
                         math.cos(th)])

    def wo_world(self):
        n, s, t = self.frame()
        w = self.wo_local()
        return w[0] * s + w[1] * t + w[2] * n


GEOMETRIES = {
    "pole": Geometry((0.0, 1.0, 0.0), 0.0),            # normal incidence: the lobe axis is the map's pole
    "tilted45": Geometry((0.3, 0.8, 0.2), 45.0),
    "grazing80": Geometry((0.6, 0.3, -0.74), 80.0),    # half of a glossy lobe below the horizon
    "down80": Geometry((-0.2, -0.9, 0.3), 80.0),       # facing down: little light above the horizon
}


@dataclass(frozen=True)
class Case:
    map_id: str
    mat_id: str
    geom_id: str
    levels: int | None = None   # product depth override

    @property
    def id(self):
        return f"{self.map_id}-{self.mat_id}-{self.geom_id}" + ("" if self.levels is None else f"-P{self.levels}")


# Every material under every map; the geometries rotate so that each material and each map
# meets every geometry. Plus two product-depth overrides (the full tree depth, and 1).
_G = list(GEOMETRIES)
CASES = [Case(m, b, _G[(i + j) % len(_G)]) for i, m in enumerate(MAPS) for j, b in enumerate(MATERIALS)]
CASES += [Case("sky", "phong20", "tilted45", levels=11), Case("one_texel", "ggx0.05", "grazing80", levels=1)]
CASE_IDS = [c.id for c in CASES]

N_CHI2 = 2 * len(CASES)        # leaf-aligned cells + position inside the leaf, per case
N_SAMPLES = 50_000            # >= 5 expected per pooled cell; the chi-square cells pool below that
N_Z, N_PHI = 128, 256          # stratified uniform directions: one jittered point per (z, phi) cell
N_UNIFORM = N_Z * N_PHI


@functools.lru_cache(maxsize=None)
def environment(map_id: str) -> Environment:
    return MAPS[map_id]()


@functools.lru_cache(maxsize=None)
def strategy_of(map_id: str, mat_id: str, levels=None) -> WaveletStrategy:
    s = WaveletStrategy(levels=levels)
    s.prepare(environment(map_id), [MATERIALS[mat_id]])
    return s


def points(case: Case, count: int) -> ShadingPoints:
    """``count`` copies of the case's shading point (material index 0 of its strategy)."""
    g, m = GEOMETRIES[case.geom_id], MATERIALS[case.mat_id]
    n, s, t = g.frame()
    rep = lambda v: np.broadcast_to(v, (count, 3)).copy()
    return ShadingPoints(np.zeros((count, 3)), rep(n), rep(s), rep(t), rep(g.wo_local()),
                         np.full(count, m.kind), np.full(count, float(m.param)),
                         np.broadcast_to(m.albedo, (count, 3)).astype(np.float64), np.zeros(count, np.int64))


def pdf_world(case: Case, d: np.ndarray) -> np.ndarray:
    """The product pdf per unit solid angle at world directions d (N, 3)."""
    sp = points(case, len(d))
    return strategy_of(case.map_id, case.mat_id, case.levels).pdf(sp, sp.to_local(d), d)


def pdf_square(case: Case):
    """The product pdf as a density on the lat-long square: pdf(d(uv)) * 2 pi^2 sin(theta),
    the Jacobian d omega / du dv of phi = 2 pi u, theta = pi v."""
    env = environment(case.map_id)

    def pdf(uv):
        return pdf_world(case, env.square_to_world(uv)) * 2 * np.pi ** 2 * np.sin(np.pi * uv[:, 1])

    return pdf


@pytest.fixture(scope="module", params=CASES, ids=CASE_IDS)
def case(request):
    """The sampler cases; module scope makes pytest run all tests of one case together, so the
    caches below hold one case's samples at a time."""
    return request.param


@functools.lru_cache(maxsize=1)
def samples_of(case: Case):
    strat = strategy_of(case.map_id, case.mat_id, case.levels)
    rng = np.random.default_rng(seed_of("samples/" + case.id))
    return strat.sample(points(case, N_SAMPLES), rng.random((N_SAMPLES, 2)))


def stratified_sphere(nz: int, nphi: int, rng) -> np.ndarray:
    """One uniformly jittered direction in each of nz x nphi equal-area (z, phi) cells: each
    point is uniform on the sphere, and means over them have no more variance than iid ones."""
    z = (np.arange(nz)[:, None] + rng.random((nz, nphi))) * (2.0 / nz) - 1.0
    phi = (np.arange(nphi)[None, :] + rng.random((nz, nphi))) * (2 * np.pi / nphi)
    r = np.sqrt(np.maximum(0.0, 1 - z * z))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1).reshape(-1, 3)


@functools.lru_cache(maxsize=1)
def uniform_directions(case: Case):
    """N_UNIFORM stratified uniform directions, then every texel centre; with their product pdf."""
    rng = np.random.default_rng(seed_of("uniform/" + case.id))
    d = np.concatenate([stratified_sphere(N_Z, N_PHI, rng), texel_centre_directions(environment(case.map_id))])
    return d, pdf_world(case, d)


def texel_centre_directions(env: Environment) -> np.ndarray:
    """World directions of every texel centre, from the documented lat-long lookup."""
    v = (np.arange(env.height) + 0.5) / env.height
    u = (np.arange(env.width) + 0.5) / env.width
    theta, phi = np.meshgrid(v * np.pi, u * 2 * np.pi, indexing="ij")
    d_map = np.stack([np.sin(theta) * np.sin(phi), np.cos(theta), -np.sin(theta) * np.cos(phi)], -1)
    return d_map.reshape(-1, 3) @ env.world_from_map.T


def leaf_side(case: Case) -> int:
    return 1 << strategy_of(case.map_id, case.mat_id, case.levels).trees.n_levels


# ============================================================================= 1. the numpy sampler
@pytest.mark.slow
def test_product_chi2_on_leaves(case):
    """(a) Product samples follow pdf() (chi-square on leaf-aligned cells of the lat-long square).

    Cells: the leaves, split 2 x 2 where fewer than 256 leaves have mass (a single lit texel
    covers 1 x 2 leaves of the 64 x 32 maps), and at least 32 x 32 cells in all (the 3 x 2
    map has 4 x 4 leaves). The pdf is constant on leaves (module docstring), so the midpoint
    rule is exact on these cells.
    """
    ds = samples_of(case)
    assert np.all(np.isfinite(ds.wi_world)), "non-finite sample directions"
    assert np.all(ds.pdf > 0), f"{(~(ds.pdf > 0)).sum()} samples returned with pdf <= 0 or NaN"
    env = environment(case.map_id)
    uv = env.world_to_square(ds.wi_world)
    side = leaf_side(case)
    strat = strategy_of(case.map_id, case.mat_id, case.levels)
    lit = int((strat.trees.nodes()[strat.tree_index[0]][-side * side:] > 0).sum())
    cells = max(side * (2 if lit < 256 else 1), 32)
    ok, p, msg = chi2_test(uv, pdf_square(case), SquareGrid.uniform(cells), n_tests=N_CHI2, quad=1,
                           rule="midpoint")
    assert ok, msg


@pytest.mark.slow
def test_product_uniform_inside_leaves(case):
    """(a') Given its leaf, a sample lands uniformly inside it: the samples' positions inside
    their leaves, pooled, are uniform on [0, 1)^2 (chi-square, 16 x 16 cells)."""
    ds = samples_of(case)
    side = leaf_side(case)
    uv = environment(case.map_id).world_to_square(ds.wi_world)
    frac = np.mod(uv * side, 1.0)
    ok, p, msg = chi2_test(frac, lambda x: np.ones(len(x)), SquareGrid.uniform(16), n_tests=N_CHI2, quad=1,
                           rule="midpoint")
    assert ok, msg


@pytest.mark.slow
def test_product_sample_pdf_equals_pdf(case):
    """(b) The pdf returned with a sample equals pdf() of its direction (rtol 1e-6).

    Both are the same float64 expression of the same leaf (the direction is mapped back to
    the square by world_to_square, float64 round trip ~1e-16), so any difference means the
    direction was looked up in another leaf than it was drawn from, or the Jacobian differs.
    The first 20 000 samples are checked, and 4 096 more from a grid of cell-centred u.
    """
    strat = strategy_of(case.map_id, case.mat_id, case.levels)
    ds = samples_of(case)
    g = (np.arange(64) + 0.5) / 64
    grid = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    dg = strat.sample(points(case, len(grid)), grid)
    d = np.concatenate([ds.wi_world[:20_000], dg.wi_world])
    p = np.concatenate([ds.pdf[:20_000], dg.pdf])
    q = pdf_world(case, d)
    bad = ~np.isclose(p, q, rtol=1e-6, atol=0)
    assert not bad.any(), (f"{bad.sum()} of {len(p)} samples: sample pdf {p[bad][:3].tolist()} != pdf() "
                           f"{q[bad][:3].tolist()} at {d[bad][:3].tolist()}")


@pytest.mark.slow
def test_product_pdf_integrates_to_one(case):
    """(c) The pdf integrates to 1, two ways.

    1. Exactly, on the lat-long square: one midpoint per leaf (the pdf is constant on leaves).
       The product conditionals of the four children of a node sum to 1 in float64; the only
       error is float32 rounding in the light tree (a node's mass vs. the sum of its leaves,
       <= 2n roundings of 2^-24 with n <= 6 here): 1e-5 covers it with margin.
    2. On the sphere, by Monte Carlo over 32k stratified uniform directions: 4 pi mean(pdf),
       within 5 standard errors plus 1e-6 (the iid formula, which overestimates the error of a
       stratified mean). This checks the Jacobian and world_to_square (with rotate_y) end to end.
    """
    side = leaf_side(case)
    c = (np.arange(side) + 0.5) / side
    uv = np.stack(np.meshgrid(c, c), -1).reshape(-1, 2)
    exact = pdf_square(case)(uv).sum() / side ** 2
    assert abs(exact - 1) < 1e-5, f"pdf integrates to {exact} on the lat-long square"

    d, p = uniform_directions(case)
    x = 4 * np.pi * p[:N_UNIFORM]
    mean, se = x.mean(), x.std(ddof=1) / np.sqrt(len(x))
    assert abs(mean - 1) <= 5 * se + 1e-6, f"Monte Carlo integral {mean} +- {se}"


def node_radius(level: int, n_edge: int = 257) -> float:
    """Largest angle between a level-`level` node's centre direction and any direction in
    the node (lat-long square, phi = 2 pi u, theta = pi v), over all nodes of the level.

    The angle to a fixed point has no interior maximum on a node (which never holds its
    centre's antipode), so the node's border is sampled, n_edge points an edge; the slack
    covers the gaps (half a gap, of at most pi / (n_edge - 1) radians of arc).
    """
    side = 1 << level
    t = np.linspace(0, 1, n_edge)
    border = np.concatenate([np.stack([t, 0 * t], 1), np.stack([t, 1 + 0 * t], 1),
                             np.stack([0 * t, t], 1), np.stack([1 + 0 * t, t], 1)])

    def sq(u, v):
        phi, theta = 2 * np.pi * u, np.pi * v
        return np.stack([np.sin(theta) * np.sin(phi), np.cos(theta), -np.sin(theta) * np.cos(phi)], -1)

    worst = 0.0
    for y in range(side):   # every column is a rotation of column 0
        c = sq(0.5 / side, (y + 0.5) / side)
        b = sq(border[:, 0] / side, (y + border[:, 1]) / side)
        worst = max(worst, float(np.arccos(np.clip(b @ c, -1, 1)).max()))
    return worst + np.pi / (n_edge - 1)


def horizon_margin(depth: int) -> float:
    """An angle eps such that every direction more than eps above the horizon has a positive
    BRDF factor in all its ancestor nodes of levels 1..depth.

    Documented factors (strategies/product.py): lambert and phong clamp(cos_n + h_l, 0, 1), ggx
    clamp(cos_n / h_l + 1, 0, 1), both > 0 iff cos_n > -h_l at the node's centre, with
    h_l = HORIZON_BLUR / 2^l; the phong exp(-k x) and ggx (1 + k x)^-2 factors are > 0 in
    float64 for every direction (k x <= 2 max(kappa) = 400 here). A direction at eps above
    the horizon is within node_radius(l) of its level-l ancestor's centre, so that centre's
    cos_n >= -sin(node_radius(l) - eps), which is > -h_l once eps > node_radius(l) - asin(h_l).
    """
    eps = 0.0
    for level in range(1, depth + 1):
        h = product.HORIZON_BLUR / (1 << level)
        if h < 1:
            eps = max(eps, node_radius(level) - math.asin(h))
    return eps + 1e-6


@pytest.mark.slow
def test_product_pdf_positive_where_light_above_horizon(case):
    """(d) pdf > 0 wherever the map has radiance (for lambert, which walks the compensated light
    tree: radiance above the map's mean) and the direction is more than horizon_margin(P) above
    the shading point's horizon (P the case's product depth).

    Closer to the horizon (and below it) the product pdf may be 0 by design: a node whose
    centre is far below the horizon gets importance 0 even if a corner of it is above; the
    bsdf half of the MIS pair covers those directions (test (e)). Directions: 32k stratified
    uniform ones and every texel centre.
    """
    strat = strategy_of(case.map_id, case.mat_id, case.levels)
    env = environment(case.map_id)
    d, p = uniform_directions(case)
    n, _, _ = GEOMETRIES[case.geom_id].frame()
    eps = horizon_margin(int(strat.levels[0]))
    lum = env.eval(d) @ LUMINANCE
    if strat.tree_kinds[strat.tree_index[0]] == "compensated":
        # the compensated leaves, from the map (not from the strategy's tree)
        n_levels = strat.trees.n_levels
        leaves = env.luminance_square(n_levels, compensated=True)
        ij = np.minimum((env.world_to_square(d) * (1 << n_levels)).astype(np.int64), (1 << n_levels) - 1)
        lum = np.where(leaves[ij[:, 1], ij[:, 0]] > 0, lum, 0.0)
    need = (lum > 0) & (d @ n > math.sin(eps))
    bad = need & ~(p > 0)
    assert need.sum() > 0 or case.geom_id == "down80" or case.map_id.startswith("one_texel"), \
        "the check is empty"
    assert not bad.any(), (f"{bad.sum()} of {need.sum()} lit directions more than {math.degrees(eps):.1f} deg "
                           f"above the horizon have product pdf 0, e.g. {d[bad][:3].tolist()}")


def test_mis_pair_covers_the_integrand(case):
    """(e) The MIS unbiasedness condition: wherever f cos L > 0, the product pdf or the bsdf
    pdf is > 0 (the MIS weights, balance heuristic, then sum to 1 there). 32k stratified uniform
    directions and every texel centre."""
    env = environment(case.map_id)
    d, p_prod = uniform_directions(case)
    sp = points(case, len(d))
    wl = sp.to_local(d)
    integrand = sp.bsdf_eval_cos(wl) * (env.eval(d) @ LUMINANCE)
    p_bsdf = sp.bsdf_pdf(wl)
    assert np.all(np.isfinite(p_prod)) and np.all(p_prod >= 0)
    bad = (integrand > 0) & ~((p_prod > 0) | (p_bsdf > 0))
    assert not bad.any(), f"{bad.sum()} directions with f cos L > 0 and both pdfs 0, e.g. {d[bad][:3].tolist()}"


@pytest.mark.parametrize("map_id", ["one_texel_rot90", "sky", "map3x2"])
@pytest.mark.parametrize("mat_id", ["phong200", "ggx0.3"])
def test_product_depth_zero_is_light_sampling(map_id, mat_id):
    """With the product depth overridden to 0 the walk never looks at the BRDF: the pdf is the
    light strategy's, m(leaf) / m(root) 4^n / (2 pi^2 sin theta).

    rtol 1e-5: the light pdf comes from the float32 kernel (its uv rounded to float32), the
    product pdf from float64 arithmetic on the same tree. Directions whose square point lies
    within 1e-6 of a leaf edge are left out: float32 rounding may put them in the neighbour
    leaf (the texel centres of a 64 x 32 map, for one, sit exactly on the edges of a 64 x 64
    tree's leaves). Directions: 50k uniform ones and every leaf centre.
    """
    case = Case(map_id, mat_id, "tilted45", levels=0)
    env = environment(map_id)
    light = LightStrategy()
    light.prepare(env)
    side = 1 << light.tree.n_levels
    assert side == leaf_side(case)
    c = (np.arange(side) + 0.5) / side
    rng = np.random.default_rng(seed_of("depth0/" + case.id))
    d = np.concatenate([uniform_sphere(50_000, rng),
                        env.square_to_world(np.stack(np.meshgrid(c, c), -1).reshape(-1, 2))])
    f = env.world_to_square(d) * side
    inside = np.all(np.abs(f - np.round(f)) > 1e-6 * side, axis=1)
    assert inside.mean() > 0.99
    np.testing.assert_allclose(pdf_world(case, d[inside]), light.pdf_directions(d[inside]), rtol=1e-5, atol=0)


# ============================================================================= 2. kernel vs numpy
def _scene(env, mats):
    cam = Camera(np.zeros(3), np.array([0, 0, -1.0]), np.array([0, 1.0, 0]), 40.0)
    return Scene("t", 8, 8, 1, "wavelet", 0, cam, env, np.zeros((0, 3), np.float32),
                 np.zeros((0, 3), np.int32), np.zeros(0, np.int32), list(mats))


# float32 Jacobian: the kernel computes sin(theta) = sqrt(1 - y^2) from a float32 direction whose
# y carries an absolute error of a few ulp(1) (JAC_DY); the Jacobian 1 / sin(theta) then has a
# relative error <= JAC_DY / (1 - y^2). A slot's value depends on its pdf with a relative
# sensitivity <= 2 (the bsdf slot's weight, q / (q + p) for wavelet's balance heuristic, q^2 / (q^2 + p^2)
# for mis's power heuristic, has d log / d log p >= -2).
JAC_DY = 2.4e-7
RTOL = 2e-3   # float32 vs float64 elsewhere (as tests/test_shading.py)
ATOL = 1e-6


def _special_normals(env):
    """Axis normals (the lat-long map's poles +-Y, its phi = 0 seam -Z) and the centre
    directions of nodes of levels 1-3 (at normal incidence the lobe axis is then exactly a
    node's centre, x = 1 - d . axis = 0 there)."""
    axes = np.concatenate([np.eye(3), -np.eye(3)])
    uv = np.array([[0.25, 0.25], [0.375, 0.625], [0.8125, 0.0625], [0.5625, 0.9375]])
    return np.concatenate([axes, env.square_to_world(uv)])


@pytest.mark.slow
@pytest.mark.parametrize("map_id", ["sky", "sky_rot90"])
def test_kernel_matches_numpy_on_lobe_axes_and_grazing(map_id):
    """The shade kernel's wavelet estimates equal the numpy twin's, from the same uniforms, for
    lobe axes on special directions and at grazing views.

    Shading points: the normals of _special_normals, each viewed at 0 degrees (the lobe axis is
    the normal itself: on a pole, on the seam, on a node centre), 80, 89 and 89.9 degrees, for
    all five materials, 300 uniforms each. Per sample and slot: values agree within
    RTOL + 2 JAC_DY / (1 - y^2) relative (see JAC_DY) plus ATOL, and, where the value exceeds
    ATOL, directions within 2e-4. Allowed misses: 0.1 % of all slots and 1 % of any
    configuration's (a direction within float rounding of a leaf or texel edge looks up the
    neighbour; far outside a phong 200 lobe the kernel's exp(-k x) underflows in float32 and
    its walk falls back to the light masses, where numpy still sees ~1e-170). Each
    configuration's mean estimate must agree to 0.25 of its standard error: the differences
    are irrelevant next to the Monte Carlo noise.

    Left out: the bsdf slot of ggx at exactly normal incidence. There the visible-normal
    sampler's azimuthal frame is set by the rounding noise of wo.xy (Heitz 2018 picks any
    frame when wo is the normal; the distribution is rotationally symmetric), so the kernel
    and numpy draw equally valid but different directions from the same u.
    """
    env = environment(map_id)
    mats = list(MATERIALS.values())
    scene = _scene(env, mats)
    strat = strategies.make("wavelet", candidates=0)   # the pair; resampling: test_kernel_matches_numpy_with_candidates
    strat.prepare(env, mats)
    normals = _special_normals(env)
    views = (0.0, 80.0, 89.0, 89.9)
    per = 300
    configs = [(i, v, m) for i in range(len(normals)) for v in views for m in range(len(mats))]
    n = np.repeat(normals[[c[0] for c in configs]], per, 0)
    s, t = warp.frame(n)
    th = np.radians(np.repeat([c[1] for c in configs], per))
    wo = np.sin(th)[:, None] * (0.6 * s + 0.8 * t) + np.cos(th)[:, None] * n
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    mat = np.repeat([c[2] for c in configs], per).astype(np.int32)
    rng = np.random.default_rng(seed_of("kernel-axes/" + map_id))
    u = rng.random((len(n), 4), dtype=np.float32)
    wi_k, val_k = KernelShader(scene, strat)(n, wo, mat, u)
    wi_r, val_r = NumpyShader(scene, strat)(n, wo, mat, u)
    assert np.all(np.isfinite(val_k)) and np.all(val_k >= 0)
    compare = np.ones(val_r.shape[:2], bool)
    compare[(th == 0) & (np.array([m.kind for m in mats])[mat] == bsdfs.GGX), 1] = False
    y = np.abs(wi_r[..., 1])
    with np.errstate(divide="ignore"):
        rtol = RTOL + 2 * JAC_DY / np.maximum(1 - y * y, 0.0)
    ok = np.all(np.abs(val_k - val_r) <= ATOL + rtol[..., None] * np.abs(val_r), axis=2)
    significant = np.abs(val_r).max(axis=2) > ATOL
    ok &= (np.abs(wi_k - wi_r).max(axis=2) < 2e-4) | ~significant   # same direction where it matters
    ok |= ~compare
    assert ok.mean() >= 0.999, f"{(~ok).sum()} of {compare.sum()} slots differ"
    okc = ok.reshape(len(configs), per * 2).mean(1)
    yk = (val_k * compare[..., None]).sum(1).reshape(len(configs), per, 3)
    yr = (val_r * compare[..., None]).sum(1).reshape(len(configs), per, 3)
    se = yr.std(1, ddof=1) / np.sqrt(per)
    gap = np.abs(yk.mean(1) - yr.mean(1))
    worse = (okc < 0.99) | np.any(gap > 0.25 * se + ATOL, axis=1)
    if worse.any():
        k = np.nonzero(worse)[0][:5]
        raise AssertionError("configurations (normal, view, material) where kernel and numpy differ: "
                             + "; ".join(f"{normals[configs[i][0]].round(3).tolist()}, {configs[i][1]} deg, "
                                         f"{mats[configs[i][2]].name}: {okc[i]:.3f} of slots agree, means "
                                         f"{yk[i].mean(0)} vs {yr[i].mean(0)} (se {se[i]})" for i in k))


@pytest.mark.slow
@pytest.mark.parametrize("candidates", [2, 8, 17])
@pytest.mark.parametrize("map_id", ["sky", "sky_rot90", "map3x2"])
def test_kernel_matches_numpy_with_candidates(map_id, candidates):
    """The shade kernel's resampling estimator (wavelet with candidates, kernels/shade.cl
    RIS_PRODUCT) against its numpy twin (strategies.ris_shade_reference), from the same
    uniforms: random normals and views (none at exact normal incidence, where the ggx
    sampler's azimuth is left to rounding), all five materials, 4000 points. The candidates'
    uniforms are the same float32 numbers in both (R2_FIXED); a candidate whose walk or
    direction rounds into a neighbouring leaf or texel changes the weights a little and may
    change which candidate is picked, so 99.5% of the slots must agree (values within
    RTOL + ATOL, directions within 2e-4), and the means within a quarter of their
    standard error."""
    env = environment(map_id)
    mats = list(MATERIALS.values())
    scene = _scene(env, mats)
    strat = strategies.make("wavelet", candidates=candidates)
    strat.prepare(env, mats)
    rng = np.random.default_rng(seed_of(f"kernel-ris/{map_id}/{candidates}"))
    count = 4000
    n, wo = random_normals_views(rng, count)
    mat = rng.integers(0, len(mats), count).astype(np.int32)
    u = rng.random((count, 4), dtype=np.float32)
    wi_k, val_k, off_k = KernelShader(scene, strat)(n, wo, mat, u, with_offset=True)
    wi_r, val_r, off_r = NumpyShader(scene, strat)(n, wo, mat, u, with_offset=True)
    assert np.all(np.isfinite(val_k)) and np.all(val_k >= 0) and np.all(np.isfinite(off_k))
    ok = np.all(np.abs(val_k - val_r) <= ATOL + RTOL * np.abs(val_r), axis=2)
    ok &= (np.abs(wi_k - wi_r).max(axis=2) < 2e-4) | (np.abs(val_r).max(axis=2) <= ATOL)
    assert ok.mean() >= 0.995, f"{(~ok).sum()} of {ok.size} slots differ"
    # the control variate: offset + both values = albedo U, the candidates' unshadowed estimate
    # (no pick involved), so it agrees where the candidates do
    u_k, u_r = off_k + val_k.sum(1), off_r + val_r.sum(1)
    agree = np.all(np.abs(u_k - u_r) <= ATOL + RTOL * np.abs(u_r), axis=1)
    assert agree.mean() >= 0.995, f"{(~agree).sum()} of {agree.size} points' U differ"
    assert np.all(u_k >= -ATOL - RTOL * np.abs(val_k).sum(1))   # U >= 0 up to rounding, per point
    yk, yr = val_k.sum(1), val_r.sum(1)
    se = yr.std(0, ddof=1) / np.sqrt(count)
    assert np.all(np.abs(yk.mean(0) - yr.mean(0)) <= 0.25 * se + ATOL), (yk.mean(0), yr.mean(0), se)


@pytest.mark.parametrize("mat_ids, kinds, index", [
    (["phong200"], ["plain"], [0]),
    (["lambert"], ["compensated"], [0]),
    (["lambert", "ggx0.05", "lambert"], ["plain", "compensated"], [1, 0, 1])])
def test_light_trees_per_material(mat_ids, kinds, index):
    """WaveletStrategy keeps one light tree per kind its materials need: plain for glossy
    lobes, MIS-compensated for lambert; each tree's leaves are the map's (plain or
    compensated) leaf masses, and info() reports the choice and the memory of all trees (the
    device buffer: their nodes plus each tree's cache-line origin and padding, < 27 floats)
    plus the per-material lobe tables (8 bytes each)."""
    env = environment("sky")
    s = WaveletStrategy()
    s.prepare(env, [MATERIALS[m] for m in mat_ids])
    assert s.tree_kinds == kinds and s.tree_index.tolist() == index
    nodes = s.trees.nodes()
    n = s.trees.n_levels
    for tree, kind in zip(nodes, kinds):
        want = env.luminance_square(n, compensated=kind == "compensated").ravel()
        np.testing.assert_allclose(tree[-want.size:], want, rtol=1e-6, atol=1e-30)
    info = s.info()
    trees = info["memory_bytes"] - 8 * len(mat_ids)
    assert trees == s.trees.buffer.size
    assert 0 <= trees - nodes.size * 4 < 27 * 4 * len(nodes)
    assert info["product_light_tree"] == {MATERIALS[m].name: kinds[i] for m, i in zip(mat_ids, index)}


# ============================================================================= 3. product depth
def test_lobe_kappa_values():
    """lobe_kappa: 0 for lambert, n for phong, 1 / (2 alpha^2) for ggx, capped at MAX_KAPPA."""
    for p in (0.0, 0.3, 1.0, 80.0):
        assert product.lobe_kappa(bsdfs.LAMBERT, p) == 0.0
    for e in (0.0, 1.0, 20.0, 200.0, 1e5):
        assert product.lobe_kappa(bsdfs.PHONG, e) == pytest.approx(e, rel=1e-15)
    for a in (0.02, 0.05, 0.1, 0.3, 0.7, 1.0):
        assert product.lobe_kappa(bsdfs.GGX, a) == pytest.approx(1 / (2 * a * a), rel=1e-12)
    # the scene format allows phong exponents up to 1e6 and ggx alpha down to 1e-4 (5e7)
    assert product.lobe_kappa(bsdfs.PHONG, 1e6) == product.MAX_KAPPA
    assert product.lobe_kappa(bsdfs.GGX, 1e-4) == product.MAX_KAPPA
    assert np.isfinite(product.lobe_kappa(bsdfs.GGX, 1e-4))


@pytest.mark.parametrize("alpha", [0.05, 0.1, 0.3])
def test_ggx_kappa_is_the_documented_profile(alpha):
    """At normal incidence D(h) / D(n) as a function of the reflected direction d is
    (1 + x (1 - alpha^2) / (2 alpha^2))^-2 with x = 1 - d . n (tan^2 theta_h = x / (2 - x)),
    so the documented (1 + kappa x)^-2 with kappa = lobe_kappa matches it within a relative
    2 alpha^2 over the upper hemisphere. A kappa of the wrong power of alpha misses by far."""
    kappa = product.lobe_kappa(bsdfs.GGX, alpha)
    th_h = np.linspace(0, np.pi / 4 - 1e-9, 400)
    h = np.stack([np.sin(th_h), 0 * th_h, np.cos(th_h)], 1)
    x = 1 - np.cos(2 * th_h)
    ratio = bsdfs.ggx_d(h, alpha) / bsdfs.ggx_d(np.array([[0.0, 0.0, 1.0]]), alpha)
    np.testing.assert_allclose((1 + kappa * x) ** -2, ratio, rtol=2 * alpha ** 2 + 1e-12)


def test_product_levels_override_and_caps():
    """An override wins, clamped to [0, tree levels]; lambert (kappa 0) gets min(3, levels)."""
    for tree_levels in range(0, 12):
        for kappa in (0.0, 1.0, 200.0, 1e6):
            for o in range(-2, 15):
                assert product.product_levels(kappa, tree_levels, o) == min(max(o, 0), tree_levels)
        assert product.product_levels(0.0, tree_levels) == min(3, tree_levels)


def test_product_levels_monotone_and_capped():
    """Without override: non-decreasing in kappa (from lambert's 0 up), between
    min(MIN_PRODUCT_LEVELS, levels) and the tree levels, and, where not clamped, the coarsest
    level whose nodes (theta extent pi / 2^P) are no wider than half the lobe width
    1 / (2 sqrt(kappa)) (strategies/product.py)."""
    kappas = np.concatenate([[0.0], np.logspace(-3, 7, 3001)])
    lo = product.MIN_PRODUCT_LEVELS
    for tree_levels in range(0, 12):
        p = np.array([product.product_levels(k, tree_levels) for k in kappas])
        assert np.all(np.diff(p) >= 0), f"not monotone for tree levels {tree_levels}"
        assert np.all(p <= tree_levels) and np.all(p >= min(lo, tree_levels))
        free = (p > lo) & (p < tree_levels)
        half_width = 1 / (2 * np.sqrt(kappas[free]))
        assert np.all(np.pi / 2.0 ** p[free] <= half_width * (1 + 1e-12))
        assert np.all(np.pi / 2.0 ** (p[free] - 1) > half_width)
    # a narrower lobe needs a deeper product where the tree allows it
    assert product.product_levels(200.0, 11) > product.product_levels(20.0, 11) > lo


def _levels_by_name(info, names):
    """info()['product_levels'] as a list in material order (a dict by name, or a list)."""
    pl = info["product_levels"]
    return [pl[n] for n in names] if isinstance(pl, dict) else list(pl)


@pytest.mark.parametrize("override", [None, 0, 2, 5, 11])
def test_strategy_product_levels_per_material(override):
    """WaveletStrategy.prepare gives every material product_levels(lobe_kappa(material), tree
    levels, override), and reports them in info()."""
    mats = list(MATERIALS.values())
    strat = WaveletStrategy(levels=override)
    strat.prepare(environment("sky"), mats)
    n = strat.trees.n_levels
    expect = [product.product_levels(product.lobe_kappa(m.kind, m.param), n, override) for m in mats]
    assert strat.levels.tolist() == expect
    np.testing.assert_allclose(strat.kappa, [product.lobe_kappa(m.kind, m.param) for m in mats])
    assert _levels_by_name(strat.info(), [m.name for m in mats]) == expect


@pytest.mark.parametrize("levels,tree_levels", [(0, 5), (1, 5), (2, 5), (3, 5), (5, 5), (7, 10), (4, 3), (9, 2)])
def test_coefficients_per_walk_counts_the_twins_lobe_evaluations(monkeypatch, levels, tree_levels):
    """product.coefficients_per_walk (--json's product_coefficients_per_walk) is the number of
    node importances (product scaling coefficients) the numpy twin evaluates per walk: counted
    by wrapping node_importance during pdf_reference, which walks the sampled path."""
    env = environment("sky")
    rng = np.random.default_rng(5)
    tree = HaarTree(rng.random((1 << tree_levels, 1 << tree_levels)) + 0.1).nodes()[0]
    count = 64
    calls = []
    real = product.node_importance

    def counting(env_, mass, *args):
        calls.append(np.size(mass))
        return real(env_, mass, *args)

    monkeypatch.setattr(product, "node_importance", counting)
    axis = np.tile([0.0, 1.0, 0.0], (count, 1))
    product.pdf_reference(tree, tree_levels, env, axis, axis, np.full(count, 50.0), np.full(count, levels),
                          np.full(count, bsdfs.PHONG), rng.random((count, 2)))
    assert sum(calls) == count * product.coefficients_per_walk(levels, tree_levels)


def test_strategy_reports_coefficients():
    """info() reports the light coefficients kept (4^n of 4^N) and per material the product
    coefficients per walk."""
    mats = list(MATERIALS.values())
    env = environment("sky")
    strat = WaveletStrategy(light_levels=4)
    strat.prepare(env, mats)
    info = strat.info()
    assert info["light_tree"] == "16x16" and info["light_coefficients_kept"] == 4 ** 4
    assert info["light_coefficients_full"] == 4 ** env.square_levels()
    assert info["product_coefficients_per_walk"] == {
        m.name: product.coefficients_per_walk(p, 4) for m, p in zip(mats, strat.levels.tolist())}


# ============================================================================= 4. unbiasedness
def _kernel_estimates(scene, name, normal, wo, count, seed, visible=None, **options):
    """count one-point shading samples of strategy `name` with the kernel: (count, 3) estimates,
    the part without a shadow ray (the control variate's offset) plus each slot's value times
    its visibility, visible(wi (count, 3)) -> bool (count,) (None: nothing occludes)."""
    strat = strategies.make(name, **options)
    strat.prepare(scene.environment, scene.materials)
    rng = np.random.default_rng(seed)
    n = np.broadcast_to(normal, (count, 3)).astype(np.float64)
    w = np.broadcast_to(wo, (count, 3)).astype(np.float64)
    wi, val, off = KernelShader(scene, strat)(n, w, np.zeros(count, np.int32), rng.random((count, 4), dtype=np.float32),
                                             with_offset=True)
    vis = np.ones(wi.shape[:2]) if visible is None else np.stack([visible(wi[:, k]) for k in range(wi.shape[1])], 1)
    estimate = off.astype(np.float64) + (val.astype(np.float64) * vis[:, :, None]).sum(1)
    if visible is None:
        return estimate
    return estimate, np.abs(off).astype(np.float64) + np.abs(val).astype(np.float64).sum(1)


N_POINT = 100_000


def _assert_point_estimate_equals_mis(case, name, tag, visible=None, family=1, **options):
    """E[name] = E[mis] at the case's shading point (kernel; without visibility, or with the
    same visible(wi) for both): 100k samples of
    each with independent uniforms; per channel the difference of the means must lie within
    z sqrt(se_a^2 + se_m^2), z the two-sided normal quantile at 1e-3 / (3 channels x the cases)
    (Sidak). Where the integrand is 0 both must be exactly 0."""
    env = environment(case.map_id)
    scene = _scene(env, [MATERIALS[case.mat_id]])
    g = GEOMETRIES[case.geom_id]
    n, _, _ = g.frame()
    a = _kernel_estimates(scene, name, n, g.wo_world(), N_POINT, seed_of(f"point-{tag}/" + case.id), visible,
                          **options)
    b = _kernel_estimates(scene, "mis", n, g.wo_world(), N_POINT, seed_of("point-m/" + case.id), visible)
    size = None
    if visible is not None:   # (estimates, their parts' magnitudes)
        (a, size), b = a, b[0]
    assert np.all(np.isfinite(a)) and (visible is not None or np.all(a >= 0))
    ma, mb = a.mean(0), b.mean(0)
    se = np.sqrt(a.var(0, ddof=1) / len(a) + b.var(0, ddof=1) / len(b))
    z = stats.norm.isf(sidak_alpha(1e-3, 3 * len(CASES) * family) / 2)   # family: comparisons per case
    # + float32 rounding: relative 1e-7 of the means, and with an occluder 1e-6 of the samples'
    # magnitudes (the offset albedo U - value_a - value_b cancels to ~10 roundings, not to 0)
    tol = 1e-7 * np.maximum(ma, mb) + (0.0 if visible is None else 1e-6 * size.mean(0))
    assert np.all(np.abs(ma - mb) <= z * se + tol), \
        f"{name} {ma} vs mis {mb}: difference {ma - mb}, z = {np.abs(ma - mb) / np.maximum(se, 1e-300)} > {z:.2f}"


@pytest.mark.slow
def test_wavelet_estimate_equals_mis_at_a_point(case):
    """E[wavelet] = E[mis] = integral of f cos L at one shading point (kernel, no visibility):
    the default resampling estimator (strategies.DEFAULT_CANDIDATES) and the MIS pair."""
    assert strategies.DEFAULT_CANDIDATES >= 2
    _assert_point_estimate_equals_mis(case, "wavelet", "w", family=2, levels=case.levels)
    _assert_point_estimate_equals_mis(case, "wavelet", "w0", family=2, levels=case.levels, candidates=0)


def _half_blocked(wi):
    """A synthetic occluder for the point tests: directions with world x + 0.4 z > 0.1 are blocked
    (a wall across part of every case's hemisphere)."""
    return wi[:, 0] + 0.4 * wi[:, 2] <= 0.1


@pytest.mark.slow
def test_wavelet_control_variate_unbiased_under_occlusion(case):
    """With an occluder the control variate's offset (albedo U - value_a - value_b, no shadow
    ray) no longer cancels: E[offset + value_a V(y_a) + value_b V(y_b)] must still equal mis's
    E[value_a V + value_b V] under the same visibility; and without the control variate too,
    on the first map's cases (every material: each case is another kernel build, 4 s cold)."""
    _assert_point_estimate_equals_mis(case, "wavelet", "wv", _half_blocked, 2, levels=case.levels)
    if case in CASES[:len(MATERIALS)]:
        _assert_point_estimate_equals_mis(case, "wavelet", "wv0", _half_blocked, 2, levels=case.levels,
                                          control_variate=False)


@pytest.mark.slow
@pytest.mark.parametrize("four_slot_case", CASES[:len(MATERIALS)], ids=CASE_IDS[:len(MATERIALS)])
def test_wavelet_four_slots_unbiased_under_occlusion(four_slot_case):
    """Four directions per sample (slots=4, two more shadow rays): E[offset + the four values
    times their visibilities] equals mis's under the same occluder, on the first map's cases
    (every material; each case is another kernel build)."""
    c = four_slot_case
    _assert_point_estimate_equals_mis(c, "wavelet", "w4", _half_blocked, 2, levels=c.levels, slots=4)


@pytest.mark.slow
def test_wavelet_two_candidates_estimate_equals_mis_at_a_point(case):
    """The same with 2 candidates, one product and one BSDF (an odd split, 9 + 8, is compared
    with the numpy twin in test_kernel_matches_numpy_with_candidates)."""
    _assert_point_estimate_equals_mis(case, "wavelet", "w2", levels=case.levels, candidates=2)


def test_mis_comp_estimate_equals_mis_at_a_point(case):
    """E[mis_comp] = E[mis] at one shading point: MIS compensation zeroes the light pdf below the
    map's mean luminance and the BSDF sample must cover exactly that part (the adversarial maps
    include one lit texel and black ones)."""
    _assert_point_estimate_equals_mis(case, "mis_comp", "c")


@pytest.mark.parametrize("mat_id", ["lambert", "phong20", "ggx0.3"])
def test_wavelet_estimate_equals_mis_under_a_1e30_texel(mat_id):
    """A sun of 1e30 over a sky of 1: the product walk's conditionals once multiplied two
    importance sums, which overflowed float32 past ~1e19, so the walk lost the sun (the image
    1000x too dark from 1e24 on, while mis and the numpy twin were right). Same test as above."""
    px = np.ones((32, 64, 3), np.float32)
    px[9, 24] = 1e30
    scene = _scene(Environment(px), [MATERIALS[mat_id]])
    n, wo = np.array([0.0, 1.0, 0.0]), np.array([0.3, 0.9, 0.1]) / np.linalg.norm([0.3, 0.9, 0.1])
    a = _kernel_estimates(scene, "wavelet", n, wo, N_POINT, seed_of("sun1e30-w/" + mat_id))
    b = _kernel_estimates(scene, "mis", n, wo, N_POINT, seed_of("sun1e30-m/" + mat_id))
    assert np.all(np.isfinite(a)) and np.all(a >= 0)
    ma, mb = a.mean(0), b.mean(0)
    se = np.sqrt(a.var(0, ddof=1) / len(a) + b.var(0, ddof=1) / len(b))
    z = stats.norm.isf(sidak_alpha(1e-3, 3 * 3) / 2)
    assert np.all(np.abs(ma - mb) <= z * se), f"wavelet {ma} vs mis {mb}, z = {np.abs(ma - mb) / se}"


#: maps that ship with wavlight (wavlight.data); black_by_lamps is st_fagans_interior_512 with the
#: black texels of the small Debevec probes (next to its lamps, a bottom band:
#: wavlight.evaluation.stability.black_around_lamps)
REAL_MAPS = ("rooitou_park_512", "st_fagans_interior_512", "black_by_lamps")
# three spheres side by side, one per material, under the scene-format document's camera
REAL_MATERIALS = {"ggx": dict(type="ggx", albedo=[0.95, 0.8, 0.6], roughness=0.1),
                  "phong": dict(type="phong", albedo=[0.8, 0.85, 0.9], exponent=100.0),
                  "lambert": dict(type="lambert", albedo=[0.7, 0.6, 0.5])}
WAVELET_SPP, MIS_SPP = 1024, 4096


@pytest.fixture(scope="module")
def real_scenes(tmp_path_factory):
    from wavlight.evaluation.stability import black_around_lamps

    folder = tmp_path_factory.mktemp("real")
    write_env(folder, "black_by_lamps.exr",
              black_around_lamps(read_image(str(data.path("st_fagans_interior_512")))))
    loaded = {}

    def get(map_name, floor=False):
        """The three spheres under map_name; with ``floor``, standing on a lambert floor (their
        contact shadows, and the sky they hide from it and from each other)."""
        if (map_name, floor) in loaded:
            return loaded[map_name, floor]
        env = str(folder / "black_by_lamps.exr") if map_name == "black_by_lamps" else f"data:{map_name}"
        sub = folder / (map_name + ("-floor" if floor else ""))
        sub.mkdir()
        objects = [dict(shape="sphere", center=[x, 0.5, 0.0], radius=0.75, subdivisions=4, material=m)
                   for x, m in zip((-1.7, 0.0, 1.7), REAL_MATERIALS)]
        materials = dict(REAL_MATERIALS)
        if floor:
            objects.append(dict(shape="quad", center=[0.0, -0.25, 0.0], normal=[0.0, 1.0, 0.0], size=8.0,
                                material="floor"))
            materials["floor"] = dict(type="lambert", albedo=[0.5, 0.5, 0.5])
        loaded[map_name, floor] = load(
            sub, render=dict(width=36, height=12 if not floor else 18, spp=16, seed=1),
            camera=dict(eye=[0.0, 1.0, 4.0], target=[0.0, 0.5 if not floor else 0.2, 0.0], up=[0.0, 1.0, 0.0],
                        fov_y=35.0 if not floor else 45.0),
            environment=dict(file=env), objects=objects, materials=materials)
        return loaded[map_name, floor]

    return get


_MIS_RENDERS = {}


@pytest.mark.slow
@pytest.mark.parametrize("strategy", ["wavelet", "wavelet-pair", "mis_comp"])
@pytest.mark.parametrize("map_name", REAL_MAPS)
def test_render_equals_mis_under_real_maps(real_scenes, map_name, strategy):
    """Three spheres (ggx alpha 0.1, phong n = 100, lambert) under a real light probe: the
    wavelet image (the default resampling estimator and the MIS pair, wavelet_candidates = 0), and the
    mis_comp image, equals the mis image within their combined standard error (render_full's
    per-pixel stderr), pixel by pixel (two-sided, Student t, Bonferroni over the pixel
    channels at 1e-5, scenes_util.z_threshold) and on the image mean per channel (Bonferroni
    over the 3 channels). Different seeds. black_by_lamps has black texels next to its lamps.

    Sample counts: mis is heavy-tailed on the spheres' rims (grazing views of the glossy lobes
    under small bright lamps: at one rim pixel of a phong sphere under st_fagans_interior
    0.1 % of its samples carry 15 % of the mean), so at low spp its per-pixel stderr is often
    an underestimate and a t-test against it fails without any bias (measured: 4 % of seeds
    fail that one pixel at 512 + 512 spp). With mis at 4096 spp (and wavelet, whose tail there
    is ~15x lighter, at 1024) the bootstrap rate of such false alarms is below 1/4000.
    """
    scene = real_scenes(map_name)
    options = {"wavelet_candidates": 0} if strategy == "wavelet-pair" else {}   # the MIS pair
    strategy = strategy.split("-")[0]
    a = wavlight.render_full(scene, spp=WAVELET_SPP, strategy=strategy, seed=101, **options)
    assert a.stats["strategy"] == strategy
    assert ("product_levels" in a.stats) == (strategy == "wavelet")
    _assert_equals_mis(a, _mis_render(scene, map_name), strategy)


@pytest.mark.slow
@pytest.mark.parametrize("map_name", REAL_MAPS)
def test_render_equals_mis_with_shadows_under_real_maps(real_scenes, map_name):
    """The same three spheres standing on a lambert floor: shadows everywhere below them, so
    the wavelet strategy chooses its shadowed budget from the scene (8 candidates, 4 slots,
    strategies.AUTO_BUDGET) and its control variate subtracts blocked directions. Its image
    equals the mis image within their combined standard error, tested as above (the seeds are
    fixed; the false-alarm rate quoted above was measured on the spheres alone, and the floor
    adds only lambert pixels, whose mis estimates have light tails). A bias of a few percent
    in the shadowed budget's estimator fails it (tried: 0.3 times the fourth slot's value
    added to every sample, visible or not)."""
    scene = real_scenes(map_name, floor=True)
    a = wavlight.render_full(scene, spp=WAVELET_SPP, strategy="wavelet", seed=103)
    assert a.stats["visibility_variance"] >= strategies.SHADOWED_VARIANCE
    assert (a.stats["wavelet_candidates"], a.stats["wavelet_slots"]) == strategies.AUTO_BUDGET["shadowed"]
    _assert_equals_mis(a, _mis_render(scene, map_name + "-floor"), "wavelet")


def _mis_render(scene, key):
    if key not in _MIS_RENDERS:
        _MIS_RENDERS[key] = wavlight.render_full(scene, spp=MIS_SPP, strategy="mis", seed=202)
    return _MIS_RENDERS[key]


def _assert_equals_mis(a, b, strategy):
    """Image a equals mis image b within their combined standard error: per pixel channel
    (Bonferroni over them at 1e-5) and on the image mean per channel."""
    ia, ib = a.image.astype(np.float64), b.image.astype(np.float64)
    sa, sb = a.stderr.astype(np.float64), b.stderr.astype(np.float64)
    assert np.all(np.isfinite(ia)) and np.all(np.isfinite(sa))
    se = np.sqrt(sa ** 2 + sb ** 2)
    diff = ia - ib
    fixed = 1e-6 + 2e-6 * np.abs(ib)
    z = z_threshold(diff.size, WAVELET_SPP)
    bad = np.abs(diff) > z * se + fixed
    assert not bad.any(), (f"{bad.sum()} of {diff.size} pixel channels differ beyond {z:.2f} combined stderr, "
                           f"e.g. at {np.argwhere(bad)[:3].tolist()}: {strategy} {ia[bad][:3]} mis {ib[bad][:3]} "
                           f"se {se[bad][:3]}")
    m = ia.shape[0] * ia.shape[1]
    d = diff.reshape(-1, 3).mean(0)
    se_mean = np.sqrt((se ** 2).reshape(-1, 3).sum(0)) / m
    z3 = z_threshold(3, WAVELET_SPP * m)
    assert np.all(np.abs(d) <= z3 * se_mean + fixed.mean()), \
        f"image means differ: {strategy} {ia.mean((0, 1))} mis {ib.mean((0, 1))} (se {se_mean}, z {np.abs(d) / se_mean})"


@pytest.fixture(scope="module")
def furnace_scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("furnace")
    env = write_env(d, "white.exr", np.ones((64, 128, 3)))
    albedo = [0.7, 0.45, 0.2]
    scene = load(d, render=dict(width=16, height=16, spp=64, seed=3),
                 camera=dict(eye=[0.3, 0.4, 3.5], target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0], fov_y=40.0),
                 environment=dict(file=env),
                 objects=[dict(shape="sphere", center=[0.0, 0.0, 0.0], radius=1.0, subdivisions=5,
                               material="white")],
                 materials={"white": dict(type="lambert", albedo=albedo)})
    # pixels whose four corner rays all hit the icosphere's inscribed sphere: entirely on the
    # object; pixels whose corner rays all miss the circumscribed sphere by a margin: background
    v = scene.vertices.astype(np.float64)
    f = scene.faces
    nrm = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    r_in = float(np.abs(np.einsum("ij,ij->i", nrm, v[f[:, 0]])).min())
    cam = camera_of(scene)
    corners = cam.pixel_rays(1)
    inner = np.all(np.isfinite(ray_sphere(cam.eye, corners, np.zeros(3), r_in)), axis=-1)
    background = np.all(~np.isfinite(ray_sphere(cam.eye, corners, np.zeros(3), 1.02)), axis=-1)
    assert inner.sum() > 40 and background.sum() > 20
    return scene, np.array(albedo), inner, background


@pytest.mark.slow
@pytest.mark.parametrize("levels, candidates", [(None, None), (0, None), (1, None), (4, None), (11, None),
                                                (None, 0), (0, 0), (None, 2), (None, 32)])
def test_wavelet_white_furnace_every_depth(furnace_scene, levels, candidates):
    """A lambert sphere under a constant environment of 1 shows its albedo exactly in
    expectation, whatever the product depth (None: the default, 3 for lambert; 0: light
    sampling; 12: clamped to the light tree's depth) and the resampling candidates (None:
    the default; 0: the MIS pair); the background is exactly 1."""
    scene, albedo, inner, background = furnace_scene
    r = wavlight.render_full(scene, spp=64, strategy="wavelet", seed=7, wavelet_levels=levels,
                             wavelet_candidates=candidates)
    # (a lone sphere: nothing in shadow, so unset candidates come from AUTO_BUDGET's unshadowed pair)
    assert r.stats["visibility_variance"] == (None if candidates == 0 else 0.0)
    assert r.stats["wavelet_candidates"] == (strategies.AUTO_BUDGET["unshadowed"][0] if candidates is None else candidates)
    side = int(r.stats["light_tree"].split("x")[0])
    expect = product.product_levels(0.0, side.bit_length() - 1, levels)
    assert _levels_by_name(r.stats, ["white"]) == [expect]
    assert np.all(r.image[background] == 1.0) and np.all(r.stderr[background] == 0.0)
    check_estimates(r.image, r.stderr, albedo, inner, 64, label=f"furnace/wavelet P={levels} M={candidates}")


# ============================================================================= 5. command line
def _command():
    exe = Path(sys.executable).with_name("wavlight")
    return [str(exe)] if exe.is_file() else [sys.executable, "-m", "cli.main"]


def test_cli_wavelet_strategy_and_levels(tmp_path):
    """`wavlight render --strategy wavelet --wavelet-levels 2 --json` renders and reports the
    product depth of every material of the default scene: 2 for all three (light trees have
    at least 2 levels, so the override is not clamped); and the budget chosen from the
    scene's shadows (two spheres on a floor: shadowed, AUTO_BUDGET's second pair)."""
    out, stats_ = _render_json(tmp_path, REPO / "scenes" / "default.toml", "--wavelet-levels", "2", "--spp", "2",
                               "--width", "16", "--height", "12")
    assert stats_["strategy"] == "wavelet" and stats_["spp"] == 2
    assert "product_levels" in stats_, sorted(stats_)
    levels = stats_["product_levels"]
    values = list(levels.values()) if isinstance(levels, dict) else list(levels)
    assert values == [2, 2, 2], levels
    assert stats_["visibility_variance"] > strategies.SHADOWED_VARIANCE, stats_
    assert (stats_["wavelet_candidates"], stats_["wavelet_slots"]) == strategies.AUTO_BUDGET["shadowed"], stats_
    # the memory used: the light trees (reported on their own too) and the per-material tables
    assert stats_["memory_bytes"] == stats_["light_tree_bytes"] + 8 * len(values), stats_
    img = read_image(str(out))
    assert img.shape[:2] == (12, 16) and np.all(np.isfinite(img)) and img.max() > 0


def _render_json(tmp_path, scene, *flags):
    """`wavlight render SCENE -o tmp_path/w.pfm --strategy wavelet FLAGS --json --quiet` in a
    subprocess: the output's path and the printed statistics (exit code 0 asserted)."""
    out = tmp_path / "w.pfm"
    p = subprocess.run(_command() + ["render", str(scene), "-o", str(out), "--strategy", "wavelet", *flags,
                                     "--json", "--quiet"],
                       capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert p.returncode == 0, f"exit {p.returncode}\n{p.stdout}\n{p.stderr}"
    return out, json.loads(p.stdout.strip().splitlines()[-1])


def _default_scene_with(tmp_path, render_keys: str) -> Path:
    """scenes/default.toml with extra lines in its [render] table, written to tmp_path."""
    text = (REPO / "scenes" / "default.toml").read_text()
    assert "[render]\n" in text
    path = tmp_path / "keys.toml"
    path.write_text(text.replace("[render]\n", "[render]\n" + render_keys, 1))
    return path


def test_scene_keys_choose_the_trees_and_flags_override_them(tmp_path):
    """[render] light_levels and wavelet_levels in a scene file set the light tree's depth and
    every material's product depth (reported with the coefficients they keep);
    --light-levels and --wavelet-levels on the command line win over the keys."""
    path = _default_scene_with(tmp_path, "light_levels = 3\nwavelet_levels = 1\n")
    st = wavlight.render_full(str(path), spp=1, strategy="wavelet", width=8, height=6).stats
    assert st["light_tree"] == "8x8" and st["light_coefficients_kept"] == 64
    env = wavlight.load_scene(str(path)).environment
    assert st["light_tree_tv"] == round(env.tree_tv(3), 5) and st["light_tree_tv"] > 0.01   # (set by hand)
    assert list(st["product_levels"].values()) == [1, 1, 1]
    assert list(st["product_coefficients_per_walk"].values()) == [16, 16, 16]   # level 0's look-ahead
    _, st = _render_json(tmp_path, path, "--light-levels", "2", "--wavelet-levels", "2", "--spp", "1",
                         "--width", "8", "--height", "6")
    assert st["light_tree"] == "4x4" and st["light_coefficients_kept"] == 16
    assert list(st["product_levels"].values()) == [2, 2, 2]


def _kernel_float_literals(name):
    """The float literals of the __constant array `name` in kernels/product.h."""
    import re
    from wavlight import cl
    text = cl.kernel_source("product.h")
    body = re.search(name + r"\[16\] = \{([^}]*)\}", text).group(1)
    return np.array([float.fromhex(v.strip().rstrip("f")) if "0x" in v else float(v.strip().rstrip("f"))
                     for v in body.split(",")])


def test_angle_step_constants_are_sin_and_cos_of_pi_over_powers_of_two():
    """kernels/product.h SIN_PI_2K / COS_PI_2K hold sin and cos of pi / 2^k rounded to float32
    (pi and pi / 2 exactly), and the numpy twin's tables are the same floats."""
    k = np.arange(16)
    got_s, got_c = _kernel_float_literals("SIN_PI_2K"), _kernel_float_literals("COS_PI_2K")
    np.testing.assert_allclose(got_s, np.sin(np.pi / 2.0 ** k), rtol=2 ** -24, atol=1e-15)
    np.testing.assert_allclose(got_c, np.cos(np.pi / 2.0 ** k), rtol=2 ** -24, atol=1e-15)
    np.testing.assert_array_equal(product.SIN_PI_2K, got_s.astype(np.float32))
    np.testing.assert_array_equal(product.COS_PI_2K, got_c.astype(np.float32))


def test_node_centre_angles_kernel_matches_numpy_and_exact():
    """kernels/product.h child_angles, followed down random paths to levels 1..13, against its numpy
    twin product.centre_angles and against the exact sin and cos of phi = 2 pi (x + 0.5) / 2^L,
    theta = pi (y + 0.5) / 2^L: the float32 recurrence stays within a few ulp per level."""
    import pyopencl as pcl
    from wavlight import cl
    src = cl.kernel_source("product.h") + """
    __kernel void centre_angles_test(__global const uint *xs, __global const uint *ys, const int level,
                                     const uint count, __global float *out)
    {
        const uint base = (uint)get_global_id(0) * LANES;
        const uintv x = vloadv(0, xs + base), y = vloadv(0, ys + base);
        NodeAngles a = root_angles();
        for (int l = 0; l < level; ++l) {
            const uint sh = (uint)(level - 1 - l);
            a = child_angles(&a, l, as_intv((x >> sh) & 1u) != 0, as_intv((y >> sh) & 1u) != 0);
        }
        vstorev(a.sp, 0, out + base);
        vstorev(a.cp, 0, out + count + base);
        vstorev(a.st, 0, out + 2 * count + base);
        vstorev(a.ct, 0, out + 3 * count + base);
    }"""
    inline = int(cl.inline_builtins(cl.runtime().device))   # as cl.program builds the walks
    prog = pcl.Program(cl.runtime().context, src).build(options=[f"-DLANES={cl.LANES}", f"-DINLINE_BUILTINS={inline}"])
    q = cl.thread_queue()
    rng = np.random.default_rng(5)
    count = 64 * cl.LANES
    for level in range(1, 14):
        side = 1 << level
        x = rng.integers(0, side, count).astype(np.uint32)
        y = rng.integers(0, side, count).astype(np.uint32)
        x[:4], y[:4] = [0, side - 1, 0, side - 1], [0, 0, side - 1, side - 1]   # the corners
        out = cl.empty(16 * count)
        pcl.Kernel(prog, "centre_angles_test")(q, (count // cl.LANES,), None, cl.to_device(x), cl.to_device(y),
                                                np.int32(level), np.uint32(count), out)
        got = cl.read(out, (4, count), np.float32, q).astype(np.float64)
        twin = np.array(product.centre_angles(x, y, level), np.float64)
        phi, theta = 2 * np.pi * (x + 0.5) / side, np.pi * (y + 0.5) / side
        exact = np.array([np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta)])
        tol = 4e-7 * (level + 1)
        np.testing.assert_allclose(got, twin, rtol=0, atol=tol, err_msg=f"level {level}")
        np.testing.assert_allclose(twin, exact, rtol=0, atol=tol, err_msg=f"level {level}")
        np.testing.assert_allclose(got, exact, rtol=0, atol=tol, err_msg=f"level {level}")
