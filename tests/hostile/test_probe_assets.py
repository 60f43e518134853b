"""Mesh files with materials, as a hostile user would hand them to ``wavlight render``.

What holds (docs/scene-format.md, "Mesh files with their materials"): a glTF that requires an
extension is refused (exit 2, one 'Error:' line naming the file and the extension, nothing
written); everything else renders with a documented fallback and one 'warning:' line naming
the file and the part (exit 3, the code of input repaired rather than refused): a texture
missing or unreadable (the base colour alone), an extension used but not required (ignored),
a primitive that is not triangles (skipped), an OBJ whose MTL is missing (the default
material), an MTL's map_Kd missing (Kd alone).
"""
from __future__ import annotations

import json

import pytest

from assets_util import write_glb, write_obj
from test_cli import assert_clean_failure, run_inproc, stderr_lines


def _gltf(folder, edit):
    """The test GLB re-exported as a .gltf with its files in ``folder``, its JSON changed by ``edit``."""
    import trimesh

    files = trimesh.load_scene(write_glb(folder / "src.glb")).export(file_type="gltf")
    doc = json.loads(files.pop("model.gltf"))
    for name, data in files.items():
        (folder / name).write_bytes(data)
    edit(doc, folder)
    path = folder / "model.gltf"
    path.write_text(json.dumps(doc))
    return path


def _floor_material(doc):
    return next(m for m in doc["materials"] if "baseColorTexture" in m.get("pbrMetallicRoughness", {}))


def _missing_texture(doc, folder):
    doc["images"][0] = {"uri": "stripes.png"}


def _unreadable_texture(doc, folder):
    doc["images"][0] = {"uri": "stripes.png"}
    (folder / "stripes.png").write_bytes(b"\x89PNG\r\n\x1a\nnot a png at all")


def _lines(doc, folder):
    doc["meshes"][-1]["primitives"][0]["mode"] = 1


def _fan(doc, folder):
    doc["meshes"][-1]["primitives"][0]["mode"] = 6


def _optional_extension(doc, folder):
    doc["extensionsUsed"] = ["KHR_materials_clearcoat"]
    _floor_material(doc)["extensions"] = {"KHR_materials_clearcoat": {"clearcoatFactor": 1.0}}


def _required_extension(doc, folder):
    doc["extensionsUsed"] = doc["extensionsRequired"] = ["KHR_draco_mesh_compression"]


WARNED = {   # case: (edit, words the one warning line holds besides the file)
    "texture missing": (_missing_texture, ("'floor'", "stripes.png", "missing or unreadable")),
    "texture unreadable": (_unreadable_texture, ("'floor'", "stripes.png", "missing or unreadable")),
    "lines primitive": (_lines, ("mesh", "primitive 0", "LINES", "skipped")),
    "triangle fan": (_fan, ("mesh", "primitive 0", "TRIANGLE_FAN", "skipped")),
    "optional extension": (_optional_extension, ("'floor'", "KHR_materials_clearcoat", "ignored")),
}


def _render(path, folder):
    out = folder / "out.png"
    return run_inproc("render", path, "--spp", 1, "--width", 16, "--height", 12, "-o", out, "-q"), out


def _assert_warned(o, out, path, words):
    assert o.exception is None and "Traceback" not in o.stderr, o.describe()
    lines = stderr_lines(o)
    assert o.code == 3 and out.exists(), o.describe()
    assert len(lines) == 1 and lines[0].startswith("warning: "), o.describe()
    for w in (str(path), *words):
        assert w in lines[0], f"{w!r} not named\n{o.describe()}"


@pytest.mark.parametrize("case", list(WARNED))
def test_gltf_fallbacks_warn(tmp_path, case):
    edit, words = WARNED[case]
    path = _gltf(tmp_path, edit)
    o, out = _render(path, tmp_path)
    _assert_warned(o, out, path, words)


def test_gltf_required_extension_refused(tmp_path):
    path = _gltf(tmp_path, _required_extension)
    o, out = _render(path, tmp_path)
    assert_clean_failure(o, path, "KHR_draco_mesh_compression", output=out)


def test_obj_mtl_missing_warns(tmp_path):
    path = write_obj(tmp_path, write_mtl=False)
    o, out = _render(path, tmp_path)
    _assert_warned(o, out, path, ("a.mtl", "missing", "default material"))


def test_obj_texture_missing_warns(tmp_path):
    metal = "newmtl tex\nKd 0.8 0.8 0.8\nmap_Kd stripes.png\nnewmtl shiny\nKd 0 0 0\nKs 0.5 0.5 0.5\nNs 50\n" \
            "newmtl dull\nKd 0.5 0.4 0.3\n"
    path = write_obj(tmp_path, write_texture=False, mtl_text=metal)
    o, out = _render(path, tmp_path)
    _assert_warned(o, out, path, ("'tex'", "stripes.png", "missing or unreadable"))


def test_obj_material_not_in_library_warns(tmp_path):
    metal = "newmtl tex\nKd 0.8 0.8 0.8\nmap_Kd stripes.png\nnewmtl dull\nKd 0.5 0.4 0.3\n"
    path = write_obj(tmp_path, mtl_text=metal, shiny="nowhere")
    o, out = _render(path, tmp_path)
    _assert_warned(o, out, path, ("default material",))


def test_plastic_part_refused_or_rendered(tmp_path):
    """A non-metal glTF part maps to plastic: rendered where this build has plastic, else one
    'Error:' line naming the file and the part, nothing written."""
    from wavlight import bsdfs

    path = write_glb(tmp_path / "a.glb", plastic_sphere=True)
    o, out = _render(path, tmp_path)
    if "plastic" in bsdfs.TYPES:
        assert o.code == 0 and out.exists(), o.describe()
    else:
        assert_clean_failure(o, path, "'red'", "plastic", output=out)


def test_env_with_a_scene_file_refused(tmp_path):
    """--env names the map of a mesh file rendered directly; a scene file names its own."""
    scene = tmp_path / "s.toml"
    scene.write_text('[environment]\nprocedural = "sky"\n')
    o = run_inproc("render", scene, "--env", "data:rooitou_park_512", "-o", tmp_path / "s.png")
    assert_clean_failure(o, "--env", scene, output=tmp_path / "s.png")


def test_asset_that_is_no_mesh_refused(tmp_path):
    """A .glb that is not a glTF: one line naming the file, nothing written."""
    path = tmp_path / "junk.glb"
    path.write_bytes(b"not a gltf at all" * 10)
    o, out = _render(path, tmp_path)
    assert_clean_failure(o, path, output=out)
