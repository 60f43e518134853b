"""The ``wavelet`` strategy: product (light x BRDF x cosine) samples by a top-down hierarchical
warp (:mod:`wavlight.strategies.product`), resampled with BSDF candidates (Chen & Gao sec. 3.2
and 4.3-4.4; Burke et al. 2005; generalized RIS, Lin et al. 2022)."""
from __future__ import annotations

import math
import numbers

import numpy as np

from .. import bsdfs
from ..envmap import luminance
from ..errors import ArgumentError, shown
from ..haar.tree import HaarTree
from ..options import Constraint, Option
from . import product
from .base import DirectionSamples, ShadingPoints, Strategy
from .light import LIGHT_LEVELS, LightStrategy, tree_info
from .simple import BsdfStrategy


#: the wavelet strategy's directions (shadow rays) per shading sample with candidates: 2 (as
#: mis's pair) unless chosen from the scene (AUTO_BUDGET); 4 halves the visibility's share of
#: the variance for two more rays (docs/decisions/four-slots.md)
DEFAULT_SLOTS = 2
SLOT_COUNTS = (2, 4)
#: the wavelet strategy's resampling candidates per shading sample (ris_shade_reference) unless
#: chosen from the scene (AUTO_BUDGET): 8 by measurement (docs/decisions/resampling-candidates.md); 0 is
#: the MIS pair of one product and one BSDF sample
DEFAULT_CANDIDATES = 8
#: (candidates, slots) that a render gives the wavelet strategy where neither option nor scene
#: sets them, by the scene's visibility variance (wavlight.occlusion.visibility_variance):
#: below SHADOWED_VARIANCE (a relative variance of visibility: 0 for lone objects, 0.085 for the
#: bunny's own shadows, 0.22-0.30 for objects on floors) the candidates carry the variance; from
#: it on, the slots' visibility does (docs/decisions/budget-from-shadows.md)
SHADOWED_VARIANCE = 0.05
AUTO_BUDGET = {"unshadowed": (16, 2), "shadowed": (8, 4)}
MAX_CANDIDATES = 64
#: candidate j's uniforms are frac(u.xy + j R2) (Roberts' R2 sequence), the offsets in 24-bit
#: fixed point so that the kernel's float32 sums are the twin's bit for bit (kernels/shade.cl)
R2_FIXED = (12664746, 9560334)

WAVELET_LEVELS = Option("wavelet_levels", int, "Product depth of the wavelet walk for every material, cut to the "
                        "light tree's depth (0: the walk follows the light tree alone).",
                        default_doc="per material, from its lobe", lo=0, hi=11)
WAVELET_CANDIDATES = Option("wavelet_candidates", int, "wavelet: resampling candidates per shading sample, half "
                            "from the product walk, half from the BSDF (0: the MIS pair of one product and one "
                            "BSDF sample).",
                            default_doc="from the scene's shadows: 16, or 8 where the camera sees shadows",
                            lo=0, hi=MAX_CANDIDATES, refused={1: "0 is the MIS pair"})
WAVELET_SLOTS = Option("wavelet_slots", int, "wavelet with candidates: directions resampled per shading sample, one "
                       "shadow ray each; 4 halves the visibility's noise for two more rays.",
                       default_doc="from the scene's shadows: 2, or 4 where the camera sees shadows",
                       values=SLOT_COUNTS)
WAVELET_CONTROL_VARIATE = Option("wavelet_control_variate", bool, "wavelet with candidates: carry the candidates' "
                                 "unshadowed estimate as a control variate (unbiased either way).", default=True)
#: four slots resample from candidates; the MIS pair (candidates 0) has two directions
SLOTS_NEED_CANDIDATES = Constraint(("wavelet_slots", "wavelet_candidates"), lambda slots, m: slots == 2 or m != 0,
                                   "4 needs the resampling estimator (wavelet_candidates 2..64), not 0")

class WaveletStrategy(Strategy):
    """Product (light x BRDF x cosine) samples by a top-down hierarchical warp
    (:mod:`wavlight.strategies.product`), combined with BSDF samples: by default as the candidates of
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
    (benchmarks/point_variance.py exact_product:mix0.9).

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
    options = {"levels": WAVELET_LEVELS, "light_levels": LIGHT_LEVELS, "candidates": WAVELET_CANDIDATES,
               "slots": WAVELET_SLOTS, "control_variate": WAVELET_CONTROL_VARIATE}
    constraints = (SLOTS_NEED_CANDIDATES,)

    def __init__(self, levels: int | None = None, light_levels: int | None = None,
                 compensated_kinds: tuple = (bsdfs.LAMBERT,), candidates: int | None = None,
                 control_variate: bool = True, slots: int | None = None):
        where = "strategies.WaveletStrategy"
        self.control_variate = self.checked("control_variate", control_variate)
        self._candidates_given = candidates is not None
        self.candidates = DEFAULT_CANDIDATES if candidates is None else self.checked("candidates", candidates)
        self._slots_given = slots is not None
        self.slots = DEFAULT_SLOTS if slots is None else self.checked("slots", slots)
        self.visibility_variance = None
        if not SLOTS_NEED_CANDIDATES.ok(self.slots, self.candidates):
            raise ArgumentError(f"{where}: slots must be 2, or 4 with candidates (the MIS pair has 2), "
                                f"got {self.slots}")
        self.light = LightStrategy(self.checked("light_levels", light_levels))
        self.bsdf = BsdfStrategy()
        self.override = self.checked("levels", levels)
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
        # plastic's diffuse lobe: the lambert shape at a lambert material's depth (see sample)
        self.plastic_diffuse_levels = product.product_levels(0.0, n, self.override)
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

    def _diffuse_lobes(self, sp):
        """Plastic's diffuse lobes: the lambert shape about the normal, kappa 0, at
        plastic_diffuse_levels."""
        count = len(sp)
        return (sp.n, np.zeros(count), np.full(count, self.plastic_diffuse_levels, np.int32),
                np.full(count, bsdfs.LAMBERT, np.int32))

    def _lobe_q(self, sp):
        """The probability of each point's own (specular) lobe: plastic_spec_prob for plastic, 1 else."""
        plastic = sp.kind == bsdfs.PLASTIC
        if not plastic.any():
            return None
        q = np.ones(len(sp))
        q[plastic] = bsdfs.plastic_spec_prob(sp.wo[plastic], sp.table[plastic])
        return q

    def sample(self, sp, u):
        """The product walk; for plastic a one-sample mixture of its specular lobe's walk
        (probability q = bsdfs.plastic_spec_prob) and its diffuse lobe's (the lambert shape),
        u.x choosing and rescaled (float32, as kernels/shade.cl mixture_walk); density q p_spec +
        (1 - q) p_diffuse."""
        axis, kappa, levels, shape = self._lobes(sp, sp.material)
        q = self._lobe_q(sp)
        if q is not None:
            q32, u0 = q.astype(np.float32), np.asarray(u[:, 0], np.float32)
            use_d = ~(u0 < q32)
            with np.errstate(divide="ignore", invalid="ignore"):
                u0 = np.where(use_d, (u0 - q32) / (np.float32(1) - q32), u0 / q32).astype(np.float32)
            u = np.stack([u0.astype(np.float64), np.asarray(u[:, 1], np.float64)], 1)
            diffuse = self._diffuse_lobes(sp)
            axis, kappa, levels, shape = (np.where(use_d.reshape((-1,) + (1,) * (np.ndim(a) - 1)), b, a)
                                          for a, b in zip((axis, kappa, levels, shape), diffuse))
        uv, pdf_sq = product.sample_reference(self._nodes, self.trees.n_levels, self.env, axis, sp.n,
                                              kappa, levels, shape, u, self.tree_index[sp.material])
        d = self.env.square_to_world(uv)
        if q is not None:
            local = sp.to_local(d)
            return DirectionSamples(d, local, self.pdf(sp, local, d))
        return DirectionSamples(d, sp.to_local(d), pdf_sq * self.env.square_to_solid_angle(d))

    def pdf(self, sp, wi_local, wi_world):
        axis, kappa, levels, shape = self._lobes(sp, sp.material)
        uv = self.env.world_to_square(wi_world)
        trees = self.tree_index[sp.material]
        p = product.pdf_reference(self._nodes, self.trees.n_levels, self.env, axis, sp.n, kappa, levels, shape, uv,
                                  trees)
        q = self._lobe_q(sp)
        if q is not None:
            axis, kappa, levels, shape = self._diffuse_lobes(sp)
            p = q * p + (1.0 - q) * product.pdf_reference(self._nodes, self.trees.n_levels, self.env, axis, sp.n,
                                                          kappa, levels, shape, uv, trees)
        return p * self.env.square_to_solid_angle(wi_world)

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
    times its visibility (plastic: its colour at y, bsdfs.tint, in place of the albedo, here and
    in U below; the target p^ takes f cos without colour). Unbiased for every M: the expectation involves only each
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
    with / without, docs/decisions/control-variate.md): the glossy and lambert spheres 0.44-0.98, the bunny scenes
    0.88-1.02.
    With ``strategy.slots`` = 4 four directions are resampled, at u.z, u.z + 1/2, u.z + 1/4
    and u.z + 3/4, each valued sum(w) / 4 instead of / 2 (the same estimator with twice the
    shadow rays: the visibility's variance halves; the offset subtracts all four values).
    Returns wi (N, S, 3) and value (N, S, 3) (S = slots), and with ``with_offset`` offset (N, 3)."""

    mp, mb = strategy.ris_split if split is None else split
    m = mp + mb
    n = len(sp)
    u = np.asarray(u)
    dirs = np.zeros((m, n, 3))
    w = np.zeros((m, n))
    colour = np.zeros((n, 3))   # U: sum_j w_j L(x_j) / lum(L(x_j)) times x_j's colour (the albedo but for plastic)
    tints = np.zeros((m, n, 3))   # each candidate's colour: the albedo, plastic's bsdfs.tint
    for j in range(m):
        uu = candidate_uniforms(u, j).astype(np.float64)
        ds = strategy.sample(sp, uu) if j < mp else strategy.bsdf.sample(sp, uu)
        p_prod = ds.pdf if j < mp else strategy.pdf(sp, ds.wi_local, ds.wi_world)
        p_bsdf = strategy.bsdf.pdf(sp, ds.wi_local, ds.wi_world) if j < mp else ds.pdf
        rgb = env.eval(ds.wi_world)
        lum = luminance(rgb)
        fcos, tints[j] = sp.bsdf_value(ds.wi_local)
        target = fcos * lum
        denom = mp * p_prod + mb * p_bsdf
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            wj = np.where((denom > 0) & (target > 0), target / denom, 0.0)
            w[j] = np.where(np.isfinite(wj), wj, 0.0)
            colour += np.where((w[j] > 0)[:, None], w[j][:, None] * rgb / lum[:, None] * tints[j], 0.0)
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
        wi[:, slot], value[:, slot] = y, scale[:, None] * tints[pick, np.arange(n)] * rgb
    offset = np.zeros((n, 3))
    if strategy.control_variate:
        with np.errstate(invalid="ignore", over="ignore"):
            offset = colour - value.sum(1)
        # where the offset or a slot's value overflowed, the whole sample is 0 (as the kernel)
        ok = np.isfinite(offset).all(1) & np.isfinite(value).all((1, 2))
        value, offset = np.where(ok[:, None, None], value, 0.0), np.where(ok[:, None], offset, 0.0)
    return (wi, value, offset) if with_offset else (wi, value)


