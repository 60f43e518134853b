"""Progressive refinement (wavlight.relight.progressive): passes merged into a running mean whose
mean and standard error are those of all the samples at once, whatever the split; the relative
error's definition; the passes' schedule. And the factor's type chosen from the bake file
(wavlight.relight.frames.frames_for)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from wavlight.relight.mixture import mean_and_error
from wavlight.relight.progressive import LIT_FRACTION, PassSchedule, RunningMean, relative_error


def _pass(samples):
    """(mean, standard error, n) of samples (n, H, W, 3), as a frame reports them."""
    n = len(samples)
    mean, err = mean_and_error(samples.sum(0), (samples ** 2).sum(0), n)
    return mean, err, n


@pytest.mark.parametrize("split", [(2, 4, 8, 16), (1, 1, 1, 3, 24), (30,), (1, 29)])
def test_passes_merge_into_the_mean_and_error_of_all_samples(split):
    rng = np.random.default_rng(7)
    samples = rng.gamma(0.5, 2.0, (sum(split), 4, 5, 3))
    run = RunningMean()
    first = 0
    for n in split:
        run.add(*_pass(samples[first:first + n]))
        first += n
    mean, err, n = _pass(samples)
    assert run.spp == n and run.passes == len(split)
    np.testing.assert_allclose(run.mean, mean, rtol=1e-12)
    np.testing.assert_allclose(run.stderr, err, rtol=1e-9)


def test_a_single_sample_has_no_error_and_the_next_pass_gives_it():
    run = RunningMean()
    run.add(np.full((2, 2, 3), 1.0), np.full((2, 2, 3), np.inf), 1)
    assert np.isinf(run.stderr).all() and run.relative_error() is None
    run.add(np.full((2, 2, 3), 3.0), np.full((2, 2, 3), np.inf), 1)
    # two samples, 1 and 3: mean 2, sample variance 2, standard error 1
    np.testing.assert_allclose(run.mean, 2.0)
    np.testing.assert_allclose(run.stderr, 1.0)
    assert run.relative_error() == pytest.approx(0.5)


def test_relative_error_is_the_mean_over_lit_pixels_of_luminance_ratios():
    mean = np.zeros((2, 2, 3))
    mean[0, 0], mean[0, 1], mean[1, 0] = 1.0, 4.0, 1e-9     # (1, 1) black: not lit; (1, 0) below the fraction
    err = np.zeros((2, 2, 3))
    err[0, 0], err[0, 1], err[1, 0], err[1, 1] = 0.1, 0.2, 5.0, np.inf
    level = 5.0 / 4 / 1.0    # the image's mean luminance (grey pixels: Y = the value)
    assert 1e-9 < LIT_FRACTION * level < 1.0
    assert relative_error(mean, err) == pytest.approx((0.1 / 1.0 + 0.2 / 4.0) / 2, rel=1e-6)
    assert relative_error(np.zeros((2, 2, 3)), err) is None


def test_the_schedule_doubles_while_passes_are_short_and_ends_at_the_total():
    s = PassSchedule(first=2, grow_seconds=1.0, most=16, total=100)
    spp = []
    for seconds in (0.1, 0.1, 2.0, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1):
        if s.done():
            break
        spp.append(s.spp)
        s.after(seconds)
    # as many as all before, at most twice the last: 2, 2, 4, then 4 after a slow pass, 8, 16 (the cap)
    assert spp[:6] == [2, 2, 4, 4, 8, 16] and sum(spp) == 100 and s.done()


def test_frames_for_chooses_the_type_of_the_factor_once(device, tmp_path):
    import wavlight
    from wavlight.relight.frames import LightingFrames, frames_for

    scene = Path(__file__).resolve().parents[2] / "scenes" / "spot_ggx.toml"
    t = wavlight.bake(str(scene), output=str(tmp_path / "s.wlt"), width=16, height=16, spp=1, levels=3, terms=16)
    try:
        frames = frames_for(t)
        assert isinstance(frames, LightingFrames) and t.varies == "lighting"
        state = frames.state_from({"rotate_y": 30.0})
        image, stats = frames.frame(state)
        np.testing.assert_array_equal(image, t.frame(None, 30.0))
        assert [s["rotate_y"] for s in frames.turn(state, 4)] == [30.0, 120.0, 210.0, 300.0]
        with pytest.raises(wavlight.WavlightError, match="varies the lighting.*--translate"):
            LightingFrames.refuse_held(t.path, {"translate": (0.0, 0.0, 0.0)})
    finally:
        t.close()
