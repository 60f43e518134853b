"""Sampling trees on the unit square: build, warp, pdf (Chen & Gao sec. 4.3, eq. 17-22).

A :class:`HaarTree` holds the scaling-coefficient pyramid of one or more
non-negative 2^n x 2^n images, stored as box masses (node value = integral of the
image over the node's square, ``2^-l F^0_{l,t}``, eq. 17). Warping and pdf
evaluation run in the OpenCL kernels of ``kernels/tree.cl`` and ``kernels/warp.cl``;
the ``*_reference`` functions here are their plain numpy twins, used by the tests.

Batched trees (one per shading point, e.g. the eq. 25 product pyramids of
:mod:`wavlight.haar`) use the same kernels: sample ``i`` uses tree
``i // samples_per_tree``. The wavelet strategy itself needs no per-point tree: its
top-down product walk (``kernels/product.h``) shares the walk's child choice.

Image orientation: ``image[y, x]``; a point ``(u, v)`` of the square lies in
column ``floor(u 2^n)``, row ``floor(v 2^n)``.

Layout: on the host a pyramid's level l is row-major, node (x, y) at
``level_offset(l) + y 2^l + x``. On the device (``HaarTree.buffer``, the product trees
of :class:`wavlight.haar.ProductPyramids`) each level is in Morton order, so that a
walk step reads a node's four children from one cache line (kernels/common.h);
:func:`device_order` and :func:`host_order` convert, ``HaarTree`` and ``nodes()`` do
it for their callers. In ``HaarTree.buffer`` tree t's node i is float
``t tree_stride(n) + TREE_ORIGIN + i`` (every level from 2 on cache-line aligned).
"""
from __future__ import annotations

import numbers

import numpy as np

from .. import cl
from ..errors import ArgumentError, check_int, check_real, shown

ONE_MINUS_EPS = np.float32(np.nextafter(np.float32(1), np.float32(0)))


def level_offset(level: int) -> int:
    """Index of the first node of ``level`` in a pyramid (see kernels/common.h)."""
    return (4 ** level - 1) // 3


#: A light tree's node 0 lies TREE_ORIGIN floats into its place in ``HaarTree.buffer``, and
#: trees lie ``tree_stride(n)`` floats apart, so that every level from 2 on starts on a
#: 64-byte cache line on the device (kernels/common.h, which measures it)
TREE_ORIGIN = 11


def tree_stride(n_levels: int) -> int:
    """Floats from one tree to the next in ``HaarTree.buffer`` (a multiple of 16; TREE_STRIDE)."""
    return (tree_size(n_levels) + TREE_ORIGIN + 15) & ~15


def tree_size(n_levels: int) -> int:
    """Number of nodes in a pyramid whose leaves are at level ``n_levels``."""
    return level_offset(n_levels + 1)


def morton_index(x, y) -> np.ndarray:
    """Index of node (x, y) within its level on the device: the bits of x at the even
    positions, those of y at the odd ones (kernels/common.h morton_index), for
    coordinates below 2^32, as uint64."""
    def spread(v):
        v = np.asarray(v, np.uint64) & np.uint64(0xFFFFFFFF)
        for s, mk in ((16, 0x0000FFFF0000FFFF), (8, 0x00FF00FF00FF00FF), (4, 0x0F0F0F0F0F0F0F0F),
                      (2, 0x3333333333333333), (1, 0x5555555555555555)):
            v = (v | (v << np.uint64(s))) & np.uint64(mk)
        return v
    return spread(x) | (spread(y) << np.uint64(1))


def _level_axes(l: int) -> list[int]:
    """Axes of a level's (2,) * 2l view (y's bits, then x's, most significant first) in Morton
    order: y_{l-1} x_{l-1} .. y_0 x_0, so that flattening gives morton_index(x, y)."""
    return [a for b in range(l) for a in (b, l + b)]


def _reorder(nodes: np.ndarray, n_levels: int, to_device: bool) -> np.ndarray:
    """nodes (..., tree_size(n)) in the other layout: one gather, its index built per call by
    transposing each level's (2,) * 2l view of arange (no table kept between calls)."""
    nodes = np.asarray(nodes)
    if nodes.shape[-1] != tree_size(n_levels):
        raise ArgumentError(f"haar.tree.{'device' if to_device else 'host'}_order: pyramids of {n_levels} "
                            f"levels have {tree_size(n_levels)} nodes, got shape {nodes.shape}")
    index = np.empty(tree_size(n_levels), np.int64)
    for l in range(n_levels + 1):
        axes = _level_axes(l)
        source = np.arange(4 ** l).reshape((2,) * (2 * l)).transpose(axes if to_device else np.argsort(axes))
        index[level_offset(l):level_offset(l + 1)] = level_offset(l) + source.ravel()
    return np.take(nodes, index, axis=-1)


def device_order(nodes: np.ndarray, n_levels: int) -> np.ndarray:
    """Host pyramids (..., tree_size(n)) (row-major levels) in the device's Morton order."""
    return _reorder(nodes, n_levels, True)


def host_order(nodes: np.ndarray, n_levels: int) -> np.ndarray:
    """Device pyramids (..., tree_size(n)) (Morton levels) in the host's row-major order."""
    return _reorder(nodes, n_levels, False)


def leaf_levels(side: int) -> int:
    """n for a 2^n x 2^n image; raises ArgumentError (a ValueError) for other sides."""
    if (isinstance(side, (bool, np.bool_)) or not isinstance(side, numbers.Integral) or side < 1
            or side & (side - 1)):
        raise ArgumentError(f"haar.tree.leaf_levels: tree images must be 2^n x 2^n, got side {shown(side)}")
    return int(side).bit_length() - 1


def _leaves(where: str, leaves) -> np.ndarray:
    """leaves as float32 (T, 2^n, 2^n), finite and non-negative, else ArgumentError."""
    a = np.asarray(check_real(where, "leaves", leaves), np.float32)
    a = a[None] if a.ndim == 2 else a
    side = a.shape[-1] if a.ndim == 3 else 0
    if a.ndim != 3 or a.shape[1] != side or side < 1 or side & (side - 1):
        raise ArgumentError(f"{where}: leaves must be (T, 2^n, 2^n) or (2^n, 2^n), got shape {np.shape(leaves)}")
    if not np.all(np.isfinite(a)) or np.any(a < 0):
        raise ArgumentError(f"{where}: tree leaves must be finite and non-negative")
    return a


def _walk_args(where: str, tree, n_levels, points, name: str, samples_per_tree):
    """Checked arguments of the numpy twins: tree (T, tree_size(n)) float32, n, points (N, 2), and
    samples_per_tree, which must give every point a tree."""
    n_levels = check_int(where, "n_levels", n_levels, 0, 30)
    tree = check_real(where, "tree", tree)
    size = tree_size(n_levels)
    if tree.size == 0 or tree.size % size:
        raise ArgumentError(f"{where}: tree must hold whole pyramids of tree_size({n_levels}) = {size} nodes, "
                            f"got shape {tree.shape}")
    points = check_real(where, name, points)
    if points.ndim != 2 or points.shape[1] != 2:
        raise ArgumentError(f"{where}: {name} must be (N, 2), got shape {points.shape}")
    n, trees = len(points), tree.size // size
    samples_per_tree = check_int(where, "samples_per_tree", samples_per_tree, 1 if n else 0)
    if n and -(-n // samples_per_tree) > trees:
        raise ArgumentError(f"{where}: {n} points at {samples_per_tree} per tree need "
                            f"{-(-n // samples_per_tree)} trees, tree holds {trees}")
    return np.asarray(tree, np.float32).reshape(trees, size), n_levels, points, samples_per_tree


# ----------------------------------------------------------------------------- numpy reference
def build_reference(leaves: np.ndarray) -> np.ndarray:
    """Pyramids of box masses from leaf masses.

    leaves : (T, 2^n, 2^n) or (2^n, 2^n) float, non-negative
    returns : (T, tree_size(n)) float32
    """
    leaves = _leaves("haar.tree.build_reference", leaves)
    n = leaf_levels(leaves.shape[-1])
    out = np.empty((leaves.shape[0], tree_size(n)), np.float32)
    level = leaves
    for l in range(n, -1, -1):
        out[:, level_offset(l):level_offset(l + 1)] = level.reshape(len(level), -1)
        if l:
            level = (level[:, 0::2, 0::2] + level[:, 0::2, 1::2]) + (level[:, 1::2, 0::2] + level[:, 1::2, 1::2])
    return out


def leaf_point(leaf: np.ndarray, u: np.ndarray, n_levels: int) -> np.ndarray:
    """The point at offset u (N, 2) inside leaves (N, 2) of a 2^n grid, float32 (kernels/warp.h).

    u is clamped to 1 - 2^(n - 23) first, so that leaf + u rounds below leaf + 1 in float32:
    the point stays inside its leaf.
    """
    top = np.float32(1.0 - 2.0 ** (n_levels - 23))
    return ((leaf.astype(np.float32) + np.minimum(np.asarray(u, np.float32), top))
            * np.float32(1.0 / (1 << n_levels))).astype(np.float32)


def choose_child_reference(m00, m10, m01, m11, u: np.ndarray):
    """One step of the walk for N samples (numpy twin of kernels/warp.h choose_child).

    m.. : (N,) the four children's masses (00 10 01 11); u : (N, 2), rescaled in place in
    its own dtype (float32 here is bitwise the kernel). Compares u * sum with a mass (no
    division), never picks a side of zero mass. Returns (go_top, go_left) boolean arrays.
    """
    top, bottom = m00 + m10, m01 + m11
    s_row = top + bottom
    go_top = (u[:, 1] * s_row < top) | ~(bottom > 0)
    row = np.where(go_top, top, bottom)
    u[:, 1] = np.fmin((u[:, 1] * s_row - np.where(go_top, 0, top)) / row, ONE_MINUS_EPS)
    left, right = np.where(go_top, m00, m01), np.where(go_top, m10, m11)
    s_col = left + right
    go_left = (u[:, 0] * s_col < left) | (right == 0)
    col = np.where(go_left, left, right)
    u[:, 0] = np.fmin((u[:, 0] * s_col - np.where(go_left, 0, left)) / col, ONE_MINUS_EPS)
    return go_top, go_left


def sample_reference(tree: np.ndarray, n_levels: int, u: np.ndarray, samples_per_tree: int):
    """Top-down warp of uniform points (numpy twin of ``warp_sample``).

    tree : (T, tree_size(n)) float32;  u : (N, 2) float in [0, 1)
    returns : uv (N, 2) float32 in [0, 1), pdf (N,) float32 on the unit square
    """
    tree, n_levels, u, samples_per_tree = _walk_args("haar.tree.sample_reference", tree, n_levels, u, "u",
                                                     samples_per_tree)
    u = np.clip(np.nan_to_num(np.asarray(u, np.float32), nan=0.0), 0, ONE_MINUS_EPS)  # as clamp_unit
    t = np.arange(len(u)) // samples_per_tree
    x = np.zeros(len(u), np.int64)
    y = np.zeros(len(u), np.int64)
    with np.errstate(divide="ignore", invalid="ignore"):
        for l in range(n_levels):
            cside = 2 << l
            c = level_offset(l + 1) + (2 * y) * cside + 2 * x
            m00, m10 = tree[t, c], tree[t, c + 1]
            m01, m11 = tree[t, c + cside], tree[t, c + cside + 1]
            go_top, go_left = choose_child_reference(m00, m10, m01, m11, u)
            y = 2 * y + (~go_top)
            x = 2 * x + (~go_left)
    u = np.nan_to_num(u, nan=0.0)
    uv = leaf_point(np.stack([x, y], 1), u, n_levels)
    return uv, pdf_reference(tree, n_levels, uv, samples_per_tree)


def pdf_reference(tree: np.ndarray, n_levels: int, uv: np.ndarray, samples_per_tree: int) -> np.ndarray:
    """Density on the unit square of given points (numpy twin of ``warp_pdf``)."""
    tree, n_levels, uv, samples_per_tree = _walk_args("haar.tree.pdf_reference", tree, n_levels, uv, "uv",
                                                      samples_per_tree)
    side = 1 << n_levels
    t = np.arange(len(uv)) // samples_per_tree
    ix = np.clip(np.floor(uv[:, 0] * side).astype(np.int64), 0, side - 1)
    iy = np.clip(np.floor(uv[:, 1] * side).astype(np.int64), 0, side - 1)
    root = tree[t, 0]
    leaf = tree[t, level_offset(n_levels) + iy * side + ix]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(root > 0, leaf / root * np.float32(side * side), 0).astype(np.float32)


# ----------------------------------------------------------------------------- OpenCL
class HaarTree:
    """Scaling-coefficient pyramids of T images of side 2^n, resident on the OpenCL device.

    ``HaarTree(leaves)`` with ``leaves`` (T, 2^n, 2^n) or (2^n, 2^n) non-negative masses.
    ``integral`` is each image's total mass (the root, eq. 18).
    """

    def __init__(self, leaves: np.ndarray):
        leaves = _leaves("haar.tree.HaarTree", leaves)
        if not len(leaves):
            raise ArgumentError("haar.tree.HaarTree: leaves must hold at least one image, got shape "
                                f"{leaves.shape}")
        self.n_levels = leaf_levels(leaves.shape[-1])
        self.n_trees = leaves.shape[0]
        self.stride = tree_stride(self.n_levels)
        rt = cl.runtime()
        self.buffer = cl.empty(4 * self.n_trees * self.stride)
        prog = cl.program("tree.cl")
        # the leaves into level n in Morton order on the device, then the levels above them
        leaf_buf = cl.to_device(leaves)   # (kept until the blocking read below)
        cl.kernel(prog, "tree_load_leaves")(rt.queue, (4 ** self.n_levels, self.n_trees), None, self.buffer,
                                            np.uint64(self.stride), leaf_buf, np.int32(self.n_levels))
        knl = cl.kernel(prog, "tree_reduce")
        for level in range(self.n_levels - 1, -1, -1):
            knl(rt.queue, (4 ** level, self.n_trees), None, self.buffer,
                np.uint64(self.stride), np.int32(level))
        self.integral = self.device_nodes()[:, 0].copy()

    @classmethod
    def from_pyramids(cls, pyramids: np.ndarray) -> "HaarTree":
        """Trees from whole pyramids (T, tree_size(n)) float32 of non-negative masses in the host's
        row-major level order, parent = sum of its children (as :class:`wavlight.haar.ProductPyramids`
        gives them): uploaded in the device's layout, without building them again."""
        where = "haar.tree.HaarTree.from_pyramids"
        nodes = np.asarray(check_real(where, "pyramids", pyramids), np.float32)
        if nodes.ndim != 2 or nodes.shape[0] < 1:
            raise ArgumentError(f"{where}: pyramids must be (T, tree_size(n)) with T >= 1, got shape {nodes.shape}")
        n = next((k for k in range(32) if tree_size(k) >= nodes.shape[1]), None)
        if n is None or tree_size(n) != nodes.shape[1]:
            raise ArgumentError(f"{where}: a pyramid has tree_size(n) nodes, got {nodes.shape[1]}")
        if not np.all(np.isfinite(nodes)) or nodes.min(initial=0.0) < 0:
            raise ArgumentError(f"{where}: pyramids must be finite and non-negative")
        self = cls.__new__(cls)
        self.n_levels, self.n_trees, self.stride = n, nodes.shape[0], tree_stride(n)
        padded = np.zeros((self.n_trees, self.stride), np.float32)
        padded[:, TREE_ORIGIN:TREE_ORIGIN + tree_size(n)] = device_order(nodes, n)
        self.buffer = cl.to_device(padded)
        self.integral = nodes[:, 0].copy()
        return self

    @classmethod
    def on_device(cls, buffer, n_levels: int, n_trees: int, integral: np.ndarray) -> "HaarTree":
        """Trees already in a device buffer in this class's layout (tree_stride(n) floats apart,
        node 0 at TREE_ORIGIN, Morton levels), as :meth:`wavlight.haar.ProductPyramids.trees`
        makes them; ``integral`` (T,) their roots."""
        self = cls.__new__(cls)
        self.n_levels, self.n_trees, self.stride = int(n_levels), int(n_trees), tree_stride(int(n_levels))
        self.buffer, self.integral = buffer, np.asarray(integral, np.float32)
        return self

    def device_nodes(self) -> np.ndarray:
        """(T, tree_size(n)) float32: the trees as the device holds them (Morton order), copied."""
        raw = cl.read(self.buffer, (self.n_trees, self.stride), np.float32)
        return raw[:, TREE_ORIGIN:TREE_ORIGIN + tree_size(self.n_levels)]

    def nodes(self) -> np.ndarray:
        """The whole pyramid, (T, tree_size(n)) float32, copied to the host (row-major levels)."""
        return host_order(self.device_nodes(), self.n_levels)

    def _run(self, name, pts, samples_per_tree, outputs):
        where, arg = ("haar.tree.HaarTree.sample", "u") if outputs == 2 else ("haar.tree.HaarTree.pdf", "uv")
        pts = np.ascontiguousarray(check_real(where, arg, pts), np.float32)
        if pts.ndim != 2 or pts.shape[1] != 2:
            raise ArgumentError(f"{where}: {arg} must be (N, 2), got shape {pts.shape}")
        n = len(pts)
        if samples_per_tree is None:
            samples_per_tree = max(1, -(-n // self.n_trees))
        samples_per_tree = check_int(where, "samples_per_tree", samples_per_tree, 1)
        if -(-n // samples_per_tree) > self.n_trees:  # sample i reads tree i // samples_per_tree
            raise ArgumentError(f"{where}: {n} points at {samples_per_tree} per tree need "
                                f"{-(-n // samples_per_tree)} trees, this HaarTree holds {self.n_trees}")
        if n == 0:
            return [np.empty((0, 2), np.float32), np.empty(0, np.float32)][-outputs:]
        queue = cl.thread_queue()  # callers may be threads
        src = cl.to_device(pts)
        uv = cl.empty(pts.nbytes) if outputs == 2 else None
        pdf = cl.empty(4 * n)
        args = [self.buffer, np.uint64(self.stride)]
        # built per depth (the walk unrolls); BATCHED: a tree per samples_per_tree samples
        prog = cl.program("warp.cl", N_LEVELS=self.n_levels, BATCHED=int(samples_per_tree < n))
        size = (cl.items(n, cl.LANES),), (cl.WALK_WORK_GROUP,)   # eight points per work-item (kernels/simd.h)
        if name == "warp_sample":
            cl.kernel(prog, name)(queue, *size, *args, np.uint32(samples_per_tree), np.uint32(n), src, np.uint32(2),
                                  uv, pdf)
        else:
            cl.kernel(prog, name)(queue, *size, *args, np.int32(self.n_levels), np.uint32(samples_per_tree),
                                  np.uint32(n), src, pdf)
        res = [cl.read(pdf, (n,), np.float32, queue)]
        if uv is not None:
            res.insert(0, np.ascontiguousarray(cl.read(uv, (2, n), np.float32, queue).T))  # u, v planes
        return res

    def sample(self, u: np.ndarray, samples_per_tree: int | None = None):
        """Warp uniform points: u (N, 2) -> uv (N, 2) in [0, 1)^2 and pdf (N,) on the square
        (u must be (N, 2): a flat (2N,) array is refused, no longer reshaped).

        Sample i uses tree ``i // samples_per_tree`` (default: N / T, all of one tree for T = 1).
        """
        uv, pdf = self._run("warp_sample", u, samples_per_tree, 2)
        return uv, pdf

    def pdf(self, uv: np.ndarray, samples_per_tree: int | None = None) -> np.ndarray:
        """Density on the unit square at points uv (N, 2), the one ``sample`` returns there."""
        return self._run("warp_pdf", uv, samples_per_tree, 1)[0]
