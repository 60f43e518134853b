"""A baked transfer (:func:`wavlight.relight.bake`) and its frames under new lighting.

    transfer = wavlight.bake(scene, output="bunny.wlt")        # or Transfer.load("bunny.wlt")
    image = transfer.frame(rotate_y=120, terms=256)           # float32 (H, W, 3)

A frame (Chen & Gao eq. 6-8): the lighting projected onto the transfer's texels
(:func:`.lighting.project`: another map, turned about +Y, scaled), its Haar coefficients, the
K of largest priority (:func:`.lighting.select_terms`), and per pixel a_p N^2 sum_i T^_p,i L^_i
(:mod:`.frame`), plus the map itself where the pixel's camera samples missed. Approximate by
design: the texels' resolution, the K terms and the transfer's compression each leave an error,
which the bake measures on a held-out rotation and records (``measured``).
"""
from __future__ import annotations

import os
import tempfile
import time

import numpy as np

from .. import cl, data
from ..atomic import atomic_write, size_is
from ..envmap import Environment, read_image
from ..errors import ArgumentError, WavlightError, check_degrees, shown
from . import lighting, store
from .frame import (DeviceFrame, background_bilinear_reference, background_lookup, background_reference,
                    background_uv, coat_reference, image_reference)
from .settings import FRAME

MAX_TERMS = FRAME["terms"].hi
#: the maps whose lighting projectors a Transfer keeps (the viewer offers a few)
MAPS_KEPT = 4


class Transfer:
    """The transfer of one scene's camera and objects, read from its bake file (whole, into
    memory: :func:`wavlight.relight.store.read`).

    width, height, n_levels (texels 2^n x 2^n), block, bits, spp (camera samples per pixel),
    terms (the default K), priority, scene ({path, content_hash}), camera, environment (the
    scene's own map: pixels, rotate_y), measured (the bake's errors and choices)."""

    def __init__(self, path: str, baked: store.BakeFile):
        self.path, self.header, self._s = path, baked.header, baked.sections
        self._file = baked
        self._device = self._lit = self._bg_lookup = self._entry_counts = None
        self._maps = {}   # projectors of the maps frames asked for, by map (a few)
        h = baked.header
        self.width, self.height = int(h["width"]), int(h["height"])
        self.n_levels, self.block, self.bits = int(h["n_levels"]), int(h["block"]), int(h["bits"])
        self.blocks = (int(h["blocks"][0]), int(h["blocks"][1]))   # (columns, rows) of blocks
        self.spp = int(h["spp"])
        self.terms, self.priority = int(h["terms"]), str(h["priority"])
        self.scene, self.camera, self.measured = h["scene"], h["camera"], h.get("measured", {})

    # -- files
    @classmethod
    def load(cls, path, verify: bool = True) -> "Transfer":
        """A bake file, read whole and checked (:func:`wavlight.relight.store.read`: magic,
        version, checksums, length, every field against the sections): a one-line WavlightError
        for a file that is not one, truncated, damaged, inconsistent or of another version."""
        try:
            path = os.fspath(path)
        except TypeError:
            raise ArgumentError(f"Transfer.load: path must be a file name, got {shown(path)}") from None
        return cls(path, store.read(path, verify))

    def copy(self) -> "Transfer":
        """Another Transfer over the same sections (read-only arrays, not copied) with its own maps'
        projectors and device buffers, for another thread (the viewer's converge); also where the
        file is gone or was written over since (a bake made without an output)."""
        if self._file is None:
            raise WavlightError(f"{self.path}: the Transfer is closed")
        return Transfer(self.path, self._file)

    def save(self, path) -> None:
        """Write the bake file as it was loaded to ``path`` (atomically:
        :func:`wavlight.atomic.atomic_write`), whatever has happened to the file since."""
        path = os.fspath(path)
        if self._file is None:
            raise WavlightError(f"{self.path}: the Transfer is closed")
        if os.path.abspath(path) == os.path.abspath(self.path):
            return
        with atomic_write(path, check=size_is(self.file_bytes)) as tmp, open(tmp, "wb") as out:
            out.write(self._file.head)
            out.write(memoryview(self._file.data))

    def close(self):
        """Release the sections and the device's buffers."""
        self._device = self._lit = self._bg_lookup = self._entry_counts = None
        self._maps = {}
        self._s = {}
        self._file = None

    def __del__(self):
        try:
            self.close()
        except Exception:   # interpreter shutdown
            pass

    @property
    def varies(self) -> str:
        """The factor the bake's frames vary: "lighting" (a bake file without ``vary``, made before
        the other factors existed, included), "object" or "view" (relight.settings BAKE["vary"]):
        :func:`wavlight.relight.frames.frames_for` chooses its frames' type by it."""
        return self.header.get("vary", "lighting")

    @property
    def scene_rotate_y(self) -> float:
        """The rotation of the map in the baked scene, degrees reduced modulo 360: a frame's
        default."""
        return check_degrees(self.path, "environment_rotate_y", self.header["environment_rotate_y"])

    def summary(self) -> dict:
        """What the bake chose, its sizes and what it measured (``wavlight bake --json``)."""
        side = 1 << self.n_levels
        m = self.measured
        return {"width": self.width, "height": self.height, "spp": self.spp, "texels": f"{side}x{side}",
                "n_levels": self.n_levels, "texel_points": self.header.get("texel_points"), "block": self.block,
                "bits": self.bits, "terms": self.terms,
                "priority": self.priority, "tolerance": self.header.get("tolerance"), "file": self.path,
                "file_bytes": self.file_bytes, "entries": self.entries, "entries_full": m.get("entries_full"),
                "bake_seconds": m.get("bake_seconds"), "rays": m.get("rays"),
                "rays_per_second": m.get("rays_per_second"), "measured": m,
                "scene": self.scene,
                **({"vary": "view", "model": self.header.get("model"), "cache": self.header.get("cache")}
                   if self.varies == "view" else {})}

    @property
    def file_bytes(self) -> int:
        return int(self.header["file_bytes"])

    @property
    def entries(self) -> int:
        return int(self._s["entry_scale"].shape[0])

    # -- lighting
    def environment(self, env=None, scale: float = FRAME["scale"].default) -> Environment:
        """The lighting of a frame: ``env`` (an Environment, a map file or ``"data:NAME"``, or
        None: the scene's own map as baked), without its rotation (a frame's ``rotate_y`` sets it), times ``scale``
        (the last one asked for is kept: frames of one map do not read it again)."""
        key = (id(env) if isinstance(env, Environment) else env, float(scale))
        found = self._maps.get(key)
        if found is not None and (not isinstance(env, Environment) or found[2] is env):
            return found[0]
        environment = self._environment(env, scale)
        if len(self._maps) >= MAPS_KEPT:
            self._maps.pop(next(iter(self._maps)))
        self._maps[key] = (environment, None, env)   # its projector made when a relit frame needs it
        return environment

    def _projector(self, environment):
        for key, (kept, projector, env) in self._maps.items():
            if kept is environment:
                if projector is None:
                    projector = lighting.Projector(environment, self.n_levels)
                    self._maps[key] = (kept, projector, env)
                return projector
        return lighting.Projector(environment, self.n_levels)

    def _coefficients(self, environment: Environment, rotate_y: float, backend: str) -> np.ndarray:
        """(3, N, N) the lighting's Haar coefficients: on the device where it has doubles (its
        kernels give numpy's coefficients bit for bit; the map's integrals uploaded once per
        projector), else numpy's."""
        projector = self._projector(environment)
        if backend == "numpy" or not lighting.DeviceProjector.available():
            return lighting.coefficients(projector(rotate_y))
        device = self._lit.get(id(projector)) if self._lit is not None else None
        if device is None or device.projector is not projector:
            kept = {id(p) for _, p, _ in self._maps.values() if p is not None}
            self._lit = {k: v for k, v in (self._lit or {}).items() if k in kept}
            device = self._lit[id(projector)] = lighting.DeviceProjector(projector)
        return device.coefficients(rotate_y)

    def _environment(self, env, scale):
        if env is None:
            return Environment(np.asarray(self._s["environment"]), scale, 0.0, "the baked environment")
        if isinstance(env, Environment):
            return Environment(env.pixels, scale, 0.0, env.name)
        if isinstance(env, (str, os.PathLike)):
            name = os.fspath(env)   # a file, or a "data:NAME" asset (wavlight.data)
            return Environment(read_image(data.resolve(name, kind="environment map")), scale, 0.0, name)
        raise ArgumentError(f"Transfer.frame: env must be an Environment, a map file or None, got {shown(env)}")

    def lighting(self, env=None, rotate_y=None, scale: float = FRAME["scale"].default):
        """(3, N, N) Haar coefficients of the frame's lighting on the transfer's texels (numpy's;
        a frame's come from the device, equal bit for bit)."""
        rot = self.scene_rotate_y if rotate_y is None else check_degrees("Transfer.lighting", "rotate_y", rotate_y)
        environment = self.environment(env, scale)
        return lighting.coefficients(self._projector(environment)(rot))

    # -- frames
    def frame(self, env=None, rotate_y=None, scale: float = FRAME["scale"].default, terms=None, priority=None,
              backend: str = "opencl", background: str = FRAME["background"].default) -> np.ndarray:
        """(H, W, 3) float32: the frame under ``env`` (default: the scene's map) turned to
        ``rotate_y`` degrees about +Y (absolute, as the scene's rotate_y; default the scene's),
        times ``scale``, from ``terms`` lighting coefficients (default: the bake's choice); where
        camera samples missed, the map's nearest texels, (``background="bilinear"``) its
        bilinear filter or (``background="none"``) nothing: those samples contribute 0."""
        return self.frame_timed(env, rotate_y, scale, terms, priority, backend, background)[0]

    def frame_timed(self, env=None, rotate_y=None, scale: float = FRAME["scale"].default, terms=None, priority=None,
                    backend: str = "opencl", background: str = FRAME["background"].default):
        """The frame and its timings, the terms, the entries read and the rotation (degrees, reduced
        modulo 360). Timings, seconds: lighting (the turned map's texels and their Haar
        coefficients), terms (the selection of K), product (the sparse product times the albedo),
        assembly (the rest: the background where camera samples missed, the copy back, the
        finiteness check), background (the first part of the assembly), frame (all)."""
        where = "Transfer.frame"
        if self.varies == "view":
            raise WavlightError(f"{self.path}: this bake varies the view (its lighting is fixed): its frames come "
                                "from wavlight.relight.view_frames.ViewFrames")
        if rotate_y is not None:
            rotate_y = check_degrees(where, "rotate_y", rotate_y)
        scale = FRAME["scale"].check(scale, where)
        background = FRAME["background"].check(background, where)
        terms = self.terms if terms is None else FRAME["terms"].check(terms, where)
        priority = self.priority if priority is None else FRAME["priority"].check(priority, where)
        if backend not in ("opencl", "numpy"):
            raise ArgumentError(f"{where}: backend must be opencl or numpy, got {shown(backend)}")
        t0 = time.perf_counter()
        environment = self.environment(env, scale)
        rot = self.scene_rotate_y if rotate_y is None else rotate_y
        coeffs = self._coefficients(environment, rot, backend)
        t1 = time.perf_counter()
        columns = lighting.select_terms(coeffs, terms, priority, self._s["rms"])
        side = 1 << self.n_levels
        values = coeffs.reshape(3, -1)[:, columns].T * float(side * side)
        t2 = time.perf_counter()
        if backend == "numpy":
            image = image_reference(self._s["offsets"], self._s["entry_scale"], self._s["entry_data"], columns, values,
                                    self._s["albedo"], self.blocks[0])
            if "coat_blocks" in self._s:   # plastic's coat, without the albedo
                image += coat_reference(self._s["coat_blocks"], self._s["coat_offsets"], self._s["coat_entry_scale"],
                                        self._s["coat_entry_data"], columns, values,
                                        self.blocks[0] * self.blocks[1], self.blocks[0], self.width, self.height)
            t3 = time.perf_counter()
            self._add_background(image, environment, rot, background)
            t_bg = time.perf_counter()
        else:
            device = self._frame_device()
            queue = cl.thread_queue()
            out = device.product(columns, values, queue)
            queue.finish()
            t3 = time.perf_counter()
            device.background(out, environment, rot, queue, background)
            queue.finish()
            t_bg = time.perf_counter()
            image = device.read(out, queue)
        if not np.isfinite(image).all():
            raise WavlightError(f"{self.path}: the frame overflows float32 (its transfer times the lighting; a "
                                "smaller --scale or map)")
        t4 = time.perf_counter()
        return image, {"lighting_seconds": t1 - t0, "terms_seconds": t2 - t1, "product_seconds": t3 - t2,
                       "assembly_seconds": t4 - t3, "background_seconds": t_bg - t3, "frame_seconds": t4 - t0,
                       "terms": int(len(columns)),
                       "entries_read": self._entries_read(columns), "rotate_y": rot}

    def _entries_read(self, columns: np.ndarray) -> int:
        """The stored entries of the coefficients ``columns``: the sum of their counts (counted
        once per Transfer)."""
        if self._entry_counts is None:
            self._entry_counts = np.count_nonzero(np.asarray(self._s["offsets"]) >= 0, axis=1)
        return int(self._entry_counts[columns].sum()) if len(columns) else 0

    def _frame_device(self) -> DeviceFrame:
        if self._device is None:
            self._device = DeviceFrame(self._s, self.width, self.height, self.blocks[0], self.spp)
        return self._device

    def _add_background(self, image: np.ndarray, environment: Environment, rotate_y: float,
                        background: str = "nearest") -> None:
        """numpy: the environment where the camera samples missed, added to ``image`` (H, W, 3)
        (with ``background="none"`` nothing: misses contribute 0)."""
        pixels = self._s["background_pixel"]
        if background == "none":
            return
        if len(pixels) and background == "bilinear":
            count, uv = background_uv(self._s["background_dir"], self._s["background_mask"])
            seen = background_bilinear_reference(environment.pixels, rotate_y, count, uv)
            image.reshape(-1, 3)[np.asarray(pixels, np.int64)] += seen
        elif len(pixels):
            u0, row = self._background_lookup(environment.height)
            seen = background_reference(environment.pixels, rotate_y, self._s["background_mask"], u0, row)
            image.reshape(-1, 3)[np.asarray(pixels, np.int64)] += seen

    def _background_lookup(self, env_height: int):
        """The background samples' u at rotation 0 and map rows, per map height (kept)."""
        if self._bg_lookup is None or self._bg_lookup[0] != env_height:
            self._bg_lookup = (env_height, *background_lookup(self._s["background_dir"], env_height))
        return self._bg_lookup[1:]


def finish_bake(writer, output, header: dict, arrays: dict) -> Transfer:
    """Write a bake's file from ``writer`` (a store.TransferWriter holding its entries) with
    ``header`` and the other sections ``arrays``, atomically, to ``output`` (None: a temporary
    file, removed as soon as it is read: the Transfer holds the whole file in memory, and a
    process killed later leaves nothing behind)."""
    if output is not None:
        writer.finish(os.fspath(output), header, arrays)
        return Transfer(os.fspath(output), store.read(os.fspath(output), verify=False))
    fd, output = tempfile.mkstemp(prefix=".wavlight-bake-", suffix=".wlt")
    os.close(fd)
    try:
        writer.finish(output, header, arrays)
        return Transfer(output, store.read(output, verify=False))
    finally:
        os.unlink(output)
