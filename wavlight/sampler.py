"""Pixel-sample generators: the uniform numbers behind each pixel sample.

Every pixel sample consumes six uniforms in three 2D pairs: the jitter inside the
pixel (box filter), the guide sample (light, product or the strategy's first
direction) and the BSDF sample. All are counter-based Philox-4x32-10 numbers, a
function of (seed, tile, sample index), drawn inside the camera and shade kernels
(:mod:`wavlight.rng`; nothing is generated on the host or uploaded). Scene key
``[render] sampler``, flag ``--sampler``:

``independent`` (default)
    Every number independent and uniform (Mitsuba 3's default ``independent`` sampler).
``stratified``
    Each 2D pair is stratified over the k samples of a pixel in one pass: the unit
    square is cut into an m x n grid (m = floor(sqrt(k)), n = ceil(k / m), so m n >= k)
    and sample j of the pixel takes cell ``permute(j, m n, key)`` (:func:`permute`, a
    random permutation chosen by a key per pixel, pass and pair) with its own Philox
    pair as the point inside the cell (:func:`stratify_pair`). So the k samples fill k
    distinct cells. Distinct pairs have independent keys ("padding", as pbrt's
    stratified sampler), so the pairs stay independent of each other. Each sample is
    uniform on the square by itself (a uniformly chosen cell, a uniform point in it),
    so every estimator stays unbiased. The hierarchical warps preserve stratification
    (paper sec. 4.3), so light and product samples come out stratified over their pdf.
    It costs no more than ``independent``: one more Philox draw per sample for the keys
    and the permutation's hash.

The integrator draws a pass's k samples of a pixel together, and a pass holds all
spp of a pixel up to ``integrator.TILE_SAMPLES / 64`` = 1024 spp; beyond that each
pass is stratified on its own. The per-pixel standard error is computed as for
independent samples; with ``stratified`` it is an upper bound (stratification only
removes variance between strata). This module holds the numpy twins of the kernels'
``permute_index`` and ``stratify_pair`` (kernels/rng.h); :class:`wavlight.rng.Stream`
applies them.
"""
from __future__ import annotations

import numpy as np

from .options import Option

SAMPLERS = ("independent", "stratified")
#: the render setting that chooses the sampler (every strategy draws its numbers through it)
SAMPLER = Option("sampler", str, "Pixel-sample uniforms: independent, or each 2D pair stratified over the "
                 "pixel's samples (wavlight.sampler).", default="independent", values=SAMPLERS)


def grid(k: int) -> tuple[int, int]:
    """(m, n): the m x n grid of cells a pixel's k samples are stratified over (m n >= k)."""
    m = max(1, int(np.floor(np.sqrt(k))))
    return m, -(-k // m)


def permute(i: np.ndarray, length: int, key: np.ndarray) -> np.ndarray:
    """Element i of the random permutation of 0 .. length - 1 chosen by key (uint32 arrays;
    Kensler 2013, "Correlated Multi-Jittered Sampling": a hash that is a bijection on the
    smallest power-of-two range holding length, walked until it lands below length), then
    rotated by (key >> 16) mod length (kernels/rng.h ``permute_index``)."""
    u32 = np.uint32
    i = np.array(i, u32)
    p = np.broadcast_to(np.asarray(key, u32), i.shape)
    w = length - 1
    for s in (1, 2, 4, 8, 16):
        w |= w >> s
    w = u32(w)
    out = i.copy()
    todo = np.arange(i.size)             # the entries still walking (flat), each round fewer
    i, pk = i.reshape(-1).copy(), p.reshape(-1)
    flat = out.reshape(-1)
    with np.errstate(over="ignore"):
        while len(todo):   # cycle-walking rounds (about 2 expected), not samples; as the kernel
            q = pk[todo]
            x = i[todo]
            x ^= q; x *= u32(0xe170893d); x ^= q >> u32(16); x ^= (x & w) >> u32(4)
            x ^= q >> u32(8); x *= u32(0x0929eb3f); x ^= q >> u32(23); x ^= (x & w) >> u32(1)
            x *= u32(1) | q >> u32(27); x *= u32(0x6935fa69); x ^= (x & w) >> u32(11); x *= u32(0x74dcb303)
            x ^= (x & w) >> u32(2); x *= u32(0x9e501cc3); x ^= (x & w) >> u32(2); x *= u32(0xc860a3df)
            x &= w; x ^= x >> u32(5)
            done = x < length
            flat[todo[done]] = x[done]
            i[todo] = x
            todo = todo[~done]
        return (out + (p >> u32(16)) % u32(length)) % u32(length)


def stratify_pair(a: np.ndarray, b: np.ndarray, j: np.ndarray, k: int, key: np.ndarray):
    """Uniforms (a, b) float32 of sample j of a pixel's k -> the point (a, b) of cell
    permute(j, m n, key) of the m x n grid (kernels/rng.h ``stratify_pair``), float32 below 1."""
    m, n = grid(k)
    cell = permute(j, m * n, key)
    top = np.float32(1.0 - 2.0 ** -24)
    x = np.minimum(((cell % m).astype(np.float32) + np.asarray(a, np.float32)) / np.float32(m), top)
    y = np.minimum(((cell // m).astype(np.float32) + np.asarray(b, np.float32)) / np.float32(n), top)
    return x, y
