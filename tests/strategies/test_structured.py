"""The ``structured`` strategy (wavlight/strategies/structured.py): structured importance sampling
(Agarwal et al. 2003).

Checked here:
- registration and options (library, scene keys, render_full, CLI);
- the farthest-point k-center: covering radii exact and non-increasing, every new center at
  least the covering radius away from the previous ones (the 2-approximation argument),
  nearest-center assignment against brute force;
- the strata partition the non-black texels and conserve power (luminance and RGB) exactly;
- stratified mode: the sampled pdf is lum / Phi and matches ``pdf``; strata are chosen with
  probability Phi_s / Phi (chi-square); white furnace; unbiased against ``mis`` on a sphere
  on a floor under a real map with black texels next to its lamps (black_by_lamps), per pixel
  and image mean;
- preintegrated mode: flagged biased (warning, info, JSON); close to the exact integral when
  the light is one small bright region, measurably biased on a smooth map (the same check
  passes for stratified mode there).

Statistical checks use fixed seeds and a false-alarm probability of about 1e-5 each.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner
from scipy import stats

import wavlight
import wavlight.data
from scenes_util import (ALPHA, camera_of, check_estimates, dir_from_uv, load, shading_points, write_env,
                         write_scene, z_threshold)
from wavlight import bsdfs, strategies, warp
from wavlight.strategies import structured
from wavlight.envmap import LUMINANCE, Environment, procedural_sky
from wavlight.errors import SceneError

Z = float(stats.norm.isf(ALPHA / 2))
LUM = LUMINANCE.astype(np.float64)


# ----------------------------------------------------------------------------- helpers
def _sky(width=64, height=32, sun=True, sun_radiance=50.0):
    kw = dict(sun_elevation=40.0, sun_azimuth=30.0, sun_radius=5.0, sun_radiance=sun_radiance)
    pix = procedural_sky(width=width, height=height, **kw)
    if not sun:
        pix = procedural_sky(width=width, height=height, sun_radius=1e-3)
    return pix


def _quadrature(pix, sp0, sub=6):
    """RGB integral of f cos(w) L(w) over the sphere for one shading point (no albedo): each texel
    split into sub x sub cells, f cos at the cell centre times the cell's exact solid angle."""
    h, w = pix.shape[:2]
    fu = (np.arange(w * sub) + 0.5) / (w * sub)
    v_edges = np.arange(h * sub + 1) / (h * sub)
    fv = (v_edges[:-1] + v_edges[1:]) / 2
    domega_row = 2 * np.pi / (w * sub) * (np.cos(np.pi * v_edges[:-1]) - np.cos(np.pi * v_edges[1:]))
    uu, vv = np.meshgrid(fu, fv)
    d = dir_from_uv(uu.ravel(), vv.ravel())
    one = lambda a: np.repeat(a[:1], len(d), axis=0)
    fcos = bsdfs.eval_cos(int(sp0.kind[0]), float(sp0.param[0]), warp.to_local(d, one(sp0.s), one(sp0.t),
                                                                                one(sp0.n)), one(sp0.wo))
    g = (fcos.reshape(h * sub, w * sub) * domega_row[:, None]).reshape(h, sub, w, sub).sum(axis=(1, 3))
    return np.einsum("hw,hwc->c", g, pix.astype(np.float64))


def _prepared(env, **kw):
    st = strategies.make("structured", **kw)
    st.prepare(env)
    return st


# ============================================================================= registration and options
def test_registered_and_options():
    assert "structured" in wavlight.STRATEGIES and "structured" in strategies.REGISTRY
    assert "structured" not in strategies.KERNEL_ID                 # shaded by NumpyShader
    st = strategies.make("structured")
    assert (st.k, st.mode, st.samples) == (structured.DEFAULT_STRATA, "stratified", structured.PER_STRATUM)
    for bad in (dict(strata=0), dict(strata=5000), dict(mode="points"), dict(samples=0)):
        with pytest.raises(ValueError):
            strategies.make("structured", **bad)


def _tiny_scene_file(folder, **render):
    env = write_env(folder, "sky.exr", _sky(32, 16))
    return write_scene(folder, render=dict(width=12, height=10, spp=2, **render),
                       camera=dict(eye=[0.0, 0.6, 3.0], target=[0.0, 0.0, 0.0], fov_y=40.0),
                       environment=dict(file=env),
                       objects=[dict(shape="sphere", center=[0.0, 0.0, 0.0], radius=0.8, material="m")],
                       materials={"m": dict(type="ggx", albedo=[0.9, 0.7, 0.5], roughness=0.3)})


def test_scene_keys_render_options_and_flags(tmp_path):
    scene = wavlight.load_scene(_tiny_scene_file(tmp_path, strategy="structured", structured_strata=12))
    assert scene.options == {"structured_strata": 12}
    r = wavlight.render_full(scene)
    assert (r.stats["structured_strata"], r.stats["structured_mode"], r.stats["structured_biased"]) == \
        (12, "stratified", False)
    assert np.all(np.isfinite(r.image)) and np.all(r.image >= 0)
    with pytest.warns(UserWarning, match="biased"):
        r = wavlight.render_full(scene, structured_strata=20, structured_mode="preintegrated")
    assert r.stats["structured_biased"] is True and "biased" in r.stats["structured_note"]
    for kw in (dict(structured_strata=0), dict(structured_mode="x")):
        with pytest.raises(wavlight.WavlightError):
            wavlight.render_full(scene, **kw)
    for key, value, msg in (("structured_strata", 0, "between 1 and 1024"), ("structured_strata", 2000, "between 1 and 1024"),
                            ("structured_mode", "points", "must be one of stratified"), ("structured_strata", 2.5, "integer")):
        d = tmp_path / f"bad_{key}_{value}"
        d.mkdir()
        with pytest.raises(SceneError, match=rf"\[render\]\.{key}.*{msg}"):
            wavlight.load_scene(_tiny_scene_file(d, **{key: value}))


def test_cli_accepts_structured_options(tmp_path):
    from wavlight.cli.main import main

    scene = _tiny_scene_file(tmp_path)
    out = tmp_path / "o.exr"
    r = CliRunner().invoke(main, ["render", str(scene), "-o", str(out), "--strategy", "structured",
                                  "--structured-strata", "16", "--json", "--quiet"])
    assert r.exit_code == 0, r.output
    st = json.loads(r.stdout.strip().splitlines()[-1])
    assert (st["strategy"], st["structured_strata"], st["structured_mode"]) == ("structured", 16, "stratified")
    assert out.is_file()
    r = CliRunner().invoke(main, ["render", str(scene), "-o", str(out), "--strategy", "structured",
                                  "--structured-strata", "16", "--structured-mode", "preintegrated", "--json",
                                  "--quiet"])
    assert r.exit_code == 0, r.output
    st = json.loads(r.stdout.strip().splitlines()[-1])
    assert st["structured_biased"] is True and st["structured_mode"] == "preintegrated"
    r = CliRunner().invoke(main, ["render", str(scene), "-o", str(out), "--strategy", "structured",
                                  "--structured-strata", "0"])
    assert r.exit_code == 2


# ============================================================================= k-center and strata
def test_k_center_properties():
    rng = np.random.default_rng(4)
    pts = rng.normal(size=(1500, 3))
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)
    centers, radii = structured.k_center(pts, 40, first=7)
    assert centers[0] == 7 and len(np.unique(centers)) == 40
    dist = np.linalg.norm(pts[:, None, :] - pts[None, centers, :], axis=2)     # (N, k)
    for i in range(40):
        cover = dist[:, :i + 1].min(axis=1).max()
        assert radii[i] == pytest.approx(cover, abs=1e-7)                      # exact covering radius
        if i:
            pair = np.linalg.norm(pts[centers[:i + 1], None] - pts[None, centers[:i + 1]], axis=2)
            pair[np.diag_indices(i + 1)] = np.inf
            assert pair.min() >= radii[i] - 1e-9                              # centers farther apart than it
    assert np.all(np.diff(radii) <= 1e-12)
    near = structured.nearest_center(pts, pts[centers])
    np.testing.assert_array_equal(near, dist.argmin(axis=1))


@pytest.mark.parametrize("k", [1, 5, 64])
def test_strata_partition_and_conserve_power(k, monkeypatch):
    monkeypatch.setattr(structured, "MAX_CANDIDATES", 300)      # exercise the subsampled path
    pix = _sky(64, 32, sun_radiance=500.0)                      # the sun: ~70% of the power
    pix[20:24, 10:30] = 0.0                                      # black texels: in no stratum
    env = Environment(pix, rotate_y=30.0)
    s = structured.Strata(env, k)
    rgb = pix.reshape(-1, 3).astype(np.float64)
    lum = rgb @ LUM
    nz = np.nonzero(lum > 0)[0]
    assert s.k == k and len(s.phi) == k
    np.testing.assert_array_equal(np.sort(s.texel), nz)           # every non-black texel exactly once
    assert np.all(s.stop > s.start) and s.start[0] == 0 and s.stop[-1] == len(nz)
    np.testing.assert_array_equal(s.start[1:], s.stop[:-1])
    d_omega = s.d_omega
    assert d_omega.sum() == pytest.approx(4 * np.pi, rel=1e-12)
    assert s.phi.sum() == pytest.approx((lum * d_omega).sum(), rel=1e-12)
    assert s.phi.sum() == pytest.approx(env.luminance_square().sum(), rel=1e-6)   # float32 luminance there
    np.testing.assert_allclose(s.rgb.sum(axis=0), (rgb * d_omega[:, None]).sum(axis=0), rtol=1e-12)
    np.testing.assert_allclose(s.rgb @ LUM, s.phi, rtol=1e-12)
    assert s.omega.sum() == pytest.approx(d_omega[nz].sum(), rel=1e-12)
    assert np.all(s.phi > 0)
    np.testing.assert_allclose(np.linalg.norm(s.centroid, axis=1), 1.0, rtol=1e-12)
    if k == 64:
        # the sun (5 degrees, 70% of the power) is the top layer: it shares no stratum with the sky
        # (the texels at its edge, partly covered, may form layers between the two)
        sun = np.isin(s.texel, np.nonzero(lum > 400)[0])
        assert s.layers >= 3 and set(s.level[s.stratum_of[sun]]) == {s.layers - 1}
        assert not np.intersect1d(s.stratum_of[sun], s.stratum_of[~sun]).size


def test_stratified_pdf_and_stratum_frequencies():
    pix = _sky(64, 32)
    env = Environment(pix, rotate_y=-50.0)
    st = _prepared(env, strata=16)
    count = 200_000
    sp = shading_points([0.0, 1.0, 0.0], 30.0, bsdfs.LAMBERT, 0.0, count)
    u = np.random.default_rng(3).random((count, 4))
    ds = st.sample(sp, u)
    lum = (pix.reshape(-1, 3).astype(np.float64) @ LUM)
    # sampled directions land in their texels; pdf = lum / Phi there
    pos = st.strata.sample_texels(u[:, 0], u[:, 1])
    hit = env.texel_index(ds.wi_world)
    assert np.mean(hit == st.strata.texel[pos]) > 0.999
    np.testing.assert_allclose(ds.pdf, lum[st.strata.texel[pos]] / st.strata.total, rtol=1e-12)
    same = hit == st.strata.texel[pos]
    np.testing.assert_allclose(st.pdf(sp, ds.wi_local, ds.wi_world)[same], ds.pdf[same], rtol=1e-12)
    # strata chosen with probability Phi_s / Phi
    observed = np.bincount(st.strata.stratum_of[pos], minlength=st.strata.k)
    _, p = stats.chisquare(observed, st.strata.phi / st.strata.total * count)
    assert p > ALPHA, p


def test_systematic_samples_unbiased_and_lower_variance():
    """samples = 8 (systematic over the stratum CDF) and samples = 1 both estimate the exact
    unshadowed integral; the systematic one with less than 1/8 of the variance."""
    pix = _sky(64, 32)
    env = Environment(pix)
    count = 20000
    albedo = np.array([0.9, 0.6, 0.3])
    sp = shading_points([0.3, 1.0, 0.2], 40.0, bsdfs.GGX, 0.3, count, albedo=albedo)
    exact = albedo * _quadrature(pix, sp)
    est = {}
    for n in (1, 8):
        _, value = _prepared(env, strata=32, samples=n).shade(env, sp, np.random.default_rng(n).random((count, 4)))
        assert value.shape == (count, n, 3)
        est[n] = value.sum(axis=1)
        se = est[n].std(axis=0, ddof=1) / math.sqrt(count)
        assert np.all(np.abs(est[n].mean(axis=0) - exact) <= z_threshold(3, count) * se + 2e-3 * exact), \
            (n, est[n].mean(axis=0), exact, se)
    assert (est[8] @ LUM).var() * 8 < (est[1] @ LUM).var()


# ============================================================================= preintegrated: biased
def _bias_detected(est, exact, count):
    """True when the mean of ``est`` (count, 3) differs from ``exact`` beyond Z standard errors
    in some channel (and by more than 1% relative, above quadrature error)."""
    mean = est.mean(axis=0)
    se = est.std(axis=0, ddof=1) / math.sqrt(count)
    return bool(np.any((np.abs(mean - exact) > Z * se + 0.01 * exact))), mean


def test_preintegrated_bias_small_light_vs_smooth_map():
    count = 4000
    sp = shading_points([0.2, 1.0, 0.1], 35.0, bsdfs.GGX, 0.3, count)
    u = np.random.default_rng(9).random((count, 4))
    # one small bright region on a near-black map: collapsing it to a point costs little
    small = np.full((64, 128, 3), 1e-4, np.float32)
    small[18:20, 72:74] = 1600.0
    env = Environment(small)
    with pytest.warns(UserWarning, match="biased"):
        st = _prepared(env, strata=16, mode="preintegrated")
    assert st.info()["structured_biased"] is True
    _, value = st.shade(env, sp, u)
    exact = _quadrature(small, sp)
    detected, mean = _bias_detected(value.sum(axis=1), exact, count)
    assert not detected and np.all(np.abs(mean / exact - 1) < 0.03), (mean, exact)
    # a smooth sky: the glossy lobe sees point lights instead of the sky; the check detects it
    smooth = _sky(64, 32, sun=False)
    env = Environment(smooth)
    exact = _quadrature(smooth, sp)
    with pytest.warns(UserWarning):
        _, value = _prepared(env, strata=16, mode="preintegrated").shade(env, sp, u)
    detected, mean = _bias_detected(value.sum(axis=1), exact, count)
    assert detected and np.max(np.abs(mean / exact - 1)) > 0.05, (mean, exact)
    # stratified mode on the same map passes the same check
    _, value = _prepared(env, strata=16).shade(env, sp, u)
    detected, mean = _bias_detected(value.sum(axis=1), exact, count)
    assert not detected, (mean, exact)


def test_preintegrated_all_lights_when_few_strata():
    """K <= 8: K slots, one per light, deterministic: albedo f cos(c_s) Phi_s^rgb."""
    env = Environment(_sky(32, 16))
    with pytest.warns(UserWarning):
        st = _prepared(env, strata=6, mode="preintegrated")
    sp = shading_points([0.0, 1.0, 0.0], 20.0, bsdfs.LAMBERT, 0.0, 5, albedo=(0.5, 0.5, 0.5))
    wi, value = st.shade(env, sp, np.random.default_rng(0).random((5, 4)))
    assert wi.shape == value.shape == (5, 6, 3)
    cos = np.maximum(st.strata.centroid[:, 1], 0.0)
    np.testing.assert_allclose(value[0], 0.5 * (cos / np.pi)[:, None] * st.strata.rgb, rtol=1e-9, atol=1e-15)


# ============================================================================= rendering
def test_white_furnace(tmp_path):
    env = write_env(tmp_path, "white.exr", np.ones((8, 16, 3)))
    albedo = np.array([0.7, 0.45, 0.2])
    scene = load(tmp_path, render=dict(width=20, height=20, spp=16, seed=3),
                 camera=dict(eye=[0.3, 0.4, 3.5], target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0], fov_y=40.0),
                 environment=dict(file=env),
                 objects=[dict(shape="sphere", center=[0.0, 0.0, 0.0], radius=1.0, subdivisions=5,
                               material="white")],
                 materials={"white": dict(type="lambert", albedo=albedo.tolist())})
    r = wavlight.render_full(scene, strategy="structured", spp=16, seed=5, structured_strata=16)
    cam = camera_of(scene)
    rays = cam.centre_rays()
    to_c = -cam.eye / np.linalg.norm(cam.eye)
    inner = np.arccos(np.clip(rays @ to_c, -1, 1)) < 0.8 * math.asin(1.0 / np.linalg.norm(cam.eye))
    assert inner.sum() > 60
    check_estimates(r.image, r.stderr, albedo, inner, 16, label="structured furnace")


def test_unbiased_against_mis_under_black_texels_by_lamps(tmp_path):
    """structured (stratified, K = 64, 64 spp) and mis (128 spp) agree on a glossy sphere on a
    floor under the shipped st_fagans_interior_512 with black texels next to its lamps and a
    black bottom band (stability.black_around_lamps, as in the small Debevec probes): every
    pixel channel and the image mean within their combined standard error (Bonferroni over the
    pixels, Student t with the smaller spp)."""
    from wavlight.envmap import read_image
    from wavlight.evaluation.stability import black_around_lamps

    env = write_env(tmp_path, "lamps.exr",
                    black_around_lamps(read_image(str(wavlight.data.path("st_fagans_interior_512")))))
    scene = load(tmp_path, render=dict(width=40, height=30, spp=16, seed=1),
                 camera=dict(eye=[0.0, 1.0, 3.2], target=[0.0, 0.45, 0.0], fov_y=38.0),
                 environment=dict(file=env, rotate_y=60.0),
                 objects=[dict(shape="sphere", center=[0.0, 0.6, 0.0], radius=0.6, material="glossy"),
                          dict(shape="quad", center=[0.0, 0.0, 0.0], normal=[0.0, 1.0, 0.0], size=5.0,
                               material="floor")],
                 materials={"glossy": dict(type="ggx", albedo=[0.9, 0.7, 0.4], roughness=0.3),
                            "floor": dict(type="lambert", albedo=[0.5, 0.5, 0.5])})
    a = wavlight.render_full(scene, strategy="structured", spp=64, seed=2)
    b = wavlight.render_full(scene, strategy="mis", spp=128, seed=3)
    diff = a.image.astype(np.float64) - b.image
    se = np.sqrt(a.stderr.astype(np.float64) ** 2 + b.stderr.astype(np.float64) ** 2)
    hit = (a.stderr > 0).any(axis=2) | (b.stderr > 0).any(axis=2)
    assert hit.sum() > 700
    assert np.all(diff[~hit] == 0)
    m = int(hit.sum())
    z = z_threshold(3 * m, 64)
    zs = np.abs(diff[hit]) / np.maximum(se[hit], 1e-30)
    assert np.all(zs <= z), f"{(zs > z).sum()} pixel channels beyond {z:.2f} stderr, worst z {zs.max():.2f}"
    mean_diff = diff[hit].mean(axis=0)
    mean_se = np.sqrt((se[hit] ** 2).sum(axis=0)) / m
    assert np.all(np.abs(mean_diff) <= z_threshold(3, 64 * m) * mean_se), (mean_diff, mean_se)


def test_black_and_tiny_maps():
    """An all-black map gives 0 (no strata, no NaN); 1x1 and 2x1 maps give at most as many strata
    as texels and stay unbiased (lambert under a constant 1x1 map: the albedo)."""
    sp = shading_points([0.0, 1.0, 0.0], 30.0, bsdfs.LAMBERT, 0.0, 4000, albedo=(0.5, 0.5, 0.5))
    u = np.random.default_rng(1).random((4000, 4))
    env = Environment(np.zeros((4, 8, 3), np.float32))
    st = _prepared(env)
    wi, value = st.shade(env, sp, u)
    assert np.all(value == 0) and np.all(np.isfinite(wi)) and np.all(st.sample(sp, u).pdf == 0)
    env = Environment(np.ones((1, 1, 3), np.float32))
    st = _prepared(env, strata=64)
    assert st.strata.k == 1
    est = st.shade(env, sp, u)[1].sum(axis=1)
    se = est.std(axis=0, ddof=1) / math.sqrt(len(est))
    assert np.all(np.abs(est.mean(axis=0) - 0.5) <= Z * se)
    assert _prepared(Environment(np.ones((1, 2, 3), np.float32)), strata=64).strata.k == 2


def test_per_stratum_default_is_unbiased_and_uses_every_stratum():
    """The default draws one direction in every stratum (K slots) and sums f cos L / p_s: under a
    constant map a lambert point gives its albedo on average (within 5 standard errors over
    independent shading samples), and every stratum gets a slot."""
    env = Environment(np.ones((16, 32, 3), np.float32))
    strat = _prepared(env, strata=8)
    count = 4000
    sp = shading_points((0.0, 1.0, 0.0), 30.0, bsdfs.LAMBERT, 0.0, count, albedo=(0.5, 0.5, 0.5))
    wi, value = strat.shade(env, sp, np.random.default_rng(7).random((count, 4)))
    assert wi.shape == (count, strat.strata.k, 3)
    est = value.sum(axis=1)[:, 0]
    assert abs(est.mean() - 0.5) < 5 * est.std(ddof=1) / np.sqrt(count) + 1e-9
    # each slot's direction lies in its own stratum
    t = env.texel_index(wi.reshape(-1, 3)).reshape(count, -1)
    slot_of = np.empty(env.width * env.height, np.int64)
    slot_of[strat.strata.texel] = strat.strata.stratum_of
    assert np.all(slot_of[t] == np.arange(strat.strata.k)[None, :])
