"""The bake: each pixel's transfer T1 = f_r cos V on the world-frame lat-long square, the fixed
factor of a relit frame (Chen & Gao sec. 2.2, eq. 6-8, with the lighting as T2).

For pixel p with camera samples s = 1..S (jittered in the pixel, stratified over it) and
texel t of solid angle Omega_t,

    T_p,t = (1 / S) sum_s  ratio_s  integral over t of  f_s(w, wo_s) cos(theta) V(x_s, w) dw,

f without its albedo (lambert, normalized phong and the ggx conductor here are albedo x shape),
the pixel's albedo a_p stored apart (the mean albedo of its samples that hit, albedo_s the
sample's material's albedo times its base-colour texture at the hit where it has one; ratio_s =
lum(albedo_s) / lum(a_p), so that luminance is exact where a pixel mixes materials or texels and
only its chroma is the mean's). A frame is then a_p sum_t T_p,t L_t with L_t the lighting's mean
radiance over texel t (:mod:`wavlight.relight.lighting`), plus (1 / S) sum over the samples
that miss of the environment in their direction (a bit mask per pixel; the frame draws the
same camera samples again).

Plastic (Mitsuba 3's roughplastic, ``nonlinear`` false) is not albedo x shape: f cos = coat +
albedo x base, linear in the albedo. T takes its base (the part the albedo multiplies), and a
bake that varies the lighting estimates a second transfer, the coat's,

    C_p,t = (1 / S) sum over the samples on plastic of  integral over t of  f_coat cos V dw,

without the albedo (its pass of the texel kernel, ``part`` 1, with its own uniforms and shadow
rays), stored for the blocks that see plastic (:data:`wavlight.relight.store.COAT_SECTIONS`):
a frame is a_p sum_t T_p,t L_t + sum_t C_p,t L_t (docs/decisions/plastic-in-the-bake.md).

Estimator (kernels/relight.cl, bake_texel_rays; numpy twin :func:`texel_rays_reference`):
one shadow ray per (pixel, texel) pair. The pixel's samples are grouped by the triangle they
hit (one normal and material per group: :class:`PixelSamples`; on a face shaded smooth, where
the shading normal varies over the triangle, each sample is a group of its own); the texel gets
four points
stratified 2 x 2 and uniform in solid angle; f cos is evaluated for every group at every point
(weighted by the group's share of the pixel's samples), and the ray goes from a sample of the
group picked with probability f / sum f towards its point; the estimate Omega_t (sum f / 4) V
is unbiased for the pixel's mean of the texel's four-point quadrature of f cos V over its
footprint, and exact where V is the same over texel and pixel: only the visibility's variance is
left, and the cost grows with the triangles a pixel sees (with its samples on smooth faces).
Texels where the BRDF is 0 (below the horizon, outside a phong lobe, below the geometric surface:
docs/decisions/shading-normals.md) cost no ray. The texels then go
through the Haar transform (:func:`wavlight.haar.forward_cl`), and a block of BLOCK x BLOCK
pixels is compressed and quantized (:mod:`wavlight.relight.store`).
"""
from __future__ import annotations

import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from .. import bsdfs, cl, haar, rng
from ..camera import camera_rays
from ..envmap import LUMINANCE
from ..errors import ArgumentError, shown
from ..integrator import render_full
from ..raytrace import RayTracer
from ..scene import check_scene, load_scene, require_untextured
from ..threads import default_threads
from ..warp import frame as tangent_frame
from . import lighting, store
from .dask import bake_on_cluster
from .settings import BAKE, LOBE_SPACINGS, SPP_CHOICES
from .transfer import finish_bake

#: a block is BLOCK x BLOCK pixels: one tile of the bake, one unit of storage (the file format's)
BLOCK = store.BLOCK


@dataclass
class PixelSamples:
    """The camera samples of a tile's P pixels, S each, and their groups.

    A group is the samples of one pixel that hit one flat triangle (one normal, one material: f
    depends on the sample only through its view direction, whose spread over a pixel is
    negligible), or one sample on a smooth face (its own shading normal), so a texel needs one
    BRDF evaluation per group and point, not per sample.
    Group j of pixel p sits at p S + j (count[p] of them): normal (the shading normal),
    geometric (the face's normal towards the viewer: no light from below it), wo (its members'
    mean view direction), kind, param, weight (sum of its members' albedo ratios / S), first and
    size (its members: members[p S + first .. + size - 1], sample indices p S + s).

    origin (P S, 3) float32: each sample's shadow-ray origin; albedo (P, 3) float32 a_p;
    miss (P,) uint64, bit s set where sample s misses; dirs (P S, 3) float32 the samples'
    directions. Plastic (not albedo x shape): material, each group's material (its row of
    ``table``, the scene's plastic table, :attr:`wavlight.scene.Scene.material_table`), and
    coat_weight, a plastic group's share of the pixel's samples (size / S; 0 for the other
    kinds), the weight of the coat's transfer, which the albedo does not multiply.
    """

    samples: int
    count: np.ndarray
    normal: np.ndarray
    geometric: np.ndarray
    wo: np.ndarray
    kind: np.ndarray
    param: np.ndarray
    weight: np.ndarray
    first: np.ndarray
    size: np.ndarray
    members: np.ndarray
    origin: np.ndarray
    albedo: np.ndarray
    miss: np.ndarray
    dirs: np.ndarray
    material: np.ndarray | None = None
    coat_weight: np.ndarray | None = None
    table: np.ndarray | None = None

    def __len__(self):
        return len(self.albedo)

    @property
    def has_coat(self) -> bool:
        """Whether some group is plastic (the tile has a coat's transfer)."""
        return self.coat_weight is not None and bool(np.any(self.coat_weight > 0))


def camera_jitter(seed: int, tile: int, pixels: int, samples: int, first: int = 0) -> np.ndarray:
    """(P S, 2) float32: the jitters of a tile's camera samples first .. first + P S - 1 (Philox
    stream JITTER, stratified over each pixel's S samples as the stratified sampler does,
    :mod:`wavlight.sampler`)."""
    return rng.Stream(seed, tile, first, samples).uniforms(rng.JITTER, pixels * samples)[:, :2]


def camera_samples(scene, tracer, width, height, x0, y0, w, h, samples: int, seed: int, tile: int,
                   at=None) -> PixelSamples:
    """S jittered camera samples per pixel of the w x h tile at (x0, y0), traced to their hits
    and grouped by pixel and triangle. ``at`` = (columns, rows): the image column of each of
    the tile's columns x0 + i and the image row of each row y0 + j (a sparse grid of the
    width x height image's own pixels, as the pilot bake takes them); default the tile itself."""
    P, S = w * h, samples
    count = P * S
    pix = np.arange(P)
    px, py = x0 + pix % w, y0 + pix // w
    if at is not None:
        px, py = np.asarray(at[0])[px], np.asarray(at[1])[py]
    px, py = np.repeat(px, S), np.repeat(py, S)
    eye, d = camera_rays(scene, px, py, camera_jitter(seed, tile, P, S), width, height)
    textured = getattr(scene, "textured", False)
    prim, t, bu, bv = tracer.intersect_uv(eye, d)
    hit = prim >= 0
    normal = np.zeros((count, 3), np.float32)
    geometric = np.zeros((count, 3), np.float32)
    origin = np.zeros((count, 3), np.float32)
    if hit.any():
        normal[hit], geometric[hit], _, origin[hit] = tracer.hit(scene.camera.eye, d[hit], t[hit], prim[hit], bu[hit],
                                                                 bv[hit])
    mat = np.where(hit, scene.face_material[np.maximum(prim, 0)] if len(scene.face_material) else 0, 0)
    albedo_s = np.where(hit[:, None], scene.material_albedo[mat], 0.0)
    if textured and hit.any():   # the sample's albedo times its material's texture there
        albedo_s[hit] = scene.albedo_at(prim[hit], bu[hit], bv[hit])
    hits = hit.reshape(P, S).sum(1)
    albedo = (albedo_s.reshape(P, S, 3).sum(1) / np.maximum(hits, 1)[:, None]).astype(np.float32)
    lum_p = np.repeat(albedo @ LUMINANCE, S)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(lum_p > 0, (albedo_s @ LUMINANCE) / lum_p, 0.0)
    # groups: a pixel's hits on one flat triangle, or one hit on a smooth face, in order of
    # (pixel, triangle or sample)
    sample = np.arange(count)
    live = sample[hit]
    smooth = np.any(tracer.corner_normals[np.maximum(prim, 0)] < len(tracer.shading_normals) - 1, axis=1)
    key = np.where(smooth, tracer.n_faces + sample, prim).astype(np.int64)
    order = live[np.lexsort((key[live], live // S))]
    pixel_of = order // S
    new = np.ones(len(order), bool)
    new[1:] = (pixel_of[1:] != pixel_of[:-1]) | (key[order][1:] != key[order][:-1])
    starts = np.flatnonzero(new)
    sizes = np.diff(np.append(starts, len(order)))
    gpix = pixel_of[starts]
    rank = np.arange(len(starts)) - np.searchsorted(gpix, gpix)     # the group's index in its pixel
    slot = gpix * S + rank
    group_count = np.bincount(gpix, minlength=P).astype(np.uint32)
    members = np.zeros(count, np.uint32)
    within = np.arange(len(order)) - np.repeat(starts, sizes)        # position inside the group
    members[np.repeat(gpix * S, sizes) + np.repeat(starts - np.searchsorted(pixel_of, gpix), sizes) + within] = order
    first = np.zeros(count, np.uint32)
    first[slot] = starts - np.searchsorted(pixel_of, gpix)
    size = np.zeros(count, np.uint32)
    size[slot] = sizes
    g_normal = np.zeros((count, 3), np.float32)
    g_normal[slot] = normal[order[starts]]
    g_geometric = np.zeros((count, 3), np.float32)
    g_geometric[slot] = geometric[order[starts]]
    wo_sum = np.add.reduceat(-d[order].astype(np.float64), starts, axis=0) if len(order) else np.zeros((0, 3))
    g_wo = np.zeros((count, 3), np.float32)
    g_wo[slot] = wo_sum / np.linalg.norm(wo_sum, axis=1, keepdims=True)
    g_kind = np.zeros(count, np.int32)
    g_kind[slot] = scene.material_kind[mat[order[starts]]]
    g_param = np.zeros(count, np.float32)
    g_param[slot] = scene.material_param[mat[order[starts]]]
    g_weight = np.zeros(count, np.float32)
    g_weight[slot] = (np.add.reduceat(ratio[order], starts) if len(order) else np.zeros(0)) / S
    g_material = np.zeros(count, np.int32)
    g_material[slot] = mat[order[starts]]
    g_coat = np.where(g_kind == bsdfs.PLASTIC, size / np.float32(S), 0.0).astype(np.float32)
    missed = (~hit).reshape(P, S).astype(np.uint64)
    mask = (missed << np.arange(S, dtype=np.uint64)).sum(1, dtype=np.uint64)
    return PixelSamples(S, group_count, g_normal, g_geometric, g_wo, g_kind, g_param, g_weight, first, size,
                        members, origin, albedo, mask, d, g_material, g_coat, getattr(scene, "material_table", None))


#: points per texel where f cos is evaluated (kernels/relight.cl TEXEL_POINTS): g x g strata
POINT_CHOICES = BAKE["points"].values
POINT_GRID = {1: 1, 4: 2, 16: 4}


def texel_points(scene, n_levels: int) -> int:
    """Points per texel a scene needs at 2^n x 2^n texels: g x g, the fewest (g = 1, 2, 4) whose
    spacing puts LOBE_SPACINGS of them across the scene's narrowest lobe (at most 16). The
    point's jitter is the texel integral's noise; a coarser texel gets more points, so that
    the noise is about that of the finer texels it sums (the pilot measures those)."""
    texel = np.pi / (1 << n_levels)
    # plastic's coat is a ggx lobe of its alpha (its own transfer: :data:`PARTS`)
    lobe = min((float(bsdfs.lobe_width(bsdfs.GGX if m.kind == bsdfs.PLASTIC else m.kind, m.param))
                for m in scene.materials), default=np.pi / 2)
    for grid in (1, 2, 4):   # three choices
        if texel / grid * LOBE_SPACINGS <= lobe:
            return grid * grid
    return 16


def texel_rays_reference(ps: PixelSamples, n_levels: int, seed: int, tile: int, first: int = 0,
                         count: int | None = None, points: int = 4, part: int = 0):
    """numpy twin of ``bake_texel_rays``: directions (C, 3), weights (C,) and the picked samples
    (C,) of pairs first .. first + C - 1 (float64; the kernel's float32 agrees to rounding and
    picks the same point unless a reservoir step lies within rounding of its threshold; each
    step draws its own uniform, :func:`wavlight.rng.step_uniforms`). ``part`` 0: the transfer
    the albedo multiplies (plastic's diffuse base); 1: plastic's coat (:data:`PARTS`)."""
    side, S = 1 << n_levels, ps.samples
    count = len(ps) * side * side - first if count is None else count
    g = np.arange(first, first + count, dtype=np.int64)
    p, t = g >> (2 * n_levels), g & (side * side - 1)
    row, col = t >> n_levels, t & (side - 1)
    u = rng.uniforms(seed, tile, PARTS[part], first, count).astype(np.float64)
    weights = ps.coat_weight if part else ps.weight
    material = ps.material if ps.material is not None else np.zeros(len(ps.kind), np.int32)
    z0, z1 = np.cos(np.pi * row / side), np.cos(np.pi * (row + 1) / side)
    directions = []
    grid = POINT_GRID[points]
    for q in range(points):   # the texel's strata, not pairs
        uu = (col + ((q % grid) + u[:, 0]) / grid) / side
        zz = z0 + ((q // grid) + u[:, 1]) / grid * (z1 - z0)
        sn = np.sqrt(np.maximum(1.0 - zz * zz, 0.0))
        directions.append(np.stack([np.sin(2 * np.pi * uu) * sn, zz, -np.cos(2 * np.pi * uu) * sn], 1))
    total = np.zeros(count)
    key = (u[:, 2].astype(np.float64) * 2.0 ** 24).astype(np.uint32)
    step = 0
    pick_dir = directions[0].copy()
    picked = p * S
    groups = ps.count[p]
    for j in range(int(ps.count.max(initial=0))):   # groups, not pairs
        on = j < groups
        gj = p * S + j
        n = ps.normal[gj].astype(np.float64)
        geo = ps.geometric[gj].astype(np.float64)
        sx, tx = tangent_frame(np.where(on[:, None], n, [0.0, 0.0, 1.0]))
        wo_w = ps.wo[gj].astype(np.float64)
        wo = np.stack([np.einsum("ij,ij->i", wo_w, a) for a in (sx, tx, n)], 1)
        kind, param, c = ps.kind[gj], ps.param[gj].astype(np.float64), weights[gj].astype(np.float64)
        if part:   # the coat's pass: plastic groups alone
            on = on & (kind == bsdfs.PLASTIC)
        for d in directions:   # the texel's points, not pairs
            wi = np.stack([np.einsum("ij,ij->i", d, a) for a in (sx, tx, n)], 1)
            f = np.zeros(count)
            for kd in np.unique(kind[on]):   # material kinds, not pairs
                sel = on & (kind == kd)
                if kd == bsdfs.PLASTIC:
                    coat, base = bsdfs.plastic_parts(wi[sel], wo[sel], ps.table[material[gj][sel]])
                    f[sel] = coat if part else base
                else:
                    f[sel] = bsdfs.eval_cos(int(kd), param[sel], wi[sel], wo[sel])
            f = np.where(on & np.isfinite(f) & (f > 0) & (np.einsum("ij,ij->i", d, geo) > 0), f * c, 0.0)
            grown = total + f
            take = rng.step_uniforms(key, step).astype(np.float64) * grown < f
            step += 1
            pick_dir = np.where(take[:, None], d, pick_dir)
            picked = np.where(take, gj, picked)
            total = grown
    size = np.maximum(ps.size[picked].astype(np.int64), 1)
    k = np.minimum((u[:, 3].astype(np.float32) * size.astype(np.float32)).astype(np.int64), size - 1)
    sample = ps.members[p * S + ps.first[picked].astype(np.int64) + k]
    omega = (z0 - z1) * 2 * np.pi / side
    weight = np.where(total > 0, omega * total / points, 0.0)
    return pick_dir, weight, sample.astype(np.int64)


#: the stream of each part's texel uniforms: 0 the transfer the albedo multiplies, 1 plastic's coat
PARTS = (rng.TEXEL, rng.TEXEL_COAT)


def texel_rays(ps: PixelSamples, n_levels: int, seed: int, tile: int, bsdf_kinds: int = 15, queue=None,
               points: int = 4, part: int = 0):
    """The kernel ``bake_texel_rays`` over all of a tile's (pixel, texel) pairs: directions
    (P 4^n, 3), weights (P 4^n,) float32 and the picked samples (P 4^n,) uint32. ``bsdf_kinds``:
    the bit mask of the material kinds the scene has (the kernel evaluates only those);
    ``part`` 0 the transfer the albedo multiplies, 1 plastic's coat (:data:`PARTS`)."""
    count = len(ps) << (2 * n_levels)
    queue = queue or cl.thread_queue()
    prog = cl.program("relight.cl", BSDF_KINDS=int(bsdf_kinds), TEXEL_POINTS=int(points))
    # the thread's reusable buffers: a fresh 20 MB a tile cost PoCL allocations and page faults
    dirs, weights, picks = (cl.scratch(f"bake_{name}", size * count) for name, size in
                            (("dirs", 12), ("weights", 4), ("picks", 4)))
    k0, k1 = rng.key(seed)
    material = ps.material if ps.material is not None else np.zeros(len(ps.kind), np.int32)
    table = ps.table if ps.table is not None and ps.table.size else np.zeros(bsdfs.PLASTIC_STRIDE, np.float32)
    cl.kernel(prog, "bake_texel_rays")(
        queue, (cl.items(count, cl.LANES),), (cl.WORK_GROUP,), np.uint32(count), np.uint32(0),
        np.uint32(n_levels), np.uint32(ps.samples), np.uint32(tile), np.uint32(k0), np.uint32(k1),
        np.uint32(PARTS[part]), np.uint32(part),
        *(cl.to_device(a) for a in (np.asarray(material, np.int32), np.asarray(table, np.float32), ps.count,
                                    ps.normal, ps.geometric, ps.wo, ps.kind, ps.param,
                                    ps.coat_weight if part else ps.weight, ps.first, ps.size, ps.members)),
        dirs, weights, picks)
    return (cl.read(dirs, (count, 3), np.float32, queue), cl.read(weights, (count,), np.float32, queue),
            cl.read(picks, (count,), np.uint32, queue))


def tile_transfer(ps: PixelSamples, tracer, n_levels: int, seed: int, tile: int, backend: str = "opencl",
                  bsdf_kinds: int = 15, points: int = 4, part: int = 0):
    """(P, N, N) float32 texel transfer of a tile's pixels (module docstring; ``part`` 1: plastic's
    coat, :data:`PARTS`) and the number of shadow rays it traced."""
    if backend == "opencl":
        dirs, weight, pick = texel_rays(ps, n_levels, seed, tile, bsdf_kinds, points=points, part=part)
    else:
        dirs, weight, pick = texel_rays_reference(ps, n_levels, seed, tile, points=points, part=part)
    live = np.flatnonzero(weight > 0)
    blocked = tracer.occluded(np.take(ps.origin, pick[live].astype(np.int64), axis=0), np.take(dirs, live, axis=0))
    out = np.zeros(len(weight), np.float32)
    out[live] = np.where(blocked, 0.0, weight[live])
    side = 1 << n_levels
    return out.reshape(-1, side, side), len(live)


# ----------------------------------------------------------------------------- the whole image
#: the held-out lighting of a bake: the scene's map turned this far from its own rotation (no
#: frame is likely to test exactly there), on which compression and terms are measured
HELD_OUT_DEGREES = 137.0
#: camera samples per pixel at most (a pixel's miss mask is one 64-bit word)
MAX_SAMPLES = BAKE["spp"].hi
BITS = BAKE["bits"].values


def _tiles(width: int, height: int):
    """(block id, x0, y0, w, h) of the BLOCK x BLOCK tiles, row-major."""
    bw, bh = -(-width // BLOCK), -(-height // BLOCK)
    return [(by * bw + bx, bx * BLOCK, by * BLOCK, min(BLOCK, width - bx * BLOCK), min(BLOCK, height - by * BLOCK))
            for by in range(bh) for bx in range(bw)], (bw, bh)


def _padded(values: np.ndarray, w: int, h: int):
    """A tile's per-pixel rows (w h, ...) placed in the block's BLOCK x BLOCK grid (zeros elsewhere)."""
    out = np.zeros((BLOCK, BLOCK) + values.shape[1:], values.dtype)
    out[:h, :w] = values.reshape((h, w) + values.shape[1:])
    return out.reshape((BLOCK * BLOCK,) + values.shape[1:])


@dataclass
class Settings:
    """What a bake is made with: size, camera samples, texel levels, compression, the held-out
    lighting (4^n, 3) coefficients times N^2 (:mod:`.frame`), seed, backend."""

    width: int
    height: int
    spp: int
    n_levels: int
    tolerance: float
    bits: int
    held_out: np.ndarray
    seed: int
    backend: str = "opencl"
    points: int = 4
    #: bake plastic's coat as a second transfer (a bake that varies the lighting)
    coat: bool = False
    #: a bake that varies one object: the levels of each pixel's product T1 x L (coarse texels)
    #: and the fixed lighting's mean luminance on them, (2^m, 2^m)
    product_levels: int | None = None
    product_luminance: np.ndarray | None = None


class _Worker:
    """A scene's ray tracer and material mask, made once per process (or thread pool)."""

    def __init__(self, scene):
        self.scene = scene
        self.tracer = RayTracer(scene.vertices, scene.faces, threads=1, normals=scene.normals,
                                normal_faces=scene.normal_faces)
        self.kinds = int(np.bitwise_or.reduce(1 << np.unique(scene.material_kind))) if len(scene.materials) else 1


def bake_block(worker: _Worker, settings: Settings, tile) -> dict:
    """One block of the bake: its texels' transfer, Haar coefficients, compressed and quantized
    (a pure function of the scene, the settings and the tile: any process computes the same)."""
    block_id, x0, y0, w, h = tile
    s = settings
    ps = camera_samples(worker.scene, worker.tracer, s.width, s.height, x0, y0, w, h, s.spp, s.seed, block_id)
    texels, rays = tile_transfer(ps, worker.tracer, s.n_levels, s.seed, block_id, s.backend, worker.kinds, s.points)
    coeffs = haar.forward(texels)   # numpy's is the faster here: one tile, no transfers to the device
    side2 = 4 ** s.n_levels
    coeffs = _padded(np.asarray(coeffs, np.float32).reshape(w * h, side2), w, h)
    cols, scales, q, e2, n2 = store.compress_block(coeffs, s.held_out, s.tolerance, s.bits,
                                                   np.random.default_rng([s.seed, block_id]))
    some = np.flatnonzero(ps.miss)
    c64 = coeffs.astype(np.float64)
    result = {"tile": tile, "columns": cols, "scales": scales, "data": q, "error2": e2, "norm2": n2,
              "albedo": ps.albedo.reshape(h, w, 3), "rays": rays, "sum_sq": np.einsum("pc,pc->c", c64, c64),
              "background": ((y0 + some // w) * s.width + x0 + some % w, ps.miss[some],
                             ps.dirs.reshape(-1, s.spp, 3)[some])}
    if s.coat and ps.has_coat:   # plastic's coat: a second transfer, compressed alike (store.CoatWriter)
        coat, coat_rays = tile_transfer(ps, worker.tracer, s.n_levels, s.seed, block_id, s.backend, worker.kinds,
                                        s.points, part=1)
        coat = _padded(np.asarray(haar.forward(coat), np.float32).reshape(w * h, side2), w, h)
        result["coat"] = store.compress_block(coat, s.held_out, s.tolerance, s.bits,
                                              np.random.default_rng([s.seed, block_id, 1]))
        result["rays"] += coat_rays
    if s.product_levels is not None:   # T1 x L on coarse texels (exact: texels add up)
        m, k = s.product_levels, 1 << (s.n_levels - s.product_levels)
        if ps.has_coat:   # plastic's coat, over lum(a_p) as T's scale is: the frame's lum(a_p) T + C
            coat, coat_rays = tile_transfer(ps, worker.tracer, s.n_levels, s.seed, block_id, s.backend, worker.kinds,
                                            s.points, part=1)
            lum = ps.albedo.astype(np.float64) @ LUMINANCE
            texels = texels + (coat / np.where(lum > 0, lum, 1.0)[:, None, None]).astype(np.float32)
            result["rays"] += coat_rays
        coarse = texels.reshape(w * h, 1 << m, k, 1 << m, k).sum(axis=(2, 4))
        result["product"] = (coarse * s.product_luminance).reshape(w * h, -1).astype(np.float16)
    return result


_WORKERS = {}   # per process: (scene path, content hash) -> _Worker


def bake_block_task(task: dict) -> dict:
    """:func:`bake_block` for a worker process (dask.distributed): the scene by path, checked by
    its content hash, loaded once per process."""
    key = (task["scene_path"], task["content_hash"], task.get("without"))
    worker = _WORKERS.get(key)
    if worker is None:
        scene = load_scene(task["scene_path"])
        if scene.content_hash != task["content_hash"]:
            raise ArgumentError(f"{task['scene_path']}: this worker sees another scene than the bake read")
        if task.get("without") is not None:
            scene = scene.without(scene.find_object(task["without"]))
        worker = _WORKERS[key] = _Worker(scene)
    return bake_block(worker, task["settings"], task["tile"])


#: the pilot bake that chooses camera samples, texel levels, terms and priority: this many of
#: the image's pixels on its longer side (a regular grid of them), at most PILOT_LEVELS texel
#: levels, two bakes with different seeds at the bake's camera samples (MAX_SAMPLES where the
#: pilot chooses them) measure the noise
PILOT_SIDE = 32
PILOT_LEVELS = 7
TERM_CHOICES = (32, 64, 128, 256, 512, 1024, 2048, 4096)
#: the held-out lightings the pilot measures terms on: the scene's map turned by these degrees
HELD_OUT_TURNS = (HELD_OUT_DEGREES, HELD_OUT_DEGREES + 120.0, HELD_OUT_DEGREES + 240.0)
#: the pilot's K keeps its term error within this part of its share, and its n and S count the
#: noise at this many times its measure: another map needs more terms than turns of the baked
#: one, and its bright spots raise the noise (docs/decisions/relight-model-choice.md)
TERM_MARGIN = 0.5
NOISE_MARGIN = float(np.sqrt(2.0))


def pilot_grid(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(columns, rows): the image's pixels the pilot bakes, about PILOT_SIDE on the longer side,
    spread evenly over the image (pixels of the bake's own size, so that their sub-pixel
    variance is the bake's)."""
    aspect = width / height
    pw, ph = (PILOT_SIDE, max(1, round(PILOT_SIDE / aspect))) if aspect >= 1 else (max(1, round(PILOT_SIDE * aspect)),
                                                                                 PILOT_SIDE)
    pw, ph = min(pw, width), min(ph, height)
    return (((np.arange(pw) + 0.5) * width / pw).astype(np.int64),
            ((np.arange(ph) + 0.5) * height / ph).astype(np.int64))


def _pilot_transfer(scene, worker, grid, width, height, spp, seed, top, backend, points=None) -> np.ndarray:
    """(P, 2^top, 2^top) float64: the pilot pixels' texels, baked with ``seed`` (``points`` per
    texel, default :func:`texel_points`)."""
    tiles, _ = _tiles(len(grid[0]), len(grid[1]))
    texels = []
    points = texel_points(scene, top) if points is None else points
    for tile in tiles:   # a few blocks, not pixels
        _, x0, y0, w, h = tile
        ps = camera_samples(scene, worker.tracer, width, height, x0, y0, w, h, spp, seed, tile[0], at=grid)
        t = tile_transfer(ps, worker.tracer, top, seed, tile[0], backend, worker.kinds, points)[0].astype(np.float64)
        if ps.has_coat:   # plastic: its frame is lum(a_p) T + T_coat, here over lum(a_p) as T's is
            lum = ps.albedo.astype(np.float64) @ LUMINANCE
            coat = tile_transfer(ps, worker.tracer, top, seed, tile[0], backend, worker.kinds, points, part=1)[0]
            t += coat / np.where(lum > 0, lum, 1.0)[:, None, None]
        texels.append(t)
    return np.concatenate(texels)


def _relative(a: np.ndarray, b: np.ndarray, norm: float) -> float:
    """||a - b|| / norm; 0 where norm is 0, inf where anything is not finite (nothing fits)."""
    diff = float(np.linalg.norm(a - b))
    if not (np.isfinite(diff) and np.isfinite(norm)):
        return float("inf")
    return diff / norm if norm > 0 else 0.0


def choose_model(scene, tolerance: float, spp, seed: int, levels=None, terms=None, priority=None,
                 backend: str = "opencl", width=None, height=None, points=None) -> dict:
    """The camera samples S, texel levels n, terms K and their priority a scene needs for
    ``tolerance`` (a relative L2 error of frames), from pilot bakes of the image's own pixels
    (:func:`pilot_grid`) at 2^PILOT_LEVELS texels and coarser, measured under held-out
    lightings (the map turned by HELD_OUT_TURNS). The error has four parts that add in
    quadrature:

    - the texels' bias: ||f_n - f_top|| + ||f_(top-1) - f_top|| (texels summed 2 x 2 are exact
      coarser texels; the second term bounds the finest pilot's own, as the differences halve
      per level);
    - the bake's noise at n: two pilots with different seeds at level n measure it, at ``spp``
      or, where S is chosen, at MAX_SAMPLES; its variance is a / S + b (b: the texels' shadow
      rays, one per pixel and texel whatever S), so at S <= MAX_SAMPLES it is at most
      sqrt(MAX_SAMPLES / S) times that;
    - the terms: the error of K terms against all, on the worst held-out lighting;
    - the compression of the bake's blocks.

    n is the fewest levels whose bias and noise (times NOISE_MARGIN) are within tolerance / 2
    together (else the least of them), S the fewest of SPP_CHOICES that keeps them there (else
    the most); the rest,
    sqrt((tolerance^2 - bias^2 - noise^2) / 2) (at least tolerance / 4), is the share of the
    compression and of the terms: K, the fewest of TERM_CHOICES within TERM_MARGIN of it, by
    the priority with the lower error at K = 256. Given values are kept. Returns the choices, the share
    and the errors measured."""
    if spp is not None and levels is not None and terms is not None and priority is not None:
        return {"spp": int(spp), "n_levels": int(levels), "terms": int(terms), "priority": priority,
                "share": tolerance / np.sqrt(3.0), "pilot": None}
    env = scene.environment
    width = scene.width if width is None else width
    height = scene.height if height is None else height
    grid = pilot_grid(width, height)
    top = PILOT_LEVELS if levels is None else levels
    worker = _Worker(scene)
    pilot_spp = MAX_SAMPLES if spp is None else int(spp)
    lum = LUMINANCE.astype(np.float64)
    rot = env.rotate_y + HELD_OUT_TURNS[0]
    lowest = min(top, 4)                  # the coarsest level measured (the pilot's own when it is below)
    held = {m: lighting.project(env, m, rot) @ lum for m in range(top, lowest - 1, -1)}

    def pair(m):
        """The two pilots' frames at level m under the held-out lighting, their transfer's mean."""
        a, b = (_pilot_transfer(scene, worker, grid, width, height, pilot_spp, seed + k, m, backend, points)
                for k in (1, 2))
        return np.einsum("pij,ij->p", a, held[m]), np.einsum("pij,ij->p", b, held[m]), (a + b) / 2

    def noise_of(f1, f2):   # one pilot's: the two differ by sqrt(2) of it
        return _relative(f1, f2, np.linalg.norm((f1 + f2) / 2)) / np.sqrt(2.0)

    f1, f2, T = pair(top)
    noise_at = {top: noise_of(f1, f2)}
    frames = {}
    for n in range(top, lowest - 1, -1):   # levels, not pixels
        k = 1 << (top - n)
        frames[n] = np.einsum("pij,ij->p", T.reshape(len(T), 1 << n, k, 1 << n, k).sum(axis=(2, 4)), held[n])
    norm = np.linalg.norm(frames[top])
    raw = {n: _relative(f, frames[top], norm) for n, f in frames.items()}
    bias = {n: e + raw.get(top - 1, 0.0) for n, e in raw.items()}
    joint = tolerance / 2.0
    if levels is not None:
        n = levels
    else:
        for m in range(top - 1, 3, -1):   # coarser levels while their bias leaves room, a few
            if bias[m] > joint:
                break
            g1, g2, _ = pair(m)
            noise_at[m] = noise_of(g1, g2)
        both = {m: float(np.hypot(bias[m], NOISE_MARGIN * noise_at[m])) for m in noise_at}
        fits = [m for m, e in both.items() if e <= joint]
        n = min(fits) if fits else min(both, key=both.get)
    if spp is None:
        fits = [s for s in SPP_CHOICES
                if np.hypot(bias[n], NOISE_MARGIN * noise_at[n] * np.sqrt(pilot_spp / s)) <= joint]
        spp = fits[0] if fits else SPP_CHOICES[-1]
    noise = noise_at[n] * float(np.sqrt(pilot_spp / spp))
    share = float(np.sqrt(max(tolerance ** 2 - bias[n] ** 2 - noise ** 2, tolerance ** 2 / 8) / 2.0))
    k = 1 << (top - n)
    Tn = T.reshape(len(T), 1 << n, k, 1 << n, k).sum(axis=(2, 4))
    coeffs_t = haar.forward(Tn).reshape(len(T), -1)                      # (P, 4^n)
    rms = np.sqrt((coeffs_t ** 2).mean(0))
    lights = [lighting.coefficients(lighting.project(env, n, env.rotate_y + turn))
              for turn in HELD_OUT_TURNS]                                 # (3, N, N) each
    lums = [np.tensordot(lum, L, axes=1).ravel() * 4.0 ** n for L in lights]
    fulls = [coeffs_t @ L for L in lums]

    def error(kk, pr):
        worst = 0.0
        for L, L_lum, full in zip(lights, lums, fulls):   # the held-out lightings, a few
            cols = lighting.select_terms(L, kk, pr, rms)
            worst = max(worst, _relative(coeffs_t[:, cols] @ L_lum[cols], full, np.linalg.norm(full)))
        return worst

    if priority is None:
        priority = min(("transfer", "area"), key=lambda pr: (error(256, pr), pr != "transfer"))
    term_error = {kk: error(kk, priority) for kk in [k for k in TERM_CHOICES if k <= 4 ** n] or [4 ** n]}
    if terms is None:
        fits = [kk for kk, e in term_error.items() if e <= share * TERM_MARGIN]
        terms = fits[0] if fits else max(term_error)
    predicted = float(np.sqrt(noise ** 2 + bias[n] ** 2 + term_error.get(terms, 0.0) ** 2 + share ** 2))
    return {"spp": int(spp), "n_levels": int(n), "terms": int(terms), "priority": priority, "share": share,
            "pilot": {"size": [len(grid[0]), len(grid[1])], "levels": top, "spp": pilot_spp,
                      "held_out_rotate_y": [float(env.rotate_y + t) for t in HELD_OUT_TURNS],
                      "noise": round(noise, 5),
                      "noise_at_pilot_spp": {str(m): round(float(v), 5) for m, v in noise_at.items()},
                      "level_error": {str(m): round(v, 5) for m, v in bias.items()},
                      "term_error": {str(m): round(v, 5) for m, v in term_error.items()},
                      "predicted_error": round(predicted, 5)}}


def plastic_materials(scene) -> list:
    """The names of the plastic materials the scene's faces use (plastic's albedo scales its
    diffuse base alone: its coat is a second transfer, :data:`PARTS`)."""
    used = np.unique(np.asarray(getattr(scene, "face_material", []), np.int64))
    return [scene.materials[i].name for i in used if scene.materials[i].kind == bsdfs.PLASTIC]


#: the factors a bake of per-pixel transfer varies (a bake that varies the view: relight/view_bake.py)
PIXEL_VARY = ("lighting", "object")
#: a bake that varies one object: each pixel's product T1 x L on 2^OBJECT_PRODUCT_LEVELS texels,
#: and the scene without the object converged with this many samples per pixel
OBJECT_PRODUCT_LEVELS = 4
STATIC_SPP = BAKE["static_spp"].default


def bounding_sphere(local: np.ndarray):
    """(centre (3,), radius) of an object's vertices (N, 3) in its own frame: the centre of their
    box and the distance to the farthest of them."""
    lo, hi = local.min(0), local.max(0)
    center = (lo + hi) / 2
    return center, float(np.linalg.norm(local - center, axis=1).max())


def bake(scene, output=None, width=None, height=None, spp=None, levels=None,
         tolerance: float = BAKE["tolerance"].default, bits: int = BAKE["bits"].default, terms=None, priority=None,
         seed: int = BAKE["seed"].default, threads=None, progress=None, backend: str = "opencl", dask_address=None,
         points=None, vary: str = BAKE["vary"].default, object=None, static_spp: int = STATIC_SPP):
    """Bake the transfer of ``scene`` (a Scene or a scene file) for its camera at width x height
    (default: the scene's) with ``spp`` camera samples per pixel; write it to ``output``
    (default: a temporary file the Transfer owns) and return the :class:`Transfer`.

    The camera samples, the texel levels (2^n x 2^n), the default terms K and their priority
    are chosen from the scene for ``tolerance`` by pilot bakes (:func:`choose_model`) unless
    given; each block is compressed to the share of the tolerance the pilot leaves it (on the
    held-out lighting) and quantized to ``bits``.
    ``points`` per texel (1, 4 or 16) default to :func:`texel_points`.

    ``vary="object"`` with ``object`` (a name or an index) bakes for frames in which that object
    moves (:mod:`wavlight.relight.moving`): the transfer of the scene without it (camera rays and
    shadows alike), each pixel's product T1 x L of that transfer and the scene's fixed lighting on
    2^OBJECT_PRODUCT_LEVELS texels, and the scene without it converged with ``static_spp``
    samples per pixel (the ``wavelet`` strategy; unbiased).
    (A bake that varies the view is :func:`wavlight.relight.view_bake.bake_view`; :func:`wavlight.bake`
    takes all three.)
    ``progress(done, total, rays, seconds)`` after each block. ``dask_address``: bake the
    blocks on that dask.distributed scheduler (the workers read the scene file at the same
    path); the file is identical to a local bake's."""
    where = "relight.bake"
    if isinstance(scene, (str, os.PathLike)):
        scene = load_scene(scene)
    check_scene(scene)
    width = BAKE["width"].check(scene.width if width is None else width, where)
    height = BAKE["height"].check(scene.height if height is None else height, where)
    spp, levels, terms, priority, points = (None if v is None else BAKE[k].check(v, where) for k, v in
                                            (("spp", spp), ("levels", levels), ("terms", terms),
                                             ("priority", priority), ("points", points)))
    tolerance, bits, seed = (BAKE[k].check(v, where) for k, v in (("tolerance", tolerance), ("bits", bits),
                                                                   ("seed", seed)))
    if vary not in PIXEL_VARY:
        raise ArgumentError(f"{where}: vary must be one of {' | '.join(PIXEL_VARY)}, got {shown(vary)}")
    if scene.environment.is_black:
        raise ArgumentError(f"{scene.path}: [environment]: the environment is black everywhere; nothing to relight")
    full, moving = scene, None
    if vary == "object":
        if object is None:
            raise ArgumentError(f"{where}: vary='object' needs the object that moves (a name or an index)")
        require_untextured(scene, "a bake with vary='object'")
        moving = scene.find_object(object)
        kinds = np.unique(scene.face_material[moving.faces_range[0]:moving.faces_range[1]])
        if len(kinds) > 1:   # its frames shade the moving object with one material (SceneObject.material)
            raise ArgumentError(f"{scene.path}: the object {object!r} has {len(kinds)} materials (its mesh file's "
                                "parts); a bake with vary='object' moves an object of one material: give it a material")
        scene = scene.without(moving)
        static_spp = BAKE["static_spp"].check(static_spp, where)
    elif object is not None:
        raise ArgumentError(f"{where}: an object is given only with vary='object'")
    if dask_address is not None and scene.path == "<dict>":
        raise ArgumentError(f"{where}: a bake on a Dask cluster needs the scene as a file (its workers load it)")
    if output is not None:   # the map, the albedo (and an object bake's static image) at least
        store.check_output(output, scene.environment.pixels.size * 4 + width * height * 12
                           * (3 if moving is not None else 1))
    t0 = time.perf_counter()
    model = choose_model(scene, tolerance, spp, seed, levels, terms, priority, backend, width, height, points)
    n, spp = model["n_levels"], model["spp"]
    env = scene.environment
    held = lighting.coefficients(lighting.project(env, n, env.rotate_y + HELD_OUT_DEGREES)).reshape(3, -1).T
    points = texel_points(scene, n) if points is None else points
    settings = Settings(width, height, spp, n, model["share"], bits, held * float(4 ** n), seed, backend,
                        points)
    if moving is not None:
        settings.product_levels = min(OBJECT_PRODUCT_LEVELS, n)
        settings.product_luminance = (lighting.project(env, settings.product_levels) @ LUMINANCE.astype(np.float64))
        product = np.zeros((height * width, 4 ** settings.product_levels), np.float16)
    tiles, (bw, bh) = _tiles(width, height)
    side2 = 4 ** n
    coat = settings.coat = vary == "lighting" and bool(plastic_materials(scene))
    writer = store.TransferWriter(n, BLOCK, bits, output=output)
    if coat:
        writer.coat = store.TransferWriter(n, BLOCK, bits, output=output)
    albedo = np.zeros((height, width, 3), np.float32)
    background = []
    sum_sq = np.zeros(side2)
    totals = {"rays": 0, "error2": 0.0, "norm2": 0.0, "done": 0, "coat_error2": 0.0, "coat_norm2": 0.0}
    lock = threading.Lock()
    t_pilot = time.perf_counter() - t0

    def collect(result):
        block_id, x0, y0, w, h = result["tile"]
        with lock:
            writer.add(block_id, result["columns"], result["scales"], result["data"])
            if "coat" in result:
                writer.coat.add(block_id, *result["coat"][:3])
                totals["coat_error2"] += result["coat"][3]
                totals["coat_norm2"] += result["coat"][4]
            albedo[y0:y0 + h, x0:x0 + w] = result["albedo"]
            pixel, mask, dirs = result["background"]
            if len(pixel):
                background.append((np.asarray(pixel, np.uint32), mask, dirs))
            sum_sq[:] += result["sum_sq"]
            if moving is not None:
                rows = (y0 + np.arange(h))[:, None] * width + x0 + np.arange(w)[None, :]
                product[rows.reshape(-1)] = result["product"]
            totals["rays"] += result["rays"]
            totals["error2"] += result["error2"]
            totals["norm2"] += result["norm2"]
            totals["done"] += 1
            if progress:
                progress(totals["done"], len(tiles), totals["rays"], time.perf_counter() - t0)

    try:
        if dask_address is not None:
            bake_on_cluster(dask_address, full, settings, tiles, bake_block_task, collect,
                            None if moving is None else moving.index)
        else:
            worker = _Worker(scene)
            with ThreadPoolExecutor(threads or default_threads()) as pool:
                for result in pool.map(lambda tile: bake_block(worker, settings, tile), tiles):
                    collect(result)
        seconds = time.perf_counter() - t0
        header = {
            **store.header_of(scene),
            "width": width, "height": height, "spp": spp, "seed": seed, "n_levels": n, "block": BLOCK,
            "texel_points": points,
            "blocks": [bw, bh], "bits": bits, "tolerance": tolerance, "terms": model["terms"],
            "priority": model["priority"], "environment_rotate_y": float(env.rotate_y),
            "environment_name": env.name, "vary": vary,
            "measured": {"bake_seconds": round(seconds, 3), "pilot_seconds": round(t_pilot, 3),
                         "rays": totals["rays"],
                         "rays_per_second": round(totals["rays"] / (seconds - t_pilot), 1) if seconds > t_pilot else None,
                         "held_out_rotate_y": float(env.rotate_y + HELD_OUT_DEGREES),
                         "compression_error": (float(np.sqrt(totals["error2"] / totals["norm2"]))
                                               if totals["norm2"] > 0 else 0.0),
                         "noise": (model["pilot"] or {}).get("noise"),
                         "predicted_error": (model["pilot"] or {}).get("predicted_error"),
                         "level_error": (model["pilot"] or {}).get("level_error", {}).get(str(n)),
                         "term_error": (model["pilot"] or {}).get("term_error", {}).get(str(model["terms"])),
                         "entries": writer.entries, "entries_full": side2 * bw * bh, "pilot": model["pilot"]},
        }
        if coat:   # plastic's coat: its own transfer (store.COAT_SECTIONS)
            header["coat"] = True
            header["measured"]["coat_entries"] = writer.coat.entries
            header["measured"]["coat_compression_error"] = (float(np.sqrt(totals["coat_error2"] / totals["coat_norm2"]))
                                                            if totals["coat_norm2"] > 0 else 0.0)
        order = np.argsort(np.concatenate([b[0] for b in background])) if background else np.zeros(0, np.int64)
        arrays = {"albedo": albedo, "environment": env.pixels.astype(np.float32),
                  "background_pixel": (np.concatenate([b[0] for b in background])[order] if background
                                       else np.zeros(0, np.uint32)),
                  "background_mask": (np.concatenate([b[1] for b in background])[order] if background
                                      else np.zeros(0, np.uint64)),
                  "background_dir": (np.concatenate([b[2] for b in background])[order] if background
                                     else np.zeros((0, spp, 3), np.float32)),
                  "rms": np.sqrt(sum_sq / max(width * height, 1)).astype(np.float32)}
        if moving is not None:
            static = render_full(scene, spp=static_spp, strategy="wavelet", width=width, height=height,
                                 seed=seed + 1)
            arrays.update(static=static.image, static_stderr=static.stderr, product_leaves=product)
            center, radius = bounding_sphere(moving.local)
            header["object"] = {"index": moving.index, "name": moving.name, "rotate": moving.rotate,
                                "translate": np.asarray(moving.translate, float).tolist(),
                                "center": center.tolist(), "radius": radius}
            header["product_levels"] = settings.product_levels
            header["static"] = {"spp": static_spp, "strategy": "wavelet",
                                "seconds": static.stats["setup_seconds"] + static.stats["render_seconds"]}
            header["scene"]["content_hash"] = full.content_hash
        return finish_bake(writer, output, header, arrays)
    finally:
        writer.close()
