"""Direction samplers against their densities: warps, BRDFs, the environment light, MIS.

Every sampler is checked four ways (after Mitsuba's chi2 tests and pbrt's sampling tests):
  (a) its pdf integrates to one over the sphere (quadrature, convergence checked),
  (b) a Pearson chi-square test of its samples against the pdf (tests/support/chi2.py),
  (c) the pdf returned with a sample equals the pdf evaluated for that direction,
  (d) BRDF weights eval_cos / pdf are finite, non-negative and equal to their closed form.

Statistics: fixed seeds; the chi-square tests of this file form one family whose
false-rejection probability is 1 % (Sidak-corrected per test); other tolerances are
derived from floating-point error bounds or standard errors, as stated where used.
"""
from __future__ import annotations

import functools
import zlib
from dataclasses import dataclass
from typing import Callable

import numpy as np
import pytest

from chi2 import SphereGrid, SquareGrid, chi2_test, frame_about, integral
from scenes_util import map3x2, one_texel_map
from wavlight import bsdfs, warp
from wavlight.envmap import LUMINANCE, Environment, procedural_sky
from wavlight.strategies import LightStrategy, balance_heuristic, power_heuristic


def seed_of(name: str) -> int:
    """A fixed seed per test case (stable across runs and Python versions)."""
    return zlib.crc32(name.encode())


def wo_at(theta_deg: float, phi: float = 0.7) -> np.ndarray:
    t = np.radians(theta_deg)
    return np.array([np.sin(t) * np.cos(phi), np.sin(t) * np.sin(phi), np.cos(t)])


def uniform_sphere(n: int, rng) -> np.ndarray:
    z = rng.uniform(-1, 1, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


# ============================================================================= direction samplers
@dataclass
class Case:
    """One direction sampler: ``sample(u) -> (wi, pdf or None)`` and ``pdf(wi)``; local frame, z = normal."""

    id: str
    sample: Callable
    pdf: Callable
    kind: int | None = None  # BRDF cases only
    param: float | None = None
    wo: np.ndarray | None = None
    jumps_z: tuple = (0.0,)  # z values (grid frame) where the pdf may jump or kink
    axis: tuple = (0.0, 0.0, 1.0)  # pole of the chi-square grid


def _bsdf_case(name, kind, param, theta):
    wo = wo_at(theta) if theta else np.array([0.0, 0.0, 1.0])

    def sample(u, kind=kind, param=param, wo=wo):
        return bsdfs.sample(kind, param, u, np.broadcast_to(wo, (len(u), 3)).copy())

    def pdf(d, kind=kind, param=param, wo=wo):
        return bsdfs.pdf(kind, param, d, np.broadcast_to(wo, (len(d), 3)).copy())

    # GGX: D(h) jumps to 0 where h.z = 0, i.e. on the cone wi.z = -wo.z (normal frame);
    # at the single point wi = -wo the half vector is undefined and the pdf has no limit
    # (a point singularity; the chi2 helper's quadrature budget covers its cell).
    # Phong: the lobe max(0, cos alpha)^n has a kink at alpha = 90 deg about the mirror
    # direction, so its grid is built about that direction.
    jumps = (0.0, -wo[2]) if kind == bsdfs.GGX else (0.0,)
    axis = tuple(bsdfs.reflect(wo[None])[0]) if kind == bsdfs.PHONG else (0.0, 0.0, 1.0)
    return Case(f"{name}-{param:g}-wo{theta}" if kind != bsdfs.LAMBERT else f"{name}-wo{theta}",
                sample, pdf, kind, param, wo, jumps, axis)


WO_ANGLES = (0, 45, 85)
CASES = [
    Case("uniform_hemisphere", lambda u: (warp.square_to_uniform_hemisphere(u), None),
         warp.square_to_uniform_hemisphere_pdf),
    Case("cosine_hemisphere", lambda u: (warp.square_to_cosine_hemisphere(u), None),
         warp.square_to_cosine_hemisphere_pdf),
]
CASES += [_bsdf_case("lambert", bsdfs.LAMBERT, 0.0, th) for th in WO_ANGLES]
CASES += [_bsdf_case("phong", bsdfs.PHONG, n, th) for n in (1.0, 20.0, 200.0) for th in WO_ANGLES]
CASES += [_bsdf_case("ggx", bsdfs.GGX, a, th) for a in (0.05, 0.2, 0.7) for th in WO_ANGLES]
BSDF_CASES = [c for c in CASES if c.kind is not None]

# Light-strategy maps (see LIGHT_MAPS below) and the chi-square family of this file.
LIGHT_MAP_IDS = ("one_texel", "one_texel_rot90", "one_texel_pole", "constant", "map3x2", "map2x1",
                 "sky", "sky_rot90")
N_CHI2 = len(CASES) + 1 + len(LIGHT_MAP_IDS) + 1  # + equal-area map + constant map on the sphere

N_CHI2_SAMPLES = 200_000


def adaptive_grid(case: Case, n_pilot: int = 50_000) -> SphereGrid:
    """Cells about ``case.axis`` whose z and phi edges follow the sampler's own marginals.

    The edges are quantiles of a *pilot* sample drawn with a different seed from the
    tested one (so the partition is fixed before the test sample is drawn, as the
    chi-square test requires), merged with a coarse uniform grid that covers the
    whole sphere, plus the z values where the pdf jumps, so that no cell straddles
    a discontinuity and Gauss-Legendre quadrature converges.
    """
    rng = np.random.default_rng(seed_of(case.id + "/pilot"))
    frame = frame_about(case.axis)
    d, _ = case.sample(rng.random((n_pilot, 2)))
    d = d @ frame.T
    z = np.quantile(d[:, 2], np.linspace(0, 1, 25))
    phi = np.quantile(np.mod(np.arctan2(d[:, 1], d[:, 0]), 2 * np.pi), np.linspace(0, 1, 33))
    z_edges = np.unique(np.round(np.concatenate([z, np.linspace(-1, 1, 9), case.jumps_z]), 12))
    phi_edges = np.unique(np.round(np.concatenate([phi, np.linspace(0, 2 * np.pi, 9)]), 12))
    # Drop slivers (quantiles of a point mass, e.g. z = 1 at the pole) that are thinner than 1e-9.
    z_edges = z_edges[np.concatenate([[True], np.diff(z_edges) > 1e-9])]
    phi_edges = phi_edges[np.concatenate([[True], np.diff(phi_edges) > 1e-9])]
    z_edges[0], z_edges[-1] = -1.0, 1.0
    phi_edges[0], phi_edges[-1] = 0.0, 2 * np.pi
    return SphereGrid(z_edges, phi_edges, frame)


@functools.lru_cache(maxsize=None)
def grid_of(case_id: str) -> SphereGrid:
    return adaptive_grid(next(c for c in CASES if c.id == case_id))


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.id)
def test_pdf_integrates_to_one(case):
    """(a) The pdf integrates to 1 over the sphere.

    Gauss-Legendre, 8 x 8 and 16 x 16 nodes per cell of the adaptive grid. We require
    the two to agree within 2e-4 (the quadrature has converged) and the finer one to
    be within 1e-3 of 1. 1e-3 is below every plausible normalisation slip here: the
    smallest is Phong's (n+2) for (n+1) at n = 200, a relative error of 1/201 = 5e-3.
    """
    coarse, fine = integral(case.pdf, grid_of(case.id), quad=8)
    assert abs(coarse - fine) < 2e-4, f"quadrature not converged: {coarse} vs {fine}"
    assert abs(fine - 1.0) < 1e-3, f"pdf integrates to {fine}"


@pytest.mark.slow
@pytest.mark.parametrize("case", CASES, ids=lambda c: c.id)
def test_chi2_samples_match_pdf(case):
    """(b) Samples follow the pdf (chi-square, Sidak-corrected over this file's family)."""
    rng = np.random.default_rng(seed_of(case.id))
    d, _ = case.sample(rng.random((N_CHI2_SAMPLES, 2)))
    ok, p, msg = chi2_test(d, case.pdf, grid_of(case.id), n_tests=N_CHI2, quad=8)
    assert ok, msg


@pytest.mark.parametrize("case", BSDF_CASES, ids=lambda c: c.id)
def test_sample_pdf_equals_pdf(case):
    """(c) The pdf returned with each sample equals pdf() evaluated for that direction (rtol 1e-5)."""
    rng = np.random.default_rng(seed_of(case.id + "/c"))
    u = np.concatenate([rng.random((50_000, 2)),
                        np.array([[0, 0], [0, 0.5], [0.5, 0], [1 - 1e-12, 0.3], [0.3, 1 - 1e-12]])])
    wi, p = case.sample(u)
    q = case.pdf(wi)
    assert np.all(np.isfinite(p)) and np.all(p >= 0)
    np.testing.assert_allclose(p, q, rtol=1e-5, atol=0)


def smith_g1_ggx(w, alpha):
    """Smith masking for GGX, written out independently: 2 cos / (cos + sqrt(a^2 + (1 - a^2) cos^2))."""
    c = w[:, 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        g = 2 * c / (c + np.sqrt(alpha ** 2 + (1 - alpha ** 2) * c * c))
    return np.where(c > 0, g, 0.0)


@pytest.mark.parametrize("case", BSDF_CASES, ids=lambda c: c.id)
def test_bsdf_weight(case):
    """(d) weight = eval_cos / pdf is finite, >= 0 and equals its closed form.

    Closed forms (the sampling densities cancel D or the lobe exactly):
      lambert: 1 above the surface;  phong: (n+2)/(n+1) max(0, cos_i);
      ggx (visible normals): G1(wi) (Heitz 2018, eq. 19 with G2 = G1(wi) G1(wo)).
    Samples with pdf 0 are "no sample" and must carry eval_cos 0 as well. rtol 1e-9:
    both sides are a few float64 operations on the same inputs.
    """
    rng = np.random.default_rng(seed_of(case.id + "/d"))
    wo = np.broadcast_to(case.wo, (50_000, 3)).copy()
    wi, p = case.sample(rng.random((len(wo), 2)))
    f = bsdfs.eval_cos(case.kind, case.param, wi, wo)
    assert np.all(np.isfinite(f)) and np.all(f >= 0)
    assert np.all(f[p == 0] == 0), "eval_cos > 0 for a sample of pdf 0"
    live = p > 0
    weight = f[live] / p[live]
    assert np.all(np.isfinite(weight)) and np.all(weight >= 0)
    cos_i = np.maximum(wi[live, 2], 0.0)
    if case.kind == bsdfs.LAMBERT:
        expect = np.where(cos_i > 0, 1.0, 0.0)
    elif case.kind == bsdfs.PHONG:
        expect = (case.param + 2) / (case.param + 1) * cos_i
    else:
        expect = smith_g1_ggx(wi[live], case.param)
    np.testing.assert_allclose(weight, expect, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("case", BSDF_CASES, ids=lambda c: c.id)
def test_bsdf_pdf_covers_eval(case):
    """Support: wherever eval_cos > 0 the sampling pdf is > 0 (else BSDF sampling is biased)."""
    rng = np.random.default_rng(seed_of(case.id + "/support"))
    wi = uniform_sphere(200_000, rng)
    wo = np.broadcast_to(case.wo, wi.shape).copy()
    f = bsdfs.eval_cos(case.kind, case.param, wi, wo)
    p = bsdfs.pdf(case.kind, case.param, wi, wo)
    bad = (f > 0) & ~(p > 0)
    assert not bad.any(), f"{bad.sum()} directions with eval_cos > 0 and pdf 0, e.g. {wi[bad][:3]}"


# ----------------------------------------------------------------------------- chi2 helper self-checks
def test_chi2_helper_rejects_wrong_pdf():
    """The helper can fail: cosine-distributed samples tested against the uniform hemisphere pdf."""
    rng = np.random.default_rng(1)
    d = warp.square_to_cosine_hemisphere(rng.random((20_000, 2)))
    ok, p, msg = chi2_test(d, warp.square_to_uniform_hemisphere_pdf, SphereGrid.uniform(16, 32))
    assert not ok and p < 1e-10, msg
    assert "observed" in msg and "expected" in msg


def test_chi2_helper_rejects_samples_in_zero_pdf_cells():
    rng = np.random.default_rng(2)
    d = warp.square_to_uniform_hemisphere(rng.random((20_000, 2)))
    d[:10, 2] *= -1  # ten samples below the horizon, where the pdf is 0
    ok, p, msg = chi2_test(d, warp.square_to_uniform_hemisphere_pdf, SphereGrid.uniform(16, 32))
    assert not ok and "zero integrated pdf" in msg, msg


# ============================================================================= environment light
LIGHT_MAPS = {
    # one lit texel in a black 64 x 32 map, away from the poles ...
    "one_texel": lambda: Environment(one_texel_map(16, 40)),
    "one_texel_rot90": lambda: Environment(one_texel_map(16, 40), rotate_y=90.0),
    # ... and in the first row (a texel at the pole, of small solid angle)
    "one_texel_pole": lambda: Environment(one_texel_map(0, 17)),
    "constant": lambda: Environment(np.ones((32, 64, 3), np.float32)),
    "map3x2": lambda: Environment(map3x2()),
    "map2x1": lambda: Environment(np.array([[[1.0, 1.0, 1.0], [0.25, 0.5, 2.0]]], np.float32)),
    "sky": lambda: Environment(procedural_sky()),
    "sky_rot90": lambda: Environment(procedural_sky(), rotate_y=90.0),
}
assert tuple(LIGHT_MAPS) == LIGHT_MAP_IDS


@functools.lru_cache(maxsize=None)
def light_of(map_id: str) -> LightStrategy:
    s = LightStrategy()
    s.prepare(LIGHT_MAPS[map_id]())
    return s


def texel_centre_directions(env: Environment) -> np.ndarray:
    """World directions of every texel centre (H * W, 3), from the documented lat-long lookup."""
    v = (np.arange(env.height) + 0.5) / env.height
    u = (np.arange(env.width) + 0.5) / env.width
    theta, phi = np.meshgrid(v * np.pi, u * 2 * np.pi, indexing="ij")
    d_map = np.stack([np.sin(theta) * np.sin(phi), np.cos(theta), -np.sin(theta) * np.cos(phi)], -1)
    return d_map.reshape(-1, 3) @ env.world_from_map.T


def light_square_pdf(light: LightStrategy):
    """The light pdf as a density on the tree's lat-long square (phi = 2 pi u, theta = pi v):
    pdf_directions(d(uv)) * 2 pi^2 sin(theta), the Jacobian d omega / du dv."""
    env = light.env

    def pdf(uv):
        return light.pdf_directions(env.square_to_world(uv)) * 2 * np.pi ** 2 * np.sin(np.pi * uv[:, 1])

    return pdf


def light_square_grid(light: LightStrategy):
    """Square cells aligned with the tree's leaves: 2 x 2 cells per leaf up to 128 cells a side,
    otherwise one cell per block of leaves. The pdf is constant on every sub-cell of the
    midpoint rule, so the per-cell integral is exact."""
    side = 1 << light.tree.n_levels
    cells = min(2 * side, 128) if side <= 64 else 64
    quad = max(1, side // cells)
    return SquareGrid.uniform(cells), quad


@pytest.mark.parametrize("map_id", LIGHT_MAP_IDS)
def test_light_chi2(map_id):
    """Light samples follow pdf_directions (chi-square).

    The test runs on the tree's lat-long square: the sampled directions are mapped back
    with world_to_square and compared with pdf_directions x the Jacobian there. The pdf is
    piecewise constant on the tree's leaves, so cells aligned with the leaves make the
    expected counts exact; a (cos theta, phi) grid would cut leaves and need very fine
    quadrature near the sun.
    """
    light = light_of(map_id)
    rng = np.random.default_rng(seed_of("light/" + map_id))
    n = 1_000_000 if map_id.startswith("sky") else 200_000
    d, _ = light.sample_directions(rng.random((n, 2)))
    assert np.all(np.isfinite(d)), "non-finite light sample directions"
    uv = light.env.world_to_square(d)
    grid, quad = light_square_grid(light)
    ok, p, msg = chi2_test(uv, light_square_pdf(light), grid, n_tests=N_CHI2, quad=quad, rule="midpoint")
    assert ok, msg


def test_light_chi2_constant_map_on_sphere():
    """For a constant map the light samples follow pdf_directions on the sphere (close to
    1/(4 pi), up to the sin(theta) variation inside each lat-long leaf).

    This one runs in (cos theta, phi) cells of the world frame, so it also checks the
    square-to-world path (lat-long map, Jacobian, rotation) end to end. The pdf jumps at
    leaf rows, which these cells cut, hence the finer quadrature.
    """
    light = light_of("constant")
    rng = np.random.default_rng(seed_of("light/constant/sphere"))
    d, _ = light.sample_directions(rng.random((N_CHI2_SAMPLES, 2)))
    ok, p, msg = chi2_test(d, light.pdf_directions, SphereGrid.uniform(32, 64), n_tests=N_CHI2, quad=24)
    assert ok, msg


@pytest.mark.parametrize("map_id", LIGHT_MAP_IDS)
def test_light_sample_pdf_equals_pdf_directions(map_id):
    """The pdf returned by sample_directions equals pdf_directions of the returned directions.

    rtol 1e-5: both are float32 tree values times the Jacobian; a mismatch means the direction
    was looked up in another leaf than the one it was drawn from (so MIS would weigh it
    with a wrong density). Inputs: random u, a 64 x 64 grid of cell-centred u, and the
    largest values below 1 plus 1 itself. (u = 0 is left out on purpose: it can put uv on
    the square's border, the phi = 0 seam or a pole, where a direction has two square
    preimages in different leaves; that set has measure zero and does not bias MIS.)
    """
    light = light_of(map_id)
    rng = np.random.default_rng(seed_of("light/c/" + map_id))
    g = np.concatenate([(np.arange(64) + 0.5) / 64, [1 - 2 ** -24, 1 - 1e-9, 1.0]])
    u = np.concatenate([rng.random((300_000, 2)), np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)])
    d, p = light.sample_directions(u)
    q = light.pdf_directions(d)
    bad = ~np.isclose(p, q, rtol=1e-5, atol=0)
    if bad.any():
        i = np.nonzero(bad)[0]
        uv, _ = light.tree.sample(u[i])
        raise AssertionError(
            f"{bad.sum()} of {len(u)} samples have sample pdf != pdf_directions, e.g. "
            f"u = {u[i[:3]].tolist()}, uv = {uv[:3].tolist()}, sample pdf = {p[i[:3]].tolist()}, "
            f"pdf_directions = {q[i[:3]].tolist()}")


@pytest.mark.parametrize("map_id", LIGHT_MAP_IDS)
def test_light_pdf_integrates_to_one(map_id):
    """The light pdf integrates to 1 over the sphere, two ways.

    1. Exactly, on the lat-long square: one midpoint per leaf of the square density (the
       pdf is constant on each leaf there). The only error is float32 rounding of the tree
       (root = sum of leaves, <= 2n roundings, n <= 11, relative 2^-24 each): 1e-5 covers
       2 * 11 * 6e-8 = 1.3e-6 with margin.
    2. Independently of the map: Monte Carlo with 1M uniform directions, 4 pi mean(pdf);
       accept within 5 standard errors (estimated from the same samples) plus 1e-6.
    """
    light = light_of(map_id)
    side = 1 << light.tree.n_levels
    c = (np.arange(side) + 0.5) / side
    uv = np.stack(np.meshgrid(c, c), -1).reshape(-1, 2)
    exact = light_square_pdf(light)(uv).sum() / side ** 2
    assert abs(exact - 1) < 1e-5, f"pdf integrates to {exact} on the lat-long square"

    rng = np.random.default_rng(seed_of("light/int/" + map_id))
    x = 4 * np.pi * light.pdf_directions(uniform_sphere(1_000_000, rng))
    mean, se = x.mean(), x.std(ddof=1) / np.sqrt(len(x))
    assert abs(mean - 1) <= 5 * se + 1e-6, f"Monte Carlo integral {mean} +- {se}"


@pytest.mark.parametrize("map_id", LIGHT_MAP_IDS)
def test_light_pdf_positive_where_radiance(map_id):
    """pdf_directions > 0 wherever the map has radiance: at every texel centre and at 400k
    uniform random directions. (A zero pdf where L > 0 makes light sampling biased.)"""
    light = light_of(map_id)
    env = light.env
    rng = np.random.default_rng(seed_of("light/pos/" + map_id))
    d = np.concatenate([texel_centre_directions(env), uniform_sphere(400_000, rng)])
    lum = env.eval(d) @ LUMINANCE
    p = light.pdf_directions(d)
    bad = (lum > 0) & ~(p > 0)
    assert not bad.any(), (f"{bad.sum()} directions with radiance > 0 but light pdf 0 "
                           f"(tree integral {light.tree.integral}), e.g. {d[bad][:3].tolist()}")


def quadrant_map(values_rgb, width=16, height=8):
    """A lat-long map constant on each quarter of columns [k W/4, (k+1) W/4)."""
    px = np.zeros((height, width, 3), np.float32)
    for k, v in enumerate(values_rgb):
        px[:, k * width // 4:(k + 1) * width // 4] = v
    return px


@pytest.mark.parametrize("rotate", [0.0, 90.0, 37.0])
def test_light_zero_variance_on_leaf_constant_map(rotate):
    """Importance is perfect when luminance is constant on every leaf (after pbrt's lights_test).

    Map: four column quarters of luminance L_q = (1, 3, 9, 27) in different colours. The
    tree's leaves nest inside texels (2^n >= W, H, powers of two), and each leaf holds the
    exact integral L dOmega over it, so for a sample at polar angle theta in a leaf spanning
    [theta0, theta1] the estimator is
        Y = luminance(env.eval(d)) / pdf(d) = I * pi sin(theta) / (2^n (cos theta0 - cos theta1))
    with I = pi sum(L_q) the exact integral: zero variance up to the sin(theta) variation
    inside the leaf, which the test divides out. rtol 1e-5 covers float32 (~1e-6). Uniform
    sphere sampling, Y = 4 pi L, misses I by up to 170 %, so the check discriminates. The
    rotations check that eval and the pdf agree on rotate_y.
    """
    lums = np.array([1.0, 3.0, 9.0, 27.0])
    chroma = np.array([[1.0, 0.2, 0.1], [0.1, 1.0, 0.3], [0.3, 0.1, 1.0], [0.6, 0.6, 0.6]])
    rgb = chroma * (lums / (chroma @ LUMINANCE))[:, None]
    light = LightStrategy()
    light.prepare(Environment(quadrant_map(rgb), rotate_y=rotate))
    lq = rgb.astype(np.float32) @ LUMINANCE  # the quarters' luminances as the map stores them
    exact = np.pi * lq.sum()
    side = 1 << light.tree.n_levels

    rng = np.random.default_rng(seed_of(f"zero-variance/{rotate}"))
    d, p = light.sample_directions(rng.random((100_000, 2)))
    lum = light.env.eval(d) @ LUMINANCE
    assert np.all(lum > 0)
    theta = np.pi * light.env.world_to_square(d)[:, 1]
    row = np.minimum((theta / np.pi * side).astype(np.int64), side - 1)
    dcos = np.cos(np.pi * row / side) - np.cos(np.pi * (row + 1) / side)
    y = lum / p
    np.testing.assert_allclose(y * side * dcos / (np.pi * np.sin(theta)), exact, rtol=1e-5)

    d_uni = uniform_sphere(100_000, rng)
    y_uni = 4 * np.pi * (light.env.eval(d_uni) @ LUMINANCE)
    assert np.abs(y_uni / exact - 1).max() > 0.5  # the property is not trivially true
    # ... while uniform sampling is unbiased for the same integral (5 standard errors)
    assert abs(y_uni.mean() - exact) < 5 * y_uni.std() / np.sqrt(len(y_uni))


# ============================================================================= MIS
HEURISTICS = [(power_heuristic, 9 / 25), (balance_heuristic, 3 / 7)]   # with w(3, 4)


@pytest.mark.parametrize("heuristic, w34", HEURISTICS, ids=["power", "balance"])
def test_mis_heuristic_range_and_partition(heuristic, w34):
    """w(a, b) in [0, 1] and w(a, b) + w(b, a) = 1 whenever a + b > 0 (0 for a = b = 0).

    pdfs over 30 decades either side of 1 (log-uniform), exact zeros and equal pairs;
    the sum is exact to a few ulps (rtol 1e-12).
    """
    rng = np.random.default_rng(20)
    a = 10.0 ** rng.uniform(-30, 30, 100_000)
    b = 10.0 ** rng.uniform(-30, 30, 100_000)
    a[::7] = 0
    b[::11] = 0
    b[::13] = a[::13]
    wab, wba = heuristic(a, b), heuristic(b, a)
    assert np.all(np.isfinite(wab)) and np.all((wab >= 0) & (wab <= 1))
    pos = a + b > 0
    np.testing.assert_allclose((wab + wba)[pos], 1.0, rtol=1e-12)
    assert np.all(wab[~pos] == 0)
    # the heuristic itself: a^2 / (a^2 + b^2) (power), a / (a + b) (balance)
    np.testing.assert_allclose(heuristic(3.0, 4.0), w34, rtol=1e-15)
    np.testing.assert_allclose(heuristic(2.0, 0.0), 1.0)


def test_mis_heuristic_of_each_strategy():
    """mis and mis_comp weigh by the power heuristic (as pbrt-v4 and Mitsuba 3), wavelet by the
    balance heuristic (measured better for it: WaveletStrategy's docstring)."""
    from wavlight import strategies

    assert strategies.make("mis").heuristic == "power"
    assert strategies.make("mis_comp").heuristic == "power"
    assert strategies.make("wavelet").heuristic == "balance"


@pytest.mark.parametrize("heuristic", [h for h, _ in HEURISTICS], ids=["power", "balance"])
def test_mis_heuristic_extreme_magnitudes(heuristic):
    """Same partition property where a^2 or b^2 leaves the float64 range.

    A Phong lobe of exponent 200 has pdf (201 / 2 pi) cos^200 ~ 1e-200 at 85 degrees from
    its mirror direction; squared, that underflows to 0. Large pdfs (1e200) overflow.
    """
    a = np.array([1e-200, 1e-170, 1e200, 1e160, 1e-200])
    b = np.array([0.0, 0.0, 1.0, 1e160, 1e-200])
    wab, wba = heuristic(a, b), heuristic(b, a)
    assert np.all(np.isfinite(wab)) and np.all((wab >= 0) & (wab <= 1)), wab
    np.testing.assert_allclose(wab + wba, 1.0, rtol=1e-12)
