"""Frames in which one object moves (Chen & Gao sec. 2.2: "fix the lighting and view conditions,
and relocate a single object"): the bake of the rest of the scene, then per frame the object's
occlusion O_j alone.

A bake with ``vary="object"`` (:func:`wavlight.relight.bake.bake`) holds, for the scene without
the moving object: each pixel's transfer T1 = f cos V_rest, its product with the fixed lighting
on coarse texels (``product_leaves``), and the image of that scene converged by an unbiased
render (``static``, S_p). With the object placed anew, a pixel's radiance is

    B_p = E_x[ integral f cos L V_rest (1 - O_j) dw ] = S_p - E_x[ D(x) ],
    D(x) = integral f cos L V_rest O_j dw,

x a camera sample in the pixel. D is what the object takes away; it is estimated per camera
sample (eq. 12's bidirectional estimator, with the visibility of the rest inside the sampled
product: its noise is O_j's) from ``directions`` directions (DIRECTIONS) of the defensive
mixture of the pixel's product T1 x L (the coarse texel by the hierarchical warp, eq. 17-22,
then inside it the lighting's own resolution) and, with probability 0.1, the BSDF, at the
mixture's density, their uniforms stratified over the pixel's spp x directions: where a
direction meets the object (traced against the object alone, in its own frame, so nothing is
rebuilt per frame) and not the rest, D gets f cos L / p, over the directions (plastic: (coat +
albedo base) L / p, its BSDF share sampling both lobes, and its pixels' product leaves that of
T + C / lum(a_p), the coat's transfer added: docs/decisions/plastic-in-the-bake.md). The variance of D
is the object's occlusion's: per direction a Bernoulli trial (blocked or not) times a nearly
constant f cos L / p, largest in the object's hard shadow, where D is nearly all of S; the
directions of one camera sample share its hit point, and stratified over the pixel the many
that reach a sun fall on it in a fixed share rather than by chance
(docs/decisions/moving-occlusion-directions.md). A direction that misses the object's box
needs no ray (D = 0 there exactly): the kernel ``moving_occlusion`` (kernels/relight_moving.cl,
numpy twin :func:`occlusion_records_reference`) tests each against the box at this frame's
place (first its texel against the cone around the box, before the direction inside the texel
is drawn) and returns only those that meet it, as records ready for the object's ray tracer.

Pixels whose footprint may see the object itself (the cone of the pixel meets the object's
bounding sphere and the pixel lies in the box of a projected triangle; decided from the
object's place alone, not from random samples, so that the choice does not bias the estimate)
are rendered in full against the moved scene with the ``wavelet`` strategy (its product walk,
resampling and control variate: the renderer's shade kernel, :class:`wavlight.shading.KernelShader`,
twin :func:`wavlight.strategies.shade_reference`; its candidates and slots chosen from the
scene's shadows as a render chooses them), the closer hit of the rest and the object and the
shading uniforms, stratified over the pixel's samples, from the kernel ``moving_points`` (twin
:func:`shading_points_reference`). The camera rays of a frame are kept for the next frames of
the same seed and spp (the viewer draws every frame with seed 0); a frame runs as chunks of
rows on a pool of threads. Every frame is unbiased: tests/relight/test_relight_moving.py
checks it against ``mis`` of the moved scene. ``backend="numpy"`` computes the same estimator
with the numpy twins (same random numbers).
"""
from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from types import SimpleNamespace
from typing import NamedTuple

import numpy as np

from .. import bsdfs, camera, cl, occlusion, raytrace, rng, strategies
from ..camera import camera_rays, project
from ..envmap import Environment
from ..errors import ArgumentError, WavlightError, check_degrees, check_int, check_real
from ..haar.tree import HaarTree, tree_stride
from ..integrator import RenderResult
from ..raytrace import RayTracer
from ..scene import MAX_COORDINATE, rotation
from ..threads import default_threads
from ..sampler import stratify_pair
from ..shading import KernelShader, NumpyShader
from ..warp import frame as tangent_frame
from ..warp import to_local
from .bake import bounding_sphere, camera_jitter
from .converge import PASS_SPP
from .mixture import TexelLight, mean_and_error, mixture_directions, scene_of, tint_of
from .settings import FRAME, OBJECT_FRAME_SPP

#: a frame's chunk c draws its Philox numbers as tile FRAME_TILES + c (streams rng.JITTER,
#: rng.MOVING_DIRECTIONS, rng.MOVING_MIS)
FRAME_TILES = 11 << 16
#: a chunk is whole rows of the image: at most this many pixels and camera samples (memory
#: stays bounded at any size; a row of more samples is one chunk); a frame of more samples per
#: pixel takes them in passes of at most PASS_SPP (and CHUNK_SAMPLES / width) per pixel
CHUNK_PIXELS = 1 << 16
CHUNK_SAMPLES = 1 << 18
#: a frame's camera rays (and their hits on the rest) are kept for the next frames of its seed and spp
#: where it is one pass of at most this many samples (the viewer's frames: 4 and 1 spp)
KEPT_SAMPLES = 1 << 22
#: the per-pixel product trees kept from frame to frame (device memory, about 1.4 kB a pixel
#: at 16 x 16 texels: a 256 x 256 image's whole)
TREE_CACHE_BYTES = 256 << 20
DEFENSIVE = 0.1
BACKENDS = ("opencl", "numpy")
#: directions of the mixture per camera sample for the object's occlusion D, stratified over the
#: pixel's spp x DIRECTIONS (docs/decisions/moving-occlusion-directions.md)
DIRECTIONS = 4
MAX_DIRECTIONS = 64
#: the object's box (its own frame) is grown by this share of the coordinates' size before the
#: kernel tests directions against it (float32 rounding: it must never drop a ray that meets it)
BOX_MARGIN = 1e-4
#: a launch of moving_occlusion takes at most this many directions (its records' regions: 40
#: bytes per direction, about 10 MB)
OCCLUSION_BATCH = 1 << 18
#: words per record of moving_occlusion (the sample's direction, origin, direction, contribution)
RECORD = 10
#: a frame is cut into at least MIN_CHUNKS chunks of rows where each keeps MIN_CHUNK_SAMPLES
#: camera samples, run on a pool of threads (wavlight.threads.default_threads)
MIN_CHUNKS = 16
MIN_CHUNK_SAMPLES = 1 << 14
#: frames of this many (seed, spp) keep their camera rays for the next ones
KEPT_SEEDS = 2
_WARMED = set()


def counter_uniforms(seed: int, tile: int, stream: int, index: np.ndarray, j=0) -> np.ndarray:
    """(N, 4) float32: the four uniforms of Philox counters (index, tile, stream, j) (kernels/
    relight_moving.cl ``counter_uniforms``; j = 0 is :func:`wavlight.rng.uniforms`' counter)."""
    index = np.asarray(index, np.int64)
    counter = np.zeros((len(index), 4), np.uint32)
    counter[:, 0] = index.astype(np.uint64).astype(np.uint32)
    counter[:, 1], counter[:, 2] = tile, stream
    counter[:, 3] = np.broadcast_to(np.asarray(j, np.int64), index.shape).astype(np.uint32)
    w = rng.philox4x32_10(counter, rng.key(seed))
    return (w >> np.uint32(8)).astype(np.float32) * np.float32(2.0 ** -24)


def strata_keys(seed: int, tile: int, index: np.ndarray) -> np.ndarray:
    """(N, 4) uint32: the words of stream rng.STRATA at ``index`` (word 0 keys the camera
    jitter's cells, words 1 and 2 the pairs of the directions or of the shading uniforms)."""
    index = np.asarray(index, np.int64)
    counter = np.zeros((len(index), 4), np.uint32)
    counter[:, 0] = index.astype(np.uint64).astype(np.uint32)
    counter[:, 1], counter[:, 2] = tile, rng.STRATA
    return rng.philox4x32_10(counter, rng.key(seed))


def stratified_uniforms(seed: int, tile: int, stream: int, first: int, slots: np.ndarray, spp: int,
                        directions: int = 1) -> np.ndarray:
    """(N D, 4) float32, numpy twin of the kernels' uniforms (kernels/relight_moving.cl): for the
    camera samples ``slots`` (N,) of a pass of ``spp`` per pixel (pixel slot // spp) and D =
    ``directions`` per sample (row i D + j), Philox counter (first + slot, tile, stream, j), the
    pairs (0, 1) and (2, 3) stratified over the pixel's spp D cells (cell (slot % spp) D + j) by
    words 1 and 2 of stream STRATA at first + pixel (:func:`wavlight.sampler.stratify_pair`)."""
    slots = np.asarray(slots, np.int64)
    index = np.repeat(first + slots, directions)
    j = np.tile(np.arange(directions), len(slots))
    u = counter_uniforms(seed, tile, stream, index, j)
    keys = np.repeat(strata_keys(seed, tile, first + slots // spp), directions, axis=0)
    cell = (np.repeat(slots % spp, directions) * directions + j).astype(np.uint32)
    cells = spp * directions
    u[:, 0], u[:, 1] = stratify_pair(u[:, 0], u[:, 1], cell, cells, keys[:, 1])
    u[:, 2], u[:, 3] = stratify_pair(u[:, 2], u[:, 3], cell, cells, keys[:, 2])
    return u


def meets_box(place: np.ndarray, box: np.ndarray, origin: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """(N,) bool, numpy twin of the kernel's ``meets_box``: whether the rays from origin (N, 3)
    along direction (N, 3) meet the box (lo, hi) = box (6,) of the object's own frame, the object
    at world = R local + T (place (12,): R row-major, then T). A slab test whose minima and
    maxima drop NaN (0 / 0: a ray in a face's plane), as OpenCL's fmin and fmax."""
    place = np.asarray(place, np.float64)
    R, T = place[:9].reshape(3, 3), place[9:]
    o = (np.asarray(origin, np.float64) - T) @ R
    w = np.asarray(direction, np.float64) @ R
    box = np.asarray(box, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = (box[:3] - o) / w, (box[3:] - o) / w
    near = np.fmax.reduce(np.fmin(t0, t1), axis=1, initial=-np.inf)
    far = np.fmin.reduce(np.fmax(t0, t1), axis=1, initial=np.inf)
    return (near <= far) & (far >= 0)


class Records(NamedTuple):
    """The directions of the object's occlusion D that meet its box: camera sample (N,) (its
    position in the launch), the direction's number j among the sample's (N,), shadow-ray origin
    (N, 3) and direction (N, 3) in the object's own frame (local = R^T (world - T)) and the
    unoccluded contribution albedo f cos L / p (N, 3)."""

    sample: np.ndarray
    j: np.ndarray
    origin: np.ndarray
    direction: np.ndarray
    value: np.ndarray


def occlusion_records_reference(scene, tracer, environment, inside, trees, d, prim, t, slots, spp: int,
                                directions: int, seed: int, tile: int, first: int, place, box,
                                tree_offset: int = 0, defensive: float = DEFENSIVE, uv=None) -> Records:
    """numpy twin of the ``moving_occlusion`` kernel (kernels/relight_moving.cl), records in its
    order: for camera rays from ``scene``'s eye along d (N, 3) that hit ``tracer``'s triangles
    prim (N,) at t (N,), samples ``slots`` (N,) of a pass of spp per pixel (pixel slot // spp's
    product tree at ``tree_offset`` + that in ``trees``), ``directions`` directions each of the
    defensive mixture (:func:`wavlight.relight.mixture.mixture_directions`; the BSDF alone where
    the pixel's product is 0), their uniforms :func:`stratified_uniforms` (stream
    rng.MOVING_DIRECTIONS); the records of those whose ray meets the object's box
    (:func:`meets_box`) with a contribution > 0 (their rays in the object's own frame). ``uv``: the
    hits' barycentrics (u, v) for their shading normals (None: flat); no light from below the
    geometric surface (docs/decisions/shading-normals.md)."""
    nd = directions
    count = len(d)
    eye = scene.camera.eye
    d32, t32 = np.asarray(d, np.float32), np.asarray(t, np.float32)
    if uv is not None and tracer.smooth:
        nrm, geo, _, origin = tracer.hit(eye, d32, t32, prim, uv[0], uv[1])
    else:
        nrm, _, origin = tracer.surface(eye, d32, t32, prim)
        geo = nrm
    nrm = nrm.astype(np.float64)
    s_ax, t_ax = tangent_frame(nrm)
    wo = to_local(-np.asarray(d, np.float64), s_ax, t_ax, nrm)
    mat = scene.face_material[prim]
    slots = np.asarray(slots, np.int64)
    pixel = slots // spp + tree_offset
    u = stratified_uniforms(seed, tile, rng.MOVING_DIRECTIONS, first, slots, spp, nd)
    # the mixture's slots: direction j of sample slot of pixel p is row p spp D + (slot % spp) D + j
    rows = np.repeat(pixel * spp * nd + (slots % spp) * nd, nd) + np.tile(np.arange(nd), count)
    u_all = np.full((trees.n_trees * spp * nd, 4), 0.5, np.float32)
    u_all[rows] = u
    has = np.repeat(trees.integral[pixel] > 0, nd)
    alpha = np.where(has, defensive, 1.0)
    rep = lambda a: np.repeat(a, nd, axis=0)   # noqa: E731  (per sample -> per direction)
    table = rep(scene.material_table[mat]) if len(scene.materials) else None   # plastic's rows
    direction, weight, share = mixture_directions(trees, inside, u_all, rows, spp * nd, has, alpha,
                                                  rep(scene.material_kind[mat]), rep(scene.material_param[mat]),
                                                  rep(wo), (rep(s_ax), rep(t_ax), rep(nrm)),
                                                  geometric=rep(geo.astype(np.float64)), table=table, with_share=True)
    value = tint_of(share, rep(scene.material_albedo[mat])) * (weight[:, None] * environment.eval(direction))
    o = rep(origin.astype(np.float64))
    keep = meets_box(place, box, o, direction) & (weight > 0) & (value.max(1) > 0)
    i, j = np.repeat(np.arange(count), nd), np.tile(np.arange(nd), count)
    # the kernel's order: work-item (LANES samples), then direction, then lane
    order = np.lexsort((i % cl.LANES, j, i // cl.LANES))
    order = order[keep[order]]
    place = np.asarray(place, np.float64)
    R, T = place[:9].reshape(3, 3), place[9:]
    return Records(i[order], j[order], (o[order] - T) @ R, direction[order] @ R, value[order])


def shading_points_reference(scene, tracer, object_tracer, object_material: int, environment, d, prim, t,
                             prim_object, t_object, R, T, object_offset: float, slots, spp: int, seed: int,
                             tile: int, first: int, uv=None, uv_object=None):
    """numpy twin of the ``moving_points`` kernel (kernels/relight_moving.cl): for camera rays
    from ``scene``'s eye along d (N, 3) that hit the rest's triangles prim (N,) at t (N,) and the
    object's (``object_tracer``'s, in its own frame: world = R local + T) prim_object at
    t_object, the closer one's shading point: planes (16, N) of the shading normal turned towards
    the viewer (interpolated at the barycentrics ``uv`` of the rest's hits and ``uv_object`` of
    the object's, the tracers' :meth:`RayTracer.hit`; None: the face normal), the shadow-ray
    origin (the offset of kernels/hit.h along the face normal, the object's floor
    ``object_offset``), the four shading uniforms (stream rng.MOVING_MIS, stratified over the
    pixel's spp samples: :func:`stratified_uniforms`), the environment's radiance for misses
    (0 for hits) and the face normal turned towards the viewer; and the material (N,) (-1 for a
    miss)."""
    d = np.asarray(d, np.float32)
    prim, prim_object = np.asarray(prim), np.asarray(prim_object)
    t, t_object = np.asarray(t, np.float32), np.asarray(t_object, np.float32)
    count = len(d)
    eye = np.asarray(scene.camera.eye, np.float32)
    on_object = (prim_object >= 0) & ((prim < 0) | (t_object < t))
    hit = on_object | (prim >= 0)
    out = np.zeros((16, count))
    material = np.full(count, -1, np.int64)
    rest = np.flatnonzero(hit & ~on_object)
    if uv is not None and tracer.smooth:
        n, g, _, origin = tracer.hit(eye, d[rest], t[rest], prim[rest], np.asarray(uv[0])[rest],
                                     np.asarray(uv[1])[rest])
    else:
        n, _, origin = tracer.surface(eye, d[rest], t[rest], prim[rest])
        g = n
    out[0:3, rest], out[3:6, rest], out[13:16, rest] = n.T, origin.T, g.T
    material[rest] = scene.face_material[prim[rest]]
    ob = np.flatnonzero(on_object)
    m = (object_tracer.face_normals[prim_object[ob]].astype(np.float64) @ np.asarray(R, np.float64).T)
    m *= np.where(np.einsum("ij,ij->i", m, d[ob]) > 0, -1.0, 1.0)[:, None]
    p = eye.astype(np.float64) + d[ob] * t_object[ob, None].astype(np.float64)
    eps = np.maximum(np.maximum(raytrace.OFFSET_RELATIVE * np.abs(p).max(1, initial=0.0), object_offset),
                     RayTracer.eye_offset_floor(eye))
    out[3:6, ob], out[13:16, ob] = (p + m * eps[:, None]).T, m.T
    ns = m
    if uv_object is not None and object_tracer.smooth and len(ob):   # the object's own corner normals, turned
        c = object_tracer.shading_normals[object_tracer.corner_normals[prim_object[ob]]].astype(np.float64)
        a, b = np.asarray(uv_object[0], np.float64)[ob, None], np.asarray(uv_object[1], np.float64)[ob, None]
        s = ((1.0 - a - b) * c[:, 0] + a * c[:, 1] + b * c[:, 2]) @ np.asarray(R, np.float64).T
        length = np.linalg.norm(s, axis=1, keepdims=True)
        ok = length ** 2 > raytrace.SMOOTH_MIN_LENGTH2
        ns = np.where(ok, s / np.where(ok, length, 1.0), m)
        ns *= np.where(np.einsum("ij,ij->i", ns, d[ob]) > 0, -1.0, 1.0)[:, None]
    out[0:3, ob] = ns.T
    material[ob] = object_material
    out[6:10] = stratified_uniforms(seed, tile, rng.MOVING_MIS, first, slots, spp).T
    miss = np.flatnonzero(~hit)
    out[10:13, miss] = environment.eval(d[miss].astype(np.float64)).T
    return out, material


class _MovingKernels:
    """The kernels of kernels/relight_moving.cl with their tables: the rest's face normals (and
    shadow-ray offset floors) and materials, the object's face normals in its own frame, the
    lighting inside the texels (running sums of each texel's leaf masses, float32) and the
    environment's texels (shared with the shader)."""

    def __init__(self, rest, tracer, object_tracer, inside, shader, n_levels, directions):
        def rows(t):
            out = np.zeros((max(len(t.face_normals), 1), 4), np.float32)
            out[:len(t.face_normals), :3] = t.face_normals
            out[:len(t.face_normals), 3] = t.face_offset_floor
            return cl.to_device(out)

        def smooth(t):   # the shading normals' corner rows and table, and whether any face uses them
            corners = t.corner_normals if len(t.corner_normals) else np.zeros((1, 3), np.int32)
            return (cl.to_device(np.ascontiguousarray(corners, np.int32)),
                    cl.to_device(np.ascontiguousarray(t.shading_normals, np.float32)), np.int32(t.smooth))

        self.faces, self.object_faces = rows(tracer), rows(object_tracer)
        self.smooth, self.object_smooth = smooth(tracer), smooth(object_tracer)
        materials = rest.face_material if len(rest.face_material) else np.zeros(1, np.int32)
        self.face_material = cl.to_device(np.asarray(materials, np.int32))
        albedo = np.zeros((len(rest.materials), 4), np.float32)
        albedo[:, :3] = rest.material_albedo
        self.kind = cl.to_device(rest.material_kind.astype(np.int32))
        self.param = cl.to_device(rest.material_param.astype(np.float32))
        self.albedo = cl.to_device(albedo)
        self.table = cl.to_device(np.ascontiguousarray(rest.material_table, np.float32).reshape(-1)
                                  if len(rest.materials) else np.zeros(bsdfs.PLASTIC_STRIDE, np.float32))
        self.cdf = cl.to_device(np.ascontiguousarray(inside.cdf, np.float32))
        self.k = np.uint32(inside.k)
        self.directions = int(directions)
        self.shader = shader
        kinds = int(np.bitwise_or.reduce(1 << np.asarray(rest.material_kind, np.int64), initial=0)) or 1
        self.program = cl.program("relight_moving.cl", N_LEVELS=int(n_levels), BSDF_KINDS=kinds, ND=self.directions,
                                  OFFSET_RELATIVE=repr(float(np.float32(raytrace.OFFSET_RELATIVE))))

    def occlusion(self, eye, d, prim, t, slots, trees, tree_offset: int, spp: int, seed: int, tile: int, first: int,
                  place, box, uv=None) -> Records:
        """The ``moving_occlusion`` kernel's records (as :func:`occlusion_records_reference`
        returns them) and then ``moving_compact``: the uniforms drawn in the kernel, pixel
        slot // spp's tree at ``tree_offset`` + that in ``trees``."""
        count = len(d)
        if count == 0:
            return _no_records()
        q = cl.thread_queue()
        groups = -(-count // cl.LANES)
        nd = self.directions
        region = cl.scratch("moving_region", 4 * RECORD * cl.LANES * nd * groups)
        counts = cl.scratch("moving_counts", 4 * groups)
        sh = self.shader
        cl.kernel(self.program, "moving_occlusion")(
            q, (cl.items(count, cl.LANES),), (cl.WORK_GROUP,), np.uint32(count),
            cl.upload("moving_slot", np.asarray(slots, np.uint32), q),
            cl.upload("moving_dirs", np.asarray(d, np.float32), q),
            cl.upload("moving_prim", np.asarray(prim, np.int32), q),
            cl.upload("moving_t", np.asarray(t, np.float32), q),
            *np.asarray(eye, np.float32), RayTracer.eye_offset_floor(eye), self.faces, self.face_material,
            *self._bary("moving_bary", uv, self.smooth, q),
            self.kind, self.param, self.albedo, self.table, trees.buffer, np.uint32(trees.stride), np.uint32(tree_offset),
            np.uint32(spp), self.cdf, self.k, sh.texels, *sh.env_size, sh.rot, np.float32(DEFENSIVE),
            cl.upload("moving_place", np.asarray(place, np.float32), q),
            cl.upload("moving_box", np.asarray(box, np.float32), q), cl.upload("moving_sphere", _sphere(place, box), q),
            np.uint32(tile), np.uint32(rng.MOVING_DIRECTIONS), np.uint32(first),
            *(np.uint32(x) for x in rng.key(seed)), region, counts)
        n = cl.read(counts, (groups,), np.uint32, q)
        offsets = np.zeros(groups, np.uint32)
        np.cumsum(n[:-1], out=offsets[1:])
        total = int(offsets[-1]) + int(n[-1])
        if total == 0:
            return _no_records()
        out = cl.scratch("moving_records", 4 * RECORD * total)
        cl.kernel(self.program, "moving_compact")(
            q, (cl.items(groups),), (cl.WORK_GROUP,), np.uint32(groups), region, counts,
            cl.upload("moving_offsets", offsets, q), out)
        rec = cl.read(out, (total, RECORD), np.uint32, q)
        values = rec[:, 1:].view(np.float32)
        return Records(rec[:, 0] // np.uint32(nd), rec[:, 0] % np.uint32(nd), values[:, 0:3], values[:, 3:6],
                       values[:, 6:9])

    def _bary(self, name, uv, smooth, q):
        """The kernels' barycentrics buffer (rows u, v), the tables and the flag of ``smooth`` (flat
        where ``uv`` is None)."""
        flag = smooth[2] if uv is not None else np.int32(0)
        bary = (cl.upload(name, np.stack([np.asarray(uv[0], np.float32), np.asarray(uv[1], np.float32)], 1), q)
                if flag else smooth[1])   # (not read when flat)
        return bary, smooth[0], smooth[1], flag

    def points(self, eye, d, prim, t, prim_object, t_object, slots, place, object_material: int,
               object_offset: float, spp: int, seed: int, tile: int, first: int, uv=None, uv_object=None):
        """The ``moving_points`` kernel: (planes (16, N) float32, material (N,) int32) as
        :func:`shading_points_reference` returns them."""
        count = len(d)
        q = cl.thread_queue()
        out = cl.scratch("moving_points", 4 * 16 * max(count, 1))
        mat = cl.scratch("moving_material", 4 * max(count, 1))
        if count:
            sh = self.shader
            cl.kernel(self.program, "moving_points")(
                q, (cl.items(count, cl.LANES),), (cl.WORK_GROUP,), np.uint32(count),
                cl.upload("moving_slot", np.asarray(slots, np.uint32), q),
                cl.upload("moving_dirs", np.asarray(d, np.float32), q),
                cl.upload("moving_prim", np.asarray(prim, np.int32), q),
                cl.upload("moving_t", np.asarray(t, np.float32), q),
                cl.upload("moving_prim_object", np.asarray(prim_object, np.int32), q),
                cl.upload("moving_t_object", np.asarray(t_object, np.float32), q),
                *np.asarray(eye, np.float32), RayTracer.eye_offset_floor(eye), self.faces, self.face_material,
                *self._bary("moving_bary", uv, self.smooth, q), self.object_faces,
                *self._bary("moving_bary_object", uv_object, self.object_smooth, q), np.int32(object_material),
                np.float32(object_offset),
                cl.upload("moving_place", np.asarray(place, np.float32), q),
                sh.texels, *sh.env_size, sh.rot, np.uint32(spp), np.uint32(tile), np.uint32(rng.MOVING_MIS),
                np.uint32(first), *(np.uint32(x) for x in rng.key(seed)), out, mat)
        return cl.read(out, (16, count), np.float32, q), cl.read(mat, (count,), np.int32, q)

    def warm_up(self, eye, trees):
        """A tiny and a large launch of each kernel (PoCL compiles per work-group size and again
        for large grids; shading.KernelShader.warm_up), once per process and program."""
        if self.program in _WARMED:
            return
        place = np.float32([1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0])
        box = np.float32([-1, -1, -1, 1, 1, 1])
        for count in (1, 1 << 16):
            d = np.tile(np.float32([0.0, 0.0, 1.0]), (count, 1))
            zeros, ones = np.zeros(count, np.int32), np.ones(count, np.float32)
            self.occlusion(eye, d, zeros, ones, np.zeros(count, np.uint32), trees, 0, 1, 0, 0, 0, place, box)
            self.points(eye, d, zeros, ones, zeros - 1, ones, np.arange(count, dtype=np.uint32), place, 0, 0.0, 1,
                        0, 0, 0)
        _WARMED.add(self.program)


def _object_normals(scene, ob) -> dict:
    """The object's shading normals in its own frame (after its scale, before its rotation) and
    its faces' corner rows of them: RayTracer's ``normals`` and ``normal_faces``."""
    rows = (np.full((len(ob.faces), 3), -1, np.int64) if scene.normal_faces is None
            else np.asarray(scene.normal_faces[ob.faces_range[0]:ob.faces_range[1]], np.int64))
    local = ob.local_normals if ob.local_normals is not None else np.zeros((0, 3))
    return {"normals": np.asarray(local, np.float32),
            "normal_faces": np.where(rows >= 0, rows - ob.normals_range[0], -1)}


def _sphere(place, box) -> np.ndarray:
    """(4,) float32: the centre (world) and radius of the sphere through the corners of the box
    (6,) of the object's own frame, the object at ``place`` (R row-major, then T), a little grown."""
    place, box = np.asarray(place, np.float64), np.asarray(box, np.float64)
    centre = place[:9].reshape(3, 3) @ ((box[:3] + box[3:]) / 2) + place[9:]
    radius = np.linalg.norm(box[3:] - box[:3]) / 2 * (1 + BOX_MARGIN)
    return np.append(centre, radius).astype(np.float32)


def _no_records() -> Records:
    return Records(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3), np.float32),
                   np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32))


class _Chunk:
    """What a chunk's frames of one seed and spp share: its camera rays and their hits on the
    rest (they do not depend on the object's place)."""

    def __init__(self, d, prim, t, uv):
        self.d, self.prim, self.t, self.uv = d, prim, t, uv


class MovingObject:
    """The moving object's frames for one bake: the scene (checked against the bake), the tracers
    of the rest and of the object (in its own frame), the lighting, the per-pixel products and,
    with ``backend="opencl"``, the kernels (module docstring)."""

    def __init__(self, transfer, scene=None, backend: str = "opencl", directions: int = DIRECTIONS):
        if transfer.varies != "object":
            raise WavlightError(f"{transfer.path}: this bake varies the {transfer.varies}, "
                                "not an object")
        if backend not in BACKENDS:
            raise ArgumentError(f"relight.moving: backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
        self.directions = check_int("relight.moving", "directions", directions, 1, MAX_DIRECTIONS)
        self.transfer, self.backend = transfer, backend
        self.scene = scene_of(transfer, scene)
        info = transfer.header["object"]
        if info["index"] >= len(self.scene.objects) or info.get("name") != self.scene.objects[info["index"]].name:
            raise WavlightError(f"{transfer.path}: its moving object, {info['index']} ({info.get('name')}), is not "
                                f"one of the scene's")
        self.object = self.scene.find_object(info["index"])
        self.rest = self.scene.without(self.object)
        self.rest_tracer = RayTracer(self.rest.vertices, self.rest.faces, threads=2, normals=self.rest.normals,
                                     normal_faces=self.rest.normal_faces)
        self.object_tracer = RayTracer(self.object.local, self.object.faces, threads=2,
                                       **_object_normals(self.scene, self.object))
        self._faces = tuple(np.ascontiguousarray(self.object.faces[:, j], np.int64) for j in range(3))
        self.center, self.radius = bounding_sphere(self.object.local)   # the scene's object (its hash checked)
        self._box = (self.object.local.min(0).astype(np.float64), self.object.local.max(0).astype(np.float64))
        env = transfer.environment()
        rot = transfer.scene_rotate_y
        if rot != check_degrees(self.scene.path, "rotate_y", self.scene.environment.rotate_y):
            raise WavlightError(f"{transfer.path}: its map is turned by {rot:g} degrees, the scene's by "
                                f"{self.scene.environment.rotate_y:g}")
        self.environment = Environment(env.pixels, 1.0, rot, env.name)   # radiance lookups, turned
        self.m = int(transfer.header["product_levels"])
        self.inside = TexelLight(env, self.m, rot, map_pixels=False)   # as its kernel: uniform in a leaf
        sc = self.scene
        # the pixels rendered in full: the wavelet strategy, its budget from the scene's own shadows
        # (the object at its place in the scene file), as a render of the scene chooses it
        self.wavelet = strategies.make("wavelet")
        if self.wavelet.wants_visibility:
            whole = RayTracer(sc.vertices, sc.faces, threads=2)
            self.wavelet.fit_to_visibility(occlusion.visibility_variance(sc, whole, transfer.width, transfer.height))
            del whole
        self.wavelet.prepare(self.environment, sc.materials)
        lit = SimpleNamespace(environment=self.environment, material_kind=sc.material_kind,
                              material_param=sc.material_param, material_albedo=sc.material_albedo,
                              materials=sc.materials, face_material=sc.face_material,
                              material_table=sc.material_table)   # (plastic's rows)
        self.static = np.asarray(transfer._s["static"], np.float64)
        self.static_se = np.asarray(transfer._s["static_stderr"], np.float64)
        self._static_rows = self.static.reshape(-1, 3)
        self._static_var = self.static_se.reshape(-1, 3) ** 2
        self.leaves = transfer._s["product_leaves"]
        self._trees, self._tree_bytes, self._all_trees = {}, 0, None
        self._centre_rays = (None, None)
        self._mask_key, self._mask = None, None
        self._kept, self._chunks = {}, {}   # (seed, spp) -> the chunks' camera rays; this frame's
        self._kernels = None
        self._pool = ThreadPoolExecutor(default_threads())
        self._lock, self._tree_lock = threading.Lock(), threading.Lock()
        if backend == "opencl":
            self._shader = KernelShader(lit, self.wavelet)
            self._kernels = _MovingKernels(self.rest, self.rest_tracer, self.object_tracer, self.inside, self._shader,
                                           self.m, self.directions)
            self._kernels.warm_up(sc.camera.eye, HaarTree(np.ones((1, 1 << self.m, 1 << self.m), np.float32)))
            self._product_trees(0, 1)   # the whole image's trees where they fit: made with the bake's loading
        else:
            self._shader = NumpyShader(lit, self.wavelet)

    # -- the object's place
    def placement(self, translate=None, rotate=None):
        """(R (3, 3), T (3,)) of the object at ``translate`` and ``rotate`` [axis, degrees]
        (absolute, replacing its own keys; None keeps them)."""
        where = "relight.moving"
        ob = self.object
        t = ob.translate if translate is None else check_real(where, "translate", translate, finite=True).reshape(-1)
        if np.shape(t) != (3,) or np.abs(t).max() > MAX_COORDINATE:
            raise ArgumentError(f"{where}: translate must be three numbers within the ray tracer's range (|x| <= "
                                f"{MAX_COORDINATE:g}), got {np.asarray(t).tolist()}")
        r = ob.rotate if rotate is None else check_real(where, "rotate", rotate, finite=True).reshape(-1)
        if r is not None:
            r = np.asarray(r, np.float64)
            if r.shape != (4,) or not np.abs(r[:3]).max() > 0:
                raise ArgumentError(f"{where}: rotate must be [axis x, y, z, degrees] with a non-zero axis")
            # the axis is a direction (scaled first: its length may overflow), the angle reduced
            r = [*(r[:3] / np.abs(r[:3]).max()), check_degrees(where, "rotate's angle", r[3])]
        return rotation(r), np.asarray(t, np.float64)

    def _object_pixels(self, R, T, width, height):
        """(H, W) bool: the pixels a camera sample of which may see the object: those whose
        footprint's cone meets the object's bounding sphere and lies in the bounding box of one of
        its triangles' projections (grown by a pixel), a test of the place alone, conservative
        (every pixel one of whose samples could hit the object is in it). Kept for the next
        frame at the same place."""
        key = (width, height, np.asarray(R, np.float64).tobytes(), np.asarray(T, np.float64).tobytes())
        if key == self._mask_key:
            return self._mask
        near = self._sphere_pixels(R, T, width, height)
        xy, depth = project(self.scene.camera, self.object.local @ R.T + T, width, height)
        if near.any() and np.all(depth > 0):   # (a vertex behind the eye: the cone test alone)
            near = near & self._boxes(xy, width, height)
        self._mask_key, self._mask = key, near
        return near

    def _boxes(self, xy, width, height):
        """(H, W) bool: the union of the boxes of the triangles whose vertices project to xy
        (V, 2), each grown by a pixel."""
        # each vertex's pixel (clipped just outside the image: the boxes' overlaps stay the same)
        cx = np.floor(np.clip(xy[:, 0], -2.0, width + 2.0)).astype(np.int32)
        cy = np.floor(np.clip(xy[:, 1], -2.0, height + 2.0)).astype(np.int32)
        f0, f1, f2 = self._faces
        x0, x1, x2, y0, y1, y2 = cx[f0], cx[f1], cx[f2], cy[f0], cy[f1], cy[f2]
        lo_x, hi_x = np.minimum(np.minimum(x0, x1), x2) - 1, np.maximum(np.maximum(x0, x1), x2) + 1
        lo_y, hi_y = np.minimum(np.minimum(y0, y1), y2) - 1, np.maximum(np.maximum(y0, y1), y2) + 1
        keep = (hi_x >= 0) & (hi_y >= 0) & (lo_x < width) & (lo_y < height)
        lo_x, lo_y = np.maximum(lo_x[keep], 0), np.maximum(lo_y[keep], 0)
        hi_x, hi_y = np.minimum(hi_x[keep], width - 1) + 1, np.minimum(hi_y[keep], height - 1) + 1
        # the union of the boxes: +1 at each box's first corner, -1 past its edges, summed up
        w1, size = width + 1, (height + 1) * (width + 1)
        plus = np.bincount(np.concatenate([lo_y * w1 + lo_x, hi_y * w1 + hi_x]), minlength=size)
        minus = np.bincount(np.concatenate([lo_y * w1 + hi_x, hi_y * w1 + lo_x]), minlength=size)
        marks = (plus - minus).reshape(height + 1, w1)
        return marks.cumsum(0).cumsum(1)[:height, :width] > 0

    def _sphere_pixels(self, R, T, width, height):
        """(H, W) bool: the pixels whose footprint's cone meets the object's bounding sphere."""
        cam = self.scene.camera
        c = R @ self.center + T
        if self._centre_rays[0] != (width, height):   # the pixels' centre rays, kept for the next frames
            py, px = np.mgrid[0:height, 0:width]
            d = camera_rays(self.scene, px.ravel(), py.ravel(), np.full((width * height, 2), 0.5), width, height)[1]
            self._centre_rays = ((width, height), d.astype(np.float64))
        d = self._centre_rays[1]
        to = c - np.asarray(cam.eye, np.float64)
        dist = np.linalg.norm(to)
        if dist <= self.radius:
            return np.ones((height, width), bool)
        half = np.arcsin(min(self.radius / dist, 1.0))
        # the pixel's own half-diagonal angle, from the vertical field of view
        pixel = np.radians(cam.fov_y) / height * 0.75
        return (d @ (to / dist) >= np.cos(min(half + pixel, np.pi))).reshape(height, width)

    def _trace_object(self, R, T, origins, dirs, closest=False):
        """Rays against the object alone, in its own frame (rigid: distances are kept); origins
        (N, 3), or (3,) for one origin of all rays (moved in float64: a far place keeps its
        precision; the directions in float32)."""
        d = np.asarray(dirs, np.float32) @ np.asarray(R, np.float32)
        o = ((np.asarray(origins, np.float64) - T) @ R).astype(np.float32)
        o = np.broadcast_to(o, d.shape) if o.ndim == 1 else o
        if closest:   # prim, t and the barycentrics (u, v)
            prim, t, u, v = self.object_tracer.intersect_uv(o, d)
            return prim, t, (u, v)
        return self.object_tracer.occluded(o, d)

    # -- a frame
    def frame(self, translate=None, rotate=None, spp=None, seed: int = FRAME["seed"].default) -> RenderResult:
        """The unbiased frame with the object at its new place (module docstring), with ``spp``
        camera samples per pixel (default OBJECT_FRAME_SPP). One frame at a time (the frames share
        what they keep)."""
        spp = FRAME["spp"].check(OBJECT_FRAME_SPP if spp is None else spp, "relight.moving")
        seed = FRAME["seed"].check(seed, "relight.moving")
        R, T = self.placement(translate, rotate)
        with self._lock:
            return self._frame(R, T, spp, seed)

    def _frame(self, R, T, spp, seed):
        t0 = time.perf_counter()
        tr = self.transfer
        width, height = tr.width, tr.height
        touched = self._object_pixels(R, T, width, height).reshape(-1)
        # samples per pixel of one pass: a frame of more takes them in passes (bounded memory)
        k = min(spp, PASS_SPP, max(1, CHUNK_SAMPLES // width))
        # the camera rays of the last KEPT_SEEDS (seed, spp) (the viewer's seed 0 at its two spp:
        # while dragging and at rest), for frames of one pass of at most KEPT_SAMPLES
        keep = k == spp and width * height * spp <= KEPT_SAMPLES
        self._chunks = (self._kept.pop((seed, spp), None) or {}) if keep else {}
        if keep:
            self._kept[(seed, spp)] = self._chunks
            while len(self._kept) > KEPT_SEEDS:
                self._kept.pop(next(iter(self._kept)))
        image = np.zeros((width * height, 3))
        error = np.zeros((width * height, 3))
        # chunks of whole rows: bounded memory, and at least MIN_CHUNKS where each keeps
        # MIN_CHUNK_SAMPLES, so that the pool's threads overlap one chunk's numpy with another's
        # rays and kernels (a constant, not the thread count: images do not depend on threads)
        rows = max(1, min(CHUNK_PIXELS // width, CHUNK_SAMPLES // (width * k)))
        rows = min(rows, max(-(-height // MIN_CHUNKS), -(-MIN_CHUNK_SAMPLES // (width * k))))

        def run(chunk):
            first, last = chunk * rows * width, min((chunk + 1) * rows, height) * width
            P = last - first
            sums, squares = np.zeros((P, 3)), np.zeros((P, 3))
            n_rays = 0
            for start in range(0, spp, k):   # passes of samples per pixel, not samples
                kk = min(k, spp - start)
                value, r = self._chunk(R, T, touched, first, last, kk, seed, chunk, start * P, keep)
                n_rays += r
                v = value.reshape(P, kk, 3)
                sums += v.sum(1)
                squares += np.einsum("pkc,pkc->pc", v, v)
            mean, err = mean_and_error(sums, squares, spp)
            image[first:last] = mean
            if spp > 1:
                error[first:last] = np.sqrt(err * err + np.where(touched[first:last, None], 0.0,
                                                                 self._static_var[first:last]))
            else:
                error[first:last] = np.inf
            return n_rays

        rays = sum(self._pool.map(run, range(-(-height // rows))))
        seconds = time.perf_counter() - t0
        stats = {"spp": spp, "seed": seed, "width": width, "height": height, "render_seconds": round(seconds, 4),
                 "rays": rays, "object_pixels": int(touched.sum()), "backend": self.backend, "pass_spp": k,
                 "pass_samples": min(height, rows) * width * k, "chunks": -(-height // rows),
                 "translate": T.tolist(), "directions": self.directions,
                 "wavelet_candidates": self.wavelet.candidates, "wavelet_slots": self.wavelet.slots,
                 "estimator": "static image minus the object's occlusion D; wavelet where the object may be seen"}
        return RenderResult(image.reshape(height, width, 3).astype(np.float32),
                            error.reshape(height, width, 3).astype(np.float32), stats)

    def _camera(self, chunk, first, last, spp, seed, start: int = 0, keep: bool = True):
        """The chunk's camera rays (whole rows first .. last - 1 of the image, spp jittered samples
        per pixel, stratified: Philox stream JITTER of tile FRAME_TILES + chunk, from sample
        ``start`` of the tile on) and their hits on the rest, with ``keep`` kept for the next
        frames of the seed and spp."""
        kept = self._chunks.get(chunk) if keep else None
        if kept is not None:
            return kept
        tr, scene = self.transfer, self.scene
        width, height = tr.width, tr.height
        P = last - first
        tile = FRAME_TILES + chunk
        if self.backend == "opencl" and P * spp < camera.MAX_PASS_RAYS:
            d = camera.pass_rays(scene, width, height, seed, tile, 0, first // width, width, P // width, spp, start,
                                 stratified=True)
        else:   # the same jitters in numpy
            pixels = np.arange(first, last)
            d = camera_rays(scene, np.repeat(pixels % width, spp), np.repeat(pixels // width, spp),
                            camera_jitter(seed, tile, P, spp, start), width, height)[1]
        eye = np.broadcast_to(scene.camera.eye.astype(np.float32), d.shape)
        prim, t, bu, bv = self.rest_tracer.intersect_uv(eye, d)
        kept = _Chunk(d, prim, t, (bu, bv))
        if keep:
            self._chunks[chunk] = kept
        return kept

    def _chunk(self, R, T, touched, first, last, spp, seed, chunk, start: int = 0, keep: bool = True):
        """(values (P S, 3) per sample of the chunk's pixels first .. last - 1, rays): one pass of
        spp samples per pixel, its random numbers from sample ``start`` of the chunk's tile on."""
        cam = self._camera(chunk, first, last, spp, seed, start, keep)
        P = last - first
        touched = touched[first:last]
        full = np.repeat(touched, spp) if spp > 1 else touched   # samples of pixels rendered in full
        static = self._static_rows[first:last]
        value = np.repeat(static, spp, axis=0) if spp > 1 else static.copy()
        rays = P * spp
        # the others: S_p minus the object's occlusion D at each sample
        rest = np.flatnonzero(~full & (cam.prim >= 0))
        if len(rest):
            D, r = self._occlusion(R, T, cam, rest, first, last, spp, seed, chunk, start)
            rays += r
            value[rest] -= D
        # pixels that may see the object: the wavelet strategy against the moved scene
        idx = np.flatnonzero(full)
        if len(idx):
            value[idx], r = self._full(R, T, cam, idx, spp, seed, chunk, start)
            rays += r
        return value, rays

    def _product_trees(self, first, last):
        """(HaarTree of the products T1 x L, index of pixel ``first``'s tree in it): one tree per
        pixel; they do not depend on the object's place, so they are kept for the next frames
        (the whole image's in one HaarTree where it fits in TREE_CACHE_BYTES, else the chunks'
        while they fit; larger images rebuild the chunks beyond)."""
        side = 1 << self.m
        n_pixels = self.transfer.width * self.transfer.height
        whole = self.backend == "opencl" and 4 * n_pixels * tree_stride(self.m) <= TREE_CACHE_BYTES
        if whole:
            with self._tree_lock:   # (the frame's chunks share it)
                if self._all_trees is None:
                    leaves = np.asarray(self.leaves[:n_pixels], np.float32).reshape(n_pixels, side, side)
                    self._all_trees = HaarTree(np.maximum(leaves, 0.0))
            return self._all_trees, first
        key = (first, last)
        with self._tree_lock:
            if key in self._trees:
                return self._trees[key], 0
        leaves = np.asarray(self.leaves[first:last], np.float32).reshape(last - first, side, side)
        made = HaarTree(np.maximum(leaves, 0.0))
        size = 4 * made.n_trees * made.stride
        with self._tree_lock:
            if key not in self._trees and self._tree_bytes + size <= TREE_CACHE_BYTES:
                self._trees[key] = made
                self._tree_bytes += size
        return made, 0

    def _place(self, R, T):
        """The object's place for the kernels, (12,) float32 (R row-major, then T), and its box in
        its own frame grown by BOX_MARGIN of its size and of the coordinates' (float32 rounding of
        the rays and of their move into the object's frame), (6,) float32 (lo, hi)."""
        lo, hi = self._box
        size = float(np.max(hi - lo)) + float(np.abs(T).max()) + float(np.abs(np.concatenate([lo, hi])).max())
        size = max(size, float(self.rest_tracer.scale))
        grow = BOX_MARGIN * size
        place = np.concatenate([np.asarray(R, np.float64).ravel(), np.asarray(T, np.float64)]).astype(np.float32)
        return place, np.concatenate([lo - grow, hi + grow]).astype(np.float32)

    def _occlusion(self, R, T, cam, rest, first, last, spp, seed, chunk, start: int = 0):
        """(D (len(rest), 3), rays) at the chunk's samples ``rest`` (which hit the rest of the
        scene): per sample the mean of its ``directions`` directions' contributions where the
        object blocks them and the rest does not (directions that miss the object's box are not
        traced: D is 0 there exactly)."""
        trees, offset = self._product_trees(first, last)
        place, box = self._place(R, T)
        tile = FRAME_TILES + chunk
        D = np.zeros((len(rest), 3))
        rays = 0
        batch = max(1, OCCLUSION_BATCH // self.directions)
        for b0 in range(0, len(rest), batch):   # launches of bounded memory, not samples
            part = rest[b0:b0 + batch]
            if self.backend == "opencl":
                rec = self._kernels.occlusion(self.scene.camera.eye, cam.d[part], cam.prim[part], cam.t[part], part,
                                              trees, offset, spp, seed, tile, start, place, box,
                                              uv=(cam.uv[0][part], cam.uv[1][part]))
            else:
                rec = occlusion_records_reference(self.rest, self.rest_tracer, self.environment, self.inside, trees,
                                                  cam.d[part], cam.prim[part], cam.t[part], part, spp, self.directions,
                                                  seed, tile, start, place, box, offset,
                                                  uv=(cam.uv[0][part], cam.uv[1][part]))
            if not len(rec.sample):
                continue
            blocked = self.object_tracer.occluded(np.asarray(rec.origin, np.float32),
                                                  np.asarray(rec.direction, np.float32))
            hit = np.flatnonzero(blocked)
            rays += len(rec.sample)
            if len(hit):   # back to the world: world = R local + T
                origin = (np.asarray(rec.origin[hit], np.float64) @ R.T + T).astype(np.float32)
                direction = (np.asarray(rec.direction[hit], np.float64) @ R.T).astype(np.float32)
                rest_blocked = self.rest_tracer.occluded(origin, direction)
                rays += len(hit)
                hit = hit[~rest_blocked]
                at = np.asarray(rec.sample[hit], np.int64) + b0
                for c in range(3):   # channels, not samples
                    D[:, c] += np.bincount(at, weights=rec.value[hit, c], minlength=len(rest))
        return D / self.directions, rays

    def _full(self, R, T, cam, idx, spp, seed, chunk, start: int = 0):
        """(values (len(idx), 3), rays): the wavelet strategy against the moved scene at the chunk's
        samples ``idx`` (of pixels that may see the object): the closer hit of the rest's and the
        object's, its shading uniforms from sample ``start`` of the chunk's tile on."""
        eye = self.scene.camera.eye
        d, prim_r, t_r, slots = cam.d[idx], cam.prim[idx], cam.t[idx], idx
        uv = (cam.uv[0][idx], cam.uv[1][idx])
        prim_o, t_o, uv_o = self._trace_object(R, T, eye.astype(np.float32), d, closest=True)
        rays = len(idx)
        tile = FRAME_TILES + chunk
        # the object's own floor of the shadow-ray offset: its largest coordinate at this place
        c = R @ self.center + T
        object_offset = np.float32(raytrace.OFFSET_FLOOR * (float(np.abs(c).max()) + self.radius))
        place, _ = self._place(R, T)
        if self.backend == "opencl":
            planes, material = self._kernels.points(eye, d, prim_r, t_r, prim_o, t_o, slots, place,
                                                    self.object.material, object_offset, spp, seed, tile, start,
                                                    uv=uv, uv_object=uv_o)
        else:
            planes, material = shading_points_reference(self.rest, self.rest_tracer, self.object_tracer,
                                                        self.object.material, self.environment, d, prim_r, t_r,
                                                        prim_o, t_o, R, T, object_offset, slots, spp, seed, tile,
                                                        start, uv=uv, uv_object=uv_o)
        value = planes[10:13].T.astype(np.float64)   # misses: the environment
        hits = np.flatnonzero(material >= 0)
        if not len(hits):
            return value, rays
        n = np.ascontiguousarray(planes[0:3, hits].T)
        origin = np.ascontiguousarray(planes[3:6, hits].T, np.float32)
        u = np.ascontiguousarray(planes[6:10, hits].T, np.float32)
        g = np.ascontiguousarray(planes[13:16, hits].T)
        wi, val, offset = self._shader(n, -d[hits], material[hits], u, g=g, with_offset=True)
        # shadow rays for the non-zero estimates of every slot, in one batch (as the integrator's
        # visible_sum): against the rest, then the unblocked ones against the object
        val = np.asarray(val).transpose(1, 2, 0)   # planes (slot, component, point): the kernel's layout
        slot, pt = np.nonzero(np.maximum(np.maximum(val[:, 0], val[:, 1]), val[:, 2]) > 0)
        w = np.take(np.asarray(wi, np.float32).reshape(-1, 3), pt * val.shape[0] + slot, axis=0)
        o = np.take(origin, pt, axis=0)
        blocked = self.rest_tracer.occluded(o, w)
        free = np.flatnonzero(~blocked)
        if len(free):   # in the object's frame: each point's origin moved once, not each ray's
            local = ((origin.astype(np.float64) - T) @ R).astype(np.float32)
            blocked[free] = self.object_tracer.occluded(np.take(local, pt[free], axis=0),
                                                        w[free] @ np.asarray(R, np.float32))
        rays += len(pt) + len(free)
        visible = np.zeros((val.shape[0], len(hits)), val.dtype)
        visible[slot, pt] = ~blocked
        total = np.asarray(offset, np.float64).T.copy()
        for j in range(val.shape[0]):   # the strategy's slots, not samples
            total += val[j] * visible[j]
        value[hits] = total.T
        return value, rays


def moving_frame(transfer, translate=None, rotate=None, spp=None, seed: int = FRAME["seed"].default, scene=None,
                 backend: str = "opencl") -> RenderResult:
    """One unbiased frame of a bake with ``vary="object"`` with the object at ``translate`` and
    ``rotate`` (absolute; None keeps its own): :class:`MovingObject` (made once per call; keep
    one for many frames)."""
    return MovingObject(transfer, scene, backend).frame(translate, rotate, spp, seed)
