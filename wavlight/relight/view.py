"""Frames from a moving camera from precomputed transfer (Chen & Gao sec. 2.2, eq. 6-8, with the
view as the varying factor): the lighting and the objects stay fixed, the camera moves.

    B(x, wo) = integral of L(w) V(x, w) max(cos theta, 0) f_r(x, w, wo) dw = <T1(x), T2>,
    T1(x, w) = L(w) V(x, w) max(cos theta, 0)  (per surface point, baked),
    T2 = f_r(x, ., wo)  (per frame; the albedo factored out: f_r = albedo x shape).

The surface cache. T1 depends on the surface point, not on the camera, so it is baked on points
spread over every object's surface: each scene face of area A carries a triangular lattice of
(k + 1)(k + 2) / 2 points, k = ceil(sqrt(2 A D)) (about D points per unit area; and at least
longest edge / 2 h, h = sqrt(2 / (sqrt(3) D)) the spacing of an equilateral lattice of density
D), D the density in points per unit area (default: CACHE_POINTS over the scene's area,
:mod:`wavlight.relight.settings`); lattice points that coincide (shared vertices and edges of one object)
are one cache point, whose normal is the area-weighted mean of its faces' shading normals there
(the corner normals interpolated at the lattice point, turned to the face normal's side: the
face normal where a face is shaded flat; docs/decisions/shading-normals.md). A camera ray's
hit on face F at barycentric (u, v) lies in one lattice triangle of F: its three points and
their barycentric weights are the hit's cache points (points of the same object; a point whose
normal is more than CREASE_DEGREES from the face's is left out, the others renormalized).
Surfaces are cached on the side their faces' normals point to (outwards on closed meshes, as
the file gives a quad's normal); a hit on a face's other side has no cache (black in the
approximate frame; the unbiased frame is exact there too).

The bake. For cache point x and texel t of the world-frame lat-long square (2^n x 2^n texels,
the convention of :mod:`.lighting`), T1_t(x) = L_t G_t(x), G_t(x) = integral over t of V(x, w)
max(cos, 0) dw (solid angle, sin theta included) and L_t the fixed lighting's exact mean radiance
over the texel (:func:`.lighting.project`): <T1, f_r> with these texels is the integral up to the
covariance of L, V cos and f_r inside a texel (a sun smaller than a texel keeps its energy but
its shadows blur to the texel's size). G_t is estimated by the bake's texel kernel
(``bake_texel_rays``, :func:`wavlight.relight.bake.texel_rays`, a lambert "pixel" per cache
point): cos evaluated at TEXEL_POINTS stratified points of the texel, one shadow ray towards one
of them picked in proportion to cos: Omega_t mean(cos) V, unbiased for the texel's integral, and
no ray where L_t = 0 or the texel is below the horizon. The texels of each channel go through the
Haar transform; blocks of BLOCK^2 points (sorted by object and Morton order of position, so that
a block is a patch of surface) are compressed together (coefficient columns by decreasing energy
until what is left out is within the tolerance, :func:`wavlight.relight.store.compress_block`)
and quantized (a scale per coefficient and block, shared by the three channels).

The approximate frame (kernel ``view_product`` in kernels/relight_view.cl, numpy twin
:func:`product_reference`). Camera rays through the pixel centres (or the centres of S x S
sub-pixels, ``supersample``, their mean the pixel's value) are traced; each hit has its
three cache points and weights. The product <T1, f_r> is evaluated top-down over T1's quadtree:
a node's average from its parent's and its three wavelet coefficients (eq. 13), refined until
f_r is nearly constant over it (its angular radius r <= refine (delta + w) / g, delta the angle
from the lobe's axis, the mirror direction, w the lobe's width), then its average times f_r at its
centre (the midpoint rule); nodes below the shading normal's horizon are skipped. The midpoint
rule's first-order error is T1's mass inside the node times f_r's change across it, and a sun
puts much of the mass in a few nodes away from their centres: a node holding a share phi of
T1's mass (its channels' |average| times its area over the root's) is refined further, g =
max(1, sqrt(phi / mass)) rounded up to a power of two (docs/decisions/view-walk-mass.md). Two modes:

- ``point``: for every cache point k the hits use, B_k = <T1(x_k), f_r(x_k, ., wo_k)> with the
  point's own (area-averaged) normal and wo_k the direction to the eye; a pixel is its albedo
  times the barycentric blend of its three points' B_k. lambert points need only the scaling
  coefficient: B = T^_0 N^2 / pi. One product per point: the fastest.
- ``pixel``: per ray, B = <sum_k w_k T1(x_k), f_r(., wo) rho> (the product is linear in T1: the
  walk reads the three points' coefficients and blends them) with the hit's shading normal n (as
  ``mis`` shades: the face normal where the face is flat) and the pixel's own view direction, so
  that f_r is the pixel's. T1 holds
  max(cos, 0) at the points' normals, whose blend m = sum_k w_k n_k makes sum_k w_k T1_k =
  L V (m . w) above the points' horizons; with ``tau`` > 0 a leaf's factor rho (at most RHO_MAX)
  turns that cosine into the face's, max(n . w, 0) / (m . w) smoothed over the node
  (:func:`ramp`), and a node is also refined while |n - m| sin r > tau max(m . c, sin r,
  RHO_FLOOR) (T1 is small near m's horizon);
  ``tau`` = 0 keeps the baked cosine (rho = 1). lambert pixels take the scaling coefficient
  where rho is constant (tau = 0, or n along m), and walk otherwise.

Pixels whose ray misses see the environment (its nearest texel, :meth:`wavlight.envmap.Environment.eval`;
with ``background="bilinear"`` its filter, :meth:`~wavlight.envmap.Environment.eval_background`).

On the device (backend ``opencl``) a frame after its camera rays is three kernels: ``view_lookup``
(per ray its three cache points and weights, numpy twin :meth:`ViewFrames.hit_points`, and a
flag per cache point used), ``view_product`` over the flagged points (``point`` mode) and
``view_assemble`` (per ray the albedo times the blend of its points' B_k, or the environment's
texel; the numpy frame is its twin); only the flags, the nodes visited and the image come back.
``pixel`` mode reads the lookup's points and weights back and walks per pixel. The walk refines
a node by testing its four children together (float4 lanes, kernels/relight_view.cl).

Approximate by design: the texels, the cache's
spacing (shadows and highlights are interpolated between points), the compression and the
midpoint rule each leave an error; and one ray per pixel samples facets smaller than a pixel
where ``mis`` integrates over the pixel (benchmarks/relight_view.py measures both modes against
``mis``, with one and with 4 x 4 rays per pixel).

The unbiased frame (:meth:`ViewFrames.converge`, on the device: :mod:`wavlight.relight.view_converge`).
Each pixel's camera samples draw their directions from a defensive mixture: the product T1 x f_r
(visibility inside it: T1 holds V) of the cache at the hit of the pixel's centre ray, on 2^m x 2^m
texels (m = min(n, PRODUCT_LEVELS); the top-left 2^m x 2^m block of T1's coefficients is the
transform of its coarser texels, eq. 13), times f_r averaged over points of each texel for that
hit's normal and view, walked by the hierarchical warp (eq. 17-22), then inside the texel by the lighting's own
luminance at the map's resolution (:class:`wavlight.relight.mixture.TexelLight`); the BSDF; and
the lighting alone (a bright light that the bake's one shadow ray per texel hid from a cache
point's T1 is still found). Every direction is evaluated with the true f_r cos, the radiance and a
shadow ray, and weighted by the mixture's pdf (every technique's pdf, exact); the pixel's product
at the trees' texels is the control variate's known integral: unbiased whatever the cache's
approximations (tests/relight/test_relight_view.py checks it against ``mis``).
"""
from __future__ import annotations

import dataclasses
import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from .. import bsdfs, cl, haar
from ..camera import camera_rays
from ..envmap import LUMINANCE, Environment
from ..errors import ArgumentError, WavlightError, check_int, check_number, check_real
from ..integrator import RenderResult
from ..raytrace import SMOOTH_MIN_LENGTH2, RayTracer
from ..scene import MAX_COORDINATE, Camera, check_scene, load_scene, require_untextured
from ..threads import default_threads
from ..warp import frame as tangent_frame
from ..warp import to_local
from . import lighting, store
from .bake import BLOCK, PixelSamples, choose_model, texel_rays, texel_rays_reference
from .converge import PASS_SPP
from .mixture import TexelLight, check_shares, scene_of, square_to_world
from .frame import DeviceEntries
from .settings import BAKE, CACHE_POINTS, FRAME, UNBIASED_SPP, VIEW_TEXEL_POINTS, WRITTEN_SUPERSAMPLE
from .store import lattice_size
from .transfer import finish_bake

#: cache points per block of the bake file (one entry row holds their three channels)
POINTS = BLOCK * BLOCK
#: at most this many lattice entries (bounded memory)
MAX_LATTICE = 1 << 25
#: a cache point whose normal is further than this from the hit face's is not interpolated
CREASE_DEGREES = 60.0
#: the approximate frame refines a node until its angular radius is at most REFINE (delta + w) / g,
#: g = max(1, sqrt(phi / MASS)) for a node holding the share phi of T1's mass (0: g = 1)
REFINE = FRAME["refine"].default
MASS = FRAME["mass"].default
#: g is rounded up to a power of two 2^k, k <= MASS_STEPS (cos and sin of the scaled radius tabulated)
MASS_STEPS = 8
#: the unbiased frame's product texel levels at most (:mod:`wavlight.relight.view_converge`)
PRODUCT_LEVELS = 4
#: pixels per chunk of a frame (bounded memory)
CHUNK_PIXELS = 1 << 16
#: a view direction this close to the tangent plane is lifted to it (silhouette points)
MIN_COS_VIEW = 1e-3
#: the approximate frame's modes: a product per cache point or per pixel; :meth:`ViewFrames.frame`'s
#: default is the viewer's
MODES = FRAME["mode"].values
MODE = "point"
#: the pixel mode's cosine correction: a node is refined while the factor rho varies more than this
TAU = FRAME["tau"].default
#: rays per pixel of a frame: at most MAX_SUPERSAMPLE^2
MAX_SUPERSAMPLE = FRAME["supersample"].hi


def still_settings(refine: float = REFINE, mass: float = MASS, mode: str = FRAME["mode"].default,
                   supersample=None, tau: float = TAU) -> dict:
    """A written frame's settings (``wavlight frame``; the defaults are its records',
    :data:`wavlight.relight.settings.FRAME`): a product per ray at WRITTEN_SUPERSAMPLE^2 rays per
    pixel (2.8% from ``mis`` over the rough bunnies' frames, 3.3-3.4% on the bunny), where
    :meth:`ViewFrames.frame`'s defaults (``point``, one ray) are the viewer's
    (docs/decisions/view-point-mode.md). ``supersample`` None: WRITTEN_SUPERSAMPLE in ``pixel``
    mode, 1 in ``point`` mode (more rays do not sharpen its blend). Checked by :meth:`ViewFrames.frame`."""
    if supersample is None:
        supersample = WRITTEN_SUPERSAMPLE if mode == "pixel" else 1
    return {"refine": refine, "mass": mass, "mode": mode, "supersample": supersample, "tau": tau}


#: a written frame's settings where none are given
STILL = still_settings()


# ----------------------------------------------------------------------------- the surface cache
@dataclass
class SurfaceCache:
    """Points on the scene's surfaces (module docstring): position, normal (P, 3) float64, the
    material and a face of each point (P,); per scene face its lattice subdivisions k and first
    lattice entry; the cache point of every lattice entry."""

    position: np.ndarray
    normal: np.ndarray
    material: np.ndarray
    face: np.ndarray
    face_k: np.ndarray
    face_base: np.ndarray
    lattice: np.ndarray
    spacing: float
    density: float

    def __len__(self):
        return len(self.position)


def lattice_local(i, j, k):
    """The index inside its face's lattice of point (i, j) (i + j <= k): rows of constant j."""
    return j * (k + 1) - j * (j - 1) // 2 + i


def _morton3(q: np.ndarray) -> np.ndarray:
    """Morton codes of (N, 3) integers in [0, 1024)."""
    out = np.zeros(len(q), np.int64)
    for bit in range(10):   # bits, not points
        for axis in range(3):
            out |= ((q[:, axis] >> bit) & 1) << (3 * bit + axis)
    return out


def face_objects(scene) -> np.ndarray:
    """(F,) the object index of each face (0 for all where the scene lists no objects)."""
    obj = np.zeros(len(scene.faces), np.int64)
    for ob in scene.objects:   # objects, not faces
        obj[ob.faces_range[0]:ob.faces_range[1]] = ob.index
    return obj


def build_cache(scene, density=None, points: int = CACHE_POINTS) -> SurfaceCache:
    """The surface cache of ``scene`` at ``density`` points per unit area (default: ``points``
    over the scene's area): lattices on every face, coincident points of one object merged,
    sorted by object and Morton order (module docstring)."""
    where = "relight.view"
    v = scene.vertices.astype(np.float64)
    f = scene.faces.astype(np.int64)
    if not len(f):
        raise ArgumentError(f"{where}: the scene has no surfaces to cache")
    e0, e1 = v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]
    cross = np.cross(e0, e1)
    area = 0.5 * float(np.linalg.norm(cross, axis=1).sum())
    if not area > 0:
        raise ArgumentError(f"{where}: the scene's surfaces have no area")
    density = points / area if density is None else BAKE["density"].check(density, where)
    spacing = float(np.sqrt(2.0 / (np.sqrt(3.0) * density)))
    longest = np.maximum(np.maximum(np.linalg.norm(e0, axis=1), np.linalg.norm(e1, axis=1)),
                         np.linalg.norm(v[f[:, 2]] - v[f[:, 1]], axis=1))
    k = np.maximum(np.ceil(np.sqrt(np.linalg.norm(cross, axis=1) * density) - 1e-9),   # (k^2 / 2) / area = D
                   np.ceil(longest / (2.0 * spacing) - 1e-9))                          # no sliver of spacing > 2 h
    k = np.maximum(1, k).astype(np.int64)
    sizes = lattice_size(k)
    total = int(sizes.sum())
    if total > MAX_LATTICE:
        raise ArgumentError(f"{where}: a density of {density:g} points per unit area needs {total} lattice points "
                            f"(at most {MAX_LATTICE}): lower it")
    base = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    pos = np.zeros((total, 3))
    bary = np.zeros((total, 2))   # each lattice entry's (u, v) on its face
    entry_face = np.repeat(np.arange(len(f)), sizes)
    for kk in np.unique(k):   # distinct subdivisions, not faces
        faces = np.flatnonzero(k == kk)
        j, i = np.nonzero(np.arange(kk + 1)[:, None] + np.arange(kk + 1)[None, :] <= kk)
        local = lattice_local(i, j, kk)
        at = base[faces][:, None] + local[None, :]
        pos[at] = (v[f[faces, 0]][:, None] + (i / kk)[None, :, None] * e0[faces][:, None]
                   + (j / kk)[None, :, None] * e1[faces][:, None])
        bary[at, 0], bary[at, 1] = (i / kk)[None, :], (j / kk)[None, :]
    obj = face_objects(scene)[entry_face]
    extent = max(float(np.abs(v).max()), 1e-30)
    quant = np.round(pos / (extent * 2.0 ** -40)).astype(np.int64)
    keys = np.concatenate([obj[:, None], quant], 1)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    count = len(first)
    weighted = entry_normals(scene, entry_face, bary, cross)   # area x the shading normal there
    normal = np.stack([np.bincount(inverse, weighted[:, a], count) for a in range(3)], 1)
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    fallback = cross[entry_face[first]]
    normal = np.where(length > 0, normal / np.where(length > 0, length, 1.0),
                      fallback / np.maximum(np.linalg.norm(fallback, axis=1, keepdims=True), 1e-300))
    position = pos[first]
    point_obj = obj[first]
    # blocks are patches: by object, then Morton order inside the object's box
    lo = np.zeros((point_obj.max() + 1, 3))
    hi = np.ones((point_obj.max() + 1, 3))
    for o in np.unique(point_obj):   # objects, not points
        sel = point_obj == o
        lo[o], hi[o] = position[sel].min(0), position[sel].max(0)
    q = ((position - lo[point_obj]) / np.maximum(hi[point_obj] - lo[point_obj], 1e-30) * 1023.999).astype(np.int64)
    order = np.lexsort((_morton3(np.clip(q, 0, 1023)), point_obj))
    rank = np.empty(count, np.int64)
    rank[order] = np.arange(count)
    face = entry_face[first][order]
    material = (scene.face_material[face] if len(scene.face_material) else np.zeros(count)).astype(np.int32)
    return SurfaceCache(position[order], normal[order], material, face, k.astype(np.int32), base.astype(np.int64),
                        rank[inverse].astype(np.int32), spacing, float(density))


def entry_normals(scene, face: np.ndarray, bary: np.ndarray, cross: np.ndarray) -> np.ndarray:
    """(N, 3): at points (u, v) = ``bary`` of faces ``face``, the shading normal (the scene's
    corner normals interpolated, turned to the side of the face normal; the face normal where the
    face is flat or they cancel) times the face's |cross| (twice its area): ``cross[face]`` itself
    where flat."""
    c = cross[face]
    if scene.normal_faces is None or not len(face):
        return c
    table = np.concatenate([np.asarray(scene.normals, np.float64).reshape(-1, 3), np.zeros((1, 3))])
    rows = np.asarray(scene.normal_faces, np.int64)[face]
    n = table[np.where(rows < 0, len(table) - 1, rows)]
    u, v = bary[:, :1], bary[:, 1:]
    s = (1.0 - u - v) * n[:, 0] + u * n[:, 1] + v * n[:, 2]
    length = np.linalg.norm(s, axis=1, keepdims=True)
    ok = length ** 2 > SMOOTH_MIN_LENGTH2
    s = np.where(ok, s / np.where(ok, length, 1.0), 0.0)
    s *= np.where(np.einsum("ij,ij->i", s, c) < 0, -1.0, 1.0)[:, None]
    return np.where(ok, s * np.linalg.norm(c, axis=1, keepdims=True), c)


def barycentric(vertices: np.ndarray, faces: np.ndarray, face: np.ndarray, p: np.ndarray):
    """(u, v) with p = v0 + u (v1 - v0) + v (v2 - v0) on ``face`` (N,) for points p (N, 3)."""
    tri = faces[face].astype(np.int64)
    v0 = vertices[tri[:, 0]].astype(np.float64)
    e0, e1 = vertices[tri[:, 1]] - v0, vertices[tri[:, 2]] - v0
    d = np.asarray(p, np.float64) - v0
    d00, d01, d11 = (np.einsum("ij,ij->i", a, b) for a, b in ((e0, e0), (e0, e1), (e1, e1)))
    d20, d21 = np.einsum("ij,ij->i", d, e0), np.einsum("ij,ij->i", d, e1)
    den = d00 * d11 - d01 * d01
    den = np.where(den != 0, den, 1.0)
    u = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    return np.clip(u, 0.0, 1.0), np.clip(w, 0.0, 1.0)


def lattice_points(face_k: np.ndarray, face_base: np.ndarray, lattice: np.ndarray, face: np.ndarray, u, v):
    """The three cache points (N, 3) and barycentric weights (N, 3) of hits at (u, v) of faces
    (N,): the lattice triangle holding the hit (module docstring)."""
    k = face_k[face].astype(np.int64)
    fu, fv = np.asarray(u, np.float64) * k, np.asarray(v, np.float64) * k
    i = np.clip(fu.astype(np.int64), 0, k - 1)
    j = np.clip(fv.astype(np.int64), 0, k - 1 - i)
    a, b = np.clip(fu - i, 0.0, 1.0), np.clip(fv - j, 0.0, 1.0)
    upper = (a + b > 1.0) & (i + j <= k - 2)
    lo_w = np.stack([1.0 - a - b, a, b], 1)
    up_w = np.stack([a + b - 1.0, 1.0 - b, 1.0 - a], 1)
    weights = np.clip(np.where(upper[:, None], up_w, lo_w), 0.0, 1.0)
    ii = np.where(upper[:, None], np.stack([i + 1, i + 1, i], 1), np.stack([i, i + 1, i], 1))
    jj = np.where(upper[:, None], np.stack([j + 1, j, j + 1], 1), np.stack([j, j, j + 1], 1))
    local = lattice_local(ii, jj, k[:, None])
    return lattice[face_base[face][:, None] + local].astype(np.int64), weights


# ----------------------------------------------------------------------------- the BRDF factor
def brdf_reference(kind: np.ndarray, param: np.ndarray, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """f_r(wi, wo) without albedo and without cos theta_i, local frames (N, 3) (the kernel's
    ``view_brdf``; for cos_i > 0 it is :func:`wavlight.bsdfs.eval_cos` / cos_i)."""
    kind = np.broadcast_to(kind, len(wi))
    param = np.broadcast_to(np.asarray(param, np.float64), len(wi))
    out = np.full(len(wi), 1.0 / np.pi)
    ix, iy, iz = wi[:, 0], wi[:, 1], wi[:, 2]
    ox, oy, oz = wo[:, 0], wo[:, 1], wo[:, 2]
    ph = kind == bsdfs.PHONG
    if ph.any():
        ca = np.maximum(iz * oz - ix * ox - iy * oy, 0.0)[ph]
        with np.errstate(divide="ignore"):
            out[ph] = np.where(ca > 0, (param[ph] + 2) / (2 * np.pi) * ca ** param[ph], 0.0)
    gg = kind == bsdfs.GGX
    if gg.any():
        a2 = param[gg] ** 2
        h = wi[gg] + wo[gg]
        hh = np.einsum("ij,ij->i", h, h)
        ok = hh > 0
        nhz = np.where(ok, h[:, 2] / np.sqrt(np.where(ok, hh, 1.0)), 0.0)
        ih = np.einsum("ij,ij->i", wi[gg], h)
        d = nhz * nhz * (a2 - 1) + 1
        D = a2 / (np.pi * d * d)
        c2 = np.maximum(oz[gg] ** 2, 1e-30)
        g1o = np.where(oz[gg] > 0, 2 / (1 + np.sqrt(1 + a2 * np.maximum(1 - c2, 0) / c2)), 0.0)
        z = np.maximum(iz[gg], 0.0)
        gi = 2 / (z + np.sqrt(a2 + (1 - a2) * z * z))
        good = ok & (nhz > 0) & (ih > 0) & (oz[gg] > 0)
        out[gg] = np.where(good, D * g1o / (4 * np.maximum(oz[gg], 1e-30)) * gi, 0.0)
    return out


def lobe(kind: np.ndarray, param: np.ndarray, normal: np.ndarray, wo: np.ndarray):
    """Each item's lobe axis (the mirror direction; the normal for lambert) and width (as
    :func:`wavlight.bsdfs.lobe_width`: ggx 2 alpha, phong 1 / sqrt(e + 1), lambert pi / 2),
    world frame."""
    axis = 2.0 * np.einsum("ij,ij->i", wo, normal)[:, None] * normal - wo
    axis = np.where((kind == bsdfs.LAMBERT)[:, None], normal, axis)
    return axis, bsdfs.lobe_width(kind, param)


def lifted_view(normal: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """View directions (N, 3) at least MIN_COS_VIEW above the tangent plane (a silhouette point's
    mean normal may face slightly away from the eye)."""
    c = np.einsum("ij,ij->i", wo, normal)
    w = np.where((c < MIN_COS_VIEW)[:, None], wo + (MIN_COS_VIEW - c)[:, None] * normal, wo)
    return w / np.linalg.norm(w, axis=1, keepdims=True)


@dataclass
class NodeTables:
    """Per quadtree node (level order, node (l, x, y) at (4^l - 1) / 3 + y 2^l + x) its centre's
    world direction (float4, w = 0), and per node row (l, y) at 2^l - 1 + y: q = r / refine,
    cos and sin of it, and sin r (2 where r >= pi / 2: never wholly below a horizon), r the
    largest angle from the centre to the node's border (its region's farthest point); and per
    row and k = 1 .. MASS_STEPS (row-major) cos and sin of min(2^k q, pi), for the walk's g = 2^k."""

    centres: np.ndarray
    rows: np.ndarray
    radius: np.ndarray
    scaled: np.ndarray


_TABLES = {}


def node_tables(n_levels: int, refine: float) -> NodeTables:
    """The tables of a quadtree of n levels for ``refine`` (kept per pair)."""
    key = (int(n_levels), float(refine))
    found = _TABLES.get(key)
    if found is not None:
        return found
    centres, radius = [], []
    edge = np.linspace(0.0, 1.0, 65)
    for l in range(n_levels + 1):   # levels, not nodes
        s = 1 << l
        y, x = np.mgrid[0:s, 0:s]
        uv = np.stack([(x.ravel() + 0.5) / s, (y.ravel() + 0.5) / s], 1)
        centres.append(square_to_world(uv))
        # the border of node (0, y) of each row: rows are congruent under turns about +Y
        rows_y = np.arange(s)[:, None]
        border = np.concatenate([np.stack([edge + 0 * rows_y, 0 * edge + rows_y], -1),
                                 np.stack([edge + 0 * rows_y, 0 * edge + rows_y + 1], -1),
                                 np.stack([0 * edge + 0 * rows_y, edge + rows_y], -1),
                                 np.stack([0 * edge + 1 + 0 * rows_y, edge + rows_y], -1)], 1) / s
        b = square_to_world(np.clip(border.reshape(-1, 2), 0.0, 1.0)).reshape(s, -1, 3)
        c = square_to_world(np.stack([np.full(s, 0.5 / s), (np.arange(s) + 0.5) / s], 1))
        ang = np.arccos(np.clip(np.einsum("rkj,rj->rk", b, c), -1.0, 1.0)).max(1)
        radius.append(np.minimum(ang * (1 + 1e-3) + 1e-6, np.pi))
    r = np.concatenate(radius)
    q = r / refine
    rows = np.stack([q, np.cos(np.minimum(q, np.pi)), np.sin(np.minimum(q, np.pi)),
                     np.where(r < np.pi / 2, np.sin(r), 2.0)], 1).astype(np.float32)
    qk = np.minimum(q[:, None] * 2.0 ** np.arange(1, MASS_STEPS + 1), np.pi)
    scaled = np.stack([np.cos(qk), np.sin(qk)], -1).astype(np.float32)          # (rows, MASS_STEPS, 2)
    cen = np.zeros((sum(4 ** l for l in range(n_levels + 1)), 4), np.float32)
    cen[:, :3] = np.concatenate(centres)
    tables = _TABLES[key] = NodeTables(cen, rows, r, scaled)
    return tables


def _items(kind, param, normal, wo, t1_normal, tau):
    """(I, 16) float32 per item: shading normal, view direction, lobe axis, width, cos and sin of
    it, T1's normal, the cosine's correction tolerance."""
    axis, width = lobe(kind, param, normal, wo)
    tau = np.broadcast_to(np.asarray(tau, np.float64), len(kind))
    return np.concatenate([normal, wo, axis, width[:, None], np.cos(width)[:, None], np.sin(width)[:, None],
                           t1_normal, tau[:, None]], 1).astype(np.float32)


def _coefficients(offsets, scale, data, points: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """(len(points), 3, len(columns)) float64: the stored coefficients ``columns`` of the points
    (0 where a block keeps none)."""
    b, j = points // POINTS, points % POINTS
    o = np.asarray(offsets[np.asarray(columns, np.int64)[None, :], b[:, None]], np.int64)   # (I, C)
    keep = o >= 0
    oc = np.where(keep, o, 0)
    sc = np.where(keep, np.asarray(scale)[oc], 0.0)
    out = np.empty((len(points), 3, len(columns)))
    for c in range(3):   # channels
        out[:, c] = np.asarray(data)[oc, (c * POINTS + j)[:, None]] * sc
    return out


def _blended(offsets, scale, data, points: np.ndarray, weights: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """(I, C, 3) float64: sum_k weights[:, k] x coefficient columns[:, c] of points[:, k], per item
    its own columns (I, C)."""
    out = np.zeros(columns.shape + (3,))
    data = np.asarray(data)
    for k in range(points.shape[1]):   # the item's points (1 or 3)
        b, j = points[:, k] // POINTS, points[:, k] % POINTS
        o = np.asarray(offsets[columns, b[:, None]], np.int64)
        keep = o >= 0
        oc = np.where(keep, o, 0)
        sc = np.where(keep, np.asarray(scale)[oc], 0.0) * weights[:, k:k + 1]
        for c in range(3):   # channels
            out[:, :, c] += data[oc, (c * POINTS + j)[:, None]] * sc
    return out


def ramp(x, s):
    """The mean of max(x', 0) over x' uniform in [x - s, x + s] (the kernel's ``view_ramp``)."""
    x, s = np.asarray(x, np.float64), np.asarray(s, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        mid = (x + s) ** 2 / (4.0 * s)
    return np.where(x >= s, x, np.where(x <= -s, 0.0, mid))


#: the cosine's correction factor rho is at most RHO_MAX (a node near T1's horizon); its
#: refinement bounds |n - m| sin r by tau max(m . c, sin r, RHO_FLOOR) (the kernel's constants)
RHO_MAX = 4.0
RHO_FLOOR = 0.5


def mass_steps(share: np.ndarray) -> np.ndarray:
    """k = min(ceil(log2(share) / 2), MASS_STEPS) where share = phi / mass > 1, else 0 (NaN too):
    g = 2^k >= sqrt(share), ceil(log2) from the float32's exponent and mantissa bits as the
    kernel's ``view_mass_steps`` takes it (infinity: MASS_STEPS)."""
    share = np.atleast_1d(np.asarray(share, np.float32))
    bits = share.view(np.uint32).astype(np.int64)
    c = ((bits >> 23) & 0xFF) - 127 + ((bits & 0x7FFFFF) != 0)   # ceil(log2(share)) for share >= 1
    return np.where(share > 1.0, np.minimum((c + 1) // 2, MASS_STEPS), 0).astype(np.int64)


def product_reference(offsets, scale, data, n_levels: int, points: np.ndarray, kind, param, normal, wo,
                      refine: float = REFINE, weights=None, t1_normal=None, tau: float = 0.0,
                      mass: float = MASS):
    """numpy twin of ``view_product``: (B (I, 3) float64, nodes visited (I,)) for items (cache
    points ``points`` (I,) or (I, K) blended with ``weights`` (I, K), shaded with ``normal`` and
    view direction wo (world, unit), material kind and parameter; ``t1_normal`` the blend of the
    points' normals (default ``normal``), ``tau`` the cosine's correction tolerance, 0 for
    none, and ``mass`` the share of T1's mass above which a node refines further, 0 for none:
    kernels/relight_view.cl), level by level over the frontier of all items' nodes
    (float64; the kernel's float32 takes the same nodes but where a test lies within rounding
    of its threshold)."""
    points = np.asarray(points, np.int64)
    if points.ndim == 1:
        points = points[:, None]
    weights = np.ones(points.shape) if weights is None else np.asarray(weights, np.float64).reshape(points.shape)
    kind = np.asarray(kind, np.int64)
    param = np.asarray(param, np.float64)
    normal, wo = np.asarray(normal, np.float64), np.asarray(wo, np.float64)
    m_all = normal if t1_normal is None else np.asarray(t1_normal, np.float64)
    tau = float(tau)
    side = 1 << n_levels
    n2 = float(side * side)
    tables = node_tables(n_levels, refine)
    axis, width = lobe(kind, param, normal, wo)
    s_ax, t_ax = tangent_frame(normal)
    wo_l = to_local(wo, s_ax, t_ax, normal)
    ml = np.linalg.norm(m_all, axis=1)
    dn = np.linalg.norm(normal - m_all, axis=1)
    root = _blended(offsets, scale, data, points, weights, np.zeros((len(points), 1), np.int64))[:, 0]
    root_mass = np.abs(root).sum(1)
    per_mass = np.divide(1.0, root_mass * mass, out=np.zeros_like(root_mass), where=(root_mass > 0) & (mass > 0))
    out = np.zeros((len(points), 3))
    visited = np.ones(len(points), np.int64)
    lam = (kind == bsdfs.LAMBERT) & ((tau <= 0) | (np.einsum("ij,ij->i", normal, m_all) >= ml * (1 - 1e-6)))
    out[lam] = root[lam] * (n2 / np.pi / (np.maximum(ml[lam], 1e-6) if tau > 0 else np.ones(lam.sum())))[:, None]
    item = np.flatnonzero(~lam)
    x = np.zeros(len(item), np.int64)
    y = np.zeros(len(item), np.int64)
    avg = root[item]
    visited[item] = 0
    for level in range(n_levels + 1):   # levels of the tree, not nodes
        if not len(item):
            break
        s = 1 << level
        np.add.at(visited, item, 1)
        row = tables.rows[s - 1 + y].astype(np.float64)
        r_eps = tables.radius[s - 1 + y] / refine
        c = tables.centres[(s * s - 1) // 3 + y * s + x, :3].astype(np.float64)
        sin_r = np.where(tables.radius[s - 1 + y] < np.pi / 2, np.sin(tables.radius[s - 1 + y]), 1.0)
        nc = np.einsum("ij,ij->i", c, normal[item])
        live = nc >= -np.where(tables.radius[s - 1 + y] < np.pi / 2, sin_r, 2.0)
        k = mass_steps(np.abs(avg).sum(1) * per_mass[item] / (s * s))   # of phi / mass
        r_eps = r_eps * 2.0 ** k
        need = r_eps - width[item]
        at = (s - 1 + y) * MASS_STEPS + np.maximum(k - 1, 0)
        scaled = tables.scaled.reshape(-1, 2)[at].astype(np.float64)
        cq, sq = np.where(k > 0, scaled[:, 0], row[:, 1]), np.where(k > 0, scaled[:, 1], row[:, 2])
        cos_need = cq * np.cos(width[item]) + sq * np.sin(width[item])
        leaf = (need <= 0) | ((need < np.pi) & (np.einsum("ij,ij->i", c, axis[item]) <= cos_need))
        mc = np.einsum("ij,ij->i", c, m_all[item])
        if tau > 0:
            leaf &= sin_r * dn[item] <= tau * np.maximum(mc, np.maximum(sin_r, RHO_FLOOR))
        leaf |= level == n_levels
        at = live & leaf
        if at.any():
            ii = item[at]
            wl = np.stack([np.einsum("ij,ij->i", c[at], a[ii]) for a in (s_ax, t_ax, normal)], 1)
            f = brdf_reference(kind[ii], param[ii], wl, wo_l[ii])
            if tau > 0:
                den = ramp(mc[at], sin_r[at] * ml[ii])
                with np.errstate(divide="ignore", invalid="ignore"):
                    rho = np.where(den > 0, np.minimum(ramp(nc[at], sin_r[at]) / den, RHO_MAX), 0.0)
                f = f * rho
            np.add.at(out, ii, avg[at] * (n2 / (s * s) * f)[:, None])
        go = live & ~leaf
        if not go.any():
            break
        item, x, y, avg = item[go], x[go], y[go], avg[go]
        cols = np.stack([y * side + s + x, (s + y) * side + x, (s + y) * side + s + x], 1)   # (M, 3)
        cm = _blended(offsets, scale, data, points[item], weights[item], cols)              # (M, 3 m, 3 ch)
        c1, c2, c3 = cm[:, 0], cm[:, 1], cm[:, 2]
        kids = []
        for dy in (0, 1):   # the four children
            for dx in (0, 1):
                s1, s2 = (1 if dx == 0 else -1), (1 if dy == 0 else -1)
                kids.append((2 * x + dx, 2 * y + dy, avg + s * (s1 * c1 + s2 * c2 + s1 * s2 * c3)))
        item = np.concatenate([item] * 4)
        x = np.concatenate([k[0] for k in kids])
        y = np.concatenate([k[1] for k in kids])
        avg = np.concatenate([k[2] for k in kids])
    return out, visited


class ViewDevice:
    """The bake file's entries as device buffers (:class:`wavlight.relight.frame.DeviceEntries`)
    and the kernel ``view_product`` over them."""

    def __init__(self, transfer):
        s = transfer._s
        self.entries = DeviceEntries(s["offsets"], s["entry_scale"], s["entry_data"])
        self.n_levels, self.n_blocks = transfer.n_levels, int(s["offsets"].shape[1])
        self._tables = {}

    def walk(self, points, kind, param, normal, wo, refine: float = REFINE, weights=None, t1_normal=None,
             tau: float = 0.0, queue=None, mass: float = MASS):
        """Launch ``view_product`` on the items (see :func:`product_reference`): its output
        buffers, B (I, 3) float32 and nodes visited (I,) uint32, left on the device."""
        queue = queue or cl.thread_queue()
        points = np.asarray(points)
        count = len(points)
        per = 1 if points.ndim == 1 else points.shape[1]
        weights = np.ones(count * per, np.float32) if weights is None else np.asarray(weights, np.float32)
        tables = self._tables.get(refine)
        if tables is None:
            t = node_tables(self.n_levels, refine)
            tables = self._tables[refine] = (cl.to_device(t.centres), cl.to_device(t.rows),
                                             cl.to_device(t.scaled))
        prog = cl.program("relight_view.cl", QBITS=self.entries.bits, POINTS=POINTS, K=per, MASS_STEPS=MASS_STEPS)
        normal = np.asarray(normal, np.float64)
        geom = _items(np.asarray(kind), np.asarray(param, np.float64), normal, np.asarray(wo, np.float64),
                      normal if t1_normal is None else np.asarray(t1_normal, np.float64), tau)
        out = cl.scratch("view_walk_out", 12 * count)
        visited = cl.scratch("view_walk_visited", 4 * count)
        cl.kernel(prog, "view_product")(
            queue, (-(-count // cl.WORK_GROUP) * cl.WORK_GROUP,), (cl.WORK_GROUP,), np.uint32(count),
            np.uint32(self.n_levels), np.uint32(self.n_blocks),
            cl.upload("view_walk_points", np.ascontiguousarray(points, np.uint32), queue),
            cl.upload("view_walk_weights", np.ascontiguousarray(weights, np.float32), queue),
            cl.upload("view_walk_geom", geom, queue),
            cl.upload("view_walk_kind", np.asarray(kind, np.int32), queue),
            cl.upload("view_walk_param", np.asarray(param, np.float32), queue),
            tables[0], tables[1], tables[2], self.entries.offsets[0], self.entries.scale[0], self.entries.data[0],
            np.float32(mass), out, visited)
        return out, visited

    def products(self, points, kind, param, normal, wo, refine: float = REFINE, weights=None, t1_normal=None,
                 tau: float = 0.0, queue=None, mass: float = MASS):
        """(B (I, 3) float32, nodes visited (I,) uint32) of the items (see :func:`product_reference`)."""
        queue = queue or cl.thread_queue()
        count = len(points)
        if not count:
            return np.zeros((0, 3), np.float32), np.zeros(0, np.uint32)
        out, visited = self.walk(points, kind, param, normal, wo, refine, weights, t1_normal, tau, queue, mass)
        return cl.read(out, (count, 3), np.float32, queue), cl.read(visited, (count,), np.uint32, queue)


def device_has_doubles() -> bool:
    """Whether the OpenCL device computes in double precision (kernels/relight_view.cl's ``wide``)."""
    return "cl_khr_fp64" in cl.runtime().device.extensions.split()


class FrameDevice:
    """The frame's tables on the device, for the kernels ``view_lookup`` and ``view_assemble``
    (kernels/relight_view.cl): per face its lattice k, first entry, normal and material, the
    lattice's cache points, the points' normals, the materials' albedo, the environment's texels
    and rotation."""

    def __init__(self, frames, device: ViewDevice):
        self.points = len(frames.position)
        self.wide = np.float64 if device_has_doubles() else np.float32
        env = frames.environment
        self.face_k = cl.to_device(np.ascontiguousarray(frames.face_k, np.int32))
        self.face_base = cl.to_device(np.ascontiguousarray(frames.face_base, np.int64))
        self.lattice = cl.to_device(np.ascontiguousarray(frames.lattice, np.int32))
        self.normal = cl.to_device(np.ascontiguousarray(frames.normal32, np.float32))
        self.face_normal = cl.to_device(np.ascontiguousarray(frames.face_normal32, np.float32))
        self.face_material = cl.to_device(np.ascontiguousarray(frames.scene.face_material, np.int32))
        self.albedo = cl.to_device(np.ascontiguousarray(frames.albedo_of, np.float32).reshape(-1))
        self.env = cl.to_device(np.ascontiguousarray(env.pixels, np.float32).reshape(-1))
        self.env_size = (np.uint32(env.width), np.uint32(env.height))
        self.map_from_world = cl.to_device(np.ascontiguousarray(env.map_from_world, self.wide).reshape(-1))
        self.cos_crease = np.float32(np.cos(np.radians(CREASE_DEGREES)))
        self._zeros = np.zeros(self.points, np.uint8)
        bilinear = {"BACKGROUND_BILINEAR": 1} if env.background == "bilinear" else {}
        self.program = cl.program("relight_view.cl", QBITS=device.entries.bits, POINTS=POINTS, K=1,
                                  MASS_STEPS=MASS_STEPS, **bilinear)

    def lookup(self, prim, u, v, d, queue):
        """Launch ``view_lookup`` on camera rays (prim (N,) int32, -1 a miss; embree's u, v; unit
        directions d (N, 3) float32): the buffers of their cache points (N, 3) uint32 and weights
        (N, 3) float32 (the device twin of :meth:`ViewFrames.hit_points`, all rays), the ray
        buffers, and the cache points of weight > 0 (sorted)."""
        count = len(prim)
        prim_b = cl.upload("view_prim", np.ascontiguousarray(prim, np.int32), queue)
        dir_b = cl.upload("view_dir", np.ascontiguousarray(d, np.float32), queue)
        used = cl.upload("view_used", self._zeros, queue)
        ids, w = cl.scratch("view_ids", 12 * count), cl.scratch("view_weights", 12 * count)
        cl.kernel(self.program, "view_lookup")(
            queue, (cl.items(count),), (cl.WORK_GROUP,), np.uint32(count), prim_b,
            cl.upload("view_u", np.ascontiguousarray(u, np.float32), queue),
            cl.upload("view_v", np.ascontiguousarray(v, np.float32), queue), dir_b, self.face_k, self.face_base,
            self.lattice, self.normal, self.face_normal, self.cos_crease, ids, w, used)
        points = np.flatnonzero(cl.read(used, (self.points,), np.uint8, queue))
        return ids, w, prim_b, dir_b, points

    def assemble(self, count, prim_b, ids, w, dir_b, points, B, queue, image=None) -> np.ndarray:
        """Launch ``view_assemble``: (N, 3) float32 (into ``image`` if given), a hit's albedo x the
        blend of its points' B (rows of ``B`` in the order of ``points``), a miss's environment
        texel."""
        row = np.full(self.points, -1, np.int32)
        row[points] = np.arange(len(points), dtype=np.int32)
        out = cl.scratch("view_image", 12 * count)
        cl.kernel(self.program, "view_assemble")(
            queue, (cl.items(count),), (cl.WORK_GROUP,), np.uint32(count), prim_b, ids, w,
            cl.upload("view_row", row, queue), B, self.face_material, self.albedo, dir_b, self.env, *self.env_size,
            self.map_from_world, out)
        if image is None:
            return cl.read(out, (count, 3), np.float32, queue)
        cl.opencl().enqueue_copy(queue, image, out)
        return image


# ----------------------------------------------------------------------------- the bake
@dataclass
class _Settings:
    n_levels: int
    tolerance: float
    bits: int
    seed: int
    backend: str
    points: int
    light: np.ndarray        # (N, N, 3) the lighting's mean radiance per texel


def _point_samples(cache: SurfaceCache, tracer, lo: int, hi: int) -> PixelSamples:
    """The cache points lo .. hi - 1 as the texel kernel's pixels: one sample, one lambert group
    each (its cosine with the point's normal, nothing below its face: the face normal), the
    shadow rays from the point moved off the surface along its face's normal."""
    P = hi - lo
    normal = cache.normal[lo:hi]
    geometric = tracer.face_normals[cache.face[lo:hi]].astype(np.float32)
    geometric *= np.where(np.einsum("ij,ij->i", geometric, normal) < 0, -1.0, 1.0).astype(np.float32)[:, None]
    p = cache.position[lo:hi].astype(np.float32)
    offset = tracer.shadow_offsets(p, cache.face[lo:hi], np.zeros(3))
    origin = (p + geometric * offset[:, None]).astype(np.float32)
    ones = np.ones(P, np.uint32)
    return PixelSamples(1, ones, normal.astype(np.float32), geometric, normal.astype(np.float32),
                        np.full(P, bsdfs.LAMBERT, np.int32), np.zeros(P, np.float32), np.ones(P, np.float32),
                        np.zeros(P, np.uint32), ones, np.arange(P, dtype=np.uint32), origin,
                        np.ones((P, 3), np.float32), np.zeros(P, np.uint64), normal.astype(np.float32))


def point_transfer(cache: SurfaceCache, tracer, s: _Settings, block: int):
    """(P, 3, N, N) float32 T1 = L_t G_t of a block's cache points (module docstring) and the
    shadow rays traced."""
    lo, hi = block * POINTS, min((block + 1) * POINTS, len(cache))
    ps = _point_samples(cache, tracer, lo, hi)
    n = s.n_levels
    if s.backend == "opencl":
        dirs, weight, pick = texel_rays(ps, n, s.seed, block, 1 << bsdfs.LAMBERT, points=s.points)
    else:
        dirs, weight, pick = texel_rays_reference(ps, n, s.seed, block, points=s.points)
    lit = (s.light.max(axis=2) > 0).reshape(-1)
    texel = np.arange(len(weight)) & ((1 << (2 * n)) - 1)
    live = np.flatnonzero((weight > 0) & lit[texel])
    blocked = tracer.occluded(np.take(ps.origin, pick[live].astype(np.int64), axis=0), np.take(dirs, live, axis=0))
    g = np.zeros(len(weight), np.float32)
    g[live] = np.where(blocked, 0.0, weight[live] * np.float32(np.pi))   # lambert's f cos = cos / pi
    side = 1 << n
    g = g.reshape(-1, 1, side, side)
    return g * np.moveaxis(s.light, -1, 0)[None].astype(np.float32), len(live)


def _bake_block(cache, tracer, s: _Settings, block: int) -> dict:
    T1, rays = point_transfer(cache, tracer, s, block)
    P = len(T1)
    side2 = 4 ** s.n_levels
    coeffs = np.asarray(haar.forward(T1), np.float32).reshape(P, 3, side2)
    rows = np.zeros((3, POINTS, side2), np.float32)
    rows[:, :P] = np.moveaxis(coeffs, 1, 0)
    rows = rows.reshape(3 * POINTS, side2)
    held = np.zeros((side2, 3))
    held[0] = 1.0                           # the scaling coefficient: a lambert point's frame
    cols, scales, q, _, _ = store.compress_block(rows, held, s.tolerance, s.bits,
                                                 np.random.default_rng([s.seed, block]))
    approx = np.zeros_like(rows)
    approx[:, cols] = (q.astype(np.float32) * scales[:, None]).T
    diff = rows.astype(np.float64) - approx
    lum = np.tensordot(LUMINANCE.astype(np.float64), coeffs.astype(np.float64), axes=([0], [1]))   # (P, 4^n)
    return {"block": block, "columns": cols, "scales": scales, "data": q, "rays": rays,
            "error2": float(np.einsum("ij,ij->", diff, diff)), "norm2": float(np.einsum("ij,ij->", rows, rows, dtype=np.float64)),
            "sum_sq": np.einsum("pc,pc->c", lum, lum)}


def bake_view(scene, output=None, levels=None, tolerance: float = BAKE["tolerance"].default,
              bits: int = BAKE["bits"].default, seed: int = BAKE["seed"].default, threads=None, progress=None,
              backend: str = "opencl", points=None, density=None, cache_points: int = CACHE_POINTS):
    """Bake T1 = L V max(cos, 0) of ``scene`` on its surface cache (module docstring) into
    ``output`` (default: a temporary file the Transfer owns); returns the
    :class:`wavlight.relight.Transfer` (header ``vary = "view"``).

    ``levels``: texels 2^n x 2^n (default: the fewest within ``tolerance`` / sqrt(3), chosen by
    the lighting bake's pilot at the scene's camera, :func:`wavlight.relight.bake.choose_model`);
    ``density``: cache points per unit area (default: ``cache_points`` over the scene's area);
    ``points``: texel points (1, 4 or 16; default VIEW_TEXEL_POINTS); each block is compressed to ``tolerance`` /
    sqrt(3) (relative L2 of T1) and quantized to ``bits``."""
    where = "relight.bake"
    if isinstance(scene, (str, os.PathLike)):
        scene = load_scene(scene)
    check_scene(scene)
    if levels is not None:
        levels = BAKE["levels"].check(levels, where)
    tolerance, bits, seed = (BAKE[k].check(v, where) for k, v in (("tolerance", tolerance), ("bits", bits),
                                                                   ("seed", seed)))
    points = BAKE["points"].check(VIEW_TEXEL_POINTS if points is None else points, where)
    cache_points = check_int(where, "cache_points", cache_points, 1, MAX_LATTICE)
    require_untextured(scene, "a bake with vary='view'")
    if scene.environment.is_black:
        raise ArgumentError(f"{scene.path}: [environment]: the environment is black everywhere; nothing to relight")
    if output is not None:   # the map at least
        store.check_output(output, scene.environment.pixels.size * 4)
    t0 = time.perf_counter()
    pilot = None
    if levels is None:
        model = choose_model(scene, tolerance, 4, seed, None, 256, "area", backend)
        levels, pilot = model["n_levels"], model["pilot"]
    n = levels
    cache = build_cache(scene, density, cache_points)
    env = scene.environment
    s = _Settings(n, tolerance / np.sqrt(3.0), bits, seed, backend, points, lighting.project(env, n))
    tracer = RayTracer(scene.vertices, scene.faces, threads=1)
    n_blocks = -(-len(cache) // POINTS)
    writer = store.TransferWriter(n, BLOCK, bits, row=3 * POINTS, output=output)
    sum_sq = np.zeros(4 ** n)
    totals = {"rays": 0, "error2": 0.0, "norm2": 0.0, "done": 0}
    lock = threading.Lock()
    t_setup = time.perf_counter() - t0

    def collect(r):
        with lock:
            writer.add(r["block"], r["columns"], r["scales"], r["data"])
            sum_sq[:] += r["sum_sq"]
            for key in ("rays", "error2", "norm2"):
                totals[key] += r[key]
            totals["done"] += 1
            if progress:
                progress(totals["done"], n_blocks, totals["rays"], time.perf_counter() - t0)

    try:
        with ThreadPoolExecutor(threads or default_threads()) as pool:
            for r in pool.map(lambda b: _bake_block(cache, tracer, s, b), range(n_blocks)):
                collect(r)
        seconds = time.perf_counter() - t0
        side = 1 << n
        model = {"vary": "view", "n_levels": n, "texels": f"{side}x{side}", "levels_from": "pilot" if pilot else "given",
                 "cache_points": len(cache), "density": cache.density, "spacing": cache.spacing,
                 "texel_points": points, "tolerance": tolerance, "bits": bits,
                 "compression_tolerance": tolerance / np.sqrt(3.0)}
        header = {
            **store.header_of(scene),
            "width": scene.width, "height": scene.height, "spp": 1, "seed": seed, "n_levels": n, "block": BLOCK,
            "texel_points": points, "blocks": [n_blocks, 1], "bits": bits, "tolerance": tolerance, "terms": 4 ** n,
            "priority": "transfer", "environment_rotate_y": float(env.rotate_y), "environment_name": env.name,
            "vary": "view", "model": model,
            "cache": {"points": len(cache), "density": cache.density, "spacing": cache.spacing,
                      "faces": int(len(cache.face_k)), "lattice": int(len(cache.lattice)), "row": 3 * POINTS},
            "measured": {"bake_seconds": round(seconds, 3), "pilot_seconds": round(t_setup, 3), "rays": totals["rays"],
                         "rays_per_second": (round(totals["rays"] / (seconds - t_setup), 1) if seconds > t_setup
                                             else None),
                         "compression_error": (float(np.sqrt(totals["error2"] / totals["norm2"]))
                                               if totals["norm2"] > 0 else 0.0),
                         "entries": writer.entries, "entries_full": 4 ** n * n_blocks, "pilot": pilot},
        }
        arrays = {"environment": env.pixels.astype(np.float32),
                  "albedo": scene.material_albedo[cache.material].astype(np.float32).reshape(-1, 3),
                  "background_pixel": np.zeros(0, np.uint32), "background_mask": np.zeros(0, np.uint64),
                  "background_dir": np.zeros((0, 1, 3), np.float32),
                  "rms": np.sqrt(sum_sq / max(len(cache), 1)).astype(np.float32),
                  "view_position": cache.position.astype(np.float32), "view_normal": cache.normal.astype(np.float32),
                  "view_material": cache.material.astype(np.int32), "view_face_k": cache.face_k.astype(np.int32),
                  "view_face_base": cache.face_base.astype(np.int64), "view_lattice": cache.lattice.astype(np.int32)}
        return finish_bake(writer, output, header, arrays)
    finally:
        writer.close()


# ----------------------------------------------------------------------------- frames
def check_camera(where: str, eye, target, up, fov) -> Camera:
    """A frame's camera: finite eye and target within the ray tracer's range, apart, the view not
    along ``up``, 0 < fov < 180."""
    eye = check_real(where, "eye", eye, finite=True).reshape(-1).astype(np.float64)
    target = check_real(where, "target", target, finite=True).reshape(-1).astype(np.float64)
    if eye.shape != (3,) or target.shape != (3,):
        raise ArgumentError(f"{where}: eye and target must be three numbers each")
    if max(np.abs(eye).max(), np.abs(target).max()) > MAX_COORDINATE:
        raise ArgumentError(f"{where}: eye and target must be within the ray tracer's range (|x| <= "
                            f"{MAX_COORDINATE:g}), got {eye.tolist()} and {target.tolist()}")
    fov = FRAME["fov"].check(fov, where)
    fwd = target - eye
    if not np.linalg.norm(fwd) > 1e-9 * max(1.0, float(np.abs(eye).max())):
        raise ArgumentError(f"{where}: the eye {eye.tolist()} and the target are the same point")
    up = np.asarray(up, np.float64)
    if np.linalg.norm(np.cross(fwd / np.linalg.norm(fwd), up / np.linalg.norm(up))) < 1e-6:
        raise ArgumentError(f"{where}: the view from {eye.tolist()} to {target.tolist()} is along the camera's up")
    return Camera(eye, target, up, float(fov))


def orbit_eyes(eye, target, frames: int) -> np.ndarray:
    """(frames, 3): the eye turned about the vertical axis through the target by 360 i / frames."""
    eye, target = np.asarray(eye, np.float64), np.asarray(target, np.float64)
    a = 2 * np.pi * np.arange(frames) / frames
    rel = eye - target
    c, s = np.cos(a), np.sin(a)
    return target + np.stack([c * rel[0] + s * rel[2], np.full(frames, rel[1]), -s * rel[0] + c * rel[2]], 1)


class ViewFrames:
    """The frames of a view bake: its scene (reloaded and checked against the bake), tracer,
    cache and device entries."""

    def __init__(self, transfer, scene=None, background: str = FRAME["background"].default):
        background = FRAME["background"].check(background, "relight.ViewFrames")
        varies = transfer.varies
        if varies != "view":
            raise WavlightError(f"{transfer.path}: this bake varies the {'lighting' if varies == 'lighting' else 'object'}"
                                f", not the view")
        self.transfer = transfer
        self.scene = scene_of(transfer, scene)
        self.tracer = RayTracer(self.scene.vertices, self.scene.faces, threads=2, normals=self.scene.normals,
                                normal_faces=self.scene.normal_faces)
        s = transfer._s
        self.position = np.asarray(s["view_position"], np.float64)
        self.normal = np.asarray(s["view_normal"], np.float64)
        self.material = np.asarray(s["view_material"], np.int64)
        self.face_k, self.face_base = np.asarray(s["view_face_k"]), np.asarray(s["view_face_base"])
        self.lattice = np.asarray(s["view_lattice"])
        if len(self.face_k) != len(self.scene.faces):
            raise WavlightError(f"{transfer.path}: its cache holds {len(self.face_k)} faces, the scene "
                                f"{len(self.scene.faces)}")
        if len(self.material) and self.material.max() >= len(self.scene.materials):
            raise WavlightError(f"{transfer.path}: its cache points' materials go up to {self.material.max()}, the "
                                f"scene has {len(self.scene.materials)}")
        self.n = transfer.n_levels
        self.kind_of = self.scene.material_kind
        self.param_of = self.scene.material_param
        self.albedo_of = self.scene.material_albedo.astype(np.float64)
        fn = np.asarray(self.tracer.face_normals, np.float64)
        self.face_normal = fn / np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
        self.face_normal32 = self.face_normal.astype(np.float32)
        self.normal32 = self.normal.astype(np.float32)
        #: the lighting, and what camera rays that miss see (``background``: nearest or bilinear)
        self.environment = self.scene.environment.with_background(background)
        self._device = None
        self._frame_device = None
        self._centres = {}
        self._inside = None

    # -- cameras
    def camera(self, eye=None, target=None, fov=None):
        cam = self.scene.camera
        return check_camera("relight.view", cam.eye if eye is None else eye, cam.target if target is None else target,
                            cam.up, cam.fov_y if fov is None else fov)

    def size(self, width=None, height=None) -> tuple:
        """(width, height) of a frame: those given, checked (FRAME's ranges), else the bake's."""
        w = FRAME["width"].check(self.transfer.width if width is None else width, "relight.view")
        h = FRAME["height"].check(self.transfer.height if height is None else height, "relight.view")
        return w, h

    def _pixel_centres(self, width, first, count, supersample: int = 1):
        """Columns, rows (float32) and offsets of the rays of pixels first .. first + count - 1
        of a frame ``width`` wide: the pixel's centre, or the centres of its S x S sub-pixels
        (S = ``supersample``; a pixel's S^2 rays adjacent), the last chunk's kept: the next frame's."""
        key = (width, first, count, supersample)
        if key not in self._centres:
            sub = supersample * supersample
            kept = self._centres.get(("rays", count, supersample))
            if kept is None:   # the chunk's pixels (from 0) and sub-pixel offsets, shared by its chunks
                k = np.tile(np.arange(sub), count)
                offsets = np.stack([(k % supersample + 0.5) / supersample, (k // supersample + 0.5) / supersample], 1)
                kept = (np.repeat(np.arange(count), sub), offsets.astype(np.float32))
            pix = kept[0] + first
            self._centres = {key: ((pix % width).astype(np.float32), (pix // width).astype(np.float32), kept[1]),
                             ("rays", count, supersample): kept}
        return self._centres[key]

    # -- the cache at hits
    def hit_points(self, eye, d, prim, t, uv=None):
        """The cache points (M, 3) and normalized weights (M, 3) of hits (prim >= 0) (at barycentric
        ``uv`` if given, else from the hit points), with 0 where a point is not usable (another
        side of the face, a crease); and the face normals."""
        if uv is None:
            p = np.asarray(eye, np.float64) + d.astype(np.float64) * t.astype(np.float64)[:, None]
            uv = barycentric(self.scene.vertices, self.scene.faces, prim, p)
        ids, w = lattice_points(self.face_k, self.face_base, self.lattice, prim, *uv)
        fn = self.face_normal32[prim]
        front = np.einsum("ij,ij->i", fn, d) < 0
        compat = np.einsum("ijk,ik->ij", self.normal32[ids], fn) >= np.float32(np.cos(np.radians(CREASE_DEGREES)))
        w = w * (compat & front[:, None])
        total = w.sum(1, keepdims=True)
        return ids, np.where(total > 0, w / np.where(total > 0, total, 1.0), 0.0), fn

    def shading_normals(self, eye, d, t, prim, u, v, fn):
        """The shading normals (M, 3) float32 of hits at barycentrics (u, v) (RayTracer.hit), turned
        to the side of their face normals ``fn`` as the cache is (a hit on the face's back side has
        no cache); ``fn`` itself where the scene is flat."""
        if not self.tracer.smooth or not len(prim):
            return fn
        n = self.tracer.hit(eye, np.asarray(d, np.float32), np.asarray(t, np.float32), prim, u, v)[0]
        return (n * np.where(np.einsum("ij,ij->i", n, fn) < 0, -1.0, 1.0)[:, None]).astype(np.float32)

    def _point_items(self, points, eye):
        """The point mode's items: cache points, material kind and parameter, normals and view
        directions towards ``eye`` (lifted above the tangent plane)."""
        wo = np.asarray(eye, np.float64) - self.position[points]
        wo /= np.linalg.norm(wo, axis=1, keepdims=True)
        nrm = self.normal[points]
        mat = self.material[points]
        return points, self.kind_of[mat], self.param_of[mat], nrm, lifted_view(nrm, wo)

    def products(self, points, eye, refine=REFINE, backend="opencl", mass: float = MASS):
        """B_k (K, 3) (albedo factored out) and nodes visited of cache points seen from ``eye``."""
        points, kind, param, nrm, wo = self._point_items(points, eye)
        if backend == "numpy":
            s = self.transfer._s
            return product_reference(s["offsets"], s["entry_scale"], s["entry_data"], self.n, points, kind, param,
                                     nrm, wo, refine, mass=mass)
        if self._device is None:
            self._device = ViewDevice(self.transfer)
        return self._device.products(points, kind, param, nrm, wo, refine, mass=mass)

    def pixel_products(self, ids, w, face_normal, d, mat, refine=REFINE, tau: float = TAU, backend="opencl",
                       mass: float = MASS):
        """B (M, 3) (albedo factored out) and nodes visited of pixels: the blend of their cache
        points ``ids`` (M, 3) with weights ``w`` (M, 3), shaded with the normal ``face_normal`` (the
        hits' shading normals, :meth:`shading_normals`), the view
        direction -d, material ``mat`` and the cosine's correction ``tau`` (module docstring)."""
        n = np.asarray(face_normal, np.float64)
        wo = lifted_view(n, -np.asarray(d, np.float64))
        m = np.einsum("ij,ijk->ik", np.asarray(w, np.float64), self.normal[ids])
        kind, param = self.kind_of[mat], self.param_of[mat]
        if backend == "numpy":
            s = self.transfer._s
            return product_reference(s["offsets"], s["entry_scale"], s["entry_data"], self.n, ids, kind, param, n, wo,
                                     refine, w, m, tau, mass)
        if self._device is None:
            self._device = ViewDevice(self.transfer)
        return self._device.products(ids, kind, param, n, wo, refine, w, m, tau, mass=mass)

    def frame(self, eye=None, target=None, fov=None, width=None, height=None, refine: float = REFINE,
              backend: str = "opencl", mode: str = MODE, tau: float = TAU, mass: float = MASS,
              supersample: int = 1):
        """The approximate frame (H, W, 3) float32 seen from ``eye`` towards ``target`` (defaults:
        the scene's camera) and its timings (module docstring): ``mode`` "point" (a product per
        cache point, blended per pixel) or "pixel" (a product per pixel, of its points' blended T1
        with its shading normal, view direction and the cosine corrected within ``tau``); ``refine``
        and ``mass`` set where the walk stops (module docstring); ``supersample`` S traces S x S rays
        per pixel (its sub-pixels' centres) and takes their mean (``mis`` integrates over the
        pixel, and a mesh's facets can be smaller than a pixel)."""
        where = "relight.view"
        refine, mass = FRAME["refine"].check(refine, where), FRAME["mass"].check(mass, where)
        if backend not in ("opencl", "numpy"):
            raise ArgumentError(f"relight.view: backend must be opencl or numpy, got {backend!r}")
        mode, tau = FRAME["mode"].check(mode, where), FRAME["tau"].check(tau, where)
        supersample = FRAME["supersample"].check(supersample, where)
        cam = self.camera(eye, target, fov)
        width, height = self.size(width, height)
        sub = supersample * supersample
        t0 = time.perf_counter()
        scene = dataclasses.replace(self.scene, camera=cam)
        count = width * height
        image = (np.empty if backend == "opencl" else np.zeros)((count, 3), np.float32)   # the device writes all
        timing = {"rays_seconds": 0.0, "lookup_seconds": 0.0, "product_seconds": 0.0, "assembly_seconds": 0.0}
        products, visited = 0, 0
        on_device = backend == "opencl"
        if on_device:
            queue = cl.thread_queue()
            if self._device is None:
                self._device = ViewDevice(self.transfer)
            if self._frame_device is None:
                self._frame_device = FrameDevice(self, self._device)
        step = max(1, CHUNK_PIXELS * 4 // sub)
        for first in range(0, count, step):   # chunks of pixels (bounded memory)
            ta = time.perf_counter()
            chunk = min(step, count - first)
            eye_a, d = camera_rays(scene, *self._pixel_centres(width, first, chunk, supersample), width, height)
            pix = np.arange(chunk * sub)   # the chunk's rays
            rays = image[first:first + chunk] if sub == 1 else \
                (np.empty if on_device else np.zeros)((len(pix), 3), np.float32)
            prim, t, u, v = self.tracer.intersect_uv(eye_a, d)
            tb = time.perf_counter()
            if on_device:
                # the cache lookup on the device; in point mode the walks and the assembly too
                fd = self._frame_device
                ids_b, w_b, prim_b, dir_b, points = fd.lookup(prim, u, v, d, queue)
            if mode == "pixel" or not on_device:
                hit = np.flatnonzero(prim >= 0)
                if on_device:
                    ids = cl.read(ids_b, (len(pix), 3), np.uint32, queue)[hit].astype(np.int64)
                    w = cl.read(w_b, (len(pix), 3), np.float32, queue)[hit].astype(np.float64)
                    fn = self.face_normal32[prim[hit]]
                else:
                    ids, w, fn = self.hit_points(cam.eye, d[hit], prim[hit], t[hit], (u[hit], v[hit]))
                mat = self.scene.face_material[prim[hit]]
                fn = self.shading_normals(cam.eye, d[hit], t[hit], prim[hit], u[hit], v[hit], fn)
            if mode == "point":
                if not on_device:
                    used = np.zeros(len(self.position), bool)
                    used[ids[w > 0]] = True
                    points = np.flatnonzero(used)
                tc = time.perf_counter()
                if on_device:
                    if len(points):
                        B_b, visited_b = self._device.walk(*self._point_items(points, cam.eye), refine, queue=queue,
                                                               mass=mass)
                        nodes = cl.read(visited_b, (len(points),), np.uint32, queue)
                    else:
                        B_b, nodes = cl.scratch("view_walk_out", 12), np.zeros(0, np.uint32)
                    td = time.perf_counter()
                    fd.assemble(len(pix), prim_b, ids_b, w_b, dir_b, points, B_b, queue, rays)
                else:
                    B, nodes = self.products(points, cam.eye, refine, backend, mass)
                    td = time.perf_counter()
                    # a point of weight 0 (or none shaded at all: only back faces seen) reads the zero row
                    at = np.full(len(self.position), len(points), np.int64)
                    at[points] = np.arange(len(points))
                    rows = np.concatenate([np.asarray(B, np.float32).reshape(-1, 3), np.zeros((1, 3), np.float32)])
                    blend = np.einsum("ij,ijc->ic", w.astype(np.float32), rows[at[ids]])
                    rays[pix[hit]] = blend * self.albedo_of[mat].astype(np.float32)
                shaded = len(points)
            else:
                ok = np.flatnonzero(w.sum(1) > 0)
                tc = time.perf_counter()
                B, nodes = self.pixel_products(ids[ok], w[ok], fn[ok], d[hit][ok], mat[ok], refine, tau, backend,
                                               mass)
                td = time.perf_counter()
                if on_device:   # the environment where rays miss (no point's row: 0 on hits)
                    fd.assemble(len(pix), prim_b, ids_b, w_b, dir_b, np.zeros(0, np.int64),
                                cl.scratch("view_walk_out", 12), queue, rays)
                rays[pix[hit][ok]] = np.asarray(B, np.float32) * self.albedo_of[mat[ok]].astype(np.float32)
                shaded = len(ok)
            if not on_device:
                miss = np.flatnonzero(prim < 0)
                rays[pix[miss]] = self.environment.eval_background(d[miss].astype(np.float64))
            if sub > 1:
                image[first:first + chunk] = rays.reshape(chunk, sub, 3).mean(1)
            te = time.perf_counter()
            products += shaded
            visited += int(np.sum(nodes, dtype=np.int64))
            for key, dt in (("rays_seconds", tb - ta), ("lookup_seconds", tc - tb), ("product_seconds", td - tc),
                            ("assembly_seconds", te - td)):
                timing[key] += dt
        seconds = time.perf_counter() - t0
        stats = {"frame_seconds": seconds, **timing, "width": width, "height": height, "eye": cam.eye.tolist(),
                 "target": cam.target.tolist(), "fov": cam.fov_y, "mode": mode, "tau": tau,
                 "items": "cache points" if mode == "point" else "rays",
                 "cache_points_shaded": products, "nodes_per_point": round(visited / max(products, 1), 2),
                 "refine": refine, "mass": mass, "supersample": supersample}
        return image.reshape(height, width, 3), stats

    # -- the unbiased frame
    def _texel_light(self):
        if self._inside is None:
            env = self.environment
            m = min(self.n, PRODUCT_LEVELS)
            self._inside = TexelLight(Environment(env.pixels, 1.0, 0.0, env.name), m, env.rotate_y)
        return self._inside

    def converge(self, eye=None, target=None, fov=None, width=None, height=None, spp: int = UNBIASED_SPP,
                 seed: int = FRAME["seed"].default, slots=None, defensive=None, threads=None,
                 progress=None, light=None, control: bool = True, backend: str = "opencl", candidates=None,
                 coherence=None) -> RenderResult:
        """The unbiased frame from ``eye`` (module docstring; kernels and kept trees:
        :mod:`wavlight.relight.view_converge`, whose SLOTS, DEFENSIVE, LIGHT_SHARE, CANDIDATES
        and COHERENCE are the defaults; ``control``: the control variate; ``backend="numpy"``
        the kernels' numpy twins): image, per-pixel standard error, stats; ``setup_seconds`` the
        device tables made by this call (the first), ``frame_seconds`` that plus the frame's."""
        from . import view_converge as vc

        where = "relight.view"
        spp, seed = FRAME["spp"].check(spp, where), FRAME["seed"].check(seed, where)
        slots = vc.SLOTS if slots is None else slots
        defensive = vc.DEFENSIVE if defensive is None else defensive
        light = vc.LIGHT_SHARE if light is None else light
        candidates = vc.CANDIDATES if candidates is None else candidates
        coherence = check_number(where, "coherence", vc.COHERENCE if coherence is None else coherence, 0.0)
        defensive, light = check_shares(where, defensive, light)
        cam = self.camera(eye, target, fov)
        width, height = self.size(width, height)
        scene = dataclasses.replace(self.scene, camera=cam)
        t0 = time.perf_counter()
        inside = self._texel_light()
        if backend == "opencl":   # the entries and the lookup's tables, shared with the approximate frame
            if self._device is None:
                self._device = ViewDevice(self.transfer)
            if self._frame_device is None:
                self._frame_device = FrameDevice(self, self._device)
        frames = vc.converger(self, inside, self._device, self._frame_device, backend, threads)
        setup = time.perf_counter() - t0
        result = frames.frame(scene, width, height, spp, seed, slots, defensive, light, control, PASS_SPP, progress,
                              candidates, coherence)
        result.stats["setup_seconds"] = round(setup, 4)
        result.stats["frame_seconds"] = round(setup + result.stats["render_seconds"], 4)
        return result
