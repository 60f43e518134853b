"""OpenCL sampling-tree kernels against their numpy twins and against the maths.

kernels/tree.cl (tree_reduce) and kernels/warp.cl (warp_sample, warp_pdf), driven by
wavlight.haar.tree.HaarTree, are compared with build_reference, sample_reference
and pdf_reference, and checked for the properties the warp promises: samples never
in zero-mass leaves, u in [0, 1] maps into [0, 1)^2, pdf 0 (not NaN) for an all-zero
tree, stratification preserved, the pdf integrates to one, and the samples follow
the pdf (chi-square, tests/support/chi2.py, Sidak-corrected over this file).
"""
from __future__ import annotations

import functools

import numpy as np
import pytest
from scipy import stats

from chi2 import SquareGrid, chi2_test
from wavlight.haar.tree import (ONE_MINUS_EPS, TREE_ORIGIN, HaarTree, build_reference, device_order,
                                    host_order, level_offset, morton_index, pdf_reference, sample_reference,
                                    tree_size)

U32 = 2.0 ** -24  # unit roundoff of float32


# ----------------------------------------------------------------------------- test trees
def _zeros_tree(seed=3):
    """32 x 32 with zero leaves (40 %), one zero quadrant of the root and one zero level-2 node."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(0.05, 1.0, (32, 32))
    a[rng.random((32, 32)) < 0.4] = 0
    a[:16, 16:] = 0  # level-1 node (x=1, y=0): rows 0-15, columns 16-31
    a[16:24, 0:8] = 0  # level-2 node (x=0, y=2)
    return a


def _checker(side=16):
    """Mass only in leaves of even row and even column: every such leaf's right and lower
    neighbours are empty, so a point that leaves its leaf by rounding lands in zero mass."""
    a = np.zeros((side, side))
    a[0::2, 0::2] = np.random.default_rng(4).uniform(0.5, 2.0, (side // 2, side // 2))
    return a


def _peaky(seed=5):
    rng = np.random.default_rng(seed)
    a = rng.uniform(0, 1e-3, (64, 64))
    a[37, 22] = 100.0  # 98 % of the mass in one leaf of 4096
    return a


TREES = {
    "n0": lambda: np.array([[2.5]]),
    "n1": lambda: np.array([[1.0, 2.0], [3.0, 4.0]]),
    "n3-random": lambda: np.random.default_rng(1).uniform(0.1, 1.0, (8, 8)),
    "n5-lognormal": lambda: np.exp(np.random.default_rng(2).normal(0, 2, (32, 32))),
    "n5-zeros": _zeros_tree,
    "n4-checker": _checker,
    "n6-peaky": _peaky,
    "n7-random": lambda: np.random.default_rng(6).random((128, 128)),
    "n10-random": lambda: np.random.default_rng(7).random((1024, 1024)),
}
CHI2_TREES = [k for k in TREES if k != "n10-random"]  # n10 is only compared with the reference
N_BATCH_CHI2 = 4
N_CHI2 = len(CHI2_TREES) + N_BATCH_CHI2


@functools.lru_cache(maxsize=None)
def leaves_of(tree_id):
    return np.asarray(TREES[tree_id](), np.float32)


@functools.lru_cache(maxsize=None)
def tree_of(tree_id) -> HaarTree:
    return HaarTree(leaves_of(tree_id))


def leaf_index(uv, side):
    """(column, row) of the leaf holding each point, as warp_pdf finds it."""
    ix = np.clip(np.floor(uv[:, 0] * side).astype(np.int64), 0, side - 1)
    iy = np.clip(np.floor(uv[:, 1] * side).astype(np.int64), 0, side - 1)
    return ix, iy


# u at the edges of [0, 1]: 0, 1/2, the largest float32 below 1, 1 itself, and the 64
# floats just below 1 paired with 0.3.
EDGE_U = np.array([[a, b] for a in (0.0, 0.5, 1 - 2 ** -24, 1.0) for b in (0.0, 0.5, 1 - 2 ** -24, 1.0)]
                  + [[1 - k * 2 ** -24, 0.3] for k in range(1, 65)]
                  + [[0.3, 1 - k * 2 ** -24] for k in range(1, 65)], np.float32)


def random_u(n, seed):
    return np.random.default_rng(seed).random((n, 2)).astype(np.float32)


# ============================================================================= build
@pytest.mark.parametrize("tree_id", list(TREES))
def test_build_matches_reference(tree_id):
    """tree_reduce == build_reference, and both are the exact box sums within float32 error.

    Each parent is ((a + b) + (c + d)) of non-negative floats: 2 roundings deep, so a node
    at level l carries relative error <= 2 (n - l) u32 (1 + o(1)) against the exact sum of
    its leaves (computed in float64). Kernel and reference add in the same order, so they
    agree to within twice that; in practice they are bitwise equal.
    """
    leaves = leaves_of(tree_id)
    t = tree_of(tree_id)
    n = t.n_levels
    got = t.nodes()[0]
    ref = build_reference(leaves)[0]
    assert got.shape == (tree_size(n),)
    bound = 2.05 * max(n, 1) * U32
    np.testing.assert_allclose(got, ref, rtol=2 * bound, atol=0)
    # exact sums of the leaves, level by level, in float64
    level = leaves.astype(np.float64)
    for l in range(n, -1, -1):
        np.testing.assert_allclose(got[level_offset(l):level_offset(l + 1)], level.ravel(), rtol=bound, atol=0,
                                   err_msg=f"level {l}")
        if l:
            level = level.reshape(1 << (l - 1), 2, 1 << (l - 1), 2).sum(axis=(1, 3))
    assert t.integral[0] == got[0]


def test_build_batched():
    """Several trees in one buffer: each equals its own single build and the reference."""
    rng = np.random.default_rng(11)
    leaves = rng.random((6, 16, 16)).astype(np.float32)
    leaves[2] = 0
    leaves[4, :8] = 0
    t = HaarTree(leaves)
    got = t.nodes()
    assert got.shape == (6, tree_size(4))
    np.testing.assert_allclose(got, build_reference(leaves), rtol=4 * 4 * U32, atol=0)
    for k in range(6):
        np.testing.assert_array_equal(got[k], HaarTree(leaves[k]).nodes()[0])
    np.testing.assert_array_equal(t.integral, got[:, 0])


# ----------------------------------------------------------------------------- device layout
def test_device_order_puts_a_nodes_children_together():
    """On the device (Morton levels, kernels/common.h) the children of node k of level l are
    nodes 4k .. 4k + 3 of level l + 1, top-left, top-right, bottom-left, bottom-right; host_order
    undoes device_order; the HaarTree buffer holds device_order(nodes())."""
    n = 5
    leaves = np.random.default_rng(21).random((2, 1 << n, 1 << n)).astype(np.float32)
    host = build_reference(leaves)
    dev = device_order(host, n)
    np.testing.assert_array_equal(host_order(dev, n), host)
    for l in range(n):
        side = 1 << l
        y, x = np.divmod(np.arange(side * side), side)
        k = morton_index(x, y)   # each host node's index in its device level
        parent = dev[:, level_offset(l) + k]
        kids = [dev[:, level_offset(l + 1) + 4 * k + c] for c in range(4)]
        host_kids = [host[:, level_offset(l + 1) + (2 * y + dy) * 2 * side + 2 * x + dx]
                     for dy in (0, 1) for dx in (0, 1)]
        for got, want in zip(kids, host_kids):
            np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(parent, host[:, level_offset(l):level_offset(l + 1)])
    from wavlight import cl
    built = HaarTree(leaves)
    raw = cl.read(built.buffer, (2, built.stride), np.float32)   # as tree_load_leaves and tree_reduce built it
    # node 0 at TREE_ORIGIN, trees a multiple of 16 floats apart (every level from 2 on line-aligned)
    assert built.stride % 16 == 0 and built.stride >= TREE_ORIGIN + tree_size(n)
    assert all((TREE_ORIGIN + level_offset(l)) % 16 == 0 for l in range(2, n + 1))
    np.testing.assert_allclose(raw[:, TREE_ORIGIN:TREE_ORIGIN + tree_size(n)], dev, rtol=4 * n * U32, atol=0)
    assert morton_index(5, 3).item() == 0b011011   # x = 101, y = 011 interleaved: y2 x2 y1 x1 y0 x0


# ============================================================================= paired steps
@pytest.mark.slow
@pytest.mark.parametrize("pair_level, barriers", [(3, 0), (6, 1)], ids=["from3-inline", "from6-barriers"])
def test_paired_steps_are_bit_identical(pair_level, barriers):
    """kernels/warp.h paired_step (two levels per load, from level pair_level or the next of
    the leaves' parity on) against the walks built without pairs (PAIR_LEVEL past the
    tree): the light walk (warp.cl) and the product walk below its product levels
    (product.cl, depths 3 and 4, so that pairs start at and after the product levels)
    return the same points and densities bit for bit, on a 2^10 tree with zero masses
    among its leaves; as the renderer walks (without barriers) and as the stand-alone
    kernels do. (Two cases, not four: each builds six programs, cold in CI.)"""
    from wavlight import bsdfs, cl
    from wavlight.strategies import product

    rng = np.random.default_rng(pair_level)
    n = 10
    leaves = rng.random((1 << n, 1 << n)).astype(np.float32) ** 8
    leaves[rng.random(leaves.shape) < 0.2] = 0.0
    tree = HaarTree(leaves)
    count = 20_003
    u = rng.random((count, 2), dtype=np.float32)
    u[:5] = [[0.0, 0.0], [ONE_MINUS_EPS, ONE_MINUS_EPS], [0.5, 0.5], [0.0, ONE_MINUS_EPS], [ONE_MINUS_EPS, 0.0]]
    q = cl.thread_queue()
    # work-groups as the library launches each build: with barriers as HaarTree.sample, without as the renderer
    size = (cl.items(count, cl.LANES),), (cl.WALK_WORK_GROUP if barriers else cl.WORK_GROUP,)
    u_buf, uv_buf, pdf_buf = cl.to_device(u), cl.empty(8 * count), cl.empty(4 * count)

    def outputs():
        return cl.read(uv_buf, (2, count), np.float32, q), cl.read(pdf_buf, (count,), np.float32, q)

    runs = {}
    for pairs in (pair_level, 64):
        knl = cl.kernel(cl.program("warp.cl", N_LEVELS=n, BATCHED=0, PAIR_LEVEL=pairs, WALK_BARRIERS=barriers),
                        "warp_sample")
        knl(q, *size, tree.buffer, np.uint64(tree.stride), np.uint32(count), np.uint32(count), u_buf, np.uint32(2),
            uv_buf, pdf_buf)
        runs[("light", pairs)] = outputs()
    nrm = rng.normal(size=(count, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    n4, wo4 = np.zeros((count, 4), np.float32), np.zeros((count, 4), np.float32)
    n4[:, :3], wo4[:, :3] = nrm, nrm + 0.3 * rng.normal(size=(count, 3))
    wo4[:, :3] /= np.linalg.norm(wo4[:, :3], axis=1, keepdims=True)
    rot = cl.to_device(np.eye(3, dtype=np.float32).ravel())
    kappa = product.lobe_kappa(bsdfs.PHONG, 200.0)
    shape = product.lobe_shape(bsdfs.PHONG, 200.0)
    for depth in (3, 4):
        for pairs in (pair_level, 64):
            knl = cl.kernel(cl.program("product.cl", N_LEVELS=n, PRODUCT_LEVELS=depth, LOBE_SHAPES=1 << shape,
                                       PAIR_LEVEL=pairs, WALK_BARRIERS=barriers), "product_sample_points")
            knl(q, *size, tree.buffer, rot, np.uint32(count), cl.to_device(n4), cl.to_device(wo4),
                cl.to_device(np.zeros(count, np.int32)), cl.to_device(np.array([kappa], np.float32)),
                cl.to_device(np.array([depth + 256 * shape], np.int32)), u_buf, np.uint32(2), uv_buf, pdf_buf)
            runs[(f"product{depth}", pairs)] = outputs()
    for walk in ("light", "product3", "product4"):
        (uv_a, pdf_a), (uv_b, pdf_b) = runs[(walk, pair_level)], runs[(walk, 64)]
        np.testing.assert_array_equal(uv_a, uv_b, err_msg=walk)
        np.testing.assert_array_equal(pdf_a, pdf_b, err_msg=walk)
        assert np.isfinite(pdf_a).all() and (pdf_a > 0).all()


# ============================================================================= warp_sample / warp_pdf
@pytest.mark.parametrize("tree_id", list(TREES))
def test_warp_sample_matches_reference(tree_id):
    """warp_sample == sample_reference: the same leaf for every sample, uv within 1e-5,
    pdf within 1e-6 relative.

    Both run the same float32 operations in the same order, so they are expected to be
    bitwise equal. The tolerance allows for a device whose division is not correctly
    rounded (OpenCL allows 2.5 ulp): an error e in the rescaled u at one level is divided
    by the child's probability at each later level (in both coordinates: the product of
    those is <= 1 / p_leaf) and finally by the side 2^n, giving |d uv| <= ~1e-7 for the
    trees here except where a leaf is very unlikely, whence 1e-5. The leaf itself must
    match exactly: a different leaf is a different sample, not a rounding error.
    """
    t = tree_of(tree_id)
    side = 1 << t.n_levels
    g = (np.arange(32) + 0.5) / 32
    u = np.concatenate([random_u(100_000, 21), np.stack(np.meshgrid(g, g), -1).reshape(-1, 2),
                        EDGE_U]).astype(np.float32)
    uv, pdf = t.sample(u)
    uv_ref, pdf_ref = sample_reference(t.nodes(), t.n_levels, u, len(u))
    assert uv.dtype == np.float32 and uv.shape == (len(u), 2) and pdf.shape == (len(u),)
    kx, ky = leaf_index(uv, side)
    rx, ry = leaf_index(uv_ref, side)
    same = (kx == rx) & (ky == ry)
    assert same.all(), f"{(~same).sum()} samples in another leaf, e.g. u = {u[~same][:3].tolist()}"
    np.testing.assert_allclose(uv, uv_ref, atol=1e-5, rtol=0)
    np.testing.assert_allclose(pdf, pdf_ref, rtol=1e-6, atol=0)


@pytest.mark.parametrize("tree_id", list(TREES))
def test_warp_pdf_matches_reference(tree_id):
    """warp_pdf == pdf_reference at random points, on every leaf boundary and at 0, 1-eps, 1.

    pdf = leaf / root * 4^n: one float32 division times a power of two in both, so equal
    to 1 ulp (rtol 1e-6).
    """
    t = tree_of(tree_id)
    side = 1 << t.n_levels
    edges = np.concatenate([np.arange(side + 1) / side, [ONE_MINUS_EPS]])
    rng = np.random.default_rng(22)
    bx = np.stack([edges, rng.random(len(edges))], 1)
    uv = np.concatenate([random_u(100_000, 23), bx, bx[:, ::-1], [[1.0, 1.0], [0.0, 0.0]]]).astype(np.float32)
    got = t.pdf(uv)
    ref = pdf_reference(t.nodes(), t.n_levels, uv, len(uv))
    np.testing.assert_allclose(got, ref, rtol=1e-6, atol=0)
    # and the formula itself, from the leaves
    ix, iy = leaf_index(uv.astype(np.float64), side)
    leaves = leaves_of(tree_id).astype(np.float64)
    np.testing.assert_allclose(got, leaves[iy, ix] / leaves.sum() * side * side, rtol=4 * t.n_levels * U32 + 1e-7)


def test_batched_samples_use_their_own_tree():
    """Sample i uses tree i // samples_per_tree: tree k has all its mass in leaf k only,
    so every sample of tree k must land in leaf k with pdf 4^n."""
    T, side, m = 12, 8, 1000
    leaves = np.zeros((T, side, side), np.float32)
    for k in range(T):
        leaves[k, k // side, k % side] = 1.0 + k
    t = HaarTree(leaves)
    uv, pdf = t.sample(random_u(T * m, 31), samples_per_tree=m)
    ix, iy = leaf_index(uv, side)
    k = np.arange(T * m) // m
    assert np.all(iy * side + ix == k)
    np.testing.assert_array_equal(pdf, np.float32(side * side))
    # warp_pdf with the same batching: the centre of tree k's own leaf has pdf 4^n, the
    # centre of the next tree's leaf has pdf 0
    own = np.stack([(k % side + 0.5) / side, (k // side + 0.5) / side], 1).astype(np.float32)
    other = np.stack([((k + 1) % T % side + 0.5) / side, ((k + 1) % T // side + 0.5) / side], 1)
    np.testing.assert_array_equal(t.pdf(own, samples_per_tree=m), np.float32(side * side))
    np.testing.assert_array_equal(t.pdf(other.astype(np.float32), samples_per_tree=m), 0.0)
    # default samples_per_tree = N / T
    uv2, _ = t.sample(random_u(T * m, 31))
    np.testing.assert_array_equal(uv2, uv)


def test_batched_random_trees_match_reference():
    rng = np.random.default_rng(32)
    leaves = rng.random((5, 32, 32)).astype(np.float32)
    leaves[1] = 0
    leaves[3, 16:, :] = 0
    leaves[rng.random(leaves.shape) < 0.2] = 0
    t = HaarTree(leaves)
    m = 20_000
    u = random_u(5 * m, 33)
    uv, pdf = t.sample(u, samples_per_tree=m)
    uv_ref, pdf_ref = sample_reference(t.nodes(), t.n_levels, u, m)
    np.testing.assert_allclose(uv, uv_ref, atol=1e-5, rtol=0)
    np.testing.assert_allclose(pdf, pdf_ref, rtol=1e-6, atol=0)
    p = t.pdf(uv, samples_per_tree=m)
    np.testing.assert_allclose(p, pdf_reference(t.nodes(), t.n_levels, uv, m), rtol=1e-6, atol=0)
    assert np.all(pdf[m:2 * m] == 0)  # the all-zero tree


# ============================================================================= zero mass, edges
@pytest.mark.parametrize("tree_id", ["n5-zeros", "n4-checker", "n6-peaky", "n1"])
def test_no_sample_in_zero_mass_leaf(tree_id):
    """Random u: every sample lies in a leaf of positive mass and carries pdf > 0."""
    t = tree_of(tree_id)
    side = 1 << t.n_levels
    uv, pdf = t.sample(random_u(500_000, 41))
    ix, iy = leaf_index(uv, side)
    mass = leaves_of(tree_id)[iy, ix]
    bad = ~(mass > 0) | ~(pdf > 0)
    assert not bad.any(), f"{bad.sum()} samples in zero-mass leaves, e.g. uv = {uv[bad][:3].tolist()}"


@pytest.mark.parametrize("tree_id", ["n1", "n3-random", "n5-zeros", "n4-checker", "n7-random", "all-zero"])
def test_u_at_and_near_one_stays_in_square(tree_id):
    """u = 1 - eps, u = 1.0 exactly and their neighbours map into [0, 1)^2 (the documented
    range of HaarTree.sample), never to NaN."""
    t = HaarTree(np.zeros((8, 8), np.float32)) if tree_id == "all-zero" else tree_of(tree_id)
    uv, pdf = t.sample(EDGE_U)
    assert np.all(np.isfinite(uv)) and np.all(np.isfinite(pdf))
    out = ~np.all((uv >= 0) & (uv < 1), axis=1)
    assert not out.any(), f"{out.sum()} points outside [0, 1)^2: u = {EDGE_U[out][:4].tolist()} -> uv = {uv[out][:4].tolist()}"


@pytest.mark.parametrize("tree_id", ["n4-checker", "n5-zeros"])
def test_u_near_one_stays_in_its_leaf(tree_id):
    """u close to 1 must not carry a sample out of the leaf it walked to.

    In the checker tree every non-empty leaf has empty right and lower neighbours, so a
    point that crosses its leaf's far edge (uv = (x + u') / 2^n rounding up to (x + 1) / 2^n)
    lands in zero mass: then HaarTree.pdf(uv) is 0 for a drawn sample.
    """
    t = tree_of(tree_id)
    side = 1 << t.n_levels
    uv, pdf = t.sample(EDGE_U)
    ix, iy = leaf_index(uv, side)
    mass = leaves_of(tree_id)[iy, ix]
    bad = ~(mass > 0) | ~(pdf > 0)
    assert not bad.any(), (f"{bad.sum()} of {len(EDGE_U)} edge samples in zero-mass leaves: "
                           f"u = {EDGE_U[bad][:3].tolist()} -> uv = {uv[bad][:3].tolist()}, pdf = {pdf[bad][:3].tolist()}")


def test_all_zero_tree():
    """A tree of zero mass gives pdf 0 ("no sample") everywhere and no NaN."""
    t = HaarTree(np.zeros((16, 16), np.float32))
    assert t.integral[0] == 0
    u = np.concatenate([random_u(10_000, 51), EDGE_U])
    uv, pdf = t.sample(u)
    assert np.all(np.isfinite(uv)) and np.all(pdf == 0)
    p = t.pdf(random_u(10_000, 52))
    assert np.all(p == 0)


# ============================================================================= stratification
def jittered(k, seed):
    """k x k jittered grid on [0, 1)^2, (k^2, 2) float32, one point per stratum."""
    rng = np.random.default_rng(seed)
    i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    pts = (np.stack([i.ravel(), j.ravel()], 1) + rng.random((k * k, 2))) / k
    return pts.astype(np.float32)


@pytest.mark.parametrize("value", [1.0, 0.37])
def test_stratified_uniform_tree_one_sample_per_leaf(value):
    """Uniform 16 x 16 tree, 16 x 16 jittered u: exactly one sample in each leaf.

    Every split has p = 1/2 exactly, so the warp is u -> 2u or 2u - 1 per level (exact in
    float32): stratum (i, j) goes to leaf (i, j).
    """
    t = HaarTree(np.full((16, 16), value, np.float32))
    for seed in range(5):
        uv, pdf = t.sample(jittered(16, seed))
        ix, iy = leaf_index(uv, 16)
        counts = np.bincount(iy * 16 + ix, minlength=256)
        assert np.all(counts == 1), counts.reshape(16, 16)
        np.testing.assert_array_equal(pdf, 1.0)


def test_leaf_preimages_are_rectangles():
    """The warp maps an axis-aligned rectangle of u onto each leaf, of area p_leaf.

    Proof sketch: at each level the top/bottom choice depends only on u.y (given the node)
    and the left/right choice only on u.x (given the pair), and the rescalings are
    monotone, so a node's preimage (a rectangle) is cut by one horizontal line and then
    by vertical lines. This is what keeps stratified inputs stratified: every stratum
    inside a preimage sends its point to that leaf.

    Check: on a regular 256 x 256 grid of u (cell centres), the grid points reaching each
    leaf fill a full W x H block of grid indices, and since a rectangle of side s holds
    256 s +- 1 centres per axis, (W - 1)(H - 1) <= 256^2 p_leaf <= (W + 1)(H + 1).
    """
    k = 256
    leaves = leaves_of("n5-zeros")[:16, :16].copy()  # 16 x 16 with zeros and a zero block
    leaves[:, 8:] = leaves_of("n5-lognormal")[:16, 8:16]
    t = HaarTree(leaves)
    g = (np.arange(k) + 0.5) / k
    gx, gy = np.meshgrid(g, g, indexing="ij")  # grid index (i, j) <-> u = (g[i], g[j])
    uv, _ = t.sample(np.stack([gx.ravel(), gy.ravel()], 1).astype(np.float32))
    ix, iy = leaf_index(uv, 16)
    leaf = (iy * 16 + ix).reshape(k, k)
    p = (leaves / leaves.astype(np.float64).sum()).ravel()
    for lid in np.unique(leaf):
        ii, jj = np.nonzero(leaf == lid)
        w, h = ii.max() - ii.min() + 1, jj.max() - jj.min() + 1
        assert len(ii) == w * h, f"leaf {lid}: preimage is not a rectangle"
        assert (w - 1) * (h - 1) <= k * k * p[lid] * (1 + 1e-6) + 1e-9
        assert k * k * p[lid] <= (w + 1) * (h + 1) * (1 + 1e-6)
    assert np.all(p[np.unique(leaf)] > 0)


def test_stratified_input_lowers_variance():
    """For a non-uniform tree, jittered u gives a lower-variance estimate of a smooth
    integral than independent u.

    (Jittered sampling of u can never do worse than independent sampling, whatever the
    warp; the rectangle property above is what makes it do markedly better after the
    warp.) Estimator: mean of g(uv) / pdf(uv) over 256 points for g(x, y) =
    exp(sin 3x + cos 2y), on a 16 x 16 tree with leaves in [0.25, 1] (so g / pdf is
    bounded and the 256-point means are close to normal, as the F-test assumes).
    200 repetitions each; one-sided F-test of the two sample variances at level 1e-3.
    """
    t = HaarTree(np.random.default_rng(60).uniform(0.25, 1.0, (16, 16)).astype(np.float32))
    reps, n = 200, 256

    def estimate(u):
        uv, pdf = t.sample(u)
        x, y = uv[:, 0].astype(np.float64), uv[:, 1].astype(np.float64)
        return (np.exp(np.sin(3 * x) + np.cos(2 * y)) / pdf).reshape(reps, n).mean(1)

    strat = estimate(np.concatenate([jittered(16, 1000 + r) for r in range(reps)]))
    indep = estimate(random_u(reps * n, 61))
    f = indep.var(ddof=1) / strat.var(ddof=1)
    p = stats.f.sf(f, reps - 1, reps - 1)
    assert p < 1e-3, f"variance ratio independent/stratified = {f:.3g} (p = {p:.3g})"
    # both estimate the same integral (5 standard errors of the independent estimate)
    assert abs(strat.mean() - indep.mean()) < 5 * indep.std(ddof=1) / np.sqrt(reps)


# ============================================================================= pdf integral, chi-square
@pytest.mark.parametrize("tree_id", list(TREES))
def test_warp_pdf_integrates_to_one(tree_id):
    """Integral of HaarTree.pdf over the square = 1: the pdf is constant on each leaf, so a
    2 x 2 midpoint rule per leaf is exact. Error: sum(leaf)/root with root a float32 sum
    (<= 2n roundings) and a float32 quotient per leaf: rtol (2n + 2) u32, rounded up."""
    t = tree_of(tree_id)
    side = 1 << t.n_levels
    c = (np.arange(2 * side) + 0.5) / (2 * side)
    uv = np.stack(np.meshgrid(c, c), -1).reshape(-1, 2).astype(np.float32)
    total = t.pdf(uv).astype(np.float64).sum() / len(uv)
    assert abs(total - 1) <= (2 * t.n_levels + 4) * U32, total


def tree_grid(side):
    """Square cells aligned with the leaves (2 x 2 cells per leaf up to 128 a side, else 64
    cells of several leaves each) and a midpoint rule that is exact on them."""
    cells = 2 * side if side <= 64 else 64
    return SquareGrid.uniform(cells), max(1, side // cells)


@pytest.mark.parametrize("tree_id", CHI2_TREES)
def test_chi2_warp_against_tree_pdf(tree_id):
    t = tree_of(tree_id)
    uv, _ = t.sample(random_u(200_000, 71))
    grid, quad = tree_grid(1 << t.n_levels)
    ok, p, msg = chi2_test(uv, t.pdf, grid, n_tests=N_CHI2, quad=quad, rule="midpoint")
    assert ok, msg


def test_chi2_batched_trees():
    """Four different trees sampled in one launch; each tree's samples against its own pdf."""
    rng = np.random.default_rng(81)
    leaves = np.exp(rng.normal(0, 1.5, (N_BATCH_CHI2, 16, 16))).astype(np.float32)
    leaves[1, :, :8] = 0
    leaves[2, rng.random((16, 16)) < 0.5] = 0
    t = HaarTree(leaves)
    m = 100_000
    uv, _ = t.sample(random_u(N_BATCH_CHI2 * m, 82), samples_per_tree=m)
    grid, quad = tree_grid(16)
    for k in range(N_BATCH_CHI2):
        single = HaarTree(leaves[k])
        ok, p, msg = chi2_test(uv[k * m:(k + 1) * m], single.pdf, grid, n_tests=N_CHI2, quad=quad,
                               rule="midpoint")
        assert ok, f"tree {k}: {msg}"


# ============================================================================= sphere.h direction maps
def test_fast_atan2_within_three_ulp_of_pi():
    """fast_atan2 (sphere.h) against float64 arctan2, over all octants, 60 decades of scale,
    the axes and signed zeros.

    Bound: float32 rounding of lo / hi and of (t - 1) / (t + 1) (~2 ulp of the reduced
    argument, < 1/2 ulp of pi after the polynomial's slope <= 1), Cephes' polynomial
    (< 2e-7 relative on [-tan(pi/8), tan(pi/8)]) and the three additions of pi/4, pi/2,
    pi (1/2 ulp each): under 3 ulp of pi (ulp(pi) = 2^-22 = 2.4e-7).
    """
    from wavlight import cl

    rng = np.random.default_rng(40)
    n = 1 << 18
    yx = np.concatenate([rng.normal(size=(n, 2)),
                         rng.uniform(-1, 1, (n, 2)) * np.exp(rng.uniform(-30, 30, (n, 1))),
                         [[0, 0], [-0.0, -1], [0, 1], [0, -1], [1, 0], [-1, 0], [1, 1], [-1, -1],
                          [1e-30, -1], [-1e-30, -1], [1, 1e-30], [3e38, 3e38], [1e-38, -1e-38]]]).astype(np.float32)
    out = cl.empty(4 * len(yx))
    q = cl.thread_queue()
    cl.kernel(cl.program("sphere.cl"), "atan2_points")(q, (len(yx),), None, cl.to_device(yx), out)
    got = cl.read(out, (len(yx),), np.float32, q).astype(np.float64)
    ref = np.arctan2(yx[:, 0].astype(np.float64), yx[:, 1].astype(np.float64))
    ref = np.where(np.isclose(np.abs(ref), np.pi) & (yx[:, 0] == 0), np.pi, ref)  # +-0 -> pi: the same u
    assert np.all(np.isfinite(got))
    assert np.abs(got - ref).max() <= 3 * 2.0 ** -22


def test_world_to_square_kernel_matches_numpy():
    """env_world_to_square (sphere.h) against Environment.world_to_square, with rotate_y.

    theta comes from atan2(sin, cos) in the kernel and arccos in numpy: equal to float32
    accuracy, 1e-6 of the square (a texel of a 4096-wide map is 2.4e-4), and both sides of
    the seam at u = 0 agree modulo 1. At the two poles u is arbitrary and not compared.
    """
    from wavlight import cl
    from wavlight.envmap import Environment

    env = Environment(np.ones((8, 16, 3), np.float32), 1.0, 35.0)
    rng = np.random.default_rng(41)
    d = rng.normal(size=(200_000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = np.concatenate([d, [[0, 1, 0], [0, -1, 0], [1, 0, 0], [0, 0, 1], [0, 0, -1], [-1, 0, 0]]])
    w4 = np.zeros((len(d), 4), np.float32)
    w4[:, :3] = d
    out = cl.empty(8 * len(d))
    q = cl.thread_queue()
    cl.kernel(cl.program("sphere.cl"), "world_to_square")(
        q, (len(d),), None, cl.to_device(env.map_from_world.astype(np.float32).ravel()), cl.to_device(w4), out)
    got = cl.read(out, (len(d), 2), np.float32, q).astype(np.float64)
    d32 = w4[:, :3].astype(np.float64)  # the kernel's input, renormalised: arccos needs unit length
    ref = env.world_to_square(d32 / np.linalg.norm(d32, axis=1, keepdims=True))
    du = np.abs(got[:, 0] - ref[:, 0])
    du = np.minimum(du, 1 - du)
    pole = np.hypot(w4[:, 0], w4[:, 2]) == 0  # u is arbitrary there (atan2(+-0, +-0))
    assert pole.sum() == 2 and du[~pole].max() <= 1e-6 and np.abs(got[:, 1] - ref[:, 1]).max() <= 1e-6


def test_fast_sincos_within_2e7_absolute():
    """fast_sincos (sphere.h) against float64 sin and cos on [-4 pi, 4 pi] (the kernels pass
    angles in [-pi, 2 pi]) and at the quadrant boundaries.

    Bound: Cody-Waite reduction with a two-part pi/2 (error ~|j| 2^-47, negligible), Cephes'
    sinf / cosf polynomials on [-pi/4, pi/4] (< 1e-7 absolute), float32 rounding of the
    argument itself (x is exact; the polynomial's rounding ~1 ulp of 1 = 1.2e-7): 2e-7.
    """
    from wavlight import cl

    x = np.concatenate([np.random.default_rng(42).uniform(-4 * np.pi, 4 * np.pi, 1 << 18),
                        np.arange(-8, 9) * np.pi / 4, [0.0, -0.0, 1e-30]]).astype(np.float32)
    out = cl.empty(8 * len(x))
    q = cl.thread_queue()
    cl.kernel(cl.program("sphere.cl"), "sincos_points")(q, (len(x),), None, cl.to_device(x), out)
    got = cl.read(out, (len(x), 2), np.float32, q).astype(np.float64)
    x64 = x.astype(np.float64)
    assert np.abs(got[:, 0] - np.sin(x64)).max() <= 2e-7
    assert np.abs(got[:, 1] - np.cos(x64)).max() <= 2e-7


def test_square_to_world_kernel_matches_numpy():
    """env_square_to_world (sphere.h) against Environment.square_to_world, with rotate_y: unit
    directions equal within float32 accuracy (2e-7 per sin / cos, a few roundings: 1e-6)."""
    from wavlight import cl
    from wavlight.envmap import Environment

    env = Environment(np.ones((8, 16, 3), np.float32), 1.0, -70.0)
    uv = np.random.default_rng(43).random((100_000, 2)).astype(np.float32)
    uv = np.concatenate([uv, [[0, 0], [0.5, 0.5], [0.25, 1 - 2 ** -24], [1 - 2 ** -24, 0.75]]]).astype(np.float32)
    out = cl.empty(16 * len(uv))
    q = cl.thread_queue()
    cl.kernel(cl.program("sphere.cl"), "square_to_world")(
        q, (len(uv),), None, cl.to_device(env.map_from_world.astype(np.float32).ravel()), cl.to_device(uv), out)
    got = cl.read(out, (len(uv), 4), np.float32, q)[:, :3].astype(np.float64)
    ref = env.square_to_world(uv.astype(np.float64))
    assert np.abs(got - ref).max() <= 1e-6


def test_walk_never_enters_a_zero_mass_child_next_to_a_denormal_one():
    """u * (top + bottom) can round up to a denormal top mass, so `u * sum < top` alone would
    send a sample into a zero-mass bottom row (choose_child guards against it): in a tree whose
    only mass is one denormal texel, every sample lands in that texel, kernel and twin alike."""
    leaves = np.zeros((2, 2), np.float32)
    leaves[0, 0] = np.float32(3e-45)   # two ulps of the smallest denormal
    t = HaarTree(leaves)
    if not t.integral[0] > 0:
        pytest.skip("this device flushes denormals to zero")
    g = (np.arange(64) + 0.5) / 64
    u = np.concatenate([np.stack(np.meshgrid(g, g), -1).reshape(-1, 2), EDGE_U]).astype(np.float32)
    for uv, pdf in (t.sample(u), sample_reference(t.nodes(), t.n_levels, u, len(u))):
        kx, ky = leaf_index(uv, 2)
        assert (kx == 0).all() and (ky == 0).all()
        np.testing.assert_allclose(pdf, 4.0, rtol=1e-6)
