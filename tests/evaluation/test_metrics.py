"""wavlight.evaluation.metrics: known answers on hand-computable images, and the reference-variance correction.

The statistical checks draw a synthetic "true image" mu, images x = mu + noise and noisy
references (the mean of n samples, with their standard error as a renderer reports it), with a
fixed seed, and compare the mean of a metric over T trials with its expectation, within 4
standard errors of that mean. The corrected MSE is exactly unbiased; the corrected relMSE is
unbiased up to the noise of its denominator r^2 + eps (relative O(s^2 / r^2)): the cases keep
that well below the tolerance and check that the uncorrected metric is far outside it.
"""
from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

from wavlight.evaluation import metrics

REPO = Path(__file__).resolve().parents[2]


def img(*pixels):
    """A 1 x N image from N RGB triples (or scalars, repeated over the channels)."""
    return np.array([[p if np.ndim(p) else (p, p, p) for p in pixels]], np.float64)


# ----------------------------------------------------------------------------- known answers
def test_mse_and_relmse_known_answers():
    ref = img(1.0, 1.0)
    x = img(1.0, 3.0)
    assert metrics.mse(x, ref) == pytest.approx(2.0)                    # (0 + 4) / 2
    assert metrics.relmse(x, ref) == pytest.approx(2.0 / 1.01)          # 4 / (1 + 0.01) / 2
    assert metrics.relmse(img(0.5), img(0.0)) == pytest.approx(25.0)    # 0.25 / 0.01
    assert metrics.relmse(img(2.0), img(1.0), eps=0.0) == pytest.approx(1.0)
    assert metrics.mse(x, x) == 0.0 and metrics.relmse(x, x) == 0.0
    # channels count separately: error only in red
    assert metrics.mse(img((3.0, 1.0, 1.0)), img(1.0)) == pytest.approx(4.0 / 3)


def test_reference_variance_is_subtracted():
    ref, x, se = img(1.0, 1.0), img(3.0, 1.0), img(0.5, 0.5)
    assert metrics.mse(x, ref, se) == pytest.approx((4 - 0.25 + 0 - 0.25) / 2)
    assert metrics.relmse(x, ref, se) == pytest.approx((3.75 - 0.25) / 1.01 / 2)
    # an image equal to the reference scores minus the reference's variance (can be negative)
    assert metrics.relmse(ref, ref, se) == pytest.approx(-0.25 / 1.01)
    # float32 inputs give float64 arithmetic
    assert metrics.relmse(x.astype(np.float32), ref.astype(np.float32), se.astype(np.float32)) == \
        pytest.approx(metrics.relmse(x, ref, se), rel=1e-12)


def test_variance_over_repetitions():
    reps = np.stack([img(1.0, 2.0), img(3.0, 2.0)])
    var = metrics.pixel_variance(reps)
    assert var.shape == (1, 2, 3)
    assert np.allclose(var[0, 0], 2.0) and np.allclose(var[0, 1], 0.0)  # (1-3)^2 / 2, ddof 1
    assert metrics.mean_variance(reps) == pytest.approx(1.0)
    assert metrics.relative_variance(reps, img(1.0, 0.0)) == pytest.approx((2.0 / 1.01 + 0.0) / 2)
    with pytest.raises(ValueError, match="2 repetitions"):
        metrics.pixel_variance(reps[:1])


def test_bias_and_its_standard_error():
    ref = img(1.0, 2.0)
    reps = np.stack([ref + 1.0, ref + 3.0])            # every value +2 on average, variance 2
    b, se = metrics.bias(reps, ref)
    n = ref.size                                       # 6 values
    assert b == pytest.approx(2.0)
    assert se == pytest.approx(math.sqrt(2.0 / (2 * n)))
    s = np.full_like(ref, 0.3)                         # the reference's own noise adds sum(s^2)/n^2
    b, se = metrics.bias(reps, ref, s)
    assert se == pytest.approx(math.sqrt(2.0 / (2 * n) + 0.09 / n))
    b, se = metrics.bias(reps[:1], ref)                # one repetition: no spread, no SE
    assert b == pytest.approx(1.0) and se is None
    b, se = metrics.bias(np.stack([ref + 1.0, ref - 1.0]), ref)
    assert b == pytest.approx(0.0)


def test_max_error_finds_the_firefly():
    ref = img(1.0, 1.0, 0.0, 1.0)
    x = img(1.1, 0.9, (0.0, 0.0, 0.5), 1.0)
    assert metrics.max_error(x, ref) == pytest.approx(0.5)
    # relative: the firefly on a black pixel, 0.5 / sqrt(0 + 0.01) = 5
    assert metrics.max_error(x, ref, relative=True) == pytest.approx(5.0)


def test_error_map_per_pixel():
    ref = img(1.0, 0.0)
    x = img((3.0, 1.0, 1.0), 0.1)
    e = metrics.error_map(x, ref)
    assert e.shape == (1, 2)
    assert e[0, 0] == pytest.approx(math.sqrt(4.0 / 1.01 / 3))
    assert e[0, 1] == pytest.approx(1.0)               # sqrt(0.01 / 0.01)


def test_shape_and_stderr_checks():
    with pytest.raises(ValueError, match="shape"):
        metrics.mse(img(1.0), img(1.0, 2.0))
    with pytest.raises(ValueError, match="stderr shape"):
        metrics.relmse(img(1.0), img(1.0), img(0.1, 0.1))
    with pytest.raises(ValueError, match="not finite"):
        metrics.relmse(img(1.0), img(1.0), img(np.inf))


# ----------------------------------------------------------------------------- statistics
def _trials(seed, trials, sigma_x, ref_se, n_ref=16, shape=(24, 24, 3), lo=1.0, hi=3.0):
    """(mu, per-trial corrected, uncorrected and true-image values of a metric function)."""
    rng = np.random.default_rng(seed)
    mu = rng.uniform(lo, hi, shape)
    sample_sd = ref_se * math.sqrt(n_ref)
    for _ in range(trials):
        x = mu + sigma_x * rng.standard_normal(shape)
        samples = mu + sample_sd * rng.standard_normal((n_ref,) + shape)
        r = samples.mean(axis=0)
        s = samples.std(axis=0, ddof=1) / math.sqrt(n_ref)
        yield mu, x, r, s


def _mean_se(values):
    v = np.asarray(values)
    return v.mean(), v.std(ddof=1) / math.sqrt(len(v))


def test_corrected_mse_is_unbiased_against_the_true_image():
    expected = 0.1 ** 2                                # E (x - mu)^2
    corrected, raw = [], []
    for mu, x, r, s in _trials(1, 300, sigma_x=0.1, ref_se=0.1):
        corrected.append(metrics.mse(x, r, s))
        raw.append(metrics.mse(x, r))
    m, se = _mean_se(corrected)
    assert abs(m - expected) < 4 * se, (m, se, expected)
    m_raw, se_raw = _mean_se(raw)
    assert m_raw - expected > 20 * se_raw              # without correction: + ref_se^2 (2x here)


def test_corrected_relmse_of_a_noisy_reference_is_unbiased():
    # reference noise (se 0.05) adds 25% to the error of x (sd 0.1), but is small next to r ~ 1..3
    corrected, raw = [], []
    expected = None
    for mu, x, r, s in _trials(2, 200, sigma_x=0.1, ref_se=0.05):
        if expected is None:
            expected = float(np.mean(0.1 ** 2 / (mu * mu + metrics.EPS)))
        corrected.append(metrics.relmse(x, r, s))
        raw.append(metrics.relmse(x, r))
    m, se = _mean_se(corrected)
    assert abs(m - expected) < 4 * se, (m, se, expected)
    m_raw, se_raw = _mean_se(raw)
    assert (m_raw - expected) > 20 * se_raw, (m_raw, se_raw, expected)


def test_bias_of_an_unbiased_estimator_is_within_its_standard_error():
    rng = np.random.default_rng(3)
    mu = rng.uniform(0.5, 2.0, (16, 16, 3))
    z = []
    for _ in range(200):
        reps = mu + 0.3 * rng.standard_normal((3,) + mu.shape)
        samples = mu + 0.2 * rng.standard_normal((8,) + mu.shape)
        b, se = metrics.bias(reps, samples.mean(axis=0), samples.std(axis=0, ddof=1) / math.sqrt(8))
        z.append(b / se)
    z = np.asarray(z)
    # standardised bias: mean 0 and sd ~1 when the SE formula is right
    assert abs(z.mean()) < 4 / math.sqrt(len(z))
    assert 0.8 < z.std(ddof=1) < 1.2


# ----------------------------------------------------------------------------- one implementation
def test_relmse_benchmark_uses_the_library_metric():
    path = REPO / "benchmarks" / "relmse.py"
    spec = importlib.util.spec_from_file_location("relmse_bench", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.relmse is metrics.relmse
    assert "def rel_mse" not in path.read_text() and "def relmse" not in path.read_text()
