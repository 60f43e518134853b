"""Counter-based uniforms: Philox-4x32-10 (Salmon et al. 2011, "Parallel random
numbers: as easy as 1, 2, 3"), the ``independent`` sampler's numbers.

Each number is a pure function of (seed, tile, stream, sample index), so a kernel
draws the uniforms where it uses them (``kernels/rng.h``: the camera-ray kernel its
jitters, ``shade_rays`` its four shading uniforms) and nothing is generated on the
host or uploaded; images depend neither on threads nor on batch sizes. This module
is the numpy twin, checked against Random123's known-answer vectors and against
the kernels.

Counter (c0, c1, c2, c3) = (sample index in its tile, tile index, stream, 0), key =
the seed's low and high 32 bits. Stream ``JITTER`` gives the pixel jitter (words 0,
1), stream ``SHADING`` the four shading uniforms (guide pair, BSDF pair). A 32-bit
word w becomes the float32 (w >> 8) 2^-24 in [0, 1).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

JITTER, SHADING = 0, 1
_M0, _M1 = np.uint64(0xD2511F53), np.uint64(0xCD9E8D57)
_W0, _W1 = 0x9E3779B9, 0xBB67AE85
_MASK = np.uint64(0xFFFFFFFF)


def philox4x32_10(counter: np.ndarray, key) -> np.ndarray:
    """(N, 4) uint32 counters, key (k0, k1) -> (N, 4) uint32 random words."""
    c = [np.asarray(counter, np.uint32)[:, j].astype(np.uint64) for j in range(4)]
    k0, k1 = int(key[0]) & 0xFFFFFFFF, int(key[1]) & 0xFFFFFFFF
    for _ in range(10):  # rounds, not samples
        p0, p1 = _M0 * c[0], _M1 * c[2]
        c = [(p1 >> np.uint64(32)) ^ c[1] ^ np.uint64(k0), p1 & _MASK,
             (p0 >> np.uint64(32)) ^ c[3] ^ np.uint64(k1), p0 & _MASK]
        k0, k1 = (k0 + _W0) & 0xFFFFFFFF, (k1 + _W1) & 0xFFFFFFFF
    return np.stack(c, axis=1).astype(np.uint32)


def key(seed: int) -> tuple[int, int]:
    """The Philox key of a render seed (its low and high 32 bits)."""
    return int(seed) & 0xFFFFFFFF, (int(seed) >> 32) & 0xFFFFFFFF


def uniforms(seed: int, tile: int, stream: int, first: int, count: int) -> np.ndarray:
    """(count, 4) float32 in [0, 1): the numbers of samples first .. first + count - 1 of a tile."""
    counter = np.zeros((count, 4), np.uint32)
    counter[:, 0] = np.arange(first, first + count, dtype=np.uint64).astype(np.uint32)
    counter[:, 1] = tile
    counter[:, 2] = stream
    words = philox4x32_10(counter, key(seed))
    return (words >> np.uint32(8)).astype(np.float32) * np.float32(2.0 ** -24)


class Stream(NamedTuple):
    """The independent sampler's numbers of one pass of a tile: samples first, first + 1, ...
    of tile ``tile`` of a render with seed ``seed``."""

    seed: int
    tile: int
    first: int

    def uniforms(self, stream: int, count: int) -> np.ndarray:
        """(count, 4) float32: the pass's numbers in ``stream`` (JITTER or SHADING)."""
        return uniforms(self.seed, self.tile, stream, self.first, count)
