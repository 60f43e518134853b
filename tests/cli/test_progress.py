"""The commands' one progress bar (cli/progress.py, tqdm): drawn on a terminal only, never wider
than the terminal (also after it is resized, and with a long label), telling the parts done, the
rate and the time left; nothing at all on a stream that is not a terminal."""
from __future__ import annotations

import fcntl
import io
import os
import pty
import re
import struct
import subprocess
import termios
import threading
import time

import pytest

from test_cli import _command, run_inproc, scene_text, write_scene
from tqdm.utils import disp_len
from wavlight.cli.progress import FALLBACK_COLUMNS, ProgressBar, progress_bar, terminal_columns


def set_columns(fd, columns, rows=24):
    fcntl.ioctl(fd, termios.TIOCSWINSZ, struct.pack("HHHH", rows, columns, 0, 0))


class Terminal:
    """A pseudo-terminal of ``columns`` columns: ``stream`` writes to it, ``read()`` returns what
    was drawn so far (a thread drains it, so that a full buffer never blocks the writer)."""

    def __init__(self, columns):
        self.master, self.slave = pty.openpty()
        set_columns(self.slave, columns)
        attrs = termios.tcgetattr(self.slave)
        attrs[1] &= ~termios.ONLCR           # keep "\n" as written (no "\r\n")
        termios.tcsetattr(self.slave, termios.TCSANOW, attrs)
        self.stream = io.TextIOWrapper(io.FileIO(self.slave, "w", closefd=False), encoding="utf-8",
                                       line_buffering=False, write_through=True)
        self.chunks, self.lock = [], threading.Lock()
        self.thread = threading.Thread(target=self._drain, daemon=True)
        self.thread.start()

    def _drain(self):
        while True:
            try:
                data = os.read(self.master, 4096)
            except OSError:   # EIO once the slave side is closed
                return
            if not data:
                return
            with self.lock:
                self.chunks.append(data)

    def read(self, settle=0.2) -> str:
        time.sleep(settle)
        with self.lock:
            data, self.chunks = b"".join(self.chunks), []
        return data.decode("utf-8", errors="replace")

    def close(self):
        self.stream.flush()
        os.close(self.slave)
        self.thread.join(timeout=5)
        os.close(self.master)


def drawn_lines(text: str) -> list[str]:
    """What each redraw put on the line (split at carriage returns and newlines)."""
    return [part for part in re.split(r"[\r\n]", text) if part.strip()]


def test_the_width_is_the_terminals():
    t = Terminal(57)
    try:
        assert terminal_columns(t.stream) == 57
    finally:
        t.close()
    assert terminal_columns(io.StringIO()) == FALLBACK_COLUMNS   # no terminal: the fallback


@pytest.mark.parametrize("columns", [80, 40])
def test_a_render_bar_fits_the_terminal_and_tells_parts_rate_and_time_left(columns):
    t = Terminal(columns)
    try:
        bar = ProgressBar(t.stream, "parts", "samples")
        for done in range(1, 9):
            bar(done, 8, done * 1_500_000, done * 0.15)   # 10 M samples/s
            time.sleep(0.12)                              # past tqdm's minimum interval
        bar.close()
        lines = drawn_lines(t.read())
    finally:
        t.close()
    assert lines, "nothing was drawn on the terminal"
    widest = max(disp_len(line) for line in lines)
    assert widest <= columns - 1, (widest, lines)
    last = lines[-1]
    assert "8/8 parts" in last and "100%" in last, last
    if columns >= 80:   # room for everything: the rate and the time left are there
        middle = next(line for line in lines if "4/8" in line)
        assert "10.00 M samples/s" in middle and "<" in middle, middle


@pytest.mark.parametrize("columns", [20, 2, 1])
def test_a_narrow_terminal_gets_a_bar_within_it(columns):
    """20 columns, and the narrowest: one column left after the last (which wraps) is still a
    width (tqdm takes ncols=0 for no limit at all)."""
    t = Terminal(columns)
    try:
        bar = ProgressBar(t.stream, "parts", "samples")
        for done in range(1, 4):
            bar(done, 3, done * 1_500_000, done * 0.15)
        bar.close()
        lines = drawn_lines(t.read())
    finally:
        t.close()
    assert lines and max(disp_len(line) for line in lines) <= max(columns - 1, 1), lines


def test_the_bar_follows_a_resized_terminal():
    t = Terminal(100)
    try:
        bar = ProgressBar(t.stream, "parts", "rays")
        bar(1, 10, 1000, 0.1)
        time.sleep(0.12)
        bar(2, 10, 2000, 0.2)
        before = drawn_lines(t.read())
        set_columns(t.slave, 30)
        for done in range(3, 11):
            time.sleep(0.12)
            bar(done, 10, done * 1000, done * 0.1)
        bar.close()
        after = drawn_lines(t.read())
    finally:
        t.close()
    assert before and max(disp_len(line) for line in before) <= 99
    assert max(disp_len(line) for line in before) > 30, before   # the wide terminal was used
    assert after and max(disp_len(line) for line in after) <= 29, after


def test_a_long_label_is_cut_to_the_terminal():
    """An experiment's reports name the run just finished; a long name must not wrap the line."""
    t = Terminal(80)
    try:
        bar = ProgressBar(t.stream, "runs")
        long = "reference " + "scene-with-a-very-long-name/" * 6 + "wavelet/spp 1024/seed 3"
        for done in range(1, 6):
            bar(done, 5, long)
            time.sleep(0.12)
        bar.close()
        lines = drawn_lines(t.read())
    finally:
        t.close()
    assert lines and max(disp_len(line) for line in lines) <= 79, lines
    assert any("5/5 runs" in line for line in lines), lines
    assert any("reference scene" in line for line in lines), lines   # the label, cut


def test_nothing_is_drawn_where_stderr_is_not_a_terminal():
    stream = io.StringIO()
    with progress_bar("parts", "samples", stream=stream) as bar:
        assert bar is None
    assert stream.getvalue() == ""
    t = Terminal(80)
    try:
        with progress_bar("parts", "samples", quiet=True, stream=t.stream) as bar:   # --quiet
            assert bar is None
        with progress_bar("parts", "samples", stream=t.stream) as bar:
            assert isinstance(bar, ProgressBar)
        assert t.read() == ""    # nothing reported, nothing drawn
    finally:
        t.close()


def test_a_render_draws_no_bar_into_a_pipe(tmp_path):
    scene = write_scene(tmp_path, scene_text())
    o = run_inproc("render", scene, "-o", tmp_path / "o.png")
    assert o.code == 0, o.describe()
    assert "\r" not in o.stderr and "%|" not in o.stderr, o.stderr
    assert o.stderr.startswith("wrote "), o.stderr


def test_a_render_on_an_80_column_terminal_stays_within_it(tmp_path):
    """The real command with stderr on a pseudo-terminal of 80 columns: a bar is drawn, every
    line of it fits, and the closing line follows."""
    scene = write_scene(tmp_path, scene_text(render="width = 64\nheight = 48\nspp = 16\n"))
    t = Terminal(80)
    try:
        p = subprocess.run(_command() + ["render", str(scene), "-o", str(tmp_path / "o.png")], stdin=subprocess.DEVNULL,
                           stdout=subprocess.PIPE, stderr=t.slave, timeout=300, env={**os.environ, "COLUMNS": "200"})
        text = t.read(settle=0.5)
    finally:
        t.close()
    assert p.returncode == 0, text
    lines = drawn_lines(text)
    assert any("parts" in line and "%|" in line for line in lines), lines
    assert max(disp_len(line) for line in lines if "%|" in line) <= 79, lines
    assert lines[-1].startswith("wrote "), lines


@pytest.mark.slow
def test_a_first_build_on_a_terminal_says_so_in_one_line(tmp_path):
    """With an empty kernel cache (a fresh XDG_CACHE_HOME and POCL_CACHE_DIR) a render on a
    terminal prints one `note:` line before it compiles; the same render again prints none."""
    scene = write_scene(tmp_path, scene_text())
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache"), "POCL_CACHE_DIR": str(tmp_path / "pocl")}
    notes = []
    for run in range(2):
        t = Terminal(100)
        try:
            p = subprocess.run(_command() + ["render", str(scene), "-o", str(tmp_path / f"o{run}.png")],
                               stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=t.slave, timeout=600, env=env)
            text = t.read(settle=0.5)
        finally:
            t.close()
        assert p.returncode == 0, text
        notes.append([line for line in drawn_lines(text) if line.startswith("note: ")])
    assert len(notes[0]) == 1 and "compiling OpenCL kernels" in notes[0][0], notes
    assert notes[1] == [], notes
