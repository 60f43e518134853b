"""Environment importance sampling (``light``) and its MIS combinations with the BSDF
(``mis``, ``mis_comp``): a hierarchical warp of the map's Haar tree (Chen & Gao eq. 17-22)."""
from __future__ import annotations

import numpy as np

from ..haar.tree import HaarTree
from ..options import Option
from .base import DirectionSamples, Strategy
from .simple import BsdfStrategy

#: the light tree's depth, shared by every strategy that builds one
LIGHT_LEVELS = Option("light_levels", int, "Depth n of the light tree (2^n x 2^n leaves), cut to the map's own depth.",
                      default_doc="from the map's content", lo=1, hi=11)


class LightStrategy(Strategy):
    """Environment importance sampling: luminance x solid angle, by a hierarchical
    warp of a :class:`HaarTree` on the map's lat-long square (Chen & Gao eq. 17-22).

    pdf(wi) = tree pdf at the square point of wi / (2 pi^2 sin theta).
    """

    name = "light"
    options = {"levels": LIGHT_LEVELS}

    def __init__(self, levels: int | None = None, compensated: bool = False):
        self.override = self.checked("levels", levels)
        self.compensated = compensated   # only as one technique of MIS (MisCompensatedStrategy)

    def depth(self, environment):
        """The light tree's depth n (2^n x 2^n leaves) and the total variation it leaves
        (Environment.light_levels, which chooses n by it; Environment.tree_tv where
        --light-levels sets n, cut to the map's full depth)."""
        if self.override is None:
            return environment.light_levels()
        n = min(max(int(self.override), 1), environment.square_levels())
        return n, environment.tree_tv(n)

    def prepare(self, environment, materials=()):
        self.env = environment
        n, self.tv = self.depth(environment)
        self.tree = HaarTree(environment.luminance_square(n, compensated=self.compensated))

    def sample_directions(self, u):
        """u (N, 2) -> world directions (N, 3) and pdf per solid angle (N,)."""
        uv, pdf_sq = self.tree.sample(u)
        d = self.env.square_to_world(uv.astype(np.float64))
        return d, pdf_sq.astype(np.float64) * self.env.square_to_solid_angle(d)

    def pdf_directions(self, d_world):
        uv = self.env.world_to_square(d_world)
        return self.tree.pdf(uv).astype(np.float64) * self.env.square_to_solid_angle(d_world)

    def sample(self, sp, u):
        d, pdf = self.sample_directions(u)
        return DirectionSamples(d, sp.to_local(d), pdf)

    def pdf(self, sp, wi_local, wi_world):
        return self.pdf_directions(wi_world)

    def info(self):
        return tree_info(self.tree, self.tv, self.env)


def tree_info(tree: HaarTree, tv, environment) -> dict:
    """--json's light tree entries: leaf grid, bytes of all trees in the buffer, the total
    variation the depth leaves, and the Haar coefficients of the
    map's luminance that the depth keeps per tree, 4^n (the scaling coefficient and every
    detail coefficient of the levels above the leaves: a tree of depth n is the map's Haar
    expansion cut below level n), against the 4^N of the map's full square (depth N,
    Environment.square_levels)."""
    side = 1 << tree.n_levels
    return {"light_tree": f"{side}x{side}", "light_tree_bytes": int(tree.stride * tree.n_trees * 4),
            "light_tree_tv": round(float(tv), 5),
            "light_coefficients_kept": 4 ** tree.n_levels,
            "light_coefficients_full": 4 ** environment.square_levels()}


class MisStrategy(Strategy):
    """One light and one BSDF sample per shading sample, power heuristic."""

    name = "mis"
    options = {"light_levels": LIGHT_LEVELS}

    def __init__(self, light_levels: int | None = None):
        self.light = LightStrategy(self.checked("light_levels", light_levels))
        self.bsdf = BsdfStrategy()

    def prepare(self, environment, materials=()):
        self.light.prepare(environment)

    def info(self):
        return self.light.info()


class MisCompensatedStrategy(MisStrategy):
    """``mis`` with MIS compensation (Karlik et al. 2019; pbrt-v4's default for image
    lights, Mitsuba 3's ``mis_compensation``): the light sample follows max(luminance -
    mean luminance, 0) x solid angle (Environment.luminance_square(compensated=True)),
    so it spends no samples on the texels dimmer than the map's mean, which the BSDF
    sample covers. Unbiased only as MIS: the light pdf is 0 there, and every BSDF here
    samples its whole support (the power heuristic gives the BSDF sample weight 1
    where the light pdf is 0). A map without texels above its mean falls back to
    uniform in solid angle. Same shade kernel as ``mis``, another light tree.

    Weak spot (docs/strategies.md, the stability suite): where visibility blocks a glossy lobe's core,
    the light that arrives comes through the lobe's tail from texels dimmer than the
    mean, which only the rare BSDF samples there find: same mean, far more variance
    (2 500x at a pixel of a near-mirror sphere on a floor). Hence not the default."""

    name = "mis_comp"

    def __init__(self, light_levels: int | None = None):
        self.light = LightStrategy(self.checked("light_levels", light_levels), compensated=True)
        self.bsdf = BsdfStrategy()

    def info(self):
        return {**self.light.info(), "mis_compensation": True}

