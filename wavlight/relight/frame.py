"""A relit frame: the double product integral <T1, T2> of the transfer and the lighting
(Chen & Gao eq. 6-8) as a sparse dot product of their Haar coefficients, and the environment
where the camera samples missed.

For pixel p, B_p = a_p sum_t T_p,t L_t = a_p N^2 sum_i T^_p,i L^_i (Parseval on the unit
square's orthonormal basis, :mod:`wavlight.relight.lighting`), over the K lighting
coefficients i a frame keeps and the transfer's stored entries: the offset table of the bake
file gives entry o = offsets[i, b] of coefficient i in block b (or none), a row of quantized
values q_o of the block's BLOCK^2 pixels with its scale. The kernel ``frame_product``
(kernels/relight.cl; numpy twin :func:`image_reference`) walks the K rows of the table,
four blocks to a work-item, and writes the frame's pixels times their albedo a_p: a frame reads
only the entries of its K coefficients, and the host sends only their indices and lighting
values and reads the frame back once. A bake with plastic's coat (C, stored for the blocks that
see plastic: :data:`wavlight.relight.store.COAT_SECTIONS`) adds N^2 sum_i C^_p,i L^_i over the same
coefficients, without the albedo (``frame_product`` built with COAT, twin :func:`coat_reference`).

Where a pixel's camera samples missed, the frame adds the map itself, turned, at the samples'
directions (nearest texel, as :meth:`wavlight.envmap.Environment.eval`): the kernel
``frame_background`` (numpy twin :func:`background_reference`) takes each pixel's missing
samples sorted by map row and u (:func:`background_samples`, once per map height), so that a
rotation, which only shifts u, leaves the samples of one map texel in a run, and looks each
run's texel up once. With ``background = "bilinear"`` (:data:`wavlight.options.BACKGROUND`;
display only, the lighting stays the map's texels) the kernel ``frame_background_bilinear``
(numpy twin :func:`background_bilinear_reference`) filters the turned map bilinearly at each
missing sample (:func:`wavlight.envmap.bilinear`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import cl
from ..envmap import bilinear


def product_reference(offsets: np.ndarray, entry_scale: np.ndarray, entry_data: np.ndarray, columns: np.ndarray,
                      values: np.ndarray) -> np.ndarray:
    """(n_blocks, BLOCK^2, 3) float64, block b's pixels' sum over the kept coefficients c_k
    (``columns`` (K,)) with lighting ``values`` (K, 3) (times N^2) of q_o scale_o L_k,
    o = offsets[c_k, b] where it exists."""
    n_blocks, pixels = offsets.shape[1], entry_data.shape[1]
    out = np.zeros((n_blocks, pixels, 3))
    rows = np.asarray(offsets[np.asarray(columns, np.int64)], np.int64)          # (K, n_blocks)
    term, block = np.nonzero(rows >= 0)
    ids = rows[term, block]
    step = max(1, (1 << 22) // pixels)
    for i in range(0, len(ids), step):   # chunks of entries, for bounded memory
        q = np.asarray(entry_data[ids[i:i + step]], np.float64)
        w = np.asarray(entry_scale[ids[i:i + step]], np.float64)[:, None] * np.asarray(values, np.float64)[term[i:i + step]]
        np.add.at(out, block[i:i + step], q[:, :, None] * w[:, None, :])
    return out


def untile(blocks: np.ndarray, blocks_x: int, width: int, height: int) -> np.ndarray:
    """(height, width, C) pixels of (n_blocks, BLOCK^2, C) blocks, blocks_x to a row of the
    image, BLOCK^2 pixels to a block in rows of BLOCK (the parts beyond the image left out)."""
    n_blocks, pixels, c = blocks.shape
    b = int(round(pixels ** 0.5))
    bh = n_blocks // blocks_x
    img = blocks.reshape(bh, blocks_x, b, b, c).transpose(0, 2, 1, 3, 4).reshape(bh * b, blocks_x * b, c)
    return img[:height, :width]


def image_reference(offsets: np.ndarray, entry_scale: np.ndarray, entry_data: np.ndarray, columns: np.ndarray,
                    values: np.ndarray, albedo: np.ndarray, blocks_x: int) -> np.ndarray:
    """numpy twin of ``frame_product``: (H, W, 3) float32, each pixel's sum over the kept
    coefficients (:func:`product_reference`, in float64) times its albedo (H, W, 3)."""
    h, w = albedo.shape[:2]
    img = untile(product_reference(offsets, entry_scale, entry_data, columns, values), blocks_x, w, h)
    return np.ascontiguousarray(img * albedo, np.float32)


def coat_reference(coat_blocks: np.ndarray, offsets: np.ndarray, entry_scale: np.ndarray, entry_data: np.ndarray,
                   columns: np.ndarray, values: np.ndarray, n_blocks: int, blocks_x: int, width: int,
                   height: int) -> np.ndarray:
    """numpy twin of ``frame_product`` with COAT: (H, W, 3) float32, plastic's coat in a frame,
    each pixel's sum over the kept coefficients of its block's coat entries (the store's
    coat_offsets over the blocks ``coat_blocks`` of the image's ``n_blocks``; no albedo)."""
    some = product_reference(offsets, entry_scale, entry_data, columns, values)
    full = np.zeros((n_blocks, some.shape[1], 3))
    full[np.asarray(coat_blocks, np.int64)] = some
    return np.ascontiguousarray(untile(full, blocks_x, width, height), np.float32)


class DeviceEntries:
    """The bake file's index and quantized entries as read-only device buffers over its memory
    (no copy on a CPU device where OpenCL can use the host memory), shared by every frame.
    ``block_of``: the image's block of each of the entries' blocks (plastic's coat, whose
    entries are stored for the blocks that see plastic alone); None: the image's own blocks."""

    TILE_BLOCKS = 4
    #: work-items per work-group of ``frame_product``: left to PoCL, a frame's 256 work-items (512^2)
    #: were one group, on one core
    GROUP = 4

    def __init__(self, offsets: np.ndarray, entry_scale: np.ndarray, entry_data: np.ndarray, block_of=None):
        self.pixels = int(entry_data.shape[1])
        self.block = int(round(self.pixels ** 0.5))
        self.bits = 8 * entry_data.dtype.itemsize
        self.n_blocks = int(offsets.shape[1])
        self.offsets = self._buffer(offsets, np.int32)
        self.scale = self._buffer(entry_scale, np.float32)
        self.data = self._buffer(entry_data, entry_data.dtype)
        self.coat = block_of is not None
        self.block_of = self._buffer(np.zeros(1, np.int32) if block_of is None else np.asarray(block_of, np.int32),
                                     np.int32)

    @staticmethod
    def _buffer(a, dtype):
        pyopencl = cl.opencl()
        flat = np.asarray(a).reshape(-1)
        if flat.size == 0:
            flat = np.zeros(64, dtype)
        mf = pyopencl.mem_flags
        try:
            return pyopencl.Buffer(cl.runtime().context, mf.READ_ONLY | mf.USE_HOST_PTR, hostbuf=flat), flat
        except (pyopencl.Error, TypeError, ValueError, BufferError):   # a read-only map: a copy
            return cl.to_device(np.ascontiguousarray(flat, dtype)), None

    def image(self, columns: np.ndarray, values: np.ndarray, albedo_buffer, blocks_x: int, width: int, height: int,
              out, queue=None):
        """Enqueue the kernel ``frame_product`` for the kept coefficients ``columns`` (K,) with
        lighting ``values`` (K, 3) (times N^2): the frame's (height, width, 3) float32 pixels
        times their albedo (the device buffer ``albedo_buffer``), into the device buffer ``out``;
        a coat's (``block_of`` given) added to ``out`` as they are."""
        if self.n_blocks == 0:
            return
        queue = queue or cl.thread_queue()
        prog = cl.program("relight.cl", QBITS=self.bits, BLOCK=self.block, TILE_BLOCKS=self.TILE_BLOCKS,
                          COAT=int(self.coat))
        light = np.zeros((max(len(columns), 1), 4), np.float32)
        light[:len(columns), :3] = values
        cols = np.zeros(max(len(columns), 1), np.int32)
        cols[:len(columns)] = columns
        items = -(-self.n_blocks // (self.TILE_BLOCKS * self.GROUP)) * self.GROUP
        cl.kernel(prog, "frame_product")(
            queue, (items,), (self.GROUP,), np.uint32(len(columns)), np.uint32(self.n_blocks), np.uint32(blocks_x),
            np.uint32(width), np.uint32(height), cl.upload("frame_columns", cols, queue),
            cl.upload("frame_light", light, queue), self.offsets[0], self.scale[0], self.data[0], albedo_buffer,
            self.block_of[0], out)


def background_lookup(dirs: np.ndarray, env_height: int):
    """Each background sample's u at rotate_y = 0 (float32) and map row (int32), from its world
    direction (M, S, 3): a rotation about +Y only shifts u (u_map = u + rotate_y / 360)."""
    d = np.asarray(dirs, np.float64).reshape(-1, 3)
    u = np.arctan2(d[:, 0], -d[:, 2]) / (2 * np.pi)
    u = (u - np.floor(u)).astype(np.float32)
    v = np.arccos(np.clip(d[:, 1], -1.0, 1.0)) / np.pi
    row = np.minimum((v * env_height).astype(np.int64), env_height - 1).astype(np.int32)
    return u.reshape(dirs.shape[:2]), row.reshape(dirs.shape[:2])


@dataclass(frozen=True)
class BackgroundSamples:
    """The missing camera samples of a frame's background pixels, as ``frame_background`` takes
    them: pixel i's count[i] (M,) uint32 samples in the first slots of u0[i] and row[i] ((M,
    SLOTS) float32 and int32, SLOTS = S rounded up to whole vectors of ``cl.LANES``), sorted
    by map row and then by u at rotate_y = 0 (:func:`background_lookup`'s values; row -1 in
    the slots beyond count[i]); seg (M, 2, 4) float32: the pixel's first two map rows (its
    samples' first and last u0 there, the row and the number of samples, both as int32 bits;
    zeros where there is no second row)."""

    count: np.ndarray
    u0: np.ndarray
    row: np.ndarray
    seg: np.ndarray


def background_samples(dirs: np.ndarray, mask: np.ndarray, env_height: int, lanes: int = cl.LANES) -> BackgroundSamples:
    """The background pixels' missing samples (bit s of ``mask`` (M,) set: sample s of the pixel's
    directions ``dirs`` (M, S, 3)) for a map of ``env_height`` rows, sorted per pixel by row and
    u0: the key row * 2^32 + the bits of u0 (a float32 >= 0, whose bits order as its values)."""
    u0, row = background_lookup(dirs, env_height)
    m, samples = u0.shape
    slots = -(-max(samples, 1) // lanes) * lanes
    missing = ((np.asarray(mask, np.uint64)[:, None] >> np.arange(samples, dtype=np.uint64)) & np.uint64(1)) > 0
    key = (row.astype(np.uint64) << np.uint64(32)) | u0.view(np.uint32).astype(np.uint64)
    key[~missing] = np.iinfo(np.uint64).max
    key.sort(axis=1)                                               # the missing ones come first
    count = missing.sum(1).astype(np.uint32)
    kept = np.arange(samples)[None, :] < count[:, None]
    u0s = np.zeros((m, slots), np.float32)
    rows = np.full((m, slots), -1, np.int32)
    u0s[:, :samples] = np.where(kept, (key & np.uint64(0xFFFFFFFF)).astype(np.uint32).view(np.float32), 0.0)
    rows[:, :samples] = np.where(kept, (key >> np.uint64(32)).astype(np.int64), -1)
    # the first two rows' spans of slots: [0, n0) and [n0, n0 + n1)
    n0 = (rows == rows[:, :1]).sum(1) * (count > 0)
    second = rows[np.arange(m), np.minimum(n0, slots - 1)]
    n1 = np.where(n0 < count, (rows == second[:, None]).sum(1), 0)
    seg = np.zeros((m, 2, 4), np.float32)
    ids = np.arange(m)
    for k, (lo, n) in enumerate(((np.zeros(m, np.int64), n0), (n0, n1))):
        has = n > 0
        first, last = np.where(has, lo, 0), np.where(has, lo + n - 1, 0)
        seg[:, k, 0] = np.where(has, u0s[ids, first], 0.0)
        seg[:, k, 1] = np.where(has, u0s[ids, last], 0.0)
        seg[:, k, 2] = np.where(has, rows[ids, first], 0).astype(np.int32).view(np.float32)
        seg[:, k, 3] = n.astype(np.uint32).view(np.float32)
    return BackgroundSamples(count, u0s, rows, seg)


def background_reference(pixels: np.ndarray, rotate_y: float, mask: np.ndarray, u0: np.ndarray,
                         row: np.ndarray) -> np.ndarray:
    """numpy twin of ``frame_background``: (M, 3) float32, (1 / S) sum over the missing samples of
    the map (H, W, 3) turned to ``rotate_y`` at their nearest texels (the kernel's float32 steps),
    sample by sample, from :func:`background_lookup`'s u0 and rows (M, S)."""
    m, samples = u0.shape
    h, w = pixels.shape[:2]
    u = u0 + np.float32(rotate_y / 360.0)
    u = u - np.floor(u)
    col = np.minimum((u * np.float32(w)).astype(np.int32), w - 1)
    radiance = np.asarray(pixels, np.float32).reshape(-1, 3)[(row.astype(np.int64) * w + col).reshape(-1)]
    missing = ((np.asarray(mask, np.uint64)[:, None] >> np.arange(samples, dtype=np.uint64)) & np.uint64(1)) > 0
    total = (radiance.reshape(m, samples, 3) * missing[..., None]).sum(1, dtype=np.float32)
    return total * np.float32(1.0 / samples)


def background_uv(dirs: np.ndarray, mask: np.ndarray):
    """The background pixels' missing samples for ``frame_background_bilinear``: count (M,) uint32
    and uv (M, S, 2) float32, pixel i's missing samples' (u at rotate_y = 0, v) in its first
    count[i] slots (in their order; zeros beyond), from their directions (M, S, 3) and ``mask``."""
    m, samples = np.asarray(mask).shape[0], dirs.shape[1]
    d = np.asarray(dirs, np.float64).reshape(-1, 3)
    u = np.arctan2(d[:, 0], -d[:, 2]) / (2 * np.pi)
    u = u - np.floor(u)
    v = np.arccos(np.clip(d[:, 1], -1.0, 1.0)) / np.pi
    both = np.stack([u, v], 1).astype(np.float32).reshape(m, samples, 2)
    missing = ((np.asarray(mask, np.uint64)[:, None] >> np.arange(samples, dtype=np.uint64)) & np.uint64(1)) > 0
    order = np.argsort(~missing, axis=1, kind="stable")               # the missing ones first, in order
    uv = np.take_along_axis(both, order[:, :, None], axis=1)
    count = missing.sum(1).astype(np.uint32)
    uv[np.arange(samples)[None, :] >= count[:, None]] = 0.0
    return count, np.ascontiguousarray(uv)


def background_bilinear_reference(pixels: np.ndarray, rotate_y: float, count: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """numpy twin of ``frame_background_bilinear``: (M, 3) float32, (1 / S) sum over each pixel's
    count[i] missing samples uv (M, S, 2) (:func:`background_uv`) of the map (H, W, 3) turned to
    ``rotate_y``, filtered bilinearly (:func:`wavlight.envmap.bilinear`; the kernel's float32 steps)."""
    m, samples = uv.shape[:2]
    u = uv[:, :, 0].reshape(-1) + np.float32(rotate_y / 360.0)
    u = u - np.floor(u)
    seen = bilinear(pixels, u, uv[:, :, 1].reshape(-1)).reshape(m, samples, 3)
    kept = np.arange(samples)[None, :] < np.asarray(count)[:, None]
    return (seen * kept[..., None]).sum(1, dtype=np.float32) * np.float32(1.0 / samples)


def background_cl(env_buffer, env_width: int, rotate_y: float, buffers, count: int, samples: int, out,
                  queue=None) -> None:
    """Enqueue the kernel ``frame_background``: the map (a device buffer, ``env_width`` columns)
    turned to ``rotate_y`` at the ``count`` background pixels' missing samples, added to those
    pixels of the frame in the device buffer ``out`` ((H, W, 3) float32). ``buffers``: the
    device buffers of :class:`BackgroundSamples`' count, seg, u0 and row, and the pixels'
    indices in the frame (M,) uint32; ``samples``: S, the camera samples per pixel."""
    if count:
        queue = queue or cl.thread_queue()
        prog = cl.program("relight.cl", SLOTS=-(-samples // cl.LANES) * cl.LANES)
        n, seg, u0, row, pixel = buffers
        cl.kernel(prog, "frame_background")(
            queue, (cl.items(count),), (cl.WORK_GROUP,), np.uint32(count), np.float32(1.0 / samples),
            np.int32(env_width), np.float32(rotate_y / 360.0), n, seg, u0, row, pixel, env_buffer, out)


def background_bilinear_cl(env_buffer, env_width: int, env_height: int, rotate_y: float, buffers, count: int,
                           samples: int, out, queue=None) -> None:
    """Enqueue the kernel ``frame_background_bilinear``: as :func:`background_cl`, the map filtered
    bilinearly; ``buffers``: the device buffers of :func:`background_uv`'s count and uv, and the
    pixels' indices in the frame (M,) uint32."""
    if count:
        queue = queue or cl.thread_queue()
        prog = cl.program("relight.cl", SLOTS=-(-samples // cl.LANES) * cl.LANES)
        n, uv, pixel = buffers
        cl.kernel(prog, "frame_background_bilinear")(
            queue, (cl.items(count),), (cl.WORK_GROUP,), np.uint32(count), np.uint32(samples),
            np.float32(1.0 / samples), np.int32(env_width), np.int32(env_height), np.float32(rotate_y / 360.0),
            n, uv, pixel, env_buffer, out)


class DeviceFrame:
    """What the frames of one bake keep on the device: its entries (:class:`DeviceEntries`), the
    pixels' albedo, the background's samples (per map height) and the map (per Environment),
    and the frame's buffer (the calling thread's scratch)."""

    def __init__(self, sections: dict, width: int, height: int, blocks_x: int, samples: int):
        s = sections
        self.entries = DeviceEntries(s["offsets"], s["entry_scale"], s["entry_data"])
        self.coat = (DeviceEntries(s["coat_offsets"], s["coat_entry_scale"], s["coat_entry_data"], s["coat_blocks"])
                     if "coat_blocks" in s else None)
        self.width, self.height, self.blocks_x, self.samples = width, height, blocks_x, samples
        self.albedo = cl.to_device(np.ascontiguousarray(s["albedo"], np.float32))
        self._dirs, self._mask = s["background_dir"], s["background_mask"]
        self._pixel = cl.to_device(np.ascontiguousarray(s["background_pixel"], np.uint32)) if len(self._mask) else None
        self._bg = self._env = self._uv = None

    def background_buffers(self, env_height: int):
        """The device buffers of :func:`background_samples` for maps of ``env_height`` rows (the
        last height asked for is kept), and the pixels' indices."""
        if self._bg is None or self._bg[0] != env_height:
            bg = background_samples(self._dirs, self._mask, env_height)
            self._bg = (env_height, (cl.to_device(bg.count), cl.to_device(bg.seg), cl.to_device(bg.u0),
                                     cl.to_device(bg.row), self._pixel))
        return self._bg[1]

    def bilinear_buffers(self):
        """The device buffers of :func:`background_uv` (made once), and the pixels' indices."""
        if self._uv is None:
            count, uv = background_uv(self._dirs, self._mask)
            self._uv = (cl.to_device(count), cl.to_device(uv), self._pixel)
        return self._uv

    def env_buffer(self, environment):
        """The map on the device, uploaded once per Environment."""
        if self._env is None or self._env[0] is not environment:
            self._env = (environment, cl.to_device(np.ascontiguousarray(environment.pixels, np.float32)))
        return self._env[1]

    def product(self, columns: np.ndarray, values: np.ndarray, queue=None):
        """Enqueue the frame's sparse product (:meth:`DeviceEntries.image`) into the thread's
        frame buffer, which is returned."""
        queue = queue or cl.thread_queue()
        out = cl.scratch("frame_image", 12 * self.width * self.height)
        self.entries.image(columns, values, self.albedo, self.blocks_x, self.width, self.height, out, queue)
        if self.coat is not None:   # plastic's coat, added (the queue runs in order)
            self.coat.image(columns, values, self.albedo, self.blocks_x, self.width, self.height, out, queue)
        return out

    def background(self, out, environment, rotate_y: float, queue=None, background: str = "nearest") -> None:
        """Enqueue the background's lookup (:func:`background_cl`, or :func:`background_bilinear_cl`
        with ``background="bilinear"``) into the frame buffer ``out``."""
        if not len(self._mask):
            return
        if background == "bilinear":
            background_bilinear_cl(self.env_buffer(environment), environment.width, environment.height, rotate_y,
                                   self.bilinear_buffers(), len(self._mask), self.samples, out, queue)
        else:
            background_cl(self.env_buffer(environment), environment.width, rotate_y,
                          self.background_buffers(environment.height), len(self._mask), self.samples, out, queue)

    def read(self, out, queue=None) -> np.ndarray:
        """(H, W, 3) float32: the frame buffer, once its kernels are done."""
        return cl.read(out, (self.height, self.width, 3), np.float32, queue or cl.thread_queue())
