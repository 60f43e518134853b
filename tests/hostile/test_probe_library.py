"""The library API misused, as a hostile caller would.

A library call with an argument of the wrong type, shape or range raises a one-line
:class:`wavlight.WavlightError` (ArgumentError: also a ValueError) that names the function or
the file and the argument, never a bare TypeError, ValueError or MemoryError from deep inside,
never a NaN image, never an attempt to allocate or write an absurd amount (np.broadcast_to
makes a 10^10-pixel image out of 4 bytes; icosphere(20) is 20 G triangles). Python's own
errors for a call with arguments the function does not have (an unknown keyword) stay
TypeErrors, as for any Python function; run_suite, which takes free-form options, names an
unknown one.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

import wavlight
from wavlight import envmap, imageio, meshes, raytrace
from wavlight.errors import WavlightError
from wavlight.evaluation import experiment
from scenes_util import run_limited

IMG = np.ones((4, 8, 3), np.float32)


def _scene(tmp_path):
    (tmp_path / "s.toml").write_text('[render]\nwidth = 8\nheight = 6\nspp = 2\n[camera]\neye = [0.0, 1.0, 3.0]\n'
                                     'target = [0.0, 0.4, 0.0]\n[environment]\nprocedural = "sky"\n'
                                     '[[objects]]\nshape = "sphere"\nsubdivisions = 1\n')
    return wavlight.load_scene(str(tmp_path / "s.toml"))


CASES = {   # case: (call(tmp_path), words of the message)
    # ---- writing images
    "save_image path None": (lambda t: wavlight.save_image(None, IMG), "path must be a file name"),
    "save_image path 123": (lambda t: wavlight.save_image(123, IMG), "path must be a file name"),
    "save_image path with NUL": (lambda t: wavlight.save_image(str(t / "a\0.png"), IMG), "path must be a file name"),
    "save_image path empty": (lambda t: wavlight.save_image("", IMG), "path must be a file name"),
    "save_image image None": (lambda t: wavlight.save_image(str(t / "a.png"), None), "image of real numbers"),
    "save_image image a string": (lambda t: wavlight.save_image(str(t / "a.png"), "abc"), "image of real numbers"),
    "save_image object array": (lambda t: wavlight.save_image(str(t / "a.png"), np.zeros((2, 2, 3), object)),
                                "image of real numbers"),
    "save_image complex": (lambda t: wavlight.save_image(str(t / "a.exr"), np.zeros((2, 2, 3), complex)),
                           "image of real numbers"),
    "save_image 2-d": (lambda t: wavlight.save_image(str(t / "a.exr"), np.zeros((2, 3))), "(H, W, 3)"),
    "save_image empty": (lambda t: wavlight.save_image(str(t / "a.exr"), np.zeros((0, 5, 3))), "empty"),
    "save_image beyond float32": (lambda t: wavlight.save_image(str(t / "a.exr"), np.full((2, 2, 3), 1e39)),
                                  "beyond float32"),
    "save_image NaN": (lambda t: wavlight.save_image(str(t / "a.exr"), np.full((2, 2, 3), np.nan)), "NaN"),
    "save_image .tiff": (lambda t: wavlight.save_image(str(t / "a.tiff"), IMG), "unsupported output format"),
    "save_image no folder": (lambda t: wavlight.save_image(str(t / "no" / "a.exr"), IMG), "does not exist"),
    "save_images not pairs": (lambda t: imageio.save_images(5), "(path, image) pairs"),
    "save_images one path twice": (lambda t: imageio.save_images([(t / "a.exr", IMG), (t / "a.exr", IMG)]),
                                   "named twice"),
    # ---- reading maps, meshes
    "read_image None": (lambda t: envmap.read_image(None), "is not a path"),
    "read_image 3 (a file descriptor)": (lambda t: envmap.read_image(3), "is not a path"),
    "read_image a folder": (lambda t: envmap.read_image(str(t)), "is a folder"),
    "read_ply None": (lambda t: meshes.read_ply(None), "mesh file's path"),
    "read_ply 0 (stdin's descriptor)": (lambda t: meshes.read_ply(0), "mesh file's path"),
    "read_obj a folder": (lambda t: meshes.read_obj(str(t)), "is a folder"),
    "icosphere 2.5": (lambda t: meshes.icosphere(2.5), "subdivisions must be an integer"),
    "icosphere -1": (lambda t: meshes.icosphere(-1), "subdivisions must be between 0 and 10"),
    "icosphere radius nan": (lambda t: meshes.icosphere(1, float("nan")), "radius"),
    # ---- environments
    "Environment of a string": (lambda t: envmap.Environment("abc"), "pixels must be an array of real numbers"),
    "Environment scale None": (lambda t: envmap.Environment(IMG, scale=None), "scale must be a number"),
    "Environment scale NaN": (lambda t: envmap.Environment(IMG, scale=float("nan")), "scale must be a finite"),
    "Environment rotate_y a string": (lambda t: envmap.Environment(IMG, rotate_y="x"), "rotate_y must be a number"),
    "Environment empty": (lambda t: envmap.Environment(np.zeros((0, 0, 3))), "(H, W, 3)"),
    "procedural_sky width 0": (lambda t: envmap.procedural_sky(width=0), "width must be between 1"),
    "procedural_sky zenith of 2": (lambda t: envmap.procedural_sky(zenith=(1, 2)), "zenith must be 3 numbers"),
    "procedural_sky sun_radius 0": (lambda t: envmap.procedural_sky(sun_radius=0.0), "sun_radius"),
    # ---- ray tracing
    "RayTracer of strings": (lambda t: raytrace.RayTracer("x", "y"), "vertices must be an array of real numbers"),
    "RayTracer NaN vertices": (lambda t: raytrace.RayTracer(np.full((3, 3), np.nan), [[0, 1, 2]]), "finite"),
    "RayTracer face out of range": (lambda t: raytrace.RayTracer(np.eye(3), [[0, 1, 5]]), "index the 3 vertices"),
    "RayTracer float faces": (lambda t: raytrace.RayTracer(np.eye(3), [[0.0, 1.0, 2.0]]), "integers"),
    "RayTracer threads a string": (lambda t: raytrace.RayTracer(np.eye(3), [[0, 1, 2]], threads="x"), "threads"),
    "intersect of mismatched shapes": (lambda t: raytrace.RayTracer(np.eye(3), [[0, 1, 2]]).intersect(
        np.zeros((2, 3)), np.zeros((3, 3))), "(N, 3)"),
    # ---- rendering
    "render_full None": (lambda t: wavlight.render_full(None), "expected a Scene"),
    "render_full spp 2.5": (lambda t: wavlight.render_full(_scene(t), spp=2.5), "spp must be an integer"),
    "render_full spp 10^30": (lambda t: wavlight.render_full(_scene(t), spp=10 ** 30), "spp must be between"),
    "render_full threads '2'": (lambda t: wavlight.render_full(_scene(t), threads="2"), "threads"),
    # ---- experiments and suites
    "run_experiment workers 10^6": (lambda t: experiment.run_experiment(t / "e.toml", t / "o", workers=10 ** 6),
                                    "workers must be an integer in 1..64"),
    "run_experiment resume 'no'": (lambda t: experiment.run_experiment(t / "e.toml", t / "o", resume="no"),
                                   "resume must be True or False"),
    "run_experiment dask_timeout -1": (lambda t: experiment.run_experiment(t / "e.toml", t / "o", dask_timeout=-1),
                                       "dask_timeout"),
    "run_experiment out_dir None": (lambda t: experiment.run_experiment(t / "e.toml", None), "out_dir"),
    "run_suite unknown": (lambda t: experiment.run_suite("nope", t / "o"), "unknown suite"),
    "run_suite size -1": (lambda t: experiment.run_suite("stability", t / "o", size=-1), "size must be"),
    "run_suite spp 'x'": (lambda t: experiment.run_suite("stability", t / "o", spp="x"), "spp must be an integer"),
    "run_suite 10^6 repetitions": (lambda t: experiment.run_suite("stability", t / "o", repetitions=10 ** 6),
                                   "repetitions must be at most 1000"),
    "run_suite cases a string": (lambda t: experiment.run_suite("stability", t / "o", cases="one_texel"),
                                 "lists of names"),
    "run_suite unknown option": (lambda t: experiment.run_suite("stability", t / "o", colour=1),
                                 "unknown option 'colour'"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_misuse_is_a_one_line_wavlight_error(tmp_path, case):
    """Each misuse raises a WavlightError of one line (< 300 characters) holding the words, and
    leaves no `.wavlight-*` temporary in tmp_path."""
    call, words = CASES[case]
    before = set(tmp_path.iterdir())
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)   # numpy's overflow and invalid-value warnings
        with pytest.raises(WavlightError) as e:
            call(tmp_path)
    msg = str(e.value)
    assert words in msg and "\n" not in msg and len(msg) < 300, msg
    assert not [p for p in set(tmp_path.iterdir()) - before if p.name.startswith(".wavlight-")]


ABSURD = r"""
import sys
import numpy as np
from wavlight import envmap, imageio, meshes
from wavlight.errors import WavlightError
huge = np.broadcast_to(np.float32(0.5), (100_000, 100_000, 3))   # 10^10 pixels in 4 bytes
calls = {"icosphere(10**9)": lambda: meshes.icosphere(10 ** 9),
         "procedural_sky(10**6 x 10**6)": lambda: envmap.procedural_sky(width=10 ** 6, height=10 ** 6),
         "Environment(10^10 texels)": lambda: envmap.Environment(huge),
         "save_image(10^10 pixels)": lambda: imageio.save_image(sys.argv[1], huge)}
for name, call in calls.items():
    try:
        call()
        print(name, "no error")
    except WavlightError as e:
        print(name, "ok", str(e)[:120])
    except BaseException as e:
        print(name, "bad", type(e).__name__, str(e)[:120])
"""


def test_absurd_sizes_are_refused_before_allocating(tmp_path):
    """icosphere(10^9), a 10^6 x 10^6 procedural sky, an Environment or a save_image of a
    10^10-pixel array (np.broadcast_to: no memory) are refused from their sizes, at once, in a
    child limited to 3 GB of address space; unchecked, icosphere would subdivide until memory ran
    out (20 GB and more) and save_image would write a 120 GB file."""
    p, seconds = run_limited(ABSURD, tmp_path / "a.exr", gigabytes=3, timeout=60, what="not refused")
    lines = p.stdout.splitlines()
    assert len(lines) == 4 and all(" ok " in line for line in lines), p.stdout + p.stderr[-1000:]
    assert seconds < 30 and not list(tmp_path.iterdir())


def test_a_degenerate_face_in_a_python_built_scene_renders_finite(tmp_path):
    """A Scene edited in Python to hold a zero-area face (load_scene removes them) renders a
    finite image without numpy's divide warnings: the ray tracer gives such a face a zero
    normal, not a NaN one."""
    scene = _scene(tmp_path)
    scene.faces = np.concatenate([scene.faces, [[0, 0, 1]]]).astype(np.int32)
    scene.face_material = np.concatenate([scene.face_material, [0]]).astype(np.int32)
    scene.normal_faces = np.concatenate([scene.normal_faces, [[-1, -1, -1]]]).astype(np.int32)   # shaded flat
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        image = wavlight.render(scene, spp=2)
    assert np.all(np.isfinite(image))


def test_memory_a_render_needs_is_stated(monkeypatch):
    """imageio.render_bytes states the memory a size needs (36 bytes per
    pixel, measured, plus the process), and check_memory refuses what will not fit, in one line."""
    assert imageio.render_bytes(16384, 16384) == 16384 * 16384 * 36 + imageio.RENDER_BASE_BYTES
    monkeypatch.setattr(imageio, "available_bytes", lambda: 1 << 30)
    with pytest.raises(WavlightError, match=r"x\.png: a 16384x16384 render needs about 10\.1 GB .* 1\.1 GB is available"):
        imageio.check_memory("x.png", 16384, 16384)
    assert imageio.check_memory("x.png", 64, 48) == imageio.render_bytes(64, 48)
