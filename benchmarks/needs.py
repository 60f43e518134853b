"""The example data a benchmark reads, fetched before anything is timed, or the script stops
with the one line that says why it cannot be (not a benchmark itself: it writes no result).

The maps and meshes are assets of :mod:`wavlight.data`: downloaded on first use into the user
cache, or read from the folder that ``WAVLIGHT_DATA`` names (without a network, set it to a
folder holding them: ``envmaps/rooitou_park_1k.hdr``, ``meshes/bunny.ply``, ...).
"""
from __future__ import annotations

import sys


def fetch(script: str, *names: str) -> None:
    """Fetch the assets ``names`` now; exit with ``script: <the one-line reason>`` when one
    cannot be had."""
    import wavlight
    import wavlight.data

    try:
        for name in names:
            wavlight.data.path(name)
    except wavlight.WavlightError as e:
        sys.exit(f"{script}: {e}")
