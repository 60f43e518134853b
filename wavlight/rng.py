"""Counter-based uniforms: Philox-4x32-10 (Salmon et al. 2011, "Parallel random
numbers: as easy as 1, 2, 3"), the samplers' numbers (:mod:`wavlight.sampler`).

Each number is a pure function of (seed, tile, stream, sample index), so a kernel
draws the uniforms where it uses them (``kernels/rng.h``: the camera-ray kernel its
jitters, ``shade_rays`` its four shading uniforms) and nothing is generated on the
host or uploaded; images depend neither on threads nor on batch sizes. This module
is the numpy twin, checked against Random123's known-answer vectors and against
the kernels.

Counter (c0, c1, c2, c3) = (sample index in its tile, tile index, stream, 0), key =
the seed's low and high 32 bits. Stream ``JITTER`` gives the pixel jitter (words 0,
1), stream ``SHADING`` the four shading uniforms (guide pair, BSDF pair). A 32-bit
word w becomes the float32 (w >> 8) 2^-24 in [0, 1). The ``stratified`` sampler moves
each pair into a cell of its pixel's grid (:func:`sampler.stratify_pair`), keyed by
words 0, 1, 2 (jitter, guide, BSDF pair) of stream ``STRATA`` at index (the pass's first
index + pixel): one counter per pixel and pass.

Every stream id of wavlight is declared here, once (:data:`STREAMS`): two uses with different
streams never draw the same numbers, whatever their tiles and indices, so no two ranges overlap
(tests/test_rng_streams.py checks it, and that ``kernels/rng.h`` defines the ids the kernels
name with the same values). Changing an id changes the images of its use.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .sampler import stratify_pair

# ----------------------------------------------------------------------------- the stream registry
#: the pixel jitter: camera rays of renders, bakes and frames (kernels/rng.h RNG_JITTER)
JITTER = 0
#: the shade kernel's four uniforms: guide pair, BSDF pair (RNG_SHADING)
SHADING = 1
#: the stratified sampler's cell orders, one counter per pixel and pass (RNG_STRATA)
STRATA = 2
#: the bake's texel uniforms: point jitter, the reservoir's key, the sample (RNG_TEXEL, kernels/relight.cl)
TEXEL = 8
#: the bake's texel uniforms of the plastic coat's transfer (its second pass: RNG_TEXEL_COAT)
TEXEL_COAT = 9
#: the unbiased frame's mixture directions (wavlight.relight.converge): stream start + slot, one per slot
CONVERGE_DIRECTIONS = range(10, 10 + 64)
#: the unbiased frame's resampling: the candidates' uniforms and the picks among them
CONVERGE_RESAMPLE = 74
CONVERGE_PICK = 75
#: a moving-object frame (wavlight.relight.moving): the mixture's directions (kernels/relight_moving.cl
#: gets it as its ``stream`` argument; the counter's last word is the direction's number among its
#: camera sample's) and the shading uniforms of the pixels that may see the object
MOVING_DIRECTIONS = 76
MOVING_MIS = 77

#: every stream's ids by name: no two overlap
STREAMS = {name: value if isinstance(value, range) else range(value, value + 1) for name, value in (
    ("JITTER", JITTER), ("SHADING", SHADING), ("STRATA", STRATA), ("TEXEL", TEXEL), ("TEXEL_COAT", TEXEL_COAT),
    ("CONVERGE_DIRECTIONS", CONVERGE_DIRECTIONS), ("CONVERGE_RESAMPLE", CONVERGE_RESAMPLE),
    ("CONVERGE_PICK", CONVERGE_PICK), ("MOVING_DIRECTIONS", MOVING_DIRECTIONS), ("MOVING_MIS", MOVING_MIS))}

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


def words(seed: int, tile: int, stream: int, first: int, count: int) -> np.ndarray:
    """(count, 4) uint32: the Philox words of indices first .. first + count - 1 of a tile's stream."""
    counter = np.zeros((count, 4), np.uint32)
    counter[:, 0] = np.arange(first, first + count, dtype=np.uint64).astype(np.uint32)
    counter[:, 1] = tile
    counter[:, 2] = stream
    return philox4x32_10(counter, key(seed))


def uniforms(seed: int, tile: int, stream: int, first: int, count: int) -> np.ndarray:
    """(count, 4) float32 in [0, 1): the numbers of samples first .. first + count - 1 of a tile."""
    return (words(seed, tile, stream, first, count) >> np.uint32(8)).astype(np.float32) * np.float32(2.0 ** -24)


def step_uniforms(key: np.ndarray, step: int) -> np.ndarray:
    """numpy twin of kernels/rng.h step_uniform: float32 uniforms of step ``step`` for the
    uint32 ``key`` of each lane (lowbias32 of key + step * 0x9E3779B9)."""
    x = (key.astype(np.uint64) + np.uint64((step * 0x9E3779B9) & 0xFFFFFFFF)) & _MASK
    x ^= x >> np.uint64(16)
    x = (x * np.uint64(0x7FEB352D)) & _MASK
    x ^= x >> np.uint64(15)
    x = (x * np.uint64(0x846CA68B)) & _MASK
    x ^= x >> np.uint64(16)
    return (x >> np.uint64(8)).astype(np.float32) * np.float32(2.0 ** -24)


class Stream(NamedTuple):
    """The sampler's numbers of one pass of a tile: samples first, first + 1, ... of tile
    ``tile`` of a render with seed ``seed``; with ``k`` > 0 (the ``stratified`` sampler) the
    pass holds k samples of each pixel, pixel-major, and each pair is stratified over them."""

    seed: int
    tile: int
    first: int
    k: int = 0

    def uniforms(self, stream: int, count: int) -> np.ndarray:
        """(count, 4) float32: the pass's numbers in ``stream`` (JITTER: words 0, 1 the jitter;
        SHADING: the guide pair and the BSDF pair)."""
        u = uniforms(self.seed, self.tile, stream, self.first, count)
        if self.k:
            r = np.arange(count, dtype=np.uint32)
            pixel, j = r // np.uint32(self.k), r % np.uint32(self.k)
            keys = words(self.seed, self.tile, STRATA, self.first, int(pixel[-1]) + 1 if count else 0)[pixel]
            pairs = ((0, 0),) if stream == JITTER else ((0, 1), (2, 2))   # (first column, key word)
            for col, word in pairs:   # pairs, not samples
                u[:, col], u[:, col + 1] = stratify_pair(u[:, col], u[:, col + 1], j, self.k, keys[:, word])
        return u
