"""wavlight/meshes.py: the PLY reader against trimesh, its fallback, and the icosphere."""
import numpy as np
import pytest
import trimesh

from wavlight import data, meshes
from wavlight.errors import SceneError
from wavlight.scene import load_scene


@pytest.mark.parametrize("encoding", ["ascii", "binary"])
def test_read_ply_matches_trimesh_on_a_real_mesh(tmp_path, encoding):
    """The shipped Spot (wavlight.data, 5856 triangles) written as a PLY by trimesh's own
    exporter, ASCII and binary, with per-vertex normals: read_ply gives trimesh's vertices and
    faces exactly."""
    v, f = meshes.read_obj(str(data.path("spot")))
    path = tmp_path / f"spot-{encoding}.ply"
    mesh = trimesh.Trimesh(v, f, process=False)
    mesh.vertex_normals   # computed, so that the file carries nx ny nz beside x y z
    path.write_bytes(mesh.export(file_type="ply", encoding=encoding))
    got = meshes.read_ply(str(path))
    ref = trimesh.load(str(path), force="mesh", process=False)
    assert got is not None and len(got[1]) == 5856
    np.testing.assert_allclose(got[0], ref.vertices, rtol=0, atol=0)
    np.testing.assert_array_equal(got[1], ref.faces)


def _write_ply(path, fmt, vertices, faces, vextra=0, fextra=0):
    """A PLY with x y z plus `vextra` float properties per vertex and a `fextra` int property per face."""
    head = ["ply", f"format {fmt} 1.0", "comment test", f"element vertex {len(vertices)}",
            "property float x", "property float y", "property float z"]
    head += [f"property float extra{k}" for k in range(vextra)]
    head += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
    head += [f"property int flag{k}" for k in range(fextra)]
    head += ["end_header"]
    vrows = np.hstack([vertices, np.full((len(vertices), vextra), 0.25)]).astype(np.float32)
    with open(path, "wb") as fh:
        fh.write(("\n".join(head) + "\n").encode())
        if fmt == "ascii":
            for r in vrows:
                fh.write((" ".join(f"{x:.9g}" for x in r) + "\n").encode())
            for f in faces:
                fh.write((" ".join(str(x) for x in [len(f), *f, *([7] * fextra)]) + "\n").encode())
        else:
            e = "<" if fmt == "binary_little_endian" else ">"
            fh.write(vrows.astype(e + "f4").tobytes())
            for f in faces:
                fh.write(np.array([len(f)], np.uint8).tobytes())
                fh.write(np.array([*f, *([7] * fextra)], e + "i4").tobytes())


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
@pytest.mark.parametrize("extra", [(0, 0), (2, 1)])
def test_read_ply_formats_and_extra_properties(tmp_path, fmt, extra):
    rng = np.random.default_rng(3)
    v = rng.random((9, 3)).astype(np.float32)
    f = rng.integers(0, 9, (7, 3))
    path = tmp_path / "m.ply"
    _write_ply(path, fmt, v, f, *extra)
    got = meshes.read_ply(str(path))
    assert got is not None
    np.testing.assert_array_equal(got[0], v.astype(np.float64))
    np.testing.assert_array_equal(got[1], f)


@pytest.mark.parametrize("fmt, faces", [("ascii", [[0, 1, 2, 3], [0, 1, 4]]),
                                         ("binary_little_endian", [[0, 1, 2, 3], [0, 1, 4, 3]])])
def test_polygons_fall_back_to_trimesh(tmp_path, fmt, faces):
    """Quads are outside the reader's subset: read_ply says so, and load_scene's trimesh
    path triangulates them (trimesh reads binary lists of one length only)."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1]], np.float32)
    path = tmp_path / "quad.ply"
    _write_ply(path, fmt, v, faces)
    assert meshes.read_ply(str(path)) is None
    (tmp_path / "s.toml").write_text(
        '[render]\nwidth = 8\nheight = 8\n[camera]\neye = [0, 0, 5]\ntarget = [0, 0, 0]\n'
        '[environment]\nprocedural = "sky"\n[[objects]]\nmesh = "quad.ply"\nmaterial = "m"\n'
        '[materials.m]\ntype = "lambert"\nalbedo = [0.5, 0.5, 0.5]\n')
    triangles = sum(len(f) - 2 for f in faces)
    assert len(load_scene(str(tmp_path / "s.toml")).faces) == triangles


def test_malformed_ply_is_a_scene_error(tmp_path):
    (tmp_path / "bad.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex three\nend_header\n1 2 3\n")
    (tmp_path / "s.toml").write_text(
        '[render]\nwidth = 8\nheight = 8\n[camera]\neye = [0, 0, 5]\ntarget = [0, 0, 0]\n'
        '[environment]\nprocedural = "sky"\n[[objects]]\nmesh = "bad.ply"\nmaterial = "m"\n'
        '[materials.m]\ntype = "lambert"\nalbedo = [0.5, 0.5, 0.5]\n')
    with pytest.raises(SceneError, match="mesh"):
        load_scene(str(tmp_path / "s.toml"))


SCENE_WITH_MESH = ('[render]\nwidth = 8\nheight = 8\n[camera]\neye = [0, 0, 5]\ntarget = [0, 0, 0]\n'
                   '[environment]\nprocedural = "sky"\n[[objects]]\nmesh = "{mesh}"\nmaterial = "m"\n'
                   '[materials.m]\ntype = "lambert"\nalbedo = [0.5, 0.5, 0.5]\n')


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian"])
def test_truncated_ply_is_a_scene_error(tmp_path, fmt):
    """A header that declares more faces than the file holds: an error naming the truncation,
    not a mesh with fewer triangles (trimesh read such files without a word)."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
    _write_ply(tmp_path / "full.ply", fmt, v, [[0, 1, 2], [0, 2, 3]])
    data = (tmp_path / "full.ply").read_bytes()
    cut = data[:data.rindex(b"\n", 0, len(data) - 1) + 1] if fmt == "ascii" else data[:-13]
    (tmp_path / "cut.ply").write_bytes(cut)
    (tmp_path / "s.toml").write_text(SCENE_WITH_MESH.format(mesh="cut.ply"))
    with pytest.raises(SceneError, match="truncated"):
        load_scene(str(tmp_path / "s.toml"))


def test_obj_with_bytes_that_are_not_utf8_loads(tmp_path):
    """A Latin-1 comment in an OBJ file (trimesh alone needs charset_normalizer for it)."""
    (tmp_path / "m.obj").write_bytes(b"# caf\xe9 cr\xe8me\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (tmp_path / "s.toml").write_text(SCENE_WITH_MESH.format(mesh="m.obj"))
    assert len(load_scene(str(tmp_path / "s.toml")).faces) == 1


def test_obj_with_a_nan_vertex_is_a_scene_error(tmp_path):
    """As for PLY: trimesh's processing dropped the face without a warning."""
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv nan 1 0\nf 1 2 3\nf 1 2 4\n")
    (tmp_path / "s.toml").write_text(SCENE_WITH_MESH.format(mesh="m.obj"))
    with pytest.raises(SceneError, match="NaN"):
        load_scene(str(tmp_path / "s.toml"))


@pytest.mark.parametrize("sub", [0, 1, 3, 5])
def test_icosphere_is_trimesh_icosphere(sub):
    """The same sphere as trimesh.creation.icosphere: vertex set, face count, area; closed,
    consistently wound, outward-facing."""
    v, f = meshes.icosphere(sub, 2.5)
    ref = trimesh.creation.icosphere(subdivisions=sub, radius=2.5)
    assert v.shape == ref.vertices.shape and f.shape == ref.faces.shape
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 2.5, rtol=1e-12)
    key = lambda a: a[np.lexsort(np.round(a, 9).T)]   # noqa: E731
    np.testing.assert_allclose(key(v), key(np.asarray(ref.vertices)), atol=1e-9)
    mesh = trimesh.Trimesh(v, f, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    np.testing.assert_allclose(mesh.area, ref.area, rtol=1e-12)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert np.all(np.einsum("ij,ij->i", n, v[f].mean(axis=1)) > 0)
