"""Signals at every stage, a full disk and concurrent writers.

Whenever `wavlight render` is interrupted (SIGINT, SIGTERM, SIGKILL) while it loads,
renders or writes, the output is either the previous file, untouched, or absent, never a
half-written image; SIGINT and SIGTERM leave no temporary behind, and the temporary a SIGKILL
must leave is removed by the next successful write into that folder; a full disk is one line
and leaves neither a partial file nor a temporary; writers that race on one output leave one
complete image and never remove each other's temporaries.

The stages are made deterministic: the child process is the real CLI, with the stage's
function (load_scene, render_full, OpenImageIO's writer) wrapped to print a marker and wait,
so that the signal arrives inside that stage. A small tmpfs (mount -t tmpfs, root only) is the
full disk; those cases are skipped where it cannot be mounted.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

import wavlight
from wavlight.envmap import read_image
from wavlight.errors import WavlightError

from test_cli import _command, no_temporaries, run_inproc, scene_text, write_scene

CHILD = r"""
import sys, time
stage, scene, out = sys.argv[1:4]
import OpenImageIO as oiio
import wavlight


def marked(fn):
    def wrapper(*a, **k):
        print("STAGE", flush=True)
        time.sleep(60)
        return fn(*a, **k)
    return wrapper


if stage == "load":
    wavlight.load_scene = marked(wavlight.load_scene)
elif stage == "render":
    wavlight.render_full = marked(wavlight.render_full)
else:   # write: the pixels have started to go to the temporary file
    real = oiio.ImageOutput.create

    class Slow:
        def __init__(self, inner):
            self.inner = inner

        def __getattr__(self, name):
            return getattr(self.inner, name)

        def write_image(self, *a):
            ok = self.inner.write_image(*a)
            marked(lambda: None)()
            return ok

    oiio.ImageOutput.create = staticmethod(lambda path: Slow(real(path)))
from wavlight.cli.main import main
sys.argv = ["wavlight", "render", scene, "-o", out, "-q"]
main()
"""

STAGES = [("load", signal.SIGTERM), ("render", signal.SIGINT), ("render", signal.SIGTERM),
          ("write", signal.SIGINT), ("write", signal.SIGTERM), ("write", signal.SIGKILL)]


def _interrupted(tmp_path, stage, sig):
    """Run the CLI child into tmp_path/o.png (which holds a previous image), send sig at the stage;
    (returncode, stderr, previous bytes)."""
    scene = write_scene(tmp_path, scene_text())
    out = tmp_path / "o.png"
    wavlight.save_image(str(out), np.full((6, 8, 3), 0.25, np.float32))
    previous = out.read_bytes()
    p = subprocess.Popen([sys.executable, "-c", CHILD, stage, str(scene), str(out)], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONWARNINGS": ""})
    try:
        line = p.stdout.readline()
        assert line.strip() == "STAGE", (line, p.stderr.read() if p.poll() is not None else "")
        p.send_signal(sig)
        _, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    return p.returncode, err, previous


@pytest.mark.slow
@pytest.mark.parametrize("stage, sig", STAGES, ids=[f"{s}-{g.name}" for s, g in STAGES])
def test_an_interrupted_render_leaves_the_previous_output(tmp_path, stage, sig):
    """Interrupted at any stage, the previous o.png is untouched (never half written); after
    SIGINT or SIGTERM no `.wavlight-*` temporary is left, the exit code is 130 or 143 and one line
    says why (a SIGTERM is turned into an orderly exit that removes the temporaries, where the
    default action would kill the process and leave them); after SIGKILL the one temporary left is removed by the next successful render
    into the folder."""
    code, err, previous = _interrupted(tmp_path, stage, sig)
    out = tmp_path / "o.png"
    assert out.read_bytes() == previous
    assert "Traceback" not in err, err
    if sig == signal.SIGKILL:
        assert code == -signal.SIGKILL
        assert len(no_temporaries(tmp_path)) == 1
        o = run_inproc("render", tmp_path / "scene.toml", "-o", tmp_path / "other.png", "-q")
        assert o.code == 0, o.describe()
        assert no_temporaries(tmp_path) == []
        return
    assert no_temporaries(tmp_path) == [], no_temporaries(tmp_path)
    # the shells' convention: 128 + the signal's number, and one line that says which
    assert code == 128 + sig, (code, err)
    assert err.strip().splitlines() == [f"Error: {'terminated' if sig == signal.SIGTERM else 'interrupted'} "
                                        f"({sig.name})"], err


@pytest.mark.slow
def test_a_killed_experiment_resumes_to_the_same_results(tmp_path):
    """An experiment killed (SIGKILL) after its first run resumes to the results of an
    uninterrupted run, and leaves no temporary after the resume."""
    from test_probe_experiment import write_spec, spec_text

    spec = write_spec(tmp_path, spec_text(budgets="spp = [1, 2]\nrepetitions = 2\n"))
    out = tmp_path / "out"
    code = "import sys, wavlight.evaluation as ev\nev.run_experiment(sys.argv[1], sys.argv[2])\n"
    p = subprocess.Popen([sys.executable, "-c", code, str(spec), str(out)], stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not list(out.glob("runs/*/*/*/*.json")):
            time.sleep(0.02)
        p.send_signal(signal.SIGKILL)
        p.wait(30)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    from wavlight.evaluation import experiment
    res = experiment.run_experiment(spec, out)
    assert res["reused"] >= 1 and res["reused"] + res["rendered"] == 4
    clean = experiment.run_experiment(spec, tmp_path / "clean")
    for a, b in zip(res["runs"], clean["runs"]):
        assert a["relmse"] == b["relmse"] and a["image"] == b["image"]
    assert not [p for p in out.rglob(".wavlight-*")]


def _children(pid: int) -> set:
    """The processes whose parent is ``pid`` (Linux: /proc)."""
    found = set()
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as fh:
                    fields = fh.read().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                found.add(int(entry))
    return found


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.slow
@pytest.mark.skipif(not os.path.isdir("/proc"), reason="finds the worker processes in /proc")
def test_the_workers_of_a_killed_experiment_end_with_it(tmp_path):
    """`experiment --workers 2` killed outright (SIGKILL: its pool cannot be shut down): its
    worker processes end within seconds instead of waiting for tasks for ever."""
    from test_probe_experiment import write_spec, spec_text

    spec = write_spec(tmp_path, spec_text(experiment_keys="size = [48, 32]\nthreads = 1\npilot_spp = 1\n",
                                          budgets="spp = [16, 64]\nrepetitions = 8\n"))
    p = subprocess.Popen([*_command(), "experiment", str(spec), "-o", str(tmp_path / "out"), "--workers", "2", "-q"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    workers = set()
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and len(workers) < 2 and p.poll() is None:
            workers = {c for c in _children(p.pid)
                       if b"spawn_main" in open(f"/proc/{c}/cmdline", "rb").read()}
            time.sleep(0.05)
        assert len(workers) == 2, "the experiment started no workers"
        p.send_signal(signal.SIGKILL)
        p.wait(30)
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and any(map(_alive, workers)):
            time.sleep(0.1)
        left = [w for w in workers if _alive(w)]
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
        for w in workers:
            if _alive(w):
                os.kill(w, signal.SIGKILL)
    assert not left, f"worker processes {left} outlived the experiment"


# ============================================================================= a full disk
@pytest.fixture
def full_disk(tmp_path):
    """A 256 KiB tmpfs, or a skip where it cannot be mounted (not root, no mount)."""
    mnt = tmp_path / "small"
    mnt.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mnt)], capture_output=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs: {r.stderr.decode().strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


@pytest.mark.parametrize("ext", [".exr", ".png", ".pfm", ".hdr"])
def test_a_full_disk_is_one_line_and_leaves_the_previous_file(full_disk, ext):
    """A write that does not fit (a 512 x 512 noisy image on a 256 KiB disk) fails in one
    line naming the file, keeps the previous file and leaves no temporary."""
    out = full_disk / f"o{ext}"
    wavlight.save_image(str(out), np.full((4, 4, 3), 0.5, np.float32))
    previous = out.read_bytes()
    noise = np.random.default_rng(0).random((512, 512, 3)).astype(np.float32)
    with pytest.raises(WavlightError) as e:
        wavlight.save_image(str(out), noise)
    assert str(out) in str(e.value) and "\n" not in str(e.value)
    assert out.read_bytes() == previous and no_temporaries(full_disk) == []


def test_an_experiment_on_a_full_disk_is_one_line(full_disk, tmp_path):
    """An experiment whose folder fills up fails in one line (exit 2 in the CLI) and leaves
    no temporary; what was written before stays readable."""
    from click.testing import CliRunner

    from test_probe_experiment import spec_text, write_spec
    from wavlight.cli.main import main

    spec = write_spec(tmp_path, spec_text(experiment_keys="size = [96, 64]\nthreads = 1\n",
                                          budgets="spp = [1, 2, 3, 4]\nrepetitions = 2\n"))
    r = CliRunner().invoke(main, ["experiment", str(spec), "-o", str(full_disk / "out"), "-q"])
    lines = [line for line in r.stderr.splitlines() if line.strip() and not line.startswith("warning:")]
    assert r.exit_code == 2 and len(lines) == 1 and lines[0].startswith("Error:"), r.output[-2000:]
    assert not list(full_disk.rglob(".wavlight-*"))


# ============================================================================= concurrent writers
def test_threads_racing_on_one_output_leave_one_complete_image(tmp_path):
    """Two threads writing different images to one path 15 times each leave a complete
    image equal to one of the two, and no temporary."""
    a, b = np.full((64, 96, 3), 0.25, np.float32), np.full((64, 96, 3), 2.0, np.float32)
    out = tmp_path / "o.exr"
    errors = []

    def write(img):
        try:
            for _ in range(15):
                wavlight.save_image(str(out), img)
        except BaseException as e:   # noqa: BLE001
            errors.append(e)
    threads = [threading.Thread(target=write, args=(img,)) for img in (a, b)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    got = read_image(str(out))
    assert np.array_equal(got, a) or np.array_equal(got, b)
    assert no_temporaries(tmp_path) == []


def test_processes_racing_on_one_folder_keep_each_others_temporaries(tmp_path):
    """Two processes writing into one folder at once (30 images each, to one shared name
    and to their own) never remove each other's live temporaries (each write's clean-up removes
    only dead processes' files): every write succeeds, every file is complete."""
    code = ("import sys, numpy as np, wavlight\n"
            "v = float(sys.argv[2])\n"
            "for i in range(30):\n"
            "    wavlight.save_image(sys.argv[1] + '/shared.exr', np.full((256, 256, 3), v, np.float32))\n"
            "    wavlight.save_image(sys.argv[1] + f'/own{v:g}.png', np.full((256, 256, 3), v, np.float32))\n"
            "print('ok')\n")
    ps = [subprocess.Popen([sys.executable, "-c", code, str(tmp_path), v], stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True) for v in ("0.5", "3")]
    outs = [p.communicate(timeout=120) for p in ps]
    assert all(p.returncode == 0 and o.strip() == "ok" for p, (o, _) in zip(ps, outs)), outs
    got = read_image(str(tmp_path / "shared.exr"))
    assert np.all(got == 0.5) or np.all(got == 3.0)
    assert no_temporaries(tmp_path) == []


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_an_interrupted_bake_leaves_no_scratch(tmp_path, sig):
    """SIGINT or SIGTERM while a bake collects its blocks: exit 130 or 143 with one line, and
    neither the bake file nor its scratch (`.entries`, beside the output) nor a temporary left."""
    scene = write_scene(tmp_path, scene_text(render="width = 128\nheight = 96\nspp = 2\n"))
    out = tmp_path / "b.wlt"
    p = subprocess.Popen(_command() + ["bake", str(scene), "-o", str(out), "--spp", "16", "--levels", "6",
                                       "--terms", "64"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.time() + 120
        while not any(n.endswith(".entries") for n in os.listdir(tmp_path)) and p.poll() is None:
            assert time.time() < deadline, "the bake never started collecting blocks"
            time.sleep(0.05)
        assert p.poll() is None, p.communicate()
        p.send_signal(sig)
        _, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    assert p.returncode == 128 + sig, (p.returncode, err)
    assert err.strip().splitlines()[-1] == f"Error: {'terminated' if sig == signal.SIGTERM else 'interrupted'} " \
                                           f"({sig.name})", err
    assert sorted(os.listdir(tmp_path)) == ["scene.toml"], os.listdir(tmp_path)
