"""The unbiased counterpart of a relit frame: directions importance-sampled from the product
T1 x L of the bake's transfer and the frame's lighting, evaluated with the true BRDF, radiance
and a shadow ray (Chen & Gao sec. 2.2, eq. 6-8 and 12, sec. 4.3-4.4, eq. 17-25).

Per tile of pixels (whole blocks of the bake, one block row), the pixels' transfer on
2^m x 2^m texels (the bake's quantized entries, read on the device: m = min(n, PRODUCT_LEVELS),
a finer bake summed to them) and the lighting's luminance on the same texels give each pixel's
product pyramid by eq. 25 at its leaves, H+_t gl_t (H+_t = max(H_t, 0), the compressed
transfer's ringing clamped; gl_t the lighting's luminance mass of texel t), summed bottom up
(kernel ``converge_trees``, twin :func:`tile_trees_reference`); the hierarchical warp walks it
(kernels/warp.h, eq. 17-22): a direction lands in texel t with probability proportional to
H+_t gl_t; inside the texel, as the lighting's luminance at the map's own resolution (the
world-frame square of 2^top x 2^top leaves, top = the map's depth, a light tree's leaves,
:func:`.lighting.project`), and inside the leaf as the map's pixels (a leaf of a map turned by
a fraction of a column overlaps two of them: :class:`_TexelLight`): a sun smaller than a texel
is found inside it, a sun one pixel wide in proportion to its own radiance. The pdf per solid
angle = p_t 4^m (mass of the leaf / mass of the texel) 4^(top - m) (mass of the piece / mass of
the leaf) / (its share of the leaf's area) / (2 pi^2 sin theta). Visibility is inside that
product (T1 holds V), which is what the ``wavelet`` strategy's product lacks on shadowed
scenes: where T1 is accurate, the estimate's noise is the visibility's variance inside a texel
and the pixel.

The relit frame is the control variate: g(w) = H+_t / Omega_t L(w), the pixel's clamped
transfer in the direction's texel (read from its tree's leaf, H+_t = leaf / gl_t) times the
map's radiance there, has the known integral G = sum_t H+_t L_t (the pixel's approximate frame,
eq. 8, with every term, L_t the texel's mean radiance; summed with the tree), and each sample
adds G + (f cos V L - g) / pdf: unbiased, since the lighting's share of the mixture makes the
pdf positive wherever g is. The transfer is scaled by c = S / hits of the bake's camera
samples (:func:`hit_scales`): the frame's sample that hits is compared with the transfer of
the bake's samples that hit. Without a lighting share there is no control variate.

Each camera sample (jittered in its pixel, stratified over the pass's samples of the pixel)
takes ``slots`` directions of the defensive mixture (1 - alpha - beta) p_product + alpha p_bsdf
+ beta p_light (alpha = ``defensive``, beta = ``light``; where the pixel has no product,
alpha = 1 - beta), each traced and weighted by f cos / that pdf. The lighting alone finds a
bright light where the bake's one shadow ray per texel hid it from a pixel's transfer; the BSDF
covers every direction its lobe reaches, so the pdf is non-zero wherever the integrand is (the
compressed product may be 0 there: dropped coefficients, a surface the pixel's samples did not
see in the bake, a pixel whose product is 0 altogether). Samples that miss see the environment.
The estimate is unbiased for any transfer: a converged frame equals ``mis`` of the same scene
and lighting within their standard errors (tests/relight/test_relight.py).

T1 is the mean of the lobes of the pixel's camera samples. Where their mirror directions spread
wider than COHERENCE times a sample's own lobe (a glossy pixel over several facets,
:func:`footprint_spread`), T1 is much wider than that lobe: the sample then resamples its slots
among CANDIDATES mixture directions by a target of its own lobe and T1's visibility
(:func:`resampling_target`, Talbot et al. 2005), without the control variate, whose g (T1's
mean lobe) is far from the sample's f cos V there.

Passes. :class:`ConvergeFrames` holds what frames share: the scene's ray tracer, its tables and
the bake's entries on the device, the pixels' footprint spreads (measured once, on first use),
and for the current lighting (map, rotation, scale) its tables and the tiles' trees, kept up to
TREE_CACHE_BYTES of device memory. A frame then runs per tile: its trees (kept, or one launch of
``converge_trees``), and per pass of at most PASS_SAMPLES camera samples: the camera rays
(kernels/camera.cl), their hits (embree), one launch of ``converge_shade`` (every direction, pdf,
estimate and control variate; twin :func:`shade_reference`), the shadow rays of the estimates
that are not 0 (embree), and the pixels' sums. A second frame under the same lighting (more
samples, another seed) pays only for the passes. :func:`converge` is one frame of a
ConvergeFrames it keeps for the next call with the same transfer and scene.
"""
from __future__ import annotations

import os
import threading
import time
import weakref
from typing import NamedTuple

import numpy as np

from .. import bsdfs, camera, cl, rng
from ..camera import camera_rays
from ..envmap import bilinear, luminance
from ..errors import ArgumentError, WavlightError, check_degrees, check_int, check_number
from ..haar import inverse
from ..haar.tree import HaarTree, build_reference, level_offset, morton_index
from ..integrator import RenderResult
from ..raytrace import RayTracer
from ..scene import check_scene, load_scene
from ..threads import default_threads, map_until_stopped
from ..warp import frame as tangent_frame
from ..warp import to_local
from . import converge_kernels as kernels
from . import lighting
from .bake import BLOCK
from .frame import DeviceEntries
from .settings import FRAME, UNBIASED_SPP

MAX_SPP = FRAME["spp"].hi
#: the product trees' levels at most (finer bakes are summed to them: 2^m x 2^m texels of the
#: transfer are its coefficients' top-left 2^m x 2^m block times 4^(n - m)); inside a texel
#: the lighting's own leaves place the direction (docs/decisions/relight-product-levels.md,
#: docs/decisions/relight-converge-kernels.md: 2^6 x 2^6 trees write four times the memory)
PRODUCT_LEVELS = 5
#: directions (shadow rays) per camera sample (docs/decisions/relight-converge-kernels.md)
SLOTS = 4
#: the mixture's shares: the BSDF (defensive) and the lighting alone; the product has the rest
DEFENSIVE = 0.3
LIGHT_SHARE = 0.1
#: resampled directions (docs/decisions/relight-resampling.md): a camera sample whose pixel's
#: footprint reflects over more than COHERENCE times its lobe's width (:func:`footprint_spread`,
#: :func:`wavlight.bsdfs.lobe_width`) picks its slots among CANDIDATES mixture directions
CANDIDATES = 16
COHERENCE = 0.25
MAX_CANDIDATES = 256
#: the resampling target (:func:`resampling_target`): the sample's lobe to this power, the
#: transfer to the rest, and the shares of f cos and of T that keep it positive
LOBE_POWER = 0.6
TARGET_BSDF = 0.05
TARGET_TRANSFER = 0.1
#: directions per camera sample at most (slot j takes point j of the lattice below)
MAX_SLOTS = len(rng.CONVERGE_DIRECTIONS)
#: a camera sample's slots (and a resampled one's candidates) are the points j of the rank-1
#: lattice of the R4 sequence (Roberts 2018: alpha_i = phi^-i, phi^5 = phi + 1) shifted by one
#: Philox draw of four uniforms, frac(u_i + j alpha_i) (:func:`lattice`): each point uniform,
#: the points of a sample spread over the cube; alpha_i in 24-bit fixed point, so that the sum
#: is exact in float32 (the kernel adds the same floats)
LATTICE = (14372620, 12312662, 10547948, 9036163)
#: sub-pixel rays per side of the fixed grid that measures a pixel's footprint
FOOTPRINT_GRID = 2
#: a tile: at most this many of the bake's blocks of one block row (its trees on the device at
#: once: 2048 pixels, 11 MB at 2^5 x 2^5 texels, 45 MB at 2^6 x 2^6)
TILE_BLOCKS = 8
#: camera samples of a tile taken at once (a pass; more spp, more passes): the memory of a pass
#: stays bounded at any spp
PASS_SAMPLES = 1 << 16
#: and at most this many samples per pixel
PASS_SPP = 64
#: the tiles' trees of the current lighting kept on the device for the next frame, at most this
#: many bytes (and a quarter of the device's global memory)
TREE_CACHE_BYTES = 1 << 30
#: a frame's tile i draws its Philox numbers as tile CONVERGE_TILES + i (streams rng.JITTER,
#: rng.STRATA, rng.CONVERGE_*): not the bake's tiles, so that a frame's camera samples are
#: never the bake's own
CONVERGE_TILES = 13 << 16
BACKENDS = ("opencl", "numpy")


def check_scene_matches(transfer, scene):
    """The scene a bake was made from, as loaded now: a WavlightError if its content or camera
    differs from the bake's (the transfer would be of another scene)."""
    if scene.content_hash != transfer.scene.get("content_hash"):
        raise WavlightError(f"{scene.path}: the scene has changed since {transfer.path} was baked (its content "
                            "hash differs): bake it again")
    cam = transfer.camera
    same = all(np.allclose(getattr(scene.camera, k), cam[k], rtol=0, atol=1e-9) for k in ("eye", "target", "up"))
    if not same or abs(float(scene.camera.fov_y) - float(cam["fov_y"])) > 1e-9:
        raise WavlightError(f"{scene.path}: its camera differs from the one {transfer.path} was baked for")


def check_shares(where: str, defensive, light):
    """The mixture's shares: defensive (the BSDF's) and light (the lighting's) in [0, 1), with
    defensive + light < 1 where a pixel has a product and the BSDF's share left to the others."""
    defensive = check_number(where, "defensive", defensive, 0.0, 1.0)
    light = check_number(where, "light", light, 0.0, 1.0)
    if light >= 1.0 or defensive + light >= 1.0:
        raise ArgumentError(f"{where}: defensive + light must be below 1 (the product's share), got "
                            f"{defensive:g} + {light:g}")
    return defensive, light


def _scene_of(transfer, scene):
    if scene is None:
        path = transfer.scene.get("path")
        if not path:
            raise WavlightError(f"{transfer.path}: baked from a scene given as a dict: pass its scene")
        if not os.path.isfile(path):
            raise WavlightError(f"{transfer.path}: its scene {path} is not there: pass the scene (--scene FILE)")
        scene = load_scene(path)
    elif isinstance(scene, (str, os.PathLike)):
        scene = load_scene(scene)
    check_scene(scene)
    check_scene_matches(transfer, scene)
    return scene


def square_to_world(uv: np.ndarray) -> np.ndarray:
    """World directions (N, 3) of points of the world-frame lat-long square (rotate_y = 0)."""
    phi, theta = 2 * np.pi * uv[:, 0], np.pi * uv[:, 1]
    st = np.sin(theta)
    return np.stack([np.sin(phi) * st, np.cos(theta), -np.cos(phi) * st], 1)


def world_to_square(d: np.ndarray) -> np.ndarray:
    """The inverse of :func:`square_to_world` (points in [0, 1)^2)."""
    u = np.arctan2(d[:, 0], -d[:, 2]) / (2 * np.pi)
    u = u - np.floor(u)
    v = np.arccos(np.clip(d[:, 1], -1.0, 1.0)) / np.pi
    one_below = np.nextafter(1.0, 0.0)
    return np.stack([np.minimum(u, one_below), np.minimum(v, one_below)], 1)


def solid_angle_jacobian(d: np.ndarray) -> np.ndarray:
    """du dv / d omega = 1 / (2 pi^2 sin theta) at world directions (0 at the poles)."""
    s = np.hypot(d[:, 0], d[:, 2])
    with np.errstate(divide="ignore"):
        return np.where(s > 0, 1.0 / (2 * np.pi ** 2 * np.where(s > 0, s, 1.0)), 0.0)


class _Block:
    """A block's stored coefficients, from the bake file's offset table (the twins' input)."""

    def __init__(self, transfer):
        self.offsets = transfer._s["offsets"]

    def coefficients(self, transfer, block: int) -> np.ndarray:
        """(BLOCK^2, 4^n) float32: the block's pixels' dequantized transfer coefficients (every
        coefficient column in the bake's order: flat dense Haar indices)."""
        ids = np.asarray(self.offsets[:, block], np.int64)
        cols = np.flatnonzero(ids >= 0)
        out = np.zeros((BLOCK * BLOCK, len(ids)), np.float32)
        if len(cols):
            q = np.asarray(transfer._s["entry_data"][ids[cols]], np.float32)
            scale = np.asarray(transfer._s["entry_scale"][ids[cols]], np.float32)
            out[:, cols] = (q * scale[:, None]).T
        return out


def tile_coefficients(transfer, tile, levels: int) -> np.ndarray:
    """(w h, 2^m, 2^m) float32: the transfer coefficients of the tile's pixels (row-major in the
    tile) on 2^m x 2^m texels, m = ``levels`` <= n: the top-left 2^m x 2^m block of each
    pixel's 2^n x 2^n coefficients times 4^(n - m), the transform of its summed texels."""
    n, blocks = transfer.n_levels, _Block(transfer)
    side = 1 << levels
    out = np.zeros((tile.h, tile.w, side, side), np.float32)
    for j in range(tile.blocks):   # blocks, not pixels
        c = blocks.coefficients(transfer, tile.block_row * transfer.blocks[0] + tile.bx0 + j)
        c = c.reshape(BLOCK, BLOCK, 1 << n, 1 << n)[:tile.h, :, :side, :side] * np.float32(4.0 ** (n - levels))
        x = j * BLOCK
        out[:, x:x + BLOCK] = c[:, :min(BLOCK, tile.w - x)]
    return out.reshape(tile.w * tile.h, side, side)


class Tile(NamedTuple):
    """A tile of the image: ``blocks`` of the bake's blocks of block row ``block_row`` from block
    column ``bx0``, the pixels x0 .. x0 + w - 1, y0 .. y0 + h - 1 (clipped to the image)."""

    index: int
    block_row: int
    bx0: int
    blocks: int
    x0: int
    y0: int
    w: int
    h: int


def tiles_of(transfer) -> list:
    """The image's tiles: TILE_BLOCKS blocks of a block row each (fewer at the right edge)."""
    bw, bh = transfer.blocks
    out = []
    for by in range(bh):
        for bx0 in range(0, bw, TILE_BLOCKS):
            nb = min(TILE_BLOCKS, bw - bx0)
            x0, y0 = bx0 * BLOCK, by * BLOCK
            out.append(Tile(len(out), by, bx0, nb, x0, y0, min(nb * BLOCK, transfer.width - x0),
                            min(BLOCK, transfer.height - y0)))
    return out


class _LightingState:
    """One lighting of a ConvergeFrames: its key, the lighting inside the texels, its tables on
    the device and the tiles' trees kept under it."""

    def __init__(self, key, inside, device):
        self.key, self.inside, self.device = key, inside, device
        self.trees, self.kept_bytes = {}, 0
        self.lock = threading.Lock()


def _environment_key(env):
    """What identifies a frame's map: None (the baked one), a file or data: name, or an
    Environment object (by identity; the ConvergeFrames keeps it)."""
    if env is None or isinstance(env, (str, os.PathLike)):
        return ("map", None if env is None else os.fspath(env))
    return ("object", id(env))


class ConvergeFrames:
    """Unbiased frames of one lighting bake (module docstring): ``frame(env, rotate_y, scale,
    spp, seed, ...)``. ``scene``: the scene the transfer was baked from (default: reloaded from
    the path the bake recorded; refused if it changed). ``backend="numpy"`` runs the kernels'
    numpy twins (same random numbers, same estimator; slow: tests). What does not depend on the
    lighting is made here and kept; what does, per lighting, and kept while frames keep it."""

    def __init__(self, transfer, scene=None, threads=None, backend: str = "opencl"):
        if transfer.header.get("vary", "lighting") != "lighting":
            raise WavlightError(f"{transfer.path}: this bake varies the {transfer.header.get('vary')}, not the "
                                "lighting: its unbiased frames are its own")
        if backend not in BACKENDS:
            raise ArgumentError(f"relight.ConvergeFrames: backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
        self.transfer, self.backend = transfer, backend
        self.threads = threads
        self.scene = _scene_of(transfer, scene)
        t0 = time.perf_counter()
        sc = self.scene
        self.tracer = RayTracer(sc.vertices, sc.faces, threads=1)
        self.hit_scale = hit_scales(transfer).astype(np.float32)
        #: the trees' scale: c, and 0 where every camera sample of the bake missed (no transfer: no tree)
        self.tree_scale = np.where(bake_hits(transfer) > 0, self.hit_scale, 0.0).astype(np.float32)
        self.tiles = tiles_of(transfer)
        self.lobe_width = bsdfs.lobe_width(sc.material_kind, sc.material_param).astype(np.float32)
        self._spread, self._spread_rays = {}, 0
        self._lighting = None
        self._spare = {}   # tile -> TileTrees of a lighting no longer current, their buffers for reuse
        self._map = None   # (map key, its Environment, its lighting.Projector, env): the last map's
        self._sections = transfer._s
        self._lock = threading.Lock()
        if backend == "opencl":
            device = cl.runtime().device
            self.tree_cache_bytes = min(TREE_CACHE_BYTES, int(device.global_mem_size) // 4)
            entries = DeviceEntries(transfer._s["offsets"], transfer._s["entry_scale"], transfer._s["entry_data"])
            self._trees = kernels.TreeKernel(entries, transfer._s["offsets"], self.tree_scale, transfer.n_levels,
                                             transfer.blocks[0], transfer.width)
            self._shade = kernels.ShadeKernel(sc, self.tracer, self.lobe_width)
            camera.warm_up(sc)
        else:
            self.tree_cache_bytes = 0
        self.setup_seconds = time.perf_counter() - t0

    def serves(self, transfer, scene) -> bool:
        """Whether this holds ``transfer`` (open, the same sections) and ``scene`` (the same
        object, or None where this one was reloaded from the bake's path)."""
        return transfer._s is self._sections and bool(self._sections) and (scene is None or scene is self.scene)

    # -- what frames share
    def program(self, levels: int, slots: int, candidates: int, control: bool, background: str = "nearest"):
        """kernels/converge.cl for this bake and scene (:func:`.converge_kernels.program`)."""
        return kernels.program(levels, self.transfer.bits, self._shade.kinds, slots, candidates, control, LATTICE,
                               background)

    def spread(self, tile, prog=None):
        """The footprint spread of the tile's pixels (measured once): (w h,) float32 on the host
        and its device buffer (kernel ``converge_spread`` of ``prog``; twin footprint_spread)."""
        with self._lock:
            s = self._spread.get(tile.index)
        if s is None:
            tr = self.transfer
            if self.backend == "opencl" and prog is not None:
                d, prim = footprint_rays(self.scene, self.tracer, tile.x0, tile.y0, tile.w, tile.h, tr.width,
                                         tr.height)
                s = self._shade.spread(prog, d, prim, FOOTPRINT_GRID ** 2)
            else:
                s = footprint_spread(self.scene, self.tracer, tile.x0, tile.y0, tile.w, tile.h, tr.width,
                                     tr.height).astype(np.float32)
                s = (cl.to_device(s) if self.backend == "opencl" else None, s)
            with self._lock:
                self._spread[tile.index] = s = (s[1], s[0])
                self._spread_rays += tile.w * tile.h * FOOTPRINT_GRID ** 2
        return s

    def lighting(self, env, rotate_y: float, scale: float, levels: int) -> _LightingState:
        """The lighting state of (env, rotate_y, scale) on 2^levels texels: the current one, or
        made anew (the current one's trees released)."""
        key = (_environment_key(env), float(rotate_y), float(scale), int(levels))
        current = self._lighting
        if current is not None and current.key == key:
            return current
        if current is not None:   # its trees' buffers serve the new lighting's (no new pages to fault in)
            self._spare = current.trees
        self._lighting = None
        env_key = key[0] + (float(scale),)
        same_map = (self._map is not None and self._map[0] == env_key
                    and (env_key[0] == "map" or self._map[3] is env))   # (an object: the very one)
        if same_map:   # another rotation of the same map
            base, projector = self._map[1], self._map[2]
        else:
            base, projector = self.transfer.environment(env, scale), None   # unrotated, scaled
        inside = _TexelLight(base, levels, rotate_y, projector=projector)
        self._map = (env_key, base, inside.projector, env)
        device = kernels.Lighting(inside.tables()) if self.backend == "opencl" else None
        state = _LightingState(key, inside, device)
        state.env = env   # (an Environment object's identity is its key: keep it alive)
        self._lighting = state
        return state

    def tile_trees(self, state, tile, prog):
        """The tile's product trees under the lighting ``state``: kept ones, or built (and kept
        while they fit in tree_cache_bytes); with the numpy backend (HaarTree, host nodes, G)."""
        with state.lock:
            kept = state.trees.get(tile.index)
        if kept is not None:
            return kept, True
        m = state.inside.n
        if self.backend == "numpy":
            coeffs = tile_coefficients(self.transfer, tile, m)
            scale = self.tree_scale[tile.y0:tile.y0 + tile.h, tile.x0:tile.x0 + tile.w].reshape(-1)
            nodes, relit = tile_trees_reference(coeffs, state.inside, scale)
            return (HaarTree.from_pyramids(nodes), nodes, relit), False
        nbytes = kernels.TileTrees(None, None, tile.w * tile.h, m).nbytes
        with state.lock:
            keep = state.kept_bytes + nbytes <= self.tree_cache_bytes
            if keep:
                state.kept_bytes += nbytes
            spare = self._spare.pop(tile.index, None) if keep else None
        if spare is not None and spare.levels != m:
            spare = None
        made = self._trees(prog, state.device, tile, into=spare if keep else "scratch")
        if keep:
            with state.lock:
                state.trees[tile.index] = made
        return made, False

    # -- a frame
    def frame(self, env=None, rotate_y=None, scale: float = FRAME["scale"].default, spp: int = UNBIASED_SPP,
              seed: int = FRAME["seed"].default, progress=None, slots: int = SLOTS, defensive: float = DEFENSIVE,
              levels: int = PRODUCT_LEVELS, light: float = LIGHT_SHARE, control: bool = True,
              candidates: int = CANDIDATES, coherence: float = COHERENCE,
              background: str = FRAME["background"].default) -> RenderResult:
        """The unbiased frame under ``env`` (default: the baked map; a file, data:NAME or an
        Environment) turned to ``rotate_y`` (default: the scene's) and scaled, with ``spp`` camera
        samples per pixel, each with ``slots`` directions of the defensive mixture (module
        docstring). The product trees have min(n, ``levels``) levels. With ``control`` (and a
        lighting share ``light`` > 0) the pixel's relit value G is the control variate's known
        integral. A camera sample whose pixel's footprint reflects over more than ``coherence``
        times its lobe's width resamples its slots from ``candidates`` directions (0: never).
        Camera samples that miss see the map's pixel, or with ``background="bilinear"`` its
        bilinear filter (display only). Returns a RenderResult: image, per-pixel standard error, stats."""
        where = "relight.converge"
        background = FRAME["background"].check(background, where)
        spp, seed = FRAME["spp"].check(spp, where), FRAME["seed"].check(seed, where)
        levels = check_int(where, "levels", levels, 1, 16)
        slots = check_int(where, "slots", slots, 1, MAX_SLOTS)
        candidates = check_int(where, "candidates", candidates, 0, MAX_CANDIDATES)
        coherence = check_number(where, "coherence", coherence, 0.0, None)
        defensive, light = check_shares(where, defensive, light)
        scale = FRAME["scale"].check(scale, where)
        if rotate_y is not None:
            rotate_y = check_degrees(where, "rotate_y", rotate_y)
        if progress is not None and not callable(progress):
            raise ArgumentError(f"{where}: progress must be a callable or None")
        use_control = bool(control) and light > 0
        tr = self.transfer
        rot = tr.scene_rotate_y if rotate_y is None else float(rotate_y)
        m = min(tr.n_levels, levels)
        t0 = time.perf_counter()
        state = self.lighting(env, rot, scale, m)
        lighting_seconds = time.perf_counter() - t0
        prog = None
        if self.backend == "opencl":
            prog = self.program(m, slots, candidates, use_control, background)
        width, height = tr.width, tr.height
        sums = np.zeros((height, width, 3))
        squares = np.zeros((height, width, 3))
        totals = {"rays": 0, "done": 0, "hits": 0, "resampled": 0, "kept": 0}
        lock = threading.Lock()
        shares = (defensive, light, coherence)
        eye = np.broadcast_to(self.scene.camera.eye.astype(np.float32), (1, 3))
        spread_rays = self._spread_rays

        def one(tile, stop):
            trees, was_kept = self.tile_trees(state, tile, prog)
            spread = self.spread(tile, prog) if candidates else (np.zeros(tile.w * tile.h, np.float32), None)
            if self.backend == "opencl" and spread[1] is None:
                spread = (spread[0], cl.to_device(spread[0]))
            if prog is not None:
                self._shade.warm_up(prog, slots, trees, spread[1], state.device, shares)
            P = tile.w * tile.h
            tile_id = CONVERGE_TILES + tile.index
            per_pass = pass_spp(spp, P)
            s_sum, s_sq = np.zeros((P, 3)), np.zeros((P, 3))
            rays = hits = chosen = 0
            for first in range(0, spp, per_pass):   # passes of samples per pixel, not samples: bounded memory
                if stop.is_set():   # the caller stopped waiting (an error, Ctrl-C)
                    return
                k = min(per_pass, spp - first)
                d = camera.pass_rays(self.scene, width, height, seed, tile_id, tile.x0, tile.y0, tile.w, tile.h, k,
                                     first * P, kernel=self.backend == "opencl", stratified=True)
                prim, t = self.tracer.intersect(np.broadcast_to(eye, d.shape), d)
                rays += len(d)
                if self.backend == "opencl":
                    direct, origin, wi, value = self._shade(prog, slots, d, prim, t, k, first * P, trees, spread[1],
                                                            state.device, shares, seed, tile_id)
                else:
                    direct, origin, wi, value = shade_reference(
                        self.scene, self.tracer, d, prim, t, k, trees[0], trees[1], trees[2], spread[0], state.inside,
                        (seed, tile_id), first * P, slots, defensive, light, use_control, candidates, coherence,
                        background)
                v, traced = visible_sum(self.tracer, direct, origin, wi, value)
                rays += traced
                hit = prim >= 0
                hits += int(hit.sum())
                if candidates:
                    mat = self.scene.face_material[prim[hit]]
                    chosen += int((spread[0][np.flatnonzero(hit) // k] > coherence * self.lobe_width[mat]).sum())
                v = v.reshape(P, k, 3)
                s_sum += v.sum(1)
                s_sq += (v * v).sum(1)
            img = (slice(tile.y0, tile.y0 + tile.h), slice(tile.x0, tile.x0 + tile.w))
            with lock:
                sums[img] += s_sum.reshape(tile.h, tile.w, 3)
                squares[img] += s_sq.reshape(tile.h, tile.w, 3)
                totals["rays"] += rays
                totals["done"] += 1
                totals["hits"] += hits
                totals["resampled"] += chosen
                totals["kept"] += int(was_kept)
                if progress:
                    progress(totals["done"], len(self.tiles), totals["rays"], time.perf_counter() - t0)

        threads = self.threads or default_threads()
        map_until_stopped(one, self.tiles, threads)
        self._spare = {}
        seconds = time.perf_counter() - t0
        mean, err = mean_and_error(sums, squares, spp)
        max_tile = max(t.w * t.h for t in self.tiles)
        rays = totals["rays"] + self._spread_rays - spread_rays
        stats = {"spp": spp, "seed": seed, "width": width, "height": height, "render_seconds": round(seconds, 4),
                 "lighting_seconds": round(lighting_seconds, 4), "rays": rays,
                 "rays_per_second": round(rays / seconds, 1) if seconds > 0 else None,
                 "rotate_y": rot, "background": background,
                 "product_levels": m, "slots": slots, "candidates": candidates,
                 "pass_spp": pass_spp(spp, max_tile), "pass_samples": max_tile * pass_spp(spp, max_tile),
                 "tiles": len(self.tiles), "tiles_kept": totals["kept"], "kept_tree_bytes": state.kept_bytes,
                 "backend": self.backend,
                 "resampled_share": round(totals["resampled"] / totals["hits"], 4) if totals["hits"] else 0.0,
                 "estimator": "product T1 x L (eq. 25) + BSDF + lighting, defensive mixture"
                              + (", the relit frame as control variate" if use_control else "")
                              + (", resampled where the pixel's footprint is wider than the lobe" if candidates else "")}
        return RenderResult(mean.astype(np.float32), err.astype(np.float32), stats)

    def release_lighting(self):
        """Drop the current lighting's tables and kept trees: the next frame makes them anew (in
        new buffers)."""
        self._lighting = None
        self._spare = {}

    def close(self):
        """Release the device memory of the kept trees, tables and footprints."""
        self._lighting = self._map = None
        self._spare = {}
        self._spread = {}


def pass_spp(spp: int, pixels: int) -> int:
    """Camera samples per pixel of one pass over a tile of ``pixels``: at most PASS_SPP, and
    PASS_SAMPLES in all."""
    return max(1, min(spp, PASS_SPP, PASS_SAMPLES // pixels))


def visible_sum(tracer, direct, origin, wi, value):
    """(N, 3) float64 per camera sample: ``direct`` plus its slots' estimates ``value`` (S, 3, N)
    whose shadow rays from ``origin`` (N, 3) along ``wi`` (S, 3, N) are not blocked; only the
    estimates that are not 0 are traced. Returns it and the rays traced."""
    S, _, N = value.shape
    live = np.flatnonzero(np.maximum(np.maximum(value[:, 0], value[:, 1]), value[:, 2]) > 0)   # slot N + sample
    pt = live % N
    dirs = np.stack([wi[:, c, :].reshape(-1)[live] for c in range(3)], 1)   # three components, not samples
    blocked = tracer.occluded(np.take(origin, pt, axis=0), np.asarray(dirs, np.float32))
    visible = np.zeros(S * N, value.dtype)
    visible[live] = ~blocked
    return np.asarray(direct, np.float64) + (value * visible.reshape(S, 1, N)).sum(0).T, len(live)


_LAST = {"frames": None, "transfer": None}
_LAST_LOCK = threading.Lock()


def converge(transfer, scene=None, env=None, rotate_y=None, scale: float = FRAME["scale"].default,
             spp: int = UNBIASED_SPP, seed: int = FRAME["seed"].default, threads=None, progress=None, slots: int = SLOTS,
             defensive: float = DEFENSIVE, levels: int = PRODUCT_LEVELS, light: float = LIGHT_SHARE,
             control: bool = True, candidates: int = CANDIDATES, coherence: float = COHERENCE,
             backend: str = "opencl", background: str = FRAME["background"].default) -> RenderResult:
    """The unbiased frame of ``transfer`` under ``env`` (default: the baked map) turned to
    ``rotate_y`` (default: the scene's) and scaled, with ``spp`` camera samples per pixel: one
    frame of a :class:`ConvergeFrames` (its ``frame`` documents the other arguments), the one of
    the last call where it holds the same transfer and scene (the same object, or None again),
    so that another call under the same lighting pays only for its samples. ``scene``: the scene
    the transfer was baked from (default: reloaded from the path the bake recorded; refused if
    it changed). The stats' ``frame_seconds``: this call's time after the bake and scene were
    loaded (the ConvergeFrames it made, if any, and the frame: ``setup_seconds`` +
    ``render_seconds``)."""
    with _LAST_LOCK:
        frames = _LAST["frames"]
        same = (frames is not None and _LAST["transfer"]() is transfer and frames.backend == backend
                and frames.threads == threads and frames.serves(transfer, scene))
        if not same:
            _LAST["frames"] = _LAST["transfer"] = frames = None
            if scene is None or isinstance(scene, (str, os.PathLike)):
                scene = _scene_of(transfer, scene)   # loaded: not part of the frame's time
            frames = ConvergeFrames(transfer, scene, threads, backend)
            _LAST["frames"], _LAST["transfer"] = frames, weakref.ref(transfer)
            setup = frames.setup_seconds
        else:
            setup = 0.0
        result = frames.frame(env, rotate_y, scale, spp, seed, progress, slots, defensive, levels, light, control,
                              candidates, coherence, background)
    result.stats["setup_seconds"] = round(setup, 4)
    result.stats["frame_seconds"] = round(setup + result.stats["render_seconds"], 4)
    return result


def footprint_rays(scene, tracer, x0: int, y0: int, w: int, h: int, width: int, height: int):
    """The fixed FOOTPRINT_GRID x FOOTPRINT_GRID grid of rays through each pixel of the w x h tile
    at (x0, y0), pixel-major: directions (P G^2, 3) float32 and the faces they hit (-1: a miss)."""
    g = FOOTPRINT_GRID
    P = w * h
    pix = np.repeat(np.arange(P), g * g)
    sub = (np.stack(np.meshgrid(np.arange(g), np.arange(g)), -1).reshape(-1, 2) + 0.5) / g
    eye, d = camera_rays(scene, x0 + pix % w, y0 + pix // w, np.tile(sub, (P, 1)).astype(np.float32), width, height)
    return d, tracer.intersect(eye, d)[0]


def footprint_spread(scene, tracer, x0: int, y0: int, w: int, h: int, width: int, height: int) -> np.ndarray:
    """(h w,) the angular spread, radians, of the mirror directions over each pixel of the w x h
    tile at (x0, y0): rays through a fixed FOOTPRINT_GRID x FOOTPRINT_GRID grid of the pixel
    (deterministic: the choice it feeds does not depend on the frame's random numbers),
    sqrt(2 (1 - |mean r|)) of the hits' unit mirror directions r (for small angles, about their
    root-mean-square angle from their mean; 0 where at most one ray hits, so that such a pixel's
    samples are never resampled). A pixel's transfer is the mean of its
    camera samples' lobes: where their mirror directions spread wider than the lobe, the
    transfer is wider than any one sample's lobe."""
    g = FOOTPRINT_GRID
    P = w * h
    pix = np.repeat(np.arange(P), g * g)
    d, prim = footprint_rays(scene, tracer, x0, y0, w, h, width, height)
    hit = np.flatnonzero(prim >= 0)
    nrm = tracer.face_normals[prim[hit]].astype(np.float64)
    dh = d[hit].astype(np.float64)
    nrm *= np.where(np.einsum("ij,ij->i", nrm, dh) > 0, -1.0, 1.0)[:, None]   # turned towards the viewer
    mirror = dh - 2.0 * np.einsum("ij,ij->i", dh, nrm)[:, None] * nrm
    sums = np.stack([np.bincount(pix[hit], mirror[:, k], P) for k in range(3)], 1)   # 3 axes, not pixels
    count = np.bincount(pix[hit], minlength=P)
    length = np.linalg.norm(sums, axis=1) / np.maximum(count, 1)
    return np.where(count > 1, np.sqrt(np.maximum(2.0 * (1.0 - length), 0.0)), 0.0)


def bake_hits(transfer) -> np.ndarray:
    """(H, W) float64: how many of the bake's S camera samples of each pixel hit a surface."""
    hits = np.full(transfer.width * transfer.height, float(transfer.spp))
    pixels = np.asarray(transfer._s["background_pixel"], np.int64)
    if len(pixels):
        mask = np.asarray(transfer._s["background_mask"], np.uint64)
        hits[pixels] -= np.unpackbits(mask.view(np.uint8).reshape(-1, 8), axis=1).sum(1)
    return hits.reshape(transfer.height, transfer.width)


def hit_scales(transfer) -> np.ndarray:
    """(H, W) S / hits: the bake's camera samples over those of them that hit, per pixel (1 where
    all miss). The transfer is a mean over all S samples, misses counted as 0; a camera sample of
    the frame that hits is closer to the transfer of the hits alone, on a silhouette's pixels
    too. A constant per pixel: the control variate (g and G alike) stays unbiased."""
    hits = bake_hits(transfer)
    return np.where(hits > 0, transfer.spp / np.maximum(hits, 1.0), 1.0)


class _TexelLight:
    """The lighting inside the transfer's texels at the map's resolution: leaf masses (exact
    integrals of luminance, world frame, turned) grouped by texel, for sampling a point inside a
    texel in proportion to them and for the density factor of that choice.

    The leaves are the world-frame square's 2^m x 2^m cells (m >= the map's square levels, so a
    leaf is at most one map pixel wide and tall). Turned by an angle that is not a whole number
    of map columns, a leaf overlaps up to 2 x 2 of the map's pixels; with ``map_pixels`` (the
    default) the point is placed inside the leaf in proportion to those pieces (their luminance
    times their share of the leaf's solid angle), so that a sun one map pixel wide is sampled in
    proportion to its own radiance, not to its leaf's mean with a dark neighbour; and
    :meth:`radiance` is the map pixel's. Without, the point is uniform in its leaf (what the
    moving object's kernel does, kernels/relight_moving.cl)."""

    def __init__(self, environment, n_levels: int, rotate_y: float, map_pixels: bool = True, projector=None):
        top = max(environment.square_levels(), n_levels)
        if projector is None or projector.environment is not environment or projector.n_levels != top:
            projector = lighting.Projector(environment, top)
        self.projector = projector   # (for another rotation of the same map: :meth:`Projector.__call__` alone)
        rgb = projector(rotate_y)
        leaf_angles = lighting.texel_solid_angles(top)[:, None]
        masses = luminance(rgb) * leaf_angles                                          # (M, M)
        self.n, self.top, self.k = n_levels, top, 1 << (top - n_levels)
        self.rotate_y = float(rotate_y)
        side, k = 1 << n_levels, self.k
        self.rgb = rgb
        self.texel_angles = lighting.texel_solid_angles(n_levels)
        # each texel's mean radiance: its leaves' integrals over its solid angle (exact, nested)
        self.texel_radiance = ((rgb * leaf_angles[:, :, None]).reshape(side, k, side, k, 3).sum((1, 3))
                               / self.texel_angles[:, None, None]).reshape(side * side, 3)
        blocks = masses.reshape(side, k, side, k).transpose(0, 2, 1, 3).reshape(side * side, k * k)
        self.texel_mass = blocks.sum(1)
        self.texel_luminance = (self.texel_mass.reshape(side, side)
                                / lighting.texel_solid_angles(n_levels)[:, None])
        self.cdf = np.cumsum(blocks, axis=1)
        self.blocks = blocks
        self.map_pixels = bool(map_pixels)
        if self.map_pixels:
            self._pieces(environment, rotate_y)

    def _pieces(self, environment, rotate_y: float):
        """Per leaf column: the map columns of its two pieces and the first's share of the leaf's
        width; per leaf row: the map rows, the first's share of the height and of the solid angle
        (the map turned by rotate_y: map u = world u + rotate_y / 360, as lighting.Projector)."""
        count = 1 << self.top
        h, w = environment.height, environment.width
        self.map_rgb = environment.pixels.astype(np.float64)
        self.map_lum = luminance(self.map_rgb)
        x0 = ((np.arange(count) / count + float(rotate_y) / 360.0) % 1.0) * w   # a leaf's left edge, map columns
        first = np.floor(x0)
        self.col_share = np.clip((first + 1.0 - x0) * count / w, 0.0, 1.0)
        self.cols = np.stack([first.astype(np.int64) % w, (first.astype(np.int64) + 1) % w])
        y0 = np.arange(count) * h / count
        first = np.floor(y0)
        self.row_share = np.clip((first + 1.0 - y0) * count / h, 0.0, 1.0)
        self.rows = np.stack([np.minimum(first.astype(np.int64), h - 1), np.minimum(first.astype(np.int64) + 1, h - 1)])
        theta = np.pi * np.arange(count + 1) / count
        split = np.pi * (np.arange(count) + self.row_share) / count
        band = np.cos(theta[:-1]) - np.cos(theta[1:])                  # > 0: every row has solid angle
        self.row_angle_share = np.clip((np.cos(theta[:-1]) - np.cos(split)) / band, 0.0, 1.0)

    def _piece_masses(self, a, b):
        """(4, N) the pieces' luminance times their share of leaf (column a, row b)'s solid angle,
        in the order (row 0, col 0), (row 0, col 1), (row 1, col 0), (row 1, col 1)."""
        wc, wr = self.col_share[a], self.row_angle_share[b]
        out = []
        for r, share_r in ((0, wr), (1, 1.0 - wr)):        # the 2 x 2 pieces, not samples
            for c, share_c in ((0, wc), (1, 1.0 - wc)):
                out.append(self.map_lum[self.rows[r, b], self.cols[c, a]] * share_c * share_r)
        return np.stack(out)

    def _place_in_leaf(self, a, b, su, sv):
        """Points (fu, fv) inside leaves (column a, row b) from uniforms su, sv, in proportion to
        the pieces' masses, and the density factor of that placement against uniform in the leaf."""
        m = self._piece_masses(a, b)
        total = m.sum(0)
        top = m[0] + m[1]
        one_below = np.nextafter(1.0, 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            lower = sv * total >= top                       # the second row piece
            sv2 = np.where(lower, (sv * total - top) / (total - top), sv * total / top)
            sv2 = np.where(np.isfinite(sv2), np.clip(sv2, 0.0, one_below), sv)
            m0, m1 = np.where(lower, m[2], m[0]), np.where(lower, m[3], m[1])
            right = su * (m0 + m1) >= m0
            su2 = np.where(right, (su * (m0 + m1) - m0) / m1, su * (m0 + m1) / m0)
            su2 = np.where(np.isfinite(su2), np.clip(su2, 0.0, one_below), su)
        hc, hr = self.col_share[a], self.row_share[b]
        fu = np.where(right, hc + su2 * (1.0 - hc), su2 * hc)
        fv = np.where(lower, hr + sv2 * (1.0 - hr), sv2 * hr)
        return fu, fv, self._piece_factor(m, total, right, lower, a, b)

    def _piece_factor(self, m, total, right, lower, a, b):
        """The density of a point in piece (lower, right) of leaves (a, b) against uniform in the
        leaf: the piece's share of the leaf's mass over its share of the leaf's area."""
        piece = np.where(lower, np.where(right, m[3], m[2]), np.where(right, m[1], m[0]))
        area = (np.where(right, 1.0 - self.col_share[a], self.col_share[a])
                * np.where(lower, 1.0 - self.row_share[b], self.row_share[b]))
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.where((total > 0) & (area > 0),
                         piece / np.where(total > 0, total, 1.0) / np.where(area > 0, area, 1.0), 0.0)
        return f

    def _leaf_of(self, uv):
        """Leaf column a and row b of points uv, and whether each lies in its leaf's second
        column piece (right) and second row piece (lower) of the map's pixels."""
        count = 1 << self.top
        x = np.asarray(uv, np.float64) * count
        cell = np.minimum(x.astype(np.int64), count - 1)
        a, b = cell[:, 0], cell[:, 1]
        if not self.map_pixels:
            return a, b, None, None
        return a, b, x[:, 0] - a >= self.col_share[a], x[:, 1] - b >= self.row_share[b]

    def leaf_masses(self) -> np.ndarray:
        """(2^n, 2^n) float32: the lighting's luminance mass of each texel on the unit square,
        its mean luminance times 4^-n: the factor gl_t of the product trees' leaves (eq. 25 at
        the finest level: the box mass of the lighting times the transfer's texel value)."""
        side = 1 << self.n
        return (self.texel_luminance * (1.0 / (side * side))).astype(np.float32)

    def tables(self) -> dict:
        """The lighting on the device's terms (kernels/converge.cl LIGHT_ARGS), float32 and uint32
        bits: the running sums of each texel's leaf masses (leaf_cdf, texel-major), each texel's
        last one (texel_total), the guide to them (leaf_guide: per texel and cell g of k^2 cells,
        how many running sums are <= (g / k^2) total, in float32 as the kernel multiplies), the
        running sum of the texels' masses (texel_cdf), per leaf column its first map column's share of the leaf's
        width and its two map columns (columns), per leaf row the first map row's share of the
        leaf's height and of its solid angle and its two map rows (rows), the map's pixels
        (r, g, b, luminance), and per texel in Morton order (the trees' leaf order) the leaf
        masses of :meth:`leaf_masses` and the mean radiance (r, g, b, 0); the texel rows' solid
        angles (omega)."""
        if not self.map_pixels:
            raise ArgumentError("relight._TexelLight.tables: the kernels place points by the map's pixels")
        count, side = 1 << self.top, 1 << self.n
        columns = np.zeros((count, 4), np.float32)
        columns[:, 0] = self.col_share
        columns.view(np.uint32)[:, 1:3] = self.cols.T.astype(np.uint32)
        rows = np.zeros((count, 4), np.float32)
        rows[:, 0], rows[:, 1] = self.row_share, self.row_angle_share
        rows.view(np.uint32)[:, 2:4] = self.rows.T.astype(np.uint32)
        h, w = self.map_lum.shape
        pixels = np.empty((h * w, 4), np.float32)
        pixels[:, :3] = self.map_rgb.reshape(-1, 3)
        pixels[:, 3] = self.map_lum.reshape(-1)
        row, col = np.divmod(np.arange(side * side), side)
        morton = np.argsort(morton_index(col, row))        # texel (row-major) of each Morton index
        radiance = np.zeros((side * side, 4), np.float32)
        radiance[:, :3] = self.texel_radiance[morton]
        cdf = np.ascontiguousarray(self.cdf, np.float32)                      # (texels, k^2), rows non-decreasing
        texels, kk = cdf.shape
        total = cdf[:, -1]
        cells = (np.arange(kk + 1, dtype=np.float32) / np.float32(kk))[None, :] * total[:, None]   # float32 products
        # counts per row by one search: non-negative float32 bits order as their values; the
        # texel's index above them keeps the rows apart
        offset = np.arange(texels, dtype=np.int64)[:, None] << 32
        keys = (offset | cdf.view(np.uint32).astype(np.int64)).reshape(-1)
        guide = np.searchsorted(keys, (offset | cells.view(np.uint32).astype(np.int64)).reshape(-1), side="right")
        guide = (guide.reshape(texels, kk + 1) - np.arange(texels)[:, None] * kk).astype(np.uint32)
        return {"levels": self.n, "top": self.top, "kbits": self.top - self.n, "map_width": w, "map_height": h,
                "map_shift": np.float32(self.rotate_y / 360.0),
                "leaf_cdf": cdf.reshape(-1), "texel_total": np.ascontiguousarray(total),
                "leaf_guide": guide.reshape(-1),
                "texel_cdf": np.cumsum(self.texel_mass).astype(np.float32), "columns": columns, "rows": rows,
                "map": pixels, "map_lum": np.ascontiguousarray(pixels[:, 3]), "leaf_masses": np.ascontiguousarray(self.leaf_masses().reshape(-1)[morton]),
                "radiance": radiance, "omega": self.texel_angles.astype(np.float32)}

    def radiance(self, uv):
        """(N, 3): the lighting's radiance at points uv of the square: the map pixel's under the
        point (with ``map_pixels``; the piece of its leaf that holds it), else its leaf's mean."""
        a, b, right, lower = self._leaf_of(uv)
        if not self.map_pixels:
            return self.rgb[b, a]
        row = np.where(lower, self.rows[1, b], self.rows[0, b])
        return self.map_rgb[row, np.where(right, self.cols[1, a], self.cols[0, a])]

    def background(self, uv, background: str = "nearest"):
        """(N, 3): what camera rays that miss see at points uv of the world-frame square: the map
        pixel (:meth:`radiance`), or with ``background="bilinear"`` the turned map filtered
        bilinearly (:func:`wavlight.envmap.bilinear`, the kernel's float32 steps)."""
        if background != "bilinear":
            return self.radiance(uv)
        u = np.asarray(uv[:, 0], np.float32) + np.float32(self.rotate_y / 360.0)
        return bilinear(self.map_rgb, u - np.floor(u), uv[:, 1]).astype(np.float64)

    def _texel(self, uv):
        side = 1 << self.n
        cell = np.minimum((uv * side).astype(np.int64), side - 1)
        return cell[:, 1] * side + cell[:, 0], uv * side - cell

    def sample(self, uv):
        """Points of the product tree's texels (uniform inside them) moved to a leaf chosen by the
        luminance inside the texel (the point's position in its texel reused as the uniforms),
        then inside the leaf by the map's pixels (``map_pixels``): (uv (N, 2), density factor
        (N,) against uniform in the texel)."""
        t, frac = self._texel(uv)
        k, side = self.k, 1 << self.n
        one_below = np.nextafter(1.0, 0.0)
        if k == 1:
            leaf = np.zeros(len(uv), np.int64)
            s, factor = np.clip(frac[:, 0], 0.0, one_below), np.where(self.texel_mass[t] > 0, 1.0, 0.0)
        else:
            total = self.texel_mass[t]
            target = frac[:, 0] * total
            leaf = np.minimum(_entries_at_most(self.cdf, t, target), k * k - 1)
            below = np.where(leaf > 0, self.cdf[t, np.maximum(leaf - 1, 0)], 0.0)
            mass = self.blocks[t, leaf]
            with np.errstate(divide="ignore", invalid="ignore"):
                s = np.where(mass > 0, (target - below) / np.where(mass > 0, mass, 1.0), frac[:, 0])
                factor = np.where(total > 0, mass / np.where(total > 0, total, 1.0) * k * k, 0.0)
            s = np.clip(s, 0.0, one_below)
        a = (t % side) * k + leaf % k
        b = (t // side) * k + leaf // k
        sv = np.clip(frac[:, 1], 0.0, one_below)
        if self.map_pixels:
            fu, fv, inner = self._place_in_leaf(a, b, s, sv)
            factor = factor * inner
        else:
            fu, fv = s, sv
        count = 1 << self.top
        out = np.stack([np.minimum((a + fu) / count, one_below), np.minimum((b + fv) / count, one_below)], 1)
        return out, factor

    def sample_light(self, a, b, c):
        """Points of the square drawn from the lighting alone: a texel in proportion to its mass
        by ``a``, then the point (b, c) of the texel moved to a leaf by :meth:`sample` (three
        uniforms, so that each choice has all of its bits): the lighting's technique of the
        mixture, density :meth:`light_pdf` per unit square."""
        cdf = self._texel_cdf()
        t = np.minimum(np.searchsorted(cdf, a * cdf[-1], side="right"), len(cdf) - 1)
        side = 1 << self.n
        one_below = np.nextafter(1.0, 0.0)
        uv = np.stack([(t % side + np.clip(b, 0.0, one_below)) / side, (t // side + np.clip(c, 0.0, one_below)) / side],
                      1)
        return self.sample(uv)[0]

    def light_pdf(self, uv):
        """The density per unit square of :meth:`sample_light` at points uv (N, 2)."""
        t, _ = self._texel(uv)
        total = self._texel_cdf()[-1]
        if total <= 0:
            return np.zeros(len(uv))
        return self.texel_mass[t] / total * float(4 ** self.n) * self.factor(uv)

    def _texel_cdf(self):
        if getattr(self, "_cdf", None) is None:
            self._cdf = np.cumsum(self.texel_mass)
        return self._cdf

    def factor(self, uv):
        """The density factor of :meth:`sample` at points uv (N, 2) against uniform in the texel:
        (leaf mass / texel mass) k^2, times the piece's inside the leaf (``map_pixels``); 0 where
        the texel holds no light."""
        t, _ = self._texel(uv)
        k = self.k
        a, b, right, lower = self._leaf_of(uv)
        total = self.texel_mass[t]
        leaf = (b % k) * k + a % k
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.where(total > 0, self.blocks[t, leaf] / np.where(total > 0, total, 1.0) * k * k, 0.0)
        if self.map_pixels:
            m = self._piece_masses(a, b)
            f = f * self._piece_factor(m, m.sum(0), right, lower, a, b)
        return f


def _entries_at_most(cdf: np.ndarray, rows: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Per sample i, how many entries of the non-decreasing row ``cdf[rows[i]]`` are <= target[i]
    (``np.searchsorted(..., side="right")`` row by row), by a bisection over all samples at once:
    log2 of the row's length gathers of one value per sample, never a copy of the rows."""
    lo = np.zeros(len(rows), np.int64)
    hi = np.full(len(rows), cdf.shape[1], np.int64)
    active = lo < hi
    while active.any():
        mid = (lo + hi) // 2
        below = cdf[rows, np.minimum(mid, cdf.shape[1] - 1)] <= target
        lo = np.where(active & below, mid + 1, lo)
        hi = np.where(active & ~below, mid, hi)
        active = lo < hi
    return lo


def mean_and_error(sums: np.ndarray, squares: np.ndarray, spp: int):
    """Per-pixel mean and its standard error from the sums and sums of squares of ``spp``
    independent samples (inf with a single sample)."""
    mean = sums / spp
    if spp > 1:
        return mean, np.sqrt(np.maximum(squares - spp * mean ** 2, 0.0) / (spp - 1) / spp)
    return mean, np.full_like(mean, np.inf)


def lattice(u: np.ndarray, j) -> np.ndarray:
    """(N, 4) float32: frac(u + j alpha) for uniforms u (N, 4) float32 and lattice points j (N,)
    or a scalar, alpha = LATTICE / 2^24 (numpy twin of kernels/converge.cl ``lattice``, the same
    float32 operations)."""
    j = np.asarray(j, np.uint64)
    offset = np.stack([((j * np.uint64(a)) & np.uint64(0xFFFFFF)).astype(np.float32) for a in LATTICE], -1)
    c = np.asarray(u, np.float32) + offset * np.float32(2.0 ** -24)    # four axes, not samples
    return np.where(c >= 1, c - np.float32(1), c).astype(np.float32)


def tile_trees_reference(coeffs: np.ndarray, inside, hit_scale: np.ndarray):
    """numpy twin of ``converge_trees`` (kernels/converge.cl): for pixels' transfer coefficients
    (P, 2^m, 2^m) (:func:`tile_coefficients`), the lighting inside the texels ``inside`` (a
    :class:`_TexelLight` of m levels) and the pixels' hit scales c (P,): the product pyramids
    (P, tree_size(m)) float32 (row-major levels, the host's layout) of the leaves
    gl_t H+_t, H+_t = max(c H_t, 0) (H_t the texel values of the inverse transform, eq. 13;
    gl_t :meth:`_TexelLight.leaf_masses`), and the relit values G (P, 3) float64 = sum over t
    with gl_t > 0 of H+_t L_t (L_t the texel's mean radiance)."""
    side = 1 << inside.n
    h = np.maximum(inverse(np.asarray(coeffs, np.float64)) * np.asarray(hit_scale, np.float64)[:, None, None], 0.0)
    gl = inside.leaf_masses()
    leaves = (gl[None] * h.astype(np.float32)).astype(np.float32)
    relit = np.einsum("pij,ijc->pc", np.where(gl > 0, h, 0.0), inside.texel_radiance.reshape(side, side, 3))
    return build_reference(leaves), relit


def transfer_from_trees(nodes: np.ndarray, inside, pixel, uv) -> np.ndarray:
    """(N,) H+_t / Omega_t: the clamped transfer of pixels ``pixel`` in the texel t that holds
    each point uv (N, 2) of the square, per unit solid angle, read from their product trees'
    leaves (``nodes`` (P, tree_size(m)), row-major levels): leaf / gl_t (0 where gl_t is 0)."""
    t, _ = inside._texel(uv)
    side = 1 << inside.n
    gl = inside.leaf_masses().reshape(-1)[t].astype(np.float64)
    leaf = np.asarray(nodes, np.float64)[np.asarray(pixel, np.int64), level_offset(inside.n) + t]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(gl > 0, leaf / np.where(gl > 0, gl, 1.0), 0.0) / inside.texel_angles[t // side]


def shade_reference(scene, tracer, d, prim, t, k: int, trees, nodes, relit, spread, inside, key, first: int,
                    slots: int, defensive: float = DEFENSIVE, light: float = LIGHT_SHARE, control: bool = True,
                    candidates: int = CANDIDATES, coherence: float = COHERENCE, background: str = "nearest"):
    """numpy twin of ``converge_shade`` (kernels/converge.cl): one pass of a tile's camera rays
    from ``scene``'s eye along d (N, 3) that hit ``tracer``'s triangles prim (N,) (-1: a miss)
    at t (N,), k per pixel, pixel-major. The tile's pixels' product trees: ``trees`` (a
    :class:`wavlight.haar.HaarTree`, whose warp kernels walk them), ``nodes`` their pyramids
    (P, tree_size(m)) row-major, ``relit`` their G (P, 3), ``spread`` their footprint spreads (P,);
    ``inside`` the lighting (:class:`_TexelLight`), ``key`` = (seed, tile), ``first`` the pass's
    first sample index in the tile. A miss sees the map (direct; :meth:`_TexelLight.background`); a hit gets ``slots``
    directions of the mixture (:func:`mixture_directions`; the uniforms of slot j are
    :func:`lattice` point j of Philox stream rng.CONVERGE_DIRECTIONS[0] at index first + r),
    each estimated as albedo f cos L / pdf / slots
    (L the map's pixel, :meth:`_TexelLight.radiance`), and with ``control`` direct =
    albedo (G - sum of g / pdf / slots), g = :func:`transfer_from_trees` L; or, where its pixel's
    spread exceeds ``coherence`` times its lobe's width, ``slots`` picks among ``candidates``
    mixture directions by resampled importance sampling (:func:`resample_reference`). Returns
    direct (N, 3), origin (N, 3), wi (S, 3, N), value (S, 3, N) float64, the kernel's planes."""
    N = len(d)
    seed, tile = key
    direct, origin = np.zeros((N, 3)), np.zeros((N, 3))
    wi, value = np.zeros((slots, 3, N)), np.zeros((slots, 3, N))
    miss = np.flatnonzero(prim < 0)
    direct[miss] = inside.background(world_to_square(np.asarray(d, np.float64)[miss]), background)
    hit = np.flatnonzero(prim >= 0)
    if not len(hit):
        return direct, origin, wi, value
    hits = _Hits.of(scene, tracer, d, t, prim, hit, k)
    origin[hit] = hits.origin
    has_p = np.asarray(nodes)[hits.pixel, 0] > 0
    alpha = np.where(has_p, defensive, 1.0 - light)
    albedo = scene.material_albedo[hits.mat].astype(np.float64)
    chosen = np.zeros(len(hit), bool)
    if candidates:
        chosen = np.asarray(spread, np.float64)[hits.pixel] > coherence * bsdfs.lobe_width(hits.kind, hits.param)
    mix = np.flatnonzero(~chosen)
    if len(mix):
        sub = hits.subset(mix)
        cv = np.zeros((len(mix), 3))
        u_sample = rng.uniforms(seed, tile, rng.CONVERGE_DIRECTIONS[0], first, N)
        for slot in range(slots):   # directions per camera sample, not samples
            u_all = lattice(u_sample, slot)
            direction, weight, pdf = mixture_directions(trees, inside, u_all, sub.index, k, has_p[mix], alpha[mix],
                                                        sub.kind, sub.param, sub.wo, sub.axes, light, with_pdf=True)
            uv = world_to_square(direction)
            radiance = inside.radiance(uv)
            wi[slot][:, sub.index] = direction.T
            value[slot][:, sub.index] = (albedo[mix] * (weight / slots)[:, None] * radiance).T
            if control:
                g = transfer_from_trees(nodes, inside, sub.pixel, uv)[:, None] * radiance
                with np.errstate(divide="ignore", invalid="ignore"):
                    term = np.where((pdf > 0)[:, None], g / np.where(pdf > 0, pdf, 1.0)[:, None], 0.0)
                cv += np.where(np.isfinite(term), term, 0.0) / slots
        if control:
            direct[sub.index] = albedo[mix] * (np.asarray(relit, np.float64)[sub.pixel] - cv)
    pick = np.flatnonzero(chosen)
    if len(pick):
        sub = hits.subset(pick)
        directions, values = resample_reference(sub, trees, nodes, inside, has_p[pick], alpha[pick], N, k, key, slots,
                                                light, candidates, first)
        for slot in range(slots):
            wi[slot][:, sub.index] = directions[:, slot].T
            value[slot][:, sub.index] = (albedo[pick] * values[:, slot]).T
    return direct, origin, wi, value


def resample_reference(hits, trees, nodes, inside, has_p, alpha, count: int, spp: int, key, slots: int, light: float,
                       candidates: int, first: int = 0):
    """The resampled directions of camera samples ``hits`` (their estimate without the albedo),
    by resampled importance sampling (Talbot et al. 2005): ``candidates`` directions x_m of the
    defensive mixture q (:func:`mixture_directions`, no shadow ray), ``slots`` of them picked in
    proportion to w_m = p(x_m) / q(x_m) (systematic: one uniform, the picks (u + k) / slots),
    p = :func:`resampling_target`, each to be traced and weighted by f cos L V / p(y) x mean(w).
    On average over the picks that is sum_m f cos L V (x_m) / q(x_m) / candidates, unbiased as p
    is positive wherever f cos L is. Where the pixel's transfer, the mean of its camera samples'
    f cos V, is much wider than this sample's own lobe (a glossy pixel whose footprint spans
    several facets), the transfer's product spends most of its directions outside the lobe; the
    target's own lobe takes them back. ``count``: the camera samples of the pass, from sample
    ``first`` of the tile on (the uniforms' layout: candidate j of sample r is :func:`lattice`
    point j of Philox stream rng.CONVERGE_RESAMPLE of ``key`` at index first + r; the picks'
    uniform rng.CONVERGE_PICK's).
    Returns directions (n, slots, 3) and estimates (n, slots, 3) before the shadow rays."""
    m = candidates
    u = lattice(np.repeat(rng.uniforms(*key, rng.CONVERGE_RESAMPLE, first, count), m, 0), np.tile(np.arange(m), count))
    cand = hits.candidates(m)
    direction, weight, pdf = mixture_directions(trees, inside, u, cand.index, spp * m, np.repeat(has_p, m),
                                                np.repeat(alpha, m), cand.kind, cand.param, cand.wo, cand.axes, light,
                                                with_pdf=True)
    fcos = weight * pdf
    uv = world_to_square(direction)
    radiance = inside.radiance(uv)
    target = resampling_target(fcos, radiance, transfer_from_trees(nodes, inside, cand.pixel, uv))
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.where(pdf > 0, target / np.where(pdf > 0, pdf, 1.0), 0.0)
    w = np.where(np.isfinite(w), w, 0.0).reshape(-1, m)
    cdf = np.cumsum(w, 1)
    n = len(hits.index)
    u0 = rng.uniforms(*key, rng.CONVERGE_PICK, first, count)[hits.index, 0].astype(np.float64)
    at = (u0[:, None] + np.arange(slots)) / slots * cdf[:, -1:]          # (n, slots) points on the sums
    rows = np.repeat(np.arange(n), slots)
    picks = np.minimum(_entries_at_most(cdf, rows, at.reshape(-1)), m - 1)   # the first entry above each
    flat = rows * m + picks
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(target[flat] > 0, np.repeat(cdf[:, -1], slots) / m / target[flat], 0.0) / slots
    estimate = (np.where(np.isfinite(scale), scale, 0.0) * fcos[flat])[:, None] * radiance[flat]
    return direction[flat].reshape(n, slots, 3), estimate.reshape(n, slots, 3)


def shade_by_mixture(scene, tracer, d, t, prim, hit, trees, inside, mass, spp: int, key, environment,
                     defensive: float, slots: int, light: float = 0.0, first: int = 0):
    """The radiance (len(hit), 3) of the camera samples ``hit`` (of spp per pixel, directions
    ``d`` with hits ``prim`` at ``t``) from ``slots`` directions each of the defensive mixture
    (:func:`mixture_directions`, the lighting's share ``light``; the pixels' product trees
    ``trees`` of totals ``mass``) seen from ``scene``'s camera, each evaluated with the true
    f cos, ``environment``'s radiance and a shadow ray; the uniforms are Philox stream
    (``key`` = (seed, tile), rng.CONVERGE_DIRECTIONS[slot]), from sample ``first`` of the tile
    on. The mixture alone, in numpy (the view bake's unbiased frame, :mod:`.view`; the lighting
    bake's runs in kernels/converge.cl, twin :func:`shade_reference`). Returns it and the rays
    traced."""
    if slots > MAX_SLOTS:   # one stream per slot
        raise ArgumentError(f"relight.shade_by_mixture: at most {MAX_SLOTS} slots, got {slots}")
    hits = _Hits.of(scene, tracer, d, t, prim, hit, spp)
    has_p = mass[hits.pixel] > 0
    alpha = np.where(has_p, defensive, 1.0 - light)   # pixels without a product: the BSDF and the lighting
    total = np.zeros((len(hit), 3))
    rays = 0
    for slot in range(slots if len(hit) else 0):   # directions per camera sample, not samples
        u_all = rng.uniforms(*key, rng.CONVERGE_DIRECTIONS[slot], first, len(d))
        direction, weight = mixture_directions(trees, inside, u_all, hits.index, spp, has_p, alpha, hits.kind,
                                               hits.param, hits.wo, hits.axes, light)
        weight = weight / slots
        live = np.flatnonzero(weight > 0)
        blocked = tracer.occluded(hits.origin[live], direction[live].astype(np.float32))
        rays += len(live)
        total[live] += (weight[live] * ~blocked)[:, None] * environment.eval(direction[live])
    return scene.material_albedo[hits.mat].astype(np.float64) * total, rays


class _Hits(NamedTuple):
    """Camera samples that hit: their index among the tile's samples, pixel, shading frame
    (s, t, n: the face normal turned to the viewer), view in it, shadow-ray origin, material."""

    index: np.ndarray
    pixel: np.ndarray
    axes: tuple
    wo: np.ndarray
    origin: np.ndarray
    mat: np.ndarray
    kind: np.ndarray
    param: np.ndarray

    @classmethod
    def of(cls, scene, tracer, d, t, prim, hit, spp: int):
        nrm, _, origin = tracer.surface(scene.camera.eye, d[hit], t[hit], prim[hit])
        nrm = nrm.astype(np.float64)
        s_ax, t_ax = tangent_frame(nrm)
        wo = to_local(-d[hit].astype(np.float64), s_ax, t_ax, nrm)
        mat = scene.face_material[prim[hit]]
        return cls(np.asarray(hit), np.asarray(hit) // spp, (s_ax, t_ax, nrm), wo, origin, mat,
                   scene.material_kind[mat], scene.material_param[mat])

    def subset(self, sel):
        return _Hits(self.index[sel], self.pixel[sel], tuple(a[sel] for a in self.axes), self.wo[sel],
                     self.origin[sel], self.mat[sel], self.kind[sel], self.param[sel])

    def candidates(self, m: int):
        """Each sample m times in a row, the candidates of :func:`shade_by_resampling`: their
        ``index`` is their row among the tile's samples' m candidates each (sample-major)."""
        rows = (self.index[:, None] * m + np.arange(m)).reshape(-1)
        return _Hits(rows, *(tuple(np.repeat(a, m, 0) for a in f) if isinstance(f, tuple) else np.repeat(f, m, 0)
                             for f in self[1:]))


def resampling_target(fcos, radiance, transfer):
    """The target of the resampled directions (:func:`shade_by_resampling`) at directions of
    the camera sample's f cos, the lighting's ``radiance`` (N, 3) and the pixel's transfer T
    per solid angle: Y(L) [(f cos)^LOBE_POWER T^(1 - LOBE_POWER) + TARGET_BSDF f cos +
    TARGET_TRANSFER T], Y the luminance. The first term is the sample's own lobe with the
    visibility the transfer holds; the second keeps it positive wherever f cos L is, so that the
    estimate is unbiased where the transfer missed a direction."""
    fcos, transfer = np.maximum(fcos, 0.0), np.maximum(transfer, 0.0)
    return luminance(radiance) * (fcos ** LOBE_POWER * transfer ** (1.0 - LOBE_POWER) + TARGET_BSDF * fcos
                                  + TARGET_TRANSFER * transfer)


def mixture_directions(trees, inside, u_all, hit, spp: int, has_product, alpha, kind, param, wo, axes,
                       light: float = 0.0, with_pdf: bool = False):
    """Directions of the defensive mixture and their weights, for the samples ``hit`` of
    ``len(u_all)`` (spp per pixel, each pixel's product tree in ``trees``): with probability
    1 - alpha - light the product (its tree by the hierarchical warp, eq. 17-22, then inside
    the texel by the lighting, ``inside``), with probability alpha the BSDF, with probability
    ``light`` the lighting alone (:meth:`_TexelLight.sample_light`: where a noisy transfer
    hides a bright light, the lighting still finds it); ``axes`` (s, t, n) the hits' tangent
    frames, ``wo`` the view in them. The pdf is the mixture's, every technique's at the chosen
    direction, so that f cos / pdf is unbiased. Returns unit directions (N, 3) and f cos / pdf
    (N,) (0 where either is 0 or not finite); with ``with_pdf`` also the mixture's pdf (N,) per solid
    angle."""
    s_ax, t_ax, nrm = axes
    u = u_all[hit].astype(np.float64)
    uv_tree, _ = trees.sample(np.ascontiguousarray(u_all[:, :2]), spp)   # every sample slot, in pixel order
    uv_p, _ = inside.sample(uv_tree[hit].astype(np.float64))
    d_p = square_to_world(uv_p)
    use_b = u[:, 2] < alpha          # the BSDF's uniforms: u.z rescaled below alpha, and u.w
    ub = np.clip(np.stack([np.where(use_b, u[:, 2] / alpha, 0.0), u[:, 3]], 1), 0.0, np.nextafter(1.0, 0.0))
    wl_b = bsdfs.sample_each(kind, param, ub, wo)
    d_b = wl_b[:, :1] * s_ax + wl_b[:, 1:2] * t_ax + wl_b[:, 2:3] * nrm
    direction = np.where(use_b[:, None], d_b, d_p)
    if light > 0:                    # the lighting's: u.z in [alpha, alpha + light) chooses it, and its
        use_l = ~use_b & (u[:, 2] < alpha + light)   # direction takes the product's unused u.x, u.y and u.w
        if use_l.any():
            direction[use_l] = square_to_world(inside.sample_light(u[use_l, 0], u[use_l, 1], u[use_l, 3]))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    uv = world_to_square(direction)
    p_tree = trees.pdf(np.ascontiguousarray(_spread(uv, hit, len(u_all)), np.float32), spp)[hit]
    p_prod = np.where(has_product, p_tree.astype(np.float64) * inside.factor(uv), 0.0) * solid_angle_jacobian(direction)
    wl = to_local(direction, s_ax, t_ax, nrm)
    fcos, p_bsdf = bsdfs.eval_pdf_each(kind, param, wl, wo)
    pdf = (1 - alpha - light) * p_prod + alpha * p_bsdf
    if light > 0:
        pdf = pdf + light * inside.light_pdf(uv) * solid_angle_jacobian(direction)
    with np.errstate(divide="ignore", invalid="ignore"):
        weight = np.where((pdf > 0) & (fcos > 0), fcos / pdf, 0.0)
    weight = np.where(np.isfinite(weight), weight, 0.0)
    return (direction, weight, np.where(np.isfinite(pdf), pdf, 0.0)) if with_pdf else (direction, weight)


def _spread(values: np.ndarray, at: np.ndarray, count: int) -> np.ndarray:
    """(count, 2): ``values`` at rows ``at``, the point (0.5, 0.5) elsewhere (the tree pdf kernel
    takes one point per sample of every pixel)."""
    out = np.full((count, 2), 0.5)
    out[at] = values
    return out
