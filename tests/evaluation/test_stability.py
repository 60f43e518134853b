"""The stability suite (wavlight/evaluation/stability.py), small: the quick cases (analytic references and the
all-black map) x every strategy at 12 x 12 pixels, 3 x 32 spp, run once per module; then its
statistics on synthetic data, deliberately biased, NaN-producing and crashing renders, the
real-map cases without a network, and the command line.
"""
from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
from click.testing import CliRunner
from scipy import stats

import wavlight
from wavlight.cli.main import main

from scenes_util import toml_text, write_raw_image
from wavlight.data import DATA_ENV, URL_ENV
from wavlight.evaluation import stability

QUICK = dict(size=(12, 12), spp=32, repetitions=3)


def _no_nan(text):
    """json.loads that refuses NaN and Infinity."""
    def bad(name):
        raise AssertionError(f"{name} in JSON output")
    return json.loads(text, parse_constant=bad)


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("stability")
    seen = []
    results = stability.run_stability(out, cases=stability.QUICK_CASES, progress=lambda *a: seen.append(a),
                                      **QUICK)
    return out, results, seen


# ----------------------------------------------------------------------------- the quick suite
@pytest.mark.slow
def test_outputs_exist_and_hold_no_nan(quick):
    out, results, seen = quick
    for name in ("stability.csv", "stability.json", "charts/stability.png", "charts/stability.svg"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    data = _no_nan((out / "stability.json").read_text())
    assert len(data["cells"]) == len(stability.QUICK_CASES) * len(wavlight.STRATEGIES)
    assert data["cells_tested"] == sum(c["verdict"] != "failed" for c in data["cells"])
    with open(out / "stability.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(data["cells"])
    assert {r["strategy"] for r in rows} == set(wavlight.STRATEGIES)   # discovered at run time (sir too)
    for r in rows:
        for k, v in r.items():
            assert v.lower() not in ("nan", "inf", "-inf"), (r["case"], r["strategy"], k, v)
    assert seen and seen[-1][0] == seen[-1][1]                            # progress reached the end
    assert "stability suite" in stability.format_table(results)


@pytest.mark.slow
def test_nothing_crashes_and_no_output_holds_nan(quick):
    _, results, _ = quick
    for c in results["cells"]:
        assert c["verdict"] != "failed", (c["case"], c["strategy"], c["failure"])
        assert c["nan_values"] == 0
        for k in ("z_mean", "variance", "rel_variance", "firefly", "vov", "pixel_skew"):
            assert c[k] is not None and math.isfinite(c[k]), (c["case"], c["strategy"], k)


def test_every_strategy_passes_the_bias_test_on_analytic_cases(quick):
    """Every strategy wavlight ships is unbiased by construction (README, Strategies)."""
    _, results, _ = quick
    kinds = {ci["case"]: ci["reference"] for ci in results["cases"]}
    assert set(kinds.values()) <= {"analytic", "exactly 0"}
    for c in results["cells"]:
        assert c["verdict"] == "ok", (c["case"], c["strategy"], c["z_mean"], c["z_pixel_max"], c["pixel_test"])
    # the per-pixel test really ran where the maps are smooth, for every strategy
    smooth = [c for c in results["cells"] if c["case"] in ("overcast_lambert", "tiny_2x1", "tiny_1x1")]
    assert len(smooth) == 3 * len(wavlight.STRATEGIES)
    assert all(c["pixel_test"] == "applied" and c["pixels_tested"] >= 100 for c in smooth)


def test_variance_and_fireflies_are_measured(quick):
    _, results, _ = quick
    v = {(c["case"], c["strategy"]): c for c in results["cells"]}
    # cosine (= bsdf) sampling of a lambert floor under a constant map is exact: no variance, no firefly
    for s in ("cosine", "bsdf"):
        assert v["tiny_1x1", s]["variance"] == 0 and v["tiny_1x1", s]["firefly"] < 1e-5
    assert v["tiny_1x1", "uniform"]["variance"] > 0 and v["tiny_1x1", "uniform"]["firefly"] > 0.01
    # one bright texel: light sampling finds it, hemisphere sampling mostly misses it (fireflies)
    assert v["one_texel", "uniform"]["firefly"] > 10 * v["one_texel", "light"]["firefly"]
    assert v["one_texel", "uniform"]["rel_variance"] > 100 * v["one_texel", "light"]["rel_variance"]


def test_all_black_map_gives_exactly_zero(quick, tmp_path):
    _, results, _ = quick
    info = next(ci for ci in results["cases"] if ci["case"] == "all_black")
    assert info["cli_refuses"] is True
    cells = [c for c in results["cells"] if c["case"] == "all_black"]
    assert len(cells) == len(wavlight.STRATEGIES) and all(c["exact_zero"] is True for c in cells)
    # and the command line refuses the same scene with one line and exit code 2
    built = stability.CASES["all_black"].build(8, 8)
    write_raw_image(tmp_path / "black.exr", built.scene["environment"]["pixels"])   # a scene file names a file
    path = tmp_path / "scene.toml"
    path.write_text(toml_text({**built.scene, "environment": {"file": "black.exr"}}))
    r = CliRunner().invoke(main, ["render", str(path), "-o", str(tmp_path / "x.exr"), "--quiet"])
    assert r.exit_code == 2 and "black everywhere" in r.output


def test_room_slit_is_closed_but_for_its_slit(tmp_path):
    """The room_slit case's scene: every pixel sees the room's inside, the sky is seen only
    through the slit (every upward direction from the floor's centre is blocked, directions
    towards the slit are not), and the budget pilot counts it as shadowed."""
    from wavlight import occlusion, strategies
    from wavlight.camera import camera_rays
    from wavlight.raytrace import RayTracer

    built = stability.CASES["room_slit"].build(16, 16)
    scene = wavlight.load_dict(built.scene)
    tracer = RayTracer(scene.vertices, scene.faces)
    py, px = np.mgrid[0:16, 0:16]
    for corner in ((0.0, 0.0), (1.0, 1.0)):
        o, d = camera_rays(scene, px.ravel(), py.ravel(), np.tile(corner, (256, 1)), 16, 16)
        assert np.all(tracer.intersect(o, d)[0] >= 0)
    rng = np.random.default_rng(1)
    d = rng.normal(size=(4096, 3)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    centre = np.float32([[0.0, 0.01, 0.0]])
    up = d[d[:, 1] > 0.2]
    assert np.all(tracer.occluded(np.repeat(centre, len(up), 0), up))
    to_slit = np.float32([[0.0, 0.1, 1.0]]) / np.linalg.norm([0.0, 0.1, 1.0])
    assert not tracer.occluded(centre, to_slit)[0]
    assert occlusion.visibility_variance(scene, tracer, 16, 16) >= strategies.SHADOWED_VARIANCE


#: the cases whose maps are generated, and the format their files had before the maps were given
#: to load_dict as arrays
GENERATED = {"sun_synthetic": ".exr", "overcast_lambert": ".pfm", "one_texel": ".exr", "all_black": ".exr",
             "black_by_lamps": ".exr", "bad_texels": ".exr", "npot_map": ".exr", "tiny_2x1": ".pfm",
             "tiny_1x1": ".exr"}


@pytest.mark.parametrize("name", sorted(GENERATED))
def test_given_maps_are_the_pixels_of_the_files_they_replace(tmp_path, name):
    """Each generated map given as an array makes the scene its file made (written as float32
    .exr or .pfm and read back): the same environment pixels bit for bit, geometry, settings and
    warnings, so that every render, seed for seed, and every result of the suite is unchanged."""
    import warnings

    built = stability.CASES[name].build(10, 8)
    env = dict(built.scene["environment"])
    pixels = env.pop("pixels")
    assert pixels.dtype == np.float32
    write_raw_image(tmp_path / f"map{GENERATED[name]}", pixels)
    scenes, caught = [], []
    for table in ({**env, "pixels": pixels}, {**env, "file": f"map{GENERATED[name]}"}):
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always")
            scenes.append(wavlight.load_dict({**built.scene, "environment": table}, base_dir=tmp_path))
        caught.append([str(w.message).split(": ")[-1] for w in seen])
    given, filed = scenes
    assert np.array_equal(given.environment.pixels, filed.environment.pixels)
    assert given.environment.rotate_y == filed.environment.rotate_y
    for key in ("vertices", "faces", "face_material"):
        assert np.array_equal(getattr(given, key), getattr(filed, key))
    assert caught[0] == caught[1]
    assert given.files == [] and filed.files == [str(tmp_path / f"map{GENERATED[name]}")]


def test_a_case_renders_the_same_image_from_its_array_as_from_its_file(tmp_path, device):
    built = stability.CASES["npot_map"].build(8, 6)
    env = dict(built.scene["environment"])
    write_raw_image(tmp_path / "map.exr", env.pop("pixels"))
    given = wavlight.load_dict(built.scene)
    filed = wavlight.load_dict({**built.scene, "environment": {**env, "file": "map.exr"}}, base_dir=tmp_path)
    for strategy in ("mis", "wavelet"):
        a = wavlight.render(given, spp=4, strategy=strategy, seed=11)
        b = wavlight.render(filed, spp=4, strategy=strategy, seed=11)
        assert np.array_equal(a, b), strategy


def test_bad_texels_warning_is_recorded(quick):
    _, results, _ = quick
    info = next(ci for ci in results["cases"] if ci["case"] == "bad_texels")
    assert info["warned"] is True
    assert any("28 texel(s) with NaN, Inf or negative values" in w for w in info["warnings"])


# ----------------------------------------------------------------------------- the statistics
def test_t_quantile_matches_scipy():
    for p in (1e-2, 1e-5, 1e-8):
        for dof in (60, 508, 5000):
            assert abs(stability.t_quantile(p, dof) - stats.t.isf(p, dof)) < 2e-3 * stats.t.isf(p, dof)


def test_thresholds_grow_with_the_number_of_tests():
    a = stability.thresholds(0.01, 10, 100, 500)
    b = stability.thresholds(0.01, 100, 100, 500)
    c = stability.thresholds(0.01, 100, 10000, 500)
    assert a[0] < b[0] and a[1] < b[1] < c[1] and b[0] == c[0]
    assert abs(b[0] - stats.t.isf(0.01 / (2 * 100 * 3) / 2, 500)) < 0.01


def _gaussian(rng, r=4, h=16, w=16, mu=1.0, sigma=0.2, spp=64, shift=0.0):
    """R images whose pixels are means of spp normal samples, with their standard errors."""
    x = rng.normal(mu, sigma, (r, h, w, 3, spp))
    return x.mean(-1) + shift, x.std(-1, ddof=1) / math.sqrt(spp)


def _verdict(images, stderrs, ref, spp, n_cells=1, **kw):
    st = stability.bias_statistics(images, stderrs, ref, spp=spp, **kw)
    t_mean, t_pixel = stability.thresholds(0.01, n_cells, st["n_pixels"], images.shape[0] * (spp - 1))
    return stability.judge(st, t_mean, t_pixel), st


def test_unbiased_synthetic_data_passes_and_biased_is_flagged():
    rng = np.random.default_rng(1)
    ok = [_verdict(*_gaussian(rng), 1.0, 64)[0]["verdict"] for _ in range(20)]
    assert ok.count("ok") == 20
    # a 1% bias of the image mean (about 8 standard errors)
    v, st = _verdict(*_gaussian(rng, shift=0.01), 1.0, 64)
    assert v["verdict"] == "biased?" and st["z_mean"] > 5
    # a local bias: one pixel off by 30% leaves the image mean within its error, the per-pixel test sees it
    x, s = _gaussian(rng, h=32, w=32)
    x[:, 5, 7, :] *= 1.3
    v, st = _verdict(x, s, 1.0, 64)
    assert abs(st["z_mean"]) < 3 and v["pixel_test"] == "applied" and v["pixels_over"] == 1
    assert v["verdict"] == "biased?"
    # a deterministic (zero-variance) estimator that is off by 1e-3: z is capped, flagged
    z = np.zeros((3, 4, 4, 3))
    v, st = _verdict(np.full((3, 4, 4, 3), 1.001), z, 1.0, 64)
    assert v["verdict"] == "biased?" and st["z_mean"] == stability.Z_CAP
    # ... but float32 rounding of an exact answer is not a bias
    v, _ = _verdict(np.full((3, 4, 4, 3), np.float32(0.7)), z, 0.7, 64)
    assert v["verdict"] == "ok"


def test_heavy_tails_are_not_called_bias():
    """An unbiased estimator with rare huge samples (value 1e4 with probability 1e-4, else ~0):
    most pixels see none of them, their z-scores are meaningless; the suite must say so."""
    rng = np.random.default_rng(2)
    r, h, w, spp = 4, 16, 16, 64
    hits = rng.random((r, h, w, 3, spp)) < 1e-3
    samples = np.where(hits, 1.0 / 1e-3, 0.0) + rng.normal(0.0, 0.01, hits.shape)
    x, s = samples.mean(-1), samples.std(-1, ddof=1) / math.sqrt(spp)
    v, st = _verdict(x, s, 1.0, spp)
    assert st["pixel_skew"] > stability.PIXEL_SKEW_LIMIT
    assert v["pixel_test"] != "applied" and v["verdict"] in ("ok", "heavy-tail?")


# ----------------------------------------------------------------------------- injected faults
class FakeRender:
    """wavlight.render_full with faults: scale the image of one strategy, raise, or return NaN."""

    def __init__(self, scale=None, pixel=None, raises=(), nans=()):
        self.scale, self.pixel, self.raises, self.nans = scale or {}, pixel or {}, raises, nans

    def __call__(self, scene, spp=None, strategy=None, **kw):
        if strategy in self.raises:
            raise RuntimeError("kernel exploded\nsecond line")
        r = wavlight.render_full(scene, spp=spp, strategy=strategy, **kw)
        image = r.image.copy()
        image *= self.scale.get(strategy, 1.0)
        if strategy in self.pixel:
            image[3, 4] *= self.pixel[strategy]
        if strategy in self.nans:
            image[0, 0, 1] = np.nan
        return wavlight.RenderResult(image, r.stderr, r.stats)


def test_a_biased_fake_strategy_is_flagged(tmp_path):
    fake = FakeRender(scale={"cosine": 1.03}, pixel={"light": 2.0})
    res = stability.run_stability(tmp_path, cases=["overcast_lambert", "tiny_1x1"], strategies=["cosine", "light", "mis"],
                                  render=fake, **QUICK)
    v = {(c["case"], c["strategy"]): c for c in res["cells"]}
    for case in ("overcast_lambert", "tiny_1x1"):
        assert v[case, "cosine"]["verdict"] == "biased?", v[case, "cosine"]       # 3% everywhere
        assert v[case, "light"]["verdict"] == "biased?", v[case, "light"]         # one pixel twice too bright
        assert v[case, "light"]["pixels_over"] >= 1
        assert v[case, "mis"]["verdict"] == "ok"


def test_exceptions_and_nan_are_recorded_not_raised(tmp_path):
    fake = FakeRender(raises=("light",), nans=("cosine",))
    res = stability.run_stability(tmp_path, cases=["tiny_2x1"], strategies=["light", "cosine", "mis"], render=fake,
                                  **QUICK)
    v = {c["strategy"]: c for c in res["cells"]}
    assert v["light"]["verdict"] == "failed" and v["light"]["failure"] == "RuntimeError: kernel exploded; second line"
    assert v["cosine"]["verdict"] == "failed" and v["cosine"]["nan_values"] == QUICK["repetitions"]
    assert "NaN" in v["cosine"]["failure"]
    assert v["mis"]["verdict"] == "ok"
    _no_nan((tmp_path / "stability.json").read_text())
    assert (tmp_path / "charts" / "stability.png").is_file()
    assert "kernel exploded" in stability.format_table(res)


def test_real_map_cases_run_offline_on_shipped_maps(tmp_path, monkeypatch):
    """The cases under real maps (sun_rooitou, black_by_lamps) read only maps that ship with
    wavlight: with an empty data folder and a mirror URL on a closed port (any download would
    fail), both run and are tested."""
    import socket

    with socket.socket() as sock:   # a port that was free a moment ago: nothing listens there
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    monkeypatch.setenv(DATA_ENV, str(tmp_path / "empty"))
    monkeypatch.setenv(URL_ENV, f"http://127.0.0.1:{port}")
    res = stability.run_stability(tmp_path / "out", cases=["sun_rooitou", "black_by_lamps"], strategies=["mis"],
                                  reference_spp=64, **QUICK)
    assert [ci["status"] for ci in res["cases"]] == ["ok", "ok"], [ci["note"] for ci in res["cases"]]
    assert res["cells_tested"] == 2 and not (tmp_path / "empty").exists()


def test_black_around_lamps_blackens_the_lamps_neighbours_and_the_bottom_band():
    """One lamp on the seam (column 0) of a 16 x 32 map of 1: its 8 neighbours, wrapping to the
    last column, become 0 and it stays; the bottom band (1/16 of 16 rows: 1 row) becomes 0;
    every other texel is unchanged."""
    pix = np.ones((16, 32, 3), np.float32)
    pix[5, 0] = 1e4
    out = stability.black_around_lamps(pix)
    expected = pix.copy()
    for r in (4, 5, 6):
        for c in (31, 0, 1):
            if (r, c) != (5, 0):
                expected[r, c] = 0.0
    expected[15] = 0.0
    np.testing.assert_array_equal(out, expected)


def test_bad_arguments_raise_wavlight_errors(tmp_path):
    with pytest.raises(wavlight.WavlightError, match="unknown case"):
        stability.run_stability(tmp_path, cases=["nope"])
    with pytest.raises(wavlight.WavlightError, match="unknown strategy"):
        stability.run_stability(tmp_path, strategies=["nope"])
    with pytest.raises(wavlight.WavlightError, match="at least 2"):
        stability.run_stability(tmp_path, spp=1)


def test_analytic_floor_formula():
    """floor_radiance: a constant map of 1 gives albedo (the furnace); the upper half only."""
    assert np.allclose(stability.floor_radiance(np.ones((4, 8, 3)), [0.5, 0.6, 0.7]), [0.5, 0.6, 0.7])
    assert np.allclose(stability.floor_radiance(np.ones((5, 3, 3)), [1, 1, 1]), 1.0)   # odd height
    lower = np.zeros((4, 8, 3))
    lower[2:] = 100.0
    assert np.all(stability.floor_radiance(lower, [1, 1, 1]) == 0)
    bad = np.ones((2, 2, 3))
    bad[0, 0] = [np.nan, np.inf, -1.0]
    assert np.allclose(stability.floor_radiance(bad, [1, 1, 1]), 0.5)   # that texel counts as 0


# ----------------------------------------------------------------------------- command line
def test_cli_runs_the_suite(tmp_path, monkeypatch):
    monkeypatch.setattr(stability, "CASES", {k: stability.CASES[k] for k in ("tiny_1x1",)})
    monkeypatch.setattr(stability, "DEFAULTS", dict(stability.DEFAULTS, size=(8, 8), spp=8, repetitions=2))
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["experiment", "--suite", "stability", "-o", str(out), "-q"])
    assert r.exit_code == 0, r.output
    assert "stability suite: 1 cases" in r.output and "tiny_1x1" in r.output
    assert (out / "stability.csv").is_file() and (out / "charts" / "stability.svg").is_file()


@pytest.mark.parametrize("args", [[], ["SPEC.toml", "--suite", "stability"]])
def test_cli_wants_spec_or_suite(tmp_path, args):
    args = [str(tmp_path / a) if a.endswith(".toml") else a for a in args]
    r = CliRunner().invoke(main, ["experiment", *args, "-o", str(tmp_path / "o")])
    assert r.exit_code == 2 and "either SPEC or --suite" in r.output
