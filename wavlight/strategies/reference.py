"""The numpy twin of the ``shade`` kernel (kernels/shade.cl): every kernel strategy's
directions and unoccluded estimates for given shading points and uniforms."""
from __future__ import annotations

import numpy as np

from .base import HEURISTICS, Strategy, ShadingPoints, unoccluded
from .light import MisStrategy
from .wavelet import WaveletStrategy, ris_shade_reference


def shade_reference(strategy: Strategy, env, sp: ShadingPoints, u: np.ndarray, with_offset=False):
    """numpy twin of the ``shade`` kernel (kernels/shade.cl).

    u : (N, 4) uniforms; single strategies use u[:, :2], MIS draws its light sample
    from u[:, :2] (slot 0) and its bsdf sample from u[:, 2:] (slot 1).
    returns wi (N, 2, 3) world directions and value (N, 2, 3) unoccluded estimates, and with
    ``with_offset`` the part of the estimate without a shadow ray, offset (N, 3) (zero but
    for the wavelet resampling estimator's control variate, :func:`ris_shade_reference`).
    """
    if isinstance(strategy, WaveletStrategy) and strategy.candidates:
        return ris_shade_reference(strategy, env, sp, u, with_offset=with_offset)
    n = len(sp)
    wi = np.zeros((n, 2, 3))
    value = np.zeros((n, 2, 3))
    if isinstance(strategy, (MisStrategy, WaveletStrategy)):
        guide = strategy if isinstance(strategy, WaveletStrategy) else strategy.light
        pairs = ((0, guide, strategy.bsdf, u[:, :2]), (1, strategy.bsdf, guide, u[:, 2:4]))
        weight = HEURISTICS[strategy.heuristic]
        for slot, mine, other, uu in pairs:
            ds = mine.sample(sp, uu)
            w = weight(ds.pdf, other.pdf(sp, ds.wi_local, ds.wi_world))
            wi[:, slot], value[:, slot] = ds.wi_world, unoccluded(sp, env, ds, w)
    else:
        ds = strategy.sample(sp, u[:, :2])
        wi[:, 0], value[:, 0] = ds.wi_world, unoccluded(sp, env, ds, 1.0)
    return (wi, value, np.zeros((n, 3))) if with_offset else (wi, value)

