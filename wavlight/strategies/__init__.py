"""Direction sampling strategies for direct environment lighting.

Every strategy draws directions with an exact pdf per unit solid angle, and every
strategy that MIS combines can evaluate that pdf for any direction (``sir`` cannot:
its resampling weights replace the pdf). A pdf of 0 means "no sample": its
contribution is 0, never NaN.

| id        | draws wi from                                  | pdf                                   |
|-----------|------------------------------------------------|---------------------------------------|
| uniform   | the hemisphere about the shading normal        | 1 / 2 pi                              |
| cosine    | the hemisphere, cosine-weighted                | cos / pi                              |
| bsdf      | the BRDF (lambert cosine, phong lobe, ggx VNDF) | :mod:`wavlight.bsdfs`                 |
| light     | the environment: luminance x solid angle, by a | tree pdf on the lat-long square /     |
|           | hierarchical warp of a :class:`HaarTree`       | (2 pi^2 sin theta) (eq. 19-22)        |
| mis       | one light and one bsdf sample, power heuristic | both, weighted (Veach 1997)           |
| mis_comp  | as mis, the light tree of max(L - mean, 0)     | both, power heuristic (Karlik 2019)   |
| wavelet   | M candidates from the product walk (top-down   | RIS weights over both pdfs            |
|           | warp, :mod:`.product`) and the BSDF,           | (ris_shade_reference); M = 0: both,   |
|           | two resampled by f cos L; M = 0: one of each   | balance heuristic                     |
| sir       | M light candidates, N resampled by f cos L     | RIS weights (:mod:`.sir`)             |
| structured| strata of the map (k-center), one per stratum  | per stratum (:mod:`.structured`)      |

The ``mis`` estimator is Mitsuba 3's ``direct`` integrator with one emitter and one
BSDF sample: each sample's contribution f L cos V / p is weighted by
p_s^2 / (p_light^2 + p_bsdf^2) (the power heuristic). ``wavelet`` with candidates = 0 weights
by p_s / (p_product + p_bsdf) (the balance heuristic; :class:`WaveletStrategy` says why); with
candidates M >= 2 (by default chosen from the scene's shadows, AUTO_BUDGET) it resamples two
or four directions from M candidates (:func:`ris_shade_reference`).
"""
from __future__ import annotations

import inspect

from ..errors import ArgumentError, shown
from ..options import markdown_table
from ..sampler import SAMPLER
from .base import (HEURISTICS, DirectionSamples, ShadingPoints, Strategy, balance_heuristic,
                   power_heuristic)
from .light import LightStrategy, MisCompensatedStrategy, MisStrategy, tree_info
from .reference import shade_reference
from .simple import BsdfStrategy, CosineStrategy, UniformStrategy
from .sir import SirStrategy
from .structured import StructuredStrategy
from .wavelet import (AUTO_BUDGET, DEFAULT_CANDIDATES, DEFAULT_SLOTS, MAX_CANDIDATES, R2_FIXED,
                      SHADOWED_VARIANCE, SLOT_COUNTS, WaveletStrategy, candidate_uniforms,
                      ris_shade_reference, slot_shift)

#: kernel ids of the strategies (-DSTRATEGY in kernels/shade.cl); mis_comp runs mis's kernel
KERNEL_ID = {"uniform": 0, "cosine": 1, "bsdf": 2, "light": 3, "mis": 4, "mis_comp": 4, "wavelet": 5}

REGISTRY = {cls.name: cls for cls in (UniformStrategy, CosineStrategy, BsdfStrategy, LightStrategy, MisStrategy,
                                     MisCompensatedStrategy, WaveletStrategy, SirStrategy, StructuredStrategy)}
#: the strategy ids of scene files, ``--strategy`` and experiment files
STRATEGIES = tuple(REGISTRY)


def _collect():
    """Every option by key (the strategies' in registry order, then the sampler's), the strategies
    each applies to, and the constraints between them."""
    options, applies, constraints = {}, {}, []
    for cls in REGISTRY.values():
        for opt in cls.options.values():
            options.setdefault(opt.key, opt)
            applies.setdefault(opt.key, []).append(cls.name)
        constraints += [c for c in cls.constraints if c not in constraints]
    options[SAMPLER.key], applies[SAMPLER.key] = SAMPLER, list(STRATEGIES)
    return options, {k: tuple(v) for k, v in applies.items()}, tuple(constraints)


#: OPTIONS: key -> Option; APPLIES: key -> the strategy ids that take it; CONSTRAINTS between options
OPTIONS, APPLIES, CONSTRAINTS = _collect()


def check_options(values: dict, where: str) -> dict:
    """The options set in ``values`` (key -> value; None: not set), each checked by its record and
    together by the constraints: a dict of normalised values without the unset ones, or an
    ArgumentError ``where: key must be ...`` (an unknown key lists the known ones)."""
    out = {}
    for key, value in values.items():
        if key not in OPTIONS:
            raise ArgumentError(f"{where}: unknown option {shown(key)} (options: {', '.join(OPTIONS)})")
        if value is not None:
            out[key] = OPTIONS[key].check(value, where)
    for c in CONSTRAINTS:
        bad = c.problem(out)
        if bad:
            raise ArgumentError(f"{where}: {bad[0]} {bad[1]}")
    return out


def constructor_options(strategy: str, values: dict) -> dict:
    """The constructor arguments of ``strategy`` from checked option values by key (options of
    other strategies and the sampler are left out)."""
    by_key = {opt.key: param for param, opt in REGISTRY[strategy].options.items()}
    return {by_key[k]: v for k, v in values.items() if k in by_key}


def make(name: str, **options) -> Strategy:
    """The strategy registered as ``name`` (REGISTRY), built with its constructor's arguments."""
    cls = REGISTRY.get(name) if isinstance(name, str) else None
    if cls is None:
        raise ArgumentError(f"strategies.make: unknown strategy {shown(name)} ({' | '.join(REGISTRY)})")
    accepted = [p for p in inspect.signature(cls).parameters if p not in ("args", "kwargs")]
    unknown = [k for k in options if k not in accepted]
    if unknown:
        raise ArgumentError(f"strategies.make: strategy {name!r} has no option {unknown[0]!r} "
                            f"(options: {', '.join(accepted) or 'none'})")
    return cls(**options)


def options_table(scene_keys: bool = True) -> str:
    """The markdown table of every option (docs/cli.md, docs/scene-format.md)."""
    applies = {k: ("all",) if set(v) == set(STRATEGIES) else v for k, v in APPLIES.items()}
    return markdown_table(OPTIONS.values(), applies, scene_keys)


__all__ = ["REGISTRY", "STRATEGIES", "OPTIONS", "APPLIES", "CONSTRAINTS", "KERNEL_ID", "make", "check_options",
           "constructor_options", "options_table", "Strategy", "ShadingPoints", "DirectionSamples", "HEURISTICS",
           "power_heuristic", "balance_heuristic", "UniformStrategy", "CosineStrategy", "BsdfStrategy",
           "LightStrategy", "MisStrategy", "MisCompensatedStrategy", "WaveletStrategy", "SirStrategy",
           "StructuredStrategy", "tree_info", "shade_reference", "ris_shade_reference", "candidate_uniforms",
           "slot_shift", "AUTO_BUDGET", "DEFAULT_CANDIDATES", "DEFAULT_SLOTS", "MAX_CANDIDATES", "R2_FIXED",
           "SHADOWED_VARIANCE", "SLOT_COUNTS"]
