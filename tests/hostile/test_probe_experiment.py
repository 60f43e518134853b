"""Experiment files, resume records and experiment folders, as a hostile user would give them.

A bad experiment key is one line naming the file and the key, found before anything
is rendered or allocated (10^8 repetitions must not grow memory before the refusal); resume
records that hold valid JSON of the wrong type, or the right hash with wrong fields, are
treated like a damaged image: one warning naming the file, and that run (reference, pilot) is
made again; an output folder that would overwrite an input is refused; temporaries a killed
experiment left are removed by the next run; a budget that is capped, or a reference that is
black, is never silent.

One tiny experiment (a sphere under the sky at 8 x 6, mis, spp [1], 1 repetition, a 4-spp
reference, a 0.05 s budget) runs once per module; the cases copy its folder and damage it.
Charts are switched off in the resume cases (they are not under test and cost a second each).
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import wavlight
from wavlight.cli.main import main
from wavlight.errors import WavlightError
from wavlight.evaluation import experiment
from scenes_util import run_limited, write_raw_image

SCENE = """[render]
width = 8
height = 6
spp = 1
[camera]
eye = [0.0, 1.0, 3.0]
target = [0.0, 0.4, 0.0]
[environment]
procedural = "sky"
[[objects]]
shape = "sphere"
subdivisions = 1
"""


def spec_text(experiment_keys="size = [8, 6]\nthreads = 1\npilot_spp = 1\n", budgets="spp = [1]\nseconds = [0.05]\n"
              "repetitions = 1\n", scenes='[[scenes]]\npath = "sc.toml"\n', strategies='[[strategies]]\nid = "mis"\n',
              reference="spp = 4\n"):
    return (f"[experiment]\n{experiment_keys}\n[reference]\n{reference}\n{scenes}\n{strategies}\n"
            f"[budgets]\n{budgets}\n")


def write_spec(folder, text=None, name="e.toml"):
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "sc.toml").write_text(SCENE)
    (folder / name).write_text(spec_text() if text is None else text)
    return folder / name


@pytest.fixture(scope="module")
def done(tmp_path_factory):
    """A finished tiny experiment: (spec path, its output folder)."""
    folder = tmp_path_factory.mktemp("probe-exp")
    spec = write_spec(folder)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        experiment.run_experiment(spec, folder / "out")
    return spec, folder / "out"


@pytest.fixture
def no_charts(monkeypatch):
    monkeypatch.setattr(experiment, "error_charts", lambda *a, **k: [])
    monkeypatch.setattr(experiment, "error_maps", lambda *a, **k: [])


def rerun(spec, out):
    """run_experiment again: (results, [warning messages])."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = experiment.run_experiment(spec, out)
    return res, [str(w.message) for w in caught if "cannot be met" not in str(w.message)]


def copy(done, tmp_path):
    spec, out = done
    shutil.copytree(out, tmp_path / "out")
    return spec, tmp_path / "out"


# ============================================================================= resume records
RECORDS = {"run": "runs/sc/mis/spp1/0.json", "reference": "reference/sc.json", "pilot": "pilot/sc/mis.json"}
DAMAGE = {   # what the record file holds instead
    "a list": "[1, 2, 3]",
    "a number": "42",
    "a string": '"done"',
    "null": "null",
    "not JSON": "{ half a record",
    "JSON nested 100 000 deep": "[" * 100_000 + "]" * 100_000,
    "its hash, wrong fields": None,   # the record with its right hash and every number as a string
}


def _damage(path, how):
    if DAMAGE[how] is not None:
        path.write_text(DAMAGE[how])
        return
    rec = json.loads(path.read_text())
    path.write_text(json.dumps({k: (str(v) if k != "hash" else v) for k, v in rec.items()}))


@pytest.mark.slow
@pytest.mark.parametrize("how", list(DAMAGE))
@pytest.mark.parametrize("record", list(RECORDS))
def test_a_damaged_resume_record_is_redone(done, tmp_path, no_charts, record, how):
    """A resume record that is not a usable JSON object (a list, a number, a string, JSON too
    deep to parse, or its own hash with fields of the wrong kind) warns once, naming the file,
    and the run / reference / pilot is made again; the experiment completes, with no
    AttributeError or KeyError traceback."""
    spec, out = copy(done, tmp_path)
    _damage(out / RECORDS[record], how)
    res, warned = rerun(spec, out)
    if how != "null":   # (null is read as "no record": nothing to warn about)
        assert any(RECORDS[record].split("/")[-1] in w for w in warned), warned
    # (a pilot measured again may give the time budget another spp, hence a new run)
    assert res["rendered"] in ((1,) if record == "run" else (0,) if record == "reference" else (0, 1))
    assert len(res["runs"]) == 2
    json.loads((out / RECORDS[record]).read_text())["hash"]   # rewritten whole


def test_a_run_record_naming_another_image_is_redone(done, tmp_path, no_charts):
    """A run record with the right hash whose image field points elsewhere (../../x.exr) is not
    trusted: it is warned about and rendered again, and the metrics read the run's own image."""
    spec, out = copy(done, tmp_path)
    path = out / RECORDS["run"]
    rec = json.loads(path.read_text())
    rec["image"] = "../../elsewhere.exr"
    path.write_text(json.dumps(rec))
    res, warned = rerun(spec, out)
    assert res["rendered"] == 1 and any("spp1/0" in w and "not this run's" in w for w in warned), warned


def test_a_damaged_reference_image_is_rendered_again(done, tmp_path, no_charts):
    """A reference image that is truncated (its record intact) is treated like a damaged run
    image: one warning, and it is rendered again; the experiment does not stop on "cannot read
    pixels"."""
    spec, out = copy(done, tmp_path)
    ref = out / "reference" / "sc.exr"
    ref.write_bytes(ref.read_bytes()[:200])
    res, warned = rerun(spec, out)
    assert any("reference" in w for w in warned), warned
    assert res["reference"]["sc"]["corrected"]


def test_a_pilot_with_an_impossible_fit_is_measured_again(done, tmp_path, no_charts):
    """A pilot record (right hash) whose fit says 0 s per spp would give an infinite spp (a
    division by zero): it is warned about and measured again."""
    spec, out = copy(done, tmp_path)
    path = out / RECORDS["pilot"]
    rec = json.loads(path.read_text())
    rec["render_b"] = 0.0
    path.write_text(json.dumps(rec))
    res, warned = rerun(spec, out)
    assert any("mis.json" in w for w in warned), warned


# ============================================================================= temporaries
def test_temporaries_of_a_killed_experiment_are_removed(done, tmp_path, no_charts):
    """`.wavlight-*` temporaries that a killed experiment left (in charts/, runs/..., the
    folder itself) are removed by the next run; a live process's are kept."""
    spec, out = copy(done, tmp_path)
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    host = wavlight.atomic.host_id()
    stale = [out / "charts" / f".wavlight-{dead}.{host}-sc-spp.png.a1b2c3d4.png",
             out / "runs" / "sc" / "mis" / "spp1" / f".wavlight-{dead}.{host}-0.exr.q1w2e3r4.exr",
             out / f".wavlight-{dead}.{host}-results.json.z9x8c7v6.tmp"]
    live = out / "charts" / f".wavlight-{os.getpid()}.{host}-sc-time.png.live0001.png"
    for p in stale + [live]:
        p.write_bytes(b"half")
    rerun(spec, out)
    assert not [p for p in stale if p.exists()] and live.exists()


# ============================================================================= refused before any work
def _never_render(monkeypatch):
    def fail(*a, **k):
        raise AssertionError("rendered before the bad key was found")
    monkeypatch.setattr(experiment, "render_full", fail)


def test_a_bad_reference_of_a_later_scene_is_found_before_any_render(tmp_path, monkeypatch):
    """A second scene's reference file of the wrong size is refused before the first scene's
    reference, pilots and runs are rendered: the spec is checked whole before any work, so a
    bad late value never costs the renders before it (nor, with 10^8 repetitions, 2 GB of run
    records)."""
    spec = write_spec(tmp_path)
    write_raw_image(tmp_path / "ref.exr", np.ones((7, 8, 3), np.float32))
    text = spec_text(scenes='[[scenes]]\npath = "sc.toml"\n[[scenes]]\npath = "sc.toml"\nname = "two"\n'
                     'reference = "ref.exr"\n')
    spec.write_text(text)
    _never_render(monkeypatch)
    with pytest.raises(WavlightError, match=r"ref\.exr: reference image is 8x7"):
        experiment.run_experiment(spec, tmp_path / "out")


@pytest.mark.parametrize("keys, names", [
    ("size = [8, 6]\nthreads = 1\npilot_spp = 1000000\n", ("e.toml", "[experiment].pilot_spp")),
    ("size = [8, 6]\nthreads = 1000000\n", ("e.toml", "[experiment].threads")),
])
def test_experiment_keys_out_of_range_name_file_and_key(tmp_path, monkeypatch, keys, names):
    """[experiment] keys that render_full would refuse late (pilot_spp whose 4 x exceeds the spp
    cap, threads beyond 4096) are refused first, naming the file and the key, not with render_full's
    "spp must be between 1 and 1000000, got 4000000" after the reference's render."""
    spec = write_spec(tmp_path, spec_text(experiment_keys=keys))
    _never_render(monkeypatch)
    with pytest.raises(WavlightError) as e:
        experiment.run_experiment(spec, tmp_path / "out")
    assert all(n in str(e.value) for n in names), str(e.value)


def test_1e8_repetitions_are_refused_before_memory_grows(tmp_path):
    """10^8 repetitions are refused in one line naming [budgets].repetitions, quickly and in
    little memory: the child is limited to 4 GB of address space, and a run list of 10^8 entries
    would pass 2 GB before anything was refused."""
    spec = write_spec(tmp_path, spec_text(budgets="spp = [1]\nrepetitions = 100000000\n",
                                          reference="spp = 4\nseed = 1000000000\n"))
    code = ("import sys, wavlight.evaluation as ev\n"
            "try:\n    ev.run_experiment(sys.argv[1], sys.argv[2])\n"
            "except Exception as e:\n    print(type(e).__name__, e)\n")
    p, seconds = run_limited(code, spec, tmp_path / "out", gigabytes=4, timeout=30, what="not refused")
    assert p.stdout.startswith("WavlightError") and "[budgets].repetitions" in p.stdout, p.stdout + p.stderr[-1500:]
    assert seconds < 30


@pytest.mark.parametrize("workers", [0, 65, 10 ** 6, 2.5, True])
def test_workers_beyond_the_cap_are_refused(tmp_path, workers):
    """workers has an upper bound (MAX_WORKERS = 64 local processes, each a
    Python with OpenCL of ~0.3-0.4 GB); outside 1..64 (or not an integer) a one-line error."""
    spec = write_spec(tmp_path)
    with pytest.raises(WavlightError, match="workers must be an integer in 1..64"):
        experiment.run_experiment(spec, tmp_path / "out", workers=workers)


def test_cli_workers_beyond_the_cap_are_refused(tmp_path):
    """`--workers 1000000` is one line naming --workers and the cap
    (wavlight.evaluation.experiment.MAX_WORKERS), exit 2, and no output folder is made."""
    spec = write_spec(tmp_path)
    r = CliRunner().invoke(main, ["experiment", str(spec), "-o", str(tmp_path / "out"), "-q", "--workers", "1000000"])
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert r.exit_code == 2 and len(lines) == 1 and "--workers" in lines[0] and "64" in lines[0], r.output
    assert not (tmp_path / "out").exists()


def test_a_size_that_cannot_fit_in_memory_is_refused(tmp_path, monkeypatch):
    """An experiment whose runs need more memory than the machine has
    (here: 36 bytes per pixel x 16384^2 against 1 GB available) is refused before rendering,
    saying how much it needs."""
    spec = write_spec(tmp_path, spec_text(experiment_keys="size = [16384, 16384]\nthreads = 1\n"))
    monkeypatch.setattr(wavlight.imageio, "available_bytes", lambda: 1 << 30)
    _never_render(monkeypatch)
    with pytest.raises(WavlightError, match=r"16384x16384 render needs about 10\.1 GB"):
        experiment.run_experiment(spec, tmp_path / "out")


# ============================================================================= silent oddities
def test_a_black_reference_file_is_refused(tmp_path, monkeypatch):
    """An all-black reference file is refused as an all-black map is (relative errors against it
    are undefined), before anything is rendered."""
    spec = write_spec(tmp_path)
    write_raw_image(tmp_path / "black.exr", np.zeros((6, 8, 3), np.float32))
    spec.write_text(spec_text(scenes='[[scenes]]\npath = "sc.toml"\nreference = "black.exr"\n'))
    _never_render(monkeypatch)
    with pytest.raises(WavlightError, match=r"black\.exr: reference image is black everywhere"):
        experiment.run_experiment(spec, tmp_path / "out")


def test_a_time_budget_past_the_spp_cap_says_so(tmp_path, no_charts, monkeypatch):
    """A time budget whose pilot fit needs more than the spp cap is capped with a warning naming
    the budget, never silently. The pilot is faked: 1e-9 s per spp."""
    spec = write_spec(tmp_path, spec_text(budgets="seconds = [10.0]\nrepetitions = 1\n"))
    monkeypatch.setattr(experiment._Runner, "pilot", lambda self, s, st: {
        "setup_seconds": 0.0, "render_a": 0.0, "render_b": 1e-9})
    calls = []
    monkeypatch.setattr(experiment, "render_full", lambda scene, spp=None, **kw: calls.append(spp) or
                        wavlight.render_full(scene, spp=min(spp, 2), **kw))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            experiment.run_experiment(spec, tmp_path / "out")
        except Exception:   # noqa: BLE001 (the faked spp makes the run's record odd; only the warning counts)
            pass
    msgs = [str(w.message) for w in caught]
    assert any("[budgets].seconds" in m and "capped" in m and "1000000" in m for m in msgs), msgs


# ============================================================================= outputs that are inputs
def test_out_dir_holding_the_spec_as_spec_toml_is_refused(tmp_path):
    """`-o DIR` where DIR/spec.toml is the experiment file itself is refused (the run
    writes DIR/spec.toml)."""
    folder = tmp_path / "d"
    spec = write_spec(folder, name="spec.toml")
    with pytest.raises(WavlightError, match=r"spec\.toml: is an input of this run"):
        experiment.run_experiment(spec, folder)


def test_a_reference_inside_the_folders_the_run_writes_is_refused(tmp_path):
    """A reference file under DIR/reference/ (or a scene's map under DIR/runs/) is refused:
    those folders are the experiment's own."""
    spec = write_spec(tmp_path)
    (tmp_path / "out" / "reference").mkdir(parents=True)
    write_raw_image(tmp_path / "out" / "reference" / "sc.exr", np.ones((6, 8, 3), np.float32))
    spec.write_text(spec_text(scenes='[[scenes]]\npath = "sc.toml"\nreference = "out/reference/sc.exr"\n'))
    with pytest.raises(WavlightError, match=r"reference/ is written by the experiment"):
        experiment.run_experiment(spec, tmp_path / "out")
    (tmp_path / "out" / "runs").mkdir()
    write_raw_image(tmp_path / "out" / "runs" / "map.exr", np.ones((4, 8, 3), np.float32))
    (tmp_path / "sc.toml").write_text(SCENE.replace('procedural = "sky"', 'file = "out/runs/map.exr"'))
    spec.write_text(spec_text())
    with pytest.raises(WavlightError, match=r"runs/ is written by the experiment"):
        experiment.run_experiment(spec, tmp_path / "out")


# ============================================================================= spec values
SPECS = {   # case: (spec text, names the error must hold)
    "nested 1000 deep": (spec_text() + "x = " + "[" * 1000 + "]" * 1000 + "\n", ("e.toml",)),
    "name with a slash": (spec_text(experiment_keys='name = "../up"\n'), ("e.toml", "[experiment].name")),
    "size of zero": (spec_text(experiment_keys="size = [0, 6]\n"), ("e.toml", "[experiment].size")),
    "threads zero": (spec_text(experiment_keys="threads = 0\n"), ("e.toml", "[experiment].threads")),
    "pilot_spp a string": (spec_text(experiment_keys='pilot_spp = "4"\n'), ("e.toml", "[experiment].pilot_spp")),
    "unknown experiment key": (spec_text(experiment_keys="colour = 1\n"), ("e.toml", "[experiment].colour")),
    "spp empty": (spec_text(budgets="spp = []\n"), ("e.toml", "[budgets].spp")),
    "spp 10^7": (spec_text(budgets="spp = [10000000]\n"), ("e.toml", "[budgets].spp")),
    "seconds nan": (spec_text(budgets="seconds = [nan]\n"), ("e.toml", "[budgets].seconds")),
    "seconds negative": (spec_text(budgets="seconds = [-1.0]\n"), ("e.toml", "[budgets].seconds")),
    "repetitions zero": (spec_text(budgets="spp = [1]\nrepetitions = 0\n"), ("e.toml", "[budgets].repetitions")),
    "reference spp 1": (spec_text(reference="spp = 1\n"), ("e.toml", "[reference].spp")),
    "reference strategy unknown": (spec_text(reference='strategy = "path"\n'), ("e.toml", "[reference].strategy")),
    "strategy unknown": (spec_text(strategies='[[strategies]]\nid = "path"\n'), ("e.toml", "[[strategies]][0].id")),
    "option for another strategy": (spec_text(strategies='[[strategies]]\nid = "mis"\nwavelet_levels = 3\n'),
                                    ("e.toml", "[[strategies]][0].wavelet_levels")),
    "scene path missing": (spec_text(scenes='[[scenes]]\npath = "none.toml"\n'), ("e.toml", "[[scenes]][0].path")),
    "a 1 MB list": (spec_text(budgets="spp = [" + ", ".join(["0"] * 200_000) + "]\n"), ("e.toml", "[budgets].spp")),
}


@pytest.mark.parametrize("case", list(SPECS))
def test_bad_spec_value_is_one_line(tmp_path, case):
    """A bad spec value is exit 2 and one line naming the file and the key, under 400
    characters, and no output folder: a value nested 1000 deep is caught by spec.load_spec
    (no RecursionError), and a 1 MB list is shown cut short (errors.shown), not echoed whole."""
    text, names = SPECS[case]
    spec = write_spec(tmp_path, text)
    r = CliRunner().invoke(main, ["experiment", str(spec), "-o", str(tmp_path / "out"), "-q"])
    lines = [line for line in r.stderr.splitlines() if line.strip() and not line.startswith("warning:")]
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exception
    assert r.exit_code == 2 and len(lines) == 1 and lines[0].startswith("Error:"), r.output[-2000:]
    assert all(n in lines[0] for n in names) and len(lines[0]) < 400, lines[0][:500]
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("kind", ["fifo", "symlink loop"])
def test_spec_or_reference_of_another_kind(tmp_path, kind):
    """A spec path, or a reference file, that is a FIFO or a link loop is one line saying so, at
    once (wavlight.errors.file_problem names the kind; opening a FIFO would wait for a writer, and
    os.path.isfile alone would call either "no such file")."""
    from test_probe_files import KINDS

    make, words = KINDS[kind]
    spec = write_spec(tmp_path)
    make(tmp_path / "ref.exr")
    spec.write_text(spec_text(scenes='[[scenes]]\npath = "sc.toml"\nreference = "ref.exr"\n'))
    make(tmp_path / "fifo.toml")
    for target in (spec, tmp_path / "fifo.toml"):
        r = CliRunner().invoke(main, ["experiment", str(target), "-o", str(tmp_path / "out"), "-q"])
        assert r.exit_code == 2 and words in r.stderr and "no such file" not in r.stderr, r.output
