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
|           | warp, :mod:`wavlight.product`) and the BSDF,   | (ris_shade_reference); M = 0: both,   |
|           | two resampled by f cos L; M = 0: one of each   | balance heuristic                     |
| sir       | M light candidates, N resampled by f cos L     | RIS weights (:mod:`wavlight.sir`)     |
| structured| strata of the map (k-center), one per stratum  | per stratum (:mod:`wavlight.structured`) |

The ``mis`` estimator is Mitsuba 3's ``direct`` integrator with one emitter and one
BSDF sample: each sample's contribution f L cos V / p is weighted by
p_s^2 / (p_light^2 + p_bsdf^2) (the power heuristic). ``wavelet`` with candidates = 0 weights
by p_s / (p_product + p_bsdf) (the balance heuristic; :class:`WaveletStrategy` says why); with
candidates M >= 2 (by default chosen from the scene's shadows, AUTO_BUDGET) it resamples two
or four directions from M candidates (:func:`ris_shade_reference`).
"""
from __future__ import annotations

import inspect
import math
import numbers
from dataclasses import dataclass

import numpy as np

from . import bsdfs, product, warp
from .distributions import HaarTree
from .errors import ArgumentError, check_int, shown


#: the wavelet strategy's directions (shadow rays) per shading sample with candidates: 2 (as
#: mis's pair) unless chosen from the scene (AUTO_BUDGET); 4 halves the visibility's share of
#: the variance for two more rays (README, "Four slots")
DEFAULT_SLOTS = 2
SLOT_COUNTS = (2, 4)   # (wavlight.scene.WAVELET_SLOTS, which validates scene files, repeats it)
#: the wavelet strategy's resampling candidates per shading sample (ris_shade_reference) unless
#: chosen from the scene (AUTO_BUDGET): 8 by measurement (README, "The wavelet strategy"); 0 is
#: the MIS pair of one product and one BSDF sample
DEFAULT_CANDIDATES = 8
#: (candidates, slots) that a render gives the wavelet strategy where neither option nor scene
#: sets them, by the scene's visibility variance (wavlight.occlusion.visibility_variance):
#: below SHADOWED_VARIANCE (a relative variance of visibility: 0 for lone objects, 0.085 for the
#: bunny's own shadows, 0.22-0.30 for objects on floors) the candidates carry the variance; from
#: it on, the slots' visibility does (README, "Budget from the scene's shadows")
SHADOWED_VARIANCE = 0.05
AUTO_BUDGET = {"unshadowed": (16, 2), "shadowed": (8, 4)}
MAX_CANDIDATES = 64
#: candidate j's uniforms are frac(u.xy + j R2) (Roberts' R2 sequence), the offsets in 24-bit
#: fixed point so that the kernel's float32 sums are the twin's bit for bit (kernels/shade.cl)
R2_FIXED = (12664746, 9560334)


@dataclass
class ShadingPoints:
    """Surface points to shade (N of them), in world space with local frames.

    p, n, s, t : (N, 3) position, shading normal (facing the viewer) and tangents
    wo : (N, 3) local direction to the viewer; kind, param, albedo : per point material
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

    def __len__(self):
        return len(self.n)

    def to_local(self, w):
        return warp.to_local(w, self.s, self.t, self.n)

    def to_world(self, w):
        return warp.to_world(w, self.s, self.t, self.n)

    def _by_kind(self, fn, out, *arrays):
        for k in np.unique(self.kind):
            idx = np.nonzero(self.kind == k)[0]
            out[idx] = fn(int(k), self.param[idx], *(a[idx] for a in arrays))
        return out

    def bsdf_eval_cos(self, wi_local):
        """f(wi, wo) cos_i without albedo, (N,)."""
        return self._by_kind(bsdfs.eval_cos, np.zeros(len(self)), wi_local, self.wo)

    def bsdf_pdf(self, wi_local):
        return self._by_kind(bsdfs.pdf, np.zeros(len(self)), wi_local, self.wo)

    def bsdf_sample(self, u):
        wi = np.zeros((len(self), 3))
        pdf = np.zeros(len(self))
        for k in np.unique(self.kind):
            idx = np.nonzero(self.kind == k)[0]
            wi[idx], pdf[idx] = bsdfs.sample(int(k), self.param[idx], u[idx], self.wo[idx])
        return wi, pdf


@dataclass
class DirectionSamples:
    """wi_world, wi_local (N, 3) and pdf (N,) per unit solid angle (0: no sample)."""

    wi_world: np.ndarray
    wi_local: np.ndarray
    pdf: np.ndarray


def _levels_option(where: str, name: str, value, lo: int):
    """None, or a depth override >= lo (an int; depths beyond the map's are clamped when used)."""
    return None if value is None else check_int(where, name, value, lo)


class Strategy:
    """A way of drawing one direction per shading point."""

    name = ""
    heuristic = "power"   # MIS weight of the two-sample strategies: "power" or "balance"
    wants_visibility = False   # whether a render should measure the scene's shadows for it first

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


class LightStrategy(Strategy):
    """Environment importance sampling: luminance x solid angle, by a hierarchical
    warp of a :class:`HaarTree` on the map's lat-long square (Chen & Gao eq. 17-22).

    pdf(wi) = tree pdf at the square point of wi / (2 pi^2 sin theta).
    """

    name = "light"

    def __init__(self, levels: int | None = None, compensated: bool = False):
        self.override = _levels_option("strategies.LightStrategy", "levels", levels, 1)
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


class WaveletStrategy(Strategy):
    """Product (light x BRDF x cosine) samples by a top-down hierarchical warp
    (:mod:`wavlight.product`), combined with BSDF samples: by default as the candidates of
    a resampling estimator (``candidates``, below, and :func:`ris_shade_reference`), with
    ``candidates=0`` by the balance heuristic in a pair.

    The pair, like ``mis``: one product sample and one BSDF sample per shading sample. The
    BSDF sample keeps the estimator unbiased where the approximate product is 0.
    ``levels`` overrides the per-material product depth.

    The two are weighted by the balance heuristic p_s / (p_product + p_bsdf), not the
    power heuristic of ``mis``. Chosen by measurement: both pdfs follow the BRDF lobe, so
    neither is much the better match where the integrand is large, and the power
    heuristic's sharper weights then only add variance (Veach 1997, sec. 9.2, recommends
    it where one technique matches far better). Measured per shading point
    (benchmarks/point_variance.py, 48 sphere points x 256 samples, variance relative to
    ``mis``), power -> balance: phong 200 0.40 / 0.12 / 0.24 -> 0.34 / 0.097 / 0.20
    under rooitou / st_fagans / potsdamer, ggx 0.05 0.77 / 0.26 / 0.43 -> 0.74 / 0.25 /
    0.42, ggx 0.2 0.70 / 0.19 / 0.21 -> 0.54 / 0.16 / 0.19, lambert 0.56 / 0.37 / 0.30
    -> 0.48 / 0.30 / 0.28: lower on all twelve. (Not for ``mis``: it copies pbrt-v4's
    and Mitsuba 3's power heuristic, the baseline users know.) A mixture that gives the
    product more than half of the samples (one-sample MIS, product with probability 0.6
    / 0.75 / 0.9: 0.53 / 0.70 / 1.10 for phong 200 under rooitou) is worse with this approximate product; with the exact product at
    leaf resolution (a per-point table, far too slow to render with) 0.9 gave 0.030
    (point_variance.py exact_product:mix0.9; results point-variance-*-session7-*.json).

    Lambert materials walk the MIS-compensated light tree (max(L - mean, 0), as
    ``mis_comp``; ``compensated_kinds``): the product sample then leaves the texels
    dimmer than the map's mean to the BSDF (cosine) sample, which covers them about as
    well, and spends itself on the bright ones. Unbiased as MIS: the cosine sample's pdf
    is > 0 wherever the product's is 0. Per shading point (variance relative to
    ``mis``): lambert 0.48 / 0.30 / 0.28 -> 0.45 / 0.13 / 0.22 under rooitou /
    st_fagans / potsdamer. Glossy lobes keep the plain tree: compensated, phong 200
    went 0.34 -> 0.81 under rooitou (where the sun lifts the mean above the whole sky,
    a lobe reflecting the sky gets no product samples and its BSDF sample carries it
    alone). A scene with both kinds holds both trees in one HaarTree buffer, ``trees``
    (twice the memory); ``light`` only chooses their depth.

    ``candidates`` M (0 or 2..64; default DEFAULT_CANDIDATES = 8, in a render AUTO_BUDGET's):
    with M >= 2 the shade kernel does not pair one product and one BSDF sample but resamples
    two directions from M candidates of both (:func:`ris_shade_reference`); ``sample`` and
    ``pdf`` stay the walk's.
    ``control_variate`` (default True; only with candidates): the estimate carries the
    candidates' own unshadowed estimate as a control variate (:func:`ris_shade_reference`).
    ``slots`` (2, the default, or 4; 4 only with candidates): directions resampled from the
    candidates per shading sample, one shadow ray each (:func:`ris_shade_reference`).
    Candidates and slots left as None take the defaults here; a render then chooses them
    from its scene's shadows (:meth:`fit_to_visibility`).
    """

    name = "wavelet"
    heuristic = "balance"

    def __init__(self, levels: int | None = None, light_levels: int | None = None,
                 compensated_kinds: tuple = (bsdfs.LAMBERT,), candidates: int | None = None,
                 control_variate: bool = True, slots: int | None = None):
        where = "strategies.WaveletStrategy"
        if not isinstance(control_variate, (bool, np.bool_)):
            raise ArgumentError(f"{where}: control_variate must be True or False, got {shown(control_variate)}")
        self.control_variate = bool(control_variate)
        self._candidates_given = candidates is not None
        candidates = DEFAULT_CANDIDATES if candidates is None else candidates
        self.candidates = check_int(where, "candidates", candidates, 0, MAX_CANDIDATES)
        if self.candidates == 1:
            raise ArgumentError(f"{where}: candidates must be 0 (the MIS pair) or 2..{MAX_CANDIDATES}, got 1")
        self.slots = DEFAULT_SLOTS if slots is None else check_int(where, "slots", slots, 2, 4)
        self._slots_given = slots is not None
        self.visibility_variance = None
        if self.slots not in SLOT_COUNTS or (self.slots != 2 and not self.candidates):
            raise ArgumentError(f"{where}: slots must be 2, or 4 with candidates (the MIS pair has 2), "
                                f"got {self.slots}")
        self.light = LightStrategy(_levels_option(where, "light_levels", light_levels, 1))
        self.bsdf = BsdfStrategy()
        self.override = _levels_option(where, "levels", levels, 0)
        kinds = tuple(bsdfs.TYPES.values())
        ok = np.iterable(compensated_kinds) and not isinstance(compensated_kinds, str)
        self.compensated_kinds = tuple(compensated_kinds) if ok else ()
        if not ok or not all(isinstance(k, numbers.Integral) and not isinstance(k, (bool, np.bool_)) and k in kinds
                             for k in self.compensated_kinds):
            names = ", ".join(f"{v} ({k})" for k, v in bsdfs.TYPES.items())
            raise ArgumentError(f"{where}: compensated_kinds must be a tuple of bsdf kinds ({names}), "
                                f"got {shown(compensated_kinds)}")

    @property
    def wants_visibility(self) -> bool:
        """Whether candidates or slots are left to :meth:`fit_to_visibility` (with candidates 0,
        the MIS pair, the slots are 2 and nothing is)."""
        return not self._candidates_given or (not self._slots_given and self.candidates > 0)

    def fit_to_visibility(self, variance: float):
        """Candidates and slots not given to the constructor, from the scene's visibility
        variance (:func:`wavlight.occlusion.visibility_variance`): AUTO_BUDGET's pair for an
        unshadowed scene (variance < SHADOWED_VARIANCE) or a shadowed one. Before
        :meth:`prepare` only."""
        where = "strategies.WaveletStrategy.fit_to_visibility"
        if hasattr(self, "trees"):   # the kernels are built for the budget that prepare saw
            raise ArgumentError(f"{where}: call it before prepare()")
        if not isinstance(variance, numbers.Real) or not math.isfinite(variance) or variance < 0:
            raise ArgumentError(f"{where}: variance must be a finite number >= 0, got {shown(variance)}")
        self.visibility_variance = float(variance)
        candidates, slots = AUTO_BUDGET["shadowed" if self.visibility_variance >= SHADOWED_VARIANCE
                                        else "unshadowed"]
        if not self._candidates_given:
            self.candidates = candidates
        if not self._slots_given:
            self.slots = slots if self.candidates else DEFAULT_SLOTS

    def prepare(self, environment, materials=()):
        """The light trees, and per material its product depth, lobe shape and light tree:
        the plain one, or for lambert materials the MIS-compensated one (see the class
        docstring); both in one HaarTree buffer when the scene needs both."""
        self.env = environment
        n, self.tv = self.light.depth(environment)   # (self.light only chooses the depth: no tree of its own)
        compensated = np.array([m.kind in self.compensated_kinds for m in materials], bool)
        kinds = [False] * bool((~compensated).any() or not len(compensated)) + [True] * bool(compensated.any())
        self.trees = HaarTree(np.stack([environment.luminance_square(n, compensated=c) for c in kinds]))
        self.tree_index = np.where(compensated, len(kinds) - 1, 0).astype(np.int32)
        self.tree_kinds = ["compensated" if c else "plain" for c in kinds]
        self.names = [m.name for m in materials]
        self.kappa = np.array([product.lobe_kappa(m.kind, m.param) for m in materials], np.float64)
        self.levels = np.array([product.product_levels(k, n, self.override) for k in self.kappa], np.int32)
        self.shapes = np.array([product.lobe_shape(m.kind, m.param) for m in materials], np.int32)
        self._host_nodes = None

    @property
    def _nodes(self):
        """The light trees on the host, (trees, tree size) (only the numpy twin needs them)."""
        if self._host_nodes is None:
            self._host_nodes = self.trees.nodes()
        return self._host_nodes

    def _lobes(self, sp, material):
        wo_w = sp.to_world(sp.wo)
        axis = np.where((sp.kind == bsdfs.LAMBERT)[:, None], sp.n,
                        2.0 * np.einsum("ij,ij->i", wo_w, sp.n)[:, None] * sp.n - wo_w)
        return axis, self.kappa[material], self.levels[material], self.shapes[material]

    def sample(self, sp, u):
        axis, kappa, levels, shape = self._lobes(sp, sp.material)
        uv, pdf_sq = product.sample_reference(self._nodes, self.trees.n_levels, self.env, axis, sp.n,
                                              kappa, levels, shape, u, self.tree_index[sp.material])
        d = self.env.square_to_world(uv)
        return DirectionSamples(d, sp.to_local(d), pdf_sq * self.env.square_to_solid_angle(d))

    def pdf(self, sp, wi_local, wi_world):
        axis, kappa, levels, shape = self._lobes(sp, sp.material)
        uv = self.env.world_to_square(wi_world)
        return product.pdf_reference(self._nodes, self.trees.n_levels, self.env, axis, sp.n, kappa, levels,
                                     shape, uv, self.tree_index[sp.material]) * self.env.square_to_solid_angle(wi_world)

    @property
    def ris_split(self):
        """(product candidates, BSDF candidates) of the resampling estimator: half and half
        (the product walk gets the odd one). Measured per shading point on the glossy and lambert
        spheres (benchmarks/point_variance.py, M = 8, variance over mis's, rooitou / st_fagans /
        potsdamer): 4 + 4 against 6 + 2 phong 200 0.057 / 0.017 / 0.032 against 0.100 / 0.018 /
        0.040, ggx 0.05 0.134 / 0.044 / 0.057 against 0.222 / 0.062 / 0.097, lambert 0.097 /
        0.024 / 0.032 against 0.154 / 0.047 / 0.039; ggx 0.2 alone prefers 6 + 2 (0.096 /
        0.023 / 0.031 against 0.108 / 0.029 / 0.033). BSDF candidates alone (0 + 8) are 4 to 600x
        worse: the product candidates carry the light."""
        bsdf = self.candidates // 2
        return self.candidates - bsdf, bsdf

    def info(self):
        return {**tree_info(self.trees, self.tv, self.env), "wavelet_candidates": self.candidates,
                "wavelet_control_variate": bool(self.candidates and self.control_variate),
                "wavelet_slots": self.slots,
                "visibility_variance": (None if self.visibility_variance is None
                                        else round(self.visibility_variance, 4)),
                "product_levels": dict(zip(self.names, self.levels.tolist())),
                "product_kappa": dict(zip(self.names, [round(k, 3) for k in self.kappa.tolist()])),
                "product_light_tree": dict(zip(self.names, [self.tree_kinds[i] for i in self.tree_index])),
                "product_coefficients_per_walk": dict(zip(self.names, [
                    product.coefficients_per_walk(p, self.trees.n_levels) for p in self.levels.tolist()])),
                # the light trees and the shade kernel's per-material lobe tables (kappa and
                # the coded depth, shape and tree: 8 bytes); the product itself is walked per
                # sample, so nothing here grows with the image or the spp
                "memory_bytes": int(self.trees.stride * self.trees.n_trees * 4 + 8 * len(self.names))}


class MisStrategy(Strategy):
    """One light and one BSDF sample per shading sample, power heuristic."""

    name = "mis"

    def __init__(self, light_levels: int | None = None):
        self.light = LightStrategy(_levels_option("strategies.MisStrategy", "light_levels", light_levels, 1))
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

    Weak spot (README, stability suite): where visibility blocks a glossy lobe's core,
    the light that arrives comes through the lobe's tail from texels dimmer than the
    mean, which only the rare BSDF samples there find: same mean, far more variance
    (2 500x at a pixel of a near-mirror sphere on a floor). Hence not the default."""

    name = "mis_comp"

    def __init__(self, light_levels: int | None = None):
        light_levels = _levels_option("strategies.MisCompensatedStrategy", "light_levels", light_levels, 1)
        self.light = LightStrategy(light_levels, compensated=True)
        self.bsdf = BsdfStrategy()

    def info(self):
        return {**self.light.info(), "mis_compensation": True}


#: kernel ids of the strategies (-DSTRATEGY in kernels/shade.cl); mis_comp runs mis's kernel
KERNEL_ID = {"uniform": 0, "cosine": 1, "bsdf": 2, "light": 3, "mis": 4, "mis_comp": 4, "wavelet": 5}

from .sir import SirStrategy  # noqa: E402  (sir.py builds on the classes above)
from .structured import StructuredStrategy  # noqa: E402

REGISTRY = {cls.name: cls for cls in (UniformStrategy, CosineStrategy, BsdfStrategy, LightStrategy, MisStrategy,
                                     MisCompensatedStrategy, WaveletStrategy, SirStrategy, StructuredStrategy)}


def make(name: str, **options) -> Strategy:
    """The strategy registered as ``name`` (REGISTRY), built with its constructor's options."""
    cls = REGISTRY.get(name) if isinstance(name, str) else None
    if cls is None:
        raise ArgumentError(f"strategies.make: unknown strategy {shown(name)} ({' | '.join(REGISTRY)})")
    accepted = [p for p in inspect.signature(cls).parameters if p not in ("args", "kwargs")]
    unknown = [k for k in options if k not in accepted]
    if unknown:
        raise ArgumentError(f"strategies.make: strategy {name!r} has no option {unknown[0]!r} "
                            f"(options: {', '.join(accepted) or 'none'})")
    return cls(**options)


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


def _unoccluded(sp, env, ds, mis_weight):
    """albedo f cos L / pdf (x MIS weight) per sample, (N, 3); 0 where pdf is 0."""
    fcos = sp.bsdf_eval_cos(ds.wi_local)
    with np.errstate(divide="ignore", invalid="ignore"):
        scalar = np.where(ds.pdf > 0, fcos * mis_weight / ds.pdf, 0.0)
    scalar = np.where((scalar > 0) & np.isfinite(scalar), scalar, 0.0)
    return scalar[:, None] * sp.albedo * env.eval(ds.wi_world)




def candidate_uniforms(u: np.ndarray, j: int) -> np.ndarray:
    """float32 (N, 2): frac(u + j R2) computed as the kernel does (one float32 add, minus 1)."""
    off = np.array([((j * r) & 0xFFFFFF) * 2.0 ** -24 for r in R2_FIXED], np.float32)
    c = np.asarray(u, np.float32)[:, :2] + off
    return np.where(c >= np.float32(1), c - np.float32(1), c)


def slot_shift(k: int, slots: int) -> float:
    """Where slot k of S (a power of two) picks among the candidates: at u.z + k' / S, k' the
    bit reversal of k, so that the first S' slots of S are the S' slots of an S' budget."""
    bits = slots.bit_length() - 1
    return int(format(k, f"0{bits}b")[::-1], 2) / slots if bits else 0.0


def ris_shade_reference(strategy: "WaveletStrategy", env, sp: ShadingPoints, u: np.ndarray, split=None,
                        with_offset=False):
    """The wavelet strategy with ``candidates`` M >= 2: resampled importance sampling from
    product candidates (numpy twin of kernels/shade.cl, RIS_PRODUCT).

    Chen & Gao's bidirectional estimator (sec. 3.2, eq. 10-12: the unshadowed integral times
    the mean visibility of directions drawn from the product) with the directions drawn as
    Burke et al. 2005 do, by resampling, but from candidates that already follow the product:
    M_p from the product walk and M_b from the BSDF (half and half, :attr:`WaveletStrategy.ris_split`),
    candidate j from the uniforms frac(u.xy + j R2). Weights w_j = p^(x_j) / (M_p p_prod(x_j)
    + M_b p_bsdf(x_j)), p^ = f cos lum(L): the balance heuristic over the candidates' own
    pdfs (generalized RIS, Lin et al. 2022). Two directions y are resampled in proportion to
    w, with u.z and u.z + 1/2; each slot's estimate is albedo L(y) / lum(L(y)) sum(w) / 2,
    times its visibility. Unbiased for every M: the expectation involves only each
    candidate's own marginal pdf, and M_p p_prod + M_b p_bsdf > 0 wherever f cos L > 0 (the
    BSDF covers its support). On an unoccluded point the estimate is the M-candidate MIS
    estimate of the unshadowed integral: its noise falls about as 1/M, for two shadow rays.
    split (M_p, M_b) overrides the strategy's (benchmarks/point_variance.py compares splits).

    Control variate (``strategy.control_variate``, the default): the two slots' values are
    also known unshadowed, and U = sum_j w_j L(x_j) / lum(L(x_j)) (per channel: the
    candidates' own M-sample MIS estimate of the unshadowed integral) has the same
    expectation as their sum; so the estimate albedo U - value_a - value_b (the offset,
    which needs no shadow ray) + value_a V(y_a) + value_b V(y_b) stays unbiased, and where
    both directions are visible it is albedo U exactly, without the noise of which
    candidate's colour the slots picked. Where both are blocked it is a difference
    instead of 0 (zero only on average over the picks), so a sample (rarely a pixel at low
    spp) can be negative. Where the offset or a slot's value is not finite (an overflow) the
    whole sample is 0, as in the kernel. Measured on images (96², 16 spp, 4 seeds, relMSE
    with / without, README): the glossy and lambert spheres 0.44-0.98, the bunny scenes
    0.88-1.02.
    With ``strategy.slots`` = 4 four directions are resampled, at u.z, u.z + 1/2, u.z + 1/4
    and u.z + 3/4, each valued sum(w) / 4 instead of / 2 (the same estimator with twice the
    shadow rays: the visibility's variance halves; the offset subtracts all four values).
    Returns wi (N, S, 3) and value (N, S, 3) (S = slots), and with ``with_offset`` offset (N, 3)."""
    from .envmap import luminance

    mp, mb = strategy.ris_split if split is None else split
    m = mp + mb
    n = len(sp)
    u = np.asarray(u)
    dirs = np.zeros((m, n, 3))
    w = np.zeros((m, n))
    colour = np.zeros((n, 3))   # U: sum_j w_j L(x_j) / lum(L(x_j))
    for j in range(m):
        uu = candidate_uniforms(u, j).astype(np.float64)
        ds = strategy.sample(sp, uu) if j < mp else strategy.bsdf.sample(sp, uu)
        p_prod = ds.pdf if j < mp else strategy.pdf(sp, ds.wi_local, ds.wi_world)
        p_bsdf = strategy.bsdf.pdf(sp, ds.wi_local, ds.wi_world) if j < mp else ds.pdf
        rgb = env.eval(ds.wi_world)
        lum = luminance(rgb)
        target = sp.bsdf_eval_cos(ds.wi_local) * lum
        denom = mp * p_prod + mb * p_bsdf
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            wj = np.where((denom > 0) & (target > 0), target / denom, 0.0)
            w[j] = np.where(np.isfinite(wj), wj, 0.0)
            colour += np.where((w[j] > 0)[:, None], w[j][:, None] * rgb / lum[:, None], 0.0)
        dirs[j] = ds.wi_world
    total = w.sum(0)
    cum = np.cumsum(w, 0)
    slots = strategy.slots
    wi = np.zeros((n, slots, 3))
    value = np.zeros((n, slots, 3))
    us = np.asarray(u, np.float32)[:, 2]
    # slot k at u.z + k' / S, k' the bit reversal of k (0, 2, 1, 3 for four: slots a, b as with
    # two, then c and d between them), wrapped into [0, 1) by float32 operations as the kernel does
    shifts = [slot_shift(k, slots) for k in range(slots)]
    thresholds = [us if h == 0 else np.where(us >= np.float32(1 - h), us - np.float32(1 - h), us + np.float32(h))
                  for h in shifts]
    for slot, v in enumerate(thresholds):
        # the first candidate of positive weight whose running sum reaches v total (the last if none)
        reach = (cum >= v.astype(np.float64) * total) & (w > 0)
        pick = np.where(reach.any(0), reach.argmax(0), m - 1)
        y = dirs[pick, np.arange(n)]
        rgb = env.eval(y)
        lum = luminance(rgb)
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where((total > 0) & (lum > 0), np.float32(1.0 / slots) * total / lum, 0.0)
        wi[:, slot], value[:, slot] = y, scale[:, None] * sp.albedo * rgb
    offset = np.zeros((n, 3))
    if strategy.control_variate:
        with np.errstate(invalid="ignore", over="ignore"):
            offset = sp.albedo * colour - value.sum(1)
        # where the offset or a slot's value overflowed, the whole sample is 0 (as the kernel)
        ok = np.isfinite(offset).all(1) & np.isfinite(value).all((1, 2))
        value, offset = np.where(ok[:, None, None], value, 0.0), np.where(ok[:, None], offset, 0.0)
    return (wi, value, offset) if with_offset else (wi, value)


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
            wi[:, slot], value[:, slot] = ds.wi_world, _unoccluded(sp, env, ds, w)
    else:
        ds = strategy.sample(sp, u[:, :2])
        wi[:, 0], value[:, 0] = ds.wi_world, _unoccluded(sp, env, ds, 1.0)
    return (wi, value, np.zeros((n, 3))) if with_offset else (wi, value)
