"""The loop of the unbiased frames over tiles and passes (wavlight.relight.tile_passes): the mean
and standard error of all the samples whatever the passes, the tiles' counts, progress, a failing
pass stopping the frame."""
from __future__ import annotations

import threading

import numpy as np
import pytest

from wavlight.relight.tile_passes import TileWork, pass_spp, run_tiles
from wavlight.relight.view_converge import Tile   # a view bake's tiles: index, x0, y0, w, h


WIDTH, HEIGHT = 7, 5
TILES = [Tile(0, 0, 0, 7, 2), Tile(1, 0, 2, 4, 3), Tile(2, 4, 2, 3, 3)]


def value(x, y, j):
    """(..., 3): sample j of pixel (x, y), a function of the three only."""
    base = np.sin(0.37 * (y * WIDTH + x) + 1.3 * j ** 1.5) + 2.0
    return np.stack([base, 2.0 * base, base * base], -1)


def work_of(per_pass: int, calls=None):
    def start(tile):
        return ("shared", tile.index), {"rays": tile.w * tile.h, "kept": tile.index % 2}

    def samples(state, tile, first, k):
        assert state == ("shared", tile.index)
        if calls is not None:
            calls.append((tile.index, first, k))
        p = np.arange(tile.w * tile.h)
        x, y = tile.x0 + p % tile.w, tile.y0 + p // tile.w
        j = first + np.arange(k)
        v = value(x[:, None], y[:, None], j[None, :]).reshape(-1, 3)   # pixel p's samples in rows p k ..
        return v, {"rays": len(v), "hits": k}

    return TileWork(start, samples, lambda pixels: pass_spp(99, pixels, per_pass, 1 << 16))


@pytest.mark.parametrize("per_pass", [1, 3, 64])
def test_the_mean_and_error_are_those_of_all_the_samples_whatever_the_passes(per_pass):
    spp = 10
    calls, seen = [], []
    lock = threading.Lock()

    def progress(done, tiles, rays, seconds):
        with lock:
            seen.append((done, tiles, rays))

    mean, err, totals = run_tiles(work_of(per_pass, calls), TILES, WIDTH, HEIGHT, spp, 2, progress)
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH]
    v = value(x[..., None], y[..., None], np.arange(spp)[None, None, :])          # (H, W, spp, 3)
    np.testing.assert_allclose(mean, v.mean(2), rtol=1e-12)
    np.testing.assert_allclose(err, v.std(2, ddof=1) / np.sqrt(spp), rtol=1e-9)
    # every sample once, in passes of at most per_pass per pixel
    for tile in TILES:
        passes = sorted((first, k) for index, first, k in calls if index == tile.index)
        assert [f for f, _ in passes] == list(range(0, spp, per_pass))
        assert sum(k for _, k in passes) == spp and max(k for _, k in passes) <= per_pass
    pixels = WIDTH * HEIGHT
    assert totals == {"rays": pixels + pixels * spp, "done": 3, "kept": 1, "hits": len(TILES) * spp}
    assert sorted(d for d, _, _ in seen) == [1, 2, 3] and all(t == 3 for _, t, _ in seen)
    assert max(r for _, _, r in seen) == totals["rays"]


def test_a_single_sample_has_no_error():
    mean, err, _ = run_tiles(work_of(4), TILES, WIDTH, HEIGHT, 1, 1)
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH]
    np.testing.assert_allclose(mean, value(x, y, 0))
    assert np.isinf(err).all()


def test_pass_spp_bounds_the_samples_of_a_pass():
    assert pass_spp(16, 100, 64, 1 << 16) == 16
    assert pass_spp(1000, 100, 64, 1 << 16) == 64
    assert pass_spp(1000, 4096, 64, 1 << 16) == 16
    assert pass_spp(1000, 1 << 20, 64, 1 << 16) == 1


def test_a_failing_pass_stops_the_frame():
    base = work_of(1)
    calls = []

    def samples(state, tile, first, k):
        calls.append(first)
        if tile.index == 0 and first == 2:
            raise RuntimeError("pass failed")
        return base.samples(state, tile, first, k)

    with pytest.raises(RuntimeError, match="pass failed"):
        run_tiles(TileWork(base.start, samples, base.pass_spp), TILES, WIDTH, HEIGHT, 1000, 2)
    assert len(calls) < 3 * 1000   # the other tiles stopped at their next pass
