"""File kinds and sizes, as a hostile user would give them.

Bad input (a malformed or missing file, a FIFO, a folder, a symbolic link loop,
a device, a truncated or absurdly large file, a mesh with bad indices) gets one clear line
naming the file, and saying what is wrong with it (never "no such file" for a file that
exists, never "degenerate triangle" for a bad index), exit code 2, no traceback, no hang and
no output or temporary left behind; an output path that names an input of the run is refused
before rendering, so that no input is ever overwritten; images are written in strips (memory
a few MiB beyond the image), identical to a whole-image write.

Each case says what holds. Fast cases only: the in-process CLI (click's CliRunner) on
8 x 6 images; the slow ones (memory at large sizes, time to refuse) are in
benchmarks/probe_memory.py.
"""
from __future__ import annotations

import os
import threading

import numpy as np
import pytest

import wavlight
from wavlight import atomic, display, imageio, meshes
from wavlight.envmap import read_image
from wavlight.errors import WavlightError, file_problem, shown

from test_cli import assert_clean_failure, run_inproc, scene_text, write_scene
from scenes_util import write_raw_image

SKY = np.full((8, 16, 3), 0.5, np.float32)


def _within(seconds, fn, *args):
    """fn(*args) on a thread that must finish in time (a FIFO opened for reading would block)."""
    box = {}

    def run():
        try:
            box["value"] = fn(*args)
        except BaseException as e:   # noqa: BLE001
            box["error"] = e

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(seconds)
    assert not t.is_alive(), f"{fn.__name__} still running after {seconds} s (a hang)"
    if "error" in box:
        raise box["error"]
    return box.get("value")


# ============================================================================= kinds of files
def _fifo(p):
    os.mkfifo(p)


def _folder(p):
    os.mkdir(p)


def _loop(p):
    os.symlink(p.with_name(p.name + ".b"), p)
    os.symlink(p, p.with_name(p.name + ".b"))


def _broken(p):
    os.symlink(p.with_name("nowhere.exr"), p)


def _device(p):
    os.symlink("/dev/zero", p)


def _empty(p):
    p.write_bytes(b"")


KINDS = {   # kind: (make it at path p, words the message must hold)
    "fifo": (_fifo, "FIFO"),
    "folder": (_folder, "folder"),
    "symlink loop": (_loop, "symbolic link loop"),
    "broken symlink": (_broken, "broken symbolic link"),
    "device": (_device, "device"),
}


@pytest.mark.parametrize("kind", list(KINDS))
def test_file_problem_names_the_kind(tmp_path, kind):
    """A path that exists but is not a regular file is named for what it is."""
    make, words = KINDS[kind]
    p = tmp_path / "x.exr"
    make(p)
    assert words in file_problem(p)


@pytest.mark.parametrize("kind", list(KINDS))
def test_environment_map_of_another_kind(tmp_path, kind):
    """[environment].file naming a FIFO, folder, link loop, broken link or device is one
    line naming the key and the kind, at once (a FIFO must not block the reader)."""
    make, words = KINDS[kind]
    make(tmp_path / "map.exr")
    scene = write_scene(tmp_path, scene_text(env='file = "map.exr"'))
    o = _within(20, run_inproc, "render", scene, "-o", tmp_path / "o.png")
    msg = assert_clean_failure(o, "[environment].file", "map.exr", output=tmp_path / "o.png", folder=tmp_path)
    assert words in msg and "no such file" not in msg


@pytest.mark.parametrize("kind", list(KINDS))
def test_mesh_of_another_kind(tmp_path, kind):
    """[[objects]].mesh naming a FIFO, folder, link loop, broken link or device is one line
    naming the key and the kind (wavlight.errors.file_problem), never "no such file" for a path
    that exists."""
    make, words = KINDS[kind]
    make(tmp_path / "m.ply")
    scene = write_scene(tmp_path, scene_text(objects='[[objects]]\nmesh = "m.ply"\n'))
    o = _within(20, run_inproc, "render", scene, "-o", tmp_path / "o.png")
    msg = assert_clean_failure(o, "[[objects]][0].mesh", "m.ply", output=tmp_path / "o.png")
    assert words in msg and "no such file" not in msg, msg


@pytest.mark.parametrize("kind", ["fifo", "symlink loop", "device"])
def test_scene_file_of_another_kind(tmp_path, kind):
    """The scene path itself naming a FIFO, a link loop or a device is one line saying so
    (scene.load_scene asks wavlight.errors.file_problem, as above)."""
    make, words = KINDS[kind]
    make(tmp_path / "s.toml")
    o = _within(20, run_inproc, "render", tmp_path / "s.toml", "-o", tmp_path / "o.png")
    msg = assert_clean_failure(o, "s.toml", output=tmp_path / "o.png")
    assert words in msg and "no such file" not in msg, msg


# ============================================================================= damaged and absurd maps
def _truncated(ext):
    def make(p):
        wavlight.save_image(str(p.with_suffix(ext)), SKY + np.arange(16, dtype=np.float32)[None, :, None])
        data = p.with_suffix(ext).read_bytes()
        p.with_suffix(ext).write_bytes(data[:len(data) // 2])
        return p.with_suffix(ext)
    return make


def _pfm_header(w, h):
    def make(p):
        p = p.with_suffix(".pfm")
        head = f"PF\n{w} {h}\n-1.0\n".encode()
        p.write_bytes(head + b"\0" * 1200)
        if w * h:   # a sparse file of the claimed size (OpenImageIO refuses a header larger than its file)
            with open(p, "r+b") as fh:
                fh.truncate(len(head) + w * h * 12)
        return p
    return make


def _text(p):
    p = p.with_suffix(".hdr")
    p.write_bytes(b"#?RADIANCE\nthis is not an image\n" * 50)
    return p


def _empty_file(p):
    p = p.with_suffix(".exr")
    p.write_bytes(b"")
    return p


MAPS = {   # case: (make the map beside p, returns its path; words of the message)
    "truncated exr": (_truncated(".exr"), "cannot read"),
    "truncated hdr": (_truncated(".hdr"), "cannot read pixels"),
    "truncated pfm": (_truncated(".pfm"), "cannot read pixels"),
    "empty file": (_empty_file, "cannot read image"),
    "text posing as hdr": (_text, "cannot read"),
    "pfm header of 20000 x 20000": (_pfm_header(20000, 20000), "too large"),
    "pfm header of 0 x 0": (_pfm_header(0, 0), "cannot read"),
}


@pytest.mark.parametrize("case", list(MAPS))
def test_damaged_or_absurd_map(tmp_path, case):
    """A truncated, empty, non-image or absurdly large map is one line naming the map and
    the problem, refused before its pixels are read (no 4.8 GB allocation for a 20000 x 20000 header)."""
    make, words = MAPS[case]
    path = make(tmp_path / "map")
    scene = write_scene(tmp_path, scene_text(env=f'file = "{path.name}"'))
    o = _within(20, run_inproc, "render", scene, "-o", tmp_path / "o.png")
    msg = assert_clean_failure(o, "[environment].file", path.name, output=tmp_path / "o.png", folder=tmp_path)
    assert words in msg, msg


def test_map_of_many_channels_reads_three(tmp_path):
    """A map of 5 channels is read as its first three (no 5-channel allocation)."""
    import OpenImageIO as oiio

    px = np.random.default_rng(0).random((4, 8, 5)).astype(np.float32)
    out = oiio.ImageOutput.create(str(tmp_path / "m.exr"))
    assert out.open(str(tmp_path / "m.exr"), oiio.ImageSpec(8, 4, 5, oiio.FLOAT))
    assert out.write_image(px)
    out.close()
    np.testing.assert_array_equal(read_image(str(tmp_path / "m.exr")), px[..., :3])


# ============================================================================= meshes with bad indices
def _ply(path, faces, index_type="int", count_type="uchar", ascii_rows=None, nv=4):
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32)[:nv]
    head = ["ply", "format ascii 1.0", f"element vertex {nv}", "property float x", "property float y",
            "property float z", f"element face {len(ascii_rows or faces)}",
            f"property list {count_type} {index_type} vertex_indices", "end_header"]
    rows = [" ".join(f"{x:g}" for x in v) for v in verts]
    rows += ascii_rows or ["3 " + " ".join(str(i) for i in f) for f in faces]
    path.write_text("\n".join(head + rows) + "\n")
    return path


PLYS = {   # case: (kwargs of _ply, words)
    "fractional index": (dict(faces=[], ascii_rows=["3 0 1.5 2"]), "face 0: vertex index 1.5 is not an integer"),
    "float index type": (dict(faces=[(0, 1, 2)], index_type="float"), "floating-point type"),
    "negative index": (dict(faces=[(0, 1, 2), (0, -1, 2)]), "face 1: vertex index -1 is outside 0..3"),
    "index past the vertices": (dict(faces=[(0, 1, 4)]), "face 0: vertex index 4 is outside 0..3"),
}


@pytest.mark.parametrize("case", list(PLYS))
def test_ply_bad_indices_name_the_face(tmp_path, case):
    """A bad PLY index is an error naming the face and the index (not a silently truncated
    index, not "degenerate triangle(s) removed", not "face indices out of range")."""
    kw, words = PLYS[case]
    _ply(tmp_path / "m.ply", **kw)
    with pytest.raises(ValueError, match=words):
        meshes.read_ply(str(tmp_path / "m.ply"))
    scene = write_scene(tmp_path, scene_text(objects='[[objects]]\nmesh = "m.ply"\n'))
    o = run_inproc("render", scene, "-o", tmp_path / "o.png")
    msg = assert_clean_failure(o, "[[objects]][0].mesh", "m.ply", output=tmp_path / "o.png")
    assert words in msg and "degenerate" not in msg


OBJS = {   # case: (file text, words)
    "index 0": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "line 4: face index 0"),
    "index past the vertices": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", "line 4: face index 4 but the file holds 3"),
    "fractional index": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2.5 3\n", "line 4: face index '2.5' is not an integer"),
    "negative index before the first": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -4\n", "line 4: face index -4"),
    "two-vertex face": ("v 0 0 0\nv 1 0 0\nf 1 2\n", "line 3: a face needs at least three vertices"),
    "vertex of two numbers": ("v 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "line 1: a vertex needs three numbers"),
    "vertex not a number": ("v 0 0 x\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "line 1: vertex coordinate 'x'"),
}


@pytest.mark.parametrize("case", list(OBJS))
def test_obj_reader_names_the_line(tmp_path, case):
    """meshes.read_obj refuses a bad OBJ index or vertex naming the line."""
    text, words = OBJS[case]
    (tmp_path / "m.obj").write_text(text)
    with pytest.raises(ValueError, match=words):
        meshes.read_obj(str(tmp_path / "m.obj"))


@pytest.mark.parametrize("case", ["index 0", "index past the vertices", "fractional index"])
def test_obj_bad_index_through_the_cli(tmp_path, case):
    """An OBJ face index 0 (or past the vertices, or fractional) is one line naming the line, not
    "degenerate triangle(s) removed" (trimesh would read 0 as vertex 0): scenes read .obj files
    with wavlight.meshes.read_obj."""
    text, words = OBJS[case]
    (tmp_path / "m.obj").write_text(text)
    scene = write_scene(tmp_path, scene_text(objects='[[objects]]\nmesh = "m.obj"\n'))
    o = run_inproc("render", scene, "-o", tmp_path / "o.png")
    msg = assert_clean_failure(o, "[[objects]][0].mesh", "m.obj", output=tmp_path / "o.png")
    assert "line 4" in msg and "degenerate" not in msg, msg


def test_obj_reader_matches_trimesh_on_real_meshes(tmp_path):
    """read_obj gives the triangles trimesh gives (same set, same orientation) for the OBJ
    meshes that ship with wavlight (Spot, with texture coordinates; the teapot) and for a file
    of quads and a pentagon."""
    import io
    import warnings

    import trimesh

    from wavlight import data

    polygons = tmp_path / "polygons.obj"   # quads and a pentagon, in the three f forms
    polygons.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\nv 0.5 1.5 0.5\n"
                        "vt 0 0\nvn 0 0 1\nf 1 2 3 4\nf 5/1 6/1 7/1 8/1\nf 1//1 2//1 6//1 5//1\n"
                        "f 2/1/1 3/1/1 7/1/1 6/1/1\nf 4 3 9 7 8\n")
    for path in (data.path("spot"), data.path("teapot"), polygons):
        name = path.name
        v, f = meshes.read_obj(str(path))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            m = trimesh.load(io.StringIO(path.read_text(errors="replace")), file_type="obj",
                             force="mesh", process=False)
        ours, theirs = v[f], np.asarray(m.vertices)[np.asarray(m.faces)]

        def canonical(tris):   # each triangle rotated to start at its smallest vertex; then sorted
            keys = [tuple(map(tuple, np.roll(t, -min(range(3), key=lambda k: tuple(t[k])), axis=0))) for t in tris]
            return sorted(keys)
        assert canonical(ours) == canonical(theirs), name


def test_mesh_file_too_large_is_refused_before_reading(tmp_path):
    """A mesh file beyond MAX_MESH_BYTES (a sparse 3 GB PLY) is refused from its size, at
    once, without reading it into memory."""
    p = tmp_path / "huge.ply"
    with open(p, "wb") as fh:
        fh.truncate(3 << 30)
    with pytest.raises(ValueError, match="GB; meshes of up to 2 GiB"):
        _within(5, meshes.read_ply, str(p))


# ============================================================================= outputs that name inputs
def _sky_scene(tmp_path, out_name="map.exr"):
    write_raw_image(tmp_path / "map.exr", SKY)
    return write_scene(tmp_path, scene_text(env='file = "map.exr"'))


def test_same_file_sees_links(tmp_path):
    """imageio.same_file sees a path, a symbolic link to it and a hard link to it as one file."""
    a = tmp_path / "a.exr"
    a.write_bytes(b"x")
    os.symlink(a, tmp_path / "s.exr")
    os.link(a, tmp_path / "h.exr")
    (tmp_path / "other.exr").write_bytes(b"x")
    assert imageio.same_file(a, tmp_path / "s.exr") and imageio.same_file(a, tmp_path / "h.exr")
    assert imageio.same_file(a, tmp_path / "sub" / ".." / "a.exr")
    assert not imageio.same_file(a, tmp_path / "other.exr")


def test_check_not_input_refuses_an_input(tmp_path):
    """imageio.check_not_input names the output and the input it would replace."""
    scene = _sky_scene(tmp_path)
    inputs = imageio.scene_files(scene)
    assert str(tmp_path / "map.exr") in inputs and str(scene) in inputs
    with pytest.raises(WavlightError, match=r"map\.exr: is an input of this run"):
        imageio.check_not_input([tmp_path / "map.exr"], inputs)
    imageio.check_not_input([tmp_path / "o.exr"], inputs)


@pytest.mark.parametrize("how", ["the map", "a symlink to the map", "--stderr-out is the map"])
def test_render_output_that_is_an_input_is_refused(tmp_path, how):
    """`wavlight render scene.toml -o map.exr`, where map.exr is the scene's own map (or a link
    to it, or --stderr-out naming it), is refused before rendering, and the map is left as it was:
    the outputs are checked against the scene's files after the scene is loaded and before it is
    rendered."""
    scene = _sky_scene(tmp_path)
    before = (tmp_path / "map.exr").read_bytes()
    if how == "the map":
        args = ["-o", tmp_path / "map.exr"]
    elif how == "a symlink to the map":
        os.symlink(tmp_path / "map.exr", tmp_path / "link.exr")
        args = ["-o", tmp_path / "link.exr"]
    else:
        args = ["-o", tmp_path / "o.exr", "--stderr-out", tmp_path / "map.exr"]
    o = run_inproc("render", scene, *args, "--spp", 2)
    assert_clean_failure(o, "is an input", folder=tmp_path)
    assert (tmp_path / "map.exr").read_bytes() == before
    assert not (tmp_path / "o.exr").exists()


# ============================================================================= the strip writer
@pytest.mark.parametrize("ext", imageio.FORMATS)
def test_strips_write_what_a_whole_image_write_does(tmp_path, ext, monkeypatch):
    """An image written in strips (here 1 row each, OpenImageIO's scanlines) is the same
    file content as one written whole, in every format (PFM's bottom-up rows included)."""
    import OpenImageIO as oiio

    img = np.random.default_rng(1).normal(0.5, 1.0, (37, 23, 3)).astype(np.float32)
    wavlight.save_image(str(tmp_path / f"whole{ext}"), img)
    monkeypatch.setattr(imageio, "STRIP_BYTES", 1)
    assert len(imageio._rows(37, 23)) == 37
    wavlight.save_image(str(tmp_path / f"strips{ext}"), img)

    def pixels(p):
        inp = oiio.ImageInput.open(str(p))
        px = inp.read_image()
        inp.close()
        return px
    np.testing.assert_array_equal(pixels(tmp_path / f"whole{ext}"), pixels(tmp_path / f"strips{ext}"))


def test_srgb_strip_encoding_matches_srgb_encode():
    """The in-place float32 sRGB conversion gives the 8-bit values of srgb_encode."""
    x = np.concatenate([np.linspace(-1, 2, 3999, dtype=np.float32),
                        np.float32([0.0031308, 0.0031307, 0.04045, 1.0, 0.5, 0.0])]).reshape(-1, 1, 3)
    old = (imageio.srgb_encode(x) * 255.0 + 0.5).astype(np.uint8)
    np.testing.assert_array_equal(display.encode8(x), old)


def test_unaligned_and_strided_images_are_written(tmp_path):
    """An image whose buffer is not aligned (numpy gives one when unpickling from a byte offset,
    as a dask worker's image arrives; OpenImageIO refuses such a buffer, "buffer is wrong size")
    or not contiguous (a transposed view) is written correctly."""
    img = np.random.default_rng(2).random((24, 32, 3)).astype(np.float32)
    buf = bytearray(img.nbytes + 1)
    unaligned = np.frombuffer(buf, np.uint8, img.nbytes, 1).view(np.float32).reshape(img.shape)
    unaligned[...] = img
    assert not unaligned.flags.aligned
    wavlight.save_image(str(tmp_path / "u.exr"), unaligned)
    np.testing.assert_array_equal(read_image(str(tmp_path / "u.exr")), img)
    t = np.ascontiguousarray(img.transpose(1, 0, 2)).transpose(1, 0, 2)
    wavlight.save_image(str(tmp_path / "t.pfm"), t)
    np.testing.assert_array_equal(read_image(str(tmp_path / "t.pfm")), img)


def test_a_killed_writers_temporary_is_removed_by_the_next_write(tmp_path):
    """A `.wavlight-*` temporary that a killed process left beside an output
    is removed by the next successful write into that folder; a live process's is kept."""
    import subprocess
    import sys

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    host = atomic.host_id()
    stale = tmp_path / f".wavlight-{dead}.{host}-o.png.abc123xy.png"
    live = tmp_path / f".wavlight-{os.getppid()}.{host}-o.png.zzz999qq.png"
    other_host = tmp_path / f".wavlight-{dead}.00000000-o.png.abc123xy.png"
    for p in (stale, live, other_host):
        p.write_bytes(b"half an image")
    wavlight.save_image(str(tmp_path / "o.png"), SKY)
    names = sorted(p.name for p in tmp_path.iterdir())
    assert stale.name not in names and live.name in names and other_host.name in names, names


# ============================================================================= messages that flood
def test_shown_never_floods():
    """A value shown in a message is at most ~80 characters plus its size,
    whatever its length or depth, and showing it does not build its whole repr."""
    import time

    nested = []
    for _ in range(100_000):
        nested = [nested]
    t = time.perf_counter()
    for value in (list(range(10 ** 6)), "x" * 10 ** 7, {i: i for i in range(10 ** 5)}, nested, b"\0" * 10 ** 7):
        text = shown(value)
        assert len(text) < 130 and "\n" not in text, text[:200]
    assert time.perf_counter() - t < 1.0


def test_a_1_mb_value_in_a_scene_is_not_echoed(tmp_path):
    """A scene value that is a 1 MB array gives a short error line: every message shows a value
    through errors.shown, never its whole repr (benchmarks/probe_memory.py times a 10 MB one)."""
    big = "[" + ", ".join(["1.0"] * 200_000) + "]"   # 1 MB: the message must not grow with it
    scene = write_scene(tmp_path, scene_text(camera=f"eye = {big}\n"))
    o = run_inproc("render", scene, "-o", tmp_path / "o.png")
    msg = assert_clean_failure(o, "[camera].eye", output=tmp_path / "o.png")
    assert len(msg) < 300, len(msg)
