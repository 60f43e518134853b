"""The stability suite: adversarial cases x every strategy, tested for bias, variance, fireflies and failures.

    results = wavlight.evaluation.stability.run_stability("out/stability")

or ``wavlight experiment --suite stability -o out/stability`` (about 2-2.5 minutes on 2 cores). The
strategies are every id of ``wavlight.scene.STRATEGIES`` at call time, so new ones join without
an edit. A small version runs in ``tests/evaluation/test_stability.py``: ``QUICK_CASES`` (the cases with
analytic answers and light enough tails, and the all-black map) at 12 x 12 pixels, 3 x 32 spp.

**Cases** (:data:`CASES`, from ``shared/docs/method.md``, "Failure modes to test"; each builds its
scene as a dict for :func:`wavlight.load_dict`, its generated maps given as float32 arrays
(``[environment] pixels``: no file is written, and the pixels are those a float32 .exr or .pfm
of them would hold); the real maps are those that ship with wavlight (:mod:`wavlight.data`), so
that the suite runs offline):

==================  ==========================================================  ===========
case                what it probes                                              reference
==================  ==========================================================  ===========
sun_synthetic       a 0.5 degree (diameter) sun of 1e5 over a dim sky,          analytic
                    1024 x 512, lambert floor
sun_rooitou         rooitou_park_512 (66% of the energy in 13 texels),          mis
                    ggx 0.05 sphere on a lambert floor
mirror_ggx          near-mirror ggx (alpha 0.005) sphere on a floor under the    mis
                    procedural sky (0.75 degree sun of 2e4)
overcast_lambert    lambert floor under a smooth CIE overcast map (.pfm)        analytic
grazing             ggx 0.2 and phong 50 quads seen at 80-89 degrees from       mis
                    their normal, under the procedural sky
room_slit           a closed room lit only through a slit under its front wall  mis
                    (procedural sky, sun 8 degrees up): the map's bright
                    directions are blocked almost everywhere; ggx 0.1 sphere
one_texel           a 32 x 16 map black except one texel of 500                 analytic
all_black           an all-black map (the CLI refuses it; the library renders   exactly 0
                    black): ggx sphere on a lambert floor
black_by_lamps      st_fagans_interior_512 with the black texels of the small   mis
                    Debevec probes: next to its lamps, and a bottom band
                    (:func:`black_around_lamps`), ggx 0.1 sphere on a floor
bad_texels          a sky with NaN, +Inf, -Inf and negative texels (a warning   analytic
                    is expected), lambert floor
npot_map            a 37 x 19 map (non-power-of-two, odd height: the horizon    analytic
                    cuts a row), floor seen at grazing angles
tiny_2x1            a 2 x 1 map (two texels), lambert floor                     analytic
tiny_1x1            a 1 x 1 map: the furnace, L = albedo x radiance             analytic
==================  ==========================================================  ===========

**References.** *Analytic*: a lambert floor (normal +Y, nothing above it, every camera ray of the
measured pixels hits it) under a piecewise-constant lat-long map reflects
``albedo / pi x sum over texels of L_texel x integral of cos(theta) over the texel's part of the
upper hemisphere``; a texel row [theta0, theta1] of width 2 pi / W contributes
``(2 pi / W) (sin^2 min(theta1, pi/2) - sin^2 theta0) / 2`` (rotate_y does not change it). It is
computed here in float64 from the pixels the case wrote (NaN, Inf and negative texels set to 0
by this module, independently of wavlight's sanitising) or, for real maps, read. Only pixels whose
four corner rays hit the floor are tested (all of them in every case here). *mis*: a
``reference_spp`` (default 4096) render with ``mis`` and seed 1000003 (apart from the
repetitions' seeds 0..R-1); its per-pixel standard error enters every test. *exactly 0*: the
all-black map, where every pixel of every strategy must be exactly 0 with a zero standard error.

**Per case and strategy** (a *cell*): R renders (``repetitions``, default 4, seeds 0..R-1) at
``spp`` (default 128) and ``size`` (default 24 x 24), each giving an image x_k and a per-pixel
standard error s_k (:class:`wavlight.RenderResult`). Then, with r the reference and s_r its
standard error (0 when analytic), per pixel and channel:

- the mean xbar = mean_k x_k, its squared standard error se^2 = sum_k s_k^2 / R^2, with
  nu = R (spp - 1) degrees of freedom;
- ``z_pixel`` = (xbar - r) / sqrt(se^2 + s_r^2);
- per channel c, the image mean's difference d_c = mean over the N tested pixels of (xbar - r)
  and its standard error sqrt(sum (se^2 + s_r^2)) / N (pixels are independent estimates: each
  draws its own samples); ``z_mean`` is the d_c / se_c of largest magnitude (channels are tested
  separately: they share samples, so pooling them as independent values, as
  :func:`wavlight.evaluation.metrics.bias` does, would understate the standard error);
- float32 rounding: |d| is first reduced by 1e-5 |r| + 1e-6 (the zero-variance estimators, e.g.
  cosine sampling of a lambert floor under a constant map, are exact only up to it); a zero
  standard error with a difference left is |z| = ``Z_CAP`` (1e9; z is capped there in all outputs).

**The bias test and its thresholds.** The whole run controls its family-wise false-alarm rate at
``alpha`` (default 0.01): it is split evenly between the n cells that were tested, and in each
cell evenly between the image-mean test (3 channels) and the per-pixel test (3 N values), with
Bonferroni corrections, so

    t_mean  = Student-t quantile(1 - alpha / (2 n 3) / 2, nu)
    t_pixel = Student-t quantile(1 - alpha / (2 n 3 N) / 2, nu)

(the quantile by the Cornish-Fisher expansion of the normal one; for the full suite, n = 117, N =
576, nu = 508: t_mean = 4.38, t_pixel = 5.66). A cell is "biased?" only when |z_mean| > t_mean,
or when the per-pixel test applies and some pixel's |z_pixel| > t_pixel.

**Heavy tails.** These z-scores assume that the means are close to normal. An unbiased estimator
whose energy comes in rare, huge samples (bsdf or uniform sampling of a tiny sun: one sample in
~1e4 carries most of the integral) breaks that: a pixel (or a repetition) that drew none of them
is too low *and* has a too small standard error, which no finite test can tell from a bias. Two
measures, both from the spread of the R per-repetition variances, decide which tests can be
trusted:

- ``vov``, the *variance of the variance* of the image mean (as MCNP's VOV check): with v_k the
  summed squared standard errors of repetition k, vov = var_k(v_k) / mean_k(v_k)^2 (about 1e-5
  for well-behaved estimators here, above 0.1 when some repetitions caught rare samples and others
  did not). With ``vov`` > ``VOV_LIMIT`` (0.1, MCNP's limit) the cell is ``heavy_tail``: the
  per-pixel test is not applied, and a failed image-mean test reads "heavy-tail?" (inconclusive)
  instead of "biased?".
- ``pixel_skew``, a bound on the skewness of a pixel's mean of R spp samples: ``pixel_vov``, the
  mean over the tested pixels and channels of var_k(s_k^2) / mean_k(s_k^2)^2, estimates the
  relative variance of a variance of spp samples, (kurtosis - (spp-3)/(spp-1)) / spp; Pearson's
  inequality skewness^2 <= kurtosis - 1 bounds the skewness, and the excess over the normal's
  kurtosis is used, skewness^2 ~ kurtosis - 3 (tight for the rare-large-sample laws that matter
  here), divided by R spp for the mean. The extreme quantiles of the per-pixel test (t_pixel ~
  5.6) are sensitive to skewness (an Edgeworth correction of order skewness x t^3 / 3), so the
  per-pixel test is applied only when ``pixel_skew`` <= ``PIXEL_SKEW_LIMIT`` (0.2; in the full
  suite every cell the per-pixel test wrongly rejected before this rule had pixel_skew >= 0.28,
  every accepted one <= 0.2). Within it, pixels whose per-repetition variances differ by more than
  ``PIXEL_SPREAD_LIMIT`` (10x), or are 0 in every repetition while the pixel differs from the
  reference, are not tested (``pixels_tail``): their standard error is itself unreliable.

What no test on finitely many samples can see: an estimator whose rare samples were missed by
every repetition (the variances then agree); its cell reads "biased?". The full suite's budgets
are chosen so that the tiny suns are hit many times per cell; the image-mean test, on all R spp N
samples of a cell, is by far the more robust of the two.

**Other measures per cell.** ``variance`` and ``rel_variance``: :func:`wavlight.evaluation.metrics.mean_variance`
and :func:`~wavlight.evaluation.metrics.relative_variance` over the R repetitions (variance of one render's
pixel); ``relmse``: mean over repetitions of :func:`~wavlight.evaluation.metrics.relmse` (reference-variance
corrected); ``firefly``: the largest |x_k - r| over repetitions, pixels and channels divided by
the mean of r over the tested pixels (the largest error itself when that mean is 0); ``seconds``:
setup + sampling of the R renders (the first render of a strategy in a process includes its
kernel build). **Failures**: any exception (caught, recorded as ``Type: first line``), and any
NaN or Inf in an image or standard error (counted in ``nan_values``; never expected). The
all-black case records ``exact_zero``; the bad-texel case records the warnings of loading its
scene (``warnings``) and fails when the expected one is missing.

**Verdict** per cell: ``failed`` (exception, NaN/Inf, missing expected warning, or no
reference), ``biased?``, ``heavy-tail?`` (see above) or ``ok``.

**Outputs** in DIR: ``stability.csv`` (one row per cell), ``stability.json`` (settings, cases,
cells, thresholds, seconds; no NaN: non-finite numbers are written as null), and
``charts/stability.png`` / ``.svg``: per case (rows) and strategy (columns) the bias evidence
max(|z_mean| / t_mean, |z_pixel| / t_pixel) on a log colour scale (above 1 = the test rejects;
"(mean only)" / "(tail)": the per-pixel test did not apply, see above), and log10 of the relative
variance; failed cells are crossed out, and each cell is labelled with its
verdict. :func:`format_table` gives the text table the CLI prints (column ``tested``: mean+px,
mean, or mean (tail) for heavy-tailed cells).
"""
from __future__ import annotations

import json
import math
import os
import statistics
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from . import metrics
from .spec import REFERENCE_SEED
from ..errors import WavlightError, described
from ..version import __version__

Z_CAP = 1e9
VOV_LIMIT = 0.1
PIXEL_SKEW_LIMIT = 0.2
PIXEL_SPREAD_LIMIT = 10.0
DEFAULTS = dict(size=(24, 24), spp=128, repetitions=4, reference_spp=4096, alpha=0.01)
QUICK_CASES = ("overcast_lambert", "one_texel", "all_black", "bad_texels", "npot_map", "tiny_2x1", "tiny_1x1")


# ----------------------------------------------------------------------------- scenes
def scene_dict(*, camera, environment, objects, materials, width, height) -> dict:
    """A case's scene as a dict for :func:`wavlight.load_dict` (render settings: size only; the rest
    is passed to render_full)."""
    return {"render": {"width": width, "height": height}, "camera": camera, "environment": environment,
            "objects": list(objects), "materials": materials}


def given_map(pixels) -> dict:
    """An ``[environment]`` table of a generated map: its pixels as float32 (what a float32 .exr or
    .pfm of them holds; NaN, Inf and negative texels kept for the scene's own sanitising)."""
    with np.errstate(over="ignore", invalid="ignore"):
        return {"pixels": np.asarray(pixels, np.float32)}


def sanitized(pixels) -> np.ndarray:
    """float64 copy with NaN, Inf and negative values set to 0 (this module's own rule, per value)."""
    p = np.asarray(pixels, np.float64)
    return np.where(np.isfinite(p) & (p >= 0), p, 0.0)


def floor_radiance(pixels, albedo) -> np.ndarray:
    """(3,) radiance of an unoccluded lambert floor (normal +Y) under a lat-long map (H, W, 3).

    albedo / pi x sum over texels of L x (2 pi / W) (sin^2 min(theta1, pi/2) - sin^2 theta0) / 2
    for the texel rows [theta0, theta1] that start above the horizon (theta0 < pi/2).
    """
    p = sanitized(pixels)
    h, w = p.shape[:2]
    t0 = np.arange(h) * np.pi / h
    t1 = np.minimum((np.arange(h) + 1) * np.pi / h, np.pi / 2)
    rows = np.where(t0 < np.pi / 2, (np.sin(t1) ** 2 - np.sin(t0) ** 2) / 2, 0.0) * (2 * np.pi / w)
    return np.asarray(albedo, np.float64) / np.pi * np.einsum("h,hwc->c", rows, p)


def floor_mask(scene, width, height, half_size) -> np.ndarray:
    """(H, W) bool: pixels whose four corner rays hit the floor quad (y = 0, |x|, |z| < half_size)."""
    from ..camera import camera_rays

    py, px = np.mgrid[0:height, 0:width]
    ok = np.ones(width * height, bool)
    for jx, jy in ((0, 0), (1, 0), (0, 1), (1, 1)):
        jit = np.tile([float(jx), float(jy)], (width * height, 1))
        o, d = camera_rays(scene, px.ravel().astype(float), py.ravel().astype(float), jit, width, height)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -o[:, 1] / d[:, 1]
        hit = o + t[:, None] * d
        ok &= (t > 0) & (np.abs(hit[:, 0]) < half_size) & (np.abs(hit[:, 2]) < half_size)
    return ok.reshape(height, width)


# ----------------------------------------------------------------------------- cases
@dataclass
class Built:
    """A case's scene (a dict for wavlight.load_dict) and how to judge it."""

    scene: dict
    reference: str                  # "analytic" | "mis" | "zero"
    expected: np.ndarray | None = None   # (3,) or (H, W, 3): the analytic reference
    floor_half: float | None = None      # analytic floor: pixels must hit it (see floor_mask)
    expect_warning: str | None = None    # a fragment of a warning that loading must emit
    note: str = ""


@dataclass
class Case:
    name: str
    title: str
    build: object                    # build(width, height) -> Built
    info: dict = field(default_factory=dict)


CASES: dict[str, Case] = {}


def case(name, title):
    def register(fn):
        CASES[name] = Case(name, title, fn)
        return fn
    return register


LAMBERT_FLOOR = {"type": "lambert", "albedo": [0.6, 0.6, 0.6]}
FLOOR_ALBEDO = np.array([0.6, 0.6, 0.6])


def _floor_case(width, height, env_table, pixels, *, eye=(0.0, 3.0, 3.0), target=(0.0, 0.0, 0.0),
                fov=30.0, half=15.0, expect_warning=None, note="") -> Built:
    scale = float(env_table.get("scale", 1.0))
    scene = scene_dict(camera={"eye": list(eye), "target": list(target), "up": [0.0, 1.0, 0.0],
                                       "fov_y": fov},
                       environment=env_table,
                       objects=[{"shape": "quad", "center": [0.0, 0.0, 0.0], "normal": [0.0, 1.0, 0.0],
                                 "size": 2 * half, "material": "floor"}],
                       materials={"floor": LAMBERT_FLOOR}, width=width, height=height)
    return Built(scene, "analytic", floor_radiance(pixels, FLOOR_ALBEDO) * scale, floor_half=half,
                 expect_warning=expect_warning, note=note)


def _sphere_floor(width, height, env_table, sphere_mat, *, eye=(0.0, 1.4, 4.2), target=(0.0, 0.8, 0.0),
                  fov=32.0, floor=True, reference="mis") -> Built:
    objects = [{"shape": "sphere", "center": [0.0, 0.8, 0.0], "radius": 0.8, "subdivisions": 4,
                "material": "ball"}]
    mats = {"ball": sphere_mat}
    if floor:
        objects.append({"shape": "quad", "center": [0.0, 0.0, 0.0], "normal": [0.0, 1.0, 0.0], "size": 12.0,
                        "material": "floor"})
        mats["floor"] = LAMBERT_FLOOR
    scene = scene_dict(camera={"eye": list(eye), "target": list(target), "up": [0.0, 1.0, 0.0],
                                       "fov_y": fov},
                       environment=env_table, objects=objects, materials=mats, width=width, height=height)
    return Built(scene, reference)


def _dim_sky(width, height, factor=0.5):
    from ..envmap import procedural_sky
    return procedural_sky(sun_radiance=0.0, width=width, height=height).astype(np.float64) * factor


def sun_disk_coverage(width, height, elevation, azimuth, radius_deg, k=8) -> np.ndarray:
    """(H, W) fraction of each texel covered by a disk of angular radius radius_deg (k x k supersampling)."""
    el, az = math.radians(elevation), math.radians(azimuth)
    sun = np.array([math.cos(el) * math.sin(az), math.sin(el), -math.cos(el) * math.cos(az)])
    th = (np.arange(height * k) + 0.5) / (height * k) * np.pi
    rows = np.nonzero(np.abs(th - (np.pi / 2 - el)) < math.radians(radius_deg) + 2 * np.pi / height)[0]
    ph = (np.arange(width * k) + 0.5) / (width * k) * 2 * np.pi
    t, p = th[rows][:, None], ph[None, :]
    d = np.stack(np.broadcast_arrays(np.sin(t) * np.sin(p), np.cos(t) + 0 * p, -np.sin(t) * np.cos(p)), -1)
    rr, cc = np.nonzero(d @ sun > math.cos(math.radians(radius_deg)))
    cov = np.zeros((height, width))
    np.add.at(cov, (rows[rr] // k, cc // k), 1.0 / (k * k))
    return cov


@case("sun_synthetic", "0.5 deg sun of 1e5 over a dim sky (1024x512), lambert floor")
def _sun_synthetic(width, height):
    w, h = 1024, 512
    pix = _dim_sky(w, h)
    cov = sun_disk_coverage(w, h, 40.0, 30.0, 0.25)
    pix += cov[..., None] * 1e5
    return _floor_case(width, height, given_map(pix), pix,
                       note=f"sun on {int((cov > 0).sum())} texels, {100 * _sun_share(pix, cov):.0f}% of the floor's light")


def _sun_share(pix, cov):
    sun = pix * (cov[..., None] > 0)
    return float(floor_radiance(sun, [1, 1, 1]).mean() / floor_radiance(pix, [1, 1, 1]).mean())


@case("sun_rooitou", "rooitou_park_512 tiny sun, ggx 0.05 sphere on a lambert floor")
def _sun_rooitou(width, height):
    env = {"file": "data:rooitou_park_512"}
    return _sphere_floor(width, height, env, {"type": "ggx", "albedo": [0.95, 0.8, 0.5], "roughness": 0.05})


@case("mirror_ggx", "near-mirror ggx 0.005 sphere on a floor, procedural sky (0.75 deg sun of 2e4)")
def _mirror_ggx(width, height):
    env = {"procedural": "sky", "sun_elevation": 30.0, "sun_azimuth": 160.0}
    return _sphere_floor(width, height, env, {"type": "ggx", "albedo": [0.9, 0.9, 0.9], "roughness": 0.005})


@case("overcast_lambert", "lambert floor under a smooth CIE overcast map (128x64 .pfm)")
def _overcast(width, height):
    w, h = 128, 64
    theta = (np.arange(h) + 0.5) / h * np.pi
    sky = np.where(theta < np.pi / 2, (1 + 2 * np.cos(theta)) / 3, 0.15)
    pix = np.broadcast_to(sky[:, None, None] * np.array([0.9, 0.95, 1.0]), (h, w, 3)).copy()
    return _floor_case(width, height, {**given_map(pix), "rotate_y": 40.0}, pix)


@case("grazing", "ggx 0.2 and phong 50 quads seen 80-89 deg off their normal, procedural sky")
def _grazing(width, height):
    scene = scene_dict(camera={"eye": [0.0, 0.35, 6.0], "target": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0],
                                       "fov_y": 8.0},
                       environment={"procedural": "sky", "sun_elevation": 12.0, "sun_azimuth": 170.0},
                       objects=[{"shape": "quad", "center": [-50.0, 0.0, 0.0], "normal": [0.0, 1.0, 0.0],
                                 "size": [100.0, 200.0], "material": "glossy"},
                                {"shape": "quad", "center": [50.0, 0.0, 0.0], "normal": [0.0, 1.0, 0.0],
                                 "size": [100.0, 200.0], "material": "shiny"}],
                       materials={"glossy": {"type": "ggx", "albedo": [0.9, 0.9, 0.9], "roughness": 0.2},
                                  "shiny": {"type": "phong", "albedo": [0.8, 0.8, 0.8], "exponent": 50.0}},
                       width=width, height=height)
    return Built(scene, "mis")


@case("room_slit", "a closed room lit through a slit under the front wall (procedural sky, low sun), "
                   "ggx 0.1 sphere on its lambert floor")
def _room_slit(width, height):
    # 4 x 3 x 4 room; the front wall (z = 2) stops 0.4 above the floor, and the sun, 8 deg up
    # in the +z direction, lights the floor through that slit; every strategy that samples the
    # map (light, mis, wavelet, sir, structured) sends most samples to blocked directions
    wall = {"material": "wall"}
    objects = [dict(wall, shape="quad", center=[0.0, 0.0, 0.0], normal=[0.0, 1.0, 0.0], size=4.0),
               dict(wall, shape="quad", center=[0.0, 3.0, 0.0], normal=[0.0, -1.0, 0.0], size=4.0),
               dict(wall, shape="quad", center=[0.0, 1.5, -2.0], normal=[0.0, 0.0, 1.0], size=[4.0, 3.0]),
               dict(wall, shape="quad", center=[-2.0, 1.5, 0.0], normal=[1.0, 0.0, 0.0], size=[4.0, 3.0]),
               dict(wall, shape="quad", center=[2.0, 1.5, 0.0], normal=[-1.0, 0.0, 0.0], size=[4.0, 3.0]),
               dict(wall, shape="quad", center=[0.0, 1.7, 2.0], normal=[0.0, 0.0, -1.0], size=[4.0, 2.6]),
               {"shape": "sphere", "center": [0.0, 0.6, -0.6], "radius": 0.6, "subdivisions": 4, "material": "ball"}]
    scene = scene_dict(camera={"eye": [0.0, 1.6, 1.6], "target": [0.0, 0.5, -1.0], "up": [0.0, 1.0, 0.0],
                                       "fov_y": 60.0},
                       environment={"procedural": "sky", "sun_elevation": 8.0, "sun_azimuth": 180.0},
                       objects=objects,
                       materials={"wall": LAMBERT_FLOOR,
                                  "ball": {"type": "ggx", "albedo": [0.9, 0.9, 0.9], "roughness": 0.1}},
                       width=width, height=height)
    return Built(scene, "mis", note="light enters only through a 0.4-high slit")


@case("one_texel", "a 32x16 map black but one texel of 500, lambert floor")
def _one_texel(width, height):
    pix = np.zeros((16, 32, 3))
    pix[3, 9] = 500.0
    return _floor_case(width, height, given_map(pix), pix)


@case("all_black", "all-black map (library: black image; CLI: refused), ggx sphere on a floor")
def _all_black(width, height):
    b = _sphere_floor(width, height, given_map(np.zeros((8, 16, 3))),
                      {"type": "ggx", "albedo": [0.9, 0.9, 0.9], "roughness": 0.1}, reference="zero")
    b.note = "the CLI refuses this scene (exit code 2); every strategy must give exactly 0"
    return b


def black_around_lamps(pixels, lamp: float = 100.0, band: float = 1 / 16) -> np.ndarray:
    """(H, W, 3) float32: a lat-long map with the black texels of the small Debevec probes made
    in it: the texels next to a lamp (the 8 neighbours, wrapping around in u, of each texel whose
    luminance exceeds ``lamp`` times the map's mean over solid angle; lamps themselves are kept),
    where those probes' resampling filter left clamped negative lobes, and the bottom ``band`` of
    the rows, where a probe has no data. A sampler whose pdf is 0 where the integrand is not is
    biased under it; the probes themselves do not ship (their terms are unstated)."""
    from ..envmap import luminance

    p = np.array(pixels, np.float32)
    h = p.shape[0]
    lum = luminance(p.astype(np.float64))
    theta = np.arange(h + 1) * np.pi / h
    solid = (np.cos(theta[:-1]) - np.cos(theta[1:]))[:, None]
    lamps = lum > lamp * (lum * solid).sum() / (solid.sum() * lum.shape[1])
    near = np.zeros_like(lamps)
    for dy in (-1, 0, 1):
        rows = np.zeros_like(lamps)
        rows[max(dy, 0):h + min(dy, 0)] = lamps[max(-dy, 0):h - max(dy, 0)]
        for dx in (-1, 0, 1):
            near |= np.roll(rows, dx, axis=1)
    p[near & ~lamps] = 0.0
    p[h - int(round(band * h)):] = 0.0
    return p


@case("black_by_lamps", "st_fagans_interior_512 with black texels next to its lamps and a black bottom band "
                        "(as the small Debevec probes), ggx 0.1 sphere on a floor")
def _black_by_lamps(width, height):
    from ..data import path
    from ..envmap import read_image

    env = given_map(black_around_lamps(read_image(str(path("st_fagans_interior_512")))))
    return _sphere_floor(width, height, env, {"type": "ggx", "albedo": [0.9, 0.9, 0.9], "roughness": 0.1},
                         eye=(0.0, 2.6, 3.6), target=(0.0, 0.6, 0.0))


@case("bad_texels", "sky with NaN, +Inf, -Inf and negative texels (warning expected), lambert floor")
def _bad_texels(width, height):
    rng = np.random.default_rng(7)
    pix = _dim_sky(64, 32, 1.0)
    pix[4, 10] = 40.0                                      # a lamp, so the map is not trivially smooth
    flat = pix.reshape(-1, 3)
    idx = rng.choice(len(flat), 28, replace=False)
    flat[idx[:10], rng.integers(0, 3, 10)] = np.nan
    flat[idx[10:15]] = np.inf
    flat[idx[15:18], 1] = -np.inf
    flat[idx[18:], :] = -5.0
    return _floor_case(width, height, given_map(pix), pix, expect_warning="NaN, Inf or negative",
                       note="28 bad texels (10 NaN, 5 +Inf, 3 -Inf, 10 negative)")


@case("npot_map", "37x19 map (non-power-of-two, odd height), floor seen at 84-89 deg")
def _npot(width, height):
    rng = np.random.default_rng(3)
    pix = _dim_sky(37, 19) + rng.gamma(2.0, 0.1, (19, 37, 3))
    pix[5, 30] = 80.0
    return _floor_case(width, height, {**given_map(pix), "rotate_y": -25.0}, pix,
                       eye=(0.0, 0.5, 6.0), fov=8.0, half=100.0)


@case("tiny_2x1", "a 2x1 map (two texels), lambert floor")
def _tiny_2x1(width, height):
    pix = np.array([[[2.0, 1.0, 0.5], [0.25, 1.0, 3.0]]])
    return _floor_case(width, height, {**given_map(pix), "rotate_y": 10.0}, pix)


@case("tiny_1x1", "a 1x1 map (the furnace: albedo x radiance), lambert floor")
def _tiny_1x1(width, height):
    pix = np.array([[[1.5, 1.0, 0.5]]])
    return _floor_case(width, height, {**given_map(pix), "scale": 2.0}, pix)


# ----------------------------------------------------------------------------- statistics
def t_quantile(p_upper: float, dof: float) -> float:
    """Student-t quantile t with P(T > t) = p_upper (Cornish-Fisher expansion of the normal quantile)."""
    z = -statistics.NormalDist().inv_cdf(p_upper)
    if not math.isfinite(dof) or dof <= 0:
        return z
    v = float(dof)
    return (z + (z ** 3 + z) / (4 * v) + (5 * z ** 5 + 16 * z ** 3 + 3 * z) / (96 * v ** 2)
            + (3 * z ** 7 + 19 * z ** 5 + 17 * z ** 3 - 15 * z) / (384 * v ** 3))


def thresholds(alpha: float, n_cells: int, n_pixels: int, dof: float) -> tuple[float, float]:
    """(t_mean, t_pixel): Bonferroni thresholds of one cell (see the module docstring)."""
    n = max(1, n_cells)
    t_mean = t_quantile(alpha / (2 * n * 3) / 2, dof)
    t_pixel = t_quantile(alpha / (2 * n * 3 * max(1, n_pixels)) / 2, dof)
    return t_mean, t_pixel


def _z(diff, se, ref):
    """diff / se after the float32 rounding slack; a zero se with a difference left gives Z_CAP."""
    slack = 1e-5 * np.abs(ref) + 1e-6
    d = np.sign(diff) * np.maximum(np.abs(diff) - slack, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(se > 0, d / np.where(se > 0, se, 1.0), np.where(d == 0, 0.0, np.sign(d) * Z_CAP))
    return np.clip(z, -Z_CAP, Z_CAP)


def bias_statistics(images, stderrs, ref, ref_stderr=None, mask=None, spp=None) -> dict:
    """z-scores of R repetitions against a reference (everything the verdict needs but the thresholds).

    images, stderrs : (R, H, W, 3); ref : (H, W, 3) or broadcastable; ref_stderr : (H, W, 3) or None;
    mask : (H, W) bool, the pixels tested (default all). Returns z_mean (signed, the channel of
    largest |z|), z_channels, d_channels, se_channels, z_pixel (H, W, 3; 0 outside the mask),
    pixel_spread (H, W, 3: max/min over repetitions of the squared standard errors), vov, mask,
    n_pixels and dof = R (spp - 1) (None without spp).
    """
    x = np.asarray(images, np.float64)
    s = np.asarray(stderrs, np.float64)
    r_count = x.shape[0]
    ref = np.broadcast_to(np.asarray(ref, np.float64), x.shape[1:])
    sr2 = 0.0 if ref_stderr is None else np.asarray(ref_stderr, np.float64) ** 2
    mask = np.ones(x.shape[1:3], bool) if mask is None else np.asarray(mask, bool)
    xbar = x.mean(axis=0)
    se2 = (s ** 2).sum(axis=0) / r_count ** 2 + sr2
    diff = xbar - ref
    z_pixel = np.where(mask[..., None], _z(diff, np.sqrt(se2), ref), 0.0)
    n = int(mask.sum())
    d_c = diff[mask].mean(axis=0) if n else np.zeros(3)
    se_c = np.sqrt(se2[mask].sum(axis=0)) / max(n, 1)
    z_c = _z(d_c, se_c, ref[mask].mean(axis=0) if n else np.zeros(3))
    k = int(np.argmax(np.abs(z_c)))
    # variance of the variance over repetitions
    v = (s[:, mask] ** 2).sum(axis=(1, 2))
    vov = float(v.var(ddof=1) / v.mean() ** 2) if r_count >= 2 and v.mean() > 0 else 0.0
    s2 = s ** 2
    lo, hi = s2.min(axis=0), s2.max(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        spread = np.where(hi == 0, 1.0, np.where(lo > 0, hi / np.where(lo > 0, lo, 1.0), np.inf))
    # the per-pixel variance of the variance over repetitions -> kurtosis -> a bound on the skewness
    # of a pixel's mean over all R spp samples (Pearson: skewness^2 <= kurtosis - 1)
    m2 = s2[:, mask].mean(axis=0)
    rv = s2[:, mask].var(axis=0, ddof=1)[m2 > 0] / m2[m2 > 0] ** 2 if r_count >= 2 else np.zeros(0)
    pixel_vov = float(rv.mean()) if rv.size else 0.0
    if spp and spp > 3 and rv.size:
        kurtosis = spp * pixel_vov + (spp - 3) / (spp - 1)
        pixel_skew = math.sqrt(max(kurtosis - 3.0, 0.0) / (r_count * spp))
    else:
        pixel_skew = 0.0 if not rv.size else math.inf
    # no variance in any repetition, yet a difference: no sample showed the pixel's variance
    spread = np.where((hi == 0) & (_z(diff, 0.0, ref) != 0), np.inf, spread)
    return {"z_mean": float(z_c[k]), "z_channels": z_c.tolist(), "d_channels": d_c.tolist(),
            "se_channels": se_c.tolist(), "z_pixel": z_pixel, "pixel_spread": spread, "mask": mask,
            "n_pixels": n, "vov": vov, "pixel_vov": pixel_vov, "pixel_skew": pixel_skew, "dof": r_count * (spp - 1) if spp else None}


def judge(stats: dict, t_mean: float, t_pixel: float) -> dict:
    """The verdict of one cell from :func:`bias_statistics` and its thresholds (module docstring)."""
    heavy = stats["vov"] > VOV_LIMIT
    skewed = stats["pixel_skew"] > PIXEL_SKEW_LIMIT
    mean_fails = abs(stats["z_mean"]) > t_mean
    mask = stats["mask"]
    tail_px = mask & np.any(stats["pixel_spread"] > PIXEL_SPREAD_LIMIT, axis=-1)
    usable = (mask & ~tail_px)[..., None]
    zp = np.where(usable, np.abs(stats["z_pixel"]), 0.0)
    if heavy:
        pixel_test = f"skipped: heavy tail (vov {stats['vov']:.2g} > {VOV_LIMIT:g})"
    elif skewed:
        pixel_test = f"skipped: skewed pixels (pixel_skew {stats['pixel_skew']:.2g} > {PIXEL_SKEW_LIMIT:g})"
    else:
        pixel_test = "applied"
    applied = pixel_test == "applied"
    z_px_max = float(zp.max()) if applied and zp.size else None
    over = int(np.count_nonzero(np.any(zp > t_pixel, axis=-1))) if applied else None
    if heavy:
        verdict = "heavy-tail?" if mean_fails else "ok"
    else:
        verdict = "biased?" if (mean_fails or over) else "ok"
    evidence = abs(stats["z_mean"]) / t_mean
    if applied:
        evidence = max(evidence, z_px_max / t_pixel)
    return {"verdict": verdict, "heavy_tail": heavy, "pixel_test": pixel_test, "z_pixel_max": z_px_max,
            "pixels_over": over, "pixels_tested": int(np.count_nonzero(mask & ~tail_px)) if applied else 0,
            "pixels_tail": int(np.count_nonzero(tail_px)), "evidence": evidence}


# ----------------------------------------------------------------------------- running
def _finite_or_none(x):
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def _clean(obj):
    """JSON-ready: numpy scalars to Python, non-finite floats to None."""
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    return _finite_or_none(obj)


def run_stability(out_dir, cases=None, strategies=None, size=None, spp=None, repetitions=None,
                  reference_spp=None, alpha=None, threads=None, progress=None, render=None) -> dict:
    """Run the stability suite into ``out_dir``; returns the dict written to ``stability.json``.

    cases: names from :data:`CASES` (default all); strategies: ids (default every id of
    ``wavlight.scene.STRATEGIES`` at call time); size (w, h), spp (>= 2), repetitions (>= 2),
    reference_spp, alpha: see the module docstring (defaults in :data:`DEFAULTS`).
    ``progress(done, total, what)`` after each reference and cell. ``render`` replaces
    :func:`wavlight.render_full` (tests inject failures with it).
    """
    from .. import scene as scene_mod
    from ..integrator import render_full

    t_start = time.perf_counter()
    cfg = dict(DEFAULTS)
    for k, v in (("size", size), ("spp", spp), ("repetitions", repetitions), ("reference_spp", reference_spp),
                 ("alpha", alpha)):
        if v is not None:
            cfg[k] = v
    from ..errors import check_int, check_number, shown
    from ..scene import MAX_SIDE, MAX_SPP

    size = cfg["size"]
    if isinstance(size, (str, bytes)) or not hasattr(size, "__len__") or len(size) != 2:
        raise WavlightError(f"stability: size must be (width, height), got {shown(size)}")
    width, height = (check_int("stability", name, x, 1, MAX_SIDE) for name, x in zip(("width", "height"), size))
    for name in ("spp", "repetitions", "reference_spp"):   # (repetitions: each a render of every cell)
        cfg[name] = check_int("stability", name, cfg[name], 2)
        check_int("stability", name, cfg[name], hi=MAX_SPP if name != "repetitions" else 1000)
    cfg["alpha"] = check_number("stability", "alpha", cfg["alpha"], 0.0, 1.0)
    if not 0 < cfg["alpha"] < 1:
        raise WavlightError(f"stability: alpha must be in (0, 1), got {cfg['alpha']}")
    if progress is not None and not callable(progress):
        raise WavlightError(f"stability: progress must be a callable or None, got {shown(progress)}")
    if isinstance(cases, str) or isinstance(strategies, str):
        raise WavlightError("stability: cases and strategies must be lists of names, not one string")
    names = list(CASES) if cases is None else list(cases)
    for n in names:
        if n not in CASES:
            raise WavlightError(f"stability: unknown case {n!r} ({' | '.join(CASES)})")
    strats = list(scene_mod.STRATEGIES) if strategies is None else list(strategies)
    for s in strats:
        if s not in scene_mod.STRATEGIES:
            raise WavlightError(f"stability: unknown strategy {s!r} ({' | '.join(scene_mod.STRATEGIES)})")
    render = render or render_full
    from .charts import require_matplotlib
    require_matplotlib()
    out_dir = str(out_dir)
    if os.path.exists(out_dir) and not os.path.isdir(out_dir):
        raise WavlightError(f"{out_dir}: exists and is not a folder")
    os.makedirs(out_dir, exist_ok=True)
    from ..atomic import remove_stale_temporaries
    for folder in (out_dir, os.path.join(out_dir, "charts")):   # what a killed run's writers left
        remove_stale_temporaries(folder)

    total = len(names) * len(strats) + len(names)
    done = 0

    def step(what):
        nonlocal done
        done += 1
        if progress:
            progress(done, total, what)

    case_info, cells, raw = [], [], []
    for name in names:
        c = CASES[name]
        info = {"case": name, "title": c.title, "status": "ok", "note": "", "warnings": [], "reference": None}
        case_info.append(info)
        ref = ref_se = None
        try:
            built = c.build(width, height)
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                sc = scene_mod.load_dict(built.scene)
            info["warnings"] = sorted({str(w.message) for w in caught})
            info["reference"] = {"analytic": "analytic", "zero": "exactly 0",
                                 "mis": f"mis {cfg['reference_spp']} spp"}[built.reference]
            info["note"] = built.note
            info["cli_refuses"] = bool(sc.environment.is_black)
            if built.expect_warning is not None:
                info["expected_warning"] = built.expect_warning
                info["warned"] = any(built.expect_warning in w for w in info["warnings"])
            mask = np.ones((height, width), bool)
            if built.reference == "analytic":
                mask = floor_mask(sc, width, height, built.floor_half)
                ref = np.broadcast_to(np.asarray(built.expected, np.float64), (height, width, 3))
                info["expected"] = np.asarray(built.expected, float).tolist()
            elif built.reference == "zero":
                ref = np.zeros((height, width, 3))
            else:
                r = render(sc, spp=cfg["reference_spp"], strategy="mis", width=width, height=height,
                           seed=REFERENCE_SEED, threads=threads)
                ref, ref_se = np.asarray(r.image, np.float64), np.asarray(r.stderr, np.float64)
                if not (np.all(np.isfinite(ref)) and np.all(np.isfinite(ref_se))):
                    raise WavlightError("the mis reference holds NaN or Inf")
            info["pixels_tested"] = int(mask.sum())
            info["reference_mean"] = float(ref[mask].mean()) if mask.any() else 0.0
        except Exception as e:  # a failing case must not stop the suite
            info.update(status="failed", note=f"scene or reference failed: {described(e)}")
            for s in strats:
                cells.append(_cell(name, s, cfg, verdict="failed", failure=info["note"]))
                raw.append(None)
                step(f"{name}/{s}: no reference")
            step(f"{name}: failed")
            continue
        step(f"{name}: reference ({info['reference']})")
        missing_warning = built.expect_warning is not None and not info["warned"]
        for s in strats:
            cell, stats = _run_cell(render, sc, name, s, cfg, width, height, ref, ref_se, mask, built, threads)
            if missing_warning and cell["verdict"] != "failed":
                cell.update(verdict="failed", failure=f"expected a warning containing {built.expect_warning!r}")
            cells.append(cell)
            raw.append(stats)
            step(f"{name}/{s}: {'failed' if cell['verdict'] == 'failed' else 'rendered'}")

    # thresholds from the number of cells tested, then verdicts
    tested = [i for i, st in enumerate(raw) if st is not None]
    n_cells = len(tested)
    dof = cfg["repetitions"] * (cfg["spp"] - 1)
    for i in tested:
        cell, st = cells[i], raw[i]
        t_mean, t_pixel = thresholds(cfg["alpha"], n_cells, st["n_pixels"], dof)
        j = judge(st, t_mean, t_pixel)
        cell.update(t_mean=t_mean, t_pixel=t_pixel, **{k: v for k, v in j.items() if k != "verdict"})
        if cell["verdict"] == "pending":
            cell["verdict"] = j["verdict"]
    t_mean, t_pixel = thresholds(cfg["alpha"], n_cells, width * height, dof)
    results = {"suite": "stability", "out_dir": os.path.abspath(out_dir), "wavlight": __version__,
               "settings": {**cfg, "size": [width, height], "reference_seed": REFERENCE_SEED,
                            "vov_limit": VOV_LIMIT, "pixel_skew_limit": PIXEL_SKEW_LIMIT, "pixel_spread_limit": PIXEL_SPREAD_LIMIT, "z_cap": Z_CAP},
               "strategies": strats, "cases": case_info, "cells_tested": n_cells,
               "thresholds": {"dof": dof, "t_mean": t_mean, "t_pixel_full_image": t_pixel,
                              "rule": "family-wise alpha split evenly over the tested cells, then half to the "
                                      "image-mean test (3 channels) and half to the per-pixel test (3 N values)"},
               "cells": cells}
    files = ["stability.csv", "stability.json"]
    from .records import csv_text, write_json, write_text
    write_text(os.path.join(out_dir, "stability.csv"), csv_text(cells, COLUMNS))
    files += chart(results, out_dir)
    results["files"] = files
    results["counts"] = {v: sum(1 for c in cells if c["verdict"] == v)
                         for v in ("ok", "biased?", "heavy-tail?", "failed")}
    results["seconds"] = round(time.perf_counter() - t_start, 2)
    results = _clean(results)
    json.dumps(results, allow_nan=False)  # never a NaN in the output
    write_json(os.path.join(out_dir, "stability.json"), results)
    return results


COLUMNS = ["case", "strategy", "verdict", "failure", "spp", "repetitions", "z_mean", "t_mean", "z_pixel_max",
           "t_pixel", "pixel_test", "pixels_over", "pixels_tested", "pixels_tail", "heavy_tail", "vov", "pixel_vov",
           "pixel_skew", "evidence", "bias", "bias_se",
           "rel_bias", "variance", "rel_variance", "relmse", "firefly", "nan_values", "exact_zero", "seconds",
           "note"]


def _cell(case_name, strategy, cfg, verdict, failure, note=""):
    cell = {c: None for c in COLUMNS}
    cell.update(case=case_name, strategy=strategy, verdict=verdict, failure=failure, spp=cfg["spp"],
                repetitions=cfg["repetitions"], note=note, warnings=[])
    return cell


def _run_cell(render, sc, case_name, strategy, cfg, width, height, ref, ref_se, mask, built, threads):
    """Renders and statistics of one case and strategy; (cell record, stats or None)."""
    cell = _cell(case_name, strategy, cfg, verdict="pending", failure=None)
    t0 = time.perf_counter()
    images, stderrs, seconds = [], [], 0.0
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            for k in range(cfg["repetitions"]):
                r = render(sc, spp=cfg["spp"], strategy=strategy, width=width, height=height, seed=k,
                           threads=threads)
                images.append(np.asarray(r.image, np.float64))
                stderrs.append(np.asarray(r.stderr, np.float64))
                st = getattr(r, "stats", None) or {}
                seconds += float(st.get("setup_seconds", 0.0)) + float(st.get("render_seconds", 0.0))
        cell["warnings"] = sorted({str(w.message) for w in caught})
    except Exception as e:
        cell.update(verdict="failed", failure=described(e), seconds=round(time.perf_counter() - t0, 3))
        return cell, None
    cell["seconds"] = round(seconds or time.perf_counter() - t0, 3)
    x, s = np.stack(images), np.stack(stderrs)
    if x.shape[1:] != (height, width, 3) or s.shape != x.shape:
        cell.update(verdict="failed", failure=f"image shape {x.shape[1:]}, expected {(height, width, 3)}")
        return cell, None
    bad = int(np.count_nonzero(~np.isfinite(x)) + np.count_nonzero(~np.isfinite(s)))
    cell["nan_values"] = bad
    if bad:
        cell.update(verdict="failed", failure=f"{bad} NaN or Inf value(s) in the images or standard errors")
        return cell, None
    if built.reference == "zero":
        cell["exact_zero"] = bool(np.all(x == 0) and np.all(s == 0))
    m = mask
    ref_mean = float(ref[m].mean()) if m.any() else 0.0
    stats = bias_statistics(x, s, ref, ref_se, m, spp=cfg["spp"])
    d = np.asarray(stats["d_channels"])
    se = np.asarray(stats["se_channels"])
    cell["z_mean"] = stats["z_mean"]
    cell["vov"] = stats["vov"]
    cell["pixel_vov"] = stats["pixel_vov"]
    cell["pixel_skew"] = stats["pixel_skew"]
    cell["bias"] = float(d.mean())
    cell["bias_se"] = float(np.sqrt((se ** 2).mean()))  # of the mean of the three channel differences, if independent
    cell["rel_bias"] = float(d.mean() / ref_mean) if ref_mean > 0 else float(d.mean())
    xm, rm = x[:, m], ref[m]
    cell["variance"] = metrics.mean_variance(xm)
    cell["rel_variance"] = metrics.relative_variance(xm, rm)
    rse = None if ref_se is None else ref_se[m]
    cell["relmse"] = float(np.mean([metrics.relmse(img, rm, rse) for img in xm]))
    err = max(metrics.max_error(img, rm) for img in xm)
    cell["firefly"] = err / ref_mean if ref_mean > 0 else err
    return cell, stats


# ----------------------------------------------------------------------------- reporting
def _fmt(x, spec):
    return "-" if x is None else format(x, spec)


def _fmt_z(x, spec):
    """A z-score; huge ones (a zero standard error, Z_CAP) in exponent form."""
    return "-" if x is None else format(x, spec if abs(x) < 1e4 else "+.1e")


def format_table(results: dict) -> str:
    """The cells as a plain-text table, one block per case (what the CLI prints)."""
    st = results["settings"]
    th = results["thresholds"]
    lines = [f"stability suite: {len(results['cases'])} cases x {len(results['strategies'])} strategies, "
             f"{st['size'][0]}x{st['size'][1]} px, {st['repetitions']} x {st['spp']} spp; "
             f"{results['cells_tested']} cells tested at family-wise alpha {st['alpha']:g}: "
             f"|z_mean| > {th['t_mean']:.2f}, |z_px| > {th['t_pixel_full_image']:.2f} (full image) -> biased?",
             "counts: " + ", ".join(f"{k} {v}" for k, v in results.get("counts", {}).items())]
    head = ["strategy", "verdict", "tested", "z_mean", "max|z_px|", "px>t", "vov", "pskew", "rel.bias", "variance", "rel.var",
            "firefly", "s", "failure / warnings"]
    for ci in results["cases"]:
        lines += ["", f"{ci['case']}: {ci['title']} (reference: {ci['reference'] or '-'})"
                  + (f" [{ci['status']}: {ci['note']}]" if ci["status"] != "ok" else
                     (f" -- {ci['note']}" if ci.get("note") else ""))]
        if ci.get("warnings"):
            lines.append(f"  loading warned: {ci['warnings'][0][:110]}")
        rows = [head]
        for c in results["cells"]:
            if c["case"] != ci["case"]:
                continue
            extra = c["failure"] or ""
            if c.get("exact_zero") is not None:
                extra = extra or ("exactly 0" if c["exact_zero"] else "NOT exactly 0")
            if not extra and c.get("warnings"):
                extra = "warned: " + c["warnings"][0][:60]
            tested = "-" if c["pixel_test"] is None else ("mean+px" if c["pixel_test"] == "applied" else
                                                          "mean (tail)" if c["heavy_tail"] else "mean")
            rows.append([c["strategy"], c["verdict"], tested, _fmt_z(c["z_mean"], "+.2f"), _fmt_z(c["z_pixel_max"], ".2f"),
                         _fmt(c["pixels_over"], "d"), _fmt(c["vov"], ".2g"), _fmt(c["pixel_skew"], ".2g"), _fmt(c["rel_bias"], "+.2e"),
                         _fmt(c["variance"], ".3g"), _fmt(c["rel_variance"], ".3g"), _fmt(c["firefly"], ".3g"),
                         _fmt(c["seconds"], ".1f"), extra])
        widths = [max(len(r[i]) for r in rows) for i in range(len(head) - 1)]
        for r in rows:
            lines.append("  " + "  ".join(v.ljust(w) if i < 3 else v.rjust(w)
                                          for i, (v, w) in enumerate(zip(r, widths))) + "  " + r[-1])
    lines.append(f"\n{results.get('seconds', 0):.0f} s")
    return "\n".join(lines)


def chart(results: dict, out_dir) -> list:
    """charts/stability.png and .svg: bias evidence and relative variance per case x strategy."""
    from matplotlib import colors
    from matplotlib.figure import Figure

    from .charts import save_figure

    case_names = [c["case"] for c in results["cases"]]
    strats = results["strategies"]
    by = {(c["case"], c["strategy"]): c for c in results["cells"]}
    ev = np.full((len(case_names), len(strats)), np.nan)
    var = np.full_like(ev, np.nan)
    for i, cn in enumerate(case_names):
        for j, s in enumerate(strats):
            c = by.get((cn, s))
            if c and c["verdict"] != "failed" and c.get("evidence") is not None:
                ev[i, j] = max(c["evidence"], 1e-3)
                if c["rel_variance"] is not None and c["rel_variance"] > 0:
                    var[i, j] = math.log10(c["rel_variance"])
    fig = Figure(figsize=(4.0 + 1.5 * len(strats), 1.2 + 0.42 * len(case_names)), layout="constrained")
    axes = fig.subplots(1, 2)
    short = {"ok": "ok", "biased?": "BIAS?", "heavy-tail?": "tail?", "failed": "FAIL"}
    panels = ((axes[0], ev, "bias evidence max(|z| / threshold) (> 1: rejects)\n(mean only): per-pixel "
                            "test not applicable, (tail): heavy tail",
               dict(cmap="RdYlGn_r", norm=colors.LogNorm(vmin=1e-2, vmax=1e2))),
              (axes[1], var, "log10 relative variance (per render)", dict(cmap="viridis")))
    for ax, data, title, kw in panels:
        im = ax.imshow(np.ma.masked_invalid(data), aspect="auto", interpolation="nearest", **kw)
        ax.set_xticks(range(len(strats)), strats, rotation=45, ha="right", fontsize=8)
        ax.set_yticks(range(len(case_names)), case_names, fontsize=8)
        ax.set_title(title, fontsize=9)
        fig.colorbar(im, ax=ax, shrink=0.8)
        for i, cn in enumerate(case_names):
            for j, s in enumerate(strats):
                c = by.get((cn, s))
                if c is None:
                    continue
                v = c["verdict"]
                if v == "failed":
                    ax.plot([j - 0.45, j + 0.45], [i - 0.45, i + 0.45], color="k", lw=1.2)
                    ax.plot([j - 0.45, j + 0.45], [i + 0.45, i - 0.45], color="k", lw=1.2)
                label = short.get(v, v)
                if ax is axes[0] and v != "failed" and c.get("pixel_test") != "applied":
                    label += "\n(tail)" if c.get("heavy_tail") else "\n(mean only)"
                if ax is axes[1] and v != "failed":
                    if np.isfinite(data[i, j]):
                        label = f"{data[i, j]:.1f}"
                    elif c.get("rel_variance") == 0:
                        label = "0"
                ax.text(j, i, label, ha="center", va="center", fontsize=6.5,
                        color="k" if v != "failed" else "red", fontweight="bold" if v != "ok" else "normal")
    st = results["settings"]
    fig.suptitle(f"stability: {st['size'][0]}x{st['size'][1]} px, {st['repetitions']} x {st['spp']} spp, "
                 f"alpha {st['alpha']:g} over {results['cells_tested']} cells", fontsize=10)
    return save_figure(fig, out_dir, "stability")
