"""Tiles in passes: the loop every unbiased frame of a bake runs over its pixels (Chen & Gao
eq. 12's estimator, per pixel a mean of independent camera samples, each weighted by its
mixture's pdf).

A frame is cut into tiles of pixels, and a tile's samples into passes of at most k samples per
pixel (k from the factor: at most a number per pixel, and a number of camera samples in all,
so that the memory of a pass stays bounded at any spp). Per tile the factor first makes what
its passes share (:attr:`TileWork.start`: the tile's product trees, its pixels' footprints),
then each pass returns the estimates of samples first .. first + k - 1 of every pixel of the
tile (:attr:`TileWork.samples`); the tile's sums and sums of squares of those estimates are
added to the frame's once the tile is done, so that a frame does not depend on the order the
tiles end in. The tiles run on a thread pool that stops at the next pass when the caller stops
waiting (:func:`wavlight.threads.map_until_stopped`: an error, Ctrl-C), and ``progress(done,
tiles, rays, seconds)`` is called as each tile ends. The frame's mean and per-pixel standard
error come from the sums (:func:`wavlight.relight.mixture.mean_and_error`).

The lighting bake's frames (:mod:`wavlight.relight.converge`) and the view bake's
(:mod:`wavlight.relight.view_converge`) run this loop with their own parts.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, NamedTuple

import numpy as np

from ..threads import map_until_stopped
from .mixture import mean_and_error


def pass_spp(spp: int, pixels: int, limit: int, samples: int) -> int:
    """Camera samples per pixel of one pass over a tile of ``pixels``: at most ``limit``, and
    ``samples`` camera samples in all (one at least)."""
    return max(1, min(spp, limit, samples // pixels))


@dataclass(frozen=True)
class TileWork:
    """A factor's parts of the loop (module docstring). A tile has ``x0``, ``y0``, ``w``, ``h``
    (its pixels in the frame); ``counts`` are dicts of numbers (``rays`` among them) summed over
    the frame's tiles.

    - ``start(tile) -> (state, counts)``: what the tile's passes share, made before its first;
    - ``samples(state, tile, first, k) -> (values, counts)``: the pass of samples first .. first
      + k - 1 of each pixel of the tile: ``values`` (P k, 3), pixel p's samples in rows
      p k .. p k + k - 1 (P = w h);
    - ``pass_spp(pixels) -> k``: the samples per pixel of a pass over a tile of that many pixels.
    """

    start: Callable[[Any], tuple]
    samples: Callable[[Any, Any, int, int], tuple]
    pass_spp: Callable[[int], int]


class Accumulated(NamedTuple):
    """A frame's passes: the per-pixel mean and standard error (H, W, 3) float64, and the tiles'
    counts summed (``done``: the tiles that ended)."""

    mean: np.ndarray
    stderr: np.ndarray
    totals: dict


def run_tiles(work: TileWork, tiles, width: int, height: int, spp: int, threads: int, progress=None,
              t0=None) -> Accumulated:
    """``spp`` samples per pixel of every tile of ``tiles`` (a frame ``width`` x ``height``) in
    passes, on ``threads`` threads (module docstring); ``progress(done, tiles, rays, seconds)``
    after each tile, seconds since ``t0`` (default: now)."""
    t0 = time.perf_counter() if t0 is None else t0
    sums = np.zeros((height, width, 3))
    squares = np.zeros((height, width, 3))
    totals = {"rays": 0, "done": 0}
    lock = threading.Lock()

    def one(tile, stop):
        state, counts = work.start(tile)
        counts = dict(counts)
        P = tile.w * tile.h
        per_pass = work.pass_spp(P)
        s_sum, s_sq = np.zeros((P, 3)), np.zeros((P, 3))
        for first in range(0, spp, per_pass):   # passes of samples per pixel, not samples: bounded memory
            if stop.is_set():   # the caller stopped waiting (an error, Ctrl-C)
                return
            k = min(per_pass, spp - first)
            v, more = work.samples(state, tile, first, k)
            for key, n in more.items():   # a few counters
                counts[key] = counts.get(key, 0) + n
            v = v.reshape(P, k, 3)
            s_sum += v.sum(1)
            s_sq += (v * v).sum(1)
        img = (slice(tile.y0, tile.y0 + tile.h), slice(tile.x0, tile.x0 + tile.w))
        with lock:
            sums[img] += s_sum.reshape(tile.h, tile.w, 3)
            squares[img] += s_sq.reshape(tile.h, tile.w, 3)
            for key, n in counts.items():   # a few counters
                totals[key] = totals.get(key, 0) + n
            totals["done"] += 1
            if progress:
                progress(totals["done"], len(tiles), totals["rays"], time.perf_counter() - t0)

    map_until_stopped(one, tiles, threads)
    mean, err = mean_and_error(sums, squares, spp)
    return Accumulated(mean, err, totals)
