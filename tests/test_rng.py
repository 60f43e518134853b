"""The independent sampler's counter-based numbers (wavlight/rng.py, kernels/rng.h).

Philox-4x32-10 against Random123's published known-answer vectors
(DEShawResearch/random123, tests/kat_vectors, the three "philox4x32 10" lines);
the kernels' draws against the numpy twin; and a chi-square check that the floats
are uniform and pairwise independent in the pairs the renderer uses.
"""
import numpy as np
import pytest
from scipy import stats

import wavlight
from wavlight import camera, rng

KAT = [  # counter (4 words), key (2 words), result (4 words)
    ((0, 0, 0, 0), (0, 0), (0x6627E8D5, 0xE169C58D, 0xBC57AC4C, 0x9B00DBD8)),
    ((0xFFFFFFFF,) * 4, (0xFFFFFFFF,) * 2, (0x408F276D, 0x41C83B0E, 0xA20BC7C6, 0x6D5451FD)),
    ((0x243F6A88, 0x85A308D3, 0x13198A2E, 0x03707344), (0xA4093822, 0x299F31D0),
     (0xD16CFE09, 0x94FDCCEB, 0x5001E420, 0x24126EA1)),
]


@pytest.mark.parametrize("counter, key, expected", KAT)
def test_philox_known_answers(counter, key, expected):
    got = rng.philox4x32_10(np.array([counter], np.uint32), key)[0]
    assert [int(x) for x in got] == list(expected)


def test_uniforms_in_unit_interval_and_distinct_streams():
    a = rng.uniforms(7, 3, rng.JITTER, 0, 4096)
    b = rng.uniforms(7, 3, rng.SHADING, 0, 4096)
    c = rng.uniforms(7, 4, rng.JITTER, 0, 4096)
    d = rng.uniforms(8, 3, rng.JITTER, 0, 4096)
    assert a.dtype == np.float32 and (a >= 0).all() and (a < 1).all()
    for other in (b, c, d):
        assert np.mean(a == other) < 1e-3
    # a pass's numbers are the same whatever the pass boundaries
    np.testing.assert_array_equal(rng.uniforms(7, 3, rng.JITTER, 1000, 96), a[1000:1096])
    # high seed bits reach the key
    assert np.mean(rng.uniforms(1 << 40, 0, 0, 0, 256) == rng.uniforms(0, 0, 0, 0, 256)) < 1e-2


PAIRS = [(0, 1), (2, 3), (0, 2), (1, 3)]


@pytest.mark.parametrize("pair", PAIRS)
def test_uniform_pairs_chi_square(pair):
    """2^20 samples of one stream: the 2D histogram of two words on 32 x 32 cells is uniform
    (Pearson's chi-square, Sidak-corrected 1% over this file's tests)."""
    u = rng.uniforms(1234, 5, rng.SHADING, 0, 1 << 20)
    h, _, _ = np.histogram2d(u[:, pair[0]], u[:, pair[1]], bins=32, range=[[0, 1], [0, 1]])
    p = stats.chisquare(h.ravel()).pvalue
    assert p > 1 - (1 - 0.01) ** (1 / (len(PAIRS) + 1))


def test_consecutive_samples_chi_square():
    """Neighbouring sample indices (the eight lanes of a work-item) are independent."""
    u = rng.uniforms(99, 0, rng.JITTER, 0, (1 << 20) + 1)[:, 0]
    h, _, _ = np.histogram2d(u[:-1], u[1:], bins=32, range=[[0, 1], [0, 1]])
    p = stats.chisquare(h.ravel()).pvalue
    assert p > 1 - (1 - 0.01) ** (1 / (len(PAIRS) + 1))


@pytest.mark.parametrize("stratified", [False, True], ids=["independent", "stratified"])
@pytest.mark.parametrize("tile, first, side, k", [(0, 0, 8, 16), (37, 4096, 5, 3)])
def test_camera_kernel_matches_numpy(tile, first, side, k, stratified):
    """kernels/camera.cl (Philox jitters drawn in the kernel, stratified per pixel or not)
    against camera.camera_rays with rng.Stream's numbers; a tile whose ray count is not a
    multiple of 8 exercises the partial lanes."""
    scene = wavlight.load_scene("scenes/default.toml")
    got = camera.pass_rays(scene, 320, 240, 11, tile, 100, 60, side, side + 1, k, first, stratified=stratified)
    ref = camera.pass_rays(scene, 320, 240, 11, tile, 100, 60, side, side + 1, k, first, kernel=False,
                           stratified=stratified)
    assert got.shape == ref.shape == (side * (side + 1) * k, 3)
    np.testing.assert_allclose(got, ref, atol=2e-6)


def test_camera_pass_size_is_bounded():
    """The kernels find a ray's pixel by one float division, exact below 2^22 rays per pass
    (kernels/rng.h div_small): a larger pass is refused, not silently mis-assigned."""
    scene = wavlight.load_scene("scenes/default.toml")
    with pytest.raises(ValueError, match="at most"):
        camera.pass_rays(scene, 4096, 4096, 1, 0, 0, 0, 2048, 2048, 1, 0)
