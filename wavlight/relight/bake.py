"""The bake: each pixel's transfer T1 = f_r cos V on the world-frame lat-long square, the fixed
factor of a relit frame (Chen & Gao sec. 2.2, eq. 6-8, with the lighting as T2).

For pixel p with camera samples s = 1..S (jittered in the pixel, stratified over it) and
texel t of solid angle Omega_t,

    T_p,t = (1 / S) sum_s  ratio_s  integral over t of  f_s(w, wo_s) cos(theta) V(x_s, w) dw,

f without its albedo (lambert, normalized phong and the ggx conductor here are albedo x shape),
the pixel's albedo a_p stored apart (the mean albedo of its samples that hit; ratio_s =
lum(albedo_s) / lum(a_p), so that luminance is exact where a pixel mixes materials and only
its chroma is the mean's). A frame is then a_p sum_t T_p,t L_t with L_t the lighting's mean
radiance over texel t (:mod:`wavlight.relight.lighting`), plus (1 / S) sum over the samples
that miss of the environment in their direction (a bit mask per pixel; the frame draws the
same camera samples again).

Estimator (kernels/relight.cl, bake_texel_rays; numpy twin :func:`texel_rays_reference`):
one shadow ray per (pixel, texel) pair. The pixel's samples are grouped by the triangle they
hit (one normal and material per group: :class:`PixelSamples`); the texel gets four points
stratified 2 x 2 and uniform in solid angle; f cos is evaluated for every group at every point
(weighted by the group's share of the pixel's samples), and the ray goes from a sample of the
group picked with probability f / sum f towards its point; the estimate Omega_t (sum f / 4) V
is unbiased for the pixel's mean of the texel's four-point quadrature of f cos V over its
footprint, and exact where V is the same over texel and pixel: only the visibility's variance is
left, and the cost grows with the triangles a pixel sees, not with its samples. Texels where
the BRDF is 0 (below the horizon, outside a phong lobe) cost no ray. The texels then go
through the Haar transform (:func:`wavlight.haar.forward_cl`), and a block of BLOCK x BLOCK
pixels is compressed and quantized (:mod:`wavlight.relight.store`).
"""
from __future__ import annotations

import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from .. import bsdfs, cl, haar, rng
from ..camera import camera_rays
from ..envmap import LUMINANCE
from ..errors import ArgumentError, check_int, check_number, shown
from ..integrator import render_full
from ..raytrace import RayTracer
from ..scene import MAX_SIDE, check_scene, load_scene
from ..warp import frame as tangent_frame
from . import lighting, store
from .dask import bake_on_cluster
from .transfer import finish_bake

#: Philox stream of the bake's texel uniforms (kernels/relight.cl RNG_TEXEL)
TEXEL_STREAM = 8
#: a block is BLOCK x BLOCK pixels: one tile of the bake, one unit of storage
BLOCK = 16


@dataclass
class PixelSamples:
    """The camera samples of a tile's P pixels, S each, and their groups.

    A group is the samples of one pixel that hit one triangle (one normal, one material: f
    depends on the sample only through its view direction, whose spread over a pixel is
    negligible), so a texel needs one BRDF evaluation per group and point, not per sample.
    Group j of pixel p sits at p S + j (count[p] of them): normal, wo (its members' mean
    view direction), kind, param, weight (sum of its members' albedo ratios / S), first and
    size (its members: members[p S + first .. + size - 1], sample indices p S + s).

    origin (P S, 3) float32: each sample's shadow-ray origin; albedo (P, 3) float32 a_p;
    miss (P,) uint64, bit s set where sample s misses; dirs (P S, 3) float32 the samples'
    directions.
    """

    samples: int
    count: np.ndarray
    normal: np.ndarray
    wo: np.ndarray
    kind: np.ndarray
    param: np.ndarray
    weight: np.ndarray
    first: np.ndarray
    size: np.ndarray
    members: np.ndarray
    origin: np.ndarray
    albedo: np.ndarray
    miss: np.ndarray
    dirs: np.ndarray

    def __len__(self):
        return len(self.albedo)


def camera_jitter(seed: int, tile: int, pixels: int, samples: int) -> np.ndarray:
    """(P S, 2) float32: the jitters of a tile's camera samples (Philox stream JITTER, stratified
    over each pixel's S samples as the stratified sampler does, :mod:`wavlight.sampler`)."""
    return rng.Stream(seed, tile, 0, samples).uniforms(rng.JITTER, pixels * samples)[:, :2]


def camera_samples(scene, tracer, width, height, x0, y0, w, h, samples: int, seed: int, tile: int) -> PixelSamples:
    """S jittered camera samples per pixel of the w x h tile at (x0, y0), traced to their hits
    and grouped by pixel and triangle."""
    P, S = w * h, samples
    count = P * S
    pix = np.arange(P)
    px, py = np.repeat(x0 + pix % w, S), np.repeat(y0 + pix // w, S)
    eye, d = camera_rays(scene, px, py, camera_jitter(seed, tile, P, S), width, height)
    prim, t = tracer.intersect(eye, d)
    hit = prim >= 0
    normal = np.zeros((count, 3), np.float32)
    origin = np.zeros((count, 3), np.float32)
    if hit.any():
        n, _, o = tracer.surface(scene.camera.eye, d[hit], t[hit], prim[hit])
        normal[hit], origin[hit] = n, o
    mat = np.where(hit, scene.face_material[np.maximum(prim, 0)] if len(scene.face_material) else 0, 0)
    albedo_s = np.where(hit[:, None], scene.material_albedo[mat], 0.0)
    hits = hit.reshape(P, S).sum(1)
    albedo = (albedo_s.reshape(P, S, 3).sum(1) / np.maximum(hits, 1)[:, None]).astype(np.float32)
    lum_p = np.repeat(albedo @ LUMINANCE, S)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(lum_p > 0, (albedo_s @ LUMINANCE) / lum_p, 0.0)
    # groups: a pixel's hits on one triangle, in order of (pixel, triangle)
    sample = np.arange(count)
    live = sample[hit]
    order = live[np.lexsort((prim[live], live // S))]
    pixel_of = order // S
    new = np.ones(len(order), bool)
    new[1:] = (pixel_of[1:] != pixel_of[:-1]) | (prim[order][1:] != prim[order][:-1])
    starts = np.flatnonzero(new)
    sizes = np.diff(np.append(starts, len(order)))
    gpix = pixel_of[starts]
    rank = np.arange(len(starts)) - np.searchsorted(gpix, gpix)     # the group's index in its pixel
    slot = gpix * S + rank
    group_count = np.bincount(gpix, minlength=P).astype(np.uint32)
    members = np.zeros(count, np.uint32)
    within = np.arange(len(order)) - np.repeat(starts, sizes)        # position inside the group
    members[np.repeat(gpix * S, sizes) + np.repeat(starts - np.searchsorted(pixel_of, gpix), sizes) + within] = order
    first = np.zeros(count, np.uint32)
    first[slot] = starts - np.searchsorted(pixel_of, gpix)
    size = np.zeros(count, np.uint32)
    size[slot] = sizes
    g_normal = np.zeros((count, 3), np.float32)
    g_normal[slot] = normal[order[starts]]
    wo_sum = np.add.reduceat(-d[order].astype(np.float64), starts, axis=0) if len(order) else np.zeros((0, 3))
    g_wo = np.zeros((count, 3), np.float32)
    g_wo[slot] = wo_sum / np.linalg.norm(wo_sum, axis=1, keepdims=True)
    g_kind = np.zeros(count, np.int32)
    g_kind[slot] = scene.material_kind[mat[order[starts]]]
    g_param = np.zeros(count, np.float32)
    g_param[slot] = scene.material_param[mat[order[starts]]]
    g_weight = np.zeros(count, np.float32)
    g_weight[slot] = (np.add.reduceat(ratio[order], starts) if len(order) else np.zeros(0)) / S
    missed = (~hit).reshape(P, S).astype(np.uint64)
    mask = (missed << np.arange(S, dtype=np.uint64)).sum(1, dtype=np.uint64)
    return PixelSamples(S, group_count, g_normal, g_wo, g_kind, g_param, g_weight, first, size, members,
                        origin, albedo, mask, d)


#: points per texel where f cos is evaluated (kernels/relight.cl TEXEL_POINTS): 4 (2 x 2 strata) or 1
POINT_CHOICES = (1, 4)
#: a BRDF lobe narrower than this many texels (in theta) gets four points per texel
NARROW_LOBE_TEXELS = 3.0


def lobe_width(kind: int, param: float) -> float:
    """A BRDF lobe's angular width, radians: lambert's hemisphere pi / 2, phong's 1 / sqrt(n + 1)
    (its cos^n falls to 1/e there), ggx's 2 alpha (the reflected lobe is about twice the
    microfacet distribution's width)."""
    if kind == bsdfs.PHONG:
        return 1.0 / np.sqrt(param + 1.0)
    if kind == bsdfs.GGX:
        return 2.0 * param
    return np.pi / 2


def texel_points(scene, n_levels: int) -> int:
    """Points per texel a scene needs: four where a lobe is narrower than NARROW_LOBE_TEXELS
    texels (f cos then varies inside one), one otherwise."""
    texel = np.pi / (1 << n_levels)
    narrow = [lobe_width(m.kind, m.param) < NARROW_LOBE_TEXELS * texel for m in scene.materials]
    return 4 if any(narrow) else 1


def texel_rays_reference(ps: PixelSamples, n_levels: int, seed: int, tile: int, first: int = 0,
                         count: int | None = None, points: int = 4):
    """numpy twin of ``bake_texel_rays``: directions (C, 3), weights (C,) and the picked samples
    (C,) of pairs first .. first + C - 1 (float64; the kernel's float32 agrees to rounding and
    picks the same point unless a reservoir step lies within rounding of its threshold)."""
    side, S = 1 << n_levels, ps.samples
    count = len(ps) * side * side - first if count is None else count
    g = np.arange(first, first + count, dtype=np.int64)
    p, t = g >> (2 * n_levels), g & (side * side - 1)
    row, col = t >> n_levels, t & (side - 1)
    u = rng.uniforms(seed, tile, TEXEL_STREAM, first, count).astype(np.float64)
    z0, z1 = np.cos(np.pi * row / side), np.cos(np.pi * (row + 1) / side)
    directions = []
    grid = 2 if points == 4 else 1
    for q in range(points):   # the texel's strata, not pairs
        uu = (col + ((q % grid) + u[:, 0]) / grid) / side
        zz = z0 + ((q // grid) + u[:, 1]) / grid * (z1 - z0)
        sn = np.sqrt(np.maximum(1.0 - zz * zz, 0.0))
        directions.append(np.stack([np.sin(2 * np.pi * uu) * sn, zz, -np.cos(2 * np.pi * uu) * sn], 1))
    total = np.zeros(count)
    r = u[:, 2].copy()
    pick_dir = directions[0].copy()
    picked = p * S
    groups = ps.count[p]
    for j in range(int(ps.count.max(initial=0))):   # groups, not pairs
        on = j < groups
        gj = p * S + j
        n = ps.normal[gj].astype(np.float64)
        sx, tx = tangent_frame(np.where(on[:, None], n, [0.0, 0.0, 1.0]))
        wo_w = ps.wo[gj].astype(np.float64)
        wo = np.stack([np.einsum("ij,ij->i", wo_w, a) for a in (sx, tx, n)], 1)
        kind, param, c = ps.kind[gj], ps.param[gj].astype(np.float64), ps.weight[gj].astype(np.float64)
        for d in directions:   # the texel's points, not pairs
            wi = np.stack([np.einsum("ij,ij->i", d, a) for a in (sx, tx, n)], 1)
            f = np.zeros(count)
            for kd in np.unique(kind[on]):   # material kinds, not pairs
                sel = on & (kind == kd)
                f[sel] = bsdfs.eval_cos(int(kd), param[sel], wi[sel], wo[sel])
            f = np.where(on & np.isfinite(f) & (f > 0), f * c, 0.0)
            grown = total + f
            x = r * grown
            take = x < f
            with np.errstate(divide="ignore", invalid="ignore"):
                r = np.where(take, x / np.where(f > 0, f, 1.0), np.where(total > 0, (x - f) / np.where(total > 0, total, 1.0), r))
            r = np.clip(r, 0.0, 1.0 - 2.0 ** -24)
            pick_dir = np.where(take[:, None], d, pick_dir)
            picked = np.where(take, gj, picked)
            total = grown
    size = np.maximum(ps.size[picked].astype(np.int64), 1)
    k = np.minimum((u[:, 3].astype(np.float32) * size.astype(np.float32)).astype(np.int64), size - 1)
    sample = ps.members[p * S + ps.first[picked].astype(np.int64) + k]
    omega = (z0 - z1) * 2 * np.pi / side
    weight = np.where(total > 0, omega * total / points, 0.0)
    return pick_dir, weight, sample.astype(np.int64)


def texel_rays(ps: PixelSamples, n_levels: int, seed: int, tile: int, bsdf_kinds: int = 7, queue=None,
               points: int = 4):
    """The kernel ``bake_texel_rays`` over all of a tile's (pixel, texel) pairs: directions
    (P 4^n, 3), weights (P 4^n,) float32 and the picked samples (P 4^n,) uint32. ``bsdf_kinds``:
    the bit mask of the material kinds the scene has (the kernel evaluates only those)."""
    count = len(ps) << (2 * n_levels)
    queue = queue or cl.thread_queue()
    prog = cl.program("relight.cl", BSDF_KINDS=int(bsdf_kinds), TEXEL_POINTS=int(points))
    # the thread's reusable buffers: a fresh 20 MB a tile cost PoCL allocations and page faults
    dirs, weights, picks = (cl.scratch(f"bake_{name}", size * count) for name, size in
                            (("dirs", 12), ("weights", 4), ("picks", 4)))
    k0, k1 = rng.key(seed)
    cl.kernel(prog, "bake_texel_rays")(
        queue, (cl.items(count, cl.LANES),), (cl.WORK_GROUP,), np.uint32(count), np.uint32(0),
        np.uint32(n_levels), np.uint32(ps.samples), np.uint32(tile), np.uint32(k0), np.uint32(k1),
        *(cl.to_device(a) for a in (ps.count, ps.normal, ps.wo, ps.kind, ps.param, ps.weight, ps.first, ps.size,
                                    ps.members)), dirs, weights, picks)
    return (cl.read(dirs, (count, 3), np.float32, queue), cl.read(weights, (count,), np.float32, queue),
            cl.read(picks, (count,), np.uint32, queue))


def tile_transfer(ps: PixelSamples, tracer, n_levels: int, seed: int, tile: int, backend: str = "opencl",
                  bsdf_kinds: int = 7, points: int = 4):
    """(P, N, N) float32 texel transfer of a tile's pixels (module docstring) and the number of
    shadow rays it traced."""
    if backend == "opencl":
        dirs, weight, pick = texel_rays(ps, n_levels, seed, tile, bsdf_kinds, points=points)
    else:
        dirs, weight, pick = texel_rays_reference(ps, n_levels, seed, tile, points=points)
    live = np.flatnonzero(weight > 0)
    blocked = tracer.occluded(np.take(ps.origin, pick[live].astype(np.int64), axis=0), np.take(dirs, live, axis=0))
    out = np.zeros(len(weight), np.float32)
    out[live] = np.where(blocked, 0.0, weight[live])
    side = 1 << n_levels
    return out.reshape(-1, side, side), len(live)


# ----------------------------------------------------------------------------- the whole image
#: the held-out lighting of a bake: the scene's map turned this far from its own rotation (no
#: frame is likely to test exactly there), on which compression and terms are measured
HELD_OUT_DEGREES = 137.0
MAX_SAMPLES = 64
BITS = (8, 16)


def _tiles(width: int, height: int):
    """(block id, x0, y0, w, h) of the BLOCK x BLOCK tiles, row-major."""
    bw, bh = -(-width // BLOCK), -(-height // BLOCK)
    return [(by * bw + bx, bx * BLOCK, by * BLOCK, min(BLOCK, width - bx * BLOCK), min(BLOCK, height - by * BLOCK))
            for by in range(bh) for bx in range(bw)], (bw, bh)


def _padded(values: np.ndarray, w: int, h: int):
    """A tile's per-pixel rows (w h, ...) placed in the block's BLOCK x BLOCK grid (zeros elsewhere)."""
    out = np.zeros((BLOCK, BLOCK) + values.shape[1:], values.dtype)
    out[:h, :w] = values.reshape((h, w) + values.shape[1:])
    return out.reshape((BLOCK * BLOCK,) + values.shape[1:])


@dataclass
class Settings:
    """What a bake is made with: size, camera samples, texel levels, compression, the held-out
    lighting (4^n, 3) coefficients times N^2 (:mod:`.frame`), seed, backend."""

    width: int
    height: int
    spp: int
    n_levels: int
    tolerance: float
    bits: int
    held_out: np.ndarray
    seed: int
    backend: str = "opencl"
    points: int = 4
    #: a bake that varies one object: the levels of each pixel's product T1 x L (coarse texels)
    #: and the fixed lighting's mean luminance on them, (2^m, 2^m)
    product_levels: int | None = None
    product_luminance: np.ndarray | None = None


class _Worker:
    """A scene's ray tracer and material mask, made once per process (or thread pool)."""

    def __init__(self, scene):
        self.scene = scene
        self.tracer = RayTracer(scene.vertices, scene.faces, threads=1)
        self.kinds = int(np.bitwise_or.reduce(1 << np.unique(scene.material_kind))) if len(scene.materials) else 1


def bake_block(worker: _Worker, settings: Settings, tile) -> dict:
    """One block of the bake: its texels' transfer, Haar coefficients, compressed and quantized
    (a pure function of the scene, the settings and the tile: any process computes the same)."""
    block_id, x0, y0, w, h = tile
    s = settings
    ps = camera_samples(worker.scene, worker.tracer, s.width, s.height, x0, y0, w, h, s.spp, s.seed, block_id)
    texels, rays = tile_transfer(ps, worker.tracer, s.n_levels, s.seed, block_id, s.backend, worker.kinds, s.points)
    coeffs = haar.forward(texels)   # numpy's is the faster here: one tile, no transfers to the device
    side2 = 4 ** s.n_levels
    coeffs = _padded(np.asarray(coeffs, np.float32).reshape(w * h, side2), w, h)
    cols, scales, q, e2, n2 = store.compress_block(coeffs, s.held_out, s.tolerance, s.bits,
                                                   np.random.default_rng([s.seed, block_id]))
    some = np.flatnonzero(ps.miss)
    c64 = coeffs.astype(np.float64)
    result = {"tile": tile, "columns": cols, "scales": scales, "data": q, "error2": e2, "norm2": n2,
              "albedo": ps.albedo.reshape(h, w, 3), "rays": rays, "sum_sq": np.einsum("pc,pc->c", c64, c64),
              "background": ((y0 + some // w) * s.width + x0 + some % w, ps.miss[some],
                             ps.dirs.reshape(-1, s.spp, 3)[some])}
    if s.product_levels is not None:   # T1 x L on coarse texels (exact: texels add up)
        m, k = s.product_levels, 1 << (s.n_levels - s.product_levels)
        coarse = texels.reshape(w * h, 1 << m, k, 1 << m, k).sum(axis=(2, 4))
        result["product"] = (coarse * s.product_luminance).reshape(w * h, -1).astype(np.float16)
    return result


_WORKERS = {}   # per process: (scene path, content hash) -> _Worker


def bake_block_task(task: dict) -> dict:
    """:func:`bake_block` for a worker process (dask.distributed): the scene by path, checked by
    its content hash, loaded once per process."""
    key = (task["scene_path"], task["content_hash"], task.get("without"))
    worker = _WORKERS.get(key)
    if worker is None:
        scene = load_scene(task["scene_path"])
        if scene.content_hash != task["content_hash"]:
            raise ArgumentError(f"{task['scene_path']}: this worker sees another scene than the bake read")
        if task.get("without") is not None:
            scene = scene.without(scene.find_object(task["without"]))
        worker = _WORKERS[key] = _Worker(scene)
    return bake_block(worker, task["settings"], task["tile"])


#: the pilot bake that chooses texel levels, terms and priority: this many pixels on its longer
#: side, at most PILOT_LEVELS texel levels
PILOT_SIDE = 32
PILOT_LEVELS = 7
TERM_CHOICES = (32, 64, 128, 256, 512, 1024, 2048, 4096)


def choose_model(scene, tolerance: float, spp: int, seed: int, levels=None, terms=None, priority=None,
                 backend: str = "opencl") -> dict:
    """The texel levels n, the terms K and their priority a scene needs for ``tolerance``, from
    a pilot bake of PILOT_SIDE pixels at 2^PILOT_LEVELS texels, measured on the held-out
    rotation: n, the smallest whose frame is within tolerance / sqrt(3) of the finest (texels
    summed 2 x 2 are exact coarser texels); K, the fewest (of TERM_CHOICES) within tolerance /
    sqrt(3) of all terms, by the priority with the lower error at K = 256. Given values are
    kept. Returns the choices and the errors measured."""
    if levels is not None and terms is not None and priority is not None:   # nothing left to choose
        return {"n_levels": int(levels), "terms": int(terms), "priority": priority, "pilot": None}
    share = tolerance / np.sqrt(3.0)
    env = scene.environment
    aspect = scene.width / scene.height
    pw, ph = (PILOT_SIDE, max(1, round(PILOT_SIDE / aspect))) if aspect >= 1 else (max(1, round(PILOT_SIDE * aspect)), PILOT_SIDE)
    top = PILOT_LEVELS if levels is None else levels
    worker = _Worker(scene)
    tiles, _ = _tiles(pw, ph)
    rot = env.rotate_y + HELD_OUT_DEGREES
    texels = []
    for tile in tiles:   # a few blocks, not pixels
        _, x0, y0, w, h = tile
        ps = camera_samples(scene, worker.tracer, pw, ph, x0, y0, w, h, spp, seed + 1, tile[0])
        texels.append(tile_transfer(ps, worker.tracer, top, seed + 1, tile[0], backend, worker.kinds,
                                    texel_points(scene, top))[0])
    T = np.concatenate(texels).astype(np.float64)                     # (P, 2^top, 2^top)
    lum = LUMINANCE.astype(np.float64)
    frames, level_error = {}, {}
    for n in range(top, 3, -1):   # levels, not pixels
        k = 1 << (top - n)
        Tn = T.reshape(len(T), 1 << n, k, 1 << n, k).sum(axis=(2, 4))
        Ln = lighting.project(env, n, rot) @ lum
        frames[n] = np.einsum("pij,ij->p", Tn, Ln)
    ref = frames[top]
    norm = np.linalg.norm(ref)
    for n, f in frames.items():
        level_error[n] = float(np.linalg.norm(f - ref) / norm) if norm > 0 else 0.0
    n = levels if levels is not None else min(k for k, e in level_error.items() if e <= share)
    k = 1 << (top - n)
    Tn = T.reshape(len(T), 1 << n, k, 1 << n, k).sum(axis=(2, 4))
    coeffs_t = haar.forward(Tn).reshape(len(T), -1)                      # (P, 4^n)
    rms = np.sqrt((coeffs_t ** 2).mean(0))
    L = lighting.coefficients(lighting.project(env, n, rot))              # (3, N, N)
    full = coeffs_t @ (np.tensordot(lum, L, axes=1).ravel() * 4.0 ** n)
    fnorm = np.linalg.norm(full)

    def error(kk, pr):
        cols = lighting.select_terms(L, kk, pr, rms)
        part = coeffs_t[:, cols] @ (np.tensordot(lum, L, axes=1).ravel()[cols] * 4.0 ** n)
        return float(np.linalg.norm(part - full) / fnorm) if fnorm > 0 else 0.0

    if priority is None:
        priority = min(("transfer", "area"), key=lambda pr: (error(256, pr), pr != "transfer"))
    term_error = {kk: error(kk, priority) for kk in TERM_CHOICES if kk <= 4 ** n}
    if terms is None:
        fits = [kk for kk, e in term_error.items() if e <= share]
        terms = fits[0] if fits else max(term_error)
    return {"n_levels": int(n), "terms": int(terms), "priority": priority,
            "pilot": {"size": [pw, ph], "levels": top, "held_out_rotate_y": rot,
                      "level_error": {str(k): round(v, 5) for k, v in level_error.items()},
                      "term_error": {str(k): round(v, 5) for k, v in term_error.items()}}}


#: the factors a bake of per-pixel transfer varies (a bake that varies the view: relight/view.py)
PIXEL_VARY = ("lighting", "object")
#: a bake that varies one object: each pixel's product T1 x L on 2^OBJECT_PRODUCT_LEVELS texels,
#: and the scene without the object converged with this many samples per pixel
OBJECT_PRODUCT_LEVELS = 4
STATIC_SPP = 256


def bake(scene, output=None, width=None, height=None, spp: int = 16, levels=None, tolerance: float = 0.02,
         bits: int = 8, terms=None, priority=None, seed: int = 0, threads=None, progress=None,
         backend: str = "opencl", dask_address=None, points=None, vary: str = "lighting", object=None,
         static_spp: int = STATIC_SPP):
    """Bake the transfer of ``scene`` (a Scene or a scene file) for its camera at width x height
    (default: the scene's) with ``spp`` camera samples per pixel; write it to ``output``
    (default: a temporary file the Transfer owns) and return the :class:`Transfer`.

    The texel levels (2^n x 2^n), the default terms K and their priority are chosen from the
    scene for ``tolerance`` by a pilot bake (:func:`choose_model`) unless given; each block is
    compressed to ``tolerance`` / sqrt(3) on the held-out lighting and quantized to ``bits``.
    ``points`` per texel (1 or 4) default to :func:`texel_points`.

    ``vary="object"`` with ``object`` (a name or an index) bakes for frames in which that object
    moves (:mod:`wavlight.relight.moving`): the transfer of the scene without it (camera rays and
    shadows alike), each pixel's product T1 x L of that transfer and the scene's fixed lighting on
    2^OBJECT_PRODUCT_LEVELS texels, and the scene without it converged with ``static_spp``
    samples per pixel (the ``wavelet`` strategy; unbiased).
    (A bake that varies the view is :func:`wavlight.relight.view.bake_view`; :func:`wavlight.bake`
    takes all three.)
    ``progress(done, total, rays, seconds)`` after each block. ``dask_address``: bake the
    blocks on that dask.distributed scheduler (the workers read the scene file at the same
    path); the file is identical to a local bake's."""
    where = "relight.bake"
    if isinstance(scene, (str, os.PathLike)):
        scene = load_scene(scene)
    check_scene(scene)
    width = check_int(where, "width", scene.width if width is None else width, 1, MAX_SIDE)
    height = check_int(where, "height", scene.height if height is None else height, 1, MAX_SIDE)
    spp = check_int(where, "spp", spp, 1, MAX_SAMPLES)
    if levels is not None:
        levels = check_int(where, "levels", levels, 2, 8)
    if terms is not None:
        terms = check_int(where, "terms", terms, 1, 1 << 22)
    if priority is not None and priority not in lighting.PRIORITIES:
        raise ArgumentError(f"{where}: priority must be one of {' | '.join(lighting.PRIORITIES)}, got {priority!r}")
    tolerance = check_number(where, "tolerance", tolerance, 1e-6, 1.0)
    if bits not in BITS:
        raise ArgumentError(f"{where}: bits must be 8 or 16, got {bits!r}")
    seed = check_int(where, "seed", seed, 0, 2 ** 62)
    if points is not None and points not in POINT_CHOICES:
        raise ArgumentError(f"{where}: points must be 1 or 4, got {points!r}")
    if vary not in PIXEL_VARY:
        raise ArgumentError(f"{where}: vary must be one of {' | '.join(PIXEL_VARY)}, got {shown(vary)}")
    if scene.environment.is_black:
        raise ArgumentError(f"{scene.path}: [environment]: the environment is black everywhere; nothing to relight")
    full, moving = scene, None
    if vary == "object":
        if object is None:
            raise ArgumentError(f"{where}: vary='object' needs the object that moves (a name or an index)")
        moving = scene.find_object(object)
        scene = scene.without(moving)
        static_spp = check_int(where, "static_spp", static_spp, 2, 1 << 20)
    elif object is not None:
        raise ArgumentError(f"{where}: an object is given only with vary='object'")
    if dask_address is not None and scene.path == "<dict>":
        raise ArgumentError(f"{where}: a bake on a Dask cluster needs the scene as a file (its workers load it)")
    t0 = time.perf_counter()
    model = choose_model(scene, tolerance, min(spp, 4), seed, levels, terms, priority, backend)
    n = model["n_levels"]
    env = scene.environment
    held = lighting.coefficients(lighting.project(env, n, env.rotate_y + HELD_OUT_DEGREES)).reshape(3, -1).T
    points = texel_points(scene, n) if points is None else points
    settings = Settings(width, height, spp, n, tolerance / np.sqrt(3.0), bits, held * float(4 ** n), seed, backend,
                        points)
    if moving is not None:
        settings.product_levels = min(OBJECT_PRODUCT_LEVELS, n)
        settings.product_luminance = (lighting.project(env, settings.product_levels) @ LUMINANCE.astype(np.float64))
        product = np.zeros((height * width, 4 ** settings.product_levels), np.float16)
    tiles, (bw, bh) = _tiles(width, height)
    side2 = 4 ** n
    writer = store.TransferWriter(n, BLOCK, bits)
    albedo = np.zeros((height, width, 3), np.float32)
    background = []
    sum_sq = np.zeros(side2)
    totals = {"rays": 0, "error2": 0.0, "norm2": 0.0, "done": 0}
    lock = threading.Lock()
    t_pilot = time.perf_counter() - t0

    def collect(result):
        block_id, x0, y0, w, h = result["tile"]
        with lock:
            writer.add(block_id, result["columns"], result["scales"], result["data"])
            albedo[y0:y0 + h, x0:x0 + w] = result["albedo"]
            pixel, mask, dirs = result["background"]
            if len(pixel):
                background.append((np.asarray(pixel, np.uint32), mask, dirs))
            sum_sq[:] += result["sum_sq"]
            if moving is not None:
                rows = (y0 + np.arange(h))[:, None] * width + x0 + np.arange(w)[None, :]
                product[rows.reshape(-1)] = result["product"]
            totals["rays"] += result["rays"]
            totals["error2"] += result["error2"]
            totals["norm2"] += result["norm2"]
            totals["done"] += 1
            if progress:
                progress(totals["done"], len(tiles), totals["rays"], time.perf_counter() - t0)

    try:
        if dask_address is not None:
            bake_on_cluster(dask_address, full, settings, tiles, bake_block_task, collect,
                            None if moving is None else moving.index)
        else:
            worker = _Worker(scene)
            with ThreadPoolExecutor(threads or 2 * (os.cpu_count() or 1)) as pool:
                for result in pool.map(lambda tile: bake_block(worker, settings, tile), tiles):
                    collect(result)
        seconds = time.perf_counter() - t0
        header = {
            **store.header_of(scene),
            "width": width, "height": height, "spp": spp, "seed": seed, "n_levels": n, "block": BLOCK,
            "texel_points": points,
            "blocks": [bw, bh], "bits": bits, "tolerance": tolerance, "terms": model["terms"],
            "priority": model["priority"], "environment_rotate_y": float(env.rotate_y),
            "environment_name": env.name, "vary": vary,
            "measured": {"bake_seconds": round(seconds, 3), "pilot_seconds": round(t_pilot, 3),
                         "rays": totals["rays"],
                         "rays_per_second": round(totals["rays"] / (seconds - t_pilot), 1) if seconds > t_pilot else None,
                         "held_out_rotate_y": float(env.rotate_y + HELD_OUT_DEGREES),
                         "compression_error": (float(np.sqrt(totals["error2"] / totals["norm2"]))
                                               if totals["norm2"] > 0 else 0.0),
                         "level_error": (model["pilot"] or {}).get("level_error", {}).get(str(n)),
                         "term_error": (model["pilot"] or {}).get("term_error", {}).get(str(model["terms"])),
                         "entries": writer.entries, "entries_full": side2 * bw * bh, "pilot": model["pilot"]},
        }
        order = np.argsort(np.concatenate([b[0] for b in background])) if background else np.zeros(0, np.int64)
        arrays = {"albedo": albedo, "environment": env.pixels.astype(np.float32),
                  "background_pixel": (np.concatenate([b[0] for b in background])[order] if background
                                       else np.zeros(0, np.uint32)),
                  "background_mask": (np.concatenate([b[1] for b in background])[order] if background
                                      else np.zeros(0, np.uint64)),
                  "background_dir": (np.concatenate([b[2] for b in background])[order] if background
                                     else np.zeros((0, spp, 3), np.float32)),
                  "rms": np.sqrt(sum_sq / max(width * height, 1)).astype(np.float32)}
        if moving is not None:
            static = render_full(scene, spp=static_spp, strategy="wavelet", width=width, height=height,
                                 seed=seed + 1)
            arrays.update(static=static.image, static_stderr=static.stderr, product_leaves=product)
            lo, hi = moving.local.min(0), moving.local.max(0)
            center = (lo + hi) / 2
            header["object"] = {"index": moving.index, "name": moving.name, "rotate": moving.rotate,
                                "translate": np.asarray(moving.translate, float).tolist(),
                                "center": center.tolist(),
                                "radius": float(np.linalg.norm(moving.local - center, axis=1).max())}
            header["product_levels"] = settings.product_levels
            header["static"] = {"spp": static_spp, "strategy": "wavelet",
                                "seconds": static.stats["setup_seconds"] + static.stats["render_seconds"]}
            header["scene"]["content_hash"] = full.content_hash
        return finish_bake(writer, output, header, arrays)
    finally:
        writer.close()
