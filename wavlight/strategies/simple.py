"""Strategies that follow one factor of the integrand: the hemisphere, its cosine, the BRDF."""
from __future__ import annotations

from .. import warp
from .base import DirectionSamples, Strategy


class UniformStrategy(Strategy):
    name = "uniform"

    def sample(self, sp, u):
        wl = warp.square_to_uniform_hemisphere(u)
        return DirectionSamples(sp.to_world(wl), wl, warp.square_to_uniform_hemisphere_pdf(wl))

    def pdf(self, sp, wi_local, wi_world):
        return warp.square_to_uniform_hemisphere_pdf(wi_local)


class CosineStrategy(Strategy):
    name = "cosine"

    def sample(self, sp, u):
        wl = warp.square_to_cosine_hemisphere(u)
        return DirectionSamples(sp.to_world(wl), wl, warp.square_to_cosine_hemisphere_pdf(wl))

    def pdf(self, sp, wi_local, wi_world):
        return warp.square_to_cosine_hemisphere_pdf(wi_local)


class BsdfStrategy(Strategy):
    name = "bsdf"

    def sample(self, sp, u):
        wl, pdf = sp.bsdf_sample(u)
        return DirectionSamples(sp.to_world(wl), wl, pdf)

    def pdf(self, sp, wi_local, wi_world):
        return sp.bsdf_pdf(wi_local)

