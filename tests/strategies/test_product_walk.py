"""The product walk at the edges of its input and on stratified input (paper sec. 4.3), for the
renderer's walk (kernels/product.cl ``product_sample_points``) and its
numpy twin (``wavlight.strategies.product.sample_reference``); the light walk's own tests of the same
properties are in test_kernels.py.

Light trees with zero-mass nodes next to lit ones (black sky, a lit band, single bright
texels, a checker of black and lit blocks), so that a sample pushed across its leaf's edge by
rounding lands where the product has no mass; every lobe model (lambert, phong 200, ggx 0.05,
ggx 0.2 with the half-vector model) at full product depth.
"""
from __future__ import annotations

import numpy as np
import pytest

from scenes_util import random_normals_views
from walks import product_kernel_samples
from wavlight import bsdfs
from wavlight.strategies import product
from wavlight.haar.tree import HaarTree
from wavlight.envmap import Environment

# u at and next to 0, 1/2 and 1 - 2^-24 (the largest float32 below 1), 1.0 itself (clamped), and
# runs of float32 steps below 1 in each coordinate
EDGE_U = np.array([[a, b] for a in (0.0, 0.5, 1 - 2 ** -24, 1.0) for b in (0.0, 0.5, 1 - 2 ** -24, 1.0)]
                  + [[1 - k * 2 ** -24, 0.3] for k in range(1, 33)]
                  + [[0.3, 1 - k * 2 ** -24] for k in range(1, 33)]
                  + [[1 - k * 2 ** -24, 1 - k * 2 ** -24] for k in range(1, 33)], np.float32)

MATERIALS = [(bsdfs.LAMBERT, 0.0), (bsdfs.PHONG, 200.0), (bsdfs.GGX, 0.05), (bsdfs.GGX, 0.2)]


def _map(kind: str) -> np.ndarray:
    """A 64 x 32 map whose luminance has zero-mass regions next to lit ones."""
    px = np.zeros((32, 64, 3), np.float32)
    rng = np.random.default_rng(3)
    if kind == "band":   # a lit band above the horizon and three single bright texels below it
        px[6:12, 8:40] = rng.uniform(0.5, 2.0, (6, 32, 1))
        for row, col in ((20, 5), (25, 33), (31, 63)):
            px[row, col] = 500.0
    else:                # 4 x 4-texel blocks, lit and black in a checker
        block = (np.add.outer(np.arange(32) // 4, np.arange(64) // 4) % 2).astype(np.float32)
        px[:] = (block * rng.uniform(0.2, 3.0, (32, 64)))[..., None]
    return px


def _walk_setup(map_kind: str, n_levels: int, count: int, seed: int):
    """Environment, light tree, shading points (random normals and views, each material in turn)
    and the per-material tables, at full product depth."""
    env = Environment(_map(map_kind), 1.0, 25.0)
    tree = HaarTree(env.luminance_square(n_levels))
    rng = np.random.default_rng(seed)
    nrm, wo = random_normals_views(rng, count)
    material = np.arange(count) % len(MATERIALS)
    mat_shape = np.array([product.lobe_shape(k, p) for k, p in MATERIALS])
    mat_kappa = np.array([product.lobe_kappa(k, p) for k, p in MATERIALS])
    mat_depth = np.full(len(MATERIALS), n_levels)
    shape = mat_shape[material]
    mirror = 2 * np.einsum("ij,ij->i", wo, nrm)[:, None] * nrm - wo
    axis = np.where((shape == bsdfs.LAMBERT)[:, None], nrm, mirror)
    return env, tree, nrm, wo, material, (mat_kappa, mat_depth, mat_shape), axis


def _reference_args(tree, n_levels, env, axis, nrm, tables, material):
    mat_kappa, mat_depth, mat_shape = tables
    return (tree.nodes(), n_levels, env, axis, nrm, mat_kappa[material], mat_depth[material], mat_shape[material])


def _kernel(tree, env, n_levels, nrm, wo, material, tables, u):
    mat_kappa, mat_depth, mat_shape = tables
    shapes = int(np.bitwise_or.reduce(1 << mat_shape))
    return product_kernel_samples(tree, env, n_levels, nrm, wo, material, mat_kappa, mat_depth, mat_shape,
                                  np.zeros(len(mat_shape), np.int32), u, shapes)


@pytest.mark.parametrize("map_kind", ["band", "checker"])
def test_product_walk_u_at_and_near_one(map_kind):
    """u at 0, 1 - 2^-24, 1.0 and the float32 steps just below 1: every sample, of the kernel and
    of the twin, lies in [0, 1)^2 with a finite pdf > 0, and in a leaf where the product has that
    pdf: pdf() at the returned point equals the returned pdf (the twin to rtol 1e-6; the kernel,
    float32 against the float64 pdf, to the 2e-2 of the kernel-against-twin test). A point
    pushed by rounding across its leaf's far edge would land in a zero-mass leaf (pdf() = 0)."""
    n_levels = 5
    per = 64   # shading points, each with every edge u
    env, tree, nrm, wo, material, tables, axis = _walk_setup(map_kind, n_levels, per, seed=21)
    rep = np.repeat(np.arange(per), len(EDGE_U))
    u = np.tile(EDGE_U, (per, 1))
    args = _reference_args(tree, n_levels, env, axis[rep], nrm[rep], tables, material[rep])
    uv_r, pdf_r = product.sample_reference(*args, u.astype(np.float64))
    uv_k, pdf_k = _kernel(tree, env, n_levels, nrm[rep], wo[rep], material[rep], tables, u)
    for name, uv, pdf, rtol in (("numpy twin", uv_r, pdf_r, 1e-6), ("kernel", uv_k, pdf_k, 2e-2)):
        assert np.all(np.isfinite(uv)) and np.all(np.isfinite(pdf)), name
        inside = np.all((uv >= 0) & (uv < 1), axis=1)
        assert inside.all(), f"{name}: {(~inside).sum()} points outside [0, 1)^2, e.g. u = {u[~inside][:3].tolist()}"
        assert np.all(pdf > 0), f"{name}: {(~(pdf > 0)).sum()} samples with pdf <= 0"
        again = product.pdf_reference(*args, uv.astype(np.float64))
        ok = np.isclose(again, pdf, rtol=rtol, atol=0)
        assert ok.all(), (f"{name}: {(~ok).sum()} of {len(ok)} samples: returned pdf {pdf[~ok][:3].tolist()}, "
                          f"pdf() there {again[~ok][:3].tolist()}, u = {u[~ok][:3].tolist()}")


@pytest.mark.slow
@pytest.mark.parametrize("map_kind", ["band", "checker"])
@pytest.mark.parametrize("mat", range(len(MATERIALS)), ids=["lambert", "phong200", "ggx0.05", "ggx0.2"])
def test_product_walk_leaf_preimages_are_rectangles(map_kind, mat):
    """Stratified inputs stay stratified: for one shading point the walk maps an axis-aligned
    rectangle of u onto each leaf, of area the leaf's probability (as the light walk: at each
    level the row is chosen by u.y and the column by u.x, with monotone rescalings; the product
    only changes the children's weights). Check, kernel and twin: on a regular 256 x 256 grid
    of u (cell centres) the grid points reaching each leaf fill a full W x H block of grid
    indices, and (W - 1)(H - 1) <= 256^2 p_leaf <= (W + 1)(H + 1) (a rectangle of side s holds
    256 s +- 1 centres per axis). So every stratum inside a preimage sends its point there."""
    n_levels, k = 4, 256
    env, tree, nrm, wo, material, tables, axis = _walk_setup(map_kind, n_levels, 8, seed=30 + mat)
    i = mat   # the first shading point of this material (materials cycle over the points)
    g = (np.arange(k) + 0.5) / k
    gx, gy = np.meshgrid(g, g, indexing="ij")   # grid index (a, b) <-> u = (g[a], g[b])
    u = np.stack([gx.ravel(), gy.ravel()], 1)
    one = np.zeros(len(u), np.int64) + i
    args = _reference_args(tree, n_levels, env, axis[one], nrm[one], tables, material[one])
    side = 1 << n_levels
    c = (np.arange(side) + 0.5) / side
    centres = np.stack(np.meshgrid(c, c, indexing="ij"), -1).reshape(-1, 2)   # leaf (x, y) centres
    cargs = _reference_args(tree, n_levels, env, axis[one[:len(centres)]], nrm[one[:len(centres)]], tables,
                            material[one[:len(centres)]])
    p_leaf = product.pdf_reference(*cargs, centres).reshape(side, side) / side ** 2   # [x, y]
    assert abs(p_leaf.sum() - 1) < 1e-5
    uv_r, _ = product.sample_reference(*args, u)
    uv_k, _ = _kernel(tree, env, n_levels, nrm[one], wo[one], material[one], tables, u.astype(np.float32))
    for name, uv in (("numpy twin", uv_r), ("kernel", uv_k)):
        lx, ly = np.floor(np.asarray(uv, np.float64) * side).astype(int).T
        leaf = (lx * side + ly).reshape(k, k)
        for lid in np.unique(leaf):
            a, b = np.nonzero(leaf == lid)
            w, h = a.max() - a.min() + 1, b.max() - b.min() + 1
            p = p_leaf.ravel()[lid]
            assert p > 0, f"{name}: grid points in leaf {lid}, of zero probability"
            assert len(a) == w * h, f"{name}: the preimage of leaf {lid} is not a rectangle"
            assert (w - 1) * (h - 1) <= k * k * p * (1 + 1e-4) + 1e-9, f"{name}: leaf {lid} {w} x {h}, p {p}"
            assert k * k * p <= (w + 1) * (h + 1) * (1 + 1e-4), f"{name}: leaf {lid} {w} x {h}, p {p}"
