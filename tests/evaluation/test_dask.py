"""Parallel runs: the same tiny experiment (default scene at 8x8, mis and wavelet, spp [1, 2],
2 seeds, a 16-spp reference) in this process, in 2 spawned processes (``workers=2``) and on a
dask.distributed LocalCluster (skipped without dask) gives identical per-run images and metrics."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from wavlight.cli.main import main
from wavlight.evaluation import experiment
from wavlight.envmap import read_image

REPO = Path(__file__).resolve().parents[2]
DEFAULT_SCENE = (REPO / "scenes" / "default.toml").as_posix()

SPEC = f"""
[experiment]
name = "par"
size = [8, 8]
threads = 1

[reference]
spp = 16

[[scenes]]
path = "{DEFAULT_SCENE}"

[[strategies]]
id = "mis"

[[strategies]]
id = "wavelet"
wavelet_levels = 4

[budgets]
spp = [1, 2]
repetitions = 2
"""

METRICS = ("scene", "strategy", "budget", "spp", "seed", "mse", "relmse", "max_error", "max_rel_error", "image")


@pytest.fixture(scope="module")
def local(tmp_path_factory):
    folder = tmp_path_factory.mktemp("par")
    spec = folder / "par.toml"
    spec.write_text(SPEC)
    return spec, folder / "local", experiment.run_experiment(spec, folder / "local")


def assert_same(a_out, a, b_out, b):
    assert len(a["runs"]) == len(b["runs"]) == 8
    assert b["rendered"] == 8 and b["reused"] == 0
    for ra, rb in zip(a["runs"], b["runs"]):
        assert {k: ra[k] for k in METRICS} == {k: rb[k] for k in METRICS}
        assert np.array_equal(read_image(str(Path(a_out) / ra["image"])), read_image(str(Path(b_out) / rb["image"])))
    for ga, gb in zip(a["groups"], b["groups"]):
        for k in ("relmse", "mse", "variance", "bias", "bias_se"):
            assert ga[k] == gb[k], k
    assert json.loads((Path(b_out) / "results.json").read_text())["runs"] == b["runs"]


@pytest.mark.slow
def test_two_worker_processes_equal_local(local, tmp_path):
    spec, out, res = local
    r = CliRunner().invoke(main, ["experiment", str(spec), "-o", str(tmp_path / "w2"), "-q", "--workers", "2"])
    assert r.exit_code == 0, r.output
    par = json.loads((tmp_path / "w2" / "results.json").read_text())
    assert par["executor"] == "2 processes" and res["executor"] == "in-process"
    assert_same(out, res, tmp_path / "w2", par)


@pytest.mark.slow
def test_dask_local_cluster_equals_local(local, tmp_path):
    distributed = pytest.importorskip("distributed")
    spec, out, res = local
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as c:
        par = experiment.run_experiment(spec, tmp_path / "dask", dask_address=c.scheduler_address)
        assert par["executor"] == f"dask {c.scheduler_address}"
        assert_same(out, res, tmp_path / "dask", par)
        # resumed through dask: nothing is submitted again
        again = experiment.run_experiment(spec, tmp_path / "dask", dask_address=c.scheduler_address)
        assert again["rendered"] == 0 and again["reused"] == 8


@pytest.mark.slow
def test_workers_and_dask_are_exclusive(local, tmp_path):
    spec = local[0]
    r = CliRunner().invoke(main, ["experiment", str(spec), "-o", str(tmp_path / "x"), "--workers", "2",
                                  "--dask", "tcp://127.0.0.1:1"])
    assert r.exit_code == 2 and "not both" in r.stderr
    r = CliRunner().invoke(main, ["experiment", str(spec), "-o", str(tmp_path / "x"), "--workers", "0"])
    assert r.exit_code == 2


@pytest.mark.parametrize("address", ["notaurl", "tcp://host-without-port", "127.0.0.1:8786"])
def test_bad_dask_address_is_one_line_before_any_work(local, tmp_path, address):
    """A malformed scheduler address is refused before references or pilots are rendered."""
    pytest.importorskip("distributed")
    spec = local[0]
    r = CliRunner().invoke(main, ["experiment", str(spec), "-o", str(tmp_path / "x"), "--dask", address])
    assert r.exit_code == 2, r.output
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "expected a scheduler address tcp://HOST:PORT" in lines[0], r.stderr
    assert not (tmp_path / "x").exists()
