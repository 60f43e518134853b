"""Pixel-sample generators: the uniform numbers behind each pixel sample.

Every pixel sample consumes six uniforms in three 2D pairs: the jitter inside the
pixel (box filter), the guide sample (light, product or the strategy's first
direction) and the BSDF sample. Scene key ``[render] sampler``, flag ``--sampler``:

``independent`` (default)
    Every number independent and uniform (Mitsuba 3's default ``independent``
    sampler): counter-based Philox-4x32-10 numbers, a function of (seed, tile,
    sample index), drawn inside the camera and shade kernels (:mod:`wavlight.rng`).
``stratified``
    :func:`stratified` returns all six for ``k`` samples of each of ``P`` pixels,
    pixel-major (row ``p k + j`` is sample ``j`` of pixel ``p``), as ``(P k, 6)`` float32.
    Each 2D pair is stratified over the k samples of a pixel: the unit square is cut
    into an m x n grid (m = floor(sqrt(k)), n = ceil(k / m), so m n >= k), every pixel
    and every pair draws k distinct cells at random and one uniform point in each.
    Distinct pairs use independent cell orders ("padding", pbrt's stratified
    sampler), so the pairs stay independent of each other. Each sample is uniform on
    the square by itself (a uniformly chosen cell, a uniform point in it), so every
    estimator stays unbiased. The hierarchical warps preserve stratification (paper
    sec. 4.3), so light and product samples come out stratified over their pdf.

The integrator draws a pass's k samples of a pixel together, and a pass holds all
spp of a pixel up to ``integrator.TILE_SAMPLES / 64`` = 1024 spp; beyond that each
pass is stratified on its own. The per-pixel standard error is computed as for
independent samples; with ``stratified`` it is an upper bound (stratification only
removes variance between strata).
"""
from __future__ import annotations

import numpy as np

SAMPLERS = ("independent", "stratified")
DIMENSIONS = 6  # jitter (2), guide sample (2), BSDF sample (2)


def stratified_pairs(rng: np.random.Generator, pixels: int, k: int, pairs: int) -> np.ndarray:
    """(pixels k, 2 pairs) float64: per pixel and pair, k points in k distinct cells of an m x n grid."""
    m = max(1, int(np.floor(np.sqrt(k))))
    n = -(-k // m)
    out = np.empty((pixels, k, 2 * pairs))
    for d in range(pairs):  # pairs, not samples: 3 iterations
        # k distinct cells of m n per pixel: the first k of a random permutation (argsort of keys)
        cells = np.argsort(rng.random((pixels, m * n)), axis=1)[:, :k]
        cx, cy = cells % m, cells // m
        jitter = rng.random((pixels, k, 2))
        out[:, :, 2 * d] = (cx + jitter[..., 0]) / m
        out[:, :, 2 * d + 1] = (cy + jitter[..., 1]) / n
    return out.reshape(pixels * k, 2 * pairs)


def stratified(rng: np.random.Generator, pixels: int, k: int) -> np.ndarray:
    """(pixels k, 6) float32 uniforms in [0, 1), pixel-major, each pair stratified per pixel."""
    u = stratified_pairs(rng, pixels, k, DIMENSIONS // 2).astype(np.float32)
    # (c + j) / m can round up to 1.0 in float32: keep every number below 1
    return np.minimum(u, np.float32(1.0 - 2.0 ** -24))
