"""Progressive refinement of an unbiased frame: passes of a few samples per pixel, each with a
seed of its own, merged into a running mean whose per-pixel standard error is that of all the
samples taken (Chen & Gao eq. 12's estimator is a mean of independent samples: a mean of more
of them is the same estimator at more spp).

    run = RunningMean()
    for seed, spp in enumerate(schedule):        # PassSchedule: 2, 2, 4, 8, ... spp per pass
        result = frames.converge(state, spp, seed)
        run.add(result.image, result.stderr, spp)
        show(run.mean, run.spp, run.relative_error())

Merging (:meth:`RunningMean.add`). A pass of n_k samples per pixel reports its mean m_k and its
standard error e_k; its sum of squared deviations is M2_k = n_k (n_k - 1) e_k^2 (0 for a single
sample, whose error is unknown). Two sets merge exactly (Chan, Golub & LeVeque 1979):
n = n_a + n_b, delta = m_b - m_a, m = m_a + delta n_b / n, M2 = M2_a + M2_b + delta^2 n_a n_b / n;
the mean's standard error is sqrt(M2 / ((n - 1) n)). This is the mean and the standard error
one pass of all n samples would report (the same sample variance), whatever the split: a first
pass of 1 spp gets its error from the second.

The relative error shown (:func:`relative_error`): over the lit pixels, the mean of
Y(e_p) / Y(m_p), Y the luminance (wavlight.envmap.LUMINANCE weights) of the pixel's mean m_p and of
its per-channel standard errors e_p (Y(e_p) bounds the standard error of Y(m_p) from above);
a pixel is lit where Y(m_p) > LIT_FRACTION times the image's mean luminance and its error is
finite. None while no pixel is lit or every error is unknown (a single sample).

Schedule (:class:`PassSchedule`): the first pass takes FIRST_SPP samples per pixel, and each
next pass as many as all the passes before it, at most twice the last, while the last pass took
less than GROW_SECONDS (else as many as the last): 2, 2, 4, 8, 16, ..., so that the samples taken
double with each pass (the error falls by sqrt(2) a pass: 64 spp after six passes and 64 spp of
work, where passes of 2, 4, 8, ... would pass it only after 126), the fixed cost of a pass is
paid over more samples as the image converges, and the page gets a new picture at least every
few seconds; at most MAX_PASS_SPP a pass; refinement ends at MAX_SPP samples in all.
"""
from __future__ import annotations

import numpy as np

from ..envmap import LUMINANCE

#: a pixel counts towards the relative error where its mean luminance is above this fraction of
#: the image's mean luminance (a black background's relative error is not defined)
LIT_FRACTION = 1e-3
#: the passes' samples per pixel: the first pass's, then as many as all before (at most twice the
#: last) while a pass takes less than GROW_SECONDS, at most MAX_PASS_SPP per pass; MAX_SPP in all
FIRST_SPP = 2
GROW_SECONDS = 1.0
MAX_PASS_SPP = 64
MAX_SPP = 1 << 16


class RunningMean:
    """The mean and standard error of all the samples of the passes added (module docstring):
    ``mean``, ``stderr`` (H, W, 3) float64, ``spp`` (the samples per pixel taken), ``passes``."""

    def __init__(self):
        self.mean = self._m2 = None
        self.spp = self.passes = 0

    def add(self, mean, stderr, spp: int) -> None:
        """Merge a pass of ``spp`` samples per pixel with its per-pixel mean and standard error."""
        spp = int(spp)
        if spp < 1:
            raise ValueError(f"a pass of {spp} samples per pixel")
        m = np.asarray(mean, np.float64)
        if spp > 1:
            e = np.asarray(stderr, np.float64)
            m2 = spp * (spp - 1) * np.where(np.isfinite(e), e, 0.0) ** 2
        else:
            m2 = np.zeros_like(m)
        if self.mean is None:
            self.mean, self._m2 = m.copy(), m2
        else:
            n_a, n = self.spp, self.spp + spp
            delta = m - self.mean
            self.mean += delta * (spp / n)
            self._m2 += m2 + delta * delta * (n_a * spp / n)
        self.spp += spp
        self.passes += 1

    @property
    def stderr(self) -> np.ndarray:
        """The mean's per-pixel standard error (inf with a single sample per pixel)."""
        if self.spp < 2:
            return np.full_like(self.mean, np.inf)
        return np.sqrt(np.maximum(self._m2, 0.0) / ((self.spp - 1) * self.spp))

    def relative_error(self):
        """:func:`relative_error` of the running mean and its standard error."""
        return None if self.mean is None or self.spp < 2 else relative_error(self.mean, self.stderr)


def relative_error(mean, stderr):
    """The image's estimated relative error (module docstring): the mean over the lit pixels of
    Y(stderr) / Y(mean); None where no pixel is lit with a finite error."""
    w = np.asarray(LUMINANCE, np.float64)
    y = np.asarray(mean, np.float64) @ w
    ey = np.asarray(stderr, np.float64) @ w
    level = float(y.mean()) if y.size else 0.0
    lit = (y > LIT_FRACTION * level) & np.isfinite(ey) & (level > 0)
    if not lit.any():
        return None
    return float(np.mean(ey[lit] / y[lit]))


class PassSchedule:
    """The samples per pixel of each pass (module docstring): ``spp`` the next pass's, ``done()``
    once MAX_SPP are taken in all; ``after(seconds)`` records how long the last pass took."""

    def __init__(self, first: int = FIRST_SPP, grow_seconds: float = GROW_SECONDS, most: int = MAX_PASS_SPP,
                 total: int = MAX_SPP):
        self.spp, self.grow_seconds, self.most, self.total = int(first), float(grow_seconds), int(most), int(total)
        self.taken = 0

    def done(self) -> bool:
        return self.taken >= self.total

    def after(self, seconds: float) -> None:
        """The pass of ``spp`` samples took ``seconds``: the next one's spp."""
        self.taken += self.spp
        if seconds < self.grow_seconds and self.spp < self.most:
            self.spp = min(self.most, 2 * self.spp, self.taken)
        self.spp = max(1, min(self.spp, self.total - self.taken)) if not self.done() else self.spp
