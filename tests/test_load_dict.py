"""wavlight.load_dict: a scene from a Python dict with exactly the TOML file's structure, with the
same validation and errors as wavlight.load_scene; and the scene's content hash."""
from __future__ import annotations

import numpy as np
import pytest

import wavlight
from scenes_util import toml_text, write_raw_image
from wavlight import SceneError


def _dict(**render):
    return {"render": {"width": 16, "height": 12, "spp": 2, **render},
            "camera": {"eye": [0.0, 1.0, 4.0], "target": [0.0, 0.5, 0.0], "fov_y": 40.0},
            "environment": {"file": "env.exr", "rotate_y": 30.0},
            "objects": [{"shape": "sphere", "center": [0.0, 0.5, 0.0], "radius": 0.5, "material": "gold"},
                        {"mesh": "tri.obj", "translate": [0.0, -0.1, 0.0], "scale": 2.0},
                        {"shape": "quad", "normal": [0.0, 1.0, 0.0], "size": [4.0, 3.0], "material": "floor"}],
            "materials": {"gold": {"type": "ggx", "albedo": [1.0, 0.78, 0.34], "roughness": 0.15},
                          "floor": {"type": "lambert", "albedo": [0.6, 0.6, 0.6]}}}


@pytest.fixture
def folder(tmp_path):
    write_raw_image(tmp_path / "env.exr", np.linspace(0.1, 2.0, 8 * 16 * 3, dtype=np.float32).reshape(8, 16, 3))
    (tmp_path / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 0 1\nf 1 2 3\n")
    return tmp_path


def test_a_dict_gives_the_scene_its_toml_file_gives(folder):
    d = _dict(strategy="wavelet", wavelet_candidates=8, sampler="stratified")
    (folder / "scene.toml").write_text(toml_text(d))
    a = wavlight.load_scene(folder / "scene.toml")
    b = wavlight.load_dict(d, base_dir=folder)
    assert b.path == "<dict>"
    for key in ("width", "height", "spp", "strategy", "seed", "options", "content_hash"):
        assert getattr(a, key) == getattr(b, key), key
    for key in ("vertices", "faces", "face_material"):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key))
    np.testing.assert_array_equal(a.environment.pixels, b.environment.pixels)
    assert [m.name for m in a.materials] == [m.name for m in b.materials]
    assert b.options == {"wavelet_candidates": 8, "sampler": "stratified"}
    # and it renders as the file does
    np.testing.assert_array_equal(wavlight.render(a, spp=2, width=8, height=6),
                                  wavlight.render(b, spp=2, width=8, height=6))


def test_relative_paths_resolve_against_base_dir_or_the_current_folder(folder, monkeypatch):
    with pytest.raises(SceneError, match=r"<dict>: \[environment\]\.file: .*env\.exr"):
        wavlight.load_dict(_dict(), base_dir=folder / "..")
    monkeypatch.chdir(folder)
    assert wavlight.load_dict(_dict()).environment.width == 16
    with pytest.raises(SceneError, match="base_dir must be an existing folder"):
        wavlight.load_dict(_dict(), base_dir=folder / "nowhere")


def test_python_types_stand_for_toml_types(folder):
    d = _dict(width=np.int64(16))
    d["camera"]["eye"] = np.array([0.0, 1.0, 4.0])
    d["camera"]["target"] = (0.0, np.float32(0.5), 0)
    d["environment"]["file"] = folder / "env.exr"
    scene = wavlight.load_dict(d, base_dir=folder)
    assert scene.width == 16 and scene.camera.target.tolist() == [0.0, 0.5, 0.0]


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["render"].update(spp=0), r"<dict>: \[render\]\.spp: must be at least 1, got 0"),
    (lambda d: d["render"].update(colour="red"), r"<dict>: \[render\]\.colour: unknown key"),
    (lambda d: d["render"].update(wavelet_candidates=1), r"<dict>: \[render\]\.wavelet_candidates: must be 0 \| 2\.\.64"),
    (lambda d: d["render"].update(wavelet_slots=4, wavelet_candidates=0),
     r"<dict>: \[render\]\.wavelet_slots: 4 needs the resampling estimator"),
    (lambda d: d["render"].update(width=None), r"<dict>: render\.width: must be a TOML value"),
    (lambda d: d["render"].update(width=object()), r"<dict>: render\.width: must be a TOML value .* got object"),
    (lambda d: d.update(lights={}), r"<dict>: lights: unknown table"),
    (lambda d: d["objects"][0].update(material="steel"), r"<dict>: \[\[objects\]\]\[0\]\.material: unknown material"),
    (lambda d: d["camera"].update(eye=np.zeros(10 ** 6)), r"<dict>: camera\.eye: must be a short list"),
    (lambda d: d["camera"].update(eye=[1.0, 2.0]), r"<dict>: \[camera\]\.eye: must be a list of 3 finite numbers"),
    (lambda d: d.update({1: 2}), r"<dict>: keys must be strings"),
])
def test_errors_name_the_dict_and_the_key(folder, edit, message):
    d = _dict()
    edit(d)
    with pytest.raises(SceneError, match=message):
        wavlight.load_dict(d, base_dir=folder)


def test_a_non_dict_is_refused():
    for bad in ([1, 2], "scene.toml", None):
        with pytest.raises(SceneError, match="must be a table of tables|must be a TOML value"):
            wavlight.load_dict(bad)


def test_deep_nesting_is_refused_in_one_line(tmp_path):
    """A TOML file with values nested 1 000 deep (2.5 KB) and a dict nested as deep: a SceneError,
    not a RecursionError."""
    path = tmp_path / "deep.toml"
    path.write_text("[render]\nwidth = " + "[" * 1000 + "]" * 1000 + "\n")
    with pytest.raises(SceneError, match="nested too deeply"):
        wavlight.load_scene(path)
    deep = []
    for _ in range(1000):
        deep = [deep]
    with pytest.raises(SceneError, match="nested too deeply"):
        wavlight.load_dict({"render": {"width": deep}})


def test_the_content_hash_follows_settings_and_files(folder):
    base = wavlight.load_dict(_dict(), base_dir=folder).content_hash
    assert len(base) == 64
    assert wavlight.load_dict(_dict(), base_dir=folder).content_hash == base
    assert wavlight.load_dict(_dict(spp=3), base_dir=folder).content_hash != base
    (folder / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 0 2\nf 1 2 3\n")   # a mesh it reads
    changed = wavlight.load_dict(_dict(), base_dir=folder).content_hash
    assert changed != base
    write_raw_image(folder / "env.exr", np.ones((8, 16, 3), np.float32))     # the map it reads
    assert wavlight.load_dict(_dict(), base_dir=folder).content_hash not in (base, changed)


# ----------------------------------------------------------------------------- arrays instead of files
def _caught(fn):
    """(result, [warning messages]) of fn()."""
    import warnings

    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        result = fn()
    return result, [str(w.message) for w in seen]


def _error(d, **kw):
    with pytest.raises(SceneError) as e:
        _caught(lambda: wavlight.load_dict(d, **kw))
    assert "\n" not in str(e.value)
    return str(e.value)


def _without(text, prefix):
    assert text.startswith(prefix), (text, prefix)
    return text[len(prefix):]


def test_a_map_given_as_pixels_is_the_map_of_its_file(folder):
    """pixels (H, W, 3) make the scene the file of the same float32 pixels makes: the same
    environment, the same sanitising and warning (naming the key instead of the file)."""
    rng = np.random.default_rng(0)
    pixels = rng.uniform(0.0, 3.0, (8, 16, 3)).astype(np.float32)
    pixels[1, 2] = [np.nan, 1.0, -2.0]
    pixels[3, 4, 1] = np.inf
    write_raw_image(folder / "bad.exr", pixels)
    d = _dict()
    filed, file_warnings = _caught(lambda: wavlight.load_dict({**d, "environment": {"file": "bad.exr", "scale": 2.0}},
                                                              base_dir=folder))
    given, given_warnings = _caught(lambda: wavlight.load_dict({**d, "environment": {"pixels": pixels, "scale": 2.0}},
                                                               base_dir=folder))
    np.testing.assert_array_equal(given.environment.pixels, filed.environment.pixels)
    assert len(file_warnings) == len(given_warnings) == 1
    assert _without(given_warnings[0], "<dict>: [environment].pixels: ") == \
        _without(file_warnings[0], f"{folder / 'bad.exr'}: ")
    assert given.files == [str(folder / "tri.obj")]   # the map is no file
    # other numbers and nested lists stand for the same pixels
    as_lists, _ = _caught(lambda: wavlight.load_dict(
        {**d, "environment": {"pixels": np.nan_to_num(pixels, posinf=0.0).tolist()}}, base_dir=folder))
    assert as_lists.environment.pixels.dtype == np.float32


@pytest.mark.parametrize("pixels, words", [
    (np.zeros((4, 4)), "(H, W, 3) array of numbers, got shape (4, 4)"),
    (np.zeros((4, 4, 4)), "got shape (4, 4, 4)"),
    (np.zeros((0, 4, 3)), "got shape (0, 4, 3)"),
    ("sky.exr", "(H, W, 3) array of numbers, got 'sky.exr'"),
    (np.array([["a", "b", "c"]] * 2).reshape(1, 2, 3), "array of numbers"),
    (np.ones((2, 2, 3), bool), "array of numbers"),
])
def test_bad_pixels_are_one_line(folder, pixels, words):
    msg = _error({**_dict(), "environment": {"pixels": pixels}}, base_dir=folder)
    assert msg.startswith("<dict>: [environment].pixels: ") and words in msg


def test_an_absurd_map_is_refused_with_the_files_words_before_it_is_read(folder):
    from wavlight.envmap import MAX_TEXELS

    huge = np.broadcast_to(np.float32(1.0), (1 << 13, (MAX_TEXELS >> 13) + 1, 3))   # no memory
    msg = _error({**_dict(), "environment": {"pixels": huge}}, base_dir=folder)
    assert f"image of {huge.shape[1]}x{huge.shape[0]} texels is too large (at most {MAX_TEXELS} texels" in msg
    assert "give either pixels or file" in _error({**_dict(), "environment": {"pixels": np.ones((2, 2, 3)),
                                                                              "file": "env.exr"}}, base_dir=folder)
    assert "given to wavlight.load_dict only" in _toml_error(folder, '[environment]\npixels = [[[1.0, 1.0, 1.0]]]\n')


def _toml_error(folder, text):
    (folder / "s.toml").write_text(text)
    with pytest.raises(SceneError) as e:
        wavlight.load_scene(folder / "s.toml")
    return str(e.value)


def _box():
    """A unit cube's 8 vertices and 12 triangles, and one degenerate triangle more."""
    import trimesh

    box = trimesh.creation.box()
    return np.asarray(box.vertices), np.vstack([box.faces, [[0, 0, 1]]])


def test_a_mesh_given_as_arrays_or_trimesh_is_the_mesh_of_its_file(folder):
    """vertices and faces, a trimesh.Trimesh, and the OBJ file of the same mesh make the same
    geometry, with the same degenerate-triangle warning."""
    import trimesh

    from test_scene import write_obj

    v, f = _box()
    write_obj(folder / "box.obj", v, f)
    d = _dict()

    def scene(obj):
        return _caught(lambda: wavlight.load_dict({**d, "objects": [{**obj, "translate": [0.0, 0.5, 0.0]}]},
                                                  base_dir=folder))
    filed, fw = scene({"mesh": "box.obj"})
    given, gw = scene({"vertices": v, "faces": f})
    mesh = trimesh.Trimesh(v, f, process=False)
    tm, tw = scene({"mesh": mesh})
    for other in (given, tm):
        for key in ("vertices", "faces", "face_material"):
            np.testing.assert_array_equal(getattr(other, key), getattr(filed, key))
    assert len(filed.faces) == 12 and len(fw) == len(gw) == len(tw) == 1
    assert _without(gw[0], "<dict>: [[objects]][0]: ") == _without(fw[0], "<dict>: [[objects]][0]: ")
    assert tw == gw and given.content_hash != filed.content_hash
    assert scene({"mesh": trimesh.Trimesh(v.copy(), f.copy(), process=False)})[0].content_hash == tm.content_hash


@pytest.mark.parametrize("obj, key, words", [
    ({"vertices": np.zeros((3, 3))}, "faces", "is required"),
    ({"faces": [[0, 1, 2]]}, "vertices", "is required"),
    ({"vertices": np.zeros((3, 2)), "faces": [[0, 1, 2]]}, "vertices", "(V, 3) array of numbers, got shape (3, 2)"),
    ({"vertices": np.eye(3), "faces": [[0, 1]]}, "faces", "(F, 3) array of vertex indices, got shape (1, 2)"),
    ({"vertices": np.eye(3), "faces": np.zeros((0, 3), int)}, "faces", "holds no triangles"),
    ({"vertices": np.eye(3), "faces": [[0, 1, 3]]}, "faces",
     "face 0: vertex index 3 is outside 0..2 (the vertices array holds 3 vertices)"),
    ({"vertices": np.eye(3), "faces": [[0, 1.5, 2]]}, "faces", "face 0: vertex index 1.5 is not an integer"),
    ({"vertices": np.eye(3), "faces": [[0, 1, 2]], "shape": "quad"}, "shape", "not both"),
    ({"vertices": np.eye(3), "faces": [[0, 1, 2]], "mesh": "tri.obj"}, "mesh", "not both"),
    ({"mesh": 42}, "mesh", "a mesh with vertices and faces (a trimesh.Trimesh), got int"),
    ({"vertices": "v.npy", "faces": [[0, 1, 2]]}, "vertices", "array of vertex coordinates, got 'v.npy'"),
])
def test_bad_mesh_arrays_are_one_line(folder, obj, key, words):
    msg = _error({**_dict(), "objects": [obj]}, base_dir=folder)
    assert msg.startswith(f"<dict>: [[objects]][0].{key}: ") and words in msg, msg


def test_mesh_arrays_take_the_files_checks(folder):
    """NaN vertices, coordinates beyond the ray tracer's range and all-degenerate meshes get a
    mesh file's words; too many triangles are refused from the shape alone."""
    from test_scene import write_obj

    from wavlight.scene import MAX_COORDINATE, MAX_TRIANGLES

    tri = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    for vertices, words in ((np.where(np.eye(3) > 0, np.nan, tri), "vertices hold NaN or Inf"),
                            (tri * 10 * MAX_COORDINATE, "beyond the ray tracer's range"),
                            (np.zeros((3, 3)), "every triangle is degenerate")):
        write_obj(folder / "m.obj", vertices, [[0, 1, 2]])
        from_file = _error({**_dict(), "objects": [{"mesh": "m.obj"}]}, base_dir=folder)
        given = _error({**_dict(), "objects": [{"vertices": vertices, "faces": [[0, 1, 2]]}]}, base_dir=folder)
        assert given == from_file and words in given
    many = np.broadcast_to(np.int64(0), (MAX_TRIANGLES + 1, 3))   # no memory: counted from its shape
    assert "more than" in _error({**_dict(), "objects": [{"vertices": tri, "faces": many}]}, base_dir=folder)
    assert "given to wavlight.load_dict only" in _toml_error(
        folder, '[environment]\nprocedural = "sky"\n[[objects]]\nvertices = [[0.0, 0.0, 0.0]]\nfaces = [[0, 0, 0]]\n')


def test_the_content_hash_covers_the_arrays_bytes(folder):
    pixels = np.linspace(0.0, 1.0, 4 * 8 * 3).reshape(4, 8, 3)
    v, f = _box()

    def hashed(pixels, v, f):
        d = {**_dict(), "environment": {"pixels": pixels}, "objects": [{"vertices": v, "faces": f}]}
        return _caught(lambda: wavlight.load_dict(d, base_dir=folder))[0].content_hash
    base = hashed(pixels, v, f)
    assert hashed(pixels.astype(np.float32), v, f.astype(np.int32)) == base   # the same values as used
    moved = pixels.copy()
    moved[2, 3, 1] = np.nextafter(np.float32(moved[2, 3, 1]), np.float32(2))
    assert hashed(moved, v, f) != base
    other = v.copy()
    other[0, 0] += 1e-3
    assert hashed(pixels, other, f) != base
    assert hashed(pixels, v, f[::-1]) != base
    assert hashed(pixels.reshape(8, 4, 3), v, f) != base   # the same bytes in another shape
