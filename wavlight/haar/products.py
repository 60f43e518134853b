"""Tripling coefficients (Chen & Gao sec. 4.2, eq. 14-16) and product integrals of two and three
Haar-represented functions (Ng et al. 2004: linear in the coefficients kept).
"""
from __future__ import annotations

import numpy as np

from ..errors import ArgumentError, check_int, check_integers
from .sparse import (
    SparseHaar,
    node_averages,
    channels_of,
    common_nodes,
    Keyed,
    node_of,
    node_table,
    Rows,
    shape_out,
)
from .transform import (
    MAX_LEVELS,
    broadcast_sets,
    details,
    embed,
    as_float,
    levels_of,
    scaling_levels,
    coeff_basis,
)


# ============================================================================= tripling coefficients (sec. 4.2)
def tripling(i, j, k, n_levels: int) -> np.ndarray:
    """C_ijk = integral of psi_i psi_j psi_k over the unit square (eq. 16), by the Haar tripling
    coefficient theorem (Ng et al. 2004). Indices are flat dense indices; vectorised."""
    where = "haar.tripling"
    n_levels = check_int(where, "n_levels", n_levels, 0, MAX_LEVELS)
    i, j, k = broadcast_sets(where, {name: check_integers(where, name, a, 4 ** n_levels)
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



# ============================================================================= product integrals (Ng et al. 2004)
def double_product_integral(G, H):
    """Integral of G H from coefficients (dense (..., 2^n, 2^n) or SparseHaar): orthonormality
    makes it the dot product of the coefficient vectors."""
    where = "haar.double_product_integral"
    if isinstance(G, SparseHaar) and isinstance(H, SparseHaar):
        channels_of(where, G, H)
        n = max(G.n_levels, H.n_levels)
        g, h = Keyed(G, n), Keyed(H, n)
        _, a, b = common_nodes(g, h)
        total = (a * b).sum(axis=0) + g.get(np.int64(0)) * h.get(np.int64(0))
        return shape_out(total, G, H)
    g, h = dense_common(where, G=G, H=H)
    return np.sum(g * h, axis=(-2, -1))


def dense_common(where: str, **sets):
    """The named sets (dense or SparseHaar) as dense arrays of one resolution, batch shapes
    checked to broadcast."""
    arrs = {k: s.to_dense() if isinstance(s, SparseHaar) else as_float(s, where, k) for k, s in sets.items()}
    n = max(levels_of(a, where, k) for k, a in arrs.items())
    try:
        np.broadcast_shapes(*(a.shape[:-2] for a in arrs.values()))
    except ValueError:
        shapes = ", ".join(f"{k} {a.shape}" for k, a in arrs.items())
        raise ArgumentError(f"{where}: batch shapes do not broadcast: {shapes}") from None
    return [embed(a, n) for a in arrs.values()]


def _permanent(g1, g2, g3, h1, h2, h3, k1, k2, k3):
    """Sum over the six assignments of distinct wavelet types (tripling case 2)."""
    return g1 * (h2 * k3 + h3 * k2) + g2 * (h1 * k3 + h3 * k1) + g3 * (h1 * k2 + h2 * k1)


def triple_product_integral(G, H, K):
    """Integral of G H K from coefficients (dense (..., 2^n, 2^n) or all three SparseHaar),
    linear in the number of coefficients (see the module notes)."""
    where = "haar.triple_product_integral"
    if all(isinstance(s, SparseHaar) for s in (G, H, K)):
        channels_of(where, G, H, K)
        return _triple_sparse(G, H, K)
    g, h, k = dense_common(where, G=G, H=H, K=K)
    n = levels_of(g, where, "G")
    total = g[..., 0, 0] * h[..., 0, 0] * k[..., 0, 0]  # case 1
    pyramids = (scaling_levels(c, n) for c in (g, h, k))
    for l, (_, sg), (_, sh), (_, sk) in zip(range(n), *pyramids):  # wavelet levels 0..n-1
        gb, hb, kb = (details(c, l) for c in (g, h, k))
        s = 1 << l
        ag, ah, ak = sg * s, sh * s, sk * s  # averages over the node squares
        term = sum(gb[m] * hb[m] * ak + gb[m] * kb[m] * ah + hb[m] * kb[m] * ag for m in range(3))
        term = term + s * _permanent(*gb, *hb, *kb)  # case 2
        total = total + term.sum(axis=(-2, -1))
    return total


def _triple_sparse(G, H, K):
    n = max(G.n_levels, H.n_levels, K.n_levels)
    cg, ch, ck = Keyed(G, n), Keyed(H, n), Keyed(K, n)
    total = cg.get(np.int64(0)) * ch.get(np.int64(0)) * ck.get(np.int64(0))
    # case 3: identical wavelet pairs times the third function's average (its coarser part)
    for a_set, b_set, c_set in ((cg, ch, ck), (cg, ck, ch), (ch, ck, cg)):
        keys, a, b = common_nodes(a_set, b_set)
        if len(keys):
            total = total + (a * b * node_averages(c_set, (keys - 1) // 3)).sum(axis=0)
    # case 2: three different wavelet types on one square
    (ng, tg), (nh, th), (nk, tk) = (node_table(c, n) for c in (cg, ch, ck))
    space = max((4 ** n - 1) // 3, 1)
    ih, ik = Rows(nh, space).find(ng), Rows(nk, space).find(ng)
    in_all = (ih >= 0) & (ik >= 0)
    allk = ng[in_all]
    if len(allk):
        a, b, c = tg[in_all], th[ih[in_all]], tk[ik[in_all]]
        scale = np.ldexp(1.0, node_of(allk)[0])[:, None]
        total = total + (scale * _permanent(a[:, 0], a[:, 1], a[:, 2], b[:, 0], b[:, 1], b[:, 2],
                                            c[:, 0], c[:, 1], c[:, 2])).sum(axis=0)
    return shape_out(total, G, H, K)
