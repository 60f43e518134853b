"""Batch experiments end to end: a tiny experiment (default scene at 8x6, mis and wavelet,
spp [1, 2] and a 0.05 s time budget, 2 seeds, a 16-spp reference) runs once per module into a
temporary folder; the tests read its outputs, recompute its metrics from the saved images,
resume it (renders counted through a wrapped ``wavlight.render_full``) and feed the command
line malformed experiment files (exit code 2, one line naming the file and the key).
"""
from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import wavlight
from wavlight.cli.main import main
from wavlight.evaluation import experiment, records
from wavlight.strategies import APPLIES
from wavlight.evaluation import metrics
from wavlight.envmap import read_image
from scenes_util import write_raw_image

REPO = Path(__file__).resolve().parents[2]
DEFAULT_SCENE = (REPO / "scenes" / "default.toml").as_posix()

TINY = f"""
[experiment]
name = "tiny"
size = [8, 6]
pilot_spp = 1

[reference]
strategy = "mis"
spp = 16

[[scenes]]
path = "{DEFAULT_SCENE}"

[[strategies]]
id = "mis"

[[strategies]]
id = "wavelet"
label = "wav"
wavelet_levels = 4

[budgets]
spp = [1, 2]
seconds = [0.05]
repetitions = 2
"""


class Counter:
    """Wraps wavlight.render_full; records (spp, width, height) of every call."""

    def __init__(self, real):
        self.real, self.calls = real, []

    def __call__(self, scene, spp=None, *args, **kw):
        self.calls.append((spp, kw.get("width"), kw.get("height"), kw.get("seed")))
        return self.real(scene, spp, *args, **kw)

    @property
    def timed(self):
        """Calls other than the 8x8 warm-ups."""
        return [c for c in self.calls if (c[1], c[2]) != (experiment.WARMUP_SIZE, experiment.WARMUP_SIZE)]


def run_counted(spec, out, **kw):
    counter = Counter(wavlight.render_full)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(experiment, "render_full", counter)
        results = experiment.run_experiment(spec, out, **kw)
    return results, counter


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    folder = tmp_path_factory.mktemp("experiment")
    spec = folder / "tiny.toml"
    spec.write_text(TINY)
    events = []
    results, counter = run_counted(spec, folder / "out", progress=lambda *a: events.append(a))
    return {"spec": spec, "out": folder / "out", "results": results, "counter": counter, "events": events}


def copy_of(tiny, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(tiny["out"], out)
    return out


# ----------------------------------------------------------------------------- outputs
@pytest.mark.slow
def test_outputs_exist_and_are_not_empty(tiny):
    out = tiny["out"]
    for name in ("results.csv", "results.json", "runs.csv", "spec.toml", "reference/default.exr",
                 "reference/default.stderr.exr", "reference/default.json"):
        assert (out / name).stat().st_size > 0, name
    for stem in ("default-spp", "default-time", "error-maps"):
        png = (out / "charts" / f"{stem}.png").read_bytes()
        assert png.startswith(b"\x89PNG") and len(png) > 5000, stem
        svg = (out / "charts" / f"{stem}.svg").read_text()
        assert "<svg" in svg and len(svg) > 5000, stem
    assert (out / "spec.toml").read_text() == TINY
    assert not list(out.rglob(".wavlight-*")), "temporary files left behind"


def test_csv_and_json_hold_every_group_and_run(tiny):
    res = json.loads((tiny["out"] / "results.json").read_text())
    assert res["rendered"] == 12 and res["reused"] == 0
    assert len(res["runs"]) == 2 * 3 * 2 and len(res["groups"]) == 2 * 3
    assert res["budgets"] == ["spp1", "spp2", "0.05s"]
    rows = list(csv.DictReader((tiny["out"] / "results.csv").open()))
    assert len(rows) == 6 and set(experiment.GROUP_COLUMNS) == set(rows[0])
    assert {(r["strategy"], r["budget"]) for r in rows} == {(s, b) for s in ("mis", "wav")
                                                           for b in ("spp1", "spp2", "0.05s")}
    runs = list(csv.DictReader((tiny["out"] / "runs.csv").open()))
    assert len(runs) == 12
    for g in res["groups"]:
        for key in ("mse", "relmse", "relmse_sd", "variance", "rel_variance", "bias", "bias_se", "max_error",
                    "setup_seconds", "render_seconds", "total_seconds"):
            assert isinstance(g[key], float) and np.isfinite(g[key]), (key, g)
    for item in res["runs"] + res["groups"]:
        assert isinstance(item["budget_exceeded"], bool)
        if item["budget_kind"] == "spp":
            assert item["budget_exceeded"] is False
    # the returned dict is what results.json holds
    assert json.loads(json.dumps(tiny["results"])) == res


def test_runs_record_timings_and_settings(tiny):
    out = tiny["out"]
    for r in tiny["results"]["runs"]:
        rec = json.loads((out / "runs" / r["scene"] / r["strategy"] / r["budget"] / f"{r['seed']}.json").read_text())
        assert rec["total_seconds"] == pytest.approx(rec["setup_seconds"] + rec["render_seconds"], abs=2e-4)
        assert rec["setup_seconds"] > 0 and rec["render_seconds"] > 0
        assert (rec["width"], rec["height"]) == (8, 6)
        assert rec["stats"]["strategy"] == {"mis": "mis", "wav": "wavelet"}[r["strategy"]]
        if r["strategy"] == "wav":
            assert rec["options"] == {"wavelet_levels": 4}
        assert len(rec["hash"]) == 16
    # the time budget's spp comes from the cached pilot fit
    for label in ("mis", "wav"):
        pilot = json.loads((out / "pilot" / "default" / f"{label}.json").read_text())
        spp = experiment._Runner.spp_for(pilot, 0.05)
        assert all(r["spp"] == spp for r in tiny["results"]["runs"]
                   if r["strategy"] == label and r["budget"] == "0.05s")


def test_every_render_is_counted_once(tiny):
    timed = tiny["counter"].timed
    runs = [c for c in timed if c[3] in (0, 1)]
    assert len(runs) == 12                                 # 2 strategies x 3 budgets x 2 seeds
    assert sum(1 for c in timed if c[0] == 16 and c[3] == 1_000_003) == 1   # the reference
    events = tiny["events"]
    total = events[0][1]
    assert [e[0] for e in events] == list(range(1, total + 1))
    assert total == 1 + 2 + 12                             # reference, 2 pilots, 12 runs


def test_metrics_agree_with_the_saved_images(tiny):
    out, res = tiny["out"], tiny["results"]
    ref = read_image(str(out / "reference" / "default.exr"))
    se = read_image(str(out / "reference" / "default.stderr.exr"))
    assert ref.shape == (6, 8, 3) and np.all(se >= 0) and np.any(se > 0)
    assert res["reference"]["default"]["corrected"] is True
    for r in res["runs"]:
        x = read_image(str(out / r["image"]))
        assert r["relmse"] == pytest.approx(metrics.relmse(x, ref, se), rel=1e-12)
        assert r["mse"] == pytest.approx(metrics.mse(x, ref, se), rel=1e-12)
        assert r["max_error"] == pytest.approx(float(np.abs(x.astype(float) - ref).max()), rel=1e-12)
    for g in res["groups"]:
        mine = [r for r in res["runs"] if (r["strategy"], r["budget"]) == (g["strategy"], g["budget"])]
        imgs = np.stack([read_image(str(out / r["image"])) for r in mine])
        assert g["relmse"] == pytest.approx(np.mean([r["relmse"] for r in mine]), rel=1e-12)
        assert g["relmse_min"] <= g["relmse"] <= g["relmse_max"]
        assert g["variance"] == pytest.approx(float(np.mean(np.var(imgs.astype(float), axis=0, ddof=1))), rel=1e-12)
        # bias and its SE on the channel mean (correlated channels); the reference's SE: mean of the channels'
        b, b_se = metrics.bias(*(np.mean(a.astype(float), axis=-1, keepdims=True) for a in (imgs, ref, se)))
        assert (g["bias"], g["bias_se"]) == (pytest.approx(b, rel=1e-12), pytest.approx(b_se, rel=1e-12))
        assert g["bias"] == pytest.approx(metrics.bias(imgs, ref, se)[0], rel=1e-9, abs=1e-12)
        assert g["relmse_x_seconds"] == pytest.approx(g["relmse"] * g["total_seconds"])


def test_bias_se_accounts_for_correlated_channels():
    """Channel noise perfectly correlated (as grey pixels give): pooling the 3 channels as
    independent values makes the SE sqrt(3) too small; the SE of the channel mean is the true
    standard deviation of the bias estimate, for the runs' spread and the reference's alike."""
    rng = np.random.default_rng(7)
    reps, h, w = 4, 64, 64
    ref = np.broadcast_to(rng.uniform(0.5, 1.5, (h, w, 1)), (h, w, 3)).copy()
    noise = rng.normal(0.0, 1.0, (reps, h, w, 1))
    images = ref + noise                                   # the same noise in R, G and B
    b, se = experiment._bias(images, ref, None)
    pooled = metrics.bias(images, ref, None)
    assert b == pytest.approx(pooled[0], rel=1e-12)
    assert se == pytest.approx(np.sqrt(3) * pooled[1], rel=1e-9)
    assert se == pytest.approx(1 / np.sqrt(reps * h * w), rel=0.05)   # sd of the mean of R*H*W unit normals
    # the reference's own SE: as correlated, the same sqrt(3)
    ref_se = np.full((h, w, 3), 0.5)
    only_ref = experiment._bias(np.broadcast_to(ref, (reps, h, w, 3)), ref, ref_se)[1]
    assert only_ref == pytest.approx(np.sqrt(3) * metrics.bias(np.broadcast_to(ref, (reps, h, w, 3)), ref,
                                                               ref_se)[1], rel=1e-9)
    assert only_ref == pytest.approx(0.5 / np.sqrt(h * w), rel=1e-9)
    # honest: over many experiments, bias / SE has a standard deviation of about 1
    z = []
    for _ in range(300):
        b, se = experiment._bias(ref[:8, :8] + rng.normal(0.0, 1.0, (reps, 8, 8, 1)), ref[:8, :8], None)
        z.append(b / se)
    assert 0.85 < np.std(z) < 1.15, np.std(z)


def test_runs_are_reproducible_from_their_seed(tiny):
    r = next(r for r in tiny["results"]["runs"] if r["strategy"] == "mis" and r["budget"] == "spp2")
    scene = wavlight.load_scene(DEFAULT_SCENE)
    again = wavlight.render_full(scene, spp=2, strategy="mis", width=8, height=6, seed=r["seed"])
    assert np.array_equal(again.image, read_image(str(tiny["out"] / r["image"])))


def test_equal_time_error_maps_use_the_time_budget(tiny):
    assert tiny["results"]["equal_time"] == {"default": {"mis": "0.05s", "wav": "0.05s"}}


def test_summary_table(tiny):
    text = experiment.format_summary(tiny["results"])
    lines = text.splitlines()
    assert lines[0].startswith("experiment tiny: 12 runs (12 rendered, 0 reused)")
    header = next(i for i, line in enumerate(lines) if line.startswith("strategy"))
    assert "relMSE" in lines[header] and "bias" in lines[header]
    body = lines[header + 1: header + 7]
    assert [line.split()[:2] for line in body] == [["mis", "spp1"], ["mis", "spp2"], ["mis", "0.05s"],
                                                  ["wav", "spp1"], ["wav", "spp2"], ["wav", "0.05s"]]


def test_summary_notes_a_peers_approximated_materials(tiny):
    """A Mitsuba peer that approximates a material (phong as ggx) carries a bias no spp removes:
    the summary says so under the scene's table."""
    import copy

    results = copy.deepcopy(tiny["results"])
    run = results["runs"][0]
    run["stats"] = {**run.get("stats", {}), "approximated_materials": ["plastic"]}
    text = experiment.format_summary(results)
    assert f"note: {run['strategy']} renders material 'plastic' with an approximation" in text
    assert "approximation" not in experiment.format_summary(tiny["results"])


# ----------------------------------------------------------------------------- resume
def test_resume_renders_nothing_when_finished(tiny, tmp_path):
    out = copy_of(tiny, tmp_path)
    results, counter = run_counted(tiny["spec"], out)
    assert counter.calls == []
    assert results["rendered"] == 0 and results["reused"] == 12
    assert [g["relmse"] for g in results["groups"]] == [g["relmse"] for g in tiny["results"]["groups"]]


def test_resume_renders_only_what_is_missing_or_changed(tiny, tmp_path):
    out = copy_of(tiny, tmp_path)
    (out / "runs" / "default" / "wav" / "spp2" / "1.json").unlink()        # an unfinished run
    rec_path = out / "runs" / "default" / "mis" / "spp1" / "0.json"         # a run from other settings
    rec = json.loads(rec_path.read_text())
    rec["hash"] = "0" * 16
    rec_path.write_text(json.dumps(rec))
    results, counter = run_counted(tiny["spec"], out)
    assert sorted(counter.timed) == [(1, 8, 6, 0), (2, 8, 6, 1)]
    assert results["rendered"] == 2 and results["reused"] == 10


def test_resume_renders_a_broken_run_image_again(tiny, tmp_path):
    """A run whose record is intact but whose image is truncated, not an image, of another size,
    has a NaN pixel or is gone is rendered again with a one-line warning (it aborted the whole
    experiment with OpenImageIO's error); the new images are the old ones (seeded renders)."""
    out = copy_of(tiny, tmp_path)
    runs = out / "runs" / "default"
    truncated = runs / "mis" / "spp1" / "0.exr"
    truncated.write_bytes(truncated.read_bytes()[:300])
    (runs / "mis" / "spp2" / "1.exr").write_bytes(b"not an image")
    write_raw_image(runs / "wav" / "spp1" / "0.exr", np.ones((4, 4, 3), np.float32))
    nan = read_image(str(runs / "wav" / "spp2" / "1.exr")).copy()
    nan[1, 2, 0] = np.nan
    write_raw_image(runs / "wav" / "spp2" / "1.exr", nan)
    (runs / "mis" / "0.05s" / "0.exr").unlink()
    with pytest.warns(UserWarning) as caught:
        results, counter = run_counted(tiny["spec"], out)
    again = sorted(str(w.message) for w in caught if "again" in str(w.message))
    assert len(again) == 5 and all("\n" not in m for m in again), again
    for part, problem in [("mis/spp1/seed 0", "cannot be read"), ("mis/spp2/seed 1", "cannot be read"),
                          ("wav/spp1/seed 0", "has shape (4, 4, 3), not (6, 8, 3)"),
                          ("wav/spp2/seed 1", "has 1 NaN or Inf pixel(s)"), ("mis/0.05s/seed 0", "is missing")]:
        assert any(f"the run's image {problem}: rendering default/{part} again" in m for m in again), (part, again)
    assert sorted((c[1], c[2], c[3]) for c in counter.timed) == [(8, 6, 0)] * 3 + [(8, 6, 1)] * 2
    assert results["rendered"] == 5 and results["reused"] == 7
    assert [g["relmse"] for g in results["groups"]] == [g["relmse"] for g in tiny["results"]["groups"]]


def test_a_new_budget_adds_only_its_runs(tiny, tmp_path):
    out = copy_of(tiny, tmp_path)
    spec = tmp_path / "more.toml"
    spec.write_text(TINY.replace("spp = [1, 2]", "spp = [1, 2, 3]"))
    results, counter = run_counted(spec, out)
    assert sorted(c[:3] for c in counter.timed) == [(3, 8, 6)] * 4
    assert results["rendered"] == 4 and len(results["groups"]) == 8


@pytest.mark.slow
def test_no_resume_renders_everything_again(tmp_path):
    spec = tmp_path / "one.toml"
    spec.write_text(TINY.replace("spp = [1, 2]\nseconds = [0.05]\nrepetitions = 2", "spp = [1]\nrepetitions = 1")
                    .replace('[[strategies]]\nid = "wavelet"\nlabel = "wav"\nwavelet_levels = 4\n', ""))
    first, counter = run_counted(spec, tmp_path / "out")
    assert first["rendered"] == 1 and len(counter.timed) == 2          # the reference and the run
    counter = Counter(wavlight.render_full)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(experiment, "render_full", counter)
        r = CliRunner().invoke(main, ["experiment", str(spec), "-o", str(tmp_path / "out"), "-q", "--no-resume"])
    assert r.exit_code == 0, r.output
    assert "(1 rendered, 0 reused)" in r.stdout
    assert len(counter.timed) == 2


# ----------------------------------------------------------------------------- reference files
def test_reference_from_a_file(tiny, tmp_path):
    ref = tiny["out"] / "reference" / "default.exr"
    spec = tmp_path / "fileref.toml"
    spec.write_text(f"""
[experiment]
size = [8, 6]
[[scenes]]
path = "{DEFAULT_SCENE}"
reference = "{ref.as_posix()}"
[[strategies]]
id = "mis"
[budgets]
spp = [2]
repetitions = 1
""")
    results = experiment.run_experiment(spec, tmp_path / "out")
    assert results["reference"]["default"]["corrected"] is False
    run = results["runs"][0]
    x = read_image(str(tmp_path / "out" / run["image"]))
    assert run["relmse"] == pytest.approx(metrics.relmse(x, read_image(str(ref))), rel=1e-12)
    g = results["groups"][0]
    assert g["variance"] is None and g["bias_se"] is None and g["relmse_sd"] is None
    assert "metrics not corrected" in experiment.format_summary(results)
    # the wrong size is one clear error
    spec.write_text(spec.read_text().replace("size = [8, 6]", "size = [8, 8]"))
    with pytest.raises(wavlight.WavlightError, match=r"default\.exr: reference image is 8x6"):
        experiment.run_experiment(spec, tmp_path / "out2")
    # so is a reference with NaN pixels (every metric would be NaN)
    bad = read_image(str(ref)).copy()
    bad[2, 3] = np.nan
    write_raw_image(str(tmp_path / "nan.exr"), bad)   # (save_image refuses NaN)
    spec.write_text(spec.read_text().replace("size = [8, 8]", "size = [8, 6]").replace(ref.as_posix(),
                                                                                        (tmp_path / "nan.exr").as_posix()))
    with pytest.raises(wavlight.WavlightError, match=r"nan\.exr: reference image has 1 NaN or Inf pixel"):
        experiment.run_experiment(spec, tmp_path / "out3")


@pytest.mark.parametrize("kwargs, message", [(dict(out_dir=None), "out_dir"), (dict(progress=5), "progress")])
def test_run_experiment_checks_its_arguments_first(tmp_path, kwargs, message):
    spec = tmp_path / "s.toml"
    spec.write_text(TINY)
    args = {"out_dir": tmp_path / "out", **kwargs}
    with pytest.raises(wavlight.WavlightError, match=message):
        experiment.run_experiment(spec, **args)
    assert not (tmp_path / "out").exists() and not (tmp_path / "None").exists()


def test_results_json_has_no_nan_tokens(tmp_path):
    """JSON has no NaN: a metric that is not a number is written as null."""
    records.write_json(tmp_path / "r.json", {"a": [1.0, float("nan")], "b": {"c": float("inf")}, "d": "x"})
    assert json.loads((tmp_path / "r.json").read_text()) == {"a": [1.0, None], "b": {"c": None}, "d": "x"}


# ----------------------------------------------------------------------------- the command line
@pytest.mark.slow
def test_cli_prints_the_summary(tiny, tmp_path):
    out = copy_of(tiny, tmp_path)
    r = CliRunner().invoke(main, ["experiment", str(tiny["spec"]), "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert "experiment tiny: 12 runs (0 rendered, 12 reused)" in r.stdout
    assert "wrote " in r.stderr
    r = CliRunner().invoke(main, ["experiment", str(tiny["spec"]), "-o", str(out), "--quiet"])
    # --quiet: no progress and no "wrote" lines; warnings stay (TINY's 0.05 s budget is below
    # what 1 spp takes here, which the experiment says once per group)
    assert r.exit_code == 0, r.output
    assert all(line.startswith("warning: ") for line in r.stderr.splitlines()), r.stderr


BAD = [
    ("[experiment]\nnam = 1\n", "[experiment].nam: unknown key"),
    ("[[scenes]]\npath = 'x.toml'\n", "[[scenes]][0].path: no such file"),
    ("[[strategies]]\nid = 'mis'\n[budgets]\nspp = [1]\n", "[[scenes]]: at least one"),
    (f"[[scenes]]\npath = '{DEFAULT_SCENE}'\n[budgets]\nspp = [1]\n", "[[strategies]]: at least one"),
    (f"[[scenes]]\npath = '{DEFAULT_SCENE}'\n[[strategies]]\nid = 'magic'\n[budgets]\nspp = [1]\n",
     "[[strategies]][0].id: unknown strategy 'magic'"),
    (f"[[scenes]]\npath = '{DEFAULT_SCENE}'\n[[strategies]]\nid = 'mis'\n[budgets]\nspp = [0, 4]\n",
     "[budgets].spp: must be a non-empty list of integers >= 1"),
    (f"[[scenes]]\npath = '{DEFAULT_SCENE}'\n[[strategies]]\nid = 'mis'\n[budgets]\nrepetitions = 2\n",
     "[budgets].spp: give spp"),
    (f"[[scenes]]\npath = '{DEFAULT_SCENE}'\n[[strategies]]\nid = 'mis'\n[budgets]\nseconds = [-1]\n",
     "[budgets].seconds: must be a non-empty list of numbers > 0"),
    (f"[[scenes]]\npath = '{DEFAULT_SCENE}'\n[[strategies]]\nid = 'mis'\n[[strategies]]\nid = 'mis'\n"
     "[budgets]\nspp = [1]\n", "[[strategies]][1].label: label 'mis' is used twice"),
    (f"[reference]\nspp = 1\n[[scenes]]\npath = '{DEFAULT_SCENE}'\n[[strategies]]\nid = 'mis'\n"
     "[budgets]\nspp = [1]\n", "[reference].spp: must be an integer >= 2"),
    (f"[experiment]\nsize = [8]\n[[scenes]]\npath = '{DEFAULT_SCENE}'\n", "[experiment].size: must be [width, height]"),
    (f"[[scenes]]\npath = '{DEFAULT_SCENE}'\n[[strategies]]\nid = 'mis'\nsampler = 'sobol'\n[budgets]\nspp = [1]\n",
     "[[strategies]][0].sampler: must be one of independent | stratified, got 'sobol'"),
    ("[budgets\nspp = [1]\n", "malformed TOML"),
    (f"[[scenes]]\npath = '{DEFAULT_SCENE}'\n[[strategies]]\nid = 'mis'\nwavelet_levels = 4\n[budgets]\nspp = [1]\n",
     "[[strategies]][0].wavelet_levels: does not apply to 'mis' (only to wavelet)"),
    (f"[reference]\nseed = 1\n[[scenes]]\npath = '{DEFAULT_SCENE}'\n[[strategies]]\nid = 'mis'\n"
     "[budgets]\nspp = [1]\nrepetitions = 3\n", "[budgets].repetitions: the runs' seeds 0..2 include"),
    (f"[[scenes]]\npath = '{DEFAULT_SCENE}'\nreference = '{DEFAULT_SCENE}'\n[[strategies]]\nid = 'mis'\n"
     "[budgets]\nspp = [1]\n", "[[scenes]][0].reference: cannot read"),
    ("[runs]\n", "runs: unknown table"),
]


@pytest.mark.parametrize("text,message", BAD, ids=[m for _, m in BAD])
def test_cli_bad_spec_is_one_line_and_exit_2(tmp_path, text, message):
    spec = tmp_path / "bad.toml"
    spec.write_text(text)
    r = CliRunner().invoke(main, ["experiment", str(spec), "-o", str(tmp_path / "out")])
    assert r.exit_code == 2, r.output
    assert r.exception is None or isinstance(r.exception, SystemExit)
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith(f"Error: {spec}: ") and message in lines[0], lines[0]
    assert r.stdout == ""
    assert not (tmp_path / "out").exists()


def test_cli_missing_spec_and_output_is_a_file(tmp_path):
    r = CliRunner().invoke(main, ["experiment", str(tmp_path / "none.toml"), "-o", str(tmp_path / "o")])
    assert r.exit_code == 2 and "none.toml: no such file" in r.stderr
    spec = tmp_path / "ok.toml"
    spec.write_text(TINY)
    (tmp_path / "file").write_text("x")
    r = CliRunner().invoke(main, ["experiment", str(spec), "-o", str(tmp_path / "file")])
    assert r.exit_code == 2 and "exists and is not a folder" in r.stderr, r.output


def test_example_experiment_is_valid():
    spec = experiment.load_spec(REPO / "experiments" / "example.toml")
    assert [s.name for s in spec.scenes] == ["default", "spot_ggx"]
    assert [s.label for s in spec.strategies] == ["mis", "wavelet", "light", "bsdf"]
    assert spec.size == (64, 48) and spec.repetitions == 2


# ----------------------------------------------------------------------------- Mitsuba peers
SMOOTH_SCENE = """
[render]
width = 8
height = 8
[camera]
eye = [0.0, 0.0, 4.0]
target = [0.0, 0.0, 0.0]
fov_y = 30.0
[environment]
file = "smooth.exr"
[[objects]]
shape = "sphere"
center = [0.0, 0.0, 0.0]
radius = 1.0
material = "m"
[materials.m]
type = "lambert"
albedo = [0.5, 0.5, 0.5]
"""


def test_mitsuba_peer_runs_against_the_wavlight_reference(tmp_path):
    from wavlight.evaluation import peers
    if not peers.available():
        pytest.skip("Mitsuba 3 (llvm_ad_rgb) not available")
    v = np.linspace(0.2, 1.0, 8, dtype=np.float32)[:, None, None]          # a smooth sky: bright at the top
    wavlight.save_image(str(tmp_path / "smooth.exr"), np.broadcast_to(v, (8, 16, 3)).copy())
    (tmp_path / "smooth.toml").write_text(SMOOTH_SCENE)
    spec = tmp_path / "peer.toml"
    spec.write_text("""
[reference]
spp = 256
[[scenes]]
path = "smooth.toml"
[[strategies]]
id = "mis"
[[strategies]]
id = "mitsuba:mis"
[budgets]
spp = [64]
seconds = [0.3]
repetitions = 1
""")
    results = experiment.run_experiment(spec, tmp_path / "out")
    pilot = json.loads((tmp_path / "out" / "pilot" / "smooth" / "mitsuba-mis.json").read_text())
    timed = next(r for r in results["runs"] if r["strategy"] == "mitsuba-mis" and r["budget"] == "0.3s")
    assert timed["spp"] == experiment._Runner.spp_for(pilot, 0.3)
    by = {r["strategy"]: r for r in results["runs"] if r["budget"] == "spp64"}
    assert set(by) == {"mis", "mitsuba-mis"}
    peer = by["mitsuba-mis"]
    assert peer["strategy_id"] == "mitsuba:mis" and peer["spp"] == 64
    assert peer["setup_seconds"] > 0 and peer["render_seconds"] > 0
    assert np.isfinite(peer["relmse"]) and peer["relmse"] < 0.01, peer["relmse"]
    assert "mitsuba-mis" in experiment.format_summary(results)
    rec = json.loads((tmp_path / "out" / "runs" / "smooth" / "mitsuba-mis" / "spp64" / "0.json").read_text())
    assert rec["stats"]["strategy"] == "mitsuba:mis"


def test_mitsuba_strategy_errors(tmp_path, monkeypatch):
    from wavlight.evaluation import peers
    spec = tmp_path / "bad.toml"
    base = f"[[scenes]]\npath = '{DEFAULT_SCENE}'\n[budgets]\nspp = [1]\n[[strategies]]\n"
    spec.write_text(base + "id = 'mitsuba:wavelet'\n")
    with pytest.raises(wavlight.WavlightError, match=r"\[\[strategies\]\]\[0\]\.id: unknown Mitsuba strategy"):
        experiment.load_spec(spec)
    monkeypatch.setattr(peers, "available", lambda: False)
    spec.write_text(base + "id = 'mitsuba:mis'\n")
    r = CliRunner().invoke(main, ["experiment", str(spec), "-o", str(tmp_path / "out")])
    assert r.exit_code == 2
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "[[strategies]][0].id: 'mitsuba:mis' needs Mitsuba 3" in lines[0], r.stderr


def test_strategy_sampler_option_reaches_the_renderer(tmp_path):
    """``sampler = "stratified"`` in a [[strategies]] table becomes a render option."""
    spec = tmp_path / "s.toml"
    spec.write_text(f"[[scenes]]\npath = '{DEFAULT_SCENE}'\n[[strategies]]\nid = 'mis'\nlabel = 'mis-strat'\n"
                    "sampler = 'stratified'\n[budgets]\nspp = [1]\n")
    st = experiment.load_spec(spec).strategies[0]
    assert st.options == {"sampler": "stratified"}
    scene = wavlight.load_scene(DEFAULT_SCENE)
    r = experiment._render(scene, st.id, st.options, 2, 8, 6, 0, 1)
    assert r.stats["sampler"] == "stratified"


# ----------------------------------------------------------------------------- strategy options
def strategy_spec(tmp_path, lines):
    spec = tmp_path / "opts.toml"
    spec.write_text(f"[[scenes]]\npath = '{DEFAULT_SCENE}'\n[budgets]\nspp = [1]\n[[strategies]]\n" + lines)
    return spec


@pytest.mark.parametrize("sid, option, value", [("mis", "wavelet_levels", 4), ("light", "wavelet_levels", 4),
                                                ("bsdf", "light_levels", 6), ("uniform", "light_levels", 6),
                                                ("structured", "light_levels", 6)])
def test_an_option_the_strategy_does_not_take_is_refused(tmp_path, sid, option, value):
    """It was accepted and ignored (a wavelet-only option given to mis): one keyed error instead."""
    spec = strategy_spec(tmp_path, f"id = '{sid}'\n{option} = {value}\n")
    with pytest.raises(wavlight.WavlightError) as e:
        experiment.load_spec(spec)
    assert str(e.value).startswith(f"{spec}: [[strategies]][0].{option}: does not apply to '{sid}' (only to ")
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("sid, lines, options", [
    ("wavelet", "wavelet_levels = 4\nlight_levels = 6\n", {"wavelet_levels": 4, "light_levels": 6}),
    ("sir", "light_levels = 6\n", {"light_levels": 6}), ("mis_comp", "light_levels = 6\n", {"light_levels": 6}),
    ("light", "light_levels = 6\n", {"light_levels": 6}), ("uniform", "sampler = 'stratified'\n",
                                                           {"sampler": "stratified"})])
def test_options_the_strategy_takes_are_kept(tmp_path, sid, lines, options):
    assert experiment.load_spec(strategy_spec(tmp_path, f"id = '{sid}'\n" + lines)).strategies[0].options == options


@pytest.mark.slow
def test_option_table_matches_the_renderer():
    """APPLIES (derived from the strategies' own option declarations) says which strategies an
    option reaches: exactly those whose render reports a light tree of that depth (light_levels),
    product levels (wavelet_levels), candidates or slots."""
    for sid in wavlight.STRATEGIES:
        r = wavlight.render_full(DEFAULT_SCENE, spp=1, strategy=sid, width=4, height=4, seed=0,
                                 light_levels=2, wavelet_levels=1, wavelet_candidates=3, wavelet_slots=4)
        assert (r.stats.get("light_tree") == "4x4") == (sid in APPLIES["light_levels"]), sid
        levels = r.stats.get("product_levels")
        assert (levels is not None and set(levels.values()) == {1}) == \
            (sid in APPLIES["wavelet_levels"]), sid
        assert (r.stats.get("wavelet_candidates") == 3) == \
            (sid in APPLIES["wavelet_candidates"]), sid
        assert (r.stats.get("wavelet_slots") == 4) == (sid in APPLIES["wavelet_slots"]), sid
    assert set(APPLIES["sampler"]) == set(wavlight.STRATEGIES)


# ----------------------------------------------------------------------------- time budgets
def test_a_time_budget_below_one_spp_is_warned_about_and_recorded(tmp_path):
    """A budget that even 1 spp exceeds gave 1 spp silently: now one warning naming the strategy,
    the budget and the time 1 spp took, and budget_exceeded in results.json."""
    spec = tmp_path / "short.toml"
    spec.write_text(TINY.replace("spp = [1, 2]\nseconds = [0.05]\nrepetitions = 2", "seconds = [0.0001]\nrepetitions = 2")
                    .replace('[[strategies]]\nid = "wavelet"\nlabel = "wav"\nwavelet_levels = 4\n', ""))
    with pytest.warns(UserWarning) as caught:
        results = experiment.run_experiment(spec, tmp_path / "out")
    msgs = [str(w.message) for w in caught if "time budget" in str(w.message)]
    assert len(msgs) == 1, msgs
    g = results["groups"][0]
    assert msgs[0] == (f"default/mis: the time budget of 0.0001 s cannot be met even at 1 spp: 1 spp took "
                       f"{g['total_seconds']:.3g} s (setup {g['setup_seconds']:.3g} s)")
    assert g["spp"] == 1 and g["budget_exceeded"] is True
    assert [r["budget_exceeded"] for r in results["runs"]] == [True, True]
    saved = json.loads((tmp_path / "out" / "results.json").read_text())
    assert [r["budget_exceeded"] for r in saved["runs"]] == [True, True] and saved["groups"][0]["budget_exceeded"]
    # only a 1-spp run over its time budget: more spp over it is the pilot fit's noise, spp budgets have no time
    base = {"budget_kind": "seconds", "spp": 1, "total_seconds": 0.2, "target_seconds": 0.1}
    assert experiment._budget_exceeded(base)
    assert not experiment._budget_exceeded({**base, "total_seconds": 0.05})
    assert not experiment._budget_exceeded({**base, "spp": 2})
    assert not experiment._budget_exceeded({**base, "budget_kind": "spp", "target_seconds": None})


def _scene_with_map(tmp_path, pixels):
    write_raw_image(tmp_path / "map.exr", pixels)
    scene = tmp_path / "scene.toml"
    scene.write_text('[environment]\nfile = "map.exr"\n[camera]\neye = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\n'
                     '[[objects]]\nshape = "sphere"\nmaterial = "m"\n[materials.m]\ntype = "lambert"\n')
    spec = tmp_path / "spec.toml"
    spec.write_text(f"[experiment]\nsize = [8, 6]\n[reference]\nspp = 4\n[[scenes]]\npath = '{scene.as_posix()}'\n"
                    "[[strategies]]\nid = 'mis'\n[budgets]\nspp = [1]\n")
    return spec


def test_cli_all_black_environment_is_refused_as_by_render(tmp_path):
    spec = _scene_with_map(tmp_path, np.zeros((8, 16, 3), np.float32))
    r = CliRunner().invoke(main, ["experiment", str(spec), "-o", str(tmp_path / "out"), "-q"])
    assert r.exit_code == 2, r.output
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "scene.toml: [environment]: the environment is black everywhere" in lines[0], r.stderr
    assert not (tmp_path / "out").exists()


def test_cli_sanitised_map_finishes_then_exits_3(tmp_path):
    """Bad texels: one warning line, the experiment runs and writes its results, exit code 3."""
    px = np.ones((8, 16, 3), np.float32)
    px[2, 3], px[4, 5, 1] = np.nan, -1.0
    spec = _scene_with_map(tmp_path, px)
    r = CliRunner().invoke(main, ["experiment", str(spec), "-o", str(tmp_path / "out"), "-q"])
    assert r.exit_code == 3, r.output
    warns = [line for line in r.stderr.splitlines() if line.startswith("warning:")]
    assert len(warns) == 1 and "2 texel(s) with NaN, Inf or negative values" in warns[0], r.stderr
    assert not [line for line in r.stderr.splitlines() if line.startswith("Error")]
    assert (tmp_path / "out" / "results.json").is_file()
