"""The unbiased relit frame on the OpenCL device (kernels/converge.cl): the lighting's tables,
each tile's product trees T1 x L (eq. 17-25) and the shading of its camera samples (eq. 12 with
the mixture of :mod:`wavlight.relight.converge`).

:class:`Lighting` holds one frame lighting's tables on the device (the lighting inside the
texels, :meth:`wavlight.relight.mixture.TexelLight.tables`). :class:`TreeKernel` builds a
tile's trees from the bake file's quantized entries, read where they are mapped
(:class:`wavlight.relight.frame.DeviceEntries`): the coefficients never pass through the host.
:class:`ShadeKernel` shades a pass of a tile's camera samples: the host traces the camera rays
before it and the shadow rays after it (embree), as :mod:`wavlight.integrator` does. Their numpy
twins are :func:`wavlight.relight.converge.tile_trees_reference` and
:func:`wavlight.relight.converge.shade_reference`.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .. import bsdfs, cl, raytrace, rng, textures
from ..envmap import BACKGROUND_MODE
from ..haar.tree import TREE_ORIGIN, host_order, tree_size, tree_stride
from ..raytrace import RayTracer

#: a tile's pixels are eight to a work-item of converge_trees, in block rows of this many pixels
BLOCK_SIDE = 16
_WARMED = set()


class TileTrees(NamedTuple):
    """A tile's product trees on the device: P trees tree_stride(m) floats apart (node 0 at
    TREE_ORIGIN, Morton levels: the layout of :class:`wavlight.haar.HaarTree`), and the pixels'
    relit values G (P, 4) float32 (r, g, b, 0)."""

    buffer: object
    relit: object
    pixels: int
    levels: int

    @property
    def nbytes(self) -> int:
        return 4 * self.pixels * (tree_stride(self.levels) + 4)

    def read(self, queue=None):
        """The trees on the host: pyramids (P, tree_size(m)) float32 (row-major levels, as
        :func:`wavlight.relight.converge.tile_trees_reference` gives them; zeros below a root of
        0, where the kernel writes the root alone) and G (P, 3)."""
        queue = queue or cl.thread_queue()
        m = self.levels
        raw = cl.read(self.buffer, (self.pixels, tree_stride(m)), np.float32, queue)
        relit = cl.read(self.relit, (self.pixels, 4), np.float32, queue)
        nodes = host_order(raw[:, TREE_ORIGIN:TREE_ORIGIN + tree_size(m)], m)
        return np.where(nodes[:, :1] > 0, nodes, np.float32(0)), relit[:, :3]

    def coat_share(self, queue=None) -> np.ndarray:
        """(P,) float32: each pixel's coat share s (relit's fourth value; 0 without plastic), the
        tint of its control variate (kernels/converge.cl)."""
        return cl.read(self.relit, (self.pixels, 4), np.float32, queue or cl.thread_queue())[:, 3]


class Lighting:
    """One lighting's tables on the device (``tables``: :meth:`.mixture.TexelLight.tables`)."""

    def __init__(self, tables: dict):
        self.levels, self.top, self.kbits = int(tables["levels"]), int(tables["top"]), int(tables["kbits"])
        self.map_w = int(tables["map_width"])
        self.map_h, self.map_shift = int(tables["map_height"]), float(tables["map_shift"])   # (the background)
        self.buffers = {name: cl.to_device(np.ascontiguousarray(tables[name])) for name in
                        ("leaf_cdf", "texel_total", "leaf_guide", "texel_cdf", "texel_guide", "columns", "rows",
                         "map", "map_lum",
                         "leaf_masses", "radiance", "omega")}

    def light_args(self) -> tuple:
        """The kernels' LIGHT_ARGS."""
        b = self.buffers
        return (b["leaf_cdf"], b["texel_total"], b["leaf_guide"], b["texel_cdf"], b["texel_guide"], b["columns"],
                b["rows"], b["map"], b["map_lum"], np.uint32(self.map_w), np.uint32(self.top), np.uint32(self.kbits))


def program(levels: int, bits: int, kinds: int, slots: int, candidates: int, control: bool, lattice,
            textures: bool = False, background: str = "nearest", coat: bool = False):
    """kernels/converge.cl built for product trees of ``levels`` levels, entries of ``bits`` bits,
    the material kinds ``kinds`` (bit mask), ``slots`` directions per camera sample,
    ``candidates`` resampled ones (0: none), the control variate or not, the uniforms'
    ``lattice`` (four 24-bit constants), base-colour ``textures`` or not, what misses see
    (``background``: nearest, bilinear or none) and whether the trees add plastic's coat (``coat``;
    memoised per process, :func:`wavlight.cl.program`)."""
    extra = {"BACKGROUND_MODE": BACKGROUND_MODE[background]}
    if coat:
        extra["COAT"] = 1
    return cl.program("converge.cl", N_LEVELS=int(levels), QBITS=int(bits), BSDF_KINDS=int(kinds) or 1,
                      SLOTS=int(slots), CANDIDATES=int(candidates), CONTROL=int(bool(control)),
                      TEXTURES=int(bool(textures)), **extra,
                      OFFSET_RELATIVE=repr(float(np.float32(raytrace.OFFSET_RELATIVE))),
                      **{f"LATTICE{i}": f"{int(a)}u" for i, a in enumerate(lattice)})


class TreeKernel:
    """converge_trees for one bake: its entries on the device (``entries``, the quantized rows and
    their scales), its offset table per block over the coefficients of each product level m
    (made once per m), the pixels' hit scales. ``coat``: plastic's coat, (its entries, its
    offsets over the image's blocks (4^n, blocks), -1 where a block holds none, and the pixels'
    weights 1 / lum(a_p), 0 where a pixel sees no plastic: :func:`wavlight.relight.converge.coat_weights`),
    added to the trees' transfer (a program built with ``coat``); None: no coat."""

    def __init__(self, entries, offsets: np.ndarray, hit_scale: np.ndarray, bake_levels: int, blocks_w: int,
                 image_w: int, coat=None):
        self.entries, self.offsets = entries, offsets
        self.bake_levels, self.blocks_w, self.image_w = int(bake_levels), int(blocks_w), int(image_w)
        self.hit_scale = cl.to_device(np.ascontiguousarray(hit_scale, np.float32))
        self._by_level = {}
        self.coat = coat
        if coat is not None:
            self._coat_weight = cl.to_device(np.ascontiguousarray(coat[2], np.float32))
        else:   # (not read: a program without COAT; -1: no entry)
            self._coat_weight = cl.to_device(np.zeros(8, np.float32))
            self._no_coat = cl.to_device(np.full(8, -1, np.int32))

    @staticmethod
    def _layout(offsets, levels: int, bake_levels: int):
        side, n = 1 << levels, bake_levels
        rows = (np.arange(side)[:, None] * (1 << n) + np.arange(side)[None, :]).reshape(-1)
        return cl.to_device(np.ascontiguousarray(np.asarray(offsets[rows], np.int32).T))

    def block_offsets(self, levels: int):
        """The device's (blocks, 4^m) int32 table: block b's entry of coefficient (row, col) of the
        2^m x 2^m layout (the top-left block of the bake's 2^n x 2^n) at b 4^m + row 2^m + col;
        and the coat's alike (or a table of -1 where there is no coat)."""
        bufs = self._by_level.get(levels)
        if bufs is None:
            coat = (self._layout(self.coat[1], levels, self.bake_levels) if self.coat is not None else self._no_coat)
            bufs = self._by_level[levels] = (self._layout(self.offsets, levels, self.bake_levels), coat)
        return bufs

    def __call__(self, prog, lighting: Lighting, tile, queue=None, into=None) -> TileTrees:
        """The trees of ``tile`` (a :class:`wavlight.relight.converge.Tile`) under ``lighting``, in
        new buffers, or ``into``'s (a TileTrees of the same size), or with ``into="scratch"`` the
        calling thread's scratch buffers (trees used by this thread only, until its next tile)."""
        queue = queue or cl.thread_queue()
        m = lighting.levels
        stride = tree_stride(m)
        P = tile.w * tile.h
        if into == "scratch":
            out, relit = cl.scratch("converge_trees", 4 * P * stride), cl.scratch("converge_relit", 16 * P)
        elif into is not None:
            out, relit = into.buffer, into.relit
        else:
            out, relit = cl.empty(4 * P * stride), cl.empty(16 * P)
        e = self.entries
        ce = self.coat[0] if self.coat is not None else e
        hs = np.float32(float(1 << m) * 4.0 ** (self.bake_levels - m))
        offsets, coat_offsets = self.block_offsets(m)
        cl.kernel(prog, "converge_trees")(
            queue, (-(-2 * BLOCK_SIDE * tile.blocks // cl.WORK_GROUP) * cl.WORK_GROUP,), (cl.WORK_GROUP,),
            offsets, e.scale[0], e.data[0], np.uint32(self.blocks_w), np.uint32(tile.block_row),
            np.uint32(tile.bx0), np.uint32(tile.x0), np.uint32(tile.y0), np.uint32(tile.w), np.uint32(tile.h),
            np.uint32(self.image_w), self.hit_scale, hs, lighting.buffers["leaf_masses"], lighting.buffers["radiance"],
            np.uint32(stride), out, relit, coat_offsets, ce.scale[0], ce.data[0], self._coat_weight)
        return TileTrees(out, relit, P, m)


class ShadeKernel:
    """converge_shade for one scene: its face normals (and shadow-ray offset floors), the shading
    normals' corner rows and table, materials, their albedos and lobe widths on the device, and in
    a textured scene (``textured``) the faces' texture coordinates, the materials' textures and
    the texels (wavlight.textures)."""

    def __init__(self, scene, tracer: RayTracer, lobe_width: np.ndarray):
        rows = np.zeros((max(len(tracer.face_normals), 1), 4), np.float32)
        rows[:len(tracer.face_normals), :3] = tracer.face_normals
        rows[:len(tracer.face_normals), 3] = tracer.face_offset_floor
        materials = scene.face_material if len(scene.face_material) else np.zeros(1, np.int32)
        albedo = np.zeros((len(scene.materials), 4), np.float32)
        albedo[:, :3] = scene.material_albedo
        self.eye = np.asarray(scene.camera.eye, np.float32)
        self.eye_offset = RayTracer.eye_offset_floor(scene.camera.eye)
        corners = tracer.corner_normals if len(tracer.corner_normals) else np.zeros((1, 3), np.int32)
        self.smooth = (cl.to_device(np.ascontiguousarray(corners, np.int32)),
                       cl.to_device(np.ascontiguousarray(tracer.shading_normals, np.float32)), np.int32(tracer.smooth))
        self.tables = (cl.to_device(rows), cl.to_device(np.asarray(materials, np.int32)),
                       cl.to_device(scene.material_kind.astype(np.int32)),
                       cl.to_device(scene.material_param.astype(np.float32)), cl.to_device(albedo),
                       cl.to_device(np.asarray(lobe_width, np.float32)),
                       cl.to_device(np.ascontiguousarray(scene.material_table, np.float32).reshape(-1)
                                    if len(scene.materials) else np.zeros(bsdfs.PLASTIC_STRIDE, np.float32)))
        self.kinds = int(np.bitwise_or.reduce(1 << np.asarray(scene.material_kind, np.int64), initial=0)) or 1
        self.textured = bool(getattr(scene, "textured", False))
        if self.textured:
            texels, table = scene.texture_atlas()
            self.texture_tables = (cl.to_device(textures.face_uv(scene.faces, scene.vertex_uv)),
                                   cl.to_device(scene.material_texture), cl.to_device(texels), cl.to_device(table))
        else:
            dummy = cl.to_device(np.zeros(8, np.float32))
            self.texture_tables = (dummy, cl.to_device(np.full(max(len(scene.materials), 1), -1, np.int32)), dummy,
                                   cl.to_device(np.zeros(4, np.int32)))

    def __call__(self, prog, slots: int, d, prim, t, k: int, first: int, trees: TileTrees, spread, lighting: Lighting,
                  shares, seed: int, tile: int, queue=None, bary=None):
        """One pass of a tile: camera rays along d (N, 3) from the eye that hit prim (N,) (-1: a miss)
        at t (N,), k samples per pixel, pixel-major, the pass's first sample index ``first`` of
        the tile (``tile``: its Philox tile); ``bary`` (N, 2) embree's barycentric (u, v) of the
        hits, for the shading normals and needed in a textured scene (None: every face flat).
        The inputs are uploaded without a wait each (the queue is in order; the read of the
        planes waits for them).
        ``spread`` the tile pixels' footprint spreads on the device, ``shares`` (defensive, light,
        coherence). Returns float32 direct (N, 3),
        origin (N, 3), wi (S, 3, N) and value (S, 3, N) (planes: slot, component, sample)."""
        queue = queue or cl.thread_queue()
        count = len(d)
        S = int(slots)
        out = cl.scratch("converge_out", 4 * (6 + 6 * S) * max(count, 1))
        if self.textured and bary is None and count:
            raise ValueError("converge ShadeKernel: a textured scene needs the hits' barycentric coordinates (bary)")
        if count:
            defensive, light, coherence = shares
            smooth = self.smooth[2] if bary is not None else np.int32(0)
            bary_buf = (cl.upload("converge_bary", np.asarray(bary, np.float32), queue, blocking=False)
                        if bary is not None and (smooth or self.textured) else self.smooth[1])   # (not read)
            cl.kernel(prog, "converge_shade")(
                queue, (cl.items(count, cl.LANES),), (cl.WORK_GROUP,), np.uint32(count), np.uint32(k),
                np.uint32(first), cl.upload("converge_dirs", np.asarray(d, np.float32), queue, blocking=False),
                cl.upload("converge_prim", np.asarray(prim, np.int32), queue, blocking=False),
                cl.upload("converge_t", np.asarray(t, np.float32), queue, blocking=False), *self.eye, self.eye_offset,
                *self.tables[:2],
                bary_buf, *self.smooth, *self.tables[2:], *self.texture_tables, trees.buffer,
                np.uint32(tree_stride(trees.levels)), trees.relit, spread,
                lighting.buffers["leaf_masses"], lighting.buffers["omega"], *lighting.light_args(),
                np.int32(lighting.map_h), np.float32(lighting.map_shift), np.float32(defensive), np.float32(light),
                np.float32(coherence), np.uint32(tile),
                np.uint32(rng.CONVERGE_DIRECTIONS[0]), *(np.uint32(x) for x in rng.key(seed)), out)
        planes = cl.read(out, (6 + 6 * S, count), np.float32, queue)
        return (planes[:3].T, planes[3:6].T, planes[6:6 + 3 * S].reshape(S, 3, count),
                planes[6 + 3 * S:].reshape(S, 3, count))

    def spread(self, prog, d, prim, rays: int, queue=None):
        """converge_spread: the footprint spreads (P,) of P pixels from their ``rays`` grid rays each
        along d (P rays, 3) that hit prim (-1: a miss), on the device (the buffer) and the host."""
        queue = queue or cl.thread_queue()
        count = len(prim) // rays
        out = cl.empty(4 * max(count, 1))
        if count:
            cl.kernel(prog, "converge_spread")(
                queue, (cl.items(count, cl.LANES),), (cl.WORK_GROUP,), np.uint32(count), np.uint32(rays),
                cl.upload("spread_dirs", np.asarray(d, np.float32), queue),
                cl.upload("spread_prim", np.asarray(prim, np.int32), queue), self.tables[0], out)
        return out, cl.read(out, (count,), np.float32, queue)

    def warm_up(self, prog, slots, trees: TileTrees, spread, lighting: Lighting, shares):
        """A tiny and a large launch (PoCL compiles per work-group size and again for large grids:
        wavlight.shading.KernelShader.warm_up), once per process and program, on rays that miss."""
        if prog in _WARMED:
            return
        for count in (1, 1 << 16):
            d = np.tile(np.float32([0.0, 0.0, 1.0]), (count, 1))
            self(prog, slots, d, np.full(count, -1, np.int32), np.ones(count, np.float32), count, 0, trees, spread,
                 lighting, shares, 0, 0, bary=np.zeros((count, 2), np.float32))
        _WARMED.add(prog)
