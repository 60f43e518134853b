"""Writes checked end to end: an output file is complete and readable, or there is none and
the exit code says why in one line.

A full disk is reproduced two ways. Everywhere: OpenImageIO's writer wrapped to behave as it
does on a full disk (every call succeeds and the file is left empty or cut), PIL's GIF writer
and the bake's scratch writes raising ENOSPC, and the free space reported as 0. Where root may
mount one (skipped elsewhere): a small tmpfs, filled. Also: a bake checks its output before any
work and keeps its scratch beside the output; turntables and orbits check their folder and
frame names before any work.
"""
from __future__ import annotations

import errno
import json
import os
import subprocess
import sys

import numpy as np
import pytest

import wavlight
from scenes_util import toml_text, write_raw_image
from test_relight_cli import FAST, SCENE, one_error_line, run
from wavlight import atomic
from wavlight.envmap import read_image
from wavlight.errors import WavlightError

IMAGE = np.random.default_rng(1).uniform(0.0, 2.0, (24, 40, 3)).astype(np.float32)
EXTENSIONS = (".png", ".hdr", ".exr", ".pfm")


def temporaries(folder):
    return sorted(p.name for p in folder.rglob(".wavlight-*"))


# ============================================================================= fixtures
@pytest.fixture(scope="module")
def baked(tmp_path_factory, device):
    folder = tmp_path_factory.mktemp("writes")
    rng = np.random.default_rng(0)
    write_raw_image(folder / "sky.exr", rng.uniform(0.2, 2.0, (16, 32, 3)).astype(np.float32))
    (folder / "scene.toml").write_text(toml_text(SCENE))
    r = run("bake", folder / "scene.toml", "-o", folder / "scene.wlt", *FAST, "-q")
    assert r.exit_code == 0, r.output
    return folder, folder / "scene.wlt"


@pytest.fixture(scope="module")
def view_baked(baked):
    folder, _ = baked
    out = folder / "view.wlt"
    r = run("bake", folder / "scene.toml", "-o", out, "--vary", "view", "--levels", 3, "--density", 100, "-q")
    assert r.exit_code == 0, r.output
    return out


class _Silent:
    """An OpenImageIO writer as it behaves on a full disk: every call reports success, and the
    file is left holding ``keep`` of what was written (0: empty)."""

    def __init__(self, inner, name, keep):
        self.inner, self.name, self.keep = inner, name, keep

    def __getattr__(self, attr):
        return getattr(self.inner, attr)

    def geterror(self, *a):
        self.inner.geterror(*a)
        return ""

    def close(self):
        self.inner.close()
        size = os.path.getsize(self.name)
        with open(self.name, "r+b") as fh:
            fh.truncate(int(size * self.keep))
        return True


@pytest.fixture
def silent_full_disk(monkeypatch):
    """Make OpenImageIO's writers silent about a full disk from the write number ``state["from"]``
    on (0: every write), keeping ``state["keep"]`` of each file."""
    import OpenImageIO as oiio

    real = oiio.ImageOutput.create
    state = {"from": 0, "keep": 0.0, "writes": 0}

    def create(name, *args):
        out = real(name, *args)
        state["writes"] += 1
        return _Silent(out, name, state["keep"]) if state["writes"] > state["from"] else out

    monkeypatch.setattr(oiio.ImageOutput, "create", staticmethod(create))
    return state


def _mount(folder, *options):
    folder.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", ",".join(options), "tmpfs", str(folder)], capture_output=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs: {r.stderr.decode().strip() or 'mount failed'}")


@pytest.fixture
def small_disk(tmp_path):
    """A 64 KiB tmpfs (root only; skipped elsewhere); ``fill(left)`` leaves ``left`` bytes free."""
    mnt = tmp_path / "disk"
    _mount(mnt, "size=64k")

    def fill(left=0):
        with open(mnt / "filler", "wb") as fh:
            try:
                fh.write(b"\0" * max(0, atomic.free_bytes(mnt / "x") - left))
                fh.flush()
            except OSError:
                pass
        return mnt
    try:
        yield fill
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


@pytest.fixture
def read_only_folder(tmp_path):
    """A folder nobody may write into: a read-only tmpfs for root (who ignores permissions),
    mode 0555 for anyone else."""
    folder = tmp_path / "ro"
    if os.geteuid() == 0:
        _mount(folder, "ro", "size=64k")
        try:
            yield folder
        finally:
            subprocess.run(["umount", "-l", str(folder)], capture_output=True)
    else:
        folder.mkdir()
        folder.chmod(0o555)
        try:
            yield folder
        finally:
            folder.chmod(0o755)


# ============================================================================= the library
@pytest.mark.parametrize("keep", [0.0, 0.5])
@pytest.mark.parametrize("ext", EXTENSIONS)
def test_a_silently_failed_write_is_one_line_and_leaves_the_previous_file(tmp_path, silent_full_disk, ext, keep):
    """A writer that reports success with nothing or half written (OpenImageIO's PNG and HDR
    writers on a full disk): the file is read back before it replaces the target."""
    out = tmp_path / f"o{ext}"
    silent_full_disk.update({"from": 1, "keep": keep})   # the first write is real, the next silent
    wavlight.save_image(str(out), np.full((4, 4, 3), 0.5, np.float32))
    previous = out.read_bytes()
    with pytest.raises(WavlightError) as e:
        wavlight.save_image(str(out), IMAGE)
    message = str(e.value)
    assert message.startswith(f"{out}: write failed") and "\n" not in message, message
    assert out.read_bytes() == previous and temporaries(tmp_path) == []


def test_several_images_are_all_or_nothing_when_the_second_is_cut(tmp_path, silent_full_disk):
    silent_full_disk.update({"from": 1, "keep": 0.5})
    with pytest.raises(WavlightError, match="b.exr: write failed"):
        wavlight.imageio.save_images([(str(tmp_path / "a.exr"), IMAGE), (str(tmp_path / "b.exr"), IMAGE)])
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_an_atomic_write_checks_fsyncs_and_renames(tmp_path):
    """The helper itself: a temporary named for the stale clean-up in the target's folder, the
    usual mode, the check's one-line failure, and every error removing the temporary."""
    out = tmp_path / "t.txt"
    with atomic.atomic_write(out, check=atomic.size_is(5)) as tmp:
        assert os.path.dirname(tmp) == str(tmp_path)
        name = os.path.basename(tmp)
        assert name.startswith(f".wavlight-{os.getpid()}.{atomic.host_id()}-t.txt.") and name.endswith(".txt")
        with open(tmp, "wb") as fh:
            fh.write(b"12345")
    umask = os.umask(0)
    os.umask(umask)
    assert out.read_bytes() == b"12345" and out.stat().st_mode & 0o777 == 0o666 & ~umask
    with pytest.raises(WavlightError, match=r"t.txt: write failed \(3 bytes written of 5"):
        with atomic.atomic_write(out, check=atomic.size_is(5)) as tmp:
            with open(tmp, "wb") as fh:
                fh.write(b"123")
    with pytest.raises(WavlightError, match="t.txt: write failed .the written file is empty"):
        with atomic.atomic_write(out):
            pass
    with pytest.raises(WavlightError, match=r"t.txt: cannot write \(No space left on device\)"):
        with atomic.atomic_write(out):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    with pytest.raises(KeyError):   # anything else passes through, the temporary removed all the same
        with atomic.atomic_write(out):
            raise KeyError("x")
    assert out.read_bytes() == b"12345" and temporaries(tmp_path) == []


def test_free_space_is_checked_before_a_bake(tmp_path, monkeypatch, device):
    import shutil

    rng = np.random.default_rng(0)
    write_raw_image(tmp_path / "sky.exr", rng.uniform(0.2, 2.0, (16, 32, 3)).astype(np.float32))
    (tmp_path / "scene.toml").write_text(toml_text(SCENE))
    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage._replace(free=100))
    from wavlight.relight import bake as bake_module

    def no_work(*a, **k):
        raise AssertionError("the bake started its work")
    monkeypatch.setattr(bake_module, "choose_model", no_work)
    r = run("bake", tmp_path / "scene.toml", "-o", tmp_path / "x.wlt", *FAST)
    one_error_line(r, "x.wlt", "no room", "100 bytes free")
    assert not (tmp_path / "x.wlt").exists() and temporaries(tmp_path) == []


# ============================================================================= frame and render
@pytest.mark.parametrize("ext", EXTENSIONS)
def test_frame_on_a_silently_full_disk_writes_nothing_and_exits_2(baked, tmp_path, silent_full_disk, ext):
    _, bake_file = baked
    r = run("frame", bake_file, "-o", tmp_path / f"x{ext}")
    one_error_line(r, f"x{ext}", "write failed")
    assert "wrote" not in r.output and not (tmp_path / f"x{ext}").exists() and temporaries(tmp_path) == []


def test_render_on_a_silently_full_disk_writes_nothing_and_exits_2(baked, tmp_path, silent_full_disk):
    folder, _ = baked
    for ext in (".png", ".hdr"):
        r = run("render", folder / "scene.toml", "-o", tmp_path / f"r{ext}", "--spp", 2)
        one_error_line(r, f"r{ext}", "write failed")
        assert not (tmp_path / f"r{ext}").exists()
    assert temporaries(tmp_path) == []


def test_a_turntable_that_fills_the_disk_stops_at_the_first_frame_that_fails(baked, tmp_path, silent_full_disk):
    """Frames before the full disk are complete; the one that failed and the GIF are absent."""
    _, bake_file = baked
    silent_full_disk["from"] = 2
    r = run("frame", bake_file, "--turntable", 5, "-o", tmp_path / "tt")
    one_error_line(r, "frame-0002.png", "write failed")
    assert sorted(os.listdir(tmp_path / "tt")) == ["frame-0000.png", "frame-0001.png"]
    for name in ("frame-0000.png", "frame-0001.png"):
        assert read_image(str(tmp_path / "tt" / name)).shape == (12, 16, 3)


def test_an_animation_that_does_not_fit_leaves_no_file(baked, tmp_path, monkeypatch):
    """Pillow's APNG writer raising ENOSPC half way (the GIF before it used to leave a .part file)."""
    from PIL import Image

    real = Image.Image.save

    def save(self, fp, format=None, **params):
        if format == "PNG" and params.get("save_all"):
            with open(fp, "wb") as fh:
                fh.write(b"\x89PNG half")
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(self, fp, format, **params)
    monkeypatch.setattr(Image.Image, "save", save)
    _, bake_file = baked
    r = run("frame", bake_file, "--turntable", 3, "-o", tmp_path / "tt")
    one_error_line(r, "turntable.png", "No space left on device")
    assert sorted(os.listdir(tmp_path / "tt")) == ["frame-0000.png", "frame-0001.png", "frame-0002.png"]
    assert not [p for p in (tmp_path / "tt").iterdir() if p.suffix == ".part"]


# ============================================================================= bake
def test_bake_refuses_a_read_only_output_file_before_any_work(baked, tmp_path):
    folder, _ = baked
    locked = tmp_path / "locked.wlt"
    locked.write_bytes(b"keep me")
    locked.chmod(0o444)
    r = run("bake", folder / "scene.toml", "-o", locked, *FAST)
    one_error_line(r, "locked.wlt", "read-only")
    assert locked.read_bytes() == b"keep me"


def test_bake_refuses_a_read_only_folder_before_any_work(baked, read_only_folder):
    folder, _ = baked
    r = run("bake", folder / "scene.toml", "-o", read_only_folder / "x.wlt", *FAST)
    one_error_line(r, "x.wlt", "cannot write into")


def test_bake_keeps_its_scratch_beside_the_output_not_in_tmpdir(baked, tmp_path, monkeypatch):
    """A system temporary folder that cannot be used does not matter: the scratch goes beside
    the output, named for the stale clean-up, which removes a killed bake's scratch."""
    import tempfile

    folder, _ = baked
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "no-such-tmpdir"))
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    out = tmp_path / "out"
    out.mkdir()
    stale = out / f".wavlight-{dead}.{atomic.host_id()}-x.wlt.k1ll3d.entries"
    stale.write_bytes(b"a killed bake's entries")
    seen = []
    from wavlight.relight import store

    real_add = store.TransferWriter.add

    def add(self, *a):
        seen.append(self._tmp)
        return real_add(self, *a)
    monkeypatch.setattr(store.TransferWriter, "add", add)
    r = run("bake", folder / "scene.toml", "-o", out / "x.wlt", *FAST, "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["file_bytes"] == os.path.getsize(out / "x.wlt")
    scratch = os.path.basename(seen[0])
    assert os.path.dirname(seen[0]) == str(out), seen[0]
    assert scratch.startswith(f".wavlight-{os.getpid()}.{atomic.host_id()}-x.wlt.") and scratch.endswith(".entries")
    assert sorted(p.name for p in out.iterdir()) == ["x.wlt"]   # no scratch left; the stale one reclaimed


def test_a_bake_whose_scratch_does_not_fit_is_one_line(baked, tmp_path, monkeypatch):
    """ENOSPC while the blocks are collected: one line, no file, no scratch."""
    folder, _ = baked
    from wavlight.relight import store

    real_init = store.TransferWriter.__init__

    class Full:
        def __init__(self, fh):
            self.fh = fh
            self.closed = False

        def write(self, data):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        def flush(self):
            pass

        def close(self):
            self.closed = True
            self.fh.close()

    def init(self, *a, **k):
        real_init(self, *a, **k)
        self._fh = Full(self._fh)
    monkeypatch.setattr(store.TransferWriter, "__init__", init)
    r = run("bake", folder / "scene.toml", "-o", tmp_path / "x.wlt", *FAST)
    one_error_line(r, "x.wlt", "No space left on device")
    assert list(tmp_path.iterdir()) == []


# ============================================================================= turntables and orbits
def test_turntable_frames_must_not_overwrite_inputs(baked, tmp_path):
    """A bake named like a frame or an animation in the output folder is refused before any work."""
    folder, bake_file = baked
    out = tmp_path / "tt"
    out.mkdir()
    for name in ("frame-0001.png", "turntable.png", "turntable.mp4"):
        disguised = out / name
        disguised.write_bytes(bake_file.read_bytes())
        r = run("frame", disguised, "--turntable", 3, "-o", out)
        one_error_line(r, name, "input of this run")
        assert disguised.read_bytes() == bake_file.read_bytes()
        assert sorted(os.listdir(out)) == [name]
        disguised.unlink()


def test_turntable_output_that_is_a_file_is_one_line(baked, tmp_path):
    _, bake_file = baked
    existing = tmp_path / "tt"
    existing.write_text("a file")
    r = run("frame", bake_file, "--turntable", 3, "-o", existing)
    one_error_line(r, "tt", "is a file, not a folder")
    assert existing.read_text() == "a file"


def test_turntable_into_a_read_only_folder_is_one_line(baked, read_only_folder):
    _, bake_file = baked
    r = run("frame", bake_file, "--turntable", 3, "-o", read_only_folder)
    one_error_line(r, "frame-0000.png", "cannot write into")
    r = run("frame", bake_file, "--turntable", 3, "-o", read_only_folder / "new")
    one_error_line(r, "new", "cannot make the folder")


def test_turntable_refuses_a_read_only_frame_before_any_work(baked, tmp_path):
    _, bake_file = baked
    out = tmp_path / "tt"
    out.mkdir()
    (out / "frame-0002.png").write_bytes(b"keep")
    (out / "frame-0002.png").chmod(0o444)
    r = run("frame", bake_file, "--turntable", 3, "-o", out)
    one_error_line(r, "frame-0002.png", "read-only")
    assert sorted(os.listdir(out)) == ["frame-0002.png"]


def test_orbit_checks_its_folder_before_any_work(view_baked, tmp_path):
    out = tmp_path / "orbit"
    out.write_text("a file")
    one_error_line(run("frame", view_baked, "--orbit", 3, "-o", out), "orbit", "is a file, not a folder")
    out.unlink()
    out.mkdir()
    disguised = out / "orbit.png"
    disguised.write_bytes(view_baked.read_bytes())
    one_error_line(run("frame", disguised, "--orbit", 3, "-o", out), "orbit.png", "input of this run")
    assert sorted(os.listdir(out)) == ["orbit.png"]


# ============================================================================= a real full disk (root)
@pytest.mark.parametrize("ext", EXTENSIONS)
def test_frame_into_a_full_tmpfs_is_one_line(baked, small_disk, ext):
    _, bake_file = baked
    disk = small_disk(0)
    r = run("frame", bake_file, "-o", disk / f"x{ext}")
    one_error_line(r, f"x{ext}")
    assert sorted(os.listdir(disk)) == ["filler"]


def test_bake_into_a_nearly_full_tmpfs_is_one_line(baked, small_disk):
    """Room for the sections known before the bake, not for its entries."""
    folder, bake_file = baked
    disk = small_disk(2 * 16 * 32 * 3 * 4)
    r = run("bake", folder / "scene.toml", "-o", disk / "x.wlt", *FAST)
    one_error_line(r, "x.wlt")
    assert sorted(os.listdir(disk)) == ["filler"]


@pytest.mark.slow
def test_a_long_turntable_into_a_small_tmpfs_leaves_only_complete_frames(baked, small_disk):
    """`--turntable 3600` into 64 KiB: it stops with one line at the first frame that does not
    fit; every frame left is complete and readable, no temporary, no animation."""
    _, bake_file = baked
    disk = small_disk(1 << 30)   # nothing filled: the frames fill it
    out = disk / "tt"
    r = run("frame", bake_file, "--turntable", 3600, "-o", out)
    one_error_line(r, "frame-")
    assert "write failed" in r.output or "No space left on device" in r.output, r.output
    names = sorted(os.listdir(out))
    assert names and "turntable.png" not in names and not [n for n in names if n.startswith(".wavlight-")]
    assert names == [f"frame-{i:04d}.png" for i in range(len(names))] and len(names) < 3600
    for name in names:
        assert os.path.getsize(out / name) > 0
        assert read_image(str(out / name)).shape == (12, 16, 3)
