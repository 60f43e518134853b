"""Sparse Haar coefficient sets: compression (Ng et al. 2003's nonlinear approximation) and
lookup by key (tables over the key space, or binary search), shared by the products.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ArgumentError, check_int, check_integers, check_number, check_real
from .transform import MAX_LEVELS, as_float, checked_square, coeff_basis


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
        val = as_float(self.value, where, "value")
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
        c, n = checked_square(coeffs, where, "coeffs")
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


def channels_of(where: str, *sets: "SparseHaar"):
    """Sparse sets' channel counts (values (K,) or (K, C)) must agree or be 1."""
    counts = {s.value.shape[1] for s in sets if s.value.ndim == 2} - {1}
    if len(counts) > 1:
        raise ArgumentError(f"{where}: sparse sets have different channel counts {sorted(counts)}")


def _energy(coeffs, where: str) -> np.ndarray:
    c, _ = checked_square(coeffs, where, "coeffs")
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



# ============================================================================= sparse helpers
#: A set of K keys in a key space of S is indexed by a table over the whole space (int32
#: slots, so at most 4 TABLE_SPREAD bytes per key) when S <= TABLE_SPREAD K: lookups O(1),
#: building O(S) = O(K). Sparser sets are indexed by binary search, O(log K) per lookup.
TABLE_SPREAD = 64


class Keyed:
    """A coefficient set by key: wavelet (l, x, y, m) -> 1 + 3 nid + m - 1 with nid the node's
    pyramid index (independent of n), the scaling function -> 0; values (K, C) in the set's
    dtype. ``get`` finds keys through :class:`Rows` (no sorting for sets dense enough for a
    table)."""

    def __init__(self, sp: SparseHaar, n_levels: int):
        l, x, y, m = coeff_basis(sp.index, sp.n_levels)
        nid = (np.left_shift(1, 2 * l) - 1) // 3 + (y << l) + x
        self.keys = np.where(m == 0, 0, 1 + 3 * nid + m - 1)
        self.vals = sp.value.reshape(len(sp.value), 1 if sp.value.ndim == 1 else sp.value.shape[1])
        self.rows = Rows(self.keys, 4 ** n_levels)

    def get(self, q) -> np.ndarray:
        """Values (..., C) at keys q, 0 where absent."""
        q = np.asarray(q, np.int64)
        if len(self.keys) == 0:
            return np.zeros(q.shape + self.vals.shape[1:], self.vals.dtype)
        row = self.rows.find(q)
        return np.where((row >= 0)[..., None], self.vals[row], self.vals.dtype.type(0))


class Rows:
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


def node_of(nid):
    """(level, x, y) of pyramid node indices (the level by integer search, exact at every
    level up to MAX_LEVELS)."""
    nid = np.asarray(nid, np.int64)
    l = np.searchsorted(_LEVEL_STARTS, nid, side="right").astype(np.int64) - 1
    r = nid - _LEVEL_STARTS[l]
    return l, r & (np.left_shift(1, l) - 1), r >> l


def node_averages(t: Keyed, nid):
    """Average of the function over the squares of nodes ``nid``: 2^l F^0_{l,t}, the scaling
    coefficient plus the parents' wavelets at the right sign, (Q, C). Top-down over the
    distinct nodes on the queries' paths to the root, one level at a time (the traversal of
    Ng et al. 2004): a node's average is its parent's plus 2^(l-1) (s_x W1 + s_y W2 + s_x s_y W3)
    of the parent's wavelets. The queries are grouped by level in one stable sort of their
    levels, so the cost is the number of distinct nodes on the paths (at most min(Q n,
    4^n / 3)), not Q times the depth."""
    l, x, y = node_of(nid)
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


def common_nodes(a: Keyed, b: Keyed):
    """Wavelet keys present in both sets, with both value rows."""
    row = b.rows.find(a.keys)
    w = (a.keys > 0) & (row >= 0)
    return a.keys[w], a.vals[w], b.vals[row[w]]


def node_table(t: Keyed, n_levels: int):
    """Distinct wavelet nodes of a set and their (U, 3, C) coefficient table."""
    w = t.keys > 0
    nid, m = np.divmod(t.keys[w] - 1, 3)
    uniq, inv = _distinct(nid, max((4 ** n_levels - 1) // 3, 1))
    table = np.zeros((len(uniq), 3, t.vals.shape[1]))
    table[inv, m] = t.vals[w]
    return uniq, table


def shape_out(total: np.ndarray, *sets: SparseHaar):
    return total if any(s.value.ndim == 2 for s in sets) else total[0]
