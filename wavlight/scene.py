"""Scene files (TOML, docs/scene-format.md) and dicts of the same structure: parse, validate, build geometry.

Every key of the scene format is accepted as written there. wavlight adds:

- ``[environment] procedural = "sky"`` instead of ``file``: the built-in sky
  (:func:`wavlight.envmap.procedural_sky`) with optional ``sun_elevation``,
  ``sun_azimuth`` (degrees, elevation in [-90, 90]; azimuth from -Z towards +X), ``sun_radius`` (degrees, at most 90,
  default 0.75) and ``sun_radiance`` (default 2e4). ``scale`` and ``rotate_y`` apply.
- ``[environment] file`` and ``[[objects]] mesh`` may name an asset of :mod:`wavlight.data` as
  ``"data:NAME"`` (a shipped file, or one fetched on first use); the Scene's ``files`` and
  ``content_hash`` then hold the asset's file as for any other.
- ``[[objects]]`` without ``material`` get a grey lambert (albedo 0.5).
- ``[render]`` takes every strategy option and the sampler by its key (``wavelet_candidates``,
  ``light_levels``, ``sampler``, ...): the table :data:`wavlight.strategies.OPTIONS` declares
  each one's type, range and default (docs/scene-format.md lists them).

Scenes also come from Python dicts of the same structure (:func:`load_dict`), which may give
arrays where a file names them: ``[environment] pixels`` (an (H, W, 3) array: the map), and
``[[objects]] vertices`` and ``faces`` ((V, 3) and (F, 3) arrays) or ``mesh`` as a mesh object
(a ``trimesh.Trimesh``: its vertices and faces). They are checked as the files are (the same
limits, messages and warnings) and read no file. A Scene records its ``content_hash``: the
settings as parsed, the bytes of every file it reads and of every array it was given.

Limits: width, height, spp and seed as :data:`wavlight.options.WIDTH`, ``HEIGHT``, ``SPP`` and
``SEED`` declare them (docs/scene-format.md). Errors name the file and the
key (``scene.toml: [render].spp: must be at least 1, got 0``) and raise
:class:`wavlight.errors.SceneError`.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import re
import tomllib
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from . import assets, bsdfs, data, meshes, textures
from .envmap import MAX_RADIANCE, MAX_TEXELS, Environment, procedural_sky, read_image
from .errors import SanitisedInputWarning, SceneError, WavlightError, file_problem, shown
from .options import BACKGROUND, FOV, HEIGHT, SEED, SPP, WIDTH
from .strategies import CONSTRAINTS, OPTIONS, STRATEGIES

ROUGHNESS_RANGE = (1e-4, 1.0)   # ggx alpha
EXPONENT_RANGE = (0.0, 1e6)     # phong n
IOR_RANGE = (1.0, 4.0)          # plastic ior, above 1 (Mitsuba refuses int_ior = ext_ior)
PLASTIC_IOR = 1.5               # plastic's default ior
PLASTIC_ALPHA = 0.1             # plastic's default alpha (roughplastic's)
MAX_SIDE = WIDTH.hi
MAX_SPP = SPP.hi
#: Largest |coordinate| of a vertex or of the camera: embree ignores geometry beyond about
#: +-1.8e18 (its documented range), which would vanish from the image without a word.
MAX_COORDINATE = 1e18
#: Largest albedo component: above 1 a surface reflects more than it receives (a warning);
#: beyond this, albedo x radiance (up to envmap.MAX_RADIANCE = 1e30) nears float32's limit.
MAX_ALBEDO = 1e6


@dataclass
class Camera:
    eye: np.ndarray
    target: np.ndarray
    up: np.ndarray
    fov_y: float


@dataclass
class Material:
    name: str
    kind: int          # bsdfs.LAMBERT | PHONG | GGX | PLASTIC
    albedo: np.ndarray  # (3,)
    param: float       # phong exponent, ggx or plastic alpha (0 for lambert)
    ior: float = PLASTIC_IOR   # plastic's index of refraction (Mitsuba's int_ior; ext_ior 1)
    texture: int = -1  # index in Scene.textures of a base-colour texture multiplying albedo (-1: none)


@dataclass
class SceneObject:
    """One [[objects]] table as loaded: its ``name`` (or None), ``index`` in the file, vertices
    after ``scale`` but before ``rotate`` and ``translate`` (``local``, float64), faces (local
    indices), the transform, its material index, and its ranges in the scene's merged faces and
    vertices."""

    name: str | None
    index: int
    local: np.ndarray
    faces: np.ndarray
    rotate: list | None
    translate: np.ndarray
    material: int
    faces_range: tuple
    vertices_range: tuple
    #: shading normals after ``scale`` (its inverse transpose) but before ``rotate`` (N, 3), and
    #: their rows in the scene's ``normals``
    local_normals: np.ndarray = None
    normals_range: tuple = (0, 0)


@dataclass
class Scene:
    """A loaded scene: settings, camera, environment, and one merged triangle soup.

    vertices : (V, 3) float32; faces : (F, 3) int32; face_material : (F,) int32;
    normals : (N, 3) float32 unit shading normals; normal_faces : (F, 3) int32, each corner's row
    of ``normals``, -1 where the face is shaded with its geometric normal (``face_normals = true``,
    or a Scene made without normals: ``normal_faces`` None, every face flat)
    """

    path: str
    width: int
    height: int
    spp: int
    strategy: str
    seed: int
    camera: Camera
    environment: Environment
    vertices: np.ndarray
    faces: np.ndarray
    face_material: np.ndarray
    materials: list = field(default_factory=list)
    #: the strategies' and the sampler's settings that the scene's [render] table gives, by key
    #: (wavlight.strategies.OPTIONS); render_full's keywords override them
    options: dict = field(default_factory=dict)
    #: sha256 of the scene's content: its settings as parsed and the bytes of every file it reads
    content_hash: str = ""
    #: the files the scene reads (environment map, meshes), as found
    files: list = field(default_factory=list)
    #: the [[objects]] as loaded (SceneObject): names, local geometry, transforms, face ranges
    objects: list = field(default_factory=list)
    #: base-colour textures, (H, W, 3) float32 linear (sRGB-decoded at load), indexed by Material.texture
    textures: list = field(default_factory=list)
    #: (V, 2) float32 texture coordinates of the vertices (zeros where a mesh has none), or None
    vertex_uv: np.ndarray | None = None
    #: the shading normals (docs/decisions/shading-normals.md) and each face corner's row of them
    normals: np.ndarray = None
    normal_faces: np.ndarray = None

    def find_object(self, key) -> "SceneObject":
        """The object named ``key``, or at index ``key`` (an int or a string of digits); a
        WavlightError listing the objects otherwise."""
        if isinstance(key, str) and not key.isdigit():
            for ob in self.objects:
                if ob.name == key:
                    return ob
        else:
            try:
                i = int(key)
            except (TypeError, ValueError):
                i = -1
            if 0 <= i < len(self.objects):
                return self.objects[i]
        known = ", ".join(f"{ob.index} ({ob.name})" if ob.name else str(ob.index) for ob in self.objects)
        raise WavlightError(f"{self.path}: no object {shown(key)} (objects: {known or 'none'})")

    def without(self, ob: "SceneObject") -> "Scene":
        """The same scene without object ``ob`` (its faces removed; vertices kept)."""
        keep = np.ones(len(self.faces), bool)
        keep[ob.faces_range[0]:ob.faces_range[1]] = False
        normal_faces = None if self.normal_faces is None else self.normal_faces[keep]
        return replace(self, faces=self.faces[keep], face_material=self.face_material[keep], normal_faces=normal_faces,
                       objects=[o for o in self.objects if o is not ob],
                       content_hash=hashlib.sha256(f"{self.content_hash} without {ob.index}".encode()).hexdigest())

    def faceted(self) -> "Scene":
        """The same scene shaded with its face normals everywhere (as ``face_normals = true`` on every
        object)."""
        return replace(self, normal_faces=None,
                       content_hash=hashlib.sha256(f"{self.content_hash} faceted".encode()).hexdigest())

    def moved(self, ob: "SceneObject", translate=None, rotate=None) -> "Scene":
        """The same scene with object ``ob`` at a new place: ``translate`` (3,) and ``rotate``
        [axis x, y, z, degrees] replace its own keys where given (absolute, as in the file)."""
        translate = ob.translate if translate is None else np.asarray(translate, np.float64).reshape(3)
        rotate = ob.rotate if rotate is None else [float(x) for x in rotate]
        vertices = self.vertices.copy()
        start, stop = ob.vertices_range
        vertices[start:stop] = (ob.local @ rotation(rotate).T + translate).astype(np.float32)
        normals = self.normals
        if ob.local_normals is not None and len(ob.local_normals):
            normals = self.normals.copy()
            normals[ob.normals_range[0]:ob.normals_range[1]] = (ob.local_normals @ rotation(rotate).T).astype(np.float32)
        moved = replace(ob, translate=translate, rotate=rotate)
        return replace(self, vertices=vertices, normals=normals, objects=[moved if o is ob else o for o in self.objects],
                       content_hash=hashlib.sha256(f"{self.content_hash} moved {ob.index} {list(translate)} "
                                                   f"{rotate}".encode()).hexdigest())


    @property
    def material_kind(self):
        return np.array([m.kind for m in self.materials], np.int32)

    @property
    def material_param(self):
        return np.array([m.param for m in self.materials], np.float64)

    @property
    def material_albedo(self):
        return np.array([m.albedo for m in self.materials], np.float32).reshape(-1, 3)

    @property
    def material_texture(self):
        """(materials,) int32: each material's texture index, -1 where it has none."""
        return np.array([getattr(m, "texture", -1) for m in self.materials], np.int32)

    @property
    def textured(self) -> bool:
        """Whether some face's material has a base-colour texture (hits then need texture coordinates)."""
        return bool(len(self.textures) and len(self.face_material)
                    and (self.material_texture[np.unique(self.face_material)] >= 0).any())

    def texture_atlas(self):
        """(texels (T, 4) float32, table (n, 4) int32) of wavlight.textures.atlas, made once per Scene."""
        key = tuple(id(t) for t in self.textures)
        cached = self.__dict__.get("_atlas")
        if cached is None or cached[0] != key:
            cached = (key, textures.atlas(self.textures))
            self.__dict__["_atlas"] = cached
        return cached[1]

    def albedo_at(self, face, bu, bv) -> np.ndarray:
        """(N, 3) float32 albedo at hits on faces (N,) at embree's barycentric (bu, bv): the
        material's albedo times its texture's bilinear lookup (wavlight.textures; the numpy twin
        of the kernels' albedo)."""
        face = np.asarray(face, np.int64)
        mat = self.face_material[face]
        albedo = self.material_albedo[mat]
        if not self.textured:
            return albedo
        uv = textures.hit_uv(textures.face_uv(self.faces[face], self.vertex_uv), np.arange(len(face)), bu, bv)
        texels, table = self.texture_atlas()
        return (albedo * textures.lookup(texels, table, self.material_texture[mat], uv)).astype(np.float32)

    @property
    def material_table(self):
        """The plastic table (materials, bsdfs.PLASTIC_STRIDE) float32: each plastic material's
        row (bsdfs.plastic_table), zeros for the other kinds."""
        rows = np.zeros((len(self.materials), bsdfs.PLASTIC_STRIDE), np.float32)
        for i, m in enumerate(self.materials):   # materials, not pixels
            if m.kind == bsdfs.PLASTIC:
                rows[i] = bsdfs.plastic_table(m.param, getattr(m, "ior", PLASTIC_IOR), m.albedo)
        return rows


def check_scene(scene) -> None:
    """What a renderer relies on in a Scene, checked again at render time (a Scene can be built
    or edited in Python, past load_scene's checks): a one-line WavlightError for a wrong type,
    shape or range, so that no kernel ever reads out of bounds."""
    def bad(what):
        raise WavlightError(f"scene {getattr(scene, 'path', '?')}: {what}")

    if not isinstance(scene, Scene):
        raise WavlightError(f"expected a Scene (wavlight.load_scene(path)) or a scene file's path, got "
                            f"{type(scene).__name__}")
    if not isinstance(getattr(scene, "options", None), dict):
        bad(f"options must be a dict of option values by key, got {type(getattr(scene, 'options', None)).__name__}")
    if not isinstance(scene.environment, Environment):
        bad(f"environment must be an Environment, got {type(scene.environment).__name__}")
    cam = scene.camera
    try:
        eye, target, up = (np.asarray(v, np.float64).reshape(3) for v in (cam.eye, cam.target, cam.up))
        fov = float(cam.fov_y)
    except (AttributeError, TypeError, ValueError):
        bad("camera must have eye, target and up (3 numbers each) and fov_y")
    if not (np.all(np.isfinite([*eye, *target, *up])) and 0 < fov < 180):
        bad("camera eye, target and up must be finite and fov_y in (0, 180) degrees")
    if max(np.abs(eye).max(), np.abs(target).max()) > MAX_COORDINATE:
        bad(f"camera eye and target must be within the ray tracer's range (|x| <= {MAX_COORDINATE:g})")
    view = target - eye
    if np.linalg.norm(view) == 0 or np.linalg.norm(np.cross(view, up)) == 0:
        bad("camera eye equals target, or up is parallel to the view")
    v, f, fm = (np.asarray(a) for a in (scene.vertices, scene.faces, scene.face_material))
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or fm.shape != (len(f),):
        bad(f"vertices (V, 3), faces (F, 3) and face_material (F,) expected, got {v.shape}, {f.shape}, {fm.shape}")
    if len(f) and not (np.issubdtype(f.dtype, np.integer) and np.issubdtype(fm.dtype, np.integer)):
        bad("faces and face_material must be integers")
    if not np.all(np.isfinite(v)):
        bad("vertices hold NaN or Inf")
    if v.size and np.abs(v).max() > MAX_COORDINATE:
        bad(f"vertex coordinates beyond the ray tracer's range (|x| <= {MAX_COORDINATE:g})")
    if len(f) and (f.min() < 0 or f.max() >= len(v)):
        bad("face indices out of range")
    if len(fm) and (fm.min() < 0 or fm.max() >= len(scene.materials)):
        bad(f"face_material out of range (0..{len(scene.materials) - 1})")
    tex = getattr(scene, "textures", [])
    if not isinstance(tex, list) or not all(isinstance(t, np.ndarray) and t.dtype == np.float32 and t.ndim == 3
                                            and t.shape[2] == 3 and t.shape[0] * t.shape[1] >= 1 for t in tex):
        bad("textures must be a list of (H, W, 3) float32 arrays")
    if sum(t.shape[0] * t.shape[1] for t in tex) > textures.MAX_ATLAS_TEXELS:
        bad(f"textures hold more than {textures.MAX_ATLAS_TEXELS} texels")
    if any(not (np.all(np.isfinite(t)) and t.min(initial=0.0) >= 0) for t in tex):
        bad("textures must be finite and >= 0")
    if any(not (-1 <= int(getattr(m, "texture", -1)) < len(tex)) for m in scene.materials):
        bad(f"a material's texture index is out of range (-1..{len(tex) - 1})")
    if getattr(scene, "textured", False):
        uv = getattr(scene, "vertex_uv", None)
        if (not isinstance(uv, np.ndarray) or uv.shape != (len(v), 2) or uv.dtype != np.float32
                or not np.all(np.isfinite(uv))):
            bad("a textured scene needs vertex_uv, (V, 2) finite float32")
    if getattr(scene, "normal_faces", None) is not None:   # the shading normals (None: every face flat)
        rows = np.asarray(scene.normal_faces)
        n = np.asarray(scene.normals if scene.normals is not None else np.zeros((0, 3)))
        if n.ndim != 2 or n.shape[1] != 3 or rows.shape != f.shape or (rows.size and not np.issubdtype(rows.dtype,
                                                                                                       np.integer)):
            bad(f"normals (N, 3) and normal_faces (F, 3) integers expected, got {n.shape} and {rows.shape}")
        if rows.size and (rows.min() < -1 or rows.max() >= len(n)):
            bad(f"normal_faces must name rows of the {len(n)} normals or be -1")
        if not np.all(np.isfinite(n)):
            bad("normals hold NaN or Inf")
    limits = {bsdfs.LAMBERT: (0.0, np.inf), bsdfs.PHONG: EXPONENT_RANGE, bsdfs.GGX: ROUGHNESS_RANGE,
              bsdfs.PLASTIC: ROUGHNESS_RANGE}
    for m in scene.materials:
        albedo = np.asarray(getattr(m, "albedo", None), np.float64)
        if getattr(m, "kind", None) not in limits or albedo.shape != (3,):
            bad(f"material {getattr(m, 'name', m)!r}: kind must be lambert, phong, ggx or plastic, albedo 3 numbers")
        ior = getattr(m, "ior", PLASTIC_IOR)
        if m.kind == bsdfs.PLASTIC and not (isinstance(ior, (int, float, np.floating, np.integer))
                                            and IOR_RANGE[0] < float(ior) <= IOR_RANGE[1]):
            bad(f"material {m.name!r}: plastic ior must be in ({IOR_RANGE[0]:g}, {IOR_RANGE[1]:g}], got {ior!r}")
        lo, hi = limits[m.kind]
        if not (np.all(np.isfinite(albedo)) and albedo.min() >= 0 and lo <= float(m.param) <= hi):
            bad(f"material {m.name!r}: albedo must be finite and >= 0, the parameter in [{lo:g}, {hi:g}], "
                f"got {albedo.tolist()} and {m.param}")


# ----------------------------------------------------------------------------- validation helpers
class Table:
    """One TOML table, reading typed keys and rejecting unknown ones."""

    def __init__(self, path, name, data):
        self.path, self.name = path, name
        if not isinstance(data, dict):
            self.fail("", f"must be a table, got {type(data).__name__}")
        self.data = data
        self.used = set()

    def fail(self, key, msg):
        raise SceneError(self.path, f"{self.name}.{key}" if key else self.name, msg)

    def has(self, key):
        return key in self.data

    def lookup(self, key, required=False):
        """(present, value) of ``key``, marked as used; a required key that is absent fails."""
        self.used.add(key)
        if key not in self.data:
            if required:
                self.fail(key, "is required")
            return False, None
        return True, self.data[key]

    def get(self, key, kind, default=None, required=False):
        present, v = self.lookup(key, required)
        if not present:
            return default
        if kind == "int":
            if isinstance(v, bool) or not isinstance(v, int):
                self.fail(key, f"must be an integer, got {shown(v)}")
        elif kind == "float":
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                self.fail(key, f"must be a finite number, got {shown(v)}")
            v = float(v)
        elif kind == "str":
            if not isinstance(v, str):
                self.fail(key, f"must be a string, got {shown(v)}")
        elif kind == "bool":
            if not isinstance(v, bool):
                self.fail(key, f"must be true or false, got {shown(v)}")
        elif kind == "vec3":
            if (not isinstance(v, list) or len(v) != 3
                    or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)):
                self.fail(key, f"must be a list of 3 finite numbers, got {shown(v)}")
            v = np.array(v, np.float64)
        return v

    def num_or_vec(self, key, n, default):
        """A number, or a list of n numbers (size, scale)."""
        self.used.add(key)
        if key not in self.data:
            return np.full(n, default, np.float64)
        v = self.data[key]
        ok_num = lambda x: isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
        if ok_num(v):
            return np.full(n, float(v))
        if isinstance(v, list) and len(v) == n and all(ok_num(x) for x in v):
            return np.array(v, np.float64)
        self.fail(key, f"must be a number or a list of {n} numbers, got {shown(v)}")

    def options(self) -> dict:
        """The strategies' and the sampler's settings that this table gives, by key, each checked by
        its declaration (wavlight.strategies.OPTIONS) and together by the constraints."""
        found = {}
        for key, option in OPTIONS.items():
            if key in self.data:
                self.used.add(key)
                why = option.problem(self.data[key])
                if why:
                    self.fail(key, why)
                found[key] = option.kind(self.data[key])
        for constraint in CONSTRAINTS:
            bad = constraint.problem(found)
            if bad:
                self.fail(*bad)
        return found

    def done(self):
        extra = sorted(set(self.data) - self.used)
        if extra:
            self.fail(extra[0], "unknown key")


def _positive(t: Table, key, value, lo=None, hi=None):
    if lo is not None and value < lo:
        t.fail(key, f"must be at least {lo}, got {value}")
    if hi is not None and value > hi:
        t.fail(key, f"must be at most {hi}, got {value}")
    return value


# ----------------------------------------------------------------------------- geometry
def _axis_angle(axis, degrees):
    axis = axis / np.linalg.norm(axis)
    a = math.radians(degrees)
    x, y, z = axis
    c, s, C = math.cos(a), math.sin(a), 1 - math.cos(a)
    return np.array([[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
                     [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
                     [z * x * C - y * s, z * y * C + x * s, c + z * z * C]])


def quad_axes(normal):
    """t1 = normalize(Y x n) (or +X when n is parallel to Y), t2 = n x t1."""
    n = normal / np.linalg.norm(normal)
    t1 = np.cross([0.0, 1.0, 0.0], n)
    if np.linalg.norm(t1) < 1e-9:
        t1 = np.array([1.0, 0.0, 0.0])
    t1 /= np.linalg.norm(t1)
    return n, t1, np.cross(n, t1)


# ----------------------------------------------------------------------------- arrays given to load_dict
#: the keys at which load_dict takes arrays (a mesh object at ``mesh``) in place of files
_GIVEN_KEY = re.compile(r"^(environment\.pixels|objects\[\d+\]\.(vertices|faces|mesh))$")


class _Given:
    """A value load_dict takes as it is where a file would be read (``_GIVEN_KEY``): an array, or
    a mesh object. It is checked where its key is read; the arrays made of it there (``arrays``:
    the pixels, or the vertices and faces, as the scene uses them) enter the content hash by
    their bytes."""

    def __init__(self, value):
        self.value = value
        self.arrays = ()

    def hashed(self) -> dict:
        """What the content hash takes of it: each array's dtype, shape and the sha256 of its bytes."""
        digest = hashlib.sha256()
        for a in self.arrays:
            digest.update(f"{a.dtype.str}{a.shape}".encode())
            digest.update(np.ascontiguousarray(a).data)
        return {"arrays": [[a.dtype.str, list(a.shape)] for a in self.arrays], "sha256": digest.hexdigest()}


def _hashed(value):
    """json.dumps' default for the content hash: a given array's description and digest."""
    if isinstance(value, _Given):
        return value.hashed()
    raise TypeError(f"{type(value).__name__} is not a scene value")


def _given_array(t: Table, key: str, value, what: str) -> np.ndarray:
    """``value`` as an array of real numbers (not copied where it is one), or a one-line error."""
    if isinstance(value, np.ndarray):
        a = value
    else:
        try:
            a = np.asarray(value)
        except (TypeError, ValueError, MemoryError):
            t.fail(key, f"must be {what}, got {shown(value)}")
    if a.dtype.kind not in "iuf":
        t.fail(key, f"must be {what}, got {shown(value)}")
    return a


def _given_pixels(t: Table) -> np.ndarray:
    """The map of ``[environment] pixels``: (H, W, 3) float32 (a copy), with the limits of a map file."""
    present, given = t.lookup("pixels")
    if not isinstance(given, _Given):
        t.fail("pixels", "an array of pixels is given to wavlight.load_dict only; a scene file names its map with file")
    a = _given_array(t, "pixels", given.value, "an (H, W, 3) array of numbers")
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] < 1 or a.shape[1] < 1:
        t.fail("pixels", f"must be an (H, W, 3) array of numbers, got shape {a.shape}")
    if a.shape[0] * a.shape[1] > MAX_TEXELS:   # read_image's words, before any conversion
        t.fail("pixels", f"image of {a.shape[1]}x{a.shape[0]} texels is too large "
                         f"(at most {MAX_TEXELS} texels, {MAX_TEXELS * 12 >> 20} MiB as float RGB)")
    with np.errstate(over="ignore", invalid="ignore"):   # beyond float32: Inf, then sanitised as a file's
        pixels = np.array(a, np.float32)
    given.arrays = (pixels,)
    return pixels


def _given_mesh(t: Table):
    """(vertices (V, 3) float64, faces (F, 3) int64) of ``vertices`` and ``faces`` arrays, or of a
    ``mesh`` object with vertices and faces (a trimesh.Trimesh), with a mesh file's checks."""
    if t.has("mesh"):
        if t.has("vertices") or t.has("faces"):
            t.fail("mesh", "give either mesh or vertices and faces, not both")
        _, given = t.lookup("mesh")
        obj = given.value
        if not (hasattr(obj, "vertices") and hasattr(obj, "faces")):
            t.fail("mesh", f"must be a mesh file, data:NAME or a mesh with vertices and faces (a trimesh.Trimesh), "
                           f"got {type(obj).__name__}")
        keys, values, owners = ("mesh", "mesh"), (obj.vertices, obj.faces), (given, given)
    else:
        if t.has("shape"):
            t.fail("shape", "give either shape or vertices and faces, not both")
        keys = ("vertices", "faces")
        owners = tuple(t.lookup(k, required=True)[1] for k in keys)
        for key, owner in zip(keys, owners):
            if not isinstance(owner, _Given):
                t.fail(key, "arrays are given to wavlight.load_dict only; a scene file names a mesh file")
        values = tuple(o.value for o in owners)
    v = _given_array(t, keys[0], values[0], "a (V, 3) array of vertex coordinates")
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 1:
        t.fail(keys[0], f"vertices must be a (V, 3) array of numbers, got shape {v.shape}")
    if len(v) > MAX_GIVEN_VERTICES:
        t.fail(keys[0], f"{len(v)} vertices; at most {MAX_GIVEN_VERTICES} (three per triangle of the most a scene "
                        "may have)")
    f = _given_array(t, keys[1], values[1], "an (F, 3) array of vertex indices")
    if f.ndim != 2 or f.shape[1] != 3:
        t.fail(keys[1], f"faces must be an (F, 3) array of vertex indices, got shape {f.shape}")
    if len(f) == 0:
        t.fail(keys[1], "the mesh holds no triangles")
    try:
        f = meshes.check_indices(f, len(v), holder="the vertices array")
    except meshes.MeshError as e:
        t.fail(keys[1], str(e))
    v = np.array(v, np.float64)
    if owners[0] is owners[1]:
        owners[0].arrays = (v, f)
    else:
        owners[0].arrays, owners[1].arrays = (v,), (f,)
    return v, f


def _given_triangles(o: dict) -> int:
    """The triangles of an object's given faces or mesh object, from its shape alone (0 where it
    has none or its shape is wrong: its own check names that)."""
    given = o.get("faces") if isinstance(o.get("faces"), _Given) else o.get("mesh")
    if not isinstance(given, _Given):
        return 0
    faces = getattr(given.value, "faces", None) if given is o.get("mesh") else given.value
    shape = getattr(faces, "shape", None)
    if shape is None:
        try:
            shape = (len(faces),)
        except TypeError:
            return 0
    return int(shape[0]) if len(shape) else 0


def _smooth(v, f, file_normals=None, corners=None):
    """(normals (N, 3), each corner's row (F, 3)): the file's normals where it gives them (per
    vertex, or per corner as an OBJ does: ``corners``, -1 where a corner has none), else the
    area-weighted vertex normals (:func:`meshes.vertex_normals`). A file normal that is zero or not
    finite is replaced by the computed one."""
    computed = meshes.vertex_normals(v, f)
    if file_normals is None or len(file_normals) == 0:
        return computed, np.asarray(f, np.int64)
    given = meshes.unit_rows(file_normals)
    if corners is None:   # per vertex
        bad = ~np.any(given != 0, axis=1)
        return np.where(bad[:, None], computed, given), np.asarray(f, np.int64)
    ok = corners >= 0
    ok[ok] = np.any(given[corners[ok]] != 0, axis=1)
    rows = np.where(ok, corners, len(given) + np.asarray(f, np.int64))
    return np.concatenate([given, computed]), rows


def _load_mesh(t: Table, path: str):
    """(vertices, faces, normals, corner rows) of a mesh file: PLY triangle meshes by
    :func:`meshes.read_ply`, OBJ by :func:`meshes.read_obj` (an index 0, past the end or
    fractional is named with its line, not taken for a degenerate triangle), everything else by
    trimesh, imported only then: each geometry of the file with its node's transform, loaded
    with ``process=False`` so that its vertices and their normals stay as the file has them
    (trimesh's concatenation of a file's parts, ``force="mesh"``, drops the normals). Normals as
    :func:`_smooth` makes them; trimesh's own where the file has none (angle-weighted)."""
    try:
        if path.lower().endswith(".ply"):
            mesh = meshes.read_ply(path, normals=True)
            if mesh is not None:
                return (*mesh[:2], *_smooth(*mesh))
        if path.lower().endswith(".obj"):
            v, f, vn, corners = meshes.read_obj(path, normals=True)
            if len(f) == 0:
                t.fail("mesh", f"{path} holds no triangles")
            return (v, f, *_smooth(v, f, vn, corners))
        import trimesh

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            loaded = trimesh.load(path, process=False)
            parts = []
            if isinstance(loaded, trimesh.Scene):
                for node in loaded.graph.nodes_geometry:
                    matrix, name = loaded.graph[node]
                    g = loaded.geometry[name]
                    if hasattr(g, "faces") and len(g.faces):
                        m = np.asarray(matrix, np.float64)
                        normal_matrix = np.linalg.inv(m[:3, :3]).T
                        parts.append((g.vertices @ m[:3, :3].T + m[:3, 3], g.faces, g.vertex_normals @ normal_matrix.T))
            elif hasattr(loaded, "faces") and len(loaded.faces):
                parts.append((loaded.vertices, loaded.faces, loaded.vertex_normals))
    except SceneError:
        raise
    except Exception as e:  # trimesh raises many types for bad files
        t.fail("mesh", f"cannot load {path}: {str(e).splitlines()[0] if str(e) else type(e).__name__}")
    if not parts:
        t.fail("mesh", f"{path} holds no triangles")
    offsets = np.cumsum([0] + [len(p[0]) for p in parts])
    v = np.concatenate([np.asarray(p[0], np.float64) for p in parts])
    f = np.concatenate([np.asarray(p[1], np.int64) + o for p, o in zip(parts, offsets)])
    return (v, f, *_smooth(v, f, np.concatenate([np.asarray(p[2], np.float64) for p in parts])))


def _shape(t: Table, base_dir, files: list, file_materials: bool = False):
    """(vertices, faces, normals, each corner's row of normals, parts) of one object before its
    transform: a mesh file's normals, else area-weighted vertex normals (meshes given as arrays
    too), the sphere's exact normals, the quad's own; ``parts`` (a list of wavlight.assets.Part,
    whose vertices and faces are concatenated in order) for a glTF or OBJ + MTL mesh file read
    with its materials (``file_materials``: the object names no material), else None."""
    if t.has("mesh") and t.has("shape"):
        t.fail("shape", "give either mesh or shape, not both")
    if t.has("vertices") or t.has("faces") or isinstance(t.data.get("mesh"), _Given):
        v, f = _given_mesh(t)
        return (v, f, *_smooth(v, f), None)
    if t.has("mesh"):
        rel = t.get("mesh", "str")
        try:
            path = data.resolve(rel, base_dir, kind="mesh")
        except WavlightError as e:
            t.fail("mesh", str(e))
        problem = file_problem(path)
        if problem:
            t.fail("mesh", f"{path}: {problem}")
        if file_materials and assets.has_materials(path):
            try:
                found = assets.read_cached(path)
            except (WavlightError, OSError) as e:
                t.fail("mesh", f"{path}: {e}")
            if found is not None:
                parts, _, linked = found
                files += [path, *linked]
                starts = np.cumsum([0] + [len(p.vertices) for p in parts])
                v = np.concatenate([p.vertices for p in parts])
                f = np.concatenate([p.faces + s for p, s in zip(parts, starts)])
                return (v, f, *_smooth(v, f, np.concatenate([p.normals for p in parts])), parts)
        v, f, n, rows = _load_mesh(t, path)
        files.append(path)
        if len(f) == 0:
            t.fail("mesh", f"{path} holds no triangles")
        return v, f, n, rows, None
    kind = t.get("shape", "str", required=True)
    if kind == "sphere":
        center = t.get("center", "vec3", np.zeros(3))
        radius = _positive(t, "radius", t.get("radius", "float", 1.0), lo=1e-9)
        sub = _positive(t, "subdivisions", t.get("subdivisions", "int", 5), lo=0, hi=8)
        v, f = meshes.icosphere(sub, radius)
        return v + center, f, v / radius, f, None
    if kind == "quad":
        center = t.get("center", "vec3", np.zeros(3))
        normal = t.get("normal", "vec3", np.array([0.0, 1.0, 0.0]))
        if np.linalg.norm(normal) == 0:
            t.fail("normal", "must not be zero")
        size = t.num_or_vec("size", 2, 1.0)
        if np.any(size <= 0):
            t.fail("size", f"must be positive, got {size.tolist()}")
        n, t1, t2 = quad_axes(normal)
        h1, h2 = 0.5 * size[0] * t1, 0.5 * size[1] * t2
        v = np.array([center - h1 - h2, center + h1 - h2, center + h1 + h2, center - h1 + h2])
        # counter-clockwise seen from +n
        f = np.array([[0, 1, 2], [0, 2, 3]]) if np.dot(np.cross(t1, t2), n) > 0 else np.array([[0, 2, 1], [0, 3, 2]])
        return v, f, np.tile(n / np.linalg.norm(n), (4, 1)), f, None
    t.fail("shape", f"unknown shape {kind!r} (sphere | quad)")


def rotation(rotate) -> np.ndarray:
    """The 3 x 3 matrix of a ``rotate`` value [axis x, y, z, degrees] (identity for None)."""
    if rotate is None:
        return np.eye(3)
    return _axis_angle(np.asarray(rotate[:3], np.float64), float(rotate[3]))


def _transform(t: Table, v):
    """(scaled local vertices, rotate [ax, ay, az, deg] or None, translate (3,), scale (3,)): an
    object's transform in the order scale, rotate, translate."""
    scale = t.num_or_vec("scale", 3, 1.0)
    if np.any(scale == 0):
        t.fail("scale", "must not be zero")
    v = v * scale
    rotate = None
    if t.has("rotate"):
        r = t.data["rotate"]
        t.used.add("rotate")
        if (not isinstance(r, list) or len(r) != 4
                or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in r)):
            t.fail("rotate", f"must be [axis x, y, z, degrees] of finite numbers, got {shown(r)}")
        if np.linalg.norm(np.array(r[:3], np.float64)) == 0:
            t.fail("rotate", "axis must not be zero")
        rotate = [float(x) for x in r]
    return v, rotate, t.get("translate", "vec3", np.zeros(3)), scale


def _good_triangles(path, key, v, f):
    """(F,) bool: the triangles that are not degenerate (zero area), with a warning for the others;
    a SceneError for out-of-range indices, vertices beyond range or every triangle degenerate."""
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise SceneError(path, key, "face indices out of range")
    if not np.all(np.isfinite(v)):
        raise SceneError(path, key, "vertices hold NaN or Inf")
    if v.size and np.abs(v).max() > MAX_COORDINATE:
        raise SceneError(path, key, f"vertex coordinates reach {np.abs(v).max():.3g}, beyond the ray tracer's "
                                    f"range (|x| <= {MAX_COORDINATE:g})")
    e = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    area2 = np.linalg.norm(e, axis=1)
    extent = np.ptp(v, axis=0).max() if len(v) else 0.0
    good = area2 > 1e-14 * extent ** 2 if extent > 0 else area2 > 0
    if not good.all():
        warnings.warn(f"{path}: {key}: {int((~good).sum())} degenerate triangle(s) removed", SanitisedInputWarning,
                      stacklevel=3)
    if not good.any():
        raise SceneError(path, key, "every triangle is degenerate (zero area)")
    return good


# ----------------------------------------------------------------------------- loading
#: the largest scene file read (geometry belongs in mesh files: a 10 MB value took seconds to parse)
MAX_SCENE_BYTES = 16 << 20
#: the most triangles a scene may have (about 390 bytes each while it is built and traced:
#: 2^24 of them is about 6.5 GB); counted from the shapes before they are made
MAX_TRIANGLES = 1 << 24
OBJECT_KEYS = {"mesh", "shape", "center", "radius", "subdivisions", "normal", "size", "translate", "rotate",
               "scale", "material", "name", "vertices", "faces", "face_normals"}
#: the most vertices a mesh given as arrays may have: three per triangle of the most a scene may
#: have (a mesh file's limit is its size, meshes.MAX_MESH_BYTES)
MAX_GIVEN_VERTICES = 3 * MAX_TRIANGLES

#: how deep a scene's values may nest (a table in a list in a table is 3): deeper input is refused
#: before any of it is read, rather than recursing without bound
MAX_NESTING = 16


def load_scene(path) -> Scene:
    """Read and validate a scene file (TOML, docs/scene-format.md); build its environment and
    merged geometry. Relative paths in it resolve against the file's folder. Errors name the
    file and the key (:class:`wavlight.errors.SceneError`)."""
    path = str(path)
    problem = file_problem(path)
    if problem:
        raise SceneError(path, "", problem)
    if os.path.getsize(path) > MAX_SCENE_BYTES:
        raise SceneError(path, "", f"a scene file of {os.path.getsize(path) >> 20} MiB; at most "
                                   f"{MAX_SCENE_BYTES >> 20} MiB (meshes belong in mesh files)")
    try:
        with open(path, "rb") as fh:
            doc = tomllib.load(fh)
    except tomllib.TOMLDecodeError as e:
        raise SceneError(path, "", f"malformed TOML: {e}") from None
    except RecursionError:
        raise SceneError(path, "", f"values nested too deeply (a scene nests at most {MAX_NESTING} levels)") from None
    except (OSError, UnicodeDecodeError) as e:
        raise SceneError(path, "", f"cannot read: {e}") from None
    return _parse(doc, path, os.path.dirname(os.path.abspath(path)))


def load_dict(d: dict, base_dir=None) -> Scene:
    """A scene from a Python dict with exactly the TOML file's structure (Mitsuba 3's
    ``load_dict`` is the model)::

        wavlight.load_dict({"render": {"width": 64, "height": 48, "strategy": "wavelet"},
                            "environment": {"procedural": "sky"},
                            "objects": [{"shape": "sphere", "radius": 0.5, "material": "gold"}],
                            "materials": {"gold": {"type": "ggx", "roughness": 0.1}}})

    Tuples and numpy arrays stand for TOML arrays, numpy scalars for numbers, ``pathlib``
    paths for strings. Arrays may stand for files: ``"environment": {"pixels": (H, W, 3)}`` for a
    map, ``{"vertices": (V, 3), "faces": (F, 3)}`` or ``{"mesh": trimesh.Trimesh}`` for an
    object's mesh, checked as files are (the same limits, messages and warnings, with
    ``<dict>`` and the key in place of the file) and hashed by their bytes. Relative paths
    resolve against ``base_dir`` (default: the current folder). Validation and errors are those
    of :func:`load_scene`, naming ``<dict>`` for the file."""
    if base_dir is None:
        base_dir = os.getcwd()
    if not isinstance(base_dir, (str, os.PathLike)) or not os.path.isdir(base_dir):
        raise SceneError("<dict>", "", f"base_dir must be an existing folder, got {shown(base_dir)}")
    return _parse(_plain(d, "<dict>", "", 0), "<dict>", os.path.abspath(base_dir))


def load_asset(path, environment=None, width=None, height=None) -> Scene:
    """A scene of one mesh file, rendered directly (``wavlight render ASSET.glb --env MAP``): the
    file as the only object, with its own materials (wavlight.assets), under the map
    ``environment`` (a file or ``data:NAME``, relative to the current folder; the procedural sky
    where None), seen by the file's glTF camera where it has one, else by a camera that frames
    its bounds (:func:`wavlight.assets.frame_bounds`, the default field of view). Errors name the
    file (SceneError). ``path`` may name a mesh asset of wavlight.data (``data:spot``)."""
    path = os.fspath(path)
    if path.startswith(data.PREFIX):
        try:
            path = data.resolve(path, kind="mesh")
        except WavlightError as e:
            raise SceneError(path, "", str(e)) from None
    path = os.path.abspath(path)
    problem = file_problem(path)
    if problem:
        raise SceneError(path, "", problem)
    if not assets.has_materials(path):
        raise SceneError(path, "", f"an asset rendered directly is a {', '.join(assets.SUFFIXES)} file")
    try:
        found = assets.read(path)
    except (WavlightError, OSError) as e:
        raise SceneError(path, "", str(e)) from None
    render = {k: v for k, v in (("width", width), ("height", height)) if v is not None}
    doc = {"render": render, "environment": {"file": environment} if environment is not None else {"procedural": "sky"},
           "objects": [{"mesh": path}]}
    try:
        with assets.reuse(path, found):
            scene = _parse(_plain(doc, path, "", 0), path, os.getcwd())
    except SceneError as e:   # the file's own problems without the scene-table key of its object
        if e.key == "[[objects]][0].mesh" and str(e).startswith(f"{path}: {e.key}: {path}: "):
            raise SceneError(path, "", str(e)[len(f"{path}: {e.key}: {path}: "):]) from None
        if e.key.startswith("[[objects]][0]"):
            raise SceneError(path, "", str(e)[len(f"{path}: {e.key}: "):]) from None
        raise
    own = found[1] if found is not None else None
    if own is not None:
        camera = Camera(own.eye, own.target, own.up, own.fov_y)
    else:
        eye, target, up = assets.frame_bounds(scene.vertices.min(axis=0), scene.vertices.max(axis=0), FOV.default,
                                              scene.width / scene.height)
        camera = Camera(eye, target, up, FOV.default)
    return replace(scene, camera=camera)


def _plain(v, path, key, depth):
    """A dict scene's values as TOML's types (dict, list, str, int, float, bool)."""
    if depth > MAX_NESTING:
        raise SceneError(path, key, f"values nested too deeply (a scene nests at most {MAX_NESTING} levels)")
    if _GIVEN_KEY.match(key) and not (key.endswith(".mesh") and isinstance(v, (str, os.PathLike))):
        return _Given(v)   # an array (or a mesh object) in place of a file: checked where it is read
    if isinstance(v, dict):
        bad = [k for k in v if not isinstance(k, str)]
        if bad:
            raise SceneError(path, key, f"keys must be strings, got {shown(bad[0])}")
        return {k: _plain(x, path, f"{key}.{k}" if key else k, depth + 1) for k, x in v.items()}
    if isinstance(v, np.ndarray):
        if v.size > 16:   # no scene value is a long array: refuse it without converting it
            raise SceneError(path, key, f"must be a short list, got {shown(v)}")
        v = v.tolist()
    if isinstance(v, (list, tuple)):
        return [_plain(x, path, f"{key}[{i}]", depth + 1) for i, x in enumerate(v)]
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, os.PathLike):
        return os.fspath(v)
    if v is None or not isinstance(v, (str, int, float, bool)):
        raise SceneError(path, key, f"must be a TOML value (table, list, string, number or boolean), "
                                    f"got {type(v).__name__}")
    return v


def _parse(doc, path: str, base: str) -> Scene:
    """A Scene from a parsed document (TOML's types); ``path`` names it in errors."""
    if not isinstance(doc, dict):
        raise SceneError(path, "", f"must be a table of tables, got {type(doc).__name__}")
    _check_depth(doc, path)
    unknown = sorted(set(doc) - {"render", "camera", "environment", "objects", "materials"})
    if unknown:
        raise SceneError(path, unknown[0], "unknown table")
    files = []   # the files the scene reads, for its content hash

    r = Table(path, "[render]", doc.get("render", {}))
    width, height, spp = (_positive(r, o.key, r.get(o.key, "int", o.default), o.lo, o.hi)
                          for o in (WIDTH, HEIGHT, SPP))
    strategy = r.get("strategy", "str", "mis")
    if strategy not in STRATEGIES:
        r.fail("strategy", f"unknown strategy {shown(strategy)} ({' | '.join(STRATEGIES)})")
    seed = _positive(r, "seed", r.get("seed", "int", SEED.default), SEED.lo, SEED.hi)
    options = r.options()
    r.done()

    c = Table(path, "[camera]", doc.get("camera", {}))
    camera = Camera(c.get("eye", "vec3", np.array([0.0, 1.0, 4.0])),
                    c.get("target", "vec3", np.array([0.0, 0.5, 0.0])),
                    c.get("up", "vec3", np.array([0.0, 1.0, 0.0])),
                    _positive(c, FOV.key, c.get(FOV.key, "float", FOV.default), FOV.lo, FOV.hi))
    for key, point in (("eye", camera.eye), ("target", camera.target)):
        if np.abs(point).max() > MAX_COORDINATE:
            c.fail(key, f"must be within the ray tracer's range (|x| <= {MAX_COORDINATE:g}), got {point.tolist()}")
    fwd = camera.target - camera.eye
    if np.linalg.norm(fwd) == 0:
        c.fail("target", "must differ from eye")
    if np.linalg.norm(np.cross(fwd, camera.up)) < 1e-9 * np.linalg.norm(fwd) * max(np.linalg.norm(camera.up), 1e-30):
        c.fail("up", "must not be parallel to the view direction")
    c.done()

    environment = _environment(Table(path, "[environment]", doc.get("environment", {})), base, files)

    mats_doc = doc.get("materials", {})
    if not isinstance(mats_doc, dict):
        raise SceneError(path, "materials", "must be a table of tables")
    materials, index = [], {}
    for name, m in mats_doc.items():
        t = Table(path, f"[materials.{name}]", m)
        kind = t.get("type", "str", required=True)
        if kind not in bsdfs.TYPES:
            t.fail("type", f"unknown BRDF {kind!r} (lambert | phong | ggx | plastic)")
        albedo = t.get("albedo", "vec3", np.array([0.8, 0.8, 0.8]))
        if np.any(albedo < 0):
            t.fail("albedo", "must not be negative")
        if np.any(albedo > MAX_ALBEDO):
            t.fail("albedo", f"must be at most {MAX_ALBEDO:g} (1 reflects all light), got {albedo.tolist()}")
        if np.any(albedo > 1):
            warnings.warn(f"{path}: [materials.{name}].albedo: above 1, the surface reflects more light than "
                          "it receives", stacklevel=2)
        # Both keys are accepted on every type (the format's own example does so); each type uses its own.
        roughness = _positive(t, "roughness", t.get("roughness", "float", 0.2), *ROUGHNESS_RANGE)
        exponent = _positive(t, "exponent", t.get("exponent", "float", 100.0), *EXPONENT_RANGE)
        alpha = _positive(t, "alpha", t.get("alpha", "float", PLASTIC_ALPHA), *ROUGHNESS_RANGE)
        ior = t.get("ior", "float", PLASTIC_IOR)
        if not IOR_RANGE[0] < ior <= IOR_RANGE[1]:
            t.fail("ior", f"must be in ({IOR_RANGE[0]:g}, {IOR_RANGE[1]:g}] (above the outside's 1), got {ior}")
        param = {"ggx": roughness, "phong": exponent, "plastic": alpha}.get(kind, 0.0)
        t.done()
        for key, users in (("roughness", "ggx"), ("exponent", "phong"), ("alpha", "plastic"),
                           ("ior", "plastic")):   # a key of another type: said
            if t.has(key) and kind != users:
                warnings.warn(f"{path}: [materials.{name}].{key}: ignored: only {users} materials use it",
                              stacklevel=2)
        index[name] = len(materials)
        materials.append(Material(name, bsdfs.TYPES[kind], albedo.astype(np.float32), float(param), float(ior)))

    objs = doc.get("objects", [])
    if not isinstance(objs, list):
        raise SceneError(path, "objects", "must be an array of tables ([[objects]])")
    _check_objects(path, objs, index)
    verts, faces, fmat, objects, uvs, texture_list, normals, normal_faces = [], [], [], [], [], [], [], []
    offset = face_offset = normal_offset = 0
    triangles = 0
    for i, o in enumerate(objs):
        t = Table(path, f"[[objects]][{i}]", o)
        object_name = t.get("name", "str")
        if object_name is not None:
            if not object_name or any(ob.name == object_name for ob in objects):
                t.fail("name", f"must be a non-empty name no other object has, got {shown(object_name)}")
        name = t.get("material", "str")
        v, f, n, rows, parts = _shape(t, base, files, file_materials=name is None)
        flat = t.get("face_normals", "bool", False)
        triangles += len(f)
        if triangles > MAX_TRIANGLES:
            raise SceneError(path, t.name, f"the objects up to this one make more than {MAX_TRIANGLES} triangles; "
                                           f"at most {MAX_TRIANGLES} are supported (about 390 bytes each)")
        local, rotate, translate, scale = _transform(t, v)
        v = local @ rotation(rotate).T + translate
        # normals go with the inverse transpose of the scale (then the rotation)
        local_n = np.zeros((0, 3)) if flat else meshes.unit_rows(n / scale)
        uv = None
        if name is not None and name not in index:
            t.fail("material", f"unknown material {name!r}")
        if parts is not None:   # the mesh file's own materials, part by part
            fm, uv = _part_materials(t, parts, materials, index, texture_list)
        else:
            if name is None:
                name = _default_material(materials, index)
            fm = np.full(len(f), index[name], np.int32)
        t.done()
        good = _good_triangles(path, t.name, v, f)
        f, fm = f[good], fm[good]
        rows = np.full((len(f), 3), -1, np.int64) if flat else rows[good] + normal_offset
        objects.append(SceneObject(object_name, i, local, f.astype(np.int32), rotate, translate, int(fm[0]),
                                   (face_offset, face_offset + len(f)), (offset, offset + len(v)), local_n,
                                   (normal_offset, normal_offset + len(local_n))))
        verts.append(v)
        uvs.append(uv)
        normals.append(local_n @ rotation(rotate).T)
        normal_faces.append(rows)
        normal_offset += len(local_n)
        faces.append(f + offset)
        fmat.append(fm)
        offset += len(v)
        face_offset += len(f)
    if not materials:
        materials.append(Material("__default__", bsdfs.LAMBERT, np.full(3, 0.5, np.float32), 0.0))
    vertices = np.concatenate(verts).astype(np.float32) if verts else np.zeros((0, 3), np.float32)
    vertex_uv = None
    if any(uv is not None for uv in uvs):
        vertex_uv = np.concatenate([np.zeros((len(v), 2), np.float32) if uv is None else uv
                                    for v, uv in zip(verts, uvs)]).astype(np.float32)
    digest = hashlib.sha256(json.dumps(doc, sort_keys=True, default=_hashed).encode())
    for name in files:
        digest.update(_file_digest(name))
    return Scene(path, width, height, spp, strategy, seed, camera, environment, vertices,
                 np.concatenate(faces).astype(np.int32) if faces else np.zeros((0, 3), np.int32),
                 np.concatenate(fmat) if fmat else np.zeros(0, np.int32), materials, options, digest.hexdigest(),
                 files, objects, texture_list, vertex_uv,
                 np.concatenate(normals).astype(np.float32) if normals else np.zeros((0, 3), np.float32),
                 np.concatenate(normal_faces).astype(np.int32) if normal_faces else np.zeros((0, 3), np.int32))


def _default_material(materials: list, index: dict) -> str:
    """The name of the default material (a grey lambert, albedo 0.5), added on first use."""
    if "__default__" not in index:
        index["__default__"] = len(materials)
        materials.append(Material("__default__", bsdfs.LAMBERT, np.full(3, 0.5, np.float32), 0.0))
    return "__default__"


def _part_materials(t: "Table", parts, materials: list, index: dict, texture_list: list):
    """(per-face material indices (F,) int32, vertex texture coordinates (V, 2) float32 or None) of
    a mesh file's parts (wavlight.assets.Part, in the order of its merged faces), appending a
    Material per mapped part and its texture to the scene's (``texture_list``)."""
    mesh, fm, uv, textured = t.data.get("mesh"), [], [], False
    for part in parts:
        m = part.material
        if m is None:
            k = index[_default_material(materials, index)]
        else:
            kind = bsdfs.TYPES.get(m.type)
            if kind is None:
                t.fail("mesh", f"{mesh}: {part.name}: maps to {m.type} ({m.why}), "
                               f"which this version of wavlight does not render; to render the file, give its object a "
                               f"material in a scene file (material = \"NAME\")")
            albedo = np.asarray(m.albedo, np.float64)
            if not np.all(np.isfinite(albedo)) or albedo.max() > MAX_ALBEDO:
                t.fail("mesh", f"{mesh}: {part.name}: albedo {albedo.tolist()} must be finite and at most "
                               f"{MAX_ALBEDO:g}")
            tex = -1
            if part.texture is not None:
                ids = [id(x) for x in texture_list]
                if id(part.texture) not in ids:
                    if (sum(x.shape[0] * x.shape[1] for x in texture_list)
                            + part.texture.shape[0] * part.texture.shape[1]) > textures.MAX_ATLAS_TEXELS:
                        t.fail("mesh", f"{mesh}: {part.name}: the scene's textures would hold more than "
                                       f"{textures.MAX_ATLAS_TEXELS} texels")
                    texture_list.append(part.texture)
                    ids.append(id(part.texture))
                tex = ids.index(id(part.texture))
                textured = True
            k = len(materials)
            materials.append(Material(f"{mesh}:{m.source or part.name}", kind, albedo.astype(np.float32),
                                      float(m.alpha) if m.type != "lambert" else 0.0, float(m.ior), texture=tex))
        fm.append(np.full(len(part.faces), k, np.int32))
        uv.append(part.uv if part.uv is not None else np.zeros((len(part.vertices), 2), np.float32))
    return np.concatenate(fm), (np.concatenate(uv).astype(np.float32) if textured else None)


def _check_objects(path, objs, materials: dict) -> None:
    """Every [[objects]] table's keys, material and name, and the triangles its built-in shape
    would make, checked before any geometry is built or any mesh read (a bad key on the last of
    many objects is found at once; spheres beyond any memory are refused before they exist)."""
    names, triangles = set(), 0
    for i, o in enumerate(objs):
        key = f"[[objects]][{i}]"
        if not isinstance(o, dict):
            raise SceneError(path, key, f"must be a table, got {type(o).__name__}")
        extra = sorted(set(o) - OBJECT_KEYS)
        if extra:
            raise SceneError(path, f"{key}.{extra[0]}", "unknown key")
        material = o.get("material")
        if material is not None and (not isinstance(material, str) or material not in materials):
            raise SceneError(path, f"{key}.material", f"unknown material {shown(material)}")
        name = o.get("name")
        if name is not None:
            if not isinstance(name, str) or not name or name in names:
                raise SceneError(path, f"{key}.name", f"must be a non-empty name no other object has, got {shown(name)}")
            names.add(name)
        if o.get("shape") == "sphere":
            s = o.get("subdivisions", 5)
            # a value outside 0..8 is left to the object's own check, which names it
            triangles += 20 * 4 ** s if isinstance(s, int) and not isinstance(s, bool) and 0 <= s <= 8 else 0
        elif o.get("shape") == "quad":
            triangles += 2
        else:
            triangles += _given_triangles(o)
        if triangles > MAX_TRIANGLES:
            raise SceneError(path, key, f"the objects up to this one make more than {MAX_TRIANGLES} triangles; "
                                        f"at most {MAX_TRIANGLES} are supported (about 390 bytes each)")


def _check_depth(doc, path):
    """Refuse values nested deeper than MAX_NESTING before anything walks them (iteratively)."""
    stack = [(doc, 0)]
    while stack:
        v, depth = stack.pop()
        if depth > MAX_NESTING:
            raise SceneError(path, "", f"values nested too deeply (a scene nests at most {MAX_NESTING} levels)")
        if isinstance(v, dict):
            stack += [(x, depth + 1) for x in v.values()]
        elif isinstance(v, list):
            stack += [(x, depth + 1) for x in v]


def _file_digest(name) -> bytes:
    """sha256 of a file's bytes, read in blocks."""
    h = hashlib.sha256()
    with open(name, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.digest()


def _environment(t: Table, base, files: list) -> Environment:
    scale = _positive(t, "scale", t.get("scale", "float", 1.0), 0.0)
    rotate_y = t.get("rotate_y", "float", 0.0)
    background = t.get("background", "str", BACKGROUND.default)
    why = BACKGROUND.problem(background)
    if why:
        t.fail("background", why)
    if t.has("file") and t.has("procedural"):
        t.fail("procedural", "give either file or procedural, not both")
    if t.has("pixels") and (t.has("file") or t.has("procedural")):
        t.fail("pixels", f"give either pixels or {'file' if t.has('file') else 'procedural'}, not both")
    if t.has("pixels"):
        pixels = _given_pixels(t)
        name, source = f"{t.path}: [environment].pixels", "pixels"
    elif t.has("procedural"):
        kind = t.get("procedural", "str")
        if kind != "sky":
            t.fail("procedural", f"unknown procedural environment {kind!r} (sky)")
        kw = {k: t.get(k, "float") for k in ("sun_elevation", "sun_azimuth", "sun_radius", "sun_radiance")
              if t.has(k)}
        if not -90 <= kw.get("sun_elevation", 0.0) <= 90:
            t.fail("sun_elevation", "must be in [-90, 90] degrees")
        if not 0 < kw.get("sun_radius", 1.0) <= 90:
            t.fail("sun_radius", "must be in (0, 90] degrees")
        if kw.get("sun_radiance", 1.0) < 0:
            t.fail("sun_radiance", "must not be negative")
        pixels, name, source = procedural_sky(**kw), "procedural sky", "sun_radiance"
    else:
        rel = t.get("file", "str", required=True)
        try:
            fname = data.resolve(rel, base, kind="environment map")
            pixels = read_image(fname)
        except WavlightError as e:
            t.fail("file", str(e))
        name, source = fname, "file"
        files.append(fname)
    t.done()
    with np.errstate(over="ignore", invalid="ignore"):
        scaled = np.nan_to_num(pixels, nan=0, posinf=0, neginf=0) * np.float32(scale)
        if not np.all(np.isfinite(scaled)):
            t.fail("scale", f"{scale} makes the environment's radiance overflow to Inf")
    peak = float(scaled.max(initial=0.0))
    if peak > np.float32(MAX_RADIANCE):
        t.fail("scale" if scale != 1.0 else source, f"radiance up to {peak:.3g}; at most {MAX_RADIANCE:g} is "
               "supported (float32 estimates would overflow): rescale the map")
    return Environment(pixels, scale, rotate_y, name, background)
