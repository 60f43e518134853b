"""The relit frame's fast paths (wavlight.relight.frame, lighting.select_terms): each against
its definition on inputs made to hit its edge cases; the kernels against their numpy twins."""
from __future__ import annotations

import numpy as np
import pytest

from wavlight import haar
from wavlight.relight import lighting


def select_by_sort(coeffs, terms, kind, rms=None):
    """The definition: the first K of the coefficients sorted by (-priority, index)."""
    p = lighting.priority(coeffs, kind, rms)
    k = min(terms, int(np.count_nonzero(p)))
    return np.sort(np.lexsort((np.arange(p.size), -p))[:max(k, 0)]).astype(np.int64)


@pytest.mark.parametrize("kind", lighting.PRIORITIES)
def test_select_terms_equals_the_sort(kind):
    """The partition keeps the same set as a full sort, ties (many equal priorities, zeros)
    included."""
    rng = np.random.default_rng(11)
    cases = [haar.forward(rng.random((3, 16, 16))),
             haar.forward(np.round(rng.random((3, 16, 16)) * 3)),                # many equal coefficients
             np.where(rng.random((3, 16, 16)) < 0.7, 0.0, 1.0),                   # zeros and one value
             np.zeros((3, 16, 16))]
    rms = np.round(rng.random(256) * 4) / 4                                        # ties, and zeros
    for c in cases:
        for terms in (1, 5, 17, 64, 200, 256, 1000):
            np.testing.assert_array_equal(lighting.select_terms(c, terms, kind, rms), select_by_sort(c, terms, kind, rms))
