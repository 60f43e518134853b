"""Scene values and types, as a hostile user would write them.

A scene value of the wrong type, out of range, absurd in size or nested without end is one line
naming the file and the key (exit 2, no traceback, no output), found before any geometry is
built or pixel rendered; a key that does nothing (roughness on lambert) is never silent. The
checks live in wavlight/scene.py; each case below says what holds.

The rule for keys of another material type: every key is checked (its type and range) and then
either used or reported. A key no material type knows is an error; a key that another type uses
(roughness on lambert or phong, exponent on lambert or ggx) is a warning naming the types that
use it, exit code 0: refusing it would refuse the scene format's own example (a ggx material
with "exponent = 100.0  # phong only", which tests/test_scene.py loads verbatim).
"""
from __future__ import annotations


import pytest

from scenes_util import run_limited
from test_cli import assert_clean_failure, run_inproc, scene_text, stderr_lines, write_scene

SPHERE = '[[objects]]\nshape = "sphere"\nsubdivisions = 1\n'


def _objects(text):
    return scene_text(objects=text)


BAD = {   # case: (scene text, names the one error line must hold)
    # ---- nesting and size
    "arrays nested 1000 deep": (scene_text(render="width = " + "[" * 1000 + "]" * 1000 + "\n"), ("scene.toml",)),
    "inline tables nested 1000 deep": ("x = " + "{a = " * 1000 + "1" + "}" * 1000 + "\n", ("scene.toml",)),
    "tables nested 1000 deep": ("[" + ".".join(["a"] * 1000) + "]\nx = 1\n", ("scene.toml",)),
    # ---- wrong types at every level
    "render is an array": ('render = [1, 2]\n[camera]\neye = [0.0, 1.0, 3.0]\n[environment]\nprocedural = "sky"\n',
                           ("scene.toml", "render")),
    "materials is an array": ("materials = [1]\n" + _objects(SPHERE), ("scene.toml", "materials")),
    "objects is a table": ("[objects]\nshape = 1\n" + scene_text(objects=""), ("scene.toml", "objects")),
    "width is a bool": (scene_text(render="width = true\n"), ("[render].width",)),
    "width is inf": (scene_text(render="width = inf\n"), ("[render].width",)),
    "width is a float": (scene_text(render="width = 8.0\n"), ("[render].width",)),
    "seed beyond 64 bits": (scene_text(render="seed = 99999999999999999999999\n"), ("[render].seed",)),
    "spp a string": (scene_text(render='spp = "16"\n'), ("[render].spp",)),
    "fov_y nan": (scene_text(camera="eye = [0.0, 1.0, 3.0]\nfov_y = nan\n"), ("[camera].fov_y",)),
    "fov_y 180": (scene_text(camera="eye = [0.0, 1.0, 3.0]\nfov_y = 180.0\n"), ("[camera].fov_y",)),
    "eye with a string": (scene_text(camera='eye = [0.0, 1.0, "3"]\n'), ("[camera].eye",)),
    "eye of four numbers": (scene_text(camera="eye = [0.0, 1.0, 3.0, 4.0]\n"), ("[camera].eye",)),
    "eye beyond the ray tracer": (scene_text(camera="eye = [0.0, 1.0, 1e30]\n"), ("[camera].eye",)),
    "up along the view": (scene_text(camera="eye = [0.0, 3.0, 0.0]\ntarget = [0.0, 0.0, 0.0]\n"), ("[camera].up",)),
    "scale negative": (scene_text(env='procedural = "sky"\nscale = -1.0'), ("[environment].scale",)),
    "scale overflowing": (scene_text(env='procedural = "sky"\nscale = 1e38'), ("[environment].scale",)),
    "sun_radius 0": (scene_text(env='procedural = "sky"\nsun_radius = 0.0'), ("[environment].sun_radius",)),
    "unknown procedural": (scene_text(env='procedural = "clouds"'), ("[environment].procedural",)),
    "file and procedural": (scene_text(env='procedural = "sky"\nfile = "x.exr"'), ("[environment]",)),
    "radius 1e300": (_objects('[[objects]]\nshape = "sphere"\nradius = 1e300\n'), ("[[objects]][0]",)),
    "radius 0": (_objects('[[objects]]\nshape = "sphere"\nradius = 0.0\n'), ("[[objects]][0].radius",)),
    "subdivisions 9": (_objects('[[objects]]\nshape = "sphere"\nsubdivisions = 9\n'), ("[[objects]][0].subdivisions",)),
    "subdivisions negative": (_objects('[[objects]]\nshape = "sphere"\nsubdivisions = -1\n'),
                              ("[[objects]][0].subdivisions",)),
    "quad of size 1e-300": (_objects('[[objects]]\nshape = "quad"\nsize = 1e-300\n'), ("[[objects]][0]",)),
    "quad normal zero": (_objects('[[objects]]\nshape = "quad"\nnormal = [0.0, 0.0, 0.0]\n'),
                         ("[[objects]][0].normal",)),
    "scale zero": (_objects(SPHERE + "scale = 0.0\n"), ("[[objects]][0].scale",)),
    "rotate axis zero": (_objects(SPHERE + "rotate = [0.0, 0.0, 0.0, 30.0]\n"), ("[[objects]][0].rotate",)),
    "rotate of three": (_objects(SPHERE + "rotate = [0.0, 1.0, 30.0]\n"), ("[[objects]][0].rotate",)),
    "material a number": (_objects(SPHERE + "material = 5\n"), ("[[objects]][0].material",)),
    "mesh and shape": (_objects('[[objects]]\nshape = "sphere"\nmesh = "m.ply"\n'), ("[[objects]][0]",)),
    "unknown shape": (_objects('[[objects]]\nshape = "torus"\n'), ("[[objects]][0].shape",)),
    "albedo 1e300": (_objects(SPHERE + 'material = "m"\n[materials.m]\ntype = "lambert"\nalbedo = [1e300, 1.0, 1.0]\n'),
                     ("[materials.m].albedo",)),
    "albedo negative": (_objects(SPHERE + 'material = "m"\n[materials.m]\ntype = "lambert"\nalbedo = [-1.0, 1.0, 1.0]\n'),
                        ("[materials.m].albedo",)),
    "roughness 0": (_objects(SPHERE + 'material = "m"\n[materials.m]\ntype = "ggx"\nroughness = 0.0\n'),
                    ("[materials.m].roughness",)),
    "exponent 1e9": (_objects(SPHERE + 'material = "m"\n[materials.m]\ntype = "phong"\nexponent = 1e9\n'),
                     ("[materials.m].exponent",)),
    "material type missing": (_objects(SPHERE + 'material = "m"\n[materials.m]\nalbedo = [0.5, 0.5, 0.5]\n'),
                              ("[materials.m].type",)),
    "material not a table": (_objects(SPHERE) + "[materials]\nm = 5\n", ("[materials.m]",)),
    "unknown key on a material": (_objects(SPHERE + 'material = "m"\n[materials.m]\ntype = "ggx"\nshine = 1.0\n'),
                                  ("[materials.m].shine",)),
    "wavelet_levels 12": (scene_text(render="wavelet_levels = 12\n"), ("[render].wavelet_levels",)),
    "light_levels 0": (scene_text(render="light_levels = 0\n"), ("[render].light_levels",)),
    "sir_candidates 10^6": (scene_text(render="sir_candidates = 1000000\n"), ("[render].sir_candidates",)),
    "structured_strata 0": (scene_text(render="structured_strata = 0\n"), ("[render].structured_strata",)),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_scene_value_is_one_line(tmp_path, case):
    """A bad scene value is exit 2, one 'Error:' line naming the file and key, no traceback, no
    output (arrays, inline tables or tables nested 1000 deep are caught by scene.load_scene, not
    left to end in a RecursionError)."""
    text, names = BAD[case]
    scene = write_scene(tmp_path, text)
    o = run_inproc("render", scene, "-o", tmp_path / "o.png")
    msg = assert_clean_failure(o, *names, output=tmp_path / "o.png", folder=tmp_path)
    assert len(msg) < 400, msg


@pytest.mark.parametrize("kind, key, users", [("lambert", "roughness = 0.3", "ggx"),
                                              ("lambert", "exponent = 50.0", "phong"),
                                              ("phong", "roughness = 0.3", "ggx")])
def test_a_key_of_another_material_type_is_never_silent(tmp_path, kind, key, users):
    """Roughness on a lambert material (or any key another type uses) is reported in one warning
    naming the key and the types that use it ("[materials.m].roughness: ignored: only ggx
    materials use it"), exit 0: the rule above, never ignored without a word."""
    text = _objects(SPHERE + 'material = "m"\n') + f'[materials.m]\ntype = "{kind}"\n{key}\n'
    scene = write_scene(tmp_path, text)
    o = run_inproc("render", scene, "-o", tmp_path / "o.png", "--spp", 1)
    assert o.exception is None and o.code == 0, o.describe()
    warned = [line for line in stderr_lines(o) if line.startswith("warning:") and key.split()[0] in line]
    assert len(warned) == 1 and f"[materials.m].{key.split()[0]}" in warned[0] and users in warned[0], o.describe()


def test_a_bad_key_on_the_last_of_many_objects_is_found_before_any_geometry(tmp_path, monkeypatch):
    """An unknown key on the last of 2 000 objects is refused before any object's geometry is
    built: scene.load_scene checks every table's keys and types in one pass, then builds the
    geometry, so a bad key on object 100 001 is found without building the 100 000 spheres
    before it (about 15 s of work)."""
    from wavlight import meshes

    built = []
    real = meshes.icosphere
    monkeypatch.setattr(meshes, "icosphere", lambda *a, **k: built.append(1) or real(*a, **k))
    objs = SPHERE * 1999 + SPHERE + "colour = 1\n"
    scene = write_scene(tmp_path, scene_text(objects=objs))
    o = run_inproc("render", scene, "-o", tmp_path / "o.png")
    assert_clean_failure(o, "[[objects]][1999].colour", output=tmp_path / "o.png")
    assert not built, f"{len(built)} spheres built before the bad key was found"


def test_triangles_beyond_any_memory_are_refused_before_building(tmp_path):
    """100 spheres of subdivisions 8 (131 M triangles: ~50 GB at the ~390 bytes per triangle
    measured for load, BVH and shading tables; 16 spheres of subdivisions 7, 5.2 M triangles,
    take 2.1 GB and 21 s) are refused in one line before they are built, from the faces each
    shape will have: scene.load_scene sums the triangle counts (spheres 20 x 4^s, quads 2;
    meshes as they load) and refuses above MAX_TRIANGLES (2^24 = 16.8 M, ~6.5 GB), naming
    [[objects]]. Run in a child limited to 3 GB of address space, so that code which built them
    would fail instead of filling the machine."""
    objs = '[[objects]]\nshape = "sphere"\nsubdivisions = 8\n' * 100
    scene = write_scene(tmp_path, scene_text(objects=objs))
    code = ("import sys\nfrom wavlight.cli.main import main\n"
            "sys.argv = ['wavlight', 'render', sys.argv[1], '-o', sys.argv[2]]\nmain()\n")
    p, seconds = run_limited(code, scene, tmp_path / "o.png", gigabytes=3, timeout=20,
                             what="still building geometry")
    lines = [line for line in p.stderr.splitlines() if line.strip()]
    assert p.returncode == 2 and len(lines) == 1 and lines[0].startswith("Error:"), (p.returncode, p.stderr[-2000:])
    assert "[[objects]]" in lines[0] and "Traceback" not in p.stderr
    assert seconds < 20, seconds
