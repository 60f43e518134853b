"""Scaling-coefficient pyramids and product scaling coefficients (Chen & Gao sec. 4.3-4.4,
eq. 17-25), on the host and batched on the device (``ProductPyramids``, kernels/haar.cl).
"""
from __future__ import annotations

import numpy as np

from .. import cl
from ..errors import ArgumentError, check_int, check_integers
from .products import dense_common
from .sparse import SparseHaar, node_averages, channels_of, common_nodes, Keyed, node_of
from .transform import (
    MAX_LEVELS,
    broadcast_sets,
    details,
    as_float,
    scaling_levels,
    checked_square,
    coeff_basis,
    coeff_index,
    node_scale,
)
from .tree import host_order, level_offset, morton_index, tree_size


# ============================================================================= scaling coefficients (sec. 4.3-4.4)
def scaling_pyramid(coeffs, levels: int | None = None) -> np.ndarray:
    """Box-mass pyramid (..., tree_size(L)) of a coefficient set, levels 0..L (default n),
    in the layout of haar/tree.py: node value 2^-l F^0_{l,t} (eq. 17). Only coefficients
    of levels < L are read; a SparseHaar gives (tree_size(L),) or (C, tree_size(L))."""
    where = "haar.scaling_pyramid"
    if isinstance(coeffs, SparseHaar):
        n = coeffs.n_levels
        L = n if levels is None else check_int(where, "levels", levels, 0, n)
        keep = coeff_basis(coeffs.index, n)
        sel = (keep[3] == 0) | (keep[0] < L)
        sub = SparseHaar(L, coeff_index(keep[0][sel], keep[1][sel], keep[2][sel], keep[3][sel], L),
                         coeffs.value[sel])
        return scaling_pyramid(sub.to_dense())
    c, n = checked_square(coeffs, where, "coeffs")
    L = n if levels is None else check_int(where, "levels", levels, 0, n)
    out = np.empty(c.shape[:-2] + (tree_size(L),), c.dtype)
    for l, s in scaling_levels(c[..., :1 << L, :1 << L], L):
        out[..., level_offset(l):level_offset(l + 1)] = s.reshape(s.shape[:-2] + (-1,)) * 2.0 ** -l
    return out


def _reduce4(a: np.ndarray) -> np.ndarray:
    return (a[..., 0::2, 0::2] + a[..., 0::2, 1::2]) + (a[..., 1::2, 0::2] + a[..., 1::2, 1::2])


def product_scaling(G, H, levels: int | None = None) -> np.ndarray:
    """Box-mass pyramid (..., tree_size(L)) of the product F = G H by eq. 25:
    2^-l F^0_{l,t} = G^0_{l,t} H^0_{l,t} + sum_{l' >= l, t' in t, m} G^m_{l',t'} H^m_{l',t'}.

    G, H: dense (..., 2^n, 2^n) coefficients (resolutions may differ; leading axes broadcast)
    or SparseHaar (values (K, C) give a leading channel axis). L defaults to the finer n.
    Sparse pairs cost O(4^L + K): only their common wavelets enter the sum.
    """
    where = "haar.product_scaling"
    sparse = isinstance(G, SparseHaar) and isinstance(H, SparseHaar)
    G, H = (s if isinstance(s, SparseHaar) else checked_square(s, where, k)[0] for k, s in (("G", G), ("H", H)))
    n = max(s.n_levels if isinstance(s, SparseHaar) else s.shape[-1].bit_length() - 1 for s in (G, H))
    L = n if levels is None else check_int(where, "levels", levels, 0, n)
    if sparse:
        channels_of(where, G, H)
        # scaling pyramids from the coefficients of levels < L; D from the common wavelets
        pg, ph = (_pad_pyramid(scaling_pyramid(s, min(L, s.n_levels)), min(L, s.n_levels), L)
                  for s in (G, H))
        keys, a, b = common_nodes(Keyed(G, n), Keyed(H, n))
        prod = (a * b).T  # (C, Kc)
        lv, x, y = node_of((keys - 1) // 3)
        d = np.maximum(lv - L, 0)
        lv, x, y = np.minimum(lv, L), x >> d, y >> d  # finer than L: fold into the level-L ancestor
        D = np.zeros((prod.shape[0], tree_size(L)))
        if len(keys):
            np.add.at(D, (slice(None), (np.left_shift(1, 2 * lv) - 1) // 3 + (y << lv) + x), prod)
        for l in range(L - 1, -1, -1):
            s = 1 << l
            child = D[:, level_offset(l + 1):level_offset(l + 2)].reshape(-1, 2 * s, 2 * s)
            D[:, level_offset(l):level_offset(l + 1)] += _reduce4(child).reshape(-1, s * s)
        out = pg * ph * node_scale(L) ** 2 + D  # G^0 H^0 + D (F^0 = 2^l mass)
        return out if any(s.value.ndim == 2 for s in (G, H)) else out[0]
    g, h = dense_common(where, G=G, H=H)
    shape = np.broadcast_shapes(g.shape[:-2], h.shape[:-2])
    out = np.empty(shape + (tree_size(L),), np.result_type(g, h))
    # D_{l,t}: own wavelet products plus the children's D, bottom up from level n - 1
    D = np.zeros(shape + (1 << n, 1 << n), out.dtype)
    for l in range(n - 1, -1, -1):
        own = sum(a * b for a, b in zip(details(g, l), details(h, l)))
        D = own + _reduce4(D)
        if l <= L:
            out[..., level_offset(l):level_offset(l + 1)] = D.reshape(shape + (-1,))
    if L == n:
        out[..., level_offset(n):] = 0.0
    for (l, sg), (_, sh) in zip(scaling_levels(g, L), scaling_levels(h, L)):
        out[..., level_offset(l):level_offset(l + 1)] += (sg * sh).reshape(shape + (-1,))
    return out


def _pad_pyramid(p: np.ndarray, k: int, L: int) -> np.ndarray:
    """A mass pyramid of levels 0..k as (C, tree_size(L)), L >= k: below level k the
    function is constant on each level-k square, so a child holds a quarter of its parent."""
    p = p.reshape(-1, tree_size(k))
    out = np.empty((p.shape[0], tree_size(L)))
    out[:, :tree_size(k)] = p
    leaf = p[:, level_offset(k):].reshape(-1, 1 << k, 1 << k)
    for l in range(k + 1, L + 1):
        r = 1 << (l - k)
        out[:, level_offset(l):level_offset(l + 1)] = (
            np.repeat(np.repeat(leaf, r, -1), r, -2).reshape(len(p), -1) / (r * r))
    return out


def _sparse_of(where: str, name: str, s) -> SparseHaar:
    """A SparseHaar as is; dense (2^n, 2^n) or (C, 2^n, 2^n) coefficients as their non-zeros."""
    if isinstance(s, SparseHaar):
        return s
    c, _ = checked_square(s, where, name)
    if c.ndim > 3:
        raise ArgumentError(f"{where}: {name} must be one set, (2^n, 2^n) or (C, 2^n, 2^n), got shape {c.shape}")
    return SparseHaar.from_dense(c)


def product_scaling_at(G, H, level, x, y) -> np.ndarray:
    """Eq. 25 at single nodes (level, x, y) (arrays, Q), from sparse coefficient lists: box
    masses (Q,) or (C, Q) of G H without building the pyramid, O(K log K + Q n log K) (the
    common wavelets' prefix sums in Morton order are searched once per level).
    G, H: SparseHaar or dense (2^n, 2^n) / (C, 2^n, 2^n) coefficients; levels 0..max n."""
    where = "haar.product_scaling_at"
    G, H = (_sparse_of(where, k, s) for k, s in (("G", G), ("H", H)))
    channels_of(where, G, H)
    level, x, y = broadcast_sets(where, {k: check_integers(where, k, a).reshape(-1)
                                     for k, a in (("level", level), ("x", x), ("y", y))})
    n = max(G.n_levels, H.n_levels)
    if np.any((level < 0) | (level > n)):
        raise ArgumentError(f"{where}: level must be in [0, {n}], got {level[(level < 0) | (level > n)][0]}")
    side = np.left_shift(1, level)
    if np.any((x < 0) | (y < 0) | (x >= side) | (y >= side)):
        raise ArgumentError(f"{where}: x and y must be in [0, 2^level)")
    g, h = Keyed(G, n), Keyed(H, n)
    nid = (np.left_shift(1, 2 * level) - 1) // 3 + (y << level) + x
    out = node_averages(g, nid) * node_averages(h, nid) * np.ldexp(1.0, -2 * level)[:, None]
    keys, a, b = common_nodes(g, h)
    if len(keys):
        prod = a * b
        lv, px, py = node_of((keys - 1) // 3)
        z = morton_index(px, py)
        zq = morton_index(x, y)
        for lp in np.unique(lv):
            sel = lv == lp
            order = np.argsort(z[sel], kind="stable")
            zs = z[sel][order]
            cum = np.concatenate([np.zeros((1, prod.shape[1])), np.cumsum(prod[sel][order], axis=0)])
            # the level-lp nodes inside (level, x, y) are one Morton range
            d = (2 * np.maximum(lp - level, 0)).astype(np.uint64)
            lo = np.searchsorted(zs, zq << d)
            hi = np.searchsorted(zs, (zq + np.uint64(1)) << d)
            out += np.where((lp >= level)[:, None], cum[hi] - cum[lo], 0.0)
    out = out.T
    return out if any(s.value.ndim == 2 for s in (G, H)) else out[0]



class ProductPyramids:
    """Eq. 25 on the device for one shared G (the environment) and batches of H.

    ``ProductPyramids(G, h_levels, levels=None)``: G dense (2^n, 2^n) coefficients or a
    SparseHaar; each H is a dense (2^m, 2^m) coefficient set, m = ``h_levels``. Output trees
    have levels 0..L (default m), ``stride = tree_size(L)`` floats apart. The kernel works at
    leaf level P = max(L, m) <= max(n, m), one work-group per tree holding 2 4^P floats of
    local memory (P <= 8 on PoCL CPU devices):
    H's scaling coefficients top-down to level m, leaf masses G^0 H^0 at level P, then
    parent = sum of children (equal to eq. 25, additive in float32).
    ``nonnegative=True`` clamps negative leaf masses (ringing of compressed inputs) to 0.
    """

    def __init__(self, G, h_levels: int, levels: int | None = None, nonnegative: bool = False,
                 work_group: int = 16):
        where = "haar.ProductPyramids"
        if isinstance(G, SparseHaar):
            n, channels = G.n_levels, G.value.ndim - 1
        else:
            G, n = checked_square(G, where, "G")
            channels = G.ndim - 2
        if channels:
            raise ArgumentError(f"{where}: G must be one single-channel coefficient set, (2^n, 2^n) or "
                                f"a SparseHaar with values (K,)")
        self.h_levels = m = check_int(where, "h_levels", h_levels, 0, MAX_LEVELS)
        self.levels = L = m if levels is None else check_int(where, "levels", levels, 0, max(n, m))
        self.leaf_level = P = max(L, m)
        device = cl.runtime().device
        if 8 * 4 ** P > device.local_mem_size:
            raise ArgumentError(f"{where}: product trees of leaf level {P} do not fit the device's local memory "
                                f"({device.local_mem_size} bytes)")
        work_group = check_int(where, "work_group", work_group, 1, device.max_work_group_size)
        k = min(P, n)
        masses = scaling_pyramid(G, k)
        leaf = _pad_pyramid(masses, k, P)[0, level_offset(P):]  # G's masses at level P
        self.stride = tree_size(L)
        self.nonnegative = bool(nonnegative)
        self.work_group = int(min(work_group, 4 ** P))
        self._g = cl.to_device(leaf.astype(np.float32))
        self._prog = cl.program("haar.cl")

    def enqueue(self, queue, h_buf, n_trees: int, out_buf, stride: int | None = None, origin: int = 0):
        """Launch on device buffers: h_buf (T, 2^m, 2^m) float32 -> out_buf, tree t's node 0 at
        float ``origin + t stride`` (default stride: tree_size(L), origin 0), the trees in the
        device's Morton order, the walks' level order (haar/tree.py layout; with
        ``stride = tree_stride(L)`` and ``origin = TREE_ORIGIN`` a HaarTree's buffer)."""
        import pyopencl  # deferred like in cl.py
        nbytes = 4 * 4 ** self.leaf_level
        knl = cl.kernel(self._prog, "haar_product_tree")
        return knl(queue, (self.work_group, n_trees), (self.work_group, 1), self._g, h_buf,
                   np.int32(self.h_levels), np.int32(self.leaf_level), np.int32(self.levels),
                   out_buf, np.uint64(self.stride if stride is None else stride), np.uint64(origin),
                   np.int32(self.nonnegative), pyopencl.LocalMemory(nbytes), pyopencl.LocalMemory(nbytes))

    def trees(self, H, queue=None):
        """The pyramids of H (T, 2^m, 2^m) as a :class:`wavlight.haar.HaarTree` that stays on the
        device (no copy to the host and back; its ``integral`` read from the roots alone)."""
        from .tree import TREE_ORIGIN, HaarTree, tree_stride

        h = np.ascontiguousarray(as_float(H, "haar.ProductPyramids.trees", "H"), np.float32)
        side = 1 << self.h_levels
        if h.ndim != 3 or h.shape[1:] != (side, side) or len(h) == 0:
            raise ArgumentError(f"haar.ProductPyramids.trees: H must be (T, {side}, {side}) with T >= 1, "
                                f"got shape {h.shape}")
        queue = queue or cl.thread_queue()
        stride = tree_stride(self.levels)
        out = cl.empty(4 * len(h) * stride)
        self.enqueue(queue, cl.to_device(h), len(h), out, stride, TREE_ORIGIN)
        roots = np.empty(len(h), np.float32)
        cl.opencl().enqueue_copy(queue, roots, out, buffer_origin=(4 * TREE_ORIGIN, 0), host_origin=(0, 0),
                              region=(4, len(h)), buffer_pitches=(4 * stride,), host_pitches=(4,))
        return HaarTree.on_device(out, self.levels, len(h), roots)

    def __call__(self, H, queue=None) -> np.ndarray:
        """Pyramids (T, stride) float32 for H (T, 2^m, 2^m) or (2^m, 2^m) dense coefficients,
        row-major (the host's layout)."""
        h = np.ascontiguousarray(as_float(H, "haar.ProductPyramids", "H"), np.float32)
        h = h[None] if h.ndim == 2 else h
        side = 1 << self.h_levels
        if h.ndim != 3 or h.shape[1:] != (side, side):
            raise ArgumentError(f"haar.ProductPyramids: H must be (T, {side}, {side}) or ({side}, {side}), "
                                f"got shape {h.shape}")
        queue = queue or cl.thread_queue()
        out = cl.empty(4 * len(h) * self.stride)
        if len(h):
            self.enqueue(queue, cl.to_device(h), len(h), out)
        return host_order(cl.read(out, (len(h), self.stride), np.float32, queue), self.levels)
