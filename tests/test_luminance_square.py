"""Environment.luminance_square: the light tree's leaf masses, the exact integral of
luminance over each leaf's solid angle, computed over the overlap bands only."""
import numpy as np
import pytest

from wavlight.envmap import LUMINANCE, Environment, luminance


def _dense(env, n):
    """The same integral as dense matrices: rows (leaf x texel overlap in cos theta) @ luminance
    @ columns (texel x leaf overlap in phi)."""
    side = 1 << n
    lum = luminance(env.pixels.astype(np.float64))  # as wavlight: float64 luminance of the float32 texels
    lt, tt = np.arange(side + 1) / side * np.pi, np.arange(env.height + 1) / env.height * np.pi
    lo, hi = np.maximum(lt[:-1, None], tt[None, :-1]), np.minimum(lt[1:, None], tt[None, 1:])
    rows = np.where(hi > lo, np.cos(lo) - np.cos(hi), 0.0)
    lp, tp = np.arange(side + 1) / side * 2 * np.pi, np.arange(env.width + 1) / env.width * 2 * np.pi
    cols = np.clip(np.minimum(lp[None, 1:], tp[1:, None]) - np.maximum(lp[None, :-1], tp[:-1, None]), 0, None)
    return rows @ lum @ cols


@pytest.mark.parametrize("shape", [(8, 16), (37, 50), (300, 700)])
@pytest.mark.parametrize("n", [1, 3, 6, 9])
def test_banded_equals_dense(shape, n):
    rng = np.random.default_rng(n)
    env = Environment((rng.random(shape + (3,)) ** 6 * 50).astype(np.float32))
    got, ref = env.luminance_square(n), _dense(env, n)
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-14 * ref.max())


def test_leaf_masses_by_quadrature():
    """Independent of both: midpoint quadrature in (phi, cos theta) over each leaf, 64 x 64 nodes,
    luminance of the texel under each node (exact but for nodes in cells cut by texel edges)."""
    rng = np.random.default_rng(2)
    env = Environment(rng.random((6, 10, 3)).astype(np.float32))
    n, q = 3, 64
    side = 1 << n
    lum = luminance(env.pixels.astype(np.float64))
    got = env.luminance_square(n)
    for y in range(side):
        z_hi, z_lo = np.cos(np.pi * y / side), np.cos(np.pi * (y + 1) / side)
        z = z_lo + (np.arange(q) + 0.5) / q * (z_hi - z_lo)
        rows = np.minimum((np.arccos(z) / np.pi * 6).astype(int), 5)
        for x in range(side):
            phi = 2 * np.pi * (x + (np.arange(q) + 0.5) / q) / side
            cols = np.minimum((phi / (2 * np.pi) * 10).astype(int), 9)
            quad = lum[rows[:, None], cols[None, :]].mean() * (z_hi - z_lo) * 2 * np.pi / side
            assert got[y, x] == pytest.approx(quad, rel=0.05)
    assert got.sum() == pytest.approx((_dense(env, 0)).sum(), rel=1e-12)


@pytest.mark.parametrize("shape", [(8, 16), (37, 50)])
def test_compensated_masses(shape):
    """compensated=True (MIS compensation): the integral of max(luminance - mean, 0), the mean
    over the sphere taken from the uncompensated masses (their sum / 4 pi); a map without texels
    above its mean (a constant one) gives the integral of 1, uniform in solid angle."""
    rng = np.random.default_rng(7)
    env = Environment((rng.random(shape + (3,)) ** 6 * 50).astype(np.float32))
    mean = _dense(env, 0).sum() / (4 * np.pi)
    above = np.maximum(luminance(env.pixels.astype(np.float64)) - mean, 0.0)
    want = _dense(Environment(np.repeat(above.reshape(shape)[..., None], 3, axis=2) / LUMINANCE.sum()), 4)
    got = env.luminance_square(4, compensated=True)
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-9 * want.max())
    assert np.all(got <= env.luminance_square(4) + 1e-12) and (above == 0).any() and got.sum() > 0
    const = Environment(np.full(shape + (3,), 2.0, np.float32))
    np.testing.assert_allclose(const.luminance_square(3, compensated=True),
                               _dense(Environment(np.ones(shape + (3,), np.float32)), 3) / LUMINANCE.sum(),
                               rtol=1e-6)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_luminance_is_the_weighted_sum(dtype):
    """envmap.luminance: the LUMINANCE-weighted sum over the last axis, in the colours' float
    type and shape (elementwise, without BLAS), equal to the matrix product within rounding."""
    rng = np.random.default_rng(11)
    rgb = (rng.random((5, 7, 3)) * 100).astype(dtype)
    got = luminance(rgb)
    assert got.shape == (5, 7) and got.dtype == dtype
    want = rgb.astype(np.float64) @ LUMINANCE.astype(np.float64)
    np.testing.assert_allclose(got, want, rtol=4 * np.finfo(dtype).eps)


def _tv(env, n):
    """Total variation between the full-depth leaf distribution and its depth-n blocks taken as
    constant (Environment.light_levels' definition), from luminance_square at both depths."""
    top = env.square_levels()
    full = env.luminance_square(top)
    k = 1 << (top - n)
    coarse = np.kron(env.luminance_square(n), np.ones((k, k))) / (k * k)   # spread over its fine leaves
    return 0.5 * np.abs(full - coarse).sum() / full.sum()


def test_light_levels_follow_the_content():
    """The light tree's depth is the smallest n >= 2 within the tolerance (checked against the
    TV computed here from luminance_square at each depth): a smooth sky needs fewer levels
    than the same sky with one tiny, bright texel (a sun), which needs every level."""
    h, w = 64, 128
    theta = (np.arange(h) + 0.5) / h * np.pi
    smooth = np.broadcast_to((1.0 + 0.5 * np.cos(theta))[:, None, None], (h, w, 3)).astype(np.float32).copy()
    sun = smooth.copy()
    sun[20, 77] = 1e5
    top = Environment(smooth).square_levels()
    assert top == 7
    chosen = {}
    for name, px in (("smooth", smooth), ("sun", sun)):
        env = Environment(px)
        n, tv = env.light_levels()
        assert tv == pytest.approx(_tv(env, n), rel=1e-4) if n < top else tv == 0.0   # (its tree is float32)
        assert n == top or tv <= 0.01
        assert n == 2 or _tv(env, n - 1) > 0.01
        chosen[name] = n
        for m in (2, 4, top - 1, top, top + 1):   # the measure also for a depth set by hand
            assert env.tree_tv(m) == pytest.approx(_tv(env, min(m, top)), rel=1e-4, abs=1e-12)
    assert chosen["smooth"] < chosen["sun"] == top, chosen
