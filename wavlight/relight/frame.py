"""A relit frame: the double product integral <T1, T2> of the transfer and the lighting
(Chen & Gao eq. 6-8) as a sparse dot product of their Haar coefficients.

For pixel p, B_p = a_p sum_t T_p,t L_t = a_p N^2 sum_i T^_p,i L^_i (Parseval on the unit
square's orthonormal basis, :mod:`wavlight.relight.lighting`), over the K lighting
coefficients i a frame keeps and the transfer's stored entries (column i, block b). Each
selected column's entries are gathered by block (:func:`gather`): entry j of block b carries
its row of quantized values q_j (BLOCK^2 pixels) and the weight w_j = scale_j N^2 L^_i (RGB);
a block's pixels sum q_j w_j over its entries, in the kernel ``frame_product``
(kernels/relight.cl, eight pixels per work-item) or its numpy twin :func:`product_reference`.
"""
from __future__ import annotations

import numpy as np

from .. import cl


def gather(column_start: np.ndarray, entry_block: np.ndarray, entry_scale: np.ndarray, columns: np.ndarray,
           values: np.ndarray, n_blocks: int):
    """The entries of the selected ``columns`` (K,) with lighting ``values`` (K, 3) (already
    times N^2), grouped by block: (entry ids (E,) int64, weights (E, 4) float32 (RGB and a pad),
    block_start (n_blocks + 1,) uint32)."""
    columns = np.asarray(columns, np.int64)
    starts, ends = column_start[columns], column_start[columns + 1]
    counts = (ends - starts).astype(np.int64)
    total = int(counts.sum())
    term = np.repeat(np.arange(len(columns)), counts)
    # entry ids: each column's run starts .. ends - 1, concatenated
    run_start = np.repeat(starts - np.concatenate([[0], np.cumsum(counts)[:-1]]), counts)
    ids = run_start + np.arange(total)
    blocks = np.asarray(entry_block[ids], np.int64)
    order = np.argsort(blocks, kind="stable")
    ids, term, blocks = ids[order], term[order], blocks[order]
    weights = np.zeros((total, 4), np.float32)
    weights[:, :3] = np.asarray(entry_scale[ids], np.float64)[:, None] * np.asarray(values, np.float64)[term]
    block_start = np.zeros(n_blocks + 1, np.uint32)
    np.cumsum(np.bincount(blocks, minlength=n_blocks), out=block_start[1:])
    return ids, weights, block_start


def product_reference(entry_data: np.ndarray, ids: np.ndarray, weights: np.ndarray, block_start: np.ndarray):
    """numpy twin of ``frame_product``: (n_blocks, BLOCK^2, 3) float64 sums of q w per block."""
    n_blocks = len(block_start) - 1
    pixels = entry_data.shape[1]
    out = np.zeros((n_blocks, pixels, 3))
    if len(ids) == 0:
        return out
    block_of = np.repeat(np.arange(n_blocks), np.diff(block_start.astype(np.int64)))
    step = max(1, (1 << 22) // pixels)
    for i in range(0, len(ids), step):   # chunks of entries, for bounded memory
        q = np.asarray(entry_data[ids[i:i + step]], np.float64)
        contrib = q[:, :, None] * weights[i:i + step, None, :3].astype(np.float64)
        np.add.at(out, block_of[i:i + step], contrib)
    return out


class DeviceEntries:
    """The bake file's quantized entries as one read-only device buffer over its memory map (no
    copy on a CPU device where OpenCL can use the host memory), reused by every frame."""

    def __init__(self, entry_data: np.ndarray):
        pyopencl = cl._cl()
        self.pixels = int(entry_data.shape[1])
        self.bits = 8 * entry_data.dtype.itemsize
        flat = np.asarray(entry_data).reshape(-1)
        if flat.size == 0:
            flat = np.zeros(64, entry_data.dtype)
        mf = pyopencl.mem_flags
        try:
            self.buffer = pyopencl.Buffer(cl.runtime().context, mf.READ_ONLY | mf.USE_HOST_PTR, hostbuf=flat)
        except (pyopencl.Error, TypeError, ValueError, BufferError):   # read-only maps: a copy
            self.buffer = cl.to_device(np.ascontiguousarray(flat))
        self._keep = flat

    def product(self, ids, weights, block_start, queue=None) -> np.ndarray:
        """(n_blocks, BLOCK^2, 3) float32: the kernel ``frame_product``."""
        n_blocks = len(block_start) - 1
        queue = queue or cl.thread_queue()
        out = cl.empty(4 * 3 * n_blocks * self.pixels)
        if len(ids):
            prog = cl.program("relight.cl", QBITS=self.bits)
            per = self.pixels // 8
            cl.kernel(prog, "frame_product")(
                queue, (cl.items(n_blocks * per),), (cl.WORK_GROUP,), np.uint32(n_blocks), np.uint32(self.pixels),
                cl.to_device(np.asarray(block_start, np.uint32)), cl.to_device(np.asarray(ids, np.uint32)),
                cl.to_device(np.ascontiguousarray(weights, np.float32)), self.buffer, out)
            planes = cl.read(out, (3, n_blocks, self.pixels), np.float32, queue)
            return np.moveaxis(planes, 0, -1)
        return np.zeros((n_blocks, self.pixels, 3), np.float32)


def background_reference(environment, rotate_y: float, mask: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """numpy twin of ``frame_background``: (M, 3) float64, (1 / S) sum over the missing samples of
    the map turned to ``rotate_y`` (nearest texel) in their directions."""
    from ..envmap import rotation_y

    m, samples = len(mask), dirs.shape[1]
    turned = np.asarray(dirs, np.float64).reshape(-1, 3) @ rotation_y(rotate_y)   # d_map = R^T d
    radiance = environment.eval(turned).reshape(m, samples, 3).astype(np.float64)
    missing = ((np.asarray(mask, np.uint64)[:, None] >> np.arange(samples, dtype=np.uint64)) & np.uint64(1)) > 0
    return (radiance * missing[..., None]).sum(1) / samples


def background_cl(env_buffer, env_shape, rotate_y: float, mask_buffer, dirs_buffer, count: int, samples: int,
                  queue=None) -> np.ndarray:
    """The kernel ``frame_background`` on device buffers: (M, 3) float32."""
    from ..envmap import rotation_y

    queue = queue or cl.thread_queue()
    out = cl.empty(12 * max(count, 1))
    if count:
        prog = cl.program("relight.cl")
        m = cl.to_device(np.ascontiguousarray(rotation_y(rotate_y).T, np.float32))   # map_from_world
        cl.kernel(prog, "frame_background")(queue, (cl.items(count),), (cl.WORK_GROUP,), np.uint32(count),
                                            np.uint32(samples), np.int32(env_shape[1]), np.int32(env_shape[0]),
                                            m, mask_buffer, dirs_buffer, env_buffer, out)
        return cl.read(out, (count, 3), np.float32, queue)
    return np.zeros((0, 3), np.float32)
