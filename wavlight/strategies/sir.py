"""The ``sir`` strategy: bidirectional importance sampling by sampling-importance-resampling
(Burke, Ghosh and Heidrich 2005; Chen & Gao §3.2, eq. 10-12).

Chen & Gao's bidirectional estimator (eq. 12) draws directions from the normalised product
p = f cos L / L_ns (eq. 10, visibility left out), with L_ns = integral f cos L dw the
unshadowed radiance (eq. 11), and then only the visibility is left to estimate::

    L_{N,p} = 1/N sum_k f(y_k) L(y_k) V(y_k) cos / p(y_k) = L_ns / N sum_k V(y_k).       (12)

Neither L_ns nor an exact product sampler is available in closed form. Burke et al. draw the
y_k by sampling-importance-resampling; we use its unbiased form, resampled importance
sampling (RIS; Talbot et al. 2005), which also supplies an unbiased estimate of L_ns.

Per shading point (x, wo), with p_hat(w) = f(w, wo) cos(w) lum(L(w)) (the BRDF without
albedo, the map's luminance; unshadowed; RGB is carried by the ratio L_rgb / lum below):

1. M candidates x_1..x_M, i.i.d. from a source density q: the environment's light sampling
   (``source="light"``, the light tree of :class:`~wavlight.strategies.LightStrategy`, q
   proportional to luminance x solid angle) or the BRDF (``source="bsdf"``,
   ``ShadingPoints.bsdf_sample``).
2. Resampling weights w_j = p_hat(x_j) / q(x_j), and the RIS weight

       W = (1/M) sum_j w_j,            E[W] = integral p_hat dw = lum-L_ns (w/o albedo).

   W is an ordinary M-sample importance-sampling estimate of the (luminance) L_ns of eq. 11.
3. N directions y_1..y_N resampled from the candidates with probability w_j / sum_i w_i, with
   replacement (a categorical draw per y_k by inverse CDF over the candidates).
4. One shadow ray per y_k; the estimate (eq. 12 with p(y_k) replaced by p_hat(y_k) / W)::

       L_hat = 1/N sum_k  albedo f(y_k) L(y_k) cos V(y_k) / p_hat(y_k) * W
             = W albedo / N sum_k  (L_rgb / lum)(y_k) V(y_k).

   With ``plastic`` (f cos = coat + albedo x base) the albedo does not factor out: p_hat keeps
   f without albedo (coat + base, positive wherever the integrand is), and "albedo" above is the
   colour that turns f into f with albedo at y_k (ShadingPoints.bsdf_value's tint: the albedo for
   the other materials), so the estimate is W / N sum_k (f_rgb / f)(y_k) (L_rgb / lum)(y_k) V(y_k),
   unbiased as before.

   For a grey map this is exactly eq. 12, L_ns_hat / N sum_k V(y_k): the resampled
   directions distribute (as M grows) like eq. 10, and the noise left is the visibility's
   plus that of W. If sum_j w_j = 0 (no candidate sees any light through the lobe) the
   estimate is 0, which is also what W = 0 gives.

Unbiasedness (RIS, Talbot et al. 2005): E[L_hat] = integral f L V cos dw exactly, for any
M >= 1 and N >= 1, provided (a) p_hat > 0 wherever the integrand f L V cos is non-zero and
(b) q > 0 wherever p_hat > 0. (a) holds because the luminance weights are positive, so
lum(L) = 0 only where every channel of L is 0. (b) holds for ``source="light"`` because the
light tree's leaves hold the exact luminance integral of the texels they overlap, so its pdf
is positive wherever the map is (up to float32 underflow of a leaf mass, ~1e-38 x solid
angle, and the measure-zero poles), and for ``source="bsdf"`` because every BRDF's sampling
pdf is positive wherever f cos is (lambert cos/pi, phong (n+1)/2pi cos^n, ggx visible
normals G1 D / 4 cos_o). Each y_k is an unbiased RIS sample, so their mean is too; the N
samples share the candidates (resampling with replacement), so the variance of W is not
divided by N: N reduces only the visibility (and colour-ratio) part. M reduces the variance
of W as 1/M (i.i.d. candidates) and brings the y_k closer to eq. 10.

Options: M = ``candidates`` (default 32; scene key ``[render] sir_candidates``, CLI
``--sir-candidates``), N = ``samples`` (default 1; ``sir_samples``, ``--sir-samples``),
``source`` ("light" | "bsdf"; library only). Cost per shading sample: M candidate draws and
BRDF/map evaluations (no rays) and N shadow rays. There is no kernel: the strategy shades
through :class:`wavlight.shading.NumpyShader`, which calls :meth:`SirStrategy.shade`
(N slots per point instead of ``shade_reference``'s two).

Randomness: the shader hands four uniforms per point (``u``, (P, 4)); SIR needs 2M + N.
:meth:`SirStrategy.shade` seeds a numpy Generator from a hash of the bytes of ``u`` (plus
M, N and the source), so a render stays a deterministic function of its seed (the tiles'
streams are seeded by (seed, tile)) and independent of the thread count. Points are shaded
in chunks of about ``CHUNK_CANDIDATES`` candidates (and ``CHUNK_COMPARISONS`` entries of
the resampling step's points x N x M comparison), so memory stays bounded for large M, N;
everything within a chunk is vectorised over points x candidates.
"""
from __future__ import annotations

import hashlib

import numpy as np

from ..envmap import luminance
from ..errors import ArgumentError, shown
from ..options import Option
from .base import DirectionSamples, ShadingPoints, Strategy
from .light import LIGHT_LEVELS, LightStrategy

#: about this many candidates (points x M) are processed at once (bounded memory)
CHUNK_CANDIDATES = 1 << 17
#: and at most this many entries (points x N x M) in the resampling comparison
CHUNK_COMPARISONS = 1 << 24
DEFAULT_CANDIDATES = 32
DEFAULT_SAMPLES = 1
SOURCES = ("light", "bsdf")
SIR_CANDIDATES = Option("sir_candidates", int, "sir: candidates M drawn from the environment per shading sample.",
                        default=DEFAULT_CANDIDATES, lo=1, hi=65536)
SIR_SAMPLES = Option("sir_samples", int, "sir: directions N resampled from the candidates, one shadow ray each.",
                     default=DEFAULT_SAMPLES, lo=1, hi=1024)


def repeat_points(sp: ShadingPoints, m: int) -> ShadingPoints:
    """Every shading point m times in a row (point-major), for one candidate each."""
    rep = lambda a: None if a is None else np.repeat(np.asarray(a), m, axis=0)
    return ShadingPoints(rep(sp.p), rep(sp.n), rep(sp.s), rep(sp.t), rep(sp.wo), rep(sp.kind), rep(sp.param),
                         rep(sp.albedo), rep(sp.material), rep(sp.table), rep(sp.g))


def slice_points(sp: ShadingPoints, a: int, b: int) -> ShadingPoints:
    cut = lambda x: None if x is None else x[a:b]
    return ShadingPoints(cut(sp.p), sp.n[a:b], sp.s[a:b], sp.t[a:b], sp.wo[a:b], sp.kind[a:b], sp.param[a:b],
                         sp.albedo[a:b], cut(sp.material), cut(sp.table), cut(sp.g))


def rng_from_uniforms(u: np.ndarray, *tag) -> np.random.Generator:
    """A numpy Generator seeded by a hash of the bytes of u (and of ``tag``): deterministic per u."""
    h = hashlib.blake2b(np.ascontiguousarray(u).tobytes(), digest_size=16)
    h.update(repr(tag).encode())
    return np.random.default_rng(int.from_bytes(h.digest(), "little"))


class SirStrategy(Strategy):
    """Resampled importance sampling of f cos L: M candidates from ``source``, N resampled.

    See the module docstring for the estimator and its conditions. ``light_levels`` sets the
    light tree's depth (default: from the map's content).
    """

    name = "sir"
    options = {"candidates": SIR_CANDIDATES, "samples": SIR_SAMPLES, "light_levels": LIGHT_LEVELS}

    def __init__(self, candidates: int | None = None, samples: int | None = None, source: str = "light",
                 light_levels: int | None = None):
        where = "strategies.SirStrategy"
        self.candidates = DEFAULT_CANDIDATES if candidates is None else self.checked("candidates", candidates)
        self.samples = DEFAULT_SAMPLES if samples is None else self.checked("samples", samples)
        if not isinstance(source, str) or source not in SOURCES:
            raise ArgumentError(f"{where}: source must be one of {' | '.join(SOURCES)}, got {shown(source)}")
        self.source = source
        self.light = LightStrategy(self.checked("light_levels", light_levels))
        self.env = None

    def prepare(self, environment, materials=()):
        self.env = environment
        if self.source == "light":
            self.light.prepare(environment)

    # -- the three steps, on one chunk of points
    def _candidates(self, sp: ShadingPoints, rng: np.random.Generator):
        """M candidates per point: world directions (P, M, 3), f cos without albedo (P, M), radiance
        times the colour that puts the albedo into f (P, M, 3; ShadingPoints.bsdf_value),
        p_hat (P, M) and resampling weights w = p_hat / q (P, M)."""
        p, m = len(sp), self.candidates
        rep = repeat_points(sp, m)
        u = rng.random((p * m, 2))
        if self.source == "light":
            d, q = self.light.sample_directions(u)
            wl = rep.to_local(d)
        else:
            wl, q = rep.bsdf_sample(u)
            d = rep.to_world(wl)
        fcos, tint = rep.bsdf_value(wl)   # f cos without albedo, and the colour that puts it in
        radiance = self.env.eval(d).astype(np.float64)
        p_hat = np.maximum(fcos, 0.0) * luminance(radiance)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            w = np.where(q > 0, p_hat / q, 0.0)
        w = np.where(np.isfinite(w) & (w > 0), w, 0.0)
        return (d.reshape(p, m, 3), fcos.reshape(p, m), radiance.reshape(p, m, 3) * tint.reshape(p, m, 3),
                p_hat.reshape(p, m), w.reshape(p, m))

    def _resample(self, w: np.ndarray, rng: np.random.Generator, n: int):
        """N candidate indices per point (P, N), drawn with probability w_j / sum w, with replacement;
        and the RIS weight W = sum w / M (P,)."""
        cdf = np.cumsum(w, axis=1)
        total = cdf[:, -1]
        r = rng.random((len(w), n)) * total[:, None]
        # index = number of cdf entries <= r: the first j with cdf_j > r (zero weights never win)
        idx = np.minimum((cdf[:, None, :] <= r[:, :, None]).sum(axis=2), w.shape[1] - 1)
        return idx, total / w.shape[1]

    def _chunk(self, sp: ShadingPoints, rng, n):
        d, fcos, radiance, p_hat, w = self._candidates(sp, rng)
        idx, big_w = self._resample(w, rng, n)
        pick = lambda a: np.take_along_axis(a, idx.reshape(idx.shape + (1,) * (a.ndim - 2)), axis=1)
        ph, fc = pick(p_hat), pick(fcos)
        with np.errstate(divide="ignore", invalid="ignore"):
            scalar = np.where(ph > 0, fc * big_w[:, None] / ph, 0.0)          # f cos W / p_hat, (P, N)
        scalar = np.where(np.isfinite(scalar), scalar, 0.0)
        return pick(d), scalar, pick(radiance), big_w

    def _run(self, sp: ShadingPoints, rng, n):
        count = len(sp)
        wi, scalar, radiance, big_w = np.zeros((count, n, 3)), np.zeros((count, n)), np.zeros((count, n, 3)), \
            np.zeros(count)
        step = max(1, min(CHUNK_CANDIDATES // self.candidates, CHUNK_COMPARISONS // (self.candidates * n)))
        for a in range(0, count, step):
            b = min(count, a + step)
            wi[a:b], scalar[a:b], radiance[a:b], big_w[a:b] = self._chunk(slice_points(sp, a, b), rng, n)
        return wi, scalar, radiance, big_w

    def _rng(self, u):
        return rng_from_uniforms(np.asarray(u, np.float64), "sir", self.candidates, self.samples, self.source)

    # -- public
    def shade(self, env, sp: ShadingPoints, u: np.ndarray):
        """The shader's call: wi (P, N, 3) world directions, value (P, N, 3) unoccluded estimates
        albedo f L cos W / (N p_hat) per slot; the integrator traces one shadow ray per non-zero
        slot and sums the visible ones (the estimator of the module docstring)."""
        if self.env is None or env is not self.env:
            self.prepare(env)
        wi, scalar, radiance, _ = self._run(sp, self._rng(u), self.samples)
        value = (scalar / self.samples)[..., None] * radiance
        return wi, value

    def ris_weight(self, sp: ShadingPoints, u: np.ndarray) -> np.ndarray:
        """W = (1/M) sum_j p_hat(x_j) / q(x_j) per point, (P,): an unbiased estimate of the
        unshadowed integral of f cos lum(L) (eq. 11 with luminance, without albedo)."""
        return self._run(sp, self._rng(u), 1)[3]

    def sample(self, sp, u):
        """One resampled direction per point (N = 1). Its ``pdf`` field is p_hat(y) / W, the
        reciprocal of the RIS contribution weight: f L cos / pdf is then the unbiased RIS
        estimate. It is not a density that :meth:`pdf` could evaluate (RIS has none in closed
        form), so sir cannot enter MIS."""
        wi, scalar, radiance, big_w = self._run(sp, self._rng(u), 1)
        d = wi[:, 0]
        fcos = np.maximum(sp.bsdf_eval_cos(sp.to_local(d)), 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            pdf = np.where(scalar[:, 0] > 0, fcos / scalar[:, 0], 0.0)
        return DirectionSamples(d, sp.to_local(d), pdf)

    def pdf(self, sp, wi_local, wi_world):
        raise NotImplementedError("sir: the density of a resampled direction has no closed form")

    def info(self):
        out = {"sir_candidates": self.candidates, "sir_samples": self.samples, "sir_source": self.source}
        if self.source == "light" and hasattr(self.light, "tree"):
            out.update(self.light.info())
        return out
