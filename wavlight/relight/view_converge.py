"""The view bake's unbiased frame on the device (:meth:`wavlight.relight.view_frames.ViewFrames.converge`;
Chen & Gao sec. 2.2, eq. 6-8 with the view as the varying factor, sec. 4.3-4.4, eq. 12-25).

Per tile of pixels (whole rows of the frame, at most TILE_PIXELS), the pixels' product trees:
each pixel's centre ray is traced (embree), its three cache points and weights found
(``view_lookup``, kernels/relight_view.cl), and kernel ``view_converge_trees``
(kernels/relight_view_converge.cl, numpy twin :func:`trees_reference`) builds its tree on
2^m x 2^m texels (m = min(n, wavlight.relight.view_frames.PRODUCT_LEVELS)): the leaves H+_t gl_t with
H+_t = max(f_r Y(T1_t) / Y(R_t), 0), T1_t the blend of the points' transfer summed over the texel
(the top-left 2^m x 2^m block of the bake's coefficients, eq. 13), f_r the mean of the BRDF at
the centres of FR_POINTS x FR_POINTS parts of the texel for the pixel's face normal, view direction
and material (0 below the face's horizon), R_t the lighting's mean radiance and gl_t its luminance mass
(:meth:`wavlight.relight.mixture.TexelLight.leaf_masses`): H+_t is about the integral of
f_r cos V over the texel, as the lighting bake's trees hold it (:mod:`wavlight.relight.converge`),
and the same pass sums the pixel's relit value G = sum_t H+_t R_t (the approximate frame at m
levels by the midpoint rule). The trees of the current camera (eye, target, fov, size) are kept
on the device up to TREE_CACHE_BYTES: another frame from the same camera (more samples, another
seed) pays only for its passes.

Per pass of at most PASS_SAMPLES camera samples of a tile (and ``pass_spp`` per pixel): the
camera rays (kernels/camera.cl, stratified in the pixel), their hits (embree), one launch of
``converge_shade`` (kernels/converge.cl, numpy twin :func:`wavlight.relight.converge.shade_reference`):
per hit ``slots`` directions of the defensive mixture (1 - alpha - beta) product + alpha BSDF +
beta lighting, their pdfs (every technique's), estimates albedo f cos L / pdf / slots (plastic:
(coat + albedo base) L / pdf / slots, either lobe sampled by the BSDF's share) and, with
``control``, the control variate k (G - sum of g / pdf / slots), g(w) = H+_t / Omega_t L(w), k the
albedo (plastic: tinted by the coat's share of G, whose trees hold base + coat / lum(albedo));
then the shadow rays of the estimates that are not 0 (embree, :func:`wavlight.relight.converge.visible_sum`).
Unbiased whatever the cache's approximations: the lighting's share makes the pdf positive
wherever g is, the BSDF's wherever f cos L is (tests/relight/test_relight_view.py against ``mis``).
With ``candidates`` a camera sample whose pixel's footprint reflects wider than its lobe
resamples its directions (the lighting bake's resampling; the footprints measured once per camera).
The tiles and their passes run in :func:`wavlight.relight.tile_passes.run_tiles`, as the lighting
bake's do.
"""
from __future__ import annotations

import threading
import time
import weakref
from typing import NamedTuple

import numpy as np

from .. import bsdfs, camera, cl, haar
from ..camera import camera_rays
from ..envmap import LUMINANCE
from ..errors import ArgumentError, check_int
from ..haar.tree import HaarTree, build_reference, morton_index, tree_stride
from ..integrator import RenderResult
from ..raytrace import RayTracer
from ..threads import default_threads
from ..warp import frame as tangent_frame
from ..warp import to_local
from . import converge_kernels as kernels
from . import tile_passes
from .bake import BLOCK
from .converge import COHERENCE, FOOTPRINT_GRID, LATTICE, MAX_CANDIDATES, MAX_SLOTS, PASS_SAMPLES, \
    TREE_CACHE_BYTES, PassShading, footprint_rays, footprint_spread

#: directions (shadow rays) per camera sample, and the mixture's shares of the BSDF and the
#: lighting alone (docs/decisions/relight-view-converge-kernels.md)
SLOTS = 8
DEFENSIVE = 0.3
LIGHT_SHARE = 0.1
#: resampled directions (:mod:`wavlight.relight.converge`): none by default, their candidates
#: cost more than they save here (docs/decisions/relight-view-converge-kernels.md)
CANDIDATES = 0
#: f_r in a tree's texel: its mean over the centres of FR_POINTS x FR_POINTS parts of the texel
#: (docs/decisions/relight-view-converge-kernels.md)
FR_POINTS = 2
#: a tile: whole rows of the frame, at most this many pixels (its trees: 22 MB at 2^5 x 2^5)
TILE_PIXELS = 1 << 12
#: a frame's tile i draws its Philox numbers as tile VIEW_TILES + i: neither the bake's tiles
#: nor the lighting bake's frames' (wavlight.relight.converge.CONVERGE_TILES)
VIEW_TILES = 14 << 16
BACKENDS = ("opencl", "numpy")
#: plastic's coat in the trees is divided by the albedo's luminance, at least this
#: (kernels/relight_view_converge.cl VC_MIN_LUM)
MIN_LUMINANCE = 1e-3
#: cache points per block of the bake file (wavlight.relight.surface_cache.POINTS)
POINTS = BLOCK * BLOCK


_LIGHTINGS = weakref.WeakKeyDictionary()
_LIGHTINGS_LOCK = threading.Lock()


def device_lighting(inside) -> kernels.Lighting:
    """The device tables of the lighting inside the texels ``inside`` (a TexelLight), made once
    per TexelLight and kept while it lives (the ViewFrames of one map share it:
    :func:`wavlight.relight.view_frames.texel_light`)."""
    with _LIGHTINGS_LOCK:
        found = _LIGHTINGS.get(inside)
    if found is None:
        found = kernels.Lighting(inside.tables())
        with _LIGHTINGS_LOCK:
            found = _LIGHTINGS.setdefault(inside, found)
    return found


class Tile(NamedTuple):
    """Rows y0 .. y0 + h - 1 of a frame w pixels wide."""

    index: int
    x0: int
    y0: int
    w: int
    h: int


def tiles_of(width: int, height: int) -> list:
    """The frame's tiles: whole rows, at most TILE_PIXELS pixels each (one row at least)."""
    rows = max(1, TILE_PIXELS // width)
    return [Tile(i, 0, y0, width, min(rows, height - y0)) for i, y0 in enumerate(range(0, height, rows))]


def per_pass(spp: int, pixels: int, limit: int) -> int:
    """Camera samples per pixel of one pass over a tile of ``pixels``: at most ``limit`` and
    PASS_SAMPLES in all."""
    return tile_passes.pass_spp(spp, pixels, limit, PASS_SAMPLES)


# ----------------------------------------------------------------------------- the trees' twin
def point_coefficients(transfer, points: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """(len(points), 3, len(columns)) float64: the stored coefficients ``columns`` (flat indices of
    the 2^n x 2^n layout) of cache points ``points`` (block p // POINTS, row p % POINTS), 0 where
    the block keeps none."""
    s = transfer._s
    b, j = points // POINTS, points % POINTS
    o = np.asarray(s["offsets"][np.asarray(columns, np.int64)[None, :], b[:, None]], np.int64)   # (I, C)
    keep = o >= 0
    oc = np.where(keep, o, 0)
    sc = np.where(keep, np.asarray(s["entry_scale"])[oc], 0.0)
    data = np.asarray(s["entry_data"])
    out = np.empty((len(points), 3, len(columns)))
    for c in range(3):   # channels
        out[:, c] = data[oc, (c * POINTS + j)[:, None]] * sc
    return out


def texel_luminance(transfer, ids: np.ndarray, w: np.ndarray, levels: int) -> np.ndarray:
    """(M, 2^m, 2^m) float64: per item the luminance of the blend (weights ``w`` (M, 3)) of its
    cache points' (``ids`` (M, 3)) T1 summed over each of 2^m x 2^m texels (the top-left block of
    the coefficients, inverted, times 4^(n - m))."""
    n, m = transfer.n_levels, levels
    side, small = 1 << n, 1 << m
    rr, cc = np.mgrid[0:small, 0:small]
    uniq, inv = np.unique(np.asarray(ids, np.int64).reshape(-1), return_inverse=True)
    coeffs = point_coefficients(transfer, uniq, (rr * side + cc).ravel())                  # (U, 3, M^2)
    lum = np.tensordot(coeffs, LUMINANCE.astype(np.float64), axes=([1], [0])).reshape(-1, small, small)
    blend = np.einsum("pj,pjab->pab", np.asarray(w, np.float64), lum[inv.reshape(np.shape(ids))])
    return haar.inverse(blend) * float(4 ** (n - m)) if len(blend) else blend


def part_directions(levels: int, parts: int) -> np.ndarray:
    """(4^m, parts^2, 4) float32: per texel of 2^m x 2^m (row-major) the world directions of the
    centres of its parts x parts parts (row-major in the texel), padded to four floats."""
    side = 1 << levels
    u = (np.arange(side * parts) + 0.5) / (side * parts)
    phi, theta = np.meshgrid(2 * np.pi * u, np.pi * u)
    st = np.sin(theta)
    fine = np.stack([np.sin(phi) * st, np.cos(theta), -np.cos(phi) * st], -1)          # (side S, side S, 3)
    parts_ = fine.reshape(side, parts, side, parts, 3).transpose(0, 2, 1, 3, 4).reshape(side * side, parts * parts, 3)
    out = np.zeros((side * side, parts * parts, 4), np.float32)
    out[..., :3] = parts_
    return out


def trees_reference(frames, inside, d, prim, u, v, parts: int | None = None):
    """numpy twin of ``view_converge_trees`` (kernels/relight_view_converge.cl): for P centre
    rays (unit directions d (P, 3), faces prim (P,), -1 a miss, embree's u, v) of ``frames``
    (a :class:`wavlight.relight.view_frames.ViewFrames`) and the lighting inside the texels ``inside``
    (a TexelLight of m levels): the product pyramids (P, tree_size(m)) float32 (row-major
    levels) of leaves max(f_r Y(T1_t), 0) / 4^m where gl_t > 0 (module docstring), and the
    relit values G (P, 3) float64 = sum_t (leaf_t / gl_t) R_t; f_r the mean over the centres of
    ``parts`` x ``parts`` parts of each texel (default FR_POINTS)."""
    m = inside.n
    side = 1 << m
    S = FR_POINTS if parts is None else int(parts)
    P = len(prim)
    leaves = np.zeros((P, side, side), np.float32)
    relit = np.zeros((P, 4))
    hit = np.flatnonzero(np.asarray(prim) >= 0)
    if len(hit):
        d = np.asarray(d, np.float32)
        ids, w, fn = frames.hit_points(None, d[hit], prim[hit], None, (u[hit], v[hit]))
        ok = np.flatnonzero(w.sum(1) > 0)
        if len(ok):
            rows = hit[ok]
            T = texel_luminance(frames.transfer, ids[ok], w[ok], m)                        # (M, side, side)
            nrm = fn[ok].astype(np.float64)
            dh = d[rows].astype(np.float64)
            nrm *= np.where(np.einsum("ij,ij->i", nrm, dh) > 0, -1.0, 1.0)[:, None]
            s_ax, t_ax = tangent_frame(nrm)
            wo = to_local(-dh, s_ax, t_ax, nrm)
            dirs = part_directions(m, S)[..., :3].astype(np.float64).reshape(-1, 3)    # (side^2 S^2, 3)
            wl = np.stack([a @ dirs.T for a in (s_ax, t_ax, nrm)], -1)                     # (M, side^2 S^2, 3)
            mat = frames.scene.face_material[prim[rows]]
            M, n_dirs = len(rows), len(dirs)
            kind = np.repeat(frames.kind_of[mat], n_dirs)
            table = np.repeat(frames.plastic_table[mat], n_dirs, axis=0)
            wl_all, wo_all = wl.reshape(-1, 3), np.repeat(wo, n_dirs, axis=0)
            fcos, _ = bsdfs.eval_pdf_each(kind, np.repeat(frames.param_of[mat], n_dirs), wl_all, wo_all, table)
            # plastic: base + coat / lum(albedo) (the kernel's; the coat in units of the albedo's luminance)
            coat = np.zeros(len(fcos))
            pl = np.flatnonzero(kind == bsdfs.PLASTIC)
            if len(pl):
                spec, diff = bsdfs.plastic_parts(wl_all[pl], wo_all[pl], table[pl])
                la = np.maximum(np.repeat(frames.albedo_of[mat], n_dirs, axis=0)[pl] @ LUMINANCE, MIN_LUMINANCE)
                coat[pl] = spec / la
                fcos[pl] = diff + coat[pl]
            iz = wl[..., 2].reshape(-1)
            above = np.where(iz > 0, iz, 1.0)
            f = np.where(iz > 0, fcos / above, 0.0)   # f_r: f cos / cos above the horizon
            f = f.reshape(M, side, side, S * S).mean(-1)
            fc = np.where(iz > 0, coat / above, 0.0).reshape(M, side, side, S * S).mean(-1)
            gl = inside.leaf_masses().astype(np.float64)                                  # (side, side)
            leaf = np.where(gl > 0, np.maximum(f * T, 0.0) / (side * side), 0.0)
            leaves[rows] = leaf
            h = np.where(gl > 0, leaf / np.where(gl > 0, gl, 1.0), 0.0)
            radiance = inside.texel_radiance.reshape(side, side, 3)
            relit[rows, :3] = np.einsum("pij,ijc->pc", h, radiance)
            y = h * (radiance @ LUMINANCE)                                                    # (M, side, side)
            with np.errstate(divide="ignore", invalid="ignore"):
                coat_y = np.where(h > 0, y * fc / np.where(f != 0, f, 1.0), 0.0).sum((1, 2))
            all_y = y.sum((1, 2))
            relit[rows, 3] = np.clip(np.where(all_y > 0, coat_y / np.where(all_y > 0, all_y, 1.0), 0.0), 0.0, 1.0)
    return build_reference(leaves), relit


# ----------------------------------------------------------------------------- the frames
class ViewConverge:
    """Unbiased frames of one view bake (module docstring): ``frame(camera, width, height, spp,
    seed, ...)``. ``frames``: its :class:`wavlight.relight.view_frames.ViewFrames`; ``inside``: the
    bake's lighting inside the product's texels (a TexelLight); ``device`` and ``lookup``: the
    bake's entries on the device and the cache lookup's tables (its ViewDevice and FrameDevice,
    which the approximate frame uses too); ``backend="numpy"`` runs the
    kernels' numpy twins (the same random numbers and estimator; slow: tests). What every frame
    shares is made here; the trees of the last camera are kept."""

    def __init__(self, frames, inside, device=None, lookup=None, backend: str = "opencl", threads=None):
        if backend not in BACKENDS:
            raise ArgumentError(f"relight.view: backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
        t0 = time.perf_counter()
        self.frames, self.inside, self.backend, self.threads = frames, inside, backend, threads
        #: what camera samples that miss see (the ViewFrames' background: nearest, bilinear or none)
        self.background = frames.environment.background
        self.levels = inside.n
        sc = frames.scene
        self.lobe_width = bsdfs.lobe_width(sc.material_kind, sc.material_param).astype(np.float32)
        self._camera, self._camera_frames = None, 0
        self._trees, self._spare, self._spreads, self.kept_bytes = {}, {}, {}, 0
        self._lock = threading.Lock()
        if backend == "opencl":
            m = self.levels
            runtime_device = cl.runtime().device
            self.tree_cache_bytes = min(TREE_CACHE_BYTES, int(runtime_device.global_mem_size) // 4)
            if device is None or lookup is None:
                raise ArgumentError("relight.ViewConverge: the opencl backend takes the bake's ViewDevice and "
                                    "FrameDevice (wavlight.relight.view_walk)")
            self.device, self.lookup = device, lookup
            self.light = device_lighting(inside)
            self.shade = kernels.ShadeKernel(sc, frames.tracer, self.lobe_width)
            self.bits = int(self.device.entries.bits)
            self.no_spread = cl.to_device(np.zeros(1, np.float32))
            self.spread_program = kernels.program(m, self.bits, self.shade.kinds, 1, 0, False, LATTICE)
            self.tree_program = cl.program("relight_view_converge.cl", QBITS=self.bits, POINTS=POINTS, K=1,
                                           N_LEVELS=m, VC_SUB=FR_POINTS)
            side = 1 << m
            row, col = np.divmod(np.arange(side * side), side)
            morton = np.argsort(morton_index(col, row))        # texel (row-major) of each Morton index
            self.texel_dirs = cl.to_device(part_directions(m, FR_POINTS)[morton].reshape(-1, 4))
            n = frames.n
            rows = (np.arange(side)[:, None] * (1 << n) + np.arange(side)[None, :]).reshape(-1)
            self.block_offsets = cl.to_device(np.ascontiguousarray(
                np.asarray(frames.transfer._s["offsets"][rows], np.int32).T))   # (blocks, 4^m)
            self.materials = (cl.to_device(sc.material_kind.astype(np.int32)),
                              cl.to_device(sc.material_param.astype(np.float32)))
            # plastic: the albedo's luminance and the plastic table (kernels/relight_view_converge.cl)
            self.plastic = (cl.to_device(np.ascontiguousarray(sc.material_albedo, np.float32).reshape(-1)),
                            cl.to_device(np.ascontiguousarray(frames.plastic_table, np.float32).reshape(-1)
                                         if len(sc.materials) else np.zeros(bsdfs.PLASTIC_STRIDE, np.float32)))
            camera.warm_up(sc)
        else:
            self.tree_cache_bytes = 0
        self.setup_seconds = time.perf_counter() - t0

    def program(self, slots: int, candidates: int, control: bool):
        """kernels/converge.cl's shade kernel for this bake's product levels, scene and background."""
        return kernels.program(self.levels, self.bits, self.shade.kinds, slots, candidates, control, LATTICE,
                               textures=self.shade.textured, background=self.background)

    def use_camera(self, key):
        """Keep the trees of camera ``key`` (eye, target, fov, width, height): another camera's
        are released, their buffers kept for the new camera's tiles of the same size."""
        if self._camera != key:
            self._spare = self._trees
            self._trees, self._spreads, self.kept_bytes = {}, {}, 0
            self._camera, self._camera_frames = key, 0

    def tile_trees(self, scene, tile, width: int, height: int, new_buffers: bool = True):
        """The tile's product trees from ``scene``'s camera (kept, or built and kept while they
        fit in tree_cache_bytes): a :class:`.converge_kernels.TileTrees`, or with the numpy
        backend (HaarTree, host pyramids, G); and whether they were kept. Trees are kept in an
        earlier camera's buffers, or in new ones only with ``new_buffers`` (a camera's first
        frame builds them in scratch buffers instead, as
        :meth:`wavlight.relight.converge.ConvergeFrames.tile_trees`)."""
        with self._lock:
            kept = self._trees.get(tile.index)
        if kept is not None:
            return kept, True
        P = tile.w * tile.h
        pix = np.arange(P)
        eye, d = camera_rays(scene, tile.x0 + pix % tile.w, tile.y0 + pix // tile.w, np.full((P, 2), 0.5, np.float32),
                             width, height)
        prim, _, u, v = self.frames.tracer.intersect_uv(eye, d)
        if self.backend == "numpy":
            nodes, relit = trees_reference(self.frames, self.inside, d, prim, u, v)
            return (HaarTree.from_pyramids(nodes), nodes, relit), False
        m = self.levels
        stride = tree_stride(m)
        queue = cl.thread_queue()
        nbytes = kernels.TileTrees(None, None, P, m).nbytes
        with self._lock:
            fits = self.kept_bytes + nbytes <= self.tree_cache_bytes
            spare = self._spare.pop(tile.index, None) if fits else None
            if spare is not None and (spare.pixels != P or spare.levels != m):
                spare = None
            keep = fits and (spare is not None or new_buffers)
            if keep:
                self.kept_bytes += nbytes
        if spare is not None:
            out, relit = spare.buffer, spare.relit
        elif keep:
            out, relit = cl.empty(4 * P * stride), cl.empty(16 * P)
        else:
            out, relit = cl.scratch("view_converge_trees", 4 * P * stride), cl.scratch("view_converge_relit", 16 * P)
        ids_b, w_b, prim_b, dir_b, _ = self.lookup.lookup(prim, u, v, d, queue, points=False)
        e = self.device.entries
        hs = np.float32(float(1 << m) * 4.0 ** (self.frames.n - m))
        cl.kernel(self.tree_program, "view_converge_trees")(
            queue, (cl.items(P),), (cl.WORK_GROUP,), np.uint32(P), ids_b, w_b, prim_b, dir_b, self.lookup.face_normal,
            self.lookup.face_material, *self.materials, self.block_offsets, e.scale[0], e.data[0], self.texel_dirs,
            self.light.buffers["leaf_masses"], self.light.buffers["radiance"], hs, np.uint32(stride), out, relit,
            *self.plastic)
        made = kernels.TileTrees(out, relit, P, m)
        if keep:
            with self._lock:
                self._trees[tile.index] = made
        return made, False

    def spread(self, scene, tile, width: int, height: int):
        """The footprint spreads of the tile's pixels from ``scene``'s camera (measured once per
        camera, :func:`wavlight.relight.converge.footprint_spread`; kernel ``converge_spread``):
        (P,) float32 on the host and the device buffer (None with the numpy backend)."""
        with self._lock:
            kept = self._spreads.get(tile.index)
        if kept is not None:
            return kept
        tracer = self.frames.tracer
        if self.backend == "numpy":
            s = (footprint_spread(scene, tracer, tile.x0, tile.y0, tile.w, tile.h, width, height).astype(np.float32),
                 None)
        else:
            fd, fprim = footprint_rays(scene, tracer, tile.x0, tile.y0, tile.w, tile.h, width, height)
            buf, host = self.shade.spread(self.spread_program, fd, fprim, FOOTPRINT_GRID ** 2)
            s = (host, buf)
        with self._lock:
            self._spreads[tile.index] = s
        return s

    def frame(self, scene, width: int, height: int, spp: int, seed: int, slots: int = SLOTS,
              defensive: float = DEFENSIVE, light: float = LIGHT_SHARE, control: bool = True, pass_limit: int = 64,
              progress=None, candidates: int = CANDIDATES, coherence: float = COHERENCE) -> RenderResult:
        """The unbiased frame of ``scene`` (the bake's scene with the frame's camera) at width x
        height, ``spp`` camera samples per pixel, each with ``slots`` directions of the defensive
        mixture (shares ``defensive`` and ``light``; with ``control`` and light > 0 the relit
        value G is the control variate's integral), at most ``pass_limit`` samples per pixel a
        pass. A camera sample whose pixel's footprint reflects over more than ``coherence`` times
        its lobe's width resamples its slots from ``candidates`` mixture directions (0: never;
        :mod:`wavlight.relight.converge`). Returns a RenderResult: image, per-pixel standard
        error, stats."""
        slots = check_int("relight.view", "slots", slots, 1, MAX_SLOTS)
        candidates = check_int("relight.view", "candidates", candidates, 0, MAX_CANDIDATES)
        use_control = bool(control) and light > 0
        cam = scene.camera
        self.use_camera((tuple(np.asarray(cam.eye, np.float64)), tuple(np.asarray(cam.target, np.float64)),
                         float(cam.fov_y), int(width), int(height)))
        tiles = tiles_of(width, height)
        tracer = self.frames.tracer
        prog = None
        if self.backend == "opencl":
            prog = self.program(slots, candidates, use_control)
            self.shade.eye = np.asarray(cam.eye, np.float32)
            self.shade.eye_offset = RayTracer.eye_offset_floor(cam.eye)
        t0 = time.perf_counter()
        shares = (defensive, light, coherence)
        eye = np.broadcast_to(np.asarray(cam.eye, np.float32), (1, 3))
        max_tile = max(t.w * t.h for t in tiles)

        def start(tile):
            ta = time.perf_counter()
            trees, was_kept = self.tile_trees(scene, tile, width, height, new_buffers=self._camera_frames > 0)
            P = tile.w * tile.h
            rays = 0 if was_kept else P
            if candidates:
                rays += 0 if tile.index in self._spreads else P * FOOTPRINT_GRID ** 2
                spread = self.spread(scene, tile, width, height)
            else:   # not read
                spread = (np.zeros(P, np.float32), None if prog is None else self.no_spread)
            tb = time.perf_counter()
            if prog is not None:
                self.shade.warm_up(prog, slots, trees, spread[1], self.light, shares)
            return (trees, spread), {"rays": rays, "kept": int(was_kept), "trees_seconds": tb - ta}

        shading = PassShading(scene, tracer, self.shade if prog is not None else None, prog,
                              self.light if prog is not None else None, self.inside, eye, seed, slots, shares,
                              use_control, candidates, self.background, self.lobe_width)

        def samples(shared, tile, first, k):
            P = tile.w * tile.h
            tile_id = VIEW_TILES + tile.index
            d = pass_rays(scene, width, height, seed, tile_id, tile, k, first * P, self.backend == "opencl")
            return shading.samples(d, k, first * P, tile_id, *shared)

        work = tile_passes.TileWork(start, samples, lambda pixels: per_pass(spp, pixels, pass_limit))
        mean, err, totals = tile_passes.run_tiles(work, tiles, width, height, spp, self.threads or default_threads(),
                                                  progress, t0)
        self._camera_frames += 1
        self._spare = {}
        seconds = time.perf_counter() - t0
        k_pass = per_pass(spp, max_tile, pass_limit)
        stats = {"spp": spp, "seed": seed, "width": width, "height": height, "render_seconds": round(seconds, 4),
                 "rays": totals["rays"], "rays_per_second": round(totals["rays"] / seconds, 1) if seconds > 0 else None,
                 "eye": np.asarray(cam.eye).tolist(), "target": np.asarray(cam.target).tolist(), "fov": cam.fov_y,
                 "background": self.background, "product_levels": self.levels, "slots": slots,
                 "candidates": candidates,
                 "resampled_share": round(totals["resampled"] / totals["hits"], 4) if totals["hits"] else 0.0,
                 "pass_spp": k_pass, "pass_samples": max_tile * k_pass,
                 "tiles": len(tiles), "tiles_kept": totals["kept"], "kept_tree_bytes": self.kept_bytes,
                 "trees_thread_seconds": round(totals["trees_seconds"], 4), "backend": self.backend,
                 "estimator": "product T1 x f_r of the surface cache + BSDF + lighting, defensive mixture"
                              + (", the relit frame as control variate" if use_control else "")
                              + (", resampled where the pixel's footprint is wider than the lobe"
                                 if candidates else "")}
        return RenderResult(mean.astype(np.float32), err.astype(np.float32), stats)

    def close(self):
        """Release the kept trees' device memory."""
        self._trees, self._spare, self._spreads, self.kept_bytes, self._camera = {}, {}, {}, 0, None


def pass_rays(scene, width: int, height: int, seed: int, tile_id: int, tile, k: int, first: int, kernel: bool):
    """One pass's camera rays of ``tile``: :func:`wavlight.camera.pass_rays`, k stratified
    samples per pixel (the kernel, or its numpy twin)."""
    return camera.pass_rays(scene, width, height, seed, tile_id, tile.x0, tile.y0, tile.w, tile.h, k, first,
                            kernel=kernel, stratified=True)


_KEPT = weakref.WeakKeyDictionary()
_KEPT_LOCK = threading.Lock()


def converger(frames, inside, device=None, lookup=None, backend: str = "opencl", threads=None) -> ViewConverge:
    """The ViewConverge of ``frames`` (made on first use and kept with it, per backend and
    threads), so that frames from the same camera keep their trees."""
    with _KEPT_LOCK:
        per = _KEPT.setdefault(frames, {})
        found = per.get((backend, threads))
        if found is None:
            found = per[(backend, threads)] = ViewConverge(frames, inside, device, lookup, backend, threads)
        return found
