"""The pinhole camera: rays through uniformly jittered points of the pixels (box filter).

:func:`camera_rays` is the numpy version for given jitters (tests);
:func:`pass_rays` makes the rays of one pass of a tile with the sampler's jitters
(Philox stream ``rng.JITTER``, stratified per pixel with the ``stratified`` sampler:
:mod:`wavlight.sampler`), in the ``camera_rays`` kernel (``kernels/camera.cl``) or,
with ``kernel=False``, in numpy with the same numbers.
"""
from __future__ import annotations

import numpy as np

from . import cl, rng

_WARMED = set()

#: a pass's rays (the kernels find a ray's pixel and sample index by one float division,
#: kernels/rng.h ``div_small``, exact below 2^22); the integrator's passes hold about
#: integrator.TILE_SAMPLES = 2^16
MAX_PASS_RAYS = 1 << 22


def _basis(cam, width, height):
    """fwd, right, up (3,) and the float32 affine constants sx, sy, ox, oy of the image plane:
    x = (px + jx) sx - ox, y = oy - (py + jy) sy (row 0 at the top)."""
    fwd = cam.target - cam.eye
    fwd = fwd / np.linalg.norm(fwd)
    right = np.cross(fwd, cam.up)
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    tan = np.tan(np.radians(cam.fov_y) * 0.5)
    consts = np.float32([2.0 * tan * (width / height) / width, 2.0 * tan / height, tan * width / height, tan])
    return fwd.astype(np.float32), right.astype(np.float32), up.astype(np.float32), consts


def camera_rays(scene, px: np.ndarray, py: np.ndarray, jitter: np.ndarray, width, height):
    """Pinhole rays through points (px + jx, py + jy) of the image plane.

    px, py : (N,) pixel column and row (row 0 at the top); jitter : (N, 2) in [0, 1)
    returns origins (N, 3) (a broadcast view of the eye), unit directions (N, 3), float32
    """
    fwd, right, up, (sx, sy, ox, oy) = _basis(scene.camera, width, height)
    x = (np.asarray(px, np.float32) + jitter[:, 0].astype(np.float32)) * sx - ox
    y = oy - (np.asarray(py, np.float32) + jitter[:, 1].astype(np.float32)) * sy
    d = np.empty((len(x), 3), np.float32)
    for c in range(3):  # components, not pixels: three vectorised lines
        d[:, c] = fwd[c] + x * right[c] + y * up[c]
    d /= np.sqrt(np.einsum("ij,ij->i", d, d))[:, None]
    return np.broadcast_to(scene.camera.eye.astype(np.float32), d.shape), d


def project(cam, points: np.ndarray, width, height):
    """Image-plane coordinates of world points, the inverse of :func:`camera_rays`: (N, 2) float64
    (column, row; a point seen by a sample of pixel (i, j) lies in [i, i + 1) x [j, j + 1)) and
    each point's depth along the view direction (N,) (<= 0: behind the eye)."""
    fwd, right, up, (sx, sy, ox, oy) = (np.asarray(a, np.float64) for a in _basis(cam, width, height))
    q = np.asarray(points, np.float64) - np.asarray(cam.eye, np.float64)
    z = q @ fwd
    with np.errstate(divide="ignore", invalid="ignore"):
        x, y = (q @ right) / z, (q @ up) / z
    return np.stack([(x + ox) / sx, (oy - y) / sy], 1), z


def pass_rays(scene, width, height, seed, tile, x0, y0, w, h, k, first, kernel=True,
              stratified=False) -> np.ndarray:
    """(w h k, 3) float32 directions of one pass: k samples of each pixel of the w x h tile at
    (x0, y0), pixel-major, with jitters from Philox stream JITTER at tile sample indices
    first .. first + w h k - 1 (``stratified``: stratified over each pixel's k samples,
    ``rng.Stream(seed, tile, first, k)``)."""
    count = w * h * k
    if count >= MAX_PASS_RAYS:
        raise ValueError(f"camera.pass_rays: a pass holds at most {MAX_PASS_RAYS - 1} rays, "
                         f"got {count}")
    if not kernel:
        pix = np.arange(w * h, dtype=np.int32)
        jitter = rng.Stream(seed, tile, first, k if stratified else 0).uniforms(rng.JITTER, count)
        return camera_rays(scene, np.repeat(x0 + pix % w, k), np.repeat(y0 + pix // w, k), jitter, width, height)[1]
    fwd, right, up, consts = _basis(scene.camera, width, height)
    q = cl.thread_queue()
    out = cl.scratch("camera_dirs", 12 * count)
    prog = cl.program("camera.cl")
    cl.kernel(prog, "camera_rays")(
        q, (cl.items(count, cl.LANES),), (cl.WORK_GROUP,), np.int32(x0), np.int32(y0), np.uint32(w), np.uint32(k),
        np.uint32(count), np.uint32(first), np.uint32(tile), *(np.uint32(x) for x in rng.key(seed)),
        np.int32(bool(stratified)), *fwd, *right, *up, *consts, out)
    return cl.read(out, (count, 3), np.float32, q)


def warm_up(scene):
    """A tiny and a large launch of the camera kernel (PoCL compiles per work-group size and
    again for large grids; see shading.KernelShader.warm_up), once per process."""
    if "camera" in _WARMED:
        return
    for side in (1, 64):
        pass_rays(scene, 64, 64, 0, 0, 0, 0, side, side, 16, 0)
    _WARMED.add("camera")
