"""wavlight.sampler: stratified pixel-sample uniforms (drawn in the kernels; here through
their numpy twin rng.Stream, which tests/test_rng.py and tests/test_shading.py check
against the kernels).

What the sampler promises (module doc): every number in [0, 1); each sample uniform on
the square by itself (so estimators stay unbiased); within a pixel and a pair the k
samples occupy k distinct cells of the m x n grid (one per cell when k = m n); pairs
independent of each other. Then end to end: the white furnace with the stratified
sampler equals the albedo within the reported (conservative) standard error, and
stratification lowers the error of a smooth image (the reason it exists).
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

import wavlight
from wavlight import rng, sampler
from scenes_util import check_estimates, load, write_env


def _cells(u, k):
    m, n = sampler.grid(k)
    return np.floor(u[..., 0] * m).astype(int) + m * np.floor(u[..., 1] * n).astype(int), m * n


def _stratified(seed, pixels, k):
    """(pixels k, 6) float32: the stratified sampler's six numbers per sample (jitter, guide
    pair, BSDF pair) for one pass of `pixels` pixels of k samples, as the kernels draw them."""
    stream = rng.Stream(seed, 3, 1000, k)
    return np.concatenate([stream.uniforms(rng.JITTER, pixels * k)[:, :2],
                           stream.uniforms(rng.SHADING, pixels * k)], axis=1)


@pytest.mark.parametrize("length", list(range(1, 70)) + [255, 256, 257, 1024])
def test_permute_is_a_permutation(length):
    """Every key gives a bijection of 0 .. length - 1, including keys near 2^32 (where a final
    (i + key) % length without reduction would wrap and collide)."""
    keys = np.random.default_rng(length).integers(0, 2 ** 32, 64, dtype=np.uint64).astype(np.uint32)
    keys[:3] = [0, 0xFFFFFFFF, 0xFFFFFFFE]
    got = sampler.permute(np.tile(np.arange(length, dtype=np.uint32), (64, 1)), length, keys[:, None])
    np.testing.assert_array_equal(np.sort(got, axis=1), np.broadcast_to(np.arange(length), got.shape))


@pytest.mark.parametrize("k", [1, 2, 10, 16, 17, 64])
def test_stratified_cells_are_distinct_per_pixel_and_pair(k):
    pixels = 500
    u = _stratified(k, pixels, k)
    assert u.shape == (pixels * k, 6) and u.dtype == np.float32
    assert np.all(u >= 0) and np.all(u < 1)
    m, n = sampler.grid(k)
    for pair in range(3):
        v = u[:, 2 * pair:2 * pair + 2].reshape(pixels, k, 2).astype(np.float64)
        cells, total = _cells(v, k)
        assert total >= k
        # float32 rounding of (cell + u) / m may put a point that lies within a rounding
        # error of its cell's edge onto the edge (u > 1 - 2^-22 rounds 6 + u up to 7): such
        # points (a few in 10^5) belong to either cell; every other sample's cell is its own
        edge = np.minimum(np.abs(v[..., 0] * m - np.round(v[..., 0] * m)),
                          np.abs(v[..., 1] * n - np.round(v[..., 1] * n))) < 1e-5
        assert edge.mean() < 1e-3
        cells = np.where(edge, -1 - np.arange(cells.size).reshape(cells.shape), cells)
        srt = np.sort(cells, axis=1)
        assert np.all(np.diff(srt, axis=1) > 0), "two samples of a pixel share a cell"
        if total == k and not edge.any():  # a full grid: every cell exactly once
            assert np.array_equal(srt, np.broadcast_to(np.arange(k), srt.shape))


@pytest.mark.parametrize("k", [3, 16])
def test_each_sample_is_uniform_on_its_own(k):
    """Sample j of every pixel, over 40000 pixels: a chi-square test against the uniform
    density on a 10 x 10 grid, for every j and pair (Sidak-corrected to 1 % overall)."""
    pixels = 40_000
    u = _stratified(7, pixels, k).reshape(pixels, k, 6)
    tests = k * 3
    alpha = 1 - (1 - 0.01) ** (1 / tests)
    for j in range(k):
        for pair in range(3):
            h, _, _ = np.histogram2d(u[:, j, 2 * pair], u[:, j, 2 * pair + 1], bins=10, range=[[0, 1], [0, 1]])
            p = stats.chisquare(h.ravel()).pvalue
            assert p > alpha, (j, pair, p)


@pytest.mark.parametrize("pairs", [(0, 1), (1, 2), (0, 2)])
def test_pairs_are_independent(pairs):
    """The cells of two pairs of the same sample: a chi-square test of independence on their
    contingency table (16 x 16 cells, 20000 pixels x 16 samples; Sidak over the three)."""
    pixels, k = 20_000, 16
    u = _stratified(11, pixels, k).reshape(pixels, k, 6)
    a, b = pairs
    c0, _ = _cells(u[..., 2 * a:2 * a + 2], k)
    c1, _ = _cells(u[..., 2 * b:2 * b + 2], k)
    table = np.zeros((16, 16))
    np.add.at(table, (c0.ravel(), c1.ravel()), 1)
    assert stats.chi2_contingency(table).pvalue > 1 - (1 - 0.01) ** (1 / 3)


@pytest.fixture(scope="module")
def white(tmp_path_factory):
    d = tmp_path_factory.mktemp("sampler")
    env = write_env(d, "white.exr", np.ones((4, 8, 3)))
    scene = load(d, render=dict(width=16, height=16, spp=16, seed=3),
                 camera=dict(eye=[0.0, 0.0, 3.0], target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0], fov_y=30.0),
                 environment=dict(file=env),
                 objects=[dict(shape="sphere", center=[0.0, 0.0, 0.0], radius=1.0, subdivisions=5,
                               material="m")],
                 materials={"m": dict(type="lambert", albedo=[0.6, 0.6, 0.6])})
    return scene


@pytest.mark.parametrize("strategy", ["uniform", "light", "mis", "wavelet"])
def test_stratified_white_furnace(white, strategy):
    """Unbiased: a lambert sphere under a constant environment of 1 returns the albedo, within
    the reported standard error (which stratification can only overestimate)."""
    r = wavlight.render_full(white, strategy=strategy, spp=16, sampler="stratified")
    assert r.stats["sampler"] == "stratified"
    centre = np.zeros((16, 16), bool)
    centre[5:11, 5:11] = True  # pixels entirely on the tessellated sphere
    check_estimates(r.image, r.stderr, np.full(3, 0.6), centre, 16, label=f"stratified/{strategy}")


def test_stratification_lowers_the_error_of_a_smooth_image(tmp_path):
    """A lambert quad under the procedural sky (smooth, no visibility) with `uniform` hemisphere
    sampling at 16 spp: the mean squared error against a 4096-spp reference, over 3 seeds, is
    at least 2x lower when stratified (for a smooth 2D integrand 16 jittered strata cut the
    variance by far more than that; a failure means the strata do not reach the estimator)."""
    scene = load(tmp_path, render=dict(width=12, height=12, spp=16, seed=1),
                 camera=dict(eye=[0.0, 2.0, 0.01], target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0], fov_y=20.0),
                 environment=dict(procedural="sky", sun_radiance=0.0),
                 objects=[dict(shape="quad", center=[0.0, 0.0, 0.0], normal=[0.0, 1.0, 0.0], size=4.0,
                               material="m")],
                 materials={"m": dict(type="lambert", albedo=[0.5, 0.5, 0.5])})
    ref = wavlight.render_full(scene, strategy="cosine", spp=4096, seed=99).image
    mse = {}
    for smp in ("independent", "stratified"):
        mse[smp] = np.mean([np.mean((wavlight.render_full(scene, strategy="uniform", spp=16, seed=s,
                                                          sampler=smp).image - ref) ** 2) for s in range(3)])
    assert mse["stratified"] * 2 < mse["independent"], mse


def test_unknown_sampler_is_a_one_line_error(white):
    with pytest.raises(wavlight.WavlightError, match=r"sampler must be one of independent \| stratified"):
        wavlight.render_full(white, spp=1, sampler="sobol")
