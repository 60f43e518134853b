"""Ray queries with embreex: closest hits for camera rays, occlusion for shadow rays.

Geometry is one triangle soup in float32 (embree's precision). Large batches are
split over threads: embreex releases the GIL, so two threads use both cores.
Where embreex has no wheel (Linux aarch64) the queries go through trimesh's own
numpy intersector (:class:`TrimeshQueries`, with the ``rtree`` package): the same
answers, far slower.

The scene is built without Embree's robust flag (``robust=False``), as Mitsuba 3
does by default (its ``embree_use_robust_intersections`` is off): robust traversal
measured 13-15% slower on the bunny's camera and shadow rays, and the tests of
flat quads under uniform light and of shadows pass without it.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from .errors import ArgumentError, check_int, check_integers, check_real
from .threads import MAX_THREADS

_CHUNK = 1 << 15
#: embree takes int32 indices and a float32 soup: at most this many vertices and faces.
MAX_ELEMENTS = (1 << 31) - 1


def _geometry(vertices, faces):
    """(vertices (V, 3) finite, faces (F, 3) integers in [0, V)) or a one-line ArgumentError."""
    v = check_real("RayTracer", "vertices", vertices, finite=True)
    f = check_integers("RayTracer", "faces", faces)
    if v.ndim != 2 or v.shape[1] != 3 or (f.size and (f.ndim != 2 or f.shape[1] != 3)):
        raise ArgumentError(f"RayTracer: vertices (V, 3) and faces (F, 3) expected, got shapes {v.shape} and {f.shape}")
    f = f.reshape(-1, 3)
    if len(v) > MAX_ELEMENTS or len(f) > MAX_ELEMENTS:
        raise ArgumentError(f"RayTracer: at most {MAX_ELEMENTS} vertices and faces (embree's int32 indices), got "
                            f"{len(v)} and {len(f)}")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise ArgumentError(f"RayTracer: faces must index the {len(v)} vertices, got "
                            f"{int(f.min()) if f.min() < 0 else int(f.max())}")
    if v.size and np.abs(v).max() > 1.8e18:
        raise ArgumentError("RayTracer: vertex coordinates beyond embree's range (|x| <= 1.8e18)")
    return v, f


def _rays(where, origins, dirs):
    o = check_real(where, "origins", origins)
    d = check_real(where, "dirs", dirs)
    if o.ndim != 2 or o.shape[1] != 3 or d.shape != o.shape:
        raise ArgumentError(f"{where}: origins and dirs must both be (N, 3), got shapes {o.shape} and {d.shape}")
    return o, d

# Shadow rays start at the hit point moved along the face normal by
#     max(OFFSET_RELATIVE |p|, OFFSET_FLOOR max(|v| of the face's vertices), OFFSET_FLOOR |eye|)
# (|.| the largest coordinate): local, so that geometry elsewhere in the scene (a large
# floor, a far object) does not move the shadows here, and far above float32's rounding of
# embree's hit distance and of eye + t d (~1e-7 of those magnitudes). Mitsuba 3 offsets by
# (1 + |p|) 1.8e-4, which assumes scenes of unit size.
OFFSET_RELATIVE = 1e-4
OFFSET_FLOOR = 1e-6
#: an interpolated shading normal shorter than this squared (corner normals that cancel, a flat
#: face's row of zeros) gives way to the geometric normal
SMOOTH_MIN_LENGTH2 = 1e-12


class EmbreeQueries:
    """Closest hits and occlusion of float32 rays against one triangle soup, by embree."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        import embreex.mesh_construction as mc
        import embreex.rtcore_scene as rtcs

        self._scene = rtcs.EmbreeScene(robust=False)
        mc.TriangleMesh(self._scene, np.ascontiguousarray(vertices, np.float32), np.ascontiguousarray(faces, np.int32))
        # embree builds its acceleration structure at the first query: one query here, so
        # that the build is part of every render's setup rather than of its first batch
        self.occluded(np.zeros((1, 3), np.float32), np.float32([[0.0, 0.0, 1.0]]))

    def closest(self, o, d):
        """(prim (N,) int32, -1 a miss; t, u, v (N,) float32): embree's barycentric u, v."""
        r = self._scene.run(o, d, output=1)
        return r["primID"].astype(np.int32), r["tfar"], r["u"].astype(np.float32), r["v"].astype(np.float32)

    def occluded(self, o, d):
        return self._scene.run(o, d, query="OCCLUDED") >= 0


class TrimeshQueries:
    """The same queries by trimesh's numpy ray-triangle intersector (needs ``rtree``): the
    fallback where embreex has no wheel. Written against trimesh, not by hand."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        import trimesh
        from trimesh.ray.ray_triangle import RayMeshIntersector

        self._mesh = trimesh.Trimesh(np.asarray(vertices, np.float64), np.asarray(faces, np.int64), process=False)
        self._rays = RayMeshIntersector(self._mesh)

    def closest(self, o, d):
        import trimesh

        n = len(o)
        prim = np.full(n, -1, np.int32)
        t, u, v = np.full(n, np.inf, np.float32), np.zeros(n, np.float32), np.zeros(n, np.float32)
        o64, d64 = np.asarray(o, np.float64), np.asarray(d, np.float64)
        tri, ray, loc = self._rays.intersects_id(o64, d64, multiple_hits=False, return_locations=True)
        if len(tri):
            prim[ray] = tri
            t[ray] = np.einsum("ij,ij->i", loc - o64[ray], d64[ray]) / np.einsum("ij,ij->i", d64[ray], d64[ray])
            bary = trimesh.triangles.points_to_barycentric(self._mesh.triangles[tri], loc)
            u[ray], v[ray] = bary[:, 1], bary[:, 2]
        return prim, t, u, v

    def occluded(self, o, d):
        return np.asarray(self._rays.intersects_any(np.asarray(o, np.float64), np.asarray(d, np.float64)), bool)


def default_queries():
    """EmbreeQueries where embreex imports, else TrimeshQueries."""
    try:
        import embreex  # noqa: F401
        return EmbreeQueries
    except ImportError:
        return TrimeshQueries


class RayTracer:
    """Closest-hit and occlusion queries against vertices (V, 3) and faces (F, 3).

    ``queries``: the class that answers them (default :func:`default_queries`). ``normals`` (N, 3)
    and ``normal_faces`` (F, 3) (a Scene's: each corner's row of normals, -1 for a face shaded
    with its geometric normal; None: every face flat) give the shading normals of :meth:`hit`
    (docs/decisions/shading-normals.md): ``shading_normals`` holds them with a last row of zeros
    that the -1 corners name (``corner_normals``), and ``smooth`` says whether any face uses them."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, threads: int = 1, queries=None, normals=None,
                 normal_faces=None):
        vertices, faces = _geometry(vertices, faces)
        self.n_faces = len(faces)
        self.threads = check_int("RayTracer", "threads", threads, 1, MAX_THREADS)
        self._queries = None
        if self.n_faces:
            self._queries = (queries or default_queries())(vertices, faces)
        v = np.asarray(vertices, np.float64)
        f = np.asarray(faces, np.int64)
        if self.n_faces:
            n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
            length = np.linalg.norm(n, axis=1, keepdims=True)
            # a zero-area face (a Scene built in Python; load_scene removes them) gets a zero normal,
            # not NaN: embree never reports a hit on it, and nothing divides by 0 with a warning
            self.face_normals = np.divide(n, length, out=np.zeros_like(n), where=length > 0).astype(np.float32)
            extent = float(np.ptp(v, axis=0).max())
            self.scale = max(extent, float(np.abs(v).max()), 1e-6)
            self.face_offset_floor = (OFFSET_FLOOR * np.abs(v[f]).max(axis=(1, 2))).astype(np.float32)
        else:
            self.face_normals = np.zeros((0, 3), np.float32)
            self.face_offset_floor = np.zeros(0, np.float32)
            self.scale = 1.0
        table = np.zeros((0, 3), np.float32) if normals is None else np.asarray(normals, np.float32).reshape(-1, 3)
        self.shading_normals = np.concatenate([table, np.zeros((1, 3), np.float32)])
        rows = (np.full((self.n_faces, 3), -1, np.int64) if normal_faces is None
                else np.asarray(normal_faces, np.int64).reshape(-1, 3))
        if rows.shape != (self.n_faces, 3) or (rows.size and (rows.min() < -1 or rows.max() >= len(table))):
            raise ArgumentError(f"RayTracer: normal_faces must be ({self.n_faces}, 3) rows of the {len(table)} "
                                f"normals or -1, got shape {rows.shape}")
        self.corner_normals = np.where(rows < 0, len(table), rows).astype(np.int32)
        self.smooth = bool(np.any(rows >= 0))

    @staticmethod
    def eye_offset_floor(eye) -> np.float32:
        """The part of the shadow-ray offset that the eye's position sets (OFFSET_FLOOR |eye|)."""
        return np.float32(OFFSET_FLOOR * float(np.abs(np.asarray(eye, np.float64)).max()))

    def shadow_offsets(self, p: np.ndarray, face: np.ndarray, eye) -> np.ndarray:
        """How far shadow rays from hit points p (N, 3) on faces (N,) move along the normal (float32)."""
        p = np.asarray(p, np.float32)
        return np.maximum(np.maximum(np.float32(OFFSET_RELATIVE) * np.abs(p).max(axis=1, initial=0.0),
                                     self.face_offset_floor[face]), self.eye_offset_floor(eye))

    def surface(self, eye, d, t, face):
        """At hits of rays eye + t d (d (N, 3), t (N,), float32) on faces (N,): the face normal
        turned towards the viewer, the hit point p and the shadow-ray origin p moved
        :meth:`shadow_offsets` along that normal (float32, as the shade kernel computes them)."""
        fn = self.face_normals[face]
        n = fn * np.where(np.einsum("ij,ij->i", fn, d) > 0, np.float32(-1), np.float32(1))[:, None]
        p = np.asarray(eye, np.float32) + d * np.asarray(t, np.float32)[:, None]
        return n, p, p + n * self.shadow_offsets(p, face, eye)[:, None]

    def hit(self, eye, d, t, face, u, v):
        """At hits of rays eye + t d (d (N, 3), t (N,), float32) on faces (N,) at embree's
        barycentrics u, v (N,): (shading normal, geometric normal, p, shadow-ray origin), float32,
        as the kernels' ``hit_point`` and ``shading_normal`` (kernels/hit.h) compute them. The
        geometric normal and the origin are :meth:`surface`'s; the shading normal is
        normalize((1 - u - v) n0 + u n1 + v n2) of the face's corner normals, turned towards the
        viewer, or the geometric normal where that sum is (nearly) zero (a flat face's corners
        name the row of zeros)."""
        g, p, origin = self.surface(eye, d, t, face)
        u = np.asarray(u, np.float32)[:, None]
        v = np.asarray(v, np.float32)[:, None]
        c = self.shading_normals[self.corner_normals[face]]   # (N, 3 corners, 3)
        n = (np.float32(1) - u - v) * c[:, 0] + u * c[:, 1] + v * c[:, 2]
        length2 = np.einsum("ij,ij->i", n, n)
        ok = length2 > np.float32(SMOOTH_MIN_LENGTH2)
        n = np.where(ok[:, None], n / np.sqrt(np.where(ok, length2, 1))[:, None], g).astype(np.float32)
        n = n * np.where(np.einsum("ij,ij->i", n, d) > 0, np.float32(-1), np.float32(1))[:, None]
        return n, g, p, origin

    def _map(self, fn, origins, dirs):
        n = len(origins)
        if self.threads == 1 or n <= _CHUNK:
            return fn(origins, dirs)
        parts = np.array_split(np.arange(n), min(self.threads, -(-n // _CHUNK)))
        with ThreadPoolExecutor(len(parts)) as pool:
            res = list(pool.map(lambda idx: fn(origins[idx[0]:idx[-1] + 1], dirs[idx[0]:idx[-1] + 1]), parts))
        if isinstance(res[0], tuple):
            return tuple(np.concatenate(r) for r in zip(*res))
        return np.concatenate(res)

    def intersect(self, origins: np.ndarray, dirs: np.ndarray):
        """Closest hits: (prim (N,) int32, -1 for a miss; t (N,) float32)."""
        origins, dirs = _rays("RayTracer.intersect", origins, dirs)
        if self._queries is None or len(origins) == 0:
            return np.full(len(origins), -1, np.int32), np.full(len(origins), np.inf, np.float32)

        def run(o, d):
            prim, t, _, _ = self._queries.closest(np.ascontiguousarray(o, np.float32),
                                                  np.ascontiguousarray(d, np.float32))
            return prim, t

        return self._map(run, origins, dirs)

    def intersect_uv(self, origins: np.ndarray, dirs: np.ndarray):
        """Closest hits with embree's barycentric (u, v) of each (p = (1 - u - v) v0 + u v1 + v v2):
        prim (N,) int32 (-1: a miss), t, u, v (N,) float32."""
        origins, dirs = _rays("RayTracer.intersect_uv", origins, dirs)
        n = len(origins)
        if self._queries is None or n == 0:
            return np.full(n, -1, np.int32), np.full(n, np.inf, np.float32), np.zeros(n, np.float32), np.zeros(n, np.float32)

        def run(o, d):
            return self._queries.closest(np.ascontiguousarray(o, np.float32), np.ascontiguousarray(d, np.float32))

        return self._map(run, origins, dirs)

    def occluded(self, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """(N,) bool: True where the ray from origin along dir hits any triangle."""
        origins, dirs = _rays("RayTracer.occluded", origins, dirs)
        if self._queries is None or len(origins) == 0:
            return np.zeros(len(origins), bool)

        def run(o, d):
            return self._queries.occluded(np.ascontiguousarray(o, np.float32), np.ascontiguousarray(d, np.float32))

        return self._map(run, origins, dirs)
