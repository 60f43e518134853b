"""A relit frame: the double product integral <T1, T2> of the transfer and the lighting
(Chen & Gao eq. 6-8) as a sparse dot product of their Haar coefficients.

For pixel p, B_p = a_p sum_t T_p,t L_t = a_p N^2 sum_i T^_p,i L^_i (Parseval on the unit
square's orthonormal basis, :mod:`wavlight.relight.lighting`), over the K lighting
coefficients i a frame keeps and the transfer's stored entries: the offset table of the bake
file gives entry o = offsets[i, b] of coefficient i in block b (or none), a row of quantized
values q_o of the block's BLOCK^2 pixels with its scale. The kernel ``frame_product``
(kernels/relight.cl; numpy twin :func:`product_reference`) walks the K rows of the table,
four blocks to a work-item: a frame reads only the entries of its K coefficients, and the host
sends only their indices and lighting values.
"""
from __future__ import annotations

import numpy as np

from .. import cl


def product_reference(offsets: np.ndarray, entry_scale: np.ndarray, entry_data: np.ndarray, columns: np.ndarray,
                      values: np.ndarray) -> np.ndarray:
    """numpy twin of ``frame_product``: (n_blocks, BLOCK^2, 3) float64, block b's pixels' sum over
    the kept coefficients c_k (``columns`` (K,)) with lighting ``values`` (K, 3) (times N^2) of
    q_o scale_o L_k, o = offsets[c_k, b] where it exists."""
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


class DeviceEntries:
    """The bake file's index and quantized entries as read-only device buffers over its memory
    maps (no copy on a CPU device where OpenCL can use the host memory), shared by every frame."""

    TILE_BLOCKS = 4

    def __init__(self, offsets: np.ndarray, entry_scale: np.ndarray, entry_data: np.ndarray):
        self.pixels = int(entry_data.shape[1])
        self.bits = 8 * entry_data.dtype.itemsize
        self.n_blocks = int(offsets.shape[1])
        self.offsets = self._buffer(offsets, np.int32)
        self.scale = self._buffer(entry_scale, np.float32)
        self.data = self._buffer(entry_data, entry_data.dtype)

    @staticmethod
    def _buffer(a, dtype):
        pyopencl = cl._cl()
        flat = np.asarray(a).reshape(-1)
        if flat.size == 0:
            flat = np.zeros(64, dtype)
        mf = pyopencl.mem_flags
        try:
            return pyopencl.Buffer(cl.runtime().context, mf.READ_ONLY | mf.USE_HOST_PTR, hostbuf=flat), flat
        except (pyopencl.Error, TypeError, ValueError, BufferError):   # a read-only map: a copy
            return cl.to_device(np.ascontiguousarray(flat, dtype)), None

    def product(self, columns: np.ndarray, values: np.ndarray, queue=None) -> np.ndarray:
        """(n_blocks, BLOCK^2, 3) float32: the kernel ``frame_product`` for the kept coefficients
        ``columns`` (K,) with lighting ``values`` (K, 3) (times N^2)."""
        queue = queue or cl.thread_queue()
        out = cl.empty(4 * 3 * self.n_blocks * self.pixels)
        if len(columns):
            prog = cl.program("relight.cl", QBITS=self.bits, PIXELS=self.pixels, TILE_BLOCKS=self.TILE_BLOCKS)
            light = np.zeros((len(columns), 4), np.float32)
            light[:, :3] = values
            items = -(-self.n_blocks // self.TILE_BLOCKS)
            cl.kernel(prog, "frame_product")(
                queue, (items,), None, np.uint32(len(columns)), np.uint32(self.n_blocks),
                cl.to_device(np.asarray(columns, np.int32)), cl.to_device(light), self.offsets[0], self.scale[0],
                self.data[0], out)
            planes = cl.read(out, (3, self.n_blocks, self.pixels), np.float32, queue)
            return np.moveaxis(planes, 0, -1)
        return np.zeros((self.n_blocks, self.pixels, 3), np.float32)


def background_lookup(dirs: np.ndarray, env_height: int):
    """Each background sample's u at rotate_y = 0 (float32) and map row (int32), from its world
    direction (M, S, 3): a rotation about +Y only shifts u (u_map = u + rotate_y / 360)."""
    d = np.asarray(dirs, np.float64).reshape(-1, 3)
    u = np.arctan2(d[:, 0], -d[:, 2]) / (2 * np.pi)
    u = (u - np.floor(u)).astype(np.float32)
    v = np.arccos(np.clip(d[:, 1], -1.0, 1.0)) / np.pi
    row = np.minimum((v * env_height).astype(np.int64), env_height - 1).astype(np.int32)
    return u.reshape(dirs.shape[:2]), row.reshape(dirs.shape[:2])


def background_reference(pixels: np.ndarray, rotate_y: float, mask: np.ndarray, u0: np.ndarray,
                         row: np.ndarray) -> np.ndarray:
    """numpy twin of ``frame_background``: (M, 3) float32, (1 / S) sum over the missing samples of
    the map (H, W, 3) turned to ``rotate_y`` at their nearest texels (the kernel's float32 steps)."""
    m, samples = u0.shape
    h, w = pixels.shape[:2]
    u = u0 + np.float32(rotate_y / 360.0)
    u = u - np.floor(u)
    col = np.minimum((u * np.float32(w)).astype(np.int32), w - 1)
    radiance = np.asarray(pixels, np.float32).reshape(-1, 3)[(row.astype(np.int64) * w + col).reshape(-1)]
    missing = ((np.asarray(mask, np.uint64)[:, None] >> np.arange(samples, dtype=np.uint64)) & np.uint64(1)) > 0
    total = (radiance.reshape(m, samples, 3) * missing[..., None]).sum(1, dtype=np.float32)
    return total * np.float32(1.0 / samples)


def background_cl(env_buffer, env_width: int, rotate_y: float, mask_buffer, u0_buffer, row_buffer, count: int,
                  samples: int, queue=None) -> np.ndarray:
    """The kernel ``frame_background`` on device buffers: (M, 3) float32."""
    queue = queue or cl.thread_queue()
    out = cl.scratch("frame_background", 12 * max(count, 1))
    if count:
        prog = cl.program("relight.cl")
        cl.kernel(prog, "frame_background")(queue, (cl.items(count, cl.LANES),), (cl.WORK_GROUP,), np.uint32(count),
                                            np.uint32(samples), np.int32(env_width),
                                            np.float32(rotate_y / 360.0), mask_buffer, u0_buffer, row_buffer,
                                            env_buffer, out)
        return cl.read(out, (count, 3), np.float32, queue)
    return np.zeros((0, 3), np.float32)
