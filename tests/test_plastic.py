"""The plastic material (Mitsuba 3's roughplastic; docs/decisions/plastic-material.md).

Its numpy twin (wavlight.bsdfs) against Mitsuba 3's own BSDF where Mitsuba is installed, the
kernels (kernels/bsdf.h through kernels/bsdf.cl) against the twin, the properties its
sampling relies on (reciprocity, energy, the pdf of the sampler), and every strategy (the
numpy-only sir and structured too) against ``mis`` on a plastic sphere (the shade kernels
against their twins on plastic are in tests/test_shading.py; the bakes in tests/relight/).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import wavlight
from wavlight import bsdfs, warp
from scenes_util import check_estimates, load, over_floor, write_env, write_sun_sky, z_threshold

CASES = [(0.05, 1.5, (0.8, 0.2, 0.1)), (0.3, 1.5, (0.1, 0.5, 0.9)), (0.7, 1.33, (1.0, 1.0, 1.0)),
         (0.002, 2.0, (0.5, 0.5, 0.5))]


def _directions(rng, count, lower=0.0):
    """count unit directions with z > lower (uniform on the sphere, cut)."""
    d = rng.normal(size=(4 * count + 64, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d[d[:, 2] > lower][:count]


def _tables(case, count):
    alpha, ior, albedo = case
    return np.tile(bsdfs.plastic_table(alpha, ior, albedo), (count, 1)), np.asarray(albedo, np.float64)


# ============================================================================= Mitsuba's BSDF
@pytest.fixture(scope="module")
def mitsuba_scalar():
    try:
        import mitsuba as mi
    except ImportError:
        pytest.skip("Mitsuba 3 is not installed (pip install 'wavlight[peers]'): the roughplastic comparison "
                    "needs it")
    mi.set_variant("scalar_rgb")
    return mi


@pytest.mark.parametrize("case", CASES, ids=[f"alpha{c[0]}-ior{c[1]}" for c in CASES])
def test_plastic_is_mitsubas_roughplastic(mitsuba_scalar, case):
    """f cos and pdf of bsdfs' plastic equal Mitsuba 3's roughplastic (ggx, nonlinear false,
    ext_ior 1) at random pairs of directions, to Mitsuba's float32 rounding (Mitsuba's si.wi is
    wavlight's wo, the viewer's side)."""
    mi = mitsuba_scalar
    alpha, ior, albedo = case
    bsdf = mi.load_dict({"type": "roughplastic", "distribution": "ggx", "alpha": alpha, "int_ior": ior,
                         "ext_ior": 1.0, "nonlinear": False,
                         "diffuse_reflectance": {"type": "rgb", "value": list(albedo)}})
    rng = np.random.default_rng(7)
    count = 200
    wo, wi = _directions(rng, count, 0.02), _directions(rng, count, 0.02)
    # half of the pairs near the mirror direction, where the specular lobe is large
    wi[::2] = bsdfs.reflect(wo[::2]) + 0.3 * alpha * rng.normal(size=(count // 2, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wi = wi[wi[:, 2] > 0.02]
    wo = wo[:len(wi)]
    table, alb = _tables(case, len(wi))
    spec, diff = bsdfs.plastic_parts(wi, wo, table)
    ours = spec[:, None] + diff[:, None] * alb
    ours_pdf = bsdfs.plastic_pdf(wi, wo, table)
    ctx = mi.BSDFContext()
    theirs, theirs_pdf = np.zeros((len(wi), 3)), np.zeros(len(wi))
    for k in range(len(wi)):   # Mitsuba's scalar variant takes one direction per call (a test, not a hot path)
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*wo[k])
        theirs[k] = np.array(bsdf.eval(ctx, si, mi.Vector3f(*wi[k])))
        theirs_pdf[k] = bsdf.pdf(ctx, si, mi.Vector3f(*wi[k]))
    np.testing.assert_allclose(ours, theirs, rtol=2e-4, atol=1e-6)
    np.testing.assert_allclose(ours_pdf, theirs_pdf, rtol=2e-4, atol=1e-6)


# ============================================================================= kernel and twin
@pytest.mark.parametrize("kinds", [15, 8], ids=["all-kinds", "plastic-only"])
def test_material_kernels_match_numpy(device, kinds):
    """kernels/bsdf.h material_eval_pdf and material_sample (through kernels/bsdf.cl) against
    bsdfs.eval_split, pdf and sample, for every kind in one program (and plastic alone):
    directions to 2e-4 but where the lobe choice u0 < q falls within float32 rounding of q
    (at most 0.1%), values to 1e-3 relative."""
    from wavlight import cl

    rng = np.random.default_rng(3)
    mats = [(bsdfs.LAMBERT, 0.0), (bsdfs.PHONG, 40.0), (bsdfs.GGX, 0.2)] if kinds == 15 else []
    mats += [(bsdfs.PLASTIC, c[0]) for c in CASES]
    table = np.zeros((len(mats), bsdfs.PLASTIC_STRIDE), np.float32)
    for i, (kind, param) in enumerate(mats):
        if kind == bsdfs.PLASTIC:
            case = next(c for c in CASES if c[0] == param)
            table[i] = bsdfs.plastic_table(*case)
    count = 8000
    mat = rng.integers(0, len(mats), count).astype(np.int32)
    kind = np.array([m[0] for m in mats], np.int32)[mat]
    param = np.array([m[1] for m in mats], np.float32)[mat]
    wo = _directions(rng, count, 0.01)
    wi = _directions(rng, count, -0.3)
    u = rng.random((count, 2), dtype=np.float32)
    q = cl.thread_queue()
    prog = cl.program("bsdf.cl", BSDF_KINDS=kinds)
    four = lambda a: cl.to_device(np.concatenate([a, np.zeros((len(a), 1))], 1).astype(np.float32))
    args = (cl.to_device(kind), cl.to_device(param), cl.to_device(mat), cl.to_device(table.ravel()))
    out = cl.empty(16 * count)
    cl.kernel(prog, "material_eval_points")(q, (count,), None, four(wi), four(wo), *args, out)
    got = cl.read(out, (count, 4), np.float32, q)
    cl.kernel(prog, "material_sample_points")(q, (count,), None, four(wo), cl.to_device(u), *args, out)
    sampled = cl.read(out, (count, 4), np.float32, q)[:, :3]
    f, fd, p, ws = np.zeros(count), np.zeros(count), np.zeros(count), np.zeros((count, 3))
    for k in np.unique(kind):   # material kinds
        sel = kind == k
        tab = table[mat[sel]]
        f[sel], fd[sel] = bsdfs.eval_split(int(k), param[sel].astype(np.float64), wi[sel], wo[sel], table=tab)
        p[sel] = bsdfs.pdf(int(k), param[sel].astype(np.float64), wi[sel], wo[sel], table=tab)
        ws[sel] = bsdfs.sample(int(k), param[sel].astype(np.float64), u[sel].astype(np.float64), wo[sel],
                               table=tab)[0]
    for name, a, b in (("f cos", got[:, 0], f), ("albedo's part", got[:, 1], fd), ("pdf", got[:, 2], p)):
        np.testing.assert_allclose(a, b, rtol=1e-3, atol=1e-5, err_msg=name)
    close = np.abs(sampled - ws).max(1) < 2e-4
    assert close.mean() > 0.999, f"{(~close).sum()} of {count} sampled directions differ"
    assert (close | (kind != bsdfs.PLASTIC)).mean() > 0.999


# ============================================================================= properties
@pytest.mark.parametrize("case", CASES, ids=[f"alpha{c[0]}-ior{c[1]}" for c in CASES])
def test_plastic_is_reciprocal(case):
    """f(wi, wo) = f(wo, wi) (f cos / cos_i both ways): the Fresnel term at the half vector, D,
    G1 G1 / (4 cos_i cos_o) and T(cos_i) T(cos_o) are symmetric."""
    rng = np.random.default_rng(5)
    count = 4000
    wi, wo = _directions(rng, count, 0.01), _directions(rng, count, 0.01)
    table, _ = _tables(case, count)
    a = bsdfs.plastic_parts(wi, wo, table)
    b = bsdfs.plastic_parts(wo, wi, table)
    for x, y in zip(a, b):
        np.testing.assert_allclose(x / wi[:, 2], y / wo[:, 2], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("case", CASES, ids=[f"alpha{c[0]}-ior{c[1]}" for c in CASES])
@pytest.mark.parametrize("view_deg", [0.0, 50.0, 85.0])
def test_plastic_pdf_is_its_samplers(case, view_deg):
    """The sampler's density is the pdf: over the upper hemisphere the pdf integrates (uniform
    samples) to the share of samples the sampler puts there, and for the integrand g = f cos
    the estimates E_sampler[g / pdf] and E_uniform[g / p_uniform] agree, each within its
    standard error (fixed seeds; the same z threshold as the renders' tests). With the
    albedo 1, that integral (the directional albedo) is at most 1: a white furnace loses
    energy, never gains it."""
    rng = np.random.default_rng(int(view_deg) + 17)
    count = 400_000
    th = math.radians(view_deg)
    wo = np.tile([math.sin(th), 0.0, math.cos(th)], (count, 1))
    table, albedo = _tables(case, count)
    z = z_threshold(3, count)
    wu = warp.square_to_uniform_hemisphere(rng.random((count, 2)))
    mass = bsdfs.plastic_pdf(wu, wo, table) / warp.square_to_uniform_hemisphere_pdf(wu)
    ws, pdf = bsdfs.plastic_sample(rng.random((count, 2)), wo, table)
    above = (ws[:, 2] > 0).astype(np.float64)
    se = math.hypot(mass.std() / math.sqrt(count), above.std() / math.sqrt(count))
    assert abs(mass.mean() - above.mean()) <= z * se + 1e-9, (mass.mean(), above.mean(), se)
    g_u = bsdfs.plastic_eval(wu, wo, table) / warp.square_to_uniform_hemisphere_pdf(wu)
    with np.errstate(divide="ignore", invalid="ignore"):
        g_s = np.where(pdf > 0, bsdfs.plastic_eval(ws, wo, table) / pdf, 0.0)
    se = math.hypot(g_u.std() / math.sqrt(count), g_s.std() / math.sqrt(count))
    assert abs(g_u.mean() - g_s.mean()) <= z * se, (g_u.mean(), g_s.mean(), se)
    white = np.tile(bsdfs.plastic_table(case[0], case[1], (1.0, 1.0, 1.0)), (count, 1))
    with np.errstate(divide="ignore", invalid="ignore"):
        furnace = np.where(pdf > 0, bsdfs.plastic_eval(ws, wo, white) / pdf, 0.0)
    assert furnace.mean() <= 1.0 + z * furnace.std() / math.sqrt(count), furnace.mean()


def test_tint_gives_f_cos_with_albedo():
    """bsdfs.tint turns the scalar f cos into f cos with albedo: spec + albedo diffuse."""
    rng = np.random.default_rng(2)
    wi, wo = _directions(rng, 500, 0.01), _directions(rng, 500, 0.01)
    table, albedo = _tables(CASES[0], 500)
    f, fd = bsdfs.eval_split(bsdfs.PLASTIC, np.full(500, CASES[0][0]), wi, wo, table=table)
    spec, diff = bsdfs.plastic_parts(wi, wo, table)
    np.testing.assert_allclose(f[:, None] * bsdfs.tint(f, fd, np.tile(albedo, (500, 1))),
                               spec[:, None] + diff[:, None] * albedo, rtol=1e-12, atol=1e-15)


# ============================================================================= scenes
def test_scene_plastic_keys(tmp_path):
    """type "plastic": albedo, alpha (default 0.1) and ior (default 1.5); a bad ior is one line."""
    write_sun_sky(tmp_path)
    base = over_floor({"shape": "sphere", "radius": 0.5, "center": [0, 0.5, 0]}, width=8, height=8)
    base["materials"]["m"] = {"type": "plastic", "albedo": [0.5, 0.2, 0.1]}
    scene = wavlight.load_dict(base, base_dir=tmp_path)
    m = scene.materials[0]
    assert (m.kind, m.param, m.ior) == (bsdfs.PLASTIC, 0.1, 1.5)
    base["materials"]["m"] = {"type": "plastic", "albedo": [0.5, 0.2, 0.1], "alpha": 0.3, "ior": 1.7}
    m = wavlight.load_dict(base, base_dir=tmp_path).materials[0]
    assert (m.param, m.ior) == (0.3, 1.7)
    base["materials"]["m"]["ior"] = 1.0
    with pytest.raises(wavlight.SceneError, match="ior"):
        wavlight.load_dict(base, base_dir=tmp_path)


SUN_STRATEGIES = ["light", "mis_comp", "wavelet", "wavelet-pair", "sir", "structured"]
SMOOTH_STRATEGIES = ["uniform", "cosine", "bsdf"] + SUN_STRATEGIES


def _smooth_sky(folder):
    """A 64 x 32 sky, 1.5 at the zenith to 0.3 at the nadir, with a broad warm glow (a Gaussian of
    about 15 degrees, peak 40): lighting that the BSDF-only strategies find at 64 spp."""
    rows, cols = np.meshgrid(np.arange(32) + 0.5, np.arange(64) + 0.5, indexing="ij")
    glow = 40.0 * np.exp(-((rows - 9.0) ** 2 + (cols - 20.0) ** 2) / (2 * 2.5 ** 2))
    sky = np.linspace(1.5, 0.3, 32)[:, None, None] + glow[..., None] * np.array([1.0, 0.8, 0.6])
    write_env(folder, "sky.exr", sky.astype(np.float32))


@pytest.fixture(scope="module")
def plastic_scenes(tmp_path_factory):
    scenes = {}
    for sky in ("sun", "smooth"):
        d = tmp_path_factory.mktemp(f"plastic-{sky}")
        write_sun_sky(d) if sky == "sun" else _smooth_sky(d)
        scene = over_floor({"shape": "sphere", "radius": 0.6, "center": [0, 0.6, 0], "subdivisions": 4},
                           width=24, height=20)
        scene["materials"]["m"] = {"type": "plastic", "albedo": [0.7, 0.3, 0.1], "alpha": 0.15, "ior": 1.5}
        scene["materials"]["floor"] = {"type": "plastic", "albedo": [0.4, 0.5, 0.6], "alpha": 0.6}
        scenes[sky] = load(d, **scene)
    return scenes


@pytest.mark.slow
@pytest.mark.parametrize("sky, strategy", [("sun", s) for s in SUN_STRATEGIES]
                         + [("smooth", s) for s in SMOOTH_STRATEGIES])
def test_strategies_agree_with_mis_on_plastic(plastic_scenes, sky, strategy):
    """Every strategy against mis on a plastic sphere over a plastic floor, per pixel and on
    the mean, within the two renders' standard errors (unbiased: wavelet's product walk samples
    the two-lobe mixture with its exact pdf). wavelet-pair: the MIS pair (no candidates). Under a
    sky with a one-texel sun of 3000 (hard shadows) the strategies that sample the light; under a
    smooth sky every one (uniform, cosine and bsdf find a one-texel sun in about 1 of 300
    samples: at 64 spp their standard error is not an estimate of their error)."""
    scene = plastic_scenes[sky]
    spp = 64
    opts = {"wavelet_candidates": 0} if strategy == "wavelet-pair" else {}
    name = strategy.split("-")[0]
    ref = wavlight.render_full(scene, strategy="mis", spp=spp, seed=1)
    r = wavlight.render_full(scene, strategy=name, spp=spp, seed=2, **opts)
    mask = np.ones(r.image.shape[:2], bool)
    check_estimates(r.image - ref.image, np.hypot(r.stderr, ref.stderr), 0.0, mask, spp, label=f"{sky}/{strategy}")
