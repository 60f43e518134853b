"""What a newcomer's install gives: ``python -m wavlight``, the licence and citation files
consistent with pyproject.toml and the README, the project's links, and the charts' matplotlib as
an extra that an experiment names in one line when it is missing."""
from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from click.testing import CliRunner

import wavlight
from wavlight.cli.main import main
from wavlight.errors import WavlightError

REPO = Path(__file__).resolve().parent.parent
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]


def test_python_dash_m_runs_the_command_line():
    p = subprocess.run([sys.executable, "-m", "wavlight", "--version"], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip().endswith(wavlight.__version__), p.stdout
    p = subprocess.run([sys.executable, "-m", "wavlight", "render", "--help"], capture_output=True, text=True,
                       timeout=120)
    assert p.returncode == 0 and "--spp" in p.stdout, p.stderr


def test_the_licence_is_the_one_pyproject_declares():
    text = (REPO / "LICENSE").read_text()
    assert PYPROJECT["license"] == "MIT" and "LICENSE" in PYPROJECT["license-files"]
    assert text.startswith("MIT License") and "Copyright (c) the wavlight authors" in text
    assert "THE SOFTWARE IS PROVIDED \"AS IS\"" in text


def test_the_citation_file_names_the_software_and_the_paper_it_implements():
    yaml = pytest.importorskip("yaml")
    cff = yaml.safe_load((REPO / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software"
    for key in ("message", "title", "authors"):   # what CFF 1.2 requires
        assert cff[key], key
    assert cff["license"] == PYPROJECT["license"] and cff["version"] == wavlight.__version__
    assert cff["repository-code"] == PYPROJECT["urls"]["Source"]
    paper = re.search(r'Chen & Gao, "([^"]+)"', " ".join((REPO / "README.md").read_text().split())).group(1)
    ref = next(r for r in cff["references"] if r["title"] == paper)   # the README's title
    assert [a["family-names"] for a in ref["authors"]] == ["Chen", "Gao"]
    for r in cff["references"]:
        assert r["type"] and r["title"] and r["authors"]


def test_the_project_links_point_at_the_repository_and_its_docs():
    urls = PYPROJECT["urls"]
    home = "https://github.com/wavlight/wavlight"
    assert urls["Source"] == home and urls["Issues"] == f"{home}/issues"
    folder = urls["Documentation"].removeprefix(f"{home}/tree/main/")
    assert (REPO / folder).is_dir() and (REPO / folder / "cli.md").is_file()
    assert any(c.startswith("Programming Language :: Python :: 3.") for c in PYPROJECT["classifiers"])


def test_matplotlib_is_an_extra_that_the_test_extra_includes():
    assert not any(d.startswith("matplotlib") for d in PYPROJECT["dependencies"])
    extras = PYPROJECT["optional-dependencies"]
    assert any(d.startswith("matplotlib") for d in extras["experiments"])
    assert "wavlight[experiments]" in extras["test"]
    assert any(d.startswith("tqdm") for d in PYPROJECT["dependencies"])


def test_an_experiment_without_matplotlib_is_one_line_naming_the_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)   # as if not installed: its import fails
    with pytest.raises(WavlightError, match=r"pip install 'wavlight\[experiments\]'"):
        wavlight.evaluation.run_experiment(REPO / "experiments" / "example.toml", tmp_path / "lib")
    for args in (["experiment", str(REPO / "experiments" / "example.toml"), "-o", str(tmp_path / "a")],
                 ["experiment", "--suite", "stability", "-o", str(tmp_path / "b")]):
        r = CliRunner().invoke(main, args)
        lines = [line for line in r.stderr.splitlines() if line.strip()]
        assert r.exit_code == 2 and len(lines) == 1, r.output
        assert lines[0].startswith("Error: ") and "'experiments' extra" in lines[0], lines
    assert sorted(p.name for p in tmp_path.iterdir()) == []   # no work, no folder
