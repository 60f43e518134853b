"""Haar wavelets (wavlight/haar/, kernels/haar.cl) against definitions and pointwise integration.

Basis images are built here from the definitions (module notes of haar.py), independently
of the transform. Integrals of piecewise-constant images are exact pixel sums.

Tolerances: float64 results are sums of O(4^n) terms of magnitude <= 1 from inputs in
[0, 1) (or coefficients of such images), so they agree to a few hundred ulps; we use
1e-12 absolute (~4500 ulps at 1.0) throughout. Float32 kernels: each of the <= 2n
levels (n reconstruction steps of H, n reductions) adds a few ulps relative to
operands of one sign for positive images, so 16 (levels) eps32 relative is generous yet
catches any wrong coefficient (errors of >= 1e-3 relative).
"""
from __future__ import annotations

import numpy as np
import pytest

from wavlight import cl, haar
from wavlight.errors import ArgumentError
from wavlight.haar import sparse as haar_sparse
from wavlight.haar.tree import HaarTree, build_reference, device_order, level_offset, tree_size

EPS32 = float(np.finfo(np.float32).eps)
TOL64 = 1e-12


# ============================================================================= helpers
def basis_image(level, x, y, m, n):
    """Pixel values of basis function (level, x, y, m) on a 2^n x 2^n grid, from the definition."""
    side = 1 << n
    img = np.zeros((side, side))
    if m == 0:
        return img + 1.0
    r = side >> level  # pixels per node side
    h = r // 2
    block = np.full((r, r), 2.0 ** level)
    if m == 1:
        block[:, h:] *= -1  # + left, - right
    elif m == 2:
        block[h:, :] *= -1  # + top, - bottom
    else:
        block[:h, h:] *= -1
        block[h:, :h] *= -1
    img[y * r:(y + 1) * r, x * r:(x + 1) * r] = block
    return img


def all_basis(n):
    """(4^n, 2^n, 2^n): basis image of every flat index."""
    l, x, y, m = haar.coeff_basis(np.arange(4 ** n), n)
    return np.stack([basis_image(*b, n) for b in zip(l, x, y, m)])


def box_sums(pixels):
    """float64 box-mass pyramid (..., tree_size(n)) of pixel values (mass = pixel * 4^-n)."""
    a = np.asarray(pixels, np.float64)
    n = a.shape[-1].bit_length() - 1
    levels = [a * 4.0 ** -n]
    for _ in range(n):
        a = levels[0]
        levels.insert(0, (a[..., 0::2, 0::2] + a[..., 0::2, 1::2]) + (a[..., 1::2, 0::2] + a[..., 1::2, 1::2]))
    return np.concatenate([v.reshape(v.shape[:-2] + (-1,)) for v in levels], axis=-1)


def upsample(pixels, n):
    """Pixel values on a finer 2^n grid (the same piecewise-constant function)."""
    r = (1 << n) // pixels.shape[-1]
    return np.repeat(np.repeat(pixels, r, -1), r, -2)


def recon(s: haar.SparseHaar, n=None):
    img = haar.inverse(s.to_dense())
    return img if n is None else upsample(img, n)


# ============================================================================= layout and transform
@pytest.mark.parametrize("n", [0, 1, 3, 6])
def test_layout_helpers_round_trip(n):
    idx = np.arange(4 ** n)
    l, x, y, m = haar.coeff_basis(idx, n)
    np.testing.assert_array_equal(haar.coeff_index(l, x, y, m, n), idx)
    assert (m == 0).sum() == 1 and m[0] == 0
    for lev in range(n):  # 4^l nodes per level and type, inside the level's grid
        for t in (1, 2, 3):
            sel = (l == lev) & (m == t)
            assert sel.sum() == 4 ** lev
            assert x[sel].max() < 2 ** lev and y[sel].max() < 2 ** lev
    np.testing.assert_array_equal(haar.node_scale(2), [1, 2, 2, 2, 2] + [4] * 16)


def test_layout_blocks():
    n = 3
    assert haar.coeff_index(1, 1, 0, 1, n) == 0 * 8 + 2 + 1  # m = 1: c[y, s + x]
    assert haar.coeff_index(1, 1, 0, 2, n) == 2 * 8 + 1      # m = 2: c[s + y, x]
    assert haar.coeff_index(2, 3, 2, 3, n) == 6 * 8 + 7      # m = 3: c[s + y, s + x]


def test_single_basis_function_images():
    """forward(basis image) = unit vector, inverse(unit vector) = basis image, Gram = identity."""
    n = 3
    B = all_basis(n)
    C = haar.forward(B).reshape(len(B), -1)
    np.testing.assert_allclose(C, np.eye(len(B)), atol=TOL64)
    np.testing.assert_allclose(haar.inverse(np.eye(len(B)).reshape(B.shape)), B, atol=TOL64)
    gram = np.einsum("ipq,jpq->ij", B, B) / 4 ** n
    np.testing.assert_allclose(gram, np.eye(len(B)), atol=TOL64)


@pytest.mark.parametrize("shape", [(1, 1), (2, 2), (3, 32, 32), (2, 3, 16, 16), (512, 512)])
def test_round_trip_and_parseval(shape):
    rng = np.random.default_rng(11)
    img = rng.uniform(-1, 1, shape)
    c = haar.forward(img)
    np.testing.assert_allclose(haar.inverse(c), img, atol=TOL64)
    # Parseval: sum of squared coefficients = integral of F^2 = mean of squared pixels
    np.testing.assert_allclose(np.sum(c ** 2, axis=(-2, -1)), np.mean(img ** 2, axis=(-2, -1)),
                               rtol=TOL64)
    np.testing.assert_allclose(c[..., 0, 0], img.mean(axis=(-2, -1)), atol=TOL64)  # eq. 18


def test_batch_axes_and_dtype():
    rng = np.random.default_rng(12)
    img = rng.random((2, 3, 8, 8)).astype(np.float32)
    c = haar.forward(img)
    assert c.dtype == np.float32
    np.testing.assert_array_equal(c[1, 2], haar.forward(img[1, 2]))
    with pytest.raises(ValueError):
        haar.forward(np.zeros((6, 6)))


# ============================================================================= sparse sets and compression
def test_sparse_round_trip_and_validation():
    rng = np.random.default_rng(13)
    c = haar.forward(rng.random((3, 8, 8)))  # channels first
    s = haar.SparseHaar.from_dense(c, [5, 0, 9])
    np.testing.assert_array_equal(s.index, [0, 5, 9])
    assert s.value.shape == (3, 3) and len(s) == 3
    d = s.to_dense()
    assert d.shape == (3, 8, 8)
    np.testing.assert_array_equal(d.reshape(3, -1)[:, [0, 5, 9]], c.reshape(3, -1)[:, [0, 5, 9]])
    assert np.count_nonzero(d) == 9
    full = haar.SparseHaar.from_dense(c)
    np.testing.assert_array_equal(full.to_dense(), c)
    with pytest.raises(ValueError):
        haar.SparseHaar(3, [1, 1], [0.0, 1.0])
    with pytest.raises(ValueError):
        haar.SparseHaar(2, [16], [1.0])


def test_compress_topk():
    rng = np.random.default_rng(14)
    c = haar.forward(rng.random((32, 32)) ** 4)
    for k in (1, 2, 50, 1024, 5000):
        s = haar.compress_topk(c, k)
        assert len(s) == min(k, 1024) and s.index[0] == 0  # scaling coefficient always kept
        kept = np.zeros(1024, bool)
        kept[s.index] = True
        mag = np.abs(c.reshape(-1))
        if 1 < k < 1024:
            assert mag[kept][1:].min() >= mag[~kept].max()  # the largest wavelets
    # multi-channel: joint selection by the L2 norm over channels
    c3 = haar.forward(rng.random((3, 16, 16)))
    s3 = haar.compress_topk(c3, 20)
    e = np.sum(c3 ** 2, axis=0).reshape(-1)
    keep = np.zeros(256, bool)
    keep[s3.index] = True
    assert s3.value.shape == (20, 3) and e[keep][1:].min() >= e[~keep].max()


def test_compress_energy():
    rng = np.random.default_rng(15)
    c = haar.forward(rng.random((32, 32)) ** 4)
    e = c.reshape(-1) ** 2
    for f in (0.0, 0.5, 0.9, 0.99, 0.999):
        s = haar.compress_energy(c, f)
        kept = np.sum(s.value ** 2)
        assert s.index[0] == 0 and kept >= f * e.sum() * (1 - TOL64)
        if len(s) > 1:  # the fewest: without the smallest kept wavelet it falls short
            assert kept - np.min(s.value[1:] ** 2) < f * e.sum()
    assert len(haar.compress_energy(c, 0.0)) == 1
    s = haar.compress_energy(c, 1.0)
    assert len(s) == np.count_nonzero(c)
    np.testing.assert_allclose(recon(s), haar.inverse(c), atol=TOL64)
    with pytest.raises(ValueError):
        haar.compress_energy(c, 1.5)


# ============================================================================= tripling coefficients
def test_tripling_exhaustive_8x8():
    """All 64^3 triples of an 8x8 image against pixel sums of basis images."""
    n = 3
    B = all_basis(n).reshape(64, -1)
    brute = np.einsum("ip,jp,kp->ijk", B, B, B) / 64.0
    idx = np.arange(64)
    C = haar.tripling(idx[:, None, None], idx[None, :, None], idx[None, None, :], n)
    np.testing.assert_allclose(C, brute, atol=TOL64)
    # every case of the theorem occurs, with both signs for case 3
    l, x, y, m = haar.coeff_basis(idx, n)
    i, j, k = np.nonzero(np.abs(brute) > 0.5)
    case1 = (m[i] == 0) & (m[j] == 0) & (m[k] == 0)
    case2 = (m[i] > 0) & (m[j] > 0) & (m[k] > 0) & (m[i] != m[j]) & (m[j] != m[k]) & (m[i] != m[k])
    case3 = ~case1 & ~case2
    assert case1.sum() == 1 and case2.sum() == 6 * 21  # 21 nodes, 6 orders of the three types
    np.testing.assert_array_equal(C[i[case2], j[case2], k[case2]], 2.0 ** l[i[case2]])
    v3 = C[i[case3], j[case3], k[case3]]
    assert (v3 > 0).any() and (v3 < 0).any()
    assert set(np.abs(v3)) == {1.0, 2.0}  # third function at level 0 / scaling, or level 1
    # spot checks: psi^1_0 twice with phi; psi^1_{1,(1,0)} twice with psi^1_0 (right half: -1)
    a = haar.coeff_index(0, 0, 0, 1, n)
    b = haar.coeff_index(1, 1, 0, 1, n)
    assert haar.tripling(a, a, 0, n) == 1.0
    assert haar.tripling(b, a, b, n) == -1.0
    assert haar.tripling(a, b, b, n) == -1.0


def test_tripling_sampled_16x16():
    """Random triples of a 16x16 image, biased towards the non-zero cases: k is often i, and
    j often a function whose square contains i's (coarser, or the same node)."""
    n = 4
    B = all_basis(n).reshape(256, -1)
    rng = np.random.default_rng(16)
    N = 20000
    i = rng.integers(0, 256, N)
    l, x, y, m = haar.coeff_basis(i, n)
    lc = rng.integers(0, l + 1)
    mc = rng.integers(0, 4, N)
    cover = haar.coeff_index(np.where(mc == 0, 0, lc), np.where(mc == 0, 0, x >> (l - lc)),
                             np.where(mc == 0, 0, y >> (l - lc)), mc, n)
    j = np.where(rng.random(N) < 0.7, cover, rng.integers(0, 256, N))
    k = np.where(rng.random(N) < 0.5, i, np.where(rng.random(N) < 0.5, cover, rng.integers(0, 256, N)))
    perm = rng.permuted(np.stack([i, j, k]), axis=0)  # the theorem is symmetric: any position
    brute = np.einsum("np,np,np->n", B[perm[0]], B[perm[1]], B[perm[2]]) / 256.0
    np.testing.assert_allclose(haar.tripling(*perm, n), brute, atol=TOL64)
    assert np.count_nonzero(brute > 0) > 1000 and np.count_nonzero(brute < 0) > 1000


# ============================================================================= product integrals
def test_product_integrals_dense():
    rng = np.random.default_rng(17)
    g, h, k = rng.random((3, 4, 16, 16))
    G, H, K = haar.forward(g), haar.forward(h), haar.forward(k)
    np.testing.assert_allclose(haar.triple_product_integral(G, H, K), np.mean(g * h * k, axis=(-2, -1)),
                               atol=TOL64)
    np.testing.assert_allclose(haar.double_product_integral(G, H), np.mean(g * h, axis=(-2, -1)),
                               atol=TOL64)
    # signed images and broadcasting against one shared light
    s = rng.uniform(-1, 1, (16, 16))
    np.testing.assert_allclose(haar.triple_product_integral(haar.forward(s), H, K),
                               np.mean(s * h * k, axis=(-2, -1)), atol=TOL64)


def test_product_integrals_mixed_resolution():
    rng = np.random.default_rng(18)
    g, h, k = rng.random((8, 8)), rng.random((32, 32)), rng.random((16, 16))
    G, H, K = haar.forward(g), haar.forward(h), haar.forward(k)
    pointwise = np.mean(upsample(g, 5) * h * upsample(k, 5))
    np.testing.assert_allclose(haar.triple_product_integral(G, H, K), pointwise, atol=TOL64)
    sp = [haar.SparseHaar.from_dense(c) for c in (G, H, K)]
    np.testing.assert_allclose(haar.triple_product_integral(*sp), pointwise, atol=TOL64)
    np.testing.assert_allclose(haar.double_product_integral(sp[0], sp[1]),
                               np.mean(upsample(g, 5) * h), atol=TOL64)


@pytest.mark.parametrize("keep", [1, 7, 60, 400])
def test_product_integrals_sparse(keep):
    rng = np.random.default_rng(19 + keep)
    imgs = rng.random((3, 32, 32)) ** 3
    G, H, K = (haar.compress_topk(haar.forward(a), keep) for a in imgs)
    g, h, k = recon(G), recon(H), recon(K)
    np.testing.assert_allclose(haar.triple_product_integral(G, H, K), np.mean(g * h * k), atol=TOL64)
    np.testing.assert_allclose(haar.double_product_integral(G, H), np.mean(g * h), atol=TOL64)
    # dense and sparse paths agree; mixing falls back to dense
    np.testing.assert_allclose(haar.triple_product_integral(G, H.to_dense(), K), np.mean(g * h * k),
                               atol=TOL64)


def test_product_integrals_sparse_channels():
    rng = np.random.default_rng(20)
    light = haar.compress_energy(haar.forward(rng.random((3, 16, 16)) ** 4), 0.95)  # RGB
    brdf = haar.compress_topk(haar.forward(rng.random((16, 16))), 40)
    vis = haar.compress_topk(haar.forward((rng.random((16, 16)) > 0.3) * 1.0), 40)
    got = haar.triple_product_integral(light, brdf, vis)
    want = np.mean(recon(light) * recon(brdf) * recon(vis), axis=(-2, -1))
    assert got.shape == (3,)
    np.testing.assert_allclose(got, want, atol=TOL64)


# ============================================================================= scaling coefficients
def test_scaling_pyramid_dense_and_sparse():
    rng = np.random.default_rng(21)
    img = rng.random((2, 32, 32))
    c = haar.forward(img)
    p = haar.scaling_pyramid(c)
    np.testing.assert_allclose(p, box_sums(img), atol=TOL64)
    # haar/tree.py layout: build_reference takes leaf masses, float32
    np.testing.assert_allclose(p, build_reference(img / 1024.0), rtol=8 * 5 * EPS32)
    np.testing.assert_allclose(haar.scaling_pyramid(c, 3), p[:, :tree_size(3)], atol=TOL64)
    s = haar.compress_topk(c[0], 100)
    ref = box_sums(recon(s))
    np.testing.assert_allclose(haar.scaling_pyramid(s), ref, atol=TOL64)
    np.testing.assert_allclose(haar.scaling_pyramid(s, 2), ref[:tree_size(2)], atol=TOL64)
    F0 = haar.node_scale(5) * p  # scaling coefficients (eq. 17)
    np.testing.assert_allclose(F0[:, 0], c[:, 0, 0], atol=TOL64)
    np.testing.assert_allclose(F0[:, level_offset(5):], img.reshape(2, -1) / 32, atol=TOL64)


@pytest.mark.parametrize("levels", [None, 0, 2, 4])
def test_product_scaling_dense_equals_box_sums(levels):
    """Eq. 25 (wavelets of levels l' >= l) equals the box sums of the pointwise product."""
    rng = np.random.default_rng(22)
    g = rng.random((16, 16)) ** 3
    h = rng.uniform(-1, 1, (5, 16, 16))  # a batch of H sharing G
    got = haar.product_scaling(haar.forward(g), haar.forward(h), levels)
    L = 4 if levels is None else levels
    np.testing.assert_allclose(got, box_sums(g * h)[:, :tree_size(L)], atol=TOL64)


def test_product_scaling_mixed_resolution():
    rng = np.random.default_rng(23)
    g, h = rng.random((64, 64)), rng.random((8, 8))
    got = haar.product_scaling(haar.forward(g), haar.forward(h))
    np.testing.assert_allclose(got, box_sums(g * upsample(h, 6)), atol=TOL64)
    got = haar.product_scaling(haar.SparseHaar.from_dense(haar.forward(h)),
                               haar.SparseHaar.from_dense(haar.forward(g)), 4)
    np.testing.assert_allclose(got, box_sums(g * upsample(h, 6))[:tree_size(4)], atol=TOL64)


@pytest.mark.parametrize("levels", [None, 0, 3, 5])
def test_product_scaling_sparse_equals_box_sums_of_reconstruction(levels):
    rng = np.random.default_rng(24)
    G = haar.compress_energy(haar.forward(rng.random((32, 32)) ** 6), 0.9)
    H = haar.compress_topk(haar.forward(rng.random((32, 32))), 30)
    L = 5 if levels is None else levels
    ref = box_sums(recon(G) * recon(H))[:tree_size(L)]
    np.testing.assert_allclose(haar.product_scaling(G, H, levels), ref, atol=TOL64)
    np.testing.assert_allclose(haar.product_scaling(G.to_dense(), H.to_dense(), levels), ref, atol=TOL64)


def test_product_scaling_at_nodes():
    rng = np.random.default_rng(25)
    G = haar.compress_topk(haar.forward(rng.random((3, 32, 32))), 80)  # RGB light
    H = haar.compress_topk(haar.forward(rng.random((16, 16))), 25)     # coarser BRDF
    ref = box_sums(recon(G) * upsample(recon(H), 5))
    level = np.repeat(np.arange(6), 4 ** np.arange(6))
    r = np.arange(tree_size(5)) - (4 ** level - 1) // 3
    got = haar.product_scaling_at(G, H, level, r & ((1 << level) - 1), r >> level)
    assert got.shape == (3, tree_size(5))
    np.testing.assert_allclose(got, ref, atol=TOL64)


def test_node_of_is_exact_at_every_level():
    """haar.sparse.node_of inverts the pyramid index (4^l - 1) / 3 + y 2^l + x exactly at the first,
    last and a middle node of every level up to MAX_LEVELS (a float64 logarithm misplaces the
    last nodes of levels >= 27)."""
    levels, xs, ys = [], [], []
    for l in range(haar.MAX_LEVELS + 1):
        side = 1 << l
        for x, y in ((0, 0), (side - 1, side - 1), (side // 3, side - 1), (side - 1, 0)):
            levels.append(l), xs.append(x), ys.append(y)
    l, x, y = (np.array(a, np.int64) for a in (levels, xs, ys))
    nid = (np.left_shift(1, 2 * l) - 1) // 3 + (y << l) + x
    got = haar_sparse.node_of(nid)
    for a, b in zip(got, (l, x, y)):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("spread", [10 ** 9, 0, None], ids=["tables", "binary_search", "default"])
def test_sparse_lookups_by_table_and_by_search(monkeypatch, spread):
    """The sparse paths find coefficients through a table over the key space or, for sets
    sparser than 1 / haar.sparse.TABLE_SPREAD of it, by binary search: with every set tabled, none,
    or as chosen, they give the pointwise integrals and box sums, with mixed resolutions,
    channels, few shared wavelets, a set without its scaling coefficient and an empty set."""
    if spread is not None:
        monkeypatch.setattr(haar_sparse, "TABLE_SPREAD", spread)
    rng = np.random.default_rng(27)
    G = haar.compress_topk(haar.forward(rng.random((2, 32, 32)) ** 4), 150)   # two channels
    H = haar.compress_topk(haar.forward(rng.random((16, 16))), 40)           # coarser
    top = haar.compress_topk(haar.forward(rng.random((32, 32)) ** 2), 60)
    K = haar.SparseHaar(5, top.index[top.index != 0], top.value[top.index != 0])   # no scaling coefficient
    assert len(K) == 59
    g, h, k = recon(G), upsample(recon(H), 5), recon(K)
    np.testing.assert_allclose(haar.triple_product_integral(G, H, K), np.mean(g * h * k, axis=(-2, -1)), atol=TOL64)
    np.testing.assert_allclose(haar.double_product_integral(G, K), np.mean(g * k, axis=(-2, -1)), atol=TOL64)
    np.testing.assert_allclose(haar.product_scaling(G, K), box_sums(g * k), atol=TOL64)
    level = np.repeat(np.arange(6), 4 ** np.arange(6))
    r = np.arange(tree_size(5)) - (4 ** level - 1) // 3
    got = haar.product_scaling_at(G, H, level, r & ((1 << level) - 1), r >> level)
    np.testing.assert_allclose(got, box_sums(g * h), atol=TOL64)
    empty = haar.SparseHaar(5, [], [])
    assert haar.triple_product_integral(H, K, empty) == 0 and haar.double_product_integral(empty, K) == 0
    np.testing.assert_array_equal(haar.product_scaling_at(np.zeros((32, 32)), H, level, r & ((1 << level) - 1),
                                                          r >> level), 0.0)


# ============================================================================= OpenCL kernels
@pytest.mark.slow
@pytest.mark.parametrize("n,T", [(0, 3), (1, 2), (3, 5), (6, 4), (9, 1)])
def test_forward_kernel(device, n, T):
    rng = np.random.default_rng(26 + n)
    img = rng.random((T, 1 << n, 1 << n)).astype(np.float32)
    coeffs, pyr = haar.forward_cl(img)
    # same float32 operations up to exact powers of two: equal to the numpy transform
    np.testing.assert_allclose(coeffs, haar.forward(img), rtol=0, atol=4 * EPS32 * 2.0 ** -n)
    np.testing.assert_allclose(haar.forward(img.astype(np.float64)), coeffs, atol=4 * (n + 1) * EPS32)
    # the pyramid is HaarTree's (same leaves, same summation order)
    np.testing.assert_array_equal(pyr, build_reference(img * np.float32(4.0 ** -n)))
    np.testing.assert_array_equal(pyr, HaarTree(img * np.float32(4.0 ** -n)).nodes())


@pytest.mark.parametrize("shape", [(3, 2, 16, 16), (3, 8, 8), (32, 32), (1, 1, 4, 4), (2, 0, 8, 8)])
def test_kernels_take_any_leading_axes(device, shape):
    """Colour images and batches of them go to the device as they are: forward_cl and
    inverse_cl fold every leading axis into the batch and give it back, each set transformed
    as the numpy transform does it alone (a single 2-D image comes back 2-D)."""
    rng = np.random.default_rng(44)
    img = rng.random(shape).astype(np.float32)
    n = shape[-1].bit_length() - 1
    coeffs, pyr = haar.forward_cl(img)
    assert coeffs.shape == shape and pyr.shape == shape[:-2] + (tree_size(n),)
    flat = img.reshape((-1,) + shape[-2:])
    np.testing.assert_allclose(coeffs.reshape(flat.shape), haar.forward(flat), rtol=0, atol=4 * EPS32 * 2.0 ** -n)
    if len(flat):
        np.testing.assert_array_equal(pyr.reshape(-1, tree_size(n)), build_reference(flat * np.float32(4.0 ** -n)))
    back = haar.inverse_cl(coeffs)
    assert back.shape == shape
    np.testing.assert_allclose(back, img, atol=8 * (n + 1) * EPS32)


@pytest.mark.parametrize("n,T", [(0, 3), (1, 2), (3, 5), (6, 4), (9, 1)])
def test_inverse_kernel(device, n, T):
    """inverse_cl against the numpy inverse (float32 twin: the same operations up to exact
    powers of two) and against float64, and the round trip with forward_cl; a single
    2-D set comes back 2-D."""
    rng = np.random.default_rng(43 + n)
    img = rng.random((T, 1 << n, 1 << n)).astype(np.float32)
    coeffs = haar.forward(img.astype(np.float64)).astype(np.float32)
    got = haar.inverse_cl(coeffs)
    assert got.shape == img.shape and got.dtype == np.float32
    np.testing.assert_allclose(got, haar.inverse(coeffs), rtol=0, atol=4 * EPS32)
    np.testing.assert_allclose(got, haar.inverse(coeffs.astype(np.float64)), atol=4 * (n + 1) * EPS32)
    np.testing.assert_allclose(haar.inverse_cl(haar.forward_cl(img)[0]), img, atol=8 * (n + 1) * EPS32)
    np.testing.assert_array_equal(haar.inverse_cl(coeffs[0]), got[0])


@pytest.mark.slow
@pytest.mark.parametrize("n,m,L", [(5, 5, 5), (9, 5, 5), (9, 6, 6), (9, 8, 8), (6, 6, 3), (4, 6, 6),
                                   (7, 4, 6), (2, 3, 0)])
def test_product_kernel_matches_eq25(device, n, m, L):
    """Pixels in [0.1, 1): every pyramid value is a sum of positive terms, so the float32
    error stays relative (H's reconstruction error is relative to its largest pixels)."""
    rng = np.random.default_rng(100 * n + 10 * m + L)
    g = rng.uniform(0.1, 1, (1 << n, 1 << n))
    h = rng.uniform(0.1, 1, (7, 1 << m, 1 << m))
    G, H = haar.forward(g), haar.forward(h).astype(np.float32)
    if 8 * 4 ** max(m, L) > device.device.local_mem_size:   # this device's limit: refused in one line
        with pytest.raises(ArgumentError, match="do not fit the device's local memory"):
            haar.ProductPyramids(G, m, levels=L)
        return
    out = haar.ProductPyramids(G, m, levels=L)(H)
    ref = haar.product_scaling(G, H.astype(np.float64), L)
    assert out.shape == (7, tree_size(L)) and out.dtype == np.float32
    np.testing.assert_allclose(out, ref, rtol=16 * (n + m + 2) * EPS32)
    P = max(m, L)
    if P == L:  # additive in float32, exactly as HaarTree builds it from the leaves
        np.testing.assert_array_equal(out, HaarTree(out[:, level_offset(L):].reshape(7, 1 << L, 1 << L)).nodes())
    # on the device (enqueue) the trees are in the warp's Morton order; __call__ returns them row-major
    pp = haar.ProductPyramids(G, m, levels=L)
    buf = cl.empty(4 * 7 * pp.stride)
    pp.enqueue(cl.thread_queue(), cl.to_device(np.ascontiguousarray(H)), 7, buf)
    np.testing.assert_array_equal(cl.read(buf, (7, pp.stride), np.float32, cl.thread_queue()), device_order(out, L))


def test_product_kernel_sparse_light_and_clamp(device):
    """A compressed light and compressed BRDFs: eq. 25 on the reconstructions; with
    ``nonnegative`` the ringing below zero is clamped in the leaves, still additive."""
    rng = np.random.default_rng(27)
    G = haar.compress_energy(haar.forward(rng.random((64, 64)) ** 8), 0.8)
    H = np.stack([haar.compress_topk(haar.forward(rng.random((16, 16)) ** 4), 12).to_dense()
                  for _ in range(6)]).astype(np.float32)
    out = haar.ProductPyramids(G, 4)(H)
    ref = haar.product_scaling(G, H.astype(np.float64), 4)
    scale = box_sums(np.abs(recon(G, 6)) * np.abs(upsample(haar.inverse(H.astype(np.float64)), 6)))
    assert np.all(np.abs(out - ref) <= 16 * 12 * EPS32 * scale[:, :tree_size(4)])
    assert (ref < 0).any()  # the compressed product does ring below zero
    clamped = haar.ProductPyramids(G, 4, nonnegative=True)(H)
    assert (clamped >= 0).all()
    leaves = np.maximum(ref[:, level_offset(4):], 0).reshape(6, 16, 16)
    np.testing.assert_allclose(clamped, box_sums(leaves * 256), rtol=16 * 12 * EPS32, atol=1e-12)
    np.testing.assert_array_equal(clamped, HaarTree(clamped[:, level_offset(4):].reshape(6, 16, 16)).nodes())


def test_product_kernel_rejects_bad_input(device):
    G = haar.forward(np.ones((8, 8)))
    too_deep = next(p for p in range(1, 32) if 8 * 4 ** p > device.device.local_mem_size)   # this device's limit
    with pytest.raises(ValueError):
        haar.ProductPyramids(G, too_deep)
    with pytest.raises(ValueError):
        haar.ProductPyramids(G, 2, levels=4)
    with pytest.raises(ValueError):
        haar.ProductPyramids(G, 2)(np.zeros((3, 8, 8)))


@pytest.mark.parametrize("n", [0, 1, 4, 6])
def test_texel_values_are_the_inverse_at_those_texels(n):
    """texel_values reads 3n + 1 coefficients per texel; it equals the whole inverse there."""
    rng = np.random.default_rng(40 + n)
    c = rng.normal(size=(4, 1 << n, 1 << n))
    img = haar.inverse(c)
    which, x, y = rng.integers(0, 4, 500), rng.integers(0, 1 << n, 500), rng.integers(0, 1 << n, 500)
    np.testing.assert_allclose(haar.texel_values(c, which, x, y), img[which, y, x], rtol=1e-12, atol=1e-12)
    with pytest.raises(ArgumentError):
        haar.texel_values(c[0], [0], [0], [0])
