"""Nonstandard 2D Haar wavelets: transform, compression, tripling coefficients, products
(Chen & Gao sec. 4.1-4.4, eq. 13-25; Ng et al. 2003, 2004).

Conventions
-----------
*Images* are functions on the unit square, piecewise constant on a 2^n x 2^n grid,
stored ``image[y, x]`` (y the row; "top" means small y, "left" small x). Every
function here acts on the last two axes; all leading axes are a batch. A colour
image (2^n, 2^n, C) is transformed as ``forward(np.moveaxis(img, -1, 0))``: channels
come first, like any other batch axis.

*Basis* (orthonormal, eq. 13): the scaling function phi = 1 on the unit square and,
for each level 0 <= l < n and node t = (x, y) (0 <= x, y < 2^l, square
[x, x+1] 2^-l x [y, y+1] 2^-l), three wavelets of value +-2^l on that square:
m = 1 horizontal difference (+ on the left half, - on the right), m = 2 vertical
difference (+ top, - bottom), m = 3 diagonal (+ top-left and bottom-right).
Scaling coefficient of a node: F^0_{l,t} = integral of F * 2^l over its square
= 2^l * mass (eq. 17); the root F^0_{0,0} is the integral (eq. 18).

*Dense layout* (in place, Stollnitz et al.): coefficients of a 2^n x 2^n image are a
2^n x 2^n array ``c``; ``c[0, 0]`` is the scaling coefficient and the wavelets of
level l (s = 2^l) sit in three s x s blocks::

    m = 1: c[y, s + x]      m = 2: c[s + y, x]      m = 3: c[s + y, s + x]

A basis index is the flat position ``row * 2^n + col`` (``coeff_index`` /
``coeff_basis``). The top-left 2^k x 2^k block is the transform of the same image
at resolution 2^k, so sets of different resolutions compare by zero padding.

*Sparse* (:class:`SparseHaar`): sorted flat indices and values, (K,) or (K, C);
``to_dense`` gives (2^n, 2^n) or (C, 2^n, 2^n).

*Pyramids* are box masses in the layout of ``distributions.py``: node (l, x, y) at
``level_offset(l) + y 2^l + x`` holds 2^-l F^0_{l,t}; many pyramids stack on a
leading axis, ``tree_size(L)`` apart.

Algorithms
----------
*Triple product integral* (Ng et al. 2004, linear time). Of the three cases of the
tripling theorem (sec. 4.2), case 3 pairs two identical wavelets w at node (l, t)
with every coarser function that overlaps them; summed, those coarser functions are
the third image's average over the node's square, X(l,t) = 2^l X^0_{l,t}, the
running sum of its parents' scaling coefficients. Hence

    int G H K = G0 H0 K0 + sum over nodes (l, t) of
                [ sum_m (G^m H^m K(l,t) + G^m K^m H(l,t) + H^m K^m G(l,t))
                  + 2^l sum over permutations (a, b, c) of (1, 2, 3) of G^a H^b K^c ].

Dense: one top-down pass gives every average, O(4^n). Sparse: only nodes where two
sets share a wavelet contribute, and their averages come from one top-down pass over
the distinct nodes on their paths to the root (Ng et al.'s traversal; ``_averages``);
coefficients are found by key in O(1) through a table over the key space where the set
fills at least 1/64 of it (binary search, O(log K), for sparser sets), so the cost is
linear in the K kept coefficients plus those paths' distinct nodes (at most min(C n,
4^n / 3) for C shared wavelets; ``haar_bench.py``). The double product is a dot product.

*Product scaling coefficients* (eq. 23-25). On a node's square Q, G is its average
plus the wavelets inside Q; wavelets integrate to zero over Q and are orthonormal,
so with levels l' >= l (the node's own wavelets included)

    2^-l F^0_{l,t} = G^0_{l,t} H^0_{l,t} + D_{l,t},   D_{l,t} = sum_{l' >= l, t' in t, m} G^m H^m,

which is eq. 25 divided by 2^l, exactly the box sum of G H (tested). D is
accumulated bottom-up (D_{l,t} = own products + the children's D). Sparse inputs
only touch the common wavelets; ``product_scaling_at`` evaluates single nodes with
per-level prefix sums in Morton order, for nodes a sample visits.
On the device (``ProductPyramids``) the pyramid is built as leaf products reduced
bottom-up, which equals eq. 25 level by level and keeps parent = sum of children in
float32, as the warp in ``kernels/warp.h`` expects.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import cl
from .distributions import host_order, level_offset, morton_index, tree_size
from .errors import ArgumentError, check_int, check_integers, check_number, check_real

__all__ = [
    "coeff_index", "coeff_basis", "node_scale", "forward", "inverse", "scaling_pyramid",
    "SparseHaar", "compress_topk", "compress_energy", "tripling", "double_product_integral",
    "triple_product_integral", "product_scaling", "product_scaling_at", "forward_cl",
    "ProductPyramids",
]

MAX_LEVELS = 31  # flat indices 4^n - 1 fit int64


# ============================================================================= layout
def coeff_index(level, x, y, m, n_levels: int):
    """Flat dense index of basis function (level, x, y, m); m = 0 is the scaling function
    (level = x = y = 0). Vectorised."""
    where = "haar.coeff_index"
    n_levels = check_int(where, "n_levels", n_levels, 0, MAX_LEVELS)
    level, x, y, m = _broadcast(where, {k: check_integers(where, k, v) for k, v in
                                        (("level", level), ("x", x), ("y", y), ("m", m))})
    if np.any((m < 0) | (m > 3)):
        raise ArgumentError(f"{where}: m must be 0 (scaling) or 1, 2, 3 (wavelets), got {m[(m < 0) | (m > 3)][0]}")
    wav = m > 0
    if np.any(wav & ((level < 0) | (level >= n_levels))):
        raise ArgumentError(f"{where}: a wavelet's level must be in [0, {n_levels}), got "
                            f"{level[wav & ((level < 0) | (level >= n_levels))][0]}")
    side = np.left_shift(1, np.where(wav, level, 0))
    if np.any(wav & ((x < 0) | (y < 0) | (x >= side) | (y >= side))):
        raise ArgumentError(f"{where}: a wavelet's x and y must be in [0, 2^level)")
    s = np.left_shift(1, level)
    row = np.where((m == 2) | (m == 3), s + y, y)
    col = np.where((m == 1) | (m == 3), s + x, x)
    return np.where(m == 0, 0, row * (1 << n_levels) + col)


def coeff_basis(index, n_levels: int):
    """(level, x, y, m) of flat dense indices; the scaling function is (0, 0, 0, 0). Vectorised."""
    n_levels = check_int("haar.coeff_basis", "n_levels", n_levels, 0, MAX_LEVELS)
    index = check_integers("haar.coeff_basis", "index", index, 4 ** n_levels)
    row, col = np.divmod(index, 1 << n_levels)
    big = np.maximum(row, col)
    level = np.frexp(np.maximum(big, 1).astype(np.float64))[1].astype(np.int64) - 1
    s = np.left_shift(1, level)
    m = np.where(big == 0, 0, np.where(row < s, 1, np.where(col < s, 2, 3)))
    x = np.where((m == 1) | (m == 3), col - s, col)
    y = np.where((m == 2) | (m == 3), row - s, row)
    z = np.zeros_like(index)
    return np.where(m == 0, z, level), np.where(m == 0, z, x), np.where(m == 0, z, y), m


def node_scale(n_levels: int) -> np.ndarray:
    """2^l for every node of a pyramid: F^0 = node_scale * masses (eq. 17)."""
    n_levels = check_int("haar.node_scale", "n_levels", n_levels, 0, MAX_LEVELS)
    return np.concatenate([np.full(4 ** l, 2.0 ** l) for l in range(n_levels + 1)])


def _levels_of(a: np.ndarray, where: str, name: str) -> int:
    """n of (..., 2^n, 2^n) arrays, else ArgumentError."""
    side = a.shape[-1] if a.ndim >= 2 else 0
    if a.ndim < 2 or a.shape[-2] != side or side < 1 or side & (side - 1):
        raise ArgumentError(f"{where}: {name} must be (..., 2^n, 2^n) arrays, got shape {a.shape}")
    return side.bit_length() - 1


def _float(a, where: str, name: str) -> np.ndarray:
    """a as a float array (float32 or wider) of finite real numbers, else ArgumentError."""
    a = check_real(where, name, a, finite=True)
    return a.astype(np.result_type(a.dtype, np.float32), copy=False)


def _square(a, where: str, name: str):
    """a as finite float (..., 2^n, 2^n) arrays, and n."""
    a = _float(a, where, name)
    return a, _levels_of(a, where, name)


def _broadcast(where: str, arrays: dict) -> list:
    """The named arrays broadcast together, else ArgumentError naming their shapes."""
    try:
        return np.broadcast_arrays(*arrays.values())
    except ValueError:
        shapes = ", ".join(f"{k} {np.shape(v)}" for k, v in arrays.items())
        raise ArgumentError(f"{where}: shapes do not broadcast: {shapes}") from None


def _channels(where: str, *sets: "SparseHaar"):
    """Sparse sets' channel counts (values (K,) or (K, C)) must agree or be 1."""
    counts = {s.value.shape[1] for s in sets if s.value.ndim == 2} - {1}
    if len(counts) > 1:
        raise ArgumentError(f"{where}: sparse sets have different channel counts {sorted(counts)}")


def _embed(c: np.ndarray, n: int) -> np.ndarray:
    """Coefficients of resolution 2^k zero-padded to 2^n (the same function)."""
    k = c.shape[-1]
    if k == 1 << n:
        return c
    out = np.zeros(c.shape[:-2] + (1 << n, 1 << n), c.dtype)
    out[..., :k, :k] = c
    return out


# ============================================================================= transform (sec. 4.1)
def forward(images) -> np.ndarray:
    """Orthonormal nonstandard Haar transform of (..., 2^n, 2^n) images (eq. 13), dense layout."""
    a, n = _square(images, "haar.forward", "images")
    out = np.empty_like(a)
    s = a * 2.0 ** -n  # F^0_{n,t} = 2^-n * pixel
    for l in range(n - 1, -1, -1):
        h = 1 << l
        a00, a01 = s[..., 0::2, 0::2], s[..., 0::2, 1::2]
        a10, a11 = s[..., 1::2, 0::2], s[..., 1::2, 1::2]
        out[..., :h, h:2 * h] = 0.5 * ((a00 - a01) + (a10 - a11))
        out[..., h:2 * h, :h] = 0.5 * ((a00 + a01) - (a10 + a11))
        out[..., h:2 * h, h:2 * h] = 0.5 * ((a00 - a01) - (a10 - a11))
        s = 0.5 * ((a00 + a01) + (a10 + a11))
    out[..., 0, 0] = s[..., 0, 0]
    return out


def _scaling_levels(c: np.ndarray, last: int):
    """Yield (l, F^0_l) for l = 0..last from dense coefficients, top down (inverse steps)."""
    s = c[..., 0:1, 0:1]
    yield 0, s
    for l in range(last):
        h = 1 << l
        d1, d2, d3 = _details(c, l)
        nxt = np.empty(s.shape[:-2] + (2 * h, 2 * h), s.dtype)
        nxt[..., 0::2, 0::2] = 0.5 * ((s + d1) + (d2 + d3))
        nxt[..., 0::2, 1::2] = 0.5 * ((s - d1) + (d2 - d3))
        nxt[..., 1::2, 0::2] = 0.5 * ((s + d1) - (d2 + d3))
        nxt[..., 1::2, 1::2] = 0.5 * ((s - d1) - (d2 - d3))
        s = nxt
        yield l + 1, s


def inverse(coeffs) -> np.ndarray:
    """Images (..., 2^n, 2^n) from dense coefficients; inverse of :func:`forward`."""
    c, n = _square(coeffs, "haar.inverse", "coeffs")
    for _, s in _scaling_levels(c, n):
        pass
    return s * 2.0 ** n


# ============================================================================= sparse sets and compression
@dataclass(frozen=True)
class SparseHaar:
    """A sparse coefficient set: flat dense indices (K,) int64, sorted and unique, and
    values (K,) or (K, C) float; absent coefficients are zero."""

    n_levels: int
    index: np.ndarray
    value: np.ndarray

    def __post_init__(self):
        where = "haar.SparseHaar"
        n = check_int(where, "n_levels", self.n_levels, 0, MAX_LEVELS)
        idx = check_integers(where, "index", self.index, 4 ** n).reshape(-1)
        val = _float(self.value, where, "value")
        if val.shape[:1] != idx.shape or val.ndim > 2:
            raise ArgumentError(f"{where}: value must be (K,) or (K, C) for K = {len(idx)} indices, "
                                f"got shape {val.shape}")
        order = np.argsort(idx, kind="stable")
        dup = np.diff(idx[order]) == 0
        if np.any(dup):
            raise ArgumentError(f"{where}: index {idx[order][1:][dup][0]} appears more than once")
        object.__setattr__(self, "n_levels", n)
        object.__setattr__(self, "index", idx[order])
        object.__setattr__(self, "value", val[order])

    def __len__(self) -> int:
        return len(self.index)

    def to_dense(self) -> np.ndarray:
        """(2^n, 2^n) or (C, 2^n, 2^n) dense coefficients."""
        side = 1 << self.n_levels
        out = np.zeros((side * side,) + self.value.shape[1:], self.value.dtype)
        out[self.index] = self.value
        return np.moveaxis(out, 0, -1).reshape(self.value.shape[1:] + (side, side))

    @classmethod
    def from_dense(cls, coeffs, keep=None) -> "SparseHaar":
        """From (2^n, 2^n) or (C, 2^n, 2^n) coefficients; ``keep`` = flat indices or a flat
        boolean mask (default: the coefficients non-zero in any channel)."""
        where = "haar.SparseHaar.from_dense"
        c, n = _square(coeffs, where, "coeffs")
        if c.ndim > 3:
            raise ArgumentError(f"{where}: coeffs must be one set, (2^n, 2^n) or (C, 2^n, 2^n), got shape {c.shape}")
        flat = c.reshape(c.shape[:-2] + (-1,))
        flat = flat.T if c.ndim == 3 else flat
        if keep is None:
            keep = np.flatnonzero(np.any(flat.reshape(len(flat), -1) != 0, axis=1))
        elif check_real(where, "keep", keep).dtype == bool:
            keep = np.asarray(keep)
            if keep.size != len(flat):
                raise ArgumentError(f"{where}: a boolean keep must have one entry per coefficient ({len(flat)}), "
                                    f"got {keep.size}")
            keep = np.flatnonzero(keep)
        else:
            keep = check_integers(where, "keep", keep, len(flat))
        return cls(n, keep, flat[keep])


def _energy(coeffs, where: str) -> np.ndarray:
    c, _ = _square(coeffs, where, "coeffs")
    if c.ndim > 3:
        raise ArgumentError(f"{where}: coeffs must be one set, (2^n, 2^n) or (C, 2^n, 2^n), got shape {c.shape}")
    e = np.square(c.astype(np.float64)).reshape(-1, c.shape[-1] ** 2)
    return e.sum(axis=0)


def _by_energy(e: np.ndarray) -> np.ndarray:
    """Indices by decreasing energy, scaling coefficient first, ties by index."""
    key = -e
    key[0] = -np.inf
    return np.argsort(key, kind="stable")


def compress_topk(coeffs, k: int) -> SparseHaar:
    """Keep k coefficients in all: the scaling coefficient and the k - 1 wavelets of largest
    magnitude (L2 norm over channels). Ng et al. 2003 nonlinear approximation."""
    k = check_int("haar.compress_topk", "k", k, 1)
    order = _by_energy(_energy(coeffs, "haar.compress_topk"))
    return SparseHaar.from_dense(coeffs, order[:k])


def compress_energy(coeffs, fraction: float) -> SparseHaar:
    """Keep the fewest coefficients (scaling coefficient included first) whose sum of squares
    reaches ``fraction`` of the total energy."""
    fraction = check_number("haar.compress_energy", "fraction", fraction, 0.0, 1.0)
    e = _energy(coeffs, "haar.compress_energy")
    order = _by_energy(e)
    cum = np.cumsum(e[order])
    k = int(np.searchsorted(cum, fraction * cum[-1], side="left")) + 1
    return SparseHaar.from_dense(coeffs, order[:min(k, len(order))])


# ============================================================================= tripling coefficients (sec. 4.2)
def tripling(i, j, k, n_levels: int) -> np.ndarray:
    """C_ijk = integral of psi_i psi_j psi_k over the unit square (eq. 16), by the Haar tripling
    coefficient theorem (Ng et al. 2004). Indices are flat dense indices; vectorised."""
    where = "haar.tripling"
    n_levels = check_int(where, "n_levels", n_levels, 0, MAX_LEVELS)
    i, j, k = _broadcast(where, {name: check_integers(where, name, a, 4 ** n_levels)
                                 for name, a in (("i", i), ("j", j), ("k", k))})
    b = {"i": coeff_basis(i, n_levels), "j": coeff_basis(j, n_levels), "k": coeff_basis(k, n_levels)}
    ids = {"i": i, "j": j, "k": k}
    (li, xi, yi, mi), (lj, xj, yj, mj), (lk, xk, yk, mk) = b["i"], b["j"], b["k"]
    out = np.zeros(i.shape)
    # case 1: three scaling functions
    out[(mi == 0) & (mj == 0) & (mk == 0)] = 1.0
    # case 2: one square, three different wavelet types: 2^l
    same = (li == lj) & (lj == lk) & (xi == xj) & (xj == xk) & (yi == yj) & (yj == yk)
    distinct = (mi > 0) & (mj > 0) & (mk > 0) & (mi != mj) & (mj != mk) & (mi != mk)
    out = np.where(same & distinct, np.ldexp(1.0, li), out)
    # case 3: two identical wavelets and a strictly coarser overlapping function: +-2^l'
    for a, c in (("i", "k"), ("i", "j"), ("j", "i")):
        other = ({"i", "j", "k"} - {a, c}).pop()  # the second of the identical pair
        la, xa, ya, ma = b[a]
        lc, xc, yc, mc = b[c]
        pair = (ids[a] == ids[other]) & (ma > 0)
        coarser = (mc == 0) | (lc < la)
        d = np.maximum(la - lc, 1)
        inside = (mc == 0) | (((xa >> d) == xc) & ((ya >> d) == yc))
        qx, qy = (xa >> (d - 1)) & 1, (ya >> (d - 1)) & 1  # child quadrant of the coarse square
        sx, sy = 1 - 2 * qx, 1 - 2 * qy
        sign = np.select([mc == 1, mc == 2, mc == 3], [sx, sy, sx * sy], 1)
        val = sign * np.ldexp(1.0, np.where(mc == 0, 0, lc))
        out = np.where(pair & coarser & inside, val, out)
    return out


# ============================================================================= sparse helpers
#: A set of K keys in a key space of S is indexed by a table over the whole space (int32
#: slots, so at most 4 TABLE_SPREAD bytes per key) when S <= TABLE_SPREAD K: lookups O(1),
#: building O(S) = O(K). Sparser sets are indexed by binary search, O(log K) per lookup.
TABLE_SPREAD = 64


class _Keyed:
    """A coefficient set by key: wavelet (l, x, y, m) -> 1 + 3 nid + m - 1 with nid the node's
    pyramid index (independent of n), the scaling function -> 0; values (K, C) in the set's
    dtype. ``get`` finds keys through :class:`_Rows` (no sorting for sets dense enough for a
    table)."""

    def __init__(self, sp: SparseHaar, n_levels: int):
        l, x, y, m = coeff_basis(sp.index, sp.n_levels)
        nid = (np.left_shift(1, 2 * l) - 1) // 3 + (y << l) + x
        self.keys = np.where(m == 0, 0, 1 + 3 * nid + m - 1)
        self.vals = sp.value.reshape(len(sp.value), 1 if sp.value.ndim == 1 else sp.value.shape[1])
        self.rows = _Rows(self.keys, 4 ** n_levels)

    def get(self, q) -> np.ndarray:
        """Values (..., C) at keys q, 0 where absent."""
        q = np.asarray(q, np.int64)
        if len(self.keys) == 0:
            return np.zeros(q.shape + self.vals.shape[1:], self.vals.dtype)
        row = self.rows.find(q)
        return np.where((row >= 0)[..., None], self.vals[row], self.vals.dtype.type(0))


class _Rows:
    """Row of each of ``keys`` (distinct, in [0, space)): find(q) -> row, or -1 where absent;
    a table over the space where it holds at most TABLE_SPREAD slots per key, else binary
    search over the sorted keys."""

    def __init__(self, keys: np.ndarray, space: int):
        self.keys = keys
        self.table = len(keys) > 0 and space <= TABLE_SPREAD * len(keys)
        if self.table:
            self.slot = np.zeros(space, np.int32)   # 1 + row; 0: absent
            self.slot[keys] = np.arange(1, len(keys) + 1, dtype=np.int32)
        else:
            self.order = np.argsort(keys, kind="stable")
            self.sorted = keys[self.order]

    def find(self, q: np.ndarray) -> np.ndarray:
        if self.table:
            return self.slot[q].astype(np.int64) - 1
        if len(self.keys) == 0:
            return np.full(np.shape(q), -1, np.int64)
        pos = np.minimum(np.searchsorted(self.sorted, q), len(self.keys) - 1)
        return np.where(self.sorted[pos] == q, self.order[pos], -1)


def _distinct(idx: np.ndarray, space: int):
    """The distinct values of idx (in [0, space)) and each element's position among them:
    O(len + space) through a table where space <= TABLE_SPREAD len, else np.unique."""
    if len(idx) == 0 or space > TABLE_SPREAD * len(idx):
        return np.unique(idx, return_inverse=True)
    slot = np.zeros(space, np.int64)
    slot[idx] = np.arange(1, len(idx) + 1)   # one occurrence of each value keeps its slot
    first = slot[idx] == np.arange(1, len(idx) + 1)
    rank = np.cumsum(first) - 1
    return idx[first], rank[slot[idx] - 1]


#: The pyramid index of each level's first node, (4^l - 1) / 3 for l = 0..32 (exact in int64).
_LEVEL_STARTS = np.array([(4 ** l - 1) // 3 for l in range(33)], np.int64)


def _node_of(nid):
    """(level, x, y) of pyramid node indices (the level by integer search, exact at every
    level up to MAX_LEVELS)."""
    nid = np.asarray(nid, np.int64)
    l = np.searchsorted(_LEVEL_STARTS, nid, side="right").astype(np.int64) - 1
    r = nid - _LEVEL_STARTS[l]
    return l, r & (np.left_shift(1, l) - 1), r >> l


def _averages(t: _Keyed, nid):
    """Average of the function over the squares of nodes ``nid``: 2^l F^0_{l,t}, the scaling
    coefficient plus the parents' wavelets at the right sign, (Q, C). Top-down over the
    distinct nodes on the queries' paths to the root, one level at a time (the traversal of
    Ng et al. 2004): a node's average is its parent's plus 2^(l-1) (s_x W1 + s_y W2 + s_x s_y W3)
    of the parent's wavelets. The queries are grouped by level in one stable sort of their
    levels, so the cost is the number of distinct nodes on the paths (at most min(Q n,
    4^n / 3)), not Q times the depth."""
    l, x, y = _node_of(nid)
    depth = int(l.max(initial=0))
    by_level = np.argsort(l.astype(np.int8), kind="stable")   # a radix sort of small integers
    bounds = np.concatenate([[0], np.cumsum(np.bincount(l, minlength=depth + 1))])
    asked = [by_level[bounds[lv]:bounds[lv + 1]] for lv in range(depth + 1)]
    # per level, bottom-up: the distinct nodes needed (the queries there, then the parents of
    # the nodes needed below) and each entry's position among them
    flat, pos = [None] * (depth + 1), [None] * (depth + 1)
    parents = np.empty(0, np.int64)
    for lv in range(depth, -1, -1):
        flat[lv], pos[lv] = _distinct(np.concatenate([(y[asked[lv]] << lv) + x[asked[lv]], parents]), 4 ** lv)
        fx, fy = flat[lv] & ((1 << lv) - 1), flat[lv] >> lv
        parents = ((fy >> 1) << max(lv - 1, 0)) + (fx >> 1)
    out = np.empty((len(l), t.vals.shape[1]), t.vals.dtype)
    avg = np.broadcast_to(t.get(np.int64(0)), (len(flat[0]), t.vals.shape[1]))
    out[asked[0]] = avg[pos[0][:len(asked[0])]]
    for lv in range(1, depth + 1):   # top-down
        fx, fy = flat[lv] & ((1 << lv) - 1), flat[lv] >> lv
        base = 1 + 3 * ((4 ** (lv - 1) - 1) // 3 + ((fy >> 1) << (lv - 1)) + (fx >> 1))
        sx, sy = (1 - 2 * (fx & 1))[:, None], (1 - 2 * (fy & 1))[:, None]
        avg = avg[pos[lv - 1][len(asked[lv - 1]):]] + 2.0 ** (lv - 1) * (
            t.get(base) * sx + t.get(base + 1) * sy + t.get(base + 2) * (sx * sy))
        out[asked[lv]] = avg[pos[lv][:len(asked[lv])]]
    return out


def _common(a: _Keyed, b: _Keyed):
    """Wavelet keys present in both sets, with both value rows."""
    row = b.rows.find(a.keys)
    w = (a.keys > 0) & (row >= 0)
    return a.keys[w], a.vals[w], b.vals[row[w]]


def _node_table(t: _Keyed, n_levels: int):
    """Distinct wavelet nodes of a set and their (U, 3, C) coefficient table."""
    w = t.keys > 0
    nid, m = np.divmod(t.keys[w] - 1, 3)
    uniq, inv = _distinct(nid, max((4 ** n_levels - 1) // 3, 1))
    table = np.zeros((len(uniq), 3, t.vals.shape[1]))
    table[inv, m] = t.vals[w]
    return uniq, table


def _shape_out(total: np.ndarray, *sets: SparseHaar):
    return total if any(s.value.ndim == 2 for s in sets) else total[0]


# ============================================================================= product integrals (Ng et al. 2004)
def double_product_integral(G, H):
    """Integral of G H from coefficients (dense (..., 2^n, 2^n) or SparseHaar): orthonormality
    makes it the dot product of the coefficient vectors."""
    where = "haar.double_product_integral"
    if isinstance(G, SparseHaar) and isinstance(H, SparseHaar):
        _channels(where, G, H)
        n = max(G.n_levels, H.n_levels)
        g, h = _Keyed(G, n), _Keyed(H, n)
        _, a, b = _common(g, h)
        total = (a * b).sum(axis=0) + g.get(np.int64(0)) * h.get(np.int64(0))
        return _shape_out(total, G, H)
    g, h = _dense_common(where, G=G, H=H)
    return np.sum(g * h, axis=(-2, -1))


def _dense_common(where: str, **sets):
    """The named sets (dense or SparseHaar) as dense arrays of one resolution, batch shapes
    checked to broadcast."""
    arrs = {k: s.to_dense() if isinstance(s, SparseHaar) else _float(s, where, k) for k, s in sets.items()}
    n = max(_levels_of(a, where, k) for k, a in arrs.items())
    try:
        np.broadcast_shapes(*(a.shape[:-2] for a in arrs.values()))
    except ValueError:
        shapes = ", ".join(f"{k} {a.shape}" for k, a in arrs.items())
        raise ArgumentError(f"{where}: batch shapes do not broadcast: {shapes}") from None
    return [_embed(a, n) for a in arrs.values()]


def _permanent(g1, g2, g3, h1, h2, h3, k1, k2, k3):
    """Sum over the six assignments of distinct wavelet types (tripling case 2)."""
    return g1 * (h2 * k3 + h3 * k2) + g2 * (h1 * k3 + h3 * k1) + g3 * (h1 * k2 + h2 * k1)


def triple_product_integral(G, H, K):
    """Integral of G H K from coefficients (dense (..., 2^n, 2^n) or all three SparseHaar),
    linear in the number of coefficients (see the module notes)."""
    where = "haar.triple_product_integral"
    if all(isinstance(s, SparseHaar) for s in (G, H, K)):
        _channels(where, G, H, K)
        return _triple_sparse(G, H, K)
    g, h, k = _dense_common(where, G=G, H=H, K=K)
    n = _levels_of(g, where, "G")
    total = g[..., 0, 0] * h[..., 0, 0] * k[..., 0, 0]  # case 1
    pyramids = (_scaling_levels(c, n) for c in (g, h, k))
    for l, (_, sg), (_, sh), (_, sk) in zip(range(n), *pyramids):  # wavelet levels 0..n-1
        gb, hb, kb = (_details(c, l) for c in (g, h, k))
        s = 1 << l
        ag, ah, ak = sg * s, sh * s, sk * s  # averages over the node squares
        term = sum(gb[m] * hb[m] * ak + gb[m] * kb[m] * ah + hb[m] * kb[m] * ag for m in range(3))
        term = term + s * _permanent(*gb, *hb, *kb)  # case 2
        total = total + term.sum(axis=(-2, -1))
    return total


def _details(c: np.ndarray, l: int):
    """The three wavelet blocks (m = 1, 2, 3) of level l, each (..., 2^l, 2^l)."""
    s = 1 << l
    return c[..., :s, s:2 * s], c[..., s:2 * s, :s], c[..., s:2 * s, s:2 * s]


def _triple_sparse(G, H, K):
    n = max(G.n_levels, H.n_levels, K.n_levels)
    cg, ch, ck = _Keyed(G, n), _Keyed(H, n), _Keyed(K, n)
    total = cg.get(np.int64(0)) * ch.get(np.int64(0)) * ck.get(np.int64(0))
    # case 3: identical wavelet pairs times the third function's average (its coarser part)
    for a_set, b_set, c_set in ((cg, ch, ck), (cg, ck, ch), (ch, ck, cg)):
        keys, a, b = _common(a_set, b_set)
        if len(keys):
            total = total + (a * b * _averages(c_set, (keys - 1) // 3)).sum(axis=0)
    # case 2: three different wavelet types on one square
    (ng, tg), (nh, th), (nk, tk) = (_node_table(c, n) for c in (cg, ch, ck))
    space = max((4 ** n - 1) // 3, 1)
    ih, ik = _Rows(nh, space).find(ng), _Rows(nk, space).find(ng)
    in_all = (ih >= 0) & (ik >= 0)
    allk = ng[in_all]
    if len(allk):
        a, b, c = tg[in_all], th[ih[in_all]], tk[ik[in_all]]
        scale = np.ldexp(1.0, _node_of(allk)[0])[:, None]
        total = total + (scale * _permanent(a[:, 0], a[:, 1], a[:, 2], b[:, 0], b[:, 1], b[:, 2],
                                            c[:, 0], c[:, 1], c[:, 2])).sum(axis=0)
    return _shape_out(total, G, H, K)


# ============================================================================= scaling coefficients (sec. 4.3-4.4)
def scaling_pyramid(coeffs, levels: int | None = None) -> np.ndarray:
    """Box-mass pyramid (..., tree_size(L)) of a coefficient set, levels 0..L (default n),
    in the layout of distributions.py: node value 2^-l F^0_{l,t} (eq. 17). Only coefficients
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
    c, n = _square(coeffs, where, "coeffs")
    L = n if levels is None else check_int(where, "levels", levels, 0, n)
    out = np.empty(c.shape[:-2] + (tree_size(L),), c.dtype)
    for l, s in _scaling_levels(c[..., :1 << L, :1 << L], L):
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
    G, H = (s if isinstance(s, SparseHaar) else _square(s, where, k)[0] for k, s in (("G", G), ("H", H)))
    n = max(s.n_levels if isinstance(s, SparseHaar) else s.shape[-1].bit_length() - 1 for s in (G, H))
    L = n if levels is None else check_int(where, "levels", levels, 0, n)
    if sparse:
        _channels(where, G, H)
        # scaling pyramids from the coefficients of levels < L; D from the common wavelets
        pg, ph = (_pad_pyramid(scaling_pyramid(s, min(L, s.n_levels)), min(L, s.n_levels), L)
                  for s in (G, H))
        keys, a, b = _common(_Keyed(G, n), _Keyed(H, n))
        prod = (a * b).T  # (C, Kc)
        lv, x, y = _node_of((keys - 1) // 3)
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
    g, h = _dense_common(where, G=G, H=H)
    shape = np.broadcast_shapes(g.shape[:-2], h.shape[:-2])
    out = np.empty(shape + (tree_size(L),), np.result_type(g, h))
    # D_{l,t}: own wavelet products plus the children's D, bottom up from level n - 1
    D = np.zeros(shape + (1 << n, 1 << n), out.dtype)
    for l in range(n - 1, -1, -1):
        own = sum(a * b for a, b in zip(_details(g, l), _details(h, l)))
        D = own + _reduce4(D)
        if l <= L:
            out[..., level_offset(l):level_offset(l + 1)] = D.reshape(shape + (-1,))
    if L == n:
        out[..., level_offset(n):] = 0.0
    for (l, sg), (_, sh) in zip(_scaling_levels(g, L), _scaling_levels(h, L)):
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
    c, _ = _square(s, where, name)
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
    _channels(where, G, H)
    level, x, y = _broadcast(where, {k: check_integers(where, k, a).reshape(-1)
                                     for k, a in (("level", level), ("x", x), ("y", y))})
    n = max(G.n_levels, H.n_levels)
    if np.any((level < 0) | (level > n)):
        raise ArgumentError(f"{where}: level must be in [0, {n}], got {level[(level < 0) | (level > n)][0]}")
    side = np.left_shift(1, level)
    if np.any((x < 0) | (y < 0) | (x >= side) | (y >= side)):
        raise ArgumentError(f"{where}: x and y must be in [0, 2^level)")
    g, h = _Keyed(G, n), _Keyed(H, n)
    nid = (np.left_shift(1, 2 * level) - 1) // 3 + (y << level) + x
    out = _averages(g, nid) * _averages(h, nid) * np.ldexp(1.0, -2 * level)[:, None]
    keys, a, b = _common(g, h)
    if len(keys):
        prod = a * b
        lv, px, py = _node_of((keys - 1) // 3)
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


# ============================================================================= OpenCL (kernels/haar.cl)
def forward_cl(images, queue=None):
    """Forward transform of (..., 2^n, 2^n) images on the device (any leading axes, e.g.
    colour channels or a batch, folded into one batch of T), one launch per level.

    returns coeffs (..., 2^n, 2^n) float32 (dense layout) and the box-mass pyramids
    (..., tree_size(n)) float32 computed on the way (distributions.py layout).
    """
    where = "haar.forward_cl"
    img = np.ascontiguousarray(_float(images, where, "images"), np.float32)
    if img.ndim < 2:
        raise ArgumentError(f"{where}: images must be (..., 2^n, 2^n), got shape {img.shape}")
    n = _levels_of(img, where, "images")
    lead, side, stride = img.shape[:-2], 1 << n, tree_size(n)
    img = img.reshape(-1, side, side)
    T = img.shape[0]
    if T == 0 or n == 0:  # no image, or one pixel: F^0 = pixel = mass
        return img.reshape(lead + (side, side)).copy(), img.reshape(lead + (stride,)).copy()
    queue = queue or cl.thread_queue()
    prog = cl.program("haar.cl")
    src = cl.to_device(img)
    pyr = cl.empty(4 * T * stride)
    coef = cl.empty(img.nbytes)
    cl.kernel(prog, "haar_load_leaves")(queue, (side * side, T), None, src, pyr, np.uint64(stride),
                                        np.int32(n))
    knl = cl.kernel(prog, "haar_forward_level")
    for level in range(n - 1, -1, -1):
        knl(queue, (4 ** level, T), None, pyr, np.uint64(stride), coef, np.int32(n), np.int32(level))
    return (cl.read(coef, img.shape, np.float32, queue).reshape(lead + (side, side)),
            cl.read(pyr, (T, stride), np.float32, queue).reshape(lead + (stride,)))


def inverse_cl(coeffs, queue=None):
    """Inverse transform of (..., 2^n, 2^n) dense coefficients on the device (any leading axes,
    folded into one batch), one launch per level (kernels/haar.cl ``haar_inverse_level``;
    numpy twin :func:`inverse`): images of the same shape, float32."""
    where = "haar.inverse_cl"
    c = np.ascontiguousarray(_float(coeffs, where, "coeffs"), np.float32)
    if c.ndim < 2:
        raise ArgumentError(f"{where}: coeffs must be (..., 2^n, 2^n), got shape {c.shape}")
    n = _levels_of(c, where, "coeffs")
    shape = c.shape
    c = c.reshape((-1,) + shape[-2:])
    T = c.shape[0]
    if T == 0 or n == 0:   # one pixel: pixel = F^0
        out = c.copy()
    else:
        queue = queue or cl.thread_queue()
        knl = cl.kernel(cl.program("haar.cl"), "haar_inverse_level")
        src = cl.to_device(c)
        first = np.zeros((T, c[0].size), np.float32)   # level 0: F^0 of each set, at its tree's start
        first[:, 0] = c[:, 0, 0]
        bufs = [cl.to_device(first), cl.empty(c.nbytes)]
        for level in range(n):
            scale = np.float32(2.0 ** n if level == n - 1 else 1.0)
            knl(queue, (4 ** level, T), None, src, bufs[0], bufs[1], np.int32(n), np.int32(level), scale)
            bufs.reverse()
        out = cl.read(bufs[0], c.shape, np.float32, queue)
    return out.reshape(shape)


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
            G, n = _square(G, where, "G")
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

    def enqueue(self, queue, h_buf, n_trees: int, out_buf):
        """Launch on device buffers: h_buf (T, 2^m, 2^m) float32 -> out_buf (T, stride) float32,
        the trees in the device's Morton order, the walks' level order (distributions.py Layout;
        node 0 at each tree's start, not at HaarTree's TREE_ORIGIN)."""
        import pyopencl  # deferred like in cl.py
        nbytes = 4 * 4 ** self.leaf_level
        knl = cl.kernel(self._prog, "haar_product_tree")
        return knl(queue, (self.work_group, n_trees), (self.work_group, 1), self._g, h_buf,
                   np.int32(self.h_levels), np.int32(self.leaf_level), np.int32(self.levels),
                   out_buf, np.uint64(self.stride), np.int32(self.nonnegative),
                   pyopencl.LocalMemory(nbytes), pyopencl.LocalMemory(nbytes))

    def __call__(self, H, queue=None) -> np.ndarray:
        """Pyramids (T, stride) float32 for H (T, 2^m, 2^m) or (2^m, 2^m) dense coefficients,
        row-major (the host's layout)."""
        h = np.ascontiguousarray(_float(H, "haar.ProductPyramids", "H"), np.float32)
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
