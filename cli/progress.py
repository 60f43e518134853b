"""The commands' one progress bar (tqdm), on stderr and only where stderr is a terminal.

Every command that works for more than a moment draws it: ``render`` and ``frame --spp``
(parts of the image, samples or rays per second), ``bake`` (blocks, rays per second),
``experiment`` (runs, the one just finished), turntables and orbits (frames). It tells the
parts done of the total, the rate, the time spent and the time left, and is never wider than
the terminal: its width is measured again at each report (a resized window), 80 columns where
the terminal does not say, and longer text is cut.

    with progress_bar("parts", "samples", quiet) as bar:     # None: nothing is drawn
        wavlight.render_full(scene, progress=bar)
"""
from __future__ import annotations

import contextlib
import os
import sys
import time

from tqdm import tqdm

#: the width where the terminal does not tell its own
FALLBACK_COLUMNS = 80
#: the longest label (an experiment's run just finished) shown after the numbers
LABEL_CHARS = 32


def terminal_columns(stream) -> int:
    """The width of the terminal ``stream`` writes to (FALLBACK_COLUMNS where unknown)."""
    try:
        columns = os.get_terminal_size(stream.fileno()).columns
    except (AttributeError, OSError, ValueError):
        return FALLBACK_COLUMNS
    return columns if columns > 0 else FALLBACK_COLUMNS


def is_terminal(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):   # no isatty, or a closed stream
        return False


class _Line(tqdm):
    """tqdm redrawing its line with an erase to the line's end (ANSI EL) rather than with spaces
    up to the previous line's length, which would wrap once the terminal is made narrower."""

    @staticmethod
    def status_printer(file):
        def print_status(s):
            file.write(f"\r{s}\x1b[K")
            file.flush()
        return print_status


class ProgressBar:
    """One tqdm bar over ``counts`` (parts, blocks, runs, frames), fed by the library's progress
    reports. ``unit``: what the reports' amount counts (samples, rays) for the rate."""

    def __init__(self, stream, counts: str = "parts", unit: str | None = None):
        self.stream, self.counts, self.unit = stream, counts, unit
        self._bar = None   # made at the first report, which tells the total
        self.t0 = time.time()   # the work starts now (tqdm's clock: time.time)

    def __call__(self, done, total, *about):
        """A report: ``(done, total, amount, seconds)`` from a render, a bake or an unbiased frame
        (the rate shown is amount / seconds of ``unit``), ``(done, total, what)`` from an
        experiment (what was just finished), or ``(done, total)``."""
        # the last column would wrap on some terminals; at least 1 (tqdm takes 0 for no limit)
        columns = max(1, terminal_columns(self.stream) - 1)
        if self._bar is None:
            # the clock (elapsed time, rate, time left) runs from the start of the work, not from
            # this first report, which is drawn at once
            self._bar = _Line(total=total, file=self.stream, ncols=columns, unit=self.counts, leave=True,
                              smoothing=0, dynamic_ncols=False,
                              bar_format="{percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} {unit} "
                                         "[{elapsed}<{remaining}{postfix}]")
            self._bar.start_t = self._bar.last_print_t = self.t0
        bar = self._bar
        bar.ncols = columns
        if bar.total != total:
            bar.total = total
        if len(about) == 2 and self.unit is not None:
            amount, seconds = about
            rate = amount / seconds if seconds > 0 else 0.0
            bar.set_postfix_str(f"{rate / 1e6:.2f} M {self.unit}/s", refresh=False)
        elif len(about) == 1:
            what = " ".join(str(about[0]).split())
            bar.set_postfix_str(what if len(what) <= LABEL_CHARS else what[:LABEL_CHARS - 3] + "...", refresh=False)
        if done >= total:   # the last report is always drawn
            bar.n = done
            bar.refresh()
        else:
            bar.update(done - bar.n)

    def close(self):
        if self._bar is not None:
            self._bar.ncols = max(1, terminal_columns(self.stream) - 1)
            self._bar.close()
            self._bar = None


@contextlib.contextmanager
def progress_bar(counts: str = "parts", unit: str | None = None, quiet: bool = False, stream=None):
    """A :class:`ProgressBar` on ``stream`` (default stderr) while the block runs, closed at its
    end (also on an error, before the error's line); None when ``quiet`` or where the stream is
    not a terminal (a pipe, a file, a test), so that nothing is drawn."""
    stream = sys.stderr if stream is None else stream
    if quiet or not is_terminal(stream):
        yield None
        return
    bar = ProgressBar(stream, counts, unit)
    try:
        yield bar
    finally:
        bar.close()
