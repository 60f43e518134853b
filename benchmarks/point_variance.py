"""Direction-sampling error per shading point, without the pixel footprint.

On a unit sphere seen from (0, 0, 4), --points visible shading points spread as the
image spreads them (uniform over the projected disc), each shaded with --samples
independent estimates (both MIS slots, no visibility: a sphere never shadows itself)
by the numpy twins of the strategies (wavlight.strategies.shade_reference). Per point
the relative variance var / (mean^2 + 0.01), mean the average of all strategies'
means; printed as the mean over the points of each strategy's relative variance over
`mis`'s. This is the quantity the product sampler's model decides (the image relMSE
of benchmarks/relmse.py adds the pixel-footprint variance that no direction sampler
removes), and it is how the product model's parameters were chosen.
`wavelet` is the library's default (the resampling estimator with DEFAULT_CANDIDATES = 8
candidates; `wavelet:candidates=0` the MIS pair, which the variants below modify), and
`wavelet:risP+B` that estimator with P product and B BSDF candidates
(wavlight.strategies.ris_shade_reference), `wavelet:control_variate=0` without its control
variate (with it, an unshadowed point's estimate is the candidates' U, no pick).
--strategies may also name other designs of `wavelet` (VARIANTS): wavelet_power (the
power heuristic), wavelet_plain (the plain light tree for lambert too),
wavelet_all_compensated (the compensated tree for every material); and per-point product
tables, the ideals the walk approximates (_table_product): exact_product (the product at
the light tree's leaf resolution, exactly), depth_table (at the walk's product depth P,
the light tree below), depth_table_fine (at P + 1), depth_table_footprint (at P, only
where BRDF x cosine >= 1% of its peak) and depth_table[_fine]_offsetA (the table built
for the point's frame tilted by A degrees: a table per pixel serving the pixel's other
points). Where the walk loses to the tables: coarseC (a table of
the walk's own lobe model, summed exactly, for the first C levels), exact_fineF[_plus1]
(the true BRDF at node centres from level F on, [one level deeper]), centroidS[_geoG]
[_nolook] (the lobe evaluated at each node's light centroid, widened by S x the light's
spread [+ G x the node-size blur]), wavelet_nolook and wavelet_lookK (K look-ahead levels). Strategy options follow the name
(wavelet:levels=9). A name with ":mixS" (wavelet:mix0.9, exact_product:mix0.9) gives
the product the share S of the samples by one-sample MIS instead of the pair. --phong-blur sets
the phong lobe widening of the numpy twin (wavlight.strategies.product PHONG_BLUR, in units of pi;
the kernel's PHONG_BLUR_F must then be set to match before rendering).

Prints one JSON object and writes it, with the run's provenance (benchmarks/provenance.py:
commit, CPU, OpenCL platform, command), to benchmarks/results/point_variance.json unless -o
names another ("-": none).

    python benchmarks/point_variance.py [--maps rooitou_park_1k,...] [--materials phong200,ggx0.05]
                                        [--strategies wavelet,mis_comp,wavelet_power]
                                        [--points 128] [--samples 512] [--phong-blur 0.2,0.35] [-o FILE]

The figures in benchmarks/results/ come from

    python benchmarks/point_variance.py                     # point_variance.json
    python benchmarks/point_variance.py --points 48 --samples 256 \
        --strategies wavelet:candidates=0,wavelet:candidates=0:mix0.9,depth_table,depth_table:mix0.9,depth_table_fine:mix0.9,depth_table_footprint:mix0.9,exact_product \
        -o benchmarks/results/point_variance-tables.json   # the walk against per-point tables
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
MATERIALS = {"phong50": ("phong", 50.0), "phong200": ("phong", 200.0), "phong1000": ("phong", 1000.0),
             "ggx0.05": ("ggx", 0.05), "ggx0.2": ("ggx", 0.2), "lambert": ("lambert", None)}


def _variant(heuristic="balance", compensated="lambert"):
    from wavlight import bsdfs, strategies

    kinds = {"lambert": (bsdfs.LAMBERT,), "none": (), "all": (bsdfs.LAMBERT, bsdfs.PHONG, bsdfs.GGX)}[compensated]
    s = strategies.WaveletStrategy(compensated_kinds=kinds, candidates=0)
    s.heuristic = heuristic
    return s


def _table_product(extra_levels=None, footprint=0.0, offset_degrees=0.0):
    """Per-point product tables: the ideal the product walk approximates, far too slow to
    render with (one table of 4^k entries per shading point).

    extra_levels None: exact_product, light leaf mass x BRDF x cosine at every leaf centre
    of the light tree, sampled by inverse CDF over the leaves, uniform inside the leaf.
    extra_levels e: depth_table, the same at the product depth P + e (node mass x BRDF x
    cosine at the node centre), then the light tree inside the chosen node, as the walk
    continues below P: the walk's target without its level-by-level approximation.
    footprint f > 0 keeps only the nodes whose BRDF x cosine is at least f times the
    table's largest (the lobe's footprint, what a renderer could afford to tabulate).
    offset_degrees > 0 builds each point's table for its shading frame (normal and view
    together) tilted by that angle about a random tangent axis, so the lobe's mirror direction
    moves by that angle: a table per pixel, built at the pixel's centre, serves samples whose
    shading points lie elsewhere in the pixel (on the 96^2 sphere of relmse.py one pixel turns
    the normal by about 1.3 degrees and the mirror direction by 2.6; a sample lies 0.38 pixel
    from the centre on average, about 1 degree of mirror direction)."""
    from wavlight import bsdfs, strategies
    from wavlight.haar.tree import level_offset

    class TableProduct(strategies.WaveletStrategy):
        def prepare(self, environment, materials=()):
            super().prepare(environment, materials)
            n = self.trees.n_levels
            k = n if extra_levels is None else min(max(int(self.levels.max()) + extra_levels, 0), n)
            side = 1 << k
            nodes = self._nodes[0].astype(np.float64)
            self.table_mass = nodes[level_offset(k):level_offset(k) + side * side]
            self.leaf = nodes[level_offset(n):]
            y, x = np.divmod(np.arange(side * side), side)
            self.dirs = environment.square_to_world(np.stack([(x + 0.5) / side, (y + 0.5) / side], 1))
            self.k, self.n, self.side, self.tables = k, n, side, {}

        def _table(self, sp, i):
            key = tuple(sp.p[i]) + tuple(sp.wo[i])
            if key not in self.tables:
                d = self.dirs
                s_, t_, n_ = sp.s[i], sp.t[i], sp.n[i]
                if offset_degrees:
                    rng = np.random.default_rng(abs(hash(key)) % (1 << 32))
                    phi, ang = rng.uniform(0, 2 * np.pi), np.radians(offset_degrees)
                    axis = np.cos(phi) * s_ + np.sin(phi) * t_   # tilt the frame about a tangent axis
                    def rot(v):
                        return (v * np.cos(ang) + np.cross(axis, v) * np.sin(ang)
                                + axis * (axis @ v) * (1 - np.cos(ang)))
                    s_, t_, n_ = rot(s_), rot(t_), rot(n_)
                local = np.stack([d @ s_, d @ t_, d @ n_], 1)
                f = np.nan_to_num(bsdfs.eval_cos(int(sp.kind[i]), np.full(len(d), sp.param[i]), local,
                                                 np.repeat(sp.wo[i:i + 1], len(d), 0)))
                w = self.table_mass * np.where(f >= footprint * f.max(), f, 0.0)
                total = w.sum()
                p = w / total if total > 0 else np.zeros_like(w)
                self.tables[key] = (p, np.cumsum(p))
            return self.tables[key]

        def _groups(self, sp):
            _, first, inverse = np.unique(np.concatenate([sp.p, sp.wo], 1), axis=0, return_index=True,
                                          return_inverse=True)
            return first, inverse.ravel()

        def _inside(self, uv):
            """Density on the square, given its table node, of the light tree below the node
            (4^k for k = n: uniform in the leaf), and the node's index."""
            n, k, ls = self.n, self.k, 1 << self.n
            ij = np.minimum((uv * ls).astype(np.int64), ls - 1)
            node = (ij[:, 1] >> (n - k)) * self.side + (ij[:, 0] >> (n - k))
            mass = self.table_mass[node]
            leaf = self.leaf[ij[:, 1] * ls + ij[:, 0]]
            ok = mass > 0
            return np.where(ok, leaf / np.where(ok, mass, 1.0), 0.0) * ls * ls, node

        def sample(self, sp, u):
            u = np.asarray(u, np.float64)
            node, rx, p_node = np.zeros(len(sp), np.int64), np.zeros(len(sp)), np.zeros(len(sp))
            first, inverse = self._groups(sp)
            for g, i in enumerate(first):
                sel = np.nonzero(inverse == g)[0]
                p, cdf = self._table(sp, i)
                j = np.minimum(np.searchsorted(cdf, u[sel, 0] * cdf[-1], side="right"), len(p) - 1)
                below = np.where(j > 0, cdf[np.maximum(j - 1, 0)], 0.0)
                rx[sel] = np.clip((u[sel, 0] * cdf[-1] - below) / np.where(p[j] > 0, p[j], 1.0), 0, 1 - 1e-9)
                node[sel], p_node[sel] = j, p[j]
            s, ls = 1 << (self.n - self.k), 1 << self.n
            uv = np.zeros((len(sp), 2))
            for j in np.unique(node):   # below the table: inverse CDF over the node's leaves
                sel = np.nonzero(node == j)[0]
                ny, nx = divmod(int(j), self.side)
                block = self.leaf.reshape(ls, ls)[ny * s:(ny + 1) * s, nx * s:(nx + 1) * s].ravel()
                cdf = np.cumsum(block)
                t = rx[sel] * cdf[-1]
                q = np.minimum(np.searchsorted(cdf, t, side="right"), len(block) - 1)
                below = np.where(q > 0, cdf[np.maximum(q - 1, 0)], 0.0)
                fx = np.clip((t - below) / np.where(block[q] > 0, block[q], 1.0), 0, 1 - 1e-9)
                qy, qx = np.divmod(q, s)
                uv[sel] = np.stack([(nx * s + qx + fx) / ls, (ny * s + qy + u[sel, 1]) / ls], 1)
            inside, _ = self._inside(uv)
            d = self.env.square_to_world(uv)
            return strategies.DirectionSamples(d, sp.to_local(d),
                                               p_node * inside * self.env.square_to_solid_angle(d))

        def pdf(self, sp, wi_local, wi_world):
            inside, node = self._inside(self.env.world_to_square(wi_world))
            out = np.zeros(len(sp))
            first, inverse = self._groups(sp)
            for g, i in enumerate(first):
                sel = np.nonzero(inverse == g)[0]
                out[sel] = self._table(sp, i)[0][node[sel]] * inside[sel]
            return out * self.env.square_to_solid_angle(wi_world)

    return TableProduct(compensated_kinds=(), candidates=0)


def _coarse_table(coarse, extra=0):
    """A per-point table for the walk's first `coarse` levels only: the importances of the
    nodes of levels 1..coarse are the sums of the depth-(P + extra) node importances
    (light mass x the walk's lobe model at the node centre) below them, so the coarse
    choices see the product as the full table does; below level `coarse` the walk goes on
    with its own importances. What a per-pixel table of 4^coarse entries would buy."""
    from wavlight import strategies
    from wavlight.strategies import product
    from wavlight.haar.tree import choose_child_reference, level_offset

    class CoarseTable(strategies.WaveletStrategy):
        def prepare(self, environment, materials=()):
            super().prepare(environment, materials)
            self.cache = {}
            self.coarse = min(coarse, int(self.levels.max()))

        def _levels_of(self, sp):
            """Per sample, the table pyramids' levels 1..coarse, stacked over the points: {l: (N, 2^l, 2^l)}.
            One material per run (as main() makes them): every point then has the same depth."""
            key = id(sp)
            if self.cache.get("key") != key:
                if len(np.unique(sp.material)) > 1:
                    raise ValueError("coarse tables: one material per run")
                n = self.trees.n_levels
                axis, kappa, levels, shape = self._lobes(sp, sp.material)
                base = self._bases(sp)
                _, first, inverse = np.unique(np.concatenate([sp.p, sp.wo], 1), axis=0, return_index=True,
                                              return_inverse=True)
                tree = self._nodes.ravel().astype(np.float64)
                stacks = {l: [] for l in range(1, self.coarse + 1)}
                for i in first:
                    d = min(int(levels[i]) + extra, n)
                    side = 1 << d
                    y, x = np.divmod(np.arange(side * side), side)
                    mass = tree[base[i] + level_offset(d) + y * side + x]
                    rep = lambda a: np.repeat(a[i:i + 1], side * side, 0)
                    a = product.node_importance(self.env, mass, x, y, d, rep(axis), rep(sp.n), rep(kappa),
                                                rep(shape)).reshape(side, side)
                    for l in range(d, 0, -1):
                        if l <= self.coarse:
                            stacks[l].append(a)
                        a = a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2]
                self.cache = {"key": key, "group": inverse.ravel(),
                              "levels": {l: np.stack(v) for l, v in stacks.items()}, "keep": sp}
            return self.cache["group"], self.cache["levels"]

        def _weights(self, sp, sel, l, x, y, base):
            """(len(sel), 4) child importances at step l (children on level l + 1)."""
            axis, kappa, levels, shape = self._lobes(sp, sp.material)
            if l < self.coarse:
                group, pyr = self._levels_of(sp)
                a, g = pyr[l + 1], group[sel]
                return np.stack([a[g, 2 * y, 2 * x], a[g, 2 * y, 2 * x + 1], a[g, 2 * y + 1, 2 * x],
                                 a[g, 2 * y + 1, 2 * x + 1]], 1)
            return product._children(self._nodes.ravel().astype(np.float64), self.env, x, y, l, axis[sel], sp.n[sel],
                                     kappa[sel], shape[sel], self.trees.n_levels, base[sel])

        def _bases(self, sp):
            return self.tree_index[sp.material].astype(np.int64) * self.trees.stride

        def _walk_pdf(self, sp, uv):
            n = self.trees.n_levels
            tree = self._nodes.ravel().astype(np.float64)
            base = self._bases(sp)
            _, _, levels, _ = self._lobes(sp, sp.material)
            side = 1 << n
            lx = np.clip((uv[:, 0] * side).astype(np.int64), 0, side - 1)
            ly = np.clip((uv[:, 1] * side).astype(np.int64), 0, side - 1)
            depth = np.minimum(levels, n)
            p = np.ones(len(uv))
            for l in range(int(depth.max())):
                sel = np.nonzero(l < depth)[0]
                cx, cy = lx[sel] >> (n - l - 1), ly[sel] >> (n - l - 1)
                w = self._weights(sp, sel, l, cx >> 1, cy >> 1, base)
                s = w.sum(1)
                p[sel] *= np.where(s > 0, w[np.arange(len(sel)), (cx & 1) + 2 * (cy & 1)] / np.where(s > 0, s, 1), 0)
            nx, ny = lx >> (n - depth), ly >> (n - depth)
            offsets = np.array([level_offset(int(d)) for d in range(n + 1)])
            node = tree[base + offsets[depth] + ny * (1 << depth) + nx]
            leaf = tree[base + level_offset(n) + ly * side + lx]
            with np.errstate(divide="ignore", invalid="ignore"):
                return np.where(node > 0, p * leaf / node * side * side, 0.0)

        def sample(self, sp, u):
            n = self.trees.n_levels
            tree = self._nodes.ravel().astype(np.float64)
            base = self._bases(sp)
            _, _, levels, _ = self._lobes(sp, sp.material)
            u = np.clip(np.asarray(u, np.float64)[:, :2].copy(), 0, 1 - 1e-9)
            x = np.zeros(len(u), np.int64)
            y = np.zeros(len(u), np.int64)
            depth = np.minimum(levels, n)
            for l in range(n):
                cside = 2 << l
                c = base + level_offset(l + 1) + (2 * y) * cside + 2 * x
                w = np.stack([tree[c], tree[c + 1], tree[c + cside], tree[c + cside + 1]], 1)
                prod = np.nonzero(l < depth)[0]
                if len(prod):
                    w[prod] = self._weights(sp, prod, l, x[prod], y[prod], base)
                go_top, go_left = choose_child_reference(w[:, 0], w[:, 1], w[:, 2], w[:, 3], u)
                y = 2 * y + (~go_top)
                x = 2 * x + (~go_left)
            uv = np.minimum((np.stack([x, y], 1) + u) / (1 << n), 1 - 1e-9)
            d = self.env.square_to_world(uv)
            return strategies.DirectionSamples(d, sp.to_local(d), self._walk_pdf(sp, uv) * self.env.square_to_solid_angle(d))

        def pdf(self, sp, wi_local, wi_world):
            return self._walk_pdf(sp, self.env.world_to_square(wi_world)) * self.env.square_to_solid_angle(wi_world)

    return CoarseTable(candidates=0)


def _exact_importance(mass, d, axis, n, kappa, shape):
    """mass x the true BRDF x cosine at directions d (world), from the walk's lobe arguments
    (axis the mirror direction, kappa = n for phong, 1 / (2 alpha^2) for ggx)."""
    from wavlight import bsdfs

    dot = lambda a, b: np.einsum("ij,ij->i", a, b)
    cos_i = dot(d, n)
    wo = 2.0 * dot(axis, n)[:, None] * n - axis
    cos_o = dot(wo, n)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        phong = (kappa + 2) / (2 * np.pi) * np.maximum(dot(d, axis), 0) ** kappa * np.maximum(cos_i, 0)
        a2 = 1.0 / (2.0 * np.where(kappa > 0, kappa, 1.0))
        h = d + wo
        h /= np.linalg.norm(h, axis=1, keepdims=True)
        ch = dot(h, n)
        D = np.where(ch > 0, a2 / (np.pi * (ch * ch * (a2 - 1) + 1) ** 2), 0)
        g1 = lambda c: np.where(c > 0, 2 / (1 + np.sqrt(1 + a2 * np.maximum(1 - c * c, 0) / np.maximum(c * c, 1e-30))), 0)
        ggx = np.where((cos_i > 0) & (cos_o > 0) & (dot(d, h) > 0), D * g1(cos_i) * g1(cos_o) / (4 * np.maximum(cos_o, 1e-12)), 0)
        lam = np.maximum(cos_i, 0) / np.pi
    lobe = np.select([shape == bsdfs.PHONG, (shape == bsdfs.GGX) | (shape == 3)], [phong, ggx], lam)
    return mass * np.nan_to_num(lobe)


def _patched(patches, prepare=None):
    """A `wavelet` strategy (the MIS pair) whose sample and pdf run with names of wavlight.strategies.product replaced:
    patches(strategy) -> {name: value}; prepare(strategy) runs after its own prepare."""
    from wavlight import strategies
    from wavlight.strategies import product

    class Patched(strategies.WaveletStrategy):
        def prepare(self, environment, materials=()):
            super().prepare(environment, materials)
            if prepare is not None:
                prepare(self)

        def _run(self, fn, *args):
            new = patches(self)
            saved = {k: getattr(product, k) for k in new}
            for k, v in new.items():
                setattr(product, k, v)
            try:
                return fn(*args)
            finally:
                for k, v in saved.items():
                    setattr(product, k, v)

        def sample(self, sp, u):
            return self._run(super().sample, sp, u)

        def pdf(self, sp, wi_local, wi_world):
            return self._run(super().pdf, sp, wi_local, wi_world)

    return Patched(candidates=0)


def _exact_fine(first_level, plus=0):
    """`wavelet` whose node importances on levels >= first_level use the true BRDF x cosine at
    the node centre (no lobe model, no widening); plus > 0 deepens the product by that many levels."""
    from wavlight.strategies import product

    model = product.node_importance

    def importance(env, mass, x, y, level, axis, n, kappa, shape):
        if level < first_level:
            return model(env, mass, x, y, level, axis, n, kappa, shape)
        inv = 1.0 / (1 << level)
        d = env.square_to_world(np.stack([(x + 0.5) * inv, (y + 0.5) * inv], 1))
        return _exact_importance(mass, d, axis, n, kappa, shape)

    def deeper(s):
        s.levels = np.minimum(s.levels + plus, s.trees.n_levels).astype(np.int32)
    return _patched(lambda s: {"node_importance": importance}, deeper)


def _centroid(spread=1.0, lookahead=True, horizon="node", geometric=0.0):
    """`wavelet` whose node importances evaluate the lobe at the node's light centroid (the
    mass-weighted mean direction of its leaves) instead of its centre, widened by the light's
    own spread in the node, 1 - |mean vector| / mass (a von Mises-Fisher light of
    1/kappa_L ~ 1 - rho: the product of two such lobes widens as 1/kappa + 1/kappa_L),
    times `spread` (plus `geometric` times the node-size blur). lookahead False: no
    look-ahead levels."""
    from wavlight.strategies import product
    from wavlight.haar.tree import level_offset

    def vectors(s):
        """Per level, the mass-weighted sums of the leaf directions below each node, of the first
        light tree: for scenes of one tree (one material per run, as main() makes them)."""
        if s.trees.n_trees != 1:
            raise ValueError("centroid: one light tree per run")
        n = s.trees.n_levels
        side = 1 << n
        y, x = np.divmod(np.arange(side * side), side)
        d = s.env.square_to_world(np.stack([(x + 0.5) / side, (y + 0.5) / side], 1))
        leaf = s._nodes[0, level_offset(n):].astype(np.float64)
        s.vectors = {n: (leaf[:, None] * d).reshape(side, side, 3)}
        for lv in range(n - 1, -1, -1):
            a = s.vectors[lv + 1]
            s.vectors[lv] = a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2]

    def patches(s):
        def importance(env, mass, x, y, level, axis, n, kappa, shape):
            v = s.vectors[level][y, x]
            length = np.linalg.norm(v, axis=1)
            ok = (mass > 0) & (length > 0)
            inv = 1.0 / (1 << level)
            centre = env.square_to_world(np.stack([(x + 0.5) * inv, (y + 0.5) * inv], 1))
            d = np.where(ok[:, None], v / np.where(ok, length, 1.0)[:, None], centre)
            rho = np.where(ok, length / np.where(ok, mass, 1.0), 1.0)
            r2 = spread * np.maximum(1.0 - rho, 0.0) + geometric * (product.LOBE_BLUR * inv) ** 2
            rh = product.HORIZON_BLUR * inv if horizon == "node" else np.sqrt(2 * r2) * horizon
            cos_n = np.einsum("ij,ij->i", d, n)
            x1 = 1.0 - np.einsum("ij,ij->i", d, axis)
            with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
                ik = np.where(kappa > 0, 1.0 / np.where(kappa > 0, kappa, 1.0), 0.0)
                k = np.where(kappa > 0, 1.0 / (ik + r2), 0.0)
                hz = np.clip(cos_n / np.maximum(rh, 1e-6) + 1.0, 0.0, 1.0)
                ggx = (1.0 / (1.0 + k * x1)) ** 2 * hz
                wo = 2.0 * np.einsum("ij,ij->i", axis, n)[:, None] * n - axis
                h = d + wo
                hn = np.einsum("ij,ij->i", h, n)
                nh2 = np.where(hn > 0, hn * hn / np.einsum("ij,ij->i", h, h), 0.0)
                a2 = 0.5 * (ik + r2)
                ggx_half = a2 / (nh2 * (a2 - 1.0) + 1.0) ** 2 * hz
                hor = np.clip(cos_n + rh, 0.0, 1.0)
                phong = (1.0 / (1.0 + 0.125 * k * x1)) ** 8 * hor
            lobe = np.select([shape == product.GGX_HALF, shape == 2, shape == 1], [ggx_half, ggx, phong], hor)
            return mass * np.nan_to_num(lobe)
        return {"node_importance": importance, **({} if lookahead else {"LOOKAHEAD_LEVELS": 0})}
    return _patched(patches, vectors)


def _lookahead(levels=0):
    """`wavelet` with `levels` look-ahead levels (0: none)."""
    return _patched(lambda s: {"LOOKAHEAD_LEVELS": levels})


# other designs of `wavelet`, for comparison: the power heuristic (as `mis` weighs), the
# plain light tree for lambert too, the compensated tree for every material; and the
# per-point tables and refinements of the walk (the yardsticks above)
VARIANTS = {"wavelet_power": lambda: _variant(heuristic="power", compensated="none"),
            "wavelet_plain": lambda: _variant(compensated="none"),
            "wavelet_all_compensated": lambda: _variant(compensated="all"),
            "exact_product": _table_product,
            "depth_table": lambda: _table_product(0), "depth_table_fine": lambda: _table_product(1),
            "depth_table_footprint": lambda: _table_product(0, footprint=0.01),
            **{f"depth_table_offset{a}": (lambda a=a: _table_product(0, offset_degrees=a)) for a in (0.35, 0.7, 1.4)},
            **{f"depth_table_fine_offset{a}": (lambda a=a: _table_product(1, offset_degrees=a)) for a in (0.35, 0.7, 1.4)},
            "coarse2": lambda: _coarse_table(2), "coarse3": lambda: _coarse_table(3),
            "coarse4": lambda: _coarse_table(4), "coarse5": lambda: _coarse_table(5),
            "coarse6": lambda: _coarse_table(6), "coarse7": lambda: _coarse_table(7),
            **{f"exact_fine{f}": (lambda f=f: _exact_fine(f)) for f in range(1, 11)},
            **{f"exact_fine{f}_plus1": (lambda f=f: _exact_fine(f, 1)) for f in range(1, 11)},
            **{f"centroid{c}": (lambda c=c: _centroid(c)) for c in (0.1, 0.25, 0.5, 1, 2, 4, 8)},
            **{f"centroid{c}_nolook": (lambda c=c: _centroid(c, False)) for c in (0.1, 0.25, 0.5, 1, 2, 4, 8)},
            **{f"centroid{c}_geo{g}": (lambda c=c, g=g: _centroid(c, geometric=g)) for c in (0.1, 0.25, 0.5, 1)
               for g in (0.25, 0.5, 1)},
            **{f"centroid{c}_geo{g}_nolook": (lambda c=c, g=g: _centroid(c, False, geometric=g))
               for c in (0.1, 0.25, 0.5, 1) for g in (0.25, 0.5, 1)},
            "wavelet_nolook": lambda: _lookahead(),
            **{f"wavelet_look{k}": (lambda k=k: _lookahead(k)) for k in range(1, 6)}}


def mixture_estimates(strategy, env, sp, u, share):
    """One-sample MIS (Veach's one-sample model) instead of the strategy's pair: each of the two
    slots draws from the product with probability `share`, else from the BSDF (the choice made
    with u.x, rescaled), and weighs f L cos / (share p_product + (1 - share) p_bsdf); the two
    slots are averaged. Returns (N, 2, 3) like shade_reference, summing to the estimate."""
    from wavlight import strategies
    from wavlight.strategies.base import unoccluded

    out = np.zeros((len(sp), 2, 3))
    for slot in range(2):
        uu = u[:, 2 * slot:2 * slot + 2]
        pick = uu[:, 0] < share
        up, ub = uu.copy(), uu.copy()
        up[:, 0] = np.minimum(uu[:, 0] / share, 1 - 1e-9)
        ub[:, 0] = np.clip((uu[:, 0] - share) / (1 - share), 0, 1 - 1e-9)
        a, b = strategy.sample(sp, up), strategy.bsdf.sample(sp, ub)
        ds = strategies.DirectionSamples(np.where(pick[:, None], a.wi_world, b.wi_world),
                                         np.where(pick[:, None], a.wi_local, b.wi_local), np.where(pick, a.pdf, b.pdf))
        p_prod = np.where(pick, a.pdf, strategy.pdf(sp, ds.wi_local, ds.wi_world))
        p_bsdf = np.where(pick, strategy.bsdf.pdf(sp, ds.wi_local, ds.wi_world), b.pdf)
        with np.errstate(divide="ignore", invalid="ignore"):
            w = np.where(ds.pdf > 0, ds.pdf / (share * p_prod + (1 - share) * p_bsdf), 0.0)
        out[:, slot] = 0.5 * unoccluded(sp, env, ds, w)
    return out


def sphere_points(scene, count, rng):
    """count visible points of the unit sphere (uniform over the projected disc) as ShadingPoints."""
    from wavlight import strategies, warp

    xy = rng.random((3 * count, 2)) * 2 - 1
    xy = xy[(xy ** 2).sum(1) < 0.97][:count]
    n = np.concatenate([xy, np.sqrt(1 - (xy ** 2).sum(1, keepdims=True))], 1)
    wo = np.array([0.0, 0.0, 4.0]) - n
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    m = scene.materials[0]

    def points(idx):
        s, t = warp.frame(n[idx])
        k = len(idx)
        return strategies.ShadingPoints(p=n[idx], n=n[idx], s=s, t=t, wo=warp.to_local(wo[idx], s, t, n[idx]),
                                        kind=np.full(k, m.kind), param=np.full(k, m.param),
                                        albedo=np.tile(m.albedo, (k, 1)), material=np.zeros(k, np.int64))
    return len(n), points


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--maps", default="rooitou_park_1k,st_fagans_interior_1k,potsdamer_platz_1k")
    ap.add_argument("--materials", default="phong200,ggx0.05,ggx0.2")
    ap.add_argument("--strategies", default="wavelet,mis_comp")
    ap.add_argument("--phong-blur", default="", help="comma-separated phong lobe widenings (units of pi)")
    ap.add_argument("--points", type=int, default=128)
    ap.add_argument("--samples", type=int, default=512)
    sys.path.insert(0, HERE)
    import needs
    from provenance import add_output_argument, provenance, write_result

    add_output_argument(ap, "point_variance")
    args = ap.parse_args()
    prov = provenance()
    needs.fetch("point_variance", *args.maps.split(","))

    import wavlight
    from wavlight import strategies
    from wavlight.strategies import product

    blurs = [float(b) for b in args.phong_blur.split(",")] if args.phong_blur else [product.PHONG_BLUR / np.pi]
    out = {"points": args.points, "samples": args.samples, "phong_blur_pi": blurs, "cases": {}}
    for env_name in args.maps.split(","):
        for mat_name in args.materials.split(","):
            kind, param = MATERIALS[mat_name]
            key = {"phong": "exponent", "ggx": "roughness"}.get(kind)
            mat = {"type": kind, "albedo": [0.9, 0.9, 0.9], **({key: param} if key else {})}
            scene = wavlight.load_dict({
                "environment": {"file": f"data:{env_name}"},
                "camera": {"eye": [0.0, 0.0, 4.0], "target": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0], "fov_y": 32.0},
                "objects": [{"shape": "sphere", "center": [0.0, 0.0, 0.0], "radius": 1.0, "material": "m"}],
                "materials": {"m": mat}})
            env = scene.environment
            count, points = sphere_points(scene, args.points, np.random.default_rng(7))
            idx = np.repeat(np.arange(count), args.samples)
            sp = points(idx)
            u = np.random.default_rng(11).random((len(idx), 4))

            def estimates(strategy, share=None):
                strategy.prepare(env, scene.materials)
                if share is None:   # (the whole estimate: the control variate's offset too)
                    _, val, off = strategies.shade_reference(strategy, env, sp, u, with_offset=True)
                    return (val.sum(1) + off).mean(1).reshape(count, args.samples)
                val = mixture_estimates(strategy, env, sp, u, share)
                return val.sum(1).mean(1).reshape(count, args.samples)

            def make(spec):
                """'wavelet', 'wavelet:levels=9' (strategy options) or a VARIANTS name."""
                base, *opts = spec.split(":")
                if base in VARIANTS:
                    if opts:
                        sys.exit(f"point_variance: {spec}: options apply to strategies, not to {base}")
                    return VARIANTS[base]()
                return strategies.make(base, **{k: bool(int(v)) if k == "control_variate" else int(v)
                                                for k, v in (o.split("=") for o in opts)})

            runs = {"mis": estimates(strategies.make("mis"))}
            for name in args.strategies.split(","):
                base, _, share = name.partition(":mix")
                rbase, _, ris = name.partition(":ris")
                if ris:
                    mp, mb = (int(x) for x in ris.split("+"))
                    strat = make(rbase)
                    strat.prepare(env, scene.materials)
                    _, val, off = strategies.ris_shade_reference(strat, env, sp, u.astype(np.float32),
                                                                 split=(mp, mb), with_offset=True)
                    runs[name] = (val.sum(1) + off).mean(1).reshape(count, args.samples)
                elif share:
                    runs[name] = estimates(make(base), float(share))
                elif name in VARIANTS:
                    runs[name] = estimates(VARIANTS[name]())
                elif name == "wavelet" and kind == "phong":
                    for b in blurs:
                        saved, product.PHONG_BLUR = product.PHONG_BLUR, b * np.pi
                        try:
                            runs[f"wavelet phong_blur={b}"] = estimates(strategies.make("wavelet"))
                        finally:
                            product.PHONG_BLUR = saved
                else:
                    runs[name] = estimates(make(name))
            mean = np.mean([r.mean(1) for r in runs.values()], axis=0)
            rel = {k: r.var(1) / (mean ** 2 + 1e-2) for k, r in runs.items()}
            row = {k: round(float(v.mean() / rel["mis"].mean()), 4) for k, v in rel.items() if k != "mis"}
            row["mis_relative_variance"] = round(float(rel["mis"].mean()), 5)
            out["cases"][f"sphere/{mat_name}/{env_name}"] = row
            print(f"sphere/{mat_name}/{env_name}: {row}", file=sys.stderr, flush=True)
    print(json.dumps(out, indent=1))
    write_result(args.output, out, prov)


if __name__ == "__main__":
    main()
