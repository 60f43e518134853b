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
a fraction of a column overlaps two of them: :class:`TexelLight`): a sun smaller than a texel
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

Plastic (f cos = coat + albedo x base: docs/decisions/plastic-in-the-bake.md). Each direction is
estimated with its true colour, (coat + albedo base) L / pdf (:func:`.mixture.tint_of`), and the
BSDF's share samples either lobe (bsdfs.plastic_sample). The product is that of
H = T + w_p C, the bake's transfer and its coat's, w_p = 1 / lum(a_p) on a pixel whose block holds
a coat (:func:`coat_weights`; the frame's lum(a_p) T + C over lum(a_p)), summed in the
coefficients (the transform is linear); the control variate's colour is the sample's albedo a
tinted by the coat's share s of the pixel's mean transfer (its scaling coefficients'),
(1 - s) a + s lum(a): a constant per camera sample, so the estimate stays unbiased.

Passes. :class:`ConvergeFrames` holds what frames share: the scene's ray tracer, its tables and
the bake's entries on the device, the pixels' footprint spreads (measured once, on first use),
and for the current lighting (map, rotation, scale) its tables and the tiles' trees, kept up to
TREE_CACHE_BYTES of device memory. A frame then runs per tile: its trees (kept, or one launch of
``converge_trees``), and per pass of at most PASS_SAMPLES camera samples: the camera rays
(kernels/camera.cl), their hits (embree), one launch of ``converge_shade`` (every direction, pdf,
estimate and control variate; twin :func:`shade_reference`), the shadow rays of the estimates
that are not 0 (embree), and the pixels' sums (the loop over tiles and passes:
:func:`wavlight.relight.tile_passes.run_tiles`). A second frame under the same lighting (more
samples, another seed) pays only for the passes. :func:`converge` is one frame of a
ConvergeFrames it keeps for the next call with the same transfer and scene.
"""
from __future__ import annotations

import os
import threading
import time
import weakref
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numpy as np

from .. import bsdfs, camera, cl, rng
from ..camera import camera_rays
from ..errors import ArgumentError, WavlightError, check_degrees, check_int, check_number
from ..haar import inverse
from ..haar.tree import HaarTree, build_reference, level_offset
from ..envmap import LUMINANCE
from ..integrator import RenderResult
from ..raytrace import RayTracer
from ..threads import default_threads
from . import converge_kernels as kernels
from . import tile_passes
from .bake import BLOCK
from .frame import DeviceEntries
from .mixture import (DEFENSIVE, LATTICE, LIGHT_SHARE, MAX_SLOTS, Hits, TexelLight, check_shares, entries_at_most,
                      lattice, mixture_directions, resampling_target, scene_of, tint_of, world_to_square)
from .settings import FRAME, UNBIASED_SPP

MAX_SPP = FRAME["spp"].hi
#: the product trees' levels at most (finer bakes are summed to them: 2^m x 2^m texels of the
#: transfer are its coefficients' top-left 2^m x 2^m block times 4^(n - m)); inside a texel
#: the lighting's own leaves place the direction (docs/decisions/relight-product-levels.md,
#: docs/decisions/relight-converge-kernels.md: 2^6 x 2^6 trees write four times the memory)
PRODUCT_LEVELS = 5
#: directions (shadow rays) per camera sample (docs/decisions/relight-converge-kernels.md)
SLOTS = 4
#: resampled directions (docs/decisions/relight-resampling.md): a camera sample whose pixel's
#: footprint reflects over more than COHERENCE times its lobe's width (:func:`footprint_spread`,
#: :func:`wavlight.bsdfs.lobe_width`) picks its slots among CANDIDATES mixture directions
CANDIDATES = 8
COHERENCE = 0.25
MAX_CANDIDATES = 256
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














class _Block:
    """A block's stored coefficients, from the bake file's offset table (the twins' input);
    ``coat``: plastic's coat's (its offsets over the image's blocks, :func:`coat_offsets`)."""

    def __init__(self, transfer, coat: bool = False):
        self.prefix = "coat_" if coat else ""
        self.offsets = coat_offsets(transfer) if coat else transfer._s["offsets"]

    def coefficients(self, transfer, block: int) -> np.ndarray:
        """(BLOCK^2, 4^n) float32: the block's pixels' dequantized transfer coefficients (every
        coefficient column in the bake's order: flat dense Haar indices)."""
        ids = np.asarray(self.offsets[:, block], np.int64)
        cols = np.flatnonzero(ids >= 0)
        out = np.zeros((BLOCK * BLOCK, len(ids)), np.float32)
        if len(cols):
            q = np.asarray(transfer._s[self.prefix + "entry_data"][ids[cols]], np.float32)
            scale = np.asarray(transfer._s[self.prefix + "entry_scale"][ids[cols]], np.float32)
            out[:, cols] = (q * scale[:, None]).T
        return out


def coat_offsets(transfer) -> np.ndarray:
    """(4^n, blocks) int32: the entry of plastic's coat's coefficient c in each of the image's
    blocks (the store's coat_offsets spread over its coat_blocks), -1 where it holds none."""
    s = transfer._s
    out = np.full((1 << (2 * transfer.n_levels), transfer.blocks[0] * transfer.blocks[1]), -1, np.int32)
    if "coat_blocks" in s:
        out[:, np.asarray(s["coat_blocks"], np.int64)] = s["coat_offsets"]
    return out


def coat_weights(transfer) -> np.ndarray:
    """(H, W) float32: the weight w_p of plastic's coat in the pixel's product tree, 1 / lum(a_p)
    where the pixel's block holds a coat (its transfer H + w_p H_coat is then the frame's
    lum(a_p) H + H_coat over lum(a_p), as H's scale is), 0 elsewhere."""
    out = np.zeros((transfer.height, transfer.width), np.float32)
    s = transfer._s
    if "coat_blocks" not in s:
        return out
    lum = np.asarray(s["albedo"], np.float64) @ LUMINANCE
    held = np.zeros(transfer.blocks[0] * transfer.blocks[1], bool)
    held[np.asarray(s["coat_blocks"], np.int64)] = True
    by, bx = np.arange(transfer.height) // BLOCK, np.arange(transfer.width) // BLOCK
    inside = held.reshape(transfer.blocks[1], transfer.blocks[0])[by[:, None], bx[None, :]]
    with np.errstate(divide="ignore"):
        return np.where(inside & (lum > 0), 1.0 / np.where(lum > 0, lum, 1.0), 0.0).astype(np.float32)


def tile_coefficients(transfer, tile, levels: int, coat: bool = False) -> np.ndarray:
    """(w h, 2^m, 2^m) float32: the transfer coefficients of the tile's pixels (row-major in the
    tile) on 2^m x 2^m texels, m = ``levels`` <= n: the top-left 2^m x 2^m block of each
    pixel's 2^n x 2^n coefficients times 4^(n - m), the transform of its summed texels
    (``coat``: plastic's coat's)."""
    n, blocks = transfer.n_levels, _Block(transfer, coat)
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
        self.frames = 0   # frames made under it (its first builds its trees in scratch buffers)
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
        if transfer.varies != "lighting":
            raise WavlightError(f"{transfer.path}: this bake varies the {transfer.varies}, not the lighting: its "
                                "unbiased frames are its own")
        if backend not in BACKENDS:
            raise ArgumentError(f"relight.ConvergeFrames: backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
        self.transfer, self.backend = transfer, backend
        self.threads = threads
        self.scene = scene_of(transfer, scene)
        t0 = time.perf_counter()
        sc = self.scene
        self.tracer = RayTracer(sc.vertices, sc.faces, threads=1, normals=sc.normals, normal_faces=sc.normal_faces)
        hits = bake_hits(transfer)
        self.hit_scale = hit_scales(transfer, hits).astype(np.float32)
        #: the trees' scale: c, and 0 where every camera sample of the bake missed (no transfer: no tree)
        self.tree_scale = np.where(hits > 0, self.hit_scale, 0.0).astype(np.float32)
        self.tiles = tiles_of(transfer)
        self.lobe_width = bsdfs.lobe_width(sc.material_kind, sc.material_param).astype(np.float32)
        #: plastic's coat in the trees (a bake of a scene with plastic: store.COAT_SECTIONS)
        self.coat = "coat_blocks" in transfer._s
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
            coat = None
            if self.coat:   # plastic's coat: its entries, their offsets over the image's blocks, the weights
                s = transfer._s
                coat = (DeviceEntries(s["coat_offsets"], s["coat_entry_scale"], s["coat_entry_data"]),
                        coat_offsets(transfer), coat_weights(transfer))
            self._trees = kernels.TreeKernel(entries, transfer._s["offsets"], self.tree_scale, transfer.n_levels,
                                             transfer.blocks[0], transfer.width, coat)
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
                               self._shade.textured, background, self.coat)

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
        inside = TexelLight(base, levels, rotate_y, projector=projector)
        self._map = (env_key, base, inside.projector, env)
        device = kernels.Lighting(inside.tables()) if self.backend == "opencl" else None
        state = _LightingState(key, inside, device)
        state.env = env   # (an Environment object's identity is its key: keep it alive)
        self._lighting = state
        return state

    def tile_trees(self, state, tile, prog, new_buffers: bool = True):
        """The tile's product trees under the lighting ``state``: kept ones, or built (and kept
        while they fit in tree_cache_bytes); with the numpy backend (HaarTree, host nodes, G).
        Trees are kept in an earlier lighting's buffers, or in new ones only with
        ``new_buffers``: without, where no earlier buffers serve, they are built in the thread's
        scratch buffers (a lighting's first frame: faulting in new pages costs it more than its
        trees cost to build; docs/decisions/relight-converge-kernels.md)."""
        with state.lock:
            kept = state.trees.get(tile.index)
        if kept is not None:
            return kept, True
        m = state.inside.n
        if self.backend == "numpy":
            coeffs = tile_coefficients(self.transfer, tile, m)
            scale = self.tree_scale[tile.y0:tile.y0 + tile.h, tile.x0:tile.x0 + tile.w].reshape(-1)
            coat = None
            if self.coat:   # plastic's coat: H + w_p H_coat, and G with the coat's share (kernels/converge.cl)
                weight = coat_weights(self.transfer)[tile.y0:tile.y0 + tile.h, tile.x0:tile.x0 + tile.w].reshape(-1)
                coat = (tile_coefficients(self.transfer, tile, m, coat=True), weight)
            nodes, relit = tile_trees_reference(coeffs, state.inside, scale, coat)
            return (HaarTree.from_pyramids(nodes), nodes, relit), False
        nbytes = kernels.TileTrees(None, None, tile.w * tile.h, m).nbytes
        with state.lock:
            fits = state.kept_bytes + nbytes <= self.tree_cache_bytes
            spare = self._spare.pop(tile.index, None) if fits else None
            if spare is not None and spare.levels != m:
                spare = None
            keep = fits and (spare is not None or new_buffers)
            if keep:
                state.kept_bytes += nbytes
        made = self._trees(prog, state.device, tile, into=spare if keep else "scratch")
        if keep:
            with state.lock:
                state.trees[tile.index] = made
        return made, False

    def prepare(self, levels: int = PRODUCT_LEVELS, slots: int = SLOTS, candidates: int = CANDIDATES,
                control: bool = True, background: str = FRAME["background"].default) -> None:
        """Make now what the first frame would (its kernels' program and every tile's footprint
        spread, which do not depend on the lighting), so that it pays only for its lighting and
        passes: the viewer prepares its converge thread's frames when a page opens. ``background``:
        the frames' (their program differs by it)."""
        prog = None
        if self.backend == "opencl":
            prog = self.program(min(self.transfer.n_levels, levels), slots, candidates, bool(control),
                                FRAME["background"].check(background, "relight.converge"))
        if candidates:
            self.footprints(prog)

    def footprints(self, prog=None) -> None:
        """Measure every tile's footprint spread not measured yet (:meth:`spread`)."""
        for tile in self.tiles:
            self.spread(tile, prog)

    def warm(self, env=None, rotate_y=None, scale: float = FRAME["scale"].default, levels: int = PRODUCT_LEVELS,
             stop=None, background: str = FRAME["background"].default) -> int:
        """Make the lighting's tables and every tile's product trees (kept while they fit) before a
        frame asks for them, tile by tile until ``stop()`` is true: the viewer's converge thread
        warms the lighting of a page at rest, so that its first pass pays only for its samples
        (with the program of its ``background``). Returns the tiles whose trees are kept."""
        tr = self.transfer
        m = min(tr.n_levels, levels)
        state = self.lighting(env, tr.scene_rotate_y if rotate_y is None else float(rotate_y), scale, m)
        if self.backend != "opencl":
            return 0
        prog = self.program(m, SLOTS, CANDIDATES, True, FRAME["background"].check(background, "relight.converge"))
        for i, tile in enumerate(self.tiles):
            if stop is not None and stop():
                break
            trees, _ = self.tile_trees(state, tile, prog)
            if i == 0:   # the shading kernel's first launches (PoCL compiles per work-group size)
                host, device = self.spread(tile, prog)
                self._shade.warm_up(prog, SLOTS, trees, cl.to_device(host) if device is None else device,
                                    state.device, (DEFENSIVE, LIGHT_SHARE, COHERENCE))
        # the trees are read by a frame's tile threads on queues of their own: built before they are
        cl.thread_queue().finish()
        return len(state.trees)

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
        Camera samples that miss see the map's pixel, with ``background="bilinear"`` its
        bilinear filter, with ``background="none"`` nothing: they contribute 0 (display only). Returns a RenderResult: image, per-pixel standard error, stats."""
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
        spread_rays = self._spread_rays
        prog = None
        if self.backend == "opencl":
            prog = self.program(m, slots, candidates, use_control, background)
        with ThreadPoolExecutor(1) as aside:
            # the footprints do not depend on the lighting: measured while its tables are made (numpy, one core)
            footprints = (aside.submit(self.footprints, prog)
                          if candidates and prog is not None and len(self._spread) < len(self.tiles) else None)
            state = self.lighting(env, rot, scale, m)
            lighting_seconds = time.perf_counter() - t0
            if footprints is not None:
                footprints.result()
        width, height = tr.width, tr.height
        shares = (defensive, light, coherence)
        eye = np.broadcast_to(self.scene.camera.eye.astype(np.float32), (1, 3))

        def start(tile):
            trees, was_kept = self.tile_trees(state, tile, prog, new_buffers=state.frames > 0)
            spread = self.spread(tile, prog) if candidates else (np.zeros(tile.w * tile.h, np.float32), None)
            if self.backend == "opencl" and spread[1] is None:
                spread = (spread[0], cl.to_device(spread[0]))
            if prog is not None:
                self._shade.warm_up(prog, slots, trees, spread[1], state.device, shares)
            return (trees, spread), {"kept": int(was_kept)}

        shading = PassShading(self.scene, self.tracer, self._shade if prog is not None else None, prog,
                              state.device, state.inside, eye, seed, slots, shares, use_control, candidates,
                              background, self.lobe_width)

        def samples(shared, tile, first, k):
            P = tile.w * tile.h
            tile_id = CONVERGE_TILES + tile.index
            d = camera.pass_rays(self.scene, width, height, seed, tile_id, tile.x0, tile.y0, tile.w, tile.h, k,
                                 first * P, kernel=self.backend == "opencl", stratified=True)
            return shading.samples(d, k, first * P, tile_id, *shared)

        work = tile_passes.TileWork(start, samples, lambda pixels: pass_spp(spp, pixels))
        mean, err, totals = tile_passes.run_tiles(work, self.tiles, width, height, spp,
                                                  self.threads or default_threads(), progress, t0)
        with state.lock:
            state.frames += 1
        self._spare = {}
        seconds = time.perf_counter() - t0
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


class PassShading(NamedTuple):
    """What the passes of one unbiased frame shade with (a lighting bake's, :class:`ConvergeFrames`,
    or a view bake's, :class:`.view_converge.ViewConverge`): the scene and its ray tracer, the
    ``kernel`` (a :class:`.converge_kernels.ShadeKernel`; None: its numpy twin
    :func:`shade_reference`) and its program, the lighting (on the device, and inside the
    texels), the eye, and the frame's seed, slots, shares (defensive, light, coherence), control
    variate, candidates, background and the materials' lobe widths."""
    scene: object
    tracer: RayTracer
    kernel: object
    prog: object
    lighting: object
    inside: TexelLight
    eye: np.ndarray
    seed: int
    slots: int
    shares: tuple
    control: bool
    candidates: int
    background: str
    lobe_width: np.ndarray

    def samples(self, d, k: int, first: int, tile_id: int, trees, spread):
        """One pass of a tile: the camera rays d (k per pixel, pixel-major, the pass's first sample
        ``first`` of the tile, Philox tile ``tile_id``) traced, shaded with the tile's ``trees``
        and footprint ``spread`` (host, device), their shadow rays traced: the samples' values
        (N, 3) and the pass's counts (rays, hits, resampled)."""
        prim, t, bu, bv = self.tracer.intersect_uv(np.broadcast_to(self.eye, d.shape), d)
        bary = np.stack([bu, bv], axis=1)   # the shading normals and textures at the hits
        defensive, light, coherence = self.shares
        if self.kernel is not None:
            direct, origin, wi, value = self.kernel(self.prog, self.slots, d, prim, t, k, first, trees, spread[1],
                                                    self.lighting, self.shares, self.seed, tile_id, bary=bary)
        else:
            direct, origin, wi, value = shade_reference(
                self.scene, self.tracer, d, prim, t, k, trees[0], trees[1], trees[2], spread[0], self.inside,
                (self.seed, tile_id), first, self.slots, defensive, light, self.control, self.candidates, coherence,
                bary=bary, background=self.background)
        v, traced = visible_sum(self.tracer, direct, origin, wi, value)
        hit = prim >= 0
        chosen = 0
        if self.candidates:
            mat = self.scene.face_material[prim[hit]]
            chosen = int((spread[0][np.flatnonzero(hit) // k] > coherence * self.lobe_width[mat]).sum())
        return v, {"rays": len(d) + traced, "hits": int(hit.sum()), "resampled": chosen}


def pass_spp(spp: int, pixels: int) -> int:
    """Camera samples per pixel of one pass over a tile of ``pixels``: at most PASS_SPP, and
    PASS_SAMPLES in all."""
    return tile_passes.pass_spp(spp, pixels, PASS_SPP, PASS_SAMPLES)


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
                scene = scene_of(transfer, scene)   # loaded: not part of the frame's time
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


def hit_scales(transfer, hits=None) -> np.ndarray:
    """(H, W) S / hits: the bake's camera samples over those of them that hit, per pixel (1 where
    all miss). The transfer is a mean over all S samples, misses counted as 0; a camera sample of
    the frame that hits is closer to the transfer of the hits alone, on a silhouette's pixels
    too. A constant per pixel: the control variate (g and G alike) stays unbiased. ``hits``:
    :func:`bake_hits` of the transfer, where the caller has it."""
    hits = bake_hits(transfer) if hits is None else hits
    return np.where(hits > 0, transfer.spp / np.maximum(hits, 1.0), 1.0)










def tile_trees_reference(coeffs: np.ndarray, inside, hit_scale: np.ndarray, coat=None):
    """numpy twin of ``converge_trees`` (kernels/converge.cl): for pixels' transfer coefficients
    (P, 2^m, 2^m) (:func:`tile_coefficients`), the lighting inside the texels ``inside`` (a
    :class:`TexelLight` of m levels) and the pixels' hit scales c (P,): the product pyramids
    (P, tree_size(m)) float32 (row-major levels, the host's layout) of the leaves
    gl_t H+_t, H+_t = max(c H_t, 0) (H_t the texel values of the inverse transform, eq. 13;
    gl_t :meth:`TexelLight.leaf_masses`), and the relit values G (P, 3) float64 = sum over t
    with gl_t > 0 of H+_t L_t (L_t the texel's mean radiance). ``coat`` = (coefficients
    (P, 2^m, 2^m), weights w_p (P,)): plastic's coat, H the transform of the coefficients
    plus w_p times the coat's (:func:`coat_weights`), and G (P, 4) with the coat's share of the
    pixel's mean transfer, clip(w_p C_0 / (T_0 + w_p C_0), 0, 1) from the scaling coefficients
    (the control variate's tint, :func:`shade_reference`)."""
    side = 1 << inside.n
    share = None
    if coat is not None:
        c, w = np.asarray(coat[0], np.float64), np.asarray(coat[1], np.float64)
        coeffs = (np.asarray(coeffs, np.float64) + w[:, None, None] * c).astype(np.float32)
        root, coat_root = coeffs[:, 0, 0].astype(np.float64), w * c[:, 0, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            share = np.clip(np.where(root > 0, coat_root / np.where(root > 0, root, 1.0), 0.0), 0.0, 1.0)
    h = np.maximum(inverse(np.asarray(coeffs, np.float64)) * np.asarray(hit_scale, np.float64)[:, None, None], 0.0)
    gl = inside.leaf_masses()
    leaves = (gl[None] * h.astype(np.float32)).astype(np.float32)
    relit = np.einsum("pij,ijc->pc", np.where(gl > 0, h, 0.0), inside.texel_radiance.reshape(side, side, 3))
    if share is not None:
        relit = np.concatenate([relit, share[:, None]], 1)
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
                    candidates: int = CANDIDATES, coherence: float = COHERENCE, bary=None,
                    background: str = "nearest"):
    """numpy twin of ``converge_shade`` (kernels/converge.cl): one pass of a tile's camera rays
    from ``scene``'s eye along d (N, 3) that hit ``tracer``'s triangles prim (N,) (-1: a miss)
    at t (N,), k per pixel, pixel-major. The tile's pixels' product trees: ``trees`` (a
    :class:`wavlight.haar.HaarTree`, whose warp kernels walk them), ``nodes`` their pyramids
    (P, tree_size(m)) row-major, ``relit`` their G (P, 3), ``spread`` their footprint spreads (P,);
    ``inside`` the lighting (:class:`TexelLight`; ``relit`` (P, 4) with the coat's share last where
    the bake has plastic's coat, :func:`tile_trees_reference`), ``key`` = (seed, tile), ``first`` the pass's
    first sample index in the tile. A miss sees the map (direct; :meth:`TexelLight.background`:
    its pixel, with ``background="bilinear"`` its filter, with ``"none"`` 0); a hit gets ``slots``
    directions of the mixture (:func:`mixture_directions`; the uniforms of slot j are
    :func:`lattice` point j of Philox stream rng.CONVERGE_DIRECTIONS[0] at index first + r),
    each estimated as albedo f cos L / pdf / slots (plastic: (coat + albedo base) L / pdf / slots,
    :func:`.mixture.tint_of`)
    (L the map's pixel, :meth:`TexelLight.radiance`), and with ``control`` direct =
    k (G - sum of g / pdf / slots), g = :func:`transfer_from_trees` L, k = (1 - s) albedo + s lum(albedo)
    (s the coat's share, 0 without plastic); or, where its pixel's
    spread exceeds ``coherence`` times its lobe's width, ``slots`` picks among ``candidates``
    mixture directions by resampled importance sampling (:func:`resample_reference`). Hits are
    shaded with their shading normals and, in a textured scene, the hit's albedo
    (Scene.albedo_at), both at ``bary`` (N, 2) embree's barycentric (u, v) of the hits (None:
    every face flat). Returns direct (N, 3), origin (N, 3), wi (S, 3, N), value (S, 3, N)
    float64, the kernel's planes."""
    N = len(d)
    seed, tile = key
    direct, origin = np.zeros((N, 3)), np.zeros((N, 3))
    wi, value = np.zeros((slots, 3, N)), np.zeros((slots, 3, N))
    miss = np.flatnonzero(prim < 0)
    direct[miss] = inside.background(world_to_square(np.asarray(d, np.float64)[miss]), background)
    hit = np.flatnonzero(prim >= 0)
    if not len(hit):
        return direct, origin, wi, value
    hits = Hits.of(scene, tracer, d, t, prim, hit, k, bary)
    table = scene.material_table[hits.mat] if len(scene.materials) else None
    relit = np.asarray(relit, np.float64)
    coat_share = relit[:, 3] if relit.shape[1] == 4 else np.zeros(len(relit))
    relit = relit[:, :3]
    origin[hit] = hits.origin
    has_p = np.asarray(nodes)[hits.pixel, 0] > 0
    alpha = np.where(has_p, defensive, 1.0 - light)
    if getattr(scene, "textured", False):
        if bary is None:
            raise ValueError("relight.converge.shade_reference: a textured scene needs the hits' barycentric (bary)")
        b = np.asarray(bary, np.float32)[hit]
        albedo = scene.albedo_at(prim[hit], b[:, 0], b[:, 1]).astype(np.float64)
    else:
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
            direction, weight, pdf, part = mixture_directions(
                trees, inside, u_all, sub.index, k, has_p[mix], alpha[mix], sub.kind, sub.param, sub.wo, sub.axes,
                light, with_pdf=True, geometric=sub.geometric, table=None if table is None else table[mix],
                with_share=True)
            uv = world_to_square(direction)
            radiance = inside.radiance(uv)
            wi[slot][:, sub.index] = direction.T
            value[slot][:, sub.index] = (tint_of(part, albedo[mix]) * (weight / slots)[:, None] * radiance).T
            if control:
                g = transfer_from_trees(nodes, inside, sub.pixel, uv)[:, None] * radiance
                with np.errstate(divide="ignore", invalid="ignore"):
                    term = np.where((pdf > 0)[:, None], g / np.where(pdf > 0, pdf, 1.0)[:, None], 0.0)
                cv += np.where(np.isfinite(term), term, 0.0) / slots
        if control:
            s = coat_share[sub.pixel][:, None]
            tint = (1.0 - s) * albedo[mix] + s * (albedo[mix] @ LUMINANCE)[:, None]
            direct[sub.index] = tint * (relit[sub.pixel] - cv)
    pick = np.flatnonzero(chosen)
    if len(pick):
        sub = hits.subset(pick)
        directions, values, part = resample_reference(sub, trees, nodes, inside, has_p[pick], alpha[pick], N, k, key,
                                                      slots, light, candidates, first,
                                                      None if table is None else table[pick])
        for slot in range(slots):
            wi[slot][:, sub.index] = directions[:, slot].T
            value[slot][:, sub.index] = (tint_of(part[:, slot], albedo[pick]) * values[:, slot]).T
    return direct, origin, wi, value


def resample_reference(hits, trees, nodes, inside, has_p, alpha, count: int, spp: int, key, slots: int, light: float,
                       candidates: int, first: int = 0, table=None):
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
    ``table``: the hits' rows of the plastic table (None: no plastic).
    Returns directions (n, slots, 3), estimates (n, slots, 3) before the shadow rays and the share
    of each the albedo multiplies (n, slots) (:func:`.mixture.tint_of`)."""
    m = candidates
    u = lattice(np.repeat(rng.uniforms(*key, rng.CONVERGE_RESAMPLE, first, count), m, 0), np.tile(np.arange(m), count))
    cand = hits.candidates(m)
    direction, weight, pdf, part = mixture_directions(
        trees, inside, u, cand.index, spp * m, np.repeat(has_p, m), np.repeat(alpha, m), cand.kind, cand.param,
        cand.wo, cand.axes, light, with_pdf=True, geometric=cand.geometric,
        table=None if table is None else np.repeat(table, m, 0), with_share=True)
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
    picks = np.minimum(entries_at_most(cdf, rows, at.reshape(-1)), m - 1)   # the first entry above each
    flat = rows * m + picks
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(target[flat] > 0, np.repeat(cdf[:, -1], slots) / m / target[flat], 0.0) / slots
    estimate = (np.where(np.isfinite(scale), scale, 0.0) * fcos[flat])[:, None] * radiance[flat]
    return direction[flat].reshape(n, slots, 3), estimate.reshape(n, slots, 3), part[flat].reshape(n, slots)










