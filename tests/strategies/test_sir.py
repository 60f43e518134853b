"""The ``sir`` strategy (wavlight/strategies/sir.py): resampled importance sampling of f cos L.

Checked here:
- registration, options (scene keys, render_full, CLI), determinism;
- the white furnace (a lambert sphere under a constant map renders its albedo);
- the RIS weight W = (1/M) sum p_hat / q is an unbiased estimate of the unshadowed integral of
  f cos lum(L): its mean over many draws against quadrature over the map's texels, for both
  candidate sources;
- the shadowed estimator under a synthetic occluder against quadrature of f cos L V;
- M and N change the variance the expected way (Brown-Forsythe test, fixed seeds);
- unbiasedness against ``mis`` on a glossy sphere on a floor under rooitou_park_512 (image mean
  and per pixel, Bonferroni, combined standard errors).

Statistical checks use fixed seeds and a false-alarm probability of about 1e-5 each
(``scenes_util.ALPHA``).
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner
from scipy import stats

import wavlight
from scenes_util import (ALPHA, camera_of, check_estimates, dir_from_uv, load, shading_points, write_env,
                         write_scene, z_threshold)
from wavlight import bsdfs, strategies, warp
from wavlight.strategies import sir
from wavlight.envmap import LUMINANCE, Environment, procedural_sky
from wavlight.errors import SceneError

Z = float(stats.norm.isf(ALPHA / 2))


# ----------------------------------------------------------------------------- helpers
def _smooth_map(sun_radiance=40.0, width=128, height=64, seed=3):
    rng = np.random.default_rng(seed)
    return procedural_sky(sun_elevation=50.0, sun_azimuth=20.0, sun_radius=4.0, sun_radiance=sun_radiance,
                          width=width, height=height) + rng.random((height, width, 3)).astype(np.float32) * 0.2


def _strategy(env, **kw):
    st = strategies.make("sir", **kw)
    st.prepare(env)
    return st


def _texel_quadrature(env_pixels, sp0, visible=None, sub=6):
    """Integral over the sphere of f cos(w) x C(w) (x V(w)) for one shading point, with C the map's
    texel value (piecewise constant, the scene format's lat-long convention): each texel split
    into sub x sub cells, f cos at the cell centre times the cell's exact solid angle.
    Returns (luminance integral, RGB integral)."""
    h, w = env_pixels.shape[:2]
    fu = (np.arange(w * sub) + 0.5) / (w * sub)
    v_edges = np.arange(h * sub + 1) / (h * sub)
    fv = (v_edges[:-1] + v_edges[1:]) / 2
    dphi = 2 * np.pi / (w * sub)
    domega_row = dphi * (np.cos(np.pi * v_edges[:-1]) - np.cos(np.pi * v_edges[1:]))
    uu, vv = np.meshgrid(fu, fv)
    d = dir_from_uv(uu.ravel(), vv.ravel())
    one = lambda a: np.repeat(a[:1], len(d), axis=0)
    wl = warp.to_local(d, one(sp0.s), one(sp0.t), one(sp0.n))
    fcos = bsdfs.eval_cos(int(sp0.kind[0]), float(sp0.param[0]), wl, one(sp0.wo))
    if visible is not None:
        fcos = fcos * visible(d)
    g = (fcos.reshape(h * sub, w * sub) * domega_row[:, None]).reshape(h, sub, w, sub).sum(axis=(1, 3))
    rgb = np.einsum("hw,hwc->c", g, env_pixels.astype(np.float64))
    return float(rgb @ LUMINANCE.astype(np.float64)), rgb


# ============================================================================= registration and options
def test_registered_without_kernel():
    assert "sir" in wavlight.STRATEGIES and "sir" in strategies.REGISTRY
    assert "sir" not in strategies.KERNEL_ID          # shaded by NumpyShader
    st = strategies.make("sir", candidates=8, samples=3, source="bsdf")
    assert (st.candidates, st.samples, st.source) == (8, 3, "bsdf")
    st = strategies.make("sir")
    assert (st.candidates, st.samples, st.source) == (sir.DEFAULT_CANDIDATES, sir.DEFAULT_SAMPLES, "light")
    for bad in (dict(candidates=0), dict(samples=0), dict(source="sky")):
        with pytest.raises(ValueError):
            strategies.make("sir", **bad)
    with pytest.raises(NotImplementedError):
        st.pdf(None, None, None)


def _tiny_scene_file(folder, **render):
    env = write_env(folder, "sky.exr", _smooth_map(width=32, height=16))
    return write_scene(folder, render=dict(width=12, height=10, spp=2, **render),
                camera=dict(eye=[0.0, 0.6, 3.0], target=[0.0, 0.0, 0.0], fov_y=40.0),
                environment=dict(file=env),
                objects=[dict(shape="sphere", center=[0.0, 0.0, 0.0], radius=0.8, material="m"),
                         dict(shape="quad", center=[0.0, -0.8, 0.0], normal=[0.0, 1.0, 0.0], size=4.0,
                              material="m")],
                materials={"m": dict(type="ggx", albedo=[0.9, 0.7, 0.5], roughness=0.3)})


def _tiny_scene(folder, **render):
    return wavlight.load_scene(_tiny_scene_file(folder, **render))


def test_scene_keys_and_render_options(tmp_path):
    scene = _tiny_scene(tmp_path, strategy="sir", sir_candidates=5, sir_samples=3)
    assert scene.options == {"sir_candidates": 5, "sir_samples": 3}
    r = wavlight.render_full(scene)
    assert (r.stats["sir_candidates"], r.stats["sir_samples"], r.stats["sir_source"]) == (5, 3, "light")
    assert np.all(np.isfinite(r.image)) and np.all(r.image >= 0)
    r2 = wavlight.render_full(scene, sir_candidates=7, sir_samples=1)
    assert (r2.stats["sir_candidates"], r2.stats["sir_samples"]) == (7, 1)
    # N shadow rays per shaded sample: more rays with N = 3 than with N = 1
    assert r.stats["rays"] > r2.stats["rays"]
    (tmp_path / "plain").mkdir()
    plain = _tiny_scene(tmp_path / "plain")
    assert plain.options == {}
    with pytest.raises(wavlight.WavlightError):
        wavlight.render_full(plain, strategy="sir", sir_candidates=0)
    for key, value, msg in (("sir_candidates", 0, "between 1 and 65536"), ("sir_samples", 0, "between 1 and 1024"),
                            ("sir_candidates", 70000, "between 1 and 65536"), ("sir_samples", 2.5, "integer")):
        d = tmp_path / f"bad_{key}_{value}"
        d.mkdir()
        with pytest.raises(SceneError, match=rf"\[render\]\.{key}.*{msg}"):
            _tiny_scene(d, **{key: value})


def test_deterministic_per_seed_and_thread_count(tmp_path):
    scene = _tiny_scene(tmp_path)
    a = wavlight.render_full(scene, strategy="sir", seed=4, threads=1, sir_candidates=6, sir_samples=2)
    b = wavlight.render_full(scene, strategy="sir", seed=4, threads=2, sir_candidates=6, sir_samples=2)
    c = wavlight.render_full(scene, strategy="sir", seed=5, threads=2, sir_candidates=6, sir_samples=2)
    assert np.array_equal(a.image, b.image) and np.array_equal(a.stderr, b.stderr)
    assert not np.array_equal(a.image, c.image)


def test_cli_accepts_sir_options(tmp_path):
    from wavlight.cli.main import main

    scene = _tiny_scene_file(tmp_path)
    out = tmp_path / "o.exr"
    r = CliRunner().invoke(main, ["render", str(scene), "-o", str(out), "--strategy", "sir", "--sir-candidates",
                                  "8", "--sir-samples", "2", "--json", "--quiet"])
    assert r.exit_code == 0, r.output
    st = json.loads(r.stdout.strip().splitlines()[-1])
    assert (st["strategy"], st["sir_candidates"], st["sir_samples"]) == ("sir", 8, 2)
    assert out.is_file()
    r = CliRunner().invoke(main, ["render", str(scene), "-o", str(out), "--strategy", "sir",
                                  "--sir-candidates", "0"])
    assert r.exit_code == 2


# ============================================================================= shading level
def test_sample_pdf_is_reciprocal_contribution_weight():
    """strategy.sample's pdf field p_hat / W makes shade_reference's f L cos / pdf equal the RIS
    estimate of SirStrategy.shade (N = 1, same uniforms)."""
    env = Environment(_smooth_map())
    st = _strategy(env, candidates=8)
    rng = np.random.default_rng(2)
    sp = shading_points([0.3, 1.0, 0.2], 40.0, bsdfs.GGX, 0.2, 500, albedo=(0.9, 0.6, 0.3))
    u = rng.random((len(sp), 4))
    wi, value = st.shade(env, sp, u)
    ds = st.sample(sp, u)
    assert wi.shape == value.shape == (len(sp), 1, 3)
    np.testing.assert_allclose(ds.wi_world, wi[:, 0])
    np.testing.assert_allclose(strategies.base.unoccluded(sp, env, ds, 1.0), value[:, 0], rtol=1e-9, atol=1e-12)


def test_black_lobe_and_bsdf_furnace_at_shading_level():
    """sum w = 0 gives 0 (no NaN); bsdf-sourced candidates on lambert under a constant map have
    w = 1 exactly, so the estimate is the albedo with no variance."""
    pix = np.ones((16, 32, 3), np.float32)
    pix[:8] = 0.0                                     # the upper hemisphere is black
    env = Environment(pix)
    up = shading_points([0.0, 1.0, 0.0], 30.0, bsdfs.PHONG, 50.0, 300)
    _, value = _strategy(env, candidates=16, samples=2).shade(env, up, np.random.default_rng(0).random((300, 4)))
    assert np.all(value == 0.0)
    env = Environment(np.ones((16, 32, 3), np.float32))
    sp = shading_points([0.2, 0.5, 1.0], 70.0, bsdfs.LAMBERT, 0.0, 300, albedo=(0.7, 0.45, 0.2))
    wi, value = _strategy(env, candidates=4, samples=3, source="bsdf").shade(
        env, sp, np.random.default_rng(1).random((300, 4)))
    assert value.shape == (300, 3, 3)
    np.testing.assert_allclose(value.sum(axis=1), np.tile([0.7, 0.45, 0.2], (300, 1)), rtol=1e-6)


@pytest.mark.parametrize("source,kind,param,view", [("light", bsdfs.GGX, 0.3, 50.0),
                                                    ("light", bsdfs.LAMBERT, 0.0, 10.0),
                                                    ("bsdf", bsdfs.GGX, 0.3, 50.0),
                                                    ("bsdf", bsdfs.PHONG, 30.0, 20.0)])
def test_ris_weight_is_unbiased_for_unshadowed_integral(source, kind, param, view, monkeypatch):
    """E[W] = integral f cos lum(L) dw (eq. 11 with luminance, no albedo): mean over 20000
    independent draws against texel quadrature, within Z standard errors + 2e-3 relative
    (quadrature error). The light-source case with ggx also runs in small chunks."""
    if source == "light" and kind == bsdfs.GGX:
        monkeypatch.setattr(sir, "CHUNK_CANDIDATES", 4096)
    pix = _smooth_map()
    env = Environment(pix)
    st = _strategy(env, candidates=16, source=source)
    count = 20000
    sp = shading_points([0.4, 1.0, -0.3], view, kind, param, count)
    big_w = st.ris_weight(sp, np.random.default_rng(7).random((count, 4)))
    exact, _ = _texel_quadrature(pix, sp)
    se = big_w.std(ddof=1) / math.sqrt(count)
    assert abs(big_w.mean() - exact) <= Z * se + 2e-3 * exact, (big_w.mean(), exact, se)


def _occluder(d):
    """A synthetic visibility: blocked inside a 35-degree cap (e.g. a neighbouring wall)."""
    axis = np.array([0.5, 0.7, 0.1]) / np.linalg.norm([0.5, 0.7, 0.1])
    return (d @ axis < math.cos(math.radians(35.0))).astype(np.float64)


def _shadowed(st, env, sp, seed):
    wi, value = st.shade(env, sp, np.random.default_rng(seed).random((len(sp), 4)))
    vis = _occluder(wi.reshape(-1, 3)).reshape(wi.shape[:2])
    return np.einsum("pkc,pk->pc", value, vis)


def test_shadowed_estimate_unbiased_and_variance_falls_with_n():
    """The estimator with a visibility V (applied to the N slots as the integrator does) against
    quadrature of albedo f cos L V per channel; and at fixed M = 16, N = 8 has lower variance
    than N = 1 (one-sided Brown-Forsythe, p < ALPHA), since N averages visibility only."""
    pix = _smooth_map(sun_radiance=200.0)
    env = Environment(pix)
    count = 20000
    albedo = np.array([0.9, 0.6, 0.3])
    sp = shading_points([0.0, 1.0, 0.0], 45.0, bsdfs.GGX, 0.5, count, albedo=albedo)
    _, rgb = _texel_quadrature(pix, sp, visible=_occluder)
    est = {}
    for n in (1, 8):
        est[n] = _shadowed(_strategy(env, candidates=16, samples=n), env, sp, 11 + n)
        se = est[n].std(axis=0, ddof=1) / math.sqrt(count)
        z = z_threshold(3, count)
        assert np.all(np.abs(est[n].mean(axis=0) - albedo * rgb) <= z * se + 2e-3 * albedo * rgb), \
            (n, est[n].mean(axis=0), albedo * rgb, se)
    lum1, lum8 = est[1] @ LUMINANCE, est[8] @ LUMINANCE
    assert lum8.var() < lum1.var()
    _, p = stats.levene(lum1, lum8, center="median")
    assert p < ALPHA, (lum1.var(), lum8.var(), p)


def test_variance_of_ris_weight_falls_as_one_over_m():
    """W is the mean of M i.i.d. weights: Var(W_4) / Var(W_32) = 8. One-sided Brown-Forsythe
    (p < ALPHA) for the direction, and the ratio within [4, 16]."""
    env = Environment(_smooth_map())
    count = 20000
    sp = shading_points([0.2, 1.0, 0.5], 30.0, bsdfs.GGX, 0.3, count)
    w4 = _strategy(env, candidates=4).ris_weight(sp, np.random.default_rng(21).random((count, 4)))
    w32 = _strategy(env, candidates=32).ris_weight(sp, np.random.default_rng(22).random((count, 4)))
    ratio = w4.var() / w32.var()
    _, p = stats.levene(w4, w32, center="median")
    assert p < ALPHA and 4.0 < ratio < 16.0, (ratio, p)


# ============================================================================= rendering
@pytest.fixture(scope="module")
def furnace(tmp_path_factory):
    d = tmp_path_factory.mktemp("sir_furnace")
    env = write_env(d, "white.exr", np.ones((4, 8, 3)))
    albedo = [0.7, 0.45, 0.2]
    scene = load(d, render=dict(width=20, height=20, spp=16, seed=3),
                 camera=dict(eye=[0.3, 0.4, 3.5], target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0], fov_y=40.0),
                 environment=dict(file=env),
                 objects=[dict(shape="sphere", center=[0.0, 0.0, 0.0], radius=1.0, subdivisions=5,
                               material="white")],
                 materials={"white": dict(type="lambert", albedo=albedo)})
    return scene, np.array(albedo)


@pytest.mark.parametrize("m,n", [(32, 1), (8, 2)])
def test_white_furnace(furnace, m, n):
    """A convex lambert sphere under a constant map of 1 renders its albedo, within standard error."""
    scene, albedo = furnace
    r = wavlight.render_full(scene, strategy="sir", spp=16, seed=5, sir_candidates=m, sir_samples=n)
    cam = camera_of(scene)
    rays = cam.centre_rays()
    # pixels whose centre ray hits well inside the sphere's silhouette (tessellation-safe)
    to_c = -cam.eye / np.linalg.norm(cam.eye)
    ang = np.arccos(np.clip(rays @ to_c, -1, 1))
    inner = ang < 0.8 * math.asin(1.0 / np.linalg.norm(cam.eye))
    assert inner.sum() > 60
    assert np.all(r.stderr[inner] > 0)                 # light-sourced candidates: W is noisy
    check_estimates(r.image, r.stderr, albedo, inner, 16, label=f"sir furnace M={m} N={n}")


@pytest.fixture(scope="module")
def rooitou_scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("sir_rooitou")
    return load(d, render=dict(width=40, height=30, spp=16, seed=1),
                camera=dict(eye=[0.0, 1.0, 3.2], target=[0.0, 0.45, 0.0], fov_y=38.0),
                environment=dict(file="data:rooitou_park_512", rotate_y=150.0),
                objects=[dict(shape="sphere", center=[0.0, 0.6, 0.0], radius=0.6, material="glossy"),
                         dict(shape="quad", center=[0.0, 0.0, 0.0], normal=[0.0, 1.0, 0.0], size=5.0,
                              material="floor")],
                materials={"glossy": dict(type="ggx", albedo=[0.9, 0.7, 0.4], roughness=0.3),
                           "floor": dict(type="lambert", albedo=[0.5, 0.5, 0.5])})


def test_unbiased_against_mis_under_rooitou(rooitou_scene):
    """sir (M = 16, N = 2, 64 spp) and mis (128 spp) agree on a glossy sphere on a floor under
    rooitou_park_512 (tiny sun, shadows): the image mean and every pixel channel within their
    combined standard error (Bonferroni over the pixels, Student t with the smaller spp)."""
    scene = rooitou_scene
    a = wavlight.render_full(scene, strategy="sir", spp=64, seed=2, sir_candidates=16, sir_samples=2)
    b = wavlight.render_full(scene, strategy="mis", spp=128, seed=3)
    diff = a.image.astype(np.float64) - b.image
    se = np.sqrt(a.stderr.astype(np.float64) ** 2 + b.stderr.astype(np.float64) ** 2)
    hit = (a.stderr > 0).any(axis=2) | (b.stderr > 0).any(axis=2)
    assert hit.sum() > 700
    assert np.all(diff[~hit] == 0)                     # background: the map itself, exactly
    m = int(hit.sum())
    z = z_threshold(3 * m, 64)
    zs = np.abs(diff[hit]) / np.maximum(se[hit], 1e-30)
    assert np.all(zs <= z), f"{(zs > z).sum()} pixel channels beyond {z:.2f} stderr, worst z {zs.max():.2f}"
    mean_diff = diff[hit].mean(axis=0)
    mean_se = np.sqrt((se[hit] ** 2).sum(axis=0)) / m
    assert np.all(np.abs(mean_diff) <= z_threshold(3, 64 * m) * mean_se), (mean_diff, mean_se)
    # the point of sir: lower variance than mis at equal spp on the sphere and floor
    rel = lambda r: float((r.stderr[hit] ** 2).mean() / r.image[hit].mean() ** 2)
    assert rel(a) * 64 < rel(b) * 128
