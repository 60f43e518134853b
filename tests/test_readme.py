"""The README's commands run as written, on the data that ships (no ../shared, no network).

Every ``wavlight ...`` line of the README's Set-up, Rendering, Experiments and Relighting
blocks is run as a process from a scratch folder (input paths of the repository made absolute).
Commands that take minutes as written get flags appended that shrink them (click keeps an
option's last value): smaller images, fewer samples and frames. The rest is the README's text.
The example experiment runs as written (about a minute: slow); the stability suite's command runs
with the suite's sizes made small.
"""
from __future__ import annotations

import os
import re
import shlex
import signal
import subprocess
import sys
import urllib.request
from pathlib import Path

import pytest

from repo import REPO

WAVLIGHT = str(Path(sys.executable).with_name("wavlight"))
#: appended to a command of the README so that it finishes in seconds
SHRINK = {
    "render": ["--width", "32", "--height", "24", "--spp", "2"],
    "bake": ["--width", "32", "--height", "24", "--spp", "4", "--levels", "3", "--terms", "64"],
    "frame": [],
}


def readme_commands(section: str) -> list[list[str]]:
    """The ``wavlight`` command lines of the first bash block under the README heading `section`."""
    text = (REPO / "README.md").read_text()
    part = text.split(f"\n## {section}\n", 1)[1].split("\n## ", 1)[0]
    block = re.search(r"```bash\n(.*?)```", part, re.S).group(1)
    return [shlex.split(line) for line in block.splitlines() if line.startswith("wavlight ")]


def _absolute(args: list[str]) -> list[str]:
    """Input paths of the repository (scenes/..., experiments/...) made absolute."""
    return [str(REPO / a) if (REPO / a).is_file() and "/" in a else a for a in args]


def _shrunk(args: list[str]) -> list[str]:
    command = args[1]
    extra = list(SHRINK.get(command, []))
    if command == "frame":
        if "--turntable" in args:
            extra += ["--turntable", "3"]
        if "--spp" in args:
            extra += ["--spp", "2"]
    return _absolute(args) + extra


def _run(args, cwd, timeout=900):
    r = subprocess.run([WAVLIGHT, *args[1:]], capture_output=True, text=True, cwd=cwd, timeout=timeout,
                       env={k: v for k, v in os.environ.items() if k != "WAVLIGHT_DATA"})
    assert r.returncode == 0, f"{shlex.join(args)}\n{r.stderr}"
    assert "Traceback" not in r.stderr
    return r


def test_the_readme_has_its_commands():
    assert len(readme_commands("Set-up")) == 1
    assert readme_commands("Set-up")[0][:2] == ["wavlight", "render"]
    assert len(readme_commands("Rendering")) >= 3
    assert {c[1] for c in readme_commands("Relighting")} == {"bake", "frame", "view"}
    assert {c[1] for c in readme_commands("Experiments")} == {"experiment"}


@pytest.mark.slow
def test_setup_and_rendering_commands_run(tmp_path):
    """The set-up's render and every Rendering example write their images (no network, no
    data folder: the shipped scenes and maps)."""
    for args in readme_commands("Set-up") + readme_commands("Rendering"):
        _run(_shrunk(args), tmp_path)
        outputs = [args[i + 1] for i, a in enumerate(args) if a in ("-o", "--stderr-out")]
        for out in outputs:
            assert (tmp_path / out).is_file() and (tmp_path / out).stat().st_size > 0, (args, out)


@pytest.mark.slow
def test_relighting_commands_run(tmp_path):
    """bake, the frames (rotated, another map, a turntable, converged) and the viewer's page."""
    for args in readme_commands("Relighting"):
        args = _shrunk(args)
        if args[1] == "view":
            proc = subprocess.Popen([WAVLIGHT, *args[1:], "--no-browser"], cwd=tmp_path, stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True)
            try:
                url = proc.stdout.readline().strip()
                assert url.startswith("http://127.0.0.1:"), proc.stderr.read() if proc.poll() is not None else url
                with urllib.request.urlopen(url, timeout=60) as page:
                    assert page.status == 200 and b"<html" in page.read(4096).lower()
            finally:
                proc.send_signal(signal.SIGINT)
                proc.wait(timeout=60)
            continue
        _run(args, tmp_path)
        if "-o" in args:
            out = tmp_path / args[args.index("-o") + 1]
            assert out.exists(), args
            if out.is_dir():
                assert len(list(out.glob("frame-*.png"))) == 3


@pytest.mark.slow
def test_the_example_experiment_runs_as_written(tmp_path):
    """The example experiment (about a minute), as the README gives it."""
    args = next(a for a in readme_commands("Experiments") if "--suite" not in a)
    _run(_absolute(args), tmp_path, timeout=1800)
    assert (tmp_path / args[args.index("-o") + 1] / "results.json").is_file()


def test_the_stability_suite_command_runs(tmp_path, monkeypatch):
    """The README's stability suite command, in this process with the suite's sizes made small
    (its full size takes minutes; tests/evaluation/test_stability.py checks its verdicts)."""
    from click.testing import CliRunner

    from wavlight.cli.main import main
    from wavlight.evaluation import stability

    monkeypatch.setitem(stability.DEFAULTS, "size", (6, 6))
    monkeypatch.setitem(stability.DEFAULTS, "spp", 4)
    monkeypatch.setitem(stability.DEFAULTS, "repetitions", 2)
    monkeypatch.setitem(stability.DEFAULTS, "reference_spp", 16)
    args = next(a for a in readme_commands("Experiments") if "--suite" in a)
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(main, args[1:])
    assert r.exit_code == 0, r.output
    assert (tmp_path / args[args.index("-o") + 1] / "stability.json").is_file()


def test_the_exit_code_tables_name_every_code_a_command_exits_with():
    """0, 2, 3 and the signals' 130 and 143 (wavlight.cli.main), in the README's table and in
    docs/cli.md's."""
    import signal

    from wavlight.cli.main import INTERRUPTED_EXIT_CODE
    from wavlight.errors import SANITISED_EXIT_CODE

    codes = {"0", "2", str(SANITISED_EXIT_CODE), str(INTERRUPTED_EXIT_CODE), str(128 + signal.SIGTERM)}
    for doc in (REPO / "README.md", REPO / "docs" / "cli.md"):
        rows = [line.split("|")[1] for line in doc.read_text().splitlines()
                if line.startswith("| ") and line.split("|")[1].strip()[:1].isdigit()]
        listed = {code.strip() for row in rows for code in row.split(",")}
        assert codes <= listed, (doc.name, sorted(codes - listed))
