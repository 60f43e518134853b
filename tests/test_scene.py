"""Scene files: every documented key, defaults, geometry, the procedural sky, and errors.

The format is /work/shared/docs/scene-format.md (the interface users rely on); wavlight's own
additions and defaults are documented in wavlight/scene.py. These tests only call
wavlight.load_scene (no OpenCL), so they are fast.
"""
from __future__ import annotations

import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

import wavlight
from scenes_util import write_raw_image
from wavlight import SceneError, WavlightError
from wavlight.scene import quad_axes

#: the scene format's contract (beside the repository in development and CI) and wavlight's own
#: docs/scene-format.md, which repeats the contract's example verbatim
CONTRACT = Path(__file__).resolve().parents[2] / "shared" / "docs" / "scene-format.md"
DOC = Path(__file__).resolve().parents[1] / "docs" / "scene-format.md"
SKY = '[environment]\nprocedural = "sky"\n'


# ----------------------------------------------------------------------------- helpers
write_env = write_raw_image  # scenes_util


def write_scene(folder, text, name="scene.toml"):
    path = Path(folder) / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def load(folder, text, name="scene.toml"):
    return wavlight.load_scene(str(write_scene(folder, text, name)))


def write_obj(path, vertices, faces):
    """faces are 0-based here; OBJ is 1-based."""
    lines = [f"v {float(x):.17g} {float(y):.17g} {float(z):.17g}" for x, y, z in vertices]
    lines += ["f " + " ".join(str(i + 1) for i in f) for f in faces]
    Path(path).write_text("\n".join(lines) + "\n")
    return path


def write_ply(path, vertices, faces):
    head = ["ply", "format ascii 1.0", f"element vertex {len(vertices)}", "property float x",
            "property float y", "property float z", f"element face {len(faces)}",
            "property list uchar int vertex_indices", "end_header"]
    body = ([f"{float(x):.9g} {float(y):.9g} {float(z):.9g}" for x, y, z in vertices]
            + [f"3 {a} {b} {c}" for a, b, c in faces])
    Path(path).write_text("\n".join(head + body) + "\n")
    return path


def rodrigues(v, axis, degrees):
    """Right-handed rotation of the rows of v about axis, written independently of wavlight."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    a = math.radians(degrees)
    v = np.asarray(v, float)
    return (v * math.cos(a) + np.cross(k, v) * math.sin(a)
            + np.outer(v @ k, k) * (1 - math.cos(a)))


def same_points(got, want, tol=1e-5):
    """Same set of points, in any order (loaders may reorder or merge vertices)."""
    got, want = np.asarray(got, float), np.asarray(want, float)
    assert len(got) == len(want), (got, want)
    d = np.linalg.norm(got[:, None, :] - want[None, :, :], axis=2)
    assert d.min(axis=0).max() < tol, (got, want)
    assert d.min(axis=1).max() < tol, (got, want)


def face_normals(scene):
    v = scene.vertices.astype(float)
    f = scene.faces
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    return n, 0.5 * np.linalg.norm(n, axis=1)


TETRA_V = [(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)]
TETRA_F = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]


# ----------------------------------------------------------------------------- every key
ALL_KEYS = """
[render]
width = 24
height = 16
spp = 3
strategy = "bsdf"
seed = 11

[camera]
eye = [0.0, 2.0, 6.0]
target = [0.0, 0.25, 0.0]
up = [0.0, 1.0, 0.0]
fov_y = 40.0

[environment]
file = "env/sky.exr"
scale = 2.0
rotate_y = 30.0

[[objects]]
mesh = "meshes/tetra.obj"
translate = [1.0, 0.0, 0.0]
rotate = [0.0, 1.0, 0.0, 30.0]
scale = 0.5
material = "gold"

[[objects]]
shape = "sphere"
center = [0.0, 1.0, 0.0]
radius = 0.5
subdivisions = 2
translate = [0.0, 0.0, 0.0]
rotate = [1.0, 0.0, 0.0, 10.0]
scale = [1.0, 1.0, 1.0]
material = "plastic"

[[objects]]
shape = "quad"
center = [0.0, 0.0, 0.0]
normal = [0.0, 1.0, 0.0]
size = [4.0, 3.0]
material = "floor"

[[objects]]
shape = "quad"
center = [0.0, 0.0, -2.0]
normal = [0.0, 0.0, 1.0]
size = 2.0

[materials.gold]
type = "ggx"
albedo = [1.0, 0.78, 0.34]
roughness = 0.15

[materials.plastic]
type = "phong"
albedo = [0.6, 0.15, 0.15]
exponent = 60.0

[materials.floor]
type = "lambert"
albedo = [0.6, 0.6, 0.6]
"""


def test_scene_using_every_key_loads(tmp_path):
    env = np.full((8, 16, 3), 0.5, np.float32)
    env[0] = [1.0, 2.0, 3.0]
    (tmp_path / "env").mkdir()
    write_env(tmp_path / "env" / "sky.exr", env)
    (tmp_path / "meshes").mkdir()
    write_obj(tmp_path / "meshes" / "tetra.obj", TETRA_V, TETRA_F)
    s = load(tmp_path, ALL_KEYS)

    assert (s.width, s.height, s.spp, s.strategy, s.seed) == (24, 16, 3, "bsdf", 11)
    np.testing.assert_allclose(s.camera.eye, [0, 2, 6])
    np.testing.assert_allclose(s.camera.target, [0, 0.25, 0])
    np.testing.assert_allclose(s.camera.up, [0, 1, 0])
    assert s.camera.fov_y == 40.0
    assert s.environment.rotate_y == 30.0
    np.testing.assert_allclose(s.environment.pixels, env * 2.0)  # radiance = pixel x scale
    # 4 + 320 (icosphere, 2 subdivisions) + 2 + 2 triangles
    assert len(s.faces) == 4 + 20 * 4 ** 2 + 2 + 2
    assert s.vertices.dtype == np.float32 and s.faces.dtype == np.int32
    assert s.faces.min() >= 0 and s.faces.max() < len(s.vertices)
    names = [m.name for m in s.materials]
    kinds = {m.name: m.kind for m in s.materials}
    assert kinds["gold"] == 2 and kinds["plastic"] == 1 and kinds["floor"] == 0
    gold = s.materials[names.index("gold")]
    np.testing.assert_allclose(gold.albedo, [1.0, 0.78, 0.34], rtol=1e-6)
    assert gold.param == pytest.approx(0.15)
    assert s.materials[names.index("plastic")].param == pytest.approx(60.0)
    # the per-face material follows the objects (the last quad has none: the grey default)
    fm = [s.materials[i].name for i in s.face_material]
    assert fm[:4] == ["gold"] * 4
    assert set(fm[4:4 + 320]) == {"plastic"}
    assert fm[324:326] == ["floor", "floor"]
    default = s.materials[s.face_material[-1]]
    assert default.kind == 0
    np.testing.assert_allclose(default.albedo, [0.5, 0.5, 0.5])


def _doc_toml_block(doc=DOC):
    blocks = re.findall(r"```toml\n(.*?)```", doc.read_text(), re.S)
    assert blocks, f"no ```toml block in {doc}"
    return blocks[0]


def test_the_docs_example_is_the_contracts():
    """docs/scene-format.md's example is the contract's, where the contract is at hand (in
    development and CI, beside the repository); elsewhere the docs' own example is tested below."""
    if CONTRACT.is_file():
        assert _doc_toml_block(DOC) == _doc_toml_block(CONTRACT)
    else:
        assert "[materials.gold]" in _doc_toml_block(DOC)


def test_scene_format_doc_example_loads_verbatim(tmp_path):
    """The example in scene-format.md, unchanged, with its two files provided at the paths it names.

    Its [materials.gold] is a ggx material that also carries `exponent = 100.0  # phong only`:
    the doc promises that every key is accepted exactly as written there.
    """
    text = _doc_toml_block()
    scenes = tmp_path / "scenes"
    (scenes / "meshes").mkdir(parents=True)
    write_ply(scenes / "meshes" / "bunny.ply", TETRA_V, TETRA_F)
    envdir = tmp_path / "shared" / "data" / "envmaps"
    envdir.mkdir(parents=True)
    wavlight.save_image(str(envdir / "kiara_1_dawn_1k.hdr"), np.full((8, 16, 3), 0.5, np.float32))
    s = load(scenes, text)
    assert (s.width, s.height, s.spp, s.strategy, s.seed) == (256, 256, 16, "mis", 7)
    assert len(s.faces) == 4
    gold = [m for m in s.materials if m.name == "gold"][0]
    assert gold.kind == 2 and gold.param == pytest.approx(0.15)


@pytest.mark.parametrize("strategy", ["uniform", "cosine", "bsdf", "light", "mis"])
def test_each_strategy_name_is_accepted(tmp_path, strategy):
    s = load(tmp_path, f'[render]\nstrategy = "{strategy}"\n' + SKY)
    assert s.strategy == strategy


@pytest.mark.parametrize("ext", ["exr", "pfm", "hdr"])
def test_environment_file_formats(tmp_path, ext):
    px = np.random.default_rng(1).uniform(0.1, 4.0, (8, 16, 3)).astype(np.float32)
    wavlight.save_image(str(tmp_path / f"env.{ext}"), px)
    s = load(tmp_path, f'[environment]\nfile = "env.{ext}"\nscale = 0.5\n')
    assert s.environment.pixels.shape == (8, 16, 3)
    want = px * 0.5
    if ext == "hdr":  # RGBE: 8-bit mantissas with an exponent shared by the texel's channels
        err = np.abs(s.environment.pixels - want) / want.max(axis=2, keepdims=True)
        assert err.max() < 0.01
    else:
        np.testing.assert_allclose(s.environment.pixels, want, rtol=1e-6)


def _top_bright(h=4, w=8):
    px = np.full((h, w, 3), 0.25, np.float32)
    px[0] = [4.0, 2.0, 1.0]  # row 0 = the top = +Y
    return px


@pytest.mark.parametrize("ext", ["exr", "hdr", "pfm"])
def test_environment_row_zero_is_up(tmp_path, ext):
    """Row 0 of the file is the top of the map: looking up (+Y) sees it (via wavlight's own writer)."""
    wavlight.save_image(str(tmp_path / f"env.{ext}"), _top_bright())
    s = load(tmp_path, f'[environment]\nfile = "env.{ext}"\n')
    np.testing.assert_allclose(s.environment.eval(np.array([[0.0, 1.0, 0.0]])), [[4.0, 2.0, 1.0]], rtol=0.01)
    np.testing.assert_allclose(s.environment.eval(np.array([[0.0, -1.0, 0.0]])), [[0.25] * 3], rtol=0.01)


def test_pfm_written_by_the_spec_is_read_upright(tmp_path):
    """A PFM stores its scanlines bottom to top (the PFM spec; Mitsuba, HDRShop, Debevec's files).

    The file is written by hand here, independently of OpenImageIO. (OpenImageIO 3.2 only flips
    PFM on read when the caller passes the "pnm:pfmflip" config hint; its writer flips by itself.)
    """
    px = _top_bright()
    h, w = px.shape[:2]
    body = np.ascontiguousarray(px[::-1]).astype("<f4").tobytes()  # bottom row first
    (tmp_path / "env.pfm").write_bytes(f"PF\n{w} {h}\n-1.0\n".encode() + body)
    s = load(tmp_path, '[environment]\nfile = "env.pfm"\n')
    np.testing.assert_allclose(s.environment.pixels, px)


def test_relative_paths_resolve_against_the_scene_folder(tmp_path, monkeypatch):
    (tmp_path / "a" / "b").mkdir(parents=True)
    write_env(tmp_path / "a" / "env.pfm", np.ones((4, 8, 3)))
    write_obj(tmp_path / "a" / "b" / "m.obj", TETRA_V, TETRA_F)
    path = write_scene(tmp_path / "a" / "b", '[environment]\nfile = "../env.pfm"\n[[objects]]\nmesh = "m.obj"\n')
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    s = wavlight.load_scene(str(path))
    assert len(s.faces) == 4


# ----------------------------------------------------------------------------- defaults
def test_defaults(tmp_path):
    s = load(tmp_path, SKY)
    assert (s.width, s.height, s.spp, s.strategy, s.seed) == (256, 256, 16, "mis", 0)
    np.testing.assert_allclose(s.camera.eye, [0, 1, 4])
    np.testing.assert_allclose(s.camera.target, [0, 0.5, 0])
    np.testing.assert_allclose(s.camera.up, [0, 1, 0])
    assert s.camera.fov_y == 35.0
    assert s.environment.rotate_y == 0.0
    assert s.vertices.shape == (0, 3) and s.faces.shape == (0, 3) and s.face_material.shape == (0,)
    assert len(s.materials) >= 1  # always something to index


def test_object_defaults(tmp_path):
    s = load(tmp_path, SKY + '[[objects]]\nshape = "sphere"\n')
    assert len(s.faces) == 20 * 4 ** 5  # subdivisions = 5
    np.testing.assert_allclose(np.linalg.norm(s.vertices, axis=1), 1.0, rtol=1e-6)  # radius 1 at 0
    (m,) = s.materials
    assert m.kind == 0
    np.testing.assert_allclose(m.albedo, [0.5, 0.5, 0.5])  # objects without material: grey lambert
    q = load(tmp_path, SKY + '[[objects]]\nshape = "quad"\n')
    same_points(q.vertices, [(-0.5, 0, 0.5), (0.5, 0, 0.5), (0.5, 0, -0.5), (-0.5, 0, -0.5)])


def test_material_defaults(tmp_path):
    s = load(tmp_path, SKY + '[materials.a]\ntype = "lambert"\n[materials.b]\ntype = "ggx"\n'
             '[materials.c]\ntype = "phong"\n')
    m = {x.name: x for x in s.materials}
    for name in "abc":
        np.testing.assert_allclose(m[name].albedo, [0.8, 0.8, 0.8])
    assert m["b"].param == pytest.approx(0.2)
    assert m["c"].param == pytest.approx(100.0)


# ----------------------------------------------------------------------------- transforms
def test_transform_order_scale_rotate_translate(tmp_path):
    verts = [(1.0, 2.0, 3.0), (-1.0, 0.5, 0.0), (0.0, -2.0, 1.0), (2.0, 1.0, -1.0)]
    write_obj(tmp_path / "m.obj", verts, TETRA_F)
    s = load(tmp_path, SKY + '[[objects]]\nmesh = "m.obj"\nscale = [2.0, 3.0, 0.5]\n'
             'rotate = [1.0, 1.0, 0.0, 40.0]\ntranslate = [1.0, -2.0, 3.0]\n')
    want = rodrigues(np.array(verts) * [2.0, 3.0, 0.5], [1, 1, 0], 40.0) + [1.0, -2.0, 3.0]
    same_points(s.vertices, want)


def test_transform_uniform_scale(tmp_path):
    write_obj(tmp_path / "m.obj", TETRA_V, TETRA_F)
    s = load(tmp_path, SKY + '[[objects]]\nmesh = "m.obj"\nscale = 3\n')
    same_points(s.vertices, np.array(TETRA_V) * 3)


def test_rotation_is_right_handed_in_degrees(tmp_path):
    """+90 degrees about +Y sends +X to -Z and +Z to +X (hand-computed, not via a formula)."""
    verts = [(1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, 1.0, 0.0), (1.0, 1.0, 1.0)]
    write_obj(tmp_path / "m.obj", verts, TETRA_F)
    s = load(tmp_path, SKY + '[[objects]]\nmesh = "m.obj"\nrotate = [0, 2, 0, 90]\n')
    same_points(s.vertices, [(0, 0, -1), (1, 0, 0), (0, 1, 0), (1, 1, -1)])
    s = load(tmp_path, SKY + '[[objects]]\nmesh = "m.obj"\nrotate = [0.0, 0.0, 1.0, 90.0]\n')
    same_points(s.vertices, [(0, 1, 0), (0, 0, 1), (-1, 0, 0), (-1, 1, 1)])  # +X -> +Y, +Y -> -X


def test_shape_center_then_object_transform(tmp_path):
    s = load(tmp_path, SKY + '[[objects]]\nshape = "sphere"\ncenter = [1.0, 0.0, 0.0]\nradius = 0.25\n'
             'subdivisions = 1\nrotate = [0.0, 1.0, 0.0, 90.0]\ntranslate = [0.0, 5.0, 0.0]\n')
    # the sphere's center (1, 0, 0) rotates to (0, 0, -1), then moves up by 5
    np.testing.assert_allclose(np.linalg.norm(s.vertices - [0, 5, -1], axis=1), 0.25, rtol=1e-5)


# ----------------------------------------------------------------------------- quads
@pytest.mark.parametrize("normal, t1, t2", [
    ((0, 1, 0), (1, 0, 0), (0, 0, -1)),      # parallel to Y: t1 = +X
    ((0, -3, 0), (1, 0, 0), (0, 0, 1)),      # anti-parallel, not unit
    ((0, 0, 1), (1, 0, 0), (0, 1, 0)),
    ((1, 0, 0), (0, 0, -1), (0, 1, 0)),
    ((0, 0, -2), (-1, 0, 0), (0, 1, 0)),
])
def test_quad_axes_hand_computed(normal, t1, t2):
    n, a1, a2 = quad_axes(np.array(normal, float))
    np.testing.assert_allclose(n, np.array(normal) / np.linalg.norm(normal), atol=1e-12)
    np.testing.assert_allclose(a1, t1, atol=1e-12)
    np.testing.assert_allclose(a2, t2, atol=1e-12)


def _quad_expected(center, normal, s1, s2):
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    y = np.array([0.0, 1.0, 0.0])
    t1 = np.array([y[1] * n[2] - y[2] * n[1], y[2] * n[0] - y[0] * n[2], y[0] * n[1] - y[1] * n[0]])
    t1 = np.array([1.0, 0.0, 0.0]) if np.linalg.norm(t1) < 1e-9 else t1 / np.linalg.norm(t1)
    t2 = np.cross(n, t1)
    c = np.asarray(center, float)
    return [c + a * s1 / 2 * t1 + b * s2 / 2 * t2 for a in (-1, 1) for b in (-1, 1)], n


@pytest.mark.parametrize("normal", [(0, 1, 0), (0, -1, 0), (1, 2, 3), (0, 0, 1), (-1, 0.5, 0)])
@pytest.mark.parametrize("size, s1, s2", [("2.5", 2.5, 2.5), ("[1.0, 4.0]", 1.0, 4.0)])
def test_quad_vertices(tmp_path, normal, size, s1, s2):
    center = (0.5, -1.0, 2.0)
    s = load(tmp_path, SKY + f'[[objects]]\nshape = "quad"\ncenter = {list(map(float, center))}\n'
             f'normal = {list(map(float, normal))}\nsize = {size}\n')
    want, n = _quad_expected(center, normal, s1, s2)
    same_points(s.vertices, want)
    assert len(s.faces) == 2
    fn, area = face_normals(s)
    np.testing.assert_allclose(area.sum(), s1 * s2, rtol=1e-5)
    np.testing.assert_allclose(np.abs(fn / np.linalg.norm(fn, axis=1, keepdims=True) @ n), 1.0, atol=1e-5)


# ----------------------------------------------------------------------------- spheres
@pytest.mark.parametrize("sub", [0, 1, 3])
def test_sphere_center_radius(tmp_path, sub):
    center, radius = np.array([1.5, -0.5, 2.0]), 0.75
    s = load(tmp_path, SKY + f'[[objects]]\nshape = "sphere"\ncenter = {center.tolist()}\n'
             f'radius = {radius}\nsubdivisions = {sub}\n')
    np.testing.assert_allclose(np.linalg.norm(s.vertices - center, axis=1), radius, rtol=1e-5)
    assert len(s.faces) == 20 * 4 ** sub
    assert len(s.vertices) == 10 * 4 ** sub + 2
    np.testing.assert_allclose(s.vertices.mean(axis=0), center, atol=1e-5)


def test_two_objects_merge_with_offset_indices(tmp_path):
    write_obj(tmp_path / "m.obj", TETRA_V, TETRA_F)
    s = load(tmp_path, SKY + '[[objects]]\nmesh = "m.obj"\n[[objects]]\nmesh = "m.obj"\ntranslate = [5, 0, 0]\n')
    assert len(s.faces) == 8 and len(s.vertices) == 8
    assert s.faces[:4].max() < 4 and s.faces[4:].min() >= 4
    assert s.vertices[s.faces[4:]].reshape(-1, 3)[:, 0].min() >= 5 - 1e-6


# ----------------------------------------------------------------------------- procedural sky
def _dir(row, col, h, w):
    theta, phi = (row + 0.5) / h * np.pi, (col + 0.5) / w * 2 * np.pi
    return np.array([np.sin(theta) * np.sin(phi), np.cos(theta), -np.sin(theta) * np.cos(phi)])


def _sun(el, az):
    el, az = math.radians(el), math.radians(az)
    return np.array([math.cos(el) * math.sin(az), math.sin(el), -math.cos(el) * math.cos(az)])


@pytest.mark.parametrize("el, az", [(35.0, 30.0), (10.0, -120.0), (60.0, 150.0)])
def test_procedural_sky_keys(tmp_path, el, az):
    s = load(tmp_path, f'[environment]\nprocedural = "sky"\nsun_elevation = {el}\nsun_azimuth = {az}\n'
             'sun_radius = 3.0\nsun_radiance = 1000.0\nscale = 0.5\n')
    px = s.environment.pixels
    assert np.all(np.isfinite(px)) and px.min() >= 0
    h, w = px.shape[:2]
    lum = px @ [0.2126, 0.7152, 0.0722]
    np.testing.assert_allclose(px.max(axis=(0, 1)), 0.5 * 1000.0 * np.array([1.0, 0.95, 0.85]), rtol=1e-5)
    # every sun texel (half covered or more) touches the sun's disk about (elevation, azimuth
    # from -Z towards +X): its centre within the radius plus half a texel's diagonal
    rows, cols = np.nonzero(lum > 0.5 * lum.max())
    assert len(rows) > 3
    half_diagonal = math.degrees(math.hypot(math.pi / h, 2 * math.pi / w)) / 2
    for r, c in zip(rows, cols):
        ang = math.degrees(math.acos(np.clip(_dir(r, c, h, w) @ _sun(el, az), -1, 1)))
        assert ang < 3.0 + half_diagonal
    # the sky is far dimmer than the sun, and the sun is looked up where it should be
    assert np.median(lum) < 2.0
    np.testing.assert_allclose(s.environment.eval(_sun(el, az)[None]), [[500.0, 475.0, 425.0]], rtol=1e-5)


def test_procedural_sky_rotate_y(tmp_path):
    """rotate_y = +90 sends the map's +X direction to world -Z (world = R_y * map)."""
    s = load(tmp_path, '[environment]\nprocedural = "sky"\nsun_elevation = 0.0\nsun_azimuth = 90.0\n'
             'sun_radius = 4.0\nsun_radiance = 100.0\nrotate_y = 90.0\n')
    # the sun is at map +X; after the rotation it must be seen at world -Z, not at world +X
    np.testing.assert_allclose(s.environment.eval(np.array([[0.0, 0.0, -1.0]])), [[100, 95, 85]], rtol=1e-5)
    assert s.environment.eval(np.array([[1.0, 0.0, 0.0]]))[0, 0] < 10


def test_procedural_sky_defaults(tmp_path):
    s = load(tmp_path, SKY)
    px = s.environment.pixels
    assert px.shape[2] == 3 and np.all(np.isfinite(px)) and px.min() >= 0
    np.testing.assert_allclose(px.max(axis=(0, 1)), 2.0e4 * np.array([1.0, 0.95, 0.85]), rtol=1e-5)
    np.testing.assert_allclose(s.environment.eval(_sun(35.0, 30.0)[None]), [[2.0e4, 1.9e4, 1.7e4]], rtol=1e-5)


# ----------------------------------------------------------------------------- errors
# (scene text, the key the message must name); every message also names the file.
BAD = {
    "slots without candidates": ('[render]\nwavelet_candidates = 0\nwavelet_slots = 4\n' + SKY,
                                 "[render].wavelet_slots"),
    "albedo absurd": ('[materials.m]\ntype = "ggx"\nalbedo = [1e300, 1.0, 1.0]\n' + SKY, "[materials.m].albedo"),
    "unknown table": ('[rendr]\nspp = 1\n' + SKY, "rendr"),
    "render not a table": ('render = 3\n' + SKY, "[render]"),
    "unknown render key": ('[render]\nspp = 2\nsamples = 4\n' + SKY, "[render].samples"),
    "width float": ('[render]\nwidth = 3.5\n' + SKY, "[render].width"),
    "width string": ('[render]\nwidth = "64"\n' + SKY, "[render].width"),
    "width bool": ('[render]\nwidth = true\n' + SKY, "[render].width"),
    "width zero": ('[render]\nwidth = 0\n' + SKY, "[render].width"),
    "width absurd": ('[render]\nwidth = 100000\nheight = 100000\n' + SKY, "[render].width"),
    "height absurd": ('[render]\nheight = 100000\n' + SKY, "[render].height"),
    "height negative": ('[render]\nheight = -4\n' + SKY, "[render].height"),
    "spp zero": ('[render]\nspp = 0\n' + SKY, "[render].spp"),
    "spp huge": ('[render]\nspp = 1000000000\n' + SKY, "[render].spp"),
    "spp float": ('[render]\nspp = 2.0\n' + SKY, "[render].spp"),
    "strategy unknown": ('[render]\nstrategy = "best"\n' + SKY, "[render].strategy"),
    "strategy not a string": ('[render]\nstrategy = 3\n' + SKY, "[render].strategy"),
    "seed float": ('[render]\nseed = 1.5\n' + SKY, "[render].seed"),
    "camera unknown key": ('[camera]\nfov = 30.0\n' + SKY, "[camera].fov"),
    "eye two numbers": ('[camera]\neye = [1.0, 2.0]\n' + SKY, "[camera].eye"),
    "eye string": ('[camera]\neye = "origin"\n' + SKY, "[camera].eye"),
    "eye nan": ('[camera]\neye = [nan, 1.0, 4.0]\n' + SKY, "[camera].eye"),
    "target inf": ('[camera]\ntarget = [0.0, inf, 0.0]\n' + SKY, "[camera].target"),
    "target equals eye": ('[camera]\neye = [1.0, 1.0, 1.0]\ntarget = [1.0, 1.0, 1.0]\n' + SKY, "[camera].target"),
    "up parallel": ('[camera]\neye = [0.0, 5.0, 0.0]\ntarget = [0.0, 0.0, 0.0]\n' + SKY, "[camera].up"),
    "fov zero": ('[camera]\nfov_y = 0.0\n' + SKY, "[camera].fov_y"),
    "fov 180": ('[camera]\nfov_y = 180.0\n' + SKY, "[camera].fov_y"),
    "fov string": ('[camera]\nfov_y = "wide"\n' + SKY, "[camera].fov_y"),
    "no environment": ('[render]\nspp = 1\n', "[environment].file"),
    "environment file missing": ('[environment]\nfile = "nope.exr"\n', "[environment].file"),
    "environment file not a string": ('[environment]\nfile = 3\n', "[environment].file"),
    "environment file and procedural": ('[environment]\nfile = "a.exr"\nprocedural = "sky"\n', "[environment].procedural"),
    "environment unknown key": (SKY + 'rotate = 30.0\n', "[environment].rotate"),
    "environment scale negative": (SKY + 'scale = -1.0\n', "[environment].scale"),
    "environment scale string": (SKY + 'scale = "1"\n', "[environment].scale"),
    "environment rotate_y nan": (SKY + 'rotate_y = nan\n', "[environment].rotate_y"),
    "procedural unknown": ('[environment]\nprocedural = "clouds"\n', "[environment].procedural"),
    "sun_radius zero": (SKY + 'sun_radius = 0.0\n', "[environment].sun_radius"),
    "sun_radius past 90": (SKY + 'sun_radius = 120.0\n', "[environment].sun_radius"),
    "sun_elevation past 90": (SKY + 'sun_elevation = 500.0\n', "[environment].sun_elevation"),
    "sun_radiance past 1e30": (SKY + 'sun_radiance = 1e31\n', "[environment].sun_radiance"),
    "sun_radiance negative": (SKY + 'sun_radiance = -5.0\n', "[environment].sun_radiance"),
    "sun_elevation string": (SKY + 'sun_elevation = "high"\n', "[environment].sun_elevation"),
    "objects not an array": ('objects = 3\n' + SKY, "objects"),
    "object not a table": ('objects = [1, 2]\n' + SKY, "[[objects]][0]"),
    "object unknown key": (SKY + '[[objects]]\nshape = "sphere"\ncolour = "red"\n', "[[objects]][0].colour"),
    "object without shape or mesh": (SKY + '[[objects]]\ntranslate = [0.0, 0.0, 0.0]\n', "[[objects]][0].shape"),
    "mesh and shape": (SKY + '[[objects]]\nmesh = "m.obj"\nshape = "sphere"\n', "[[objects]][0].shape"),
    "mesh missing": (SKY + '[[objects]]\nmesh = "missing.obj"\n', "[[objects]][0].mesh"),
    "mesh not a string": (SKY + '[[objects]]\nmesh = 7\n', "[[objects]][0].mesh"),
    "shape unknown": (SKY + '[[objects]]\nshape = "cube"\n', "[[objects]][0].shape"),
    "radius zero": (SKY + '[[objects]]\nshape = "sphere"\nradius = 0.0\n', "[[objects]][0].radius"),
    "radius negative": (SKY + '[[objects]]\nshape = "sphere"\nradius = -1.0\n', "[[objects]][0].radius"),
    "radius string": (SKY + '[[objects]]\nshape = "sphere"\nradius = "big"\n', "[[objects]][0].radius"),
    "subdivisions too many": (SKY + '[[objects]]\nshape = "sphere"\nsubdivisions = 12\n', "[[objects]][0].subdivisions"),
    "subdivisions float": (SKY + '[[objects]]\nshape = "sphere"\nsubdivisions = 2.5\n', "[[objects]][0].subdivisions"),
    "center wrong length": (SKY + '[[objects]]\nshape = "sphere"\ncenter = [0.0, 1.0]\n', "[[objects]][0].center"),
    "quad normal zero": (SKY + '[[objects]]\nshape = "quad"\nnormal = [0.0, 0.0, 0.0]\n', "[[objects]][0].normal"),
    "quad size zero": (SKY + '[[objects]]\nshape = "quad"\nsize = 0.0\n', "[[objects]][0].size"),
    "quad size negative": (SKY + '[[objects]]\nshape = "quad"\nsize = [1.0, -2.0]\n', "[[objects]][0].size"),
    "quad size three": (SKY + '[[objects]]\nshape = "quad"\nsize = [1.0, 2.0, 3.0]\n', "[[objects]][0].size"),
    "translate two": (SKY + '[[objects]]\nshape = "quad"\ntranslate = [1.0, 2.0]\n', "[[objects]][0].translate"),
    "translate inf": (SKY + '[[objects]]\nshape = "quad"\ntranslate = [inf, 0.0, 0.0]\n', "[[objects]][0].translate"),
    "rotate three": (SKY + '[[objects]]\nshape = "quad"\nrotate = [0.0, 1.0, 30.0]\n', "[[objects]][0].rotate"),
    "rotate zero axis": (SKY + '[[objects]]\nshape = "quad"\nrotate = [0.0, 0.0, 0.0, 30.0]\n', "[[objects]][0].rotate"),
    "rotate string": (SKY + '[[objects]]\nshape = "quad"\nrotate = "y30"\n', "[[objects]][0].rotate"),
    "scale zero": (SKY + '[[objects]]\nshape = "quad"\nscale = 0\n', "[[objects]][0].scale"),
    "scale two": (SKY + '[[objects]]\nshape = "quad"\nscale = [1.0, 2.0]\n', "[[objects]][0].scale"),
    "scale bool": (SKY + '[[objects]]\nshape = "quad"\nscale = true\n', "[[objects]][0].scale"),
    "material unknown": (SKY + '[[objects]]\nshape = "quad"\nmaterial = "gold"\n', "[[objects]][0].material"),
    "material not a string": (SKY + '[[objects]]\nshape = "quad"\nmaterial = 1\n', "[[objects]][0].material"),
    "materials not a table": ('materials = 3\n' + SKY, "materials"),
    "material not a table": (SKY + '[materials]\ngold = 3\n', "[materials.gold]"),
    "material type missing": (SKY + '[materials.gold]\nalbedo = [1.0, 1.0, 1.0]\n', "[materials.gold].type"),
    "material type unknown": (SKY + '[materials.gold]\ntype = "metal"\n', "[materials.gold].type"),
    "albedo negative": (SKY + '[materials.gold]\ntype = "lambert"\nalbedo = [0.5, -0.1, 0.5]\n', "[materials.gold].albedo"),
    "albedo short": (SKY + '[materials.gold]\ntype = "lambert"\nalbedo = [0.5, 0.5]\n', "[materials.gold].albedo"),
    "albedo scalar": (SKY + '[materials.gold]\ntype = "lambert"\nalbedo = 0.5\n', "[materials.gold].albedo"),
    "roughness zero": (SKY + '[materials.gold]\ntype = "ggx"\nroughness = 0.0\n', "[materials.gold].roughness"),
    "roughness above one": (SKY + '[materials.gold]\ntype = "ggx"\nroughness = 2.0\n', "[materials.gold].roughness"),
    "exponent negative": (SKY + '[materials.gold]\ntype = "phong"\nexponent = -1.0\n', "[materials.gold].exponent"),
    "exponent string": (SKY + '[materials.gold]\ntype = "phong"\nexponent = "high"\n', "[materials.gold].exponent"),
    "material unknown key": (SKY + '[materials.gold]\ntype = "lambert"\ncolor = [1.0, 1.0, 1.0]\n', "[materials.gold].color"),
}


def _check_scene_error(err: SceneError, path, key):
    msg = str(err)
    assert isinstance(err, WavlightError)
    assert "\n" not in msg, f"not one line: {msg!r}"
    assert str(path) in msg, f"file not named: {msg!r}"
    if key:
        assert key in msg, f"key {key!r} not named: {msg!r}"
        assert key in err.key or err.key in key
    assert err.path == str(path)


@pytest.mark.parametrize("case", sorted(BAD))
def test_scene_errors_name_file_and_key(tmp_path, case):
    text, key = BAD[case]
    write_obj(tmp_path / "m.obj", TETRA_V, TETRA_F)
    path = write_scene(tmp_path, text)
    with pytest.raises(SceneError) as e:
        wavlight.load_scene(str(path))
    _check_scene_error(e.value, path, key)


def test_malformed_toml(tmp_path):
    path = write_scene(tmp_path, '[render\nspp = 1\n')
    with pytest.raises(SceneError) as e:
        wavlight.load_scene(str(path))
    _check_scene_error(e.value, path, None)
    assert "TOML" in str(e.value) and "line 1" in str(e.value)


def test_duplicate_key_is_malformed(tmp_path):
    path = write_scene(tmp_path, '[render]\nspp = 1\nspp = 2\n' + SKY)
    with pytest.raises(SceneError) as e:
        wavlight.load_scene(str(path))
    _check_scene_error(e.value, path, None)


def test_not_utf8(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_bytes(b'[render]\nstrategy = "\xff\xfe"\n')
    with pytest.raises(SceneError) as e:
        wavlight.load_scene(str(path))
    _check_scene_error(e.value, path, None)


def test_missing_scene_file(tmp_path):
    path = tmp_path / "nope.toml"
    with pytest.raises(SceneError) as e:
        wavlight.load_scene(str(path))
    _check_scene_error(e.value, path, None)


def test_scene_path_is_a_folder(tmp_path):
    with pytest.raises(SceneError) as e:
        wavlight.load_scene(str(tmp_path))
    _check_scene_error(e.value, tmp_path, None)


@pytest.mark.parametrize("content", [b"this is not an image\n" * 4, b"", b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 4"])
def test_unreadable_environment_file(tmp_path, content):
    (tmp_path / "env.hdr").write_bytes(content)
    path = write_scene(tmp_path, '[environment]\nfile = "env.hdr"\n')
    with pytest.raises(SceneError) as e:
        wavlight.load_scene(str(path))
    _check_scene_error(e.value, path, "[environment].file")
    assert "env.hdr" in str(e.value)


def test_environment_file_is_a_folder(tmp_path):
    (tmp_path / "env.exr").mkdir()
    path = write_scene(tmp_path, '[environment]\nfile = "env.exr"\n')
    with pytest.raises(SceneError) as e:
        wavlight.load_scene(str(path))
    _check_scene_error(e.value, path, "[environment].file")


@pytest.mark.parametrize("content", [b"", b"garbage that is not an obj file\x00\x01\x02", b"v 0 0 0\nv 1 0 0\n"])
def test_unreadable_or_empty_mesh(tmp_path, content):
    (tmp_path / "bad.ply").write_bytes(content)
    path = write_scene(tmp_path, SKY + '[[objects]]\nmesh = "bad.ply"\n')
    with pytest.raises(SceneError) as e:
        wavlight.load_scene(str(path))
    _check_scene_error(e.value, path, "[[objects]][0].mesh")


def test_mesh_indices_out_of_range(tmp_path):
    write_ply(tmp_path / "m.ply", TETRA_V, [(0, 1, 9)])
    path = write_scene(tmp_path, SKY + '[[objects]]\nmesh = "m.ply"\n')
    with pytest.raises(SceneError) as e:
        wavlight.load_scene(str(path))
    _check_scene_error(e.value, path, "[[objects]][0]")


def test_errors_name_the_right_object(tmp_path):
    path = write_scene(tmp_path, SKY + '[[objects]]\nshape = "quad"\n[[objects]]\nshape = "sphere"\nradius = -2.0\n')
    with pytest.raises(SceneError) as e:
        wavlight.load_scene(str(path))
    _check_scene_error(e.value, path, "[[objects]][1].radius")


@pytest.mark.parametrize("rotate", ["[0.0, 1.0, 0.0, nan]", "[inf, 0.0, 0.0, 30.0]", "[0.0, 1.0, 0.0, inf]"])
def test_non_finite_rotate_names_the_rotate_key(tmp_path, rotate):
    """A NaN/Inf in `rotate` must be reported against [[objects]][0].rotate (like translate, scale)."""
    path = write_scene(tmp_path, SKY + f'[[objects]]\nshape = "quad"\nrotate = {rotate}\n')
    with pytest.raises(SceneError) as e:
        wavlight.load_scene(str(path))
    _check_scene_error(e.value, path, "[[objects]][0].rotate")


# ----------------------------------------------------------------------------- degenerate triangles
GOOD_AND_DEGENERATE = (
    [(0, 0, 0), (1, 0, 0), (0, 1, 0), (2, 0, 0), (3, 0, 0), (0, 0, 1)],
    [(0, 1, 2), (1, 3, 4),  # collinear: zero area
     (0, 2, 5), (5, 5, 1)],  # repeated vertex: zero area
)


@pytest.mark.parametrize("fmt", ["obj", "ply"])
def test_degenerate_triangles_removed_with_warning(tmp_path, fmt):
    v, f = GOOD_AND_DEGENERATE
    (write_obj if fmt == "obj" else write_ply)(tmp_path / f"m.{fmt}", v, f)
    path = write_scene(tmp_path, SKY + f'[[objects]]\nmesh = "m.{fmt}"\n')
    with pytest.warns(UserWarning) as rec:
        s = wavlight.load_scene(str(path))
    msgs = [str(w.message) for w in rec if "degenerate" in str(w.message)]
    assert len(msgs) == 1, [str(w.message) for w in rec]
    assert str(path) in msgs[0] and "[[objects]][0]" in msgs[0] and "2 degenerate" in msgs[0]
    assert "\n" not in msgs[0]
    assert len(s.faces) == 2
    _, area = face_normals(s)
    assert np.all(area > 0.1)


def test_mesh_of_only_degenerate_triangles_is_an_error(tmp_path):
    write_ply(tmp_path / "flat.ply", [(0, 0, 0), (1, 1, 1), (2, 2, 2), (3, 3, 3)], [(0, 1, 2), (1, 2, 3), (0, 0, 3)])
    path = write_scene(tmp_path, SKY + '[[objects]]\nshape = "quad"\n[[objects]]\nmesh = "flat.ply"\n')
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(SceneError) as e:
            wavlight.load_scene(str(path))
    _check_scene_error(e.value, path, "[[objects]][1]")
    assert "degenerate" in str(e.value)


def test_tiny_but_valid_triangles_are_kept(tmp_path):
    """A small object far from others is not 'degenerate': the test is relative to its own size."""
    v = np.array(TETRA_V) * 1e-4 + [1e3, 0, 0]
    write_obj(tmp_path / "m.obj", v, TETRA_F)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        s = load(tmp_path, SKY + '[[objects]]\nmesh = "m.obj"\n')
    assert len(s.faces) == 4


def test_clean_mesh_gives_no_warning(tmp_path):
    write_obj(tmp_path / "m.obj", TETRA_V, TETRA_F)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        s = load(tmp_path, SKY + '[[objects]]\nmesh = "m.obj"\n[[objects]]\nshape = "sphere"\n')
    assert len(s.faces) == 4 + 20 * 4 ** 5


# ----------------------------------------------------------------------------- bad texels
@pytest.mark.parametrize("ext", ["exr"])
def test_nan_inf_negative_texels_set_to_zero_with_warning(tmp_path, ext):
    px = np.random.default_rng(3).uniform(0.5, 2.0, (8, 16, 3)).astype(np.float32)
    bad = {(1, 2, 0): np.nan, (3, 4, 1): np.inf, (3, 5, 2): -np.inf, (5, 6, 2): -0.25, (7, 15, 0): np.nan}
    for (r, c, ch), val in bad.items():
        px[r, c, ch] = val
    write_env(tmp_path / f"env.{ext}", px)
    path = write_scene(tmp_path, f'[environment]\nfile = "env.{ext}"\nscale = 3.0\n')
    with pytest.warns(UserWarning) as rec:
        s = wavlight.load_scene(str(path))
    msgs = [str(w.message) for w in rec]
    assert len(msgs) == 1, msgs
    assert f"env.{ext}" in msgs[0] and "5 texel" in msgs[0] and "\n" not in msgs[0]
    out = s.environment.pixels
    assert np.all(np.isfinite(out)) and out.min() >= 0
    for (r, c, ch) in bad:
        assert out[r, c, ch] == 0
    good = np.ones(px.shape[:2], bool)
    for (r, c, _) in bad:
        good[r, c] = False
    np.testing.assert_allclose(out[good], px[good] * 3.0, rtol=1e-6)
    # looking straight at a NaN texel gives a finite, non-negative radiance
    d = _dir(1, 2, 8, 16)
    assert np.all(np.isfinite(s.environment.eval(d[None]))) and s.environment.eval(d[None]).min() >= 0


def test_clean_environment_gives_no_warning(tmp_path):
    write_env(tmp_path / "env.exr", np.full((4, 8, 3), 0.5))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load(tmp_path, '[environment]\nfile = "env.exr"\n')


def test_environment_scale_overflow_never_gives_inf(tmp_path):
    """Finite texels times a finite scale can overflow float32: the radiance must stay finite
    (or the scene be refused with an error naming [environment].scale), never Inf."""
    px = np.full((4, 8, 3), 1.0, np.float32)
    px[0, 0] = 1e38
    write_env(tmp_path / "env.exr", px)
    path = write_scene(tmp_path, '[environment]\nfile = "env.exr"\nscale = 100.0\n')
    try:
        s = wavlight.load_scene(str(path))
    except SceneError as e:
        _check_scene_error(e, path, "[environment].scale")
    else:
        assert np.all(np.isfinite(s.environment.pixels))


@pytest.mark.parametrize("value, scale, key", [(1e33, 1.0, "[environment].file"), (1e28, 1e4, "[environment].scale")])
def test_environment_radiance_above_the_limit_is_refused(tmp_path, value, scale, key):
    """Radiance above envmap.MAX_RADIANCE (1e30) would overflow the float32 estimates: a one-line
    error naming the file or the scale that took it there."""
    px = np.full((4, 8, 3), 1.0, np.float32)
    px[1, 2] = value
    write_env(tmp_path / "env.exr", px)
    path = write_scene(tmp_path, f'[environment]\nfile = "env.exr"\nscale = {scale}\n')
    with pytest.raises(SceneError) as e:
        wavlight.load_scene(str(path))
    _check_scene_error(e.value, path, key)
    assert "1e+30" in str(e.value)


def test_single_channel_environment_is_grey(tmp_path):
    import OpenImageIO as oiio

    p = str(tmp_path / "g.exr")
    out = oiio.ImageOutput.create(p)
    out.open(p, oiio.ImageSpec(8, 4, 1, oiio.FLOAT))
    out.write_image(np.full((4, 8, 1), 0.7, np.float32))
    out.close()
    s = load(tmp_path, '[environment]\nfile = "g.exr"\n')
    np.testing.assert_allclose(s.environment.pixels, 0.7, rtol=1e-6)
    assert s.environment.pixels.shape == (4, 8, 3)


@pytest.mark.parametrize("radius", [0.05, 0.27, 0.75, 3.0])
def test_procedural_sun_keeps_its_power_at_any_radius(radius):
    """The sun disk's power, radiance x 2 pi (1 - cos r), within 0.1% whatever its size against
    the texels (a 0.1 degree sun once vanished, one of 0.25 covered twice its solid angle)."""
    from wavlight.envmap import procedural_sky

    black = dict(zenith=(0.0, 0.0, 0.0), horizon=(0.0, 0.0, 0.0), ground=(0.0, 0.0, 0.0))
    px = procedural_sky(sun_radius=radius, sun_radiance=1.0, width=256, height=128, **black)[..., 0]
    theta = (np.arange(128) + 0.5) / 128 * np.pi
    omega = (2 * np.pi / 256) * (np.cos(theta - np.pi / 256) - np.cos(theta + np.pi / 256))
    power = float((px * omega[:, None]).sum())
    assert power == pytest.approx(2 * np.pi * (1 - math.cos(math.radians(radius))), rel=1e-3)


def test_ldr_environment_is_decoded_from_srgb_with_a_warning(tmp_path):
    """An 8-bit PNG holds sRGB-encoded values: read as linear radiance after decoding, with a
    warning that a light probe should be HDR."""
    import OpenImageIO as oiio

    px = np.zeros((4, 8, 3), np.uint8)
    px[..., 0], px[..., 1], px[..., 2] = 255, 128, 10
    out = oiio.ImageOutput.create(str(tmp_path / "env.png"))
    out.open(str(tmp_path / "env.png"), oiio.ImageSpec(8, 4, 3, oiio.UINT8))
    out.write_image(px)
    out.close()
    path = write_scene(tmp_path, '[environment]\nfile = "env.png"\n')
    with pytest.warns(UserWarning, match="low-dynamic-range"):
        s = wavlight.load_scene(str(path))
    srgb = np.array([255, 128, 10]) / 255.0
    linear = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    np.testing.assert_allclose(s.environment.pixels[0, 0], linear, rtol=1e-5)


def test_albedo_above_one_warns(tmp_path):
    with pytest.warns(UserWarning, match=r"\[materials.m\].albedo: above 1"):
        load(tmp_path, SKY + '[materials.m]\ntype = "lambert"\nalbedo = [1.2, 0.5, 0.5]\n'
             '[[objects]]\nshape = "quad"\nmaterial = "m"\n')


@pytest.mark.parametrize("text, key", [
    ('[[objects]]\nshape = "quad"\ncenter = [0.0, 0.0, 0.0]\nnormal = [0.0, 0.0, 1.0]\nsize = 4e18\n',
     "[[objects]][0]"),
    ('[[objects]]\nshape = "sphere"\ncenter = [0.0, 0.0, 0.0]\nradius = 1e20\n', "[[objects]][0]"),
    ('[[objects]]\nshape = "sphere"\ncenter = [0.0, 0.0, 0.0]\nradius = 1.0\nscale = 1e30\n', "[[objects]][0]"),
    ('[camera]\neye = [0.0, 1.0, 4e19]\n', "[camera].eye"),
    ('[camera]\ntarget = [-2e18, 0.0, 0.0]\n', "[camera].target")])
def test_coordinates_beyond_the_ray_tracers_range_are_refused(tmp_path, text, key):
    """embree ignores geometry beyond about +-1.8e18: such a quad, sphere or scaled object would
    vanish from the image without a word (found by probing: exit 0, the image as if the
    object were not there). Beyond scene.MAX_COORDINATE the scene is refused in one line naming
    the object or camera key; up to it, it loads."""
    from wavlight.scene import MAX_COORDINATE

    path = write_scene(tmp_path, SKY + text)
    with pytest.raises(SceneError) as e:
        wavlight.load_scene(str(path))
    _check_scene_error(e.value, path, key)
    assert f"{MAX_COORDINATE:g}" in str(e.value)
    s = load(tmp_path / "ok", SKY + '[[objects]]\nshape = "quad"\ncenter = [0.0, 0.0, 0.0]\n'
                              'normal = [0.0, 0.0, 1.0]\nsize = 1e18\n')
    assert np.abs(s.vertices).max() <= MAX_COORDINATE


def test_check_scene_refuses_edited_coordinates_beyond_range(tmp_path):
    """A Scene edited in Python past load_scene's checks is checked again at render time."""
    s = load(tmp_path, SKY + '[[objects]]\nshape = "quad"\ncenter = [0.0, 0.0, 0.0]\nnormal = [0.0, 0.0, 1.0]\n'
                            'size = 2.0\n')
    s.vertices = s.vertices * np.float32(1e19)
    with pytest.raises(WavlightError, match="ray tracer's range"):
        wavlight.render(s, spp=1, width=4, height=4)
