"""The bake of a view bake (Chen & Gao sec. 2.2, eq. 6-8, with the view as the varying factor):
the lighting and the objects stay fixed, the camera moves, so the factor baked per surface point is

    T1(x, w) = L(w) V(x, w) max(cos theta, 0)  (eq. 7, per cache point x)

on the surface cache (:mod:`wavlight.relight.surface_cache`); the frames take <T1(x), f_r(x, ., wo)>
(:mod:`wavlight.relight.view_walk`, :mod:`wavlight.relight.view_frames`).

For cache point x and texel t of the world-frame lat-long square (2^n x 2^n texels,
the convention of :mod:`.lighting`), T1_t(x) = L_t G_t(x), G_t(x) = integral over t of V(x, w)
max(cos, 0) dw (solid angle, sin theta included) and L_t the fixed lighting's exact mean radiance
over the texel (:func:`.lighting.project`): <T1, f_r> with these texels is the integral up to the
covariance of L, V cos and f_r inside a texel (a sun smaller than a texel keeps its energy but
its shadows blur to the texel's size). G_t is estimated by the bake's texel kernel
(``bake_texel_rays``, :func:`wavlight.relight.bake.texel_rays`, a lambert "pixel" per cache
point): cos evaluated at TEXEL_POINTS stratified points of the texel, one shadow ray towards one
of them picked in proportion to cos: Omega_t mean(cos) V, unbiased for the texel's integral, and
no ray where L_t = 0 or the texel is below the horizon. The texels of each channel go through the
Haar transform (sec. 4.1); blocks of BLOCK^2 points (sorted by object and Morton order of
position, so that a block is a patch of surface) are compressed together (coefficient columns by
decreasing energy until what is left out is within the tolerance,
:func:`wavlight.relight.store.compress_block`) and quantized (a scale per coefficient and block,
shared by the three channels). T1 holds no albedo: the file stores each cache point's albedo
apart, its material's times its base-colour texture at the point (:func:`point_albedo`).
"""
from __future__ import annotations

import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from .. import bsdfs, haar
from ..envmap import LUMINANCE
from ..errors import ArgumentError, check_int
from ..raytrace import RayTracer
from ..scene import check_scene, load_scene
from ..threads import default_threads
from . import lighting, store
from .bake import BLOCK, PixelSamples, choose_model, texel_rays, texel_rays_reference
from .settings import BAKE, CACHE_POINTS, VIEW_TEXEL_POINTS
from .surface_cache import MAX_LATTICE, POINTS, SurfaceCache, barycentric, build_cache
from .transfer import finish_bake


@dataclass
class _Settings:
    n_levels: int
    tolerance: float
    bits: int
    seed: int
    backend: str
    points: int
    light: np.ndarray        # (N, N, 3) the lighting's mean radiance per texel


def _point_samples(cache: SurfaceCache, tracer, lo: int, hi: int) -> PixelSamples:
    """The cache points lo .. hi - 1 as the texel kernel's pixels: one sample, one lambert group
    each (its cosine with the point's normal, nothing below its face: the face normal), the
    shadow rays from the point moved off the surface along its face's normal."""
    P = hi - lo
    normal = cache.normal[lo:hi]
    geometric = tracer.face_normals[cache.face[lo:hi]].astype(np.float32)
    geometric *= np.where(np.einsum("ij,ij->i", geometric, normal) < 0, -1.0, 1.0).astype(np.float32)[:, None]
    p = cache.position[lo:hi].astype(np.float32)
    offset = tracer.shadow_offsets(p, cache.face[lo:hi], np.zeros(3))
    origin = (p + geometric * offset[:, None]).astype(np.float32)
    ones = np.ones(P, np.uint32)
    return PixelSamples(1, ones, normal.astype(np.float32), geometric, normal.astype(np.float32),
                        np.full(P, bsdfs.LAMBERT, np.int32), np.zeros(P, np.float32), np.ones(P, np.float32),
                        np.zeros(P, np.uint32), ones, np.arange(P, dtype=np.uint32), origin,
                        np.ones((P, 3), np.float32), np.zeros(P, np.uint64), normal.astype(np.float32))


def point_transfer(cache: SurfaceCache, tracer, s: _Settings, block: int):
    """(P, 3, N, N) float32 T1 = L_t G_t of a block's cache points (module docstring) and the
    shadow rays traced."""
    lo, hi = block * POINTS, min((block + 1) * POINTS, len(cache))
    ps = _point_samples(cache, tracer, lo, hi)
    n = s.n_levels
    if s.backend == "opencl":
        dirs, weight, pick = texel_rays(ps, n, s.seed, block, 1 << bsdfs.LAMBERT, points=s.points)
    else:
        dirs, weight, pick = texel_rays_reference(ps, n, s.seed, block, points=s.points)
    lit = (s.light.max(axis=2) > 0).reshape(-1)
    texel = np.arange(len(weight)) & ((1 << (2 * n)) - 1)
    live = np.flatnonzero((weight > 0) & lit[texel])
    blocked = tracer.occluded(np.take(ps.origin, pick[live].astype(np.int64), axis=0), np.take(dirs, live, axis=0))
    g = np.zeros(len(weight), np.float32)
    g[live] = np.where(blocked, 0.0, weight[live] * np.float32(np.pi))   # lambert's f cos = cos / pi
    side = 1 << n
    g = g.reshape(-1, 1, side, side)
    return g * np.moveaxis(s.light, -1, 0)[None].astype(np.float32), len(live)


def _bake_block(cache, tracer, s: _Settings, block: int) -> dict:
    T1, rays = point_transfer(cache, tracer, s, block)
    P = len(T1)
    side2 = 4 ** s.n_levels
    coeffs = np.asarray(haar.forward(T1), np.float32).reshape(P, 3, side2)
    rows = np.zeros((3, POINTS, side2), np.float32)
    rows[:, :P] = np.moveaxis(coeffs, 1, 0)
    rows = rows.reshape(3 * POINTS, side2)
    held = np.zeros((side2, 3))
    held[0] = 1.0                           # the scaling coefficient: a lambert point's frame
    cols, scales, q, _, _ = store.compress_block(rows, held, s.tolerance, s.bits,
                                                 np.random.default_rng([s.seed, block]))
    approx = np.zeros_like(rows)
    approx[:, cols] = (q.astype(np.float32) * scales[:, None]).T
    diff = rows.astype(np.float64) - approx
    lum = np.tensordot(LUMINANCE.astype(np.float64), coeffs.astype(np.float64), axes=([0], [1]))   # (P, 4^n)
    return {"block": block, "columns": cols, "scales": scales, "data": q, "rays": rays,
            "error2": float(np.einsum("ij,ij->", diff, diff)), "norm2": float(np.einsum("ij,ij->", rows, rows, dtype=np.float64)),
            "sum_sq": np.einsum("pc,pc->c", lum, lum)}


def point_albedo(scene, cache: SurfaceCache) -> np.ndarray:
    """(P, 3) float32: the albedo of each cache point, its material's times its base-colour texture
    there (Scene.albedo_at at the point's place on its face; a point shared by faces takes its
    first face's texture coordinates)."""
    if not len(cache) or not scene.textured:
        return scene.material_albedo[cache.material].astype(np.float32).reshape(-1, 3)
    u, v = barycentric(scene.vertices, scene.faces, cache.face, cache.position)
    return scene.albedo_at(cache.face, u.astype(np.float32), v.astype(np.float32)).reshape(-1, 3)


def bake_view(scene, output=None, levels=None, tolerance: float = BAKE["tolerance"].default,
              bits: int = BAKE["bits"].default, seed: int = BAKE["seed"].default, threads=None, progress=None,
              backend: str = "opencl", points=None, density=None, cache_points: int = CACHE_POINTS):
    """Bake T1 = L V max(cos, 0) of ``scene`` on its surface cache (module docstring) into
    ``output`` (default: a temporary file the Transfer owns); returns the
    :class:`wavlight.relight.Transfer` (header ``vary = "view"``).

    ``levels``: texels 2^n x 2^n (default: the fewest within ``tolerance`` / sqrt(3), chosen by
    the lighting bake's pilot at the scene's camera, :func:`wavlight.relight.bake.choose_model`);
    ``density``: cache points per unit area (default: ``cache_points`` over the scene's area);
    ``points``: texel points (1, 4 or 16; default VIEW_TEXEL_POINTS); each block is compressed to ``tolerance`` /
    sqrt(3) (relative L2 of T1) and quantized to ``bits``."""
    where = "relight.bake"
    if isinstance(scene, (str, os.PathLike)):
        scene = load_scene(scene)
    check_scene(scene)
    if levels is not None:
        levels = BAKE["levels"].check(levels, where)
    tolerance, bits, seed = (BAKE[k].check(v, where) for k, v in (("tolerance", tolerance), ("bits", bits),
                                                                   ("seed", seed)))
    points = BAKE["points"].check(VIEW_TEXEL_POINTS if points is None else points, where)
    cache_points = check_int(where, "cache_points", cache_points, 1, MAX_LATTICE)
    if scene.environment.is_black:
        raise ArgumentError(f"{scene.path}: [environment]: the environment is black everywhere; nothing to relight")
    if output is not None:   # the map at least
        store.check_output(output, scene.environment.pixels.size * 4)
    t0 = time.perf_counter()
    pilot = None
    if levels is None:
        model = choose_model(scene, tolerance, 4, seed, None, 256, "area", backend)
        levels, pilot = model["n_levels"], model["pilot"]
    n = levels
    cache = build_cache(scene, density, cache_points)
    env = scene.environment
    s = _Settings(n, tolerance / np.sqrt(3.0), bits, seed, backend, points, lighting.project(env, n))
    tracer = RayTracer(scene.vertices, scene.faces, threads=1)
    n_blocks = -(-len(cache) // POINTS)
    writer = store.TransferWriter(n, BLOCK, bits, row=3 * POINTS, output=output)
    sum_sq = np.zeros(4 ** n)
    totals = {"rays": 0, "error2": 0.0, "norm2": 0.0, "done": 0}
    lock = threading.Lock()
    t_setup = time.perf_counter() - t0

    def collect(r):
        with lock:
            writer.add(r["block"], r["columns"], r["scales"], r["data"])
            sum_sq[:] += r["sum_sq"]
            for key in ("rays", "error2", "norm2"):
                totals[key] += r[key]
            totals["done"] += 1
            if progress:
                progress(totals["done"], n_blocks, totals["rays"], time.perf_counter() - t0)

    try:
        with ThreadPoolExecutor(threads or default_threads()) as pool:
            for r in pool.map(lambda b: _bake_block(cache, tracer, s, b), range(n_blocks)):
                collect(r)
        seconds = time.perf_counter() - t0
        side = 1 << n
        model = {"vary": "view", "n_levels": n, "texels": f"{side}x{side}", "levels_from": "pilot" if pilot else "given",
                 "cache_points": len(cache), "density": cache.density, "spacing": cache.spacing,
                 "texel_points": points, "tolerance": tolerance, "bits": bits,
                 "compression_tolerance": tolerance / np.sqrt(3.0)}
        header = {
            **store.header_of(scene),
            "width": scene.width, "height": scene.height, "spp": 1, "seed": seed, "n_levels": n, "block": BLOCK,
            "texel_points": points, "blocks": [n_blocks, 1], "bits": bits, "tolerance": tolerance, "terms": 4 ** n,
            "priority": "transfer", "environment_rotate_y": float(env.rotate_y), "environment_name": env.name,
            "vary": "view", "model": model,
            "cache": {"points": len(cache), "density": cache.density, "spacing": cache.spacing,
                      "faces": int(len(cache.face_k)), "lattice": int(len(cache.lattice)), "row": 3 * POINTS},
            "measured": {"bake_seconds": round(seconds, 3), "pilot_seconds": round(t_setup, 3), "rays": totals["rays"],
                         "rays_per_second": (round(totals["rays"] / (seconds - t_setup), 1) if seconds > t_setup
                                             else None),
                         "compression_error": (float(np.sqrt(totals["error2"] / totals["norm2"]))
                                               if totals["norm2"] > 0 else 0.0),
                         "entries": writer.entries, "entries_full": 4 ** n * n_blocks, "pilot": pilot},
        }
        arrays = {"environment": env.pixels.astype(np.float32),
                  "albedo": point_albedo(scene, cache),
                  "background_pixel": np.zeros(0, np.uint32), "background_mask": np.zeros(0, np.uint64),
                  "background_dir": np.zeros((0, 1, 3), np.float32),
                  "rms": np.sqrt(sum_sq / max(len(cache), 1)).astype(np.float32),
                  "view_position": cache.position.astype(np.float32), "view_normal": cache.normal.astype(np.float32),
                  "view_material": cache.material.astype(np.int32), "view_face_k": cache.face_k.astype(np.int32),
                  "view_face_base": cache.face_base.astype(np.int64), "view_lattice": cache.lattice.astype(np.int32)}
        return finish_bake(writer, output, header, arrays)
    finally:
        writer.close()

