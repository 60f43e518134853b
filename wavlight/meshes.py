"""Triangle meshes without trimesh's import cost: a PLY reader for the common subset
and the icosphere.

trimesh (with the scipy it imports) takes 0.7-1.4 s to import on the development
machine and 0.4 s to parse the 3 MB ASCII bunny, more than wavlight's whole setup
and a third of a 512x512 render. :func:`read_ply` reads PLY files whose elements are
exactly ``vertex`` (scalar properties including x, y, z) and ``face`` (a
``vertex_indices`` list first, then scalar properties) with triangles only, in ASCII
or binary, in 0.1 s; it returns None for anything else, which
:func:`wavlight.scene.load_scene` then hands to trimesh (OBJ files always go there).
:func:`icosphere` builds the ``sphere`` shape (trimesh's construction: an
icosahedron, each subdivision splitting every triangle in four at its edge
midpoints, projected onto the sphere).
"""
from __future__ import annotations

import os

import numpy as np

from .errors import WavlightError, check_int, check_number, file_problem


class MeshError(WavlightError, ValueError):
    """A mesh file that cannot be read as given (a ValueError too, as before): the message says
    why, naming the face or line; load_scene prefixes the file and the key."""


#: Mesh files are read whole into memory: larger ones are refused before reading.
MAX_MESH_BYTES = 2 << 30
#: icosphere's limit (scene files allow 8: 1.3 M triangles; 10 is 21 M, about 2 GB of geometry).
MAX_SUBDIVISIONS = 10

_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
          "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
          "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def _header(data: bytes):
    """(format, [(name, count, properties)], offset of the body); a property is (name, type)
    or ("list", count type, index type, name)."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise MeshError("not a PLY file (no 'ply' magic or 'end_header')")
    nl = data.find(b"\n", end)
    body = len(data) if nl < 0 else nl + 1
    fmt, elements = None, []
    for line in data[:end].decode("ascii", "replace").splitlines()[1:]:
        w = line.split()
        if not w or w[0] in ("comment", "obj_info"):
            continue
        if w[0] == "format" and len(w) >= 2:
            fmt = w[1]
        elif w[0] == "element" and len(w) == 3 and w[2].isdigit():
            elements.append((w[1], int(w[2]), []))
        elif w[0] == "property" and elements and len(w) >= 3:
            elements[-1][2].append(("list", w[2], w[3], w[4]) if w[1] == "list" and len(w) == 5 else (w[2], w[1]))
        else:
            raise MeshError(f"malformed PLY header line {line.strip()!r}")
    return fmt, elements, body


def _read_bytes(path: str) -> bytes:
    """The file's bytes; ValueError (with the reason) for a path that is not a readable regular
    file (an int would open a file descriptor; a FIFO would block) or a file beyond MAX_MESH_BYTES."""
    if not isinstance(path, (str, os.PathLike)):
        raise MeshError(f"expected a mesh file's path, got {type(path).__name__}")
    problem = file_problem(path)
    if problem is not None:
        raise MeshError(problem)
    size = os.stat(path).st_size
    if size > MAX_MESH_BYTES:
        raise MeshError(f"the file is {size / 1e9:.1f} GB; meshes of up to {MAX_MESH_BYTES >> 30} GiB are read")
    with open(path, "rb") as fh:
        return fh.read()


def check_indices(idx, nv: int, what: str = "face", holder: str = "the file"):
    """idx (F, 3) float64 or integer -> int64, or a MeshError (a ValueError) naming the first bad
    face; ``holder`` names what holds the vertices in the message (a file, an array)."""
    idx = np.asarray(idx)
    if idx.dtype.kind == "f":
        frac = ~np.isfinite(idx) | (idx != np.round(idx))
        if frac.any():
            i = int(np.argmax(frac.any(axis=1)))
            bad = idx[i][frac[i]][0]
            raise MeshError(f"{what} {i}: vertex index {bad:g} is not an integer")
    out = np.asarray(idx, np.int64) if idx.dtype.kind != "f" else np.round(idx).astype(np.int64)
    bad = (out < 0) | (out >= nv)
    if bad.any():
        i = int(np.argmax(bad.any(axis=1)))
        raise MeshError(f"{what} {i}: vertex index {int(out[i][bad[i]][0])} is outside 0..{nv - 1} "
                         f"({holder} holds {nv} vertices)")
    return out


def read_ply(path: str, normals: bool = False):
    """(vertices (V, 3) float64, faces (F, 3) int64) of a triangle PLY in the subset above,
    or None when the file is outside it. ValueError for a malformed header or bad indices.
    With ``normals``: (vertices, faces, the file's vertex normals nx, ny, nz (V, 3) float64 or
    None where it has none)."""
    data = _read_bytes(path)
    fmt, elements, start = _header(data)
    if [e[0] for e in elements] != ["vertex", "face"]:
        return None
    (_, nv, vprops), (_, nf, fprops) = elements
    names = [p[0] for p in vprops]
    if ("list" in names or not {"x", "y", "z"} <= set(names)
            or any(p[0] != "list" and p[1] not in _TYPES for p in vprops + fprops)
            or not fprops or fprops[0][0] != "list" or fprops[0][3] not in ("vertex_indices", "vertex_index")
            or fprops[0][1] not in _TYPES or fprops[0][2] not in _TYPES
            or any(p[0] == "list" for p in fprops[1:])):
        return None
    if _TYPES[fprops[0][2]][0] == "f" or _TYPES[fprops[0][1]][0] == "f":
        raise MeshError(f"the face list '{' '.join(fprops[0])}' has a floating-point type; "
                         "counts and vertex indices must be integer types")
    xyz = [names.index(c) for c in "xyz"]
    nxyz = [names.index(c) for c in ("nx", "ny", "nz")] if {"nx", "ny", "nz"} <= set(names) else None
    width = 4 + len(fprops) - 1                     # count, three indices, the other face properties
    if fmt == "ascii":
        try:
            tokens = np.array(data[start:].split(), dtype=np.float64)
        except ValueError:
            return None
        if len(tokens) < nv * len(vprops) + nf * width:
            raise MeshError(f"truncated: the header declares {nv} vertices and {nf} faces, the file "
                             f"holds fewer values")
        if len(tokens) != nv * len(vprops) + nf * width:
            return None                             # polygons other than triangles, or trailing data
        table = tokens[:nv * len(vprops)].reshape(nv, len(vprops))
        # values as the declared type holds them (float x y z: float32, as a binary file would)
        verts = np.stack([table[:, j].astype(_TYPES[vprops[j][1]]) for j in xyz], 1).astype(np.float64)
        vn = None if nxyz is None else np.stack([table[:, j].astype(_TYPES[vprops[j][1]]) for j in nxyz],
                                                1).astype(np.float64)
        rows = tokens[nv * len(vprops):].reshape(nf, width)
        counts, idx = rows[:, 0], rows[:, 1:4]
    elif fmt in ("binary_little_endian", "binary_big_endian"):
        e = "<" if fmt == "binary_little_endian" else ">"
        vdt = np.dtype([(f"p{k}", e + _TYPES[t]) for k, (_, t) in enumerate(vprops)])
        fdt = np.dtype([("n", e + _TYPES[fprops[0][1]]), ("i", e + _TYPES[fprops[0][2]], (3,))]
                       + [(f"q{k}", e + _TYPES[t]) for k, (_, t) in enumerate(fprops[1:])])
        if len(data) - start < nv * vdt.itemsize + nf * fdt.itemsize:
            raise MeshError(f"truncated: the header declares {nv} vertices and {nf} faces, the file "
                             f"is {nv * vdt.itemsize + nf * fdt.itemsize - (len(data) - start)} bytes short")
        if len(data) - start != nv * vdt.itemsize + nf * fdt.itemsize:
            return None
        v = np.frombuffer(data, vdt, count=nv, offset=start)
        verts = np.stack([v[f"p{k}"] for k in xyz], axis=1).astype(np.float64)
        vn = None if nxyz is None else np.stack([v[f"p{k}"] for k in nxyz], axis=1).astype(np.float64)
        f = np.frombuffer(data, fdt, count=nf, offset=start + nv * vdt.itemsize)
        counts, idx = f["n"], f["i"]
    else:
        return None
    if not np.all(counts == 3):
        return None
    return (verts, check_indices(idx, nv), vn) if normals else (verts, check_indices(idx, nv))


def read_obj(path: str, normals: bool = False):
    """(vertices (V, 3) float64, faces (F, 3) int64) of a Wavefront OBJ file's geometry: ``v x y
    z [...]`` and ``f a b c ...`` lines (references ``i``, ``i/t``, ``i//n``, ``i/t/n``; 1-based,
    negative ones relative to the vertices read so far; a quad as (0, 1, 2), (2, 3, 0) and a
    polygon of k > 4 vertices as the fan of k - 2 triangles (0, j, j + 1), as trimesh splits
    them). With ``normals`` also the file's ``vn`` normals (N, 3) float64 and each corner's row
    of them (F, 3) int64, -1 for a corner without one (``i`` or ``i/t``, or an index outside
    the ``vn`` lines). Other lines (vt, o, g, s, usemtl, mtllib, l, p, ...) are ignored; a backslash at the end of a line continues it. Bytes that are not UTF-8 (say in
    a comment) are replaced. ValueError naming the line for a vertex without three numbers, a
    face of fewer than three vertices, an index that is not an integer, 0 or outside the
    vertices."""
    text = _read_bytes(path).decode("utf-8", errors="replace").replace("\\\r\n", " ").replace("\\\n", " ")
    coords, vlines = [], []
    tris, tlines, ntris = [], [], []
    ncoords = []
    nv = 0
    for number, line in enumerate(text.splitlines(), 1):
        w = line.split()
        if not w:
            continue
        key = w[0]
        if key == "v":
            if len(w) < 4:
                raise MeshError(f"line {number}: a vertex needs three numbers, got {line.strip()[:60]!r}")
            coords += w[1:4]
            vlines.append(number)
            nv += 1
        elif key == "vn" and normals:
            ncoords.append(w[1:4])
        elif key == "f":
            if len(w) < 4:
                raise MeshError(f"line {number}: a face needs at least three vertices, got {line.strip()[:60]!r}")
            refs, nrefs = [], []
            for ref in w[1:]:
                head = ref.split("/", 1)[0]
                if normals:
                    nrefs.append(_normal_ref(ref, len(ncoords)))
                try:
                    i = int(head)
                except ValueError:
                    raise MeshError(f"line {number}: face index {head[:30]!r} is not an integer") from None
                if i == 0:
                    raise MeshError(f"line {number}: face index 0 (OBJ indices start at 1; negative ones count "
                                     "back from the last vertex)")
                if i < 0:
                    if -i > nv:
                        raise MeshError(f"line {number}: face index {i} reaches before the first vertex "
                                         f"({nv} read so far)")
                    i = nv + i
                else:
                    i -= 1
                refs.append(i)
            if len(refs) == 4:   # trimesh's split of a quad, so that the triangles match its reader's
                tris += [(refs[0], refs[1], refs[2]), (refs[2], refs[3], refs[0])]
                tlines += [number, number]
                if normals:
                    ntris += [(nrefs[0], nrefs[1], nrefs[2]), (nrefs[2], nrefs[3], nrefs[0])]
                continue
            for j in range(1, len(refs) - 1):
                tris.append((refs[0], refs[j], refs[j + 1]))
                tlines.append(number)
                if normals:
                    ntris.append((nrefs[0], nrefs[j], nrefs[j + 1]))
    try:
        verts = np.array(coords, np.float64).reshape(-1, 3)
    except ValueError:
        for k, c in enumerate(coords):
            try:
                float(c)
            except ValueError:
                raise MeshError(f"line {vlines[k // 3]}: vertex coordinate {c[:30]!r} is not a number") from None
        raise
    faces = np.array(tris, np.int64).reshape(-1, 3)
    if faces.size and faces.max() >= nv:
        k = int(np.argmax(faces.max(axis=1) >= nv))
        raise MeshError(f"line {tlines[k]}: face index {int(faces[k].max()) + 1} but the file holds {nv} vertices")
    if not normals:
        return verts, faces
    try:
        vn = np.array([c + ["nan"] * (3 - len(c)) for c in ncoords], np.float64).reshape(-1, 3)
    except ValueError:
        vn = np.full((len(ncoords), 3), np.nan)   # an unreadable vn line: no file normals
    corner = np.array(ntris, np.int64).reshape(-1, 3)
    return verts, faces, vn, corner


def _normal_ref(ref: str, count: int) -> int:
    """The 0-based ``vn`` row of a face reference ``i/t/n`` or ``i//n`` (negative: relative to the
    ``count`` normals read so far), -1 where it names none or one outside them."""
    parts = ref.split("/")
    if len(parts) < 3 or not parts[2]:
        return -1
    try:
        k = int(parts[2])
    except ValueError:
        return -1
    k = count + k if k < 0 else k - 1
    return k if 0 <= k < count else -1


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V, 3) float64 unit normals per vertex: the sum of its faces' normals weighted by their
    areas (the cross products of two edges, unnormalised), normalised; zero for a vertex of no
    face or whose faces cancel. (trimesh and Mitsuba 3 weight by the corner's angle instead.)"""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    e = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n = np.zeros_like(v)
    for k in range(3):   # the three corners, vectorised over faces
        np.add.at(n, f[:, k], e)
    return unit_rows(n)


def unit_rows(n: np.ndarray) -> np.ndarray:
    """Rows of n divided by their lengths (float64); rows of zero length, or not finite, become zero."""
    n = np.asarray(n, np.float64)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    ok = np.isfinite(length) & (length > 0)
    return np.where(ok, np.divide(n, np.where(ok, length, 1.0)), 0.0)


def icosphere(subdivisions: int, radius: float = 1.0):
    """(vertices (V, 3), faces (F, 3)) of a sphere about the origin: an icosahedron subdivided
    `subdivisions` times (20 4^s faces; at most MAX_SUBDIVISIONS), counter-clockwise seen from
    outside."""
    subdivisions = check_int("meshes.icosphere", "subdivisions", subdivisions, 0, MAX_SUBDIVISIONS)
    radius = check_number("meshes.icosphere", "radius", radius, 0.0)
    t = (1.0 + 5.0 ** 0.5) / 2.0
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
                  [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], np.float64)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
                  [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
                  [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]], np.int64)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    for _ in range(subdivisions):  # levels, not vertices: each step is vectorised
        edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        unique, inverse = np.unique(edges, axis=0, return_inverse=True)
        mid = v[unique[:, 0]] + v[unique[:, 1]]
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        m = len(v) + inverse.reshape(3, -1)          # midpoints of edges 01, 12, 20 of every face
        a, b, c = f[:, 0], f[:, 1], f[:, 2]
        f = np.concatenate([np.stack(x, axis=1) for x in
                            ((a, m[0], m[2]), (m[0], b, m[1]), (m[2], m[1], c), (m[0], m[1], m[2]))])
        v = np.concatenate([v, mid])
    return v * radius, f
