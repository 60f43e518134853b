"""Wavelet product importance sampling: light x BRDF x cosine, top-down (numpy twin of kernels/product.h).

Design (decided by measurement: docs/decisions/top-down-walk.md): no per-point tree
and no precomputed BRDF tables. The sampling tree of the product is walked
top-down, evaluating only the four children of each visited node (Clarberg et
al. 2005 evaluate the product top-down too). A node's importance is its product
scaling coefficient approximated by the first term of eq. 25,
F^0_s ~ 2^l G^0_s H^0_s: the environment's exact box mass (the light tree) times
the BRDF x cosine at the node's centre with a lobe pre-filtered to the node's size

    lambert  I = mass clamp(d . n + h_l, 0, 1)
    phong    I = mass (1 + k_l x / 8)^-8 clamp(d . n + h_l, 0, 1)   (~ exp(-k_l x))
    ggx      I = mass (1 + k_l x)^-2 clamp(d . n / h_l + 1, 0, 1)              (alpha <= 0.1)
    ggx      I = mass pi D_{alpha_l}(h) clamp(d . n / h_l + 1, 0, 1),  h = normalize(d + wo)  (alpha > 0.1)

with x = 1 - d . axis, r_l = 0.35 pi / 2^l the lobe blur (phong: 0.2 pi / 2^l) and h_l = 0.75 pi / 2^l
the horizon blur (a node of the lat-long square spans pi / 2^l in theta; blurs
near the node's half size measured best: wider lobes waste samples on bright
nodes outside the lobe), and
k_l = 1 / (1/kappa + r_l^2) the lobe widened to the node. phong: cos^n a ~
exp(n (cos a - 1)), kappa = n, times the cosine. ggx at normal incidence:
D(h) ~ (1 + x / (2 alpha^2))^-2 in the reflected direction, kappa = 1 / (2 alpha^2).
Wide ggx lobes (alpha > 0.1, :func:`lobe_shape`) use the microfacet distribution at
the true half vector of the node's centre and the view direction instead, with
alpha_l^2 = alpha^2 + r_l^2 / 2 (the same widening), so the lobe keeps its real
shape, stretched and off-specular at grazing views; this measured better for
ggx 0.2 and worse for ggx 0.05 (kernels/product.h). f cos has no cosine factor,
only the horizon (softened to the node's size). lambert: the cosine. Below
the product depth P (chosen per material so that nodes are smaller than half the
lobe's width, :func:`product_levels`) the BRDF is taken as constant and the walk
continues in the light tree. The pdf is exact for the sampler (product of the
conditionals), so with MIS against BSDF sampling the estimator is unbiased even
where the approximate importance is 0.
"""
from __future__ import annotations

import numbers

import numpy as np

from .. import bsdfs
from ..haar.tree import ONE_MINUS_EPS, choose_child_reference, level_offset, tree_size
from ..errors import ArgumentError, check_int, check_integers, check_number, check_real, shown

LOBE_BLUR = 0.35 * np.pi     # lobe widening at level l: LOBE_BLUR / 2^l (see kernels/product.h)
PHONG_BLUR = 0.2 * np.pi     # phong's (measured, kernels/product.h)
HORIZON_BLUR = 0.75 * np.pi  # horizon softening at level l: HORIZON_BLUR / 2^l
MAX_KAPPA = 1e6


def _pi_over_powers_of_two():
    k = np.arange(16)
    s, c = np.sin(np.pi / 2.0 ** k), np.cos(np.pi / 2.0 ** k)
    s[:2], c[:2] = (0.0, 1.0), (-1.0, 0.0)   # pi and pi / 2 exactly, as the kernel's literals
    return s.astype(np.float32), c.astype(np.float32)


SIN_PI_2K, COS_PI_2K = _pi_over_powers_of_two()   # sin, cos of pi / 2^k, k = 0..15 (kernels/product.h)


def split_angle(s, c, k):
    """sin and cos of a - pi/2^k and a + pi/2^k from those of a, float32 (kernels/product.h split_angle)."""
    s, c = np.float32(s), np.float32(c)
    sd, cd = SIN_PI_2K[k], COS_PI_2K[k]
    sc, cs, cc, ss = s * cd, c * sd, c * cd, s * sd
    return sc - cs, cc + ss, sc + cs, cc - ss


def centre_angles(x, y, level):
    """sin phi, cos phi, sin theta, cos theta of the centres of nodes (x, y) of `level` (arrays),
    built as kernels/product.h builds them during a walk: from the root's centre (phi = pi,
    theta = pi / 2) the children's by the angle-sum formulas, level by level along the path, in
    float32 (phi = 2 pi (x + 0.5) / 2^level, theta = pi (y + 0.5) / 2^level up to rounding)."""
    where = "strategies.product.centre_angles"
    level = check_int(where, "level", level, 0, len(SIN_PI_2K) - 2)   # split_angle(.., level + 1) below
    x, y = check_integers(where, "x", x, 1 << level), check_integers(where, "y", y, 1 << level)
    sp, cp = np.zeros(x.shape, np.float32), np.full(x.shape, -1.0, np.float32)
    st, ct = np.ones(y.shape, np.float32), np.zeros(y.shape, np.float32)
    for l in range(level):
        right, bottom = (x >> (level - 1 - l)) & 1 == 1, (y >> (level - 1 - l)) & 1 == 1
        s0, c0, s1, c1 = split_angle(sp, cp, l + 1)
        sp, cp = np.where(right, s1, s0), np.where(right, c1, c0)
        s0, c0, s1, c1 = split_angle(st, ct, l + 2)
        st, ct = np.where(bottom, s1, s0), np.where(bottom, c1, c0)
    return sp, cp, st, ct


GGX_HALF = 3                # lobe shape of wide ggx lobes: D at the true half vector (kernels/product.h)
GGX_HALF_MIN_ALPHA = 0.1    # ggx roughness above which GGX_HALF is used (measured, see kernels/product.h)


def _material(where: str, kind, param):
    """A material's kind (bsdfs.TYPES) and parameter (ggx alpha > 0, phong exponent >= 0; lambert's
    is not read), else ArgumentError."""
    kinds = tuple(bsdfs.TYPES.values())
    if isinstance(kind, (bool, np.bool_)) or not isinstance(kind, numbers.Integral) or kind not in kinds:
        names = ", ".join(f"{v} ({k})" for k, v in bsdfs.TYPES.items())
        raise ArgumentError(f"{where}: kind must be one of {names}, got {shown(kind)}")
    if kind == bsdfs.LAMBERT:
        return int(kind), param
    param = check_number(where, "param", param, 0.0)
    if kind in (bsdfs.GGX, bsdfs.PLASTIC) and param == 0.0:
        raise ArgumentError(f"{where}: param (ggx or plastic alpha) must be positive, got 0")
    return int(kind), param


def lobe_shape(kind: int, param: float) -> int:
    """The node-importance model of a material: its kind, or GGX_HALF for ggx with alpha > 0.1;
    plastic's specular lobe as ggx's."""
    kind, param = _material("strategies.product.lobe_shape", kind, param)
    if kind == bsdfs.PLASTIC:   # its specular lobe (its diffuse one: plastic_diffuse_lobe)
        kind = bsdfs.GGX
    return GGX_HALF if kind == bsdfs.GGX and param > GGX_HALF_MIN_ALPHA else int(kind)


def lobe_kappa(kind: int, param: float) -> float:
    """von Mises-Fisher concentration of a material's lobe (0 for lambert)."""
    kind, param = _material("strategies.product.lobe_kappa", kind, param)
    if kind == bsdfs.LAMBERT:
        return 0.0
    if kind == bsdfs.PHONG:
        return float(min(max(param, 0.0), MAX_KAPPA))
    return float(min(1.0 / (2.0 * param * param), MAX_KAPPA))  # the (1 + k x)^-2 profile's k


MIN_PRODUCT_LEVELS = 3  # the cosine lobe is broad: 8 x 8 nodes of 22.5 x 45 degrees resolve it


def product_levels(kappa: float, tree_levels: int, override: int | None = None) -> int:
    """Product depth P: nodes (theta extent pi / 2^l) no wider than half the lobe width 1/sqrt(kappa),
    at least MIN_PRODUCT_LEVELS (lambert, kappa = 0), at most the light tree's depth. An integer
    override wins, clamped to [0, tree_levels]."""
    where = "strategies.product.product_levels"
    kappa = check_number(where, "kappa", kappa, 0.0)
    tree_levels = check_int(where, "tree_levels", tree_levels, 0)
    if override is not None:
        return int(min(max(check_int(where, "override", override), 0), tree_levels))
    if kappa <= 0:
        return min(MIN_PRODUCT_LEVELS, tree_levels)
    # lobe width ~ 1/sqrt(kappa) (phong) or sqrt(2) alpha = 1/sqrt(kappa) (ggx)
    level = int(np.ceil(np.log2(2.0 * np.pi * np.sqrt(kappa))))
    return int(min(max(level, MIN_PRODUCT_LEVELS), tree_levels))


def node_importance(env, mass, x, y, level, axis, n, kappa, shape):
    """I(s) for nodes (x, y) of `level` (arrays), per-sample lobes axis, n (N, 3), kappa, shape (N,)."""
    inv = 1.0 / (1 << level)
    c = np.stack([(x + 0.5) * inv, (y + 0.5) * inv], 1)
    d = env.square_to_world(c)
    r, rp, rh = LOBE_BLUR * inv, PHONG_BLUR * inv, HORIZON_BLUR * inv
    cos_n = np.einsum("ij,ij->i", d, n)
    x1 = 1.0 - np.einsum("ij,ij->i", d, axis)
    with np.errstate(divide="ignore", over="ignore"):
        k = np.where(kappa > 0, 1.0 / (1.0 / np.where(kappa > 0, kappa, 1.0) + r * r), 0.0)
        horizon = np.clip(cos_n / rh + 1.0, 0.0, 1.0)
        ggx = (1.0 / (1.0 + k * x1)) ** 2 * horizon
        # wide ggx: pi D(h) at the true half vector, alpha_l^2 = alpha^2 + r^2 / 2 (1/(2 kappa) = alpha^2)
        wo = 2.0 * np.einsum("ij,ij->i", axis, n)[:, None] * n - axis  # axis is the mirror direction
        h = d + wo
        hn = np.einsum("ij,ij->i", h, n)
        nh2 = np.where(hn > 0, hn * hn / np.einsum("ij,ij->i", h, h), 0.0)
        a2 = 0.5 * (np.where(kappa > 0, 1.0 / np.where(kappa > 0, kappa, 1.0), 0.0) + r * r)
        ggx_half = a2 / (nh2 * (a2 - 1.0) + 1.0) ** 2 * horizon
    hor = np.clip(cos_n + rh, 0.0, 1.0)
    with np.errstate(divide="ignore", over="ignore"):
        kp = np.where(kappa > 0, 1.0 / (1.0 / np.where(kappa > 0, kappa, 1.0) + rp * rp), 0.0)
    phong = (1.0 / (1.0 + 0.125 * kp * x1)) ** 8 * hor  # ~ exp(-k x), 8x cheaper in the kernel than exp
    lobe = np.select([shape == GGX_HALF, shape == bsdfs.GGX, shape == bsdfs.PHONG], [ggx_half, ggx, phong], hor)
    return mass * lobe


LOOKAHEAD_LEVELS = 3  # levels whose child importances sum the grandchildren's (kernels/product.h)


def coefficients_per_walk(levels: int, tree_levels: int) -> int:
    """Product scaling coefficients (eq. 25's first term, one lobe evaluation each) that the
    choices of one walk of product depth ``levels`` use, on a light tree of ``tree_levels``
    levels: the four children of the node it visits at each of its first P = min(levels,
    tree_levels) levels, or their sixteen grandchildren at the LOOKAHEAD_LEVELS coarsest (as
    :func:`_children` and kernels/product.h ``node_importances``); 4P + 36 for P >= 3 on a
    tree of 4 levels or more. The walk's sparse share of the product: phong 200 (P = 7) uses
    64, against the 4^7 = 16 384 leaves of a dense product tree at that depth
    (wavlight.haar.ProductPyramids). (The kernel, eight walks to a vector, evaluates every
    lane to the deepest P of the scene's materials, and the resampling estimator computes
    levels 0 and 1 once per shading point for all its candidates.)"""
    p = min(int(levels), int(tree_levels))
    return sum(16 if (l < LOOKAHEAD_LEVELS and l + 2 <= tree_levels) else 4 for l in range(p))


def _children(tree, env, x, y, level, axis, n, kappa, shape, n_levels, base):
    cside = 2 << level
    first = base + level_offset(level + 1) + (2 * y) * cside + 2 * x
    idx = np.stack([first, first + 1, first + cside, first + cside + 1], 1)
    m = tree[idx].astype(np.float64)
    if level < LOOKAHEAD_LEVELS and level + 2 <= n_levels:
        # look-ahead: a child's importance is the sum of its four children's (level + 2)
        gside = 4 << level
        imp = np.zeros_like(m)
        for k in range(4):
            cx, cy = 2 * x + (k & 1), 2 * y + (k >> 1)
            for j in range(4):
                gx, gy = 2 * cx + (j & 1), 2 * cy + (j >> 1)
                mg = tree[base + level_offset(level + 2) + gy * gside + gx].astype(np.float64)
                imp[:, k] += node_importance(env, mg, gx, gy, level + 2, axis, n, kappa, shape)
    else:
        imp = np.stack([node_importance(env, m[:, k], 2 * x + (k & 1), 2 * y + (k >> 1), level + 1, axis, n,
                                        kappa, shape)
                        for k in range(4)], 1)
    s = imp.sum(1)
    bad = ~(s > 0) | ~np.isfinite(s)
    imp[bad] = m[bad]
    return imp


def _walk_args(where, tree, n_levels, axis, n, kappa, levels, shape, points, name, tree_index):
    """Checked arguments of the product twins (shapes, the tree's depth, tree_index in range)."""
    n_levels = check_int(where, "n_levels", n_levels, 0, 30)
    tree = check_real(where, "tree", tree)
    size = tree_size(n_levels)
    if tree.ndim not in (1, 2) or tree.shape[-1] != size or tree.size == 0:
        raise ArgumentError(f"{where}: tree must be (tree_size(n),) or (T, tree_size(n)) with tree_size({n_levels}) "
                            f"= {size}, got shape {tree.shape}")
    points = check_real(where, name, points)
    if points.ndim != 2 or points.shape[1] != 2:
        raise ArgumentError(f"{where}: {name} must be (N, 2), got shape {points.shape}")
    count = len(points)
    for arg, a, tail in (("axis", axis, (3,)), ("n", n, (3,)), ("kappa", kappa, ()), ("levels", levels, ()),
                         ("shape", shape, ())):
        if np.shape(a) != (count,) + tail:
            raise ArgumentError(f"{where}: {arg} must be {(count,) + tail} like {name}, got shape {np.shape(a)}")
    if count and np.min(check_integers(where, "levels", levels)) < 0:
        raise ArgumentError(f"{where}: levels must be non-negative")
    if tree_index is not None:
        idx = check_integers(where, "tree_index", tree_index, tree.size // size)
        if idx.ndim > 1 or idx.size not in (1, count):
            raise ArgumentError(f"{where}: tree_index must be one index or ({count},), got shape {idx.shape}")
    return n_levels, points


def _offsets(tree_index, count, stride):
    """Per-sample offsets of their light trees in the flat buffer (tree_index * stride)."""
    if tree_index is None:
        return np.zeros(count, np.int64)
    return np.broadcast_to(np.asarray(tree_index, np.int64) * stride, (count,))


def sample_reference(tree, n_levels, env, axis, n, kappa, levels, shape, u, tree_index=None):
    """Product samples: uv (N, 2) on the square and pdf (N,) on the square (numpy twin).

    tree : light masses, one tree (tree_size(n),) or several (T, tree_size(n)); tree_index
    (N,) picks each sample's tree (default 0); axis, n : (N, 3); kappa (N,); levels, shape (N,) int.
    """
    n_levels, u = _walk_args("strategies.product.sample_reference", tree, n_levels, axis, n, kappa, levels, shape, u, "u",
                             tree_index)
    stride = np.shape(tree)[-1]
    tree = np.asarray(tree, np.float64).ravel()
    base = _offsets(tree_index, len(u), stride)
    u = np.clip(np.nan_to_num(np.asarray(u, np.float64), nan=0.0), 0, ONE_MINUS_EPS)  # as clamp_unit
    count = len(u)
    x = np.zeros(count, np.int64)
    y = np.zeros(count, np.int64)
    depth = np.minimum(levels, n_levels)
    with np.errstate(divide="ignore", invalid="ignore"):
        for l in range(n_levels):
            prod = l < depth
            cside = 2 << l
            c = base + level_offset(l + 1) + (2 * y) * cside + 2 * x
            m = np.stack([tree[c], tree[c + 1], tree[c + cside], tree[c + cside + 1]], 1)
            w = m.copy()
            if prod.any():
                w[prod] = _children(tree, env, x[prod], y[prod], l, axis[prod], n[prod], kappa[prod], shape[prod],
                                    n_levels, base[prod])
            go_top, go_left = choose_child_reference(w[:, 0], w[:, 1], w[:, 2], w[:, 3], u)
            y = 2 * y + (~go_top)
            x = 2 * x + (~go_left)
    side = 1 << n_levels
    leaf = np.stack([x, y], 1)
    # float64 (the kernel's float32 leaf point, haar.tree.leaf_point, would put tiny
    # offsets exactly on the leaf's edge, where the direction's round trip may change leaf)
    uv = np.minimum((leaf + np.nan_to_num(u)) / side, np.nextafter((leaf + 1) / side, 0))
    return uv, pdf_reference(tree.reshape(-1, stride), n_levels, env, axis, n, kappa, levels, shape, uv,
                             tree_index)


def pdf_reference(tree, n_levels, env, axis, n, kappa, levels, shape, uv, tree_index=None):
    """Density on the square of the product sampler at points uv (N, 2) (numpy twin of product_pdf);
    tree and tree_index as for :func:`sample_reference`."""
    n_levels, uv = _walk_args("strategies.product.pdf_reference", tree, n_levels, axis, n, kappa, levels, shape, uv, "uv",
                              tree_index)
    stride = np.shape(tree)[-1]
    tree = np.asarray(tree, np.float64).ravel()
    count = len(uv)
    base = _offsets(tree_index, count, stride)
    side = 1 << n_levels
    lx = np.clip(np.floor(uv[:, 0] * side).astype(np.int64), 0, side - 1)
    ly = np.clip(np.floor(uv[:, 1] * side).astype(np.int64), 0, side - 1)
    depth = np.minimum(levels, n_levels)
    p = np.ones(count)
    with np.errstate(divide="ignore", invalid="ignore"):
        for l in range(int(depth.max(initial=0))):
            sel = np.nonzero(l < depth)[0]
            cx, cy = lx[sel] >> (n_levels - l - 1), ly[sel] >> (n_levels - l - 1)
            imp = _children(tree, env, cx >> 1, cy >> 1, l, axis[sel], n[sel], kappa[sel], shape[sel], n_levels,
                            base[sel])
            p[sel] *= imp[np.arange(len(sel)), (cx & 1) + 2 * (cy & 1)] / imp.sum(1)
        nx, ny = lx >> (n_levels - depth), ly >> (n_levels - depth)
        offsets = np.array([level_offset(int(d)) for d in range(n_levels + 1)])
        node = tree[base + offsets[depth] + ny * (1 << depth) + nx]
        leaf = tree[base + level_offset(n_levels) + ly * side + lx]
        return np.where((node > 0) & (tree[base] > 0), p * leaf / node * side * side, 0.0)
