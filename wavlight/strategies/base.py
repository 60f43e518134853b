"""The strategies' common ground: shading points, direction samples, the Strategy interface,
MIS heuristics and the unoccluded estimate albedo f cos L / pdf.

Every strategy draws directions with an exact pdf per unit solid angle (pbrt-v4's and
Mitsuba 3's convention); a pdf of 0 means "no sample": its contribution is 0, never NaN.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import bsdfs, warp


@dataclass
class ShadingPoints:
    """Surface points to shade (N of them), in world space with local frames.

    p, n, s, t : (N, 3) position, shading normal (facing the viewer) and tangents
    wo : (N, 3) local direction to the viewer; kind, param, albedo : per point material;
    table : (N, bsdfs.PLASTIC_STRIDE) the plastic rows (Scene.material_table), needed where
    a point is plastic
    g : (N, 3) the geometric normal (facing the viewer) in the local frame, or None (the
    shading normal is the geometric one): directions below it carry no light
    (docs/decisions/shading-normals.md)
    """

    p: np.ndarray
    n: np.ndarray
    s: np.ndarray
    t: np.ndarray
    wo: np.ndarray
    kind: np.ndarray
    param: np.ndarray
    albedo: np.ndarray
    material: np.ndarray = None
    table: np.ndarray = None
    g: np.ndarray = None

    def __len__(self):
        return len(self.n)

    def to_local(self, w):
        return warp.to_local(w, self.s, self.t, self.n)

    def to_world(self, w):
        return warp.to_world(w, self.s, self.t, self.n)

    def _table(self, idx):
        return None if self.table is None else self.table[idx]

    def _by_kind(self, fn, out, *arrays):
        for k in np.unique(self.kind):   # material kinds, not points
            idx = np.nonzero(self.kind == k)[0]
            out[idx] = fn(int(k), self.param[idx], *(a[idx] for a in arrays), table=self._table(idx))
        return out

    def bsdf_eval_cos(self, wi_local):
        """f(wi, wo) cos_i without albedo, (N,) (plastic: its specular and diffuse parts' sum); 0
        where wi is below the geometric surface (``g``)."""
        fcos = self._by_kind(bsdfs.eval_cos, np.zeros(len(self)), wi_local, self.wo)
        if self.g is not None:
            fcos = np.where(np.einsum("ij,ij->i", wi_local, self.g) > 0, fcos, 0.0)
        return fcos

    def bsdf_value(self, wi_local):
        """(f cos without albedo (N,), the colour (N, 3) that makes it f cos with albedo:
        the albedo, or plastic's bsdfs.tint)."""
        f, diffuse = np.zeros(len(self)), np.zeros(len(self))
        for k in np.unique(self.kind):   # material kinds, not points
            idx = np.nonzero(self.kind == k)[0]
            f[idx], diffuse[idx] = bsdfs.eval_split(int(k), self.param[idx], wi_local[idx], self.wo[idx],
                                                    table=self._table(idx))
        if self.g is not None:   # below the geometric surface: no light (as bsdf_eval_cos)
            below = np.einsum("ij,ij->i", wi_local, self.g) <= 0
            f[below], diffuse[below] = 0.0, 0.0
        return f, bsdfs.tint(f, diffuse, self.albedo)

    def bsdf_pdf(self, wi_local):
        return self._by_kind(bsdfs.pdf, np.zeros(len(self)), wi_local, self.wo)

    def bsdf_sample(self, u):
        wi = np.zeros((len(self), 3))
        pdf = np.zeros(len(self))
        for k in np.unique(self.kind):   # material kinds, not points
            idx = np.nonzero(self.kind == k)[0]
            wi[idx], pdf[idx] = bsdfs.sample(int(k), self.param[idx], u[idx], self.wo[idx], table=self._table(idx))
        return wi, pdf


@dataclass
class DirectionSamples:
    """wi_world, wi_local (N, 3) and pdf (N,) per unit solid angle (0: no sample)."""

    wi_world: np.ndarray
    wi_local: np.ndarray
    pdf: np.ndarray


class Strategy:
    """A way of drawing one direction per shading point.

    ``options`` maps the constructor's user-facing parameters to their :class:`wavlight.options.Option`
    records (the one declaration of each range, default and help text; scene keys, flags,
    experiment keys and render_full keywords come from them); ``constraints`` ties two of them.
    """

    name = ""
    heuristic = "power"   # MIS weight of the two-sample strategies: "power" or "balance"
    wants_visibility = False   # whether a render should measure the scene's shadows for it first
    options: dict = {}
    constraints: tuple = ()

    @classmethod
    def checked(cls, param: str, value):
        """A constructor argument checked by its option's record: None stays None (the default or
        a choice made later), anything else is normalised or refused with an ArgumentError
        ``strategies.<Class>: <param> must be ...``."""
        return None if value is None else cls.options[param].check(value, f"strategies.{cls.__name__}", param)

    def fit_to_visibility(self, variance: float):
        """Adapt to the scene's visibility variance (wavlight.occlusion); before :meth:`prepare`,
        and only when :attr:`wants_visibility`."""

    def prepare(self, environment, materials=()):
        """Per-render precomputation (trees, tables); called once before shading."""

    def sample(self, sp: ShadingPoints, u: np.ndarray) -> DirectionSamples:
        raise NotImplementedError

    def pdf(self, sp: ShadingPoints, wi_local: np.ndarray, wi_world: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def info(self) -> dict:
        return {}


def power_heuristic(p_a, p_b):
    """p_a^2 / (p_a^2 + p_b^2), computed on ratios so that it neither under- nor overflows."""
    p_a, p_b = np.asarray(p_a, np.float64), np.asarray(p_b, np.float64)
    big = np.maximum(p_a, p_b)
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = p_a / big, p_b / big
        return np.where(big > 0, a * a / (a * a + b * b), 0.0)


def balance_heuristic(p_a, p_b):
    """p_a / (p_a + p_b), computed on ratios so that it neither under- nor overflows."""
    p_a, p_b = np.asarray(p_a, np.float64), np.asarray(p_b, np.float64)
    big = np.maximum(p_a, p_b)
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = p_a / big, p_b / big
        return np.where(big > 0, a / (a + b), 0.0)


HEURISTICS = {"power": power_heuristic, "balance": balance_heuristic}


def unoccluded(sp, env, ds, mis_weight):
    """albedo f cos L / pdf (x MIS weight) per sample, (N, 3); 0 where pdf is 0 (plastic: its
    f cos with albedo, the scalar f cos times its tint)."""
    fcos, tint = sp.bsdf_value(ds.wi_local)
    with np.errstate(divide="ignore", invalid="ignore"):
        scalar = np.where(ds.pdf > 0, fcos * mis_weight / ds.pdf, 0.0)
    scalar = np.where((scalar > 0) & np.isfinite(scalar), scalar, 0.0)
    return scalar[:, None] * tint * env.eval(ds.wi_world)
