"""Error metrics of rendered images against a reference (numpy; the single implementation).

Notation: ``x`` an image (H, W, 3), ``r`` the reference, ``s`` the reference's
per-pixel standard error (``RenderResult.stderr``: sample standard deviation / sqrt(spp)),
``N`` the number of values (pixels x channels), ``x_1 .. x_R`` the repetitions of one
run (same settings, seeds 0..R-1), ``eps = 1e-2``. Means run over pixels and channels.

- ``mse(x, r, s)``      = mean((x - r)^2 - s^2)
- ``relmse(x, r, s)``   = mean(((x - r)^2 - s^2) / (r^2 + eps))
  Without ``s`` the ``- s^2`` term is left out. With it, the reference's own noise is
  subtracted: if ``r = mu + d`` with E[d] = 0, Var d = sigma_r^2, and ``x`` is independent
  of ``r``, then E[(x - r)^2] = E[(x - mu)^2] + sigma_r^2, and s^2 is an unbiased estimate
  of sigma_r^2 (the sample variance over the reference's spp, divided by spp). So
  ``mse`` is an unbiased estimate of the error against the true image ``mu``; ``relmse``
  is too, up to the noise of its denominator r^2 + eps (a relative bias of order
  s^2 / r^2, small for any reference worth the name). The corrected value can be
  slightly negative when x is much closer to mu than r is. eps keeps dark pixels from
  dominating (as in benchmarks/relmse.py and the rendering literature).
- ``pixel_variance([x_k])`` = per-pixel sample variance over the repetitions (ddof 1),
  shape (H, W, 3); :func:`mean_variance` and :func:`relative_variance` summarise it as
  mean(var) and mean(var / (r^2 + eps)).
- ``bias([x_k], r, s)`` = mean(xbar - r) with xbar the per-pixel mean over repetitions:
  the signed error of the image's average, 0 in expectation for an unbiased estimator.
  Its standard error assumes independent pixels (each pixel's samples are independent
  in wavlight's integrator): SE^2 = mean(var) / (R N) + sum(s^2) / N^2, the variance of
  the mean of xbar (from the spread over repetitions, so R >= 2; else None) plus that
  of the mean of r (when s is given). For heavy-tailed estimators (bsdf sampling of a
  tiny sun) low-spp repetitions usually miss the rare huge samples, so both their mean
  and their spread come out too low: bias / SE is then no z-score.
- ``max_error(x, r)`` = max |x - r| over pixels and channels (fireflies);
  ``relative=True``: max |x - r| / sqrt(r^2 + eps), the largest term of relMSE's root.
- ``error_map(x, r)`` = sqrt(mean over channels of (x - r)^2 / (r^2 + eps)), (H, W): the
  per-pixel relative error shown in the experiment's false-colour maps.

All functions accept float32 or float64 arrays and compute in float64.
"""
from __future__ import annotations

import math

import numpy as np

from ..errors import ArgumentError

EPS = 1e-2


def _pair(x, ref):
    x = np.asarray(x, np.float64)
    ref = np.asarray(ref, np.float64)
    if x.shape != ref.shape:
        raise ArgumentError(f"image shape {x.shape} differs from reference shape {ref.shape}")
    return x, ref


def _se2(ref_stderr, shape):
    if ref_stderr is None:
        return 0.0
    s = np.asarray(ref_stderr, np.float64)
    if s.shape != shape:
        raise ArgumentError(f"reference stderr shape {s.shape} differs from reference shape {shape}")
    if not np.all(np.isfinite(s)):
        raise ArgumentError("reference stderr is not finite (a 1-spp reference has none)")
    return s * s


def _stack(images):
    x = np.asarray(images, np.float64)
    if x.ndim < 2 or x.shape[0] < 1:
        raise ArgumentError("expected a stack of repetitions (R, H, W, 3) with R >= 1")
    return x


def mse(x, ref, ref_stderr=None) -> float:
    """Mean squared error, minus the reference's own variance when its stderr is given."""
    x, ref = _pair(x, ref)
    return float(np.mean((x - ref) ** 2 - _se2(ref_stderr, ref.shape)))


def relmse(x, ref, ref_stderr=None, eps=EPS) -> float:
    """Relative MSE, mean(((x - r)^2 - s^2) / (r^2 + eps)); ``- s^2`` only with ``ref_stderr``."""
    x, ref = _pair(x, ref)
    return float(np.mean(((x - ref) ** 2 - _se2(ref_stderr, ref.shape)) / (ref * ref + eps)))


def pixel_variance(images) -> np.ndarray:
    """Per-pixel sample variance over repetitions (R, H, W, 3) -> (H, W, 3); needs R >= 2."""
    x = _stack(images)
    if x.shape[0] < 2:
        raise ArgumentError("the variance over repetitions needs at least 2 repetitions")
    return x.var(axis=0, ddof=1)


def mean_variance(images) -> float:
    """mean over pixels and channels of :func:`pixel_variance`."""
    return float(np.mean(pixel_variance(images)))


def relative_variance(images, ref, eps=EPS) -> float:
    """mean(var / (r^2 + eps)): the variance part of relMSE."""
    var = pixel_variance(images)
    ref = np.asarray(ref, np.float64)
    if var.shape != ref.shape:
        raise ArgumentError(f"image shape {var.shape} differs from reference shape {ref.shape}")
    return float(np.mean(var / (ref * ref + eps)))


def bias(images, ref, ref_stderr=None) -> tuple[float, float | None]:
    """(mean(xbar - r), its standard error) over repetitions (R, H, W, 3); SE None when R < 2."""
    x = _stack(images)
    ref = np.asarray(ref, np.float64)
    if x.shape[1:] != ref.shape:
        raise ArgumentError(f"image shape {x.shape[1:]} differs from reference shape {ref.shape}")
    n = ref.size
    value = float(np.mean(x.mean(axis=0) - ref))
    if x.shape[0] < 2:
        return value, None
    var_mean = float(np.mean(x.var(axis=0, ddof=1))) / (x.shape[0] * n)
    var_ref = float(np.sum(_se2(ref_stderr, ref.shape))) / (n * n)
    return value, math.sqrt(var_mean + var_ref)


def max_error(x, ref, relative=False, eps=EPS) -> float:
    """Largest |x - r| over pixels and channels; ``relative``: largest |x - r| / sqrt(r^2 + eps)."""
    x, ref = _pair(x, ref)
    err = np.abs(x - ref)
    if relative:
        err = err / np.sqrt(ref * ref + eps)
    return float(err.max()) if err.size else 0.0


def error_map(x, ref, eps=EPS) -> np.ndarray:
    """Per-pixel relative error sqrt(mean_c (x - r)^2 / (r^2 + eps)), shape (H, W)."""
    x, ref = _pair(x, ref)
    return np.sqrt(np.mean((x - ref) ** 2 / (ref * ref + eps), axis=-1))
