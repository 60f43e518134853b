"""The surface cache of a view bake (Chen & Gao sec. 2.2, eq. 6-8, with the view as the varying
factor): the points over every object's surface that carry the baked factor T1 (eq. 7,
:mod:`wavlight.relight.view_bake`), and the lattice that finds a camera hit's cache points.

    B(x, wo) = <T1(x), T2>,  T1(x, w) = L(w) V(x, w) max(cos theta, 0)  (per surface point)

T1 depends on the surface point, not on the camera, so it is baked on points
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

Points are sorted by object and Morton order of position, so that a block of POINTS = BLOCK^2
points of the bake file is a patch of surface.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ArgumentError
from ..raytrace import SMOOTH_MIN_LENGTH2
from .bake import BLOCK
from .settings import BAKE, CACHE_POINTS
from .store import lattice_size

#: cache points per block of the bake file (one entry row holds their three channels)
POINTS = BLOCK * BLOCK
#: at most this many lattice entries (bounded memory)
MAX_LATTICE = 1 << 25
#: a cache point whose normal is further than this from the hit face's is not interpolated
CREASE_DEGREES = 60.0


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

