"""The direct-lighting integrator: camera rays, shading, shadow rays, tiles, accumulation.

Path of one pixel sample (see docs/architecture.md): :mod:`wavlight.camera` makes a ray
through a uniformly jittered point of the pixel (box filter); :class:`RayTracer`
finds the closest hit; the shader's ``shade_rays`` (:mod:`wavlight.shading`, one
kernel launch per batch) gives a miss the environment's radiance and a hit its
face normal flipped towards the viewer, the strategy's directions and pdfs, the
estimate ``albedo f cos L / pdf`` times the MIS weight, and the shadow-ray origin
(the hit point moved along that normal by ``RayTracer.shadow_offsets``); only non-zero
estimates get a shadow ray (occlusion query, :meth:`_Renderer.visible_sum`). Per-pixel means and
standard errors come from the per-sample values.

Images are rendered in tiles, each in passes of about ``TILE_SAMPLES`` samples, so
memory is bounded at any resolution and any spp; tiles run on a thread pool
(numpy, embree and OpenCL release the GIL) of two threads per core by default, so
that one tile's numpy and embree work overlaps another's wait for the OpenCL
device (measured 10% faster than one per core on 2 cores). Rays, hit points and
normals are float32 (embree's precision); sums are float64. A tile with few siblings is cut
into parts at pass boundaries (:func:`_parts`, a constant count) so that every thread
works. Random numbers: counter-based Philox numbers of (seed, tile, sample index) drawn in
the kernels (:mod:`wavlight.rng`; stratified per pixel and pass with the ``stratified``
sampler, :mod:`wavlight.sampler`); so images do not depend on the number of threads.
At setup a ``wavelet`` render whose candidates or slots are not given traces a pilot of
shadow rays (:mod:`wavlight.occlusion`) and chooses them from the scene's shadows
(``strategies.AUTO_BUDGET``); the pilot's time is part of ``setup_seconds``.
"""
from __future__ import annotations

import dataclasses
import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from . import camera, occlusion, rng, strategies
from .camera import camera_rays  # noqa: F401  (also the integrator's public name)
from .raytrace import RayTracer
from .shading import KernelShader, NumpyShader
from .errors import WavlightError, shown
from .imageio import check_memory
from .options import BACKGROUND, HEIGHT, SEED, SPP, WIDTH
from .sampler import SAMPLER
from .scene import Scene, check_scene, load_scene
from .strategies import STRATEGIES
from .threads import MAX_THREADS, default_threads

TILE_SAMPLES = 1 << 16


@dataclass
class RenderResult:
    """image (H, W, 3) float32; stderr (H, W, 3) float32, the standard error of each pixel
    (sample standard deviation / sqrt(spp); inf at spp = 1)."""

    image: np.ndarray
    stderr: np.ndarray
    stats: dict = field(default_factory=dict)


class _Renderer:
    def __init__(self, scene: Scene, strategy: str, spp: int, width: int, height: int, seed: int, threads,
                 backend="opencl", options=None, sampler_name="independent"):
        self.scene, self.spp, self.width, self.height, self.seed = scene, spp, width, height, seed
        self.sampler = sampler_name
        self.threads = threads or default_threads()
        t0 = time.perf_counter()
        self.tracer = RayTracer(scene.vertices, scene.faces, normals=scene.normals, normal_faces=scene.normal_faces)
        # hits need their barycentric coordinates for the shading normals or textures (once: not per pass)
        self.needs_bary = bool(scene.textured or self.tracer.smooth)
        self.strategy = strategies.make(strategy, **(options or {}))
        if self.strategy.wants_visibility:   # the wavelet budget from the scene's shadows
            self.strategy.fit_to_visibility(occlusion.visibility_variance(scene, self.tracer, width, height))
        self.strategy.prepare(scene.environment, scene.materials)
        # Strategies without a shade kernel (no KERNEL_ID, e.g. sir) shade in numpy.
        numpy_shader = backend == "numpy" or strategy not in strategies.KERNEL_ID
        self.shader = (NumpyShader if numpy_shader else KernelShader)(scene, self.strategy, self.tracer)
        self.kernel_camera = backend != "numpy"
        if self.kernel_camera:
            camera.warm_up(scene)
        self.setup_seconds = time.perf_counter() - t0
        self.rays = 0
        self._rays_lock = threading.Lock()

    def count_rays(self, n):
        with self._rays_lock:
            self.rays += int(n)

    # -- shadow rays
    def visible_sum(self, shaded):
        """(3, N) radiance per camera ray: what it sees directly plus its visible estimates.
        Shadow rays only for non-zero estimates (MIS has two per point, sir S), from the
        origins the shader computed."""
        value = shaded.value
        # (channel-wise maxima over planes: no reduction over a length-3 axis)
        slot, pt = np.nonzero(np.maximum(np.maximum(value[:, 0], value[:, 1]), value[:, 2]) > 0)
        # wi is (points, slots, 3): one flat gather (3x faster than wi[pt, slot] at 4 slots)
        wi = np.take(shaded.wi.reshape(-1, 3), pt * value.shape[0] + slot, axis=0)
        blocked = self.tracer.occluded(np.take(shaded.origin, pt, axis=0), wi)
        self.count_rays(len(pt))
        visible = np.zeros((value.shape[0], value.shape[2]), value.dtype)
        visible[slot, pt] = ~blocked
        out = shaded.direct.astype(np.float64)
        for j in range(value.shape[0]):  # slots, not samples: 2 for MIS
            out += value[j] * visible[j]
        return out

    # -- one tile
    def tile(self, index, x0, y0, w, h):
        """Mean and standard error of the tile's pixels, in passes of at most ~TILE_SAMPLES samples."""
        return self.finish(*self.sums(index, x0, y0, w, h, 0, self.spp), w, h)

    def sums(self, index, x0, y0, w, h, first, count):
        """Per-pixel sums (3, w h) of samples first .. first + count - 1 of each pixel of a tile,
        and of their squares, in passes of at most ~TILE_SAMPLES samples (``first`` a multiple of
        the pass size)."""
        total = np.zeros((3, w * h))
        total_sq = np.zeros((3, w * h))
        per_pass = _pass_size(self.spp, w, h)
        for start in range(first, first + count, per_pass):
            k = min(per_pass, first + count - start)
            values = self._samples(index, start, x0, y0, w, h, k).reshape(3, w * h, k)
            total += values.sum(axis=2)
            total_sq += np.einsum("cik,cik->ci", values, values)
        return total, total_sq

    def finish(self, total, total_sq, w, h):
        """Mean and standard error (h, w, 3) from the sums of all spp samples of each pixel."""
        spp = self.spp
        mean = total / spp
        if spp > 1:
            var = np.maximum(total_sq - spp * mean ** 2, 0.0) / (spp - 1)
            err = np.sqrt(var / spp)
        else:
            err = np.full_like(mean, np.inf)
        return mean.T.reshape(h, w, 3), err.T.reshape(h, w, 3)

    def _samples(self, tile, first, x0, y0, w, h, k):
        """(3, w h k) radiance estimates (planes r, g, b): samples first .. first + k - 1 of each
        pixel of a tile, pixel-major."""
        d, prim, t, u, bary = self.camera_samples(tile, first, x0, y0, w, h, k)
        return self.visible_sum(self.shader.shade_rays(self.scene.camera.eye, d, prim, t, u, bary))

    def camera_samples(self, tile, first, x0, y0, w, h, k):
        """The camera rays of samples first .. first + k - 1 of each pixel of a tile, pixel-major:
        directions d, hit triangle prim and distance t, the shading uniforms u (an
        ``rng.Stream``: Philox numbers at tile sample indices first w h + (pixel k + j), drawn
        in the kernels; ``stratified``: each pair stratified over the pixel's k samples), and
        where the scene is textured or smooth the hits' barycentric coordinates bary (N, 2)
        (else None)."""
        eye = self.scene.camera.eye
        u = rng.Stream(self.seed, tile, first * w * h, k if self.sampler == "stratified" else 0)
        d = camera.pass_rays(self.scene, self.width, self.height, self.seed, tile, x0, y0, w, h, k, u.first,
                             kernel=self.kernel_camera, stratified=bool(u.k))
        origins = np.broadcast_to(eye.astype(np.float32), d.shape)
        bary = None
        if self.needs_bary:
            prim, t, bu, bv = self.tracer.intersect_uv(origins, d)
            bary = np.stack([bu, bv], axis=1)
        else:
            prim, t = self.tracer.intersect(origins, d)
        self.count_rays(len(d))
        return d, prim, t, u, bary


def _tiles(width, height, spp):
    side = max(8, int(np.sqrt(TILE_SAMPLES / spp)))
    tiles = []
    for y0 in range(0, height, side):
        for x0 in range(0, width, side):
            tiles.append((len(tiles), x0, y0, min(side, width - x0), min(side, height - y0)))
    return tiles


def _pass_size(spp, w, h):
    """Samples per pixel in one pass over a w x h tile (about TILE_SAMPLES samples)."""
    return max(1, min(spp, TILE_SAMPLES // (w * h)))


#: A render is cut into at least this many parts where it can be (tiles, and the passes of a
#: tile when there are fewer tiles): so that a small image with many spp still uses every
#: thread and moves its progress bar. A constant, not the thread count, so that images do not
#: depend on the number of threads.
MIN_PARTS = 32


def _parts(tiles, spp):
    """Work items (tile, first, count): each tile's spp, cut at pass boundaries into
    ceil(MIN_PARTS / tiles) contiguous parts where it has that many passes."""
    parts = []
    for tile in tiles:
        _, _, _, w, h = tile
        per_pass = _pass_size(spp, w, h)
        passes = -(-spp // per_pass)
        cuts = min(passes, max(1, -(-MIN_PARTS // len(tiles))))
        bounds = [per_pass * (passes * j // cuts) for j in range(cuts)] + [spp]
        parts += [(tile, a, b - a) for a, b in zip(bounds[:-1], bounds[1:])]
    return parts


BACKENDS = ("opencl", "numpy")


def _integer(name, value, lo, hi):
    """value as an int in [lo, hi], else a one-line WavlightError (no silent truncation of 2.7)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise WavlightError(f"{name} must be an integer, got {value!r}")
    if not lo <= value <= hi:
        raise WavlightError(f"{name} must be between {lo} and {hi}, got {value}")
    return int(value)


def render_full(scene: Scene, spp=None, strategy=None, width=None, height=None, seed=None,
                progress=None, threads=None, backend="opencl", background=None, **options) -> RenderResult:
    """Render with statistics: image, per-pixel standard error and timings.

    ``scene`` is a Scene or a scene file's path. Arguments left as None come from the scene
    file. ``progress(done, total, samples, seconds)`` is called after each part (a tile, or a
    run of its passes: :func:`_parts`). ``backend="numpy"`` shades with the numpy reference
    instead of the OpenCL kernel (same random numbers, same estimator).

    ``options`` are the strategies' and the sampler's settings by key, as in the scene file's
    ``[render]`` table and the CLI's flags: ``wavelet_candidates``, ``wavelet_slots``,
    ``wavelet_levels``, ``wavelet_control_variate``, ``light_levels``, ``sir_candidates``,
    ``sir_samples``, ``structured_strata``, ``structured_mode``, ``sampler``
    (:data:`wavlight.strategies.OPTIONS` declares each one's range and default; docs/cli.md
    lists them). A value of None, or a key left out, takes the scene's value, else the
    default; options of strategies other than the one rendered are checked and ignored.
    ``wavelet`` without candidates or slots chooses them from the scene's shadows
    (strategies.AUTO_BUDGET, :mod:`wavlight.occlusion`).

    ``background`` (:data:`wavlight.options.BACKGROUND`; None: the scene's ``[environment]
    background``) is what camera rays that miss see: the map's nearest texel or its bilinear
    filter; the lighting is the map itself either way.
    """
    if isinstance(scene, (str, os.PathLike)):
        scene = load_scene(scene)
    check_scene(scene)
    if background is not None:
        background = BACKGROUND.check(background, "render_full")
        if background != scene.environment.background:
            scene = dataclasses.replace(scene, environment=scene.environment.with_background(background))

    def pick(option, value, fallback):
        """The argument, else the scene's value; validated either way (a Scene may be edited)."""
        return _integer(option.key, fallback if value is None else value, option.lo, option.hi)

    spp, width, height, seed = (pick(o, v, getattr(scene, o.key)) for o, v in
                                ((SPP, spp), (WIDTH, width), (HEIGHT, height), (SEED, seed)))
    strategy = scene.strategy if strategy is None else strategy
    if strategy not in STRATEGIES:
        raise WavlightError(f"unknown strategy {shown(strategy)} ({' | '.join(STRATEGIES)})")
    if backend not in BACKENDS:
        raise WavlightError(f"unknown backend {shown(backend)} ({' | '.join(BACKENDS)})")
    if threads is not None:
        threads = _integer("threads", threads, 1, MAX_THREADS)
    if progress is not None and not callable(progress):
        raise WavlightError(f"progress must be a callable or None, got {shown(progress)}")
    scene_options = scene.options if isinstance(scene.options, dict) else {}
    given = strategies.check_options(options, "render_full")      # unknown keys and bad values refused
    values = strategies.check_options({**scene_options, **given}, "render_full")
    sampler_name = values.get("sampler", SAMPLER.default)
    options = strategies.constructor_options(strategy, values)
    check_memory("render_full", width, height)   # the film, before any of it is allocated
    r = _Renderer(scene, strategy, spp, width, height, seed, threads, backend, options, sampler_name)
    image = np.zeros((height, width, 3), np.float32)
    stderr = np.zeros((height, width, 3), np.float32)
    tiles = _tiles(width, height, spp)
    parts = _parts(tiles, spp)
    t0 = time.perf_counter()
    done = 0
    sums = {}
    with ThreadPoolExecutor(r.threads) as pool:
        results = pool.map(lambda part: r.sums(*part[0], part[1], part[2]), parts)
        for n, ((tile, first, count), (total, total_sq)) in enumerate(zip(parts, results)):
            i, x0, y0, w, h = tile
            if i in sums:   # the parts of a tile arrive in order: sums do not depend on threads
                total, total_sq = sums[i][0] + total, sums[i][1] + total_sq
            sums[i] = (total, total_sq)
            if first + count == spp:
                image[y0:y0 + h, x0:x0 + w], stderr[y0:y0 + h, x0:x0 + w] = r.finish(*sums.pop(i), w, h)
            done += w * h * count
            if progress:
                progress(n + 1, len(parts), done, time.perf_counter() - t0)
    seconds = time.perf_counter() - t0
    samples = width * height * spp
    stats = {"strategy": strategy, "spp": spp, "width": width, "height": height, "seed": seed,
             "background": scene.environment.background,
             "setup_seconds": round(r.setup_seconds, 4), "render_seconds": round(seconds, 4),
             "samples_per_second": round(samples / seconds, 1) if seconds > 0 else None,
             "rays": r.rays, "rays_per_second": round(r.rays / seconds, 1) if seconds > 0 else None,
             "sampler": sampler_name, "tiles": len(tiles), "threads": r.threads, **r.strategy.info()}
    return RenderResult(image, stderr, stats)


def render(scene: Scene, spp=None, strategy=None, width=None, height=None, seed=None,
           progress=None, threads=None, **options) -> np.ndarray:
    """Render a scene (a Scene, or a scene file's path); returns a float32 (H, W, 3) linear RGB
    image. The other keywords (backend, sampler, wavelet_candidates, ...) are :func:`render_full`'s."""
    return render_full(scene, spp, strategy, width, height, seed, progress, threads, **options).image
