"""Mesh files with their materials and textures: glTF 2.0 (``.gltf``, ``.glb``) and OBJ + MTL,
read through trimesh's loaders, as parts (geometry with node transforms applied, texture
coordinates, a material of wavlight's, a base-colour texture) and a camera.

The material mapping (docs/scene-format.md, "Materials of mesh files"):

| file | wavlight |
|---|---|
| glTF metallic-roughness, ``metallicFactor >= 0.5`` | ``ggx``: albedo = base colour, alpha = roughness^2 |
| glTF metallic-roughness, ``metallicFactor < 0.5`` | ``plastic``: albedo = base colour, alpha = roughness^2, ior 1.5 |
| MTL ``Kd`` without ``Ks`` (or ``Ks`` black) | ``lambert``: albedo = ``Kd`` |
| MTL ``Kd`` and ``Ks`` | ``plastic``: albedo = ``Kd``, alpha = sqrt(2 / (``Ns`` + 2)), ior 1.5 |
| MTL ``Ks`` with ``Kd`` black | ``ggx``: albedo = ``Ks``, alpha = sqrt(2 / (``Ns`` + 2)) |

glTF's defaults apply where a factor is absent (base colour 1, metallic 1, roughness 1);
alpha is kept within the scene format's roughness range [1e-4, 1]. trimesh holds a glTF base
colour factor as 8-bit (steps of 1/255, linear). The MTL's alpha is the Phong-to-microfacet
width of Walter et al. 2007 (sec. 5.2, alpha_b = sqrt(2 / (n + 2))); MTL ``Kd`` absent is
0.8, ``Ns`` absent 0 (alpha 1). A base-colour texture (glTF ``baseColorTexture``, MTL
``map_Kd``) multiplies the albedo through the part's texture coordinates
(:mod:`wavlight.textures`). Parts without a material take the scene's default (a grey
lambert).

Bad input: a glTF requiring an extension (``extensionsRequired``) is refused (a
:class:`wavlight.meshes.MeshError`); everything else is a :class:`SanitisedInputWarning`
naming the file and the part, with a fallback: a missing or unreadable texture, or one
without texture coordinates (the part's base colour alone); an extension used but not
required (ignored); a primitive that is not triangles (points, lines; skipped); an OBJ whose
material library is missing (the whole file as geometry with the default material); an MTL
material the OBJ names but the library lacks (the default material).
"""
from __future__ import annotations

import contextlib
import json
import os
import re
import struct
import warnings
from dataclasses import dataclass

import numpy as np

from . import textures
from .errors import SanitisedInputWarning, WavlightError
from .meshes import MeshError

#: the file types whose materials wavlight reads (other meshes are geometry only)
SUFFIXES = (".glb", ".gltf", ".obj")
#: the scene format's range of a microfacet alpha (scene.ROUGHNESS_RANGE)
ALPHA_RANGE = (1e-4, 1.0)
#: the dielectric coating's index of refraction of the mapped ``plastic`` parts
PLASTIC_IOR = 1.5
#: MTL ``Kd`` where a material has none
MTL_DEFAULT_KD = 0.8
_MODES = {0: "POINTS", 1: "LINES", 2: "LINE_LOOP", 3: "LINE_STRIP", 4: "TRIANGLES", 5: "TRIANGLE_STRIP",
          6: "TRIANGLE_FAN"}


@dataclass
class FileMaterial:
    """A part's material in wavlight's terms: ``type`` (``lambert``, ``ggx``, ``plastic``),
    ``albedo`` (3,), ``alpha`` (the microfacet width; 0 for lambert), ``ior`` (plastic's), and
    where it comes from (``source``: the file's material name)."""

    type: str
    albedo: np.ndarray
    alpha: float = 0.0
    ior: float = PLASTIC_IOR
    source: str = ""
    why: str = ""   # the file's values that chose the type, for messages


@dataclass
class Part:
    """One part of a mesh file: ``name`` (its mesh and material, for messages), vertices (V, 3)
    float64 with the file's node transforms applied, faces (F, 3) int64, ``uv`` (V, 2) float32
    or None, ``material`` (a :class:`FileMaterial`, or None for the scene's default),
    ``texture`` ((H, W, 3) float32 linear, or None) and ``normals`` (V, 3): the file's vertex
    normals with the node transforms applied, trimesh's (angle-weighted) where it has none."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None
    material: FileMaterial | None
    texture: np.ndarray | None
    normals: np.ndarray | None = None


@dataclass
class FileCamera:
    """A camera a file holds (glTF's first perspective camera): eye, target, up, vertical fov in degrees."""

    eye: np.ndarray
    target: np.ndarray
    up: np.ndarray
    fov_y: float


def _alpha(x) -> float:
    return float(np.clip(x, *ALPHA_RANGE))


def gltf_material(base_color=None, metallic=None, roughness=None, source="") -> FileMaterial:
    """The mapping of glTF's metallic-roughness material (linear base colour RGB(A), factors; None
    for glTF's defaults 1, 1, 1): ggx where metallic >= 0.5, else plastic; alpha = roughness^2."""
    base = np.ones(3) if base_color is None else np.asarray(base_color, np.float64).reshape(-1)[:3]
    metallic = 1.0 if metallic is None else float(metallic)
    roughness = 1.0 if roughness is None else float(roughness)
    alpha = _alpha(roughness * roughness)
    if metallic >= 0.5:
        return FileMaterial("ggx", base, alpha, source=source, why=f"glTF metallicFactor {metallic:g} >= 0.5")
    return FileMaterial("plastic", base, alpha, PLASTIC_IOR, source=source,
                        why=f"glTF metallicFactor {metallic:g} < 0.5")


def mtl_material(kd=None, ks=None, ns=None, source="") -> FileMaterial:
    """The mapping of an MTL material (``Kd``, ``Ks``: a number or three; ``Ns``; None where
    absent): lambert (no or black Ks), plastic (Kd and Ks), ggx (Ks with black Kd), alpha =
    sqrt(2 / (Ns + 2))."""
    kd = np.full(3, MTL_DEFAULT_KD) if kd is None else np.broadcast_to(np.asarray(kd, np.float64), (3,)).copy()
    kd = np.maximum(kd, 0.0)
    ks = None if ks is None else np.maximum(np.broadcast_to(np.asarray(ks, np.float64), (3,)).copy(), 0.0)
    alpha = _alpha(np.sqrt(2.0 / (max(float(ns or 0.0), 0.0) + 2.0)))
    if ks is None or ks.max() == 0:
        return FileMaterial("lambert", kd, 0.0, source=source, why="MTL Kd without Ks")
    if kd.max() == 0:
        return FileMaterial("ggx", ks, alpha, source=source, why="MTL Ks with Kd black")
    return FileMaterial("plastic", kd, alpha, PLASTIC_IOR, source=source, why="MTL Kd and Ks")


def _warn(path, part, message):
    warnings.warn(f"{path}: {part}: {message}", SanitisedInputWarning, stacklevel=4)


# ----------------------------------------------------------------------------- checks on the file's own words
def gltf_json(path: str):
    """The JSON document of a .gltf or .glb file (for the checks trimesh does not report:
    required and used extensions, primitive modes, texture references), or None where it
    cannot be read (trimesh's loader then says why)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(20)
            if path.lower().endswith(".glb") or head[:4] == b"glTF":
                if len(head) < 20 or head[:4] != b"glTF":
                    return None
                length, kind = struct.unpack("<I4s", head[12:20])
                if kind != b"JSON" or length > 64 << 20:
                    return None
                text = fh.read(length)
            else:
                fh.seek(0)
                text = fh.read(64 << 20)
        doc = json.loads(text)
    except (OSError, ValueError, UnicodeDecodeError, struct.error):
        return None
    return doc if isinstance(doc, dict) else None


def _named(items, i, what):
    item = items[i] if isinstance(items, list) and 0 <= i < len(items) and isinstance(items[i], dict) else {}
    return f"{what} {item.get('name')!r}" if item.get("name") else f"{what} {i}"


def _check_gltf(path: str, doc) -> None:
    """Refuse required extensions; warn of used ones and of primitives that are not triangles."""
    if doc is None:
        return
    required = [e for e in doc.get("extensionsRequired", []) if isinstance(e, str)]
    if required:
        raise MeshError(f"requires the glTF extension(s) {', '.join(required)}, which wavlight does not read")
    used = [e for e in doc.get("extensionsUsed", []) if isinstance(e, str)]
    if used:
        where = [_named(doc.get("materials"), i, "material") for i, m in enumerate(doc.get("materials") or [])
                 if isinstance(m, dict) and isinstance(m.get("extensions"), dict) and m["extensions"]]
        _warn(path, ", ".join(where) if where else "the file",
              f"glTF extension(s) {', '.join(used)} ignored (the core metallic-roughness material is read)")
    for i, mesh in enumerate(doc.get("meshes") or []):
        prims = mesh.get("primitives") if isinstance(mesh, dict) else None
        for k, p in enumerate(prims if isinstance(prims, list) else []):
            mode = p.get("mode", 4) if isinstance(p, dict) else 4
            if mode not in (4, 5):
                _warn(path, f"{_named(doc.get('meshes'), i, 'mesh')} primitive {k}",
                      f"mode {_MODES.get(mode, mode)} is not triangles; skipped")


def _gltf_textures(doc):
    """{material index: image description} of the materials whose base colour has a texture."""
    out = {}
    for i, m in enumerate((doc or {}).get("materials") or []):
        pbr = m.get("pbrMetallicRoughness") if isinstance(m, dict) else None
        tex = pbr.get("baseColorTexture") if isinstance(pbr, dict) else None
        if isinstance(tex, dict):
            name = m.get("name") or f"material {i}"
            try:
                src = doc["textures"][tex["index"]]["source"]
                image = doc["images"][src]
                what = f"image {image.get('uri') or image.get('name') or src!r}"
            except (KeyError, IndexError, TypeError):
                what = "a texture the file does not define"
            out[name] = what
    return out


def _mtl_libraries(path: str):
    """The material libraries an OBJ names (``mtllib``), as paths beside it, the ``map_Kd`` each
    material of those found names ({material name: file name}) and the names of their materials."""
    maps, names = {}, set()
    with open(path, "rb") as fh:
        text = fh.read()
    libs = [os.path.join(os.path.dirname(path), m.decode("utf-8", "replace").strip())
            for m in re.findall(rb"^[ \t]*mtllib[ \t]+([^\r\n]+)", text, flags=re.M | re.I)]
    for lib in libs:
        if not os.path.isfile(lib):
            continue
        current = None
        with open(lib, "rb") as fh:
            for raw in fh:
                w = raw.decode("utf-8", "replace").strip().split(None, 1)
                if len(w) == 2 and w[0].lower() == "newmtl":
                    current = w[1].strip()
                    names.add(current)
                elif len(w) == 2 and w[0].lower() == "map_kd" and current is not None:
                    maps[current] = w[1].strip()
    return libs, maps, names


# ----------------------------------------------------------------------------- reading
def has_materials(path: str) -> bool:
    """Whether wavlight reads materials from a mesh file of this type (by its suffix)."""
    return str(path).lower().endswith(SUFFIXES)


def renders_directly(reference: str) -> bool:
    """Whether ``reference`` (a path, or ``data:NAME`` of wavlight.data) names a mesh file that
    ``wavlight render`` renders directly: a .glb, .gltf or .obj file, or such a mesh asset."""
    from . import data

    reference = str(reference)
    if reference.startswith(data.PREFIX):
        found = data.registry().get(reference[len(data.PREFIX):])
        return found is not None and found.kind == "mesh" and has_materials(found.file)
    return has_materials(reference)


def _trimesh_scene(path: str):
    import trimesh

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return trimesh.load_scene(path, process=False)
    except MeshError:
        raise
    except Exception as e:   # trimesh raises many types for bad files
        raise MeshError(f"cannot load: {str(e).splitlines()[0] if str(e) else type(e).__name__}") from None


def _texture(path, part, image, uv, described="its base-colour texture"):
    """(H, W, 3) linear float32 of a part's texture, or None with a warning naming the file and part."""
    if image is None:
        return None
    if uv is None:
        _warn(path, part, f"{described} is ignored: the part has no texture coordinates; its base colour alone "
                          "is used")
        return None
    try:
        return textures.from_image(image)
    except WavlightError as e:
        _warn(path, part, f"{described}: {e}; its base colour alone is used")
        return None


def _normals(scene, g) -> np.ndarray:
    """(V, 3) the vertex normals of ``g``, one of ``scene.dump()``'s copies: its source geometry's
    (the file's, or trimesh's where it has none) through the node's transform (the inverse
    transpose). dump() itself drops the file's normals and computes them anew."""
    matrix, name = scene.graph[g.metadata["node"]]
    n = np.asarray(scene.geometry[name].vertex_normals, np.float64) @ np.linalg.inv(np.asarray(matrix)[:3, :3])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def read(path: str):
    """(parts, camera or None, the files read beside it) of a glTF or OBJ file; None for an OBJ
    that names no material library (its geometry alone is read as any mesh's). Node transforms
    are applied. A MeshError for a file that cannot be read; warnings (SanitisedInputWarning)
    for the fallbacks listed in the module's docstring."""
    path = str(path)
    is_obj = path.lower().endswith(".obj")
    if is_obj:
        libs, maps, names = _mtl_libraries(path)
        if not libs:
            return None
        missing = [os.path.basename(lib) for lib in libs if not os.path.isfile(lib)]
        if missing:
            _warn(path, "the whole file", f"material library {', '.join(missing)} missing; the scene's default "
                                          "material is used")
            return None
        doc, textured = None, {}
    else:
        doc = gltf_json(path)
        _check_gltf(path, doc)
        maps, names, textured = {}, set(), _gltf_textures(doc)
    scene = _trimesh_scene(path)
    parts, seen = [], {}
    for g in scene.dump():
        faces = getattr(g, "faces", None)
        if faces is None or len(faces) == 0:
            continue   # points and lines: warned by _check_gltf
        gname = (g.metadata or {}).get("name", "mesh")
        visual = getattr(g, "visual", None)
        mat = getattr(visual, "material", None)
        uv = getattr(visual, "uv", None)
        uv = None if uv is None or len(uv) != len(g.vertices) else np.asarray(uv, np.float32)
        if uv is not None and not np.all(np.isfinite(uv)):
            _warn(path, f"mesh {gname!r}", "texture coordinates hold NaN or Inf; set to 0")
            uv = np.nan_to_num(uv, nan=0.0, posinf=0.0, neginf=0.0)
        mname = getattr(mat, "name", None)
        part = f"mesh {gname!r}" + (f" (material {mname!r})" if mname else "")
        material, image, described = None, None, "its base-colour texture"
        kind = type(mat).__name__
        if kind == "PBRMaterial":
            factor = mat.baseColorFactor
            base = None if factor is None else np.asarray(factor, np.float64)[:3] / (
                255.0 if np.asarray(factor).dtype == np.uint8 else 1.0)
            material = gltf_material(base, mat.metallicFactor, mat.roughnessFactor, source=mname or "")
            image = mat.baseColorTexture
            if image is None and mname in textured:
                _warn(path, part, f"base-colour texture ({textured[mname]}) missing or unreadable; its base colour "
                                  "alone is used")
        elif kind == "SimpleMaterial" and is_obj:
            kw = getattr(mat, "kwargs", {}) or {}
            if mname not in names:
                _warn(path, part, "the material library has no such material; the scene's default material is used")
            else:
                material = mtl_material(kw.get("kd"), kw.get("ks"), kw.get("ns"), source=mname or "")
                image, described = mat.image, f"its map_Kd texture {maps.get(mname, '')!r}"
                if image is None and mname in maps:
                    _warn(path, part, f"map_Kd texture {maps[mname]!r} missing or unreadable; its Kd alone is used")
        elif is_obj:
            _warn(path, part, "no material from the material library; the scene's default material is used")
        texture = None
        if image is not None:
            key = (id(image), uv is None)
            if key not in seen:   # an image several parts share is decoded once
                seen[key] = _texture(path, part, image, uv, described)
            texture = seen[key]
        parts.append(Part(part, np.asarray(g.vertices, np.float64), np.asarray(faces, np.int64),
                          uv if texture is not None else None, material, texture, _normals(scene, g)))
    if not parts:
        raise MeshError("holds no triangles")
    return parts, _camera(scene), _linked_files(path, doc, libs if is_obj else [], maps)


def _linked_files(path, doc, libs, maps):
    """The files beside a mesh file that its parts were read from (a .gltf's buffers and images,
    an OBJ's material libraries and map_Kd textures) that exist: for the scene's content hash."""
    folder = os.path.dirname(path)
    names = list(libs) + [os.path.join(folder, m) for m in maps.values()]
    for key in ("buffers", "images"):
        for item in (doc or {}).get(key) or []:
            uri = item.get("uri") if isinstance(item, dict) else None
            if isinstance(uri, str) and not uri.startswith("data:"):
                names.append(os.path.join(folder, uri))
    return [n for n in dict.fromkeys(names) if os.path.isfile(n)]


def _camera(scene):
    """The glTF camera trimesh read (its node's transform: the camera looks along -Z, up +Y), or None."""
    try:
        if not scene.has_camera:
            return None
        cam = scene.camera
        t = np.asarray(scene.camera_transform, np.float64)
    except Exception:   # a camera trimesh could not make sense of: the bounds are framed instead
        return None
    if not np.all(np.isfinite(t)):
        return None
    eye = t[:3, 3]
    forward = -t[:3, 2]
    up = t[:3, 1]
    if np.linalg.norm(forward) == 0 or np.linalg.norm(np.cross(forward, up)) == 0:
        return None
    fov_y = float(cam.fov[1])
    if not 0 < fov_y < 180:
        return None
    return FileCamera(eye, eye + forward / np.linalg.norm(forward), up, fov_y)


def frame_bounds(lo, hi, fov_y: float, aspect: float):
    """A camera (eye, target, up) that frames the box [lo, hi]: it looks at the box's centre from
    the direction (0, 0.5, 1) (above the front; +Y up, as glTF's), as near as lets the box's
    eight corners fit the vertical field of view ``fov_y`` (degrees) and the horizontal one of
    the image's ``aspect`` (width / height), with 5% to spare."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    centre = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-6)
    back = np.array([0.0, 0.5, 1.0]) / np.sqrt(1.25)          # from the centre towards the eye
    up = np.array([0.0, 1.0, 0.0])
    right = np.cross(up, back)
    right /= np.linalg.norm(right)
    cam_up = np.cross(back, right)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]) - centre
    x, y, depth = corners @ right, corners @ cam_up, corners @ back   # depth > 0: towards the eye
    ty = np.tan(np.radians(fov_y) / 2)
    tx = ty * aspect
    # a corner at (x, y) and distance d - depth from the eye fits where |x| <= tx (d - depth)
    d = np.max(np.maximum(np.abs(x) / (tx / 1.05), np.abs(y) / (ty / 1.05)) + depth)
    d = max(d, float(depth.max()) + 0.1 * radius)
    return centre + d * back, centre, up


_REUSED: dict = {}


@contextlib.contextmanager
def reuse(path: str, found):
    """Within the block, :func:`read_cached` of ``path`` returns ``found`` (what :func:`read` gave)
    rather than reading the file again: ``wavlight render ASSET`` reads the file once for its
    camera and its parts."""
    key = os.path.abspath(path)
    _REUSED[key] = found
    try:
        yield
    finally:
        _REUSED.pop(key, None)


def read_cached(path: str):
    """:func:`read`, or what :func:`reuse` holds for the path."""
    key = os.path.abspath(path)
    return _REUSED[key] if key in _REUSED else read(path)
