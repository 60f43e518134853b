"""The relit frames' unbiased estimator as an experiment strategy (``id = "relight"``): each
scene baked once into DIR/bakes/, the bake amortized over ``frames`` frames in every run's
setup seconds, reused on resume, and its runs measured against the same reference as ``mis``."""
from __future__ import annotations

import json

import numpy as np
import pytest

from wavlight.errors import WavlightError
from wavlight.evaluation import experiment, run_experiment
from wavlight.evaluation.spec import load_spec

from scenes_util import scene_dict, toml_text

SCENE = scene_dict(
    render={"width": 16, "height": 12, "spp": 1},
    camera={"eye": [0.0, 1.0, 3.0], "target": [0.0, 0.4, 0.0], "fov_y": 40.0},
    environment={"procedural": "sky"},
    materials={"glossy": {"type": "ggx", "albedo": [0.8, 0.7, 0.6], "roughness": 0.3}},
    objects=[{"shape": "sphere", "subdivisions": 2, "radius": 0.5, "center": [0.0, 0.5, 0.0], "material": "glossy"},
             {"shape": "quad", "size": 4.0}])


def spec_text(relight='bake_spp = 4\nlevels = 4\nframes = 10\n', budgets="spp = [2, 8]\nrepetitions = 2\n"):
    return ('[experiment]\nname = "rl"\nthreads = 2\npilot_spp = 1\n[reference]\nspp = 64\n'
            '[[scenes]]\npath = "sc.toml"\n[[strategies]]\nid = "mis"\n'
            f'[[strategies]]\nid = "relight"\n{relight}[budgets]\n{budgets}')


def write(folder, text):
    (folder / "sc.toml").write_text(toml_text(SCENE))
    (folder / "e.toml").write_text(text)
    return folder / "e.toml"


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    folder = tmp_path_factory.mktemp("relight-exp")
    spec = write(folder, spec_text())
    return spec, folder / "out", run_experiment(spec, folder / "out")


def test_relight_runs_sit_beside_mis(finished):
    spec, out, results = finished
    rows = [r for r in results["runs"] if r["strategy"] == "relight"]
    assert len(rows) == 4 and all(np.isfinite(r["relmse"]) for r in rows)
    bake = json.loads((out / "bakes" / "sc" / "relight.json").read_text())
    assert (out / bake["file"]).is_file() and bake["bake_seconds"] > 0
    for r in rows:   # the bake, amortized over the 10 frames it serves, is each run's setup
        assert r["setup_seconds"] == pytest.approx(bake["bake_seconds"] / 10, abs=1e-4)
        assert r["total_seconds"] == pytest.approx(r["setup_seconds"] + r["render_seconds"], abs=1e-3)
    groups = {(g["strategy"], g["spp"]): g for g in results["groups"]}
    assert set(groups) >= {("relight", 2), ("relight", 8), ("mis", 2), ("mis", 8)}


def test_relight_error_falls_with_spp_as_an_unbiased_estimate(finished):
    """relMSE of an unbiased estimate is variance / spp plus the reference's own noise: from
    2 to 8 spp it must fall, by no less than half of the factor 4, within two standard errors of
    the difference (the means of two repetitions each: the estimator's rare large samples, where
    the product misses a light the defensive BSDF mixture finds, make them vary)."""
    _, _, results = finished
    groups = {(g["strategy"], g["spp"]): g for g in results["groups"]}
    lo, hi = groups["relight", 8], groups["relight", 2]
    se = np.hypot(lo["relmse_sd"], 0.5 * hi["relmse_sd"]) / np.sqrt(2.0)
    assert lo["relmse"] < 0.5 * hi["relmse"] + 2.0 * se


def test_resume_reuses_the_bake(finished, monkeypatch):
    spec, out, _ = finished

    def no_bake(*a, **k):
        raise AssertionError("baked again")

    monkeypatch.setattr("wavlight.relight.bake.bake", no_bake)
    again = run_experiment(spec, out)
    assert again["rendered"] == 0 and again["reused"] == 8


def test_a_time_budget_fits_relight_from_its_pilot(tmp_path):
    spec = write(tmp_path, spec_text(budgets="seconds = [0.5]\nrepetitions = 1\n"))
    results = run_experiment(spec, tmp_path / "out")
    rows = [r for r in results["runs"] if r["strategy"] == "relight"]
    assert len(rows) == 1 and rows[0]["spp"] >= 1
    assert (tmp_path / "out" / "pilot" / "sc" / "relight.json").is_file()


def test_a_budget_past_the_unbiased_frames_bound_is_capped_there(tmp_path):
    """A pilot whose cost per spp is next to nothing (the unbiased frame's setup dominating its
    short pilots) asks for more spp than the relit frame takes: the budget is capped at the
    frame's bound (FRAME["spp"]), not at a scene's, with a warning."""
    from wavlight.relight.settings import FRAME

    spec = load_spec(write(tmp_path, spec_text(budgets="seconds = [0.5]\nrepetitions = 1\n")))
    relight = next(st for st in spec.strategies if st.id == "relight")
    other = next(st for st in spec.strategies if st.id != "relight")
    most = experiment.most_spp(relight)
    assert most == FRAME["spp"].hi < experiment.most_spp(other)
    pilot = {"setup_seconds": 0.0, "render_a": 0.0, "render_b": 1e-9}
    with pytest.warns(UserWarning, match=f"capped at the most a render takes, {most} spp"):
        assert experiment._Runner.spp_for(pilot, 0.5, "here", most) == most


@pytest.mark.parametrize("keys, named", [
    ("bake_spp = 0\n", "[[strategies]][1].bake_spp"),
    ("bake_spp = 65\n", "[[strategies]][1].bake_spp"),
    ("levels = 9\n", "[[strategies]][1].levels"),
    ("frames = 1.5\n", "[[strategies]][1].frames"),
    ("wavelet_levels = 4\n", "[[strategies]][1].wavelet_levels"),
    ("colour = 1\n", "[[strategies]][1].colour"),
])
def test_bad_relight_keys_are_one_line(tmp_path, keys, named):
    spec = write(tmp_path, spec_text(relight=keys))
    with pytest.raises(WavlightError, match=named.replace("[", r"\[").replace("]", r"\]").replace(".", r"\.")):
        load_spec(spec)


def test_relight_keys_do_not_apply_elsewhere(tmp_path):
    text = spec_text().replace('id = "mis"\n', 'id = "mis"\nframes = 10\n')
    with pytest.raises(WavlightError, match=r"\[\[strategies\]\]\[0\]\.frames: unknown key"):
        load_spec(write(tmp_path, text))


def test_the_bakes_folder_is_the_experiments_own(tmp_path):
    (tmp_path / "out" / "bakes").mkdir(parents=True)
    spec = write(tmp_path, spec_text())
    (tmp_path / "e.toml").write_text(spec_text().replace('path = "sc.toml"', 'path = "out/bakes/sc.toml"'))
    (tmp_path / "out" / "bakes" / "sc.toml").write_text(toml_text(SCENE))
    with pytest.raises(WavlightError, match="bakes/ is written by the experiment"):
        experiment.run_experiment(spec, tmp_path / "out")
