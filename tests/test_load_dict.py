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
