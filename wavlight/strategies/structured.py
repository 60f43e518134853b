"""The ``structured`` strategy: structured importance sampling of the environment
(Agarwal, Ramamoorthi, Belongie and Jensen 2003, "Structured importance sampling of
environment maps").

Strata (computed once per render, :meth:`StructuredStrategy.prepare`, vectorised numpy)
---------------------------------------------------------------------------------------
Every texel t of the lat-long map has a direction (its centre), a solid angle
dOmega_t = dphi (cos theta_0 - cos theta_1) (exact) and a power Phi_t = lum(L_t) dOmega_t.
Texels of power 0 (black) can never contribute to f L cos V and are left out (an all-black
map has no strata and every estimate is 0; a map of T < K texels gets T strata).

1. **Illumination levels.** Texels are thresholded by luminance into ``levels`` (default 4)
   layers, the thresholds placed at equal-energy quantiles: sorted by luminance, the
   texels' cumulative power crosses j/levels x Phi at the j-th threshold. A few very bright
   texels (a sun) then form the top layer by themselves; a smooth map gets layers of
   roughly equal energy. Empty layers (one texel holding more than 1/levels of the
   energy) are dropped.
2. **Strata per layer.** Layer j (energy E_j, solid angle Omega_j) gets
   n_j proportional to sqrt(E_j Omega_j) of the K strata (largest remainders, at least
   one per non-empty layer, at most its texel count). Agarwal et al. weight a layer by a
   power of its luminance times its area in the same spirit; we chose the geometric mean
   of energy and area because energy alone spends as many strata on a 50-texel sun as on
   the whole sky (refining a sun spatially gains nothing), and area alone ignores
   brightness.
3. **Hochbaum-Shmoys k-center within a layer.** Farthest-point clustering of the
   layer's texel directions (unit vectors, chordal distance |a - b|): the first center is
   the layer's most powerful texel, each next one the candidate farthest from all
   centers so far. This greedy choice is a 2-approximation of the optimal covering
   radius, because every new center is at least the current covering radius away from
   all previous ones (:func:`k_center` returns those radii; the tests check it). At most
   ``MAX_CANDIDATES`` texels per layer are candidates (a fixed-seed uniform subsample of
   larger layers); then *every* texel of the layer is assigned to its nearest center
   (largest dot product, in chunks): K strata in all, each a set of texels with power
   Phi_s = sum_t Phi_t and solid angle Omega_s = sum_t dOmega_t. The strata partition
   the non-black texels and conserve the power exactly.

Mode ``"stratified"`` (default; unbiased)
-----------------------------------------
By default (``samples = "strata"``) every shading sample draws one jittered direction
in *every* stratum s: a texel t of s with probability Phi_t / Phi_s, a point uniform in
solid angle within t; with p_s(w) = (Phi_t / Phi_s) / dOmega_t = lum(L_t) / Phi_s the
estimate is the sum over the strata of albedo f cos L V / p_s (K shadow rays), unbiased
because the strata partition the lit texels (Agarwal et al.'s stratified estimator).
The uniforms come from a numpy Generator seeded from the bytes of u (as
:mod:`wavlight.strategies.sir` does), so renders stay a deterministic function of the seed.

``samples = 1``: one direction per shading sample, a stratum with probability Phi_s / Phi
(u.x), a texel of it by power (u.y), a point in the texel (u.z, u.w):

    pdf(w) = (Phi_s / Phi) (Phi_t / Phi_s) / dOmega_t = lum(L_t) / Phi,

which **in distribution equals light sampling by texel power** (the integrator draws the
uniforms i.i.d. per pixel sample and gives the shader no pixel grouping). ``samples = n``:
n directions by systematic sampling over the stratum-ordered CDF, x_j = (j + u.x) / n,
each slot weighted 1/n.

Mode ``"preintegrated"`` (the original algorithm's use of the strata; **biased**)
--------------------------------------------------------------------------------
Each stratum is collapsed to one directional light at its power-weighted centroid
direction c_s (normalised sum of Phi_t w_t) carrying the stratum's RGB power
Phi_s^rgb = sum L_rgb dOmega. The shading point's estimate of the K lights' sum
sum_s albedo f(c_s) cos(c_s) Phi_s^rgb V(c_s) is: with K <= ``ALL_LIGHTS`` (8), all K
terms with K shadow rays; otherwise one light chosen with probability proportional to
w_s = f cos(c_s) Phi_s (luminance; u.x), the estimate albedo f cos Phi_s^rgb / (w_s /
sum w). That is an unbiased estimate *of the point-light sum*, not of the integral: the
lighting inside each stratum is replaced by a point, so glossy lobes narrower than a
stratum see spikes or miss the light, shadows become hard, and cos/BRDF variation across
a stratum is lost. The bias shrinks with K and vanishes for a map that is K points of
light; it is largest for smooth, wide maps with glossy BRDFs. ``info()`` says
``structured_biased: true`` and prepare emits a warning.
"""
from __future__ import annotations

import warnings

import numpy as np

from ..envmap import luminance
from ..errors import ArgumentError, check_int
from ..options import Option
from .sir import repeat_points, slice_points, rng_from_uniforms
from .base import DirectionSamples, ShadingPoints, Strategy

MODES = ("stratified", "preintegrated")
DEFAULT_STRATA = 16
PER_STRATUM = "strata"  # samples: one jittered direction in every stratum (the default)
DEFAULT_LEVELS = 4
MAX_STRATA = 1024
STRUCTURED_STRATA = Option("structured_strata", int, "structured: number of strata K (one shadow ray per stratum "
                           "and sample).", default=DEFAULT_STRATA, lo=1, hi=MAX_STRATA)
STRUCTURED_MODE = Option("structured_mode", str, "structured: stratified (unbiased) or preintegrated (biased: one "
                         "light per stratum).", default=MODES[0], values=MODES)
#: at most this many candidate texels per level enter the farthest-point loop
MAX_CANDIDATES = 4096
#: preintegrated: with at most this many strata, all lights get a shadow ray
ALL_LIGHTS = 8
#: about this many (point, light) or (texel, center) pairs are processed at once
CHUNK = 1 << 20


# ----------------------------------------------------------------------------- the strata
def texel_geometry(height: int, width: int):
    """Map-frame centre directions (H W, 3) and exact solid angles (H W,) of the lat-long texels."""
    t_edges = np.arange(height + 1) / height * np.pi
    d_omega_row = (2 * np.pi / width) * (np.cos(t_edges[:-1]) - np.cos(t_edges[1:]))
    theta = (np.arange(height) + 0.5) / height * np.pi
    phi = (np.arange(width) + 0.5) / width * 2 * np.pi
    st = np.sin(theta)[:, None]
    d = np.stack(np.broadcast_arrays(st * np.sin(phi)[None, :], np.cos(theta)[:, None],
                                     -st * np.cos(phi)[None, :]), -1).reshape(-1, 3)
    return d, np.repeat(d_omega_row, width)


def k_center(points: np.ndarray, k: int, first: int = 0):
    """Hochbaum-Shmoys farthest-point k-center on unit vectors (chordal distance).

    Returns (indices of the k centers into ``points``, radii) where radii[i] is the covering
    radius of all points by the first i+1 centers (radii[-1]: the final covering radius).
    """
    m = len(points)
    k = min(int(k), m)
    centers = np.empty(k, np.int64)
    radii = np.empty(k)
    centers[0] = first
    # squared chordal distance |a - b|^2 = 2 - 2 a.b, kept as the nearest-center distance
    dist = np.maximum(2.0 - 2.0 * (points @ points[first]), 0.0)
    for i in range(1, k):
        radii[i - 1] = np.sqrt(dist.max())
        nxt = int(np.argmax(dist))
        centers[i] = nxt
        dist = np.minimum(dist, np.maximum(2.0 - 2.0 * (points @ points[nxt]), 0.0))
    radii[k - 1] = np.sqrt(dist.max())
    return centers, radii


def nearest_center(points: np.ndarray, centers: np.ndarray) -> np.ndarray:
    """Index of the nearest of ``centers`` (C, 3) for every point (N, 3), in chunks."""
    out = np.empty(len(points), np.int64)
    step = max(1, CHUNK // max(1, len(centers)))
    for a in range(0, len(points), step):
        out[a:a + step] = np.argmax(points[a:a + step] @ centers.T, axis=1)
    return out


def _allocate(weight: np.ndarray, count: np.ndarray, k: int) -> np.ndarray:
    """k strata over levels in proportion to weight (largest remainder, one at a time):
    at least 1 per level, at most its texel count."""
    n = np.minimum(np.ones(len(weight), np.int64), count)
    k = max(min(int(k), int(count.sum())), int(n.sum()))
    target = weight / weight.sum() * k if weight.sum() > 0 else count / count.sum() * k
    while n.sum() < k:
        j = int(np.argmax(np.where(n < count, target - n, -np.inf)))
        n[j] += 1
    return n


class Strata:
    """The K strata of an environment (see the module docstring).

    texel : (T,) flat texel indices of the non-black texels, stratum-major;
    power : (T,) their power lum dOmega; cum : (T,) its running sum (float64);
    start, stop : (K,) each stratum's range in ``texel``; phi : (K,) Phi_s; omega : (K,)
    Omega_s; rgb : (K, 3) RGB power; centroid : (K, 3) power-weighted mean direction
    (world frame); level : (K,) the layer of each stratum; total : Phi.
    """

    def __init__(self, env, k: int = DEFAULT_STRATA, levels: int = DEFAULT_LEVELS, seed: int = 0):
        h, w = env.height, env.width
        dirs, d_omega = texel_geometry(h, w)
        rgb = env.pixels.reshape(-1, 3).astype(np.float64)
        lum = luminance(rgb)
        nz = np.nonzero(lum > 0)[0]
        self.texel_count = h * w
        if len(nz) == 0:
            raise ValueError("structured: the environment is black everywhere")
        power = lum[nz] * d_omega[nz]
        levels = max(1, min(int(levels), int(k)))
        # 1. layers by luminance, thresholds at equal-energy quantiles
        lum_nz = lum[nz]
        order = np.argsort(lum_nz, kind="stable")
        cum = np.cumsum(power[order])
        cross = np.searchsorted(cum, np.arange(1, levels) / levels * cum[-1], side="right")
        thresholds = lum_nz[order][np.minimum(cross, len(nz) - 1)]
        layer = np.searchsorted(thresholds, lum_nz, side="right")   # equal luminances share a layer
        used = np.unique(layer)
        layer = np.searchsorted(used, layer)                    # drop empty layers
        n_layers = len(used)
        energy = np.bincount(layer, power, n_layers)
        area = np.bincount(layer, d_omega[nz], n_layers)
        count = np.bincount(layer, minlength=n_layers)
        per_layer = _allocate(np.sqrt(energy * area), count, int(k))
        # 2-3. k-center per layer, then all texels to their nearest center
        rng = np.random.default_rng(seed)
        stratum = np.empty(len(nz), np.int64)
        stratum_layer, self.radii, base = [], [], 0
        for j in range(n_layers):
            members = np.nonzero(layer == j)[0]
            cand = members
            if len(cand) > MAX_CANDIDATES:
                cand = np.sort(rng.choice(members, MAX_CANDIDATES, replace=False))
                brightest = members[np.argmax(power[members])]
                if brightest not in cand:
                    cand[0] = brightest
            first = int(np.argmax(power[cand]))
            centers, radii = k_center(dirs[nz[cand]], per_layer[j], first)
            stratum[members] = base + nearest_center(dirs[nz[members]], dirs[nz[cand[centers]]])
            stratum_layer += [j] * len(centers)
            self.radii.append(radii)
            base += len(centers)
        k_eff = base
        # stratum-major order, and per-stratum sums
        o = np.argsort(stratum, kind="stable")
        self.texel = nz[o]
        self.power = power[o]
        self.cum = np.cumsum(self.power)
        sid = stratum[o]
        self.start = np.searchsorted(sid, np.arange(k_eff), side="left")
        self.stop = np.searchsorted(sid, np.arange(k_eff), side="right")
        self.stratum_of = sid
        self.phi = np.bincount(sid, self.power, k_eff)
        self.omega = np.bincount(sid, d_omega[self.texel], k_eff)
        self.rgb = np.stack([np.bincount(sid, rgb[self.texel, c] * d_omega[self.texel], k_eff) for c in range(3)], 1)
        weighted = np.stack([np.bincount(sid, self.power * dirs[self.texel, c], k_eff) for c in range(3)], 1)
        norm = np.linalg.norm(weighted, axis=1, keepdims=True)
        # a stratum whose power-weighted directions cancel (never for k-center strata) keeps its first texel
        fallback = dirs[self.texel[self.start]]
        centroid = np.where(norm > 1e-12 * self.phi[:, None], weighted / np.maximum(norm, 1e-300), fallback)
        self.centroid = centroid @ env.world_from_map.T
        self.level = np.array(stratum_layer, np.int64)
        self.layers = n_layers
        self.total = float(self.cum[-1])
        self.lum = lum
        self.d_omega = d_omega
        self.k = k_eff

    def sample_texels(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Positions in ``texel`` for uniforms x (the stratum, by Phi_s / Phi) and y (the texel
        within it, by Phi_t / Phi_s)."""
        ends = self.cum[self.stop - 1]
        begins = ends - self.phi
        s = np.minimum(np.searchsorted(ends, x * self.total, side="right"), self.k - 1)
        target = begins[s] + y * self.phi[s]
        pos = np.searchsorted(self.cum, target, side="right")
        return np.clip(pos, self.start[s], self.stop[s] - 1)


# ----------------------------------------------------------------------------- the strategy
class StructuredStrategy(Strategy):
    """Structured importance sampling (Agarwal et al. 2003): K strata from luminance layers and
    farthest-point k-center; ``mode`` "stratified" (unbiased) or "preintegrated" (biased)."""

    name = "structured"
    options = {"strata": STRUCTURED_STRATA, "mode": STRUCTURED_MODE}

    def __init__(self, strata: int | None = None, mode: str | None = None, samples: int | str = PER_STRATUM,
                 levels: int = DEFAULT_LEVELS):
        where = "strategies.StructuredStrategy"
        self.k = DEFAULT_STRATA if strata is None else self.checked("strata", strata)
        self.mode = MODES[0] if mode is None else self.checked("mode", mode)
        if samples is None or isinstance(samples, str):
            if samples not in (None, PER_STRATUM):
                raise ArgumentError(f"{where}: samples must be {PER_STRATUM!r} or an integer, got {samples!r}")
            self.samples = PER_STRATUM
        else:
            self.samples = check_int(where, "samples", samples, 1)
        self.levels = check_int(where, "levels", levels, 1)
        self.env = None

    def prepare(self, environment, materials=()):
        self.env = environment
        # an all-black map has no strata: every estimate is 0 (as the integral is)
        self.strata = None if environment.is_black else Strata(environment, self.k, self.levels)
        if self.mode == "preintegrated":
            warnings.warn("structured: preintegrated mode is biased (each stratum collapsed to one directional "
                          "light); use structured_mode = \"stratified\" for an unbiased estimate", stacklevel=2)

    # -- stratified
    def _texel_directions(self, pos, a, b):
        """World directions uniform in solid angle within texels ``texel[pos]`` (uniforms a, b)."""
        t = self.strata.texel[pos]
        h, w = self.env.height, self.env.width
        row, col = t // w, t % w
        phi = (col + a) / w * 2 * np.pi
        z0, z1 = np.cos(row / h * np.pi), np.cos((row + 1) / h * np.pi)
        z = z0 + b * (z1 - z0)
        st = np.sqrt(np.maximum(1.0 - z * z, 0.0))
        d = np.stack([np.sin(phi) * st, z, -np.cos(phi) * st], 1)
        return d @ self.env.world_from_map.T, t

    def sample(self, sp, u):
        """One direction per point by u (P, 4): stratum u[:,0], texel u[:,1], point u[:,2:4];
        pdf = lum(texel) / Phi."""
        u = np.asarray(u, np.float64)
        if self.strata is None:
            d = np.tile([0.0, 1.0, 0.0], (len(sp), 1))
            return DirectionSamples(d, sp.to_local(d), np.zeros(len(sp)))
        d, t = self._texel_directions(self.strata.sample_texels(u[:, 0], u[:, 1]), u[:, 2], u[:, 3])
        return DirectionSamples(d, sp.to_local(d), self.strata.lum[t] / self.strata.total)

    def pdf(self, sp, wi_local, wi_world):
        if self.strata is None:
            return np.zeros(len(wi_world))
        return self.strata.lum[self.env.texel_index(wi_world)] / self.strata.total

    def _per_stratum(self, sp: ShadingPoints, u):
        """One jittered direction in every stratum (K slots): texel by power within the stratum,
        point uniform in the texel; estimate f cos L / p_s with p_s = lum(texel) / Phi_s, summed
        over the strata (Agarwal et al.'s stratified estimator, unbiased)."""
        st = self.strata
        p, k = len(sp), st.k
        rng = rng_from_uniforms(u, "structured-strata", k)
        y, a, b = rng.random((3, p, k))
        begins = (st.cum[st.stop - 1] - st.phi)[None, :]
        pos = np.searchsorted(st.cum, (begins + y * st.phi[None, :]).ravel(), side="right")
        pos = np.clip(pos, np.tile(st.start, p), np.tile(st.stop - 1, p))
        d, t = self._texel_directions(pos, a.ravel(), b.ravel())
        rep = repeat_points(sp, k)
        fcos, tint = rep.bsdf_value(rep.to_local(d))
        rgb = self.env.pixels.reshape(-1, 3)[t].astype(np.float64)
        scalar = np.maximum(fcos, 0.0) * np.tile(st.phi, p) / st.lum[t]
        value = scalar[:, None] * rgb * tint
        return d.reshape(p, k, 3), value.reshape(p, k, 3)

    def _stratified(self, sp: ShadingPoints, u):
        if self.samples == PER_STRATUM:
            return self._per_stratum(sp, u)
        p, n = len(sp), self.samples
        if n == 1:
            x, y, a, b = (u[:, i:i + 1] for i in range(4))
        else:
            rng = rng_from_uniforms(u, "structured", self.k, n)
            x = (np.arange(n)[None, :] + u[:, :1]) / n             # systematic over the stratum CDF
            y, a, b = rng.random((3, p, n))
        d, t = self._texel_directions(self.strata.sample_texels(x.ravel(), y.ravel()), a.ravel(), b.ravel())
        rep = repeat_points(sp, n)
        fcos, tint = rep.bsdf_value(rep.to_local(d))
        rgb = self.env.pixels.reshape(-1, 3)[t].astype(np.float64)
        scalar = np.maximum(fcos, 0.0) * self.strata.total / self.strata.lum[t] / n
        value = scalar[:, None] * rgb * tint
        return d.reshape(p, n, 3), value.reshape(p, n, 3)

    # -- preintegrated
    def _preintegrated(self, sp: ShadingPoints, u):
        st = self.strata
        p, k = len(sp), st.k
        rep = repeat_points(sp, k)
        d = np.tile(st.centroid, (p, 1))
        fcos, tint = rep.bsdf_value(rep.to_local(d))
        fcos, tint = np.maximum(fcos, 0.0).reshape(p, k), tint.reshape(p, k, 3)   # tint: albedo x f's colour
        if k <= ALL_LIGHTS:
            value = fcos[:, :, None] * st.rgb[None, :, :] * tint
            return np.broadcast_to(st.centroid, (p, k, 3)).copy(), value
        w = fcos * st.phi[None, :]
        cdf = np.cumsum(w, axis=1)
        total = cdf[:, -1]
        pick = np.minimum((cdf <= (u[:, 0] * total)[:, None]).sum(axis=1), k - 1)
        rows = np.arange(p)
        value = np.where((total > 0)[:, None], st.rgb[pick] / st.phi[pick, None] * total[:, None], 0.0) * tint[rows, pick]
        value = np.where((fcos[rows, pick] > 0)[:, None], value, 0.0)
        return st.centroid[pick][:, None, :], value[:, None, :]

    def shade(self, env, sp: ShadingPoints, u: np.ndarray):
        """The shader's call: wi (P, S, 3) world directions and value (P, S, 3) unoccluded
        estimates per slot (stratified: S = K with samples = "strata", the default, else
        ``samples``; preintegrated: 1 or K)."""
        if self.env is None or env is not self.env:
            self.prepare(env)
        u = np.asarray(u, np.float64)
        if self.strata is None:
            return np.zeros((len(sp), 1, 3)), np.zeros((len(sp), 1, 3))
        fn = self._stratified if self.mode == "stratified" else self._preintegrated
        per = self.strata.k if (self.mode != "stratified" or self.samples == PER_STRATUM) else self.samples
        step = max(1, CHUNK // per)
        parts = [fn(slice_points(sp, a, min(len(sp), a + step)), u[a:a + step]) for a in range(0, len(sp), step)]
        if not parts:
            s = per if (self.mode == "stratified" or self.strata.k <= ALL_LIGHTS) else 1
            return np.zeros((0, s, 3)), np.zeros((0, s, 3))
        return np.concatenate([q[0] for q in parts]), np.concatenate([q[1] for q in parts])

    def info(self):
        out = {"structured_mode": self.mode, "structured_strata": self.k,
               "structured_biased": self.mode == "preintegrated"}
        if getattr(self, "strata", None) is not None:
            out.update(structured_strata=int(self.strata.k), structured_layers=int(self.strata.layers))
        if self.mode == "preintegrated":
            out["structured_note"] = "biased: each stratum collapsed to one directional light"
        out["structured_samples"] = self.samples
        return out
